//! A toy machine type, added the way docs/adding-a-plugin.md says — this
//! folder plus one registration line — and run through the engine by the
//! tests below, so the walkthrough cannot rot: if adding a machine ever
//! needs an edit outside its folder (a match arm in the engine, a table
//! the engine must be told about), this stops compiling or fails.
//!
//! The toy is a three-axis measuring machine whose points are checked
//! against a reference (its own table, `toy_points`, declared below and
//! registered through `MachinePlugin::tables`): its model says the machine is perfect, so the
//! paired observation is the measured deviation against zero, and the
//! fleet diagnosis has to find what the tests put in the data (a scale
//! error along x).

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{NoKeys, SectionCheck};
use sparkout_pipeline::contracts::plausible::MetresRule;
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{MachinePlugin, Result, Stage, StageContext, StageOutput, StageSpec};

/// The toy's one machine, built in as a plugin's machines are.
const TOY_CMM_TOML: &str = "[machine]\nid = \"toy-cmm\"\nplugin = \"toy\"\ndescription = \"a perfect three-axis measuring machine (test plugin)\"\n";

/// The toy's own table: each reference point, nominal and measured.
pub const TOY_POINTS: TableSchema = TableSchema {
    name: "toy_points",
    columns: &[
        req("point", I32),
        req("x_mm", F64),
        req("y_mm", F64),
        req("z_mm", F64),
        req("mx_mm", F64),
        req("my_mm", F64),
        req("mz_mm", F64),
        opt("t_s", F64),
    ],
    monotonic_t_s: true,
    ranges: &[],
    metres_rule: Some(MetresRule {
        columns: &["x_mm", "y_mm", "z_mm"],
        max_abs_below: 2.5,
    }),
};

pub const OBSERVABLES: [&str; 3] = ["toy_dx", "toy_dy", "toy_dz"];

pub struct ToyPlugin;

impl MachinePlugin for ToyPlugin {
    fn name(&self) -> &'static str {
        "toy"
    }
    fn tables(&self) -> &'static [TableSchema] {
        &[TOY_POINTS]
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["toy_points"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![Arc::new(ObserveStage)]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("toy-cmm", TOY_CMM_TOML)]
    }
    fn observables(&self) -> Vec<&'static str> {
        OBSERVABLES.to_vec()
    }
}

/// `observe`: one row per reference point and axis; real = measured −
/// nominal, sim = 0 (the toy's model is the nominal geometry).
pub struct ObserveStage;

const SPEC: StageSpec = StageSpec {
    name: "observe",
    version: 1,
    reads: &[&TOY_POINTS],
    reads_artifacts: &[],
    writes: &["observations"],
    reads_augmented_model: false,
    about: "paired observations toy_dx/dy/dz (measured vs a perfect machine)",
    config: SectionCheck::of::<NoKeys>(),
};

