use super::*;

/// A deterministic test signal: Gaussian-ish noise (sum of uniforms from
/// an LCG) plus decaying bursts at the given onsets.
pub fn synth(
    n: usize,
    fs: f64,
    noise_v: f64,
    bursts: &[(f64, f64, f64)], // (onset_s, amplitude_v, decay_s)
    seed: u64,
) -> (Vec<f64>, Vec<f32>) {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut uni = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 11) as f64) / ((1u64 << 53) as f64)
    };
    let t: Vec<f64> = (0..n).map(|i| i as f64 / fs).collect();
    let v: Vec<f32> = t
        .iter()
        .map(|&ti| {
            // Irwin–Hall(12) − 6 ≈ N(0, 1)
            let g: f64 = (0..12).map(|_| uni()).sum::<f64>() - 6.0;
            let mut x = noise_v * g;
            for &(t0, a, tau) in bursts {
                if ti >= t0 {
                    let dt = ti - t0;
                    x += a * (-dt / tau).exp() * (2.0 * std::f64::consts::PI * 250e3 * dt).sin();
                }
            }
            x as f32
        })
        .collect();
    (t, v)
}

fn params(fs: f64) -> AeParams {
    AeParams::from_seconds(fs, 1e-3, 8.0, 0.5e-3, 0.5, 5e-3)
}

