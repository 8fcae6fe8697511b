//! Inline SVG charts (plotters' SVG backend): no network, no JavaScript.

use plotters::prelude::*;

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

/// How a series is drawn.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    Line,
    Points,
}

pub struct Series<'a> {
    pub name: &'a str,
    pub points: &'a [(f64, f64)],
    pub mark: Mark,
}

/// An x–y chart of one or more series.
pub fn xy_chart(title: &str, x_label: &str, y_label: &str, series: &[Series]) -> String {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (640, 360)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (x0, x1) = bounds(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
        let (y0, y1) = bounds(series.iter().flat_map(|s| s.points.iter().map(|p| p.1)));
        let chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, y0..y1);
        if let Ok(mut chart) = chart {
            let _ = chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .light_line_style(WHITE.mix(0.0))
                .draw();
            for (i, s) in series.iter().enumerate() {
                let c = COLORS[i % COLORS.len()];
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|p| p.0.is_finite() && p.1.is_finite())
                    .collect();
                let drawn = match s.mark {
                    Mark::Line => chart.draw_series(LineSeries::new(pts, c.stroke_width(2))),
                    Mark::Points => {
                        chart.draw_series(pts.into_iter().map(|p| Circle::new(p, 3, c.filled())))
                    }
                };
                if let Ok(d) = drawn {
                    d.label(s.name.to_string()).legend(move |(x, y)| {
                        Rectangle::new([(x, y - 4), (x + 12, y + 4)], c.filled())
                    });
                }
            }
            if series.len() > 1 {
                let _ = chart
                    .configure_series_labels()
                    .border_style(BLACK)
                    .background_style(WHITE.mix(0.8))
                    .draw();
            }
        }
        let _ = root.present();
    }
    out
}

/// Horizontal bars (label, value), e.g. effect ranking.
pub fn bar_chart(title: &str, value_label: &str, bars: &[(String, f64)]) -> String {
    let mut out = String::new();
    {
        let h = (60 + 22 * bars.len().max(1)) as u32;
        let root = SVGBackend::with_string(&mut out, (640, h)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (_, hi) = bounds(bars.iter().map(|b| b.1).chain([0.0]));
        let n = bars.len().max(1);
        let chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(180)
            .build_cartesian_2d(0.0..hi.max(1e-12), 0..n);
        if let Ok(mut chart) = chart {
            let labels: Vec<String> = bars.iter().map(|b| b.0.clone()).collect();
            let _ = chart
                .configure_mesh()
                .x_desc(value_label)
                .y_labels(n)
                .y_label_formatter(&|i| {
                    (n - 1)
                        .checked_sub(*i)
                        .and_then(|k| labels.get(k).cloned())
                        .unwrap_or_default()
                })
                .disable_y_mesh()
                .draw();
            let _ = chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
                let y = n - 1 - i;
                Rectangle::new(
                    [(0.0, y), (b.1.max(0.0), y + 1)],
                    COLORS[0].mix(0.8).filled(),
                )
            }));
        }
        let _ = root.present();
    }
    out
}

/// A heat map of values on a grid (x, y, value), diverging colours around 0.
pub fn heatmap(title: &str, cells: &[(f64, f64, f64)], value_label: &str) -> String {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (640, 420)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let mut xs: Vec<f64> = cells.iter().map(|c| c.0).collect();
        let mut ys: Vec<f64> = cells.iter().map(|c| c.1).collect();
        xs.sort_by(f64::total_cmp);
        xs.dedup();
        ys.sort_by(f64::total_cmp);
        ys.dedup();
        let step = |v: &[f64]| {
            v.windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min)
                .min(1e300)
        };
        let dx = if xs.len() > 1 { step(&xs) } else { 1.0 };
        let dy = if ys.len() > 1 { step(&ys) } else { 1.0 };
        let (x0, x1) = bounds(xs.iter().copied());
        let (y0, y1) = bounds(ys.iter().copied());
        let vmax = cells
            .iter()
            .map(|c| c.2.abs())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max)
            .max(1e-12);
        let chart = ChartBuilder::on(&root)
            .caption(
                format!("{title} (±{vmax:.4} {value_label})"),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, y0..y1);
        if let Ok(mut chart) = chart {
            let _ = chart.configure_mesh().x_desc("x_mm").y_desc("y_mm").draw();
            let _ = chart.draw_series(cells.iter().filter(|c| c.2.is_finite()).map(|c| {
                let t = (c.2 / vmax).clamp(-1.0, 1.0);
                // Blue for negative, red for positive, white at zero.
                let (r, g, b) = if t >= 0.0 {
                    (255.0, 255.0 * (1.0 - t), 255.0 * (1.0 - t))
                } else {
                    (255.0 * (1.0 + t), 255.0 * (1.0 + t), 255.0)
                };
                Rectangle::new(
                    [
                        (c.0 - dx / 2.0, c.1 - dy / 2.0),
                        (c.0 + dx / 2.0, c.1 + dy / 2.0),
                    ],
                    RGBColor(r as u8, g as u8, b as u8).filled(),
                )
            }));
        }
        let _ = root.present();
    }
    out
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
        assert!(s.starts_with("<svg") && s.contains("</svg>"));
        let b = bar_chart("b", "mm", &[("drift:t_s".into(), 0.5)]);
        assert!(b.contains("drift:t_s"));
        let h = heatmap("h", &[(0.0, 0.0, 1.0), (1.0, 0.0, -1.0)], "mm");
        assert!(h.contains("<rect"));
    }
}
