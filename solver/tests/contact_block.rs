//! Contact benchmark: a block pressed on a rigid frictionless plane through the log-barrier
//! contact ([`twistopt_solver::contact`]). The exact answer is B1's homogeneous uniaxial
//! compression: the contact pressure equals the applied nominal stress, uniformly (each contact
//! node carries the consistent nodal load of that pressure), and the block's stretch and lateral
//! stretch are B1's. A second test presses a block on a wider deformable block (node-to-triangle
//! contact with moving triangles): action equals reaction, nothing penetrates, and the tangent
//! equals central differences of the residual at the contact state. A third checks adjoint
//! sensitivities at a contact state against central differences of re-solved models.
mod common;
use std::collections::BTreeMap;
use twistopt_solver::contact::{self, Barrier, Contact, Slave};
use twistopt_solver::continuation::{correct, ramp, ContinuationOptions, LoadPath, PathEnd, PathModel};
use twistopt_solver::dofmap::Constraints;
use twistopt_solver::element::Formulation;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::{ElementKind, Mesh};
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};

const KIND: ElementKind = ElementKind::Hex27;

/// The loads with every prescribed slot of `nodes` in component `c` set to `v`.
fn loads_with(model: &Model, nodes: &[usize], c: usize, v: f64) -> Loads {
    let mut l = Loads::zero(model);
    for (s, (n, cc)) in model.dofs.presc_nodes.iter().enumerate() {
        if *cc == c && nodes.contains(n) {
            l.presc[s] = v;
        }
    }
    l
}

fn opts() -> ContinuationOptions {
    ContinuationOptions { max: 0.05, newton: twistopt_solver::solve::NewtonOptions { rtol: 1e-12, ..Default::default() }, ..ContinuationOptions::default() }
}

/// Unit cube on rollers (x = 0, y = 0), its top pushed down by `s`, its bottom face in barrier
/// contact with the rigid plane z = −g0.
struct Block {
    model: Model,
    top: Vec<usize>,
    bottom: Vec<usize>,
    weights: Vec<(usize, f64)>,
}

fn block(ratio: f64, barrier: Barrier, g0: f64) -> Block {
    let mesh = meshgen::boxed(KIND, [2, 2, 2], [1.0, 1.0, 1.0]);
    let mut cons = Constraints::default();
    cons.prescribe_set(&mesh.node_sets["xmin"], &[0], 0.0);
    cons.prescribe_set(&mesh.node_sets["ymin"], &[1], 0.0);
    let top = mesh.node_sets["zmax"].clone();
    let bottom = mesh.node_sets["zmin"].clone();
    cons.prescribe_set(&top, &[2], 0.0);
    let weights = contact::nodal_areas(&mesh, &mesh.face_sets["zmin"]);
    let triangles = contact::plane_obstacle([0.5, 0.5, -g0], [0.0, 0.0, 1.0], 10.0);
    let slaves = weights.iter().map(|&(node, weight)| Slave { node, weight, targets: vec![0, 1] }).collect();
    let mat = NeoHookean::with_ratio(0.34, ratio).unwrap();
    let mut model = Model::new(mesh, Formulation::standard(KIND), mat.into(), &cons, None).unwrap();
    let blend = Contact::default_blend(&triangles, &model.mesh.nodes);
    model.set_contact(Contact { barrier, blend, triangles, slaves, faces: model.mesh.face_sets["zmin"].clone(), axle: None, planes: Vec::new() }).unwrap();
    Block { model, top, bottom, weights }
}

