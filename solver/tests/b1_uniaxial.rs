//! B1: homogeneous uniaxial tension/compression against the exact compressible solution.
mod common;
use twistopt_solver::continuation::{ramp, ContinuationOptions, PathEnd};
use twistopt_solver::dofmap::Constraints;
use twistopt_solver::element::Formulation;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};

fn uniaxial(kind: ElementKind, ratio: f64, stretches: &[f64]) -> Vec<(f64, f64, f64)> {
    // one Q2 element or a 2x2x2 Q1 block (the deformation is homogeneous: any mesh is exact)
    let n = if kind == ElementKind::Hex27 { 1 } else { 2 };
    let mesh = meshgen::boxed(kind, [n, n, n], [1.0, 1.0, 1.0]);
    let mut cons = Constraints::default();
    cons.prescribe_set(&mesh.node_sets["xmin"], &[0], 0.0);
    cons.prescribe_set(&mesh.node_sets["ymin"], &[1], 0.0);
    cons.prescribe_set(&mesh.node_sets["zmin"], &[2], 0.0);
    let xmax = mesh.node_sets["xmax"].clone();
    cons.prescribe_set(&xmax, &[0], 1.0);
    let mat = NeoHookean::with_ratio(0.34, ratio).unwrap();
    let model = Model::new(mesh, Formulation::standard(kind), mat.into(), &cons, None).unwrap();
    let mut out = Vec::new();
    for &lam in stretches {
        let from = Loads::zero(&model);
        let mut to = Loads::zero(&model);
        for (s, (n, c)) in model.dofs.presc_nodes.iter().enumerate() {
            if *c == 0 && xmax.contains(n) {
                to.presc[s] = lam - 1.0;
            }
        }
        let q0 = vec![0.0; model.n_reduced()];
        // the benchmark is checked to 1e-8: converge Newton further than the path default
        let opts = ContinuationOptions { max: 0.02, newton: twistopt_solver::solve::NewtonOptions { rtol: 1e-11, ..Default::default() }, ..ContinuationOptions::default() };
        let res = ramp(&model, &q0, &from, &to, &opts);
        assert_eq!(res.end, PathEnd::Completed, "{kind:?} κ/μ = {ratio}, λ = {lam}");
        let a = res.assembled.unwrap();
        let force = xmax.iter().map(|&n| a.r_full[3 * n]).sum::<f64>();
        // lateral stretch from the corner node (1,1,1)
        let corner = (0..model.mesh.n_nodes()).find(|&n| model.mesh.nodes[n] == [1.0, 1.0, 1.0]).unwrap();
        let lat = 1.0 + a.u[corner][1];
        out.push((lam, force, lat)); // area 1 → force = nominal stress
    }
    out
}

#[test]
fn b1_matches_compressible_reference_to_1e8() {
    let b1 = common::shared("benchmarks/b1_uniaxial_tension.json");
    for (key, ratio) in [("kappa_over_mu_1000", 1000.0), ("kappa_over_mu_5000", 5000.0)] {
        let rows = b1["compressible"]["quad"][key].as_array().unwrap();
        let lams: Vec<f64> = rows.iter().map(|r| r["stretch"].as_f64().unwrap()).collect();
        // Q1/P0 (mean dilatation) over the whole range; Q2/P1 down to λ = 0.8: below about 0.75
        // the Q2/P1 block bifurcates into a spurious non-homogeneous mode (a known property of
        // mixed elements in large compression, see solver/README.md).
        for kind in [ElementKind::Hex8, ElementKind::Hex27] {
            let sel: Vec<(usize, f64)> = lams.iter().copied().enumerate().filter(|(_, l)| kind == ElementKind::Hex8 || *l >= 0.8).collect();
            let got = uniaxial(kind, ratio, &sel.iter().map(|x| x.1).collect::<Vec<_>>());
            for ((i, _), (lam, p, t)) in sel.iter().zip(got) {
                let row = &rows[*i];
                let pref = row["nominal_stress_MPa"].as_f64().unwrap();
                let tref = row["lateral_stretch"].as_f64().unwrap();
                assert!((p - pref).abs() <= 1e-8 * pref.abs() + 1e-13, "{kind:?} {key} λ={lam}: P {p} vs {pref}");
                assert!(((t - tref) / tref).abs() < 1e-8, "{kind:?} {key} λ={lam}: t {t} vs {tref}");
            }
        }
    }
}
