//! The cavity's self-contact in the actuator scenes (issue 19): the contact set across the
//! cyclic cut, a vacuum path whose walls stay apart is unchanged by it, adjoint gradients at a
//! contact state (past the wall's snap) equal central differences; the pure-twist axle and the
//! end plates.
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::contact::Vertex;
use twistopt_solver::material::NeoHookean;

fn opts(contact: bool) -> SceneOptions {
    let mut o = SceneOptions::new(MeshSpec::preset("coarse").unwrap(), NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    if contact {
        o.contact = Some(ContactOptions::default());
    }
    o
}

fn example() -> ActuatorGeometry {
    ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0), RangePolicy::TableI).unwrap()
}

#[test]
fn self_contact_set_spans_the_neighbouring_sectors() {
    let sm = SceneModel::build(&example(), &opts(true), SceneKind::Free).unwrap();
    let c = sm.model.contact().expect("contact modelled");
    assert!(!c.slaves.is_empty());
    // every slave is a cavity node; candidates include the neighbouring sectors' copies
    let rotated = c.slaves.iter().flat_map(|s| s.targets.iter()).filter(|&&t| c.triangles[t].iter().any(|v| matches!(v, Vertex::Rotated { .. }))).count();
    assert!(rotated > 0, "no candidate across the cyclic cut");
    for s in &c.slaves {
        assert!(sm.cavity_nodes.contains(&s.node));
        assert!(s.weight > 0.0);
    }
    // the unloaded state is admissible and out of the barrier's reach
    let x0 = &sm.model.mesh.nodes;
    let gap = c.min_gap(&|n| x0[n]);
    assert!(gap > ContactOptions::default().dhat_mm, "reference gap {gap}");
    // pushing one wall node of the sector onto its facing wall is refused as a penetration:
    // the slave with the smallest reference gap, moved along the way to its closest point
    let pos = |v: &Vertex| match *v {
        Vertex::Node(n) => x0[n],
        Vertex::Fixed(p) => p,
        Vertex::Rotated { node, angle } => {
            let (sn, cs) = angle.sin_cos();
            let p = x0[node];
            [cs * p[0] - sn * p[1], sn * p[0] + cs * p[1], p[2]]
        }
    };
    let txy = |t: usize| [pos(&c.triangles[t][0]), pos(&c.triangles[t][1]), pos(&c.triangles[t][2])];
    // the facing wall: the nearest candidate triangle the slave projects into, from its front
    let (s, t, d) = c
        .slaves
        .iter()
        .flat_map(|s| s.targets.iter().map(move |&t| (s, t)))
        .filter_map(|(s, t)| {
            let (d, sd, kind) = twistopt_solver::contact::point_triangle(x0[s.node], txy(t));
            (kind == twistopt_solver::contact::Closest::Face && sd > 0.0).then_some((s, t, d))
        })
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .expect("a slave facing a candidate triangle");
    let tri = c.triangles[t];
    let centre: Vec<f64> = (0..3).map(|k| (pos(&tri[0])[k] + pos(&tri[1])[k] + pos(&tri[2])[k]) / 3.0).collect();
    let p = x0[s.node];
    let mut moved = x0.clone();
    // 0.01 mm beyond the triangle's centre: refused
    let len = (0..3).map(|k| (centre[k] - p[k]).powi(2)).sum::<f64>().sqrt();
    moved[s.node] = [0, 1, 2].map(|k| centre[k] + 0.01 * (centre[k] - p[k]) / len);
    assert!(d > 0.0);
    assert!(c.terms(&|n| moved[n], false).is_err(), "a node driven through the facing wall is not refused");
    // a step carrying it 5 mm beyond (far behind the barrier's reach) is cut before the wall
    let far = [0, 1, 2].map(|k| centre[k] + 5.0 * (centre[k] - p[k]) / len - p[k]);
    let node = s.node;
    let tau = c.max_step(&|n| x0[n], &|n| if n == node { far } else { [0.0; 3] }, 0.8);
    assert!(tau < 1.0 && tau * (len + 5.0) < 0.8 * len + 1e-9, "step fraction {tau} (the wall at {len} mm of {} mm)", len + 5.0);
}

