//! `verify`: an optimiser's best design against a sweep's best.
//!
//! Reads `SWEEP_DIR/manifest.json` + `results.jsonl` and `OPT_DIR/best.json`, whose keys are
//! (exactly) `r_mm, l_mm, alpha_deg` (the design-space parameters by name), `p_kPa, theta_deg,
//! tau_Nm, omega_J_m3, max_radius_mm, evaluations, status`. Compares the objective (Ω of the
//! problem's primary mode, by the letter's rule), the distance between the two designs (in
//! variables scaled to [0, 1] by the Table-I bounds, and per parameter), feasibility (optimiser:
//! status `ok`/`converged`/… not a failure and max radius ≤ the ballooning limit) and the ratio
//! of FE design evaluations (sweep rows that ran the FE model / optimiser evaluations).

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::Path;

use super::{read_rows, Manifest, ModeSummary, Row, RESULTS};
use crate::geometry::DesignSpace;
use crate::problem::Problem;

/// The optimiser's best design (`best.json`).
#[derive(Clone, Debug, PartialEq)]
pub struct OptimiserBest {
    pub design: BTreeMap<String, f64>,
    pub p_kpa: Option<f64>,
    pub theta_deg: Option<f64>,
    pub tau_nm: Option<f64>,
    pub omega_j_m3: f64,
    pub max_radius_mm: Option<f64>,
    pub evaluations: u64,
    pub status: String,
}

/// Keys of best.json besides the design parameters.
pub const BEST_KEYS: [&str; 7] = ["p_kPa", "theta_deg", "tau_Nm", "omega_J_m3", "max_radius_mm", "evaluations", "status"];

/// Read `DIR/best.json`.
/// The `[fidelity]` an optimiser directory's single-stage run used (`input.json`'s
/// problem.fidelity); None when unknown or when the run had stages (each stage has its own).
fn optimiser_fidelity(dir: &Path) -> Option<Value> {
    let v: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("input.json")).ok()?).ok()?;
    let pr = v.get("problem")?;
    if pr.pointer("/optimise/stages").and_then(Value::as_array).is_some_and(|a| !a.is_empty()) {
        return None;
    }
    pr.get("fidelity").cloned()
}

/// Two `[fidelity]` tables name the same model: the same preset / mesh and the same reduced
/// model (or none); fallback thresholds and the like do not change the model's answer.
fn same_fidelity(a: &Value, b: Option<&Value>) -> bool {
    let key = |v: Option<&Value>, k: &str| v.and_then(|v| v.get(k)).filter(|x| !x.is_null()).cloned();
    ["preset", "mesh", "rom"].iter().all(|k| key(Some(a), k) == key(b, k))
}

pub fn read_best(dir: &Path) -> Result<OptimiserBest> {
    let p = dir.join("best.json");
    let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let v: Value = serde_json::from_str(&text).map_err(|e| anyhow!("{}: not JSON ({e})", p.display()))?;
    let o = v.as_object().ok_or_else(|| anyhow!("{}: expected a JSON object", p.display()))?;
    let space = DesignSpace::actuator();
    let required: Vec<&str> = space.names().into_iter().chain(BEST_KEYS).collect();
    let missing: Vec<&str> = required.iter().copied().filter(|k| !o.contains_key(*k)).collect();
    if !missing.is_empty() {
        bail!("{}: missing key(s) {} (required: {})", p.display(), missing.join(", "), required.join(", "));
    }
    let num = |k: &str| -> Result<Option<f64>> {
        match o.get(k) {
            None => bail!("{}: missing key '{k}'", p.display()),
            Some(Value::Null) => Ok(None),
            Some(x) => x.as_f64().filter(|x| x.is_finite()).map(Some).ok_or_else(|| anyhow!("{}: '{k}' must be a finite number or null", p.display())),
        }
    };
    let mut design = BTreeMap::new();
    for par in &DesignSpace::actuator().params {
        design.insert(par.name.clone(), num(&par.name)?.ok_or_else(|| anyhow!("{}: '{}' is null", p.display(), par.name))?);
    }
    let evaluations = match o.get("evaluations") {
        None => bail!("{}: missing key 'evaluations'", p.display()),
        Some(x) => x.as_u64().ok_or_else(|| anyhow!("{}: 'evaluations' must be a non-negative integer", p.display()))?,
    };
    let status = match o.get("status") {
        None => bail!("{}: missing key 'status'", p.display()),
        Some(x) => x.as_str().ok_or_else(|| anyhow!("{}: 'status' must be a string", p.display()))?.to_string(),
    };
    Ok(OptimiserBest {
        design,
        p_kpa: num("p_kPa")?,
        theta_deg: num("theta_deg")?,
        tau_nm: num("tau_Nm")?,
        omega_j_m3: num("omega_J_m3")?.ok_or_else(|| anyhow!("{}: 'omega_J_m3' is null", p.display()))?,
        max_radius_mm: num("max_radius_mm")?,
        evaluations,
        status,
    })
}

