//! Summarise studies/calculix-crosscheck/runs/<design>/<mesh>/crosscheck.json into a Markdown
//! table (stdout) and plots (θ, τ relative differences and wall times against the DOFs).
//!
//!   cargo run --release --example calculix_study -- studies/calculix-crosscheck

use anyhow::{Context, Result};
use std::path::PathBuf;
use twistopt::plot::{line_plot, LinePlot, Series};

fn main() -> Result<()> {
    let root = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "studies/calculix-crosscheck".into()));
    let runs = root.join("runs");
    let mut designs: Vec<_> = std::fs::read_dir(&runs).with_context(|| format!("{}", runs.display()))?.filter_map(|e| e.ok()).map(|e| e.path()).collect();
    designs.sort();
    println!("| design | mesh | twistopt el. | ccx el. | scene | twistopt dofs | ccx equations | θ twistopt (°) | θ ccx (°) | Δθ | τ twistopt (N·m) | τ ccx (N·m) | Δτ | t twistopt (s) | t ccx (s) | ccx status |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut rel = LinePlot::new("twistopt (Q2/P1 Hex27) vs CalculiX (C3D20R) at 40 kPa", "CalculiX equations", "(twistopt − ccx)/|ccx| (%)");
    let mut time = LinePlot::new("Wall time at 40 kPa (same run, 2 shared cores)", "DOFs (twistopt sector / ccx full model)", "wall time (s)");
    for d in &designs {
        let name = d.file_name().unwrap().to_string_lossy().to_string();
        let mut meshes: Vec<_> = std::fs::read_dir(d)?.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.join("crosscheck.json").exists()).collect();
        meshes.sort_by_key(|p| {
            let m = p.file_name().unwrap().to_string_lossy().to_string();
            let n: Vec<usize> = m.split(['x', '-']).filter_map(|s| s.parse().ok()).collect();
            n.iter().product::<usize>()
        });
        let (mut th, mut ta, mut tw_t, mut cc_t) = (vec![], vec![], vec![], vec![]);
        for m in &meshes {
            let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(m.join("crosscheck.json"))?)?;
            let mesh = m.file_name().unwrap().to_string_lossy().to_string();
            let el = r["twistopt"]["element"].as_str().unwrap_or("standard").to_string();
            let cel = r["ccx"]["element"].as_str().unwrap_or("?").to_string();
            let Some(scenes) = r["scenes"].as_object() else {
                continue;
            };
            for (scene, s) in scenes {
                let f = |v: &serde_json::Value| v.as_f64();
                let row = s["comparison"].as_array().and_then(|a| a.last()).cloned().unwrap_or_default();
                let eq = s["ccx"]["equations"].as_u64().unwrap_or(0);
                let pct = |v: &serde_json::Value| f(v).map(|x| format!("{:+.2} %", 100.0 * x)).unwrap_or("–".into());
                let num = |v: &serde_json::Value, p: usize| f(v).map(|x| format!("{x:.p$}")).unwrap_or("–".into());
                let free = scene == "free" || scene == "pure-twist";
                println!(
                    "| {name} | {mesh} | {el} | {cel} | {scene} | {} | {eq} | {} | {} | {} | {} | {} | {} | {:.1} | {:.1} | {} |",
                    s["twistopt"]["dofs"],
                    if free { num(&row["twistopt"]["theta_deg"], 3) } else { "–".into() },
                    if free { num(&row["ccx"]["theta_deg"], 3) } else { "–".into() },
                    pct(&row["rel_diff"]["theta"]),
                    if free { "–".into() } else { num(&row["twistopt"]["tau_Nm"], 5) },
                    // free scenes: ccx's residual moment on the free cap (0 when fully converged)
                    if free { format!("({} residual)", num(&row["ccx"]["tau_Nm"], 5)) } else { num(&row["ccx"]["tau_Nm"], 5) },
                    pct(&row["rel_diff"]["tau"]),
                    f(&s["twistopt"]["wall_time_s"]).unwrap_or(f64::NAN),
                    f(&s["ccx"]["wall_time_s"]).unwrap_or(f64::NAN),
                    s["ccx"]["status"].as_str().unwrap_or("?"),
                );
                if el != "standard" || cel != "C3D20R" {
                    continue;
                }
                if let Some(x) = f(&row["rel_diff"]["theta"]) {
                    th.push((eq as f64, 100.0 * x));
                }
                if let Some(x) = f(&row["rel_diff"]["tau"]) {
                    ta.push((eq as f64, 100.0 * x));
                }
                if let (Some(a), Some(b)) = (f(&s["twistopt"]["wall_time_s"]), f(&s["ccx"]["wall_time_s"])) {
                    tw_t.push((s["twistopt"]["dofs"].as_f64().unwrap_or(0.0), a));
                    cc_t.push((eq as f64, b));
                }
            }
        }
        for v in [&mut th, &mut ta, &mut tw_t, &mut cc_t] {
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        if !th.is_empty() {
            rel = rel.with(Series::new(format!("{name}: θ (free)"), th));
        }
        if !ta.is_empty() {
            rel = rel.with(Series::new(format!("{name}: τ (blocked)"), ta));
        }
        if !tw_t.is_empty() {
            time = time.with(Series::markers_only(format!("{name}: twistopt"), tw_t));
            time = time.with(Series::markers_only(format!("{name}: ccx"), cc_t));
        }
    }
    line_plot(&root.join("rel_diff_vs_dofs"), &rel)?;
    line_plot(&root.join("wall_time_vs_dofs"), &time)?;
    Ok(())
}
