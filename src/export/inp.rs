//! CalculiX/Abaqus input-deck export of the mesh (nodes, elements, node sets, element-face
//! surfaces). Hex8 → C3D8; Hex20 → C3D20; Hex27 → C3D20 through its first 20 nodes (the face and
//! body centres are dropped with [`Mesh::to_kind`]).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use twistopt_solver::mesh::{ElementKind, Mesh};

/// Render the deck as a string (1-based node and element numbers).
pub fn inp_string(mesh: &Mesh, heading: &str) -> String {
    inp_string_with_type(mesh, heading, None)
}

/// [`inp_string`] with another CalculiX element type for the same nodes (e.g. `C3D20R` for a
/// quadratic mesh, `C3D8I` for a linear one); `None` keeps the default of the element kind.
pub fn inp_string_with_type(mesh: &Mesh, heading: &str, element_type: Option<&str>) -> String {
    let m;
    let mesh = if mesh.kind == ElementKind::Hex27 {
        m = mesh.to_kind(ElementKind::Hex20);
        &m
    } else {
        mesh
    };
    let mut s = String::new();
    let _ = writeln!(s, "*HEADING\n{heading}");
    s.push_str("*NODE, NSET=NALL\n");
    for (i, p) in mesh.nodes.iter().enumerate() {
        // CalculiX reads at most 20 characters per field: 13 significant digits fit
        let _ = writeln!(s, "{}, {:.12e}, {:.12e}, {:.12e}", i + 1, p[0], p[1], p[2]);
    }
    let _ = writeln!(s, "*ELEMENT, TYPE={}, ELSET=EALL", element_type.unwrap_or(mesh.kind.abaqus_name()));
    for e in 0..mesh.n_elements() {
        let ids: Vec<String> = mesh.element(e).iter().map(|n| (n + 1).to_string()).collect();
        // at most 16 entries per line (element number + 15 nodes), continuation lines after
        let mut line = format!("{}", e + 1);
        let mut count = 1;
        for id in ids {
            if count == 16 {
                let _ = writeln!(s, "{line},");
                line = id;
                count = 1;
            } else {
                line.push_str(", ");
                line.push_str(&id);
                count += 1;
            }
        }
        let _ = writeln!(s, "{line}");
    }
    for (name, nodes) in &mesh.node_sets {
        let _ = writeln!(s, "*NSET, NSET={}", name.to_uppercase());
        for chunk in nodes.chunks(16) {
            let ids: Vec<String> = chunk.iter().map(|n| (n + 1).to_string()).collect();
            let _ = writeln!(s, "{}", ids.join(", "));
        }
    }
    for (name, faces) in &mesh.face_sets {
        let _ = writeln!(s, "*SURFACE, NAME={}, TYPE=ELEMENT", name.to_uppercase());
        for f in faces {
            let _ = writeln!(s, "{}, {}", f.element + 1, f.side.abaqus_label());
        }
    }
    s
}

/// Write the deck to `path`.
pub fn write_inp(path: &Path, mesh: &Mesh, heading: &str) -> Result<()> {
    std::fs::write(path, inp_string(mesh, heading)).with_context(|| format!("cannot write {}", path.display()))
}
