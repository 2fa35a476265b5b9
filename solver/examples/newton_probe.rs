use twistopt_solver::dofmap::Constraints;
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};
use twistopt_solver::solve::{follow_path, StepOptions};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let ps = match args.get(1).map(|s| s.as_str()) { Some("none") => PressureSpace::None, Some("p0") => PressureSpace::P0, _ => PressureSpace::P1 };
    let lam: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(0.9);
    let kind = ElementKind::Hex27;
    let mesh = meshgen::boxed(kind, [1, 1, 1], [1.0, 1.0, 1.0]);
    let mut cons = Constraints::default();
    for &n in &mesh.node_sets["xmin"] { cons.prescribed.push((n, 0, 0.0)); }
    for &n in &mesh.node_sets["ymin"] { cons.prescribed.push((n, 1, 0.0)); }
    for &n in &mesh.node_sets["zmin"] { cons.prescribed.push((n, 2, 0.0)); }
    let xmax = mesh.node_sets["xmax"].clone();
    for &n in &xmax { cons.prescribed.push((n, 0, 1.0)); }
    let mat = NeoHookean::with_ratio(0.34, 1000.0).unwrap();
    let model = Model::new(mesh, Formulation { kind, pressure: ps, ngauss: 3 }, mat.into(), &cons, None).unwrap();
    let mut to = Loads::zero(&model);
    for (s, (n, c)) in model.dofs.presc_nodes.iter().enumerate() { if *c == 0 && xmax.contains(n) { to.presc[s] = lam - 1.0; } }
    let so = StepOptions { initial: 0.01, max: 0.01, ..Default::default() };
    let res = follow_path(&model, &vec![0.0; model.n_reduced()], &Loads::zero(&model), &to, &so, |_| None);
    println!("{:?} steps {} its {}", res.status, res.steps, res.newton_iterations);
    // pure Newton from a tiny perturbation of the converged state
    let mut q: Vec<f64> = res.q.iter().enumerate().map(|(i, v)| v + 1e-4 * (((i * 37) % 11) as f64 / 11.0 - 0.5)).collect();
    for it in 0..8 {
        let a = model.assemble(&q, &res.loads, true).unwrap();
        let rn: f64 = a.r.iter().map(|v| v * v).sum::<f64>().sqrt();
        println!("it {it} |r| {rn:.3e}");
        if rn < 1e-14 { break; }
        let f = model.factor(a.k.as_ref().unwrap()).unwrap();
        let dq = f.solve(&a.r).unwrap();
        for (x, d) in q.iter_mut().zip(&dq) { *x -= d; }
    }
    // print the state: u at nodes
    let a = model.assemble(&res.q, &res.loads, false).unwrap();
    let mut maxdev: f64 = 0.0;
    let l = lam; let t = 1.0 + a.u[model.mesh.nodes.iter().position(|p| *p == [1.0,1.0,1.0]).unwrap()][1];
    for (x, u) in model.mesh.nodes.iter().zip(&a.u) { let ex = [(l-1.0)*x[0], (t-1.0)*x[1], (t-1.0)*x[2]]; for i in 0..3 { maxdev = maxdev.max((u[i]-ex[i]).abs()); } }
    println!("max deviation from homogeneous {maxdev:e}");
}
