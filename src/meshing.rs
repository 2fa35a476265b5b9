//! Structured hexahedral meshes of the actuator wall (GEOMETRY.md §5).
//!
//! Lattice: N_around × N_along × N_through elements, with (around, along, through) = (ξ, η, ζ)
//! right-handed (around = counter-clockwise, along = +z, through = inner → outer), so every
//! element Jacobian is positive.
//!
//! * **Around**: Na a multiple of 3. Arc-aligned (default): per 120° sector nL =
//!   round((Na/3)·θL/(θL+θN)) element edges (clipped to [1, Na/3 − 1]; all Na/3 when r = R or
//!   when the notch is shorter than [`NOTCH_MIN_SHARE`] of an element, i.e. r within ~0.05 mm of R) go
//!   uniformly (in arc length) on the lobe and the rest on the notch, so nodes fall exactly on the
//!   six curvature jumps; node i = 0 is the start of lobe 0 (junction N2 → L0). Uniform: ŝᵢ = i/Na,
//!   node 0 at the tip of lobe 0. Note: in arc-aligned mode the node distribution depends on nL,
//!   which is piecewise constant in r, so node coordinates are smooth in r only between the
//!   values of r where nL changes (the shape derivatives are exact within such an interval); the
//!   uniform split is smooth everywhere.
//! * **Along**: Nz a multiple of 4, rings at uniform arc length of the profile (ζ = 1/4, 3/4 are
//!   the profile junctions).
//! * **Through**: k = 0 inner … k = Nt outer (η = 1 − k/Nt).
//! * Quadratic elements use the lattice 2Na × (2Nz + 1) × (2Nt + 1) with mid-nodes at the
//!   parameter midpoints (ŝ, arc length ζ, η), so every node lies on the exact geometry.
//!   Hex20 is the Hex27 mesh reduced by [`Mesh::to_kind`].
//!
//! Node numbering (Hex8/Hex27): node = (k·NZ + j)·NA + i over lattice indices (i around, j along,
//! k through).

use std::collections::BTreeMap;

use num_dual::Dual64;
use twistopt_solver::mesh::{ElementKind, Face, Mesh, Side, HEX27_NATURAL};

use crate::geometry::{scalar::cst, Actuator, ActuatorGeometry, GeometryError, Scalar};

/// Mesh presets: (name, N_around, N_along, N_through, element kind), Hex27 (Q2/P1) in the thin
/// wall, chosen by studies/speed-accuracy (`default`: θ, τ within 1 %; `sweep`: Ω within 3 %).
/// `fine` is 60x20x2: on the paper example it moves θ, τ by 0.14 %, 0.2 % from `default`
/// (studies/paper-example); the earlier 96x32x3 (≈ 88 k dofs on the sector) did not finish a
/// 71 kPa ramp in 30 min on 2 cores and is still available as an explicit mesh string.
pub const MESH_PRESETS: &[(&str, usize, usize, usize, ElementKind)] = &[
    ("coarse", 24, 8, 1, ElementKind::Hex27),
    ("default", 48, 16, 2, ElementKind::Hex27),
    ("fine", 60, 20, 2, ElementKind::Hex27),
    // the fastest mesh with Ω within 3 % of the Richardson reference on five designs
    // (studies/speed-accuracy): for grid sweeps
    ("sweep", 48, 16, 1, ElementKind::Hex27),
];

/// Errors of mesh specification and generation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error("mesh: {0}")]
    Spec(String),
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error("mesh: element {element} is inverted (Jacobian determinant {det:.3e} at natural point {at:?}); the geometry/mesh combination is not usable")]
    Inverted { element: usize, det: f64, at: [f64; 3] },
}

/// What mesh to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MeshSpec {
    /// elements around the full circumference (multiple of 3)
    pub n_around: usize,
    /// elements along the height (multiple of 4)
    pub n_along: usize,
    /// elements through the wall (≥ 1)
    pub n_through: usize,
    pub kind: ElementKind,
    /// only the 120° sector i ∈ [0, Na/3) with two cut faces and cyclic node pairs
    pub sector: bool,
    /// arc-aligned split around (nodes on the curvature jumps); default true
    pub arc_aligned: bool,
}

