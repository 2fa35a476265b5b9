//! `twistopt export PROBLEM.toml --format inp --scene NAME --out DIR`: a complete, runnable
//! CalculiX deck of one scene of a problem (see [`crate::calculix`]).

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;

use crate::calculix::{build_deck, CcxElement, DeckOptions};
use crate::problem::Problem;
use crate::scene::SceneKind;

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Problem file (TOML; schema in problems/README.md).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Export format (only `inp`: a CalculiX deck).
    #[arg(long, default_value = "inp")]
    pub format: String,
    /// Scene: free, blocked, pure-twist or pure-twist-blocked.
    #[arg(long)]
    pub scene: String,
    /// CalculiX element: C3D20R (default), C3D20, C3D8I or C3D8.
    #[arg(long, default_value = "C3D20R")]
    pub element: String,
    /// Override a problem value: section.key=value (as for `evaluate`). Repeatable.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Output directory (created if missing); the deck is DIR/<scene>.inp.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: &ExportArgs) -> Result<()> {
    if args.format != "inp" {
        bail!("--format '{}' is not supported (expected inp)", args.format);
    }
    let scene = SceneKind::parse(&args.scene).ok_or_else(|| anyhow!("--scene: unknown scene '{}' (expected free, blocked, pure-twist or pure-twist-blocked)", args.scene))?;
    let element = CcxElement::parse(&args.element).map_err(|e| anyhow!("--element: {e}"))?;
    let problem = Problem::load(&args.problem, &args.set)?;
    let v = problem.validate()?;
    let opts = DeckOptions { element, cap_load: problem.scenes.cap_load, ..DeckOptions::default() };
    let deck = build_deck(&v.geometry, &v.mesh, &v.material, scene, &v.load.targets(), &opts)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create output directory {}", args.out.display()))?;
    let path = args.out.join(format!("{}.inp", scene.name()));
    std::fs::write(&path, &deck.text).with_context(|| format!("cannot write {}", path.display()))?;
    println!(
        "wrote {} ({} nodes, {} {} elements, {} steps to {:?} kPa, cap area {:.3} mm2); run it with: cd {} && ccx -i {}",
        path.display(),
        deck.mesh.n_nodes() + 2,
        deck.mesh.n_elements(),
        element.name(),
        deck.step_pressures_kpa.len(),
        deck.step_pressures_kpa,
        deck.cap_area_mm2,
        args.out.display(),
        scene.name()
    );
    Ok(())
}
