//! `evaluate`: run a [`Problem`]'s scenes and write result.json, CSV tables, plots and ParaView
//! series to an output directory.
//!
//! Solver failures (ballooning, inversion, limit point, self-contact, …) are results, not errors:
//! the scene's `status` and `cause` say what ended it and every file is still written with the
//! steps it reached. Errors are reserved for bad input and I/O.
//!
//! # Energy density (the letter's rule)
//!
//! For the pair `free` + `blocked` (combined mode) and the pair `pure-twist` +
//! `pure-twist-blocked`: the common pressure is the lower of the two scenes' highest converged
//! positive pressures; θ (free scene) and τ (blocked scene) are linearly interpolated between
//! recorded steps at that pressure and Ω = τθ/(8V), V = πR0²L ([`energy_density`]). θ is signed
//! about +z and the letter states no sign convention, so |θ| and |τ| are used when θ and τ have
//! the same sign (the blocked actuator pushes the way it would turn); otherwise Ω is reported
//! signed (≤ 0) and `abs_values_used = false` says so. The same is done for the vacuum branch
//! (the two scenes' least negative final pressures) and at every requested pressure both scenes
//! reached (`omega_by_pressure`).

use anyhow::{Context, Result};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

use crate::export::{write_pvd, write_vtu, DataArray};
use crate::plot::{line_plot, LinePlot, Series};
use crate::problem::{LoadPlan, Problem, Validated};
use crate::scene::{energy_density, run_pressure, run_torque_rotation, SceneKind, SceneResult, SceneStatus, StepRecord, TorqueRotation};

/// Write pretty JSON through a temporary file and a rename, so that an interrupted run never
/// leaves a truncated file (non-finite numbers become null).
pub fn write_json_atomic(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value)? + "\n";
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}

/// Append one JSON line (a single write, then fsync) for resumable result files; a line torn by
/// a kill is ended first, so the new row stays a line of its own.
pub fn append_json_line(path: &Path, row: &impl serde::Serialize) -> Result<()> {
    use std::io::Write;
    let torn = std::fs::read(path).map(|b| b.last().is_some_and(|&c| c != b'\n')).unwrap_or(false);
    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut line = if torn { "\n".to_string() } else { String::new() };
    line += &serde_json::to_string(row)?;
    line.push('\n');
    f.write_all(line.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
    f.sync_all()?;
    Ok(())
}

/// The complete JSON lines of a file written by [`append_json_line`] (a torn or missing file
/// gives the lines that parse; none when it does not exist).
pub fn read_json_lines(path: &Path) -> Vec<serde_json::Value> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect()
}

/// Process CPU time (user + system, all threads) in seconds, from /proc/self/stat (NaN where
/// that is not available).
pub fn process_cpu_time_s() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            // fields 14, 15 of stat (utime, stime) are 12, 13 after the ')' (state is field 3)
            let u: f64 = f.get(11)?.parse().ok()?;
            let k: f64 = f.get(12)?.parse().ok()?;
            Some((u + k) / 100.0)
        })
        .unwrap_or(f64::NAN)
}

/// What model a result comes from: the full FE model, or a reduced one (its directory, sizes and
/// the errors measured when it was trained).
pub fn fidelity_json(v: &crate::problem::Validated) -> Value {
    match &v.rom {
        None => json!({ "model": "full" }),
        Some((rom, m)) => json!({
            "model": "reduced",
            "modes": rom.basis.k,
            "pressure_modes": rom.basis.pressure.as_ref().map_or(0, |p| p.kp),
            "sample_elements": rom.sample.distinct_elements().len(),
            "sample_points": rom.sample.points.len(),
            "elements": m.report.elements,
            "format_version": m.format_version,
            "training_designs": m.report.training_designs.len(),
            "validation": m.validation.as_ref().map(|x| json!({ "designs": x["designs"], "omega_rel_error": x["omega_rel_error"], "p_end_rel_error": x["p_end_rel_error"] })),
        }),
    }
}

/// Relative tolerance for matching recorded pressures to requested ones.
const P_TOL: f64 = 1e-9;

