//! CANopen for the replay: CiA 301 (NMT, SYNC producer, heartbeat consumer,
//! EMCY consumer, expedited SDO client) and CiA 402 (drive state machine,
//! cyclic synchronous position mode 8, RPDO target 0x607A, TPDO statusword
//! 0x6041 + actual position 0x6064). The object dictionary and PDO mappings
//! are the shipped EDS (configs/can/cia402_drive.eds), checked here against
//! what the code encodes; configs/can/cia402_pdo.dbc describes the same
//! frames for cantools.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{bail, Result};

use super::bus::{CanBus, CanFrame, Dir};
use super::envelope::{Envelope, Violation};
use super::source::Plan;

pub const NMT_ID: u32 = 0x000;
pub const SYNC_ID: u32 = 0x080;
pub const EMCY_BASE: u32 = 0x080;
pub const TPDO1_BASE: u32 = 0x180;
pub const RPDO1_BASE: u32 = 0x200;
/// SDO server → client (responses).
pub const SDO_TX_BASE: u32 = 0x580;
/// SDO client → server (requests).
pub const SDO_RX_BASE: u32 = 0x600;
pub const HEARTBEAT_BASE: u32 = 0x700;

/// CiA 301 NMT commands (byte 0 of the NMT frame).
pub mod nmt {
    pub const START: u8 = 0x01;
    pub const STOP: u8 = 0x02;
    pub const PRE_OPERATIONAL: u8 = 0x80;
    pub const RESET_NODE: u8 = 0x81;
    pub const RESET_COMMUNICATION: u8 = 0x82;
    /// Heartbeat states (the heartbeat's single byte).
    pub const HB_BOOTUP: u8 = 0x00;
    pub const HB_STOPPED: u8 = 0x04;
    pub const HB_OPERATIONAL: u8 = 0x05;
    pub const HB_PRE_OPERATIONAL: u8 = 0x7F;
}

/// CiA 402 controlword commands (0x6040).
pub mod cw {
    pub const DISABLE_VOLTAGE: u16 = 0x0000;
    pub const QUICK_STOP: u16 = 0x0002;
    pub const SHUTDOWN: u16 = 0x0006;
    pub const SWITCH_ON: u16 = 0x0007;
    pub const DISABLE_OPERATION: u16 = 0x0007;
    pub const ENABLE_OPERATION: u16 = 0x000F;
    pub const FAULT_RESET: u16 = 0x0080;
}

/// Objects used (CiA 301 / CiA 402).
pub mod obj {
    pub const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
    pub const CONTROLWORD: u16 = 0x6040;
    pub const STATUSWORD: u16 = 0x6041;
    pub const MODES_OF_OPERATION: u16 = 0x6060;
    pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
    pub const POSITION_ACTUAL_VALUE: u16 = 0x6064;
    pub const TARGET_POSITION: u16 = 0x607A;
    /// Cyclic synchronous position mode (0x6060 value).
    pub const MODE_CSP: u8 = 8;
}

/// Statusword bit 13 in CSP: following error detected by the drive.
pub const SW_FOLLOWING_ERROR: u16 = 1 << 13;

/// CiA 402 drive states, decoded from the statusword per CiA 402 table 30.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriveState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

