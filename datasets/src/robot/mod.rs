//! Synthetic robotic-grinding fleet (docs/models.md §1; the data layout is
//! docs/robot_data_spec.md, the tables docs/formats.md §4).
//!
//! Each run is a KUKA-KR16-like cell probing a block with the grinding wheel
//! (acoustic-emission touch detection, docs/models.md §1.1–1.2) in the thesis's
//! pattern (3 faces × 3 concentric squares × 4 points, §1.3), followed by a
//! weld-repair grinding cycle (rough, finish, spark-out, §1.4).
//!
//! Frames. `cmd_*` is the commanded TCP; `act_*` is the TCP the controller
//! measures (joint encoders through the kinematic model), i.e. `cmd` plus
//! servo noise. The *physical* wheel can sit elsewhere: thermal drift and
//! backlash are invisible to motor-side encoders, so they appear as
//! `act − physical`. Contact happens when the physical wheel reaches the true
//! surface; interpolating the motion log at that time therefore gives where
//! the controller believes the contact is — the true surface point when no
//! effect is injected, the true point shifted by the effect otherwise, which
//! is exactly how the effect reaches the `touch_normal` observable.
//!
//! Timing per approach (spec): motion `segment` = plan `seq` from the start
//! of the approach until the robot has stopped; contact `t_c` = the physical
//! wheel reaches the true surface (controller clock); registration
//! `t_r = t_c + latency` (latency 0 unless `trigger_latency` is injected:
//! the effect-free baseline has no catalogue effect at all); the robot keeps
//! moving at approach speed until `t_r`, then decelerates, dwells and
//! retracts. The AE burst starts at `t_c` on the recorder clock
//! (`ae t_s = controller t_s − clock_offset_s`).
//!
//! Observables (docs/robot_data_spec.md; conventions as the robot plugin
//! reads them): a touch's "normal coordinate" is its coordinate on the face's
//! normal axis (z, x, y for `xy`, `yz`, `zx`); `approach_normal_mm_s` = v ×
//! the approach direction's +axis component; `dir` = sign along +axis of the
//! last commanded move before the approach segment (the generator alternates
//! inward legs and outward "reversal" legs at random). Registered touches
//! (probe.parquet) scatter with the AE method's thesis repeatability
//! (σ = range/d2(12), 7.7 µm at 5 mm/s, 26 µm at 10 mm/s); the contact
//! itself scatters by 2 µm (what AE-derived touches see).
//!
//! Determinism: every run draws from its own `ChaCha8Rng` streams keyed by
//! (seed, run index), so the files are byte-identical for a seed whatever
//! the number of rayon threads.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

use crate::generator::{
    fleet_summary, DemoFleet, GenerateOptions, Generated, Generator, Predicted, RunSize,
};
use crate::rng::{normal, stream_rng, symmetric, uniform};
use crate::{bail, Context, Result};
use arrow::array::{Float32Array, Float64Array};
use arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use arrow::record_batch::RecordBatch;
use nalgebra::{Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, write_parquet_batches_atomic,
    BatchBuilder, MotionColumns,
};
use sparkout_pipeline::diagnose::{shape_value, Kind};
use sparkout_pipeline::EffectSpec;

type V3 = Vector3<f64>;

// The generator in its sections, one file each.
mod ae;
mod config;
mod consts;
mod effects;
mod generate;
mod motion;
mod plan;
mod tables;
#[cfg(test)]
mod tests;
mod truth;

use ae::*;
pub use config::*;
use consts::*;
pub use effects::*;
pub use generate::*;
use motion::*;
use plan::*;
use tables::*;
use truth::*;
