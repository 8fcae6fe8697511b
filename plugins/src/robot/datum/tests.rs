use super::*;
use crate::robot::repeatability::tests::synth_touches;

#[test]
fn standalone_planes_give_their_intersection() {
    // x = 1, y = 2, z = 3 given in scrambled order and scale.
    let args: StageArgs = [(
        "planes".to_string(),
        "0,0,2,-6; 1,0,0,-1; 0,-1,0,2".to_string(),
    )]
    .into_iter()
    .collect();
    let v = DatumStage.run_standalone(&args).unwrap().unwrap();
    let v: DatumStandalone = serde_json::from_value(v).unwrap();
    let p = v.datum_mm.unwrap();
    assert!((p[0] - 1.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12 && (p[2] - 3.0).abs() < 1e-12);
    assert_eq!(v.planes["xy"].ols.map(|o| o[0]), Some(3.0));
    let GivenSquareness::Faces(sq) = &v.squareness_rad else {
        panic!("planes facing three axes are labelled by face: {v:?}");
    };
    assert!(sq.xy_yz.unwrap().abs() < 1e-15);
    let bad: StageArgs = [(
        "planes".to_string(),
        "0,0,1,0;0,0.01,1,-1;1,0,0,0".to_string(),
    )]
    .into_iter()
    .collect();
    let e = DatumStage.run_standalone(&bad).unwrap().unwrap_err();
    assert!(e.to_string().contains("nearly parallel"), "{e}");
}

#[test]
fn datum_of_synthetic_block_within_its_uncertainty() {
    let origin = Vector3::new(100.0, 200.0, -12.0);
    let ts = synth_touches(origin, &[5.0], 5, 0.0, 0.01, 21);
    let cfg = DatumConfig::default();
    let a = analyse(&ts, &cfg, std::path::Path::new("probe.parquet")).unwrap();
    let err = a.main.datum.p - origin;
    let cov = a.main.datum.cov;
    // Mahalanobis distance within the 99.9 % region of χ²₃.
    let m = err.dot(&(cov.try_inverse().unwrap() * err));
    assert!(m < 16.3, "datum error {err} vs cov {cov}");
    assert_eq!(a.squares.len(), 3);
    let s = summary(&ts, &a, &cfg, "ae");
    // E ≈ −α for near-axis-aligned planes.
    let e0 = s.error_vector_mm.unwrap()[0];
    assert!((e0 + a.alpha_mm[1].unwrap()).abs() < 1e-3);
    assert!(s.datum_ellipsoid_mm.semi_axes_mm[0].unwrap() > 0.0);
}

#[test]
fn trigger_latency_is_removed_before_the_datum() {
    // 20 ms at 5 and 10 mm/s: 0.1–0.2 mm of overshoot into each face.
    let origin = Vector3::new(10.0, 20.0, 30.0);
    let ts = synth_touches(origin, &[5.0, 10.0], 5, 0.02, 0.005, 33);
    let f = std::path::Path::new("probe.parquet");
    let a = analyse(&ts, &DatumConfig::default(), f).unwrap();
    assert!((a.latency_s["ae"] - 0.02).abs() < 1e-3, "{:?}", a.latency_s);
    let err = a.main.datum.p - origin;
    let m = err.dot(&(a.main.datum.cov.try_inverse().unwrap() * err));
    assert!(m < 16.3, "corrected datum error {err}");
    let raw = DatumConfig {
        correct_latency: false,
        ..DatumConfig::default()
    };
    let b = analyse(&ts, &raw, f).unwrap();
    // Uncorrected, the datum sits inside the block by ≈ v̄·L = 0.15 mm
    // on every axis (approaches along −axis).
    let e = b.main.datum.p - origin;
    assert!(e.iter().all(|x| (x + 0.15).abs() < 0.02), "{e}");
}

#[test]
fn bad_faces_are_input_errors() {
    let origin = Vector3::zeros();
    let ts = synth_touches(origin, &[5.0], 1, 0.0, 0.001, 1);
    let cfg = DatumConfig::default();
    let f = std::path::Path::new("probe.parquet");
    // Fewer than 3 points on a face.
    let few: Vec<Touch> = ts
        .iter()
        .filter(|t| t.face != Face::Zx || t.point < 2)
        .cloned()
        .collect();
    let e = analyse(&few, &cfg, f).err().unwrap();
    let ie = e.input().unwrap();
    assert!(
        ie.message.contains("at least 3") && ie.message.contains("zx"),
        "{ie}"
    );
    // Collinear: the yz face's points all on one line.
    let mut col = ts.clone();
    for t in col.iter_mut().filter(|t| t.face == Face::Yz) {
        t.p.z = t.p.y;
    }
    let e = analyse(&col, &cfg, f).err().unwrap();
    assert!(e.to_string().contains("collinear"), "{e}");
    // Nearly parallel: the zx face's points actually lie on a plane
    // tilted 88° towards xy.
    let mut par = ts.clone();
    let n = Vector3::new(
        0.0,
        (2.0f64).to_radians().sin(),
        (2.0f64).to_radians().cos(),
    );
    for t in par.iter_mut().filter(|t| t.face == Face::Zx) {
        // (x, z) in-plane positions kept; put the point on n·p = 0.
        let (x, z) = (t.p.x, t.p.z + 30.0);
        t.p = Vector3::new(x, -(n.z * z) / n.y, z);
    }
    let e = analyse(&par, &cfg, f).err().unwrap();
    assert!(e.to_string().contains("nearly parallel"), "{e}");
}
