//! `twistopt evaluate`: outputs of a small run of the letter's example, one-line errors for bad
//! problem files, and solver failures reported as a status in result.json.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/paper-example.toml");

fn out_dir(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn evaluate(problem: &str, sets: &[&str], out: &Path) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_twistopt"));
    c.arg("evaluate").arg(problem);
    for s in sets {
        c.arg("--set").arg(s);
    }
    c.arg("--out").arg(out).output().expect("run twistopt")
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(!text.contains("NaN") && !text.contains("inf"), "non-finite number in {}", path.display());
    serde_json::from_str(&text).unwrap()
}

/// Every number in the JSON is finite (serde_json cannot even represent others) and every step
/// field is a number, not null.
fn assert_steps_finite(scene: &Value) {
    for s in scene["steps"].as_array().unwrap() {
        for k in ["p_kPa", "theta_deg", "axial_mm", "tau_Nm", "max_radius_mm", "cavity_volume_mm3", "min_detF"] {
            assert!(s[k].as_f64().is_some_and(f64::is_finite), "step field {k} = {}", s[k]);
        }
        assert!(s["newton_iterations"].as_u64().is_some());
    }
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn writes_result_tables_plots_and_paraview_series() {
    let d = out_dir("evaluate-example");
    let out = evaluate(EXAMPLE, &["fidelity.preset=\"coarse\"", "load.pressures_kPa=[-15,30]", "torque_rotation.pressures_kPa=[30]", "torque_rotation.points=2"], &d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r = read_json(&d.join("result.json"));
    for key in ["problem", "design", "mesh", "scenes", "omega_J_m3", "omega", "torque_rotation"] {
        assert!(r.get(key).is_some(), "result.json lacks {key}");
    }
    // the effective problem has the overrides and the defaults
    assert_eq!(r["problem"]["fidelity"]["preset"], "coarse");
    assert_eq!(r["problem"]["load"]["pressures_kPa"], serde_json::json!([-15.0, 30.0]));
    assert_eq!(f(&r["problem"]["material"]["mu_MPa"]), 0.34);
    assert_eq!(r["mesh"]["size"], "24x8x1");
    assert!((f(&r["design"]["r_mm"]) - 8.660254037844386).abs() < 1e-12);
    for name in ["free", "blocked"] {
        let s = &r["scenes"][name];
        for key in ["status", "cause", "steps", "dofs", "elements", "newton_iterations", "wall_time_s"] {
            assert!(s.get(key).is_some(), "scene {name} lacks {key}");
        }
        assert_eq!(s["status"], "completed", "{name}: {}", s["cause"]);
        assert_steps_finite(s);
        let p: Vec<f64> = s["steps"].as_array().unwrap().iter().map(|x| f(&x["p_kPa"])).collect();
        assert_eq!(p, vec![-15.0, 0.0, 30.0], "{name}: the unloaded state and the requested pressures");
        assert_eq!(s["elements"].as_u64(), Some(64), "coarse sector: 24/3 × 8 × 1 elements");
    }
    // free twist at 30 kPa on the coarse sector: about −6.9° (opposite sign to the vacuum branch),
    // and the blocked torque pushes the same way
    let step = |scene: &str, i: usize, k: &str| f(&r["scenes"][scene]["steps"][i][k]);
    let theta30 = step("free", 2, "theta_deg");
    let tau30 = step("blocked", 2, "tau_Nm");
    assert!((-7.3..-6.5).contains(&theta30), "θ(30 kPa) = {theta30}");
    assert!((-0.021..-0.017).contains(&tau30), "τ(30 kPa) = {tau30}");
    assert!(step("free", 0, "theta_deg") > 0.0, "vacuum twists the other way");
    assert!(step("free", 2, "axial_mm") > 0.0, "pressure extends the actuator");
    assert!(step("blocked", 2, "theta_deg").abs() < 1e-12, "the blocked cap does not turn");
    // Ω by the letter's rule at the common highest pressure (30 kPa), from |θ| and |τ|
    let v_m3 = std::f64::consts::PI * 25.0 * 25.0 * 40.0 * 1e-9;
    let omega = f(&r["omega_J_m3"]);
    let expect = theta30.abs().to_radians() * tau30.abs() / (8.0 * v_m3);
    assert!((omega - expect).abs() < 1e-9 * expect, "Ω = {omega}, expected {expect}");
    assert!((2.5..5.0).contains(&omega), "Ω = {omega} J/m³");
    let pos = &r["omega"]["combined"]["positive"];
    assert_eq!(f(&pos["p_kPa"]), 30.0);
    assert_eq!(pos["abs_values_used"], true);
    let table = r["omega"]["combined"]["omega_by_pressure"].as_array().unwrap();
    assert_eq!(table.iter().map(|x| f(&x["p_kPa"])).collect::<Vec<_>>(), vec![-15.0, 30.0]);
    assert!(f(&r["omega"]["combined"]["negative"]["omega_J_m3"]) > 0.0);
    // torque-rotation: τ(0) is the blocked torque, τ(θ_free) ≈ 0, linear in between
    let tr = &r["torque_rotation"][0];
    assert_eq!(tr["mode"], "combined");
    assert_eq!(tr["status"], "completed");
    let pts = tr["points"].as_array().unwrap();
    assert_eq!(pts.len(), 3);
    assert!((f(&pts[0]["tau_Nm"]) - tau30).abs() < 1e-6 * tau30.abs());
    assert!((f(&pts[2]["theta_deg"]) - theta30).abs() < 1e-9);
    assert!(f(&pts[2]["tau_Nm"]).abs() < 1e-3 * tau30.abs());
    assert!(f(&tr["nonlinearity"]) < 0.02);
    // CSV tables: header + one row per recorded step
    for name in ["free", "blocked"] {
        let csv = std::fs::read_to_string(d.join(format!("{name}.csv"))).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "p_kPa,theta_deg,axial_mm,tau_Nm,max_radius_mm,cavity_volume_mm3,min_detF,newton_iterations");
        assert_eq!(lines.len(), 4);
        let row: Vec<f64> = lines[3].split(',').map(|x| x.parse().unwrap()).collect();
        assert_eq!(row[0], 30.0);
    }
    let csv = std::fs::read_to_string(d.join("torque_rotation.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4);
    // plots: PNG and SVG
    for stem in ["theta_vs_p", "tau_vs_p", "torque_rotation"] {
        let png = std::fs::read(d.join(format!("{stem}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{stem}.png");
        assert!(png.len() > 10_000, "{stem}.png has content");
        let svg = std::fs::read_to_string(d.join(format!("{stem}.svg"))).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("<polyline"), "{stem}.svg");
    }
    // ParaView: one VTU per recorded step, listed in the PVD in pressure order
    for name in ["free", "blocked"] {
        let pvd = std::fs::read_to_string(d.join(format!("{name}.pvd"))).unwrap();
        let vtus: Vec<_> = std::fs::read_dir(d.join(name)).unwrap().filter_map(|e| e.ok()).filter(|e| e.path().extension().is_some_and(|x| x == "vtu")).collect();
        assert_eq!(vtus.len(), 3, "{name}: one VTU per step");
        assert_eq!(pvd.matches("<DataSet").count(), 3);
        assert!(pvd.contains(&format!("file=\"{name}/step_002.vtu\"")));
        let vtu = std::fs::read_to_string(d.join(name).join("step_002.vtu")).unwrap();
        assert!(vtu.contains("Name=\"displacement\" NumberOfComponents=\"3\""));
        assert!(vtu.contains("Name=\"von_mises_MPa\" NumberOfComponents=\"1\""));
    }
}

/// Bad input: non-zero exit, one line on stderr naming the field, no panic, nothing written.
fn expect_error(problem: &str, sets: &[&str], needles: &[&str]) {
    let d = out_dir("evaluate-bad");
    let out = evaluate(problem, sets, &d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{sets:?} should fail");
    assert_ne!(out.status.code(), Some(101), "{sets:?} panicked: {stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{sets:?}: one line, got:\n{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{sets:?}: error should contain '{n}', got: {stderr}");
    }
    assert!(!d.join("result.json").exists(), "nothing is written on bad input");
}

#[test]
fn bad_input_gives_one_line_errors_naming_the_field() {
    let dir = out_dir("evaluate-bad-files");
    std::fs::create_dir_all(&dir).unwrap();
    let malformed = dir.join("malformed.toml");
    std::fs::write(&malformed, "[design]\nr_mm = 10\nl_mm = = 12\n").unwrap();
    expect_error(malformed.to_str().unwrap(), &[], &["malformed.toml", "line 3"]);
    let unknown = dir.join("unknown.toml");
    std::fs::write(&unknown, std::fs::read_to_string(EXAMPLE).unwrap().replace("l_mm = 10.0", "l_mm = 10.0\nwaist_mm = 3")).unwrap();
    expect_error(unknown.to_str().unwrap(), &[], &["design.waist_mm", "unknown field"]);
    expect_error(EXAMPLE, &["scenes.run=[\"free\",\"twisted\"]"], &["scenes.run", "twisted"]);
    expect_error(EXAMPLE, &["load.p_max_kPa=0"], &["load.p_max_kPa"]);
    expect_error(EXAMPLE, &["load.p_max_kPa=-20"], &["load.p_max_kPa"]);
    expect_error(EXAMPLE, &["load.pressures_kPa=[]"], &["load.pressures_kPa", "empty"]);
    expect_error(EXAMPLE, &["design.r_mm=3"], &["design.r_mm", "[8.660254, 20] mm"]);
    expect_error(EXAMPLE, &["design.alpha_deg=\"sixty\""], &["design.alpha_deg"]);
    expect_error(EXAMPLE, &["fidelity.preset=medium"], &["fidelity.preset", "medium"]);
    expect_error(EXAMPLE, &["fidelity.mesh=40x16x2"], &["fidelity.mesh", "n_around"]);
    expect_error(EXAMPLE, &["material.mu_MPa=0"], &["material.mu_MPa"]);
    expect_error(EXAMPLE, &["output.paraview=true"], &["output.paraview"]);
    expect_error(EXAMPLE, &["designs.r_mm=10"], &["designs"]);
    expect_error(EXAMPLE, &["torque_rotation.pressures_kPa=[30]", "scenes.run=[\"free\"]"], &["torque_rotation", "blocked"]);
    expect_error(dir.join("missing.toml").to_str().unwrap(), &[], &["missing.toml"]);
}

#[test]
fn a_pressure_beyond_what_the_wall_survives_is_a_status_not_an_error() {
    let d = out_dir("evaluate-overload");
    let out = evaluate(EXAMPLE, &["fidelity.preset=coarse", "load.p_max_kPa=2000", "scenes.run=[\"free\"]", "output.vtu=false"], &d);
    assert!(out.status.success(), "a solver failure exits 0: {}", String::from_utf8_lossy(&out.stderr));
    let r = read_json(&d.join("result.json"));
    let s = &r["scenes"]["free"];
    let status = s["status"].as_str().unwrap();
    assert_ne!(status, "completed");
    assert!(!s["cause"].as_str().unwrap().is_empty());
    assert_steps_finite(s);
    // every converged step of the ramp is recorded, in increasing pressure, ending below 2000 kPa
    let p: Vec<f64> = s["steps"].as_array().unwrap().iter().map(|x| f(&x["p_kPa"])).collect();
    assert!(p.len() >= 5, "{p:?}");
    assert!(p.windows(2).all(|w| w[1] > w[0]));
    assert!(p[p.len() - 1] > 50.0 && p[p.len() - 1] < 2000.0, "{p:?}");
    // no pair ran, so no Ω; the CSV and the plot are still written
    assert!(r.get("omega_J_m3").is_none());
    assert_eq!(std::fs::read_to_string(d.join("free.csv")).unwrap().lines().count(), p.len() + 1);
    assert!(d.join("theta_vs_p.png").exists() && d.join("theta_vs_p.svg").exists());
    assert!(!d.join("free.pvd").exists(), "vtu = false writes no ParaView series");
}

#[test]
fn pure_twist_pair_gives_its_own_energy_density() {
    let d = out_dir("evaluate-pure-twist");
    let out = evaluate(
        EXAMPLE,
        &[
            "fidelity.preset=coarse",
            "scenes.run=[\"pure-twist\",\"pure-twist-blocked\"]",
            "load.pressures_kPa=[30]",
            "torque_rotation.pressures_kPa=[30]",
            "torque_rotation.points=1",
            "output.vtu=false",
        ],
        &d,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r = read_json(&d.join("result.json"));
    assert!(r.get("omega_J_m3").is_none(), "no combined pair ran");
    let theta = f(&r["scenes"]["pure-twist"]["steps"][1]["theta_deg"]);
    let tau = f(&r["scenes"]["pure-twist-blocked"]["steps"][1]["tau_Nm"]);
    // with the axial motion held the actuator twists less than in the combined mode (≈ −6.9°)
    assert!((-6.3..-5.5).contains(&theta), "pure twist θ(30 kPa) = {theta}");
    assert!((-0.018..-0.014).contains(&tau), "pure twist τ(30 kPa) = {tau}");
    assert_eq!(f(&r["scenes"]["pure-twist"]["steps"][1]["axial_mm"]), 0.0, "the axle holds the cap");
    let v_m3 = std::f64::consts::PI * 25.0 * 25.0 * 40.0 * 1e-9;
    let omega = f(&r["omega_pure_twist_J_m3"]);
    let expect = theta.abs().to_radians() * tau.abs() / (8.0 * v_m3);
    assert!((omega - expect).abs() < 1e-9 * expect, "Ω = {omega}, expected {expect}");
    let tr = &r["torque_rotation"][0];
    assert_eq!(tr["mode"], "pure-twist");
    assert!((f(&tr["points"][0]["tau_Nm"]) - tau).abs() < 1e-6 * tau.abs());
    assert!((f(&tr["free_theta_deg"]) - theta).abs() < 1e-9);
}

/// Every problem file shipped in problems/ loads and validates (a user's first command must not
/// fail on the file itself); the pure-twist vacuum problem's axle reaches the scene options.
#[test]
fn shipped_problem_files_validate() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("problems");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().and_then(|x| x.to_str()) != Some("toml") {
            continue;
        }
        n += 1;
        if std::fs::read_to_string(&p).unwrap().lines().any(|l| l.trim() == "[sweep]") {
            // a sweep's problem: `sweep --count` parses and validates it without running
            let o = Command::new(env!("CARGO_BIN_EXE_twistopt")).arg("sweep").arg(&p).arg("--count").output().unwrap();
            assert!(o.status.success(), "{}: {}", p.display(), String::from_utf8_lossy(&o.stderr));
            continue;
        }
        let problem = twistopt::problem::Problem::load(&p, &[]).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
        let v = problem.validate().unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
        if p.file_name().unwrap() == "vacuum-pure-twist.toml" {
            assert_eq!(problem.scene_options(&v).contact.unwrap().axle_radius_mm, Some(2.0));
        }
    }
    assert!(n >= 10, "{n} problem files");
}
