//! The optimiser end to end on a small problem: the blocking torque over α at a fixed pressure
//! (the letter: τ first grows with α, peaks, then falls — an interior optimum), on a very coarse
//! mesh so that the test stays fast. MMA, SLSQP and the pure-Rust SQP must agree (the SQP alone in a
//! build without the `nlopt` feature, which scripts/test.sh also runs).

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twistopt"))
}

/// The optimisers of this build (scripts/test.sh also runs this file without the `nlopt`
/// feature, where only the pure-Rust SQP exists).
fn optimisers() -> &'static str {
    if cfg!(feature = "nlopt") {
        "optimise.optimisers=[\"mma\",\"slsqp\",\"sqp\"]"
    } else {
        "optimise.optimisers=[\"sqp\"]"
    }
}

#[test]
fn optimisers_agree_on_the_torque_optimum_in_alpha() {
    let dir = std::env::temp_dir().join(format!("twistopt-optimise-{}", std::process::id()));
    let out = bin()
        .args([
            "optimise",
            "problems/max-torque.toml",
            "--set",
            "fidelity.mesh=12x4x1",
            "--set",
            "load.p_max_kPa=20",
            "--set",
            "optimise.variables=[\"alpha_deg\"]",
            "--set",
            optimisers(),
            "--set",
            "optimise.starts=1",
            "--set",
            "optimise.max_evaluations=30",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let best: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("best.json")).unwrap()).unwrap();
    for k in ["r_mm", "l_mm", "alpha_deg", "p_kPa", "theta_deg", "tau_Nm", "omega_J_m3", "max_radius_mm", "evaluations", "status"] {
        assert!(best.get(k).is_some(), "best.json lacks {k}");
    }
    // every design value of the best by name (the fixed ones included)
    for k in ["r_mm", "l_mm", "alpha_deg", "p_kPa"] {
        assert_eq!(best["design"][k].as_f64(), best[k].as_f64(), "best.json design.{k}");
    }
    let runs = best["runs"].as_array().unwrap();
    assert_eq!(runs.len(), if cfg!(feature = "nlopt") { 3 } else { 1 });
    let objs: Vec<f64> = runs.iter().map(|r| r["objective"].as_f64().expect("each run found a feasible design")).collect();
    let top = objs.iter().copied().fold(f64::MIN, f64::max);
    for (r, o) in runs.iter().zip(&objs) {
        assert!((top - o) / top < 5e-3, "{}: {o} vs best {top}", r["optimiser"]);
        assert!(r["evaluations"].as_u64().unwrap() <= 30);
    }
    // an interior optimum in α (the Table-I box is 60–360°) where dτ/dα vanishes
    let a = best["alpha_deg"].as_f64().unwrap();
    assert!(a > 61.0 && a < 359.0, "alpha {a}");
    assert!(best["kkt"].as_f64().unwrap() < 1e-2, "kkt {}", best["kkt"]);
    assert!(best["tau_Nm"].as_f64().unwrap().abs() > 0.0);
    // every evaluation is in the history with its gradient and constraints
    let hist: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("history.json")).unwrap()).unwrap();
    let n: usize = hist["runs"].as_array().unwrap().iter().map(|r| r["evaluations"].as_array().unwrap().len()).sum();
    assert_eq!(n as u64, best["evaluations"].as_u64().unwrap());
    // … and each was appended to evaluations.jsonl as it finished
    let lines = std::fs::read_to_string(dir.join("evaluations.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = lines.lines().filter(|l| !l.trim().is_empty()).map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(rows.len(), n);
    assert!(rows.iter().all(|r| r["run"].is_string() && r["objective"].is_number()));
    for f in ["objective.png", "objective.svg", "constraint.png", "constraint.svg"] {
        assert!(dir.join(f).exists(), "{f}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Multi-fidelity continuation: a run optimises on a very coarse mesh, then restarts from that
/// stage's best design on a finer one; the result (best.json) is the last stage's.
#[test]
fn fidelity_stages_continue_from_the_previous_best() {
    let dir = std::env::temp_dir().join(format!("twistopt-optimise-stages-{}", std::process::id()));
    let out = bin()
        .args([
            "optimise",
            "problems/max-torque.toml",
            "--set",
            "load.p_max_kPa=20",
            "--set",
            "optimise.variables=[\"alpha_deg\", \"l_mm\"]",
            "--set",
            if cfg!(feature = "nlopt") { "optimise.optimisers=[\"slsqp\"]" } else { "optimise.optimisers=[\"sqp\"]" },
            "--set",
            "optimise.starts=1",
            "--set",
            "optimise.max_evaluations=40",
            "--set",
            "optimise.stages=[{mesh=\"12x4x1\", max_evaluations=20}, {mesh=\"18x8x1\", max_evaluations=20}]",
            "--map",
            "3x2",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let best: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("best.json")).unwrap()).unwrap();
    assert_eq!(best["mesh"], "18x8x1", "{best}");
    let run = &best["runs"][0];
    let by_stage: Vec<u64> = run["evaluations_by_stage"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert_eq!(by_stage.len(), 2, "{run}");
    assert!(by_stage.iter().all(|n| (1..=20).contains(n)), "{by_stage:?}");
    assert!(best["kkt"].as_f64().unwrap() < 1e-2, "kkt {}", best["kkt"]);
    let hist: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("history.json")).unwrap()).unwrap();
    let evs = hist["runs"][0]["evaluations"].as_array().unwrap();
    let n0 = by_stage[0] as usize;
    assert!(evs[..n0].iter().all(|e| e["stage"] == 0 && e["mesh"] == "12x4x1"));
    assert!(evs[n0..].iter().all(|e| e["stage"] == 1 && e["mesh"] == "18x8x1"));
    // the second stage starts at the first stage's best feasible design
    let stage0_best = evs[..n0].iter().filter(|e| e["feasible"] == true).max_by(|a, b| a["objective"].as_f64().unwrap().total_cmp(&b["objective"].as_f64().unwrap())).unwrap();
    assert_eq!(evs[n0]["x"], stage0_best["x"]);
    // the finer stage improves on (or keeps) the design it started from, measured on its own mesh
    let start1 = evs[n0]["objective"].as_f64().unwrap();
    assert!(best["objective"].as_f64().unwrap() >= start1 * (1.0 - 1e-9), "{} < {start1}", best["objective"]);
    // the objective map over (α, l) on the first stage's mesh, with the design path
    let map: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("map.json")).unwrap()).unwrap();
    assert_eq!(map["mesh"], "12x4x1");
    assert_eq!(map["alpha_deg"].as_array().unwrap().len(), 3);
    assert_eq!(map["l_mm"].as_array().unwrap().len(), 2);
    let vals: Vec<f64> = map["value"].as_array().unwrap().iter().flat_map(|r| r.as_array().unwrap().iter().filter_map(|v| v.as_f64())).collect();
    assert!(vals.len() >= 4 && vals.iter().all(|v| v.is_finite() && *v > 0.0), "{map}");
    for f in ["map.png", "map.svg"] {
        assert!(dir.join(f).exists(), "{f}");
    }
    // interrupted after half its evaluations (and in the middle of writing a line): --resume
    // replays the recorded half and ends where the whole run ended
    let lines: Vec<String> = std::fs::read_to_string(dir.join("evaluations.jsonl")).unwrap().lines().map(String::from).collect();
    let total = lines.len();
    let kept = total / 2;
    let mut text = lines[..kept].join("\n");
    text.push('\n');
    text.push_str(&lines[kept][..lines[kept].len() / 2]);
    std::fs::write(dir.join("evaluations.jsonl"), text).unwrap();
    let _ = std::fs::remove_file(dir.join("best.json"));
    let resume_args = |extra: &[&str]| {
        let mut c = bin();
        c.args(["optimise", "problems/max-torque.toml", "--set", "load.p_max_kPa=20", "--set", "optimise.variables=[\"alpha_deg\", \"l_mm\"]", "--set"]);
        c.arg(if cfg!(feature = "nlopt") { "optimise.optimisers=[\"slsqp\"]" } else { "optimise.optimisers=[\"sqp\"]" });
        c.args(["--set", "optimise.starts=1", "--set", "optimise.max_evaluations=40", "--set", "optimise.stages=[{mesh=\"12x4x1\", max_evaluations=20}, {mesh=\"18x8x1\", max_evaluations=20}]"]);
        c.args(extra).arg("--resume").arg("--out").arg(&dir);
        c.output().unwrap()
    };
    let out = resume_args(&[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains(&format!("resuming: {kept} recorded evaluations")), "{stdout}");
    let again: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("best.json")).unwrap()).unwrap();
    assert_eq!(again["objective"], best["objective"], "resumed {again}\nwhole {best}");
    assert_eq!(again["alpha_deg"], best["alpha_deg"]);
    assert_eq!(again["evaluations"], best["evaluations"]);
    // only the evaluations the record lacked were run (and appended)
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr.lines().filter(|l| l.contains("] evaluation ")).count(), total - kept, "{stderr}");
    assert_eq!(std::fs::read_to_string(dir.join("evaluations.jsonl")).unwrap().lines().filter(|l| l.trim_end().ends_with('}')).count(), total);
    // resuming another problem is refused
    let out = resume_args(&["--set", "load.p_max_kPa=25"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("another problem"), "{}", String::from_utf8_lossy(&out.stderr));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn optimise_rejects_bad_sections() {
    let dir = std::env::temp_dir().join(format!("twistopt-optimise-bad-{}", std::process::id()));
    for (set, msg) in [
        ("optimise.objective=\"speed\"", "optimise.objective"),
        ("optimise.variables=[\"q_mm\"]", "unknown variable"),
        ("optimise.optimisers=[\"newton\"]", "not available"),
        ("optimise.starts=0", "optimise.starts"),
        ("optimise.banana=1", "banana"),
        ("load.p_max_kPa=0", "load.p_max_kPa"),
        ("optimise.p_min_kPa=90", "optimise.p_min_kPa"),
        ("optimise.variables=[]", "optimise.variables is empty"),
        ("optimise.optimisers=[]", "optimise.optimisers is empty"),
        ("optimise.stages=[{max_evaluations=5}]", "optimise.stages[0]: give either preset or mesh"),
        ("optimise.stages=[{preset=\"huge\", max_evaluations=5}]", "optimise.stages[0].preset"),
        ("optimise.stages=[{preset=\"coarse\", max_evaluations=80}, {preset=\"default\", max_evaluations=80}]", "sum to 160"),
        ("optimise.objective=\"stroke\"", "needs optimise.vacuum_kPa"),
        ("optimise.vacuum_kPa=68", "only by the two-sided objectives"),
    ] {
        // this build's optimisers first, so that the case's own value (later) is what is tested
        let out = bin().args(["optimise", "problems/energy-density.toml", "--set", optimisers(), "--set", set, "--out"]).arg(&dir).output().unwrap();
        assert!(!out.status.success(), "{set} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(msg) && !err.contains("panicked"), "{set}: {err}");
    }
    // a problem without [optimise]
    let out = bin().args(["optimise", "problems/paper-example.toml", "--out"]).arg(&dir).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("[optimise]"));
}

/// The two-sided objectives (issue 19): the bi-directional stroke |θ(+p) − θ(−p⁻)| and
/// Ω(+p) + Ω(−p⁻) with their adjoint gradients (the vacuum side's without its fixed pressure)
/// equal central differences of the optimiser's own evaluation, coarse mesh, p⁻ = 15 kPa (the
/// walls still apart: the contact-state adjoint is checked in tests/contact.rs).
#[test]
fn two_sided_objectives_match_central_differences() {
    use twistopt::optimise::build_problem;
    use twistopt::problem::Problem;
    for (objective, vacuum_ref) in [("stroke", None), ("energy-density-both", Some(()))] {
        let sets: Vec<String> = vec![
            "fidelity.preset=\"coarse\"".into(),
            format!("optimise.objective=\"{objective}\""),
            "optimise.vacuum_kPa=15".into(),
            "optimise.variables=[\"l_mm\", \"alpha_deg\", \"p_kPa\"]".into(),
            optimisers().into(),
        ];
        let problem = Problem::load(std::path::Path::new("problems/energy-density.toml"), &sets).unwrap();
        let v = problem.validate().unwrap();
        let (op, _) = build_problem(&problem, &v).unwrap();
        let x = vec![0.4, 0.5, 0.3];
        let e = op.evaluate(&x, &mut None, None);
        assert_eq!(e.status, "ok", "{objective}: {}", e.status);
        let vac = e.vacuum.as_ref().expect("vacuum side");
        assert!((vac.p_kpa + 15.0).abs() < 1e-12);
        let (tp, tv) = (e.theta_deg.unwrap(), vac.theta_deg.unwrap());
        // the two sides twist opposite ways
        assert!(tp * tv < 0.0, "θ(+p) = {tp}, θ(−p⁻) = {tv}");
        match vacuum_ref {
            None => assert!((e.objective - (tp - tv).abs()).abs() < 1e-9 * e.objective.abs()),
            Some(()) => {
                let om = vac.omega_j_m3.unwrap();
                let op_ = twistopt::scene::energy_density(tp, e.tau_nm.unwrap());
                assert!(om > 0.0 && (e.objective - (op_ + om)).abs() < 1e-9 * e.objective.abs(), "{} vs {op_} + {om}", e.objective);
            }
        }
        let h = 1e-4;
        for i in 0..x.len() {
            let mut xp = x.clone();
            xp[i] += h;
            let mut xm = x.clone();
            xm[i] -= h;
            let (ep, em) = (op.evaluate(&xp, &mut None, None), op.evaluate(&xm, &mut None, None));
            assert!(ep.status == "ok" && em.status == "ok");
            let fd = (ep.f - em.f) / (2.0 * h);
            let err = (e.df[i] - fd).abs() / e.df.iter().map(|d| d.abs()).fold(0.0, f64::max);
            println!("{objective} {}: adjoint {:.8e} fd {fd:.8e} rel {err:.1e}", op.variables[i].name, e.df[i]);
            assert!(err < 1e-5, "{objective} {}: adjoint {} vs fd {fd}", op.variables[i].name, e.df[i]);
        }
    }
}
