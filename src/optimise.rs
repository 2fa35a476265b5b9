//! Gradient-based design optimisation on the FE model with adjoint gradients.
//!
//! # Problem
//! Maximise an objective of the design and the pressure — the energy density Ω = τθ/(8V) (θ from
//! the rotation-free scene, τ from the rotation-held scene, both at the same pressure p), |θ| or
//! |τ| — over the chosen variables (by default r, l, α inside the letter's Table-I box and
//! p ∈ [p_min, p_max]) subject to the ballooning limit in every scene: the KS aggregate of the
//! deformed outer radius ≤ the limit (1.15·R0). The KS value bounds the true max from above, so a
//! KS-feasible design is feasible.
//!
//! # Scaling and stopping
//! Variables are scaled to [0, 1] by their bounds. The objective is minimised as −objective / its
//! reference (100 J/m³, 10°, 0.1 N·m); a radius constraint is (KS − limit) / (limit − R).
//! Optimisers stop at `max_evaluations` FE evaluations, when the scaled step is below `xtol_rel`,
//! or when the objective changes by less than `ftol_rel` (relative).
//!
//! # Stability: the pressure maximum
//! Under pressure control an inflated tube has a pressure maximum (limit point) beyond which it
//! snaps through and balloons; on this geometry that, not the radius limit, usually ends a ramp
//! (the letter's "analysis fails ... when the ballooning effect occurs"). Each evaluation
//! therefore continues every scene from p upward to find its pressure maximum p_lim — under
//! volume control, to 1e-6 relative ([`crate::scene::pressure_maximum`]; a pressure ramp where
//! that cannot decide) — and its design sensitivity by the null-vector formula
//! dp_lim/ds = −φᵀ∂r/∂s / φᵀ∂r/∂p ([`twistopt_solver::adjoint::limit_sensitivity`]).
//! The constraint `stability` = (p − (1 − m)·min p_lim)/(p_max − p_min) ≤ 0, m =
//! [`STABILITY_MARGIN`], is then smooth with a gradient in every variable. The search stops at
//! cap = min([`LIMIT_WINDOW`]·p, p_max)/(1 − m); without a maximum up to there p_lim is clipped to
//! the cap, so the constraint stays continuous (its design gradient is then zero).
//!
//! A design whose ramp fails before p has no stable equilibrium at p: the evaluation reports the
//! values at the last converged pressure (status `failed-before-p`, in `theta_deg`, `tau_Nm`) and
//! is infeasible through the stability constraint, so the optimiser backs off. The objective and
//! its gradient handed to the optimiser are the last good point's linear model at x (values at the
//! scenes' different failure pressures are not the objective at p: they can exceed any feasible
//! value and so reward the jump into the failed region, seen with SLSQP at p = p_max; a constant
//! value would stop nlopt on `ftol_rel`). An evaluation that cannot be built at all (invalid
//! geometry) is infeasible with the same model. A run's start that fails before p is moved below
//! its pressure maximum before the optimiser starts (p = (1 − 1.5m)·p_lim). Nothing is lost:
//! every evaluation is a row of the history with its status.
//!
//! # Optimisers
//! Behind [`Optimiser`]: nlopt MMA and SLSQP (cargo feature `nlopt`, default on; the bundled C
//! library is LGPL) and a pure-Rust trust-region SQP whose QP subproblems clarabel solves (elastic
//! constraints so that every subproblem is feasible, ℓ1 merit function, damped BFGS Hessian).
//! Runs (optimiser × start) go in parallel with rayon; the evaluations of a run are sequential,
//! each from a cold start ([`WARM_STARTS`]: warm starts from the previous converged states were
//! measured not to pay).

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Instant;

use crate::geometry::{ActuatorGeometry, DesignSpace, RangePolicy, R_TUBE};
use crate::gradient::{design_gradient, DesignGradient, WarmStarts, P_PRESSURE};
use crate::scene::{SceneKind, SceneOptions, SceneStatus};

/// What to maximise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Objective {
    EnergyDensity,
    Twist,
    Torque,
    /// the bi-directional stroke |θ(+p) − θ(−p⁻)| of the rotation-free scene
    Stroke,
    /// Ω(+p) + Ω(−p⁻): both sides' energy densities
    EnergyDensityBoth,
}

impl Objective {
    pub fn parse(s: &str) -> Option<Objective> {
        match s {
            "energy-density" => Some(Objective::EnergyDensity),
            "twist" => Some(Objective::Twist),
            "torque" => Some(Objective::Torque),
            "stroke" => Some(Objective::Stroke),
            "energy-density-both" => Some(Objective::EnergyDensityBoth),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Objective::EnergyDensity => "energy-density",
            Objective::Twist => "twist",
            Objective::Torque => "torque",
            Objective::Stroke => "stroke",
            Objective::EnergyDensityBoth => "energy-density-both",
        }
    }
    /// Whether the objective has a vacuum side (evaluated at −p⁻ as well as at +p).
    pub fn two_sided(self) -> bool {
        matches!(self, Objective::Stroke | Objective::EnergyDensityBoth)
    }
    /// Reference value that scales the objective (and its unit).
    pub fn reference(self) -> (f64, &'static str) {
        match self {
            Objective::EnergyDensity => (100.0, "J/m3"),
            Objective::Twist => (10.0, "deg"),
            Objective::Torque => (0.1, "N*m"),
            Objective::Stroke => (10.0, "deg"),
            Objective::EnergyDensityBoth => (100.0, "J/m3"),
        }
    }
}

/// A bounded variable.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Variable {
    pub name: String,
    pub lower: f64,
    pub upper: f64,
}

/// Everything an optimisation run needs.
#[derive(Clone, Debug)]
pub struct OptProblem {
    pub objective: Objective,
    /// the scenes evaluated at every design (rotation-free and/or rotation-held)
    pub scenes: Vec<SceneKind>,
    pub variables: Vec<Variable>,
    /// values of every design parameter and of p_kPa (the fixed ones stay at these)
    pub fixed: BTreeMap<String, f64>,
    /// the geometry variant of the problem's design (the spec by default)
    pub variant: crate::geometry::GeometryVariant,
    pub policy: RangePolicy,
    pub opts: SceneOptions,
    pub ks_rho: f64,
    pub ballooning_limit_mm: f64,
    /// p⁻ (kPa, > 0) of the two-sided objectives: their vacuum side is solved at −p⁻
    pub vacuum_kpa: Option<f64>,
    pub max_evaluations: usize,
    pub xtol_rel: f64,
    pub ftol_rel: f64,
    /// multi-fidelity continuation: the stages every run goes through in order (empty: one
    /// stage on `opts.mesh` with `max_evaluations`)
    pub stages: Vec<Stage>,
    /// which stage this problem is (set by [`OptProblem::stage_problems`]; stamped on evaluations)
    pub stage: usize,
}

/// A fidelity stage: the mesh and the evaluation budget.
#[derive(Clone, Debug)]
pub struct Stage {
    /// the preset name or the mesh string, as the problem file gave it
    pub label: String,
    pub mesh: crate::meshing::MeshSpec,
    pub max_evaluations: usize,
    pub xtol_rel: f64,
    pub ftol_rel: f64,
    /// the stage's reduced model (`rom = "DIR"`)
    pub rom: Option<StageRom>,
}

/// A stage's reduced model: the model, its training box and scenes, its fallback threshold.
#[derive(Clone, Debug)]
pub struct StageRom {
    pub rom: std::sync::Arc<twistopt_solver::rom::Rom>,
    pub design_box: Vec<crate::geometry::ParamSpec>,
    pub scenes: Vec<crate::scene::SceneKind>,
    pub fallback: Option<f64>,
}

/// One FE evaluation in the optimiser's terms (minimisation, scaled variables).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Evaluation {
    /// scaled variables in [0, 1]
    pub x: Vec<f64>,
    /// design parameters and p by name
    pub design: BTreeMap<String, f64>,
    /// the objective in its unit (Ω in J/m³, |θ| in °, |τ| in N·m)
    #[serde(deserialize_with = "null_nan::f64")]
    pub objective: f64,
    /// d objective / d variable (unscaled units)
    pub gradient: BTreeMap<String, f64>,
    /// constraints ≤ 0 (scaled): `radius:<scene>` and `stability`
    pub constraints: BTreeMap<String, f64>,
    pub feasible: bool,
    pub theta_deg: Option<f64>,
    #[serde(rename = "tau_Nm")]
    pub tau_nm: Option<f64>,
    /// true max deformed radius over the scenes
    #[serde(deserialize_with = "null_nan::f64")]
    pub max_radius_mm: f64,
    /// the lowest pressure maximum of the scenes found by continuing the ramp from p up to the
    /// pressure bound (None: none below the bound)
    #[serde(rename = "p_limit_kPa")]
    pub p_limit_kpa: Option<f64>,
    /// per scene: status (converged, or what ended the ramp) and the pressure reached
    pub scenes: BTreeMap<String, (SceneStatus, f64)>,
    pub status: String,
    pub newton_iterations: usize,
    pub adjoint_solves: usize,
    pub time_s: f64,
    pub warm_started: bool,
    /// the vacuum side of a two-sided objective (None for the others)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vacuum: Option<VacuumSide>,
    /// fidelity stage (0-based) and its mesh (`<Na>x<Nz>x<Nt>`)
    #[serde(default)]
    pub stage: usize,
    #[serde(default)]
    pub mesh: String,
    /// scaled objective f = −objective/reference and its gradient in x; constraint Jacobian
    /// (what the optimiser saw: kept so that an interrupted optimisation replays exactly)
    #[serde(default, rename = "f_scaled", deserialize_with = "null_nan::f64")]
    pub f: f64,
    #[serde(default, rename = "df_scaled", deserialize_with = "null_nan::vec")]
    pub df: Vec<f64>,
    #[serde(default, rename = "g_scaled", deserialize_with = "null_nan::vec")]
    pub g: Vec<f64>,
    #[serde(default, rename = "dg_scaled", deserialize_with = "null_nan::vec2")]
    pub dg: Vec<Vec<f64>>,
}

/// The vacuum side of a two-sided evaluation: the scenes' values at −p⁻.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VacuumSide {
    #[serde(rename = "p_kPa")]
    pub p_kpa: f64,
    pub theta_deg: Option<f64>,
    #[serde(rename = "tau_Nm")]
    pub tau_nm: Option<f64>,
    /// Ω of the pair at −p⁻ (signed by the letter's rule, as at +p)
    #[serde(rename = "omega_J_m3")]
    pub omega_j_m3: Option<f64>,
    /// the closest approach of two cavity walls at −p⁻ (mm; None without contact)
    #[serde(rename = "min_contact_distance_mm", default, skip_serializing_if = "Option::is_none")]
    pub min_contact_distance_mm: Option<f64>,
    /// with contact: the elements folded between their quadrature points at −p⁻ (the scenes'
    /// largest count; > 0: a state the mesh does not represent, studies/vacuum)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub folded_elements: Option<usize>,
}

