//! Adjoint sensitivities of output functionals at a converged equilibrium.
//!
//! At an equilibrium r(q; s) = 0 of a hyperelastic model with conservative loads (the cavity
//! pressure is conservative: r contains −p ∂V/∂x, and +p·A_cap on rigid caps that carry no
//! pressure, a dead load whose area follows the reference shape), the total derivative of a functional J(q; s)
//! with respect to any input s — a reference-coordinate field (shape), the pressure, a material
//! parameter, a prescribed value — is
//!
//!   dJ/ds = ∂J/∂s + λᵀ ∂r/∂s,   K λ = −∂J/∂q,
//!
//! with K = ∂r/∂q the (symmetric) reduced tangent already factored by the last Newton step. The
//! equilibrium of a hyperelastic body is a function of the final loads only (path independence),
//! so only the final state is needed, whatever load steps led to it.
//!
//! The partial derivatives at fixed q come from forward-mode dual numbers pushed through the same
//! generic element, cavity-volume and constraint code as the residual ([`evaluate`]): one dual
//! evaluation per input direction, plus one per reaction functional (whose ∂J/∂q is the tangent
//! column ∂r/∂(DOF), by symmetry). Each functional costs one solve with the existing factor.
//!
//! Functionals ([`Functional`]): a rigid-body DOF value, the generalised reaction conjugate to a
//! rigid-body DOF (force or moment on a held body), the cavity volume, and a Kreisselmeier–
//! Steinhauser aggregate of the nodes' current distance from the z axis (a smooth max radius).

use crate::dofmap::{rotation, BodyDof, Comp};
use crate::element::{self, ElementError};
use crate::model::{Factor, Loads, Model, SolveError};
use crate::scalar::Scalar;
use crate::surface;
use num_dual::{Dual, Dual64};
use rayon::prelude::*;

