//! The robot plugin's stages on small runs built here (not by the fleet
//! generator): AE contact detection against known contact times, the datum
//! against the known block pose, the trigger latency from two approach
//! speeds, recorded vs AE-derived touches, the cycle model, observations,
//! report sections, and every bad input docs/formats.md names for it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{Array, Float64Array, Int32Array, StringArray};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::{
    read_parquet, write_parquet_atomic, write_parquet_batches_atomic, BatchBuilder, MachineResolver,
};
use sparkout_pipeline::engine::{Engine, PipelineConfig, Quiet};
use sparkout_pipeline::{InputError, MachinePlugin, StageArgs, StageOutput};

// ---------------------------------------------------------------- helpers

type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn axis(k: usize) -> V3 {
    let mut v = [0.0; 3];
    v[k] = 1.0;
    v
}
/// Small rotation R = Rz·Ry·Rx applied to v.
fn rotate(r: V3, v: V3) -> V3 {
    let (sx, cx) = r[0].sin_cos();
    let (sy, cy) = r[1].sin_cos();
    let (sz, cz) = r[2].sin_cos();
    let v = [v[0], cx * v[1] - sx * v[2], sx * v[1] + cx * v[2]];
    let v = [cy * v[0] + sy * v[2], v[1], -sy * v[0] + cy * v[2]];
    [cz * v[0] - sz * v[1], sz * v[0] + cz * v[1], v[2]]
}

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / ((1u64 << 53) as f64)
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

const FACES: [(&str, usize, usize, usize); 3] = [("xy", 2, 0, 1), ("yz", 0, 1, 2), ("zx", 1, 0, 2)];

/// How to build a run.
#[derive(Clone)]
struct Spec {
    speeds: Vec<f64>,
    trials: i32,
    /// 4 (outer square) or 12 (three squares).
    points: i32,
    /// Controller trigger latency (s) of the registered touches.
    latency_s: f64,
    /// Registration noise of probe touches along the normal (mm).
    probe_noise_mm: f64,
    /// Encoder noise of act_* (mm).
    act_noise_mm: f64,
    with_probe: bool,
    with_ae: bool,
    with_passes: bool,
    /// Bursts at contacts (false: an AE log without contact).
    bursts: bool,
    ae_rate_hz: f64,
    clock_offset_s: f64,
    origin: V3,
    rotation: V3,
    seed: u64,
}

impl Default for Spec {
    fn default() -> Self {
        Spec {
            speeds: vec![5.0, 10.0],
            trials: 2,
            points: 12,
            latency_s: 0.004,
            probe_noise_mm: 0.002,
            act_noise_mm: 0.002,
            with_probe: false,
            with_ae: true,
            with_passes: true,
            bursts: true,
            ae_rate_hz: 200_000.0,
            clock_offset_s: 0.0123,
            origin: [400.2, 99.9, 300.05],
            rotation: [0.0008, -0.0005, 0.001],
            seed: 1,
        }
    }
}

/// What the test knows and the stages must find.
struct Truth {
    origin: V3,
    /// (seq, controller time of the true contact).
    contacts: Vec<(i32, f64)>,
}

struct PlanRow {
    seq: i32,
    face: &'static str,
    point: i32,
    trial: i32,
    v: f64,
    nom: V3,
    dir: V3,
}