impl DriveState {
    pub fn from_statusword(sw: u16) -> DriveState {
        use DriveState::*;
        match (sw & 0x4F, sw & 0x6F) {
            (0x00, _) => NotReadyToSwitchOn,
            (0x40, _) => SwitchOnDisabled,
            (_, 0x21) => ReadyToSwitchOn,
            (_, 0x23) => SwitchedOn,
            (_, 0x27) => OperationEnabled,
            (_, 0x07) => QuickStopActive,
            (0x0F, _) => FaultReactionActive,
            (0x08, _) => Fault,
            _ => NotReadyToSwitchOn,
        }
    }
    /// The statusword bits a drive in this state reports (bit 9 remote set).
    pub fn statusword(self) -> u16 {
        use DriveState::*;
        0x0200
            | match self {
                NotReadyToSwitchOn => 0x00,
                SwitchOnDisabled => 0x40,
                ReadyToSwitchOn => 0x21,
                SwitchedOn => 0x23,
                OperationEnabled => 0x27,
                QuickStopActive => 0x07,
                FaultReactionActive => 0x0F,
                Fault => 0x08,
            }
    }
    /// The controlword that moves a drive one step towards Operation enabled.
    pub fn next_command(self) -> Option<u16> {
        use DriveState::*;
        match self {
            Fault => Some(cw::FAULT_RESET),
            SwitchOnDisabled => Some(cw::SHUTDOWN),
            ReadyToSwitchOn => Some(cw::SWITCH_ON),
            SwitchedOn => Some(cw::ENABLE_OPERATION),
            OperationEnabled => None,
            // Wait (the drive is booting or reacting to a fault).
            NotReadyToSwitchOn | FaultReactionActive => Some(cw::DISABLE_VOLTAGE),
            QuickStopActive => Some(cw::DISABLE_VOLTAGE),
        }
    }
}

/// RPDO1: controlword (0x6040, u16) + target position (0x607A, i32), little endian.
pub fn rpdo1(node: u8, controlword: u16, target: i32) -> CanFrame {
    let mut d = [0u8; 6];
    d[..2].copy_from_slice(&controlword.to_le_bytes());
    d[2..].copy_from_slice(&target.to_le_bytes());
    CanFrame::new(0, RPDO1_BASE + node as u32, &d)
}
/// TPDO1: statusword (0x6041, u16) + position actual value (0x6064, i32).
pub fn tpdo1(node: u8, statusword: u16, actual: i32) -> CanFrame {
    let mut d = [0u8; 6];
    d[..2].copy_from_slice(&statusword.to_le_bytes());
    d[2..].copy_from_slice(&actual.to_le_bytes());
    CanFrame::new(0, TPDO1_BASE + node as u32, &d)
}
/// (word, position) of a 6-byte PDO of the layout above.
pub fn decode_pdo(f: &CanFrame) -> Option<(u16, i32)> {
    let d = f.payload();
    (d.len() == 6).then(|| {
        (
            u16::from_le_bytes([d[0], d[1]]),
            i32::from_le_bytes([d[2], d[3], d[4], d[5]]),
        )
    })
}
pub fn nmt_frame(command: u8, node: u8) -> CanFrame {
    CanFrame::new(0, NMT_ID, &[command, node])
}
pub fn sync_frame() -> CanFrame {
    CanFrame::new(0, SYNC_ID, &[])
}
pub fn heartbeat(node: u8, state: u8) -> CanFrame {
    CanFrame::new(0, HEARTBEAT_BASE + node as u32, &[state])
}
pub fn emcy(node: u8, code: u16, register: u8) -> CanFrame {
    let c = code.to_le_bytes();
    CanFrame::new(
        0,
        EMCY_BASE + node as u32,
        &[c[0], c[1], register, 0, 0, 0, 0, 0],
    )
}

