//! Named design parameters, their admissible ranges and validation.
//!
//! The optimiser sees a design as a list of *named* parameters (`r_mm`, `l_mm`, `alpha_deg`)
//! described by a [`DesignSpace`]; nothing downstream depends on there being exactly three.
//!
//! Besides the three Table-I parameters a design may carry *optional* shape parameters of the
//! geometry variants ([`DesignSpace::optional`]: `end_tangent_deg`) and a [`GeometryVariant`].
//! An optional parameter that is absent takes the spec's value through the spec's code path
//! (bit-identical); one that is present is a design parameter like the others (gradients,
//! optimisation variables).

use std::collections::BTreeMap;

use super::{section_constants_f64, GeometryVariant, SectionReading, R_TUBE, T_WALL};

/// Name of the lobe/notch arc radius parameter (construction frame), mm.
pub const P_R: &str = "r_mm";
/// Name of the waist radius (minimal lateral radius) parameter, mm.
pub const P_L: &str = "l_mm";
/// Name of the end-to-end pre-twist parameter, degrees.
pub const P_ALPHA: &str = "alpha_deg";
/// Name of the optional end-tangent angle of the lateral profile (from the vertical, positive =
/// leaning towards the axis), degrees; the spec's value is 0 (vertical ends).
pub const P_END_TANGENT: &str = "end_tangent_deg";

/// Which parameter box a design is validated against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum RangePolicy {
    /// The letter's Table I box: r ∈ [5√3, 20] mm, l ∈ [10, 20] mm, α ∈ [60°, 360°].
    #[default]
    TableI,
    /// The range the construction supports (GEOMETRY.md §2.2, §3, §4.3):
    /// r ∈ [R√21/14, 20] mm, l ∈ [l_min(r), 20] mm with the offset-validity bound
    /// [`l_min_extended`], α any finite value (negative allowed).
    Extended,
}

/// One named design parameter and its Table-I range.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ParamSpec {
    pub name: String,
    pub unit: String,
    pub description: String,
    /// Table-I lower bound.
    pub min: f64,
    /// Table-I upper bound.
    pub max: f64,
}

/// The list of design parameters the geometry understands.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DesignSpace {
    pub params: Vec<ParamSpec>,
}

impl Default for DesignSpace {
    fn default() -> Self {
        Self::actuator()
    }
}

impl DesignSpace {
    /// The twisting actuator's design space (Table I of the letter).
    pub fn actuator() -> Self {
        DesignSpace {
            params: vec![
                ParamSpec { name: P_R.into(), unit: "mm".into(), description: "arc radius of the horseshoe section (construction frame)".into(), min: 5.0 * 3f64.sqrt(), max: 20.0 },
                ParamSpec { name: P_L.into(), unit: "mm".into(), description: "minimal lateral radius of the bellows profile (waist)".into(), min: 10.0, max: 20.0 },
                ParamSpec { name: P_ALPHA.into(), unit: "deg".into(), description: "pre-twist of the top face relative to the bottom face".into(), min: 60.0, max: 360.0 },
            ],
        }
    }

    /// Optional shape parameters of the geometry variants (not in Table I; absent = the spec's
    /// value). `min`/`max` are the box they are validated against (the end tangent is also
    /// limited by the profile's existence at the design's l, see [`super::Profile::check`]).
    pub fn optional() -> Self {
        use super::freeform::{profile_param, twist_param, N_PROFILE_MODES, N_TWIST_MODES, PROFILE_MODE_MAX_MM, TWIST_MODE_MAX_DEG};
        let mut params = vec![ParamSpec {
            name: P_END_TANGENT.into(),
            unit: "deg".into(),
            description: "end-tangent angle of the lateral profile from the vertical (0 = the spec's vertical ends, > 0 leaning towards the axis)".into(),
            min: -30.0,
            max: 60.0,
        }];
        for k in 1..=N_TWIST_MODES {
            params.push(ParamSpec {
                name: twist_param(k),
                unit: "deg".into(),
                description: format!("freeform twist law: coefficient of sin({k}πz/L) added to the linear pre-twist αz/L (the end-to-end twist stays α)"),
                min: -TWIST_MODE_MAX_DEG,
                max: TWIST_MODE_MAX_DEG,
            });
        }
        for k in 1..=N_PROFILE_MODES {
            params.push(ParamSpec {
                name: profile_param(k),
                unit: "mm".into(),
                description: format!("freeform lateral profile: coefficient of sin²(πz/L)·cos({}πz/L) added to the bellows radius ρ(z) (value and slope zero at both ends)", k - 1),
                min: -PROFILE_MODE_MAX_MM,
                max: PROFILE_MODE_MAX_MM,
            });
        }
        DesignSpace { params }
    }

