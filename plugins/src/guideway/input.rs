//! Reading and checking a run's guideway.parquet (docs/formats.md §4) into the
//! sample series the three-probe separation needs (docs/models.md §3.1): sample
//! index n without gaps or repeats, the grid index of the workpiece point
//! under probe A, direction, pass and infeed count, time.
//!
//! Bad input is an [`InputError`] naming file, column and first offending
//! row: gaps/repeats in `n`, a probe spacing that is not a whole number of
//! sample steps (unless `interpolate` is configured), positions off the
//! sample grid, a probe stuck at one value.

use std::path::{Path, PathBuf};

use super::config::{machine_section, MachineProbes, MachineTable};
use crate::guideway::tables::GUIDEWAY;
use arrow::array::{Array, Int64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use sparkout_pipeline::contracts::Table;
use sparkout_pipeline::{InputError, Result, Run};

/// The three probes' columns, A, B, C.
pub const PROBES: [&str; 3] = ["za_mm", "zb_mm", "zc_mm"];

/// How readings are checked and prepared (`[guideway.separate]`).
#[derive(Debug, Clone, Copy)]
pub struct InputOptions {
    /// Resample onto a grid whose step divides the probe spacing when the
    /// spacing is not a whole number of sample steps or positions are off
    /// the grid (linear interpolation along x within each pass).
    pub interpolate: bool,
    /// This many equal consecutive readings of one probe = a stuck sensor.
    pub stuck_samples: usize,
}

impl Default for InputOptions {
    fn default() -> Self {
        InputOptions {
            interpolate: false,
            stuck_samples: 8,
        }
    }
}

/// Probe geometry and process constants of a run (run.toml `[process]`
/// first, then the machine config).
#[derive(Debug, Clone, Copy)]
pub struct Geometry {
    /// L1 = L2 (mm).
    pub spacing_mm: f64,
    /// ΔL (mm).
    pub step_mm: f64,
    /// Table speed (mm/s), for t_s when the table has none.
    pub speed_mm_s: f64,
}

/// The raw columns of guideway.parquet (what a test can build by hand).
#[derive(Debug, Clone, Default)]
pub struct RawReadings {
    pub n: Vec<i64>,
    pub x_mm: Vec<f64>,
    pub z_mm: [Vec<f64>; 3],
    pub dir: Option<Vec<i8>>,
    pub t_s: Option<Vec<f64>>,
    pub temp_c: Option<Vec<f64>>,
    /// Extra column `infeed_count` (docs/formats.md: extra columns pass
    /// through); when absent every pass is one infeed.
    pub infeed_count: Option<Vec<i64>>,
}

/// Prepared sample series.
#[derive(Debug, Clone)]
pub struct Readings {
    pub path: PathBuf,
    pub n: Vec<i64>,
    pub x_mm: Vec<f64>,
    pub z_mm: [Vec<f64>; 3],
    /// Travel direction ±1.
    pub dir: Vec<f64>,
    pub t_s: Vec<f64>,
    /// Whether t_s was recorded (else n·ΔL/speed).
    pub t_recorded: bool,
    pub temp_c: Option<Vec<f64>>,
    /// Infeeds so far (1 in the first pass).
    pub infeed_count: Vec<i32>,
    /// 0-based pass (maximal run of one direction).
    pub pass: Vec<i32>,
    /// Grid index of the workpiece point under probe A.
    pub j: Vec<usize>,
    /// Sample step ΔL after any resampling (mm).
    pub step_mm: f64,
    /// Probe spacing in sample steps (L = k·ΔL).
    pub k: usize,
    pub spacing_mm: f64,
    /// x of grid index 0.
    pub x0_mm: f64,
    pub resampled: bool,
}

impl Readings {
    pub fn len(&self) -> usize {
        self.n.len()
    }
    pub fn is_empty(&self) -> bool {
        self.n.is_empty()
    }
    /// Workpiece grid points: probe A's positions plus 2k beyond.
    pub fn positions(&self) -> usize {
        self.j.iter().max().map(|m| m + 2 * self.k + 1).unwrap_or(0)
    }
    pub fn passes(&self) -> usize {
        self.pass.last().map(|p| *p as usize + 1).unwrap_or(0)
    }
}

fn bad(path: &Path, column: &str, row: Option<usize>, msg: String) -> crate::Error {
    let mut e = InputError::new(path, msg).column(column);
    if let Some(r) = row {
        e = e.row(r);
    }
    e.into()
}

fn positive(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite() && *x > 0.0)
}

