//! An observable's covariate columns, in memory or in a column file in
//! the output's scratch folder, read a range of rows at a time
//! (docs/design.md §8). Over [`COVARIATES_IN_MEMORY_MAX_BYTES`] an
//! observable's covariates are the largest thing its diagnosis would hold
//! (10 columns of 8 B a row at 4.8·10⁶ rows are 385 MB): in a file, a pass
//! holds the chunk it reads. The same values either way, so the same bits.

use std::borrow::Cow;
use std::fs::File;
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::effect::{CovStats, EffectData};
use crate::{err, Result};

/// Up to this many bytes (rows × covariates × 8 B) an observable's
/// covariates stay in memory; above, they go to a column file when the
/// diagnosis has a scratch folder (a fleet's, a file's diagnosis).
/// `SPARKOUT_COVARIATES_MAX_BYTES` overrides it (0: always to the file).
/// It moves time and memory, never a result.
pub const COVARIATES_IN_MEMORY_MAX_BYTES: usize = 64 << 20;

/// Rows a chunked read of a column file takes at a time.
pub const READ_ROWS: usize = 1 << 18;

/// Rows from which [`Covariates::rows`] reads a file's columns side by
/// side (128 KiB a column): below, a run's rows for the intervals, the
/// reads are too short to be worth a task each.
const PARALLEL_READ_MIN_ROWS: usize = 1 << 14;

/// The budget in force: `default`, or the byte count in the environment
/// variable `var` (a warning and the default when it is not one).
pub fn byte_budget(var: &str, default: usize) -> usize {
    match std::env::var(var) {
        Err(_) => default,
        Ok(v) => v.trim().parse().unwrap_or_else(|_| {
            tracing::warn!("{var}={v:?} is not a byte count: the default {default} is used");
            default
        }),
    }
}

/// [`COVARIATES_IN_MEMORY_MAX_BYTES`] or its override, read once.
pub fn in_memory_budget() -> usize {
    static BUDGET: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *BUDGET.get_or_init(|| {
        byte_budget(
            "SPARKOUT_COVARIATES_MAX_BYTES",
            COVARIATES_IN_MEMORY_MAX_BYTES,
        )
    })
}

/// The covariates of one observable's rows (in the gather's order): names,
/// constants, and values wherever they are held.
pub struct Covariates {
    n: usize,
    names: Vec<String>,
    stats: Vec<CovStats>,
    store: Store,
}

enum Store {
    Memory(Vec<Vec<f64>>),
    /// Covariate j is the file's column `at[j]`.
    File {
        file: ColumnFile,
        at: Vec<usize>,
    },
}

impl Covariates {
    /// Columns held in memory, each with its constants (computed in
    /// parallel); every column has `n` values.
    pub fn in_memory(n: usize, cols: Vec<(String, Vec<f64>)>) -> Covariates {
        let stats = cols
            .par_iter()
            .map(|(_, v)| CovStats::from_values(v))
            .collect();
        Covariates::held(n, cols, stats)
    }

    /// Columns held in memory with their constants already known.
    pub fn held(n: usize, cols: Vec<(String, Vec<f64>)>, stats: Vec<CovStats>) -> Covariates {
        for (c, v) in &cols {
            assert_eq!(v.len(), n, "covariate {c}: a value per row");
        }
        let (names, values) = cols.into_iter().unzip();
        Covariates {
            n,
            names,
            stats,
            store: Store::Memory(values),
        }
    }

    /// The columns `at` of a column file of `n` rows, named `names`, with
    /// their constants.
    pub fn in_file(
        n: usize,
        file: ColumnFile,
        at: Vec<usize>,
        names: Vec<String>,
        stats: Vec<CovStats>,
    ) -> Covariates {
        assert_eq!(file.rows, n, "the file holds the rows");
        Covariates {
            n,
            names,
            stats,
            store: Store::File { file, at },
        }
    }

