//! The `twistopt` binary: outputs of `geometry`, and clean one-line errors for bad input.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twistopt"))
}

fn out_dir(name: &str) -> std::path::PathBuf {
    let d = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Run and expect a failure whose stderr is one line naming `needle`.
fn expect_error(args: &[&str], needle: &str) {
    let out = bin().args(args).output().expect("run twistopt");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} should fail; stderr: {stderr}");
    assert_ne!(out.status.code(), Some(101), "{args:?} panicked: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: error must be one line, got:\n{stderr}");
    assert!(stderr.contains(needle), "{args:?}: error should name '{needle}', got: {stderr}");
}

#[test]
fn bad_input_gives_one_line_errors_naming_the_field() {
    let d = out_dir("cli-bad");
    let o = d.to_str().unwrap();
    expect_error(&["geometry", "--r", "3", "--l", "10", "--alpha", "60", "--out", o], "r_mm");
    expect_error(&["geometry", "--r", "3", "--l", "10", "--alpha", "60", "--out", o], "[8.660254, 20] mm");
    expect_error(&["geometry", "--r", "10", "--l", "NaN", "--alpha", "60", "--out", o], "l_mm");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "-5", "--out", o], "alpha_deg");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "90", "--mesh", "bogus", "--out", o], "mesh");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "90", "--mesh", "40x16x2", "--out", o], "n_around");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "inf", "--out", o], "alpha_deg");
    expect_error(&["geometry", "--r", "6", "--l", "15", "--alpha", "90", "--extended-range", "--out", o], "r_mm");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "abc", "--out", o], "--alpha");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--out", o], "--alpha");
    expect_error(&["geometry", "--r", "10", "--l", "12", "--alpha", "90", "--mesh", "3000x400x4", "--out", o], "limit");
    assert!(!d.join("summary.json").exists(), "nothing is written on error");
}

#[test]
fn geometry_writes_summary_and_exports() {
    let d = out_dir("cli-paper-example");
    let out = bin().args(["geometry", "--r", "8.660254037844386", "--l", "10", "--alpha", "60", "--mesh", "coarse"]).arg("--out").arg(&d).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for f in ["summary.json", "mesh.vtu", "outer.stl", "cavity.stl", "mesh.inp"] {
        assert!(d.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let s: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap()).unwrap();
    for key in ["r_mm", "l_mm", "alpha_deg", "T_mm", "B_mm", "rho_a_mm", "inner_end_area_mm2", "chamber_volume_mm3", "wall_volume_mm3", "outer_volume_mm3", "min_scaled_jacobian", "nodes", "elements"]
    {
        assert!(s.get(key).is_some(), "summary.json lacks {key}");
    }
    let f = |k: &str| s[k].as_f64().unwrap();
    assert!((f("T_mm") - 18.660254037844386).abs() < 1e-12);
    assert!((f("rho_a_mm") - 12.5).abs() < 1e-12);
    assert!((f("chamber_volume_mm3") - 10673.344366736535).abs() < 1e-5);
    assert!((f("inner_end_area_mm2") - 545.9245394654889).abs() < 1e-9);
    assert!((f("wall_volume_mm3") - (20756.657467046745 - 10673.344366736535)).abs() < 1e-5);
    assert_eq!(s["elements"].as_u64().unwrap(), 24 * 8);
    assert_eq!(s["nodes"].as_u64().unwrap(), 48 * 17 * 3);
    assert!(f("min_scaled_jacobian") > 0.2);
    // INP: C3D20 elements (Hex27 exported through its first 20 nodes) and all sets
    let inp = std::fs::read_to_string(d.join("mesh.inp")).unwrap();
    assert!(inp.contains("*ELEMENT, TYPE=C3D20, ELSET=EALL"));
    for set in ["BOTTOM", "TOP", "CAVITY", "OUTER"] {
        assert!(inp.contains(&format!("*NSET, NSET={set}")), "{set}");
        assert!(inp.contains(&format!("*SURFACE, NAME={set}, TYPE=ELEMENT")), "{set}");
    }
    // cavity faces are ζ− = S1, outer ζ+ = S2
    assert!(inp.contains("\n1, S1\n"));
}

#[test]
fn sector_linear_and_extended_range_runs() {
    let d = out_dir("cli-sector");
    let out = bin().args(["geometry", "--r", "10", "--l", "12", "--alpha", "-30", "--extended-range", "--sector", "--order", "linear"]).args(["--mesh", "24x8x2", "--out"]).arg(&d).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let s: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["elements"].as_u64().unwrap(), 8 * 8 * 2);
    assert_eq!(s["element_kind"].as_str().unwrap(), "Hex8");
    assert_eq!(s["cyclic_pairs"].as_u64().unwrap(), 9 * 3);
    let inp = std::fs::read_to_string(d.join("mesh.inp")).unwrap();
    assert!(inp.contains("TYPE=C3D8") && inp.contains("NSET=CUT_START") && inp.contains("NAME=CUT_END"));
}

#[test]
fn help_explains_every_option() {
    let out = bin().arg("--help").output().unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("geometry"));
    let out = bin().args(["geometry", "--help"]).output().unwrap();
    let h = String::from_utf8_lossy(&out.stdout);
    for opt in ["--r", "--l", "--alpha", "--mesh", "--order", "--sector", "--extended-range", "--out", "coarse", "quadratic"] {
        assert!(h.contains(opt), "help lacks {opt}:\n{h}");
    }
}
