//! Patch test: a distorted mesh whose boundary nodes follow a homogeneous deformation x = F X + c
//! reproduces it exactly at every interior node, with zero residual and uniform stress.
use twistopt_solver::continuation::{ramp, ContinuationOptions, PathEnd};
use twistopt_solver::dofmap::Constraints;
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};

#[test]
fn homogeneous_deformation_is_reproduced_on_a_distorted_mesh() {
    let f = [[1.2, 0.1, -0.05], [0.05, 0.95, 0.08], [-0.03, 0.02, 0.9]];
    for form in [Formulation::standard(ElementKind::Hex27), Formulation::standard(ElementKind::Hex8), Formulation { kind: ElementKind::Hex8, pressure: PressureSpace::None, ngauss: 2 }] {
        // interior lattice points displaced: a distorted (but valid) 3×3×3 mesh of the unit cube
        let mesh = meshgen::structured(form.kind, 3, 3, 3, |p| {
            let b = |t: f64| t * (1.0 - t);
            [p[0] + 0.15 * b(p[0]) * (p[1] - 0.4) + 0.05 * b(p[0]) * b(p[2]), p[1] + 0.12 * b(p[1]) * (p[2] - 0.6), p[2] + 0.1 * b(p[2]) * (p[0] - 0.5)]
        });
        let boundary: Vec<usize> = (0..mesh.n_nodes()).filter(|&n| ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"].iter().any(|s| mesh.node_sets[*s].contains(&n))).collect();
        let mut cons = Constraints::default();
        for &n in &boundary {
            let x = mesh.nodes[n];
            for i in 0..3 {
                let u = (0..3).map(|j| f[i][j] * x[j]).sum::<f64>() - x[i] + 0.01 * i as f64;
                cons.prescribed.push((n, i, u));
            }
        }
        let mat = NeoHookean::with_ratio(0.34, 100.0).unwrap();
        let model = Model::new(mesh, form, mat.into(), &cons, None).unwrap();
        let mut to = Loads::zero(&model);
        to.presc = model.dofs.presc_targets.clone();
        // the patch test is checked to round-off: converge Newton further than the path default
        let opts = ContinuationOptions { max: 0.1, newton: twistopt_solver::solve::NewtonOptions { rtol: 1e-12, ..Default::default() }, ..ContinuationOptions::default() };
        let res = ramp(&model, &vec![0.0; model.n_reduced()], &Loads::zero(&model), &to, &opts);
        assert_eq!(res.end, PathEnd::Completed, "{form:?}");
        let a = model.assemble(&res.q, &res.loads, false).unwrap();
        let mut worst: f64 = 0.0;
        for (n, x) in model.mesh.nodes.iter().enumerate() {
            for i in 0..3 {
                let exact = (0..3).map(|j| f[i][j] * x[j]).sum::<f64>() - x[i] + 0.01 * i as f64;
                worst = worst.max((a.u[n][i] - exact).abs());
            }
        }
        assert!(worst < 1e-9, "{form:?}: max nodal error {worst:e}");
        let rmax = a.r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(rmax < 1e-10, "{form:?}: residual {rmax:e}");
    }
}
