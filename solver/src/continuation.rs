//! Path following: one continuation method for every load path, written once against a model
//! interface ([`PathModel`]) that the full sparse model ([`LoadPath`]) and a reduced-order model
//! both implement.
//!
//! A path is the equilibrium set r(q, λ) = 0 of a model under loads that depend on one parameter
//! λ ∈ [λ₀, λ_end] (e.g. a cavity pressure ramp). The method:
//!
//! * **Predictor.** At a converged point the tangent t = dq/dλ = −K⁻¹ ∂r/∂λ costs one solve with
//!   the factor already computed. The first step predicts along t; once two points exist, a
//!   Hermite extrapolation through the previous point (value) and the current one (value and
//!   tangent) is used, whose error is O(h³) instead of O(h²).
//! * **Step length** from the prediction error of the last step, e = ‖q − q_pred‖/‖q_pred − q_k‖
//!   (∝ h for the tangent line, ∝ h² for the extrapolation; target `target_error`), capped by the
//!   Newton iteration count. (A prediction error estimated before the solve, from the chord
//!   correction with the current factor, was tried and overestimates the true error 100–300×
//!   here: the residual of a prediction is dominated by the volumetric term κ·O(|Δq|²).)
//! * **Corrector.** Newton with the mixed (three-field) tangent linearised about the previous
//!   iterate ([`crate::model::Model::assemble_lin`]), an energy-slope line search whose trial
//!   points need only residuals, and the stopping test of [`NewtonOptions`].
//! * **Control switch.** Where the model has a control functional c(q) (the cavity volume), the
//!   path switches from λ to c as its parameter before a fold of λ: when the stiffness dλ/dc has
//!   fallen below `switch_stiffness` of its initial value, or when the next λ step would reach
//!   half-way to the fold predicted from the stiffness trend. Under c control (bordered Newton: λ
//!   is an unknown) the fold is a regular point, so it is passed and located instead of probed
//!   by failing load steps.
//! * **Events located on the path by root finding**: the fold (λ maximum, dλ/dc = 0; secant on
//!   the stiffness, to `locate_tol` relative in λ), loss of stability with λ still rising (a
//!   bifurcation; secant on the tangent's smallest eigenvalue, bisection as a fallback), output
//!   thresholds ([`Stop`], e.g. a ballooning limit on a radius; Illinois regula falsi), stations
//!   (λ values the path must produce a point at) and the end λ_end.
//!
//! Every Newton iteration is counted, those of failed attempts too ([`PathStats`]).

use crate::adjoint::{self, Functional};
use crate::element::ElementError;
use crate::model::{Assembled, Factor, Loads, Model, SolveError};
use crate::solve::{FailureCause, NewtonFailure, NewtonOptions};

/// What a model evaluates at a state (q, λ).
#[derive(Clone, Debug)]
pub struct Eval<K> {
    /// The residual r(q, λ) in the model's unknowns.
    pub r: Vec<f64>,
    /// The force scale for relative convergence tests (size of the terms summed into r).
    pub scale: f64,
    /// The control functional c(q) and its gradient ∂c/∂q (e.g. the cavity volume); None = the
    /// model has none (the path stays under λ control).
    pub control: Option<(f64, Vec<f64>)>,
    /// Smallest det F (or equivalent) of the state, for reports.
    pub min_det: f64,
    /// The tangent ∂r/∂q, when requested.
    pub k: Option<K>,
    /// The potential Π(q, λ) whose gradient is r, when the model has one and knows it (else
    /// [`relax`] estimates its changes from the slope along a step).
    pub potential: Option<f64>,
}

/// Why a model could not be evaluated at a state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EvalFailure {
    /// An element inverted (det F ≤ 0).
    Inversion,
    /// A non-finite value.
    NonFinite,
}

/// The model interface of the path follower: residual and tangent, factorisation and solves, the
/// load rate and the outputs. Nothing here needs the full nodal fields.
pub trait PathModel {
    type Matrix;
    type Factor;
    /// Number of unknowns.
    fn dim(&self) -> usize;
    /// Residual (and, with `tangent`, the tangent) at (q, λ). `lin` is the state the tangent's
    /// internal fields are linearised about (None = the exact tangent at q).
    fn eval(&self, q: &[f64], lam: f64, tangent: bool, lin: Option<&[f64]>) -> Result<Eval<Self::Matrix>, EvalFailure>;
    /// Factor the tangent: Cholesky when `definite` (an error if not positive definite), else a
    /// factorisation of a symmetric indefinite matrix.
    fn factor(&self, k: &Self::Matrix, definite: bool) -> Result<Self::Factor, SolveError>;
    fn solve(&self, f: &Self::Factor, b: &[f64]) -> Result<Vec<f64>, SolveError>;
    /// The largest fraction of the step q → q + dq at λ that the model admits before evaluating
    /// it (contact: no node may pass through a surface on the way; 1 by default).
    fn step_limit(&self, _q: &[f64], _lam: f64, _dq: &[f64]) -> f64 {
        1.0
    }
    /// The diagonal of a tangent (None: the model cannot; [`relax`] then refuses).
    fn diagonal(&self, _k: &Self::Matrix) -> Option<Vec<f64>> {
        None
    }
    /// The tangent with `d` added to its diagonal (the shifted matrix of [`relax`]).
    fn shifted(&self, _k: &Self::Matrix, _d: &[f64]) -> Option<Self::Matrix> {
        None
    }
    /// ∂r/∂λ at fixed q (`ev` is the evaluation at (q, λ)).
    fn load_rate(&self, q: &[f64], lam: f64, ev: &Eval<Self::Matrix>) -> Result<Vec<f64>, EvalFailure>;
    /// The outputs recorded at a converged point.
    fn outputs(&self, q: &[f64], lam: f64, ev: &Eval<Self::Matrix>) -> Vec<f64>;
    /// The coordinates y(q) in which the path is extrapolated (identity by default). A model whose
    /// unknowns include finite rotations predicts better in coordinates that represent those
    /// rotations linearly ([`LoadPath`] uses cylindrical coordinates about its rigid body's axis).
    fn predictor_coords(&self, q: &[f64]) -> Vec<f64> {
        q.to_vec()
    }
    /// dy = (∂y/∂q) dq at q.
    fn predictor_rate(&self, _q: &[f64], dq: &[f64]) -> Vec<f64> {
        dq.to_vec()
    }
    /// q(y), the inverse of [`PathModel::predictor_coords`].
    fn from_predictor_coords(&self, y: &[f64]) -> Vec<f64> {
        y.to_vec()
    }
}

/// How the path is parametrised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Control {
    /// λ is prescribed (load control).
    Load,
    /// The control functional c(q) is prescribed and λ is an unknown (volume control).
    Functional,
}

/// An output threshold that ends the path where it is first crossed: output `output` reaching
/// `threshold` from below (`rising`) or from above.
#[derive(Clone, Debug, PartialEq)]
pub struct Stop {
    pub name: String,
    pub output: usize,
    pub threshold: f64,
    pub rising: bool,
}

impl Stop {
    /// Whether the output goes from before the threshold (`from`) to on or beyond it (`to`).
    pub fn crossed(&self, from: f64, to: f64) -> bool {
        let sg = if self.rising { 1.0 } else { -1.0 };
        sg * (from - self.threshold) < 0.0 && sg * (to - self.threshold) >= 0.0
    }
}

/// Path-following options.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ContinuationOptions {
    /// First step, as a fraction of λ_end − λ₀.
    pub initial: f64,
    /// Smallest step (fraction of λ_end − λ₀) before a failure is accepted.
    pub min: f64,
    /// Largest step (fraction of λ_end − λ₀).
    pub max: f64,
    /// Step length target: the prediction error e = ‖q − q_predicted‖/‖q_predicted − q_previous‖
    /// of a converged step (e ∝ h for the tangent line, ∝ h² for the quadratic extrapolation).
    pub target_error: f64,
    /// The same target under control-functional control, where Newton's convergence radius was
    /// measured smaller (steps at e ≈ 1e-2 failed under volume control, converged under load
    /// control).
    pub target_error_functional: f64,
    /// Under control-functional control, a step is kept within this multiple of the distance to
    /// the fold predicted from the stiffness trend (dλ/dc linear in c): the fold is bracketed
    /// without overshooting into the unstable, poorly convergent branch beyond it.
    pub fold_overshoot: f64,
    /// Steps that needed more Newton iterations than this are not grown.
    pub target_iterations: usize,
    /// Largest growth of the step from one step to the next.
    pub max_growth: f64,
    pub max_steps: usize,
    /// Switch to control-functional control when dλ/dc falls below this fraction of its first
    /// value (None = never switch; the fold is then found by loss of stability).
    pub switch_stiffness: Option<f64>,
    /// Relative accuracy in λ of located events (fold, stability loss, thresholds).
    pub locate_tol: f64,
    /// Relative accuracy in c of a located fold's state (its outputs vary with c at first
    /// order): the next secant estimate within it, or the bracket narrower than it (where the
    /// stiffness jumps at a stability loss next to the pressure maximum, the secant stalls
    /// and the bracket is bisected).
    #[serde(default = "default_locate_control_tol")]
    pub locate_control_tol: f64,
    /// End the path at a fold of λ (else pass it under control-functional control).
    pub stop_at_fold: bool,
    /// End the path where a converged point loses stability with λ still rising.
    pub stop_at_instability: bool,
    /// Start under this control (`Functional` for paths beyond a fold).
    pub start_control: Control,
    /// With `Functional` control: end where the control functional reaches this value.
    pub control_end: Option<f64>,
    /// Use the mixed (linearised-dilatation) tangent in Newton iterations.
    pub mixed_tangent: bool,
    /// Predict by the cubic Hermite extrapolation through the last two points (values and
    /// tangents; error O(h⁴)) instead of the quadratic (value, tangent, previous value; O(h³)).
    pub cubic: bool,
    /// A path started under functional control (`start_control`): its first step as a
    /// fraction of |c| at the start (None: `initial` of λ_end − λ₀ converted by dc/dλ there),
    /// e.g. from a nearby design's path (a warm start near its fold).
    #[serde(default)]
    pub initial_functional: Option<f64>,
    pub newton: NewtonOptions,
}

impl Default for ContinuationOptions {
    fn default() -> Self {
        ContinuationOptions {
            initial: 0.01,
            min: 1e-5,
            max: 0.25,
            target_error: 0.01,
            target_error_functional: 0.003,
            fold_overshoot: 1.5,
            target_iterations: 4,
            max_growth: 2.0,
            max_steps: 500,
            switch_stiffness: Some(0.35),
            locate_tol: 1e-6,
            locate_control_tol: default_locate_control_tol(),
            stop_at_fold: true,
            stop_at_instability: true,
            start_control: Control::Load,
            control_end: None,
            // measured: with the cubic, cylindrical predictor the exact tangent needs fewer
            // iterations than the mixed one (132 vs 150 on a sweep design) and meets fewer
            // indefinite iterates; with the tangent-line predictor alone the mixed one was better
            mixed_tangent: false,
            cubic: true,
            initial_functional: None,
            // ‖r‖ ≤ 1e-7 of the force scale: quadratic convergence overshoots it, so the outputs
            // at fixed load move by < 1e-9 relative against 1e-12 (measured; see README)
            // (and give up on a solve whose residual is above its start after 3 iterations: the
            // step control retries a shorter step for less than a failed solve's iterations)
            newton: NewtonOptions { rtol: 1e-7, stall_iterations: 3, stall_ratio: 0.1, ..NewtonOptions::default() },
        }
    }
}

fn default_locate_control_tol() -> f64 {
    1e-4
}

/// Why a path point was recorded.
#[derive(Clone, Debug, PartialEq)]
pub enum PointKind {
    Start,
    Step,
    /// One of the requested stations (its index).
    Station(usize),
    /// Where the path ended (fold, instability, threshold, end).
    End,
    /// The stable state a snap landed on ([`follow_snapping`]): the path jumps to it from the
    /// point before.
    Snapped,
}

/// A converged point of the path.
#[derive(Clone, Debug)]
pub struct PathPoint {
    pub lam: f64,
    pub q: Vec<f64>,
    /// control functional value
    pub control: Option<f64>,
    pub outputs: Vec<f64>,
    pub min_det: f64,
    /// the tangent is positive definite
    pub stable: bool,
    pub kind: PointKind,
    /// Newton iterations spent on this point (including failed attempts before it)
    pub newton_iterations: usize,
}

/// How a path ended.
#[derive(Clone, Debug, PartialEq)]
pub enum PathEnd {
    /// λ_end (or `control_end`) reached.
    Completed,
    /// A fold of λ (its maximum along the path), located to `locate_tol`.
    Fold,
    /// The tangent lost positive definiteness with λ still rising (a bifurcation), located to
    /// `locate_tol`: the last point is the last stable state.
    Instability,
    /// An output threshold was reached ([`Stop`] by index).
    Stopped(usize),
    /// The path could not be continued.
    Failed(FailureCause),
}

/// Work counts of a path.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathStats {
    /// converged continuation steps (points other than the start)
    pub steps: usize,
    /// Newton iterations (tangent factorisations of iterates), all attempts
    pub newton_iterations: usize,
    /// of which in attempts that failed
    pub failed_iterations: usize,
    pub failed_attempts: usize,
    /// tangent factorisations in all
    pub factorizations: usize,
    /// Newton iterations spent locating events (included in `newton_iterations`)
    pub locate_iterations: usize,
}

