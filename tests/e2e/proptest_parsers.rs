//! On stable: property tests of every parser a user's file
//! reaches — run.toml, machine configs, the contract tables (Parquet bytes
//! and values), observations, the candump log reader and the EDS check.
//! Each must answer with a value or an error, never a panic, and accept or
//! refuse exactly what the contract says. The cargo-fuzz targets in fuzz/
//! drive the same functions with coverage guidance.

use std::path::Path;

use proptest::prelude::*;
use sparkout_pipeline::contracts::config_keys::{check_process, load_machine};
use sparkout_pipeline::contracts::{
    write_parquet_atomic, BatchBuilder, MachineConfig, RunSpec, Table,
};
use sparkout_pipeline::diagnose::observations::validate_observations;
use sparkout_pipeline::replay::canopen::{check_eds, DRIVE_EDS};
use sparkout_pipeline::replay::log_bus::{format_line, parse_line};
use sparkout_pipeline::replay::CanFrame;

const GUIDEWAY_MACHINE: &str = include_str!("../../configs/machines/guideway-grinder.toml");

fn guideway_batch(z: Vec<f64>) -> BatchBuilder {
    let n = z.len();
    BatchBuilder::new()
        .i64("n", (0..n as i64).collect())
        .f64("x_mm", (0..n).map(|i| 30.0 * i as f64).collect())
        .f64("za_mm", z)
        .f64("zb_mm", vec![0.001; n])
        .f64("zc_mm", vec![0.002; n])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn candump_line_never_panics(s in "\\PC{0,60}") {
        let _ = parse_line(&s);
    }

    #[test]
    fn candump_line_of_bytes_never_panics(b in proptest::collection::vec(any::<u8>(), 0..60)) {
        let _ = parse_line(&String::from_utf8_lossy(&b));
    }

    #[test]
    fn candump_round_trip(t in 0u64..4_000_000_000_000, id in 0u32..0x800,
                          data in proptest::collection::vec(any::<u8>(), 0..=8)) {
        let f = CanFrame::new(t, id, &data);
        let line = format_line(&f, "can0");
        prop_assert_eq!(parse_line(&line).unwrap(), Some(f));
    }

    #[test]
    fn eds_check_never_panics(s in "\\PC{0,300}") {
        let _ = check_eds(&s);
    }

    #[test]
    fn eds_with_a_line_changed_never_panics(i in 0usize..400, repl in "\\PC{0,20}") {
        let mut lines: Vec<&str> = DRIVE_EDS.lines().collect();
        if !lines.is_empty() {
            let k = i % lines.len();
            lines[k] = &repl;
        }
        let _ = check_eds(&lines.join("\n"));
    }

    #[test]
    fn run_toml_never_panics(s in "\\PC{0,200}") {
        let _ = RunSpec::parse(Path::new("r"), &s);
    }

    #[test]
    fn run_toml_started_is_a_datetime_or_refused(started in "[0-9a-zA-Z:\\- ]{0,25}") {
        let text = format!("[run]\nid = \"r\"\nmachine = \"m\"\nplugin = \"p\"\nstarted = \"{started}\"\n");
        match RunSpec::parse(Path::new("r"), &text) {
            Ok(spec) => {
                let dt: toml::value::Datetime = spec.started.unwrap().parse().unwrap();
                prop_assert!(dt.date.is_some());
            }
            Err(e) => prop_assert_eq!(e.column.as_deref(), Some("run.started")),
        }
    }

    #[test]
    fn process_keys_outside_the_plugin_list_are_refused(key in "[a-z_]{1,12}", v in any::<f64>()) {
        let text = format!("[run]\nid = \"r\"\nmachine = \"m\"\nplugin = \"guideway\"\n[process]\n{key} = {v:?}\n");
        let text = text.replace("NaN", "nan");
        if let Ok(spec) = RunSpec::parse(Path::new("r"), &text) {
            use sparkout_pipeline::MachinePlugin;
            let known = sparkout_plugins::guideway::GuidewayPlugin.process_keys();
            let r = check_process(&spec, "guideway", known);
            // Accepted exactly when the key is known and its range holds.
            let in_range = known
                .iter()
                .any(|(k, check)| *k == key && check.accepts(&toml::Value::Float(v)));
            prop_assert_eq!(r.is_ok(), in_range && v.is_finite());
        }
    }

    #[test]
    fn machine_config_edits_are_checked(section in "[a-z]{1,8}", key in "[a-z_]{1,14}", v in any::<f64>()) {
        let text = format!("{GUIDEWAY_MACHINE}\n[{section}]\n{key} = {v:?}\n");
        let text = text.replace("NaN", "nan");
        // The appended table may redefine an existing one: not valid TOML.
        if let Ok(table) = text.parse::<toml::Table>() {
            let mut m = MachineConfig { id: "g".into(), source: "g.toml".into(), table, text: text.clone(), ..MachineConfig::default() };
            let builtin: toml::Table = GUIDEWAY_MACHINE.parse().unwrap();
            let known = builtin.get(&section).and_then(|s| s.get(&key)).is_some();
            let r = load_machine(&mut m, "guideway", &[GUIDEWAY_MACHINE], &[]);
            if r.is_ok() {
                prop_assert!(known && v.is_finite());
            }
            if !known {
                prop_assert!(r.is_err());
            }
        }
    }

    #[test]
    fn machine_config_text_never_panics(s in "\\PC{0,200}") {
        if let Ok(table) = s.parse::<toml::Table>() {
            let mut m = MachineConfig { id: "g".into(), source: "g.toml".into(), table, text: s.clone(), ..MachineConfig::default() };
            let _ = load_machine(&mut m, "guideway", &[GUIDEWAY_MACHINE], &[]);
        }
    }

    #[test]
    fn probe_readings_accepted_iff_finite_and_plausible(z in proptest::collection::vec(
        prop_oneof![any::<f64>(), -150.0f64..150.0, -0.05f64..0.05], 2..40)) {
        let batch = guideway_batch(z.clone()).build();
        let r = Table::from_batch(Path::new("guideway.parquet"), &sparkout_plugins::guideway::tables::GUIDEWAY, batch);
        let ok = z.iter().all(|v| v.is_finite() && v.abs() <= 100.0);
        prop_assert_eq!(r.is_ok(), ok, "{:?}", r.err());
    }

    #[test]
    fn observations_accepted_iff_finite_and_plausible(real in proptest::collection::vec(
        prop_oneof![any::<f64>(), -2e4f64..2e4, -0.1f64..0.1], 1..30)) {
        let n = real.len();
        let b = BatchBuilder::new()
            .str("run", &vec!["r0"; n])
            .str("observable", &vec!["surface_z"; n])
            .f64("sim", vec![0.0; n])
            .f64("real", real.clone())
            .f64("x_mm", (0..n).map(|i| i as f64).collect())
            .build();
        let r = validate_observations(&b, Path::new("obs.parquet"));
        let ok = real.iter().all(|v| v.is_finite() && v.abs() <= 1e4);
        prop_assert_eq!(r.is_ok(), ok);
    }
}

proptest! {
    // Parquet round trips touch the disk: fewer cases.
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Any corruption of a valid Parquet file is an error naming the file,
    /// never a panic.
    #[test]
    fn corrupted_parquet_is_an_error_not_a_panic(
        flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in proptest::option::of(any::<prop::sample::Index>()),
    ) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("guideway.parquet");
        write_parquet_atomic(&p, &guideway_batch(vec![0.01, 0.02, -0.01, 0.0]).build()).unwrap();
        let mut bytes = std::fs::read(&p).unwrap();
        for (i, b) in &flips {
            let k = i.index(bytes.len());
            bytes[k] ^= b | 1;
        }
        if let Some(c) = cut {
            let k = c.index(bytes.len());
            bytes.truncate(k);
        }
        std::fs::write(&p, &bytes).unwrap();
        let r = std::panic::catch_unwind(|| Table::read(&p, &sparkout_plugins::guideway::tables::GUIDEWAY));
        prop_assert!(r.is_ok(), "the reader panicked");
        if let Ok(Err(e)) = r {
            prop_assert_eq!(e.file, p);
        }
    }
}
