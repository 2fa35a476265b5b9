//! Read-back of the exports by a reader no one here wrote: Python's `meshio`
//! (tests/python/check_exports.py). Fails, with a pointer to scripts/setup.sh, when meshio is not
//! installed.

use std::path::PathBuf;
use std::process::Command;

fn run_case(name: &str, args: &[&str], rtol: &str) {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    let out = Command::new(env!("CARGO_BIN_EXE_twistopt")).args(["geometry"]).args(args).arg("--out").arg(&d).output().expect("run twistopt");
    assert!(out.status.success(), "twistopt failed: {}", String::from_utf8_lossy(&out.stderr));
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_exports.py");
    let py = Command::new("python3").arg(&script).arg(&d).arg(rtol).output();
    let py = match py {
        Ok(o) => o,
        Err(e) => panic!("cannot run python3 ({e}): run `bash scripts/setup.sh` to install python3, meshio and numpy"),
    };
    let stdout = String::from_utf8_lossy(&py.stdout);
    let stderr = String::from_utf8_lossy(&py.stderr);
    if py.status.code() == Some(3) {
        panic!("meshio/numpy are not importable by python3: run `bash scripts/setup.sh` first ({stderr})");
    }
    assert!(py.status.success(), "meshio read-back failed for {name}:\n{stdout}\n{stderr}");
    assert!(stdout.contains("OK"), "{stdout}");
    eprintln!("{stdout}");
}

#[test]
fn meshio_reads_vtu_and_closed_stls_paper_example() {
    // quadratic default mesh: chamber within 0.05 %, outer within 0.3 %
    run_case("readback-paper", &["--r", "8.660254037844386", "--l", "10", "--alpha", "60"], "0.003");
}

#[test]
fn meshio_reads_linear_and_sector_exports() {
    run_case("readback-linear", &["--r", "13.2", "--l", "16", "--alpha", "200", "--order", "linear", "--mesh", "96x32x2"], "0.01");
    // sector mesh in the VTU, STLs from the full mesh
    run_case("readback-sector", &["--r", "20", "--l", "14", "--alpha", "90", "--sector", "--mesh", "fine"], "0.002");
}
