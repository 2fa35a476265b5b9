//! The example design's free or blocked scene under vacuum with self-contact, through the
//! wall's snap (issue 19; studies/vacuum/README.md): every recorded state (p, θ, τ, cavity
//! volume, smallest contact distance, snapped) and the path's work.
//!
//!   cargo run --release --example vacuum_snap -- [MESH=coarse] [P_END_kPa=-68] [free|blocked]
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mesh = args.get(1).cloned().unwrap_or("coarse".into());
    let p_end: f64 = args.get(2).map(|s| s.parse().expect("P_END_kPa")).unwrap_or(-68.0);
    let kind = SceneKind::parse(args.get(3).map(|s| s.as_str()).unwrap_or("free")).expect("scene");
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let mut opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    // (REACH=mm overrides the candidates' reach)
    opts.contact = Some(ContactOptions { reach_mm: std::env::var("REACH").ok().and_then(|s| s.parse().ok()).unwrap_or(ContactOptions::default().reach_mm), ..ContactOptions::default() });
    let targets: Vec<f64> = (1..=((-p_end / 10.0).floor() as usize)).map(|i| -10.0 * i as f64).chain([p_end]).collect();
    let t0 = std::time::Instant::now();
    let r = run_pressure(&geom, &opts, kind, &targets).unwrap();
    println!("scene {} on {mesh}: {} ({}) in {:.1} s, {} Newton iterations ({} failed)", r.scene, r.status.name(), r.cause, t0.elapsed().as_secs_f64(), r.newton_iterations, r.path.failed_iterations);
    println!("{:>10} {:>9} {:>9} {:>10} {:>9} {:>8} snapped", "p kPa", "θ deg", "τ N·m", "V mm³", "d_min mm", "its");
    for s in &r.steps {
        println!(
            "{:>10.4} {:>9.4} {:>9.5} {:>10.1} {:>9.4} {:>8} {}",
            s.p_kpa,
            s.theta_deg,
            s.tau_nm,
            s.cavity_volume_mm3,
            s.contact_distance_mm.unwrap_or(f64::NAN),
            s.newton_iterations,
            if s.snapped { "snap" } else { "" }
        );
    }
}
