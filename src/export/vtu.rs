//! VTK XML UnstructuredGrid (ASCII) and PVD time-series writers.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use anyhow::{bail, Context, Result};
use twistopt_solver::mesh::Mesh;

/// A named data array: `ncomp` components per point (or cell), `values.len() = ncomp × count`.
#[derive(Clone, Copy, Debug)]
pub struct DataArray<'a> {
    pub name: &'a str,
    pub ncomp: usize,
    pub values: &'a [f64],
}

impl<'a> DataArray<'a> {
    pub fn new(name: &'a str, ncomp: usize, values: &'a [f64]) -> Self {
        DataArray { name, ncomp, values }
    }
}

fn push_array(out: &mut String, a: &DataArray<'_>, count: usize, what: &str) -> Result<()> {
    if a.ncomp == 0 || a.values.len() != a.ncomp * count {
        bail!("{what} array '{}' has {} values; expected {} components × {count} = {}", a.name, a.values.len(), a.ncomp, a.ncomp * count);
    }
    if let Some(v) = a.values.iter().find(|v| !v.is_finite()) {
        bail!("{what} array '{}' contains a non-finite value ({v})", a.name);
    }
    let _ = writeln!(out, "        <DataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"ascii\">", xml_escape(a.name), a.ncomp);
    for chunk in a.values.chunks(a.ncomp.max(1) * 4) {
        out.push_str("          ");
        for v in chunk {
            let _ = write!(out, "{v:e} ");
        }
        out.push('\n');
    }
    out.push_str("        </DataArray>\n");
    Ok(())
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// Write `mesh` as an ASCII `.vtu` with optional point and cell data arrays.
pub fn write_vtu(path: &Path, mesh: &Mesh, point_data: &[DataArray<'_>], cell_data: &[DataArray<'_>]) -> Result<()> {
    let np = mesh.n_nodes();
    let ne = mesh.n_elements();
    let npe = mesh.kind.nodes_per_element();
    let mut s = String::with_capacity(64 * (np + ne * npe));
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <UnstructuredGrid>\n");
    let _ = writeln!(s, "    <Piece NumberOfPoints=\"{np}\" NumberOfCells=\"{ne}\">");
    s.push_str("      <Points>\n        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for p in &mesh.nodes {
        let _ = writeln!(s, "          {:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    s.push_str("        </DataArray>\n      </Points>\n      <Cells>\n");
    s.push_str("        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for e in 0..ne {
        s.push_str("          ");
        for n in mesh.element(e) {
            let _ = write!(s, "{n} ");
        }
        s.push('\n');
    }
    s.push_str("        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for e in 0..ne {
        let _ = writeln!(s, "          {}", (e + 1) * npe);
    }
    s.push_str("        </DataArray>\n        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    let t = mesh.kind.vtk_cell_type();
    for _ in 0..ne {
        let _ = writeln!(s, "          {t}");
    }
    s.push_str("        </DataArray>\n      </Cells>\n");
    if !point_data.is_empty() {
        s.push_str("      <PointData>\n");
        for a in point_data {
            push_array(&mut s, a, np, "point-data")?;
        }
        s.push_str("      </PointData>\n");
    }
    if !cell_data.is_empty() {
        s.push_str("      <CellData>\n");
        for a in cell_data {
            push_array(&mut s, a, ne, "cell-data")?;
        }
        s.push_str("      </CellData>\n");
    }
    s.push_str("    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    let mut f = std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    f.write_all(s.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Write a `.pvd` collection: (time, file name relative to the .pvd) for a time series.
pub fn write_pvd(path: &Path, entries: &[(f64, String)]) -> Result<()> {
    let mut s = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n");
    for (t, f) in entries {
        if !t.is_finite() {
            bail!("pvd entry '{f}' has a non-finite time {t}");
        }
        let _ = writeln!(s, "    <DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{}\"/>", xml_escape(f));
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    std::fs::write(path, s).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}
