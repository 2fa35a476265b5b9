//! Newton's method with line search, and the adaptive load stepper.
//!
//! Every loop is bounded; no NaN leaves the solver: a non-finite residual, an inverted element or
//! a non-positive-definite tangent is a recorded failure with its cause, and the caller keeps the
//! last converged state.

use crate::element::ElementError;
use crate::model::{Assembled, Factor, Loads, Model, SolveError};

/// Newton options.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NewtonOptions {
    pub max_iter: usize,
    /// Converged when ‖r‖ ≤ rtol · max(‖f_int‖, ‖f_ext‖) …
    pub rtol: f64,
    /// … or ‖r‖ ≤ atol (force units).
    pub atol: f64,
    /// Below ‖r‖ ≤ stagnation_rtol · scale, stop when the residual stops decreasing (round-off).
    pub stagnation_rtol: f64,
    /// Give up (divergence) when the residual is still above its initial value after this many
    /// iterations, or above 1e-6 of it after twice as many.
    pub stall_iterations: usize,
    /// Energy criterion: converged when |Δq·r| ≤ etol · |Δq₀·r₀| (first iteration of the solve)
    /// and ‖r‖ ≤ stagnation_rtol · scale.
    pub etol: f64,
    pub line_search: bool,
    /// Use LU instead of Cholesky (indefinite tangents, e.g. past a limit point under displacement control).
    pub indefinite: bool,
    /// Keep the residual norms of every iteration (for logs/tests).
    pub log: bool,
}

impl Default for NewtonOptions {
    fn default() -> Self {
        NewtonOptions { max_iter: 25, rtol: 1e-10, atol: 1e-13, stagnation_rtol: 1e-7, stall_iterations: 8, etol: 1e-22, line_search: true, indefinite: false, log: false }
    }
}

/// Why a Newton solve failed.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum NewtonFailure {
    NotPositiveDefinite,
    Inversion,
    Divergence,
    IterationLimit,
}

