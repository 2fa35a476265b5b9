//! Shape functions and Gauss quadrature for hexahedra and their quadrilateral faces.

use crate::mesh::{ElementKind, FACE_NATURAL, HEX27_NATURAL};

/// 1-D Gauss–Legendre points and weights on [−1, 1] for n = 1, 2, 3, 4.
pub fn gauss_1d(n: usize) -> (Vec<f64>, Vec<f64>) {
    match n {
        1 => (vec![0.0], vec![2.0]),
        2 => {
            let a = 1.0 / 3f64.sqrt();
            (vec![-a, a], vec![1.0, 1.0])
        }
        3 => {
            let a = (0.6f64).sqrt();
            (vec![-a, 0.0, a], vec![5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0])
        }
        4 => {
            let a = (3.0 / 7.0 - 2.0 / 7.0 * (6.0f64 / 5.0).sqrt()).sqrt();
            let b = (3.0 / 7.0 + 2.0 / 7.0 * (6.0f64 / 5.0).sqrt()).sqrt();
            let wa = (18.0 + 30f64.sqrt()) / 36.0;
            let wb = (18.0 - 30f64.sqrt()) / 36.0;
            (vec![-b, -a, a, b], vec![wb, wa, wa, wb])
        }
        _ => panic!("gauss_1d: n = {n} not tabulated (1..=4)"),
    }
}

/// Tensor-product Gauss rule on the cube: points and weights.
pub fn gauss_hex(n: usize) -> Vec<([f64; 3], f64)> {
    let (x, w) = gauss_1d(n);
    let mut out = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                out.push(([x[i], x[j], x[k]], w[i] * w[j] * w[k]));
            }
        }
    }
    out
}

/// Tensor-product Gauss rule on the square.
pub fn gauss_quad(n: usize) -> Vec<([f64; 2], f64)> {
    let (x, w) = gauss_1d(n);
    let mut out = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            out.push(([x[i], x[j]], w[i] * w[j]));
        }
    }
    out
}

/// 1-D Lagrange basis on nodes {−1, 0, 1} (quadratic) and its derivative, for node position `a`.
#[inline]
fn lag2(a: i8, x: f64) -> (f64, f64) {
    match a {
        -1 => (0.5 * x * (x - 1.0), x - 0.5),
        0 => (1.0 - x * x, -2.0 * x),
        _ => (0.5 * x * (x + 1.0), x + 0.5),
    }
}

/// 1-D linear basis on nodes {−1, 1}.
#[inline]
fn lag1(a: i8, x: f64) -> (f64, f64) {
    let s = a as f64;
    (0.5 * (1.0 + s * x), 0.5 * s)
}

/// Values and natural derivatives of the element's shape functions at ξ.
/// Returns (N[a], dN[a][0..3]).
pub fn hex_shape(kind: ElementKind, xi: [f64; 3]) -> (Vec<f64>, Vec<[f64; 3]>) {
    let nn = kind.nodes_per_element();
    let mut n = vec![0.0; nn];
    let mut dn = vec![[0.0; 3]; nn];
    match kind {
        ElementKind::Hex8 | ElementKind::Hex27 => {
            let f = if kind == ElementKind::Hex8 { lag1 } else { lag2 };
            for a in 0..nn {
                let c = HEX27_NATURAL[a];
                let (l0, d0) = f(c[0], xi[0]);
                let (l1, d1) = f(c[1], xi[1]);
                let (l2, d2) = f(c[2], xi[2]);
                n[a] = l0 * l1 * l2;
                dn[a] = [d0 * l1 * l2, l0 * d1 * l2, l0 * l1 * d2];
            }
        }
        ElementKind::Hex20 => {
            for a in 0..nn {
                let c = HEX27_NATURAL[a];
                let (x, y, z) = (xi[0], xi[1], xi[2]);
                let (a0, a1, a2) = (c[0] as f64, c[1] as f64, c[2] as f64);
                if a < 8 {
                    let (p, q, r) = (1.0 + a0 * x, 1.0 + a1 * y, 1.0 + a2 * z);
                    let s = a0 * x + a1 * y + a2 * z - 2.0;
                    n[a] = 0.125 * p * q * r * s;
                    dn[a] = [0.125 * a0 * q * r * (s + p), 0.125 * a1 * p * r * (s + q), 0.125 * a2 * p * q * (s + r)];
                } else {
                    // one natural coordinate is 0 on this edge
                    let f = |ci: f64, v: f64| {
                        if ci == 0.0 {
                            (1.0 - v * v, -2.0 * v)
                        } else {
                            (0.5 * (1.0 + ci * v), 0.5 * ci)
                        }
                    };
                    let (l0, d0) = f(a0, x);
                    let (l1, d1) = f(a1, y);
                    let (l2, d2) = f(a2, z);
                    n[a] = l0 * l1 * l2;
                    dn[a] = [d0 * l1 * l2, l0 * d1 * l2, l0 * l1 * d2];
                }
            }
        }
    }
    (n, dn)
}

