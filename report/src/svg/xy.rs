//! x–y charts: series drawn as lines, points or shaded bands (an interval
//! between a lower and an upper bound), integer x axes ticked with names
//! (a night's date, a run id), rings marking points (an alert), and dash
//! patterns once the palette's colours run out (an eighth series would
//! otherwise repeat the first one's colour).

use std::fmt::Write;

use plotters::prelude::*;

use super::{
    axis_formatter, bounds, compact, framed_chart, hex, BAR_TEXT_PX, COLORS, DESC_PX, FONT,
    LABEL_PX,
};

/// How a series is drawn.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Mark {
    Line,
    Points,
    /// A shaded band: the points are its outline, the lower bound left to
    /// right then the upper bound right to left ([`band_outline`]).
    Band,
}

pub struct Series<'a> {
    pub name: &'a str,
    pub points: &'a [(f64, f64)],
    pub mark: Mark,
}

/// The outline of a band from (x, lower, upper) triples: the polygon a
/// [`Mark::Band`] series fills. Triples with a missing bound are skipped.
pub fn band_outline(x_lo_hi: &[(f64, f64, f64)]) -> Vec<(f64, f64)> {
    let ok: Vec<&(f64, f64, f64)> = x_lo_hi
        .iter()
        .filter(|p| p.0.is_finite() && p.1.is_finite() && p.2.is_finite())
        .collect();
    ok.iter()
        .map(|p| (p.0, p.1))
        .chain(ok.iter().rev().map(|p| (p.0, p.2)))
        .collect()
}

/// What a chart shows beyond its series.
#[derive(Clone, Copy, Default)]
pub struct XyExtras<'a> {
    /// Names of the integer x positions 0, 1, 2, …: the x ticks are these
    /// names at whole positions only (a night's date, a run id). Empty: an
    /// x axis whose values are all whole numbers still gets whole ticks.
    pub x_names: &'a [String],
    /// Rings around points, each with a short label above it (an alert on
    /// a night): (x, y, label).
    pub rings: &'a [(f64, f64, String)],
}

/// Dash patterns by palette round: solid, dashed, dotted.
const DASHES: [&str; 3] = ["", "9 4", "2 3"];

/// The colour and dash pattern of series `i`: the palette's colours
/// first, then the same colours dashed, then dotted. A band takes the
/// colour of the series after it (a value and its interval read as one)
/// and uses no colour of its own.
fn style_of(series: &[Series], i: usize) -> (RGBColor, &'static str) {
    let k = series[..i].iter().filter(|s| s.mark != Mark::Band).count();
    (
        COLORS[k % COLORS.len()],
        DASHES[(k / COLORS.len()) % DASHES.len()],
    )
}

/// An x–y chart of one or more series.
pub fn xy_chart(title: &str, x_label: &str, y_label: &str, series: &[Series]) -> String {
    xy_chart_sized(title, x_label, y_label, series, (720, 380))
}

/// [`xy_chart`] at a given size in px (plots sized to their content).
pub fn xy_chart_sized(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    size: (u32, u32),
) -> String {
    xy_chart_with(
        title,
        (x_label, y_label),
        series,
        size,
        &XyExtras::default(),
    )
}

/// Whole-number tick positions over [lo, hi]: every `step`-th integer, the
/// step the smallest of 1, 2, 5, 10, … that keeps `max_ticks` or fewer.
pub fn integer_ticks(lo: f64, hi: f64, max_ticks: usize) -> Vec<i64> {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return Vec::new();
    }
    let (a, b) = (lo.ceil() as i64, hi.floor() as i64);
    let n = (b - a + 1).max(0) as usize;
    let step = (0..18u32)
        .flat_map(|e| [1i64, 2, 5].map(|m| m * 10i64.pow(e)))
        .find(|s| n.div_ceil(*s as usize) <= max_ticks.max(1))
        .unwrap_or(1);
    (a..=b).filter(|i| i.rem_euclid(step) == 0).collect()
}

