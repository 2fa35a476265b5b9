//! Contact pairs for a CalculiX deck, taken from a deformed state that twistopt computed.
//!
//! ccx's self-contact of one surface (`*CONTACT PAIR … CAVITY, CAVITY`) pairs every face with
//! its own neighbours and diverges long before any two walls meet (studies/vacuum § CalculiX
//! under vacuum). A deck that can follow the collapse needs the facing patches instead, and
//! those are known only from the collapsed state itself. [`contact_patches`] finds them on the
//! deck's own mesh: every cavity node that comes within `delta` of a cavity face outside its own
//! neighbourhood (faces with a vertex within `exclude` of it at rest, as in
//! `solver::contact::self_contact`) marks its faces and the faces it approaches; the marked faces
//! split into connected patches (faces sharing a node), and every two patches that approach each
//! other become one slave/master pair.

use anyhow::{bail, Result};
use std::collections::{BTreeMap, BTreeSet, HashMap};

use twistopt_solver::contact::{face_triangles, point_triangle, Vertex};
use twistopt_solver::integrity::{face_point, inside_element, jacobian_det, norm, project_on_face};
use twistopt_solver::mesh::{Face, Mesh};
use twistopt_solver::scalar::{cross, dot};

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// One contact pair of the deck: slave faces and master faces (faces of the deck's mesh).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PatchPair {
    pub slave: Vec<Face>,
    pub master: Vec<Face>,
    /// the smallest node-to-face distance between the two patches in the state they came from (mm)
    pub min_distance_mm: f64,
    /// cavity nodes of the slave patch within `delta` of the master patch
    pub close_nodes: usize,
}

