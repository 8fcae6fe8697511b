//! sparkout-can: `sparkout replay` — stream a run's (compensated) commanded path to the
//! drives over CANopen / CiA 402, inside a safety envelope, and record what
//! the drives did as a new run (docs/design.md §9).
//!
//! Pieces: [`bus`] (the `CanBus` trait), backends [`sim`], [`log_bus`] and
//! `socketcan_bus` (Linux, feature `socketcan`), the master in [`canopen`],
//! the limits in [`envelope`], the path in [`source`], the record in [`record`].

// `!(x <= limit)` is deliberate throughout: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

// The ground floor, by the module names the replay uses (`crate::contracts`…).
pub(crate) use sparkout_core::contracts;

pub mod bus;
pub mod canopen;
pub mod compare;
pub mod decode;
pub mod eds;
pub mod envelope;
pub mod error;
pub mod log_bus;
pub mod record;
pub mod sim;
#[cfg(all(target_os = "linux", feature = "socketcan"))]
pub mod socketcan_bus;
pub mod source;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

pub use bus::{CanBus, CanFrame, Dir};
pub use canopen::{MasterConfig, Outcome, StopKind};
pub use envelope::Envelope;
pub use error::{Error, Result};
pub use sim::{SimBus, SimConfig, SimFault};
pub use source::Plan;

/// Which bus to drive.
#[derive(Debug, Clone, PartialEq)]
pub enum BusSpec {
    Sim,
    Log(PathBuf),
    SocketCan(String),
}

impl BusSpec {
    pub fn parse(s: &str) -> Result<BusSpec> {
        if s == "sim" {
            return Ok(BusSpec::Sim);
        }
        if let Some(f) = s.strip_prefix("log:") {
            if f.is_empty() {
                return Err(Error::bad_option(
                    "--bus",
                    s,
                    "--bus log:FILE needs a file name".into(),
                ));
            }
            return Ok(BusSpec::Log(PathBuf::from(f)));
        }
        if let Some(i) = s.strip_prefix("socketcan:") {
            if i.is_empty() {
                return Err(Error::bad_option(
                    "--bus",
                    s,
                    "--bus socketcan:IFACE needs an interface name, e.g. socketcan:can0".into(),
                ));
            }
            return Ok(BusSpec::SocketCan(i.to_string()));
        }
        Err(Error::bad_option(
            "--bus",
            s,
            format!("--bus `{s}`: use sim, log:FILE or socketcan:IFACE"),
        ))
    }
}

/// Everything a replay needs; checked by [`ReplayOptions::validate`] before
/// any file is read or any frame sent.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    pub run_dir: PathBuf,
    pub compensation: Option<PathBuf>,
    pub bus: BusSpec,
    pub cycle_ms: f64,
    pub dry_run: bool,
    pub envelope: Envelope,
    pub record: Option<PathBuf>,
    /// Drive increments per mm (the DBC's factor 0.0001 mm assumes 10000).
    pub counts_per_mm: f64,
    pub nodes: [u8; 3],
    pub heartbeat_ms: u16,
    /// Heartbeat consumer timeout, in producer periods.
    pub heartbeat_timeout_periods: f64,
    /// Simulated drives: position-loop time constant and speed limit.
    pub sim_lag_s: f64,
    pub sim_max_speed_mm_s: f64,
    pub sim_faults: Vec<SimFault>,
    /// Keep every frame in the outcome (tests; the dry-run printout).
    pub keep_traffic: bool,
    /// Check the whole plan against the envelope before anything is sent.
    pub preflight: bool,
    /// Which axis of its node each machine axis is (1, or 2 for a
    /// two-axis drive's objects at +0x800).
    pub drive_axes: [u8; 3],
    /// The EDS/DCF of a node (`--eds NODE=FILE`, `[replay] eds`).
    pub eds: std::collections::BTreeMap<u8, PathBuf>,
    /// `--bus log:FILE` may replace an existing file.
    pub force: bool,
}