/// Shape functions of a face (4, 8 or 9 nodes, in the order of `ElementKind::face_nodes`).
pub fn face_shape(nf: usize, st: [f64; 2]) -> (Vec<f64>, Vec<[f64; 2]>) {
    let mut n = vec![0.0; nf];
    let mut dn = vec![[0.0; 2]; nf];
    for a in 0..nf {
        let c = FACE_NATURAL[a];
        match nf {
            4 | 9 => {
                let f = if nf == 4 { lag1 } else { lag2 };
                let (l0, d0) = f(c[0], st[0]);
                let (l1, d1) = f(c[1], st[1]);
                n[a] = l0 * l1;
                dn[a] = [d0 * l1, l0 * d1];
            }
            8 => {
                let (x, y) = (st[0], st[1]);
                let (a0, a1) = (c[0] as f64, c[1] as f64);
                if a < 4 {
                    let (p, q) = (1.0 + a0 * x, 1.0 + a1 * y);
                    let s = a0 * x + a1 * y - 1.0;
                    n[a] = 0.25 * p * q * s;
                    dn[a] = [0.25 * a0 * q * (s + p), 0.25 * a1 * p * (s + q)];
                } else {
                    let f = |ci: f64, v: f64| {
                        if ci == 0.0 {
                            (1.0 - v * v, -2.0 * v)
                        } else {
                            (0.5 * (1.0 + ci * v), 0.5 * ci)
                        }
                    };
                    let (l0, d0) = f(a0, x);
                    let (l1, d1) = f(a1, y);
                    n[a] = l0 * l1;
                    dn[a] = [d0 * l1, l0 * d1];
                }
            }
            _ => panic!("face_shape: {nf} nodes"),
        }
    }
    (n, dn)
}

/// Default quadrature order (points per direction) for an element kind.
pub fn default_gauss(kind: ElementKind) -> usize {
    match kind {
        ElementKind::Hex8 => 2,
        _ => 3,
    }
}

/// Precomputed shape data at the quadrature points of an element kind.
#[derive(Clone, Debug)]
pub struct HexRule {
    pub kind: ElementKind,
    pub points: Vec<[f64; 3]>,
    pub weights: Vec<f64>,
    pub n: Vec<Vec<f64>>,
    pub dn: Vec<Vec<[f64; 3]>>,
}

impl HexRule {
    pub fn new(kind: ElementKind, ngauss: usize) -> Self {
        let rule = gauss_hex(ngauss);
        let mut points = Vec::new();
        let mut weights = Vec::new();
        let mut n = Vec::new();
        let mut dn = Vec::new();
        for (p, w) in rule {
            let (a, b) = hex_shape(kind, p);
            points.push(p);
            weights.push(w);
            n.push(a);
            dn.push(b);
        }
        HexRule { kind, points, weights, n, dn }
    }
}

/// Precomputed face shape data.
#[derive(Clone, Debug)]
pub struct FaceRule {
    pub nf: usize,
    pub weights: Vec<f64>,
    pub n: Vec<Vec<f64>>,
    pub dn: Vec<Vec<[f64; 2]>>,
}

impl FaceRule {
    pub fn new(nf: usize, ngauss: usize) -> Self {
        let rule = gauss_quad(ngauss);
        let mut weights = Vec::new();
        let mut n = Vec::new();
        let mut dn = Vec::new();
        for (p, w) in rule {
            let (a, b) = face_shape(nf, p);
            weights.push(w);
            n.push(a);
            dn.push(b);
        }
        FaceRule { nf, weights, n, dn }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partition_of_unity_and_kronecker() {
        for kind in [ElementKind::Hex8, ElementKind::Hex20, ElementKind::Hex27] {
            for (a, c) in kind.natural_coords().iter().enumerate() {
                let xi = [c[0] as f64, c[1] as f64, c[2] as f64];
                let (n, _) = hex_shape(kind, xi);
                for (b, v) in n.iter().enumerate() {
                    let e = if a == b { 1.0 } else { 0.0 };
                    assert!((v - e).abs() < 1e-14, "{kind:?} {a} {b}");
                }
            }
            let (n, dn) = hex_shape(kind, [0.3, -0.2, 0.7]);
            assert!((n.iter().sum::<f64>() - 1.0).abs() < 1e-14);
            for d in 0..3 {
                assert!(dn.iter().map(|g| g[d]).sum::<f64>().abs() < 1e-13);
            }
            // derivative check
            let h = 1e-6;
            for d in 0..3 {
                let mut xp = [0.3, -0.2, 0.7];
                let mut xm = xp;
                xp[d] += h;
                xm[d] -= h;
                let (np, _) = hex_shape(kind, xp);
                let (nm, _) = hex_shape(kind, xm);
                for a in 0..n.len() {
                    assert!(((np[a] - nm[a]) / (2.0 * h) - dn[a][d]).abs() < 1e-8);
                }
            }
        }
        for nf in [4, 8, 9] {
            let (n, dn) = face_shape(nf, [0.1, -0.6]);
            assert!((n.iter().sum::<f64>() - 1.0).abs() < 1e-14);
            let h = 1e-6;
            for d in 0..2 {
                let mut p = [0.1, -0.6];
                let mut m = p;
                p[d] += h;
                m[d] -= h;
                let (np, _) = face_shape(nf, p);
                let (nm, _) = face_shape(nf, m);
                for a in 0..nf {
                    assert!(((np[a] - nm[a]) / (2.0 * h) - dn[a][d]).abs() < 1e-8);
                }
            }
            for (a, c) in FACE_NATURAL[..nf].iter().enumerate() {
                let (n, _) = face_shape(nf, [c[0] as f64, c[1] as f64]);
                assert!((n[a] - 1.0).abs() < 1e-14);
            }
        }
    }
}
