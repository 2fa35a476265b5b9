//! Training of the reduced-order model over a design box ([`twistopt_solver::rom`]): full-order
//! ramps of the scenes on space-filling training designs give the snapshots, POD gives the basis
//! of the nodal unknowns (shared by every design and scene of one mesh), ECSW the element sample.

use crate::geometry::{ActuatorGeometry, Design, DesignSpace, RangePolicy};
use crate::scene::{SceneKind, SceneModel, SceneOptions};
use anyhow::{anyhow, bail, Result};
use rayon::prelude::*;
use std::time::Instant;
use twistopt_solver::rom::{Basis, EcswOptions, Frame, Rom, Snapshot, Truncation};

/// How a reduced model is trained.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrainOptions {
    /// training designs: the Halton sequence over the Table-I box (`optimise::starting_points`)
    pub designs: usize,
    /// scenes whose pressure ramps (to the pressure maximum or `p_max_kpa`) give the snapshots
    pub scenes: Vec<SceneKind>,
    pub p_max_kpa: f64,
    pub truncation: Truncation,
    pub ecsw: EcswOptions,
    /// the components the basis is expressed in
    #[serde(default)]
    pub frame: Frame,
    /// a reduced pressure space of this many modes (POD of the elements' pressures), or None:
    /// each element condenses its own pressure, as the full model does
    #[serde(default)]
    pub pressure_modes: Option<Truncation>,
    /// at most this many modes added to the POD basis from the full tangent's lowest
    /// eigenvectors at the last states of the training ramps that end at an instability
    /// ([`end_modes`]): the buckling directions no converged state contains (0: none)
    #[serde(default)]
    pub buckling_modes: usize,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            designs: 16,
            scenes: vec![SceneKind::Free, SceneKind::Blocked],
            p_max_kpa: 100.0,
            truncation: Truncation::Tail { tol: 1e-6, max: 60 },
            ecsw: EcswOptions { tau: 0.01, max_elements: 400, tangent_directions: 2, points: false, max_snapshots: 0 },
            frame: Frame::Cylindrical,
            pressure_modes: Some(Truncation::Modes(10)),
            buckling_modes: 0,
        }
    }
}

/// The full-order states of one scene ramp on one design.
pub struct Ramp {
    pub design: Design,
    pub kind: SceneKind,
    /// (pressure kPa, model unknowns q, prescribed values)
    pub states: Vec<(f64, Vec<f64>, Vec<f64>)>,
    /// the nodal unknowns of the loaded states in the basis frame (POD snapshots)
    pub frame_states: Vec<Vec<f64>>,
    /// the elements' pressure coefficients of the loaded states (pressure POD snapshots)
    pub pressure_states: Vec<Vec<f64>>,
    pub newton_iterations: usize,
    /// the pressure bound it was ramped to (kPa): a ramp whose last state is below it ended at
    /// a failure of the path (pressure maximum, bifurcation)
    pub p_max_kpa: f64,
}

/// What training measured.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrainReport {
    pub training_designs: Vec<Design>,
    pub snapshots: usize,
    pub modes: usize,
    pub singular_values: Vec<f64>,
    /// of the pressure snapshots (empty without a reduced pressure space)
    #[serde(default)]
    pub pressure_singular_values: Vec<f64>,
    /// the sample's distinct elements
    pub sample_elements: usize,
    /// its quadrature points (0: an element-level sample)
    #[serde(default)]
    pub sample_points: usize,
    pub elements: usize,
    pub ecsw_residual: f64,
    /// snapshots the ECSW fit left out (their projection inverts an element)
    #[serde(default)]
    pub ecsw_skipped_snapshots: usize,
    pub snapshot_time_s: f64,
    pub pod_time_s: f64,
    pub ecsw_time_s: f64,
    pub full_newton_iterations: usize,
    /// singular values of the modes appended from the ramps' end modes (fraction of a unit
    /// direction outside the POD basis; empty: none added)
    #[serde(default)]
    pub buckling_singular_values: Vec<f64>,
}

/// Designs at the points of the Halton sequence over the Table-I box (values in [0.1, 0.9] of
/// each range, from the sequence's `skip`+1-th point).
pub fn halton_designs(count: usize, skip: usize) -> Vec<Design> {
    let space = DesignSpace::actuator();
    crate::optimise::starting_points(space.len(), count + skip)
        .into_iter()
        .skip(skip)
        .map(|u| {
            let x: Vec<f64> = space.params.iter().zip(&u).map(|(p, t)| p.min + (t - 0.1) / 0.8 * (p.max - p.min)).collect();
            space.design_from_vec(&x).expect("design vector of the space's size")
        })
        .collect()
}

/// The training designs: the 2ⁿ corners of the Table-I box (the energy optimum sits on one),
/// then Halton points, `count` in all (at least the corners).
pub fn training_designs(count: usize) -> Vec<Design> {
    let space = DesignSpace::actuator();
    let n = space.len();
    let mut out: Vec<Design> = (0..1usize << n)
        .map(|c| {
            let x: Vec<f64> = space.params.iter().enumerate().map(|(i, p)| if c >> i & 1 == 1 { p.max } else { p.min }).collect();
            space.design_from_vec(&x).expect("design vector of the space's size")
        })
        .collect();
    out.extend(halton_designs(count.saturating_sub(out.len()), 0));
    out
}

/// Uniform random designs over the Table-I box (seeded, reproducible).
pub fn random_designs(count: usize, seed: u64) -> Vec<Design> {
    let space = DesignSpace::actuator();
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = || {
        // SplitMix64
        s = s.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..count)
        .map(|_| {
            let x: Vec<f64> = space.params.iter().map(|p| p.min + next() * (p.max - p.min)).collect();
            space.design_from_vec(&x).expect("design vector of the space's size")
        })
        .collect()
}

/// The full-order ramp of one scene on one design to its pressure maximum (or `p_max_kpa`),
/// without the ballooning stop, with every converged state.
pub fn full_ramp(design: &Design, opts: &SceneOptions, kind: SceneKind, p_max_kpa: f64, frame: Frame, reference: &[[f64; 3]]) -> Result<Ramp> {
    let geom = ActuatorGeometry::new(design, RangePolicy::TableI)?;
    let mut full = opts.clone();
    full.rom = None;
    let sm = SceneModel::build(&geom, &full, kind)?;
    let (states, its) = crate::scene::ramp_states(&sm, &full, p_max_kpa);
    let frame_states = states.iter().filter(|s| s.0 != 0.0).map(|s| twistopt_solver::rom::to_frame(&sm.model, frame, reference, &s.1)).collect::<Result<_, _>>()?;
    let pressure_states = states.iter().filter(|s| s.0 != 0.0).map(|s| twistopt_solver::rom::pressure_snapshot(&sm.model, &s.1, &s.2)).collect::<Result<_, _>>()?;
    Ok(Ramp { design: design.clone(), kind, states, frame_states, pressure_states, newton_iterations: its, p_max_kpa })
}

