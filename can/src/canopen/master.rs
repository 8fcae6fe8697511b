//! The replay's CANopen master: brings the drives up (NMT, SDO
//! configuration, CiA 402 enable), streams the plan's setpoints in cyclic
//! synchronous position mode on SYNC, watches heartbeats, EMCY and the
//! envelope, and stops (quick stop, NMT stop) on any fault.

use super::pdo::*;
use super::protocol::*;
use crate::bus::{CanBus, CanFrame, Dir};
use crate::eds::DeviceDescription;
use crate::envelope::{Envelope, Violation};
use crate::error::{Error, Result};
use crate::source::Plan;
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};

/// Settings of the master (all times in µs on the bus clock).
#[derive(Debug, Clone)]
pub struct MasterConfig {
    pub cycle_us: u64,
    /// Node id per axis (x, y, z).
    pub nodes: [u8; 3],
    /// Which axis of its node each machine axis is (1 = objects at 0x6000,
    /// 2 = at 0x6800, …); two machine axes may share a two-axis drive.
    pub drive_axes: [u8; 3],
    /// The EDS/DCF of each node; a node without one is taken to be the
    /// shipped profile (configs/can/cia402_drive.eds).
    pub descriptions: BTreeMap<u8, DeviceDescription>,
    pub counts_per_mm: f64,
    /// Producer heartbeat time written to every drive (0x1017).
    pub heartbeat_ms: u16,
    /// A drive whose last heartbeat is older than this is lost.
    pub heartbeat_timeout_us: u64,
    pub sdo_timeout_us: u64,
    /// Cycles a drive may take for one CiA 402 transition before it counts as refused.
    pub transition_timeout_cycles: u32,
    /// Cycles the quick stop command is repeated after a stop (≥ 2).
    pub stop_hold_cycles: u32,
    /// Keep every frame sent and received (tests, dry-run printout).
    pub keep_traffic: bool,
}

/// What ended a replay early.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopKind {
    Envelope,
    Heartbeat,
    Emcy,
    BusOff,
    FollowingError,
    DriveFault,
    Refused,
    Sdo,
    Interrupt,
}

/// One streamed cycle: the setpoint sent and (when it came) the feedback.
#[derive(Debug, Clone)]
pub struct Sample {
    /// SYNC time of the cycle.
    pub t_us: u64,
    pub cmd: [i32; 3],
    pub act: [Option<i32>; 3],
    pub status: [Option<u16>; 3],
}

#[derive(Debug, Clone)]
pub struct Outcome {
    pub reached_operation_enabled: bool,
    pub cycles_streamed: usize,
    pub stop: Option<(StopKind, String)>,
    /// When the stop condition was detected / the first quick stop was sent.
    pub detected_us: Option<u64>,
    pub quick_stop_us: Option<u64>,
    pub samples: Vec<Sample>,
    pub traffic: Vec<(Dir, CanFrame)>,
    pub frames_tx: u64,
    pub frames_rx: u64,
    pub sync_frames: u64,
    pub max_following_mm: f64,
    /// What the start-up found worth saying (optional objects missing,
    /// a drive's own mapping used, limits wider than the envelope).
    pub warnings: Vec<String>,
    /// The PDOs each machine axis was driven through.
    pub pdos: Vec<AxisPdos>,
    /// 0x1008 of each node that has one (a segmented SDO upload).
    pub device_names: BTreeMap<u8, String>,
}

/// Where an axis' PDO mapping came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MapSource {
    /// Written by the master over SDO and read back equal.
    Configured,
    /// The drive refused the writes; its own mapping carries what is needed.
    DriveOwn,
}

/// The PDOs of one machine axis after start-up.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AxisPdos {
    pub axis: &'static str,
    pub drive: AxisRef,
    pub rpdo: PdoMap,
    pub rpdo_source: MapSource,
    pub tpdo: PdoMap,
    pub tpdo_source: MapSource,
}

const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// What one start-up SDO step is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum What {
    DeviceName,
    Heartbeat,
    /// COB-ID write, invalid (before the mapping) or valid (after).
    Cob {
        a: usize,
        tx: bool,
        valid: bool,
    },
    Count0 {
        a: usize,
        tx: bool,
    },
    Entry {
        a: usize,
        tx: bool,
    },
    Count {
        a: usize,
        tx: bool,
    },
    Tt {
        a: usize,
        tx: bool,
    },
    ReadCount {
        a: usize,
        tx: bool,
    },
    ReadEntry {
        a: usize,
        tx: bool,
    },
    ReadCob {
        a: usize,
        tx: bool,
    },
    ReadTt {
        a: usize,
        tx: bool,
    },
    /// No frame: compare what was read back (or adopt the drive's own).
    Verify {
        a: usize,
        tx: bool,
        fallback: bool,
    },
    Interp,
    LimitMin {
        a: usize,
    },
    LimitMax {
        a: usize,
    },
    MaxVel {
        a: usize,
    },
    /// No frame: the drive's limits against the plan and envelope.
    CheckLimits {
        a: usize,
    },
    Mode,
    ModeDisplay {
        a: usize,
    },
    Status {
        a: usize,
    },
    Actual {
        a: usize,
    },
}

impl What {
    /// The PDO a step belongs to.
    fn pdo(&self) -> Option<(usize, bool)> {
        use What::*;
        match *self {
            Cob { a, tx, .. }
            | Count0 { a, tx }
            | Entry { a, tx }
            | Count { a, tx }
            | Tt { a, tx }
            | ReadCount { a, tx }
            | ReadEntry { a, tx }
            | ReadCob { a, tx }
            | ReadTt { a, tx }
            | Verify { a, tx, .. } => Some((a, tx)),
            _ => None,
        }
    }
    fn optional(&self) -> bool {
        matches!(
            self,
            What::DeviceName
                | What::Interp
                | What::LimitMin { .. }
                | What::LimitMax { .. }
                | What::MaxVel { .. }
        )
    }
}

#[derive(Debug, Clone)]
struct Step {
    index: u16,
    sub: u8,
    /// Some: a download of these bytes; None: an upload (or no frame).
    write: Option<Vec<u8>>,
    what: What,
}

impl Step {
    fn read(index: u16, sub: u8, what: What) -> Step {
        Step {
            index,
            sub,
            write: None,
            what,
        }
    }
    fn write(index: u16, sub: u8, data: Vec<u8>, what: What) -> Step {
        Step {
            index,
            sub,
            write: Some(data),
            what,
        }
    }
    fn local(what: What) -> Step {
        Step::read(0, 0, what)
    }
    fn is_local(&self) -> bool {
        matches!(self.what, What::Verify { .. } | What::CheckLimits { .. })
    }
}

