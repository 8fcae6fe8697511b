//! Recorded vs AE-derived touches of the same plan row (`touch_compare`),
//! and the `contacts` artifact (one row per AE event).

use super::*;
use crate::robot::summary::{CompareGroup, CompareSummary};

/// Recorded vs AE-derived touches of the same plan row.
pub(super) fn compare(
    probe: &[Touch],
    ae: &[Touch],
) -> Option<(arrow::record_batch::RecordBatch, CompareSummary)> {
    let ae_by_seq: BTreeMap<i32, &Touch> = ae.iter().map(|t| (t.seq, t)).collect();
    let pairs: Vec<(&Touch, &Touch)> = probe
        .iter()
        .filter(|p| p.seq >= 0)
        .filter_map(|p| ae_by_seq.get(&p.seq).map(|a| (p, *a)))
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let d: Vec<Vector3<f64>> = pairs.iter().map(|(p, a)| p.p - a.p).collect();
    let dn: Vec<f64> = pairs.iter().map(|(p, a)| p.normal() - a.normal()).collect();
    let dt: Vec<f64> = pairs.iter().map(|(p, a)| p.t_s - a.t_s).collect();
    let dist: Vec<f64> = d.iter().map(|v| v.norm()).collect();
    let batch = BatchBuilder::new()
        .i32("seq", pairs.iter().map(|(p, _)| p.seq).collect())
        .str(
            "face",
            &pairs
                .iter()
                .map(|(p, _)| p.face.label())
                .collect::<Vec<_>>(),
        )
        .i32("point", pairs.iter().map(|(p, _)| p.point).collect())
        .i32("trial", pairs.iter().map(|(p, _)| p.trial).collect())
        .str(
            "method",
            &pairs
                .iter()
                .map(|(p, _)| p.method.as_str())
                .collect::<Vec<_>>(),
        )
        .f64(
            "approach_mm_s",
            pairs.iter().map(|(p, _)| p.approach_mm_s).collect(),
        )
        .f64("dt_s", dt.clone())
        .f64("dx_mm", d.iter().map(|v| v.x).collect())
        .f64("dy_mm", d.iter().map(|v| v.y).collect())
        .f64("dz_mm", d.iter().map(|v| v.z).collect())
        .f64("dnormal_mm", dn.clone())
        .f64("dist_mm", dist.clone())
        .build();
    let n = pairs.len() as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    // The controller registers a touch L seconds after the contact the AE
    // shows: the time difference estimates the trigger latency directly.
    let summary = CompareSummary {
        n: pairs.len(),
        rms_dist_mm: (dist.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        max_dist_mm: dist.iter().fold(0.0f64, |m, x| m.max(*x)),
        mean_dnormal_mm: mean(&dn),
        mean_dt_s: mean(&dt),
        by_speed: by_speed(&pairs, &dn, &dt),
    };
    Some((batch, summary))
}

pub(super) fn by_speed(pairs: &[(&Touch, &Touch)], dn: &[f64], dt: &[f64]) -> Vec<CompareGroup> {
    let mut g: BTreeMap<(String, u64), (f64, Vec<usize>)> = BTreeMap::new();
    for (i, (p, _)) in pairs.iter().enumerate() {
        g.entry((p.method.clone(), p.approach_mm_s.to_bits()))
            .or_insert((p.approach_mm_s, Vec::new()))
            .1
            .push(i);
    }
    g.into_iter()
        .map(|((m, _), (v, idx))| {
            let n = idx.len() as f64;
            CompareGroup {
                method: m,
                approach_mm_s: v,
                n: idx.len(),
                mean_dnormal_mm: idx.iter().map(|&i| dn[i]).sum::<f64>() / n,
                mean_dt_s: idx.iter().map(|&i| dt[i]).sum::<f64>() / n,
            }
        })
        .collect()
}

pub(super) fn contacts_batch(
    r: &AeResult,
    roles: &[(i32, Role)],
) -> arrow::record_batch::RecordBatch {
    let e = &r.events;
    BatchBuilder::new()
        .f64(
            "t_s",
            e.iter().map(|x| x.onset_t_s + r.clock_offset_s).collect(),
        )
        .f64("ae_t_s", e.iter().map(|x| x.onset_t_s).collect())
        .i64("ae_row", e.iter().map(|x| x.onset_index as i64).collect())
        .f64("peak_v", e.iter().map(|x| x.peak_v).collect())
        .f64("duration_s", e.iter().map(|x| x.duration_s()).collect())
        .f64(
            "threshold_v",
            e.iter().map(|x| x.floor.threshold_v).collect(),
        )
        .f64("release_v", e.iter().map(|x| x.floor.release_v).collect())
        .f64("noise_mean_v", e.iter().map(|x| x.floor.centre_v).collect())
        .f64("noise_sigma_v", e.iter().map(|x| x.floor.sigma_v).collect())
        .i32("seq", roles.iter().map(|r| r.0).collect())
        .str(
            "role",
            &roles.iter().map(|r| r.1.label()).collect::<Vec<_>>(),
        )
        .build()
}

pub(super) fn empty_contacts() -> arrow::record_batch::RecordBatch {
    let r = AeResult {
        events: Vec::new(),
        detector: AeDetector::new(AeParams::from_seconds(1.0, 1.0, 1.0, 1.0, 1.0, 2.0)),
        samples: 0,
        blocks: 0,
        clock_offset_s: 0.0,
        fs_hz: 1.0,
        kind: SignalKind::Raw,
        kind_source: KindSource::Config,
        first_negative: None,
    };
    contacts_batch(&r, &[])
}
