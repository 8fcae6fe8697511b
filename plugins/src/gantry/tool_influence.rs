//! Preston removal with a disc polishing tool on springs (docs/models.md §2.5):
//! the tool influence function (removal depth rate around the tool centre),
//! dwell-time maps of tool paths (raster, Archimedean spiral), and their
//! convolution by FFT (realfft along rows, rustfft along columns).

use sparkout_pipeline::toml_f64;
use std::f64::consts::PI;
use std::path::Path;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::RealFftPlanner;
use rustfft::FftPlanner;
use sparkout_pipeline::InputError;

use super::grid::Grid;

/// The polishing tool: a disc pressed by springs (docs/models.md §2.5).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolishTool {
    /// Preston coefficient, Pa⁻¹ (= m²/N).
    pub k_p_per_pa: f64,
    /// Contact pressure, Pa: configured, or k_s·(l_f − l_i)/area from the springs.
    pub pressure_pa: f64,
    pub radius_mm: f64,
    /// Disc rotation, rev/s.
    pub rev_per_s: f64,
    /// Translational relative speed of the disc over the stone, mm/s.
    pub linear_speed_mm_s: f64,
    /// Spring compression l_f − l_i, mm: a height change δ of the tool
    /// changes the pressure by −δ/compression (what turns a structural Z
    /// error into a removal error).
    pub spring_compression_mm: f64,
    /// Tool-centre feed of polishing passes, mm/s.
    pub feed_mm_s: f64,
    /// Raster step-over between passes, mm.
    pub step_over_mm: f64,
    /// Path acceleration at pass ends, mm/s².
    pub accel_mm_s2: f64,
}

impl PolishTool {
    /// From the machine's `[polishing]` table; a run's `[process]` key of
    /// the same name wins. Negative or zero pressure and k_p are errors.
    pub fn read(
        source: &str,
        t: &super::machine::MachinePolishing,
        process: &toml::Table,
        run_toml: &Path,
    ) -> Result<PolishTool, InputError> {
        let get = |key: &str, default: Option<f64>| -> Result<f64, InputError> {
            let Some(v) = process.get(key) else {
                // The machine's value, read and checked (> 0) at load.
                return match (t.value(key), default) {
                    (Some(x), _) | (None, Some(x)) => Ok(x),
                    (None, None) => Err(InputError::new(
                        source,
                        format!("required key [polishing].{key} is missing"),
                    )
                    .column(format!("polishing.{key}"))),
                };
            };
            let col = format!("process.{key}");
            match toml_f64(v) {
                Some(x) if x.is_finite() && x > 0.0 => Ok(x),
                _ => Err(InputError::new(
                    run_toml.display().to_string(),
                    format!("{col} must be a positive number (found {v}); pressure, k_p, speeds and sizes of the polishing tool cannot be zero or negative"),
                )
                .column(col)),
            }
        };
        let k_p_per_pa = get("k_p_per_pa", None)?;
        let radius_mm = match process
            .get("tool_radius_mm")
            .map(|_| ())
            .or(t.tool_radius_mm.map(|_| ()))
        {
            Some(_) => get("tool_radius_mm", None)?,
            None => (get("tool_area_mm2", None)? / PI).sqrt(),
        };
        let spring_compression_mm = get("spring_compression_mm", Some(0.5))?;
        let pressure_pa = match process
            .get("pressure_pa")
            .map(|_| ())
            .or(t.pressure_pa.map(|_| ()))
        {
            Some(_) => get("pressure_pa", None)?,
            None => {
                // p = k_s·(l_f − l_i)/area (docs/models.md §2.5), N/mm² → Pa.
                let k_s = get("spring_rate_n_mm", None)?;
                k_s * spring_compression_mm / (PI * radius_mm * radius_mm) * 1e6
            }
        };
        Ok(PolishTool {
            k_p_per_pa,
            pressure_pa,
            radius_mm,
            rev_per_s: get("rev_per_s", None)?,
            linear_speed_mm_s: get("linear_speed_mm_s", None)?,
            spring_compression_mm,
            feed_mm_s: get("feed_mm_s", Some(100.0))?,
            step_over_mm: get("step_over_mm", Some(radius_mm / 2.0))?,
            accel_mm_s2: get("accel_mm_s2", Some(500.0))?,
        })
    }

