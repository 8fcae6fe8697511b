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
            .map_err(anyhow::Error::from),
        )
    }
}