impl PathStats {
    pub fn add(&mut self, o: &PathStats) {
        self.steps += o.steps;
        self.newton_iterations += o.newton_iterations;
        self.failed_iterations += o.failed_iterations;
        self.failed_attempts += o.failed_attempts;
        self.factorizations += o.factorizations;
        self.locate_iterations += o.locate_iterations;
    }
}

/// The result of a path.
pub struct PathResult<M: PathModel> {
    pub points: Vec<PathPoint>,
    pub end: PathEnd,
    pub stats: PathStats,
    /// The tangent and its factor at the last point (for adjoint and limit sensitivities), when
    /// it could be factored.
    pub last: Option<(M::Matrix, M::Factor)>,
    /// the control in use at the end
    pub control: Control,
}

/// A converged state with its tangent factor, its path tangent and stiffness.
struct Node<M: PathModel> {
    lam: f64,
    q: Vec<f64>,
    ev: Eval<M::Matrix>,
    factor: M::Factor,
    stable: bool,
    /// the state and dq/dλ in predictor coordinates
    y: Vec<f64>,
    ty: Vec<f64>,
    /// c and dc/dλ
    c: Option<f64>,
    dc: Option<f64>,
    out: Vec<f64>,
    /// the factor is the last Newton iterate's, not this state's ([`Solved::lagged`])
    lagged: bool,
}

impl<M: PathModel> Node<M> {
    /// dλ/dc
    fn stiffness(&self) -> Option<f64> {
        self.dc.map(|d| 1.0 / d)
    }
    fn param(&self, ctl: Control) -> f64 {
        match ctl {
            Control::Load => self.lam,
            Control::Functional => self.c.unwrap_or(f64::NAN),
        }
    }
    /// d(y, λ)/d(parameter), y the predictor coordinates
    fn rates(&self, ctl: Control) -> (Vec<f64>, f64) {
        match (ctl, self.dc) {
            (Control::Functional, Some(dc)) => (self.ty.iter().map(|v| v / dc).collect(), 1.0 / dc),
            _ => (self.ty.clone(), 1.0),
        }
    }
}

/// The stationary point of the cubic λ(c) with values λ0, λ1 and slopes k0, k1 at c0, c1, where
/// the slopes have opposite signs: the root of its quadratic derivative between c0 and c1 (None
/// where the data give none there, e.g. non-finite values).
fn hermite_stationary(c0: f64, l0: f64, k0: f64, c1: f64, l1: f64, k1: f64) -> Option<f64> {
    let h = c1 - c0;
    if !(h != 0.0 && h.is_finite() && k0 * k1 < 0.0 && l0.is_finite() && l1.is_finite()) {
        return None;
    }
    // h dλ/dc(t) = (6t² − 6t)(λ0 − λ1) + h k0 (3t² − 4t + 1) + h k1 (3t² − 2t), t = (c − c0)/h
    let d = l0 - l1;
    let (qa, qb, qc) = (6.0 * d + 3.0 * h * (k0 + k1), -6.0 * d - h * (4.0 * k0 + 2.0 * k1), h * k0);
    let scale = qa.abs().max(qb.abs()).max(qc.abs());
    let t = if qa.abs() <= 1e-12 * scale {
        -qc / qb
    } else {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 {
            return None;
        }
        // (the numerically stable pair of roots; the one in (0, 1))
        let r = -0.5 * (qb + qb.signum() * disc.sqrt());
        [r / qa, if r != 0.0 { qc / r } else { f64::NAN }].into_iter().find(|t| *t > 0.0 && *t < 1.0)?
    };
    (t > 0.0 && t < 1.0).then_some(c0 + t * h)
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The outcome of a corrector solve.
pub struct Solved<M: PathModel> {
    pub q: Vec<f64>,
    pub lam: f64,
    pub ev: Eval<M::Matrix>,
    pub factor: M::Factor,
    /// the converged tangent is positive definite
    pub stable: bool,
    pub iterations: usize,
    /// ‖r‖ of every iterate, with `NewtonOptions::log`
    pub residual_norms: Vec<f64>,
    /// the factor (and `ev.k`) are those of the last Newton iterate before q, not of q itself
    /// (converged within one correction: see `lagged` of [`correct`])
    pub lagged: bool,
}

/// Newton's method at fixed λ (load control, `c_target` None) or with the control functional
/// held at `c_target` (λ an unknown; the bordered system K Δq + r_λ Δλ = −r, ∇cᵀ Δq = c_target −
/// c solved with one factorisation and two solves). `lin0` is the state the first tangent is
/// linearised about (the converged point a prediction came from). Under load control an energy
/// line search (trial points need residuals only) globalises the step. A converged state whose
/// tangent is not positive definite is returned with `stable = false` and an indefinite factor.
/// With `lagged`, a state that converges right after a correction is returned with the factor of
/// the iterate before it (one correction away, relative difference ~ the last correction) instead
/// of a new tangent assembly and factorisation: the path follower does this for its steps and
/// refactors only the states it hands on. On failure the iterations spent are returned with the
/// cause.
#[allow(clippy::too_many_arguments)]
pub fn correct<M: PathModel>(m: &M, q0: &[f64], lam0: f64, c_target: Option<f64>, opts: &NewtonOptions, mixed: bool, lin0: Option<&[f64]>, lagged: bool) -> Result<Solved<M>, (NewtonFailure, usize)> {
    let trace = trace_enabled();
    let mut q = q0.to_vec();
    let mut lam = lam0;
    let mut lin: Option<Vec<f64>> = lin0.filter(|_| mixed).map(|v| v.to_vec());
    let mut its = 0usize;
    let mut indefinite_seen = false;
    let fail = |f: NewtonFailure, its: usize, indefinite_seen: bool| {
        // a solve that met indefinite tangents and then failed to converge is the signature of a
        // load beyond a limit point (no nearby stable equilibrium)
        let f = match f {
            NewtonFailure::Divergence | NewtonFailure::IterationLimit if indefinite_seen && c_target.is_none() && !opts.indefinite => NewtonFailure::NotPositiveDefinite,
            other => other,
        };
        Err((f, its))
    };
    let mut ev = match m.eval(&q, lam, true, lin.as_deref()) {
        Ok(e) => e,
        Err(e) => return fail(eval_fail(e), 0, false),
    };
    let mut last_norm = f64::INFINITY;
    let mut growth = 0;
    let mut e0 = 0.0;
    let mut r0 = f64::INFINITY;
    let mut log = Vec::new();
    let ctol = c_target.map(|c| 1e-10 * c.abs().max(ev.control.as_ref().map_or(0.0, |x| x.0.abs())).max(1e-300));
    for it in 0..=opts.max_iter {
        let rn = norm(&ev.r);
        let dc = match (c_target, &ev.control) {
            (Some(ct), Some((c, _))) => ct - c,
            (Some(_), None) => return fail(NewtonFailure::Divergence, its, indefinite_seen),
            _ => 0.0,
        };
        if !rn.is_finite() || !dc.is_finite() {
            return fail(NewtonFailure::Divergence, its, indefinite_seen);
        }
        if opts.log {
            log.push(rn);
        }
        let scale = ev.scale;
        let tol = (opts.rtol * scale).max(opts.atol);
        let floor = (opts.stagnation_rtol * scale).max(opts.atol);
        let at_floor = it > 0 && rn <= floor && rn > 0.5 * last_norm;
        let c_ok = ctol.map_or(true, |t| dc.abs() <= t);
        if (rn <= tol || at_floor) && c_ok {
            let k = ev.k.as_ref().expect("tangent requested");
            return match definite_factor(m, k) {
                Some((factor, stable)) => Ok(Solved { q, lam, ev, factor, stable, iterations: its, residual_norms: log, lagged: false }),
                None => fail(NewtonFailure::Divergence, its, indefinite_seen),
            };
        }
        if it == opts.max_iter {
            break;
        }
        if rn > last_norm * 1e3 {
            growth += 1;
            if growth >= 2 {
                return fail(NewtonFailure::Divergence, its, indefinite_seen);
            }
        }
        if it == 0 {
            r0 = rn;
        }
        // fail fast: a solve that is not converging hands back to the step control early
        // (after stall_iterations a converging solve has cut its residual by far more than 10×:
        // measured 3e-5 at worst on sweep designs; stalled ones, on an indefinite tangent with
        // line-search steps of 0.01–0.1, by less than 2×)
        // (not below the stagnation floor: there a solve polishing to round-off is not stalled)
        if rn > floor && ((it >= opts.stall_iterations && rn > opts.stall_ratio * r0) || (it >= 2 * opts.stall_iterations && rn > 1e-6 * r0)) {
            return fail(NewtonFailure::Divergence, its, indefinite_seen);
        }
        last_norm = rn;
        its += 1;
        let k = ev.k.take().expect("tangent requested");
        // Cholesky first (also under functional control, where the tangent is positive definite
        // until the fold), an indefinite factorisation when it fails
        let (factor, definite) = match m.factor(&k, !opts.indefinite) {
            Ok(f) => (f, !opts.indefinite),
            Err(SolveError::NotPositiveDefinite) => {
                indefinite_seen = true;
                match m.factor(&k, false) {
                    Ok(f) => (f, false),
                    Err(_) => return fail(NewtonFailure::NotPositiveDefinite, its, indefinite_seen),
                }
            }
            Err(_) => return fail(NewtonFailure::Divergence, its, indefinite_seen),
        };
        let neg: Vec<f64> = ev.r.iter().map(|v| -v).collect();
        let Ok(a) = m.solve(&factor, &neg) else {
            return fail(NewtonFailure::Divergence, its, indefinite_seen);
        };
        // the step (Δq, Δλ)
        let (dq, dlam) = match (c_target, &ev.control) {
            (Some(_), Some((_, g))) => {
                let rl = match m.load_rate(&q, lam, &ev) {
                    Ok(v) => v,
                    Err(e) => return fail(eval_fail(e), its, indefinite_seen),
                };
                let Ok(b) = m.solve(&factor, &rl) else {
                    return fail(NewtonFailure::Divergence, its, indefinite_seen);
                };
                // Δq = a − Δλ b with ∇cᵀΔq = dc
                let dl = (dot(g, &a) - dc) / dot(g, &b);
                if !dl.is_finite() {
                    return fail(NewtonFailure::Divergence, its, indefinite_seen);
                }
                (a.iter().zip(&b).map(|(x, y)| x - dl * y).collect::<Vec<f64>>(), dl)
            }
            _ => (a, 0.0),
        };
        let g0 = dot(&dq, &ev.r);
        {
            if it == 0 {
                e0 = g0.abs();
            } else if g0.abs() <= opts.etol * e0 && rn <= floor && c_ok {
                // energy criterion: the remaining correction carries no energy
                ev.k = Some(k);
                // (this iterate's factorisation is the converged state's: not a correction)
                return match definite_factor(m, ev.k.as_ref().expect("kept")) {
                    Some((f, s)) => Ok(Solved { q, lam, ev, factor: f, stable: s, iterations: its - 1, residual_norms: log, lagged: false }),
                    None => fail(NewtonFailure::Divergence, its, indefinite_seen),
                };
            }
        }
        // line search: residual-only trials on the energy slope g(s) = Δq·r(q + sΔq) under load
        // control; step cutting on inversion only under functional control
        // (from the longest step the model admits: no passage through a contact surface)
        let mut s = m.step_limit(&q, lam, &dq).clamp(1e-6, 1.0);
        let mut accepted: Option<(Vec<f64>, f64, Eval<M::Matrix>)> = None;
        for _ls in 0..8 {
            let qt: Vec<f64> = q.iter().zip(&dq).map(|(x, d)| x + s * d).collect();
            let lt = lam + s * dlam;
            match m.eval(&qt, lt, false, None) {
                Err(_) => {
                    s *= 0.25;
                    continue;
                }
                Ok(et) => {
                    if c_target.is_some() || !opts.line_search || opts.indefinite {
                        accepted = Some((qt, lt, et));
                        break;
                    }
                    let gs = dot(&dq, &et.r);
                    if !gs.is_finite() {
                        s *= 0.25;
                        continue;
                    }
                    if gs.abs() <= 0.8 * g0.abs() || s < 0.05 || g0 >= 0.0 {
                        accepted = Some((qt, lt, et));
                        break;
                    }
                    // secant step towards the zero of g along the direction
                    let snew = if gs > 0.0 { s * g0 / (g0 - gs) } else { s * 2.0 };
                    let snew = snew.clamp(0.1 * s, 1.0);
                    if (snew - s).abs() < 1e-3 {
                        accepted = Some((qt, lt, et));
                        break;
                    }
                    s = snew;
                }
            }
        }
        if trace {
            let (imax, rmax) = ev.r.iter().enumerate().fold((0, 0.0f64), |a, (i, v)| if v.abs() > a.1 { (i, v.abs()) } else { a });
            let n = ev.r.len();
            let tail = norm(&ev.r[n.saturating_sub(2)..]);
            let after = accepted.as_ref().map_or(f64::NAN, |a| norm(&a.2.r));
            eprintln!(
                "[newton] it {it} |r| {rn:.3e} (max {rmax:.2e} at {imax}/{n}, last two {tail:.2e}) scale {scale:.3e} dc {dc:.3e} g0 {g0:.3e} s {s:.3} λ {lam:.7} definite {definite} → |r| {after:.3e}"
            );
        }
        let Some((qt, lt, et)) = accepted else {
            return fail(NewtonFailure::Inversion, its, indefinite_seen);
        };
        if lagged {
            // converged one correction after this factorisation: keep it (see the doc above)
            let rt = norm(&et.r);
            let tol_t = (opts.rtol * et.scale).max(opts.atol);
            let floor_t = (opts.stagnation_rtol * et.scale).max(opts.atol);
            let ct_ok = match (c_target, &et.control) {
                (Some(ct), Some((c, _))) => ctol.map_or(true, |t| (ct - c).abs() <= t),
                (Some(_), None) => false,
                _ => true,
            };
            if rt.is_finite() && (rt <= tol_t || (rt <= floor_t && rt > 0.5 * rn)) && ct_ok {
                if opts.log {
                    log.push(rt);
                }
                let ev = Eval { k: Some(k), ..et };
                return Ok(Solved { q: qt, lam: lt, ev, factor, stable: definite, iterations: its, residual_norms: log, lagged: true });
            }
        }
        let prev = std::mem::replace(&mut q, qt);
        lam = lt;
        if mixed {
            lin = Some(prev);
        }
        ev = match m.eval(&q, lam, true, lin.as_deref()) {
            Ok(e) => e,
            Err(e) => return fail(eval_fail(e), its, indefinite_seen),
        };
    }
    fail(NewtonFailure::IterationLimit, its, indefinite_seen)
}

/// Factor a converged tangent: (factor, positive definite).
fn definite_factor<M: PathModel>(m: &M, k: &M::Matrix) -> Option<(M::Factor, bool)> {
    match m.factor(k, true) {
        Ok(f) => Some((f, true)),
        Err(SolveError::NotPositiveDefinite) => m.factor(k, false).ok().map(|f| (f, false)),
        Err(_) => None,
    }
}

fn eval_fail(e: EvalFailure) -> NewtonFailure {
    match e {
        EvalFailure::Inversion => NewtonFailure::Inversion,
        EvalFailure::NonFinite => NewtonFailure::Divergence,
    }
}

fn cause_of(f: NewtonFailure) -> FailureCause {
    match f {
        NewtonFailure::NotPositiveDefinite => FailureCause::LimitPoint,
        NewtonFailure::Inversion => FailureCause::Inversion,
        NewtonFailure::Divergence => FailureCause::Divergence,
        NewtonFailure::IterationLimit => FailureCause::IterationLimit,
    }
}

/// Failed attempts in a row after which a path ends (its step control had shrunk the step to
/// the minimum long before: each failure divides it by 4).
const MAX_FAILURES_IN_ROW: usize = 60;

/// `TWISTOPT_TRACE=1` prints every step and Newton iteration to stderr.
pub fn trace_enabled() -> bool {
    static TRACE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *TRACE.get_or_init(|| std::env::var_os("TWISTOPT_TRACE").is_some())
}

/// Follow the path of `m` from the state `q0` at λ₀ = `lam0` towards `lam_end`, producing a point
/// at each of `stations` (λ values between λ₀ and λ_end) and ending at the first of: λ_end (or
/// `control_end`), a fold, a loss of stability, a [`Stop`] threshold, or a failure.
pub fn follow<M: PathModel>(m: &M, q0: &[f64], lam0: f64, lam_end: f64, stations: &[f64], stops: &[Stop], o: &ContinuationOptions) -> PathResult<M> {
    follow_impl(m, q0, lam0, None, lam_end, stations, stops, o)
}

/// [`follow`] from a start the caller has already solved with [`correct`] (a warm start
/// converged from a nearby design's state): the path takes it, with its tangent and factor, as
/// its first node instead of evaluating and factoring the same state again. The start's
/// Newton iterations are the caller's (not in the returned stats). Solve it with `lagged`
/// false (as the path's own nodes are handed on): its factor is then the state's own.
pub fn follow_from<M: PathModel>(m: &M, start: Solved<M>, lam_end: f64, stations: &[f64], stops: &[Stop], o: &ContinuationOptions) -> PathResult<M> {
    let (q0, lam0) = (start.q.clone(), start.lam);
    follow_impl(m, &q0, lam0, Some(start), lam_end, stations, stops, o)
}

#[allow(clippy::too_many_arguments)]
fn follow_impl<M: PathModel>(m: &M, q0: &[f64], lam0: f64, solved: Option<Solved<M>>, lam_end: f64, stations: &[f64], stops: &[Stop], o: &ContinuationOptions) -> PathResult<M> {
    let mut f = Follower { m, o, stats: PathStats::default(), trace: trace_enabled(), stops, points: Vec::new() };
    let (end, last, ctl) = f.run(q0, lam0, solved, lam_end, stations);
    // the state handed on (adjoint, limit sensitivity) gets the exact tangent and factor
    let last = last.and_then(|n| {
        if !n.lagged {
            return n.ev.k.map(|k| (k, n.factor));
        }
        f.stats.factorizations += 1;
        let ev = m.eval(&n.q, n.lam, true, None).ok()?;
        let k = ev.k?;
        let (factor, stable) = definite_factor(m, &k)?;
        if let Some(p) = f.points.last_mut() {
            p.stable = stable;
        }
        Some((k, factor))
    });
    PathResult { points: f.points, end, stats: f.stats, last, control: ctl }
}

/// The path follower's working state.
struct Follower<'a, M: PathModel> {
    m: &'a M,
    o: &'a ContinuationOptions,
    stats: PathStats,
    trace: bool,
    stops: &'a [Stop],
    points: Vec<PathPoint>,
}

