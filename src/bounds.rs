//! Upper bounds of the command-line numbers that size work or output, and
//! the gate on work whose size can be predicted. A bound is generous (a
//! real fleet never meets it) but finite, so a typo (`--ae-rate-hz 1e12`)
//! is refused in the argument parser instead of filling the disk; `--help`
//! states each bound. Work that stays inside every bound can still be too
//! large (10⁵ runs at 10 MHz): [`check_size`] refuses it up front unless
//! `--force-size` is given.

/// Runs one `generate` makes.
pub const MAX_RUNS: u64 = 100_000;
/// AE sample rate, Hz (10 MHz: above any AE sensor's band).
pub const MAX_AE_RATE_HZ: f64 = 1e7;
/// Cross-validation folds (the diagnosis config's own range).
pub const MAX_FOLDS: u64 = 1000;
/// Predicted bytes written above which work needs `--force-size`.
pub const MAX_WRITE_BYTES: u64 = 10_000_000_000;

/// A clap value parser for a finite number in (lo, hi].
pub fn f64_above_at_most(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: f64 = s
            .trim()
            .parse()
            .map_err(|_| format!("`{s}` is not a number"))?;
        if v.is_finite() && v > lo && v <= hi {
            Ok(v)
        } else {
            Err(format!("{v} is outside ({lo}, {hi}]"))
        }
    }
}

pub use sparkout_datasets::Predicted;

/// Physical memory of this machine (Linux `/proc/meminfo` `MemTotal`), or
/// `None` where that cannot be read (then memory is not gated).
pub fn machine_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Refuse work predicted to write more than [`MAX_WRITE_BYTES`] or to hold
/// more than half of `memory_bytes`, unless `force`; `what` names the work
/// and the flags that size it.
pub fn check_size(
    what: &str,
    p: Predicted,
    memory_bytes: Option<u64>,
    force: bool,
) -> anyhow::Result<()> {
    if force {
        return Ok(());
    }
    let gb = |b: u64| b as f64 / 1e9;
    if p.write_bytes > MAX_WRITE_BYTES {
        anyhow::bail!(
            "{what} would write about {:.1} GB (more than {:.0} GB); make it smaller, or pass --force-size if you mean it",
            gb(p.write_bytes),
            gb(MAX_WRITE_BYTES)
        );
    }
    if let Some(m) = memory_bytes {
        if p.peak_memory_bytes > m / 2 {
            anyhow::bail!(
                "{what} would hold about {:.1} GB in memory (more than half of this machine's {:.1} GB); make it smaller, or pass --force-size if you mean it",
                gb(p.peak_memory_bytes),
                gb(m)
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounded_numbers_and_the_size_gate() {
        let p = f64_above_at_most(0.0, MAX_AE_RATE_HZ);
        assert_eq!(p("1e6"), Ok(1e6));
        assert_eq!(p("1e7"), Ok(1e7));
        for bad in ["1e12", "0", "-5", "nan", "inf", "fast"] {
            assert!(p(bad).is_err(), "{bad}");
        }
        let small = Predicted {
            write_bytes: 1_000_000,
            peak_memory_bytes: 1_000_000,
        };
        check_size("x", small, Some(8_000_000_000), false).unwrap();
        let big_disk = Predicted {
            write_bytes: MAX_WRITE_BYTES + 1,
            ..small
        };
        let e = check_size("generate", big_disk, None, false).unwrap_err();
        assert!(e.to_string().contains("--force-size"), "{e}");
        check_size("generate", big_disk, None, true).unwrap();
        let big_memory = Predicted {
            peak_memory_bytes: 5_000_000_000,
            ..small
        };
        let e = check_size("generate", big_memory, Some(8_000_000_000), false).unwrap_err();
        assert!(e.to_string().contains("half"), "{e}");
        check_size("generate", big_memory, Some(16_000_000_000), false).unwrap();
        assert!(machine_memory_bytes().is_none_or(|m| m > 0));
    }
}
