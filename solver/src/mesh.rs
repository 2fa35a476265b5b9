//! Mesh data shared by the mesh generators, the exporters and the FE core.
//!
//! Hexahedral elements only (the actuator wall is a structured hex mesh). Node ordering of every
//! element kind follows VTK (`VTK_HEXAHEDRON` = 12, `VTK_QUADRATIC_HEXAHEDRON` = 25,
//! `VTK_TRIQUADRATIC_HEXAHEDRON` = 29); the first 20 nodes of a Hex27 are a Hex20 in the order of
//! CalculiX/Abaqus C3D20, and the first 8 nodes of both are the C3D8 corners.
//!
//! Local natural coordinates (ξ, η, ζ) ∈ [−1, 1]³; corner 0 is (−1,−1,−1), corners 0–3 lie on
//! ζ = −1 counter-clockwise seen from +ζ, corners 4–7 above them.

use std::collections::BTreeMap;

/// Element kinds supported by the FE core.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum ElementKind {
    /// Trilinear 8-node hexahedron.
    Hex8,
    /// Serendipity 20-node hexahedron (corners + edge midpoints).
    Hex20,
    /// Triquadratic 27-node hexahedron (Lagrange Q2).
    Hex27,
}

/// Natural coordinates of the 27 nodes of a triquadratic hex in VTK order. Hex8 uses the first 8,
/// Hex20 the first 20.
pub const HEX27_NATURAL: [[i8; 3]; 27] = [
    [-1, -1, -1],
    [1, -1, -1],
    [1, 1, -1],
    [-1, 1, -1],
    [-1, -1, 1],
    [1, -1, 1],
    [1, 1, 1],
    [-1, 1, 1],
    // edge midpoints: (0,1) (1,2) (2,3) (3,0) (4,5) (5,6) (6,7) (7,4) (0,4) (1,5) (2,6) (3,7)
    [0, -1, -1],
    [1, 0, -1],
    [0, 1, -1],
    [-1, 0, -1],
    [0, -1, 1],
    [1, 0, 1],
    [0, 1, 1],
    [-1, 0, 1],
    [-1, -1, 0],
    [1, -1, 0],
    [1, 1, 0],
    [-1, 1, 0],
    // face centres in VTK order: η=−1, ξ=+1, η=+1, ξ=−1, ζ=−1, ζ=+1
    [0, -1, 0],
    [1, 0, 0],
    [0, 1, 0],
    [-1, 0, 0],
    [0, 0, -1],
    [0, 0, 1],
    // body centre
    [0, 0, 0],
];

impl ElementKind {
    pub fn nodes_per_element(self) -> usize {
        match self {
            ElementKind::Hex8 => 8,
            ElementKind::Hex20 => 20,
            ElementKind::Hex27 => 27,
        }
    }
    /// Polynomial order along an edge (1 or 2).
    pub fn order(self) -> usize {
        match self {
            ElementKind::Hex8 => 1,
            _ => 2,
        }
    }
    pub fn vtk_cell_type(self) -> u8 {
        match self {
            ElementKind::Hex8 => 12,
            ElementKind::Hex20 => 25,
            ElementKind::Hex27 => 29,
        }
    }
    /// CalculiX/Abaqus element name (full integration; Hex27 has no counterpart and is exported
    /// through its first 20 nodes).
    pub fn abaqus_name(self) -> &'static str {
        match self {
            ElementKind::Hex8 => "C3D8",
            ElementKind::Hex20 | ElementKind::Hex27 => "C3D20",
        }
    }
    /// Natural coordinates of the element's nodes.
    pub fn natural_coords(self) -> &'static [[i8; 3]] {
        &HEX27_NATURAL[..self.nodes_per_element()]
    }
    /// Local node indices of one face, ordered so that the parametric normal
    /// (∂x/∂s × ∂x/∂t with the face's own coordinates s, t from [`face_natural`]) points
    /// **out of the element**. Corners first (counter-clockwise seen from outside), then edge
    /// midpoints, then (Hex27) the face centre: 4, 8 or 9 nodes.
    pub fn face_nodes(self, side: Side) -> Vec<usize> {
        let all = face_nodes27(side);
        let n = match self {
            ElementKind::Hex8 => 4,
            ElementKind::Hex20 => 8,
            ElementKind::Hex27 => 9,
        };
        all[..n].to_vec()
    }
}

/// One of the six sides of a hex in natural coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub enum Side {
    XiMinus,
    XiPlus,
    EtaMinus,
    EtaPlus,
    ZetaMinus,
    ZetaPlus,
}

impl Side {
    pub const ALL: [Side; 6] = [Side::XiMinus, Side::XiPlus, Side::EtaMinus, Side::EtaPlus, Side::ZetaMinus, Side::ZetaPlus];
    /// (axis 0..3, sign ±1)
    pub fn axis_sign(self) -> (usize, i8) {
        match self {
            Side::XiMinus => (0, -1),
            Side::XiPlus => (0, 1),
            Side::EtaMinus => (1, -1),
            Side::EtaPlus => (1, 1),
            Side::ZetaMinus => (2, -1),
            Side::ZetaPlus => (2, 1),
        }
    }
    /// Abaqus/CalculiX face label of a C3D8/C3D20 element (S1 = ζ−, S2 = ζ+, S3 = η−, S4 = ξ+,
    /// S5 = η+, S6 = ξ−).
    pub fn abaqus_label(self) -> &'static str {
        match self {
            Side::ZetaMinus => "S1",
            Side::ZetaPlus => "S2",
            Side::EtaMinus => "S3",
            Side::XiPlus => "S4",
            Side::EtaPlus => "S5",
            Side::XiMinus => "S6",
        }
    }
}