impl Default for MeshSpec {
    fn default() -> Self {
        MeshSpec::preset("default").expect("default preset exists")
    }
}

impl MeshSpec {
    pub fn new(n_around: usize, n_along: usize, n_through: usize, kind: ElementKind) -> Result<Self, MeshError> {
        let s = MeshSpec { n_around, n_along, n_through, kind, sector: false, arc_aligned: true };
        s.validate()?;
        Ok(s)
    }

    /// A named preset (`coarse`, `default`, `fine`).
    pub fn preset(name: &str) -> Result<Self, MeshError> {
        let names: Vec<&str> = MESH_PRESETS.iter().map(|p| p.0).collect();
        MESH_PRESETS
            .iter()
            .find(|p| p.0 == name)
            .map(|&(_, a, z, t, kind)| MeshSpec { n_around: a, n_along: z, n_through: t, kind, sector: false, arc_aligned: true })
            .ok_or_else(|| MeshError::Spec(format!("unknown mesh preset '{name}' (expected one of {} or <Na>x<Nz>x<Nt>, e.g. 48x16x2)", names.join(", "))))
    }

    /// A preset name or an explicit `<Na>x<Nz>x<Nt>` string (quadratic Hex27 by default; change
    /// `kind` afterwards).
    pub fn parse(s: &str) -> Result<Self, MeshError> {
        let t = s.trim();
        if t.contains('x') && t.chars().next().is_some_and(|c| c.is_ascii_digit()) {
            let parts: Vec<&str> = t.split('x').collect();
            let bad = || MeshError::Spec(format!("cannot parse mesh size '{s}' (expected <Na>x<Nz>x<Nt> with positive integers, e.g. 48x16x2)"));
            if parts.len() != 3 {
                return Err(bad());
            }
            let n: Vec<usize> = parts.iter().map(|p| p.parse::<usize>().map_err(|_| bad())).collect::<Result<_, _>>()?;
            let spec = MeshSpec { n_around: n[0], n_along: n[1], n_through: n[2], kind: ElementKind::Hex27, sector: false, arc_aligned: true };
            spec.validate()?;
            Ok(spec)
        } else {
            Self::preset(t)
        }
    }

    pub fn with_kind(mut self, kind: ElementKind) -> Self {
        self.kind = kind;
        self
    }
    pub fn with_sector(mut self, sector: bool) -> Self {
        self.sector = sector;
        self
    }
    pub fn with_arc_aligned(mut self, arc_aligned: bool) -> Self {
        self.arc_aligned = arc_aligned;
        self
    }

    /// Text form `<Na>x<Nz>x<Nt>`.
    pub fn size_string(&self) -> String {
        format!("{}x{}x{}", self.n_around, self.n_along, self.n_through)
    }

    pub fn validate(&self) -> Result<(), MeshError> {
        if self.n_around < 6 || !self.n_around.is_multiple_of(3) {
            return Err(MeshError::Spec(format!("n_around = {} must be a multiple of 3 and at least 6", self.n_around)));
        }
        if self.n_along < 4 || !self.n_along.is_multiple_of(4) {
            return Err(MeshError::Spec(format!("n_along = {} must be a positive multiple of 4 (element faces on the profile junctions)", self.n_along)));
        }
        if self.n_through < 1 {
            return Err(MeshError::Spec("n_through must be at least 1".into()));
        }
        if self.n_around * self.n_along * self.n_through > 1_000_000 {
            return Err(MeshError::Spec(format!("{} elements requested; the limit is 1 000 000", self.n_around * self.n_along * self.n_through)));
        }
        Ok(())
    }

