//! The actuator geometry of `GEOMETRY.md` (shared spec), implemented exactly:
//! six-arc "triangular horseshoe" section, three-arc bellows profile, isotropic blending,
//! inward 3-D normal offset of the wall and a linear twist applied last.
//!
//! Other readings of the letter (section normalisation, offset side, twist order: a
//! [`GeometryVariant`]; the profile's end-tangent angle: the optional design parameter
//! `end_tangent_deg`) are selectable; the default of each is the spec, computed by the spec's own
//! code path (bit-identical). Formulas: `studies/letter-calibration/VARIANTS.md`.
//!
//! Every formula is generic over [`Scalar`] (`f64` or a `num_dual` dual number), so that node
//! coordinates can be differentiated with respect to every design parameter.
//!
//! Conventions: mm, angles in radians inside the formulas (α is given in degrees in a
//! [`Design`]). ŝ ∈ [0, 1) is the normalised arc length of the section, ŝ = 0 at the tip of
//! lobe 0, the point (T, 0) of the construction frame.

pub mod design;
pub mod freeform;
pub mod scalar;
pub mod variant;
pub mod volume;

pub use design::{l_min_extended, l_min_waist, offset_locally_valid, r_min_extended, Design, DesignSpace, GeometryError, ParamSpec, RangePolicy, P_ALPHA, P_END_TANGENT, P_L, P_R};
pub use scalar::Scalar;
pub use variant::{GeometryVariant, OffsetSide, SectionReading, TwistOrder};

use num_dual::Dual;
use scalar::{atan2, cst, dot2, rot2, sinc, versinc};
use std::f64::consts::{FRAC_PI_3, PI};

/// Tube outer radius R (mm).
pub const R_TUBE: f64 = 20.0;
/// Actuator height L (mm).
pub const L_TUBE: f64 = 40.0;
/// Wall thickness t (mm).
pub const T_WALL: f64 = 3.0;
/// Smallest principal radius (mm) the offset wall of a geometry variant may have on its offset
/// side: the surface the wall is offset from must have radii ≥ t + this (else the variant is
/// refused at that design; the spec's own designs all satisfy it).
pub const MIN_WALL_RADIUS: f64 = 0.2;
/// Radius of the envelope used for the energy density (letter), R0 (mm).
pub const R0_ENVELOPE: f64 = 25.0;

/// Closed-form constants of the cross-section (construction frame, GEOMETRY.md §0, §2).
#[derive(Clone, Copy, Debug)]
pub struct Section<D> {
    /// arc radius r
    pub r: D,
    /// notch half-angle u
    pub u: D,
    /// lobe arc angle θL = 2u + 2π/3
    pub theta_l: D,
    /// notch arc angle θN = 2u
    pub theta_n: D,
    /// triangle vertex → inflection point distance along a side
    pub x: D,
    /// lobe-centre distance from the axis
    pub d: D,
    /// notch-centre distance from the axis
    pub e: D,
    /// max radius T = d + r
    pub t_max: D,
    /// min radius B = e − r
    pub b_min: D,
    /// perimeter P = r(2π + 12u)
    pub perimeter: D,
    /// area A = (3√3/2)de + πr²
    pub area: D,
    /// polar angle of the inflection point φJ = atan2(√3R/2 − x, R/2)
    pub phi_j: D,
}

/// A point of the section with its differential data (GEOMETRY.md §2.4).
#[derive(Clone, Copy, Debug)]
pub struct SectionPoint<D> {
    /// position c(ŝ)
    pub c: [D; 2],
    /// unit tangent τ (counter-clockwise)
    pub tau: [D; 2],
    /// outward unit normal ν = (τy, −τx)
    pub nu: [D; 2],
    /// signed curvature: +1/r on lobes (convex), −1/r on notches (concave)
    pub kappa: D,
    /// support value p = c·ν (> 0)
    pub p: D,
    /// which arc: 0..6 in the order L0 N0 L1 N1 L2 N2
    pub arc: usize,
}

/// Section constants in `f64` (used by range checks).
pub fn section_constants_f64(r: f64) -> Section<f64> {
    Section::new(r)
}

impl<D: Scalar> Section<D> {
    pub fn new(r: D) -> Self {
        let rr = R_TUBE;
        let psi0 = (3f64.sqrt() / 5.0).atan();
        let arg = r.recip() * (3f64.sqrt() * rr / (2.0 * 7f64.sqrt()));
        // arg ≤ 1 for r ≥ R√21/14; clamp round-off at that limit
        let mut u = if arg.re() >= 1.0 { cst::<D>(PI / 2.0 - psi0) } else { arg.asin() - psi0 };
        if u.re() < 0.0 && u.re() > -1e-12 {
            // r = R up to round-off: the circle limit (u = 0)
            u = u - u.re();
        }
        let theta_l = u * 2.0 + 2.0 * PI / 3.0;
        let theta_n = u * 2.0;
        let x = r * u.sin() * 2.0;
        let d = cst::<D>(rr / 2.0) - r * (u + FRAC_PI_3).cos();
        let e = cst::<D>(rr) + r * u.cos() - r * u.sin() * 3f64.sqrt();
        let t_max = d + r;
        let b_min = e - r;
        let perimeter = r * (u * 12.0 + 2.0 * PI);
        let area = d * e * (1.5 * 3f64.sqrt()) + r * r * PI;
        let phi_j = (cst::<D>(3f64.sqrt() * rr / 2.0) - x).atan2(cst(rr / 2.0));
        Section { r, u, theta_l, theta_n, x, d, e, t_max, b_min, perimeter, area, phi_j }
    }

    /// The section of a [`SectionReading`]: the spec's construction for `Triangle`, otherwise the
    /// six-arc ring with lobe-centre distance d = R − r (`TipsOnR`) or d = R/2 (`MidpointCentres`).
    pub fn with_reading(r: D, reading: SectionReading) -> Self {
        match reading {
            SectionReading::Triangle => Section::new(r),
            SectionReading::TipsOnR => Section::from_lobe_centre(r, cst::<D>(R_TUBE) - r),
            SectionReading::MidpointCentres => Section::from_lobe_centre(r, cst::<D>(R_TUBE / 2.0)),
        }
    }

    /// The equal-radius six-arc ring (3-fold, mirror-symmetric, G1) with arc radius r and lobe
    /// centres at distance d from the axis. The notch centres sit at e (angle π/3 from a lobe
    /// centre) with the lobe and notch circles externally tangent, |C − D|² = d² + e² − de = 4r²:
    ///   e = (d + √(16r² − 3d²))/2,  u = θL/2 − π/3 = atan2(√3e, e − 2d) − π/3,
    ///   x = 2r sin u (notch chord), T = d + r, B = e − r, P = r(2π + 12u),
    ///   A = (3√3/2)de + πr², φJ = atan2(√3e, 2d + e) (polar angle of the inflection point (C+D)/2).
    /// Exists for 16r² > 3d²; u = 0 (the circle) when d = 0.
    pub fn from_lobe_centre(r: D, d: D) -> Self {
        let s3 = 3f64.sqrt();
        let e = (d + (r * r * 16.0 - d * d * 3.0).sqrt()) * 0.5;
        let mut u = atan2(e * s3, e - d * 2.0) - FRAC_PI_3;
        if u.re().abs() < 1e-12 && d.re() == 0.0 {
            // d = 0: the circle (u = 0 up to round-off)
            u = u - u.re();
        }
        let theta_l = u * 2.0 + 2.0 * PI / 3.0;
        let theta_n = u * 2.0;
        let x = r * u.sin() * 2.0;
        let t_max = d + r;
        let b_min = e - r;
        let perimeter = r * (u * 12.0 + 2.0 * PI);
        let area = d * e * (1.5 * s3) + r * r * PI;
        let phi_j = atan2(e * s3, d * 2.0 + e);
        Section { r, u, theta_l, theta_n, x, d, e, t_max, b_min, perimeter, area, phi_j }
    }

    /// Fraction of a 120° sector (lobe + notch) taken by the lobe, θL/(θL + θN).
    pub fn lobe_fraction(&self) -> D {
        self.theta_l / (self.theta_l + self.theta_n)
    }

    /// ŝ of the start of lobe k (junction N_{k−1} → L_k), in [0, 1) for k = 1, 2 and negative for
    /// k = 0 (ŝ is periodic).
    pub fn lobe_start_shat(&self, k: usize) -> D {
        (cst::<D>(k as f64) - self.lobe_fraction() * 0.5) * (1.0 / 3.0)
    }