/// The face's in-plane natural axes (s, t) as element axes, chosen so that e_s × e_t is the
/// outward direction of the side.
pub fn face_axes(side: Side) -> (usize, usize) {
    // outward +ξ: (η, ζ) since e_η × e_ζ = e_ξ; outward −ξ: (ζ, η).
    match side {
        Side::XiPlus => (1, 2),
        Side::XiMinus => (2, 1),
        Side::EtaPlus => (2, 0),
        Side::EtaMinus => (0, 2),
        Side::ZetaPlus => (0, 1),
        Side::ZetaMinus => (1, 0),
    }
}

/// Natural (s, t) coordinates of the 9 face nodes in the order of [`ElementKind::face_nodes`].
pub const FACE_NATURAL: [[i8; 2]; 9] = [[-1, -1], [1, -1], [1, 1], [-1, 1], [0, -1], [1, 0], [0, 1], [-1, 0], [0, 0]];

fn face_nodes27(side: Side) -> [usize; 9] {
    let (axis, sign) = side.axis_sign();
    let (sa, ta) = face_axes(side);
    let mut out = [0usize; 9];
    for (slot, st) in FACE_NATURAL.iter().enumerate() {
        let mut xi = [0i8; 3];
        xi[axis] = sign;
        xi[sa] = st[0];
        xi[ta] = st[1];
        out[slot] = HEX27_NATURAL.iter().position(|c| *c == xi).expect("face node exists in the 27-node table");
    }
    out
}

/// A face of an element: (element index, side).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub struct Face {
    pub element: usize,
    pub side: Side,
}

/// An unstructured hexahedral mesh with named node and face sets.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Mesh {
    pub nodes: Vec<[f64; 3]>,
    pub kind: ElementKind,
    /// Flat connectivity, `kind.nodes_per_element()` entries per element.
    pub connectivity: Vec<usize>,
    pub node_sets: BTreeMap<String, Vec<usize>>,
    /// Face sets. The orientation of a face is always the outward normal of its element.
    pub face_sets: BTreeMap<String, Vec<Face>>,
}

impl Mesh {
    pub fn n_nodes(&self) -> usize {
        self.nodes.len()
    }
    pub fn n_elements(&self) -> usize {
        self.connectivity.len() / self.kind.nodes_per_element()
    }
    pub fn element(&self, e: usize) -> &[usize] {
        let n = self.kind.nodes_per_element();
        &self.connectivity[e * n..(e + 1) * n]
    }
    /// Global node ids of a face, in the order of [`ElementKind::face_nodes`].
    pub fn face_nodes(&self, f: Face) -> Vec<usize> {
        let el = self.element(f.element);
        self.kind.face_nodes(f.side).into_iter().map(|l| el[l]).collect()
    }
    /// Element node coordinates.
    pub fn element_coords(&self, e: usize) -> Vec<[f64; 3]> {
        self.element(e).iter().map(|&n| self.nodes[n]).collect()
    }
    /// The same mesh with lower-order elements: Hex27 → Hex20 (drops face and body centres) or
    /// Hex27/Hex20 → Hex8 (corners only). Unused nodes are removed and renumbered; node sets are
    /// mapped and face sets are kept.
    pub fn to_kind(&self, kind: ElementKind) -> Mesh {
        assert!(kind.nodes_per_element() <= self.kind.nodes_per_element());
        let npe_old = self.kind.nodes_per_element();
        let npe = kind.nodes_per_element();
        let mut map = vec![usize::MAX; self.nodes.len()];
        let mut nodes = Vec::new();
        let mut connectivity = Vec::with_capacity(self.n_elements() * npe);
        for e in 0..self.n_elements() {
            for &n in &self.connectivity[e * npe_old..e * npe_old + npe] {
                if map[n] == usize::MAX {
                    map[n] = nodes.len();
                    nodes.push(self.nodes[n]);
                }
                connectivity.push(map[n]);
            }
        }
        let node_sets = self.node_sets.iter().map(|(k, v)| (k.clone(), v.iter().filter(|&&n| map[n] != usize::MAX).map(|&n| map[n]).collect())).collect();
        Mesh { nodes, kind, connectivity, node_sets, face_sets: self.face_sets.clone() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn face_node_tables_are_consistent() {
        for side in Side::ALL {
            let nodes = ElementKind::Hex27.face_nodes(side);
            let (axis, sign) = side.axis_sign();
            for &n in &nodes {
                assert_eq!(HEX27_NATURAL[n][axis], sign);
            }
            // corners first, each a hex8 corner
            assert!(nodes[..4].iter().all(|&n| n < 8));
            assert!(nodes[4..8].iter().all(|&n| (8..20).contains(&n)));
            assert!(nodes[8] >= 20);
            // outward orientation: (c1 - c0) × (c3 - c0) has the sign of the side
            let c = |i: usize| {
                let a = HEX27_NATURAL[nodes[i]];
                [a[0] as f64, a[1] as f64, a[2] as f64]
            };
            let a = [c(1)[0] - c(0)[0], c(1)[1] - c(0)[1], c(1)[2] - c(0)[2]];
            let b = [c(3)[0] - c(0)[0], c(3)[1] - c(0)[1], c(3)[2] - c(0)[2]];
            let n = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
            assert!(n[axis] * sign as f64 > 0.0, "{side:?}");
        }
    }
}