/// An expedited SDO request (CiA 301 §7.2.4.3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoRequest {
    /// Write 1, 2 or 4 bytes.
    Download {
        index: u16,
        sub: u8,
        data: Vec<u8>,
    },
    Upload {
        index: u16,
        sub: u8,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoResponse {
    Downloaded {
        index: u16,
        sub: u8,
    },
    Uploaded {
        index: u16,
        sub: u8,
        value: u32,
        len: u8,
    },
    Abort {
        index: u16,
        sub: u8,
        code: u32,
    },
}

impl SdoRequest {
    pub fn index_sub(&self) -> (u16, u8) {
        match self {
            SdoRequest::Download { index, sub, .. } | SdoRequest::Upload { index, sub } => {
                (*index, *sub)
            }
        }
    }
    pub fn frame(&self, node: u8) -> CanFrame {
        let mut d = [0u8; 8];
        let (index, sub) = self.index_sub();
        d[1..3].copy_from_slice(&index.to_le_bytes());
        d[3] = sub;
        match self {
            SdoRequest::Download { data, .. } => {
                assert!(
                    matches!(data.len(), 1..=4),
                    "expedited SDO carries 1–4 bytes"
                );
                // ccs=1, n = 4 − len, e=1, s=1.
                d[0] = 0x20 | (((4 - data.len()) as u8) << 2) | 0x03;
                d[4..4 + data.len()].copy_from_slice(data);
            }
            SdoRequest::Upload { .. } => d[0] = 0x40,
        }
        CanFrame::new(0, SDO_RX_BASE + node as u32, &d)
    }
    /// Parse a request frame (the server side, used by the simulated drive).
    pub fn parse(f: &CanFrame) -> Option<SdoRequest> {
        let d = f.payload();
        if d.len() != 8 {
            return None;
        }
        let index = u16::from_le_bytes([d[1], d[2]]);
        let sub = d[3];
        match d[0] & 0xE0 {
            0x20 if d[0] & 0x03 == 0x03 => {
                let len = 4 - ((d[0] >> 2) & 0x03) as usize;
                Some(SdoRequest::Download {
                    index,
                    sub,
                    data: d[4..4 + len].to_vec(),
                })
            }
            0x40 => Some(SdoRequest::Upload { index, sub }),
            _ => None,
        }
    }
}

impl SdoResponse {
    pub fn frame(&self, node: u8) -> CanFrame {
        let mut d = [0u8; 8];
        let (index, sub) = match self {
            SdoResponse::Downloaded { index, sub }
            | SdoResponse::Uploaded { index, sub, .. }
            | SdoResponse::Abort { index, sub, .. } => (*index, *sub),
        };
        d[1..3].copy_from_slice(&index.to_le_bytes());
        d[3] = sub;
        match self {
            SdoResponse::Downloaded { .. } => d[0] = 0x60,
            SdoResponse::Uploaded { value, len, .. } => {
                d[0] = 0x40 | ((4 - len) << 2) | 0x03;
                d[4..8].copy_from_slice(&value.to_le_bytes());
            }
            SdoResponse::Abort { code, .. } => {
                d[0] = 0x80;
                d[4..8].copy_from_slice(&code.to_le_bytes());
            }
        }
        CanFrame::new(0, SDO_TX_BASE + node as u32, &d)
    }
    pub fn parse(f: &CanFrame) -> Option<SdoResponse> {
        let d = f.payload();
        if d.len() != 8 {
            return None;
        }
        let index = u16::from_le_bytes([d[1], d[2]]);
        let sub = d[3];
        let word = u32::from_le_bytes([d[4], d[5], d[6], d[7]]);
        match d[0] & 0xE0 {
            0x60 => Some(SdoResponse::Downloaded { index, sub }),
            0x40 if d[0] & 0x03 == 0x03 => {
                let len = 4 - ((d[0] >> 2) & 0x03);
                let mask = if len == 4 {
                    u32::MAX
                } else {
                    (1u32 << (8 * len)) - 1
                };
                Some(SdoResponse::Uploaded {
                    index,
                    sub,
                    value: word & mask,
                    len,
                })
            }
            0x80 => Some(SdoResponse::Abort {
                index,
                sub,
                code: word,
            }),
            _ => None,
        }
    }
}

/// The shipped EDS of the drive profile.
pub const DRIVE_EDS: &str = include_str!("../../../configs/can/cia402_drive.eds");

/// Check that an EDS maps the PDOs exactly as this master encodes them:
/// RPDO1 = 0x6040 (16 bit) + 0x607A (32 bit) on COB-ID $NODEID+0x200,
/// TPDO1 = 0x6041 (16 bit) + 0x6064 (32 bit) on $NODEID+0x180, synchronous.
pub fn check_eds(text: &str) -> Result<()> {
    let mut sections: std::collections::BTreeMap<
        String,
        std::collections::BTreeMap<String, String>,
    > = Default::default();
    let mut cur = String::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            cur = s.to_ascii_lowercase();
            continue;
        }
        if let Some((k, v)) = line.split_once('=') {
            sections
                .entry(cur.clone())
                .or_default()
                .insert(k.trim().to_ascii_lowercase(), v.trim().to_ascii_lowercase());
        }
    }
    let expect = |section: &str, value: &str| -> Result<()> {
        let got = sections
            .get(section)
            .and_then(|s| s.get("defaultvalue"))
            .map(|s| s.as_str());
        if got != Some(value) {
            bail!(
                "EDS [{section}] DefaultValue is {got:?}, the replay master encodes {value}: \
                 fix configs/can/cia402_drive.eds or the master together"
            );
        }
        Ok(())
    };
    expect("1400sub1", "$nodeid+0x200")?;
    expect("1600sub0", "2")?;
    expect("1600sub1", "0x60400010")?;
    expect("1600sub2", "0x607a0020")?;
    expect("1800sub1", "$nodeid+0x180")?;
    expect("1800sub2", "1")?;
    expect("1a00sub0", "2")?;
    expect("1a00sub1", "0x60410010")?;
    expect("1a00sub2", "0x60640020")?;
    for o in ["6040", "6041", "6060", "6061", "6064", "607a", "1017"] {
        if !sections.contains_key(o) {
            bail!("EDS has no object [{o}] (the replay master uses it)");
        }
    }
    Ok(())
}

