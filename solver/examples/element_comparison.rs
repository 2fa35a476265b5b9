//! Element comparison on the verification benchmarks: Q2/P1 (Hex27), Q1/P0 (Hex8, mean
//! dilatation) and pure-displacement Q1/Q2, error against the reference vs reduced DOFs and wall
//! time. Prints a markdown table (committed as solver/element_comparison.md):
//!
//!   cargo run --release -p twistopt-solver --example element_comparison > solver/element_comparison.md
//!
//! B5: Cook's membrane tip u_y (κ/μ = 5000) vs 6.9339. B3: hollow tube twisted 90° over 40 mm at
//! fixed length (κ/μ = 1000) on the helically periodic slice (h = 2 mm), M and N vs the compressible
//! reference. B2: closed-end inflation (κ/μ = 1000), quarter slice (h = 2 mm) under volume control
//! to λ_A = 2.5 (past the maximum), P at λ_A = 1.5 and 2.5 vs the compressible reference.
use std::path::PathBuf;
use std::time::Instant;
use twistopt_solver::continuation::{follow, ContinuationOptions, Control, LoadPath, PathEnd};
use twistopt_solver::element::{Formulation, PressureSpace};
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::model::Loads;
use twistopt_solver::solve::NewtonOptions;
use twistopt_solver::verify::{cook_membrane, inflation_slice, torsion_slice};

fn shared(path: &str) -> serde_json::Value {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared").join(path);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| {
        eprintln!("reading {}: {e}", p.display());
        std::process::exit(1)
    });
    serde_json::from_str(&s).unwrap_or_else(|e| {
        eprintln!("parsing {}: {e}", p.display());
        std::process::exit(1)
    })
}

fn name(f: &Formulation) -> &'static str {
    match (f.kind, f.pressure) {
        (ElementKind::Hex27, PressureSpace::P1) => "Q2/P1 (Hex27)",
        (ElementKind::Hex27, PressureSpace::None) => "Q2 displacement (Hex27)",
        (ElementKind::Hex8, PressureSpace::P0) => "Q1/P0 (Hex8)",
        (ElementKind::Hex8, PressureSpace::None) => "Q1 displacement (Hex8)",
        _ => "other",
    }
}

fn status(s: &PathEnd) -> String {
    match s {
        PathEnd::Completed => "ok".into(),
        PathEnd::Failed(c) => format!("failed: {}", c.as_str()),
        other => format!("{other:?}"),
    }
}