    /// Evaluate the section at normalised arc length ŝ (any real; periodic with period 1).
    pub fn eval(&self, shat: D) -> SectionPoint<D> {
        let fl = self.lobe_fraction();
        // position in units of sectors, measured from the start of lobe 0
        let q = shat * 3.0 + fl * 0.5;
        let kf = q.re().floor();
        let f = q - kf;
        let k = (kf.rem_euclid(3.0)) as usize;
        let span = self.theta_l + self.theta_n;
        let (c, tau, nu, kappa, arc) = if f.re() < fl.re() || self.theta_n.re() == 0.0 {
            // lobe k (k = 0 here, rotated afterwards): centre (d, 0), angle a, CCW
            let a = self.theta_l * (-0.5) + f * span;
            let (sa, ca) = a.sin_cos();
            let c = [self.d + self.r * ca, self.r * sa];
            (c, [-sa, ca], [ca, sa], self.r.recip(), 2 * k)
        } else {
            // notch k: centre e(cos π/3, sin π/3), angle b decreasing (CW)
            let b = cst::<D>(4.0 * PI / 3.0) + self.u - (f - fl) * span;
            let (sb, cb) = b.sin_cos();
            let ctr = [self.e * 0.5, self.e * (3f64.sqrt() / 2.0)];
            let c = [ctr[0] + self.r * cb, ctr[1] + self.r * sb];
            (c, [sb, -cb], [-cb, -sb], -self.r.recip(), 2 * k + 1)
        };
        let phi = 2.0 * PI * k as f64 / 3.0;
        let (cs, sn) = (cst::<D>(phi.cos()), cst::<D>(phi.sin()));
        let c = rot2(c, cs, sn);
        let tau = rot2(tau, cs, sn);
        let nu = rot2(nu, cs, sn);
        let p = dot2(c, nu);
        SectionPoint { c, tau, nu, kappa, p, arc }
    }

    /// Polar form ρsec(φ) of the section (GEOMETRY.md §2.4), valid where the section is
    /// star-shaped and each ray meets it once (the Table-I range).
    pub fn polar_radius(&self, phi: D) -> D {
        let period = 2.0 * PI / 3.0;
        let shifted = phi + FRAC_PI_3;
        let n = (shifted.re() / period).floor();
        let w = shifted - n * period - FRAC_PI_3;
        if w.re().abs() <= self.phi_j.re() {
            let sw = w.sin();
            w.cos() * self.d + (self.r * self.r - self.d * self.d * sw * sw).sqrt()
        } else {
            let wn = w - w.re().signum() * FRAC_PI_3;
            let sw = wn.sin();
            wn.cos() * self.e - (self.r * self.r - self.e * self.e * sw * sw).sqrt()
        }
    }
}

/// The bellows profile ρ(z): three tangent arcs of radius ρa, vertical at both ends (§3) — or,
/// with an end-tangent angle γ ([`Profile::with_end_tangent`]), leaving the end planes at the
/// angle γ from the vertical (positive = leaning towards the axis).
#[derive(Clone, Copy, Debug)]
pub struct Profile<D> {
    /// waist radius l
    pub l: D,
    /// δ = R − l
    pub delta: D,
    /// curvature 1/ρa of the arcs (0 for the straight tube l = R)
    pub kappa_a: D,
    /// tangent angle (from the vertical) at the two arc junctions; the spec's turning angle
    /// 2 atan(2δ/L) of each end arc (which turns β − γ in general)
    pub beta: D,
    /// total arc length (4ρaβ for the spec, L for the straight tube)
    pub length: D,
    /// end-tangent angle γ (radians); None = the spec's vertical ends (computed by the spec's
    /// closed forms)
    pub gamma: Option<D>,
    /// height of the lower arc junction (L/4 for the spec; the upper one is at L − z_junction)
    pub z_junction: D,
    /// arc length of each end arc (length/4 for the spec)
    pub end_length: D,
    /// freeform profile modes' coefficients (mm) added to the arcs' radius
    /// ([`freeform::profile_offset`]); None = the spec's three arcs (their own code path)
    pub bumps: Option<[D; freeform::N_PROFILE_MODES]>,
}

/// Value and derivatives of the profile at one height.
#[derive(Clone, Copy, Debug)]
pub struct ProfileValue<D> {
    pub rho: D,
    pub drho: D,
    pub d2rho: D,
}

/// Smallest turning angle of the end arcs of a profile with an end tangent (2°): below it the
/// end arcs (and the mesh rings on them) collapse into the single-arc limit.
pub const MIN_END_ARC_TURN_RAD: f64 = 2.0 * PI / 180.0;

impl<D: Scalar> Profile<D> {
    pub fn new(l: D) -> Self {
        let delta = cst::<D>(R_TUBE) - l;
        let kappa_a = delta * 4.0 / (delta * delta + L_TUBE * L_TUBE / 4.0);
        let beta = (delta * (2.0 / L_TUBE)).atan() * 2.0;
        // 4ρaβ = 4β/κa, written without the 0/0 at δ = 0: β = 2 atan(2δ/L),
        // κa = 4δ/(δ² + L²/4), so 4β/κa = (δ² + L²/4) · 2 atan(2δ/L)/δ.
        let length = if delta.re() == 0.0 {
            // d(length)/dδ = 0 at δ = 0 (length = L + O(δ²))
            cst::<D>(L_TUBE) + delta * delta * (8.0 / (3.0 * L_TUBE))
        } else {
            (delta * delta + L_TUBE * L_TUBE / 4.0) * beta / delta
        };
        Profile { l, delta, kappa_a, beta, length, gamma: None, z_junction: cst(L_TUBE / 4.0), end_length: length * 0.25, bumps: None }
    }

    /// The three-arc profile (ρ = R at both ends, waist ρ = l at z = L/2, mirror-symmetric about
    /// the waist) whose end arcs leave the end planes at the angle γ from the vertical
    /// (ρ'(0) = −tan γ). With the lower end-arc centre C1 = (R − ρa cos γ, −ρa sin γ) and the
    /// middle-arc centre C2 = (l + ρa, L/2) (in the (ρ, z) half-plane), tangency |C1C2| = 2ρa gives
    /// for κ = 1/ρa the quadratic (δ² + L²/4)κ² + (L sin γ − 2δ(1 + cos γ))κ − 2(1 − cos γ) = 0
    /// (positive root); the junctions are the midpoints of C1C2: z_J = L/4 − ρa sin γ/2, with the
    /// tangent angle β = atan2(κL/4 + sin γ/2, (1 + cos γ − κδ)/2). γ = 0 is the spec's profile.
    /// Feasible when the end arcs turn: β − γ > 0 (see [`Profile::check`]).
    pub fn with_end_tangent(l: D, gamma: D) -> Self {
        let delta = cst::<D>(R_TUBE) - l;
        let (sg, cg) = gamma.sin_cos();
        let a = delta * delta + L_TUBE * L_TUBE / 4.0;
        let b = sg * L_TUBE - delta * (cg + 1.0) * 2.0;
        let c = (cst::<D>(1.0) - cg) * (-2.0);
        let disc = (b * b - a * c * 4.0).sqrt();
        // the positive root, in the form without cancellation
        let kappa_a = if b.re() <= 0.0 { (disc - b) / (a * 2.0) } else { c * (-2.0) / (b + disc) };
        let (z_junction, beta, end_length, mid_length) = if kappa_a.re() == 0.0 {
            // the straight tube (δ = 0, γ = 0)
            (cst::<D>(L_TUBE / 4.0), cst::<D>(0.0), cst::<D>(L_TUBE / 4.0), cst::<D>(L_TUBE / 2.0))
        } else {
            let zj = cst::<D>(L_TUBE / 4.0) - sg / (kappa_a * 2.0);
            let beta = atan2(kappa_a * (L_TUBE / 4.0) + sg * 0.5, (cg + 1.0 - kappa_a * delta) * 0.5);
            (zj, beta, (beta - gamma) / kappa_a, beta * 2.0 / kappa_a)
        };
        Profile { l, delta, kappa_a, beta, length: end_length * 2.0 + mid_length, gamma: Some(gamma), z_junction, end_length, bumps: None }
    }

