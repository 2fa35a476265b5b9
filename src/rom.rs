//! Training of the reduced-order model over a design box ([`twistopt_solver::rom`]): full-order
//! ramps of the scenes on space-filling training designs give the snapshots, POD gives the basis
//! of the nodal unknowns (shared by every design and scene of one mesh), ECSW the element sample.

use crate::geometry::{ActuatorGeometry, Design, DesignSpace, RangePolicy};
use crate::scene::{SceneKind, SceneModel, SceneOptions};
use anyhow::{anyhow, Result};
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
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            designs: 16,
            scenes: vec![SceneKind::Free, SceneKind::Blocked],
            p_max_kpa: 100.0,
            truncation: Truncation::Tail { tol: 1e-6, max: 60 },
            ecsw: EcswOptions { tau: 0.01, max_elements: 400, tangent_directions: 2 },
            frame: Frame::Cylindrical,
            pressure_modes: Some(Truncation::Modes(10)),
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
    pub sample_elements: usize,
    pub elements: usize,
    pub ecsw_residual: f64,
    pub snapshot_time_s: f64,
    pub pod_time_s: f64,
    pub ecsw_time_s: f64,
    pub full_newton_iterations: usize,
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
    Ok(Ramp { design: design.clone(), kind, states, frame_states, pressure_states, newton_iterations: its })
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
    let reference = reference_nodes(opts, t.frame, t.scenes.first().copied().unwrap_or(SceneKind::Free))?;
    let jobs: Vec<(usize, SceneKind)> = (0..designs.len()).flat_map(|d| t.scenes.iter().map(move |&k| (d, k))).collect();
    let ramps: Vec<Ramp> = jobs
        .par_iter()
        .filter_map(|&(d, k)| match full_ramp(&designs[d], opts, k, t.p_max_kpa, t.frame, &reference) {
            Ok(r) => {
                log(&format!("  training design {} ({}) {}: {} states, {} Newton iterations", d, label(&designs[d]), k.name(), r.states.len(), r.newton_iterations));
                Some(r)
            }
            Err(e) => {
                log(&format!("  training design {} {}: skipped ({e})", d, k.name()));
                None
            }
        })
        .collect();
    let snapshot_time_s = t0.elapsed().as_secs_f64();
    // the nodal part of every loaded state, in the basis frame
    let snaps: Vec<Vec<f64>> = ramps.iter().flat_map(|r| r.frame_states.iter().cloned()).collect();
    if snaps.is_empty() {
        return Err(anyhow!("no training states: every training ramp failed"));
    }
    let t1 = Instant::now();
    let mut basis = Basis::pod(&snaps, t.truncation)?;
    basis.frame = t.frame;
    basis.reference = reference;
    if let Some(tr) = t.pressure_modes {
        let ps: Vec<Vec<f64>> = ramps.iter().flat_map(|r| r.pressure_states.iter().cloned()).collect();
        let np = opts.formulation.pressure.dim().max(1);
        let pb = twistopt_solver::rom::PressureBasis::pod(&ps, np, tr)?;
        log(&format!("  pressure POD: {} snapshots of {} coefficients → {} modes", ps.len(), ps[0].len(), pb.kp));
        basis.pressure = Some(pb);
    }
    let pod_time_s = t1.elapsed().as_secs_f64();
    log(&format!("  POD: {} snapshots of {} unknowns → {} modes ({:?} frame)", snaps.len(), basis.n, basis.k, basis.frame));
    // ECSW over the same states, design by design (each on its own geometry); max_elements = 0:
    // no hyper-reduction (every element at weight 1)
    let t2 = Instant::now();
    let mut acc = twistopt_solver::rom::EcswAccumulator::new(t.ecsw.tangent_directions);
    let mut elements = 0;
    let fit = if t.ecsw.max_elements == 0 {
        let geom = ActuatorGeometry::new(&designs[0], RangePolicy::TableI)?;
        let mut full = opts.clone();
        full.rom = None;
        elements = SceneModel::build(&geom, &full, t.scenes[0])?.model.mesh.n_elements();
        twistopt_solver::rom::EcswFit { sample: twistopt_solver::rom::Sample::all(elements), residual: 0.0, rows: 0 }
    } else {
        for r in &ramps {
            let geom = ActuatorGeometry::new(&r.design, RangePolicy::TableI)?;
            let mut full = opts.clone();
            full.rom = None;
            let sm = SceneModel::build(&geom, &full, r.kind)?;
            elements = sm.model.mesh.n_elements();
            let snaps: Vec<Snapshot> = r.states.iter().filter(|s| s.0 != 0.0).map(|s| Snapshot { model: &sm.model, q: s.1.clone(), presc: s.2.clone() }).collect();
            acc.add(&basis, &snaps)?;
        }
        acc.fit(&t.ecsw)
    };
    let ecsw_time_s = t2.elapsed().as_secs_f64();
    log(&format!("  ECSW: {} of {} elements, relative residual {:.2e} (τ = {})", fit.sample.elements.len(), elements, fit.residual, t.ecsw.tau));
    let report = TrainReport {
        training_designs: designs.to_vec(),
        snapshots: snaps.len(),
        modes: basis.k,
        singular_values: basis.singular_values.clone(),
        pressure_singular_values: basis.pressure.as_ref().map(|p| p.singular_values.clone()).unwrap_or_default(),
        sample_elements: fit.sample.elements.len(),
        elements,
        ecsw_residual: fit.residual,
        snapshot_time_s,
        pod_time_s,
        ecsw_time_s,
        full_newton_iterations: ramps.iter().map(|r| r.newton_iterations).sum(),
    };
    Ok((Rom { basis, sample: fit.sample }, report))
}

/// "r=…, l=…, alpha=…" of a design.
pub fn label(d: &Design) -> String {
    d.values.iter().map(|(k, v)| format!("{k}={v:.4}")).collect::<Vec<_>>().join(", ")
}
