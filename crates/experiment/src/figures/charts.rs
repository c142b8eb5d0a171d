//! The two chart kinds the report needs: panels of lines and points ([`Lines`]: PSNR against
//! wall time, time against channel count, PSNR against noise level) and grouped bars
//! ([`Bars`]: ablation variants).

use super::plot::{Draw, colour, font, msg};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// One series of a panel.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// Index into the palette (the same method keeps its colour across figures).
    pub colour: usize,
    /// Joined by a line (else only markers).
    pub line: bool,
    pub dashed: bool,
    pub markers: bool,
}

impl Series {
    pub fn line(label: impl Into<String>, colour: usize, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
            colour,
            line: true,
            dashed: false,
            markers: false,
        }
    }

    pub fn points(label: impl Into<String>, colour: usize, points: Vec<(f64, f64)>) -> Self {
        Series {
            markers: true,
            line: false,
            ..Series::line(label, colour, points)
        }
    }
}

/// One panel: axes, a title and its series.
#[derive(Clone, Debug, Default)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
    /// Category names for integer x positions (tick labels), when x is categorical.
    pub x_ticks: Option<Vec<(f64, String)>>,
}

impl Panel {
    /// Mean PSNR (dB) against training time (s, log axis): the runs' learning curves.
    pub fn psnr_time(title: impl Into<String>, series: Vec<Series>) -> Self {
        Panel {
            title: title.into(),
            x_label: "training time (s, log)".into(),
            y_label: "mean PSNR (dB)".into(),
            log_x: true,
            log_y: false,
            series,
            x_ticks: None,
        }
    }
}

/// A grid of panels.
#[derive(Clone, Debug)]
pub struct Lines {
    pub title: String,
    pub panels: Vec<Panel>,
    pub cols: usize,
    /// Panel size in pixels.
    pub panel: (u32, u32),
}

const TITLE_H: u32 = 36;
const LEGEND_ROW_H: u32 = 22;

fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { (0.1, 10.0) } else { (0.0, 1.0) };
    }
    if log {
        (lo / 1.5, hi * 1.5)
    } else {
        let pad = ((hi - lo) * 0.08).max(1e-6 * hi.abs().max(1.0));
        (lo - pad, hi + pad)
    }
}

impl Lines {
    /// The distinct series of all panels (label and style), in first-seen order: one legend
    /// for the figure.
    fn legend(&self) -> Vec<&Series> {
        let mut out: Vec<&Series> = Vec::new();
        for s in self.panels.iter().flat_map(|p| &p.series) {
            if !out.iter().any(|o| o.label == s.label) {
                out.push(s);
            }
        }
        out
    }

    /// Legend entries laid out in rows: `(row, x)` of each.
    fn legend_layout(&self) -> Vec<(u32, u32)> {
        let width = self.size_without_legend().0;
        let (mut row, mut x) = (0, 10);
        self.legend()
            .iter()
            .map(|s| {
                let w = 34 + 7 * s.label.chars().count() as u32 + 18;
                if x + w > width && x > 10 {
                    row += 1;
                    x = 10;
                }
                let at = (row, x);
                x += w;
                at
            })
            .collect()
    }

    fn size_without_legend(&self) -> (u32, u32) {
        let rows = self.panels.len().div_ceil(self.cols.max(1)) as u32;
        (
            self.panel.0 * self.cols.max(1) as u32,
            self.panel.1 * rows.max(1) + TITLE_H,
        )
    }

    fn legend_height(&self) -> u32 {
        self.legend_layout()
            .last()
            .map_or(0, |(r, _)| (r + 1) * LEGEND_ROW_H + 4)
    }
}