    /// Whether the profile exists as three arcs of one radius, convex–concave–convex: with an end
    /// tangent, each end arc must turn by at least [`MIN_END_ARC_TURN_RAD`] (γ = 0 is always
    /// allowed: the spec), β below 90° (no overhang) and the junction inside (0, L/2).
    pub fn check(&self) -> Result<(), String> {
        let Some(g) = self.gamma else { return Ok(()) };
        let (g, b) = (g.re(), self.beta.re());
        if g == 0.0 {
            return Ok(());
        }
        if !(self.kappa_a.re() > 0.0) || !(b - g >= MIN_END_ARC_TURN_RAD) {
            return Err(format!("the end arcs would turn by {:.3}° (at least {:.0}° needed: the profile degenerates into a single arc)", (b - g).to_degrees(), MIN_END_ARC_TURN_RAD.to_degrees()));
        }
        if b >= PI / 2.0 {
            return Err(format!("the junction tangent would be {:.2}° from the vertical (the profile would overhang)", b.to_degrees()));
        }
        let zj = self.z_junction.re();
        if !(zj > 0.0 && zj < L_TUBE / 2.0) {
            return Err(format!("the arc junction would be at z = {zj:.3} mm, outside (0, L/2)"));
        }
        Ok(())
    }

    /// Arc radius ρa (infinite for the straight tube).
    pub fn rho_a(&self) -> D {
        self.kappa_a.recip()
    }

    /// The same profile with freeform modes added (coefficients in mm; None = none).
    pub fn with_bumps(mut self, bumps: Option<[D; freeform::N_PROFILE_MODES]>) -> Self {
        self.bumps = bumps;
        self
    }

    /// ρ(z), ρ'(z), ρ''(z) (with the freeform modes, if any). z outside [0, L] is clamped to
    /// the nearest end arc formula.
    pub fn eval(&self, z: D) -> ProfileValue<D> {
        let v = self.eval_arcs(z);
        match &self.bumps {
            None => v,
            Some(b) => {
                let (d, dd, d2) = freeform::profile_offset(b, z);
                ProfileValue { rho: v.rho + d, drho: v.drho + dd, d2rho: v.d2rho + d2 }
            }
        }
    }

    /// The three arcs' ρ(z), ρ'(z), ρ''(z) (without freeform modes).
    fn eval_arcs(&self, z: D) -> ProfileValue<D> {
        let k = self.kappa_a;
        let zr = z.re();
        let one = cst::<D>(1.0);
        if let Some(g) = self.gamma {
            let zj = self.z_junction.re();
            if zr <= zj || zr >= L_TUBE - zj {
                // end arcs: sin φ = κw + sin γ at distance w from the end plane, and
                // ρ − R = ρa(cos φ − cos γ) = −w(κw + 2 sin γ)/(cos φ + cos γ)
                let (w, sgn) = if zr <= zj { (z, 1.0) } else { (cst::<D>(L_TUBE) - z, -1.0) };
                let (sg, cg) = g.sin_cos();
                let sphi = k * w + sg;
                let cphi = (one - sphi * sphi).sqrt();
                let rho = cst::<D>(R_TUBE) - w * (k * w + sg * 2.0) / (cphi + cg);
                let drho = -(sphi / cphi) * sgn;
                let d2rho = -k / (cphi * cphi * cphi);
                return ProfileValue { rho, drho, d2rho };
            }
            let w = z - L_TUBE / 2.0;
            let q = (one - k * k * w * w).sqrt();
            return ProfileValue { rho: self.l + k * w * w / (one + q), drho: k * w / q, d2rho: k / (q * q * q) };
        }
        if zr <= L_TUBE / 4.0 || zr >= 3.0 * L_TUBE / 4.0 {
            // convex end arcs, centre (R − ρa, 0) or (R − ρa, L)
            let (w, sgn) = if zr <= L_TUBE / 4.0 { (z, 1.0) } else { (cst::<D>(L_TUBE) - z, -1.0) };
            let q = (one - k * k * w * w).sqrt();
            let rho = cst::<D>(R_TUBE) - k * w * w / (one + q);
            let drho = -(k * w / q) * sgn;
            let d2rho = -k / (q * q * q);
            ProfileValue { rho, drho, d2rho }
        } else {
            let w = z - L_TUBE / 2.0;
            let q = (one - k * k * w * w).sqrt();
            let rho = self.l + k * w * w / (one + q);
            let drho = k * w / q;
            let d2rho = k / (q * q * q);
            ProfileValue { rho, drho, d2rho }
        }
    }

    /// (z, ρ) at normalised arc length ζ ∈ [0, 1] of the profile (ζ = 1/4, 3/4 are the junctions).
    /// With an end tangent the arc length is uniform on each arc, with the junctions still at
    /// ζ = 1/4, 3/4 (for γ = 0 this is the uniform arc length of the spec).
    pub fn at_arclength(&self, zeta: f64) -> (D, D) {
        let (z, rho) = self.at_arclength_arcs(zeta);
        match &self.bumps {
            None => (z, rho),
            // (the arc length of the three arcs: the freeform modes move ρ, not the rings' z)
            Some(b) => (z, rho + freeform::profile_offset(b, z).0),
        }
    }

    fn at_arclength_arcs(&self, zeta: f64) -> (D, D) {
        if let Some(g) = self.gamma {
            let (sg, cg) = g.sin_cos();
            // end arc from an end plane: arc length s, turned angle θ = κs:
            // Δz = s(cos γ sinc θ − sin γ versinc θ), R − ρ = s(cos γ versinc θ + sin γ sinc θ)
            let end = |s: D| {
                let th = s * self.kappa_a;
                let (si, ve) = (sinc(th), versinc(th));
                (s * (cg * si - sg * ve), s * (cg * ve + sg * si))
            };
            return if zeta <= 0.25 {
                let (dz, dr) = end(self.end_length * (4.0 * zeta));
                (dz, cst::<D>(R_TUBE) - dr)
            } else if zeta < 0.75 {
                let sm = (self.length - self.end_length * 2.0) * (2.0 * (zeta - 0.5));
                let th = sm * self.kappa_a;
                (cst::<D>(L_TUBE / 2.0) + sm * sinc(th), self.l + sm * versinc(th))
            } else {
                let (dz, dr) = end(self.end_length * (4.0 * (1.0 - zeta)));
                (cst::<D>(L_TUBE) - dz, cst::<D>(R_TUBE) - dr)
            };
        }
        if zeta <= 0.25 {
            let s = self.length * zeta;
            let th = s * self.kappa_a;
            (s * sinc(th), cst::<D>(R_TUBE) - s * versinc(th))
        } else if zeta < 0.75 {
            let sm = self.length * (zeta - 0.5);
            let th = sm * self.kappa_a;
            (cst::<D>(L_TUBE / 2.0) + sm * sinc(th), self.l + sm * versinc(th))
        } else {
            let s3 = self.length * (1.0 - zeta);
            let th = s3 * self.kappa_a;
            (cst::<D>(L_TUBE) - s3 * sinc(th), cst::<D>(R_TUBE) - s3 * versinc(th))
        }
    }
}

/// The actuator geometry for one design, generic over the scalar type.
#[derive(Clone, Copy, Debug)]
pub struct Actuator<D> {
    pub section: Section<D>,
    pub profile: Profile<D>,
    /// twist α in radians
    pub alpha: D,
    /// the reading of the geometry (default: the spec)
    pub variant: GeometryVariant,
    /// freeform twist-law modes' coefficients (radians, [`freeform::twist_offset`]); None = the
    /// spec's linear twist (its own code path)
    pub twist_modes: Option<[D; freeform::N_TWIST_MODES]>,
}

/// Outer-surface data at one (ŝ, z).
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint<D> {
    /// untwisted outer point S0
    pub s0: [D; 3],
    /// untwisted outward unit normal n0
    pub n0: [D; 3],
    pub sec: SectionPoint<D>,
    pub prof: ProfileValue<D>,
    /// W = sqrt(1 + λ'² p²)
    pub w: D,
}

impl<D: Scalar> Actuator<D> {
    /// Geometry from raw parameters (r, l in mm, α in **radians**). No validation: use
    /// [`ActuatorGeometry::new`] for checked construction.
    pub fn new(r: D, l: D, alpha_rad: D) -> Self {
        Actuator { section: Section::new(r), profile: Profile::new(l), alpha: alpha_rad, variant: GeometryVariant::default(), twist_modes: None }
    }

    /// Geometry of a [`GeometryVariant`] with an optional end-tangent angle γ of the profile
    /// (radians; None = the spec's vertical ends). No validation.
    pub fn with_variant(r: D, l: D, alpha_rad: D, end_tangent_rad: Option<D>, variant: GeometryVariant) -> Self {
        let profile = match end_tangent_rad {
            None => Profile::new(l),
            Some(g) => Profile::with_end_tangent(l, g),
        };
        Actuator { section: Section::with_reading(r, variant.section), profile, alpha: alpha_rad, variant, twist_modes: None }
    }

