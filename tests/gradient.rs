//! Adjoint gradients against central finite differences (one-sided at the Table-I bounds) at
//! coarse fidelity, for five designs across the space in the free, blocked and pure-twist scenes;
//! path independence; the CLI's gradient.json.

use std::process::Command;
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::gradient::{fd_check, max_rel_error, scene_gradient, DEFAULT_KS_RHO_PER_MM};
use twistopt::meshing::MeshSpec;
use twistopt::scene::{SceneKind, SceneOptions};
use twistopt_solver::material::{Material, NeoHookean};

const R_MIN: f64 = 8.660254037844386; // 5√3
const P_KPA: f64 = 20.0;

fn opts() -> SceneOptions {
    SceneOptions::new(MeshSpec::preset("coarse").unwrap(), Material::NeoHookean(NeoHookean::with_ratio(0.34, 300.0).unwrap()))
}

/// Adjoint vs FD (steps 1e-4 and 1e-5 of each parameter's range, plus their Richardson
/// extrapolation): every component within 1e-5 relative.
fn check_design(r: f64, l: f64, alpha: f64) {
    let g = ActuatorGeometry::new(&Design::new(r, l, alpha), RangePolicy::TableI).unwrap();
    let o = opts();
    for kind in [SceneKind::Free, SceneKind::Blocked, SceneKind::PureTwist] {
        let sg = scene_gradient(&g, &o, kind, P_KPA, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
        assert_eq!(sg.status, twistopt::scene::SceneStatus::Converged, "{kind:?} at ({r}, {l}, {alpha}): {}", sg.cause);
        assert!(sg.ks_gap_mm >= 0.0 && sg.ks_gap_mm < 0.3, "KS gap {}", sg.ks_gap_mm);
        // every functional has a gradient w.r.t. r, l, α, p, μ
        for grad in sg.gradients.values() {
            for name in ["r_mm", "l_mm", "alpha_deg", "p_kPa", "mu_MPa"] {
                assert!(grad[name].is_finite(), "{name}");
            }
        }
        let rep = fd_check(&g, &o, kind, &sg, &[1e-4, 1e-5]);
        let worst = max_rel_error(&rep);
        let detail: Vec<String> =
            rep.iter().flat_map(|(f, m)| m.iter().filter(|(_, c)| !(c.rel_error <= 1e-5)).map(move |(p, c)| format!("{f}/{p}: adjoint {} fd {:?} rel {}", c.adjoint, c.fd, c.rel_error))).collect();
        assert!(worst <= 1e-5, "{kind:?} at ({r}, {l}, {alpha}): max rel error {worst:e}: {detail:?}");
    }
}

#[test]
fn adjoint_matches_fd_thinnest_wall_full_twist() {
    check_design(R_MIN, 15.0, 360.0);
}

#[test]
fn adjoint_matches_fd_narrow_waist() {
    check_design(13.0, 10.0, 120.0);
}

#[test]
fn adjoint_matches_fd_straight_profile() {
    check_design(10.0, 20.0, 240.0);
}

#[test]
fn adjoint_matches_fd_mid_space() {
    check_design(14.33, 15.0, 210.0);
}

/// The gradient depends on the final state only: two different load-step histories give the
/// same values and gradients (to the Newton tolerance).
#[test]
fn gradient_is_path_independent() {
    let g = ActuatorGeometry::new(&Design::new(R_MIN, 12.0, 150.0), RangePolicy::TableI).unwrap();
    let mut a = opts();
    a.steps.initial = 0.5;
    a.steps.max = 0.5;
    let mut b = opts();
    b.steps.initial = 0.05;
    b.steps.max = 0.1;
    let ga = scene_gradient(&g, &a, SceneKind::Free, 25.0, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
    let gb = scene_gradient(&g, &b, SceneKind::Free, 25.0, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
    assert_ne!(gb.cost.newton_iterations, ga.cost.newton_iterations, "the histories differ");
    for (f, grad) in &ga.gradients {
        for (p, v) in grad {
            let w = gb.gradients[f][p];
            assert!((v - w).abs() <= 1e-7 * v.abs().max(1e-9), "{f}/{p}: {v} vs {w}");
        }
        let (va, vb) = (ga.values[f], gb.values[f]);
        assert!((va - vb).abs() <= 1e-9 * va.abs().max(1e-9), "{f}: {va} vs {vb}");
    }
}

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twistopt"))
}

/// The CLI on the paper example (free + blocked, coarse, 20 kPa): gradient.json with values,
/// gradients by parameter name, Ω's gradient, the FD comparison and `max_rel_error`.
#[test]
fn cli_gradient_check_fd() {
    let dir = std::env::temp_dir().join(format!("twistopt-gradient-{}", std::process::id()));
    let out =
        bin().args(["gradient", "problems/paper-example.toml", "--set", "fidelity.preset=coarse", "--pressure", "20", "--check-fd", "--fd-steps", "1e-4,1e-5", "--out"]).arg(&dir).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("gradient.json")).unwrap()).unwrap();
    let worst = doc["max_rel_error"].as_f64().unwrap();
    assert!(worst <= 1e-5, "max_rel_error {worst}");
    let th = &doc["scenes"]["free"];
    assert_eq!(th["status"], "converged");
    assert!(th["values"]["theta_deg"].as_f64().unwrap() < 0.0);
    for p in ["r_mm", "l_mm", "alpha_deg", "p_kPa", "mu_MPa"] {
        assert!(th["gradients"]["theta_deg"][p].as_f64().is_some(), "{p}");
        assert!(doc["scenes"]["blocked"]["gradients"]["tau_Nm"][p].as_f64().is_some(), "{p}");
    }
    // Ω = k θ τ and its gradient by the product rule
    let om = &doc["omega"]["combined"];
    let (t, q) = (th["values"]["theta_deg"].as_f64().unwrap(), doc["scenes"]["blocked"]["values"]["tau_Nm"].as_f64().unwrap());
    let k = twistopt::scene::energy_density(1.0, 1.0);
    assert!((om["value"].as_f64().unwrap() - k * t * q).abs() < 1e-12 * (k * t * q).abs());
    let dp = k * (q * th["gradients"]["theta_deg"]["p_kPa"].as_f64().unwrap() + t * doc["scenes"]["blocked"]["gradients"]["tau_Nm"]["p_kPa"].as_f64().unwrap());
    assert!((om["gradient"]["p_kPa"].as_f64().unwrap() - dp).abs() < 1e-12 * dp.abs());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cli_gradient_rejects_bad_input() {
    let dir = std::env::temp_dir().join(format!("twistopt-gradient-bad-{}", std::process::id()));
    for extra in [vec!["--pressure", "nan"], vec!["--ks-rho", "-1"], vec!["--fd-steps", "0.5"]] {
        let out = bin().args(["gradient", "problems/paper-example.toml"]).args(&extra).arg("--out").arg(&dir).output().unwrap();
        assert!(!out.status.success(), "{extra:?} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.starts_with("error:") && !err.contains("panicked"), "{extra:?}: {err}");
    }
}

/// The limit pressure (the pressure maximum ending a ramp) and its sensitivity by the null-vector
/// formula: exact in μ (p_lim ∝ μ at fixed κ/μ, so dp_lim/dμ = p_lim/μ) and against central
/// differences of p_lim in α and l (p_lim is located under volume control to 1e-6 relative).
#[test]
fn limit_pressure_sensitivity() {
    let mut o = opts();
    o.mesh = MeshSpec::parse("12x4x1").unwrap();
    let run = |l: f64, a: f64| {
        let g = ActuatorGeometry::new(&Design::new(R_MIN, l, a), RangePolicy::TableI).unwrap();
        scene_gradient(&g, &o, SceneKind::Blocked, 40.0, DEFAULT_KS_RHO_PER_MM, None, Some(90.0)).unwrap()
    };
    let base = run(16.8, 250.0);
    let pl = base.p_limit_kpa.expect("a pressure maximum below 90 kPa");
    assert!(pl > 40.0 && pl < 90.0, "{pl}");
    let dmu = base.p_limit_gradient["mu_MPa"];
    assert!((dmu - pl / 0.34).abs() < 1e-3 * pl / 0.34, "dp_lim/dmu {dmu} vs p_lim/mu {}", pl / 0.34);
    for (name, h, l, a) in [("alpha_deg", 1.0, 0.0, 1.0), ("l_mm", 0.1, 1.0, 0.0)] {
        let p = run(16.8 + l * h, 250.0 + a * h).p_limit_kpa.unwrap();
        let m = run(16.8 - l * h, 250.0 - a * h).p_limit_kpa.unwrap();
        let fd = (p - m) / (2.0 * h);
        let ad = base.p_limit_gradient[name];
        eprintln!("{name}: dp_lim null-vector {ad} vs central FD {fd}");
        assert!((fd - ad).abs() < 0.005 * fd.abs().max(1e-3), "{name}: null-vector {ad} vs fd {fd}");
    }
}
