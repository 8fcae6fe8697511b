//! The generator registry: every synthetic-data generator
//! implements [`Generator`] and is listed once in [`all_generators`], so
//! `sparkout generate` and `sparkout demo` name no machine. Adding a machine
//! type: its plugin folder, its generator file here, one line in
//! [`all_generators`] (docs/adding-a-plugin.md).

use std::path::{Path, PathBuf};

use crate::{bail, Result};
use sparkout_pipeline::EffectSpec;

/// What `sparkout generate` passes to every generator.
#[derive(Debug, Clone, PartialEq)]
pub struct GenerateOptions {
    pub runs: usize,
    pub seed: u64,
    /// AE sample rate, for generators whose runs carry an AE log.
    pub ae_rate_hz: Option<f64>,
    /// `raw` or `rms` (a conditioned RMS log), for generators whose runs
    /// carry an AE log.
    pub ae_signal: Option<String>,
}

/// The fleet `sparkout demo` makes of one machine type: small enough to run
/// in seconds, with one effect the model lacks, which the plugin's
/// end-to-end test names first at this fleet size.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoFleet {
    pub runs: usize,
    pub seed: u64,
    pub effect: &'static str,
}

/// What a generator wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Generated {
    /// Runs generated.
    pub runs: usize,
    /// The line `sparkout generate` prints.
    pub summary: String,
}

/// Predicted size of a generation: `sparkout generate` refuses one that is
/// too large before writing anything (unless `--force-size`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Predicted {
    /// Bytes written.
    pub write_bytes: u64,
    /// Bytes held in memory at the peak.
    pub peak_memory_bytes: u64,
}

/// The size of one generated run at a generator's defaults, measured (a
/// debug build's `generate NAME --runs 1`: the run directory's bytes, and
/// the peak RSS above that of a `--list-effects` call).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunSize {
    pub disk_bytes: u64,
    pub memory_bytes: u64,
}

impl RunSize {
    /// `runs` runs, each generated whole in memory and written, as many at
    /// a time as the thread pool has threads.
    pub fn fleet(self, runs: usize) -> Predicted {
        let at_once = runs.min(rayon::current_num_threads()).max(1) as u64;
        Predicted {
            write_bytes: self.disk_bytes.saturating_mul(runs as u64),
            peak_memory_bytes: self.memory_bytes.saturating_mul(at_once),
        }
    }
}

/// A synthetic-data generator: a plugin's forward model with injected
/// effects and noise, seeded and deterministic.
pub trait Generator: Send + Sync {
    /// What `sparkout generate NAME` takes: the plugin's name for a machine
    /// type.
    fn name(&self) -> &'static str;
    /// The effects it can inject: (name, what it does).
    fn known_effects(&self) -> Vec<(&'static str, &'static str)>;
    /// `--list-effects`: one line per effect.
    fn effects_listing(&self) -> String {
        let fx = self.known_effects();
        let w = fx
            .iter()
            .map(|(n, _)| n.len() + 2)
            .max()
            .unwrap_or(0)
            .max(18);
        fx.iter()
            .map(|(name, about)| format!("{name:w$} {about}\n"))
            .collect()
    }
    /// What generating with `opts` would write and hold, predicted from
    /// the options alone (nothing is generated).
    fn predicted_size(&self, opts: &GenerateOptions) -> Predicted;
    /// Generate into `out` (a fleet root, or a file for non-fleet data).
    fn generate(
        &self,
        out: &Path,
        opts: &GenerateOptions,
        effects: &[EffectSpec],
    ) -> Result<Generated>;
    /// Writes one table (a .parquet file) rather than a fleet of run
    /// directories: `generate` then refuses an existing file.
    fn writes_file(&self) -> bool {
        false
    }
    /// Its fleet in `sparkout demo`; `None` keeps it out of the demo.
    fn demo(&self) -> Option<DemoFleet> {
        None
    }
    /// Generate the demo fleet under `root` with `effects`.
    fn generate_demo(&self, root: &Path, effects: &[EffectSpec]) -> Result<Generated> {
        let Some(d) = self.demo() else {
            bail!("`{}` has no demo fleet", self.name());
        };
        let opts = GenerateOptions {
            runs: d.runs,
            seed: d.seed,
            ae_rate_hz: None,
            ae_signal: None,
        };
        self.generate(root, &opts, effects)
    }
}

