//! Inline SVG charts (plotters' SVG backend): no network, no JavaScript.
//! Every chart carries `class="chart"` so the page's stylesheet can scale
//! it down to the column width (no element wider than the viewport);
//! axis text is 14 px so it reads at 100 % zoom.

use std::fmt::Write;

use plotters::prelude::*;

mod xy;
pub use xy::*;

/// Palette for series (colour-blind friendly, Okabe–Ito).
const COLORS: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
];

const FONT: &str = "sans-serif";
// Plotters' SVG backend writes text at ~0.8 × the size asked: these give
// 16 px captions, 13–14 px tick labels and axis titles on the page.
const CAPTION_PX: u32 = 20;
const LABEL_PX: u32 = 17;
const DESC_PX: u32 = 18;
/// Text drawn by hand (colour bar), in px as written.
const BAR_TEXT_PX: u32 = 14;
/// Width of the colour bar strip beside a heat map.
const BAR_W: u32 = 96;

fn bounds(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        let pad = if lo.abs() > 0.0 { lo.abs() * 0.1 } else { 1.0 };
        return (lo - pad, hi + pad);
    }
    let pad = (hi - lo) * 0.05;
    (lo - pad, hi + pad)
}

/// A tick label with three significant digits and no exponent for the
/// sizes a report shows.
/// A chart on the SVG backend over f64 axes.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<F64Axis, F64Axis>>;
type F64Axis = plotters::coord::types::RangedCoordf64;

/// The pages' chart frame: caption, margins, label areas (the y label area
/// wide enough for the chart's tick text), over the given x and y ranges.
fn framed_chart<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    title: &str,
    y_label_area_px: u32,
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
) -> Option<Chart<'a, 'b>> {
    ChartBuilder::on(root)
        .caption(title, (FONT, CAPTION_PX))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(y_label_area_px)
        .build_cartesian_2d(x, y)
        .ok()
}

/// Axes with their descriptions and tick text in the pages' style, no
/// grid lines (a map's cells fill the plot). Each axis in one notation.
fn draw_axes(
    chart: &mut Chart,
    (x_label, y_label): (&str, &str),
    (x, y): ((f64, f64), (f64, f64)),
) {
    let (ax, ay) = (axis_formatter(x.0, x.1, 7), axis_formatter(y.0, y.1, 6));
    let fx = |v: &f64| ax.text(*v);
    let fy = |v: &f64| ay.text(*v);
    let _ = chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_labels(7)
        .y_labels(6)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .label_style((FONT, LABEL_PX))
        .axis_desc_style((FONT, DESC_PX))
        .disable_mesh()
        .draw();
}

/// One axis's tick text in one notation: every label with the decimals
/// of the axis's tick step, so an axis reads 0.5, 1.0, 1.5 and not 0.500,
/// 1, 1.50; values too small or too large for plain notation share the
/// scientific one.
#[derive(Clone, Copy, Debug)]
pub struct AxisText {
    decimals: usize,
    scientific: bool,
}

impl AxisText {
    /// Every label with `decimals` decimals.
    pub fn fixed(decimals: usize) -> AxisText {
        AxisText {
            decimals,
            scientific: false,
        }
    }
    pub fn text(&self, v: f64) -> String {
        if !v.is_finite() {
            return "—".into();
        }
        let d = self.decimals;
        let s = if self.scientific {
            if v == 0.0 {
                return "0".into();
            }
            format!("{v:.d$e}")
        } else {
            format!("{v:.d$}")
        };
        // "-0.0" is "0.0".
        match s.strip_prefix('-') {
            Some(r) if r.chars().all(|c| c == '0' || c == '.') => r.to_string(),
            _ => s,
        }
    }
}