/// The centre of the Table-I box: the reference design of a [`Frame::Piola`] basis.
pub fn reference_design() -> Design {
    let space = DesignSpace::actuator();
    let x: Vec<f64> = space.params.iter().map(|p| 0.5 * (p.min + p.max)).collect();
    space.design_from_vec(&x).expect("design vector of the space's size")
}

/// The node positions of the reference design's mesh (empty unless the frame is Piola).
pub fn reference_nodes(opts: &SceneOptions, frame: Frame, kind: SceneKind) -> Result<Vec<[f64; 3]>> {
    if frame != Frame::Piola {
        return Ok(Vec::new());
    }
    let geom = ActuatorGeometry::new(&reference_design(), RangePolicy::TableI)?;
    let mut full = opts.clone();
    full.rom = None;
    Ok(SceneModel::build(&geom, &full, kind)?.model.mesh.nodes.clone())
}

/// Train a reduced model: full ramps of `t.scenes` on `t.designs` Halton designs, POD of every
/// converged state's nodal unknowns, ECSW on the same states.
pub fn train(opts: &SceneOptions, t: &TrainOptions, log: impl Fn(&str) + Sync) -> Result<(Rom, TrainReport)> {
    let designs = training_designs(t.designs);
    train_on(opts, t, &designs, log)
}

/// [`train`] on given training designs.
pub fn train_on(opts: &SceneOptions, t: &TrainOptions, designs: &[Design], log: impl Fn(&str) + Sync) -> Result<(Rom, TrainReport)> {
    let t0 = Instant::now();
    let ramps = training_ramps(opts, t, designs, &log)?;
    let snapshot_time_s = t0.elapsed().as_secs_f64();
    let (rom, mut report) = from_ramps(opts, t, &ramps, &log)?;
    report.training_designs = designs.to_vec();
    report.snapshot_time_s = snapshot_time_s;
    Ok((rom, report))
}

/// The full-order ramps of `t.scenes` on each design (a failed ramp is logged and skipped).
pub fn training_ramps(opts: &SceneOptions, t: &TrainOptions, designs: &[Design], log: &(impl Fn(&str) + Sync)) -> Result<Vec<Ramp>> {
    ramps_in(opts, t, designs, None, log)
}

/// The bases (POD of the ramps' states: displacement, and pressure when `t.pressure_modes`) of
/// training ramps, without a sample.
pub fn bases(opts: &SceneOptions, t: &TrainOptions, ramps: &[Ramp]) -> Result<Basis> {
    let snaps: Vec<Vec<f64>> = ramps.iter().flat_map(|r| r.frame_states.iter().cloned()).collect();
    if snaps.is_empty() {
        return Err(anyhow!("no training states: every training ramp failed"));
    }
    let mut basis = Basis::pod(&snaps, t.truncation)?;
    basis.frame = t.frame;
    basis.reference = reference_nodes(opts, t.frame, t.scenes.first().copied().unwrap_or(SceneKind::Free))?;
    if t.buckling_modes > 0 {
        let dirs = end_modes(opts, t, ramps)?;
        basis.append_directions(&dirs, t.buckling_modes, BUCKLING_MODE_TOL)?;
    }
    if let Some(tr) = t.pressure_modes {
        let ps: Vec<Vec<f64>> = ramps.iter().flat_map(|r| r.pressure_states.iter().cloned()).collect();
        let np = opts.formulation.pressure.dim().max(1);
        basis.pressure = Some(twistopt_solver::rom::PressureBasis::pod(&ps, np, tr)?);
    }
    Ok(basis)
}

/// A direction outside the POD basis adds a mode only if at least this fraction of it (of a
/// unit vector) lies outside.
pub const BUCKLING_MODE_TOL: f64 = 0.05;

/// The full tangent's lowest eigenvector (by inverse iteration with its factor) at the last
/// state of every training ramp that ended before `t.p_max_kpa` (at a pressure maximum or where
/// the tangent lost positive definiteness), as its nodal part in the basis frame. At a
/// bifurcation the path's states never contain that mode, so a basis of states alone cannot
/// lose stability there: the reduced path runs on past the full model's end.
pub fn end_modes(opts: &SceneOptions, t: &TrainOptions, ramps: &[Ramp]) -> Result<Vec<Vec<f64>>> {
    let reference = reference_nodes(opts, t.frame, t.scenes.first().copied().unwrap_or(SceneKind::Free))?;
    let ended: Vec<&Ramp> = ramps.iter().filter(|r| r.states.last().is_some_and(|s| s.0 != 0.0 && s.0 < t.p_max_kpa * (1.0 - 1e-9))).collect();
    ended
        .par_iter()
        .map(|r| {
            let (p, q, _) = r.states.last().expect("a ramp with a state");
            let geom = ActuatorGeometry::new(&r.design, RangePolicy::TableI)?;
            let mut full = opts.clone();
            full.rom = None;
            let sm = SceneModel::build(&geom, &full, r.kind)?;
            let loads = sm.loads(*p, 0.0);
            let k = sm.model.assemble(q, &loads, true).map_err(|e| anyhow!("end mode of {} {}: {e}", label(&r.design), r.kind.name()))?.k.ok_or_else(|| anyhow!("no tangent"))?;
            let f = sm.model.factor(&k).or_else(|_| sm.model.factor_indefinite(&k)).map_err(|e| anyhow!("end mode of {} {}: {e}", label(&r.design), r.kind.name()))?;
            let phi = f.inverse_iteration(12).map_err(|e| anyhow!("end mode of {} {}: {e}", label(&r.design), r.kind.name()))?;
            Ok(twistopt_solver::rom::to_frame(&sm.model, t.frame, &reference, &phi)?)
        })
        .collect()
}

