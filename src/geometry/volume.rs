//! Volumes of the actuator (GEOMETRY.md §6).
//!
//! * Outer volume: (A/T²)∫₀^L ρ(z)² dz, integrated by Gauss–Legendre on each of the three profile
//!   arcs (the integrand is analytic on each arc, so the rule converges to round-off).
//! * Chamber volume: the cavity is bounded by the inner wall X = S0 − t n0 (untwisted; the twist
//!   is a rotation of horizontal slices and does not change volumes) and the two end planes.
//!   By the divergence theorem with the field (x, y, 0)/2, whose flux through the horizontal
//!   end planes vanishes,
//!   V = ½ ∬ (x N_x + y N_y) dŝ dz with N = ∂X/∂ŝ × ∂X/∂z (pointing out of the cavity),
//!   over the inner wall parameterised by the outer-surface parameters (ŝ, z) ∈ [0,1) × [0, L].
//!   The inner point's height differs from z in the sloped zones, but the parameterisation still
//!   covers the inner wall exactly once (the end rings stay in the end planes because ρ' = 0
//!   there). The integrand is analytic on each of the 6 × 3 patches bounded by the arc
//!   junctions and the profile junctions z = L/4, 3L/4, so tensor Gauss–Legendre on each patch
//!   converges spectrally; 3-fold symmetry reduces the work to one 120° sector. The partial
//!   derivatives come from forward-mode dual numbers.
//!
//! Geometry variants: the designed surface always encloses (A/T²)∫ρ²dz (the twist rotates
//! horizontal slices); it is the outer surface for an inward offset and the cavity for an outward
//! one. The offset surface's volume is the surface integral above, over the wall as
//! [`Actuator::point`] parameterises it; when the wall is trimmed by the end planes (twist before
//! offset, or a profile end tangent) the z-range of the first and last patch is
//! [δ0(ŝ), z_J] and [L − z_J, L + δL(ŝ)] ([`Actuator::trim_shifts`]), still exact.

use num_dual::Dual;

use super::scalar::{cst, gauss_legendre};
use super::{Actuator, OffsetSide, Scalar, L_TUBE};

/// Quadrature points per patch direction for the volume integrals.
pub const VOLUME_QUADRATURE_POINTS: usize = 48;

fn z_patches() -> [(f64, f64); 3] {
    [(0.0, L_TUBE / 4.0), (L_TUBE / 4.0, 3.0 * L_TUBE / 4.0), (3.0 * L_TUBE / 4.0, L_TUBE)]
}

/// The profile's arc patches in z (junctions at z_J, L − z_J; f64: the integrands' parameter
/// derivatives are continuous across the junctions because the profile is C1).
fn z_patches_of<D: Scalar>(act: &Actuator<D>) -> [(f64, f64); 3] {
    if act.profile.gamma.is_none() {
        return z_patches();
    }
    let zj = act.profile.z_junction.re();
    [(0.0, zj), (zj, L_TUBE - zj), (L_TUBE - zj, L_TUBE)]
}

/// Outer volume (generic: pass a dual-number actuator for derivatives): the designed volume
/// (A/T²)∫ρ²dz for an inward offset (the spec), the outer offset surface's enclosed volume for an
/// outward one.
pub fn outer_volume<D: Scalar>(act: &Actuator<D>) -> D {
    match act.variant.offset {
        OffsetSide::Inward => designed_volume(act),
        OffsetSide::Outward => enclosed_volume(act, 0.0, VOLUME_QUADRATURE_POINTS),
    }
}

/// Volume enclosed by the designed (lofted) surface and the end planes, (A/T²)∫ρ²dz.
pub fn designed_volume<D: Scalar>(act: &Actuator<D>) -> D {
    let (x, w) = gauss_legendre(VOLUME_QUADRATURE_POINTS);
    let mut integral = cst::<D>(0.0);
    for (a, b) in z_patches_of(act) {
        let h = 0.5 * (b - a);
        for (xi, wi) in x.iter().zip(&w) {
            let z = a + h * (xi + 1.0);
            let rho = act.profile.eval(cst(z)).rho;
            integral += rho * rho * (wi * h);
        }
    }
    act.section.area / (act.section.t_max * act.section.t_max) * integral
}

