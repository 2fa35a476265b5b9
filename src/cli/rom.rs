//! `twistopt rom train`: train a reduced-order model over the Table-I box for a problem's mesh,
//! element, material and scene options (see [`crate::rom`]).

use crate::problem::Problem;
use crate::rom::{EnrichOptions, Manifest, TrainOptions, FORMAT_VERSION};
use crate::scene::SceneKind;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use twistopt_solver::rom::{EcswOptions, Truncation};

#[derive(Debug, Subcommand)]
pub enum RomCommand {
    /// Train a reduced model: full-order free and blocked ramps to failure on the box's corners
    /// and Halton designs (cached in DIR/ramps, so an interrupted training resumes), POD of the
    /// displacements and of the element pressures, ECSW; writes DIR/manifest.json and
    /// DIR/basis.bin (and, with --validate N, full-vs-reduced errors on N random designs).
    Train(TrainArgs),
    /// Compare a trained reduced model with the full model on seeded random designs of the
    /// Table-I box, free + blocked ramped to failure, one design at a time: OUT/rows.jsonl (one
    /// line per design, appended as each finishes: re-running the same command resumes) and
    /// OUT/summary.json (errors, statuses, indicators, CPU s per design).
    Validate(ValidateArgs),
    /// Robustness check of a reduced model: seeded random designs of the Table-I box, each with
    /// a random pressure bound of either sign, free + blocked on the reduced model alone (no
    /// fallback): every scene must end in a status with its cause, never a panic, an error or a
    /// non-finite value. OUT/rows.jsonl (resumable), OUT/summary.json; exits non-zero on any
    /// problem.
    Check(CheckArgs),
}

/// The problem and the reduced model a `rom validate` or `rom check` is of.
#[derive(Debug, Args)]
pub struct RomOf {
    /// Problem file the model was trained for (mesh, element, material, scene options).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Override a problem value: section.key=value (repeatable).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// The reduced model's directory (`rom train --out`).
    #[arg(long, value_name = "DIR")]
    pub rom: PathBuf,
}