/// Reading back numbers that JSON wrote as null (serde_json writes NaN and ±∞ so): NaN.
mod null_nan {
    use serde::{Deserialize, Deserializer};
    pub fn f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
    pub fn vec<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<Option<f64>>::deserialize(d)?.into_iter().map(|v| v.unwrap_or(f64::NAN)).collect())
    }
    pub fn vec2<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<f64>>, D::Error> {
        Ok(Vec::<Vec<Option<f64>>>::deserialize(d)?.into_iter().map(|r| r.into_iter().map(|v| v.unwrap_or(f64::NAN)).collect()).collect())
    }
}

impl Evaluation {
    /// An evaluation of an analytic problem in scaled variables (minimise f s.t. g ≤ 0): the
    /// objective is −f; for tests and for users plugging in their own functions.
    pub fn from_parts(x: &[f64], f: f64, df: Vec<f64>, g: Vec<f64>, dg: Vec<Vec<f64>>) -> Evaluation {
        let feasible = g.iter().all(|v| *v <= FEAS_TOL);
        Evaluation {
            x: x.to_vec(),
            design: x.iter().enumerate().map(|(i, v)| (format!("x{i}"), *v)).collect(),
            objective: -f,
            gradient: df.iter().enumerate().map(|(i, v)| (format!("x{i}"), -v)).collect(),
            constraints: g.iter().enumerate().map(|(i, v)| (format!("g{i}"), *v)).collect(),
            feasible,
            theta_deg: None,
            tau_nm: None,
            max_radius_mm: f64::NAN,
            p_limit_kpa: None,
            scenes: BTreeMap::new(),
            status: "ok".into(),
            newton_iterations: 0,
            adjoint_solves: 0,
            time_s: 0.0,
            warm_started: false,
            vacuum: None,
            stage: 0,
            mesh: String::new(),
            f,
            df,
            g,
            dg,
        }
    }
}

/// Result of one optimiser run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunResult {
    pub optimiser: String,
    pub start: usize,
    pub x0: Vec<f64>,
    pub status: String,
    pub evaluations: Vec<Evaluation>,
    /// index into `evaluations` of the best feasible point (None: none feasible)
    pub best: Option<usize>,
    /// KKT measure at the best point: ‖projected gradient of the Lagrangian‖∞ / ‖∇f(x0)‖∞ (scaled
    /// variables; x0 the run's start)
    pub kkt: Option<f64>,
    pub multipliers: Option<Vec<f64>>,
    pub wall_time_s: f64,
}

/// Constraint feasibility tolerance (scaled units, ≈ 0.009 mm of radius).
pub const FEAS_TOL: f64 = 1e-3;

/// The pressure is kept this fraction below the scenes' lowest pressure maximum (snap-through):
/// an actuator cannot be operated at its limit point, and solves there are ill-conditioned.
pub const STABILITY_MARGIN: f64 = 0.02;

/// Warm-start an evaluation from the previous one's converged states. Off: measured (bench
/// `warm_start`) at optimiser-sized steps next to the energy optimum, Newton from the
/// neighbour's state on the new geometry did not converge in any case (sweep and default meshes,
/// steps of 0.5 mm / 10° and 40°), so the warm start cost 3–9 extra iterations before the cold
/// path; the cold path costs 2.5–3 iterations per step.
pub const WARM_STARTS: bool = false;

/// The limit-pressure search covers p ≤ p_lim ≤ LIMIT_WINDOW·p/(1 − m) (at most p_max/(1 − m)).
pub const LIMIT_WINDOW: f64 = 1.25;

impl OptProblem {
    pub fn n(&self) -> usize {
        self.variables.len()
    }

    /// The geometry's design of unscaled values (p_kPa dropped), with the problem's variant.
    pub fn design_of(&self, values: &BTreeMap<String, f64>) -> crate::geometry::Design {
        crate::geometry::Design { values: values.iter().filter(|(k, _)| k.as_str() != P_PRESSURE).map(|(k, v)| (k.clone(), *v)).collect(), variant: self.variant }
    }

    /// The design parameters and p by name at scaled variables x (the fixed ones included).
    pub fn unscale(&self, x: &[f64]) -> BTreeMap<String, f64> {
        let mut d = self.fixed.clone();
        for (v, xi) in self.variables.iter().zip(x) {
            d.insert(v.name.clone(), v.lower + xi.clamp(0.0, 1.0) * (v.upper - v.lower));
        }
        d
    }

    fn constraint_names(&self) -> Vec<String> {
        let mut c: Vec<String> = self.scenes.iter().map(|k| format!("radius:{}", k.name())).collect();
        c.push("stability".into());
        if self.envelope() {
            for kind in ["envelope", "waist", "fold"] {
                c.extend(envelope_heights().into_iter().map(|z| format!("{kind}:z={z:.1}")));
            }
        }
        if self.freeform() {
            c.push("jacobian".into());
        }
        c
    }

    pub fn n_constraints(&self) -> usize {
        self.scenes.len() + 1 + if self.envelope() { SHAPE_CONSTRAINTS * ENVELOPE_POINTS } else { 0 } + usize::from(self.freeform())
    }

    /// The freeform shape's validity as differentiable constraints, each at the
    /// [`envelope_heights`], with their Jacobian in the scaled variables (dual actuators):
    ///
    /// * envelope (ρ(z) − R)/2 mm ≤ 0: the rest radius within the tube radius;
    /// * waist (ρ_min(r) − ρ(z))/2 mm ≤ 0, ρ_min = [`crate::geometry::l_min_waist`]: the offset
    ///   notch walls stay apart and off the axis (its r-derivative by central differences of the
    ///   closed form);
    /// * fold κ₁(z)·(t + 0.5 mm) − 1 ≤ 0, κ₁(z) the largest convex principal curvature of the
    ///   untwisted outer surface around the section at height z (240 samples; its gradient at
    ///   the maximiser): the inward offset by t does not fold.
    ///
    /// The geometry refuses designs beyond these limits by a margin ([`crate::geometry::freeform_validity`]),
    /// so that a step across a constraint can still be evaluated.
    fn envelope_of(&self, geom: &ActuatorGeometry) -> (Vec<f64>, Vec<Vec<f64>>) {
        use num_dual::Dual64;
        let duals: Vec<Option<crate::geometry::Actuator<Dual64>>> = self.variables.iter().map(|v| if v.name == P_PRESSURE { None } else { geom.dual_actuator(&v.name).ok() }).collect();
        let span = |v: &Variable| v.upper - v.lower;
        let heights = envelope_heights();
        let (mut g, mut dg) = (Vec::new(), Vec::new());
        // envelope
        for &z in &heights {
            g.push((geom.act.profile.eval(z).rho - R_TUBE) / ENVELOPE_SCALE_MM);
            dg.push(self.variables.iter().zip(&duals).map(|(v, a)| a.as_ref().map_or(0.0, |a| a.profile.eval(Dual64::from(z)).rho.eps) * span(v) / ENVELOPE_SCALE_MM).collect());
        }
        // waist
        let r = geom.act.section.r;
        let need = crate::geometry::l_min_waist(r);
        let h = 1e-6 * r;
        let dneed = (crate::geometry::l_min_waist(r + h) - crate::geometry::l_min_waist(r - h)) / (2.0 * h);
        for &z in &heights {
            g.push((need - geom.act.profile.eval(z).rho) / ENVELOPE_SCALE_MM);
            dg.push(
                self.variables
                    .iter()
                    .zip(&duals)
                    .map(|(v, a)| {
                        let drho = a.as_ref().map_or(0.0, |a| a.profile.eval(Dual64::from(z)).rho.eps);
                        let dr = if v.name == crate::geometry::P_R { dneed } else { 0.0 };
                        (dr - drho) * span(v) / ENVELOPE_SCALE_MM
                    })
                    .collect(),
            );
        }
        // fold
        let margin = crate::geometry::T_WALL + 0.5;
        for &z in &heights {
            let (mut kmax, mut smax) = (f64::NEG_INFINITY, 0.0);
            for i in 0..FOLD_SAMPLES {
                let shat = i as f64 / FOLD_SAMPLES as f64;
                let k1 = geom.act.principal_curvatures0(shat, z).0;
                if k1 > kmax {
                    (kmax, smax) = (k1, shat);
                }
            }
            g.push(kmax * margin - 1.0);
            dg.push(self.variables.iter().zip(&duals).map(|(v, a)| a.as_ref().map_or(0.0, |a| a.principal_curvatures0(Dual64::from(smax), Dual64::from(z)).0.eps) * margin * span(v)).collect());
        }
        (g, dg)
    }

    /// The mesh-quality constraint of a freeform design: (floor − s)/scale ≤ 0, s the least
    /// scaled Jacobian of this problem's mesh of the design
    /// ([`crate::meshing::min_scaled_jacobian_sensitivity`]; its gradient at the minimising
    /// element and point), floor [`JACOBIAN_CONSTRAINT_FLOOR`] above the mesh's refusal at
    /// [`crate::meshing::FREEFORM_MIN_SCALED_JACOBIAN`], so that the optimiser is held off
    /// before a design is refused (and sees the constraint's gradient at a refused design too).
    fn jacobian_of(&self, geom: &ActuatorGeometry) -> Result<(f64, Vec<f64>), crate::meshing::MeshError> {
        let names: Vec<String> = self.variables.iter().map(|v| v.name.clone()).collect();
        let (sj, d) = crate::meshing::min_scaled_jacobian_sensitivity(geom, &self.opts.mesh, &names)?;
        let dg = self.variables.iter().zip(d).map(|(v, di)| if v.name == P_PRESSURE { 0.0 } else { -di * (v.upper - v.lower) / JACOBIAN_CONSTRAINT_SCALE }).collect();
        Ok(((JACOBIAN_CONSTRAINT_FLOOR - sj) / JACOBIAN_CONSTRAINT_SCALE, dg))
    }

    /// The shape constraints of a design: envelope, waist and fold at the [`envelope_heights`]
    /// (with a profile mode among the variables) and the mesh-quality constraint (with any
    /// freeform mode), in the order of the problem's constraints after radius and stability.
    fn shape_constraints_of(&self, geom: &ActuatorGeometry) -> Result<(Vec<f64>, Vec<Vec<f64>>), crate::meshing::MeshError> {
        let (mut g, mut dg) = if self.envelope() { self.envelope_of(geom) } else { (Vec::new(), Vec::new()) };
        if self.freeform() {
            let (gj, dj) = self.jacobian_of(geom)?;
            g.push(gj);
            dg.push(dj);
        }
        Ok((g, dg))
    }

