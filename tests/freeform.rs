//! The freeform design family (issue 20): the letter's three-parameter geometry reproduced
//! through the freeform code path, the modes' end conditions, their shape derivatives against
//! central differences, validity errors, and adjoint FE gradients w.r.t. freeform parameters
//! against central differences at coarse fidelity.

mod common;
use common::{assert_close, test_vectors};
use twistopt::geometry::freeform::{profile_param, twist_param, N_PROFILE_MODES, N_TWIST_MODES};
use twistopt::geometry::{ActuatorGeometry, Design, DesignSpace, RangePolicy, L_TUBE};
use twistopt::gradient::{fd_check, max_rel_error, scene_gradient, DEFAULT_KS_RHO_PER_MM};
use twistopt::meshing::{build_mesh, mesh_shape_derivatives, MeshSpec};
use twistopt::scene::{SceneKind, SceneOptions};
use twistopt_solver::material::{Material, NeoHookean};

/// `d` with every freeform mode present at the given values (absent = 0).
fn with_modes(d: &Design, twist: &[f64], profile: &[f64]) -> Design {
    let mut d = d.clone();
    for k in 1..=N_TWIST_MODES {
        d = d.with(&twist_param(k), twist.get(k - 1).copied().unwrap_or(0.0)).unwrap();
    }
    for k in 1..=N_PROFILE_MODES {
        d = d.with(&profile_param(k), profile.get(k - 1).copied().unwrap_or(0.0)).unwrap();
    }
    d
}

#[test]
fn freeform_space_has_at_least_twenty_parameters_and_contains_table_one() {
    let s = DesignSpace::freeform();
    assert!(s.len() >= 20, "{} parameters", s.len());
    for n in DesignSpace::actuator().names() {
        assert!(s.get(n).is_some(), "{n}");
    }
    // zero modes = the spec: a design vector with the three values and zeros
    let x: Vec<f64> = s
        .params
        .iter()
        .map(|p| match p.name.as_str() {
            "r_mm" => 12.0,
            "l_mm" => 15.0,
            "alpha_deg" => 200.0,
            _ => 0.0,
        })
        .collect();
    let d = s.design_from_vec(&x).unwrap();
    assert_eq!(d.parameter_names().len(), s.len());
    assert!(ActuatorGeometry::new(&d, RangePolicy::TableI).unwrap().act.is_freeform());
}

/// Every value of shared/geometry/test_vectors.json through the freeform code path (all modes
/// present at zero) to 1e-9, and the coarse and default meshes' nodes equal to the spec's.
#[test]
fn zero_modes_reproduce_the_spec_geometry() {
    let tv = test_vectors();
    let mut checked = 0;
    for d in tv.as_array().unwrap() {
        let (r, l, a) = (d["r"].as_f64().unwrap(), d["l"].as_f64().unwrap(), d["alpha_deg"].as_f64().unwrap());
        let spec = Design::new(r, l, a);
        let ff = with_modes(&spec, &[], &[]);
        let g = ActuatorGeometry::new(&ff, RangePolicy::TableI).unwrap();
        assert!(g.act.is_freeform());
        let tag = format!("freeform at r={r} l={l} alpha={a}");
        assert_close(g.outer_volume(), d["outer_volume"].as_f64().unwrap(), 1e-9, &format!("{tag} outer_volume"));
        assert_close(g.chamber_volume(), d["chamber_volume"].as_f64().unwrap(), 1e-9, &format!("{tag} chamber_volume"));
        assert_close(g.inner_end_area(), d["end_inner_area"].as_f64().unwrap(), 1e-9, &format!("{tag} end_inner_area"));
        for pt in d["points"].as_array().unwrap() {
            let (s, z, eta) = (pt["shat"].as_f64().unwrap(), pt["z"].as_f64().unwrap(), pt["eta"].as_f64().unwrap());
            let x = g.act.point(s, z, eta);
            let n0 = g.act.surface(s, z).n0;
            for c in 0..3 {
                assert_close(x[c], pt["point"][c].as_f64().unwrap(), 1e-9, &format!("{tag} point({s},{z},{eta})[{c}]"));
                assert_close(n0[c], pt["untwisted_outer_normal"][c].as_f64().unwrap(), 1e-9, &format!("{tag} n0[{c}]"));
                checked += 2;
            }
        }
        let gs = ActuatorGeometry::new(&spec, RangePolicy::TableI).unwrap();
        for preset in ["coarse", "default"] {
            let ms = MeshSpec::preset(preset).unwrap();
            let (a_, b_) = (build_mesh(&g, &ms).unwrap(), build_mesh(&gs, &ms).unwrap());
            let worst = a_.mesh.nodes.iter().zip(&b_.mesh.nodes).flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs())).fold(0.0, f64::max);
            assert!(worst <= 1e-9, "{tag} {preset} mesh: nodes differ by {worst:e}");
        }
    }
    assert!(checked > 200, "{checked}");
}

