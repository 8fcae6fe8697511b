//! `sparkout diagnose`: the gap diagnosis on any paired-observations table.

use std::path::Path;

use anyhow::{bail, Context};
use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::contracts::{write_atomic, write_json_atomic};
use sparkout_pipeline::diagnose::{self, DiagnoseConfig, EffectScope};

use crate::registry;

pub use crate::cli::DiagnoseFlags as Flags;

/// `[diagnose]` of the config (built-in, --config, --set), then the flags.
pub fn config(flags: &Flags) -> anyhow::Result<Checked<DiagnoseConfig>> {
    let pc = registry::config(&flags.config)?;
    // The flags are keys of the section, checked with it.
    let mut section = pc.section("diagnose");
    if let Some(k) = flags.folds {
        section.insert("folds".into(), toml::Value::Integer(k as i64));
    }
    if let Some(s) = flags.seed {
        section.insert("seed".into(), toml::Value::Integer(s as i64));
    }
    if let Some(e) = &flags.effects {
        section.insert(
            "effects".into(),
            toml::Value::Array(e.iter().cloned().map(toml::Value::String).collect()),
        );
    }
    Checked::<DiagnoseConfig>::read(&section)
        .with_context(|| format!("config {} (with the flags): [diagnose]", pc.source))
}

/// Does `observable` match one of a plugin's declared names (`prefix*`
/// matches by prefix)?
fn produced_by(declared: &[&str], observable: &str) -> bool {
    declared.iter().any(|d| match d.strip_suffix('*') {
        Some(prefix) => observable.starts_with(prefix),
        None => *d == observable,
    })
}

pub fn diagnose(observations: &Path, out: &Path, flags: &Flags) -> anyhow::Result<u8> {
    let cfg = config(flags)?;
    // The keys, sim and real indexed batch by batch; the covariates are
    // read from the file one observable at a time, so a table far larger
    // than memory diagnoses (docs/scale.md).
    let file = diagnose::index_observations_file(observations)?;
    let table_observables = file.observables().to_vec();
    // A foreign table gets the catalogue only; `--plugin NAME` adds that
    // plugin's composites, scoped to the observables it produces when the
    // table has any of them (a sparkout fleet table), else to all.
    let all = registry::plugins();
    let mut chosen = Vec::new();
    for name in &flags.plugins {
        let Some(p) = all.iter().find(|p| p.name() == name) else {
            let known: Vec<&str> = all.iter().map(|p| p.name()).collect();
            bail!("unknown plugin `{name}` (known: {})", known.join(", "));
        };
        let declared = p.observables();
        let mine: Vec<String> = table_observables
            .iter()
            .filter(|o| produced_by(&declared, o))
            .cloned()
            .collect();
        chosen.push((p.name(), mine, p.effects()));
    }
    let scopes: Vec<EffectScope> = chosen
        .iter()
        .map(|(plugin, mine, effects)| EffectScope {
            plugin,
            observables: (!mine.is_empty()).then_some(mine.as_slice()),
            effects,
        })
        .collect();
    // The per-row results wait on disk, in a hidden folder of the output
    // removed once diagnosis.parquet is written; an output folder this
    // run created stays only if the diagnosis succeeds.
    let created = !out.exists();
    let results_dir = out.join(".diagnosis-results");
    let progress = |msg: &str| tracing::info!("{msg}");
    let d = match diagnose::diagnose_indexed(
        file,
        &cfg,
        &scopes,
        None,
        Some(&results_dir),
        &progress,
    ) {
        Ok(d) => d,
        Err(e) => {
            if created {
                let _ = std::fs::remove_dir(out);
            }
            return Err(e.into());
        }
    };
    d.per_row.write_parquet(&out.join("diagnosis.parquet"))?;
    write_json_atomic(&out.join("augmented_model.json"), &d.augmented_model)?;
    let page = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>sparkout diagnosis</title></head><body>\n<h1>Sim-to-real gap diagnosis of {}</h1>\n{}\n</body></html>\n",
        sparkout_pipeline::report::esc(&observations.display().to_string()),
        d.report_html
    );
    write_atomic(&out.join("report.html"), page.as_bytes())?;
    // diagnosis.json last: its presence means the set is complete.
    write_json_atomic(&out.join("diagnosis.json"), &d.diagnosis)?;
    if flags.json {
        println!("{}", serde_json::to_string_pretty(&d.diagnosis)?);
    } else {
        let sel = &d.diagnosis.selected;
        // The pooled gap is in the observables' unit when they share one
        // (each is in its contract unit: mm, or mm/s for a velocity).
        let units: std::collections::BTreeSet<&str> = d
            .diagnosis
            .per_observable
            .iter()
            .map(|o| o.unit.as_str())
            .collect();
        let unit = match units.len() {
            1 => units.first().copied().unwrap_or("mm"),
            _ => "mm",
        };
        let [gap, noise, after] =
            <[String; 3]>::try_from(sparkout_pipeline::units::format::show_group(
                &[
                    d.diagnosis.gap.rms_mm,
                    d.diagnosis.gap.noise_floor_mm,
                    d.diagnosis.unexplained.rms_mm,
                ],
                unit,
            ))
            .expect("three figures");
        println!(
            "gap RMS {gap}, noise floor {noise}; selected: {}; held-out RMS after {after}",
            if sel.is_empty() {
                "none (no effect explains the gap)".to_string()
            } else {
                sel.join(", ")
            },
        );
        for e in d.diagnosis.effects.iter().filter(|e| e.selected) {
            let shrink = match (e.shrink, e.shrink_interval) {
                (Some(s), Some([lo, hi])) => {
                    format!("held-out shrink {s:.2} (95 % {lo:.2}–{hi:.2})")
                }
                (Some(s), None) => format!("held-out shrink {s:.2}"),
                _ => String::new(),
            };
            println!("  {} on {}: {shrink}", e.key(), e.observable);
            if !e.indistinguishable_from.is_empty() {
                println!("    {}", e.explained_text());
            }
            for p in e.params_text() {
                println!("    {p}");
            }
        }
        for o in &d.diagnosis.per_observable {
            if !o.minor.is_empty() {
                println!(
                    "  {}: minor (not stable or material enough to select): {}",
                    o.observable,
                    o.minor.join(", ")
                );
            }
            for s in diagnose::document::caution_sentences(o, &d.diagnosis.effects) {
                println!("  {}: {s}", o.observable);
            }
        }
        println!("wrote {}", out.join("diagnosis.json").display());
    }
    Ok(0)
}