/// What the start-up read back of one PDO.
#[derive(Debug, Clone, Default)]
struct Readback {
    count: Option<u8>,
    entries: Vec<Mapped>,
    cob: Option<u32>,
    tt: Option<u8>,
    invalidated: bool,
    /// The abort that sent this PDO to the drive's own mapping.
    refused: Option<u32>,
}

/// One node's SDO client: the start-up script and the transfer in flight.
#[derive(Debug, Default, Clone)]
struct NodeSdo {
    node: u8,
    queue: VecDeque<Step>,
    pending: Option<(Step, SdoTransfer, u64)>,
    done: bool,
}

/// The drive limits read at start-up, per axis.
#[derive(Debug, Default, Clone, Copy)]
struct Limits {
    min: Option<i32>,
    max: Option<i32>,
    max_vel: Option<u32>,
}

/// What the plan needs of each axis (counts, counts/s).
#[derive(Debug, Clone, Copy)]
struct AxisNeed {
    min: i64,
    max: i64,
    peak_speed: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Init,
    Enable,
    Stream(usize),
    Finish(u32),
    Stopping(u32),
    Done,
}

#[derive(Debug, Clone)]
struct NodeInfo {
    drive: AxisRef,
    rpdo: PdoMap,
    tpdo: PdoMap,
    rpdo_source: MapSource,
    tpdo_source: MapSource,
    limits: Limits,
    mode_display: Option<u8>,
    status: Option<u16>,
    actual: Option<i32>,
    last_heartbeat_us: Option<u64>,
    hb_state: Option<u8>,
    state_since_cycle: u64,
    last_state: Option<DriveState>,
}

/// The replay master: one cycle at a time, every decision before a frame goes out.
pub struct Master {
    cfg: MasterConfig,
    nodes: [NodeInfo; 3],
    sdo: Vec<NodeSdo>,
    descriptions: BTreeMap<u8, DeviceDescription>,
    readback: BTreeMap<(usize, bool), Readback>,
    needs: Option<[AxisNeed; 3]>,
    max_speed_envelope: f64,
    /// SDO transfers given up on: an abort goes to the node.
    timed_out: Vec<(u8, u16, u8)>,
    phase: Phase,
    cycle: u64,
    hold: [i32; 3],
    last_sent: Option<[i32; 3]>,
    prev_step: [i32; 3],
    following_limit_mm: Option<f64>,
    out: Outcome,
}

impl Master {
    pub fn new(cfg: MasterConfig) -> Result<Master> {
        if cfg.cycle_us < 1000 {
            return Err(Error::Master(format!(
                "cycle of {} µs is shorter than 1 ms",
                cfg.cycle_us
            )));
        }
        if cfg.stop_hold_cycles < 2 {
            return Err(Error::Master(
                "the quick stop must be held for at least 2 cycles".into(),
            ));
        }
        check_eds(DRIVE_EDS)?;
        let mut descriptions = cfg.descriptions.clone();
        let mut nodes = Vec::new();
        for (a, axis_name) in AXIS_NAMES.iter().enumerate() {
            let drive = AxisRef::new(cfg.nodes[a], cfg.drive_axes[a]);
            if !(1..=4).contains(&drive.axis) {
                return Err(Error::Master(format!(
                    "axis {axis_name}: drive axis {} of node {} — a drive has axes 1–4 (one RPDO/TPDO pair each)",
                    drive.axis,
                    drive.node
                )));
            }
            if let Some(b) = (0..a)
                .find(|&b| cfg.nodes[b] == cfg.nodes[a] && cfg.drive_axes[b] == cfg.drive_axes[a])
            {
                return Err(Error::Master(format!(
                    "axes {} and {axis_name} are both {drive}: each machine axis needs its own drive axis",
                    AXIS_NAMES[b]
                )));
            }
            if let std::collections::btree_map::Entry::Vacant(e) = descriptions.entry(drive.node) {
                e.insert(DeviceDescription::parse(
                    "configs/can/cia402_drive.eds (shipped)",
                    DRIVE_EDS,
                    drive.node,
                )?);
            }
            let d = &descriptions[&drive.node];
            check_description(d, drive)?;
            nodes.push(NodeInfo {
                drive,
                rpdo: needed_rpdo(drive, d),
                tpdo: needed_tpdo(drive, d),
                rpdo_source: MapSource::Configured,
                tpdo_source: MapSource::Configured,
                limits: Limits::default(),
                mode_display: None,
                status: None,
                actual: None,
                last_heartbeat_us: None,
                hb_state: None,
                state_since_cycle: 0,
                last_state: None,
            });
        }
        let nodes: [NodeInfo; 3] = nodes.try_into().expect("three axes");
        let mut sdo: Vec<NodeSdo> = Vec::new();
        for n in &nodes {
            if !sdo.iter().any(|s| s.node == n.drive.node) {
                sdo.push(NodeSdo {
                    node: n.drive.node,
                    ..Default::default()
                });
            }
        }
        Ok(Master {
            cfg,
            nodes,
            sdo,
            descriptions,
            readback: BTreeMap::new(),
            needs: None,
            max_speed_envelope: f64::INFINITY,
            timed_out: Vec::new(),
            phase: Phase::Init,
            cycle: 0,
            hold: [0; 3],
            last_sent: None,
            prev_step: [0; 3],
            following_limit_mm: None,
            out: Outcome {
                reached_operation_enabled: false,
                cycles_streamed: 0,
                stop: None,
                detected_us: None,
                quick_stop_us: None,
                samples: Vec::new(),
                traffic: Vec::new(),
                frames_tx: 0,
                frames_rx: 0,
                sync_frames: 0,
                max_following_mm: 0.0,
                warnings: Vec::new(),
                pdos: Vec::new(),
                device_names: BTreeMap::new(),
            },
        })
    }

    fn node_index(&self, node: u32) -> Option<usize> {
        self.cfg.nodes.iter().position(|&n| n as u32 == node)
    }

    /// The RPDO of axis `a` carrying `controlword` and `target`, packed by
    /// the axis' mapping (a drive's own mapping may add the mode of
    /// operation, always CSP, and dummy entries).
    fn rpdo(&self, a: usize, controlword: u16, target: i32) -> CanFrame {
        let n = &self.nodes[a];
        let o = n.drive.offset();
        let payload = n.rpdo.encode(|index, _| {
            if index == 0x6040 + o {
                controlword as i64
            } else if index == 0x607A + o {
                target as i64
            } else if index == 0x6060 + o {
                obj::MODE_CSP as i64
            } else {
                0
            }
        });
        CanFrame::new(0, n.rpdo.id(), &payload)
    }

