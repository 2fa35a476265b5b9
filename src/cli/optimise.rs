//! `twistopt optimise`: gradient-based optimisation of a problem file's `[optimise]` section
//! (see [`crate::optimise`]); writes DIR/history.json, DIR/best.json and convergence plots.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Value};

use crate::evaluate::write_json_atomic;
use crate::optimise::{all_runs, build_problem, problem_starting_points, run_name, Objective, RunResult, FEAS_TOL};
use crate::plot::{line_plot, LinePlot, Series};
use crate::problem::Problem;

#[derive(Debug, Args)]
pub struct OptimiseArgs {
    /// Problem file with an [optimise] section (schema in problems/README.md).
    #[arg(value_name = "PROBLEM.toml")]
    pub problem: PathBuf,
    /// Override a problem value: section.key=value (repeatable; e.g. --set optimise.starts=1).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// After the runs, map the objective over (α, l) on an NAxNL grid at the best design's other
    /// variables (r, p), on the first stage's mesh, with every run's design path drawn over it
    /// (DIR/map.{png,svg}, DIR/map.json). Costs NA·NL evaluations.
    #[arg(long, value_name = "NAxNL")]
    pub map: Option<String>,
    /// Resume an interrupted optimisation in --out: the evaluations recorded in
    /// DIR/evaluations.jsonl are replayed (the optimisers are deterministic, so each run asks
    /// for the same points again) and the runs go on from where they stopped. Refused unless
    /// DIR/input.json shows the same problem, optimisers and starts.
    #[arg(long)]
    pub resume: bool,
    /// Run only start I of the problem's optimise.starts (0 <= I < starts): the same starting
    /// point and run names as in the full multi-start, so that separate processes (one per
    /// start, e.g. the tasks of a Slurm job array) together make the full run; join their
    /// directories with `twistopt optimise-merge`.
    #[arg(long, value_name = "I")]
    pub start: Option<usize>,
    /// Run only this one of the problem's optimise.optimisers (with --start: one run).
    #[arg(long, value_name = "NAME")]
    pub optimiser: Option<String>,
}

#[derive(Debug, Args)]
pub struct OptimiseMergeArgs {
    /// Output directories of one optimisation's runs (each written by `optimise`, e.g. with
    /// --start I or --optimiser NAME). They must hold the same problem, optimisers and starts,
    /// and no run twice.
    #[arg(value_name = "RUN_DIR", required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output directory: history.json with every run, best.json (the best feasible design over
    /// the runs), plots, and input.json + evaluations.jsonl, so that `optimise PROBLEM --resume
    /// --out DIR` finishes runs that are missing or were cut short.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// The runs an output directory holds: a `selection` in its input.json (written by --start and
/// --optimiser) restricts the full multi-start (every optimiser × every start).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Selection {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimiser: Option<String>,
}

impl Selection {
    /// The selected (optimiser, start) runs of the full list, in its order.
    pub fn runs(&self, optimisers: &[String], n_starts: usize) -> Vec<(String, usize)> {
        all_runs(optimisers, n_starts).into_iter().filter(|(o, s)| self.start.unwrap_or(*s) == *s && self.optimiser.as_deref().unwrap_or(o) == o).collect()
    }

    fn is_all(&self) -> bool {
        self.start.is_none() && self.optimiser.is_none()
    }

    fn describe(&self, n_starts: usize) -> String {
        match (&self.optimiser, self.start) {
            (None, None) => format!("from {n_starts} starts"),
            (None, Some(i)) => format!("from start {i} of {n_starts}"),
            (Some(_), None) => format!("only, from {n_starts} starts"),
            (Some(_), Some(i)) => format!("only, from start {i} of {n_starts}"),
        }
    }
}

