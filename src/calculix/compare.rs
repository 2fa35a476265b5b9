//! twistopt and CalculiX side by side on the same scenes, design, material and mesh.

use anyhow::{Context, Result};
use serde_json::{json, Value};
use std::path::Path;

use super::contact::{contact_patches, map_deformed, surface_gaps, PatchPair};
use super::{build_deck, build_deck_with, ccx_version, run_deck, CcxRun, CcxState, DeckExtras, DeckOptions};
use crate::evaluate::select_steps;
use crate::problem::{Problem, Validated};
use crate::scene::{run_pressure, SceneKind, SceneResult, StepRecord};
use twistopt_solver::integrity::{least_jacobians, penetration};

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
    /// under vacuum with contact: the deck's contact pairs, and for a free rotation the runs at
    /// prescribed rotations that located ccx's free twist ([`vacuum_contact_runs`])
    pub contact: Option<Value>,
}

/// Prescribed rotations of the free-twist search: twistopt's θ(p) times these factors.
pub const ROTATION_FACTORS: [f64; 2] = [1.0, 0.98];

/// The contact pairs of a vacuum deck from twistopt's deepest converged state of `tw` (its fields
/// kept). `base` is the deck without contact (its mesh is the full 360° ccx mesh).
pub fn vacuum_patches(tw: &SceneResult, base: &super::Deck, sector: bool, delta_mm: f64) -> Result<Vec<PatchPair>> {
    let fields = tw.fields.as_ref().ok_or_else(|| anyhow::anyhow!("twistopt kept no fields to take contact pairs from"))?;
    let (k, _) = tw.steps.iter().enumerate().filter(|(_, s)| s.p_kpa < 0.0).min_by(|a, b| a.1.p_kpa.total_cmp(&b.1.p_kpa)).ok_or_else(|| anyhow::anyhow!("twistopt reached no negative pressure"))?;
    let u = fields.displacements.get(k).ok_or_else(|| anyhow::anyhow!("no displacement field for step {k}"))?;
    let x = map_deformed(&base.mesh, &fields.mesh, u, if sector { 3 } else { 1 })?;
    let faces = base.mesh.face_sets.get("cavity").ok_or_else(|| anyhow::anyhow!("the deck's mesh has no cavity faces"))?;
    // a patch that approaches itself cannot be split into slave and master: narrow the patches
    let mut delta = delta_mm;
    loop {
        match contact_patches(&base.mesh, faces, &x, crate::geometry::T_WALL, delta) {
            Err(_) if delta > 0.05 => delta *= 0.5,
            r => return r,
        }
    }
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
    let targets = v.load.targets();
    let vacuum_contact = opts.contact.is_some() && targets.iter().any(|p| *p < 0.0);
    opts.keep_fields = vacuum_contact;
    // a cross-check compares two codes on the same discretisation, folded elements included
    // (each row reports them: least_jacobian_ratio, folded_elements); the ramp goes on past them
    if let Some(c) = opts.contact.as_mut() {
        c.stop_at_fold = false;
    }
    if twistopt_element == TwistoptElement::Matched {
        opts.formulation = deck_opts.element.matched_formulation().ok_or_else(|| anyhow::anyhow!("twistopt has no formulation matching {} (use C3D20R or C3D20)", deck_opts.element.name()))?;
    }
    let mut tw = match run_pressure(&v.geometry, &opts, scene, &targets) {
        Ok(r) => r,
        Err(e) => SceneResult::model_error(scene, e.to_string().replace('\n', " ")),
    };
    select_steps(&mut tw, &v.load);
    let base = build_deck(&v.geometry, &v.mesh, &v.material, scene, &targets, deck_opts)?;
    let (run, contact) = if vacuum_contact {
        let (run, info) = vacuum_contact_runs(&tw, &base, v, scene, &targets, deck_opts, opts.sector, ccx, &dir.join(scene.name()), threads)?;
        (run, Some(info))
    } else {
        (run_deck(ccx, &base, &dir.join(scene.name()), scene.name(), threads)?, None)
    };
    tw.fields = None;
    let mut rows = Vec::new();
    for c in &run.states {
        if c.p_kpa == 0.0 {
            continue;
        }
        if let Some(t) = tw.steps.iter().find(|s| same_p(s.p_kpa, c.p_kpa)) {
            rows.push(row(scene, t, c));
        }
    }
    Ok(SceneCheck { scene, twistopt: tw, ccx: run, rows, contact })
}