    /// The start-up script of every node: identity, heartbeat, the PDOs
    /// of each of its axes, interpolation period, limits, mode.
    fn build_script(&mut self) {
        let cycle_us = self.cfg.cycle_us;
        for s in &mut self.sdo {
            let node = s.node;
            let d = &self.descriptions[&node];
            let has =
                |index: u16, sub: u8| d.entries.iter().any(|e| e.index == index && e.sub == sub);
            let mut q = VecDeque::new();
            if has(0x1008, 0) {
                q.push_back(Step::read(0x1008, 0, What::DeviceName));
            }
            q.push_back(Step::write(
                obj::PRODUCER_HEARTBEAT_TIME,
                0,
                self.cfg.heartbeat_ms.to_le_bytes().to_vec(),
                What::Heartbeat,
            ));
            let axes: Vec<usize> = (0..3)
                .filter(|&a| self.nodes[a].drive.node == node)
                .collect();
            for &a in &axes {
                let n = &self.nodes[a];
                for (tx, m) in [(false, &n.rpdo), (true, &n.tpdo)] {
                    let k = n.drive.pdo();
                    let (comm, map) = if tx {
                        (0x1800 + k, 0x1A00 + k)
                    } else {
                        (0x1400 + k, 0x1600 + k)
                    };
                    // CiA 301: a mapping is changed only while its PDO is
                    // invalid and its count is 0; the count written last
                    // makes the new mapping take effect.
                    q.push_back(Step::write(
                        comm,
                        1,
                        (m.cob_id | COB_INVALID).to_le_bytes().to_vec(),
                        What::Cob {
                            a,
                            tx,
                            valid: false,
                        },
                    ));
                    q.push_back(Step::write(map, 0, vec![0], What::Count0 { a, tx }));
                    for (i, e) in m.entries.iter().enumerate() {
                        q.push_back(Step::write(
                            map,
                            i as u8 + 1,
                            e.raw().to_le_bytes().to_vec(),
                            What::Entry { a, tx },
                        ));
                    }
                    q.push_back(Step::write(
                        map,
                        0,
                        vec![m.entries.len() as u8],
                        What::Count { a, tx },
                    ));
                    q.push_back(Step::write(
                        comm,
                        2,
                        vec![m.transmission],
                        What::Tt { a, tx },
                    ));
                    q.push_back(Step::write(
                        comm,
                        1,
                        m.cob_id.to_le_bytes().to_vec(),
                        What::Cob { a, tx, valid: true },
                    ));
                    q.push_back(Step::read(map, 0, What::ReadCount { a, tx }));
                    q.push_back(Step::local(What::Verify {
                        a,
                        tx,
                        fallback: false,
                    }));
                }
            }
            for &a in &axes {
                let o = self.nodes[a].drive.offset();
                if has(0x60C2 + o, 1) && has(0x60C2 + o, 2) {
                    let (value, exp) = interpolation_period(cycle_us);
                    q.push_back(Step::write(0x60C2 + o, 1, vec![value], What::Interp));
                    q.push_back(Step::write(0x60C2 + o, 2, vec![exp as u8], What::Interp));
                }
                if has(0x607D + o, 1) && has(0x607D + o, 2) {
                    q.push_back(Step::read(0x607D + o, 1, What::LimitMin { a }));
                    q.push_back(Step::read(0x607D + o, 2, What::LimitMax { a }));
                }
                if has(0x607F + o, 0) {
                    q.push_back(Step::read(0x607F + o, 0, What::MaxVel { a }));
                }
                q.push_back(Step::local(What::CheckLimits { a }));
                q.push_back(Step::write(
                    obj::MODES_OF_OPERATION + o,
                    0,
                    vec![obj::MODE_CSP],
                    What::Mode,
                ));
                q.push_back(Step::read(
                    obj::MODES_OF_OPERATION_DISPLAY + o,
                    0,
                    What::ModeDisplay { a },
                ));
                q.push_back(Step::read(obj::STATUSWORD + o, 0, What::Status { a }));
                q.push_back(Step::read(
                    obj::POSITION_ACTUAL_VALUE + o,
                    0,
                    What::Actual { a },
                ));
            }
            s.queue = q;
        }
    }

    fn send(&mut self, bus: &mut dyn CanBus, f: CanFrame) -> Result<()> {
        let mut f = f;
        f.t_us = bus.now_us();
        bus.send(f)?;
        self.out.frames_tx += 1;
        if f.id == SYNC_ID {
            self.out.sync_frames += 1;
        }
        if self.cfg.keep_traffic {
            self.out.traffic.push((Dir::Tx, f));
        }
        Ok(())
    }