/// The modes keep the end faces: the nodes in the planes z = 0 and z = L are the spec's, the
/// end-to-end twist stays α, and the interior moves.
#[test]
fn modes_keep_the_end_faces_and_move_the_interior() {
    let spec = Design::new(12.0, 15.0, 200.0);
    let ff = with_modes(&spec, &[20.0, -15.0, 5.0, 0.0, 3.0, -2.0], &[0.8, -0.6, 0.3, 0.2, -0.2, 0.1, 0.05, -0.05]);
    let (gf, gs) = (ActuatorGeometry::new(&ff, RangePolicy::TableI).unwrap(), ActuatorGeometry::new(&spec, RangePolicy::TableI).unwrap());
    let ms = MeshSpec::preset("coarse").unwrap();
    let (mf, msp) = (build_mesh(&gf, &ms).unwrap(), build_mesh(&gs, &ms).unwrap());
    let (mut ends, mut moved) = (0, 0.0f64);
    for (p, q) in mf.mesh.nodes.iter().zip(&msp.mesh.nodes) {
        let d = (0..3).map(|c| (p[c] - q[c]).abs()).fold(0.0, f64::max);
        if q[2].abs() < 1e-9 || (q[2] - L_TUBE).abs() < 1e-9 {
            assert!(d < 1e-12, "end node {q:?} moved by {d:e}");
            ends += 1;
        } else {
            moved = moved.max(d);
        }
    }
    assert!(ends > 0 && moved > 0.5, "ends {ends}, interior moved by {moved}");
    assert!((gf.chamber_volume() - gs.chamber_volume()).abs() > 10.0);
}

/// dX/dp of every mesh node for every freeform parameter (dual numbers) against central
/// differences of the mesh, and the chamber volume's derivative against its central difference.
#[test]
fn shape_derivatives_of_every_freeform_parameter_match_central_differences() {
    let base = with_modes(&Design::new(12.0, 15.0, 200.0), &[10.0, -5.0, 4.0, 2.0, -1.0, 1.0], &[0.5, -0.3, 0.2, 0.1, -0.1, 0.05, 0.02, -0.02]);
    let g = ActuatorGeometry::new(&base, RangePolicy::TableI).unwrap();
    let ms = MeshSpec::preset("coarse").unwrap();
    let ders = mesh_shape_derivatives(&g, &ms).unwrap();
    let vol_ders = g.scalar_derivatives();
    let names: Vec<String> = (1..=N_TWIST_MODES).map(twist_param).chain((1..=N_PROFILE_MODES).map(profile_param)).collect();
    for name in &names {
        let h = if name.starts_with("twist") { 1e-3 } else { 1e-5 };
        let v = base.get(name).unwrap();
        let gp = ActuatorGeometry::new(&base.with(name, v + h).unwrap(), RangePolicy::TableI).unwrap();
        let gm = ActuatorGeometry::new(&base.with(name, v - h).unwrap(), RangePolicy::TableI).unwrap();
        let (mp, mm) = (build_mesh(&gp, &ms).unwrap(), build_mesh(&gm, &ms).unwrap());
        let d = &ders.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no derivative for {name}")).1;
        let scale = d.iter().flat_map(|p| p.iter().map(|x| x.abs())).fold(0.0, f64::max);
        assert!(scale > 1e-6, "{name}: zero shape derivative");
        let mut worst = 0.0f64;
        for ((a, b), dd) in mp.mesh.nodes.iter().zip(&mm.mesh.nodes).zip(d) {
            for c in 0..3 {
                worst = worst.max(((a[c] - b[c]) / (2.0 * h) - dd[c]).abs());
            }
        }
        assert!(worst <= 1e-6 * scale, "{name}: node derivative off by {worst:e} (scale {scale:e})");
        let dv = vol_ders.iter().find(|s| &s.param == name).unwrap().chamber_volume;
        let fd = (gp.chamber_volume() - gm.chamber_volume()) / (2.0 * h);
        // (the difference quotient carries the volume's round-off, ~1e-15·V, over 2h)
        let tol = 1e-6 * fd.abs().max(1.0) + 1e-14 * gp.chamber_volume() / h;
        assert!((dv - fd).abs() <= tol, "{name}: dV/dp {dv} vs FD {fd}");
    }
}

