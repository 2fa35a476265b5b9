use std::time::Instant;
use twistopt_solver::element::Formulation;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::solve::{StepOptions, NewtonOptions};
use twistopt_solver::verify::*;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let nt: usize = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(48);
    let nr: usize = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(4);
    let kind = if args.get(3).map(|s| s.as_str()) == Some("8") { ElementKind::Hex8 } else { ElementKind::Hex27 };
    let indef = args.get(4).map(|s| s.as_str()) == Some("lu");
    let h: f64 = args.get(5).map(|s| s.parse().unwrap()).unwrap_or(2.0);
    let t = Instant::now();
    let s = torsion_slice(kind, Formulation::standard(kind), nt, nr, h, 1000.0, false).unwrap();
    println!("dofs {}", s.model.n_reduced());
    let opts = StepOptions { initial: 1.0, max: 1.0, newton: NewtonOptions { indefinite: indef, ..Default::default() }, ..Default::default() };
    let (pts, st, cost) = s.twist(40.0, &[1.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0], &opts);
    for p in &pts { println!("{:?}", p); }
    println!("{st:?} {cost:?} {:.2}s", t.elapsed().as_secs_f64());
}
