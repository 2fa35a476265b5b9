//! Closed, consistently oriented triangle surfaces of the actuator and a binary STL writer.
//!
//! * [`outer_surface`]: the outer wall faces plus the two planar end discs: encloses the outer
//!   volume.
//! * [`cavity_surface`]: the cavity wall faces (reversed, so normals point out of the cavity)
//!   plus the two planar end discs: encloses the chamber volume.
//!
//! Quadratic faces (9 nodes) become 8 triangles through their mid-nodes (Hex20 faces get a face
//! centre from the serendipity map), linear faces 2 triangles. Each end closure is a fan from
//! the axis point (0, 0, z_end) over the wall's boundary edges at that end (the end polygons are
//! star-shaped about the axis), oriented opposite to the wall edge it closes, so the result is
//! watertight (every edge shared by exactly two triangles) with outward normals.

use std::collections::HashMap;
use std::io::Write as _;
use std::path::Path;

use anyhow::{bail, Context, Result};
use twistopt_solver::mesh::Mesh;

use crate::geometry::L_TUBE;

/// An indexed triangle surface.
#[derive(Clone, Debug, Default)]
pub struct ClosedSurface {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[usize; 3]>,
}

impl ClosedSurface {
    /// Enclosed volume by the divergence theorem (positive for outward orientation).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = [self.vertices[t[0]], self.vertices[t[1]], self.vertices[t[2]]];
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0
            })
            .sum()
    }

    /// Number of edges not shared by exactly two triangles with opposite directions
    /// (0 for a closed, consistently oriented surface).
    pub fn defective_edges(&self) -> usize {
        let mut count: HashMap<(usize, usize), i32> = HashMap::new();
        for t in &self.triangles {
            for m in 0..3 {
                let (a, b) = (t[m], t[(m + 1) % 3]);
                *count.entry((a, b)).or_default() += 1;
            }
        }
        count.iter().filter(|(&(a, b), &c)| c != 1 || count.get(&(b, a)).copied().unwrap_or(0) != 1).count()
    }
}

fn face_triangles(mesh: &Mesh, face_nodes: &[usize], extra: &mut Vec<[f64; 3]>) -> Vec<[usize; 3]> {
    match face_nodes.len() {
        4 => {
            let n = face_nodes;
            vec![[n[0], n[1], n[2]], [n[0], n[2], n[3]]]
        }
        8 | 9 => {
            let c = &face_nodes[..4];
            let m = &face_nodes[4..8];
            let centre = if face_nodes.len() == 9 {
                face_nodes[8]
            } else {
                // serendipity face map at (0, 0): −¼ Σ corners + ½ Σ mid-edges
                let mut p = [0.0; 3];
                for &k in c {
                    p.iter_mut().zip(mesh.nodes[k]).for_each(|(a, x)| *a -= 0.25 * x);
                }
                for &k in m {
                    p.iter_mut().zip(mesh.nodes[k]).for_each(|(a, x)| *a += 0.5 * x);
                }
                extra.push(p);
                mesh.nodes.len() + extra.len() - 1
            };
            let quads = [[c[0], m[0], centre, m[3]], [m[0], c[1], m[1], centre], [centre, m[1], c[2], m[2]], [m[3], centre, m[2], c[3]]];
            quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect()
        }
        n => panic!("unexpected face with {n} nodes"),
    }
}

fn closed_surface_from_faces(mesh: &Mesh, set: &str, reverse: bool) -> Result<ClosedSurface> {
    let faces = mesh.face_sets.get(set).with_context(|| format!("mesh has no face set '{set}'"))?;
    if mesh.face_sets.contains_key("cut_start") {
        bail!("STL export needs the full 360° mesh (this is a sector mesh); build it with sector = false");
    }
    let mut extra = Vec::new();
    let mut tris = Vec::new();
    for f in faces {
        let fnodes = mesh.face_nodes(*f);
        for t in face_triangles(mesh, &fnodes, &mut extra) {
            tris.push(if reverse { [t[0], t[2], t[1]] } else { t });
        }
    }
    // compact vertex numbering
    let mut map: HashMap<usize, usize> = HashMap::new();
    let mut vertices = Vec::new();
    let get = |i: usize| {
        if i < mesh.nodes.len() {
            mesh.nodes[i]
        } else {
            extra[i - mesh.nodes.len()]
        }
    };
    let mut triangles: Vec<[usize; 3]> = tris
        .iter()
        .map(|t| {
            let mut o = [0; 3];
            for m in 0..3 {
                o[m] = *map.entry(t[m]).or_insert_with(|| {
                    vertices.push(get(t[m]));
                    vertices.len() - 1
                });
            }
            o
        })
        .collect();
    // boundary edges (used once): close with fans from the axis
    let mut count: HashMap<(usize, usize), usize> = HashMap::new();
    for t in &triangles {
        for m in 0..3 {
            let (a, b) = (t[m], t[(m + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut fans = Vec::new();
    let bottom_c = vertices.len();
    vertices.push([0.0, 0.0, 0.0]);
    let top_c = vertices.len();
    vertices.push([0.0, 0.0, L_TUBE]);
    for t in &triangles {
        for m in 0..3 {
            let (a, b) = (t[m], t[(m + 1) % 3]);
            if count[&(a.min(b), a.max(b))] == 1 {
                let za = vertices[a][2];
                let zb = vertices[b][2];
                let c = if za.abs() < 1e-9 && zb.abs() < 1e-9 {
                    bottom_c
                } else if (za - L_TUBE).abs() < 1e-9 && (zb - L_TUBE).abs() < 1e-9 {
                    top_c
                } else {
                    bail!("open edge of face set '{set}' away from the end planes (z = {za}, {zb})");
                };
                fans.push([b, a, c]);
            }
        }
    }
    triangles.extend(fans);
    Ok(ClosedSurface { vertices, triangles })
}

/// Closed outer surface (outer wall + end discs). Needs a full (not sector) mesh.
pub fn outer_surface(mesh: &Mesh) -> Result<ClosedSurface> {
    closed_surface_from_faces(mesh, "outer", false)
}

/// Closed cavity surface (inner wall + end discs), normals pointing out of the cavity.
pub fn cavity_surface(mesh: &Mesh) -> Result<ClosedSurface> {
    closed_surface_from_faces(mesh, "cavity", true)
}

/// Write a binary STL (facet normals from the vertex order).
pub fn write_stl_binary(path: &Path, surf: &ClosedSurface, name: &str) -> Result<()> {
    let mut buf = Vec::with_capacity(84 + 50 * surf.triangles.len());
    let mut header = [b' '; 80];
    let h = format!("twistopt {name}");
    let hb = h.as_bytes();
    header[..hb.len().min(80)].copy_from_slice(&hb[..hb.len().min(80)]);
    buf.extend_from_slice(&header);
    buf.extend_from_slice(&(surf.triangles.len() as u32).to_le_bytes());
    for t in &surf.triangles {
        let [a, b, c] = [surf.vertices[t[0]], surf.vertices[t[1]], surf.vertices[t[2]]];
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let mut n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len > 0.0 {
            n.iter_mut().for_each(|x| *x /= len);
        }
        for x in n.iter().chain(a.iter()).chain(b.iter()).chain(c.iter()) {
            buf.extend_from_slice(&(*x as f32).to_le_bytes());
        }
        buf.extend_from_slice(&0u16.to_le_bytes());
    }
    let mut f = std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    f.write_all(&buf).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}
