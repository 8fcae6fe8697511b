//! A per-row column of the diagnosis table held as stretches of equal
//! values.
//!
//! A fleet's observation rows come run by run and, within a run, one
//! observable at a time, so the table's key columns (run unit, machine,
//! observable) and its optional `trial`, `point` and `real_u` hold long
//! stretches of one value — a servo fleet has ≈ 6 stretches per run of
//! ≈ 14 600 rows. Held plainly they were 44 B of every row of the table
//! (≈ 1.3 GB at 2 000 servo runs, the largest part of `aggregate`'s memory
//! beside the observable being diagnosed); held as stretches they are a few
//! hundred kB. A random row is found by bisection ([`RunLength::at`] walks
//! rows of one stretch in O(1)). A table in another order (shuffled,
//! interleaved) has stretches of a row or two; such a column turns into
//! one value per row ([`SHORT_STRETCH`]).

use std::ops::Range;

/// Values a stretch is made of: equal bit for bit (a NaN `real_u` is one
/// value like any other).
pub trait Same: Copy {
    fn same(self, other: Self) -> bool;
}

impl Same for u32 {
    fn same(self, other: u32) -> bool {
        self == other
    }
}

impl Same for i64 {
    fn same(self, other: i64) -> bool {
        self == other
    }
}

impl Same for f64 {
    fn same(self, other: f64) -> bool {
        self.to_bits() == other.to_bits()
    }
}

/// A column of `len()` rows: as stretches (stretch s covers rows
/// `ends[s - 1]..ends[s]` and holds `values[s]`; neighbours differ) while
/// they are long, as one value per row once they are short.
///
/// A table written in another order than run by run — rows shuffled, or
/// interleaved by time across runs, as any writer may — has stretches of a
/// row or two: held as stretches its keys cost 16 B a row and every lookup
/// of a row is a bisection over millions of stretches (the noise floor of a
/// shuffled 7·10⁶-row fleet table took 1.4 s per observable, against 0.01 s
/// sorted). So once the stretches average fewer than [`SHORT_STRETCH`] rows
/// (judged after [`JUDGE_AFTER`] stretches, so a table's first rows do not
/// decide alone), the column turns into plain rows: 4–8 B a row, a lookup
/// an index. The values, and everything read from them, are the same
/// either way.
#[derive(Clone, Debug)]
pub struct RunLength<T> {
    held: Held<T>,
}

#[derive(Clone, Debug)]
enum Held<T> {
    Stretches { ends: Vec<usize>, values: Vec<T> },
    Rows(Vec<T>),
}

/// Stretches shorter than this on average: the column is held as rows.
pub const SHORT_STRETCH: usize = 4;
/// Stretches held before their length is judged.
pub const JUDGE_AFTER: usize = 4096;

impl<T> Default for RunLength<T> {
    fn default() -> RunLength<T> {
        RunLength {
            held: Held::Stretches {
                ends: Vec::new(),
                values: Vec::new(),
            },
        }
    }
}

/// Two columns are equal when their rows are, however they are held.
impl<T: Same> PartialEq for RunLength<T> {
    fn eq(&self, other: &RunLength<T>) -> bool {
        self.len() == other.len()
            && self
                .spans()
                .zip(other.spans())
                .all(|((ra, a), (rb, b))| ra == rb && a.same(b))
    }
}

impl<T: Same> RunLength<T> {
    pub fn new() -> RunLength<T> {
        RunLength::default()
    }