/// Statistics of a converged Newton solve.
#[derive(Clone, Debug, Default)]
pub struct NewtonStats {
    pub iterations: usize,
    pub residual_norms: Vec<f64>,
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn ext_scale(loads: &Loads, a: &Assembled) -> f64 {
    let fb: f64 = loads.body_forces.iter().map(|f| f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sum::<f64>().sqrt();
    let fn_: f64 = norm(&loads.nodal_forces);
    a.f_scale.max(fb).max(fn_)
}

/// Solve r(q) = 0 at fixed loads starting from q (updated in place on success, restored on failure).
/// On success the returned assembly holds the tangent at the converged state.
pub fn newton(model: &Model, q: &mut Vec<f64>, loads: &Loads, opts: &NewtonOptions) -> Result<(NewtonStats, Assembled), NewtonFailure> {
    newton_factored(model, q, loads, opts).map(|(s, a, _)| (s, a))
}

/// As [`newton`], also returning the Cholesky factor of the tangent at the converged state.
/// Iterates whose tangent is indefinite (off equilibrium, e.g. a follower-pressure step) are
/// solved with LU; a converged state whose tangent is not positive definite is unstable and is
/// reported as `NotPositiveDefinite` (unless `opts.indefinite`, where the LU factor is returned).
pub fn newton_factored(model: &Model, q: &mut Vec<f64>, loads: &Loads, opts: &NewtonOptions) -> Result<(NewtonStats, Assembled, Factor), NewtonFailure> {
    let mut indefinite_seen = false;
    match newton_inner(model, q, loads, opts, &mut indefinite_seen) {
        // a solve that met indefinite tangents and then failed to converge is the signature of a
        // load beyond a limit point (no nearby stable equilibrium)
        Err(NewtonFailure::Divergence | NewtonFailure::IterationLimit) if indefinite_seen && !opts.indefinite => {
            Err(NewtonFailure::NotPositiveDefinite)
        }
        other => other,
    }
}

fn newton_inner(
    model: &Model,
    q: &mut Vec<f64>,
    loads: &Loads,
    opts: &NewtonOptions,
    indefinite_seen: &mut bool,
) -> Result<(NewtonStats, Assembled, Factor), NewtonFailure> {
    let q_start = q.clone();
    let fail = |q: &mut Vec<f64>, f: NewtonFailure| {
        *q = q_start.clone();
        Err(f)
    };
    let mut stats = NewtonStats::default();
    let trace_newton = trace_enabled();
    let mut a = match model.assemble(q, loads, true) {
        Ok(a) => a,
        Err(e) => return fail(q, elem_fail(e)),
    };
    let mut last_norm = f64::INFINITY;
    let mut growth = 0;
    let mut e0 = 0.0;
    let mut r0 = f64::INFINITY;
    for it in 0..=opts.max_iter {
        let rn = norm(&a.r);
        if !rn.is_finite() {
            return fail(q, NewtonFailure::Divergence);
        }
        if opts.log {
            stats.residual_norms.push(rn);
        }
        let scale = ext_scale(loads, &a);
        let tol = (opts.rtol * scale).max(opts.atol);
        // round-off floor: the volumetric terms carry errors of order κ·ε, so below a loose
        // tolerance a residual that no longer halves has converged as far as it can
        let at_floor = it > 0 && rn <= (opts.stagnation_rtol * scale).max(opts.atol) && rn > 0.5 * last_norm;
        if rn <= tol || at_floor {
            stats.iterations = it;
            let k = a.k.as_ref().expect("tangent requested");
            let fac = if opts.indefinite { model.factor_lu(k) } else { model.factor(k) };
            return match fac {
                Ok(f) => Ok((stats, a, f)),
                Err(SolveError::NotPositiveDefinite) => fail(q, NewtonFailure::NotPositiveDefinite),
                Err(_) => fail(q, NewtonFailure::Divergence),
            };
        }
        if it == opts.max_iter {
            break;
        }
        if rn > last_norm * 1e3 {
            growth += 1;
            if growth >= 2 {
                return fail(q, NewtonFailure::Divergence);
            }
        }
        if it == 0 {
            r0 = rn;
        }
        // fail fast: a solve that is not converging should hand back to the step control early
        if (it >= opts.stall_iterations && rn > r0) || (it >= 2 * opts.stall_iterations && rn > 1e-6 * r0) {
            return fail(q, NewtonFailure::Divergence);
        }
        last_norm = rn;
        let kv = a.k.take().expect("tangent requested");
        let fac = if opts.indefinite { model.factor_indefinite(&kv) } else { model.factor(&kv) };
        let fac = match fac {
            Ok(f) => f,
            Err(SolveError::NotPositiveDefinite) => {
                *indefinite_seen = true;
                match model.factor_indefinite(&kv) {
                    Ok(f) => f,
                    Err(_) => return fail(q, NewtonFailure::NotPositiveDefinite),
                }
            }
            Err(_) => return fail(q, NewtonFailure::Divergence),
        };
        let neg: Vec<f64> = a.r.iter().map(|v| -v).collect();
        let dq = match fac.solve(&neg) {
            Ok(d) => d,
            Err(_) => return fail(q, NewtonFailure::Divergence),
        };
        // line search on the energy slope g(s) = dq · r(q + s dq)
        let g0: f64 = dq.iter().zip(&a.r).map(|(d, r)| d * r).sum();
        if it == 0 {
            e0 = g0.abs();
        } else if g0.abs() <= opts.etol * e0 && rn <= (opts.stagnation_rtol * scale).max(opts.atol) {
            // energy criterion: the remaining Newton correction carries no energy
            stats.iterations = it;
            a.k = Some(kv);
            return match fac {
                Factor::Llt(_) => Ok((stats, a, fac)),
                _ if opts.indefinite => Ok((stats, a, fac)),
                _ => fail(q, NewtonFailure::NotPositiveDefinite),
            };
        }
        let mut s = 1.0;
        let mut accepted = None;
        for _ls in 0..8 {
            let qt: Vec<f64> = q.iter().zip(&dq).map(|(x, d)| x + s * d).collect();
            match model.assemble(&qt, loads, true) {
                Err(_) => {
                    s *= 0.25;
                    continue;
                }
                Ok(at) => {
                    if !opts.line_search || opts.indefinite {
                        accepted = Some((qt, at));
                        break;
                    }
                    let gs: f64 = dq.iter().zip(&at.r).map(|(d, r)| d * r).sum();
                    if !gs.is_finite() {
                        s *= 0.25;
                        continue;
                    }
                    if gs.abs() <= 0.8 * g0.abs() || s < 0.05 || g0 >= 0.0 {
                        accepted = Some((qt, at));
                        break;
                    }
                    // secant step towards the zero of g along the direction
                    let snew = if gs > 0.0 { s * g0 / (g0 - gs) } else { s * 2.0 };
                    let snew = snew.clamp(0.1 * s, 1.0);
                    if (snew - s).abs() < 1e-3 {
                        accepted = Some((qt, at));
                        break;
                    }
                    s = snew;
                }
            }
        }
        if trace_newton {
            eprintln!("[newton] it {it} |r| {rn:.3e} scale {scale:.3e} g0 {g0:.3e} s {s:.3} indefinite {}", !matches!(fac, Factor::Llt(_)));
        }
        match accepted {
            Some((qt, at)) => {
                *q = qt;
                a = at;
            }
            None => return fail(q, NewtonFailure::Inversion),
        }
    }
    fail(q, NewtonFailure::IterationLimit)
}

/// `TWISTOPT_TRACE=1` in the environment prints every load step and Newton iteration to stderr
/// (a debugging aid for hard load paths).
fn trace_enabled() -> bool {
    static TRACE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *TRACE.get_or_init(|| std::env::var_os("TWISTOPT_TRACE").is_some())
}

fn elem_fail(e: ElementError) -> NewtonFailure {
    match e {
        ElementError::Inverted(_) | ElementError::BadReference(_) => NewtonFailure::Inversion,
        ElementError::NonFinite(_) => NewtonFailure::Divergence,
    }
}

/// Load-stepping options. The path parameter t runs from 0 to 1.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StepOptions {
    pub initial: f64,
    pub min: f64,
    pub max: f64,
    pub grow: f64,
    pub cut: f64,
    /// Grow the step when Newton converged in at most this many iterations.
    pub easy_iterations: usize,
    pub max_steps: usize,
    pub newton: NewtonOptions,
}

impl Default for StepOptions {
    fn default() -> Self {
        StepOptions {
            initial: 0.1,
            min: 1e-4,
            max: 0.25,
            grow: 1.5,
            cut: 0.5,
            easy_iterations: 5,
            max_steps: 1000,
            newton: NewtonOptions::default(),
        }
    }
}

/// Why a load path ended before its end.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FailureCause {
    /// The tangent lost positive definiteness (pressure maximum / instability).
    LimitPoint,
    /// An element inverted (det F ≤ 0) at every step size tried.
    Inversion,
    /// Newton diverged at the smallest step.
    Divergence,
    /// Newton hit its iteration limit at the smallest step.
    IterationLimit,
    /// The step count limit was reached.
    StepLimit,
}

