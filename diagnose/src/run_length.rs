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
//! hundred kB. The price: a column whose value changes on every row costs
//! 16 B a row (an end and a value) instead of its 4–8 B, and a random row
//! is found by bisection ([`RunLength::at`] walks ascending rows in O(1)).

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

/// A column of `len()` rows as stretches: stretch s covers rows
/// `ends[s - 1]..ends[s]` and holds `values[s]`; neighbours differ.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunLength<T> {
    ends: Vec<usize>,
    values: Vec<T>,
}

impl<T: Same> RunLength<T> {
    pub fn new() -> RunLength<T> {
        RunLength {
            ends: Vec::new(),
            values: Vec::new(),
        }
    }

    /// Rows in the column.
    pub fn len(&self) -> usize {
        self.ends.last().copied().unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.ends.is_empty()
    }

    /// Stretches held (what the column costs: 16 B each at most).
    pub fn stretches(&self) -> usize {
        self.ends.len()
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
        match (self.values.last(), self.ends.last_mut()) {
            (Some(&last), Some(end)) if last.same(v) => *end += n,
            _ => {
                self.ends.push(len + n);
                self.values.push(v);
            }
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

    /// The stretch holding row `i`.
    fn stretch_of(&self, i: usize) -> usize {
        assert!(i < self.len(), "row {i} of a column of {} rows", self.len());
        self.ends.partition_point(|&e| e <= i)
    }

    /// Row `i`'s value.
    pub fn get(&self, i: usize) -> T {
        self.values[self.stretch_of(i)]
    }

    /// The values of `rows`, in their order: a row in the stretch of the
    /// previous one costs a comparison, any other a bisection.
    pub fn at(&self, rows: &[usize]) -> Vec<T> {
        let mut out = Vec::with_capacity(rows.len());
        let mut s = usize::MAX;
        for &i in rows {
            let inside = s != usize::MAX
                && i < self.ends[s]
                && i >= if s == 0 { 0 } else { self.ends[s - 1] };
            if !inside {
                s = self.stretch_of(i);
            }
            out.push(self.values[s]);
        }
        out
    }

    /// Each stretch: its rows and value, in row order.
    pub fn spans(&self) -> impl Iterator<Item = (Range<usize>, T)> + '_ {
        self.ends
            .iter()
            .zip(&self.values)
            .scan(0, |start, (&end, &v)| {
                let rows = *start..end;
                *start = end;
                Some((rows, v))
            })
    }

    /// Every row's value, in row order.
    pub fn iter(&self) -> impl Iterator<Item = T> + '_ {
        self.spans()
            .flat_map(|(rows, v)| std::iter::repeat_n(v, rows.len()))
    }

    /// The rows whose value passes `keep`, ascending.
    pub fn rows_where(&self, keep: impl Fn(T) -> bool) -> Vec<usize> {
        let mut out = Vec::new();
        for (rows, v) in self.spans() {
            if keep(v) {
                out.extend(rows);
            }
        }
        out
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
