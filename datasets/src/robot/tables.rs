//! The run's tables (motion, plan, probe, passes) and run.toml. (Part of the robot generator; see mod.rs.)

use super::*;

pub(super) fn motion_batch(pieces: &[Piece], rate_hz: f64, rng: &mut ChaCha8Rng) -> RecordBatch {
    let t_end = pieces.last().map(|p| p.t1).unwrap_or(0.0);
    let n = (t_end * rate_hz).floor() as usize + 1;
    let mut m = MotionColumns::default();
    let mut act: [Vec<f64>; 3] = Default::default();
    let (mut feed, mut seg) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut pi = 0;
    for k in 0..n {
        let t = k as f64 / rate_hz;
        while pi + 1 < pieces.len() && t >= pieces[pi].t1 {
            pi += 1;
        }
        let p = &pieces[pi];
        let tt = t.min(p.t1);
        let c = p.pos(tt);
        m.t_s.push(t);
        for ax in 0..3 {
            m.cmd_mm[ax].push(c[ax]);
        }
        for ax in 0..3 {
            act[ax].push(c[ax] + ACT_NOISE_MM * normal(rng));
        }
        feed.push(p.speed(tt));
        seg.push(if t < p.t1 { p.segment } else { -1 });
    }
    m.act_mm = Some(act);
    m.feed_mm_s = Some(feed);
    m.segment = Some(seg);
    m.into_batch()
}

pub(super) fn plan_batch(plan: &[PlanRow]) -> RecordBatch {
    let faces: Vec<&str> = plan.iter().map(|r| r.face.label()).collect();
    let methods = vec!["ae"; plan.len()];
    let f = |g: &dyn Fn(&PlanRow) -> f64| plan.iter().map(g).collect::<Vec<f64>>();
    BatchBuilder::new()
        .i32("seq", plan.iter().map(|r| r.seq).collect())
        .str("face", &faces)
        .i32("point", plan.iter().map(|r| r.point).collect())
        .i32("trial", plan.iter().map(|r| r.trial).collect())
        .str("method", &methods)
        .f64("approach_mm_s", f(&|r| r.speed_mm_s))
        .f64("nom_x_mm", f(&|r| r.nom.x))
        .f64("nom_y_mm", f(&|r| r.nom.y))
        .f64("nom_z_mm", f(&|r| r.nom.z))
        .f64("dir_x", f(&|r| r.dir.x))
        .f64("dir_y", f(&|r| r.dir.y))
        .f64("dir_z", f(&|r| r.dir.z))
        .build()
}

pub(super) fn probe_batch(plan: &[PlanRow], touches: &[Touch]) -> RecordBatch {
    let rows: Vec<&PlanRow> = touches.iter().map(|t| &plan[t.row]).collect();
    let faces: Vec<&str> = rows.iter().map(|r| r.face.label()).collect();
    let methods: Vec<&str> = rows.iter().map(|r| r.method).collect();
    BatchBuilder::new()
        .f64("t_s", touches.iter().map(|t| t.t_r).collect())
        .str("face", &faces)
        .i32("point", rows.iter().map(|r| r.point).collect())
        .i32("trial", rows.iter().map(|r| r.trial).collect())
        .str("method", &methods)
        .f64("approach_mm_s", rows.iter().map(|r| r.speed_mm_s).collect())
        .f64("nom_x_mm", rows.iter().map(|r| r.nom.x).collect())
        .f64("nom_y_mm", rows.iter().map(|r| r.nom.y).collect())
        .f64("nom_z_mm", rows.iter().map(|r| r.nom.z).collect())
        .f64("x_mm", touches.iter().map(|t| t.registered.x).collect())
        .f64("y_mm", touches.iter().map(|t| t.registered.y).collect())
        .f64("z_mm", touches.iter().map(|t| t.registered.z).collect())
        .build()
}