/// Probe geometry of a run; a missing or bad value names run.toml's key.
pub fn geometry(run: &Run) -> Result<Geometry> {
    let toml_path = run.spec.run_toml_path();
    let probes: MachineProbes = machine_section(run);
    let get = |process_key: &str, machine_key: &str, machine_value: Option<f64>| -> Result<f64> {
        match run.spec.process.get(process_key) {
            Some(v) => {
                let x = match v {
                    toml::Value::Float(f) => Some(*f),
                    toml::Value::Integer(i) => Some(*i as f64),
                    _ => None,
                };
                positive(x).ok_or_else(|| {
                    bad(
                        &toml_path,
                        &format!("process.{process_key}"),
                        None,
                        format!("[process].{process_key} must be a number > 0 (mm), found {v}"),
                    )
                })
            }
            None => positive(machine_value).ok_or_else(|| {
                bad(
                    &toml_path,
                    &format!("process.{process_key}"),
                    None,
                    format!(
                        "[process].{process_key} is missing and machine `{}` has no [{}] (docs/formats.md: guideway runs give probe_spacing_mm and sample_step_mm)",
                        run.machine.id,
                        machine_key.replace('.', "] ")
                    ),
                )
            }),
        }
    };
    Ok(Geometry {
        spacing_mm: get("probe_spacing_mm", "probes.spacing_mm", probes.spacing_mm)?,
        step_mm: get(
            "sample_step_mm",
            "probes.sample_step_mm",
            probes.sample_step_mm,
        )?,
        speed_mm_s: positive(machine_section::<MachineTable>(run).speed_mm_s)
            .unwrap_or(20_000.0 / 60.0),
    })
}

/// Any integer column as i64 (extra columns are not normalised by the reader).
fn int_column(table: &Table, name: &str) -> Result<Option<Vec<i64>>> {
    let Some(col) = table.batch().column_by_name(name) else {
        return Ok(None);
    };
    let c = cast(col, &DataType::Int64).map_err(|e| {
        bad(
            table.path(),
            name,
            None,
            format!("must be an integer column: {e}"),
        )
    })?;
    let a = c
        .as_any()
        .downcast_ref::<Int64Array>()
        .expect("cast to int64");
    if let Some(i) = (0..a.len()).find(|&i| a.is_null(i)) {
        return Err(bad(table.path(), name, Some(i), "null value".into()));
    }
    Ok(Some(a.values().to_vec()))
}

/// Optional float column with every value finite.
fn opt_finite(table: &Table, name: &str) -> Result<Option<Vec<f64>>> {
    if !table.has(name) {
        return Ok(None);
    }
    let col = table.batch().column_by_name(name).expect("has");
    if let Some(i) = (0..col.len()).find(|&i| col.is_null(i)) {
        return Err(bad(table.path(), name, Some(i), "null value".into()));
    }
    let v = table.f64(name)?;
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(bad(
            table.path(),
            name,
            Some(i),
            "NaN or infinite value".into(),
        ));
    }
    Ok(Some(v.to_vec()))
}

/// The run's guideway table, read and prepared.
pub fn load(run: &Run, opt: &InputOptions) -> Result<Readings> {
    let table = run.require(&GUIDEWAY)?;
    let g = geometry(run)?;
    prepare(table.path(), raw_from_table(&table)?, &g, opt)
}

/// A guideway.parquet file outside a run (`sparkout stage separate
/// --guideway FILE`), read and validated against the contract.
pub fn load_file(path: &Path, g: &Geometry, opt: &InputOptions) -> Result<Readings> {
    let table = Table::read(path, &GUIDEWAY)?;
    prepare(path, raw_from_table(&table)?, g, opt)
}

/// The contract columns of a validated guideway table.
pub fn raw_from_table(table: &Table) -> Result<RawReadings> {
    let dir = if table.has("dir") {
        let col = table.batch().column_by_name("dir").expect("has");
        if let Some(i) = (0..col.len()).find(|&i| col.is_null(i)) {
            return Err(bad(table.path(), "dir", Some(i), "null value".into()));
        }
        Some(table.i8("dir")?.to_vec())
    } else {
        None
    };
    Ok(RawReadings {
        n: table.i64("n")?.to_vec(),
        x_mm: table.f64("x_mm")?.to_vec(),
        z_mm: [
            table.f64(PROBES[0])?.to_vec(),
            table.f64(PROBES[1])?.to_vec(),
            table.f64(PROBES[2])?.to_vec(),
        ],
        dir,
        t_s: opt_finite(table, "t_s")?,
        temp_c: opt_finite(table, "temp_c")?,
        infeed_count: int_column(table, "infeed_count")?,
    })
}

