//! Geometry variants (issue 10; studies/letter-calibration/VARIANTS.md): every variant against
//! the checks the spec's own geometry passes — G1 where claimed, volumes (mesh vs quadrature vs
//! closed form), no inverted elements over the Table-I box, the spec unchanged, the end-tangent
//! derivative against central differences (geometry and FE gradient), the cap-load switch, and a
//! problem file per variant through `twistopt evaluate` at one low pressure.

mod common;
use common::{assert_close, test_vectors};
use std::path::PathBuf;
use std::process::Command;
use twistopt::export::{cavity_surface, outer_surface};
use twistopt::geometry::volume::{designed_volume, enclosed_volume, end_ring_area};
use twistopt::geometry::{end_areas, Actuator, ActuatorGeometry, Design, GeometryVariant, OffsetSide, RangePolicy, Section, SectionReading, TwistOrder, L_TUBE, P_END_TANGENT, R_TUBE, T_WALL};
use twistopt::gradient::{scene_gradient, DEFAULT_KS_RHO_PER_MM};
use twistopt::meshing::{build_mesh, mesh_shape_derivatives, MeshSpec};
use twistopt::scene::{equilibrium, SceneKind, SceneModel, SceneOptions};
use twistopt_solver::material::{Material, NeoHookean};

const R0: f64 = 8.660254037844386; // 5√3

fn variant(name: &str) -> GeometryVariant {
    GeometryVariant::parse(name).unwrap()
}

fn design(r: f64, l: f64, a: f64, v: GeometryVariant, gamma: Option<f64>) -> Design {
    let d = Design::new(r, l, a).with_variant(v);
    match gamma {
        Some(g) => d.with_end_tangent(g),
        None => d,
    }
}

fn geom(r: f64, l: f64, a: f64, v: GeometryVariant, gamma: Option<f64>) -> ActuatorGeometry {
    ActuatorGeometry::new(&design(r, l, a, v, gamma), RangePolicy::TableI).unwrap_or_else(|e| panic!("{v} γ={gamma:?} ({r}, {l}, {a}): {e}"))
}

#[test]
fn spec_variant_is_the_spec_exactly() {
    // the spec through the variant machinery reproduces the shared test vectors…
    let tv = test_vectors();
    for d in tv.as_array().unwrap() {
        let (r, l, a) = (d["r"].as_f64().unwrap(), d["l"].as_f64().unwrap(), d["alpha_deg"].as_f64().unwrap());
        let dd: Design = serde_json::from_value(serde_json::json!({"values": {"r_mm": r, "l_mm": l, "alpha_deg": a}, "variant": "spec"})).unwrap();
        let g = ActuatorGeometry::new(&dd, RangePolicy::TableI).unwrap();
        assert!(g.act.variant.is_spec() && !g.act.needs_trim());
        assert_close(g.chamber_volume(), d["chamber_volume"].as_f64().unwrap(), 1e-9, "chamber volume");
        assert_close(g.outer_volume(), d["outer_volume"].as_f64().unwrap(), 1e-9, "outer volume");
        assert_close(g.inner_end_area(), d["end_inner_area"].as_f64().unwrap(), 1e-9, "inner end area");
        let spec = Actuator::<f64>::new(r, l, a.to_radians());
        for pt in d["points"].as_array().unwrap() {
            let (s, z, eta) = (pt["shat"].as_f64().unwrap(), pt["z"].as_f64().unwrap(), pt["eta"].as_f64().unwrap());
            let x = g.act.wall_point(s, z, eta);
            for c in 0..3 {
                assert_close(x[c], pt["point"][c].as_f64().unwrap(), 1e-9, "point");
            }
            // …and is bit for bit the spec's own code path
            assert_eq!(x, spec.point(s, z, eta));
        }
        // the default design serialises without the variant (JSON outputs unchanged)
        assert!(!serde_json::to_string(&g.design).unwrap().contains("variant"));
        // meshes identical to the bit
        let spec_geom = ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::TableI).unwrap();
        let m = MeshSpec::preset("coarse").unwrap();
        assert_eq!(build_mesh(&g, &m).unwrap().mesh.nodes, build_mesh(&spec_geom, &m).unwrap().mesh.nodes);
    }
}