/// The ECSW sample of a basis on training ramps (each state on its own design's geometry);
/// `ecsw.max_elements == 0`: every element (with `ecsw.points`, every quadrature point) at
/// weight 1.
pub fn fit_sample(opts: &SceneOptions, basis: &Basis, ramps: &[Ramp], ecsw: &EcswOptions) -> Result<twistopt_solver::rom::EcswFit> {
    let mut full = opts.clone();
    full.rom = None;
    let first = ramps.first().ok_or_else(|| anyhow!("no training ramps"))?;
    if ecsw.max_elements == 0 {
        let geom = ActuatorGeometry::new(&first.design, RangePolicy::TableI)?;
        let model = SceneModel::build(&geom, &full, first.kind)?.model;
        let elements = model.mesh.n_elements();
        let sample = if ecsw.points { twistopt_solver::rom::Sample::all_points(elements, model.form.rule().weights.len()) } else { twistopt_solver::rom::Sample::all(elements) };
        return Ok(twistopt_solver::rom::EcswFit { sample, residual: 0.0, rows: 0, skipped: 0 });
    }
    let mut acc = twistopt_solver::rom::EcswAccumulator::new(ecsw.tangent_directions);
    acc.points = ecsw.points;
    // with max_snapshots, every stride-th loaded state over all ramps
    let loaded: usize = ramps.iter().map(|r| r.states.iter().filter(|s| s.0 != 0.0).count()).sum();
    let stride = if ecsw.max_snapshots > 0 { loaded.div_ceil(ecsw.max_snapshots).max(1) } else { 1 };
    let mut index = 0usize;
    for r in ramps {
        let geom = ActuatorGeometry::new(&r.design, RangePolicy::TableI)?;
        let sm = SceneModel::build(&geom, &full, r.kind)?;
        let mut snaps: Vec<Snapshot> = Vec::new();
        for s in r.states.iter().filter(|s| s.0 != 0.0) {
            if index % stride == 0 {
                snaps.push(Snapshot { model: &sm.model, q: s.1.clone(), presc: s.2.clone() });
            }
            index += 1;
        }
        acc.add(basis, &snaps)?;
    }
    Ok(acc.fit(ecsw))
}

/// A reduced model of training ramps: [`bases`], then [`fit_sample`].
pub fn from_ramps(opts: &SceneOptions, t: &TrainOptions, ramps: &[Ramp], log: &(impl Fn(&str) + Sync)) -> Result<(Rom, TrainReport)> {
    let t1 = Instant::now();
    let basis = bases(opts, t, ramps)?;
    let pod_time_s = t1.elapsed().as_secs_f64();
    let snapshots: usize = ramps.iter().map(|r| r.frame_states.len()).sum();
    let appended = basis.appended_singular_values.len();
    log(&format!("  POD: {} snapshots of {} unknowns → {} modes ({:?} frame)", snapshots, basis.n, basis.k - appended, basis.frame));
    if t.buckling_modes > 0 {
        log(&format!(
            "  end modes: {} appended (at most {}; their parts outside the POD basis: {:?})",
            appended,
            t.buckling_modes,
            basis.appended_singular_values.iter().map(|s| (s * 1e3).round() / 1e3).collect::<Vec<_>>()
        ));
    }
    if let Some(pb) = &basis.pressure {
        log(&format!("  pressure POD: {} snapshots of {} coefficients → {} modes", snapshots, pb.psi.len() / pb.kp.max(1), pb.kp));
    }
    let t2 = Instant::now();
    let fit = fit_sample(opts, &basis, ramps, &t.ecsw)?;
    if fit.sample.weights.is_empty() {
        bail!("ECSW chose no sample ({} training snapshot(s) left out because their projection onto the basis inverts an element): the basis cannot represent the training states", fit.skipped);
    }
    let ecsw_time_s = t2.elapsed().as_secs_f64();
    let n_elements = {
        let geom = ActuatorGeometry::new(&ramps[0].design, RangePolicy::TableI)?;
        let mut full = opts.clone();
        full.rom = None;
        SceneModel::build(&geom, &full, ramps[0].kind)?.model.mesh.n_elements()
    };
    log(&format!("  ECSW: {}, relative residual {:.2e} (τ = {})", fit.sample.describe(n_elements), fit.residual, t.ecsw.tau));
    if fit.skipped > 0 {
        log(&format!("  ECSW: {} snapshot(s) left out: their projection onto the basis inverts an element", fit.skipped));
    }
    let mut designs: Vec<Design> = Vec::new();
    for r in ramps {
        if !designs.iter().any(|d| d.values == r.design.values) {
            designs.push(r.design.clone());
        }
    }
    let report = TrainReport {
        training_designs: designs,
        snapshots,
        modes: basis.k,
        singular_values: basis.singular_values.clone(),
        pressure_singular_values: basis.pressure.as_ref().map(|p| p.singular_values.clone()).unwrap_or_default(),
        sample_elements: fit.sample.distinct_elements().len(),
        sample_points: fit.sample.points.len(),
        elements: n_elements,
        ecsw_residual: fit.residual,
        ecsw_skipped_snapshots: fit.skipped,
        snapshot_time_s: 0.0,
        pod_time_s,
        ecsw_time_s,
        full_newton_iterations: ramps.iter().map(|r| r.newton_iterations).sum(),
        buckling_singular_values: basis.appended_singular_values.clone(),
    };
    Ok((Rom::new(basis, fit.sample), report))
}

/// "r=…, l=…, alpha=…" of a design.
pub fn label(d: &Design) -> String {
    d.values.iter().map(|(k, v)| format!("{k}={v:.4}")).collect::<Vec<_>>().join(", ")
}

// ---------------------------------------------------------------------------------------------
// ROM directories: manifest.json + basis.bin, and the training's ramp cache

/// The format version of a ROM directory (manifest.json + basis.bin).
pub const FORMAT_VERSION: u32 = 1;

/// What a ROM directory's manifest.json holds: what the model was trained for (mesh, element,
/// material, scene options, design box) and how (options, designs, costs), its sizes and its
/// sample, and the errors measured at training.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Manifest {
    pub format_version: u32,
    pub mesh: crate::meshing::MeshSpec,
    pub formulation: twistopt_solver::element::Formulation,
    pub material: twistopt_solver::material::Material,
    pub sector: bool,
    pub cap_load: bool,
    /// the design box the training designs cover (a design outside it is refused)
    pub design_box: Vec<crate::geometry::ParamSpec>,
    pub frame: Frame,
    /// nodal unknowns, displacement modes, pressure coefficients per element, pressure modes
    pub n: usize,
    pub k: usize,
    pub np: usize,
    pub kp: usize,
    pub reference_nodes: usize,
    pub sample: twistopt_solver::rom::Sample,
    pub options: TrainOptions,
    pub report: TrainReport,
    /// the training's total CPU time (process, s) and wall time
    pub train_cpu_s: f64,
    pub train_wall_s: f64,
    /// full vs reduced on held-out designs, when measured at training (`--validate N`)
    #[serde(default)]
    pub validation: Option<serde_json::Value>,
    /// the error-indicator threshold above which a scene falls back to the full model
    /// (`SceneOptions::rom_fallback`), calibrated on a validation (`rom validate --calibrate`)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback_indicator: Option<f64>,
    /// how it was calibrated (the validation, the rule, the share of designs it sends back)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback_calibration: Option<serde_json::Value>,
    /// the greedy enrichment (`rom train --enrich`): options, rounds (the candidates' indicators
    /// and the designs each added), the final model's indicators
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub enrichment: Option<serde_json::Value>,
}