    /// Preston removal depth rate at distance ρ from the tool centre, mm/s:
    /// dz/dt = k_p·p·v (docs/models.md §2.5) with the relative speed of the
    /// spinning, translating disc v(ρ) = sqrt(v_lin² + (2π·n·ρ)²); zero
    /// outside the disc. k_p [1/Pa]·p [Pa] is dimensionless.
    pub fn rate_mm_s(&self, rho_mm: f64) -> f64 {
        if rho_mm > self.radius_mm {
            return 0.0;
        }
        let w = 2.0 * PI * self.rev_per_s * rho_mm;
        self.k_p_per_pa * self.pressure_pa * (self.linear_speed_mm_s.powi(2) + w * w).sqrt()
    }

    /// Volume removal rate of the whole disc on the stone, mm³/s.
    pub fn volume_rate_mm3_s(&self) -> f64 {
        // ∫₀^r rate(ρ)·2πρ dρ by the midpoint rule (smooth integrand).
        let n = 400;
        let h = self.radius_mm / n as f64;
        (0..n)
            .map(|i| {
                let r = (i as f64 + 0.5) * h;
                self.rate_mm_s(r) * 2.0 * PI * r * h
            })
            .sum()
    }

    /// The influence function sampled on a grid's steps: (values, kx, ky),
    /// odd sizes, centred, row-major (y rows).
    pub fn kernel(&self, dx: f64, dy: f64) -> (Vec<f64>, usize, usize) {
        let hx = (self.radius_mm / dx).floor() as usize;
        let hy = (self.radius_mm / dy).floor() as usize;
        let (kx, ky) = (2 * hx + 1, 2 * hy + 1);
        let mut k = vec![0.0; kx * ky];
        for j in 0..ky {
            for i in 0..kx {
                let x = (i as f64 - hx as f64) * dx;
                let y = (j as f64 - hy as f64) * dy;
                k[j * kx + i] = self.rate_mm_s((x * x + y * y).sqrt());
            }
        }
        (k, kx, ky)
    }
}

/// Smallest n' ≥ n whose prime factors are 2, 3, 5, 7 (fast FFT sizes).
pub fn fast_len(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5, 7] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

/// Linear 2-D convolution of an image (nx × ny, row-major) with an odd
/// kernel (kx × ky, centred), cropped to the image ("same"), by FFT: real
/// FFTs along rows (realfft), complex FFTs along columns (rustfft), rows and
/// columns in parallel (rayon), blocked transposes between the two.
pub fn fft_convolve_same(
    img: &[f64],
    nx: usize,
    ny: usize,
    ker: &[f64],
    kx: usize,
    ky: usize,
) -> Vec<f64> {
    Convolver::new(nx, ny, ker, kx, ky).apply(img)
}

/// [`fft_convolve_same`] with its plans and the kernel's spectrum kept, for
/// iterative solvers that convolve the same-sized image many times (the
/// dwell-time optimisation: two convolutions per iteration).
pub struct Convolver {
    nx: usize,
    ny: usize,
    kx: usize,
    ky: usize,
    px: usize,
    py: usize,
    r2c: Arc<dyn realfft::RealToComplex<f64>>,
    c2r: Arc<dyn realfft::ComplexToReal<f64>>,
    fwd: Arc<dyn rustfft::Fft<f64>>,
    inv: Arc<dyn rustfft::Fft<f64>>,
    /// Kernel spectrum, column-major, already scaled by 1/(px·py).
    kernel: Vec<Complex<f64>>,
    /// The three spectrum-sized buffers of [`Convolver::apply`], kept
    /// between calls: each is tens of MB, above glibc's largest mmap
    /// threshold, so a fresh one per call was an mmap, page faults and
    /// zeroing — a third of a 2048² convolution. A call that finds them in
    /// use (another thread) allocates its own.
    work: Mutex<Workspace>,
}