#[test]
fn sections_are_g1_six_arc_rings_for_every_reading() {
    let mut rs: Vec<f64> = (0..23).map(|k| R0 + 0.5 * k as f64).collect();
    rs.push(20.0);
    for reading in [SectionReading::Triangle, SectionReading::TipsOnR, SectionReading::MidpointCentres] {
        for &r in &rs {
            let s = Section::<f64>::with_reading(r, reading);
            let tag = format!("{reading:?} r = {r}");
            // lobe and notch circles externally tangent, θL − θN = 2π/3
            let (c0, d0) = ([s.d, 0.0], [s.e * 0.5, s.e * 3f64.sqrt() / 2.0]);
            assert_close(((c0[0] - d0[0]).powi(2) + (c0[1] - d0[1]).powi(2)).sqrt(), 2.0 * r, 1e-12, &format!("{tag}: |C−D| = 2r"));
            assert_close(s.theta_l - s.theta_n, 2.0 * std::f64::consts::PI / 3.0, 1e-13, &tag);
            assert!(s.b_min > 0.0 && s.t_max > s.b_min - 1e-12, "{tag}");
            if s.theta_n == 0.0 {
                continue;
            }
            let fl = s.lobe_fraction();
            for k in 0..3 {
                for sj in [s.lobe_start_shat(k), s.lobe_start_shat(k) + fl / 3.0] {
                    let (a, b) = (s.eval(sj - 1e-11), s.eval(sj + 1e-11));
                    for c in 0..2 {
                        assert!((a.c[c] - b.c[c]).abs() < 1e-8 && (a.tau[c] - b.tau[c]).abs() < 1e-8, "{tag}: G1 at ŝ = {sj}");
                    }
                    assert!(a.kappa * b.kappa < 0.0, "{tag}: curvature changes sign at ŝ = {sj}");
                }
            }
            // the arc-length parameterisation closes and its polygon encloses the area A
            let n = 3000;
            let mut area = 0.0;
            for i in 0..n {
                let (p, q) = (s.eval(i as f64 / n as f64).c, s.eval((i + 1) as f64 / n as f64).c);
                area += 0.5 * (p[0] * q[1] - p[1] * q[0]);
            }
            assert_close(area, s.area, 2e-5, &format!("{tag}: area"));
        }
    }
}

#[test]
fn designed_surface_is_g1_in_z_for_every_variant_and_end_tangent() {
    // the designed surface of every variant is G1 across the profile junctions (three tangent
    // arcs)
    // there; the offset layers are parallel surfaces, so they share its normal: G1 too (their
    // z-parameterisation is only C0, the speed jumps with the curvature)
    let mut checked = 0;
    for v in GeometryVariant::all() {
        for gamma in [None, Some(-12.0), Some(18.0)] {
            let Ok(g) = ActuatorGeometry::new(&design(R0, 15.0, 60.0, v, gamma), RangePolicy::TableI) else {
                continue;
            };
            checked += 1;
            let act = g.act;
            let zj = act.profile.z_junction;
            let h = 1e-6;
            // unit normal from one-sided differences below (−1) or above (+1) z
            let normal = |s: f64, z: f64, eta: f64, side: f64| {
                let p = act.point(s, z + side * h, eta);
                let p2 = act.point(s, z + side * 2.0 * h, eta);
                let q = act.point(s + 1e-6, z + side * h, eta);
                let xz = [(p2[0] - p[0]) * side, (p2[1] - p[1]) * side, (p2[2] - p[2]) * side];
                let xs = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let n = [xs[1] * xz[2] - xs[2] * xz[1], xs[2] * xz[0] - xs[0] * xz[2], xs[0] * xz[1] - xs[1] * xz[0]];
                let m = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                (p, [n[0] / m, n[1] / m, n[2] / m])
            };
            for &s in &[0.01, 0.07, 0.2, 0.31] {
                for z in [zj, L_TUBE - zj] {
                    for eta in [0.0, 0.5, 1.0] {
                        let ((a, na), (b, nb)) = (normal(s, z, eta, -1.0), normal(s, z, eta, 1.0));
                        for c in 0..3 {
                            assert!((a[c] - b[c]).abs() < 1e-4, "{v} γ={gamma:?}: C0 at z = {z}");
                            assert!((na[c] - nb[c]).abs() < 1e-4, "{v} γ={gamma:?} η={eta}: G1 at z = {z}, ŝ = {s}: {na:?} vs {nb:?}");
                        }
                    }
                }
            }
        }
    }
    assert!(checked >= 30, "{checked}");
}

