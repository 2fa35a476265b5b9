//! The actuator geometry of `GEOMETRY.md` (shared spec), implemented exactly:
//! six-arc "triangular horseshoe" section, three-arc bellows profile, isotropic blending,
//! inward 3-D normal offset of the wall and a linear twist applied last.
//!
//! Every formula is generic over [`Scalar`] (`f64` or a `num_dual` dual number), so that node
//! coordinates can be differentiated with respect to every design parameter.
//!
//! Conventions: mm, angles in radians inside the formulas (α is given in degrees in a
//! [`Design`]). ŝ ∈ [0, 1) is the normalised arc length of the section, ŝ = 0 at the tip of
//! lobe 0, the point (T, 0) of the construction frame.

pub mod design;
pub mod scalar;
pub mod volume;

pub use design::{
    l_min_extended, l_min_waist, offset_locally_valid, r_min_extended, Design, DesignSpace, GeometryError, ParamSpec, RangePolicy,
    P_ALPHA, P_L, P_R,
};
pub use scalar::Scalar;

use scalar::{cst, dot2, rot2, sinc, versinc};
use std::f64::consts::{FRAC_PI_3, PI};

/// Tube outer radius R (mm).
pub const R_TUBE: f64 = 20.0;
/// Actuator height L (mm).
pub const L_TUBE: f64 = 40.0;
/// Wall thickness t (mm).
pub const T_WALL: f64 = 3.0;
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

/// The bellows profile ρ(z): three tangent arcs of radius ρa, vertical at both ends (§3).
#[derive(Clone, Copy, Debug)]
pub struct Profile<D> {
    /// waist radius l
    pub l: D,
    /// δ = R − l
    pub delta: D,
    /// curvature 1/ρa of the arcs (0 for the straight tube l = R)
    pub kappa_a: D,
    /// turning angle β of each end arc, 2 atan(2δ/L)
    pub beta: D,
    /// total arc length 4ρaβ (L for the straight tube)
    pub length: D,
}

