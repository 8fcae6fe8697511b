//! Wall time per step, logged at debug level when the work ends: where a
//! night's diagnosis spends its time (a pass over an observable, a round's
//! passes over the rows).

/// Laps of named steps; a step timed twice adds up.
pub(crate) struct StepClock {
    what: String,
    last: std::time::Instant,
    laps: Vec<(&'static str, f64)>,
}

impl StepClock {
    /// A clock for `what` (the log line's start), running from now.
    pub(crate) fn new(what: String) -> StepClock {
        StepClock {
            what,
            last: std::time::Instant::now(),
            laps: Vec::new(),
        }
    }

    /// The time since the last lap (or the start) goes to `step`.
    pub(crate) fn lap(&mut self, step: &'static str) {
        let now = std::time::Instant::now();
        let s = now.duration_since(self.last).as_secs_f64();
        self.last = now;
        match self.laps.iter_mut().find(|(k, _)| *k == step) {
            Some((_, t)) => *t += s,
            None => self.laps.push((step, s)),
        }
    }

    /// Logs the total and each step (debug level).
    pub(crate) fn done(&self) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let total: f64 = self.laps.iter().map(|(_, s)| s).sum();
        let steps: Vec<String> = self
            .laps
            .iter()
            .map(|(k, s)| format!("{k} {s:.2} s"))
            .collect();
        tracing::debug!("{} in {total:.2} s ({})", self.what, steps.join(", "));
    }
}
