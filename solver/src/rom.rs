//! Projection-based reduced-order model: a POD basis of the nodal unknowns, element-level ECSW
//! hyper-reduction, and the reduced model as a [`PathModel`], so that the same continuation,
//! fold location and stability checks follow its load paths.
//!
//! **Coordinates.** A model's unknowns q are its free nodal DOFs (numbered first, see
//! [`DofMap::n_nodal`]) followed by the free rigid-body DOFs. The reduced coordinates are
//! z = (a, b): k modal amplitudes and the rigid-body DOFs kept as generalised coordinates, with
//! q = (V a, b) for an orthonormal basis V (n_nodal × k). The basis is a property of the mesh
//! topology, not of one geometry: every model with the same DOF numbering (e.g. each design of a
//! parametric family on one mesh) can use it, each with its own reference coordinates.
//!
//! **Hyper-reduction (ECSW).** The reduced internal force Σ_e J_eᵀ f_e(u_e) is replaced by
//! Σ_{e∈S} w_e J_eᵀ f_e over a sample S with non-negative weights, J_e = ∂u_e/∂z. This is the
//! exact gradient of the weighted energy Σ w_e E_e, so the reduced tangent (its exact Hessian,
//! rigid-rotation curvature included) is symmetric, and positive definite wherever the element
//! energies are convex. The weights come from a non-negative least-squares fit of every element's
//! reduced force over training snapshots ([`ecsw`]), stopped at a relative residual τ.
//!
//! **Cavity.** The cavity volume, its gradient and Hessian are evaluated exactly on every cavity
//! face (no sampling): the pressure load and its load stiffness are those of the full model
//! projected on the basis.
//!
//! **Outputs.** The recorded functionals ([`Functional`]) are evaluated on the reconstructed full
//! displacement field; a reaction of a rigid body is the weighted sum over the sampled elements
//! (the ECSW fit includes every rigid-body DOF's generalised force, prescribed ones too, so that
//! reactions are reproduced).

use crate::adjoint::{BodyState, Functional, State};
use crate::continuation::{elem_eval, Eval, EvalFailure, PathModel};
use crate::dofmap::{BodyDof, BodyKin, Comp};
use crate::element::{self, ElementError};
use crate::model::{Loads, Model, SolveError};
use crate::shape::HexRule;
use crate::surface;
use faer::linalg::solvers::{Llt, PartialPivLu, Solve};
use faer::{Mat, Side};

/// Errors building a reduced model.
#[derive(Debug, thiserror::Error)]
pub enum RomError {
    #[error("no snapshots")]
    NoSnapshots,
    #[error("snapshot {0} has {1} entries, expected {2}")]
    SnapshotSize(usize, usize, usize),
    #[error("non-finite value in snapshot {0}")]
    NonFinite(usize),
    #[error("singular value decomposition failed")]
    Svd,
    #[error("the basis has {0} rows but the model has {1} nodal unknowns")]
    BasisSize(usize, usize),
    #[error("element {0} in the sample, but the mesh has {1} elements")]
    SampleElement(usize, usize),
    #[error("element evaluation failed in a training snapshot: {0}")]
    Element(#[from] ElementError),
}

/// How many POD modes to keep.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Truncation {
    /// The fewest modes whose discarded squared singular values sum to at most this fraction of
    /// the total (the relative squared projection error of the snapshot set), capped at `max`.
    Tail { tol: f64, max: usize },
    /// Exactly this many modes (fewer if the snapshots span fewer).
    Modes(usize),
}

/// The components a basis is expressed in, node by node.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Frame {
    /// the model's own (x, y, z) components
    #[default]
    Cartesian,
    /// (radial, circumferential, axial) components about the z axis at each node's reference
    /// position: a displacement field that rotates with the reference geometry (e.g. the same
    /// motion of two designs whose sections are pre-twisted differently) has the same components
    Cylindrical,
}

/// An orthonormal basis of the nodal unknowns: V (n × k), stored row-major, in the components
/// of `frame` (the model's unknowns are then T V a with T the per-node rotation to the frame,
/// orthonormal too).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Basis {
    #[serde(default)]
    pub frame: Frame,
    pub n: usize,
    pub k: usize,
    /// row-major: entry (i, j) at v[i k + j]
    pub v: Vec<f64>,
    /// every singular value of the snapshot matrix (not only the kept ones)
    pub singular_values: Vec<f64>,
}

impl Basis {
    /// POD of snapshot vectors (each of length n) by a thin SVD.
    pub fn pod(snapshots: &[Vec<f64>], trunc: Truncation) -> Result<Basis, RomError> {
        let m = snapshots.len();
        if m == 0 {
            return Err(RomError::NoSnapshots);
        }
        let n = snapshots[0].len();
        for (i, s) in snapshots.iter().enumerate() {
            if s.len() != n {
                return Err(RomError::SnapshotSize(i, s.len(), n));
            }
            if !s.iter().all(|v| v.is_finite()) {
                return Err(RomError::NonFinite(i));
            }
        }
        let a = Mat::<f64>::from_fn(n, m, |i, j| snapshots[j][i]);
        let svd = a.thin_svd().map_err(|_| RomError::Svd)?;
        let s: Vec<f64> = (0..m.min(n)).map(|i| svd.S()[i]).collect();
        let total: f64 = s.iter().map(|x| x * x).sum();
        let k = match trunc {
            Truncation::Modes(k) => k.min(s.iter().filter(|&&x| x > 1e-14 * s[0]).count()),
            Truncation::Tail { tol, max } => {
                let mut tail = total;
                let mut k = 0;
                while k < s.len() && tail > tol * total && k < max {
                    tail -= s[k] * s[k];
                    k += 1;
                }
                k
            }
        };
        let u = svd.U();
        let mut v = vec![0.0; n * k];
        for i in 0..n {
            for j in 0..k {
                v[i * k + j] = u[(i, j)];
            }
        }
        Ok(Basis { frame: Frame::Cartesian, n, k, v, singular_values: s })
    }