/// Row spectra, the column-major spectrum, and the rows back.
#[derive(Default)]
struct Workspace {
    rows: Vec<Complex<f64>>,
    spec: Vec<Complex<f64>>,
    back: Vec<Complex<f64>>,
}

impl Convolver {
    pub fn new(nx: usize, ny: usize, ker: &[f64], kx: usize, ky: usize) -> Convolver {
        assert_eq!(ker.len(), kx * ky);
        let px = fast_len(nx + kx - 1);
        let py = fast_len(ny + ky - 1);
        let mut rp = RealFftPlanner::<f64>::new();
        let mut cp = FftPlanner::<f64>::new();
        let mut c = Convolver {
            nx,
            ny,
            kx,
            ky,
            px,
            py,
            r2c: rp.plan_fft_forward(px),
            c2r: rp.plan_fft_inverse(px),
            fwd: cp.plan_fft_forward(py),
            inv: cp.plan_fft_inverse(py),
            kernel: Vec::new(),
            work: Mutex::new(Workspace::default()),
        };
        let norm = 1.0 / (px * py) as f64;
        let mut w = Workspace::default();
        c.spectrum(ker, kx, ky, &mut w);
        w.spec.iter_mut().for_each(|v| *v *= norm);
        c.kernel = w.spec;
        c
    }

    /// Spectrum into `w.spec`, column-major (cx columns of py) so column
    /// FFTs are contiguous; `w.rows` holds the row spectra on the way.
    fn spectrum(&self, src: &[f64], w: usize, h: usize, work: &mut Workspace) {
        let cx = self.px / 2 + 1;
        let zero = Complex::new(0.0, 0.0);
        let r2c = &self.r2c;
        // Every element is written below (row spectra, transposed columns
        // with their zero padding): a kept buffer needs no clearing.
        work.rows.resize(h * cx, zero);
        let rows = &mut work.rows;
        rows.par_chunks_mut(cx).enumerate().for_each_init(
            || (r2c.make_input_vec(), r2c.make_scratch_vec()),
            |(buf, scratch), (j, out)| {
                buf.iter_mut().for_each(|v| *v = 0.0);
                buf[..w].copy_from_slice(&src[j * w..(j + 1) * w]);
                r2c.process_with_scratch(buf, out, scratch)
                    .expect("fft sizes");
            },
        );
        // A kept buffer holds the last spectrum: its padding rows must be
        // cleared; a fresh one is zero already.
        let clear_padding = !work.spec.is_empty();
        work.spec.resize(cx * self.py, zero);
        transpose(rows, h, cx, &mut work.spec, self.py, clear_padding);
        process_columns(&self.fwd, &mut work.spec, self.py);
    }

    /// The image (nx × ny, row-major) convolved with the kernel, "same".
    pub fn apply(&self, img: &[f64]) -> Vec<f64> {
        let (nx, ny, px, py) = (self.nx, self.ny, self.px, self.py);
        assert_eq!(img.len(), nx * ny);
        let cx = px / 2 + 1;
        let zero = Complex::new(0.0, 0.0);
        let mut fresh = Workspace::default();
        let mut kept = self.work.try_lock().ok();
        let work = kept.as_deref_mut().unwrap_or(&mut fresh);
        self.spectrum(img, nx, ny, work);
        let a = &mut work.spec;
        a.par_iter_mut()
            .zip(self.kernel.par_iter())
            .for_each(|(u, v)| *u *= *v);
        process_columns(&self.inv, a, py);
        // Back to rows: only the ny rows the crop keeps (offset oy), in
        // blocks of rows on the pool (a copy: results do not depend on it).
        let (ox, oy) = (self.kx / 2, self.ky / 2);
        work.back.resize(ny * cx, zero);
        let (a, rows) = (&work.spec, &mut work.back);
        rows.par_chunks_mut(TRANSPOSE_BLOCK * cx)
            .enumerate()
            .for_each(|(b, block)| {
                let j0 = b * TRANSPOSE_BLOCK;
                let h = block.len() / cx;
                for i in 0..cx {
                    let col = &a[i * py + oy + j0..i * py + oy + j0 + h];
                    for (j, v) in col.iter().enumerate() {
                        block[j * cx + i] = *v;
                    }
                }
            });
        let c2r = &self.c2r;
        let mut out = vec![0.0; nx * ny];
        out.par_chunks_mut(nx)
            .zip(rows.par_chunks_mut(cx))
            .for_each_init(
                || (c2r.make_output_vec(), c2r.make_scratch_vec()),
                |(buf, scratch), (o, spec_row)| {
                    // Imaginary parts of DC/Nyquist are rounding noise for a real result.
                    spec_row[0].im = 0.0;
                    if px.is_multiple_of(2) {
                        spec_row[cx - 1].im = 0.0;
                    }
                    c2r.process_with_scratch(spec_row, buf, scratch)
                        .expect("fft sizes");
                    o.copy_from_slice(&buf[ox..ox + nx]);
                },
            );
        out
    }
}