/// Per negative step of twistopt's path: the smallest node gap and the sampled and exact signed
/// surface gaps over the contact pairs, on twistopt's own element's full mesh ([`surface_gaps`],
/// 7 × 7 samples per slave face). The barrier keeps the first ≥ 0; the exact one (negative only
/// where a point of one wall lies inside the other wall's material) shows whether the faces
/// between the nodes overlap, the sampled one estimates it with chords. Also, over the whole
/// cavity with no pairs ([`penetration`]): the deepest cavity sample inside another element and
/// how many are (inside unfolded elements, and inside any), and the elements' least det J
/// relative to their centre's on a 9³ grid ([`least_jacobian`]; ≤ 0: the element's map folds
/// between its quadrature points).
pub fn twistopt_surface_gaps(tw: &SceneResult, v: &Validated, pairs: &[PatchPair], sector: bool) -> Result<Value> {
    let Some(fields) = tw.fields.as_ref() else {
        return Ok(Value::Null);
    };
    if pairs.is_empty() {
        return Ok(Value::Null);
    }
    let full = crate::meshing::build_mesh(&v.geometry, &v.mesh.with_sector(false))?.mesh;
    let full = if full.kind == fields.mesh.kind { full } else { full.to_kind(fields.mesh.kind) };
    let mut rows = Vec::new();
    for (k, s) in tw.steps.iter().enumerate() {
        if s.p_kpa >= 0.0 {
            continue;
        }
        let Some(u) = fields.displacements.get(k) else { continue };
        let x = map_deformed(&full, &fields.mesh, u, if sector { 3 } else { 1 })?;
        let (mut node_gap, mut sampled, mut exact) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
        for pair in pairs {
            let g = surface_gaps(&full, &pair.slave, &pair.master, &x, 7);
            node_gap = node_gap.min(g.node);
            sampled = sampled.min(g.sampled);
            exact = exact.min(g.exact);
        }
        let jac = least_jacobians(&full, &x, 9);
        let folded = jac.iter().filter(|&&j| !(j > 0.0)).count();
        let least = jac.iter().copied().fold(f64::INFINITY, f64::min);
        let cavity = &full.face_sets["cavity"];
        let (depth, inside) = penetration(&full, cavity, cavity, &x, 7, &|e| jac[e] > 0.0);
        let (depth_all, inside_all) = penetration(&full, cavity, cavity, &x, 7, &|_| true);
        rows.push(json!({"p_kPa": s.p_kpa, "node_gap_mm": node_gap, "surface_gap_mm": sampled, "surface_gap_exact_mm": exact,
            "penetration_mm": depth, "samples_inside_material": inside, "penetration_incl_folded_mm": depth_all, "samples_inside_incl_folded": inside_all,
            "least_jacobian_ratio": least, "folded_elements": folded}));
    }
    Ok(json!({"element": format!("{:?}", fields.mesh.kind), "pairs": pairs.len(), "samples_per_face": 49, "steps": rows}))
}

/// twistopt's deformed node positions on the deck's full mesh (deck node id − 1 = index) at each
/// negative pressure it reached, as JSON `{"p_kPa": [..], "x": [[[x, y, z], ..], ..]}`: the input
/// of studies/vacuum/ccx-contact/surface_gap.py's `--positions`.
pub fn write_deformed(tw: &SceneResult, base: &super::Deck, sector: bool, path: &Path) -> Result<()> {
    let Some(fields) = tw.fields.as_ref() else {
        return Ok(());
    };
    let mut ps = Vec::new();
    let mut xs = Vec::new();
    for (k, s) in tw.steps.iter().enumerate() {
        if s.p_kpa < 0.0 {
            if let Some(u) = fields.displacements.get(k) {
                ps.push(s.p_kpa);
                xs.push(map_deformed(&base.mesh, &fields.mesh, u, if sector { 3 } else { 1 })?);
            }
        }
    }
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
    }
    std::fs::write(path, serde_json::to_string(&json!({"p_kPa": ps, "x": xs}))?).with_context(|| format!("cannot write {}", path.display()))
}

