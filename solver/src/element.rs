//! Solid hexahedral element for nearly incompressible finite-strain hyperelasticity.
//!
//! Total-Lagrangian, displacement-based energy with a *projected dilatation*:
//!
//!   E_e(u) = ∫ W_iso(Ī1) dV + ∫ U(θ) dV,   θ = Π_h J,
//!
//! where Π_h is the element-wise L²(reference) projection onto a discontinuous pressure space
//! (`P1` = span{1, ξ, η, ζ}, `P0` = constants, `None` = no projection, θ = J). This is exactly the
//! statically condensed three-field (u, p, θ) Hu–Washizu element of deal.II step-44 (Q2-DGP1-DGP1
//! for `Hex27` + `P1`; Q1-P0 "mean dilatation" for `Hex8` + `P0`), written as a pure displacement
//! energy: the discrete pressure is p̃ = Π_h U'(θ). The tangent is the exact Hessian of E_e, so
//! it is symmetric.
//!
//! Kernels are plain functions of local data. `residual` is generic over the scalar type (`f64` or
//! dual numbers) for shape/material derivatives; `tangent` is the `f64` Hessian.

use crate::material::Hyperelastic;
use crate::mesh::ElementKind;
use crate::scalar::{det3, inv3, Scalar, M3};
use crate::shape::HexRule;

/// Discontinuous pressure/dilatation space of the mixed element.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum PressureSpace {
    /// Pure displacement element (locks for nearly incompressible materials; for comparison only).
    None,
    /// Element-constant pressure (mean dilatation / Q1P0).
    P0,
    /// Linear discontinuous pressure (Q2/P1).
    P1,
}

impl PressureSpace {
    pub fn dim(self) -> usize {
        match self {
            PressureSpace::None => 0,
            PressureSpace::P0 => 1,
            PressureSpace::P1 => 4,
        }
    }
    #[inline]
    fn basis(self, xi: [f64; 3]) -> [f64; 4] {
        [1.0, xi[0], xi[1], xi[2]]
    }
}

/// An element formulation: node layout, pressure space and quadrature order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Formulation {
    pub kind: ElementKind,
    pub pressure: PressureSpace,
    pub ngauss: usize,
}

impl Formulation {
    /// The recommended formulation for a node layout: Q2/P1 (Hex27), Q2s/P1 (Hex20), Q1/P0 (Hex8).
    pub fn standard(kind: ElementKind) -> Self {
        match kind {
            ElementKind::Hex8 => Formulation { kind, pressure: PressureSpace::P0, ngauss: 2 },
            _ => Formulation { kind, pressure: PressureSpace::P1, ngauss: 3 },
        }
    }
    pub fn rule(&self) -> HexRule {
        HexRule::new(self.kind, self.ngauss)
    }
}

/// Why an element could not be evaluated.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum ElementError {
    #[error("reference element {0} has a non-positive Jacobian")]
    BadReference(usize),
    #[error("element {0} inverted (det F <= 0 at a quadrature point)")]
    Inverted(usize),
    #[error("element {0} produced a non-finite value")]
    NonFinite(usize),
    #[error("the sparse tangent's setup (ordering, symbolic analysis) failed")]
    Setup,
    #[error("contact: node {0} reached or crossed its contact surface")]
    Penetration(usize),
}

/// Summary of one element evaluation.
#[derive(Clone, Copy, Debug)]
pub struct ElementInfo<D> {
    pub energy: D,
    /// Smallest det F over the quadrature points (and smallest projected θ).
    pub min_det_f: f64,
}

/// The kinematics at one quadrature point of an element.
pub struct QpData<D> {
    /// ∇_X N_a of each node
    pub g: Vec<[D; 3]>,
    pub f: M3<D>,
    pub finv: M3<D>,
    pub j: D,
    /// quadrature weight × det(∂X/∂ξ)
    pub wj0: D,
    /// the pressure-space basis {1, ξ, η, ζ} at the point
    pub q: [f64; 4],
}

fn qp_data<D: Scalar>(rule: &HexRule, gp: usize, x0: &[[D; 3]], u: &[[D; 3]], q: [f64; 4]) -> Result<QpData<D>, ElementError> {
    let dn = &rule.dn[gp];
    let nn = dn.len();
    let mut jac: M3<D> = [[D::zero(); 3]; 3];
    for a in 0..nn {
        for i in 0..3 {
            for jj in 0..3 {
                jac[i][jj] += x0[a][i] * dn[a][jj];
            }
        }
    }
    let det0 = det3(&jac);
    if !(det0.re() > 0.0) {
        return Err(ElementError::BadReference(0));
    }
    let jinv = inv3(&jac, det0); // dξ/dX
    let mut g = vec![[D::zero(); 3]; nn];
    for a in 0..nn {
        for cap in 0..3 {
            g[a][cap] = jinv[0][cap] * dn[a][0] + jinv[1][cap] * dn[a][1] + jinv[2][cap] * dn[a][2];
        }
    }
    let mut f: M3<D> = [[D::zero(); 3]; 3];
    for i in 0..3 {
        f[i][i] = D::one();
    }
    for a in 0..nn {
        for i in 0..3 {
            for cap in 0..3 {
                f[i][cap] += u[a][i] * g[a][cap];
            }
        }
    }
    let j = det3(&f);
    if !(j.re() > 0.0) {
        return Err(ElementError::Inverted(0));
    }
    let finv = inv3(&f, j);
    Ok(QpData { g, f, finv, j, wj0: det0 * rule.weights[gp], q })
}

