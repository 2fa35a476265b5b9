//! Speed–accuracy study (issue 9): error of θ, τ, max radius and Ω against a Richardson-extrapolated
//! reference, and wall time per evaluation and per gradient, for fidelity variants × designs.
//!
//! ```text
//! cargo run --release --example speed_accuracy -- run    [--out DIR] [--pressure KPA] [--threads N] [--only V1,V2,...] [--designs D1,D2,...] [--list]
//! cargo run --release --example speed_accuracy -- report [--out DIR]
//! ```
//!
//! `run` evaluates every (variant, design) pair of the study plan (or `--only` those variants,
//! which may be any variant name, see [`Variant::parse`]) that is not yet in `DIR/results.jsonl`:
//! the free and blocked scenes ramped from 0 to the pressure (`gradient::design_gradient`, which
//! runs the forward ramp and then the adjoint gradient of every functional), one JSON line per
//! pair appended with a single write + fsync as soon as it finishes. Re-running resumes; a torn
//! last line is ignored. `report` reads the lines and writes `summary.json`, `table.md` and the
//! Pareto plots `pareto.{png,svg}` (max error over θ, τ, max radius, Ω) and
//! `pareto_theta_tau.{png,svg}` (max error of θ and τ).
//!
//! Variant names: `<Na>x<Nz>x<Nt>` (Hex27 Q2/P1, 120° sector, κ/μ = 300) with optional suffixes
//! `-hex8` (Q1/P0), `-hex20` (Q2-serendipity/P1), `-q2p0` (Hex27 with element-constant pressure),
//! `-full` (360° model), `-k<κ/μ>` (e.g. `-k1000`).

use anyhow::{anyhow, bail, Context, Result};
use plotters::prelude::*;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use twistopt::evaluate::{append_json_line, process_cpu_time_s, read_json_lines};
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::gradient::{design_gradient, DEFAULT_KS_RHO_PER_MM};
use twistopt::meshing::MeshSpec;
use twistopt::scene::{energy_density, SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;

/// Study pressure (kPa): below the lowest limit point of the five designs on every mesh (the
/// hardest, r = 5√3, l = 20, α = 360°, fails near 40 kPa on 12x4x1).
const PRESSURE_KPA: f64 = 25.0;

/// The five designs spanning the Table-I box (id, r, l, α, note).
const DESIGNS: [(&str, f64, f64, f64, &str); 5] = [
    ("D1", 8.660254037844386, 10.0, 60.0, "letter's example"),
    ("D2", 8.660254037844386, 12.15, 152.3, "letter's optimum"),
    ("D3", 8.660254037844386, 20.0, 360.0, "corner: thin bellows, full pre-twist"),
    ("D4", 13.2, 15.0, 180.0, "centre of the box"),
    ("D5", 17.0, 10.0, 300.0, "large r, stiff"),
];

/// Richardson family: m × (12x4x1), h ∝ 1/m in all three directions. The reference of a design
/// uses the three finest members that ran for it (48x16x4 costs several times 36x12x3 and runs
/// only where the budget allowed; see the README).
const RICHARDSON: [(&str, f64); 4] = [("12x4x1", 1.0), ("24x8x2", 2.0), ("36x12x3", 3.0), ("48x16x4", 4.0)];

/// Mesh on which the κ/μ effect is measured (the reference at κ/μ = k is the κ/μ = 300 reference
/// shifted by this mesh's change from 300 to k).
const KAPPA_MESH: &str = "24x8x2";

/// Mesh presets as of this study's base commit (src/meshing.rs; `fine` is being changed to
/// 60x20x2 on main).
const PRESET_NAMES: [(&str, &str); 3] = [("coarse", "24x8x1"), ("default", "48x16x2"), ("fine (new)", "60x20x2")];

#[derive(Clone, Debug)]
struct Variant {
    name: String,
    na: usize,
    nz: usize,
    nt: usize,
    kind: ElementKind,
    pressure: PressureSpace,
    sector: bool,
    kappa_over_mu: f64,
}

impl Variant {
    fn parse(name: &str) -> Result<Variant> {
        let mut parts = name.split('-');
        let size = parts.next().ok_or_else(|| anyhow!("empty variant"))?;
        let n: Vec<usize> = size.split('x').map(|s| s.parse::<usize>()).collect::<Result<_, _>>().with_context(|| format!("variant '{name}': size"))?;
        if n.len() != 3 {
            bail!("variant '{name}': size must be <Na>x<Nz>x<Nt>");
        }
        let mut v = Variant { name: name.to_string(), na: n[0], nz: n[1], nt: n[2], kind: ElementKind::Hex27, pressure: PressureSpace::P1, sector: true, kappa_over_mu: DEFAULT_KAPPA_OVER_MU };
        for s in parts {
            match s {
                "hex8" => {
                    v.kind = ElementKind::Hex8;
                    v.pressure = PressureSpace::P0;
                }
                "hex20" => v.kind = ElementKind::Hex20,
                "q2p0" => v.pressure = PressureSpace::P0,
                "full" => v.sector = false,
                k if k.starts_with('k') => v.kappa_over_mu = k[1..].parse().with_context(|| format!("variant '{name}': κ/μ"))?,
                other => bail!("variant '{name}': unknown suffix '{other}'"),
            }
        }
        Ok(v)
    }

    fn formulation(&self) -> Formulation {
        let mut f = Formulation::standard(self.kind);
        f.pressure = self.pressure;
        f
    }

    fn element_label(&self) -> &'static str {
        match (self.kind, self.pressure) {
            (ElementKind::Hex27, PressureSpace::P1) => "Hex27 Q2/P1",
            (ElementKind::Hex27, PressureSpace::P0) => "Hex27 Q2/P0",
            (ElementKind::Hex20, _) => "Hex20 Q2s/P1",
            (ElementKind::Hex8, PressureSpace::P0) => "Hex8 Q1/P0",
            _ => "other",
        }
    }

    /// Q2/P1 Hex27 on the sector at κ/μ = 300: what `twistopt sweep --fidelity` / `[fidelity]` can run.
    fn is_preset_like(&self) -> bool {
        self.kind == ElementKind::Hex27 && self.pressure == PressureSpace::P1 && self.sector && self.kappa_over_mu == DEFAULT_KAPPA_OVER_MU
    }

    fn group(&self) -> &'static str {
        if !self.sector {
            "sector vs full"
        } else if self.kappa_over_mu != DEFAULT_KAPPA_OVER_MU {
            "κ/μ"
        } else if self.kind != ElementKind::Hex27 || self.pressure != PressureSpace::P1 {
            "element"
        } else {
            "mesh (Hex27 Q2/P1)"
        }
    }
}

/// The study plan: (variant, design indices). Cheap variants first.
fn plan() -> Vec<(String, Vec<usize>)> {
    let all: Vec<usize> = (0..DESIGNS.len()).collect();
    let mut p: Vec<(String, Vec<usize>)> = Vec::new();
    let mut add = |v: &str, d: &[usize]| p.push((v.to_string(), d.to_vec()));
    // Hex27 Q2/P1 meshes: sweep candidates, presets, through-wall, the Richardson family
    for v in ["12x4x1", "18x4x1", "12x8x1", "18x8x1", "24x8x1", "24x8x2", "24x8x3", "36x12x3", "48x16x1", "48x16x2", "60x20x2"] {
        add(v, &all);
    }
    // the fourth Richardson member (m = 4) where the compute budget allowed: the letter's example
    add("48x16x4", &[0]);
    // element order / formulation
    for v in ["24x8x1-hex20", "24x8x1-q2p0", "48x16x2-hex8", "48x16x4-hex8"] {
        add(v, &all);
    }
    // κ/μ (the reference at κ/μ ≠ 300 is shifted by the κ/μ effect on 24x8x2)
    for k in [100, 1000, 10000] {
        add(&format!("24x8x1-k{k}"), &all);
        add(&format!("24x8x2-k{k}"), &all);
    }
    // sector vs full (one design)
    add("24x8x1-full", &[0]);
    p
}