/// Errors of a sensitivity computation.
#[derive(Debug, thiserror::Error)]
pub enum AdjointError {
    #[error("sensitivities with periodic (helical) constraints are not implemented")]
    Periodic,
    #[error("limit-point sensitivities through contact states are not implemented yet")]
    Contact,
    #[error("element evaluation failed: {0}")]
    Element(#[from] ElementError),
    #[error("adjoint solve failed: {0}")]
    Solve(#[from] SolveError),
    #[error("{0}")]
    Input(String),
    #[error("non-finite sensitivity of functional {0}")]
    NonFinite(usize),
}

/// Kinematics of a rigid body with values of the scalar type: translation c, rotation vector ψ,
/// R(ψ) and ∂R/∂ψ_k.
#[derive(Clone, Debug)]
pub struct BodyState<D> {
    pub c: [D; 3],
    pub psi: [D; 3],
    pub r: [[D; 3]; 3],
    pub dr: [[[D; 3]; 3]; 3],
}

/// A model evaluated at fixed reduced unknowns q, generic over the scalar.
#[derive(Clone, Debug)]
pub struct State<D> {
    pub x0: Vec<[D; 3]>,
    pub u: Vec<[D; 3]>,
    /// full nodal residual f_int − f_ext (3 per node)
    pub r_full: Vec<D>,
    /// reduced residual (∂u/∂q)ᵀ r_full − body forces
    pub r: Vec<D>,
    pub volume: D,
    /// ∂V/∂x (3 per node); empty without a cavity
    pub gvol_full: Vec<D>,
    pub bodies: Vec<BodyState<D>>,
}

impl State<f64> {
    /// The state of an assembly (same values as [`evaluate`] at its inputs, without re-evaluating
    /// the elements): what the path follower reads its recorded outputs from.
    pub fn from_assembly(model: &Model, a: &crate::model::Assembled) -> State<f64> {
        let bodies = a.kin.iter().map(|k| BodyState { c: k.c, psi: k.psi, r: k.r, dr: k.dr }).collect();
        State { x0: model.mesh.nodes.clone(), u: a.u.clone(), r_full: a.r_full.clone(), r: a.r.clone(), volume: a.volume, gvol_full: Vec::new(), bodies }
    }
}

/// Inputs of an evaluation: reference coordinates, reduced unknowns, pressure, prescribed values
/// and material parameters, each possibly dual.
pub struct Inputs<'a, D> {
    pub x0: &'a [[D; 3]],
    pub q: &'a [D],
    pub pressure: D,
    pub presc: &'a [D],
    pub params: &'a [D],
}

fn sub<D: Scalar>(a: [D; 3], b: [f64; 3]) -> [D; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// R(ψ) and ∂R/∂ψ_k for a generic scalar (∂R/∂ψ_k by a nested dual number).
fn body_state<D: Scalar>(c: [D; 3], psi: [D; 3]) -> BodyState<D> {
    let r = rotation(psi);
    let mut dr = [[[D::zero(); 3]; 3]; 3];
    for (k, drk) in dr.iter_mut().enumerate() {
        let p: [Dual<D>; 3] = std::array::from_fn(|j| Dual::new(psi[j], if j == k { D::one() } else { D::zero() }));
        let rr = rotation(p);
        for i in 0..3 {
            for j in 0..3 {
                drk[i][j] = rr[i][j].eps;
            }
        }
    }
    BodyState { c, psi, r, dr }
}

/// Coefficient ∂u_c/∂(DOF k) of a rigid node at offset d from the body reference.
fn rigid_coef<D: Scalar>(b: &BodyState<D>, k: usize, c: usize, d: [D; 3]) -> D {
    if k < 3 {
        if k == c {
            D::one()
        } else {
            D::zero()
        }
    } else {
        let m = &b.dr[k - 3];
        m[c][0] * d[0] + m[c][1] * d[1] + m[c][2] * d[2]
    }
}

/// Evaluate the model's residual, cavity volume and kinematics at fixed q (generic over the
/// scalar; with `f64` it reproduces [`Model::assemble`]'s residual). Dead loads (`nodal_forces`,
/// `body_forces`) are taken from `loads`; pressure, prescribed values and material parameters from
/// `inp`.
pub fn evaluate<D: Scalar>(model: &Model, inp: &Inputs<D>, loads: &Loads) -> Result<State<D>, AdjointError> {
    let dofs = &model.dofs;
    if !dofs.periodic.is_empty() {
        return Err(AdjointError::Periodic);
    }
    let nn_total = model.mesh.nodes.len();
    if inp.x0.len() != nn_total || inp.q.len() != dofs.n_reduced() || inp.presc.len() != dofs.presc_targets.len() {
        return Err(AdjointError::Input("input sizes do not match the model".into()));
    }
    let x0 = inp.x0;
    let val = |bd: BodyDof| match bd {
        BodyDof::Free(i) => inp.q[i],
        BodyDof::Presc(s) => inp.presc[s],
    };
    let bodies: Vec<BodyState<D>> = dofs.body_dofs.iter().map(|bd| body_state([val(bd[0]), val(bd[1]), val(bd[2])], [val(bd[3]), val(bd[4]), val(bd[5])])).collect();
    // displacements
    let mut u = vec![[D::zero(); 3]; nn_total];
    for (n, un) in u.iter_mut().enumerate() {
        for (c, uc) in un.iter_mut().enumerate() {
            *uc = match dofs.comps[3 * n + c] {
                Comp::Free(k) => inp.q[k as usize],
                Comp::Presc(s) => inp.presc[s as usize],
                Comp::Lin(s, l) => dofs.terms[s as usize..s as usize + l as usize].iter().map(|&(k, cf)| inp.q[k as usize] * cf).sum(),
                Comp::Rigid(b) => {
                    let body = &bodies[b as usize];
                    let d = sub(x0[n], dofs.bodies[b as usize].reference);
                    body.c[c] + (0..3).map(|j| body.r[c][j] * d[j]).sum::<D>() - d[c]
                }
                Comp::Periodic(_) => return Err(AdjointError::Periodic),
            };
        }
    }
    // elements (parallel; summed in element order)
    let rule = model.form.rule();
    let ne = model.mesh.n_elements();
    let forces: Vec<Result<Vec<D>, ElementError>> = (0..ne)
        .into_par_iter()
        .with_min_len(16)
        .map(|e| {
            let conn = model.mesh.element(e);
            let xe: Vec<[D; 3]> = conn.iter().map(|&n| x0[n]).collect();
            let ue: Vec<[D; 3]> = conn.iter().map(|&n| u[n]).collect();
            let mut f = vec![D::zero(); 3 * conn.len()];
            element::residual(&model.form, &rule, &model.material, inp.params, &xe, &ue, &mut f).map_err(|err| crate::model::relabel(err, e))?;
            Ok(f)
        })
        .collect();
    let mut r_full = vec![D::zero(); 3 * nn_total];
    for (e, f) in forces.into_iter().enumerate() {
        let f = f?;
        for (a, &n) in model.mesh.element(e).iter().enumerate() {
            for c in 0..3 {
                r_full[3 * n + c] += f[3 * a + c];
            }
        }
    }
    // cavity: volume and −p ∂V/∂x (the full model's volume loop)
    let mut volume = D::zero();
    let mut gvol_full = Vec::new();
    if let Some(cav) = &model.cavity {
        gvol_full = vec![D::zero(); 3 * nn_total];
        let xcur = |n: usize| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]];
        volume = surface::volume_and_gradient(cav, xcur, &mut gvol_full, |_, _, _, _| {});
        for (rv, &g) in r_full.iter_mut().zip(&gvol_full) {
            *rv -= inp.pressure * g;
        }
    }
    // contact: the barrier forces at the state's values, to first order in its derivative
    // (f + H δx, H the exact Hessian in the current positions, δx = x − x̄ the dual part of the
    // positions), the slave weights ∫N dA of the shape as the factor w(X)/w̄
    if let Some(con) = model.contact() {
        let xd: Vec<[D; 3]> = (0..nn_total).map(|n| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]]).collect();
        let xre: Vec<[f64; 3]> = xd.iter().map(|p| [p[0].re(), p[1].re(), p[2].re()]).collect();
        let (terms, _) = con.terms(&|n| xre[n], true).map_err(|p| AdjointError::Element(ElementError::Penetration(p.node)))?;
        let weights: std::collections::HashMap<usize, D> = crate::contact::nodal_areas_at(&model.mesh, &con.faces, x0).into_iter().collect();
        for t in &terms {
            let ratio = match weights.get(&t.nodes[0]) {
                Some(w) if t.weight > 0.0 => *w / t.weight,
                _ => D::one(),
            };
            let nv = 3 * t.nodes.len();
            let dx: Vec<D> = (0..nv).map(|j| xd[t.nodes[j / 3]][j % 3] - D::from(xre[t.nodes[j / 3]][j % 3])).collect();
            for i in 0..nv {
                let mut v = ratio * t.force[i];
                for (j, dxj) in dx.iter().enumerate() {
                    v += *dxj * t.hessian[i * nv + j];
                }
                r_full[3 * t.nodes[i / 3] + i % 3] += v;
            }
        }
    }
    if !loads.nodal_forces.is_empty() {
        if loads.nodal_forces.len() != r_full.len() {
            return Err(AdjointError::Input("nodal_forces has the wrong length".into()));
        }
        for (rv, f) in r_full.iter_mut().zip(&loads.nodal_forces) {
            *rv -= *f;
        }
    }
    // reduce
    let mut r = vec![D::zero(); dofs.n_reduced()];
    for n in 0..nn_total {
        for c in 0..3 {
            let v = r_full[3 * n + c];
            match dofs.comps[3 * n + c] {
                Comp::Free(k) => r[k as usize] += v,
                Comp::Presc(_) => {}
                Comp::Lin(s, l) => {
                    for &(k, cf) in &dofs.terms[s as usize..s as usize + l as usize] {
                        r[k as usize] += v * cf;
                    }
                }
                Comp::Rigid(b) => {
                    let b = b as usize;
                    let d = sub(x0[n], dofs.bodies[b].reference);
                    for k in 0..6 {
                        if let BodyDof::Free(i) = dofs.body_dofs[b][k] {
                            r[i] += v * rigid_coef(&bodies[b], k, c, d);
                        }
                    }
                }
                Comp::Periodic(_) => return Err(AdjointError::Periodic),
            }
        }
    }
    // the caps' pressure correction and the bodies' dead forces (as Model::assemble; the cap
    // areas follow the reference shape)
    for (i, v) in model.rigid_load_terms(x0, inp.pressure, &loads.body_forces) {
        r[i] += v;
    }
    Ok(State { x0: x0.to_vec(), u, r_full, r, volume, gvol_full, bodies })
}