fn same_p(a: f64, b: f64) -> bool {
    (a - b).abs() <= P_TOL * (1.0 + a.abs().max(b.abs()))
}

fn step_finite(s: &StepRecord) -> bool {
    [s.p_kpa, s.theta_deg, s.axial_mm, s.tau_nm, s.max_radius_mm, s.cavity_volume_mm3, s.min_det_f].iter().all(|v| v.is_finite())
}

/// Keep the steps to report: with a list of target pressures, the unloaded state, the states at
/// the targets, and the last converged state of a branch that stopped before its last target;
/// with a ramp, every converged step. Non-finite records are dropped. Fields follow the steps.
pub fn select_steps(r: &mut SceneResult, plan: &LoadPlan) {
    let n = r.steps.len();
    let keep: Vec<bool> = match plan {
        LoadPlan::Ramp(_) => vec![true; n],
        LoadPlan::Targets(t) => {
            let pmax = r.steps.iter().map(|s| s.p_kpa).fold(f64::NEG_INFINITY, f64::max);
            let pmin = r.steps.iter().map(|s| s.p_kpa).fold(f64::INFINITY, f64::min);
            let tmax = t.iter().copied().fold(0.0, f64::max);
            let tmin = t.iter().copied().fold(0.0, f64::min);
            r.steps
                .iter()
                .map(|s| {
                    s.p_kpa == 0.0 || t.iter().any(|&p| same_p(p, s.p_kpa)) || (s.p_kpa > 0.0 && s.p_kpa == pmax && !same_p(pmax, tmax)) || (s.p_kpa < 0.0 && s.p_kpa == pmin && !same_p(pmin, tmin))
                })
                .collect()
        }
    };
    let keep: Vec<bool> = keep.iter().zip(&r.steps).map(|(k, s)| *k && step_finite(s)).collect();
    let mut steps = Vec::new();
    let mut seen_zero = false;
    let mut idx = Vec::new();
    for (i, s) in r.steps.iter().enumerate() {
        if !keep[i] || (s.p_kpa == 0.0 && seen_zero) {
            continue;
        }
        seen_zero |= s.p_kpa == 0.0;
        let mut s = s.clone();
        if let LoadPlan::Targets(t) = plan {
            if let Some(&p) = t.iter().find(|&&p| same_p(p, s.p_kpa)) {
                s.p_kpa = p;
            }
        }
        steps.push(s);
        idx.push(i);
    }
    r.steps = steps;
    if let Some(f) = r.fields.as_mut() {
        f.displacements = idx.iter().filter_map(|&i| f.displacements.get(i).cloned()).collect();
    }
    if r.states.len() == n {
        r.states = idx.iter().map(|&i| r.states[i].clone()).collect();
    } else {
        r.states.clear();
    }
}

/// Linear interpolation of `value` over steps sorted by pressure; None outside the range.
pub fn interpolate(steps: &[StepRecord], p: f64, value: impl Fn(&StepRecord) -> f64) -> Option<f64> {
    let mut s: Vec<&StepRecord> = steps.iter().collect();
    s.sort_by(|a, b| a.p_kpa.total_cmp(&b.p_kpa));
    if let Some(x) = s.iter().find(|x| same_p(x.p_kpa, p)) {
        return Some(value(x));
    }
    s.windows(2).find(|w| w[0].p_kpa <= p && p <= w[1].p_kpa).map(|w| {
        let t = (p - w[0].p_kpa) / (w[1].p_kpa - w[0].p_kpa);
        value(w[0]) + t * (value(w[1]) - value(w[0]))
    })
}

/// θ, τ and Ω at one pressure (the letter's rule, see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OmegaPoint {
    #[serde(rename = "p_kPa")]
    pub p_kpa: f64,
    pub theta_deg: f64,
    #[serde(rename = "tau_Nm")]
    pub tau_nm: f64,
    /// θ and τ have the same sign, so |θ| and |τ| were used
    pub same_sign: bool,
    #[serde(rename = "omega_J_m3")]
    pub omega_j_m3: f64,
}

