//! Freeform shape modes on top of the letter's three-parameter family (issue 20): optional
//! design parameters that, when all absent, leave the spec's geometry and its code path
//! untouched, and at zero give the spec's geometry to round-off.
//!
//! * **Twist law** α(z) = α z/L + Σₖ aₖ sin(kπz/L), k = 1…[`N_TWIST_MODES`] (`twist_k_deg`): a
//!   non-linear pre-twist with the same end-to-end twist α (every mode vanishes at both ends).
//! * **Lateral profile** ρ(z) = ρ_spec(z; l) + Σₖ bₖ Bₖ(z), k = 1…[`N_PROFILE_MODES`]
//!   (`profile_k_mm`), with Bₖ(z) = sin²(πz/L) cos((k − 1)πz/L): every mode and its slope vanish
//!   at both ends, so the end rings keep the radius R and the vertical tangent of the spec (planar
//!   end faces, horizontal offset there). k = 1 is a symmetric bulge, even k are antisymmetric.
//!
//! Both are smooth (C∞) in z and in the coefficients, so the mesh's node coordinates and every
//! FE output are differentiable in every coefficient by the same dual numbers as r, l and α.

use std::f64::consts::PI;

use super::scalar::cst;
use super::{Scalar, L_TUBE};

/// Number of twist-law modes (`twist_1_deg` … `twist_8_deg`).
pub const N_TWIST_MODES: usize = 8;
/// Number of lateral-profile modes (`profile_1_mm` … `profile_10_mm`).
pub const N_PROFILE_MODES: usize = 10;

/// Bound on a twist-mode coefficient (degrees): a quarter turn (the box the optimiser searches;
/// the local twist rate then stays within a few times Table I's largest, 360° over L).
pub const TWIST_MODE_MAX_DEG: f64 = 90.0;
/// Bound on a profile-mode coefficient (mm): a quarter of the tube radius (validity — within
/// the envelope, necks wide enough, offset not folding — is checked on the resulting surface by
/// [`super::freeform_validity`]).
pub const PROFILE_MODE_MAX_MM: f64 = 5.0;

/// Name of twist mode k (1-based).
pub fn twist_param(k: usize) -> String {
    format!("twist_{k}_deg")
}

/// Name of profile mode k (1-based).
pub fn profile_param(k: usize) -> String {
    format!("profile_{k}_mm")
}

/// (Kind, 0-based mode index) of a freeform parameter name.
pub fn parse_param(name: &str) -> Option<(ModeKind, usize)> {
    let (kind, rest) = if let Some(r) = name.strip_prefix("twist_").and_then(|r| r.strip_suffix("_deg")) {
        (ModeKind::Twist, r)
    } else if let Some(r) = name.strip_prefix("profile_").and_then(|r| r.strip_suffix("_mm")) {
        (ModeKind::Profile, r)
    } else {
        return None;
    };
    let k: usize = rest.parse().ok()?;
    let n = match kind {
        ModeKind::Twist => N_TWIST_MODES,
        ModeKind::Profile => N_PROFILE_MODES,
    };
    (k >= 1 && k <= n && rest == k.to_string()).then_some((kind, k - 1))
}

/// Which family of modes a freeform parameter belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModeKind {
    Twist,
    Profile,
}

/// Twist mode k (1-based) at height z: (sin(kπz/L), d/dz).
pub fn twist_mode<D: Scalar>(k: usize, z: D) -> (D, D) {
    let w = k as f64 * PI / L_TUBE;
    let (s, c) = (z * w).sin_cos();
    (s, c * w)
}

/// Profile mode k (1-based) at height z: (Bₖ, Bₖ', Bₖ'') with Bₖ = sin²(πz/L) cos((k − 1)πz/L).
pub fn profile_mode<D: Scalar>(k: usize, z: D) -> (D, D, D) {
    let w = PI / L_TUBE;
    let m = (k - 1) as f64;
    let s = z * w;
    let (sn, cs) = s.sin_cos();
    let (sm, cm) = (s * m).sin_cos();
    let s2 = sn * sn;
    let sin2 = sn * cs * 2.0;
    let cos2 = cs * cs - s2;
    let b = s2 * cm;
    let db = (sin2 * cm - s2 * sm * m) * w;
    let d2b = (cos2 * cm * 2.0 - sin2 * sm * (2.0 * m) - s2 * cm * (m * m)) * (w * w);
    (b, db, d2b)
}

/// Σₖ aₖ sin(kπz/L) and its z-derivative (radians, radians/mm).
pub fn twist_offset<D: Scalar>(a: &[D; N_TWIST_MODES], z: D) -> (D, D) {
    let mut v = cst::<D>(0.0);
    let mut dv = cst::<D>(0.0);
    for (k, ak) in a.iter().enumerate() {
        let (s, ds) = twist_mode(k + 1, z);
        v += *ak * s;
        dv += *ak * ds;
    }
    (v, dv)
}

/// Σₖ bₖ Bₖ(z) and its first two z-derivatives (mm).
pub fn profile_offset<D: Scalar>(b: &[D; N_PROFILE_MODES], z: D) -> (D, D, D) {
    let mut v = cst::<D>(0.0);
    let mut dv = cst::<D>(0.0);
    let mut d2v = cst::<D>(0.0);
    for (k, bk) in b.iter().enumerate() {
        let (m, dm, d2m) = profile_mode(k + 1, z);
        v += *bk * m;
        dv += *bk * dm;
        d2v += *bk * d2m;
    }
    (v, dv, d2v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

    #[test]
    fn modes_vanish_at_the_ends_with_their_slopes_and_differentiate_exactly() {
        for k in 1..=N_PROFILE_MODES {
            for z in [0.0, L_TUBE] {
                let (b, db, _): (f64, f64, f64) = profile_mode(k, z);
                assert!(b.abs() < 1e-15 && db.abs() < 1e-14, "profile mode {k} at z = {z}: {b} {db}");
            }
            // derivatives against dual numbers
            for z in [1.3, 9.7, 20.0, 33.1] {
                let (_, db, d2b) = profile_mode(k, z);
                let (bd, dbd, _) = profile_mode(k, Dual64::new(z, 1.0));
                assert!((bd.eps - db).abs() < 1e-13 && (dbd.eps - d2b).abs() < 1e-13, "mode {k} z {z}");
            }
        }
        for k in 1..=N_TWIST_MODES {
            assert!(twist_mode(k, 0.0f64).0.abs() < 1e-15 && twist_mode(k, L_TUBE).0.abs() < 1e-14);
            let (_, ds) = twist_mode(k, 7.0);
            assert!((twist_mode(k, Dual64::new(7.0, 1.0)).0.eps - ds).abs() < 1e-14);
        }
    }

    #[test]
    fn parameter_names_round_trip() {
        for k in 1..=N_TWIST_MODES {
            assert_eq!(parse_param(&twist_param(k)), Some((ModeKind::Twist, k - 1)));
        }
        for k in 1..=N_PROFILE_MODES {
            assert_eq!(parse_param(&profile_param(k)), Some((ModeKind::Profile, k - 1)));
        }
        for bad in ["twist_0_deg", "twist_9_deg", "profile_11_mm", "profile_01_mm", "twist_1_mm", "r_mm"] {
            assert_eq!(parse_param(bad), None, "{bad}");
        }
    }
}