#[derive(Debug, Args)]
pub struct CheckArgs {
    #[command(flatten)]
    pub of: RomOf,
    /// Number of random designs.
    #[arg(long, default_value_t = 1000)]
    pub designs: usize,
    /// Seed of the designs and pressures.
    #[arg(long, default_value_t = 11)]
    pub seed: u64,
    /// Lowest pressure bound (kPa; negative: vacuum).
    #[arg(long, default_value_t = -20.0, allow_hyphen_values = true)]
    pub p_min: f64,
    /// Highest pressure bound (kPa).
    #[arg(long, default_value_t = 150.0, allow_hyphen_values = true)]
    pub p_max: f64,
    /// Output directory (default: DIR/check-seed<SEED>).
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    #[command(flatten)]
    pub of: RomOf,
    /// Number of random designs.
    #[arg(long, default_value_t = 200)]
    pub designs: usize,
    /// Seed of the random designs (training uses corners and Halton points, so any seed gives
    /// held-out designs).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Pressure bound of the ramps (kPa).
    #[arg(long, default_value_t = 100.0)]
    pub p_max: f64,
    /// Output directory (default: DIR/validation-seed<SEED>).
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
    /// Calibrate the model's fallback threshold on this validation and record it in
    /// DIR/manifest.json (see `fidelity.rom_fallback` in problems/README.md).
    #[arg(long)]
    pub calibrate: bool,
    /// Take the full-order answers from an earlier validation's rows.jsonl on the same problem,
    /// seed and pressure bound (another reduced model of the same mesh) instead of recomputing
    /// them; each reused row is checked to be of the same design and marked `full_reused`.
    #[arg(long, value_name = "ROWS.jsonl")]
    pub full_from: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct RomArgs {
    #[command(subcommand)]
    pub command: RomCommand,
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Problem file: its mesh, material and scene options are the ones the model is for.
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Override a problem value: section.key=value (repeatable).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Output directory of the model (created if missing; re-running resumes its ramps).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Training designs: the 8 corners of the box, then Halton points.
    #[arg(long, default_value_t = 40)]
    pub designs: usize,
    /// Displacement modes kept (at most).
    #[arg(long, default_value_t = 80)]
    pub modes: usize,
    /// Pressure modes (0: each element condenses its own pressure, which locks).
    #[arg(long, default_value_t = 10)]
    pub pressure_modes: usize,
    /// ECSW tolerance τ (0: no hyper-reduction, every element at weight 1).
    #[arg(long, default_value_t = 0.0)]
    pub tau: f64,
    /// Pressure bound of the training ramps (kPa).
    #[arg(long, default_value_t = 100.0)]
    pub p_max: f64,
    /// Hyper-reduce by quadrature points instead of whole elements (needs pressure modes):
    /// each sampled point is evaluated alone, so far fewer kernels run per iteration.
    #[arg(long)]
    pub points: bool,
    /// Fit the ECSW weights on at most this many snapshots, evenly spaced over the training
    /// states (0: all). The quadrature-level fit's normal equations grow with the square of the
    /// candidates (27 per element), so it fits on a subset.
    #[arg(long, default_value_t = 0)]
    pub ecsw_snapshots: usize,
    /// Append at most this many modes from the full tangent's lowest eigenvectors at the ends of
    /// the training ramps that stop at an instability (a pressure maximum or a bifurcation): the
    /// buckling directions, which no converged state contains. Without them a reduced model can
    /// miss a bifurcation and run on to a later pressure maximum (the pure-twist scenes at large α).
    #[arg(long, default_value_t = 0)]
    pub buckling_modes: usize,
    /// After training, compare with the full model on this many seeded random designs.
    #[arg(long, default_value_t = 0)]
    pub validate: usize,
    /// Components the modes are expressed in: cylindrical (radial / circumferential / axial at
    /// each node: modes follow each design's pre-twist; smaller POD error at a given k), cartesian
    /// (one Φ for every design: the cavity volume is then reduced as an exact cubic with
    /// precomputed tensors, a cheaper tangent) or piola (pushed forward from the box centre's mesh).
    #[arg(long, default_value = "cylindrical", value_parser = ["cylindrical", "cartesian", "piola"])]
    pub frame: String,
    /// Scenes whose ramps are the snapshots, comma-separated (default: the problem's
    /// scenes.run): free,blocked for the combined mode, pure-twist,pure-twist-blocked for the
    /// pure-twist mode, or all four. The model refuses any other scene.
    #[arg(long, value_name = "SCENE,SCENE")]
    pub scenes: Option<String>,
    /// Greedy enrichment: after training, up to this many rounds, each ramping the reduced
    /// model on the candidate designs, adding the worst by the error indicator (the full model's
    /// residual at the reduced states) to the training designs and retraining. Resumable
    /// (DIR/enrichment.json and the cached ramps).
    #[arg(long, default_value_t = 0)]
    pub enrich: usize,
    /// Enrichment candidates: this many seeded random designs of the box.
    #[arg(long, default_value_t = 100)]
    pub enrich_candidates: usize,
    /// Designs added per enrichment round (the worst ones).
    #[arg(long, default_value_t = 2)]
    pub enrich_batch: usize,
    /// Stop enriching once every candidate's indicator is at most this.
    #[arg(long, default_value_t = 0.08)]
    pub enrich_target: f64,
    /// Seed of the enrichment candidates (the validations' default seeds are 7 and 42).
    #[arg(long, default_value_t = 1001)]
    pub enrich_seed: u64,
}

pub fn run(args: &RomArgs) -> Result<()> {
    match &args.command {
        RomCommand::Train(a) => train(a),
        RomCommand::Validate(a) => validate(a),
        RomCommand::Check(a) => check(a),
    }
}

/// The scene options of a problem file on the full model, without fields: what a reduced model
/// is trained for and validated against.
fn full_options(path: &std::path::Path, set: &[String]) -> Result<crate::scene::SceneOptions> {
    Ok(full_options_and_scenes(path, set)?.0)
}

/// [`full_options`] and the problem's scenes (`scenes.run`).
fn full_options_and_scenes(path: &std::path::Path, set: &[String]) -> Result<(crate::scene::SceneOptions, Vec<SceneKind>)> {
    let problem = Problem::load(path, set)?;
    let v = problem.validate()?;
    let mut opts = problem.scene_options(&v);
    opts.rom = None;
    opts.rom_scenes.clear();
    opts.keep_fields = false;
    Ok((opts, v.scenes))
}

/// The training scenes: `--scenes` (comma-separated) or the problem's; a complete pair of one
/// mode at least (free + blocked, or pure-twist + pure-twist-blocked), for validation.
fn training_scenes(list: Option<&str>, problem: &[SceneKind]) -> Result<Vec<SceneKind>> {
    let scenes: Vec<SceneKind> = match list {
        Some(s) => s
            .split(',')
            .map(|n| SceneKind::parse(n.trim()).ok_or_else(|| anyhow::anyhow!("--scenes: unknown scene '{}' (expected free, blocked, pure-twist or pure-twist-blocked)", n.trim())))
            .collect::<Result<_>>()?,
        None => problem.to_vec(),
    };
    let mut uniq = Vec::new();
    for k in scenes {
        if !uniq.contains(&k) {
            uniq.push(k);
        }
    }
    let has = |k: SceneKind| uniq.contains(&k);
    if !((has(SceneKind::Free) && has(SceneKind::Blocked)) || (has(SceneKind::PureTwist) && has(SceneKind::PureTwistBlocked))) {
        anyhow::bail!(
            "the training scenes ({}) must hold a mode's twist and torque scenes: free + blocked or pure-twist + pure-twist-blocked (--scenes, or the problem's scenes.run)",
            uniq.iter().map(|k| k.name()).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(uniq)
}

fn train(a: &TrainArgs) -> Result<()> {
    let (mut opts, problem_scenes) = full_options_and_scenes(&a.problem, &a.set)?;
    let scenes = training_scenes(a.scenes.as_deref(), &problem_scenes)?;
    if !(a.tau >= 0.0 && a.tau < 1.0) {
        anyhow::bail!("--tau {} must be in [0, 1)", a.tau);
    }
    if a.points && a.pressure_modes == 0 {
        anyhow::bail!("--points needs pressure modes (--pressure-modes > 0): an element's own pressure is condensed over all its quadrature points");
    }
    if a.modes == 0 || a.designs == 0 {
        anyhow::bail!("--modes and --designs must be positive");
    }
    if !(a.p_max > 0.0 && a.p_max <= 1000.0) {
        anyhow::bail!("--p-max {} must be in (0, 1000] kPa", a.p_max);
    }
    if a.enrich > 0 && (a.enrich_candidates == 0 || a.enrich_batch == 0 || !(a.enrich_target >= 0.0 && a.enrich_target.is_finite())) {
        anyhow::bail!("--enrich needs --enrich-candidates > 0, --enrich-batch > 0 and a finite --enrich-target ≥ 0");
    }
    let t = TrainOptions {
        designs: a.designs,
        p_max_kpa: a.p_max,
        truncation: Truncation::Modes(a.modes),
        ecsw: EcswOptions { tau: a.tau, max_elements: if a.tau > 0.0 { 100_000 } else { 0 }, tangent_directions: 0, points: a.points, max_snapshots: a.ecsw_snapshots },
        pressure_modes: (a.pressure_modes > 0).then_some(Truncation::Modes(a.pressure_modes)),
        buckling_modes: a.buckling_modes,
        frame: match a.frame.as_str() {
            "cartesian" => twistopt_solver::rom::Frame::Cartesian,
            "piola" => twistopt_solver::rom::Frame::Piola,
            _ => twistopt_solver::rom::Frame::Cylindrical,
        },
        scenes,
        ..TrainOptions::default()
    };
    opts.rom_scenes = t.scenes.clone();
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let designs = crate::rom::training_designs(t.designs);
    let jobs = designs.len() * t.scenes.len();
    println!("training a reduced model for mesh {:?} on {} designs × {} scenes ({} ramps) into {}", opts.mesh, designs.len(), t.scenes.len(), jobs, a.out.display());
    let c0 = crate::evaluate::process_cpu_time_s();
    let w0 = std::time::Instant::now();
    let pb = indicatif::ProgressBar::with_draw_target(Some(jobs as u64), indicatif::ProgressDrawTarget::stderr());
    if let Ok(style) = indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} ramps, ETA {eta_precise} {msg}") {
        pb.set_style(style.progress_chars("=> "));
    }
    let ramps = crate::rom::training_ramps_cached(&opts, &t, &designs, &a.out, &|s: &str| {
        pb.inc(1);
        pb.suspend(|| eprintln!("  {s}"));
    })?;
    pb.finish_and_clear();
    let log = |s: &str| println!("{s}");
    let (mut rom, mut report) = crate::rom::from_ramps(&opts, &t, &ramps, &log)?;
    let mut enrichment = None;
    if a.enrich > 0 {
        let eo = EnrichOptions { rounds: a.enrich, candidates: a.enrich_candidates, batch: a.enrich_batch, target: a.enrich_target, seed: a.enrich_seed };
        let (r, rep, record) = enrich(&opts, &t, &eo, &designs, rom, report, &a.out, a.p_max)?;
        (rom, report, enrichment) = (r, rep, Some(record));
    }
    let space = crate::geometry::DesignSpace::actuator();
    let mut manifest = Manifest {
        format_version: FORMAT_VERSION,
        mesh: opts.mesh,
        formulation: opts.formulation,
        material: opts.material,
        sector: opts.sector,
        cap_load: opts.cap_load,
        design_box: space.params.clone(),
        frame: rom.basis.frame,
        n: rom.basis.n,
        k: rom.basis.k,
        np: rom.basis.pressure.as_ref().map_or(0, |p| p.np),
        kp: rom.basis.pressure.as_ref().map_or(0, |p| p.kp),
        reference_nodes: rom.basis.reference.len(),
        sample: rom.sample.clone(),
        options: t.clone(),
        report,
        train_cpu_s: crate::evaluate::process_cpu_time_s() - c0,
        train_wall_s: w0.elapsed().as_secs_f64(),
        validation: None,
        fallback_indicator: None,
        fallback_calibration: None,
        enrichment,
    };
    crate::rom::save(&a.out, &rom, &manifest)?;
    println!(
        "wrote {}: {} modes, {} pressure modes, {}; training {:.0} CPU s ({:.0} s wall)",
        a.out.display(),
        manifest.k,
        manifest.kp,
        manifest.sample.describe(manifest.report.elements),
        manifest.train_cpu_s,
        manifest.train_wall_s
    );
    if a.validate > 0 {
        let val = crate::rom::validate(&opts, std::sync::Arc::new(rom.clone()), a.validate, 42, a.p_max, &|s: &str| println!("  {s}"))?;
        println!(
            "validation on {} random designs: Ω error median {:.2} %, p95 {:.2} %; end-pressure error median {:.3} %, p95 {:.3} %; {:.2} vs {:.2} CPU s per design (reduced vs full)",
            a.validate,
            100.0 * val["omega_rel_error"]["median"].as_f64().unwrap_or(f64::NAN),
            100.0 * val["omega_rel_error"]["p95"].as_f64().unwrap_or(f64::NAN),
            100.0 * val["p_end_rel_error"]["median"].as_f64().unwrap_or(f64::NAN),
            100.0 * val["p_end_rel_error"]["p95"].as_f64().unwrap_or(f64::NAN),
            val["cpu_s_per_design_rom"].as_f64().unwrap_or(f64::NAN),
            val["cpu_s_per_design_full"].as_f64().unwrap_or(f64::NAN)
        );
        manifest.validation = Some(val);
        manifest.train_cpu_s = crate::evaluate::process_cpu_time_s() - c0;
        crate::rom::save(&a.out, &rom, &manifest)?;
    }
    Ok(())
}

/// Greedy enrichment of a trained model (see [`TrainArgs::enrich`]): returns the final model,
/// its report and the enrichment record (options, rounds, the final model's indicators). The
/// rounds done are kept in DIR/enrichment.json after each round; a re-run with the same options
/// and initial designs replays them from the cached ramps and goes on.
#[allow(clippy::too_many_arguments)]
fn enrich(
    opts: &crate::scene::SceneOptions,
    t: &TrainOptions,
    eo: &EnrichOptions,
    designs: &[crate::geometry::Design],
    mut rom: twistopt_solver::rom::Rom,
    mut report: crate::rom::TrainReport,
    dir: &std::path::Path,
    p_max: f64,
) -> Result<(twistopt_solver::rom::Rom, crate::rom::TrainReport, serde_json::Value)> {
    let state_path = dir.join("enrichment.json");
    let candidates = crate::rom::random_designs(eo.candidates, eo.seed);
    let mut rounds: Vec<serde_json::Value> = Vec::new();
    if let Ok(text) = std::fs::read_to_string(&state_path) {
        match serde_json::from_str::<serde_json::Value>(&text) {
            Ok(v) if v["options"] == serde_json::json!(eo) && v["initial_designs"] == serde_json::json!(designs) && v["p_max_kPa"] == serde_json::json!(p_max) => {
                rounds = v["rounds"].as_array().cloned().unwrap_or_default();
            }
            _ => println!("enrichment: {} is of other options or designs: starting afresh", state_path.display()),
        }
    }
    let added_of = |rounds: &[serde_json::Value]| -> Vec<usize> {
        rounds.iter().flat_map(|r| r["added"].as_array().cloned().unwrap_or_default()).filter_map(|a| a["candidate"].as_u64().map(|i| i as usize)).collect()
    };
    let log = |s: &str| println!("{s}");
    let train_on = |added: &[usize]| -> Result<(twistopt_solver::rom::Rom, crate::rom::TrainReport)> {
        let mut all = designs.to_vec();
        all.extend(added.iter().map(|&i| candidates[i].clone()));
        let ramps = crate::rom::training_ramps_cached(opts, t, &all, dir, &|s: &str| eprintln!("  {s}"))?;
        crate::rom::from_ramps(opts, t, &ramps, &log)
    };
    let save = |rounds: &[serde_json::Value], fin: Option<&serde_json::Value>| -> Result<serde_json::Value> {
        let v = serde_json::json!({ "options": eo, "p_max_kPa": p_max, "initial_designs": designs, "rounds": rounds, "final": fin });
        crate::sweep::write_atomic(&state_path, &serde_json::to_string_pretty(&v)?)?;
        Ok(v)
    };
    if !rounds.is_empty() {
        println!("enrichment: resuming after {} round(s) done", rounds.len());
        (rom, report) = train_on(&added_of(&rounds))?;
    }
    let pass = |rom: &twistopt_solver::rom::Rom, excluded: &[usize], round: usize, batch: usize| {
        let rom = std::sync::Arc::new(rom.clone());
        let n = candidates.len() - excluded.len();
        let pb = indicatif::ProgressBar::with_draw_target(Some(n as u64), indicatif::ProgressDrawTarget::stderr());
        if let Ok(style) = indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} candidates, ETA {eta_precise} {msg}") {
            pb.set_style(style.progress_chars("=> "));
        }
        pb.set_message(format!("enrichment round {round}"));
        let (ind, picks) = crate::rom::enrichment_pick(opts, &rom, &candidates, excluded, p_max, batch, eo.target, &|_, _| pb.inc(1));
        pb.finish_and_clear();
        (ind, picks)
    };
    let converged = |rounds: &[serde_json::Value]| rounds.last().is_some_and(|r| r["added"].as_array().is_some_and(|a| a.is_empty()));
    while rounds.len() < eo.rounds && !converged(&rounds) {
        let added = added_of(&rounds);
        let (ind, picks) = pass(&rom, &added, rounds.len(), eo.batch);
        let rec = crate::rom::enrichment_round_record(rounds.len(), &ind, &picks, &candidates);
        println!(
            "enrichment round {}: indicator over {} candidates max {} p90 {} median {}; adding {}",
            rounds.len(),
            ind.len(),
            rec["indicator"]["max"],
            rec["indicator"]["p90"],
            rec["indicator"]["median"],
            if picks.is_empty() {
                format!("none (every indicator ≤ {})", eo.target)
            } else {
                picks.iter().map(|&i| format!("candidate {i} ({})", crate::rom::label(&candidates[i]))).collect::<Vec<_>>().join(", ")
            }
        );
        rounds.push(rec);
        save(&rounds, None)?;
        if !picks.is_empty() {
            let mut all = added;
            all.extend(&picks);
            (rom, report) = train_on(&all)?;
        }
    }
    // the final model's indicators (the last round's when it added nothing)
    let fin = if converged(&rounds) {
        rounds.last().cloned().unwrap_or_default()
    } else {
        let added = added_of(&rounds);
        let (ind, _) = pass(&rom, &added, rounds.len(), 0);
        let rec = crate::rom::enrichment_round_record(rounds.len(), &ind, &[], &candidates);
        println!("enrichment: the final model's indicator over {} candidates max {} p90 {} median {}", ind.len(), rec["indicator"]["max"], rec["indicator"]["p90"], rec["indicator"]["median"]);
        rec
    };
    let record = save(&rounds, Some(&fin))?;
    Ok((rom, report, record))
}