    /// The same actuator with freeform modes: twist-law coefficients (radians) and profile
    /// coefficients (mm); None = the spec's linear twist / three-arc profile.
    pub fn with_freeform(mut self, twist: Option<[D; freeform::N_TWIST_MODES]>, profile: Option<[D; freeform::N_PROFILE_MODES]>) -> Self {
        self.twist_modes = twist;
        self.profile = self.profile.with_bumps(profile);
        self
    }

    /// Whether the actuator carries freeform modes.
    pub fn is_freeform(&self) -> bool {
        self.twist_modes.is_some() || self.profile.bumps.is_some()
    }

    /// The twist angle φ(z) (radians) and φ'(z): αz/L for the spec, plus the freeform modes.
    pub fn twist_angle(&self, z: D) -> (D, D) {
        let lin = self.alpha * z * (1.0 / L_TUBE);
        let rate = self.alpha * (1.0 / L_TUBE);
        match &self.twist_modes {
            None => (lin, rate),
            Some(a) => {
                let (v, dv) = freeform::twist_offset(a, z);
                (lin + v, rate + dv)
            }
        }
    }

    /// The same actuator over nested dual numbers (derivative part zero), for partial derivatives
    /// with respect to the surface parameters.
    pub fn lift(&self) -> Actuator<Dual<D>> {
        let z = D::zero();
        let lift = |x: D| Dual::new(x, z);
        Actuator::with_variant(lift(self.section.r), lift(self.profile.l), lift(self.alpha), self.profile.gamma.map(lift), self.variant)
            .with_freeform(self.twist_modes.map(|a| a.map(lift)), self.profile.bumps.map(|b| b.map(lift)))
    }

    /// Whether the wall must be trimmed by the end planes: the offset direction is not horizontal
    /// at the end rings (a profile end tangent, or the twist applied before the offset). False for
    /// the spec, whose end faces are planar by construction.
    pub fn needs_trim(&self) -> bool {
        self.variant.twist == TwistOrder::BeforeOffset || self.profile.gamma.is_some()
    }

    /// Scale λ(z) = ρ(z)/T and its derivatives.
    pub fn lambda(&self, z: D) -> (D, D, D) {
        let pv = self.profile.eval(z);
        let it = self.section.t_max.recip();
        (pv.rho * it, pv.drho * it, pv.d2rho * it)
    }

    /// Untwisted outer surface point S0 and its outward unit normal n0.
    pub fn surface(&self, shat: D, z: D) -> SurfacePoint<D> {
        let sec = self.section.eval(shat);
        let prof = self.profile.eval(z);
        let it = self.section.t_max.recip();
        let lam = prof.rho * it;
        let dlam = prof.drho * it;
        let lp = dlam * sec.p;
        let w = (lp * lp + 1.0).sqrt();
        let iw = w.recip();
        SurfacePoint { s0: [lam * sec.c[0], lam * sec.c[1], z], n0: [sec.nu[0] * iw, sec.nu[1] * iw, -lp * iw], sec, prof, w }
    }

    /// Untwisted point of the wall: S0 − η t n0 (η = 0 outer, η = 1 inner); with an outward
    /// offset S0 + (1 − η) t n0 (the designed surface S0 is the cavity, η = 1).
    pub fn untwisted_point(&self, shat: D, z: D, eta: D) -> [D; 3] {
        let sp = self.surface(shat, z);
        match self.variant.offset {
            OffsetSide::Inward => {
                let o = eta * T_WALL;
                [sp.s0[0] - o * sp.n0[0], sp.s0[1] - o * sp.n0[1], sp.s0[2] - o * sp.n0[2]]
            }
            OffsetSide::Outward => {
                let o = (cst::<D>(1.0) - eta) * T_WALL;
                [sp.s0[0] + o * sp.n0[0], sp.s0[1] + o * sp.n0[1], sp.s0[2] + o * sp.n0[2]]
            }
        }
    }

    /// Twist Tw: rotation about +z by α·z/L (φ(z) with freeform modes), applied last.
    pub fn twist(&self, p: [D; 3]) -> [D; 3] {
        let ang = self.twist_angle(p[2]).0;
        let (s, c) = ang.sin_cos();
        [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]
    }

    /// The twisted designed surface S(ŝ, z) = Tw(S0(ŝ, z)) and its outward unit normal
    /// N = (Rot(αz/L) ν, −q)/√(1 + q²), q = λ'p − λ(α/L)(c·τ).
    pub fn twisted_surface(&self, shat: D, z: D) -> ([D; 3], [D; 3]) {
        let sec = self.section.eval(shat);
        let prof = self.profile.eval(z);
        let it = self.section.t_max.recip();
        let lam = prof.rho * it;
        let dlam = prof.drho * it;
        let (ang, rate) = self.twist_angle(z);
        let q = dlam * sec.p - lam * rate * dot2(sec.c, sec.tau);
        let iw = (q * q + 1.0).sqrt().recip();
        let (sn, cs) = ang.sin_cos();
        let c = rot2([lam * sec.c[0], lam * sec.c[1]], cs, sn);
        let nu = rot2(sec.nu, cs, sn);
        ([c[0], c[1], z], [nu[0] * iw, nu[1] * iw, -q * iw])
    }

    /// Wall point X(ŝ, z, η) at the surface parameters (ŝ, z) of the designed surface, before
    /// any trimming by the end planes: Tw(S0 − η t n0) for the spec (η = 0 outer, 1 inner);
    /// Tw(S0 + (1 − η) t n0) with an outward offset; S − η t N (or S + (1 − η) t N) when the twist
    /// comes first ([`Actuator::twisted_surface`]).
    pub fn point(&self, shat: D, z: D, eta: D) -> [D; 3] {
        match self.variant.twist {
            TwistOrder::AfterOffset => self.twist(self.untwisted_point(shat, z, eta)),
            TwistOrder::BeforeOffset => {
                let (s, n) = self.twisted_surface(shat, z);
                let o = match self.variant.offset {
                    OffsetSide::Inward => -eta * T_WALL,
                    OffsetSide::Outward => (cst::<D>(1.0) - eta) * T_WALL,
                };
                [s[0] + o * n[0], s[1] + o * n[1], s[2] + o * n[2]]
            }
        }
    }

    /// Whether layer η is the designed surface itself (no offset).
    fn is_designed_layer(&self, eta: D) -> bool {
        match self.variant.offset {
            OffsetSide::Inward => eta.re() == 0.0,
            OffsetSide::Outward => eta.re() == 1.0,
        }
    }

    /// Parameter shift δ with height(X(ŝ, target + δ, η)) = target (the offset layer η meets the
    /// plane z = target), by Newton's method with a finite-difference slope of the real part; the
    /// dual parts converge with the values (at least 3 iterations after the real part has).
    fn trim_shift(&self, shat: D, eta: D, target: f64) -> D {
        let zero = D::zero();
        if self.is_designed_layer(eta) {
            return zero;
        }
        let height = |z: f64| self.point(cst::<D>(shat.re()), cst::<D>(z), cst::<D>(eta.re()))[2].re();
        let mut d = zero;
        let mut settled = 0;
        for _ in 0..60 {
            let g = self.point(shat, d + target, eta)[2] - target;
            let z = target + d.re();
            let h = 1e-6;
            let slope = (height(z + h) - height(z - h)) / (2.0 * h);
            d -= g * (1.0 / slope);
            if g.re().abs() <= 1e-13 * (1.0 + target.abs()) {
                settled += 1;
                if settled >= 3 {
                    break;
                }
            }
        }
        d
    }

    /// The trim shifts (δ0, δL) of layer η at ŝ: the parameters z = δ0 and z = L + δL of the
    /// layer's points in the planes z = 0 and z = L (zero for the spec).
    pub fn trim_shifts(&self, shat: D, eta: D) -> (D, D) {
        if !self.needs_trim() {
            return (D::zero(), D::zero());
        }
        (self.trim_shift(shat, eta, 0.0), self.trim_shift(shat, eta, L_TUBE))
    }

    /// Wall point of the solid trimmed by the end planes: X(ŝ, z', η) with the parameter
    /// z' = z + (1 − z/z_J) δ0 on the lower end arc (z < z_J), z' = z + (1 − (L − z)/z_J) δL on
    /// the upper one (z > L − z_J) and z' = z on the middle arc, so that z = 0 and z = L map onto
    /// the end planes for every layer while every point stays on its own profile arc (the nodes
    /// of the junction rings stay on the curvature jumps, and the map is smooth in the design
    /// parameters). Equal to [`Actuator::point`] when no trimming is needed (the spec).
    pub fn wall_point(&self, shat: D, z: D, eta: D) -> [D; 3] {
        if !self.needs_trim() {
            return self.point(shat, z, eta);
        }
        let sh = self.trim_shifts(shat, eta);
        self.wall_point_with(shat, z, eta, sh)
    }

