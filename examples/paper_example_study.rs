//! Summary of studies/paper-example: θ(p) and τ(p) at every fidelity beside the letter's Fig. 4a
//! values, and a mesh-convergence table.
//!
//! cargo run --release --example paper_example_study -- studies/paper-example coarse default fine
//!
//! Reads `<dir>/<run>/result.json` for each run, writes `<dir>/theta_vs_p_fidelity.{png,svg}`
//! and `<dir>/tau_vs_p_fidelity.{png,svg}`, and prints a Markdown table.

use anyhow::{anyhow, Context, Result};
use serde_json::Value;
use std::path::PathBuf;
use twistopt::evaluate::interpolate;
use twistopt::plot::{line_plot, LinePlot, Series};
use twistopt::scene::StepRecord;

fn steps(r: &Value, scene: &str) -> Result<Vec<StepRecord>> {
    serde_json::from_value(r["scenes"][scene]["steps"].clone()).with_context(|| format!("scenes.{scene}.steps"))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().ok_or_else(|| anyhow!("usage: paper_example_study DIR RUN..."))?);
    let runs = &args[1..];
    let reference: Value = {
        let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference/paper.json");
        serde_json::from_str(&std::fs::read_to_string(&p).with_context(|| format!("{}", p.display()))?)?
    };
    let letter: Vec<(f64, f64)> = reference["sim_example_fig4"]["twist_deg_at_p"]
        .as_array()
        .ok_or_else(|| anyhow!("paper.json: sim_example_fig4.twist_deg_at_p"))?
        .iter()
        .filter_map(|x| Some((x["p_kPa"].as_f64()?, x["theta_deg"].as_f64()?)))
        .collect();

    let mut theta_plot = LinePlot::new("Free twist θ(p), r = 5√3 mm, l = 10 mm, α = 60°", "cavity pressure p (kPa)", "twist θ about +z (°)");
    let mut tau_plot = LinePlot::new("Blocking torque τ(p), r = 5√3 mm, l = 10 mm, α = 60°", "cavity pressure p (kPa)", "torque on the cap τ about +z (N·m)");
    println!("| run | mesh | dofs (free) | status free / blocked | θ(−68) ° | vacuum end: p kPa, θ ° | θ(+71) ° | τ(+71) N·m | Ω J/m³ (at p kPa) | wall time s |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for run in runs {
        let path = dir.join(run).join("result.json");
        let r: Value = serde_json::from_str(&std::fs::read_to_string(&path).with_context(|| format!("{}", path.display()))?)?;
        let free = steps(&r, "free")?;
        let blocked = steps(&r, "blocked")?;
        let fmt = |v: Option<f64>, d: usize| v.map(|x| format!("{x:.d$}")).unwrap_or_else(|| "—".into());
        let th_neg = interpolate(&free, -68.0, |s| s.theta_deg);
        let th_pos = interpolate(&free, 71.0, |s| s.theta_deg);
        let tau_pos = interpolate(&blocked, 71.0, |s| s.tau_nm);
        let om = &r["omega"]["combined"]["positive"];
        let vac = free.iter().min_by(|a, b| a.p_kpa.total_cmp(&b.p_kpa)).map(|s| (s.p_kpa, s.theta_deg));
        println!(
            "| {run} | {} | {} | {} / {} | {} | {} | {} | {} | {} ({}) | {:.0} |",
            r["mesh"]["size"].as_str().unwrap_or("?"),
            r["scenes"]["free"]["dofs"],
            r["scenes"]["free"]["status"].as_str().unwrap_or("?"),
            r["scenes"]["blocked"]["status"].as_str().unwrap_or("?"),
            fmt(th_neg, 2),
            vac.map(|(p, t)| format!("{p:.1}, {t:.2}")).unwrap_or_else(|| "—".into()),
            fmt(th_pos, 2),
            fmt(tau_pos, 4),
            fmt(om["omega_J_m3"].as_f64(), 2),
            fmt(om["p_kPa"].as_f64(), 1),
            r["wall_time_s"].as_f64().unwrap_or(0.0),
        );
        let label = format!("{run} ({})", r["mesh"]["size"].as_str().unwrap_or("?"));
        theta_plot.series.push(Series::new(label.clone(), free.iter().map(|s| (s.p_kpa, s.theta_deg)).collect()));
        tau_plot.series.push(Series::new(label, blocked.iter().map(|s| (s.p_kpa, s.tau_nm)).collect()));
    }
    // headroom above the data for the legend, so that it covers no point
    theta_plot.y_range = Some((-35.0, 55.0));
    theta_plot.series.push(Series::markers_only("letter, Fig. 4a (Abaqus)", letter.clone()));
    theta_plot.series.push(Series::markers_only("letter mirrored (θ → −θ)", letter.iter().map(|&(p, t)| (p, -t)).collect()));
    line_plot(&dir.join("theta_vs_p_fidelity"), &theta_plot)?;
    line_plot(&dir.join("tau_vs_p_fidelity"), &tau_plot)?;
    Ok(())
}