/// Value and derivatives of the profile at one height.
#[derive(Clone, Copy, Debug)]
pub struct ProfileValue<D> {
    pub rho: D,
    pub drho: D,
    pub d2rho: D,
}

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
        Profile { l, delta, kappa_a, beta, length }
    }

    /// Arc radius ρa (infinite for the straight tube).
    pub fn rho_a(&self) -> D {
        self.kappa_a.recip()
    }

    /// ρ(z), ρ'(z), ρ''(z). z outside [0, L] is clamped to the nearest end arc formula.
    pub fn eval(&self, z: D) -> ProfileValue<D> {
        let k = self.kappa_a;
        let zr = z.re();
        let one = cst::<D>(1.0);
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
    pub fn at_arclength(&self, zeta: f64) -> (D, D) {
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
        Actuator { section: Section::new(r), profile: Profile::new(l), alpha: alpha_rad }
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
        SurfacePoint {
            s0: [lam * sec.c[0], lam * sec.c[1], z],
            n0: [sec.nu[0] * iw, sec.nu[1] * iw, -lp * iw],
            sec,
            prof,
            w,
        }
    }

    /// Untwisted point of the wall: S0 − η t n0 (η = 0 outer, η = 1 inner).
    pub fn untwisted_point(&self, shat: D, z: D, eta: D) -> [D; 3] {
        let sp = self.surface(shat, z);
        let o = eta * T_WALL;
        [sp.s0[0] - o * sp.n0[0], sp.s0[1] - o * sp.n0[1], sp.s0[2] - o * sp.n0[2]]
    }

    /// Twist Tw: rotation about +z by α·z/L, applied last.
    pub fn twist(&self, p: [D; 3]) -> [D; 3] {
        let ang = self.alpha * p[2] * (1.0 / L_TUBE);
        let (s, c) = ang.sin_cos();
        [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]
    }

    /// Final wall point X(ŝ, z, η) = Tw(S0 − η t n0).
    pub fn point(&self, shat: D, z: D, eta: D) -> [D; 3] {
        self.twist(self.untwisted_point(shat, z, eta))
    }

    /// Outer point in polar form S(φ, z) = (λ ρsec(φ − αz/L) cos φ, …, z) (§2.4).
    pub fn outer_point_polar(&self, phi: D, z: D) -> [D; 3] {
        let (lam, _, _) = self.lambda(z);
        let rs = self.section.polar_radius(phi - self.alpha * z * (1.0 / L_TUBE)) * lam;
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
    pub min_convex_radius_outer_mm: f64,
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
    /// stay locally valid with a 0.5 mm margin).
    pub fn new(design: &Design, policy: RangePolicy) -> Result<Self, GeometryError> {
        let (r, l, a) = design.validate(policy)?;
        let act = Actuator::new(r, l, a.to_radians());
        let g = ActuatorGeometry { design: design.clone(), policy, act };
        if policy == RangePolicy::Extended {
            let kmax = g.max_convex_curvature0();
            if kmax * (T_WALL + 0.5) >= 1.0 {
                return Err(GeometryError::OutOfRange {
                    name: P_L.into(),
                    value: l,
                    range: format!("[{:.4}, 20] mm", l_min_extended(r).min(f64::MAX)),
                    hint: format!(
                        " (at r_mm = {r} the outer surface has a convex radius {:.3} mm < t + 0.5 mm: the inward offset would self-intersect)",
                        1.0 / kmax
                    ),
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
    /// d/d(parameter `seed`) (by name; α derivative is per **degree**).
    pub fn dual_actuator(&self, seed: &str) -> Result<Actuator<num_dual::Dual64>, GeometryError> {
        use num_dual::Dual64;
        let (sr, sl, sa): (f64, f64, f64) = match seed {
            P_R => (1.0, 0.0, 0.0),
            P_L => (0.0, 1.0, 0.0),
            P_ALPHA => (0.0, 0.0, 1.0),
            other => {
                return Err(GeometryError::UnknownParameter {
                    name: other.to_string(),
                    known: DesignSpace::actuator().names().join(", "),
                })
            }
        };
        Ok(Actuator::new(
            Dual64::new(self.r(), sr),
            Dual64::new(self.l(), sl),
            Dual64::new(self.alpha_rad(), sa.to_radians()),
        ))
    }

    /// Largest convex principal curvature of the untwisted outer surface over a sample grid
    /// (see [`max_convex_curvature0`]).
    pub fn max_convex_curvature0(&self) -> f64 {
        max_convex_curvature0(&self.act)
    }

    /// Inner end-face area A_in = (R/T)²A − t(R/T)P + πt² (closed form, Steiner).
    pub fn inner_end_area(&self) -> f64 {
        inner_end_area(&self.act.section)
    }

    /// Outer end-face area (R/T)²A.
    pub fn outer_end_area(&self) -> f64 {
        outer_end_area(&self.act.section)
    }

    /// Derivatives of the scalar outputs (volumes, end areas) with respect to every named
    /// design parameter (α per degree), by forward-mode dual numbers through the same
    /// quadratures as the values.
    pub fn scalar_derivatives(&self) -> Vec<ScalarDerivatives> {
        DesignSpace::actuator()
            .names()
            .into_iter()
            .map(|name| {
                let a = self.dual_actuator(name).expect("known parameter");
                let outer = volume::outer_volume(&a).eps;
                let chamber = volume::chamber_volume(&a).eps;
                ScalarDerivatives {
                    param: name.to_string(),
                    outer_volume: outer,
                    chamber_volume: chamber,
                    wall_volume: outer - chamber,
                    inner_end_area: inner_end_area(&a.section).eps,
                    outer_end_area: outer_end_area(&a.section).eps,
                }
            })
            .collect()
    }

    /// Outer volume (A/T²)∫ρ²dz (Gauss–Legendre per profile arc: exact to round-off).
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
            outer_end_area_mm2: self.outer_end_area(),
            inner_end_area_mm2: self.inner_end_area(),
            outer_volume_mm3: outer,
            chamber_volume_mm3: chamber,
            wall_volume_mm3: outer - chamber,
            min_convex_radius_outer_mm: 1.0 / self.max_convex_curvature0(),
        }
    }
}
