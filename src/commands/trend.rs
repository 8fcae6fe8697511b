//! `sparkout trend` and `--history` (issue 13 item 5): the night's
//! diagnosis appended to a fleet history, and the trend report over nights.

use std::path::Path;

use anyhow::Context;
use sparkout_pipeline::report::trend::{append_night, write_trend, Trend};

/// `sparkout trend --history DIR --out DIR`.
pub fn trend(history: &Path, out: &Path, json: bool) -> anyhow::Result<u8> {
    let t = write_trend(history, out)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&t)?);
    } else {
        print_trend(&t, out);
    }
    Ok(0)
}

fn print_trend(t: &Trend, out: &Path) {
    println!(
        "{} night(s), {} parameter series, {} alert(s)",
        t.nights.len(),
        t.series.len(),
        t.alerts.len()
    );
    for a in &t.alerts {
        println!("  ALERT {} {}: {}", a.night, a.kind, a.message);
    }
    println!("trend: {}", out.join("trend.html").display());
}

/// Appends a finished diagnosis.json to the history, then rewrites the trend
/// report into `trend_out`.
pub fn append(
    history: &Path,
    night: &str,
    diagnosis: &Path,
    trend_out: &Path,
) -> anyhow::Result<()> {
    let bytes = std::fs::read(diagnosis)
        .with_context(|| format!("cannot read {} for the history", diagnosis.display()))?;
    let v: serde_json::Value = serde_json::from_slice(&bytes)?;
    let file = append_night(history, night, &v)?;
    println!("history: {}", file.display());
    let t = write_trend(history, trend_out)?;
    print_trend(&t, trend_out);
    Ok(())
}
