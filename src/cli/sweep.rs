//! `twistopt sweep` and `twistopt sweep-merge`: grid sweeps (see [`crate::sweep`]).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::sweep::{load_problem, merge, run_sweep, RunOptions, Shard, SweepConfig};

#[derive(Debug, Args)]
pub struct SweepArgs {
    /// Problem file (TOML; schema in problems/README.md): material, load.p_max_kPa (ramp end),
    /// scenes, fidelity and optionally a [sweep] section with the grid.
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Grid: `table1` (the letter's Table I, 39 864 designs) or `every=K` (every K-th value of
    /// each Table-I axis); overrides the problem file's [sweep] section.
    #[arg(long, value_name = "table1|every=K")]
    pub grid: Option<String>,
    /// Mesh fidelity: a preset (coarse, default, fine) or <Na>x<Nz>x<Nt> (Hex27); overrides
    /// the problem's [fidelity]. `rom:DIR`: the reduced model in DIR (`twistopt rom train`,
    /// for the problem's mesh) instead of the full model.
    #[arg(long, value_name = "PRESET|NaxNzxNt")]
    pub fidelity: Option<String>,
    /// Run only shard I of N (0 <= I < N): the designs whose grid index i has i mod N = I.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Run only these grid indices (the `index` of a sweep's rows): a comma- or
    /// whitespace-separated list, or @FILE holding one (e.g. a sweep's best designs re-run at
    /// full order into a new --out directory).
    #[arg(long, value_name = "I,J,…|@FILE")]
    pub indices: Option<String>,
    /// Override a problem value (section.key=value, as for `evaluate`; also sweep.*). Repeatable.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Worker threads (default: all cores). Each worker evaluates one design at a time.
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Print the grid and the number of designs, then stop.
    #[arg(long)]
    pub count: bool,
    /// Output directory (created if missing; re-running the same command resumes it).
    #[arg(long, value_name = "DIR", required_unless_present = "count")]
    pub out: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct SweepMergeArgs {
    /// Shard directories of one sweep (each written by `sweep --shard I/N`).
    #[arg(value_name = "SHARD_DIR", required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output directory: the merged sweep (resumable without --shard to fill missing designs).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// The problem, grid and shard of a `sweep` command line.
pub fn config(args: &SweepArgs) -> Result<SweepConfig> {
    let mut sets = args.set.clone();
    if let Some(f) = &args.fidelity {
        let f = f.trim();
        if let Some(dir) = f.strip_prefix("rom:") {
            sets.push(format!("fidelity.rom={}", toml::Value::String(dir.to_string())));
        } else if f.chars().next().is_some_and(|c| c.is_ascii_digit()) {
            sets.push(format!("fidelity.mesh={f}"));
        } else {
            sets.push(format!("fidelity.preset={f}"));
        }
    }
    let shard = match &args.shard {
        Some(s) => Shard::parse(s)?,
        None => Shard::default(),
    };
    let (problem, section) = load_problem(&args.problem, &sets)?;
    let cfg = SweepConfig::new(problem, section.as_ref(), args.grid.as_deref(), shard)?;
    match &args.indices {
        None => Ok(cfg),
        Some(spec) => cfg.with_indices(parse_indices(spec)?),
    }
}

/// `--indices`: "I,J …" or "@FILE" (the same list in a file; `#` starts a comment).
pub fn parse_indices(spec: &str) -> Result<Vec<u64>> {
    let text = match spec.trim().strip_prefix('@') {
        Some(path) => std::fs::read_to_string(path.trim()).map_err(|e| anyhow::anyhow!("--indices @{path}: cannot read the file ({e})"))?,
        None => spec.to_string(),
    };
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.split('#').next().unwrap_or("");
        for tok in line.split(|c: char| c == ',' || c.is_whitespace()).filter(|t| !t.is_empty()) {
            out.push(tok.parse::<u64>().map_err(|_| anyhow::anyhow!("--indices: '{tok}' is not a grid index (a non-negative integer)"))?);
        }
    }
    if out.is_empty() {
        anyhow::bail!("--indices '{spec}': no grid index given");
    }
    Ok(out)
}

pub fn run(args: &SweepArgs) -> Result<()> {
    let cfg = config(args)?;
    for w in &cfg.warnings {
        eprintln!("warning: {w}");
    }
    if args.count {
        println!("grid {}: {} designs ({}); shard {}/{}: {} designs", cfg.grid.name, cfg.grid.len(), cfg.grid.shape(), cfg.shard.index, cfg.shard.count, cfg.size());
        for a in &cfg.grid.axes {
            let (lo, hi) = a.values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
            println!("  {}: {} values from {lo} to {hi}", a.name, a.values.len());
        }
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let opts = RunOptions { threads: args.threads, progress: true, outputs: true };
    let rep = run_sweep(&cfg, out, &opts, |l| println!("{l}"))?;
    let rate = if rep.wall_time_s > 0.0 { rep.computed as f64 / rep.wall_time_s } else { 0.0 };
    println!(
        "computed {} designs in {:.1} s on {} threads ({rate:.3} designs/s); {} of {} in this shard done; wrote {}",
        rep.computed,
        rep.wall_time_s,
        rep.threads,
        rep.already_done + rep.computed,
        rep.n_designs_shard,
        out.display()
    );
    Ok(())
}

pub fn run_merge(args: &SweepMergeArgs) -> Result<()> {
    let (n, missing, files) = merge(&args.dirs, &args.out)?;
    println!("merged {n} rows from {} shard directories into {} ({} files)", args.dirs.len(), args.out.display(), files.len());
    if !missing.is_empty() {
        println!("shards missing: {missing:?} (run `sweep --out {}` without --shard to compute their designs)", args.out.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_indices;

    #[test]
    fn indices_lists_and_files() {
        assert_eq!(parse_indices("1646, 1508 12\n7").unwrap(), vec![1646, 1508, 12, 7]);
        assert!(parse_indices("3,-1").unwrap_err().to_string().contains("'-1'"));
        assert!(parse_indices(" , ").is_err());
        let f = std::env::temp_dir().join(format!("twistopt-indices-{}.txt", std::process::id()));
        std::fs::write(&f, "# top designs\n10 # best\n11,12\n").unwrap();
        assert_eq!(parse_indices(&format!("@{}", f.display())).unwrap(), vec![10, 11, 12]);
        let _ = std::fs::remove_file(&f);
        assert!(parse_indices("@/nonexistent/twistopt-indices").unwrap_err().to_string().contains("cannot read"));
    }
}
