#![allow(dead_code)]
use std::path::PathBuf;

/// The shared read-only material sits beside the repository: `$CARGO_MANIFEST_DIR/../shared`.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("shared")
}

pub fn test_vectors() -> serde_json::Value {
    let p = shared_dir().join("geometry").join("test_vectors.json");
    let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("cannot read {} ({e}); the shared/ directory must sit beside the repository", p.display()));
    serde_json::from_str(&text).expect("test_vectors.json parses")
}

/// |a − b| ≤ tol·max(|b|, 1): relative for values ≳ 1, absolute for references ≈ 0.
pub fn assert_close(a: f64, b: f64, tol: f64, what: &str) {
    let scale = b.abs().max(1.0);
    assert!((a - b).abs() <= tol * scale, "{what}: got {a:.17e}, reference {b:.17e}, diff {:.3e} > {:.1e}·{scale}", (a - b).abs(), tol);
}