pub fn run(args: &OptimiseArgs) -> Result<()> {
    let problem = Problem::load(&args.problem, &args.set)?;
    let v = problem.validate()?;
    let (op, sec) = build_problem(&problem, &v)?;
    let map = match &args.map {
        Some(m) => {
            let parts: Vec<usize> = m.split('x').map(|t| t.trim().parse::<usize>()).collect::<Result<_, _>>().map_err(|_| anyhow::anyhow!("--map '{m}' is not NAxNL (e.g. 9x6)"))?;
            match parts[..] {
                [na, nl] if (2..=200).contains(&na) && (2..=200).contains(&nl) => Some((na, nl)),
                _ => anyhow::bail!("--map '{m}': give NAxNL with 2 to 200 points each (e.g. 9x6)"),
            }
        }
        None => None,
    };
    if map.is_some() && !(op.variables.iter().any(|x| x.name == "alpha_deg") && op.variables.iter().any(|x| x.name == "l_mm")) {
        anyhow::bail!("--map needs alpha_deg and l_mm among optimise.variables");
    }
    let starts = problem_starting_points(&op, sec.starts, sec.start_from_design, sec.start_spread, sec.start_p_kpa);
    let selection = Selection { start: args.start, optimiser: args.optimiser.clone() };
    if let Some(i) = selection.start {
        if i >= starts.len() {
            anyhow::bail!("--start {i}: the problem has optimise.starts = {} (give 0 to {})", starts.len(), starts.len() - 1);
        }
    }
    if let Some(o) = &selection.optimiser {
        if !sec.optimisers.contains(o) {
            anyhow::bail!("--optimiser '{o}' is not among the problem's optimise.optimisers ({})", sec.optimisers.join(", "));
        }
    }
    let jobs = selection.runs(&sec.optimisers, starts.len());
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let t0 = std::time::Instant::now();
    println!(
        "optimise {} over {} with {} {} ({} scenes per evaluation, mesh {}, at most {} evaluations per run)",
        op.objective.name(),
        op.variables.iter().map(|v| v.name.as_str()).collect::<Vec<_>>().join(", "),
        selection.optimiser.clone().unwrap_or_else(|| sec.optimisers.join(", ")),
        selection.describe(starts.len()),
        op.scenes.len(),
        stages_string(&op),
        if op.stages.is_empty() { op.max_evaluations } else { op.stages.iter().map(|s| s.max_evaluations).sum() }
    );
    let finished: std::sync::Mutex<Vec<RunResult>> = std::sync::Mutex::new(Vec::new());
    let evals_path = args.out.join("evaluations.jsonl");
    let input_path = args.out.join("input.json");
    // the full multi-start, and which of its runs this directory holds (only written when not all)
    let mut input = json!({ "problem": problem, "optimisers": sec.optimisers, "starts": starts });
    if !selection.is_all() {
        input["selection"] = serde_json::to_value(&selection)?;
    }
    let recorded = if args.resume {
        let before: Value = std::fs::read_to_string(&input_path)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .ok_or_else(|| anyhow::anyhow!("--resume: {} is missing or unreadable (was this directory written by `twistopt optimise`?)", input_path.display()))?;
        if before != serde_json::from_str::<Value>(&input.to_string())? {
            anyhow::bail!(
                "--resume: {} records another problem, optimisers, starts or selection (--start, --optimiser) than this command; resume with the same problem file and options, or use a new --out",
                input_path.display()
            );
        }
        let rec = read_recorded(&evals_path)?;
        println!("resuming: {} recorded evaluations of {} runs are replayed", rec.values().map(|v| v.len()).sum::<usize>(), rec.len());
        rec
    } else {
        // a new optimisation starts a new log (history.json and best.json are rewritten as well)
        let _ = std::fs::remove_file(&evals_path);
        std::collections::BTreeMap::new()
    };
    crate::sweep::write_atomic(&input_path, &serde_json::to_string_pretty(&input)?)?;
    let runs = crate::optimise::run_selected(
        &op,
        &jobs,
        &starts,
        &recorded,
        |r| {
            if let Ok(mut f) = finished.lock() {
                f.push(r.clone());
                if let Err(e) = write_results(&args.out, &op, &v, &f, t0.elapsed().as_secs_f64(), None) {
                    eprintln!("warning: could not write intermediate results: {e:#}");
                }
            }
            let b = r.best.map(|i| &r.evaluations[i]);
            println!(
                "  {} start {}: {} after {} evaluations in {:.1} s; best {}",
                r.optimiser,
                r.start,
                r.status,
                r.evaluations.len(),
                r.wall_time_s,
                b.map(|e| format!("{:.4} at {}", e.objective, fmt_design(&e.design))).unwrap_or_else(|| "none feasible".into())
            );
        },
        |run, k, e| {
            eprintln!(
                "  [{run}] evaluation {k}: objective {:.4}{} at {} ({} Newton iterations, {:.1} s{})",
                e.objective,
                if e.feasible { "" } else { " (infeasible)" },
                fmt_design(&e.design),
                e.newton_iterations,
                e.time_s,
                if e.status == "ok" { String::new() } else { format!(", {}", e.status) }
            );
            // every evaluation also goes to evaluations.jsonl at once, so an interrupted optimisation
            // keeps the evaluations of its unfinished runs (history.json holds finished runs)
            let mut j = serde_json::to_value(e).unwrap_or(Value::Null);
            j["run"] = json!(run);
            j["evaluation"] = json!(k);
            if let Err(err) = crate::evaluate::append_json_line(&evals_path, &j) {
                eprintln!("warning: could not append to {}: {err:#}", evals_path.display());
            }
        },
    );
    let unit = op.objective.reference().1;
    let best = write_results(&args.out, &op, &v, &runs, t0.elapsed().as_secs_f64(), None)?;
    println!("best: {}", serde_json::to_string(&best["summary"]).unwrap_or_default());
    plots(&args.out, &runs, unit)?;
    if let Some((na, nl)) = map {
        objective_map(&args.out, &op, &runs, na, nl)?;
    }
    println!("wrote history.json, best.json and plots to {} in {:.1} s", args.out.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

/// DIR/input.json of an `optimise` output directory: the full multi-start and which of its
/// runs the directory holds.
#[derive(Debug, serde::Deserialize)]
struct Input {
    problem: Value,
    optimisers: Vec<String>,
    starts: Vec<Vec<f64>>,
    #[serde(default)]
    selection: Option<Selection>,
}

impl Input {
    fn read(dir: &Path) -> Result<Option<(Value, Input)>> {
        let p = dir.join("input.json");
        let text = match std::fs::read_to_string(&p) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", p.display())),
        };
        let raw: Value = serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: not JSON ({e})", p.display()))?;
        let input: Input = serde_json::from_value(raw.clone()).map_err(|e| anyhow::anyhow!("{}: not an optimise input record ({e})", p.display()))?;
        Ok(Some((raw, input)))
    }

    /// The full multi-start this directory belongs to (input.json without the selection).
    fn full(raw: &Value) -> Value {
        let mut v = raw.clone();
        if let Some(o) = v.as_object_mut() {
            o.remove("selection");
        }
        v
    }

    fn runs(&self) -> Vec<(String, usize)> {
        self.selection.clone().unwrap_or_default().runs(&self.optimisers, self.starts.len())
    }
}

/// A finished run as history.json records it.
#[derive(serde::Deserialize)]
struct HistoryRun {
    optimiser: String,
    start: usize,
    x0: Vec<f64>,
    status: String,
    wall_time_s: f64,
    best_evaluation: Option<usize>,
    kkt: Option<f64>,
    multipliers: Option<Vec<Option<f64>>>,
    evaluations: Vec<crate::optimise::Evaluation>,
}

/// The finished runs of DIR/history.json and its wall time (none when the file is missing:
/// no run finished).
fn read_history(dir: &Path) -> Result<(Vec<RunResult>, f64)> {
    let p = dir.join("history.json");
    let text = match std::fs::read_to_string(&p) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((Vec::new(), 0.0)),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", p.display())),
    };
    let h: Value = serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: not JSON ({e})", p.display()))?;
    let runs = h.get("runs").and_then(|r| r.as_array()).ok_or_else(|| anyhow::anyhow!("{}: no runs (not an optimise history)", p.display()))?;
    let mut out = Vec::new();
    for (k, r) in runs.iter().enumerate() {
        let r: HistoryRun = serde_json::from_value(r.clone()).map_err(|e| anyhow::anyhow!("{}: run {k} is unreadable ({e})", p.display()))?;
        let best = match r.best_evaluation {
            Some(b) if b >= 1 && b <= r.evaluations.len() => Some(b - 1),
            Some(b) => anyhow::bail!("{}: run '{}' has best_evaluation {b} of {} evaluations", p.display(), run_name(&r.optimiser, r.start), r.evaluations.len()),
            None => None,
        };
        out.push(RunResult {
            optimiser: r.optimiser,
            start: r.start,
            x0: r.x0,
            status: r.status,
            evaluations: r.evaluations,
            best,
            kkt: r.kkt,
            multipliers: r.multipliers.map(|m| m.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect()),
            wall_time_s: r.wall_time_s,
        });
    }
    Ok((out, h.get("wall_time_s").and_then(|t| t.as_f64()).unwrap_or(0.0)))
}

