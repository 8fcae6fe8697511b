//! `sparkout can decode LOG`: a recorded bus log as CiA 301/402 events;
//! `sparkout can describe FILE`: a drive's EDS or DCF as the replay reads it.

use std::path::Path;

use anyhow::{bail, Context};
use sparkout_pipeline::contracts::write_atomic;
use sparkout_pipeline::replay::decode::decode_log;
use sparkout_pipeline::replay::eds::DeviceDescription;

pub fn describe(file: &Path, node: u8, json: bool) -> anyhow::Result<u8> {
    let d = DeviceDescription::load(file, node)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&d)?);
    } else {
        print!("{}", d.describe());
    }
    Ok(0)
}

pub fn decode(log: &Path, format: &str, out: Option<&Path>) -> anyhow::Result<u8> {
    if let Some(o) = out {
        if o.exists() {
            bail!(
                "{} already exists; choose a new file (decoded events are never written over a file)",
                o.display()
            );
        }
    }
    let d = decode_log(log)?;
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