#[test]
fn block_on_rigid_plane_is_b1_compression() {
    let b1 = common::shared("benchmarks/b1_uniaxial_tension.json");
    let rows = b1["compressible"]["quad"]["kappa_over_mu_1000"].as_array().unwrap();
    let barrier = Barrier { dhat: 1e-3, kappa: 20.0 };
    let g0 = 1.5e-3; // the plane starts beyond the barrier's reach: the unloaded block is at rest
    let blk = block(1000.0, barrier, g0);
    let m = &blk.model;
    // Q2/P1 stays homogeneous down to λ = 0.8 (see b1_uniaxial.rs)
    for lam_ref in [0.9, 0.8] {
        let row = rows.iter().find(|r| (r["stretch"].as_f64().unwrap() - lam_ref).abs() < 1e-12).unwrap();
        let p_ref = row["nominal_stress_MPa"].as_f64().unwrap();
        let t_ref = row["lateral_stretch"].as_f64().unwrap();
        // the top displacement that gives the stretch λ: s = (1 − λ) + g0 − gap, the gap being
        // unknown in advance; a secant on the measured stretch
        let mut s = (1.0 - lam_ref) + g0;
        let to = loads_with(m, &blk.top, 2, -s);
        let res = ramp(m, &vec![0.0; m.n_reduced()], &Loads::zero(m), &to, &opts());
        assert_eq!(res.end, PathEnd::Completed, "λ = {lam_ref}, s = {s}");
        let mut q = res.q;
        let mut a = res.assembled.unwrap();
        // secant corrections by Newton from the last state (a ramp over a tiny load change would
        // judge its steps by prediction errors at round-off level)
        let mut prev: Option<(f64, f64)> = None;
        for _ in 0..8 {
            let lam = 1.0 + a.u[blk.top[0]][2] - a.u[blk.bottom[0]][2];
            if (lam - lam_ref).abs() < 1e-12 {
                break;
            }
            let slope = prev.map_or(-1.0, |(s0, l0)| (lam - l0) / (s - s0));
            prev = Some((s, lam));
            s -= (lam - lam_ref) / slope;
            let to = loads_with(m, &blk.top, 2, -s);
            let lp = LoadPath::new(m, to.clone(), to.clone(), Vec::new());
            let sol = correct(&lp, &q, 0.0, None, &opts().newton, true, None, false).unwrap_or_else(|e| panic!("λ = {lam_ref}, s = {s}: {e:?}"));
            q = sol.q;
            a = m.assemble(&q, &to, false).unwrap();
        }
        let lam = 1.0 + a.u[blk.top[0]][2] - a.u[blk.bottom[0]][2];
        assert!((lam - lam_ref).abs() < 1e-12, "stretch {lam} vs {lam_ref}");
        // homogeneous: every bottom node at the same gap, every top node at the same height
        let gaps: Vec<f64> = blk.bottom.iter().map(|&n| a.u[n][2] + g0).collect();
        let (gmin, gmax) = gaps.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &g| (lo.min(g), hi.max(g)));
        assert!(gmin > 0.0 && gmin < barrier.dhat, "gap {gmin}");
        assert!(gmax - gmin < 1e-12, "gaps spread {gmin}..{gmax}");
        assert!((a.contact_gap - gmin).abs() < 1e-14);
        // the nominal stress from the top reaction (area 1) is B1's
        let p_top: f64 = blk.top.iter().map(|&n| a.r_full[3 * n + 2]).sum();
        assert!((p_top - p_ref).abs() <= 1e-8 * p_ref.abs(), "λ = {lam_ref}: P {p_top} vs {p_ref}");
        // the lateral stretch is B1's
        let corner = (0..m.mesh.n_nodes()).find(|&n| m.mesh.nodes[n] == [1.0, 1.0, 1.0]).unwrap();
        let t = 1.0 + a.u[corner][0];
        assert!(((t - t_ref) / t_ref).abs() < 1e-8, "λ = {lam_ref}: t {t} vs {t_ref}");
        // the contact pressure is the applied one: κ|b'(gap)| = |P|, and each node carries the
        // consistent load |P|·∫N dA of a uniform pressure
        assert!((barrier.pressure(gmin) - p_ref.abs()).abs() <= 1e-8 * p_ref.abs(), "contact pressure {} vs {}", barrier.pressure(gmin), p_ref.abs());
        let x = |n: usize| [m.mesh.nodes[n][0] + a.u[n][0], m.mesh.nodes[n][1] + a.u[n][1], m.mesh.nodes[n][2] + a.u[n][2]];
        let (terms, _) = m.contact().unwrap().terms(&x, false).unwrap();
        assert_eq!(terms.len(), blk.weights.len());
        let mut total = 0.0;
        for (t, &(node, w)) in terms.iter().zip(&blk.weights) {
            assert_eq!(t.nodes, vec![node]);
            let f = -t.force[2]; // the plane pushes up
            assert!((f - p_ref.abs() * w).abs() <= 1e-8 * p_ref.abs() * w, "node {node}: {f} vs {}", p_ref.abs() * w);
            assert!(t.force[0].abs() < 1e-15 && t.force[1].abs() < 1e-15, "frictionless");
            total += f;
        }
        assert!((total - p_ref.abs()).abs() <= 1e-8 * p_ref.abs());
    }
}