/// What happened between two consecutive nodes.
enum Event<M: PathModel> {
    Stop(usize, Node<M>),
    Fold(Node<M>),
    Instability(Node<M>),
}

impl<'a, M: PathModel> Follower<'a, M> {
    fn newton(&mut self, q0: &[f64], lam: f64, c_target: Option<f64>, lin: Option<&[f64]>, locate: bool) -> Result<Node<M>, NewtonFailure> {
        // event location needs tightly converged states (near a fold the tangent is nearly
        // singular and amplifies the residual into the state and its stiffness)
        let tight;
        let nopts = if locate {
            tight = NewtonOptions { rtol: self.o.newton.rtol.min(1e-10), ..self.o.newton.clone() };
            &tight
        } else {
            &self.o.newton
        };
        // a prediction from the converged state `lin` that passes a node through a contact
        // surface (the extrapolation is blind to it) is pulled back to before the crossing
        let pulled;
        let q0 = match lin {
            Some(base) => {
                let dq: Vec<f64> = q0.iter().zip(base).map(|(a, b)| a - b).collect();
                let tau = self.m.step_limit(base, lam, &dq);
                if tau < 1.0 {
                    pulled = base.iter().zip(&dq).map(|(b, d)| b + tau * d).collect::<Vec<f64>>();
                    &pulled[..]
                } else {
                    q0
                }
            }
            None => q0,
        };
        let res = correct(self.m, q0, lam, c_target, nopts, self.o.mixed_tangent, lin, !locate);
        match res {
            Ok(s) => {
                self.stats.newton_iterations += s.iterations;
                if locate {
                    self.stats.locate_iterations += s.iterations;
                }
                self.node(s)
            }
            Err((e, its)) => {
                self.stats.newton_iterations += its;
                self.stats.failed_iterations += its;
                self.stats.failed_attempts += 1;
                if locate {
                    self.stats.locate_iterations += its;
                }
                if self.trace {
                    eprintln!("[path] solve at λ {lam:.7} c {c_target:?} failed: {e:?} after {its} its");
                }
                Err(e)
            }
        }
    }

    /// A converged node from a corrector solve (its tangent dq/dλ, stiffness and outputs).
    fn node(&mut self, s: Solved<M>) -> Result<Node<M>, NewtonFailure> {
        self.stats.factorizations += 1;
        let rl = self.m.load_rate(&s.q, s.lam, &s.ev).map_err(eval_fail)?;
        let t: Vec<f64> = self.m.solve(&s.factor, &rl).map_err(|_| NewtonFailure::Divergence)?.into_iter().map(|v| -v).collect();
        let (c, dc) = match &s.ev.control {
            Some((c, g)) => (Some(*c), Some(dot(g, &t))),
            None => (None, None),
        };
        let out = self.m.outputs(&s.q, s.lam, &s.ev);
        let y = self.m.predictor_coords(&s.q);
        let ty = self.m.predictor_rate(&s.q, &t);
        Ok(Node { lam: s.lam, q: s.q, ev: s.ev, factor: s.factor, stable: s.stable, y, ty, c, dc, out, lagged: s.lagged })
    }

    fn push(&mut self, n: &Node<M>, kind: PointKind, its: usize) {
        self.points.push(PathPoint { lam: n.lam, q: n.q.clone(), control: n.c, outputs: n.out.clone(), min_det: n.ev.min_det, stable: n.stable, kind, newton_iterations: its });
    }

    /// Solve for the point at parameter value `s` (λ or c per `ctl`) between nodes a and b,
    /// predicted by their Hermite cubic.
    fn solve_between(&mut self, a: &Node<M>, b: &Node<M>, ctl: Control, s: f64) -> Result<Node<M>, NewtonFailure> {
        let (qp, lp) = hermite(self.m, a, b, ctl, s);
        match ctl {
            Control::Load => self.newton(&qp, s, None, Some(&a.q), true),
            Control::Functional => self.newton(&qp, lp, Some(s), Some(&a.q), true),
        }
    }

    fn run(&mut self, q0: &[f64], lam0: f64, solved: Option<Solved<M>>, lam_end: f64, stations: &[f64]) -> (PathEnd, Option<Node<M>>, Control) {
        let o = self.o;
        let span = lam_end - lam0;
        let ctl = o.start_control;
        if !(lam0.is_finite() && lam_end.is_finite()) || o.control_end.is_some_and(|c| !c.is_finite()) {
            return (PathEnd::Failed(FailureCause::Divergence), None, ctl);
        }
        // the start: solved by the caller, or accepted as it is when its Newton correction is
        // round-off against the path's response K⁻¹ r_λ (λ_end − λ₀) (e.g. the unloaded
        // state), else solved
        let accepted = if solved.is_some() {
            solved
        } else {
            self.accept_start(q0, lam0, span)
        };
        let start = match accepted {
            Some(s) => self.node(s),
            None => self.newton(q0, lam0, None, None, false),
        };
        let cur = match start {
            Ok(n) => n,
            Err(e) => return (PathEnd::Failed(cause_of(e)), None, ctl),
        };
        self.run_from(cur, lam0, lam_end, stations, ctl)
    }

    /// `q0` as the path's start if its Newton correction is round-off (see [`Follower::run`]).
    fn accept_start(&mut self, q0: &[f64], lam0: f64, span: f64) -> Option<Solved<M>> {
        self.m.eval(q0, lam0, true, None).ok().and_then(|ev| {
            if span == 0.0 {
                return None;
            }
            let rl = self.m.load_rate(q0, lam0, &ev).ok()?;
            let (factor, stable) = definite_factor(self.m, ev.k.as_ref()?)?;
            let d = self.m.solve(&factor, &ev.r).ok()?;
            let t = self.m.solve(&factor, &rl).ok()?;
            if !(norm(&d) <= 1e-9 * norm(&t) * span.abs()) {
                return None;
            }
            self.stats.factorizations += 1;
            Some(Solved { q: q0.to_vec(), lam: lam0, ev, factor, stable, iterations: 0, residual_norms: Vec::new(), lagged: false })
        })
    }

