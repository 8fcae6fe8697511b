//! The `sim` backend: in-process CiA 402 drives, one per axis, on a virtual
//! clock. Each drive has an NMT state, a heartbeat producer (0x1017), an
//! expedited SDO server for the objects the master uses, the CiA 402 state
//! machine driven by the controlword, and in cyclic synchronous position
//! mode follows the target latched at each SYNC with a first-order lag and
//! a speed limit (a servo loop's closed-loop response), answering with a
//! synchronous TPDO. Faults can be injected at given times.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::error::{Error, Result};

use super::bus::{CanBus, CanFrame, CAN_ERR_BUSOFF};
use super::canopen::pdo::{self, split_axis, Mapped, PdoMap, COB_INVALID};
use super::canopen::{self, abort, nmt, obj, AxisRef, DriveState, SdoServer, ServerAction};
use super::eds::DeviceDescription;

/// A fault to inject (times in µs on the virtual clock).
#[derive(Debug, Clone, PartialEq)]
pub enum SimFault {
    /// The drive stops producing heartbeats.
    HeartbeatStops { node: u8, at_us: u64 },
    /// The drive sends an EMCY and goes to Fault.
    Emcy { node: u8, at_us: u64, code: u16 },
    /// The controller reports bus-off (an error frame).
    BusOff { at_us: u64 },
    /// The encoder slips: the actual position jumps by `mm` (a following error).
    FollowingError { node: u8, at_us: u64, mm: f64 },
    /// The drive refuses Switched on → Operation enabled.
    RefuseEnable { node: u8 },
    /// The operator presses Ctrl-C (sets the interrupt flag).
    Interrupt { at_us: u64 },
}

impl SimFault {
    /// The drive it targets, if any.
    pub fn node(&self) -> Option<u8> {
        match self {
            SimFault::HeartbeatStops { node, .. }
            | SimFault::Emcy { node, .. }
            | SimFault::FollowingError { node, .. }
            | SimFault::RefuseEnable { node } => Some(*node),
            SimFault::BusOff { .. } | SimFault::Interrupt { .. } => None,
        }
    }
    /// When it fires (µs on the virtual clock), if timed.
    pub fn at_us(&self) -> Option<u64> {
        match self {
            SimFault::HeartbeatStops { at_us, .. }
            | SimFault::Emcy { at_us, .. }
            | SimFault::BusOff { at_us }
            | SimFault::FollowingError { at_us, .. }
            | SimFault::Interrupt { at_us } => Some(*at_us),
            SimFault::RefuseEnable { .. } => None,
        }
    }
    /// Parse `KIND[@TIME][:NODE]`, e.g. `heartbeat@1.5s:2`, `emcy@0.8s`,
    /// `busoff@1s`, `following@0.5s:1`, `refuse:3`, `sigint@2s`. TIME takes
    /// `s` or `ms`; NODE defaults to the first axis' node.
    pub fn parse(spec: &str, default_node: u8) -> Result<SimFault> {
        let bad = |message: String| Error::bad_option("--sim-fault", spec, message);
        let (head, node) = match spec.rsplit_once(':') {
            Some((h, n)) => (
                h,
                n.parse::<u8>().map_err(|_| {
                    bad(format!(
                        "--sim-fault `{spec}`: node `{n}` is not a number 1–127"
                    ))
                })?,
            ),
            None => (spec, default_node),
        };
        let (kind, at) = match head.split_once('@') {
            Some((k, t)) => (k, Some(t)),
            None => (head, None),
        };
        let at_us = match at {
            None => None,
            Some(t) => {
                let (num, scale) = if let Some(v) = t.strip_suffix("ms") {
                    (v, 1e3)
                } else if let Some(v) = t.strip_suffix('s') {
                    (v, 1e6)
                } else {
                    (t, 1e6)
                };
                let v: f64 = num.parse().map_err(|_| {
                    bad(format!(
                        "--sim-fault `{spec}`: time `{t}` is not like 1.5s or 200ms"
                    ))
                })?;
                if !(v.is_finite() && v >= 0.0) {
                    return Err(bad(format!("--sim-fault `{spec}`: time must be ≥ 0")));
                }
                Some((v * scale).round() as u64)
            }
        };
        let need_at = || {
            at_us.ok_or_else(|| {
                bad(format!(
                    "--sim-fault `{spec}`: needs a time, e.g. {kind}@1.5s"
                ))
            })
        };
        Ok(match kind {
            "heartbeat" => SimFault::HeartbeatStops { node, at_us: need_at()? },
            "emcy" => SimFault::Emcy { node, at_us: need_at()?, code: 0x2310 },
            "busoff" | "bus-off" => SimFault::BusOff { at_us: need_at()? },
            "following" => SimFault::FollowingError { node, at_us: need_at()?, mm: 1.0 },
            "refuse" => SimFault::RefuseEnable { node },
            "sigint" => SimFault::Interrupt { at_us: need_at()? },
            other => {
                return Err(bad(format!(
                "--sim-fault `{spec}`: unknown fault `{other}` (heartbeat, emcy, busoff, following, refuse, sigint)"
            )))
            }
        })
    }
}

