//! `form_cldata`: the segments' tool paths as CLDATA-like text, one program
//! per segment (docs/models.md §4: "one tool-path program per segment … switch
//! programs as dressing shrinks the wheel").
//!
//! In the DAG it turns the `toolpath` artifact into a `cldata` artifact
//! (segment, line, text — one row per line, so the text is reproducible from
//! Parquet). Run-less, `sparkout stage form_cldata --profile profile.parquet
//! --r-max-mm 175 --range-mm 50 --segments 5 --cldata-dir DIR` segments a
//! design profile file and writes `DIR/segment_NN.cls` (atomically).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::form::tables::PROFILE;
use crate::{bail, err, Context};
use arrow::record_batch::RecordBatch;
use serde_json::Value;
use sparkout_pipeline::config_check::{read_section, NoKeys, SectionCheck};
use sparkout_pipeline::contracts::{batch_f64, batch_i32, write_atomic, BatchBuilder, Table};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::config::{curvature, SegmentSection};
use super::model::ProfileRows;
use super::segment::{self, SegmentConfig};
use super::summary::{CldataStandalone, CldataSummary, ProgramLines};

/// CLDATA-like programs, one text per segment, from a `toolpath` batch.
pub fn programs(toolpath: &RecordBatch) -> Result<BTreeMap<i32, String>> {
    let seg = batch_i32(toolpath, "segment")?;
    let nom = batch_f64(toolpath, "nominal_mm")?;
    let phi = batch_f64(toolpath, "phi_rad")?;
    let (x, z, a, c) = (
        batch_f64(toolpath, "x_mm")?,
        batch_f64(toolpath, "z_mm")?,
        batch_f64(toolpath, "a_rad")?,
        batch_f64(toolpath, "c_rad")?,
    );
    let mut out: BTreeMap<i32, String> = BTreeMap::new();
    for i in 0..seg.len() {
        let text = out.entry(seg[i]).or_insert_with(|| {
            let mut h = String::new();
            let _ = writeln!(
                h,
                "PARTNO / SPARKOUT FORM SEGMENT {} NOMINAL {:.4} MM",
                seg[i], nom[i]
            );
            let _ = writeln!(h, "UNITS / MM");
            let _ = writeln!(
                h,
                "$$ wheel-centre path for a wheel of radius {:.4} mm (docs/models.md §4)",
                nom[i]
            );
            let _ = writeln!(
                h,
                "$$ GOTO / X (mm, centre distance from the work axis), Z (mm), A (rad), C (rad)"
            );
            let _ = writeln!(h, "CUTTER / {:.4}", 2.0 * nom[i]);
            let _ = writeln!(h, "MULTAX / ON");
            h
        });
        let _ = writeln!(
            text,
            "GOTO / {:.6}, {:.6}, {:.8}, {:.8}  $$ PHI {:.8}",
            x[i], z[i], a[i], c[i], phi[i]
        );
    }
    for t in out.values_mut() {
        t.push_str("FINI\n");
    }
    Ok(out)
}

/// The `cldata` artifact: one row per line.
pub fn cldata_batch(programs: &BTreeMap<i32, String>) -> RecordBatch {
    let (mut seg, mut line, mut text) = (Vec::new(), Vec::new(), Vec::new());
    for (s, t) in programs {
        for (k, l) in t.lines().enumerate() {
            seg.push(*s);
            line.push(k as i32 + 1);
            text.push(l.to_string());
        }
    }
    BatchBuilder::new()
        .i32("segment", seg)
        .i32("line", line)
        .str("text", &text)
        .build()
}

pub struct CldataStage;

const SPEC: StageSpec = StageSpec {
    name: "form_cldata",
    version: 1,
    reads: &[],
    reads_artifacts: &["toolpath"],
    writes: &["cldata"],
    reads_augmented_model: false,
    about: "CLDATA-like text programs (GOTO / X, Z, A, C) per segment; run-less: --profile FILE --r-max-mm --range-mm --segments --cldata-dir DIR",
    config: SectionCheck::of::<NoKeys>(),
};