impl FailureCause {
    pub fn as_str(self) -> &'static str {
        match self {
            FailureCause::LimitPoint => "limit-point",
            FailureCause::Inversion => "inversion",
            FailureCause::Divergence => "divergence",
            FailureCause::IterationLimit => "iteration-limit",
            FailureCause::StepLimit => "step-limit",
        }
    }
}

/// Outcome of a load path.
#[derive(Clone, Debug, PartialEq)]
pub enum PathStatus {
    Completed,
    /// The step callback asked to stop (e.g. a ballooning limit was exceeded).
    Stopped(String),
    Failed(FailureCause),
}

/// A converged step handed to the callback.
pub struct StepInfo<'a> {
    pub t: f64,
    pub loads: &'a Loads,
    pub q: &'a [f64],
    pub assembled: &'a Assembled,
    pub newton_iterations: usize,
}

/// Result of a load path: final status, last converged t, state and loads.
pub struct PathResult {
    pub status: PathStatus,
    pub t: f64,
    pub q: Vec<f64>,
    pub loads: Loads,
    pub steps: usize,
    pub newton_iterations: usize,
}

/// Follow loads(t) = lerp(from, to, t) from t = 0 (state q0 converged at `from`) to t = 1.
/// The callback sees each converged step and returns `Some(reason)` to stop there.
pub fn follow_path(
    model: &Model,
    q0: &[f64],
    from: &Loads,
    to: &Loads,
    opts: &StepOptions,
    mut on_step: impl FnMut(&StepInfo) -> Option<String>,
) -> PathResult {
    let mut q = q0.to_vec();
    let mut t = 0.0;
    let mut dt = opts.initial.min(opts.max).max(opts.min);
    let mut steps = 0;
    let mut total_it = 0;
    let mut last_fail = None;
    let mut loads = from.clone();
    // factor of the tangent at the last converged state, for the predictor
    let mut f_conv: Option<Factor> = model.assemble(&q, from, true).ok().and_then(|a| a.k).and_then(|k| model.factor(&k).ok());
    let trace = trace_enabled();
    while t < 1.0 - 1e-12 {
        if steps >= opts.max_steps {
            return PathResult { status: PathStatus::Failed(FailureCause::StepLimit), t, q, loads, steps, newton_iterations: total_it };
        }
        let tn = (t + dt).min(1.0);
        let trial = Loads::lerp(from, to, tn);
        let mut qn = q.clone();
        // predictor: q − K(q_conv)⁻¹ r(q_conv; loads(t + dt)) — linear response to the increment
        if let Some(f) = &f_conv {
            if let Ok(a) = model.assemble(&q, &trial, false) {
                if let Ok(dq) = f.solve(&a.r) {
                    let qp: Vec<f64> = q.iter().zip(&dq).map(|(x, d)| x - d).collect();
                    if model.assemble(&qp, &trial, false).is_ok() {
                        qn = qp;
                    }
                }
            }
        }
        let res = newton_factored(model, &mut qn, &trial, &opts.newton);
        if trace {
            match &res {
                Ok((st, _, _)) => eprintln!("[trace] t {tn:.5} dt {dt:.5} p {:.4} kPa: converged in {}", trial.pressure * 1e3, st.iterations),
                Err(f) => eprintln!("[trace] t {tn:.5} dt {dt:.5} p {:.4} kPa: failed {f:?}", trial.pressure * 1e3),
            }
        }
        match res {
            Ok((stats, a, fac)) => {
                steps += 1;
                f_conv = Some(fac);
                total_it += stats.iterations;
                t = tn;
                q = qn;
                loads = trial;
                last_fail = None;
                let info = StepInfo { t, loads: &loads, q: &q, assembled: &a, newton_iterations: stats.iterations };
                if let Some(reason) = on_step(&info) {
                    return PathResult { status: PathStatus::Stopped(reason), t, q, loads, steps, newton_iterations: total_it };
                }
                dt = step_after_success(opts, dt, stats.iterations);
            }
            Err(f) => {
                total_it += opts.newton.max_iter.min(3);
                last_fail = Some(f);
                match step_after_failure(opts, dt) {
                    Some(d) => dt = d,
                    None => break,
                }
            }
        }
    }
    let status = path_status(last_fail);
    PathResult { status, t, q, loads, steps, newton_iterations: total_it }
}