    /// [`Actuator::wall_point`] with precomputed [`Actuator::trim_shifts`].
    pub fn wall_point_with(&self, shat: D, z: D, eta: D, shifts: (D, D)) -> [D; 3] {
        if !self.needs_trim() {
            return self.point(shat, z, eta);
        }
        let zj = self.profile.z_junction;
        let one = cst::<D>(1.0);
        let zp = if z.re() < zj.re() {
            z + (one - z / zj) * shifts.0
        } else if z.re() > L_TUBE - zj.re() {
            z + (one - (cst::<D>(L_TUBE) - z) / zj) * shifts.1
        } else {
            z
        };
        self.point(shat, zp, eta)
    }

    /// Outer point in polar form S(φ, z) = (λ ρsec(φ − αz/L) cos φ, …, z) (§2.4).
    pub fn outer_point_polar(&self, phi: D, z: D) -> [D; 3] {
        let (lam, _, _) = self.lambda(z);
        let rs = self.section.polar_radius(phi - self.twist_angle(z).0) * lam;
        let (s, c) = phi.sin_cos();
        [rs * c, rs * s, z]
    }

    /// Principal curvatures (k1 ≥ k2) of the untwisted outer surface S0 at (ŝ, z), positive =
    /// convex, from the analytic fundamental forms of §4.3:
    /// E = λ², F = λλ'(c·τ), G = 1 + λ'²|c|², −II = diag(λκ/W, −λ''p/W).
    pub fn principal_curvatures0(&self, shat: D, z: D) -> (D, D) {
        let sec = self.section.eval(shat);
        let (lam, dlam, d2lam) = self.lambda(z);
        let lp = dlam * sec.p;
        let w = (lp * lp + 1.0).sqrt();
        // metric in (s, z) with s the construction arc length (ds/dŝ = P)
        let e = lam * lam;
        let f = lam * dlam * dot2(sec.c, sec.tau);
        let g = dlam * dlam * dot2(sec.c, sec.c) + 1.0;
        let l2 = lam * sec.kappa / w;
        let n2 = -d2lam * sec.p / w;
        // det(II − k I) = 0 with M = 0
        let a = e * g - f * f;
        let b = -(l2 * g + n2 * e);
        let c = l2 * n2;
        let mut disc2 = b * b - a * c * 4.0;
        if disc2.re() < 0.0 {
            disc2 = cst(0.0);
        }
        let disc = disc2.sqrt();
        let k1 = (-b + disc) / (a * 2.0);
        let k2 = (-b - disc) / (a * 2.0);
        (k1, k2)
    }
}

/// How far beyond the tube radius R a freeform profile may still be built (mm): the envelope
/// ρ ≤ R is a design constraint (the optimiser's `envelope:*` constraints, with gradients), so a
/// design just across it must still be evaluable; beyond this it is refused.
pub const ENVELOPE_SLACK_MM: f64 = 1.0;

/// Samples in z of [`freeform_validity`]'s checks.
const FREEFORM_CHECK_SAMPLES: usize = 401;

/// The validity of a freeform design's surface, each a condition with a margin, checked on a
/// sample of heights: the rest radius stays within R + [`ENVELOPE_SLACK_MM`], the waist conditions of
/// [`l_min_waist`] hold at the smallest ρ (the lobe necks' offset walls stay ≥ 1 mm apart and
/// off the axis), and every convex principal radius of the outer surface is ≥ t + 0.5 mm (the
/// inward offset does not fold, as for the extended range). The twist modes change none of these
/// (the twist rotates the offset wall's horizontal slices).
pub fn freeform_validity(act: &Actuator<f64>) -> Result<(), GeometryError> {
    let n = FREEFORM_CHECK_SAMPLES;
    let (mut rmax, mut zmax, mut rmin, mut zmin) = (f64::NEG_INFINITY, 0.0, f64::INFINITY, 0.0);
    for i in 0..n {
        let z = L_TUBE * i as f64 / (n - 1) as f64;
        let rho = act.profile.eval(z).rho;
        if !rho.is_finite() {
            return Err(GeometryError::Invalid(format!("the freeform profile is not finite at z = {z:.2} mm")));
        }
        if rho > rmax {
            (rmax, zmax) = (rho, z);
        }
        if rho < rmin {
            (rmin, zmin) = (rho, z);
        }
    }
    if rmax > R_TUBE + ENVELOPE_SLACK_MM {
        return Err(GeometryError::Invalid(format!(
            "profile_*_mm: the rest radius ρ(z) = {rmax:.4} mm at z = {zmax:.2} mm exceeds the tube radius R = {R_TUBE} mm by more than {ENVELOPE_SLACK_MM} mm (the freeform profile must stay within the envelope; the optimiser holds ρ ≤ R as a constraint)"
        )));
    }
    let need = l_min_waist(act.section.r);
    if rmin < need {
        return Err(GeometryError::Invalid(format!(
            "profile_*_mm / l_mm: the smallest rest radius ρ = {rmin:.4} mm (at z = {zmin:.2} mm) is below {need:.4} mm, the least at which the offset notch walls stay 1 mm apart and off the axis at r_mm = {}",
            act.section.r
        )));
    }
    let k = max_convex_curvature0(act);
    if k * (T_WALL + 0.5) >= 1.0 {
        return Err(GeometryError::Invalid(format!(
            "profile_*_mm: the outer surface has a convex principal radius {:.3} mm < t + 0.5 mm = {} mm, so the inward offset by t would fold",
            1.0 / k,
            T_WALL + 0.5
        )));
    }
    Ok(())
}

/// Closed-form scalar summary of one design (GEOMETRY.md §0, §3, §6).
#[derive(Clone, Debug, serde::Serialize)]
pub struct GeometrySummary {
    pub r_mm: f64,
    pub l_mm: f64,
    pub alpha_deg: f64,
    pub u_rad: f64,
    pub theta_l_rad: f64,
    pub theta_n_rad: f64,
    pub x_mm: f64,
    pub d_mm: f64,
    pub e_mm: f64,
    #[serde(rename = "T_mm")]
    pub t_mm: f64,
    #[serde(rename = "B_mm")]
    pub b_mm: f64,
    #[serde(rename = "P_mm")]
    pub p_mm: f64,
    #[serde(rename = "A_mm2")]
    pub a_mm2: f64,
    pub phi_j_rad: f64,
    pub delta_mm: f64,
    /// ρa; `null` for the straight tube (l = R)
    pub rho_a_mm: Option<f64>,
    pub beta_rad: f64,
    pub profile_length_mm: f64,
    pub outer_end_area_mm2: f64,
    pub inner_end_area_mm2: f64,
    pub outer_volume_mm3: f64,
    pub chamber_volume_mm3: f64,
    pub wall_volume_mm3: f64,
    /// smallest convex principal radius of the untwisted outer surface (sampled), mm
    /// (of the untwisted designed surface for a variant)
    pub min_convex_radius_outer_mm: f64,
    /// the geometry variant (omitted for the spec)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub variant: Option<String>,
    /// the profile's end-tangent angle (omitted when the design does not carry it)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub end_tangent_deg: Option<f64>,
    /// height of the lower profile junction (omitted for the spec's L/4)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub junction_z_mm: Option<f64>,
}

/// Largest convex principal curvature of S0 over a 240 × 81 sample grid in (ŝ, z), which
/// contains the waist z = L/2, the lobe tips and the profile junctions z = L/4, 3L/4 (where the
/// convex one-sided limit is evaluated).
pub fn max_convex_curvature0(act: &Actuator<f64>) -> f64 {
    let mut kmax: f64 = 0.0;
    let ns = 240;
    let nz = 81;
    for i in 0..ns {
        let shat = i as f64 / ns as f64;
        for j in 0..nz {
            let z = L_TUBE * j as f64 / (nz - 1) as f64;
            let (k1, _) = act.principal_curvatures0(shat, z);
            kmax = kmax.max(k1);
        }
    }
    kmax
}

/// Inner end-face area A_in = (R/T)²A − t(R/T)P + πt² (Steiner formula for the offset curve).
pub fn inner_end_area<D: Scalar>(s: &Section<D>) -> D {
    let k = s.t_max.recip() * R_TUBE;
    k * k * s.area - k * s.perimeter * T_WALL + PI * T_WALL * T_WALL
}

/// Outer end-face area (R/T)²A.
pub fn outer_end_area<D: Scalar>(s: &Section<D>) -> D {
    let k = s.t_max.recip() * R_TUBE;
    k * k * s.area
}