fn write_run(root: &Path, id: &str, s: &Spec) -> (PathBuf, Truth) {
    let dir = root.join("kr16-lab").join(id);
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = Rng(s.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 7);
    let nominal_origin = [400.0, 100.0, 300.0];
    // True planes: faces through the true corner with rotated normals.
    let normals: Vec<V3> = FACES
        .iter()
        .map(|f| rotate(s.rotation, axis(f.1)))
        .collect();
    let ds: Vec<f64> = normals.iter().map(|n| dot(*n, s.origin)).collect();
    // The plan: every point of every face, trials × speeds.
    let mut plan = Vec::new();
    for &v in &s.speeds {
        for (fi, f) in FACES.iter().enumerate() {
            let _ = fi;
            for point in 0..s.points {
                let half = [15.0, 10.0, 5.0][(point / 4) as usize];
                let c = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)][(point % 4) as usize];
                let mut nom = nominal_origin;
                nom[f.2] -= 25.0 + c.0 * half;
                nom[f.3] -= 25.0 + c.1 * half;
                for trial in 0..s.trials {
                    plan.push(PlanRow {
                        seq: plan.len() as i32,
                        face: f.0,
                        point,
                        trial,
                        v,
                        nom,
                        dir: scale(axis(f.1), -1.0),
                    });
                }
            }
        }
    }
    // Motion: move 50 ms to a standoff 0.5 mm outside, approach along dir
    // until the controller registers (contact + latency), stop 10 ms.
    struct Piece {
        t0: f64,
        t1: f64,
        p0: V3,
        p1: V3,
        seg: i32,
    }
    let mut pieces = Vec::new();
    let mut t = 0.05;
    let mut pos = add(nominal_origin, [5.0, 5.0, 5.0]);
    let mut contacts = Vec::new();
    let mut probe = Vec::new();
    for r in &plan {
        let fi = FACES.iter().position(|f| f.0 == r.face).unwrap();
        let start = add(r.nom, scale(r.dir, -0.5));
        pieces.push(Piece {
            t0: t,
            t1: t + 0.05,
            p0: pos,
            p1: start,
            seg: -1,
        });
        t += 0.05;
        let (n, d) = (normals[fi], ds[fi]);
        let tc = (d - dot(n, start)) / (r.v * dot(n, r.dir));
        assert!(
            tc > 0.02 && tc < 0.5 / r.v * 2.0,
            "contact inside the approach"
        );
        let t_contact = t + tc;
        let t_stop = t_contact + s.latency_s;
        let stop = add(start, scale(r.dir, r.v * (t_stop - t)));
        pieces.push(Piece {
            t0: t,
            t1: t_stop,
            p0: start,
            p1: stop,
            seg: r.seq,
        });
        contacts.push((r.seq, t_contact));
        let reg = add(stop, scale(r.dir, s.probe_noise_mm * rng.normal()));
        probe.push((t_stop, r, reg));
        pieces.push(Piece {
            t0: t_stop,
            t1: t_stop + 0.01,
            p0: stop,
            p1: stop,
            seg: -1,
        });
        t = t_stop + 0.01;
        pos = stop;
    }
    let t_end = t + 0.05;
    let rate = 1000.0;
    let n_motion = (t_end * rate) as usize;
    let (mut mt, mut cmd, mut act, mut seg) = (
        Vec::new(),
        [vec![], vec![], vec![]],
        [vec![], vec![], vec![]],
        Vec::new(),
    );
    let mut k = 0;
    for i in 0..n_motion {
        let ti = i as f64 / rate;
        while k + 1 < pieces.len() && ti > pieces[k].t1 {
            k += 1;
        }
        let pc = &pieces[k];
        let (p, sg) = if ti < pc.t0 {
            (pc.p0, -1)
        } else if ti > pc.t1 {
            (pc.p1, -1)
        } else {
            let w = if pc.t1 > pc.t0 {
                (ti - pc.t0) / (pc.t1 - pc.t0)
            } else {
                0.0
            };
            (add(pc.p0, scale(add(pc.p1, scale(pc.p0, -1.0)), w)), pc.seg)
        };
        mt.push(ti);
        seg.push(sg);
        for a in 0..3 {
            cmd[a].push(p[a]);
            act[a].push(p[a] + s.act_noise_mm * rng.normal());
        }
    }
    let motion = BatchBuilder::new()
        .f64("t_s", mt)
        .f64("cmd_x_mm", cmd[0].clone())
        .f64("cmd_y_mm", cmd[1].clone())
        .f64("cmd_z_mm", cmd[2].clone())
        .f64("act_x_mm", act[0].clone())
        .f64("act_y_mm", act[1].clone())
        .f64("act_z_mm", act[2].clone())
        .i32("segment", seg)
        .build();
    write_parquet_atomic(&dir.join("motion.parquet"), &motion).unwrap();
    let col = |f: &dyn Fn(&PlanRow) -> f64| plan.iter().map(f).collect::<Vec<f64>>();
    let plan_b = BatchBuilder::new()
        .i32("seq", plan.iter().map(|r| r.seq).collect())
        .str("face", &plan.iter().map(|r| r.face).collect::<Vec<_>>())
        .i32("point", plan.iter().map(|r| r.point).collect())
        .i32("trial", plan.iter().map(|r| r.trial).collect())
        .str("method", &vec!["ae"; plan.len()])
        .f64("approach_mm_s", col(&|r| r.v))
        .f64("nom_x_mm", col(&|r| r.nom[0]))
        .f64("nom_y_mm", col(&|r| r.nom[1]))
        .f64("nom_z_mm", col(&|r| r.nom[2]))
        .f64("dir_x", col(&|r| r.dir[0]))
        .f64("dir_y", col(&|r| r.dir[1]))
        .f64("dir_z", col(&|r| r.dir[2]))
        .build();
    write_parquet_atomic(&dir.join("plan.parquet"), &plan_b).unwrap();
    if s.with_probe {
        let pc =
            |f: &dyn Fn(&(f64, &PlanRow, V3)) -> f64| probe.iter().map(f).collect::<Vec<f64>>();
        let b = BatchBuilder::new()
            .f64("t_s", pc(&|p| p.0))
            .str("face", &probe.iter().map(|p| p.1.face).collect::<Vec<_>>())
            .i32("point", probe.iter().map(|p| p.1.point).collect())
            .i32("trial", probe.iter().map(|p| p.1.trial).collect())
            .str("method", &vec!["ae"; probe.len()])
            .f64("approach_mm_s", pc(&|p| p.1.v))
            .f64("nom_x_mm", pc(&|p| p.1.nom[0]))
            .f64("nom_y_mm", pc(&|p| p.1.nom[1]))
            .f64("nom_z_mm", pc(&|p| p.1.nom[2]))
            .f64("x_mm", pc(&|p| p.2[0]))
            .f64("y_mm", pc(&|p| p.2[1]))
            .f64("z_mm", pc(&|p| p.2[2]))
            .build();
        write_parquet_atomic(&dir.join("probe.parquet"), &b).unwrap();
    }
    if s.with_ae {
        // Triggered recorder: 20 ms around each contact, in the AE clock
        // (controller time − clock offset), on the global sample grid.
        let fs = s.ae_rate_hz;
        let mut batches = Vec::new();
        for &(_, tc) in &contacts {
            let t_ae = tc - s.clock_offset_s;
            let (i0, i1) = (
                ((t_ae - 0.010) * fs).ceil() as i64,
                ((t_ae + 0.010) * fs) as i64,
            );
            let (mut ts, mut vs) = (Vec::new(), Vec::new());
            for i in i0..i1 {
                let ti = i as f64 / fs;
                let mut x = 0.005 * rng.normal();
                if s.bursts && ti >= t_ae {
                    let dt = ti - t_ae;
                    x += 0.15 * (-dt / 2e-3).exp() * (2.0 * std::f64::consts::PI * 40e3 * dt).sin();
                }
                ts.push(ti);
                vs.push(x as f32);
            }
            batches.push(BatchBuilder::new().f64("t_s", ts).f32("ae_v", vs).build());
        }
        let schema = batches[0].schema();
        write_parquet_batches_atomic(&dir.join("ae.parquet"), schema, batches.into_iter().map(Ok))
            .unwrap();
    }
    let mut toml = format!(
        "[run]\nid = \"{id}\"\nmachine = \"kr16-lab\"\nplugin = \"robot\"\nstarted = \"2026-11-20T08:00:00Z\"\n[process]\nweld_mm = 2.27\ncontact_area_mm2 = 100.0\n"
    );
    if s.with_ae {
        toml.push_str(&format!(
            "[ae]\nsample_rate_hz = {}\nkind = \"raw\"\nclock_offset_s = {}\n",
            s.ae_rate_hz, s.clock_offset_s
        ));
    }
    std::fs::write(dir.join("run.toml"), toml).unwrap();
    if s.with_passes {
        // docs/models.md §1.4 with α = 0.5, heights measured to ±1 µm.
        let docs = [0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.0, 0.0];
        let stages = [
            "rough", "rough", "rough", "rough", "rough", "rough", "rough", "finish", "finish",
            "spark", "spark",
        ];
        let mut h = 102.27;
        let mut prev = 0.0;
        let (mut hb, mut ha, mut t0, mut t1) = (vec![], vec![], vec![], vec![]);
        for (i, dp) in docs.iter().enumerate() {
            let cut = (dp + 0.5 * prev) / 1.5;
            prev = cut;
            hb.push(h + 0.001 * rng.normal());
            h -= cut;
            ha.push(h + 0.001 * rng.normal());
            t0.push(t_end + 20.0 * i as f64);
            t1.push(t_end + 20.0 * i as f64 + 15.0);
        }
        // Heights are read once: each pass's "before" is the previous "after".
        let n = hb.len();
        hb[1..].copy_from_slice(&ha[..n - 1]);
        let b = BatchBuilder::new()
            .i32("pass", (1..=docs.len() as i32).collect())
            .str("stage", &stages)
            .f64("nominal_doc_mm", docs.to_vec())
            .f64("feed_mm_s", vec![20.0; docs.len()])
            .f64("height_before_mm", hb)
            .f64("height_after_mm", ha)
            .f64("t_start_s", t0)
            .f64("t_end_s", t1)
            .build();
        write_parquet_atomic(&dir.join("passes.parquet"), &b).unwrap();
    }
    (
        dir,
        Truth {
            origin: s.origin,
            contacts,
        },
    )
}