/// Convenience: factor the tangent of a converged assembly (for adjoint solves).
pub fn factor_converged(model: &Model, a: &Assembled) -> Result<Factor, SolveError> {
    match &a.k {
        Some(k) => model.factor(k),
        None => Err(SolveError::Singular),
    }
}

/// Newton's method under volume control: the cavity pressure p is an unknown and the cavity volume
/// is held at `v_target` (bordered system). With g = ∂V/∂q and ℓ the reduced load of a unit
/// pressure (ℓ = g, or g less the caps' share when the caps carry no pressure; r = f_int − p ℓ −
/// f_ext) each iteration solves
///
///   K Δq − ℓ Δp = −r,   gᵀ Δq = V_target − V(q),
///
/// by two solves with one LU factorisation of K (which is indefinite past a pressure maximum):
/// K a = −r, K b = ℓ, Δp = (V_target − V − gᵀa)/(gᵀb), Δq = a + Δp b. `q` and `p` are updated in
/// place on success and restored on failure. `loads.pressure` is ignored.
pub fn newton_volume(
    model: &Model,
    q: &mut Vec<f64>,
    p: &mut f64,
    loads: &Loads,
    v_target: f64,
    opts: &NewtonOptions,
) -> Result<(NewtonStats, Assembled), NewtonFailure> {
    let (q_start, p_start) = (q.clone(), *p);
    let fail = |q: &mut Vec<f64>, p: &mut f64, f: NewtonFailure| {
        *q = q_start.clone();
        *p = p_start;
        Err(f)
    };
    if model.cavity.is_none() || !v_target.is_finite() || !p.is_finite() {
        return fail(q, p, NewtonFailure::Divergence);
    }
    let mut stats = NewtonStats::default();
    let mut lo = loads.clone();
    lo.pressure = *p;
    let mut a = match model.assemble(q, &lo, true) {
        Ok(a) => a,
        Err(e) => return fail(q, p, elem_fail(e)),
    };
    let vtol = 1e-10 * v_target.abs().max(a.volume.abs());
    let mut r1 = f64::INFINITY;
    let mut last_norm = f64::INFINITY;
    let mut growth = 0;
    for it in 0..=opts.max_iter {
        let rn = norm(&a.r);
        let dv = v_target - a.volume;
        if !rn.is_finite() || !dv.is_finite() {
            return fail(q, p, NewtonFailure::Divergence);
        }
        if opts.log {
            stats.residual_norms.push(rn);
        }
        let scale = ext_scale(&lo, &a).max(p.abs() * norm(&a.dvol));
        let tol = (opts.rtol * scale).max(opts.atol);
        let at_floor = it > 0 && rn <= (opts.stagnation_rtol * scale).max(opts.atol) && rn > 0.5 * last_norm;
        if trace_enabled() {
            eprintln!("[newton-volume] it {it} |r| {rn:.3e} tol {tol:.3e} dV {dv:.3e} vtol {vtol:.3e} p {:.6}", *p * 1e3);
        }
        if (rn <= tol || at_floor) && dv.abs() <= vtol {
            stats.iterations = it;
            return Ok((stats, a));
        }
        if it == opts.max_iter {
            break;
        }
        if rn > last_norm * 1e3 {
            growth += 1;
            if growth >= 2 {
                return fail(q, p, NewtonFailure::Divergence);
            }
        }
        // fail fast: from a converged start the first iterate carries the increment's residual;
        // a solve that has not reduced it after a few iterations is outside Newton's basin
        if it == 1 {
            r1 = rn;
        }
        if it >= (opts.stall_iterations / 2).max(3) && rn > r1 {
            return fail(q, p, NewtonFailure::Divergence);
        }
        last_norm = rn;
        let kv = a.k.take().expect("tangent requested");
        let fac = match model.factor_indefinite(&kv) {
            Ok(f) => f,
            Err(_) => return fail(q, p, NewtonFailure::Divergence),
        };
        let neg: Vec<f64> = a.r.iter().map(|v| -v).collect();
        // the load of a unit pressure (∂V/∂q, less the caps' share when they carry no pressure)
        let unit = model.unit_pressure_load(&a.dvol);
        let (da, db) = match (fac.solve(&neg), fac.solve(&unit)) {
            (Ok(x), Ok(y)) => (x, y),
            _ => return fail(q, p, NewtonFailure::Divergence),
        };
        let gb: f64 = a.dvol.iter().zip(&db).map(|(g, b)| g * b).sum();
        let ga: f64 = a.dvol.iter().zip(&da).map(|(g, x)| g * x).sum();
        let dp = (dv - ga) / gb;
        if !dp.is_finite() {
            return fail(q, p, NewtonFailure::Divergence);
        }
        // full Newton step; halve it only if an element inverts
        let mut s = 1.0;
        let mut accepted = None;
        for _ in 0..8 {
            let qt: Vec<f64> = q.iter().zip(da.iter().zip(&db)).map(|(x, (a1, b1))| x + s * (a1 + dp * b1)).collect();
            let pt = *p + s * dp;
            lo.pressure = pt;
            match model.assemble(&qt, &lo, true) {
                Ok(at) => {
                    accepted = Some((qt, pt, at));
                    break;
                }
                Err(_) => s *= 0.5,
            }
        }
        match accepted {
            Some((qt, pt, at)) => {
                *q = qt;
                *p = pt;
                a = at;
            }
            None => return fail(q, p, NewtonFailure::Inversion),
        }
    }
    fail(q, p, NewtonFailure::IterationLimit)
}