/// The samples' own checks: `n` consecutive (docs/models.md §3.1 indexes the
/// recursion by n), and no probe stuck on one reading for
/// `stuck_samples` samples in a row.
fn check_samples(path: &Path, raw: &RawReadings, opt: &InputOptions) -> Result<()> {
    let len = raw.n.len();
    // n: consecutive samples, no gaps, no repeats (docs/models.md §3.1 indexes
    // the recursion by n).
    for i in 1..len {
        let (a, b) = (raw.n[i - 1], raw.n[i]);
        if b != a + 1 {
            let what = if b == a {
                format!("n repeats ({b} twice)")
            } else if b < a {
                format!("n goes back from {a} to {b}")
            } else {
                format!(
                    "gap in n: {a} is followed by {b} ({} samples missing)",
                    b - a - 1
                )
            };
            return Err(bad(
                path,
                "n",
                Some(i),
                format!("{what}; samples must be consecutive (n, n+1, …)"),
            ));
        }
    }
    // A stuck sensor: the same reading many samples in a row.
    let stuck = opt.stuck_samples.max(2);
    for (c, z) in raw.z_mm.iter().enumerate() {
        let mut start = 0;
        for i in 1..=len {
            if i == len || z[i] != z[start] {
                if i - start >= stuck {
                    return Err(bad(
                        path,
                        PROBES[c],
                        Some(start),
                        format!(
                            "probe reads {} for {} samples in a row (rows {start}–{}): the sensor looks stuck (limit: stuck_samples = {stuck})",
                            z[start],
                            i - start,
                            i - 1
                        ),
                    ));
                }
                start = i;
            }
        }
    }
    Ok(())
}

/// The direction of travel per sample: recorded (`dir`, ±1), else the
/// sign of the move, kept over stops.
fn direction(path: &Path, raw: &RawReadings) -> Result<Vec<f64>> {
    let len = raw.n.len();
    Ok(match &raw.dir {
        Some(d) => {
            if let Some(i) = d.iter().position(|v| *v != 1 && *v != -1) {
                return Err(bad(
                    path,
                    "dir",
                    Some(i),
                    format!("dir must be +1 or −1, found {}", d[i]),
                ));
            }
            d.iter().map(|v| *v as f64).collect()
        }
        None => {
            let mut out = vec![0.0; len];
            let first = raw
                .x_mm
                .windows(2)
                .map(|w| w[1] - w[0])
                .find(|d| *d != 0.0)
                .map(|d| d.signum())
                .unwrap_or(1.0);
            let mut cur = first;
            out[0] = first;
            for (i, o) in out.iter_mut().enumerate().skip(1) {
                let d = raw.x_mm[i] - raw.x_mm[i - 1];
                if d != 0.0 {
                    cur = d.signum();
                }
                *o = cur;
            }
            out
        }
    })
}

/// Check and prepare raw readings (see the module doc for what is an error).
pub fn prepare(
    path: &Path,
    raw: RawReadings,
    g: &Geometry,
    opt: &InputOptions,
) -> Result<Readings> {
    let len = raw.n.len();
    if len < 3 {
        return Err(bad(
            path,
            "n",
            None,
            format!("{len} samples: the three-probe separation needs at least 3"),
        ));
    }
    check_samples(path, &raw, opt)?;
    let dir = direction(path, &raw)?;
    let mut pass = vec![0i32; len];
    for i in 1..len {
        pass[i] = pass[i - 1] + (dir[i] != dir[i - 1]) as i32;
    }
    let infeed_count: Vec<i32> = match &raw.infeed_count {
        Some(c) => c.iter().map(|v| *v as i32).collect(),
        None => pass.iter().map(|p| p + 1).collect(),
    };
    let (t_s, t_recorded) = match &raw.t_s {
        Some(t) => (t.clone(), true),
        None => (
            raw.n
                .iter()
                .map(|n| (n - raw.n[0]) as f64 * g.step_mm / g.speed_mm_s)
                .collect(),
            false,
        ),
    };
    let ratio = g.spacing_mm / g.step_mm;
    let k = ratio.round();
    let whole = k >= 1.0 && (ratio - k).abs() <= 1e-6 * ratio;
    let x0 = raw.x_mm.iter().cloned().fold(f64::INFINITY, f64::min);
    let off_grid = raw.x_mm.iter().position(|x| {
        let q = (x - x0) / g.step_mm;
        (q - q.round()).abs() > 0.01
    });
    let r = Readings {
        path: path.to_path_buf(),
        n: raw.n,
        x_mm: raw.x_mm,
        z_mm: raw.z_mm,
        dir,
        t_s,
        t_recorded,
        temp_c: raw.temp_c,
        infeed_count,
        pass,
        j: Vec::new(),
        step_mm: g.step_mm,
        k: k.max(1.0) as usize,
        spacing_mm: g.spacing_mm,
        x0_mm: x0,
        resampled: false,
    };
    if !whole || off_grid.is_some() {
        if opt.interpolate {
            return resample(r);
        }
        if !whole {
            return Err(bad(
                path,
                "x_mm",
                None,
                format!(
                    "probe spacing {} mm is not a whole number of sample steps ({} mm; ratio {ratio:.4}): the three probes do not see common workpiece points. Record with a step that divides the spacing, or set [guideway.separate] interpolate = true",
                    g.spacing_mm, g.step_mm
                ),
            ));
        }
        let i = off_grid.expect("checked");
        return Err(bad(
            path,
            "x_mm",
            Some(i),
            format!(
                "x = {} mm is off the sample grid ({} mm + multiples of ΔL = {} mm); set [guideway.separate] interpolate = true to resample",
                r.x_mm[i], x0, g.step_mm
            ),
        ));
    }
    Ok(with_grid(r))
}

