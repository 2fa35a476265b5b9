//! Frictionless contact by a smooth log barrier (the barrier of IPC, Li et al., SIGGRAPH 2020).
//!
//! A *slave* node i carries the energy κ wᵢ b(dᵢ) g(Bᵢ), with
//!
//! * dᵢ the node's distance to its *target surface*, a set of triangles (the contact surface of
//!   another part, the other side of the same cavity, a neighbouring sector's copy of it, or a
//!   fixed obstacle), **blended** over the triangles near the node: dᵢ = Σ w_t d_t / Σ w_t with
//!   d_t the signed distance to triangle t's plane and w_t = Π_edges S(e/ε + ½)·C(d_t), e the
//!   in-plane distance of the node's projection from the edge (positive inside), S the C² smooth
//!   step and ε the blend width ([`Contact::blend`]); C drops triangles farther than 2–3 d̂ in
//!   front of the node or ¼–½ d̂ behind it (a node farther behind came round the triangle's edge,
//!   not through it: the steps' collision check excludes that);
//!   Inside a triangle, away from its edges, dᵢ is that triangle's plane distance; across an
//!   edge shared by two coplanar triangles the weights sum to 1, so on a flat surface dᵢ is
//!   exactly the distance; across a crease it blends the two planes' distances smoothly. (The
//!   distance to the closest triangle instead has a gradient jump over every concave crease,
//!   on which Newton stalls: measured in tests/contact_block.rs.);
//! * b(d) = −(d − d̂)² ln(d/d̂) for d < d̂ and 0 beyond (`ipc-toolkit` src/ipc/barrier/barrier.cpp),
//!   C² at d̂ and unbounded as d → 0;
//! * g(B) = 1 for Bᵢ = Σ w_t ≥ 1 (inside a surface), 0 for Bᵢ ≤ ½ and 3x² − 2x³ between
//!   (x = 2Bᵢ − 1), which fades the contact out beyond a surface's free edge. A node with
//!   Bᵢ ≤ ½ is not over the surface and has no term: beside a triangle's edge it may lie behind
//!   the triangle's plane without having passed through the triangle (measured on the collapsing
//!   actuator cavity, where such nodes were refused as penetrations and stalled the path);
//! * wᵢ the node's consistent reference area ∫ Nᵢ dA over the slave faces ([`nodal_areas`]), so
//!   that equal gaps carry the consistent nodal loads of a uniform contact pressure κ·|b'(d)| and
//!   the contact pressure does not depend on the mesh.
//!
//! The energy's gradient is the contact force and its Hessian is the exact one (not projected:
//! the Newton solves and the adjoint see the same tangent), from second-order dual numbers of
//! each triangle's (d_t, w_t) in the node and the triangle's vertices, combined by the quotient
//! rule.
//!
//! A state where a node over its target surface (Bᵢ > ½) has reached or crossed it (dᵢ ≤ 0) is
//! not admissible:
//! the assembly reports [`crate::element::ElementError::Penetration`], which the Newton line
//! search treats like an inverted element (the step is cut). No step passes a node through a
//! surface: the path follower's and the relaxation's line searches start from the step fraction
//! that [`Contact::max_step`] admits (continuous collision detection by conservative
//! advancement), whatever the distance.
//!
//! Hex27 (and Hex8) faces enter as triangles on their node grid ([`face_triangles`]), oriented
//! with the face's outward normal; a cyclic sector's neighbours as rotated copies
//! ([`Vertex::Rotated`]).

use crate::mesh::{Face, Mesh};
use crate::scalar::{cross, dot, Scalar};
use crate::shape::FaceRule;
use nalgebra::SVector;
use num_dual::{hessian, Dual2SVec64};

/// The barrier: its reach d̂ (a length) and stiffness κ (a pressure per length: the contact
/// pressure at gap d is κ·|b'(d)|).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Barrier {
    pub dhat: f64,
    pub kappa: f64,
}

impl Barrier {
    /// b(d), b'(d), b''(d) (zero for d ≥ d̂; only d > 0 is meaningful).
    pub fn eval(&self, d: f64) -> (f64, f64, f64) {
        let dh = self.dhat;
        if d >= dh {
            return (0.0, 0.0, 0.0);
        }
        let x = d - dh;
        let l = (d / dh).ln();
        (-x * x * l, -2.0 * x * l - x * x / d, -2.0 * l - 4.0 * x / d + x * x / (d * d))
    }

    /// The contact pressure κ·|b'(d)| at gap d.
    pub fn pressure(&self, d: f64) -> f64 {
        -self.kappa * self.eval(d).1
    }

    /// The gap at which the contact pressure is `p` (> 0), by bisection on the monotone κ|b'|.
    pub fn gap_at_pressure(&self, p: f64) -> f64 {
        // κ|b'| falls monotonically from ∞ at 0 to 0 at d̂: bisection in log d
        let (mut lo, mut hi) = (self.dhat * 1e-15, self.dhat);
        for _ in 0..200 {
            let mid = (lo * hi).sqrt();
            if self.pressure(mid) > p {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (lo * hi).sqrt()
    }
}

/// A triangle vertex: a mesh node (moves with the model), a fixed point (a rigid obstacle), or
/// a node's copy rotated about the z axis by `angle` (rad): the neighbouring sector of a
/// cyclically symmetric model, whose displacement is the rotated displacement of the modelled one.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Vertex {
    Node(usize),
    Fixed([f64; 3]),
    Rotated { node: usize, angle: f64 },
}

impl Vertex {
    /// The vertex's position with the mesh nodes at `x`.
    pub fn position(&self, x: &impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
        match *self {
            Vertex::Node(n) => x(n),
            Vertex::Fixed(p) => p,
            Vertex::Rotated { node, angle } => apply(&rot_z(angle), x(node)),
        }
    }

    /// The mesh node the vertex follows, if any.
    pub fn node(&self) -> Option<usize> {
        match *self {
            Vertex::Node(n) | Vertex::Rotated { node: n, .. } => Some(n),
            Vertex::Fixed(_) => None,
        }
    }
}

/// The rotation about z by `angle`.
pub fn rot_z(angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn apply(m: &[[f64; 3]; 3], p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2])
}

/// A target triangle; its normal (b − a) × (c − a) points to the side slave nodes come from.
pub type Triangle = [Vertex; 3];

/// A slave node: its weight (consistent reference area) and its candidate target triangles
/// (indices into [`Contact::triangles`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Slave {
    pub node: usize,
    pub weight: f64,
    pub targets: Vec<usize>,
}

/// A frictionless barrier contact: slave nodes against target triangles.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Contact {
    pub barrier: Barrier,
    /// the width ε of the band around each triangle edge over which neighbouring triangles'
    /// distances are blended (a length; [`Contact::default_blend`])
    pub blend: f64,
    pub triangles: Vec<Triangle>,
    pub slaves: Vec<Slave>,
    /// The slave faces whose consistent nodal areas ([`nodal_areas`]) are the slaves' weights,
    /// so that shape sensitivities differentiate the weights too (empty: weights given, not
    /// shape-dependent).
    pub faces: Vec<Face>,
    /// A rigid axle (a cylinder about the z axis) that its slave nodes stay outside of.
    #[serde(default)]
    pub axle: Option<Axle>,
    /// Rigid planes (e.g. a tube's end plates) that their slave nodes stay in front of.
    #[serde(default)]
    pub planes: Vec<Plane>,
}

/// A rigid, frictionless plane: each slave node (node, weight) stays on the side
/// n·(x − x_ref) > 0, with the barrier term κ w b(n·(x − x_ref)). The plane passes through
/// `point`, a fixed point or a mesh node that it follows in translation (e.g. a node of a rigid
/// cap that only translates along and turns about its normal); `normal` is a unit vector.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Plane {
    pub normal: [f64; 3],
    pub point: Vertex,
    pub slaves: Vec<(usize, f64)>,
}

impl Plane {
    fn reference(&self, x: &impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
        self.point.position(x)
    }

    /// The signed distance of a point from the plane, the reference point at `r`.
    fn gap(&self, p: [f64; 3], r: [f64; 3]) -> f64 {
        (0..3).map(|c| self.normal[c] * (p[c] - r[c])).sum()
    }
}

/// A rigid, frictionless cylinder about the z axis (e.g. an axle through a cavity): each slave
/// node (node, weight) has the barrier term κ w b(ρ − radius), ρ its distance from the axis. The
/// weights are consistent nodal areas of [`Contact::faces`] like the self-contact slaves'.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Axle {
    pub radius: f64,
    pub slaves: Vec<(usize, f64)>,
}

impl Axle {
    /// The signed distance of a point from the axle's surface (negative: inside it).
    pub fn gap(&self, p: [f64; 3]) -> f64 {
        p[0].hypot(p[1]) - self.radius
    }

