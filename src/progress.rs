//! Progress: a bar (indicatif) when stderr is a terminal, plain log lines
//! (tracing) otherwise — nightly batches log to files.

use std::io::IsTerminal;
use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressStyle};
use sparkout_pipeline::engine::Progress;

pub fn init_logging(verbose: u8) {
    let level = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("SPARKOUT_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .without_time()
        .try_init();
}

pub struct BatchProgress {
    bar: Mutex<Option<ProgressBar>>,
    terminal: bool,
}

impl BatchProgress {
    pub fn new() -> Self {
        BatchProgress {
            bar: Mutex::new(None),
            terminal: std::io::stderr().is_terminal(),
        }
    }
    pub fn finish(&self) {
        if let Some(b) = self.bar.lock().expect("bar").take() {
            b.finish_and_clear();
        }
    }
}

impl Progress for BatchProgress {
    fn start(&self, runs: usize) {
        if self.terminal {
            let b = ProgressBar::new(runs as u64);
            b.set_style(
                ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} runs {msg}",
                )
                .expect("template")
                .progress_chars("=> "),
            );
            *self.bar.lock().expect("bar") = Some(b);
        } else {
            tracing::info!("processing {runs} runs");
        }
    }
    fn run_done(&self, label: &str, ok: bool, computed: usize, cached: usize) {
        let line = if ok {
            format!("{label}: ok ({computed} stages computed, {cached} cached)")
        } else {
            format!("{label}: REJECTED (see failures.json)")
        };
        match self.bar.lock().expect("bar").as_ref() {
            Some(b) => {
                b.inc(1);
                b.set_message(label.to_string());
                if !ok {
                    b.println(line);
                }
            }
            None => {
                if ok {
                    tracing::info!("{line}")
                } else {
                    tracing::warn!("{line}")
                }
            }
        }
    }
    fn message(&self, msg: &str) {
        match self.bar.lock().expect("bar").as_ref() {
            Some(b) => b.set_message(msg.to_string()),
            None => tracing::info!("{msg}"),
        }
    }
}