/// The lines of DIR/evaluations.jsonl by run name (complete lines only; a torn last line is
/// left out, as `--resume` leaves it out).
fn evaluation_lines(dir: &Path) -> Result<std::collections::BTreeMap<String, Vec<String>>> {
    let p = dir.join("evaluations.jsonl");
    let mut out: std::collections::BTreeMap<String, Vec<String>> = Default::default();
    let text = match std::fs::read_to_string(&p) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", p.display())),
    };
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        if let Some(run) = serde_json::from_str::<Value>(line).ok().and_then(|j| j.get("run").and_then(|r| r.as_str()).map(String::from)) {
            out.entry(run).or_default().push(line.to_string());
        }
    }
    Ok(out)
}

/// What `optimise-merge` did.
pub struct MergeReport {
    /// finished runs in the merged history
    pub finished: usize,
    /// runs of the multi-start
    pub total: usize,
    /// runs with evaluations but not finished (resumable)
    pub unfinished: Vec<String>,
    /// runs no directory has anything of
    pub missing: Vec<String>,
    pub best: Value,
}

/// Join the output directories of one optimisation's runs into `out` (see [`OptimiseMergeArgs`]).
/// Runs are identified by name ("<optimiser> start <i>"); a run is taken from the directory
/// whose selection holds it, and `out`'s own records (an earlier merge, a resume) fill in runs
/// that no directory has anything of.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<MergeReport> {
    use std::collections::BTreeMap;
    if dirs.is_empty() {
        anyhow::bail!("optimise-merge: give at least one run directory");
    }
    let same = |a: &Path, b: &Path| matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y);
    if let Some(d) = dirs.iter().find(|d| same(d, out)) {
        anyhow::bail!("--out {} is one of the run directories; merge into a new directory", d.display());
    }
    let mut first: Option<(PathBuf, Value, Input)> = None;
    let mut owner: BTreeMap<String, PathBuf> = BTreeMap::new();
    let mut finished: BTreeMap<String, RunResult> = BTreeMap::new();
    let mut lines: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut wall = 0.0;
    for d in dirs {
        let (raw, input) = Input::read(d)?.ok_or_else(|| anyhow::anyhow!("{}: no input.json (not a directory written by `twistopt optimise`)", d.display()))?;
        if let Some((d0, raw0, _)) = &first {
            let (a, b) = (Input::full(raw0), Input::full(&raw));
            if a != b {
                let what: Vec<&str> = ["problem", "optimisers", "starts"].into_iter().filter(|k| a.get(k) != b.get(k)).collect();
                anyhow::bail!("{} holds another optimisation than {} ({} differ)", d.display(), d0.display(), what.join(", "));
            }
        }
        let covered = input.runs();
        for (o, s) in &covered {
            let name = run_name(o, *s);
            if let Some(other) = owner.insert(name.clone(), d.clone()) {
                anyhow::bail!("run '{name}' is in both {} and {} (give each run once)", other.display(), d.display());
            }
        }
        let names: std::collections::BTreeSet<String> = covered.iter().map(|(o, s)| run_name(o, *s)).collect();
        let (runs, w) = read_history(d)?;
        wall += w;
        for r in runs {
            let name = run_name(&r.optimiser, r.start);
            if !names.contains(&name) {
                anyhow::bail!("{}: history.json has run '{name}', which its input.json does not select", d.display());
            }
            finished.insert(name, r);
        }
        for (name, l) in evaluation_lines(d)? {
            if names.contains(&name) {
                lines.insert(name, l);
            }
        }
        if first.is_none() {
            first = Some((d.clone(), raw, input));
        }
    }
    let (_, raw0, input) = first.expect("at least one directory");
    let full_input = Input::full(&raw0);
    // what out already holds fills in runs that no directory has anything of
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    if let Some((raw, _)) = Input::read(out)? {
        if Input::full(&raw) != full_input {
            anyhow::bail!("{} holds another optimisation than {} (use a new --out)", out.display(), dirs[0].display());
        }
        let has = |name: &String, f: &BTreeMap<String, RunResult>, l: &BTreeMap<String, Vec<String>>| f.contains_key(name) || l.contains_key(name);
        let (old_runs, _) = read_history(out)?;
        let old_lines = evaluation_lines(out)?;
        let take: Vec<String> = old_runs.iter().map(|r| run_name(&r.optimiser, r.start)).chain(old_lines.keys().cloned()).filter(|n| !has(n, &finished, &lines)).collect();
        for r in old_runs {
            let name = run_name(&r.optimiser, r.start);
            if take.contains(&name) {
                finished.insert(name, r);
            }
        }
        for (name, l) in old_lines {
            if take.contains(&name) {
                lines.insert(name, l);
            }
        }
    }
    let problem: Problem = serde_json::from_value(input.problem.clone()).map_err(|e| anyhow::anyhow!("{}/input.json: cannot rebuild the problem ({e})", dirs[0].display()))?;
    let v = problem.validate()?;
    let (op, _) = build_problem(&problem, &v)?;
    let all = all_runs(&input.optimisers, input.starts.len());
    let runs: Vec<RunResult> = all.iter().filter_map(|(o, s)| finished.get(&run_name(o, *s)).cloned()).collect();
    let unfinished: Vec<String> = all.iter().map(|(o, s)| run_name(o, *s)).filter(|n| !finished.contains_key(n) && lines.contains_key(n)).collect();
    let missing: Vec<String> = all.iter().map(|(o, s)| run_name(o, *s)).filter(|n| !finished.contains_key(n) && !lines.contains_key(n)).collect();
    // input.json and evaluations.jsonl as a run of the whole multi-start would have them, so
    // that `optimise --resume --out OUT` replays the finished runs and completes the others
    crate::sweep::write_atomic(&out.join("input.json"), &serde_json::to_string_pretty(&full_input)?)?;
    let mut text = String::new();
    for (o, s) in &all {
        for l in lines.get(&run_name(o, *s)).into_iter().flatten() {
            text.push_str(l);
            text.push('\n');
        }
    }
    crate::sweep::write_atomic(&out.join("evaluations.jsonl"), &text)?;
    let best = write_results(out, &op, &v, &runs, wall, Some(dirs))?;
    plots(out, &runs, op.objective.reference().1)?;
    Ok(MergeReport { finished: runs.len(), total: all.len(), unfinished, missing, best })
}