    /// Row i of V.
    #[inline]
    pub fn row(&self, i: usize) -> &[f64] {
        &self.v[i * self.k..(i + 1) * self.k]
    }

    /// Vᵀ x.
    pub fn project(&self, x: &[f64]) -> Vec<f64> {
        let mut a = vec![0.0; self.k];
        for (i, &xi) in x.iter().enumerate().take(self.n) {
            if xi != 0.0 {
                for (aj, vj) in a.iter_mut().zip(self.row(i)) {
                    *aj += vj * xi;
                }
            }
        }
        a
    }

    /// V a.
    pub fn lift(&self, a: &[f64]) -> Vec<f64> {
        (0..self.n).map(|i| self.row(i).iter().zip(a).map(|(v, x)| v * x).sum()).collect()
    }

    /// The first k modes only.
    pub fn truncated(&self, k: usize) -> Basis {
        let k = k.min(self.k);
        let mut v = vec![0.0; self.n * k];
        for i in 0..self.n {
            v[i * k..(i + 1) * k].copy_from_slice(&self.row(i)[..k]);
        }
        Basis { frame: self.frame, n: self.n, k, v, singular_values: self.singular_values.clone() }
    }
}

/// The ECSW element sample: elements and their non-negative weights.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample {
    pub elements: Vec<usize>,
    pub weights: Vec<f64>,
}

impl Sample {
    /// Every element with weight 1 (no hyper-reduction).
    pub fn all(n_elements: usize) -> Sample {
        Sample { elements: (0..n_elements).collect(), weights: vec![1.0; n_elements] }
    }
}

/// The map between a model's unknowns q and the reduced coordinates z = (a, b): q = (Φ a, b)
/// with Φ = T V the basis in the model's components.
#[derive(Clone)]
pub struct Reduction<'a> {
    pub model: &'a Model,
    pub basis: &'a Basis,
    /// Φ (n × k, row-major)
    phi: std::borrow::Cow<'a, [f64]>,
}