    fn order(&self) -> usize {
        self.kind.order()
    }
    fn lattice_dims(&self) -> [usize; 3] {
        let q = self.order();
        let na = if self.sector { q * self.n_around / 3 + 1 } else { q * self.n_around };
        [na, q * self.n_along + 1, q * self.n_through + 1]
    }
    fn elements_around(&self) -> usize {
        if self.sector {
            self.n_around / 3
        } else {
            self.n_around
        }
    }
}

/// Mesh quality summary.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MeshQuality {
    /// min over elements and evaluation points (corners + Gauss points) of
    /// det J / (|∂x/∂ξ| |∂x/∂η| |∂x/∂ζ|)
    pub min_scaled_jacobian: f64,
    /// element where the minimum occurs
    pub worst_element: usize,
    /// smallest Jacobian determinant (mm³ per unit natural volume)
    pub min_det_jacobian: f64,
    /// number of (element, point) evaluations
    pub points_checked: usize,
}

/// A generated actuator mesh.
#[derive(Clone, Debug)]
pub struct ActuatorMesh {
    pub mesh: Mesh,
    /// sector meshes: (node on cut_start, node on cut_end) with end = Rot(+120°)·start;
    /// empty for a full mesh
    pub cyclic_pairs: Vec<(usize, usize)>,
    pub quality: MeshQuality,
    pub spec: MeshSpec,
}

/// Smallest notch length, in elements of the uniform split, that gets its own element(s) in the
/// arc-aligned split (below it the notch, < 1 % of an element, shares the lobe's last element).
pub const NOTCH_MIN_SHARE: f64 = 0.01;

/// Around-parameters of the lattice (ŝ for each lattice index i).
fn around_shat<D: Scalar>(act: &Actuator<D>, spec: &MeshSpec) -> Vec<D> {
    let q = spec.order();
    let na = spec.n_around;
    let per = na / 3;
    let nlat = spec.lattice_dims()[0];
    if !spec.arc_aligned {
        return (0..nlat).map(|m| cst::<D>(m as f64 / (q * na) as f64)).collect();
    }
    let sec = &act.section;
    let fl = sec.lobe_fraction();
    // a notch shorter than NOTCH_MIN_SHARE of an element gets no element of its own (as at r = R,
    // where it vanishes): otherwise r just below R (e.g. an optimiser's r = R − 1e-15) would give
    // elements of zero width
    let (nl, nn) = if sec.theta_n.re() <= 0.0 || (per as f64) * (1.0 - fl.re()) < NOTCH_MIN_SHARE {
        (per, 0)
    } else {
        let nl = ((per as f64) * fl.re()).round() as usize;
        let nl = nl.clamp(1, per - 1);
        (nl, per - nl)
    };
    // element-boundary position in sector units, measured from the start of lobe 0
    let qpos = |i: usize| -> D {
        let k = i / per;
        let ii = i % per;
        if ii < nl {
            fl * (ii as f64 / nl as f64) + k as f64
        } else {
            fl + (cst::<D>(1.0) - fl) * ((ii - nl) as f64 / nn as f64) + k as f64
        }
    };
    (0..nlat)
        .map(|m| {
            let i = m / q;
            let sub = m % q;
            let a = qpos(i);
            let pos = if sub == 0 {
                a
            } else {
                let b = if i + 1 == na { cst::<D>(3.0) } else { qpos(i + 1) };
                (a + b) * 0.5
            };
            (pos - fl * 0.5) * (1.0 / 3.0)
        })
        .collect()
}