/// End-face areas (inner, outer) of any variant. Closed forms when the end rings are plane
/// offset curves of the end section (no trimming): inward (the spec) A_in = k²A − tkP + πt²,
/// A_out = k²A; outward A_in = k²A, A_out = k²A + tkP + πt² (k = R/T, Steiner). Otherwise the
/// area ½∮(x dy − y dx) of the trimmed ring in the plane z = 0, by Gauss–Legendre quadrature per
/// arc of the section (see [`volume::end_ring_area`]).
pub fn end_areas<D: Scalar>(act: &Actuator<D>) -> (D, D) {
    let s = &act.section;
    if act.needs_trim() {
        return (volume::end_ring_area(act, 1.0), volume::end_ring_area(act, 0.0));
    }
    match act.variant.offset {
        OffsetSide::Inward => (inner_end_area(s), outer_end_area(s)),
        OffsetSide::Outward => {
            let k = s.t_max.recip() * R_TUBE;
            (k * k * s.area, k * k * s.area + k * s.perimeter * T_WALL + PI * T_WALL * T_WALL)
        }
    }
}

/// d(output)/d(param) for the scalar geometry outputs.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScalarDerivatives {
    pub param: String,
    pub outer_volume: f64,
    pub chamber_volume: f64,
    pub wall_volume: f64,
    pub inner_end_area: f64,
    pub outer_end_area: f64,
}

/// A validated design and its geometry (f64).
#[derive(Clone, Debug)]
pub struct ActuatorGeometry {
    pub design: Design,
    pub policy: RangePolicy,
    pub act: Actuator<f64>,
}

impl ActuatorGeometry {
    /// Validate the design against `policy` and build the geometry. In the extended range the
    /// principal curvatures of the outer surface are also checked (the inward offset by t must
    /// stay locally valid with a 0.5 mm margin; for an outward offset the concave radii).
    pub fn new(design: &Design, policy: RangePolicy) -> Result<Self, GeometryError> {
        let (r, l, a) = design.validate(policy)?;
        let gamma = design.end_tangent_deg().map(f64::to_radians);
        let act = Actuator::with_variant(r, l, a.to_radians(), gamma, design.variant).with_freeform(design.twist_modes_deg().map(|v| v.map(f64::to_radians)), design.profile_modes_mm());
        if let Err(why) = act.profile.check() {
            let g = design.end_tangent_deg().unwrap_or(0.0);
            return Err(GeometryError::OutOfRange { name: P_END_TANGENT.into(), value: g, range: format!("[-30, {:.3}] deg", end_tangent_max_deg(l)), hint: format!(" at l_mm = {l}: {why}") });
        }
        let g = ActuatorGeometry { design: design.clone(), policy, act };
        if act.is_freeform() {
            freeform_validity(&act)?;
        }
        if !(design.variant.is_spec() && gamma.is_none()) {
            // a variant's wall must be a valid normal offset (the spec's is, over its ranges:
            // GEOMETRY.md §4.3); twisting first can fold it where the twist shear makes the
            // designed surface's radii smaller than t
            let (k, sh, zz) = max_offset_curvature(&act);
            if k * (T_WALL + MIN_WALL_RADIUS) >= 1.0 {
                let side = if act.variant.offset == OffsetSide::Inward { "convex" } else { "concave" };
                return Err(GeometryError::Invalid(format!(
                    "variant = \"{}\" cannot be built at r_mm = {r}, l_mm = {l}, alpha_deg = {a}{}: the surface the wall is offset from has a {side} principal radius {:.3} mm < t + {MIN_WALL_RADIUS} mm (at ŝ = {sh:.3}, z = {zz:.2} mm), so its normal offset would fold or come within {MIN_WALL_RADIUS} mm of folding{}",
                    act.variant,
                    design.end_tangent_deg().map(|g| format!(", end_tangent_deg = {g}")).unwrap_or_default(),
                    1.0 / k,
                    if act.variant.twist == TwistOrder::BeforeOffset { " (the twist shear lowers the radii: reduce alpha_deg or raise l_mm)" } else { "" }
                )));
            }
        }
        if policy == RangePolicy::Extended {
            let kmax = match act.variant.offset {
                OffsetSide::Inward => g.max_convex_curvature0(),
                OffsetSide::Outward => max_concave_curvature0(&act),
            };
            if kmax * (T_WALL + 0.5) >= 1.0 {
                let side = if act.variant.offset == OffsetSide::Inward { "convex radius" } else { "concave radius" };
                let range = if design.variant.is_spec() && gamma.is_none() { format!("[{:.4}, 20] mm", l_min_extended(r).min(f64::MAX)) } else { "(0, 20] mm".into() };
                return Err(GeometryError::OutOfRange {
                    name: P_L.into(),
                    value: l,
                    range,
                    hint: format!(" (at r_mm = {r} the designed surface has a {side} {:.3} mm < t + 0.5 mm: the offset would self-intersect)", 1.0 / kmax),
                });
            }
        }
        Ok(g)
    }

    pub fn r(&self) -> f64 {
        self.act.section.r
    }
    pub fn l(&self) -> f64 {
        self.act.profile.l
    }
    pub fn alpha_rad(&self) -> f64 {
        self.act.alpha
    }

    /// The actuator with dual-number parameters, seeded so that the derivative part is
    /// d/d(parameter `seed`) (by name; α and the end tangent per **degree**). The end tangent can
    /// be seeded on a design that does not carry it (the derivative at the spec's γ = 0).
    pub fn dual_actuator(&self, seed: &str) -> Result<Actuator<num_dual::Dual64>, GeometryError> {
        use num_dual::Dual64;
        let mode = freeform::parse_param(seed);
        let (sr, sl, sa, sg): (f64, f64, f64, f64) = match (seed, mode) {
            (P_R, _) => (1.0, 0.0, 0.0, 0.0),
            (P_L, _) => (0.0, 1.0, 0.0, 0.0),
            (P_ALPHA, _) => (0.0, 0.0, 1.0, 0.0),
            (P_END_TANGENT, _) => (0.0, 0.0, 0.0, 1.0),
            (_, Some(_)) => (0.0, 0.0, 0.0, 0.0),
            (other, None) => return Err(GeometryError::UnknownParameter { name: other.to_string(), known: self.design.parameter_names().join(", ") }),
        };
        let gamma = match (self.act.profile.gamma, sg != 0.0) {
            (Some(g), _) => Some(Dual64::new(g, sg.to_radians())),
            (None, true) => Some(Dual64::new(0.0, sg.to_radians())),
            (None, false) => None,
        };
        // freeform modes: the design's (or zeros where the seeded family is absent: the
        // derivative at the spec's geometry), the seeded one with a unit derivative part
        let mut twist = self.act.twist_modes.map(|a| a.map(Dual64::from));
        let mut bumps = self.act.profile.bumps.map(|b| b.map(Dual64::from));
        match mode {
            Some((freeform::ModeKind::Twist, i)) => twist.get_or_insert([Dual64::from(0.0); freeform::N_TWIST_MODES])[i].eps = 1f64.to_radians(),
            Some((freeform::ModeKind::Profile, i)) => bumps.get_or_insert([Dual64::from(0.0); freeform::N_PROFILE_MODES])[i].eps = 1.0,
            None => {}
        }
        Ok(Actuator::with_variant(Dual64::new(self.r(), sr), Dual64::new(self.l(), sl), Dual64::new(self.alpha_rad(), sa.to_radians()), gamma, self.act.variant).with_freeform(twist, bumps))
    }

    /// Largest convex principal curvature of the untwisted outer surface over a sample grid
    /// (see [`max_convex_curvature0`]).
    pub fn max_convex_curvature0(&self) -> f64 {
        max_convex_curvature0(&self.act)
    }

    /// Inner end-face area: A_in = (R/T)²A − t(R/T)P + πt² (closed form, Steiner) for the spec;
    /// see [`end_areas`] for the variants.
    pub fn inner_end_area(&self) -> f64 {
        end_areas(&self.act).0
    }

    /// Outer end-face area: (R/T)²A for the spec; see [`end_areas`].
    pub fn outer_end_area(&self) -> f64 {
        end_areas(&self.act).1
    }

    /// Derivatives of the scalar outputs (volumes, end areas) with respect to every named
    /// design parameter (α per degree), by forward-mode dual numbers through the same
    /// quadratures as the values.
    pub fn scalar_derivatives(&self) -> Vec<ScalarDerivatives> {
        self.design
            .parameter_names()
            .into_iter()
            .map(|name| {
                let a = self.dual_actuator(&name).expect("known parameter");
                let outer = volume::outer_volume(&a).eps;
                let chamber = volume::chamber_volume(&a).eps;
                let (ain, aout) = end_areas(&a);
                ScalarDerivatives { param: name, outer_volume: outer, chamber_volume: chamber, wall_volume: outer - chamber, inner_end_area: ain.eps, outer_end_area: aout.eps }
            })
            .collect()
    }