impl Draw for Lines {
    fn size(&self) -> (u32, u32) {
        let (w, h) = self.size_without_legend();
        (w, h + self.legend_height())
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let (title, rest) = root.split_vertically(TITLE_H);
        title
            .draw_text(&self.title, &font(20), (10, 8))
            .map_err(msg)?;
        let (legend, body) = rest.split_vertically(self.legend_height());
        for (s, (row, x)) in self.legend().into_iter().zip(self.legend_layout()) {
            let c = colour(s.colour);
            let (x, y) = (x as i32, (row * LEGEND_ROW_H) as i32 + 11);
            if s.line {
                let style = c.stroke_width(2);
                if s.dashed {
                    for k in 0..3 {
                        legend
                            .draw(&PathElement::new(
                                vec![(x + k * 10, y), (x + k * 10 + 6, y)],
                                style,
                            ))
                            .map_err(msg)?;
                    }
                } else {
                    legend
                        .draw(&PathElement::new(vec![(x, y), (x + 26, y)], style))
                        .map_err(msg)?;
                }
            }
            if s.markers {
                legend
                    .draw(&Circle::new((x + 13, y), 4, c.filled()))
                    .map_err(msg)?;
            }
            legend
                .draw_text(&s.label, &font(13), (x + 34, y - 8))
                .map_err(msg)?;
        }
        let rows = self.panels.len().div_ceil(self.cols.max(1));
        let areas = body.split_evenly((rows.max(1), self.cols.max(1)));
        for (p, area) in self.panels.iter().zip(areas.iter()) {
            draw_panel(p, area)?;
        }
        Ok(())
    }
}

fn draw_panel<DB: DrawingBackend>(p: &Panel, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
    let xs = p.series.iter().flat_map(|s| s.points.iter().map(|q| q.0));
    let ys = p.series.iter().flat_map(|s| s.points.iter().map(|q| q.1));
    let (x0, x1) = range(xs, p.log_x);
    let (y0, y1) = range(ys, p.log_y);
    let mut b = ChartBuilder::on(area);
    b.caption(&p.title, font(16))
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(56);
    let ticks = p.x_ticks.clone();
    let x_fmt = move |v: &f64| match &ticks {
        Some(t) => t
            .iter()
            .find(|(x, _)| (x - v).abs() < 1e-6)
            .map(|(_, l)| l.clone())
            .unwrap_or_default(),
        None => format_tick(*v),
    };
    let n_ticks = p.x_ticks.as_ref().map_or(8, |t| t.len().max(2));
    // A logarithmic axis labels 1, 2 and 5 of each decade (its mesh lines are denser).
    let y_fmt = |v: &f64| {
        let mantissa = *v / 10f64.powf(v.log10().floor());
        let shown = [1.0, 2.0, 5.0, 10.0]
            .iter()
            .any(|m| (mantissa - m).abs() < 1e-6);
        match (shown, *v) {
            (false, _) => String::new(),
            (true, v) if (0.01..1e4).contains(&v) => format_tick(v),
            (true, v) => format!("{:.0}e{}", mantissa, v.log10().floor()),
        }
    };
    // One arm per scale pair: plotters types linear and logarithmic axes apart. Ticks as
    // before on linear axes; a logarithmic y axis gets short labels.
    macro_rules! finish {
        ($xr:expr, $yr:expr, $log_x:expr, $log_y:expr) => {{
            let mut chart = b.build_cartesian_2d($xr, $yr).map_err(msg)?;
            let mut mesh = chart.configure_mesh();
            mesh.x_desc(&p.x_label)
                .y_desc(&p.y_label)
                .label_style(font(12))
                .axis_desc_style(font(13))
                .light_line_style(RGBColor(238, 238, 238))
                .x_label_formatter(&x_fmt);
            if !$log_x {
                mesh.x_labels(n_ticks);
            }
            if $log_y {
                mesh.y_label_formatter(&y_fmt);
            }
            mesh.draw().map_err(msg)?;
            draw_series(&mut chart, p)
        }};
    }
    match (p.log_x, p.log_y) {
        (true, true) => finish!((x0..x1).log_scale(), (y0..y1).log_scale(), true, true),
        (true, false) => finish!((x0..x1).log_scale(), y0..y1, true, false),
        (false, true) => finish!(x0..x1, (y0..y1).log_scale(), false, true),
        (false, false) => finish!(x0..x1, y0..y1, false, false),
    }
}

fn format_tick(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 100.0 || (v.fract() == 0.0 && v.abs() >= 1.0) {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn draw_series<'a, DB, X, Y>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
    p: &Panel,
) -> Result<(), String>
where
    DB: DrawingBackend + 'a,
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    for s in &p.series {
        let c = colour(s.colour);
        let pts = s.points.clone();
        if s.line && s.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts.clone(), 6, 4, c.stroke_width(2)))
                .map_err(msg)?;
        } else if s.line {
            chart
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                .map_err(msg)?;
        }
        if s.markers {
            chart
                .draw_series(pts.iter().map(|&q| Circle::new(q, 4, c.filled())))
                .map_err(msg)?;
        }
    }
    Ok(())
}