impl ReplayOptions {
    pub fn new(run_dir: &Path, bus: BusSpec) -> ReplayOptions {
        ReplayOptions {
            run_dir: run_dir.to_path_buf(),
            compensation: None,
            bus,
            cycle_ms: 4.0,
            dry_run: false,
            envelope: Envelope {
                max_comp_mm: 0.5,
                max_step_mm: 1.0,
                max_step_change_mm: 0.5,
                max_following_mm: 0.5,
            },
            record: None,
            counts_per_mm: 10_000.0,
            nodes: [1, 2, 3],
            heartbeat_ms: 20,
            heartbeat_timeout_periods: 3.0,
            sim_lag_s: 0.002,
            sim_max_speed_mm_s: 500.0,
            sim_faults: Vec::new(),
            keep_traffic: false,
            preflight: true,
            drive_axes: [1, 1, 1],
            eds: Default::default(),
            force: false,
        }
    }

    pub fn cycle_us(&self) -> u64 {
        (self.cycle_ms * 1000.0).round() as u64
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.cycle_ms.is_finite() && self.cycle_ms >= 1.0) {
            return Err(Error::bad_option(
                "--cycle-ms",
                self.cycle_ms,
                format!(
                    "--cycle-ms {}: the cycle must be at least 1 ms (CANopen drives sync at 1–10 ms; default 4)",
                    self.cycle_ms
                ),
            ));
        }
        self.envelope.validate()?;
        if !(self.counts_per_mm.is_finite() && self.counts_per_mm > 0.0) {
            return Err(Error::bad_option(
                "--counts-per-mm",
                self.counts_per_mm,
                format!("--counts-per-mm {} must be > 0", self.counts_per_mm),
            ));
        }
        let n = self.nodes;
        let same = |a: usize, b: usize| n[a] == n[b] && self.drive_axes[a] == self.drive_axes[b];
        if n.iter().any(|&x| !(1..=127).contains(&x)) || same(0, 1) || same(1, 2) || same(0, 2) {
            return Err(Error::bad_option(
                "--nodes",
                format!("{},{},{}", n[0], n[1], n[2]),
                format!("--nodes {n:?} (drive axes {:?}): three distinct drive axes, node ids 1–127 (x, y, z)", self.drive_axes),
            ));
        }
        if self.drive_axes.iter().any(|a| !(1..=4).contains(a)) {
            return Err(Error::bad_option(
                "--axis",
                format!("{:?}", self.drive_axes),
                format!("--axis: a drive axis is 1–4, found {:?}", self.drive_axes),
            ));
        }
        for node in self.eds.keys() {
            if !n.contains(node) {
                return Err(Error::bad_option(
                    "--eds",
                    node,
                    format!(
                        "--eds {node}=…: node {node} drives no axis (nodes {},{},{})",
                        n[0], n[1], n[2]
                    ),
                ));
            }
        }
        let descriptions = self.descriptions()?;
        for (node, axis) in n.iter().zip(self.drive_axes) {
            if let Some(d) = descriptions.get(node) {
                canopen::pdo::check_description(d, canopen::AxisRef::new(*node, axis))?;
            }
        }
        if self.heartbeat_ms == 0 || !(self.heartbeat_timeout_periods >= 1.0) {
            return Err(Error::bad_option(
                "--heartbeat-ms",
                self.heartbeat_ms,
                "heartbeat period must be > 0 ms and its timeout ≥ 1 period".into(),
            ));
        }
        if !(self.sim_lag_s >= 0.0 && self.sim_max_speed_mm_s > 0.0) {
            return Err(Error::bad_option(
                "--sim-lag-s",
                format!(
                    "{} (--sim-max-speed-mm-s {})",
                    self.sim_lag_s, self.sim_max_speed_mm_s
                ),
                "--sim-lag-s must be ≥ 0 and --sim-max-speed-mm-s > 0".into(),
            ));
        }
        if self.dry_run && self.record.is_some() {
            return Err(Error::bad_option(
                "--record",
                self.record.as_deref().unwrap_or(Path::new("")).display(),
                "--dry-run drives no real axis, so there is nothing to --record; drop one of them"
                    .into(),
            ));
        }
        if let Some(r) = &self.record {
            if r.join("run.toml").exists() {
                return Err(Error::bad_option(
                    "--record",
                    r.display(),
                    format!(
                        "--record {}: already holds a run (run.toml); choose a new directory",
                        r.display()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// A `--sim-fault` that could never fire is an error, not a replay that
    /// silently ends well: its node must be one of `--nodes`, its time
    /// within the streamed path (the virtual clock also counts the start-up
    /// before streaming, so a time inside the path always fires).
    pub fn validate_faults(&self, plan: &Plan) -> Result<()> {
        let streamed_us = plan.cmd_mm.len() as u64 * self.cycle_us();
        for f in &self.sim_faults {
            if let Some(node) = f.node() {
                if !self.nodes.contains(&node) {
                    return Err(Error::bad_option(
                        "--sim-fault",
                        format!("{f:?}"),
                        format!(
                            "--sim-fault {f:?}: node {node} is not one of the drives (--nodes {},{},{})",
                            self.nodes[0], self.nodes[1], self.nodes[2]
                        ),
                    ));
                }
            }
            if let Some(at) = f.at_us() {
                if at >= streamed_us {
                    return Err(Error::bad_option(
                        "--sim-fault",
                        format!("{f:?}"),
                        format!(
                            "--sim-fault {f:?}: at {} s, after the end of the path ({} cycles of {} ms = {} s); it would never fire",
                            at as f64 * 1e-6,
                            plan.cmd_mm.len(),
                            self.cycle_ms,
                            streamed_us as f64 * 1e-6
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Each `--eds` file read for its node (errors name file and line).
    pub fn descriptions(&self) -> Result<std::collections::BTreeMap<u8, eds::DeviceDescription>> {
        let mut out = std::collections::BTreeMap::new();
        for (node, path) in &self.eds {
            out.insert(*node, eds::DeviceDescription::load(path, *node)?);
        }
        Ok(out)
    }

    fn master_config(&self) -> Result<MasterConfig> {
        Ok(MasterConfig {
            cycle_us: self.cycle_us(),
            nodes: self.nodes,
            drive_axes: self.drive_axes,
            descriptions: self.descriptions()?,
            counts_per_mm: self.counts_per_mm,
            heartbeat_ms: self.heartbeat_ms,
            heartbeat_timeout_us: (self.heartbeat_ms as f64
                * 1000.0
                * self.heartbeat_timeout_periods)
                .round() as u64,
            sdo_timeout_us: 100_000,
            transition_timeout_cycles: 25,
            stop_hold_cycles: 3,
            keep_traffic: self.keep_traffic || self.dry_run,
        })
    }

    fn sim_config(&self, plan: &Plan) -> Result<SimConfig> {
        let start = |a: usize| {
            plan.cmd_mm
                .first()
                .map(|c| ((c[a] + plan.comp_mm[0][a]) * self.counts_per_mm).round())
                .filter(|v| v.is_finite() && v.abs() <= i32::MAX as f64)
                .unwrap_or(0.0) as i32
        };
        Ok(SimConfig {
            nodes: self.nodes,
            start_counts: [start(0), start(1), start(2)],
            lag_s: self.sim_lag_s,
            max_speed_mm_s: self.sim_max_speed_mm_s,
            counts_per_mm: self.counts_per_mm,
            quick_stop_decel_mm_s2: 5000.0,
            faults: self.sim_faults.clone(),
            drive_axes: self.drive_axes,
            // The simulated drives are what their files declare.
            profiles: self
                .descriptions()?
                .iter()
                .map(|(n, d)| (*n, sim::SimProfile::from_description(d)))
                .collect(),
        })
    }
}

/// The `[replay]` table of a machine config: which EDS/DCF describes each
/// node and which drive axis each machine axis is, e.g.
///
/// ```toml
/// [replay]
/// eds = { "1" = "drives/xy.eds", "3" = "drives/z.dcf" }   # relative to this file
/// axes = { x = "1", y = "1:2", z = "3" }                  # NODE or NODE:AXIS
/// ```
///
/// Every file is read and checked here (a missing file or object is an
/// error naming the config, the key and the file); flags win over it.
pub fn apply_machine_replay(
    opts: &mut ReplayOptions,
    m: &crate::contracts::MachineConfig,
) -> Result<()> {
    let Some(t) = m.table.get("replay") else {
        return Ok(());
    };
    let src = &m.source;
    let Some(t) = t.as_table() else {
        return Err(machine(
            src,
            "replay",
            format!("{src}: [replay] must be a table"),
        ));
    };
    let base = Path::new(src)
        .parent()
        .filter(|p| !src.starts_with("built-in") && !p.as_os_str().is_empty())
        .map(Path::to_path_buf)
        .unwrap_or_default();
    for (key, v) in t {
        match key.as_str() {
            "eds" => {
                let Some(map) = v.as_table() else {
                    return Err(machine(src, "replay.eds", format!("{src}: replay.eds must be a table of node = \"file\", e.g. eds = {{ \"1\" = \"drive.eds\" }}")));
                };
                for (node, file) in map {
                    let n: u8 = node
                        .parse()
                        .ok()
                        .filter(|n| (1..=127).contains(n))
                        .ok_or_else(|| {
                            machine(
                                src,
                                format!("replay.eds.\"{node}\""),
                                format!("{src}: replay.eds key `{node}` is not a node id 1–127"),
                            )
                        })?;
                    let Some(f) = file.as_str() else {
                        return Err(machine(
                            src,
                            format!("replay.eds.\"{node}\""),
                            format!("{src}: replay.eds.\"{node}\" must be a file name (a string)"),
                        ));
                    };
                    let path = base.join(f);
                    if !path.is_file() {
                        return Err(machine(
                            src,
                            format!("replay.eds.\"{node}\""),
                            format!(
                                "{src}: replay.eds.\"{node}\" = \"{f}\": no file {}",
                                path.display()
                            ),
                        ));
                    }
                    opts.eds.insert(n, path);
                }
            }
            "axes" => {
                let Some(map) = v.as_table() else {
                    return Err(machine(src, "replay.axes", format!("{src}: replay.axes must be a table like axes = {{ x = \"1\", y = \"1:2\" }}")));
                };
                for (axis, spec) in map {
                    let a = ["x", "y", "z"]
                        .iter()
                        .position(|n| n.eq_ignore_ascii_case(axis))
                        .ok_or_else(|| {
                            machine(
                                src,
                                format!("replay.axes.{axis}"),
                                format!("{src}: replay.axes key `{axis}` is not x, y or z"),
                            )
                        })?;
                    let text = match spec {
                        toml::Value::String(s) => s.clone(),
                        toml::Value::Integer(i) => i.to_string(),
                        other => {
                            return Err(machine(
                                src,
                                format!("replay.axes.{axis}"),
                                format!("{src}: replay.axes.{axis} = {other}: use \"NODE\" or \"NODE:AXIS\""),
                            ))
                        }
                    };
                    let r = canopen::AxisRef::parse(&text).map_err(|e| {
                        machine(
                            src,
                            format!("replay.axes.{axis}"),
                            format!("{src}: replay.axes.{axis} {e}"),
                        )
                    })?;
                    opts.nodes[a] = r.node;
                    opts.drive_axes[a] = r.axis;
                }
            }
            other => {
                return Err(machine(
                    src,
                    format!("replay.{other}"),
                    format!(
                        "{src}: unknown key replay.{other} (a machine's [replay] has: eds, axes)"
                    ),
                ))
            }
        }
    }
    Ok(())
}

/// A bad key of a machine config's `[replay]`.
fn machine(file: &str, key: impl Into<String>, message: String) -> Error {
    Error::MachineConfig {
        file: file.to_string(),
        key: key.into(),
        message,
    }
}

/// What happened, for the CLI (printed and as JSON).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ReplayReport {
    pub bus: String,
    pub dry_run: bool,
    pub cycle_ms: f64,
    pub cycles_planned: usize,
    pub cycles_streamed: usize,
    pub sync_frames: u64,
    pub frames_tx: u64,
    pub frames_rx: u64,
    pub reached_operation_enabled: bool,
    pub completed: bool,
    pub stop_kind: Option<StopKind>,
    pub reason: Option<String>,
    pub detected_s: Option<f64>,
    pub quick_stop_s: Option<f64>,
    pub max_following_mm: f64,
    /// What the start-up found worth saying (a drive's own mapping used,
    /// optional objects missing, limits wider than the envelope).
    pub warnings: Vec<String>,
    /// The PDOs each axis was driven through, and where they came from.
    pub pdos: Vec<canopen::AxisPdos>,
    /// 0x1008 of each node that has one.
    pub device_names: std::collections::BTreeMap<u8, String>,
    pub envelope: Envelope,
    pub log: Option<PathBuf>,
    pub recorded: Option<PathBuf>,
    pub recorded_rows: usize,
}

/// Load, check and resample the source; check the plan against the envelope.
pub fn prepare(opts: &ReplayOptions) -> Result<(crate::contracts::RunSpec, Plan)> {
    opts.validate()?;
    let (spec, plan) = source::load_plan(
        &opts.run_dir,
        opts.compensation.as_deref(),
        opts.cycle_us() as f64 * 1e-6,
    )?;
    opts.validate_faults(&plan)?;
    if opts.preflight {
        preflight(&plan, &opts.envelope, opts.counts_per_mm, opts.cycle_us())?;
    }
    Ok((spec, plan))
}

/// Every setpoint of the plan checked against the envelope before the first
/// frame: a path that would be stopped half-way is refused up front.
pub fn preflight(plan: &Plan, env: &Envelope, cpm: f64, cycle_us: u64) -> Result<()> {
    let mut prev: Option<[i32; 3]> = None;
    let mut prev_step = [0i32; 3];
    for (k, (c, d)) in plan.cmd_mm.iter().zip(&plan.comp_mm).enumerate() {
        let p = prev.unwrap_or_else(|| {
            // The first setpoint is checked against itself (the sim and a
            // positioned machine stand there); the master re-checks it
            // against the drives' actual position.
            let mut s = [0i32; 3];
            for a in 0..3 {
                s[a] = ((c[a] + d[a]) * cpm)
                    .round()
                    .clamp(i32::MIN as f64, i32::MAX as f64) as i32;
            }
            s
        });
        match env.check(c, d, &p, &prev_step, cpm) {
            Ok(t) => {
                for a in 0..3 {
                    prev_step[a] = t[a] - p[a];
                }
                prev = Some(t);
            }
            Err(v) => {
                return Err(Error::EnvelopeRefused {
                    setpoint: k,
                    t_s: plan.t0_s + k as f64 * cycle_us as f64 * 1e-6,
                    why: v.0,
                })
            }
        }
    }
    Ok(())
}

/// Run a prepared replay on the chosen bus. `interrupt` is the SIGINT flag.
pub fn run(
    opts: &ReplayOptions,
    spec: &crate::contracts::RunSpec,
    plan: &Plan,
    interrupt: Arc<AtomicBool>,
) -> Result<(ReplayReport, Outcome)> {
    let master = canopen::Master::new(opts.master_config()?)?;
    let sim_cfg = opts.sim_config(plan)?;
    let sim = || SimBus::new(sim_cfg.clone()).with_interrupt(interrupt.clone());
    let mut log_path = None;
    let mut bus: Box<dyn CanBus> = match (&opts.bus, opts.dry_run) {
        (BusSpec::Log(p), _) => {
            log_path = Some(p.clone());
            Box::new(log_bus::LogBus::create(sim(), p, opts.force)?)
        }
        // A dry run opens no hardware: simulated drives answer in its place.
        (BusSpec::Sim, _) | (BusSpec::SocketCan(_), true) => Box::new(sim()),
        #[cfg(all(target_os = "linux", feature = "socketcan"))]
        (BusSpec::SocketCan(iface), false) => Box::new(socketcan_bus::SocketCanBus::open(iface)?),
        #[cfg(not(all(target_os = "linux", feature = "socketcan")))]
        (BusSpec::SocketCan(_), false) => return Err(Error::NoSocketCan),
    };
    let describe = if opts.dry_run {
        format!(
            "dry run ({} not opened; simulated drives answer)",
            match &opts.bus {
                BusSpec::Sim => "sim".to_string(),
                BusSpec::Log(p) => format!("log:{}", p.display()),
                BusSpec::SocketCan(i) => format!("socketcan:{i}"),
            }
        )
    } else {
        bus.describe()
    };
    tracing::info!(
        "replay: {} setpoints every {} ms on {describe}",
        plan.cmd_mm.len(),
        opts.cycle_ms
    );
    let outcome = master.run(bus.as_mut(), plan, &opts.envelope, &interrupt)?;
    let completed = outcome.stop.is_none() && outcome.cycles_streamed == plan.cmd_mm.len();
    let outcome_text = match &outcome.stop {
        None => "completed".to_string(),
        Some((_, why)) => format!("quick stop: {why}"),
    };
    let mut recorded = None;
    let mut recorded_rows = 0;
    if let Some(out) = &opts.record {
        let info = record::RecordInfo {
            bus: describe.clone(),
            cycle_s: opts.cycle_us() as f64 * 1e-6,
            counts_per_mm: opts.counts_per_mm,
            compensation: opts.compensation.clone(),
            outcome: outcome_text.clone(),
        };
        match record::write_recorded_run(out, spec, plan, &outcome, &info) {
            Ok(rows) => {
                recorded = Some(out.clone());
                recorded_rows = rows;
            }
            Err(e) if outcome.stop.is_some() => {
                tracing::warn!("replay: no record written: {e:#}");
            }
            Err(e) => return Err(e),
        }
    }
    let report = ReplayReport {
        bus: describe,
        dry_run: opts.dry_run,
        cycle_ms: opts.cycle_us() as f64 * 1e-3,
        cycles_planned: plan.cmd_mm.len(),
        cycles_streamed: outcome.cycles_streamed,
        sync_frames: outcome.sync_frames,
        frames_tx: outcome.frames_tx,
        frames_rx: outcome.frames_rx,
        reached_operation_enabled: outcome.reached_operation_enabled,
        completed,
        stop_kind: outcome.stop.as_ref().map(|s| s.0),
        reason: outcome.stop.as_ref().map(|s| s.1.clone()),
        detected_s: outcome.detected_us.map(|t| t as f64 * 1e-6),
        quick_stop_s: outcome.quick_stop_us.map(|t| t as f64 * 1e-6),
        max_following_mm: outcome.max_following_mm,
        warnings: outcome.warnings.clone(),
        pdos: outcome.pdos.clone(),
        device_names: outcome.device_names.clone(),
        envelope: opts.envelope,
        log: log_path,
        recorded,
        recorded_rows,
    };
    Ok((report, outcome))
}

#[cfg(test)]
mod error_tests;
#[cfg(test)]
mod pdo_tests;
#[cfg(test)]
mod tests;
