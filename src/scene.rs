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
use twistopt_solver::adjoint::Functional;
use twistopt_solver::continuation::{correct, follow, follow_from, follow_snapping, ContinuationOptions, Control, LoadPath, PathEnd, PathStats, PointKind, SnapOptions, Solved, Stop};
use twistopt_solver::dofmap::{BodyDof, Constraints, Cyclic, DofSpec, RigidBody};
use twistopt_solver::element::Formulation;
use twistopt_solver::material::Material;
use twistopt_solver::model::{Assembled, Factor, Loads, Model, ModelError};
use twistopt_solver::solve::FailureCause;

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
        [lateral, lateral, if self.axial_free() { DofSpec::Free } else { held }, lateral, lateral, if self.rotation_free() { DofSpec::Free } else { held }]
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
    /// path-following options (step control, Newton tolerances, event location)
    pub steps: ContinuationOptions,
    /// Keep the nodal displacements of every recorded step (for VTU time series).
    pub keep_fields: bool,
    /// The cavity pressure also pushes on the cap (default true, the closed-cavity model); false =
    /// on the lateral wall only. It changes nothing where the cap's axial translation is held
    /// (pure-twist scenes) except the axial reaction.
    pub cap_load: bool,
    /// Solve with this reduced-order model instead of the full one (`rom` fidelity): path states
    /// are then its reduced coordinates.
    pub rom: Option<std::sync::Arc<twistopt_solver::rom::Rom>>,
    /// the design box the reduced model was trained on: a design outside it is refused
    pub rom_box: Vec<crate::geometry::ParamSpec>,
    /// the scenes the reduced model was trained on: another scene is refused (its constraints
    /// select other modes; empty: not checked)
    pub rom_scenes: Vec<SceneKind>,
    /// At `rom` fidelity: a scene whose reduced ramp ends with an error indicator above this
    /// value, or in a solver failure (divergence, iteration or step limit), is run again on the
    /// full model (None: never).
    pub rom_fallback: Option<f64>,
    /// Frictionless self-contact of the cavity wall (the neighbouring sectors' walls included,
    /// as rotated copies): None = not modelled (a vacuum path then stops where two cavity walls
    /// come within the contact gap).
    pub contact: Option<ContactOptions>,
}

/// The cavity's self-contact ([`twistopt_solver::contact`]): the barrier's reach d̂, the contact
/// pressure at the gap d̂/10 (which sets the barrier stiffness κ), and the reference distance
/// within which wall triangles are candidates of a wall node (beyond its own two rings of
/// triangles and what lies within one wall thickness t both in space and along the surface,
/// [`twistopt_solver::contact::self_contact`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactOptions {
    #[serde(default = "default_dhat_mm")]
    pub dhat_mm: f64,
    #[serde(rename = "pressure_MPa", default = "default_contact_pressure")]
    pub pressure_mpa: f64,
    #[serde(default = "default_reach_mm")]
    pub reach_mm: f64,
    /// the width of the band over which neighbouring wall triangles' distances are blended
    #[serde(default = "default_blend_mm")]
    pub blend_mm: f64,
    /// The radius of the rigid axle that the pure-twist scenes embed along the axis (the letter's
    /// "rigid axle ... inside the actuator"; it gives no radius): the cavity wall's contact with
    /// it, frictionless, by the same barrier. None: the axle holds the caps' axial motion only.
    /// Other scenes have no axle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axle_radius_mm: Option<f64>,
    /// End a vacuum ramp where an element first folds between its quadrature points (located on
    /// the path; status `inversion`): past it the mesh does not represent the wall (the element
    /// covers some points twice and its faces pass through its neighbours'). false: go on and
    /// record each step's `folded_elements` and `penetration_mm`.
    #[serde(default = "default_true")]
    pub stop_at_fold: bool,
}

fn default_true() -> bool {
    true
}

fn default_dhat_mm() -> f64 {
    0.1
}

fn default_contact_pressure() -> f64 {
    0.1
}

fn default_reach_mm() -> f64 {
    // the walls that meet in the collapse are up to a cavity's width apart; with 8 mm the
    // example design's walls passed through each other past −47 kPa (coarse mesh: the cavity
    // volume went negative), with 20 mm they did not
    20.0
}

fn default_blend_mm() -> f64 {
    // (the coarse example's shortest cavity triangle edge is 0.43 mm: well inside it)
    0.02
}

impl Default for ContactOptions {
    fn default() -> Self {
        ContactOptions { dhat_mm: default_dhat_mm(), pressure_mpa: default_contact_pressure(), reach_mm: default_reach_mm(), blend_mm: default_blend_mm(), axle_radius_mm: None, stop_at_fold: true }
    }
}

impl ContactOptions {
    /// The barrier: κ such that κ·|b'(d̂/10)| = pressure.
    pub fn barrier(&self) -> twistopt_solver::contact::Barrier {
        let unit = twistopt_solver::contact::Barrier { dhat: self.dhat_mm, kappa: 1.0 };
        twistopt_solver::contact::Barrier { dhat: self.dhat_mm, kappa: self.pressure_mpa / unit.pressure(0.1 * self.dhat_mm) }
    }
}

impl SceneOptions {
    pub fn new(mesh: MeshSpec, material: Material) -> Self {
        SceneOptions {
            formulation: Formulation::standard(mesh.kind),
            mesh,
            material,
            sector: true,
            ballooning_limit_mm: 1.15 * R0_ENVELOPE,
            steps: ContinuationOptions::default(),
            keep_fields: false,
            cap_load: true,
            rom: None,
            rom_box: Vec::new(),
            rom_scenes: Vec::new(),
            rom_fallback: None,
            contact: None,
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
    #[error("{0}")]
    OutsideRom(String),
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
    /// the last [`SceneModel::integrity`]: (the displacements' bit pattern hash, result), so
    /// that the two output slots of one state measure it once
    integrity_cache: std::sync::Mutex<Option<(u64, Integrity)>>,
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
    /// With self-contact modelled: the smallest signed distance of a cavity node to the cavity
    /// wall it may touch (mm; ≥ 0: no interpenetration).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_distance_mm: Option<f64>,
    /// With self-contact modelled: the deepest point of the cavity surface inside the material of
    /// another element (mm; 0: none), measured on the elements' own quadratic faces, between the
    /// nodes included ([`SceneModel::integrity`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub penetration_mm: Option<f64>,
    /// With self-contact modelled: how many elements' maps fold between their quadrature points
    /// (det J ≤ 0 somewhere; [`SceneModel::integrity`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub folded_elements: Option<usize>,
    /// With self-contact modelled: the least det ∂x/∂ξ of any element relative to its centre's
    /// (on a 9³ grid; ≤ 0: an element folds, and a vacuum ramp ends there unless
    /// `scenes.contact.stop_at_fold = false`; [`SceneModel::integrity`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub least_jacobian_ratio: Option<f64>,
    /// The state was reached by a snap (a jump past a lost stability under the pressure supply),
    /// not along a continuous path from the one before.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub snapped: bool,
}

/// How a scene's load path ended (serialised as the kebab-case names).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SceneStatus {
    /// the last target was reached
    Completed,
    /// the max deformed radius reached the ballooning limit (located on the path)
    Ballooning,
    /// two cavity walls came together under vacuum (contact is not modelled)
    SelfContact,
    /// a pressure maximum (fold) or a loss of stability with the pressure rising (bifurcation)
    LimitPoint,
    Inversion,
    Divergence,
    IterationLimit,
    StepLimit,
    /// a state at the requested pressure (gradients)
    Converged,
    /// the adjoint could not be evaluated at the state
    GradientFailed,
    /// the scene's model could not be built
    ModelError,
}

impl SceneStatus {
    pub fn name(self) -> &'static str {
        match self {
            SceneStatus::Completed => "completed",
            SceneStatus::Ballooning => "ballooning",
            SceneStatus::SelfContact => "self-contact",
            SceneStatus::LimitPoint => "limit-point",
            SceneStatus::Inversion => "inversion",
            SceneStatus::Divergence => "divergence",
            SceneStatus::IterationLimit => "iteration-limit",
            SceneStatus::StepLimit => "step-limit",
            SceneStatus::Converged => "converged",
            SceneStatus::GradientFailed => "gradient-failed",
            SceneStatus::ModelError => "model-error",
        }
    }
    fn from_failure(f: FailureCause) -> SceneStatus {
        match f {
            FailureCause::LimitPoint => SceneStatus::LimitPoint,
            FailureCause::Inversion => SceneStatus::Inversion,
            FailureCause::Divergence => SceneStatus::Divergence,
            FailureCause::IterationLimit => SceneStatus::IterationLimit,
            FailureCause::StepLimit => SceneStatus::StepLimit,
        }
    }
}

