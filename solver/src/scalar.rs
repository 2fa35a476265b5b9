//! Scalar abstraction: element kernels are written once, generic over `f64` and forward-mode dual
//! numbers (`num_dual::Dual64`), so that shape and parameter derivatives of residuals come from the
//! same code as the residual itself.

pub use num_dual::{Dual64, DualNum};

/// A real scalar: `f64` or a dual number over `f64`.
pub trait Scalar: DualNum<Primitive = f64> + Copy + Send + Sync {}
impl<T: DualNum<Primitive = f64> + Copy + Send + Sync> Scalar for T {}

pub type M3<D> = [[D; 3]; 3];

#[inline]
pub fn c<D: Scalar>(v: f64) -> D {
    D::from(v)
}

#[inline]
pub fn det3<D: Scalar>(m: &M3<D>) -> D {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// Inverse of a 3×3 matrix given its determinant.
#[inline]
pub fn inv3<D: Scalar>(m: &M3<D>, det: D) -> M3<D> {
    let r = det.recip();
    [
        [(m[1][1] * m[2][2] - m[1][2] * m[2][1]) * r, (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * r, (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * r],
        [(m[1][2] * m[2][0] - m[1][0] * m[2][2]) * r, (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * r, (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * r],
        [(m[1][0] * m[2][1] - m[1][1] * m[2][0]) * r, (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * r, (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * r],
    ]
}

#[inline]
pub fn cross<D: Scalar>(a: [D; 3], b: [D; 3]) -> [D; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline]
pub fn dot<D: Scalar>(a: [D; 3], b: [D; 3]) -> D {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub fn lift3(v: [f64; 3]) -> [Dual64; 3] {
    [Dual64::from(v[0]), Dual64::from(v[1]), Dual64::from(v[2])]
}

/// Solve a small dense SPD system (n ≤ 8) by Cholesky; returns None if not positive definite.
pub fn small_spd_inverse<D: Scalar>(a: &[D], n: usize) -> Option<Vec<D>> {
    // Gauss–Jordan on the (small) matrix; adequate and generic for duals.
    let mut m: Vec<D> = a.to_vec();
    let mut inv: Vec<D> = (0..n * n).map(|k| if k % (n + 1) == 0 { D::one() } else { D::zero() }).collect();
    for col in 0..n {
        let piv = m[col * n + col];
        if !(piv.re() > 0.0) {
            return None;
        }
        let r = piv.recip();
        for j in 0..n {
            m[col * n + j] = m[col * n + j] * r;
            inv[col * n + j] = inv[col * n + j] * r;
        }
        for i in 0..n {
            if i != col {
                let f = m[i * n + col];
                if f.re() != 0.0 || D::NDERIV > 0 {
                    for j in 0..n {
                        m[i * n + j] = m[i * n + j] - f * m[col * n + j];
                        inv[i * n + j] = inv[i * n + j] - f * inv[col * n + j];
                    }
                }
            }
        }
    }
    Some(inv)
}
