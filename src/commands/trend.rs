//! `sparkout trend` and `--history`: the night's diagnosis appended to a
//! fleet history, and the ranked trend report over nights.

use std::path::Path;

use anyhow::Context;
use sparkout_pipeline::diagnose::Diagnosis;
use sparkout_pipeline::files::json::read_json;
use sparkout_pipeline::report::trend::{
    append_events, append_night, fingerprint, parse_event, write_trend, Trend, TrendConfig,
};

use crate::cli::{ConfigArgs, DiagnoseFlags};
use crate::registry;

/// `[trend]` of the config (built-in, --config, --set).
fn trend_config(config: &ConfigArgs) -> anyhow::Result<TrendConfig> {
    let pc = registry::config(config)?;
    TrendConfig::from_toml(&pc.section("trend"))
        .with_context(|| format!("config {}: [trend]", pc.source))
}

/// `sparkout trend --history DIR --out DIR [--event SPEC]...`.
pub fn trend(
    config: &ConfigArgs,
    history: &Path,
    out: &Path,
    events: &[String],
    json: bool,
) -> anyhow::Result<u8> {
    let cfg = trend_config(config)?;
    let events = events
        .iter()
        .map(|e| parse_event(e, None))
        .collect::<sparkout_pipeline::Result<Vec<_>>>()?;
    let t = write_trend(history, out, &events, &cfg)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&t)?);
    } else {
        print_trend(&t, out);
    }
    Ok(0)
}

/// The summary: every alert, newest night first, by rank.
fn print_trend(t: &Trend, out: &Path) {
    println!(
        "{} night(s), {} parameter series, {} event(s), {} alert(s)",
        t.nights.len(),
        t.series.len(),
        t.events.len(),
        t.alerts.len()
    );
    for n in &t.notes {
        println!("  note: {n}");
    }
    for e in &t.events {
        let who = if e.machine.is_empty() {
            "fleet"
        } else {
            &e.machine
        };
        println!(
            "  event {} {} {who}: new baseline {}",
            e.night, e.kind, e.note
        );
    }
    for a in &t.alerts {
        println!("  ALERT {} #{} {}: {}", a.night, a.rank, a.kind, a.message);
    }
    println!("trend: {}", out.join("trend.html").display());
}

/// The night `diagnose --history` appends.
pub struct Night<'a> {
    pub history: &'a Path,
    pub night: &'a str,
    /// `--event` specs, dated this night unless they say otherwise.
    pub events: &'a [String],
}

/// Appends a finished diagnosis.json to the history, then rewrites the trend
/// report into `trend_out`.
pub fn append(
    flags: &DiagnoseFlags,
    n: &Night,
    diagnosis: &Path,
    trend_out: &Path,
) -> anyhow::Result<()> {
    let cfg = trend_config(&flags.config)?;
    let events = n
        .events
        .iter()
        .map(|e| parse_event(e, Some(n.night)))
        .collect::<sparkout_pipeline::Result<Vec<_>>>()?;
    let d: Diagnosis =
        read_json(diagnosis).with_context(|| format!("{} for the history", diagnosis.display()))?;
    // The settings the diagnosis ran with and the code behind it (the
    // diagnosis' version, the named plugins' effects): a change between
    // nights is an event, not an alert.
    let dcfg = super::diagnose::config(flags)?;
    let effects: Vec<String> = registry::plugins()
        .iter()
        .filter(|p| flags.plugins.iter().any(|n| n == p.name()))
        .flat_map(|p| p.effects().iter().map(|e| e.key()).collect::<Vec<_>>())
        .collect();
    let settings = serde_json::to_string(&(
        &*dcfg,
        &flags.plugins,
        sparkout_pipeline::engine::DIAGNOSE_STAGE_VERSION,
        effects,
    ))?;
    let file = append_night(n.history, n.night, &d, &fingerprint(&settings))?;
    append_events(n.history, &events)?;
    println!("history: {}", file.display());
    let t = write_trend(n.history, trend_out, &[], &cfg)?;
    print_trend(&t, trend_out);
    Ok(())
}
