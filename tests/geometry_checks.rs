//! The checks of GEOMETRY.md §9 (plus design validation).

mod common;
use common::assert_close;
use std::f64::consts::PI;
use twistopt::geometry::scalar::gauss_legendre;
use twistopt::geometry::{l_min_extended, r_min_extended, Actuator, ActuatorGeometry, Design, GeometryError, RangePolicy, Section, L_TUBE, R_TUBE, T_WALL};

fn r_grid() -> Vec<f64> {
    // Table I grid 5√3 + 0.5k up to 19.66, plus the nominal end 20
    let mut v: Vec<f64> = (0..23).map(|k| 5.0 * 3f64.sqrt() + 0.5 * k as f64).collect();
    v.push(20.0);
    v
}

fn junction_shats(s: &Section<f64>) -> Vec<f64> {
    let fl = s.lobe_fraction();
    (0..3)
        .flat_map(|k| {
            let a = s.lobe_start_shat(k);
            [a, a + fl / 3.0]
        })
        .collect()
}

#[test]
fn circle_limit_r_equals_r_tube() {
    let s = Section::new(20.0);
    assert_close(s.area, PI * R_TUBE * R_TUBE, 1e-12, "area");
    assert_close(s.t_max, R_TUBE, 1e-12, "T");
    assert_close(s.b_min, R_TUBE, 1e-12, "B");
    assert_close(s.perimeter, 2.0 * PI * R_TUBE, 1e-12, "P");
    for i in 0..50 {
        let p = s.eval(i as f64 / 50.0);
        assert_close((p.c[0].powi(2) + p.c[1].powi(2)).sqrt(), R_TUBE, 1e-12, "on circle");
        assert_close(p.p, R_TUBE, 1e-12, "support value");
    }
}

#[test]
fn semicircle_limit_six_circle_chain() {
    let r = 5.0 * 3f64.sqrt();
    let s = Section::new(r);
    assert_close(s.u, PI / 6.0, 1e-13, "u");
    assert_close(s.theta_l, PI, 1e-13, "θL");
    assert_close(s.theta_n, PI / 3.0, 1e-13, "θN");
    assert_close(s.d, R_TUBE / 2.0, 1e-13, "d = R/2 (lobe centres on edge midpoints)");
    assert_close(s.e, R_TUBE, 1e-13, "e = R (notch centres on the vertices)");
    assert_close(s.x, 3f64.sqrt() * R_TUBE / 4.0, 1e-13, "x = s/4");
    // lobe chord = 2r: the junctions of lobe 0 are (R/2, ±r)
    let j = junction_shats(&s);
    let a = s.eval(j[0]);
    let b = s.eval(j[1]);
    assert_close(((a.c[0] - b.c[0]).powi(2) + (a.c[1] - b.c[1]).powi(2)).sqrt(), 2.0 * r, 1e-12, "lobe chord");
    assert_close(s.t_max / s.b_min, 18.660254037844386 / 11.339745962155618, 1e-12, "T/B");
}

#[test]
fn g1_tangency_and_inflection_points_on_triangle_sides_over_r_grid() {
    for r in r_grid() {
        let s = Section::new(r);
        // lobe and notch circles externally tangent: |C − D| = 2r
        let c0 = [s.d, 0.0];
        let d0 = [s.e * 0.5, s.e * 3f64.sqrt() / 2.0];
        assert_close(((c0[0] - d0[0]).powi(2) + (c0[1] - d0[1]).powi(2)).sqrt(), 2.0 * r, 1e-12, "|C-D| = 2r");
        for (m, sj) in junction_shats(&s).into_iter().enumerate() {
            if s.theta_n == 0.0 {
                continue; // circle: no junctions
            }
            let eps = 1e-11;
            let a = s.eval(sj - eps);
            let b = s.eval(sj + eps);
            for c in 0..2 {
                assert!((a.c[c] - b.c[c]).abs() < 1e-8, "r={r} junction {m}: position jump");
                assert!((a.tau[c] - b.tau[c]).abs() < 1e-8, "r={r} junction {m}: tangent jump");
            }
            assert!(a.kappa * b.kappa < 0.0, "r={r} junction {m}: curvature must change sign");
            // inflection point on the side of the inscribed triangle next to lobe k:
            // the side line is {x·(cos φk, sin φk) = R/2}
            let k = m / 2; // junction 2k is the start, 2k+1 the end of lobe k
            let phi = 2.0 * PI * k as f64 / 3.0;
            let p = s.eval(sj).c;
            assert_close(p[0] * phi.cos() + p[1] * phi.sin(), R_TUBE / 2.0, 1e-12, &format!("r={r} junction {m} on side"));
        }
        // unit tangent, unit normal, support value everywhere positive
        for i in 0..240 {
            let p = s.eval(i as f64 / 240.0);
            assert_close(p.tau[0].hypot(p.tau[1]), 1.0, 1e-14, "unit tangent");
            assert!(p.p > 0.0, "r={r}: support value must be positive");
        }
    }
}

