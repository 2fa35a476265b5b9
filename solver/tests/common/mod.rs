#![allow(dead_code)]
use serde_json::Value;
use std::path::PathBuf;

pub fn shared(path: &str) -> Value {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared").join(path);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("reading {}: {e}", p.display()));
    serde_json::from_str(&s).unwrap()
}

/// The largest difference between the assembled reduced tangent at (q, loads) and central
/// differences (step h) of the reduced residual, relative to the largest diagonal entry, with its
/// (row, column).
pub fn tangent_fd_error(model: &twistopt_solver::model::Model, q: &[f64], loads: &twistopt_solver::model::Loads, h: f64) -> (f64, usize, usize) {
    let a = model.assemble(q, loads, true).unwrap();
    let k = model.dense(a.k.as_ref().unwrap());
    let n = model.n_reduced();
    let kmax = (0..n).map(|i| k[(i, i)].abs()).fold(0.0, f64::max);
    let mut worst = (0.0f64, 0, 0);
    for col in 0..n {
        let mut qp = q.to_vec();
        let mut qm = q.to_vec();
        qp[col] += h;
        qm[col] -= h;
        let rp = model.assemble(&qp, loads, false).unwrap().r;
        let rm = model.assemble(&qm, loads, false).unwrap().r;
        for row in 0..n {
            let e = ((rp[row] - rm[row]) / (2.0 * h) - k[(row, col)]).abs() / kmax;
            if e > worst.0 {
                worst = (e, row, col);
            }
        }
    }
    worst
}
