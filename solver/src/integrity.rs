//! Checks of a deformed mesh's integrity that its quadrature points do not see: a surface
//! passing into the material (a wall through another wall, or through itself where it folds),
//! and an element whose isoparametric map folds between its quadrature points (det J ≤ 0 there
//! while every quadrature point's is positive). Both are measured on the element's own
//! (quadratic) geometry, not on a proxy.

use crate::mesh::{Face, Mesh};
use crate::scalar::dot;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The mesh with copies of itself rotated about z by each of `copies` (radians; 0 = the mesh
/// itself), nodes and elements of copy k numbered after those of copy k − 1, and the positions
/// `x` rotated alike: a cyclic sector's neighbours, for checks across its cut. The copies share
/// no nodes (the cut's nodes appear once per copy); each face set holds its faces in every copy
/// (copy 0's first); node sets are dropped.
pub fn with_copies(mesh: &Mesh, x: &[[f64; 3]], copies: &[f64]) -> (Mesh, Vec<[f64; 3]>) {
    let n = mesh.nodes.len();
    let rot = |a: f64, p: [f64; 3]| {
        let (s, c) = a.sin_cos();
        [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]
    };
    let mut m = mesh.clone();
    let ne = mesh.n_elements();
    m.node_sets.clear();
    for (name, fs) in m.face_sets.iter_mut() {
        *fs = (0..copies.len()).flat_map(|k| mesh.face_sets[name].iter().map(move |f| Face { element: f.element + k * ne, side: f.side })).collect();
    }
    m.nodes = copies.iter().flat_map(|&a| mesh.nodes.iter().map(move |&p| rot(a, p))).collect();
    let npe = mesh.kind.nodes_per_element();
    m.connectivity = (0..copies.len()).flat_map(|k| mesh.connectivity.iter().map(move |&v| v + k * n)).collect();
    debug_assert_eq!(m.connectivity.len(), copies.len() * mesh.n_elements() * npe);
    let xs = copies.iter().flat_map(|&a| x.iter().map(move |&p| rot(a, p))).collect();
    (m, xs)
}

/// The deepest interpenetration of a surface into the material: every face of `faces` sampled on
/// an m × m grid, each sample tested against every element of the mesh that does not hold it
/// (strictly inside, by inverting the element's isoparametric map). Needs no contact pairs, so
/// it also sees a wall folded onto itself. Only the elements `e` with `tested(e)` are tested (an
/// element whose map folds between its quadrature points, [`least_jacobian`] ≤ 0, covers some
/// points twice and its "inside" is not the material's). The depth of a sample inside an
/// element is its distance to that element's nearest face of `walls` (the surface it passed
/// through, e.g. the cavity's faces of every sector copy), or, for an element without one (a
/// second layer through the wall), to the nearest such face of the elements sharing a node with
/// it.
/// Returns (depth, count): the largest such depth (0 if no sample is inside an element) and how
/// many samples are inside one.
pub fn penetration(mesh: &Mesh, faces: &[Face], walls: &[Face], x: &[[f64; 3]], m: usize, tested: &dyn Fn(usize) -> bool) -> (f64, usize) {
    let m = m.max(2);
    let st_of = |i: usize, j: usize| [-1.0 + 2.0 * i as f64 / (m - 1) as f64, -1.0 + 2.0 * j as f64 / (m - 1) as f64];
    // the elements' bounding boxes (of their nodes; a quadratic element bulges beyond them by its
    // edges' sag: pad by a tenth of the box's size)
    let boxes: Vec<([f64; 3], [f64; 3])> = (0..mesh.n_elements())
        .map(|e| {
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for &n in mesh.element(e) {
                for c in 0..3 {
                    lo[c] = lo[c].min(x[n][c]);
                    hi[c] = hi[c].max(x[n][c]);
                }
            }
            let pad = 0.1 * (0..3).map(|c| hi[c] - lo[c]).fold(0.0, f64::max);
            (lo.map(|v| v - pad), hi.map(|v| v + pad))
        })
        .collect();
    let in_box = |e: usize, p: [f64; 3]| -> bool {
        let (lo, hi) = &boxes[e];
        (0..3).all(|c| p[c] >= lo[c] && p[c] <= hi[c])
    };
    // the distance from p to a face: projected from the nearest point of a 5 × 5 grid on it
    let to_face = |g: Face, p: [f64; 3]| {
        let mut start = ([0.0, 0.0], f64::INFINITY);
        for a in 0..25 {
            let st = [-1.0 + 0.5 * (a % 5) as f64, -1.0 + 0.5 * (a / 5) as f64];
            let d = norm(sub(p, face_point(mesh, g, x, st).0));
            if d < start.1 {
                start = (st, d);
            }
        }
        norm(sub(p, project_on_face(mesh, g, x, p, start.0).1))
    };
    let (mut depth, mut count) = (0.0f64, 0usize);
    let trace = std::env::var_os("TWISTOPT_GAP_TRACE").is_some();
    for &f in faces {
        for i in 0..m {
            for j in 0..m {
                let p = face_point(mesh, f, x, st_of(i, j)).0;
                for e in 0..boxes.len() {
                    if e == f.element || !tested(e) || !in_box(e, p) {
                        continue;
                    }
                    let Some(xi) = inside_element(mesh, e, x, p) else { continue };
                    count += 1;
                    let own: Vec<Face> = walls.iter().filter(|g| g.element == e).copied().collect();
                    let near: Vec<Face> = if own.is_empty() {
                        let en = mesh.element(e);
                        walls.iter().filter(|g| mesh.element(g.element).iter().any(|n| en.contains(n))).copied().collect()
                    } else {
                        own
                    };
                    let d = near.iter().map(|&g| to_face(g, p)).fold(f64::NAN, f64::min);
                    if trace {
                        eprintln!(
                            "[penetration] {d:.3e} mm: face {f:?} sample ({i}, {j}) inside element {e} at ξ {xi:?}, det J {:.3e} (element's least on a 9³ grid {:.3e})",
                            jacobian_det(mesh, e, x, xi),
                            least_jacobian(mesh, e, x, 9)
                        );
                    }
                    depth = depth.max(if d.is_finite() { d } else { 0.0 });
                }
            }
        }
    }
    (depth, count)
}

pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// A face's point at (s, t) and its two tangents.
pub fn face_point(mesh: &Mesh, f: Face, x: &[[f64; 3]], st: [f64; 2]) -> ([f64; 3], [[f64; 3]; 2]) {
    let nodes = mesh.face_nodes(f);
    let (nn, dn) = crate::shape::face_shape(nodes.len(), st);
    let (mut p, mut ts) = ([0.0; 3], [[0.0; 3]; 2]);
    for (a, &n) in nodes.iter().enumerate() {
        for c in 0..3 {
            p[c] += nn[a] * x[n][c];
            ts[0][c] += dn[a][0] * x[n][c];
            ts[1][c] += dn[a][1] * x[n][c];
        }
    }
    (p, ts)
}

/// The closest point of a face to `p`: (s, t) in [−1, 1]² and the point, by projected
/// Gauss–Newton from `st0` (the face's curvature over a contact gap is small: a few iterations).
pub fn project_on_face(mesh: &Mesh, f: Face, x: &[[f64; 3]], p: [f64; 3], st0: [f64; 2]) -> ([f64; 2], [f64; 3]) {
    let clamp = |v: f64| v.clamp(-1.0, 1.0);
    let mut st = st0.map(clamp);
    for _ in 0..50 {
        let (q, ts) = face_point(mesh, f, x, st);
        let r = sub(p, q);
        let (a, b, c) = (dot(ts[0], ts[0]), dot(ts[0], ts[1]), dot(ts[1], ts[1]));
        let (g0, g1) = (dot(ts[0], r), dot(ts[1], r));
        let det = a * c - b * b;
        if !(det.abs() > 0.0) {
            break;
        }
        let mut d = [(c * g0 - b * g1) / det, (a * g1 - b * g0) / det];
        // on a bound with the step pointing out: slide along the other direction only
        for k in 0..2 {
            if (st[k] >= 1.0 && d[k] > 0.0) || (st[k] <= -1.0 && d[k] < 0.0) {
                d[k] = 0.0;
                let o = 1 - k;
                let (aa, gg) = if o == 0 { (a, g0) } else { (c, g1) };
                d[o] = gg / aa;
            }
        }
        let next = [clamp(st[0] + d[0]), clamp(st[1] + d[1])];
        let moved = (next[0] - st[0]).abs().max((next[1] - st[1]).abs());
        st = next;
        if moved < 1e-14 {
            break;
        }
    }
    (st, face_point(mesh, f, x, st).0)
}

/// The least det ∂x/∂ξ of element `e` over an n × n × n grid of ξ ∈ [−1, 1]³ (n ≥ 2), relative
/// to its value at the centre: ≤ 0 where the element's map folds between its quadrature points.
pub fn least_jacobian(mesh: &Mesh, e: usize, x: &[[f64; 3]], n: usize) -> f64 {
    let n = n.max(2);
    let c = jacobian_det(mesh, e, x, [0.0; 3]);
    let mut least = f64::INFINITY;
    for a in 0..n * n * n {
        let xi = [a % n, (a / n) % n, a / (n * n)].map(|k| -1.0 + 2.0 * k as f64 / (n - 1) as f64);
        least = least.min(jacobian_det(mesh, e, x, xi) / c);
    }
    least
}

/// [`least_jacobian`] of every element of the mesh (the shape functions' derivatives on the grid
/// computed once).
pub fn least_jacobians(mesh: &Mesh, x: &[[f64; 3]], n: usize) -> Vec<f64> {
    let n = n.max(2);
    let grid: Vec<Vec<[f64; 3]>> = (0..n * n * n)
        .map(|a| crate::shape::hex_shape(mesh.kind, [a % n, (a / n) % n, a / (n * n)].map(|k| -1.0 + 2.0 * k as f64 / (n - 1) as f64)).1)
        .chain(std::iter::once(crate::shape::hex_shape(mesh.kind, [0.0; 3]).1))
        .collect();
    (0..mesh.n_elements())
        .map(|e| {
            let nodes = mesh.element(e);
            let det = |dn: &[[f64; 3]]| {
                let mut j = [[0.0; 3]; 3];
                for (a, &nd) in nodes.iter().enumerate() {
                    for c in 0..3 {
                        for d in 0..3 {
                            j[c][d] += x[nd][c] * dn[a][d];
                        }
                    }
                }
                j[0][0] * (j[1][1] * j[2][2] - j[1][2] * j[2][1]) - j[0][1] * (j[1][0] * j[2][2] - j[1][2] * j[2][0]) + j[0][2] * (j[1][0] * j[2][1] - j[1][1] * j[2][0])
            };
            let c = det(&grid[n * n * n]);
            grid[..n * n * n].iter().map(|dn| det(dn) / c).fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// det ∂x/∂ξ of element `e` at ξ.
pub fn jacobian_det(mesh: &Mesh, e: usize, x: &[[f64; 3]], xi: [f64; 3]) -> f64 {
    let (_, dn) = crate::shape::hex_shape(mesh.kind, xi);
    let mut j = nalgebra::Matrix3::<f64>::zeros();
    for (a, &n) in mesh.element(e).iter().enumerate() {
        for c in 0..3 {
            for d in 0..3 {
                j[(c, d)] += x[n][c] * dn[a][d];
            }
        }
    }
    j.determinant()
}

/// The natural coordinates ξ of `p` in element `e` (nodes at `x`) if `p` lies strictly inside
/// it (max |ξᵢ| < 1 − 1e-9), by Newton on the isoparametric map from the centre.
pub fn inside_element(mesh: &Mesh, e: usize, x: &[[f64; 3]], p: [f64; 3]) -> Option<[f64; 3]> {
    let nodes = mesh.element(e);
    let mut xi = [0.0; 3];
    for it in 0..50 {
        let (nn, dn) = crate::shape::hex_shape(mesh.kind, xi);
        let mut q = [0.0; 3];
        let mut j = nalgebra::Matrix3::<f64>::zeros();
        for (a, &n) in nodes.iter().enumerate() {
            for c in 0..3 {
                q[c] += nn[a] * x[n][c];
                for d in 0..3 {
                    j[(c, d)] += x[n][c] * dn[a][d];
                }
            }
        }
        let r = nalgebra::Vector3::from(sub(p, q));
        let d = j.lu().solve(&r)?;
        for c in 0..3 {
            // a point far outside may send Newton off: keep ξ bounded
            xi[c] = (xi[c] + d[c]).clamp(-3.0, 3.0);
        }
        if d.amax() < 1e-13 {
            break;
        }
        // well outside after a few iterations: not inside (Newton from the centre converges
        // in 2–4 iterations for a point inside an element this module meets)
        if it >= 6 && xi.iter().any(|v| v.abs() > 1.5) {
            return None;
        }
    }
    let (nn, _) = crate::shape::hex_shape(mesh.kind, xi);
    let mut q = [0.0; 3];
    for (a, &n) in nodes.iter().enumerate() {
        for c in 0..3 {
            q[c] += nn[a] * x[n][c];
        }
    }
    let scale = norm(sub(x[nodes[0]], x[nodes[6]])).max(1e-300);
    (norm(sub(p, q)) <= 1e-10 * scale && xi.iter().all(|v| v.abs() < 1.0 - 1e-9)).then_some(xi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::ElementKind;

    /// Two Hex27 stacked in z (z ∈ [0, 2]); the upper element's top face moved down to
    /// z = 0.005, into the lower element: the 3 × 3 interior samples of its 5 × 5 grid lie inside
    /// the lower element's material, 0.005 above its bottom face (the edge samples lie on that
    /// element's boundary, not inside it). At rest nothing is inside.
    #[test]
    fn penetration_of_a_face_into_another_element() {
        let m = crate::meshgen::boxed(ElementKind::Hex27, [1, 1, 2], [1.0, 1.0, 2.0]);
        let faces: Vec<Face> = m.face_sets["zmin"].iter().chain(&m.face_sets["zmax"]).copied().collect();
        assert_eq!(penetration(&m, &faces, &faces, &m.nodes, 5, &|_| true), (0.0, 0));
        let mut x = m.nodes.clone();
        for p in x.iter_mut().filter(|p| (p[2] - 2.0).abs() < 1e-12) {
            p[2] = 0.005;
        }
        let (depth, count) = penetration(&m, &faces, &faces, &x, 5, &|_| true);
        // the upper element (inverted here) is not tested: the same
        assert_eq!(penetration(&m, &faces, &faces, &x, 5, &|e| e == 0), (depth, count));
        assert_eq!(penetration(&m, &faces, &faces, &x, 5, &|e| e == 1), (0.0, 0));
        assert_eq!(count, 9);
        assert!((depth - 0.005).abs() < 1e-12, "{depth}");
    }

    /// The batch and the one-element least Jacobian agree; a block's is 1 at rest, and ≤ 0 once a
    /// corner node is pushed through the opposite face.
    #[test]
    fn least_jacobian_of_a_block() {
        let m = crate::meshgen::boxed(ElementKind::Hex27, [1, 1, 1], [1.0, 1.0, 1.0]);
        assert!((least_jacobians(&m, &m.nodes, 9)[0] - 1.0).abs() < 1e-12);
        let mut x = m.nodes.clone();
        let corner = (0..x.len()).find(|&i| x[i].iter().all(|v| v.abs() < 1e-12)).unwrap();
        x[corner] = [0.0, 0.0, 1.2];
        let (one, all) = (least_jacobian(&m, 0, &x, 9), least_jacobians(&m, &x, 9)[0]);
        assert!(one <= 0.0 && (one - all).abs() < 1e-12, "{one} {all}");
    }

    /// A Hex27 block at x ∈ [1, 2] with a copy rotated about z: by π the copy is far away and
    /// nothing is inside another element; by 0.1 rad it overlaps the block, and samples of the
    /// block's faces lie inside the copy's element (element 1 of the combined mesh).
    #[test]
    fn a_rotated_copy_is_tested_too() {
        let mut m = crate::meshgen::boxed(ElementKind::Hex27, [1, 1, 1], [1.0, 1.0, 1.0]);
        for p in m.nodes.iter_mut() {
            p[0] += 1.0;
        }
        let faces = m.face_sets["xmin"].clone();
        let (far, xf) = with_copies(&m, &m.nodes, &[0.0, std::f64::consts::PI]);
        assert_eq!((far.n_elements(), far.face_sets["xmin"].len()), (2, 2));
        assert_eq!(penetration(&far, &faces, &far.face_sets["xmin"], &xf, 5, &|_| true), (0.0, 0));
        let (near, xn) = with_copies(&m, &m.nodes, &[0.0, 0.1]);
        let (depth, count) = penetration(&near, &faces, &near.face_sets["xmin"], &xn, 5, &|e| e == 1);
        assert!(count > 0 && depth > 0.0, "{depth} {count}");
    }
}
