//! `sparkout replay`: wiring only — flags → `ReplayOptions`, SIGINT → the
//! master's interrupt flag, the report → stdout. The replay itself lives in
//! sparkout_pipeline::replay.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::{bail, Context};
use sparkout_pipeline::replay::{self, log_bus, BusSpec, Dir, Envelope, ReplayOptions, SimFault};

use crate::cli::ReplayArgs;

/// Frames printed by a dry run without a log file.
const DRY_RUN_PRINT: usize = 24;

pub fn replay(args: &ReplayArgs) -> anyhow::Result<u8> {
    if args.nodes.len() != 3 {
        bail!("--nodes takes three node ids (x, y, z), e.g. --nodes 1,2,3");
    }
    if let Some(log) = &args.compare {
        return compare(args, log);
    }
    let (Some(run), Some(bus)) = (&args.run, &args.bus) else {
        bail!("replay needs --run DIR and --bus BUS (or --compare LOG)");
    };
    let bus = BusSpec::parse(bus)?;
    let nodes = [args.nodes[0], args.nodes[1], args.nodes[2]];
    let mut opts = ReplayOptions::new(run, bus);
    opts.compensation = args.compensation.clone();
    opts.cycle_ms = args.cycle_ms;
    opts.dry_run = args.dry_run;
    opts.envelope = Envelope {
        max_comp_mm: args.max_comp_mm,
        max_step_mm: args.max_step_mm,
        max_step_change_mm: args.max_step_change_mm,
        max_following_mm: args.max_following_mm,
    };
    opts.record = args.record.clone();
    opts.counts_per_mm = args.counts_per_mm;
    opts.nodes = nodes;
    opts.heartbeat_ms = args.heartbeat_ms;
    opts.force = args.force;
    // The machine's [replay] table (EDS files, drive axes), then the flags.
    if let Ok(spec) = sparkout_pipeline::contracts::RunSpec::load(run) {
        match crate::registry::resolver(args.machines.clone()).resolve(&spec) {
            Ok(m) => replay::apply_machine_replay(&mut opts, &m)?,
            Err(e) if args.machines.is_some() => return Err(e.into()),
            // A run whose machine is not found has no [replay] to read;
            // the replay itself needs none.
            Err(_) => {}
        }
    }
    for (node, file) in super::can::eds_flags(&args.eds)? {
        opts.eds.insert(node, file);
    }
    for (a, r) in super::can::axis_flags(&args.axes)? {
        opts.nodes[a] = r.node;
        opts.drive_axes[a] = r.axis;
    }
    opts.sim_lag_s = args.sim_lag_s;
    opts.sim_max_speed_mm_s = args.sim_max_speed_mm_s;
    opts.sim_faults = args
        .sim_faults
        .iter()
        .map(|s| SimFault::parse(s, nodes[0]))
        .collect::<replay::Result<_>>()?;
    if !opts.sim_faults.is_empty() && matches!(opts.bus, BusSpec::SocketCan(_)) && !opts.dry_run {
        bail!("--sim-fault injects faults into simulated drives: use --bus sim or log:FILE (or --dry-run)");
    }

    // Every check before anything is sent (bad input → exit 1, nothing sent).
    let (spec, plan) = replay::prepare(&opts)?;

    // Ctrl-C sets the flag; the master quick-stops every drive at its next cycle.
    let interrupt = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGINT, interrupt.clone())
        .context("cannot install the SIGINT handler")?;

    let (report, outcome) = replay::run(&opts, &spec, &plan, interrupt)?;

    if opts.dry_run && report.log.is_none() {
        let tx: Vec<_> = outcome
            .traffic
            .iter()
            .filter(|(d, _)| *d == Dir::Tx)
            .collect();
        println!(
            "dry run: {} frames would be sent (first {} below; --bus log:FILE keeps all of them)",
            tx.len(),
            DRY_RUN_PRINT.min(tx.len())
        );
        for (_, f) in tx.iter().take(DRY_RUN_PRINT) {
            println!("  {}", log_bus::format_line(f, log_bus::LOG_IFACE));
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "replay on {}: {} of {} setpoints streamed every {} ms ({} SYNC, {} frames sent, {} received); Operation enabled: {}; max following error {:.4} mm",
            report.bus,
            report.cycles_streamed,
            report.cycles_planned,
            report.cycle_ms,
            report.sync_frames,
            report.frames_tx,
            report.frames_rx,
            if report.reached_operation_enabled { "yes" } else { "no" },
            report.max_following_mm
        );
        for p in &report.pdos {
            println!(
                "axis {} = {}: RPDO 0x{:03X} [{}] ({}), TPDO 0x{:03X} [{}] ({})",
                p.axis,
                p.drive,
                p.rpdo.id(),
                p.rpdo
                    .entries
                    .iter()
                    .map(|e| e.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                source(p.rpdo_source),
                p.tpdo.id(),
                p.tpdo
                    .entries
                    .iter()
                    .map(|e| e.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                source(p.tpdo_source),
            );
        }
        for w in &report.warnings {
            println!("warning: {w}");
        }
        if let Some(p) = &report.log {
            println!("candump log: {}", p.display());
        }
        if let Some(p) = &report.recorded {
            println!(
                "recorded run: {} ({} rows)",
                p.display(),
                report.recorded_rows
            );
        }
    }
    match &report.reason {
        None => {
            if !args.json {
                println!("replay completed");
            }
            Ok(super::ALL_GOOD)
        }
        Some(why) => {
            eprintln!(
                "replay ended by a quick stop at t = {:.6} s: {why}",
                report.quick_stop_s.unwrap_or_default()
            );
            Ok(super::SOME_RUNS_FAILED)
        }
    }
}

fn source(s: replay::canopen::MapSource) -> &'static str {
    match s {
        replay::canopen::MapSource::Configured => "configured, read back",
        replay::canopen::MapSource::DriveOwn => "the drive's own, read-only",
    }
}

/// `replay --compare LOG`: the recorded traffic against this command's
/// envelope, axes from --axis or else --nodes (x, y, z), the cycle from the
/// log's SYNC period.
fn compare(args: &ReplayArgs, log: &std::path::Path) -> anyhow::Result<u8> {
    let axes = if args.axes.is_empty() {
        ["x", "y", "z"]
            .iter()
            .zip(&args.nodes)
            .map(|(a, n)| format!("{a}={n}"))
            .collect()
    } else {
        args.axes.clone()
    };
    super::can::compare(&super::can::CompareArgs {
        log: log.to_path_buf(),
        eds: args.eds.clone(),
        axes,
        max_step_mm: args.max_step_mm,
        max_step_change_mm: args.max_step_change_mm,
        counts_per_mm: args.counts_per_mm,
        cycle_ms: None,
        json: args.json,
    })
}