fn main() {
    let q2p1 = Formulation::standard(ElementKind::Hex27);
    let q1p0 = Formulation::standard(ElementKind::Hex8);
    let q1 = Formulation { kind: ElementKind::Hex8, pressure: PressureSpace::None, ngauss: 2 };
    let q2 = Formulation { kind: ElementKind::Hex27, pressure: PressureSpace::None, ngauss: 3 };

    println!("### B5 Cook's membrane (plane strain, κ/μ = 5000): tip u_y vs 6.9339 mm\n");
    println!("| element | mesh | DOFs | u_y (mm) | error | Newton its | time (s) | status |");
    println!("|---|---|---|---|---|---|---|---|");
    let b5 = shared("benchmarks/b5_cook_membrane.json");
    let r5 = &b5["reference_values"]["heicast_mu0.34_kappa_over_mu_5000"];
    let (uy_ref, tr) = (r5["tip_uy_mm"].as_f64().unwrap(), r5["traction_N_per_mm2"].as_f64().unwrap());
    for (f, ns) in [(q2p1, vec![4, 8, 16]), (q1p0, vec![8, 16, 32]), (q2, vec![8, 16]), (q1, vec![16, 32])] {
        for n in ns {
            let t = Instant::now();
            match cook_membrane(f, n, 5000.0, tr) {
                Ok(r) => println!(
                    "| {} | {n}×{n}×1 | {} | {:.4} | {:+.2} % | {} | {:.2} | {} |",
                    name(&f),
                    r.dofs,
                    r.uy,
                    100.0 * (r.uy / uy_ref - 1.0),
                    r.newton_iterations,
                    t.elapsed().as_secs_f64(),
                    status(&r.status)
                ),
                Err(e) => println!("| {} | {n}×{n}×1 | – | – | – | – | – | {e} |", name(&f)),
            }
        }
    }

    println!("\n### B3 hollow tube 17/20, 90° over 40 mm, fixed length (κ/μ = 1000): M = 1304.380 N·mm, N = −28.2297 N\n");
    println!("| element | around × wall × along (2 mm slice) | DOFs | M error | N error | Newton its | time (s) | status |");
    println!("|---|---|---|---|---|---|---|---|");
    let b3 = shared("benchmarks/b3_torsion.json");
    let r3 = b3["compressible_reference_quad"]["hollow_fixed_length"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["angle_deg"].as_f64() == Some(90.0) && r["kappa_over_mu"].as_f64() == Some(1000.0))
        .unwrap()
        .clone();
    let (m_ref, n_ref) = (r3["M_Nmm"].as_f64().unwrap(), r3["N_N"].as_f64().unwrap());
    let opts = ContinuationOptions { initial: 1.0, max: 1.0, stop_at_instability: false, newton: NewtonOptions { indefinite: true, ..Default::default() }, ..Default::default() };
    for (f, meshes) in [(q2p1, vec![(12, 1), (24, 2), (48, 4)]), (q1p0, vec![(24, 2), (48, 4), (96, 8)]), (q2, vec![(24, 2)]), (q1, vec![(48, 4)])] {
        for (nt, nr) in meshes {
            let t = Instant::now();
            let s = match torsion_slice(f.kind, f, nt, nr, 2.0, 1000.0, false) {
                Ok(s) => s,
                Err(e) => {
                    println!("| {} | {nt}×{nr}×1 | – | – | – | – | – | {e} |", name(&f));
                    continue;
                }
            };
            let (pts, st, cost) = s.twist(40.0, &[10.0, 30.0, 60.0, 90.0], &opts);
            match pts.last().filter(|p| p.angle_deg == 90.0) {
                Some(p) => println!(
                    "| {} | {nt}×{nr}×1 | {} | {:+.3} % | {:+.3} % | {} | {:.2} | {} |",
                    name(&f),
                    s.model.n_reduced(),
                    100.0 * (p.m / m_ref - 1.0),
                    100.0 * (p.n / n_ref - 1.0),
                    cost.newton_iterations,
                    t.elapsed().as_secs_f64(),
                    status(&st)
                ),
                None => println!("| {} | {nt}×{nr}×1 | {} | – | – | {} | {:.2} | {} |", name(&f), s.model.n_reduced(), cost.newton_iterations, t.elapsed().as_secs_f64(), status(&st)),
            }
        }
    }

    println!("\n### B2 closed-end inflation (κ/μ = 1000), volume control past the maximum: P at λ_A = 1.5 and 2.5\n");
    println!("| element | around quarter × wall × along | DOFs | P error λ_A = 1.5 | P error λ_A = 2.5 | Newton its | time (s) | status |");
    println!("|---|---|---|---|---|---|---|---|");
    let b2 = shared("benchmarks/b2_cylinder_inflation.json");
    let rows = b2["compressible_reference"]["closed_ends_quad_kappa_over_mu_1000"]["table"].as_array().unwrap().clone();
    let row = |la: f64| rows.iter().find(|r| r["lA"].as_f64() == Some(la)).unwrap();
    let targets: Vec<(f64, f64, f64)> = [1.5, 2.5].iter().map(|&la| (la, row(la)["lz"].as_f64().unwrap(), row(la)["P_MPa"].as_f64().unwrap())).collect();
    for (f, meshes) in [(q2p1, vec![(4, 1), (8, 2)]), (q1p0, vec![(8, 2), (16, 4), (32, 8)]), (q2, vec![(8, 2)]), (q1, vec![(16, 4)])] {
        for (nt, nr) in meshes {
            let t = Instant::now();
            let s = match inflation_slice(f, nt, nr, 2.0, 1000.0) {
                Ok(s) => s,
                Err(e) => {
                    println!("| {} | {nt}×{nr}×1 | – | – | – | – | – | {e} |", name(&f));
                    continue;
                }
            };
            let m = &s.model;
            let mut to = Loads::zero(m);
            to.pressure = 0.05;
            let lp = LoadPath::new(m, Loads::zero(m), to, Vec::new());
            let (mut q, mut lam) = (vec![0.0; m.n_reduced()], 0.0);
            let mut errs = Vec::new();
            let mut its = 0;
            let mut last = PathEnd::Completed;
            for &(la, lz, p_ref) in &targets {
                let o = ContinuationOptions { start_control: Control::Functional, control_end: Some(s.volume_of(la, lz)), stop_at_fold: false, stop_at_instability: false, ..Default::default() };
                let res = follow(&lp, &q, lam, 10.0, &[], &[], &o);
                its += res.stats.newton_iterations;
                last = res.end.clone();
                let Some(end) = res.points.last().filter(|_| res.end == PathEnd::Completed) else {
                    break;
                };
                errs.push(format!("{:+.4} %", 100.0 * (lp.loads(end.lam).pressure / p_ref - 1.0)));
                q = end.q.clone();
                lam = end.lam;
            }
            errs.resize(2, "–".into());
            println!("| {} | {nt}×{nr}×1 | {} | {} | {} | {its} | {:.2} | {} |", name(&f), m.n_reduced(), errs[0], errs[1], t.elapsed().as_secs_f64(), status(&last));
        }
    }
}
