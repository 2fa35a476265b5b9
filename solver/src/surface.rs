//! Closed-cavity volume as a function of the nodal positions, with its exact gradient and Hessian.
//!
//! A cavity is bounded by a set of element faces (oriented outward of the solid, i.e. pointing
//! into the cavity) and by planar caps normal to the z axis that close it at its two ends. By the
//! divergence theorem with the field x/3,
//!
//!   V = −⅓ ∫_wall x·n da  +  ⅙ Σ_{boundary edges e of the wall} ∫_e z (x dy − y dx),
//!
//! where the edges are traversed in the faces' own corner order. The edge term is ⅓·h·A of each
//! horizontal cap at height h; it vanishes on cut edges lying in planes through the z axis and
//! cancels between the two cut faces of a cyclic sector, so the same formula gives the cavity
//! volume of the full model, of a 1/n sector (V_sector = V/n) and of symmetry-plane slices.
//! A cavity pressure p is then the conservative load p ∂V/∂x with the symmetric load stiffness
//! p ∂²V/∂x², and the force it puts on a rigid cap is p·A_cap.
//!
//! **Caps without pressure** ([`Cavity::cap_load`] = false): the pressure acts on the wall faces
//! only. For a cap whose boundary ring is carried by a rigid body (and stays normal to z — the
//! body translates and rotates about z), the cap's share of p ∂V/∂q is exactly p·A_cap on the
//! body's z translation (δV = ∫_wall δx·n + ∫_cap δx·n, and a rigid cap moving in its own plane
//! adds nothing), so removing it leaves the consistent follower load of the wall. The model adds
//! +p·A_cap to the residual of each such body's free z translation, with A_cap the signed area
//! ([`rigid_cap_areas`]) of the ring in the reference configuration (rigid motions keep it);
//! the load stays conservative and the tangent unchanged. Caps on prescribed nodes only move
//! reactions. If the body tilts (lateral rotations free) the removed force keeps the z direction,
//! an error of the order of the tilt angle.

use crate::mesh::{Face, Mesh};
use crate::scalar::{cross, dot, Scalar};
use crate::shape::{gauss_1d, FaceRule};
use std::collections::HashMap;

/// A boundary edge of the wall: 2 (linear) or 3 (quadratic: end, mid, end) node ids, in traversal order.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge(pub Vec<usize>);

/// The cavity: wall faces plus their free boundary edges.
#[derive(Clone, Debug)]
pub struct Cavity {
    pub faces: Vec<Face>,
    pub face_nodes: Vec<Vec<usize>>,
    pub edges: Vec<Edge>,
    pub rule: FaceRule,
    /// whether the pressure also acts on the planar caps closing the cavity (default true);
    /// false = on the wall faces only (see the module docs)
    pub cap_load: bool,
}

impl Cavity {
    /// Every term of the volume: the wall faces, then the boundary edges, each with whether it
    /// is a face (the order the cavity's scatter tables and Hessian caches follow).
    pub fn items(&self) -> impl Iterator<Item = (&[usize], bool)> + '_ {
        self.face_nodes.iter().map(|v| (v.as_slice(), true)).chain(self.edges.iter().map(|e| (e.0.as_slice(), false)))
    }

    pub fn new(mesh: &Mesh, faces: &[Face]) -> Self {
        let face_nodes: Vec<Vec<usize>> = faces.iter().map(|f| mesh.face_nodes(*f)).collect();
        let nf = face_nodes.first().map(|v| v.len()).unwrap_or(4);
        // face edges: corner i -> corner i+1, midside node 4+i for quadratic faces
        let mut count: HashMap<(usize, usize), usize> = HashMap::new();
        let mut all = Vec::new();
        for fnodes in &face_nodes {
            for i in 0..4 {
                let a = fnodes[i];
                let b = fnodes[(i + 1) % 4];
                let e = if nf >= 8 { vec![a, fnodes[4 + i], b] } else { vec![a, b] };
                *count.entry((a.min(b), a.max(b))).or_insert(0) += 1;
                all.push(e);
            }
        }
        let edges = all
            .into_iter()
            .filter(|e| {
                let (a, b) = (e[0], *e.last().unwrap());
                count[&(a.min(b), a.max(b))] == 1
            })
            .map(Edge)
            .collect();
        Cavity { faces: faces.to_vec(), face_nodes, edges, rule: FaceRule::new(nf, 3), cap_load: true }
    }
}

