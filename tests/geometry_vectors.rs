//! Every value in shared/geometry/test_vectors.json, reproduced to 1e-9 relative (1e-9 absolute
//! where the reference is ≈ 0).

mod common;
use common::{assert_close, test_vectors};
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy, L_TUBE, R_TUBE, T_WALL};

const TOL: f64 = 1e-9;

#[test]
fn all_test_vectors_reproduced() {
    let tv = test_vectors();
    let designs = tv.as_array().expect("array of designs");
    assert_eq!(designs.len(), 5);
    let mut checked = 0usize;
    for d in designs {
        let r = d["r"].as_f64().unwrap();
        let l = d["l"].as_f64().unwrap();
        let a = d["alpha_deg"].as_f64().unwrap();
        let tag = format!("design r={r} l={l} alpha={a}");
        assert_eq!(d["R"].as_f64().unwrap(), R_TUBE);
        assert_eq!(d["L"].as_f64().unwrap(), L_TUBE);
        assert_eq!(d["t"].as_f64().unwrap(), T_WALL);
        let g = ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::TableI).expect("valid design");
        let s = &g.act.section;
        let sec = &d["section"];
        for (key, val) in
            [("u", s.u), ("theta_L", s.theta_l), ("theta_N", s.theta_n), ("x", s.x), ("d", s.d), ("e", s.e), ("T", s.t_max), ("B", s.b_min), ("P", s.perimeter), ("A", s.area), ("phi_J", s.phi_j)]
        {
            assert_close(val, sec[key].as_f64().unwrap(), TOL, &format!("{tag} section.{key}"));
            checked += 1;
        }
        let p = &g.act.profile;
        let pr = &d["profile"];
        assert_close(p.delta, pr["delta"].as_f64().unwrap(), TOL, &format!("{tag} delta"));
        assert_close(p.beta, pr["beta"].as_f64().unwrap(), TOL, &format!("{tag} beta"));
        assert_close(p.length, pr["length"].as_f64().unwrap(), TOL, &format!("{tag} length"));
        match pr["rho_a"].as_f64() {
            Some(ra) => assert_close(p.rho_a(), ra, TOL, &format!("{tag} rho_a")),
            None => assert!(p.rho_a().is_infinite() && l == 20.0, "{tag}: rho_a null only for the straight tube"),
        }
        checked += 4;
        assert_close(g.inner_end_area(), d["end_inner_area"].as_f64().unwrap(), TOL, &format!("{tag} end_inner_area"));
        assert_close(g.outer_volume(), d["outer_volume"].as_f64().unwrap(), TOL, &format!("{tag} outer_volume"));
        assert_close(g.chamber_volume(), d["chamber_volume"].as_f64().unwrap(), TOL, &format!("{tag} chamber_volume"));
        checked += 3;
        for pt in d["points"].as_array().unwrap() {
            let shat = pt["shat"].as_f64().unwrap();
            let z = pt["z"].as_f64().unwrap();
            let eta = pt["eta"].as_f64().unwrap();
            let x = g.act.point(shat, z, eta);
            let n0 = g.act.surface(shat, z).n0;
            for c in 0..3 {
                assert_close(x[c], pt["point"][c].as_f64().unwrap(), TOL, &format!("{tag} point({shat},{z},{eta})[{c}]"));
                assert_close(n0[c], pt["untwisted_outer_normal"][c].as_f64().unwrap(), TOL, &format!("{tag} n0({shat},{z})[{c}]"));
                checked += 2;
            }
        }
    }
    assert!(checked > 250, "checked {checked} values");
}
