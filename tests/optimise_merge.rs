//! Multi-start optimisation split over processes: `optimise --start I [--optimiser NAME]` runs
//! part of the multi-start, `optimise-merge` joins the parts; the merged history.json and
//! best.json equal a single-process multi-start (all but wall times), a partial merge resumes to
//! the full one, and bad input is a one-line error.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twistopt"))
}

fn dir(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The optimisers of this build (scripts/test.sh also builds without the `nlopt` feature).
fn optimisers() -> Vec<&'static str> {
    if cfg!(feature = "nlopt") {
        vec!["mma", "sqp"]
    } else {
        vec!["sqp"]
    }
}

/// The blocking torque over α and l at 20 kPa on a very coarse mesh, 3 starts (a few seconds).
fn problem_args() -> Vec<String> {
    let opts = optimisers().iter().map(|o| format!("\"{o}\"")).collect::<Vec<_>>().join(", ");
    [
        "problems/max-torque.toml".to_string(),
        "--set".into(),
        "fidelity.mesh=12x4x1".into(),
        "--set".into(),
        "load.p_max_kPa=20".into(),
        "--set".into(),
        "optimise.variables=[\"alpha_deg\", \"l_mm\"]".into(),
        "--set".into(),
        format!("optimise.optimisers=[{opts}]"),
        "--set".into(),
        "optimise.starts=3".into(),
        "--set".into(),
        "optimise.max_evaluations=15".into(),
    ]
    .into()
}

fn optimise(out: &Path, extra: &[&str]) -> Output {
    let o = bin().arg("optimise").args(problem_args()).args(extra).arg("--out").arg(out).output().unwrap();
    assert!(o.status.success(), "optimise {extra:?} failed: {}", String::from_utf8_lossy(&o.stderr));
    o
}

fn merge(dirs: &[&Path], out: &Path) -> Output {
    bin().arg("optimise-merge").args(dirs).arg("--out").arg(out).output().unwrap()
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// A JSON value without wall times and the merge's provenance.
fn strip(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(m.iter().filter(|(k, _)| !["wall_time_s", "time_s", "merged_from"].contains(&k.as_str())).map(|(k, x)| (k.clone(), strip(x))).collect()),
        Value::Array(a) => Value::Array(a.iter().map(strip).collect()),
        x => x.clone(),
    }
}

fn assert_same_optimisation(a: &Path, b: &Path) {
    for f in ["history.json", "best.json"] {
        let (x, y) = (strip(&json(&a.join(f))), strip(&json(&b.join(f))));
        assert!(x == y, "{f} of {} differs from {}", b.display(), a.display());
    }
}

fn one_line_error(o: &Output, needle: &str) {
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains(needle) && e.trim().lines().count() == 1 && !e.contains("panicked"), "expected one line with '{needle}': {e}");
}

#[test]
fn starts_as_separate_processes_merge_to_the_multi_start() {
    let d = dir("optimise-merge");
    let opts = optimisers();
    let n_runs = 3 * opts.len();

    // the single-process multi-start
    let full = d.join("full");
    optimise(&full, &[]);
    let hist = json(&full.join("history.json"));
    assert_eq!(hist["runs"].as_array().unwrap().len(), n_runs);

    // start 0 (every optimiser), start 1 one optimiser per process, start 2 (every optimiser)
    let s0 = d.join("s0");
    let o = optimise(&s0, &["--start", "0"]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("from start 0 of 3"));
    let s0_hist = json(&s0.join("history.json"));
    let runs: Vec<(String, u64)> = s0_hist["runs"].as_array().unwrap().iter().map(|r| (r["optimiser"].as_str().unwrap().to_string(), r["start"].as_u64().unwrap())).collect();
    assert_eq!(runs, opts.iter().map(|o| (o.to_string(), 0)).collect::<Vec<_>>());
    assert_eq!(json(&s0.join("input.json"))["selection"], serde_json::json!({"start": 0}));
    let mut parts = vec![s0.clone()];
    for o in &opts {
        let p = d.join(format!("s1-{o}"));
        optimise(&p, &["--start", "1", "--optimiser", o]);
        assert_eq!(json(&p.join("history.json"))["runs"].as_array().unwrap().len(), 1);
        parts.push(p);
    }
    let s2 = d.join("s2");
    optimise(&s2, &["--start", "2"]);
    parts.push(s2.clone());

    let merged = d.join("merged");
    let refs: Vec<&Path> = parts.iter().map(|p| p.as_path()).collect();
    let o = merge(&refs, &merged);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains(&format!("merged {n_runs} of {n_runs} runs")) && !out.contains("not finished"), "{out}");
    assert_same_optimisation(&full, &merged);
    let best = json(&merged.join("best.json"));
    assert_eq!(best["merged_from"].as_array().unwrap().len(), parts.len());
    assert_eq!(best["runs"].as_array().unwrap().len(), n_runs);
    // every run's evaluations are kept, one line each
    let lines = std::fs::read_to_string(merged.join("evaluations.jsonl")).unwrap();
    assert_eq!(lines.lines().count() as u64, best["evaluations"].as_u64().unwrap());
    for f in ["objective.png", "constraint.svg", "input.json"] {
        assert!(merged.join(f).exists(), "{f}");
    }
    // merging again into the same directory gives the same result
    let o = merge(&refs, &merged);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_optimisation(&full, &merged);

    // a partial merge reports the missing runs; resuming it computes only those
    let partial = d.join("partial");
    let o = merge(&[&s0, &s2], &partial);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    let missing = opts.iter().map(|o| format!("\"{o} start 1\"")).collect::<Vec<_>>().join(", ");
    assert!(out.contains(&format!("merged {} of {n_runs} runs", 2 * opts.len())) && out.contains(&format!("no record: [{missing}]")), "{out}");
    let o = optimise(&partial, &["--resume"]);
    let err = String::from_utf8_lossy(&o.stderr);
    let new: Vec<&str> = err.lines().filter(|l| l.contains("] evaluation ")).collect();
    assert!(!new.is_empty() && new.iter().all(|l| l.contains(" start 1] ")), "only start 1 is computed: {new:?}");
    assert_same_optimisation(&full, &partial);

    // bad input: one line each, nothing written
    let o = merge(&[&s0, &s0], &d.join("x"));
    one_line_error(&o, "is in both");
    let o = merge(&[&s0, &full], &d.join("x"));
    one_line_error(&o, &format!("run '{} start 0' is in both", opts[0]));
    let o = merge(&[&s0, &s2], &s0);
    one_line_error(&o, "is one of the run directories");
    let o = merge(&[&d.join("nothing")], &d.join("x"));
    one_line_error(&o, "no input.json");
    let other = d.join("other");
    optimise(&other, &["--start", "1", "--set", "optimise.max_evaluations=14"]);
    let o = merge(&[&s0, &other], &d.join("x"));
    one_line_error(&o, "holds another optimisation");
    assert!(!d.join("x").join("history.json").exists());
    for (args, needle) in
        [(vec!["--start", "3"], "--start 3: the problem has optimise.starts = 3"), (vec!["--optimiser", "cobyla"], "--optimiser 'cobyla' is not among"), (vec!["--start", "1", "--resume"], "--resume")]
    {
        let o = bin().arg("optimise").args(problem_args()).args(&args).arg("--out").arg(&s0).output().unwrap();
        one_line_error(&o, needle);
    }
    let _ = std::fs::remove_dir_all(&d);
}
