//! Structured hex meshes: topology, sets, orientation, quality, sector/cyclic pairs, shape
//! derivatives, and meshed volumes against the closed forms.

mod common;
use common::assert_close;
use twistopt::export::{cavity_surface, outer_surface};
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy, L_TUBE};
use twistopt::meshing::{build_mesh, mesh_shape_derivatives, MeshError, MeshSpec, MESH_PRESETS};
use twistopt::solver::mesh::{ElementKind, Mesh};

fn geom(r: f64, l: f64, a: f64) -> ActuatorGeometry {
    ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::TableI).expect("valid design")
}

const R0: f64 = 8.660254037844386;

#[test]
fn presets_parse_and_sizes() {
    for &(name, a, z, t, kind) in MESH_PRESETS {
        let s = MeshSpec::parse(name).unwrap();
        assert_eq!((s.n_around, s.n_along, s.n_through, s.kind), (a, z, t, kind));
        assert!(s.arc_aligned && !s.sector);
    }
    let s = MeshSpec::parse("36x12x3").unwrap();
    assert_eq!((s.n_around, s.n_along, s.n_through), (36, 12, 3));
    for bad in ["huge", "37x12x2", "36x10x2", "36x12x0", "36x12", "axbxc", ""] {
        let e = MeshSpec::parse(bad).unwrap_err();
        assert!(matches!(e, MeshError::Spec(_)), "{bad}: {e}");
        assert!(e.to_string().starts_with("mesh:"), "{e}");
    }
    assert!(MeshSpec::parse("huge").unwrap_err().to_string().contains("unknown mesh preset 'huge'"));
}

fn check_counts(m: &Mesh, spec: &MeshSpec) {
    let q = spec.kind.order();
    let na = if spec.sector { spec.n_around / 3 } else { spec.n_around };
    assert_eq!(m.n_elements(), na * spec.n_along * spec.n_through);
    let around = if spec.sector { q * na + 1 } else { q * na };
    let nodes_27 = around * (q * spec.n_along + 1) * (q * spec.n_through + 1);
    match spec.kind {
        ElementKind::Hex8 | ElementKind::Hex27 => assert_eq!(m.n_nodes(), nodes_27),
        ElementKind::Hex20 => assert!(m.n_nodes() < nodes_27),
    }
    assert_eq!(m.face_sets["cavity"].len(), na * spec.n_along);
    assert_eq!(m.face_sets["outer"].len(), na * spec.n_along);
    assert_eq!(m.face_sets["bottom"].len(), na * spec.n_through);
    assert_eq!(m.face_sets["top"].len(), na * spec.n_through);
    for n in &m.node_sets["bottom"] {
        assert!(m.nodes[*n][2].abs() < 1e-12);
    }
    for n in &m.node_sets["top"] {
        assert!((m.nodes[*n][2] - L_TUBE).abs() < 1e-12);
    }
}

/// Outward normal of a face at its centre (from its corner nodes) and the face centre.
fn face_normal(m: &Mesh, f: twistopt::solver::mesh::Face) -> ([f64; 3], [f64; 3]) {
    let n = m.face_nodes(f);
    let p: Vec<[f64; 3]> = n[..4].iter().map(|&i| m.nodes[i]).collect();
    let d1 = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
    let d2 = [p[3][0] - p[1][0], p[3][1] - p[1][1], p[3][2] - p[1][2]];
    let nn = [d1[1] * d2[2] - d1[2] * d2[1], d1[2] * d2[0] - d1[0] * d2[2], d1[0] * d2[1] - d1[1] * d2[0]];
    let c = [0, 1, 2].map(|k| p.iter().map(|q| q[k]).sum::<f64>() / 4.0);
    (nn, c)
}