/// Projection data: (θ at each qp, p̃ at each qp, M⁻¹ (np×np)).
fn project<D: Scalar, M: Hyperelastic>(ps: PressureSpace, mat: &M, params: &[D], qp: &[QpData<D>]) -> Result<(Vec<D>, Vec<D>, Vec<D>), ElementError> {
    let np = ps.dim();
    if np == 0 {
        let theta: Vec<D> = qp.iter().map(|d| d.j).collect();
        let pt: Vec<D> = qp.iter().map(|d| mat.u_vol(params, d.j)[1]).collect();
        return Ok((theta, pt, vec![]));
    }
    let mut m = vec![D::zero(); np * np];
    let mut b = vec![D::zero(); np];
    for d in qp {
        for r in 0..np {
            b[r] += d.j * d.wj0 * d.q[r];
            for s in 0..np {
                m[r * np + s] += d.wj0 * (d.q[r] * d.q[s]);
            }
        }
    }
    let minv = crate::scalar::small_spd_inverse(&m, np).ok_or(ElementError::BadReference(0))?;
    let a: Vec<D> = (0..np).map(|r| (0..np).map(|s| minv[r * np + s] * b[s]).sum()).collect();
    let theta: Vec<D> = qp.iter().map(|d| (0..np).map(|r| a[r] * d.q[r]).sum()).collect();
    if theta.iter().any(|t| !(t.re() > 0.0)) {
        return Err(ElementError::Inverted(0));
    }
    let mut rhs = vec![D::zero(); np];
    for (d, t) in qp.iter().zip(&theta) {
        let up = mat.u_vol(params, *t)[1];
        for r in 0..np {
            rhs[r] += up * d.wj0 * d.q[r];
        }
    }
    let cc: Vec<D> = (0..np).map(|r| (0..np).map(|s| minv[r * np + s] * rhs[s]).sum()).collect();
    let pt: Vec<D> = qp.iter().map(|d| (0..np).map(|r| cc[r] * d.q[r]).sum()).collect();
    Ok((theta, pt, minv))
}

/// The projection of a dilatation field given at the quadrature points, Θ = Π_h v, and the
/// pressure p̃ = Π_h U'(Θ), with the element's M⁻¹ (empty = no projection). A non-positive Θ is
/// clamped (the tangent of a state that far off equilibrium is only a search direction).
fn project_field<M: Hyperelastic>(ps: PressureSpace, mat: &M, params: &[f64], qp: &[QpData<f64>], v: &[f64], minv: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let np = ps.dim();
    if np == 0 {
        let th: Vec<f64> = v.iter().map(|t| t.max(1e-3)).collect();
        let pt = th.iter().map(|t| mat.u_vol(params, *t)[1]).collect();
        return (th, pt);
    }
    let proj = |vals: &[f64]| -> Vec<f64> {
        let mut b = vec![0.0; np];
        for (d, x) in qp.iter().zip(vals) {
            for r in 0..np {
                b[r] += x * d.wj0 * d.q[r];
            }
        }
        let a: Vec<f64> = (0..np).map(|r| (0..np).map(|s| minv[r * np + s] * b[s]).sum()).collect();
        qp.iter().map(|d| (0..np).map(|r| a[r] * d.q[r]).sum()).collect()
    };
    let th: Vec<f64> = proj(v).into_iter().map(|t| t.max(1e-3)).collect();
    let up: Vec<f64> = th.iter().map(|t| mat.u_vol(params, *t)[1]).collect();
    let pt = proj(&up);
    (th, pt)
}

/// The kinematics of an element at its quadrature point `gp`.
pub fn gather_point<D: Scalar>(form: &Formulation, rule: &HexRule, x0: &[[D; 3]], u: &[[D; 3]], gp: usize) -> Result<QpData<D>, ElementError> {
    qp_data(rule, gp, x0, u, form.pressure.basis(rule.points[gp]))
}

/// The kinematics of an element at each of its quadrature points.
pub fn gather<D: Scalar>(form: &Formulation, rule: &HexRule, x0: &[[D; 3]], u: &[[D; 3]]) -> Result<Vec<QpData<D>>, ElementError> {
    (0..rule.weights.len()).map(|gp| qp_data(rule, gp, x0, u, form.pressure.basis(rule.points[gp]))).collect()
}

/// Element energy and internal force vector f = ∂E/∂u (3·nn, node-major), generic over the scalar.
pub fn residual<D: Scalar, M: Hyperelastic>(form: &Formulation, rule: &HexRule, mat: &M, params: &[D], x0: &[[D; 3]], u: &[[D; 3]], f_out: &mut [D]) -> Result<ElementInfo<D>, ElementError> {
    residual_with(form, rule, mat, params, x0, u, None, f_out)
}