#[test]
fn block_cannot_be_pushed_through_the_plane() {
    // a state with the bottom just behind the plane is refused (the Newton line search cuts the
    // step); a step that would carry it farther through is cut before the plane (collision check)
    let blk = block(1000.0, Barrier { dhat: 1e-3, kappa: 20.0 }, 1.5e-3);
    let m = &blk.model;
    // the whole block translated 1.6 mm down (no element distorts): its bottom is 0.1 d̂ behind
    // the plane
    let through = 1.6e-3;
    let loads = loads_with(m, &blk.top, 2, -through);
    let mut q = vec![0.0; m.n_reduced()];
    let mut idx = Vec::new();
    for n in 0..m.mesh.n_nodes() {
        if !m.dofs.is_prescribed(n, 2) {
            idx.clear();
            m.dofs.row_pattern(n, 2, &mut idx);
            assert_eq!(idx.len(), 1);
            q[idx[0] as usize] = -through;
        }
    }
    match m.assemble(&q, &loads, false) {
        Err(twistopt_solver::element::ElementError::Penetration(n)) => assert!(blk.bottom.contains(&n)),
        other => panic!("expected a penetration error, got {:?}", other.map(|a| a.contact_gap)),
    }
    // the step from rest to 1 m through the plane is cut at 0.8 of the way to the plane
    let lp = LoadPath::new(m, loads.clone(), loads.clone(), Vec::new());
    let far: Vec<f64> = q.iter().map(|v| v / through * 1e3).collect();
    let tau = lp.step_limit(&vec![0.0; m.n_reduced()], 0.0, &far);
    assert!((tau - 0.8 * 1.5e-3 / 1e3).abs() < 1e-6 * tau, "{tau}");
}

/// Two meshes in one (node and element ids of `b` offset; sets prefixed "a_" and "b_").
fn merge(a: Mesh, b: Mesh) -> Mesh {
    let (na, ea) = (a.n_nodes(), a.n_elements());
    let mut node_sets = BTreeMap::new();
    let mut face_sets = BTreeMap::new();
    for (k, v) in a.node_sets {
        node_sets.insert(format!("a_{k}"), v);
    }
    for (k, v) in b.node_sets {
        node_sets.insert(format!("b_{k}"), v.into_iter().map(|n| n + na).collect());
    }
    for (k, v) in a.face_sets {
        face_sets.insert(format!("a_{k}"), v);
    }
    for (k, v) in b.face_sets {
        face_sets.insert(
            format!("b_{k}"),
            v.into_iter()
                .map(|mut f| {
                    f.element += ea;
                    f
                })
                .collect(),
        );
    }
    let mut nodes = a.nodes;
    nodes.extend(b.nodes);
    let mut connectivity = a.connectivity;
    connectivity.extend(b.connectivity.into_iter().map(|n| n + na));
    Mesh { nodes, kind: a.kind, connectivity, node_sets, face_sets }
}

