//! Probe: train a ROM on coarse designs and compare it with the full model on random designs.
//! cargo run --release --example rom_probe -- PRESET N_TRAIN N_TEST TAU MAXMODES
use std::sync::Arc;
use std::time::Instant;
use twistopt::geometry::{ActuatorGeometry, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::rom::{random_designs, train, TrainOptions};
use twistopt::scene::{run_pressure, SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
use twistopt_solver::material::NeoHookean;
use twistopt_solver::rom::{EcswOptions, Truncation};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = a.get(1).map(|s| s.as_str()).unwrap_or("coarse");
    let ntrain: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let ntest: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(4);
    let tau: f64 = a.get(4).and_then(|s| s.parse().ok()).unwrap_or(0.01);
    let maxk: usize = a.get(5).and_then(|s| s.parse().ok()).unwrap_or(60);
    let opts = SceneOptions::new(MeshSpec::preset(preset).unwrap(), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).unwrap().into());
    let t = TrainOptions { designs: ntrain, truncation: Truncation::Tail { tol: 1e-8, max: maxk }, ecsw: EcswOptions { tau, max_elements: 1000, tangent_directions: std::env::var("TDIRS").ok().and_then(|s| s.parse().ok()).unwrap_or(0) }, ..TrainOptions::default() };
    let t0 = Instant::now();
    let (rom, rep) = train(&opts, &t, |s| eprintln!("{s}")).unwrap();
    eprintln!("trained in {:.1} s: {} modes, {} / {} elements, ecsw residual {:.2e}", t0.elapsed().as_secs_f64(), rep.modes, rep.sample_elements, rep.elements, rep.ecsw_residual);
    let sv: Vec<String> = rep.singular_values.iter().take(60).map(|s| format!("{:.1e}", s / rep.singular_values[0])).collect();
    eprintln!("singular values / first: {}", sv.join(" "));
    let mut rom = rom;
    if std::env::var_os("ALL_ELEMENTS").is_some() {
        rom.sample = twistopt_solver::rom::Sample::all(rep.elements);
    }
    let rom = Arc::new(rom);
    let mut ro = opts.clone();
    ro.rom = Some(rom.clone());
    let tests = if std::env::var_os("ON_TRAINING").is_some() { twistopt::rom::halton_designs(ntest, 0) } else { random_designs(ntest, 42) };
    for d in tests {
        let g = ActuatorGeometry::new(&d, RangePolicy::TableI).unwrap();
        for kind in [SceneKind::Free, SceneKind::Blocked] {
            let t1 = Instant::now();
            let f = run_pressure(&g, &opts, kind, &[100.0]).unwrap();
            let tf = t1.elapsed().as_secs_f64();
            let t2 = Instant::now();
            let r = run_pressure(&g, &ro, kind, &[100.0]).unwrap();
            let tr = t2.elapsed().as_secs_f64();
            let pf = f.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
            let pr = r.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
            let pc = 0.9 * pf.min(pr);
            let val = |res: &twistopt::scene::SceneResult| twistopt::evaluate::interpolate(&res.steps, pc, |s| if kind == SceneKind::Free { s.theta_deg } else { s.tau_nm }).unwrap_or(f64::NAN);
            let (vf, vr) = (val(&f), val(&r));
            let rad = |res: &twistopt::scene::SceneResult| twistopt::evaluate::interpolate(&res.steps, pc, |s| s.max_radius_mm).unwrap_or(f64::NAN);
            println!(
                "{} {:>8}: full {} p_end {:.3} ({} its, {:.2} s) | rom {} p_end {:.3} ({} its, {:.3} s) | p_end err {:+.2}% | value@{:.1} full {:.5} rom {:.5} err {:+.2}% | radius err {:+.3}%",
                twistopt::rom::label(&d),
                kind.name(),
                f.status,
                pf,
                f.newton_iterations,
                tf,
                r.status,
                pr,
                r.newton_iterations,
                tr,
                100.0 * (pr - pf) / pf,
                pc,
                vf,
                vr,
                100.0 * (vr - vf) / vf,
                100.0 * (rad(&r) - rad(&f)) / rad(&f)
            );
        }
    }
}