/// The per-node rotations T of a frame for a model's nodal unknowns: for each free node, its
/// three unknowns and the 3×3 matrix whose columns are the frame's unit vectors (None for the
/// Cartesian frame).
fn frame_rotations(model: &Model, frame: Frame) -> Option<Vec<([usize; 3], [[f64; 3]; 3])>> {
    match frame {
        Frame::Cartesian => None,
        Frame::Cylindrical => Some(
            model
                .dofs
                .free_nodes()
                .into_iter()
                .map(|(n, k)| {
                    let x = model.mesh.nodes[n];
                    let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
                    let (c, s) = if r > 1e-12 { (x[0] / r, x[1] / r) } else { (1.0, 0.0) };
                    // columns e_r, e_θ, e_z
                    (k, [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                })
                .collect(),
        ),
    }
}

/// The nodal unknowns q (first n_nodal entries of a model state) in the components of `frame`:
/// Tᵀ q (what POD snapshots of a frame are).
pub fn to_frame(model: &Model, frame: Frame, q: &[f64]) -> Vec<f64> {
    let n = model.dofs.n_nodal();
    let mut y = q[..n].to_vec();
    if let Some(rots) = frame_rotations(model, frame) {
        for (k, t) in rots {
            if k.iter().all(|&i| i < n) {
                for c in 0..3 {
                    y[k[c]] = (0..3).map(|r| t[r][c] * q[k[r]]).sum();
                }
            }
        }
    }
    y
}

impl<'a> Reduction<'a> {
    pub fn new(model: &'a Model, basis: &'a Basis) -> Result<Self, RomError> {
        let nn = model.dofs.n_nodal();
        if basis.n != nn {
            return Err(RomError::BasisSize(basis.n, nn));
        }
        let phi = match frame_rotations(model, basis.frame) {
            None => std::borrow::Cow::Borrowed(basis.v.as_slice()),
            Some(rots) => {
                let k = basis.k;
                let mut phi = basis.v.clone();
                for (idx, t) in rots {
                    if idx.iter().any(|&i| i >= nn) {
                        continue;
                    }
                    for j in 0..k {
                        let v = [basis.v[idx[0] * k + j], basis.v[idx[1] * k + j], basis.v[idx[2] * k + j]];
                        for r in 0..3 {
                            phi[idx[r] * k + j] = t[r][0] * v[0] + t[r][1] * v[1] + t[r][2] * v[2];
                        }
                    }
                }
                std::borrow::Cow::Owned(phi)
            }
        };
        Ok(Reduction { model, basis, phi })
    }
    /// Row i of Φ.
    #[inline]
    fn phi_row(&self, i: usize) -> &[f64] {
        let k = self.basis.k;
        &self.phi[i * k..(i + 1) * k]
    }
    /// k + the model's free non-nodal DOFs.
    pub fn dim(&self) -> usize {
        self.basis.k + self.model.n_reduced() - self.basis.n
    }
    /// q(z).
    pub fn lift(&self, z: &[f64]) -> Vec<f64> {
        let k = self.basis.k;
        let mut q: Vec<f64> = (0..self.basis.n).map(|i| self.phi_row(i).iter().zip(&z[..k]).map(|(v, x)| v * x).sum()).collect();
        q.extend_from_slice(&z[k..]);
        q
    }
    /// z of the orthogonal projection of q.
    pub fn project(&self, q: &[f64]) -> Vec<f64> {
        let k = self.basis.k;
        let mut z = vec![0.0; k];
        for (i, &qi) in q.iter().enumerate().take(self.basis.n) {
            if qi != 0.0 {
                for (zj, vj) in z.iter_mut().zip(self.phi_row(i)) {
                    *zj += vj * qi;
                }
            }
        }
        z.extend_from_slice(&q[self.basis.n..]);
        z
    }
    /// Row of ∂q_i/∂z added into `out` with factor `c`.
    #[inline]
    fn add_row(&self, i: usize, c: f64, out: &mut [f64]) {
        if i < self.basis.n {
            for (o, v) in out.iter_mut().zip(self.phi_row(i)) {
                *o += c * v;
            }
        } else {
            out[self.basis.k + i - self.basis.n] += c;
        }
    }
    /// J = ∂u/∂z for the listed nodes (3 rows per node, dim() columns, row-major) at `kin`.
    fn jacobian(&self, nodes: &[usize], kin: &[BodyKin], scratch: &mut Vec<(u32, f64)>, out: &mut Vec<f64>) {
        let m = self.dim();
        out.clear();
        out.resize(3 * nodes.len() * m, 0.0);
        let x0 = &self.model.mesh.nodes;
        for (a, &n) in nodes.iter().enumerate() {
            for c in 0..3 {
                scratch.clear();
                self.model.dofs.row(x0, kin, n, c, scratch);
                let row = &mut out[(3 * a + c) * m..(3 * a + c + 1) * m];
                for &(i, cf) in scratch.iter() {
                    self.add_row(i as usize, cf, row);
                }
            }
        }
    }
}

/// Generalised forces conjugate to each of the 6 DOFs of each rigid body (free or prescribed) of
/// an element force vector, added into `out` (6 per body).
fn body_forces_of(model: &Model, kin: &[BodyKin], nodes: &[usize], f: &[f64], w: f64, out: &mut [f64]) {
    let x0 = &model.mesh.nodes;
    for (a, &n) in nodes.iter().enumerate() {
        for c in 0..3 {
            if let Comp::Rigid(b) = model.dofs.comps[3 * n + c] {
                let b = b as usize;
                let d = crate::dofmap::sub(x0[n], model.dofs.bodies[b].reference);
                let fc = w * f[3 * a + c];
                out[6 * b + c] += fc;
                for k in 0..3 {
                    let m = &kin[b].dr[k][c];
                    out[6 * b + 3 + k] += fc * (m[0] * d[0] + m[1] * d[1] + m[2] * d[2]);
                }
            }
        }
    }
}

/// One training snapshot for [`ecsw`]: a model (its design's geometry) and a state q of it.
pub struct Snapshot<'a> {
    pub model: &'a Model,
    pub q: Vec<f64>,
    pub presc: Vec<f64>,
}

/// Options of the ECSW fit.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct EcswOptions {
    /// stop when ‖G ξ − b‖ ≤ τ ‖b‖
    pub tau: f64,
    /// at most this many elements
    pub max_elements: usize,
    /// Besides the reduced forces, fit the reduced tangent applied to this many fixed
    /// pseudo-random directions per snapshot (each block scaled to unit norm like the forces), so
    /// that the sample reproduces the stiffness (limit points) and not only the forces.
    #[serde(default)]
    pub tangent_directions: usize,
}

/// The result of an ECSW fit.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EcswFit {
    pub sample: Sample,
    /// the relative residual ‖G ξ − b‖ / ‖b‖ reached
    pub residual: f64,
    pub rows: usize,
}

/// Element-level ECSW: for every snapshot, each element's reduced force (J_eᵀ f_e on the modes,
/// and its generalised forces on every rigid-body DOF) at the snapshot's projected state is a
/// column block of G; the weights solve min ‖G ξ − b‖, ξ ≥ 0, b = G 1, by a greedy active-set
/// NNLS (Lawson–Hanson) stopped at ‖G ξ − b‖ ≤ τ ‖b‖. Each snapshot's rows are scaled by its
/// ‖b_s‖, so that every snapshot counts alike. The fit works on the Gram matrix GᵀG (elements ×
/// elements), accumulated snapshot by snapshot ([`EcswAccumulator`]), so that snapshots of many
/// models (designs) need not be held at once.
pub fn ecsw(basis: &Basis, snapshots: &[Snapshot], opts: &EcswOptions) -> Result<EcswFit, RomError> {
    let mut acc = EcswAccumulator::new(opts.tangent_directions);
    acc.add(basis, snapshots)?;
    Ok(acc.fit(opts))
}

