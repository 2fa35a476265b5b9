//! `twistopt sweep`, `sweep-merge` and `verify` through the binary: a SIGKILLed and resumed
//! sweep equals an uninterrupted one (each design exactly once), shards merge to the same rows,
//! failing designs are rows, verify compares a hand-made best.json, bad input is one line.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twistopt"))
}

fn dir(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// 8 designs: α = 30° is outside Table I (2 invalid-geometry rows), 6 FE designs on a 12x4x1
/// sector ramped to 20 kPa (well under a second each).
const PROBLEM: &str = r#"
[load]
p_max_kPa = 20
[fidelity]
mesh = "12x4x1"
[sweep]
r_mm = [8.660254037844386]
l_mm = [10, 15]
alpha_deg = [30, 60, 180, 300]
"#;

fn write_problem(d: &Path, text: &str) -> PathBuf {
    let p = d.join("problem.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn sweep(problem: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let o = bin().arg("sweep").arg(problem).args(["--threads", "1", "--out"]).arg(out).args(extra).output().unwrap();
    assert!(o.status.success(), "sweep failed: {}", String::from_utf8_lossy(&o.stderr));
    o
}

/// Rows by id, with the wall times removed (everything else must be equal).
fn rows(out: &Path) -> BTreeMap<String, Value> {
    rows_of(out, false)
}

/// As [`rows`]; with `allow_torn`, a last line without its newline (a kill during a write) is
/// ignored.
fn rows_of(out: &Path, allow_torn: bool) -> BTreeMap<String, Value> {
    let mut text = std::fs::read_to_string(out.join("results.jsonl")).unwrap();
    if allow_torn {
        text.truncate(text.rfind('\n').map(|i| i + 1).unwrap_or(0));
    }
    let mut m = BTreeMap::new();
    for line in text.lines() {
        let mut v: Value = serde_json::from_str(line).unwrap();
        let o = v.as_object_mut().unwrap();
        o.remove("wall_time_s");
        for s in o["scenes"].as_object_mut().unwrap().values_mut() {
            s.as_object_mut().unwrap().remove("wall_time_s");
        }
        let id = o["id"].as_str().unwrap().to_string();
        assert!(m.insert(id.clone(), v).is_none(), "{id} appears twice in {}", out.display());
    }
    m
}

fn complete_lines(path: &Path) -> usize {
    std::fs::read(path).map(|b| b.iter().filter(|&&c| c == b'\n').count()).unwrap_or(0)
}

#[test]
fn killed_resumed_sharded_and_verified() {
    let d = dir("sweep-kill");
    let problem = write_problem(&d, PROBLEM);

    // uninterrupted reference
    let a = d.join("a");
    let t0 = Instant::now();
    sweep(&problem, &a, &[]);
    let ref_time = t0.elapsed();
    let ra = rows(&a);
    assert_eq!(ra.len(), 8);
    let status = |r: &Value| r["status"].as_str().unwrap().to_string();
    let invalid: Vec<&Value> = ra.values().filter(|r| status(r) == "invalid-geometry").collect();
    assert_eq!(invalid.len(), 2);
    for r in &invalid {
        assert_eq!(r["design"]["alpha_deg"].as_f64(), Some(30.0));
        assert!(r["cause"].as_str().unwrap().contains("alpha_deg"), "{r}");
        assert!(r["omega_J_m3"].is_null());
    }
    for r in ra.values().filter(|r| status(r) != "invalid-geometry") {
        assert_eq!(status(r), "ok", "{r}");
        // 20 kPa is reached by both scenes: Ω at 20 kPa, twist grows with α, feasible
        assert_eq!(r["p_omega_kPa"].as_f64(), Some(20.0), "{r}");
        assert!(r["omega_J_m3"].as_f64().unwrap() > 0.0);
        assert!(r["feasible"].as_bool().unwrap());
        assert_eq!(r["scenes"]["free"]["status"], "completed");
        let rad = r["max_radius_mm"].as_f64().unwrap();
        assert!(rad > 19.0 && rad < 28.75, "{rad}");
    }
    let theta = |a: f64, l: f64| ra.values().find(|r| r["design"]["alpha_deg"].as_f64() == Some(a) && r["design"]["l_mm"].as_f64() == Some(l)).and_then(|r| r["theta_max_deg"].as_f64()).unwrap().abs();
    assert!(theta(60.0, 10.0) < theta(180.0, 10.0) && theta(180.0, 10.0) < theta(300.0, 10.0));
    for f in ["manifest.json", "results.csv", "summary.json", "map_theta.png", "map_tau.svg", "map_omega.png"] {
        assert!(a.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let csv = std::fs::read_to_string(a.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 9);
    assert!(csv.starts_with("index,r_mm,l_mm,alpha_deg,status"));

    // killed (SIGKILL) after the first rows, a torn line appended, then resumed
    let b = d.join("b");
    let mut child = bin().arg("sweep").arg(&problem).args(["--threads", "1", "--out"]).arg(&b).stdout(std::process::Stdio::null()).spawn().unwrap();
    let results = b.join("results.jsonl");
    let deadline = Instant::now() + ref_time * 5 + Duration::from_secs(30);
    while complete_lines(&results) < 3 {
        assert!(Instant::now() < deadline, "no rows appeared");
        assert!(child.try_wait().unwrap().is_none(), "the sweep ended before it could be killed");
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL on Unix
    child.wait().unwrap();
    let before = rows_of(&b, true);
    assert!(before.len() >= 3 && before.len() < 8, "killed with {} rows", before.len());
    let mut f = std::fs::OpenOptions::new().append(true).open(&results).unwrap();
    std::io::Write::write_all(&mut f, b"{\"id\":\"5:alpha_deg=60,l_mm=15,r_mm=8.6602").unwrap();
    drop(f);
    let o = sweep(&problem, &b, &[]);
    let log = String::from_utf8_lossy(&o.stdout);
    assert!(log.contains(&format!("done {}; to run {}", before.len(), 8 - before.len())), "{log}");
    assert!(log.contains("dropped 1"), "{log}");
    let rb = rows(&b);
    assert_eq!(rb, ra, "resumed sweep differs from the uninterrupted one");
    assert_eq!(complete_lines(&results), 8, "each design exactly once");
    // rows finished before the kill were not recomputed (their times are unchanged)
    let times = |out: &Path| -> BTreeMap<String, f64> {
        std::fs::read_to_string(out.join("results.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str::<Value>(l).unwrap())
            .map(|v| (v["id"].as_str().unwrap().to_string(), v["wall_time_s"].as_f64().unwrap()))
            .collect()
    };
    let tb = times(&b);
    let t_before: BTreeMap<String, f64> = {
        let text = std::fs::read_to_string(&results).unwrap();
        text.lines().take(before.len()).map(|l| serde_json::from_str::<Value>(l).unwrap()).map(|v| (v["id"].as_str().unwrap().to_string(), v["wall_time_s"].as_f64().unwrap())).collect()
    };
    for (id, t) in &t_before {
        assert_eq!(tb[id], *t);
    }
    // resuming a finished sweep computes nothing
    let o = sweep(&problem, &b, &[]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("to run 0"));

    // a different problem is refused in the same directory
    let o = bin().arg("sweep").arg(&problem).args(["--set", "load.p_max_kPa=25", "--out"]).arg(&b).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("different sweep") && e.contains("load") && e.trim().lines().count() == 1, "{e}");

    // two shards, merged
    let (s0, s1, m) = (d.join("s0"), d.join("s1"), d.join("merged"));
    sweep(&problem, &s0, &["--shard", "0/2"]);
    sweep(&problem, &s1, &["--shard", "1/2"]);
    assert_eq!(rows(&s0).len() + rows(&s1).len(), 8);
    assert!(rows(&s0).values().all(|r| r["index"].as_u64().unwrap() % 2 == 0));
    let o = bin().arg("sweep-merge").arg(&s0).arg(&s1).arg("--out").arg(&m).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(rows(&m), ra, "merged shards differ from the single run");
    let o = bin().arg("sweep-merge").arg(&s0).arg(&a).arg("--out").arg(d.join("bad-merge")).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    // the merged directory resumes as a complete, unsharded sweep
    let o = sweep(&problem, &m, &[]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("done 8; to run 0"));

    // verify: a hand-made optimiser result 0.5 % below the sweep's best, 0.1 mm off in l
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(a.join("summary.json")).unwrap()).unwrap();
    let best = &summary["best_omega"];
    let best_omega = best["values"]["omega_J_m3"].as_f64().unwrap();
    let max_omega = ra.values().filter_map(|r| r["omega_J_m3"].as_f64()).fold(0.0, f64::max);
    assert_eq!(best_omega, max_omega);
    let bd = &best["design"];
    let opt = d.join("opt");
    std::fs::create_dir_all(&opt).unwrap();
    let best_json = serde_json::json!({
        "r_mm": bd["r_mm"], "l_mm": bd["l_mm"].as_f64().unwrap() - 0.1, "alpha_deg": bd["alpha_deg"],
        "p_kPa": 20.0, "theta_deg": 10.0, "tau_Nm": 0.1, "omega_J_m3": 0.995 * best_omega,
        "max_radius_mm": 22.0, "evaluations": 3, "status": "converged"
    });
    std::fs::write(opt.join("best.json"), best_json.to_string()).unwrap();
    let o = bin().arg("verify").arg(&problem).arg("--sweep").arg(&a).arg("--optimise").arg(&opt).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(opt.join("verify.json")).unwrap()).unwrap();
    assert!((v["omega_relative_difference"].as_f64().unwrap() + 0.005).abs() < 1e-12, "{v}");
    assert_eq!(v["within_1_percent"], true);
    assert!((v["scaled_distance"].as_f64().unwrap() - 0.01).abs() < 1e-12, "{v}"); // 0.1 mm of l's 10 mm range
    assert!((v["per_parameter"]["l_mm"]["diff"].as_f64().unwrap() + 0.1).abs() < 1e-12);
    assert_eq!(v["per_parameter"]["alpha_deg"]["diff"].as_f64(), Some(0.0));
    assert_eq!(v["sweep"]["fe_evaluations"].as_u64(), Some(6));
    assert_eq!(v["evaluation_ratio"].as_f64(), Some(2.0));
    assert_eq!(v["at_least_100x_fewer_evaluations"], false);
    assert_eq!(v["optimiser"]["feasible"], true);
    assert_eq!(v["sweep"]["best"]["omega_J_m3"].as_f64(), Some(best_omega));
    // the optimiser's design re-evaluated as a sweep row (the letter's rule): 0.1 mm from the
    // sweep's best design, so within a few % of its Ω
    let rule = &v["optimiser_design_by_the_letters_rule"];
    assert_eq!(rule["status"], "ok", "{rule}");
    let rr = rule["omega_relative_difference"].as_f64().unwrap();
    assert!(rr.abs() < 0.05 && (rule["omega_J_m3"].as_f64().unwrap() / best_omega - 1.0 - rr).abs() < 1e-12, "{rule}");
    let txt = std::fs::read_to_string(opt.join("verify.txt")).unwrap();
    assert!(txt.contains("-0.50 %") && txt.contains("within 1 %") && txt.trim().lines().count() == 1, "{txt}");
    // the same in the explicit combined mode; the pure-twist mode did not run in this sweep
    let o = bin().arg("verify").arg(&problem).arg("--sweep").arg(&a).arg("--optimise").arg(&opt).args(["--mode", "combined", "--out"]).arg(d.join("v2")).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v2: Value = serde_json::from_str(&std::fs::read_to_string(d.join("v2/verify.json")).unwrap()).unwrap();
    assert_eq!(v2["omega_relative_difference"], v["omega_relative_difference"]);
    assert_eq!(v2["mode"], "combined");
    for (mode, needle) in [("pure-twist", "in mode pure-twist"), ("bogus", "--mode 'bogus'")] {
        let o = bin().arg("verify").arg(&problem).arg("--sweep").arg(&a).arg("--optimise").arg(&opt).args(["--mode", mode]).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && e.contains(needle) && e.trim().lines().count() == 1, "{e}");
    }
    // a best.json without a required key is a one-line error
    std::fs::write(opt.join("best.json"), r#"{"r_mm": 10, "l_mm": 12, "alpha_deg": 60}"#).unwrap();
    let o = bin().arg("verify").arg(&problem).arg("--sweep").arg(&a).arg("--optimise").arg(&opt).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && e.contains("missing key(s) p_kPa, theta_deg, tau_Nm, omega_J_m3, max_radius_mm, evaluations, status") && e.trim().lines().count() == 1, "{e}");
}

#[test]
fn bad_input_is_one_line() {
    let d = dir("sweep-bad");
    let problem = write_problem(&d, PROBLEM);
    let broken = d.join("broken.toml");
    std::fs::write(&broken, "[load\np_max_kPa = 20\n").unwrap();
    let unknown = d.join("unknown.toml");
    std::fs::write(&unknown, PROBLEM.replace("[sweep]", "[sweep]\nstep = 3")).unwrap();
    let out = d.join("out");
    let p = problem.to_str().unwrap();
    let o = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["sweep", p, "--shard", "3/2", "--out", o], "--shard '3/2'"),
        (vec!["sweep", p, "--grid", "every=0", "--out", o], "every"),
        (vec!["sweep", p, "--grid", "bogus", "--out", o], "--grid 'bogus'"),
        (vec!["sweep", p, "--fidelity", "huge", "--out", o], "fidelity.preset"),
        (vec!["sweep", p, "--set", "load.pressures_kPa=[10]", "--out", o], "load.p_max_kPa"),
        (vec!["sweep", broken.to_str().unwrap(), "--out", o], "line 1"),
        (vec!["sweep", unknown.to_str().unwrap(), "--out", o], "sweep.step"),
        (vec!["sweep", p], "--out"),
        (vec!["sweep-merge", o, "--out", o], "manifest.json"),
    ] {
        let r = bin().args(&args).output().unwrap();
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && r.status.code() != Some(101), "{args:?}: {e}");
        assert!(!e.contains("panicked") && e.trim().lines().count() == 1 && e.contains(needle), "{args:?}: {e}");
    }
    assert!(!out.join("results.jsonl").exists());
    // --count prints the Table-I count without running
    let r = bin().args(["sweep", p, "--grid", "table1", "--count"]).output().unwrap();
    let s = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success() && s.contains("39864 designs (r_mm 24 × l_mm 11 × alpha_deg 151)"), "{s}");
}