    /// Run the whole replay: configure, enable, stream `plan`, stop.
    pub fn run(
        mut self,
        bus: &mut dyn CanBus,
        plan: &Plan,
        env: &Envelope,
        interrupt: &AtomicBool,
    ) -> Result<Outcome> {
        let cpm = self.cfg.counts_per_mm;
        env.validate()?;
        if plan.cmd_mm.len() != plan.comp_mm.len() {
            return Err(Error::Master(format!(
                "plan: {} setpoints but {} compensation rows",
                plan.cmd_mm.len(),
                plan.comp_mm.len()
            )));
        }
        self.following_limit_mm = Some(env.max_following_mm);
        let cycle_s = self.cfg.cycle_us as f64 * 1e-6;
        self.max_speed_envelope = env.max_step_mm * cpm / cycle_s;
        let mut needs = [AxisNeed {
            min: i64::MAX,
            max: i64::MIN,
            peak_speed: 0.0,
        }; 3];
        let mut prev: Option<[f64; 3]> = None;
        // What the drives will be asked for: setpoints the envelope would
        // refuse never reach them (the replay stops there instead).
        let max_step = env.max_step_mm * cpm;
        for (c, d) in plan.cmd_mm.iter().zip(&plan.comp_mm) {
            let now = [0, 1, 2].map(|a| ((c[a] + d[a]) * cpm).round());
            for a in 0..3 {
                let t = now[a];
                if t.is_finite() && t.abs() <= i32::MAX as f64 {
                    needs[a].min = needs[a].min.min(t as i64);
                    needs[a].max = needs[a].max.max(t as i64);
                    if let Some(p) = prev.filter(|p| p[a].is_finite()) {
                        let step = (t - p[a]).abs();
                        if step <= max_step {
                            needs[a].peak_speed = needs[a].peak_speed.max(step / cycle_s);
                        }
                    }
                }
            }
            prev = Some(now);
        }
        self.needs = Some(needs);
        self.build_script();
        loop {
            let t = self.cycle * self.cfg.cycle_us;
            bus.wait_until(t)?;
            let mut fault = self.drain(bus)?;
            if fault.is_none() {
                fault = self.check_timeouts(t);
            }
            for (node, index, sub) in std::mem::take(&mut self.timed_out) {
                let p = sdo_abort_payload(index, sub, abort::TIMEOUT);
                self.send(bus, CanFrame::new(0, SDO_RX_BASE + node as u32, &p))?;
            }
            if fault.is_none() && interrupt.load(Ordering::SeqCst) {
                fault = Some((StopKind::Interrupt, "interrupted (SIGINT)".to_string()));
            }
            if let Some((kind, why)) = fault {
                self.begin_stop(kind, why, t);
            }
            match self.phase {
                Phase::Init => self.init_cycle(bus, t)?,
                Phase::Enable => self.enable_cycle(bus, plan, env, cpm)?,
                Phase::Stream(i) => self.stream_cycle(bus, plan, env, cpm, i, t)?,
                Phase::Finish(n) => {
                    for a in 0..3 {
                        let f = self.rpdo(a, cw::DISABLE_OPERATION, self.hold[a]);
                        self.send(bus, f)?;
                    }
                    self.phase = if n + 1 >= 2 {
                        Phase::Done
                    } else {
                        Phase::Finish(n + 1)
                    };
                }
                Phase::Stopping(n) => {
                    self.quick_stop_all(bus, t)?;
                    self.phase = if n + 1 >= self.cfg.stop_hold_cycles {
                        Phase::Done
                    } else {
                        Phase::Stopping(n + 1)
                    };
                }
                Phase::Done => {}
            }
            self.send(bus, sync_frame())?;
            // Start-up SDO exchanges are not paced by the cycle: a drive
            // answers within a fraction of it, so up to four round trips
            // fit between two SYNCs (the SYNC itself stays on time).
            let mut k = 1;
            while self.phase == Phase::Init && self.cycle > 0 && k < 4 {
                let tk = t + k * self.cfg.cycle_us / 4;
                bus.wait_until(tk)?;
                if let Some((kind, why)) = self.drain(bus)? {
                    self.begin_stop(kind, why, tk);
                    break;
                }
                self.init_cycle(bus, tk)?;
                k += 1;
            }
            if self.phase == Phase::Done {
                // Let the last feedback arrive, then leave the drives in
                // pre-operational (a normal end) or in quick stop (a stop).
                bus.wait_until(t + self.cfg.cycle_us)?;
                self.drain(bus)?;
                if self.out.stop.is_none() {
                    self.send(bus, nmt_frame(nmt::PRE_OPERATIONAL, 0))?;
                }
                break;
            }
            self.cycle += 1;
        }
        bus.finish()?;
        Ok(self.out)
    }

    fn begin_stop(&mut self, kind: StopKind, why: String, t: u64) {
        if matches!(self.phase, Phase::Stopping(_) | Phase::Done) || self.out.stop.is_some() {
            return;
        }
        tracing::warn!(
            "replay: quick stop of every drive at t = {:.6} s: {why}",
            t as f64 * 1e-6
        );
        self.out.stop = Some((kind, why));
        self.out.detected_us = Some(t);
        self.phase = Phase::Stopping(0);
    }

    fn quick_stop_all(&mut self, bus: &mut dyn CanBus, t: u64) -> Result<()> {
        for a in 0..3 {
            // Hold the last target: a drive in quick stop ramps down on its
            // own deceleration (0x6085) and ignores it; nothing new is commanded.
            let f = self.rpdo(a, cw::QUICK_STOP, self.hold[a]);
            self.send(bus, f)?;
        }
        if self.out.quick_stop_us.is_none() {
            self.out.quick_stop_us = Some(t);
        }
        Ok(())
    }

    fn init_cycle(&mut self, bus: &mut dyn CanBus, t: u64) -> Result<()> {
        if self.cycle == 0 {
            self.send(bus, nmt_frame(nmt::PRE_OPERATIONAL, 0))?;
            return Ok(());
        }
        for i in 0..self.sdo.len() {
            if self.out.stop.is_some() {
                return Ok(());
            }
            let node = self.sdo[i].node;
            if self.sdo[i].pending.is_some() || self.sdo[i].done {
                continue;
            }
            loop {
                match self.sdo[i].queue.pop_front() {
                    Some(step) if step.is_local() => {
                        if let Some((kind, why)) = self.local_step(i, step.what) {
                            self.begin_stop(kind, why, t);
                            return Ok(());
                        }
                    }
                    Some(step) => {
                        let (tr, payload) = match &step.write {
                            Some(data) => SdoTransfer::download(step.index, step.sub, data.clone()),
                            None => SdoTransfer::upload(step.index, step.sub),
                        };
                        self.sdo[i].pending = Some((step, tr, t));
                        self.send(bus, CanFrame::new(0, SDO_RX_BASE + node as u32, &payload))?;
                        break;
                    }
                    None => {
                        self.sdo[i].done = true;
                        break;
                    }
                }
            }
        }
        if self.sdo.iter().all(|n| n.done) {
            self.out.pdos = (0..3)
                .map(|a| {
                    let n = &self.nodes[a];
                    AxisPdos {
                        axis: AXIS_NAMES[a],
                        drive: n.drive,
                        rpdo: n.rpdo.clone(),
                        rpdo_source: n.rpdo_source,
                        tpdo: n.tpdo.clone(),
                        tpdo_source: n.tpdo_source,
                    }
                })
                .collect();
            for a in 0..3 {
                self.hold[a] = self.nodes[a].actual.unwrap_or(0);
                self.nodes[a].state_since_cycle = self.cycle;
            }
            self.send(bus, nmt_frame(nmt::START, 0))?;
            self.phase = Phase::Enable;
        }
        Ok(())
    }

    fn enable_cycle(
        &mut self,
        bus: &mut dyn CanBus,
        plan: &Plan,
        env: &Envelope,
        cpm: f64,
    ) -> Result<()> {
        let mut all_enabled = true;
        for a in 0..3 {
            let state = DriveState::from_statusword(self.nodes[a].status.unwrap_or(0));
            if state != DriveState::OperationEnabled {
                all_enabled = false;
            }
            let cmd = state.next_command().unwrap_or(cw::ENABLE_OPERATION);
            let f = self.rpdo(a, cmd, self.hold[a]);
            self.send(bus, f)?;
        }
        if all_enabled {
            self.out.reached_operation_enabled = true;
            tracing::info!("replay: every drive in Operation enabled (CSP)");
            if plan.cmd_mm.is_empty() {
                self.phase = Phase::Finish(0);
                return Ok(());
            }
            // The path must start where the axes are (no machine model covers
            // for a jump: the envelope's step limit applies from the hold).
            let first = plan.cmd_mm[0];
            for a in 0..3 {
                let target = first[a] + plan.comp_mm[0][a];
                let d = (target - self.hold[a] as f64 / cpm).abs();
                if !(d <= env.max_step_mm) {
                    let why = format!(
                        "axis {} is at {:.4} mm but the path starts at {:.4} mm ({:.4} mm away, more than one step of {} mm): position the axis at the path start first",
                        ["x", "y", "z"][a],
                        self.hold[a] as f64 / cpm,
                        target,
                        d,
                        env.max_step_mm
                    );
                    let t = bus.now_us();
                    self.begin_stop(StopKind::Envelope, why, t);
                    return Ok(());
                }
            }
            self.last_sent = Some(self.hold);
            self.phase = Phase::Stream(0);
        }
        Ok(())
    }