pub fn run_merge(args: &OptimiseMergeArgs) -> Result<()> {
    let r = merge(&args.dirs, &args.out)?;
    println!("merged {} of {} runs from {} directories into {} (history.json, best.json, plots)", r.finished, r.total, args.dirs.len(), args.out.display());
    println!("best: {}", serde_json::to_string(&r.best["summary"]).unwrap_or_default());
    if !r.unfinished.is_empty() || !r.missing.is_empty() {
        println!(
            "not finished: {:?}; no record: {:?} (run `optimise PROBLEM --resume --out {}` with the same problem and --set options to complete them)",
            r.unfinished,
            r.missing,
            args.out.display()
        );
    }
    Ok(())
}

/// The evaluations of DIR/evaluations.jsonl by run, in order (a torn last line is skipped).
/// Each line carries its run's evaluation number k (replayed evaluations count): a later line
/// with number k supersedes the record from k on. A resumed run that went elsewhere than its
/// record (another binary's numerics, an older record without the scaled gradients) appends
/// from where it diverged, and the next resume replays what that run did, not the stale tail.
fn read_recorded(path: &std::path::Path) -> Result<std::collections::BTreeMap<String, Vec<crate::optimise::Evaluation>>> {
    let mut out: std::collections::BTreeMap<String, Vec<crate::optimise::Evaluation>> = Default::default();
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let Ok(j) = serde_json::from_str::<Value>(line) else { continue };
        let Some(run) = j.get("run").and_then(|r| r.as_str()).map(String::from) else { continue };
        let k = j.get("evaluation").and_then(|k| k.as_u64()).map(|k| k as usize);
        if let Ok(e) = serde_json::from_value::<crate::optimise::Evaluation>(j) {
            let v = out.entry(run).or_default();
            match k {
                Some(k) if k >= 1 => {
                    v.truncate(k - 1);
                    // a gap (a lost line) ends what can be replayed of this run
                    if v.len() == k - 1 {
                        v.push(e);
                    }
                }
                _ => v.push(e),
            }
        }
    }
    Ok(out)
}

