//! CLI values that begin with `-` are values: engineers
//! type negative numbers, and a plane list that starts with one must not be
//! taken for a flag.

use crate::common::sparkout;

/// Solve the 3×3 system `n·p = -d` of three planes by Cramer's rule.
fn intersect(p: [[f64; 4]; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let a = [
        [p[0][0], p[0][1], p[0][2]],
        [p[1][0], p[1][1], p[1][2]],
        [p[2][0], p[2][1], p[2][2]],
    ];
    let b = [-p[0][3], -p[1][3], -p[2][3]];
    let d = det(a);
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        *o = det(m) / d;
    }
    out
}

#[test]
fn planes_with_negative_coefficients_are_values() {
    let planes = [
        [-0.0076, -0.0018, -1.0, 12.44463],
        [-1.0, 0.0021, -0.0009, -20.1],
        [0.0013, -1.0, -0.0004, -13.2],
    ];
    let spec = planes
        .iter()
        .map(|p| p.map(|v| v.to_string()).join(","))
        .collect::<Vec<_>>()
        .join(";");
    assert!(spec.starts_with('-'));
    // The value right after the flag, and the JSON flag after it.
    let o = sparkout(&["stage", "datum", "--planes", &spec, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let got: Vec<f64> = v["datum_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    // Planes are normalised before they are intersected; the point is the same.
    let want = intersect(planes);
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-9, "{got:?} vs {want:?}");
    }
    // `--planes=...` gives the same answer.
    let eq = sparkout(&["stage", "datum", &format!("--planes={spec}"), "--json"]);
    assert_eq!(eq.stdout, o.stdout);
}

#[test]
fn a_negative_number_for_a_numeric_option_is_a_value_not_a_flag() {
    // clap must hand `-1` to the option (and the option reject it for its
    // own reason), not report an unknown flag `-1`.
    let o = sparkout(&[
        "diagnose",
        "x.parquet",
        "--out",
        "/nonexistent-dir",
        "--folds",
        "-1",
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!e.contains("unexpected argument"), "{e}");
}