fn engine(config: &str) -> Engine {
    let plugins = sparkout_plugins::all_plugins();
    let builtins: BTreeMap<String, String> = plugins
        .iter()
        .flat_map(|p| p.builtin_machines())
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    // Only the built-in machines: the tests must not depend on the cwd.
    let resolver = MachineResolver {
        dirs: Vec::new(),
        builtins,
    };
    let mut cfg = PipelineConfig::builtin();
    for line in config.lines().filter(|l| !l.trim().is_empty()) {
        cfg.set(line.trim()).unwrap();
    }
    Engine::new(plugins, resolver, cfg).unwrap()
}

fn stage(dir: &Path, name: &str) -> sparkout_pipeline::Result<StageOutput> {
    engine("").run_single_stage(dir, name).map(|(_, o)| o)
}

fn input_error(e: &sparkout_pipeline::Error) -> &InputError {
    e.input()
        .unwrap_or_else(|| panic!("not an input error: {e:#}"))
}

fn f64s(b: &RecordBatch, name: &str) -> Vec<f64> {
    let a = b
        .column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap();
    (0..a.len())
        .map(|i| if a.is_null(i) { f64::NAN } else { a.value(i) })
        .collect()
}
fn i32s(b: &RecordBatch, name: &str) -> Vec<i32> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<Int32Array>()
        .unwrap()
        .values()
        .to_vec()
}
fn strs(b: &RecordBatch, name: &str) -> Vec<String> {
    let a = b
        .column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<StringArray>()
        .unwrap();
    (0..a.len()).map(|i| a.value(i).to_string()).collect()
}
fn artifact<'a>(o: &'a StageOutput, name: &str) -> &'a RecordBatch {
    &o.artifacts
        .iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no artifact {name}"))
        .1
}