    /// The node's gap and, if within the barrier's reach d̂, its term: (energy, force, Hessian
    /// (row-major 3×3, empty unless asked)); Err if p is on or inside the axle.
    #[allow(clippy::type_complexity)]
    fn term(&self, barrier: &Barrier, weight: f64, p: [f64; 3], want_hessian: bool) -> Result<(f64, Option<(f64, Vec<f64>, Vec<f64>)>), ()> {
        let rho = p[0].hypot(p[1]);
        let gap = rho - self.radius;
        if !(gap > 0.0) {
            return Err(());
        }
        if gap >= barrier.dhat || weight == 0.0 {
            return Ok((gap, None));
        }
        let n = [p[0] / rho, p[1] / rho, 0.0];
        let (b, b1, b2) = barrier.eval(gap);
        let kw = barrier.kappa * weight;
        let force = n.iter().map(|v| kw * b1 * v).collect();
        let mut hess = Vec::new();
        if want_hessian {
            // ∇ρ = n, ∇²ρ = (P − n nᵀ)/ρ with P the projection on the xy plane
            hess = vec![0.0; 9];
            for i in 0..3 {
                for j in 0..3 {
                    let pij = if i == j && i < 2 { 1.0 } else { 0.0 };
                    hess[3 * i + j] = kw * (b2 * n[i] * n[j] + b1 * (pij - n[i] * n[j]) / rho);
                }
            }
        }
        Ok((gap, Some((kw * b, force, hess))))
    }
}

/// The type of the closest point of a triangle to a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Closest {
    /// The face interior (the distance is the signed distance to the triangle's plane).
    Face,
    /// The edge from vertex i to vertex (i + 1) % 3.
    Edge(usize),
    Vertex(usize),
}

/// Distance from p to the triangle (a, b, c) in f64: (unsigned distance, signed distance to the
/// plane, closest-point type).
pub fn point_triangle(p: [f64; 3], t: [[f64; 3]; 3]) -> (f64, f64, Closest) {
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let nrm = |u: [f64; 3]| dot(u, u).sqrt();
    let e0 = sub(t[1], t[0]);
    let e1 = sub(t[2], t[0]);
    let n = cross(e0, e1);
    let nn = nrm(n);
    let ap = sub(p, t[0]);
    let signed = if nn > 0.0 { dot(n, ap) / nn } else { f64::NAN };
    if nn > 0.0 {
        // barycentric coordinates of the projection: p' = a + u e0 + v e1
        let (d00, d01, d11) = (dot(e0, e0), dot(e0, e1), dot(e1, e1));
        let (d20, d21) = (dot(ap, e0), dot(ap, e1));
        let den = d00 * d11 - d01 * d01;
        let u = (d11 * d20 - d01 * d21) / den;
        let v = (d00 * d21 - d01 * d20) / den;
        // (a projection on an edge or vertex, to round-off, counts as the face's: on a flat
        // surface the edge and vertex types would carry a spurious lateral curvature 1/d)
        let tol = 1e-9;
        if u >= -tol && v >= -tol && u + v <= 1.0 + tol {
            return (signed.abs(), signed, Closest::Face);
        }
    }
    // the closest point lies on the boundary: the nearest edge, clamped to its ends
    let mut best = (f64::INFINITY, Closest::Vertex(0));
    for i in 0..3 {
        let (a, b) = (t[i], t[(i + 1) % 3]);
        let e = sub(b, a);
        let ee = dot(e, e);
        let s = if ee > 0.0 { dot(sub(p, a), e) / ee } else { 0.0 };
        let (d, kind) = if s <= 0.0 {
            (nrm(sub(p, a)), Closest::Vertex(i))
        } else if s >= 1.0 {
            (nrm(sub(p, b)), Closest::Vertex((i + 1) % 3))
        } else {
            (nrm(sub(p, [a[0] + s * e[0], a[1] + s * e[1], a[2] + s * e[2]])), Closest::Edge(i))
        };
        if d < best.0 {
            best = (d, kind);
        }
    }
    (best.0, signed, best.1)
}

/// The distance of type `kind` from p to the triangle, generic in the scalar (for its
/// derivatives): the signed plane distance for [`Closest::Face`], else the unsigned distance to
/// the edge's line or to the vertex.
pub fn typed_distance<D: Scalar>(p: [D; 3], t: [[D; 3]; 3], kind: Closest) -> D {
    let sub = |u: [D; 3], v: [D; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    match kind {
        Closest::Face => {
            let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
            dot(n, sub(p, t[0])) / dot(n, n).sqrt()
        }
        Closest::Edge(i) => {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            let c = cross(sub(p, a), sub(b, a));
            let e = sub(b, a);
            (dot(c, c) / dot(e, e)).sqrt()
        }
        Closest::Vertex(i) => {
            let d = sub(p, t[i]);
            dot(d, d).sqrt()
        }
    }
}

/// One slave node's contribution at the current positions.
#[derive(Clone, Debug)]
pub struct SlaveTerm {
    /// the node's distance to its target surface
    pub gap: f64,
    pub energy: f64,
    /// the slave's weight (its reference area) in the term
    pub weight: f64,
    /// the nodes the term couples (the slave first, then the target triangle's mesh nodes)
    pub nodes: Vec<usize>,
    /// ∂E/∂x over `nodes` (3 per node)
    pub force: Vec<f64>,
    /// ∂²E/∂x² over `nodes`, row-major (empty unless requested)
    pub hessian: Vec<f64>,
}

/// Why a state is not admissible for the contact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Penetration {
    pub node: usize,
}

impl Contact {
    /// Check node and triangle indices against a mesh of `n_nodes` nodes.
    pub fn validate(&self, n_nodes: usize) -> Result<(), String> {
        if !(self.barrier.dhat > 0.0 && self.barrier.dhat.is_finite()) || !(self.barrier.kappa > 0.0 && self.barrier.kappa.is_finite()) {
            return Err(format!("contact barrier needs d̂ > 0 and κ > 0 (got d̂ = {}, κ = {})", self.barrier.dhat, self.barrier.kappa));
        }
        if !(self.blend > 0.0 && self.blend.is_finite()) {
            return Err(format!("contact blend width must be > 0 (got {})", self.blend));
        }
        for (k, t) in self.triangles.iter().enumerate() {
            for v in t {
                if let Some(n) = &v.node() {
                    if *n >= n_nodes {
                        return Err(format!("contact triangle {k} refers to node {n} of {n_nodes}"));
                    }
                }
            }
        }
        if let Some(ax) = &self.axle {
            if !(ax.radius > 0.0 && ax.radius.is_finite()) {
                return Err(format!("contact axle radius must be > 0 (got {})", ax.radius));
            }
            if let Some(&(n, w)) = ax.slaves.iter().find(|(n, w)| *n >= n_nodes || !(*w >= 0.0 && w.is_finite())) {
                return Err(format!("contact axle slave node {n} of {n_nodes} (weight {w})"));
            }
        }
        for (k, pl) in self.planes.iter().enumerate() {
            let len = (pl.normal.iter().map(|v| v * v).sum::<f64>()).sqrt();
            if !((len - 1.0).abs() < 1e-9) {
                return Err(format!("contact plane {k}: the normal must be a unit vector (|n| = {len})"));
            }
            match pl.point {
                Vertex::Fixed(_) => {}
                Vertex::Node(n) if n < n_nodes => {}
                other => return Err(format!("contact plane {k}: its point must be fixed or a mesh node (got {other:?})")),
            }
            if let Some(&(n, w)) = pl.slaves.iter().find(|(n, w)| *n >= n_nodes || !(*w >= 0.0 && w.is_finite()) || Vertex::Node(*n) == pl.point) {
                return Err(format!("contact plane {k}: slave node {n} of {n_nodes} (weight {w}; not the plane's own node)"));
            }
        }
        for s in &self.slaves {
            if s.node >= n_nodes {
                return Err(format!("contact slave node {} of {n_nodes}", s.node));
            }
            if !(s.weight >= 0.0 && s.weight.is_finite()) {
                return Err(format!("contact slave node {} has weight {}", s.node, s.weight));
            }
            if let Some(&t) = s.targets.iter().find(|&&t| t >= self.triangles.len()) {
                return Err(format!("contact slave node {} refers to triangle {t} of {}", s.node, self.triangles.len()));
            }
            if s.targets.iter().any(|&t| self.triangles[t].contains(&Vertex::Node(s.node))) {
                return Err(format!("contact slave node {} is a vertex of one of its own target triangles", s.node));
            }
        }
        Ok(())
    }

    /// The node groups the tangent couples: each slave with every node of its candidate triangles.
    pub fn coupling_groups(&self) -> Vec<Vec<usize>> {
        self.slaves
            .iter()
            .map(|s| {
                let mut g = vec![s.node];
                for &t in &s.targets {
                    for v in &self.triangles[t] {
                        if let Some(n) = v.node() {
                            g.push(n);
                        }
                    }
                }
                g.sort_unstable();
                g.dedup();
                g
            })
            .chain(self.planes.iter().filter_map(|pl| pl.point.node().map(|r| (pl, r))).flat_map(|(pl, r)| pl.slaves.iter().map(move |&(n, _)| if n < r { vec![n, r] } else { vec![r, n] })))
            .collect()
    }

    fn coords(&self, t: usize, x: &impl Fn(usize) -> [f64; 3]) -> [[f64; 3]; 3] {
        let tri = &self.triangles[t];
        [0, 1, 2].map(|k| tri[k].position(x))
    }