/// The facing patches of the cavity surface `faces` of `mesh` at the deformed nodes `x`.
pub fn contact_patches(mesh: &Mesh, faces: &[Face], x: &[[f64; 3]], exclude: f64, delta: f64) -> Result<Vec<PatchPair>> {
    if x.len() != mesh.n_nodes() {
        bail!("contact_patches: {} positions for {} nodes", x.len(), mesh.n_nodes());
    }
    let x0 = &mesh.nodes;
    let tris: Vec<Vec<[usize; 3]>> = faces
        .iter()
        .map(|&f| {
            face_triangles(mesh, f)
                .into_iter()
                .map(|t| {
                    // face triangles have mesh nodes as vertices
                    let id = |v: Vertex| v.node().unwrap_or(usize::MAX);
                    [id(t[0]), id(t[1]), id(t[2])]
                })
                .collect()
        })
        .collect();
    let face_nodes: Vec<Vec<usize>> = faces.iter().map(|&f| mesh.face_nodes(f)).collect();
    let nodes: BTreeSet<usize> = face_nodes.iter().flatten().copied().collect();
    let d2 = |a: [f64; 3], b: [f64; 3]| (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f64>();
    // faces of each node
    let mut faces_of: HashMap<usize, Vec<usize>> = HashMap::new();
    for (fi, fnodes) in face_nodes.iter().enumerate() {
        for &n in fnodes {
            faces_of.entry(n).or_default().push(fi);
        }
    }
    // (slave face, master face) → (smallest distance, close nodes)
    let mut approach: BTreeMap<(usize, usize), (f64, usize)> = BTreeMap::new();
    let mut marked: BTreeSet<usize> = BTreeSet::new();
    for &n in &nodes {
        let p = x[n];
        for (fi, fnodes) in face_nodes.iter().enumerate() {
            if fnodes.iter().any(|&m| m == n || d2(x0[m], x0[n]) < exclude * exclude) {
                continue;
            }
            let d = tris[fi].iter().map(|t| point_triangle(p, [x[t[0]], x[t[1]], x[t[2]]]).0).fold(f64::INFINITY, f64::min);
            if d < delta {
                marked.insert(fi);
                for &sf in &faces_of[&n] {
                    marked.insert(sf);
                    let e = approach.entry((sf, fi)).or_insert((f64::INFINITY, 0));
                    e.0 = e.0.min(d);
                    e.1 += 1;
                }
            }
        }
    }
    // connected patches of the marked faces (sharing a node)
    let marked: Vec<usize> = marked.into_iter().collect();
    let mut patch_of: HashMap<usize, usize> = HashMap::new();
    let mut npatch = 0;
    for &start in &marked {
        if patch_of.contains_key(&start) {
            continue;
        }
        let mut stack = vec![start];
        patch_of.insert(start, npatch);
        while let Some(f) = stack.pop() {
            for &n in &face_nodes[f] {
                for &g in &faces_of[&n] {
                    if marked.binary_search(&g).is_ok() && !patch_of.contains_key(&g) {
                        patch_of.insert(g, npatch);
                        stack.push(g);
                    }
                }
            }
        }
        npatch += 1;
    }
    // patch pairs, the lower-numbered patch as the slave
    let mut pairs: BTreeMap<(usize, usize), (f64, usize)> = BTreeMap::new();
    for (&(sf, mf), &(d, k)) in &approach {
        let (a, b) = (patch_of[&sf], patch_of[&mf]);
        if a == b {
            bail!("a patch of the cavity surface approaches itself (faces {sf} and {mf}): it cannot be split into a slave and a master surface; lower delta");
        }
        let e = pairs.entry((a.min(b), a.max(b))).or_insert((f64::INFINITY, 0));
        e.0 = e.0.min(d);
        if a < b {
            e.1 += k;
        }
    }
    let members = |p: usize| -> Vec<Face> { marked.iter().filter(|f| patch_of[f] == p).map(|&f| faces[f]).collect() };
    Ok(pairs.into_iter().map(|((a, b), (d, k))| PatchPair { slave: members(a), master: members(b), min_distance_mm: d, close_nodes: k }).collect())
}

/// Deformed positions of the nodes of `full` (a full 360° mesh) from a displacement field `u` on
/// `part` (the same structured mesh or its 120° sector, of any element kind with the same
/// nodes): every node of `full` is found in `part` rotated about z by a multiple of `2π/copies`.
pub fn map_deformed(full: &Mesh, part: &Mesh, u: &[[f64; 3]], copies: usize) -> Result<Vec<[f64; 3]>> {
    let key = |p: [f64; 3]| ((p[0] * 1e5).round() as i64, (p[1] * 1e5).round() as i64, (p[2] * 1e5).round() as i64);
    let mut at: HashMap<(i64, i64, i64), usize> = HashMap::new();
    for (i, p) in part.nodes.iter().enumerate() {
        at.insert(key(*p), i);
    }
    let mut out = Vec::with_capacity(full.n_nodes());
    'node: for p in &full.nodes {
        for k in 0..copies.max(1) {
            let a = -(k as f64) * 2.0 * std::f64::consts::PI / copies.max(1) as f64;
            let (s, c) = a.sin_cos();
            let q = [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
            // look up the rounded key and its neighbours (round-off at a rounding boundary)
            for dx in -1..=1i64 {
                for dy in -1..=1i64 {
                    for dz in -1..=1i64 {
                        let k0 = key(q);
                        if let Some(&i) = at.get(&(k0.0 + dx, k0.1 + dy, k0.2 + dz)) {
                            let w = u[i];
                            // rotate the displacement back by −a
                            let (s, c) = (-a).sin_cos();
                            out.push([p[0] + c * w[0] - s * w[1], p[1] + s * w[0] + c * w[1], p[2] + w[2]]);
                            continue 'node;
                        }
                    }
                }
            }
        }
        bail!("node at ({:.4}, {:.4}, {:.4}) of the full mesh has no counterpart in the model's mesh", p[0], p[1], p[2]);
    }
    Ok(out)
}

/// The gaps between two patches of a mesh's faces at the nodes `x` ([`surface_gaps`]), in mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceGaps {
    /// from the slave patch's nodes to the master patch's node triangles ([`face_triangles`]):
    /// what the contact barrier sees
    pub node: f64,
    /// between the faces' own (quadratic) surfaces, the slave face sampled on an m × m grid and
    /// the master face replaced by the triangles of its own m × m grid, negative where a sample
    /// lies behind the nearest such triangle's plane. Its chords and the nearest triangle's sign
    /// (wrong beside an edge) make it an estimate, good to about the chords' sag.
    pub sampled: f64,
    /// the same slave samples against the master faces themselves: the distance to the closest
    /// point of the quadratic master face (projected by Newton), negative where the sample lies
    /// inside a master face's element (the isoparametric map inverted): a point of one wall
    /// inside the other wall's material
    pub exact: f64,
}