/// Lattice node coordinates (Hex8 / Hex27 lattice) for any scalar type.
fn lattice_coords<D: Scalar>(act: &Actuator<D>, spec: &MeshSpec) -> Vec<[D; 3]> {
    let [na, nz, nk] = spec.lattice_dims();
    let shat = around_shat(act, spec);
    let zs: Vec<D> = (0..nz).map(|j| act.profile.at_arclength(j as f64 / (nz - 1) as f64).0).collect();
    let mut out = Vec::with_capacity(na * nz * nk);
    if act.needs_trim() {
        // geometry variants whose wall is trimmed by the end planes (end tangent, twist first)
        for k in 0..nk {
            let eta = cst::<D>(1.0 - k as f64 / (nk - 1) as f64);
            let shifts: Vec<(D, D)> = shat.iter().map(|s| act.trim_shifts(*s, eta)).collect();
            for z in zs.iter() {
                for (s, sh) in shat.iter().zip(&shifts) {
                    out.push(act.wall_point_with(*s, *z, eta, *sh));
                }
            }
        }
        return out;
    }
    for k in 0..nk {
        let eta = cst::<D>(1.0 - k as f64 / (nk - 1) as f64);
        for z in zs.iter() {
            for s in shat.iter() {
                out.push(act.point(*s, *z, eta));
            }
        }
    }
    out
}

/// Hex8 or Hex27 topology on the lattice, plus sets and cyclic pairs.
fn lattice_topology(spec: &MeshSpec) -> (ElementKind, Vec<usize>, BTreeMap<String, Vec<usize>>, BTreeMap<String, Vec<Face>>, Vec<(usize, usize)>) {
    let lat_kind = if spec.kind == ElementKind::Hex8 { ElementKind::Hex8 } else { ElementKind::Hex27 };
    let q = spec.order();
    let [na, nz, nk] = spec.lattice_dims();
    let idx = |i: usize, j: usize, k: usize| (k * nz + j) * na + i;
    let ne_a = spec.elements_around();
    let (ne_z, ne_t) = (spec.n_along, spec.n_through);
    let npe = lat_kind.nodes_per_element();
    let mut conn = Vec::with_capacity(ne_a * ne_z * ne_t * npe);
    let mut faces: BTreeMap<String, Vec<Face>> = BTreeMap::new();
    let mut e = 0usize;
    for ek in 0..ne_t {
        for ej in 0..ne_z {
            for ei in 0..ne_a {
                for nat in &HEX27_NATURAL[..npe] {
                    let off = |a: i8| (q * (a + 1) as usize) / 2;
                    let mut i = q * ei + off(nat[0]);
                    if !spec.sector {
                        i %= na;
                    }
                    conn.push(idx(i, q * ej + off(nat[1]), q * ek + off(nat[2])));
                }
                let mut add = |name: &str, side: Side| {
                    faces.entry(name.to_string()).or_default().push(Face { element: e, side });
                };
                if ek == 0 {
                    add("cavity", Side::ZetaMinus);
                }
                if ek == ne_t - 1 {
                    add("outer", Side::ZetaPlus);
                }
                if ej == 0 {
                    add("bottom", Side::EtaMinus);
                }
                if ej == ne_z - 1 {
                    add("top", Side::EtaPlus);
                }
                if spec.sector && ei == 0 {
                    add("cut_start", Side::XiMinus);
                }
                if spec.sector && ei == ne_a - 1 {
                    add("cut_end", Side::XiPlus);
                }
                e += 1;
            }
        }
    }
    let mut nsets: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut pairs = Vec::new();
    for k in 0..nk {
        for j in 0..nz {
            for i in 0..na {
                let n = idx(i, j, k);
                if j == 0 {
                    nsets.entry("bottom".into()).or_default().push(n);
                }
                if j == nz - 1 {
                    nsets.entry("top".into()).or_default().push(n);
                }
                if k == 0 {
                    nsets.entry("cavity".into()).or_default().push(n);
                }
                if k == nk - 1 {
                    nsets.entry("outer".into()).or_default().push(n);
                }
                if spec.sector && i == 0 {
                    nsets.entry("cut_start".into()).or_default().push(n);
                    pairs.push((n, idx(na - 1, j, k)));
                }
                if spec.sector && i == na - 1 {
                    nsets.entry("cut_end".into()).or_default().push(n);
                }
            }
        }
    }
    for v in nsets.values_mut() {
        v.sort_unstable();
    }
    (lat_kind, conn, nsets, faces, pairs)
}