/// Side of the cache blocks of the transposes.
const TRANSPOSE_BLOCK: usize = 32;

/// Row-major (h × w) → column-major with column length `ld` (rows ≥ h are
/// the zero padding, set to zero when `clear_padding`), in cache-sized
/// blocks, blocks of columns on the pool.
fn transpose(
    src: &[Complex<f64>],
    h: usize,
    w: usize,
    dst: &mut [Complex<f64>],
    ld: usize,
    clear_padding: bool,
) {
    const B: usize = TRANSPOSE_BLOCK;
    dst.par_chunks_mut(B * ld)
        .enumerate()
        .for_each(|(b, cols)| {
            let i0 = b * B;
            if clear_padding {
                for col in cols.chunks_mut(ld) {
                    col[h.min(ld)..].fill(Complex::new(0.0, 0.0));
                }
            }
            let ncol = (cols.len() / ld).min(w.saturating_sub(i0));
            for j0 in (0..h).step_by(B) {
                for j in j0..(j0 + B).min(h) {
                    let row = &src[j * w + i0..j * w + i0 + ncol];
                    for (di, v) in row.iter().enumerate() {
                        cols[di * ld + j] = *v;
                    }
                }
            }
        });
}

fn process_columns(fft: &Arc<dyn rustfft::Fft<f64>>, data: &mut [Complex<f64>], len: usize) {
    data.par_chunks_mut(len).for_each_init(
        || vec![Complex::new(0.0, 0.0); fft.get_inplace_scratch_len()],
        |scratch, col| fft.process_with_scratch(col, scratch),
    );
}

/// The same convolution done directly (tests; tiny grids): image and
/// kernel with their (columns, rows).
pub fn direct_convolve_same(
    img: &[f64],
    (nx, ny): (usize, usize),
    ker: &[f64],
    (kx, ky): (usize, usize),
) -> Vec<f64> {
    let (ox, oy) = ((kx / 2) as isize, (ky / 2) as isize);
    let mut out = vec![0.0; nx * ny];
    for j in 0..ny as isize {
        for i in 0..nx as isize {
            let mut s = 0.0;
            for q in 0..ky as isize {
                for p in 0..kx as isize {
                    let (si, sj) = (i + ox - p, j + oy - q);
                    if si >= 0 && sj >= 0 && (si as usize) < nx && (sj as usize) < ny {
                        s += img[sj as usize * nx + si as usize]
                            * ker[(q * kx as isize + p) as usize];
                    }
                }
            }
            out[j as usize * nx + i as usize] = s;
        }
    }
    out
}

/// One sample of a tool path (commanded), with what the observations need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSample {
    pub t_s: f64,
    pub x_mm: f64,
    pub y_mm: f64,
    /// Time this sample stands for (half the intervals to its neighbours).
    pub dt_s: f64,
    pub feed_mm_s: f64,
    /// |tangential acceleration|, mm/s².
    pub a_mm_s2: f64,
    /// Pass id (−1 off a pass: a step-over move).
    pub segment: i32,
    /// Sign of the motion along the pass axis (+1/−1), 0 when still.
    pub dir: f64,
    /// Distance along the path to the nearer end of its pass, mm.
    pub path_end_mm: f64,
}