/// The pressure of an element given from outside: its coefficients in the element's pressure
/// space (`PressureSpace::dim` of them, in the basis {1, ξ, η, ζ}), e.g. from a pressure field
/// projected on a global reduced space. The element then contributes the isochoric energy and the
/// force ∫ (P_iso + p J F⁻ᵀ) : ∇δu; the volumetric energy and its stiffness U'' are the caller's.
pub type GivenPressure<'a> = Option<&'a [f64]>;

/// [`residual`], optionally with the pressure given ([`GivenPressure`]): the energy returned is
/// then the isochoric part only.
#[allow(clippy::too_many_arguments)]
pub fn residual_with<D: Scalar, M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[D],
    x0: &[[D; 3]],
    u: &[[D; 3]],
    given: GivenPressure,
    f_out: &mut [D],
) -> Result<ElementInfo<D>, ElementError> {
    for v in f_out.iter_mut() {
        *v = D::zero();
    }
    let info = residual_impl(form, rule, mat, params, x0, u, given, |_, i, v| f_out[i] += v)?;
    if f_out.iter().any(|v| !v.re().is_finite()) {
        return Err(ElementError::NonFinite(0));
    }
    Ok(info)
}

/// [`residual_with`] split by quadrature point: `f_out` (n_points × 3·nn, point-major) holds each
/// point's contribution to the element force (their sum is `residual_with`'s).
#[allow(clippy::too_many_arguments)]
pub fn residual_points_with<M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[f64],
    x0: &[[f64; 3]],
    u: &[[f64; 3]],
    given: GivenPressure,
    f_out: &mut Vec<f64>,
) -> Result<ElementInfo<f64>, ElementError> {
    let nd = 3 * x0.len();
    f_out.clear();
    f_out.resize(nd * rule.weights.len(), 0.0);
    let info = residual_impl(form, rule, mat, params, x0, u, given, |gi, i, v| f_out[gi * nd + i] += v)?;
    if f_out.iter().any(|v| !v.is_finite()) {
        return Err(ElementError::NonFinite(0));
    }
    Ok(info)
}

/// The element force, each quadrature point's contribution to component i passed to
/// `sink(point, i, value)`.
#[allow(clippy::too_many_arguments)]
fn residual_impl<D: Scalar, M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[D],
    x0: &[[D; 3]],
    u: &[[D; 3]],
    given: GivenPressure,
    mut sink: impl FnMut(usize, usize, D),
) -> Result<ElementInfo<D>, ElementError> {
    let nn = x0.len();
    let qp = gather(form, rule, x0, u)?;
    let (theta, pt) = match given {
        None => {
            let (theta, pt, _) = project(form.pressure, mat, params, &qp)?;
            (theta, pt)
        }
        Some(pc) => (qp.iter().map(|d| d.j).collect(), qp.iter().map(|d| D::from(given_at(pc, &d.q))).collect()),
    };
    let mut energy = D::zero();
    let mut min_j = f64::INFINITY;
    for (gi, d) in qp.iter().enumerate() {
        min_j = min_j.min(d.j.re()).min(theta[gi].re());
        let i1: D = (0..3).map(|i| (0..3).map(|k| d.f[i][k] * d.f[i][k]).sum::<D>()).sum();
        let jm23 = d.j.powf(-2.0 / 3.0);
        let [w, w1, _] = mat.w_iso(params, jm23 * i1);
        let uv = if given.is_some() { D::zero() } else { mat.u_vol(params, theta[gi])[0] };
        energy += (w + uv) * d.wj0;
        // P_iso = W1 J^(-2/3) (2F − 2/3 I1 F^-T);  volumetric: p̃ J F^-T
        let mut p: M3<D> = [[D::zero(); 3]; 3];
        for i in 0..3 {
            for cap in 0..3 {
                p[i][cap] = w1 * jm23 * (d.f[i][cap] * 2.0 - i1 * d.finv[cap][i] * (2.0 / 3.0)) + pt[gi] * d.j * d.finv[cap][i];
            }
        }
        for a in 0..nn {
            let ga = d.g[a];
            for i in 0..3 {
                sink(gi, 3 * a + i, (p[i][0] * ga[0] + p[i][1] * ga[1] + p[i][2] * ga[2]) * d.wj0);
            }
        }
    }
    if !energy.re().is_finite() {
        return Err(ElementError::NonFinite(0));
    }
    Ok(ElementInfo { energy, min_det_f: min_j })
}