/// Node renumbering of [`Mesh::to_kind`] (first appearance in the reduced connectivity).
fn reduction_map(mesh: &Mesh, kind: ElementKind) -> Vec<usize> {
    let npe_old = mesh.kind.nodes_per_element();
    let npe = kind.nodes_per_element();
    let mut map = vec![usize::MAX; mesh.nodes.len()];
    let mut next = 0;
    for e in 0..mesh.n_elements() {
        for &n in &mesh.connectivity[e * npe_old..e * npe_old + npe] {
            if map[n] == usize::MAX {
                map[n] = next;
                next += 1;
            }
        }
    }
    map
}

/// The smallest minimum scaled Jacobian a freeform design's mesh may have (the letter's designs
/// at Table I's extremes have ≥ 0.17 on the coarse mesh, 0.45 at the paper example); a freeform
/// shape whose elements are more distorted is refused rather than solved on a poor mesh.
pub const FREEFORM_MIN_SCALED_JACOBIAN: f64 = 0.1;

/// Build the mesh for a validated geometry.
pub fn build_mesh(geom: &ActuatorGeometry, spec: &MeshSpec) -> Result<ActuatorMesh, MeshError> {
    spec.validate()?;
    let nodes = lattice_coords(&geom.act, spec);
    let (lat_kind, connectivity, node_sets, face_sets, pairs) = lattice_topology(spec);
    let mut mesh = Mesh { nodes, kind: lat_kind, connectivity, node_sets, face_sets };
    let mut cyclic_pairs = pairs;
    if spec.kind == ElementKind::Hex20 {
        let map = reduction_map(&mesh, ElementKind::Hex20);
        mesh = mesh.to_kind(ElementKind::Hex20);
        cyclic_pairs = cyclic_pairs.into_iter().filter(|(a, b)| map[*a] != usize::MAX && map[*b] != usize::MAX).map(|(a, b)| (map[a], map[b])).collect();
    }
    let quality = mesh_quality(&mesh)?;
    if geom.act.is_freeform() && quality.min_scaled_jacobian < FREEFORM_MIN_SCALED_JACOBIAN {
        return Err(MeshError::Spec(format!(
            "the freeform design's mesh {} has a minimum scaled Jacobian {:.3} (element {}), below the floor {FREEFORM_MIN_SCALED_JACOBIAN} for freeform shapes: the twist law or profile varies too fast for this mesh (reduce twist_*_deg / profile_*_mm, or refine the mesh)",
            spec.size_string(),
            quality.min_scaled_jacobian,
            quality.worst_element
        )));
    }
    Ok(ActuatorMesh { mesh, cyclic_pairs, quality, spec: *spec })
}

/// The least scaled Jacobian of a geometry's mesh, as [`mesh_quality`] measures it (the corners
/// and Gauss points of every element), with its derivative w.r.t. each of `names` (design
/// parameters, in design units; 0 for a name the design does not have) at the minimising element
/// and point (the minimum is not smooth where two elements tie; its gradient there is one of
/// theirs). No floor is applied: a freeform mesh that [`build_mesh`] refuses has one too.
pub fn min_scaled_jacobian_sensitivity(geom: &ActuatorGeometry, spec: &MeshSpec, names: &[String]) -> Result<(f64, Vec<f64>), MeshError> {
    spec.validate()?;
    let nodes = lattice_coords(&geom.act, spec);
    let (lat_kind, connectivity, node_sets, face_sets, _) = lattice_topology(spec);
    let mut mesh = Mesh { nodes, kind: lat_kind, connectivity, node_sets, face_sets };
    if spec.kind == ElementKind::Hex20 {
        mesh = mesh.to_kind(ElementKind::Hex20);
    }
    let pts = quality_points(mesh.kind);
    let grads: Vec<Vec<[f64; 3]>> = pts.iter().map(|p| shape_gradients(mesh.kind, *p)).collect();
    let (mut sj_min, mut at) = (f64::INFINITY, (0usize, 0usize));
    let mut coords = Vec::with_capacity(27);
    for e in 0..mesh.n_elements() {
        coords.clear();
        coords.extend(mesh.element(e).iter().map(|&n| mesh.nodes[n]));
        for (k, g) in grads.iter().enumerate() {
            let sj = scaled_jacobian(&coords, g);
            if !sj.is_finite() {
                return Err(MeshError::Spec(format!("element {e}: non-finite Jacobian at a quality point")));
            }
            if sj < sj_min {
                (sj_min, at) = (sj, (e, k));
            }
        }
    }
    let derivs = mesh_shape_derivatives(geom, spec)?;
    let conn = mesh.element(at.0);
    let d = names
        .iter()
        .map(|name| match derivs.iter().find(|(n, _)| n == name) {
            None => 0.0,
            Some((_, dx)) => {
                let c: Vec<[Dual64; 3]> = conn.iter().map(|&n| std::array::from_fn(|r| Dual64::new(mesh.nodes[n][r], dx[n][r]))).collect();
                scaled_jacobian(&c, &grads[at.1]).eps
            }
        })
        .collect();
    Ok((sj_min, d))
}

