//! diagnosis.parquet: one row per observation, built a slice at a time
//! as it is written, from the table's ids and the per-row results.

use std::collections::BTreeMap;
use std::fs::File;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch};
use arrow::datatypes::{DataType, Field, Schema};

use crate::observations::Table;
use crate::run_length::RunLength;
use crate::Result;

/// Rows of diagnosis.parquet per batch built and written: the text keys
/// exist for one slice at a time, never for the fleet (docs/scale.md).
pub const PER_ROW_SLICE: usize = 1 << 16;

/// diagnosis.parquet: [machine,] run, observable, gap, contrib_<key>…,
/// residual_after — one row per observation, in input order. Held as the
/// table's ids and the per-row results (in memory, or spilled per
/// observable: [`ResultSpill`]); the rows are built a slice at a time as
/// they are written ([`PerRow::write_parquet`]).
pub struct PerRow {
    /// The keys (ids and names; its row values are gone).
    table: Table,
    /// The selected effects' keys, in selection order.
    keys: Vec<String>,
    results: Results,
    schema: Arc<Schema>,
}

/// Each row's gap, held-out residual and selected effects' contributions.
pub enum Results {
    /// In table order, a column per key (0 on rows of observables the key
    /// was not selected for).
    Memory {
        gap: Vec<f64>,
        residual: Vec<f64>,
        contrib: BTreeMap<String, Vec<f64>>,
    },
    Spilled(ResultSpill),
}

impl PerRow {
    pub(crate) fn new(mut table: Table, keys: &[String], results: Results) -> PerRow {
        table.values = Box::new(crate::observations::InMemory::default());
        table.real_u = None;
        let mut fields = Vec::new();
        if table.has_machine {
            fields.push(Field::new("machine", DataType::Utf8, false));
        }
        fields.extend([
            Field::new("run", DataType::Utf8, false),
            Field::new("observable", DataType::Utf8, false),
            Field::new("gap", DataType::Float64, false),
        ]);
        for k in keys {
            fields.push(Field::new(format!("contrib_{k}"), DataType::Float64, false));
        }
        fields.push(Field::new("residual_after", DataType::Float64, false));
        PerRow {
            table,
            keys: keys.to_vec(),
            results,
            schema: Arc::new(Schema::new(fields)),
        }
    }

    pub fn schema(&self) -> Arc<Schema> {
        self.schema.clone()
    }

    pub fn num_rows(&self) -> usize {
        self.table.n
    }

    /// The rows in slices of [`PER_ROW_SLICE`], in order.
    pub fn batches(&self) -> impl Iterator<Item = Result<RecordBatch>> + '_ {
        self.batches_of(PER_ROW_SLICE)
    }

    /// The rows in slices of `rows` rows, in order.
    pub fn batches_of(&self, rows: usize) -> impl Iterator<Item = Result<RecordBatch>> + '_ {
        let mut cursor = self.cursor();
        (0..self.num_rows()).step_by(rows.max(1)).map(move |at| {
            let r = at..(at + rows.max(1)).min(self.num_rows());
            self.slice(r, cursor.as_mut().map_err(|e| crate::err!("{e:#}"))?)
        })
    }

    /// Every row in one batch (small tables; tests).
    pub fn to_batch(&self) -> Result<RecordBatch> {
        self.slice(0..self.num_rows(), &mut self.cursor()?)
    }

    /// Writes diagnosis.parquet to `path` atomically, a slice at a time.
    pub fn write_parquet(&self, path: &std::path::Path) -> Result<()> {
        // Written while nothing else runs: its columns encode in parallel.
        crate::contracts::write::write_parquet_stream_atomic(
            path,
            self.schema(),
            self.batches(),
            crate::contracts::write::Encoding::ColumnsInParallel,
        )
    }

    fn cursor(&self) -> Result<Cursor> {
        match &self.results {
            Results::Memory { .. } => Ok(Cursor::Memory),
            Results::Spilled(s) => s.cursor(&self.keys),
        }
    }

    /// Rows `r` (the next rows of `cursor`) as a batch.
    fn slice(&self, r: Range<usize>, cursor: &mut Cursor) -> Result<RecordBatch> {
        let rows: Vec<usize> = r.clone().collect();
        let mut cols: Vec<ArrayRef> = Vec::new();
        if self.table.has_machine {
            cols.push(self.table.text_column("machine", &rows));
        }
        cols.push(self.table.text_column("run", &rows));
        cols.push(self.table.text_column("observable", &rows));
        let num = |v: Vec<f64>| Arc::new(Float64Array::from(v)) as ArrayRef;
        match (&self.results, cursor) {
            (
                Results::Memory {
                    gap,
                    residual,
                    contrib,
                },
                _,
            ) => {
                cols.push(num(gap[r.clone()].to_vec()));
                for k in &self.keys {
                    let c = contrib.get(k).expect("a selected key has its column");
                    cols.push(num(c[r.clone()].to_vec()));
                }
                cols.push(num(residual[r].to_vec()));
            }
            (Results::Spilled(_), Cursor::Spilled(c)) => {
                let nk = self.keys.len();
                let mut contrib = vec![Vec::with_capacity(rows.len()); nk];
                let mut gap = Vec::with_capacity(rows.len());
                let mut residual = Vec::with_capacity(rows.len());
                let mut rec = vec![0.0; nk + 2];
                for obs in self.table.obs.at(&rows) {
                    c.next(obs, &mut rec)?;
                    gap.push(rec[0]);
                    residual.push(rec[1]);
                    for (col, v) in contrib.iter_mut().zip(&rec[2..]) {
                        col.push(*v);
                    }
                }
                cols.push(num(gap));
                cols.extend(contrib.into_iter().map(num));
                cols.push(num(residual));
            }
            (Results::Spilled(_), Cursor::Memory) => {
                unreachable!("a spill reads through its cursor")
            }
        }
        Ok(RecordBatch::try_new(self.schema.clone(), cols)?)
    }
}