    /// [`OptProblem::shape_constraints_of`] at scaled variables x (None where the geometry cannot
    /// be built).
    pub fn shape_constraints(&self, x: &[f64]) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
        let design = self.unscale(x);
        let d = self.design_of(&design);
        let geom = ActuatorGeometry::new(&d, self.policy).ok()?;
        self.shape_constraints_of(&geom).ok()
    }

    /// Whether the rest radius is a constraint: a freeform profile mode is a variable.
    fn envelope(&self) -> bool {
        self.variables.iter().any(|v| matches!(crate::geometry::freeform::parse_param(&v.name), Some((crate::geometry::freeform::ModeKind::Profile, _))))
    }

    /// Whether any freeform mode (twist law or profile) is a variable: then the mesh's quality
    /// is a constraint.
    fn freeform(&self) -> bool {
        self.variables.iter().any(|v| crate::geometry::freeform::parse_param(&v.name).is_some())
    }

    /// The problem of each fidelity stage (the problem itself when it has no stages).
    pub fn stage_problems(&self) -> Vec<(String, OptProblem)> {
        if self.stages.is_empty() {
            return vec![(self.opts.mesh.size_string(), self.clone())];
        }
        self.stages
            .iter()
            .enumerate()
            .map(|(k, st)| {
                let mut p = self.clone();
                p.opts.mesh = st.mesh;
                p.opts.formulation = twistopt_solver::element::Formulation::standard(st.mesh.kind);
                // a stage runs on its own reduced model or on the full one (a problem-level
                // fidelity.rom is for another mesh)
                p.opts.rom = st.rom.as_ref().map(|r| r.rom.clone());
                p.opts.rom_box = st.rom.as_ref().map(|r| r.design_box.clone()).unwrap_or_default();
                p.opts.rom_scenes = st.rom.as_ref().map(|r| r.scenes.clone()).unwrap_or_default();
                p.opts.rom_fallback = st.rom.as_ref().and_then(|r| r.fallback);
                p.max_evaluations = st.max_evaluations;
                p.xtol_rel = st.xtol_rel;
                p.ftol_rel = st.ftol_rel;
                p.stages.clear();
                p.stage = k;
                (st.label.clone(), p)
            })
            .collect()
    }

    /// One FE evaluation (never panics; failures are infeasible evaluations with a status).
    pub fn evaluate(&self, x: &[f64], warm: &mut Option<WarmStarts>, last_good: Option<&Evaluation>) -> Evaluation {
        let t0 = Instant::now();
        let design = self.unscale(x);
        let n = self.n();
        let m = self.n_constraints();
        let (oref, _) = self.objective.reference();
        let mut ev = Evaluation::from_parts(x, 0.0, vec![0.0; n], vec![1.0; m], vec![vec![0.0; n]; m]);
        ev.design = design.clone();
        ev.stage = self.stage;
        ev.mesh = self.opts.mesh.size_string();
        ev.objective = f64::NAN;
        ev.gradient.clear();
        ev.constraints.clear();
        ev.feasible = false;
        let fail = |mut ev: Evaluation, why: String| {
            ev.status = why;
            if let Some(lg) = last_good {
                extrapolate(&mut ev, lg);
            } else {
                ev.objective = 0.0;
            }
            ev.time_s = t0.elapsed().as_secs_f64();
            ev
        };
        let d = self.design_of(&design);
        let geom = match ActuatorGeometry::new(&d, self.policy) {
            Ok(g) => g,
            Err(e) => return fail(ev, format!("invalid-geometry: {e}")),
        };
        // the shape constraints first: a design whose mesh is refused below still hands the
        // optimiser the mesh-quality constraint and its gradient
        let j0 = self.scenes.len() + 1;
        match self.shape_constraints_of(&geom) {
            Ok((g, dg)) => {
                ev.g[j0..j0 + g.len()].copy_from_slice(&g);
                for (row, d) in ev.dg[j0..].iter_mut().zip(dg) {
                    *row = d;
                }
            }
            Err(e) => return fail(ev, format!("invalid-geometry: mesh: {e}")),
        }
        let p = design[P_PRESSURE];
        let pi = self.variables.iter().position(|v| v.name == P_PRESSURE);
        // the limit search goes to the pressure whose margin the highest allowed p needs
        let (pmax, prange) = match pi {
            Some(i) => (self.variables[i].upper, self.variables[i].upper - self.variables[i].lower),
            None => (LIMIT_WINDOW * p, p.abs().max(1.0)),
        };
        // only a limit near p can make the constraint active: search up to LIMIT_WINDOW·p (at most
        // p_max); beyond, p_lim is taken as the cap (a continuous, conservative clip)
        let reach = (LIMIT_WINDOW * p).min(pmax).max(p);
        let cap = reach / (1.0 - STABILITY_MARGIN);
        let start = if WARM_STARTS { warm.as_ref() } else { None };
        let dg: DesignGradient = match design_gradient(&geom, &self.opts, &self.scenes, p, self.ks_rho, start, Some(cap)) {
            Ok(g) => g,
            Err(e) => return fail(ev, format!("model-error: {e}")),
        };
        ev.newton_iterations = dg.newton_iterations;
        ev.adjoint_solves = dg.adjoint_solves;
        ev.warm_started = dg.scenes.values().all(|s| s.cost.warm_started);
        let mut p_reached = p;
        let mut all_ok = true;
        for (name, s) in &dg.scenes {
            ev.scenes.insert(name.clone(), (s.status, s.p_kpa));
            if s.status != SceneStatus::Converged {
                all_ok = false;
                p_reached = p_reached.min(s.p_kpa);
            }
            if s.status == SceneStatus::GradientFailed {
                return fail(ev, format!("{name}: {}", s.cause));
            }
        }
        ev.max_radius_mm = dg.scenes.values().map(|s| s.max_radius_mm).fold(0.0, f64::max);
        // the vacuum side of a two-sided objective, at −p⁻ on the full model of the same mesh (the
        // reduced models cover positive pressures only); its gradients w.r.t. the design only (p⁻
        // is fixed: the p_kPa variable is the positive side's)
        let vac = match (self.objective.two_sided(), self.vacuum_kpa) {
            (true, Some(pv)) => {
                let scenes: Vec<SceneKind> = if self.objective == Objective::Stroke { self.scenes.iter().copied().filter(|k| k.rotation_free()).collect() } else { self.scenes.clone() };
                let mut vopts = self.opts.clone();
                vopts.rom = None;
                let vg = match design_gradient(&geom, &vopts, &scenes, -pv, self.ks_rho, None, None) {
                    Ok(g) => g,
                    Err(e) => return fail(ev, format!("model-error (vacuum side): {e}")),
                };
                ev.newton_iterations += vg.newton_iterations;
                ev.adjoint_solves += vg.adjoint_solves;
                for (name, s) in &vg.scenes {
                    ev.scenes.insert(format!("{name}@vacuum"), (s.status, s.p_kpa));
                }
                if let Some(s) = vg.scenes.values().find(|s| s.status != SceneStatus::Converged) {
                    return fail(ev, format!("failed-vacuum: {} {} at {:.3} kPa: {}", s.scene, s.status, s.p_kpa, s.cause));
                }
                // a state with folded elements is not one the mesh represents (as a scene's ramp
                // would end before it, `scenes.contact.stop_at_fold`)
                if vopts.contact.is_some_and(|c| c.stop_at_fold) {
                    if let Some(s) = vg.scenes.values().find(|s| s.folded_elements.is_some_and(|k| k > 0)) {
                        return fail(
                            ev,
                            format!(
                                "failed-vacuum: {} inversion at {:.3} kPa: {} elements fold between their quadrature points (scenes.contact.stop_at_fold = false accepts the state)",
                                s.scene,
                                s.p_kpa,
                                s.folded_elements.unwrap_or(0)
                            ),
                        );
                    }
                }
                let key = if self.scenes.contains(&SceneKind::Free) { "combined" } else { "pure-twist" };
                ev.vacuum = Some(VacuumSide {
                    p_kpa: -pv,
                    theta_deg: vg.scenes.values().find_map(|s| s.values.get("theta_deg").copied()),
                    tau_nm: vg.scenes.values().find_map(|s| s.values.get("tau_Nm").copied()),
                    omega_j_m3: vg.omega.get(key).map(|o| o.value),
                    min_contact_distance_mm: vg.scenes.values().filter_map(|s| s.contact_distance_mm).reduce(f64::min),
                    folded_elements: vg.scenes.values().filter_map(|s| s.folded_elements).max(),
                });
                Some(vg)
            }
            _ => None,
        };
        // a vacuum-side gradient without its pressure component
        let design_only = |g: &BTreeMap<String, f64>| -> BTreeMap<String, f64> { g.iter().filter(|(k, _)| k.as_str() != P_PRESSURE).map(|(k, v)| (k.clone(), *v)).collect() };
        let add = |a: &BTreeMap<String, f64>, b: &BTreeMap<String, f64>, sb: f64| -> BTreeMap<String, f64> {
            let mut c = a.clone();
            for (k, v) in b {
                *c.entry(k.clone()).or_insert(0.0) += sb * v;
            }
            c
        };
        // the objective and its gradient by parameter name
        let (obj, grad): (f64, BTreeMap<String, f64>) = match self.objective {
            Objective::EnergyDensity => {
                let key = if self.scenes.contains(&SceneKind::Free) { "combined" } else { "pure-twist" };
                match dg.omega.get(key) {
                    Some(o) => (o.value, o.gradient.clone()),
                    None => return fail(ev, "model-error: no pair of scenes for the energy density".into()),
                }
            }
            Objective::EnergyDensityBoth => {
                let key = if self.scenes.contains(&SceneKind::Free) { "combined" } else { "pure-twist" };
                match (dg.omega.get(key), vac.as_ref().and_then(|v| v.omega.get(key))) {
                    (Some(o), Some(ov)) => (o.value + ov.value, add(&o.gradient, &design_only(&ov.gradient), 1.0)),
                    _ => return fail(ev, "model-error: no pair of scenes for the energy density on both sides".into()),
                }
            }
            Objective::Stroke => {
                let th = |g: &DesignGradient| g.scenes.values().find(|s| s.values.contains_key("theta_deg")).map(|s| (s.values["theta_deg"], s.gradients["theta_deg"].clone()));
                match (th(&dg), vac.as_ref().and_then(th)) {
                    (Some((tp, gp)), Some((tv, gv))) => {
                        let d = tp - tv;
                        let sg = if d < 0.0 { -1.0 } else { 1.0 };
                        (d.abs(), add(&gp, &design_only(&gv), -1.0).into_iter().map(|(k, g)| (k, sg * g)).collect())
                    }
                    _ => return fail(ev, "model-error: no rotation-free scene gives theta_deg on both sides".into()),
                }
            }
            Objective::Twist | Objective::Torque => {
                let f = if self.objective == Objective::Twist { "theta_deg" } else { "tau_Nm" };
                match dg.scenes.values().find(|s| s.values.contains_key(f)) {
                    Some(s) => {
                        let v = s.values[f];
                        let sg = if v < 0.0 { -1.0 } else { 1.0 };
                        (v.abs(), s.gradients[f].iter().map(|(k, g)| (k.clone(), sg * g)).collect())
                    }
                    None => return fail(ev, format!("model-error: no scene gives {f}")),
                }
            }
        };
        for s in dg.scenes.values() {
            if let Some(t) = s.values.get("theta_deg") {
                ev.theta_deg = Some(*t);
            }
            if let Some(t) = s.values.get("tau_Nm") {
                ev.tau_nm = Some(*t);
            }
        }
        ev.objective = obj;
        ev.f = -obj / oref;
        for (i, v) in self.variables.iter().enumerate() {
            let gv = grad.get(&v.name).copied().unwrap_or(0.0);
            ev.gradient.insert(v.name.clone(), gv);
            ev.df[i] = -gv * (v.upper - v.lower) / oref;
        }
        // radius constraints
        let cscale = self.ballooning_limit_mm - R_TUBE;
        for (j, k) in self.scenes.iter().enumerate() {
            let s = &dg.scenes[k.name()];
            ev.g[j] = (s.values.get("max_radius_ks_mm").copied().unwrap_or(f64::INFINITY) - self.ballooning_limit_mm) / cscale;
            for (i, v) in self.variables.iter().enumerate() {
                ev.dg[j][i] = s.gradients.get("max_radius_ks_mm").and_then(|g| g.get(&v.name)).copied().unwrap_or(0.0) * (v.upper - v.lower) / cscale;
            }
        }
        // stability: p ≤ (1 − margin) · p_lim, p_lim = the lowest pressure maximum of the scenes
        let ms = self.scenes.len();
        let lim = dg.scenes.values().filter_map(|s| s.p_limit_kpa.map(|pl| (pl, &s.p_limit_gradient))).min_by(|a, b| a.0.total_cmp(&b.0));
        match lim {
            Some((pl, grad)) => {
                let keep = 1.0 - STABILITY_MARGIN;
                ev.g[ms] = (p - keep * pl) / prange;
                for (i, v) in self.variables.iter().enumerate() {
                    ev.dg[ms][i] = if v.name == P_PRESSURE { 1.0 } else { -keep * grad.get(&v.name).copied().unwrap_or(0.0) * (v.upper - v.lower) / prange };
                }
                ev.p_limit_kpa = Some(pl);
            }
            None => {
                // no failure up to the cap: p_lim > cap, clipped to the cap (continuous with the
                // branch above; (1 − m)·cap = min(LIMIT_WINDOW·p, p_max))
                ev.g[ms] = (p - reach) / prange;
                if let Some(i) = pi {
                    ev.dg[ms][i] = if LIMIT_WINDOW * p < pmax { 1.0 - LIMIT_WINDOW } else { 1.0 };
                }
            }
        }
        if !all_ok {
            ev.status = format!(
                "failed-before-p: {}",
                dg.scenes.values().filter(|s| s.status != SceneStatus::Converged).map(|s| format!("{} {} at {:.3} kPa", s.scene, s.status, s.p_kpa)).collect::<Vec<_>>().join(", ")
            );
            // no objective at p: the optimiser sees the last good point's (the module docs)
            match last_good {
                Some(lg) => extrapolate(&mut ev, lg),
                None => {
                    ev.f = 0.0;
                    ev.df = vec![0.0; n];
                    ev.objective = 0.0;
                }
            }
        }
        for (name, gv) in self.constraint_names().into_iter().zip(&ev.g) {
            ev.constraints.insert(name, *gv);
        }
        let finite = ev.f.is_finite() && ev.df.iter().chain(ev.g.iter()).chain(ev.dg.iter().flatten()).all(|v| v.is_finite());
        if !finite {
            return fail(ev, "non-finite value or gradient".into());
        }
        ev.feasible = all_ok && ev.g.iter().all(|g| *g <= FEAS_TOL);
        if all_ok {
            *warm = Some(dg.warm_starts());
        }
        ev.time_s = t0.elapsed().as_secs_f64();
        ev
    }
}

