//! The cost of the cavity's self-contact set on the example design: sparsity (nnz, factor nnz), one
//! assembly + factorisation, candidates (studies/vacuum/README.md).
//!
//!   cargo run --release --example contact_cost
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::model::Loads;
fn main() {
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0), RangePolicy::TableI).unwrap();
    for mesh in ["coarse", "default"] {
        for contact in [false, true] {
            let mut o = SceneOptions::new(MeshSpec::preset(mesh).unwrap(), NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
            if contact {
                o.contact = Some(ContactOptions::default());
            }
            let t = std::time::Instant::now();
            let sm = SceneModel::build(&geom, &o, SceneKind::Free).unwrap();
            let tb = t.elapsed().as_secs_f64();
            let q = vec![0.0; sm.model.n_reduced()];
            let l = Loads::zero(&sm.model);
            let t = std::time::Instant::now();
            for _ in 0..5 {
                let a = sm.model.assemble(&q, &l, true).unwrap();
                let _ = sm.model.factor_indefinite(a.k.as_ref().unwrap());
            }
            let ta = t.elapsed().as_secs_f64() / 5.0;
            let (ns, nc) = sm.model.contact().map_or((0, 0), |c| (c.slaves.len(), c.slaves.iter().map(|s| s.targets.len()).sum()));
            println!("{mesh} contact {contact}: build {tb:.2} s, nnz {}, factor nnz {}, assemble+factor {ta:.3} s, slaves {ns}, candidates {nc}", sm.model.nnz(), sm.model.factor_nnz());
        }
    }
}
