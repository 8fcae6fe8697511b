//! `sparkout can compare LOG`: what a master sent to the drives in a
//! recorded bus log, against the safety envelope. Target positions (0x607A)
//! and target velocities (0x60FF) of every axis, whether in an RPDO
//! (decoded through the node's mapping: its EDS/DCF, or the configuration
//! the log itself shows) or in an SDO write, are checked per drive axis:
//!
//! * a target position step between two commands larger than the
//!   envelope's step (`max_step_mm` per cycle), the first one measured from
//!   the drive's last reported actual position (0x6064) when the log has one;
//! * a change of that step between two cycles larger than
//!   `max_step_change_mm`;
//! * a target velocity above `max_step_mm` per cycle.
//!
//! The compensation limit needs the commanded path, which a bus log does
//! not hold: it is checked by `sparkout replay` before anything is sent.

use std::collections::BTreeMap;

use serde::Serialize;

use super::canopen::pdo::split_axis;
use super::decode::{BusEvent, Decoded};

/// The envelope as a bus log can be checked against it.
#[derive(Debug, Clone)]
pub struct CompareSettings {
    pub max_step_mm: f64,
    pub max_step_change_mm: f64,
    pub counts_per_mm: f64,
    /// The SYNC cycle (s); `None`: the log's median SYNC period.
    pub cycle_s: Option<f64>,
    /// Machine axis names by (node, drive axis), for the report.
    pub axis_names: BTreeMap<(u8, u8), String>,
}

/// One frame outside the envelope.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    /// 1-based line of the log (the frame number).
    pub line: usize,
    pub t_s: Option<f64>,
    pub node: u8,
    /// The machine axis, when known (`--axis`).
    pub axis: Option<String>,
    pub object: String,
    pub value: i64,
    pub limit: String,
    pub why: String,
}

/// What the comparison found.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub commands_checked: usize,
    pub cycle_s: Option<f64>,
    pub findings: Vec<Finding>,
    /// What could not be checked and why.
    pub notes: Vec<String>,
}

#[derive(Default)]
struct AxisTrack {
    last: Option<i64>,
    last_step: Option<i64>,
    actual: Option<i64>,
}

/// The median SYNC period of a log (s).
fn sync_period(d: &Decoded) -> Option<f64> {
    let t: Vec<f64> = d
        .events
        .iter()
        .filter(|e| e.kind == "sync")
        .filter_map(|e| e.t_s)
        .collect();
    let mut dt: Vec<f64> = t
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|x| *x > 0.0)
        .collect();
    if dt.is_empty() {
        return None;
    }
    dt.sort_by(|a, b| a.total_cmp(b));
    Some(dt[dt.len() / 2])
}

/// Every target in `d` against the envelope.
pub fn compare(d: &Decoded, s: &CompareSettings) -> Comparison {
    let cycle_s = s.cycle_s.or_else(|| sync_period(d));
    let cpm = s.counts_per_mm;
    let step_limit = s.max_step_mm * cpm;
    let change_limit = s.max_step_change_mm * cpm;
    let mut tracks: BTreeMap<(u8, u8), AxisTrack> = BTreeMap::new();
    let mut out = Comparison {
        commands_checked: 0,
        cycle_s,
        findings: Vec::new(),
        notes: Vec::new(),
    };
    let mut velocity_unchecked = false;
    // (index, value) pairs an event carries towards / from a drive.
    let targets = |e: &BusEvent| -> Vec<(u16, u8, i64)> {
        if e.kind.starts_with("rpdo") || e.kind.starts_with("tpdo") {
            e.objects
                .iter()
                .map(|o| (o.index, o.subindex, o.value))
                .collect()
        } else if e.kind == "sdo_request" && e.text.starts_with("SDO write") {
            match (e.index, e.subindex, e.value) {
                // An SDO value is read unsigned: a target is INTEGER32.
                (Some(i), Some(sub), Some(v)) => vec![(i, sub, v as u32 as i32 as i64)],
                _ => vec![],
            }
        } else {
            vec![]
        }
    };
    for e in &d.events {
        let Some(node) = e.node else { continue };
        let to_drive = e.kind.starts_with("rpdo") || e.kind == "sdo_request";
        for (index, sub, v) in targets(e) {
            if sub != 0 {
                continue;
            }
            let (axis, base) = split_axis(index);
            let key = (node, axis);
            let t = tracks.entry(key).or_default();
            let name = s.axis_names.get(&key).cloned();
            let finding = |object: &str, limit: String, why: String| Finding {
                line: e.line,
                t_s: e.t_s,
                node,
                axis: name.clone(),
                object: object.to_string(),
                value: v,
                limit,
                why,
            };
            match (base, to_drive) {
                (0x6064, false) => t.actual = Some(v),
                (0x607A, true) => {
                    out.commands_checked += 1;
                    let from = t.last.or(t.actual);
                    if let Some(p) = from {
                        let step = v - p;
                        if (step.abs() as f64) > step_limit {
                            out.findings.push(finding(
                                &format!("0x{index:04X} target position"),
                                format!("{step_limit:.0} counts ({} mm) per cycle", s.max_step_mm),
                                format!(
                                    "step {step} counts ({:.4} mm) from {} {p}",
                                    step as f64 / cpm,
                                    if t.last.is_some() {
                                        "the previous target"
                                    } else {
                                        "the actual position"
                                    }
                                ),
                            ));
                        }
                        if let (Some(ps), Some(_)) = (t.last_step, t.last) {
                            let change = step - ps;
                            if (change.abs() as f64) > change_limit {
                                out.findings.push(finding(
                                    &format!("0x{index:04X} target position"),
                                    format!("{change_limit:.0} counts ({} mm) per cycle²", s.max_step_change_mm),
                                    format!(
                                        "step changed by {change} counts ({:.4} mm) from the previous step {ps}",
                                        change as f64 / cpm
                                    ),
                                ));
                            }
                        }
                        if t.last.is_some() {
                            t.last_step = Some(step);
                        }
                    }
                    t.last = Some(v);
                }
                (0x60FF, true) => {
                    out.commands_checked += 1;
                    match cycle_s {
                        Some(c) => {
                            let vmax = step_limit / c;
                            if (v.abs() as f64) > vmax {
                                out.findings.push(finding(
                                    &format!("0x{index:04X} target velocity"),
                                    format!("{vmax:.0} counts/s ({:.3} mm/s)", vmax / cpm),
                                    format!("|velocity| {:.3} mm/s", v.abs() as f64 / cpm),
                                ));
                            }
                        }
                        None => velocity_unchecked = true,
                    }
                }
                _ => {}
            }
        }
    }
    if velocity_unchecked {
        out.notes.push(
            "target velocities not checked: the log has no SYNC to take the cycle from; pass --cycle-ms".into(),
        );
    }
    if out.commands_checked == 0 {
        out.notes.push(
            "no target position or velocity found: give the node's EDS (--eds NODE=FILE) if the log does not show its PDO mapping being configured".into(),
        );
    }
    out
}