/// What the optimiser sees at a point without an objective (failed before p, or not evaluated):
/// the last good point's linear model there, f = f_g + ∇f_g·(x − x_g), ∇f = ∇f_g (the objective
/// reported stays the last good one's). A constant f would read as "no change" and stop nlopt on
/// `ftol_rel` (measured: MMA stopped after 8 evaluations, 6 of them failed before p,
/// studies/freeform/pure-twist); the point stays infeasible through its constraints.
fn extrapolate(ev: &mut Evaluation, lg: &Evaluation) {
    let step: f64 = lg.df.iter().zip(ev.x.iter().zip(&lg.x)).map(|(d, (x, xg))| d * (x - xg)).sum();
    ev.f = lg.f + if step.is_finite() { step } else { 0.0 };
    ev.df = lg.df.clone();
    ev.objective = lg.objective;
}

/// Stopping rules of a run.
#[derive(Clone, Copy, Debug)]
pub struct StopRules {
    pub max_evaluations: usize,
    pub xtol_rel: f64,
    pub ftol_rel: f64,
}

/// A run's evaluation log with a cache of the last point (nlopt asks for the objective and the
/// constraints at the same x separately). The evaluator is any function of the scaled variables
/// (the FE problem, or an analytic test problem).
pub struct Session<'a> {
    evaluator: Box<dyn FnMut(&[f64], Option<&Evaluation>) -> Evaluation + 'a>,
    pub stop: StopRules,
    pub n_constraints: usize,
    pub evaluations: Vec<Evaluation>,
    /// set when the evaluation budget is exhausted
    pub exhausted: bool,
    /// evaluations of an interrupted run, answered in order while the optimiser asks for the
    /// same points (the algorithms are deterministic); dropped at the first other point
    replay: std::collections::VecDeque<Evaluation>,
    on_replay: Option<Box<dyn Fn(&Evaluation) + 'a>>,
    /// how many evaluations were answered from the replay
    pub replayed: usize,
}

/// Two scaled design points are the same evaluation point (to the JSON round trip of floats).
fn same_point(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12)
}

impl<'a> Session<'a> {
    /// A session on the FE problem (warm starts carried from evaluation to evaluation); `log`
    /// sees every evaluation (e.g. to print progress).
    pub fn new(problem: &'a OptProblem, log: impl Fn(&Evaluation) + 'a) -> Self {
        let mut warm: Option<WarmStarts> = None;
        let stop = StopRules { max_evaluations: problem.max_evaluations, xtol_rel: problem.xtol_rel, ftol_rel: problem.ftol_rel };
        Session::with_evaluator(
            stop,
            problem.n_constraints(),
            Box::new(move |x, last_good| {
                let ev = problem.evaluate(x, &mut warm, last_good);
                log(&ev);
                ev
            }),
        )
    }

    pub fn with_evaluator(stop: StopRules, n_constraints: usize, evaluator: Box<dyn FnMut(&[f64], Option<&Evaluation>) -> Evaluation + 'a>) -> Self {
        Session { evaluator, stop, n_constraints, evaluations: Vec::new(), exhausted: false, replay: Default::default(), on_replay: None, replayed: 0 }
    }

    /// Answer from these recorded evaluations (of an interrupted run, in their order) while the
    /// optimiser asks for their points; `on_replay` sees each one answered.
    pub fn with_replay(mut self, replay: Vec<Evaluation>, on_replay: impl Fn(&Evaluation) + 'a) -> Self {
        self.replay = replay.into();
        self.on_replay = Some(Box::new(on_replay));
        self
    }

    /// The evaluation at x (cached when x repeats the last point).
    pub fn eval(&mut self, x: &[f64]) -> Evaluation {
        if let Some(last) = self.evaluations.last() {
            if last.x == x {
                return last.clone();
            }
        }
        if self.evaluations.len() >= self.stop.max_evaluations {
            self.exhausted = true;
            // answer with the last point's data; the driver stops
            if let Some(last) = self.evaluations.last() {
                return last.clone();
            }
        }
        if let Some(r) = self.replay.pop_front() {
            // (a history from a version with other constraints is not replayed: its rows do not fit)
            if same_point(&r.x, x) && r.df.len() == x.len() && r.g.len() == self.n_constraints && r.dg.len() == self.n_constraints {
                self.replayed += 1;
                if let Some(f) = &self.on_replay {
                    f(&r);
                }
                self.evaluations.push(r.clone());
                return r;
            }
            // the run went elsewhere than recorded: evaluate from here on
            self.replay.clear();
        }
        let last_good = self.evaluations.iter().rev().find(|e| e.status == "ok").cloned();
        let ev = (self.evaluator)(x, last_good.as_ref());
        self.evaluations.push(ev.clone());
        ev
    }

    /// Index of the best feasible evaluation.
    pub fn best(&self) -> Option<usize> {
        self.evaluations.iter().enumerate().filter(|(_, e)| e.feasible).max_by(|a, b| a.1.objective.total_cmp(&b.1.objective)).map(|(i, _)| i)
    }
}

/// An optimisation algorithm over scaled variables in [0, 1]ⁿ.
pub trait Optimiser: Sync {
    fn name(&self) -> &'static str;
    /// Run from x0, evaluating through the session; returns a stop status.
    fn run(&self, session: &mut Session, x0: &[f64]) -> String;
}

/// The optimisers available in this build, by name.
pub fn optimiser(name: &str) -> Option<Box<dyn Optimiser>> {
    match name {
        #[cfg(feature = "nlopt")]
        "mma" => Some(Box::new(nlopt_driver::NloptOptimiser { algorithm: nlopt_driver::Which::Mma })),
        #[cfg(feature = "nlopt")]
        "slsqp" => Some(Box::new(nlopt_driver::NloptOptimiser { algorithm: nlopt_driver::Which::Slsqp })),
        "sqp" => Some(Box::new(sqp::TrustRegionSqp)),
        _ => None,
    }
}

/// Names accepted by [`optimiser`] in this build.
pub fn available_optimisers() -> Vec<&'static str> {
    let mut v = Vec::new();
    if cfg!(feature = "nlopt") {
        v.extend(["mma", "slsqp"]);
    }
    v.push("sqp");
    v
}

#[cfg(feature = "nlopt")]
mod nlopt_driver {
    use super::*;
    use nlopt::{Algorithm, Nlopt, Target};
    use std::cell::RefCell;

    #[derive(Clone, Copy)]
    pub enum Which {
        Mma,
        Slsqp,
    }

    pub struct NloptOptimiser {
        pub algorithm: Which,
    }

    impl Optimiser for NloptOptimiser {
        fn name(&self) -> &'static str {
            match self.algorithm {
                Which::Mma => "mma",
                Which::Slsqp => "slsqp",
            }
        }

