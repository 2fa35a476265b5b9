//! VTU/PVD/STL/INP writers: structure, data arrays, error handling.

use twistopt::export::{cavity_surface, outer_surface, write_pvd, write_stl_binary, write_vtu, DataArray};
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::{build_mesh, MeshSpec};
use twistopt::solver::mesh::ElementKind;

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("export-tests");
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn vtu_time_series_with_point_and_cell_data() {
    let g = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).unwrap();
    let am = build_mesh(&g, &MeshSpec::parse("12x4x1").unwrap().with_kind(ElementKind::Hex8)).unwrap();
    let m = &am.mesh;
    let mut entries = Vec::new();
    for step in 0..3 {
        let u: Vec<f64> = m.nodes.iter().flat_map(|p| [0.0, 0.0, step as f64 * 0.01 * p[2]]).collect();
        let s: Vec<f64> = (0..m.n_elements()).map(|e| e as f64 * step as f64).collect();
        let name = format!("step{step}.vtu");
        write_vtu(&tmp(&name), m, &[DataArray::new("displacement", 3, &u)], &[DataArray::new("stress", 1, &s)]).unwrap();
        entries.push((step as f64 * 0.5, name));
    }
    write_pvd(&tmp("series.pvd"), &entries).unwrap();
    let pvd = std::fs::read_to_string(tmp("series.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet ").count(), 3);
    assert!(pvd.contains("file=\"step2.vtu\""));
    let vtu = std::fs::read_to_string(tmp("step1.vtu")).unwrap();
    assert!(vtu.contains(&format!("NumberOfPoints=\"{}\" NumberOfCells=\"{}\"", m.n_nodes(), m.n_elements())));
    assert!(vtu.contains("Name=\"displacement\" NumberOfComponents=\"3\""));
    assert!(vtu.contains("<CellData>") && vtu.contains("Name=\"stress\""));
    // wrong lengths and non-finite values are errors, not corrupt files
    let short = vec![0.0; 5];
    let e = write_vtu(&tmp("bad.vtu"), m, &[DataArray::new("u", 3, &short)], &[]).unwrap_err();
    assert!(e.to_string().contains("'u'"), "{e}");
    let nan = vec![f64::NAN; m.n_elements()];
    assert!(write_vtu(&tmp("bad.vtu"), m, &[], &[DataArray::new("s", 1, &nan)]).is_err());
    assert!(write_pvd(&tmp("bad.pvd"), &[(f64::NAN, "x.vtu".into())]).is_err());
}

#[test]
fn stl_surfaces_closed_for_every_kind_and_sector_is_refused() {
    let g = ActuatorGeometry::new(&Design::new(13.2, 16.0, 200.0), RangePolicy::TableI).unwrap();
    let exact = g.chamber_volume();
    for kind in [ElementKind::Hex8, ElementKind::Hex20, ElementKind::Hex27] {
        let am = build_mesh(&g, &MeshSpec::parse("48x16x1").unwrap().with_kind(kind)).unwrap();
        let cav = cavity_surface(&am.mesh).unwrap();
        let out = outer_surface(&am.mesh).unwrap();
        assert_eq!(cav.defective_edges(), 0, "{kind:?}");
        assert_eq!(out.defective_edges(), 0, "{kind:?}");
        // flat triangles on a surface twisted by 200°: second-order error, 3.6e-3 at this size
        let tol = if kind == ElementKind::Hex8 { 2e-2 } else { 5e-3 };
        assert!((cav.volume() - exact).abs() / exact < tol, "{kind:?}: {} vs {exact}", cav.volume());
        assert!((out.volume() - g.outer_volume()).abs() / g.outer_volume() < tol);
        write_stl_binary(&tmp(&format!("cavity-{kind:?}.stl")), &cav, "cavity").unwrap();
        let len = std::fs::metadata(tmp(&format!("cavity-{kind:?}.stl"))).unwrap().len();
        assert_eq!(len, 84 + 50 * cav.triangles.len() as u64);
    }
    let sector = build_mesh(&g, &MeshSpec::parse("48x16x1").unwrap().with_sector(true)).unwrap();
    let e = cavity_surface(&sector.mesh).unwrap_err();
    assert!(e.to_string().contains("full 360"), "{e}");
}

#[test]
fn inp_numbering_and_surfaces() {
    let g = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).unwrap();
    let am = build_mesh(&g, &MeshSpec::parse("12x4x1").unwrap().with_sector(true)).unwrap();
    let s = twistopt::export::inp::inp_string(&am.mesh, "test");
    let hex20 = am.mesh.to_kind(ElementKind::Hex20);
    // node lines
    let nodes = s.split("*NODE, NSET=NALL\n").nth(1).unwrap().split('*').next().unwrap().lines().count();
    assert_eq!(nodes, hex20.n_nodes());
    // 21 entries per element → one continuation line each
    let elems = s.split("*ELEMENT, TYPE=C3D20, ELSET=EALL\n").nth(1).unwrap().split('*').next().unwrap().lines().count();
    assert_eq!(elems, 2 * am.mesh.n_elements());
    for name in ["CAVITY", "OUTER", "BOTTOM", "TOP", "CUT_START", "CUT_END"] {
        let block = s.split(&format!("*SURFACE, NAME={name}, TYPE=ELEMENT\n")).nth(1).unwrap();
        let n = block.split('*').next().unwrap().lines().count();
        assert_eq!(n, am.mesh.face_sets[&name.to_lowercase()].len(), "{name}");
    }
    assert!(s.contains(", S6\n") && s.contains(", S4\n") && s.contains(", S3\n") && s.contains(", S5\n"));
}