#[test]
fn topology_sets_and_face_orientation_all_kinds() {
    let g = geom(R0, 10.0, 60.0);
    for kind in [ElementKind::Hex8, ElementKind::Hex20, ElementKind::Hex27] {
        for sector in [false, true] {
            let spec = MeshSpec::parse("24x8x2").unwrap().with_kind(kind).with_sector(sector);
            let am = build_mesh(&g, &spec).unwrap();
            check_counts(&am.mesh, &spec);
            assert!(am.quality.min_scaled_jacobian > 0.2, "{kind:?} {}", am.quality.min_scaled_jacobian);
            let m = &am.mesh;
            // cavity faces point into the cavity (towards the axis), outer faces away from it,
            // bottom faces −z, top faces +z
            for f in &m.face_sets["cavity"] {
                let (n, c) = face_normal(m, *f);
                assert!(n[0] * c[0] + n[1] * c[1] < 0.0);
            }
            for f in &m.face_sets["outer"] {
                let (n, c) = face_normal(m, *f);
                assert!(n[0] * c[0] + n[1] * c[1] > 0.0);
            }
            for f in &m.face_sets["bottom"] {
                assert!(face_normal(m, *f).0[2] < 0.0);
            }
            for f in &m.face_sets["top"] {
                assert!(face_normal(m, *f).0[2] > 0.0);
            }
            if sector {
                assert_eq!(m.face_sets["cut_start"].len(), 8 * 2);
                assert_eq!(m.face_sets["cut_end"].len(), 8 * 2);
                assert_eq!(m.node_sets["cut_start"].len(), am.cyclic_pairs.len());
            } else {
                assert!(am.cyclic_pairs.is_empty() && !m.face_sets.contains_key("cut_start"));
            }
            // every node is used
            let mut used = vec![false; m.n_nodes()];
            m.connectivity.iter().for_each(|&n| used[n] = true);
            assert!(used.iter().all(|&u| u));
        }
    }
}