    /// Outer volume: (A/T²)∫ρ²dz for the spec (Gauss–Legendre per profile arc: exact to
    /// round-off); see [`volume::outer_volume`].
    pub fn outer_volume(&self) -> f64 {
        volume::outer_volume(&self.act)
    }

    /// Chamber (cavity) volume: divergence theorem over the inner wall (§6), see [`volume`].
    pub fn chamber_volume(&self) -> f64 {
        volume::chamber_volume(&self.act)
    }

    pub fn wall_volume(&self) -> f64 {
        self.outer_volume() - self.chamber_volume()
    }

    pub fn summary(&self) -> GeometrySummary {
        let s = &self.act.section;
        let p = &self.act.profile;
        let outer = self.outer_volume();
        let chamber = self.chamber_volume();
        let (ain, aout) = end_areas(&self.act);
        GeometrySummary {
            r_mm: self.design.r_mm(),
            l_mm: self.design.l_mm(),
            alpha_deg: self.design.alpha_deg(),
            u_rad: s.u,
            theta_l_rad: s.theta_l,
            theta_n_rad: s.theta_n,
            x_mm: s.x,
            d_mm: s.d,
            e_mm: s.e,
            t_mm: s.t_max,
            b_mm: s.b_min,
            p_mm: s.perimeter,
            a_mm2: s.area,
            phi_j_rad: s.phi_j,
            delta_mm: p.delta,
            rho_a_mm: if p.kappa_a == 0.0 { None } else { Some(p.rho_a()) },
            beta_rad: p.beta,
            profile_length_mm: p.length,
            outer_end_area_mm2: aout,
            inner_end_area_mm2: ain,
            outer_volume_mm3: outer,
            chamber_volume_mm3: chamber,
            wall_volume_mm3: outer - chamber,
            min_convex_radius_outer_mm: 1.0 / self.max_convex_curvature0(),
            variant: if self.act.variant.is_spec() { None } else { Some(self.act.variant.name()) },
            end_tangent_deg: self.design.end_tangent_deg(),
            junction_z_mm: p.gamma.map(|_| p.z_junction),
        }
    }
}

/// Principal curvatures (k1 ≥ k2, positive = convex) of the surface the wall is offset from —
/// S0 (twist after the offset, the spec) or Tw(S0) (twist first) — at (ŝ, z), from the first and
/// second fundamental forms I_ij = S_i·S_j, B_ij = S_i·N_j (Weingarten), with the partial
/// derivatives by dual numbers.
pub fn offset_base_curvatures(act: &Actuator<f64>, shat: f64, z: f64) -> (f64, f64) {
    use num_dual::Dual64;
    let a = act.lift();
    let base = |s: Dual64, zz: Dual64| -> ([Dual64; 3], [Dual64; 3]) {
        match act.variant.twist {
            TwistOrder::BeforeOffset => a.twisted_surface(s, zz),
            TwistOrder::AfterOffset => {
                let sp = a.surface(s, zz);
                (sp.s0, sp.n0)
            }
        }
    };
    let (ps, ns) = base(Dual64::new(shat, 1.0), Dual64::from(z));
    let (pz, nz) = base(Dual64::from(shat), Dual64::new(z, 1.0));
    let v = |p: [Dual64; 3]| [p[0].eps, p[1].eps, p[2].eps];
    let (su, sv, nu, nv) = (v(ps), v(pz), v(ns), v(nz));
    let d3 = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let (a11, a12, a22) = (d3(su, su), d3(su, sv), d3(sv, sv));
    let (b11, b12, b22) = (d3(su, nu), 0.5 * (d3(su, nv) + d3(sv, nu)), d3(sv, nv));
    let qa = a11 * a22 - a12 * a12;
    let qb = -(a11 * b22 + a22 * b11 - 2.0 * a12 * b12);
    let qc = b11 * b22 - b12 * b12;
    let disc = (qb * qb - 4.0 * qa * qc).max(0.0).sqrt();
    ((-qb + disc) / (2.0 * qa), (-qb - disc) / (2.0 * qa))
}

/// The largest principal curvature on the offset side of the surface the wall is offset from
/// (convex for an inward offset, concave for an outward one; [`offset_base_curvatures`]), over a
/// 240 × 81 grid in (ŝ, z) plus the one-sided limits at the profile junctions; with its (ŝ, z).
/// The normal offset by t is locally valid (does not fold) iff this is below 1/t.
pub fn max_offset_curvature(act: &Actuator<f64>) -> (f64, f64, f64) {
    let (ns, nz) = (240, 81);
    let zj = act.profile.z_junction;
    let mut zs: Vec<f64> = (0..nz).map(|j| L_TUBE * j as f64 / (nz - 1) as f64).collect();
    zs.extend([zj, zj + 1e-9, L_TUBE - zj, L_TUBE - zj - 1e-9]);
    let mut best = (0.0f64, 0.0, 0.0);
    for i in 0..ns {
        let shat = i as f64 / ns as f64;
        for &z in &zs {
            let (k1, k2) = offset_base_curvatures(act, shat, z);
            let k = match act.variant.offset {
                OffsetSide::Inward => k1,
                OffsetSide::Outward => -k2,
            };
            if k > best.0 {
                best = (k, shat, z);
            }
        }
    }
    best
}

/// Largest concave principal curvature (−k2) of S0 over the sample grid of
/// [`max_convex_curvature0`] (the local validity of an outward offset).
pub fn max_concave_curvature0(act: &Actuator<f64>) -> f64 {
    let mut kmax: f64 = 0.0;
    let (ns, nz) = (240, 81);
    for i in 0..ns {
        let shat = i as f64 / ns as f64;
        for j in 0..nz {
            let z = L_TUBE * j as f64 / (nz - 1) as f64;
            let (_, k2) = act.principal_curvatures0(shat, z);
            kmax = kmax.max(-k2);
        }
    }
    kmax
}