    /// The slave's distance to its target surface: (unsigned distance, signed distance, closest
    /// type, triangle), or None without candidates.
    pub fn closest(&self, s: &Slave, x: &impl Fn(usize) -> [f64; 3]) -> Option<(f64, f64, Closest, usize)> {
        let p = x(s.node);
        let mut best: Option<(f64, f64, Closest, usize)> = None;
        for &t in &s.targets {
            let (d, sd, kind) = point_triangle(p, self.coords(t, x));
            // the closest; on a tie (a node above a shared edge or vertex), a face type first
            let better = match best {
                None => true,
                Some(b) => {
                    let tie = (d - b.0).abs() <= 1e-12 * d.max(b.0);
                    if tie {
                        kind == Closest::Face && b.2 != Closest::Face
                    } else {
                        d < b.0
                    }
                }
            };
            if better {
                best = Some((d, sd, kind, t));
            }
        }
        best
    }

    /// A slave's blended distance to its target surface (None where no target triangle's
    /// blend weight reaches it).
    pub fn blended_gap(&self, s: &Slave, x: &impl Fn(usize) -> [f64; 3]) -> Option<f64> {
        let p = x(s.node);
        let (mut sa, mut sb) = (0.0, 0.0);
        for &t in &s.targets {
            let (d, w) = blend_terms(p, self.coords(t, x), self.blend, self.barrier.dhat);
            sa += w * d;
            sb += w;
        }
        over_surface_gap(sa, sb)
    }

    /// The smallest blended distance of any slave node to its target surface (∞ without slaves
    /// within a triangle's reach).
    pub fn min_gap(&self, x: &impl Fn(usize) -> [f64; 3]) -> f64 {
        self.slaves.iter().filter_map(|s| self.blended_gap(s, x)).fold(self.obstacle_gap(x), f64::min)
    }

    /// The smallest distance of an axle or plane slave from its obstacle (∞ without any).
    pub fn obstacle_gap(&self, x: &impl Fn(usize) -> [f64; 3]) -> f64 {
        let axle = self.axle.as_ref().map_or(f64::INFINITY, |ax| ax.slaves.iter().map(|&(n, _)| ax.gap(x(n))).fold(f64::INFINITY, f64::min));
        self.planes.iter().fold(axle, |m, pl| {
            let r = pl.reference(x);
            pl.slaves.iter().map(|&(n, _)| pl.gap(x(n), r)).fold(m, f64::min)
        })
    }

    /// The smallest distance of any slave node to its target surface (∞ without candidates):
    /// the signed blended distance where the node is within a triangle's blend band (negative:
    /// the node has passed through the surface), else the unsigned distance to the closest
    /// triangle (far from contact the sign of one triangle's plane is not the side of the surface:
    /// on a concave wall the node lies behind the planes of its own wall's other triangles).
    pub fn min_distance(&self, x: &impl Fn(usize) -> [f64; 3]) -> f64 {
        self.slaves.iter().filter_map(|s| self.blended_gap(s, x).or_else(|| self.closest(s, x).map(|c| c.0))).fold(self.obstacle_gap(x), f64::min)
    }

    /// The largest fraction τ ∈ (0, 1] of the straight motion x → x + dx of every node that
    /// passes no slave through the face of one of its target triangles: continuous collision
    /// detection of each point–triangle pair (the point crosses the moving triangle's plane where
    /// det[b − a, c − a, p − a](τ), a cubic, changes sign, at a point inside the triangle), the
    /// step cut to `keep` of the first crossing. Pairs that cannot meet within the step (distance
    /// above the largest relative motion) are skipped; a node behind a triangle's plane at the
    /// start came round its edge and is not checked. So no step tunnels through a surface,
    /// however far beyond the barrier's reach it lands.
    pub fn max_step(&self, x: &impl Fn(usize) -> [f64; 3], dx: &impl Fn(usize) -> [f64; 3], keep: f64) -> f64 {
        let motion = |t: usize| {
            self.triangles[t].map(|v| match v {
                Vertex::Node(n) => dx(n),
                Vertex::Fixed(_) => [0.0; 3],
                Vertex::Rotated { node, angle } => apply(&rot_z(angle), dx(node)),
            })
        };
        let norm = |a: [f64; 3]| (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let at = |a: [f64; 3], d: [f64; 3], t: f64| [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]];
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let mut tmax = 1.0f64;
        for s in &self.slaves {
            let (p0, dp) = (x(s.node), dx(s.node));
            let lp = norm(dp);
            for &t in &s.targets {
                let (c0, dc) = (self.coords(t, x), motion(t));
                let l = lp + dc.iter().map(|v| norm(*v)).fold(0.0, f64::max);
                if !(l > 0.0) {
                    continue;
                }
                let (d0, sd0, _) = point_triangle(p0, c0);
                if sd0 <= 0.0 || l * tmax < d0 {
                    continue;
                }
                let state = |tau: f64| {
                    let c = [at(c0[0], dc[0], tau), at(c0[1], dc[1], tau), at(c0[2], dc[2], tau)];
                    (at(p0, dp, tau), c)
                };
                let f = |tau: f64| {
                    let (p, c) = state(tau);
                    let n = crate::scalar::cross(sub(c[1], c[0]), sub(c[2], c[0]));
                    crate::scalar::dot(n, sub(p, c[0]))
                };
                // the first sign change of the cubic on [0, tmax] (8 intervals), by bisection
                let f0 = f(0.0);
                let mut lo = 0.0;
                let mut hit = None;
                for k in 1..=8 {
                    let hi = tmax * k as f64 / 8.0;
                    if f(hi) * f0 <= 0.0 {
                        let (mut a, mut b) = (lo, hi);
                        for _ in 0..40 {
                            let m = 0.5 * (a + b);
                            if f(m) * f0 > 0.0 {
                                a = m;
                            } else {
                                b = m;
                            }
                        }
                        hit = Some(b);
                        break;
                    }
                    lo = hi;
                }
                let Some(tc) = hit else { continue };
                // through the triangle's face at the crossing (not its boundary: a node on a free
                // edge is at most half over the surface and has no barrier to stop it)
                let (p, c) = state(tc);
                let (dist, _, kind) = point_triangle(p, c);
                let size = norm(sub(c[1], c[0])).max(norm(sub(c[2], c[0])));
                if kind == Closest::Face && dist <= 1e-6 * size.max(1e-12) + 1e-9 {
                    tmax = tmax.min(keep * tc);
                }
            }
        }
        // the axle: the first root of |p_xy + τ dp_xy|² = radius² (a node outside moving in)
        if let Some(ax) = &self.axle {
            for &(n, _) in &ax.slaves {
                let (p, d) = (x(n), dx(n));
                let a = d[0] * d[0] + d[1] * d[1];
                let b = 2.0 * (p[0] * d[0] + p[1] * d[1]);
                let c = p[0] * p[0] + p[1] * p[1] - ax.radius * ax.radius;
                if !(a > 0.0) || c <= 0.0 || b >= 0.0 {
                    continue;
                }
                let disc = b * b - 4.0 * a * c;
                if disc < 0.0 {
                    continue;
                }
                // the smaller root, in the cancellation-free form 2c / (−b + √disc)
                let tc = 2.0 * c / (-b + disc.sqrt());
                if tc > 0.0 && tc <= tmax {
                    tmax = tmax.min(keep * tc);
                }
            }
        }
        // the planes: the gap is linear in the step
        for pl in &self.planes {
            let r = pl.reference(x);
            let dr = match pl.point {
                Vertex::Node(n) => dx(n),
                _ => [0.0; 3],
            };
            for &(n, _) in &pl.slaves {
                let g0 = pl.gap(x(n), r);
                let d = dx(n);
                let rate: f64 = (0..3).map(|c| pl.normal[c] * (d[c] - dr[c])).sum();
                if g0 > 0.0 && rate < 0.0 {
                    let tc = -g0 / rate;
                    if tc <= tmax {
                        tmax = tmax.min(keep * tc);
                    }
                }
            }
        }
        tmax
    }

    /// A blend width for a target mesh: a tenth of its shortest triangle edge (reference
    /// positions `x0`; fixed vertices as they are).
    pub fn default_blend(triangles: &[Triangle], x0: &[[f64; 3]]) -> f64 {
        let pos = |v: &Vertex| v.position(&|n| x0[n]);
        let mut hmin = f64::INFINITY;
        for t in triangles {
            for i in 0..3 {
                let (a, b) = (pos(&t[i]), pos(&t[(i + 1) % 3]));
                hmin = hmin.min(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt());
            }
        }
        0.1 * hmin
    }

