//! The reduced-order model: its residual and tangent are the full model's projected on the
//! basis (all elements at weight 1), its tangent is the exact Hessian of the hyper-reduced energy
//! (any sample), and a model trained on a few coarse designs reproduces the full paths.
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::{SceneKind, SceneModel, SceneOptions, DEFAULT_KAPPA_OVER_MU, MU_HEICAST_MPA};
use twistopt_solver::continuation::PathModel;
use twistopt_solver::material::NeoHookean;
use twistopt_solver::rom::{Basis, Frame, Rom, RomPath, Sample, Truncation};

fn opts(preset: &str) -> SceneOptions {
    SceneOptions::new(MeshSpec::preset(preset).unwrap(), NeoHookean::with_ratio(MU_HEICAST_MPA, DEFAULT_KAPPA_OVER_MU).unwrap().into())
}

/// A random orthonormal basis of k columns (Gram–Schmidt of seeded pseudo-random vectors with a
/// smooth component, so that the states it spans stay admissible at small amplitudes).
fn random_basis(n: usize, k: usize, seed: u64) -> Basis {
    let mut s = seed;
    let mut rnd = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    let snaps: Vec<Vec<f64>> = (0..k).map(|_| (0..n).map(|_| rnd()).collect()).collect();
    Basis::pod(&snaps, Truncation::Modes(k)).unwrap()
}

fn scene(kind: SceneKind) -> (SceneModel, SceneOptions) {
    let o = opts("coarse");
    let g = ActuatorGeometry::new(&Design::new(12.0, 14.0, 200.0), RangePolicy::TableI).unwrap();
    (SceneModel::build(&g, &o, kind).unwrap(), o)
}

#[test]
fn reduced_residual_and_tangent_are_the_projected_full_ones() {
    // the Piola frame's reference: another design's mesh
    let reference = {
        let g = ActuatorGeometry::new(&Design::new(9.0, 17.0, 300.0), RangePolicy::TableI).unwrap();
        SceneModel::build(&g, &opts("coarse"), SceneKind::Free).unwrap().model.mesh.nodes.clone()
    };
    for (kind, frame) in [(SceneKind::Free, Frame::Cartesian), (SceneKind::Blocked, Frame::Cartesian), (SceneKind::Free, Frame::Cylindrical), (SceneKind::Blocked, Frame::Piola)] {
        let (sm, _) = scene(kind);
        let model = &sm.model;
        let nn = model.dofs.n_nodal();
        let mut basis = random_basis(nn, 6, 7);
        basis.frame = frame;
        if frame == Frame::Piola {
            basis.reference = reference.clone();
        }
        let sample = Sample::all(model.mesh.n_elements());
        let from = sm.loads(0.0, 0.0);
        let to = sm.loads(30.0, 0.0);
        let rp = RomPath::new(model, &basis, &sample, from.clone(), to.clone(), sm.functionals()).unwrap();
        let m = rp.dim();
        assert_eq!(m, 6 + model.n_reduced() - nn);
        // in every frame, projecting a lifted state gives it back
        let zt: Vec<f64> = (0..m).map(|i| (i as f64 * 0.37).sin()).collect();
        let back = rp.red.project(&rp.red.lift(&zt));
        assert!(zt.iter().zip(&back).all(|(a, b)| (a - b).abs() < 1e-12), "{frame:?}: project(lift(z)) != z");
        // a state with a rotation of the cap (free scene) and modal amplitudes of 0.05 mm
        let mut z = vec![0.05, -0.03, 0.02, 0.04, -0.01, 0.03];
        z.extend((6..m).map(|i| 0.01 * (i as f64 - 5.0)));
        let lam = 0.6;
        let ev = rp.eval(&z, lam, true, None).unwrap();
        let q = rp.red.lift(&z);
        let loads = rp.loads(lam);
        let a = model.assemble(&q, &loads, true).unwrap();
        // Φᵀ r and Φᵀ K Φ with Φ = diag(V, I)
        let phi_col = |j: usize| -> Vec<f64> {
            let mut e = vec![0.0; m];
            e[j] = 1.0;
            rp.red.lift(&e)
        };
        let rscale = a.r.iter().map(|x| x.abs()).fold(0.0, f64::max);
        let kv = a.k.as_ref().unwrap();
        let kcols: Vec<Vec<f64>> = (0..m).map(|j| model.sym_matvec(kv, &phi_col(j))).collect();
        let kmax = kcols.iter().flatten().map(|x| x.abs()).fold(0.0, f64::max);
        for i in 0..m {
            let pi = phi_col(i);
            let ri: f64 = pi.iter().zip(&a.r).map(|(x, y)| x * y).sum();
            assert!((ev.r[i] - ri).abs() <= 1e-10 * rscale, "{kind:?} r[{i}]: rom {} full {}", ev.r[i], ri);
            for j in 0..m {
                let kij: f64 = pi.iter().zip(&kcols[j]).map(|(x, y)| x * y).sum();
                let k = ev.k.as_ref().unwrap()[(i, j)];
                assert!((k - kij).abs() <= 1e-9 * kmax, "{kind:?} K[{i},{j}]: rom {k} full {kij}");
            }
        }
        // the volume gradient and the outputs are the full model's
        let (vol, dvol) = ev.control.clone().unwrap();
        assert!((vol - a.volume).abs() <= 1e-12 * a.volume.abs());
        for i in 0..m {
            let di: f64 = phi_col(i).iter().zip(&a.dvol).map(|(x, y)| x * y).sum();
            assert!((dvol[i] - di).abs() <= 1e-10 * a.dvol.iter().map(|x| x.abs()).fold(0.0, f64::max));
        }
        let out = rp.outputs(&z, lam, &ev);
        let st = twistopt_solver::adjoint::State::from_assembly(model, &a);
        for (f, o) in sm.functionals().iter().zip(&out) {
            let full = f.eval(model, &st).unwrap();
            assert!((o - full).abs() <= 1e-9 * full.abs().max(1.0), "{kind:?} {f:?}: rom {o} full {full}");
        }
    }
}

#[test]
fn hyper_reduced_tangent_is_the_derivative_of_its_residual() {
    let (sm, _) = scene(SceneKind::Free);
    let model = &sm.model;
    let basis = random_basis(model.dofs.n_nodal(), 5, 11);
    // every third element with weights 2.5–3.5
    let elements: Vec<usize> = (0..model.mesh.n_elements()).step_by(3).collect();
    let weights: Vec<f64> = elements.iter().map(|&e| 2.5 + (e % 5) as f64 * 0.25).collect();
    let sample = Sample { elements, weights, points: Vec::new() };
    let rp = RomPath::new(model, &basis, &sample, sm.loads(0.0, 0.0), sm.loads(30.0, 0.0), Vec::new()).unwrap();
    let m = rp.dim();
    let z: Vec<f64> = (0..m).map(|i| 0.04 * ((i * 37 % 11) as f64 / 11.0 - 0.4)).collect();
    let k = rp.eval(&z, 0.7, true, None).unwrap().k.unwrap();
    assert_tangent_is_central_difference("hyper-reduced", k, &z, |z| rp.eval(z, 0.7, false, None).unwrap().r);
    let _ = Rom::new(basis, sample);
}

