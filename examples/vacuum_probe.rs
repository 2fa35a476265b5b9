//! Where the example design's cavity collapses under vacuum, contact ignored: the free (or
//! blocked) scene followed towards a target pressure without stopping at folds, printing p, θ, V,
//! the self-contact margin (closest cavity nodes of different sectors) and the closest pair of
//! cavity nodes of one sector (reference positions) at each point. Where the path loses
//! stability, the tangent's null vector (inverse iteration) is reported and, with IMP ≠ 0, the
//! path is re-run on the geometry moved by that mode scaled to IMP mm. Exploration for issue 19
//! (studies/vacuum/README.md).
//!
//!   IMP=0.03 cargo run --release --example vacuum_probe -- [MESH=coarse] [P_END_kPa=-68] [free|blocked]
use twistopt::geometry::{ActuatorGeometry, Design, RangePolicy};
use twistopt::meshing::MeshSpec;
use twistopt::scene::*;
use twistopt_solver::continuation::{critical_mode, follow, ContinuationOptions, Control, Eval, EvalFailure, PathModel, PathPoint};
use twistopt_solver::model::SolveError;

/// A path model whose control functional is the amplitude φ·q along a direction (the path then
/// runs with the amplitude prescribed and the pressure free).
const AMP_OFFSET: f64 = 10.0;

struct Amplitude<'a, M: PathModel> {
    inner: &'a M,
    phi: Vec<f64>,
}

impl<'a, M: PathModel> PathModel for Amplitude<'a, M> {
    type Matrix = M::Matrix;
    type Factor = M::Factor;
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn eval(&self, q: &[f64], lam: f64, tangent: bool, lin: Option<&[f64]>) -> Result<Eval<M::Matrix>, EvalFailure> {
        let mut e = self.inner.eval(q, lam, tangent, lin)?;
        // (offset so that the follower's step bounds, relative to the control's size, are not tiny)
        e.control = Some((AMP_OFFSET + q.iter().zip(&self.phi).map(|(a, b)| a * b).sum::<f64>(), self.phi.clone()));
        Ok(e)
    }
    fn factor(&self, k: &M::Matrix, definite: bool) -> Result<M::Factor, SolveError> {
        self.inner.factor(k, definite)
    }
    fn solve(&self, f: &M::Factor, b: &[f64]) -> Result<Vec<f64>, SolveError> {
        self.inner.solve(f, b)
    }
    fn load_rate(&self, q: &[f64], lam: f64, ev: &Eval<M::Matrix>) -> Result<Vec<f64>, EvalFailure> {
        self.inner.load_rate(q, lam, ev)
    }
    fn outputs(&self, q: &[f64], lam: f64, ev: &Eval<M::Matrix>) -> Vec<f64> {
        self.inner.outputs(q, lam, ev)
    }
}

