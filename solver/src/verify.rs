//! Verification problems (the benchmarks of /work/shared/benchmarks): model builders and drivers
//! shared by the tests and the element-comparison example. Units mm, N, MPa.
//!
//! * B5 Cook's membrane: plane strain as one element through z with u_z = 0 at every node, dead
//!   vertical traction on the x = 48 edge (consistent nodal forces).
//! * B3/B6 torsion of the 17/20 tube: an axial slice of the full ring whose end faces are tied by
//!   a helical periodicity constraint (see [`torsion_slice`]).
//! * B2 closed-end inflation of the 17/20 tube: a quarter slice with symmetry rollers, bottom
//!   u_z = 0, top u_z tied to one free DOF (see [`inflation_slice`]).

use crate::continuation::{ramp, ContinuationOptions, PathEnd};
use crate::dofmap::{Constraints, DofSpec, Periodic, RigidBody};
use crate::element::Formulation;
use crate::material::NeoHookean;
use crate::mesh::ElementKind;
use crate::meshgen;
use crate::model::{resultant, Loads, Model, ModelError};
use crate::surface;

/// Shear modulus of Hei-Cast 8400 (MPa).
pub const MU: f64 = 0.34;
/// Inner and outer radius of the benchmark tube (mm).
pub const TUBE_A: f64 = 17.0;
pub const TUBE_B: f64 = 20.0;

fn check_slice(n_theta: usize, n_r: usize, h: f64, theta_multiple: usize) -> Result<(), ModelError> {
    if n_theta == 0 || !n_theta.is_multiple_of(theta_multiple) || n_theta > 4096 || n_r == 0 || n_r > 256 || !(h.is_finite() && h > 0.0) {
        return Err(ModelError::Mesh(format!("tube slice: {n_theta} elements around (a positive multiple of {theta_multiple}), {n_r} through the wall, height {h}")));
    }
    Ok(())
}

/// Result of a Cook's membrane run.
#[derive(Clone, Debug)]
pub struct CookResult {
    /// Tip displacement at C = (48, 60).
    pub ux: f64,
    pub uy: f64,
    pub dofs: usize,
    pub status: PathEnd,
    pub steps: usize,
    pub newton_iterations: usize,
}

/// B5: Cook's membrane on an n × n mesh (one element through the unit thickness), μ = 0.34,
/// κ/μ given, dead traction 0.0264983 N/mm² (total 0.423973 N per mm of thickness).
pub fn cook_membrane(form: Formulation, n: usize, kappa_over_mu: f64, traction: f64) -> Result<CookResult, ModelError> {
    if n == 0 || n > 512 {
        return Err(ModelError::Mesh(format!("Cook's membrane: {n} elements per side (1..=512)")));
    }
    let mesh = meshgen::structured(form.kind, n, n, 1, |p| {
        let x = 48.0 * p[0];
        let yb = 44.0 * p[0];
        let yt = 44.0 + 16.0 * p[0];
        [x, yb + p[1] * (yt - yb), p[2]]
    });
    let mut cons = Constraints::default();
    for &node in &mesh.node_sets["xmin"] {
        for c in 0..3 {
            cons.prescribed.push((node, c, 0.0));
        }
    }
    // plane strain: u_z = 0 everywhere (duplicates of the clamped nodes are ignored)
    for node in 0..mesh.n_nodes() {
        cons.prescribed.push((node, 2, 0.0));
    }
    let forces = surface::dead_traction(&mesh, &mesh.face_sets["xmax"], [0.0, traction, 0.0]).ok_or_else(|| ModelError::Mesh("non-finite traction".into()))?;
    let tip = (0..mesh.n_nodes())
        .find(|&i| (mesh.nodes[i][0] - 48.0).abs() < 1e-9 && (mesh.nodes[i][1] - 60.0).abs() < 1e-9 && mesh.nodes[i][2].abs() < 1e-12)
        .ok_or_else(|| ModelError::Mesh("tip node not found".into()))?;
    let mat = NeoHookean::with_ratio(MU, kappa_over_mu).map_err(|e| ModelError::Mesh(e.to_string()))?;
    let model = Model::new(mesh, form, mat.into(), &cons, None)?;
    let from = Loads::zero(&model);
    let mut to = Loads::zero(&model);
    to.nodal_forces = forces;
    let q0 = vec![0.0; model.n_reduced()];
    let opts = ContinuationOptions { initial: 0.05, max: 0.1, ..ContinuationOptions::default() };
    let res = ramp(&model, &q0, &from, &to, &opts);
    let u = res.assembled.as_ref().map(|a| a.u[tip]).unwrap_or([f64::NAN; 3]);
    Ok(CookResult { ux: u[0], uy: u[1], dofs: model.n_reduced(), status: res.end, steps: res.stats.steps, newton_iterations: res.stats.newton_iterations })
}