/// The normal equations of the ECSW fit, accumulated over snapshots.
#[derive(Clone, Debug, Default)]
pub struct EcswAccumulator {
    /// tangent directions per snapshot (see [`EcswOptions::tangent_directions`])
    pub tangent_directions: usize,
    a: Option<Mat<f64>>,
    c: Vec<f64>,
    bb: f64,
    rows: usize,
}

impl EcswAccumulator {
    pub fn new(tangent_directions: usize) -> Self {
        EcswAccumulator { tangent_directions, ..Default::default() }
    }

    /// Add the rows of these snapshots (all of models with the same mesh).
    pub fn add(&mut self, basis: &Basis, snapshots: &[Snapshot]) -> Result<(), RomError> {
        use rayon::prelude::*;
        let Some(first) = snapshots.first() else { return Ok(()) };
        let ne = first.model.mesh.n_elements();
        let nt = self.tangent_directions;
        let blocks: Vec<Result<(Mat<f64>, Vec<f64>, f64, usize), RomError>> = snapshots.par_iter().map(|s| snapshot_rows(basis, s, nt)).collect();
        for blk in blocks {
            let (g, cs, b2, r) = blk?;
            let a = self.a.get_or_insert_with(|| Mat::<f64>::zeros(ne, ne));
            if a.nrows() != g.nrows() {
                return Err(RomError::SampleElement(g.nrows(), a.nrows()));
            }
            *a += &g;
            if self.c.is_empty() {
                self.c = vec![0.0; ne];
            }
            for (x, y) in self.c.iter_mut().zip(&cs) {
                *x += y;
            }
            self.bb += b2;
            self.rows += r;
        }
        Ok(())
    }

    /// The weights by the τ-stopped NNLS.
    pub fn fit(&self, opts: &EcswOptions) -> EcswFit {
        let Some(a) = &self.a else {
            return EcswFit { sample: Sample { elements: Vec::new(), weights: Vec::new() }, residual: 1.0, rows: 0 };
        };
        let (xi, res) = nnls_gram(a, &self.c, self.bb, opts.tau, opts.max_elements);
        let mut elements = Vec::new();
        let mut weights = Vec::new();
        for (e, &w) in xi.iter().enumerate() {
            if w > 0.0 {
                elements.push(e);
                weights.push(w);
            }
        }
        EcswFit { sample: Sample { elements, weights }, residual: res, rows: self.rows }
    }
}

/// One snapshot's scaled rows of G as their Gram contribution: (GᵀG, Gᵀb, bᵀb, rows). The
/// rows are the element's reduced force on the modes and on every rigid-body DOF, then (with
/// `tangent_dirs`) its reduced tangent times fixed pseudo-random unit directions; each block is
/// scaled by the norm of its sum over the elements.
fn snapshot_rows(basis: &Basis, s: &Snapshot, tangent_dirs: usize) -> Result<(Mat<f64>, Vec<f64>, f64, usize), RomError> {
    let ne = s.model.mesh.n_elements();
    let red = Reduction::new(s.model, basis)?;
    let q = red.lift(&red.project(&s.q));
    let kin = s.model.dofs.body_kinematics(&q, &s.presc);
    let u = s.model.dofs.expand(&s.model.mesh.nodes, &q, &s.presc, &kin);
    let nb = s.model.dofs.bodies.len();
    let m = red.dim();
    let nf = basis.k + 6 * nb;
    let rows = nf + tangent_dirs * m;
    let mut g = Mat::<f64>::zeros(rows, ne);
    let rule = s.model.form.rule();
    let mut scratch = Vec::new();
    let mut jac = Vec::new();
    let mut bf = vec![0.0; 6 * nb];
    // fixed directions (unit vectors of a linear congruential sequence)
    let dirs: Vec<Vec<f64>> = (0..tangent_dirs)
        .map(|t| {
            let mut x = 0x2545F4914F6CDD1Du64.wrapping_add(t as u64 * 7919);
            let v: Vec<f64> = (0..m)
                .map(|_| {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    ((x >> 11) as f64 / (1u64 << 53) as f64) - 0.5
                })
                .collect();
            let n = v.iter().map(|y| y * y).sum::<f64>().sqrt();
            v.into_iter().map(|y| y / n).collect()
        })
        .collect();
    let nn = s.model.mesh.kind.nodes_per_element();
    let nd = 3 * nn;
    let mut ke = vec![0.0; if tangent_dirs > 0 { nd * nd } else { 0 }];
    for e in 0..ne {
        let conn = s.model.mesh.element(e);
        let xe: Vec<[f64; 3]> = conn.iter().map(|&n| s.model.mesh.nodes[n]).collect();
        let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
        let mut f = vec![0.0; nd];
        if tangent_dirs > 0 {
            element::tangent_mixed(&s.model.form, &rule, &s.model.material, &s.model.params, &xe, &ue, None, &mut f, &mut ke)
        } else {
            element::residual(&s.model.form, &rule, &s.model.material, &s.model.params, &xe, &ue, &mut f)
        }
        .map_err(|err| crate::model::relabel(err, e))?;
        red.jacobian(conn, &kin, &mut scratch, &mut jac);
        for (r, fr) in f.iter().enumerate() {
            if *fr != 0.0 {
                for j in 0..basis.k {
                    g[(j, e)] += jac[r * m + j] * fr;
                }
            }
        }
        bf.iter_mut().for_each(|v| *v = 0.0);
        body_forces_of(s.model, &kin, conn, &f, 1.0, &mut bf);
        for (j, v) in bf.iter().enumerate() {
            g[(basis.k + j, e)] = *v;
        }
        if tangent_dirs > 0 {
            let jm = faer::MatRef::from_row_major_slice(&jac, nd, m);
            let km = faer::MatRef::from_row_major_slice(&ke, nd, nd);
            let kz = jm.transpose() * (km * jm);
            for (t, d) in dirs.iter().enumerate() {
                for i in 0..m {
                    g[(nf + t * m + i, e)] = (0..m).map(|j| kz[(i, j)] * d[j]).sum();
                }
            }
        }
    }
    let b: Vec<f64> = (0..rows).map(|i| (0..ne).map(|e| g[(i, e)]).sum()).collect();
    // block scales: forces, then each tangent direction
    let mut blocks = vec![(0, nf)];
    blocks.extend((0..tangent_dirs).map(|t| (nf + t * m, nf + (t + 1) * m)));
    let mut bs = b.clone();
    for (lo, hi) in blocks {
        let n: f64 = b[lo..hi].iter().map(|x| x * x).sum::<f64>().sqrt();
        let sc = if n > 0.0 { 1.0 / n } else { 1.0 };
        for i in lo..hi {
            bs[i] *= sc;
            for j in 0..ne {
                g[(i, j)] *= sc;
            }
        }
    }
    let gram = g.transpose() * &g;
    let c: Vec<f64> = (0..ne).map(|j| (0..rows).map(|i| g[(i, j)] * bs[i]).sum()).collect();
    let bb = bs.iter().map(|x| x * x).sum::<f64>();
    Ok((gram, c, bb, rows))
}

