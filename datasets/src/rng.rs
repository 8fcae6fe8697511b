//! The generators' random numbers, one copy for all of them.
//! Every run draws from its own ChaCha8 stream of the fleet seed, so
//! runs are generated in parallel and still byte-identical for a seed; each
//! generator documents which stream number serves what.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// The ChaCha8 generator of `seed`, on stream `stream`.
pub fn stream_rng(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// A standard normal draw.
pub fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// A uniform draw in [lo, hi).
pub fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// A uniform draw in [−half, half). Not `uniform(rng, -half, half)`: that
/// rounds differently in the last bit, and the robot fleets' bytes are
/// pinned by this form.
pub fn symmetric(rng: &mut ChaCha8Rng, half: f64) -> f64 {
    half * (2.0 * rng.random::<f64>() - 1.0)
}
