//! Line plots (PNG and SVG) with plotters and an embedded DejaVu Sans font: no system font
//! libraries, identical output on every machine.
//!
//! [`line_plot`] draws any number of named series (lines with optional point markers) on linear
//! axes and writes `<stem>.png` and `<stem>.svg`.

use anyhow::{anyhow, bail, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Once;

/// One named curve.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// draw a marker at every point
    pub markers: bool,
    /// draw the connecting line
    pub line: bool,
}

impl Series {
    /// A line with markers.
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { name: name.into(), points, markers: true, line: true }
    }
    /// Markers only (e.g. reference values).
    pub fn markers_only(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { name: name.into(), points, markers: true, line: false }
    }
}

/// A plot: title, axis labels and series.
#[derive(Clone, Debug)]
pub struct LinePlot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// draw the y = 0 and x = 0 axes when inside the range
    pub zero_axes: bool,
    /// fixed axis ranges (default: the data with a 5 % margin)
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
}

impl LinePlot {
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        LinePlot { title: title.into(), x_label: x_label.into(), y_label: y_label.into(), series: Vec::new(), zero_axes: true, x_range: None, y_range: None }
    }
    pub fn with(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }
}

pub(crate) const FONT: &str = "sans-serif";
const WIDTH: u32 = 900;
const HEIGHT: u32 = 620;

static FONT_INIT: Once = Once::new();

pub(crate) fn register_font() -> Result<()> {
    let mut ok = true;
    FONT_INIT.call_once(|| {
        ok = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok() && plotters::style::register_font(FONT, FontStyle::Bold, dejavu::sans::bold()).is_ok();
    });
    if !ok {
        bail!("plot: the embedded DejaVu Sans font could not be loaded");
    }
    Ok(())
}

/// Distinct colours for up to 10 series (then repeats).
fn colour(i: usize) -> RGBColor {
    const C: [RGBColor; 10] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(255, 127, 14),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];
    C[i % C.len()]
}

/// Axis range with a 5 % margin; a degenerate range is widened to ±1 around its value.
fn range(vals: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    let span = hi - lo;
    if span <= 1e-12 * (1.0 + lo.abs().max(hi.abs())) {
        let pad = if lo.abs() > 0.0 { 0.1 * lo.abs() } else { 1.0 };
        return Some((lo - pad, hi + pad));
    }
    Some((lo - 0.05 * span, hi + 0.05 * span))
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, plot: &LinePlot) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot '{}': {e:?}", plot.title);
    root.fill(&WHITE).map_err(err)?;
    let pts = || plot.series.iter().flat_map(|s| s.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
    let valid = |r: Option<(f64, f64)>| r.filter(|(a, b)| a.is_finite() && b.is_finite() && b > a);
    let (x0, x1) = valid(plot.x_range).or_else(|| range(pts().map(|p| p.0))).unwrap_or((-1.0, 1.0));
    let (y0, y1) = valid(plot.y_range).or_else(|| range(pts().map(|p| p.1))).unwrap_or((-1.0, 1.0));
    let mut chart = ChartBuilder::on(&root).caption(&plot.title, (FONT, 22).into_font()).margin(16).x_label_area_size(50).y_label_area_size(80).build_cartesian_2d(x0..x1, y0..y1).map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(plot.x_label.as_str())
        .y_desc(plot.y_label.as_str())
        .label_style((FONT, 15).into_font())
        .axis_desc_style((FONT, 17).into_font())
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(err)?;
    if plot.zero_axes {
        let grey = RGBColor(90, 90, 90);
        if y0 < 0.0 && y1 > 0.0 {
            chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], grey.stroke_width(1))).map_err(err)?;
        }
        if x0 < 0.0 && x1 > 0.0 {
            chart.draw_series(LineSeries::new([(0.0, y0), (0.0, y1)], grey.stroke_width(1))).map_err(err)?;
        }
    }
    for (i, s) in plot.series.iter().enumerate() {
        let c = colour(i);
        let p: Vec<(f64, f64)> = s.points.iter().copied().filter(|p| p.0.is_finite() && p.1.is_finite()).collect();
        let mut legend_done = false;
        if s.line && !p.is_empty() {
            chart.draw_series(LineSeries::new(p.clone(), c.stroke_width(2))).map_err(err)?.label(s.name.as_str()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
            legend_done = true;
        }
        if s.markers && !p.is_empty() {
            if s.line {
                chart.draw_series(p.iter().map(|&xy| Circle::new(xy, 3, c.filled()))).map_err(err)?;
            } else {
                let anno = chart.draw_series(p.iter().map(|&xy| TriangleMarker::new(xy, 7, c.filled()))).map_err(err)?;
                if !legend_done {
                    anno.label(s.name.as_str()).legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, c.filled()));
                }
            }
        }
    }
    if plot.series.iter().any(|s| !s.name.is_empty()) {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .label_font((FONT, 15).into_font())
            .position(legend_corner(plot, (x0, x1), (y0, y1)))
            .draw()
            .map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// The corner whose 35 % × 35 % box holds the fewest data points (ties: upper left first).
fn legend_corner(plot: &LinePlot, (x0, x1): (f64, f64), (y0, y1): (f64, f64)) -> SeriesLabelPosition {
    let corners =
        [(SeriesLabelPosition::UpperLeft, false, true), (SeriesLabelPosition::UpperRight, true, true), (SeriesLabelPosition::LowerRight, true, false), (SeriesLabelPosition::LowerLeft, false, false)];
    let pts: Vec<(f64, f64)> = plot.series.iter().flat_map(|s| s.points.iter().copied()).collect();
    let count = |right: bool, upper: bool| {
        pts.iter()
            .filter(|(x, y)| {
                let fx = (x - x0) / (x1 - x0);
                let fy = (y - y0) / (y1 - y0);
                (if right { fx > 0.65 } else { fx < 0.35 }) && (if upper { fy > 0.65 } else { fy < 0.35 })
            })
            .count()
    };
    let mut best = (usize::MAX, SeriesLabelPosition::UpperLeft);
    for (pos, right, upper) in corners {
        let c = count(right, upper);
        if c < best.0 {
            best = (c, pos);
        }
    }
    best.1
}

/// Write `<stem>.png` and `<stem>.svg`; returns the two paths.
pub fn line_plot(stem: &Path, plot: &LinePlot) -> Result<[PathBuf; 2]> {
    register_font()?;
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw(BitMapBackend::new(&png, (WIDTH, HEIGHT)).into_drawing_area(), plot)?;
    draw(SVGBackend::new(&svg, (WIDTH, HEIGHT)).into_drawing_area(), plot)?;
    Ok([png, svg])
}

/// A scalar field on a rectangular grid (cell-centred values; None = infeasible or failed,
/// drawn grey) with paths drawn over it (e.g. an optimiser's designs).
#[derive(Clone, Debug)]
pub struct MapPlot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub value_label: String,
    /// cell centres along x and y (ascending)
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// values[iy][ix]
    pub values: Vec<Vec<Option<f64>>>,
    /// named polylines (each drawn with markers, the last point larger)
    pub paths: Vec<Series>,
    pub note: String,
}