/// Lawson–Hanson NNLS on the normal equations: min ½ξᵀAξ − cᵀξ (A = GᵀG, c = Gᵀb, bb = bᵀb),
/// ξ ≥ 0, stopped when the relative residual √(bb − 2cᵀξ + ξᵀAξ)/√bb ≤ τ or when `max_active`
/// columns are active. Returns ξ and the relative residual.
pub fn nnls_gram(a: &Mat<f64>, c: &[f64], bb: f64, tau: f64, max_active: usize) -> (Vec<f64>, f64) {
    let n = c.len();
    let mut x = vec![0.0; n];
    let mut active: Vec<usize> = Vec::new();
    let resid = |x: &[f64]| {
        let mut ax = 0.0;
        let mut cx = 0.0;
        for i in 0..n {
            if x[i] != 0.0 {
                cx += c[i] * x[i];
                for j in 0..n {
                    if x[j] != 0.0 {
                        ax += x[i] * a[(i, j)] * x[j];
                    }
                }
            }
        }
        ((bb - 2.0 * cx + ax).max(0.0) / bb.max(1e-300)).sqrt()
    };
    let solve_active = |act: &[usize]| -> Option<Vec<f64>> {
        let m = act.len();
        let sub = Mat::<f64>::from_fn(m, m, |i, j| a[(act[i], act[j])]);
        let rhs = Mat::<f64>::from_fn(m, 1, |i, _| c[act[i]]);
        let z = match sub.llt(Side::Lower) {
            Ok(l) => l.solve(&rhs),
            Err(_) => sub.partial_piv_lu().solve(&rhs),
        };
        let z: Vec<f64> = (0..m).map(|i| z[(i, 0)]).collect();
        z.iter().all(|v| v.is_finite()).then_some(z)
    };
    let mut res = 1.0;
    for _outer in 0..(3 * n).max(10) {
        res = resid(&x);
        if res <= tau || active.len() >= max_active {
            break;
        }
        // gradient of the objective's negative: w = c − A x
        let w: Vec<f64> = (0..n).map(|i| c[i] - (0..n).filter(|&j| x[j] != 0.0).map(|j| a[(i, j)] * x[j]).sum::<f64>()).collect();
        let cand = (0..n).filter(|i| !active.contains(i)).max_by(|&i, &j| w[i].total_cmp(&w[j]));
        let Some(j) = cand.filter(|&j| w[j] > 0.0) else { break };
        active.push(j);
        // inner loop: keep the active least-squares solution feasible
        for _inner in 0..(2 * n).max(10) {
            let Some(z) = solve_active(&active) else {
                active.pop();
                break;
            };
            if z.iter().all(|&v| v > 0.0) {
                for (&i, &v) in active.iter().zip(&z) {
                    x[i] = v;
                }
                break;
            }
            // step from x toward z until a weight reaches zero
            let mut alpha = 1.0f64;
            for (&i, &v) in active.iter().zip(&z) {
                if v <= 0.0 {
                    let d = x[i] - v;
                    if d > 0.0 {
                        alpha = alpha.min(x[i] / d);
                    }
                }
            }
            for (&i, &v) in active.iter().zip(&z) {
                x[i] += alpha * (v - x[i]);
            }
            active.retain(|&i| x[i] > 1e-14);
            for i in 0..n {
                if !active.contains(&i) {
                    x[i] = 0.0;
                }
            }
            if active.is_empty() {
                break;
            }
        }
    }
    let last = resid(&x);
    (x, res.min(last))
}