fn design_index(id: &str) -> Result<usize> {
    DESIGNS.iter().position(|d| d.0 == id).ok_or_else(|| anyhow!("unknown design '{id}' (D1 … D5)"))
}

fn loadavg() -> f64 {
    std::fs::read_to_string("/proc/loadavg").ok().and_then(|s| s.split_whitespace().next()?.parse().ok()).unwrap_or(f64::NAN)
}

fn arg_value(args: &[String], key: &str) -> Option<String> {
    args.iter().position(|a| a == key).and_then(|i| args.get(i + 1).cloned())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(arg_value(&args, "--out").unwrap_or_else(|| "studies/speed-accuracy".into()));
    match args.first().map(String::as_str) {
        Some("run") => run(&args, &out),
        Some("report") => report(&out),
        _ => bail!("usage: speed_accuracy run|report [--out DIR] [--pressure KPA] [--threads N] [--only V,...] [--designs D1,...] [--list]"),
    }
}

fn run(args: &[String], out: &Path) -> Result<()> {
    let p_kpa: f64 = arg_value(args, "--pressure").map(|s| s.parse()).transpose()?.unwrap_or(PRESSURE_KPA);
    let threads: usize = arg_value(args, "--threads").map(|s| s.parse()).transpose()?.unwrap_or(1);
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global().map_err(|e| anyhow!("rayon: {e}"))?;
    let only: Option<Vec<String>> = arg_value(args, "--only").map(|s| s.split(',').map(str::to_string).collect());
    let designs_arg: Option<Vec<usize>> = arg_value(args, "--designs").map(|s| s.split(',').map(design_index).collect::<Result<_>>()).transpose()?;
    let jobs: Vec<(String, Vec<usize>)> = match &only {
        Some(vs) => vs
            .iter()
            .map(|v| {
                let d = plan().into_iter().find(|(n, _)| n == v).map(|(_, d)| d).unwrap_or_else(|| (0..DESIGNS.len()).collect());
                (v.clone(), d)
            })
            .collect(),
        None => plan(),
    };
    let jobs: Vec<(Variant, Vec<usize>)> = jobs
        .into_iter()
        .map(|(v, d)| {
            let d = match &designs_arg {
                Some(sel) => d.into_iter().filter(|i| sel.contains(i)).collect(),
                None => d,
            };
            Ok((Variant::parse(&v)?, d))
        })
        .collect::<Result<_>>()?;
    std::fs::create_dir_all(out)?;
    let path = out.join("results.jsonl");
    let done: BTreeSet<String> =
        read_json_lines(&path).iter().filter(|r| r["p_kPa"].as_f64() == Some(p_kpa)).filter_map(|r| Some(format!("{}|{}", r["variant"].as_str()?, r["design"].as_str()?))).collect();
    let todo: Vec<(&Variant, usize)> = jobs.iter().flat_map(|(v, ds)| ds.iter().map(move |&d| (v, d))).filter(|(v, d)| !done.contains(&format!("{}|{}", v.name, DESIGNS[*d].0))).collect();
    eprintln!("{} (variant, design) pairs to run at {p_kpa} kPa on {threads} thread(s); {} already in {}", todo.len(), done.len(), path.display());
    if args.iter().any(|a| a == "--list") {
        for (v, d) in &todo {
            eprintln!("  {} {}", v.name, DESIGNS[*d].0);
        }
        return Ok(());
    }
    for (v, d) in todo {
        let row = evaluate(v, d, p_kpa, threads)?;
        eprintln!(
            "{:16} {}: θ {:9.4}° τ {:9.5} N·m Ω {:8.3} J/m³ rmax {:.4}/{:.4} mm | eval {:7.2} s, grad {:6.3} s, cpu {:7.2} s, its {}, dofs {}, load {:.2} [{}]",
            v.name,
            DESIGNS[d].0,
            row["theta_deg"].as_f64().unwrap_or(f64::NAN),
            row["tau_Nm"].as_f64().unwrap_or(f64::NAN),
            row["omega_J_m3"].as_f64().unwrap_or(f64::NAN),
            row["scenes"]["free"]["max_radius_mm"].as_f64().unwrap_or(f64::NAN),
            row["scenes"]["blocked"]["max_radius_mm"].as_f64().unwrap_or(f64::NAN),
            row["eval_time_s"].as_f64().unwrap_or(f64::NAN),
            row["gradient_time_s"].as_f64().unwrap_or(f64::NAN),
            row["cpu_time_s"].as_f64().unwrap_or(f64::NAN),
            row["newton_iterations"],
            row["scenes"]["free"]["dofs"],
            row["loadavg_end"].as_f64().unwrap_or(f64::NAN),
            row["status"].as_str().unwrap_or("?"),
        );
        append_json_line(&path, &row)?;
    }
    Ok(())
}

/// One (variant, design) evaluation: free + blocked at p, forward then adjoint gradient.
fn evaluate(v: &Variant, d: usize, p_kpa: f64, threads: usize) -> Result<Value> {
    let (id, r, l, a, _) = DESIGNS[d];
    let geom = ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::TableI)?;
    let spec = MeshSpec::new(v.na, v.nz, v.nt, v.kind)?;
    let material = NeoHookean::with_ratio(MU_HEICAST_MPA, v.kappa_over_mu)?;
    let mut opts = SceneOptions::new(spec, material.into());
    opts.formulation = v.formulation();
    opts.sector = v.sector;
    let load0 = loadavg();
    let cpu0 = process_cpu_time_s();
    let t0 = Instant::now();
    let g = design_gradient(&geom, &opts, &[SceneKind::Free, SceneKind::Blocked], p_kpa, DEFAULT_KS_RHO_PER_MM, None, None)?;
    let total = t0.elapsed().as_secs_f64();
    let cpu = process_cpu_time_s() - cpu0;
    let mut scenes = serde_json::Map::new();
    let mut all_ok = true;
    for (name, s) in &g.scenes {
        let ok = s.status == twistopt::scene::SceneStatus::Converged;
        all_ok &= ok;
        scenes.insert(
            name.clone(),
            json!({
                "status": s.status, "cause": s.cause, "p_kPa": s.p_kpa, "values": s.values,
                "max_radius_mm": s.max_radius_mm, "min_det_f": s.min_det_f, "dofs": s.dofs,
                "newton_iterations": s.cost.newton_iterations, "adjoint_solves": s.cost.adjoint_solves,
                "forward_time_s": s.cost.forward_time_s, "gradient_time_s": s.cost.gradient_time_s,
                "gradients": s.gradients,
            }),
        );
    }
    let theta = g.scenes.get("free").and_then(|s| s.values.get("theta_deg").copied());
    let tau = g.scenes.get("blocked").and_then(|s| s.values.get("tau_Nm").copied());
    let omega = match (theta, tau) {
        (Some(t), Some(q)) => Some(energy_density(t, q).abs()),
        _ => None,
    };
    let omega_grad = g.omega.get("combined").map(|o| json!({"value": o.value, "gradient": o.gradient, "valid": o.valid}));
    Ok(json!({
        "variant": v.name, "group": v.group(), "design": id,
        "design_values": {"r_mm": r, "l_mm": l, "alpha_deg": a},
        "p_kPa": p_kpa, "mesh": format!("{}x{}x{}", v.na, v.nz, v.nt), "element": v.element_label(),
        "sector": v.sector, "kappa_over_mu": v.kappa_over_mu, "threads": threads,
        "status": if all_ok { "ok" } else { "failed" },
        "theta_deg": theta, "tau_Nm": tau, "omega_J_m3": omega, "omega_gradient": omega_grad,
        "eval_time_s": g.forward_time_s, "gradient_time_s": g.gradient_time_s, "total_time_s": total, "cpu_time_s": cpu,
        "newton_iterations": g.newton_iterations, "adjoint_solves": g.adjoint_solves,
        "loadavg_start": load0, "loadavg_end": loadavg(),
        "scenes": Value::Object(scenes),
    }))
}