/// Largest end-tangent angle (degrees) for which the profile with waist l exists with end arcs
/// turning at least [`MIN_END_ARC_TURN_RAD`] (bisection; 0 when no positive angle is possible).
pub fn end_tangent_max_deg(l: f64) -> f64 {
    let ok = |g: f64| Profile::with_end_tangent(l, g.to_radians()).check().is_ok();
    let hi0 = DesignSpace::optional().get(P_END_TANGENT).map(|p| p.max).unwrap_or(60.0);
    if ok(hi0) {
        return hi0;
    }
    if !ok(1e-9) {
        return 0.0;
    }
    let (mut lo, mut hi) = (1e-9, hi0);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if ok(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

    const R0: f64 = 8.660254037844386;

    #[test]
    fn general_six_arc_constructor_reproduces_the_spec_section() {
        // the spec's section is the ring with its own lobe-centre distance d
        for r in [R0, 10.0, 13.2, 16.0, 19.5, 20.0] {
            let a = Section::<f64>::new(r);
            let b = Section::<f64>::from_lobe_centre(r, a.d);
            for (x, y, what) in
                [(a.u, b.u, "u"), (a.e, b.e, "e"), (a.x, b.x, "x"), (a.t_max, b.t_max, "T"), (a.b_min, b.b_min, "B"), (a.perimeter, b.perimeter, "P"), (a.area, b.area, "A"), (a.phi_j, b.phi_j, "φJ")]
            {
                assert!((x - y).abs() < 1e-11 * (1.0 + x.abs()), "r = {r} {what}: {x} vs {y}");
            }
        }
        // readings: (A) has its tips on R; the midpoint-centre reading is the spec at 5√3
        for r in [R0, 13.2, 20.0] {
            let a = Section::<f64>::with_reading(r, SectionReading::TipsOnR);
            assert!((a.t_max - R_TUBE).abs() < 1e-12 && (a.d - (R_TUBE - r)).abs() < 1e-12);
            let m = Section::<f64>::with_reading(r, SectionReading::MidpointCentres);
            assert!((m.d - R_TUBE / 2.0).abs() < 1e-12);
        }
        let (m, s) = (Section::<f64>::with_reading(R0, SectionReading::MidpointCentres), Section::<f64>::new(R0));
        assert!((m.u - s.u).abs() < 1e-14 && (m.e - s.e).abs() < 1e-12);
        // GEOMETRY.md §8 (A): 189° lobes at r = 5√3, and the circle at r = 20
        let a = Section::<f64>::with_reading(R0, SectionReading::TipsOnR);
        assert!((a.theta_l.to_degrees() - 189.08).abs() < 0.01, "{}", a.theta_l.to_degrees());
        let c = Section::<f64>::with_reading(20.0, SectionReading::TipsOnR);
        assert!(c.u == 0.0 && (c.area - PI * 400.0).abs() < 1e-9);
        // derivatives stay finite where e = 2d (atan2 at x = 0): the midpoint reading at 5√3
        let d = Section::<Dual64>::with_reading(Dual64::new(R0, 1.0), SectionReading::MidpointCentres);
        assert!(d.u.eps.is_finite() && d.phi_j.eps.is_finite());
        let h = 1e-6;
        let fd = (Section::<f64>::with_reading(R0 + h, SectionReading::MidpointCentres).u - Section::<f64>::with_reading(R0 - h, SectionReading::MidpointCentres).u) / (2.0 * h);
        assert!((fd - d.u.eps).abs() < 1e-7, "{fd} vs {}", d.u.eps);
    }

    #[test]
    fn end_tangent_zero_is_the_spec_profile_and_other_angles_keep_the_letter_conditions() {
        for l in [10.0, 12.15, 16.0, 19.5, 20.0] {
            let s = Profile::<f64>::new(l);
            let g = Profile::<f64>::with_end_tangent(l, 0.0);
            assert!((s.kappa_a - g.kappa_a).abs() < 1e-15 && (s.beta - g.beta).abs() < 1e-14 && (s.length - g.length).abs() < 1e-12, "l = {l}");
            assert_eq!(g.z_junction, L_TUBE / 4.0);
            for k in 0..=40 {
                let z = k as f64;
                let (a, b) = (s.eval(z), g.eval(z));
                assert!((a.rho - b.rho).abs() < 1e-12 && (a.drho - b.drho).abs() < 1e-12, "l = {l} z = {z}");
                let zeta = k as f64 / 40.0;
                let (p, q) = (s.at_arclength(zeta), g.at_arclength(zeta));
                assert!((p.0 - q.0).abs() < 1e-12 && (p.1 - q.1).abs() < 1e-12, "l = {l} ζ = {zeta}");
            }
        }
        for l in [10.0, 12.0, 15.0, 18.0] {
            for gd in [-25.0f64, -5.0, 7.0, 20.0] {
                let g = gd.to_radians();
                let p = Profile::<f64>::with_end_tangent(l, g);
                if gd > end_tangent_max_deg(l) {
                    assert!(p.check().is_err());
                    continue;
                }
                p.check().unwrap();
                let tag = format!("l = {l}, γ = {gd}°");
                // ends at R with slope −tan γ, waist l with zero slope, mirror symmetric
                let (e0, el, w) = (p.eval(0.0), p.eval(L_TUBE), p.eval(L_TUBE / 2.0));
                assert!((e0.rho - R_TUBE).abs() < 1e-12 && (el.rho - R_TUBE).abs() < 1e-12, "{tag}");
                assert!((e0.drho + g.tan()).abs() < 1e-12 && (el.drho - g.tan()).abs() < 1e-12, "{tag}");
                assert!((w.rho - l).abs() < 1e-12 && w.drho.abs() < 1e-12, "{tag}");
                // C1 at the junctions, curvature ∓κ on either side (three arcs of one radius)
                for zj in [p.z_junction, L_TUBE - p.z_junction] {
                    let (a, b) = (p.eval(zj - 1e-7), p.eval(zj + 1e-7));
                    assert!((a.rho - b.rho).abs() < 1e-6 && (a.drho - b.drho).abs() < 1e-6, "{tag}: C1 at {zj}");
                    assert!(a.d2rho * b.d2rho < 0.0, "{tag}: curvature changes sign at {zj}");
                    let curv = |v: ProfileValue<f64>| v.d2rho.abs() / (1.0 + v.drho * v.drho).powf(1.5);
                    assert!((curv(a) - p.kappa_a).abs() < 1e-6 && (curv(b) - p.kappa_a).abs() < 1e-6, "{tag}: radius");
                }
                // the arc-length parameterisation lies on the profile, with the junctions at ζ = 1/4, 3/4
                let (zq, rq) = p.at_arclength(0.25);
                assert!((zq - p.z_junction).abs() < 1e-11, "{tag}: junction {zq} vs {}", p.z_junction);
                let mut len = 0.0;
                let n = 4000;
                let mut prev = p.at_arclength(0.0);
                for k in 1..=n {
                    let cur = p.at_arclength(k as f64 / n as f64);
                    assert!((p.eval(cur.0).rho - cur.1).abs() < 1e-10, "{tag}: on the profile at ζ = {}", k as f64 / n as f64);
                    len += ((cur.0 - prev.0).powi(2) + (cur.1 - prev.1).powi(2)).sqrt();
                    prev = cur;
                }
                assert!((len - p.length).abs() < 1e-5 * p.length, "{tag}: length {len} vs {}", p.length);
                let _ = rq;
            }
        }
        // existence bound: the single-arc limit γ = 2 atan(2δ/L) less the minimum end-arc turn
        let gm = end_tangent_max_deg(10.0);
        assert!(gm < (2.0 * (0.5f64).atan()).to_degrees() && gm > (2.0 * (0.5f64).atan()).to_degrees() - 5.0, "{gm}");
        assert!(Profile::<f64>::with_end_tangent(10.0, (gm - 1e-6).to_radians()).check().is_ok());
        assert!(Profile::<f64>::with_end_tangent(10.0, (gm + 1e-6).to_radians()).check().is_err());
        assert_eq!(end_tangent_max_deg(20.0), 0.0);
    }

    #[test]
    fn twisted_normal_is_the_unit_normal_and_twist_first_keeps_the_wall_thickness() {
        let act = Actuator::<f64>::with_variant(R0, 12.0, 150f64.to_radians(), None, GeometryVariant::parse("twist-first").unwrap());
        let a = act.lift();
        for &(s, z) in &[(0.03, 5.0), (0.2, 12.0), (0.41, 20.0), (0.77, 33.0)] {
            let (ps, n) = a.twisted_surface(Dual64::new(s, 1.0), Dual64::from(z));
            let (pz, _) = a.twisted_surface(Dual64::from(s), Dual64::new(z, 1.0));
            let nn: [f64; 3] = [n[0].re, n[1].re, n[2].re];
            let d = |v: [Dual64; 3]| v[0].eps * nn[0] + v[1].eps * nn[1] + v[2].eps * nn[2];
            assert!(d(ps).abs() < 1e-12 && d(pz).abs() < 1e-12, "normal ⟂ tangents at ({s}, {z})");
            assert!(((nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt() - 1.0).abs() < 1e-14);
            // the inner point is t away from the outer one along the normal
            let (o, i) = (act.point(s, z, 0.0), act.point(s, z, 1.0));
            let dist = ((o[0] - i[0]).powi(2) + (o[1] - i[1]).powi(2) + (o[2] - i[2]).powi(2)).sqrt();
            assert!((dist - T_WALL).abs() < 1e-12);
        }
        // α = 0: twisting first or last is the same wall
        let v0 = Actuator::<f64>::with_variant(R0, 12.0, 0.0, None, GeometryVariant::parse("twist-first").unwrap());
        let s0 = Actuator::<f64>::new(R0, 12.0, 0.0);
        let (p, q) = (v0.point(0.3, 14.0, 0.6), s0.point(0.3, 14.0, 0.6));
        assert!((0..3).all(|c| (p[c] - q[c]).abs() < 1e-12));
    }

    #[test]
    fn trimmed_walls_end_in_the_end_planes() {
        for (name, g) in [("twist-first", None), ("spec", Some(15f64)), ("outward+twist-first", Some(-10.0)), ("tips-on-r", Some(25.0))] {
            let v = GeometryVariant::parse(name).unwrap();
            let act = Actuator::<f64>::with_variant(R0, 13.0, 100f64.to_radians(), g.map(f64::to_radians), v);
            assert!(act.needs_trim());
            for eta in [0.0, 0.5, 1.0] {
                for i in 0..24 {
                    let s = i as f64 / 24.0;
                    let (b, t) = (act.wall_point(s, 0.0, eta), act.wall_point(s, L_TUBE, eta));
                    assert!(b[2].abs() < 1e-12 && (t[2] - L_TUBE).abs() < 1e-12, "{name} η = {eta} ŝ = {s}: {} {}", b[2], t[2]);
                }
            }
        }
        // the spec needs none (its offset is horizontal at the ends)
        assert!(!Actuator::<f64>::new(R0, 13.0, 1.0).needs_trim());
    }
}