/// Volume enclosed by the wall surface at offset fraction `eta` (0 = outer surface, 1 = inner
/// wall = chamber) and the two end planes, by the surface integral described in the module
/// docs, with `n` Gauss points per patch direction. Generic: with a dual-number actuator the
/// result carries the derivative with respect to the seeded design parameter (the surface
/// partials ∂X/∂ŝ, ∂X/∂z use a nested dual number).
pub fn enclosed_volume<D: Scalar>(act: &Actuator<D>, eta: f64, n: usize) -> D {
    if act.needs_trim() || !act.variant.is_spec() || act.is_freeform() {
        return enclosed_volume_general(act, eta, n);
    }
    let s = &act.section;
    let zero = cst::<D>(0.0);
    let one = cst::<D>(1.0);
    let lift = |x: D| Dual::new(x, zero);
    let ad = Actuator::<Dual<D>>::new(lift(s.r), lift(act.profile.l), lift(zero));
    let (x, w) = gauss_legendre(n);
    let patches_s = sector_arc_patches(s);
    let eta_d = lift(cst(eta));
    let mut total = zero;
    for &(sa, sb) in &patches_s {
        let hs = (sb - sa) * 0.5;
        for (za, zb) in z_patches() {
            let hz = 0.5 * (zb - za);
            for (xs, ws) in x.iter().zip(&w) {
                let shat = sa + hs * (xs + 1.0);
                for (xz, wz) in x.iter().zip(&w) {
                    let z = cst::<D>(za + hz * (xz + 1.0));
                    let ps = ad.untwisted_point(Dual::new(shat, one), lift(z), eta_d);
                    let pz = ad.untwisted_point(lift(shat), Dual::new(z, one), eta_d);
                    let xs_ = [ps[0].eps, ps[1].eps, ps[2].eps];
                    let xz_ = [pz[0].eps, pz[1].eps, pz[2].eps];
                    let nx = xs_[1] * xz_[2] - xs_[2] * xz_[1];
                    let ny = xs_[2] * xz_[0] - xs_[0] * xz_[2];
                    let f = (ps[0].re * nx + ps[1].re * ny) * 0.5;
                    total += f * hs * (ws * wz * hz);
                }
            }
        }
    }
    total * 3.0
}

/// The ŝ intervals of one 120° period of the section on which it is a single arc (lobe 0, then
/// the following notch when the section has one): each is integrated by its own Gauss rule.
fn sector_arc_patches<D: Scalar>(s: &super::Section<D>) -> Vec<(D, D)> {
    let fl = s.lobe_fraction();
    let s0 = s.lobe_start_shat(0);
    let mut patches = vec![(s0, s0 + fl * (1.0 / 3.0))];
    if s.theta_n.re() > 0.0 {
        patches.push((s0 + fl * (1.0 / 3.0), s0 + 1.0 / 3.0));
    }
    patches
}

/// [`enclosed_volume`] for any variant: the wall layer as [`Actuator::point`] gives it
/// (including the twist, which does not change the volume of an untrimmed wall), over z ∈
/// [δ0(ŝ), L + δL(ŝ)] when the wall is trimmed.
fn enclosed_volume_general<D: Scalar>(act: &Actuator<D>, eta: f64, n: usize) -> D {
    let s = &act.section;
    let zero = cst::<D>(0.0);
    let one = cst::<D>(1.0);
    let lift = |x: D| Dual::new(x, zero);
    let ad = act.lift();
    let (x, w) = gauss_legendre(n);
    let patches_s = sector_arc_patches(s);
    let eta_d = lift(cst(eta));
    // the junctions move with the design (end tangent) and the offset layer's integrand jumps
    // there (its z-speed involves ρ''), so the patch bounds carry the derivatives
    let zj = act.profile.z_junction;
    let zl = cst::<D>(L_TUBE);
    let mut total = zero;
    for &(sa, sb) in &patches_s {
        let hs = (sb - sa) * 0.5;
        for (xs, ws) in x.iter().zip(&w) {
            let shat = sa + hs * (xs + 1.0);
            let (d0, dl) = act.trim_shifts(shat, cst(eta));
            for (za, zb) in [(d0, zj), (zj, zl - zj), (zl - zj, zl + dl)] {
                let hz = (zb - za) * 0.5;
                for (xz, wz) in x.iter().zip(&w) {
                    let z = za + hz * (xz + 1.0);
                    let ps = ad.point(Dual::new(shat, one), lift(z), eta_d);
                    let pz = ad.point(lift(shat), Dual::new(z, one), eta_d);
                    let xs_ = [ps[0].eps, ps[1].eps, ps[2].eps];
                    let xz_ = [pz[0].eps, pz[1].eps, pz[2].eps];
                    let nx = xs_[1] * xz_[2] - xs_[2] * xz_[1];
                    let ny = xs_[2] * xz_[0] - xs_[0] * xz_[2];
                    let f = (ps[0].re * nx + ps[1].re * ny) * 0.5;
                    total += f * hs * hz * (ws * wz);
                }
            }
        }
    }
    total * 3.0
}

