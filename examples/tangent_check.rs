//! Directional FD check of the scene model's tangent: K v vs (r(q + h v) − r(q − h v)) / 2h at an
//! equilibrium of the free scene (debug aid). Usage: tangent_check [mesh] [p_kPa] [l] [alpha] [scene]
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mesh = a.get(1).cloned().unwrap_or("coarse".into());
    let p: f64 = a.get(2).map(|s| s.parse().unwrap()).unwrap_or(5.0);
    let l: f64 = a.get(3).map(|s| s.parse().unwrap()).unwrap_or(12.15);
    let al: f64 = a.get(4).map(|s| s.parse().unwrap()).unwrap_or(152.3);
    let kind = SceneKind::parse(a.get(5).map(|s| s.as_str()).unwrap_or("free")).unwrap();
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), l, al), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    let sm = SceneModel::build(&geom, &opts, kind).unwrap();
    let eq = equilibrium(&sm, &opts, p, None);
    println!("equilibrium at {} kPa (end {:?}), θ {:.3}°", eq.loads.pressure * 1e3, eq.end, eq.record.theta_deg);
    let n = sm.model.n_reduced();
    for (label, q) in [("zero", vec![0.0; n]), ("equilibrium", eq.q.clone())] {
        let loads = &eq.loads;
        let asm = sm.model.assemble(&q, loads, true).unwrap();
        let k = asm.k.clone().unwrap();
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        };
        let v: Vec<f64> = (0..n).map(|_| rnd()).collect();
        let kv = sm.model.sym_matvec(&k, &v);
        for h in [1e-4, 1e-5, 1e-6] {
            let qp: Vec<f64> = q.iter().zip(&v).map(|(x, d)| x + h * d).collect();
            let qm: Vec<f64> = q.iter().zip(&v).map(|(x, d)| x - h * d).collect();
            let rp = sm.model.assemble(&qp, loads, false).unwrap().r;
            let rm = sm.model.assemble(&qm, loads, false).unwrap().r;
            let fd: Vec<f64> = rp.iter().zip(&rm).map(|(a, b)| (a - b) / (2.0 * h)).collect();
            let err = fd.iter().zip(&kv).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
            let nrm = kv.iter().map(|x| x * x).sum::<f64>().sqrt();
            // worst components
            let mut idx: Vec<usize> = (0..n).collect();
            idx.sort_by(|&i, &j| (fd[j] - kv[j]).abs().total_cmp(&(fd[i] - kv[i]).abs()));
            println!("{label}: h {h:e}: |Kv - FD| / |Kv| = {:.3e}; worst dofs {:?}", err / nrm, &idx[..4].iter().map(|&i| (i, kv[i], fd[i])).collect::<Vec<_>>());
        }
    }
}