fn validate(a: &ValidateArgs) -> Result<()> {
    let mut opts = full_options(&a.of.problem, &a.of.set)?;
    if a.designs == 0 {
        anyhow::bail!("--designs must be positive");
    }
    if !(a.p_max > 0.0 && a.p_max <= 1000.0) {
        anyhow::bail!("--p-max {} must be in (0, 1000] kPa", a.p_max);
    }
    let (rom, mut manifest) = crate::rom::load(&a.of.rom, &opts)?;
    opts.rom_scenes = manifest.options.scenes.clone();
    let rom = std::sync::Arc::new(rom);
    let out = a.out.clone().unwrap_or_else(|| a.of.rom.join(format!("validation-seed{}", a.seed)));
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut input = serde_json::json!({ "rom": a.of.rom, "mesh": manifest.mesh, "k": manifest.k, "kp": manifest.kp, "seed": a.seed, "p_max_kPa": a.p_max });
    if let Some(f) = &a.full_from {
        input["full_from"] = serde_json::json!(f);
    }
    let (twist, torque) = crate::rom::scene_pair(&opts.rom_scenes);
    if twist != SceneKind::Free {
        // (free + blocked validations, written before the pair was recorded, resume as they are)
        input["scenes"] = serde_json::json!([twist.name(), torque.name()]);
    }
    let full_rows: std::collections::BTreeMap<u64, serde_json::Value> = match &a.full_from {
        Some(f) => {
            if !f.is_file() {
                anyhow::bail!("--full-from {}: no such file", f.display());
            }
            crate::evaluate::read_json_lines(f).into_iter().filter(|r| r.get("error").is_none()).filter_map(|r| r["index"].as_u64().map(|i| (i, r))).collect()
        }
        None => Default::default(),
    };
    let designs = crate::rom::random_designs(a.designs, a.seed);
    let header = |done: usize| {
        println!(
            "validating {} ({} modes, {} pressure modes, {}) on {} random designs (seed {}), {} already done, into {}",
            a.of.rom.display(),
            manifest.k,
            manifest.kp,
            manifest.sample.describe(manifest.report.elements),
            a.designs,
            a.seed,
            done,
            out.display()
        )
    };
    let rows = resumable_rows(
        &out,
        &input,
        "a validation of another model, seed or pressure bound",
        designs.len(),
        header,
        |i| crate::rom::validation_row(&opts, &rom, i, &designs[i], a.p_max, full_rows.get(&(i as u64))).map_err(|e| (serde_json::json!(designs[i]), e)),
        |i, row| {
            format!(
                "  {i}: {}: Ω full {:.3} reduced {:.3} J/m³; {:.1} vs {:.1} CPU s",
                crate::rom::label(&designs[i]),
                row["omega_full"].as_f64().unwrap_or(f64::NAN),
                row["omega_rom"].as_f64().unwrap_or(f64::NAN),
                row["cpu_s_rom"].as_f64().unwrap_or(f64::NAN),
                row["cpu_s_full"].as_f64().unwrap_or(f64::NAN)
            )
        },
    )?;
    let failed = rows.iter().filter(|r| r.get("error").is_some()).count();
    let calibration = crate::rom::calibrate_fallback(&rows);
    let ok: Vec<serde_json::Value> = rows.into_iter().filter(|r| r.get("error").is_none()).collect();
    let mut summary = crate::rom::validation_summary(ok, a.designs, a.seed);
    summary["failed"] = serde_json::json!(failed);
    crate::sweep::write_atomic(&out.join("summary.json"), &serde_json::to_string_pretty(&summary)?)?;
    println!(
        "{} designs ({} failed): Ω within 3 % on {}, within 3 % or 0.1 % of the largest Ω on {}; Ω error median {:.2} %, p95 {:.2} %; end-pressure error median {:.3} %, p95 {:.3} %, max {:.3} %; statuses agree on {}; {:.2} vs {:.2} CPU s per design (reduced vs full); wrote {}",
        summary["rows_done"],
        failed,
        summary["omega_within_3pct"],
        summary["omega_within_3pct_or_0.1pct_of_max"],
        100.0 * summary["omega_rel_error"]["median"].as_f64().unwrap_or(f64::NAN),
        100.0 * summary["omega_rel_error"]["p95"].as_f64().unwrap_or(f64::NAN),
        100.0 * summary["p_end_rel_error"]["median"].as_f64().unwrap_or(f64::NAN),
        100.0 * summary["p_end_rel_error"]["p95"].as_f64().unwrap_or(f64::NAN),
        100.0 * summary["p_end_rel_error"]["max"].as_f64().unwrap_or(f64::NAN),
        summary["statuses_agree"],
        summary["cpu_s_per_design_rom"].as_f64().unwrap_or(f64::NAN),
        summary["cpu_s_per_design_full"].as_f64().unwrap_or(f64::NAN),
        out.join("summary.json").display()
    );
    if let Some((t, c)) = &calibration {
        println!(
            "fallback threshold {t:.4}: {} bad rows; {} of {} rows would run again on the full model ({} of them good)",
            c["bad_rows"], c["rows_falling_back"], c["rows"], c["good_rows_falling_back"]
        );
    }
    if a.calibrate {
        let (t, mut c) = calibration.ok_or_else(|| anyhow::anyhow!("--calibrate: no successful validation row"))?;
        c["validation"] = serde_json::json!(out);
        manifest.fallback_indicator = Some(t);
        manifest.fallback_calibration = Some(c);
        crate::sweep::write_atomic(&a.of.rom.join("manifest.json"), &serde_json::to_string_pretty(&manifest)?)?;
        println!("recorded the fallback threshold in {}", a.of.rom.join("manifest.json").display());
    }
    Ok(())
}