    /// Every slave within the barrier's reach: its energy, force and (with `hessian`) tangent.
    /// Err if a node has reached or crossed its target surface (blended distance ≤ 0).
    pub fn terms(&self, x: &impl Fn(usize) -> [f64; 3], want_hessian: bool) -> Result<(Vec<SlaveTerm>, f64), Penetration> {
        let mut out = Vec::new();
        let mut min_gap = f64::INFINITY;
        let dh = self.barrier.dhat;
        let eps = self.blend;
        for s in &self.slaves {
            let p = x(s.node);
            // the triangles whose blend weight is not zero, with their plane distance
            let mut act: Vec<(usize, [[f64; 3]; 3])> = Vec::new();
            let (mut sa, mut sb) = (0.0, 0.0);
            for &t in &s.targets {
                let tc = self.coords(t, x);
                let (d, w) = blend_terms(p, tc, eps, dh);
                if w > 0.0 {
                    sa += w * d;
                    sb += w;
                    act.push((t, tc));
                }
            }
            if act.is_empty() {
                continue;
            }
            let Some(gap) = over_surface_gap(sa, sb) else { continue };
            min_gap = min_gap.min(gap);
            if !(gap > 0.0) {
                if crate::continuation::trace_enabled() {
                    let near = act.iter().map(|(_, tc)| point_triangle(p, *tc).0).fold(f64::INFINITY, f64::min);
                    eprintln!(
                        "[contact] penetration: node {} at {p:?} gap {gap:.3e} weights {sb:.3} over {} triangles, nearest {near:.3e}; {:?}",
                        s.node,
                        act.len(),
                        act.iter().map(|(t, _)| self.triangles[*t]).collect::<Vec<_>>()
                    );
                }
                return Err(Penetration { node: s.node });
            }
            if gap >= dh || s.weight == 0.0 {
                continue;
            }
            // local slots: the slave, then each vertex that follows a mesh node (fixed ones drop
            // out), with ∂y/∂x of its node (I, or the rotation of a rotated copy)
            const I3: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            let mut nodes = vec![s.node];
            let mut mats = vec![I3];
            let mut keys: Vec<(usize, u64)> = vec![(s.node, 0.0f64.to_bits())];
            let mut tri_slots: Vec<[Option<usize>; 3]> = Vec::new();
            for (t, _) in &act {
                let mut sl = [None; 3];
                for (k, vert) in self.triangles[*t].iter().enumerate() {
                    let (n, ang) = match *vert {
                        Vertex::Node(n) => (n, 0.0f64),
                        Vertex::Rotated { node, angle } => (node, angle),
                        Vertex::Fixed(_) => continue,
                    };
                    let key = (n, ang.to_bits());
                    let idx = match keys.iter().position(|k| *k == key) {
                        Some(i) => i,
                        None => {
                            keys.push(key);
                            nodes.push(n);
                            mats.push(if ang == 0.0 { I3 } else { rot_z(ang) });
                            keys.len() - 1
                        }
                    };
                    sl[k] = Some(idx);
                }
                tri_slots.push(sl);
            }
            let m = nodes.len();
            let nv = 3 * m;
            // Σ w_t d_t, Σ w_t and their first and second derivatives in the vertex positions y
            // (slot 0 the slave; then the slots above)
            let mut ga = vec![0.0; nv];
            let mut gb = vec![0.0; nv];
            let mut ha = if want_hessian { vec![0.0; nv * nv] } else { Vec::new() };
            let mut hb = if want_hessian { vec![0.0; nv * nv] } else { Vec::new() };
            for ((_, tc), sl) in act.iter().zip(&tri_slots) {
                let mut v = SVector::<f64, 12>::zeros();
                for c in 0..3 {
                    v[c] = p[c];
                    for k in 0..3 {
                        v[3 + 3 * k + c] = tc[k][c];
                    }
                }
                let f = |y: &SVector<Dual2SVec64<12>, 12>| {
                    let pt = [y[0], y[1], y[2]];
                    let tt = [[y[3], y[4], y[5]], [y[6], y[7], y[8]], [y[9], y[10], y[11]]];
                    blend_terms_generic(pt, tt, eps, dh)
                };
                let (_, gd, hd) = hessian(|y: SVector<Dual2SVec64<12>, 12>| f(&y).0, &v);
                let (w, gw, hw) = hessian(|y: SVector<Dual2SVec64<12>, 12>| f(&y).1, &v);
                let d = typed_distance(p, *tc, Closest::Face);
                // local variable i of the triangle → (slot, rotation)
                let slot_of = |i: usize| -> Option<usize> {
                    if i < 3 {
                        Some(0)
                    } else {
                        sl[(i - 3) / 3]
                    }
                };
                // map a 12-vector of y-derivatives into the local x-derivatives: x = M y-part
                let add_vec = |dst: &mut [f64], g: &dyn Fn(usize) -> f64, scale: f64| {
                    for blk in 0..4 {
                        let Some(sl_i) = slot_of(3 * blk) else { continue };
                        let mt = &mats[sl_i];
                        for c in 0..3 {
                            let mut acc = 0.0;
                            for r in 0..3 {
                                acc += mt[r][c] * g(3 * blk + r);
                            }
                            dst[3 * sl_i + c] += scale * acc;
                        }
                    }
                };
                add_vec(&mut ga, &|i| d * gw[i] + w * gd[i], 1.0);
                add_vec(&mut gb, &|i| gw[i], 1.0);
                if want_hessian {
                    for bi in 0..4 {
                        let Some(si) = slot_of(3 * bi) else { continue };
                        for bj in 0..4 {
                            let Some(sj) = slot_of(3 * bj) else { continue };
                            let (mi, mj) = (&mats[si], &mats[sj]);
                            for ci in 0..3 {
                                for cj in 0..3 {
                                    let (mut va, mut vb) = (0.0, 0.0);
                                    for r in 0..3 {
                                        for q in 0..3 {
                                            let (i, j) = (3 * bi + r, 3 * bj + q);
                                            let hw_ij = hw[(i, j)];
                                            let a_ij = d * hw_ij + gw[i] * gd[j] + gd[i] * gw[j] + w * hd[(i, j)];
                                            let c = mi[r][ci] * mj[q][cj];
                                            va += c * a_ij;
                                            vb += c * hw_ij;
                                        }
                                    }
                                    ha[(3 * si + ci) * nv + 3 * sj + cj] += va;
                                    hb[(3 * si + ci) * nv + 3 * sj + cj] += vb;
                                }
                            }
                        }
                    }
                }
            }
            // d = A/B; the energy κ w b(d) g(B), g fading the contact out beyond a surface's edge
            let (bsum, asum) = (sb, sa);
            let gd: Vec<f64> = (0..nv).map(|i| (ga[i] - gap * gb[i]) / bsum).collect();
            let (g, g1, g2) = fade(bsum);
            let (b, b1, b2) = self.barrier.eval(gap);
            let _ = asum;
            let kw = self.barrier.kappa * s.weight;
            let force: Vec<f64> = (0..nv).map(|i| kw * (b1 * g * gd[i] + b * g1 * gb[i])).collect();
            let mut hess = Vec::new();
            if want_hessian {
                hess = vec![0.0; nv * nv];
                for i in 0..nv {
                    for j in 0..nv {
                        // ∇²d = (∇²A − d ∇²B − ∇d ∇Bᵀ − ∇B ∇dᵀ) / B
                        let hdij = (ha[i * nv + j] - gap * hb[i * nv + j] - gd[i] * gb[j] - gb[i] * gd[j]) / bsum;
                        hess[i * nv + j] = kw * (b2 * g * gd[i] * gd[j] + b1 * g * hdij + b1 * g1 * (gd[i] * gb[j] + gb[i] * gd[j]) + b * g2 * gb[i] * gb[j] + b * g1 * hb[i * nv + j]);
                    }
                }
            }
            out.push(SlaveTerm { gap, energy: kw * b * g, weight: s.weight, nodes, force, hessian: hess });
        }
        if let Some(ax) = &self.axle {
            for &(node, weight) in &ax.slaves {
                let (gap, term) = ax.term(&self.barrier, weight, x(node), want_hessian).map_err(|_| Penetration { node })?;
                min_gap = min_gap.min(gap);
                if let Some((energy, force, hessian)) = term {
                    out.push(SlaveTerm { gap, energy, weight, nodes: vec![node], force, hessian });
                }
            }
        }
        for pl in &self.planes {
            let r = pl.reference(x);
            let nref = match pl.point {
                Vertex::Node(n) => Some(n),
                _ => None,
            };
            let nn = pl.normal;
            for &(node, weight) in &pl.slaves {
                let gap = pl.gap(x(node), r);
                min_gap = min_gap.min(gap);
                if !(gap > 0.0) {
                    return Err(Penetration { node });
                }
                if gap >= dh || weight == 0.0 {
                    continue;
                }
                // gap = n·(x_s − x_ref): ∇ = (n, −n), ∇² = 0
                let (b, b1, b2) = self.barrier.eval(gap);
                let kw = self.barrier.kappa * weight;
                let mut g = nn.to_vec();
                let mut nodes = vec![node];
                if let Some(rn) = nref {
                    nodes.push(rn);
                    g.extend(nn.iter().map(|v| -v));
                }
                let nv = g.len();
                let force = g.iter().map(|v| kw * b1 * v).collect();
                let hessian = if want_hessian { (0..nv * nv).map(|ij| kw * b2 * g[ij / nv] * g[ij % nv]).collect() } else { Vec::new() };
                out.push(SlaveTerm { gap, energy: kw * b, weight, nodes, force, hessian });
            }
        }
        Ok((out, min_gap))
    }
}