/// A reduced model along a load path: the [`PathModel`] of a [`Model`] under loads interpolated
/// linearly between `from` (λ = 0) and `to` (λ = 1), in the reduced coordinates of a basis with
/// an element sample.
pub struct RomPath<'a> {
    pub red: Reduction<'a>,
    pub sample: &'a Sample,
    pub from: Loads,
    pub to: Loads,
    pub functionals: Vec<Functional>,
    /// the cavity volume is the control functional (when the model has a cavity)
    pub volume_control: bool,
    rule: HexRule,
}

/// A factorised reduced tangent.
pub enum DenseFactor {
    Llt(Llt<f64>),
    Lu(PartialPivLu<f64>),
}

/// What one reduced evaluation computes besides the residual and tangent.
pub struct RomState {
    pub q: Vec<f64>,
    pub u: Vec<[f64; 3]>,
    pub kin: Vec<BodyKin>,
    /// weighted element forces and exact pressure forces at the rigid bodies' nodes (3 per node,
    /// zero elsewhere): what reactions are read from
    pub r_body: Vec<f64>,
    pub volume: f64,
    /// ∂V/∂z
    pub dvol: Vec<f64>,
    pub energy: f64,
}

impl<'a> RomPath<'a> {
    pub fn new(model: &'a Model, basis: &'a Basis, sample: &'a Sample, from: Loads, to: Loads, functionals: Vec<Functional>) -> Result<Self, RomError> {
        let red = Reduction::new(model, basis)?;
        let ne = model.mesh.n_elements();
        if let Some(&e) = sample.elements.iter().find(|&&e| e >= ne) {
            return Err(RomError::SampleElement(e, ne));
        }
        Ok(RomPath { red, sample, from, to, functionals, volume_control: model.cavity.is_some(), rule: model.form.rule() })
    }

    pub fn loads(&self, lam: f64) -> Loads {
        Loads::lerp(&self.from, &self.to, lam)
    }