fn check(a: &CheckArgs) -> Result<()> {
    let mut opts = full_options(&a.of.problem, &a.of.set)?;
    if a.designs == 0 {
        anyhow::bail!("--designs must be positive");
    }
    if !(a.p_min.is_finite() && a.p_max.is_finite() && a.p_min < a.p_max && a.p_min >= -1000.0 && a.p_max <= 1000.0) {
        anyhow::bail!("--p-min {} and --p-max {} must satisfy -1000 <= p-min < p-max <= 1000 kPa", a.p_min, a.p_max);
    }
    let (rom, manifest) = crate::rom::load(&a.of.rom, &opts)?;
    opts.rom_scenes = manifest.options.scenes.clone();
    let rom = std::sync::Arc::new(rom);
    let out = a.out.clone().unwrap_or_else(|| a.of.rom.join(format!("check-seed{}", a.seed)));
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let input = serde_json::json!({ "rom": a.of.rom, "mesh": manifest.mesh, "k": manifest.k, "seed": a.seed, "p_min_kPa": a.p_min, "p_max_kPa": a.p_max });
    let designs = crate::rom::random_designs(a.designs, a.seed);
    let pressures = crate::rom::random_pressures(a.designs, a.seed, a.p_min, a.p_max);
    let header = |done: usize| {
        println!("checking {} on {} random designs and pressures in [{}, {}] kPa (seed {}), {done} already done, into {}", a.of.rom.display(), a.designs, a.p_min, a.p_max, a.seed, out.display())
    };
    let rows = resumable_rows(
        &out,
        &input,
        "a check of another model, seed or pressure range",
        designs.len(),
        header,
        |i| crate::rom::check_row(&opts, &rom, i, &designs[i], pressures[i]).map_err(|e| (serde_json::json!(designs[i]), e)),
        |i, row| {
            let st = |s: &str| row["scenes"][s]["status"].as_str().unwrap_or("?").to_string();
            format!("  {i}: {} to {:.1} kPa: {} / {}; {} problems", crate::rom::label(&designs[i]), pressures[i], st("free"), st("blocked"), row["problems"].as_array().map_or(0, |p| p.len()))
        },
    )?;
    let summary = crate::rom::check_summary(&rows);
    crate::sweep::write_atomic(&out.join("summary.json"), &serde_json::to_string_pretty(&summary)?)?;
    println!(
        "{} designs: statuses {}; {} problems; {:.2} CPU s per design; wrote {}",
        summary["rows"],
        summary["statuses"],
        summary["problems"],
        summary["cpu_s_per_design"].as_f64().unwrap_or(f64::NAN),
        out.join("summary.json").display()
    );
    if summary["problems"].as_u64() != Some(0) {
        anyhow::bail!("{} problems (see {})", summary["problems"], out.join("summary.json").display());
    }
    Ok(())
}