/// The notation of an axis over [lo, hi] with about `labels` ticks: the
/// decimals of a step of 1, 2 or 5 × 10^k at twice that many ticks (so a
/// finer step than the one drawn never needs more decimals than given).
pub fn axis_formatter(lo: f64, hi: f64, labels: usize) -> AxisText {
    let big = lo.abs().max(hi.abs());
    let span = (hi - lo).abs();
    if !(big.is_finite() && span.is_finite()) || big == 0.0 {
        return AxisText::fixed(0);
    }
    if !(1e-3..1e6).contains(&big) {
        return AxisText {
            decimals: 2,
            scientific: true,
        };
    }
    let raw = span.max(big * 1e-9) / (2 * labels.max(1)) as f64;
    let e = raw.log10().floor();
    let m = raw / 10f64.powf(e);
    let step = if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    } * 10f64.powf(e);
    AxisText::fixed((-(step.log10() + 1e-9).floor()).clamp(0.0, 9.0) as usize)
}

/// Smallest spacing of distinct finite values (a grid's cell size; 1e300
/// when there are fewer than two).
pub fn spacing(v: impl Iterator<Item = f64>) -> f64 {
    let mut u: Vec<f64> = v.filter(|x| x.is_finite()).collect();
    u.sort_by(f64::total_cmp);
    u.dedup();
    u.windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min)
        .min(1e300)
}

pub fn tick(v: f64) -> String {
    if !v.is_finite() {
        return "—".into();
    }
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if (v.fract() == 0.0 && a < 1e6) || a >= 100.0 {
        // Whole numbers, and anything ≥ 100, without decimals.
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else if a >= 0.01 {
        format!("{v:.3}")
    } else {
        // Three significant digits, never scientific notation.
        crate::units::format::plain_number(v, 3)
    }
}

/// Mark plotters' SVG as a chart (scaled by the stylesheet), compacted.
fn classed(svg: String) -> String {
    compact(&svg).replacen(
        "<svg ",
        &format!("<svg class=\"chart\" font-family=\"{FONT}\" "),
        1,
    )
}

/// Plotters' SVG without the attributes that restate defaults (opacity 1,
/// no stroke width for unstroked shapes, the font family the root sets,
/// 16-digit font sizes): a fleet page carries dozens of charts.
fn compact(svg: &str) -> String {
    let mut s = svg
        .replace(" opacity=\"1\"", "")
        .replace(" stroke=\"none\" stroke-width=\"1\"", "")
        .replace(&format!(" font-family=\"{FONT}\""), "")
        .replace("\n</text>", "</text>")
        .replace(">\n", ">");
    // font-size="16.129032258064516" → font-size="16.1"
    let mut out = String::with_capacity(s.len());
    while let Some(i) = s.find("font-size=\"") {
        let start = i + "font-size=\"".len();
        out.push_str(&s[..start]);
        let end = s[start..].find('"').map(|e| start + e).unwrap_or(s.len());
        let v: f64 = s[start..end].parse().unwrap_or(12.0);
        out.push_str(&format!("{v:.1}"));
        s = s[end..].to_string();
    }
    out.push_str(&s);
    out
}

/// Horizontal bars (label, value), e.g. effect ranking. The label column
/// is as wide as the longest label.
pub fn bar_chart(title: &str, value_label: &str, bars: &[(String, f64)]) -> String {
    let mut out = String::new();
    {
        let h = (84 + 26 * bars.len().max(1)) as u32;
        let longest = bars.iter().map(|b| b.0.chars().count()).max().unwrap_or(4);
        let label_w = (16 + 8 * longest).clamp(60, 320) as u32;
        let root = SVGBackend::with_string(&mut out, (720, h)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (_, hi) = bounds(bars.iter().map(|b| b.1).chain([0.0]));
        let n = bars.len().max(1);
        // Segmented rows: each label centred on its bar, bars apart.
        let chart = ChartBuilder::on(&root)
            .caption(title, (FONT, CAPTION_PX))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(label_w)
            .build_cartesian_2d(0.0..hi.max(1e-12), (0..n).into_segmented());
        if let Ok(mut chart) = chart {
            let labels: Vec<String> = bars.iter().map(|b| b.0.clone()).collect();
            // One notation along the value axis.
            let notation = axis_formatter(0.0, hi, 5);
            let fx = |v: &f64| notation.text(*v);
            let fy = |v: &SegmentValue<usize>| match v {
                SegmentValue::CenterOf(i) => (n - 1)
                    .checked_sub(*i)
                    .and_then(|k| labels.get(k).cloned())
                    .unwrap_or_default(),
                _ => String::new(),
            };
            let _ = chart
                .configure_mesh()
                .x_desc(value_label)
                .y_labels(n)
                .x_label_formatter(&fx)
                .y_label_formatter(&fy)
                .label_style((FONT, LABEL_PX))
                .axis_desc_style((FONT, DESC_PX))
                .light_line_style(WHITE.mix(0.0))
                .disable_y_mesh()
                .draw();
            let _ = chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
                let y = n - 1 - i;
                let mut r = Rectangle::new(
                    [
                        (0.0, SegmentValue::Exact(y)),
                        (b.1.max(0.0), SegmentValue::Exact(y + 1)),
                    ],
                    COLORS[0].mix(0.8).filled(),
                );
                r.set_margin(3, 3, 0, 0);
                r
            }));
        }
        let _ = root.present();
    }
    classed(out)
}