    /// Residual, tangent and state at (z, loads).
    pub fn evaluate(&self, z: &[f64], loads: &Loads, want_k: bool) -> Result<(Vec<f64>, Option<Mat<f64>>, RomState, f64, f64), ElementError> {
        let model = self.red.model;
        let x0 = &model.mesh.nodes;
        let m = self.red.dim();
        let q = self.red.lift(z);
        let kin = model.dofs.body_kinematics(&q, &loads.presc);
        let u = model.dofs.expand(x0, &q, &loads.presc, &kin);
        let mut r = vec![0.0; m];
        let mut kz = want_k.then(|| Mat::<f64>::zeros(m, m));
        let mut r_body = vec![0.0; 3 * x0.len()];
        let mut energy = 0.0;
        let mut min_det = f64::INFINITY;
        let mut scale_sq = 0.0;
        let mut scratch = Vec::new();
        let mut jac = Vec::new();
        let nn = model.mesh.kind.nodes_per_element();
        let nd = 3 * nn;
        let mut f = vec![0.0; nd];
        let mut ke = vec![0.0; if want_k { nd * nd } else { 0 }];
        for (&e, &w) in self.sample.elements.iter().zip(&self.sample.weights) {
            let conn = model.mesh.element(e);
            let xe: Vec<[f64; 3]> = conn.iter().map(|&n| x0[n]).collect();
            let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
            let info = if want_k {
                element::tangent_mixed(&model.form, &self.rule, &model.material, &model.params, &xe, &ue, None, &mut f, &mut ke)
            } else {
                element::residual(&model.form, &self.rule, &model.material, &model.params, &xe, &ue, &mut f)
            }
            .map_err(|err| crate::model::relabel(err, e))?;
            energy += w * info.energy;
            min_det = min_det.min(info.min_det_f);
            self.red.jacobian(conn, &kin, &mut scratch, &mut jac);
            let jm = faer::MatRef::from_row_major_slice(&jac, nd, m);
            let fm = faer::MatRef::from_column_major_slice(&f, nd, 1);
            let re = jm.transpose() * fm;
            let mut re2 = 0.0;
            for i in 0..m {
                r[i] += w * re[(i, 0)];
                re2 += re[(i, 0)] * re[(i, 0)];
            }
            scale_sq += w * re2;
            add_body_nodal(model, conn, &f, w, &mut r_body);
            if let Some(kz) = kz.as_mut() {
                let km = faer::MatRef::from_row_major_slice(&ke, nd, nd);
                let kj = km * jm;
                faer::linalg::matmul::matmul(kz.as_mut(), faer::Accum::Add, jm.transpose(), kj.as_ref(), w, faer::Par::Seq);
            }
        }
        // cavity: exact volume, −p ∂V/∂z and −p ∂²V/∂z² over every face and boundary edge
        let mut volume = 0.0;
        let mut dvol = vec![0.0; m];
        let p = loads.pressure;
        if let Some(cav) = &model.cavity {
            let items = cav.face_nodes.iter().map(|v| (v.as_slice(), true)).chain(cav.edges.iter().map(|e| (e.0.as_slice(), false)));
            let mut g = Vec::new();
            let mut h = Vec::new();
            for (nodes, is_face) in items {
                let xs: Vec<[f64; 3]> = nodes.iter().map(|&n| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]]).collect();
                let ml = 3 * xs.len();
                g.clear();
                g.resize(ml, 0.0);
                volume += if is_face { surface::face_volume_grad(&cav.rule, &xs, &mut g) } else { surface::edge_volume_grad(&xs, &mut g) };
                self.red.jacobian(nodes, &kin, &mut scratch, &mut jac);
                let jm = faer::MatRef::from_row_major_slice(&jac, ml, m);
                let gm = faer::MatRef::from_column_major_slice(&g, ml, 1);
                let gz = jm.transpose() * gm;
                for i in 0..m {
                    dvol[i] += gz[(i, 0)];
                    r[i] -= p * gz[(i, 0)];
                }
                if p != 0.0 {
                    add_body_nodal(model, nodes, &g, -p, &mut r_body);
                    if let Some(kz) = kz.as_mut() {
                        h.clear();
                        h.resize(ml * ml, 0.0);
                        if is_face {
                            surface::face_volume_hessian(&cav.rule, &xs, &mut h);
                        } else {
                            surface::edge_volume_hessian(&xs, &mut h);
                        }
                        let hm = faer::MatRef::from_row_major_slice(&h, ml, ml);
                        let hj = hm * jm;
                        faer::linalg::matmul::matmul(kz.as_mut(), faer::Accum::Add, jm.transpose(), hj.as_ref(), -p, faer::Par::Seq);
                    }
                }
            }
        }
        let k = self.red.basis.k;
        let nb = self.red.basis.n;
        let zi = |i: usize| k + i - nb;
        // caps without pressure: +p A_cap on each body's free z translation (as the full model)
        if let Some(cav) = model.cavity.as_ref().filter(|c| !c.cap_load) {
            if p != 0.0 {
                for (b, area) in surface::rigid_cap_areas(cav, &model.dofs, x0).into_iter().enumerate() {
                    if let BodyDof::Free(i) = model.dofs.body_dofs[b][2] {
                        r[zi(i)] += p * area;
                    }
                }
            }
        }
        for (b, fb) in loads.body_forces.iter().enumerate() {
            for c in 0..3 {
                if let BodyDof::Free(i) = model.dofs.body_dofs[b][c] {
                    r[zi(i)] -= fb[c];
                }
            }
        }
        if !loads.nodal_forces.is_empty() {
            // dead nodal forces: −(∂u/∂z)ᵀ f over the loaded nodes
            let nodes: Vec<usize> = (0..x0.len()).filter(|&n| (0..3).any(|c| loads.nodal_forces.get(3 * n + c).copied().unwrap_or(0.0) != 0.0)).collect();
            self.red.jacobian(&nodes, &kin, &mut scratch, &mut jac);
            for (a, &n) in nodes.iter().enumerate() {
                for c in 0..3 {
                    let fv = loads.nodal_forces[3 * n + c];
                    for i in 0..m {
                        r[i] -= jac[(3 * a + c) * m + i] * fv;
                    }
                    if model.dofs.rigid_body_of(n, c).is_some() {
                        r_body[3 * n + c] -= fv;
                    }
                }
            }
        }
        // second-order rigid rotation term Σ R_i ∂²u_i/∂ψa∂ψb (the weighted forces at body nodes)
        if let Some(kz) = kz.as_mut() {
            for (b, body) in model.dofs.bodies.iter().enumerate() {
                let mut hb = [[0.0; 3]; 3];
                for &n in &body.nodes {
                    let d = crate::dofmap::sub(x0[n], body.reference);
                    for c in 0..3 {
                        if !body.mask[c] {
                            continue;
                        }
                        let rv = r_body[3 * n + c];
                        if rv == 0.0 {
                            continue;
                        }
                        for a in 0..3 {
                            for bb in 0..3 {
                                let mm = &kin[b].d2r[a][bb][c];
                                hb[a][bb] += rv * (mm[0] * d[0] + mm[1] * d[1] + mm[2] * d[2]);
                            }
                        }
                    }
                }
                for a in 0..3 {
                    for bb in 0..3 {
                        if let (BodyDof::Free(i), BodyDof::Free(j)) = (model.dofs.body_dofs[b][3 + a], model.dofs.body_dofs[b][3 + bb]) {
                            kz[(zi(i), zi(j))] += hb[a][bb];
                        }
                    }
                }
            }
        }
        if !r.iter().all(|v| v.is_finite()) || kz.as_ref().is_some_and(|k| !(0..m).all(|j| (0..m).all(|i| k[(i, j)].is_finite()))) {
            return Err(ElementError::NonFinite(usize::MAX));
        }
        let scale = scale_sq.sqrt().max(p.abs() * dvol.iter().map(|x| x * x).sum::<f64>().sqrt());
        Ok((r, kz, RomState { q, u, kin, r_body, volume, dvol, energy }, scale, min_det))
    }

    /// The reduced load of a unit cavity pressure, ∂V/∂z less the caps' areas when they carry no
    /// pressure (as [`Model::unit_pressure_load`]).
    fn unit_pressure_load(&self, dvol: &[f64]) -> Vec<f64> {
        let model = self.red.model;
        let mut l = dvol.to_vec();
        if let Some(cav) = model.cavity.as_ref().filter(|c| !c.cap_load) {
            for (b, area) in surface::rigid_cap_areas(cav, &model.dofs, &model.mesh.nodes).into_iter().enumerate() {
                if let BodyDof::Free(i) = model.dofs.body_dofs[b][2] {
                    l[self.red.basis.k + i - self.red.basis.n] -= area;
                }
            }
        }
        l
    }

    /// The full-model state of the functionals at a reduced evaluation.
    pub fn functional_state(&self, st: &RomState) -> State<f64> {
        let bodies = st.kin.iter().map(|k| BodyState { c: k.c, psi: k.psi, r: k.r, dr: k.dr }).collect();
        State { x0: self.red.model.mesh.nodes.clone(), u: st.u.clone(), r_full: st.r_body.clone(), r: Vec::new(), volume: st.volume, gvol_full: Vec::new(), bodies }
    }
}

