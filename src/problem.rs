//! Problem files for `twistopt evaluate`: one design, material, load, scenes, fidelity and
//! outputs in a TOML file.
//!
//! # Schema
//!
//! ```toml
//! [design]                      # required
//! r_mm = 8.660254037844386      # arc radius of the horseshoe section, mm
//! l_mm = 10.0                   # waist radius of the bellows profile, mm
//! alpha_deg = 60.0              # pre-twist of the top face, degrees
//! range = "table1"              # "table1" (the letter's Table I box, default) | "extended"
//! variant = "spec"              # geometry reading (default "spec" = GEOMETRY.md): "spec" or any
//!                               # of tips-on-r | midpoint-centres, outward, twist-first joined by
//!                               # '+' (studies/letter-calibration/VARIANTS.md)
//! # end_tangent_deg = 0.0       # optional design parameter: the lateral profile's end-tangent
//!                               # angle from the vertical (absent = the spec's vertical ends)
//!
//! [design.shape]                # optional: freeform modes on top of (r, l, α) (absent = 0 = the
//!                               # letter's shape; geometry/freeform.rs)
//! # twist_1_deg = 10.0          # twist_k_deg, k = 1…8: coefficient of sin(kπz/L) added to the
//!                               # linear pre-twist αz/L (end-to-end twist stays α), ±90°
//! # profile_1_mm = -1.0         # profile_k_mm, k = 1…10: coefficient of sin²(πz/L)cos((k−1)πz/L)
//!                               # added to the bellows radius ρ(z) (ends unchanged), ±5 mm
//!
//! [material]                    # optional; Neo-Hookean
//! mu_MPa = 0.34                 # shear modulus (default 0.34, the letter's Hei-Cast 8400)
//! kappa_over_mu = 300           # bulk / shear modulus (default scene::DEFAULT_KAPPA_OVER_MU = 300:
//!                               # θ, τ within 0.5 % of κ/μ = 3000)
//!
//! [load]                        # required: exactly one of
//! pressures_kPa = [-68, -30, 30, 71]  # cavity pressures (negative = vacuum); each sign is a branch
//!                                     # ramped from 0 through its targets in order of magnitude
//! # p_max_kPa = 71              # ramp 0 → p_max (> 0) and record every converged step
//!
//! [scenes]                      # optional
//! run = ["free", "blocked"]     # any of free, blocked, pure-twist, pure-twist-blocked (default
//!                               # free + blocked)
//! full = false                  # true: full 360° model instead of the 120° sector (also --full)
//! ballooning_limit_mm = 28.75   # stop a ramp when the max deformed radius exceeds this (1.15·R0)
//! cap_load = true               # the pressure also pushes on the top cap (default); false = on
//!                               # the lateral wall only
//! # contact = { dhat_mm = 0.1, pressure_MPa = 0.1, reach_mm = 20, blend_mm = 0.02, stop_at_fold = true }
//!                               # frictionless self-contact of the cavity wall (vacuum): the
//!                               # barrier's reach d̂, the contact pressure at d̂/10, the reference
//!                               # distance of candidate wall pairs, the crease blend width; a
//!                               # vacuum ramp then snaps through the wall's collapse and goes on;
//!                               # optional axle_radius_mm = 2: the pure-twist scenes' rigid axle
//!                               # along the axis, which the cavity wall then also contacts
//!                               # stop_at_fold = true (default): the ramp ends where an
//!                               # element folds between its quadrature points (status
//!                               # inversion); false goes on and records folded_elements
//!
//! [torque_rotation]             # optional: the letter's Fig. 4b (torque vs prescribed rotation)
//! pressures_kPa = [30, 71]      # one line per pressure (non-zero)
//! points = 5                    # rotations from 0 to the free rotation (1 … 50)
//!
//! [fidelity]                    # optional; at most one of
//! preset = "default"            # "coarse" | "default" | "fine" | "sweep" (default "default")
//! # mesh = "48x16x2"            # N_around x N_along x N_through (Hex27)
//!
//! [output]                      # optional
//! vtu = true                    # ParaView series <scene>.pvd + one VTU per recorded step
//! ```
//!
//! The torque-rotation scene runs in the combined mode (axial motion free) when `free` and
//! `blocked` are both run, and in the pure-twist mode when `pure-twist` and
//! `pure-twist-blocked` are both run; it is an error to request it otherwise.
//!
//! Overrides `--set section.key=value` are applied to the TOML table before it is deserialised;
//! the value is parsed as TOML (`--set load.pressures_kPa=[10,20]`, `--set design.alpha_deg=120`)
//! and taken as a plain string when it is not valid TOML (`--set fidelity.preset=coarse`).
//! Unknown sections or keys, wrong types and out-of-range values are errors on one line naming
//! the field (`design.r_mm`, `load.p_max_kPa`, …).

use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

use crate::geometry::{ActuatorGeometry, Design, GeometryVariant, RangePolicy};
use crate::meshing::MeshSpec;
use crate::scene::{SceneKind, SceneOptions};
use twistopt_solver::material::{Material, NeoHookean};