/// Simulated drive parameters.
#[derive(Debug, Clone)]
pub struct SimConfig {
    pub nodes: [u8; 3],
    /// Start positions (counts), where the axes stand when the replay begins.
    pub start_counts: [i32; 3],
    /// Closed-loop time constant of the position loop (s).
    pub lag_s: f64,
    /// Speed limit (mm/s) and the scale to turn it into counts.
    pub max_speed_mm_s: f64,
    pub counts_per_mm: f64,
    /// Quick-stop deceleration (mm/s²; 0x6085).
    pub quick_stop_decel_mm_s2: f64,
    pub faults: Vec<SimFault>,
    /// Which axis of its node each machine axis is (1, or 2 for the
    /// objects at +0x800 of a two-axis drive).
    pub drive_axes: [u8; 3],
    /// The object dictionary of each node; a node without one is the
    /// shipped profile ([`SimProfile::standard`]).
    pub profiles: std::collections::BTreeMap<u8, SimProfile>,
}

/// What a simulated drive's object dictionary holds beyond the CiA 402
/// basics: its default PDO mappings (per drive axis), whether they can be
/// written, the vendor quirks the master must cope with.
#[derive(Debug, Clone, PartialEq)]
pub struct SimProfile {
    /// Default RPDOk / TPDOk (index k − 1) after power-on.
    pub rpdo: Vec<PdoMap>,
    pub tpdo: Vec<PdoMap>,
    /// 0x1600… / 0x1A00… refuse writes (abort 0x06010002).
    pub read_only_mapping: bool,
    /// Objects (first-axis index) that abort 0x06040041 when mapped.
    pub unmappable: Vec<u16>,
    /// 16, or 32 for drives that declare 0x6041 UNSIGNED32.
    pub statusword_bits: u8,
    /// 0x1008 (read by segmented SDO when longer than 4 bytes).
    pub device_name: Option<String>,
    /// 0x607D sub 1 / 2, counts.
    pub position_limits: Option<(i32, i32)>,
    /// 0x607F, counts/s.
    pub max_profile_velocity: Option<u32>,
    /// Has 0x60C2.
    pub interpolation_period: bool,
}

impl SimProfile {
    /// The shipped profile: RPDOk = controlword + target position, TPDOk =
    /// statusword + position actual value, synchronous, writable.
    pub fn standard(node: u8) -> SimProfile {
        let d = DeviceDescription::parse("shipped", canopen::DRIVE_EDS, node)
            .expect("the shipped EDS parses");
        SimProfile::from_description(&d)
    }

    /// A drive as its EDS/DCF declares it: default mappings, read-only
    /// mapping parameters (AccessType ro/const on sub 0), the statusword's
    /// width, objects with PDOMapping=0, name, limits.
    pub fn from_description(d: &DeviceDescription) -> SimProfile {
        let find = |i: u16, s: u8| d.entries.iter().find(|e| e.index == i && e.sub == s);
        let node = d.node;
        let mut rpdo = Vec::new();
        let mut tpdo = Vec::new();
        for k in 1..=4u16 {
            let a = AxisRef::new(node, k as u8);
            let empty = |cob| PdoMap {
                cob_id: cob,
                transmission: pdo::SYNC_EVERY,
                entries: Vec::new(),
            };
            rpdo.push(pdo::described_map(d, false, k).unwrap_or_else(|| empty(a.rpdo_cob())));
            tpdo.push(pdo::described_map(d, true, k).unwrap_or_else(|| empty(a.tpdo_cob())));
        }
        let ro = |e: Option<&crate::eds::Entry>| {
            e.is_some_and(|e| e.access == "ro" || e.access == "const")
        };
        SimProfile {
            rpdo,
            tpdo,
            read_only_mapping: ro(find(0x1600, 0)) || ro(find(0x1A00, 0)),
            unmappable: d
                .entries
                .iter()
                .filter(|e| (0x6000..0x6800).contains(&e.index) && e.sub == 0 && !e.pdo_mapping)
                .map(|e| e.index)
                .collect(),
            statusword_bits: pdo::declared_bits(d, 0x6041, 16),
            device_name: find(0x1008, 0).and_then(|e| e.value_text.clone()),
            position_limits: match (find(0x607D, 1), find(0x607D, 2)) {
                (Some(a), Some(b)) => Some((
                    a.value.unwrap_or(i32::MIN as i128) as i32,
                    b.value.unwrap_or(i32::MAX as i128) as i32,
                )),
                _ => None,
            },
            max_profile_velocity: find(0x607F, 0).and_then(|e| e.value).map(|v| v as u32),
            interpolation_period: find(0x60C2, 1).is_some(),
        }
    }
}