/// Settings of the master (all times in µs on the bus clock).
#[derive(Debug, Clone)]
pub struct MasterConfig {
    pub cycle_us: u64,
    /// Node id per axis (x, y, z).
    pub nodes: [u8; 3],
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

#[derive(Debug, Default, Clone)]
struct NodeInfo {
    sdo_queue: VecDeque<SdoRequest>,
    sdo_pending: Option<(SdoRequest, u64)>,
    sdo_done: bool,
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
            bail!("cycle of {} µs is shorter than 1 ms", cfg.cycle_us);
        }
        if cfg.stop_hold_cycles < 2 {
            bail!("the quick stop must be held for at least 2 cycles");
        }
        check_eds(DRIVE_EDS)?;
        Ok(Master {
            cfg,
            nodes: Default::default(),
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
            },
        })
    }

    fn node_index(&self, node: u32) -> Option<usize> {
        self.cfg.nodes.iter().position(|&n| n as u32 == node)
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
            bail!(
                "plan: {} setpoints but {} compensation rows",
                plan.cmd_mm.len(),
                plan.comp_mm.len()
            );
        }
        self.following_limit_mm = Some(env.max_following_mm);
        for n in &mut self.nodes {
            n.sdo_queue = VecDeque::from(vec![
                SdoRequest::Download {
                    index: obj::PRODUCER_HEARTBEAT_TIME,
                    sub: 0,
                    data: self.cfg.heartbeat_ms.to_le_bytes().to_vec(),
                },
                SdoRequest::Download {
                    index: obj::MODES_OF_OPERATION,
                    sub: 0,
                    data: vec![obj::MODE_CSP],
                },
                SdoRequest::Upload {
                    index: obj::MODES_OF_OPERATION_DISPLAY,
                    sub: 0,
                },
                SdoRequest::Upload {
                    index: obj::STATUSWORD,
                    sub: 0,
                },
                SdoRequest::Upload {
                    index: obj::POSITION_ACTUAL_VALUE,
                    sub: 0,
                },
            ]);
        }
        loop {
            let t = self.cycle * self.cfg.cycle_us;
            bus.wait_until(t)?;
            let mut fault = self.drain(bus)?;
            if fault.is_none() {
                fault = self.check_timeouts(t);
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
                        let f = rpdo1(self.cfg.nodes[a], cw::DISABLE_OPERATION, self.hold[a]);
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
            let f = rpdo1(self.cfg.nodes[a], cw::QUICK_STOP, self.hold[a]);
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
        for a in 0..3 {
            let node = self.cfg.nodes[a];
            let n = &mut self.nodes[a];
            if n.sdo_pending.is_some() || n.sdo_done {
                continue;
            }
            match n.sdo_queue.pop_front() {
                Some(req) => {
                    let f = req.frame(node);
                    n.sdo_pending = Some((req, t));
                    self.send(bus, f)?;
                }
                None => n.sdo_done = true,
            }
        }
        if self.nodes.iter().all(|n| n.sdo_done) {
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
            let node = self.cfg.nodes[a];
            let state = DriveState::from_statusword(self.nodes[a].status.unwrap_or(0));
            if state != DriveState::OperationEnabled {
                all_enabled = false;
            }
            let cmd = state.next_command().unwrap_or(cw::ENABLE_OPERATION);
            let f = rpdo1(node, cmd, self.hold[a]);
            self.send(bus, f)?;
        }
        if all_enabled {
            self.out.reached_operation_enabled = true;
            tracing::info!("replay: every drive in Operation enabled (CSP)");
            if plan.cmd_mm.is_empty() {
                self.phase = Phase::Finish(0);
                return Ok(());
            }
            // The path must start where the axes are (MODELS.md has no model
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
                    let f = rpdo1(self.cfg.nodes[a], cw::ENABLE_OPERATION, target[a]);
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
            let (base, node) = (f.id & 0x780, f.id & 0x7F);
            let Some(a) = self.node_index(node) else {
                continue;
            };
            match base {
                HEARTBEAT_BASE => {
                    let state = f.payload().first().copied().unwrap_or(0xFF);
                    self.nodes[a].last_heartbeat_us = Some(f.t_us);
                    self.nodes[a].hb_state = Some(state);
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
                    if let Some((sw, pos)) = decode_pdo(&f) {
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
                    let Some(resp) = SdoResponse::parse(&f) else {
                        continue;
                    };
                    let Some((req, _)) = self.nodes[a].sdo_pending.take() else {
                        continue;
                    };
                    let (index, sub) = req.index_sub();
                    match resp {
                        SdoResponse::Abort { code, .. } => note(
                            &mut fault,
                            StopKind::Sdo,
                            format!("node {node} aborted SDO 0x{index:04X}:{sub}: abort code 0x{code:08X}"),
                        ),
                        SdoResponse::Downloaded { .. } => {
                            if index == obj::PRODUCER_HEARTBEAT_TIME {
                                // Heartbeat supervision starts once the drive produces it.
                                self.nodes[a].last_heartbeat_us = Some(f.t_us);
                            }
                        }
                        SdoResponse::Uploaded { value, .. } => match index {
                            obj::MODES_OF_OPERATION_DISPLAY => {
                                self.nodes[a].mode_display = Some(value as u8);
                                if value as u8 != obj::MODE_CSP {
                                    note(&mut fault, StopKind::Refused, format!("node {node} did not take cyclic synchronous position mode (0x6061 = {})", value as i8));
                                }
                            }
                            obj::STATUSWORD => self.nodes[a].status = Some(value as u16),
                            obj::POSITION_ACTUAL_VALUE => self.nodes[a].actual = Some(value as i32),
                            _ => {}
                        },
                    }
                }
                _ => {}
            }
        }
        Ok(fault)
    }

    fn check_timeouts(&mut self, t: u64) -> Option<(StopKind, String)> {
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
            if let Some((req, sent)) = &n.sdo_pending {
                if t > sent + self.cfg.sdo_timeout_us {
                    let (i, s) = req.index_sub();
                    return Some((
                        StopKind::Sdo,
                        format!(
                            "node {node} did not answer SDO 0x{i:04X}:{s} within {} ms",
                            self.cfg.sdo_timeout_us as f64 * 1e-3
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