/// [`xy_chart_sized`] with names on an integer x axis and rings.
pub fn xy_chart_with(
    title: &str,
    (x_label, y_label): (&str, &str),
    series: &[Series],
    size: (u32, u32),
    extras: &XyExtras,
) -> String {
    let mut out = String::new();
    let mut hand = String::new();
    let xs = || series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let whole_x = !extras.x_names.is_empty()
        || (xs().any(|x| x.is_finite())
            && xs().filter(|x| x.is_finite()).all(|x| x.fract() == 0.0));
    {
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (mut x0, mut x1) = bounds(xs());
        if !extras.x_names.is_empty() {
            // Every named position is on the axis, half a step padded.
            x0 = x0.min(-0.5);
            x1 = x1.max(extras.x_names.len() as f64 - 0.5);
        }
        let (y0, y1) = bounds(
            series
                .iter()
                .flat_map(|s| s.points.iter().map(|p| p.1))
                .chain(extras.rings.iter().map(|r| r.1)),
        );
        let chart = framed_chart(&root, title, 84, (x0..x1, y0..y1));
        if let Some(mut chart) = chart {
            let fy = axis_formatter(y0, y1, 6);
            let fx = axis_formatter(x0, x1, 7);
            let (fx, fy) = (|v: &f64| fx.text(*v), |v: &f64| fy.text(*v));
            let mut mesh = chart.configure_mesh();
            mesh.x_desc(x_label)
                .y_desc(y_label)
                .x_labels(if whole_x { 0 } else { 7 })
                .y_labels(6)
                .x_label_formatter(&fx)
                .y_label_formatter(&fy)
                .label_style((FONT, LABEL_PX))
                .axis_desc_style((FONT, DESC_PX));
            mesh.light_line_style(WHITE.mix(0.0));
            let _ = mesh.draw();
            if whole_x {
                whole_x_ticks(&chart, (x0, x1, y0), extras.x_names, size.0, &mut hand);
            }
            for (i, s) in series.iter().enumerate() {
                let (c, dash) = style_of(series, i);
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|p| p.0.is_finite() && p.1.is_finite())
                    .collect();
                match s.mark {
                    Mark::Band => {
                        if pts.len() >= 3 {
                            let _ = chart.draw_series(std::iter::once(Polygon::new(
                                pts,
                                c.mix(0.22).filled(),
                            )));
                        }
                    }
                    Mark::Line if dash.is_empty() => {
                        let _ = chart.draw_series(LineSeries::new(pts, c.stroke_width(2)));
                    }
                    Mark::Line => {
                        // Dashed lines by hand: plotters' SVG lines carry no
                        // dash pattern.
                        let mut d = String::new();
                        for (k, p) in pts.iter().enumerate() {
                            let (px, py) = chart.backend_coord(p);
                            let _ = write!(d, "{}{px} {py}", if k == 0 { "M" } else { "L" });
                        }
                        if !d.is_empty() {
                            let _ = write!(
                                hand,
                                r#"<path d="{d}" fill="none" stroke="{}" stroke-width="2" stroke-dasharray="{dash}"/>"#,
                                hex(c)
                            );
                        }
                    }
                    Mark::Points if dash.is_empty() => {
                        let _ = chart
                            .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, c.filled())));
                    }
                    Mark::Points => {
                        // Past the palette: hollow points.
                        let _ = chart.draw_series(
                            pts.into_iter()
                                .map(|p| Circle::new(p, 4, c.stroke_width(1))),
                        );
                    }
                }
            }
            for (x, y, label) in extras.rings {
                if !(x.is_finite() && y.is_finite()) {
                    continue;
                }
                let (px, py) = chart.backend_coord(&(*x, *y));
                let _ = write!(
                    hand,
                    r##"<circle class="ring" cx="{px}" cy="{py}" r="9" fill="none" stroke="#c00" stroke-width="2.5"/><text x="{px}" y="{}" font-size="{BAR_TEXT_PX}" fill="#c00" text-anchor="middle" font-weight="bold">{}</text>"##,
                    py - 14,
                    crate::esc(label)
                );
            }
        }
        let _ = root.present();
    }
    let inner = compact(&out);
    let inner = match inner.rfind("</svg>") {
        Some(i) => format!("{}{hand}</svg>", &inner[..i]),
        None => inner,
    };
    if series.len() < 2 {
        return inner.replacen(
            "<svg ",
            &format!("<svg class=\"chart\" font-family=\"{FONT}\" "),
            1,
        );
    }
    legend(&inner, series, size)
}

/// Ticks at whole x positions, labelled with their names (or the number),
/// as many as fit side by side.
fn whole_x_ticks(
    chart: &super::Chart,
    (x0, x1, y0): (f64, f64, f64),
    names: &[String],
    width_px: u32,
    out: &mut String,
) {
    let longest = if names.is_empty() {
        x0.abs().max(x1.abs()).log10().max(0.0) as usize + 2
    } else {
        names.iter().map(|n| n.chars().count()).max().unwrap_or(1)
    };
    // About 8 px a character at the tick text size, plus a gap.
    let fit = (width_px as usize).saturating_sub(120) / (8 * longest + 16);
    for i in integer_ticks(x0, x1, fit.max(2)) {
        let label = if names.is_empty() {
            i.to_string()
        } else {
            match usize::try_from(i).ok().and_then(|k| names.get(k)) {
                Some(n) => n.clone(),
                None => continue,
            }
        };
        let (px, py) = chart.backend_coord(&(i as f64, y0));
        let _ = write!(
            out,
            r##"<line x1="{px}" x2="{px}" y1="{py}" y2="{}" stroke="#000"/><text class="xtick" x="{px}" y="{}" font-size="{BAR_TEXT_PX}" text-anchor="middle">{}</text>"##,
            py + 5,
            py + 20,
            crate::esc(&label)
        );
    }
}