    fn stream_cycle(
        &mut self,
        bus: &mut dyn CanBus,
        plan: &Plan,
        env: &Envelope,
        cpm: f64,
        i: usize,
        t: u64,
    ) -> Result<()> {
        let prev = self.last_sent.unwrap_or(self.hold);
        match env.check(
            &plan.cmd_mm[i],
            &plan.comp_mm[i],
            &prev,
            &self.prev_step,
            cpm,
        ) {
            Ok(target) => {
                for a in 0..3 {
                    let f = self.rpdo(a, cw::ENABLE_OPERATION, target[a]);
                    self.send(bus, f)?;
                    self.prev_step[a] = target[a] - prev[a];
                }
                self.hold = target;
                self.last_sent = Some(target);
                self.out.samples.push(Sample {
                    t_us: t,
                    cmd: target,
                    act: [None; 3],
                    status: [None; 3],
                });
                self.out.cycles_streamed = i + 1;
                self.phase = if i + 1 == plan.cmd_mm.len() {
                    Phase::Finish(0)
                } else {
                    Phase::Stream(i + 1)
                };
            }
            Err(Violation(why)) => {
                let why = format!(
                    "setpoint {i} (t = {:.6} s) outside the envelope, not sent: {why}",
                    plan.t0_s + i as f64 * self.cfg.cycle_us as f64 * 1e-6
                );
                self.begin_stop(StopKind::Envelope, why, t);
                self.quick_stop_all(bus, t)?;
                self.phase = Phase::Stopping(1);
            }
        }
        Ok(())
    }

    /// Read everything received so far; the first fault seen, if any.
    fn drain(&mut self, bus: &mut dyn CanBus) -> Result<Option<(StopKind, String)>> {
        let mut fault: Option<(StopKind, String)> = None;
        let note = |f: &mut Option<(StopKind, String)>, k: StopKind, m: String| {
            if f.is_none() {
                *f = Some((k, m));
            }
        };
        let streaming = matches!(self.phase, Phase::Stream(_) | Phase::Finish(_));
        // Frames answering what was received (the next SDO segment, a
        // client abort) go out after the whole drain, so the bus log stays
        // in time order.
        let mut outbox: Vec<CanFrame> = Vec::new();
        while let Some(f) = bus.recv()? {
            self.out.frames_rx += 1;
            if self.cfg.keep_traffic {
                self.out.traffic.push((Dir::Rx, f));
            }
            if f.error {
                if f.is_bus_off() {
                    note(
                        &mut fault,
                        StopKind::BusOff,
                        format!(
                            "bus-off reported by the CAN controller at t = {:.6} s",
                            f.t_s()
                        ),
                    );
                }
                continue;
            }
            let (mut base, node) = (f.id & 0x780, f.id & 0x7F);
            let Some(mut a) = self.node_index(node) else {
                continue;
            };
            // A TPDO is known by its COB-ID (a drive's own mapping may use another).
            let tpdo_axis =
                (0..3).find(|&b| self.nodes[b].tpdo.valid() && self.nodes[b].tpdo.id() == f.id);
            if let Some(b) = tpdo_axis {
                a = b;
                base = TPDO1_BASE;
            } else if base == TPDO1_BASE {
                continue;
            }
            match base {
                HEARTBEAT_BASE => {
                    let state = f.payload().first().copied().unwrap_or(0xFF);
                    // Every machine axis on this node shares its heartbeat.
                    for b in 0..3 {
                        if self.cfg.nodes[b] as u32 == node {
                            self.nodes[b].last_heartbeat_us = Some(f.t_us);
                            self.nodes[b].hb_state = Some(state);
                        }
                    }
                    if streaming && state != nmt::HB_OPERATIONAL {
                        note(
                            &mut fault,
                            StopKind::DriveFault,
                            format!(
                                "node {node} left NMT Operational (heartbeat state 0x{state:02X})"
                            ),
                        );
                    }
                }
                EMCY_BASE => {
                    let d = f.payload();
                    let code = u16::from_le_bytes([
                        d.first().copied().unwrap_or(0),
                        d.get(1).copied().unwrap_or(0),
                    ]);
                    if code != 0 {
                        note(
                            &mut fault,
                            StopKind::Emcy,
                            format!(
                                "EMCY from node {node} (axis {}): error code 0x{code:04X}, error register 0x{:02X}",
                                ["x", "y", "z"][a],
                                d.get(2).copied().unwrap_or(0)
                            ),
                        );
                    }
                }
                TPDO1_BASE => {
                    let m = &self.nodes[a].tpdo;
                    let o = self.nodes[a].drive.offset();
                    let sw = m.value_of(f.payload(), 0x6041 + o);
                    let pos = m.find(0x6064 + o).and_then(|e| {
                        m.value_of(f.payload(), 0x6064 + o)
                            .map(|v| sign_extend(v, e.bits) as i32)
                    });
                    if let (Some(sw), Some(pos)) = (sw.map(|v| v as u16), pos) {
                        self.nodes[a].status = Some(sw);
                        self.nodes[a].actual = Some(pos);
                        let state = DriveState::from_statusword(sw);
                        if self.nodes[a].last_state != Some(state) {
                            self.nodes[a].last_state = Some(state);
                            self.nodes[a].state_since_cycle = self.cycle;
                        }
                        // The TPDO answers the last SYNC before it.
                        let k = self.out.samples.partition_point(|s| s.t_us < f.t_us);
                        // Only the first TPDO after a streamed SYNC answers it
                        // (later ones, after the last setpoint, are not matched).
                        if k > 0 && self.out.samples[k - 1].act[a].is_none() {
                            let s = &mut self.out.samples[k - 1];
                            s.act[a] = Some(pos);
                            s.status[a] = Some(sw);
                            let err_mm = (s.cmd[a] - pos) as f64 / self.cfg.counts_per_mm;
                            self.out.max_following_mm = self.out.max_following_mm.max(err_mm.abs());
                            if let Some(limit) = self.following_limit_mm {
                                if err_mm.abs() > limit {
                                    note(
                                        &mut fault,
                                        StopKind::FollowingError,
                                        format!(
                                            "following error on axis {} (node {node}): {:.4} mm > limit {limit} mm",
                                            ["x", "y", "z"][a],
                                            err_mm.abs()
                                        ),
                                    );
                                }
                            }
                        }
                        if streaming {
                            if state == DriveState::Fault
                                || state == DriveState::FaultReactionActive
                            {
                                note(
                                    &mut fault,
                                    StopKind::DriveFault,
                                    format!("node {node} reports Fault (statusword 0x{sw:04X})"),
                                );
                            } else if sw & SW_FOLLOWING_ERROR != 0 {
                                note(&mut fault, StopKind::FollowingError, format!("node {node} reports a following error (statusword 0x{sw:04X})"));
                            }
                        }
                    }
                }
                SDO_TX_BASE => {
                    let Some(i) = self.sdo.iter().position(|s| s.node as u32 == node) else {
                        continue;
                    };
                    let Some((step, mut tr, _)) = self.sdo[i].pending.take() else {
                        continue;
                    };
                    match tr.on_response(f.payload()) {
                        SdoStep::Send(p) => {
                            self.sdo[i].pending = Some((step, tr, f.t_us));
                            outbox.push(CanFrame::new(0, SDO_RX_BASE + node, &p));
                        }
                        SdoStep::Done(done) => {
                            if let Some((k, why)) = self.sdo_done(i, step, Ok(done), f.t_us) {
                                note(&mut fault, k, why);
                            }
                        }
                        SdoStep::Aborted(code) => {
                            if let Some((k, why)) = self.sdo_done(i, step, Err(code), f.t_us) {
                                note(&mut fault, k, why);
                            }
                        }
                        SdoStep::Failed(code) => {
                            outbox.push(CanFrame::new(
                                0,
                                SDO_RX_BASE + node,
                                &sdo_abort_payload(step.index, step.sub, code),
                            ));
                            note(
                                &mut fault,
                                StopKind::Sdo,
                                format!(
                                    "node {node}: SDO 0x{:04X}:{:02X} answered out of protocol; aborted with 0x{code:08X} ({})",
                                    step.index,
                                    step.sub,
                                    abort_name(code)
                                ),
                            );
                        }
                    }
                }
                _ => {}
            }
        }
        for f in outbox {
            self.send(bus, f)?;
        }
        Ok(fault)
    }