/// An output functional of a model state.
#[derive(Clone, Debug, PartialEq)]
pub enum Functional {
    /// The value of DOF `dof` (0–2 translation, 3–5 rotation vector) of rigid body `body`.
    BodyDof { body: usize, dof: usize },
    /// The generalised reaction conjugate to a rigid-body DOF, Σ_n (∂u_n/∂s)·(f_int − f_ext)_n over
    /// the body's nodes: the force (translation) or moment about the body's current reference
    /// point (rotation) that the body exerts on the structure… with the sign of f_int − f_ext,
    /// i.e. the force the held DOF must supply is its negative.
    BodyReaction { body: usize, dof: usize },
    /// The cavity volume (of the modelled part).
    CavityVolume,
    /// Kreisselmeier–Steinhauser aggregate (1/ρ) ln Σ_n exp(ρ ρ_n) of the current distance ρ_n of
    /// each listed node from the z axis: a smooth upper bound of max ρ_n, above it by at most
    /// ln(N)/ρ (ρ in 1/length).
    KsRadius { nodes: Vec<usize>, rho: f64 },
    /// The largest current distance from the z axis over the listed nodes (not smooth: its
    /// derivative is that of the farthest node; for recording, the optimiser uses `KsRadius`).
    MaxRadius { nodes: Vec<usize> },
}

impl Functional {
    /// Value on a state (generic, so that ∂J/∂s at fixed q comes from a dual state).
    pub fn eval<D: Scalar>(&self, model: &Model, st: &State<D>) -> Result<D, AdjointError> {
        match self {
            Functional::BodyDof { body, dof } => {
                let b = st.bodies.get(*body).ok_or_else(|| AdjointError::Input(format!("no rigid body {body}")))?;
                Ok(if *dof < 3 { b.c[*dof] } else { b.psi[*dof - 3] })
            }
            Functional::BodyReaction { body, dof } => {
                let bs = st.bodies.get(*body).ok_or_else(|| AdjointError::Input(format!("no rigid body {body}")))?;
                let rb = &model.dofs.bodies[*body];
                let mut g = D::zero();
                for &n in &rb.nodes {
                    let d = sub(st.x0[n], rb.reference);
                    for c in 0..3 {
                        if matches!(model.dofs.comps[3 * n + c], Comp::Rigid(b) if b as usize == *body) {
                            g += st.r_full[3 * n + c] * rigid_coef(bs, *dof, c, d);
                        }
                    }
                }
                Ok(g)
            }
            Functional::CavityVolume => Ok(st.volume),
            Functional::KsRadius { nodes, rho } => {
                if nodes.is_empty() || !(*rho > 0.0) {
                    return Err(AdjointError::Input("KS radius needs nodes and rho > 0".into()));
                }
                let radii: Vec<D> = nodes.iter().map(|&n| radius(st, n)).collect();
                let m = radii.iter().map(|v| v.re()).fold(f64::NEG_INFINITY, f64::max);
                let s: D = radii.iter().map(|&v| ((v - m) * *rho).exp()).sum();
                Ok(s.ln() / *rho + m)
            }
            Functional::MaxRadius { nodes } => {
                let best = nodes.iter().map(|&n| radius(st, n)).max_by(|a, b| a.re().total_cmp(&b.re()));
                best.ok_or_else(|| AdjointError::Input("max radius needs nodes".into()))
            }
        }
    }
}