/// The gap between two patches of a mesh's faces at the nodes `x`, measured three ways
/// ([`SurfaceGaps`]). `m` ≥ 2 samples per face direction.
pub fn surface_gaps(mesh: &Mesh, slave: &[Face], master: &[Face], x: &[[f64; 3]], m: usize) -> SurfaceGaps {
    let m = m.max(2);
    let node_tris: Vec<[[f64; 3]; 3]> = master.iter().flat_map(|&f| face_triangles(mesh, f)).map(|t| [0, 1, 2].map(|i| x[t[i].node().unwrap_or(0)])).collect();
    let mut node_gap = f64::INFINITY;
    let slave_nodes: BTreeSet<usize> = slave.iter().flat_map(|&f| mesh.face_nodes(f)).collect();
    for &n in &slave_nodes {
        for t in &node_tris {
            node_gap = node_gap.min(point_triangle(x[n], *t).0);
        }
    }
    let st_of = |i: usize, j: usize| [-1.0 + 2.0 * i as f64 / (m - 1) as f64, -1.0 + 2.0 * j as f64 / (m - 1) as f64];
    let grid = |f: Face| -> Vec<Vec<[f64; 3]>> { (0..m).map(|i| (0..m).map(|j| face_point(mesh, f, x, st_of(i, j)).0).collect()).collect() };
    // master sub-triangles with their (outward, into the cavity) normals, their face and the
    // (s, t) of their first vertex
    let mut tris: Vec<([[f64; 3]; 3], [f64; 3], usize, [f64; 2])> = Vec::new();
    for (k, &f) in master.iter().enumerate() {
        let g = grid(f);
        for i in 0..m - 1 {
            for j in 0..m - 1 {
                let (a, b, c, d) = (g[i][j], g[i + 1][j], g[i + 1][j + 1], g[i][j + 1]);
                for t in [[a, b, c], [a, c, d]] {
                    tris.push((t, cross(sub(t[1], t[0]), sub(t[2], t[0])), k, st_of(i, j)));
                }
            }
        }
    }
    let h = 2.0 / (m - 1) as f64;
    let (mut best, mut signed, mut exact) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let trace = std::env::var_os("TWISTOPT_GAP_TRACE").is_some();
    for &sf in slave {
        for (i, row) in grid(sf).into_iter().enumerate() {
            for (j, p) in row.into_iter().enumerate() {
                let dt: Vec<f64> = tris.iter().map(|(t, ..)| point_triangle(p, *t).0).collect();
                let (k0, d0) = dt.iter().enumerate().fold((0, f64::INFINITY), |acc, (k, &d)| if d < acc.1 { (k, d) } else { acc });
                if d0 < best {
                    best = d0;
                    let (t, n, ..) = &tris[k0];
                    signed = if dot(sub(p, t[0]), *n) >= 0.0 { d0 } else { -d0 };
                }
                // the master faces near the sample (a sub-triangle within its own size of the
                // nearest), each from its nearest sub-triangle's corner
                let mut start: BTreeMap<usize, (f64, [f64; 2])> = BTreeMap::new();
                for (k, (t, _, face, st)) in tris.iter().enumerate() {
                    let size = (0..3).map(|a| norm(sub(t[a], t[(a + 1) % 3]))).fold(0.0, f64::max);
                    if dt[k] <= d0 + size {
                        let e = start.entry(*face).or_insert((f64::INFINITY, *st));
                        if dt[k] < e.0 {
                            *e = (dt[k], [st[0] + 0.5 * h, st[1] + 0.5 * h]);
                        }
                    }
                }
                let mut dist = f64::INFINITY;
                let mut closest = None;
                let mut inside = None;
                for (&face, &(_, st0)) in &start {
                    let (st, q) = project_on_face(mesh, master[face], x, p, st0);
                    let d = norm(sub(p, q));
                    if d < dist {
                        dist = d;
                        let (_, ts) = face_point(mesh, master[face], x, st);
                        closest = Some((face, st, dot(sub(p, q), cross(ts[0], ts[1])).signum()));
                    }
                    if inside.is_none() {
                        inside = inside_element(mesh, master[face].element, x, p).map(|xi| (face, xi, jacobian_det(mesh, master[face].element, x, xi)));
                    }
                }
                let g = if inside.is_some() { -dist } else { dist };
                if g < exact {
                    exact = g;
                    if trace {
                        // brute force: the closest of 401 × 401 points of each candidate face
                        let mut bf = (f64::INFINITY, 0usize, [0.0; 2], 0.0);
                        for &face in start.keys() {
                            for a in 0..401 {
                                for b in 0..401 {
                                    let st = [-1.0 + a as f64 / 200.0, -1.0 + b as f64 / 200.0];
                                    let (q, ts) = face_point(mesh, master[face], x, st);
                                    let d = norm(sub(p, q));
                                    if d < bf.0 {
                                        bf = (d, face, st, dot(sub(p, q), cross(ts[0], ts[1])).signum());
                                    }
                                }
                            }
                        }
                        eprintln!("[surface gap] brute force: {:.4e} at face {:?} st {:?} sign {}", bf.0, master[bf.1], bf.2, bf.3);
                        eprintln!(
                            "[surface gap] {g:.3e} mm: slave face {sf:?} sample ({i}, {j}) at {p:?}; sampled {d0:.3e}; inside master {:?}; closest {:?}; candidates {:?}",
                            inside.map(|(f, xi, j)| (master[f], xi, j)),
                            closest.map(|(f, st, sg)| (master[f], st, sg)),
                            start.keys().map(|&k| master[k]).collect::<Vec<_>>()
                        );
                    }
                }
            }
        }
    }
    SurfaceGaps { node: node_gap, sampled: signed, exact }
}