/// Deposit the path's dwell (dt × weight per sample) on the grid nodes,
/// bilinearly: a dwell-time map in s.
pub fn dwell_map(grid: &Grid, path: &[PathSample], weight: impl Fn(usize) -> f64) -> Vec<f64> {
    let (nx, ny) = (grid.nx(), grid.ny());
    let mut d = vec![0.0; nx * ny];
    for (k, s) in path.iter().enumerate() {
        let w = s.dt_s * weight(k);
        if w == 0.0 {
            continue;
        }
        let fx = ((s.x_mm - grid.x0) / grid.dx).clamp(0.0, (nx - 1) as f64);
        let fy = ((s.y_mm - grid.y0) / grid.dy).clamp(0.0, (ny - 1) as f64);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(nx - 1), (j0 + 1).min(ny - 1));
        let (u, v) = (fx - i0 as f64, fy - j0 as f64);
        d[j0 * nx + i0] += w * (1.0 - u) * (1.0 - v);
        d[j0 * nx + i1] += w * u * (1.0 - v);
        d[j1 * nx + i0] += w * (1.0 - u) * v;
        d[j1 * nx + i1] += w * u * v;
    }
    d
}

/// Removal depth (mm) of a dwell map: the dwell convolved with the
/// influence function (docs/models.md §2.5), by FFT.
pub fn removal_of_dwell(grid: &Grid, tool: &PolishTool, dwell: &[f64]) -> Vec<f64> {
    let (ker, kx, ky) = tool.kernel(grid.dx, grid.dy);
    fft_convolve_same(dwell, grid.nx(), grid.ny(), &ker, kx, ky)
}

/// Fill in dt, feed, |a|, dir and path-end distance from positions, times
/// and segment ids (what a motion log gives).
#[allow(clippy::needless_range_loop)] // neighbours k−1, k+1 of each sample
pub fn complete_path(
    t: &[f64],
    x: &[f64],
    y: &[f64],
    seg: &[i32],
    axis_x: bool,
) -> Vec<PathSample> {
    let n = t.len();
    let mut out: Vec<PathSample> = (0..n)
        .map(|k| PathSample {
            t_s: t[k],
            x_mm: x[k],
            y_mm: y[k],
            dt_s: 0.0,
            feed_mm_s: 0.0,
            a_mm_s2: 0.0,
            segment: seg[k],
            dir: 0.0,
            path_end_mm: f64::INFINITY,
        })
        .collect();
    if n == 0 {
        return out;
    }
    let dist = |a: usize, b: usize| ((x[b] - x[a]).powi(2) + (y[b] - y[a]).powi(2)).sqrt();
    for k in 0..n {
        let lo = k.saturating_sub(1);
        let hi = (k + 1).min(n - 1);
        out[k].dt_s = 0.5 * (t[hi] - t[lo]);
        let dt = t[hi] - t[lo];
        out[k].feed_mm_s = if dt > 0.0 { dist(lo, hi) / dt } else { 0.0 };
        let d = if axis_x { x[hi] - x[lo] } else { y[hi] - y[lo] };
        out[k].dir = if d > 1e-9 {
            1.0
        } else if d < -1e-9 {
            -1.0
        } else {
            0.0
        };
    }
    for k in 0..n {
        let lo = k.saturating_sub(1);
        let hi = (k + 1).min(n - 1);
        let dt = t[hi] - t[lo];
        out[k].a_mm_s2 = if dt > 0.0 {
            ((out[hi].feed_mm_s - out[lo].feed_mm_s) / dt).abs()
        } else {
            0.0
        };
    }
    // Path-end distance: arc length to the first and last sample of the
    // sample's pass (a run of equal segment ids ≥ 0).
    let mut k = 0;
    while k < n {
        let s = seg[k];
        let mut e = k;
        while e + 1 < n && seg[e + 1] == s {
            e += 1;
        }
        if s >= 0 {
            let mut arc = vec![0.0; e - k + 1];
            for q in k + 1..=e {
                arc[q - k] = arc[q - k - 1] + dist(q - 1, q);
            }
            let total = arc[e - k];
            for q in k..=e {
                out[q].path_end_mm = arc[q - k].min(total - arc[q - k]);
            }
        }
        k = e + 1;
    }
    out
}

