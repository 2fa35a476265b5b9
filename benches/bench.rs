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
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
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

/// Sections to run: all, or those named on the command line (`cargo bench --bench bench -- newton_step`).
fn wanted(name: &str) -> bool {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    args.is_empty() || args.iter().any(|a| a == name)
}

fn merge(key: &str, section: Value) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("studies/benchmarks/results.json");
    let mut root: Value = std::fs::read_to_string(&path).ok().and_then(|s| serde_json::from_str(&s).ok()).unwrap_or_else(|| json!({}));
    if !root.is_object() {
        root = json!({});
    }
    root.as_object_mut().expect("object").insert(key.into(), section);
    std::fs::create_dir_all(path.parent().expect("parent")).expect("create studies/benchmarks");
    std::fs::write(&path, serde_json::to_string_pretty(&root).expect("json") + "\n").expect("write results.json");
    println!("wrote {key} to {}", path.display());
}

fn main() {
    twistopt::tune_allocator();
    let geom = ActuatorGeometry::new(&Design::paper_example(), RangePolicy::TableI).expect("paper example is valid");
    if wanted("mesh_generation") {
        mesh_generation(&geom);
    }
    if wanted("newton_step") {
        newton_step(&geom);
    }
    if wanted("evaluation") {
        evaluation(&geom);
    }
    if wanted("gradient") {
        gradient(&geom);
    }
    if wanted("element_kernel") {
        element_kernel(&geom);
    }
    if wanted("sweep_throughput") {
        sweep_throughput();
    }
    if wanted("sweep_throughput_rom") {
        sweep_throughput_rom();
    }
    if wanted("sweep_throughput_rom_warm") {
        sweep_throughput_rom_warm();
    }
    if wanted("rom_evaluation") {
        rom_evaluation();
    }
    if wanted("cold_evaluation") {
        cold_evaluation();
    }
    if wanted("warm_start") {
        warm_start();
    }
    if wanted("ordering") {
        ordering(&geom);
    }
}