/// The torsion slice of the 17/20 tube: the full ring (n_theta × n_r elements, one element of
/// height h along z), its bottom face (Z = 0) and top face (Z = h) tied by the helical
/// periodicity x_top = Q(α) x_bottom + (h + s) e_z.
///
/// Why this is the exact BVP of B3: the semi-inverse solution r = r(R), θ = Θ + ψZ, z = λ_z Z is
/// helically invariant — translating by h along the axis while rotating by ψh maps it onto itself —
/// so it satisfies this constraint with α = ψh and s = (λ_z − 1)h, and the slice is one period of
/// the infinitely long tube (no ends, no end effects). Radial motion is free everywhere, so the
/// cross-section can contract as the exact solution requires (a bonded rigid end plate would not
/// allow it). The other constraints only remove rigid motions the exact solution does not have:
/// u_z = 0 on the bottom face (the cross-section stays plane, which holds for r = r(R),
/// z = λ_z Z), and u_y = 0 at the bottom inner nodes at θ = 0 and 180°, u_x = 0 at θ = 90°
/// (no rigid translation/rotation in the plane; the exact u is radial on the bottom face). The end
/// loads are the nodal forces of the top face's nodes (the force the rest of the tube would
/// exert there): M = Σ (x × f)_z, N = Σ f_z.
pub struct TorsionSlice {
    pub model: Model,
    pub h: f64,
    pub top: Vec<usize>,
    /// an inner-radius node (for a) and an outer-radius node (for b) of the bottom face
    pub inner: usize,
    pub outer: usize,
    /// prescribed slot of the twist α
    pub twist_slot: usize,
}

/// Build the torsion slice. `free_length`: the axial shift s is a free DOF (N = 0) instead of 0.
pub fn torsion_slice(kind: ElementKind, form: Formulation, n_theta: usize, n_r: usize, h: f64, kappa_over_mu: f64, free_length: bool) -> Result<TorsionSlice, ModelError> {
    check_slice(n_theta, n_r, h, 4)?;
    let mesh = meshgen::ring(kind, n_theta, 1, n_r, TUBE_A, TUBE_B, h);
    let bottom = mesh.node_sets["ymin"].clone();
    let top = mesh.node_sets["ymax"].clone();
    let tol = 1e-9 * TUBE_B;
    let mut pairs = Vec::new();
    for &a in &bottom {
        let p = mesh.nodes[a];
        let b = top.iter().copied().find(|&b| (mesh.nodes[b][0] - p[0]).abs() < tol && (mesh.nodes[b][1] - p[1]).abs() < tol).ok_or_else(|| ModelError::Mesh("unmatched periodic node".into()))?;
        pairs.push((a, b));
    }
    let find =
        |x: f64, y: f64| bottom.iter().copied().find(|&n| (mesh.nodes[n][0] - x).abs() < tol && (mesh.nodes[n][1] - y).abs() < tol).ok_or_else(|| ModelError::Mesh("reference node not found".into()));
    let (n0, n90, n180) = (find(TUBE_A, 0.0)?, find(0.0, TUBE_A)?, find(-TUBE_A, 0.0)?);
    let outer = find(TUBE_B, 0.0)?;
    let mut cons = Constraints::default();
    cons.prescribe_set(&bottom, &[2], 0.0);
    cons.prescribed.push((n0, 1, 0.0));
    cons.prescribed.push((n90, 0, 0.0));
    cons.prescribed.push((n180, 1, 0.0));
    cons.periodic.push(Periodic { pairs, angle0: 0.0, twist: 0.0, shift: if free_length { DofSpec::Free } else { DofSpec::Prescribed(0.0) } });
    let mat = NeoHookean::with_ratio(MU, kappa_over_mu).map_err(|e| ModelError::Mesh(e.to_string()))?;
    let model = Model::new(mesh, form, mat.into(), &cons, None)?;
    let twist_slot = model.dofs.periodic_dofs[0].0;
    Ok(TorsionSlice { model, h, top, inner: n0, outer, twist_slot })
}