/// A converged volume-controlled step handed to the callback.
pub struct VolumeStepInfo<'a> {
    pub t: f64,
    pub volume: f64,
    pub pressure: f64,
    pub q: &'a [f64],
    pub assembled: &'a Assembled,
    pub newton_iterations: usize,
}

/// Result of a volume-controlled path: final status, last converged t, state and pressure.
pub struct VolumePathResult {
    pub status: PathStatus,
    pub t: f64,
    pub q: Vec<f64>,
    pub pressure: f64,
    pub steps: usize,
    pub newton_iterations: usize,
}

/// Follow a prescribed cavity volume V(t) = V(q0) + t (v_end − V(q0)), t ∈ [0, 1], from the
/// converged state (q0, p0) with the other loads held at `loads` — the volume-control path that
/// passes pressure maxima (the pressure is an unknown; see [`newton_volume`]). Adaptive steps as
/// in [`follow_path`]; the callback sees each converged step and returns `Some(reason)` to stop.
pub fn follow_volume(
    model: &Model,
    q0: &[f64],
    p0: f64,
    loads: &Loads,
    v_end: f64,
    opts: &StepOptions,
    mut on_step: impl FnMut(&VolumeStepInfo) -> Option<String>,
) -> VolumePathResult {
    let mut q = q0.to_vec();
    let mut p = p0;
    let mut lo = loads.clone();
    lo.pressure = p0;
    let v0 = match model.assemble(&q, &lo, false) {
        Ok(a) if model.cavity.is_some() && a.volume.is_finite() && v_end.is_finite() => a.volume,
        _ => {
            return VolumePathResult { status: PathStatus::Failed(FailureCause::Divergence), t: 0.0, q, pressure: p, steps: 0, newton_iterations: 0 }
        }
    };
    let mut t = 0.0;
    let mut dt = opts.initial.min(opts.max).max(opts.min);
    let (mut steps, mut total_it) = (0, 0);
    let mut last_fail = None;
    while t < 1.0 - 1e-12 {
        if steps >= opts.max_steps {
            return VolumePathResult { status: PathStatus::Failed(FailureCause::StepLimit), t, q, pressure: p, steps, newton_iterations: total_it };
        }
        let tn = (t + dt).min(1.0);
        let vt = v0 + tn * (v_end - v0);
        let (mut qn, mut pn) = (q.clone(), p);
        match newton_volume(model, &mut qn, &mut pn, loads, vt, &opts.newton) {
            Ok((stats, a)) => {
                steps += 1;
                total_it += stats.iterations;
                t = tn;
                q = qn;
                p = pn;
                last_fail = None;
                let info = VolumeStepInfo { t, volume: a.volume, pressure: p, q: &q, assembled: &a, newton_iterations: stats.iterations };
                if let Some(reason) = on_step(&info) {
                    return VolumePathResult { status: PathStatus::Stopped(reason), t, q, pressure: p, steps, newton_iterations: total_it };
                }
                dt = step_after_success(opts, dt, stats.iterations);
            }
            Err(f) => {
                total_it += opts.newton.max_iter.min(3);
                last_fail = Some(f);
                match step_after_failure(opts, dt) {
                    Some(d) => dt = d,
                    None => break,
                }
            }
        }
    }
    let status = path_status(last_fail);
    VolumePathResult { status, t, q, pressure: p, steps, newton_iterations: total_it }
}

/// Step size after a converged step: grow on easy steps.
fn step_after_success(opts: &StepOptions, dt: f64, iterations: usize) -> f64 {
    if iterations <= opts.easy_iterations {
        (dt * opts.grow).min(opts.max)
    } else {
        dt
    }
}

/// Step size after a failed step: cut back, or None when already at the smallest step.
fn step_after_failure(opts: &StepOptions, dt: f64) -> Option<f64> {
    if dt <= opts.min * (1.0 + 1e-9) {
        None
    } else {
        Some((dt * opts.cut).max(opts.min))
    }
}

fn path_status(last_fail: Option<NewtonFailure>) -> PathStatus {
    match last_fail {
        None => PathStatus::Completed,
        Some(f) => PathStatus::Failed(cause_of(f)),
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