/// One PDO's parameters in a simulated drive (CiA 301 rules: the mapping
/// changes only while the PDO is invalid and its count 0).
#[derive(Debug, Clone)]
struct SimPdo {
    cob: u32,
    tt: u8,
    count: u8,
    slots: [u32; 8],
}

impl SimPdo {
    fn from_map(m: &PdoMap) -> SimPdo {
        let mut slots = [0u32; 8];
        for (i, e) in m.entries.iter().take(8).enumerate() {
            slots[i] = e.raw();
        }
        SimPdo {
            cob: m.cob_id,
            tt: m.transmission,
            count: m.entries.len().min(8) as u8,
            slots,
        }
    }
    fn map(&self) -> PdoMap {
        PdoMap {
            cob_id: self.cob,
            transmission: self.tt,
            entries: self.slots[..self.count as usize]
                .iter()
                .map(|&r| Mapped::from_raw(r))
                .collect(),
        }
    }
}

#[derive(Debug, Clone)]
struct Drive {
    node: u8,
    /// Axis of its node (1 = objects at 0x6000).
    axis: u8,
    /// Produces the node's heartbeat (the node's first axis).
    hb_producer: bool,
    rpdo: SimPdo,
    tpdo: SimPdo,
    profile: SimProfile,
    interp: (u8, i8),
    nmt: u8,
    state: DriveState,
    mode: i8,
    hb_period_us: u64,
    next_hb_us: u64,
    hb_dead: bool,
    refuse_enable: bool,
    pending_target: i32,
    target: f64,
    pos: f64,
    vel: f64,
    slip: f64,
}

/// The simulated bus with its drives.
pub struct SimBus {
    cfg: SimConfig,
    now: u64,
    drives: Vec<Drive>,
    rx: VecDeque<CanFrame>,
    fired: Vec<bool>,
    cycle_us: u64,
    last_sync_us: Option<u64>,
    interrupt: Option<Arc<AtomicBool>>,
    servers: std::collections::BTreeMap<u8, SdoServer>,
    /// Every object written over SDO: (node, index, sub, bytes), in order.
    pub writes: Vec<(u8, u16, u8, Vec<u8>)>,
}

/// Reply latency of a drive (µs): the frame after the one that caused it.
const REPLY_US: u64 = 100;

impl SimBus {
    pub fn new(cfg: SimConfig) -> SimBus {
        let drives = (0..3)
            .map(|a| {
                let node = cfg.nodes[a];
                let axis = cfg.drive_axes[a].max(1);
                let profile = cfg
                    .profiles
                    .get(&node)
                    .cloned()
                    .unwrap_or_else(|| SimProfile::standard(node));
                let k = (axis - 1) as usize;
                Drive {
                    node,
                    axis,
                    hb_producer: !(0..a).any(|b| cfg.nodes[b] == node),
                    rpdo: SimPdo::from_map(&profile.rpdo[k.min(3)]),
                    tpdo: SimPdo::from_map(&profile.tpdo[k.min(3)]),
                    profile,
                    interp: (1, -3),
                    nmt: nmt::HB_PRE_OPERATIONAL,
                    state: DriveState::SwitchOnDisabled,
                    mode: 0,
                    hb_period_us: 0,
                    next_hb_us: 0,
                    hb_dead: false,
                    refuse_enable: cfg.faults.iter().any(
                        |f| matches!(f, SimFault::RefuseEnable { node } if *node == cfg.nodes[a]),
                    ),
                    pending_target: cfg.start_counts[a],
                    target: cfg.start_counts[a] as f64,
                    pos: cfg.start_counts[a] as f64,
                    vel: 0.0,
                    slip: 0.0,
                }
            })
            .collect();
        let fired = vec![false; cfg.faults.len()];
        SimBus {
            cfg,
            now: 0,
            drives,
            rx: VecDeque::new(),
            fired,
            cycle_us: 0,
            last_sync_us: None,
            interrupt: None,
            servers: Default::default(),
            writes: Vec::new(),
        }
    }