/// det J / (|J₁| |J₂| |J₃|) of an element at a natural point (shape gradients `grads`), for any
/// scalar (dual numbers give its derivative along a node motion).
fn scaled_jacobian<D: Scalar>(coords: &[[D; 3]], grads: &[[f64; 3]]) -> D {
    let z = cst::<D>(0.0);
    let mut j = [[z; 3]; 3];
    for (x, g) in coords.iter().zip(grads) {
        for c in 0..3 {
            for r in 0..3 {
                j[c][r] = j[c][r] + x[r] * g[c];
            }
        }
    }
    let [a, b, c] = j;
    let det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
    let n = |v: &[D; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    det / (n(&a) * n(&b) * n(&c))
}

/// dX/dp for every node and every named design parameter (same numbering as [`build_mesh`]),
/// from forward-mode dual numbers. α (and end-tangent) derivatives are per degree (the design
/// unit). The parameters are the design's ([`crate::geometry::Design::parameter_names`]: Table I
/// plus the optional ones it carries).
pub fn mesh_shape_derivatives(geom: &ActuatorGeometry, spec: &MeshSpec) -> Result<Vec<(String, Vec<[f64; 3]>)>, MeshError> {
    spec.validate()?;
    let mut out = Vec::new();
    let map = if spec.kind == ElementKind::Hex20 {
        let (lat_kind, connectivity, _, _, _) = lattice_topology(spec);
        let n = spec.lattice_dims().iter().product();
        let tmp = Mesh { nodes: vec![[0.0; 3]; n], kind: lat_kind, connectivity, node_sets: BTreeMap::new(), face_sets: BTreeMap::new() };
        Some(reduction_map(&tmp, ElementKind::Hex20))
    } else {
        None
    };
    for name in geom.design.parameter_names() {
        let act: Actuator<Dual64> = geom.dual_actuator(&name)?;
        let lat = lattice_coords(&act, spec);
        let d: Vec<[f64; 3]> = lat.iter().map(|p| [p[0].eps, p[1].eps, p[2].eps]).collect();
        let d = match &map {
            None => d,
            Some(map) => {
                let n = map.iter().filter(|&&m| m != usize::MAX).count();
                let mut r = vec![[0.0; 3]; n];
                for (old, &new) in map.iter().enumerate() {
                    if new != usize::MAX {
                        r[new] = d[old];
                    }
                }
                r
            }
        };
        out.push((name, d));
    }
    Ok(out)
}

/// Derivatives (∂N/∂ξ, ∂N/∂η, ∂N/∂ζ) of the element shape functions at a natural point.
pub fn shape_gradients(kind: ElementKind, xi: [f64; 3]) -> Vec<[f64; 3]> {
    twistopt_solver::shape::hex_shape(kind, xi).1
}

/// Natural points where the Jacobian is checked: the 8 corners plus the Gauss points
/// (2×2×2 for Hex8, 3×3×3 for quadratic elements).
pub fn quality_points(kind: ElementKind) -> Vec<[f64; 3]> {
    let mut pts: Vec<[f64; 3]> = HEX27_NATURAL[..8].iter().map(|a| [a[0] as f64, a[1] as f64, a[2] as f64]).collect();
    let g: Vec<f64> = if kind == ElementKind::Hex8 { vec![-1.0 / 3f64.sqrt(), 1.0 / 3f64.sqrt()] } else { vec![-(0.6f64).sqrt(), 0.0, 0.6f64.sqrt()] };
    for &a in &g {
        for &b in &g {
            for &c in &g {
                pts.push([a, b, c]);
            }
        }
    }
    pts
}

/// Jacobian matrix columns (∂x/∂ξ, ∂x/∂η, ∂x/∂ζ) of an element at a natural point.
pub fn jacobian_columns(coords: &[[f64; 3]], grads: &[[f64; 3]]) -> [[f64; 3]; 3] {
    let mut j = [[0.0; 3]; 3];
    for (x, g) in coords.iter().zip(grads) {
        for c in 0..3 {
            for r in 0..3 {
                j[c][r] += x[r] * g[c];
            }
        }
    }
    j
}

fn det3(j: &[[f64; 3]; 3]) -> f64 {
    let [a, b, c] = j;
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])
}

