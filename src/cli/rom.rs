//! `twistopt rom train`: train a reduced-order model over the Table-I box for a problem's mesh,
//! element, material and scene options (see [`crate::rom`]).

use crate::problem::Problem;
use crate::rom::{Manifest, TrainOptions, FORMAT_VERSION};
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
    /// After training, compare with the full model on this many seeded random designs.
    #[arg(long, default_value_t = 0)]
    pub validate: usize,
}

pub fn run(args: &RomArgs) -> Result<()> {
    match &args.command {
        RomCommand::Train(a) => train(a),
    }
}

fn train(a: &TrainArgs) -> Result<()> {
    let problem = Problem::load(&a.problem, &a.set)?;
    let v = problem.validate()?;
    let mut opts = problem.scene_options(&v);
    opts.rom = None;
    opts.keep_fields = false;
    if !(a.tau >= 0.0 && a.tau < 1.0) {
        anyhow::bail!("--tau {} must be in [0, 1)", a.tau);
    }
    if a.modes == 0 || a.designs == 0 {
        anyhow::bail!("--modes and --designs must be positive");
    }
    if !(a.p_max > 0.0 && a.p_max <= 1000.0) {
        anyhow::bail!("--p-max {} must be in (0, 1000] kPa", a.p_max);
    }
    let t = TrainOptions {
        designs: a.designs,
        p_max_kpa: a.p_max,
        truncation: Truncation::Modes(a.modes),
        ecsw: EcswOptions { tau: a.tau, max_elements: if a.tau > 0.0 { 100_000 } else { 0 }, tangent_directions: 0 },
        pressure_modes: (a.pressure_modes > 0).then_some(Truncation::Modes(a.pressure_modes)),
        ..TrainOptions::default()
    };
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
    let (rom, report) = crate::rom::from_ramps(&opts, &t, &ramps, &log)?;
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
    };
    crate::rom::save(&a.out, &rom, &manifest)?;
    println!(
        "wrote {}: {} modes, {} pressure modes, {} of {} elements; training {:.0} CPU s ({:.0} s wall)",
        a.out.display(),
        manifest.k,
        manifest.kp,
        manifest.sample.elements.len(),
        manifest.report.elements,
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