/// Volume contribution of one wall face (−⅓ ∫ x·(a_s × a_t)) and its gradient w.r.t. the face
/// nodes' coordinates (3·nf), generic over the scalar.
pub fn face_volume_grad<D: Scalar>(rule: &FaceRule, x: &[[D; 3]], grad: &mut [D]) -> D {
    let nf = x.len();
    grad.iter_mut().for_each(|g| *g = D::zero());
    let mut v = D::zero();
    for (g, w) in rule.weights.iter().enumerate() {
        let (n, dn) = (&rule.n[g], &rule.dn[g]);
        let mut p = [D::zero(); 3];
        let mut a_s = [D::zero(); 3];
        let mut a_t = [D::zero(); 3];
        for a in 0..nf {
            for i in 0..3 {
                p[i] += x[a][i] * n[a];
                a_s[i] += x[a][i] * dn[a][0];
                a_t[i] += x[a][i] * dn[a][1];
            }
        }
        let st = cross(a_s, a_t);
        let tx = cross(a_t, p);
        let xs = cross(p, a_s);
        let c = -w / 3.0;
        v += dot(p, st) * c;
        for a in 0..nf {
            for i in 0..3 {
                grad[3 * a + i] += (st[i] * n[a] + tx[i] * dn[a][0] + xs[i] * dn[a][1]) * c;
            }
        }
    }
    v
}

#[inline]
fn skew(v: [f64; 3]) -> [[f64; 3]; 3] {
    [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]
}

/// Hessian (3nf × 3nf, row-major) of one face's volume contribution.
pub fn face_volume_hessian(rule: &FaceRule, x: &[[f64; 3]], h: &mut [f64]) {
    let nf = x.len();
    let nd = 3 * nf;
    let mut v = vec![[0.0; 3]; nf * nf];
    face_volume_hessian_skew(rule, x, &mut v);
    for d in 0..nf {
        for e in 0..nf {
            let b = skew(v[d * nf + e]);
            for i in 0..3 {
                h[(3 * d + i) * nd + 3 * e..(3 * d + i) * nd + 3 * e + 3].copy_from_slice(&b[i]);
            }
        }
    }
}

/// The face volume Hessian's 3 × 3 blocks, each skew: block (d, e) = skew(v[d nf + e]), i.e.
/// ∂²V/∂x_d∂x_e · w = v_de × w (v_ed = −v_de, v_dd = 0).
pub fn face_volume_hessian_skew(rule: &FaceRule, x: &[[f64; 3]], v: &mut [[f64; 3]]) {
    let nf = x.len();
    v.iter_mut().for_each(|b| *b = [0.0; 3]);
    for (g, w) in rule.weights.iter().enumerate() {
        let (n, dn) = (&rule.n[g], &rule.dn[g]);
        let mut p = [0.0; 3];
        let mut a_s = [0.0; 3];
        let mut a_t = [0.0; 3];
        for a in 0..nf {
            for i in 0..3 {
                p[i] += x[a][i] * n[a];
                a_s[i] += x[a][i] * dn[a][0];
                a_t[i] += x[a][i] * dn[a][1];
            }
        }
        let c = -w / 3.0;
        // each 3×3 block is skew: c (k_st skew(a_t) + k_ss skew(a_s) + k_sx skew(x)) = skew(v)
        for d in 0..nf {
            for e in d + 1..nf {
                let k_st = -n[d] * dn[e][0] + dn[d][0] * n[e];
                let k_ss = n[d] * dn[e][1] - dn[d][1] * n[e];
                let k_sx = -dn[d][0] * dn[e][1] + dn[d][1] * dn[e][0];
                let b = &mut v[d * nf + e];
                for i in 0..3 {
                    b[i] += c * (k_st * a_t[i] + k_ss * a_s[i] + k_sx * p[i]);
                }
            }
        }
    }
    for d in 0..nf {
        for e in d + 1..nf {
            let b = v[d * nf + e];
            v[e * nf + d] = [-b[0], -b[1], -b[2]];
        }
    }
}