#[test]
fn arc_length_parameterisation_has_constant_speed_and_closes() {
    for r in [5.0 * 3f64.sqrt(), 12.0, 17.5] {
        let s = Section::new(r);
        let n = 20000;
        let mut len = 0.0;
        for i in 0..n {
            let a = s.eval(i as f64 / n as f64).c;
            let b = s.eval((i + 1) as f64 / n as f64).c;
            len += (b[0] - a[0]).hypot(b[1] - a[1]);
        }
        assert_close(len, s.perimeter, 1e-7, "polygon length ≈ P");
        let t = s.eval(0.0);
        assert_close(t.c[0], s.t_max, 1e-13, "ŝ = 0 at the lobe tip (T, 0)");
        assert_close(t.c[1], 0.0, 1e-13, "tip y");
        // area by Green's theorem on a fine polygon
        let mut area = 0.0;
        for i in 0..n {
            let a = s.eval(i as f64 / n as f64).c;
            let b = s.eval((i + 1) as f64 / n as f64).c;
            area += 0.5 * (a[0] * b[1] - a[1] * b[0]);
        }
        assert_close(area, s.area, 1e-6, "area");
    }
}

#[test]
fn polar_form_matches_arc_length_form() {
    for r in r_grid() {
        let s = Section::new(r);
        for i in 0..300 {
            let p = s.eval(i as f64 / 300.0 + 0.0007);
            let phi = p.c[1].atan2(p.c[0]);
            assert_close(s.polar_radius(phi), p.c[0].hypot(p.c[1]), 1e-11, &format!("r={r} polar"));
        }
    }
    // the twisted outer surface in polar form
    let act = Actuator::new(11.0, 13.0, 200f64.to_radians());
    for i in 0..40 {
        for j in 0..=10 {
            let z = L_TUBE * j as f64 / 10.0;
            let x = act.point(i as f64 / 40.0, z, 0.0);
            let phi = x[1].atan2(x[0]);
            let y = act.outer_point_polar(phi, z);
            for c in 0..3 {
                assert_close(y[c], x[c], 1e-11, "polar surface");
            }
        }
    }
}