#[test]
fn invalid_freeform_designs_are_refused_with_the_violated_condition() {
    let base = Design::new(12.0, 15.0, 200.0);
    let err = |d: &Design| ActuatorGeometry::new(d, RangePolicy::TableI).err().map(|e| e.to_string()).unwrap_or_default();
    // a bulge past the envelope
    let e = err(&base.with(&profile_param(1), 4.0).unwrap().with("l_mm", 18.0).unwrap());
    assert!(e.contains("exceeds the tube radius"), "{e}");
    // a neck too narrow for the offset notch walls
    let e = err(&base.with(&profile_param(1), -4.0).unwrap().with("l_mm", 10.0).unwrap().with("r_mm", 8.660254037844386).unwrap());
    assert!(e.contains("smallest rest radius") || e.contains("principal radius"), "{e}");
    // a ripple too sharp for the inward offset
    let e = err(&base.with(&profile_param(10), 2.5).unwrap());
    assert!(e.contains("principal radius") || e.contains("exceeds"), "{e}");
    // out of range and non-finite values, unknown names
    let e = err(&base.with(&twist_param(2), 100.0).unwrap());
    assert!(e.contains("twist_2_deg") && e.contains("[-90, 90]"), "{e}");
    let e = err(&base.with(&profile_param(3), f64::NAN).unwrap());
    assert!(e.contains("profile_3_mm") && e.contains("not a finite"), "{e}");
    assert!(base.with("twist_9_deg", 1.0).is_err() && base.with("profile_11_mm", 1.0).is_err());
}