    /// The flag a `sigint@T` fault sets (the same one SIGINT sets).
    pub fn with_interrupt(mut self, flag: Arc<AtomicBool>) -> SimBus {
        self.interrupt = Some(flag);
        self
    }

    fn push(&mut self, t_us: u64, mut f: CanFrame) {
        f.t_us = t_us;
        // Keep the queue in time order (replies may be scheduled out of order).
        let i = self.rx.partition_point(|g| g.t_us <= t_us);
        self.rx.insert(i, f);
    }

    fn on_sync(&mut self, t: u64) {
        let dt_s = match self.last_sync_us {
            Some(prev) if t > prev => (t - prev) as f64 * 1e-6,
            _ => 0.0,
        };
        self.last_sync_us = Some(t);
        if self.cycle_us == 0 && dt_s > 0.0 {
            self.cycle_us = (dt_s * 1e6) as u64;
        }
        let cpm = self.cfg.counts_per_mm;
        let alpha = if self.cfg.lag_s > 0.0 {
            1.0 - (-dt_s / self.cfg.lag_s).exp()
        } else {
            1.0
        };
        let vmax = self.cfg.max_speed_mm_s * cpm * dt_s;
        let dmax = self.cfg.quick_stop_decel_mm_s2 * cpm * dt_s * dt_s;
        let mut replies = Vec::new();
        for (i, d) in self.drives.iter_mut().enumerate() {
            if d.nmt != nmt::HB_OPERATIONAL {
                continue;
            }
            match d.state {
                DriveState::OperationEnabled if d.mode == obj::MODE_CSP as i8 => {
                    d.target = d.pending_target as f64;
                    let step = ((d.target - d.pos) * alpha).clamp(-vmax, vmax);
                    d.pos += step;
                    d.vel = step;
                }
                DriveState::QuickStopActive => {
                    // Ramp the speed down on the quick-stop deceleration.
                    let v = if d.vel.abs() <= dmax {
                        0.0
                    } else {
                        d.vel - dmax * d.vel.signum()
                    };
                    d.pos += v;
                    d.vel = v;
                }
                _ => d.vel = 0.0,
            }
            let sw = d.state.statusword();
            let actual = (d.pos + d.slip).round() as i32;
            let m = d.tpdo.map();
            if m.cob_id & COB_INVALID != 0 || m.entries.is_empty() {
                continue;
            }
            let (mode, vel) = (d.mode, d.vel.round() as i64);
            let payload = m.encode(|index, _| match split_axis(index).1 {
                0x6041 => sw as i64,
                0x6064 => actual as i64,
                0x6061 => mode as i64,
                0x606C => vel,
                _ => 0,
            });
            replies.push((
                t + 2 * REPLY_US + 50 * i as u64,
                CanFrame::new(0, m.cob_id & 0x7FF, &payload),
            ));
        }
        for (t, f) in replies {
            self.push(t, f);
        }
    }

    fn on_controlword(d: &mut Drive, word: u16) {
        use DriveState::*;
        let cmd = word & 0x8F;
        d.state = match (d.state, cmd) {
            (Fault, w) if w & 0x80 != 0 => SwitchOnDisabled,
            (Fault, _) | (FaultReactionActive, _) => d.state,
            (_, w) if w & 0x02 == 0 => SwitchOnDisabled, // disable voltage
            (SwitchOnDisabled, 0x06) => ReadyToSwitchOn,
            (ReadyToSwitchOn | SwitchedOn | OperationEnabled, 0x06) => ReadyToSwitchOn,
            (ReadyToSwitchOn, 0x07) | (OperationEnabled, 0x07) => SwitchedOn,
            (SwitchedOn | ReadyToSwitchOn, 0x0F) => {
                if d.refuse_enable {
                    SwitchedOn
                } else {
                    OperationEnabled
                }
            }
            (OperationEnabled, w) if w & 0x04 == 0 => QuickStopActive,
            (QuickStopActive, w) if w & 0x04 == 0 => QuickStopActive,
            (ReadyToSwitchOn | SwitchedOn, w) if w & 0x04 == 0 => SwitchOnDisabled,
            (s, _) => s,
        };
    }