    fn file_of(&self, node: u8) -> String {
        self.descriptions
            .get(&node)
            .map(|d| d.file.clone())
            .unwrap_or_default()
    }

    fn pdo_name(&self, a: usize, tx: bool) -> String {
        format!(
            "{}{}",
            if tx { "TPDO" } else { "RPDO" },
            self.nodes[a].drive.axis
        )
    }

    /// A finished (or aborted) start-up SDO step of node `i`.
    fn sdo_done(
        &mut self,
        i: usize,
        step: Step,
        r: std::result::Result<SdoDone, u32>,
        t_us: u64,
    ) -> Option<(StopKind, String)> {
        let node = self.sdo[i].node;
        let value = |d: &SdoDone| -> u64 {
            match d {
                SdoDone::Uploaded(b) => {
                    let mut x = [0u8; 8];
                    let n = b.len().min(8);
                    x[..n].copy_from_slice(&b[..n]);
                    u64::from_le_bytes(x)
                }
                SdoDone::Downloaded => 0,
            }
        };
        let verb = if step.write.is_some() {
            "write"
        } else {
            "read"
        };
        let code = match r {
            Ok(done) => {
                let v = value(&done);
                match step.what {
                    What::DeviceName => {
                        if let SdoDone::Uploaded(b) = &done {
                            let name = String::from_utf8_lossy(b)
                                .trim_end_matches('\0')
                                .to_string();
                            tracing::info!("replay: node {node} is `{name}` (0x1008)");
                            self.out.device_names.insert(node, name);
                        }
                    }
                    What::Heartbeat => {
                        // Heartbeat supervision starts once the drive produces it.
                        for b in 0..3 {
                            if self.cfg.nodes[b] == node {
                                self.nodes[b].last_heartbeat_us = Some(t_us);
                            }
                        }
                    }
                    What::Cob {
                        a,
                        tx,
                        valid: false,
                    } => {
                        self.readback.entry((a, tx)).or_default().invalidated = true;
                    }
                    What::ReadCount { a, tx } => {
                        let rb = self.readback.entry((a, tx)).or_default();
                        rb.count = Some(v as u8);
                        rb.entries.clear();
                        let k = self.nodes[a].drive.pdo();
                        let map = if tx { 0x1A00 + k } else { 0x1600 + k };
                        // The entries, in order, before whatever came next.
                        for s in (1..=(v as u8).min(64)).rev() {
                            self.sdo[i].queue.push_front(Step::read(
                                map,
                                s,
                                What::ReadEntry { a, tx },
                            ));
                        }
                    }
                    What::ReadEntry { a, tx } => {
                        self.readback
                            .entry((a, tx))
                            .or_default()
                            .entries
                            .push(Mapped::from_raw(v as u32));
                    }
                    What::ReadCob { a, tx } => {
                        self.readback.entry((a, tx)).or_default().cob = Some(v as u32)
                    }
                    What::ReadTt { a, tx } => {
                        self.readback.entry((a, tx)).or_default().tt = Some(v as u8)
                    }
                    What::LimitMin { a } => self.nodes[a].limits.min = Some(v as u32 as i32),
                    What::LimitMax { a } => self.nodes[a].limits.max = Some(v as u32 as i32),
                    What::MaxVel { a } => self.nodes[a].limits.max_vel = Some(v as u32),
                    What::ModeDisplay { a } => {
                        self.nodes[a].mode_display = Some(v as u8);
                        if v as u8 != obj::MODE_CSP {
                            return Some((
                                StopKind::Refused,
                                format!(
                                "{} did not take cyclic synchronous position mode (0x{:04X} = {})",
                                self.nodes[a].drive, step.index, v as u8 as i8
                            ),
                            ));
                        }
                    }
                    What::Status { a } => self.nodes[a].status = Some(v as u16),
                    What::Actual { a } => self.nodes[a].actual = Some(v as u32 as i32),
                    _ => {}
                }
                return None;
            }
            Err(code) => code,
        };
        let file = self.file_of(node);
        let name = abort_name(code);
        if step.what.optional() {
            self.out.warnings.push(format!(
                "node {node}: {verb} of 0x{:04X}:{:02X} aborted with 0x{code:08X} ({name}); {} declares it — going on without it",
                step.index, step.sub, file
            ));
            return None;
        }
        let refused = matches!(code, abort::READ_ONLY | 0x0601_0000 | abort::DEVICE_STATE);
        match step.what {
            What::Cob {
                a,
                tx,
                valid: false,
            }
            | What::Count0 { a, tx }
            | What::Entry { a, tx }
            | What::Count { a, tx }
                if refused
                    || (code == abort::NOT_MAPPABLE
                        && matches!(step.what, What::Count0 { .. })) =>
            {
                // The drive keeps its own mapping: read it, and use it if it
                // carries what the master needs.
                let q = &mut self.sdo[i].queue;
                q.retain(|s| s.what.pdo() != Some((a, tx)));
                let rb = self.readback.entry((a, tx)).or_default();
                rb.refused = Some(code);
                let invalidated = rb.invalidated;
                let k = self.nodes[a].drive.pdo();
                let (comm, map) = if tx {
                    (0x1800 + k, 0x1A00 + k)
                } else {
                    (0x1400 + k, 0x1600 + k)
                };
                let mut fallback = vec![Step::read(map, 0, What::ReadCount { a, tx })];
                if !invalidated {
                    fallback.push(Step::read(comm, 1, What::ReadCob { a, tx }));
                }
                fallback.push(Step::read(comm, 2, What::ReadTt { a, tx }));
                fallback.push(Step::local(What::Verify {
                    a,
                    tx,
                    fallback: true,
                }));
                if invalidated {
                    let cob = if tx {
                        self.nodes[a].tpdo.cob_id
                    } else {
                        self.nodes[a].rpdo.cob_id
                    };
                    fallback.push(Step::write(
                        comm,
                        1,
                        cob.to_le_bytes().to_vec(),
                        What::Cob { a, tx, valid: true },
                    ));
                }
                for s in fallback.into_iter().rev() {
                    q.push_front(s);
                }
                tracing::info!(
                    "replay: node {node} refused to have {} mapped (0x{code:08X} {name}); reading its own mapping",
                    self.pdo_name(a, tx)
                );
                None
            }
            What::Entry { a, tx } => {
                let e = Mapped::from_raw(u32::from_le_bytes(
                    step.write
                        .as_deref()
                        .and_then(|d| d.try_into().ok())
                        .unwrap_or([0; 4]),
                ));
                Some((StopKind::Refused, format!(
                    "{} ({file}) cannot map {e} into {}: abort 0x{code:08X} ({name}); the replay needs it there, so no drive is enabled",
                    self.nodes[a].drive,
                    self.pdo_name(a, tx)
                )))
            }
            What::Tt { a, tx } if refused => {
                let k = self.nodes[a].drive.pdo();
                let comm = if tx { 0x1800 + k } else { 0x1400 + k };
                // Use the drive's transmission type if it is synchronous.
                let pos = self.sdo[i]
                    .queue
                    .iter()
                    .position(|s| matches!(s.what, What::Verify { a: b, tx: t2, .. } if b == a && t2 == tx))
                    .unwrap_or(0);
                self.sdo[i]
                    .queue
                    .insert(pos, Step::read(comm, 2, What::ReadTt { a, tx }));
                None
            }
            _ => Some((
                StopKind::Sdo,
                format!(
                "node {node} aborted SDO {verb} 0x{:04X}:{:02X}: abort code 0x{code:08X} ({name})",
                step.index, step.sub
            ),
            )),
        }
    }