/// Work done along a path.
#[derive(Clone, Copy, Debug, Default)]
pub struct PathCost {
    pub steps: usize,
    /// Newton iterations, failed attempts included
    pub newton_iterations: usize,
}

/// One converged torsion state.
#[derive(Clone, Debug)]
pub struct TorsionPoint {
    pub angle_deg: f64,
    /// moment about the axis and axial force on the end face (N·mm, N)
    pub m: f64,
    pub n: f64,
    /// deformed inner and outer radius, axial stretch
    pub a: f64,
    pub b: f64,
    pub lz: f64,
}

impl TorsionSlice {
    /// Twist to each of `angles_deg` (end rotation over the length `length`) in turn, from the
    /// unloaded state; returns the converged states (stops at the first failure).
    pub fn twist(&self, length: f64, angles_deg: &[f64], opts: &ContinuationOptions) -> (Vec<TorsionPoint>, PathEnd, PathCost) {
        let mut cost = PathCost::default();
        let m = &self.model;
        let mut q = vec![0.0; m.n_reduced()];
        let mut from = Loads::zero(m);
        let mut out = Vec::new();
        for &ang in angles_deg {
            let mut to = from.clone();
            to.presc[self.twist_slot] = ang.to_radians() / length * self.h;
            let res = ramp(m, &q, &from, &to, opts);
            cost.steps += res.stats.steps;
            cost.newton_iterations += res.stats.newton_iterations;
            if res.end != PathEnd::Completed {
                return (out, res.end, cost);
            }
            if let Some(a) = &res.assembled {
                out.push(self.point(ang, a));
            }
            q = res.q;
            from = to;
        }
        (out, PathEnd::Completed, cost)
    }

    /// End loads and radii of an assembled state.
    pub fn point(&self, angle_deg: f64, a: &crate::model::Assembled) -> TorsionPoint {
        let x0 = &self.model.mesh.nodes;
        let (f, mo) = resultant(&self.top, x0, &a.u, &a.r_full, [0.0; 3]);
        let rad = |n: usize| {
            let x = [x0[n][0] + a.u[n][0], x0[n][1] + a.u[n][1]];
            (x[0] * x[0] + x[1] * x[1]).sqrt()
        };
        let top0 = self.top[0];
        let lz = 1.0 + (a.u[top0][2]) / self.h;
        TorsionPoint { angle_deg, m: mo[2], n: f[2], a: rad(self.inner), b: rad(self.outer), lz }
    }
}

/// The closed-end inflation slice of the 17/20 tube: a quarter (θ ∈ [0, 90°], n_theta × n_r
/// elements, one element of height h along z) with symmetry rollers on the cut planes
/// (u_y = 0 at θ = 0, u_x = 0 at θ = 90°), bottom face u_z = 0, top face u_z tied to one free
/// DOF (a rigid body with mask z, only the z translation free), cavity = the inner face set whose
/// top cap edge carries p·A_cap onto that DOF: the closed tube with free ends (F_red = 0), exact
/// for the long-tube solution r = r(R), z = λ_z Z.
pub struct InflationSlice {
    pub model: Model,
    pub h: f64,
    /// bottom inner node at θ = 0 (for a), top node (for λ_z)
    pub inner: usize,
    pub top: usize,
}

