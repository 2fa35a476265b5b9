//! `twistopt verify`: an optimiser's best design against a sweep's best (see
//! [`crate::sweep::verify`]).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::sweep::{load_problem, verify::verify};

#[derive(Debug, Args)]
pub struct VerifyArgs {
    /// Problem file (the one the sweep and the optimiser ran).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Sweep directory (manifest.json + results.jsonl, from `twistopt sweep`).
    #[arg(long, value_name = "DIR")]
    pub sweep: PathBuf,
    /// Optimiser output directory (best.json).
    #[arg(long, value_name = "DIR")]
    pub optimise: PathBuf,
    /// Override a problem value (section.key=value). Repeatable.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Objective mode when the sweep ran both pairs of scenes: combined (free + blocked) or
    /// pure-twist (default: the sweep rows' primary mode, combined when present).
    #[arg(long, value_name = "combined|pure-twist")]
    pub mode: Option<String>,
    /// Where to write verify.json and verify.txt (default: the optimiser directory).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

pub fn run(args: &VerifyArgs) -> Result<()> {
    let (problem, _) = load_problem(&args.problem, &args.set)?;
    let (v, summary) = verify(&problem, &args.sweep, &args.optimise, args.mode.as_deref())?;
    let out = args.out.clone().unwrap_or_else(|| args.optimise.clone());
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let j = out.join("verify.json");
    std::fs::write(&j, serde_json::to_string_pretty(&v)? + "\n").with_context(|| format!("cannot write {}", j.display()))?;
    let t = out.join("verify.txt");
    std::fs::write(&t, summary.clone() + "\n").with_context(|| format!("cannot write {}", t.display()))?;
    println!("{summary}");
    println!("wrote {} and {}", j.display(), t.display());
    Ok(())
}