    /// The drive that answers for `index` on `node`: PDO parameters and
    /// CiA 402 objects by their axis, everything else by the node's first axis.
    fn drive_for(&self, node: u8, index: u16) -> Option<usize> {
        let axis = match index {
            0x1400..=0x1403 | 0x1600..=0x1603 | 0x1800..=0x1803 | 0x1A00..=0x1A03 => {
                (index & 0xFF) as u8 + 1
            }
            0x6000..=0x9FFF => split_axis(index).0,
            _ => {
                return self
                    .drives
                    .iter()
                    .position(|d| d.node == node && d.hb_producer)
            }
        };
        self.drives
            .iter()
            .position(|d| d.node == node && d.axis == axis)
    }

    fn sdo_read(&self, a: usize, index: u16, sub: u8) -> std::result::Result<Vec<u8>, u32> {
        let d = &self.drives[a];
        let p = &d.profile;
        let only0 = |v: Vec<u8>| if sub == 0 { Ok(v) } else { Err(abort::NO_SUB) };
        let pdo_comm = |q: &SimPdo| match sub {
            0 => Ok(vec![2]),
            1 => Ok(q.cob.to_le_bytes().to_vec()),
            2 => Ok(vec![q.tt]),
            _ => Err(abort::NO_SUB),
        };
        let pdo_map = |q: &SimPdo| match sub {
            0 => Ok(vec![q.count]),
            1..=8 => Ok(q.slots[sub as usize - 1].to_le_bytes().to_vec()),
            _ => Err(abort::NO_SUB),
        };
        match index {
            0x1000 => only0(0x0002_0192u32.to_le_bytes().to_vec()),
            0x1008 => match &p.device_name {
                Some(n) => only0(n.as_bytes().to_vec()),
                None => Err(abort::NO_OBJECT),
            },
            obj::PRODUCER_HEARTBEAT_TIME => {
                only0(((d.hb_period_us / 1000) as u16).to_le_bytes().to_vec())
            }
            0x1400..=0x1403 => pdo_comm(&d.rpdo),
            0x1800..=0x1803 => pdo_comm(&d.tpdo),
            0x1600..=0x1603 => pdo_map(&d.rpdo),
            0x1A00..=0x1A03 => pdo_map(&d.tpdo),
            _ => match split_axis(index).1 {
                obj::STATUSWORD => {
                    let sw = d.state.statusword() as u32;
                    only0(sw.to_le_bytes()[..p.statusword_bits as usize / 8].to_vec())
                }
                obj::MODES_OF_OPERATION | obj::MODES_OF_OPERATION_DISPLAY => {
                    only0(vec![d.mode as u8])
                }
                obj::POSITION_ACTUAL_VALUE => {
                    only0(((d.pos + d.slip).round() as i32).to_le_bytes().to_vec())
                }
                obj::TARGET_POSITION => only0(d.pending_target.to_le_bytes().to_vec()),
                0x607D => match (p.position_limits, sub) {
                    (None, _) => Err(abort::NO_OBJECT),
                    (Some(_), 0) => Ok(vec![2]),
                    (Some((lo, _)), 1) => Ok(lo.to_le_bytes().to_vec()),
                    (Some((_, hi)), 2) => Ok(hi.to_le_bytes().to_vec()),
                    _ => Err(abort::NO_SUB),
                },
                0x607F => match p.max_profile_velocity {
                    Some(v) => only0(v.to_le_bytes().to_vec()),
                    None => Err(abort::NO_OBJECT),
                },
                0x60C2 if p.interpolation_period => match sub {
                    0 => Ok(vec![2]),
                    1 => Ok(vec![d.interp.0]),
                    2 => Ok(vec![d.interp.1 as u8]),
                    _ => Err(abort::NO_SUB),
                },
                _ => Err(abort::NO_OBJECT),
            },
        }
    }

    /// Whether `m` may be mapped into an RPDO (`rx`) or TPDO of drive `a`.
    fn mappable(&self, a: usize, m: Mapped, rx: bool) -> std::result::Result<(), u32> {
        let d = &self.drives[a];
        if m.index == 0 && m.raw() == 0 {
            return Ok(());
        }
        if m.is_dummy() {
            return Ok(());
        }
        let (axis, base) = split_axis(m.index);
        let width = match base {
            obj::CONTROLWORD => 16,
            obj::STATUSWORD => d.profile.statusword_bits,
            obj::MODES_OF_OPERATION | obj::MODES_OF_OPERATION_DISPLAY => 8,
            obj::POSITION_ACTUAL_VALUE | obj::TARGET_POSITION | 0x606C => 32,
            _ => return Err(abort::NOT_MAPPABLE),
        };
        let writable = matches!(
            base,
            obj::CONTROLWORD | obj::TARGET_POSITION | obj::MODES_OF_OPERATION
        );
        if axis != d.axis || m.sub != 0 || rx != writable || d.profile.unmappable.contains(&base) {
            return Err(abort::NOT_MAPPABLE);
        }
        if m.bits != width {
            return Err(abort::LENGTH);
        }
        Ok(())
    }