/// Past the wall's snap the lobes fold; the coarse mesh's elements first fold between their
/// quadrature points at about −35.3 kPa (the least relative det ∂x/∂ξ on a 9³ grid reaches 0;
/// measured, studies/vacuum). The ramp ends there, located on the path, with status `inversion`;
/// every recorded state has no folded element.
#[test]
fn a_vacuum_ramp_ends_where_an_element_folds() {
    let r = run_pressure(&example(), &opts(true), SceneKind::Free, &[-40.0]).unwrap();
    assert_eq!(r.status, SceneStatus::Inversion, "{}", r.cause);
    assert!(r.cause.contains("folds between its quadrature points"), "{}", r.cause);
    let last = r.steps.iter().min_by(|a, b| a.p_kpa.total_cmp(&b.p_kpa)).unwrap();
    assert!(last.p_kpa > -40.0 && last.p_kpa < -30.0, "ended at {} kPa", last.p_kpa);
    // past the contact (the barrier active at the end)
    assert!(last.contact_distance_mm.unwrap() < 0.1, "{last:?}");
    for s in &r.steps {
        assert_eq!(s.folded_elements, Some(0), "{s:?}");
        let j = s.least_jacobian_ratio.unwrap();
        assert!(j >= -1e-3, "{s:?}");
        if s.p_kpa > -30.0 {
            assert!(j > 0.1, "{s:?}");
        }
    }
    // the end is located: the least ratio is near 0 there
    assert!(last.least_jacobian_ratio.unwrap() < 0.02, "{last:?}");
}

#[test]
fn vacuum_path_with_contact_is_unchanged_while_the_walls_stay_apart() {
    // coarse: the path loses stability near −33 kPa with the walls ≥ 0.5 mm apart, beyond the
    // barrier's reach (0.1 mm), so the contact terms are zero all along
    let geom = example();
    let a = run_pressure(&geom, &opts(false), SceneKind::Free, &[-20.0]).unwrap();
    let b = run_pressure(&geom, &opts(true), SceneKind::Free, &[-20.0]).unwrap();
    assert_eq!(a.status, b.status, "{} / {}", a.cause, b.cause);
    assert_eq!(a.steps.len(), b.steps.len());
    for (x, y) in a.steps.iter().zip(&b.steps) {
        assert!((x.p_kpa - y.p_kpa).abs() < 1e-9 && (x.theta_deg - y.theta_deg).abs() < 1e-7, "{x:?} vs {y:?}");
    }
    let pmin = b.steps.iter().map(|s| s.p_kpa).fold(f64::INFINITY, f64::min);
    assert!((pmin + 20.0).abs() < 1e-6, "reached {pmin}");
    // with contact every step reports the mesh's integrity on its own faces: apart, the wall
    // passes into no element and no element folds; without contact it is not measured
    for s in &b.steps {
        assert_eq!((s.penetration_mm, s.folded_elements), (Some(0.0), Some(0)), "{s:?}");
    }
    assert!(a.steps.iter().all(|s| s.penetration_mm.is_none() && s.folded_elements.is_none()));
}

#[test]
fn adjoint_at_a_contact_state_matches_central_differences() {
    // coarse, free and blocked: past the wall's first snap (−32.9 kPa free) the cavity walls are
    // in contact at −34 kPa, before any element folds (−35.3 / −36.0 kPa: the state is one the
    // mesh represents); θ, τ, V and the KS radius w.r.t. r, l, α, p and μ against central
    // differences (warm re-solves of the perturbed designs at the same state), within 1e-5
    use twistopt::gradient::{fd_check, max_rel_error, scene_gradient, DEFAULT_KS_RHO_PER_MM};
    let g = example();
    let o = opts(true);
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        let sg = scene_gradient(&g, &o, kind, -34.0, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
        assert_eq!(sg.status, SceneStatus::Converged, "{kind:?}: {}", sg.cause);
        assert_eq!(sg.folded_elements, Some(0), "{kind:?}");
        // a contact state: some wall node within the barrier's reach of the facing wall
        let sm = SceneModel::build(&g, &o, kind).unwrap();
        let a = sm.model.assemble(&sg.q, &sm.loads(-34.0, 0.0), false).unwrap();
        assert!(a.contact_gap < ContactOptions::default().dhat_mm, "{kind:?}: not in contact (gap {})", a.contact_gap);
        let rep = fd_check(&g, &o, kind, &sg, &[1e-4, 1e-5]);
        // (under vacuum the KS radius hardly moves: its gradients are ~1e-9 per unit, at the
        // differences' round-off; such a component passes when adjoint and differences agree
        // to 1e-9 of the value over the parameter's whole range)
        let ok = |f: &str, c: &twistopt::gradient::FdComponent| {
            let range = c.steps[0] / 1e-4;
            let fd = c.fd_richardson.or(*c.fd.last().unwrap()).unwrap_or(f64::NAN);
            c.rel_error <= 1e-5 || (c.adjoint - fd).abs() * range <= 1e-9 * sg.values[f].abs()
        };
        let detail: Vec<String> =
            rep.iter().flat_map(|(f, m)| m.iter().filter(|(_, c)| !ok(f, c)).map(move |(p, c)| format!("{f}/{p}: adjoint {} fd {:?} rel {}", c.adjoint, c.fd, c.rel_error))).collect();
        assert!(detail.is_empty(), "{kind:?}: max rel error {:e}: {detail:?}", max_rel_error(&rep));
        // and the contact-dominated outputs themselves pass the relative test
        for f in ["theta_deg", "tau_Nm", "cavity_volume_mm3"] {
            for (p, c) in rep.get(f).into_iter().flatten() {
                assert!(c.rel_error <= 1e-5, "{kind:?} {f}/{p}: adjoint {} fd {:?}", c.adjoint, c.fd);
            }
        }
    }
}

