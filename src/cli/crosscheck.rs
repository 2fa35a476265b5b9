//! `twistopt crosscheck PROBLEM.toml [--scene NAME]... --out DIR`: the problem's scenes run by
//! twistopt and by CalculiX (ccx) on the same mesh, side by side in DIR/crosscheck.json (see
//! [`crate::calculix::compare`]).

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use clap::Args;

use crate::calculix::compare::{crosscheck, TwistoptElement};
use crate::calculix::{ccx_command, CcxElement, DeckOptions};
use crate::problem::Problem;
use crate::scene::SceneKind;

#[derive(Debug, Args)]
pub struct CrosscheckArgs {
    /// Problem file (TOML; schema in problems/README.md).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Scene to check (repeatable): free, blocked, pure-twist, pure-twist-blocked. Default: the
    /// problem's scenes.run.
    #[arg(long)]
    pub scene: Vec<String>,
    /// CalculiX element: C3D20R (default), C3D20, C3D8I or C3D8.
    #[arg(long, default_value = "C3D20R")]
    pub element: String,
    /// twistopt's element: `standard` (the problem's Q2/P1 Hex27) or `matched` (the ccx element's
    /// own discretisation: Hex20, pure displacement, 2×2×2 Gauss points for C3D20R, 3×3×3 for C3D20).
    #[arg(long, default_value = "standard")]
    pub twistopt_element: String,
    /// Override a problem value: section.key=value (as for `evaluate`). Repeatable.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Compare twistopt's full 360° model instead of the 120° sector (same as --set scenes.full=true).
    #[arg(long)]
    pub full: bool,
    /// Vacuum with contact: ccx's contact pairs take the cavity faces within this distance (mm)
    /// of a facing wall in twistopt's deepest state.
    #[arg(long, default_value_t = 0.3)]
    pub contact_patch_mm: f64,
    /// Vacuum with contact: slope of ccx's linear pressure–overclosure law (MPa/mm).
    #[arg(long, default_value_t = 10.0)]
    pub contact_slope: f64,
    /// ccx executable (default: $TWISTOPT_CCX, else `ccx` on the PATH).
    #[arg(long)]
    pub ccx: Option<String>,
    /// Output directory (created if missing): crosscheck.json and one folder per scene with the
    /// ccx deck, .dat and log.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: &CrosscheckArgs) -> Result<()> {
    let mut sets = args.set.clone();
    if args.full {
        sets.push("scenes.full=true".into());
    }
    let element = CcxElement::parse(&args.element).map_err(|e| anyhow!("--element: {e}"))?;
    let tw = TwistoptElement::parse(&args.twistopt_element).map_err(|e| anyhow!("--twistopt-element: {e}"))?;
    let problem = Problem::load(&args.problem, &sets)?;
    let scenes: Vec<SceneKind> = if args.scene.is_empty() {
        problem.validate()?.scenes
    } else {
        args.scene.iter().map(|s| SceneKind::parse(s).ok_or_else(|| anyhow!("--scene: unknown scene '{s}' (expected free, blocked, pure-twist or pure-twist-blocked)"))).collect::<Result<_>>()?
    };
    let ccx = args.ccx.clone().unwrap_or_else(ccx_command);
    if !(args.contact_patch_mm > 0.0 && args.contact_patch_mm.is_finite()) || !(args.contact_slope > 0.0 && args.contact_slope.is_finite()) {
        anyhow::bail!("--contact-patch-mm and --contact-slope must be positive (got {} and {})", args.contact_patch_mm, args.contact_slope);
    }
    let opts = DeckOptions { element, cap_load: problem.scenes.cap_load, contact_slope_mpa_per_mm: args.contact_slope, contact_patch_mm: args.contact_patch_mm, ..DeckOptions::default() };
    crosscheck(&problem, &scenes, &opts, tw, &ccx, &args.out, |l| println!("{l}"))?;
    println!("wrote {}", args.out.join("crosscheck.json").display());
    Ok(())
}
