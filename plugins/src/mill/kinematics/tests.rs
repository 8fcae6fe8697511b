use super::*;
use crate::mill::tables::TRACKER;
use std::path::Path;

fn table(point: Vec<i32>, extra: impl Fn(BatchBuilder) -> BatchBuilder) -> Table {
    let n = point.len();
    let v = |k: f64| (0..n).map(|i| k * i as f64).collect::<Vec<_>>();
    let b = BatchBuilder::new()
        .i32("point", point)
        .f64("x_mm", v(1.0))
        .f64("y_mm", v(2.0))
        .f64("z_mm", v(3.0))
        .f64("mx_mm", v(1.0))
        .f64("my_mm", v(2.0))
        .f64("mz_mm", v(3.0));
    Table::from_batch(Path::new("tracker.parquet"), &TRACKER, extra(b).build()).unwrap()
}

fn machine() -> MillMachine {
    MillMachine::from_config(&sparkout_pipeline::contracts::MachineConfig {
        id: "xfyz-mill".into(),
        source: "built-in".into(),
        table: super::super::XFYZ_MILL_TOML.parse().unwrap(),
        text: String::new(),
        ..Default::default()
    })
    .unwrap()
}

#[test]
fn tracker_columns_beyond_the_contract_are_checked() {
    let m = machine();
    // Re-measured points: same id, another trial — fine.
    let t = table(vec![0, 0, 1], |b| {
        b.i32("trial", vec![0, 1, 0]).i32("tool", vec![0, 2, 1])
    });
    let d = tracker_from_table(&t, &m).unwrap();
    assert_eq!(d.tool, vec![0, 2, 1]);
    assert_eq!(d.obs[1].pt.tool, m.tools[2]);
    // Same (point, trial) twice.
    let t = table(vec![4, 5, 4], |b| b);
    let e = tracker_from_table(&t, &m).unwrap_err();
    assert_eq!((e.column.as_deref(), e.row), (Some("point"), Some(2)));
    // A tool the machine does not have.
    let t = table(vec![0, 1, 2], |b| b.i32("tool", vec![0, 3, 1]));
    let e = tracker_from_table(&t, &m).unwrap_err();
    assert_eq!((e.column.as_deref(), e.row), (Some("tool"), Some(1)));
    // NaN in the optional t_s: the contract reader refuses it (NaN is
    // refused in every column; a value not recorded is null).
    let b = BatchBuilder::new()
        .i32("point", vec![0, 1, 2])
        .f64("x_mm", vec![0.0; 3])
        .f64("y_mm", vec![0.0; 3])
        .f64("z_mm", vec![0.0; 3])
        .f64("mx_mm", vec![0.0; 3])
        .f64("my_mm", vec![0.0; 3])
        .f64("mz_mm", vec![0.0; 3])
        .f64("t_s", vec![0.0, f64::NAN, 2.0]);
    let e = Table::from_batch(Path::new("tracker.parquet"), &TRACKER, b.build()).unwrap_err();
    assert_eq!((e.column.as_deref(), e.row), (Some("t_s"), Some(1)));
}

#[test]
fn table_interpolation_reproduces_the_model_at_nodes_and_is_close_between() {
    let layout = Layout::new(3, [(0.0, 600.0), (0.0, 400.0), (0.0, 300.0)], &[]);
    let mut m = Model::zeros(layout);
    for i in 0..m.layout.coef.len() {
        let f = m.layout.coef[i].0;
        m.params[i] = if super::super::chain::is_rotation(f) {
            2e-5
        } else {
            0.01
        };
    }
    let t = CompTable::from_model(&m, 25.0);
    let node = Point {
        q: [t.pos[0][3], t.pos[1][5], t.pos[2][2]],
        tool: V3::new(0.0, 0.0, -100.0),
    };
    assert!((t.deviation(&node) - m.deviation(&node)).norm() < 1e-12);
    let mid = Point {
        q: [37.0, 212.5, 101.0],
        tool: V3::new(0.0, 0.0, -100.0),
    };
    let d = (t.deviation(&mid) - m.deviation(&mid)).norm();
    assert!(d > 0.0 && d < 1e-3, "interpolation error {d}");
}