/// The lagged cavity Hessian (`RomPath::set_cavity_hessian_lag`): residuals are the exact
/// ones everywhere; the path follower's tangent is the exact one where the cavity Hessian is
/// computed, reuses it within the tolerance (differing from the exact tangent by the cavity
/// term's change, nonzero and small) and is exact again beyond it; `evaluate` is always exact.
#[test]
fn lagged_cavity_hessian_keeps_residuals_exact() {
    let (sm, _) = scene(SceneKind::Free);
    let model = &sm.model;
    let basis = random_basis(model.dofs.n_nodal(), 6, 5);
    let sample = Sample::all(model.mesh.n_elements());
    let exact = RomPath::new(model, &basis, &sample, sm.loads(0.0, 0.0), sm.loads(40.0, 0.0), Vec::new()).unwrap();
    let mut lag = RomPath::new(model, &basis, &sample, sm.loads(0.0, 0.0), sm.loads(40.0, 0.0), Vec::new()).unwrap();
    lag.set_cavity_hessian_lag(1e-2);
    let m = exact.dim();
    let z1: Vec<f64> = (0..m).map(|i| 0.05 * ((i * 31 % 7) as f64 / 7.0 - 0.3)).collect();
    let scaled = |f: f64| z1.iter().map(|v| v * f).collect::<Vec<f64>>();
    fn kdiff<K: std::ops::Index<(usize, usize), Output = f64>>(a: &K, b: &K, m: usize) -> f64 {
        let d = (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).map(|(i, j)| (a[(i, j)] - b[(i, j)]).abs()).fold(0.0, f64::max);
        let s = (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).map(|(i, j)| b[(i, j)].abs()).fold(0.0, f64::max);
        d / s
    }
    for (label, z, expect_lagged) in [("first", scaled(1.0), false), ("near", scaled(1.005), true), ("far", scaled(1.2), false)] {
        let el = lag.eval(&z, 0.8, true, None).unwrap();
        let ex = exact.eval(&z, 0.8, true, None).unwrap();
        let rs = ex.r.iter().map(|v| v.abs()).fold(0.0, f64::max);
        for (a, b) in el.r.iter().zip(&ex.r) {
            assert!((a - b).abs() <= 1e-12 * rs, "{label}: residual {a} vs exact {b}");
        }
        let d = kdiff(el.k.as_ref().unwrap(), ex.k.as_ref().unwrap(), m);
        if expect_lagged {
            assert!(d > 1e-12 && d < 1e-2, "{label}: lagged tangent off the exact one by {d:.3e} (expected small, nonzero)");
        } else {
            assert!(d <= 1e-12, "{label}: tangent off the exact one by {d:.3e}");
        }
        // the public evaluation is exact
        let (_, k, ..) = lag.evaluate(&z, &lag.loads(0.8), true).unwrap();
        assert!(kdiff(k.as_ref().unwrap(), ex.k.as_ref().unwrap(), m) <= 1e-12, "{label}: evaluate is not exact");
    }
}

/// A reduced pressure space spanning every element's own pressure space (Ψ = I) is the full
/// model's element-wise condensation: the same residual and tangent. A smaller space (the
/// constant pressure plus a few smooth fields) has a tangent that is the derivative of its
/// residual, symmetric.
#[test]
fn reduced_pressure_space_is_consistent() {
    use twistopt_solver::rom::PressureBasis;
    let (sm, _) = scene(SceneKind::Blocked);
    let model = &sm.model;
    let ne = model.mesh.n_elements();
    let np = 4;
    let basis = random_basis(model.dofs.n_nodal(), 5, 3);
    let sample = Sample::all(ne);
    let z: Vec<f64> = {
        let m = basis.k + model.n_reduced() - basis.n;
        (0..m).map(|i| 0.03 * ((i * 29 % 13) as f64 / 13.0 - 0.45)).collect()
    };
    let eval = |b: &Basis, s: &Sample, z: &[f64], k: bool| {
        let rp = RomPath::new(model, b, s, sm.loads(0.0, 0.0), sm.loads(30.0, 0.0), Vec::new()).unwrap();
        rp.eval(z, 0.6, k, None).unwrap()
    };
    let local = eval(&basis, &sample, &z, true);
    let mut full_space = basis.clone();
    let n = ne * np;
    full_space.pressure = Some(PressureBasis { np, kp: n, psi: (0..n * n).map(|i| if i / n == i % n { 1.0 } else { 0.0 }).collect(), singular_values: Vec::new() });
    let global = eval(&full_space, &sample, &z, true);
    let rs = local.r.iter().map(|x| x.abs()).fold(0.0, f64::max);
    for (a, b) in local.r.iter().zip(&global.r) {
        assert!((a - b).abs() <= 1e-9 * rs, "residual: element-wise {a} vs global full space {b}");
    }
    let (kl, kg) = (local.k.unwrap(), global.k.unwrap());
    let m = kl.nrows();
    let ks = (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).map(|(i, j)| kl[(i, j)].abs()).fold(0.0, f64::max);
    for i in 0..m {
        for j in 0..m {
            assert!((kl[(i, j)] - kg[(i, j)]).abs() <= 1e-8 * ks, "K[{i},{j}]: element-wise {} vs global full space {}", kl[(i, j)], kg[(i, j)]);
        }
    }
    // three pressure modes: constant, and two smooth fields of the element index; every other
    // element weighted 2
    let kp = 3;
    let mut psi = vec![0.0; n * kp];
    for e in 0..ne {
        psi[(e * np) * kp] = 1.0;
        psi[(e * np) * kp + 1] = (e as f64 * 0.3).sin();
        psi[(e * np + 1) * kp + 2] = (e as f64 * 0.2).cos();
        psi[(e * np + 3) * kp + 2] = 0.5;
    }
    let mut small = basis.clone();
    small.pressure = Some(PressureBasis { np, kp, psi, singular_values: Vec::new() });
    let elements: Vec<usize> = (0..ne).step_by(2).collect();
    let weights = vec![2.0; elements.len()];
    let s2 = Sample { elements, weights, points: Vec::new() };
    let k = eval(&small, &s2, &z, true).k.unwrap();
    assert_tangent_is_central_difference("reduced pressure", k, &z, |z| eval(&small, &s2, z, false).r);
}