        fn run(&self, session: &mut Session, x0: &[f64]) -> String {
            let n = x0.len();
            let m = session.n_constraints;
            let (xtol, ftol, maxeval) = (session.stop.xtol_rel, session.stop.ftol_rel, session.stop.max_evaluations);
            let cell = RefCell::new(session);
            let obj = |x: &[f64], grad: Option<&mut [f64]>, _: &mut ()| -> f64 {
                let ev = cell.borrow_mut().eval(x);
                if let Some(g) = grad {
                    g.copy_from_slice(&ev.df);
                }
                ev.f
            };
            let alg = match self.algorithm {
                Which::Mma => Algorithm::Mma,
                Which::Slsqp => Algorithm::Slsqp,
            };
            let mut opt = Nlopt::new(alg, n, obj, Target::Minimize, ());
            let cons = |res: &mut [f64], x: &[f64], grad: Option<&mut [f64]>, _: &mut ()| {
                let ev = cell.borrow_mut().eval(x);
                res.copy_from_slice(&ev.g);
                if let Some(g) = grad {
                    for j in 0..m {
                        g[j * n..(j + 1) * n].copy_from_slice(&ev.dg[j]);
                    }
                }
            };
            let setup = opt
                .set_lower_bounds(&vec![0.0; n])
                .and_then(|_| opt.set_upper_bounds(&vec![1.0; n]))
                // bound-constrained problems (e.g. least-squares fits) have no constraint block
                .and_then(|_| if m > 0 { opt.add_inequality_mconstraint(m, cons, (), &vec![FEAS_TOL * 0.1; m]) } else { Ok(nlopt::SuccessState::Success) })
                .and_then(|_| opt.set_xtol_rel(xtol))
                .and_then(|_| opt.set_ftol_rel(ftol))
                .and_then(|_| opt.set_maxeval(maxeval as u32));
            if let Err(e) = setup {
                return format!("nlopt setup failed: {e:?}");
            }
            let mut x = x0.to_vec();
            let status = match opt.optimize(&mut x) {
                Ok((s, _)) => format!("{s:?}"),
                Err((e, _)) => format!("{e:?}"),
            };
            drop(opt);
            if cell.borrow().exhausted {
                "MaxEvalReached".into()
            } else {
                status
            }
        }
    }
}

mod sqp {
    //! Trust-region SQP with elastic constraints: at x solve
    //!   min ½dᵀBd + ∇fᵀd + ν Σ s   s.t.  g + J d ≤ s, s ≥ 0, 0 ≤ x + d ≤ 1, ‖d‖∞ ≤ Δ
    //! with clarabel; accept by the ℓ1 merit φ = f + ν Σ max(0, g); damped BFGS update of B on the
    //! Lagrangian gradient (multipliers from the QP).
    use super::*;
    use clarabel::algebra::CscMatrix;
    use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};

    pub struct TrustRegionSqp;

    fn merit(ev: &Evaluation, nu: f64) -> f64 {
        ev.f + nu * ev.g.iter().map(|g| g.max(0.0)).sum::<f64>()
    }

    /// Dense (rows) → CSC.
    fn csc(rows: usize, cols: usize, a: &[Vec<f64>], upper_only: bool) -> CscMatrix<f64> {
        let mut colptr = vec![0usize];
        let mut rowval = Vec::new();
        let mut nzval = Vec::new();
        for c in 0..cols {
            for (r, row) in a.iter().enumerate().take(rows) {
                if upper_only && r > c {
                    continue;
                }
                if row[c] != 0.0 {
                    rowval.push(r);
                    nzval.push(row[c]);
                }
            }
            colptr.push(rowval.len());
        }
        CscMatrix::new(rows, cols, colptr, rowval, nzval)
    }

    /// Solve the elastic QP; returns (d, multipliers of g + J d ≤ s).
    fn qp(b: &[Vec<f64>], ev: &Evaluation, x: &[f64], delta: f64, nu: f64) -> Option<(Vec<f64>, Vec<f64>)> {
        let n = x.len();
        let m = ev.g.len();
        let nv = n + m;
        let mut p = vec![vec![0.0; nv]; nv];
        for i in 0..n {
            for j in 0..n {
                p[i][j] = b[i][j];
            }
        }
        let mut q = ev.df.clone();
        q.extend(std::iter::repeat_n(nu, m));
        // rows: J d − s ≤ −g (m); −s ≤ 0 (m); d ≤ min(1 − x, Δ) (n); −d ≤ min(x, Δ) (n)
        let mut a = Vec::new();
        let mut rhs = Vec::new();
        for j in 0..m {
            let mut r = vec![0.0; nv];
            r[..n].copy_from_slice(&ev.dg[j]);
            r[n + j] = -1.0;
            a.push(r);
            rhs.push(-ev.g[j]);
        }
        for j in 0..m {
            let mut r = vec![0.0; nv];
            r[n + j] = -1.0;
            a.push(r);
            rhs.push(0.0);
        }
        for i in 0..n {
            let mut r = vec![0.0; nv];
            r[i] = 1.0;
            a.push(r);
            rhs.push((1.0 - x[i]).min(delta).max(0.0));
            let mut r = vec![0.0; nv];
            r[i] = -1.0;
            a.push(r);
            rhs.push(x[i].min(delta).max(0.0));
        }
        let pm = csc(nv, nv, &p, true);
        let am = csc(a.len(), nv, &a, false);
        let cones = [NonnegativeConeT(a.len())];
        let settings = DefaultSettingsBuilder::default().verbose(false).max_iter(200).build().ok()?;
        let mut solver = DefaultSolver::new(&pm, &q, &am, &rhs, &cones, settings).ok()?;
        solver.solve();
        match solver.solution.status {
            SolverStatus::Solved | SolverStatus::AlmostSolved => {}
            _ => return None,
        }
        let d = solver.solution.x[..n].to_vec();
        let lam = solver.solution.z[..m].to_vec();
        if d.iter().chain(&lam).any(|v| !v.is_finite()) {
            return None;
        }
        Some((d, lam))
    }

    impl Optimiser for TrustRegionSqp {
        fn name(&self) -> &'static str {
            "sqp"
        }

        fn run(&self, s: &mut Session, x0: &[f64]) -> String {
            let n = x0.len();
            let (xtol, ftol) = (s.stop.xtol_rel, s.stop.ftol_rel);
            let mut x = x0.to_vec();
            let mut ev = s.eval(&x);
            let mut b: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect()).collect();
            let mut delta: f64 = 0.2;
            let mut nu: f64 = 10.0;
            loop {
                if s.exhausted || s.evaluations.len() >= s.stop.max_evaluations {
                    return "MaxEvalReached".into();
                }
                let Some((d, lam)) = qp(&b, &ev, &x, delta, nu) else {
                    return "qp-failed".into();
                };
                let dn = d.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                if dn < xtol {
                    return "XtolReached".into();
                }
                nu = nu.max(1.5 * lam.iter().fold(0.0f64, |a, v| a.max(*v)));
                let xn: Vec<f64> = x.iter().zip(&d).map(|(a, b)| (a + b).clamp(0.0, 1.0)).collect();
                let evn = s.eval(&xn);
                // predicted reduction of the merit model
                let lin: Vec<f64> = ev.g.iter().zip(&ev.dg).map(|(g, j)| g + j.iter().zip(&d).map(|(a, b)| a * b).sum::<f64>()).collect();
                let quad: f64 = 0.5 * (0..n).map(|i| (0..n).map(|j| d[i] * b[i][j] * d[j]).sum::<f64>()).sum::<f64>();
                let pred = -(ev.df.iter().zip(&d).map(|(a, b)| a * b).sum::<f64>() + quad) + nu * (ev.g.iter().map(|g| g.max(0.0)).sum::<f64>() - lin.iter().map(|g| g.max(0.0)).sum::<f64>());
                let ared = merit(&ev, nu) - merit(&evn, nu);
                let rho = if pred > 0.0 { ared / pred } else { -1.0 };
                let failed_eval = evn.status.starts_with("invalid") || evn.status.starts_with("model-error") || evn.status.starts_with("non-finite");
                if rho < 0.25 || failed_eval {
                    delta = 0.25 * dn.max(1e-6);
                } else if rho > 0.75 && dn > 0.99 * delta {
                    delta = (2.0 * delta).min(1.0);
                }
                if rho > 0.05 && !failed_eval {
                    // damped BFGS on the Lagrangian gradient
                    let lag = |e: &Evaluation| -> Vec<f64> { (0..n).map(|i| e.df[i] + lam.iter().zip(&e.dg).map(|(l, row)| l * row[i]).sum::<f64>()).collect() };
                    let y: Vec<f64> = lag(&evn).iter().zip(lag(&ev)).map(|(a, b)| a - b).collect();
                    let sv: Vec<f64> = xn.iter().zip(&x).map(|(a, b)| a - b).collect();
                    let bs: Vec<f64> = (0..n).map(|i| (0..n).map(|j| b[i][j] * sv[j]).sum()).collect();
                    let sbs: f64 = sv.iter().zip(&bs).map(|(a, b)| a * b).sum();
                    let sy: f64 = sv.iter().zip(&y).map(|(a, b)| a * b).sum();
                    if sbs > 1e-16 {
                        let theta = if sy >= 0.2 * sbs { 1.0 } else { 0.8 * sbs / (sbs - sy) };
                        let r: Vec<f64> = (0..n).map(|i| theta * y[i] + (1.0 - theta) * bs[i]).collect();
                        let sr: f64 = sv.iter().zip(&r).map(|(a, b)| a * b).sum();
                        if sr > 1e-16 {
                            for i in 0..n {
                                for j in 0..n {
                                    b[i][j] += r[i] * r[j] / sr - bs[i] * bs[j] / sbs;
                                }
                            }
                        }
                    }
                    let df = (evn.f - ev.f).abs();
                    let converged_f = df <= ftol * ev.f.abs().max(1e-12) && evn.g.iter().all(|g| *g <= FEAS_TOL);
                    x = xn;
                    ev = evn;
                    if converged_f {
                        return "FtolReached".into();
                    }
                } else if delta < xtol {
                    return "XtolReached (trust region)".into();
                }
            }
        }
    }
}