#[test]
fn block_on_deformable_block_balances_and_has_a_consistent_tangent() {
    // lower block [−0.6,2.2]²×[−1,0] (bottom fixed in z), upper block [0,1]²×[g0, 1+g0] above it
    // (each on rollers at its own x_min, y_min faces, so that every slave is over the target's
    // interior, not on its free edge); node-to-surface contact of the upper block's bottom nodes
    // with the lower block's triangulated top face (moving triangles, which the upper block dents).
    // Checked at a synthetic contact state (the upper block moved into the barrier's reach, every
    // node perturbed): the contact forces on the slaves and on the target nodes balance in force
    // and moment, and the tangent equals central differences of the residual; then along a ramp
    // into contact: it completes, the base carries the top's load, and the tangent at its end
    // equals central differences. (With the closest triangle's distance instead of the blended
    // one, Newton stalled on this ramp at a relative residual of 1e-6 to 1e-4: the distance's
    // gradient jumps over every concave crease of the dented surface.)
    let g0 = 1.5e-3;
    let lower = meshgen::structured(KIND, 3, 3, 1, |p| [2.8 * p[0] - 0.6, 2.8 * p[1] - 0.6, p[2] - 1.0]);
    let upper = meshgen::structured(KIND, 1, 1, 1, |p| [p[0], p[1], p[2] + g0]);
    let mesh = merge(lower, upper);
    let mut cons = Constraints::default();
    for part in ["a", "b"] {
        cons.prescribe_set(&mesh.node_sets[&format!("{part}_xmin")], &[0], 0.0);
        cons.prescribe_set(&mesh.node_sets[&format!("{part}_ymin")], &[1], 0.0);
    }
    let base = mesh.node_sets["a_zmin"].clone();
    let top = mesh.node_sets["b_zmax"].clone();
    cons.prescribe_set(&base, &[2], 0.0);
    cons.prescribe_set(&top, &[2], 0.0);
    let triangles: Vec<contact::Triangle> = mesh.face_sets["a_zmax"].iter().flat_map(|&f| contact::face_triangles(&mesh, f)).collect();
    let all: Vec<usize> = (0..triangles.len()).collect();
    let slaves: Vec<Slave> = contact::nodal_areas(&mesh, &mesh.face_sets["b_zmin"]).into_iter().map(|(node, weight)| Slave { node, weight, targets: all.clone() }).collect();
    let slave_nodes: Vec<usize> = slaves.iter().map(|s| s.node).collect();
    let target_nodes: Vec<usize> = mesh.node_sets["a_zmax"].clone();
    let barrier = Barrier { dhat: 1e-3, kappa: 20.0 };
    let mat = NeoHookean::with_ratio(0.34, 1000.0).unwrap();
    let mut model = Model::new(mesh, Formulation::standard(KIND), mat.into(), &cons, None).unwrap();
    let blend = Contact::default_blend(&triangles, &model.mesh.nodes);
    model.set_contact(Contact { barrier, blend, triangles, slaves, faces: model.mesh.face_sets["b_zmin"].clone(), axle: None, planes: Vec::new() }).unwrap();
    // the upper block 1.2 mm down (gap ≈ 0.3 d̂), every free unknown perturbed by up to 1e-5
    let loads = loads_with(&model, &top, 2, -1.2e-3);
    let mut q = vec![0.0; model.n_reduced()];
    let mut idx = Vec::new();
    for n in 0..model.mesh.n_nodes() {
        let upper_node = model.mesh.nodes[n][2] >= g0 - 1e-12;
        for c in 0..3 {
            if !model.dofs.is_prescribed(n, c) {
                idx.clear();
                model.dofs.row_pattern(n, c, &mut idx);
                let shift = if c == 2 && upper_node { -1.2e-3 } else { 0.0 };
                q[idx[0] as usize] = shift + 2e-5 * (((n * 31 + c * 7) % 13) as f64 / 13.0 - 0.5);
            }
        }
    }
    let a = model.assemble(&q, &loads, false).unwrap();
    assert!(a.contact_gap > 0.0 && a.contact_gap < 0.6 * barrier.dhat, "gap {}", a.contact_gap);
    let x = |n: usize| [model.mesh.nodes[n][0] + a.u[n][0], model.mesh.nodes[n][1] + a.u[n][1], model.mesh.nodes[n][2] + a.u[n][2]];
    let (terms, _) = model.contact().unwrap().terms(&x, false).unwrap();
    assert_eq!(terms.len(), slave_nodes.len(), "every slave within reach");
    let (mut on_slaves, mut on_targets, mut moment) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    for t in &terms {
        assert!(t.nodes.len() >= 4, "a slave and at least one deformable triangle");
        assert!(t.nodes[1..].iter().all(|n| target_nodes.contains(n)));
        for (k, &n) in t.nodes.iter().enumerate() {
            let f = [t.force[3 * k], t.force[3 * k + 1], t.force[3 * k + 2]];
            let dst = if slave_nodes.contains(&n) { &mut on_slaves } else { &mut on_targets };
            let p = x(n);
            for c in 0..3 {
                dst[c] += f[c];
            }
            let m = [p[1] * f[2] - p[2] * f[1], p[2] * f[0] - p[0] * f[2], p[0] * f[1] - p[1] * f[0]];
            for c in 0..3 {
                moment[c] += m[c];
            }
        }
    }
    let scale = on_slaves[2].abs();
    assert!(scale > 1e-3, "the slaves are pushed up: {on_slaves:?}");
    assert!(on_slaves[2] < 0.0, "force convention: ∂E/∂x of a compressed slave points down");
    for c in 0..3 {
        assert!((on_slaves[c] + on_targets[c]).abs() <= 1e-12 * scale, "action = reaction ({c}): {on_slaves:?} {on_targets:?}");
        assert!(moment[c].abs() <= 1e-12 * scale, "moment balance ({c}): {moment:?}");
    }
    tangent_matches_differences(&model, &q, &loads);
    // a ramp into contact: the upper block pressed 0.1 mm
    let to = loads_with(&model, &top, 2, -0.1);
    let opts = ContinuationOptions {
        max: 0.05,
        // the unloaded blocks' residual sits at round-off ≈ κ·ε ≈ 1e-13 N, above the default atol
        newton: twistopt_solver::solve::NewtonOptions { atol: 1e-11, ..Default::default() },
        ..ContinuationOptions::default()
    };
    let res = ramp(&model, &vec![0.0; model.n_reduced()], &Loads::zero(&model), &to, &opts);
    assert_eq!(res.end, PathEnd::Completed);
    assert!(res.stats.failed_attempts <= 2, "{:?}", res.stats);
    let a = res.assembled.unwrap();
    assert!(a.contact_gap > 0.0 && a.contact_gap < barrier.dhat, "gap {}", a.contact_gap);
    let fz = |nodes: &[usize]| nodes.iter().map(|&n| a.r_full[3 * n + 2]).sum::<f64>();
    let (p_top, p_base) = (fz(&top), fz(&base));
    assert!(p_top < -0.02, "the top is pushed: {p_top}");
    assert!((p_base + p_top).abs() <= 1e-9 * p_top.abs(), "base {p_base} vs top {p_top}");
    tangent_matches_differences(&model, &res.q, &res.loads);
}