/// Write history.json and best.json for the runs finished so far (atomically: an interrupted
/// optimisation keeps the runs it completed). Returns best.json's content. `merged_from`: the
/// run directories an `optimise-merge` joined (recorded in both files).
fn write_results(out: &std::path::Path, op: &crate::optimise::OptProblem, v: &crate::problem::Validated, runs: &[RunResult], wall_time_s: f64, merged_from: Option<&[PathBuf]>) -> Result<Value> {
    let unit = op.objective.reference().1;
    // history.json
    let hist_runs: Vec<Value> = runs
        .iter()
        .map(|r| {
            let evs: Vec<Value> = r
                .evaluations
                .iter()
                .enumerate()
                .map(|(k, e)| {
                    let mut j = serde_json::to_value(e).unwrap_or(Value::Null);
                    j["evaluation"] = json!(k + 1);
                    j["cumulative_evaluations"] = json!(k + 1);
                    j["best_so_far"] = json!(r.evaluations[..=k].iter().filter(|e| e.feasible).map(|e| e.objective).fold(f64::NAN, f64::max));
                    j
                })
                .collect();
            json!({
                "optimiser": r.optimiser, "start": r.start, "x0": r.x0, "status": r.status,
                "wall_time_s": r.wall_time_s, "best_evaluation": r.best.map(|b| b + 1),
                "kkt": r.kkt, "multipliers": r.multipliers, "evaluations": evs,
            })
        })
        .collect();
    let mut history = json!({
        "objective": op.objective.name(), "objective_unit": unit,
        "variables": op.variables, "fixed": op.fixed, "constraints": "radius:<scene> = (KS max radius − limit)/(limit − 20 mm) <= 0; stability = (p − (1 − margin)·p_limit)/(p range) <= 0", "stability_margin": crate::optimise::STABILITY_MARGIN,
        "ballooning_limit_mm": op.ballooning_limit_mm, "ks_rho_per_mm": op.ks_rho,
        "mesh": if op.stages.is_empty() { v.mesh.size_string() } else { op.stages.last().map(|s| s.mesh.size_string()).unwrap_or_default() },
        "stages": op.stages.iter().map(|s| json!({"label": s.label, "mesh": s.mesh.size_string(), "max_evaluations": s.max_evaluations, "xtol_rel": s.xtol_rel, "ftol_rel": s.ftol_rel})).collect::<Vec<_>>(), "scenes": op.scenes.iter().map(|k| k.name()).collect::<Vec<_>>(),
        "runs": hist_runs, "wall_time_s": wall_time_s,
    });
    let mut best = best_json(&op.objective, runs, &op.fixed);
    if let Some(dirs) = merged_from {
        let dirs: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
        history["merged_from"] = json!(dirs);
        best["merged_from"] = json!(dirs);
    }
    write_json_atomic(&out.join("history.json"), &history)?;
    write_json_atomic(&out.join("best.json"), &best)?;
    Ok(best)
}