#[test]
fn volumes_mesh_quadrature_and_closed_forms_agree_for_every_variant() {
    let coarse = MeshSpec::preset("coarse").unwrap();
    let default = MeshSpec::preset("default").unwrap();
    for v in GeometryVariant::all() {
        for gamma in [None, Some(12.0)] {
            // twisting first folds the offset near (5√3, 12, 90) for some readings: a milder twist
            let g = if v.twist == TwistOrder::BeforeOffset { geom(R0, 15.0, 60.0, v, gamma) } else { geom(R0, 12.0, 90.0, v, gamma) };
            let act = &g.act;
            let tag = format!("{v} γ={gamma:?}");
            let (vc, vo) = (g.chamber_volume(), g.outer_volume());
            // two independent integrals of the designed surface: ∫ρ² and the surface integral
            let designed_layer = if v.offset == OffsetSide::Inward { 0.0 } else { 1.0 };
            assert_close(enclosed_volume(act, designed_layer, 48), designed_volume(act), 1e-10, &format!("{tag}: designed volume"));
            // the offset side: quadrature converged, and the meshed wall converges to it
            assert_close(enclosed_volume(act, 1.0, 64), vc, 1e-9, &format!("{tag}: chamber quadrature"));
            assert_close(enclosed_volume(act, 0.0, 64), vo, 1e-9, &format!("{tag}: outer quadrature"));
            assert!(vo > vc + 5000.0, "{tag}: wall volume {}", vo - vc);
            let mut errs = Vec::new();
            for spec in [coarse, default] {
                let m = build_mesh(&g, &spec).unwrap().mesh;
                let (cav, out) = (cavity_surface(&m).unwrap(), outer_surface(&m).unwrap());
                assert_eq!(cav.defective_edges(), 0, "{tag}");
                errs.push(((cav.volume() - vc) / vc, (out.volume() - vo) / vo));
                if spec == coarse {
                    // the meshed cap ring (top) against the end-area quadrature (bottom; same by symmetry)
                    let cap = twistopt::calculix::cap_area(&build_mesh(&g, &default).unwrap().mesh).unwrap();
                    assert_close(cap, g.inner_end_area(), 2e-3, &format!("{tag}: cavity end area"));
                }
            }
            for k in 0..2 {
                let (ec, ed) = if k == 0 { (errs[0].0, errs[1].0) } else { (errs[0].1, errs[1].1) };
                assert!(ed.abs() < 5e-3, "{tag}: default mesh volume error {ed} ({k})");
                assert!(ed.abs() < 0.4 * ec.abs() + 1e-5, "{tag}: no second-order convergence {ec} → {ed} ({k})");
            }
        }
    }
    // untrimmed walls: closed forms of the end areas (Steiner) against the ring quadrature, and
    // volumes independent of α; twisting first makes them depend on α
    for v in GeometryVariant::all().into_iter().filter(|v| v.twist == TwistOrder::AfterOffset) {
        let g = geom(13.2, 15.0, 60.0, v, None);
        let (ai, ao) = end_areas(&g.act);
        assert_close(end_ring_area(&g.act, 1.0), ai, 1e-10, &format!("{v}: inner end area"));
        assert_close(end_ring_area(&g.act, 0.0), ao, 1e-10, &format!("{v}: outer end area"));
        let g2 = geom(13.2, 15.0, 300.0, v, None);
        assert_close(g2.chamber_volume(), g.chamber_volume(), 1e-10, &format!("{v}: α-independent chamber"));
        // Steiner: the offset ring differs from the designed one by t·kP + πt² (k = R/T)
        let steiner = (R_TUBE / g.act.section.t_max) * g.act.section.perimeter * T_WALL + std::f64::consts::PI * T_WALL * T_WALL;
        let ring = R_TUBE / g.act.section.t_max;
        let designed = ring * ring * g.act.section.area;
        match v.offset {
            OffsetSide::Inward => assert_close(ao - ai, steiner - 2.0 * std::f64::consts::PI * T_WALL * T_WALL, 1e-9, &format!("{v}: Steiner")),
            OffsetSide::Outward => assert_close(ao - designed, steiner, 1e-9, &format!("{v}: outward Steiner")),
        }
    }
    let (a, b) = (geom(13.2, 15.0, 60.0, variant("twist-first"), None), geom(13.2, 15.0, 150.0, variant("twist-first"), None));
    assert!(b.chamber_volume() < a.chamber_volume() - 10.0, "twist-first: a uniform wall takes more room at larger α");
}