impl Stage for CldataStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let tp = ctx.artifacts.require("toolpath")?;
        let progs = programs(&tp)?;
        let summary = CldataSummary {
            programs: progs
                .iter()
                .map(|(s, t)| ProgramLines {
                    segment: *s,
                    lines: t.lines().count(),
                })
                .collect(),
        };
        Ok(StageOutput::typed(&summary)?.with("cldata", cldata_batch(&progs)))
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(standalone(args))
    }
}

const FLAGS: &[&str] = &[
    "profile",
    "r-max-mm",
    "range-mm",
    "segments",
    "sweep-max",
    "radius-samples",
    "z-mm",
    "window-points",
    "cldata-dir",
];

fn standalone(args: &StageArgs) -> Result<Value> {
    for k in args.keys() {
        if !FLAGS.contains(&k.as_str()) {
            bail!(
                "stage form_cldata: unknown option --{k} (known: {})",
                FLAGS
                    .iter()
                    .map(|f| format!("--{f}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    let file = PathBuf::from(args.get("profile").ok_or_else(|| {
        err!("stage form_cldata: --profile <profile.parquet> (with `design` rows) is required")
    })?);
    // Flags become the same config keys `[form.segment]` takes, checked the
    // same way.
    let mut cfg = toml::Table::new();
    for (flag, key) in [
        ("r-max-mm", "r_max_mm"),
        ("range-mm", "range_mm"),
        ("segments", "segments"),
        ("sweep-max", "sweep_max"),
        ("radius-samples", "radius_samples"),
        ("z-mm", "z_mm"),
        ("window-points", "window_points"),
    ] {
        if let Some(v) = args.get(flag) {
            let x: f64 = v
                .parse()
                .map_err(|_| err!("stage form_cldata: --{flag} must be a number, found `{v}`"))?;
            cfg.insert(key.into(), toml::Value::Float(x));
        }
    }
    let section: SegmentSection = read_section(&cfg).context("stage form_cldata")?;
    let sc: SegmentConfig = segment::config_for(&section, None)?;
    let t = Table::read(&file, &PROFILE)?;
    let rows = ProfileRows::from_table(&t)?;
    let p = rows.design(&file, &curvature(section.window_points))?;
    let res = segment::compute(&p, &sc, &file, &rows.design_rows)?;
    let mut summary = CldataStandalone {
        segment: res.summary,
        cldata_files: None,
    };
    if let Some(dir) = args.get("cldata-dir") {
        let tp = res
            .output
            .artifacts
            .iter()
            .find(|(n, _)| n == "toolpath")
            .map(|(_, b)| b)
            .ok_or_else(|| err!("segment produced no toolpath"))?;
        let mut files = Vec::new();
        for (s, text) in programs(tp)? {
            let path = Path::new(dir).join(format!("segment_{s:02}.cls"));
            write_atomic(&path, text.as_bytes())?;
            files.push(path.display().to_string());
        }
        summary.cldata_files = Some(files);
    }
    Ok(serde_json::to_value(summary)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::form::curvature::{CurvatureConfig, Profile};
    use crate::form::model::WheelRange;
    use crate::form::segment::{segment, toolpath_batch};

    #[test]
    fn one_program_per_segment_with_a_goto_per_point() {
        let phi: Vec<f64> = (0..100)
            .map(|i| std::f64::consts::TAU * i as f64 / 100.0)
            .collect();
        let r: Vec<f64> = phi.iter().map(|f| 40.0 + 3.0 * f.cos()).collect();
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        let segs = segment(
            &p,
            &WheelRange {
                r_max_mm: 175.0,
                range_mm: 50.0,
            },
            2,
            3,
            crate::form::model::DeltaModel::Published,
        )
        .unwrap();
        let progs = programs(&toolpath_batch(&p, &segs, 5.0)).unwrap();
        assert_eq!(progs.len(), 2);
        for t in progs.values() {
            assert_eq!(t.lines().filter(|l| l.starts_with("GOTO")).count(), 100);
            assert!(t.ends_with("FINI\n"));
        }
        assert!(progs[&1].contains("NOMINAL 162.5000 MM"));
        let b = cldata_batch(&progs);
        assert_eq!(
            b.num_rows(),
            progs.values().map(|t| t.lines().count()).sum::<usize>()
        );
    }
}