// ---------------------------------------------------------------------------------------------
// report

/// The quantities compared: name, label, extractor.
const QUANTITIES: [(&str, &str); 5] = [("theta", "θ"), ("tau", "τ"), ("rmax_free", "max radius (free)"), ("rmax_blocked", "max radius (blocked)"), ("omega", "Ω")];

fn quantity(row: &Value, q: &str) -> Option<f64> {
    match q {
        "theta" => row["theta_deg"].as_f64(),
        "tau" => row["tau_Nm"].as_f64(),
        "rmax_free" => row["scenes"]["free"]["max_radius_mm"].as_f64(),
        "rmax_blocked" => row["scenes"]["blocked"]["max_radius_mm"].as_f64(),
        "omega" => row["omega_J_m3"].as_f64(),
        _ => None,
    }
}

/// Observed order p from three values on h ∝ 1/m1, 1/m2, 1/m3 (m1 < m2 < m3): solves
/// (f1 − f2)/(f2 − f3) = (m1^−p − m2^−p)/(m2^−p − m3^−p) by bisection; None when the differences
/// change sign (non-monotone convergence) or no root in [0.1, 12].
fn observed_order(f: [f64; 3], m: [f64; 3]) -> Option<f64> {
    let (d1, d2) = (f[0] - f[1], f[1] - f[2]);
    if d1 == 0.0 || d2 == 0.0 || d1.signum() != d2.signum() {
        return None;
    }
    let target = d1 / d2;
    let g = |p: f64| (m[0].powf(-p) - m[1].powf(-p)) / (m[1].powf(-p) - m[2].powf(-p)) - target;
    let (mut lo, mut hi) = (0.1, 12.0);
    if g(lo).signum() == g(hi).signum() {
        return None;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid).signum() == g(lo).signum() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(0.5 * (lo + hi))
}

/// Richardson extrapolation from the two finest values with order p.
fn extrapolate(f2: f64, f3: f64, m2: f64, m3: f64, p: f64) -> f64 {
    f3 + (f3 - f2) / ((m3 / m2).powf(p) - 1.0)
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
}

/// Reference for the gradient error: the finest mesh that ran (not extrapolated).
const GRADIENT_REFERENCE: &str = "36x12x3";