    /// The path on from its start node `cur`.
    fn run_from(&mut self, mut cur: Node<M>, lam0: f64, lam_end: f64, stations: &[f64], mut ctl: Control) -> (PathEnd, Option<Node<M>>, Control) {
        let o = self.o;
        let span = lam_end - lam0;
        let dir = if span >= 0.0 { 1.0 } else { -1.0 };
        let its0 = self.stats.newton_iterations;
        self.push(&cur, PointKind::Start, its0);
        if span == 0.0 {
            return (PathEnd::Completed, Some(cur), ctl);
        }
        if cur.dc.is_none() {
            ctl = Control::Load;
        }
        if ctl == Control::Functional && o.start_control == Control::Functional {
            // a functional-controlled start keeps λ's direction as the direction of c
        }
        let k0 = cur.stiffness();
        // the sign of dc/dλ on the initial branch, and the direction c moves along the path
        let cdir = cur.dc.map(|d| d.signum()).unwrap_or(1.0);
        let mut prev: Option<Node<M>> = None;
        let mut st: Vec<(usize, f64)> = stations.iter().copied().enumerate().filter(|(_, s)| (s - lam0) * dir > 0.0 && (lam_end - s) * dir >= 0.0).collect();
        st.sort_by(|a, b| ((a.1 - lam0) * dir).total_cmp(&((b.1 - lam0) * dir)));
        let mut next_station = 0usize;
        // step length: λ units under load control, c units under functional control
        let mut h = o.initial * span.abs();
        if ctl == Control::Functional {
            h = match (o.initial_functional, cur.c) {
                (Some(f), Some(c)) if f > 0.0 && f.is_finite() => f * c.abs(),
                _ => h * cur.dc.map(|d| d.abs()).unwrap_or(1.0),
            };
        }
        let mut pending_its = 0usize;
        // failed attempts since the last converged step (a bound: failures do not count as steps)
        let mut failures_in_row = 0usize;
        loop {
            if self.stats.steps >= o.max_steps {
                return (PathEnd::Failed(FailureCause::StepLimit), Some(cur), ctl);
            }
            let (hmin, hmax) = match ctl {
                Control::Load => (o.min * span.abs(), o.max * span.abs()),
                Control::Functional => {
                    let c = cur.c.unwrap_or(1.0).abs().max(1e-300);
                    (1e-9 * c, 0.5 * c)
                }
            };
            // control switch before a fold
            if ctl == Control::Load && o.switch_stiffness.is_some() && cur.dc.is_some() {
                let ratio = match (cur.stiffness(), k0) {
                    (Some(k), Some(k0)) if k0 != 0.0 => k / k0,
                    _ => 1.0,
                };
                let mut switch = ratio < o.switch_stiffness.unwrap_or(0.0);
                // a fold predicted from the stiffness trend (linear in c): switch when the next
                // step would go more than half-way to it
                if let (Some(p), Some(kc), Some(cc)) = (&prev, cur.stiffness(), cur.c) {
                    if let (Some(kp), Some(cp)) = (p.stiffness(), p.c) {
                        let slope = (kc - kp) / (cc - cp);
                        if slope.is_finite() && slope * kc * cdir < 0.0 {
                            let c_fold = cc - kc / slope;
                            let lam_fold = cur.lam + 0.5 * kc * (c_fold - cc);
                            if (lam_fold - cur.lam) * dir > 0.0 && h > 0.5 * (lam_fold - cur.lam).abs() {
                                switch = true;
                            }
                        }
                    }
                }
                if switch {
                    ctl = Control::Functional;
                    // the step in c units, shortened for the smaller error target (e ∝ h³:
                    // (0.3)^(1/3) ≈ 0.67) and Newton's smaller convergence radius under
                    // functional control: the first functional step at the full converted
                    // length failed on 2 of 2 scenes of a sweep design, at half of it none did
                    h *= 0.5 * cur.dc.map(|d| d.abs()).unwrap_or(1.0);
                    if self.trace {
                        eprintln!("[path] functional control from λ {:.7} (stiffness ratio {ratio:.3})", cur.lam);
                    }
                    continue;
                }
            }
            let sdir = match (ctl, o.control_end, cur.c) {
                (Control::Load, _, _) => dir,
                (Control::Functional, Some(ce), Some(c)) => (ce - c).signum(),
                (Control::Functional, _, _) => cdir * dir,
            };
            h = h.clamp(hmin, hmax);
            // under functional control: no further than fold_overshoot × the distance to the
            // fold predicted by the stiffness trend (linear in c)
            if ctl == Control::Functional {
                if let (Some(p), Some(kc), Some(cc)) = (&prev, cur.stiffness(), cur.c) {
                    if let (Some(kp), Some(cp)) = (p.stiffness(), p.c) {
                        let slope = (kc - kp) / (cc - cp);
                        let to_fold = -kc / slope;
                        if slope.is_finite() && to_fold.is_finite() && to_fold * sdir > 0.0 {
                            h = h.min(o.fold_overshoot * to_fold.abs()).max(hmin);
                        }
                    }
                }
            }
            let p_cur = cur.param(ctl);
            let mut target = p_cur + sdir * h;
            let mut landing: Option<PointKind> = None;
            match ctl {
                Control::Load => {
                    let next_lam = st.get(next_station).map(|s| s.1).unwrap_or(lam_end);
                    if (target - next_lam) * dir >= -1e-12 * span.abs() {
                        target = next_lam;
                        landing = Some(st.get(next_station).map_or(PointKind::End, |s| PointKind::Station(s.0)));
                    }
                }
                Control::Functional => {
                    if let Some(ce) = o.control_end {
                        if (target - ce) * sdir >= 0.0 {
                            target = ce;
                            landing = Some(PointKind::End);
                        }
                    }
                }
            }
            let hs = (target - p_cur).abs();
            // prediction: the tangent line, then the quadratic through the previous point
            let (q_start, l_start) = match prev.as_ref().filter(|_| o.cubic) {
                // an unstable state under load control (a path deliberately followed past its
                // stability limit): its tangent may be nearly singular, so no extrapolation
                _ if ctl == Control::Load && !cur.stable => (cur.q.clone(), target),
                Some(p) if (p.stable || ctl == Control::Functional) && (p.param(ctl) - cur.param(ctl)).abs() > 0.0 && p.param(ctl).is_finite() => hermite(self.m, p, &cur, ctl, target),
                _ => extrapolate(self.m, &cur, prev.as_ref(), ctl, target),
            };
            let dqn = norm(&q_start.iter().zip(&cur.q).map(|(a, b)| a - b).collect::<Vec<f64>>()).max(1e-300);
            let its_before = self.stats.newton_iterations;
            let res = match ctl {
                Control::Load => self.newton(&q_start, target, None, Some(&cur.q), false),
                Control::Functional => self.newton(&q_start, l_start, Some(target), Some(&cur.q), false),
            };
            let its = self.stats.newton_iterations - its_before;
            let new = match res {
                Err(fail) => {
                    pending_its += its;
                    if self.trace {
                        eprintln!("[path] step to {target:.7} failed ({fail:?}, {its} its)");
                    }
                    failures_in_row += 1;
                    // at the minimum step (to round-off: under functional control hmin is 1e-9 of
                    // |c|, and c + h − c loses ≈ 1e-7 of h), or after many failures in a row
                    if hs <= hmin * (1.0 + 1e-6) || failures_in_row > MAX_FAILURES_IN_ROW {
                        // under load control next to a fold: pass it under functional control
                        if ctl == Control::Load && cur.dc.is_some() && o.switch_stiffness.is_some() {
                            ctl = Control::Functional;
                            h = hs * cur.dc.map(|d| d.abs()).unwrap_or(1.0);
                            failures_in_row = 0;
                            continue;
                        }
                        return (PathEnd::Failed(cause_of(fail)), Some(cur), ctl);
                    }
                    h = (hs * 0.25).max(hmin);
                    continue;
                }
                Ok(n) => n,
            };
            self.stats.steps += 1;
            failures_in_row = 0;
            let its_point = its + std::mem::take(&mut pending_its);
            // the prediction error relative to the step
            let e = norm(&new.q.iter().zip(&q_start).map(|(a, b)| a - b).collect::<Vec<f64>>()) / dqn;
            if self.trace {
                eprintln!("[path] {ctl:?} step to {target:.7}: λ {:.7} c {:?}, {its} its, prediction error {e:.3e}, stable {}, dλ/dc {:?}", new.lam, new.c, new.stable, new.stiffness());
            }
            // events between cur and new, in path order
            match self.event(&cur, new, ctl, cdir, dir) {
                Ok(new) => {
                    // stations passed under functional control
                    if ctl == Control::Functional {
                        self.emit_stations(&cur, &new, &st, &mut next_station, dir);
                        if (new.lam - lam_end) * dir >= 0.0 {
                            let n = self.land_on_end(&cur, new, lam_end, dir);
                            self.push(&n, PointKind::End, its_point);
                            return (PathEnd::Completed, Some(n), ctl);
                        }
                    }
                    let kind = landing.clone().unwrap_or(PointKind::Step);
                    self.push(&new, kind.clone(), its_point);
                    if let PointKind::Station(_) = kind {
                        next_station += 1;
                    }
                    if kind == PointKind::End {
                        return (PathEnd::Completed, Some(new), ctl);
                    }
                    // next step length from the prediction error (extrapolation: e ∝ h²; the
                    // first, tangent-line step: e ∝ h) and the iteration count
                    let order = match (prev.is_some(), o.cubic) {
                        (false, _) => 1.0,
                        (true, false) => 2.0,
                        (true, true) => 3.0,
                    };
                    // (no prediction, e.g. from an unstable state: the iteration count decides)
                    let predicted = dqn > 1e-200;
                    let target_error = if ctl == Control::Functional { o.target_error_functional } else { o.target_error };
                    let mut fct = if predicted {
                        (target_error / e.max(1e-12)).powf(1.0 / order).clamp(0.5, o.max_growth)
                    } else if its <= o.target_iterations {
                        1.5
                    } else {
                        1.0
                    };
                    if its > o.target_iterations {
                        fct = fct.min(0.7);
                    }
                    let hbase = if landing.is_some() { h.max(hs) } else { hs };
                    h = hbase * fct;
                    prev = Some(std::mem::replace(&mut cur, new));
                }
                Err(ev) => {
                    let (end, n) = match ev {
                        Event::Stop(i, n) => (PathEnd::Stopped(i), n),
                        Event::Fold(n) => (PathEnd::Fold, n),
                        Event::Instability(n) => (PathEnd::Instability, n),
                    };
                    // an event (a fold, a stability limit, a threshold) located beyond λ_end (a
                    // step under functional control passed both): the path reached λ_end first
                    // and ends there, located on c (λ_end is also reached beyond a fold, on the
                    // branch past it, where a solve in λ may land)
                    let (end, n) = match (n.lam - lam_end) * dir > 0.0 && (cur.lam - lam_end) * dir < 0.0 {
                        true => match self.end_on_c(&cur, &n, lam_end, dir) {
                            Some(e) => (PathEnd::Completed, e),
                            None => (end, n),
                        },
                        false => (end, n),
                    };
                    self.emit_stations(&cur, &n, &st, &mut next_station, dir);
                    self.push(&n, PointKind::End, its_point);
                    return (end, Some(n), ctl);
                }
            }
        }
    }

    /// The point at λ_end between node a (before it) and node b (at or beyond it): solved under
    /// load control from their Hermite cubic, else (near a fold λ is a poor parameter) located
    /// on c; b itself when neither converges.
    fn land_on_end(&mut self, a: &Node<M>, b: Node<M>, lam_end: f64, dir: f64) -> Node<M> {
        match self.solve_between(a, &b, Control::Load, lam_end) {
            Ok(n) => n,
            Err(_) => self.end_on_c(a, &b, lam_end, dir).unwrap_or(b),
        }
    }

    /// The point at λ_end between node a (before it) and node b (beyond it), located on c to
    /// `locate_tol`, then solved at λ_end itself from there (None where the location does not
    /// converge).
    fn end_on_c(&mut self, a: &Node<M>, b: &Node<M>, lam_end: f64, dir: f64) -> Option<Node<M>> {
        let ftol = self.o.locate_tol * lam_end.abs().max(1e-300);
        let e = self.locate_crossing(a, b, Control::Functional, |x: &Node<M>| dir * (x.lam - lam_end), ftol, 0.0).filter(|e| (e.lam - lam_end).abs() <= ftol)?;
        if e.lam == lam_end {
            return Some(e);
        }
        Some(self.newton(&e.q, lam_end, None, Some(&e.q), true).unwrap_or(e))
    }

    /// Check the segment cur → new for events; Ok(new) when none, else the located end node.
    fn event(&mut self, cur: &Node<M>, new: Node<M>, ctl: Control, cdir: f64, dir: f64) -> Result<Node<M>, Event<M>> {
        let o = self.o;
        let folded = o.stop_at_fold
            && (matches!((cur.stiffness(), new.stiffness()), (Some(a), Some(b)) if a * cdir > 0.0 && b * cdir <= 0.0) || (ctl == Control::Functional && (new.lam - cur.lam) * dir < 0.0));
        let unstable = !folded && o.stop_at_instability && cur.stable && !new.stable;
        // the far end of the segment that matters: the fold or the stability limit, else new
        let far = if folded {
            self.locate_fold(cur, new)
        } else if unstable {
            match self.locate_instability(cur, &new, ctl) {
                Some(n) => n,
                None => return Err(Event::Instability(new)),
            }
        } else {
            new
        };
        // thresholds crossed before `far`
        for (i, s) in self.stops.iter().enumerate() {
            if s.crossed(cur.out[s.output], far.out[s.output]) {
                let n = self.locate_stop(cur, &far, ctl, s).unwrap_or(far);
                return Err(Event::Stop(i, n));
            }
        }
        if folded {
            Err(Event::Fold(far))
        } else if unstable {
            Err(Event::Instability(far))
        } else {
            Ok(far)
        }
    }

    /// Points at the stations whose λ lies between nodes a (exclusive) and b (inclusive), solved
    /// under load control from the Hermite cubic between them.
    fn emit_stations(&mut self, a: &Node<M>, b: &Node<M>, st: &[(usize, f64)], next: &mut usize, dir: f64) {
        while let Some(&(idx, ls)) = st.get(*next) {
            if !((ls - a.lam) * dir > 0.0 && (b.lam - ls) * dir >= 0.0) {
                break;
            }
            if let Ok(n) = self.solve_between(a, b, Control::Load, ls) {
                self.push(&n, PointKind::Station(idx), 0);
            }
            *next += 1;
        }
    }

    /// Locate a threshold crossing between a (before) and b (beyond) by Illinois regula falsi on
    /// the path parameter; the located point is on a's side, within `locate_tol` in λ.
    fn locate_stop(&mut self, a: &Node<M>, b: &Node<M>, ctl: Control, s: &Stop) -> Option<Node<M>> {
        let sg = if s.rising { 1.0 } else { -1.0 };
        let ftol = 1e-10 * s.threshold.abs().max(1e-300);
        let tol = self.o.locate_tol * a.lam.abs().max(b.lam.abs()).max(1e-300);
        self.locate_crossing(a, b, ctl, |n: &Node<M>| sg * (n.out[s.output] - s.threshold), ftol, tol)
    }