/// Ω at one pressure from a free and a blocked scene's steps, with the sign rule of the module
/// docs; None when either scene's steps do not reach `p`.
pub fn omega_at_pressure(free: &[StepRecord], blocked: &[StepRecord], p: f64) -> Option<OmegaPoint> {
    let theta = interpolate(free, p, |s| s.theta_deg)?;
    let tau = interpolate(blocked, p, |s| s.tau_nm)?;
    let same = theta * tau > 0.0;
    let omega = if same { energy_density(theta.abs(), tau.abs()) } else { energy_density(theta, tau) };
    Some(OmegaPoint { p_kpa: p, theta_deg: theta, tau_nm: tau, same_sign: same, omega_j_m3: omega })
}

/// The letter's common pressure of a free and a blocked scene on one branch (`positive` or
/// vacuum): (common, free's extreme, blocked's extreme) converged pressures, None when a scene
/// has no converged step on that branch.
pub fn common_pressure(free: &[StepRecord], blocked: &[StepRecord], positive: bool) -> Option<(f64, f64, f64)> {
    let extreme = |steps: &[StepRecord]| {
        steps.iter().map(|s| s.p_kpa).filter(|p| if positive { *p > 0.0 } else { *p < 0.0 }).fold(None, |acc: Option<f64>, p| {
            Some(match acc {
                None => p,
                Some(a) if positive => a.max(p),
                Some(a) => a.min(p),
            })
        })
    };
    let (pf, pb) = (extreme(free)?, extreme(blocked)?);
    Some((if positive { pf.min(pb) } else { pf.max(pb) }, pf, pb))
}

/// Give a (free-like, blocked-like) pair of scene results an exact step at their common pressure
/// on each branch ([`common_pressure`]: the lower of the two failure pressures), solved from the
/// nearest recorded state of the scene that lacks it, so that Ω by the letter's rule needs no
/// interpolation between steps.
pub fn complete_pair(geom: &crate::geometry::ActuatorGeometry, opts: &crate::scene::SceneOptions, free: &mut SceneResult, blocked: &mut SceneResult) {
    for positive in [true, false] {
        let Some((pc, _, _)) = common_pressure(&free.steps, &blocked.steps, positive) else {
            continue;
        };
        for r in [&mut *free, &mut *blocked] {
            if let Some(kind) = SceneKind::parse(&r.scene) {
                // a model that cannot be built leaves the result as it is (interpolated)
                let _ = crate::scene::add_step_at(geom, opts, kind, r, pc);
            }
        }
    }
}

/// Ω by the letter's rule on one branch: at the common pressure ([`common_pressure`]).
pub fn omega_letter(free: &[StepRecord], blocked: &[StepRecord], positive: bool) -> Option<OmegaPoint> {
    let (pc, _, _) = common_pressure(free, blocked, positive)?;
    omega_at_pressure(free, blocked, pc)
}

fn omega_at(free: &[StepRecord], blocked: &[StepRecord], p: f64) -> Option<Value> {
    let o = omega_at_pressure(free, blocked, p)?;
    Some(json!({
        "p_kPa": o.p_kpa,
        "theta_deg": o.theta_deg,
        "tau_Nm": o.tau_nm,
        "same_sign": o.same_sign,
        "abs_values_used": o.same_sign,
        "omega_J_m3": o.omega_j_m3,
    }))
}

/// Ω details for one pair of scenes: the letter's rule on each branch and the table at the
/// requested pressures.
fn omega_pair(free: &SceneResult, blocked: &SceneResult, requested: &[f64]) -> Value {
    let branch = |positive: bool| -> Value {
        match common_pressure(&free.steps, &blocked.steps, positive) {
            Some((pc, pf, pb)) => {
                let mut v = omega_at(&free.steps, &blocked.steps, pc).unwrap_or(Value::Null);
                if let Some(o) = v.as_object_mut() {
                    o.insert(format!("p_{}_reached_kPa", free.scene.replace('-', "_")), json!(pf));
                    o.insert(format!("p_{}_reached_kPa", blocked.scene.replace('-', "_")), json!(pb));
                }
                v
            }
            None => Value::Null,
        }
    };
    let positive = branch(true);
    let negative = branch(false);
    let table: Vec<Value> = requested.iter().filter_map(|&p| omega_at(&free.steps, &blocked.steps, p)).collect();
    let note = if positive.is_null() { format!("no positive pressure converged in both '{}' and '{}': Ω by the letter's rule does not apply", free.scene, blocked.scene) } else { String::new() };
    json!({
        "scenes": [free.scene, blocked.scene],
        "positive": positive,
        "negative": negative,
        "omega_by_pressure": table,
        "note": note,
    })
}

