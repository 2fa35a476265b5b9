use std::time::Instant;
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mesh = a.get(1).cloned().unwrap_or("sweep".into());
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 16.0, 200.0), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    let mut sm = SceneModel::build(&geom, &opts, SceneKind::Free).unwrap();
    if std::env::var_os("AMD").is_some() {
        let t = Instant::now();
        sm.model.set_ordering(twistopt_solver::model::Ordering::Amd).unwrap();
        println!("AMD symbolic {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    } else {
        let t = Instant::now();
        sm.model.set_ordering(twistopt_solver::model::Ordering::NestedDissection).unwrap();
        println!("ND symbolic {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    }
    println!("ordering {:?}: L nnz {}", sm.model.ordering(), sm.model.factor_nnz());
    let m = &sm.model;
    let n = m.n_reduced();
    let q = vec![0.0; n];
    let l = sm.loads(5.0, 0.0);
    let t = Instant::now();
    let mut ak = None;
    for _ in 0..5 {
        ak = Some(m.assemble(&q, &l, true).unwrap());
    }
    let tk = t.elapsed().as_secs_f64() / 5.0;
    let t = Instant::now();
    for _ in 0..20 {
        m.assemble(&q, &l, false).unwrap();
    }
    let tr = t.elapsed().as_secs_f64() / 20.0;
    let k = ak.unwrap().k.unwrap();
    let t = Instant::now();
    let mut f = None;
    for _ in 0..5 {
        f = Some(m.factor(&k).unwrap());
    }
    let tf = t.elapsed().as_secs_f64() / 5.0;
    let f = f.unwrap();
    let b = vec![1.0; n];
    let t = Instant::now();
    for _ in 0..20 {
        f.solve(&b).unwrap();
    }
    let ts = t.elapsed().as_secs_f64() / 20.0;
    let t = Instant::now();
    m.factor_lu(&k).unwrap();
    let tlu = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let _ = m.factor_indefinite(&k);
    let tind = t.elapsed().as_secs_f64();
    println!(
        "{mesh}: n {n} nnz {} threads {}: assemble K {:.1} ms, residual {:.2} ms, cholesky {:.1} ms, solve {:.2} ms, LU {:.1} ms, indefinite {:.1} ms",
        m.nnz(),
        rayon::current_num_threads(),
        tk * 1e3,
        tr * 1e3,
        tf * 1e3,
        ts * 1e3,
        tlu * 1e3,
        tind * 1e3
    );
}