/// The legend goes below the chart, one row per series, so it never hides
/// a point; each row shows the series' mark in its colour and dash.
fn legend(chart_svg: &str, series: &[Series], (w, h): (u32, u32)) -> String {
    let row = 20;
    let total = h + 8 + row * series.len() as u32;
    let mut s = format!(
        r#"<svg class="chart" xmlns="http://www.w3.org/2000/svg" width="{w}" height="{total}" viewBox="0 0 {w} {total}" font-family="{FONT}">"#
    );
    s.push_str(chart_svg);
    for (i, se) in series.iter().enumerate() {
        let (c, dash) = style_of(series, i);
        let y = h + 4 + row * i as u32;
        let mark = match se.mark {
            Mark::Line => format!(
                r#"<line x1="96" x2="120" y1="{m}" y2="{m}" stroke="{}" stroke-width="2"{}/>"#,
                hex(c),
                if dash.is_empty() {
                    String::new()
                } else {
                    format!(r#" stroke-dasharray="{dash}""#)
                },
                m = y + 8
            ),
            Mark::Points if dash.is_empty() => format!(
                r#"<circle cx="108" cy="{}" r="4" fill="{}"/>"#,
                y + 8,
                hex(c)
            ),
            Mark::Points => format!(
                r#"<circle cx="108" cy="{}" r="4" fill="none" stroke="{}"/>"#,
                y + 8,
                hex(c)
            ),
            Mark::Band => format!(
                r#"<rect x="96" y="{}" width="24" height="12" fill="{}" fill-opacity="0.22"/>"#,
                y + 2,
                hex(c)
            ),
        };
        let _ = write!(
            s,
            r#"{mark}<text x="128" y="{}" font-size="{BAR_TEXT_PX}">{}</text>"#,
            y + 13,
            crate::esc(se.name)
        );
    }
    s.push_str("</svg>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line<'a>(name: &'a str, pts: &'a [(f64, f64)]) -> Series<'a> {
        Series {
            name,
            points: pts,
            mark: Mark::Line,
        }
    }

    #[test]
    fn whole_ticks_step_by_one_two_five() {
        assert_eq!(integer_ticks(-0.5, 4.5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(integer_ticks(0.0, 9.0, 4), vec![0, 5]);
        assert_eq!(integer_ticks(0.0, 20.0, 6), vec![0, 5, 10, 15, 20]);
        assert_eq!(integer_ticks(0.2, 0.8, 5), Vec::<i64>::new());
    }

    #[test]
    fn named_integer_axes_are_ticked_with_the_names_only_at_whole_positions() {
        let pts = [(0.0, 1.0), (1.0, 2.0), (2.0, 1.5)];
        let names: Vec<String> = ["2026-11-01", "2026-11-02", "2026-11-03"]
            .map(String::from)
            .to_vec();
        let s = xy_chart_with(
            "t",
            ("night", "k (µm)"),
            &[line("k", &pts)],
            (900, 300),
            &XyExtras {
                x_names: &names,
                rings: &[(1.0, 2.0, "#1".into())],
            },
        );
        for n in &names {
            assert!(s.contains(&format!(">{n}</text>")), "{n}: {s}");
        }
        // No fractional tick such as 0.500 on the x axis.
        assert!(!s.contains(">0.500<") && !s.contains(">1.50<"), "{s}");
        assert!(s.contains("class=\"ring\"") && s.contains(">#1</text>"));
    }

    #[test]
    fn a_band_is_a_filled_polygon_and_series_past_the_palette_are_dashed() {
        let band = band_outline(&[(0.0, 1.0, 2.0), (1.0, 1.5, 2.5), (2.0, f64::NAN, 3.0)]);
        assert_eq!(band, vec![(0.0, 1.0), (1.0, 1.5), (1.0, 2.5), (0.0, 2.0)]);
        let s = xy_chart_sized(
            "t",
            "x",
            "y",
            &[
                Series {
                    name: "95 % interval",
                    points: &band,
                    mark: Mark::Band,
                },
                line("value", &[(0.0, 1.5), (1.0, 2.0)]),
            ],
            (600, 300),
        );
        assert!(s.contains("<polygon"), "{s}");
        assert!(s.contains("fill-opacity=\"0.22\""), "legend swatch: {s}");
        let curves: Vec<Vec<(f64, f64)>> = (0..10)
            .map(|i| vec![(0.0, i as f64), (1.0, i as f64 + 0.5)])
            .collect();
        let names: Vec<String> = (0..10).map(|i| format!("c{i}")).collect();
        let series: Vec<Series> = curves.iter().zip(&names).map(|(p, n)| line(n, p)).collect();
        let s = xy_chart_sized("t", "x", "y", &series, (600, 300));
        // Three curves past the seven colours: drawn and listed dashed.
        assert_eq!(s.matches("stroke-dasharray=\"9 4\"").count(), 6, "{s}");
    }
}