/// Grouped bars: one group per category, one bar per series in each.
#[derive(Clone, Debug)]
pub struct Bars {
    pub title: String,
    pub y_label: String,
    pub categories: Vec<String>,
    /// `(label, colour, value per category)`; None leaves a gap.
    pub series: Vec<(String, usize, Vec<Option<f64>>)>,
    pub size: (u32, u32),
}

impl Draw for Bars {
    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let values = self
            .series
            .iter()
            .flat_map(|s| s.2.iter().flatten().copied());
        let (lo, hi) = range(values, false);
        let hi = hi + (hi - lo) * 0.08; // room for the value labels
        let n = self.categories.len().max(1) as f64;
        let k = self.series.len().max(1) as f64;
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, font(18))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5..n - 0.5, lo..hi)
            .map_err(msg)?;
        let cats = self.categories.clone();
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(self.categories.len().max(2) * 2 + 1)
            .x_label_formatter(&|v| {
                let i = v.round();
                if (v - i).abs() < 1e-6 && i >= 0.0 {
                    cats.get(i as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_desc(format!("{} (axis not from 0)", self.y_label))
            .label_style(font(12))
            .axis_desc_style(font(13))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(msg)?;
        let width = 0.8 / k;
        for (j, (label, c, vals)) in self.series.iter().enumerate() {
            let c = colour(*c);
            let x0 = -0.4 + j as f64 * width;
            chart
                .draw_series(vals.iter().enumerate().filter_map(|(i, v)| {
                    v.map(|v| {
                        let x = i as f64 + x0;
                        Rectangle::new([(x, lo), (x + width * 0.92, v)], c.filled())
                    })
                }))
                .map_err(msg)?
                .label(label)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
            // The value above each bar.
            chart
                .draw_series(vals.iter().enumerate().filter_map(|(i, v)| {
                    v.map(|v| {
                        let x = i as f64 + x0;
                        Text::new(
                            format!("{v:.2}"),
                            (x, v),
                            font(11).pos(Pos::new(HPos::Left, VPos::Bottom)),
                        )
                    })
                }))
                .map_err(msg)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(font(12))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(msg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::figures::plot::save;

    #[test]
    fn charts_render_with_log_axes_categories_and_gaps() {
        let dir = tempfile::tempdir().unwrap();
        let lines = Lines {
            title: "PSNR against wall time".into(),
            cols: 2,
            panel: (320, 240),
            panels: vec![
                Panel {
                    title: "a".into(),
                    x_label: "wall time (s)".into(),
                    y_label: "PSNR (dB)".into(),
                    log_x: true,
                    log_y: false,
                    series: vec![
                        Series::line("R²-Gaussian", 3, vec![(10.0, 30.0), (100.0, 35.0)]),
                        Series::points("SART", 1, vec![(0.5, 31.0)]),
                    ],
                    x_ticks: None,
                },
                Panel {
                    title: "b".into(),
                    x_ticks: Some(vec![(0.0, "clean".into()), (1.0, "1e4".into())]),
                    series: vec![Series {
                        dashed: true,
                        markers: true,
                        ..Series::line("4D-SG", 4, vec![(0.0, 1.0), (1.0, 2.0)])
                    }],
                    ..Panel::default()
                },
                Panel::default(),
                Panel {
                    title: "log-log".into(),
                    x_label: "Gaussians".into(),
                    log_x: true,
                    log_y: true,
                    series: vec![Series::points("NAF", 2, vec![(1e4, 0.02), (1e5, 0.3)])],
                    ..Panel::default()
                },
            ],
        };
        let [png, svg] = save(&dir.path().join("lines"), &lines).unwrap();
        assert!(std::fs::metadata(png).unwrap().len() > 1000);
        let svg = std::fs::read_to_string(svg).unwrap();
        for needle in [
            "R²-Gaussian",
            "SART",
            "wall time (s)",
            "clean",
            "4D-SG",
            "NAF",
            "log-log",
        ] {
            assert!(svg.contains(needle), "{needle}");
        }
        let bars = Bars {
            title: "freeze".into(),
            y_label: "PSNR (dB)".into(),
            categories: vec!["FFFL".into(), "LLLL".into()],
            series: vec![("13 views".into(), 0, vec![Some(30.0), None])],
            size: (400, 300),
        };
        let [_, svg] = save(&dir.path().join("bars"), &bars).unwrap();
        assert!(std::fs::read_to_string(svg).unwrap().contains("FFFL"));
    }
}