    fn sdo_write(
        &mut self,
        a: usize,
        index: u16,
        sub: u8,
        data: &[u8],
        t: u64,
    ) -> std::result::Result<(), u32> {
        let le = |n: usize| -> std::result::Result<u64, u32> {
            if data.len() != n {
                return Err(abort::LENGTH);
            }
            let mut b = [0u8; 8];
            b[..n].copy_from_slice(data);
            Ok(u64::from_le_bytes(b))
        };
        match index {
            obj::PRODUCER_HEARTBEAT_TIME if sub == 0 => {
                let d = &mut self.drives[a];
                d.hb_period_us = le(2)? * 1000;
                d.next_hb_us = t + d.hb_period_us;
                Ok(())
            }
            0x1400..=0x1403 | 0x1800..=0x1803 => {
                let tx = index >= 0x1800;
                let d = &mut self.drives[a];
                let q = if tx { &mut d.tpdo } else { &mut d.rpdo };
                match sub {
                    1 => {
                        let v = le(4)? as u32;
                        // CiA 301: the id of a valid PDO is not changed.
                        if q.cob & COB_INVALID == 0 && v & COB_INVALID == 0 && v != q.cob {
                            return Err(0x0609_0030);
                        }
                        q.cob = v;
                        Ok(())
                    }
                    2 => {
                        q.tt = le(1)? as u8;
                        Ok(())
                    }
                    0 => Err(abort::READ_ONLY),
                    _ => Err(abort::NO_SUB),
                }
            }
            0x1600..=0x1603 | 0x1A00..=0x1A03 => {
                let tx = index >= 0x1A00;
                if self.drives[a].profile.read_only_mapping {
                    return Err(abort::READ_ONLY);
                }
                let q = if tx {
                    &self.drives[a].tpdo
                } else {
                    &self.drives[a].rpdo
                };
                if q.cob & COB_INVALID == 0 {
                    return Err(abort::DEVICE_STATE);
                }
                match sub {
                    0 => {
                        let n = le(1)? as u8;
                        if n > 8 {
                            return Err(0x0609_0031);
                        }
                        let slots = q.slots;
                        let mut bits = 0u32;
                        for &r in &slots[..n as usize] {
                            self.mappable(a, Mapped::from_raw(r), !tx)?;
                            bits += r & 0xFF;
                        }
                        if bits > 64 {
                            return Err(abort::PDO_LENGTH);
                        }
                        let d = &mut self.drives[a];
                        let q = if tx { &mut d.tpdo } else { &mut d.rpdo };
                        q.count = n;
                        Ok(())
                    }
                    1..=8 => {
                        if q.count != 0 {
                            return Err(abort::DEVICE_STATE);
                        }
                        let v = le(4)? as u32;
                        self.mappable(a, Mapped::from_raw(v), !tx)?;
                        let d = &mut self.drives[a];
                        let q = if tx { &mut d.tpdo } else { &mut d.rpdo };
                        q.slots[sub as usize - 1] = v;
                        Ok(())
                    }
                    _ => Err(abort::NO_SUB),
                }
            }
            0x1000 | 0x1008 | 0x1018 => Err(abort::READ_ONLY),
            _ => {
                let d = &mut self.drives[a];
                match (split_axis(index).1, sub) {
                    (obj::MODES_OF_OPERATION, 0) => {
                        d.mode = le(1)? as u8 as i8;
                        Ok(())
                    }
                    (obj::CONTROLWORD, 0) => {
                        Self::on_controlword(d, le(2)? as u16);
                        Ok(())
                    }
                    (obj::TARGET_POSITION, 0) => {
                        d.pending_target = le(4)? as u32 as i32;
                        Ok(())
                    }
                    (0x60C2, 1) if d.profile.interpolation_period => {
                        d.interp.0 = le(1)? as u8;
                        Ok(())
                    }
                    (0x60C2, 2) if d.profile.interpolation_period => {
                        d.interp.1 = le(1)? as u8 as i8;
                        Ok(())
                    }
                    (
                        obj::STATUSWORD
                        | obj::MODES_OF_OPERATION_DISPLAY
                        | obj::POSITION_ACTUAL_VALUE,
                        _,
                    ) => Err(abort::READ_ONLY),
                    _ => Err(abort::NO_OBJECT),
                }
            }
        }
    }

