use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::gradient::*;
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::{Material, NeoHookean};
fn main() {
    let a: Vec<f64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let opts = SceneOptions::new(MeshSpec::preset("coarse").unwrap(), Material::NeoHookean(NeoHookean::with_ratio(0.34, 300.0).unwrap()));
    let run = |r: f64, l: f64, al: f64| {
        let g = ActuatorGeometry::new(&Design::new(r, l, al), RangePolicy::TableI).unwrap();
        let t = std::time::Instant::now();
        let sg = scene_gradient(&g, &opts, SceneKind::Blocked, a[3], 20.0, None, Some(a[4])).unwrap();
        println!("({r},{l},{al}) status {} plim {:?} {:?} grad {:?} t {:.1}", sg.status, sg.p_limit_kpa, sg.p_limit_cause, sg.p_limit_gradient, t.elapsed().as_secs_f64());
        sg.p_limit_kpa.unwrap_or(f64::NAN)
    };
    run(a[0], a[1], a[2]);
    let h = a[5];
    let (p, m) = (run(a[0], a[1], a[2] + h), run(a[0], a[1], a[2] - h));
    println!("fd alpha {}", (p - m) / (2.0 * h));
    let (p, m) = (run(a[0], a[1] + h / 10.0, a[2]), run(a[0], a[1] - h / 10.0, a[2]));
    println!("fd l {}", (p - m) / (2.0 * h / 10.0));
}