/// Where the outputs went and the JSON written.
pub struct Evaluation {
    pub result: Value,
    pub files: Vec<PathBuf>,
}

const CSV_HEADER: &str = "p_kPa,theta_deg,axial_mm,tau_Nm,max_radius_mm,cavity_volume_mm3,min_detF,newton_iterations";

/// A number for CSV: plain decimal for ordinary magnitudes, exponent form for tiny or huge ones.
fn num(v: f64) -> String {
    if v == 0.0 || (1e-4..1e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn write_scene_csv(path: &Path, r: &SceneResult) -> Result<()> {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for x in &r.steps {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{}\n",
            num(x.p_kpa),
            num(x.theta_deg),
            num(x.axial_mm),
            num(x.tau_nm),
            num(x.max_radius_mm),
            num(x.cavity_volume_mm3),
            num(x.min_det_f),
            x.newton_iterations
        ));
    }
    std::fs::write(path, s).with_context(|| format!("cannot write {}", path.display()))
}

fn write_scene_vtu(dir: &Path, r: &SceneResult) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let sub = dir.join(&r.scene);
    std::fs::create_dir_all(&sub).with_context(|| format!("cannot create {}", sub.display()))?;
    let mut entries = Vec::new();
    if let Some(f) = &r.fields {
        for (k, (step, u)) in r.steps.iter().zip(&f.displacements).enumerate() {
            let name = format!("{}/step_{k:03}.vtu", r.scene);
            let flat: Vec<f64> = u.iter().flatten().copied().collect();
            let vm = f.von_mises(k);
            write_vtu(&dir.join(&name), &f.mesh, &[DataArray::new("displacement", 3, &flat)], &[DataArray::new("von_mises_MPa", 1, &vm)])?;
            files.push(dir.join(&name));
            entries.push((step.p_kpa, name));
        }
    }
    let pvd = dir.join(format!("{}.pvd", r.scene));
    write_pvd(&pvd, &entries)?;
    files.push(pvd);
    Ok(files)
}

fn scene_json(r: &SceneResult) -> Value {
    // how far each pressure branch got (`status` is the positive branch's end, or the vacuum
    // branch's when the positive one completed)
    let pmax = r.steps.iter().map(|s| s.p_kpa).fold(0.0, f64::max);
    let pmin = r.steps.iter().map(|s| s.p_kpa).fold(0.0, f64::min);
    let mut v = json!({
        "status": r.status,
        "cause": r.cause,
        "p_reached_kPa": {"positive": pmax, "negative": pmin},
        "steps": r.steps,
        "dofs": r.dofs,
        "elements": r.elements,
        "newton_iterations": r.newton_iterations,
        "wall_time_s": r.wall_time_s,
        "rom_indicator": r.rom_indicator,
        "rom_fallback": r.rom_fallback,
    });
    if let Some(o) = v.as_object_mut() {
        // vacuum with contact: where the path snapped, and its closest approach of two walls
        if !r.snaps_kpa.is_empty() {
            o.insert("snaps_kPa".into(), json!(r.snaps_kpa));
        }
        if let Some(d) = r.min_contact_distance_mm {
            o.insert("min_contact_distance_mm".into(), json!(d));
        }
        // and what the contact leaves on the elements' own geometry (`SceneModel::integrity`)
        if let Some(d) = r.steps.iter().filter_map(|s| s.penetration_mm).reduce(f64::max) {
            o.insert("max_penetration_mm".into(), json!(d));
        }
        if let Some(k) = r.steps.iter().filter_map(|s| s.folded_elements).max() {
            o.insert("max_folded_elements".into(), json!(k));
        }
    }
    v
}