/// A heat map: values on a grid, with a colour bar in `unit`.
#[derive(Clone, Copy)]
pub struct Heat<'a> {
    pub title: &'a str,
    /// (x, y, value) per cell centre.
    pub cells: &'a [(f64, f64, f64)],
    pub unit: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    /// The |value| at full colour: give the same to maps that are compared
    /// (before/after) so they share one scale; `None` = this map's max.
    pub vmax: Option<f64>,
    /// Diverging blue–white–red around 0 (signed data) or sequential
    /// white–red from 0 (magnitudes).
    pub diverging: bool,
    /// Cells to outline (e.g. those inside a significant region), by
    /// their centres: each is snapped to the map's nearest cell and the
    /// outer edge of the outlined cells is drawn, so the outline follows
    /// the map's own grid.
    pub outlined: &'a [(f64, f64)],
}

impl<'a> Heat<'a> {
    /// Defaults: x/y in mm, own scale, diverging when any value is negative.
    pub fn new(title: &'a str, cells: &'a [(f64, f64, f64)], unit: &'a str) -> Self {
        Heat {
            title,
            cells,
            unit,
            x_label: "x (mm)",
            y_label: "y (mm)",
            vmax: None,
            diverging: cells.iter().any(|c| c.2 < 0.0),
            outlined: &[],
        }
    }
}

/// The largest finite |value| over cell sets: one colour scale for maps
/// that are compared.
pub fn shared_vmax<'a>(sets: impl IntoIterator<Item = &'a [(f64, f64, f64)]>) -> f64 {
    sets.into_iter()
        .flat_map(|s| s.iter().map(|c| c.2.abs()))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
}

fn colour(t: f64, diverging: bool) -> RGBColor {
    if diverging {
        let t = t.clamp(-1.0, 1.0);
        // Blue for negative, red for positive, white at zero.
        let (r, g, b) = if t >= 0.0 {
            (255.0 - 75.0 * t, 255.0 * (1.0 - t), 255.0 * (1.0 - t))
        } else {
            (
                255.0 * (1.0 + t),
                255.0 * (1.0 + 0.6 * t),
                255.0 - 75.0 * (-t),
            )
        };
        RGBColor(r as u8, g as u8, b as u8)
    } else {
        let t = t.clamp(0.0, 1.0);
        // White → orange → dark red.
        let (r, g, b) = (
            255.0 - 95.0 * t,
            255.0 * (1.0 - t).powf(0.8),
            255.0 * (1.0 - t).powi(2),
        );
        RGBColor(r as u8, g as u8, b as u8)
    }
}

/// Colour-bar steps: a cell's colour is one of the bar's.
const STEPS: usize = 32;

/// `t` (value / vmax) rounded to the centre of its colour-bar step.
fn quantise(t: f64, diverging: bool) -> f64 {
    let lo = if diverging { -1.0 } else { 0.0 };
    let t = t.clamp(lo, 1.0);
    let w = (1.0 - lo) / STEPS as f64;
    let k = (((t - lo) / w) as usize).min(STEPS - 1);
    lo + (k as f64 + 0.5) * w
}