/// The response at one quadrature point of deformation F (its inverse `fi`, J = det F) under a
/// pressure field of value p there: the isochoric energy density W, the first Piola stress
/// P = P_iso + p J F⁻ᵀ (P[i][J]) and the material-form tangent A = ∂P/∂F at fixed p
/// (A[3i+J][3k+L]), with `pj_k` the p·J of its volumetric geometric term (p·J itself, or a
/// linearised state's). The quadrature-level kernel of [`tangent_with`] and of reduced models
/// that sample quadrature points.
pub fn point_tangent<M: Hyperelastic>(mat: &M, params: &[f64], fm: &M3<f64>, fi: &M3<f64>, j: f64, p: f64, pj_k: f64) -> (f64, M3<f64>, [[f64; 9]; 9]) {
    let (w, pk, [_, w1, w2], i1, jm23, gb) = point_stress_parts(mat, params, fm, fi, j, p);
    let mut a = [[0.0f64; 9]; 9];
    for i in 0..3 {
        for cj in 0..3 {
            for k in 0..3 {
                for cl in 0..3 {
                    let dik = if i == k && cj == cl { 2.0 } else { 0.0 };
                    let d2 = jm23 * (dik - (4.0 / 3.0) * (fm[i][cj] * fi[cl][k] + fm[k][cl] * fi[cj][i]) + (4.0 / 9.0) * i1 * fi[cj][i] * fi[cl][k] + (2.0 / 3.0) * i1 * fi[cj][k] * fi[cl][i]);
                    // with the volumetric geometric term p̃J(g_a⊗g_b − g_b⊗g_a) in material form
                    a[3 * i + cj][3 * k + cl] = w2 * gb[i][cj] * gb[k][cl] + w1 * d2 + pj_k * (fi[cj][i] * fi[cl][k] - fi[cl][i] * fi[cj][k]);
                }
            }
        }
    }
    (w, pk, a)
}

/// [`point_tangent`] without the tangent: (W_iso, P).
pub fn point_stress<M: Hyperelastic>(mat: &M, params: &[f64], fm: &M3<f64>, fi: &M3<f64>, j: f64, p: f64) -> (f64, M3<f64>) {
    let (w, pk, ..) = point_stress_parts(mat, params, fm, fi, j, p);
    (w, pk)
}

/// (W_iso, P, [W, W', W''] of Ī1, I1, J^(−2/3), dĪ1/dF) at a point.
#[allow(clippy::type_complexity)]
#[inline]
fn point_stress_parts<M: Hyperelastic>(mat: &M, params: &[f64], fm: &M3<f64>, fi: &M3<f64>, j: f64, p: f64) -> (f64, M3<f64>, [f64; 3], f64, f64, M3<f64>) {
    let i1: f64 = (0..3).map(|i| (0..3).map(|k| fm[i][k] * fm[i][k]).sum::<f64>()).sum();
    let jm23 = j.powf(-2.0 / 3.0);
    let i1b = jm23 * i1;
    let ws = mat.w_iso(params, i1b);
    let w1 = ws[1];
    // dĪ1/dF (the material tangent is A = W2 g⊗g + W1 d²Ī1/dF²)
    let mut gb = [[0.0; 3]; 3];
    for i in 0..3 {
        for cap in 0..3 {
            gb[i][cap] = jm23 * (2.0 * fm[i][cap] - (2.0 / 3.0) * i1 * fi[cap][i]);
        }
    }
    let mut pk = [[0.0; 3]; 3];
    for i in 0..3 {
        for cap in 0..3 {
            pk[i][cap] = w1 * gb[i][cap] + p * j * fi[cap][i];
        }
    }
    (ws[0], pk, ws, i1, jm23, gb)
}

/// A given pressure's value at a quadrature point of basis values `q` (P0: the first only).
#[inline]
fn given_at(pc: &[f64], q: &[f64; 4]) -> f64 {
    pc.iter().zip(q).map(|(c, v)| c * v).sum()
}

/// The dilatation moments of an element in its pressure space: (∫ φ_r J dV, ∫ φ_r φ_s dV, the
/// smallest det F), φ = {1, ξ, η, ζ}[..np]; the mass matrix is row-major np × np. These are the
/// element's contributions to the projection of J on a global pressure space.
pub fn dilatation_moments(form: &Formulation, rule: &HexRule, x0: &[[f64; 3]], u: &[[f64; 3]]) -> Result<(Vec<f64>, Vec<f64>, f64), ElementError> {
    let np = form.pressure.dim().max(1);
    let qp = gather(form, rule, x0, u)?;
    let mut b = vec![0.0; np];
    let mut m = vec![0.0; np * np];
    let mut min_j = f64::INFINITY;
    for d in &qp {
        min_j = min_j.min(d.j);
        for r in 0..np {
            b[r] += d.q[r] * d.j * d.wj0;
            for s_ in 0..np {
                m[r * np + s_] += d.q[r] * d.q[s_] * d.wj0;
            }
        }
    }
    Ok((b, m, min_j))
}

/// The quadrature rule's pressure-basis values {1, ξ, η, ζ} at each point, with the weights
/// times det(∂X/∂ξ) of an element (for integrals of a given pressure-space field).
pub fn pressure_quadrature(form: &Formulation, rule: &HexRule, x0: &[[f64; 3]]) -> Result<Vec<([f64; 4], f64)>, ElementError> {
    let zero = vec![[0.0; 3]; x0.len()];
    Ok(gather(form, rule, x0, &zero)?.into_iter().map(|d| (d.q, d.wj0)).collect())
}