fn radius<D: Scalar>(st: &State<D>, n: usize) -> D {
    let x = st.x0[n][0] + st.u[n][0];
    let y = st.x0[n][1] + st.u[n][1];
    (x * x + y * y).sqrt()
}

/// One input direction s: a reference-coordinate field (shape), the pressure, the material
/// parameters and the prescribed values move by these amounts per unit of s.
#[derive(Clone, Debug, Default)]
pub struct Direction {
    pub name: String,
    /// dX/ds per node (None = the shape does not change)
    pub dx0: Option<Vec<[f64; 3]>>,
    pub dpressure: f64,
    /// d(params)/ds (empty = none)
    pub dparams: Vec<f64>,
    /// d(presc)/ds (empty = none)
    pub dpresc: Vec<f64>,
}

/// Values and total derivatives of functionals at an equilibrium.
#[derive(Clone, Debug)]
pub struct Sensitivities {
    pub values: Vec<f64>,
    /// gradients[i][k] = dJ_i/ds_k
    pub gradients: Vec<Vec<f64>>,
    pub linear_solves: usize,
    pub dual_evaluations: usize,
}

fn seeded<D: Copy>(re: &[f64], eps: Option<&[f64]>, mk: impl Fn(f64, f64) -> D) -> Vec<D> {
    re.iter().enumerate().map(|(i, &v)| mk(v, eps.and_then(|e| e.get(i).copied()).unwrap_or(0.0))).collect()
}

/// Evaluate with every input a dual number seeded along `dir` (and, optionally, q along `dq`).
fn dual_state(model: &Model, q: &[f64], loads: &Loads, dir: &Direction, dq: Option<&[f64]>) -> Result<State<Dual64>, AdjointError> {
    let x0: Vec<[Dual64; 3]> = match &dir.dx0 {
        Some(v) => {
            if v.len() != model.mesh.nodes.len() {
                return Err(AdjointError::Input(format!("direction '{}': dx0 has {} nodes, the mesh {}", dir.name, v.len(), model.mesh.nodes.len())));
            }
            model.mesh.nodes.iter().zip(v).map(|(x, d)| std::array::from_fn(|i| Dual64::new(x[i], d[i]))).collect()
        }
        None => model.mesh.nodes.iter().map(|x| std::array::from_fn(|i| Dual64::from(x[i]))).collect(),
    };
    let qd = seeded(q, dq, Dual64::new);
    let presc = seeded(&loads.presc, (!dir.dpresc.is_empty()).then_some(dir.dpresc.as_slice()), Dual64::new);
    let params = seeded(&model.params, (!dir.dparams.is_empty()).then_some(dir.dparams.as_slice()), Dual64::new);
    let inp = Inputs { x0: &x0, q: &qd, pressure: Dual64::new(loads.pressure, dir.dpressure), presc: &presc, params: &params };
    evaluate(model, &inp, loads)
}

/// Map a full nodal vector g (3 per node, ∂J/∂u) to the reduced unknowns: (∂u/∂q)ᵀ g.
pub fn reduce(model: &Model, q: &[f64], loads: &Loads, g: &[f64]) -> Vec<f64> {
    model.reduce_full(&model.dofs.body_kinematics(q, &loads.presc), g)
}