pub fn inflation_slice(form: Formulation, n_theta: usize, n_r: usize, h: f64, kappa_over_mu: f64) -> Result<InflationSlice, ModelError> {
    check_slice(n_theta, n_r, h, 1)?;
    let mesh = meshgen::tube(form.kind, n_theta, 1, n_r, TUBE_A, TUBE_B, (0.0, std::f64::consts::FRAC_PI_2), h);
    let mut cons = Constraints::default();
    cons.prescribe_set(&mesh.node_sets["xmin"], &[1], 0.0);
    cons.prescribe_set(&mesh.node_sets["xmax"], &[0], 0.0);
    cons.prescribe_set(&mesh.node_sets["ymin"], &[2], 0.0);
    let top_nodes = mesh.node_sets["ymax"].clone();
    let p0 = DofSpec::Prescribed(0.0);
    cons.bodies.push(RigidBody { name: "top".into(), reference: [0.0, 0.0, h], nodes: top_nodes.clone(), mask: [false, false, true], dofs: [p0, p0, DofSpec::Free, p0, p0, p0] });
    let tol = 1e-9 * TUBE_B;
    let inner = (0..mesh.n_nodes())
        .find(|&n| (mesh.nodes[n][0] - TUBE_A).abs() < tol && mesh.nodes[n][1].abs() < tol && mesh.nodes[n][2].abs() < tol)
        .ok_or_else(|| ModelError::Mesh("inner node not found".into()))?;
    let cavity = mesh.face_sets["zmin"].clone();
    let mat = NeoHookean::with_ratio(MU, kappa_over_mu).map_err(|e| ModelError::Mesh(e.to_string()))?;
    let model = Model::new(mesh, form, mat.into(), &cons, Some(&cavity))?;
    Ok(InflationSlice { model, h, inner, top: top_nodes[0] })
}

impl InflationSlice {
    /// (λ_A = a/A, λ_z) of an assembled state.
    pub fn stretches(&self, a: &crate::model::Assembled) -> (f64, f64) {
        let x = self.model.mesh.nodes[self.inner][0] + a.u[self.inner][0];
        (x / TUBE_A, 1.0 + a.u[self.top][2] / self.h)
    }
    /// Cavity volume of the slice for given stretches: π a² λ_z h / 4.
    pub fn volume_of(&self, la: f64, lz: f64) -> f64 {
        std::f64::consts::PI * (la * TUBE_A).powi(2) * lz * self.h / 4.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let q2 = Formulation::standard(ElementKind::Hex27);
        assert!(cook_membrane(q2, 0, 5000.0, 0.02).is_err());
        assert!(cook_membrane(q2, 2, f64::NAN, 0.02).is_err());
        assert!(cook_membrane(q2, 2, 5000.0, f64::INFINITY).is_err());
        assert!(torsion_slice(ElementKind::Hex27, q2, 6, 1, 2.0, 1000.0, false).is_err());
        assert!(torsion_slice(ElementKind::Hex27, q2, 8, 0, 2.0, 1000.0, false).is_err());
        assert!(torsion_slice(ElementKind::Hex27, q2, 8, 1, -1.0, 1000.0, false).is_err());
        assert!(inflation_slice(q2, 4, 1, f64::NAN, 1000.0).is_err());
        // a non-finite twist is a failed path, not a NaN result
        let s = torsion_slice(ElementKind::Hex27, q2, 8, 1, 2.0, 1000.0, false).unwrap();
        let (pts, status, _) = s.twist(40.0, &[f64::NAN], &ContinuationOptions::default());
        assert!(pts.is_empty() && matches!(status, PathEnd::Failed(_)), "{status:?}");
        // functional (volume) control without a cavity falls back to load control (this coarse
        // slice is singular unloaded: a clean failure, no NaN); with a non-finite end volume the
        // path fails cleanly
        let m = &s.model;
        let o = ContinuationOptions { start_control: crate::continuation::Control::Functional, ..Default::default() };
        let r = ramp(m, &vec![0.0; m.n_reduced()], &Loads::zero(m), &Loads::zero(m), &o);
        assert!(r.q.iter().all(|v| v.is_finite()), "{:?}", r.end);
        let f = inflation_slice(q2, 4, 1, 2.0, 1000.0).unwrap();
        let m = &f.model;
        let mut to = Loads::zero(m);
        to.pressure = 0.01;
        let o = ContinuationOptions { start_control: crate::continuation::Control::Functional, control_end: Some(f64::NAN), ..Default::default() };
        let r = ramp(m, &vec![0.0; m.n_reduced()], &Loads::zero(m), &to, &o);
        assert!(matches!(r.end, PathEnd::Failed(_)) || r.lam.is_finite(), "{:?}", r.end);
        assert!(r.q.iter().all(|v| v.is_finite()));
    }
}