/// The C² smooth step: 0 for x ≤ 0, 1 for x ≥ 1, x³(10 − 15x + 6x²) between (h(1 − x) = 1 − h(x)).
fn smoothstep<D: Scalar>(x: D) -> D {
    let xr = x.re();
    if xr <= 0.0 {
        D::zero()
    } else if xr >= 1.0 {
        D::one()
    } else {
        x * x * x * (D::from(10.0) - x * D::from(15.0) + x * x * D::from(6.0))
    }
}

/// The blend weights' sum below which a slave is not over its target surface (no contact term).
const FADE_START: f64 = 0.5;

/// A slave's blended gap Σw·d / Σw from the sums Σw·d (`sa`) and Σw (`sb`) of its target
/// triangles, or None where the node is not over the surface:
/// * beyond a surface's free edge (or beside a crease whose other side is not a candidate) the
///   weights sum to less than 1 and the contact fades out; at half or less the node is not over
///   the surface (a node beside a triangle's edge may lie behind its plane without having passed
///   through it);
/// * behind the surface's plane where it fades out (½ < Σw < 1) the node came round the
///   surface's edge (the steps' collision check stops any passage through a triangle's face),
///   not through it. (Refused, such a node was a trap: moving over the surface from beside it,
///   where it had no term, it met an infinite wall at Σw = ½ that the energy did not show;
///   measured on the example design's free collapse with two elements through the wall, whose
///   relaxation stalled there at −64 kPa.)
fn over_surface_gap(sa: f64, sb: f64) -> Option<f64> {
    if sb <= FADE_START {
        return None;
    }
    let gap = sa / sb;
    (gap > 0.0 || sb >= 1.0).then_some(gap)
}

/// The contact fade g(B) of the blend weights' sum: 1 for B ≥ 1 (inside a surface, where the
/// weights sum to at least 1), 0 for B ≤ ½, 3x² − 2x³ between (x = (B − ½)/½: beyond a surface's
/// free edge); (g, g', g'').
fn fade(b: f64) -> (f64, f64, f64) {
    if b >= 1.0 {
        (1.0, 0.0, 0.0)
    } else if b <= FADE_START {
        (0.0, 0.0, 0.0)
    } else {
        let k = 1.0 / (1.0 - FADE_START);
        let x = (b - FADE_START) * k;
        (3.0 * x * x - 2.0 * x * x * x, (6.0 * x - 6.0 * x * x) * k, (6.0 - 12.0 * x) * k * k)
    }
}

/// A triangle's share of a slave's blended distance, generic in the scalar: (d, w) with d the
/// signed distance to the triangle's plane and w = Π S(eᵢ/ε + ½) · C(d) its weight, eᵢ the
/// in-plane distance of the projected point from edge i (positive inside), S the smooth step
/// (so that across an edge shared by two coplanar triangles the weights sum to 1), and C a cutoff
/// that drops triangles farther than 2–3 d̂ in front of the point or d̂/4–d̂/2 behind it.
pub fn blend_terms_generic<D: Scalar>(p: [D; 3], t: [[D; 3]; 3], eps: f64, dhat: f64) -> (D, D) {
    let sub = |u: [D; 3], v: [D; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
    let nn = dot(n, n).sqrt();
    let nh = [n[0] / nn, n[1] / nn, n[2] / nn];
    let d = dot(nh, sub(p, t[0]));
    let mut w = D::one();
    for i in 0..3 {
        let (a, b) = (t[i], t[(i + 1) % 3]);
        let e = sub(b, a);
        let el = dot(e, e).sqrt();
        // in-plane inward normal of edge i: n̂ × ê
        let m = cross(nh, [e[0] / el, e[1] / el, e[2] / el]);
        let ei = dot(m, sub(p, a));
        w = w * smoothstep(ei / eps + D::from(0.5));
        if w.re() == 0.0 {
            return (d, D::zero());
        }
    }
    // cutoff in front over d ∈ [2 d̂, 3 d̂]; behind over d ∈ [−d̂/2, −d̂/4] (a node farther
    // behind a triangle's plane has not come through it, which the continuous collision check
    // of the steps excludes, but round its edge)
    let c = if d.re() >= 0.0 { D::one() - smoothstep(d / dhat - D::from(2.0)) } else { smoothstep(d / dhat * D::from(4.0) + D::from(2.0)) };
    (d, w * c)
}

fn blend_terms(p: [f64; 3], t: [[f64; 3]; 3], eps: f64, dhat: f64) -> (f64, f64) {
    blend_terms_generic(p, t, eps, dhat)
}

/// The self-contact of a surface (e.g. a cavity wall): every node of `faces` is a slave
/// against the surface's triangles ([`face_triangles`]) and their copies rotated about z by each
/// of `copies` (a cyclic sector's neighbours; 0 = the modelled part itself). A slave's candidate
/// triangles are those within `reach` of it in the reference configuration, without a vertex in
/// its own neighbourhood on the surface, which it cannot touch: its own ring of triangles and the
/// next one, and whatever lies within `exclude` of it both in space and along the surface (so
/// that a wall facing it across a narrow cavity is not excluded). A uniform grid finds them. The
/// blend width is [`Contact::default_blend`].
pub fn self_contact(mesh: &Mesh, faces: &[Face], copies: &[f64], exclude: f64, reach: f64, barrier: Barrier) -> Contact {
    let base: Vec<Triangle> = faces.iter().flat_map(|&f| face_triangles(mesh, f)).collect();
    let mut triangles = Vec::with_capacity(base.len() * copies.len());
    for &ang in copies {
        for t in &base {
            triangles.push(t.map(|v| match v {
                Vertex::Node(n) if ang != 0.0 => Vertex::Rotated { node: n, angle: ang },
                other => other,
            }));
        }
    }
    let x0 = &mesh.nodes;
    let pos = |v: &Vertex| v.position(&|n| x0[n]);
    let tri_x: Vec<[[f64; 3]; 3]> = triangles.iter().map(|t| [pos(&t[0]), pos(&t[1]), pos(&t[2])]).collect();
    // grid of cell size `reach` over the triangles' vertices
    let cell = reach.max(1e-12);
    let key = |p: [f64; 3]| [(p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64, (p[2] / cell).floor() as i64];
    let mut grid: std::collections::HashMap<[i64; 3], Vec<usize>> = Default::default();
    for (t, tx) in tri_x.iter().enumerate() {
        let mut keys: Vec<[i64; 3]> = tx.iter().map(|p| key(*p)).collect();
        keys.sort_unstable();
        keys.dedup();
        for k in keys {
            grid.entry(k).or_default().push(t);
        }
    }
    let dist = |a: [f64; 3], b: [f64; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    // A node's excluded neighbourhood (the surface it cannot touch): its own ring of triangles and
    // the next ring (topologically: a coarse mesh's ring is wider than `exclude`), and the
    // triangles with a vertex within `exclude` both in space and along the surface's edges.
    // Measured only in space (the farthest vertex of the own ring, or `exclude`), it excluded the
    // facing wall across a narrow lobe: 3.2–3.9 mm across on the coarse example (radius 3.6–4.2
    // mm from the ring), 2.6 mm on 24x8x2, where the quadratic walls then overlapped by up to
    // 0.011 and 0.006 mm between the nodes with no contact term between them; now < 0.001 mm.
    let geo = SurfaceGraph::new(&triangles, copies, x0);
    let weights = nodal_areas(mesh, faces);
    let slaves = weights
        .into_iter()
        .map(|(node, weight)| {
            let p = x0[node];
            let k = key(p);
            let mut cand: Vec<usize> = Vec::new();
            // a triangle within `reach` has a vertex within reach + its size: search 2 cells out
            for dx in -2..=2 {
                for dy in -2..=2 {
                    for dz in -2..=2 {
                        if let Some(v) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                            cand.extend_from_slice(v);
                        }
                    }
                }
            }
            cand.sort_unstable();
            cand.dedup();
            // (a path of edges is up to √2 longer than the surface's geodesic on a grid of quads
            // split once)
            let near = geo.within(node, std::f64::consts::SQRT_2 * exclude);
            let own = geo.rings(node, 2);
            cand.retain(|&t| {
                let excluded = triangles[t].iter().zip(&tri_x[t]).any(|(v, x)| geo.id(v).is_some_and(|i| own.contains(&i) || (dist(*x, p) <= exclude && near.contains(&i))));
                !excluded && point_triangle(p, tri_x[t]).0 <= reach
            });
            Slave { node, weight, targets: cand }
        })
        .filter(|s| !s.targets.is_empty())
        .collect();
    let blend = Contact::default_blend(&triangles, x0);
    Contact { barrier, blend, triangles, slaves, faces: faces.to_vec(), axle: None, planes: Vec::new() }
}

/// The node graph of a triangulated surface and its rotated copies, for distances along the
/// surface: a vertex is a node (id n) or its copy rotated by `copies[c]` (id (c + 1)·N + n);
/// edges are the triangles' edges (reference lengths), and vertices that coincide (a cyclic
/// sector's cut, seen from both copies) are joined.
struct SurfaceGraph {
    n: usize,
    copies: Vec<f64>,
    adj: std::collections::HashMap<usize, Vec<(usize, f64)>>,
}

impl SurfaceGraph {
    fn new(triangles: &[Triangle], copies: &[f64], x0: &[[f64; 3]]) -> Self {
        let mut g = SurfaceGraph { n: x0.len(), copies: copies.to_vec(), adj: Default::default() };
        let pos = |v: &Vertex| v.position(&|n| x0[n]);
        let mut scale = 0.0f64;
        for t in triangles {
            for a in 0..3 {
                let (pa, pb) = (pos(&t[a]), pos(&t[(a + 1) % 3]));
                let l = ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2)).sqrt();
                scale = scale.max(l);
                if let (Some(i), Some(j)) = (g.id(&t[a]), g.id(&t[(a + 1) % 3])) {
                    g.adj.entry(i).or_default().push((j, l));
                    g.adj.entry(j).or_default().push((i, l));
                }
            }
        }
        // coincident vertices (within 1e-9 of the longest edge): a hash of positions on a grid of
        // that size, each point checked against its cell's and the neighbouring cells' points
        let tol = 1e-9 * scale.max(1e-300);
        let mut at: std::collections::HashMap<[i64; 3], Vec<usize>> = Default::default();
        let mut ids: Vec<usize> = g.adj.keys().copied().collect();
        ids.sort_unstable();
        let cell = |p: [f64; 3]| p.map(|c| (c / tol).floor() as i64);
        for &i in &ids {
            at.entry(cell(g.position(i, x0))).or_default().push(i);
        }
        let mut joins = Vec::new();
        for &i in &ids {
            let p = g.position(i, x0);
            let k = cell(p);
            for d in 0..27i64 {
                let key = [k[0] + d % 3 - 1, k[1] + (d / 3) % 3 - 1, k[2] + d / 9 - 1];
                for &j in at.get(&key).map(|v| v.as_slice()).unwrap_or(&[]) {
                    let q = g.position(j, x0);
                    if j != i && (p[0] - q[0]).abs().max((p[1] - q[1]).abs()).max((p[2] - q[2]).abs()) <= tol {
                        joins.push((i, j));
                    }
                }
            }
        }
        for (i, j) in joins {
            g.adj.entry(i).or_default().push((j, 0.0));
        }
        g
    }

    /// The graph vertex of a triangle vertex (None for a fixed point).
    fn id(&self, v: &Vertex) -> Option<usize> {
        match *v {
            Vertex::Node(n) => Some(n),
            Vertex::Rotated { node, angle } => self.copies.iter().position(|&a| a == angle).map(|c| (c + 1) * self.n + node),
            Vertex::Fixed(_) => None,
        }
    }

    fn position(&self, i: usize, x0: &[[f64; 3]]) -> [f64; 3] {
        let (c, n) = (i / self.n, i % self.n);
        if c == 0 {
            x0[n]
        } else {
            apply(&rot_z(self.copies[c - 1]), x0[n])
        }
    }

    /// The vertices within `k` edges of node `node` (copy 0): its ring of triangles' vertices
    /// for k = 1 (coincident vertices count as one).
    fn rings(&self, node: usize, k: usize) -> std::collections::HashSet<usize> {
        let mut seen: std::collections::HashSet<usize> = Default::default();
        let mut front = vec![node];
        for level in 0..=k {
            // close the front over zero-length joins
            let mut i = 0;
            while i < front.len() {
                let v = front[i];
                for &(j, l) in self.adj.get(&v).map(|a| a.as_slice()).unwrap_or(&[]) {
                    if l == 0.0 && !front.contains(&j) && !seen.contains(&j) {
                        front.push(j);
                    }
                }
                i += 1;
            }
            seen.extend(front.iter().copied());
            if level == k {
                break;
            }
            let mut next = Vec::new();
            for &v in &front {
                for &(j, _) in self.adj.get(&v).map(|a| a.as_slice()).unwrap_or(&[]) {
                    if !seen.contains(&j) && !next.contains(&j) {
                        next.push(j);
                    }
                }
            }
            front = next;
        }
        seen
    }

    /// The vertices within distance `r` of node `node` (copy 0) along the surface (Dijkstra).
    fn within(&self, node: usize, r: f64) -> std::collections::HashSet<usize> {
        use std::cmp::Reverse;
        let mut best: std::collections::HashMap<usize, f64> = Default::default();
        let mut heap = std::collections::BinaryHeap::new();
        best.insert(node, 0.0);
        heap.push((Reverse(0.0f64.to_bits()), node));
        let mut done = std::collections::HashSet::new();
        while let Some((Reverse(db), i)) = heap.pop() {
            let d = f64::from_bits(db);
            if d > r || !done.insert(i) {
                continue;
            }
            for &(j, l) in self.adj.get(&i).map(|v| v.as_slice()).unwrap_or(&[]) {
                let dj = d + l;
                if dj <= r && best.get(&j).is_none_or(|&b| dj < b) {
                    best.insert(j, dj);
                    heap.push((Reverse(dj.to_bits()), j));
                }
            }
        }
        done
    }
}

