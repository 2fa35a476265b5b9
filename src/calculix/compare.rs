//! twistopt and CalculiX side by side on the same scenes, design, material and mesh.

use anyhow::{Context, Result};
use serde_json::{json, Value};
use std::path::Path;

use super::{build_deck, ccx_version, run_deck, CcxRun, CcxState, DeckOptions};
use crate::evaluate::select_steps;
use crate::problem::{Problem, Validated};
use crate::scene::{run_pressure, SceneKind, SceneResult, StepRecord};

/// (a − b)/|b|, or None when the reference is (numerically) zero, i.e. a held quantity.
pub fn rel_diff(a: f64, b: f64, floor: f64) -> Option<f64> {
    if b.abs() <= floor || !a.is_finite() || !b.is_finite() {
        None
    } else {
        Some((a - b) / b.abs())
    }
}

fn same_p(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
}

/// One scene run by both codes.
pub struct SceneCheck {
    pub scene: SceneKind,
    pub twistopt: SceneResult,
    pub ccx: CcxRun,
    pub rows: Vec<Value>,
}

/// Compare one pressure: twistopt step vs ccx state. θ is compared where the cap rotation is
/// free, τ where it is held (elsewhere they are zero up to the solvers' tolerances).
fn row(scene: SceneKind, t: &StepRecord, c: &CcxState) -> Value {
    let free = scene.rotation_free();
    json!({
        "p_kPa": c.p_kpa,
        "twistopt": {"theta_deg": t.theta_deg, "tau_Nm": t.tau_nm, "axial_mm": t.axial_mm, "max_radius_mm": t.max_radius_mm},
        "ccx": c,
        "rel_diff": {
            "theta": if free { rel_diff(t.theta_deg, c.theta_deg, 1e-6) } else { None },
            "tau": if free { None } else { rel_diff(t.tau_nm, c.tau_nm, 1e-9) },
            "axial": rel_diff(t.axial_mm, c.axial_mm, 1e-9),
            "max_radius": rel_diff(t.max_radius_mm, c.max_radius_mm, 1e-9),
        },
    })
}

/// Which element twistopt uses in a cross-check.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TwistoptElement {
    /// the problem's element (Q2/P1 Hex27): the production model against ccx's element
    Standard,
    /// the ccx element's own discretisation ([`super::CcxElement::matched_formulation`]): the
    /// same discrete problem solved by two independent codes
    Matched,
}

impl TwistoptElement {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "standard" => Ok(TwistoptElement::Standard),
            "matched" => Ok(TwistoptElement::Matched),
            _ => anyhow::bail!("unknown twistopt element '{s}' (expected standard or matched)"),
        }
    }
}

/// Run one scene with both codes. ccx runs in `dir/<scene>/` with `threads` OpenMP threads.
#[allow(clippy::too_many_arguments)]
pub fn check_scene(problem: &Problem, v: &Validated, scene: SceneKind, deck_opts: &DeckOptions, twistopt_element: TwistoptElement, ccx: &str, dir: &Path, threads: usize) -> Result<SceneCheck> {
    let mut opts = problem.scene_options(v);
    opts.keep_fields = false;
    if twistopt_element == TwistoptElement::Matched {
        opts.formulation = deck_opts.element.matched_formulation().ok_or_else(|| anyhow::anyhow!("twistopt has no formulation matching {} (use C3D20R or C3D20)", deck_opts.element.name()))?;
    }
    let targets = v.load.targets();
    let mut tw = match run_pressure(&v.geometry, &opts, scene, &targets) {
        Ok(r) => r,
        Err(e) => SceneResult::model_error(scene, e.to_string().replace('\n', " ")),
    };
    select_steps(&mut tw, &v.load);
    let deck = build_deck(&v.geometry, &v.mesh, &v.material, scene, &targets, deck_opts)?;
    let run = run_deck(ccx, &deck, &dir.join(scene.name()), scene.name(), threads)?;
    let mut rows = Vec::new();
    for c in &run.states {
        if c.p_kpa == 0.0 {
            continue;
        }
        if let Some(t) = tw.steps.iter().find(|s| same_p(s.p_kpa, c.p_kpa)) {
            rows.push(row(scene, t, c));
        }
    }
    Ok(SceneCheck { scene, twistopt: tw, ccx: run, rows })
}