/// A quadrature-level sample of every point at weight 1 is the element-level model with every
/// element (residual, tangent, volume, outputs, reactions); a sparse point sample with uneven
/// weights has a tangent that is the derivative of its residual (also on the rigid bodies'
/// coordinates: the blocked scene), symmetric; without a pressure space it is refused.
#[test]
fn quadrature_level_sample_is_consistent() {
    use twistopt_solver::rom::PressureBasis;
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        let (sm, _) = scene(kind);
        let model = &sm.model;
        let ne = model.mesh.n_elements();
        let ngp = model.form.rule().weights.len();
        let np = 4;
        let mut basis = random_basis(model.dofs.n_nodal(), 6, 5);
        let n = ne * np;
        let kp = 3;
        let mut psi = vec![0.0; n * kp];
        for e in 0..ne {
            psi[(e * np) * kp] = 1.0;
            psi[(e * np) * kp + 1] = (e as f64 * 0.3).sin();
            psi[(e * np + 2) * kp + 2] = 0.7;
        }
        let plain = basis.clone();
        basis.pressure = Some(PressureBasis { np, kp, psi, singular_values: Vec::new() });
        let m = basis.k + model.n_reduced() - basis.n;
        let z: Vec<f64> = (0..m).map(|i| 0.03 * ((i * 31 % 17) as f64 / 17.0 - 0.45)).collect();
        fn path<'a>(sm: &'a SceneModel, basis: &'a Basis, s: &'a Sample) -> RomPath<'a> {
            RomPath::new(&sm.model, basis, s, sm.loads(0.0, 0.0), sm.loads(30.0, 0.0), sm.functionals()).unwrap()
        }
        let (el, pt) = (Sample::all(ne), Sample::all_points(ne, ngp));
        let (re, rpt) = (path(&sm, &basis, &el), path(&sm, &basis, &pt));
        let (a, b) = (re.eval(&z, 0.6, true, None).unwrap(), rpt.eval(&z, 0.6, true, None).unwrap());
        let rs = a.r.iter().map(|x| x.abs()).fold(0.0, f64::max);
        for (i, (x, y)) in a.r.iter().zip(&b.r).enumerate() {
            assert!((x - y).abs() <= 1e-10 * rs, "{kind:?} r[{i}]: elements {x} vs points {y}");
        }
        let (ka, kb) = (a.k.as_ref().unwrap(), b.k.as_ref().unwrap());
        let ks = (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).map(|(i, j)| ka[(i, j)].abs()).fold(0.0, f64::max);
        for i in 0..m {
            for j in 0..m {
                assert!((ka[(i, j)] - kb[(i, j)]).abs() <= 1e-10 * ks, "{kind:?} K[{i},{j}]: elements {} vs points {}", ka[(i, j)], kb[(i, j)]);
            }
        }
        assert!((a.scale - b.scale).abs() <= 1e-10 * a.scale, "{kind:?} scale {} vs {}", a.scale, b.scale);
        assert_eq!(a.control.as_ref().map(|c| c.0), b.control.as_ref().map(|c| c.0));
        let (oa, ob) = (re.outputs(&z, 0.6, &a), rpt.outputs(&z, 0.6, &b));
        for (x, y) in oa.iter().zip(&ob) {
            assert!((x - y).abs() <= 1e-9 * x.abs().max(1e-9), "{kind:?} output: elements {x} vs points {y}");
        }
        // every 7th point, weights 5–9
        let idx: Vec<usize> = (0..ne * ngp).step_by(7).collect();
        let sparse = Sample { elements: idx.iter().map(|i| i / ngp).collect(), weights: idx.iter().map(|i| 5.0 + (i % 5) as f64).collect(), points: idx.iter().map(|i| i % ngp).collect() };
        let rs_ = path(&sm, &basis, &sparse);
        let k = rs_.eval(&z, 0.6, true, None).unwrap().k.unwrap();
        assert_tangent_is_central_difference(&format!("{kind:?} points"), k, &z, |z| rs_.eval(z, 0.6, false, None).unwrap().r);
        assert!(RomPath::new(model, &plain, &sparse, sm.loads(0.0, 0.0), sm.loads(30.0, 0.0), Vec::new()).is_err());
    }
}

/// k equals the central difference (step 1e-6) of the residual at z, to 1e-6 of its largest
/// entry, and is symmetric to 1e-10.
fn assert_tangent_is_central_difference(label: &str, k: impl std::ops::Index<(usize, usize), Output = f64>, z: &[f64], residual: impl Fn(&[f64]) -> Vec<f64>) {
    let m = z.len();
    let mut kmax = 0.0f64;
    for i in 0..m {
        for j in 0..m {
            kmax = kmax.max(k[(i, j)].abs());
        }
    }
    let h = 1e-6;
    for j in 0..m {
        let mut zp = z.to_vec();
        zp[j] += h;
        let mut zm = z.to_vec();
        zm[j] -= h;
        let (rp_, rm_) = (residual(&zp), residual(&zm));
        for i in 0..m {
            let fd = (rp_[i] - rm_[i]) / (2.0 * h);
            assert!((fd - k[(i, j)]).abs() <= 1e-6 * kmax, "{label}: K[{i},{j}] = {} vs central difference {fd}", k[(i, j)]);
            assert!((k[(i, j)] - k[(j, i)]).abs() <= 1e-10 * kmax, "{label}: tangent not symmetric at ({i},{j})");
        }
    }
}