fn with_grid(mut r: Readings) -> Readings {
    r.j = r
        .x_mm
        .iter()
        .map(|x| ((x - r.x0_mm) / r.step_mm).round() as usize)
        .collect();
    r
}

/// Linear interpolation of `v` at `x` over strictly increasing `xs`.
fn interp(xs: &[f64], v: &[f64], x: f64) -> f64 {
    let i = xs.partition_point(|a| *a <= x).clamp(1, xs.len() - 1);
    let (x0, x1) = (xs[i - 1], xs[i]);
    let w = if x1 > x0 { (x - x0) / (x1 - x0) } else { 0.0 };
    v[i - 1] + w * (v[i] - v[i - 1])
}

/// Resample every pass onto a grid of step ΔL' = L / round(L/ΔL), so the
/// probe spacing is a whole number of steps (docs/models.md §3.1 needs L = k·ΔL).
fn resample(r: Readings) -> Result<Readings> {
    let k = (r.spacing_mm / r.step_mm).round().max(1.0);
    let step = r.spacing_mm / k;
    let x0 = r.x0_mm;
    let mut out = Readings {
        n: Vec::new(),
        x_mm: Vec::new(),
        z_mm: Default::default(),
        dir: Vec::new(),
        t_s: Vec::new(),
        temp_c: r.temp_c.as_ref().map(|_| Vec::new()),
        infeed_count: Vec::new(),
        pass: Vec::new(),
        j: Vec::new(),
        step_mm: step,
        k: k as usize,
        resampled: true,
        ..r.clone()
    };
    let mut start = 0;
    let len = r.len();
    let mut new_pass = 0;
    for i in 1..=len {
        if i < len && r.pass[i] == r.pass[start] {
            continue;
        }
        // One pass: rows start..i, x sorted ascending with repeats dropped.
        let mut idx: Vec<usize> = (start..i).collect();
        idx.sort_by(|&a, &b| r.x_mm[a].total_cmp(&r.x_mm[b]).then(a.cmp(&b)));
        idx.dedup_by(|b, a| r.x_mm[*a] == r.x_mm[*b]);
        let (d, count) = (r.dir[start], r.infeed_count[start]);
        start = i;
        if idx.len() < 2 {
            continue;
        }
        let xs: Vec<f64> = idx.iter().map(|&q| r.x_mm[q]).collect();
        let col = |v: &[f64]| -> Vec<f64> { idx.iter().map(|&q| v[q]).collect() };
        let (lo, hi) = (xs[0], xs[xs.len() - 1]);
        let m0 = ((lo - x0) / step - 1e-9).ceil() as i64;
        let m1 = ((hi - x0) / step + 1e-9).floor() as i64;
        let mut grid: Vec<f64> = (m0..=m1).map(|m| x0 + m as f64 * step).collect();
        if d < 0.0 {
            grid.reverse();
        }
        let zs = [col(&r.z_mm[0]), col(&r.z_mm[1]), col(&r.z_mm[2])];
        let ts = col(&r.t_s);
        let temps = r.temp_c.as_ref().map(|t| col(t));
        for x in grid {
            out.n.push(r.n[0] + out.x_mm.len() as i64);
            out.x_mm.push(x);
            for (o, z) in out.z_mm.iter_mut().zip(&zs) {
                o.push(interp(&xs, z, x));
            }
            out.dir.push(d);
            out.t_s.push(interp(&xs, &ts, x));
            if let (Some(o), Some(t)) = (out.temp_c.as_mut(), temps.as_ref()) {
                o.push(interp(&xs, t, x));
            }
            out.infeed_count.push(count);
            out.pass.push(new_pass);
        }
        new_pass += 1;
    }
    if out.n.len() < 3 {
        return Err(bad(
            &r.path,
            "x_mm",
            None,
            "fewer than 3 samples after resampling onto the probe-spacing grid".into(),
        ));
    }
    // Time must stay non-decreasing across passes (each pass is resampled
    // in its own direction, so it is).
    Ok(with_grid(out))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Point indices 0..m in the order pass `pass` visits them: forward on
    /// even passes, back on odd ones (a back-and-forth traverse).
    pub fn pass_points(m: usize, pass: usize) -> Vec<usize> {
        if pass.is_multiple_of(2) {
            (0..m).collect()
        } else {
            (0..m).rev().collect()
        }
    }

    pub fn geom(spacing: f64, step: f64) -> Geometry {
        Geometry {
            spacing_mm: spacing,
            step_mm: step,
            speed_mm_s: 100.0,
        }
    }

    /// One forward and one backward pass over `m` positions, smooth readings.
    pub fn raw(m: usize) -> RawReadings {
        let mut r = RawReadings::default();
        let js: Vec<usize> = (0..m).chain((0..m).rev()).collect();
        for (i, j) in js.iter().enumerate() {
            r.n.push(i as i64);
            r.x_mm.push(*j as f64 * 30.0);
            let u = *j as f64;
            r.z_mm[0].push(1e-3 * (0.1 * u).sin() + 1e-5 * i as f64);
            r.z_mm[1].push(1e-3 * (0.1 * (u + 1.0)).sin() + 2e-5 * i as f64);
            r.z_mm[2].push(1e-3 * (0.1 * (u + 2.0)).sin() + 3e-5 * i as f64);
        }
        r
    }

    fn err_of(r: Result<Readings>) -> InputError {
        r.expect_err("an error")
            .input()
            .expect("an InputError")
            .clone()
    }

    #[test]
    fn passes_directions_and_grid() {
        let r = prepare(
            Path::new("g.parquet"),
            raw(10),
            &geom(30.0, 30.0),
            &Default::default(),
        )
        .unwrap();
        assert_eq!(r.passes(), 2);
        assert_eq!(r.dir[0], 1.0);
        assert_eq!(r.dir[15], -1.0);
        assert_eq!(r.infeed_count[15], 2);
        assert_eq!(r.j[9], 9);
        assert_eq!(r.positions(), 12);
    }

    #[test]
    fn bad_inputs_name_column_and_row() {
        let p = Path::new("g.parquet");
        let o = InputOptions::default();
        let mut gap = raw(10);
        gap.n[5] += 1;
        let e = err_of(prepare(p, gap, &geom(30.0, 30.0), &o));
        assert_eq!((e.column.as_deref(), e.row), (Some("n"), Some(5)));
        assert!(e.message.contains("gap"), "{e}");
        let mut rep = raw(10);
        rep.n[4] = rep.n[3];
        let e = err_of(prepare(p, rep, &geom(30.0, 30.0), &o));
        assert!(e.message.contains("repeats") && e.row == Some(4), "{e}");
        let e = err_of(prepare(p, raw(10), &geom(45.0, 30.0), &o));
        assert!(e.message.contains("not a whole number"), "{e}");
        let mut stuck = raw(20);
        for i in 3..12 {
            stuck.z_mm[1][i] = 0.5;
        }
        let e = err_of(prepare(p, stuck, &geom(30.0, 30.0), &o));
        assert_eq!((e.column.as_deref(), e.row), (Some("zb_mm"), Some(3)));
        let mut off = raw(10);
        off.x_mm[3] += 7.0;
        let e = err_of(prepare(p, off, &geom(30.0, 30.0), &o));
        assert_eq!((e.column.as_deref(), e.row), (Some("x_mm"), Some(3)));
    }

    #[test]
    fn interpolation_resamples_onto_the_spacing_grid() {
        let o = InputOptions {
            interpolate: true,
            ..Default::default()
        };
        // Spacing 40 mm with a 30 mm step: resampled to ΔL' = 40 mm (k = 1).
        let r = prepare(Path::new("g.parquet"), raw(13), &geom(40.0, 30.0), &o).unwrap();
        assert!(r.resampled);
        assert_eq!((r.k, r.step_mm), (1, 40.0));
        assert_eq!(r.x_mm[..3], [0.0, 40.0, 80.0]);
        assert!(r.n.windows(2).all(|w| w[1] == w[0] + 1));
        assert_eq!(r.passes(), 2);
    }
}