/// The ccx side of a vacuum scene with contact: the deck gets the facing patches of twistopt's
/// deepest state as face-to-face penalty pairs ([`vacuum_patches`]). A held rotation is one run.
/// A free rotation is found as the root of ccx's cap torque: ccx's `*RIGID BODY` with a free
/// rotation node converges only linearly under vacuum (at −5.4 kPa on the coarse example it cut
/// its increments to 1e-4 of the step), while with the rotation prescribed it converges as in the
/// blocked scene. So ccx runs with the rotation prescribed at twistopt's θ(p) × each of
/// [`ROTATION_FACTORS`], the zero of its torque is interpolated at each pressure, and a last run
/// at those roots checks that the torque left there is small; the states reported are the last
/// run's with θ the root.
#[allow(clippy::too_many_arguments)]
pub fn vacuum_contact_runs(
    tw: &SceneResult,
    base: &super::Deck,
    v: &Validated,
    scene: SceneKind,
    targets: &[f64],
    deck_opts: &DeckOptions,
    sector: bool,
    ccx: &str,
    dir: &Path,
    threads: usize,
) -> Result<(CcxRun, Value)> {
    write_deformed(tw, base, sector, &dir.join("twistopt-deformed.json"))?;
    let pairs = vacuum_patches(tw, base, sector, deck_opts.contact_patch_mm)?;
    let gaps = twistopt_surface_gaps(tw, v, &pairs, sector)?;
    let mut extras = DeckExtras { contact: pairs.clone(), contact_slope_mpa_per_mm: deck_opts.contact_slope_mpa_per_mm, rotation_deg: None };
    let pairs_json =
        json!(pairs.iter().map(|p| json!({"slave_faces": p.slave.len(), "master_faces": p.master.len(), "min_distance_mm": p.min_distance_mm, "close_nodes": p.close_nodes})).collect::<Vec<_>>());
    if !scene.rotation_free() {
        let deck = build_deck_with(&v.geometry, &v.mesh, &v.material, scene, targets, deck_opts, &extras)?;
        let run = run_deck(ccx, &deck, dir, scene.name(), threads)?;
        return Ok((run, json!({"pairs": pairs_json, "contact_slope_MPa_per_mm": extras.contact_slope_mpa_per_mm, "contact_patch_mm": deck_opts.contact_patch_mm, "twistopt_surface_gap": gaps})));
    }
    // twistopt's θ at each step of ccx's schedule
    let schedule = &base.step_pressures_kpa;
    let theta_tw: Vec<f64> = schedule
        .iter()
        .map(|&p| tw.steps.iter().find(|s| same_p(s.p_kpa, p)).map(|s| s.theta_deg).ok_or_else(|| anyhow::anyhow!("twistopt did not reach {p} kPa: no rotation to prescribe there")))
        .collect::<Result<_>>()?;
    let mut runs = Vec::new();
    for (i, f) in ROTATION_FACTORS.iter().enumerate() {
        extras.rotation_deg = Some(theta_tw.iter().map(|t| t * f).collect());
        let deck = build_deck_with(&v.geometry, &v.mesh, &v.material, scene, targets, deck_opts, &extras)?;
        runs.push(run_deck(ccx, &deck, dir, &format!("{}-rot{i}", scene.name()), threads)?);
    }
    // the root of τ(θ) at each pressure from the first two runs (linear in θ over 2 %)
    let n = runs.iter().map(|r| r.states.len()).min().unwrap_or(0);
    let roots: Vec<f64> = (0..n)
        .map(|k| {
            let (a, b) = (&runs[0].states[k], &runs[1].states[k]);
            if (b.tau_nm - a.tau_nm).abs() > 0.0 {
                a.theta_deg - a.tau_nm * (b.theta_deg - a.theta_deg) / (b.tau_nm - a.tau_nm)
            } else {
                a.theta_deg
            }
        })
        .collect();
    let mut check = if n == schedule.len() {
        extras.rotation_deg = Some(roots.clone());
        let deck = build_deck_with(&v.geometry, &v.mesh, &v.material, scene, targets, deck_opts, &extras)?;
        run_deck(ccx, &deck, dir, &format!("{}-root", scene.name()), threads)?
    } else {
        let mut r = runs[0].clone();
        r.status = "not-converged".into();
        r.cause = format!("the prescribed-rotation runs reached {n} of {} pressures: {}", schedule.len(), runs.iter().map(|r| r.cause.clone()).collect::<Vec<_>>().join("; "));
        r.states.truncate(n);
        r
    };
    let residual: Vec<f64> = check.states.iter().map(|s| s.tau_nm).collect();
    for (s, root) in check.states.iter_mut().zip(&roots) {
        s.theta_deg = *root;
    }
    let info = json!({
        "pairs": pairs_json,
        "contact_slope_MPa_per_mm": extras.contact_slope_mpa_per_mm,
        "contact_patch_mm": deck_opts.contact_patch_mm,
        "twistopt_surface_gap": gaps,
        "free_twist": "ccx's theta is the rotation at which its cap torque vanishes, interpolated from runs with the rotation prescribed at twistopt's theta times rotation_factors; tau_Nm of the ccx states is the torque left at that root",
        "rotation_factors": ROTATION_FACTORS,
        "runs": runs.iter().map(|r| json!({"inp": r.inp, "status": r.status, "states": r.states})).collect::<Vec<_>>(),
        "roots_deg": roots,
        "torque_at_roots_Nm": residual,
    });
    Ok((check, info))
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
                    "snaps_kPa": c.twistopt.snaps_kpa,
                    "min_contact_distance_mm": c.twistopt.min_contact_distance_mm,
                    "wall_time_s": c.twistopt.wall_time_s,
                    "steps": c.twistopt.steps,
                },
                "ccx": c.ccx,
                "ccx_contact": c.contact,
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