fn put_f64s(out: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

fn take_f64s(bytes: &[u8], at: &mut usize, n: usize) -> Result<Vec<f64>> {
    let end = *at + 8 * n;
    if end > bytes.len() {
        return Err(anyhow!("basis.bin is truncated (needs {} more bytes)", end - bytes.len()));
    }
    let v = bytes[*at..end].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect();
    *at = end;
    Ok(v)
}

/// Write a trained model to DIR (manifest.json + basis.bin: V, then Ψ, then the reference
/// nodes, little-endian f64, row-major), each file atomically.
pub fn save(dir: &std::path::Path, rom: &Rom, manifest: &Manifest) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("cannot create {}: {e}", dir.display()))?;
    let mut bin = Vec::new();
    put_f64s(&mut bin, &rom.basis.v);
    if let Some(p) = &rom.basis.pressure {
        put_f64s(&mut bin, &p.psi);
    }
    put_f64s(&mut bin, &rom.basis.reference.iter().flatten().copied().collect::<Vec<_>>());
    let tmp = dir.join("basis.bin.tmp");
    std::fs::write(&tmp, &bin).map_err(|e| anyhow!("cannot write {}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, dir.join("basis.bin"))?;
    let mut m = manifest.clone();
    m.report.singular_values = rom.basis.singular_values.clone();
    crate::sweep::write_atomic(&dir.join("manifest.json"), &serde_json::to_string_pretty(&m)?)?;
    Ok(())
}

/// Read a ROM directory, checking that it was trained for these scene options (mesh, element,
/// material, sector, cap load); a mismatch is a clear error.
pub fn load(dir: &std::path::Path, opts: &SceneOptions) -> Result<(Rom, Manifest)> {
    let mpath = dir.join("manifest.json");
    let text = std::fs::read_to_string(&mpath).map_err(|e| anyhow!("cannot read the reduced model {}: {e} (train one with `twistopt rom train`)", mpath.display()))?;
    let m: Manifest = serde_json::from_str(&text).map_err(|e| anyhow!("{} is not a twistopt ROM manifest: {e}", mpath.display()))?;
    if m.format_version != FORMAT_VERSION {
        return Err(anyhow!("{}: ROM format version {} (this twistopt reads version {FORMAT_VERSION}); retrain it", mpath.display(), m.format_version));
    }
    let mut why = Vec::new();
    if m.mesh != opts.mesh {
        why.push(format!("mesh {:?} (the problem's: {:?})", m.mesh, opts.mesh));
    }
    if m.formulation != opts.formulation {
        why.push(format!("element {:?} (the problem's: {:?})", m.formulation, opts.formulation));
    }
    if m.material != opts.material {
        why.push(format!("material {:?} (the problem's: {:?})", m.material, opts.material));
    }
    if m.sector != opts.sector || m.cap_load != opts.cap_load {
        why.push(format!("sector = {}, cap_load = {} (the problem's: {}, {})", m.sector, m.cap_load, opts.sector, opts.cap_load));
    }
    if !why.is_empty() {
        return Err(anyhow!("the reduced model in {} was trained for another model: {}", dir.display(), why.join("; ")));
    }
    let bpath = dir.join("basis.bin");
    let bytes = std::fs::read(&bpath).map_err(|e| anyhow!("cannot read {}: {e}", bpath.display()))?;
    let need = 8 * (m.n * m.k + m.n_pressure_rows() * m.kp + 3 * m.reference_nodes);
    if bytes.len() != need {
        return Err(anyhow!("{} has {} bytes, the manifest describes {need}", bpath.display(), bytes.len()));
    }
    let mut at = 0;
    let v = take_f64s(&bytes, &mut at, m.n * m.k)?;
    let pressure = if m.kp > 0 {
        let psi = take_f64s(&bytes, &mut at, m.n_pressure_rows() * m.kp)?;
        Some(twistopt_solver::rom::PressureBasis { np: m.np, kp: m.kp, psi, singular_values: m.report.pressure_singular_values.clone() })
    } else {
        None
    };
    let refs = take_f64s(&bytes, &mut at, 3 * m.reference_nodes)?;
    let reference = refs.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let basis =
        Basis { frame: m.frame, n: m.n, k: m.k, reference, v, singular_values: m.report.singular_values.clone(), pressure, appended_singular_values: m.report.buckling_singular_values.clone() };
    Ok((Rom::new(basis, m.sample.clone()), m))
}

/// Why a design lies outside a reduced model's training box (None: inside).
pub fn outside_box(design_box: &[crate::geometry::ParamSpec], d: &Design) -> Option<String> {
    let out: Vec<String> = design_box
        .iter()
        .filter_map(|p| {
            let v = d.values.get(&p.name).copied()?;
            let tol = 1e-9 * (p.max - p.min).abs();
            (v < p.min - tol || v > p.max + tol).then(|| format!("{} = {v} outside [{}, {}]", p.name, p.min, p.max))
        })
        .collect();
    (!out.is_empty()).then(|| format!("the design is outside the reduced model's training box ({}); use the full model", out.join(", ")))
}

impl Manifest {
    fn n_pressure_rows(&self) -> usize {
        if self.kp > 0 {
            self.report.elements * self.np
        } else {
            0
        }
    }
}

/// One cached training ramp: DIR/ramps/<design>-<scene>.bin (a JSON header line, then the
/// states' pressure, q and prescribed values as little-endian f64).
fn ramp_path(dir: &std::path::Path, d: usize, kind: SceneKind) -> std::path::PathBuf {
    dir.join("ramps").join(format!("{d:04}-{}.bin", kind.name()))
}

fn write_ramp(path: &std::path::Path, r: &Ramp) -> Result<()> {
    let header = serde_json::json!({ "design": r.design, "kind": r.kind.name(), "newton_iterations": r.newton_iterations, "p_max_kPa": r.p_max_kpa,
        "states": r.states.iter().map(|s| (s.1.len(), s.2.len())).collect::<Vec<_>>() });
    let mut bytes = serde_json::to_vec(&header)?;
    bytes.push(b'\n');
    for s in &r.states {
        put_f64s(&mut bytes, &[s.0]);
        put_f64s(&mut bytes, &s.1);
        put_f64s(&mut bytes, &s.2);
    }
    if let Some(p) = path.parent() {
        std::fs::create_dir_all(p)?;
    }
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, &bytes)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// Whether a cached ramp ramped to `cached_bound` whose last state is at `p_end` is the ramp to
/// `p_max_kpa`: the same bound, or a path that failed below both.
fn cached_ramp_serves(cached_bound: f64, p_end: f64, p_max_kpa: f64) -> bool {
    (cached_bound - p_max_kpa).abs() <= 1e-9 * p_max_kpa.abs().max(1.0) || p_end < cached_bound.min(p_max_kpa) * (1.0 - 1e-9)
}

/// A cached ramp (None: missing, unreadable, or of another pressure bound, to be recomputed),
/// with its frame and pressure snapshots recomputed on its design's model. A ramp ramped to
/// another bound serves only if it ended (by failure) below both bounds: one that stopped at its
/// bound lacks the states up to a higher one (caches written before the bound was recorded were
/// ramped to the default 100 kPa).
fn read_ramp(path: &std::path::Path, opts: &SceneOptions, kind: SceneKind, frame: Frame, reference: &[[f64; 3]], p_max_kpa: f64) -> Option<Ramp> {
    let bytes = std::fs::read(path).ok()?;
    let nl = bytes.iter().position(|&b| b == b'\n')?;
    let h: serde_json::Value = serde_json::from_slice(&bytes[..nl]).ok()?;
    let design: Design = serde_json::from_value(h["design"].clone()).ok()?;
    let sizes: Vec<(usize, usize)> = serde_json::from_value(h["states"].clone()).ok()?;
    let mut at = nl + 1;
    let mut states = Vec::new();
    for (nq, npr) in sizes {
        let p = take_f64s(&bytes, &mut at, 1).ok()?[0];
        let q = take_f64s(&bytes, &mut at, nq).ok()?;
        let pr = take_f64s(&bytes, &mut at, npr).ok()?;
        states.push((p, q, pr));
    }
    if at != bytes.len() {
        return None;
    }
    let cached_bound = h["p_max_kPa"].as_f64().unwrap_or(100.0);
    let p_end = states.last().map(|s| s.0)?;
    if !cached_ramp_serves(cached_bound, p_end, p_max_kpa) {
        return None;
    }
    let geom = ActuatorGeometry::new(&design, RangePolicy::TableI).ok()?;
    let mut full = opts.clone();
    full.rom = None;
    let sm = SceneModel::build(&geom, &full, kind).ok()?;
    let frame_states = states.iter().filter(|s| s.0 != 0.0).map(|s| twistopt_solver::rom::to_frame(&sm.model, frame, reference, &s.1)).collect::<Result<_, _>>().ok()?;
    let pressure_states = states.iter().filter(|s| s.0 != 0.0).map(|s| twistopt_solver::rom::pressure_snapshot(&sm.model, &s.1, &s.2)).collect::<Result<_, _>>().ok()?;
    Some(Ramp { design, kind, states, frame_states, pressure_states, newton_iterations: h["newton_iterations"].as_u64().unwrap_or(0) as usize, p_max_kpa })
}

/// [`training_ramps`] with a cache in `dir`/ramps: a ramp already there is read instead of
/// recomputed (an interrupted training resumes), a new one is written as soon as it is done.
/// `progress` is called once per ramp (cached or computed).
pub fn training_ramps_cached(opts: &SceneOptions, t: &TrainOptions, designs: &[Design], dir: &std::path::Path, progress: &(impl Fn(&str) + Sync)) -> Result<Vec<Ramp>> {
    ramps_in(opts, t, designs, Some(dir), progress)
}

/// The training ramps, with a cache in `dir`/ramps when given.
fn ramps_in(opts: &SceneOptions, t: &TrainOptions, designs: &[Design], dir: Option<&std::path::Path>, progress: &(impl Fn(&str) + Sync)) -> Result<Vec<Ramp>> {
    let reference = reference_nodes(opts, t.frame, t.scenes.first().copied().unwrap_or(SceneKind::Free))?;
    let jobs: Vec<(usize, SceneKind)> = (0..designs.len()).flat_map(|d| t.scenes.iter().map(move |&k| (d, k))).collect();
    let ramps: Vec<Ramp> = jobs
        .par_iter()
        .filter_map(|&(d, k)| {
            let path = dir.map(|dir| ramp_path(dir, d, k));
            if let Some(r) = path.as_ref().and_then(|p| read_ramp(p, opts, k, t.frame, &reference, t.p_max_kpa)).filter(|r| r.design.values == designs[d].values) {
                progress(&format!("design {d} {}: cached", k.name()));
                return Some(r);
            }
            match full_ramp(&designs[d], opts, k, t.p_max_kpa, t.frame, &reference) {
                Ok(r) => {
                    if let Some(Err(e)) = path.as_ref().map(|p| write_ramp(p, &r)) {
                        progress(&format!("warning: cannot cache {}: {e}", path.as_ref().map(|p| p.display().to_string()).unwrap_or_default()));
                    }
                    progress(&format!("design {d} {}: {} states, {} Newton iterations", k.name(), r.states.len(), r.newton_iterations));
                    Some(r)
                }
                Err(e) => {
                    progress(&format!("design {d} {}: skipped ({e})", k.name()));
                    None
                }
            }
        })
        .collect();
    if ramps.is_empty() {
        return Err(anyhow!("no training states: every training ramp failed"));
    }
    Ok(ramps)
}

/// Ω by the letter's rule from a free and a blocked ramp to failure: both at the lower of the
/// two end pressures (θ and τ interpolated there). Returns (Ω J/m³, that pressure kPa).
pub fn omega_of(free: &crate::scene::SceneResult, blocked: &crate::scene::SceneResult) -> (f64, f64) {
    let pf = free.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
    let pb = blocked.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
    let pc = pf.min(pb);
    let th = crate::evaluate::interpolate(&free.steps, pc, |s| s.theta_deg).unwrap_or(0.0);
    let tau = crate::evaluate::interpolate(&blocked.steps, pc, |s| s.tau_nm).unwrap_or(0.0);
    (crate::scene::energy_density(th.abs(), tau.abs()), pc)
}

/// Why a reduced model trained on `trained` scenes cannot run `kind` (None: it can, or the
/// scenes are not known). A scene's constraints select which modes it needs: pure twist's held
/// axial translation makes a limit point that the free and blocked scenes' modes miss (measured:
/// Ω 9 % low, the pressure maximum missed, on a design of the box).
pub fn untrained_scene(trained: &[SceneKind], kind: SceneKind) -> Option<String> {
    (!trained.is_empty() && !trained.contains(&kind)).then(|| {
        let names: Vec<&str> = trained.iter().map(|k| k.name()).collect();
        format!(
            "the reduced model was trained on the scenes {} and not on '{}'; train one for it (`twistopt rom train --scenes {}`) or use the full model",
            names.join(", "),
            kind.name(),
            if kind.axial_free() { "free,blocked" } else { "pure-twist,pure-twist-blocked" }
        )
    })
}

/// The twist scene and the torque scene that a reduced model's validation compares (the
/// combined mode's free + blocked, or the pure-twist pair), from the scenes it was trained on.
pub fn scene_pair(trained: &[SceneKind]) -> (SceneKind, SceneKind) {
    if trained.contains(&SceneKind::Free) && trained.contains(&SceneKind::Blocked) {
        (SceneKind::Free, SceneKind::Blocked)
    } else if trained.contains(&SceneKind::PureTwist) && trained.contains(&SceneKind::PureTwistBlocked) {
        (SceneKind::PureTwist, SceneKind::PureTwistBlocked)
    } else {
        (SceneKind::Free, SceneKind::Blocked)
    }
}

/// Full vs reduced model, free + blocked ramped to failure, on seeded random designs of the
/// Table-I box: per design the end pressures, Ω and CPU s of both; and the error summary.
pub fn validate(opts: &SceneOptions, rom: std::sync::Arc<Rom>, count: usize, seed: u64, p_max_kpa: f64, progress: &(impl Fn(&str) + Sync)) -> Result<serde_json::Value> {
    let rows: Vec<serde_json::Value> = random_designs(count, seed)
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let row = validation_row(opts, &rom, i, d, p_max_kpa, None)?;
            progress(&format!("validation {}: Ω full {:.3} reduced {:.3}", label(d), row["omega_full"].as_f64().unwrap_or(f64::NAN), row["omega_rom"].as_f64().unwrap_or(f64::NAN)));
            Ok(row)
        })
        .collect::<Result<_>>()?;
    Ok(validation_summary(rows, count, seed))
}