/// The consistent reference areas ∫ Nᵢ dA of the nodes of a set of faces (summed over faces).
pub fn nodal_areas(mesh: &Mesh, faces: &[Face]) -> Vec<(usize, f64)> {
    nodal_areas_at(mesh, faces, &mesh.nodes)
}

/// [`nodal_areas`] with the nodes at `x` (generic: shape derivatives of the weights).
pub fn nodal_areas_at<D: Scalar>(mesh: &Mesh, faces: &[Face], x: &[[D; 3]]) -> Vec<(usize, D)> {
    let mut acc: std::collections::BTreeMap<usize, D> = Default::default();
    for f in faces {
        let nodes = mesh.face_nodes(*f);
        let rule = FaceRule::new(nodes.len(), 3);
        // 8-node (serendipity) faces: ∫ Nᵢ dA is negative at the corners (−A/12 on a flat
        // square), which would turn a corner's barrier into an attraction; they get the
        // row-sum-free HRZ lumping instead, wᵢ = A ∫ Nᵢ² dA / Σⱼ ∫ Nⱼ² dA (positive, summing to A).
        let hrz = nodes.len() == 8;
        let mut area = D::zero();
        let mut local = vec![D::zero(); nodes.len()];
        for (q, w) in rule.weights.iter().enumerate() {
            let mut ts = [[D::zero(); 3]; 2];
            for (a, &n) in nodes.iter().enumerate() {
                for d in 0..2 {
                    for c in 0..3 {
                        ts[d][c] += x[n][c] * rule.dn[q][a][d];
                    }
                }
            }
            let nv = cross(ts[0], ts[1]);
            let da = dot(nv, nv).sqrt() * *w;
            area += da;
            for a in 0..nodes.len() {
                let na = rule.n[q][a];
                local[a] += da * if hrz { na * na } else { na };
            }
        }
        if hrz {
            let mut sum = D::zero();
            for v in &local {
                sum += *v;
            }
            for v in local.iter_mut() {
                *v = *v * area / sum;
            }
        }
        for (a, &n) in nodes.iter().enumerate() {
            *acc.entry(n).or_insert(D::zero()) += local[a];
        }
    }
    acc.into_iter().collect()
}

/// The triangles of a face on its node grid, oriented with the face's outward normal: 2 for a
/// 4-node face, 8 for a 9-node one (4 sub-quads around the centre), 6 for an 8-node one (a
/// triangle at each corner and the quad of the edge midpoints split in two).
pub fn face_triangles(mesh: &Mesh, f: Face) -> Vec<Triangle> {
    let n = mesh.face_nodes(f);
    let v = |i: usize| Vertex::Node(n[i]);
    let tris: Vec<[usize; 3]> = match n.len() {
        4 => vec![[0, 1, 2], [0, 2, 3]],
        8 => vec![[0, 4, 7], [4, 1, 5], [5, 2, 6], [7, 6, 3], [4, 5, 6], [4, 6, 7]],
        9 => [[0, 4, 8, 7], [4, 1, 5, 8], [8, 5, 2, 6], [7, 8, 6, 3]].iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect(),
        // faces come from hexahedra of 8, 20 or 27 nodes only
        k => unreachable!("a hexahedron face has 4, 8 or 9 nodes, not {k}"),
    };
    tris.iter().map(|t| [v(t[0]), v(t[1]), v(t[2])]).collect()
}