    /// No covariates over `n` rows.
    pub fn none(n: usize) -> Covariates {
        Covariates::held(n, Vec::new(), Vec::new())
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// The covariates, in the gather's (name) order.
    pub fn names(&self) -> &[String] {
        &self.names
    }
    pub fn contains(&self, name: &str) -> bool {
        self.names.iter().any(|n| n == name)
    }
    /// Each covariate's constants.
    pub fn frames(&self) -> impl Iterator<Item = (&String, CovStats)> {
        self.names.iter().zip(self.stats.iter().copied())
    }
    /// Whether the values are in a file (read per chunk).
    pub fn in_a_file(&self) -> bool {
        matches!(self.store, Store::File { .. })
    }

    fn index(&self, name: &str) -> Result<usize> {
        self.names
            .iter()
            .position(|n| n == name)
            .ok_or_else(|| err!("effect needs covariate `{name}`, which the data lack"))
    }

    /// The rows `ranges` (one after another) of the covariates `names`:
    /// views of columns in memory when one range is asked, else copies.
    pub fn rows(&self, names: &[String], ranges: &[Range<usize>]) -> Result<CovRows<'_>> {
        let n: usize = ranges.iter().map(|r| r.len()).sum();
        let column = |c: &String| -> Result<(String, Cow<'_, [f64]>)> {
            let j = self.index(c)?;
            let v: Cow<'_, [f64]> = match &self.store {
                Store::Memory(values) => match ranges {
                    [r] => Cow::Borrowed(&values[j][r.clone()]),
                    _ => {
                        let mut v = Vec::with_capacity(n);
                        for r in ranges {
                            v.extend_from_slice(&values[j][r.clone()]);
                        }
                        Cow::Owned(v)
                    }
                },
                Store::File { file, at } => {
                    let mut v = Vec::with_capacity(n);
                    for r in coalesced(ranges) {
                        file.read_into(at[j], r, &mut v)?;
                    }
                    Cow::Owned(v)
                }
            };
            Ok((c.clone(), v))
        };
        // A pass's chunk read from a file: its columns side by side
        // (positioned reads, no shared cursor) — the chunk is made while
        // the candidates wait, so a second core reading halves the wait.
        let cols = if matches!(self.store, Store::File { .. }) && n >= PARALLEL_READ_MIN_ROWS {
            names
                .par_iter()
                .with_max_len(1)
                .map(column)
                .collect::<Result<_>>()?
        } else {
            names.iter().map(column).collect::<Result<_>>()?
        };
        Ok(CovRows { n, cols })
    }

    /// The rows `ranges` of the covariates `names` without a copy where
    /// they are in memory, and where each range's rows are in them: in
    /// memory, views of the whole columns (each range where it is in the
    /// table); from a file, the ranges read one after another
    /// ([`Covariates::rows`]). A fold group's units are scattered over the
    /// table: copying their covariates together for every chunk of every
    /// pass made an in-memory diagnosis ≈ 10 % slower (docs/design.md §8).
    pub fn rows_in_place(
        &self,
        names: &[String],
        ranges: &[Range<usize>],
    ) -> Result<(CovRows<'_>, Vec<Range<usize>>)> {
        match &self.store {
            Store::Memory(_) => Ok((self.rows_of(names, 0..self.n)?, ranges.to_vec())),
            Store::File { .. } => {
                let mut at = 0;
                let packed = ranges
                    .iter()
                    .map(|r| {
                        at += r.len();
                        at - r.len()..at
                    })
                    .collect();
                Ok((self.rows(names, ranges)?, packed))
            }
        }
    }

    /// Rows `r` of the covariates `names`.
    pub fn rows_of(&self, names: &[String], r: Range<usize>) -> Result<CovRows<'_>> {
        self.rows(names, std::slice::from_ref(&r))
    }

    /// Every row of the covariates `names` (a step that needs whole
    /// columns: a plugin effect's fit, the fallbacks).
    pub fn columns(&self, names: &[String]) -> Result<CovRows<'_>> {
        self.rows_of(names, 0..self.n)
    }

    /// Every row of the covariates, rows `r` of each.
    pub fn all_rows(&self, ranges: &[Range<usize>]) -> Result<CovRows<'_>> {
        self.rows(&self.names, ranges)
    }

    /// One covariate's whole column.
    pub fn column(&self, name: &str) -> Result<Cow<'_, [f64]>> {
        let j = self.index(name)?;
        Ok(match &self.store {
            Store::Memory(values) => Cow::Borrowed(&values[j]),
            Store::File { file, at } => {
                let mut v = Vec::with_capacity(self.n);
                file.read_into(at[j], 0..self.n, &mut v)?;
                Cow::Owned(v)
            }
        })
    }

    /// Calls `f(rows, their covariates names)` over every row, a chunk of
    /// [`READ_ROWS`] at a time from a file, at once (views) from memory.
    pub fn chunked(
        &self,
        names: &[String],
        mut f: impl FnMut(Range<usize>, &CovRows) -> Result<()>,
    ) -> Result<()> {
        let step = if self.in_a_file() {
            READ_ROWS
        } else {
            self.n.max(1)
        };
        let mut start = 0;
        while start < self.n {
            let end = (start + step).min(self.n);
            f(start..end, &self.rows_of(names, start..end)?)?;
            start = end;
        }
        Ok(())
    }

    /// Each covariate's values at the sorted positions `at`.
    pub fn at(&self, at: &[usize]) -> Result<Vec<(String, Vec<f64>)>> {
        self.names
            .iter()
            .map(|c| {
                let mut out = Vec::with_capacity(at.len());
                self.chunked(std::slice::from_ref(c), |rows, x| {
                    let v = x.col(c).expect("read");
                    let lo = at.partition_point(|&p| p < rows.start);
                    let hi = at.partition_point(|&p| p < rows.end);
                    out.extend(at[lo..hi].iter().map(|&p| v[p - rows.start]));
                    Ok(())
                })?;
                Ok((c.clone(), out))
            })
            .collect()
    }

    /// The covariates of the rows other than the sorted positions `drop`,
    /// their constants again: in place when in memory, else written to a
    /// new column file in `dir` a chunk at a time (this one's is removed
    /// when it is dropped). A column whose every dropped value keeps a copy
    /// among the kept rows keeps its distinct values, so its constants are
    /// the ones it had ([`DroppedCopies`]): no sort of the column again.
    pub fn without_rows(self, drop: &[usize], dir: Option<&Path>) -> Result<Covariates> {
        let Covariates {
            n: before,
            names,
            store,
            stats,
        } = self;
        let n = before - drop.len();
        match store {
            Store::Memory(values) => {
                let (cols, stats): (Vec<(String, Vec<f64>)>, Vec<CovStats>) = names
                    .into_iter()
                    .zip(values)
                    .zip(stats)
                    .collect::<Vec<_>>()
                    .into_par_iter()
                    .map(|((c, mut v), st)| {
                        let mut copies = DroppedCopies::of(drop.iter().map(|&p| v[p]));
                        copies.count(&v);
                        retain_positions(&mut v, drop);
                        // The runs' spans as gathered: trimming isolated
                        // spikes leaves the runs as long as they were.
                        let st = if copies.all_kept() {
                            st
                        } else {
                            CovStats::from_values(&v).with_run_span(st.run_span)
                        };
                        ((c, v), st)
                    })
                    .collect::<Vec<_>>()
                    .into_iter()
                    .unzip();
                Ok(Covariates::held(n, cols, stats))
            }
            Store::File { file, at } => {
                let dir = dir.map(Path::to_path_buf).unwrap_or_else(|| file.dir());
                let out = ColumnFile::create(&dir, n, at.len())?;
                // A column at a time, the columns side by side (positioned
                // reads and writes of one file: no shared cursor).
                let kept: Vec<bool> = at
                    .par_iter()
                    .enumerate()
                    .with_max_len(1)
                    .map(|(k, &col)| -> Result<bool> {
                        let mut buf = Vec::new();
                        let mut dropped = Vec::with_capacity(drop.len());
                        for &p in drop {
                            buf.clear();
                            file.read_into(col, p..p + 1, &mut buf)?;
                            dropped.push(buf[0]);
                        }
                        let mut copies = DroppedCopies::of(dropped.into_iter());
                        let (mut start, mut written) = (0, 0);
                        while start < before {
                            let end = (start + READ_ROWS).min(before);
                            buf.clear();
                            file.read_into(col, start..end, &mut buf)?;
                            copies.count(&buf);
                            let lo = drop.partition_point(|&p| p < start);
                            let hi = drop.partition_point(|&p| p < end);
                            let local: Vec<usize> =
                                drop[lo..hi].iter().map(|p| p - start).collect();
                            retain_positions(&mut buf, &local);
                            out.write(k, written, &buf)?;
                            written += buf.len();
                            start = end;
                        }
                        Ok(copies.all_kept())
                    })
                    .collect::<Result<_>>()?;
                // The old file goes before the new one's constants are
                // taken.
                std::mem::drop(file);
                let again: Vec<usize> = (0..at.len()).filter(|&k| !kept[k]).collect();
                let mut fresh = out.stats(&again)?.into_iter();
                let stats = stats
                    .into_iter()
                    .zip(kept)
                    .map(|(st, kept)| {
                        if kept {
                            st
                        } else {
                            fresh
                                .next()
                                .expect("a fresh constant per column sorted again")
                                .with_run_span(st.run_span)
                        }
                    })
                    .collect();
                let at: Vec<usize> = (0..at.len()).collect();
                Ok(Covariates::in_file(n, out, at, names, stats))
            }
        }
    }
}

