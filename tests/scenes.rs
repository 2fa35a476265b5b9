//! Actuator scenes: symmetry reductions, determinism, and physical sanity checks.
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::{run_pressure, SceneKind, SceneOptions, SceneResult, SceneStatus, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
use twistopt_solver::material::NeoHookean;

fn opts(preset: &str) -> SceneOptions {
    SceneOptions::new(MeshSpec::preset(preset).unwrap(), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).unwrap().into())
}

fn example(alpha: f64) -> ActuatorGeometry {
    ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, alpha), RangePolicy::Extended).unwrap()
}

fn last(r: &SceneResult) -> &twistopt::scene::StepRecord {
    assert_eq!(r.status, SceneStatus::Completed, "{}: {}", r.status, r.cause);
    r.steps.last().unwrap()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-30)
}

#[test]
fn sector_and_full_model_agree() {
    let g = example(60.0);
    let mut o = opts("coarse");
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        o.sector = true;
        let s = run_pressure(&g, &o, kind, &[30.0]).unwrap();
        o.sector = false;
        let f = run_pressure(&g, &o, kind, &[30.0]).unwrap();
        let (a, b) = (last(&s), last(&f));
        assert!(f.dofs > 2 * s.dofs);
        if kind == SceneKind::Free {
            assert!(rel(a.theta_deg, b.theta_deg) < 5e-3, "θ sector {} full {}", a.theta_deg, b.theta_deg);
        } else {
            assert!(rel(a.tau_nm, b.tau_nm) < 5e-3, "τ sector {} full {}", a.tau_nm, b.tau_nm);
        }
        assert!(rel(a.max_radius_mm, b.max_radius_mm) < 5e-3);
        assert!(rel(a.cavity_volume_mm3, b.cavity_volume_mm3) < 5e-3);
        assert!(rel(a.axial_mm, b.axial_mm) < 5e-3);
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let g = example(60.0);
    let o = opts("coarse");
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| run_pressure(&g, &o, SceneKind::Free, &[20.0]).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.steps.len(), b.steps.len());
    for (x, y) in a.steps.iter().zip(&b.steps) {
        assert!((x.theta_deg - y.theta_deg).abs() <= 1e-12 * x.theta_deg.abs().max(1.0));
        assert!((x.axial_mm - y.axial_mm).abs() <= 1e-12 * x.axial_mm.abs().max(1.0));
    }
}

#[test]
fn plain_tube_does_not_twist() {
    let g = ActuatorGeometry::new(&Design::new(20.0, 20.0, 120.0), RangePolicy::TableI).unwrap();
    let r = run_pressure(&g, &opts("coarse"), SceneKind::Free, &[50.0]).unwrap();
    let s = last(&r);
    assert!(s.theta_deg.abs() < 0.05, "θ = {}", s.theta_deg);
    assert!(s.axial_mm > 0.0);
}

#[test]
fn twist_changes_sign_with_alpha_and_pressure() {
    let o = opts("coarse");
    let pos = run_pressure(&example(60.0), &o, SceneKind::Free, &[-30.0, 30.0]).unwrap();
    let neg = run_pressure(&example(-60.0), &o, SceneKind::Free, &[30.0]).unwrap();
    assert_eq!(pos.status, SceneStatus::Completed, "{}", pos.cause);
    let at = |r: &SceneResult, p: f64| r.steps.iter().find(|s| (s.p_kpa - p).abs() < 1e-9).unwrap().theta_deg;
    let (tp, tn) = (at(&pos, 30.0), at(&pos, -30.0));
    assert!(tp.abs() > 1.0 && tn.abs() > 0.1);
    assert!(tp * tn < 0.0, "θ(+p) = {tp}, θ(−p) = {tn}");
    let tm = at(&neg, 30.0);
    assert!(rel(tm, -tp) < 1e-6, "θ(α) = {tp}, θ(−α) = {tm}");
    // θ(p) monotone on the recorded path
    let th: Vec<f64> = pos.steps.iter().map(|s| s.theta_deg).collect();
    assert!(th.windows(2).all(|w| (w[1] - w[0]) * (th[th.len() - 1] - th[0]) >= 0.0));
}

#[test]
fn default_bulk_modulus_is_high_enough() {
    // raising κ tenfold changes θ and τ by less than 0.5 %
    let g = example(60.0);
    let mut o = opts("coarse");
    let base: Vec<f64> = [SceneKind::Free, SceneKind::Blocked]
        .iter()
        .map(|&k| {
            let s = run_pressure(&g, &o, k, &[40.0]).unwrap();
            let l = last(&s);
            if k == SceneKind::Free {
                l.theta_deg
            } else {
                l.tau_nm
            }
        })
        .collect();
    o.material = NeoHookean::with_ratio(MU_HEICAST_MPA, 10.0 * DEFAULT_KAPPA_OVER_MU).unwrap().into();
    for (i, &k) in [SceneKind::Free, SceneKind::Blocked].iter().enumerate() {
        let s = run_pressure(&g, &o, k, &[40.0]).unwrap();
        let l = last(&s);
        let v = if k == SceneKind::Free { l.theta_deg } else { l.tau_nm };
        assert!(rel(v, base[i]) < 5e-3, "{:?}: {} vs {}", k, v, base[i]);
    }
}

#[test]
fn a_step_just_below_the_pressure_maximum_is_solved_under_volume_control() {
    // Ω by the letter's rule needs each scene's state at the lower of the two failure
    // pressures; where the two maxima nearly coincide (circular sections), that pressure lies
    // between a branch's last regular step and its pressure maximum, where the path is nearly
    // singular in p (under load control the steps shrank towards the fold: 500 steps)
    let g = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 14.0, 200.0), RangePolicy::TableI).unwrap();
    let o = opts("coarse");
    let mut r = run_pressure(&g, &o, SceneKind::Free, &[150.0]).unwrap();
    assert_eq!(r.status, SceneStatus::LimitPoint, "{}", r.cause);
    let n = r.steps.len();
    let (p_fold, p_below) = (r.steps[n - 1].p_kpa, r.steps[n - 2].p_kpa);
    let p = p_fold - 0.1 * (p_fold - p_below);
    let steps_before = r.path.steps;
    twistopt::scene::add_step_at(&g, &o, SceneKind::Free, &mut r, p).unwrap();
    let added = r.path.steps - steps_before;
    assert!(added <= 10, "{added} steps for the segment to p = {p} kPa (fold at {p_fold})");
    // the step is there, between the last regular step and the fold, with θ between theirs
    let k = r.steps.iter().position(|s| s.p_kpa == p).expect("a step at p");
    assert_eq!(k, n - 1);
    let (a, b, c) = (r.steps[k - 1].theta_deg, r.steps[k].theta_deg, r.steps[k + 1].theta_deg);
    assert!((a - b) * (b - c) >= 0.0, "θ {a} {b} {c} not monotone up to the fold");
}
