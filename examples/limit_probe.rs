//! Compare the pressure maximum found by the pressure ramp (step halving) with the
//! volume-controlled locator. Usage: limit_probe [mesh] [r] [l] [alpha] [p_start]
use std::time::Instant;
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: f64| a.get(i).map(|s| s.parse().unwrap()).unwrap_or(d);
    let mesh = a.get(1).cloned().unwrap_or("coarse".into());
    let geom = ActuatorGeometry::new(&Design::new(arg(2, 5.0 * 3f64.sqrt()), arg(3, 12.15), arg(4, 152.3)), RangePolicy::TableI).unwrap();
    let p0 = arg(5, 20.0);
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    for kind in [SceneKind::Free, SceneKind::Blocked, SceneKind::PureTwist, SceneKind::PureTwistBlocked] {
        let sm = SceneModel::build(&geom, &opts, kind).unwrap();
        let eq = equilibrium(&sm, &opts, p0, None);
        let t = Instant::now();
        let ramp = continue_to_failure(&sm, &opts, &eq, 120.0);
        let t_ramp = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let vol = pressure_maximum(&sm, &eq, 120.0, &opts.steps.newton);
        let t_vol = t.elapsed().as_secs_f64();
        let show = |e: &LimitOutcome| e.found().map(|e| format!("p {:.4} θ {:.3} τ {:.5} its {} ({:?})", e.record.p_kpa, e.record.theta_deg, e.record.tau_nm, e.newton_iterations, e.end.as_ref().map(|x| x.0.clone()))).unwrap_or("none below cap".into());
        println!("{:>18}: ramp {} in {t_ramp:.2}s", kind.name(), show(&ramp));
        match &vol {
            Ok(v) => println!("{:>18}  volume {} in {t_vol:.2}s", "", show(v)),
            Err(_) => println!("{:>18}  volume: undecided (fallback) in {t_vol:.2}s", ""),
        }
    }
}
