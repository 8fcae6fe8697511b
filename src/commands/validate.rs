//! `sparkout validate`: the diagnosis checked on fleets whose effect is known.

use std::path::PathBuf;

use sparkout_pipeline::contracts::{write_atomic, write_json_atomic};

pub fn validate(quick: bool, out: Option<PathBuf>, seed: u64, json: bool) -> anyhow::Result<u8> {
    let cfg = sparkout_datasets::validate::ValidateConfig {
        quick,
        seed,
        ..Default::default()
    };
    let report = sparkout_datasets::validate::run(&cfg)?;
    let text = sparkout_datasets::validate::render_text(&report);
    if let Some(out) = &out {
        write_atomic(&out.join("validation.txt"), text.as_bytes())?;
        write_json_atomic(&out.join("validation.json"), &report)?;
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{text}");
    }
    Ok(0)
}