    /// The freeform design space: Table I's three parameters and every freeform mode (the
    /// letter's family is its subspace where the modes are zero).
    pub fn freeform() -> Self {
        let mut s = Self::actuator();
        s.params.extend(Self::optional().params.into_iter().filter(|p| super::freeform::parse_param(&p.name).is_some()));
        s
    }

    /// A parameter of the actuator space or of the optional space, by name.
    pub fn lookup(name: &str) -> Option<ParamSpec> {
        DesignSpace::actuator().get(name).cloned().or_else(|| DesignSpace::optional().get(name).cloned())
    }

    pub fn names(&self) -> Vec<&str> {
        self.params.iter().map(|p| p.name.as_str()).collect()
    }

    pub fn get(&self, name: &str) -> Option<&ParamSpec> {
        self.params.iter().find(|p| p.name == name)
    }

    pub fn len(&self) -> usize {
        self.params.len()
    }

    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }

    /// Design from a vector of values in the order of `params` (for optimisers).
    pub fn design_from_vec(&self, x: &[f64]) -> Result<Design, GeometryError> {
        if x.len() != self.params.len() {
            return Err(GeometryError::Invalid(format!("design vector has {} entries; the design space has {} ({})", x.len(), self.params.len(), self.names().join(", "))));
        }
        Ok(Design { values: self.params.iter().zip(x).map(|(p, v)| (p.name.clone(), *v)).collect(), variant: GeometryVariant::default() })
    }

    /// Values of a design in the order of `params`.
    pub fn design_to_vec(&self, d: &Design) -> Result<Vec<f64>, GeometryError> {
        self.params.iter().map(|p| d.get(&p.name)).collect()
    }
}

/// Reasons a design or geometry request is rejected. Every message is one line and names the
/// offending field and the allowed range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    #[error("{name} = {value} is not a finite number (allowed range {range})")]
    NotFinite { name: String, value: f64, range: String },
    #[error("{name} = {value} is outside the allowed range {range}{hint}")]
    OutOfRange { name: String, value: f64, range: String, hint: String },
    #[error("unknown design parameter '{name}' (known parameters: {known})")]
    UnknownParameter { name: String, known: String },
    #[error("design parameter '{name}' is missing (required parameters: {known})")]
    MissingParameter { name: String, known: String },
    #[error("{0}")]
    Invalid(String),
}

/// Numerical range as text, e.g. "[8.660254, 20] mm".
fn range_text(lo: f64, hi: f64, unit: &str) -> String {
    let f = |x: f64| {
        if x.is_infinite() {
            if x > 0.0 {
                "+inf".to_string()
            } else {
                "-inf".to_string()
            }
        } else {
            let s = format!("{x:.6}");
            let s = s.trim_end_matches('0').trim_end_matches('.').to_string();
            s
        }
    };
    format!("[{}, {}] {unit}", f(lo), f(hi))
}

/// Lower bound of r for the extended range, R√21/14 ≈ 6.547 mm (u reaches its limit π/2 − ψ0).
pub fn r_min_extended() -> f64 {
    R_TUBE * 21f64.sqrt() / 14.0
}

