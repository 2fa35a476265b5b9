use twistopt_solver::dofmap::Constraints;
use twistopt_solver::element::Formulation;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::meshgen;
use twistopt_solver::model::{Loads, Model};
use twistopt_solver::solve::{newton, NewtonOptions};
fn main() {
    let kind = ElementKind::Hex8;
    let mesh = meshgen::boxed(kind, [2, 2, 2], [1.0, 1.0, 1.0]);
    let mut cons = Constraints::default();
    for &n in &mesh.node_sets["xmin"] { cons.prescribed.push((n, 0, 0.0)); }
    for &n in &mesh.node_sets["ymin"] { cons.prescribed.push((n, 1, 0.0)); }
    for &n in &mesh.node_sets["zmin"] { cons.prescribed.push((n, 2, 0.0)); }
    let xmax = mesh.node_sets["xmax"].clone();
    for &n in &xmax { cons.prescribed.push((n, 0, 1.0)); }
    let mat = NeoHookean::with_ratio(0.34, 1000.0).unwrap();
    let model = Model::new(mesh, Formulation::standard(kind), mat.into(), &cons, None).unwrap();
    let mut to = Loads::zero(&model);
    for (s, (n, c)) in model.dofs.presc_nodes.iter().enumerate() { if *c == 0 && xmax.contains(n) { to.presc[s] = -0.5; } }
    let mut q = vec![0.0; model.n_reduced()];
    let mut o = NewtonOptions::default(); o.log = true;

    let from = Loads::zero(&model);
    let mut so = twistopt_solver::solve::StepOptions::default(); so.newton.log = true; so.newton.max_iter = 12; so.max_steps = 1000;
    let res = twistopt_solver::solve::follow_path(&model, &q, &from, &to, &so, |i| { println!("t {} it {}", i.t, i.newton_iterations); None });
    println!("{:?}", res.status);
    let mut q = res.q.clone();
    let r = newton(&model, &mut q, &to, &o);
    match r { Ok((s, a)) => println!("ok {:?} fscale {}", s.residual_norms, a.f_scale), Err(e) => println!("err {e:?}") }
}
#[allow(dead_code)]
fn dense_check(model: &Model, q: &[f64], loads: &Loads) {
    let a = model.assemble(q, loads, true).unwrap();
    let m = model.matrix(a.k.unwrap());
    let n = model.n_reduced();
    let d = m.to_dense();
    let mut mind: f64 = 1e300;
    for i in 0..n { mind = mind.min(d[(i,i)]); }
    println!("n {n} min diag {mind}");
    let full = faer::Mat::<f64>::from_fn(n, n, |i, j| if i <= j { d[(i,j)] } else { d[(j,i)] });
    let ev = full.self_adjoint_eigenvalues(faer::Side::Lower).unwrap();
    println!("min eig {:?} max {:?}", ev.first(), ev.last());
}
