//! Record-back: what the drives reported becomes a recorded run (docs/formats.md
//! §1) — motion.parquet with cmd_* (the setpoints sent) and act_* (the TPDO
//! actual positions), and a run.toml — that `sparkout run` and
//! `validate-input` take like any run.
//!
//! The recorded run keeps the source's machine, plugin and [process], and a
//! copy of every other table (probe, plan, passes, topography, ae …: what
//! the plugin needs besides motion), so it passes the plugin's table
//! requirements and can be diagnosed like the source: a robot run probed by
//! AE has no probe table, only ae + motion + plan. The recorded motion keeps
//! the source's time base, so the AE log (with `[ae]` and its clock offset)
//! still lines up; being large, it is hard-linked where the file system
//! allows (sparkout replaces files, never writes into them, so the source is
//! never changed through the link) and copied otherwise. A `[replay]` table
//! says where the run came from and how the replay ended.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

use super::canopen::Outcome;
use super::source::Plan;
use crate::contracts::{write_atomic, write_parquet_atomic, MotionColumns, RunSpec};

/// What goes into `[replay]` of the recorded run.toml.
#[derive(Debug, Clone)]
pub struct RecordInfo {
    pub bus: String,
    pub cycle_s: f64,
    pub counts_per_mm: f64,
    pub compensation: Option<PathBuf>,
    pub outcome: String,
}

/// Write the recorded run into `out` (created); returns the rows written.
pub fn write_recorded_run(
    out: &Path,
    source: &RunSpec,
    plan: &Plan,
    outcome: &Outcome,
    info: &RecordInfo,
) -> Result<usize> {
    let cpm = info.counts_per_mm;
    let mut t = Vec::new();
    let mut cmd = [Vec::new(), Vec::new(), Vec::new()];
    let mut act = [Vec::new(), Vec::new(), Vec::new()];
    let mut feed = Vec::new();
    let mut seg = Vec::new();
    for (k, s) in outcome.samples.iter().enumerate() {
        // Only cycles whose feedback came back from every drive.
        let Some(a) = s.act.iter().copied().collect::<Option<Vec<i32>>>() else {
            continue;
        };
        t.push(plan.t0_s + k as f64 * info.cycle_s);
        for ax in 0..3 {
            cmd[ax].push(s.cmd[ax] as f64 / cpm);
            act[ax].push(a[ax] as f64 / cpm);
        }
        if let Some(f) = &plan.feed_mm_s {
            feed.push(f[k]);
        }
        if let Some(g) = &plan.segment {
            seg.push(g[k]);
        }
    }
    if t.is_empty() {
        return Err(Error::NothingToRecord {
            outcome: info.outcome.clone(),
        });
    }
    let rows = t.len();
    let motion = MotionColumns {
        t_s: t,
        cmd_mm: cmd,
        act_mm: Some(act),
        feed_mm_s: plan.feed_mm_s.is_some().then_some(feed),
        segment: plan.segment.is_some().then_some(seg),
    };
    std::fs::create_dir_all(out).map_err(Error::io("cannot create", out))?;
    write_parquet_atomic(&out.join("motion.parquet"), &motion.into_batch()).map_err(Error::Core)?;

    // The run's other tables, byte for byte (whatever machine type recorded
    // them: the replay knows no plugin's tables): every regular
    // `<table>.parquet` beside run.toml but the motion log it replaced.
    let mut tables: Vec<String> = std::fs::read_dir(&source.dir)
        .map_err(Error::io("cannot list", &source.dir))?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().map(|t| t.is_file()).unwrap_or(false))
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let stem = name.strip_suffix(".parquet")?.to_string();
            (stem != "motion" && !stem.starts_with('.')).then_some(stem)
        })
        .collect();
    tables.sort();
    let mut copied = Vec::new();
    for table in tables {
        let file = format!("{table}.parquet");
        let src = source.dir.join(&file);
        let dst = out.join(&file);
        if table == "ae" {
            link_or_copy(&src, &dst)?;
        } else {
            let bytes = std::fs::read(&src).map_err(Error::io("cannot read", &src))?;
            write_atomic(&dst, &bytes).map_err(Error::Core)?;
        }
        copied.push(table);
    }

    let mut doc: toml::Table = source.text.parse().map_err(Error::SourceRunToml)?;
    if !copied.iter().any(|t| t == "ae") {
        doc.remove("ae");
    }
    if let Some(run) = doc.get_mut("run").and_then(|v| v.as_table_mut()) {
        run.insert("id".into(), format!("{}-replay", source.id).into());
    }
    let mut replay = toml::Table::new();
    replay.insert("source_run".into(), source.dir.display().to_string().into());
    if let Some(c) = &info.compensation {
        replay.insert("compensation".into(), c.display().to_string().into());
    }
    replay.insert("bus".into(), info.bus.clone().into());
    replay.insert("cycle_s".into(), info.cycle_s.into());
    replay.insert("counts_per_mm".into(), info.counts_per_mm.into());
    replay.insert(
        "cycles_streamed".into(),
        (outcome.cycles_streamed as i64).into(),
    );
    replay.insert("rows_recorded".into(), (rows as i64).into());
    replay.insert("outcome".into(), info.outcome.clone().into());
    replay.insert(
        "copied_tables".into(),
        toml::Value::Array(copied.into_iter().map(Into::into).collect()),
    );
    doc.insert("replay".into(), replay.into());
    let text = format!(
        "# Recorded by `sparkout replay` from {}: cmd_* = setpoints sent, act_* = drive feedback.\n{}",
        source.dir.display(),
        toml::to_string(&doc)?
    );
    write_atomic(&out.join(RunSpec::FILE), text.as_bytes()).map_err(Error::Core)?;
    Ok(rows)
}

/// `dst` as a hard link to `src`, or a copy where links do not work (another
/// file system); either way under a temporary name renamed into place, so a
/// killed replay leaves no partial table under the final name.
fn link_or_copy(src: &Path, dst: &Path) -> Result<()> {
    let name = dst
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dst.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    if std::fs::hard_link(src, &tmp).is_err() {
        std::fs::copy(src, &tmp).map_err(|source| Error::Copy {
            from: src.to_path_buf(),
            to: tmp.clone(),
            source,
        })?;
    }
    std::fs::rename(&tmp, dst).map_err(Error::io("cannot write", dst))?;
    Ok(())
}
