//! Probe of the reduced model's accuracy: train on PRESET with N_TRAIN designs (the box corners,
//! then Halton points), then compare with the full model on N_TEST seeded random designs of the
//! Table-I box, for each number of modes in K_LIST (the first k modes of one POD basis), without
//! hyper-reduction (every element at weight 1) unless TAU > 0 (ECSW refitted for each k).
//!
//!   cargo run --release --example rom_probe -- PRESET N_TRAIN N_TEST K_LIST TAU
//!   e.g. cargo run --release --example rom_probe -- coarse 32 20 20,40,60,80,120 0
//!
//! TANGENTS = tangent directions in the ECSW fit (default 0).
//! KP = pressure modes trained (none: element-local pressures), KP_LIST = the pressure mode
//! counts to test (default: all trained).
//! Env: FRAME = cartesian | cylindrical | piola (default), KAPPA_OVER_MU (bulk/shear ratio, default 300).
//!
//! Output: one line per design and k, then a summary per k (median / 95th percentile / max of
//! the relative errors of Ω by the letter's rule, of both scenes' end pressures, CPU s per design).
use std::sync::Arc;
use std::time::Instant;
use twistopt::geometry::{ActuatorGeometry, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::rom::{random_designs, TrainOptions};
use twistopt::scene::{energy_density, run_pressure, SceneKind, SceneOptions, SceneResult, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
use twistopt_solver::material::NeoHookean;
use twistopt_solver::rom::{EcswOptions, Rom, Sample, Truncation};

fn omega(f: &SceneResult, b: &SceneResult) -> (f64, f64) {
    let pf = f.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
    let pb = b.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
    let pc = pf.min(pb);
    let th = twistopt::evaluate::interpolate(&f.steps, pc, |s| s.theta_deg).unwrap_or(f64::NAN);
    let tau = twistopt::evaluate::interpolate(&b.steps, pc, |s| s.tau_nm).unwrap_or(f64::NAN);
    (energy_density(th.abs(), tau.abs()), pc)
}

fn pct(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = a.get(1).map(|s| s.as_str()).unwrap_or("coarse");
    let ntrain: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(16);
    let ntest: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(8);
    let ks: Vec<usize> = a.get(4).map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect()).unwrap_or(vec![20, 40, 60]);
    let tau: f64 = a.get(5).and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let kmax = *ks.iter().max().unwrap();
    let opts = SceneOptions::new(
        MeshSpec::preset(preset).unwrap(),
        NeoHookean::with_ratio(MU_HEICAST_MPA, std::env::var("KAPPA_OVER_MU").ok().and_then(|s| s.parse().ok()).unwrap_or(DEFAULT_KAPPA_OVER_MU)).unwrap().into(),
    );
    let mut opts = opts;
    if std::env::var("PRESSURE").as_deref() == Ok("P0") {
        opts.formulation.pressure = twistopt_solver::element::PressureSpace::P0;
    }
    let t = TrainOptions {
        designs: ntrain,
        truncation: Truncation::Modes(kmax),
        ecsw: EcswOptions { tau: 1.0, max_elements: 0, tangent_directions: 0, points: false, max_snapshots: 0 },
        frame: match std::env::var("FRAME").as_deref() {
            Ok("cartesian") => twistopt_solver::rom::Frame::Cartesian,
            Ok("cylindrical") => twistopt_solver::rom::Frame::Cylindrical,
            _ => twistopt_solver::rom::Frame::Piola,
        },
        pressure_modes: std::env::var("KP").ok().and_then(|s| s.parse().ok()).map(Truncation::Modes),
        ..TrainOptions::default()
    };
    let kps: Vec<usize> = std::env::var("KP_LIST").ok().map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect()).unwrap_or_default();
    let t0 = Instant::now();
    let log = |s: &str| eprintln!("{s}");
    let ramps = twistopt::rom::training_ramps(&opts, &t, &twistopt::rom::training_designs(ntrain), &log).unwrap();
    let (rom, rep) = twistopt::rom::from_ramps(&opts, &t, &ramps, &log).unwrap();
    println!("trained on {} designs ({} snapshots) in {:.1} s wall; {} modes", ntrain, rep.snapshots, t0.elapsed().as_secs_f64(), rep.modes);
    let s0 = rep.singular_values[0];
    println!(
        "singular values / first at k = 10, 20, 40, 60, 80, 120: {:?}",
        [10, 20, 40, 60, 80, 120].iter().filter_map(|&k| rep.singular_values.get(k).map(|s| format!("{:.1e}", s / s0))).collect::<Vec<_>>()
    );
    let designs = random_designs(ntest, 42);
    let full: Vec<(SceneResult, SceneResult, f64)> = designs
        .iter()
        .map(|d| {
            let g = ActuatorGeometry::new(d, RangePolicy::TableI).unwrap();
            let c0 = twistopt::evaluate::process_cpu_time_s();
            let f = run_pressure(&g, &opts, SceneKind::Free, &[100.0]).unwrap();
            let b = run_pressure(&g, &opts, SceneKind::Blocked, &[100.0]).unwrap();
            (f, b, twistopt::evaluate::process_cpu_time_s() - c0)
        })
        .collect();
    let full_cpu: f64 = full.iter().map(|x| x.2).sum::<f64>() / full.len() as f64;
    println!("full model: {full_cpu:.2} CPU s per design (free + blocked)");
    let combos: Vec<(usize, Option<usize>)> = ks.iter().flat_map(|&k| if kps.is_empty() { vec![(k, None)] } else { kps.iter().map(|&p| (k, Some(p))).collect() }).collect();
    for &(k, kp) in &combos {
        let mut basis = rom.basis.truncated(k);
        if let Some(kp) = kp {
            basis.pressure = if kp == 0 { None } else { basis.pressure.map(|p| p.truncated(kp)) };
        }
        let kp = basis.pressure.as_ref().map_or(0, |p| p.kp);
        let sample = if tau > 0.0 {
            // ECSW for this basis on the training states
            let e = EcswOptions { tau, max_elements: 100_000, tangent_directions: std::env::var("TANGENTS").ok().and_then(|s| s.parse().ok()).unwrap_or(0), points: false, max_snapshots: 0 };
            let fit = twistopt::rom::fit_sample(&opts, &basis, &ramps, &e).unwrap();
            println!("ECSW k={k} kp={kp}: {} elements, residual {:.2e}", fit.sample.elements.len(), fit.residual);
            fit.sample
        } else {
            Sample::all(rep.elements)
        };
        let ns = sample.elements.len();
        let mut ro = opts.clone();
        ro.rom = Some(Arc::new(Rom::new(basis, sample)));
        let (mut eo, mut ep, mut cpu) = (Vec::new(), Vec::new(), 0.0);
        for (d, (ff, fb, _)) in designs.iter().zip(&full) {
            let g = ActuatorGeometry::new(d, RangePolicy::TableI).unwrap();
            let c0 = twistopt::evaluate::process_cpu_time_s();
            let rf = run_pressure(&g, &ro, SceneKind::Free, &[100.0]).unwrap();
            let rb = run_pressure(&g, &ro, SceneKind::Blocked, &[100.0]).unwrap();
            cpu += twistopt::evaluate::process_cpu_time_s() - c0;
            let (of, pcf) = omega(ff, fb);
            let (or, pcr) = omega(&rf, &rb);
            let end = |r: &SceneResult| r.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
            let e_o = (or - of) / of;
            let e_pf = (end(&rf) - end(ff)) / end(ff);
            let e_pb = (end(&rb) - end(fb)) / end(fb);
            println!(
                "k={k:3} kp={kp:2} {}: Ω full {of:.3} ({} / {}, p {pcf:.3}) rom {or:.3} ({} / {}, p {pcr:.3}) err {:+.2}% | p_end err free {:+.2}% blocked {:+.2}%",
                twistopt::rom::label(d),
                ff.status,
                fb.status,
                rf.status,
                rb.status,
                100.0 * e_o,
                100.0 * e_pf,
                100.0 * e_pb
            );
            eo.push(e_o.abs());
            ep.push(e_pf.abs());
            ep.push(e_pb.abs());
        }
        let n = designs.len() as f64;
        println!(
            "SUMMARY k={k} kp={kp} sample={ns}: |Ω err| median {:.2}% p95 {:.2}% max {:.2}%; |p_end err| median {:.2}% p95 {:.2}% max {:.2}%; {:.2} CPU s per design",
            100.0 * pct(&mut eo.clone(), 0.5),
            100.0 * pct(&mut eo.clone(), 0.95),
            100.0 * pct(&mut eo, 1.0),
            100.0 * pct(&mut ep.clone(), 0.5),
            100.0 * pct(&mut ep.clone(), 0.95),
            100.0 * pct(&mut ep, 1.0),
            cpu / n
        );
    }
}