/// One validation row: design `index` of the seeded set, full and reduced model, free + blocked
/// ramped to `p_max_kpa` or failure, one scene at a time (the process CPU time is the design's;
/// the models assemble in parallel themselves). A model trained on the pure-twist scenes is
/// compared on pure-twist + pure-twist-blocked ([`scene_pair`]): the row's `scenes` names them,
/// and its `*_free_*` / `*_blocked_*` keys are then the twist and the torque scene.
///
/// With `reuse`, an earlier validation row of the same index and design (of the same full model,
/// problem and pressure bound; e.g. another reduced model's validation), the full-order answer
/// is taken from it instead of being recomputed.
pub fn validation_row(opts: &SceneOptions, rom: &std::sync::Arc<Rom>, index: usize, d: &Design, p_max_kpa: f64, reuse: Option<&serde_json::Value>) -> Result<serde_json::Value> {
    use crate::scene::run_pressure;
    let mut ro = opts.clone();
    ro.rom = Some(rom.clone());
    // the reduced model's own answer (no fallback), against the full model
    ro.rom_fallback = None;
    let mut full = opts.clone();
    full.rom = None;
    let g = ActuatorGeometry::new(d, RangePolicy::TableI).map_err(|e| anyhow!("{e}"))?;
    let (twist, torque) = scene_pair(&opts.rom_scenes);
    let scenes = serde_json::json!([twist.name(), torque.name()]);
    let run = |o: &SceneOptions| -> Result<(crate::scene::SceneResult, crate::scene::SceneResult, f64)> {
        let c0 = crate::evaluate::process_cpu_time_s();
        let f = run_pressure(&g, o, twist, &[p_max_kpa])?;
        let b = run_pressure(&g, o, torque, &[p_max_kpa])?;
        Ok((f, b, crate::evaluate::process_cpu_time_s() - c0))
    };
    let end = |r: &crate::scene::SceneResult| r.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
    const FULL_KEYS: [&str; 5] = ["omega_full", "p_end_free_full", "p_end_blocked_full", "status_full", "cpu_s_full"];
    let mut row = match reuse {
        Some(prev) => {
            // (rows written before the pure-twist pair have no `scenes`: free + blocked)
            let prev_scenes = prev.get("scenes").cloned().unwrap_or_else(|| serde_json::json!(["free", "blocked"]));
            if prev["index"].as_u64() != Some(index as u64) || prev["design"] != serde_json::to_value(d)? || FULL_KEYS.iter().any(|k| prev.get(k).is_none()) || prev_scenes != scenes {
                return Err(anyhow!("the reused full-order row of design {index} is of another design or scene pair, or incomplete"));
            }
            let mut row = serde_json::json!({ "index": index, "design": d, "scenes": scenes, "full_reused": true });
            for k in FULL_KEYS {
                row[k] = prev[k].clone();
            }
            row
        }
        None => {
            let (ff, fb, cf) = run(&full)?;
            let (of, _) = omega_of(&ff, &fb);
            serde_json::json!({
                "index": index, "design": d, "scenes": scenes, "omega_full": of, "p_end_free_full": end(&ff), "p_end_blocked_full": end(&fb),
                "status_full": [ff.status.to_string(), fb.status.to_string()], "cpu_s_full": cf,
            })
        }
    };
    let (rf, rb, cr) = run(&ro)?;
    let (or, _) = omega_of(&rf, &rb);
    row["omega_rom"] = serde_json::json!(or);
    row["p_end_free_rom"] = serde_json::json!(end(&rf));
    row["p_end_blocked_rom"] = serde_json::json!(end(&rb));
    row["status_rom"] = serde_json::json!([rf.status.to_string(), rb.status.to_string()]);
    row["indicator_rom"] = serde_json::json!([rf.rom_indicator, rb.rom_indicator]);
    row["cpu_s_rom"] = serde_json::json!(cr);
    row["newton_iterations_rom"] = serde_json::json!(rf.newton_iterations + rb.newton_iterations);
    Ok(row)
}

