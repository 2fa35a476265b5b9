use twistopt_solver::element::Formulation;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::model::Loads;
use twistopt_solver::solve::{follow_path, newton, NewtonOptions, StepOptions};
use twistopt_solver::verify::*;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let kind = if a[1] == "8" { ElementKind::Hex8 } else { ElementKind::Hex27 };
    let ratio: f64 = a[2].parse().unwrap();
    let s = torsion_slice(kind, Formulation::standard(kind), 24, 2, 2.0, ratio, false).unwrap();
    let m = &s.model;
    let from = Loads::zero(m);
    let mut to = from.clone();
    to.presc[s.twist_slot] = 10f64.to_radians() / 40.0 * s.h;
    let res = follow_path(m, &vec![0.0; m.n_reduced()], &from, &to, &StepOptions { initial: 1.0, ..Default::default() }, |_| None);
    for (deg, pred) in [(12.0, false)] {
        let mut loads = to.clone();
        loads.presc[s.twist_slot] = f64::to_radians(deg) / 40.0 * s.h;
        let mut q = res.q.clone();
        if pred {
            let a = m.assemble(&q, &loads, true).unwrap();
            let dq = m.factor(a.k.as_ref().unwrap()).unwrap().solve(&a.r).unwrap();
            q.iter_mut().zip(&dq).for_each(|(x, d)| *x -= d);
        }
        for ind in [false] {
            let mut qq = q.clone();
            let r = newton(m, &mut qq, &loads, &NewtonOptions { log: true, line_search: false, indefinite: ind, rtol: 1e-16, max_iter: 12, ..Default::default() });
            match r { Ok((st, a)) => println!("{deg} pred={pred} lu={ind}: {:?} fscale {:e}", st.residual_norms, a.f_scale), Err(e) => println!("{deg} {pred} {ind}: {e:?}") }
        }
    }
}
