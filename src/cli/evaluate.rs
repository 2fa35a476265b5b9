//! `twistopt evaluate`: run a problem file's scenes and write result.json, CSV tables, plots and
//! ParaView series (see [`crate::problem`] for the file format and [`crate::evaluate`] for the
//! outputs).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::evaluate::evaluate;
use crate::problem::Problem;

#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// Problem file (TOML; schema in problems/README.md).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Override a problem value: section.key=value, the value parsed as TOML
    /// (e.g. --set design.alpha_deg=120 --set load.pressures_kPa=[10,20] --set fidelity.preset=coarse).
    /// Repeatable; applied in order.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Run the full 360° model instead of the 120° sector (same as --set scenes.full=true).
    #[arg(long)]
    pub full: bool,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: &EvaluateArgs) -> Result<()> {
    let mut sets = args.set.clone();
    if args.full {
        sets.push("scenes.full=true".into());
    }
    let problem = Problem::load(&args.problem, &sets)?;
    let t0 = std::time::Instant::now();
    let ev = evaluate(&problem, &args.out, |line| println!("{line}"))?;
    let r = &ev.result;
    for (key, what) in [("omega_J_m3", "combined"), ("omega_pure_twist_J_m3", "pure twist")] {
        if let Some(v) = r.get(key) {
            match v.as_f64() {
                Some(x) => println!("energy density ({what}): {x:.3} J/m3"),
                None => {
                    println!("energy density ({what}): not available (no common positive pressure)")
                }
            }
        }
    }
    println!("wrote {} files to {} in {:.1} s", ev.files.len(), args.out.display(), t0.elapsed().as_secs_f64());
    Ok(())
}