/// A raster over the grid's rectangle (the tool centre from edge to edge):
/// passes along x (or y) every `step` mm, trapezoidal speed profile with
/// acceleration `accel` at both ends, a step-over move between passes,
/// sampled at `rate_hz`. Times start at `t0`.
pub fn raster_path(
    grid: &Grid,
    feed: f64,
    step: f64,
    accel: f64,
    rate_hz: f64,
    axis_x: bool,
) -> Vec<PathSample> {
    let (a0, a1, b0, b1) = if axis_x {
        (grid.x0, grid.x_max(), grid.y0, grid.y_max())
    } else {
        (grid.y0, grid.y_max(), grid.x0, grid.x_max())
    };
    let n_pass = ((b1 - b0) / step).ceil() as usize + 1;
    let len = a1 - a0;
    let (mut t, mut x, mut y, mut seg) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut t0 = 0.0;
    let dt = 1.0 / rate_hz;
    let mut push = |tt: f64, a: f64, b: f64, s: i32| {
        t.push(tt);
        if axis_x {
            x.push(a);
            y.push(b);
        } else {
            x.push(b);
            y.push(a);
        }
        seg.push(s);
    };
    for p in 0..n_pass {
        let b = (b0 + p as f64 * step).min(b1);
        let fwd = p % 2 == 0;
        let (dur, pos) = trapezoid(len, feed, accel);
        let steps = (dur * rate_hz).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let tt = (k as f64 * dt).min(dur);
            let s = pos(tt);
            push(t0 + tt, if fwd { a0 + s } else { a1 - s }, b, p as i32);
        }
        t0 += dur;
        if p + 1 < n_pass {
            // Step-over to the next pass (off the pass: segment −1).
            let nb = (b0 + (p + 1) as f64 * step).min(b1);
            let (dur2, pos2) = trapezoid(nb - b, feed, accel);
            let steps2 = (dur2 * rate_hz).ceil().max(1.0) as usize;
            let a_end = if fwd { a1 } else { a0 };
            for k in 1..steps2 {
                let tt = k as f64 * dur2 / steps2 as f64;
                push(t0 + tt, a_end, b + pos2(tt), -1);
            }
            t0 += dur2;
        }
    }
    complete_path(&t, &x, &y, &seg, axis_x)
}

/// Duration and position-of-time of a straight move of `len` at `feed` with
/// acceleration `accel` (triangular when too short to reach the feed).
pub fn trapezoid(len: f64, feed: f64, accel: f64) -> (f64, impl Fn(f64) -> f64) {
    let ta = feed / accel;
    let da = 0.5 * accel * ta * ta;
    let (vmax, ta, tc) = if 2.0 * da >= len {
        let ta = (len / accel).sqrt();
        (accel * ta, ta, 0.0)
    } else {
        (feed, ta, (len - 2.0 * da) / feed)
    };
    let dur = 2.0 * ta + tc;
    let pos = move |t: f64| {
        let t = t.clamp(0.0, dur);
        if t < ta {
            0.5 * accel * t * t
        } else if t < ta + tc {
            0.5 * accel * ta * ta + vmax * (t - ta)
        } else {
            let r = dur - t;
            len - 0.5 * accel * r * r
        }
    };
    (dur, pos)
}