// ------------------------------------------------------------------ tests

#[test]
fn ae_contacts_within_one_window_of_the_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, truth) = write_run(tmp.path(), "r0000", &Spec::default());
    let out = stage(&dir, "ingest").unwrap();
    assert_eq!(out.summary["touch_source"], "ae");
    let touches = artifact(&out, "touches");
    assert_eq!(touches.num_rows(), truth.contacts.len(), "{}", out.summary);
    let seq = i32s(touches, "seq");
    let t = f64s(touches, "t_s");
    let window_s = 0.001;
    for (s, ti) in seq.iter().zip(&t) {
        let tc = truth.contacts.iter().find(|c| c.0 == *s).unwrap().1;
        assert!(
            *ti >= tc - 1e-5 && *ti - tc <= window_s,
            "seq {s}: {ti} vs truth {tc}"
        );
    }
    let contacts = artifact(&out, "contacts");
    assert_eq!(contacts.num_rows(), truth.contacts.len());
    assert!(strs(contacts, "role").iter().all(|r| r == "touch"));
    assert!(f64s(contacts, "threshold_v")
        .iter()
        .all(|&v| v > 0.005 && v < 0.01));
    assert!(out.summary["compare"].is_null());
}

#[test]
fn datum_within_its_uncertainty_of_the_true_pose() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, truth) = write_run(
        tmp.path(),
        "r0001",
        &Spec {
            seed: 5,
            ..Spec::default()
        },
    );
    let out = stage(&dir, "datum").unwrap();
    let s = &out.summary;
    let p: Vec<f64> = s["datum_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let sig: Vec<f64> = s["datum_sigma_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for a in 0..3 {
        let e = p[a] - truth.origin[a];
        assert!(sig[a] > 0.0 && sig[a] < 0.005, "σ {sig:?}");
        assert!(
            e.abs() < 4.0 * sig[a],
            "axis {a}: datum {} vs truth {} (σ {})",
            p[a],
            truth.origin[a],
            sig[a]
        );
    }
    // The block is rigid: squareness at the noise level (a few 10⁻⁵ rad).
    for k in ["xy_yz", "yz_zx", "zx_xy"] {
        assert!(
            s["squareness_rad"][k].as_f64().unwrap().abs() < 2e-4,
            "{}",
            s["squareness_rad"]
        );
    }
    // Issue JSON shape.
    for f in ["xy", "yz", "zx"] {
        let pl = &s["planes"][f];
        assert_eq!(pl["ols"].as_array().unwrap().len(), 3);
        assert_eq!(pl["tls_normal"].as_array().unwrap().len(), 3);
        assert!(
            pl["tls_d"].is_number()
                && pl["residual_rms_mm"].is_number()
                && pl["residual_max_mm"].is_number()
        );
    }
    assert_eq!(s["datum_cov_mm2"].as_array().unwrap().len(), 3);
    assert_eq!(s["error_vector_mm"].as_array().unwrap().len(), 3);
    assert_eq!(s["by_square"].as_array().unwrap().len(), 3);
    let planes = artifact(&out, "planes");
    assert!(planes.num_rows() >= 6);
    let datum = artifact(&out, "datum");
    assert_eq!(strs(datum, "scope")[0], "all");
}