#[test]
fn sector_cyclic_pairs_map_by_rotation_of_120_degrees() {
    for (arc_aligned, kind) in [(true, ElementKind::Hex27), (false, ElementKind::Hex8), (true, ElementKind::Hex20)] {
        let g = geom(13.2, 16.0, 200.0);
        let spec = MeshSpec::parse("48x16x2").unwrap().with_kind(kind).with_sector(true).with_arc_aligned(arc_aligned);
        let am = build_mesh(&g, &spec).unwrap();
        let m = &am.mesh;
        assert!(!am.cyclic_pairs.is_empty());
        let (s, c) = (2.0 * std::f64::consts::PI / 3.0).sin_cos();
        let start: std::collections::BTreeSet<usize> = m.node_sets["cut_start"].iter().copied().collect();
        let end: std::collections::BTreeSet<usize> = m.node_sets["cut_end"].iter().copied().collect();
        for &(a, b) in &am.cyclic_pairs {
            assert!(start.contains(&a) && end.contains(&b));
            let p = m.nodes[a];
            let q = m.nodes[b];
            let rp = [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
            for k in 0..3 {
                assert!((rp[k] - q[k]).abs() < 1e-12, "{kind:?}: pair ({a},{b}) {rp:?} vs {q:?}");
            }
        }
        assert_eq!(am.cyclic_pairs.len(), start.len());
        // the sector's nodes are exactly the full mesh's nodes of the first 120°
        let full = build_mesh(&g, &spec.with_sector(false)).unwrap();
        assert_eq!(full.mesh.n_elements(), 3 * m.n_elements());
    }
}

#[test]
fn arc_aligned_nodes_sit_on_the_curvature_jumps() {
    let g = geom(R0, 12.0, 90.0);
    let s = &g.act.section;
    let spec = MeshSpec::parse("48x8x1").unwrap().with_kind(ElementKind::Hex8);
    let am = build_mesh(&g, &spec).unwrap();
    // bottom ring of the outer surface: z = 0, λ = R/T, twist 0
    let na = spec.n_around;
    let outer_ring: Vec<[f64; 3]> = (0..na).map(|i| am.mesh.nodes[(spec.n_along + 1) * na + i]).collect();
    let scale = 20.0 / s.t_max;
    let fl = s.lobe_fraction();
    for k in 0..3 {
        for sj in [s.lobe_start_shat(k), s.lobe_start_shat(k) + fl / 3.0] {
            let c = s.eval(sj).c;
            let target = [c[0] * scale, c[1] * scale];
            let best = outer_ring.iter().map(|p| (p[0] - target[0]).hypot(p[1] - target[1])).fold(f64::INFINITY, f64::min);
            assert!(best < 1e-12, "junction at ŝ = {sj} not a node ({best})");
        }
    }
}

#[test]
fn no_inverted_elements_over_table_one_box() {
    let mut worst = f64::INFINITY;
    for r in [R0, 10.0, 13.2, 16.5, 20.0] {
        for l in [10.0, 13.0, 16.0, 20.0] {
            for a in [60.0, 150.0, 250.0, 360.0] {
                let g = geom(r, l, a);
                for kind in [ElementKind::Hex27, ElementKind::Hex8] {
                    let spec = MeshSpec::preset("default").unwrap().with_kind(kind);
                    let am = build_mesh(&g, &spec).unwrap_or_else(|e| panic!("r={r} l={l} a={a} {kind:?}: {e}"));
                    assert!(am.quality.min_scaled_jacobian > 0.05, "r={r} l={l} a={a}: {:?}", am.quality);
                    worst = worst.min(am.quality.min_scaled_jacobian);
                }
            }
        }
    }
    assert!(worst > 0.05);
}

#[test]
fn linear_mesh_quality_matches_the_geometry_md_table() {
    // GEOMETRY.md §5 (independent reference implementation): min scaled Jacobian of the
    // 120 × 40 × 3 linear mesh (19 680 nodes), and 240 × 80 × 4 for the max-twist design
    let cases = [
        (R0, 10.0, 60.0, "120x40x3", 0.455),
        (R0, 10.0, 180.0, "120x40x3", 0.311),
        (R0, 10.0, 360.0, "120x40x3", 0.162),
        (R0, 12.15, 152.3, "120x40x3", 0.468),
        (20.0, 20.0, 60.0, "120x40x3", 0.886),
        (R0, 11.75, 360.0, "120x40x3", 0.177),
        (R0, 11.75, 360.0, "240x80x4", 0.191),
    ];
    for (r, l, a, size, reference) in cases {
        let am = build_mesh(&geom(r, l, a), &MeshSpec::parse(size).unwrap().with_kind(ElementKind::Hex8)).unwrap();
        if size == "120x40x3" {
            assert_eq!(am.mesh.n_nodes(), 19_680);
            assert_eq!(am.mesh.n_elements(), 14_400);
        }
        let q = am.quality.min_scaled_jacobian;
        assert!((q - reference).abs() < 1.5e-3, "r={r} l={l} α={a} {size}: {q} vs GEOMETRY.md {reference}");
    }
}

#[test]
fn extended_range_meshes_stay_valid() {
    use twistopt::geometry::l_min_extended;
    for (r, a) in [(7.5, -90.0), (R0, 400.0), (12.0, 30.0), (20.0, 0.0)] {
        let l = l_min_extended(r) + 1e-3;
        let g = ActuatorGeometry::new(&Design::new(r, l, a), RangePolicy::Extended).unwrap();
        let am = build_mesh(&g, &MeshSpec::preset("default").unwrap()).unwrap();
        assert!(am.quality.min_scaled_jacobian > 0.0);
    }
}

#[test]
fn meshed_chamber_volume_converges_to_closed_form_and_is_alpha_independent() {
    let exact = geom(R0, 10.0, 60.0).chamber_volume();
    assert!((exact - 10673.3).abs() < 0.05);
    let exact_outer = geom(R0, 10.0, 60.0).outer_volume();
    let mut prev = f64::INFINITY;
    // halving h: 24x8x1 (coarse), 48x16x2 (default), 96x32x3 (finer than the fine preset)
    for name in ["coarse", "default", "96x32x3"] {
        let am = build_mesh(&geom(R0, 10.0, 60.0), &MeshSpec::parse(name).unwrap()).unwrap();
        let cav = cavity_surface(&am.mesh).unwrap();
        let out = outer_surface(&am.mesh).unwrap();
        assert_eq!(cav.defective_edges(), 0);
        assert_eq!(out.defective_edges(), 0);
        let err = (cav.volume() - exact).abs() / exact;
        assert!(err < prev * 0.6, "{name}: relative error {err} did not decrease (prev {prev})");
        prev = err;
        assert!((out.volume() - exact_outer).abs() / exact_outer < 0.02, "{name}: outer {}", out.volume());
    }
    assert!(prev < 1e-4, "fine mesh chamber volume error {prev}");
    // α-independence: the flat-triangle error grows with the twist but converges at second
    // order for every α, and the Richardson extrapolation of default/fine is the closed form
    for a in [60.0, 150.0, 360.0] {
        let g = geom(R0, 10.0, a);
        let v: Vec<f64> = ["default", "96x32x3"].iter().map(|p| cavity_surface(&build_mesh(&g, &MeshSpec::parse(p).unwrap()).unwrap().mesh).unwrap().volume()).collect();
        let (e1, e2) = ((v[0] - exact).abs(), (v[1] - exact).abs());
        assert!(e2 < 0.3 * e1, "α = {a}: no second-order convergence ({e1} → {e2})");
        let rich = (4.0 * v[1] - v[0]) / 3.0;
        assert!((rich - exact).abs() / exact < 3e-5, "α = {a}: extrapolated {rich} vs {exact}");
    }
    // linear elements also converge (2 triangles per face)
    let mut prev = f64::INFINITY;
    for size in ["24x8x1", "48x16x1", "96x32x1"] {
        let spec = MeshSpec::parse(size).unwrap().with_kind(ElementKind::Hex8);
        let v = cavity_surface(&build_mesh(&geom(R0, 10.0, 60.0), &spec).unwrap().mesh).unwrap().volume();
        let err = (v - exact).abs() / exact;
        assert!(err < prev * 0.5, "{size}: {err}");
        prev = err;
    }
}

#[test]
fn shape_derivatives_match_central_differences() {
    let d0 = Design::new(11.3, 13.4, 123.0);
    for (kind, arc) in [(ElementKind::Hex27, true), (ElementKind::Hex20, true), (ElementKind::Hex8, false)] {
        let spec = MeshSpec::parse("24x8x2").unwrap().with_kind(kind).with_arc_aligned(arc);
        let g0 = ActuatorGeometry::new(&d0, RangePolicy::TableI).unwrap();
        let ders = mesh_shape_derivatives(&g0, &spec).unwrap();
        assert_eq!(ders.len(), 3);
        let n_nodes = build_mesh(&g0, &spec).unwrap().mesh.n_nodes();
        for (name, dx) in &ders {
            assert_eq!(dx.len(), n_nodes);
            let h = 1e-5;
            let gp = ActuatorGeometry::new(&d0.with(name, d0.get(name).unwrap() + h).unwrap(), RangePolicy::TableI).unwrap();
            let gm = ActuatorGeometry::new(&d0.with(name, d0.get(name).unwrap() - h).unwrap(), RangePolicy::TableI).unwrap();
            let mp = build_mesh(&gp, &spec).unwrap().mesh;
            let mm = build_mesh(&gm, &spec).unwrap().mesh;
            let mut maxd: f64 = 0.0;
            for i in 0..n_nodes {
                for k in 0..3 {
                    let fd = (mp.nodes[i][k] - mm.nodes[i][k]) / (2.0 * h);
                    assert!((fd - dx[i][k]).abs() < 1e-6 * (1.0 + fd.abs()), "{kind:?} d/d{name} node {i}[{k}]: dual {} vs FD {fd}", dx[i][k]);
                    maxd = maxd.max(dx[i][k].abs());
                }
            }
            assert!(maxd > 1e-3, "{name}: derivative should not vanish");
        }
    }
}

#[test]
fn end_rings_planar_and_cavity_ring_matches_inner_end_area() {
    // the bottom cavity ring is the offset curve of the end section: the fan closure area
    // converges to A_in = (R/T)²A − t(R/T)P + πt²
    let g = geom(R0, 10.0, 60.0);
    let am = build_mesh(&g, &MeshSpec::parse("192x8x1").unwrap().with_kind(ElementKind::Hex8)).unwrap();
    let m = &am.mesh;
    let cav: std::collections::BTreeSet<usize> = m.node_sets["cavity"].iter().copied().collect();
    let ring: Vec<usize> = m.node_sets["bottom"].iter().copied().filter(|n| cav.contains(n)).collect();
    assert_eq!(ring.len(), 192);
    // ring nodes are numbered around in order
    let mut area = 0.0;
    for i in 0..ring.len() {
        let a = m.nodes[ring[i]];
        let b = m.nodes[ring[(i + 1) % ring.len()]];
        area += 0.5 * (a[0] * b[1] - a[1] * b[0]);
    }
    assert_close(area, g.inner_end_area(), 2e-3, "inner end area");
}

#[test]
fn default_mesh_generation_is_fast() {
    let g = geom(R0, 10.0, 60.0);
    let spec = MeshSpec::preset("default").unwrap();
    build_mesh(&g, &spec).unwrap();
    let t = std::time::Instant::now();
    for _ in 0..5 {
        build_mesh(&g, &spec).unwrap();
    }
    let per = t.elapsed().as_secs_f64() / 5.0;
    // budget 50 ms (the benchmark records the real number); generous here for loaded CI machines
    assert!(per < 0.25, "default mesh took {per} s");
}