/// Safe lower bound on l for the extended range at a given r (GEOMETRY.md §4.3).
///
/// Two conditions, both with a safety margin:
/// 1. **Global, at the waist** (analytic; the section there is the construction section scaled by
///    l/T and the wall normal is horizontal): the lobe neck (√3·e − 2r)·l/T ≥ 2t + 1 mm (the two
///    offset notch walls stay ≥ 1 mm apart) and the notch bottom B·l/T ≥ t + 1 mm (the inner wall
///    stays ≥ 1 mm off the axis); see [`l_min_waist`].
/// 2. **Local offset validity**: every convex principal radius of the untwisted outer surface S0
///    is ≥ t + 0.5 mm (so the inner wall's radii stay ≥ 0.5 mm). For l ≥ 10 the smallest radius is
///    the waist lobe r·l/T, but for smaller l the one-sided limit on the lobe flanks at the
///    profile junctions z = L/4, 3L/4 takes over, so this bound is found by bisection in l on
///    the sampled principal curvatures ([`offset_locally_valid`]).
///
/// l = 20 is always allowed when r ≤ 20 satisfies condition 1 at l = 20; if no l ≤ 20 works the
/// bound is returned as infinite (no valid l for that r). For r = 5√3 the bound is ≈ 7.91 mm
/// (Table I's l ≥ 10 is inside it everywhere).
pub fn l_min_extended(r: f64) -> f64 {
    let l0 = l_min_waist(r);
    if l0 > R_TUBE {
        return l0;
    }
    if offset_locally_valid(r, l0) {
        return l0;
    }
    if !offset_locally_valid(r, R_TUBE) {
        return f64::INFINITY;
    }
    let (mut lo, mut hi) = (l0, R_TUBE);
    while hi - lo > 1e-7 {
        let mid = 0.5 * (lo + hi);
        if offset_locally_valid(r, mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi + 1e-6
}

/// The analytic waist conditions of [`l_min_extended`] (also r·l/T ≥ t + 0.5 for the waist lobe).
pub fn l_min_waist(r: f64) -> f64 {
    let s = section_constants_f64(r);
    let t = T_WALL;
    let c1 = (t + 0.5) * s.t_max / r;
    let neck = 3f64.sqrt() * s.e - 2.0 * r;
    let c2 = if neck > 0.0 { (2.0 * t + 1.0) * s.t_max / neck } else { f64::INFINITY };
    let c3 = if s.b_min > 0.0 { (t + 1.0) * s.t_max / s.b_min } else { f64::INFINITY };
    c1.max(c2).max(c3).max(0.0)
}

/// True when every sampled convex principal radius of S0 is ≥ t + 0.5 mm.
pub fn offset_locally_valid(r: f64, l: f64) -> bool {
    let act = super::Actuator::new(r, l, 0.0);
    super::max_convex_curvature0(&act) * (T_WALL + 0.5) < 1.0
}

/// A design: a value for every parameter of a [`DesignSpace`], by name (plus any optional
/// parameters of [`DesignSpace::optional`]), and the geometry variant.
#[derive(Clone, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Design {
    pub values: BTreeMap<String, f64>,
    /// the reading of the geometry (default and omitted from JSON: the spec)
    #[serde(default, skip_serializing_if = "GeometryVariant::is_spec")]
    pub variant: GeometryVariant,
}

/// Known names (actuator + optional) for messages.
fn known_names() -> String {
    let mut v: Vec<String> = DesignSpace::actuator().names().iter().map(|s| s.to_string()).collect();
    v.extend(DesignSpace::optional().names().iter().map(|s| format!("{s} (optional)")));
    v.join(", ")
}

impl Design {
    /// Build a design from (name, value) pairs. Names are checked against the actuator design
    /// space (unknown or missing names are errors); ranges are checked by [`Design::validate`].
    pub fn from_pairs(pairs: &[(&str, f64)]) -> Result<Self, GeometryError> {
        let space = DesignSpace::actuator();
        let known = known_names();
        let mut values = BTreeMap::new();
        for (k, v) in pairs {
            if DesignSpace::lookup(k).is_none() {
                return Err(GeometryError::UnknownParameter { name: k.to_string(), known });
            }
            values.insert(k.to_string(), *v);
        }
        for p in &space.params {
            if !values.contains_key(&p.name) {
                return Err(GeometryError::MissingParameter { name: p.name.clone(), known: space.names().join(", ") });
            }
        }
        Ok(Design { values, variant: GeometryVariant::default() })
    }

    /// The same design with another geometry variant.
    pub fn with_variant(mut self, variant: GeometryVariant) -> Self {
        self.variant = variant;
        self
    }

    /// The same design with the optional end-tangent angle set (degrees).
    pub fn with_end_tangent(mut self, deg: f64) -> Self {
        self.values.insert(P_END_TANGENT.to_string(), deg);
        self
    }

    /// The freeform twist-law coefficients (degrees, absent ones 0), if the design carries any.
    pub fn twist_modes_deg(&self) -> Option<[f64; super::freeform::N_TWIST_MODES]> {
        self.modes(super::freeform::ModeKind::Twist)
    }

    /// The freeform profile coefficients (mm, absent ones 0), if the design carries any.
    pub fn profile_modes_mm(&self) -> Option<[f64; super::freeform::N_PROFILE_MODES]> {
        self.modes(super::freeform::ModeKind::Profile)
    }

    fn modes<const N: usize>(&self, kind: super::freeform::ModeKind) -> Option<[f64; N]> {
        let mut out = [0.0; N];
        let mut any = false;
        for (name, v) in &self.values {
            if let Some((k, i)) = super::freeform::parse_param(name) {
                if k == kind && i < N {
                    out[i] = *v;
                    any = true;
                }
            }
        }
        any.then_some(out)
    }

    /// The end-tangent angle (degrees) if the design carries it.
    pub fn end_tangent_deg(&self) -> Option<f64> {
        self.values.get(P_END_TANGENT).copied()
    }

    /// The names of the parameters this design is differentiated with respect to: the actuator's
    /// (Table I) and the optional ones the design carries.
    pub fn parameter_names(&self) -> Vec<String> {
        let mut v: Vec<String> = DesignSpace::actuator().names().iter().map(|s| s.to_string()).collect();
        for p in DesignSpace::optional().params {
            if self.values.contains_key(&p.name) {
                v.push(p.name);
            }
        }
        v
    }

    /// Convenience constructor for the actuator's three parameters.
    pub fn new(r_mm: f64, l_mm: f64, alpha_deg: f64) -> Self {
        let mut values = BTreeMap::new();
        values.insert(P_R.to_string(), r_mm);
        values.insert(P_L.to_string(), l_mm);
        values.insert(P_ALPHA.to_string(), alpha_deg);
        Design { values, variant: GeometryVariant::default() }
    }

    /// The letter's example design r = 5√3, l = 10, α = 60°.
    pub fn paper_example() -> Self {
        Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0)
    }

    pub fn get(&self, name: &str) -> Result<f64, GeometryError> {
        if let Some(v) = self.values.get(name) {
            return Ok(*v);
        }
        if DesignSpace::optional().get(name).is_some() {
            // absent optional parameter: the spec's value (0 for every one of them)
            return Ok(0.0);
        }
        Err(GeometryError::MissingParameter { name: name.to_string(), known: DesignSpace::actuator().names().join(", ") })
    }

    pub fn r_mm(&self) -> f64 {
        self.values.get(P_R).copied().unwrap_or(f64::NAN)
    }
    pub fn l_mm(&self) -> f64 {
        self.values.get(P_L).copied().unwrap_or(f64::NAN)
    }
    pub fn alpha_deg(&self) -> f64 {
        self.values.get(P_ALPHA).copied().unwrap_or(f64::NAN)
    }

    /// The same design with one parameter changed (name must exist; an optional parameter may
    /// be set on a design that does not carry it yet).
    pub fn with(&self, name: &str, value: f64) -> Result<Self, GeometryError> {
        if !self.values.contains_key(name) && DesignSpace::optional().get(name).is_none() {
            return Err(GeometryError::UnknownParameter { name: name.to_string(), known: self.values.keys().cloned().collect::<Vec<_>>().join(", ") });
        }
        let mut d = self.clone();
        d.values.insert(name.to_string(), value);
        Ok(d)
    }

    /// Check names, finiteness and ranges. Returns (r, l, α in degrees).
    pub fn validate(&self, policy: RangePolicy) -> Result<(f64, f64, f64), GeometryError> {
        let space = DesignSpace::actuator();
        for k in self.values.keys() {
            if DesignSpace::lookup(k).is_none() {
                return Err(GeometryError::UnknownParameter { name: k.clone(), known: known_names() });
            }
        }
        for p in DesignSpace::optional().params {
            let Some(&g) = self.values.get(&p.name) else { continue };
            let range = range_text(p.min, p.max, &p.unit);
            if !g.is_finite() {
                return Err(GeometryError::NotFinite { name: p.name, value: g, range });
            }
            if g < p.min || g > p.max {
                return Err(GeometryError::OutOfRange { name: p.name, value: g, range, hint: String::new() });
            }
        }
        if !self.variant.is_spec() && self.variant.section != SectionReading::Triangle && policy == RangePolicy::Extended {
            // the r-extension below 5√3 is the spec section's own analysis (GEOMETRY.md §2.2);
            // the other readings keep r in the Table-I range (l and α are extended)
            let p = space.get(P_R).expect("known parameter").clone();
            let r = self.get(P_R)?;
            let range = range_text(p.min, p.max, &p.unit);
            if !r.is_finite() {
                return Err(GeometryError::NotFinite { name: P_R.into(), value: r, range });
            }
            let tol = 1e-9 * p.max;
            if r < p.min - tol || r > p.max + tol {
                return Err(GeometryError::OutOfRange { name: P_R.into(), value: r, range, hint: format!(" (extended range with geometry variant '{}': r keeps the Table-I range)", self.variant) });
            }
            let l = self.get(P_L)?;
            let a = self.get(P_ALPHA)?;
            if !l.is_finite() || !(l > 0.0 && l <= R_TUBE + 1e-9) {
                return Err(GeometryError::OutOfRange { name: P_L.into(), value: l, range: "(0, 20] mm".into(), hint: " (extended range)".into() });
            }
            if !a.is_finite() {
                return Err(GeometryError::NotFinite { name: P_ALPHA.into(), value: a, range: "(-inf, +inf) deg".into() });
            }
            return Ok((r.min(R_TUBE), l.min(R_TUBE), a));
        }
        let r = self.get(P_R)?;
        let l = self.get(P_L)?;
        let a = self.get(P_ALPHA)?;
        let hint_ext = " (Table I box; pass --extended-range / RangePolicy::Extended for the wider range the construction supports)";
        let ps = |n: &str| space.get(n).expect("known parameter").clone();
        match policy {
            RangePolicy::TableI => {
                for (name, v) in [(P_R, r), (P_L, l), (P_ALPHA, a)] {
                    let p = ps(name);
                    let range = range_text(p.min, p.max, &p.unit);
                    if !v.is_finite() {
                        return Err(GeometryError::NotFinite { name: name.into(), value: v, range });
                    }
                    // tolerate round-off at the bounds (e.g. 5*sqrt(3) typed with 16 digits)
                    let tol = 1e-9 * p.max.abs().max(1.0);
                    if v < p.min - tol || v > p.max + tol {
                        return Err(GeometryError::OutOfRange { name: name.into(), value: v, range, hint: hint_ext.into() });
                    }
                }
            }
            RangePolicy::Extended => {
                let rmin = r_min_extended();
                let rr = range_text(rmin, R_TUBE, "mm");
                if !r.is_finite() {
                    return Err(GeometryError::NotFinite { name: P_R.into(), value: r, range: rr });
                }
                if r < rmin - 1e-12 || r > R_TUBE + 1e-9 {
                    return Err(GeometryError::OutOfRange { name: P_R.into(), value: r, range: rr, hint: " (extended range)".into() });
                }
                let lmin = l_min_extended(r.max(rmin));
                if lmin > R_TUBE {
                    return Err(GeometryError::OutOfRange {
                        name: P_R.into(),
                        value: r,
                        range: rr,
                        hint: format!(" (extended range; at r_mm = {r} no l_mm <= 20 keeps the inward offset of t = {T_WALL} mm free of self-intersection)"),
                    });
                }
                let lr = range_text(lmin, R_TUBE, "mm");
                if !l.is_finite() {
                    return Err(GeometryError::NotFinite { name: P_L.into(), value: l, range: lr });
                }
                if l < lmin - 1e-12 || l > R_TUBE + 1e-9 {
                    return Err(GeometryError::OutOfRange {
                        name: P_L.into(),
                        value: l,
                        range: lr,
                        hint: format!(" (extended range at r_mm = {r}: the inward offset of t = {T_WALL} mm must not self-intersect)"),
                    });
                }
                if !a.is_finite() {
                    return Err(GeometryError::NotFinite { name: P_ALPHA.into(), value: a, range: "(-inf, +inf) deg".into() });
                }
            }
        }
        Ok((r.min(R_TUBE), l.min(R_TUBE), a))
    }
}