#[test]
fn latency_from_two_speeds_and_recorded_vs_ae_touches() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = Spec {
        with_probe: true,
        latency_s: 0.004,
        seed: 9,
        ..Spec::default()
    };
    let (dir, _) = write_run(tmp.path(), "r0002", &spec);
    let out = stage(&dir, "repeatability").unwrap();
    let s = &out.summary;
    let l = s["latency_s"].as_f64().unwrap();
    let se = s["latency_by_method"]["ae"]["stderr_s"].as_f64().unwrap();
    assert!((l - 0.004).abs() < 4.0 * se + 1e-4, "latency {l} ± {se}");
    let groups = s["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 2);
    for g in groups {
        assert!(g["mean_range_mm"].as_f64().unwrap() < 0.02);
        assert_eq!(g["faces"]["xy"]["n"].as_u64(), Some(24));
    }
    // Both recorded and AE touches: the comparison says the controller
    // registers ≈ L after the AE contact, and overshoots by v·L.
    let ing = stage(&dir, "ingest").unwrap();
    assert_eq!(ing.summary["touch_source"], "probe");
    let c = &ing.summary["compare"];
    assert_eq!(c["n"].as_u64(), Some(144));
    let dt = c["mean_dt_s"].as_f64().unwrap();
    assert!((dt - 0.004).abs() < 3e-4, "mean dt {dt}");
    let cmp = artifact(&ing, "touch_compare");
    let v = f64s(cmp, "approach_mm_s");
    let dn = f64s(cmp, "dnormal_mm");
    let mean_dn = |speed: f64| {
        let x: Vec<f64> = v
            .iter()
            .zip(&dn)
            .filter(|p| *p.0 == speed)
            .map(|p| *p.1)
            .collect();
        x.iter().sum::<f64>() / x.len() as f64
    };
    assert!((mean_dn(10.0) + 0.04).abs() < 0.003, "{}", mean_dn(10.0));
    assert!((mean_dn(5.0) + 0.02).abs() < 0.003, "{}", mean_dn(5.0));
}

