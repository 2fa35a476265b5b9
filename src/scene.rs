//! Actuator scenes: the actuator's FE model under the letter's boundary conditions.
//!
//! Every scene has the bottom end face fixed, the top end face tied to a rigid cap (reference
//! point on the axis at z = L), and the cavity pressure acting on the inner wall and — through the
//! closed-cavity formulation of the solver — on the cap (force p·A_in). With
//! [`SceneOptions::cap_load`] = false the cap carries no pressure (the pressure acts on the
//! lateral wall only, as on an open tube whose ends are merely tied to plates): the solver
//! removes the cap's share p·A_cap from the cap's axial translation (a dead load in z, exact while
//! the cap stays normal to z; see `twistopt_solver::surface`). The scenes differ only in which
//! cap DOFs are free:
//!
//! | scene | axial translation | rotation about z | output |
//! |---|---|---|---|
//! | `free` | free | free | θ(p), axial displacement |
//! | `blocked` | free | held | blocking torque τ(p) |
//! | `pure-twist` | held (rigid axle) | free | θ(p) |
//! | `pure-twist-blocked` | held | held | τ(p) |
//!
//! The loads are 3-fold symmetric, so by default a scene runs on the 120° sector with cyclic
//! constraints and only these two cap DOFs (the other four vanish by symmetry). The full 360°
//! model (`sector = false`) leaves the cap's lateral translations and tilts free as well, as a
//! rigid plate free in space would be.
//!
//! Sign conventions: θ is the cap rotation about +z (right-hand rule); τ is the torque the
//! actuator exerts on the cap about +z (what a torque sensor on the blocked cap reads), so a
//! blocked actuator that would twist by +θ pushes with τ > 0.

use crate::geometry::{ActuatorGeometry, L_TUBE, R0_ENVELOPE, T_WALL};
use crate::meshing::{build_mesh, ActuatorMesh, MeshError, MeshSpec};
use std::time::Instant;
use twistopt_solver::dofmap::{BodyDof, Constraints, Cyclic, DofSpec, RigidBody};
use twistopt_solver::element::Formulation;
use twistopt_solver::material::Material;
use twistopt_solver::model::{resultant, Assembled, Loads, Model, ModelError};
use twistopt_solver::solve::{follow_path, PathStatus, StepOptions};

/// Default bulk-to-shear modulus ratio κ/μ. Measured on the paper example (coarse sector, 40 kPa):
/// going from κ/μ = 300 to 3000 changes θ by 0.12 %, τ by 0.16 %, the axial displacement by
/// 0.43 % and the cavity volume by 0.08 % (a test keeps this under 0.5 %), while Newton needs
/// 3.4× fewer iterations than at 3000.
pub const DEFAULT_KAPPA_OVER_MU: f64 = 300.0;

/// The letter's shear modulus of Hei-Cast 8400 (MPa).
pub const MU_HEICAST_MPA: f64 = 0.34;

/// The four boundary-condition scenes of the letter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SceneKind {
    Free,
    Blocked,
    PureTwist,
    PureTwistBlocked,
}

impl SceneKind {
    pub const ALL: [SceneKind; 4] = [SceneKind::Free, SceneKind::Blocked, SceneKind::PureTwist, SceneKind::PureTwistBlocked];

    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Free => "free",
            SceneKind::Blocked => "blocked",
            SceneKind::PureTwist => "pure-twist",
            SceneKind::PureTwistBlocked => "pure-twist-blocked",
        }
    }

    pub fn parse(s: &str) -> Option<SceneKind> {
        SceneKind::ALL.into_iter().find(|k| k.name() == s)
    }

    /// Axial translation of the cap is free.
    pub fn axial_free(self) -> bool {
        matches!(self, SceneKind::Free | SceneKind::Blocked)
    }

    /// Rotation of the cap about the axis is free.
    pub fn rotation_free(self) -> bool {
        matches!(self, SceneKind::Free | SceneKind::PureTwist)
    }

    /// The cap's DOFs (tx, ty, tz, rx, ry, rz) for this scene.
    fn cap_dofs(self, sector: bool) -> [DofSpec; 6] {
        let lateral = if sector { DofSpec::Prescribed(0.0) } else { DofSpec::Free };
        let held = DofSpec::Prescribed(0.0);
        [
            lateral,
            lateral,
            if self.axial_free() { DofSpec::Free } else { held },
            lateral,
            lateral,
            if self.rotation_free() { DofSpec::Free } else { held },
        ]
    }
}

/// Everything that defines how a scene is discretised and solved.
#[derive(Clone, Debug)]
pub struct SceneOptions {
    pub mesh: MeshSpec,
    pub formulation: Formulation,
    pub material: Material,
    /// Run on the 120° sector with cyclic symmetry (default) or on the full model.
    pub sector: bool,
    /// Ballooning limit on the max deformed radius (mm); the letter's 1.15·R0 = 28.75.
    pub ballooning_limit_mm: f64,
    pub steps: StepOptions,
    /// Keep the nodal displacements of every recorded step (for VTU time series).
    pub keep_fields: bool,
    /// The cavity pressure also pushes on the cap (default true, the closed-cavity model); false =
    /// on the lateral wall only. It changes nothing where the cap's axial translation is held
    /// (pure-twist scenes) except the axial reaction.
    pub cap_load: bool,
}

