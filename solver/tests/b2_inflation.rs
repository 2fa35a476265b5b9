//! B2 closed-end inflation of the 17/20 tube (free ends, F_red = 0) on a quarter slice
//! (`verify::inflation_slice`): pressure control up to the limit point, volume control past it.
mod common;
use twistopt_solver::continuation::{follow, ramp, ContinuationOptions, Control, LoadPath, PathEnd};
use twistopt_solver::element::Formulation;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::model::Loads;
use twistopt_solver::verify::{inflation_slice, InflationSlice};

fn slice() -> InflationSlice {
    // Q2/P1, 8 elements around the quarter × 2 through the wall × 1 along a 2 mm slice, κ/μ = 1000
    inflation_slice(Formulation::standard(ElementKind::Hex27), 8, 2, 2.0, 1000.0).unwrap()
}

struct Ref {
    la: f64,
    lz: f64,
    p: f64,
}

fn reference() -> (Vec<Ref>, f64, f64) {
    let b2 = common::shared("benchmarks/b2_cylinder_inflation.json");
    let c = &b2["compressible_reference"]["closed_ends_quad_kappa_over_mu_1000"];
    let rows = c["table"].as_array().unwrap().iter().map(|r| Ref { la: r["lA"].as_f64().unwrap(), lz: r["lz"].as_f64().unwrap(), p: r["P_MPa"].as_f64().unwrap() }).collect();
    (rows, c["P_max_MPa"].as_f64().unwrap(), c["lA_at_Pmax"].as_f64().unwrap())
}

#[test]
fn b2_pressure_control_up_to_the_limit_point() {
    let (rows, p_max, la_max) = reference();
    assert!((p_max - 0.0413873).abs() < 1e-7);
    let s = slice();
    let m = &s.model;
    let mut q = vec![0.0; m.n_reduced()];
    let mut from = Loads::zero(m);
    // the cavity of the quarter slice, closed by the caps through its top and bottom edges
    let v0 = m.assemble(&q, &from, false).unwrap().volume;
    let v_exact = s.volume_of(1.0, 1.0);
    assert!(((v0 - v_exact) / v_exact).abs() < 1e-5, "V = {v0} vs πA²h/4 = {v_exact}");
    // rising branch (λ_A ≤ 0.95 λ_A at P_max): λ_A and λ_z at the tabulated pressures
    for r in rows.iter().filter(|r| r.la <= 0.95 * la_max) {
        let mut to = from.clone();
        to.pressure = r.p;
        let res = ramp(m, &q, &from, &to, &ContinuationOptions::default());
        assert_eq!(res.end, PathEnd::Completed);
        let st = s.stretches(res.assembled.as_ref().unwrap());
        println!("P = {:.6}: λ_A {:.5} (ref {:.5}), λ_z {:.5} (ref {:.5})", r.p, st.0, r.la, st.1, r.lz);
        assert!((st.0 - r.la).abs() < 0.01 * r.la && (st.1 - r.lz).abs() < 0.01 * r.lz);
        q = res.q;
        from = to;
    }
    // beyond the maximum: the path switches to volume control before the fold, passes it and
    // locates it (P to 1e-6 relative of the discrete maximum)
    let mut to = from.clone();
    to.pressure = 0.05;
    let res = ramp(m, &q, &from, &to, &ContinuationOptions::default());
    let last = (res.loads.pressure, s.stretches(res.assembled.as_ref().unwrap()).0);
    println!(
        "the pressure path ends with {:?} at P = {:.7} (λ_A = {:.4}) after {} steps, {} Newton iterations; P_max = {p_max}",
        res.end, last.0, last.1, res.stats.steps, res.stats.newton_iterations
    );
    assert_eq!(res.end, PathEnd::Fold);
    assert_eq!(res.stats.failed_attempts, 0, "{:?}", res.stats);
    // the benchmark's closed-end tolerance: P_max within 0.3 %, λ_A at P_max within 1 %
    assert!((last.0 - p_max).abs() < 0.003 * p_max && (last.1 - la_max).abs() < 0.01 * la_max, "P {} λ_A {}", last.0, last.1);
}