/// Cell edges from centres (midpoints; the outer cells mirror their neighbour; a single centre
/// gets ± `default_half`).
pub(crate) fn cell_edges(c: &[f64], default_half: f64) -> Vec<(f64, f64)> {
    let n = c.len();
    (0..n)
        .map(|i| {
            let lo = if i > 0 {
                0.5 * (c[i - 1] + c[i])
            } else if n > 1 {
                c[0] - 0.5 * (c[1] - c[0])
            } else {
                c[0] - default_half
            };
            let hi = if i + 1 < n {
                0.5 * (c[i] + c[i + 1])
            } else if n > 1 {
                c[n - 1] + 0.5 * (c[n - 1] - c[n - 2])
            } else {
                c[0] + default_half
            };
            (lo, hi)
        })
        .collect()
}

/// The colour scale of a map: the finite values' range, [0, 1] when there are none, widened by
/// ±0.5 when it is a single value.
pub(crate) fn colour_range(vals: &[f64]) -> (f64, f64) {
    let (vmin, vmax) = vals.iter().filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    if !vmin.is_finite() {
        (0.0, 1.0)
    } else if vmax - vmin <= 1e-12 * (1.0 + vmax.abs()) {
        (vmin - 0.5, vmax + 0.5)
    } else {
        (vmin, vmax)
    }
}

/// A vertical viridis colour bar over [vmin, vmax] with about three significant digits in its
/// labels, drawn into `area`.
pub(crate) fn colour_bar<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, vmin: f64, vmax: f64, caption: Option<&str>, margins: (u32, u32)) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("colour bar: {e:?}");
    let digits = (2.0 - (vmax - vmin).log10().floor()).clamp(0.0, 6.0) as usize;
    let mut b = ChartBuilder::on(area);
    b.margin_top(margins.0).margin_bottom(margins.1).margin_right(10).y_label_area_size(60);
    if let Some(c) = caption {
        b.caption(c, (FONT, 12).into_font());
    }
    let mut cb = b.build_cartesian_2d(0.0..1.0, vmin..vmax).map_err(err)?;
    cb.configure_mesh().disable_mesh().disable_x_axis().label_style((FONT, 12).into_font()).y_label_formatter(&|y| format!("{:.*}", digits, y)).draw().map_err(err)?;
    let n = 100;
    cb.draw_series((0..n).map(|k| {
        let a = vmin + (vmax - vmin) * k as f64 / n as f64;
        let b = vmin + (vmax - vmin) * (k + 1) as f64 / n as f64;
        Rectangle::new([(0.0, a), (1.0, b)], ViridisRGB.get_color_normalized((0.5 * (a + b)) as f32, vmin as f32, vmax as f32).filled())
    }))
    .map_err(err)?;
    Ok(())
}