/// `sweep.vacuum_kPa` (issue 19): every design is also ramped to −p⁻ (here 15 kPa, before the
/// walls meet, on a 12x4x1 sector) and its row carries the vacuum side: both scenes completed,
/// θ and τ opposite to the positive side's, Ω > 0 at −15 kPa; a resume with another p⁻ is refused.
#[test]
fn vacuum_side_rows() {
    let d = dir("sweep-vacuum");
    let problem = write_problem(
        &d,
        r#"
[load]
p_max_kPa = 20
[fidelity]
mesh = "12x4x1"
[sweep]
vacuum_kPa = 15
r_mm = [8.660254037844386]
l_mm = [10]
alpha_deg = [60, 180]
"#,
    );
    let out = d.join("out");
    let o = sweep(&problem, &out, &[]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("without scenes.contact") || String::from_utf8_lossy(&o.stdout).contains("without scenes.contact"), "no warning");
    let r = rows(&out);
    assert_eq!(r.len(), 2);
    for row in r.values() {
        assert_eq!(row["status"], "ok", "{row}");
        let vac = &row["vacuum"];
        assert_eq!(vac["p_target_kPa"].as_f64(), Some(-15.0));
        for s in ["free", "blocked"] {
            assert_eq!(vac["scenes"][s]["status"], "completed", "{vac}");
            assert_eq!(vac["scenes"][s]["p_reached_kPa"].as_f64(), Some(-15.0), "{vac}");
        }
        let m = &vac["modes"]["combined"];
        let (th, tau, om) = (m["theta_deg"].as_f64().unwrap(), m["tau_Nm"].as_f64().unwrap(), m["omega_J_m3"].as_f64().unwrap());
        assert!(th * row["theta_omega_deg"].as_f64().unwrap() < 0.0 && tau * row["tau_omega_Nm"].as_f64().unwrap() < 0.0, "{row}");
        assert!(om > 0.0 && m["p_omega_kPa"].as_f64() == Some(-15.0), "{m}");
        // Ω at −15 kPa from θ and τ there (the letter's rule)
        let expect = twistopt::scene::energy_density(th.abs(), tau.abs());
        assert!((om - expect).abs() < 1e-9 * om, "{om} vs {expect}");
    }
    // a resume with another p⁻ is refused
    let o = bin().arg("sweep").arg(&problem).args(["--threads", "1", "--set", "sweep.vacuum_kPa=20", "--out"]).arg(&out).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("vacuum_kPa"), "{}", String::from_utf8_lossy(&o.stderr));
    // bad values are refused in one line
    let o = bin().arg("sweep").arg(&problem).args(["--threads", "1", "--set", "sweep.vacuum_kPa=-5", "--out"]).arg(d.join("bad")).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("sweep.vacuum_kPa"));
}