/// Adjoint gradients w.r.t. every freeform parameter against central differences at coarse
/// fidelity (the same check as tests/gradient.rs for r, l, α), in the free and pure-twist scenes.
#[test]
fn adjoint_gradients_of_freeform_parameters_match_central_differences() {
    // every mode present (so that every one has an adjoint gradient to check)
    let d = with_modes(&Design::new(12.0, 15.0, 200.0), &[15.0, -8.0, 4.0, -3.0, 2.0, 1.0, -1.0, 0.5], &[0.6, -0.4, 0.2, 0.15, -0.1, 0.05, 0.05, -0.03, 0.02, 0.01]);
    let g = ActuatorGeometry::new(&d, RangePolicy::TableI).unwrap();
    let o = SceneOptions::new(MeshSpec::preset("coarse").unwrap(), Material::NeoHookean(NeoHookean::with_ratio(0.34, 300.0).unwrap()));
    for kind in [SceneKind::Free, SceneKind::PureTwist] {
        let sg = scene_gradient(&g, &o, kind, 20.0, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
        assert_eq!(sg.status, twistopt::scene::SceneStatus::Converged, "{kind:?}: {}", sg.cause);
        for grad in sg.gradients.values() {
            for name in (1..=N_TWIST_MODES).map(twist_param).chain((1..=N_PROFILE_MODES).map(profile_param)) {
                assert!(grad[&name].is_finite() && grad[&name] != 0.0, "{kind:?} {name}: {}", grad[&name]);
            }
        }
        let rep = fd_check(&g, &o, kind, &sg, &[1e-4, 1e-5]);
        let worst = max_rel_error(&rep);
        let detail: Vec<String> =
            rep.iter().flat_map(|(f, m)| m.iter().filter(|(_, c)| !(c.rel_error <= 1e-5)).map(move |(p, c)| format!("{f}/{p}: adjoint {} fd {:?} rel {}", c.adjoint, c.fd, c.rel_error))).collect();
        assert!(worst <= 1e-5, "{kind:?}: max rel error {worst:e}: {detail:?}");
    }
}

/// problems/freeform-energy-density.toml: 22 variables, the envelope constraints, the starts
/// (the [design] first, the others within the spread around it), and the envelope constraint's
/// value and gradient at a bulged design against central differences.
#[test]
fn freeform_problem_starts_and_envelope_constraint() {
    use twistopt::optimise::{build_problem, problem_starting_points, ENVELOPE_POINTS, SHAPE_CONSTRAINTS};
    use twistopt::problem::Problem;
    let problem = Problem::load(std::path::Path::new("problems/freeform-energy-density.toml"), &["design.l_mm=17".into()]).unwrap();
    let v = problem.validate().unwrap();
    let (op, sec) = build_problem(&problem, &v).unwrap();
    assert_eq!(op.n(), 22);
    // radius × 2, stability, envelope / waist / fold at each height, the mesh's quality
    assert_eq!(op.n_constraints(), 2 + 1 + SHAPE_CONSTRAINTS * ENVELOPE_POINTS + 1);
    let starts = problem_starting_points(&op, sec.starts, sec.start_from_design, sec.start_spread, sec.start_p_kpa);
    assert_eq!(starts.len(), sec.starts);
    let design = op.unscale(&starts[0]);
    assert!((design["l_mm"] - 17.0).abs() < 1e-9 && (design["p_kPa"] - 36.27).abs() < 1e-9 && design["profile_1_mm"].abs() < 1e-12, "{design:?}");
    for s in &starts[1..] {
        for (x, d) in s.iter().zip(&starts[0]) {
            assert!((x - d).abs() <= 0.9 * sec.start_spread + 1e-12 && (0.0..=1.0).contains(x));
        }
        assert!(op.shape_constraints(s).is_some(), "a start whose geometry is refused");
    }
    // a bulge at l = 17: ρ(L/2) = 17 + b₁ crosses R = 20 at b₁ = 3
    let i1 = op.variables.iter().position(|x| x.name == "profile_1_mm").unwrap();
    let il = op.variables.iter().position(|x| x.name == "l_mm").unwrap();
    let mut x = starts[0].clone();
    let scaled = |v: &twistopt::optimise::Variable, val: f64| (val - v.lower) / (v.upper - v.lower);
    x[i1] = scaled(&op.variables[i1], 3.5);
    // r off its lower bound (the start's 5√3), so that central differences see both sides
    let ir = op.variables.iter().position(|x| x.name == "r_mm").unwrap();
    x[ir] = 0.3;
    let g = op.shape_constraints(&x).expect("buildable");
    let mid = ENVELOPE_POINTS / 2; // z = L/2
    assert!((g.0[mid] * 2.0 - 0.5).abs() < 1e-9, "ρ(L/2) − R = {}", g.0[mid] * 2.0);
    // the waist and fold constraints are satisfied there
    assert!(g.0[ENVELOPE_POINTS..].iter().all(|v| *v < 0.0), "{:?}", &g.0[ENVELOPE_POINTS..]);
    // every shape constraint's gradient (envelope, waist, fold) against central differences, in
    // the bulge, l, r and a twist-law mode (the fold constraint's curvature depends on all)
    let it = op.variables.iter().position(|x| x.name == "twist_2_deg").unwrap();
    let i3 = op.variables.iter().position(|x| x.name == "profile_3_mm").unwrap();
    for k in [i1, il, ir, it, i3] {
        let h = 1e-6;
        let (mut xp, mut xm) = (x.clone(), x.clone());
        xp[k] += h;
        xm[k] -= h;
        let (gp, gm) = (op.shape_constraints(&xp).unwrap().0, op.shape_constraints(&xm).unwrap().0);
        for j in 0..=SHAPE_CONSTRAINTS * ENVELOPE_POINTS {
            let fd = (gp[j] - gm[j]) / (2.0 * h);
            assert!((fd - g.1[j][k]).abs() <= 1e-5 * fd.abs().max(1.0), "shape constraint {j} / variable {k}: {} vs FD {fd}", g.1[j][k]);
        }
    }
}

/// The mesh-quality constraint (floor 0.15 on the least scaled Jacobian of the problem's mesh, the
/// refusal at 0.1): at a design the 24x16x1 mesh refuses (met by an MMA run of
/// problems/freeform-energy-density.toml, least scaled Jacobian 0.094), the constraint is
/// violated by (0.15 − 0.094)/0.1, its gradient matches central differences, and an evaluation
/// there fails with the mesh's refusal while handing the optimiser that constraint and gradient.
#[test]
fn mesh_quality_constraint_holds_off_refused_designs() {
    use twistopt::optimise::{build_problem, JACOBIAN_CONSTRAINT_FLOOR, JACOBIAN_CONSTRAINT_SCALE};
    use twistopt::problem::Problem;
    let problem = Problem::load(std::path::Path::new("problems/freeform-energy-density.toml"), &[]).unwrap();
    let v = problem.validate().unwrap();
    let (op, _) = build_problem(&problem, &v).unwrap();
    let vals = [
        ("r_mm", 9.5107),
        ("l_mm", 19.2698),
        ("alpha_deg", 315.9840),
        ("p_kPa", 38.3483),
        ("twist_1_deg", -8.4496),
        ("twist_2_deg", -12.5254),
        ("twist_3_deg", -9.4173),
        ("twist_4_deg", 0.1197),
        ("twist_5_deg", -0.0817),
        ("twist_6_deg", -13.4069),
        ("twist_7_deg", 9.7548),
        ("twist_8_deg", 5.8378),
        ("profile_1_mm", -0.9717),
        ("profile_2_mm", -0.4880),
        ("profile_3_mm", -0.0623),
        ("profile_4_mm", 0.6230),
        ("profile_5_mm", 0.1794),
        ("profile_6_mm", 0.2325),
        ("profile_7_mm", 0.1781),
        ("profile_8_mm", -0.4978),
        ("profile_9_mm", -0.1238),
        ("profile_10_mm", -0.3054),
    ];
    let x: Vec<f64> = op.variables.iter().map(|var| (vals.iter().find(|(n, _)| *n == var.name).unwrap().1 - var.lower) / (var.upper - var.lower)).collect();
    // the problem's mesh refuses this design
    let design = op.unscale(&x);
    let geom = ActuatorGeometry::new(&op.design_of(&design), RangePolicy::TableI).unwrap();
    let refused = build_mesh(&geom, &op.opts.mesh).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(refused.contains("minimum scaled Jacobian 0.09"), "{refused}");
    let (g, dg) = op.shape_constraints(&x).expect("constraints of a refused mesh");
    let j = g.len() - 1;
    let sj = JACOBIAN_CONSTRAINT_FLOOR - g[j] * JACOBIAN_CONSTRAINT_SCALE;
    assert!((0.09..0.1).contains(&sj), "least scaled Jacobian {sj}");
    assert!(dg[j].iter().any(|d| d.abs() > 1e-3), "{:?}", dg[j]);
    let ip = op.variables.iter().position(|v| v.name == "p_kPa").unwrap();
    assert_eq!(dg[j][ip], 0.0);
    for name in ["alpha_deg", "l_mm", "twist_6_deg", "twist_1_deg", "profile_4_mm", "profile_1_mm"] {
        let k = op.variables.iter().position(|v| v.name == name).unwrap();
        let h = 1e-6;
        let (mut xp, mut xm) = (x.clone(), x.clone());
        xp[k] += h;
        xm[k] -= h;
        let fd = (op.shape_constraints(&xp).unwrap().0[j] - op.shape_constraints(&xm).unwrap().0[j]) / (2.0 * h);
        assert!((fd - dg[j][k]).abs() <= 1e-5 * fd.abs().max(1.0), "{name}: {} vs FD {fd}", dg[j][k]);
    }
    // the evaluation: a failure with the refusal as its status, the constraint and its gradient
    let ev = op.evaluate(&x, &mut None, None);
    assert!(!ev.feasible && ev.status.contains("scaled Jacobian"), "{}", ev.status);
    let m = ev.g.len() - 1;
    assert!((ev.g[m] - g[j]).abs() < 1e-12 && ev.dg[m] == dg[j]);
}