impl std::fmt::Display for SceneStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The result of a pressure ramp of one scene.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SceneResult {
    pub scene: String,
    pub status: SceneStatus,
    pub cause: String,
    pub steps: Vec<StepRecord>,
    pub dofs: usize,
    pub elements: usize,
    /// every Newton iteration, failed attempts and event location included
    pub newton_iterations: usize,
    /// the path follower's work counts (both branches)
    #[serde(default)]
    pub path: PathStats,
    pub wall_time_s: f64,
    /// With `SceneOptions::keep_fields`: the mesh and the nodal displacements of each step
    /// (same order as `steps`).
    #[serde(skip)]
    pub fields: Option<SceneFields>,
    /// The reduced state of each step (same order as `steps`), for warm starts and for exact
    /// evaluations at a pressure between steps.
    #[serde(skip)]
    pub states: Vec<Vec<f64>>,
    /// At `rom` fidelity: the reduced model's error indicator at the highest recorded pressure
    /// ([`twistopt_solver::rom::RomPath::indicator`]: the full model's relative momentum residual
    /// under the reduced pressure; one residual assembly). None on the full model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom_indicator: Option<f64>,
    /// Set when the reduced ramp was rejected (`SceneOptions::rom_fallback`) and this result is
    /// the full model's: why (the reduced ramp's indicator or failure). Its states are then the
    /// full model's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom_fallback: Option<String>,
    /// Set when the positive branch started from a nearby design's state ([`WarmStart`]): the
    /// pressure it was corrected at (the branch has no steps between 0 and it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warm_start_kpa: Option<f64>,
    /// The nearby design's branch the positive branch started from (with `warm_start_kpa`):
    /// [`add_step_at`] corrects its state at the nearest pressure first.
    #[serde(skip)]
    pub warm: Option<WarmStart>,
    /// States of this branch corrected from a nearby design's (the warm start, and steps
    /// [`add_step_at`] reached that way): (pressure of the step, state − the nearby state), which
    /// the next design along the line adds to the same nearby state as its first guess
    /// (extrapolation along the line, see [`WarmStart`]).
    #[serde(skip)]
    pub warm_deltas: Vec<(f64, Vec<f64>)>,
    /// The pressures at which the path snapped through a lost stability (vacuum with contact;
    /// the states just past them are marked `snapped`).
    #[serde(default, skip_serializing_if = "Vec::is_empty", rename = "snaps_kPa")]
    pub snaps_kpa: Vec<f64>,
    /// With contact: the smallest contact distance over every state of the path (mm; ≥ 0: no
    /// interpenetration), recorded or not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_contact_distance_mm: Option<f64>,
}

/// The positive branch of a nearby design's scene (same scene, mesh topology and fidelity), to
/// start a ramp from instead of the unloaded state. One of its states just below its end is
/// corrected on the new design (at its pressure, or at its cavity volume where the branch ended
/// at a pressure maximum); it must converge to a stable state below the ballooning limit, else
/// the ramp starts cold. The path then goes on from there, its first step sized to reach just
/// past where the nearby branch ended. Stations below the start are not recorded
/// ([`add_step_at`] reaches such a pressure from the state above it). Used at `rom` fidelity
/// only (see `run_pressure_once`).
#[derive(Clone, Debug)]
pub struct WarmStart {
    /// converged states (p kPa, cavity volume mm³, state) by rising pressure, the end last
    pub points: Vec<(f64, f64, Vec<f64>)>,
    /// the branch ended at a pressure maximum
    pub fold: bool,
    /// per point: how it differs from the nearby design's state it was corrected from, where it
    /// was (`SceneResult::warm_deltas`); a design further along the line starts from point +
    /// delta (linear extrapolation along the line: its guesses start with residuals 3-10×
    /// smaller)
    pub deltas: Vec<Option<Vec<f64>>>,
}

impl WarmStart {
    /// The positive branch of a scene result (None without two positive states).
    pub fn of(r: &SceneResult) -> Option<WarmStart> {
        let mut points: Vec<(f64, f64, Vec<f64>)> =
            r.steps.iter().zip(&r.states).filter(|(s, _)| s.p_kpa > 0.0 && s.p_kpa.is_finite()).map(|(s, q)| (s.p_kpa, s.cavity_volume_mm3, q.clone())).collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let deltas = points.iter().map(|(p, _, q)| r.warm_deltas.iter().find(|(pd, d)| pd == p && d.len() == q.len()).map(|(_, d)| d.clone())).collect();
        (points.len() >= 2).then_some(WarmStart { points, fold: r.status == SceneStatus::LimitPoint, deltas })
    }
}

/// Warm-start candidates tried per ramp (from the highest).
const WARM_ATTEMPTS: usize = 2;
/// A warm start is at least this far below the nearby branch's end (relative, in cavity volume
/// where the branch ended at a pressure maximum, else in pressure).
const WARM_GAP: f64 = 0.01;
/// A nearby branch is flat near its end (warm starts in volume, see `run_pressure_once`) where
/// its relative volume grows more than this many times its relative pressure towards the end.
const WARM_FLAT: f64 = 3.0;
/// A warm start from a nearby branch's pressure maximum is corrected this fraction below the
/// maximum's volume (moved on along the line), and its first step goes as far beyond it.
const WARM_FOLD_GAP: f64 = 0.005;
/// [`add_step_at`] on a warm-started branch corrects the nearby design's state at the nearest
/// pressure when that is within this fraction of the pressure sought.
const WARM_NEAR: f64 = 0.05;
/// The first step from a warm start goes this far past the nearby branch's end, relative to
/// the start's distance to it.
const WARM_REACH: f64 = 1.1;

/// The reduced model's error indicator at a path state z (reduced coordinates) and pressure
/// (None on the full model, or where it cannot be evaluated).
pub fn rom_indicator(sm: &SceneModel, opts: &SceneOptions, z: &[f64], p_kpa: f64) -> Option<f64> {
    let rom = opts.rom.as_ref()?;
    let rp = rom.path(&sm.model, sm.loads(0.0, 0.0), sm.loads(p_kpa, 0.0), Vec::new()).ok()?;
    rp.indicator(z, 1.0).ok().filter(|v| v.is_finite())
}

impl SceneResult {
    /// A scene whose model could not be built, as a result with status `model-error`.
    pub fn model_error(kind: SceneKind, cause: String) -> SceneResult {
        SceneResult {
            scene: kind.name().to_string(),
            status: SceneStatus::ModelError,
            cause,
            steps: Vec::new(),
            dofs: 0,
            elements: 0,
            newton_iterations: 0,
            path: PathStats::default(),
            wall_time_s: 0.0,
            fields: None,
            states: Vec::new(),
            rom_indicator: None,
            rom_fallback: None,
            warm_start_kpa: None,
            warm: None,
            warm_deltas: Vec::new(),
            snaps_kpa: Vec::new(),
            min_contact_distance_mm: None,
        }
    }
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
                twistopt_solver::element::mean_cauchy_stress(&self.formulation, &rule, &self.material, &params, &x0, &u).map(|s| twistopt_solver::element::von_mises(&s)).unwrap_or(0.0)
            })
            .collect()
    }
}

impl SceneModel {
    pub fn build(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind) -> Result<SceneModel, SceneError> {
        Self::build_perturbed(geom, opts, kind, None)
    }

    /// [`SceneModel::build`] with the mesh's reference nodes moved by `offset` (one vector per
    /// node): a geometric imperfection, e.g. a small multiple of a buckling mode, that turns a
    /// bifurcation of the perfect geometry into a smooth path.
    pub fn build_perturbed(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, offset: Option<&[[f64; 3]]>) -> Result<SceneModel, SceneError> {
        if let Some(why) = opts.rom.as_ref().and_then(|_| crate::rom::outside_box(&opts.rom_box, &geom.design)) {
            return Err(SceneError::OutsideRom(why));
        }
        if opts.rom.is_some() {
            if let Some(why) = crate::rom::untrained_scene(&opts.rom_scenes, kind) {
                return Err(SceneError::OutsideRom(why));
            }
        }
        let spec = opts.mesh.with_sector(opts.sector).with_kind(opts.formulation.kind);
        let mut am = build_mesh(geom, &spec)?;
        if let Some(off) = offset {
            if off.len() != am.mesh.nodes.len() {
                return Err(SceneError::Model(twistopt_solver::model::ModelError::Mesh(format!("imperfection of {} nodes for a mesh of {}", off.len(), am.mesh.nodes.len()))));
            }
            for (x, d) in am.mesh.nodes.iter_mut().zip(off) {
                for c in 0..3 {
                    x[c] += d[c];
                }
            }
        }
        let mesh = am.mesh.clone();
        let mut cons = Constraints::default();
        cons.prescribe_set(&mesh.node_sets["bottom"], &[0, 1, 2], 0.0);
        let top_nodes = mesh.node_sets["top"].clone();
        let cap_reference = [0.0, 0.0, L_TUBE];
        cons.bodies.push(RigidBody { name: "cap".into(), reference: cap_reference, nodes: top_nodes.clone(), mask: [true; 3], dofs: kind.cap_dofs(opts.sector) });
        if opts.sector {
            cons.cyclic = Some(Cyclic { pairs: am.cyclic_pairs.clone(), angle: 2.0 * std::f64::consts::PI / 3.0 });
        }
        let cavity = mesh.face_sets["cavity"].clone();
        let cavity_nodes = mesh.node_sets["cavity"].clone();
        let mut model = Model::new(mesh, opts.formulation, opts.material, &cons, Some(&cavity))?;
        if let (Some(c), None) = (&opts.contact, &opts.rom) {
            let copies: Vec<f64> = if opts.sector { vec![0.0, 2.0 * std::f64::consts::PI / 3.0, -2.0 * std::f64::consts::PI / 3.0] } else { vec![0.0] };
            let mut con = twistopt_solver::contact::self_contact(&model.mesh, &cavity, &copies, T_WALL, c.reach_mm, c.barrier());
            // a blend width independent of the design (the solver's default, a tenth of the
            // shortest triangle edge, moves with the shape, which the adjoint does not follow:
            // measured 1e-4–1e-1 off central differences in the blocked scene)
            con.blend = c.blend_mm;
            let areas = twistopt_solver::contact::nodal_areas(&model.mesh, &cavity);
            if let (Some(a), SceneKind::PureTwist | SceneKind::PureTwistBlocked) = (c.axle_radius_mm, kind) {
                let inner = cavity_nodes.iter().map(|&n| model.mesh.nodes[n][0].hypot(model.mesh.nodes[n][1])).fold(f64::INFINITY, f64::min);
                if !(a > 0.0 && a < inner) {
                    return Err(SceneError::Model(twistopt_solver::model::ModelError::Mesh(format!(
                        "scenes.contact.axle_radius_mm = {a} does not fit inside the cavity: its wall comes within {inner:.3} mm of the axis"
                    ))));
                }
                con.axle = Some(twistopt_solver::contact::Axle { radius: a, slaves: areas.clone() });
            }
            // the end plates: the collapsing wall stays above the bottom plate (z = 0, fixed) and
            // below the top cap's (it follows the cap's axial motion: exact on the sector, where the cap
            // turns about z only; the full model's cap may also tilt, which the plane ignores).
            // Measured without them: the letter's optimum's free scene passed the wall through
            // z = 0 from −55 kPa on (1.2 mm below it at −72 kPa), ours (l = 20, α = 360°) from −35 kPa.
            let off = |ring: &str| -> Vec<(usize, f64)> {
                let ring: std::collections::HashSet<usize> = model.mesh.node_sets[ring].iter().copied().collect();
                areas.iter().copied().filter(|(n, _)| !ring.contains(n)).collect()
            };
            con.planes = vec![
                twistopt_solver::contact::Plane { normal: [0.0, 0.0, 1.0], point: twistopt_solver::contact::Vertex::Fixed([0.0, 0.0, 0.0]), slaves: off("bottom") },
                twistopt_solver::contact::Plane { normal: [0.0, 0.0, -1.0], point: twistopt_solver::contact::Vertex::Node(top_nodes[0]), slaves: off("top") },
            ];
            model.set_contact(con)?;
        }
        // the sparse tangent's setup is built where the full model will be solved (a reduced
        // model evaluates the same mesh and constraints without it)
        if opts.rom.is_none() {
            model.prepare_sparse()?;
        }
        if !opts.cap_load {
            if let Some(c) = model.cavity.as_mut() {
                c.cap_load = false;
            }
        }
        let rotation_slot = match model.dofs.body_dofs[0][5] {
            BodyDof::Presc(s) => Some(s),
            BodyDof::Free(_) => None,
        };
        Ok(SceneModel { kind, model, multiplicity: if opts.sector { 3.0 } else { 1.0 }, top_nodes, cavity_nodes, cap_reference, rotation_slot, mesh: am, integrity_cache: Default::default() })
    }