/// Throughput of the Hex27 Q2/P1 element kernel (residual + tangent of one element, 27 Gauss
/// points) at a loaded state: a plain function of local data, timed on one thread.
fn element_kernel(geom: &ActuatorGeometry) {
    use twistopt::scene::{SceneKind, SceneModel, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::element::{tangent, Formulation};
    use twistopt_solver::material::{Hyperelastic, NeoHookean};
    let nh = NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material");
    let opts = SceneOptions::new(MeshSpec::preset("coarse").expect("preset"), nh.into());
    let sm = SceneModel::build(geom, &opts, SceneKind::Free).expect("scene");
    let a = sm.model.assemble(&vec![0.0; sm.model.n_reduced()], &sm.loads(5.0, 0.0), false).expect("assembly");
    let form = Formulation::standard(twistopt_solver::mesh::ElementKind::Hex27);
    let rule = form.rule();
    let params = nh.params();
    let mesh = &sm.model.mesh;
    let conn = mesh.element(0);
    let x0: Vec<[f64; 3]> = conn.iter().map(|&n| mesh.nodes[n]).collect();
    // a deformed state: 10 % of a smooth displacement field on top of the pressurised one
    let u: Vec<[f64; 3]> = conn
        .iter()
        .map(|&n| {
            let x = mesh.nodes[n];
            let v = a.u[n];
            [v[0] + 0.1 * x[1].sin(), v[1] + 0.05 * x[2].cos(), v[2] + 0.02 * x[0]]
        })
        .collect();
    let nd = 3 * x0.len();
    let mut f = vec![0.0; nd];
    let mut k = vec![0.0; nd * nd];
    let n = 2000;
    let (t, tmin, tmax) = time(5, || {
        for _ in 0..n {
            std::hint::black_box(tangent(&form, &rule, &nh, &params, &x0, &u, &mut f, &mut k).expect("element"));
        }
    });
    let per = t / n as f64;
    println!("element_kernel Hex27 Q2/P1: {:.1} µs per element (residual + tangent), {:.0} elements/s on one thread", per * 1e6, 1.0 / per);
    merge(
        "element_kernel",
        json!({
            "description": "Hex27 Q2/P1 Neo-Hookean element: residual + 81x81 tangent at 27 Gauss points (element::tangent), one thread, median of 5 batches of 2000 calls; release build",
            "seconds_per_element": per, "elements_per_second": 1.0 / per,
            "batch_seconds_median_min_max": [t, tmin, tmax],
        }),
    );
}

/// Work counts of a set of paths: iterations per converged step (locating iterations apart)
/// and the share of iterations in failed attempts.
fn path_work(stats: &[&twistopt_solver::continuation::PathStats]) -> Value {
    let (mut steps, mut its, mut failed, mut locate, mut attempts) = (0usize, 0usize, 0usize, 0usize, 0usize);
    for s in stats {
        steps += s.steps;
        its += s.newton_iterations;
        failed += s.failed_iterations;
        locate += s.locate_iterations;
        attempts += s.failed_attempts;
    }
    let per_step = (its - failed - locate) as f64 / steps.max(1) as f64;
    json!({
        "converged_steps": steps, "newton_iterations": its, "failed_attempts": attempts, "failed_iterations": failed, "locate_iterations": locate,
        "iterations_per_converged_step": per_step, "failed_share": failed as f64 / its.max(1) as f64,
    })
}

/// Designs per second of `twistopt sweep` (free + blocked ramped to failure, 150 kPa cap) on
/// 2 threads at the `sweep` preset, on a 3-design sample spanning the Table-I box.
fn sweep_throughput() {
    use rayon::prelude::*;
    use twistopt::sweep::{evaluate_design, problem_from_str, Shard, SweepConfig};
    let text = "[load]\np_max_kPa = 150\n[scenes]\nrun = [\"free\", \"blocked\"]\n[fidelity]\npreset = \"sweep\"\n[sweep]\nr_mm = [8.660254037844386, 17.0]\nl_mm = [10, 20]\nalpha_deg = [120, 300]\n";
    let (problem, section) = problem_from_str(text, "bench", &[]).expect("problem");
    let cfg = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).expect("config");
    let v = cfg.problem.validate().expect("valid");
    let mut opts = cfg.problem.scene_options(&v);
    opts.keep_fields = false;
    // 3 of the 8 designs: grid indices 0, 3, 6
    let idx: Vec<u64> = (0..cfg.grid.len()).filter(|i| i % 3 == 0).collect();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().expect("pool");
    let t0 = std::time::Instant::now();
    let rows: Vec<_> = pool.install(|| idx.par_iter().map(|&i| evaluate_design(i, &cfg.grid.design(i), cfg.grid.range, &v, &opts, cfg.p_max_kpa)).collect());
    let wall = t0.elapsed().as_secs_f64();
    let cpu: f64 = rows.iter().map(|r| r.wall_time_s).sum();
    let rate = rows.len() as f64 / wall;
    let grid = 39_864.0;
    let work = path_work(&rows.iter().flat_map(|r| r.scenes.values().map(|s| &s.path)).collect::<Vec<_>>());
    println!(
        "sweep_throughput (sweep preset, 2 threads): {} designs in {wall:.1} s = {rate:.4} designs/s; {:.1} s per design on one thread; full Table-I grid ≈ {:.0} h at this rate (target ≤ 1 h); {work}",
        rows.len(),
        cpu / rows.len() as f64,
        grid / rate / 3600.0
    );
    merge(
        "sweep_throughput",
        json!({
            "description": "twistopt sweep's per-design evaluation (free + blocked ramped to failure or 150 kPa, pressure maximum located under volume control) on 2 threads at the `sweep` preset (48x16x1 Hex27, sector), 3 designs (grid indices 0, 3, 6 of (r, l, α) ∈ {5√3, 17} × {10, 20} × {120, 300}); release build. Wall times depend on the machine's load",
            "designs": rows.iter().map(|r| json!({"id": r.id, "status": r.status, "omega_J_m3": r.primary.omega_j_m3, "theta_max_deg": r.primary.theta_max_deg, "tau_max_Nm": r.primary.tau_max_nm,
                "p_limit_kPa": r.scenes.iter().map(|(k, s)| (k.clone(), json!(s.p_reached_kpa))).collect::<serde_json::Map<_, _>>(),
                "wall_time_s": r.wall_time_s, "path": path_work(&r.scenes.values().map(|s| &s.path).collect::<Vec<_>>())})).collect::<Vec<_>>(),
            "wall_time_s": wall, "designs_per_second": rate, "cpu_seconds_per_design": cpu / rows.len() as f64,
            "full_table1_grid_hours_at_this_rate": grid / rate / 3600.0, "target_hours": 1.0,
            "path_work": work,
            "before_issue_16": {"cpu_seconds_per_design": 135.9, "designs_wall_time_s": [107.5, 215.5, 84.8], "omega_J_m3": [78.412, 934.019, 0.291],
                "note": "the previous solver (commit c08cba2) on this machine, same bench; its Ω interpolated τ linearly between ramp steps (errors up to 0.7 %), today's is computed at the exact common pressure"},
        }),
    );
}