/// Add w·f at the rigid bodies' nodal components of a node list.
fn add_body_nodal(model: &Model, nodes: &[usize], f: &[f64], w: f64, out: &mut [f64]) {
    for (a, &n) in nodes.iter().enumerate() {
        for c in 0..3 {
            if let Comp::Rigid(_) = model.dofs.comps[3 * n + c] {
                out[3 * n + c] += w * f[3 * a + c];
            }
        }
    }
}

impl<'a> PathModel for RomPath<'a> {
    type Matrix = Mat<f64>;
    type Factor = DenseFactor;
    fn dim(&self) -> usize {
        self.red.dim()
    }
    fn eval(&self, z: &[f64], lam: f64, tangent: bool, _lin: Option<&[f64]>) -> Result<Eval<Mat<f64>>, EvalFailure> {
        let loads = self.loads(lam);
        let (r, k, st, scale, min_det) = self.evaluate(z, &loads, tangent).map_err(elem_eval)?;
        let control = (self.volume_control && self.red.model.cavity.is_some()).then(|| (st.volume, st.dvol));
        Ok(Eval { r, scale, control, min_det, k })
    }
    fn factor(&self, k: &Mat<f64>, definite: bool) -> Result<DenseFactor, SolveError> {
        if definite {
            k.llt(Side::Lower).map(DenseFactor::Llt).map_err(|_| SolveError::NotPositiveDefinite)
        } else {
            Ok(DenseFactor::Lu(k.partial_piv_lu()))
        }
    }
    fn solve(&self, f: &DenseFactor, b: &[f64]) -> Result<Vec<f64>, SolveError> {
        let rhs = faer::MatRef::from_column_major_slice(b, b.len(), 1);
        let x = match f {
            DenseFactor::Llt(l) => l.solve(rhs),
            DenseFactor::Lu(l) => l.solve(rhs),
        };
        let x: Vec<f64> = (0..b.len()).map(|i| x[(i, 0)]).collect();
        if x.iter().all(|v| v.is_finite()) {
            Ok(x)
        } else {
            Err(SolveError::Singular)
        }
    }
    fn load_rate(&self, z: &[f64], lam: f64, ev: &Eval<Mat<f64>>) -> Result<Vec<f64>, EvalFailure> {
        let presc_moves = self.from.presc != self.to.presc;
        let dead_moves = self.from.body_forces != self.to.body_forces || self.from.nodal_forces != self.to.nodal_forces;
        if !presc_moves && !dead_moves {
            let dp = self.to.pressure - self.from.pressure;
            let dvol = match &ev.control {
                Some((_, g)) => g.clone(),
                None => self.evaluate(z, &self.loads(lam), false).map_err(elem_eval)?.2.dvol,
            };
            return Ok(self.unit_pressure_load(&dvol).into_iter().map(|v| -dp * v).collect());
        }
        let eps = 1e-6;
        let rp = self.evaluate(z, &self.loads(lam + eps), false).map_err(elem_eval)?.0;
        let rm = self.evaluate(z, &self.loads(lam - eps), false).map_err(elem_eval)?.0;
        Ok(rp.iter().zip(&rm).map(|(a, b)| (a - b) / (2.0 * eps)).collect())
    }
    fn outputs(&self, z: &[f64], lam: f64, _ev: &Eval<Mat<f64>>) -> Vec<f64> {
        if self.functionals.is_empty() {
            return Vec::new();
        }
        match self.evaluate(z, &self.loads(lam), false) {
            Ok((_, _, st, _, _)) => {
                let fs = self.functional_state(&st);
                self.functionals.iter().map(|f| f.eval(self.red.model, &fs).unwrap_or(f64::NAN)).collect()
            }
            Err(_) => vec![f64::NAN; self.functionals.len()],
        }
    }
}

/// A trained reduced model: the basis of the nodal unknowns and the element sample.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rom {
    pub basis: Basis,
    pub sample: Sample,
}

impl Rom {
    /// The reduced path model of `model` under loads from `from` (λ = 0) to `to` (λ = 1).
    pub fn path<'a>(&'a self, model: &'a Model, from: Loads, to: Loads, functionals: Vec<Functional>) -> Result<RomPath<'a>, RomError> {
        RomPath::new(model, &self.basis, &self.sample, from, to, functionals)
    }
}