impl SceneOptions {
    pub fn new(mesh: MeshSpec, material: Material) -> Self {
        SceneOptions {
            formulation: Formulation::standard(mesh.kind),
            mesh,
            material,
            sector: true,
            ballooning_limit_mm: 1.15 * R0_ENVELOPE,
            steps: StepOptions { initial: 0.25, max: 0.5, min: 1e-2, ..StepOptions::default() },
            keep_fields: false,
            cap_load: true,
        }
    }
}

/// Errors building a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("the unloaded model is not solvable: {0}")]
    Initial(String),
}

/// The FE model of one scene on one design.
pub struct SceneModel {
    pub kind: SceneKind,
    pub model: Model,
    /// full-model multiple of the modelled part (3 for the sector)
    pub multiplicity: f64,
    pub top_nodes: Vec<usize>,
    pub cavity_nodes: Vec<usize>,
    pub cap_reference: [f64; 3],
    /// index into `Loads::presc` of the cap rotation when it is prescribed
    pub rotation_slot: Option<usize>,
    pub mesh: ActuatorMesh,
}

/// One converged state of a scene.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StepRecord {
    #[serde(rename = "p_kPa")]
    pub p_kpa: f64,
    pub theta_deg: f64,
    pub axial_mm: f64,
    #[serde(rename = "tau_Nm")]
    pub tau_nm: f64,
    pub max_radius_mm: f64,
    pub cavity_volume_mm3: f64,
    #[serde(rename = "min_detF")]
    pub min_det_f: f64,
    pub newton_iterations: usize,
}

/// The result of a pressure ramp of one scene.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SceneResult {
    pub scene: String,
    /// `completed`, `ballooning`, `self-contact`, `limit-point`, `inversion`, `divergence`,
    /// `iteration-limit`, `step-limit`
    pub status: String,
    pub cause: String,
    pub steps: Vec<StepRecord>,
    pub dofs: usize,
    pub elements: usize,
    pub newton_iterations: usize,
    pub wall_time_s: f64,
    /// With `SceneOptions::keep_fields`: the mesh and the nodal displacements of each step
    /// (same order as `steps`).
    #[serde(skip)]
    pub fields: Option<SceneFields>,
}

/// Mesh and per-step displacement fields of a scene run.
#[derive(Clone, Debug)]
pub struct SceneFields {
    pub mesh: twistopt_solver::mesh::Mesh,
    pub formulation: Formulation,
    pub material: Material,
    pub displacements: Vec<Vec<[f64; 3]>>,
}

impl SceneFields {
    /// von Mises stress (MPa) per element for step k.
    pub fn von_mises(&self, k: usize) -> Vec<f64> {
        let rule = self.formulation.rule();
        let params = twistopt_solver::material::Hyperelastic::params(&self.material);
        (0..self.mesh.n_elements())
            .map(|e| {
                let conn = self.mesh.element(e);
                let x0: Vec<[f64; 3]> = conn.iter().map(|&n| self.mesh.nodes[n]).collect();
                let u: Vec<[f64; 3]> = conn.iter().map(|&n| self.displacements[k][n]).collect();
                twistopt_solver::element::mean_cauchy_stress(&self.formulation, &rule, &self.material, &params, &x0, &u)
                    .map(|s| twistopt_solver::element::von_mises(&s))
                    .unwrap_or(0.0)
            })
            .collect()
    }
}

impl SceneModel {
    pub fn build(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind) -> Result<SceneModel, SceneError> {
        let spec = opts.mesh.with_sector(opts.sector).with_kind(opts.formulation.kind);
        let am = build_mesh(geom, &spec)?;
        let mesh = am.mesh.clone();
        let mut cons = Constraints::default();
        cons.prescribe_set(&mesh.node_sets["bottom"], &[0, 1, 2], 0.0);
        let top_nodes = mesh.node_sets["top"].clone();
        let cap_reference = [0.0, 0.0, L_TUBE];
        cons.bodies.push(RigidBody {
            name: "cap".into(),
            reference: cap_reference,
            nodes: top_nodes.clone(),
            mask: [true; 3],
            dofs: kind.cap_dofs(opts.sector),
        });
        if opts.sector {
            cons.cyclic = Some(Cyclic { pairs: am.cyclic_pairs.clone(), angle: 2.0 * std::f64::consts::PI / 3.0 });
        }
        let cavity = mesh.face_sets["cavity"].clone();
        let cavity_nodes = mesh.node_sets["cavity"].clone();
        let mut model = Model::new(mesh, opts.formulation, opts.material, &cons, Some(&cavity))?;
        if !opts.cap_load {
            if let Some(c) = model.cavity.as_mut() {
                c.cap_load = false;
            }
        }
        let rotation_slot = match model.dofs.body_dofs[0][5] {
            BodyDof::Presc(s) => Some(s),
            BodyDof::Free(_) => None,
        };
        Ok(SceneModel {
            kind,
            model,
            multiplicity: if opts.sector { 3.0 } else { 1.0 },
            top_nodes,
            cavity_nodes,
            cap_reference,
            rotation_slot,
            mesh: am,
        })
    }