/// [`sweep_throughput`]'s designs on the committed reduced model of the `sweep` preset
/// (studies/rom/sweep-k80, -k80-points, -k40-points) and on the full model, one design at a time on one thread each:
/// CPU s per design of both and the reduced model's Ω error.
fn sweep_throughput_rom() {
    use twistopt::sweep::{evaluate_design, problem_from_str, Shard, SweepConfig};
    // the committed reduced models of the sweep preset: element-level and quadrature-level ECSW
    let models = [
        ("sweep-k80", "80 modes, 10 pressure modes, ECSW 140 of 256 elements"),
        ("sweep-k80-points", "80 modes, 10 pressure modes, ECSW 922 quadrature points in 235 of 256 elements"),
        ("sweep-k40-points", "40 modes, 10 pressure modes, ECSW 695 quadrature points in 212 of 256 elements"),
    ];
    let config = |rom_dir: &std::path::Path| {
        let text = format!(
            "[load]\np_max_kPa = 150\n[scenes]\nrun = [\"free\", \"blocked\"]\n[fidelity]\npreset = \"sweep\"\nrom = {}\nrom_fallback = inf\n[sweep]\nr_mm = [8.660254037844386, 17.0]\nl_mm = [10, 20]\nalpha_deg = [120, 300]\n",
            toml_string(&rom_dir.display().to_string())
        );
        let (problem, section) = problem_from_str(&text, "bench", &[]).expect("problem");
        SweepConfig::new(problem, section.as_ref(), None, Shard::default()).expect("config")
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    let mut full: Option<(Vec<(Option<f64>, f64)>, f64)> = None;
    let mut out = serde_json::Map::new();
    for (name, what) in models {
        let cfg = config(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("studies/rom").join(name));
        let v = cfg.problem.validate().expect("valid");
        let mut ro = cfg.problem.scene_options(&v);
        ro.keep_fields = false;
        let mut fo = ro.clone();
        fo.rom = None;
        let ids: Vec<u64> = (0..cfg.grid.len()).filter(|i| i % 3 == 0).collect();
        // the full model once (the same designs for both reduced models)
        let (full_rows, cpu_f) = full.get_or_insert_with(|| {
            let rows: Vec<(Option<f64>, f64)> = ids
                .iter()
                .map(|&i| {
                    let f = pool.install(|| evaluate_design(i, &cfg.grid.design(i), cfg.grid.range, &v, &fo, cfg.p_max_kpa));
                    (f.primary.omega_j_m3, f.wall_time_s)
                })
                .collect();
            let t = rows.iter().map(|r| r.1).sum::<f64>();
            (rows, t)
        });
        let mut designs = Vec::new();
        let mut cpu_r = 0.0;
        for (&i, &(of, full_s)) in ids.iter().zip(full_rows.iter()) {
            let d = cfg.grid.design(i);
            let r = pool.install(|| evaluate_design(i, &d, cfg.grid.range, &v, &ro, cfg.p_max_kpa));
            cpu_r += r.wall_time_s;
            let or = r.primary.omega_j_m3;
            designs.push(json!({"id": r.id, "omega_rom_J_m3": or, "omega_full_J_m3": of,
                "omega_rel_error": match (or, of) { (Some(a), Some(b)) if b != 0.0 => json!((a - b) / b), _ => Value::Null },
                "rom_s": r.wall_time_s, "full_s": full_s,
                "rom_path": path_work(&r.scenes.values().map(|s| &s.path).collect::<Vec<_>>()),
                "rom_indicator": r.scenes.iter().map(|(k, s)| (k.clone(), json!(s.rom_indicator))).collect::<serde_json::Map<_, _>>()}));
        }
        let n = designs.len() as f64;
        println!(
            "sweep_throughput_rom {name} (sweep preset, one thread): {:.2} s per design reduced vs {:.2} s full ({:.1}×); Table-I grid ≈ {:.1} h on 2 cores; {}",
            cpu_r / n,
            *cpu_f / n,
            *cpu_f / cpu_r,
            39_864.0 * cpu_r / n / 2.0 / 3600.0,
            json!(designs)
        );
        out.insert(
            name.to_string(),
            json!({
                "description": format!("sweep_throughput's 3 designs (free + blocked to failure or 150 kPa) on the committed reduced model studies/rom/{name} ({what}; no fallback) and on the full model, one thread, one design at a time; release build. Times depend on the machine's load"),
                "designs": designs, "rom_seconds_per_design": cpu_r / n, "full_seconds_per_design": *cpu_f / n, "speedup": *cpu_f / cpu_r,
                "table1_grid_hours_on_2_cores": 39_864.0 * cpu_r / n / 2.0 / 3600.0, "target_rom_seconds_per_design": 0.18,
            }),
        );
    }
    merge("sweep_throughput_rom", Value::Object(out));
}

/// The Table-I sweep's work on the committed reduced model (studies/rom/sweep-k80-points): two
/// lines of 40 designs along α at the grid's 2° step (r = 5√3, l = 12 from α = 100°; r = 14.16,
/// l = 19 from α = 240°; a Table-I line has 151), free + blocked to failure, cold and with `sweep.warm_start`, through
/// `twistopt::sweep::run_sweep` on one thread (a line is sequential by construction).
fn sweep_throughput_rom_warm() {
    use twistopt::sweep::{problem_from_str, run_sweep, RunOptions, Shard, SweepConfig};
    const LINE: usize = 40;
    let rom = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("studies/rom/sweep-k80-points");
    let mut out = serde_json::Map::new();
    let mut per_design = Vec::new();
    for warm in [false, true] {
        let mut cpu = 0.0;
        let mut its = 0u64;
        let mut n = 0usize;
        let mut rows_all = Vec::new();
        for (r, l, a0) in [(8.660254037844386, 12.0, 100.0), (14.16025403784439, 19.0, 240.0)] {
            let alphas: Vec<String> = (0..LINE).map(|i| format!("{}", a0 + 2.0 * i as f64)).collect();
            let text = format!(
                "[load]\np_max_kPa = 150\n[scenes]\nrun = [\"free\", \"blocked\"]\n[fidelity]\npreset = \"sweep\"\nrom = {}\nrom_fallback = inf\n[sweep]\nwarm_start = {warm}\nr_mm = [{r}]\nl_mm = [{l}]\nalpha_deg = [{}]\n",
                toml_string(&rom.display().to_string()),
                alphas.join(", ")
            );
            let (problem, section) = problem_from_str(&text, "bench", &[]).expect("problem");
            let cfg = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).expect("config");
            let dir = std::env::temp_dir().join(format!("twistopt-bench-warm-{}-{warm}-{r}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            run_sweep(&cfg, &dir, &RunOptions { threads: 1, progress: false, outputs: false }, |_| {}).expect("sweep");
            let rows = twistopt::sweep::read_rows(&dir.join("results.jsonl")).expect("rows").rows;
            for row in &rows {
                cpu += row.wall_time_s;
                its += row.scenes.values().map(|s| s.newton_iterations as u64).sum::<u64>();
                n += 1;
            }
            rows_all.extend(rows);
            let _ = std::fs::remove_dir_all(&dir);
        }
        rows_all.sort_by_key(|r| (r.design.get("r_mm").map(|v| (v * 1e6) as i64), r.index));
        per_design.push(rows_all);
        let name = if warm { "warm" } else { "cold" };
        println!("sweep_throughput_rom_warm {name}: {:.3} s and {:.1} Newton iterations per design ({n} designs, one thread)", cpu / n as f64, its as f64 / n as f64);
        out.insert(name.into(), json!({"seconds_per_design": cpu / n as f64, "newton_iterations_per_design": its as f64 / n as f64, "designs": n}));
    }
    // the two runs' answers: largest relative difference of Ω, θmax, τmax
    let mut worst: f64 = 0.0;
    for (c, w) in per_design[0].iter().zip(&per_design[1]) {
        for (a, b) in [(c.primary.omega_j_m3, w.primary.omega_j_m3), (c.primary.theta_max_deg, w.primary.theta_max_deg), (c.primary.tau_max_nm, w.primary.tau_max_nm)] {
            if let (Some(a), Some(b)) = (a, b) {
                worst = worst.max((a - b).abs() / a.abs().max(1e-12));
            }
        }
    }
    let (c, w) = (out["cold"]["seconds_per_design"].as_f64().unwrap_or(f64::NAN), out["warm"]["seconds_per_design"].as_f64().unwrap_or(f64::NAN));
    println!("sweep_throughput_rom_warm: warm/cold time {:.2}, Table-I grid ≈ {:.1} h on 2 cores at the warm rate; answers within {worst:.1e}", w / c, 39_864.0 * w / 2.0 / 3600.0);
    out.insert("description".into(), json!("two lines of 40 Table-I designs along α (2° steps) on studies/rom/sweep-k80-points (no fallback), free + blocked to failure, cold and warm-started (sweep.warm_start), one thread; release build. Times depend on the machine's load"));
    out.insert("warm_over_cold_time".into(), json!(w / c));
    out.insert("table1_grid_hours_on_2_cores_warm".into(), json!(39_864.0 * w / 2.0 / 3600.0));
    out.insert("max_rel_difference_warm_vs_cold".into(), json!(worst));
    out.insert("target_seconds_per_design".into(), json!(0.18));
    merge("sweep_throughput_rom_warm", Value::Object(out));
}

/// One reduced evaluation of the committed quadrature-level model (studies/rom/sweep-k80-points)
/// at the sweep preset, at a loaded state of the free scene (the sweep probe design l = 16,
/// α = 200°, at 50 kPa, reached by the path follower): the residual with and without the
/// tangent, and the per-path setup, one thread. The hot loop of `sweep_throughput_rom`, with
/// less noise than whole designs.
fn rom_evaluation() {
    use twistopt::scene::{SceneKind, SceneModel, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::continuation::{follow, ContinuationOptions};
    use twistopt_solver::material::NeoHookean;
    let nh = NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material");
    let opts = SceneOptions::new(MeshSpec::preset("sweep").expect("preset"), nh.into());
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("studies/rom/sweep-k80-points");
    let (rom, _) = twistopt::rom::load(&dir, &opts).expect("reduced model");
    let geom = ActuatorGeometry::new(&Design::new(12.0, 16.0, 200.0), RangePolicy::TableI).expect("design");
    let sm = SceneModel::build(&geom, &opts, SceneKind::Free).expect("scene");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    pool.install(|| {
        let (from, to) = (sm.loads(0.0, 0.0), sm.loads(50.0, 0.0));
        let setup = (0..5)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(rom.path(&sm.model, from.clone(), to.clone(), sm.functionals()).expect("path"));
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min);
        let rp = rom.path(&sm.model, from.clone(), to.clone(), sm.functionals()).expect("path");
        let m = rp.red.dim();
        let res = follow(&rp, &vec![0.0; m], 0.0, 1.0, &[], &[], &ContinuationOptions::default());
        let last = res.points.last().expect("a point");
        let (z, loads) = (last.q.clone(), rp.loads(last.lam));
        // the fastest of 5 batches (the machine's load varies)
        let time = |tangent: bool, reps: usize| {
            (0..5)
                .map(|_| {
                    let t = Instant::now();
                    for _ in 0..reps {
                        std::hint::black_box(rp.evaluate(&z, &loads, tangent).expect("evaluation"));
                    }
                    t.elapsed().as_secs_f64() / reps as f64
                })
                .fold(f64::INFINITY, f64::min)
        };
        let tan = time(true, 20);
        let resid = time(false, 80);
        println!("rom_evaluation (sweep preset, k = 80, 922 points, one thread, p = {:.1} kPa): tangent {:.2} ms, residual only {:.2} ms, path setup {:.1} ms", loads.pressure * 1e3, tan * 1e3, resid * 1e3, setup * 1e3);
        merge(
            "rom_evaluation",
            json!({"description": "one evaluation of the reduced model studies/rom/sweep-k80-points (sweep preset, 80 modes + 2 rigid DOFs, 922 sampled points, 1 089 cavity surface nodes) at a loaded state of the free scene (design r 12, l 16, α 200°, 50 kPa): with the tangent, the residual only, and RomPath::new; one thread, the fastest of 5 batches", "dim": m, "tangent_ms": tan * 1e3, "residual_ms": resid * 1e3, "path_setup_ms": setup * 1e3}),
        );
    });
}

fn toml_string(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

/// A cold evaluation of the default-mesh energy-density optimum as the optimiser makes it: free
/// and blocked scenes to 36.27 kPa with the adjoint gradient, plus the stability (limit-pressure)
/// search above, on 2 threads.
fn cold_evaluation() {
    use twistopt::gradient::{design_gradient, DEFAULT_KS_RHO_PER_MM};
    use twistopt::optimise::{LIMIT_WINDOW, STABILITY_MARGIN};
    use twistopt::scene::{SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 20.0, 360.0), RangePolicy::TableI).expect("optimum is valid");
    let opts = SceneOptions::new(MeshSpec::preset("default").expect("preset"), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
    let p = 36.27;
    let cap = LIMIT_WINDOW * p / (1.0 - STABILITY_MARGIN);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().expect("pool");
    let t0 = Instant::now();
    let cpu0 = twistopt::evaluate::process_cpu_time_s();
    let g = pool.install(|| design_gradient(&geom, &opts, &[SceneKind::Free, SceneKind::Blocked], p, DEFAULT_KS_RHO_PER_MM, None, Some(cap))).expect("evaluation");
    let wall = t0.elapsed().as_secs_f64();
    let cpu = twistopt::evaluate::process_cpu_time_s() - cpu0;
    let work = path_work(&g.scenes.values().map(|s| &s.cost.path).collect::<Vec<_>>());
    let omega = g.omega.get("combined").map(|o| o.value);
    println!("cold_evaluation (default mesh, energy optimum, 2 threads): {wall:.1} s wall, {cpu:.1} s CPU, {} Newton iterations, Ω = {omega:?}; {work}", g.newton_iterations);
    merge(
        "cold_evaluation",
        json!({
            "description": "one optimiser evaluation from a cold start at the default-mesh energy-density optimum (r = 5√3, l = 20, α = 360°): free + blocked to 36.27 kPa with the adjoint gradient of every functional, then the limit-pressure search up to 1.25·p/(1 − 0.02); default preset (sector), 2 threads; target ≤ 60 s",
            "wall_time_s": wall, "cpu_time_s": cpu, "target_wall_time_s": 60.0, "threads": 2,
            "newton_iterations": g.newton_iterations, "omega_J_m3": omega,
            "scenes": g.scenes.iter().map(|(k, s)| (k.clone(), json!({"status": s.status, "dofs": s.dofs, "forward_time_s": s.cost.forward_time_s, "gradient_time_s": s.cost.gradient_time_s, "limit_time_s": s.cost.limit_time_s, "p_limit_kPa": s.p_limit_kpa, "path": path_work(&[&s.cost.path])}))).collect::<serde_json::Map<_, _>>(),
            "path_work": work,
            "before_issue_16": "5–25 min, ≈ 500 Newton iterations (the issue's measurement)",
        }),
    );
}

/// Cost of the adjoint gradient (all functionals of a scene w.r.t. r, l, α, p, μ) against the
/// forward evaluation (ramp 0 → 60 kPa) at each fidelity preset; the target is ≤ 30 % at
/// `default`.
fn gradient(geom: &ActuatorGeometry) {
    use twistopt::gradient::{scene_gradient, DEFAULT_KS_RHO_PER_MM};
    use twistopt::scene::{SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    let mut presets = serde_json::Map::new();
    for preset in ["coarse", "default"] {
        let opts = SceneOptions::new(MeshSpec::preset(preset).expect("preset"), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
        let mut scenes = serde_json::Map::new();
        for kind in [SceneKind::Free, SceneKind::Blocked] {
            let g = scene_gradient(geom, &opts, kind, 60.0, DEFAULT_KS_RHO_PER_MM, None, None).expect("scene");
            let ratio = g.cost.gradient_time_s / g.cost.forward_time_s;
            println!(
                "gradient {preset} {}: forward {:.2} s ({} Newton iterations), gradient {:.3} s ({} adjoint solves, {} dual evaluations) = {:.1} % of forward",
                g.scene,
                g.cost.forward_time_s,
                g.cost.newton_iterations,
                g.cost.gradient_time_s,
                g.cost.adjoint_solves,
                g.cost.dual_evaluations,
                100.0 * ratio
            );
            scenes.insert(
                g.scene.clone(),
                json!({"status": g.status, "dofs": g.dofs, "forward_time_s": g.cost.forward_time_s, "newton_iterations": g.cost.newton_iterations,
                       "gradient_time_s": g.cost.gradient_time_s, "adjoint_solves": g.cost.adjoint_solves, "dual_evaluations": g.cost.dual_evaluations,
                       "gradient_over_forward": ratio, "functionals": g.values.keys().collect::<Vec<_>>(),
                       "parameters": g.gradients.values().next().map(|m| m.keys().collect::<Vec<_>>())}),
            );
        }
        presets.insert(preset.into(), Value::Object(scenes));
    }
    merge(
        "gradient",
        json!({
            "description": "paper example, free and blocked scenes at 60 kPa: forward ramp (0 → 60 kPa) vs adjoint gradient of every functional (θ or τ, axial, cavity volume, KS max radius) w.r.t. r, l, α, p, μ, including the tangent factorisation at the final state; release build",
            "presets": Value::Object(presets),
        }),
    );
}

/// Cost of one Newton step of the `free` scene (sector model) at a loaded state (20 kPa):
/// assembly of residual + tangent, Cholesky factorisation (symbolic analysis reused), solve.
fn newton_step(geom: &ActuatorGeometry) {
    use twistopt::scene::{SceneKind, SceneModel, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    let mut entries = serde_json::Map::new();
    for &(name, ..) in MESH_PRESETS {
        let spec = MeshSpec::preset(name).expect("preset");
        let opts = SceneOptions::new(spec, NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
        let sm = SceneModel::build(geom, &opts, SceneKind::Free).expect("scene");
        let q = vec![0.0; sm.model.n_reduced()];
        let loads = sm.loads(5.0, 0.0);
        let runs = if name == "fine" { 3 } else { 7 };
        let (ta, _, _) = time(runs, || {
            std::hint::black_box(sm.model.assemble(&q, &loads, true).expect("assembly"));
        });
        let (tr, _, _) = time(runs, || {
            std::hint::black_box(sm.model.assemble(&q, &loads, false).expect("assembly"));
        });
        let a = sm.model.assemble(&q, &loads, true).expect("assembly");
        let k = a.k.clone().expect("tangent");
        let (tf, _, _) = time(runs, || {
            std::hint::black_box(sm.model.factor(&k).ok());
        });
        let fac = sm.model.factor(&k);
        let ts = match &fac {
            Ok(f) => {
                time(runs, || {
                    std::hint::black_box(f.solve(&a.r).expect("solve"));
                })
                .0
            }
            Err(_) => f64::NAN,
        };
        println!(
            "newton_step {name:8} dofs {:7} nnz {:9}: assembly (r+K) {:.1} ms, residual only {:.1} ms, factorisation {:.1} ms, solve {:.2} ms",
            sm.model.n_reduced(),
            sm.model.nnz(),
            ta * 1e3,
            tr * 1e3,
            tf * 1e3,
            ts * 1e3
        );
        entries.insert(
            name.to_string(),
            json!({
                "mesh": spec.size_string(), "sector": true, "dofs": sm.model.n_reduced(), "nnz_upper": sm.model.nnz(),
                "elements": sm.model.mesh.n_elements(),
                "assembly_residual_and_tangent_ms": ta * 1e3, "assembly_residual_only_ms": tr * 1e3,
                "cholesky_factorisation_ms": tf * 1e3, "solve_ms": if ts.is_finite() { json!(ts * 1e3) } else { json!(null) },
            }),
        );
    }
    merge(
        "newton_step",
        json!({
            "description": "one Newton step of the free scene on the 120° sector of the paper example at 5 kPa (state u = 0): median wall time of assembly, Cholesky factorisation (symbolic analysis reused) and solve; release build, rayon + faer on all cores",
            "threads": rayon::current_num_threads(),
            "presets": Value::Object(entries),
        }),
    );
}

/// Wall time of a default-fidelity free + blocked evaluation of the paper example up to 60 kPa.
fn evaluation(geom: &ActuatorGeometry) {
    use twistopt::scene::{run_pressure, SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    let opts = SceneOptions::new(MeshSpec::preset("default").expect("preset"), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
    let t = Instant::now();
    let mut scenes = serde_json::Map::new();
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        let r = run_pressure(geom, &opts, kind, &[60.0]).expect("scene");
        let last = r.steps.last().expect("steps");
        println!("evaluation {}: {} in {:.2} s, {} Newton iterations, θ = {:.3}°, τ = {:.4} N·m", r.scene, r.status, r.wall_time_s, r.newton_iterations, last.theta_deg, last.tau_nm);
        scenes.insert(r.scene.clone(), json!({"status": r.status, "wall_time_s": r.wall_time_s, "newton_iterations": r.newton_iterations, "steps": r.steps.len(), "dofs": r.dofs, "theta_deg": last.theta_deg, "tau_Nm": last.tau_nm, "p_kPa": last.p_kpa, "path": path_work(&[&r.path])}));
    }
    merge(
        "evaluation",
        json!({
            "description": "paper example, default fidelity (sector, Q2/P1), free + blocked ramps 0 → 60 kPa, release build",
            "total_wall_time_s": t.elapsed().as_secs_f64(),
            "scenes": Value::Object(scenes),
        }),
    );
}

/// Does a neighbouring design's converged state pay as a start? An optimiser step's second
/// evaluation (free + blocked to p with gradients and the limit search), cold and warm-started
/// from the first design's states, at the `default` and `sweep` presets.
fn warm_start() {
    use twistopt::gradient::{design_gradient, DEFAULT_KS_RHO_PER_MM};
    use twistopt::optimise::{LIMIT_WINDOW, STABILITY_MARGIN};
    use twistopt::scene::{SceneKind, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    let a = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 20.0, 360.0), RangePolicy::TableI).expect("valid");
    let p = 36.27;
    let cap = LIMIT_WINDOW * p / (1.0 - STABILITY_MARGIN);
    let scenes = [SceneKind::Free, SceneKind::Blocked];
    let mut out = serde_json::Map::new();
    for preset in ["sweep", "default"] {
        let opts = SceneOptions::new(MeshSpec::preset(preset).expect("preset"), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
        let ga = design_gradient(&a, &opts, &scenes, p, DEFAULT_KS_RHO_PER_MM, None, Some(cap)).expect("first design");
        let warm = ga.warm_starts();
        let mut cases = serde_json::Map::new();
        for (name, d) in [("step l -0.5 mm, α -10°", Design::new(5.0 * 3f64.sqrt(), 19.5, 350.0)), ("step α -40°", Design::new(5.0 * 3f64.sqrt(), 20.0, 320.0))] {
            let b = ActuatorGeometry::new(&d, RangePolicy::TableI).expect("valid");
            let t = Instant::now();
            let cold = design_gradient(&b, &opts, &scenes, p, DEFAULT_KS_RHO_PER_MM, None, Some(cap)).expect("cold");
            let t_cold = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let hot = design_gradient(&b, &opts, &scenes, p, DEFAULT_KS_RHO_PER_MM, Some(&warm), Some(cap)).expect("warm");
            let t_warm = t.elapsed().as_secs_f64();
            let (oc, ow) = (cold.omega.get("combined").map(|o| o.value), hot.omega.get("combined").map(|o| o.value));
            println!("warm_start {preset} {name}: cold {t_cold:.1} s ({} its), warm {t_warm:.1} s ({} its), Ω {oc:?} vs {ow:?}", cold.newton_iterations, hot.newton_iterations);
            cases.insert(
                name.into(),
                json!({"cold_s": t_cold, "cold_newton_iterations": cold.newton_iterations, "warm_s": t_warm, "warm_newton_iterations": hot.newton_iterations,
                "warm_used": hot.scenes.values().all(|s| s.cost.warm_started), "omega_cold": oc, "omega_warm": ow, "speed_up": t_cold / t_warm}),
            );
        }
        out.insert(preset.into(), Value::Object(cases));
    }
    // a sweep along α: the free scene of α + 5° ramped to failure, cold (from 0) or from the
    // α design's state at 90 % of its limit pressure (solved there on the new design, then the
    // path onwards to the pressure maximum)
    {
        use twistopt::scene::{continue_to_failure, equilibrium, run_pressure, SceneModel};
        let opts = SceneOptions::new(MeshSpec::preset("sweep").expect("preset"), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
        let (ga, gb) = (
            ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 20.0, 300.0), RangePolicy::TableI).expect("valid"),
            ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 20.0, 305.0), RangePolicy::TableI).expect("valid"),
        );
        let ra = run_pressure(&ga, &opts, SceneKind::Free, &[150.0]).expect("scene");
        let pa = 0.9 * ra.steps.last().map(|s| s.p_kpa).unwrap_or(0.0);
        let sma = SceneModel::build(&ga, &opts, SceneKind::Free).expect("scene");
        let qa = equilibrium(&sma, &opts, pa, None).q;
        let t = Instant::now();
        let cold = run_pressure(&gb, &opts, SceneKind::Free, &[150.0]).expect("scene");
        let t_cold = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let smb = SceneModel::build(&gb, &opts, SceneKind::Free).expect("scene");
        let eq = equilibrium(&smb, &opts, pa, Some((&qa, pa)));
        let lim = continue_to_failure(&smb, &opts, &eq, 150.0);
        let t_warm = t.elapsed().as_secs_f64();
        let p_cold = cold.steps.last().map(|s| s.p_kpa);
        let p_warm = lim.found().map(|e| e.record.p_kpa);
        let its_warm = eq.newton_iterations + lim.newton_iterations();
        println!(
            "warm_start sweep along α (free, sweep preset): cold {t_cold:.1} s ({} its, p_lim {p_cold:?}), warm {t_warm:.1} s ({its_warm} its, p_lim {p_warm:?}, warm used {})",
            cold.newton_iterations, eq.warm_started
        );
        out.insert(
            "sweep_along_alpha".into(),
            json!({"description": "free scene of (5√3, 20, 305°) ramped to its pressure maximum at the `sweep` preset: cold from 0, or warm from (5√3, 20, 300°)'s state at 90 % of that design's limit", "cold_s": t_cold, "cold_newton_iterations": cold.newton_iterations, "p_limit_cold_kPa": p_cold,
                   "warm_s": t_warm, "warm_newton_iterations": its_warm, "p_limit_warm_kPa": p_warm, "warm_used": eq.warm_started, "speed_up": t_cold / t_warm}),
        );
    }
    merge(
        "warm_start",
        json!({
            "description": "an optimiser evaluation (free + blocked to 36.27 kPa, adjoint gradients, limit search) of a design next to the energy optimum r = 5√3, l = 20, α = 360°, from a cold start and warm-started from the optimum's converged states (solved at their pressure on the new design, then the path onwards); release build, all cores",
            "presets": Value::Object(out),
        }),
    );
}

/// Fill and Cholesky time of the sector tangent (free scene, paper example, 5 kPa) under faer's
/// AMD and METIS nested dissection, from the sweep mesh to a fine 96x32x3 one.
fn ordering(geom: &ActuatorGeometry) {
    use twistopt::scene::{SceneKind, SceneModel, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
    use twistopt_solver::material::NeoHookean;
    use twistopt_solver::model::Ordering;
    let mut entries = serde_json::Map::new();
    for mesh in ["sweep", "default", "fine", "96x32x3"] {
        let spec = MeshSpec::parse(mesh).or_else(|_| MeshSpec::preset(mesh)).expect("mesh");
        let opts = SceneOptions::new(spec, NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).expect("material").into());
        let mut sm = SceneModel::build(geom, &opts, SceneKind::Free).expect("scene");
        let q = vec![0.0; sm.model.n_reduced()];
        let mut row = serde_json::Map::new();
        for ord in [Ordering::Amd, Ordering::NestedDissection] {
            let t = Instant::now();
            if sm.model.set_ordering(ord).is_err() {
                continue;
            }
            let t_sym = t.elapsed().as_secs_f64();
            // the tangent's values are stored in the ordering's (pre-permuted) pattern: assemble
            // after the analysis
            let k = sm.model.assemble(&q, &sm.loads(5.0, 0.0), true).expect("assembly").k.expect("tangent");
            sm.model.factor(&k).expect("the tangent at 5 kPa is positive definite");
            let runs = if mesh == "96x32x3" { 1 } else { 3 };
            let (tf, _, _) = time(runs, || {
                std::hint::black_box(sm.model.factor(&k).ok());
            });
            println!("ordering {mesh:8} {ord:?}: dofs {}, L nnz {}, symbolic {:.0} ms, Cholesky {:.0} ms", sm.model.n_reduced(), sm.model.factor_nnz(), t_sym * 1e3, tf * 1e3);
            row.insert(format!("{ord:?}"), json!({"factor_nnz": sm.model.factor_nnz(), "symbolic_ms": t_sym * 1e3, "cholesky_ms": tf * 1e3}));
        }
        row.insert("dofs".into(), json!(sm.model.n_reduced()));
        row.insert("tangent_nnz_upper".into(), json!(sm.model.nnz()));
        entries.insert(mesh.into(), Value::Object(row));
    }
    merge(
        "ordering",
        json!({
            "description": "fill-reducing ordering of the Hex27 sector tangent (free scene, paper example, 5 kPa): factor nnz, symbolic analysis and numeric Cholesky (median of 3; 1 at 96x32x3) under faer's AMD and METIS nested dissection; release build, all cores",
            "threads": rayon::current_num_threads(),
            "meshes": Value::Object(entries),
        }),
    );
}

fn mesh_generation(geom: &ActuatorGeometry) {
    let geom = geom.clone();
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
    merge("mesh_generation", section);
}
