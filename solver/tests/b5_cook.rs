//! B5 Cook's membrane (plane strain, κ/μ = 5000, Hei-Cast scaling): the locking test.
mod common;
use twistopt_solver::continuation::PathEnd;
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::verify::cook_membrane;

#[test]
fn b5_cook_membrane_mixed_elements_converge_and_q1_locks() {
    let b5 = common::shared("benchmarks/b5_cook_membrane.json");
    let refs = &b5["reference_values"]["heicast_mu0.34_kappa_over_mu_5000"];
    let uy_ref = refs["tip_uy_mm"].as_f64().unwrap();
    let traction = refs["traction_N_per_mm2"].as_f64().unwrap();
    assert!((uy_ref - 6.9339).abs() < 1e-4);

    // Q2/P1 (Hex27), 16 × 16: within 0.5 %
    let q2 = cook_membrane(Formulation::standard(ElementKind::Hex27), 16, 5000.0, traction).unwrap();
    assert_eq!(q2.status, PathEnd::Completed);
    let e2 = (q2.uy - uy_ref) / uy_ref;
    assert!(e2.abs() < 0.005, "Q2/P1 16x16: u_y = {} ({:+.3} %)", q2.uy, 100.0 * e2);
    // the reference's own Q2/P1 16 × 16 value (literature set, identical up to scaling)
    let own16 = b5["literature_set"]["meshes"].as_array().unwrap().iter().find(|m| m["n_elements_per_side"] == 16).unwrap()["tip_uy_mm"]["1.0"].as_f64().unwrap();
    assert!((q2.uy - own16).abs() < 1e-3 * own16, "Q2/P1 16x16 {} vs the reference code's 16x16 {own16}", q2.uy);

    // Q1/P0 (Hex8 mean dilatation), 32 × 32: within 1.5 %
    let q1 = cook_membrane(Formulation::standard(ElementKind::Hex8), 32, 5000.0, traction).unwrap();
    assert_eq!(q1.status, PathEnd::Completed);
    let e1 = (q1.uy - uy_ref) / uy_ref;
    assert!(e1.abs() < 0.015, "Q1/P0 32x32: u_y = {} ({:+.3} %)", q1.uy, 100.0 * e1);

    // pure-displacement Q1 locks: u_y < 5.5 mm (the locking indicator)
    let d = Formulation { kind: ElementKind::Hex8, pressure: PressureSpace::None, ngauss: 2 };
    let q1d = cook_membrane(d, 32, 5000.0, traction).unwrap();
    assert_eq!(q1d.status, PathEnd::Completed);
    assert!(q1d.uy < 5.5 && q1d.uy > 0.0, "pure-displacement Q1 32x32: u_y = {} (should lock)", q1d.uy);
    println!("B5 u_y: Q2/P1 16x16 {:.5} ({:+.3} %), Q1/P0 32x32 {:.5} ({:+.3} %), Q1 32x32 {:.5}", q2.uy, 100.0 * e2, q1.uy, 100.0 * e1, q1d.uy);
}