/// A complete problem (the file after overrides, with defaults filled in).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Problem {
    pub design: DesignSection,
    #[serde(default)]
    pub material: MaterialSection,
    pub load: LoadSection,
    #[serde(default)]
    pub scenes: ScenesSection,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_rotation: Option<TorqueRotationSection>,
    #[serde(default)]
    pub fidelity: FidelitySection,
    #[serde(default)]
    pub output: OutputSection,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimise: Option<OptimiseSection>,
}

/// `[optimise]`: what `twistopt optimise` maximises and how (see [`crate::optimise`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimiseSection {
    /// `energy-density` (Ω = τθ/(8V) of the rotation-free and rotation-held scenes), `twist` (|θ|),
    /// `torque` (|τ|), or one of the two-sided objectives (they need `vacuum_kPa`): `stroke`
    /// (the bi-directional stroke |θ(+p) − θ(−p⁻)| of the rotation-free scene) and
    /// `energy-density-both` (Ω(+p) + Ω(−p⁻), the sum of both sides' energy densities)
    #[serde(default = "default_objective")]
    pub objective: String,
    /// p⁻ (kPa, > 0): the vacuum side of the two-sided objectives is evaluated at −p⁻ (fixed; a
    /// path through the wall's collapse needs `scenes.contact`)
    #[serde(rename = "vacuum_kPa", default, skip_serializing_if = "Option::is_none")]
    pub vacuum_kpa: Option<f64>,
    /// the variables; the others stay at [design] (and p at load.p_max_kPa)
    #[serde(default = "default_variables")]
    pub variables: Vec<String>,
    /// lower bound of the pressure variable (kPa); the upper bound is load.p_max_kPa
    #[serde(rename = "p_min_kPa", default = "default_p_min")]
    pub p_min_kpa: f64,
    /// any of `mma`, `slsqp` (nlopt; cargo feature `nlopt`) and `sqp` (pure Rust, clarabel QPs)
    #[serde(default = "default_optimisers")]
    pub optimisers: Vec<String>,
    /// number of starting designs (space-filling, see `start_from_design`, `start_spread`)
    #[serde(default = "default_starts")]
    pub starts: usize,
    /// the first start is the [design] itself (its values of the variables; p at load.p_max_kPa
    /// when p_kPa is a variable), the others space-filling
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub start_from_design: bool,
    /// the pressure of that start when p_kPa is a variable (default load.p_max_kPa)
    #[serde(rename = "start_p_kPa", default, skip_serializing_if = "Option::is_none")]
    pub start_p_kpa: Option<f64>,
    /// the space-filling starts fill this fraction of the box around the [design] (1: the whole
    /// box; e.g. 0.2 for many freeform modes, where most of the box is not a valid geometry)
    #[serde(default = "default_start_spread", skip_serializing_if = "is_one")]
    pub start_spread: f64,
    /// FE design evaluations per optimiser run (each = every scene's forward solve + adjoint)
    #[serde(default = "default_max_evaluations")]
    pub max_evaluations: usize,
    /// stop when the scaled design moves less than this (relative)
    #[serde(default = "default_xtol")]
    pub xtol_rel: f64,
    /// stop when the objective changes less than this (relative)
    #[serde(default = "default_ftol")]
    pub ftol_rel: f64,
    /// KS aggregation parameter of the max radius (1/mm)
    #[serde(rename = "ks_rho_per_mm", default = "default_ks_rho")]
    pub ks_rho_per_mm: f64,
    /// Multi-fidelity continuation (optional): each run optimises on the first stage's mesh,
    /// then restarts from its best design on the next stage's mesh, and so on; the result is the
    /// last stage's. Without stages a run uses [fidelity] and max_evaluations. With stages,
    /// max_evaluations is the cap on their sum.
    #[serde(default)]
    pub stages: Vec<StageSection>,
}

/// One fidelity stage of `[[optimise.stages]]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSection {
    /// a mesh preset (`coarse`, `default`, `fine`, `sweep`) ...
    pub preset: Option<String>,
    /// ... or an explicit `<Na>x<Nz>x<Nt>` mesh
    pub mesh: Option<String>,
    /// FE design evaluations of this stage
    pub max_evaluations: usize,
    /// a reduced-order model directory trained for this stage's mesh (`twistopt rom train`):
    /// the stage's evaluations and gradients run on it
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom: Option<String>,
    /// this stage's stopping tolerances (default: optimise.xtol_rel / ftol_rel); an early,
    /// cheap stage need not converge tightly
    pub xtol_rel: Option<f64>,
    pub ftol_rel: Option<f64>,
}

fn default_objective() -> String {
    "energy-density".into()
}
fn default_variables() -> Vec<String> {
    vec!["r_mm".into(), "l_mm".into(), "alpha_deg".into(), "p_kPa".into()]
}
fn default_p_min() -> f64 {
    5.0
}
fn default_optimisers() -> Vec<String> {
    vec!["mma".into(), "slsqp".into()]
}
fn default_starts() -> usize {
    3
}
fn default_start_spread() -> f64 {
    1.0
}
fn is_one(x: &f64) -> bool {
    *x == 1.0
}
fn default_max_evaluations() -> usize {
    100
}
fn default_xtol() -> f64 {
    1e-4
}
fn default_ftol() -> f64 {
    1e-6
}
fn default_ks_rho() -> f64 {
    crate::gradient::DEFAULT_KS_RHO_PER_MM
}