/// Each observable's per-row results on disk until diagnosis.parquet is
/// written: the fleet-length gap, residual and contribution columns are
/// 8 B a row each (≈ 0.7 GB at 2 000 servo runs). One file per observable
/// in a hidden folder of the output, a record per row in table order —
/// gap, residual, then the observable's own contributions (raw
/// little-endian f64) — read back a row at a time in table order. The
/// folder goes when the spill is dropped.
pub struct ResultSpill {
    dir: PathBuf,
    /// Per observable id: its file and the keys of its contributions, in
    /// record order.
    parts: BTreeMap<u32, (PathBuf, Vec<String>)>,
}

impl ResultSpill {
    /// A spill in `dir` (a previous one there, left by a killed run, is
    /// removed first).
    pub fn create(dir: &Path) -> Result<ResultSpill> {
        if dir.exists() {
            std::fs::remove_dir_all(dir)?;
        }
        std::fs::create_dir_all(dir)?;
        Ok(ResultSpill {
            dir: dir.to_path_buf(),
            parts: BTreeMap::new(),
        })
    }

    /// One observable's results: slot p is table row `rows[p]`, whose
    /// gap is `gap[p]`.
    pub(crate) fn push(
        &mut self,
        obs: u32,
        rows: &[usize],
        gap: &[f64],
        residual: &[f64],
        contrib: &BTreeMap<String, Vec<f64>>,
    ) -> Result<()> {
        use std::io::Write;
        // Written in table-row order. An observable gathered from a table
        // in run order has its slots in that order already: no order list
        // (8 B a row, at the diagnosis' peak) to sort.
        let in_order = rows.windows(2).all(|w| w[0] < w[1]);
        let order: Box<dyn Iterator<Item = usize>> = if in_order {
            Box::new(0..rows.len())
        } else {
            let mut order: Vec<usize> = (0..rows.len()).collect();
            order.sort_unstable_by_key(|&p| rows[p]);
            Box::new(order.into_iter())
        };
        let path = self.dir.join(format!("{obs}.f64"));
        let mut w = std::io::BufWriter::with_capacity(1 << 20, File::create(&path)?);
        let cols: Vec<&Vec<f64>> = contrib.values().collect();
        for p in order {
            w.write_all(&gap[p].to_le_bytes())?;
            w.write_all(&residual[p].to_le_bytes())?;
            for c in &cols {
                w.write_all(&c[p].to_le_bytes())?;
            }
        }
        // Scratch for this process alone: flushed, not synced.
        w.flush()?;
        self.parts
            .insert(obs, (path, contrib.keys().cloned().collect()));
        Ok(())
    }

