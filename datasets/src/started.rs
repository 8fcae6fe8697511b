//! Run start times of generated fleets (run.toml `[run].started`): a first
//! start plus a fixed step per run index, as RFC 3339 UTC. The date rolls
//! over at midnight and at month and year ends, so any number of runs gets
//! valid, increasing times (a clock that wrapped within a day, or an hour
//! counted past 23, gave repeated or invalid times past a few dozen runs).

use sparkout_pipeline::contracts::convert::{civil_from_days, days_from_civil};

/// A run's first start: civil date and minute of the day (UTC).
#[derive(Debug, Clone, Copy)]
pub struct FirstStart {
    pub year: i64,
    pub month: i64,
    pub day: i64,
    pub minute_of_day: i64,
}

impl FirstStart {
    /// `hour`:00 UTC on the civil date `year`-`month`-`day`.
    pub const fn at(year: i64, month: i64, day: i64, hour: i64) -> FirstStart {
        FirstStart {
            year,
            month,
            day,
            minute_of_day: hour * 60,
        }
    }
}

/// The start of run `index`: `first` plus `step_min` minutes per index.
pub fn started_at(first: FirstStart, step_min: i64, index: usize) -> String {
    started_after(first, step_min * index as i64)
}

/// `first` plus `minutes`, for a fleet whose runs are not evenly spaced
/// (several a day, say).
pub fn started_after(first: FirstStart, minutes: i64) -> String {
    let minutes = first.minute_of_day + minutes;
    let days = minutes.div_euclid(24 * 60);
    let rem = minutes.rem_euclid(24 * 60);
    let z = days_from_civil(first.year, first.month, first.day) + days;
    let (y, m, d) = civil_from_days(z);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:00Z", rem / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    const AT_8: FirstStart = FirstStart::at(2026, 11, 20, 8);

    #[test]
    fn dates_roll_over_at_midnight_month_and_year_ends() {
        assert_eq!(started_at(AT_8, 15, 0), "2026-11-20T08:00:00Z");
        assert_eq!(started_at(AT_8, 15, 4 * 16), "2026-11-21T00:00:00Z");
        assert_eq!(
            started_at(AT_8, 15, 4 * 24 * 41 - 32),
            "2026-12-31T00:00:00Z"
        );
        assert_eq!(
            started_at(AT_8, 15, 4 * 24 * 42 - 32),
            "2027-01-01T00:00:00Z"
        );
        // Every hour and minute a valid clock reading, the times increasing.
        let times: Vec<String> = (0..5000).map(|i| started_at(AT_8, 20, i)).collect();
        for t in &times {
            let (hh, mm) = (&t[11..13], &t[14..16]);
            assert!(hh < "24" && mm < "60", "{t}");
        }
        assert!(times.windows(2).all(|w| w[0] < w[1]));
    }
}