#[test]
fn envelope_of_constant_sine_is_amplitude_over_sqrt2() {
    let fs = 1e6;
    let v: Vec<f32> = (0..10_000)
        .map(|i| (2.0 * std::f64::consts::PI * 1e4 * i as f64 / fs).sin() as f32)
        .collect();
    let e = rms_envelope(&v, 1000);
    assert!((e[9_999] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-3);
}

#[test]
fn events_within_one_window_of_burst_onsets_one_per_burst() {
    let fs = 1e6;
    let onsets = [0.012, 0.030, 0.0473, 0.081];
    let bursts: Vec<(f64, f64, f64)> = onsets.iter().map(|&t| (t, 0.2, 2e-3)).collect();
    let (t, v) = synth(100_000, fs, 0.005, &bursts, 7);
    let p = params(fs);
    let (ev, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(ev.len(), onsets.len(), "one event per burst: {ev:?}");
    for (e, &t0) in ev.iter().zip(&onsets) {
        assert!(
            e.onset_t_s >= t0 && e.onset_t_s - t0 <= 1e-3,
            "onset {} vs truth {}",
            e.onset_t_s,
            t0
        );
        assert!(e.peak_v > 0.05 && e.duration_s() > 0.5e-3);
    }
    let f = det.floors()[0];
    // Noise floor ≈ σ of the noise (5 mV); threshold a bit above it.
    assert!((f.centre_v - 0.005).abs() < 5e-4, "{f:?}");
    assert!(f.threshold_v > f.centre_v && f.release_v < f.threshold_v);
}

#[test]
fn chunking_does_not_change_events() {
    let fs = 1e6;
    let bursts = [(0.02, 0.15, 1e-3), (0.05, 0.3, 3e-3), (0.09, 0.1, 1e-3)];
    let (t, v) = synth(200_000, fs, 0.004, &bursts, 3);
    let p = params(fs);
    let (whole, _) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(whole.len(), 3);
    for chunk in [1usize, 7, 999, 1000, 1001, 4096, 65_537] {
        let mut det = AeDetector::new(p);
        let mut out = Vec::new();
        for (tc, vc) in t.chunks(chunk).zip(v.chunks(chunk)) {
            det.feed(tc, vc, &mut out);
        }
        det.finish(&mut out);
        assert_eq!(out.len(), whole.len(), "chunk {chunk}");
        for (a, b) in out.iter().zip(&whole) {
            assert_eq!(a.onset_index, b.onset_index, "chunk {chunk}");
            assert!((a.peak_v - b.peak_v).abs() < 1e-9 * b.peak_v);
        }
    }
}

#[test]
fn running_sum_matches_naive_envelope_after_a_huge_burst() {
    // Cancellation check: a burst 10⁴× the floor, then quiet floor; the
    // envelope the detector carries must match the naive one.
    let fs = 1e6;
    let (t, v) = synth(300_000, fs, 0.001, &[(0.02, 10.0, 5e-3)], 11);
    let p = params(fs);
    let mut det = AeDetector::new(p);
    let mut out = Vec::new();
    det.feed(&t, &v, &mut out);
    let naive = rms_envelope(&v, p.window);
    let env = (det.sum / p.window as f64).sqrt();
    assert!(
        (env - naive[v.len() - 1]).abs() < 1e-9,
        "{env} vs {}",
        naive[v.len() - 1]
    );
    assert_eq!(out.len(), 1);
}

#[test]
fn short_spike_below_dwell_is_not_a_contact() {
    // A trailing-window envelope stretches any impulse to the window
    // length, so only a dwell longer than the window rejects spikes:
    // 1.5 ms here against a 1 ms window. A 20 µs spike holds the
    // envelope up for ≈ 1 ms (no event); a contact burst decaying over
    // 3 ms holds it for several ms (one event).
    let fs = 1e6;
    let (t, v) = synth(
        60_000,
        fs,
        0.005,
        &[(0.02, 0.2, 2e-5), (0.04, 0.2, 3e-3)],
        5,
    );
    let p = AeParams::from_seconds(fs, 1e-3, 8.0, 1.5e-3, 0.5, 5e-3);
    let (ev, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(ev.len(), 1, "{ev:?}");
    assert!((ev[0].onset_t_s - 0.04).abs() < 1e-3);
    assert!(det.max_envelope_armed_v() > det.floors()[0].threshold_v);
}

/// A plain reference: naive envelope, the same warm-up / calibration /
/// threshold / dwell / hysteresis rules written the obvious way.
fn reference(t: &[f64], v: &[f32], p: AeParams) -> Vec<(u64, f64, f64)> {
    let w = p.window;
    let sums: Vec<f64> = (0..v.len())
        .map(|i| {
            let lo = (i + 1).saturating_sub(w);
            v[lo..=i].iter().map(|&x| (x as f64) * (x as f64)).sum()
        })
        .collect();
    let cal: Vec<f64> = (w..w + p.noise_window)
        .map(|i| (sums[i] / w as f64).sqrt())
        .collect();
    // Median and MAD by sorting (the detector selects in place).
    let median = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let n = s.len();
        if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        }
    };
    let centre = median(&cal);
    let dev: Vec<f64> = cal.iter().map(|e| (e - centre).abs()).collect();
    let sigma = (1.4826 * median(&dev)).max(1e-3 * centre).max(1e-12);
    let on = w as f64 * (centre + p.k_sigma * sigma).powi(2);
    let off = w as f64 * (centre + p.hysteresis * p.k_sigma * sigma).powi(2);
    let mut out = Vec::new();
    let mut i = w + p.noise_window;
    while i < v.len() {
        if sums[i] > on {
            let start = i;
            let mut j = i;
            while j < v.len() && sums[j] > on && j - start < p.min_dwell {
                j += 1;
            }
            if j - start >= p.min_dwell {
                let mut peak = sums[start..j].iter().cloned().fold(0.0, f64::max);
                while j < v.len() && sums[j] >= off {
                    peak = peak.max(sums[j]);
                    j += 1;
                }
                let end_t = if j < v.len() { t[j] } else { t[v.len() - 1] };
                out.push((start as u64, end_t, (peak / w as f64).sqrt()));
                i = j + 1;
            } else {
                i = j + 1;
            }
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn fast_paths_match_the_naive_reference() {
    // Bursts of many sizes, some barely above the threshold, some
    // shorter than the dwell once past the window.
    let fs = 1e6;
    let bursts: Vec<(f64, f64, f64)> = (0..25)
        .map(|k| {
            let a = [0.004, 0.006, 0.01, 0.03, 0.3][k % 5];
            let tau = [2e-4, 1e-3, 3e-3][k % 3];
            (0.012 + 0.011 * k as f64, a, tau)
        })
        .collect();
    let (t, v) = synth(300_000, fs, 0.005, &bursts, 13);
    let p = AeParams::from_seconds(fs, 3e-4, 6.0, 2e-4, 0.4, 2e-3);
    let expect = reference(&t, &v, p);
    assert!(expect.len() >= 10, "{}", expect.len());
    for chunk in [777usize, 65_536, 300_000] {
        let mut det = AeDetector::new(p);
        let mut got = Vec::new();
        for (tc, vc) in t.chunks(chunk).zip(v.chunks(chunk)) {
            det.feed(tc, vc, &mut got);
        }
        det.finish(&mut got);
        assert_eq!(got.len(), expect.len(), "chunk {chunk}");
        for (g, e) in got.iter().zip(&expect) {
            assert_eq!(g.onset_index, e.0);
            assert_eq!(g.end_t_s, e.1);
            assert!((g.peak_v - e.2).abs() < 1e-9 * e.2);
        }
    }
}

#[test]
fn gaps_restart_window_and_noise_floor() {
    let fs = 1e6;
    // Two recording blocks 1 s apart, each with its own burst and a
    // different noise level.
    let (t1, v1) = synth(20_000, fs, 0.002, &[(0.012, 0.1, 2e-3)], 1);
    let (t2, mut v2) = synth(20_000, fs, 0.002, &[(0.013, 0.1, 2e-3)], 2);
    v2.iter_mut().for_each(|x| *x *= 2.0);
    let mut t = t1.clone();
    t.extend(t2.iter().map(|x| x + 1.0));
    let mut v = v1;
    v.extend(v2);
    let (ev, det) = detect_events(&t, &v, params(fs), 1.5 / fs);
    assert_eq!(ev.len(), 2, "{ev:?}");
    assert!((ev[0].onset_t_s - 0.012).abs() < 1e-3);
    assert!((ev[1].onset_t_s - 1.013).abs() < 1e-3);
    assert_eq!(det.floors().len(), 2);
    assert!(det.floors()[1].centre_v > 1.5 * det.floors()[0].centre_v);
    assert_eq!(gaps(&t, None, 1.5 / fs), vec![20_000]);
}

// ------------------------------------------------- defaults at any rate

/// The settings a user who sets nothing gets (k = 8, hysteresis 0.5).
pub fn defaults() -> AeSettings {
    AeSettings {
        k_sigma: 8.0,
        hysteresis: 0.5,
        ..AeSettings::default()
    }
}

#[test]
fn lengths_derive_from_the_rate_and_the_kind_and_settings_override() {
    // 250 Hz conditioned RMS: no envelope, dwell and noise window at their
    // floors in samples (0.5 ms, 5 ms would be a fraction of one), the
    // merge gap 50 ms, crossings chained within the dwell.
    let p = AeParams::derive(250.0, SignalKind::Rms, &defaults());
    assert_eq!(
        (
            p.window,
            p.min_dwell,
            p.merge_gap,
            p.noise_window,
            p.chain_gap
        ),
        (1, 3, 13, 64, 3)
    );
    // 10 kHz RMS: the merge gap in time (50 ms), the dwell in time (0.5 ms).
    let p = AeParams::derive(1e4, SignalKind::Rms, &defaults());
    assert_eq!((p.min_dwell, p.merge_gap, p.chain_gap), (5, 500, 5));
    // 1 MHz raw: the physical lengths in seconds (1 ms, 0.5 ms, 2 ms, 5 ms);
    // the envelope bridges short dips, so nothing is chained.
    let p = AeParams::derive(1e6, SignalKind::Raw, &defaults());
    assert_eq!(
        (
            p.window,
            p.min_dwell,
            p.merge_gap,
            p.noise_window,
            p.chain_gap
        ),
        (1000, 500, 2000, 5000, 0)
    );
    // A raw signal at a low rate falls back to the floors too.
    let p = AeParams::derive(250.0, SignalKind::Raw, &defaults());
    assert_eq!((p.window, p.min_dwell, p.merge_gap), (1, 3, 10));
    // What the user sets is taken as it is, floors or not.
    let s = AeSettings {
        window_s: Some(0.02),
        min_dwell_s: Some(0.004),
        noise_window_s: Some(1.0),
        merge_gap_s: Some(0.0),
        ..defaults()
    };
    let p = AeParams::derive(250.0, SignalKind::Rms, &s);
    assert_eq!(
        (
            p.window,
            p.min_dwell,
            p.merge_gap,
            p.noise_window,
            p.chain_gap
        ),
        (5, 1, 0, 250, 0)
    );
    assert_eq!(AeParams::default_min_dwell(250.0), 3);
    assert_eq!(AeParams::default_min_dwell(1e6), 500);
}

#[test]
fn the_signal_kind_is_guessed_from_its_sign() {
    assert_eq!(SignalKind::guess(&[0.01, 0.0, 0.3]), SignalKind::Rms);
    assert_eq!(SignalKind::guess(&[0.01, -0.002, 0.3]), SignalKind::Raw);
    assert_eq!(SignalKind::guess(&[]), SignalKind::Raw);
}

#[test]
fn robust_floor_ignores_a_contact_in_the_calibration_span() {
    // 100 quiet samples at 1.0 ± 0.1 (a symmetric ramp of deviations) and
    // 40 samples of a contact at 50: the mean and σ would put the
    // threshold above the contact; the median and MAD do not move much.
    let mut v: Vec<f64> = (0..100)
        .map(|i| 1.0 + 0.1 * ((i % 21) as f64 - 10.0) / 10.0)
        .collect();
    v.extend(std::iter::repeat_n(50.0, 40));
    let (c, s) = robust_floor(&mut v);
    assert!((c - 1.0).abs() < 0.08, "centre {c}");
    assert!(s > 0.03 && s < 0.2, "scale {s}");
    // A quantised, perfectly flat floor with a few one-step readings: the
    // MAD is 0, the mean absolute deviation stands in.
    let mut q: Vec<f64> = (0..64)
        .map(|i| if i % 16 == 0 { 0.0013 } else { 0.0012 })
        .collect();
    let (c, s) = robust_floor(&mut q);
    assert_eq!(c, 0.0012);
    let expect = 1.2533 * 4.0 * 0.0001 / 64.0;
    assert!((s - expect).abs() < 1e-9, "{s} vs {expect}");
}

/// Deterministic noise for the hand-made signals: uniform in ±√3·σ (so σ
/// is `sigma`) from the fractional part of a sine hash of the index.
fn hash_noise(i: usize, sigma: f64) -> f64 {
    let x = ((i as f64) * 12.9898).sin() * 43758.5453;
    (x - x.floor() - 0.5) * 12f64.sqrt() * sigma
}

#[test]
fn hand_made_raw_signal_one_contact_each_with_the_defaults() {
    // 1 MHz raw AE, 0.1 s: noise σ 5 mV; at each contact a 100 kHz carrier
    // of 0.1 V amplitude switched on from `on` to `off` (s).
    let fs = 1e6;
    let contacts = [(0.010, 0.016), (0.040, 0.052), (0.075, 0.079)];
    let n = 100_000;
    let t: Vec<f64> = (0..n).map(|i| i as f64 / fs).collect();
    let v: Vec<f32> = t
        .iter()
        .enumerate()
        .map(|(i, &ti)| {
            let on = contacts.iter().any(|&(a, b)| ti >= a && ti < b);
            let burst = if on {
                0.1 * (2.0 * std::f64::consts::PI * 100e3 * ti).sin()
            } else {
                0.0
            };
            (hash_noise(i, 0.005) + burst) as f32
        })
        .collect();
    let p = AeParams::derive(fs, SignalKind::Raw, &defaults());
    let (ev, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(ev.len(), contacts.len(), "{ev:?}");
    for (e, &(on, off)) in ev.iter().zip(&contacts) {
        // The 1 ms window crosses the threshold within a few µs of the
        // switch-on; it falls below the release within a window of off.
        assert!(
            e.onset_t_s >= on && e.onset_t_s - on < 50e-6,
            "onset {} vs {on}",
            e.onset_t_s
        );
        assert!(
            e.end_t_s > off && e.end_t_s < off + 1.1e-3,
            "end {}",
            e.end_t_s
        );
    }
    assert_eq!(det.short_crossings(), 0);
}

/// A conditioned RMS log at 250 Hz, 20 s: air at 10 mV ± 10 %; each cut a
/// step to 0.1 V ± 30 % whose every 7th sample drops out to 4 mV (below
/// the release level), then an exit decaying with τ = 20 ms.
fn hand_made_rms(cuts: &[(f64, f64)]) -> (Vec<f64>, Vec<f32>) {
    let fs = 250.0;
    let t: Vec<f64> = (0..5000).map(|i| i as f64 / fs).collect();
    let v = t
        .iter()
        .enumerate()
        .map(|(i, &ti)| {
            let mut x = 0.01 * (1.0 + hash_noise(i, 0.1));
            for &(on, off) in cuts {
                if ti >= on && ti < off {
                    x = if i % 7 == 3 {
                        0.004
                    } else {
                        0.1 * (1.0 + hash_noise(i, 0.3))
                    };
                } else if ti >= off {
                    x += 0.1 * (-(ti - off) / 0.02).exp();
                }
            }
            x as f32
        })
        .collect();
    (t, v)
}

#[test]
fn hand_made_rms_signal_one_contact_each_with_the_defaults() {
    let fs = 250.0;
    // Cuts (on, off) in s; a cut's first sample is at or after `on`.
    let cuts = [(2.01, 4.0), (7.5, 8.3), (12.01, 16.0)];
    let (t, v) = hand_made_rms(&cuts);
    let p = AeParams::derive(fs, SignalKind::Rms, &defaults());
    let (ev, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(ev.len(), cuts.len(), "{ev:?}");
    for (e, &(on, off)) in ev.iter().zip(&cuts) {
        // The first sample of the cut: within one sample period of `on`.
        assert!(
            e.onset_t_s >= on && e.onset_t_s - on < 1.0 / fs,
            "onset {} vs {on}",
            e.onset_t_s
        );
        // The exit tail takes a few samples to fall below the release.
        assert!(
            e.end_t_s >= off && e.end_t_s < off + 0.1,
            "end {} vs {off}",
            e.end_t_s
        );
    }
    let f = det.floors()[0];
    assert!((f.centre_v - 0.01).abs() < 0.001, "{f:?}");
    // The same log with the old fixed defaults (1 ms window = 1 sample,
    // 0.5 ms dwell = 1 sample, no merge gap): every drop-out splits the cut.
    let old = AeParams::from_seconds(fs, 0.001, 8.0, 0.0005, 0.5, 0.005);
    let (ev_old, _) = detect_events(&t, &v, old, 1.5 / fs);
    assert!(ev_old.len() > 10 * cuts.len(), "{}", ev_old.len());
}

#[test]
fn a_flickering_cut_is_one_contact_and_its_crossings_are_counted() {
    // 2 samples above, 2 below the threshold through a 2 s cut: no run of
    // 3 samples (the dwell), but the crossings chain within the merge gap.
    let fs = 250.0;
    let t: Vec<f64> = (0..2500).map(|i| i as f64 / fs).collect();
    let v: Vec<f32> = (0..2500usize)
        .map(|i| {
            let air = 0.01 * (1.0 + hash_noise(i, 0.1));
            let in_cut = (1000..1500).contains(&i);
            (if in_cut && i % 4 < 2 { 0.1 } else { air }) as f32
        })
        .collect();
    let p = AeParams::derive(fs, SignalKind::Rms, &defaults());
    let (ev, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(ev.len(), 1, "{ev:?}");
    assert_eq!(ev[0].onset_index, 1000);
    assert!(det.short_crossings() > 50, "{}", det.short_crossings());
    // All of them the contact's own ripple.
    assert_eq!(det.stray_crossings(), 0);
    // With a 1-sample dwell and no merging it is 125 contacts.
    let s = AeSettings {
        min_dwell_s: Some(0.004),
        merge_gap_s: Some(0.0),
        ..defaults()
    };
    let (ev, _) = detect_events(&t, &v, AeParams::derive(fs, SignalKind::Rms, &s), 1.5 / fs);
    assert_eq!(ev.len(), 125);
}

#[test]
fn merging_and_chaining_do_not_depend_on_the_chunking() {
    // The hand-made RMS log: drop-outs end contacts that the merge gap
    // joins, and chained crossings; fed whole or in any chunks, the same.
    let fs = 250.0;
    let (t, v) = hand_made_rms(&[(2.01, 4.0), (7.5, 8.3), (12.01, 16.0)]);
    let p = AeParams::derive(fs, SignalKind::Rms, &defaults());
    let (whole, det) = detect_events(&t, &v, p, 1.5 / fs);
    assert_eq!(whole.len(), 3);
    for chunk in [1usize, 2, 7, 64, 1000] {
        let mut d = AeDetector::new(p);
        let mut out = Vec::new();
        for (tc, vc) in t.chunks(chunk).zip(v.chunks(chunk)) {
            d.feed(tc, vc, &mut out);
        }
        d.finish(&mut out);
        assert_eq!(out, whole, "chunk {chunk}");
        assert_eq!(d.short_crossings(), det.short_crossings(), "chunk {chunk}");
        assert_eq!(d.stray_crossings(), det.stray_crossings(), "chunk {chunk}");
    }
}
