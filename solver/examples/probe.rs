use std::time::Instant;
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::verify::*;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let what = args.get(1).map(|s| s.as_str()).unwrap_or("cook");
    if what == "cook" {
        for (form, n) in [
            (Formulation::standard(ElementKind::Hex27), 16usize),
            (Formulation::standard(ElementKind::Hex8), 32),
            (Formulation { kind: ElementKind::Hex8, pressure: PressureSpace::None, ngauss: 2 }, 32),
        ] {
            let t = Instant::now();
            let r = cook_membrane(form, n, 5000.0, 0.02649830784923523).unwrap();
            println!("{:?} n={n}: uy={:.5} ux={:.5} dofs={} {:?} steps={} it={} {:.2}s", form.pressure, r.uy, r.ux, r.dofs, r.status, r.steps, r.newton_iterations, t.elapsed().as_secs_f64());
        }
    }
}