/// dΩ/d(r, l, α) × (Table-I box width) of a row.
fn scaled_omega_gradient(row: &Value) -> Option<Vec<f64>> {
    let g = &row["omega_gradient"]["gradient"];
    Some(vec![g["r_mm"].as_f64()? * (20.0 - 5.0 * 3f64.sqrt()), g["l_mm"].as_f64()? * 10.0, g["alpha_deg"].as_f64()? * 300.0])
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn report(out: &Path) -> Result<()> {
    let rows = read_json_lines(&out.join("results.jsonl"));
    if rows.is_empty() {
        bail!("no rows in {}", out.join("results.jsonl").display());
    }
    let p_kpa = rows[0]["p_kPa"].as_f64().unwrap_or(PRESSURE_KPA);
    // latest row per (variant, design)
    let mut by: BTreeMap<(String, String), Value> = BTreeMap::new();
    for r in rows.iter().filter(|r| r["p_kPa"].as_f64() == Some(p_kpa)) {
        by.insert((r["variant"].as_str().unwrap_or("").into(), r["design"].as_str().unwrap_or("").into()), r.clone());
    }
    let get = |v: &str, d: &str| by.get(&(v.to_string(), d.to_string())).filter(|r| r["status"] == "ok");

    // ---- reference: Richardson on the m × (12x4x1) family, per design and quantity, from the
    // three finest members that ran for the design
    let mut reference: BTreeMap<String, BTreeMap<String, Value>> = BTreeMap::new();
    let mut orders: BTreeMap<String, Vec<f64>> = BTreeMap::new(); // from each design's finest triple
    let mut orders_by_triple: BTreeMap<String, BTreeMap<String, Vec<Value>>> = BTreeMap::new(); // triple → quantity → [(design, order)]
    let triple_of = |d: &str| -> Vec<(&str, f64)> {
        let have: Vec<(&str, f64)> = RICHARDSON.iter().copied().filter(|(v, _)| get(v, d).is_some()).collect();
        have[have.len().saturating_sub(3)..].to_vec()
    };
    for (d, ..) in DESIGNS {
        let have: Vec<(&str, f64)> = RICHARDSON.iter().copied().filter(|(v, _)| get(v, d).is_some()).collect();
        for w in have.windows(3) {
            let key = w.iter().map(|x| x.0).collect::<Vec<_>>().join(" → ");
            for (q, _) in QUANTITIES {
                let f: Vec<f64> = w.iter().filter_map(|(v, _)| get(v, d).and_then(|r| quantity(r, q))).collect();
                if f.len() == 3 {
                    let p = observed_order([f[0], f[1], f[2]], [w[0].1, w[1].1, w[2].1]);
                    orders_by_triple.entry(key.clone()).or_default().entry(q.into()).or_default().push(json!({"design": d, "order": p}));
                }
            }
        }
        let t = triple_of(d);
        if t.len() == 3 {
            for (q, _) in QUANTITIES {
                let f: Vec<f64> = t.iter().filter_map(|(v, _)| get(v, d).and_then(|r| quantity(r, q))).collect();
                if f.len() == 3 {
                    if let Some(p) = observed_order([f[0], f[1], f[2]], [t[0].1, t[1].1, t[2].1]) {
                        orders.entry(q.into()).or_default().push(p);
                    }
                }
            }
        }
    }
    let median_order: BTreeMap<String, Option<f64>> =
        QUANTITIES.iter().map(|(q, _)| (q.to_string(), orders.get(*q).and_then(|v| median(v.iter().copied().filter(|p| (1.0..=8.0).contains(p)).collect())))).collect();
    for (d, ..) in DESIGNS {
        let t = triple_of(d);
        if t.len() < 3 {
            continue;
        }
        let m = [t[0].1, t[1].1, t[2].1];
        for (q, _) in QUANTITIES {
            let f: Vec<f64> = t.iter().filter_map(|(v, _)| get(v, d).and_then(|r| quantity(r, q))).collect();
            if f.len() < 3 {
                continue;
            }
            let own = observed_order([f[0], f[1], f[2]], m);
            // the design's own order when it is within [1, 8], else the median over designs
            let (p, source) = match own {
                Some(p) if (1.0..=8.0).contains(&p) => (p, "own"),
                _ => match median_order[q] {
                    Some(p) => (p, "median over designs"),
                    None => (2.0, "nominal 2"),
                },
            };
            let fref = if f[1] == f[2] { f[2] } else { extrapolate(f[1], f[2], m[1], m[2], p) };
            // the same extrapolation from every coarser triple of the family (reference uncertainty)
            let have: Vec<(&str, f64)> = RICHARDSON.iter().copied().filter(|(v, _)| get(v, d).is_some()).collect();
            let mut alternates = Vec::new();
            for w in have.windows(3).take(have.len().saturating_sub(3)) {
                let g: Vec<f64> = w.iter().filter_map(|(v, _)| get(v, d).and_then(|r| quantity(r, q))).collect();
                if g.len() < 3 {
                    continue;
                }
                let mw = [w[0].1, w[1].1, w[2].1];
                let own_w = observed_order([g[0], g[1], g[2]], mw);
                let pw = match own_w {
                    Some(p) if (1.0..=8.0).contains(&p) => p,
                    _ => p,
                };
                let r = if g[1] == g[2] { g[2] } else { extrapolate(g[1], g[2], mw[1], mw[2], pw) };
                alternates.push(json!({"meshes": w.iter().map(|x| x.0).collect::<Vec<_>>(), "observed_order": own_w, "order_used": pw, "reference": r,
                                       "rel_difference_to_reference": if fref != 0.0 { json!((r - fref) / fref) } else { json!(0.0) }}));
            }
            reference.entry(d.into()).or_default().insert(
                q.into(),
                json!({"meshes": t.iter().map(|x| x.0).collect::<Vec<_>>(), "values": f, "m": m, "observed_order": own, "order_used": p, "order_source": source,
                       "reference": fref, "finest_minus_reference_rel": if fref != 0.0 { json!((f[2] - fref) / fref.abs()) } else { json!(0.0) },
                       "alternates": alternates}),
            );
        }
    }
    if reference.is_empty() {
        bail!("the Richardson family ({}) has not run yet", RICHARDSON.iter().map(|r| r.0).collect::<Vec<_>>().join(", "));
    }
    // the reference and its alternates (coarser triples), primary first
    let ref_values = |d: &str, q: &str| -> Vec<f64> {
        let Some(x) = reference.get(d).and_then(|m| m.get(q)) else {
            return Vec::new();
        };
        let mut v: Vec<f64> = x["reference"].as_f64().into_iter().collect();
        v.extend(x["alternates"].as_array().into_iter().flatten().filter_map(|a| a["reference"].as_f64()));
        v
    };

    // reference at κ/μ ≠ 300: shifted by the κ/μ effect on KAPPA_MESH
    let ref_at = |d: &str, q: &str, kappa: f64| -> Vec<f64> {
        let r300 = ref_values(d, q);
        if kappa == DEFAULT_KAPPA_OVER_MU {
            return r300;
        }
        let k = get(&format!("{KAPPA_MESH}-k{}", kappa as i64), d).and_then(|r| quantity(r, q));
        let b = get(KAPPA_MESH, d).and_then(|r| quantity(r, q));
        match (k, b) {
            (Some(k), Some(b)) => r300.into_iter().map(|r| r + (k - b)).collect(),
            _ => Vec::new(),
        }
    };

    // ---- per variant: errors and times
    let variants: Vec<String> = {
        let mut seen = Vec::new();
        for (name, _) in plan() {
            if by.keys().any(|(v, _)| *v == name) {
                seen.push(name);
            }
        }
        for (v, _) in by.keys() {
            if !seen.contains(v) {
                seen.push(v.clone());
            }
        }
        seen
    };
    let mut table: Vec<Value> = Vec::new();
    for name in &variants {
        let var = Variant::parse(name)?;
        let mut errs: BTreeMap<String, f64> = BTreeMap::new(); // max over designs
        let mut errs_worst: BTreeMap<String, f64> = BTreeMap::new(); // max over designs and reference estimates
        let mut grad_err: f64 = f64::NAN;
        let mut per_design = serde_json::Map::new();
        let (mut te, mut tg, mut tw, mut tcpu, mut its) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut designs = Vec::new();
        let mut failed = Vec::new();
        let mut dofs = None;
        for (d, ..) in DESIGNS {
            let Some(row) = by.get(&(name.clone(), d.to_string())) else {
                continue;
            };
            if row["status"] != "ok" {
                failed.push(d.to_string());
                continue;
            }
            designs.push(d.to_string());
            dofs = row["scenes"]["free"]["dofs"].as_u64().or(dofs);
            // single-threaded runs: process CPU time = time on a dedicated core; the forward share
            // of it is taken in proportion to the forward share of the wall time
            let (we, wg, wt, cpu) = (
                row["eval_time_s"].as_f64().unwrap_or(f64::NAN),
                row["gradient_time_s"].as_f64().unwrap_or(f64::NAN),
                row["total_time_s"].as_f64().unwrap_or(f64::NAN),
                row["cpu_time_s"].as_f64().unwrap_or(f64::NAN),
            );
            let cpu_g = cpu.min(wt).max(1e-3);
            te.push(cpu_g * we / wt);
            tg.push(cpu_g * (we + wg) / wt);
            tw.push(we);
            tcpu.push(cpu);
            its.push(row["newton_iterations"].as_f64().unwrap_or(f64::NAN));
            let mut e = serde_json::Map::new();
            for (q, _) in QUANTITIES {
                let refs = ref_at(d, q, var.kappa_over_mu);
                if let (Some(x), Some(&rf)) = (quantity(row, q), refs.first()) {
                    // signed relative to the reference: > 0 = larger magnitude than the reference
                    let rel = (x - rf) / rf;
                    e.insert(q.into(), json!(rel));
                    let en = errs.entry(q.into()).or_insert(0.0);
                    *en = en.max(rel.abs());
                    let worst = refs.iter().map(|r| ((x - r) / r).abs()).fold(0.0, f64::max);
                    let ew = errs_worst.entry(q.into()).or_insert(0.0);
                    *ew = ew.max(worst);
                }
            }
            // dΩ/d(r, l, α) scaled by the Table-I box widths, normwise against the finest mesh
            if let (Some(g), Some(gr)) = (scaled_omega_gradient(row), get(GRADIENT_REFERENCE, d).and_then(scaled_omega_gradient)) {
                let num: f64 = g.iter().zip(&gr).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
                let den: f64 = gr.iter().map(|b| b * b).sum::<f64>().sqrt();
                if den > 0.0 {
                    e.insert("omega_gradient".into(), json!(num / den));
                    grad_err = grad_err.max(num / den);
                }
            }
            per_design.insert(d.into(), Value::Object(e));
        }
        if designs.is_empty() {
            continue;
        }
        let rmax = errs.get("rmax_free").copied().unwrap_or(0.0).max(errs.get("rmax_blocked").copied().unwrap_or(0.0));
        let max_all = errs.values().copied().fold(0.0, f64::max);
        table.push(json!({
            "variant": name, "group": var.group(), "element": var.element_label(), "mesh": format!("{}x{}x{}", var.na, var.nz, var.nt),
            "sector": var.sector, "kappa_over_mu": var.kappa_over_mu, "preset_like": var.is_preset_like(),
            "reference_member": RICHARDSON.iter().any(|r| r.0 == name.as_str()),
            "preset": PRESET_NAMES.iter().find(|p| p.1 == name).map(|p| p.0),
            "dofs_free": dofs, "designs": designs, "failed_designs": failed, "all_designs": failed.is_empty() && designs.len() == DESIGNS.len(),
            "max_rel_error": {"theta": errs.get("theta"), "tau": errs.get("tau"), "max_radius": rmax, "omega": errs.get("omega"), "all": max_all,
                              "theta_tau": errs.get("theta").copied().unwrap_or(0.0).max(errs.get("tau").copied().unwrap_or(0.0)),
                              "omega_gradient_vs_finest": if grad_err.is_finite() { json!(grad_err) } else { Value::Null }},
            "max_rel_error_worst_reference": {"theta": errs_worst.get("theta"), "tau": errs_worst.get("tau"), "omega": errs_worst.get("omega"),
                              "max_radius": errs_worst.get("rmax_free").copied().unwrap_or(0.0).max(errs_worst.get("rmax_blocked").copied().unwrap_or(0.0))},
            "rel_error_by_design": Value::Object(per_design),
            "eval_time_s": {"mean": mean(&te), "max": te.iter().copied().fold(0.0, f64::max)},
            "gradient_eval_time_s": {"mean": mean(&tg), "max": tg.iter().copied().fold(0.0, f64::max)},
            "wall_eval_time_s_measured": {"mean": mean(&tw), "max": tw.iter().copied().fold(0.0, f64::max)},
            "cpu_time_s_mean": mean(&tcpu), "newton_iterations_mean": mean(&its),
        }));
    }

    // ---- Pareto front and recommendations (over variants that ran on every design)
    let complete: Vec<&Value> = table.iter().filter(|t| t["all_designs"] == true).collect();
    let t_of = |t: &Value| t["eval_time_s"]["mean"].as_f64().unwrap_or(f64::INFINITY);
    let e_of = |t: &Value, k: &str| t["max_rel_error"][k].as_f64().unwrap_or(f64::INFINITY);
    let pareto = |k: &str| -> Vec<String> {
        let mut front: Vec<&Value> =
            complete.iter().copied().filter(|a| !complete.iter().any(|b| (t_of(b) < t_of(a) && e_of(b, k) <= e_of(a, k)) || (t_of(b) <= t_of(a) && e_of(b, k) < e_of(a, k)))).collect();
        front.sort_by(|a, b| t_of(a).total_cmp(&t_of(b)));
        front.iter().map(|t| t["variant"].as_str().unwrap_or("").to_string()).collect()
    };
    let front_all = pareto("all");
    let front_omega = pareto("omega");
    let front_theta_tau = pareto("theta_tau");
    let fastest = |ok: &dyn Fn(&Value) -> bool| -> Option<&Value> { complete.iter().copied().filter(|t| t["preset_like"] == true && ok(t)).min_by(|a, b| t_of(a).total_cmp(&t_of(b))) };
    // the targets are checked against every reference estimate (worst case)
    let w_of = |t: &Value, k: &str| t["max_rel_error_worst_reference"][k].as_f64().unwrap_or(f64::INFINITY);
    let sweep = fastest(&|t| w_of(t, "omega") <= 0.03);
    let default = fastest(&|t| w_of(t, "theta") <= 0.01 && w_of(t, "tau") <= 0.01);
    let sweep_primary = fastest(&|t| e_of(t, "omega") <= 0.03);
    let default_primary = fastest(&|t| e_of(t, "theta") <= 0.01 && e_of(t, "tau") <= 0.01);
    let fastest_any = |ok: &dyn Fn(&Value) -> bool| -> Option<&Value> { complete.iter().copied().filter(|t| ok(t)).min_by(|a, b| t_of(a).total_cmp(&t_of(b))) };
    let sweep_any = fastest_any(&|t| w_of(t, "omega") <= 0.03);
    let default_any = fastest_any(&|t| w_of(t, "theta") <= 0.01 && w_of(t, "tau") <= 0.01);

    // ---- κ/μ physical effect: default mesh at κ/μ = k vs κ/μ = 10000
    let mut kappa_effect = serde_json::Map::new();
    for k in [100.0, 300.0, 1000.0] {
        let mut per = serde_json::Map::new();
        for (q, _) in QUANTITIES {
            let mut worst: f64 = 0.0;
            let mut any = false;
            for (d, ..) in DESIGNS {
                let name = if k == 300.0 { KAPPA_MESH.to_string() } else { format!("{KAPPA_MESH}-k{}", k as i64) };
                if let (Some(a), Some(b)) = (get(&name, d).and_then(|r| quantity(r, q)), get(&format!("{KAPPA_MESH}-k10000"), d).and_then(|r| quantity(r, q))) {
                    worst = worst.max(((a - b) / b.abs()).abs());
                    any = true;
                }
            }
            if any {
                per.insert(q.into(), json!(worst));
            }
        }
        kappa_effect.insert(format!("{}", k as i64), Value::Object(per));
    }

    // ---- sweep throughput (twistopt sweep runs under DIR/sweep-throughput/<mesh>/)
    let mut sweeps = serde_json::Map::new();
    let grid_size = 39_864.0;
    if let Ok(rd) = std::fs::read_dir(out.join("sweep-throughput")) {
        let mut dirs: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("summary.json").exists()).collect();
        dirs.sort();
        for dir in dirs {
            let s: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
            let lines = read_json_lines(&dir.join("results.jsonl"));
            let n = lines.len() as f64;
            let design_time: f64 = lines.iter().filter_map(|r| r["wall_time_s"].as_f64()).sum();
            let its: f64 = lines.iter().filter_map(|r| Some(r["scenes"]["free"]["newton_iterations"].as_f64()? + r["scenes"]["blocked"]["newton_iterations"].as_f64()?)).sum();
            let rate = s["last_run"]["designs_per_s"].as_f64();
            let cpu_info: Option<Value> = std::fs::read_to_string(dir.join("time.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
            let cpu_per_design = cpu_info.as_ref().and_then(|c| c["cpu_s"].as_f64()).map(|c| c / n);
            let name = dir.file_name().map(|f| f.to_string_lossy().to_string()).unwrap_or_default();
            sweeps.insert(
                name,
                json!({
                    "fidelity": s["fidelity"], "grid": s["grid"], "designs": lines.len(), "threads": s["last_run"]["threads"],
                    "wall_time_s": s["last_run"]["wall_time_s"], "designs_per_s": rate,
                    "mean_design_time_s": if n > 0.0 { json!(design_time / n) } else { Value::Null },
                    "mean_newton_iterations_per_design": if n > 0.0 { json!(its / n) } else { Value::Null },
                    "cpu_s_per_design": cpu_per_design, "loadavg": cpu_info.as_ref().map(|c| c["loadavg"].clone()),
                    "full_grid_h_at_measured_rate": rate.map(|r| grid_size / r / 3600.0),
                    "full_grid_h_quiet_2_cores": cpu_per_design.map(|c| grid_size * c / 2.0 / 3600.0),
                    "meets_1h_target_at_measured_rate": rate.map(|r| grid_size / r <= 3600.0),
                }),
            );
        }
    }

    // ---- sector vs full: the same mesh on the 120° sector and the full model
    let mut sector_full = serde_json::Map::new();
    for name in variants.iter().filter(|n| n.ends_with("-full")) {
        let base = name.trim_end_matches("-full");
        for (d, ..) in DESIGNS {
            if let (Some(f), Some(b)) = (get(name, d), get(base, d)) {
                let diffs: serde_json::Map<String, Value> =
                    QUANTITIES.iter().filter_map(|(q, _)| Some((q.to_string(), json!(((quantity(f, q)? - quantity(b, q)?) / quantity(b, q)?.abs()).abs())))).collect();
                let cpu = |r: &Value| r["cpu_time_s"].as_f64().unwrap_or(f64::NAN);
                sector_full.insert(
                    format!("{name} vs {base}, {d}"),
                    json!({"rel_difference": diffs, "dofs": [f["scenes"]["free"]["dofs"], b["scenes"]["free"]["dofs"]],
                           "newton_iterations": [f["newton_iterations"], b["newton_iterations"]], "cpu_time_ratio_full_over_sector": cpu(f) / cpu(b)}),
                );
            }
        }
    }

    let variant_summary = |t: Option<&Value>| {
        t.map(|t| json!({"variant": t["variant"], "eval_time_s": t["eval_time_s"]["mean"], "gradient_eval_time_s": t["gradient_eval_time_s"]["mean"], "max_rel_error": t["max_rel_error"], "max_rel_error_worst_reference": t["max_rel_error_worst_reference"]}))
    };
    let summary = json!({
        "description": format!("free + blocked scenes ramped 0 → {p_kpa} kPa; errors against a Richardson-extrapolated reference per design (family m × 12x4x1, each design's three finest members, Hex27 Q2/P1, sector, κ/μ = 300); times: mean over designs of the two scenes' forward ramps (mesh + model build included), single-threaded, as time on a dedicated core (process CPU time; the forward share in proportion to the wall-time split); gradient = forward + adjoint of every functional; the measured wall times (shared, loaded machine) are in wall_eval_time_s_measured"),
        "p_kPa": p_kpa,
        "designs": DESIGNS.iter().map(|(id, r, l, a, note)| json!({"id": id, "r_mm": r, "l_mm": l, "alpha_deg": a, "note": note})).collect::<Vec<_>>(),
        "presets": PRESET_NAMES.iter().map(|(n, m)| json!({"preset": n, "mesh": m})).collect::<Vec<_>>(),
        "richardson": {"family": RICHARDSON.iter().map(|r| json!({"mesh": r.0, "m": r.1})).collect::<Vec<_>>(),
                       "observed_orders_finest_triple": orders, "median_order": median_order, "observed_orders_by_triple": orders_by_triple,
                       "reference": reference},
        "kappa_reference_rule": format!("reference at κ/μ = k: Richardson reference at κ/μ = 300 + ({KAPPA_MESH} at k − {KAPPA_MESH} at 300)"),
        "kappa_effect_vs_10000": kappa_effect,
        "sector_vs_full": Value::Object(sector_full),
        "pareto_front_all": front_all, "pareto_front_omega": front_omega, "pareto_front_theta_tau": front_theta_tau,
        "recommended": {
            "rule_sweep": "fastest preset-like variant (Hex27 Q2/P1, sector, κ/μ = 300; runnable as --fidelity NaxNzxNt) whose Ω error ≤ 3 % on every design against every reference estimate",
            "rule_default": "fastest preset-like variant whose θ and τ errors ≤ 1 % on every design against every reference estimate",
            "sweep": variant_summary(sweep), "default": variant_summary(default),
            "sweep_any_variant": variant_summary(sweep_any), "default_any_variant": variant_summary(default_any),
            "sweep_primary_reference_only": variant_summary(sweep_primary), "default_primary_reference_only": variant_summary(default_primary),
            "note": "sweep/default check the targets against every reference estimate (each design's finest Richardson triple and, where a fourth family member ran, the coarser triple); *_primary_reference_only against the finest triple only",
        },
        "sweep_throughput": Value::Object(sweeps),
        "variants": table,
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)? + "\n")?;
    write_table(out, &summary)?;
    let marks: Vec<(String, String)> =
        [(sweep, "recommended: sweep"), (default, "recommended: default / optimisation")].iter().filter_map(|(t, label)| Some(((*t)?["variant"].as_str()?.to_string(), label.to_string()))).collect();
    pareto_plot(&out.join("pareto"), &table, "all", &front_all, &marks, "max relative error over θ, τ, max radius, Ω and the five designs")?;
    pareto_plot(&out.join("pareto_theta_tau"), &table, "theta_tau", &front_theta_tau, &marks, "max relative error of θ and τ over the five designs")?;
    println!("wrote summary.json, table.md, pareto.{{png,svg}}, pareto_theta_tau.{{png,svg}} to {}", out.display());
    Ok(())
}

fn pct(v: &Value) -> String {
    v.as_f64().map(|x| if x < 0.001 { format!("{:.3} %", 100.0 * x) } else { format!("{:.2} %", 100.0 * x) }).unwrap_or_else(|| "—".into())
}

fn write_table(out: &Path, s: &Value) -> Result<()> {
    let mut t = String::new();
    let p = s["p_kPa"].as_f64().unwrap_or(f64::NAN);
    t += &format!("<!-- generated by `cargo run --release --example speed_accuracy -- report` from results.jsonl; do not edit -->\n\n");
    t += &format!("### Error vs time per variant (free + blocked at {p} kPa, max over the five designs)\n\n");
    t += "| variant | group | element | preset | dofs (sector/full, free) | max err θ | max err τ | max err max radius | max err Ω | max err (all) | θ / τ / Ω, worst over reference estimates | dΩ/d(r,l,α) vs 36x12x3 | time / evaluation (s, 1 core) | time / evaluation + gradient (s, 1 core) | measured wall / evaluation (s) | Newton its | Pareto |\n";
    t += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    let front: Vec<&str> = s["pareto_front_all"].as_array().map(|a| a.iter().filter_map(|x| x.as_str()).collect()).unwrap_or_default();
    let mut rows: Vec<&Value> = s["variants"].as_array().map(|a| a.iter().collect()).unwrap_or_default();
    rows.sort_by(|a, b| {
        a["group"]
            .as_str()
            .unwrap_or("")
            .cmp(b["group"].as_str().unwrap_or(""))
            .reverse()
            .then(a["eval_time_s"]["mean"].as_f64().unwrap_or(0.0).total_cmp(&b["eval_time_s"]["mean"].as_f64().unwrap_or(0.0)))
    });
    for r in rows {
        let name = r["variant"].as_str().unwrap_or("");
        let designs = r["designs"].as_array().map(|a| a.len()).unwrap_or(0);
        let note = if r["all_designs"] == true {
            String::new()
        } else {
            format!(
                " ({} of {} designs{})",
                designs,
                DESIGNS.len(),
                r["failed_designs"].as_array().filter(|a| !a.is_empty()).map(|a| format!(", failed: {}", a.iter().filter_map(|x| x.as_str()).collect::<Vec<_>>().join(" "))).unwrap_or_default()
            )
        };
        t += &format!(
            "| {name}{}{note} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} / {} | {} | {:.2} | {:.2} | {:.2} | {:.0} | {} |\n",
            if r["reference_member"] == true { " †" } else { "" },
            r["group"].as_str().unwrap_or(""),
            r["element"].as_str().unwrap_or(""),
            r["preset"].as_str().unwrap_or(""),
            r["dofs_free"],
            pct(&r["max_rel_error"]["theta"]),
            pct(&r["max_rel_error"]["tau"]),
            pct(&r["max_rel_error"]["max_radius"]),
            pct(&r["max_rel_error"]["omega"]),
            pct(&r["max_rel_error"]["all"]),
            pct(&r["max_rel_error_worst_reference"]["theta"]),
            pct(&r["max_rel_error_worst_reference"]["tau"]),
            pct(&r["max_rel_error_worst_reference"]["omega"]),
            pct(&r["max_rel_error"]["omega_gradient_vs_finest"]),
            r["eval_time_s"]["mean"].as_f64().unwrap_or(f64::NAN),
            r["gradient_eval_time_s"]["mean"].as_f64().unwrap_or(f64::NAN),
            r["wall_eval_time_s_measured"]["mean"].as_f64().unwrap_or(f64::NAN),
            r["newton_iterations_mean"].as_f64().unwrap_or(f64::NAN),
            if front.contains(&name) { "●" } else { "" },
        );
    }
    t += "\n† member of the Richardson family (its error is not independent of the reference). Errors are against each design's primary reference (finest triple); the \"worst\" column also uses the coarser-triple reference where a fourth member ran. Times: mean over the designs, single-threaded (process CPU time); the measured wall time on the shared machine is beside it.\n";
    // per design
    t += "\n### Relative error per design: θ / τ / Ω in % ((value − reference)/reference: > 0 = larger magnitude than the reference)\n\n| variant | D1 | D2 | D3 | D4 | D5 |\n|---|---|---|---|---|---|\n";
    let sgn = |v: &Value| v.as_f64().map(|x| format!("{:+.2}", 100.0 * x)).unwrap_or_else(|| "—".into());
    let mut mesh_rows: Vec<&Value> = s["variants"].as_array().map(|a| a.iter().collect()).unwrap_or_default();
    mesh_rows.sort_by(|a, b| {
        a["group"]
            .as_str()
            .unwrap_or("")
            .cmp(b["group"].as_str().unwrap_or(""))
            .reverse()
            .then(a["eval_time_s"]["mean"].as_f64().unwrap_or(0.0).total_cmp(&b["eval_time_s"]["mean"].as_f64().unwrap_or(0.0)))
    });
    for r in mesh_rows {
        t += &format!("| {} |", r["variant"].as_str().unwrap_or(""));
        for (d, ..) in DESIGNS {
            let e = &r["rel_error_by_design"][d];
            t += &if e.is_null() { " — |".to_string() } else { format!(" {} / {} / {} |", sgn(&e["theta"]), sgn(&e["tau"]), sgn(&e["omega"])) };
        }
        t += "\n";
    }
    // Richardson
    t += "\n### Richardson reference (family m × 12x4x1; each design's three finest members)\n\n| design | quantity | meshes | values | observed order | order used | reference | finest − reference |\n|---|---|---|---|---|---|---|---|\n";
    if let Some(refs) = s["richardson"]["reference"].as_object() {
        for (d, qs) in refs {
            for (q, label) in QUANTITIES {
                let x = &qs[q];
                if x.is_null() {
                    continue;
                }
                let v = |i: usize| x["values"][i].as_f64().map(|v| format!("{v:.6}")).unwrap_or_default();
                let meshes = x["meshes"].as_array().map(|a| a.iter().filter_map(|m| m.as_str()).collect::<Vec<_>>().join(", ")).unwrap_or_default();
                t += &format!(
                    "| {d} | {label} | {meshes} | {}, {}, {} | {} | {:.2} ({}) | {:.6} | {} |\n",
                    v(0),
                    v(1),
                    v(2),
                    x["observed_order"].as_f64().map(|p| format!("{p:.2}")).unwrap_or_else(|| "non-monotone".into()),
                    x["order_used"].as_f64().unwrap_or(f64::NAN),
                    x["order_source"].as_str().unwrap_or(""),
                    x["reference"].as_f64().unwrap_or(f64::NAN),
                    pct(&x["finest_minus_reference_rel"]),
                );
                for a in x["alternates"].as_array().into_iter().flatten() {
                    let meshes = a["meshes"].as_array().map(|a| a.iter().filter_map(|m| m.as_str()).collect::<Vec<_>>().join(", ")).unwrap_or_default();
                    t += &format!(
                        "| {d} | {label} (coarser triple) | {meshes} | | {} | {:.2} | {:.6} | reference differs by {} |\n",
                        a["observed_order"].as_f64().map(|p| format!("{p:.2}")).unwrap_or_else(|| "non-monotone".into()),
                        a["order_used"].as_f64().unwrap_or(f64::NAN),
                        a["reference"].as_f64().unwrap_or(f64::NAN),
                        pct(&a["rel_difference_to_reference"]),
                    );
                }
            }
        }
    }
    t += &format!("\n### κ/μ: physical effect ({KAPPA_MESH} at κ/μ vs κ/μ = 10000, max over designs)\n\n| κ/μ | θ | τ | max radius (free) | max radius (blocked) | Ω |\n|---|---|---|---|---|---|\n");
    if let Some(k) = s["kappa_effect_vs_10000"].as_object() {
        let mut keys: Vec<&String> = k.keys().collect();
        keys.sort_by_key(|x| x.parse::<i64>().unwrap_or(0));
        for kk in keys {
            let v = &k[kk];
            t += &format!("| {kk} | {} | {} | {} | {} | {} |\n", pct(&v["theta"]), pct(&v["tau"]), pct(&v["rmax_free"]), pct(&v["rmax_blocked"]), pct(&v["omega"]));
        }
    }
    if let Some(sf) = s["sector_vs_full"].as_object() {
        if !sf.is_empty() {
            t += "\n### Sector vs full model\n\n| comparison | θ | τ | max radius (free) | Ω | dofs full / sector | CPU time full / sector |\n|---|---|---|---|---|---|---|\n";
            for (k, v) in sf {
                let d = &v["rel_difference"];
                let e = |q: &str| d[q].as_f64().map(|x| format!("{x:.1e}")).unwrap_or_else(|| "—".into());
                t += &format!(
                    "| {k} | {} | {} | {} | {} | {} / {} | {:.2} |\n",
                    e("theta"),
                    e("tau"),
                    e("rmax_free"),
                    e("omega"),
                    v["dofs"][0],
                    v["dofs"][1],
                    v["cpu_time_ratio_full_over_sector"].as_f64().unwrap_or(f64::NAN)
                );
            }
        }
    }
    t += "\n### Recommendations (computed by the report)\n\n";
    for (k, rule) in [("sweep", "rule_sweep"), ("default", "rule_default")] {
        let r = &s["recommended"][k];
        t += &format!(
            "* **{k}**: {} — {}; evaluation {} s, evaluation + gradient {} s, max errors (worst over reference estimates) θ {}, τ {}, Ω {}\n",
            r["variant"].as_str().unwrap_or("none"),
            s["recommended"][rule].as_str().unwrap_or(""),
            r["eval_time_s"].as_f64().map(|x| format!("{x:.2}")).unwrap_or_default(),
            r["gradient_eval_time_s"].as_f64().map(|x| format!("{x:.2}")).unwrap_or_default(),
            pct(&r["max_rel_error_worst_reference"]["theta"]),
            pct(&r["max_rel_error_worst_reference"]["tau"]),
            pct(&r["max_rel_error_worst_reference"]["omega"]),
        );
    }
    for (k, label) in [("sweep_primary_reference_only", "sweep, primary reference only"), ("default_primary_reference_only", "default, primary reference only")] {
        t += &format!("* {label}: {}\n", s["recommended"][k]["variant"].as_str().unwrap_or("none"));
    }
    if let Some(sw) = s["sweep_throughput"].as_object() {
        if !sw.is_empty() {
            t += "\n### Sweep throughput (`twistopt sweep`, ramp to failure, 2 threads)\n\n| mesh | designs | wall time (s) | designs/s | mean design time (s) | Newton its / design | CPU s / design | full Table-I grid at measured rate (h) | quiet 2 cores (h) | ≤ 1 h |\n|---|---|---|---|---|---|---|---|---|---|\n";
            for (name, v) in sw {
                let f = |k: &str, d: usize| v[k].as_f64().map(|x| format!("{x:.d$}")).unwrap_or_else(|| "—".into());
                t += &format!(
                    "| {name} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    v["designs"],
                    f("wall_time_s", 1),
                    f("designs_per_s", 4),
                    f("mean_design_time_s", 2),
                    f("mean_newton_iterations_per_design", 0),
                    f("cpu_s_per_design", 2),
                    f("full_grid_h_at_measured_rate", 1),
                    f("full_grid_h_quiet_2_cores", 1),
                    if v["meets_1h_target_at_measured_rate"] == true { "yes" } else { "no" },
                );
            }
        }
    }
    std::fs::write(out.join("table.md"), t)?;
    Ok(())
}

fn group_colour(g: &str) -> RGBColor {
    match g {
        "mesh (Hex27 Q2/P1)" => RGBColor(31, 119, 180),
        "element" => RGBColor(214, 39, 40),
        "κ/μ" => RGBColor(44, 160, 44),
        "sector vs full" => RGBColor(148, 103, 189),
        _ => RGBColor(127, 127, 127),
    }
}

fn pareto_plot(stem: &Path, table: &[Value], key: &str, front: &[String], marks: &[(String, String)], y_label: &str) -> Result<()> {
    static FONT: std::sync::Once = std::sync::Once::new();
    FONT.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
    let pts: Vec<(String, String, f64, f64, bool)> = table
        .iter()
        .filter(|t| t["all_designs"] == true)
        .filter_map(|t| {
            let x = t["eval_time_s"]["mean"].as_f64()?;
            let y = t["max_rel_error"][key].as_f64()?;
            Some((t["variant"].as_str()?.to_string(), t["group"].as_str()?.to_string(), x, y.max(1e-5), t["reference_member"] == true))
        })
        .collect();
    if pts.is_empty() {
        return Ok(());
    }
    let (xmin, xmax) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| (a.min(p.2), b.max(p.2)));
    let (ymin, ymax) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| (a.min(p.3), b.max(p.3)));
    let xr = (xmin / 1.6)..(xmax * 2.5);
    let yr = (ymin / 2.0).min(5e-4)..(ymax * 2.0).max(0.05);
    #[allow(clippy::too_many_arguments)]
    fn inner<DB: DrawingBackend>(
        root: DrawingArea<DB, plotters::coord::Shift>,
        pts: &[(String, String, f64, f64, bool)],
        front: &[String],
        marks: &[(String, String)],
        xr: std::ops::Range<f64>,
        yr: std::ops::Range<f64>,
        y_label: &str,
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let e = |x: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("pareto plot: {x:?}");
        root.fill(&WHITE).map_err(e)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Speed vs accuracy: free + blocked evaluation", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(70)
            .build_cartesian_2d(xr.clone().log_scale(), yr.clone().log_scale())
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("time per evaluation, free + blocked, on one core (s; mean over the five designs)")
            .y_desc(y_label)
            .y_label_formatter(&|v| {
                if *v >= 0.01 {
                    format!("{:.0} %", v * 100.0)
                } else {
                    format!("{:.2} %", v * 100.0)
                }
            })
            .x_label_formatter(&|v| {
                if *v >= 1.0 {
                    format!("{v:.0}")
                } else {
                    format!("{v:.2}")
                }
            })
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(e)?;
        // targets
        for (y, label, c) in [(0.03, "3 % (sweep: Ω)", RGBColor(200, 120, 0)), (0.01, "1 % (default: θ, τ)", RGBColor(120, 120, 120))] {
            if yr.contains(&y) {
                chart.draw_series(LineSeries::new(vec![(xr.start, y), (xr.end, y)], c.stroke_width(1))).map_err(e)?;
                chart.draw_series(std::iter::once(Text::new(label.to_string(), (xr.start * 1.05, y * 1.06), ("sans-serif", 13).into_font().color(&c)))).map_err(e)?;
            }
        }
        // Pareto front
        let mut fp: Vec<(f64, f64)> = pts.iter().filter(|p| front.contains(&p.0)).map(|p| (p.2, p.3)).collect();
        fp.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart.draw_series(LineSeries::new(fp, RGBColor(0, 0, 0).stroke_width(1))).map_err(e)?.label("Pareto front").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(1)));
        for g in ["mesh (Hex27 Q2/P1)", "element", "κ/μ", "sector vs full"] {
            let c = group_colour(g);
            let ps: Vec<&(String, String, f64, f64, bool)> = pts.iter().filter(|p| p.1 == g).collect();
            if ps.is_empty() {
                continue;
            }
            chart.draw_series(ps.iter().map(|p| Circle::new((p.2, p.3), 5, c.filled()))).map_err(e)?.label(g).legend(move |(x, y)| Circle::new((x + 9, y), 5, c.filled()));
        }
        // labels: right of the point, or below / above it when a label nearby is already placed
        let mut placed: Vec<(f64, f64)> = Vec::new();
        let mut order: Vec<&(String, String, f64, f64, bool)> = pts.iter().collect();
        order.sort_by(|a, b| a.2.total_cmp(&b.2));
        for p in order {
            let c = group_colour(&p.1);
            let mut at = (p.2 * 1.1, p.3 * 1.04);
            for dy in [1.0, 0.80, 1.28, 0.64, 1.6] {
                let cand = (p.2 * 1.1, p.3 * 1.04 * dy);
                if !placed.iter().any(|q| (cand.0 / q.0).ln().abs() < 0.45 && (cand.1 / q.1).ln().abs() < 0.12) {
                    at = cand;
                    break;
                }
            }
            placed.push(at);
            chart.draw_series(std::iter::once(Text::new(p.0.clone(), at, ("sans-serif", 11).into_font().color(&c)))).map_err(e)?;
        }
        for (v, label) in marks {
            if let Some(p) = pts.iter().find(|p| &p.0 == v) {
                chart.draw_series(std::iter::once(Circle::new((p.2, p.3), 12, RGBColor(200, 0, 0).stroke_width(2)))).map_err(e)?;
                chart.draw_series(std::iter::once(Text::new(label.clone(), (p.2 / 1.12, p.3 / 1.45), ("sans-serif", 13).into_font().style(FontStyle::Bold).color(&RGBColor(200, 0, 0))))).map_err(e)?;
            }
        }
        let refs: Vec<&(String, String, f64, f64, bool)> = pts.iter().filter(|p| p.4).collect();
        if !refs.is_empty() {
            chart
                .draw_series(refs.iter().map(|p| Circle::new((p.2, p.3), 9, BLACK.stroke_width(1))))
                .map_err(e)?
                .label("Richardson family member (error not independent)")
                .legend(|(x, y)| Circle::new((x + 9, y), 7, BLACK.stroke_width(1)));
        }
        chart.configure_series_labels().position(SeriesLabelPosition::UpperRight).background_style(WHITE.mix(0.9)).border_style(BLACK).label_font(("sans-serif", 14)).draw().map_err(e)?;
        root.present().map_err(e)?;
        Ok(())
    }
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    inner(BitMapBackend::new(&png, (1100, 760)).into_drawing_area(), &pts, front, marks, xr.clone(), yr.clone(), y_label)?;
    inner(SVGBackend::new(&svg, (1100, 760)).into_drawing_area(), &pts, front, marks, xr, yr, y_label)?;
    Ok(())
}