    fn on_sdo(&mut self, node: u8, payload: &[u8], t: u64) {
        let mut server = self.servers.remove(&node).unwrap_or_default();
        let reply = match server.on_request(payload) {
            ServerAction::Nothing => None,
            ServerAction::Reply(r) => Some(r),
            ServerAction::Read(index, sub) => {
                let r = match self.drive_for(node, index) {
                    Some(a) => self.sdo_read(a, index, sub),
                    None => Err(abort::NO_OBJECT),
                };
                Some(server.uploaded(index, sub, r))
            }
            ServerAction::Write(index, sub, data) => {
                let r = match self.drive_for(node, index) {
                    Some(a) => self.sdo_write(a, index, sub, &data, t),
                    None => Err(abort::NO_OBJECT),
                };
                if r.is_ok() {
                    self.writes.push((node, index, sub, data));
                }
                Some(server.downloaded(index, sub, r))
            }
        };
        self.servers.insert(node, server);
        if let Some(r) = reply {
            self.push(
                t + REPLY_US,
                CanFrame::new(0, canopen::SDO_TX_BASE + node as u32, &r),
            );
        }
    }

    /// The current mapping of a drive axis' RPDO and TPDO (tests).
    pub fn pdo_maps(&self, node: u8, axis: u8) -> Option<(PdoMap, PdoMap)> {
        self.drives
            .iter()
            .find(|d| d.node == node && d.axis == axis)
            .map(|d| (d.rpdo.map(), d.tpdo.map()))
    }

    /// Time-driven events up to `t`: heartbeats and injected faults, in time order.
    fn advance(&mut self, t: u64) {
        loop {
            // The earliest pending event at or before t.
            let mut next: Option<(u64, usize, bool)> = None; // (time, index, is_fault)
            for (i, d) in self.drives.iter().enumerate() {
                if d.hb_period_us > 0
                    && d.hb_producer
                    && !d.hb_dead
                    && d.next_hb_us <= t
                    && next.is_none_or(|(nt, _, _)| d.next_hb_us < nt)
                {
                    next = Some((d.next_hb_us, i, false));
                }
            }
            for (i, f) in self.cfg.faults.iter().enumerate() {
                let at = match f {
                    SimFault::HeartbeatStops { at_us, .. }
                    | SimFault::Emcy { at_us, .. }
                    | SimFault::BusOff { at_us }
                    | SimFault::FollowingError { at_us, .. }
                    | SimFault::Interrupt { at_us } => *at_us,
                    SimFault::RefuseEnable { .. } => continue,
                };
                if !self.fired[i] && at <= t && next.is_none_or(|(nt, _, _)| at < nt) {
                    next = Some((at, i, true));
                }
            }
            let Some((at, i, is_fault)) = next else { break };
            if !is_fault {
                let d = &mut self.drives[i];
                d.next_hb_us += d.hb_period_us;
                let f = canopen::heartbeat(d.node, d.nmt);
                self.push(at, f);
                continue;
            }
            self.fired[i] = true;
            let idx = |node: u8, drives: &[Drive]| drives.iter().position(|d| d.node == node);
            match self.cfg.faults[i].clone() {
                SimFault::HeartbeatStops { node, .. } => {
                    if let Some(a) = idx(node, &self.drives) {
                        self.drives[a].hb_dead = true;
                    }
                }
                SimFault::Emcy { node, code, .. } => {
                    if let Some(a) = idx(node, &self.drives) {
                        self.drives[a].state = DriveState::Fault;
                        // Error register bit 0: generic error (CiA 301 0x1001).
                        let f = canopen::emcy(node, code, 0x01);
                        self.push(at, f);
                    }
                }
                SimFault::BusOff { .. } => self.push(at, CanFrame::error(at, CAN_ERR_BUSOFF)),
                SimFault::FollowingError { node, mm, .. } => {
                    if let Some(a) = idx(node, &self.drives) {
                        self.drives[a].slip += mm * self.cfg.counts_per_mm;
                    }
                }
                SimFault::Interrupt { .. } => {
                    if let Some(flag) = &self.interrupt {
                        flag.store(true, Ordering::SeqCst);
                    }
                }
                SimFault::RefuseEnable { .. } => {}
            }
        }
    }
}