/// The element's discrete pressure p̃ = Π_h U'(Π_h J) as its coefficients in the pressure space
/// (`PressureSpace::dim` of them; empty without a pressure space): what a pressure snapshot is.
pub fn pressure_coefficients<M: Hyperelastic>(form: &Formulation, rule: &HexRule, mat: &M, params: &[f64], x0: &[[f64; 3]], u: &[[f64; 3]]) -> Result<Vec<f64>, ElementError> {
    let np = form.pressure.dim();
    if np == 0 {
        return Ok(Vec::new());
    }
    let qp = gather(form, rule, x0, u)?;
    let (_, pt, minv) = project(form.pressure, mat, params, &qp)?;
    let mut rhs = vec![0.0; np];
    for (d, p) in qp.iter().zip(&pt) {
        for r in 0..np {
            rhs[r] += p * d.wj0 * d.q[r];
        }
    }
    Ok((0..np).map(|r| (0..np).map(|s_| minv[r * np + s_] * rhs[s_]).sum()).collect())
}

thread_local! {
    /// Scratch matrices of [`tangent_mixed`] (Gs, R, M), kept per thread between elements.
    static KERNEL_BUFFERS: std::cell::RefCell<(faer::Mat<f64>, faer::Mat<f64>, faer::Mat<f64>)> =
        std::cell::RefCell::new((faer::Mat::new(), faer::Mat::new(), faer::Mat::new()));
}

/// Element energy, internal force f (3nn) and tangent K (3nn × 3nn, row-major, symmetric).
pub fn tangent<M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[f64],
    x0: &[[f64; 3]],
    u: &[[f64; 3]],
    f_out: &mut [f64],
    k_out: &mut [f64],
) -> Result<ElementInfo<f64>, ElementError> {
    tangent_mixed(form, rule, mat, params, x0, u, None, f_out, k_out)
}

/// As [`tangent`], with the volumetric part of the tangent taken at the *linearised* dilatation
/// of a previous state `u_lin` (the mixed three-field Newton): the dilatation state is
/// Θ = Π_h[J(u_lin) + J(u_lin) F(u_lin)⁻ᵀ : (F(u) − F(u_lin))], the pressure state
/// p̃ = Π_h U'(Θ), and the tangent is the exact Hessian with p̃, U''(Θ) in place of their values at
/// Π_h J(u). The residual `f_out` is unchanged (the exact energy gradient). This is the condensed
/// tangent of the three-field (u, p, Θ) Hu–Washizu Newton whose local fields are updated by their
/// linearisation instead of re-projected: away from equilibrium it avoids the spurious pressure
/// κ·O(|Δu|²) that a displacement-only tangent sees after a large step, and at equilibrium
/// (u = u_lin) it is the exact tangent.
#[allow(clippy::too_many_arguments)]
pub fn tangent_mixed<M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[f64],
    x0: &[[f64; 3]],
    u: &[[f64; 3]],
    u_lin: Option<&[[f64; 3]]>,
    f_out: &mut [f64],
    k_out: &mut [f64],
) -> Result<ElementInfo<f64>, ElementError> {
    tangent_with(form, rule, mat, params, x0, u, u_lin, None, f_out, k_out, None)
}