#[test]
fn profile_end_values_waist_c1_junctions_and_arc_length() {
    for l in [0.5, 5.0, 10.0, 11.75, 12.15, 16.0, 19.9, 20.0] {
        let act = Actuator::new(12.0, l, 0.0);
        let p = &act.profile;
        assert_close(p.eval(0.0).rho, R_TUBE, 1e-13, "ρ(0)");
        assert_close(p.eval(L_TUBE).rho, R_TUBE, 1e-13, "ρ(L)");
        assert_close(p.eval(L_TUBE / 2.0).rho, l, 1e-13, "ρ(L/2)");
        assert_close(p.eval(0.0).drho, 0.0, 1e-13, "ρ'(0)");
        assert_close(p.eval(L_TUBE).drho, 0.0, 1e-13, "ρ'(L)");
        for zj in [L_TUBE / 4.0, 3.0 * L_TUBE / 4.0] {
            let e = 1e-9;
            let a = p.eval(zj - e);
            let b = p.eval(zj + e);
            let slope = 1.0 + a.drho.abs();
            assert!((a.rho - b.rho).abs() < 1e-8 * slope, "l={l}: C0 at {zj}");
            assert!((a.drho - b.drho).abs() < 1e-7 * slope.powi(3) * (1.0 + a.d2rho.abs()), "l={l}: C1 at {zj}");
            assert_close(p.eval(zj).rho, (R_TUBE + l) / 2.0, 1e-12, "ρ at junction = (R+l)/2");
            if l < 20.0 {
                assert!(a.d2rho * b.d2rho < 0.0, "l={l}: curvature changes sign at {zj}");
            }
        }
        // arc length 4ρaβ against ∫ sqrt(1 + ρ'²) dz (Gauss–Legendre per arc)
        let (x, w) = gauss_legendre(60);
        let mut len = 0.0;
        for (a, b) in [(0.0, 10.0), (10.0, 30.0), (30.0, 40.0)] {
            let h = 0.5 * (b - a);
            for (xi, wi) in x.iter().zip(&w) {
                let d = p.eval(a + h * (xi + 1.0)).drho;
                len += wi * h * (1.0 + d * d).sqrt();
            }
        }
        let closed = if l < 20.0 { 4.0 * p.rho_a() * p.beta } else { L_TUBE };
        assert_close(p.length, closed, 1e-13, "length = 4ρaβ");
        if l > 1.0 {
            assert_close(len, p.length, 1e-10, &format!("l={l}: profile arc length"));
        }
        // at_arclength is consistent with ρ(z) and puts the junctions at ζ = 1/4, 3/4
        for i in 0..=40 {
            let zeta = i as f64 / 40.0;
            let (z, rho) = p.at_arclength(zeta);
            assert_close(p.eval(z).rho, rho, 1e-11, "at_arclength");
        }
        assert_close(p.at_arclength(0.25).0, L_TUBE / 4.0, 1e-12, "ζ = 1/4");
        assert_close(p.at_arclength(0.75).0, 3.0 * L_TUBE / 4.0, 1e-12, "ζ = 3/4");
    }
    // GEOMETRY.md §3 table
    for (l, ra, beta_deg, len) in [(10.0, 12.5, 53.13, 46.36), (11.75, 14.184, 44.83, 44.39), (16.0, 26.0, 22.62, 41.06)] {
        let p = Actuator::<f64>::new(12.0, l, 0.0).profile;
        assert!((p.rho_a() - ra).abs() < 1e-3);
        assert!((p.beta.to_degrees() - beta_deg).abs() < 1e-2);
        assert!((p.length - len).abs() < 1e-2);
    }
}

#[test]
fn plain_tube_chamber_volume_and_volumes_independent_of_alpha() {
    let g = ActuatorGeometry::new(&Design::new(20.0, 20.0, 60.0), RangePolicy::TableI).unwrap();
    assert_close(g.chamber_volume(), PI * (R_TUBE - T_WALL).powi(2) * L_TUBE, 1e-11, "tube chamber");
    assert_close(g.outer_volume(), PI * R_TUBE * R_TUBE * L_TUBE, 1e-12, "tube outer");
    assert_close(g.inner_end_area(), PI * 17.0 * 17.0, 1e-12, "tube inner end area");
    let base = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).unwrap();
    for a in [60.0, 152.3, 360.0] {
        let g = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, a), RangePolicy::TableI).unwrap();
        assert_close(g.chamber_volume(), base.chamber_volume(), 1e-14, "chamber vs α");
        assert_close(g.outer_volume(), base.outer_volume(), 1e-14, "outer vs α");
    }
    // GEOMETRY.md §6 table
    assert!((base.chamber_volume() - 10673.3).abs() < 0.05);
    assert!((base.outer_volume() - 20756.7).abs() < 0.05);
    assert!((base.wall_volume() - 10083.3).abs() < 0.05);
    assert!((base.inner_end_area() - 545.92).abs() < 0.005);
    let mt = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 16.0, 113.6), RangePolicy::TableI).unwrap();
    assert!((mt.chamber_volume() - 16684.9).abs() < 0.05);
    assert!((mt.wall_volume() - 11611.7).abs() < 0.05);
}

