//! motion.parquet (docs/formats.md §4) as typed columns: the one place that
//! names its columns for a writer, shared by the generators and the replay's
//! record-back.

use arrow::record_batch::RecordBatch;

use super::BatchBuilder;

/// The columns of a motion table: time, commanded X/Y/Z, and the optional
/// actual X/Y/Z, path feed and plan segment.
#[derive(Debug, Clone, Default)]
pub struct MotionColumns {
    pub t_s: Vec<f64>,
    /// Commanded X, Y, Z, mm.
    pub cmd_mm: [Vec<f64>; 3],
    /// Actual (encoder) X, Y, Z, mm, when the machine reports them.
    pub act_mm: Option<[Vec<f64>; 3]>,
    pub feed_mm_s: Option<Vec<f64>>,
    /// Plan segment index, −1 between segments.
    pub segment: Option<Vec<i32>>,
}

impl MotionColumns {
    /// The batch in the contract's column order.
    pub fn into_batch(self) -> RecordBatch {
        let [cx, cy, cz] = self.cmd_mm;
        let mut b = BatchBuilder::new()
            .f64("t_s", self.t_s)
            .f64("cmd_x_mm", cx)
            .f64("cmd_y_mm", cy)
            .f64("cmd_z_mm", cz);
        if let Some([ax, ay, az]) = self.act_mm {
            b = b
                .f64("act_x_mm", ax)
                .f64("act_y_mm", ay)
                .f64("act_z_mm", az);
        }
        if let Some(feed) = self.feed_mm_s {
            b = b.f64("feed_mm_s", feed);
        }
        if let Some(seg) = self.segment {
            b = b.i32("segment", seg);
        }
        b.build()
    }
}