/// [`tangent_mixed`], optionally with the pressure given ([`GivenPressure`]; `u_lin` is then
/// ignored): the tangent is then the Hessian of the isochoric energy plus the pressure's
/// geometric term p ∂²J/∂u², without U'' (the caller's), and `bv_out` (np × 3nn, row-major)
/// receives ∂(∫ φ_r J dV)/∂u, the derivative of the dilatation moments.
#[allow(clippy::too_many_arguments)]
pub fn tangent_with<M: Hyperelastic>(
    form: &Formulation,
    rule: &HexRule,
    mat: &M,
    params: &[f64],
    x0: &[[f64; 3]],
    u: &[[f64; 3]],
    u_lin: Option<&[[f64; 3]]>,
    given: GivenPressure,
    f_out: &mut [f64],
    k_out: &mut [f64],
    bv_out: Option<&mut Vec<f64>>,
) -> Result<ElementInfo<f64>, ElementError> {
    // subnormal operands in the dense products' padding lanes cost 7× (see `fpenv`)
    let _ftz = crate::fpenv::FlushDenormals::new();
    let nn = x0.len();
    let nd = 3 * nn;
    let qp = gather(form, rule, x0, u)?;
    let (theta, pt, minv) = match given {
        None => project(form.pressure, mat, params, &qp)?,
        Some(pc) => (qp.iter().map(|d| d.j).collect(), qp.iter().map(|d| given_at(pc, &d.q)).collect(), Vec::new()),
    };
    // the volumetric state of the tangent: from the exact projection, or linearised about u_lin
    let (theta_k, pt_k) = match u_lin.filter(|_| given.is_none()) {
        None => (theta.clone(), pt.clone()),
        Some(ul) => {
            let jlin: Vec<f64> = qp
                .iter()
                .map(|d| {
                    let mut fl = [[0.0f64; 3]; 3];
                    for (i, row) in fl.iter_mut().enumerate() {
                        row[i] = 1.0;
                    }
                    for a in 0..nn {
                        for i in 0..3 {
                            for cap in 0..3 {
                                fl[i][cap] += ul[a][i] * d.g[a][cap];
                            }
                        }
                    }
                    let jl = det3(&fl);
                    if !(jl > 0.0) {
                        return d.j; // no usable linearisation point: the exact dilatation
                    }
                    let fli = inv3(&fl, jl);
                    let mut tr = 0.0;
                    for i in 0..3 {
                        for cap in 0..3 {
                            tr += fli[cap][i] * (d.f[i][cap] - fl[i][cap]);
                        }
                    }
                    jl * (1.0 + tr)
                })
                .collect();
            project_field(form.pressure, mat, params, &qp, &jlin, &minv)
        }
    };
    f_out.iter_mut().for_each(|v| *v = 0.0);
    // with a given pressure, P0 and None spaces still report the moment of {1}
    let np = if given.is_some() { form.pressure.dim().max(1) } else { form.pressure.dim() };
    let nq = qp.len();
    let mut bv = vec![0.0; np * nd];
    let mut hmat = vec![0.0; np * np];
    let mut energy = 0.0;
    let mut min_j = f64::INFINITY;
    let mut sg = vec![[0.0f64; 3]; nn]; // spatial gradients g_a = F^-T G_a
                                        // K_ab[i][k] = Σ_qp Σ_JL G_aJ w A[iJ][kL] G_bL, as six matrix products over all quadrature
                                        // points at once: with Gs = [G_1 … G_nq] (nn × 3nq) and R_ik the stacked w A_ik G_qpᵀ
                                        // (3nq × nn), M_ik = Gs R_ik, K[3a+i][3b+k] = M_ik[a][b] and M_ki = M_ikᵀ (A symmetric)
    const PAIRS: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    KERNEL_BUFFERS.with(|cell| {
        let mut bufs = cell.borrow_mut();
        let (gs, rk, m) = &mut *bufs;
        // (every entry of the three is overwritten below)
        if gs.nrows() != nn || gs.ncols() != 3 * nq {
            *gs = faer::Mat::<f64>::zeros(nn, 3 * nq);
            *rk = faer::Mat::<f64>::zeros(3 * nq, 6 * nn);
            *m = faer::Mat::<f64>::zeros(nn, 6 * nn);
        }
        for (gi, d) in qp.iter().enumerate() {
            min_j = min_j.min(d.j).min(theta[gi]);
            let fi = &d.finv;
            let (uv, upp) = if given.is_some() { (0.0, 0.0) } else { (mat.u_vol(params, theta[gi])[0], mat.u_vol(params, theta_k[gi])[2]) };
            let wj0 = d.wj0;
            let pj_k = pt_k[gi] * d.j;
            let (w, pk, mut a) = point_tangent(mat, params, &d.f, fi, d.j, pt[gi], pj_k);
            energy += (w + uv) * wj0;
            for b in 0..nn {
                let gbv = d.g[b];
                for i in 0..3 {
                    sg[b][i] = fi[0][i] * gbv[0] + fi[1][i] * gbv[1] + fi[2][i] * gbv[2];
                }
            }
            // residual
            for a_ in 0..nn {
                let ga = d.g[a_];
                for i in 0..3 {
                    f_out[3 * a_ + i] += (pk[i][0] * ga[0] + pk[i][1] * ga[1] + pk[i][2] * ga[2]) * wj0;
                }
            }
            // without projection, fold U''J² g_a⊗g_b into the material-form tangent A
            if np == 0 && given.is_none() {
                for i in 0..3 {
                    for cj in 0..3 {
                        for k in 0..3 {
                            for cl in 0..3 {
                                a[3 * i + cj][3 * k + cl] += upp * d.j * d.j * fi[cj][i] * fi[cl][k];
                            }
                        }
                    }
                }
            }
            for a_ in 0..nn {
                for cj in 0..3 {
                    gs[(a_, 3 * gi + cj)] = d.g[a_][cj];
                }
            }
            for (pi, &(i, k)) in PAIRS.iter().enumerate() {
                for cj in 0..3 {
                    let arow = &a[3 * i + cj];
                    let (w0, w1, w2) = (arow[3 * k] * wj0, arow[3 * k + 1] * wj0, arow[3 * k + 2] * wj0);
                    for b in 0..nn {
                        let gb = d.g[b];
                        rk[(3 * gi + cj, pi * nn + b)] = w0 * gb[0] + w1 * gb[1] + w2 * gb[2];
                    }
                }
            }
            if np > 0 {
                for r in 0..np {
                    for b in 0..nn {
                        for i in 0..3 {
                            bv[r * nd + 3 * b + i] += d.q[r] * d.j * sg[b][i] * wj0;
                        }
                    }
                    for s in 0..np {
                        hmat[r * np + s] += upp * d.q[r] * d.q[s] * wj0;
                    }
                }
            }
        }
        faer::linalg::matmul::matmul(m.as_mut(), faer::Accum::Replace, gs.as_ref(), rk.as_ref(), 1.0, faer::Par::Seq);
        for (pi, &(i, k)) in PAIRS.iter().enumerate() {
            for a_ in 0..nn {
                for b in 0..nn {
                    let v = m[(a_, pi * nn + b)];
                    k_out[(3 * a_ + i) * nd + 3 * b + k] = v;
                    if i != k {
                        k_out[(3 * b + k) * nd + 3 * a_ + i] = v;
                    }
                }
            }
        }
    });
    if let Some(out) = bv_out {
        out.clear();
        out.extend_from_slice(&bv);
    }
    if np > 0 && given.is_none() {
        // K += Bvᵀ (M⁻¹ H M⁻¹) Bv
        let mut c = vec![0.0; np * np];
        for r in 0..np {
            for s in 0..np {
                let mut v = 0.0;
                for t in 0..np {
                    for w_ in 0..np {
                        v += minv[r * np + t] * hmat[t * np + w_] * minv[w_ * np + s];
                    }
                }
                c[r * np + s] = v;
            }
        }
        // cb = C · Bv  (np × nd)
        let mut cb = vec![0.0; np * nd];
        for r in 0..np {
            for s in 0..np {
                let crs = c[r * np + s];
                for col in 0..nd {
                    cb[r * nd + col] += crs * bv[s * nd + col];
                }
            }
        }
        for row in 0..nd {
            for r in 0..np {
                let brow = bv[r * nd + row];
                if brow != 0.0 {
                    let kr = &mut k_out[row * nd..(row + 1) * nd];
                    let cbr = &cb[r * nd..(r + 1) * nd];
                    for col in 0..nd {
                        kr[col] += brow * cbr[col];
                    }
                }
            }
        }
    }
    if !energy.is_finite() || f_out.iter().any(|v| !v.is_finite()) || k_out.iter().any(|v| !v.is_finite()) {
        return Err(ElementError::NonFinite(0));
    }
    Ok(ElementInfo { energy, min_det_f: min_j })
}