/// The weld-repair cycle (docs/models.md §1.4). The compliance model as a
/// recursion on the carried deflection: the interference of pass i is the
/// new infeed δ′ᵢ plus the deflection α·δᵢ₋₁ left by the previous pass, and
/// splits into cut and deflection, δᵢ = Iᵢ/(1+α). With a constant δ′ this is
/// exactly δᵢ = [1 − (α/(1+α))ⁱ]·δ′; spark-out passes (δ′ = 0) remove
/// (α/(1+α))·δᵢ₋₁; finishing continues the recursion with δ′ = doc_finish.
/// Effects: thermal drift lifts the wheel between passes (the infeed loses
/// the drift increment) and shifts every height reading by −drift(t); wear
/// and depth-dependent compliance remove less than the compliance model says
/// (the shortfall is not carried as deflection, so against the true α the
/// cut_depth gap is the effect's own form; the pipeline calibrates α on the
/// first pass, docs/models.md §1.4, which a depth-dependent compliance
/// shrinks too, so that effect's gap is the recurrence's misfit instead).
pub(super) fn passes(
    cfg: &RobotFleetConfig,
    fx: &Effects,
    alpha: f64,
    t_probe_end: f64,
    rng: &mut ChaCha8Rng,
) -> (RecordBatch, Vec<PassTruth>) {
    let mut stages = Vec::new();
    stages.extend(std::iter::repeat_n(
        ("rough", cfg.doc_rough_mm),
        cfg.rough_passes,
    ));
    stages.extend(std::iter::repeat_n(
        ("finish", cfg.doc_finish_mm),
        cfg.finish_passes,
    ));
    stages.extend(std::iter::repeat_n(("spark", 0.0), cfg.spark_passes));
    let duration = PASS_LENGTH_MM / cfg.grind_feed_mm_s;
    let mut t = t_probe_end + GRIND_START_DELAY_S;
    let mut h = cfg.weld_mm;
    let mut removed_mm3 = 0.0;
    let mut prev_comp = 0.0;
    let mut prev_model = 0.0;
    let mut prev_drift: Option<f64> = None;
    let mut cols = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    let mut truth = Vec::new();
    for (i, &(stage, doc)) in stages.iter().enumerate() {
        let pass = i as i32 + 1;
        let (t0, t1) = (t, t + duration);
        let d_mid = fx.drift_mm(0.5 * (t0 + t1));
        let d_inc = prev_drift.map(|p| d_mid - p).unwrap_or(0.0);
        prev_drift = Some(d_mid);
        let model = (alpha * prev_model + doc) / (1.0 + alpha);
        prev_model = model;
        let comp = ((alpha * prev_comp + doc - d_inc) / (1.0 + alpha)).max(0.0);
        prev_comp = comp;
        let cov = |c: &str| -> f64 {
            match c {
                "pass" => pass as f64,
                "nominal_doc_mm" => doc,
                "removed_mm3" => removed_mm3,
                "feed_mm_s" => cfg.grind_feed_mm_s,
                _ => 0.0,
            }
        };
        let direct: f64 = fx.cut.iter().map(|e| e.value(&cov)).sum();
        let real = (comp - fx.compliance_k_per_mm * doc * doc - fx.wear_k_mm_per_mm3 * removed_mm3
            + direct)
            .max(0.0);
        truth.push(PassTruth {
            pass,
            cut_mm: real,
            model_cut_mm: model,
            removed_mm3,
        });
        let before = h - fx.drift_mm(t0) + cfg.height_noise_mm * normal(rng);
        h -= real;
        let after = h - fx.drift_mm(t1) + cfg.height_noise_mm * normal(rng);
        removed_mm3 += real * cfg.contact_area_mm2;
        cols.0.push(pass);
        cols.1.push(stage);
        cols.2.push(doc);
        cols.3.push(cfg.grind_feed_mm_s);
        cols.4.push(before);
        cols.5.push(after);
        cols.6.push(t0);
        cols.7.push(t1);
        t = t1 + PASS_PAUSE_S;
    }
    let batch = BatchBuilder::new()
        .i32("pass", cols.0)
        .str("stage", &cols.1)
        .f64("nominal_doc_mm", cols.2)
        .f64("feed_mm_s", cols.3)
        .f64("height_before_mm", cols.4)
        .f64("height_after_mm", cols.5)
        .f64("t_start_s", cols.6)
        .f64("t_end_s", cols.7)
        .build();
    (batch, truth)
}

/// `started`: 2026-11-20T08:00:00Z plus 15 minutes per run index.
pub(super) fn started(index: usize) -> String {
    crate::started::started_at(crate::started::FirstStart::at(2026, 11, 20, 8), 15, index)
}

pub(super) fn run_toml(
    cfg: &RobotFleetConfig,
    run_id: &str,
    index: usize,
    clock_offset_s: f64,
) -> String {
    format!(
        r#"# Generated by sparkout-datasets (robot fleet generator, seed {seed}).
[run]
id = "{run_id}"
machine = "{machine}"
plugin = "robot"
started = "{started}"

[process]
weld_mm = {weld:?}
contact_area_mm2 = {area:?}
doc_rough_mm = {dr:?}
doc_finish_mm = {df:?}
rough_passes = {nr}
finish_passes = {nf}
spark_passes = {ns}
feed_mm_s = {feed:?}
pass_length_mm = {plen:?}
standoff_mm = {standoff:?}
motion_rate_hz = {mrate:?}
block_size_mm = [{bx:?}, {by:?}, {bh:?}]

[ae]
sample_rate_hz = {fs:?}
kind = "{kind}"
clock_offset_s = {off:?}
"#,
        seed = cfg.seed,
        machine = cfg.machine,
        started = started(index),
        weld = cfg.weld_mm,
        area = cfg.contact_area_mm2,
        dr = cfg.doc_rough_mm,
        df = cfg.doc_finish_mm,
        nr = cfg.rough_passes,
        nf = cfg.finish_passes,
        ns = cfg.spark_passes,
        feed = cfg.grind_feed_mm_s,
        plen = PASS_LENGTH_MM,
        standoff = cfg.standoff_mm,
        mrate = cfg.motion_rate_hz,
        bx = BLOCK_X_MM,
        by = BLOCK_Y_MM,
        bh = BLOCK_H_MM,
        fs = cfg.ae_sample_rate_hz,
        kind = cfg.ae_signal.label(),
        off = clock_offset_s,
    )
}
