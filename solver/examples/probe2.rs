use twistopt_solver::element::Formulation;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::model::Loads;
use twistopt_solver::solve::{follow_path, follow_volume, StepOptions};
use twistopt_solver::verify::*;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let kind = if a[1] == "8" { ElementKind::Hex8 } else { ElementKind::Hex27 };
    let (nt, nr): (usize, usize) = (a[2].parse().unwrap(), a[3].parse().unwrap());
    let s = inflation_slice(Formulation::standard(kind), nt, nr, 2.0, 1000.0).unwrap();
    let m = &s.model;
    let from = Loads::zero(m);
    let q0 = vec![0.0; m.n_reduced()];
    let a0 = m.assemble(&q0, &from, false).unwrap();
    println!("V0 {} vs {}", a0.volume, s.volume_of(1.0, 1.0));
    let mut to = from.clone();
    to.pressure = 0.05;
    let t = std::time::Instant::now();
    let res = follow_path(m, &q0, &from, &to, &StepOptions::default(), |st| {
        let (la, lz) = s.stretches(st.assembled);
        println!("p={:.6} lA={:.5} lz={:.5} it={}", st.loads.pressure, la, lz, st.newton_iterations);
        None
    });
    println!("{:?} last p {} steps {} {:.2}s", res.status, res.loads.pressure, res.steps, t.elapsed().as_secs_f64());
    let t = std::time::Instant::now();
    let vr = follow_volume(m, &q0, 0.0, &from, s.volume_of(2.5, 1.651), &StepOptions { initial: 0.02, max: 0.05, ..Default::default() }, |st| {
        let (la, lz) = s.stretches(st.assembled);
        println!("V p={:.6} lA={:.5} lz={:.5} it={}", st.pressure, la, lz, st.newton_iterations);
        None
    });
    println!("{:?} steps {} {:.2}s", vr.status, vr.steps, t.elapsed().as_secs_f64());
}