fn edge_shape(ne: usize, s: f64) -> (Vec<f64>, Vec<f64>) {
    if ne == 2 {
        (vec![0.5 * (1.0 - s), 0.5 * (1.0 + s)], vec![-0.5, 0.5])
    } else {
        (vec![0.5 * s * (s - 1.0), 1.0 - s * s, 0.5 * s * (s + 1.0)], vec![s - 0.5, -2.0 * s, s + 0.5])
    }
}

/// Cap term of one boundary edge: ⅙ ∫ z (x y' − y x') ds, and its gradient (3·ne), generic.
pub fn edge_volume_grad<D: Scalar>(x: &[[D; 3]], grad: &mut [D]) -> D {
    let ne = x.len();
    grad.iter_mut().for_each(|g| *g = D::zero());
    let (gp, gw) = gauss_1d(3);
    let mut v = D::zero();
    for (s, w) in gp.iter().zip(&gw) {
        let (n, dn) = edge_shape(ne, *s);
        let mut p = [D::zero(); 3];
        let mut t = [D::zero(); 3];
        for a in 0..ne {
            for i in 0..3 {
                p[i] += x[a][i] * n[a];
                t[i] += x[a][i] * dn[a];
            }
        }
        let c = *w / 6.0;
        let cr = p[0] * t[1] - p[1] * t[0];
        v += p[2] * cr * c;
        for a in 0..ne {
            grad[3 * a] += p[2] * (t[1] * n[a] - p[1] * dn[a]) * c;
            grad[3 * a + 1] += p[2] * (p[0] * dn[a] - t[0] * n[a]) * c;
            grad[3 * a + 2] += cr * n[a] * c;
        }
    }
    v
}

/// Hessian of the edge cap term (3ne × 3ne).
pub fn edge_volume_hessian(x: &[[f64; 3]], h: &mut [f64]) {
    let ne = x.len();
    let nd = 3 * ne;
    h.iter_mut().for_each(|v| *v = 0.0);
    let (gp, gw) = gauss_1d(3);
    for (s, w) in gp.iter().zip(&gw) {
        let (n, dn) = edge_shape(ne, *s);
        let mut p = [0.0; 3];
        let mut t = [0.0; 3];
        for a in 0..ne {
            for i in 0..3 {
                p[i] += x[a][i] * n[a];
                t[i] += x[a][i] * dn[a];
            }
        }
        let c = w / 6.0;
        for d in 0..ne {
            for e in 0..ne {
                let xy = p[2] * (n[d] * dn[e] - n[e] * dn[d]);
                let xz = n[e] * (n[d] * t[1] - p[1] * dn[d]);
                let yz = n[e] * (p[0] * dn[d] - n[d] * t[0]);
                let zx = n[d] * (n[e] * t[1] - p[1] * dn[e]);
                let zy = n[d] * (p[0] * dn[e] - n[e] * t[0]);
                let r = |i: usize, j: usize| (3 * d + i) * nd + 3 * e + j;
                h[r(0, 1)] += c * xy;
                h[r(1, 0)] -= c * xy;
                h[r(0, 2)] += c * xz;
                h[r(1, 2)] += c * yz;
                h[r(2, 0)] += c * zx;
                h[r(2, 1)] += c * zy;
            }
        }
    }
}

/// Signed area enclosed by an edge chain projected on the xy-plane: ½ ∫ (x dy − y dx).
pub fn edge_area(x: &[[f64; 3]]) -> f64 {
    edge_area_generic(x)
}

