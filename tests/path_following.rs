//! The path follower on one design at coarse fidelity (issue 16): the sweep's evaluation (free +
//! blocked ramped to failure) keeps the answers of the solver it replaced, and spends no Newton
//! iterations in failed attempts.
//!
//! Reference values, recorded before the change with the previous solver (commit c08cba2,
//! `twistopt sweep` on this design at the coarse preset, and `twistopt evaluate` with the blocked
//! scene solved at exactly the free scene's failure pressure for Ω):
//! p_free = 58.08995114 kPa, p_blocked = 59.77242232 kPa (pressure maxima, located to 1e-6),
//! θmax = −41.0068737°, τmax = −0.49972546 N·m (the states at those maxima), Ω = 484.119062 J/m³.
//! The previous sweep row said Ω = 486.557: it interpolated τ linearly between ramp steps.
use twistopt::geometry::{Design, RangePolicy};
use twistopt::scene::SceneStatus;
use twistopt::sweep::{evaluate_design, problem_from_str, Shard, SweepConfig};

const P_FREE: f64 = 58.08995114;
const P_BLOCKED: f64 = 59.77242232;
const THETA_MAX: f64 = -41.0068737;
const TAU_MAX: f64 = -0.49972546;
const OMEGA: f64 = 484.119062;

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn sweep_design_keeps_the_previous_answers_without_wasted_iterations() {
    let text = "[load]\np_max_kPa = 150\n[scenes]\nrun = [\"free\", \"blocked\"]\n[fidelity]\npreset = \"coarse\"\n[sweep]\nr_mm = [8.660254037844386]\nl_mm = [16]\nalpha_deg = [200]\n";
    let (problem, section) = problem_from_str(text, "test", &[]).unwrap();
    let cfg = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).unwrap();
    let v = cfg.problem.validate().unwrap();
    let opts = cfg.problem.scene_options(&v);
    let design = Design::new(5.0 * 3f64.sqrt(), 16.0, 200.0);
    let row = evaluate_design(0, &design, RangePolicy::TableI, &v, &opts, 150.0);
    assert_eq!(row.status, "ok", "{}", row.cause);
    let (f, b) = (&row.scenes["free"], &row.scenes["blocked"]);
    assert_eq!(f.status, SceneStatus::LimitPoint);
    assert_eq!(b.status, SceneStatus::LimitPoint);
    let (pf, pb) = (f.p_reached_kpa.unwrap(), b.p_reached_kpa.unwrap());
    let m = &row.primary;
    let (th, tau, om) = (m.theta_max_deg.unwrap(), m.tau_max_nm.unwrap(), m.omega_j_m3.unwrap());
    println!(
        "p_free {pf} ({:.1e}), p_blocked {pb} ({:.1e}), θmax {th} ({:.1e}), τmax {tau} ({:.1e}), Ω {om} ({:.1e})",
        rel(pf, P_FREE),
        rel(pb, P_BLOCKED),
        rel(th, THETA_MAX),
        rel(tau, TAU_MAX),
        rel(om, OMEGA)
    );
    // the pressure maxima to the location tolerance of both solvers (1e-6 each)
    assert!(rel(pf, P_FREE) < 2e-6 && rel(pb, P_BLOCKED) < 2e-6);
    // the outputs at the maxima and Ω within 0.1 % (the previous solver pinned the pressure, not
    // the state, at the maximum, where θ and τ still vary along the path)
    assert!(rel(th, THETA_MAX) < 1e-3 && rel(tau, TAU_MAX) < 1e-3 && rel(om, OMEGA) < 1e-3);
    // Ω at the free scene's maximum, taken from an exact blocked step there
    assert!((m.p_omega_kpa.unwrap() - pf).abs() < 1e-9 * pf);
    // the work: every iteration counted, few in failed attempts
    for (name, s) in [("free", f), ("blocked", b)] {
        let ps = &s.path;
        assert_eq!(s.newton_iterations, ps.newton_iterations);
        let per_step = (ps.newton_iterations - ps.locate_iterations) as f64 / ps.steps.max(1) as f64;
        let failed = ps.failed_iterations as f64 / ps.newton_iterations.max(1) as f64;
        println!(
            "{name}: {} Newton iterations, {} steps ({per_step:.2} per step), {:.1} % in failed attempts, {} locating the maximum",
            ps.newton_iterations,
            ps.steps,
            100.0 * failed,
            ps.locate_iterations
        );
        assert!(per_step <= 6.0 && failed <= 0.10, "{name}: {ps:?}");
    }
}