    /// Locate where f (negative at a, non-negative at b) crosses zero between nodes a and b by
    /// Illinois regula falsi on the path parameter: the last state on a's side once the bracket
    /// is within `tol` in λ (and, under functional control, `locate_control_tol` in c), or a
    /// state where |f| ≤ ftol.
    fn locate_crossing(&mut self, a: &Node<M>, b: &Node<M>, ctl: Control, f: impl Fn(&Node<M>) -> f64, ftol: f64, tol: f64) -> Option<Node<M>> {
        let (pa, pb) = (a.param(ctl), b.param(ctl));
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let (mut flo, mut fhi) = (f(a), f(b));
        let mut lam_lo = a.lam;
        let mut lam_hi = b.lam;
        let mut best: Option<Node<M>> = None;
        let mut side = 0i32;
        for _ in 0..40 {
            // (under functional control the bracket must also be narrow in c: where λ(c) is
            // flat, as near a pressure maximum, a bracket within tol in λ can be wide in the
            // state; measured: a ballooning stop located at once, 0.06 mm past the limit)
            let narrow_c = ctl == Control::Load || ((hi - lo) * (pb - pa)).abs() <= self.o.locate_control_tol * pa.abs();
            if (lam_hi - lam_lo).abs() <= tol && narrow_c {
                break;
            }
            let mut x = lo - flo * (hi - lo) / (fhi - flo);
            if !(x > lo && x < hi) {
                x = 0.5 * (lo + hi);
            }
            let n = self.solve_between(a, b, ctl, pa + x * (pb - pa)).ok()?;
            let fx = f(&n);
            if fx < 0.0 {
                lo = x;
                flo = fx;
                lam_lo = n.lam;
                if side == -1 {
                    fhi *= 0.5;
                }
                side = -1;
                let done = fx.abs() <= ftol;
                best = Some(n);
                if done {
                    break;
                }
            } else {
                hi = x;
                fhi = fx;
                lam_hi = n.lam;
                if side == 1 {
                    flo *= 0.5;
                }
                side = 1;
                if fx.abs() <= ftol {
                    best = Some(n);
                    break;
                }
            }
        }
        best
    }

    /// Locate the fold (dλ/dc = 0) between a (before it) and b (beyond) under functional control
    /// by secant steps on the stiffness k = dλ/dc (safeguarded by the bracket), to `locate_tol`
    /// relative in λ: the error estimate of a state at c is ½|k (c* − c)| with c* the next secant
    /// iterate. Returns the located state (b itself when it is within tolerance).
    fn locate_fold(&mut self, a: &Node<M>, b: Node<M>) -> Node<M> {
        let (Some(_), Some(_)) = (a.c, b.c) else {
            return b;
        };
        // bracket (c, k) and the last two iterates
        let (mut lo, mut hi) = ((a.c.unwrap_or(0.0), a.stiffness().unwrap_or(0.0)), (b.c.unwrap_or(0.0), b.stiffness().unwrap_or(0.0)));
        let mut x0 = lo;
        let mut lam0 = a.lam;
        let mut last = b;
        let mut near: Option<Node<M>> = None; // the latest rising-side state (for the prediction)
        for _ in 0..30 {
            let x1 = (last.c.unwrap_or(0.0), last.stiffness().unwrap_or(0.0));
            // the root of dλ/dc of the cubic through both iterates' λ and dλ/dc (the secant
            // on dλ/dc uses half of that: measured, its first estimate from the two states
            // bracketing the fold was 1-2 × 1e-4 of c off, just outside the tolerance, and cost
            // a second iteration), else the secant
            let mut cs = hermite_stationary(x0.0, lam0, x0.1, x1.0, last.lam, x1.1).unwrap_or_else(|| x1.0 - x1.1 * (x1.0 - x0.0) / (x1.1 - x0.1));
            let (bl, bh) = (lo.0.min(hi.0), lo.0.max(hi.0));
            if !(cs > bl && cs < bh) {
                cs = 0.5 * (lo.0 + hi.0);
            }
            let err = 0.5 * (x1.1 * (cs - x1.0)).abs();
            if self.trace {
                eprintln!("[fold] λ {:.10} c {:.6} k {:.4e} stable {}; bracket c ∈ [{:.6}, {:.6}]; next c* {cs:.6}, λ error estimate {err:.3e}", last.lam, x1.0, x1.1, last.stable, lo.0, hi.0);
            }
            // λ to `locate_tol`, and the state itself (c) to `locate_control_tol`, so that the outputs at
            // the fold (θ, τ, which vary along the fold at first order) are pinned too — unless
            // the stiffness is already at its noise level there (the tangent is singular at the
            // fold, so k = 1/(∇c·K⁻¹r_λ) carries no more digits)
            let k_ref = a.stiffness().unwrap_or(0.0).abs();
            let ctol = self.o.locate_control_tol * x1.0.abs();
            let c_ok = (cs - x1.0).abs() <= ctol || (hi.0 - lo.0).abs() <= ctol || x1.1.abs() <= 1e-3 * k_ref;
            if err <= self.o.locate_tol * last.lam.abs().max(1e-300) && c_ok {
                break;
            }
            let from = near.as_ref().unwrap_or(a);
            let (qp, lp) = hermite(self.m, from, &last, Control::Functional, cs);
            let lin = from.q.clone();
            let n = match self.newton(&qp, lp, Some(cs), Some(&lin), true) {
                Ok(n) => n,
                Err(_) => break,
            };
            let kn = n.stiffness().unwrap_or(0.0);
            if kn * lo.1 > 0.0 {
                lo = (cs, kn);
            } else {
                hi = (cs, kn);
            }
            x0 = x1;
            lam0 = last.lam;
            let prev = std::mem::replace(&mut last, n);
            if prev.stiffness().unwrap_or(0.0) * a.stiffness().unwrap_or(0.0) > 0.0 {
                near = Some(prev);
            }
        }
        last
    }

    /// Locate the loss of stability between a (stable) and b (unstable) by bisection on the path
    /// parameter, to `locate_tol` relative in λ; the last stable state, or None when a is it.
    fn locate_instability(&mut self, a: &Node<M>, b: &Node<M>, ctl: Control) -> Option<Node<M>> {
        let mut lo: Option<Node<M>> = None;
        let mut hi: Option<Node<M>> = None;
        for _ in 0..40 {
            let (l, h) = (lo.as_ref().unwrap_or(a), hi.as_ref().unwrap_or(b));
            if (h.lam - l.lam).abs() <= self.o.locate_tol * l.lam.abs().max(1e-300) {
                break;
            }
            let mid = 0.5 * (l.param(ctl) + h.param(ctl));
            let n = match self.solve_between(l, h, ctl, mid) {
                Ok(n) => n,
                Err(_) => break,
            };
            if n.stable {
                lo = Some(n);
            } else {
                hi = Some(n);
            }
        }
        lo
    }
}

/// The Hermite cubic through nodes a and b (values and tangents in the parameter), at s.
fn hermite<M: PathModel>(m: &M, a: &Node<M>, b: &Node<M>, ctl: Control, s: f64) -> (Vec<f64>, f64) {
    let pa = a.param(ctl);
    let pb = b.param(ctl);
    let hh = pb - pa;
    if hh == 0.0 || !hh.is_finite() {
        return extrapolate(m, a, None, ctl, s);
    }
    let (ta, la) = a.rates(ctl);
    let (tb, lb) = b.rates(ctl);
    let x = (s - pa) / hh;
    let (h00, h10, h01, h11) = (2.0 * x * x * x - 3.0 * x * x + 1.0, x * x * x - 2.0 * x * x + x, -2.0 * x * x * x + 3.0 * x * x, x * x * x - x * x);
    let y: Vec<f64> = (0..a.y.len()).map(|i| h00 * a.y[i] + h10 * hh * ta[i] + h01 * b.y[i] + h11 * hh * tb[i]).collect();
    let lam = match ctl {
        Control::Load => s,
        Control::Functional => h00 * a.lam + h10 * hh * la + h01 * b.lam + h11 * hh * lb,
    };
    (m.from_predictor_coords(&y), lam)
}

/// Extrapolation from the current node (value and tangent) and the previous one (value): the
/// quadratic q(s) = q_c + t_c d + κ d² through q_p; the tangent line without a previous node.
fn extrapolate<M: PathModel>(m: &M, cur: &Node<M>, prev: Option<&Node<M>>, ctl: Control, s: f64) -> (Vec<f64>, f64) {
    let pc = cur.param(ctl);
    let (tc, lc) = cur.rates(ctl);
    let d = s - pc;
    let quad = prev.map(|p| (p, p.param(ctl) - pc)).filter(|(_, dm)| *dm != 0.0 && dm.is_finite());
    match quad {
        Some((p, dm)) => {
            let y: Vec<f64> = (0..cur.y.len())
                .map(|i| {
                    let k = (p.y[i] - cur.y[i] - tc[i] * dm) / (dm * dm);
                    cur.y[i] + tc[i] * d + k * d * d
                })
                .collect();
            let q = m.from_predictor_coords(&y);
            let lam = match ctl {
                Control::Load => s,
                Control::Functional => {
                    let k = (p.lam - cur.lam - lc * dm) / (dm * dm);
                    cur.lam + lc * d + k * d * d
                }
            };
            (q, lam)
        }
        None => {
            let y: Vec<f64> = cur.y.iter().zip(&tc).map(|(x, t)| x + d * t).collect();
            let lam = match ctl {
                Control::Load => s,
                Control::Functional => cur.lam + d * lc,
            };
            (m.from_predictor_coords(&y), lam)
        }
    }
}

// ------------------------------------------------------------------------------------------
// Snap-through under load control

/// Options of [`relax`] and [`follow_snapping`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SnapOptions {
    /// Most snaps along one path.
    pub max_snaps: usize,
    /// The load past a lost stability at which the state is relaxed, as a fraction of
    /// |λ_end − λ₀| beyond the last stable point.
    pub overshoot: f64,
    /// The critical mode's amplitude added to the last stable state before relaxing (a fraction
    /// of the state's largest |q|): it leaves a branch that has become a saddle.
    pub kick: f64,
    /// Most iterations of one relaxation.
    pub max_iter: usize,
    /// A relaxation has converged when ‖r‖ ≤ rtol · scale and the tangent is positive definite.
    pub rtol: f64,
}

impl Default for SnapOptions {
    fn default() -> Self {
        SnapOptions { max_snaps: 200, overshoot: 1e-3, kick: 1e-3, max_iter: 1000, rtol: 1e-10 }
    }
}

/// A stable equilibrium at fixed λ reached from q0 by descending the potential (for the
/// conservative models of this crate, r = ∂Π/∂q): shifted Newton steps (K + σD) Δq = −r, D the
/// absolute diagonal of the first tangent, σ grown ×10 until the shifted matrix is positive
/// definite. Each step is cut (×¼, up to 4 times) until Π decreases enough (Armijo; where the
/// model gives no Π, until the trapezoidal estimate from the slopes Δq·r at both ends is a
/// decrease) and the state can be evaluated (no inversion, no penetration); if none does, σ
/// grows ×4. A full step divides σ by 4 (to 0: Newton's method near a minimum). It converges only to states whose own tangent is
/// positive definite, so a saddle (a branch beyond a bifurcation) is left along its unstable
/// modes. This is how a state snaps to the remote stable branch past a fold or a lost stability
/// under load control (a pressure supply does the same).
pub fn relax<M: PathModel>(m: &M, q0: &[f64], lam: f64, o: &SnapOptions) -> Result<Solved<M>, (NewtonFailure, usize)> {
    let trace = trace_enabled();
    let mut q = q0.to_vec();
    let mut ev = m.eval(&q, lam, true, None).map_err(|e| (eval_fail(e), 0))?;
    let d: Vec<f64> = {
        let dg = ev.k.as_ref().and_then(|k| m.diagonal(k)).ok_or((NewtonFailure::Divergence, 0))?;
        let mx = dg.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if !(mx > 0.0 && mx.is_finite()) {
            return Err((NewtonFailure::Divergence, 0));
        }
        dg.iter().map(|v| v.abs().max(1e-8 * mx)).collect()
    };
    let mut sigma = 0.0f64;
    let mut its = 0usize;
    let mut last_rn = f64::INFINITY;
    loop {
        let rn = norm(&ev.r);
        if !rn.is_finite() {
            return Err((NewtonFailure::Divergence, its));
        }
        let k = ev.k.take().expect("the tangent was requested");
        // converged: a small residual (or one at its round-off floor) with a definite tangent
        let floor = 1e-3 * o.rtol.sqrt() * ev.scale;
        if rn <= o.rtol * ev.scale || (rn <= floor && rn > 0.5 * last_rn) {
            if let Ok(f) = m.factor(&k, true) {
                ev.k = Some(k);
                return Ok(Solved { q, lam, ev, factor: f, stable: true, iterations: its, residual_norms: Vec::new(), lagged: false });
            }
        }
        if its >= o.max_iter {
            return Err((NewtonFailure::IterationLimit, its));
        }
        last_rn = rn;
        its += 1;
        // the shifted matrix: the smallest shift tried that is positive definite
        let factor = loop {
            let ks;
            let km = if sigma > 0.0 {
                let sd: Vec<f64> = d.iter().map(|v| sigma * v).collect();
                ks = m.shifted(&k, &sd).ok_or((NewtonFailure::Divergence, its))?;
                &ks
            } else {
                &k
            };
            match m.factor(km, true) {
                Ok(f) => break f,
                Err(SolveError::NotPositiveDefinite) if sigma < 1e8 => sigma = if sigma == 0.0 { 1e-6 } else { sigma * 10.0 },
                Err(_) => return Err((NewtonFailure::Divergence, its)),
            }
        };
        let dq: Vec<f64> = m.solve(&factor, &ev.r).map_err(|_| (NewtonFailure::Divergence, its))?.into_iter().map(|v| -v).collect();
        let g0 = dot(&dq, &ev.r);
        // backtracking on the potential (Armijo), or on its trapezoidal estimate from the slopes,
        // from the longest step the model admits (no passage through a contact surface)
        let mut step = m.step_limit(&q, lam, &dq).clamp(1e-9, 1.0);
        let mut accepted = None;
        for _ in 0..5 {
            let qt: Vec<f64> = q.iter().zip(&dq).map(|(a, b)| a + step * b).collect();
            if let Ok(et) = m.eval(&qt, lam, false, None) {
                let g1 = dot(&dq, &et.r);
                let decrease = match (ev.potential, et.potential) {
                    (Some(p0), Some(p1)) => p1 - p0 <= 1e-4 * step * g0 + 1e-14 * p0.abs(),
                    _ => 0.5 * step * (g0 + g1) < 0.0,
                };
                if g1.is_finite() && decrease {
                    accepted = Some(qt);
                    break;
                }
            }
            step *= 0.25;
        }
        if trace {
            eprintln!(
                "[relax] it {its} |r| {rn:.3e} scale {:.3e} σ {sigma:.1e} g0 {g0:.3e} |Δq|∞ {:.3e} step {}",
                ev.scale,
                dq.iter().fold(0.0f64, |a, v| a.max(v.abs())),
                if accepted.is_some() { step } else { 0.0 }
            );
        }
        if let Some(qt) = accepted {
            q = qt;
            ev = m.eval(&q, lam, true, None).map_err(|e| (eval_fail(e), its))?;
            // (a full step: towards Newton's method; a cut one: keep the shift)
            if step >= 1.0 {
                sigma = if sigma < 1e-6 { 0.0 } else { sigma / 4.0 };
            }
        } else {
            ev.k = Some(k);
            sigma = (sigma * 4.0).max(1e-6);
            if sigma > 1e8 {
                return Err((NewtonFailure::Divergence, its));
            }
        }
    }
}