/// Run the scenes with both codes and write `out/crosscheck.json`; returns its content.
/// `log` receives progress and the side-by-side table.
pub fn crosscheck(problem: &Problem, scenes: &[SceneKind], deck_opts: &DeckOptions, twistopt_element: TwistoptElement, ccx: &str, out: &Path, log: impl Fn(&str)) -> Result<Value> {
    let v = problem.validate()?;
    let version = ccx_version(ccx)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create output directory {}", out.display()))?;
    let threads = rayon::current_num_threads();
    let mut scenes_json = serde_json::Map::new();
    for &scene in scenes {
        log(&format!("scene {}: twistopt, then ccx ({}) ...", scene.name(), deck_opts.element.name()));
        let c = check_scene(problem, &v, scene, deck_opts, twistopt_element, ccx, out, threads)?;
        log(&format!(
            "scene {}: twistopt {} in {:.1} s ({} dofs, {} Newton iterations); ccx {} in {:.1} s ({} equations, {} increments, {} iterations)",
            scene.name(),
            c.twistopt.status,
            c.twistopt.wall_time_s,
            c.twistopt.dofs,
            c.twistopt.newton_iterations,
            c.ccx.status,
            c.ccx.wall_time_s,
            c.ccx.equations.map(|e| e.to_string()).unwrap_or("?".into()),
            c.ccx.increments,
            c.ccx.iterations
        ));
        if !c.ccx.cause.is_empty() {
            log(&format!("  ccx: {}", c.ccx.cause));
        }
        if !c.twistopt.cause.is_empty() {
            log(&format!("  twistopt: {}", c.twistopt.cause));
        }
        log(&format!(
            "  {:>8} | {:>10} {:>10} {:>8} | {:>10} {:>10} {:>8} | {:>8} {:>8} {:>8}",
            "p kPa", "θ° twist", "θ° ccx", "rel θ", "τ Nm twist", "τ Nm ccx", "rel τ", "r twist", "r ccx", "rel r"
        ));
        let pct = |v: &Value| v.as_f64().map(|x| format!("{:+.2}%", 100.0 * x)).unwrap_or("-".into());
        for r in &c.rows {
            log(&format!(
                "  {:>8} | {:>10.4} {:>10.4} {:>8} | {:>10.5} {:>10.5} {:>8} | {:>8.3} {:>8.3} {:>8}",
                r["p_kPa"],
                r["twistopt"]["theta_deg"].as_f64().unwrap_or(f64::NAN),
                r["ccx"]["theta_deg"].as_f64().unwrap_or(f64::NAN),
                pct(&r["rel_diff"]["theta"]),
                r["twistopt"]["tau_Nm"].as_f64().unwrap_or(f64::NAN),
                r["ccx"]["tau_Nm"].as_f64().unwrap_or(f64::NAN),
                pct(&r["rel_diff"]["tau"]),
                r["twistopt"]["max_radius_mm"].as_f64().unwrap_or(f64::NAN),
                r["ccx"]["max_radius_mm"].as_f64().unwrap_or(f64::NAN),
                pct(&r["rel_diff"]["max_radius"]),
            ));
        }
        scenes_json.insert(
            scene.name().to_string(),
            json!({
                "twistopt": {
                    "status": c.twistopt.status,
                    "cause": c.twistopt.cause,
                    "dofs": c.twistopt.dofs,
                    "elements": c.twistopt.elements,
                    "newton_iterations": c.twistopt.newton_iterations,
                    "wall_time_s": c.twistopt.wall_time_s,
                    "steps": c.twistopt.steps,
                },
                "ccx": c.ccx,
                "comparison": c.rows,
            }),
        );
    }
    let mut opts = problem.scene_options(&v);
    if twistopt_element == TwistoptElement::Matched {
        if let Some(f) = deck_opts.element.matched_formulation() {
            opts.formulation = f;
        }
    }
    let result = json!({
        "problem": problem,
        "mesh": v.mesh.size_string(),
        "twistopt": {
            "model": if opts.sector { "120° sector with cyclic symmetry" } else { "full 360°" },
            "element": twistopt_element,
            "formulation": format!("{:?}", opts.formulation),
            "threads": threads,
        },
        "ccx": {
            "command": ccx,
            "version": version,
            "element": deck_opts.element.name(),
            "model": "full 360°, cap lateral translations and tilts held",
            "increments": deck_opts.increments,
            "threads": threads,
        },
        "rel_diff_definition": "(twistopt - ccx) / |ccx|; theta only where the cap rotation is free, tau only where it is held (null otherwise)",
        "scenes": Value::Object(scenes_json),
    });
    let path = out.join("crosscheck.json");
    std::fs::write(&path, serde_json::to_string_pretty(&result)?).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(result)
}