    /// The number of unknowns of a path state at `opts`' fidelity (reduced coordinates with a ROM).
    pub fn state_dim(&self, opts: &SceneOptions) -> usize {
        match &opts.rom {
            Some(rom) => rom.basis.k + self.model.n_reduced() - self.model.dofs.n_nodal(),
            None => self.model.n_reduced(),
        }
    }

    /// The full model's unknowns of a path state at `opts`' fidelity.
    pub fn full_state(&self, opts: &SceneOptions, state: &[f64]) -> Vec<f64> {
        match &opts.rom {
            Some(rom) if state.len() != self.model.n_reduced() => match twistopt_solver::rom::Reduction::new(&self.model, &rom.basis) {
                Ok(red) => red.lift(state),
                Err(_) => vec![0.0; self.model.n_reduced()],
            },
            _ => state.to_vec(),
        }
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

    /// The functionals a scene path records, in the order of the `OUT_*` slots: the cap rotation
    /// about z, its axial translation, the generalised reaction of the rotation (the moment the
    /// actuator exerts on the cap about its current reference point, negated), the max deformed
    /// radius over all nodes and the cavity volume of the modelled part. The gradient module
    /// differentiates the same functionals.
    pub fn functionals(&self) -> Vec<Functional> {
        vec![
            Functional::BodyDof { body: 0, dof: 5 },
            Functional::BodyDof { body: 0, dof: 2 },
            Functional::BodyReaction { body: 0, dof: 5 },
            Functional::MaxRadius { nodes: (0..self.model.mesh.nodes.len()).collect() },
            Functional::CavityVolume,
        ]
    }

    /// The scene's load path from `from` to `to`, recording [`SceneModel::functionals`] (and,
    /// with `contact_gap`, the self-contact margin in slot `OUT_CONTACT`).
    pub fn path(&self, from: Loads, to: Loads, contact_gap: Option<f64>) -> LoadPath<'_> {
        let mut lp = LoadPath::new(&self.model, from, to, self.functionals());
        if let Some(con) = self.model.contact() {
            // the smallest distance of a cavity node to the wall it may touch
            let x0 = &self.model.mesh.nodes;
            lp.extra.push(Box::new(move |a: &Assembled| con.min_distance(&|n: usize| [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1], x0[n][2] + a.u[n][2]])));
            // the mesh's integrity on its own (quadratic) geometry: slots OUT_PENETRATION, OUT_FOLDED
            lp.extra.push(Box::new(move |a: &Assembled| self.integrity(&a.u).depth_mm));
            lp.extra.push(Box::new(move |a: &Assembled| self.integrity(&a.u).folded as f64));
            // slot OUT_LEAST_JACOBIAN: continuous, so that a fold is located on the path
            lp.extra.push(Box::new(move |a: &Assembled| self.integrity(&a.u).least_jacobian));
        } else if let Some(gap) = contact_gap {
            lp.extra.push(Box::new(move |a: &Assembled| self.contact_margin(a, gap)));
        }
        lp
    }

    /// The step record of recorded outputs (slots as in [`SceneModel::functionals`]).
    fn step_record(&self, out: &[f64], p_kpa: f64, min_det_f: f64, newton_iterations: usize) -> StepRecord {
        StepRecord {
            p_kpa,
            theta_deg: out[OUT_THETA].to_degrees(),
            axial_mm: out[OUT_AXIAL],
            tau_nm: -out[OUT_REACTION] * self.multiplicity * 1e-3,
            max_radius_mm: out[OUT_RADIUS],
            cavity_volume_mm3: out[OUT_VOLUME] * self.multiplicity,
            min_det_f,
            newton_iterations,
            contact_distance_mm: self.model.contact().map(|_| out.get(OUT_CONTACT).copied().unwrap_or(f64::NAN)).filter(|v| v.is_finite()),
            penetration_mm: self.model.contact().and(out.get(OUT_PENETRATION).copied()).filter(|v| v.is_finite()),
            folded_elements: self.model.contact().and(out.get(OUT_FOLDED).copied()).filter(|v| v.is_finite()).map(|v| v as usize),
            least_jacobian_ratio: self.model.contact().and(out.get(OUT_LEAST_JACOBIAN).copied()).filter(|v| v.is_finite()),
            snapped: false,
        }
    }

    /// Scene outputs of an assembled state, through the same functionals as a path.
    pub fn record(&self, a: &Assembled, loads: &Loads, newton_iterations: usize) -> StepRecord {
        let st = twistopt_solver::adjoint::State::from_assembly(&self.model, a);
        let mut out: Vec<f64> = self.functionals().iter().map(|f| f.eval(&self.model, &st).unwrap_or(f64::NAN)).collect();
        if let Some(con) = self.model.contact() {
            let x0 = &self.model.mesh.nodes;
            out.push(con.min_distance(&|n: usize| [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1], x0[n][2] + a.u[n][2]]));
            let i = self.integrity(&a.u);
            out.push(i.depth_mm);
            out.push(i.folded as f64);
            out.push(i.least_jacobian);
        }
        self.step_record(&out, loads.pressure * 1e3, a.min_det_f, newton_iterations)
    }

    /// The deformed mesh's integrity at displacements `u`, on the elements' own geometry, the
    /// rotated copies of a sector included (`twistopt_solver::integrity`), see [`Integrity`].
    /// Self-contact keeps the cavity's *nodes* off the triangles between the facing wall's
    /// nodes; this measures what that leaves.
    pub fn integrity(&self, u: &[[f64; 3]]) -> Integrity {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        for d in u.iter().flatten() {
            d.to_bits().hash(&mut h);
        }
        let key = h.finish();
        if let Some((k, r)) = *self.integrity_cache.lock().unwrap_or_else(|e| e.into_inner()) {
            if k == key {
                return r;
            }
        }
        let r = self.measure_integrity(u);
        *self.integrity_cache.lock().unwrap_or_else(|e| e.into_inner()) = Some((key, r));
        r
    }

    fn measure_integrity(&self, u: &[[f64; 3]]) -> Integrity {
        use twistopt_solver::integrity::{least_jacobians, penetration, with_copies};
        let mesh = &self.model.mesh;
        let Some(cavity) = mesh.face_sets.get("cavity") else { return Integrity { depth_mm: f64::NAN, folded: 0, least_jacobian: f64::NAN } };
        let x: Vec<[f64; 3]> = mesh.nodes.iter().zip(u).map(|(p, d)| [p[0] + d[0], p[1] + d[1], p[2] + d[2]]).collect();
        let copies: Vec<f64> = if self.multiplicity > 1.0 { vec![0.0, 2.0 * std::f64::consts::PI / 3.0, -2.0 * std::f64::consts::PI / 3.0] } else { vec![0.0] };
        let (all, xs) = with_copies(mesh, &x, &copies);
        let jac = least_jacobians(&all, &xs, 9);
        let folded = jac.iter().filter(|&&j| !(j > 0.0)).count() / copies.len();
        // copy 0's cavity sampled (the copies' samples are its rotations), every copy's walls
        let (depth, _) = penetration(&all, cavity, &all.face_sets["cavity"], &xs, 7, &|e| jac[e] > 0.0);
        // (a NaN, from an element map that could not be evaluated, counts as folded)
        let least = jac[..mesh.n_elements()].iter().fold(f64::INFINITY, |m, &j| if j.is_nan() { f64::NEG_INFINITY } else { m.min(j) });
        Integrity { depth_mm: depth, folded, least_jacobian: least.max(-1e3) }
    }

    /// The self-contact margin: the smallest current distance, less `gap`, between two cavity
    /// nodes that are farther apart than 2t in the reference configuration (rotated copies of the
    /// sector included). Contact itself is not modelled; a vacuum path stops where this reaches 0.
    pub fn contact_margin(&self, a: &Assembled, gap: f64) -> f64 {
        let x0 = &self.model.mesh.nodes;
        let cur: Vec<([f64; 3], [f64; 3])> = self.cavity_nodes.iter().map(|&n| (x0[n], [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1], x0[n][2] + a.u[n][2]])).collect();
        let copies: Vec<f64> = if self.multiplicity > 1.0 { vec![0.0, 2.0 * std::f64::consts::PI / 3.0, -2.0 * std::f64::consts::PI / 3.0] } else { vec![0.0] };
        let far = 2.0 * T_WALL;
        let mut dmin = f64::INFINITY;
        for ang in copies {
            let (s, c) = ang.sin_cos();
            let rot = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
            for (i, (xi0, xi)) in cur.iter().enumerate() {
                for (xj0, xj) in cur.iter().skip(if ang == 0.0 { i + 1 } else { 0 }) {
                    let (xj0, xj) = (rot(*xj0), rot(*xj));
                    if dist(*xi0, xj0) > far {
                        dmin = dmin.min(dist(*xi, xj));
                    }
                }
            }
        }
        dmin - gap
    }

    /// The contact gap of a vacuum path: a quarter of the element size around the cavity, at most 0.5 mm.
    fn contact_gap(&self) -> f64 {
        let hmesh = 2.0 * std::f64::consts::PI * 15.0 / (2.0 * self.mesh.spec.n_around as f64);
        (0.25 * hmesh).min(0.5)
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Output slots of a scene path (see [`SceneModel::functionals`]).
pub const OUT_THETA: usize = 0;
pub const OUT_AXIAL: usize = 1;
pub const OUT_REACTION: usize = 2;
pub const OUT_RADIUS: usize = 3;
pub const OUT_VOLUME: usize = 4;
pub const OUT_CONTACT: usize = 5;
/// With self-contact: the deepest interpenetration of the cavity surface ([`SceneModel::integrity`]).
pub const OUT_PENETRATION: usize = 6;
/// With self-contact: the number of folded elements ([`SceneModel::integrity`]).
pub const OUT_FOLDED: usize = 7;
/// With self-contact: the least relative det ∂x/∂ξ of any element ([`SceneModel::integrity`]).
pub const OUT_LEAST_JACOBIAN: usize = 8;

/// What the contact leaves on the elements' own (quadratic) geometry ([`SceneModel::integrity`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Integrity {
    /// the deepest point of the cavity surface (7 × 7 samples per face) inside another element's
    /// material, in mm (0: no interpenetration, between the nodes included); folded elements are
    /// not tested
    pub depth_mm: f64,
    /// the number of elements whose map folds between their quadrature points (det ∂x/∂ξ ≤ 0
    /// somewhere on a 9³ grid of the element; the solver's det F > 0 check at the quadrature
    /// points does not see it)
    pub folded: usize,
    /// the least det ∂x/∂ξ on that grid relative to the element's centre, over all elements
    /// (≤ 0: an element folds; 1 for an undistorted brick)
    pub least_jacobian: f64,
}

