use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mesh = args.get(1).cloned().unwrap_or("coarse".into());
    let p: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(40.0);
    let sector = args.get(3).map(|s| s != "full").unwrap_or(true);
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let mut opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, args.get(4).map(|s| s.parse().unwrap()).unwrap_or(1000.0)).unwrap().into());
    opts.sector = sector;
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        let r = run_pressure(&geom, &opts, kind, &[p]).unwrap();
        println!("{} status {} ({}) dofs {} its {} time {:.2}s", r.scene, r.status, r.cause, r.dofs, r.newton_iterations, r.wall_time_s);
        for s in &r.steps {
            println!(
                "  p {:7.2} θ {:8.4}° w {:7.4} τ {:8.5} Nm rmax {:7.3} V {:9.1} detF {:.3} it {}",
                s.p_kpa, s.theta_deg, s.axial_mm, s.tau_nm, s.max_radius_mm, s.cavity_volume_mm3, s.min_det_f, s.newton_iterations
            );
        }
    }
}
