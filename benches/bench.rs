//! `cargo bench --bench bench`: timings recorded in studies/benchmarks/results.json.
//!
//! Each section owns one top-level key of the results file and merges it in (the file is read,
//! the key replaced, and written back), so other benchmarks can add their own keys.
//! Key "mesh_generation": `build_mesh` (node coordinates + topology + quality check) for every
//! preset at the paper example, plus `mesh_shape_derivatives` — median of N runs.

use std::path::PathBuf;
use std::time::Instant;

use serde_json::{json, Value};
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::{build_mesh, mesh_shape_derivatives, MeshSpec, MESH_PRESETS};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).expect("finite timings"));
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

fn time<F: FnMut()>(runs: usize, mut f: F) -> (f64, f64, f64) {
    f(); // warm-up
    let v: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    let min = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let max = v.iter().cloned().fold(0.0, f64::max);
    (median(v), min, max)
}

fn main() {
    let geom = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).expect("paper example is valid");
    let mut entries = serde_json::Map::new();
    for &(name, ..) in MESH_PRESETS {
        let spec = MeshSpec::preset(name).expect("preset");
        let am = build_mesh(&geom, &spec).expect("mesh");
        let runs = 21;
        let (med, min, max) = time(runs, || {
            std::hint::black_box(build_mesh(&geom, &spec).expect("mesh"));
        });
        let (dmed, _, _) = time(7, || {
            std::hint::black_box(mesh_shape_derivatives(&geom, &spec).expect("derivatives"));
        });
        println!(
            "mesh_generation {name:8} {} {:?}: {} nodes, {} elements: median {:.2} ms (min {:.2}, max {:.2}); shape derivatives (3 params) {:.2} ms",
            spec.size_string(),
            spec.kind,
            am.mesh.n_nodes(),
            am.mesh.n_elements(),
            med * 1e3,
            min * 1e3,
            max * 1e3,
            dmed * 1e3
        );
        entries.insert(
            name.to_string(),
            json!({
                "mesh": spec.size_string(),
                "element_kind": format!("{:?}", spec.kind),
                "nodes": am.mesh.n_nodes(),
                "elements": am.mesh.n_elements(),
                "runs": runs,
                "median_ms": med * 1e3,
                "min_ms": min * 1e3,
                "max_ms": max * 1e3,
                "shape_derivatives_median_ms": dmed * 1e3,
                "min_scaled_jacobian": am.quality.min_scaled_jacobian,
            }),
        );
    }
    let section = json!({
        "description": "build_mesh (nodes, topology, quality check) at the paper example r=5√3, l=10, α=60°, release build; median of N runs",
        "design": {"r_mm": geom.design.r_mm(), "l_mm": geom.design.l_mm(), "alpha_deg": geom.design.alpha_deg()},
        "machine": format!("{} cores available", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)),
        "presets": Value::Object(entries),
    });

    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("studies/benchmarks/results.json");
    let mut root: Value = std::fs::read_to_string(&path)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or_else(|| json!({}));
    if !root.is_object() {
        root = json!({});
    }
    root.as_object_mut().expect("object").insert("mesh_generation".into(), section);
    std::fs::create_dir_all(path.parent().expect("parent")).expect("create studies/benchmarks");
    std::fs::write(&path, serde_json::to_string_pretty(&root).expect("json") + "\n").expect("write results.json");
    println!("wrote {}", path.display());
}