/// An Archimedean spiral r = b·θ of the tool centre around (cx, cy) out to
/// `radius`, pitch 2πb = `pitch`, at constant path speed; samples carry
/// equal arc length so their dwell sums to the spiral's duration.
pub fn spiral_path(
    cx: f64,
    cy: f64,
    radius: f64,
    pitch: f64,
    speed: f64,
    ds: f64,
) -> Vec<PathSample> {
    let b = pitch / (2.0 * PI);
    let theta_max = radius / b;
    // Arc length s(θ) = (b/2)[θ√(1+θ²) + asinh θ]; step θ by ds/|dr/dθ…|.
    let mut out = Vec::new();
    let mut th: f64 = 0.0;
    let mut t = 0.0;
    let dt = ds / speed;
    while th <= theta_max {
        let r = b * th;
        out.push(PathSample {
            t_s: t,
            x_mm: cx + r * th.cos(),
            y_mm: cy + r * th.sin(),
            dt_s: dt,
            feed_mm_s: speed,
            a_mm_s2: 0.0,
            segment: 0,
            dir: 0.0,
            path_end_mm: 0.0,
        });
        th += ds / (b * (1.0 + th * th).sqrt());
        t += dt;
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The aplm-gantry's polishing tool (k_p, pressure and speeds of
    /// docs/models.md §2.5's example) at a given disc radius and step-over; the
    /// gantry plugin's tests share it.
    pub(crate) fn aplm_tool(radius_mm: f64, step_over_mm: f64) -> PolishTool {
        PolishTool {
            k_p_per_pa: 1.7097e-8,
            pressure_pa: 389.93,
            radius_mm,
            rev_per_s: 2.5,
            linear_speed_mm_s: 1000.0,
            spring_compression_mm: 0.5,
            feed_mm_s: 100.0,
            step_over_mm,
            accel_mm_s2: 500.0,
        }
    }

    #[test]
    fn fft_equals_direct_convolution() {
        let (nx, ny) = (23, 17);
        let img: Vec<f64> = (0..nx * ny)
            .map(|k| ((k * 7919) % 101) as f64 / 100.0)
            .collect();
        let (kx, ky) = (7, 5);
        let ker: Vec<f64> = (0..kx * ky).map(|k| 1.0 + (k % 3) as f64).collect();
        let a = fft_convolve_same(&img, nx, ny, &ker, kx, ky);
        let b = direct_convolve_same(&img, (nx, ny), &ker, (kx, ky));
        for (u, v) in a.iter().zip(&b) {
            assert!((u - v).abs() < 1e-10, "{u} vs {v}");
        }
        // A kept Convolver reuses its buffers: the second image's result is
        // exactly a fresh convolution's (padding re-zeroed, nothing left
        // from the first image).
        let conv = Convolver::new(nx, ny, &ker, kx, ky);
        let first = conv.apply(&img);
        assert_eq!(first, a);
        let img2: Vec<f64> = img.iter().map(|v| 3.0 - v * v).collect();
        assert_eq!(
            conv.apply(&img2),
            fft_convolve_same(&img2, nx, ny, &ker, kx, ky)
        );
    }

    #[test]
    fn influence_function_and_sizes() {
        let t = aplm_tool(200.0, 100.0);
        // Centre: k_p·p·v_lin = 6.667e-6 × 1000 mm/s.
        assert!((t.rate_mm_s(0.0) - 1.7097e-8 * 389.93 * 1000.0).abs() < 1e-15);
        assert_eq!(t.rate_mm_s(200.1), 0.0);
        assert!(t.rate_mm_s(150.0) > t.rate_mm_s(50.0));
        let (k, kx, ky) = t.kernel(50.0, 40.0);
        assert_eq!((kx, ky), (9, 11));
        assert_eq!(k.len(), 99);
        assert_eq!(fast_len(2249), 2250);
        assert_eq!(fast_len(4095), 4096);
    }

    #[test]
    fn trapezoid_and_spiral() {
        let (d, p) = trapezoid(1000.0, 100.0, 500.0);
        assert!((d - (0.4 + 9.8)).abs() < 1e-12);
        assert!((p(d) - 1000.0).abs() < 1e-9 && p(0.0) == 0.0);
        let s = spiral_path(0.0, 0.0, 50.0, 10.0, 100.0, 2.0);
        let rmax = s.iter().map(|p| p.x_mm.hypot(p.y_mm)).fold(0.0, f64::max);
        assert!(rmax <= 50.0 + 1e-9 && rmax > 45.0);
        // Equal arc steps: consecutive samples ≈ ds apart.
        let d01 = (s[101].x_mm - s[100].x_mm).hypot(s[101].y_mm - s[100].y_mm);
        assert!((d01 - 2.0).abs() < 0.05, "{d01}");
    }
}
