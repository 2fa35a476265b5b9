//! Command-line interface. Each subcommand lives in its own module with an `Args` struct
//! (clap derive) and a `run` function; add new subcommands (evaluate, gradient, optimise,
//! sweep, export, crosscheck) by adding a variant to [`Command`] and a module here.

use clap::{Parser, Subcommand};

pub mod crosscheck;
pub mod evaluate;
pub mod export;
pub mod geometry;
pub mod gradient;
pub mod optimise;
pub mod rom;
pub mod sweep;
pub mod verify;

/// twistopt — design optimisation of soft twisting pneumatic actuators.
///
/// The actuator is a tube (outer radius 20 mm, height 40 mm, wall 3 mm) whose cross-section is a
/// triangular "horseshoe" of six arcs of radius r, whose lateral edge is a three-arc bellows with
/// waist radius l, and whose top face is pre-twisted by α (see GEOMETRY.md).
///
/// Available now: `geometry` (closed-form summary, mesh, VTU/STL/INP exports), `evaluate` (FE
/// load scenes of a problem file), `gradient` (adjoint sensitivities), `optimise` (gradient-based
/// design optimisation), `optimise-merge` (joins runs done as separate tasks), `sweep` /
/// `sweep-merge` (grid sweeps), `verify`, `export` (CalculiX
/// decks) and `crosscheck` (against CalculiX). Run
/// `twistopt <COMMAND> --help` for the options.
#[derive(Debug, Parser)]
#[command(name = "twistopt", version, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build the geometry and mesh of one design; write summary.json, mesh.vtu, outer.stl,
    /// cavity.stl and mesh.inp to an output directory.
    Geometry(geometry::GeometryArgs),
    /// Run a problem file (design, material, load, scenes, fidelity): the FE scenes, energy
    /// density and torque-rotation; write result.json, CSV tables, PNG/SVG plots and ParaView
    /// series to an output directory.
    Evaluate(evaluate::EvaluateArgs),
    /// Values and adjoint gradients of θ, τ, axial displacement, cavity volume, max radius (KS)
    /// and Ω with respect to every design parameter, the pressure and μ at one pressure; with
    /// --check-fd, central finite differences with a step study. Writes DIR/gradient.json.
    Gradient(gradient::GradientArgs),
    /// Maximise energy density, twist or torque over the design and the pressure under the
    /// ballooning limit (problem file [optimise] section): nlopt MMA/SLSQP and a pure-Rust SQP,
    /// multi-start in parallel. Writes DIR/history.json, DIR/best.json and convergence plots.
    Optimise(optimise::OptimiseArgs),
    /// Join the output directories of one optimisation's runs (`optimise --start I`, e.g. one
    /// task per start): history.json with every run, best.json with the best over them.
    OptimiseMerge(optimise::OptimiseMergeArgs),
    /// Run a problem's scenes on every design of a grid (Table I, every=K, or the problem's
    /// [sweep] section), ramped to failure; parallel, resumable (re-run the same command),
    /// shardable (--shard I/N); writes results.jsonl/csv, summary.json and Fig.-5 maps.
    Sweep(sweep::SweepArgs),
    /// Reduced-order models: `rom train` trains one over the Table-I box for a problem's mesh.
    Rom(rom::RomArgs),
    /// Join the output directories of a sweep's shards.
    SweepMerge(sweep::SweepMergeArgs),
    /// Compare an optimiser's best design (DIR/best.json) with a sweep's best; write verify.json.
    Verify(verify::VerifyArgs),
    /// Write a complete, runnable CalculiX deck (INP) of one scene of a problem file.
    Export(export::ExportArgs),
    /// Run twistopt and CalculiX (ccx) on the same scenes and mesh; write both side by side with
    /// relative differences, wall times and DOF counts to DIR/crosscheck.json.
    Crosscheck(crosscheck::CrosscheckArgs),
}

/// Run a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Geometry(args) => geometry::run(&args),
        Command::Evaluate(args) => evaluate::run(&args),
        Command::Gradient(args) => gradient::run(&args),
        Command::Optimise(args) => optimise::run(&args),
        Command::OptimiseMerge(args) => optimise::run_merge(&args),
        Command::Sweep(args) => sweep::run(&args),
        Command::Rom(args) => rom::run(&args),
        Command::SweepMerge(args) => sweep::run_merge(&args),
        Command::Verify(args) => verify::run(&args),
        Command::Export(args) => export::run(&args),
        Command::Crosscheck(args) => crosscheck::run(&args),
    }
}