    /// A start-up step that sends nothing: a PDO read back, or the limits.
    fn local_step(&mut self, i: usize, what: What) -> Option<(StopKind, String)> {
        let node = self.sdo[i].node;
        let file = self.file_of(node);
        match what {
            What::Verify { a, tx, fallback } => {
                let rb = self.readback.remove(&(a, tx)).unwrap_or_default();
                let pdo = self.pdo_name(a, tx);
                let drive = self.nodes[a].drive;
                let o = drive.offset();
                let want = if tx {
                    self.nodes[a].tpdo.clone()
                } else {
                    self.nodes[a].rpdo.clone()
                };
                let list = |m: &[Mapped]| {
                    m.iter()
                        .map(|e| e.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                };
                if !fallback {
                    if rb.count != Some(want.entries.len() as u8) || rb.entries != want.entries {
                        return Some((StopKind::Refused, format!(
                            "{drive}: {pdo} mapping read back as [{}] after [{}] was written; not enabled",
                            list(&rb.entries),
                            list(&want.entries)
                        )));
                    }
                    if let Some(tt) = rb.tt.filter(|&tt| tt != want.transmission) {
                        let ok = if tx { tt == SYNC_EVERY } else { tt <= 240 };
                        if !ok {
                            return Some((StopKind::Refused, format!(
                                "{drive}: {pdo} transmission type is {tt} and cannot be written; the replay needs synchronous ({})",
                                if tx { "1, every SYNC" } else { "0–240" }
                            )));
                        }
                        let n = &mut self.nodes[a];
                        if tx {
                            n.tpdo.transmission = tt
                        } else {
                            n.rpdo.transmission = tt
                        }
                    }
                    return None;
                }
                let code = rb.refused.unwrap_or(abort::READ_ONLY);
                let why = format!("abort 0x{code:08X} {}", abort_name(code));
                let needed: Vec<u16> = if tx {
                    vec![0x6041 + o, 0x6064 + o]
                } else {
                    vec![0x6040 + o, 0x607A + o]
                };
                let own = list(&rb.entries);
                for n in &needed {
                    if !rb.entries.iter().any(|e| e.index == *n && e.sub == 0) {
                        return Some((StopKind::Refused, format!(
                            "{drive} ({file}) refuses to have {pdo} mapped ({why}) and its own mapping [{own}] lacks 0x{n:04X} {}: no drive is enabled",
                            object_name(*n).unwrap_or_default().replace('_', " ")
                        )));
                    }
                }
                if !tx {
                    // Every byte of an RPDO is a command: only what the master
                    // can fill with a meaning is accepted.
                    if let Some(e) = rb.entries.iter().find(|e| {
                        !(e.is_dummy()
                            || e.sub == 0
                                && [0x6040 + o, 0x607A + o, 0x6060 + o].contains(&e.index))
                    }) {
                        return Some((StopKind::Refused, format!(
                            "{drive} ({file}) refuses to have {pdo} mapped ({why}) and its own mapping [{own}] also carries {e}, which the replay has no value for: no drive is enabled"
                        )));
                    }
                }
                let bits: u32 = rb.entries.iter().map(|e| e.bits as u32).sum();
                if bits > 64 {
                    return Some((StopKind::Refused, format!(
                        "{drive} ({file}): its own {pdo} mapping [{own}] is {bits} bits, more than a CAN frame's 64: no drive is enabled"
                    )));
                }
                let cob = rb.cob.unwrap_or(if tx {
                    drive.tpdo_cob()
                } else {
                    drive.rpdo_cob()
                });
                if cob & COB_INVALID != 0 {
                    return Some((StopKind::Refused, format!(
                        "{drive} ({file}): {pdo} is not valid (COB-ID 0x{cob:08X}) and cannot be configured ({why}): no drive is enabled"
                    )));
                }
                let tt = rb.tt.unwrap_or(SYNC_EVERY);
                if (tx && tt != SYNC_EVERY) || (!tx && tt > 240) {
                    return Some((StopKind::Refused, format!(
                        "{drive} ({file}): {pdo} transmission type is {tt}, the replay needs synchronous ({}), and the drive refuses writes ({why})",
                        if tx { "1, every SYNC" } else { "0–240" }
                    )));
                }
                let m = PdoMap {
                    cob_id: cob,
                    transmission: tt,
                    entries: rb.entries.clone(),
                };
                self.out.warnings.push(format!(
                    "{drive}: {pdo} mapping is read-only ({why}); using the drive's own: [{own}] on COB-ID 0x{:03X}",
                    m.id()
                ));
                let n = &mut self.nodes[a];
                if tx {
                    n.tpdo = m;
                    n.tpdo_source = MapSource::DriveOwn;
                } else {
                    n.rpdo = m;
                    n.rpdo_source = MapSource::DriveOwn;
                }
                None
            }
            What::CheckLimits { a } => {
                let axis = AXIS_NAMES[a];
                let n = &self.nodes[a];
                let cpm = self.cfg.counts_per_mm;
                let need = self.needs.map(|n| n[a]);
                let l = n.limits;
                if let (Some(min), Some(max)) = (l.min, l.max) {
                    if min == 0 && max == 0 {
                        self.out.warnings.push(format!(
                            "axis {axis} ({}): software position limits 0x607D are 0 and 0 (off): only the envelope guards the travel",
                            n.drive
                        ));
                    } else if let Some(need) = need.filter(|need| need.min <= need.max) {
                        if need.min < min as i64 || need.max > max as i64 {
                            return Some((StopKind::Refused, format!(
                                "axis {axis} ({}): the path spans {}..{} counts ({:.4}..{:.4} mm) but the drive's software position limits 0x607D are {min}..{max} counts ({:.4}..{:.4} mm): it would stop on its own limit, so it is not enabled",
                                n.drive, need.min, need.max, need.min as f64 / cpm, need.max as f64 / cpm, min as f64 / cpm, max as f64 / cpm
                            )));
                        }
                    }
                }
                if let Some(v) = l.max_vel {
                    let v = v as f64;
                    if let Some(need) = need {
                        if v < need.peak_speed {
                            return Some((StopKind::Refused, format!(
                                "axis {axis} ({}): the path needs {:.0} counts/s ({:.3} mm/s) but the drive's max profile velocity 0x607F is {v:.0} counts/s ({:.3} mm/s): it could not follow, so it is not enabled",
                                n.drive, need.peak_speed, need.peak_speed / cpm, v / cpm
                            )));
                        }
                    }
                    if v > self.max_speed_envelope {
                        self.out.warnings.push(format!(
                            "axis {axis} ({}): the drive allows {:.3} mm/s (0x607F), more than the envelope's {:.3} mm/s (--max-step-mm per cycle); the envelope is what limits the replay",
                            n.drive, v / cpm, self.max_speed_envelope / cpm
                        ));
                    }
                }
                None
            }
            _ => None,
        }
    }

    fn check_timeouts(&mut self, t: u64) -> Option<(StopKind, String)> {
        for s in &mut self.sdo {
            if let Some((step, _, sent)) = &s.pending {
                if t > sent + self.cfg.sdo_timeout_us {
                    // The client gives up: an abort 0x05040000 tells the drive
                    // (sent with the quick stop's first cycle by the caller).
                    let why = format!(
                        "node {} did not answer SDO 0x{:04X}:{:02X} within {} ms: abort 0x{:08X} ({})",
                        s.node,
                        step.index,
                        step.sub,
                        self.cfg.sdo_timeout_us as f64 * 1e-3,
                        abort::TIMEOUT,
                        abort_name(abort::TIMEOUT)
                    );
                    self.timed_out.push((s.node, step.index, step.sub));
                    s.pending = None;
                    return Some((StopKind::Sdo, why));
                }
            }
        }
        for a in 0..3 {
            let node = self.cfg.nodes[a];
            let n = &self.nodes[a];
            if let Some(last) = n.last_heartbeat_us {
                if t > last + self.cfg.heartbeat_timeout_us {
                    return Some((
                        StopKind::Heartbeat,
                        format!(
                            "heartbeat of node {node} (axis {}) lost: last at t = {:.6} s, timeout {} ms",
                            ["x", "y", "z"][a],
                            last as f64 * 1e-6,
                            self.cfg.heartbeat_timeout_us as f64 * 1e-3
                        ),
                    ));
                }
            }
            let enabled =
                DriveState::from_statusword(n.status.unwrap_or(0)) == DriveState::OperationEnabled;
            if self.phase == Phase::Enable
                && !enabled
                && self.cycle - n.state_since_cycle > self.cfg.transition_timeout_cycles as u64
            {
                let state = DriveState::from_statusword(n.status.unwrap_or(0));
                return Some((
                    StopKind::Refused,
                    format!(
                        "node {node} (axis {}) refused the transition from {state:?} towards Operation enabled (statusword 0x{:04X}, {} cycles)",
                        ["x", "y", "z"][a],
                        n.status.unwrap_or(0),
                        self.cfg.transition_timeout_cycles
                    ),
                ));
            }
        }
        None
    }
}

/// The interpolation period 0x60C2 for a cycle: value × 10^index s, the
/// value an UNSIGNED8, the coarsest exact index (4 ms = 4 × 10⁻³ s).
pub fn interpolation_period(cycle_us: u64) -> (u8, i8) {
    let mut v = cycle_us;
    let mut exp = -6i8;
    while v.is_multiple_of(10) && exp < -3 {
        v /= 10;
        exp += 1;
    }
    while v > 255 && exp < 0 {
        // Not exact in a byte: round to the next coarser unit.
        v = (v + 5) / 10;
        exp += 1;
    }
    (v.min(255) as u8, exp)
}
