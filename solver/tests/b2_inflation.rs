//! B2 closed-end inflation of the 17/20 tube (free ends, F_red = 0) on a quarter slice
//! (`verify::inflation_slice`): pressure control up to the limit point, volume control past it.
mod common;
use twistopt_solver::element::Formulation;
use twistopt_solver::mesh::ElementKind;
use twistopt_solver::model::Loads;
use twistopt_solver::solve::{follow_path, follow_volume, FailureCause, PathStatus, StepOptions};
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
    let rows = c["table"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| Ref { la: r["lA"].as_f64().unwrap(), lz: r["lz"].as_f64().unwrap(), p: r["P_MPa"].as_f64().unwrap() })
        .collect();
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
        let mut st = (0.0, 0.0);
        let res = follow_path(m, &q, &from, &to, &StepOptions::default(), |i| {
            st = s.stretches(i.assembled);
            None
        });
        assert_eq!(res.status, PathStatus::Completed);
        println!("P = {:.6}: λ_A {:.5} (ref {:.5}), λ_z {:.5} (ref {:.5})", r.p, st.0, r.la, st.1, r.lz);
        assert!((st.0 - r.la).abs() < 0.01 * r.la && (st.1 - r.lz).abs() < 0.01 * r.lz);
        q = res.q;
        from = to;
    }
    // beyond the maximum: the stepper ends at a limit point with the last pressure near P_max
    let mut to = from.clone();
    to.pressure = 0.05;
    let mut last = (0.0, 0.0);
    let res = follow_path(m, &q, &from, &to, &StepOptions::default(), |i| {
        last = (i.loads.pressure, s.stretches(i.assembled).0);
        None
    });
    println!("pressure control ends with {:?} at P = {:.7} (λ_A = {:.4}); P_max = {p_max}", res.status, last.0, last.1);
    assert_eq!(res.status, PathStatus::Failed(FailureCause::LimitPoint));
    assert!(last.0 <= p_max * 1.001 && (last.0 - p_max).abs() < 0.02 * p_max, "last P {}", last.0);
}

#[test]
fn b2_volume_control_passes_the_maximum() {
    let (rows, p_max, la_max) = reference();
    let s = slice();
    let m = &s.model;
    let loads = Loads::zero(m);
    let (mut q, mut p) = (vec![0.0; m.n_reduced()], 0.0);
    let opts = StepOptions { initial: 0.25, max: 0.5, ..Default::default() };
    // prescribe the reference cavity volume π a² λ_z h / 4 of each row, both sides of the maximum
    let mut curve: Vec<(f64, f64)> = Vec::new(); // (λ_A, P) at every converged step
    for r in &rows {
        let mut st = (0.0, 0.0);
        let res = follow_volume(m, &q, p, &loads, s.volume_of(r.la, r.lz), &opts, |i| {
            st = s.stretches(i.assembled);
            curve.push((st.0, i.pressure));
            None
        });
        assert_eq!(res.status, PathStatus::Completed, "λ_A = {}", r.la);
        let ep = (res.pressure - r.p) / r.p;
        println!("λ_A {:.5} (ref {:.3}), λ_z {:.5} (ref {:.5}), P {:.7} (ref {:.7}, {:+.4} %)", st.0, r.la, st.1, r.lz, res.pressure, r.p, 100.0 * ep);
        assert!(ep.abs() < 0.01, "P at λ_A = {}", r.la);
        assert!((st.0 - r.la).abs() < 0.01 * r.la && (st.1 - r.lz).abs() < 0.01 * r.lz);
        q = res.q;
        p = res.pressure;
        if r.la < 1.6 {
            // fine volume steps across the maximum (to 1.8)
            let next = rows.iter().find(|n| n.la > 1.6).unwrap();
            let fine = StepOptions { initial: 0.02, max: 0.02, ..Default::default() };
            let res = follow_volume(m, &q, p, &loads, s.volume_of(next.la, next.lz), &fine, |i| {
                curve.push((s.stretches(i.assembled).0, i.pressure));
                None
            });
            assert_eq!(res.status, PathStatus::Completed);
            q = res.q;
            p = res.pressure;
        }
    }
    // past the maximum (λ_A = 2.5) the tangent under pressure is indefinite: no Cholesky, but the
    // indefinite factorisation (LBLᵀ or LU) used by volume control solves it accurately
    let mut lp = loads.clone();
    lp.pressure = p;
    let a = m.assemble(&q, &lp, true).unwrap();
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