/// A converged point of a scene path with its reduced state.
struct ScenePoint {
    record: StepRecord,
    q: Vec<f64>,
}

/// The outcome of one pressure path of a scene.
struct ScenePath {
    points: Vec<ScenePoint>,
    /// why the path ended before its end: (status, cause)
    end: Option<(SceneStatus, String)>,
    stats: PathStats,
    /// tangent and factor at the last point
    last: Option<(Vec<f64>, Factor)>,
    /// at `rom` fidelity: the reduced model's error indicator at the path's highest pressure
    /// (p kPa, indicator), from the path's own reduced model
    indicator: Option<(f64, f64)>,
}

/// Follow the scene's pressure from the state `q0` at `p0_kpa` to `p_end_kpa` with stations at
/// `stations_kpa`; the ballooning limit and (for vacuum) self-contact stop it where `stop` says.
fn pressure_path(sm: &SceneModel, opts: &SceneOptions, q0: &[f64], p0_kpa: f64, p_end_kpa: f64, stations_kpa: &[f64], stop: bool) -> ScenePath {
    pressure_path_with(sm, &opts.steps, opts, q0, p0_kpa, p_end_kpa, stations_kpa, stop, false, None)
}

/// [`pressure_path`] with its own path options: on the full model, or on the reduced one when
/// `opts.rom` is set (its states are then reduced coordinates).
#[allow(clippy::too_many_arguments)]
fn pressure_path_with(
    sm: &SceneModel,
    path_opts: &ContinuationOptions,
    opts: &SceneOptions,
    q0: &[f64],
    p0_kpa: f64,
    p_end_kpa: f64,
    stations_kpa: &[f64],
    stop: bool,
    want_indicator: bool,
    guess: Option<Guess>,
) -> ScenePath {
    let vacuum = p_end_kpa < 0.0;
    let gap = sm.contact_gap();
    let (from, to) = (sm.loads(0.0, 0.0), sm.loads(p_end_kpa, 0.0));
    let mut stops = Vec::new();
    if stop {
        stops.push(Stop { name: "ballooning".into(), output: OUT_RADIUS, threshold: opts.ballooning_limit_mm, rising: true });
        if vacuum && opts.contact.is_none() {
            stops.push(Stop { name: "self-contact".into(), output: OUT_CONTACT, threshold: 0.0, rising: false });
        }
        if vacuum && opts.contact.is_some() {
            // a vanishing cavity: the cavity has closed (its walls all in contact), or walls
            // passed each other outside the contact candidates
            stops.push(Stop { name: "cavity-closed".into(), output: OUT_VOLUME, threshold: 0.0, rising: false });
        }
        if vacuum && opts.contact.is_some_and(|c| c.stop_at_fold) && opts.rom.is_none() {
            stops.push(Stop { name: "element-folds".into(), output: OUT_LEAST_JACOBIAN, threshold: 0.0, rising: false });
        }
    }
    let stations: Vec<f64> = stations_kpa.iter().map(|p| p / p_end_kpa).collect();
    let lam0 = if p_end_kpa != 0.0 { p0_kpa / p_end_kpa } else { 0.0 };
    if let Some(rom) = &opts.rom {
        let refuse = |cause: String| ScenePath { points: Vec::new(), end: Some((SceneStatus::ModelError, cause)), stats: PathStats::default(), last: None, indicator: None };
        if vacuum {
            return refuse("the reduced-order model covers positive pressures only (vacuum needs self-contact)".into());
        }
        let mut rp = match rom.path(&sm.model, from, to, sm.functionals()) {
            Ok(rp) => rp,
            Err(e) => return refuse(format!("reduced-order model: {e}")),
        };
        // the cavity's load stiffness computed once per step's corrections (exact residual)
        rp.set_cavity_hessian_lag(ROM_CAVITY_HESSIAN_LAG);
        let res = match solve_guess(&rp, q0, lam0, path_opts, guess) {
            Ok(Some(s)) => {
                let spent = s.iterations;
                let mut res = follow_from(&rp, s, 1.0, &stations, &stops, path_opts);
                res.stats.newton_iterations += spent;
                res
            }
            Ok(None) => follow(&rp, q0, lam0, 1.0, &stations, &stops, path_opts),
            Err(its) => return ScenePath::guess_failed(its),
        };
        // the indicator at the highest pressure, on this path's reduced model (as
        // `rom_indicator`, without building another)
        let top = res.points.iter().max_by(|a, b| a.lam.total_cmp(&b.lam)).filter(|_| want_indicator && p_end_kpa > 0.0);
        let indicator = top.and_then(|pt| rp.indicator(&pt.q, pt.lam).ok().filter(|v| v.is_finite()).map(|v| (rp.loads(pt.lam).pressure * 1e3, v)));
        let mut path = scene_path(sm, opts, &res.points, res.end, res.stats, |lam| rp.loads(lam), &stops, p0_kpa, gap, None);
        path.indicator = indicator;
        return path;
    }
    let lp = sm.path(from, to, (vacuum && stop).then_some(gap));
    let solved = match solve_guess(&lp, q0, lam0, path_opts, guess) {
        Ok(s) => s,
        Err(its) => return ScenePath::guess_failed(its),
    };
    let spent = solved.as_ref().map_or(0, |s| s.iterations);
    let mut res = if vacuum && sm.model.contact().is_some() {
        // under vacuum the wall buckles before it touches: the pressure supply makes it snap to
        // the collapsed, contacting state (see `follow_snapping`)
        let (q0, lam0) = solved.as_ref().map_or((q0, lam0), |s| (&s.q[..], s.lam));
        follow_snapping(&lp, q0, lam0, 1.0, &stations, &stops, path_opts, &SnapOptions::default()).0
    } else if let Some(s) = solved {
        follow_from(&lp, s, 1.0, &stations, &stops, path_opts)
    } else {
        follow(&lp, q0, lam0, 1.0, &stations, &stops, path_opts)
    };
    res.stats.newton_iterations += spent;
    scene_path(sm, opts, &res.points, res.end, res.stats, |lam| lp.loads(lam), &stops, p0_kpa, gap, res.last)
}

