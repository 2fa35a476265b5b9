//! Scalar abstraction for the geometry: every formula is written once, generic over
//! `num_dual` numbers, so that `f64` gives values and `Dual64` gives derivatives with respect to
//! any design parameter (forward mode).

/// A real number or a forward-mode dual number over `f64` (the solver's scalar abstraction, so
/// geometry and FE kernels differentiate with the same number types).
pub use twistopt_solver::scalar::Scalar;

/// Constant as a scalar.
#[inline]
pub fn cst<D: Scalar>(x: f64) -> D {
    D::from(x)
}

/// Real part.
#[inline]
pub fn re<D: Scalar>(x: D) -> f64 {
    x.re()
}

/// sin(x)/x, smooth at 0 (Taylor series for small |x|).
pub fn sinc<D: Scalar>(x: D) -> D {
    if x.re().abs() < 1e-3 {
        let x2 = x * x;
        // 1 - x²/6 + x⁴/120 - x⁶/5040 (error < 1e-22 for |x| < 1e-3)
        cst::<D>(1.0) - x2 * (cst::<D>(1.0 / 6.0) - x2 * (cst::<D>(1.0 / 120.0) - x2 * (1.0 / 5040.0)))
    } else {
        x.sin() / x
    }
}

/// (1 − cos x)/x, smooth and odd at 0.
pub fn versinc<D: Scalar>(x: D) -> D {
    let h = x * 0.5;
    h.sin() * sinc(h)
}

/// atan2(y, x) whose derivative part stays finite at x = 0 (num-dual's `atan2` differentiates
/// atan(y/x)): atan of the ratio of magnitude ≤ 1, with the quadrant added.
pub fn atan2<D: Scalar>(y: D, x: D) -> D {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (yr, xr) = (y.re(), x.re());
    if xr.abs() >= yr.abs() {
        if xr == 0.0 {
            return cst(0.0);
        }
        let a = (y / x).atan();
        if xr > 0.0 {
            a
        } else if yr >= 0.0 {
            a + PI
        } else {
            a - PI
        }
    } else {
        let a = (x / y).atan();
        if yr > 0.0 {
            -a + FRAC_PI_2
        } else {
            -a - FRAC_PI_2
        }
    }
}

/// 2-vector helpers.
#[inline]
pub fn dot2<D: Scalar>(a: [D; 2], b: [D; 2]) -> D {
    a[0] * b[0] + a[1] * b[1]
}

/// Rotate a 2-vector by the angle whose (cos, sin) are given.
#[inline]
pub fn rot2<D: Scalar>(v: [D; 2], c: D, s: D) -> [D; 2] {
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

/// Gauss–Legendre nodes and weights on [-1, 1] (Newton iteration on P_n; accurate to ~1e-15).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    let m = n.div_ceil(2);
    for i in 0..m {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut pp = 0.0;
        for _ in 0..100 {
            let mut p1 = 1.0;
            let mut p2 = 0.0;
            for j in 0..n {
                let p3 = p2;
                p2 = p1;
                p1 = ((2 * j + 1) as f64 * z * p2 - j as f64 * p3) / (j + 1) as f64;
            }
            pp = n as f64 * (z * p1 - p2) / (z * z - 1.0);
            let z1 = z;
            z = z1 - p1 / pp;
            if (z - z1).abs() < 1e-16 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * pp * pp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

    #[test]
    fn gauss_legendre_integrates_polynomials_and_cosine() {
        let (x, w) = gauss_legendre(20);
        let s: f64 = w.iter().sum();
        assert!((s - 2.0).abs() < 1e-14);
        let i4: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(4)).sum();
        assert!((i4 - 0.4).abs() < 1e-14);
        let ic: f64 = x.iter().zip(&w).map(|(x, w)| w * x.cos()).sum();
        assert!((ic - 2.0 * 1f64.sin()).abs() < 1e-14);
    }

    #[test]
    fn sinc_and_versinc_match_closed_forms_and_derivatives() {
        for &x in &[1e-6f64, 1e-4, 5e-4, 2e-3, 0.3, 1.2] {
            assert!((sinc(x) - x.sin() / x).abs() < 1e-15);
            let vs_ref = if x < 1e-2 { x / 2.0 - x.powi(3) / 24.0 + x.powi(5) / 720.0 } else { (1.0 - x.cos()) / x };
            assert!((versinc(x) - vs_ref).abs() < 1e-15, "versinc({x})");
            let d = sinc(Dual64::new(x, 1.0)).eps;
            let exact = (x * x.cos() - x.sin()) / (x * x);
            if x > 1e-2 {
                assert!((d - exact).abs() < 1e-12);
            } else {
                assert!((d + x / 3.0).abs() < 1e-9);
            }
        }
        assert_eq!(sinc(0.0), 1.0);
        assert_eq!(versinc(0.0), 0.0);
    }

    #[test]
    fn atan2_matches_std_and_differentiates_at_x_zero() {
        for &(y, x) in &[(1.0f64, 2.0f64), (2.0, 1.0), (2.0, -1.0), (-0.5, -3.0), (-2.0, 0.3), (1.0, 0.0), (-1.0, 0.0), (0.0, -2.0)] {
            assert!((atan2(y, x) - y.atan2(x)).abs() < 1e-15, "({y}, {x})");
            // d/dy atan2 = x/(x²+y²), d/dx = −y/(x²+y²)
            let dy = atan2(Dual64::new(y, 1.0), Dual64::from(x)).eps;
            let dx = atan2(Dual64::from(y), Dual64::new(x, 1.0)).eps;
            let q = x * x + y * y;
            assert!((dy - x / q).abs() < 1e-14 && (dx + y / q).abs() < 1e-14, "({y}, {x}): {dy} {dx}");
        }
    }
}