/// ∂J/∂q of a functional at a state (f64).
fn partial_q(model: &Model, q: &[f64], loads: &Loads, st: &State<f64>, f: &Functional, evals: &mut usize) -> Result<Vec<f64>, AdjointError> {
    let n = model.n_reduced();
    match f {
        Functional::BodyDof { body, dof } => {
            let mut g = vec![0.0; n];
            if let Some(BodyDof::Free(i)) = model.dofs.body_dofs.get(*body).map(|b| b[*dof]) {
                g[i] = 1.0;
            }
            Ok(g)
        }
        Functional::BodyReaction { body, dof } => {
            // ∂g/∂q = ∂r/∂s (s the DOF; mixed second derivatives of the potential commute)
            let bd = model.dofs.body_dofs.get(*body).ok_or_else(|| AdjointError::Input(format!("no rigid body {body}")))?[*dof];
            *evals += 1;
            let st = match bd {
                BodyDof::Presc(s) => {
                    let mut dp = vec![0.0; loads.presc.len()];
                    dp[s] = 1.0;
                    dual_state(model, q, loads, &Direction { dpresc: dp, ..Default::default() }, None)?
                }
                BodyDof::Free(i) => {
                    let mut dq = vec![0.0; n];
                    dq[i] = 1.0;
                    dual_state(model, q, loads, &Direction::default(), Some(&dq))?
                }
            };
            Ok(st.r.iter().map(|v| v.eps).collect())
        }
        Functional::CavityVolume => {
            if st.gvol_full.is_empty() {
                return Err(AdjointError::Input("the model has no cavity".into()));
            }
            Ok(reduce(model, q, loads, &st.gvol_full))
        }
        Functional::KsRadius { nodes, rho } => {
            let radii: Vec<f64> = nodes.iter().map(|&n| radius(st, n)).collect();
            let m = radii.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let w: Vec<f64> = radii.iter().map(|v| ((v - m) * rho).exp()).collect();
            let s: f64 = w.iter().sum();
            let mut g = vec![0.0; 3 * model.mesh.nodes.len()];
            for ((&nd, &rn), &wn) in nodes.iter().zip(&radii).zip(&w) {
                if rn > 0.0 {
                    let x = st.x0[nd][0] + st.u[nd][0];
                    let y = st.x0[nd][1] + st.u[nd][1];
                    g[3 * nd] += wn / s * x / rn;
                    g[3 * nd + 1] += wn / s * y / rn;
                }
            }
            Ok(reduce(model, q, loads, &g))
        }
        Functional::MaxRadius { nodes } => {
            let Some((&nd, rn)) = nodes.iter().map(|n| (n, radius(st, *n))).max_by(|a, b| a.1.total_cmp(&b.1)) else {
                return Err(AdjointError::Input("max radius needs nodes".into()));
            };
            let mut g = vec![0.0; 3 * model.mesh.nodes.len()];
            if rn > 0.0 {
                g[3 * nd] = (st.x0[nd][0] + st.u[nd][0]) / rn;
                g[3 * nd + 1] = (st.x0[nd][1] + st.u[nd][1]) / rn;
            }
            Ok(reduce(model, q, loads, &g))
        }
    }
}

/// Values and total derivatives dJ_i/ds_k of `functionals` along `directions` at the equilibrium
/// q under `loads`; `factor` is the factorisation of the reduced tangent at q (e.g. from
/// [`crate::solve::newton_factored`] or [`crate::solve::factor_converged`]).
pub fn sensitivities(model: &Model, q: &[f64], loads: &Loads, factor: &Factor, functionals: &[Functional], directions: &[Direction]) -> Result<Sensitivities, AdjointError> {
    let inp = Inputs { x0: &model.mesh.nodes, q, pressure: loads.pressure, presc: &loads.presc, params: &model.params };
    let st = evaluate(model, &inp, loads)?;
    let mut evals = 0;
    let values: Vec<f64> = functionals.iter().map(|f| f.eval(model, &st)).collect::<Result<_, _>>()?;
    let mut solves = 0;
    let mut lambdas = Vec::with_capacity(functionals.len());
    for f in functionals {
        let g = partial_q(model, q, loads, &st, f, &mut evals)?;
        if g.iter().all(|v| *v == 0.0) {
            lambdas.push(None);
            continue;
        }
        let minus: Vec<f64> = g.iter().map(|v| -v).collect();
        lambdas.push(Some(factor.solve(&minus)?));
        solves += 1;
    }
    let mut gradients = vec![vec![0.0; directions.len()]; functionals.len()];
    for (k, dir) in directions.iter().enumerate() {
        let ds = dual_state(model, q, loads, dir, None)?;
        evals += 1;
        let dr: Vec<f64> = ds.r.iter().map(|v| v.eps).collect();
        for (i, f) in functionals.iter().enumerate() {
            let mut g = f.eval(model, &ds)?.eps;
            if let Some(l) = &lambdas[i] {
                g += l.iter().zip(&dr).map(|(a, b)| a * b).sum::<f64>();
            }
            if !g.is_finite() {
                return Err(AdjointError::NonFinite(i));
            }
            gradients[i][k] = g;
        }
    }
    Ok(Sensitivities { values, gradients, linear_solves: solves, dual_evaluations: evals })
}

/// Sensitivity of a pressure limit point (the pressure maximum of a pressure-controlled path).
#[derive(Clone, Debug)]
pub struct LimitSensitivity {
    /// dp_lim/ds_k per direction (p in the model's pressure unit)
    pub dp: Vec<f64>,
    /// φᵀKφ/φᵀφ of the approximate null vector: how close the state is to singular
    pub rayleigh: f64,
}