/// `twistopt rom train` end to end on the coarse mesh: the model directory (manifest + basis),
/// a resumed training that reads its cached ramps, an evaluation and a sweep at ROM fidelity
/// (results say so), the reduced gradients against finite differences, the fallback, validation
/// and calibration, and the refusals (another mesh, a design outside the box).
#[test]
fn rom_train_then_evaluate_and_sweep_at_rom_fidelity() {
    use std::process::Command;
    let bin = || Command::new(env!("CARGO_BIN_EXE_twistopt"));
    let dir = std::env::temp_dir().join(format!("twistopt-rom-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let romdir = dir.join("rom");
    let train = || {
        bin()
            .args(["rom", "train", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "8", "--modes", "24", "--pressure-modes", "5", "--out"])
            .arg(&romdir)
            .output()
            .unwrap()
    };
    let out = train();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(romdir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["format_version"], 1);
    assert_eq!(m["k"], 24);
    assert_eq!(m["kp"], 5);
    assert_eq!(m["report"]["training_designs"].as_array().unwrap().len(), 8);
    assert!(m["train_cpu_s"].as_f64().unwrap() > 0.0);
    let n = m["n"].as_u64().unwrap() as usize;
    let rows = m["report"]["elements"].as_u64().unwrap() as usize * m["np"].as_u64().unwrap() as usize;
    assert_eq!(std::fs::metadata(romdir.join("basis.bin")).unwrap().len() as usize, 8 * (n * 24 + rows * 5 + 3 * m["reference_nodes"].as_u64().unwrap() as usize));
    // re-running reads the cached ramps (16 of them) and writes the same basis
    let basis = std::fs::read(romdir.join("basis.bin")).unwrap();
    let out = train();
    assert!(out.status.success());
    assert_eq!(String::from_utf8_lossy(&out.stderr).matches(": cached").count(), 16, "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(std::fs::read(romdir.join("basis.bin")).unwrap(), basis);
    // evaluate at ROM fidelity (a training design: the box's corner r = 5√3, l = 20, α = 360°)
    let rom_set = format!("fidelity.rom={}", toml::Value::String(romdir.display().to_string()));
    let ev = |extra: &[&str], out_dir: &str| {
        bin()
            .args([
                "evaluate",
                "problems/energy-density.toml",
                "--set",
                "fidelity.preset=\"coarse\"",
                "--set",
                &rom_set,
                "--set",
                "design.r_mm=8.660254037844386",
                "--set",
                "design.l_mm=20",
                "--set",
                "design.alpha_deg=360",
            ])
            .args(extra)
            .arg("--out")
            .arg(dir.join(out_dir))
            .output()
            .unwrap()
    };
    let out = ev(&[], "ev");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("ev/result.json")).unwrap()).unwrap();
    assert_eq!(r["fidelity"]["model"], "reduced", "{}", r["fidelity"]);
    assert_eq!(r["fidelity"]["modes"], 24);
    for sc in ["free", "blocked"] {
        let ind = r["scenes"][sc]["rom_indicator"].as_f64();
        assert!(ind.is_some_and(|v| v.is_finite() && v > 0.0), "{sc}: rom_indicator {:?}", r["scenes"][sc]["rom_indicator"]);
    }
    let om = r["omega_J_m3"].as_f64().unwrap();
    assert!(om.is_finite() && om > 0.0, "{om}");
    // the same design on the full model: a training design is reproduced closely
    let full = bin()
        .args([
            "evaluate",
            "problems/energy-density.toml",
            "--set",
            "fidelity.preset=\"coarse\"",
            "--set",
            "design.r_mm=8.660254037844386",
            "--set",
            "design.l_mm=20",
            "--set",
            "design.alpha_deg=360",
            "--out",
        ])
        .arg(dir.join("full"))
        .output()
        .unwrap();
    assert!(full.status.success());
    let rf: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("full/result.json")).unwrap()).unwrap();
    assert_eq!(rf["fidelity"]["model"], "full");
    assert!(rf["scenes"]["free"]["rom_indicator"].is_null());
    let of = rf["omega_J_m3"].as_f64().unwrap();
    assert!((om - of).abs() <= 0.05 * of, "Ω reduced {om} vs full {of}");
    // refusals: another mesh, a design outside the training box
    let out = ev(&["--set", "fidelity.preset=\"default\""], "ev2");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("trained for another model"), "{}", String::from_utf8_lossy(&out.stderr));
    let out = ev(&["--set", "design.range=\"extended\"", "--set", "design.l_mm=9.5"], "ev3");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside the reduced model's training box"), "{}", String::from_utf8_lossy(&out.stderr));
    // … and a scene it was not trained on (the pure-twist scenes hold the cap's axial
    // translation: their limit point needs modes the free and blocked ramps do not hold)
    assert_eq!(m["options"]["scenes"], serde_json::json!(["free", "blocked"]));
    let out = ev(&["--set", "scenes.run=[\"pure-twist\", \"pure-twist-blocked\"]"], "ev4");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not on 'pure-twist'"), "{}", String::from_utf8_lossy(&out.stderr));
    let out = bin().args(["rom", "train", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--scenes", "pure-twist", "--out"]).arg(dir.join("rom-bad")).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("must hold a mode's twist and torque scenes"), "{}", String::from_utf8_lossy(&out.stderr));
    // gradient at ROM fidelity: the reduced sensitivities of every scene functional to r, l, α,
    // p and μ equal central differences of the reduced model's re-solved equilibria
    let out = bin()
        .args(["gradient", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--set", &rom_set, "--pressure", "20", "--check-fd", "--fd-steps", "1e-4,1e-5", "--out"])
        .arg(dir.join("gr"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let gr: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("gr/gradient.json")).unwrap()).unwrap();
    assert_eq!(gr["model"]["model"], "reduced", "{}", gr["model"]);
    for sc in ["free", "blocked"] {
        assert_eq!(gr["scenes"][sc]["status"], "converged", "{}", gr["scenes"][sc]);
        assert_eq!(gr["scenes"][sc]["gradients"]["cavity_volume_mm3"].as_object().unwrap().len(), 5, "r, l, α, p, μ");
    }
    let fd_err = gr["max_rel_error"].as_f64().unwrap();
    assert!(fd_err < 1e-5, "reduced gradients vs finite differences: {fd_err:e}");
    // a staged optimisation whose first stage runs on the reduced model (its gradients), the
    // second on the full model of the same mesh from the first stage's best design
    let stages = format!("optimise.stages=[{{preset=\"coarse\", rom={}, max_evaluations=20}}, {{preset=\"coarse\", max_evaluations=20}}]", toml::Value::String(romdir.display().to_string()));
    let out = bin()
        .args(["optimise", "problems/max-torque.toml", "--set", "load.p_max_kPa=20", "--set", "optimise.variables=[\"alpha_deg\", \"l_mm\"]", "--set"])
        .arg(if cfg!(feature = "nlopt") { "optimise.optimisers=[\"slsqp\"]" } else { "optimise.optimisers=[\"sqp\"]" })
        .args(["--set", "optimise.starts=1", "--set", "optimise.max_evaluations=40", "--set", &stages, "--out"])
        .arg(dir.join("opt"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let best: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("opt/best.json")).unwrap()).unwrap();
    let run = &best["runs"][0];
    assert!(run["status"].as_str().unwrap().contains("(reduced)"), "{run}");
    let by_stage: Vec<u64> = run["evaluations_by_stage"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert!(by_stage.len() == 2 && by_stage.iter().all(|n| *n >= 1), "{by_stage:?}");
    let hist: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("opt/history.json")).unwrap()).unwrap();
    let evs = hist["runs"][0]["evaluations"].as_array().unwrap();
    let n0 = by_stage[0] as usize;
    let stage0_best = evs[..n0].iter().filter(|e| e["feasible"] == true).map(|e| e["objective"].as_f64().unwrap()).fold(0.0, f64::max);
    // the reduced stage's best and the full model's answer at the end agree within 5 %
    assert!((best["objective"].as_f64().unwrap() - stage0_best).abs() <= 0.05 * stage0_best, "full {} vs reduced {stage0_best}", best["objective"]);
    // the limit pressure's reduced sensitivity (null-vector formula) against central differences
    // of the reduced model's limit pressures at l ± 2e-3 mm
    {
        use twistopt::problem::Problem;
        let problem = Problem::load(std::path::Path::new("problems/energy-density.toml"), &["fidelity.preset=\"coarse\"".into(), rom_set.clone()]).unwrap();
        let v = problem.validate().unwrap();
        let o = problem.scene_options(&v);
        assert!(o.rom.is_some());
        let at = |l: f64| {
            let g = ActuatorGeometry::new(&Design::new(12.0, l, 200.0), RangePolicy::TableI).unwrap();
            twistopt::gradient::scene_gradient(&g, &o, SceneKind::Free, 20.0, 20.0, None, Some(150.0)).unwrap()
        };
        let base = at(14.0);
        let pl = base.p_limit_kpa.expect("a pressure maximum below 150 kPa");
        let d = base.p_limit_gradient["l_mm"];
        let h = 2e-3;
        let fd = (at(14.0 + h).p_limit_kpa.unwrap() - at(14.0 - h).p_limit_kpa.unwrap()) / (2.0 * h);
        assert!((d - fd).abs() <= 1e-3 * fd.abs().max(1e-2), "dp_lim/dl at p_lim = {pl:.3} kPa: reduced {d} vs central difference {fd}");
    }
    // the fallback: a threshold of 0 sends both scenes back to the full model, which then
    // answers exactly as the full model does; a threshold no scene reaches keeps the reduced one
    let out = ev(&["--set", "fidelity.rom_fallback=0"], "fb");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rb: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("fb/result.json")).unwrap()).unwrap();
    for sc in ["free", "blocked"] {
        let why = rb["scenes"][sc]["rom_fallback"].as_str().unwrap_or_default();
        assert!(why.contains("indicator"), "{sc}: {}", rb["scenes"][sc]);
        assert_eq!(rb["scenes"][sc]["steps"], rf["scenes"][sc]["steps"], "{sc}: the full model's steps");
    }
    assert_eq!(rb["omega_J_m3"], rf["omega_J_m3"]);
    let out = ev(&["--set", "fidelity.rom_fallback=1e9"], "nofb");
    assert!(out.status.success());
    let rn: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("nofb/result.json")).unwrap()).unwrap();
    assert!(rn["scenes"]["free"]["rom_fallback"].is_null() && rn["omega_J_m3"] == r["omega_J_m3"], "{}", rn["scenes"]["free"]);
    let out = ev(&["--set", "fidelity.rom_fallback=-1"], "fbneg");
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("rom_fallback"), "{}", String::from_utf8_lossy(&out.stderr));
    // rom validate on 2 random designs: rows and summary; a re-run resumes (nothing to do);
    // --calibrate records the threshold in the manifest, which evaluations then use
    let val = |extra: &[&str]| {
        bin().args(["rom", "validate", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "2", "--seed", "3", "--rom"]).arg(&romdir).args(extra).output().unwrap()
    };
    let out = val(&[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let vdir = romdir.join("validation-seed3");
    let rows: Vec<serde_json::Value> = std::fs::read_to_string(vdir.join("rows.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(rows.len(), 2);
    for row in &rows {
        assert!(row["cpu_s_rom"].as_f64().unwrap() > 0.0 && row["cpu_s_full"].as_f64().unwrap() > 0.0, "{row}");
        assert!(row["indicator_rom"].as_array().unwrap().iter().all(|v| v.as_f64().is_some_and(|x| x > 0.0)), "{row}");
    }
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(vdir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["rows_done"], 2);
    let out = val(&["--calibrate"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("2 already done"), "{}", String::from_utf8_lossy(&out.stdout));
    assert_eq!(std::fs::read_to_string(vdir.join("rows.jsonl")).unwrap().lines().count(), 2, "resumed, not re-run");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(romdir.join("manifest.json")).unwrap()).unwrap();
    let t = m["fallback_indicator"].as_f64().unwrap();
    assert!(t.is_finite() && t > 0.0, "{}", m["fallback_calibration"]);
    assert_eq!(m["fallback_calibration"]["rows"], 2);
    // another seed or model in the same directory is refused
    let out = bin()
        .args(["rom", "validate", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "2", "--seed", "4", "--rom"])
        .arg(&romdir)
        .arg("--out")
        .arg(&vdir)
        .output()
        .unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("another model, seed"), "{}", String::from_utf8_lossy(&out.stderr));
    // rom check: random designs and pressures of either sign on the reduced model alone, every
    // scene a status with its cause (vacuum is refused as a model error), no problem
    let out =
        bin().args(["rom", "check", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "4", "--seed", "2", "--p-min", "-30", "--rom"]).arg(&romdir).output().unwrap();
    assert!(out.status.success(), "{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    let cs: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(romdir.join("check-seed2/summary.json")).unwrap()).unwrap();
    assert_eq!(cs["rows"], 4);
    assert_eq!(cs["problems"], 0, "{cs}");
    let crow: Vec<serde_json::Value> = std::fs::read_to_string(romdir.join("check-seed2/rows.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    for r in &crow {
        for sc in ["free", "blocked"] {
            let st = r["scenes"][sc]["status"].as_str().unwrap();
            assert!(st == "completed" || !r["scenes"][sc]["cause"].as_str().unwrap().is_empty(), "{r}");
        }
    }
    // a quadrature-level model on the same cached ramps: its sample is of points, it evaluates,
    // and its validation reuses the element model's full-order rows (checked, marked)
    let ptdir = dir.join("rom-points");
    std::fs::create_dir_all(&ptdir).unwrap();
    let copy = Command::new("cp").arg("-r").arg(romdir.join("ramps")).arg(&ptdir).status().unwrap();
    assert!(copy.success());
    let out = bin()
        .args([
            "rom",
            "train",
            "problems/energy-density.toml",
            "--set",
            "fidelity.preset=\"coarse\"",
            "--designs",
            "8",
            "--modes",
            "24",
            "--pressure-modes",
            "5",
            "--tau",
            "0.02",
            "--points",
            "--ecsw-snapshots",
            "40",
            "--out",
        ])
        .arg(&ptdir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(String::from_utf8_lossy(&out.stderr).matches(": cached").count(), 16);
    let mp: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(ptdir.join("manifest.json")).unwrap()).unwrap();
    let npts = mp["sample"]["points"].as_array().map_or(0, |a| a.len());
    let all_points = mp["report"]["elements"].as_u64().unwrap() as usize * 27;
    assert!(npts > 0 && npts < all_points, "{npts} of {all_points} points sampled");
    assert_eq!(mp["report"]["sample_points"].as_u64(), Some(npts as u64));
    let out = bin()
        .args(["rom", "validate", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "2", "--seed", "3", "--full-from"])
        .arg(vdir.join("rows.jsonl"))
        .arg("--rom")
        .arg(&ptdir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let prow: Vec<serde_json::Value> = std::fs::read_to_string(ptdir.join("validation-seed3/rows.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(prow.len(), 2);
    for (a, b) in prow.iter().zip(&rows) {
        assert_eq!(a["full_reused"], true, "{a}");
        assert_eq!(a["omega_full"], b["omega_full"]);
        // (this 8-design, 24-mode model is too coarse to be accurate: the points model is
        // compared with the element model of the same basis, whose error it shares)
        let om_r = a["omega_rom"].as_f64().unwrap();
        assert!(om_r.is_finite() && om_r >= 0.0, "points model: Ω {om_r}");
        for sc in ["free", "blocked"] {
            let (pe, pp) = (b[format!("p_end_{sc}_rom")].as_f64().unwrap(), a[format!("p_end_{sc}_rom")].as_f64().unwrap());
            assert!((pp - pe).abs() <= 0.05 * pe, "points model, {sc}: p_end {pp} vs the element model's {pe}");
        }
    }
    // reusing rows of other designs is refused
    let out = bin()
        .args(["rom", "validate", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "2", "--seed", "5", "--full-from"])
        .arg(vdir.join("rows.jsonl"))
        .arg("--rom")
        .arg(&ptdir)
        .output()
        .unwrap();
    let bad: Vec<serde_json::Value> = std::fs::read_to_string(ptdir.join("validation-seed5/rows.jsonl")).unwrap_or_default().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert!(out.status.success() && bad.iter().all(|r| r["error"].as_str().is_some_and(|e| e.contains("another design"))), "{}", String::from_utf8_lossy(&out.stderr));
    // a sweep at ROM fidelity records it in its manifest, and its fallbacks in the summary
    let out =
        bin().args(["sweep", "problems/sweep-example.toml", "--set", "load.p_max_kPa=80", "--fidelity"]).arg(format!("rom:{}", romdir.display())).arg("--out").arg(dir.join("sw")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let sm = std::fs::read_to_string(dir.join("sw/summary.json")).unwrap();
    assert!(sm.contains("rom:"), "{sm}");
    let smj: serde_json::Value = serde_json::from_str(&sm).unwrap();
    assert!(smj["rom_fallbacks"]["designs"].as_u64().is_some(), "{sm}");
    // warm starts along α (sweep.warm_start): each design's ramps start from its predecessor's
    // states near their ends; the rows agree with cold ramps to the path tolerances, for far
    // fewer Newton iterations
    let line = |warm: bool, out: &str| {
        let o = bin()
            .args(["sweep", "problems/sweep-example.toml", "--threads", "1", "--set", "sweep.l_mm=[14]", "--set", "sweep.alpha_deg=[100, 102, 104, 106, 108]", "--set", "fidelity.rom_fallback=inf"])
            .args(["--set", &format!("sweep.warm_start={warm}"), "--fidelity"])
            .arg(format!("rom:{}", romdir.display()))
            .arg("--out")
            .arg(dir.join(out))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut rows: Vec<serde_json::Value> = std::fs::read_to_string(dir.join(out).join("results.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        rows.sort_by_key(|r| r["index"].as_u64());
        rows
    };
    let (cold, warm) = (line(false, "line-cold"), line(true, "line-warm"));
    let its = |rows: &[serde_json::Value]| rows.iter().flat_map(|r| r["scenes"].as_object().unwrap().values().map(|s| s["newton_iterations"].as_u64().unwrap())).sum::<u64>();
    assert_eq!(cold.len(), 5);
    for (c, w) in cold.iter().zip(&warm) {
        assert_eq!(c["status"], w["status"]);
        for key in ["omega_J_m3", "theta_max_deg", "tau_max_Nm", "p_omega_kPa"] {
            let (a, b) = (c[key].as_f64().unwrap(), w[key].as_f64().unwrap());
            assert!((a - b).abs() <= 2e-3 * a.abs(), "design {}: {key} cold {a} warm {b}", c["index"]);
        }
    }
    let warmed = warm.iter().skip(1).filter(|r| r["scenes"].as_object().unwrap().values().all(|s| s["warm_start_kPa"].as_f64().is_some())).count();
    assert!(warmed >= 3, "{warmed} of 4 designs warm-started both scenes");
    assert!(warm[0]["scenes"]["free"]["warm_start_kPa"].is_null());
    assert!(3 * its(&warm) < 2 * its(&cold), "Newton iterations warm {} cold {}", its(&warm), its(&cold));
    // from the third design on, each start is moved on along the line (its predecessor's state
    // plus how that state changed from the design before): a third of the cold iterations at
    // most (measured on the Table-I sweep: 16 against 100 per design)
    let (w3, c3) = (its(&warm[2..]), its(&cold[2..]));
    assert!(3 * w3 < c3, "Newton iterations of designs 3-5: warm {w3} cold {c3}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The reduced model's sensitivities (direct method on the reduced tangent,
/// `RomPath::direct_sensitivity`) of every scene functional to a design parameter (through the
/// meshes of l ± h) and to the pressure equal the central differences of the reduced
/// equilibria re-solved at the perturbed inputs.
#[test]
fn reduced_sensitivities_equal_finite_differences_of_reduced_equilibria() {
    use twistopt_solver::continuation::correct;
    use twistopt_solver::solve::NewtonOptions;
    let o = opts("coarse");
    let (r0, l0, a0) = (12.0, 14.0, 200.0);
    let build = |l: f64, kind: SceneKind| SceneModel::build(&ActuatorGeometry::new(&Design::new(r0, l, a0), RangePolicy::TableI).unwrap(), &o, kind).unwrap();
    for kind in [SceneKind::Free, SceneKind::Blocked] {
        let sm = build(l0, kind);
        let nn = sm.model.dofs.n_nodal();
        // a basis of the full model's own states at 4, 8, 12 kPa and two smooth extra directions
        let g = ActuatorGeometry::new(&Design::new(r0, l0, a0), RangePolicy::TableI).unwrap();
        let full = twistopt::scene::run_pressure(&g, &o, kind, &[4.0, 8.0, 12.0]).unwrap();
        let mut snaps: Vec<Vec<f64>> = full.states.iter().filter(|q| q.iter().any(|v| *v != 0.0)).map(|q| q[..nn].to_vec()).collect();
        snaps.extend((1..3).map(|j| (0..nn).map(|i| 1e-3 * ((i * j) as f64 * 0.01).sin()).collect::<Vec<f64>>()));
        let basis = Basis::pod(&snaps, Truncation::Modes(5)).unwrap();
        let sample = Sample::all(sm.model.mesh.n_elements());
        let p_to = 12.0;
        fn path<'a>(m: &'a SceneModel, basis: &'a Basis, sample: &'a Sample, p_to: f64) -> RomPath<'a> {
            RomPath::new(&m.model, basis, sample, m.loads(0.0, 0.0), m.loads(p_to, 0.0), m.functionals()).unwrap()
        }
        let path = |m| path(m, &basis, &sample, p_to);
        let rp = path(&sm);
        let newton = NewtonOptions { rtol: 1e-13, ..NewtonOptions::default() };
        let solve = |p: &RomPath, z0: &[f64], lam: f64| -> Vec<f64> {
            correct(p, z0, lam, None, &newton, false, None, false).unwrap_or_else(|e| panic!("{kind:?}: reduced Newton failed at λ {lam}: {:?}", e.0)).q
        };
        let lam = 0.5;
        let z0 = vec![0.0; rp.dim()];
        let zs = solve(&rp, &z0, lam);
        let k = rp.eval(&zs, lam, true, None).unwrap().k.unwrap();
        let factor = rp.factor(&k, false).unwrap();
        // the design parameter l (mm)
        let h = 1e-5;
        let (sp, sm_) = (build(l0 + h, kind), build(l0 - h, kind));
        let (pp, pm) = (path(&sp), path(&sm_));
        let (dz, df) = rp.direct_sensitivity(&zs, &factor, (&pp, lam), (&pm, lam), h).unwrap();
        assert_eq!(dz.len(), rp.dim());
        let big = 2e-3;
        let (bp, bm) = (build(l0 + big, kind), build(l0 - big, kind));
        let (qp_, qm_) = (path(&bp), path(&bm));
        let fp = qp_.functional_values(&solve(&qp_, &zs, lam), lam).unwrap();
        let fm = qm_.functional_values(&solve(&qm_, &zs, lam), lam).unwrap();
        // the pressure (per kPa: λ ± h_λ with dp/dλ = p_to)
        let hl = 1e-6;
        let (_, dfp) = rp.direct_sensitivity(&zs, &factor, (&rp, lam + hl), (&rp, lam - hl), hl * p_to).unwrap();
        let bl = 2e-4;
        let gp = rp.functional_values(&solve(&rp, &zs, lam + bl), lam + bl).unwrap();
        let gm = rp.functional_values(&solve(&rp, &zs, lam - bl), lam - bl).unwrap();
        let f0 = rp.functional_values(&zs, lam).unwrap();
        // (the reaction of a free DOF is zero at every equilibrium: nothing to compare)
        for (i, f) in sm.functionals().iter().enumerate() {
            if kind == SceneKind::Free && matches!(f, twistopt_solver::adjoint::Functional::BodyReaction { dof: 5, .. }) {
                continue;
            }
            for (what, direct, fd) in [("l_mm", df[i], (fp[i] - fm[i]) / (2.0 * big)), ("p_kPa", dfp[i], (gp[i] - gm[i]) / (2.0 * bl * p_to))] {
                assert!(direct.is_finite() && fd.is_finite(), "{kind:?} {f:?} {what}: {direct} vs {fd}");
                assert!(
                    (direct - fd).abs() <= 5e-5 * fd.abs().max(direct.abs()) + 1e-8 * f0[i].abs().max(1e-3),
                    "{kind:?} {f:?} d/d{what}: direct {direct} vs central difference of re-solved equilibria {fd}"
                );
            }
        }
    }
}

/// The reduced pressure space holds the element-wise constant field exactly, whatever the
/// snapshots: the reduced dilatation (det F's projection on the space) is then 1 at the
/// reference state. Snapshots whose constant parts alternate in sign over the elements, as the
/// pure-twist scenes' pressures do, gave a space without it: every state read as inverted.
#[test]
fn pressure_basis_holds_the_element_constant_field() {
    use twistopt_solver::rom::PressureBasis;
    let (np, ne) = (4, 6);
    let snaps: Vec<Vec<f64>> = (0..5).map(|s| (0..ne * np).map(|i| ((i / np) as f64 - 2.5) * ((1 + s) as f64 * (1 + i) as f64).sin()).collect()).collect();
    let pb = PressureBasis::pod(&snaps, np, Truncation::Modes(3)).unwrap();
    assert_eq!(pb.kp, 3);
    let col = |j: usize| -> Vec<f64> { (0..ne * np).map(|i| pb.psi[i * pb.kp + j]).collect() };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    for a in 0..pb.kp {
        for b in 0..pb.kp {
            let d = dot(&col(a), &col(b));
            assert!((d - if a == b { 1.0 } else { 0.0 }).abs() < 1e-12, "modes {a}, {b}: {d}");
        }
    }
    let ones: Vec<f64> = (0..ne * np).map(|i| if i % np == 0 { 1.0 } else { 0.0 }).collect();
    let mut back = vec![0.0; ne * np];
    for j in 0..pb.kp {
        let c = col(j);
        let a = dot(&c, &ones);
        back.iter_mut().zip(&c).for_each(|(x, y)| *x += a * y);
    }
    let err = back.iter().zip(&ones).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(err < 1e-12, "the constant field's projection is off by {err:e}");
}

/// A reduced model of the pure-twist pair trains (a non-empty sample) and reproduces a training
/// design's full-order pure-twist Ω.
#[test]
fn pure_twist_rom_trains_and_reproduces_a_training_design() {
    use std::process::Command;
    let bin = || Command::new(env!("CARGO_BIN_EXE_twistopt"));
    let dir = std::env::temp_dir().join(format!("twistopt-rom-pure-twist-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let romdir = dir.join("rom");
    let common = ["--set", "fidelity.preset=\"coarse\"", "--set", "load.p_max_kPa=30"];
    let out =
        bin().args(["rom", "train", "problems/pure-twist.toml"]).args(common).args(["--designs", "3", "--modes", "24", "--pressure-modes", "5", "--points", "--out"]).arg(&romdir).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(romdir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["options"]["scenes"], serde_json::json!(["pure-twist", "pure-twist-blocked"]));
    assert!(m["report"]["sample_points"].as_u64().unwrap() > 0, "{}", m["report"]);
    assert_eq!(m["report"]["ecsw_skipped_snapshots"], 0, "{}", m["report"]);
    let rom_set = format!("fidelity.rom={}", toml::Value::String(romdir.display().to_string()));
    let ev = |rom: bool, out_dir: &str| {
        let mut c = bin();
        c.args(["evaluate", "problems/pure-twist.toml"]).args(common);
        if rom {
            c.args(["--set", &rom_set]);
        }
        c.args(["--set", "design.r_mm=8.660254037844386", "--set", "design.l_mm=20", "--set", "design.alpha_deg=360", "--out"]).arg(dir.join(out_dir));
        let out = c.output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(out_dir).join("result.json")).unwrap()).unwrap();
        assert_eq!(r["fidelity"]["model"], if rom { "reduced" } else { "full" });
        r["omega_pure_twist_J_m3"].as_f64().unwrap()
    };
    let (om, of) = (ev(true, "rom-ev"), ev(false, "full-ev"));
    assert!(om.is_finite() && of > 0.0 && (om - of).abs() <= 0.05 * of, "pure-twist Ω reduced {om} vs full {of}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `rom train --enrich`: a round ranks the candidates by the reduced model's indicator, adds
/// the worst to the training designs and retrains; the record says so; a re-run resumes from
/// DIR/enrichment.json and the cached ramps and writes the same model.
#[test]
fn greedy_enrichment_adds_the_worst_candidate_and_resumes() {
    use std::process::Command;
    let bin = || Command::new(env!("CARGO_BIN_EXE_twistopt"));
    let dir = std::env::temp_dir().join(format!("twistopt-rom-enrich-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let romdir = dir.join("rom");
    let train = || {
        let out = bin()
            .args(["rom", "train", "problems/energy-density.toml", "--set", "fidelity.preset=\"coarse\"", "--designs", "8", "--modes", "16", "--pressure-modes", "4", "--p-max", "60"])
            .args(["--enrich", "1", "--enrich-candidates", "3", "--enrich-batch", "1", "--enrich-target", "0", "--enrich-seed", "5", "--out"])
            .arg(&romdir)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(romdir.join("manifest.json")).unwrap()).unwrap();
        (String::from_utf8_lossy(&out.stdout).to_string(), m, std::fs::read(romdir.join("basis.bin")).unwrap())
    };
    let (_, m, basis) = train();
    let e = &m["enrichment"];
    let rounds = e["rounds"].as_array().unwrap();
    assert_eq!(rounds.len(), 1, "{e}");
    assert_eq!(rounds[0]["candidates"], 3);
    let added = rounds[0]["added"].as_array().unwrap();
    assert_eq!(added.len(), 1, "{e}");
    // the worst candidate, and one of the seeded candidates
    assert_eq!(added[0]["indicator"], rounds[0]["indicator"]["max"], "{e}");
    let i = added[0]["candidate"].as_u64().unwrap() as usize;
    let cands = twistopt::rom::random_designs(3, 5);
    assert_eq!(added[0]["design"], serde_json::to_value(&cands[i]).unwrap());
    let trained = m["report"]["training_designs"].as_array().unwrap();
    assert_eq!(trained.len(), 9);
    assert!(trained.contains(&serde_json::to_value(&cands[i]).unwrap()));
    // the final model's indicators over the two remaining candidates
    assert_eq!(e["final"]["candidates"], 2, "{e}");
    assert!(e["final"]["indicator"]["max"].as_f64().unwrap() > 0.0);
    // a re-run resumes: the same model, no new round
    let (stdout, m2, basis2) = train();
    assert!(stdout.contains("resuming after 1 round"), "{stdout}");
    assert_eq!(m2["enrichment"]["rounds"], m["enrichment"]["rounds"]);
    assert!(basis == basis2, "the resumed enrichment wrote another basis");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A pure-twist design at large α whose full ramp stops before 100 kPa: the end mode is a
/// finite unit direction, training appends at most `buckling_modes` of them, and the reduced
/// model trained on that design with them stops where the full one does (within 2 %). (On this
/// coarse one-design model the states alone already span the mode: the case where the end
/// modes matter, held-out designs at the sweep preset, is measured in
/// studies/sweep-table1/rom-k80-pure-twist/README.md.)
#[test]
fn end_modes_let_the_reduced_model_stop_where_the_full_one_does() {
    use twistopt::rom::{end_modes, full_ramp, train_on, TrainOptions};
    use twistopt::scene::ramp_states;
    use twistopt_solver::rom::EcswOptions;
    let o = opts("coarse");
    let d = Design::new(75f64.sqrt(), 18.0, 282.0);
    let kind = SceneKind::PureTwist;
    let full = full_ramp(&d, &o, kind, 100.0, Frame::Cylindrical, &[]).unwrap();
    let p_full = full.states.last().unwrap().0;
    assert!(p_full < 100.0, "the full ramp ends before 100 kPa: {p_full}");
    let base = TrainOptions {
        designs: 1,
        scenes: vec![SceneKind::PureTwist, SceneKind::PureTwistBlocked],
        truncation: Truncation::Modes(24),
        ecsw: EcswOptions { tau: 0.0, max_elements: 0, tangent_directions: 0, points: false, max_snapshots: 0 },
        pressure_modes: Some(Truncation::Modes(5)),
        ..TrainOptions::default()
    };
    // the end mode: a unit direction, largely outside the states' span
    let modes = end_modes(&o, &base, std::slice::from_ref(&full)).unwrap();
    assert_eq!(modes.len(), 1);
    assert!(modes[0].iter().all(|v| v.is_finite()));
    let p_end = |buckling: usize| {
        let t = TrainOptions { buckling_modes: buckling, ..base.clone() };
        let (rom, report) = train_on(&o, &t, std::slice::from_ref(&d), |_| {}).unwrap();
        let added = report.buckling_singular_values.len();
        assert!(added <= buckling && (buckling == 0 || added >= 1), "{:?}", report.buckling_singular_values);
        assert_eq!(report.modes, 24 + report.buckling_singular_values.len());
        let mut ro = o.clone();
        ro.rom = Some(std::sync::Arc::new(rom));
        ro.rom_scenes = t.scenes.clone();
        let g = ActuatorGeometry::new(&d, RangePolicy::TableI).unwrap();
        let sm = SceneModel::build(&g, &ro, kind).unwrap();
        let (states, _) = ramp_states(&sm, &ro, 100.0);
        states.last().unwrap().0
    };
    let with = p_end(2);
    eprintln!("full ramp ends at {p_full:.3} kPa; reduced with end modes at {with:.3} kPa, without at {:.3} kPa", p_end(0));
    assert!((with - p_full).abs() <= 0.02 * p_full, "reduced with end modes ends at {with} kPa, full at {p_full} kPa");
}