#[test]
fn no_inverted_elements_over_the_table_one_box() {
    // corners and centre of the Table-I box (α = 0 and 360 through the extended α range), coarse
    // mesh: every design a variant accepts meshes without inverted elements; a variant may refuse
    // a design only because its offset wall would fold (twist first) or its profile does not
    // exist (end tangent at l = 20), with a message saying so
    let coarse = MeshSpec::preset("coarse").unwrap();
    let mut cases: Vec<(GeometryVariant, Option<f64>)> = GeometryVariant::all().into_iter().map(|v| (v, None)).collect();
    for v in ["spec", "tips-on-r+outward", "twist-first", "midpoint-centres"] {
        cases.push((variant(v), Some(-15.0)));
        cases.push((variant(v), Some(15.0)));
    }
    let mut report = Vec::new();
    for (v, gamma) in cases {
        let (mut built, mut refused, mut worst) = (0, 0, f64::INFINITY);
        for r in [R0, 13.2, 20.0] {
            for l in [10.0, 15.0, 20.0] {
                for a in [0.0, 180.0, 360.0] {
                    match ActuatorGeometry::new(&design(r, l, a, v, gamma), RangePolicy::Extended) {
                        Ok(g) => {
                            let am = build_mesh(&g, &coarse).unwrap_or_else(|e| panic!("{v} γ={gamma:?} ({r}, {l}, {a}): {e}"));
                            assert!(am.quality.min_scaled_jacobian > 0.0);
                            worst = worst.min(am.quality.min_scaled_jacobian);
                            built += 1;
                        }
                        Err(e) => {
                            let e = e.to_string();
                            let folding = v.twist == TwistOrder::BeforeOffset && e.contains("would fold");
                            let no_profile = gamma.is_some_and(|g| g > 0.0) && l == 20.0 && e.starts_with(P_END_TANGENT);
                            let sharp = gamma == Some(-15.0) && l == 10.0 && r == R0;
                            assert!(folding || no_profile || sharp, "{v} γ={gamma:?} ({r}, {l}, {a}) refused: {e}");
                            refused += 1;
                        }
                    }
                }
            }
        }
        if v.twist == TwistOrder::AfterOffset && gamma.is_none() {
            assert_eq!(refused, 0, "{v}: every box design must be accepted");
        }
        // α = 0 is always buildable without an end tangent (no twist shear)
        report.push(format!("{v} γ={gamma:?}: {built} built (min scaled Jacobian {worst:.3}), {refused} refused"));
    }
    println!("{}", report.join("\n"));
}

#[test]
fn shape_derivatives_including_the_end_tangent_match_central_differences() {
    let spec = MeshSpec::preset("coarse").unwrap().with_sector(true);
    for (v, gamma, l) in
        [("spec", Some(0.0), 10.0), ("spec", Some(-8.0), 14.0), ("tips-on-r+outward", Some(10.0), 10.0), ("twist-first", Some(0.0), 14.0), ("midpoint-centres+twist-first", None, 16.0)]
    {
        let d0 = design(R0 + 1.0, l, 60.0, variant(v), gamma);
        let g0 = ActuatorGeometry::new(&d0, RangePolicy::TableI).unwrap();
        let ders = mesh_shape_derivatives(&g0, &spec).unwrap();
        let names: Vec<&str> = ders.iter().map(|d| d.0.as_str()).collect();
        assert_eq!(names.contains(&P_END_TANGENT), gamma.is_some(), "{v}: end tangent reported iff the design carries it");
        for (name, dx) in &ders {
            let h = 1e-5;
            let at = |t: f64| {
                let g = ActuatorGeometry::new(&d0.with(name, d0.get(name).unwrap() + t).unwrap(), RangePolicy::Extended).unwrap();
                build_mesh(&g, &spec).unwrap().mesh.nodes
            };
            let (mp, mm) = (at(h), at(-h));
            let mut maxd: f64 = 0.0;
            for i in 0..mp.len() {
                for k in 0..3 {
                    let fd = (mp[i][k] - mm[i][k]) / (2.0 * h);
                    assert!((fd - dx[i][k]).abs() < 2e-6 * (1.0 + fd.abs()), "{v} γ={gamma:?} d/d{name} node {i}[{k}]: dual {} vs FD {fd}", dx[i][k]);
                    maxd = maxd.max(dx[i][k].abs());
                }
            }
            assert!(maxd > 1e-3, "{v} {name}: derivative should not vanish");
        }
    }
    // scalar outputs (volumes, end areas) w.r.t. the end tangent
    let d0 = design(11.0, 13.0, 120.0, variant("tips-on-r+twist-first"), Some(6.0));
    let g0 = ActuatorGeometry::new(&d0, RangePolicy::TableI).unwrap();
    let sd = g0.scalar_derivatives();
    let e = sd.iter().find(|s| s.param == P_END_TANGENT).unwrap();
    let h = 1e-4;
    let gp = ActuatorGeometry::new(&d0.with(P_END_TANGENT, 6.0 + h).unwrap(), RangePolicy::TableI).unwrap();
    let gm = ActuatorGeometry::new(&d0.with(P_END_TANGENT, 6.0 - h).unwrap(), RangePolicy::TableI).unwrap();
    for (ad, fp, fm, what) in [
        (e.chamber_volume, gp.chamber_volume(), gm.chamber_volume(), "chamber"),
        (e.outer_volume, gp.outer_volume(), gm.outer_volume(), "outer"),
        (e.inner_end_area, gp.inner_end_area(), gm.inner_end_area(), "inner end area"),
    ] {
        let fd = (fp - fm) / (2.0 * h);
        assert!((ad - fd).abs() < 1e-6 * (1.0 + fd.abs()), "d {what}/dγ: {ad} vs {fd}");
    }
}