/// Scaled Euclidean distance and per-parameter differences (b − a) between two designs.
pub fn design_distance(a: &BTreeMap<String, f64>, b: &BTreeMap<String, f64>) -> (f64, Value) {
    let mut sum = 0.0;
    let mut per = serde_json::Map::new();
    for p in &DesignSpace::actuator().params {
        let (Some(x), Some(y)) = (a.get(&p.name), b.get(&p.name)) else {
            continue;
        };
        let scaled = (y - x) / (p.max - p.min);
        sum += scaled * scaled;
        per.insert(p.name.clone(), json!({"a": x, "b": y, "diff": y - x, "scaled_diff": scaled, "unit": p.unit}));
    }
    (sum.sqrt(), Value::Object(per))
}

/// Statuses of an optimiser result that mean it failed.
const FAILED: [&str; 5] = ["error", "failed", "model-error", "invalid-geometry", "no-common-pressure"];

/// Compare; returns verify.json's content and the summary paragraph.
/// A row's values in `mode` (None: the row's primary mode).
fn mode_of<'a>(r: &'a Row, mode: Option<&str>) -> Option<&'a ModeSummary> {
    match mode {
        None => Some(&r.primary),
        Some(m) => r.modes.get(m),
    }
}

/// Compare in the sweep rows' primary mode, or in `mode` (`combined` / `pure-twist`) when the
/// sweep ran both pairs of scenes.
pub fn verify(problem: &Problem, sweep_dir: &Path, opt_dir: &Path, mode: Option<&str>) -> Result<(Value, String)> {
    let manifest = Manifest::read(sweep_dir)?.ok_or_else(|| anyhow!("{}: no manifest.json (not a sweep directory)", sweep_dir.display()))?;
    let mut rows: Vec<Row> = read_rows(&sweep_dir.join(RESULTS))?.rows;
    super::refresh_feasibility(&mut rows, &manifest);
    let best = read_best(opt_dir)?;
    let limit = problem.scenes.ballooning_limit_mm;
    let mut warnings = Vec::new();
    // the problem the sweep ran against this one (sections that change Ω)
    let ours = serde_json::to_value(problem)?;
    for k in ["material", "scenes", "fidelity"] {
        if manifest.problem.get(k) != ours.get(k) {
            warnings.push(format!("the sweep's [{k}] differs from this problem's"));
        }
    }
    // the optimiser's fidelity (its input.json, single-stage runs) against the sweep's: Ω at two
    // fidelities is not comparable, so its own Ω is then not called within 1 % (the letter's-rule
    // row below evaluates its design at the sweep's fidelity)
    let other_fidelity = optimiser_fidelity(opt_dir).filter(|f| !same_fidelity(f, manifest.problem.get("fidelity")));
    if let Some(f) = &other_fidelity {
        warnings.push(format!(
            "the optimiser ran at another fidelity ({f}) than the sweep ({}): its own Ω is not compared; see its design evaluated at the sweep's fidelity",
            manifest.problem.get("fidelity").map_or("?".into(), |v| v.to_string())
        ));
    }
    let complete = rows.len() as u64 == manifest.n_designs;
    if !complete {
        warnings.push(format!("the sweep is incomplete: {} of {} designs", rows.len(), manifest.n_designs));
    }
    if let Some(m) = mode {
        if !["combined", "pure-twist"].contains(&m) {
            bail!("--mode '{m}': expected combined or pure-twist");
        }
    }
    let (sb, sm) = rows
        .iter()
        .filter(|r| r.status == "ok")
        .filter_map(|r| mode_of(r, mode).filter(|m| m.feasible && m.omega_j_m3.is_some()).map(|m| (r, m)))
        .max_by(|a, b| a.1.omega_j_m3.unwrap_or(f64::NEG_INFINITY).total_cmp(&b.1.omega_j_m3.unwrap_or(f64::NEG_INFINITY)).then(b.0.index.cmp(&a.0.index)))
        .ok_or_else(|| anyhow!("{}: no feasible design with an energy density{} among {} rows", sweep_dir.display(), mode.map(|m| format!(" in mode {m}")).unwrap_or_default(), rows.len()))?;
    let mode_name = mode.map(str::to_string).or_else(|| sb.mode.clone()).unwrap_or_else(|| "combined".into());
    let s_omega = sm.omega_j_m3.unwrap_or(f64::NAN);
    let fe_rows = rows.iter().filter(|r| r.status != "invalid-geometry").count() as u64;
    let rel = (best.omega_j_m3 - s_omega) / s_omega.abs();
    let within = rel >= -0.01 && other_fidelity.is_none();
    let (dist, per) = design_distance(&sb.design, &best.design);
    let opt_feasible = !FAILED.contains(&best.status.as_str()) && best.max_radius_mm.is_some_and(|r| super::within_radius_limit(r, limit));
    let ratio = if best.evaluations > 0 { Some(fe_rows as f64 / best.evaluations as f64) } else { None };
    // the sweep design nearest to the optimiser's
    let nearest = rows.iter().filter(|r| r.status == "ok").map(|r| (design_distance(&r.design, &best.design).0, r)).min_by(|a, b| a.0.total_cmp(&b.0)).map(
        |(d, r)| json!({"id": r.id, "design": r.design, "scaled_distance": d, "omega_J_m3": mode_of(r, mode).and_then(|m| m.omega_j_m3), "feasible": mode_of(r, mode).is_some_and(|m| m.feasible)}),
    );
    // the optimiser's design as a sweep row: ramped to failure at the sweep's fidelity, Ω by the
    // letter's rule (at the lower failure pressure, or where the max radius reaches the limit).
    // The optimiser's own Ω is taken at its pressure variable, which the stability constraint
    // keeps STABILITY_MARGIN below the lowest pressure maximum; the grid's is at the failure
    // pressure itself. This row compares the designs by one rule.
    let rule = letter_rule_row(problem, &best.design, manifest.grid.range).map(|row| {
        let m = mode_of(&row, mode).cloned();
        let om = m.as_ref().and_then(|m| m.omega_j_m3);
        let feasible = row.status == "ok" && m.as_ref().is_some_and(|m| m.feasible);
        let rel = om.map(|o| (o - s_omega) / s_omega.abs());
        json!({
            "status": row.status, "cause": row.cause, "omega_J_m3": om, "p_kPa": m.as_ref().and_then(|m| m.p_omega_kpa),
            "theta_deg": m.as_ref().and_then(|m| m.theta_omega_deg), "tau_Nm": m.as_ref().and_then(|m| m.tau_omega_nm),
            "max_radius_mm": m.as_ref().and_then(|m| m.max_radius_mm), "feasible": feasible,
            "omega_relative_difference": rel, "within_1_percent": feasible && rel.is_some_and(|r| r >= -0.01),
            "wall_time_s": row.wall_time_s,
        })
    });
    let rule = rule.unwrap_or_else(|e| json!({"status": "error", "cause": format!("{e:#}")}));
    let v = json!({
        "objective": format!("omega_J_m3 ({mode_name} mode, the letter's rule)"),
        "mode": mode_name,
        "ballooning_limit_mm": limit,
        "sweep": {
            "dir": sweep_dir.display().to_string(),
            "grid": manifest.grid.name,
            "n_designs": manifest.n_designs,
            "rows": rows.len(),
            "complete": complete,
            "fidelity": manifest.fidelity,
            "fe_evaluations": fe_rows,
            "best": {"id": sb.id, "design": sb.design, "omega_J_m3": s_omega, "p_kPa": sm.p_omega_kpa,
                     "theta_deg": sm.theta_omega_deg, "tau_Nm": sm.tau_omega_nm,
                     "max_radius_mm": sm.max_radius_mm, "feasible": sm.feasible},
        },
        "optimiser": {
            "dir": opt_dir.display().to_string(),
            "design": best.design, "omega_J_m3": best.omega_j_m3, "p_kPa": best.p_kpa, "theta_deg": best.theta_deg,
            "tau_Nm": best.tau_nm, "max_radius_mm": best.max_radius_mm, "evaluations": best.evaluations,
            "status": best.status, "feasible": opt_feasible,
        },
        "omega_relative_difference": rel,
        "within_1_percent": within,
        "optimiser_design_by_the_letters_rule": rule,
        "scaled_distance": dist,
        "per_parameter": per,
        "evaluation_ratio": ratio,
        "at_least_100x_fewer_evaluations": ratio.is_some_and(|r| r >= 100.0),
        "nearest_sweep_design": nearest,
        "warnings": warnings,
    });
    let fmt_design = |d: &BTreeMap<String, f64>| d.iter().map(|(k, x)| format!("{k} = {x:.4}")).collect::<Vec<_>>().join(", ");
    let summary = format!(
        "In the {mode_name} mode, the optimiser's best design ({}; status {}, {}) reaches Ω = {:.2} J/m³, {:+.2} % relative to the sweep's best feasible design ({}; Ω = {:.2} J/m³ at p = {} kPa) on the {} grid ({} of {} designs, {} FE design evaluations, fidelity {}), so it is {} 1 % of it. The two designs are {:.4} apart in variables scaled to [0, 1] by the Table-I bounds. The optimiser used {} design evaluations, {} than the sweep{}.{}",
        fmt_design(&best.design),
        best.status,
        if opt_feasible { "feasible" } else { "not feasible" },
        best.omega_j_m3,
        100.0 * rel,
        fmt_design(&sb.design),
        s_omega,
        sm.p_omega_kpa.map(|p| format!("{p:.2}")).unwrap_or_else(|| "?".into()),
        manifest.grid.name,
        rows.len(),
        manifest.n_designs,
        fe_rows,
        manifest.fidelity,
        if within { "within" } else { "not within" },
        dist,
        best.evaluations,
        match ratio {
            Some(r) => format!("{r:.1}× fewer"),
            None => "no fewer (zero evaluations reported)".into(),
        },
        match ratio {
            Some(r) if r >= 100.0 => " (at least 100× fewer, as required)",
            Some(_) => " (less than the required 100×)",
            None => "",
        },
        if warnings.is_empty() { String::new() } else { format!(" Warnings: {}.", warnings.join("; ")) },
    );
    let summary = match (v["optimiser_design_by_the_letters_rule"]["omega_J_m3"].as_f64(), v["optimiser_design_by_the_letters_rule"]["omega_relative_difference"].as_f64()) {
        (Some(o), Some(r)) => format!(
            "{summary} Evaluated as the sweep evaluates a design (ramped to failure, Ω by the letter's rule at p = {} kPa; the optimiser keeps p {:.0} % below the pressure maximum), the optimiser's design reaches Ω = {o:.2} J/m³, {:+.2} % relative to the sweep's best ({}).",
            v["optimiser_design_by_the_letters_rule"]["p_kPa"].as_f64().map(|p| format!("{p:.2}")).unwrap_or_else(|| "?".into()),
            100.0 * crate::optimise::STABILITY_MARGIN,
            100.0 * r,
            if v["optimiser_design_by_the_letters_rule"]["within_1_percent"].as_bool() == Some(true) { "within 1 %" } else { "not within 1 %" },
        ),
        _ => format!("{summary} The optimiser's design could not be evaluated by the letter's rule: {}.", v["optimiser_design_by_the_letters_rule"]["cause"].as_str().unwrap_or("?")),
    };
    Ok((v, summary))
}