/// The values a trim drops from a column, each with how many times it is
/// dropped and how many times the column holds it (bit for bit). When
/// every one is held more times than dropped, the kept rows have the same
/// distinct values as the column — the same minimum, maximum and
/// spacings, so the same constants (`CovStats`: a duplicate's spacing is
/// zero, never counted) — and the column need not be sorted again. A trim
/// drops a few isolated spikes, and a fleet's covariates (positions,
/// times, commands of the same programs run after run) repeat values.
struct DroppedCopies {
    /// Total-order keys of the dropped values, ascending, distinct.
    keys: Vec<u64>,
    dropped: Vec<usize>,
    held: Vec<usize>,
    /// Keys not yet held more times than dropped: counting stops at 0.
    short: usize,
}

impl DroppedCopies {
    fn of(values: impl Iterator<Item = f64>) -> DroppedCopies {
        let mut all: Vec<u64> = values.map(crate::effect::total_order_key).collect();
        all.sort_unstable();
        let (mut keys, mut dropped) = (Vec::new(), Vec::new());
        for k in all {
            if keys.last() == Some(&k) {
                *dropped.last_mut().expect("a count per key") += 1;
            } else {
                keys.push(k);
                dropped.push(1);
            }
        }
        let held = vec![0; keys.len()];
        DroppedCopies {
            short: keys.len(),
            keys,
            dropped,
            held,
        }
    }

