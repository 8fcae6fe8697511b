//! The validation report: per case and SNR, the confusion matrix, recovery,
//! shrink against the oracle, false alarms and interval coverage; and its
//! text rendering.

use super::*;

pub(super) fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

pub(super) fn summarise(
    cfg: &ValidateConfig,
    results: Vec<FleetResult>,
    seconds: f64,
) -> ValidationReport {
    let cat: Vec<&FleetResult> = results.iter().filter(|r| r.kind == "catalogue").collect();
    let mut cases = Vec::new();
    let mut keys: Vec<(String, u64)> = cat
        .iter()
        .map(|r| (r.truth.clone(), r.snr.to_bits()))
        .collect();
    keys.dedup();
    let mut seen = std::collections::BTreeSet::new();
    for (truth, snr_bits) in keys {
        if !seen.insert((truth.clone(), snr_bits)) {
            continue;
        }
        let rs: Vec<&&FleetResult> = cat
            .iter()
            .filter(|r| r.truth == truth && r.snr.to_bits() == snr_bits)
            .collect();
        let correct = rs.iter().filter(|r| r.named == r.truth).count();
        let mut perr: Vec<f64> = rs.iter().filter_map(|r| r.param_rel_error).collect();
        perr.sort_by(f64::total_cmp);
        let locs: Vec<f64> = rs.iter().filter_map(|r| r.localisation).collect();
        let shr: Vec<f64> = rs.iter().map(|r| r.shrink).collect();
        let ratio: Vec<f64> = rs
            .iter()
            .map(|r| r.shrink / r.oracle_shrink.max(1e-12))
            .collect();
        cases.push(CaseSummary {
            truth,
            snr: f64::from_bits(snr_bits),
            fleets: rs.len(),
            top1_correct: correct,
            accuracy: correct as f64 / rs.len().max(1) as f64,
            localisation_mean: mean(&locs),
            param_rel_error_median: perr.get(perr.len() / 2).copied(),
            shrink_mean: mean(&shr).unwrap_or(0.0),
            oracle_shrink: mean(&rs.iter().map(|r| r.oracle_shrink).collect::<Vec<_>>())
                .unwrap_or(0.0),
            shrink_over_oracle: mean(&ratio).unwrap_or(0.0),
        });
    }
    let mut confusion: BTreeMap<String, BTreeMap<String, BTreeMap<String, usize>>> =
        BTreeMap::new();
    let mut acc_by: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    for r in &cat {
        *confusion
            .entry(snr_label(r.snr))
            .or_default()
            .entry(r.truth.clone())
            .or_default()
            .entry(r.named.clone())
            .or_default() += 1;
        let a = acc_by.entry(snr_label(r.snr)).or_default();
        a.0 += usize::from(r.named == r.truth);
        a.1 += 1;
    }
    let ge3: Vec<&&FleetResult> = cat.iter().filter(|r| r.snr >= 3.0).collect();
    let free: Vec<&FleetResult> = results.iter().filter(|r| r.kind == "effect_free").collect();
    let ooc: Vec<&FleetResult> = results
        .iter()
        .filter(|r| r.kind == "out_of_catalogue")
        .collect();
    let checked: usize = cat.iter().map(|r| r.intervals_checked).sum();
    let covered: usize = cat.iter().map(|r| r.intervals_covered).sum();
    let of =
        |kind: &str| -> Vec<&FleetResult> { results.iter().filter(|r| r.kind == kind).collect() };
    let rate = |rs: &[&FleetResult], f: &dyn Fn(&FleetResult) -> bool| -> Option<f64> {
        (!rs.is_empty()).then(|| rs.iter().filter(|r| f(r)).count() as f64 / rs.len() as f64)
    };
    let (two, spikes, one) = (of("two_effects"), of("spikes"), of("one_machine"));
    let spike_checked: usize = spikes.iter().map(|r| r.intervals_checked).sum();
    let spike_covered: usize = spikes.iter().map(|r| r.intervals_covered).sum();
    ValidationReport {
        quick: cfg.quick,
        seed: cfg.seed,
        fleets: results.len(),
        seconds,
        cases,
        confusion,
        accuracy_by_snr: acc_by
            .into_iter()
            .map(|(k, (c, n))| (k, c as f64 / n.max(1) as f64))
            .collect(),
        accuracy_snr_ge3: ge3.iter().filter(|r| r.named == r.truth).count() as f64
            / ge3.len().max(1) as f64,
        shrink_over_oracle_snr_ge3: mean(
            &ge3.iter()
                .map(|r| r.shrink / r.oracle_shrink.max(1e-12))
                .collect::<Vec<_>>(),
        )
        .unwrap_or(0.0),
        false_alarm_rate: free.iter().filter(|r| !r.selected.is_empty()).count() as f64
            / free.len().max(1) as f64,
        free_fleets: free.len(),
        confident_wrong_rate: ooc
            .iter()
            .filter(|r| !r.selected.is_empty() && r.unexplained_over_sigma < 1.5)
            .count() as f64
            / ooc.len().max(1) as f64,
        ooc_fleets: ooc.len(),
        ooc_localisation_mean: mean(
            &ooc.iter()
                .filter_map(|r| r.localisation)
                .collect::<Vec<_>>(),
        ),
        interval_coverage: (checked > 0).then(|| covered as f64 / checked as f64),
        intervals_checked: checked,
        two_effects_fleets: two.len(),
        two_effects_all_named_rate: rate(&two, &|r| r.all_named == Some(true)),
        two_effects_shrink_over_oracle: mean(
            &two.iter()
                .map(|r| r.shrink / r.oracle_shrink.max(1e-12))
                .collect::<Vec<_>>(),
        ),
        spike_fleets: spikes.len(),
        spike_named_rate: rate(&spikes, &|r| r.named == r.truth),
        spike_interval_coverage: (spike_checked > 0)
            .then(|| spike_covered as f64 / spike_checked as f64),
        spike_robust_shrink_over_oracle: mean(
            &spikes
                .iter()
                .filter_map(|r| Some(r.robust_shrink? / r.oracle_shrink.max(1e-12)))
                .collect::<Vec<_>>(),
        ),
        one_machine_fleets: one.len(),
        one_machine_localised_rate: rate(&one, &|r| r.machine_localised == Some(true)),
        one_machine_named_rate: rate(&one, &|r| r.machine_named == Some(true)),
        results,
    }
}