#[test]
fn b2_volume_control_passes_the_maximum() {
    let (rows, p_max, la_max) = reference();
    let s = slice();
    let m = &s.model;
    // λ ∈ [0, 1] ↔ P ∈ [0, 0.05] MPa; the path is driven by the prescribed cavity volume
    let mut to = Loads::zero(m);
    to.pressure = 0.05;
    let lp = LoadPath::new(m, Loads::zero(m), to, Vec::new());
    let (mut q, mut lam) = (vec![0.0; m.n_reduced()], 0.0);
    let mut curve: Vec<(f64, f64)> = Vec::new(); // (λ_A, P) at every converged point
                                                 // prescribe the reference cavity volume π a² λ_z h / 4 of each row, both sides of the
                                                 // maximum, with 12 intermediate volumes from λ_A = 1.5 to the next row (samples for P_max)
    let mut targets: Vec<(f64, Option<&Ref>)> = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        targets.push((s.volume_of(r.la, r.lz), Some(r)));
        if r.la >= 1.5 && r.la < 1.6 {
            let next = &rows[i + 1];
            let (v0, v1) = (s.volume_of(r.la, r.lz), s.volume_of(next.la, next.lz));
            targets.extend((1..12).map(|k| (v0 + (v1 - v0) * k as f64 / 12.0, None)));
        }
    }
    for (v, row) in targets {
        let o = ContinuationOptions { start_control: Control::Functional, control_end: Some(v), stop_at_fold: false, stop_at_instability: false, ..Default::default() };
        let res = follow(&lp, &q, lam, 10.0, &[], &[], &o);
        assert_eq!(res.end, PathEnd::Completed, "V = {v}");
        let end = res.points.last().unwrap();
        let a = lp.assemble(&end.q, end.lam).unwrap();
        curve.push((s.stretches(&a).0, lp.loads(end.lam).pressure));
        q = end.q.clone();
        lam = end.lam;
        let Some(r) = row else { continue };
        let p = lp.loads(end.lam).pressure;
        let st = s.stretches(&lp.assemble(&end.q, end.lam).unwrap());
        let ep = (p - r.p) / r.p;
        println!("λ_A {:.5} (ref {:.3}), λ_z {:.5} (ref {:.5}), P {:.7} (ref {:.7}, {:+.4} %)", st.0, r.la, st.1, r.lz, p, r.p, 100.0 * ep);
        assert!(ep.abs() < 0.01, "P at λ_A = {}", r.la);
        assert!((st.0 - r.la).abs() < 0.01 * r.la && (st.1 - r.lz).abs() < 0.01 * r.lz);
    }
    let p = lp.loads(lam).pressure;
    let loads = Loads { pressure: p, ..Loads::zero(m) };
    // past the maximum (λ_A = 2.5) the tangent under pressure is indefinite: no Cholesky, but the
    // indefinite factorisation (LBLᵀ or LU) used by volume control solves it accurately
    let a = m.assemble(&q, &loads, true).unwrap();
    let kv = a.k.unwrap();
    assert!(m.factor(&kv).is_err(), "tangent past the maximum should be indefinite");
    let b: Vec<f64> = (0..m.n_reduced()).map(|i| ((i % 7) as f64 - 3.0) * 1e-3).collect();
    let x = m.factor_indefinite(&kv).unwrap().solve(&b).unwrap();
    let kx = m.sym_matvec(&kv, &x);
    let err = kx.iter().zip(&b).map(|(u, v)| (u - v).powi(2)).sum::<f64>().sqrt() / b.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!(err < 1e-6, "indefinite solve residual {err:e}");
    // the pressure maximum: parabola through the largest sample and its neighbours
    let k = (1..curve.len() - 1).max_by(|&a, &b| curve[a].1.partial_cmp(&curve[b].1).unwrap()).unwrap();
    let ((x0, y0), (x1, y1), (x2, y2)) = (curve[k - 1], curve[k], curve[k + 1]);
    assert!(y1 >= y0 && y1 >= y2, "the path passed a maximum");
    let d01 = (y1 - y0) / (x1 - x0);
    let d12 = (y2 - y1) / (x2 - x1);
    let c2 = (d12 - d01) / (x2 - x0);
    let xm = 0.5 * (x0 + x1) - d01 / (2.0 * c2);
    let ym = y0 + d01 * (xm - x0) + c2 * (xm - x0) * (xm - x1);
    println!("P_max {ym:.7} at λ_A {xm:.5} (ref {p_max:.7} at {la_max:.5}): {:+.4} %, {:+.4} %", 100.0 * (ym / p_max - 1.0), 100.0 * (xm / la_max - 1.0));
    assert!((ym - p_max).abs() < 0.02 * p_max && (xm - la_max).abs() < 0.02 * la_max);
    // the benchmark's own closed-end tolerance: P_max within 0.3 %, λ_A at P_max within 1 %
    assert!((ym - p_max).abs() < 0.003 * p_max && (xm - la_max).abs() < 0.01 * la_max);
}
