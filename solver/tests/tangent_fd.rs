//! The assembled reduced tangent equals central finite differences of the reduced residual, with
//! each constraint and load kind separately and all together.
mod common;
use twistopt_solver::dofmap::{Constraints, Cyclic, DofSpec, RigidBody};
use twistopt_solver::element::Formulation;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};

pub fn check(model: &Model, q: &[f64], loads: &Loads, tol: f64) {
    let (worst, _, _) = common::tangent_fd_error(model, q, loads, 1e-6);
    assert!(worst < tol, "tangent vs FD: worst relative error {worst:e}");
}

fn pseudo_random(n: usize, scale: f64) -> Vec<f64> {
    (0..n).map(|i| scale * (((i * 7919 + 13) % 101) as f64 / 101.0 - 0.5)).collect()
}

#[test]
fn material_and_geometric_parts_hex27_and_hex8() {
    for kind in [ElementKind::Hex27, ElementKind::Hex8] {
        let mesh = meshgen::boxed(kind, [2, 2, 2], [1.0, 1.0, 1.0]);
        let mut cons = Constraints::default();
        cons.prescribe_set(&mesh.node_sets["zmin"], &[0, 1, 2], 0.0);
        let mat = NeoHookean::with_ratio(0.34, 1000.0).unwrap();
        let model = Model::new(mesh, Formulation::standard(kind), mat.into(), &cons, None).unwrap();
        let q = pseudo_random(model.n_reduced(), 0.02);
        check(&model, &q, &Loads::zero(&model), 1e-6);
    }
}

/// A 120° tube sector with the bottom fixed and, optionally, cavity pressure, the top tied to a
/// rigid cap (free axial translation and free rotation vector), and cyclic symmetry between the
/// cut faces (otherwise the cut faces are held in their normal direction).
fn sector(pressure: bool, rigid: bool, cyclic: bool) -> (Model, Loads, Vec<f64>) {
    let kind = ElementKind::Hex27;
    let third = 2.0 * std::f64::consts::PI / 3.0;
    let mesh = meshgen::tube(kind, 3, 2, 1, 17.0, 20.0, (0.0, third), 40.0);
    let mut cons = Constraints::default();
    let bottom: Vec<usize> = (0..mesh.n_nodes()).filter(|&n| mesh.nodes[n][2].abs() < 1e-9).collect();
    let top: Vec<usize> = (0..mesh.n_nodes()).filter(|&n| (mesh.nodes[n][2] - 40.0).abs() < 1e-9).collect();
    cons.prescribe_set(&bottom, &[0, 1, 2], 0.0);
    if rigid {
        cons.bodies.push(RigidBody {
            name: "cap".into(),
            reference: [0.0, 0.0, 40.0],
            nodes: top.clone(),
            mask: [true; 3],
            dofs: [DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0), DofSpec::Free, DofSpec::Free, DofSpec::Free, DofSpec::Free],
        });
    }
    let xmin = mesh.node_sets["xmin"].clone();
    let xmax = mesh.node_sets["xmax"].clone();
    if cyclic {
        let (s, c) = third.sin_cos();
        let mut pairs = Vec::new();
        for &a in &xmin {
            let p = mesh.nodes[a];
            let rp = [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
            let b = *xmax.iter().find(|&&b| (0..3).all(|i| (mesh.nodes[b][i] - rp[i]).abs() < 1e-9)).unwrap();
            pairs.push((a, b));
        }
        cons.cyclic = Some(Cyclic { pairs, angle: third });
    } else {
        // y = 0 plane: u_y = 0 (the other cut is left free)
        for &n in &xmin {
            if !bottom.contains(&n) && !(rigid && top.contains(&n)) {
                cons.prescribed.push((n, 1, 0.0));
            }
        }
    }
    let cavity = mesh.face_sets["zmin"].clone(); // ζ = 0 is the inner radius (faces point inward)
    let mat = NeoHookean::with_ratio(0.34, 500.0).unwrap();
    let model = Model::new(mesh, Formulation::standard(kind), mat.into(), &cons, Some(&cavity)).unwrap();
    let mut loads = Loads::zero(&model);
    loads.pressure = if pressure { 0.05 } else { 0.0 };
    let mut q = pseudo_random(model.n_reduced(), 0.05);
    if rigid {
        let nr = model.n_reduced();
        q[nr - 3] = 0.1; // rotation vector components of the cap
        q[nr - 2] = -0.05;
        q[nr - 1] = 0.4;
    }
    (model, loads, q)
}

#[test]
fn follower_pressure_part() {
    let (m, l, q) = sector(true, false, false);
    check(&m, &q, &l, 1e-6);
}

#[test]
fn rigid_coupling_part() {
    let (m, l, q) = sector(false, true, false);
    check(&m, &q, &l, 1e-6);
}

#[test]
fn cyclic_constraint_part() {
    let (m, l, q) = sector(false, false, true);
    check(&m, &q, &l, 1e-6);
}

#[test]
fn pressure_rigid_body_and_cyclic_together() {
    let (m, l, q) = sector(true, true, true);
    check(&m, &q, &l, 1e-6);
}

#[test]
fn helical_periodic_constraint_parts() {
    // ring slice with the end faces tied by x_top = Q(α) x_bottom + (h + s) e_z, s free
    use twistopt_solver::verify::torsion_slice;
    for kind in [ElementKind::Hex27, ElementKind::Hex8] {
        let s = torsion_slice(kind, Formulation::standard(kind), 8, 1, 2.0, 500.0, true).unwrap();
        let mut loads = Loads::zero(&s.model);
        loads.presc[s.twist_slot] = 0.05;
        let q = pseudo_random(s.model.n_reduced(), 0.05);
        check(&s.model, &q, &loads, 1e-6);
    }
}