fn tangent_matches_differences(model: &Model, q: &[f64], loads: &Loads) {
    let worst = common::tangent_fd_error(model, q, loads, 1e-8);
    assert!(worst.0 < 1e-6, "tangent vs FD: worst relative error {:e} at ({}, {})", worst.0, worst.1, worst.2);
}

/// A block (rollers x = 0, y = 0) whose top face is a rigid cap held at z = −push, pressed on the
/// rigid plane z = −g0, on the mesh moved by `dx0 × h`.
fn capped_block(dx0: &dyn Fn([f64; 3]) -> [f64; 3], h: f64) -> (Model, Loads) {
    let mut mesh = meshgen::boxed(KIND, [2, 2, 2], [1.0, 1.0, 1.0]);
    for x in mesh.nodes.iter_mut() {
        let d = dx0(*x);
        for c in 0..3 {
            x[c] += h * d[c];
        }
    }
    let top = mesh.node_sets["zmax"].clone();
    let mut cons = Constraints::default();
    cons.prescribe_set(&mesh.node_sets["xmin"], &[0], 0.0);
    cons.prescribe_set(&mesh.node_sets["ymin"], &[1], 0.0);
    use twistopt_solver::dofmap::{DofSpec, RigidBody};
    cons.bodies.push(RigidBody {
        name: "cap".into(),
        reference: [0.0, 0.0, 1.0],
        nodes: top,
        mask: [false, false, true],
        dofs: [DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0), DofSpec::Prescribed(0.0)],
    });
    let faces = mesh.face_sets["zmin"].clone();
    let weights = contact::nodal_areas(&mesh, &faces);
    let triangles = contact::plane_obstacle([0.5, 0.5, -1.5e-3], [0.0, 0.0, 1.0], 10.0);
    let slaves = weights.iter().map(|&(node, weight)| Slave { node, weight, targets: vec![0, 1] }).collect();
    let mat = NeoHookean::with_ratio(0.34, 100.0).unwrap();
    let mut model = Model::new(mesh, Formulation::standard(KIND), mat.into(), &cons, None).unwrap();
    let blend = Contact::default_blend(&triangles, &model.mesh.nodes);
    model.set_contact(Contact { barrier: Barrier { dhat: 1e-3, kappa: 20.0 }, blend, triangles, slaves, faces, axle: None, planes: Vec::new() }).unwrap();
    let mut loads = Loads::zero(&model);
    let twistopt_solver::dofmap::BodyDof::Presc(slot) = model.dofs.body_dofs[0][2] else { panic!("cap z is prescribed") };
    loads.presc[slot] = -0.1;
    (model, loads)
}