/// A fleet generator described as data: most machine types need no more
/// than their name, effects list, fleet function and a config sized by
/// `--runs`/`--seed` (defaults for the rest). `--ae-rate-hz` is refused.
pub struct FleetGenerator<C: 'static> {
    pub name: &'static str,
    pub known_effects: fn() -> Vec<(&'static str, &'static str)>,
    /// The fleet config for `runs` runs from `seed`.
    pub config: fn(usize, u64) -> C,
    pub generate_fleet: fn(&Path, &C, &[EffectSpec]) -> Result<Vec<PathBuf>>,
    pub demo: Option<DemoFleet>,
    /// One run at the defaults (the options change only the run count).
    pub run_size: RunSize,
}

impl<C: 'static> Generator for FleetGenerator<C> {
    fn name(&self) -> &'static str {
        self.name
    }
    fn known_effects(&self) -> Vec<(&'static str, &'static str)> {
        (self.known_effects)()
    }
    fn predicted_size(&self, opts: &GenerateOptions) -> Predicted {
        self.run_size.fleet(opts.runs)
    }
    fn generate(&self, out: &Path, opts: &GenerateOptions, fx: &[EffectSpec]) -> Result<Generated> {
        no_ae_rate(self.name, opts)?;
        let dirs = (self.generate_fleet)(out, &(self.config)(opts.runs, opts.seed), fx)?;
        Ok(fleet_summary(self.name, dirs.len(), out))
    }
    fn demo(&self) -> Option<DemoFleet> {
        self.demo.clone()
    }
}

/// Refuse `--ae-rate-hz` for a generator whose runs have no AE log.
pub fn no_ae_rate(name: &str, opts: &GenerateOptions) -> Result<()> {
    if opts.ae_rate_hz.is_some() {
        bail!("--ae-rate-hz applies to runs with an AE log only (a {name} run has none)");
    }
    if opts.ae_signal.is_some() {
        bail!("--ae-signal applies to runs with an AE log only (a {name} run has none)");
    }
    Ok(())
}

/// The summary line of a fleet generator.
pub fn fleet_summary(name: &str, dirs: usize, out: &Path) -> Generated {
    Generated {
        runs: dirs,
        summary: format!("generated {dirs} {name} runs under {}", out.display()),
    }
}

/// Test support: every `truth.json` under `root` reads back through `T`,
/// the generator's truth type, and writes back every field it holds.
/// Returns how many were read.
#[cfg(test)]
pub(crate) fn truth_files_round_trip<T>(root: &Path) -> usize
where
    T: serde::de::DeserializeOwned + serde::Serialize,
{
    fn walk(d: &Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.file_name().is_some_and(|n| n == "truth.json") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(root, &mut files);
    for f in &files {
        let bytes = std::fs::read(f).unwrap();
        let t: T = sparkout_pipeline::files::json::parse_json(f, &bytes)
            .unwrap_or_else(|e| panic!("truth.json does not read back through its type: {e}"));
        assert_eq!(
            sparkout_pipeline::files::json::reads_back_whole(&t, &bytes),
            None,
            "{}",
            f.display()
        );
    }
    files.len()
}

#[cfg(test)]
mod tests {
    use crate::{all_generators, generator};

    #[test]
    fn generator_names_are_unique_and_list_effects() {
        let g = all_generators();
        let mut names: Vec<&str> = g.iter().map(|g| g.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), g.len());
        for g in &g {
            assert!(!g.effects_listing().is_empty(), "{}", g.name());
        }
        assert!(generator("robot").is_some_and(|g| g.demo().is_some()));
        assert!(generator("nope").is_none());
    }
}