#[test]
fn cycle_observe_and_report_sections() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = write_run(
        tmp.path(),
        "r0003",
        &Spec {
            seed: 11,
            trials: 1,
            ..Spec::default()
        },
    );
    let out = stage(&dir, "cycle").unwrap();
    let s = &out.summary;
    let a = s["alpha_first_pass"].as_f64().unwrap();
    assert!((a - 0.5).abs() < 0.05, "α {a}");
    assert!((s["alpha_fit"].as_f64().unwrap() - 0.5).abs() < 0.03);
    assert_eq!(s["passes"].as_array().unwrap().len(), 11);
    assert!((s["remaining_after_mm"]["rough"].as_f64().unwrap() - 0.3199).abs() < 0.02);
    assert!(s["tau_s"]["20"].as_f64().unwrap() > 0.0);
    let obs = stage(&dir, "observe").unwrap();
    let b = artifact(&obs, "observations");
    let names = strs(b, "observable");
    let n_touch = names.iter().filter(|n| *n == "touch_normal_ae").count();
    let n_cut = names.iter().filter(|n| *n == "cut_depth").count();
    assert_eq!((n_touch, n_cut), (72, 11));
    assert!(strs(b, "run").iter().all(|r| r == "r0003"));
    let (sim, real) = (f64s(b, "sim"), f64s(b, "real"));
    assert!(sim.iter().chain(&real).all(|v| v.is_finite()));
    // touch_normal_ae rows (AE-derived touches) have positions, cut_depth rows have passes; the
    // other covariates are null.
    let x = f64s(b, "x_mm");
    let doc = f64s(b, "nominal_doc_mm");
    let an = f64s(b, "approach_normal_mm_s");
    for (i, n) in names.iter().enumerate() {
        assert_eq!(n == "touch_normal_ae", x[i].is_finite());
        assert_eq!(n == "cut_depth", doc[i].is_finite());
        if n == "touch_normal_ae" {
            assert!(an[i] == -5.0 || an[i] == -10.0);
        }
    }
    // A touch gap at the noise level (AE touches have no latency).
    let gaps: Vec<f64> = (0..names.len())
        .filter(|&i| names[i] == "touch_normal_ae")
        .map(|i| real[i] - sim[i])
        .collect();
    let rms = (gaps.iter().map(|g| g * g).sum::<f64>() / gaps.len() as f64).sqrt();
    assert!(rms < 0.005, "touch gap rms {rms}");
    // Report sections from a full in-memory chain.
    let plugin = sparkout_plugins::robot::RobotPlugin;
    let eng = engine("");
    let (run, _) = eng.open_run(&dir).unwrap();
    let store = sparkout_pipeline::ArtifactStore::default();
    for st in ["ingest", "repeatability", "datum", "cycle"] {
        let o = stage(&dir, st).unwrap();
        for (n, b) in &o.artifacts {
            store.insert(n, b.clone());
        }
        store.set_summary(st, o.summary.clone());
    }
    let sections = plugin.report_sections(&run, &store);
    let titles: Vec<&str> = sections.iter().map(|s| s.title.as_str()).collect();
    assert!(
        titles.iter().any(|t| t.contains("Repeatability")),
        "{titles:?}"
    );
    assert!(titles.iter().any(|t| t.contains("planes")));
    assert!(titles.iter().any(|t| t.contains("Datum")));
    assert!(titles.iter().any(|t| t.contains("cycle")));
    // The run was probed by AE: how the contacts were found, without warning.
    let ae = sections
        .iter()
        .find(|s| s.title == "AE contact detection")
        .unwrap_or_else(|| panic!("{titles:?}"));
    assert!(ae.html.contains("raw AE signal") && !ae.html.contains("fragmented"));
    assert!(sections.iter().all(|s| !s.html.is_empty()));
    assert!(sections.iter().any(|s| s.html.contains("<svg")));
}

#[test]
fn probing_only_run_has_an_empty_cycle() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = write_run(
        tmp.path(),
        "r0004",
        &Spec {
            with_passes: false,
            with_probe: true,
            with_ae: false,
            points: 4,
            trials: 2,
            ..Spec::default()
        },
    );
    let out = stage(&dir, "cycle").unwrap();
    assert!(out.summary["note"].as_str().unwrap().contains("no passes"));
    assert_eq!(artifact(&out, "cycle").num_rows(), 0);
    let obs = stage(&dir, "observe").unwrap();
    let names = strs(artifact(&obs, "observations"), "observable");
    assert!(names.iter().all(|n| n == "touch_normal") && names.len() == 48);
}