/// Per element: (min scaled Jacobian, min Jacobian determinant, natural point of the minimum
/// determinant) over the corners and Gauss points of [`quality_points`].
pub fn element_jacobian_extremes(mesh: &Mesh) -> Vec<(f64, f64, [f64; 3])> {
    let pts = quality_points(mesh.kind);
    let grads: Vec<Vec<[f64; 3]>> = pts.iter().map(|p| shape_gradients(mesh.kind, *p)).collect();
    let mut coords = Vec::with_capacity(27);
    let norm = |v: &[f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (0..mesh.n_elements())
        .map(|e| {
            coords.clear();
            coords.extend(mesh.element(e).iter().map(|&n| mesh.nodes[n]));
            let mut out = (f64::INFINITY, f64::INFINITY, pts[0]);
            for (p, g) in pts.iter().zip(&grads) {
                let j = jacobian_columns(&coords, g);
                let det = det3(&j);
                let sj = det / (norm(&j[0]) * norm(&j[1]) * norm(&j[2]));
                // NaN-safe: a NaN determinant or scaled Jacobian counts as inverted
                let sj = if sj.is_finite() { sj } else { f64::NEG_INFINITY };
                let det = if det.is_finite() { det } else { f64::NEG_INFINITY };
                out.0 = out.0.min(sj);
                if det < out.1 {
                    out.1 = det;
                    out.2 = *p;
                }
            }
            out
        })
        .collect()
}

/// Minimum scaled Jacobian of every element (cell data for exports).
pub fn element_scaled_jacobians(mesh: &Mesh) -> Vec<f64> {
    element_jacobian_extremes(mesh).into_iter().map(|x| x.0).collect()
}

/// Quality report; any non-positive (or non-finite) Jacobian determinant is an error.
pub fn mesh_quality(mesh: &Mesh) -> Result<MeshQuality, MeshError> {
    let per = element_jacobian_extremes(mesh);
    let npts = quality_points(mesh.kind).len();
    let mut q = MeshQuality { min_scaled_jacobian: f64::INFINITY, worst_element: 0, min_det_jacobian: f64::INFINITY, points_checked: per.len() * npts };
    for (e, &(sj, det, at)) in per.iter().enumerate() {
        if !(det > 0.0) || !(sj > 0.0) {
            return Err(MeshError::Inverted { element: e, det, at });
        }
        if sj < q.min_scaled_jacobian {
            q.min_scaled_jacobian = sj;
            q.worst_element = e;
        }
        q.min_det_jacobian = q.min_det_jacobian.min(det);
    }
    if per.is_empty() {
        return Err(MeshError::Spec("mesh has no elements".into()));
    }
    Ok(q)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_gradients_reproduce_affine_map_for_all_kinds() {
        // an affine map x = A ξ + b must give J = A exactly at any point, for every element kind
        let a = [[2.0, 0.3, -0.1], [0.1, 1.5, 0.2], [-0.2, 0.4, 0.7]];
        for kind in [ElementKind::Hex8, ElementKind::Hex20, ElementKind::Hex27] {
            let coords: Vec<[f64; 3]> = kind
                .natural_coords()
                .iter()
                .map(|n| {
                    let xi = [n[0] as f64, n[1] as f64, n[2] as f64];
                    [0, 1, 2].map(|r| a[r][0] * xi[0] + a[r][1] * xi[1] + a[r][2] * xi[2] + 1.0)
                })
                .collect();
            for p in quality_points(kind).into_iter().chain([[0.3, -0.7, 0.1]]) {
                let g = shape_gradients(kind, p);
                let sum: [f64; 3] = [0, 1, 2].map(|c| g.iter().map(|v| v[c]).sum());
                assert!(sum.iter().all(|s| s.abs() < 1e-13), "{kind:?}: partition of unity");
                let j = jacobian_columns(&coords, &g);
                for c in 0..3 {
                    for r in 0..3 {
                        assert!((j[c][r] - a[r][c]).abs() < 1e-13, "{kind:?} at {p:?}");
                    }
                }
                assert!((det3(&j) - det3(&a)).abs() < 1e-12, "det J = det A");
            }
        }
    }

    /// r just below R (an optimiser at the r bound: R − 1e-15 …) meshes like r = R instead of
    /// giving the vanishing notch zero-width elements; r a little further away keeps its notch.
    #[test]
    fn r_just_below_r_tube_meshes_like_the_circle() {
        use crate::geometry::{Design, RangePolicy};
        for preset in ["coarse", "default"] {
            let spec = MeshSpec::preset(preset).unwrap().with_sector(true);
            let at = |r: f64| build_mesh(&ActuatorGeometry::new(&Design::new(r, 19.3184, 360.0), RangePolicy::TableI).unwrap(), &spec);
            let circle = at(20.0).unwrap();
            for r in [20.0 - 4e-15, 20.0 - 1e-13, 20.0 - 1e-9, 19.999] {
                let m = at(r).unwrap_or_else(|e| panic!("{preset}, r = {r}: {e}"));
                assert!(m.quality.min_scaled_jacobian > 0.5 * circle.quality.min_scaled_jacobian, "{preset}, r = {r}: {:?}", m.quality);
                let d = m.mesh.nodes.iter().zip(&circle.mesh.nodes).map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f64::max)).fold(0.0, f64::max);
                assert!(d < 1e-2, "{preset}, r = {r}: nodes moved by {d} mm");
            }
            // r = 19.9: the notch is several % of an element and keeps its own element
            assert!(at(19.9).is_ok());
        }
    }

    #[test]
    fn inverted_element_is_an_error() {
        let coords: Vec<[f64; 3]> = HEX27_NATURAL[..8].iter().map(|n| [n[0] as f64, n[1] as f64, -(n[2] as f64)]).collect();
        let mesh = Mesh { nodes: coords, kind: ElementKind::Hex8, connectivity: (0..8).collect(), node_sets: BTreeMap::new(), face_sets: BTreeMap::new() };
        let e = mesh_quality(&mesh).unwrap_err();
        assert!(matches!(e, MeshError::Inverted { element: 0, .. }), "{e}");
        let mut ok = mesh.clone();
        ok.nodes.iter_mut().for_each(|p| p[2] = -p[2]);
        let q = mesh_quality(&ok).unwrap();
        assert!((q.min_scaled_jacobian - 1.0).abs() < 1e-14);
    }
}
