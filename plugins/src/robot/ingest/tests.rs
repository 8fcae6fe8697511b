use super::*;
use crate::robot::ae::detect_events;

/// The detector over one in-memory signal at `fs`, as the stage runs it.
fn result(t: &[f64], v: &[f32], fs: f64, kind: SignalKind, cfg: &IngestConfig) -> AeResult {
    let p = AeParams::derive(fs, kind, &cfg.settings());
    let (events, detector) = detect_events(t, v, p, 1.5 / fs);
    AeResult {
        events,
        samples: detector.samples_seen(),
        detector,
        blocks: 1,
        clock_offset_s: 0.0,
        fs_hz: fs,
        kind,
        kind_source: KindSource::Config,
        first_negative: None,
    }
}

/// 250 Hz RMS, 40 s: air at 10 mV, and four cuts of 2 s at 0.1 V. `flicker`
/// makes each cut 1 sample on, 2 samples off (down to 3 mV).
fn cuts(flicker: bool) -> (Vec<f64>, Vec<f32>) {
    let fs = 250.0;
    let t: Vec<f64> = (0..10_000).map(|i| i as f64 / fs).collect();
    let v = (0..10_000usize)
        .map(|i| {
            // ±10 % of the air level, a fixed pattern of period 13.
            let air = 0.01 * (1.0 + 0.1 * ((i * 7 % 13) as f64 - 6.0) / 6.0);
            let in_cut = (1..=4).any(|k| (k * 2000..k * 2000 + 500).contains(&i));
            match (in_cut, flicker) {
                (true, false) => 0.1,
                (true, true) if i % 3 == 0 => 0.1,
                (true, true) => 0.003,
                _ => air,
            }
        })
        .map(|x| x as f32)
        .collect();
    (t, v)
}

#[test]
fn clean_cuts_raise_no_warning() {
    let (t, v) = cuts(false);
    let r = result(&t, &v, 250.0, SignalKind::Rms, &IngestConfig::default());
    assert_eq!(r.events.len(), 4);
    assert!(r.fragmentation_warnings(Some(4)).is_empty());
    assert!(r.fragmentation_warnings(None).is_empty());
}

#[test]
fn fragmenting_contacts_raise_the_warning() {
    let (t, v) = cuts(true);
    // A 1-sample dwell and no merge gap: every flicker is a contact.
    let cfg = IngestConfig {
        min_dwell_s: Some(0.004),
        merge_gap_s: Some(0.0),
        ..IngestConfig::default()
    };
    let r = result(&t, &v, 250.0, SignalKind::Rms, &cfg);
    assert!(r.events.len() > 100, "{}", r.events.len());
    let w = r.fragmentation_warnings(None);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains("fragmented") && w[0].contains("--signal"),
        "{w:?}"
    );
    // With the plan's four touches the count says so too.
    let w = r.fragmentation_warnings(Some(4));
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[1].contains("for 4 planned touches"), "{w:?}");
    // The defaults chain the flickers into one contact per cut: the
    // dropped crossings are that contact's ripple, not a warning.
    let r = result(&t, &v, 250.0, SignalKind::Rms, &IngestConfig::default());
    assert_eq!(r.events.len(), 4, "{:?}", r.events);
    assert!(r.detector.short_crossings() > 100);
    assert_eq!(r.detector.stray_crossings(), 0);
    assert!(r.fragmentation_warnings(Some(4)).is_empty());
}

#[test]
fn a_threshold_in_the_noise_raises_the_warning() {
    // The clean cuts, with the threshold at the median + 1·σ of the air:
    // the air's own scatter crosses it again and again.
    let (t, v) = cuts(false);
    let cfg = IngestConfig {
        k_sigma: 1.0,
        ..IngestConfig::default()
    };
    let r = result(&t, &v, 250.0, SignalKind::Rms, &cfg);
    assert!(
        r.detector.stray_crossings() > 100,
        "{}",
        r.detector.stray_crossings()
    );
    let w = r.fragmentation_warnings(None);
    assert!(!w.is_empty(), "{} contacts", r.events.len());
    assert!(w[0].contains("dropped away from any contact"), "{w:?}");
}