/// One design of the reduced model's robustness check (`rom check`): free + blocked ramped
/// towards `p_kpa` (either sign) on the reduced model alone (no fallback), each inside
/// `catch_unwind`. The row lists every *problem*: a panic, an error instead of a scene status, a
/// non-finite recorded value (pressure, θ, τ, radius, volume, indicator, Ω) or a failure status
/// without its cause.
pub fn check_row(opts: &SceneOptions, rom: &std::sync::Arc<Rom>, index: usize, d: &Design, p_kpa: f64) -> Result<serde_json::Value> {
    use crate::scene::{run_pressure, SceneStatus};
    let mut ro = opts.clone();
    ro.rom = Some(rom.clone());
    ro.rom_fallback = None;
    let g = ActuatorGeometry::new(d, RangePolicy::TableI).map_err(|e| anyhow!("{e}"))?;
    let c0 = crate::evaluate::process_cpu_time_s();
    let mut scenes = serde_json::Map::new();
    let mut problems: Vec<String> = Vec::new();
    let mut results = Vec::new();
    let (twist, torque) = scene_pair(&opts.rom_scenes);
    for kind in [twist, torque] {
        let name = kind.name();
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_pressure(&g, &ro, kind, &[p_kpa]))) {
            Err(e) => {
                let msg = e.downcast_ref::<String>().cloned().or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string())).unwrap_or_default();
                problems.push(format!("{name}: panic: {msg}"));
                scenes.insert(name.into(), serde_json::json!({ "status": "panic" }));
            }
            Ok(Err(e)) => {
                problems.push(format!("{name}: error without a scene status: {e}"));
                scenes.insert(name.into(), serde_json::json!({ "status": "error", "cause": e.to_string() }));
            }
            Ok(Ok(r)) => {
                let finite = r.steps.iter().all(|s| [s.p_kpa, s.theta_deg, s.tau_nm, s.max_radius_mm, s.cavity_volume_mm3].iter().all(|v| v.is_finite()));
                if !finite {
                    problems.push(format!("{name}: a non-finite recorded value"));
                }
                if r.rom_indicator.is_some_and(|v| !v.is_finite()) {
                    problems.push(format!("{name}: non-finite indicator"));
                }
                if r.status != SceneStatus::Completed && r.cause.trim().is_empty() {
                    problems.push(format!("{name}: status {} without a cause", r.status.name()));
                }
                let last = r.steps.last();
                scenes.insert(
                    name.into(),
                    serde_json::json!({
                        "status": r.status.name(), "cause": r.cause, "steps": r.steps.len(),
                        "p_end_kPa": last.map(|s| s.p_kpa), "theta_end_deg": last.map(|s| s.theta_deg), "tau_end_Nm": last.map(|s| s.tau_nm),
                        "indicator": r.rom_indicator,
                    }),
                );
                results.push(r);
            }
        }
    }
    let omega = (results.len() == 2).then(|| omega_of(&results[0], &results[1]).0);
    if omega.is_some_and(|o| !o.is_finite()) {
        problems.push("non-finite Ω".into());
    }
    Ok(serde_json::json!({
        "index": index, "design": d, "p_kPa": p_kpa, "scenes": scenes, "omega_J_m3": omega,
        "problems": problems, "cpu_s": crate::evaluate::process_cpu_time_s() - c0,
    }))
}