/// [`edge_area`] for any scalar (exact for linear and quadratic edges: 3-point Gauss).
pub fn edge_area_generic<D: Scalar>(x: &[[D; 3]]) -> D {
    let (gp, gw) = gauss_1d(3);
    let ne = x.len();
    let mut a = D::zero();
    for (s, w) in gp.iter().zip(&gw) {
        let (n, dn) = edge_shape(ne, *s);
        let (mut p, mut t) = ([D::zero(); 2], [D::zero(); 2]);
        for k in 0..ne {
            for i in 0..2 {
                p[i] += x[k][i] * n[k];
                t[i] += x[k][i] * dn[k];
            }
        }
        a += (p[0] * t[1] - p[1] * t[0]) * (0.5 * w);
    }
    a
}

/// Signed areas of the cavity caps carried by rigid bodies, one per body of `dofs`: ½∮(x dy − y dx)
/// over the cavity's boundary edges whose nodes all have their z component tied to that body
/// (reference coordinates `x0`; positive for a cap whose outward normal — out of the cavity — is
/// +z, i.e. the same sign convention as the cap term of the volume). Zero for bodies that carry no
/// cap. Edges in planes through the z axis (cut faces of a sector) contribute nothing, so a sector
/// model gets its sector of the cap.
pub fn rigid_cap_areas<D: Scalar>(cav: &Cavity, dofs: &crate::dofmap::DofMap, x0: &[[D; 3]]) -> Vec<D> {
    use crate::dofmap::Comp;
    let mut areas = vec![D::zero(); dofs.bodies.len()];
    for e in &cav.edges {
        let body = |n: usize| match dofs.comps[3 * n + 2] {
            Comp::Rigid(b) => Some(b as usize),
            _ => None,
        };
        let Some(b) = body(e.0[0]) else { continue };
        if e.0.iter().all(|&n| body(n) == Some(b)) {
            let x: Vec<[D; 3]> = e.0.iter().map(|&n| x0[n]).collect();
            areas[b] += edge_area_generic(&x);
        }
    }
    areas
}

/// One term of the cavity volume ([`Cavity::items`]): a wall face's or a boundary edge's volume,
/// with its gradient written into `grad` (3 per node of the term).
pub fn item_volume_grad<D: Scalar>(rule: &FaceRule, x: &[[D; 3]], is_face: bool, grad: &mut [D]) -> D {
    if is_face {
        face_volume_grad(rule, x, grad)
    } else {
        edge_volume_grad(x, grad)
    }
}

/// One term's Hessian (see [`item_volume_grad`]), written into `h` (row-major, 3 per node).
pub fn item_volume_hessian(rule: &FaceRule, x: &[[f64; 3]], is_face: bool, h: &mut [f64]) {
    if is_face {
        face_volume_hessian(rule, x, h)
    } else {
        edge_volume_hessian(x, h)
    }
}

/// The cavity volume at the node positions `x(n)`, its gradient added into `grad` (3 per mesh
/// node; empty = not wanted), and every term shown to `each` (its index in [`Cavity::items`],
/// its nodes and positions, whether it is a face) for a caller that needs the terms' Hessians.
/// The one volume loop of the full model, its adjoint (dual numbers) and the reduced model's
/// error indicator.
pub fn volume_and_gradient<D: Scalar>(cav: &Cavity, x: impl Fn(usize) -> [D; 3], grad: &mut [D], mut each: impl FnMut(usize, &[usize], &[[D; 3]], bool)) -> D {
    let mut v = D::zero();
    let mut xs = Vec::with_capacity(9);
    let mut g = Vec::with_capacity(27);
    for (idx, (nodes, is_face)) in cav.items().enumerate() {
        xs.clear();
        xs.extend(nodes.iter().map(|&n| x(n)));
        g.clear();
        g.resize(3 * xs.len(), D::zero());
        v += item_volume_grad(&cav.rule, &xs, is_face, &mut g);
        if !grad.is_empty() {
            for (a, &n) in nodes.iter().enumerate() {
                for c in 0..3 {
                    grad[3 * n + c] += g[3 * a + c];
                }
            }
        }
        each(idx, nodes, &xs, is_face);
    }
    v
}