/// Sensitivity of the limit pressure at (or just before) a pressure maximum: with φ the null
/// vector of the tangent (K φ = 0 at the limit point), differentiating r(q, p, s) = 0 along the
/// limit-point curve and multiplying by φ gives
///
///   dp_lim/ds = −φᵀ ∂r/∂s / φᵀ ∂r/∂p.
///
/// φ comes from inverse iteration with the (nearly singular, still positive definite) factor of
/// the last converged state before the limit point, so the result approximates the derivative at
/// the limit point to the distance of that state from it.
pub fn limit_sensitivity(model: &Model, q: &[f64], loads: &Loads, factor: &Factor, k_values: &[f64], directions: &[Direction]) -> Result<LimitSensitivity, AdjointError> {
    if model.contact().is_some() {
        return Err(AdjointError::Contact);
    }
    let phi = factor.inverse_iteration(8).map_err(|e| match e {
        SolveError::NonFinite => AdjointError::NonFinite(0),
        e => e.into(),
    })?;
    let kphi = model.sym_matvec(k_values, &phi);
    let rayleigh = phi.iter().zip(&kphi).map(|(a, b)| a * b).sum::<f64>();
    let dot = |v: &[f64]| phi.iter().zip(v).map(|(a, b)| a * b).sum::<f64>();
    let drp = dual_state(model, q, loads, &Direction { dpressure: 1.0, ..Default::default() }, None)?;
    let denom = dot(&drp.r.iter().map(|v| v.eps).collect::<Vec<_>>());
    if denom == 0.0 || !denom.is_finite() {
        return Err(AdjointError::Input("the pressure does not load the limit mode".into()));
    }
    let mut dp = Vec::with_capacity(directions.len());
    for dir in directions {
        let ds = dual_state(model, q, loads, dir, None)?;
        let num = dot(&ds.r.iter().map(|v| v.eps).collect::<Vec<_>>());
        let v = -num / denom;
        if !v.is_finite() {
            return Err(AdjointError::NonFinite(0));
        }
        dp.push(v);
    }
    Ok(LimitSensitivity { dp, rayleigh })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dofmap::{Constraints, DofSpec, RigidBody};
    use crate::element::Formulation;
    use crate::material::{Material, NeoHookean};
    use crate::mesh::ElementKind;
    use crate::meshgen;
    use crate::solve::{newton_factored, NewtonOptions};

    /// A block with the bottom fixed and a rigid top plate: the plate's vertical translation
    /// prescribed (stretch) or free under a dead force, its rotation about z prescribed or free.
    fn block(twist_free: bool) -> Model {
        let mesh = meshgen::boxed(ElementKind::Hex27, [2, 2, 2], [1.0, 1.2, 2.0]);
        let mut cons = Constraints::default();
        cons.prescribe_set(&mesh.node_sets["zmin"], &[0, 1, 2], 0.0);
        let held = DofSpec::Prescribed(0.0);
        cons.bodies.push(RigidBody {
            name: "top".into(),
            reference: [0.5, 0.6, 2.0],
            nodes: mesh.node_sets["zmax"].clone(),
            mask: [true; 3],
            dofs: [held, held, DofSpec::Free, held, held, if twist_free { DofSpec::Free } else { DofSpec::Prescribed(0.2) }],
        });
        let mat = Material::NeoHookean(NeoHookean::with_ratio(1.0, 50.0).unwrap());
        Model::new(mesh.clone(), Formulation::standard(ElementKind::Hex27), mat, &cons, None).unwrap()
    }

    fn loads(m: &Model, s: f64) -> Loads {
        let mut l = Loads::zero(m);
        l.presc = m.dofs.presc_targets.clone();
        l.body_forces = vec![[0.0, 0.0, 0.3 * s]];
        // a dead torque about z on the plate: a nodal force couple on its nodes
        l.nodal_forces = vec![0.0; 3 * m.mesh.nodes.len()];
        for &n in &m.mesh.node_sets["zmax"] {
            let x = m.mesh.nodes[n];
            l.nodal_forces[3 * n] = -0.02 * s * (x[1] - 0.6);
            l.nodal_forces[3 * n + 1] = 0.02 * s * (x[0] - 0.5);
        }
        l
    }

    #[test]
    fn generic_residual_matches_assembly() {
        let m = block(true);
        let l = loads(&m, 1.0);
        let q: Vec<f64> = (0..m.n_reduced()).map(|i| 1e-2 * ((i as f64) * 0.37).sin()).collect();
        let a = m.assemble(&q, &l, true).unwrap();
        let inp = Inputs { x0: &m.mesh.nodes, q: &q, pressure: l.pressure, presc: &l.presc, params: &m.params };
        let st = evaluate(&m, &inp, &l).unwrap();
        let scale = a.r.iter().map(|v| v.abs()).fold(0.0, f64::max);
        for (x, y) in st.r.iter().zip(&a.r) {
            assert!((x - y).abs() <= 1e-12 * scale, "{x} vs {y}");
        }
        // dual in q reproduces the tangent: ∂r/∂q · v = K v
        let v: Vec<f64> = (0..m.n_reduced()).map(|i| ((i as f64) * 1.3).cos()).collect();
        let ds = dual_state(&m, &q, &l, &Direction::default(), Some(&v)).unwrap();
        let kv = m.sym_matvec(a.k.as_ref().unwrap(), &v);
        let ks = kv.iter().map(|x| x.abs()).fold(0.0, f64::max);
        for (x, y) in ds.r.iter().zip(&kv) {
            assert!((x.eps - y).abs() <= 1e-9 * ks, "{} vs {y}", x.eps);
        }
    }

    /// Equilibrium of the block for a perturbed input, solved by Newton from `q0`.
    fn solve(m: &Model, q0: &[f64], l: &Loads) -> (Vec<f64>, Factor) {
        let mut q = q0.to_vec();
        let opts = NewtonOptions { rtol: 1e-13, ..Default::default() };
        let (_, _, f) = newton_factored(m, &mut q, l, &opts).unwrap();
        (q, f)
    }

    #[test]
    fn adjoint_matches_central_differences_on_a_block() {
        for twist_free in [true, false] {
            let m = block(twist_free);
            let l = loads(&m, 1.0);
            let (q, fac) = solve(&m, &vec![0.0; m.n_reduced()], &l);
            let functionals = vec![
                Functional::BodyDof { body: 0, dof: 2 },
                Functional::BodyDof { body: 0, dof: 5 },
                Functional::BodyReaction { body: 0, dof: 5 },
                Functional::KsRadius { nodes: m.mesh.node_sets["zmax"].clone(), rho: 8.0 },
            ];
            // shape: a smooth bulge; material: μ; a dead-load and a prescribed-value direction
            let bulge: Vec<[f64; 3]> = m.mesh.nodes.iter().map(|x| [0.1 * x[2] * x[0], -0.05 * x[2] * x[2], 0.02 * x[0] * x[1]]).collect();
            let dirs = vec![Direction { name: "shape".into(), dx0: Some(bulge.clone()), ..Default::default() }, Direction { name: "mu".into(), dparams: vec![1.0, 0.0], ..Default::default() }];
            let s = sensitivities(&m, &q, &l, &fac, &functionals, &dirs).unwrap();
            let h = 1e-5;
            for (k, dir) in dirs.iter().enumerate() {
                let perturbed = |t: f64| {
                    let mut mp = block(twist_free);
                    if let Some(d) = &dir.dx0 {
                        for (x, dx) in mp.mesh.nodes.iter_mut().zip(d) {
                            for i in 0..3 {
                                x[i] += t * dx[i];
                            }
                        }
                        // the model caches geometry-independent data only; rebuild for safety
                        let cons_model = Model::new(mp.mesh.clone(), mp.form, mp.material, &constraints_of(&mp), None).unwrap();
                        mp = cons_model;
                    }
                    for (p, dp) in mp.params.iter_mut().zip(dir.dparams.iter().chain(std::iter::repeat(&0.0))) {
                        *p += t * dp;
                    }
                    let (qp, _) = solve(&mp, &q, &l);
                    let inp = Inputs { x0: &mp.mesh.nodes, q: &qp, pressure: l.pressure, presc: &l.presc, params: &mp.params };
                    let st = evaluate(&mp, &inp, &l).unwrap();
                    functionals.iter().map(|f| f.eval(&mp, &st).unwrap()).collect::<Vec<f64>>()
                };
                let (jp, jm) = (perturbed(h), perturbed(-h));
                for i in 0..functionals.len() {
                    let fd = (jp[i] - jm[i]) / (2.0 * h);
                    let ad = s.gradients[i][k];
                    let scale = fd.abs().max(1e-6 * s.values[i].abs()).max(1e-12);
                    assert!((fd - ad).abs() <= 1e-6 * scale + 1e-9, "twist_free {twist_free} functional {i} dir {}: adjoint {ad} fd {fd}", dir.name);
                }
            }
        }
    }

    /// The closed-end inflation slice of [`crate::verify`] with the top cap carrying no pressure.
    fn open_slice() -> crate::verify::InflationSlice {
        let mut s = crate::verify::inflation_slice(Formulation::standard(ElementKind::Hex27), 4, 2, 2.0, 100.0).unwrap();
        s.model.cavity.as_mut().unwrap().cap_load = false;
        s
    }

    #[test]
    fn caps_without_pressure_remove_exactly_p_times_the_cap_area() {
        let mut s = crate::verify::inflation_slice(Formulation::standard(ElementKind::Hex27), 4, 2, 2.0, 100.0).unwrap();
        let n = s.model.n_reduced();
        let q: Vec<f64> = (0..n).map(|i| 1e-2 * ((i as f64) * 0.37).sin()).collect();
        let mut l = Loads::zero(&s.model);
        l.pressure = 0.03;
        let on = s.model.assemble(&q, &l, true).unwrap();
        s.model.cavity.as_mut().unwrap().cap_load = false;
        let off = s.model.assemble(&q, &l, true).unwrap();
        let areas = crate::surface::rigid_cap_areas(s.model.cavity.as_ref().unwrap(), &s.model.dofs, &s.model.mesh.nodes);
        // the quarter disc of radius a = 17 bounded by the quadratic inner arc
        let exact = std::f64::consts::PI * 17.0 * 17.0 / 4.0;
        assert!((areas[0] - exact).abs() < 2e-3 * exact, "cap area {} vs {exact}", areas[0]);
        let BodyDof::Free(iz) = s.model.dofs.body_dofs[0][2] else { panic!("free z") };
        for i in 0..n {
            let d = off.r[i] - on.r[i];
            let expect = if i == iz { l.pressure * areas[0] } else { 0.0 };
            assert!((d - expect).abs() < 1e-12 * (1.0 + expect.abs()), "dof {i}: {d} vs {expect}");
        }
        assert_eq!(on.k, off.k, "the removed cap force is a dead load: same tangent");
        // the generic evaluation (adjoint residual) agrees with the assembly
        let inp = Inputs { x0: &s.model.mesh.nodes, q: &q, pressure: l.pressure, presc: &l.presc, params: &s.model.params };
        let st = evaluate(&s.model, &inp, &l).unwrap();
        let sc = off.r.iter().map(|v| v.abs()).fold(0.0, f64::max);
        assert!(st.r.iter().zip(&off.r).all(|(a, b)| (a - b).abs() <= 1e-12 * sc));
        // the unit-pressure load is ∂V/∂q less the cap area on the cap's DOF
        let unit = s.model.unit_pressure_load(&off.dvol);
        assert!((off.dvol[iz] - unit[iz] - areas[0]).abs() < 1e-12 * areas[0]);
    }

    #[test]
    fn adjoint_matches_central_differences_without_cap_load() {
        let s = open_slice();
        let m = &s.model;
        let mut l = Loads::zero(m);
        l.pressure = 0.02;
        let (q, fac) = solve(m, &vec![0.0; m.n_reduced()], &l);
        let functionals = vec![Functional::BodyDof { body: 0, dof: 2 }, Functional::CavityVolume];
        // a radial bulge that changes the cap area, and the pressure
        let bulge: Vec<[f64; 3]> = m.mesh.nodes.iter().map(|x| [0.03 * x[0] * (1.0 + 0.1 * x[2]), 0.03 * x[1] * (1.0 + 0.1 * x[2]), 0.0]).collect();
        let dirs = vec![Direction { name: "shape".into(), dx0: Some(bulge.clone()), ..Default::default() }, Direction { name: "p".into(), dpressure: 1.0, ..Default::default() }];
        let sens = sensitivities(m, &q, &l, &fac, &functionals, &dirs).unwrap();
        let h = 1e-6;
        for (k, dir) in dirs.iter().enumerate() {
            let eval = |t: f64| {
                let mut sp = open_slice();
                if let Some(d) = &dir.dx0 {
                    for (x, dx) in sp.model.mesh.nodes.iter_mut().zip(d) {
                        for i in 0..3 {
                            x[i] += t * dx[i];
                        }
                    }
                }
                let mut lp = l.clone();
                lp.pressure += t * dir.dpressure;
                let (qp, _) = solve(&sp.model, &q, &lp);
                let inp = Inputs { x0: &sp.model.mesh.nodes, q: &qp, pressure: lp.pressure, presc: &lp.presc, params: &sp.model.params };
                let st = evaluate(&sp.model, &inp, &lp).unwrap();
                functionals.iter().map(|f| f.eval(&sp.model, &st).unwrap()).collect::<Vec<f64>>()
            };
            let (jp, jm) = (eval(h), eval(-h));
            for i in 0..functionals.len() {
                let fd = (jp[i] - jm[i]) / (2.0 * h);
                let ad = sens.gradients[i][k];
                assert!((fd - ad).abs() <= 1e-5 * fd.abs().max(1e-8), "functional {i} dir {}: adjoint {ad} fd {fd}", dir.name);
            }
        }
    }

    #[test]
    fn volume_control_without_cap_load_meets_pressure_control() {
        let s = open_slice();
        let m = &s.model;
        let mut l = Loads::zero(m);
        l.pressure = 0.02;
        let (q, _) = solve(m, &vec![0.0; m.n_reduced()], &l);
        let v = m.assemble(&q, &l, false).unwrap().volume;
        let mut to = Loads::zero(m);
        to.pressure = 0.05;
        let o = crate::continuation::ContinuationOptions { start_control: crate::continuation::Control::Functional, control_end: Some(v), ..Default::default() };
        let r = crate::continuation::ramp(m, &vec![0.0; m.n_reduced()], &Loads::zero(m), &to, &o);
        assert_eq!(r.end, crate::continuation::PathEnd::Completed);
        assert!((r.loads.pressure - 0.02).abs() < 1e-7, "pressure {} vs 0.02", r.loads.pressure);
        // the open tube (no end force) shortens where the closed one lengthens
        let a = m.assemble(&q, &l, false).unwrap();
        let (_, lz_open) = s.stretches(&a);
        let closed = crate::verify::inflation_slice(Formulation::standard(ElementKind::Hex27), 4, 2, 2.0, 100.0).unwrap();
        let (qc, _) = solve(&closed.model, &vec![0.0; closed.model.n_reduced()], &l);
        let (_, lz_closed) = closed.stretches(&closed.model.assemble(&qc, &l, false).unwrap());
        assert!(lz_open < 1.0 && lz_closed > lz_open, "λz open {lz_open}, closed {lz_closed}");
    }

    fn constraints_of(m: &Model) -> Constraints {
        let mut cons = Constraints::default();
        cons.prescribe_set(&m.mesh.node_sets["zmin"], &[0, 1, 2], 0.0);
        cons.bodies = m.dofs.bodies.clone();
        cons
    }
}