impl CanBus for SimBus {
    fn describe(&self) -> String {
        "sim".into()
    }
    fn now_us(&self) -> u64 {
        self.now
    }
    fn send(&mut self, frame: CanFrame) -> Result<()> {
        let t = self.now;
        let node_of = |f: &CanFrame| (f.id & 0x7F) as u8;
        match frame.id {
            canopen::NMT_ID => {
                let d = frame.payload();
                if d.len() == 2 {
                    for drv in &mut self.drives {
                        if d[1] == 0 || d[1] == drv.node {
                            drv.nmt = match d[0] {
                                nmt::START => nmt::HB_OPERATIONAL,
                                nmt::STOP => nmt::HB_STOPPED,
                                nmt::PRE_OPERATIONAL => nmt::HB_PRE_OPERATIONAL,
                                _ => drv.nmt,
                            };
                        }
                    }
                }
            }
            canopen::SYNC_ID => self.on_sync(t),
            id if id & 0x780 == canopen::SDO_RX_BASE => {
                let node = node_of(&frame);
                if self
                    .drives
                    .iter()
                    .any(|d| d.node == node && d.nmt != nmt::HB_STOPPED)
                {
                    self.on_sdo(node, frame.payload(), t);
                }
            }
            id => {
                // An RPDO, by the COB-ID each drive's mapping listens on.
                for d in &mut self.drives {
                    let m = d.rpdo.map();
                    if m.cob_id & COB_INVALID != 0 || m.id() != id || m.entries.is_empty() {
                        continue;
                    }
                    let Some(values) = m.decode(frame.payload()) else {
                        continue;
                    };
                    if d.nmt != nmt::HB_OPERATIONAL {
                        continue;
                    }
                    for (e, v) in values {
                        match split_axis(e.index).1 {
                            obj::CONTROLWORD => Self::on_controlword(d, v as u16),
                            obj::TARGET_POSITION => {
                                d.pending_target = pdo::sign_extend(v, e.bits) as i32
                            }
                            obj::MODES_OF_OPERATION => d.mode = v as u8 as i8,
                            _ => {}
                        }
                    }
                }
            }
        }
        Ok(())
    }
    fn recv(&mut self) -> Result<Option<CanFrame>> {
        match self.rx.front() {
            Some(f) if f.t_us <= self.now => Ok(self.rx.pop_front()),
            _ => Ok(None),
        }
    }
    fn wait_until(&mut self, t_us: u64) -> Result<()> {
        if t_us > self.now {
            self.advance(t_us);
            self.now = t_us;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::cw;

    #[test]
    fn fault_specs_parse() {
        assert_eq!(
            SimFault::parse("heartbeat@1.5s:2", 1).unwrap(),
            SimFault::HeartbeatStops {
                node: 2,
                at_us: 1_500_000
            }
        );
        assert_eq!(
            SimFault::parse("busoff@200ms", 1).unwrap(),
            SimFault::BusOff { at_us: 200_000 }
        );
        assert_eq!(
            SimFault::parse("refuse", 3).unwrap(),
            SimFault::RefuseEnable { node: 3 }
        );
        for bad in ["explode@1s", "emcy", "emcy@x", "emcy@1s:z", "emcy@-1s"] {
            assert!(SimFault::parse(bad, 1).is_err(), "{bad}");
        }
    }

    #[test]
    fn drive_state_machine_reaches_operation_enabled_and_quick_stops() {
        let profile = SimProfile::standard(1);
        let mut d = Drive {
            node: 1,
            axis: 1,
            hb_producer: true,
            rpdo: SimPdo::from_map(&profile.rpdo[0]),
            tpdo: SimPdo::from_map(&profile.tpdo[0]),
            profile,
            interp: (1, -3),
            nmt: nmt::HB_OPERATIONAL,
            state: DriveState::SwitchOnDisabled,
            mode: 8,
            hb_period_us: 0,
            next_hb_us: 0,
            hb_dead: false,
            refuse_enable: false,
            pending_target: 0,
            target: 0.0,
            pos: 0.0,
            vel: 0.0,
            slip: 0.0,
        };
        let mut s = d.state;
        for _ in 0..4 {
            let c = s.next_command().unwrap_or(cw::ENABLE_OPERATION);
            SimBus::on_controlword(&mut d, c);
            s = DriveState::from_statusword(d.state.statusword());
        }
        assert_eq!(s, DriveState::OperationEnabled);
        SimBus::on_controlword(&mut d, cw::QUICK_STOP);
        assert_eq!(
            DriveState::from_statusword(d.state.statusword()),
            DriveState::QuickStopActive
        );
    }
}