/// Volume-averaged Cauchy stress of an element (MPa), σ = J⁻¹ P Fᵀ with the element's discrete
/// pressure, for post-processing.
pub fn mean_cauchy_stress<M: Hyperelastic>(form: &Formulation, rule: &HexRule, mat: &M, params: &[f64], x0: &[[f64; 3]], u: &[[f64; 3]]) -> Result<[[f64; 3]; 3], ElementError> {
    let qp = gather(form, rule, x0, u)?;
    let (_, pt, _) = project(form.pressure, mat, params, &qp)?;
    let mut sig = [[0.0; 3]; 3];
    let mut vol = 0.0;
    for (gi, d) in qp.iter().enumerate() {
        let i1: f64 = (0..3).map(|i| (0..3).map(|k| d.f[i][k] * d.f[i][k]).sum::<f64>()).sum();
        let jm23 = d.j.powf(-2.0 / 3.0);
        let w1 = mat.w_iso(params, jm23 * i1)[1];
        // σ = (2 W1 / J) J^(-2/3) dev(b) + p̃ I
        let mut b = [[0.0; 3]; 3];
        for i in 0..3 {
            for k in 0..3 {
                b[i][k] = (0..3).map(|m| d.f[i][m] * d.f[k][m]).sum();
            }
        }
        let dv = d.wj0 * d.j;
        for i in 0..3 {
            for k in 0..3 {
                let dev = b[i][k] - if i == k { i1 / 3.0 } else { 0.0 };
                sig[i][k] += (2.0 * w1 * jm23 / d.j * dev + if i == k { pt[gi] } else { 0.0 }) * dv;
            }
        }
        vol += dv;
    }
    for row in sig.iter_mut() {
        for v in row.iter_mut() {
            *v /= vol;
        }
    }
    Ok(sig)
}