/// The tangent's eigenvector of smallest eigenvalue magnitude at (q, λ) (inverse iteration, 12
/// solves), normalised to a largest entry of 1.
pub fn critical_mode<M: PathModel>(m: &M, q: &[f64], lam: f64) -> Option<Vec<f64>> {
    let ev = m.eval(q, lam, true, None).ok()?;
    let k = ev.k.as_ref()?;
    let f = match m.factor(k, true) {
        Ok(f) => f,
        Err(_) => m.factor(k, false).ok()?,
    };
    // (a deterministic start with every component present)
    let mut x: Vec<f64> = (0..q.len()).map(|i| ((i * 7919 % 101) as f64 / 101.0) - 0.5).collect();
    for _ in 0..12 {
        x = m.solve(&f, &x).ok()?;
        let n = x.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        x.iter_mut().for_each(|v| *v /= n);
    }
    Some(x)
}

/// A jump of a path followed by [`follow_snapping`].
#[derive(Clone, Debug, PartialEq)]
pub struct Snap {
    /// the load of the jump
    pub lam: f64,
    /// index (in the path's points) of the state it landed on; the point before is the last
    /// stable state it left
    pub point: usize,
    /// relaxation iterations (each a tangent factorisation)
    pub iterations: usize,
    /// the largest |Δq| of the jump
    pub jump: f64,
}

/// [`follow`] under load control that snaps through where the path would end at a fold of λ
/// or a lost stability (or fails with indefinite tangents): from the last stable point, kicked
/// along its critical mode, the state is relaxed ([`relax`]) at a load `overshoot` beyond it
/// and the path goes on from there; at most `max_snaps` times. Where the relaxation does not
/// reach a stable state (measured: a collapsing cavity wall whose descent stalls against the
/// contact barrier), the jump is followed quasi-statically instead, under control of the model's
/// functional (the cavity volume) through the unstable states until λ is back at the snap's
/// load, and relaxed there. The states of a snap's path are
/// stable equilibria; the jump itself is not a quasi-static path (a pressure-controlled structure
/// jumps dynamically). Stations crossed during a jump are not produced.
pub fn follow_snapping<M: PathModel>(m: &M, q0: &[f64], lam0: f64, lam_end: f64, stations: &[f64], stops: &[Stop], o: &ContinuationOptions, s: &SnapOptions) -> (PathResult<M>, Vec<Snap>) {
    let seg = ContinuationOptions { stop_at_fold: true, stop_at_instability: true, start_control: Control::Load, ..o.clone() };
    let mut points: Vec<PathPoint> = Vec::new();
    let mut stats = PathStats::default();
    let mut snaps: Vec<Snap> = Vec::new();
    let (mut q, mut lam) = (q0.to_vec(), lam0);
    let span = (lam_end - lam0).abs();
    let dir = if lam_end >= lam0 { 1.0 } else { -1.0 };
    loop {
        let res = follow(m, &q, lam, lam_end, stations, stops, &seg);
        stats.add(&res.stats);
        // (a later segment's start is the snap's point, already recorded)
        let skip = usize::from(!points.is_empty());
        points.extend(res.points.into_iter().skip(skip));
        let snappable = matches!(res.end, PathEnd::Instability | PathEnd::Fold | PathEnd::Failed(_));
        if snappable {
            // (states past the last stable one lie on the branch being left)
            while points.len() > 1 && points.last().is_some_and(|p| !p.stable) {
                points.pop();
            }
        }
        let Some(last) = points.last().cloned().filter(|_| snappable && snaps.len() < s.max_snaps) else {
            // (a path that would snap once more than allowed ends at the step limit, not at its fold)
            let end = if snappable && snaps.len() >= s.max_snaps { PathEnd::Failed(FailureCause::StepLimit) } else { res.end };
            return (PathResult { points, end, stats, last: res.last, control: res.control }, snaps);
        };
        let lam_t = if dir * (lam_end - last.lam) <= s.overshoot * span { lam_end } else { last.lam + dir * s.overshoot * span };
        // a state kicked along its critical mode, the sign that lowers the potential at λ_t
        let kicked = |q: &[f64], lam: f64, stats: &mut PathStats| -> Vec<f64> {
            let mut qk = q.to_vec();
            if let Some(phi) = critical_mode(m, q, lam) {
                stats.factorizations += 1;
                let scale = q.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-12);
                let g = m.eval(q, lam_t, false, None).map(|e| dot(&phi, &e.r)).unwrap_or(0.0);
                let a = if g > 0.0 { -s.kick * scale } else { s.kick * scale };
                qk.iter_mut().zip(&phi).for_each(|(x, p)| *x += a * p);
            }
            qk
        };
        let qk = kicked(&last.q, last.lam, &mut stats);
        let landed = match relax(m, &qk, lam_t, s) {
            Ok(sol) => Ok(sol),
            Err((f, its)) => {
                stats.newton_iterations += its;
                stats.failed_iterations += its;
                stats.failed_attempts += 1;
                if trace_enabled() {
                    eprintln!("[snap] relaxation at λ {lam_t:.7} failed ({f:?}, {its} iterations): passing the snap under the control functional");
                }
                // the jump followed quasi-statically instead: the path under control of the
                // functional (a volume-controlled cavity has no fold there) through the unstable
                // states, from the last stable point to where λ comes back to λ_t; relaxed there
                // (at once if that state is stable)
                let vo = ContinuationOptions { start_control: Control::Functional, stop_at_fold: false, stop_at_instability: false, control_end: None, ..o.clone() };
                let pass = follow(m, &last.q, last.lam, lam_t, &[], stops, &vo);
                stats.add(&pass.stats);
                match (&pass.end, pass.points.last()) {
                    (PathEnd::Completed, Some(p)) => {
                        let q = if p.stable { p.q.clone() } else { kicked(&p.q, p.lam, &mut stats) };
                        relax(m, &q, p.lam, s).map_err(|(f2, its2)| {
                            stats.failed_iterations += its2;
                            stats.failed_attempts += 1;
                            (f2, its2)
                        })
                    }
                    (PathEnd::Stopped(i), _) => {
                        let i = *i;
                        return (PathResult { points, end: PathEnd::Stopped(i), stats, last: None, control: Control::Functional }, snaps);
                    }
                    _ => Err((f, 0)),
                }
            }
        };
        match landed {
            Ok(sol) => {
                stats.newton_iterations += sol.iterations;
                stats.factorizations += sol.iterations + 1;
                let jump = sol.q.iter().zip(&last.q).fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
                let out = m.outputs(&sol.q, sol.lam, &sol.ev);
                // a jump across a stop's threshold ends the path there (the landed state is
                // not kept: e.g. a cavity volume that went negative in the jump)
                let crossed = stops.iter().position(|st| matches!((last.outputs.get(st.output), out.get(st.output)), (Some(&a), Some(&b)) if st.crossed(a, b)));
                if let Some(i) = crossed {
                    if trace_enabled() {
                        eprintln!("[snap] at λ {:.7}: the jump crosses the stop '{}'", sol.lam, stops[i].name);
                    }
                    return (PathResult { points, end: PathEnd::Stopped(i), stats, last: None, control: Control::Load }, snaps);
                }
                points.push(PathPoint {
                    lam: sol.lam,
                    q: sol.q.clone(),
                    control: sol.ev.control.as_ref().map(|c| c.0),
                    outputs: out,
                    min_det: sol.ev.min_det,
                    stable: true,
                    kind: PointKind::Snapped,
                    newton_iterations: sol.iterations,
                });
                snaps.push(Snap { lam: sol.lam, point: points.len() - 1, iterations: sol.iterations, jump });
                if trace_enabled() {
                    eprintln!("[snap] at λ {:.7}: {} iterations, jump {jump:.3e}", sol.lam, sol.iterations);
                }
                q = sol.q;
                lam = sol.lam;
                if dir * (lam_end - lam) <= 0.0 {
                    return (PathResult { points, end: PathEnd::Completed, stats, last: Some((sol.ev.k.expect("tangent"), sol.factor)), control: Control::Load }, snaps);
                }
            }
            Err((f, its)) => {
                stats.newton_iterations += its;
                return (PathResult { points, end: PathEnd::Failed(cause_of(f)), stats, last: None, control: Control::Load }, snaps);
            }
        }
    }
}

// ------------------------------------------------------------------------------------------
// The full-order model as a path model

/// A step that would pass a contact slave through a target surface is cut to this fraction of
/// the way to the crossing ([`PathModel::step_limit`]).
const CCD_KEEP: f64 = 0.8;

/// A [`Model`] under loads interpolated linearly between `from` (λ = 0) and `to` (λ = 1), with
/// the cavity volume as control functional and outputs read through adjoint functionals.
pub struct LoadPath<'a> {
    pub model: &'a Model,
    pub from: Loads,
    pub to: Loads,
    /// recorded outputs (evaluated on the converged state, as the adjoint differentiates them)
    pub functionals: Vec<Functional>,
    /// further outputs computed from the assembly (after the functionals' values)
    pub extra: Vec<ExtraOutput<'a>>,
    /// the cavity volume is the control functional (when the model has a cavity)
    pub volume_control: bool,
    /// extrapolate in cylindrical coordinates about this axis (see [`Cylindrical`])
    pub predictor: Option<Cylindrical>,
}

/// Cylindrical predictor coordinates: the free nodes' displacements as (radius, arc length at
/// the reference radius, axial) about an axis through `center` along coordinate `axis`, so that
/// a rotation about that axis — the rigid cap's rotation and the twist of the structure below it —
/// is extrapolated exactly. (Extrapolated in Cartesian components, a rotation by Δψ leaves the
/// wall nodes next to a rigid cap O(Δψ² r) off the exactly rotated cap nodes, which costs Newton
/// one or two line-searched iterations per step.)
#[derive(Clone, Debug)]
pub struct Cylindrical {
    pub center: [f64; 3],
    pub axis: usize,
    /// (unknowns of the node's x, y, z; reference position; reference radius and angle)
    nodes: Vec<([usize; 3], [f64; 3], f64, f64)>,
}