/// KKT measure at an evaluation: with A the constraints within `FEAS_TOL` of active, the smallest
/// ‖P(∇f + Σ_A λ_i ∇g_i)‖∞ over λ ≥ 0 (P zeroes the components that push out of the box at active
/// bounds), relative to `scale` (the run's initial ‖∇f‖∞); the least over λ from the least
/// squares of each subset of the first 8 active constraints and from a non-negative least squares
/// over all of them (an upper bound of that minimum).
/// Returns (measure, λ).
pub fn kkt_measure(ev: &Evaluation, scale: f64) -> (f64, Vec<f64>) {
    let n = ev.df.len();
    let active: Vec<usize> = (0..ev.g.len()).filter(|&j| ev.g[j] >= -FEAS_TOL && ev.dg[j].iter().any(|v| *v != 0.0)).collect();
    let proj = |v: &[f64]| -> f64 {
        (0..n)
            .map(|i| {
                let c = v[i];
                if ev.x[i] <= 1e-6 {
                    c.min(0.0).abs() // at the lower bound a positive component is fine (minimisation)
                } else if ev.x[i] >= 1.0 - 1e-6 {
                    c.max(0.0)
                } else {
                    c.abs()
                }
            })
            .fold(0.0, f64::max)
    };
    let scale = scale.max(1e-12);
    let mut best = (proj(&ev.df), vec![0.0; ev.g.len()]);
    // a candidate: multipliers `vals` of the constraints `set`, kept when its measure is lower
    let consider = |set: &[usize], vals: &[f64], best: &mut (f64, Vec<f64>)| {
        let mut lam = vec![0.0; ev.g.len()];
        for (&j, &v) in set.iter().zip(vals) {
            lam[j] = v;
        }
        let lg: Vec<f64> = (0..n).map(|i| ev.df[i] + lam.iter().zip(&ev.dg).map(|(l, r)| l * r[i]).sum::<f64>()).collect();
        let r = proj(&lg);
        if r < best.0 {
            *best = (r, lam);
        }
    };
    // least squares over each subset of the active constraints, on the interior components
    let interior: Vec<usize> = (0..n).filter(|&i| ev.x[i] > 1e-6 && ev.x[i] < 1.0 - 1e-6).collect();
    for mask in 1u32..(1u32 << active.len().min(8)) {
        let set: Vec<usize> = active.iter().enumerate().filter(|(k, _)| mask & (1 << k) != 0).map(|(_, &j)| j).collect();
        let rows = interior.len().max(1);
        let a = nalgebra::DMatrix::from_fn(rows, set.len(), |r, c| interior.get(r).map(|&i| ev.dg[set[c]][i]).unwrap_or(0.0));
        let b = nalgebra::DVector::from_fn(rows, |r, _| interior.get(r).map(|&i| -ev.df[i]).unwrap_or(0.0));
        let Ok(sol) = a.clone().svd(true, true).solve(&b, 1e-12) else {
            continue;
        };
        if sol.iter().any(|l| *l < 0.0) {
            continue;
        }
        consider(&set, sol.as_slice(), &mut best);
    }
    // all active constraints at once (the enumeration above covers subsets of the first 8 only;
    // a freeform optimum has the 19 envelope constraints active): non-negative least squares on
    // the interior components, one more candidate λ
    if active.len() > 1 && !interior.is_empty() {
        let g = faer::Mat::<f64>::from_fn(interior.len(), active.len(), |r, c| ev.dg[active[c]][interior[r]]);
        let b: Vec<f64> = interior.iter().map(|&i| -ev.df[i]).collect();
        let a = g.transpose() * &g;
        let c: Vec<f64> = (0..active.len()).map(|k| interior.iter().enumerate().map(|(r, _)| g[(r, k)] * b[r]).sum()).collect();
        let bb: f64 = b.iter().map(|v| v * v).sum();
        if bb > 0.0 && a.col_iter().all(|col| col.iter().all(|v| v.is_finite())) {
            let (x, _) = twistopt_solver::rom::nnls_gram(&a, &c, bb, 0.0, active.len());
            consider(&active, &x, &mut best);
        }
    }
    (best.0 / scale, best.1)
}

/// Heights at which a freeform profile is held inside the envelope, ρ(z) ≤ R (one constraint
/// each, with its gradient by dual numbers): the ends keep ρ = R by construction, and the
/// geometry refuses ρ more than [`crate::geometry::ENVELOPE_SLACK_MM`] beyond R, so that a step
/// across the constraint can still be evaluated.
pub const ENVELOPE_POINTS: usize = 19;
/// The mesh-quality constraint's floor on the least scaled Jacobian ([`OptProblem`] with freeform
/// modes): 0.05 above the refusal at [`crate::meshing::FREEFORM_MIN_SCALED_JACOBIAN`].
pub const JACOBIAN_CONSTRAINT_FLOOR: f64 = 0.15;
/// The mesh-quality constraint's scale: (floor − s)/scale ≤ 0.
pub const JACOBIAN_CONSTRAINT_SCALE: f64 = 0.1;
/// The envelope constraints' scale: (ρ − R)/scale ≤ 0 (mm).
const ENVELOPE_SCALE_MM: f64 = 2.0;
/// The kinds of shape constraints at each of the [`envelope_heights`]: envelope, waist, fold.
pub const SHAPE_CONSTRAINTS: usize = 3;
/// Samples around the section for the fold constraint's largest convex curvature.
const FOLD_SAMPLES: usize = 240;

/// The interior heights of the envelope constraints (mm).
pub fn envelope_heights() -> Vec<f64> {
    (1..=ENVELOPE_POINTS).map(|i| crate::geometry::L_TUBE * i as f64 / (ENVELOPE_POINTS + 1) as f64).collect()
}

/// Space-filling starting points in [0.1, 0.9]ⁿ: the Halton sequence from its second point, one
/// distinct prime base per dimension (2, 3, 5, 7, 11, …, the d-th prime for dimension d).
///
/// Plain Halton points in large bases are correlated over the first points (point k is ≈ k/b in
/// every large base b), so for bases ≥ 11 (dimensions ≥ 4) the digits are scrambled by a fixed
/// permutation per base (0 kept fixed; deterministic, seeded by the base). Dimensions 0–3 (bases 2,
/// 3, 5, 7) are the plain sequence, so every problem of ≤ 4 variables (the letter's r, l, α, p and
/// the reduced models' training designs) keeps the points it always had.
pub fn starting_points(n: usize, count: usize) -> Vec<Vec<f64>> {
    let bases = primes(n);
    let perms: Vec<Vec<u32>> = bases.iter().map(|&b| digit_permutation(b)).collect();
    let halton = |mut i: u32, b: u32, perm: &[u32]| {
        let (mut f, mut r) = (1.0, 0.0);
        while i > 0 {
            f /= b as f64;
            r += f * perm[(i % b) as usize] as f64;
            i /= b;
        }
        r
    };
    (0..count).map(|k| (0..n).map(|d| 0.1 + 0.8 * halton(k as u32 + 1, bases[d], &perms[d])).collect()).collect()
}

/// The starts of a problem: the [design] itself first when `from_design`, then space-filling
/// points ([`starting_points`]) contracted towards it by `spread` (x = x_d + spread (h − x_d), in
/// scaled variables; spread = 1 gives the Halton points themselves), skipping the points whose
/// geometry is refused (as a freeform profile far out in its box is).
pub fn problem_starting_points(op: &OptProblem, count: usize, from_design: bool, spread: f64, p_start: Option<f64>) -> Vec<Vec<f64>> {
    let xd: Vec<f64> = op
        .variables
        .iter()
        .map(|v| {
            let x = if v.name == P_PRESSURE { p_start } else { None }
                .or_else(|| op.fixed.get(&v.name).copied())
                // an optional parameter the design does not carry: its absent value (0)
                .or_else(|| crate::geometry::DesignSpace::optional().get(&v.name).map(|_| 0.0))
                .unwrap_or(v.upper);
            ((x - v.lower) / (v.upper - v.lower)).clamp(0.0, 1.0)
        })
        .collect();
    let mut out = Vec::with_capacity(count);
    if from_design && count > 0 {
        out.push(xd.clone());
    }
    // Halton points in order, skipping those whose geometry cannot be built (a run from an
    // invalid design has no gradient to follow); all of the first ones when none can be
    let want = count - out.len();
    let candidates = starting_points(op.n(), (8 * want).max(want + 64));
    let contract = |h: &Vec<f64>| -> Vec<f64> { h.iter().zip(&xd).map(|(h, d)| if spread == 1.0 { *h } else { d + spread * (h - d) }).collect() };
    // (and whose mesh is refused at a fidelity the runs use: a freeform shape too distorted)
    let meshes: Vec<crate::meshing::MeshSpec> = std::iter::once(op.opts.mesh).chain(op.stages.iter().map(|s| s.mesh)).collect();
    let valid = |x: &Vec<f64>| {
        let design = op.unscale(x);
        let d = op.design_of(&design);
        ActuatorGeometry::new(&d, op.policy).is_ok_and(|g| !g.act.is_freeform() || meshes.iter().all(|m| crate::meshing::build_mesh(&g, m).is_ok()))
    };
    let mut picked: Vec<Vec<f64>> = candidates.iter().map(contract).filter(valid).take(want).collect();
    for h in candidates.iter().map(contract) {
        if picked.len() >= want {
            break;
        }
        picked.push(h);
    }
    out.extend(picked);
    out
}

/// The first n primes.
fn primes(n: usize) -> Vec<u32> {
    let mut p: Vec<u32> = Vec::with_capacity(n);
    let mut c = 2u32;
    while p.len() < n {
        if p.iter().take_while(|&&q| q * q <= c).all(|&q| c % q != 0) {
            p.push(c);
        }
        c += 1;
    }
    p
}

/// The digit permutation of base b: the identity for b < 11, else a fixed pseudo-random
/// permutation of 1..b (Fisher–Yates driven by splitmix64 seeded with b) with 0 kept at 0.
fn digit_permutation(b: u32) -> Vec<u32> {
    let mut perm: Vec<u32> = (0..b).collect();
    if b < 11 {
        return perm;
    }
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ b as u64;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    for i in (2..b as usize).rev() {
        let j = 1 + (next() % i as u64) as usize;
        perm.swap(i, j);
    }
    perm
}

/// Where a finer stage starts: the previous stage's design, unless this mesh's ramp fails before
/// its pressure (a finer mesh has a lower pressure maximum: measured on the pure-twist problem,
/// 60.3 kPa coarse → 52.2 kPa default). Then every evaluation there hands back the last good
/// objective, the optimiser sees no change and stops (MMA on ftol, nothing feasible); the start
/// moves to a pressure below this mesh's limit instead, p = (1 − 1.5 m)·p_lim (m the stability
/// margin). The evaluation at the original design stays in the history.
fn stage_start(sp: &OptProblem, session: &mut Session, x: Vec<f64>) -> Vec<f64> {
    let Some(i) = sp.variables.iter().position(|v| v.name == P_PRESSURE) else { return x };
    let ev = session.eval(&x);
    match ev.p_limit_kpa {
        Some(pl) if ev.status.starts_with("failed-before-p") => {
            let v = &sp.variables[i];
            let p = (1.0 - 1.5 * STABILITY_MARGIN) * pl;
            let mut x = x;
            x[i] = ((p - v.lower) / (v.upper - v.lower)).clamp(0.0, 1.0);
            x
        }
        _ => x,
    }
}

/// Run every (optimiser, start) pair in parallel. `progress` is called after each run, and
/// `each` after each evaluation with the run's name and the evaluation's index.
pub fn run_all(problem: &OptProblem, optimisers: &[String], starts: &[Vec<f64>], progress: impl Fn(&RunResult) + Sync, each: impl Fn(&str, usize, &Evaluation) + Sync) -> Vec<RunResult> {
    run_all_resumed(problem, optimisers, starts, &BTreeMap::new(), progress, each)
}

/// Every run of a multi-start optimisation, (optimiser, start index), in the order of the
/// results (optimiser by optimiser, each over its starts).
pub fn all_runs(optimisers: &[String], n_starts: usize) -> Vec<(String, usize)> {
    optimisers.iter().flat_map(|o| (0..n_starts).map(move |s| (o.clone(), s))).collect()
}