/// The pure-twist scenes' rigid axle (`axle_radius_mm`): with its surface 0.13 mm inside the
/// cavity wall's innermost point at rest, a vacuum ramp pushes the wall onto it. Without the axle
/// the wall passes its radius; with it the wall stays outside at every recorded state, and the
/// adjoint gradients at the contact state equal central differences.
#[test]
fn the_pure_twist_axle_holds_the_wall_off_the_axis() {
    use twistopt::gradient::{fd_check, max_rel_error, scene_gradient, DEFAULT_KS_RHO_PER_MM};
    let g = example();
    let sm = SceneModel::build(&g, &opts(true), SceneKind::PureTwist).unwrap();
    let rho = |x: [f64; 3]| x[0].hypot(x[1]);
    let inner = sm.cavity_nodes.iter().map(|&n| rho(sm.model.mesh.nodes[n])).fold(f64::INFINITY, f64::min);
    assert!(sm.model.contact().unwrap().axle.is_none(), "no axle unless asked");
    let radius = inner - 0.13;
    let mut o = opts(true);
    o.contact.as_mut().unwrap().axle_radius_mm = Some(radius);
    // the free and blocked scenes have no axle; an axle wider than the cavity is refused
    assert!(SceneModel::build(&g, &o, SceneKind::Free).unwrap().model.contact().unwrap().axle.is_none());
    let mut wide = o.clone();
    wide.contact.as_mut().unwrap().axle_radius_mm = Some(inner + 0.01);
    assert!(SceneModel::build(&g, &wide, SceneKind::PureTwist).is_err());
    let p = -10.0;
    // the innermost deformed wall radius of a state
    let closest = |o: &SceneOptions, q: &[f64]| {
        let sm = SceneModel::build(&g, o, SceneKind::PureTwist).unwrap();
        let u = sm.model.assemble(q, &sm.loads(p, 0.0), false).unwrap().u;
        sm.cavity_nodes.iter().map(|&n| rho([sm.model.mesh.nodes[n][0] + u[n][0], sm.model.mesh.nodes[n][1] + u[n][1], 0.0])).fold(f64::INFINITY, f64::min)
    };
    let free = scene_gradient(&g, &opts(true), SceneKind::PureTwist, p, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
    assert_eq!(free.status, SceneStatus::Converged, "{}", free.cause);
    let without = closest(&opts(true), &free.q);
    assert!(without < radius, "without the axle the wall stays at {without} mm (axle {radius})");
    let sg = scene_gradient(&g, &o, SceneKind::PureTwist, p, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
    assert_eq!(sg.status, SceneStatus::Converged, "{}", sg.cause);
    let with = closest(&o, &sg.q);
    assert!(with > radius && with < radius + ContactOptions::default().dhat_mm, "with the axle the wall is at {with} mm (axle {radius})");
    eprintln!("axle {radius:.4} mm: innermost wall at {p} kPa {without:.4} mm without, {with:.4} mm with; θ {:.4}° without, {:.4}° with", free.values["theta_deg"], sg.values["theta_deg"]);
    let run = run_pressure(&g, &o, SceneKind::PureTwist, &[p]).unwrap();
    assert!(run.min_contact_distance_mm.unwrap() > 0.0, "{:?}", run.min_contact_distance_mm);
    let rep = fd_check(&g, &o, SceneKind::PureTwist, &sg, &[1e-4, 1e-5]);
    for f in ["theta_deg", "cavity_volume_mm3"] {
        for (prm, c) in rep.get(f).into_iter().flatten() {
            assert!(c.rel_error <= 1e-5, "{f}/{prm}: adjoint {} fd {:?} (max {:e})", c.adjoint, c.fd, max_rel_error(&rep));
        }
    }
}

/// The end plates: with contact, every scene keeps the cavity wall above the bottom plate
/// (z = 0) and below the top cap (a plane through one of its nodes); the rings held by the
/// plates are not their slaves, and at rest every slave is beyond the barrier's reach.
#[test]
fn end_plates_bound_the_cavity_wall() {
    let g = example();
    let sm = SceneModel::build(&g, &opts(true), SceneKind::Free).unwrap();
    let c = sm.model.contact().unwrap();
    assert_eq!(c.planes.len(), 2);
    let x = |n: usize| sm.model.mesh.nodes[n];
    for (pl, ring) in c.planes.iter().zip(["bottom", "top"]) {
        let ring = &sm.model.mesh.node_sets[ring];
        assert!(!pl.slaves.is_empty());
        assert!(pl.slaves.iter().all(|(n, w)| !ring.contains(n) && *w > 0.0 && sm.cavity_nodes.contains(n)));
        let gaps: Vec<f64> = pl
            .slaves
            .iter()
            .map(|&(n, _)| {
                (0..3)
                    .map(|k| {
                        pl.normal[k]
                            * (x(n)[k]
                                - match pl.point {
                                    Vertex::Fixed(p) => p[k],
                                    Vertex::Node(r) => x(r)[k],
                                    _ => unreachable!(),
                                })
                    })
                    .sum()
            })
            .collect();
        assert!(gaps.iter().all(|&d| d > ContactOptions::default().dhat_mm), "{:?}", gaps.iter().cloned().fold(f64::INFINITY, f64::min));
    }
    assert!(matches!(c.planes[1].point, Vertex::Node(n) if sm.top_nodes.contains(&n)));
    // at rest the wall is nowhere near a plate: no contact force
    let a = sm.model.assemble(&vec![0.0; sm.model.n_reduced()], &sm.loads(0.0, 0.0), false).unwrap();
    assert!(a.contact_gap > ContactOptions::default().dhat_mm);
}

/// The optimiser's vacuum side (a two-sided objective at −p⁻) refuses a state with folded
/// elements as a failed evaluation, as a scene's ramp would end before it; with
/// `scenes.contact.stop_at_fold = false` it takes it. Coarse example, stroke objective (the free
/// scene's vacuum side only), p⁻ = 40 kPa: past the free scene's first fold at −35.3 kPa.
#[test]
fn the_optimisers_vacuum_side_refuses_a_folded_state() {
    use twistopt::optimise::build_problem;
    use twistopt::problem::Problem;
    for stop in [true, false] {
        let sets: Vec<String> = vec![
            "fidelity.preset=\"coarse\"".into(),
            "design.l_mm=10.0".into(),
            "design.alpha_deg=60.0".into(),
            format!("scenes.contact={{stop_at_fold = {stop}}}"),
            "optimise.objective=\"stroke\"".into(),
            "optimise.vacuum_kPa=40".into(),
            "optimise.variables=[\"p_kPa\"]".into(),
        ];
        let problem = Problem::load(std::path::Path::new("problems/energy-density.toml"), &sets).unwrap();
        let v = problem.validate().unwrap();
        let (op, _) = build_problem(&problem, &v).unwrap();
        let e = op.evaluate(&[0.3], &mut None, None);
        if stop {
            assert!(e.status.starts_with("failed-vacuum") && e.status.contains("fold"), "{}", e.status);
        } else {
            assert_eq!(e.status, "ok", "{}", e.status);
            assert!(e.vacuum.as_ref().unwrap().folded_elements.unwrap() > 0, "{:?}", e.vacuum);
        }
    }
}