impl Cylindrical {
    /// About the axis of the first rigid body's rotation DOF (free preferred, the z one first);
    /// None without rigid bodies.
    pub fn of_model(model: &Model) -> Option<Cylindrical> {
        use crate::dofmap::BodyDof;
        let b = model.dofs.body_dofs.first()?;
        let body = model.dofs.bodies.first()?;
        let axis = [5, 3, 4].into_iter().find(|&k| matches!(b[k], BodyDof::Free(_))).unwrap_or(5) - 3;
        let center = body.reference;
        let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
        let nodes = model
            .dofs
            .free_nodes()
            .into_iter()
            .filter_map(|(n, k)| {
                let x = model.mesh.nodes[n];
                let (a, bb) = (x[i] - center[i], x[j] - center[j]);
                let r = (a * a + bb * bb).sqrt();
                (r > 1e-9).then(|| (k, x, r, bb.atan2(a)))
            })
            .collect();
        Some(Cylindrical { center, axis, nodes })
    }
    fn plane(&self) -> (usize, usize) {
        ((self.axis + 1) % 3, (self.axis + 2) % 3)
    }
    fn coords(&self, q: &[f64]) -> Vec<f64> {
        let (i, j) = self.plane();
        let mut y = q.to_vec();
        for &(k, x0, r0, a0) in &self.nodes {
            let (a, b) = (x0[i] + q[k[i]] - self.center[i], x0[j] + q[k[j]] - self.center[j]);
            let r = (a * a + b * b).sqrt();
            let mut d = b.atan2(a) - a0;
            d -= (d / std::f64::consts::TAU).round() * std::f64::consts::TAU;
            y[k[i]] = r;
            y[k[j]] = d * r0;
        }
        y
    }
    fn rate(&self, q: &[f64], dq: &[f64]) -> Vec<f64> {
        let (i, j) = self.plane();
        let mut dy = dq.to_vec();
        for &(k, x0, r0, _) in &self.nodes {
            let (a, b) = (x0[i] + q[k[i]] - self.center[i], x0[j] + q[k[j]] - self.center[j]);
            let r2 = a * a + b * b;
            let r = r2.sqrt();
            let (da, db) = (dq[k[i]], dq[k[j]]);
            dy[k[i]] = (a * da + b * db) / r;
            dy[k[j]] = (a * db - b * da) / r2 * r0;
        }
        dy
    }
    fn inverse(&self, y: &[f64]) -> Vec<f64> {
        let (i, j) = self.plane();
        let mut q = y.to_vec();
        for &(k, x0, r0, a0) in &self.nodes {
            let (r, ang) = (y[k[i]], a0 + y[k[j]] / r0);
            q[k[i]] = self.center[i] + r * ang.cos() - x0[i];
            q[k[j]] = self.center[j] + r * ang.sin() - x0[j];
        }
        q
    }
}

/// An output of a [`LoadPath`] computed from the full assembly of a converged state.
pub type ExtraOutput<'a> = Box<dyn Fn(&Assembled) -> f64 + Send + Sync + 'a>;

impl<'a> LoadPath<'a> {
    pub fn new(model: &'a Model, from: Loads, to: Loads, functionals: Vec<Functional>) -> Self {
        LoadPath { model, from, to, functionals, extra: Vec::new(), volume_control: model.cavity.is_some(), predictor: Cylindrical::of_model(model) }
    }
    /// The loads at λ.
    pub fn loads(&self, lam: f64) -> Loads {
        Loads::lerp(&self.from, &self.to, lam)
    }
    fn presc_moves(&self) -> bool {
        self.from.presc != self.to.presc
    }
    /// The assembly at (q, λ) (full fields: displacements, reactions), e.g. for output files.
    pub fn assemble(&self, q: &[f64], lam: f64) -> Result<Assembled, ElementError> {
        self.model.assemble(q, &self.loads(lam), false)
    }
}

/// An element failure as the path follower's evaluation failure.
pub(crate) fn elem_eval(e: ElementError) -> EvalFailure {
    match e {
        ElementError::Inverted(_) | ElementError::BadReference(_) | ElementError::Penetration(_) => EvalFailure::Inversion,
        // (a failed sparse setup: refused at model construction where the full tangent is used)
        ElementError::NonFinite(_) | ElementError::Setup => EvalFailure::NonFinite,
    }
}

impl<'a> PathModel for LoadPath<'a> {
    type Matrix = Vec<f64>;
    type Factor = Factor;
    fn dim(&self) -> usize {
        self.model.n_reduced()
    }
    fn eval(&self, q: &[f64], lam: f64, tangent: bool, lin: Option<&[f64]>) -> Result<Eval<Vec<f64>>, EvalFailure> {
        let loads = self.loads(lam);
        let a = self.model.assemble_lin(q, &loads, tangent, lin).map_err(elem_eval)?;
        let scale = {
            let fb: f64 = loads.body_forces.iter().map(|f| f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sum::<f64>().sqrt();
            a.f_scale.max(fb).max(norm(&loads.nodal_forces))
        };
        let control = (self.volume_control && self.model.cavity.is_some()).then(|| (a.volume, a.dvol.clone()));
        // Π = W (+ contact) − p V, where no dead loads act
        let dead = loads.body_forces.iter().any(|f| f.iter().any(|v| *v != 0.0)) || loads.nodal_forces.iter().any(|v| *v != 0.0);
        let potential = (!dead).then(|| a.energy - loads.pressure * a.volume);
        Ok(Eval { r: a.r, scale, control, min_det: a.min_det_f, k: a.k, potential })
    }
    fn factor(&self, k: &Vec<f64>, definite: bool) -> Result<Factor, SolveError> {
        if definite {
            self.model.factor(k)
        } else {
            self.model.factor_indefinite(k)
        }
    }
    fn solve(&self, f: &Factor, b: &[f64]) -> Result<Vec<f64>, SolveError> {
        f.solve(b)
    }
    fn step_limit(&self, q: &[f64], lam: f64, dq: &[f64]) -> f64 {
        if self.model.contact().is_none() {
            return 1.0;
        }
        self.model.contact_step_limit(q, dq, &self.loads(lam), CCD_KEEP)
    }
    fn diagonal(&self, k: &Vec<f64>) -> Option<Vec<f64>> {
        self.model.tangent_diagonal(k).ok()
    }
    fn shifted(&self, k: &Vec<f64>, d: &[f64]) -> Option<Vec<f64>> {
        self.model.tangent_shifted(k, d).ok()
    }
    fn load_rate(&self, q: &[f64], lam: f64, ev: &Eval<Vec<f64>>) -> Result<Vec<f64>, EvalFailure> {
        if !self.presc_moves() {
            // r is affine in the pressure and the dead loads at fixed q:
            // ∂r/∂λ = −Δp ℓ(q) − Δ(dead loads)
            let dp = self.to.pressure - self.from.pressure;
            let mut rl: Vec<f64> = match &ev.control {
                Some((_, g)) => self.model.unit_pressure_load(g).into_iter().map(|v| -dp * v).collect(),
                None if dp != 0.0 => {
                    let a = self.model.assemble(q, &self.loads(lam), false).map_err(elem_eval)?;
                    self.model.unit_pressure_load(&a.dvol).into_iter().map(|v| -dp * v).collect()
                }
                None => vec![0.0; self.dim()],
            };
            let dead_moves = self.from.body_forces != self.to.body_forces || self.from.nodal_forces != self.to.nodal_forces;
            if dead_moves {
                // the dead part by difference of two residuals at zero pressure change
                let mut l1 = self.loads(lam + 1.0);
                let mut l0 = self.loads(lam);
                l1.pressure = 0.0;
                l0.pressure = 0.0;
                let r1 = self.model.assemble(q, &l1, false).map_err(elem_eval)?.r;
                let r0 = self.model.assemble(q, &l0, false).map_err(elem_eval)?.r;
                for (v, (a, b)) in rl.iter_mut().zip(r1.iter().zip(&r0)) {
                    *v += a - b;
                }
            }
            return Ok(rl);
        }
        // prescribed values move: central difference of the residual (r is not affine in them)
        let eps = 1e-6;
        let rp = self.model.assemble(q, &self.loads(lam + eps), false).map_err(elem_eval)?.r;
        let rm = self.model.assemble(q, &self.loads(lam - eps), false).map_err(elem_eval)?.r;
        Ok(rp.iter().zip(&rm).map(|(a, b)| (a - b) / (2.0 * eps)).collect())
    }
    fn predictor_coords(&self, q: &[f64]) -> Vec<f64> {
        match &self.predictor {
            Some(c) => c.coords(q),
            None => q.to_vec(),
        }
    }
    fn predictor_rate(&self, q: &[f64], dq: &[f64]) -> Vec<f64> {
        match &self.predictor {
            Some(c) => c.rate(q, dq),
            None => dq.to_vec(),
        }
    }
    fn from_predictor_coords(&self, y: &[f64]) -> Vec<f64> {
        match &self.predictor {
            Some(c) => c.inverse(y),
            None => y.to_vec(),
        }
    }
    fn outputs(&self, q: &[f64], lam: f64, _ev: &Eval<Vec<f64>>) -> Vec<f64> {
        let n = self.functionals.len() + self.extra.len();
        if n == 0 {
            return Vec::new();
        }
        match self.model.assemble(q, &self.loads(lam), false) {
            Ok(a) => {
                let st = adjoint::State::from_assembly(self.model, &a);
                let mut out: Vec<f64> = self.functionals.iter().map(|f| f.eval(self.model, &st).unwrap_or(f64::NAN)).collect();
                out.extend(self.extra.iter().map(|f| f(&a)));
                out
            }
            Err(_) => vec![f64::NAN; n],
        }
    }
}

/// The end of a path between two loads of a [`Model`] ([`ramp`]).
pub struct Ramp {
    pub end: PathEnd,
    /// the last converged state, its λ and loads, and its assembly (full fields)
    pub q: Vec<f64>,
    pub lam: f64,
    pub loads: Loads,
    pub assembled: Option<Assembled>,
    pub points: Vec<PathPoint>,
    pub stats: PathStats,
}

/// Follow `model` from the converged state `q0` under `from` to the loads `to` (λ from 0 to 1)
/// and return the last state with its assembly: [`follow`] on a [`LoadPath`] without outputs.
pub fn ramp(model: &Model, q0: &[f64], from: &Loads, to: &Loads, opts: &ContinuationOptions) -> Ramp {
    let lp = LoadPath::new(model, from.clone(), to.clone(), Vec::new());
    let res = follow(&lp, q0, 0.0, 1.0, &[], &[], opts);
    let (q, lam) = res.points.last().map(|p| (p.q.clone(), p.lam)).unwrap_or((q0.to_vec(), 0.0));
    let loads = lp.loads(lam);
    let assembled = model.assemble(&q, &loads, false).ok();
    Ramp { end: res.end, q, lam, loads, assembled, points: res.points, stats: res.stats }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// r(q, λ) = q − λ with the control c = 10⁴ + q, not evaluable beyond q = 0.5 (an inadmissible
    /// state): a path under functional control must end there as a failure. At c ≈ 10⁴ the
    /// minimum step (10⁻⁹|c|) loses ≈ 10⁻⁷ of itself in c + h − c, which once made the follower
    /// retry the same minimum step for ever.
    struct Wall(f64);

    impl PathModel for Wall {
        type Matrix = f64;
        type Factor = f64;
        fn dim(&self) -> usize {
            1
        }
        fn eval(&self, q: &[f64], lam: f64, tangent: bool, _lin: Option<&[f64]>) -> Result<Eval<f64>, EvalFailure> {
            if q[0] > 0.5 {
                return Err(EvalFailure::Inversion);
            }
            Ok(Eval { r: vec![q[0] - lam], scale: 1.0, control: Some((self.0 + q[0], vec![1.0])), min_det: 1.0, k: tangent.then_some(1.0), potential: None })
        }
        fn factor(&self, k: &f64, _definite: bool) -> Result<f64, SolveError> {
            Ok(*k)
        }
        fn solve(&self, f: &f64, b: &[f64]) -> Result<Vec<f64>, SolveError> {
            Ok(vec![b[0] / f])
        }
        fn load_rate(&self, _q: &[f64], _lam: f64, _ev: &Eval<f64>) -> Result<Vec<f64>, EvalFailure> {
            Ok(vec![-1.0])
        }
        fn outputs(&self, _q: &[f64], _lam: f64, _ev: &Eval<f64>) -> Vec<f64> {
            Vec::new()
        }
    }

    #[test]
    fn a_path_against_an_inadmissible_region_ends_under_functional_control() {
        let o = ContinuationOptions { start_control: Control::Functional, ..ContinuationOptions::default() };
        // (the round-off of c + h − c depends on c: several offsets)
        for offset in [1e4, 1293.2163703536721, 3333.3, 7777.7, 12345.678, 999.9] {
            let res = follow(&Wall(offset), &[0.0], 0.0, 1.0, &[], &[], &o);
            assert!(matches!(res.end, PathEnd::Failed(_)), "{:?}", res.end);
            let last = res.points.last().unwrap();
            assert!(last.q[0] <= 0.5 && last.q[0] > 0.49, "ended at q = {}", last.q[0]);
            assert!(res.stats.failed_attempts <= MAX_FAILURES_IN_ROW + 40, "{:?}", res.stats);
        }
    }

    /// Two conservative toy models (r = ∂Π/∂q) of the instabilities a pressure ramp meets:
    /// `Fold`: r = (f(u) − λ, v), f(u) = u³ − 3u² + 2.5u, a maximum of λ at u = 1 − √(1/6) past
    /// which the state snaps to the stiff branch u > 1 + √(1/6); `Pitchfork`: r = (u − λ,
    /// (λc − λ)v + v³), a symmetric branch v = 0 that loses stability at λ = λc to v = ±√(λ − λc).
    #[derive(Clone, Copy)]
    enum Toy {
        Fold,
        Pitchfork,
        /// the pitchfork with c = u as its control functional
        PitchforkC,
    }

    /// the pitchfork's critical load
    const LC: f64 = 0.9137;

    fn f_fold(u: f64) -> f64 {
        u * u * u - 3.0 * u * u + 2.5 * u
    }

    impl PathModel for Toy {
        type Matrix = nalgebra::Matrix2<f64>;
        type Factor = nalgebra::Matrix2<f64>;
        fn dim(&self) -> usize {
            2
        }
        fn eval(&self, q: &[f64], lam: f64, tangent: bool, _lin: Option<&[f64]>) -> Result<Eval<Self::Matrix>, EvalFailure> {
            let (u, v) = (q[0], q[1]);
            let (r, k, control) = match self {
                Toy::Fold => (vec![f_fold(u) - lam, v], nalgebra::Matrix2::new(3.0 * u * u - 6.0 * u + 2.5, 0.0, 0.0, 1.0), Some((u, vec![1.0, 0.0]))),
                Toy::Pitchfork | Toy::PitchforkC => {
                    let control = matches!(self, Toy::PitchforkC).then(|| (u, vec![1.0, 0.0]));
                    (vec![u - lam, (LC - lam) * v + v * v * v], nalgebra::Matrix2::new(1.0, 0.0, 0.0, LC - lam + 3.0 * v * v), control)
                }
            };
            Ok(Eval { r, scale: 1.0, control, min_det: 1.0, k: tangent.then_some(k), potential: None })
        }
        fn factor(&self, k: &Self::Matrix, definite: bool) -> Result<Self::Matrix, SolveError> {
            if definite && k.cholesky().is_none() {
                return Err(SolveError::NotPositiveDefinite);
            }
            k.try_inverse().ok_or(SolveError::Singular)
        }
        fn solve(&self, f: &Self::Matrix, b: &[f64]) -> Result<Vec<f64>, SolveError> {
            let x = f * nalgebra::Vector2::new(b[0], b[1]);
            Ok(vec![x[0], x[1]])
        }
        fn diagonal(&self, k: &Self::Matrix) -> Option<Vec<f64>> {
            Some(vec![k[(0, 0)], k[(1, 1)]])
        }
        fn shifted(&self, k: &Self::Matrix, d: &[f64]) -> Option<Self::Matrix> {
            Some(k + nalgebra::Matrix2::new(d[0], 0.0, 0.0, d[1]))
        }
        fn load_rate(&self, q: &[f64], _lam: f64, _ev: &Eval<Self::Matrix>) -> Result<Vec<f64>, EvalFailure> {
            Ok(match self {
                Toy::Fold => vec![-1.0, 0.0],
                Toy::Pitchfork | Toy::PitchforkC => vec![-1.0, -q[1]],
            })
        }
        fn outputs(&self, q: &[f64], _lam: f64, _ev: &Eval<Self::Matrix>) -> Vec<f64> {
            q.to_vec()
        }
    }

    /// Every point of a snapping path is a stable equilibrium of its load.
    fn assert_stable_equilibria(m: &Toy, pts: &[PathPoint]) {
        for p in pts {
            let e = m.eval(&p.q, p.lam, true, None).unwrap();
            assert!(norm(&e.r) < 1e-7, "residual {} at λ {}", norm(&e.r), p.lam);
            assert!(e.k.unwrap().cholesky().is_some(), "unstable point at λ {}: {:?}", p.lam, p.q);
        }
    }

    #[test]
    fn a_load_controlled_path_snaps_past_a_fold_to_the_remote_stable_branch() {
        let m = Toy::Fold;
        let o = ContinuationOptions::default();
        let (res, snaps) = follow_snapping(&m, &[0.0, 0.0], 0.0, 1.5, &[], &[], &o, &SnapOptions::default());
        assert_eq!(res.end, PathEnd::Completed);
        assert_eq!(snaps.len(), 1, "{snaps:?}");
        // the fold: λ_max = f(1 − √(1/6)); the jump lands on the far root of f(u) = λ
        let uf = 1.0 - (1.0f64 / 6.0).sqrt();
        let sn = &snaps[0];
        assert!((sn.lam - f_fold(uf)).abs() < 2e-3, "snap at λ {} (fold {})", sn.lam, f_fold(uf));
        let landed = &res.points[sn.point];
        assert_eq!(landed.kind, PointKind::Snapped);
        assert!(landed.q[0] > 1.0 + (1.0f64 / 6.0).sqrt(), "landed at u = {}", landed.q[0]);
        assert!((res.points[sn.point - 1].q[0] - uf).abs() < 1e-2, "left from u = {}", res.points[sn.point - 1].q[0]);
        let end = res.points.last().unwrap();
        assert!((end.lam - 1.5).abs() < 1e-12 && (f_fold(end.q[0]) - 1.5).abs() < 1e-8 && end.q[0] > 2.0);
        assert_stable_equilibria(&m, &res.points);
    }

    #[test]
    fn a_snap_across_a_stop_ends_the_path_before_the_jump() {
        // the fold's jump lands at u ≈ 1.82: a stop on u rising through 1.5 ends the path at the
        // last stable state before it, and the landed state is not kept
        let m = Toy::Fold;
        let stops = [Stop { name: "u".into(), output: 0, threshold: 1.5, rising: true }];
        let (res, snaps) = follow_snapping(&m, &[0.0, 0.0], 0.0, 1.5, &[], &stops, &ContinuationOptions::default(), &SnapOptions::default());
        assert_eq!(res.end, PathEnd::Stopped(0));
        assert!(snaps.is_empty(), "{snaps:?}");
        assert!(res.points.iter().all(|p| p.q[0] < 1.5), "{:?}", res.points.last().map(|p| &p.q));
        let uf = 1.0 - (1.0f64 / 6.0).sqrt();
        assert!((res.points.last().unwrap().q[0] - uf).abs() < 1e-2);
    }

    #[test]
    fn a_snap_whose_relaxation_fails_is_passed_under_the_control_functional() {
        // no relaxation iterations allowed: every relaxation fails, so the jump past the fold
        // is followed under control of u (the functional) to the far branch
        let m = Toy::Fold;
        let o = ContinuationOptions::default();
        let s = SnapOptions { max_iter: 0, ..SnapOptions::default() };
        let (res, snaps) = follow_snapping(&m, &[0.0, 0.0], 0.0, 1.5, &[], &[], &o, &s);
        assert_eq!(snaps.len(), 1, "{snaps:?}");
        let uf = 1.0 - (1.0f64 / 6.0).sqrt();
        assert!((snaps[0].lam - f_fold(uf)).abs() < 2e-3, "snap at λ {} (fold {})", snaps[0].lam, f_fold(uf));
        let landed = &res.points[snaps[0].point];
        assert!(landed.q[0] > 1.0 + (1.0f64 / 6.0).sqrt(), "landed at u = {}", landed.q[0]);
        assert!((f_fold(landed.q[0]) - landed.lam).abs() < 1e-8);
        assert_eq!(res.end, PathEnd::Completed);
        let end = res.points.last().unwrap();
        assert!((end.lam - 1.5).abs() < 1e-12 && (f_fold(end.q[0]) - 1.5).abs() < 1e-8 && end.q[0] > 2.0);
        assert_stable_equilibria(&m, &res.points);
        assert!(res.stats.failed_attempts >= 1);
    }

    #[test]
    fn a_stability_limit_beyond_the_end_of_a_functional_step_leaves_the_path_completed() {
        // under functional control one step passes both λ_end = 0.9 and the stability limit
        // λc = 0.9137 beyond it: the path ends at λ_end, completed, not at the limit past it
        let m = Toy::PitchforkC;
        let o = ContinuationOptions { start_control: Control::Functional, initial_functional: Some(0.5), ..ContinuationOptions::default() };
        let stations = [0.85];
        let res = follow(&m, &[0.5, 0.0], 0.5, 0.9, &stations, &[], &o);
        assert_eq!(res.end, PathEnd::Completed, "{:?}", res.points.iter().map(|p| (p.lam, p.kind.clone())).collect::<Vec<_>>());
        let end = res.points.last().unwrap();
        assert_eq!(end.kind, PointKind::End);
        assert!((end.lam - 0.9).abs() < 1e-9 && (end.q[0] - 0.9).abs() < 1e-9 && end.stable, "ended at λ {} q {:?}", end.lam, end.q);
        assert!(res.points.iter().all(|p| p.lam <= 0.9 + 1e-9), "a point past λ_end");
        assert!(res.points.iter().any(|p| p.kind == PointKind::Station(0) && (p.lam - 0.85).abs() < 1e-9));
        // the same step with the end beyond the limit stops there
        let res = follow(&m, &[0.5, 0.0], 0.5, 1.0, &[], &[], &o);
        assert_eq!(res.end, PathEnd::Instability);
        assert!((res.points.last().unwrap().lam - LC).abs() < 1e-3, "{}", res.points.last().unwrap().lam);
    }

    /// Counts the tangent evaluations of a model.
    struct Counted<'a, M: PathModel>(&'a M, std::cell::Cell<usize>);