fn hex(c: RGBColor) -> String {
    format!("#{:02x}{:02x}{:02x}", c.0, c.1, c.2)
}

/// A heat map of values on a grid (x, y, value) with its colour bar.
pub fn heatmap(title: &str, cells: &[(f64, f64, f64)], value_label: &str) -> String {
    heat(&Heat::new(title, cells, value_label))
}

/// A heat map as [`Heat`] describes it.
pub fn heat(h: &Heat) -> String {
    let (w, ht) = (720u32, 440u32);
    let vmax = h.vmax.unwrap_or_else(|| shared_vmax([h.cells])).max(1e-12);
    let mut inner = String::new();
    let mut cells_svg = String::from("<g stroke=\"none\">");
    {
        let root = SVGBackend::with_string(&mut inner, (w - BAR_W, ht)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let mut xs: Vec<f64> = h.cells.iter().map(|c| c.0).collect();
        let mut ys: Vec<f64> = h.cells.iter().map(|c| c.1).collect();
        xs.sort_by(f64::total_cmp);
        xs.dedup();
        ys.sort_by(f64::total_cmp);
        ys.dedup();
        let dx = if xs.len() > 1 {
            spacing(xs.iter().copied())
        } else {
            1.0
        };
        let dy = if ys.len() > 1 {
            spacing(ys.iter().copied())
        } else {
            1.0
        };
        let (x0, x1) = bounds(xs.iter().flat_map(|x| [x - dx / 2.0, x + dx / 2.0]));
        let (y0, y1) = bounds(ys.iter().flat_map(|y| [y - dy / 2.0, y + dy / 2.0]));
        let chart = framed_chart(&root, h.title, 76, (x0..x1, y0..y1));
        if let Some(mut chart) = chart {
            draw_axes(&mut chart, (h.x_label, h.y_label), ((x0, x1), (y0, y1)));
            // Cells and outlines written by hand as compact rects (a plotters
            // rect carries five more attributes): the map's bytes matter on
            // a fleet page with dozens of maps. Colours are quantised to the
            // colour bar's steps.
            // One path per colour: "M x y h w v h h -w z" per cell.
            let mut by_colour: std::collections::BTreeMap<String, String> = Default::default();
            for c in h.cells.iter().filter(|c| c.2.is_finite()) {
                let (px0, py0) = chart.backend_coord(&(c.0 - dx / 2.0, c.1 + dy / 2.0));
                let (px1, py1) = chart.backend_coord(&(c.0 + dx / 2.0, c.1 - dy / 2.0));
                let t = quantise(c.2 / vmax, h.diverging);
                let (cw, ch) = ((px1 - px0).max(1), (py1 - py0).max(1));
                let _ = write!(
                    by_colour.entry(hex(colour(t, h.diverging))).or_default(),
                    "M{px0} {py0}h{cw}v{ch}h-{cw}z"
                );
            }
            for (fill, d) in by_colour {
                let _ = write!(cells_svg, r#"<path fill="{fill}" d="{d}"/>"#);
            }
            let edges = outline_edges(h.cells, h.outlined, (dx, dy));
            if !edges.is_empty() {
                let mut d = String::new();
                for ((ax, ay), (bx, by)) in edges {
                    let (p0, p1) = (
                        chart.backend_coord(&(ax, ay)),
                        chart.backend_coord(&(bx, by)),
                    );
                    let _ = write!(d, "M{} {}L{} {}", p0.0, p0.1, p1.0, p1.1);
                }
                let _ = write!(
                    cells_svg,
                    r##"<path class="outline" d="{d}" fill="none" stroke="#000" stroke-width="2.5" stroke-linecap="square"/>"##
                );
            }
        }
        let _ = root.present();
    }
    let mut s = format!(
        r#"<svg class="chart" xmlns="http://www.w3.org/2000/svg" width="{w}" height="{ht}" viewBox="0 0 {w} {ht}" font-family="{FONT}">"#
    );
    s.push_str(&compact(&inner));
    cells_svg.push_str("</g>");
    s.push_str(&cells_svg);
    // The colour bar: 32 steps from −vmax (or 0) to +vmax, labelled.
    let (bx, top, bottom) = ((w - BAR_W + 10) as f64, 64.0, (ht - 64) as f64);
    let lo = if h.diverging { -vmax } else { 0.0 };
    // A vertical gradient, top = +vmax; the id is unique per bar content
    // (identical bars may share it: their definitions are identical).
    let id = {
        use std::hash::{Hash, Hasher};
        let mut hs = std::collections::hash_map::DefaultHasher::new();
        (h.diverging, vmax.to_bits()).hash(&mut hs);
        format!("cbar{:x}", hs.finish())
    };
    let _ = write!(
        s,
        r#"<defs><linearGradient id="{id}" x1="0" y1="0" x2="0" y2="1">"#
    );
    let stops = 8;
    for k in 0..=stops {
        let f = k as f64 / stops as f64;
        let v = vmax - f * (vmax - lo);
        let _ = write!(
            s,
            r#"<stop offset="{f:.3}" stop-color="{}"/>"#,
            hex(colour(v / vmax, h.diverging))
        );
    }
    let _ = write!(
        s,
        r#"</linearGradient></defs><rect x="{bx}" y="{top}" width="18" height="{}" fill="url(#{id})"/>"#,
        bottom - top
    );
    let _ = write!(
        s,
        r##"<rect x="{bx}" y="{top}" width="18" height="{}" fill="none" stroke="#444"/><text x="{}" y="{}" font-size="{BAR_TEXT_PX}" font-weight="bold" text-anchor="middle">{}</text>"##,
        bottom - top,
        bx + 9.0,
        top - 14.0,
        crate::esc(h.unit)
    );
    let ticks = 5;
    let bar_text = bar_notation(vmax, lo);
    for k in 0..ticks {
        let f = k as f64 / (ticks - 1) as f64;
        let v = vmax - f * (vmax - lo);
        let y = top + f * (bottom - top);
        let _ = write!(
            s,
            r##"<line x1="{}" x2="{}" y1="{y:.1}" y2="{y:.1}" stroke="#444"/><text x="{}" y="{:.1}" font-size="{BAR_TEXT_PX}">{}</text>"##,
            bx + 18.0,
            bx + 22.0,
            bx + 25.0,
            y + 5.0,
            bar_text.text(v)
        );
    }
    s.push_str("</svg>");
    s
}

/// The colour bar's tick text: three significant digits of its full scale
/// for every tick (2.50, 1.25, 0.00, −1.25, −2.50).
fn bar_notation(vmax: f64, lo: f64) -> AxisText {
    if !(1e-3..1e6).contains(&vmax) {
        return axis_formatter(lo, vmax, 4);
    }
    let e = vmax.log10().floor() as i32;
    AxisText::fixed((2 - e).clamp(0, 9) as usize)
}

/// The map cell nearest to (x, y): its index in `cells`.
fn nearest_cell(
    cells: &[(f64, f64, f64)],
    (x, y): (f64, f64),
    (dx, dy): (f64, f64),
) -> Option<usize> {
    cells
        .iter()
        .enumerate()
        .filter(|(_, c)| c.2.is_finite())
        .map(|(i, c)| (i, ((c.0 - x) / dx).powi(2) + ((c.1 - y) / dy).powi(2)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// The outer edges of the union of the outlined cells (each snapped to
/// the nearest drawn cell), as segments in data coordinates: an edge two
/// outlined cells share is not drawn, so a region reads as one contour
/// on the cells it covers.
pub fn outline_edges(
    cells: &[(f64, f64, f64)],
    outlined: &[(f64, f64)],
    (dx, dy): (f64, f64),
) -> Vec<((f64, f64), (f64, f64))> {
    let on: std::collections::BTreeSet<usize> = outlined
        .iter()
        .filter_map(|p| nearest_cell(cells, *p, (dx, dy)))
        .collect();
    // Grid index of a cell: its centre in steps of the cell size.
    let key = |c: &(f64, f64, f64)| ((c.0 / dx).round() as i64, (c.1 / dy).round() as i64);
    let keys: std::collections::BTreeSet<(i64, i64)> = on.iter().map(|i| key(&cells[*i])).collect();
    let mut edges = Vec::new();
    for i in &on {
        let c = cells[*i];
        let (kx, ky) = key(&c);
        let (x0, x1, y0, y1) = (
            c.0 - dx / 2.0,
            c.0 + dx / 2.0,
            c.1 - dy / 2.0,
            c.1 + dy / 2.0,
        );
        if !keys.contains(&(kx - 1, ky)) {
            edges.push(((x0, y0), (x0, y1)));
        }
        if !keys.contains(&(kx + 1, ky)) {
            edges.push(((x1, y0), (x1, y1)));
        }
        if !keys.contains(&(kx, ky - 1)) {
            edges.push(((x0, y0), (x1, y0)));
        }
        if !keys.contains(&(kx, ky + 1)) {
            edges.push(((x0, y1), (x1, y1)));
        }
    }
    edges
}

/// A thumbnail of a map for the at-a-glance table ("where"): the cells on
/// the full map's colour scale (sequential from 0 for an RMS, diverging
/// for signed values), no axes — the full map with its axes and colour
/// bar is in the observable's section, one click away.
pub fn mini_heat(
    cells: &[(f64, f64, f64)],
    (w, h): (u32, u32),
    diverging: bool,
    label: &str,
) -> String {
    let mut xs: Vec<f64> = cells.iter().map(|c| c.0).collect();
    let mut ys: Vec<f64> = cells.iter().map(|c| c.1).collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    ys.sort_by(f64::total_cmp);
    ys.dedup();
    let vmax = shared_vmax([cells]);
    if xs.is_empty() || ys.is_empty() || vmax <= 0.0 {
        return String::new();
    }
    let (cw, ch) = (w as f64 / xs.len() as f64, h as f64 / ys.len() as f64);
    let mut s = format!(
        r##"<svg class="mini" width="{w}" height="{h}" role="img" aria-label="{}"><rect width="{w}" height="{h}" fill="#eee"/>"##,
        crate::esc(label)
    );
    for &(x, y, v) in cells {
        if !v.is_finite() {
            continue;
        }
        let ix = xs.partition_point(|a| *a < x) as f64;
        // y grows upwards on the workpiece, downwards in SVG.
        let iy = (ys.len() - 1 - ys.partition_point(|a| *a < y)) as f64;
        let _ = write!(
            s,
            r##"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{}"/>"##,
            ix * cw,
            iy * ch,
            cw + 0.3,
            ch + 0.3,
            hex(colour(quantise(v / vmax, diverging), diverging))
        );
    }
    s.push_str("</svg>");
    s
}

/// A thumbnail of the gap against a covariate ("which"): mean gap per bin
/// as a line over a zero line, on the row's own scale.
pub fn mini_curve(points: &[(f64, f64)], w: u32, h: u32, label: &str) -> String {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    if pts.len() < 2 {
        return String::new();
    }
    let (x0, x1) = bounds(pts.iter().map(|p| p.0));
    let (y0, y1) = bounds(pts.iter().map(|p| p.1).chain([0.0]));
    let (wf, hf) = (w as f64, h as f64);
    let px = |x: f64| 1.0 + (wf - 2.0) * (x - x0) / (x1 - x0).max(1e-300);
    let py = |y: f64| 1.0 + (hf - 2.0) * (1.0 - (y - y0) / (y1 - y0).max(1e-300));
    let mut s = format!(
        r##"<svg class="mini" width="{w}" height="{h}" role="img" aria-label="{}"><line x1="0" x2="{w}" y1="{z:.1}" y2="{z:.1}" stroke="#bbb"/><polyline fill="none" stroke="#1f77b4" stroke-width="1.5" points=""##,
        super::esc(label),
        z = py(0.0)
    );
    for (i, (x, y)) in pts.iter().enumerate() {
        let _ = write!(
            s,
            "{}{:.1},{:.1}",
            if i > 0 { " " } else { "" },
            px(*x),
            py(*y)
        );
    }
    s.push_str(r#""/></svg>"#);
    s
}

/// A ballbar-style polar plot: the radial error of circular moves against
/// the angle on the circle, drawn about a reference circle (zero error)
/// with rings at ± the largest error, so a reversal spike (a bump where an
/// axis changes direction, at 0°/90°/180°/270°) or a backlash step (the
/// circle split into offset halves) stands out at any size of error.
/// `series`: (name, [(angle rad, error)]). Hand-drawn (plotters has no
/// polar coordinates); marked `class="chart polar"`.
pub fn polar_chart(title: &str, unit: &str, series: &[(&str, &[(f64, f64)])]) -> String {
    const W: f64 = 480.0;
    const R0: f64 = 120.0;
    const SPAN: f64 = 80.0;
    let (cx, cy) = (W / 2.0, 40.0 + R0 + SPAN + 10.0);
    let e_max = series
        .iter()
        .flat_map(|s| s.1.iter().map(|p| p.1.abs()))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        .max(1e-9);
    let rad = |e: f64| R0 + SPAN * e / e_max;
    let row = 20.0;
    // Below the circle: the 270° label, then the legend and the rings' scale.
    let legend_y = cy + R0 + SPAN + 44.0;
    let h = legend_y + row * (series.len() + 1) as f64;
    let mut s = format!(
        r#"<svg class="chart polar" xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="{FONT}"><rect width="{W}" height="{h}" fill="white"/><text x="{cx}" y="24" font-size="16" text-anchor="middle">{}</text>"#,
        crate::esc(title)
    );
    for (e, dash) in [(-e_max, "4 3"), (0.0, ""), (e_max, "4 3")] {
        let _ = write!(
            s,
            r##"<circle cx="{cx}" cy="{cy}" r="{:.1}" fill="none" stroke="#999" stroke-width="1"{}/>"##,
            rad(e),
            if dash.is_empty() {
                String::new()
            } else {
                format!(r#" stroke-dasharray="{dash}""#)
            }
        );
    }
    for k in 0..4 {
        let a = k as f64 * std::f64::consts::FRAC_PI_2;
        let (dx, dy) = (a.cos(), -a.sin());
        let _ = write!(
            s,
            r##"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#ccc"/><text x="{:.1}" y="{:.1}" font-size="{BAR_TEXT_PX}" text-anchor="middle">{}°</text>"##,
            cx + dx * (R0 - SPAN),
            cy + dy * (R0 - SPAN),
            cx + dx * (R0 + SPAN),
            cy + dy * (R0 + SPAN),
            cx + dx * (R0 + SPAN + 14.0),
            cy + dy * (R0 + SPAN + 14.0) + 5.0,
            k * 90
        );
    }
    let _ = write!(
        s,
        r#"<text x="96" y="{:.1}" font-size="{BAR_TEXT_PX}">rings: −{e}, 0, +{e} {}</text>"#,
        legend_y + row * series.len() as f64 + 5.0,
        crate::esc(unit),
        e = tick(e_max)
    );
    for (i, (_, pts)) in series.iter().enumerate() {
        let c = COLORS[i % COLORS.len()];
        let mut d = String::new();
        for (k, (a, e)) in pts
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .enumerate()
        {
            let r = rad(*e);
            let _ = write!(
                d,
                "{}{:.1},{:.1}",
                if k == 0 { "M" } else { " L" },
                cx + r * a.cos(),
                cy - r * a.sin()
            );
        }
        let _ = write!(
            s,
            r#"<path d="{d}" fill="none" stroke="{}" stroke-width="1.5"/>"#,
            hex(c)
        );
    }
    for (i, (name, _)) in series.iter().enumerate() {
        let y = legend_y + row * i as f64;
        let _ = write!(
            s,
            r#"<line x1="96" x2="120" y1="{y:.0}" y2="{y:.0}" stroke="{}" stroke-width="2"/><text x="128" y="{:.0}" font-size="{BAR_TEXT_PX}">{}</text>"#,
            hex(COLORS[i % COLORS.len()]),
            y + 5.0,
            crate::esc(name)
        );
    }
    s.push_str("</svg>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_are_svg() {
        let pts = [(0.0, 1.0), (1.0, 2.0), (2.0, 1.5)];
        let s = xy_chart(
            "t",
            "x",
            "y",
            &[Series {
                name: "a",
                points: &pts,
                mark: Mark::Line,
            }],
        );
        assert!(s.starts_with("<svg class=\"chart\"") && s.contains("</svg>"));
        let b = bar_chart("b", "mm", &[("drift:t_s".into(), 0.5)]);
        assert!(b.contains("drift:t_s"));
        let h = heatmap("h", &[(0.0, 0.0, 1.0), (1.0, 0.0, -1.0)], "µm");
        assert!(h.contains("<rect"));
    }

    #[test]
    fn heat_map_has_a_colour_bar_with_its_unit_and_scale() {
        let cells = [(0.0, 0.0, 2.5), (1.0, 0.0, -1.0), (0.0, 1.0, 0.5)];
        let mut hm = Heat::new("gap", &cells, "µm");
        let own = heat(&hm);
        // Unit and the full-scale tick (±2.5) on the bar.
        assert!(own.contains(">µm</text>"), "{own}");
        assert!(own.contains(">2.50</text>") && own.contains(">-2.50</text>"));
        // One notation on the bar: the zero tick has the others' decimals.
        assert!(
            own.contains(">0.00</text>") && own.contains(">1.25</text>"),
            "{own}"
        );
        // A shared scale relabels the bar.
        hm.vmax = Some(10.0);
        let shared = heat(&hm);
        assert!(shared.contains(">10.0</text>") && !shared.contains(">2.50</text>"));
        assert!(!shared.contains("class=\"outline\""));
        // Outlined cells: one contour path.
        let o = [(0.1, -0.2)];
        hm.outlined = &o;
        assert_eq!(heat(&hm).matches("class=\"outline\"").count(), 1);
    }

    #[test]
    fn outlines_follow_the_map_cells_and_skip_shared_edges() {
        // A 3 × 2 grid of unit cells; outline the two left cells of row 0
        // (one asked off-centre: snapped to its cell).
        let cells: Vec<(f64, f64, f64)> = (0..3)
            .flat_map(|i| (0..2).map(move |j| (i as f64, j as f64, 1.0)))
            .collect();
        let e = outline_edges(&cells, &[(0.0, 0.0), (1.2, -0.1)], (1.0, 1.0));
        // Two cells side by side: 6 outer unit edges, the shared one absent.
        assert_eq!(e.len(), 6, "{e:?}");
        let on_grid = |v: f64| (v + 0.5).fract().abs() < 1e-12;
        assert!(e
            .iter()
            .all(|(a, b)| on_grid(a.0) && on_grid(a.1) && on_grid(b.0) && on_grid(b.1)));
        assert!(!e.contains(&((0.5, -0.5), (0.5, 0.5))), "shared edge drawn");
    }

    #[test]
    fn axes_read_in_one_notation() {
        let a = axis_formatter(0.0, 3.0, 7);
        assert_eq!(
            [a.text(0.5), a.text(1.0), a.text(1.5)],
            ["0.5", "1.0", "1.5"]
        );
        let b = axis_formatter(0.0, 250.0, 6);
        assert_eq!([b.text(0.0), b.text(100.0)], ["0", "100"]);
        let c = axis_formatter(0.0, 3.9e-5, 6);
        assert_eq!(c.text(3.9312e-5), "3.93e-5");
        assert_eq!(c.text(0.0), "0");
        assert_eq!(bar_notation(0.034, -0.034).text(0.0085), "0.0085");
    }

    #[test]
    fn ticks_read_without_exponents() {
        assert_eq!(tick(12.345), "12.3");
        assert_eq!(tick(0.5), "0.500");
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(250.0), "250");
        assert_eq!(tick(3.0), "3");
        assert_eq!(tick(0.0021), "0.00210");
    }
}
