//! Hyperelastic materials in decoupled form W(F) = W_iso(Ī1) + U(J), Ī1 = J^(−2/3) tr(FᵀF).
//!
//! The isochoric part depends on Ī1 only (Neo-Hooke, Yeoh, …); the volumetric part U(J) is
//! evaluated on the element's projected dilatation (see `element`). Material parameters are passed
//! as a slice so that derivatives with respect to them come from dual numbers.

use crate::scalar::Scalar;

/// Volumetric energy function.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum VolumetricLaw {
    /// U = κ/2 (J − 1)² — CalculiX/Abaqus `NEO HOOKE` with D1 = 2/κ.
    Quadratic,
    /// U = κ/2 (ln J)².
    Log,
}

/// An isotropic hyperelastic law with parameters `params()` (first is always the initial shear
/// modulus μ, last the bulk modulus κ).
pub trait Hyperelastic: Send + Sync + std::fmt::Debug {
    fn param_names(&self) -> Vec<&'static str>;
    fn params(&self) -> Vec<f64>;
    /// (W, dW/dĪ1, d²W/dĪ1²) at Ī1.
    fn w_iso<D: Scalar>(&self, p: &[D], i1b: D) -> [D; 3];
    /// (U, U', U'') at J.
    fn u_vol<D: Scalar>(&self, p: &[D], j: D) -> [D; 3];
}

/// Nearly incompressible Neo-Hookean: W = μ/2 (Ī1 − 3) + U(J).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NeoHookean {
    pub mu: f64,
    pub kappa: f64,
    pub law: VolumetricLaw,
}

/// Errors for non-physical material parameters.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MaterialError {
    #[error("material: {name} = {value} is not allowed ({why})")]
    Invalid { name: &'static str, value: f64, why: &'static str },
}

impl NeoHookean {
    /// μ > 0, κ/μ ≥ 1 (κ/μ ≈ 10²…10⁵ for rubber). Rejects NaN/inf.
    pub fn new(mu: f64, kappa: f64) -> Result<Self, MaterialError> {
        if !(mu.is_finite() && mu > 0.0) {
            return Err(MaterialError::Invalid { name: "mu", value: mu, why: "shear modulus must be finite and > 0" });
        }
        if !(kappa.is_finite() && kappa >= mu) {
            return Err(MaterialError::Invalid { name: "kappa", value: kappa, why: "bulk modulus must be finite and >= mu" });
        }
        Ok(NeoHookean { mu, kappa, law: VolumetricLaw::Quadratic })
    }
    pub fn with_ratio(mu: f64, kappa_over_mu: f64) -> Result<Self, MaterialError> {
        Self::new(mu, mu * kappa_over_mu)
    }
}

pub fn u_law<D: Scalar>(law: VolumetricLaw, kappa: D, j: D) -> [D; 3] {
    match law {
        VolumetricLaw::Quadratic => {
            let d = j - D::one();
            [kappa * d * d * 0.5, kappa * d, kappa]
        }
        VolumetricLaw::Log => {
            let l = j.ln();
            let r = j.recip();
            [kappa * l * l * 0.5, kappa * l * r, kappa * (D::one() - l) * r * r]
        }
    }
}

impl Hyperelastic for NeoHookean {
    fn param_names(&self) -> Vec<&'static str> {
        vec!["mu", "kappa"]
    }
    fn params(&self) -> Vec<f64> {
        vec![self.mu, self.kappa]
    }
    fn w_iso<D: Scalar>(&self, p: &[D], i1b: D) -> [D; 3] {
        let mu = p[0];
        [mu * (i1b - 3.0) * 0.5, mu * 0.5, D::zero()]
    }
    fn u_vol<D: Scalar>(&self, p: &[D], j: D) -> [D; 3] {
        u_law(self.law, p[1], j)
    }
}

/// Yeoh: W = Σ C_i0 (Ī1 − 3)^i, i = 1..3; μ = 2 C10.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Yeoh {
    pub c10: f64,
    pub c20: f64,
    pub c30: f64,
    pub kappa: f64,
}

impl Hyperelastic for Yeoh {
    fn param_names(&self) -> Vec<&'static str> {
        vec!["c10", "c20", "c30", "kappa"]
    }
    fn params(&self) -> Vec<f64> {
        vec![self.c10, self.c20, self.c30, self.kappa]
    }
    fn w_iso<D: Scalar>(&self, p: &[D], i1b: D) -> [D; 3] {
        let x = i1b - 3.0;
        [p[0] * x + p[1] * x * x + p[2] * x * x * x, p[0] + p[1] * x * 2.0 + p[2] * x * x * 3.0, p[1] * 2.0 + p[2] * x * 6.0]
    }
    fn u_vol<D: Scalar>(&self, p: &[D], j: D) -> [D; 3] {
        u_law(VolumetricLaw::Quadratic, p[3], j)
    }
}

/// The materials the solver knows, as one type (static dispatch in the kernels).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Material {
    NeoHookean(NeoHookean),
    Yeoh(Yeoh),
}

impl Hyperelastic for Material {
    fn param_names(&self) -> Vec<&'static str> {
        match self {
            Material::NeoHookean(m) => m.param_names(),
            Material::Yeoh(m) => m.param_names(),
        }
    }
    fn params(&self) -> Vec<f64> {
        match self {
            Material::NeoHookean(m) => m.params(),
            Material::Yeoh(m) => m.params(),
        }
    }
    fn w_iso<D: Scalar>(&self, p: &[D], i1b: D) -> [D; 3] {
        match self {
            Material::NeoHookean(m) => m.w_iso(p, i1b),
            Material::Yeoh(m) => m.w_iso(p, i1b),
        }
    }
    fn u_vol<D: Scalar>(&self, p: &[D], j: D) -> [D; 3] {
        match self {
            Material::NeoHookean(m) => m.u_vol(p, j),
            Material::Yeoh(m) => m.u_vol(p, j),
        }
    }
}

impl From<NeoHookean> for Material {
    fn from(m: NeoHookean) -> Self {
        Material::NeoHookean(m)
    }
}
