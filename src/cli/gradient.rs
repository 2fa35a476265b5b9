//! `twistopt gradient`: values and adjoint gradients of the scene outputs (θ, τ, axial
//! displacement, cavity volume, KS max radius) and of Ω with respect to every design parameter,
//! the pressure and μ, at one pressure; optionally checked against central finite differences.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::json;

use crate::gradient::{design_gradient, fd_check, max_rel_error, DEFAULT_KS_RHO_PER_MM};
use crate::problem::{LoadPlan, Problem};

#[derive(Debug, Args)]
pub struct GradientArgs {
    /// Problem file (TOML; schema in problems/README.md).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Override a problem value: section.key=value (repeatable; see `evaluate --help`).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Pressure (kPa) of the equilibrium; default: load.p_max_kPa, or the largest positive
    /// pressure of load.pressures_kPa (the most negative if there is none).
    #[arg(long = "pressure", value_name = "KPA", allow_hyphen_values = true)]
    pub pressure: Option<f64>,
    /// KS aggregation parameter of the max radius (1/mm).
    #[arg(long = "ks-rho", value_name = "PER_MM", default_value_t = DEFAULT_KS_RHO_PER_MM)]
    pub ks_rho: f64,
    /// Also compute central finite differences (one-sided at the Table-I bounds) with a step study.
    #[arg(long = "check-fd")]
    pub check_fd: bool,
    /// Relative FD steps (× the parameter's range, the pressure, μ), from large to small.
    #[arg(long = "fd-steps", value_name = "H,H,..", value_delimiter = ',', default_values_t = vec![1e-3, 1e-4, 1e-5])]
    pub fd_steps: Vec<f64>,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: &GradientArgs) -> Result<()> {
    let problem = Problem::load(&args.problem, &args.set)?;
    let v = problem.validate()?;
    let p = match args.pressure {
        Some(p) => p,
        None => match &v.load {
            LoadPlan::Ramp(p) => *p,
            LoadPlan::Targets(t) => {
                let pos = t.iter().copied().filter(|p| *p > 0.0).fold(f64::NAN, f64::max);
                if pos.is_finite() {
                    pos
                } else {
                    t.iter().copied().fold(f64::NAN, f64::min)
                }
            }
        },
    };
    if !p.is_finite() || p.abs() > 1e4 {
        bail!("--pressure = {p} kPa is not allowed (finite, |p| <= 10000)");
    }
    if !(args.ks_rho.is_finite() && args.ks_rho > 0.0) {
        bail!("--ks-rho = {} is not allowed (must be finite and > 0)", args.ks_rho);
    }
    if args.fd_steps.is_empty() || args.fd_steps.iter().any(|h| !(h.is_finite() && *h > 0.0 && *h < 0.1)) {
        bail!("--fd-steps must be positive relative steps below 0.1");
    }
    let opts = problem.scene_options(&v);
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let dg = design_gradient(&v.geometry, &opts, &v.scenes, p, args.ks_rho, None, None)?;
    let mut doc = serde_json::to_value(&dg)?;
    doc["fidelity"] = json!(v.mesh.size_string());
    doc["model"] = crate::evaluate::fidelity_json(&v);
    doc["element"] = json!(format!("{:?}", opts.formulation.kind));
    doc["ks_rho_per_mm"] = json!(args.ks_rho);
    for (name, g) in &dg.scenes {
        println!(
            "{name}: {} at p = {:.3} kPa ({} Newton iterations, forward {:.2} s, gradient {:.3} s = {:.1} %)",
            g.status,
            g.p_kpa,
            g.cost.newton_iterations,
            g.cost.forward_time_s,
            g.cost.gradient_time_s,
            100.0 * g.cost.gradient_time_s / g.cost.forward_time_s.max(1e-12)
        );
        if let Some(k) = g.folded_elements.filter(|&k| k > 0) {
            println!(
                "  warning: {k} elements fold between their quadrature points at this state, and the cavity surface passes into the material by {:.3} mm: the mesh does not represent it (the gradients are the discrete model's)",
                g.penetration_mm.unwrap_or(f64::NAN)
            );
        }
        for (f, grad) in &g.gradients {
            let parts: Vec<String> = grad.iter().map(|(k, d)| format!("{k} {d:+.5e}")).collect();
            println!("  {f} = {:.6e}; d/d: {}", g.values[f], parts.join(", "));
        }
    }
    for (name, o) in &dg.omega {
        let parts: Vec<String> = o.gradient.iter().map(|(k, d)| format!("{k} {d:+.5e}")).collect();
        println!("omega ({name}) = {:.4} J/m3; d/d: {}", o.value, parts.join(", "));
    }
    if args.check_fd {
        let mut worst: f64 = 0.0;
        for &kind in &v.scenes {
            let name = kind.name();
            let g = &dg.scenes[name];
            let t = std::time::Instant::now();
            let rep = fd_check(&v.geometry, &opts, kind, g, &args.fd_steps);
            let m = max_rel_error(&rep);
            worst = worst.max(m);
            println!("{name}: finite differences in {:.1} s, max relative error {m:.2e}", t.elapsed().as_secs_f64());
            doc["scenes"][name]["fd"] = serde_json::to_value(&rep)?;
            doc["scenes"][name]["max_rel_error"] = json!(m);
        }
        doc["max_rel_error"] = json!(worst);
        doc["fd_steps"] = json!(args.fd_steps);
    }
    let path = args.out.join("gradient.json");
    crate::evaluate::write_json_atomic(&path, &doc)?;
    println!("wrote {}", path.display());
    Ok(())
}