fn scene_opts(cap_load: bool) -> SceneOptions {
    let mut o = SceneOptions::new(MeshSpec::preset("coarse").unwrap(), Material::NeoHookean(NeoHookean::with_ratio(0.34, 300.0).unwrap()));
    o.cap_load = cap_load;
    o
}

#[test]
fn end_tangent_gradient_of_the_twist_matches_central_differences() {
    // dθ/dγ by the adjoint (design_gradient's scene gradient) against central differences of
    // warm-started equilibria, at 10 kPa on the coarse sector
    for (v, gamma, cap) in [("spec", 0.0, true), ("tips-on-r+outward", 10.0, false)] {
        let d0 = design(R0, 12.0, 90.0, variant(v), Some(gamma));
        let g0 = ActuatorGeometry::new(&d0, RangePolicy::TableI).unwrap();
        let o = scene_opts(cap);
        let sg = scene_gradient(&g0, &o, SceneKind::Free, 10.0, DEFAULT_KS_RHO_PER_MM, None, None).unwrap();
        assert_eq!(sg.status, twistopt::scene::SceneStatus::Converged);
        let ad = sg.gradients["theta_deg"][P_END_TANGENT];
        let theta = |t: f64| {
            let g = ActuatorGeometry::new(&d0.with(P_END_TANGENT, gamma + t).unwrap(), RangePolicy::TableI).unwrap();
            let sm = SceneModel::build(&g, &o, SceneKind::Free).unwrap();
            let mut oo = o.clone();
            oo.steps.newton.rtol = 1e-12;
            let eq = equilibrium(&sm, &oo, 10.0, Some((&sg.q, 10.0)));
            assert!(eq.end.is_none());
            eq.record.theta_deg
        };
        let h = 0.05;
        let fd = (theta(h) - theta(-h)) / (2.0 * h);
        println!("{v}: dθ/dγ adjoint {ad:.6e}, FD {fd:.6e}");
        assert!((ad - fd).abs() < 1e-4 * fd.abs().max(1e-3), "{v}: dθ/dγ adjoint {ad} vs FD {fd}");
    }
}

#[test]
fn without_cap_load_the_cap_is_not_pushed() {
    let g = geom(R0, 12.0, 90.0, GeometryVariant::spec(), None);
    let run = |kind: SceneKind, cap: bool| {
        let o = scene_opts(cap);
        let sm = SceneModel::build(&g, &o, kind).unwrap();
        equilibrium(&sm, &o, 15.0, None).record
    };
    // free: the closed cavity pushes the cap up by p·A_in; without it the actuator extends less
    let (on, off) = (run(SceneKind::Free, true), run(SceneKind::Free, false));
    assert!(off.axial_mm < on.axial_mm - 0.1, "axial {} (cap off) vs {} (cap on)", off.axial_mm, on.axial_mm);
    assert!(on.theta_deg != off.theta_deg);
    // with the axial motion held the cap force goes into the axle: nothing else changes
    let (on, off) = (run(SceneKind::PureTwist, true), run(SceneKind::PureTwist, false));
    assert_eq!(on.theta_deg, off.theta_deg);
    assert_eq!(on.max_radius_mm, off.max_radius_mm);
    // the CalculiX deck drops its cap force with it
    use twistopt::calculix::{build_deck, DeckOptions};
    let mat = NeoHookean::with_ratio(0.34, 300.0).unwrap().into();
    let spec = MeshSpec::parse("12x4x1").unwrap();
    let with = build_deck(&g, &spec, &mat, SceneKind::Free, &[10.0], &DeckOptions::default()).unwrap();
    let without = build_deck(&g, &spec, &mat, SceneKind::Free, &[10.0], &DeckOptions { cap_load: false, ..DeckOptions::default() }).unwrap();
    assert!(with.text.contains("*CLOAD") && !without.text.contains("*CLOAD") && without.text.contains("*DLOAD"));
}