/// Which design box the design is validated against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RangeName {
    #[default]
    Table1,
    Extended,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignSection {
    pub r_mm: f64,
    pub l_mm: f64,
    pub alpha_deg: f64,
    #[serde(default)]
    pub range: RangeName,
    /// geometry reading (default: the spec; omitted from the echo when it is)
    #[serde(default, skip_serializing_if = "GeometryVariant::is_spec")]
    pub variant: GeometryVariant,
    /// optional design parameter: the profile's end-tangent angle (degrees)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end_tangent_deg: Option<f64>,
    /// freeform shape parameters by name (`[design.shape]`: twist_k_deg, profile_k_mm; absent =
    /// 0 = the letter's shape)
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub shape: std::collections::BTreeMap<String, f64>,
}

impl DesignSection {
    /// The design (parameters and variant) of this section.
    pub fn design(&self) -> Design {
        let mut d = Design::new(self.r_mm, self.l_mm, self.alpha_deg).with_variant(self.variant);
        d.values.extend(self.shape.iter().map(|(k, v)| (k.clone(), *v)));
        match self.end_tangent_deg {
            Some(g) => d.with_end_tangent(g),
            None => d,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSection {
    #[serde(rename = "mu_MPa", default = "default_mu")]
    pub mu_mpa: f64,
    #[serde(default = "default_kappa_over_mu")]
    pub kappa_over_mu: f64,
}

fn default_mu() -> f64 {
    crate::scene::MU_HEICAST_MPA
}
fn default_kappa_over_mu() -> f64 {
    crate::scene::DEFAULT_KAPPA_OVER_MU
}

impl Default for MaterialSection {
    fn default() -> Self {
        MaterialSection { mu_mpa: default_mu(), kappa_over_mu: default_kappa_over_mu() }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSection {
    #[serde(rename = "pressures_kPa", default, skip_serializing_if = "Option::is_none")]
    pub pressures_kpa: Option<Vec<f64>>,
    #[serde(rename = "p_max_kPa", default, skip_serializing_if = "Option::is_none")]
    pub p_max_kpa: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenesSection {
    #[serde(default = "default_scenes")]
    pub run: Vec<String>,
    #[serde(default)]
    pub full: bool,
    #[serde(default = "default_ballooning")]
    pub ballooning_limit_mm: f64,
    /// whether the pressure also pushes on the top cap (default true; omitted from the echo then)
    #[serde(default = "default_true", skip_serializing_if = "is_true")]
    pub cap_load: bool,
    /// frictionless self-contact of the cavity wall under vacuum (absent: not modelled, a vacuum
    /// ramp stops where two walls come close)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact: Option<crate::scene::ContactOptions>,
}

fn is_true(b: &bool) -> bool {
    *b
}

fn default_scenes() -> Vec<String> {
    vec!["free".into(), "blocked".into()]
}
fn default_ballooning() -> f64 {
    1.15 * crate::geometry::R0_ENVELOPE
}

impl Default for ScenesSection {
    fn default() -> Self {
        ScenesSection { run: default_scenes(), full: false, ballooning_limit_mm: default_ballooning(), cap_load: true, contact: None }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorqueRotationSection {
    #[serde(rename = "pressures_kPa")]
    pub pressures_kpa: Vec<f64>,
    #[serde(default = "default_points")]
    pub points: usize,
}

fn default_points() -> usize {
    5
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FidelitySection {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// a reduced-order model directory (`twistopt rom train`): the scenes run on it instead of
    /// the full model; it must have been trained for this mesh, element, material and scenes
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom: Option<String>,
    /// with `rom`: a scene whose reduced ramp ends with an error indicator above this value (or
    /// in a solver failure) is run again on the full model; default: the model's calibrated
    /// value (`rom validate --calibrate`), else none; `inf` turns the fallback off
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom_fallback: Option<f64>,
}

impl Default for FidelitySection {
    fn default() -> Self {
        FidelitySection { preset: Some("default".into()), mesh: None, rom: None, rom_fallback: None }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSection {
    #[serde(default = "default_true")]
    pub vtu: bool,
}

fn default_true() -> bool {
    true
}

impl Default for OutputSection {
    fn default() -> Self {
        OutputSection { vtu: true }
    }
}

/// How the pressure is applied.
#[derive(Clone, Debug, PartialEq)]
pub enum LoadPlan {
    /// Ramp through these targets (both signs allowed); record the states at the targets.
    Targets(Vec<f64>),
    /// Ramp 0 → p_max and record every converged step.
    Ramp(f64),
}

impl LoadPlan {
    /// Targets for [`crate::scene::run_pressure`].
    pub fn targets(&self) -> Vec<f64> {
        match self {
            LoadPlan::Targets(t) => t.clone(),
            LoadPlan::Ramp(p) => vec![*p],
        }
    }
}

/// A validated problem: everything needed to run the scenes.
pub struct Validated {
    pub geometry: ActuatorGeometry,
    pub mesh: MeshSpec,
    pub material: Material,
    pub scenes: Vec<SceneKind>,
    pub load: LoadPlan,
    /// the reduced model of `fidelity.rom`, loaded and checked against the problem
    pub rom: Option<(std::sync::Arc<twistopt_solver::rom::Rom>, crate::rom::Manifest)>,
}

impl Problem {
    /// Read a problem file and apply `--set` overrides (`section.key=value`).
    pub fn load(path: &Path, overrides: &[String]) -> Result<Problem> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read problem file {}", path.display()))?;
        Self::from_str_with(&text, &path.display().to_string(), overrides)
    }

    /// Parse problem text (`origin` names it in error messages) and apply overrides.
    pub fn from_str_with(text: &str, origin: &str, overrides: &[String]) -> Result<Problem> {
        let mut table: toml::Table = toml::from_str(text).map_err(|e| anyhow!("{origin}: {}", located(&e, text)))?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        // Deserialise through the text of the merged table so that errors carry a position,
        // which names the section and key.
        let merged = toml::to_string(&table).map_err(|e| anyhow!("{origin}: cannot re-serialise the problem: {e}"))?;
        toml::from_str::<Problem>(&merged).map_err(|e| anyhow!("{origin}: {}", named(&e, &merged)))
    }

    /// Check every field; the first problem found is returned as a one-line error naming it.
    pub fn validate(&self) -> Result<Validated> {
        let d = &self.design;
        let policy = match d.range {
            RangeName::Table1 => RangePolicy::TableI,
            RangeName::Extended => RangePolicy::Extended,
        };
        for k in d.shape.keys() {
            if crate::geometry::freeform::parse_param(k).is_none() {
                let known: Vec<String> = crate::geometry::DesignSpace::freeform().params.into_iter().skip(3).map(|p| p.name).collect();
                bail!("design.shape.{k}: unknown freeform shape parameter (known: {})", known.join(", "));
            }
        }
        let geometry = ActuatorGeometry::new(&d.design(), policy).map_err(|e| {
            // the geometry's hint names the CLI flag of `geometry`; here the switch is design.range
            let msg = e.to_string().replace("pass --extended-range / RangePolicy::Extended", "set design.range = \"extended\"");
            let shape = msg.split([' ', ':']).next().is_some_and(|w| w.starts_with("twist_") || w.starts_with("profile_"));
            if shape {
                anyhow!("design.shape.{msg}")
            } else {
                anyhow!("design.{msg}")
            }
        })?;
        let m = &self.material;
        let material: Material = NeoHookean::with_ratio(m.mu_mpa, m.kappa_over_mu)
            .map_err(|_| {
                if !(m.mu_mpa.is_finite() && m.mu_mpa > 0.0) {
                    anyhow!("material.mu_MPa = {} is not allowed (shear modulus must be finite and > 0)", m.mu_mpa)
                } else {
                    anyhow!("material.kappa_over_mu = {} is not allowed (must be finite and >= 1)", m.kappa_over_mu)
                }
            })?
            .into();
        let load = match (&self.load.pressures_kpa, self.load.p_max_kpa) {
            (Some(_), Some(_)) => {
                bail!("load: give either load.pressures_kPa or load.p_max_kPa, not both")
            }
            (None, None) => bail!("load: missing load.pressures_kPa (list of kPa) or load.p_max_kPa (ramp end, kPa)"),
            (Some(list), None) => {
                if list.is_empty() {
                    bail!("load.pressures_kPa is empty (give at least one non-zero pressure in kPa)");
                }
                check_pressures("load.pressures_kPa", list)?;
                let mut t = list.clone();
                t.sort_by(f64::total_cmp);
                t.dedup();
                LoadPlan::Targets(t)
            }
            (None, Some(p)) => {
                if !(p.is_finite() && p > 0.0) {
                    bail!("load.p_max_kPa = {p} must be finite and > 0 (use load.pressures_kPa for vacuum)");
                }
                LoadPlan::Ramp(p)
            }
        };
        let s = &self.scenes;
        if s.run.is_empty() {
            bail!("scenes.run is empty (choose from free, blocked, pure-twist, pure-twist-blocked)");
        }
        let mut scenes = Vec::new();
        for name in &s.run {
            let k = SceneKind::parse(name).ok_or_else(|| anyhow!("scenes.run: unknown scene '{name}' (expected free, blocked, pure-twist or pure-twist-blocked)"))?;
            if scenes.contains(&k) {
                bail!("scenes.run: scene '{name}' is listed twice");
            }
            scenes.push(k);
        }
        if let Some(c) = &s.contact {
            for (k, v) in [("dhat_mm", c.dhat_mm), ("pressure_MPa", c.pressure_mpa), ("reach_mm", c.reach_mm), ("blend_mm", c.blend_mm)] {
                if !(v.is_finite() && v > 0.0) {
                    bail!("scenes.contact.{k} = {v} must be finite and positive");
                }
            }
            if let Some(a) = c.axle_radius_mm {
                if !(a.is_finite() && a > 0.0) {
                    bail!("scenes.contact.axle_radius_mm = {a} must be finite and positive");
                }
                if !scenes.iter().any(|k| matches!(k, crate::scene::SceneKind::PureTwist | crate::scene::SceneKind::PureTwistBlocked)) {
                    bail!("scenes.contact.axle_radius_mm: the axle is in the pure-twist scenes only, and scenes.run has none");
                }
            }
            // each cavity node ignores the cavity surface within one wall thickness t of it
            // (`solver::contact::self_contact`): a reach inside that finds no other wall
            if c.reach_mm <= crate::geometry::T_WALL {
                bail!(
                    "scenes.contact.reach_mm = {} must exceed the excluded neighbourhood t = {} mm (each node ignores the cavity surface within one wall thickness of it)",
                    c.reach_mm,
                    crate::geometry::T_WALL
                );
            }
        }
        if !(s.ballooning_limit_mm.is_finite() && s.ballooning_limit_mm > crate::geometry::R_TUBE) {
            bail!("scenes.ballooning_limit_mm = {} must be finite and larger than the undeformed radius {} mm", s.ballooning_limit_mm, crate::geometry::R_TUBE);
        }
        if let Some(tr) = &self.torque_rotation {
            if tr.pressures_kpa.is_empty() {
                bail!("torque_rotation.pressures_kPa is empty (give at least one non-zero pressure in kPa)");
            }
            check_pressures("torque_rotation.pressures_kPa", &tr.pressures_kpa)?;
            if !(1..=50).contains(&tr.points) {
                bail!("torque_rotation.points = {} must be between 1 and 50", tr.points);
            }
            let has = |k: SceneKind| scenes.contains(&k);
            let combined = has(SceneKind::Free) && has(SceneKind::Blocked);
            let pure = has(SceneKind::PureTwist) && has(SceneKind::PureTwistBlocked);
            if !combined && !pure {
                bail!("torque_rotation needs scenes.run to include both free and blocked (combined mode) or both pure-twist and pure-twist-blocked");
            }
        }
        let f = &self.fidelity;
        let mesh = match (&f.preset, &f.mesh) {
            (Some(_), Some(_)) => {
                bail!("fidelity: give either fidelity.preset or fidelity.mesh, not both")
            }
            (Some(p), None) => MeshSpec::preset(p).map_err(|e| anyhow!("fidelity.preset: {e}"))?,
            (None, Some(m)) => {
                if !m.trim().chars().next().is_some_and(|c| c.is_ascii_digit()) {
                    bail!("fidelity.mesh = '{m}' is not <Na>x<Nz>x<Nt> (e.g. 48x16x2; use fidelity.preset for a preset name)");
                }
                MeshSpec::parse(m).map_err(|e| anyhow!("fidelity.mesh: {e}"))?
            }
            (None, None) => MeshSpec::preset("default").map_err(|e| anyhow!("fidelity: {e}"))?,
        };
        let mut v = Validated { geometry, mesh, material, scenes, load, rom: None };
        if let Some(t) = self.fidelity.rom_fallback {
            if !(t >= 0.0) {
                bail!("fidelity.rom_fallback = {t}: the error-indicator threshold must be >= 0 (inf: no fallback)");
            }
            if self.fidelity.rom.is_none() {
                bail!("fidelity.rom_fallback needs fidelity.rom (a reduced model to fall back from)");
            }
        }
        if let Some(dir) = &self.fidelity.rom {
            let (rom, manifest) = crate::rom::load(Path::new(dir), &self.scene_options(&v)).map_err(|e| anyhow!("fidelity.rom: {e:#}"))?;
            if let Some(why) = crate::rom::outside_box(&manifest.design_box, &v.geometry.design) {
                bail!("fidelity.rom: {why}");
            }
            if let Some(why) = v.scenes.iter().find_map(|&k| crate::rom::untrained_scene(&manifest.options.scenes, k)) {
                bail!("fidelity.rom: {why}");
            }
            v.rom = Some((std::sync::Arc::new(rom), manifest));
        }
        Ok(v)
    }

    /// Scene options for the validated problem.
    pub fn scene_options(&self, v: &Validated) -> SceneOptions {
        let mut o = SceneOptions::new(v.mesh, v.material);
        o.sector = !self.scenes.full;
        o.ballooning_limit_mm = self.scenes.ballooning_limit_mm;
        o.keep_fields = self.output.vtu;
        o.cap_load = self.scenes.cap_load;
        o.contact = self.scenes.contact;
        if let Some((rom, m)) = &v.rom {
            o.rom = Some(rom.clone());
            o.rom_box = m.design_box.clone();
            o.rom_scenes = m.options.scenes.clone();
            o.rom_fallback = self.fidelity.rom_fallback.or(m.fallback_indicator).filter(|t| t.is_finite());
        }
        o
    }
}

fn check_pressures(field: &str, list: &[f64]) -> Result<()> {
    for p in list {
        if !p.is_finite() {
            bail!("{field} contains a non-finite pressure ({p})");
        }
        if *p == 0.0 {
            bail!("{field} contains 0 (the unloaded state is always recorded; give non-zero pressures)");
        }
        if p.abs() > 1.0e4 {
            bail!("{field} contains {p} kPa; the allowed magnitude is at most 10000 kPa");
        }
    }
    Ok(())
}

/// Apply one `section.key=value` override to the table.
pub fn apply_override(table: &mut toml::Table, o: &str) -> Result<()> {
    let (path, value) = o.split_once('=').ok_or_else(|| anyhow!("--set '{o}': expected section.key=value"))?;
    let keys: Vec<&str> = path.trim().split('.').map(str::trim).collect();
    if keys.len() < 2 || keys.iter().any(|k| k.is_empty()) {
        bail!("--set '{o}': expected section.key=value (e.g. design.alpha_deg=120)");
    }
    let value = value.trim();
    let parsed = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").ok_or_else(|| anyhow!("--set '{o}': no value"))?,
        Err(_) => {
            if value.is_empty() {
                bail!("--set '{o}': empty value");
            }
            toml::Value::String(value.to_string())
        }
    };
    let mut t = table;
    for k in &keys[..keys.len() - 1] {
        let entry = t.entry(k.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        t = entry.as_table_mut().ok_or_else(|| anyhow!("--set '{o}': '{k}' is not a section"))?;
    }
    let last = keys[keys.len() - 1];
    // setting one of two alternatives replaces the other (a list overrides a ramp and vice versa)
    for (a, b) in [("pressures_kPa", "p_max_kPa"), ("preset", "mesh")] {
        if keys.len() == 2 && (keys[0] == "load" || keys[0] == "fidelity") {
            if last == a {
                t.remove(b);
            } else if last == b {
                t.remove(a);
            }
        }
    }
    t.insert(last.to_string(), parsed);
    Ok(())
}

/// 1-based line and column of a byte offset.
fn line_col(text: &str, at: usize) -> (usize, usize) {
    let at = at.min(text.len());
    let before = &text[..at];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map(|i| at - i).unwrap_or(at + 1);
    (line, col)
}

/// A parse error on one line with its position.
fn located(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().replace('\n', " ");
    match e.span() {
        Some(s) => {
            let (l, c) = line_col(text, s.start);
            format!("line {l}, column {c}: {msg}")
        }
        None => msg,
    }
}

/// A deserialisation error of the merged table on one line, naming `section.key` from the
/// error's position in the re-serialised text.
fn named(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().replace('\n', " ");
    let Some(span) = e.span() else { return msg };
    if span.start == 0 && span.end == 0 {
        // about the whole document: a missing or unknown top-level section
        if let Some(f) = msg.strip_prefix("missing field ") {
            return format!("missing section [{}]", f.trim_matches('`'));
        }
        return msg;
    }
    let start = span.start.min(text.len());
    let line_start = text[..start].rfind('\n').map(|i| i + 1).unwrap_or(0);
    let line_end = text[start..].find('\n').map(|i| start + i).unwrap_or(text.len());
    let line = text[line_start..line_end].trim();
    let section = text[..line_start].lines().rev().map(str::trim).find(|l| l.starts_with('[') && l.ends_with(']')).map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_string());
    if line.starts_with('[') {
        // the error is about a whole section (missing field, unknown section)
        let sec = line.trim_matches(|c| c == '[' || c == ']').trim();
        if msg.contains("unknown field") {
            return format!("unknown section [{sec}]: {msg}");
        }
        return format!("[{sec}]: {msg}");
    }
    match (line.split_once('='), section) {
        (Some((k, _)), Some(sec)) => format!("{sec}.{}: {msg}", k.trim().trim_matches('"')),
        (Some((k, _)), None) => {
            let k = k.trim().trim_matches('"');
            if msg.contains("unknown field") {
                format!("unknown section '{k}': {msg}")
            } else {
                format!("{k}: {msg}")
            }
        }
        _ => msg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = "[design]\nr_mm = 10\nl_mm = 12\nalpha_deg = 90\n[load]\npressures_kPa = [10, 20]\n";

    #[test]
    fn defaults_and_overrides() {
        let p = Problem::from_str_with(BASE, "t", &[]).unwrap();
        assert_eq!(p.material.mu_mpa, 0.34);
        assert_eq!(p.material.kappa_over_mu, crate::scene::DEFAULT_KAPPA_OVER_MU);
        assert_eq!(p.scenes.run, vec!["free", "blocked"]);
        assert!((p.scenes.ballooning_limit_mm - 28.75).abs() < 1e-12);
        assert_eq!(p.fidelity.preset.as_deref(), Some("default"));
        assert!(p.output.vtu);
        let p = Problem::from_str_with(BASE, "t", &["design.alpha_deg=120".into(), "load.p_max_kPa=50".into(), "fidelity.preset=coarse".into(), "scenes.run=[\"pure-twist\"]".into()]).unwrap();
        assert_eq!(p.design.alpha_deg, 120.0);
        assert_eq!(p.load.p_max_kpa, Some(50.0));
        assert_eq!(p.load.pressures_kpa, None);
        assert_eq!(p.fidelity.preset.as_deref(), Some("coarse"));
        let v = p.validate().unwrap();
        assert_eq!(v.load, LoadPlan::Ramp(50.0));
        assert_eq!(v.scenes, vec![SceneKind::PureTwist]);
        assert_eq!(v.mesh.size_string(), "24x8x1");
    }

    fn err(text: &str, sets: &[&str]) -> String {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        match Problem::from_str_with(text, "t", &sets).and_then(|p| p.validate().map(|_| ())) {
            Ok(()) => panic!("expected an error for {text:?} {sets:?}"),
            Err(e) => format!("{e:#}"),
        }
    }

    #[test]
    fn contact_key() {
        // absent: not modelled, not echoed
        let p = Problem::from_str_with(BASE, "t", &[]).unwrap();
        let v = p.validate().unwrap();
        assert!(p.scene_options(&v).contact.is_none());
        assert!(!toml::to_string(&p).unwrap().contains("contact"));
        // a table with some keys: the rest take their defaults
        let p = Problem::from_str_with(BASE, "t", &["scenes.contact={reach_mm = 15.0}".into()]).unwrap();
        let v = p.validate().unwrap();
        let c = p.scene_options(&v).contact.unwrap();
        assert_eq!(c, crate::scene::ContactOptions { reach_mm: 15.0, ..Default::default() });
        assert!(toml::to_string(&p).unwrap().contains("reach_mm = 15.0"));
        assert!(c.stop_at_fold, "a vacuum ramp ends at a folded element by default");
        let p = Problem::from_str_with(BASE, "t", &["scenes.contact={stop_at_fold = false}".into()]).unwrap();
        assert!(!p.scene_options(&p.validate().unwrap()).contact.unwrap().stop_at_fold);
        let e = err(BASE, &["scenes.contact={stop_at_fold = 1}"]);
        assert!(e.contains("stop_at_fold"), "{e}");
        let e = err(BASE, &["scenes.contact={dhat_mm = -0.1}"]);
        assert!(e.starts_with("scenes.contact.dhat_mm = -0.1 must be finite and positive"), "{e}");
        let e = err(BASE, &["scenes.contact={reach_mm = 2.0}"]);
        assert!(e.contains("must exceed the excluded neighbourhood"), "{e}");
        let e = err(BASE, &["scenes.contact={reach = 2.0}"]);
        assert!(e.contains("unknown field `reach`"), "{e}");
        // the axle: pure-twist scenes only, a positive radius
        let e = err(BASE, &["scenes.contact={axle_radius_mm = 2.0}", "scenes.run=[\"free\"]"]);
        assert!(e.contains("pure-twist scenes only"), "{e}");
        let e = err(BASE, &["scenes.contact={axle_radius_mm = -2.0}", "scenes.run=[\"pure-twist\"]"]);
        assert!(e.starts_with("scenes.contact.axle_radius_mm = -2 must be finite and positive"), "{e}");
        let p = Problem::from_str_with(BASE, "t", &["scenes.contact={axle_radius_mm = 2.0}".into(), "scenes.run=[\"pure-twist\"]".into()]).unwrap();
        let v = p.validate().unwrap();
        assert_eq!(p.scene_options(&v).contact.unwrap().axle_radius_mm, Some(2.0));
    }

    #[test]
    fn freeform_shape_table() {
        let p = Problem::from_str_with(BASE, "t", &["design.shape={twist_2_deg = -10.0, profile_1_mm = 0.5}".into()]).unwrap();
        let v = p.validate().unwrap();
        assert_eq!(v.geometry.design.get("twist_2_deg").unwrap(), -10.0);
        assert_eq!(v.geometry.design.get("profile_1_mm").unwrap(), 0.5);
        assert!(v.geometry.act.is_freeform());
        assert!(v.geometry.design.parameter_names().contains(&"profile_1_mm".to_string()));
        // the echo keeps the table
        assert!(toml::to_string(&p).unwrap().contains("twist_2_deg"));
        let e = err(BASE, &["design.shape={twist_9_deg = 1.0}"]);
        assert!(e.starts_with("design.shape.twist_9_deg: unknown freeform") && e.contains("twist_8_deg"), "{e}");
        let e = err(BASE, &["design.shape={twist_1_deg = 120.0}"]);
        assert!(e.starts_with("design.shape.twist_1_deg = 120") && e.contains("[-90, 90] deg"), "{e}");
        let e = err(BASE, &["design.shape={profile_1_mm = 5.0}", "design.l_mm=18"]);
        assert!(e.starts_with("design.shape.profile_*_mm:") && e.contains("exceeds the tube radius"), "{e}");
    }

    #[test]
    fn geometry_variant_end_tangent_and_cap_load_keys() {
        // defaults: the spec, no end tangent, cap loaded; none of them echoed
        let p = Problem::from_str_with(BASE, "t", &[]).unwrap();
        assert!(p.design.variant.is_spec() && p.design.end_tangent_deg.is_none() && p.scenes.cap_load);
        let echo = toml::to_string(&p).unwrap();
        assert!(!echo.contains("variant") && !echo.contains("end_tangent") && !echo.contains("cap_load"), "{echo}");
        let v = p.validate().unwrap();
        assert!(v.geometry.design.variant.is_spec() && v.geometry.act.profile.gamma.is_none());
        assert!(p.scene_options(&v).cap_load);
        // set: parsed, validated and passed on
        let p = Problem::from_str_with(BASE, "t", &["design.variant=\"outward+tips-on-r\"".into(), "design.end_tangent_deg=8".into(), "scenes.cap_load=false".into()]).unwrap();
        assert_eq!(p.design.variant.name(), "tips-on-r+outward");
        let v = p.validate().unwrap();
        assert_eq!(v.geometry.design.variant, p.design.variant);
        assert_eq!(v.geometry.design.end_tangent_deg(), Some(8.0));
        assert!(v.geometry.act.profile.gamma.is_some());
        assert!(!p.scene_options(&v).cap_load);
        let echo = toml::to_string(&p).unwrap();
        assert!(echo.contains("variant = \"tips-on-r+outward\"") && echo.contains("cap_load = false"), "{echo}");
        // a bare word works through --set too
        let p = Problem::from_str_with(BASE, "t", &["design.variant=twist-first".into()]).unwrap();
        assert_eq!(p.design.variant.name(), "twist-first");
    }

    #[test]
    fn bad_variant_names_the_field_and_lists_the_valid_values() {
        let e = err(BASE, &["design.variant=\"inward\""]);
        assert!(e.starts_with("t: design.variant:") && e.contains("'inward'"), "{e}");
        for name in crate::geometry::variant::variant_names() {
            assert!(e.contains(&format!("\"{name}\"")), "{e} lacks {name}");
        }
        assert_eq!(e.lines().count(), 1, "{e}");
        let e = err(BASE, &["design.variant=\"tips-on-r+midpoint-centres\""]);
        assert!(e.contains("design.variant") && e.contains("section reading"), "{e}");
        let e = err(BASE, &["design.end_tangent_deg=75"]);
        assert!(e.starts_with("design.end_tangent_deg = 75") && e.contains("[-30, 60] deg"), "{e}");
        // beyond the profile's existence at this l (12 mm: about 39.8°)
        let e = err(BASE, &["design.end_tangent_deg=45"]);
        assert!(e.starts_with("design.end_tangent_deg = 45") && e.contains("l_mm = 12") && e.contains("end arcs"), "{e}");
        let e = err(BASE, &["scenes.cap_load=\"no\""]);
        assert!(e.contains("scenes.cap_load"), "{e}");
    }

    #[test]
    fn errors_name_the_field() {
        let e = err(BASE, &["design.r_m=3"]);
        assert!(e.contains("design.r_m") && e.contains("unknown field"), "{e}");
        let e = err(BASE, &["design.alpha_deg=\"abc\""]);
        assert!(e.contains("design.alpha_deg"), "{e}");
        let e = err(BASE, &["desing.r_mm=3"]);
        assert!(e.contains("desing"), "{e}");
        let e = err(BASE, &["design.r_mm=3"]);
        assert!(e.contains("r_mm"), "{e}");
        let e = err(BASE, &["load.pressures_kPa=[]"]);
        assert!(e.contains("load.pressures_kPa"), "{e}");
        let e = err(BASE, &["load.p_max_kPa=-5"]);
        assert!(e.contains("load.p_max_kPa"), "{e}");
        let e = err(BASE, &["load.p_max_kPa=nan"]);
        assert!(e.contains("load.p_max_kPa"), "{e}");
        let e = err(BASE, &["scenes.run=[\"twist\"]"]);
        assert!(e.contains("scenes.run") && e.contains("twist"), "{e}");
        let e = err(BASE, &["fidelity.preset=huge"]);
        assert!(e.contains("fidelity.preset"), "{e}");
        let e = err(BASE, &["fidelity.mesh=40x16x2"]);
        assert!(e.contains("fidelity.mesh") && e.contains("n_around"), "{e}");
        let e = err(BASE, &["material.mu_MPa=0"]);
        assert!(e.contains("material.mu_MPa"), "{e}");
        let e = err(BASE, &["material.kappa_over_mu=0.5"]);
        assert!(e.contains("material.kappa_over_mu"), "{e}");
        let e = err(BASE, &["torque_rotation.pressures_kPa=[10]", "scenes.run=[\"free\"]"]);
        assert!(e.contains("torque_rotation"), "{e}");
        let e = err("[design]\nr_mm = 10\nl_mm = 12\n[load]\np_max_kPa = 5\n", &[]);
        assert!(e.contains("alpha_deg"), "{e}");
        let e = err("[design]\nr_mm = 10\nl_mm = 12\nalpha_deg = 90\n", &[]);
        assert!(e.contains("missing section [load]"), "{e}");
        let e = err("[design]\nr_mm = 10\nl_mm = 12\n", &[]);
        assert!(e.contains("[design]") && e.contains("alpha_deg"), "{e}");
        let e = err(BASE, &["design.r_mm=3"]);
        assert!(e.starts_with("design.r_mm = 3") && e.contains("design.range"), "{e}");
        let e = err("[design\nr_mm = 10\n", &[]);
        assert!(e.contains("line 1"), "{e}");
        let e = err(BASE, &["bogus"]);
        assert!(e.contains("--set"), "{e}");
        for e in [err(BASE, &["design.r_m=3"]), err("[design\n", &[])] {
            assert_eq!(e.lines().count(), 1, "{e}");
        }
    }
}