/// Principal curvatures of S0 from central finite differences of the surface.
fn fd_principal_curvatures(act: &Actuator<f64>, shat: f64, z: f64) -> (f64, f64) {
    let h = 1e-4;
    let p = act.section.perimeter;
    // parameters (s, z) with s = construction arc length
    let f = |ds: f64, dz: f64| act.surface(shat + ds / p, z + dz).s0;
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let sc = |a: [f64; 3], k: f64| [a[0] * k, a[1] * k, a[2] * k];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let xs = sc(sub(f(h, 0.0), f(-h, 0.0)), 0.5 / h);
    let xz = sc(sub(f(0.0, h), f(0.0, -h)), 0.5 / h);
    let x0 = f(0.0, 0.0);
    let xss = sc([f(h, 0.0)[0] - 2.0 * x0[0] + f(-h, 0.0)[0], f(h, 0.0)[1] - 2.0 * x0[1] + f(-h, 0.0)[1], f(h, 0.0)[2] - 2.0 * x0[2] + f(-h, 0.0)[2]], 1.0 / (h * h));
    let xzz = sc([f(0.0, h)[0] - 2.0 * x0[0] + f(0.0, -h)[0], f(0.0, h)[1] - 2.0 * x0[1] + f(0.0, -h)[1], f(0.0, h)[2] - 2.0 * x0[2] + f(0.0, -h)[2]], 1.0 / (h * h));
    let xsz = sc(sub(sub(f(h, h), f(h, -h)), sub(f(-h, h), f(-h, -h))), 0.25 / (h * h));
    let n = [xs[1] * xz[2] - xs[2] * xz[1], xs[2] * xz[0] - xs[0] * xz[2], xs[0] * xz[1] - xs[1] * xz[0]];
    let nn = dot(n, n).sqrt();
    let n = sc(n, 1.0 / nn); // outward (τ × e_z = ν)
    let (e, ff, g) = (dot(xs, xs), dot(xs, xz), dot(xz, xz));
    // convex positive: II with the inward normal
    let (l, m, nq) = (-dot(xss, n), -dot(xsz, n), -dot(xzz, n));
    let a = e * g - ff * ff;
    let b = -(l * g - 2.0 * m * ff + nq * e);
    let c = l * nq - m * m;
    let d = (b * b - 4.0 * a * c).max(0.0).sqrt();
    ((-b + d) / (2.0 * a), (-b - d) / (2.0 * a))
}

#[test]
fn principal_curvatures_match_finite_differences() {
    for (r, l) in [(5.0 * 3f64.sqrt(), 10.0), (13.2, 16.0), (17.0, 11.0)] {
        let act = Actuator::new(r, l, 0.0);
        for &shat in &[0.0, 0.03, 0.11, 0.2, 0.29, 0.47, 0.81] {
            for &z in &[2.0, 7.5, 13.0, 20.0, 26.0, 33.0, 38.5] {
                let (k1, k2) = act.principal_curvatures0(shat, z);
                let (f1, f2) = fd_principal_curvatures(&act, shat, z);
                assert!((k1 - f1).abs() < 2e-5 * (1.0 + k1.abs()), "r={r} l={l} ŝ={shat} z={z}: k1 {k1} vs FD {f1}");
                assert!((k2 - f2).abs() < 2e-5 * (1.0 + k2.abs()), "r={r} l={l} ŝ={shat} z={z}: k2 {k2} vs FD {f2}");
            }
        }
    }
    // smallest convex radius in Table I: r·l/T at the waist lobe (4.641 mm for r = 5√3, l = 10)
    let g = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).unwrap();
    let rl_t = 5.0 * 3f64.sqrt() * 10.0 / g.act.section.t_max;
    assert_close(1.0 / g.max_convex_curvature0(), rl_t, 1e-12, "min convex radius");
    assert!((rl_t - 4.641).abs() < 1e-3);
}