#[test]
fn standalone_datum_and_cycle() {
    let eng = engine("");
    let args = |kv: &[(&str, &str)]| -> StageArgs {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    };
    let d = eng.find_stage("datum").unwrap();
    let v = d
        .run_standalone(&args(&[("planes", "0,0,1,12.4445; 1,0,0,-20; 0,1,0,-13")]))
        .unwrap()
        .unwrap();
    assert_eq!(v["datum_mm"], serde_json::json!([20.0, 13.0, -12.4445]));
    let c = eng.find_stage("cycle").unwrap();
    let v = c
        .run_standalone(&args(&[
            ("weld-mm", "2.27"),
            ("rough", "7"),
            ("finish", "2"),
            ("spark", "2"),
            ("doc-rough", "0.3"),
            ("doc-finish", "0.1"),
            ("first-cut", "0.2"),
        ]))
        .unwrap()
        .unwrap();
    let cuts: Vec<f64> = v["passes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["predicted_cut_mm"].as_f64().unwrap())
        .collect();
    let thesis = [0.200, 0.2667, 0.2889, 0.2963, 0.2988, 0.2996, 0.2999];
    for (c, t) in cuts.iter().zip(thesis) {
        assert!((c - t).abs() < 5e-5);
    }
    assert!((v["remaining_after_mm"]["rough"].as_f64().unwrap() - 0.3199).abs() < 5e-5);
}

#[test]
fn config_keys_are_checked() {
    let plugins = sparkout_plugins::all_plugins();
    let resolver = MachineResolver::default();
    let mut cfg = PipelineConfig::builtin();
    cfg.set("robot.ingest.k_sigmaa=3").unwrap();
    let e = Engine::new(plugins.clone(), resolver.clone(), cfg)
        .err()
        .unwrap();
    assert!(format!("{e:#}").contains("k_sigmaa"), "{e:#}");
    let mut cfg = PipelineConfig::builtin();
    cfg.set("robot.ingest.k_sigma=-1").unwrap();
    let e = Engine::new(plugins.clone(), resolver.clone(), cfg)
        .err()
        .unwrap();
    assert!(format!("{e:#}").contains("k_sigma"), "{e:#}");
    let mut cfg = PipelineConfig::builtin();
    cfg.set("robot.datum.fit=\"lsq\"").unwrap();
    assert!(Engine::new(plugins, resolver, cfg).is_err());
}

// ------------------------------------------------------------ bad inputs

fn rewrite(path: &Path, f: impl Fn(RecordBatch) -> RecordBatch) {
    let b = read_parquet(path).unwrap();
    write_parquet_atomic(path, &f(b)).unwrap();
}

/// Replace a column of a batch.
fn with_col(b: RecordBatch, name: &str, col: Arc<dyn Array>) -> RecordBatch {
    let i = b.schema().index_of(name).unwrap();
    let mut cols = b.columns().to_vec();
    cols[i] = col;
    RecordBatch::try_new(b.schema(), cols).unwrap()
}

#[test]
fn ae_without_contact_says_noise_floor_and_threshold() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = write_run(
        tmp.path(),
        "r0010",
        &Spec {
            bursts: false,
            points: 4,
            trials: 1,
            ..Spec::default()
        },
    );
    let e = stage(&dir, "ingest").err().unwrap();
    let ie = input_error(&e);
    assert!(ie.file.ends_with("ae.parquet"), "{ie}");
    assert!(
        ie.message.contains("no contact")
            && ie.message.contains("noise floor")
            && ie.message.contains("threshold"),
        "{ie}"
    );
}

#[test]
fn unknown_face_label_names_file_column_row() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = write_run(
        tmp.path(),
        "r0011",
        &Spec {
            with_probe: true,
            with_ae: false,
            points: 4,
            trials: 1,
            ..Spec::default()
        },
    );
    rewrite(&dir.join("probe.parquet"), |b| {
        let mut f = strs(&b, "face");
        f[5] = "xz".into();
        with_col(b, "face", Arc::new(StringArray::from(f)))
    });
    let e = stage(&dir, "ingest").err().unwrap();
    let ie = input_error(&e);
    assert!(
        ie.file.ends_with("probe.parquet")
            && ie.column.as_deref() == Some("face")
            && ie.row == Some(5),
        "{ie}"
    );
    assert!(ie.message.contains("xz"));
}

fn probe_run(tmp: &Path, id: &str) -> PathBuf {
    write_run(
        tmp,
        id,
        &Spec {
            with_probe: true,
            with_ae: false,
            points: 4,
            trials: 1,
            speeds: vec![5.0],
            ..Spec::default()
        },
    )
    .0
}

/// Keep only the probe rows for which `keep(face, point)` holds.
fn filter_probe(dir: &Path, keep: impl Fn(&str, i32) -> bool) {
    rewrite(&dir.join("probe.parquet"), |b| {
        let f = strs(&b, "face");
        let p = i32s(&b, "point");
        let mask: arrow::array::BooleanArray =
            f.iter().zip(&p).map(|(f, p)| Some(keep(f, *p))).collect();
        arrow::compute::filter_record_batch(&b, &mask).unwrap()
    });
}

#[test]
fn fewer_than_three_points_on_a_face() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = probe_run(tmp.path(), "r0012");
    filter_probe(&dir, |f, p| f != "zx" || p < 2);
    let e = stage(&dir, "datum").err().unwrap();
    let ie = input_error(&e);
    assert!(ie.file.ends_with("probe.parquet"), "{ie}");
    assert!(
        ie.message.contains("zx") && ie.message.contains("at least 3"),
        "{ie}"
    );
}