/// The resumable loop of `rom validate` and `rom check`: OUT/input.json must equal `input` (else
/// the directory holds `other`, refused), OUT/rows.jsonl gets one line per index as each
/// finishes (`row(i)`, or on its error the record {index, design, error}); indices already
/// there are skipped. Returns every row, sorted by index.
#[allow(clippy::too_many_arguments)]
fn resumable_rows(
    out: &std::path::Path,
    input: &serde_json::Value,
    other: &str,
    count: usize,
    header: impl Fn(usize),
    row: impl Fn(usize) -> std::result::Result<serde_json::Value, (serde_json::Value, anyhow::Error)>,
    line: impl Fn(usize, &serde_json::Value) -> String,
) -> Result<Vec<serde_json::Value>> {
    let input_path = out.join("input.json");
    if let Some(before) = std::fs::read_to_string(&input_path).ok().and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok()) {
        if &before != input {
            anyhow::bail!("{} holds {other} ({before}); use another --out", out.display());
        }
    }
    crate::sweep::write_atomic(&input_path, &serde_json::to_string_pretty(input)?)?;
    let rows_path = out.join("rows.jsonl");
    let mut rows: Vec<serde_json::Value> = crate::evaluate::read_json_lines(&rows_path);
    let done: std::collections::BTreeSet<u64> = rows.iter().filter_map(|r| r["index"].as_u64()).collect();
    header(done.len());
    let pb = indicatif::ProgressBar::with_draw_target(Some(count as u64), indicatif::ProgressDrawTarget::stderr());
    if let Ok(style) = indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} designs, ETA {eta_precise} {msg}") {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_position(done.len() as u64);
    for i in 0..count {
        if done.contains(&(i as u64)) {
            continue;
        }
        let r = match row(i) {
            Ok(r) => {
                pb.suspend(|| eprintln!("{}", line(i, &r)));
                r
            }
            Err((design, e)) => {
                // recorded, so that the summary counts it and a resume does not retry it forever
                pb.suspend(|| eprintln!("  {i}: failed: {e:#}"));
                serde_json::json!({ "index": i, "design": design, "error": format!("{e:#}") })
            }
        };
        crate::evaluate::append_json_line(&rows_path, &r)?;
        rows.push(r);
        pb.inc(1);
    }
    pb.finish_and_clear();
    rows.sort_by_key(|r| r["index"].as_u64().unwrap_or(u64::MAX));
    Ok(rows)
}