    /// Counts the dropped values among `values` (a piece of the column),
    /// until every one is known to keep a copy.
    fn count(&mut self, values: &[f64]) {
        let (Some(&lo), Some(&hi)) = (self.keys.first(), self.keys.last()) else {
            return;
        };
        for &v in values {
            if self.short == 0 {
                return;
            }
            let k = crate::effect::total_order_key(v);
            if k < lo || k > hi {
                continue;
            }
            if let Ok(i) = self.keys.binary_search(&k) {
                self.held[i] += 1;
                if self.held[i] == self.dropped[i] + 1 {
                    self.short -= 1;
                }
            }
        }
    }

    /// Whether every dropped value keeps a copy.
    fn all_kept(&self) -> bool {
        self.short == 0
    }
}

/// Removes the elements at `drop` (positions, sorted ascending) in place.
pub(crate) fn retain_positions<T>(v: &mut Vec<T>, drop: &[usize]) {
    let mut next = drop.iter().peekable();
    let mut i = 0;
    v.retain(|_| {
        let gone = next.next_if_eq(&&i).is_some();
        i += 1;
        !gone
    });
}

/// Adjacent ranges joined (one read instead of several).
fn coalesced(ranges: &[Range<usize>]) -> Vec<Range<usize>> {
    let mut out: Vec<Range<usize>> = Vec::with_capacity(ranges.len());
    for r in ranges {
        match out.last_mut() {
            Some(last) if last.end == r.start => last.end = r.end,
            _ => out.push(r.clone()),
        }
    }
    out
}

/// Some rows of some covariates, one after another: borrowed or read.
pub struct CovRows<'a> {
    n: usize,
    cols: Vec<(String, Cow<'a, [f64]>)>,
}

impl CovRows<'_> {
    /// The rows as an effect reads them (views).
    pub fn data(&self) -> EffectData<'_> {
        let mut d = EffectData::new(self.n);
        for (c, v) in &self.cols {
            d.push(c, v);
        }
        d
    }
    pub fn len(&self) -> usize {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    pub fn col(&self, name: &str) -> Option<&[f64]> {
        self.cols.iter().find(|(n, _)| n == name).map(|(_, v)| &**v)
    }
}