/// How a path's start is corrected from a nearby design's state (see [`solve_guess`]).
#[derive(Clone, Debug)]
struct Guess {
    /// under functional control, the control functional is held at this factor × its value at
    /// the state
    factor: f64,
    /// Newton starts from the state + this, where given (a step along the nearby branch towards
    /// the value held)
    shift: Option<Vec<f64>>,
}

impl Guess {
    fn at(factor: f64) -> Guess {
        Guess { factor, shift: None }
    }
}

/// With `guess`: Newton from the state `q` (a nearby design's, at the same load; from q +
/// `guess.shift` where given), which must converge to a stable state: the solved state (the
/// path's first node, see [`follow_from`]), or the iterations spent when it does not. A path
/// that starts under functional control holds the control functional at `guess.factor` × its
/// value at q (λ an unknown: well posed also where the load λ lies beyond this design's
/// maximum, and at a pressure maximum itself).
fn solve_guess<M: twistopt_solver::continuation::PathModel>(m: &M, q: &[f64], lam: f64, o: &ContinuationOptions, guess: Option<Guess>) -> Result<Option<Solved<M>>, usize> {
    let Some(guess) = guess else {
        return Ok(None);
    };
    let c = match o.start_control {
        Control::Functional => match m.eval(q, lam, false, None) {
            Ok(e) => e.control.map(|c| guess.factor * c.0),
            Err(_) => return Err(0),
        },
        Control::Load => None,
    };
    let shifted: Vec<f64>;
    let q = match guess.shift.as_deref().filter(|d| d.len() == q.len()) {
        Some(d) => {
            shifted = q.iter().zip(d).map(|(a, b)| a + b).collect();
            &shifted[..]
        }
        None => q,
    };
    // (converged as tightly as located events: the path takes the state as its start)
    // (and allowed the iterations of a solve from far: a guess from a nearby design starts with
    // a residual of the order of the forces, mostly in the cap's rigid DOFs, and on a design
    // 2° on from the last it fell by 6× in 3 iterations, which the path's stall rule (10× in 3)
    // refused, and the scene ramped from zero: ≈ 60 iterations instead of ≈ 10)
    let tight = twistopt_solver::solve::NewtonOptions { rtol: o.newton.rtol.min(1e-10), stall_iterations: 8, stall_ratio: 1.0, ..o.newton.clone() };
    match correct(m, q, lam, c, &tight, o.mixed_tangent, None, false) {
        Ok(s) if s.stable => Ok(Some(s)),
        Ok(s) => Err(s.iterations),
        Err((_, its)) => Err(its),
    }
}

impl ScenePath {
    /// A path whose guessed start did not converge to a stable state (no points).
    fn guess_failed(its: usize) -> ScenePath {
        let stats = PathStats { newton_iterations: its, failed_iterations: its, failed_attempts: 1, ..PathStats::default() };
        ScenePath { points: Vec::new(), end: Some((SceneStatus::Divergence, "the warm start did not converge to a stable state".into())), stats, last: None, indicator: None }
    }
}

/// A scene path from the points and end of a followed path (full or reduced model).
#[allow(clippy::too_many_arguments)]
fn scene_path(
    sm: &SceneModel,
    opts: &SceneOptions,
    pts: &[twistopt_solver::continuation::PathPoint],
    end: PathEnd,
    stats: PathStats,
    loads: impl Fn(f64) -> Loads,
    stops: &[Stop],
    p0_kpa: f64,
    gap: f64,
    last: Option<(Vec<f64>, Factor)>,
) -> ScenePath {
    let points: Vec<ScenePoint> = pts
        .iter()
        .map(|pt| ScenePoint {
            record: StepRecord { snapped: pt.kind == PointKind::Snapped, ..sm.step_record(&pt.outputs, loads(pt.lam).pressure * 1e3, pt.min_det, pt.newton_iterations) },
            q: pt.q.clone(),
        })
        .collect();
    let p_last = points.last().map(|p| p.record.p_kpa).unwrap_or(p0_kpa);
    let limit = opts.ballooning_limit_mm;
    let end = match end {
        PathEnd::Completed => None,
        PathEnd::Stopped(i) if stops[i].name == "ballooning" => Some((SceneStatus::Ballooning, format!("max deformed radius reached the ballooning limit {limit:.2} mm at p = {p_last:.4} kPa"))),
        PathEnd::Stopped(i) if stops[i].name == "cavity-closed" => {
            Some((SceneStatus::SelfContact, format!("the cavity volume vanished at p = {p_last:.4} kPa (or in the snap beyond it): the cavity has closed, or walls passed each other beyond the contact candidates (if a larger scenes.contact.reach_mm ends at the same pressure, the cavity closed)")))
        }
        PathEnd::Stopped(i) if stops[i].name == "element-folds" => Some((
            SceneStatus::Inversion,
            format!("an element folds between its quadrature points at p = {p_last:.4} kPa (or in the snap beyond it): past it the mesh does not represent the wall and the cavity surface passes through it; elements nearer cubic where the wall folds (more along the axis) go further, studies/vacuum (scenes.contact.stop_at_fold = false goes on and records folded_elements)"),
        )),
        PathEnd::Stopped(_) => Some((SceneStatus::SelfContact, format!("two cavity walls came closer than {gap:.2} mm at p = {p_last:.4} kPa (contact is not modelled)"))),
        PathEnd::Fold => Some((SceneStatus::LimitPoint, format!("pressure maximum at p = {p_last:.4} kPa (located under volume control)"))),
        PathEnd::Instability => {
            Some((SceneStatus::LimitPoint, format!("the tangent loses positive definiteness beyond p = {p_last:.4} kPa with the pressure still rising (a bifurcation; located on the path)")))
        }
        PathEnd::Failed(f) => {
            let cause = match f {
                FailureCause::LimitPoint => format!("tangent lost positive definiteness beyond p = {p_last:.3} kPa (pressure maximum / instability)"),
                FailureCause::Inversion => format!("an element inverted beyond p = {p_last:.3} kPa"),
                FailureCause::Divergence => format!("Newton diverged beyond p = {p_last:.3} kPa at the smallest step"),
                FailureCause::IterationLimit => format!("Newton hit its iteration limit beyond p = {p_last:.3} kPa at the smallest step"),
                FailureCause::StepLimit => format!("step limit reached at p = {p_last:.3} kPa"),
            };
            Some((SceneStatus::from_failure(f), cause))
        }
    };
    ScenePath { points, end, stats, last, indicator: None }
}

/// Every converged state of a scene's pressure ramp from the unloaded state towards `p_end_kpa`
/// without the ballooning stop (to the pressure maximum, an instability or `p_end_kpa`):
/// (pressure kPa, path state, prescribed values), with the Newton iterations spent.
pub fn ramp_states(sm: &SceneModel, opts: &SceneOptions, p_end_kpa: f64) -> (Vec<(f64, Vec<f64>, Vec<f64>)>, usize) {
    let path = pressure_path(sm, opts, &vec![0.0; sm.state_dim(opts)], 0.0, p_end_kpa, &[], false);
    let presc = sm.loads(0.0, 0.0).presc;
    (path.points.into_iter().map(|p| (p.record.p_kpa, p.q, presc.clone())).collect(), path.stats.newton_iterations)
}

/// A converged state of a scene at one pressure (for sensitivities and warm starts).
pub struct Equilibrium {
    pub q: Vec<f64>,
    pub loads: Loads,
    /// the last converged state's record (its pressure is the target unless `end` is set)
    pub record: StepRecord,
    /// every Newton iteration spent, failed attempts included
    pub newton_iterations: usize,
    pub path: PathStats,
    /// why the path ended before the target (status, cause); None = target reached
    pub end: Option<(SceneStatus, String)>,
    /// whether the warm start was used (Newton straight from the given state converged)
    pub warm_started: bool,
    /// the tangent (values) and its factor at this state, handed on to the adjoint
    pub factor: Option<(Vec<f64>, Factor)>,
}

impl Equilibrium {
    fn from_path(sm: &SceneModel, path: ScenePath, extra_iterations: usize, warm_started: bool) -> Equilibrium {
        let mut path = path;
        let last = path.points.pop();
        let (q, record) = match last {
            Some(p) => (p.q, p.record),
            None => {
                let q = vec![0.0; sm.model.n_reduced()];
                let record = sm.model.assemble(&q, &sm.loads(0.0, 0.0), false).map(|a| sm.record(&a, &sm.loads(0.0, 0.0), 0)).unwrap_or(StepRecord {
                    p_kpa: 0.0,
                    theta_deg: 0.0,
                    axial_mm: 0.0,
                    tau_nm: 0.0,
                    max_radius_mm: 0.0,
                    cavity_volume_mm3: 0.0,
                    min_det_f: 1.0,
                    newton_iterations: 0,
                    contact_distance_mm: None,
                    penetration_mm: None,
                    folded_elements: None,
                    least_jacobian_ratio: None,
                    snapped: false,
                });
                (q, record)
            }
        };
        let loads = sm.loads(record.p_kpa, 0.0);
        Equilibrium { q, loads, record, newton_iterations: path.stats.newton_iterations + extra_iterations, path: path.stats, end: path.end, warm_started, factor: path.last }
    }
}