pub(super) fn short(k: &str) -> String {
    k.replace("squareness", "squar")
        .replace("compliance", "compl")
        .replace("removed_mm3", "rem")
        .replace("path_end_mm", "pe")
        .replace("feed_mm_s", "feed")
        .replace("a_mm_s2", "a")
        .replace("force_n", "f")
        .replace("temp_c", "T")
        .replace("x_mm,y_mm", "xy")
        .replace("_mm", "")
}

/// A readable summary for the terminal: per-case table, confusion matrices,
/// headline rates.
pub fn render_text(r: &ValidationReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "sparkout validate{} — {} fleets in {:.1} s (seed {})",
        if r.quick { " --quick" } else { "" },
        r.fleets,
        r.seconds,
        r.seed
    );
    let _ = writeln!(
        s,
        "\n{:<26} {:>5} {:>6} {:>8} {:>8} {:>9} {:>8} {:>8}",
        "effect", "SNR", "fleets", "top-1", "local.", "par.err", "shrink", "/oracle"
    );
    for c in &r.cases {
        let _ = writeln!(
            s,
            "{:<26} {:>5} {:>6} {:>7.0}% {:>8} {:>9} {:>8.3} {:>8.2}",
            c.truth,
            c.snr,
            c.fleets,
            100.0 * c.accuracy,
            c.localisation_mean
                .map(|v| format!("{v:.2}"))
                .unwrap_or_else(|| "—".into()),
            c.param_rel_error_median
                .map(|v| format!("{v:.3}"))
                .unwrap_or_else(|| "—".into()),
            c.shrink_mean,
            c.shrink_over_oracle
        );
    }
    for (snr, m) in &r.confusion {
        let mut named: Vec<String> = m.values().flat_map(|row| row.keys().cloned()).collect();
        named.sort();
        named.dedup();
        let _ = writeln!(
            s,
            "\nconfusion matrix at {snr} (rows: true, columns: named top-1)"
        );
        let _ = write!(s, "{:<14}", "");
        for n in &named {
            let _ = write!(s, " {:>9}", short(n).chars().take(9).collect::<String>());
        }
        let _ = writeln!(s);
        for (t, row) in m {
            let _ = write!(s, "{:<14}", short(t).chars().take(14).collect::<String>());
            for n in &named {
                match row.get(n) {
                    Some(c) => {
                        let _ = write!(s, " {c:>9}");
                    }
                    None => {
                        let _ = write!(s, " {:>9}", ".");
                    }
                }
            }
            let _ = writeln!(s);
        }
    }
    let _ = writeln!(s);
    for (k, v) in &r.accuracy_by_snr {
        let _ = writeln!(s, "top-1 accuracy at {k}: {:.1} %", 100.0 * v);
    }
    let _ = writeln!(
        s,
        "top-1 accuracy at SNR ≥ 3: {:.1} %; shrink / oracle at SNR ≥ 3: {:.2}",
        100.0 * r.accuracy_snr_ge3,
        r.shrink_over_oracle_snr_ge3
    );
    let pct = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{:.0} %", 100.0 * v));
    let num = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.2}"));
    let _ = writeln!(
        s,
        "two effects at once ({} fleets): both named {}; shrink / oracle {}",
        r.two_effects_fleets,
        pct(r.two_effects_all_named_rate),
        num(r.two_effects_shrink_over_oracle)
    );
    let _ = writeln!(
        s,
        "1 % ±30σ spikes ({} fleets): named {}; 95 % interval holds the truth {}; robust shrink / spike-free oracle {}",
        r.spike_fleets,
        pct(r.spike_named_rate),
        pct(r.spike_interval_coverage),
        num(r.spike_robust_shrink_over_oracle)
    );
    let _ = writeln!(
        s,
        "effect on one of three machines ({} fleets): localised to it {}; named on it {}",
        r.one_machine_fleets,
        pct(r.one_machine_localised_rate),
        pct(r.one_machine_named_rate)
    );
    let _ = writeln!(
        s,
        "false alarms on {} effect-free fleets: {:.1} %",
        r.free_fleets,
        100.0 * r.false_alarm_rate
    );
    let _ = writeln!(
        s,
        "out-of-catalogue fleets: {}; confident wrong names (unexplained < 1.5σ): {:.1} %; localisation {}",
        r.ooc_fleets,
        100.0 * r.confident_wrong_rate,
        r.ooc_localisation_mean
            .map(|v| format!("{v:.2}"))
            .unwrap_or_else(|| "—".into())
    );
    let _ = writeln!(
        s,
        "95 % parameter intervals holding the true value: {} of {} checked (target 90–99 %)",
        r.interval_coverage
            .map(|v| format!("{:.1} %", 100.0 * v))
            .unwrap_or_else(|| "—".into()),
        r.intervals_checked
    );
    for f in r.results.iter().filter(|f| f.kind == "out_of_catalogue") {
        let _ = writeln!(
            s,
            "  {:<28} named {:<22} unexplained {:.2}σ",
            f.truth, f.named, f.unexplained_over_sigma
        );
    }
    s
}