/// The name of a run ("<optimiser> start <i>"), as in evaluations.jsonl and the progress lines.
pub fn run_name(optimiser: &str, start: usize) -> String {
    format!("{optimiser} start {start}")
}

/// [`run_all`], resuming interrupted runs: `recorded` holds each run's evaluations so far (by
/// run name, "<optimiser> start <i>", in order), which are replayed instead of re-evaluated
/// while each run asks for the same points; `each` sees only the new evaluations.
pub fn run_all_resumed(
    problem: &OptProblem,
    optimisers: &[String],
    starts: &[Vec<f64>],
    recorded: &BTreeMap<String, Vec<Evaluation>>,
    progress: impl Fn(&RunResult) + Sync,
    each: impl Fn(&str, usize, &Evaluation) + Sync,
) -> Vec<RunResult> {
    run_selected(problem, &all_runs(optimisers, starts.len()), starts, recorded, progress, each)
}

/// [`run_all_resumed`] on some of the runs: `jobs` lists (optimiser, index into `starts`). A run
/// of a subset is the same run as in the full multi-start (same starting point, same name), so
/// that runs done by separate processes can be joined (`twistopt optimise-merge`).
pub fn run_selected(
    problem: &OptProblem,
    jobs: &[(String, usize)],
    starts: &[Vec<f64>],
    recorded: &BTreeMap<String, Vec<Evaluation>>,
    progress: impl Fn(&RunResult) + Sync,
    each: impl Fn(&str, usize, &Evaluation) + Sync,
) -> Vec<RunResult> {
    use rayon::prelude::*;
    let done = Mutex::new(());
    let stages = problem.stage_problems();
    jobs.par_iter()
        .map(|(name, si)| {
            let t0 = Instant::now();
            let run_name = run_name(name, *si);
            let counter = std::cell::Cell::new(0usize);
            let mut evaluations: Vec<Evaluation> = Vec::new();
            let mut statuses = Vec::new();
            let mut x = starts[*si].clone();
            let (mut best, mut g0) = (None, 1.0);
            for (k, (label, sp)) in stages.iter().enumerate() {
                let (run_name, counter, each) = (&run_name, &counter, &each);
                let replay: Vec<Evaluation> = recorded.get(run_name.as_str()).map(|v| v.iter().filter(|e| e.stage == k).cloned().collect()).unwrap_or_default();
                let mut session = Session::new(sp, move |e| {
                    counter.set(counter.get() + 1);
                    each(run_name, counter.get(), e)
                })
                .with_replay(replay, move |_| counter.set(counter.get() + 1));
                // a start past the scenes' pressure maximum (no equilibrium at p) moves down to
                // below it, at every stage: the first stage's too (measured: an MMA run from a
                // Halton start beyond the fold stopped after 2 evaluations, studies/freeform/)
                x = stage_start(sp, &mut session, x);
                let status = match optimiser(name) {
                    Some(o) => o.run(&mut session, &x),
                    None => format!("unknown optimiser '{name}'"),
                };
                statuses.push(if stages.len() > 1 { format!("{label}: {status}") } else { status });
                // the next stage starts from this stage's best feasible design (else where it stopped)
                best = session.best();
                if let Some(b) = best.or(session.evaluations.len().checked_sub(1)) {
                    x = session.evaluations[b].x.clone();
                }
                // (the scale of the first evaluation with a gradient: a failed first one has none)
                let ginf = |e: &Evaluation| e.df.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                g0 = session.evaluations.iter().map(ginf).find(|g| *g > 0.0 && g.is_finite()).unwrap_or(1.0);
                best = best.map(|b| b + evaluations.len());
                evaluations.extend(session.evaluations);
            }
            // the result is the last stage's best (earlier stages are another fidelity)
            let (kkt, multipliers) = match best {
                Some(b) => {
                    let (k, l) = kkt_measure(&evaluations[b], g0);
                    (Some(k), Some(l))
                }
                None => (None, None),
            };
            let status = statuses.join("; ");
            let r = RunResult { optimiser: name.clone(), start: *si, x0: starts[*si].clone(), status, evaluations, best, kkt, multipliers, wall_time_s: t0.elapsed().as_secs_f64() };
            let _g = done.lock();
            progress(&r);
            r
        })
        .collect()
}