/// The equilibrium of a scene at pressure `p_kpa`, without the ballooning stop (the caller
/// constrains the radius). With `warm` = (q, p_warm), a converged state of a nearby design (same
/// mesh topology) at pressure p_warm, Newton first solves the new design at p_warm from q and the
/// path then follows from p_warm to p_kpa; if that first solve fails, the path starts from the
/// unloaded state. A path that meets a pressure maximum or an instability before `p_kpa` ends
/// there (`end`).
pub fn equilibrium(sm: &SceneModel, opts: &SceneOptions, p_kpa: f64, warm: Option<(&[f64], f64)>) -> Equilibrium {
    let mut spent = 0;
    if let Some((w, pw)) = warm.filter(|w| w.0.len() == sm.model.n_reduced() && opts.rom.is_none() && w.1.is_finite() && p_kpa != 0.0) {
        // the warm state solved at its own pressure on the new design, then the path onwards
        let lp = sm.path(sm.loads(0.0, 0.0), sm.loads(p_kpa, 0.0), None);
        let lam_w = pw / p_kpa;
        match correct(&lp, w, lam_w, None, &opts.steps.newton, opts.steps.mixed_tangent, None, false) {
            Ok(s) if s.stable => {
                spent += s.iterations;
                let path = pressure_path(sm, opts, &s.q, pw, p_kpa, &[], false);
                return Equilibrium::from_path(sm, path, spent, true);
            }
            Ok(s) => spent += s.iterations,
            Err((_, its)) => spent += its,
        }
    }
    let path = pressure_path(sm, opts, &vec![0.0; sm.state_dim(opts)], 0.0, p_kpa, &[], false);
    Equilibrium::from_path(sm, path, spent, false)
}

/// Continue an equilibrium's pressure upward to `p_cap` (kPa) without the ballooning stop:
/// `BelowCap` when it reaches the cap, else the state where it fails — the pressure maximum
/// located under volume control to 1e-6 relative, the last stable state before a bifurcation, or
/// the last converged state before a solver failure — with the failure in `end`.
pub fn continue_to_failure(sm: &SceneModel, opts: &SceneOptions, from: &Equilibrium, p_cap: f64) -> LimitOutcome {
    if from.end.is_some() || p_cap <= from.loads.pressure * 1e3 {
        return LimitOutcome::BelowCap { stats: PathStats::default() };
    }
    let path = pressure_path(sm, opts, &from.q, from.loads.pressure * 1e3, p_cap, &[], false);
    if path.end.is_none() {
        return LimitOutcome::BelowCap { stats: path.stats };
    }
    LimitOutcome::Found(Equilibrium::from_path(sm, path, 0, false))
}

/// What a search for the failure above an equilibrium found.
pub enum LimitOutcome {
    /// the state where the path fails (at the pressure maximum for a fold), with the failure in `end`
    Found(Equilibrium),
    /// the pressure reached the cap without failing (with the path's work counts)
    BelowCap { stats: PathStats },
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
            LimitOutcome::BelowCap { stats } => stats.newton_iterations,
        }
    }
    /// The continuation's work counts (steps, iterations, failed attempts).
    pub fn stats(&self) -> PathStats {
        match self {
            LimitOutcome::Found(e) => e.path.clone(),
            LimitOutcome::BelowCap { stats } => stats.clone(),
        }
    }
}

/// Ramp a scene's pressure through the given targets (kPa). Positive and negative targets are
/// two branches, each followed from the unloaded state with a point at every target; a branch
/// ends at its last target, at the ballooning limit, at self-contact (vacuum), at a pressure
/// maximum or instability (located on the path), or at a solver failure. Steps are returned
/// sorted by pressure.
pub fn run_pressure(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, targets_kpa: &[f64]) -> Result<SceneResult, SceneError> {
    run_pressure_warm(geom, opts, kind, targets_kpa, None)
}

/// [`run_pressure`], the positive branch started from `warm` where it applies (see
/// [`WarmStart`]; a fallback to the full model starts cold).
pub fn run_pressure_warm(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, targets_kpa: &[f64], warm: Option<&WarmStart>) -> Result<SceneResult, SceneError> {
    let r = run_pressure_once(geom, opts, kind, targets_kpa, warm)?;
    let (Some(_), Some(limit)) = (&opts.rom, opts.rom_fallback) else {
        return Ok(r);
    };
    let why = match (r.status, r.rom_indicator) {
        (SceneStatus::Divergence | SceneStatus::IterationLimit | SceneStatus::StepLimit, _) => format!("the reduced ramp ended in {} ({})", r.status, r.cause),
        (_, None) => "the reduced ramp's error indicator could not be evaluated".to_string(),
        (_, Some(ind)) if ind > limit => format!("the reduced ramp's error indicator {ind:.3} exceeds {limit}"),
        _ => return Ok(r),
    };
    let mut full = opts.clone();
    full.rom = None;
    let mut f = run_pressure_once(geom, &full, kind, targets_kpa, None)?;
    f.rom_indicator = r.rom_indicator;
    f.rom_fallback = Some(why);
    f.newton_iterations += r.newton_iterations;
    f.wall_time_s += r.wall_time_s;
    Ok(f)
}

/// The scene options a result's states belong to: without the reduced model where the result
/// fell back to the full one.
pub fn result_options<'a>(opts: &'a SceneOptions, r: &SceneResult) -> std::borrow::Cow<'a, SceneOptions> {
    if r.rom_fallback.is_some() && opts.rom.is_some() {
        let mut o = opts.clone();
        o.rom = None;
        std::borrow::Cow::Owned(o)
    } else {
        std::borrow::Cow::Borrowed(opts)
    }
}

/// The reduced paths' cavity Hessian reuse ([`twistopt_solver::rom::RomPath::set_cavity_hessian_lag`]):
/// a step moves the state by a few percent, its Newton corrections by well under 0.2 %.
const ROM_CAVITY_HESSIAN_LAG: f64 = 2e-3;