/// Cavity volume of the given configuration (positions of all nodes).
pub fn cavity_volume(cav: &Cavity, xcur: &[[f64; 3]]) -> f64 {
    volume_and_gradient(cav, |n| xcur[n], &mut [], |_, _, _, _| {})
}

/// Consistent nodal forces (3 per mesh node) of a uniform dead traction `t` (force per
/// undeformed area) on a set of faces: f_a = t ∫ N_a dA over the reference faces. Gauss rule of
/// 3 points per direction (exact for the areas of quadratic faces with straight or mildly curved
/// sides; exact for flat faces). Non-finite tractions give zero forces and `None`.
pub fn dead_traction(mesh: &Mesh, faces: &[Face], t: [f64; 3]) -> Option<Vec<f64>> {
    if !t.iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut f = vec![0.0; 3 * mesh.n_nodes()];
    for face in faces {
        let nodes = mesh.face_nodes(*face);
        let rule = FaceRule::new(nodes.len(), 3);
        for (g, w) in rule.weights.iter().enumerate() {
            let (n, dn) = (&rule.n[g], &rule.dn[g]);
            let mut a_s = [0.0; 3];
            let mut a_t = [0.0; 3];
            for (a, &node) in nodes.iter().enumerate() {
                for i in 0..3 {
                    a_s[i] += mesh.nodes[node][i] * dn[a][0];
                    a_t[i] += mesh.nodes[node][i] * dn[a][1];
                }
            }
            let nv = cross(a_s, a_t);
            let da = dot(nv, nv).sqrt() * w;
            for (a, &node) in nodes.iter().enumerate() {
                for i in 0..3 {
                    f[3 * node + i] += t[i] * n[a] * da;
                }
            }
        }
    }
    Some(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_check(f: &dyn Fn(&[[f64; 3]], &mut [f64]) -> f64, hess: &dyn Fn(&[[f64; 3]], &mut [f64]), x: &[[f64; 3]]) {
        let nd = 3 * x.len();
        let mut g = vec![0.0; nd];
        f(x, &mut g);
        let mut h = vec![0.0; nd * nd];
        hess(x, &mut h);
        let eps = 1e-6;
        for col in 0..nd {
            let mut xp = x.to_vec();
            let mut xm = x.to_vec();
            xp[col / 3][col % 3] += eps;
            xm[col / 3][col % 3] -= eps;
            let mut gp = vec![0.0; nd];
            let mut gm = vec![0.0; nd];
            let vp = f(&xp, &mut gp);
            let vm = f(&xm, &mut gm);
            assert!(((vp - vm) / (2.0 * eps) - g[col]).abs() < 1e-7 * (1.0 + g[col].abs()));
            for row in 0..nd {
                let fd = (gp[row] - gm[row]) / (2.0 * eps);
                assert!((fd - h[row * nd + col]).abs() < 1e-6, "H[{row},{col}] {} vs {}", fd, h[row * nd + col]);
            }
        }
    }

    #[test]
    fn face_and_edge_derivatives_match_fd() {
        let rule = FaceRule::new(9, 3);
        let x: Vec<[f64; 3]> = crate::mesh::FACE_NATURAL
            .iter()
            .map(|c| {
                let (s, t) = (c[0] as f64, c[1] as f64);
                [1.0 + s + 0.1 * t * t, 2.0 + 0.3 * s * t, 0.5 * t + 0.2 * s * s]
            })
            .collect();
        fd_check(&|x, g| face_volume_grad(&rule, x, g), &|x, h| face_volume_hessian(&rule, x, h), &x);
        let e = vec![[1.0, 0.2, 3.0], [0.7, 0.9, 3.1], [0.1, 1.2, 2.9]];
        fd_check(&|x, g| edge_volume_grad(x, g), &|x, h| edge_volume_hessian(x, h), &e);
    }
}