/// von Mises equivalent of a Cauchy stress.
pub fn von_mises(s: &[[f64; 3]; 3]) -> f64 {
    let (a, b, c) = (s[0][0] - s[1][1], s[1][1] - s[2][2], s[2][2] - s[0][0]);
    (0.5 * (a * a + b * b + c * c) + 3.0 * (s[0][1] * s[0][1] + s[1][2] * s[1][2] + s[2][0] * s[2][0])).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::{Material, NeoHookean};
    use crate::mesh::HEX27_NATURAL;

    fn distorted_element(kind: ElementKind) -> Vec<[f64; 3]> {
        kind.natural_coords()
            .iter()
            .map(|c| {
                let (x, y, z) = (c[0] as f64, c[1] as f64, c[2] as f64);
                [1.0 + x + 0.1 * y * z + 0.05 * x * x, 2.0 + 0.8 * y + 0.1 * x, 0.5 * z + 0.07 * x * y]
            })
            .collect()
    }

    fn disp(x0: &[[f64; 3]], s: f64) -> Vec<[f64; 3]> {
        x0.iter().map(|p| [s * (0.2 * p[1] + 0.1 * p[0] * p[2]), s * (-0.15 * p[0] + 0.05 * p[2] * p[2]), s * (0.12 * p[0] * p[1])]).collect()
    }

    #[test]
    fn tangent_matches_fd_of_residual_and_residual_matches_fd_of_energy() {
        let _ = HEX27_NATURAL;
        let mat: Material = NeoHookean::new(0.34, 0.34 * 100.0).unwrap().into();
        let params = mat.params();
        for form in [
            Formulation::standard(ElementKind::Hex27),
            Formulation::standard(ElementKind::Hex8),
            Formulation::standard(ElementKind::Hex20),
            Formulation { kind: ElementKind::Hex8, pressure: PressureSpace::None, ngauss: 2 },
            Formulation { kind: ElementKind::Hex27, pressure: PressureSpace::P0, ngauss: 3 },
        ] {
            let rule = form.rule();
            let x0 = distorted_element(form.kind);
            let u = disp(&x0, 1.0);
            let nd = 3 * x0.len();
            let mut f = vec![0.0; nd];
            let mut k = vec![0.0; nd * nd];
            let info = tangent(&form, &rule, &mat, &params, &x0, &u, &mut f, &mut k).unwrap();
            let mut fr = vec![0.0; nd];
            let info2 = residual(&form, &rule, &mat, &params, &x0, &u, &mut fr).unwrap();
            assert!((info.energy - info2.energy).abs() < 1e-12 * info.energy.abs().max(1.0));
            for i in 0..nd {
                assert!((f[i] - fr[i]).abs() < 1e-10 * (1.0 + f[i].abs()), "{form:?}");
            }
            let h = 1e-6;
            let kmax = k.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let fmax = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for col in 0..nd {
                let mut up = u.clone();
                let mut um = u.clone();
                up[col / 3][col % 3] += h;
                um[col / 3][col % 3] -= h;
                let mut fp = vec![0.0; nd];
                let mut fm = vec![0.0; nd];
                let ep = residual(&form, &rule, &mat, &params, &x0, &up, &mut fp).unwrap().energy;
                let em = residual(&form, &rule, &mat, &params, &x0, &um, &mut fm).unwrap().energy;
                let fd_f = (ep - em) / (2.0 * h);
                assert!((fd_f - f[col]).abs() < 1e-6 * fmax, "{form:?} f[{col}] {} vs {}", fd_f, f[col]);
                for row in 0..nd {
                    let fd = (fp[row] - fm[row]) / (2.0 * h);
                    let an = k[row * nd + col];
                    assert!((fd - an).abs() < 1e-6 * kmax, "{form:?} K[{row},{col}] fd {fd} an {an}");
                }
            }
            for r in 0..nd {
                for cc in 0..nd {
                    assert!((k[r * nd + cc] - k[cc * nd + r]).abs() < 1e-10 * kmax);
                }
            }
        }
    }

    #[test]
    fn rigid_rotation_is_stress_free() {
        let mat: Material = NeoHookean::new(0.34, 340.0).unwrap().into();
        let params = mat.params();
        let form = Formulation::standard(ElementKind::Hex27);
        let rule = form.rule();
        let x0 = distorted_element(form.kind);
        let (s, co) = (0.9f64.sin(), 0.9f64.cos());
        let u: Vec<[f64; 3]> = x0.iter().map(|p| [co * p[0] - s * p[1] - p[0] + 1.0, s * p[0] + co * p[1] - p[1] - 2.0, 0.3]).collect();
        let mut f = vec![0.0; 81];
        let info = residual(&form, &rule, &mat, &params, &x0, &u, &mut f).unwrap();
        assert!(info.energy.abs() < 1e-12);
        assert!(f.iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn cauchy_stress_of_uniaxial_state() {
        // homogeneous F = diag(λ, t, t): σ11 − σ22 = μ J^(-5/3) (λ² − t²) for Neo-Hooke
        let mat: Material = NeoHookean::new(0.34, 340.0).unwrap().into();
        let form = Formulation::standard(ElementKind::Hex27);
        let x0: Vec<[f64; 3]> = form.kind.natural_coords().iter().map(|c| [c[0] as f64, c[1] as f64, c[2] as f64]).collect();
        let (l, t) = (1.3, 0.9);
        let u: Vec<[f64; 3]> = x0.iter().map(|p| [(l - 1.0) * p[0], (t - 1.0) * p[1], (t - 1.0) * p[2]]).collect();
        let s = mean_cauchy_stress(&form, &form.rule(), &mat, &mat.params(), &x0, &u).unwrap();
        let j: f64 = l * t * t;
        let expect = 0.34 * j.powf(-5.0 / 3.0) * (l * l - t * t);
        assert!((s[0][0] - s[1][1] - expect).abs() < 1e-12);
        assert!((s[1][1] - s[2][2]).abs() < 1e-12 && s[0][1].abs() < 1e-12);
        assert!((s[1][1] - (340.0 * (j - 1.0) - expect / 3.0)).abs() < 1e-9);
        assert!((von_mises(&s) - expect.abs()).abs() < 1e-12);
    }

    #[test]
    fn inverted_element_is_an_error() {
        let mat: Material = NeoHookean::new(0.34, 340.0).unwrap().into();
        let form = Formulation::standard(ElementKind::Hex8);
        let x0 = distorted_element(form.kind);
        let u: Vec<[f64; 3]> = x0.iter().map(|p| [-2.0 * p[0], 0.0, 0.0]).collect();
        let mut f = vec![0.0; 24];
        let r = residual(&form, &form.rule(), &mat, &mat.params(), &x0, &u, &mut f);
        assert!(matches!(r, Err(ElementError::Inverted(_))));
    }
}