/// `observe.json`: how many observations the stage wrote.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
}

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let t = ctx.run.require(&TOY_POINTS)?;
        let point = t.i32("point")?;
        let nominal = [t.f64("x_mm")?, t.f64("y_mm")?, t.f64("z_mm")?];
        let measured = [t.f64("mx_mm")?, t.f64("my_mm")?, t.f64("mz_mm")?];
        let n = point.len();
        let mut b = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); 3 * n])
            .str(
                "observable",
                &OBSERVABLES
                    .iter()
                    .flat_map(|o| std::iter::repeat_n(*o, n))
                    .collect::<Vec<_>>(),
            )
            .f64("sim", vec![0.0; 3 * n])
            .f64(
                "real",
                (0..3)
                    .flat_map(|k| (0..n).map(move |i| (k, i)))
                    .map(|(k, i)| measured[k][i] - nominal[k][i])
                    .collect(),
            )
            .i32(
                "point",
                (0..3).flat_map(|_| point.iter().copied()).collect(),
            );
        for (a, name) in ["x_mm", "y_mm", "z_mm"].iter().enumerate() {
            b = b.f64(
                name,
                (0..3).flat_map(|_| nominal[a].iter().copied()).collect(),
            );
        }
        Ok(StageOutput::typed(&ObserveSummary { rows: 3 * n })?.with("observations", b.build()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sparkout_pipeline::contracts::{write_atomic, write_parquet_atomic, MachineResolver};
    use sparkout_pipeline::engine::{Engine, PipelineConfig, Quiet};
    use std::collections::BTreeMap;
    use std::path::Path;

    /// Every plugin of the build plus the toy: the one registration line a
    /// new machine type adds (in `crate::all_plugins` for a real one).
    fn plugins() -> Vec<Arc<dyn MachinePlugin>> {
        let mut p = crate::all_plugins();
        p.push(Arc::new(ToyPlugin));
        p
    }

    /// Runs of the toy whose x axis reads long by 50 µm/m (a scale error),
    /// with 1 µm of measurement noise from a fixed linear congruence.
    fn fleet(root: &Path, runs: usize) {
        let mut state: u64 = 7;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.002
        };
        for r in 0..runs {
            let dir = root.join("toy-cmm").join(format!("r{r:03}"));
            std::fs::create_dir_all(&dir).unwrap();
            let run_toml = format!(
                "[run]\nid = \"r{r:03}\"\nmachine = \"toy-cmm\"\nplugin = \"toy\"\nstarted = \"2026-11-{:02}T02:00:00Z\"\n",
                1 + r
            );
            write_atomic(&dir.join("run.toml"), run_toml.as_bytes()).unwrap();
            let n = 60;
            let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
            for i in 0..n {
                x.push(10.0 * i as f64);
                y.push(37.0 * ((i * 7) % 11) as f64);
                z.push(23.0 * ((i * 3) % 13) as f64);
            }
            let mx: Vec<f64> = x.iter().map(|x| x + 5e-5 * x + noise()).collect();
            let my: Vec<f64> = y.iter().map(|y| y + noise()).collect();
            let mz: Vec<f64> = z.iter().map(|z| z + noise()).collect();
            let b = BatchBuilder::new()
                .i32("point", (0..n).collect())
                .f64("x_mm", x)
                .f64("y_mm", y)
                .f64("z_mm", z)
                .f64("mx_mm", mx)
                .f64("my_mm", my)
                .f64("mz_mm", mz)
                .build();
            write_parquet_atomic(&dir.join("toy_points.parquet"), &b).unwrap();
        }
    }

    /// `[toy.counted]` of the test below: every read of it is counted
    /// (`validate` runs once per read, after serde).
    #[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields, default)]
    struct CountedConfig {
        gain: f64,
        label: String,
    }

    impl Default for CountedConfig {
        fn default() -> Self {
            CountedConfig {
                gain: 2.0,
                label: "plain".into(),
            }
        }
    }

    static COUNTED_READS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    impl sparkout_pipeline::config_check::Section for CountedConfig {
        const CHECKS: &'static [(&'static str, sparkout_pipeline::config_check::Check)] =
            &[("gain", sparkout_pipeline::config_check::Check::Positive)];
        fn validate(&self) -> Result<()> {
            COUNTED_READS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            Ok(())
        }
    }

    /// A stage that reports the gain its typed config holds.
    struct CountedStage;

    /// `counted.json`: the config the stage was given.
    #[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
    struct CountedSummary {
        gain: f64,
        label: String,
    }

    fn counted_summary(out: &Path) -> CountedSummary {
        serde_json::from_slice(&std::fs::read(out.join("toy-cmm/r003/counted.json")).unwrap())
            .unwrap()
    }

    #[test]
    fn summaries_round_trip() {
        crate::typed_summary::round_trip(&ObserveSummary { rows: 180 });
        let c = CountedSummary {
            gain: 2.0,
            label: "plain".into(),
        };
        let v = crate::typed_summary::round_trip(&c);
        assert_eq!(v.to_string(), r#"{"gain":2.0,"label":"plain"}"#);
    }

    const COUNTED: StageSpec = StageSpec {
        name: "counted",
        version: 1,
        reads: &[],
        reads_artifacts: &[],
        writes: &[],
        reads_augmented_model: false,
        about: "reports its config (test stage)",
        config: SectionCheck::of::<CountedConfig>(),
    };

    impl Stage for CountedStage {
        fn spec(&self) -> &'static StageSpec {
            &COUNTED
        }
        fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
            let cfg: &CountedConfig = ctx.section()?;
            StageOutput::typed(&CountedSummary {
                gain: cfg.gain,
                label: cfg.label.clone(),
            })
        }
    }

    /// The toy with the counted stage added (same name, so the toy's runs
    /// are its runs).
    struct CountingToy;

    impl MachinePlugin for CountingToy {
        fn name(&self) -> &'static str {
            "toy"
        }
        fn tables(&self) -> &'static [TableSchema] {
            ToyPlugin.tables()
        }
        fn required_tables(&self) -> Vec<Vec<&'static str>> {
            ToyPlugin.required_tables()
        }
        fn stages(&self) -> Vec<Arc<dyn Stage>> {
            vec![Arc::new(ObserveStage), Arc::new(CountedStage)]
        }
        fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
            ToyPlugin.builtin_machines()
        }
        fn observables(&self) -> Vec<&'static str> {
            ToyPlugin.observables()
        }
    }

    fn counting_engine(sets: &[&str]) -> Engine {
        let mut plugins = crate::all_plugins();
        plugins.push(Arc::new(CountingToy));
        let builtins: BTreeMap<String, String> = plugins
            .iter()
            .flat_map(|p| p.builtin_machines())
            .map(|(id, text)| (id.to_string(), text.to_string()))
            .collect();
        let mut config = PipelineConfig::builtin();
        for s in sets {
            config.set(s).unwrap();
        }
        Engine::new(plugins, MachineResolver::new(None, builtins), config).unwrap()
    }

    /// The `counted` stage's record of every run: (key, cached).
    fn counted_records(outcome: &sparkout_pipeline::engine::FleetOutcome) -> Vec<(String, bool)> {
        outcome
            .runs
            .iter()
            .map(|r| {
                let rec = r.stages.iter().find(|s| s.stage == "counted").unwrap();
                (rec.key.clone(), rec.cached)
            })
            .collect()
    }

    /// The `run` path reads each config section once per batch — when the
    /// engine is built, before any run — however many runs there are; the
    /// stages get the typed value. The cache key hashes the effective
    /// config: the default written out and the default left out are the
    /// same key (the second batch reuses every result), another value is
    /// another key (everything it affects is recomputed).
    #[test]
    fn each_section_is_read_once_per_batch_and_keyed_by_its_effective_config() {
        use std::sync::atomic::Ordering::SeqCst;
        let dir = tempfile::tempdir().unwrap();
        let (input, out) = (dir.path().join("runs"), dir.path().join("out"));
        let runs = 8;
        fleet(&input, runs);

        let before = COUNTED_READS.load(SeqCst);
        let engine = counting_engine(&["toy.counted.gain=2.0", "toy.counted.label=\"plain\""]);
        assert_eq!(
            COUNTED_READS.load(SeqCst),
            before + 1,
            "read once at engine start"
        );
        let first = engine.run_fleet(&input, &out, Some(2), &Quiet).unwrap();
        assert!(first.failures.is_empty(), "{:?}", first.failures);
        assert_eq!(first.runs.len(), runs);
        assert_eq!(
            COUNTED_READS.load(SeqCst),
            before + 1,
            "{runs} runs read no section again"
        );
        assert_eq!(counted_summary(&out).gain, 2.0);
        let written = counted_records(&first);
        assert!(written.iter().all(|(_, cached)| !cached));

        // The same settings with the defaults left out: the same keys.
        let engine = counting_engine(&[]);
        let second = engine.run_fleet(&input, &out, Some(2), &Quiet).unwrap();
        assert_eq!(COUNTED_READS.load(SeqCst), before + 2);
        let omitted = counted_records(&second);
        for ((k1, _), (k2, cached)) in written.iter().zip(&omitted) {
            assert_eq!(k1, k2);
            assert!(cached, "an unchanged effective config reuses the result");
        }

        // Another value: other keys, recomputed.
        let engine = counting_engine(&["toy.counted.gain=3"]);
        let third = engine.run_fleet(&input, &out, Some(2), &Quiet).unwrap();
        assert_eq!(COUNTED_READS.load(SeqCst), before + 3);
        for ((k1, _), (k3, cached)) in written.iter().zip(&counted_records(&third)) {
            assert_ne!(k1, k3);
            assert!(!cached);
        }
        assert_eq!(counted_summary(&out).gain, 3.0);
    }

    #[test]
    fn a_toy_machine_added_by_one_folder_runs_through_the_engine() {
        let dir = tempfile::tempdir().unwrap();
        let (input, out) = (dir.path().join("runs"), dir.path().join("out"));
        fleet(&input, 8);
        let plugins = plugins();
        let builtins: BTreeMap<String, String> = plugins
            .iter()
            .flat_map(|p| p.builtin_machines())
            .map(|(id, text)| (id.to_string(), text.to_string()))
            .collect();
        let engine = Engine::new(
            plugins,
            MachineResolver::new(None, builtins),
            PipelineConfig::builtin(),
        )
        .unwrap();
        let outcome = engine.run_fleet(&input, &out, Some(1), &Quiet).unwrap();
        assert!(outcome.failures.is_empty(), "{:?}", outcome.failures);
        assert_eq!(outcome.runs.len(), 8);
        assert!(out.join("toy-cmm/r000/observations.parquet").is_file());
        let diagnosis: serde_json::Value = serde_json::from_slice(
            &std::fs::read(outcome.diagnosis.as_ref().expect("a fleet diagnosis")).unwrap(),
        )
        .unwrap();
        let text = diagnosis.to_string();
        // The scale error along x is what the diagnosis must name for toy_dx.
        let named = diagnosis["per_observable"]
            .as_array()
            .unwrap()
            .iter()
            .find(|o| o["observable"] == "toy_dx")
            .unwrap_or_else(|| panic!("no toy_dx in {text}"))
            .to_string();
        assert!(named.contains("scale") && named.contains("x_mm"), "{named}");
    }
}