fn out_dir(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn every_variant_runs_through_evaluate_at_a_low_pressure() {
    let base = "[design]\nr_mm = 8.660254037844386\nl_mm = 12\nalpha_deg = 90\n[load]\npressures_kPa = [10]\n[scenes]\nrun = [\"free\"]\n[fidelity]\npreset = \"coarse\"\n[output]\nvtu = false\n";
    let dir = out_dir("variants-evaluate");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("p.toml");
    std::fs::write(&path, base).unwrap();
    let run = |sets: &[&str], name: &str| {
        let out = dir.join(name);
        let mut c = Command::new(env!("CARGO_BIN_EXE_twistopt"));
        c.arg("evaluate").arg(&path);
        for s in sets {
            c.arg("--set").arg(s);
        }
        let o = c.arg("--out").arg(&out).output().unwrap();
        (o, out)
    };
    let mut thetas = Vec::new();
    for (name, sets) in [
        ("spec", vec![]),
        ("tips-on-r", vec!["design.variant=\"tips-on-r\""]),
        ("midpoint-centres", vec!["design.variant=\"midpoint-centres\""]),
        ("outward", vec!["design.variant=\"outward\""]),
        ("twist-first", vec!["design.variant=\"twist-first\"", "design.l_mm=15"]),
        ("end-tangent", vec!["design.end_tangent_deg=15"]),
        ("no-cap", vec!["scenes.cap_load=false"]),
        ("combined", vec!["design.variant=\"tips-on-r+outward+twist-first\"", "design.l_mm=15", "design.alpha_deg=60", "design.end_tangent_deg=-5", "scenes.cap_load=false"]),
    ] {
        let (o, out) = run(&sets, name);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
        let free = &r["scenes"]["free"];
        assert_eq!(free["status"], "completed", "{name}: {}", free["cause"]);
        let last = free["steps"].as_array().unwrap().last().unwrap();
        assert_eq!(last["p_kPa"].as_f64().unwrap(), 10.0);
        let theta = last["theta_deg"].as_f64().unwrap();
        assert!(theta.is_finite());
        // the effective problem and the geometry summary name the variant (the spec: neither)
        let v = r["problem"]["design"]["variant"].as_str();
        let sv = r["design"]["variant"].as_str();
        if name == "spec" || name == "no-cap" || name == "end-tangent" {
            assert!(v.is_none() && sv.is_none(), "{name}");
        } else {
            assert_eq!(v, sv, "{name}");
            assert!(v.is_some());
        }
        assert_eq!(r["problem"]["scenes"]["cap_load"].as_bool(), if sets.iter().any(|s| s.contains("cap_load")) { Some(false) } else { None });
        thetas.push((name, theta));
    }
    println!("{thetas:?}");
    // the readings are different actuators
    let t = |n: &str| thetas.iter().find(|x| x.0 == n).unwrap().1;
    for n in ["tips-on-r", "outward", "twist-first", "end-tangent", "no-cap"] {
        assert!((t(n) - t("spec")).abs() > 1e-3, "{n} gives the spec's twist {}", t(n));
    }
    // an unknown variant: one line naming the field and the valid values
    let (o, _) = run(&["design.variant=\"sideways\""], "bad");
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("design.variant") && e.contains("sideways") && e.contains("\"tips-on-r\"") && e.contains("\"twist-first\""), "{e}");
    // the example problem file parses and runs (coarse, free only, low pressure)
    let ex = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/letter-calibration-example.toml");
    let out = dir.join("example");
    let o = Command::new(env!("CARGO_BIN_EXE_twistopt")).args(["evaluate", ex, "--set", "load.pressures_kPa=[10]", "--set", "scenes.run=[\"free\"]", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