fn run_pressure_once(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, targets_kpa: &[f64], warm: Option<&WarmStart>) -> Result<SceneResult, SceneError> {
    let t0 = Instant::now();
    let sm = SceneModel::build(geom, opts, kind)?;
    let mut pos: Vec<f64> = targets_kpa.iter().copied().filter(|p| *p > 0.0 && p.is_finite()).collect();
    let mut neg: Vec<f64> = targets_kpa.iter().copied().filter(|p| *p < 0.0 && p.is_finite()).collect();
    pos.sort_by(f64::total_cmp);
    neg.sort_by(|a, b| b.total_cmp(a));
    let l0 = sm.loads(0.0, 0.0);
    let a0 = sm.model.assemble(&vec![0.0; sm.model.n_reduced()], &l0, false).map_err(|e| SceneError::Initial(e.to_string()))?;
    let q0 = vec![0.0; sm.state_dim(opts)];
    let mut steps = vec![sm.record(&a0, &l0, 0)];
    let mut states = vec![q0.clone()];
    let mut status = (SceneStatus::Completed, String::new());
    let mut stats = PathStats::default();
    // the reduced model's indicator at its path's highest pressure (positive branch)
    let mut indicator: Option<(f64, f64)> = None;
    let mut warm_start_kpa = None;
    let mut warm_deltas = Vec::new();
    for branch in [pos, neg] {
        let Some(&p_end) = branch.last() else {
            continue;
        };
        let stations = &branch[..branch.len() - 1];
        // a warm start: the positive branch from a nearby design's state (see WarmStart)
        let mut warmed = None;
        // (reduced states only: they are modal amplitudes in per-node cylindrical frames, the
        // same for every design; the full model's Cartesian nodal states of a design 2° away
        // leave residuals of the order of the forces and indefinite tangents — measured)
        if let Some(w) = warm.filter(|_| p_end > 0.0 && opts.rom.is_some()) {
            let (&(p_e, v_e, _), rest) = w.points.split_last().expect("two points");
            // (at least WARM_GAP from the end: a start closer to it would leave the next design
            // only closer ones, and the steps from them grow from nothing)
            // (in volume where the branch ends at its pressure maximum, or where it is flat
            // between the start and its end, as a ballooning stop just below the maximum: under
            // load control the first step from there passed this design's maximum and failed)
            let flat = |c: &(f64, f64, Vec<f64>)| w.fold || (c.0 > 0.0 && c.1 > 0.0 && (v_e - c.1) / c.1 > WARM_FLAT * (p_e - c.0) / c.0);
            let far = |c: &&(f64, f64, Vec<f64>)| if flat(c) { c.1 <= (1.0 - WARM_GAP) * v_e } else { c.0 <= (1.0 - WARM_GAP) * p_e };
            /// A start tried from the nearby branch.
            struct Attempt<'w> {
                /// the state Newton starts from (before `correction`'s shift)
                guess: Vec<f64>,
                /// the nearby state it extrapolates
                origin: &'w Vec<f64>,
                /// that state is the nearby branch's pressure maximum
                from_end: bool,
                /// its pressure (kPa)
                p_kpa: f64,
                path: ContinuationOptions,
                correction: Guess,
            }
            let mut attempts: Vec<Attempt> = Vec::new();
            // first, where the nearby branch ended at its pressure maximum: its end state moved
            // on along the line (end to end), corrected WARM_FOLD_GAP below its volume, and a
            // first step to as far beyond it: the maximum is bracketed in one short step
            // (from a state further below, the first step's tangent-line prediction needed ≈ 5
            // iterations)
            let (q_e, d_e) = (&w.points[w.points.len() - 1].2, w.deltas.last().and_then(|d| d.as_deref()));
            if w.fold && p_e < p_end && q_e.len() == q0.len() {
                let wo = ContinuationOptions { start_control: Control::Functional, initial_functional: Some(2.0 * WARM_FOLD_GAP), ..opts.steps.clone() };
                // (the correction down from the maximum starts along the nearby branch's secant
                // from its maximum to its state nearest that far below: from the maximum itself
                // the first Newton iteration went to the volume change alone)
                let target = (1.0 - WARM_FOLD_GAP) * v_e;
                let below = w.points.iter().filter(|c| c.1 < v_e && c.2.len() == q0.len() && (c.1 - target).abs() <= 0.5 * WARM_FOLD_GAP * v_e).min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs()));
                let shift = below.map(|c| {
                    let s = (target - v_e) / (c.1 - v_e);
                    c.2.iter().zip(q_e).map(|(a, b)| s * (a - b)).collect()
                });
                attempts.push(Attempt { guess: extrapolated(q_e, d_e), origin: q_e, from_end: true, p_kpa: p_e, path: wo, correction: Guess { factor: 1.0 - WARM_FOLD_GAP, shift } });
            }
            for (cand, delta) in rest.iter().zip(&w.deltas).rev().filter(|(c, _)| far(c)).filter(|(c, _)| c.0 < p_end && c.2.len() == q0.len()).take(WARM_ATTEMPTS) {
                let (p_w, v_w, state) = cand;
                let wo = if flat(cand) && v_e > *v_w && *v_w > 0.0 {
                    ContinuationOptions { start_control: Control::Functional, initial_functional: Some(WARM_REACH * (v_e - v_w) / v_w), ..opts.steps.clone() }
                } else {
                    ContinuationOptions { initial: (WARM_REACH * (p_e - p_w) / (p_end - p_w)).clamp(opts.steps.min, 1.0), ..opts.steps.clone() }
                };
                attempts.push(Attempt { guess: extrapolated(state, delta.as_deref()), origin: state, from_end: false, p_kpa: *p_w, path: wo, correction: Guess::at(1.0) });
            }
            for Attempt { guess, origin, from_end, p_kpa: p_w, path: wo, correction } in attempts {
                let path = pressure_path_with(&sm, &wo, opts, &guess, p_w, p_end, stations, true, true, Some(correction));
                stats.add(&path.stats);
                if !(path.points.len() > 1 && path.points[0].record.max_radius_mm < opts.ballooning_limit_mm) {
                    continue;
                }
                let p0 = path.points[0].record.p_kpa;
                let delta = |q: &[f64]| q.iter().zip(origin).map(|(a, b)| a - b).collect::<Vec<f64>>();
                if !from_end {
                    warm_deltas.push((p0, delta(&path.points[0].q)));
                }
                // this branch's end from the nearby one's (both at a pressure maximum or
                // stability limit): the next design's first guess
                if let (true, Some((SceneStatus::LimitPoint, _)), Some(last)) = (w.fold, &path.end, path.points.last()) {
                    warm_deltas.push((last.record.p_kpa, delta(&last.q)));
                }
                warmed = Some((path, p0));
                break;
            }
        }
        let (path, skip) = match warmed {
            Some((path, p_w)) => {
                warm_start_kpa = Some(p_w);
                (path, 0)
            }
            None => {
                let path = pressure_path_with(&sm, &opts.steps, opts, &q0, 0.0, p_end, stations, true, true, None);
                stats.add(&path.stats);
                (path, 1)
            }
        };
        if let Some(ind) = path.indicator {
            indicator = Some(ind);
        }
        for p in path.points.into_iter().skip(skip) {
            steps.push(p.record);
            states.push(p.q);
        }
        // the positive branch's end is the scene's status unless it completed
        if let Some(e) = path.end {
            if status.0 == SceneStatus::Completed {
                status = e;
            }
        }
    }
    let snaps_kpa: Vec<f64> = steps.iter().filter(|s| s.snapped).map(|s| s.p_kpa).collect();
    let min_contact_distance_mm = steps.iter().filter_map(|s| s.contact_distance_mm).reduce(f64::min);
    let mut order: Vec<usize> = (0..steps.len()).collect();
    order.sort_by(|&a, &b| steps[a].p_kpa.total_cmp(&steps[b].p_kpa));
    let steps: Vec<StepRecord> = order.iter().map(|&i| steps[i].clone()).collect();
    let states: Vec<Vec<f64>> = order.iter().map(|&i| states[i].clone()).collect();
    let fields = opts.keep_fields.then(|| SceneFields {
        mesh: sm.model.mesh.clone(),
        formulation: opts.formulation,
        material: opts.material,
        displacements: steps
            .iter()
            .zip(&states)
            .map(|(s, q)| sm.model.assemble(&sm.full_state(opts, q), &sm.loads(s.p_kpa, 0.0), false).map(|a| a.u).unwrap_or_else(|_| vec![[0.0; 3]; sm.model.mesh.nodes.len()]))
            .collect(),
    });
    let rom_indicator = match (steps.last(), states.last()) {
        // (the path's own, where it is at the scene's highest recorded pressure)
        (Some(s), _) if opts.rom.is_some() && indicator.is_some_and(|(p, _)| p == s.p_kpa) => indicator.map(|(_, v)| v),
        (Some(s), Some(z)) if opts.rom.is_some() => rom_indicator(&sm, opts, z, s.p_kpa),
        _ => None,
    };
    Ok(SceneResult {
        snaps_kpa,
        min_contact_distance_mm,
        rom_indicator,
        rom_fallback: None,
        warm_start_kpa,
        warm: warm.filter(|_| warm_start_kpa.is_some()).cloned(),
        warm_deltas,
        scene: kind.name().to_string(),
        status: status.0,
        cause: status.1,
        steps,
        dofs: sm.state_dim(opts),
        elements: sm.model.mesh.n_elements(),
        newton_iterations: stats.newton_iterations,
        path: stats,
        wall_time_s: t0.elapsed().as_secs_f64(),
        fields,
        states,
    })
}

/// Add to `r` (a result of `kind` on `geom`) an exact step at pressure `p_kpa` inside one of its
/// branches, solved from the nearest recorded state between it and the unloaded state (no-op
/// when a step is already there or p lies beyond the branch). Used to evaluate the letter's Ω at
/// the lower of two scenes' failure pressures without interpolation.
pub fn add_step_at(geom: &ActuatorGeometry, opts: &SceneOptions, kind: SceneKind, r: &mut SceneResult, p_kpa: f64) -> Result<(), SceneError> {
    let opts = &*result_options(opts, r);
    let tol = 1e-9 * p_kpa.abs().max(1.0);
    if p_kpa == 0.0 || !p_kpa.is_finite() || r.steps.iter().any(|s| (s.p_kpa - p_kpa).abs() <= tol) || r.states.len() != r.steps.len() {
        return Ok(());
    }
    let sg = p_kpa.signum();
    let reach = r.steps.iter().map(|s| s.p_kpa * sg).fold(0.0, f64::max);
    if p_kpa * sg > reach {
        return Ok(());
    }
    let below = r.steps.iter().enumerate().filter(|(_, s)| s.p_kpa * sg >= 0.0 && s.p_kpa * sg < p_kpa * sg).max_by(|a, b| (a.1.p_kpa * sg).total_cmp(&(b.1.p_kpa * sg)));
    let Some(mut i) = below.map(|(i, _)| i) else {
        return Ok(());
    };
    // or, where that is the unloaded state (a warm-started branch has no states between 0 and
    // its start), from the nearest state above p, not a branch end at a pressure maximum
    let n = r.steps.len();
    let end_fold = r.status == SceneStatus::LimitPoint;
    let above = r.steps.iter().enumerate().filter(|(j, s)| s.p_kpa * sg > p_kpa * sg && !(end_fold && *j + 1 == n)).min_by(|a, b| (a.1.p_kpa * sg).total_cmp(&(b.1.p_kpa * sg)));
    let mut down = false;
    if let Some((j, _)) = above {
        if r.steps[i].p_kpa == 0.0 {
            i = j;
            down = true;
        }
    }
    let sm = SceneModel::build(geom, opts, kind)?;
    // a warm-started branch (reduced model) has no states between the unloaded one and its
    // start: the nearby design's state at the nearest pressure, corrected at p, is a closer
    // start than any of them (3-4 iterations, where the segment down from the start near the
    // pressure maximum took about 12, with a failed step, on the Table-I sweep)
    if let Some(w) = r.warm.as_ref().filter(|_| opts.rom.is_some()) {
        let near = w.points.iter().zip(&w.deltas).filter(|(c, _)| c.2.len() == r.states[i].len() && c.0 > 0.0 && (c.0 - p_kpa).abs() <= WARM_NEAR * p_kpa.abs()).min_by(|a, b| (a.0 .0 - p_kpa).abs().total_cmp(&(b.0 .0 - p_kpa).abs()));
        if let Some(((_, _, q), delta)) = near {
            let load = ContinuationOptions { start_control: Control::Load, ..opts.steps.clone() };
            let path = pressure_path_with(&sm, &load, opts, &extrapolated(q, delta.as_deref()), p_kpa, p_kpa, &[], false, false, Some(Guess::at(1.0)));
            r.newton_iterations += path.stats.newton_iterations;
            r.path.add(&path.stats);
            if let (None, Some(p)) = (&path.end, path.points.into_iter().last()) {
                r.warm_deltas.push((p_kpa, p.q.iter().zip(q).map(|(a, b)| a - b).collect()));
                insert_step(&sm, r, p, p_kpa);
                return Ok(());
            }
        }
    }
    // a short segment from a converged step: try it in one step (the step control shrinks it
    // if needed). Between the branch's last regular step and its pressure maximum the path is
    // nearly singular in p, so the segment goes under volume control there (under load control
    // its steps shrink towards the fold: 500 steps on a circular section whose two scenes'
    // maxima coincide to 1e-7); so does a segment down from a state above p (on a branch that
    // ends at a pressure maximum, such states lie close to it)
    let to_fold = end_fold && i + 2 == n;
    let start_control = if to_fold || down { Control::Functional } else { Control::Load };
    // down from a state near a pressure maximum: the first step in c from the branch's
    // quadratic shape there, p(c) ≈ p* − a (c − c*)² through the state and the maximum (the
    // tangent's dc/dλ, which the step would otherwise be converted by, grows without bound
    // towards the maximum: the step from it overshot, diverged and was retried three times)
    let initial_functional = if down && end_fold { down_step_functional(&r.steps[i], &r.steps[n - 1], p_kpa) } else { None };
    let short = ContinuationOptions { initial: 1.0, max: 1.0, start_control, initial_functional, max_steps: 50, ..opts.steps.clone() };
    let path = pressure_path_with(&sm, &short, opts, &r.states[i], r.steps[i].p_kpa, p_kpa, &[], false, false, None);
    r.newton_iterations += path.stats.newton_iterations;
    r.path.add(&path.stats);
    if path.end.is_none() {
        if let Some(p) = path.points.into_iter().last() {
            insert_step(&sm, r, p, p_kpa);
        }
    }
    Ok(())
}