    impl<M: PathModel> PathModel for Counted<'_, M> {
        type Matrix = M::Matrix;
        type Factor = M::Factor;
        fn dim(&self) -> usize {
            self.0.dim()
        }
        fn eval(&self, q: &[f64], lam: f64, tangent: bool, lin: Option<&[f64]>) -> Result<Eval<M::Matrix>, EvalFailure> {
            self.1.set(self.1.get() + usize::from(tangent));
            self.0.eval(q, lam, tangent, lin)
        }
        fn factor(&self, k: &M::Matrix, definite: bool) -> Result<M::Factor, SolveError> {
            self.0.factor(k, definite)
        }
        fn solve(&self, f: &M::Factor, b: &[f64]) -> Result<Vec<f64>, SolveError> {
            self.0.solve(f, b)
        }
        fn load_rate(&self, q: &[f64], lam: f64, ev: &Eval<M::Matrix>) -> Result<Vec<f64>, EvalFailure> {
            self.0.load_rate(q, lam, ev)
        }
        fn outputs(&self, q: &[f64], lam: f64, ev: &Eval<M::Matrix>) -> Vec<f64> {
            self.0.outputs(q, lam, ev)
        }
    }

    #[test]
    fn a_path_from_a_solved_start_is_the_path_from_its_state_without_evaluating_it_again() {
        // the start solved from a guess off the path (as a warm start from a nearby design is)
        let m = Counted(&Toy::Fold, std::cell::Cell::new(0));
        let o = ContinuationOptions { start_control: Control::Functional, initial_functional: Some(0.05), ..ContinuationOptions::default() };
        let s = correct(&m, &[0.31, 0.01], 0.5, Some(0.3), &o.newton, false, None, false).expect("the guess converges");
        assert!((s.q[0] - 0.3).abs() < 1e-12 && (s.lam - f_fold(0.3)).abs() < 1e-12, "{:?} {}", s.q, s.lam);
        let (q0, lam0) = (s.q.clone(), s.lam);
        m.1.set(0);
        let from = follow_from(&m, s, 1.2, &[], &[], &o);
        let tangents_from = m.1.get();
        m.1.set(0);
        let plain = follow(&m, &q0, lam0, 1.2, &[], &[], &o);
        assert_eq!(m.1.get(), tangents_from + 1, "follow_from evaluates its start's tangent again");
        assert_eq!(from.end, plain.end);
        assert_eq!(from.points.len(), plain.points.len());
        for (a, b) in from.points.iter().zip(&plain.points) {
            assert_eq!((a.lam, &a.q, &a.kind, a.stable), (b.lam, &b.q, &b.kind, b.stable));
        }
        assert!(from.points.len() > 2 && from.points[0].kind == PointKind::Start);
    }

    #[test]
    fn the_cubic_through_two_states_places_a_fold_exactly_for_a_cubic_branch() {
        // λ(c) = 1 − (c − 2)² + 0.1 (c − 2)³: maximum at c = 2 (and a minimum at 2 + 20/3)
        let l = |c: f64| 1.0 - (c - 2.0).powi(2) + 0.1 * (c - 2.0).powi(3);
        let k = |c: f64| -2.0 * (c - 2.0) + 0.3 * (c - 2.0).powi(2);
        let c = hermite_stationary(1.5, l(1.5), k(1.5), 2.7, l(2.7), k(2.7)).unwrap();
        assert!((c - 2.0).abs() < 1e-12, "{c}");
        // the linear secant on dλ/dc is off by the curvature of dλ/dc
        let secant = 2.7 - k(2.7) * (2.7 - 1.5) / (k(2.7) - k(1.5));
        assert!((secant - 2.0).abs() > 1e-2, "{secant}");
        // slopes of one sign: no estimate
        assert!(hermite_stationary(0.0, l(0.0), k(0.0), 1.0, l(1.0), k(1.0)).is_none());
    }

    #[test]
    fn a_load_controlled_path_leaves_a_branch_that_lost_stability_along_its_critical_mode() {
        let m = Toy::Pitchfork;
        let o = ContinuationOptions::default();
        let (res, snaps) = follow_snapping(&m, &[0.0, 0.0], 0.0, 2.0, &[0.5], &[], &o, &SnapOptions::default());
        assert_eq!(res.end, PathEnd::Completed);
        assert_eq!(snaps.len(), 1, "{snaps:?}");
        assert!((snaps[0].lam - LC).abs() < 3e-3, "snap at λ {}", snaps[0].lam);
        assert!(res.points.iter().any(|p| p.kind == PointKind::Station(0) && (p.lam - 0.5).abs() < 1e-12));
        let end = res.points.last().unwrap();
        assert!((end.q[0] - 2.0).abs() < 1e-8 && (end.q[1].abs() - (2.0 - LC).sqrt()).abs() < 1e-8, "{:?}", end.q);
        assert_stable_equilibria(&m, &res.points);
        // from the saddle itself (v = 0 at λ = 2, r = 0) relaxation needs a seed along the mode;
        // from a tiny one it reaches the buckled state
        let sol = relax(&m, &[2.0, 1e-9], 2.0, &SnapOptions::default()).unwrap();
        assert!(sol.stable && (sol.q[1] - (2.0 - LC).sqrt()).abs() < 1e-8, "{:?}", sol.q);
    }
}