/// The objective over (α, l) at the best design's other variables, with the runs' paths.
fn objective_map(out: &std::path::Path, op: &crate::optimise::OptProblem, runs: &[RunResult], na: usize, nl: usize) -> Result<()> {
    use rayon::prelude::*;
    let Some(best) = runs.iter().filter_map(|r| r.best.map(|b| &r.evaluations[b])).max_by(|a, b| a.objective.total_cmp(&b.objective)) else {
        println!("map: no feasible design, no map");
        return Ok(());
    };
    let (mesh_label, mp) = op.stage_problems().into_iter().next().ok_or_else(|| anyhow::anyhow!("no stage"))?;
    let ia = op.variables.iter().position(|x| x.name == "alpha_deg").unwrap_or(0);
    let il = op.variables.iter().position(|x| x.name == "l_mm").unwrap_or(0);
    let lin = |i: usize, n: usize| (0..n).map(|k| k as f64 / (n - 1) as f64).map(|t| (t, op.variables[i].lower + t * (op.variables[i].upper - op.variables[i].lower))).collect::<Vec<_>>();
    let (xa, xl) = (lin(ia, na), lin(il, nl));
    let t0 = std::time::Instant::now();
    println!("map: {na} x {nl} designs over (α, l) on {} at {}", mp.opts.mesh.size_string(), fmt_design(&best.design));
    // one row of α per l (evaluate warm-starts along the row only when optimise::WARM_STARTS is on)
    let rows: Vec<Vec<(Option<f64>, bool, String)>> = xl
        .par_iter()
        .map(|(tl, _)| {
            let mut warm = None;
            xa.iter()
                .map(|(ta, _)| {
                    let mut x = best.x.clone();
                    x[ia] = *ta;
                    x[il] = *tl;
                    let e = mp.evaluate(&x, &mut warm, None);
                    let v = (e.status == "ok" && e.objective.is_finite()).then_some(e.objective);
                    (v, e.feasible, e.status.clone())
                })
                .collect()
        })
        .collect();
    let values: Vec<Vec<Option<f64>>> = rows.iter().map(|r| r.iter().map(|c| c.0.filter(|_| c.1)).collect()).collect();
    let alphas: Vec<f64> = xa.iter().map(|p| p.1).collect();
    let ls: Vec<f64> = xl.iter().map(|p| p.1).collect();
    let others: Vec<String> = best.design.iter().filter(|(k, _)| k.as_str() != "alpha_deg" && k.as_str() != "l_mm").map(|(k, v)| format!("{k} = {v:.3}")).collect();
    let paths: Vec<Series> = runs
        .iter()
        .map(|r| Series::new(format!("{} start {}", r.optimiser, r.start), r.evaluations.iter().filter_map(|e| Some((*e.design.get("alpha_deg")?, *e.design.get("l_mm")?))).collect()))
        .collect();
    let unit = op.objective.reference().1;
    let plot = crate::plot::MapPlot {
        title: format!("{} over (α, l) at {}", op.objective.name(), others.join(", ")),
        x_label: "pre-twist α (°)".into(),
        y_label: "waist radius l (mm)".into(),
        value_label: unit.to_string(),
        xs: alphas.clone(),
        ys: ls.clone(),
        values: values.clone(),
        paths,
        note: format!("map on {} ({mesh_label}); grey: infeasible or failed; paths: every evaluation of each run (all stages, projected onto (α, l)); ring: last", mp.opts.mesh.size_string()),
    };
    crate::plot::map_plot(&out.join("map"), &plot)?;
    let j = json!({
        "objective": op.objective.name(), "unit": unit, "mesh": mp.opts.mesh.size_string(), "at": best.design,
        "alpha_deg": alphas, "l_mm": ls,
        "value": rows.iter().map(|r| r.iter().map(|c| c.0).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "feasible": rows.iter().map(|r| r.iter().map(|c| c.1).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "status": rows.iter().map(|r| r.iter().map(|c| c.2.clone()).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "wall_time_s": t0.elapsed().as_secs_f64(),
    });
    write_json_atomic(&out.join("map.json"), &j)?;
    println!("map: wrote map.png, map.svg, map.json in {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}

/// The mesh, or the fidelity stages with their budgets.
fn stages_string(op: &crate::optimise::OptProblem) -> String {
    if op.stages.is_empty() {
        op.opts.mesh.size_string()
    } else {
        op.stages.iter().map(|s| format!("{} ({}, ≤ {} evaluations)", s.mesh.size_string(), s.label, s.max_evaluations)).collect::<Vec<_>>().join(" → ")
    }
}

fn fmt_design(d: &std::collections::BTreeMap<String, f64>) -> String {
    d.iter().map(|(k, v)| format!("{k} = {v:.4}")).collect::<Vec<_>>().join(", ")
}

/// Evaluations per fidelity stage of a run.
fn by_stage(r: &RunResult) -> Vec<usize> {
    let n = r.evaluations.iter().map(|e| e.stage + 1).max().unwrap_or(0);
    (0..n).map(|k| r.evaluations.iter().filter(|e| e.stage == k).count()).collect()
}

fn best_json(obj: &Objective, runs: &[RunResult], fixed: &std::collections::BTreeMap<String, f64>) -> Value {
    let total: usize = runs.iter().map(|r| r.evaluations.len()).sum();
    let best = runs.iter().filter_map(|r| r.best.map(|b| (r, &r.evaluations[b]))).max_by(|a, b| a.1.objective.total_cmp(&b.1.objective));
    let per_run: Vec<Value> = runs
        .iter()
        .map(|r| {
            let b = r.best.map(|i| &r.evaluations[i]);
            json!({
                "optimiser": r.optimiser, "start": r.start, "status": r.status,
                "objective": b.map(|e| e.objective), "design": b.map(|e| &e.design),
                "evaluations": r.evaluations.len(), "evaluations_to_best": r.best.map(|i| i + 1),
                "evaluations_by_stage": by_stage(r), "mesh": b.map(|e| &e.mesh),
                "kkt": r.kkt, "wall_time_s": r.wall_time_s,
            })
        })
        .collect();
    let objs: Vec<f64> = runs.iter().filter_map(|r| r.best.map(|i| r.evaluations[i].objective)).collect();
    let spread = match (objs.iter().copied().reduce(f64::max), objs.iter().copied().reduce(f64::min)) {
        (Some(a), Some(b)) if a != 0.0 => Some((a - b) / a.abs()),
        _ => None,
    };
    let mut out = match best {
        Some((r, e)) => {
            let g = |k: &str| e.design.get(k).copied().or_else(|| fixed.get(k).copied());
            // every design value (freeform modes included) and the fixed ones
            let mut design = fixed.clone();
            design.extend(e.design.iter().map(|(k, v)| (k.clone(), *v)));
            json!({
                "design": design,
                "r_mm": g("r_mm"), "l_mm": g("l_mm"), "alpha_deg": g("alpha_deg"), "p_kPa": g("p_kPa"),
                "theta_deg": e.theta_deg, "tau_Nm": e.tau_nm,
                "omega_J_m3": if *obj == Objective::EnergyDensity { Some(e.objective) } else { e.theta_deg.zip(e.tau_nm).map(|(t, q)| crate::scene::energy_density(t, q)) },
                "objective": e.objective, "max_radius_mm": e.max_radius_mm, "constraints": e.constraints,
                "evaluations": total, "status": if r.kkt.is_some_and(|k| k < 1e-2) { "optimal" } else { "feasible" },
                "optimiser": r.optimiser, "start": r.start, "kkt": r.kkt, "mesh": e.mesh,
                "constraint_tolerance": FEAS_TOL,
                "vacuum": e.vacuum,
            })
        }
        None => json!({
            "r_mm": null, "l_mm": null, "alpha_deg": null, "p_kPa": null, "theta_deg": null, "tau_Nm": null,
            "omega_J_m3": null, "max_radius_mm": null, "evaluations": total, "status": "infeasible",
        }),
    };
    out["runs"] = json!(per_run);
    out["spread_of_best_objective"] = json!(spread);
    out["summary"] = json!({"objective": out["objective"], "design": [out["r_mm"], out["l_mm"], out["alpha_deg"], out["p_kPa"]], "evaluations": total, "spread": spread});
    out
}

fn plots(dir: &std::path::Path, runs: &[RunResult], unit: &str) -> Result<()> {
    let mut po = LinePlot::new("Objective per evaluation", "evaluation", format!("objective ({unit})"));
    let mut pc = LinePlot::new("Ballooning constraint per evaluation", "evaluation", "max over scenes of (KS radius − limit)/(limit − R)");
    for r in runs {
        let name = format!("{} start {}", r.optimiser, r.start);
        po.series.push(Series::new(name.clone(), r.evaluations.iter().enumerate().filter(|(_, e)| e.objective.is_finite()).map(|(k, e)| ((k + 1) as f64, e.objective)).collect()));
        pc.series.push(Series::new(
            name,
            r.evaluations
                .iter()
                .enumerate()
                .map(|(k, e)| ((k + 1) as f64, e.constraints.iter().filter(|(n, _)| n.starts_with("radius")).map(|(_, v)| *v).fold(f64::NEG_INFINITY, f64::max)))
                .filter(|(_, v)| v.is_finite())
                .collect(),
        ));
    }
    line_plot(&dir.join("objective"), &po)?;
    line_plot(&dir.join("constraint"), &pc)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    fn line(run: &str, k: usize, x: f64) -> String {
        json!({"run": run, "evaluation": k, "x": [x], "design": {"p_kPa": x}, "objective": x, "gradient": {}, "constraints": {},
               "feasible": true, "theta_deg": null, "tau_Nm": null, "max_radius_mm": 20.0, "p_limit_kPa": null, "scenes": {},
               "status": "ok", "newton_iterations": 1, "adjoint_solves": 0, "time_s": 0.0, "warm_started": false,
               "f_scaled": -x, "df_scaled": [1.0]})
        .to_string()
    }

    #[test]
    fn a_diverged_resume_supersedes_the_stale_tail_of_its_record() {
        let dir = std::env::temp_dir().join(format!("twistopt-recorded-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("evaluations.jsonl");
        // run a: 3 recorded; a resume replayed 1 and went elsewhere from evaluation 2 (2 new lines);
        // run b: 2 recorded, then a torn line; run c: a lost line 2 (gap) ends its replay
        let text = [line("a", 1, 0.1), line("a", 2, 0.2), line("b", 1, 0.5), line("a", 3, 0.3), line("b", 2, 0.6), line("a", 2, 0.25), line("a", 3, 0.35), line("c", 1, 0.7), line("c", 3, 0.9)]
            .join("\n")
            + "\n{\"run\": \"b\", \"evalu";
        std::fs::write(&path, text).unwrap();
        let rec = super::read_recorded(&path).unwrap();
        let xs = |r: &str| rec[r].iter().map(|e| e.x[0]).collect::<Vec<_>>();
        assert_eq!(xs("a"), vec![0.1, 0.25, 0.35]);
        assert_eq!(xs("b"), vec![0.5, 0.6]);
        assert_eq!(xs("c"), vec![0.7]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
