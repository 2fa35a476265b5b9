//! Diagnostic: run one scene through the path follower and print every point (with
//! `TWISTOPT_TRACE=1`, every Newton iterate and step decision too). The tuning of issue 16 was
//! measured with it. Arguments: MESH SCENE P_MAX R L ALPHA [INITIAL TARGET_ERROR RTOL SWITCH];
//! experiment switches by environment: MIXED (mixed tangent), QUAD (quadratic predictor), CART
//! (Cartesian predictor), GROWTH, ETOL, FLOOR, STATIONS=p1,p2,… (kPa).
//!   cargo run --release --example path_probe -- sweep free 150 8.660254 16 200
use std::time::Instant;
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::adjoint::Functional;
use twistopt_solver::continuation::{follow, ContinuationOptions, LoadPath, Stop};
use twistopt_solver::material::NeoHookean;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: f64| a.get(i).map(|s| s.parse().unwrap()).unwrap_or(d);
    let mesh = a.get(1).cloned().unwrap_or("coarse".into());
    let kind = SceneKind::parse(a.get(2).map(|s| s.as_str()).unwrap_or("free")).unwrap();
    let p_max = arg(3, 150.0);
    let geom = ActuatorGeometry::new(&Design::new(arg(4, 5.0 * 3f64.sqrt()), arg(5, 16.0), arg(6, 200.0)), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    let sm = SceneModel::build(&geom, &opts, kind).unwrap();
    let m = &sm.model;
    let nodes: Vec<usize> = (0..m.mesh.nodes.len()).collect();
    let f = vec![Functional::BodyDof { body: 0, dof: 5 }, Functional::BodyReaction { body: 0, dof: 5 }, Functional::MaxRadius { nodes }, Functional::CavityVolume];
    let mut lp = LoadPath::new(m, sm.loads(0.0, 0.0), sm.loads(p_max, 0.0), f);
    if std::env::var_os("CART").is_some() {
        lp.predictor = None;
    }
    let mut o = ContinuationOptions::default();
    o.initial = arg(7, 0.02);
    o.target_error = arg(8, 0.05);
    o.newton.rtol = arg(9, 1e-10);
    if let Some(s) = a.get(10) {
        o.switch_stiffness = Some(s.parse().unwrap());
    }
    if std::env::var_os("MIXED").is_some() {
        o.mixed_tangent = true;
    }
    if std::env::var_os("QUAD").is_some() {
        o.cubic = false;
    }
    if let Some(c) = std::env::var_os("GROWTH") {
        o.max_growth = c.to_str().unwrap().parse().unwrap();
    }
    if let Some(c) = std::env::var_os("ETOL") {
        o.newton.etol = c.to_str().unwrap().parse().unwrap();
    }
    if let Some(c) = std::env::var_os("FLOOR") {
        o.newton.stagnation_rtol = c.to_str().unwrap().parse().unwrap();
    }
    let stops = vec![Stop { name: "ballooning".into(), output: 2, threshold: 28.75, rising: true }];
    let t0 = Instant::now();
    let stations: Vec<f64> = std::env::var("STATIONS").ok().map(|v| v.split(',').map(|x| x.parse::<f64>().unwrap() / p_max).collect()).unwrap_or_default();
    let r = follow(&lp, &vec![0.0; m.n_reduced()], 0.0, 1.0, &stations, &stops, &o);
    let dt = t0.elapsed().as_secs_f64();
    for p in &r.points {
        println!(
            "  p {:12.8} θ {:14.10}° τ {:14.10} R {:14.10} V {:14.6} stable {} its {} {:?}",
            p.lam * p_max,
            p.outputs[0].to_degrees(),
            -p.outputs[1] * sm.multiplicity * 1e-3,
            p.outputs[2],
            p.outputs[3] * 3.0,
            p.stable,
            p.newton_iterations,
            p.kind
        );
    }
    if r.points.is_empty() {
        println!("no points: {:?}", r.end);
        return;
    }
    let s = &r.stats;
    println!(
        "{} end {:?} at p {:.6}: steps {} newton {} (failed {} in {} attempts, locate {}), factorizations {}, {:.2}/step, {:.2}s",
        kind.name(),
        r.end,
        r.points.last().unwrap().lam * p_max,
        s.steps,
        s.newton_iterations,
        s.failed_iterations,
        s.failed_attempts,
        s.locate_iterations,
        s.factorizations,
        (s.newton_iterations - s.locate_iterations) as f64 / s.steps.max(1) as f64,
        dt
    );
}