/// `count` pressures uniform in [lo, hi] kPa (seeded, SplitMix64).
pub fn random_pressures(count: usize, seed: u64, lo: f64, hi: f64) -> Vec<f64> {
    let mut s = seed ^ 0xD1B54A32D192ED03;
    (0..count)
        .map(|_| {
            s = s.wrapping_add(0x9E3779B97F4A7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
            lo + (hi - lo) * (((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64)
        })
        .collect()
}

/// The summary of `rom check` rows: statuses per scene, problems, CPU s per design.
pub fn check_summary(rows: &[serde_json::Value]) -> serde_json::Value {
    let mut statuses: std::collections::BTreeMap<String, std::collections::BTreeMap<String, usize>> = Default::default();
    let mut problems = Vec::new();
    for r in rows {
        if let Some(sc) = r["scenes"].as_object() {
            for (name, v) in sc {
                *statuses.entry(name.clone()).or_default().entry(v["status"].as_str().unwrap_or("?").to_string()).or_default() += 1;
            }
        }
        if let Some(e) = r.get("error") {
            problems.push(serde_json::json!({ "index": r["index"], "problem": e }));
        }
        for p in r["problems"].as_array().into_iter().flatten() {
            problems.push(serde_json::json!({ "index": r["index"], "problem": p }));
        }
    }
    let cpu: Vec<f64> = rows.iter().filter_map(|r| r["cpu_s"].as_f64()).collect();
    serde_json::json!({
        "rows": rows.len(), "statuses": statuses, "problems": problems.len(), "problem_rows": problems,
        "cpu_s_per_design": if cpu.is_empty() { serde_json::Value::Null } else { serde_json::json!(cpu.iter().sum::<f64>() / cpu.len() as f64) },
    })
}

/// The fallback threshold calibrated on validation rows ([`validation_row`]): a row is *bad*
/// when its reduced Ω is off by more than 3 % and by more than 0.1 % of the rows' largest Ω, or
/// an end pressure by more than 1 %; a row's indicator is the larger of its two scenes'. The
/// threshold sends every bad row back to the full model: just below the smallest bad row's
/// indicator (with no bad row: the largest indicator seen, so that only designs beyond the
/// validated range fall back). Returns the threshold and the calibration record (how many rows
/// are bad, how many good rows it also sends back).
pub fn calibrate_fallback(rows: &[serde_json::Value]) -> Option<(f64, serde_json::Value)> {
    let num = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or(f64::NAN);
    let rel = |a: f64, b: f64| if b != 0.0 { ((a - b) / b).abs() } else { (a - b).abs() };
    let rows: Vec<&serde_json::Value> = rows.iter().filter(|r| r.get("error").is_none()).collect();
    let omega_max = rows.iter().map(|r| num(r, "omega_full")).filter(|v| v.is_finite()).fold(0.0f64, f64::max);
    let indicator = |r: &serde_json::Value| -> f64 {
        let v: Vec<Option<f64>> = r["indicator_rom"].as_array().map(|a| a.iter().map(|x| x.as_f64()).collect()).unwrap_or_default();
        if v.is_empty() || v.iter().any(|x| x.is_none()) {
            f64::INFINITY // no indicator: the fallback runs anyway
        } else {
            v.into_iter().flatten().fold(0.0f64, f64::max)
        }
    };
    let bad = |r: &serde_json::Value| -> bool {
        let (om_r, om_f) = (num(r, "omega_rom"), num(r, "omega_full"));
        let omega_bad = !(rel(om_r, om_f) <= 0.03 || (om_r - om_f).abs() <= 1e-3 * omega_max);
        let p_bad = [("p_end_free_rom", "p_end_free_full"), ("p_end_blocked_rom", "p_end_blocked_full")].iter().any(|(a, b)| !(rel(num(r, a), num(r, b)) <= 0.01));
        omega_bad || p_bad
    };
    if rows.is_empty() {
        return None;
    }
    let bad_ind: Vec<f64> = rows.iter().filter(|r| bad(r)).map(|r| indicator(r)).collect();
    let finite_max = rows.iter().map(|r| indicator(r)).filter(|v| v.is_finite()).fold(0.0f64, f64::max);
    let threshold = match bad_ind.iter().copied().fold(f64::INFINITY, f64::min) {
        m if m.is_finite() => m * (1.0 - 1e-6),
        _ => finite_max,
    };
    let back = rows.iter().filter(|r| indicator(r) > threshold).count();
    let good_back = rows.iter().filter(|r| indicator(r) > threshold && !bad(r)).count();
    Some((
        threshold,
        serde_json::json!({
            "rule": "bad: Ω off by > 3 % and > 0.1 % of the largest Ω, or an end pressure off by > 1 %; threshold just below the smallest bad row's indicator (none bad: the largest indicator seen)",
            "rows": rows.len(), "bad_rows": bad_ind.len(), "rows_falling_back": back, "good_rows_falling_back": good_back,
            "share_falling_back": back as f64 / rows.len() as f64, "omega_full_max": omega_max, "threshold": threshold,
        }),
    ))
}

/// The error summary of validation rows ([`validation_row`]): Ω and end-pressure errors
/// (median, p95, max), the count of designs whose Ω is within 3 % (and within 3 % or 0.1 % of
/// the largest full-model Ω of the rows), statuses that agree, and the mean CPU s per design.
pub fn validation_summary(rows: Vec<serde_json::Value>, count: usize, seed: u64) -> serde_json::Value {
    let rel = |a: f64, b: f64| if b != 0.0 { ((a - b) / b).abs() } else { (a - b).abs() };
    let num = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or(0.0);
    let mut e_om: Vec<f64> = rows.iter().map(|r| rel(num(r, "omega_rom"), num(r, "omega_full"))).collect();
    let mut e_p: Vec<f64> = rows.iter().flat_map(|r| [rel(num(r, "p_end_free_rom"), num(r, "p_end_free_full")), rel(num(r, "p_end_blocked_rom"), num(r, "p_end_blocked_full"))]).collect();
    let omega_max = rows.iter().map(|r| num(r, "omega_full")).fold(0.0f64, f64::max);
    let within3 = rows.iter().filter(|r| rel(num(r, "omega_rom"), num(r, "omega_full")) <= 0.03).count();
    let within_floor = rows.iter().filter(|r| rel(num(r, "omega_rom"), num(r, "omega_full")) <= 0.03 || (num(r, "omega_rom") - num(r, "omega_full")).abs() <= 1e-3 * omega_max).count();
    let statuses_agree = rows.iter().filter(|r| r["status_full"] == r["status_rom"]).count();
    let q = |v: &mut Vec<f64>, f: f64| -> f64 {
        v.sort_by(f64::total_cmp);
        v.get(((v.len().max(1) - 1) as f64 * f).round() as usize).copied().unwrap_or(f64::NAN)
    };
    let cpu = |k: &str| rows.iter().map(|r| num(r, k)).sum::<f64>() / rows.len().max(1) as f64;
    serde_json::json!({
        "designs": count, "seed": seed, "rows_done": rows.len(),
        "omega_rel_error": { "median": q(&mut e_om, 0.5), "p95": q(&mut e_om, 0.95), "max": q(&mut e_om, 1.0) },
        "p_end_rel_error": { "median": q(&mut e_p, 0.5), "p95": q(&mut e_p, 0.95), "max": q(&mut e_p, 1.0) },
        "omega_within_3pct": within3, "omega_within_3pct_or_0.1pct_of_max": within_floor, "omega_full_max": omega_max,
        "statuses_agree": statuses_agree,
        "cpu_s_per_design_full": cpu("cpu_s_full"), "cpu_s_per_design_rom": cpu("cpu_s_rom"),
        "rows": rows,
    })
}

// ---------------------------------------------------------------------------------------------
// Greedy enrichment (`rom train --enrich`)

/// How `rom train --enrich` grows the training set: each round ramps the reduced model on every
/// candidate design (seeded random designs of the box, disjoint in seed from the validations),
/// ranks them by the error indicator, adds the `batch` worst to the training designs, and
/// retrains, until the worst indicator is at most `target` or `rounds` rounds have run.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnrichOptions {
    pub rounds: usize,
    pub candidates: usize,
    pub batch: usize,
    pub target: f64,
    pub seed: u64,
}

/// The reduced model's error indicator on one design: the larger of its twist and torque
/// scenes' indicators ([`scene_pair`]), each ramped to failure or `p_max_kpa` on the reduced
/// model alone (no fallback). A scene that ends in an error, or without an indicator, counts as
/// +∞ (the model cannot answer there: the first design to train on).
pub fn design_indicator(opts: &SceneOptions, rom: &std::sync::Arc<Rom>, d: &Design, p_max_kpa: f64) -> f64 {
    let mut ro = opts.clone();
    ro.rom = Some(rom.clone());
    ro.rom_fallback = None;
    let Ok(g) = ActuatorGeometry::new(d, RangePolicy::TableI) else { return f64::INFINITY };
    let (twist, torque) = scene_pair(&opts.rom_scenes);
    let mut worst = 0.0f64;
    for kind in [twist, torque] {
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| crate::scene::run_pressure(&g, &ro, kind, &[p_max_kpa]))) {
            Ok(Ok(r)) => match r.rom_indicator.filter(|v| v.is_finite()) {
                Some(v) => worst = worst.max(v),
                None => return f64::INFINITY,
            },
            _ => return f64::INFINITY,
        }
    }
    worst
}