    /// Rows in the column.
    pub fn len(&self) -> usize {
        match &self.held {
            Held::Stretches { ends, .. } => ends.last().copied().unwrap_or(0),
            Held::Rows(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Stretches of equal values in the column.
    pub fn stretches(&self) -> usize {
        match &self.held {
            Held::Stretches { ends, .. } => ends.len(),
            Held::Rows(_) => self.spans().count(),
        }
    }

    /// Whether the column is held as one value per row (its stretches
    /// were short).
    pub fn is_held_as_rows(&self) -> bool {
        matches!(self.held, Held::Rows(_))
    }

    /// Appends one row.
    pub fn push(&mut self, v: T) {
        self.push_n(v, 1);
    }

    /// Appends `n` rows of `v`.
    pub fn push_n(&mut self, v: T, n: usize) {
        if n == 0 {
            return;
        }
        let len = self.len();
        let short = match &mut self.held {
            Held::Rows(rows) => {
                rows.extend(std::iter::repeat_n(v, n));
                false
            }
            Held::Stretches { ends, values } => match (values.last(), ends.last_mut()) {
                (Some(&last), Some(end)) if last.same(v) => {
                    *end += n;
                    false
                }
                _ => {
                    // Judged on the stretches complete before this one.
                    let short = ends.len() >= JUDGE_AFTER && ends.len() * SHORT_STRETCH > len;
                    ends.push(len + n);
                    values.push(v);
                    short
                }
            },
        };
        if short {
            self.held = Held::Rows(self.iter().collect());
        }
    }

    /// Appends `other`'s rows, each value through `f`.
    pub fn extend_mapped<U: Same>(&mut self, other: &RunLength<U>, f: impl Fn(U) -> T) {
        for (rows, v) in other.spans() {
            self.push_n(f(v), rows.len());
        }
    }

    /// The column with every value through `f` (stretches that become
    /// equal merge).
    pub fn map(&self, f: impl Fn(T) -> T) -> RunLength<T> {
        let mut out = RunLength::new();
        out.extend_mapped(self, f);
        out
    }

    fn check_row(&self, i: usize) {
        assert!(i < self.len(), "row {i} of a column of {} rows", self.len());
    }

    /// Row `i`'s value.
    pub fn get(&self, i: usize) -> T {
        self.check_row(i);
        match &self.held {
            Held::Stretches { ends, values } => values[ends.partition_point(|&e| e <= i)],
            Held::Rows(v) => v[i],
        }
    }

    /// The values of `rows`, in their order: held as stretches, a row in
    /// the stretch of the previous one costs a comparison, any other a
    /// bisection.
    pub fn at(&self, rows: &[usize]) -> Vec<T> {
        let (ends, values) = match &self.held {
            Held::Rows(v) => {
                return rows
                    .iter()
                    .map(|&i| {
                        self.check_row(i);
                        v[i]
                    })
                    .collect()
            }
            Held::Stretches { ends, values } => (ends, values),
        };
        let mut out = Vec::with_capacity(rows.len());
        let mut s = usize::MAX;
        for &i in rows {
            let inside =
                s != usize::MAX && i < ends[s] && i >= if s == 0 { 0 } else { ends[s - 1] };
            if !inside {
                self.check_row(i);
                s = ends.partition_point(|&e| e <= i);
            }
            out.push(values[s]);
        }
        out
    }

    /// Each stretch: its rows and value, in row order.
    pub fn spans(&self) -> Spans<'_, T> {
        Spans {
            col: self,
            next: 0,
            start: 0,
        }
    }

    /// Every row's value, in row order.
    pub fn iter(&self) -> impl Iterator<Item = T> + '_ {
        self.spans()
            .flat_map(|(rows, v)| std::iter::repeat_n(v, rows.len()))
    }

    /// The rows whose value passes `keep`, ascending.
    pub fn rows_where(&self, keep: impl Fn(T) -> bool) -> Vec<usize> {
        // Counted first: laid out at its size, not grown (a list as long
        // as an observable's rows, at the gather's peak).
        let n = self
            .spans()
            .filter(|(_, v)| keep(*v))
            .map(|(rows, _)| rows.len())
            .sum();
        let mut out = Vec::with_capacity(n);
        for (rows, v) in self.spans() {
            if keep(v) {
                out.extend(rows);
            }
        }
        out
    }
}

/// [`RunLength::spans`]: maximal stretches of equal values, in row order.
pub struct Spans<'a, T> {
    col: &'a RunLength<T>,
    /// Held as stretches: the next stretch.
    next: usize,
    /// The next stretch's first row.
    start: usize,
}

impl<T: Same> Iterator for Spans<'_, T> {
    type Item = (Range<usize>, T);

    fn next(&mut self) -> Option<(Range<usize>, T)> {
        let (end, v) = match &self.col.held {
            Held::Stretches { ends, values } => {
                let s = self.next;
                if s == ends.len() {
                    return None;
                }
                self.next += 1;
                (ends[s], values[s])
            }
            Held::Rows(rows) => {
                let v = *rows.get(self.start)?;
                let run = rows[self.start..].iter().take_while(|x| x.same(v)).count();
                (self.start + run, v)
            }
        };
        let rows = self.start..end;
        self.start = end;
        Some((rows, v))
    }
}

