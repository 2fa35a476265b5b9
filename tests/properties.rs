//! Randomised checks over the Table-I box (proptest): every design gives a valid mesh and
//! consistent, finite geometry.

use proptest::prelude::*;
use twistopt::export::cavity_surface;
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy, L_TUBE, R_TUBE};
use twistopt::meshing::{build_mesh, MeshSpec};

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, .. ProptestConfig::default() })]

    #[test]
    fn table_one_designs_are_valid(r in 8.660254037844386f64..=20.0, l in 10.0f64..=20.0, a in 60.0f64..=360.0) {
        let g = ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::TableI).unwrap();
        let s = &g.act.section;
        prop_assert!(s.b_min > 0.0 && s.b_min <= s.t_max && s.t_max <= R_TUBE + 1e-12);
        let (vc, vo) = (g.chamber_volume(), g.outer_volume());
        prop_assert!(vc > 0.0 && vc < vo && vo <= std::f64::consts::PI * R_TUBE * R_TUBE * L_TUBE + 1e-6);
        prop_assert!(g.inner_end_area() > 0.0 && g.inner_end_area() < g.outer_end_area());
        // outer surface stays inside the tube radius R; the top ring is turned by α
        for i in 0..24 {
            let shat = i as f64 / 24.0;
            let p = g.act.point(shat, L_TUBE, 0.0);
            prop_assert!(p[0].hypot(p[1]) <= R_TUBE + 1e-12);
            let q = g.act.point(shat, 0.0, 0.0);
            let turn = (p[1].atan2(p[0]) - q[1].atan2(q[0]) - a.to_radians()).rem_euclid(2.0 * std::f64::consts::PI);
            prop_assert!(turn.min(2.0 * std::f64::consts::PI - turn) < 1e-9);
        }
        let am = build_mesh(&g, &MeshSpec::preset("coarse").unwrap()).unwrap();
        prop_assert!(am.quality.min_scaled_jacobian > 0.05);
        let v = cavity_surface(&am.mesh).unwrap().volume();
        prop_assert!((v - vc).abs() / vc < 0.05, "coarse cavity {} vs {}", v, vc);
    }
}
