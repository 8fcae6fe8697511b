//! `sparkout can decode LOG`: a recorded bus log as CiA 301/402 events;
//! `sparkout can describe FILE`: a drive's EDS or DCF as the replay reads it;
//! `sparkout can compare LOG`: what a master sent, against the envelope.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use sparkout_pipeline::contracts::{write_atomic, write_parquet_atomic};
use sparkout_pipeline::replay::canopen::AxisRef;
use sparkout_pipeline::replay::compare::{compare as compare_log, CompareSettings};
use sparkout_pipeline::replay::decode::{decode_log_with, events_batch};
use sparkout_pipeline::replay::eds::DeviceDescription;

/// `--eds NODE=FILE` flags, each file read for its node.
pub fn eds_flags(flags: &[String]) -> anyhow::Result<BTreeMap<u8, PathBuf>> {
    let mut out = BTreeMap::new();
    for f in flags {
        let (node, file) = f
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("--eds `{f}`: use NODE=FILE, e.g. --eds 1=drive.eds"))?;
        let n: u8 = node
            .trim()
            .parse()
            .ok()
            .filter(|n| (1..=127).contains(n))
            .ok_or_else(|| anyhow::anyhow!("--eds `{f}`: `{node}` is not a node id 1–127"))?;
        if out.insert(n, PathBuf::from(file)).is_some() {
            bail!("--eds: node {n} given twice");
        }
    }
    Ok(out)
}

fn load_all(files: &BTreeMap<u8, PathBuf>) -> anyhow::Result<BTreeMap<u8, DeviceDescription>> {
    let mut out = BTreeMap::new();
    for (n, p) in files {
        out.insert(*n, DeviceDescription::load(p, *n)?);
    }
    Ok(out)
}

/// `--axis AXIS=NODE[:N]` flags: (machine axis 0–2, drive axis).
pub fn axis_flags(flags: &[String]) -> anyhow::Result<Vec<(usize, AxisRef)>> {
    flags
        .iter()
        .map(|f| {
            let (axis, spec) = f.split_once('=').ok_or_else(|| {
                anyhow::anyhow!("--axis `{f}`: use AXIS=NODE or AXIS=NODE:N, e.g. --axis y=1:2")
            })?;
            let a = ["x", "y", "z"]
                .iter()
                .position(|n| n.eq_ignore_ascii_case(axis.trim()))
                .ok_or_else(|| anyhow::anyhow!("--axis `{f}`: `{axis}` is not x, y or z"))?;
            let r = AxisRef::parse(spec).map_err(|e| anyhow::anyhow!("--axis {e}"))?;
            Ok((a, r))
        })
        .collect()
}

pub fn describe(file: &Path, node: u8, json: bool) -> anyhow::Result<u8> {
    let d = DeviceDescription::load(file, node)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&d)?);
    } else {
        print!("{}", d.describe());
    }
    Ok(0)
}

pub fn decode(log: &Path, format: &str, out: Option<&Path>, eds: &[String]) -> anyhow::Result<u8> {
    if format == "parquet" && out.is_none() {
        bail!("--format parquet needs --out FILE (Parquet is not written to a terminal)");
    }
    if let Some(o) = out {
        if o.exists() {
            bail!(
                "{} already exists; choose a new file (decoded events are never written over a file)",
                o.display()
            );
        }
    }
    let files = load_all(&eds_flags(eds)?)?;
    let d = decode_log_with(log, &files)?;
    if format == "parquet" {
        let o = out.expect("checked above");
        write_parquet_atomic(o, &events_batch(&d.events))
            .with_context(|| format!("cannot write {}", o.display()))?;
        eprintln!("{} events: {}", d.events.len(), o.display());
        return Ok(0);
    }
    let mut text = String::new();
    match format {
        "jsonl" => {
            for e in &d.events {
                text.push_str(&serde_json::to_string(e)?);
                text.push('\n');
            }
        }
        _ => {
            for e in &d.events {
                let t = e
                    .t_s
                    .map(|t| format!("{t:>17.6}"))
                    .unwrap_or_else(|| format!("{:>17}", "-"));
                text.push_str(&format!(
                    "{:>6}  {t}  {:03X}  {}\n",
                    e.line, e.cob_id, e.text
                ));
            }
            text.push_str(&format!(
                "{} frames decoded, {} error frames, {} CAN FD frames (not decoded)\n",
                d.frames, d.error_frames, d.fd_frames
            ));
        }
    }
    match out {
        Some(o) => {
            write_atomic(o, text.as_bytes())
                .with_context(|| format!("cannot write {}", o.display()))?;
            eprintln!("{} events: {}", d.events.len(), o.display());
        }
        None => print!("{text}"),
    }
    Ok(0)
}

/// `sparkout can compare` flags.
pub struct CompareArgs {
    pub log: PathBuf,
    pub eds: Vec<String>,
    pub axes: Vec<String>,
    pub max_step_mm: f64,
    pub max_step_change_mm: f64,
    pub counts_per_mm: f64,
    pub cycle_ms: Option<f64>,
    pub json: bool,
}

pub fn compare(a: &CompareArgs) -> anyhow::Result<u8> {
    for (name, v) in [
        ("--max-step-mm", a.max_step_mm),
        ("--max-step-change-mm", a.max_step_change_mm),
        ("--counts-per-mm", a.counts_per_mm),
        ("--cycle-ms", a.cycle_ms.unwrap_or(1.0)),
    ] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{name} {v}: must be a finite number > 0");
        }
    }
    let files = load_all(&eds_flags(&a.eds)?)?;
    let d = decode_log_with(&a.log, &files)?;
    let names = ["x", "y", "z"];
    let settings = CompareSettings {
        max_step_mm: a.max_step_mm,
        max_step_change_mm: a.max_step_change_mm,
        counts_per_mm: a.counts_per_mm,
        cycle_s: a.cycle_ms.map(|c| c * 1e-3),
        axis_names: axis_flags(&a.axes)?
            .into_iter()
            .map(|(i, r)| ((r.node, r.axis), names[i].to_string()))
            .collect(),
    };
    let c = compare_log(&d, &settings);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        for f in &c.findings {
            println!(
                "line {:>6}  t {}  node {}{}  {} = {}: {} (limit {})",
                f.line,
                f.t_s
                    .map(|t| format!("{t:.6}"))
                    .unwrap_or_else(|| "-".into()),
                f.node,
                f.axis
                    .as_ref()
                    .map(|a| format!(" (axis {a})"))
                    .unwrap_or_default(),
                f.object,
                f.value,
                f.why,
                f.limit
            );
        }
        for n in &c.notes {
            println!("note: {n}");
        }
        println!(
            "{} commands checked against the envelope (step {} mm, step change {} mm per cycle{}): {} outside",
            c.commands_checked,
            a.max_step_mm,
            a.max_step_change_mm,
            c.cycle_s.map(|s| format!(", cycle {:.3} ms", s * 1e3)).unwrap_or_default(),
            c.findings.len()
        );
    }
    Ok(if c.findings.is_empty() { 0 } else { 2 })
}
