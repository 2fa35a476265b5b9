//! The sharded sweep and the multi-start optimisation on a real workload manager, end to end:
//! runs scripts/cluster-test.sh (a single-node Slurm started on this machine, the project's
//! job-array scripts, a task requeued mid-way in each, the merges as dependent jobs, compared
//! with single-process runs; the instance is stopped at the end), then checks its outputs again
//! here. Needs root and apt-get (the script installs munge and Slurm when missing), like CI.
//! Set TWISTOPT_SKIP_CLUSTER=1 to skip it on a machine without them.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Rows of a results.jsonl by id without the wall times; panics on a repeated id.
fn rows(path: &Path) -> BTreeMap<String, Value> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut m = BTreeMap::new();
    for line in text.lines() {
        let mut v: Value = serde_json::from_str(line).unwrap();
        let o = v.as_object_mut().unwrap();
        o.remove("wall_time_s");
        for s in o["scenes"].as_object_mut().unwrap().values_mut() {
            s.as_object_mut().unwrap().remove("wall_time_s");
        }
        let id = o["id"].as_str().unwrap().to_string();
        assert!(m.insert(id.clone(), v).is_none(), "{id} appears twice in {}", path.display());
    }
    m
}

fn strip(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(m.iter().filter(|(k, _)| !["wall_time_s", "time_s", "merged_from"].contains(&k.as_str())).map(|(k, x)| (k.clone(), strip(x))).collect()),
        Value::Array(a) => Value::Array(a.iter().map(strip).collect()),
        x => x.clone(),
    }
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

#[test]
fn sharded_sweep_and_multi_start_on_slurm_with_a_requeued_task() {
    if std::env::var_os("TWISTOPT_SKIP_CLUSTER").is_some() {
        eprintln!("TWISTOPT_SKIP_CLUSTER is set: the cluster test is skipped");
        return;
    }
    let work = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cluster");
    let _ = std::fs::remove_dir_all(&work);
    let t0 = std::time::Instant::now();
    let o = Command::new("bash").arg("scripts/cluster-test.sh").env("TWISTOPT", env!("CARGO_BIN_EXE_twistopt")).env("CLUSTER_TEST_DIR", &work).stdin(std::process::Stdio::null()).output().unwrap();
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    println!("{out}\n{err}");
    assert!(o.status.success(), "scripts/cluster-test.sh failed ({}; run as root with apt-get, or set TWISTOPT_SKIP_CLUSTER=1):\n{out}\n{err}", o.status);
    assert!(out.lines().any(|l| l.starts_with("cluster-test [") && l.ends_with("]: passed")), "{out}");
    println!("cluster test: {:.0} s", t0.elapsed().as_secs_f64());

    // the sweep: shards hold their designs once each, their union and the merge equal the single run
    let sw = work.join("sweep");
    let single = rows(&sw.join("single/results.jsonl"));
    let merged = rows(&sw.join("merged/results.jsonl"));
    assert!(single.len() >= 8, "{} reference rows", single.len());
    assert_eq!(merged, single, "merged rows differ from the single-process sweep");
    let mut union = BTreeMap::new();
    let shards: Vec<PathBuf> = (0..4).map(|i| sw.join(format!("out/shard-{i:04}"))).collect();
    for (i, d) in shards.iter().enumerate() {
        let r = rows(&d.join("results.jsonl"));
        let lines = std::fs::read_to_string(d.join("results.jsonl")).unwrap().lines().count();
        assert_eq!(lines, r.len(), "{}: a design was written twice", d.display());
        assert!(r.values().all(|x| x["index"].as_u64().unwrap() % 4 == i as u64));
        union.extend(r);
    }
    assert_eq!(union, single);
    // exactly one shard ran twice, and its second run resumed with some rows done and some to do
    let reruns: Vec<(usize, Vec<String>)> = (0..4)
        .map(|i| {
            let log = std::fs::read_to_string(sw.join(format!("logs/shard-{i}.out"))).unwrap();
            (i, log.lines().filter(|l| l.starts_with("grid ")).map(String::from).collect::<Vec<_>>())
        })
        .filter(|(_, starts)| starts.len() > 1)
        .collect();
    assert_eq!(reruns.len(), 1, "{reruns:?}");
    let (i, starts) = &reruns[0];
    assert_eq!(starts.len(), 2);
    let field = |l: &str, key: &str| -> usize { l.split(key).nth(1).and_then(|t| t.split([';', ' ']).next()).and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("no '{key}' in {l}")) };
    let size = (single.len() - i).div_ceil(4);
    assert_eq!((field(&starts[0], "; done "), field(&starts[0], "; to run ")), (0, size), "{}", starts[0]);
    let (done, to_run) = (field(&starts[1], "; done "), field(&starts[1], "; to run "));
    assert!(done >= 1 && to_run >= 1 && done + to_run == size, "{}", starts[1]);

    // the optimisation: merged history and best equal the single-process multi-start
    let op = work.join("optimise");
    for f in ["history.json", "best.json"] {
        assert!(strip(&json(&op.join("single").join(f))) == strip(&json(&op.join("merged").join(f))), "{f} differs");
    }
    let best = json(&op.join("merged/best.json"));
    assert_eq!(best["runs"].as_array().unwrap().len(), 6);
    assert_eq!(best["merged_from"].as_array().unwrap().len(), 3);
    let resumed = (0..3).filter(|i| std::fs::read_to_string(op.join(format!("logs/start-{i}.out"))).unwrap().lines().any(|l| l.starts_with("resuming: "))).count();
    assert_eq!(resumed, 1, "one start task was requeued and resumed");
}
