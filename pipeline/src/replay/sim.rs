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

use anyhow::{bail, Result};

use super::bus::{CanBus, CanFrame, CAN_ERR_BUSOFF};
use super::canopen::{self, nmt, obj, DriveState, SdoRequest, SdoResponse};

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
        let (head, node) = match spec.rsplit_once(':') {
            Some((h, n)) => (
                h,
                n.parse::<u8>().map_err(|_| {
                    anyhow::anyhow!("--sim-fault `{spec}`: node `{n}` is not a number 1–127")
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
                    anyhow::anyhow!("--sim-fault `{spec}`: time `{t}` is not like 1.5s or 200ms")
                })?;
                if !(v.is_finite() && v >= 0.0) {
                    bail!("--sim-fault `{spec}`: time must be ≥ 0");
                }
                Some((v * scale).round() as u64)
            }
        };
        let need_at = || {
            at_us.ok_or_else(|| {
                anyhow::anyhow!("--sim-fault `{spec}`: needs a time, e.g. {kind}@1.5s")
            })
        };
        Ok(match kind {
            "heartbeat" => SimFault::HeartbeatStops { node, at_us: need_at()? },
            "emcy" => SimFault::Emcy { node, at_us: need_at()?, code: 0x2310 },
            "busoff" | "bus-off" => SimFault::BusOff { at_us: need_at()? },
            "following" => SimFault::FollowingError { node, at_us: need_at()?, mm: 1.0 },
            "refuse" => SimFault::RefuseEnable { node },
            "sigint" => SimFault::Interrupt { at_us: need_at()? },
            other => bail!(
                "--sim-fault `{spec}`: unknown fault `{other}` (heartbeat, emcy, busoff, following, refuse, sigint)"
            ),
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
}

#[derive(Debug, Clone)]
struct Drive {
    node: u8,
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
}

/// Reply latency of a drive (µs): the frame after the one that caused it.
const REPLY_US: u64 = 100;

impl SimBus {
    pub fn new(cfg: SimConfig) -> SimBus {
        let drives = (0..3)
            .map(|a| Drive {
                node: cfg.nodes[a],
                nmt: nmt::HB_PRE_OPERATIONAL,
                state: DriveState::SwitchOnDisabled,
                mode: 0,
                hb_period_us: 0,
                next_hb_us: 0,
                hb_dead: false,
                refuse_enable: cfg
                    .faults
                    .iter()
                    .any(|f| matches!(f, SimFault::RefuseEnable { node } if *node == cfg.nodes[a])),
                pending_target: cfg.start_counts[a],
                target: cfg.start_counts[a] as f64,
                pos: cfg.start_counts[a] as f64,
                vel: 0.0,
                slip: 0.0,
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
            replies.push((
                t + 2 * REPLY_US + 50 * i as u64,
                canopen::tpdo1(d.node, sw, actual),
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

    fn on_sdo(&mut self, a: usize, req: SdoRequest, t: u64) {
        let d = &mut self.drives[a];
        let resp = match req {
            SdoRequest::Download { index, sub, data } => match (index, sub) {
                (obj::PRODUCER_HEARTBEAT_TIME, 0) if data.len() == 2 => {
                    let ms = u16::from_le_bytes([data[0], data[1]]) as u64;
                    d.hb_period_us = ms * 1000;
                    d.next_hb_us = t + d.hb_period_us;
                    SdoResponse::Downloaded { index, sub }
                }
                (obj::MODES_OF_OPERATION, 0) if data.len() == 1 => {
                    d.mode = data[0] as i8;
                    SdoResponse::Downloaded { index, sub }
                }
                (obj::CONTROLWORD, 0) if data.len() == 2 => {
                    Self::on_controlword(d, u16::from_le_bytes([data[0], data[1]]));
                    SdoResponse::Downloaded { index, sub }
                }
                // 0x06090011: sub-index does not exist / 0x06020000: object does not exist.
                _ => SdoResponse::Abort {
                    index,
                    sub,
                    code: 0x0602_0000,
                },
            },
            SdoRequest::Upload { index, sub } => {
                let (value, len) = match index {
                    obj::STATUSWORD => (d.state.statusword() as u32, 2),
                    obj::MODES_OF_OPERATION_DISPLAY => (d.mode as u8 as u32, 1),
                    obj::POSITION_ACTUAL_VALUE => ((d.pos + d.slip).round() as i32 as u32, 4),
                    obj::PRODUCER_HEARTBEAT_TIME => ((d.hb_period_us / 1000) as u32, 2),
                    _ => (0, 0),
                };
                if len == 0 {
                    SdoResponse::Abort {
                        index,
                        sub,
                        code: 0x0602_0000,
                    }
                } else {
                    SdoResponse::Uploaded {
                        index,
                        sub,
                        value,
                        len,
                    }
                }
            }
        };
        let f = resp.frame(d.node);
        self.push(t + REPLY_US, f);
    }

    /// Time-driven events up to `t`: heartbeats and injected faults, in time order.
    fn advance(&mut self, t: u64) {
        loop {
            // The earliest pending event at or before t.
            let mut next: Option<(u64, usize, bool)> = None; // (time, index, is_fault)
            for (i, d) in self.drives.iter().enumerate() {
                if d.hb_period_us > 0
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
            id if id & 0x780 == canopen::RPDO1_BASE => {
                if let (Some(a), Some((word, target))) = (
                    self.drives.iter().position(|d| d.node == node_of(&frame)),
                    canopen::decode_pdo(&frame),
                ) {
                    let d = &mut self.drives[a];
                    if d.nmt == nmt::HB_OPERATIONAL {
                        Self::on_controlword(d, word);
                        d.pending_target = target;
                    }
                }
            }
            id if id & 0x780 == canopen::SDO_RX_BASE => {
                if let (Some(a), Some(req)) = (
                    self.drives.iter().position(|d| d.node == node_of(&frame)),
                    SdoRequest::parse(&frame),
                ) {
                    if self.drives[a].nmt != nmt::HB_STOPPED {
                        self.on_sdo(a, req, t);
                    }
                }
            }
            _ => {}
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
    use crate::replay::canopen::cw;

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
        let mut d = Drive {
            node: 1,
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