#[test]
fn design_validation_names_parameter_and_range() {
    let bad = [
        (Design::new(3.0, 10.0, 60.0), "r_mm", "[8.660254, 20] mm"),
        (Design::new(10.0, f64::NAN, 60.0), "l_mm", "[10, 20] mm"),
        (Design::new(10.0, 12.0, -5.0), "alpha_deg", "[60, 360] deg"),
        (Design::new(10.0, 21.0, 90.0), "l_mm", "[10, 20] mm"),
        (Design::new(f64::INFINITY, 12.0, 90.0), "r_mm", "not a finite"),
    ];
    for (d, name, needle) in bad {
        let e = ActuatorGeometry::new(&d, RangePolicy::TableI).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains(name) && msg.contains(needle), "{msg}");
        assert!(!msg.contains('\n'));
    }
    // extended range
    let ext = RangePolicy::Extended;
    assert!(ActuatorGeometry::new(&Design::new(10.0, 12.0, -5.0), ext).is_ok());
    assert!(ActuatorGeometry::new(&Design::new(8.0, 15.0, 400.0), ext).is_ok());
    assert!(ActuatorGeometry::new(&Design::new(10.0, 12.0, f64::NAN), ext).is_err());
    let e = ActuatorGeometry::new(&Design::new(6.0, 15.0, 90.0), ext).unwrap_err();
    assert!(e.to_string().contains("r_mm") && e.to_string().contains("6.546537"), "{e}");
    let lmin = l_min_extended(5.0 * 3f64.sqrt());
    assert!(lmin >= 3.5 * 18.660254037844386 / (5.0 * 3f64.sqrt()) && lmin < 10.0, "{lmin}");
    assert!(ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), lmin + 0.01, 90.0), ext).is_ok());
    assert!(ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), lmin - 0.05, 90.0), ext).is_err());
    let e = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 5.0, 90.0), ext).unwrap_err();
    assert!(matches!(e, GeometryError::OutOfRange { .. }) && e.to_string().contains("l_mm"), "{e}");
    assert!((r_min_extended() - 6.546536707079771).abs() < 1e-12);
    // the whole extended l range down to l_min keeps the outer convex radii above t + 0.5
    for r in [7.5, 8.0, 5.0 * 3f64.sqrt(), 12.0, 16.0, 20.0] {
        let lmin = l_min_extended(r);
        if lmin < 20.0 {
            let g = ActuatorGeometry::new(&Design::new(r, lmin.max(0.0) + 1e-9, 30.0), ext).unwrap();
            assert!(1.0 / g.max_convex_curvature0() > T_WALL + 0.5 - 1e-9);
        }
    }
    // design vectors for optimisers, in DesignSpace order
    let space = twistopt::geometry::DesignSpace::actuator();
    assert_eq!(space.names(), vec!["r_mm", "l_mm", "alpha_deg"]);
    let d = space.design_from_vec(&[10.0, 12.0, 90.0]).unwrap();
    assert_eq!(d, Design::new(10.0, 12.0, 90.0));
    assert_eq!(space.design_to_vec(&d).unwrap(), vec![10.0, 12.0, 90.0]);
    assert!(space.design_from_vec(&[1.0]).unwrap_err().to_string().contains("r_mm, l_mm, alpha_deg"));
    // unknown / missing names
    assert!(Design::from_pairs(&[("r_mm", 10.0), ("l_mm", 12.0)]).unwrap_err().to_string().contains("alpha_deg"));
    assert!(Design::from_pairs(&[("r_mm", 10.0), ("l_mm", 12.0), ("alpha_deg", 90.0), ("h", 1.0)]).unwrap_err().to_string().contains("'h'"));
}

#[test]
fn volume_and_area_derivatives_match_central_differences() {
    let d0 = Design::new(11.3, 13.4, 123.0);
    let g0 = ActuatorGeometry::new(&d0, RangePolicy::TableI).unwrap();
    let ders = g0.scalar_derivatives();
    assert_eq!(ders.len(), 3);
    for sd in &ders {
        let h = 1e-4;
        let v = d0.get(&sd.param).unwrap();
        let gp = ActuatorGeometry::new(&d0.with(&sd.param, v + h).unwrap(), RangePolicy::TableI).unwrap();
        let gm = ActuatorGeometry::new(&d0.with(&sd.param, v - h).unwrap(), RangePolicy::TableI).unwrap();
        let fd = |f: &dyn Fn(&ActuatorGeometry) -> f64| (f(&gp) - f(&gm)) / (2.0 * h);
        let pairs = [
            (sd.chamber_volume, fd(&|g| g.chamber_volume()), "chamber"),
            (sd.outer_volume, fd(&|g| g.outer_volume()), "outer"),
            (sd.wall_volume, fd(&|g| g.wall_volume()), "wall"),
            (sd.inner_end_area, fd(&|g| g.inner_end_area()), "A_in"),
            (sd.outer_end_area, fd(&|g| g.outer_end_area()), "A_out"),
        ];
        for (ad, f, what) in pairs {
            assert!((ad - f).abs() < 1e-6 * (1.0 + f.abs()), "d{what}/d{}: dual {ad} vs FD {f}", sd.param);
        }
        if sd.param == "alpha_deg" {
            assert!(sd.chamber_volume.abs() < 1e-9 && sd.outer_volume.abs() < 1e-9, "volumes do not depend on α");
        } else {
            assert!(sd.chamber_volume.abs() > 1.0, "d chamber / d{} should not vanish", sd.param);
        }
    }
}