    /// Loads at pressure p (kPa) and prescribed cap rotation θ (rad).
    pub fn loads(&self, p_kpa: f64, theta_rad: f64) -> Loads {
        let mut l = Loads::zero(&self.model);
        l.pressure = p_kpa * 1e-3;
        if let Some(s) = self.rotation_slot {
            l.presc[s] = theta_rad;
        }
        l
    }

    /// Scene outputs of a converged state.
    pub fn record(&self, a: &Assembled, loads: &Loads, q: &[f64], newton_iterations: usize) -> StepRecord {
        let x0 = &self.model.mesh.nodes;
        let cap = &a.kin[0];
        let (_, m) = resultant(&self.top_nodes, x0, &a.u, &a.r_full, [
            self.cap_reference[0] + cap.c[0],
            self.cap_reference[1] + cap.c[1],
            self.cap_reference[2] + cap.c[2],
        ]);
        let max_radius = x0
            .iter()
            .zip(&a.u)
            .map(|(x, u)| ((x[0] + u[0]).powi(2) + (x[1] + u[1]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        let _ = q;
        StepRecord {
            p_kpa: loads.pressure * 1e3,
            theta_deg: cap.psi[2].to_degrees(),
            axial_mm: cap.c[2],
            tau_nm: -m[2] * self.multiplicity * 1e-3,
            max_radius_mm: max_radius,
            cavity_volume_mm3: a.volume * self.multiplicity,
            min_det_f: a.min_det_f,
            newton_iterations,
        }
    }

    /// Whether opposite cavity walls would touch: two cavity nodes that are far apart in the
    /// reference configuration (more than 2t) come closer than `gap` (an indicator for vacuum;
    /// contact itself is not modelled). Rotated copies of the sector are included.
    pub fn self_contact(&self, a: &Assembled, gap: f64) -> bool {
        let x0 = &self.model.mesh.nodes;
        let cur: Vec<([f64; 3], [f64; 3])> = self
            .cavity_nodes
            .iter()
            .map(|&n| (x0[n], [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1], x0[n][2] + a.u[n][2]]))
            .collect();
        let copies: Vec<f64> = if self.multiplicity > 1.0 { vec![0.0, 2.0 * std::f64::consts::PI / 3.0, -2.0 * std::f64::consts::PI / 3.0] } else { vec![0.0] };
        let far = 2.0 * T_WALL;
        for ang in copies {
            let (s, c) = ang.sin_cos();
            let rot = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
            for (i, (xi0, xi)) in cur.iter().enumerate() {
                for (xj0, xj) in cur.iter().skip(if ang == 0.0 { i + 1 } else { 0 }) {
                    let (xj0, xj) = (rot(*xj0), rot(*xj));
                    let d0 = dist(*xi0, xj0);
                    if d0 > far && dist(*xi, xj) < gap {
                        return true;
                    }
                }
            }
        }
        false
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// State carried along a ramp.
struct Ramp<'a> {
    sm: &'a SceneModel,
    opts: &'a SceneOptions,
    q: Vec<f64>,
    loads: Loads,
    steps: Vec<StepRecord>,
    fields: Vec<Vec<[f64; 3]>>,
    iterations: usize,
    gap: f64,
    /// smallest pressure step (kPa) of the step halving before a failure is accepted
    floor_kpa: f64,
}

impl<'a> Ramp<'a> {
    fn new(sm: &'a SceneModel, opts: &'a SceneOptions) -> Self {
        let hmesh = 2.0 * std::f64::consts::PI * 15.0 / (2.0 * sm.mesh.spec.n_around as f64);
        Ramp { sm, opts, q: vec![0.0; sm.model.n_reduced()], loads: sm.loads(0.0, 0.0), steps: Vec::new(), fields: Vec::new(), iterations: 0, gap: (0.25 * hmesh).min(0.5), floor_kpa: 0.1 }
    }

    /// Follow the loads to `to`; returns None when done, or the (status, cause) that ended it.
    fn go(&mut self, to: Loads) -> Option<(String, String)> {
        let sm = self.sm;
        let limit = self.opts.ballooning_limit_mm;
        let gap = self.gap;
        let mut stop_rec = Vec::new();
        let keep = self.opts.keep_fields;
        // smallest step: floor_kpa (or the options' fraction if finer), whatever the segment length
        let mut steps_opts = self.opts.steps.clone();
        let span = ((to.pressure - self.loads.pressure).abs() * 1e3).max(1e-9);
        steps_opts.min = steps_opts.min.min(self.floor_kpa / span).max(1e-6);
        let mut fields = Vec::new();
        let res = follow_path(&sm.model, &self.q, &self.loads, &to, &steps_opts, |info| {
            let rec = sm.record(info.assembled, info.loads, info.q, info.newton_iterations);
            let over = rec.max_radius_mm > limit;
            let contact = info.loads.pressure < 0.0 && sm.self_contact(info.assembled, gap);
            stop_rec.push(rec);
            if keep {
                fields.push(info.assembled.u.clone());
            }
            if over {
                Some("ballooning".to_string())
            } else if contact {
                Some("self-contact".to_string())
            } else {
                None
            }
        });
        self.steps.extend(stop_rec);
        self.fields.extend(fields);
        self.iterations += res.newton_iterations;
        self.q = res.q;
        self.loads = res.loads;
        match res.status {
            PathStatus::Completed => None,
            PathStatus::Stopped(reason) => {
                let cause = if reason == "ballooning" {
                    format!("max deformed radius exceeded the ballooning limit {limit:.2} mm")
                } else {
                    format!("two cavity walls came closer than {gap:.2} mm (contact is not modelled)")
                };
                Some((reason, cause))
            }
            PathStatus::Failed(f) => {
                let p = self.loads.pressure * 1e3;
                let cause = match f {
                    twistopt_solver::solve::FailureCause::LimitPoint => format!("tangent lost positive definiteness beyond p = {p:.3} kPa (pressure maximum / instability)"),
                    twistopt_solver::solve::FailureCause::Inversion => format!("an element inverted beyond p = {p:.3} kPa"),
                    twistopt_solver::solve::FailureCause::Divergence => format!("Newton diverged beyond p = {p:.3} kPa at the smallest step"),
                    twistopt_solver::solve::FailureCause::IterationLimit => format!("Newton hit its iteration limit beyond p = {p:.3} kPa at the smallest step"),
                    twistopt_solver::solve::FailureCause::StepLimit => format!("step limit reached at p = {p:.3} kPa"),
                };
                Some((f.as_str().to_string(), cause))
            }
        }
    }
}

/// A converged state of a scene at one pressure (for sensitivities and warm starts).
pub struct Equilibrium {
    pub q: Vec<f64>,
    pub loads: Loads,
    /// the last converged state's record (its pressure is the target unless `end` is set)
    pub record: StepRecord,
    pub newton_iterations: usize,
    /// why the ramp ended before the target (status, cause); None = target reached
    pub end: Option<(String, String)>,
    /// whether the warm start was used (Newton straight from the given state converged)
    pub warm_started: bool,
}

/// The equilibrium of a scene at pressure `p_kpa`, without the ballooning stop (the caller
/// constrains the radius). With `warm` = (q, p_warm), a converged state of a nearby design (same
/// mesh topology) at pressure p_warm, Newton first solves the new design at p_warm from q and the
/// pressure then follows from p_warm to p_kpa (a short continuation); if that first solve fails,
/// the pressure is ramped from the unloaded state.
pub fn equilibrium(sm: &SceneModel, opts: &SceneOptions, p_kpa: f64, warm: Option<(&[f64], f64)>) -> Equilibrium {
    let target = sm.loads(p_kpa, 0.0);
    let mut o = opts.clone();
    o.ballooning_limit_mm = f64::INFINITY;
    o.keep_fields = false;
    let mut iterations = 0;
    if let Some((w, pw)) = warm.filter(|w| w.0.len() == sm.model.n_reduced() && w.1.is_finite()) {
        let mut q = w.to_vec();
        let start = sm.loads(pw, 0.0);
        match twistopt_solver::solve::newton(&sm.model, &mut q, &start, &opts.steps.newton) {
            Ok((stats, a)) => {
                iterations += stats.iterations;
                if pw == p_kpa {
                    let record = sm.record(&a, &target, &q, stats.iterations);
                    return Equilibrium { q, loads: target, record, newton_iterations: iterations, end: None, warm_started: true };
                }
                let mut ramp = Ramp::new(sm, &o);
                ramp.q = q;
                ramp.loads = start;
                let end = ramp.go(target);
                let record = ramp.steps.last().cloned().unwrap_or_else(|| sm.record(&a, &ramp.loads, &ramp.q, 0));
                return Equilibrium { q: ramp.q, loads: ramp.loads, record, newton_iterations: iterations + ramp.iterations, end, warm_started: true };
            }
            Err(_) => iterations += opts.steps.newton.max_iter,
        }
    }
    let mut ramp = Ramp::new(sm, &o);
    let end = ramp.go(target);
    let record = match ramp.steps.last() {
        Some(r) => r.clone(),
        None => {
            let l0 = sm.loads(0.0, 0.0);
            let a = sm.model.assemble(&ramp.q, &l0, false);
            match a {
                Ok(a) => sm.record(&a, &l0, &ramp.q, 0),
                Err(_) => StepRecord { p_kpa: 0.0, theta_deg: 0.0, axial_mm: 0.0, tau_nm: 0.0, max_radius_mm: 0.0, cavity_volume_mm3: 0.0, min_det_f: 1.0, newton_iterations: 0 },
            }
        }
    };
    Equilibrium { q: ramp.q, loads: ramp.loads, record, newton_iterations: iterations + ramp.iterations, end, warm_started: false }
}

/// Continue an equilibrium's pressure upward to `p_cap` (kPa) without the ballooning stop:
/// `BelowCap` when it reaches the cap, else the last stable state (the pressure maximum, for a
/// limit point) with the failure in `end`.
///
/// The pressure maximum is located under volume control ([`pressure_maximum`]: exact to 1e-6
/// relative, about half the cost); when that cannot decide (a bifurcation, Newton failures) the
/// pressure ramp with step halving to 0.1 kPa is used instead.
pub fn continue_to_failure(sm: &SceneModel, opts: &SceneOptions, from: &Equilibrium, p_cap: f64) -> LimitOutcome {
    if from.end.is_some() || p_cap <= from.loads.pressure * 1e3 {
        return LimitOutcome::BelowCap { newton_iterations: 0 };
    }
    let mut spent = 0;
    match pressure_maximum(sm, from, p_cap, &opts.steps.newton) {
        Ok(found) => return found,
        Err(iterations) => spent += iterations,
    }
    let mut o = opts.clone();
    o.ballooning_limit_mm = f64::INFINITY;
    o.keep_fields = false;
    let mut ramp = Ramp::new(sm, &o);
    ramp.q = from.q.clone();
    ramp.loads = from.loads.clone();
    let Some(end) = ramp.go(sm.loads(p_cap, 0.0)) else {
        return LimitOutcome::BelowCap { newton_iterations: spent + ramp.iterations };
    };
    let record = ramp.steps.last().cloned().unwrap_or_else(|| from.record.clone());
    LimitOutcome::Found(Equilibrium { q: ramp.q, loads: ramp.loads, record, newton_iterations: spent + ramp.iterations, end: Some(end), warm_started: false })
}

/// What a search for the failure above an equilibrium found.
pub enum LimitOutcome {
    /// the last stable state (at the pressure maximum for a fold), with the failure in `end`
    Found(Equilibrium),
    /// the pressure reached the cap without failing
    BelowCap { newton_iterations: usize },
}

impl LimitOutcome {
    pub fn found(&self) -> Option<&Equilibrium> {
        match self {
            LimitOutcome::Found(e) => Some(e),
            LimitOutcome::BelowCap { .. } => None,
        }
    }
    pub fn newton_iterations(&self) -> usize {
        match self {
            LimitOutcome::Found(e) => e.newton_iterations,
            LimitOutcome::BelowCap { newton_iterations } => *newton_iterations,
        }
    }
}

/// Step floor (kPa) of a positive pressure ramp before the volume-controlled search for the
/// pressure maximum takes over.
pub const COARSE_FLOOR_KPA: f64 = 2.0;

/// A converged volume-controlled state with its pressure slope dp/dV = 1/(gᵀK⁻¹g).
struct VolState {
    q: Vec<f64>,
    p: f64,
    v: f64,
    slope: f64,
    /// the fixed-pressure tangent is positive definite (stable under pressure control)
    pd: bool,
    a: Assembled,
}

fn vol_state(sm: &SceneModel, q: Vec<f64>, p: f64, a: Assembled) -> Option<VolState> {
    let k = a.k.as_ref()?;
    let (fac, pd) = match sm.model.factor(k) {
        Ok(f) => (f, true),
        Err(_) => (sm.model.factor_indefinite(k).ok()?, false),
    };
    let b = fac.solve(&a.dvol).ok()?;
    let c: f64 = a.dvol.iter().zip(&b).map(|(g, x)| g * x).sum();
    let slope = 1.0 / c;
    (slope.is_finite() && a.volume.is_finite()).then(|| VolState { q, p, v: a.volume, slope, pd, a })
}

/// The pressure maximum above a converged, stable equilibrium, located under volume control
/// (the cavity volume prescribed, the pressure an unknown; `solve::newton_volume`), where the
/// path passes the maximum smoothly instead of failing at it. At each converged state the slope
/// dp/dV = 1/(gᵀK⁻¹g) (g = ∂V/∂q) is known, so the maximum (dp/dV = 0) is found by secant steps
/// on the slope, typically in 4–8 volume-controlled Newton solves, to |Δp| ≤ 1e-6·p.
///
/// Returns `BelowCap` when the pressure passes `p_cap_kpa` with no maximum below it; `Found`
/// with the state at the maximum (status `limit-point`) — or, when the tangent loses positive
/// definiteness while the pressure still rises (a bifurcation, not a fold), the last stable state
/// found by bisecting the volume (to 1e-4 relative in p); `Err(newton_iterations_spent)` when the
/// volume-controlled path cannot decide (Newton failures): the caller falls back to the ramp.
pub fn pressure_maximum(sm: &SceneModel, from: &Equilibrium, p_cap_kpa: f64, newton: &twistopt_solver::solve::NewtonOptions) -> Result<LimitOutcome, usize> {
    pressure_maximum_path(sm, from, p_cap_kpa, newton, f64::INFINITY, &mut Vec::new())
}

/// As [`pressure_maximum`], also recording the stable states it passes (rising pressure, in
/// order, with their displacement fields; the final state included) in `path`, and stopping with status `ballooning` at the first whose max radius exceeds
/// `ballooning_limit_mm`.
pub fn pressure_maximum_path(
    sm: &SceneModel,
    from: &Equilibrium,
    p_cap_kpa: f64,
    newton: &twistopt_solver::solve::NewtonOptions,
    ballooning_limit_mm: f64,
    path: &mut Vec<(StepRecord, Vec<[f64; 3]>)>,
) -> Result<LimitOutcome, usize> {
    if from.end.is_some() || p_cap_kpa <= from.loads.pressure * 1e3 {
        return Ok(LimitOutcome::BelowCap { newton_iterations: 0 });
    }
    let base = from.loads.clone();
    let cap = p_cap_kpa * 1e-3;
    let a0 = sm.model.assemble(&from.q, &base, true).map_err(|_| 0usize)?;
    let s0 = vol_state(sm, from.q.clone(), base.pressure, a0).ok_or(0usize)?;
    if !s0.pd || s0.slope <= 0.0 {
        return Err(0);
    }
    let mut iterations = 0usize;
    let mut prev: Option<VolState> = None;
    let mut last = s0;
    let v_ref = last.v.abs().max(1e-12);
    // first volume step: the linear prediction of half the way to the cap, at most 5 % of V
    // volume step bound: starts at the linear volume change of 2 % of the pressure (≥ 0.5 kPa),
    // grows ×1.5 after easy solves, halves after failures
    let mut dv_max = ((0.02 * last.p).max(0.5e-3) / last.slope).min(0.05 * v_ref);
    let mut converged = false;
    for _ in 0..40 {
        // next target volume: the zero of the slope's secant (p(V) concave near a maximum)
        let mut v_next = last.v + dv_max;
        if let Some(pv) = &prev {
            let curv = (last.slope - pv.slope) / (last.v - pv.v);
            if curv < 0.0 && curv.is_finite() {
                v_next = last.v - last.slope / curv;
            } else if last.slope < 0.0 {
                v_next = last.v - dv_max;
            }
        }
        // the pressure error of the best state: |Δp| ≈ ½|slope·(V* − V)|
        if prev.is_some() && 0.5 * (v_next - last.v).abs() * last.slope.abs() <= 1e-6 * last.p.abs() {
            converged = true;
            break;
        }
        v_next = v_next.clamp(last.v - dv_max, last.v + dv_max);
        let mut solved = None;
        let mut step = v_next - last.v;
        for _cut in 0..6 {
            let (mut q, mut p) = (last.q.clone(), last.p);
            match twistopt_solver::solve::newton_volume(&sm.model, &mut q, &mut p, &base, last.v + step, newton) {
                Ok((st, a)) => {
                    iterations += st.iterations;
                    if st.iterations <= 5 {
                        dv_max = (1.5 * dv_max).max(1.5 * step.abs());
                    }
                    solved = Some((q, p, a));
                    break;
                }
                Err(_) => {
                    iterations += newton.max_iter.min(5);
                    step *= 0.5;
                    dv_max = 0.5 * step.abs().max(dv_max * 0.5);
                }
            }
        }
        let (q, p, a) = solved.ok_or(iterations)?;
        let st = vol_state(sm, q, p, a).ok_or(iterations)?;
        if std::env::var_os("TWISTOPT_TRACE").is_some() {
            eprintln!("[pmax] V {:.6e} → {:.6e}: p {:.5} kPa slope {:.4e} pd {} ({} its total)", last.v, st.v, st.p * 1e3, st.slope, st.pd, iterations);
        }
        if st.p > cap && st.slope > 0.0 {
            return Ok(LimitOutcome::BelowCap { newton_iterations: iterations });
        }
        if st.pd && st.slope > 0.0 && path.last().map_or(st.p > base.pressure, |r| st.p * 1e3 > r.0.p_kpa) {
            let (_, rec) = vol_record(sm, &base, &st, iterations);
            if rec.max_radius_mm > ballooning_limit_mm {
                let cause = format!("max deformed radius exceeded the ballooning limit {ballooning_limit_mm:.2} mm");
                return Ok(vol_found(sm, &base, st, iterations, ("ballooning".into(), cause), path));
            }
            path.push((rec, st.a.u.clone()));
        }
        if !st.pd && st.slope > 0.0 {
            // stability lost with the pressure still rising: a bifurcation, not a pressure maximum.
            // Bisect the volume for the last stable state (the point a pressure ramp fails at).
            let (mut good, mut bad_v) = (last, st.v);
            for _ in 0..8 {
                if (bad_v - good.v).abs() * good.slope <= 1e-4 * good.p.abs() {
                    break;
                }
                let vm = 0.5 * (good.v + bad_v);
                let (mut q, mut p) = (good.q.clone(), good.p);
                match twistopt_solver::solve::newton_volume(&sm.model, &mut q, &mut p, &base, vm, newton) {
                    Ok((it, a)) => {
                        iterations += it.iterations;
                        match vol_state(sm, q, p, a) {
                            Some(m) if m.pd => good = m,
                            Some(_) => bad_v = vm,
                            None => break,
                        }
                    }
                    Err(_) => {
                        iterations += newton.max_iter.min(5);
                        break;
                    }
                }
            }
            let cause = format!("the tangent loses positive definiteness beyond p = {:.4} kPa with the pressure still rising (a bifurcation; located under volume control)", good.p * 1e3);
            return Ok(vol_found(sm, &base, good, iterations, ("limit-point".into(), cause), path));
        }
        // keep the new state and, of the two before, the one closer to the maximum
        let old = std::mem::replace(&mut last, st);
        let keep_old = match &prev {
            Some(pv) => old.slope.abs() <= pv.slope.abs() || old.slope * last.slope < 0.0,
            None => true,
        };
        if keep_old {
            prev = Some(old);
        }
        if let Some(pv) = &prev {
            if pv.slope.abs() < last.slope.abs() {
                let pv2 = prev.take().expect("checked");
                prev = Some(std::mem::replace(&mut last, pv2));
            }
        }
    }
    if !converged || last.slope.abs() * v_ref > 0.05 * last.p.abs() {
        return Err(iterations);
    }
    let cause = format!("pressure maximum at p = {:.4} kPa (located under volume control)", last.p * 1e3);
    Ok(vol_found(sm, &base, last, iterations, ("limit-point".into(), cause), path))
}

/// The loads and scene record of a volume-controlled state (the other loads as in `base`).
fn vol_record(sm: &SceneModel, base: &Loads, st: &VolState, iterations: usize) -> (Loads, StepRecord) {
    let mut loads = sm.loads(st.p * 1e3, 0.0);
    loads.presc = base.presc.clone();
    let record = sm.record(&st.a, &loads, &st.q, iterations);
    (loads, record)
}

/// A volume-controlled state as the end of a path (appended to `path` unless already there).
fn vol_found(sm: &SceneModel, base: &Loads, st: VolState, iterations: usize, end: (String, String), path: &mut Vec<(StepRecord, Vec<[f64; 3]>)>) -> LimitOutcome {
    let (loads, record) = vol_record(sm, base, &st, iterations);
    if path.last().map_or(true, |r| r.0.p_kpa < record.p_kpa) {
        path.push((record.clone(), st.a.u));
    }
    LimitOutcome::Found(Equilibrium { q: st.q, loads, record, newton_iterations: iterations, end: Some(end), warm_started: false })
}

/// Ramp a scene's pressure through the given targets (kPa). Positive and negative targets are
/// two branches, each ramped from the unloaded state through its targets in order of magnitude;
/// a branch ends at its last target, at the ballooning limit, at self-contact (vacuum) or at a
/// solver failure. Steps are returned sorted by pressure.
pub fn run_pressure(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, targets_kpa: &[f64]) -> Result<SceneResult, SceneError> {
    let t0 = Instant::now();
    let sm = SceneModel::build(geom, opts, kind)?;
    let mut pos: Vec<f64> = targets_kpa.iter().copied().filter(|p| *p > 0.0).collect();
    let mut neg: Vec<f64> = targets_kpa.iter().copied().filter(|p| *p < 0.0).collect();
    pos.sort_by(|a, b| a.partial_cmp(b).unwrap());
    neg.sort_by(|a, b| b.partial_cmp(a).unwrap());
    let mut steps = Vec::new();
    let mut fields: Vec<Vec<[f64; 3]>> = Vec::new();
    let mut status = ("completed".to_string(), String::new());
    let mut iterations = 0;
    // the unloaded state
    {
        let l0 = sm.loads(0.0, 0.0);
        let a = sm.model.assemble(&vec![0.0; sm.model.n_reduced()], &l0, false).map_err(|e| SceneError::Initial(e.to_string()))?;
        steps.push(sm.record(&a, &l0, &[], 0));
        fields.push(a.u.clone());
    }
    for branch in [pos, neg] {
        if branch.is_empty() {
            continue;
        }
        let mut ramp = Ramp::new(&sm, opts);
        let mut end = None;
        let positive = branch[0] > 0.0;
        let p_last = *branch.last().expect("non-empty");
        if positive {
            // a failure is first detected with a coarse step floor, then pinned under volume control
            ramp.floor_kpa = COARSE_FLOOR_KPA;
        }
        let mut i = 0;
        while i < branch.len() {
            let Some(e) = ramp.go(sm.loads(branch[i], 0.0)) else {
                i += 1;
                continue;
            };
            if positive && ramp.floor_kpa > 0.1 && !matches!(e.0.as_str(), "ballooning" | "self-contact") {
                let eq = Equilibrium { q: ramp.q.clone(), loads: ramp.loads.clone(), record: ramp.steps.last().cloned().unwrap_or_else(|| steps[0].clone()), newton_iterations: 0, end: None, warm_started: false };
                let mut path = Vec::new();
                match pressure_maximum_path(&sm, &eq, p_last, &opts.steps.newton, opts.ballooning_limit_mm, &mut path) {
                    Ok(LimitOutcome::Found(m)) => {
                        ramp.iterations += m.newton_iterations;
                        for (rec, u) in path {
                            ramp.steps.push(rec);
                            if opts.keep_fields {
                                ramp.fields.push(u);
                            }
                        }
                        end = m.end;
                        break;
                    }
                    Ok(LimitOutcome::BelowCap { newton_iterations }) | Err(newton_iterations) => {
                        // undecided: resume the pressure ramp with the fine floor
                        ramp.iterations += newton_iterations;
                        ramp.floor_kpa = 0.1;
                        continue;
                    }
                }
            }
            end = Some(e);
            break;
        }
        steps.extend(ramp.steps);
        fields.extend(ramp.fields);
        iterations += ramp.iterations;
        if let Some(e) = end {
            // the positive branch's end is the scene's status unless it completed
            if status.0 == "completed" {
                status = e;
            }
        }
    }
    let mut order: Vec<usize> = (0..steps.len()).collect();
    order.sort_by(|&a, &b| steps[a].p_kpa.total_cmp(&steps[b].p_kpa));
    let steps: Vec<StepRecord> = order.iter().map(|&i| steps[i].clone()).collect();
    let fields = if opts.keep_fields {
        Some(SceneFields {
            mesh: sm.model.mesh.clone(),
            formulation: opts.formulation,
            material: opts.material,
            displacements: order.iter().map(|&i| fields[i].clone()).collect(),
        })
    } else {
        None
    };
    Ok(SceneResult {
        scene: kind.name().to_string(),
        status: status.0,
        cause: status.1,
        steps,
        dofs: sm.model.n_reduced(),
        elements: sm.model.mesh.n_elements(),
        newton_iterations: iterations,
        wall_time_s: t0.elapsed().as_secs_f64(),
        fields,
    })
}

/// Torque at prescribed cap rotations from 0 to the free rotation, at one pressure.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TorqueRotation {
    #[serde(rename = "p_kPa")]
    pub p_kpa: f64,
    pub free_theta_deg: f64,
    /// (θ in degrees, τ in N·m)
    pub points: Vec<(f64, f64)>,
    /// max |τ − line through the end points| / |τ(0)|
    pub nonlinearity: f64,
    pub status: String,
}

/// The letter's Fig. 4b: for each pressure, the free rotation θ_f (from the `free` scene when
/// `axial_free`, else `pure-twist`), then τ at `n_points` rotations from 0 to θ_f.
pub fn run_torque_rotation(
    geom: &ActuatorGeometry,
    opts: &SceneOptions,
    axial_free: bool,
    pressures_kpa: &[f64],
    n_points: usize,
) -> Result<Vec<TorqueRotation>, SceneError> {
    let (free_kind, held_kind) = if axial_free { (SceneKind::Free, SceneKind::Blocked) } else { (SceneKind::PureTwist, SceneKind::PureTwistBlocked) };
    let free = SceneModel::build(geom, opts, free_kind)?;
    let held = SceneModel::build(geom, opts, held_kind)?;
    let mut out = Vec::new();
    for &p in pressures_kpa {
        let mut rf = Ramp::new(&free, opts);
        let fe = rf.go(free.loads(p, 0.0));
        let theta_f = rf.steps.last().map(|s| s.theta_deg).unwrap_or(0.0);
        if fe.is_some() {
            out.push(TorqueRotation { p_kpa: p, free_theta_deg: theta_f, points: vec![], nonlinearity: 0.0, status: fe.unwrap().0 });
            continue;
        }
        let mut rh = Ramp::new(&held, opts);
        let mut status = "completed".to_string();
        let mut pts = Vec::new();
        if let Some(e) = rh.go(held.loads(p, 0.0)) {
            status = e.0;
        } else {
            pts.push((0.0, rh.steps.last().map(|s| s.tau_nm).unwrap_or(0.0)));
            for k in 1..=n_points.max(1) {
                let th = theta_f * k as f64 / n_points.max(1) as f64;
                rh.steps.clear();
                if let Some(e) = rh.go(held.loads(p, th.to_radians())) {
                    status = e.0;
                    break;
                }
                pts.push((th, rh.steps.last().map(|s| s.tau_nm).unwrap_or(0.0)));
            }
        }
        let nonlinearity = match (pts.first(), pts.last()) {
            (Some(a), Some(b)) if pts.len() > 2 && a.1.abs() > 0.0 => pts
                .iter()
                .map(|(t, tau)| {
                    let line = a.1 + (b.1 - a.1) * (t - a.0) / (b.0 - a.0);
                    (tau - line).abs() / a.1.abs()
                })
                .fold(0.0, f64::max),
            _ => 0.0,
        };
        out.push(TorqueRotation { p_kpa: p, free_theta_deg: theta_f, points: pts, nonlinearity, status });
    }
    Ok(out)
}

/// The letter's energy density Ω = τθ/(8V), V = πR0²L (θ in rad, τ in N·m, V in m³) → J/m³.
pub fn energy_density(theta_deg: f64, tau_nm: f64) -> f64 {
    let v_m3 = std::f64::consts::PI * R0_ENVELOPE * R0_ENVELOPE * L_TUBE * 1e-9;
    tau_nm * theta_deg.to_radians() / (8.0 * v_m3)
}