fn draw_map<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, m: &MapPlot) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("map plot: {e:?}");
    root.fill(&WHITE).map_err(err)?;
    let vals: Vec<f64> = m.values.iter().flatten().flatten().copied().filter(|v| v.is_finite()).collect();
    let (vmin, vmax) = colour_range(&vals);
    let (w, h) = root.dim_in_pixel();
    root.draw_text(&m.note, &TextStyle::from((FONT, 13).into_font()).color(&RGBColor(80, 80, 80)), (10, h as i32 - 18)).map_err(err)?;
    let (root, _) = root.split_vertically(h - 22);
    let (main, bar) = root.split_horizontally(w.saturating_sub(110));
    let xe = cell_edges(&m.xs, 0.5);
    let ye = cell_edges(&m.ys, 0.5);
    if xe.is_empty() || ye.is_empty() {
        bail!("map plot: empty grid");
    }
    let mut chart = ChartBuilder::on(&main)
        .caption(&m.title, (FONT, 20).into_font())
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(xe[0].0..xe[xe.len() - 1].1, ye[0].0..ye[ye.len() - 1].1)
        .map_err(err)?;
    chart.configure_mesh().disable_mesh().x_desc(m.x_label.as_str()).y_desc(m.y_label.as_str()).label_style((FONT, 14).into_font()).axis_desc_style((FONT, 16).into_font()).draw().map_err(err)?;
    let mut cells = Vec::new();
    for (iy, row) in m.values.iter().enumerate() {
        for (ix, v) in row.iter().enumerate() {
            let c = match v {
                Some(v) if v.is_finite() => ViridisRGB.get_color_normalized(*v as f32, vmin as f32, vmax as f32),
                _ => RGBColor(200, 200, 200),
            };
            cells.push(Rectangle::new([(xe[ix].0, ye[iy].0), (xe[ix].1, ye[iy].1)], c.filled()));
        }
    }
    chart.draw_series(cells).map_err(err)?;
    for (i, s) in m.paths.iter().enumerate() {
        let c = colour(i + 1);
        chart
            .draw_series(LineSeries::new(s.points.iter().copied(), c.stroke_width(2)))
            .map_err(err)?
            .label(s.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        chart.draw_series(s.points.iter().map(|p| Circle::new(*p, 3, c.filled()))).map_err(err)?;
        if let Some(last) = s.points.last() {
            chart.draw_series(std::iter::once(Circle::new(*last, 7, WHITE.stroke_width(2)))).map_err(err)?;
        }
    }
    if !m.paths.is_empty() {
        chart.configure_series_labels().background_style(WHITE.mix(0.85)).border_style(BLACK).position(SeriesLabelPosition::UpperLeft).label_font((FONT, 13).into_font()).draw().map_err(err)?;
    }
    colour_bar(&bar, vmin, vmax, Some(m.value_label.as_str()), (45, 60))?;
    root.present().map_err(err)?;
    Ok(())
}

/// Write a map with paths as `<stem>.png` and `<stem>.svg`.
pub fn map_plot(stem: &Path, plot: &MapPlot) -> Result<[PathBuf; 2]> {
    register_font()?;
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_map(BitMapBackend::new(&png, (WIDTH + 110, HEIGHT + 40)).into_drawing_area(), plot)?;
    draw_map(SVGBackend::new(&svg, (WIDTH + 110, HEIGHT + 40)).into_drawing_area(), plot)?;
    Ok([png, svg])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg() {
        let dir = std::env::temp_dir().join(format!("twistopt-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let map = MapPlot {
            title: "test map".into(),
            x_label: "α (°)".into(),
            y_label: "l (mm)".into(),
            value_label: "Ω".into(),
            xs: vec![60.0, 160.0, 260.0, 360.0],
            ys: vec![10.0, 15.0, 20.0],
            values: vec![vec![Some(1.0), Some(2.0), None, Some(4.0)]; 3],
            paths: vec![Series::new("run", vec![(100.0, 12.0), (300.0, 18.0)])],
            note: "grey: infeasible".into(),
        };
        let [png, svg] = map_plot(&dir.join("map"), &map).unwrap();
        assert!(std::fs::metadata(&png).unwrap().len() > 1000 && std::fs::metadata(&svg).unwrap().len() > 1000);
        let plot = LinePlot::new("test θ(p)", "p (kPa)", "θ (°)")
            .with(Series::new("a", vec![(-10.0, -1.0), (0.0, 0.0), (10.0, 2.0)]))
            .with(Series::markers_only("ref", vec![(5.0, 1.0)]))
            .with(Series::new("flat", vec![(1.0, 3.0), (2.0, 3.0)]));
        let [png, svg] = line_plot(&dir.join("t"), &plot).unwrap();
        let png_bytes = std::fs::read(&png).unwrap();
        assert_eq!(&png_bytes[..8], b"\x89PNG\r\n\x1a\n");
        let s = std::fs::read_to_string(&svg).unwrap();
        assert!(s.starts_with("<svg") && s.contains("θ (°)"), "svg text");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
