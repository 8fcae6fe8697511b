//! The replay's CANopen master: brings the drives up (NMT, SDO
//! configuration, CiA 402 enable), streams the plan's setpoints in cyclic
//! synchronous position mode on SYNC, watches heartbeats, EMCY and the
//! envelope, and stops (quick stop, NMT stop) on any fault.

use super::protocol::*;
use crate::replay::bus::{CanBus, CanFrame, Dir};
use crate::replay::envelope::{Envelope, Violation};
use crate::replay::source::Plan;
use anyhow::{bail, Result};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};

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