/// One enrichment round's choice: the indicators of `candidates` (those not `excluded`, in
/// parallel), and the indices of the `batch` worst whose indicator exceeds `target` (worst
/// first; empty when every candidate is at or below the target). `progress` is called once per
/// candidate.
pub fn enrichment_pick(
    opts: &SceneOptions,
    rom: &std::sync::Arc<Rom>,
    candidates: &[Design],
    excluded: &[usize],
    p_max_kpa: f64,
    batch: usize,
    target: f64,
    progress: &(impl Fn(usize, f64) + Sync),
) -> (Vec<(usize, f64)>, Vec<usize>) {
    let ind: Vec<(usize, f64)> = (0..candidates.len())
        .into_par_iter()
        .filter(|i| !excluded.contains(i))
        .map(|i| {
            let v = design_indicator(opts, rom, &candidates[i], p_max_kpa);
            progress(i, v);
            (i, v)
        })
        .collect();
    let mut ranked = ind.clone();
    // worst first; ties by index (deterministic)
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let picks = ranked.iter().filter(|(_, v)| *v > target).take(batch).map(|(i, _)| *i).collect();
    (ind, picks)
}

/// The record of one enrichment round: the candidates' indicator distribution before it, and
/// the designs it added.
pub fn enrichment_round_record(round: usize, ind: &[(usize, f64)], picks: &[usize], candidates: &[Design]) -> serde_json::Value {
    let mut v: Vec<f64> = ind.iter().map(|x| x.1).collect();
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v.get(((v.len().max(1) - 1) as f64 * f).round() as usize).copied().unwrap_or(f64::NAN);
    let of = |i: usize| ind.iter().find(|x| x.0 == i).map_or(f64::NAN, |x| x.1);
    let finite = |x: f64| if x.is_finite() { serde_json::json!(x) } else { serde_json::json!(null) };
    serde_json::json!({
        "round": round,
        "candidates": ind.len(),
        "indicator": { "max": finite(q(1.0)), "p90": finite(q(0.9)), "median": finite(q(0.5)), "unanswered": v.iter().filter(|x| !x.is_finite()).count() },
        "added": picks.iter().map(|&i| serde_json::json!({ "candidate": i, "design": candidates[i], "indicator": finite(of(i)) })).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod cache_tests {
    use super::cached_ramp_serves;

    #[test]
    fn a_cached_ramp_serves_another_bound_only_if_it_failed_below_both() {
        // same bound: always
        assert!(cached_ramp_serves(100.0, 100.0, 100.0));
        assert!(cached_ramp_serves(100.0, 64.2, 100.0));
        // stopped at its bound 100: lacks the states to 150
        assert!(!cached_ramp_serves(100.0, 100.0, 150.0));
        // failed at 64 kPa: the same path to any bound above 64
        assert!(cached_ramp_serves(100.0, 64.0, 150.0));
        assert!(cached_ramp_serves(150.0, 64.0, 100.0));
        // failed at 120 under a bound of 150: a ramp to 100 stops at 100, not at 120
        assert!(!cached_ramp_serves(150.0, 120.0, 100.0));
    }
}
