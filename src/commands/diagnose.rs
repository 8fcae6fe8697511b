//! `sparkout diagnose`: the gap diagnosis on any paired-observations table.

use std::path::Path;

use sparkout_pipeline::contracts::{write_atomic, write_json_atomic, write_parquet_atomic};
use sparkout_pipeline::diagnose::{self, DiagnoseConfig};

pub fn diagnose(
    observations: &Path,
    out: &Path,
    folds: Option<usize>,
    effects: Option<Vec<String>>,
    seed: Option<u64>,
    json: bool,
) -> anyhow::Result<u8> {
    let mut cfg = DiagnoseConfig::default();
    if let Some(k) = folds {
        cfg.folds = k;
    }
    if let Some(s) = seed {
        cfg.seed = s;
    }
    cfg.effects = effects;
    cfg.validate()?;
    let obs = diagnose::read_observations(observations)?;
    let plugin_effects: Vec<Box<dyn diagnose::Effect>> = sparkout_plugins::all_plugins()
        .iter()
        .flat_map(|p| p.effects())
        .collect();
    let d = diagnose::diagnose(&obs, &cfg, &plugin_effects)?;
    write_parquet_atomic(&out.join("diagnosis.parquet"), &d.per_row)?;
    write_json_atomic(&out.join("augmented_model.json"), &d.augmented_model)?;
    let page = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>sparkout diagnosis</title></head><body>\n<h1>Sim-to-real gap diagnosis of {}</h1>\n{}\n</body></html>\n",
        sparkout_pipeline::report::esc(&observations.display().to_string()),
        d.report_html
    );
    write_atomic(&out.join("report.html"), page.as_bytes())?;
    // diagnosis.json last: its presence means the set is complete.
    write_json_atomic(&out.join("diagnosis.json"), &d.diagnosis)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&d.diagnosis)?);
    } else {
        let v = serde_json::to_value(&d.diagnosis)?;
        let sel: Vec<&str> = v["selected"]
            .as_array()
            .map(|a| a.iter().filter_map(|x| x.as_str()).collect())
            .unwrap_or_default();
        println!(
            "gap RMS {:.4} mm, noise floor {:.4} mm; selected: {}; held-out RMS after {:.4} mm",
            v["gap"]["rms_mm"].as_f64().unwrap_or(f64::NAN),
            v["gap"]["noise_floor_mm"].as_f64().unwrap_or(f64::NAN),
            if sel.is_empty() {
                "none (no effect explains the gap)".to_string()
            } else {
                sel.join(", ")
            },
            v["unexplained"]["rms_mm"].as_f64().unwrap_or(f64::NAN),
        );
        println!("wrote {}", out.join("diagnosis.json").display());
    }
    Ok(0)
}