/// Chamber volume (cavity between the inner wall and the end planes): the inner offset layer
/// for an inward offset (the spec), the designed volume for an outward one.
pub fn chamber_volume<D: Scalar>(act: &Actuator<D>) -> D {
    match act.variant.offset {
        OffsetSide::Inward => enclosed_volume(act, 1.0, VOLUME_QUADRATURE_POINTS),
        OffsetSide::Outward => designed_volume(act),
    }
}

/// Area ½∮(x dy − y dx) of the bottom ring of wall layer `eta` (trimmed into the plane z = 0),
/// Gauss–Legendre per section arc (the ring is analytic on each), ∂/∂ŝ by a nested dual number.
pub fn end_ring_area<D: Scalar>(act: &Actuator<D>, eta: f64) -> D {
    let s = &act.section;
    let zero = cst::<D>(0.0);
    let one = cst::<D>(1.0);
    let lift = |x: D| Dual::new(x, zero);
    let ad = act.lift();
    let (x, w) = gauss_legendre(VOLUME_QUADRATURE_POINTS);
    let patches_s = sector_arc_patches(s);
    let eta_d = lift(cst(eta));
    let mut total = zero;
    for &(sa, sb) in &patches_s {
        let hs = (sb - sa) * 0.5;
        for (xs, ws) in x.iter().zip(&w) {
            let shat = Dual::new(sa + hs * (xs + 1.0), one);
            let (d0, _) = ad.trim_shifts(shat, eta_d);
            let p = ad.point(shat, d0, eta_d);
            total += (p[0].re * p[1].eps - p[1].re * p[0].eps) * hs * (0.5 * ws);
        }
    }
    total * 3.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn chamber_quadrature_is_converged() {
        for (r, l) in [(5.0 * 3f64.sqrt(), 10.0), (13.2, 16.0), (20.0, 14.0)] {
            let act = Actuator::new(r, l, 0.0);
            let v48 = enclosed_volume(&act, 1.0, 48);
            let v80 = enclosed_volume(&act, 1.0, 80);
            assert!((v48 - v80).abs() < 1e-11 * v80, "r={r} l={l}: {v48} vs {v80}");
        }
    }

    #[test]
    fn outer_surface_integral_matches_closed_form_outer_volume() {
        // the same divergence-theorem integral at η = 0 against (A/T²)∫ρ²dz
        for (r, l) in [(5.0 * 3f64.sqrt(), 10.0), (11.0, 12.0), (20.0, 20.0)] {
            let act = Actuator::new(r, l, 0.3);
            let a = enclosed_volume(&act, 0.0, 48);
            let b = outer_volume(&act);
            assert!((a - b).abs() < 1e-11 * b, "r={r} l={l}: {a} vs {b}");
        }
    }

    #[test]
    fn plain_tube_chamber_is_cylinder() {
        let act = Actuator::new(20.0, 20.0, 1.0);
        let v = chamber_volume(&act);
        let exact = PI * 17.0 * 17.0 * L_TUBE;
        assert!((v - exact).abs() < 1e-10 * exact, "{v} vs {exact}");
        assert!((outer_volume(&act) - PI * 400.0 * L_TUBE).abs() < 1e-9);
    }
}
