//! AE streaming: the acoustic-emission signal, written in batches. (Part of the robot generator; see mod.rs.)

use super::*;

// AE streaming

#[derive(Debug, Clone)]
pub(super) struct AeWindow {
    pub(super) n0: u64,
    pub(super) n1: u64,
    pub(super) onset_s: f64,
    pub(super) amp_v: f64,
    pub(super) carrier_hz: f64,
    pub(super) phase: f64,
}

pub(super) struct AeBatches {
    pub(super) windows: Vec<AeWindow>,
    pub(super) wi: usize,
    pub(super) n: u64,
    pub(super) fs: f64,
    pub(super) noise_v: f64,
    pub(super) rng: ChaCha8Rng,
    pub(super) schema: SchemaRef,
}

impl Iterator for AeBatches {
    type Item = sparkout_pipeline::Result<RecordBatch>;
    fn next(&mut self) -> Option<Self::Item> {
        let mut t = Vec::with_capacity(AE_BATCH_ROWS);
        let mut v = Vec::with_capacity(AE_BATCH_ROWS);
        while t.len() < AE_BATCH_ROWS && self.wi < self.windows.len() {
            let w = &self.windows[self.wi];
            if self.n < w.n0 {
                self.n = w.n0;
            }
            let end = w.n1.min(self.n + (AE_BATCH_ROWS - t.len()) as u64);
            let omega = 2.0 * PI * w.carrier_hz;
            for n in self.n..end {
                let ts = n as f64 / self.fs;
                let z = normal(&mut self.rng);
                let dt = ts - w.onset_s;
                let burst = if dt >= 0.0 {
                    w.amp_v
                        * (1.0 - (-dt / AE_TAU_RISE_S).exp())
                        * (-dt / AE_TAU_DECAY_S).exp()
                        * (omega * dt + w.phase).sin()
                } else {
                    0.0
                };
                t.push(ts);
                v.push((self.noise_v * z + burst) as f32);
            }
            self.n = end;
            if self.n >= w.n1 {
                self.wi += 1;
            }
        }
        if t.is_empty() {
            return None;
        }
        Some(
            RecordBatch::try_new(
                self.schema.clone(),
                vec![
                    Arc::new(Float64Array::from(t)),
                    Arc::new(Float32Array::from(v)),
                ],
            )
            .map_err(crate::Error::from),
        )
    }
}

/// One contact of a conditioned RMS log, on the recorder clock.
#[derive(Debug, Clone)]
pub(super) struct RmsContact {
    /// The wheel meets the surface.
    pub(super) onset_s: f64,
    /// The wheel leaves it (retract).
    pub(super) leave_s: f64,
    /// RMS level of the cut, V.
    pub(super) level_v: f64,
}

impl RmsContact {
    /// Share (0‥1) of the cut level at `t` and whether `t` is in the cut
    /// proper (after the entry, before the exit: where drop-outs happen).
    fn shape(&self, t: f64) -> (f64, bool) {
        let dt = t - self.onset_s;
        if dt < 0.0 {
            (0.0, false)
        } else if t < self.leave_s {
            let rise = 1.0 - (-dt / AE_RMS_TAU_RISE_S).exp();
            (rise, dt >= AE_RMS_ENTRY_S)
        } else {
            let rise = 1.0 - (-(self.leave_s - self.onset_s) / AE_RMS_TAU_RISE_S).exp();
            (
                rise * (-(t - self.leave_s) / AE_RMS_TAU_EXIT_S).exp(),
                false,
            )
        }
    }
}

/// A conditioned RMS AE log, recorded continuously from sample 0 to `n_end`:
/// the air level (the sensor noise's RMS) with a log-normal scatter, and at
/// each contact the level rises to the cut's (entry), scatters more and
/// drops out now and then (cut), and decays after the wheel leaves (exit).
/// Always positive, as an RMS is.
pub(super) struct RmsBatches {
    pub(super) contacts: Vec<RmsContact>,
    pub(super) ci: usize,
    pub(super) n: u64,
    pub(super) n_end: u64,
    pub(super) fs: f64,
    pub(super) air_v: f64,
    pub(super) rng: ChaCha8Rng,
    pub(super) schema: SchemaRef,
}

impl Iterator for RmsBatches {
    type Item = sparkout_pipeline::Result<RecordBatch>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.n >= self.n_end {
            return None;
        }
        let end = self.n_end.min(self.n + AE_BATCH_ROWS as u64);
        let mut t = Vec::with_capacity((end - self.n) as usize);
        let mut v = Vec::with_capacity((end - self.n) as usize);
        for n in self.n..end {
            let ts = n as f64 / self.fs;
            // The contact in force: the latest one begun (its exit tail is
            // long gone before the next approach, seconds later).
            while self.ci + 1 < self.contacts.len() && ts >= self.contacts[self.ci + 1].onset_s {
                self.ci += 1;
            }
            let (share, level, in_cut) = match self.contacts.get(self.ci) {
                Some(c) => {
                    let (s, cut) = c.shape(ts);
                    (s, c.level_v, cut)
                }
                None => (0.0, self.air_v, false),
            };
            // Both draws every sample, so the stream stays aligned.
            let z = normal(&mut self.rng);
            let u: f64 = self.rng.random();
            let sigma = AE_RMS_SCATTER_AIR + (AE_RMS_SCATTER_CUT - AE_RMS_SCATTER_AIR) * share;
            let mut x = (self.air_v + (level - self.air_v) * share)
                * (sigma * z - 0.5 * sigma * sigma).exp();
            if in_cut && u < AE_RMS_DROPOUT_P {
                x *= AE_RMS_DROPOUT_FACTOR;
            }
            t.push(ts);
            v.push(x as f32);
        }
        self.n = end;
        Some(
            RecordBatch::try_new(
                self.schema.clone(),
                vec![
                    Arc::new(Float64Array::from(t)),
                    Arc::new(Float32Array::from(v)),
                ],
            )
            .map_err(crate::Error::from),
        )
    }
}