/// Insert the converged point `p` at pressure `p_kpa` into `r`'s steps (by pressure).
fn insert_step(sm: &SceneModel, r: &mut SceneResult, mut p: ScenePoint, p_kpa: f64) {
    p.record.p_kpa = p_kpa;
    let k = r.steps.partition_point(|s| s.p_kpa < p_kpa);
    if let Some(f) = r.fields.as_mut() {
        if let Ok(a) = sm.model.assemble(&p.q, &sm.loads(p_kpa, 0.0), false) {
            f.displacements.insert(k.min(f.displacements.len()), a.u);
        }
    }
    r.steps.insert(k, p.record);
    r.states.insert(k, p.q);
}

/// A nearby design's state moved on by how the nearby design's own state there differed from
/// its predecessor's (None or a mismatched length: the state itself).
fn extrapolated(q: &[f64], delta: Option<&[f64]>) -> Vec<f64> {
    match delta {
        Some(d) if d.len() == q.len() => q.iter().zip(d).map(|(a, b)| a + b).collect(),
        _ => q.to_vec(),
    }
}

/// The first functional step (a fraction of the start's cavity volume) from the state `from`
/// down to the pressure `p_kpa` on a branch that ends at the pressure maximum `fold`, by the
/// branch's quadratic shape there (p(c) = p* − a (c − c*)² through both), 10 % beyond the
/// estimate so that the step passes p (the path then lands on it exactly); None where the
/// records do not bracket it that way.
fn down_step_functional(from: &StepRecord, fold: &StepRecord, p_kpa: f64) -> Option<f64> {
    let (pj, cj, ps, cs) = (from.p_kpa, from.cavity_volume_mm3, fold.p_kpa, fold.cavity_volume_mm3);
    if !(ps > pj && pj > p_kpa && cs > cj && cj > 0.0) {
        return None;
    }
    let ct = cs - (cs - cj) * ((ps - p_kpa) / (ps - pj)).sqrt();
    let f = WARM_REACH * (cj - ct) / cj;
    (f.is_finite() && f > 0.0).then_some(f)
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
    pub status: SceneStatus,
    #[serde(default)]
    pub cause: String,
}

/// The letter's Fig. 4b: for each pressure, the free rotation θ_f (from the `free` scene when
/// `axial_free`, else `pure-twist`), then τ at `n_points` rotations from 0 to θ_f (a path in the
/// prescribed rotation at fixed pressure, with a point at each rotation).
pub fn run_torque_rotation(geom: &ActuatorGeometry, opts: &SceneOptions, axial_free: bool, pressures_kpa: &[f64], n_points: usize) -> Result<Vec<TorqueRotation>, SceneError> {
    let (free_kind, held_kind) = if axial_free { (SceneKind::Free, SceneKind::Blocked) } else { (SceneKind::PureTwist, SceneKind::PureTwistBlocked) };
    let free = SceneModel::build(geom, opts, free_kind)?;
    let held = SceneModel::build(geom, opts, held_kind)?;
    let q0 = vec![0.0; free.state_dim(opts)];
    let n = n_points.max(1);
    let mut out = Vec::new();
    for &p in pressures_kpa {
        let fp = pressure_path(&free, opts, &q0, 0.0, p, &[], true);
        let theta_f = fp.points.last().map(|s| s.record.theta_deg).unwrap_or(0.0);
        if let Some(e) = fp.end {
            out.push(TorqueRotation { p_kpa: p, free_theta_deg: theta_f, points: vec![], nonlinearity: 0.0, status: e.0, cause: e.1 });
            continue;
        }
        let hp = pressure_path(&held, opts, &vec![0.0; held.state_dim(opts)], 0.0, p, &[], true);
        let mut status = SceneStatus::Completed;
        let mut cause = String::new();
        let mut pts = Vec::new();
        match (hp.end, hp.points.last()) {
            (Some(e), _) => (status, cause) = e,
            (None, None) => status = SceneStatus::Divergence,
            (None, Some(last)) => {
                pts.push((0.0, last.record.tau_nm));
                // the rotation path at fixed pressure (no volume control: λ is the rotation)
                let mut lp = held.path(held.loads(p, 0.0), held.loads(p, theta_f.to_radians()), None);
                lp.volume_control = false;
                let mut o = opts.steps.clone();
                o.switch_stiffness = None;
                o.initial = 1.0 / n as f64;
                let stations: Vec<f64> = (1..n).map(|k| k as f64 / n as f64).collect();
                let res = follow(&lp, &last.q, 0.0, 1.0, &stations, &[], &o);
                for pt in res.points.iter().filter(|pt| !matches!(pt.kind, PointKind::Start | PointKind::Step)) {
                    let rec = held.step_record(&pt.outputs, p, pt.min_det, pt.newton_iterations);
                    pts.push((theta_f * pt.lam, rec.tau_nm));
                }
                if let PathEnd::Failed(f) = res.end {
                    status = SceneStatus::from_failure(f);
                    cause = format!("the rotation path failed ({}) at θ = {:.3}°", f.as_str(), theta_f * res.points.last().map_or(0.0, |p| p.lam));
                } else if res.end != PathEnd::Completed {
                    status = SceneStatus::LimitPoint;
                    cause = "the rotation path lost stability".into();
                }
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
        out.push(TorqueRotation { p_kpa: p, free_theta_deg: theta_f, points: pts, nonlinearity, status, cause });
    }
    Ok(out)
}

/// The letter's energy density Ω = τθ/(8V), V = πR0²L (θ in rad, τ in N·m, V in m³) → J/m³.
pub fn energy_density(theta_deg: f64, tau_nm: f64) -> f64 {
    let v_m3 = std::f64::consts::PI * R0_ENVELOPE * R0_ENVELOPE * L_TUBE * 1e-9;
    tau_nm * theta_deg.to_radians() / (8.0 * v_m3)
}

#[cfg(test)]
impl StepRecord {
    /// A record at pressure `p_kpa` with the given twist, torque, max radius and cavity volume,
    /// the rest neutral (unit tests of the summaries built from records).
    pub(crate) fn for_test(p_kpa: f64, theta_deg: f64, tau_nm: f64, max_radius_mm: f64, cavity_volume_mm3: f64) -> StepRecord {
        StepRecord {
            p_kpa,
            theta_deg,
            axial_mm: 0.0,
            tau_nm,
            max_radius_mm,
            cavity_volume_mm3,
            min_det_f: 1.0,
            newton_iterations: 1,
            contact_distance_mm: None,
            penetration_mm: None,
            folded_elements: None,
            least_jacobian_ratio: None,
            snapped: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(p_kpa: f64, v_mm3: f64) -> StepRecord {
        StepRecord::for_test(p_kpa, 0.0, 0.0, 20.0, v_mm3)
    }

    #[test]
    fn the_step_down_from_near_a_pressure_maximum_follows_the_branchs_parabola() {
        // p(c) = 70 − 1e-6 (c − 20000)²: from c = 19000 (p = 69) down to p = 66, c = 18000
        let (from, fold) = (rec(69.0, 19_000.0), rec(70.0, 20_000.0));
        let f = down_step_functional(&from, &fold, 66.0).unwrap();
        assert!((f - WARM_REACH * 1000.0 / 19_000.0).abs() < 1e-12, "{f}");
        // no estimate where the records do not bracket it that way
        assert!(down_step_functional(&from, &fold, 69.5).is_none());
        assert!(down_step_functional(&fold, &from, 66.0).is_none());
    }

    #[test]
    fn a_state_is_moved_on_by_its_delta_when_the_lengths_match() {
        assert_eq!(extrapolated(&[1.0, 2.0], Some(&[0.5, -1.0])), vec![1.5, 1.0]);
        assert_eq!(extrapolated(&[1.0, 2.0], Some(&[0.5])), vec![1.0, 2.0]);
        assert_eq!(extrapolated(&[1.0, 2.0], None), vec![1.0, 2.0]);
    }
}