impl<T: Same> FromIterator<T> for RunLength<T> {
    fn from_iter<I: IntoIterator<Item = T>>(it: I) -> RunLength<T> {
        let mut out = RunLength::new();
        for v in it {
            out.push(v);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretches_hold_every_row() {
        let plain: Vec<u32> = vec![3, 3, 3, 1, 1, 3, 7, 7, 7, 7, 0];
        let c: RunLength<u32> = plain.iter().copied().collect();
        assert_eq!(c.len(), plain.len());
        assert_eq!(c.stretches(), 5);
        assert_eq!(c.iter().collect::<Vec<_>>(), plain);
        for (i, v) in plain.iter().enumerate() {
            assert_eq!(c.get(i), *v);
        }
        // Ascending, descending, repeated and scattered rows alike.
        for rows in [
            vec![0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10],
            vec![10, 9, 4, 4, 0, 6],
            vec![],
        ] {
            let want: Vec<u32> = rows.iter().map(|&i| plain[i]).collect();
            assert_eq!(c.at(&rows), want);
        }
        assert_eq!(c.rows_where(|v| v == 3), vec![0, 1, 2, 5]);
        // Renumbering merges stretches that become equal.
        let m = c.map(|v| if v == 1 { 3 } else { v });
        assert_eq!(m.stretches(), 3);
        assert_eq!(
            m.iter().collect::<Vec<_>>(),
            plain
                .iter()
                .map(|&v| if v == 1 { 3 } else { v })
                .collect::<Vec<_>>()
        );
        // Appending across a boundary of equal values joins them.
        let mut a: RunLength<u32> = [1, 1].into_iter().collect();
        a.extend_mapped(&c, |v| v - v + 1);
        assert_eq!((a.len(), a.stretches()), (13, 1));
    }

    /// A column of short stretches (a shuffled table's keys) turns into
    /// rows and reads exactly as the plain values; one of long stretches
    /// stays stretches; appending across the switch loses nothing.
    #[test]
    fn short_stretches_are_held_as_rows_and_read_the_same() {
        use rand::{Rng, SeedableRng};
        // Runs of 1–3 equal values, seeded: ≈ 2 rows a stretch.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut plain: Vec<u32> = Vec::new();
        while plain.len() < 5 * JUDGE_AFTER {
            let v: u32 = rng.random_range(0..40);
            let n: usize = rng.random_range(1..=3);
            plain.extend(std::iter::repeat_n(v, n));
        }
        // Built row by row and by stretches of equal values alike.
        let by_row: RunLength<u32> = plain.iter().copied().collect();
        let mut by_stretch = RunLength::new();
        by_stretch.extend_mapped(&by_row, |v| v);
        for c in [&by_row, &by_stretch] {
            assert!(c.is_held_as_rows());
            assert_eq!(c.len(), plain.len());
            assert_eq!(c.iter().collect::<Vec<_>>(), plain);
            let mut want = 0;
            for (rows, v) in c.spans() {
                assert_eq!(rows.start, want, "spans tile the rows");
                assert!(rows.clone().all(|i| plain[i] == v));
                assert!(rows.start == 0 || plain[rows.start - 1] != v, "maximal");
                want = rows.end;
            }
            assert_eq!(want, plain.len());
            let scattered: Vec<usize> = (0..1000)
                .map(|_| rng.random_range(0..plain.len()))
                .collect();
            let want: Vec<u32> = scattered.iter().map(|&i| plain[i]).collect();
            assert_eq!(c.at(&scattered), want);
            assert_eq!(c.get(17), plain[17]);
            assert_eq!(
                c.rows_where(|v| v == 5),
                (0..plain.len())
                    .filter(|&i| plain[i] == 5)
                    .collect::<Vec<_>>()
            );
        }
        assert_eq!(by_row, by_stretch);
        // The same rows held as stretches (never judged: too few) equal.
        let mut few: RunLength<u32> = plain[..100].iter().copied().collect();
        assert!(!few.is_held_as_rows());
        let rows_100 = RunLength {
            held: Held::Rows(plain[..100].to_vec()),
        };
        assert_eq!(few, rows_100);
        // Long stretches stay stretches, however many rows.
        let long: RunLength<u32> = (0..10 * JUDGE_AFTER as u32)
            .flat_map(|v| std::iter::repeat_n(v, SHORT_STRETCH))
            .collect();
        assert!(!long.is_held_as_rows());
        // Appending rows after the switch.
        few.extend_mapped(&by_row, |v| v + 1);
        let mut want: Vec<u32> = plain[..100].to_vec();
        want.extend(plain.iter().map(|v| v + 1));
        assert_eq!(few.iter().collect::<Vec<_>>(), want);
    }

    #[test]
    #[should_panic(expected = "row 7 of a column of 7 rows")]
    fn a_row_past_the_end_of_rows_is_a_bug_said_plainly() {
        let c = RunLength {
            held: Held::Rows(vec![1u32; 7]),
        };
        c.at(&[0, 7]);
    }

    #[test]
    fn nan_is_one_value_and_signed_zeros_two() {
        let c: RunLength<f64> = [f64::NAN, f64::NAN, 0.0, -0.0, 1.0].into_iter().collect();
        assert_eq!(c.stretches(), 4);
        assert!(c.get(1).is_nan());
        assert_eq!(c.get(3).to_bits(), (-0.0f64).to_bits());
    }

    #[test]
    #[should_panic(expected = "row 2 of a column of 2 rows")]
    fn a_row_past_the_end_is_a_bug_said_plainly() {
        let c: RunLength<i64> = [5, 6].into_iter().collect();
        c.get(2);
    }
}