/// A scratch file of `cols` columns of `rows` f64 each, column after
/// column (native byte order: it lives as long as the process that wrote
/// it); removed when dropped.
pub struct ColumnFile {
    file: File,
    path: PathBuf,
    rows: usize,
}

impl Drop for ColumnFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

impl ColumnFile {
    /// A new file in `dir` (created when missing), sized for its columns.
    pub fn create(dir: &Path, rows: usize, cols: usize) -> Result<ColumnFile> {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        std::fs::create_dir_all(dir)?;
        let path = dir.join(format!(
            "covariates-{}-{}.f64",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|e| err!("{}: {e}", path.display()))?;
        file.set_len((rows * cols * 8) as u64)?;
        Ok(ColumnFile { file, path, rows })
    }

    fn dir(&self) -> PathBuf {
        self.path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default()
    }

    fn offset(&self, col: usize, row: usize) -> u64 {
        ((col * self.rows + row) * 8) as u64
    }

    /// Writes `v` to column `col` from row `start`.
    pub fn write(&self, col: usize, start: usize, v: &[f64]) -> Result<()> {
        assert!(start + v.len() <= self.rows, "inside the column");
        self.file
            .write_all_at(bytemuck::cast_slice(v), self.offset(col, start))
            .map_err(|e| err!("{}: {e}", self.path.display()))
    }

    /// Appends rows `r` of column `col` to `out`.
    pub fn read_into(&self, col: usize, r: Range<usize>, out: &mut Vec<f64>) -> Result<()> {
        assert!(r.end <= self.rows, "inside the column");
        let at = out.len();
        out.resize(at + r.len(), 0.0);
        self.file
            .read_exact_at(
                bytemuck::cast_slice_mut(&mut out[at..]),
                self.offset(col, r.start),
            )
            .map_err(|e| err!("{}: {e}", self.path.display()))
    }

    /// Column `col` whole.
    pub fn column(&self, col: usize) -> Result<Vec<f64>> {
        let mut v = Vec::with_capacity(self.rows);
        self.read_into(col, 0..self.rows, &mut v)?;
        Ok(v)
    }

    /// The constants of the columns `cols`, each read whole and sorted in
    /// place ([`CovStats::from_values_in_place`]); two at a time (one per
    /// core), not all at once.
    pub fn stats(&self, cols: &[usize]) -> Result<Vec<CovStats>> {
        cols.par_iter()
            .with_max_len(1)
            .map(|&c| Ok(CovStats::from_values_in_place(&mut self.column(c)?)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn columns(n: usize) -> Vec<(String, Vec<f64>)> {
        ["a_mm", "b_s", "c"]
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let v = (0..n)
                    .map(|i| ((i * (7 + k) * 7919) % 1013) as f64 * 0.01 - k as f64)
                    .collect();
                (c.to_string(), v)
            })
            .collect()
    }

    fn in_file(dir: &Path, n: usize) -> Covariates {
        let cols = columns(n);
        // Written in two chunks, out of order, with a column of no use
        // first: the file's columns are not the covariates' order.
        let f = ColumnFile::create(dir, n, cols.len() + 1).unwrap();
        for (k, (_, v)) in cols.iter().enumerate() {
            f.write(k + 1, n / 2, &v[n / 2..]).unwrap();
            f.write(k + 1, 0, &v[..n / 2]).unwrap();
        }
        let at: Vec<usize> = (1..=cols.len()).collect();
        let stats = f.stats(&at).unwrap();
        Covariates::in_file(n, f, at, cols.into_iter().map(|c| c.0).collect(), stats)
    }

    #[test]
    fn a_column_file_reads_what_memory_holds() {
        let dir = tempfile::tempdir().unwrap();
        let n = READ_ROWS + 1234;
        let mem = Covariates::in_memory(n, columns(n));
        let file = in_file(dir.path(), n);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let stat_bits = |c: &Covariates| -> Vec<[u64; 4]> {
            c.frames()
                .map(|(_, s)| [s.min, s.max, s.step, s.max_abs].map(f64::to_bits))
                .collect()
        };
        assert_eq!(stat_bits(&file), stat_bits(&mem));
        let names: Vec<String> = vec!["c".into(), "a_mm".into()];
        let ranges = [5..9, 9..20, 100..100, READ_ROWS - 3..READ_ROWS + 40, 7..8];
        let (m, f) = (
            mem.rows(&names, &ranges).unwrap(),
            file.rows(&names, &ranges).unwrap(),
        );
        assert_eq!(m.len(), 4 + 11 + 43 + 1);
        for c in &names {
            assert_eq!(bits(m.col(c).unwrap()), bits(f.col(c).unwrap()));
        }
        assert!(file.rows_of(&["nope".into()], 0..3).is_err());
        let at = [0, 3, READ_ROWS - 1, READ_ROWS, n - 1];
        let (ma, fa) = (mem.at(&at).unwrap(), file.at(&at).unwrap());
        assert_eq!(ma.len(), 3);
        for ((_, a), (_, b)) in ma.iter().zip(&fa) {
            assert_eq!(bits(a), bits(b));
        }
        // Rows taken out: the same columns and constants both ways, and
        // the first file goes when its covariates do.
        let drop = [1, 2, 500, READ_ROWS - 1, READ_ROWS, n - 1];
        let (mk, fk) = (
            mem.without_rows(&drop, None).unwrap(),
            file.without_rows(&drop, None).unwrap(),
        );
        assert_eq!(fk.len(), n - drop.len());
        assert_eq!(stat_bits(&fk), stat_bits(&mk));
        for c in mk.names() {
            assert_eq!(bits(&mk.column(c).unwrap()), bits(&fk.column(c).unwrap()));
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        std::mem::drop(fk);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    /// After a trim each column's constants are those of its kept values,
    /// whether they are carried over (every dropped value keeps a copy) or
    /// taken again (a dropped value was the only one: the minimum, or an
    /// interior value whose spacings merge), in memory and in a file.
    #[test]
    fn constants_after_a_trim_are_the_kept_values_constants() {
        let n = 2 * READ_ROWS + 100;
        // Column "rep": values 0..50 over and over (every value has
        // copies). Column "minimum": as "rep" but row 7 holds the only -3.
        // Column "interior": as "rep" but row 9 holds the only 20.5
        // (between 20 and 21: two spacings of 0.5 that merge into 1).
        let rep: Vec<f64> = (0..n).map(|i| (i % 50) as f64).collect();
        let mut minimum = rep.clone();
        minimum[7] = -3.0;
        let mut interior = rep.clone();
        interior[9] = 20.5;
        let cols = vec![
            ("interior".to_string(), interior),
            ("minimum".to_string(), minimum),
            ("rep".to_string(), rep),
        ];
        let drop = [7, 9, READ_ROWS + 1, n - 1];
        let dir = tempfile::tempdir().unwrap();
        let mem = Covariates::in_memory(n, cols.clone());
        let file = {
            let f = ColumnFile::create(dir.path(), n, cols.len()).unwrap();
            for (k, (_, v)) in cols.iter().enumerate() {
                f.write(k, 0, v).unwrap();
            }
            let at: Vec<usize> = (0..cols.len()).collect();
            let stats = f.stats(&at).unwrap();
            Covariates::in_file(n, f, at, cols.iter().map(|c| c.0.clone()).collect(), stats)
        };
        for trimmed in [
            mem.without_rows(&drop, None).unwrap(),
            file.without_rows(&drop, None).unwrap(),
        ] {
            for (name, st) in trimmed.frames() {
                let kept = trimmed.column(name).unwrap();
                assert_eq!(st, CovStats::from_values(&kept), "{name}");
            }
            let st: Vec<CovStats> = trimmed.frames().map(|(_, s)| s).collect();
            assert_eq!((st[0].step, st[1].min, st[2].min), (1.0, 0.0, 0.0));
        }
        // Before the trim the minimum was there; only "rep" keeps a copy of
        // every dropped value (its constants carried over).
        let before: Vec<CovStats> = Covariates::in_memory(n, cols.clone())
            .frames()
            .map(|(_, s)| s)
            .collect();
        assert_eq!(before[1].min, -3.0);
        let kept: Vec<bool> = cols
            .iter()
            .map(|(_, v)| {
                let mut copies = DroppedCopies::of(drop.iter().map(|&p| v[p]));
                copies.count(v);
                copies.all_kept()
            })
            .collect();
        assert_eq!(kept, [false, false, true]);
    }

    #[test]
    fn adjacent_ranges_are_read_at_once() {
        assert_eq!(
            coalesced(&[0..3, 3..5, 7..9, 9..9, 9..12]),
            vec![0..5, 7..12]
        );
    }
}