/// `design` evaluated as a sweep row of `problem` (its scenes, fidelity and ramp bound).
fn letter_rule_row(problem: &Problem, design: &BTreeMap<String, f64>, range: crate::geometry::RangePolicy) -> Result<Row> {
    let v = problem.validate()?;
    let mut opts = problem.scene_options(&v);
    opts.keep_fields = false;
    let p_max = match v.load {
        crate::problem::LoadPlan::Ramp(p) => p,
        crate::problem::LoadPlan::Targets(_) => bail!("load: give load.p_max_kPa (the sweep's ramp bound)"),
    };
    let d = crate::geometry::Design { values: design.clone(), variant: problem.design.variant };
    Ok(super::evaluate_design_guarded(0, &d, range, &v, &opts, p_max))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fidelity_mismatch_is_the_model_not_the_fallback() {
        let rom = json!({"preset": "sweep", "rom": "studies/rom/a", "rom_fallback": null});
        assert!(same_fidelity(&rom, Some(&json!({"preset": "sweep", "rom": "studies/rom/a", "rom_fallback": 0.1}))));
        assert!(!same_fidelity(&rom, Some(&json!({"preset": "sweep"}))), "reduced vs full model");
        assert!(!same_fidelity(&json!({"preset": "sweep"}), Some(&json!({"preset": "default"}))));
        assert!(same_fidelity(&json!({"preset": "sweep", "mesh": null}), Some(&json!({"preset": "sweep"}))));
        assert!(!same_fidelity(&json!({"preset": "sweep"}), None));
        // a staged run's fidelity is unknown here: no warning
        let dir = std::env::temp_dir().join(format!("twistopt-verify-fid-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("input.json"), r#"{"problem": {"fidelity": {"preset": "coarse"}, "optimise": {"stages": [{"mesh": "default"}]}}}"#).unwrap();
        assert_eq!(optimiser_fidelity(&dir), None);
        std::fs::write(dir.join("input.json"), r#"{"problem": {"fidelity": {"preset": "coarse"}, "optimise": {"stages": []}}}"#).unwrap();
        assert_eq!(optimiser_fidelity(&dir), Some(json!({"preset": "coarse"})));
        std::fs::remove_dir_all(&dir).ok();
    }
}