#[test]
fn sensitivities_through_contact_match_central_differences() {
    // the cap's reaction (the force that presses the block on the plane) at a contact state, and
    // its derivatives in three directions: the block widened (the contact weights grow with the
    // area), its bottom tilted (unequal gaps: non-uniform contact) and the cap pushed further
    use twistopt_solver::adjoint::{sensitivities, Direction, Functional};
    let width = |x: [f64; 3]| [x[0], x[1], 0.0];
    let tilt = |x: [f64; 3]| [0.0, 0.0, 0.02 * x[0] * (1.0 - x[2])];
    let none = |_: [f64; 3]| [0.0; 3];
    let (m, loads) = capped_block(&none, 0.0);
    let res = ramp(&m, &vec![0.0; m.n_reduced()], &Loads::zero(&m), &loads, &opts());
    assert_eq!(res.end, PathEnd::Completed);
    let q = res.q;
    let a = m.assemble(&q, &loads, true).unwrap();
    assert!(a.contact_gap < 1e-3, "in contact: gap {}", a.contact_gap);
    let f = m.factor(a.k.as_ref().unwrap()).unwrap();
    let twistopt_solver::dofmap::BodyDof::Presc(slot) = m.dofs.body_dofs[0][2] else { unreachable!() };
    let mut dpresc = vec![0.0; loads.presc.len()];
    dpresc[slot] = -1.0;
    let dir = |name: &str, g: &dyn Fn([f64; 3]) -> [f64; 3]| Direction { name: name.into(), dx0: Some(m.mesh.nodes.iter().map(|x| g(*x)).collect()), ..Default::default() };
    let dirs = vec![dir("width", &width), dir("tilt", &tilt), Direction { name: "push".into(), dpresc, ..Default::default() }];
    let fun = [Functional::BodyReaction { body: 0, dof: 2 }];
    let sens = sensitivities(&m, &q, &loads, &f, &fun, &dirs).unwrap();
    // the reaction itself: the contact force on the plane, minus the cap's (B1-like compression)
    let reaction = sens.values[0];
    assert!(reaction.abs() > 0.01, "reaction {reaction}");
    // central differences: re-solved models on the moved mesh / at the moved cap, Newton from q
    let tight = twistopt_solver::solve::NewtonOptions { rtol: 1e-13, atol: 1e-14, ..Default::default() };
    let solve_at = |m: &Model, l: &Loads| {
        let mut qq = q.clone();
        twistopt_solver::solve::newton(m, &mut qq, l, &tight).unwrap();
        let st = twistopt_solver::adjoint::State::from_assembly(m, &m.assemble(&qq, l, false).unwrap());
        fun[0].eval(m, &st).unwrap()
    };
    let h = 1e-5;
    for (k, g) in [(0usize, &width as &dyn Fn([f64; 3]) -> [f64; 3]), (1, &tilt)] {
        let (mp, lp) = capped_block(g, h);
        let (mm, lm) = capped_block(g, -h);
        let fd = (solve_at(&mp, &lp) - solve_at(&mm, &lm)) / (2.0 * h);
        let ad = sens.gradients[0][k];
        assert!((fd - ad).abs() <= 1e-5 * fd.abs().max(1e-3 * reaction.abs()), "{}: adjoint {ad} vs central differences {fd}", dirs[k].name);
    }
    let (mut lp, mut lm) = (loads.clone(), loads.clone());
    lp.presc[slot] -= h;
    lm.presc[slot] += h;
    let fd = (solve_at(&m, &lp) - solve_at(&m, &lm)) / (2.0 * h);
    let ad = sens.gradients[0][2];
    assert!((fd - ad).abs() <= 1e-5 * fd.abs(), "push: adjoint {ad} vs central differences {fd}");
}