    /// Σ residual² over every row, in table order (the order the in-memory
    /// column sums in: the same bits).
    pub(crate) fn sum_sq_residual(&self, obs: &RunLength<u32>) -> Result<f64> {
        let mut c = self.spill_cursor(&[])?;
        let mut rec = [0.0; 2];
        let mut s = 0.0;
        for o in obs.iter() {
            c.next(o, &mut rec)?;
            s += rec[1] * rec[1];
        }
        Ok(s)
    }

    fn cursor(&self, keys: &[String]) -> Result<Cursor> {
        Ok(Cursor::Spilled(self.spill_cursor(keys)?))
    }

    fn spill_cursor(&self, keys: &[String]) -> Result<SpillCursor> {
        let mut parts = BTreeMap::new();
        for (&o, (path, own)) in &self.parts {
            let at: Vec<Option<usize>> = keys
                .iter()
                .map(|k| own.iter().position(|x| x == k))
                .collect();
            let r = std::io::BufReader::with_capacity(1 << 20, File::open(path)?);
            parts.insert(o, (r, own.len(), at));
        }
        Ok(SpillCursor {
            parts,
            buf: Vec::new(),
        })
    }
}

impl Drop for ResultSpill {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

enum Cursor {
    Memory,
    Spilled(SpillCursor),
}

/// Reads a spill's records in table order: each observable's file holds
/// its rows in table order, so a row's record is its observable's next.
struct SpillCursor {
    parts: BTreeMap<u32, PartReader>,
    buf: Vec<u8>,
}

/// One observable's file: its reader, the contributions per record, and
/// where each requested key is in the record (None: not selected for it,
/// so 0).
type PartReader = (std::io::BufReader<File>, usize, Vec<Option<usize>>);

impl SpillCursor {
    /// The next row of observable `obs`: `rec[0]` its gap, `rec[1]` its
    /// residual, `rec[2..]` the requested keys' contributions (0 where a
    /// row has none).
    fn next(&mut self, obs: u32, rec: &mut [f64]) -> Result<()> {
        use std::io::Read;
        rec.iter_mut().for_each(|v| *v = 0.0);
        let Some((r, own, at)) = self.parts.get_mut(&obs) else {
            return Ok(());
        };
        self.buf.resize((*own + 2) * 8, 0);
        r.read_exact(&mut self.buf)?;
        let f =
            |j: usize| f64::from_le_bytes(self.buf[j * 8..j * 8 + 8].try_into().expect("8 bytes"));
        rec[0] = f(0);
        rec[1] = f(1);
        for (k, a) in at.iter().enumerate() {
            if let Some(j) = a {
                rec[k + 2] = f(j + 2);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::ResultSpill;
    use std::collections::BTreeMap;

    /// An observable's results are written in table-row order whether its
    /// slots come in that order (a table in run order: no order list) or
    /// not (a shuffled table): the same records either way.
    #[test]
    fn results_are_spilled_in_table_order_whatever_the_slots_order() {
        let dir = tempfile::tempdir().unwrap();
        // Table rows 0..5 of observable 0; slot p holds row rows[p].
        let records = |rows: &[usize]| {
            let gap: Vec<f64> = rows.iter().map(|&r| r as f64).collect();
            let residual: Vec<f64> = rows.iter().map(|&r| 10.0 + r as f64).collect();
            let contrib = BTreeMap::from([(
                "drift:t_s".to_string(),
                rows.iter().map(|&r| 100.0 + r as f64).collect(),
            )]);
            let mut spill = ResultSpill::create(&dir.path().join("r")).unwrap();
            spill.push(0, rows, &gap, &residual, &contrib).unwrap();
            let mut c = spill.spill_cursor(&["drift:t_s".to_string()]).unwrap();
            let mut out = Vec::new();
            for _ in 0..rows.len() {
                let mut rec = [0.0; 3];
                c.next(0, &mut rec).unwrap();
                out.push(rec);
            }
            out
        };
        let want: Vec<[f64; 3]> = (0..5)
            .map(|r| [r as f64, 10.0 + r as f64, 100.0 + r as f64])
            .collect();
        assert_eq!(records(&[0, 1, 2, 3, 4]), want);
        assert_eq!(records(&[3, 0, 4, 1, 2]), want);
    }
}