/// Build the optimisation problem of a validated problem file.
pub fn build_problem(problem: &crate::problem::Problem, v: &crate::problem::Validated) -> anyhow::Result<(OptProblem, crate::problem::OptimiseSection)> {
    use anyhow::{anyhow, bail};
    let sec = problem.optimise.clone().ok_or_else(|| anyhow!("the problem has no [optimise] section (see problems/README.md)"))?;
    let objective = Objective::parse(&sec.objective).ok_or_else(|| anyhow!("optimise.objective = '{}' (expected energy-density, twist, torque, stroke or energy-density-both)", sec.objective))?;
    match (objective.two_sided(), sec.vacuum_kpa) {
        (true, None) => bail!("optimise.objective = {} needs optimise.vacuum_kPa (p⁻ > 0: the vacuum side is solved at −p⁻)", objective.name()),
        (true, Some(pv)) if !(pv.is_finite() && pv > 0.0 && pv <= 100.0) => bail!("optimise.vacuum_kPa = {pv} must be in (0, 100] (a vacuum below −100 kPa is not physical)"),
        (false, Some(_)) => bail!("optimise.vacuum_kPa is used only by the two-sided objectives (stroke, energy-density-both), not by {}", objective.name()),
        _ => {}
    }
    let p_max = match v.load {
        crate::problem::LoadPlan::Ramp(p) => p,
        _ => bail!("optimise needs load.p_max_kPa (the upper bound of the pressure), not load.pressures_kPa"),
    };
    if !(sec.p_min_kpa.is_finite() && sec.p_min_kpa > 0.0 && sec.p_min_kpa < p_max) {
        bail!("optimise.p_min_kPa = {} must be > 0 and below load.p_max_kPa = {p_max}", sec.p_min_kpa);
    }
    let has = |k: SceneKind| v.scenes.contains(&k);
    match objective {
        Objective::EnergyDensity | Objective::EnergyDensityBoth => {
            if !((has(SceneKind::Free) && has(SceneKind::Blocked)) || (has(SceneKind::PureTwist) && has(SceneKind::PureTwistBlocked))) {
                bail!("optimise.objective = {} needs scenes.run = [free, blocked] or [pure-twist, pure-twist-blocked]", objective.name());
            }
        }
        Objective::Twist | Objective::Stroke => {
            if !(has(SceneKind::Free) || has(SceneKind::PureTwist)) {
                bail!("optimise.objective = {} needs a rotation-free scene (free or pure-twist) in scenes.run", objective.name());
            }
        }
        Objective::Torque => {
            if !(has(SceneKind::Blocked) || has(SceneKind::PureTwistBlocked)) {
                bail!("optimise.objective = torque needs a rotation-held scene (blocked or pure-twist-blocked) in scenes.run");
            }
        }
    }
    let space = DesignSpace::actuator();
    let policy = v.geometry.policy;
    let mut variables = Vec::new();
    if sec.variables.is_empty() {
        bail!("optimise.variables is empty (choose from {}, p_kPa)", space.names().join(", "));
    }
    for name in &sec.variables {
        if variables.iter().any(|x: &Variable| &x.name == name) {
            bail!("optimise.variables: '{name}' is listed twice");
        }
        if name == P_PRESSURE {
            variables.push(Variable { name: name.clone(), lower: sec.p_min_kpa, upper: p_max });
        } else {
            let ps = DesignSpace::lookup(name).ok_or_else(|| {
                anyhow!("optimise.variables: unknown variable '{name}' (expected {}, p_kPa, or the optional {})", space.names().join(", "), DesignSpace::optional().names().join(", "))
            })?;
            if policy != RangePolicy::TableI {
                bail!("optimise works in the Table-I box: set design.range = \"table1\"");
            }
            variables.push(Variable { name: name.clone(), lower: ps.min, upper: ps.max });
        }
    }
    if sec.optimisers.is_empty() {
        bail!("optimise.optimisers is empty (available: {})", available_optimisers().join(", "));
    }
    for o in &sec.optimisers {
        if optimiser(o).is_none() {
            bail!("optimise.optimisers: '{o}' is not available in this build (available: {})", available_optimisers().join(", "));
        }
    }
    if !(1..=64).contains(&sec.starts) {
        bail!("optimise.starts = {} must be between 1 and 64", sec.starts);
    }
    if !(sec.start_spread > 0.0 && sec.start_spread <= 1.0) {
        bail!("optimise.start_spread = {} must be in (0, 1]", sec.start_spread);
    }
    if let Some(p) = sec.start_p_kpa {
        if !(p >= sec.p_min_kpa && p <= p_max) {
            bail!("optimise.start_p_kPa = {p} must be within [optimise.p_min_kPa, load.p_max_kPa] = [{}, {p_max}]", sec.p_min_kpa);
        }
    }
    if !(2..=10_000).contains(&sec.max_evaluations) {
        bail!("optimise.max_evaluations = {} must be between 2 and 10000", sec.max_evaluations);
    }
    for (k, t) in [("xtol_rel", sec.xtol_rel), ("ftol_rel", sec.ftol_rel)] {
        if !(t.is_finite() && t > 0.0 && t < 1.0) {
            bail!("optimise.{k} = {t} must be in (0, 1)");
        }
    }
    if !(sec.ks_rho_per_mm.is_finite() && sec.ks_rho_per_mm > 0.0) {
        bail!("optimise.ks_rho_per_mm = {} must be finite and > 0", sec.ks_rho_per_mm);
    }
    let mut stages = Vec::new();
    for (k, st) in sec.stages.iter().enumerate() {
        let mesh = match (&st.preset, &st.mesh) {
            (Some(p), None) => crate::meshing::MeshSpec::preset(p).map_err(|e| anyhow!("optimise.stages[{k}].preset: {e}"))?,
            (None, Some(m)) => crate::meshing::MeshSpec::parse(m).map_err(|e| anyhow!("optimise.stages[{k}].mesh: {e}"))?,
            _ => bail!("optimise.stages[{k}]: give either preset or mesh"),
        };
        if !(1..=10_000).contains(&st.max_evaluations) {
            bail!("optimise.stages[{k}].max_evaluations = {} must be between 1 and 10000", st.max_evaluations);
        }
        let (xtol_rel, ftol_rel) = (st.xtol_rel.unwrap_or(sec.xtol_rel), st.ftol_rel.unwrap_or(sec.ftol_rel));
        for (key, t) in [("xtol_rel", xtol_rel), ("ftol_rel", ftol_rel)] {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                bail!("optimise.stages[{k}].{key} = {t} must be in (0, 1)");
            }
        }
        let rom = match &st.rom {
            None => None,
            Some(dir) => {
                let mut so = problem.scene_options(v);
                so.mesh = mesh;
                so.formulation = twistopt_solver::element::Formulation::standard(mesh.kind);
                let (r, m) = crate::rom::load(std::path::Path::new(dir), &so).map_err(|e| anyhow!("optimise.stages[{k}].rom: {e:#}"))?;
                if let Some(why) = v.scenes.iter().find_map(|&s| crate::rom::untrained_scene(&m.options.scenes, s)) {
                    bail!("optimise.stages[{k}].rom: {why}");
                }
                Some(StageRom { rom: std::sync::Arc::new(r), design_box: m.design_box.clone(), scenes: m.options.scenes.clone(), fallback: m.fallback_indicator })
            }
        };
        let label = st.preset.clone().or(st.mesh.clone()).unwrap_or_default();
        let label = if rom.is_some() { format!("{label} (reduced)") } else { label };
        stages.push(Stage { label, mesh, max_evaluations: st.max_evaluations, xtol_rel, ftol_rel, rom });
    }
    let budget: usize = stages.iter().map(|s| s.max_evaluations).sum();
    if budget > sec.max_evaluations {
        bail!("optimise.stages: the stages' max_evaluations sum to {budget}, more than optimise.max_evaluations = {} (the cap per run)", sec.max_evaluations);
    }
    let mut fixed = v.geometry.design.values.clone();
    fixed.insert(P_PRESSURE.into(), p_max);
    let opts = problem.scene_options(v);
    Ok((
        OptProblem {
            objective,
            scenes: v.scenes.clone(),
            variables,
            fixed,
            variant: v.geometry.design.variant,
            policy: RangePolicy::TableI,
            opts,
            ks_rho: sec.ks_rho_per_mm,
            ballooning_limit_mm: problem.scenes.ballooning_limit_mm,
            vacuum_kpa: sec.vacuum_kpa,
            max_evaluations: sec.max_evaluations,
            xtol_rel: sec.xtol_rel,
            ftol_rel: sec.ftol_rel,
            stages,
            stage: 0,
        },
        sec,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// maximise x0 + x1 on the disc x0² + x1² ≤ 0.5 in the unit box: optimum (0.5, 0.5), value 1,
    /// multiplier 1 (∇f = −(1, 1) = −λ ∇g, ∇g = (1, 1) there).
    fn disc(x: &[f64], _: Option<&Evaluation>) -> Evaluation {
        Evaluation::from_parts(x, -(x[0] + x[1]), vec![-1.0, -1.0], vec![x[0] * x[0] + x[1] * x[1] - 0.5], vec![vec![2.0 * x[0], 2.0 * x[1]]])
    }

    #[test]
    fn every_optimiser_solves_a_constrained_analytic_problem() {
        for name in available_optimisers() {
            let stop = StopRules { max_evaluations: 80, xtol_rel: 1e-6, ftol_rel: 1e-9 };
            let mut s = Session::with_evaluator(stop, 1, Box::new(disc));
            let status = optimiser(name).unwrap().run(&mut s, &[0.2, 0.7]);
            let b = s.best().unwrap_or_else(|| panic!("{name}: nothing feasible ({status})"));
            let e = &s.evaluations[b];
            assert!((e.objective - 1.0).abs() < 2e-3, "{name}: {} at {:?} ({status})", e.objective, e.x);
            assert!((e.x[0] - 0.5).abs() < 5e-3 && (e.x[1] - 0.5).abs() < 5e-3, "{name}: {:?}", e.x);
            let (kkt, lam) = kkt_measure(e, 1.0);
            assert!(kkt < 1e-2, "{name}: KKT {kkt}");
            assert!((lam[0] - 1.0).abs() < 2e-2, "{name}: multiplier {lam:?}");
            assert!(s.evaluations.len() <= 80, "{name}: {} evaluations", s.evaluations.len());
        }
    }

    /// A bound-constrained least-squares fit (no constraint block, as the letter calibration
    /// uses): min (x0 − 0.3)² + (x1 − 1.2)² on the unit box → (0.3, 1).
    #[test]
    fn every_optimiser_solves_a_bound_constrained_fit() {
        let fit = |x: &[f64], _: Option<&Evaluation>| {
            let (a, b) = (x[0] - 0.3, x[1] - 1.2);
            Evaluation::from_parts(x, a * a + b * b, vec![2.0 * a, 2.0 * b], vec![], vec![])
        };
        for name in available_optimisers() {
            let stop = StopRules { max_evaluations: 60, xtol_rel: 1e-8, ftol_rel: 1e-12 };
            let mut s = Session::with_evaluator(stop, 0, Box::new(fit));
            let status = optimiser(name).unwrap().run(&mut s, &[0.8, 0.1]);
            let e = s.evaluations.iter().min_by(|a, b| a.f.total_cmp(&b.f)).unwrap();
            assert!((e.x[0] - 0.3).abs() < 1e-4 && (e.x[1] - 1.0).abs() < 1e-6, "{name}: {:?} ({status})", e.x);
            assert!((e.f - 0.04).abs() < 1e-7, "{name}: f = {} ({status})", e.f);
        }
    }

    /// An interrupted run resumed from its recorded evaluations (through their JSON lines) asks
    /// for the same points, is answered from the record, and ends where the uninterrupted run
    /// ends, evaluating only what the record lacks.
    #[test]
    fn a_resumed_run_replays_its_record_and_ends_where_the_whole_run_ends() {
        for name in available_optimisers() {
            let stop = StopRules { max_evaluations: 40, xtol_rel: 1e-6, ftol_rel: 1e-9 };
            let mut whole = Session::with_evaluator(stop, 1, Box::new(disc));
            optimiser(name).unwrap().run(&mut whole, &[0.2, 0.7]);
            let n = whole.evaluations.len();
            assert!(n >= 4, "{name}: {n} evaluations");
            let record: Vec<Evaluation> = whole.evaluations[..n / 2].iter().map(|e| serde_json::from_str(&serde_json::to_string(e).unwrap()).unwrap()).collect();
            let calls = std::cell::Cell::new(0usize);
            let replays = std::cell::Cell::new(0usize);
            let mut resumed = Session::with_evaluator(
                stop,
                1,
                Box::new(|x: &[f64], l: Option<&Evaluation>| {
                    calls.set(calls.get() + 1);
                    disc(x, l)
                }),
            )
            .with_replay(record, |_| replays.set(replays.get() + 1));
            optimiser(name).unwrap().run(&mut resumed, &[0.2, 0.7]);
            assert_eq!(resumed.replayed, n / 2, "{name}: replayed");
            assert_eq!(replays.get(), n / 2, "{name}: replay callback");
            assert_eq!(resumed.evaluations.len(), n, "{name}: evaluation count");
            assert_eq!(calls.get(), n - n / 2, "{name}: fresh evaluations");
            let (a, b) = (&whole.evaluations[whole.best().unwrap()], &resumed.evaluations[resumed.best().unwrap()]);
            assert!(same_point(&a.x, &b.x) && a.objective == b.objective, "{name}: {:?} vs {:?}", a.x, b.x);
        }
    }

    #[test]
    fn kkt_measure_sees_bounds_and_interior_stationarity() {
        // at the upper bound with a gradient pushing out of the box: stationary
        let e = Evaluation::from_parts(&[1.0, 0.5], -1.0, vec![-2.0, 0.0], vec![-1.0], vec![vec![0.0, 1.0]]);
        assert!(kkt_measure(&e, 2.0).0 < 1e-12);
        // interior with a non-zero gradient: not stationary
        let e = Evaluation::from_parts(&[0.3, 0.5], -1.0, vec![-2.0, 0.0], vec![-1.0], vec![vec![0.0, 1.0]]);
        assert!((kkt_measure(&e, 2.0).0 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn kkt_measure_sees_stationarity_with_many_active_constraints() {
        // 12 interior variables, 12 active constraints g_k = x_k − c ≤ 0 and ∇f = −Σ λ_k e_k
        // with every λ_k = k + 1 > 0: stationary, which needs all 12 multipliers (the subset
        // enumeration covers the first 8 only)
        let n = 12;
        let df: Vec<f64> = (0..n).map(|k| -((k + 1) as f64)).collect();
        let dg: Vec<Vec<f64>> = (0..n).map(|k| (0..n).map(|i| if i == k { 1.0 } else { 0.0 }).collect()).collect();
        let e = Evaluation::from_parts(&vec![0.5; n], -1.0, df, vec![0.0; n], dg);
        let (m, lam) = kkt_measure(&e, 12.0);
        assert!(m < 1e-12, "{m}");
        for (k, l) in lam.iter().enumerate() {
            assert!((l - (k + 1) as f64).abs() < 1e-9, "λ_{k} = {l}");
        }
    }

    #[test]
    fn starting_points_in_many_dimensions_are_not_repeated_or_correlated() {
        // dimensions 0–3 are the plain Halton sequence in bases 2, 3, 5, 7 (the points every
        // ≤ 4-variable problem and the reduced models' training designs always had)
        let p = starting_points(24, 64);
        let plain = [0.5, 1.0 / 3.0, 0.2, 1.0 / 7.0];
        for (d, v) in plain.iter().enumerate() {
            assert!((p[0][d] - (0.1 + 0.8 * v)).abs() < 1e-15);
        }
        assert!((p[1][0] - (0.1 + 0.8 * 0.25)).abs() < 1e-15 && (p[1][1] - (0.1 + 0.8 * 2.0 / 3.0)).abs() < 1e-15);
        let col = |d: usize| p.iter().map(|x| x[d]).collect::<Vec<f64>>();
        let corr = |a: &[f64], b: &[f64]| {
            let m = a.len() as f64;
            let (ma, mb) = (a.iter().sum::<f64>() / m, b.iter().sum::<f64>() / m);
            let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
            let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
            let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
            cov / (va * vb).sqrt()
        };
        let mut worst: f64 = 0.0;
        for d in 0..24 {
            let a = col(d);
            assert!(a.iter().all(|v| (0.1..0.9).contains(v)), "dimension {d} leaves [0.1, 0.9]");
            // every dimension spreads over the interval: both halves hit
            assert!(a.iter().any(|&v| v < 0.4) && a.iter().any(|&v| v > 0.6), "dimension {d} does not spread");
            for e in 0..d {
                let b = col(e);
                assert!(a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 1e-9), "dimensions {d} and {e} repeat");
                worst = worst.max(corr(&a, &b).abs());
            }
        }
        // the unscrambled sequence has |correlation| ≈ 1.0 between bases 67 and 71 over 64 points
        assert!(worst < 0.5, "largest |correlation| between two dimensions: {worst}");
    }

    #[test]
    fn starting_points_are_inside_and_distinct() {
        let p = starting_points(4, 5);
        for (i, a) in p.iter().enumerate() {
            assert!(a.iter().all(|v| (0.1..=0.9).contains(v)));
            for b in &p[..i] {
                assert!(a.iter().zip(b).any(|(x, y)| (x - y).abs() > 0.05));
            }
        }
    }
}