fn torque_json(mode: &str, t: &TorqueRotation) -> Value {
    let pts: Vec<Value> = t.points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()).map(|p| json!({"theta_deg": p.0, "tau_Nm": p.1})).collect();
    json!({
        "mode": mode,
        "p_kPa": t.p_kpa,
        "free_theta_deg": if t.free_theta_deg.is_finite() { t.free_theta_deg } else { 0.0 },
        "points": pts,
        "nonlinearity": if t.nonlinearity.is_finite() { t.nonlinearity } else { 0.0 },
        "status": t.status,
        "cause": t.cause,
    })
}

/// Run a problem and write every output to `out`. `log` receives progress lines.
pub fn evaluate(problem: &Problem, out: &Path, log: impl Fn(&str) + Sync) -> Result<Evaluation> {
    let t0 = std::time::Instant::now();
    let v: Validated = problem.validate()?;
    let opts = problem.scene_options(&v);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create output directory {}", out.display()))?;
    let mut files = Vec::new();
    let targets = v.load.targets();

    // scenes: independent models, run concurrently (as many at a time as rayon has threads;
    // the sparse factorisation is sequential, so this is where a second core pays off)
    let run_one = |kind: SceneKind| -> SceneResult {
        log(&format!("scene {} ...", kind.name()));
        let mut r = match run_pressure(&v.geometry, &opts, kind, &targets) {
            Ok(r) => r,
            Err(e) => SceneResult::model_error(kind, format!("{e}").replace('\n', " ")),
        };
        select_steps(&mut r, &v.load);
        let pmax = r.steps.iter().map(|s| s.p_kpa).fold(0.0, f64::max);
        let pmin = r.steps.iter().map(|s| s.p_kpa).fold(0.0, f64::min);
        log(&format!(
            "scene {}: {}{}; {} steps recorded, p from {pmin} to {pmax} kPa, {} dofs, {:.1} s{}",
            r.scene,
            r.status,
            if r.cause.is_empty() { String::new() } else { format!(" ({})", r.cause) },
            r.steps.len(),
            r.dofs,
            r.wall_time_s,
            r.rom_fallback.as_ref().map(|w| format!(" (full model: {w})")).unwrap_or_default()
        ));
        // self-contact keeps the nodes apart; say so where the elements' own faces still overlap
        let depth = r.steps.iter().filter_map(|s| s.penetration_mm).fold(0.0, f64::max);
        let folded = r.steps.iter().filter_map(|s| s.folded_elements).max().unwrap_or(0);
        if depth > 0.0 || folded > 0 {
            let first = r
                .steps
                .iter()
                .filter(|s| s.penetration_mm.is_some_and(|d| d > 0.0) || s.folded_elements.is_some_and(|k| k > 0))
                .map(|s| s.p_kpa)
                .min_by(|a, b| a.abs().total_cmp(&b.abs()))
                .unwrap_or(f64::NAN);
            let folds = if folded > 0 { format!(", and up to {folded} elements fold between their quadrature points") } else { String::new() };
            log(&format!(
                "scene {}: warning: from p = {first} kPa on, the cavity wall's own faces pass into the material by up to {depth:.3} mm (the contact keeps only its nodes off the facing wall){folds} (steps' penetration_mm and folded_elements in result.json)",
                r.scene
            ));
        }
        r
    };
    let concurrent = rayon::current_num_threads().clamp(1, 4);
    let mut results: Vec<SceneResult> = Vec::new();
    for group in v.scenes.chunks(concurrent) {
        let done: Vec<SceneResult> = std::thread::scope(|sc| {
            let handles: Vec<_> = group.iter().map(|&k| sc.spawn(move || run_one(k))).collect();
            handles.into_iter().zip(group).map(|(h, &k)| h.join().unwrap_or_else(|_| SceneResult::model_error(k, "the scene's thread panicked".into()))).collect()
        });
        results.extend(done);
    }
    // Ω's common pressures as exact steps of both scenes of each pair
    for (fk, bk) in [(SceneKind::Free, SceneKind::Blocked), (SceneKind::PureTwist, SceneKind::PureTwistBlocked)] {
        let (fi, bi) = (results.iter().position(|r| r.scene == fk.name()), results.iter().position(|r| r.scene == bk.name()));
        if let (Some(fi), Some(bi)) = (fi, bi) {
            let (a, b) = if fi < bi {
                let (l, r) = results.split_at_mut(bi);
                (&mut l[fi], &mut r[0])
            } else {
                let (l, r) = results.split_at_mut(fi);
                (&mut r[0], &mut l[bi])
            };
            complete_pair(&v.geometry, &opts, a, b);
        }
    }
    for r in &results {
        let csv = out.join(format!("{}.csv", r.scene));
        write_scene_csv(&csv, r)?;
        files.push(csv);
        if problem.output.vtu {
            files.extend(write_scene_vtu(out, r)?);
        }
    }
    let find = |k: SceneKind| results.iter().find(|r| r.scene == k.name());

    // energy density
    let mut omega = serde_json::Map::new();
    let v_m3 = std::f64::consts::PI * crate::geometry::R0_ENVELOPE.powi(2) * crate::geometry::L_TUBE * 1e-9;
    omega.insert(
        "rule".into(),
        json!("Omega = tau*theta/(8V), V = pi*R0^2*L; theta (free scene) and tau (blocked scene) linearly interpolated at the lower of the two scenes' highest converged positive pressures; |theta| and |tau| are used only when they have the same sign, otherwise Omega is signed"),
    );
    omega.insert("V_m3".into(), json!(v_m3));
    let mut top = serde_json::Map::new();
    for (label, key, fk, bk) in [("combined", "omega_J_m3", SceneKind::Free, SceneKind::Blocked), ("pure_twist", "omega_pure_twist_J_m3", SceneKind::PureTwist, SceneKind::PureTwistBlocked)] {
        if let (Some(f), Some(b)) = (find(fk), find(bk)) {
            let pair = omega_pair(f, b, &targets);
            top.insert(key.to_string(), pair["positive"].get("omega_J_m3").cloned().unwrap_or(Value::Null));
            omega.insert(label.into(), pair);
        }
    }

    // torque-rotation (Fig. 4b)
    let mut torque: Vec<(String, TorqueRotation)> = Vec::new();
    if let Some(tr) = &problem.torque_rotation {
        let mut topts = opts.clone();
        topts.keep_fields = false;
        for (mode, axial_free, fk, bk) in [("combined", true, SceneKind::Free, SceneKind::Blocked), ("pure-twist", false, SceneKind::PureTwist, SceneKind::PureTwistBlocked)] {
            if !(v.scenes.contains(&fk) && v.scenes.contains(&bk)) {
                continue;
            }
            log(&format!("torque-rotation ({mode}) at {:?} kPa ...", tr.pressures_kpa));
            match run_torque_rotation(&v.geometry, &topts, axial_free, &tr.pressures_kpa, tr.points) {
                Ok(list) => torque.extend(list.into_iter().map(|t| (mode.to_string(), t))),
                Err(e) => {
                    for &p in &tr.pressures_kpa {
                        torque.push((mode.to_string(), TorqueRotation { p_kpa: p, free_theta_deg: 0.0, points: vec![], nonlinearity: 0.0, status: SceneStatus::ModelError, cause: e.to_string() }));
                    }
                }
            }
        }
        let mut s = String::from("mode,p_kPa,free_theta_deg,theta_deg,tau_Nm,status\n");
        for (mode, t) in &torque {
            for (th, tau) in t.points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()) {
                s.push_str(&format!("{mode},{},{},{},{},{}\n", num(t.p_kpa), num(t.free_theta_deg), num(*th), num(*tau), t.status));
            }
            if t.points.is_empty() {
                s.push_str(&format!("{mode},{},{},,,{}\n", num(t.p_kpa), num(t.free_theta_deg), t.status));
            }
        }
        let csv = out.join("torque_rotation.csv");
        std::fs::write(&csv, s).with_context(|| format!("cannot write {}", csv.display()))?;
        files.push(csv);
    }

    // plots
    let design_label = format!("r = {:.4} mm, l = {} mm, α = {}°", problem.design.r_mm, problem.design.l_mm, problem.design.alpha_deg);
    let free_like: Vec<&SceneResult> = results.iter().filter(|r| matches!(r.scene.as_str(), "free" | "pure-twist")).collect();
    if !free_like.is_empty() {
        let mut plot = LinePlot::new(format!("Free twist θ(p): {design_label}"), "cavity pressure p (kPa)", "twist θ about +z (°)");
        for r in &free_like {
            plot.series.push(Series::new(format!("{} ({})", r.scene, r.status), r.steps.iter().map(|s| (s.p_kpa, s.theta_deg)).collect()));
        }
        files.extend(line_plot(&out.join("theta_vs_p"), &plot)?);
    }
    let blocked_like: Vec<&SceneResult> = results.iter().filter(|r| matches!(r.scene.as_str(), "blocked" | "pure-twist-blocked")).collect();
    if !blocked_like.is_empty() {
        let mut plot = LinePlot::new(format!("Blocking torque τ(p): {design_label}"), "cavity pressure p (kPa)", "torque on the cap τ about +z (N·m)");
        for r in &blocked_like {
            plot.series.push(Series::new(format!("{} ({})", r.scene, r.status), r.steps.iter().map(|s| (s.p_kpa, s.tau_nm)).collect()));
        }
        files.extend(line_plot(&out.join("tau_vs_p"), &plot)?);
    }
    if !torque.is_empty() {
        let mut plot = LinePlot::new(format!("Torque vs rotation: {design_label}"), "prescribed rotation θ (°)", "torque on the cap τ (N·m)");
        for (mode, t) in &torque {
            if !t.points.is_empty() {
                plot.series.push(Series::new(format!("p = {} kPa ({mode})", t.p_kpa), t.points.clone()));
            }
        }
        files.extend(line_plot(&out.join("torque_rotation"), &plot)?);
    }

    // result.json
    let design = {
        let mut d = serde_json::to_value(v.geometry.summary())?;
        if let Some(o) = d.as_object_mut() {
            o.insert("range".into(), serde_json::to_value(problem.design.range)?);
        }
        d
    };
    let elements = results.iter().map(|r| r.elements).max().unwrap_or(0);
    let mesh = json!({
        "size": v.mesh.size_string(),
        "n_around": v.mesh.n_around,
        "n_along": v.mesh.n_along,
        "n_through": v.mesh.n_through,
        "element": format!("{:?}", v.mesh.kind),
        "model": if opts.sector { "120-degree sector (cyclic symmetry)" } else { "full 360-degree model" },
        "elements_modelled": elements,
        "preset": problem.fidelity.preset,
    });
    let scenes: serde_json::Map<String, Value> = results.iter().map(|r| (r.scene.clone(), scene_json(r))).collect();
    let mut result = serde_json::Map::new();
    result.insert("problem".into(), serde_json::to_value(problem)?);
    result.insert("design".into(), design);
    result.insert("mesh".into(), mesh);
    result.insert("fidelity".into(), fidelity_json(&v));
    result.insert("material".into(), json!({"model": "Neo-Hookean", "mu_MPa": problem.material.mu_mpa, "kappa_MPa": problem.material.mu_mpa * problem.material.kappa_over_mu}));
    result.insert("scenes".into(), Value::Object(scenes));
    for (k, val) in top {
        result.insert(k, val);
    }
    result.insert("omega".into(), Value::Object(omega));
    if problem.torque_rotation.is_some() {
        result.insert("torque_rotation".into(), Value::Array(torque.iter().map(|(m, t)| torque_json(m, t)).collect()));
    }
    result.insert("sign_convention".into(), json!("theta: cap rotation about +z (right-hand rule); tau: torque the actuator exerts on the blocked cap about +z (tau > 0 pushes towards +theta)"));
    // elapsed time of the whole evaluation (the scenes run concurrently; each scene has its own)
    result.insert("wall_time_s".into(), json!(t0.elapsed().as_secs_f64()));
    let result = Value::Object(result);
    let path = out.join("result.json");
    write_json_atomic(&path, &result)?;
    files.push(path);
    Ok(Evaluation { result, files })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(p: f64, theta: f64, tau: f64) -> StepRecord {
        StepRecord::for_test(p, theta, tau, 20.0, 1.0)
    }

    fn scene(name: &str, steps: Vec<StepRecord>) -> SceneResult {
        SceneResult {
            snaps_kpa: Vec::new(),
            min_contact_distance_mm: None,
            scene: name.into(),
            status: crate::scene::SceneStatus::Completed,
            cause: String::new(),
            steps,
            dofs: 1,
            elements: 1,
            newton_iterations: 1,
            path: Default::default(),
            wall_time_s: 0.0,
            fields: None,
            states: Vec::new(),
            rom_indicator: None,
            rom_fallback: None,
            warm_start_kpa: None,
            warm: None,
            warm_deltas: Vec::new(),
        }
    }

    #[test]
    fn omega_uses_the_lower_final_pressure_and_interpolates() {
        // free reached 70 kPa, blocked 50 kPa → common pressure 50: θ interpolated 40 → 50 kPa
        let free = scene("free", vec![rec(-20.0, -4.0, 0.0), rec(0.0, 0.0, 0.0), rec(40.0, 8.0, 0.0), rec(60.0, 12.0, 0.0), rec(70.0, 13.0, 0.0)]);
        let blocked = scene("blocked", vec![rec(-30.0, 0.0, -0.03), rec(0.0, 0.0, 0.0), rec(25.0, 0.0, 0.1), rec(50.0, 0.0, 0.2)]);
        let v = omega_pair(&free, &blocked, &[-20.0, 40.0, 60.0]);
        let pos = &v["positive"];
        assert_eq!(pos["p_kPa"].as_f64().unwrap(), 50.0);
        assert!((pos["theta_deg"].as_f64().unwrap() - 10.0).abs() < 1e-12);
        assert!((pos["tau_Nm"].as_f64().unwrap() - 0.2).abs() < 1e-12);
        let expect = 0.2 * 10f64.to_radians() / (8.0 * std::f64::consts::PI * 625.0 * 40.0 * 1e-9);
        assert!((pos["omega_J_m3"].as_f64().unwrap() - expect).abs() < 1e-9 * expect);
        assert_eq!(pos["abs_values_used"], json!(true));
        // vacuum branch: common pressure −20 (the less negative), τ interpolated to −0.02
        let neg = &v["negative"];
        assert_eq!(neg["p_kPa"].as_f64().unwrap(), -20.0);
        assert!((neg["tau_Nm"].as_f64().unwrap() + 0.02).abs() < 1e-12);
        assert!(neg["omega_J_m3"].as_f64().unwrap() > 0.0);
        // the table holds the requested pressures both scenes reached (60 is beyond blocked)
        let t = v["omega_by_pressure"].as_array().unwrap();
        assert_eq!(t.iter().map(|x| x["p_kPa"].as_f64().unwrap()).collect::<Vec<_>>(), vec![-20.0, 40.0]);
    }

    #[test]
    fn omega_is_signed_when_signs_differ() {
        let free = scene("free", vec![rec(0.0, 0.0, 0.0), rec(10.0, -5.0, 0.0)]);
        let blocked = scene("blocked", vec![rec(0.0, 0.0, 0.0), rec(10.0, 0.0, 0.05)]);
        let v = omega_pair(&free, &blocked, &[10.0]);
        assert_eq!(v["positive"]["abs_values_used"], json!(false));
        assert!(v["positive"]["omega_J_m3"].as_f64().unwrap() < 0.0);
        assert!(v["negative"].is_null());
    }

    #[test]
    fn target_selection_keeps_targets_and_the_last_reached_state() {
        let mut r = scene("free", vec![rec(-5.0, 0.0, 0.0), rec(-2.0, 0.0, 0.0), rec(0.0, 0.0, 0.0), rec(3.0, 0.0, 0.0), rec(10.000000000000002, 0.0, 0.0), rec(12.5, 0.0, 0.0)]);
        select_steps(&mut r, &LoadPlan::Targets(vec![-5.0, 10.0, 20.0]));
        let p: Vec<f64> = r.steps.iter().map(|s| s.p_kpa).collect();
        assert_eq!(p, vec![-5.0, 0.0, 10.0, 12.5]);
    }
}
