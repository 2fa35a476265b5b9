#![allow(dead_code)]
use serde_json::Value;
use std::path::PathBuf;

pub fn shared(path: &str) -> Value {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared").join(path);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("reading {}: {e}", p.display()));
    serde_json::from_str(&s).unwrap()
}
