//! Maps like the letter's Fig. 5: max |θ|, max |τ| and Ω over (α, l) at r = 5√3, 13.2 and
//! 20 mm (the grid's r values nearest to these), one figure per quantity with one panel per r,
//! a viridis colour scale and bar per panel; infeasible designs (max radius above the ballooning
//! limit at the Ω pressure) light grey, failed ones (no Ω, invalid geometry, model error) dark
//! grey, designs not (yet) computed white. PNG and SVG.

use anyhow::{anyhow, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{Grid, Row};
use crate::geometry::{P_ALPHA, P_L, P_R};
use crate::plot::{cell_edges, colour_bar, colour_range, register_font, FONT};

/// The letter's representative r values (Fig. 5).
pub const FIG5_R: [f64; 3] = [8.660254037844386, 13.2, 20.0];

const INFEASIBLE: RGBColor = RGBColor(200, 200, 200);
const FAILED: RGBColor = RGBColor(110, 110, 110);

/// One quantity to map.
struct Quantity {
    stem: &'static str,
    label: &'static str,
    value: fn(&Row) -> Option<f64>,
}

const QUANTITIES: [Quantity; 3] = [
    Quantity { stem: "map_theta", label: "max free twist |θ| (°)", value: |r| r.primary.theta_max_deg.map(f64::abs) },
    Quantity { stem: "map_tau", label: "max blocking torque |τ| (N·m)", value: |r| r.primary.tau_max_nm.map(f64::abs) },
    Quantity { stem: "map_omega", label: "energy density Ω (J/m³)", value: |r| r.primary.omega_j_m3 },
];

/// The grid's r values nearest to 5√3, 13.2 and 20 (distinct, within half the r range).
pub fn panel_r_values(grid: &Grid) -> Vec<f64> {
    let Some(ax) = grid.axes.iter().find(|a| a.name == P_R) else {
        return vec![];
    };
    let mut out: Vec<f64> = Vec::new();
    for target in FIG5_R {
        if let Some(&v) = ax.values.iter().min_by(|a, b| (*a - target).abs().total_cmp(&(*b - target).abs())) {
            if !out.contains(&v) {
                out.push(v);
            }
        }
    }
    out.sort_by(f64::total_cmp);
    out
}

/// Draw the three maps into `out`; returns the files written (none when the grid has no
/// r / l / α axes or no rows).
pub fn draw_maps(out: &Path, grid: &Grid, rows: &[Row]) -> Result<Vec<PathBuf>> {
    let axis = |n: &str| {
        grid.axes.iter().find(|a| a.name == n).map(|a| {
            let mut v = a.values.clone();
            v.sort_by(f64::total_cmp);
            v
        })
    };
    let (Some(alphas), Some(ls)) = (axis(P_ALPHA), axis(P_L)) else {
        return Ok(vec![]);
    };
    let rs = panel_r_values(grid);
    if rows.is_empty() || rs.is_empty() {
        return Ok(vec![]);
    }
    register_font()?;
    // rows by (r, l, α) bit patterns
    let key = |r: f64, l: f64, a: f64| (r.to_bits(), l.to_bits(), a.to_bits());
    let by: BTreeMap<(u64, u64, u64), &Row> = rows.iter().filter_map(|row| Some((key(*row.design.get(P_R)?, *row.design.get(P_L)?, *row.design.get(P_ALPHA)?), row))).collect();
    let panel = Panels { rs, ls, alphas, by: &by };
    let mut files = Vec::new();
    for q in &QUANTITIES {
        let png = out.join(format!("{}.png", q.stem));
        let svg = out.join(format!("{}.svg", q.stem));
        let (w, h) = ((40 + (430 + BAR_WIDTH) * panel.rs.len() as u32).max(760), 500);
        draw_one(BitMapBackend::new(&png, (w, h)).into_drawing_area(), &panel, q)?;
        draw_one(SVGBackend::new(&svg, (w, h)).into_drawing_area(), &panel, q)?;
        files.push(png);
        files.push(svg);
    }
    Ok(files)
}

struct Panels<'a> {
    rs: Vec<f64>,
    ls: Vec<f64>,
    alphas: Vec<f64>,
    by: &'a BTreeMap<(u64, u64, u64), &'a Row>,
}

impl Panels<'_> {
    fn row(&self, r: f64, l: f64, a: f64) -> Option<&Row> {
        self.by.get(&(r.to_bits(), l.to_bits(), a.to_bits())).copied()
    }
}