#[cfg(test)]
mod tests {
    use super::*;
    use twistopt_solver::mesh::ElementKind;

    /// A unit block of Hex20: its bottom faces seen from its top faces are 1 away, and inside the
    /// top faces' element (behind their outward normal), so the sampled signed surface gap is −1;
    /// the exact one is +1, the samples being on the element's boundary, not inside it; with a
    /// midside node of the bottom lifted by 0.3 (a sample point of the 5 × 5 grid), the gaps
    /// drop to 0.7 in size.
    #[test]
    fn surface_gaps_of_a_block() {
        let m = twistopt_solver::meshgen::boxed(ElementKind::Hex20, [1, 1, 1], [1.0, 1.0, 1.0]);
        let (bottom, top) = (m.face_sets["zmin"].clone(), m.face_sets["zmax"].clone());
        let g = surface_gaps(&m, &bottom, &top, &m.nodes, 5);
        assert!((g.node - 1.0).abs() < 1e-12 && (g.sampled + 1.0).abs() < 1e-12 && (g.exact - 1.0).abs() < 1e-12, "{g:?}");
        let g = surface_gaps(&m, &top, &bottom, &m.nodes, 5);
        assert!((g.node - 1.0).abs() < 1e-12 && (g.sampled + 1.0).abs() < 1e-12 && (g.exact - 1.0).abs() < 1e-12, "{g:?}");
        // the bottom face's midside node at (0.5, 0, 0) lifted by 0.3: the quadratic edge
        // x(s) peaks at the node, so both gaps drop to 0.7 there
        let mut x = m.nodes.clone();
        let mid = (0..x.len()).find(|&i| (x[i][0] - 0.5).abs() < 1e-12 && x[i][1].abs() < 1e-12 && x[i][2].abs() < 1e-12).unwrap();
        x[mid][2] += 0.3;
        let g = surface_gaps(&m, &bottom, &top, &x, 5);
        assert!((g.node - 0.7).abs() < 1e-12, "{g:?}");
        assert!((g.sampled + 0.7).abs() < 1e-12 && (g.exact - 0.7).abs() < 1e-12, "{g:?}");
    }

    /// Two Hex27 stacked in z ([0, 1]², z ∈ [0, 2]); the upper element's top face (the master)
    /// bulges by 0.01 at its centre node. The lower element's bottom face (the slave), moved
    /// flat to z = 2.005, lies inside the upper element's material by 0.005 under the bulge's
    /// peak: the exact gap is −0.005. Moved beside the master element instead (x + 1.5) and just
    /// below its top (z = 1.99), it is behind the master face's plane but outside the wall: the
    /// sampled gap is negative there, the exact one is not.
    #[test]
    fn exact_surface_gap_inside_and_beside_a_wall() {
        let m = twistopt_solver::meshgen::boxed(ElementKind::Hex27, [1, 1, 2], [1.0, 1.0, 2.0]);
        let (bottom, top) = (m.face_sets["zmin"].clone(), m.face_sets["zmax"].clone());
        let mut x = m.nodes.clone();
        let centre = (0..x.len()).find(|&i| (x[i][0] - 0.5).abs() < 1e-12 && (x[i][1] - 0.5).abs() < 1e-12 && (x[i][2] - 2.0).abs() < 1e-12).unwrap();
        x[centre][2] += 0.01;
        let low: Vec<usize> = (0..x.len()).filter(|&i| x[i][2].abs() < 1e-12).collect();
        for &i in &low {
            x[i][2] = 2.005;
        }
        let g = surface_gaps(&m, &bottom, &top, &x, 5);
        assert!((g.exact + 0.005).abs() < 1e-12, "{g:?}");
        for &i in &low {
            x[i][0] += 1.5;
            x[i][2] = 1.99;
        }
        let g = surface_gaps(&m, &bottom, &top, &x, 5);
        // the nearest master point is its edge x = 1, z = 2, 0.5 away in x and 0.01 below
        assert!(g.sampled < 0.0, "{g:?}");
        assert!((g.exact - (0.5f64.powi(2) + 0.01f64.powi(2)).sqrt()).abs() < 1e-9, "{g:?}");
    }
}