/// A fixed plane obstacle through `point` with unit normal `normal` (pointing to the slaves),
/// as two triangles covering the square of half-size `half` around `point`.
pub fn plane_obstacle(point: [f64; 3], normal: [f64; 3], half: f64) -> Vec<Triangle> {
    // two tangents t1, t2 with t1 × t2 = n
    let a = if normal[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let t1 = cross(a, normal);
    let l = dot(t1, t1).sqrt();
    let t1 = [t1[0] / l, t1[1] / l, t1[2] / l];
    let t2 = cross(normal, t1);
    let at = |s: f64, t: f64| Vertex::Fixed([point[0] + half * (s * t1[0] + t * t2[0]), point[1] + half * (s * t1[1] + t * t2[1]), point[2] + half * (s * t1[2] + t * t2[2])]);
    let (p0, p1, p2, p3) = (at(-1.0, -1.0), at(1.0, -1.0), at(1.0, 1.0), at(-1.0, 1.0));
    vec![[p0, p1, p2], [p0, p2, p3]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8-node (Hex20) faces: 6 triangles covering the face once, each along the face's outward
    /// normal; the slave weights (HRZ-lumped) are positive and sum to the face area.
    #[test]
    fn hex20_faces_triangulate_and_weigh_positively() {
        let m = crate::meshgen::boxed(crate::mesh::ElementKind::Hex20, [2, 1, 1], [2.0, 1.0, 3.0]);
        let faces = m.face_sets["zmax"].clone();
        let mut area = 0.0;
        for f in &faces {
            let tris = face_triangles(&m, *f);
            assert_eq!(tris.len(), 6);
            for t in &tris {
                let p: Vec<[f64; 3]> = t.iter().map(|v| v.position(&|n| m.nodes[n])).collect();
                let n = cross([p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]], [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]]);
                assert!(n[2] > 0.0, "triangle against the outward normal +z: {n:?}");
                area += 0.5 * n[2];
            }
        }
        assert!((area - 2.0).abs() < 1e-12, "{area}");
        let w = nodal_areas(&m, &faces);
        assert!(w.iter().all(|(_, a)| *a > 0.0), "{w:?}");
        let total: f64 = w.iter().map(|(_, a)| a).sum();
        assert!((total - 2.0).abs() < 1e-12, "{total}");
    }

    #[test]
    fn barrier_derivatives_match_differences() {
        let b = Barrier { dhat: 1e-2, kappa: 3.0 };
        for d in [1e-5, 1e-4, 3e-3, 9.9e-3] {
            let h = 1e-7 * d;
            let (_, b1, b2) = b.eval(d);
            let fd1 = (b.eval(d + h).0 - b.eval(d - h).0) / (2.0 * h);
            let fd2 = (b.eval(d + h).1 - b.eval(d - h).1) / (2.0 * h);
            assert!((fd1 - b1).abs() <= 1e-6 * b1.abs(), "{d}: {fd1} vs {b1}");
            assert!((fd2 - b2).abs() <= 1e-6 * b2.abs(), "{d}: {fd2} vs {b2}");
        }
        assert_eq!(b.eval(2e-2), (0.0, 0.0, 0.0));
        let g = b.gap_at_pressure(0.5);
        assert!((b.pressure(g) - 0.5).abs() < 1e-10);
    }

    #[test]
    fn point_triangle_types_and_distances() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let (d, s, k) = point_triangle([0.2, 0.2, 0.5], t);
        assert_eq!(k, Closest::Face);
        assert!((d - 0.5).abs() < 1e-15 && (s - 0.5).abs() < 1e-15);
        let (_, s, _) = point_triangle([0.2, 0.2, -0.5], t);
        assert!((s + 0.5).abs() < 1e-15);
        let (d, _, k) = point_triangle([0.5, -1.0, 0.0], t);
        assert_eq!(k, Closest::Edge(0));
        assert!((d - 1.0).abs() < 1e-15);
        let (d, _, k) = point_triangle([-1.0, -1.0, 1.0], t);
        assert_eq!(k, Closest::Vertex(0));
        assert!((d - 3f64.sqrt()).abs() < 1e-15);
        // the typed distances agree with the classified ones
        for p in [[0.2, 0.2, 0.5], [0.5, -1.0, 0.3], [-1.0, -1.0, 1.0], [2.0, 2.0, 0.1]] {
            let (d, s, k) = point_triangle(p, t);
            let td = typed_distance(p, t, k);
            assert!((td - if k == Closest::Face { s } else { d }).abs() < 1e-14, "{p:?}");
        }
    }

    #[test]
    fn slave_force_and_hessian_match_differences() {
        // a deformable triangle and a slave node above it: force = ∂E/∂x, Hessian = ∂f/∂x
        // node 4 is node 1's position rotated back by 0.3 rad: its copy rotated by 0.3 is vertex 1
        let r = rot_z(-0.3);
        let x1 = [1.0, 0.1, 0.05];
        let mut x = vec![[0.0, 0.0, 0.0], [9.0, 9.0, 9.0], [0.1, 1.0, -0.02], [0.3, 0.25, 0.0135], apply(&r, x1)];
        let c = Contact {
            barrier: Barrier { dhat: 0.01, kappa: 2.0 },
            blend: 0.05,
            triangles: vec![[Vertex::Node(0), Vertex::Rotated { node: 4, angle: 0.3 }, Vertex::Node(2)], [Vertex::Rotated { node: 4, angle: 0.3 }, Vertex::Fixed([2.0, 2.0, 0.0]), Vertex::Node(2)]],
            slaves: vec![Slave { node: 3, weight: 0.7, targets: vec![0, 1] }],
            faces: Vec::new(),
            axle: None,
            planes: Vec::new(),
        };
        c.validate(5).unwrap();
        // inside a triangle; over the crease between the two (both weights); inside, within the
        // blend band of a free edge (the weights sum to between ½ and 1: the fade)
        for (p, kind) in [([0.3, 0.25, 0.0135], Some(Closest::Face)), ([0.56, 0.56, 0.02], None), ([0.058, 0.5, -0.004], Some(Closest::Face))] {
            x[3] = p;
            if let Some(kind) = kind {
                assert_eq!(c.closest(&c.slaves[0], &|n| x[n]).map(|b| (b.2, b.3)), Some((kind, 0)), "{p:?}");
            }
            let energy = |x: &Vec<[f64; 3]>| c.terms(&|n| x[n], false).unwrap().0.iter().map(|t| t.energy).sum::<f64>();
            let (terms, _) = c.terms(&|n| x[n], true).unwrap();
            assert_eq!(terms.len(), 1);
            let t = &terms[0];
            let m = t.nodes.len();
            for a in 0..m {
                for ci in 0..3 {
                    let h = 1e-8;
                    let mut xp = x.clone();
                    xp[t.nodes[a]][ci] += h;
                    let mut xm = x.clone();
                    xm[t.nodes[a]][ci] -= h;
                    let fd = (energy(&xp) - energy(&xm)) / (2.0 * h);
                    let f = t.force[3 * a + ci];
                    assert!((fd - f).abs() <= 1e-6 * f.abs().max(1e-3), "{p:?} force {a},{ci}: {fd} vs {f}");
                    let fp = &c.terms(&|n| xp[n], false).unwrap().0[0].force;
                    let fm = &c.terms(&|n| xm[n], false).unwrap().0[0].force;
                    for r in 0..3 * m {
                        let fdh = (fp[r] - fm[r]) / (2.0 * h);
                        let hv = t.hessian[r * 3 * m + 3 * a + ci];
                        assert!((fdh - hv).abs() <= 1e-5 * hv.abs().max(1e-1), "{p:?} hessian {r},{a},{ci}: {fdh} vs {hv}");
                    }
                }
            }
        }
        // behind the face: not admissible
        x[3] = [0.3, 0.25, 0.008];
        assert_eq!(c.terms(&|n| x[n], false).unwrap_err(), Penetration { node: 3 });
    }

    #[test]
    fn steps_through_a_surface_are_cut_before_the_crossing_however_far() {
        // a slave 0.5 above a fixed unit triangle (z = 0, normal +z), far beyond the barrier's reach
        let c = Contact {
            barrier: Barrier { dhat: 0.01, kappa: 1.0 },
            blend: 0.05,
            triangles: vec![[Vertex::Fixed([0.0, 0.0, 0.0]), Vertex::Fixed([1.0, 0.0, 0.0]), Vertex::Fixed([0.0, 1.0, 0.0])]],
            slaves: vec![Slave { node: 0, weight: 1.0, targets: vec![0] }],
            faces: Vec::new(),
            axle: None,
            planes: Vec::new(),
        };
        let x = |_: usize| [0.2, 0.2, 0.5];
        // 10 units down: crosses the face at τ = 0.05, cut to keep × 0.05
        let tau = c.max_step(&x, &|_| [0.0, 0.0, -10.0], 0.8);
        assert!((tau - 0.8 * 0.05).abs() < 1e-9, "{tau}");
        // down and sideways, crossing the plane outside the triangle: not cut
        assert_eq!(c.max_step(&x, &|_| [3.0, 0.0, -1.0], 0.8), 1.0);
        // along the surface, or away from it: not cut
        assert_eq!(c.max_step(&x, &|_| [0.3, 0.3, 0.0], 0.8), 1.0);
        assert_eq!(c.max_step(&x, &|_| [0.0, 0.0, 5.0], 0.8), 1.0);
        // a node behind the plane (come round an edge) moving up through it is not cut
        assert_eq!(c.max_step(&|_| [0.2, 0.2, -0.5], &|_| [0.0, 0.0, 10.0], 0.8), 1.0);
        // the state itself: far behind the plane the triangle does not count (no refusal), just
        // behind it it is a penetration
        assert!(c.terms(&|_| [0.2, 0.2, -0.5], false).is_ok());
        assert!(c.terms(&|_| [0.2, 0.2, -0.001], false).is_err());
        // just behind the plane within the blend band of the free edge x = 0 (the weights sum
        // to between ½ and 1: the surface fades out there): come round the edge, no term and no
        // refusal, and not counted as a penetrating distance
        let beside = |_: usize| [0.01, 0.5, -0.001];
        let sb = blend_terms(beside(0), c.coords(0, &beside), c.blend, c.barrier.dhat).1;
        assert!(sb > FADE_START && sb < 1.0, "{sb}");
        let (terms, _) = c.terms(&beside, false).unwrap();
        assert!(terms.is_empty());
        assert!(c.min_gap(&beside).is_infinite() && c.min_distance(&beside) > 0.0);
        // the same depth inside the edge's band but over the face (weights sum to 1): refused
        assert!(c.terms(&|_| [0.03, 0.5, -0.001], false).is_err());
    }

    /// The exclusion radius is measured along the surface: of a slab's two faces (1 apart, not
    /// joined), a node of the top face has the bottom face's triangles right below it as
    /// candidates with an exclusion radius of 1.5, but none of its own face's within 1.5 of it.
    #[test]
    fn self_contact_excludes_by_distance_along_the_surface() {
        use crate::mesh::ElementKind;
        let m = crate::meshgen::boxed(ElementKind::Hex8, [4, 4, 1], [4.0, 4.0, 1.0]);
        let faces: Vec<Face> = m.face_sets["zmin"].iter().chain(&m.face_sets["zmax"]).copied().collect();
        let c = self_contact(&m, &faces, &[0.0], 1.5, 3.0, Barrier { dhat: 0.1, kappa: 1.0 });
        let top = (0..m.nodes.len()).find(|&n| m.nodes[n] == [2.0, 2.0, 1.0]).unwrap();
        let s = c.slaves.iter().find(|s| s.node == top).unwrap();
        let tri = |t: usize| c.triangles[t].map(|v| v.position(&|n| m.nodes[n]));
        assert!(s.targets.iter().any(|&t| tri(t).iter().all(|p| p[2] == 0.0) && tri(t).iter().any(|p| (p[0] - 2.0).abs() + (p[1] - 2.0).abs() <= 1.0)), "no triangle below");
        for &t in &s.targets {
            let x = tri(t);
            assert!(x.iter().all(|p| p[2] == 0.0 || ((p[0] - 2.0).powi(2) + (p[1] - 2.0).powi(2)).sqrt() > 1.5), "own face's triangle {x:?} within 1.5");
        }
    }

    /// The axle's term: the force is the energy's gradient and the Hessian the force's Jacobian
    /// (central differences), nodes beyond d̂ have none, a node inside is a penetration, and a
    /// step towards the axis is cut before the node reaches the axle.
    #[test]
    fn axle_term_derivatives_and_step_limit() {
        let barrier = Barrier { dhat: 0.1, kappa: 2.0 };
        let c = Contact { barrier, blend: 0.01, triangles: Vec::new(), slaves: Vec::new(), faces: Vec::new(), axle: Some(Axle { radius: 2.0, slaves: vec![(0, 0.7), (1, 0.3)] }), planes: Vec::new() };
        c.validate(2).unwrap();
        let pos: [[f64; 3]; 2] = [[1.5, 1.33, 4.0], [5.0, 0.0, 1.0]];
        let gap0 = pos[0][0].hypot(pos[0][1]) - 2.0;
        assert!(gap0 > 0.0 && gap0 < 0.1);
        let (terms, g) = c.terms(&|n| pos[n], true).unwrap();
        assert_eq!(terms.len(), 1, "only the node within d̂ has a term");
        assert!((g - gap0).abs() < 1e-14);
        let t = &terms[0];
        assert_eq!((t.nodes.clone(), t.weight), (vec![0], 0.7));
        let energy = |p: [f64; 3]| c.terms(&|n| if n == 0 { p } else { pos[1] }, false).unwrap().0.first().map_or(0.0, |t| t.energy);
        let force = |p: [f64; 3]| c.terms(&|n| if n == 0 { p } else { pos[1] }, false).unwrap().0[0].force.clone();
        let h = 1e-7;
        for i in 0..3 {
            let (mut a, mut b) = (pos[0], pos[0]);
            a[i] += h;
            b[i] -= h;
            let fd = (energy(a) - energy(b)) / (2.0 * h);
            assert!((fd - t.force[i]).abs() <= 1e-6 * t.force[0].abs().max(1e-12), "force {i}: {fd} vs {}", t.force[i]);
            let (fa, fb) = (force(a), force(b));
            for j in 0..3 {
                let fdj = (fa[j] - fb[j]) / (2.0 * h);
                assert!((fdj - t.hessian[3 * j + i]).abs() <= 1e-5 * t.hessian[0].abs(), "hessian {j}{i}: {fdj} vs {}", t.hessian[3 * j + i]);
            }
        }
        // pushes outwards
        assert!(t.force[0] < 0.0 && t.force[1] < 0.0 && t.force[2] == 0.0, "{:?}", t.force);
        // a node inside the axle is a penetration
        let inside = [[1.0, 1.0, 0.0], pos[1]];
        assert_eq!(c.terms(&|n| inside[n], false).unwrap_err(), Penetration { node: 0 });
        // a straight step of node 1 through the axis is cut at `keep` of the way to the surface
        let dx = [[0.0; 3], [-10.0, 0.0, 0.0]];
        let tmax = c.max_step(&|n| pos[n], &|n| dx[n], 0.8);
        assert!((tmax - 0.8 * 0.3).abs() < 1e-12, "{tmax}");
        // moving outwards or along the axle is not limited
        let out = [[1.0, 1.0, 0.0], [0.0, 0.0, 5.0]];
        assert_eq!(c.max_step(&|n| pos[n], &|n| out[n], 0.8), 1.0);
        assert!((c.min_distance(&|n| pos[n]) - gap0).abs() < 1e-14);
        // a bad radius is refused
        let mut bad = c.clone();
        bad.axle.as_mut().unwrap().radius = -1.0;
        assert!(bad.validate(2).is_err());
    }

    /// A plane through a moving node (a cap's end plate): the force is the energy's gradient in
    /// both the slave and the plane's node, the Hessian the force's Jacobian, a step that would
    /// cross it is cut, and a node behind it is a penetration.
    #[test]
    fn plane_term_derivatives_and_step_limit() {
        let barrier = Barrier { dhat: 0.1, kappa: 2.0 };
        let s3 = 1.0 / 3f64.sqrt();
        let plane = Plane { normal: [s3, -s3, s3], point: Vertex::Node(2), slaves: vec![(0, 0.5), (1, 0.25)] };
        let c = Contact { barrier, blend: 0.01, triangles: Vec::new(), slaves: Vec::new(), faces: Vec::new(), axle: None, planes: vec![plane] };
        c.validate(3).unwrap();
        assert!(c.coupling_groups().contains(&vec![0, 2]));
        let pos: [[f64; 3]; 3] = [[1.0 + 0.03 * s3, 2.0 - 0.03 * s3, 3.0 + 0.03 * s3], [1.0 + s3, 2.0 - s3, 3.0 + s3], [1.0, 2.0, 3.0]];
        let (terms, g) = c.terms(&|n| pos[n], true).unwrap();
        assert_eq!(terms.len(), 1);
        assert!((g - 0.03).abs() < 1e-12, "{g}");
        let t = &terms[0];
        assert_eq!(t.nodes, vec![0, 2]);
        let at = |k: usize, i: usize, h: f64| {
            let mut p = pos;
            p[k][i] += h;
            p
        };
        let energy = |p: [[f64; 3]; 3]| c.terms(&|n| p[n], false).unwrap().0[0].energy;
        let force = |p: [[f64; 3]; 3]| c.terms(&|n| p[n], false).unwrap().0[0].force.clone();
        let h = 1e-7;
        for (slot, k) in [(0, 0usize), (1, 2usize)] {
            for i in 0..3 {
                let fd = (energy(at(k, i, h)) - energy(at(k, i, -h))) / (2.0 * h);
                assert!((fd - t.force[3 * slot + i]).abs() <= 1e-6 * t.force[0].abs(), "force {k}/{i}: {fd} vs {}", t.force[3 * slot + i]);
                let (fa, fb) = (force(at(k, i, h)), force(at(k, i, -h)));
                for j in 0..6 {
                    let fdj = (fa[j] - fb[j]) / (2.0 * h);
                    assert!((fdj - t.hessian[j * 6 + 3 * slot + i]).abs() <= 1e-5 * t.hessian[0].abs(), "hessian {j},{k}/{i}: {fdj} vs {}", t.hessian[j * 6 + 3 * slot + i]);
                }
            }
        }
        // the plane's node moving onto slave 1 (gap 1) is cut at keep of the way
        let dx = [[0.0; 3], [0.0; 3], [2.0 * s3, -2.0 * s3, 2.0 * s3]];
        let tmax = c.max_step(&|n| pos[n], &|n| dx[n], 0.8);
        assert!((tmax - 0.8 * 0.015).abs() < 1e-12, "{tmax}");
        let behind = [pos[2], pos[1], pos[0]];
        assert!(c.terms(&|n| behind[n], false).is_err());
        let mut bad = c.clone();
        bad.planes[0].normal = [1.0, 1.0, 0.0];
        assert!(bad.validate(3).is_err());
    }
}