use twistopt_solver::material::NeoHookean;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mesh = args.get(1).cloned().unwrap_or("coarse".into());
    let p_end: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(-68.0);
    let kind = if args.get(3).map(|s| s.as_str()) == Some("blocked") { SceneKind::Blocked } else { SceneKind::Free };
    let geom = ActuatorGeometry::new(&Design::new(5.0 * 3f64.sqrt(), 10.0, 60.0), RangePolicy::TableI).unwrap();
    let spec = MeshSpec::parse(&mesh).or_else(|_| MeshSpec::preset(&mesh)).unwrap();
    let opts = SceneOptions::new(spec, NeoHookean::with_ratio(0.34, 300.0).unwrap().into());
    let sm = SceneModel::build(&geom, &opts, kind).unwrap();
    let lp = sm.path(sm.loads(0.0, 0.0), sm.loads(p_end, 0.0), Some(0.0));
    let o = ContinuationOptions { stop_at_fold: false, start_control: Control::Load, max_steps: 400, ..opts.steps.clone() };
    let q0 = vec![0.0; sm.model.n_reduced()];
    let res = follow(&lp, &q0, 0.0, 1.0, &[], &[], &o);
    println!("end {:?}, {} points", res.end, res.points.len());
    let mut points: Vec<PathPoint> = res.points.clone();
    let imp: f64 = std::env::var("IMP").ok().and_then(|s| s.parse().ok()).unwrap_or(0.03);
    let sm2;
    let lp2;
    let mut lpref = &lp;
    let mut smref = &sm;
    if res.end == twistopt_solver::continuation::PathEnd::Instability && imp != 0.0 {
        // the buckling mode at the last stable point, as a nodal field scaled to max |u| = IMP
        let b = res.points.last().unwrap().clone();
        let phi = critical_mode(&lp, &b.q, b.lam).expect("critical mode");
        let presc = vec![0.0; sm.model.dofs.presc_targets.len()];
        let qs: Vec<f64> = phi.iter().map(|v| v * 1e-7).collect();
        let kin = sm.model.dofs.body_kinematics(&qs, &presc);
        let u = sm.model.dofs.expand(&sm.model.mesh.nodes, &qs, &presc, &kin);
        let umax = u.iter().map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()).fold(0.0f64, f64::max);
        let off: Vec<[f64; 3]> = u.iter().map(|d| [d[0] * imp / umax, d[1] * imp / umax, d[2] * imp / umax]).collect();
        // where the mode is largest
        let (imax, _) = u.iter().enumerate().fold((0, 0.0), |a, (i, d)| {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if n > a.1 {
                (i, n)
            } else {
                a
            }
        });
        let x = sm.model.mesh.nodes[imax];
        println!(
            "buckling mode at p = {:.3} kPa: largest at ({:.2},{:.2},{:.2}) r = {:.2}, direction ({:.2},{:.2},{:.2}); imperfection {imp} mm",
            b.lam * p_end,
            x[0],
            x[1],
            x[2],
            (x[0] * x[0] + x[1] * x[1]).sqrt(),
            off[imax][0] / imp,
            off[imax][1] / imp,
            off[imax][2] / imp
        );
        sm2 = SceneModel::build_perturbed(&geom, &opts, kind, Some(&off)).unwrap();
        lp2 = sm2.path(sm2.loads(0.0, 0.0), sm2.loads(p_end, 0.0), Some(0.0));
        // the imperfect path is smooth: follow it through the loss of stability under volume
        // control (a snap-through under pressure control)
        let o2 = ContinuationOptions { stop_at_instability: false, ..o.clone() };
        let r2 = follow(&lp2, &vec![0.0; sm2.model.n_reduced()], 0.0, 1.0, &[], &[], &o2);
        println!("with the imperfection: end {:?}, {} points", r2.end, r2.points.len());
        points = r2.points;
        if std::env::var_os("AMPLITUDE").is_some() {
            // from the last point where the pressure still rose, on with the mode's amplitude
            // prescribed
            let k = points.iter().enumerate().fold((0, 0.0), |a, (i, p)| if p.lam > a.1 { (i, p.lam) } else { a }).0;
            let start = points[k].clone();
            let am = Amplitude { inner: &lp2, phi: phi.clone() };
            let o3 = ContinuationOptions { start_control: Control::Functional, stop_at_instability: false, stop_at_fold: false, ..o.clone() };
            let r3 = follow(&am, &start.q, start.lam, 1.0, &[], &[], &o3);
            println!("amplitude control from p = {:.3} kPa: end {:?}, {} points", start.lam * p_end, r3.end, r3.points.len());
            points.truncate(k + 1);
            points.extend(r3.points.into_iter().skip(1));
        }
        lpref = &lp2;
        smref = &sm2;
    }
    let (sm, lp) = (smref, lpref);
    for pt in &points {
        let a = sm.model.assemble(&pt.q, &lp.loads(pt.lam), false).unwrap();
        let x0 = &sm.model.mesh.nodes;
        let cur = |n: usize| [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1], x0[n][2] + a.u[n][2]];
        // the closest pair of cavity nodes farther apart than 2t in the reference (one sector)
        let mut best = (f64::INFINITY, 0, 0);
        for (i, &ni) in sm.cavity_nodes.iter().enumerate() {
            for &nj in &sm.cavity_nodes[i + 1..] {
                let d0 = (0..3).map(|c| (x0[ni][c] - x0[nj][c]).powi(2)).sum::<f64>().sqrt();
                if d0 > 6.0 {
                    let d = (0..3).map(|c| (cur(ni)[c] - cur(nj)[c]).powi(2)).sum::<f64>().sqrt();
                    if d < best.0 {
                        best = (d, ni, nj);
                    }
                }
            }
        }
        let r = sm.record(&a, &lp.loads(pt.lam), 0);
        let f = |n: usize| format!("({:.2},{:.2},{:.2})", x0[n][0], x0[n][1], x0[n][2]);
        println!(
            "p {:8.3} kPa θ {:8.3}° V {:9.1} margin {:7.3} | closest same-sector pair {:.3} mm: {} – {}",
            r.p_kpa,
            r.theta_deg,
            r.cavity_volume_mm3,
            pt.outputs.get(OUT_CONTACT).copied().unwrap_or(f64::NAN),
            best.0,
            f(best.1),
            f(best.2)
        );
    }
}