fn draw_one<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, p: &Panels, q: &Quantity) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("map {}: {e:?}", q.stem);
    root.fill(&WHITE).map_err(err)?;
    let (_, h) = root.dim_in_pixel();
    root.draw_text(
        "light grey: infeasible (max radius above the ballooning limit); dark grey: failed (no Ω); white: not computed",
        &TextStyle::from((FONT, 13).into_font()).color(&RGBColor(80, 80, 80)),
        (10, h as i32 - 18),
    )
    .map_err(err)?;
    let (root, _) = root.split_vertically(h - 22);
    let root = root.titled(&format!("{} over (α, l), colour scale per panel", q.label), (FONT, 18)).map_err(err)?;
    let panels = root.split_evenly((1, p.rs.len()));
    let a_edges = cell_edges(&p.alphas, 1.0);
    let l_edges = cell_edges(&p.ls, 0.5);
    let (x0, x1) = (a_edges[0].0, a_edges[a_edges.len() - 1].1);
    let (y0, y1) = (l_edges[0].0, l_edges[l_edges.len() - 1].1);
    for (area, &r) in panels.iter().zip(&p.rs) {
        let (vmin, vmax) = panel_range(p, q, r);
        let (pw, _) = area.dim_in_pixel();
        let (area, bar) = area.split_horizontally(pw.saturating_sub(BAR_WIDTH));
        let mut chart = ChartBuilder::on(&area).caption(format!("r = {r:.2} mm"), (FONT, 17)).margin(10).x_label_area_size(45).y_label_area_size(55).build_cartesian_2d(x0..x1, y0..y1).map_err(err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("pre-twist α (°)")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.0}"))
            .y_desc("waist radius l (mm)")
            .label_style((FONT, 13))
            .axis_desc_style((FONT, 14))
            .draw()
            .map_err(err)?;
        let mut cells = Vec::new();
        for (li, &l) in p.ls.iter().enumerate() {
            for (ai, &a) in p.alphas.iter().enumerate() {
                let Some(row) = p.row(r, l, a) else { continue };
                let colour = match (q.value)(row).filter(|v| v.is_finite()) {
                    Some(v) if row.primary.feasible => ViridisRGB.get_color_normalized(v as f32, vmin as f32, vmax as f32),
                    _ if row.status == "ok" => not_feasible_colour(row),
                    _ => FAILED,
                };
                cells.push(Rectangle::new([(a_edges[ai].0, l_edges[li].0), (a_edges[ai].1, l_edges[li].1)], colour.filled()));
            }
        }
        chart.draw_series(cells).map_err(err)?;
        colour_bar(&bar, vmin, vmax, None, (37, 55))?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Width of each panel's colour bar (pixels).
const BAR_WIDTH: u32 = 125;

/// The colour scale of one panel: its feasible values' range. Per panel, because Ω spans four
/// orders of magnitude between r = 5√3 and r = 20 mm on the Table-I grid: a shared scale
/// paints the thick-walled panels one colour.
fn panel_range(p: &Panels, q: &Quantity, r: f64) -> (f64, f64) {
    let mut vals = Vec::new();
    for &l in &p.ls {
        for &a in &p.alphas {
            if let Some(row) = p.row(r, l, a).filter(|row| row.primary.feasible) {
                if let Some(v) = (q.value)(row).filter(|v| v.is_finite()) {
                    vals.push(v);
                }
            }
        }
    }
    colour_range(&vals)
}

/// Colour of a design that ran but is not feasible: light grey when it ballooned past the
/// limit, dark grey when Ω is missing.
fn not_feasible_colour(row: &Row) -> RGBColor {
    if row.primary.omega_j_m3.is_some() {
        INFEASIBLE
    } else {
        FAILED
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_edges_are_midpoints() {
        let e = cell_edges(&[10.0, 12.0, 16.0], 0.5);
        assert_eq!(e, vec![(9.0, 11.0), (11.0, 14.0), (14.0, 18.0)]);
        assert_eq!(cell_edges(&[5.0], 0.5), vec![(4.5, 5.5)]);
    }

    #[test]
    fn fig5_panels_of_table1() {
        let r = panel_r_values(&Grid::table1());
        assert_eq!(r.len(), 3);
        assert!((r[0] - 8.660254037844386).abs() < 1e-12);
        assert!((r[1] - (8.660254037844386 + 4.5)).abs() < 1e-12, "{r:?}");
        assert_eq!(r[2], 20.0);
    }
}