#[test]
fn collinear_points_on_a_face() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = probe_run(tmp.path(), "r0013");
    // Put the yz face's touches on one line (z follows y).
    rewrite(&dir.join("probe.parquet"), |b| {
        let f = strs(&b, "face");
        let y = f64s(&b, "y_mm");
        let mut z = f64s(&b, "z_mm");
        for i in 0..z.len() {
            if f[i] == "yz" {
                z[i] = 300.0 - 100.0 + y[i];
            }
        }
        with_col(b, "z_mm", Arc::new(Float64Array::from(z)))
    });
    let e = stage(&dir, "datum").err().unwrap();
    let ie = input_error(&e);
    assert!(
        ie.message.contains("collinear") && ie.message.contains("yz"),
        "{ie}"
    );
}

#[test]
fn nearly_parallel_faces_are_an_ill_conditioned_datum() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = probe_run(tmp.path(), "r0014");
    // The zx face's touches re-measured on a plane tilted 87° away from
    // its nominal normal: nearly parallel to the xy face.
    rewrite(&dir.join("probe.parquet"), |b| {
        let f = strs(&b, "face");
        let (x, z) = (f64s(&b, "x_mm"), f64s(&b, "z_mm"));
        let mut y = f64s(&b, "y_mm");
        let tilt = 3.0f64.to_radians();
        for i in 0..y.len() {
            if f[i] == "zx" {
                // Plane sin(tilt)·y + cos(tilt)·(z − 300) = 0 through the x-range.
                y[i] = 100.0 - (z[i] - 300.0 + 0.1 * (x[i] - 400.0)) / tilt.tan();
            }
        }
        with_col(b, "y_mm", Arc::new(Float64Array::from(y)))
    });
    let e = stage(&dir, "datum").err().unwrap();
    let ie = input_error(&e);
    assert!(
        ie.message.contains("nearly parallel") && ie.message.contains("condition"),
        "{ie}"
    );
}

#[test]
fn motion_log_not_covering_a_contact() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, truth) = write_run(
        tmp.path(),
        "r0015",
        &Spec {
            points: 4,
            trials: 1,
            ..Spec::default()
        },
    );
    let last = truth.contacts.last().unwrap().1;
    rewrite(&dir.join("motion.parquet"), |b| {
        let t = f64s(&b, "t_s");
        let n = t.iter().position(|&x| x > last - 0.02).unwrap();
        b.slice(0, n)
    });
    let e = stage(&dir, "ingest").err().unwrap();
    let ie = input_error(&e);
    assert!(
        ie.file.ends_with("motion.parquet") && ie.column.as_deref() == Some("t_s"),
        "{ie}"
    );
    assert!(ie.message.contains("does not cover"), "{ie}");
}

#[test]
fn a_bad_run_is_rejected_and_the_others_go_on() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("runs");
    let small = Spec {
        points: 4,
        trials: 2,
        ..Spec::default()
    };
    write_run(&root, "r0020", &small);
    write_run(
        &root,
        "r0021",
        &Spec {
            seed: 2,
            ..small.clone()
        },
    );
    let (bad, _) = write_run(
        &root,
        "r0022",
        &Spec {
            bursts: false,
            ..small.clone()
        },
    );
    let out = tmp.path().join("out");
    let eng = engine("pipeline.stages=[\"ingest\",\"repeatability\",\"datum\",\"cycle\"]");
    let o = eng.run_fleet(&root, &out, Some(2), &Quiet).unwrap();
    assert_eq!(o.runs.len(), 2);
    assert_eq!(o.failures.len(), 1);
    let f = &o.failures[0];
    assert_eq!(f.run.as_deref(), Some("r0022"));
    assert_eq!(f.stage.as_deref(), Some("ingest"));
    assert!(f.error.contains("no contact"), "{}", f.error);
    assert!(
        !out.join("kr16-lab").join("r0022").exists(),
        "nothing of a rejected run is written"
    );
    let _ = bad;
    for r in ["r0020", "r0021"] {
        let d = out.join("kr16-lab").join(r);
        for a in [
            "touches",
            "contacts",
            "repeatability",
            "planes",
            "datum",
            "cycle",
        ] {
            assert!(d.join(format!("{a}.parquet")).is_file(), "{r}/{a}");
        }
        let rep = std::fs::read_to_string(d.join("report.html")).unwrap();
        assert!(rep.contains("Datum and its uncertainty"));
    }
}
