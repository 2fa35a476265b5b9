//! A model (mesh + formulation + material + constraints + cavity pressure), its sparse assembly in
//! the reduced unknowns, and the linear solves.

use crate::dofmap::{sub, BodyKin, Constraints, DofMap};
use crate::element::{self, ElementError, Formulation};
use crate::material::{Hyperelastic, Material};
use crate::mesh::{Face, Mesh};
use crate::shape::HexRule;
use crate::surface::{self, Cavity};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, CholeskySymbolicParams, IntranodeLbltRef, LltRef, SymbolicCholesky, SymmetricOrdering};
use faer::sparse::linalg::solvers::{Lu, SymbolicLu};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use faer::{Conj, Par};
use faer::{Mat, Side};
use rayon::prelude::*;
use std::sync::Arc;

/// Errors building a model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Constraint(#[from] crate::dofmap::ConstraintError),
    #[error("mesh: {0}")]
    Mesh(String),
    #[error("sparse factorisation setup failed: {0}")]
    Symbolic(String),
}

/// Current values of the loads: cavity pressure and every prescribed value (nodal slots, then
/// rigid-body slots, in `DofMap::presc_targets` order).
#[derive(Clone, Debug, PartialEq)]
pub struct Loads {
    pub pressure: f64,
    pub presc: Vec<f64>,
    /// External force on each rigid body's reference point (dead load).
    pub body_forces: Vec<[f64; 3]>,
    /// Dead external nodal forces, 3 per node (e.g. from `surface::dead_traction`); empty = none.
    pub nodal_forces: Vec<f64>,
}

impl Loads {
    pub fn zero(model: &Model) -> Self {
        Loads { pressure: 0.0, presc: vec![0.0; model.dofs.presc_targets.len()], body_forces: vec![[0.0; 3]; model.dofs.bodies.len()], nodal_forces: Vec::new() }
    }
    /// Linear interpolation a + t (b − a).
    pub fn lerp(a: &Loads, b: &Loads, t: f64) -> Loads {
        Loads {
            pressure: a.pressure + t * (b.pressure - a.pressure),
            presc: a.presc.iter().zip(&b.presc).map(|(x, y)| x + t * (y - x)).collect(),
            body_forces: a.body_forces.iter().zip(&b.body_forces).map(|(x, y)| [x[0] + t * (y[0] - x[0]), x[1] + t * (y[1] - x[1]), x[2] + t * (y[2] - x[2])]).collect(),
            nodal_forces: {
                // an empty vector stands for zeros
                let n = a.nodal_forces.len().max(b.nodal_forces.len());
                let at = |v: &Vec<f64>, i: usize| v.get(i).copied().unwrap_or(0.0);
                (0..n).map(|i| at(&a.nodal_forces, i) + t * (at(&b.nodal_forces, i) - at(&a.nodal_forces, i))).collect()
            },
        }
    }
}

/// Lower-triangular CSC pattern of the reduced tangent, stored in the fill-reducing order of
/// its factorisation (unknown i of the model is row/column `inv[i]`), so that the numeric
/// factorisations need no permutation of the matrix.
#[derive(Clone, Debug)]
struct Pattern {
    n: usize,
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    /// fwd[new] = old, inv[old] = new
    fwd: Arc<Vec<u32>>,
    inv: Arc<Vec<u32>>,
}

impl Pattern {
    /// The slot of entry (r, c) of the model's unknowns.
    #[inline]
    fn slot(&self, r: u32, c: u32) -> usize {
        let (r, c) = (self.inv[r as usize], self.inv[c as usize]);
        let (r, c) = if r >= c { (r, c) } else { (c, r) };
        let s = self.col_ptr[c as usize] as usize;
        let e = self.col_ptr[c as usize + 1] as usize;
        s + self.row_idx[s..e].binary_search(&r).expect("entry in pattern")
    }

    /// The same pattern renumbered by `fwd` (new → old).
    fn permuted(&self, fwd: Vec<u32>) -> Pattern {
        let n = self.n;
        let mut inv = vec![0u32; n];
        for (new, &old) in fwd.iter().enumerate() {
            inv[old as usize] = new as u32;
        }
        let mut cols: Vec<Vec<u32>> = vec![Vec::new(); n];
        for c in 0..n {
            for s in self.col_ptr[c] as usize..self.col_ptr[c + 1] as usize {
                let r = self.row_idx[s] as usize;
                let (a, b) = (inv[self.fwd[r] as usize], inv[self.fwd[c] as usize]);
                // lower triangle: column min(a, b), row max(a, b)
                let (a, b) = if a <= b { (a, b) } else { (b, a) };
                cols[a as usize].push(b);
            }
        }
        let mut col_ptr = vec![0u32];
        let mut row_idx = Vec::with_capacity(self.row_idx.len());
        for col in cols.iter_mut() {
            col.sort_unstable();
            row_idx.extend_from_slice(col);
            col_ptr.push(row_idx.len() as u32);
        }
        Pattern { n, col_ptr, row_idx, fwd: Arc::new(fwd), inv: Arc::new(inv) }
    }

    fn symbolic(&self) -> SymbolicSparseColMat<u32> {
        SymbolicSparseColMat::<u32>::new_checked(self.n, self.n, self.col_ptr.clone(), None, self.row_idx.clone())
    }
}

/// The result of one assembly.
#[derive(Clone, Debug)]
pub struct Assembled {
    /// Reduced residual r = (∂u/∂q)ᵀ (f_int − f_ext).
    pub r: Vec<f64>,
    /// Reduced tangent values (upper CSC in the model's pattern), if requested.
    pub k: Option<Vec<f64>>,
    /// Full nodal residual f_int − f_ext (3 per node): the reaction forces at constrained DOFs.
    pub r_full: Vec<f64>,
    /// √Σ_e ‖f_e‖² over the element internal force vectors: the size of the (largely cancelling)
    /// terms summed into the residual, hence the scale of its round-off; used by convergence tests.
    pub f_scale: f64,
    /// Strain energy and cavity volume (of the modelled part).
    pub energy: f64,
    pub volume: f64,
    /// ∂V/∂q: the cavity volume's gradient in the reduced unknowns (= the reduced load of a unit
    /// cavity pressure); empty without a cavity.
    pub dvol: Vec<f64>,
    pub min_det_f: f64,
    /// The smallest contact gap (∞ without contact).
    pub contact_gap: f64,
    pub u: Vec<[f64; 3]>,
    pub kin: Vec<BodyKin>,
}

/// Failures of a linear solve.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SolveError {
    #[error("tangent not positive definite")]
    NotPositiveDefinite,
    #[error("tangent singular")]
    Singular,
    #[error("non-finite value in the solution")]
    NonFinite,
    #[error("the sparse tangent's setup (ordering, symbolic analysis) failed")]
    Setup,
}

/// A finite element model.
pub struct Model {
    pub mesh: Mesh,
    pub form: Formulation,
    rule: HexRule,
    pub material: Material,
    /// Overrides of the material parameters (for parameter derivatives); None = material's own.
    pub params: Vec<f64>,
    pub dofs: DofMap,
    pub cavity: Option<Cavity>,
    /// the tangent's sparsity pattern and symbolic analysis, built on first use (a reduced-order
    /// model evaluates the same mesh and constraints without them; see [`SparseSetup`])
    sparse: std::sync::OnceLock<Result<SparseSetup, String>>,
    ordering: Ordering,
    symbolic_lu: std::sync::OnceLock<Option<(SymbolicSparseColMat<u32>, Vec<usize>, SymbolicLu<u32>)>>,
    /// Elements per parallel work unit (fixed: results do not depend on the thread count).
    pub chunk: usize,
    /// Per-element scatter tables (built on first use when they fit in memory).
    scatter_cache: std::sync::OnceLock<Option<Vec<ElemScatter>>>,
    /// Reusable element-matrix buffers of the assembly.
    buffers: std::sync::Mutex<Vec<Vec<f64>>>,
    /// Scatter tables of the cavity faces and edges.
    cavity_scatter: std::sync::OnceLock<Option<Vec<ElemScatter>>>,
    /// Frictionless barrier contact ([`crate::contact`]), if any.
    contact: Option<crate::contact::Contact>,
}

/// The sparse tangent's structure: its pattern, in the order of the fill-reducing ordering, and
/// the symbolic analysis (elimination tree, supernodes), shared by the Cholesky and the LBLᵀ
/// factorisations.
struct SparseSetup {
    pattern: Pattern,
    symbolic: Arc<SymbolicCholesky<u32>>,
}

/// Where each pair of an element's (local DOF → reduced DOF) terms lands in the CSC values.
#[derive(Clone, Debug)]
struct ElemScatter {
    local: Vec<u16>,
    slots: Vec<u32>,
}

impl Model {
    pub fn new(mesh: Mesh, form: Formulation, material: Material, constraints: &Constraints, cavity_faces: Option<&[Face]>) -> Result<Model, ModelError> {
        if form.kind != mesh.kind {
            return Err(ModelError::Mesh(format!("formulation {:?} on a {:?} mesh", form.kind, mesh.kind)));
        }
        let dofs = DofMap::build(&mesh.nodes, constraints)?;
        let cavity = cavity_faces.map(|f| Cavity::new(&mesh, f));
        let ordering = Ordering::for_size(dofs.n_reduced());
        let rule = form.rule();
        let params = material.params();
        Ok(Model {
            mesh,
            form,
            rule,
            material,
            params,
            dofs,
            cavity,
            sparse: std::sync::OnceLock::new(),
            ordering,
            symbolic_lu: std::sync::OnceLock::new(),
            chunk: 32,
            scatter_cache: std::sync::OnceLock::new(),
            buffers: std::sync::Mutex::new(Vec::new()),
            cavity_scatter: std::sync::OnceLock::new(),
            contact: None,
        })
    }

    /// Add a frictionless barrier contact (slave nodes against target triangles). Its pairs
    /// enter the tangent's sparsity pattern, so the sparse setup is redone.
    pub fn set_contact(&mut self, contact: crate::contact::Contact) -> Result<(), ModelError> {
        contact.validate(self.mesh.n_nodes()).map_err(ModelError::Mesh)?;
        self.contact = Some(contact);
        self.sparse = std::sync::OnceLock::new();
        self.scatter_cache = std::sync::OnceLock::new();
        self.cavity_scatter = std::sync::OnceLock::new();
        self.symbolic_lu = std::sync::OnceLock::new();
        Ok(())
    }

    /// The model's contact, if any.
    pub fn contact(&self) -> Option<&crate::contact::Contact> {
        self.contact.as_ref()
    }

    /// Redo the symbolic analysis with another fill-reducing ordering.
    pub fn set_ordering(&mut self, ordering: Ordering) -> Result<(), ModelError> {
        self.ordering = ordering;
        self.sparse = std::sync::OnceLock::new();
        self.scatter_cache = std::sync::OnceLock::new();
        self.cavity_scatter = std::sync::OnceLock::new();
        self.symbolic_lu = std::sync::OnceLock::new();
        self.sparse_setup().map(|_| ())
    }

    pub fn ordering(&self) -> Ordering {
        self.ordering
    }

    /// Builds the sparse tangent's pattern and symbolic analysis now (else on the first tangent
    /// assembly or factorisation), reporting a failure as a model error: what a caller that will
    /// assemble the full tangent does right after [`Model::new`].
    pub fn prepare_sparse(&self) -> Result<(), ModelError> {
        self.sparse_setup().map(|_| ())
    }

    /// The sparse tangent's pattern and symbolic analysis (built on the first call).
    fn sparse_setup(&self) -> Result<&SparseSetup, ModelError> {
        self.sparse
            .get_or_init(|| {
                let groups = self.contact.as_ref().map(|c| c.coupling_groups()).unwrap_or_default();
                let pattern = build_pattern(&self.mesh, &self.dofs, &groups);
                symbolic_analysis(&pattern, self.ordering).map(|(pattern, symbolic)| SparseSetup { pattern, symbolic }).map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|e| ModelError::Symbolic(e.clone()))
    }

    /// With contact: the largest fraction of the step q → q + dq (nodes moving on straight lines
    /// between the two states) that keeps every slave farther from its targets than `keep` times
    /// its distance at q ([`crate::contact::Contact::max_step`]); 1 without contact.
    pub fn contact_step_limit(&self, q: &[f64], dq: &[f64], loads: &Loads, keep: f64) -> f64 {
        let Some(con) = &self.contact else {
            return 1.0;
        };
        let x0 = &self.mesh.nodes;
        let u0 = self.dofs.expand(x0, q, &loads.presc, &self.dofs.body_kinematics(q, &loads.presc));
        let q1: Vec<f64> = q.iter().zip(dq).map(|(a, b)| a + b).collect();
        let u1 = self.dofs.expand(x0, &q1, &loads.presc, &self.dofs.body_kinematics(&q1, &loads.presc));
        let x = |n: usize| [x0[n][0] + u0[n][0], x0[n][1] + u0[n][1], x0[n][2] + u0[n][2]];
        let dx = |n: usize| [u1[n][0] - u0[n][0], u1[n][1] - u0[n][1], u1[n][2] - u0[n][2]];
        con.max_step(&x, &dx, keep)
    }

    /// The diagonal of a tangent (values in this model's sparse pattern), in the model's order of
    /// the unknowns.
    pub fn tangent_diagonal(&self, values: &[f64]) -> Result<Vec<f64>, SolveError> {
        let sp = self.sparse_setup().map_err(|_| SolveError::Setup)?;
        Ok((0..self.n_reduced() as u32).map(|i| values[sp.pattern.slot(i, i)]).collect())
    }

    /// The tangent with `d` added to its diagonal (a shifted, regularised Newton matrix).
    pub fn tangent_shifted(&self, values: &[f64], d: &[f64]) -> Result<Vec<f64>, SolveError> {
        let sp = self.sparse_setup().map_err(|_| SolveError::Setup)?;
        let mut v = values.to_vec();
        for (i, di) in d.iter().enumerate() {
            v[sp.pattern.slot(i as u32, i as u32)] += di;
        }
        Ok(v)
    }

    /// Entries of the Cholesky factor L (the fill of the ordering; 0 if the setup failed).
    pub fn factor_nnz(&self) -> usize {
        self.sparse_setup().map_or(0, |sp| sp.symbolic.len_val())
    }

    pub fn n_reduced(&self) -> usize {
        self.dofs.n_reduced()
    }

    pub fn nnz(&self) -> usize {
        self.sparse_setup().map_or(0, |sp| sp.pattern.row_idx.len())
    }

    /// Assemble residual (and tangent) at reduced state q under loads.
    pub fn assemble(&self, q: &[f64], loads: &Loads, want_k: bool) -> Result<Assembled, ElementError> {
        self.assemble_lin(q, loads, want_k, None)
    }

    /// As [`Model::assemble`], with the tangent's volumetric state linearised about the state
    /// `q_lin` (the previous Newton iterate or the converged state a predictor started from; see
    /// [`element::tangent_mixed`]). The residual is the same; the tangent is exact when q = q_lin.
    pub fn assemble_lin(&self, q: &[f64], loads: &Loads, want_k: bool, q_lin: Option<&[f64]>) -> Result<Assembled, ElementError> {
        let x0 = &self.mesh.nodes;
        let kin = self.dofs.body_kinematics(q, &loads.presc);
        let u = self.dofs.expand(x0, q, &loads.presc, &kin);
        let u_lin = q_lin.filter(|_| want_k).map(|ql| {
            let kl = self.dofs.body_kinematics(ql, &loads.presc);
            self.dofs.expand(x0, ql, &loads.presc, &kl)
        });
        let nn = self.mesh.kind.nodes_per_element();
        let nd = 3 * nn;
        let ne = self.mesh.n_elements();
        let mut r_full = vec![0.0; 3 * x0.len()];
        let sp = if want_k { Some(self.sparse_setup().map_err(|_| ElementError::Setup)?) } else { None };
        let mut kv = sp.map(|sp| vec![0.0; sp.pattern.row_idx.len()]);
        let mut energy = 0.0;
        let mut min_det_f = f64::INFINITY;
        let mut f_int_sq = 0.0;
        // element loop: parallel per chunk, scatter serially in element order (deterministic)
        let chunks: Vec<(usize, usize)> = (0..ne).step_by(self.chunk).map(|s| (s, (s + self.chunk).min(ne))).collect();
        let wave = 4 * rayon::current_num_threads().max(1);
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); nd];
        for wave_chunks in chunks.chunks(wave) {
            // per chunk: (energy, min det F) per element, and the element vectors / matrices in
            // one buffer each (taken from the model's pool: the kernels overwrite them)
            type ChunkOut = (Vec<(f64, f64)>, Vec<f64>, Vec<f64>);
            let results: Vec<Result<ChunkOut, ElementError>> = wave_chunks
                .par_iter()
                .map(|&(s, e)| {
                    let mut info = Vec::with_capacity(e - s);
                    let mut fbuf = vec![0.0; (e - s) * nd];
                    let mut kbuf = if want_k { self.take_buffer((e - s) * nd * nd) } else { Vec::new() };
                    let mut xe = Vec::with_capacity(nn);
                    let mut ue = Vec::with_capacity(nn);
                    let mut ul = Vec::with_capacity(nn);
                    for el in s..e {
                        let conn = self.mesh.element(el);
                        xe.clear();
                        xe.extend(conn.iter().map(|&n| x0[n]));
                        ue.clear();
                        ue.extend(conn.iter().map(|&n| u[n]));
                        let off = el - s;
                        let f = &mut fbuf[off * nd..(off + 1) * nd];
                        let res = if want_k {
                            let k = &mut kbuf[off * nd * nd..(off + 1) * nd * nd];
                            let lin = u_lin.as_ref().map(|l| {
                                ul.clear();
                                ul.extend(conn.iter().map(|&n| l[n]));
                                ul.as_slice()
                            });
                            element::tangent_mixed(&self.form, &self.rule, &self.material, &self.params, &xe, &ue, lin, f, k)
                        } else {
                            element::residual(&self.form, &self.rule, &self.material, &self.params, &xe, &ue, f)
                        };
                        match res {
                            Ok(i) => info.push((i.energy, i.min_det_f)),
                            Err(err) => {
                                self.give_buffer(kbuf);
                                return Err(relabel(err, el));
                            }
                        }
                    }
                    Ok((info, fbuf, kbuf))
                })
                .collect();
            let mut failure = None;
            for (ci, res) in results.into_iter().enumerate() {
                let (info, fbuf, kbuf) = match res {
                    Ok(r) => r,
                    Err(e) => {
                        failure.get_or_insert(e);
                        continue;
                    }
                };
                if failure.is_some() {
                    self.give_buffer(kbuf);
                    continue;
                }
                let start = wave_chunks[ci].0;
                for (off, &(en, mj)) in info.iter().enumerate() {
                    let el = start + off;
                    let f = &fbuf[off * nd..(off + 1) * nd];
                    energy += en;
                    f_int_sq += f.iter().map(|v| v * v).sum::<f64>();
                    min_det_f = min_det_f.min(mj);
                    let conn = self.mesh.element(el);
                    for (a, &n) in conn.iter().enumerate() {
                        for c in 0..3 {
                            r_full[3 * n + c] += f[3 * a + c];
                        }
                    }
                    if let (Some(kv), Some(sp)) = (kv.as_mut(), sp) {
                        let k = &kbuf[off * nd * nd..(off + 1) * nd * nd];
                        self.fill_rows(conn, &kin, &mut rows);
                        match self.scatter_tables(sp) {
                            Some(tables) => scatter_cached(&tables[el], &rows, k, kv),
                            None => self.scatter(sp, &rows, k, kv),
                        }
                    }
                }
                self.give_buffer(kbuf);
            }
            if let Some(e) = failure {
                return Err(e);
            }
        }
        // cavity pressure: −p ∂V/∂x, tangent −p ∂²V/∂x²
        let mut volume = 0.0;
        let mut gvol_full = if self.cavity.is_some() { vec![0.0; 3 * x0.len()] } else { Vec::new() };
        if let Some(cav) = &self.cavity {
            let p = loads.pressure;
            let xcur = |n: usize| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]];
            let cached = sp.and_then(|sp| self.cavity_scatter_tables(sp));
            volume = surface::volume_and_gradient(cav, xcur, &mut gvol_full, |idx, nodes, xs, is_face| {
                if let (Some(kv), Some(sp), true) = (kv.as_mut(), sp, p != 0.0) {
                    let m = 3 * xs.len();
                    let mut h = vec![0.0; m * m];
                    surface::item_volume_hessian(&cav.rule, xs, is_face, &mut h);
                    h.iter_mut().for_each(|v| *v *= -p);
                    let mut rws: Vec<Vec<(u32, f64)>> = vec![Vec::new(); m];
                    self.fill_rows(nodes, &kin, &mut rws);
                    match cached {
                        Some(tables) => scatter_cached(&tables[idx], &rws, &h, kv),
                        None => self.scatter(sp, &rws, &h, kv),
                    }
                }
            });
            if p != 0.0 {
                for (rv, g) in r_full.iter_mut().zip(&gvol_full) {
                    *rv -= p * g;
                }
            }
        }
        // barrier contact: energy κ w b(d), force and exact Hessian per slave node
        let mut contact_gap = f64::INFINITY;
        if let Some(con) = &self.contact {
            let xcur = |n: usize| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]];
            let (terms, gap) = con.terms(&xcur, want_k).map_err(|p| ElementError::Penetration(p.node))?;
            contact_gap = gap;
            let mut rws: Vec<Vec<(u32, f64)>> = Vec::new();
            for t in &terms {
                energy += t.energy;
                // (the contact forces are terms of the residual like the element forces)
                f_int_sq += t.force.iter().map(|v| v * v).sum::<f64>();
                for (a, &n) in t.nodes.iter().enumerate() {
                    for c in 0..3 {
                        r_full[3 * n + c] += t.force[3 * a + c];
                    }
                }
                if let (Some(kv), Some(sp)) = (kv.as_mut(), sp) {
                    rws.clear();
                    self.fill_rows(&t.nodes, &kin, &mut rws);
                    self.scatter(sp, &rws, &t.hessian, kv);
                }
            }
        }
        // dead nodal forces
        if !loads.nodal_forces.is_empty() {
            if loads.nodal_forces.len() != r_full.len() {
                return Err(ElementError::NonFinite(usize::MAX));
            }
            for (rv, f) in r_full.iter_mut().zip(&loads.nodal_forces) {
                *rv -= f;
            }
        }
        // reduce the residual (and the volume gradient)
        let mut r = self.reduce_full(&kin, &r_full);
        let dvol = if gvol_full.is_empty() { Vec::new() } else { self.reduce_full(&kin, &gvol_full) };
        // the caps' pressure correction and the dead forces on the bodies' reference points
        for (i, v) in self.rigid_load_terms(x0, loads.pressure, &loads.body_forces) {
            r[i] += v;
        }
        // second-order rigid rotation term Σ R_i ∂²u_i/∂ψa∂ψb
        if let (Some(kv), Some(sp)) = (kv.as_mut(), sp) {
            for (b, body) in self.dofs.bodies.iter().enumerate() {
                let mut hb = [[0.0; 3]; 3];
                for &n in &body.nodes {
                    let d = sub(x0[n], body.reference);
                    for c in 0..3 {
                        if !body.mask[c] {
                            continue;
                        }
                        let rv = r_full[3 * n + c];
                        for a in 0..3 {
                            for bb in 0..3 {
                                let m = &kin[b].d2r[a][bb][c];
                                hb[a][bb] += rv * (m[0] * d[0] + m[1] * d[1] + m[2] * d[2]);
                            }
                        }
                    }
                }
                for a in 0..3 {
                    for bb in a..3 {
                        if let (crate::dofmap::BodyDof::Free(i), crate::dofmap::BodyDof::Free(j)) = (self.dofs.body_dofs[b][3 + a], self.dofs.body_dofs[b][3 + bb]) {
                            kv[sp.pattern.slot(i as u32, j as u32)] += hb[a][bb];
                        }
                    }
                }
            }
        }
        Ok(Assembled { r, k: kv, r_full, f_scale: f_int_sq.sqrt(), energy, volume, dvol, min_det_f, contact_gap, u, kin })
    }

    /// The reduced load of a unit cavity pressure: ∂V/∂q (`dvol` of an assembly), less each rigid
    /// cap's area on its body's free z translation when the caps carry no pressure
    /// ([`Cavity::cap_load`]; the pressure part of [`Model::rigid_load_terms`]).
    pub fn unit_pressure_load(&self, dvol: &[f64]) -> Vec<f64> {
        let mut l = dvol.to_vec();
        for (i, a) in self.rigid_load_terms(&self.mesh.nodes, 1.0, &[]) {
            if let Some(v) = l.get_mut(i) {
                *v -= a;
            }
        }
        l
    }

    /// The terms of the reduced residual that act on the rigid bodies' free DOFs directly, as
    /// (reduced index, value) pairs to add: +p·A_cap on each body's free z translation when the
    /// caps carry no pressure ([`Cavity::cap_load`]: the caps' share of −p ∂V/∂q removed; A_cap
    /// of the reference positions `x0`, which rigid motions keep; see the surface module docs),
    /// and −F on the free translations of each body whose reference point carries the dead force
    /// `body_forces[b]`. Written once for the full model, its adjoint (dual numbers: the areas
    /// move with the shape) and the reduced model (its rigid coordinates).
    pub fn rigid_load_terms<D: crate::scalar::Scalar>(&self, x0: &[[D; 3]], pressure: D, body_forces: &[[f64; 3]]) -> Vec<(usize, D)> {
        let mut out = Vec::new();
        if let Some(cav) = self.cavity.as_ref().filter(|c| !c.cap_load) {
            for (b, area) in surface::rigid_cap_areas(cav, &self.dofs, x0).into_iter().enumerate() {
                if let crate::dofmap::BodyDof::Free(i) = self.dofs.body_dofs[b][2] {
                    out.push((i, pressure * area));
                }
            }
        }
        for (b, fb) in body_forces.iter().enumerate() {
            for k in 0..3 {
                if let Some(crate::dofmap::BodyDof::Free(i)) = self.dofs.body_dofs.get(b).map(|d| d[k]) {
                    out.push((i, crate::scalar::c(-fb[k])));
                }
            }
        }
        out
    }

    /// (∂u/∂q)ᵀ v for a full nodal vector v (3 per node) at the kinematics `kin`: reduces a
    /// nodal force (or any ∂J/∂u) to the reduced unknowns.
    pub fn reduce_full(&self, kin: &[BodyKin], v: &[f64]) -> Vec<f64> {
        let x0 = &self.mesh.nodes;
        let mut out = vec![0.0; self.n_reduced()];
        let mut row = Vec::with_capacity(16);
        for n in 0..x0.len() {
            for c in 0..3 {
                let vc = v[3 * n + c];
                if vc == 0.0 {
                    continue;
                }
                row.clear();
                self.dofs.row(x0, kin, n, c, &mut row);
                for &(k, cf) in &row {
                    out[k as usize] += cf * vc;
                }
            }
        }
        out
    }

    /// A scratch buffer of at least `len` values (contents unspecified) from the model's pool.
    fn take_buffer(&self, len: usize) -> Vec<f64> {
        let mut b = self.buffers.lock().ok().and_then(|mut p| p.pop()).unwrap_or_default();
        if b.len() < len {
            b.resize(len, 0.0);
        }
        b
    }

    fn give_buffer(&self, b: Vec<f64>) {
        if b.capacity() > 0 {
            if let Ok(mut p) = self.buffers.lock() {
                if p.len() < 64 {
                    p.push(b);
                }
            }
        }
    }

    fn fill_rows(&self, nodes: &[usize], kin: &[BodyKin], rows: &mut Vec<Vec<(u32, f64)>>) {
        let x0 = &self.mesh.nodes;
        rows.resize(3 * nodes.len(), Vec::new());
        for (a, &n) in nodes.iter().enumerate() {
            for c in 0..3 {
                let row = &mut rows[3 * a + c];
                row.clear();
                self.dofs.row(x0, kin, n, c, row);
            }
        }
    }

    fn scatter_tables(&self, sp: &SparseSetup) -> Option<&Vec<ElemScatter>> {
        self.scatter_cache.get_or_init(|| self.build_scatter(sp, (0..self.mesh.n_elements()).map(|e| self.mesh.element(e)))).as_ref()
    }

    /// Scatter tables of the cavity's faces, then its edges (the load stiffness −p ∂²V/∂x²).
    fn cavity_scatter_tables(&self, sp: &SparseSetup) -> Option<&Vec<ElemScatter>> {
        self.cavity_scatter
            .get_or_init(|| {
                let cav = self.cavity.as_ref()?;
                self.build_scatter(sp, cav.face_nodes.iter().map(|v| v.as_slice()).chain(cav.edges.iter().map(|e| e.0.as_slice())))
            })
            .as_ref()
    }

    /// Where each pair of (local DOF → reduced DOF) terms of each node list lands in the CSC
    /// values; None when the tables would exceed 512 MB (then the slots are searched).
    fn build_scatter<'a>(&self, sp: &SparseSetup, lists: impl Iterator<Item = &'a [usize]>) -> Option<Vec<ElemScatter>> {
        let mut total = 0usize;
        let mut out = Vec::new();
        let mut pat = Vec::new();
        for nodes in lists {
            let mut local = Vec::with_capacity(3 * nodes.len());
            let mut ks = Vec::with_capacity(3 * nodes.len());
            for (a, &n) in nodes.iter().enumerate() {
                for c in 0..3 {
                    pat.clear();
                    self.dofs.row_pattern(n, c, &mut pat);
                    for &k in &pat {
                        local.push((3 * a + c) as u16);
                        ks.push(k);
                    }
                }
            }
            let nt = ks.len();
            total += nt * nt;
            if total > 128 << 20 {
                return None;
            }
            let mut slots = vec![u32::MAX; nt * nt];
            for p in 0..nt {
                for q in 0..nt {
                    if ks[p] <= ks[q] {
                        slots[p * nt + q] = sp.pattern.slot(ks[p], ks[q]) as u32;
                    }
                }
            }
            out.push(ElemScatter { local, slots });
        }
        Some(out)
    }

    /// K_red[k,l] += Σ c_i c_j K_e[i][j] over the rows of the local DOFs (upper triangle only).
    fn scatter(&self, sp: &SparseSetup, rows: &[Vec<(u32, f64)>], ke: &[f64], kv: &mut [f64]) {
        let nd = rows.len();
        for i in 0..nd {
            let ri = &rows[i];
            if ri.is_empty() {
                continue;
            }
            for j in 0..nd {
                let rj = &rows[j];
                let v = ke[i * nd + j];
                if v == 0.0 {
                    continue;
                }
                for &(k, ck) in ri {
                    for &(l, cl) in rj {
                        if k <= l {
                            kv[sp.pattern.slot(k, l)] += ck * cl * v;
                        }
                    }
                }
            }
        }
    }

    /// The reduced tangent as a faer matrix (lower triangle stored, in the factorisation's
    /// order of the unknowns: entry (i, j) of the model is at (inv[i], inv[j])).
    fn matrix(&self, sp: &SparseSetup, values: Vec<f64>) -> SparseColMat<u32, f64> {
        SparseColMat::new(sp.pattern.symbolic(), values)
    }

    /// Cholesky factorisation with the stored symbolic analysis (sequential: on the tangents of
    /// this project faer's parallel supernodal factorisation is slower on 2 cores, and sweeps run
    /// one design per core). Fails if not positive definite.
    pub fn factor(&self, values: &[f64]) -> Result<Factor, SolveError> {
        let sp = self.sparse_setup().map_err(|_| SolveError::Setup)?;
        let a = self.matrix(sp, values.to_vec());
        let sym = sp.symbolic.clone();
        let mut lv = vec![0.0; sym.len_val()];
        let par = Par::Seq;
        let mut mem = MemBuffer::new(sym.factorize_numeric_llt_scratch::<f64>(par, Default::default()));
        match sym.factorize_numeric_llt(&mut lv, a.as_ref(), Side::Lower, Default::default(), par, MemStack::new(&mut mem), Default::default()) {
            Ok(_) => Ok(Factor { kind: FactorKind::Llt(LltOwned { sym, values: lv }), fwd: sp.pattern.fwd.clone() }),
            Err(_) => Err(SolveError::NotPositiveDefinite),
        }
    }

    /// Factorisation of the symmetric, possibly indefinite tangent: sparse LBLᵀ (Bunch–Kaufman
    /// pivoting within supernodes, with the Cholesky's symbolic structure), checked by the residual
    /// of a test solve; falls back to LU when that check fails (e.g. small problems, where faer
    /// uses an unpivoted simplicial LDLᵀ).
    pub fn factor_indefinite(&self, values: &[f64]) -> Result<Factor, SolveError> {
        let sp = self.sparse_setup().map_err(|_| SolveError::Setup)?;
        if let Some(f) = self.factor_lblt(sp, values) {
            return Ok(f);
        }
        self.factor_lu(values)
    }

    fn factor_lblt(&self, sp: &SparseSetup, values: &[f64]) -> Option<Factor> {
        let sym = sp.symbolic.clone();
        let n = sp.pattern.n;
        let a = self.matrix(sp, values.to_vec());
        let mut lv = vec![0.0; sym.len_val()];
        let mut subdiag = vec![0.0; n];
        let mut fwd = vec![0u32; n];
        let mut inv = vec![0u32; n];
        let mut mem = MemBuffer::new(sym.factorize_numeric_intranode_lblt_scratch::<f64>(Par::Seq, Default::default()));
        sym.factorize_numeric_intranode_lblt(&mut lv, &mut subdiag, &mut fwd, &mut inv, a.as_ref(), Side::Lower, Par::Seq, MemStack::new(&mut mem), Default::default());
        let f = Factor { kind: FactorKind::Lblt(Lblt { sym, values: lv, subdiag, fwd, inv }), fwd: sp.pattern.fwd.clone() };
        // accept only if a test solve is backward stable: ‖K x − b‖ ≤ 1e-11 (‖K‖_F ‖x‖ + ‖b‖)
        // (a breakdown on tiny unpivoted pivots gives a much larger backward error)
        let b: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 7919) % 13) as f64 / 13.0).collect();
        let x = f.solve(&b).ok()?;
        let kx = self.sym_matvec(values, &x);
        let nrm = |v: &[f64]| v.iter().map(|t| t * t).sum::<f64>().sqrt();
        let res: f64 = kx.iter().zip(&b).map(|(p, q)| (p - q) * (p - q)).sum::<f64>().sqrt();
        let kf: f64 = (0..n)
            .flat_map(|c| (sp.pattern.col_ptr[c] as usize..sp.pattern.col_ptr[c + 1] as usize).map(move |s| (c, s)))
            .map(|(c, s)| values[s] * values[s] * if sp.pattern.row_idx[s] as usize == c { 1.0 } else { 2.0 })
            .sum::<f64>()
            .sqrt();
        let eta = res / (kf * nrm(&x) + nrm(&b));
        (eta <= 1e-11).then_some(f)
    }

    /// The full symmetric tangent as a dense matrix in the model's order of the unknowns (tests,
    /// small problems).
    pub fn dense(&self, values: &[f64]) -> Mat<f64> {
        let Ok(sp) = self.sparse_setup() else { return Mat::zeros(0, 0) };
        let n = sp.pattern.n;
        let fwd = &sp.pattern.fwd;
        let mut d = Mat::<f64>::zeros(n, n);
        for c in 0..n {
            for s in sp.pattern.col_ptr[c] as usize..sp.pattern.col_ptr[c + 1] as usize {
                let r = sp.pattern.row_idx[s] as usize;
                let (i, j) = (fwd[r] as usize, fwd[c] as usize);
                d[(i, j)] = values[s];
                d[(j, i)] = values[s];
            }
        }
        d
    }

    /// y = K x for the tangent given by its upper-triangle values.
    pub fn sym_matvec(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        let Ok(sp) = self.sparse_setup() else { return vec![0.0; x.len()] };
        let n = sp.pattern.n;
        let fwd = &sp.pattern.fwd;
        let mut y = vec![0.0; n];
        for c in 0..n {
            let oc = fwd[c] as usize;
            for s in sp.pattern.col_ptr[c] as usize..sp.pattern.col_ptr[c + 1] as usize {
                let r = sp.pattern.row_idx[s] as usize;
                let or = fwd[r] as usize;
                let v = values[s];
                y[or] += v * x[oc];
                if r != c {
                    y[oc] += v * x[or];
                }
            }
        }
        y
    }

    /// LU factorisation of the (symmetric, possibly indefinite) tangent.
    pub fn factor_lu(&self, values: &[f64]) -> Result<Factor, SolveError> {
        let sp = self.sparse_setup().map_err(|_| SolveError::Setup)?;
        let lu_sym = self.symbolic_lu.get_or_init(|| {
            // full pattern: mirror the upper triangle
            let n = sp.pattern.n;
            let mut cols: Vec<Vec<(u32, usize)>> = vec![Vec::new(); n];
            for c in 0..n {
                for s in sp.pattern.col_ptr[c] as usize..sp.pattern.col_ptr[c + 1] as usize {
                    let r = sp.pattern.row_idx[s] as usize;
                    cols[c].push((r as u32, s));
                    if r != c {
                        cols[r].push((c as u32, s));
                    }
                }
            }
            let mut col_ptr = vec![0u32];
            let mut row_idx = Vec::new();
            let mut src = Vec::new();
            for col in cols.iter_mut() {
                col.sort_by_key(|x| x.0);
                for &(r, s) in col.iter() {
                    row_idx.push(r);
                    src.push(s);
                }
                col_ptr.push(row_idx.len() as u32);
            }
            let sym = SymbolicSparseColMat::<u32>::new_checked(n, n, col_ptr, None, row_idx);
            let lu = SymbolicLu::try_new(sym.as_ref()).ok()?;
            Some((sym, src, lu))
        });
        let (sym, src, lu) = lu_sym.as_ref().ok_or(SolveError::Singular)?;
        let vals: Vec<f64> = src.iter().map(|&s| values[s]).collect();
        let a = SparseColMat::new(sym.clone(), vals);
        Lu::try_new_with_symbolic(lu.clone(), a.as_ref()).map(|l| Factor { kind: FactorKind::Lu(l), fwd: sp.pattern.fwd.clone() }).map_err(|_| SolveError::Singular)
    }
}

/// A factorised tangent (in the factorisation's order of the unknowns; [`Factor::solve`] takes
/// and returns vectors in the model's order).
pub struct Factor {
    kind: FactorKind,
    /// fwd[new] = old
    fwd: Arc<Vec<u32>>,
}

enum FactorKind {
    Llt(LltOwned),
    Lu(Lu<u32, f64>),
    Lblt(Lblt),
}

/// A Cholesky factorisation (owned storage of faer's supernodal LLᵀ factor).
struct LltOwned {
    sym: Arc<SymbolicCholesky<u32>>,
    values: Vec<f64>,
}

/// An LBLᵀ factorisation (owned storage of faer's intranodal Bunch–Kaufman factor).
struct Lblt {
    sym: Arc<SymbolicCholesky<u32>>,
    values: Vec<f64>,
    subdiag: Vec<f64>,
    fwd: Vec<u32>,
    inv: Vec<u32>,
}

impl Factor {
    pub fn solve(&self, b: &[f64]) -> Result<Vec<f64>, SolveError> {
        let fwd = &self.fwd;
        if b.len() != fwd.len() {
            return Err(SolveError::NonFinite);
        }
        let mut m = Mat::<f64>::from_fn(b.len(), 1, |i, _| b[fwd[i] as usize]);
        match &self.kind {
            FactorKind::Llt(f) => {
                let l = LltRef::new(&f.sym, &f.values);
                let mut mem = MemBuffer::new(f.sym.solve_in_place_scratch::<f64>(1, Par::Seq));
                l.solve_in_place_with_conj(Conj::No, m.as_mut(), Par::Seq, MemStack::new(&mut mem));
            }
            FactorKind::Lu(l) => l.solve_in_place(m.as_mut()),
            FactorKind::Lblt(f) => {
                let n = f.sym.nrows();
                let perm = faer::perm::PermRef::new_checked(&f.fwd, &f.inv, n);
                let l = IntranodeLbltRef::new(&f.sym, &f.values, &f.subdiag, perm);
                let mut mem = MemBuffer::new(f.sym.solve_in_place_scratch::<f64>(1, Par::Seq));
                l.solve_in_place_with_conj(Conj::No, m.as_mut(), Par::Seq, MemStack::new(&mut mem));
            }
        }
        let mut x = vec![0.0; b.len()];
        for (i, &o) in fwd.iter().enumerate() {
            x[o as usize] = m[(i, 0)];
        }
        if x.iter().all(|v| v.is_finite()) {
            Ok(x)
        } else {
            Err(SolveError::NonFinite)
        }
    }
}

impl Factor {
    /// Whether this is a Cholesky factor (the tangent was positive definite).
    pub fn is_definite(&self) -> bool {
        matches!(self.kind, FactorKind::Llt(_))
    }

    /// The unit eigenvector of the factored matrix whose eigenvalue is nearest zero, by
    /// `iterations` steps of inverse iteration from a fixed start: near a limit point or a
    /// bifurcation, the mode in which the state loses stability.
    pub fn inverse_iteration(&self, iterations: usize) -> Result<Vec<f64>, SolveError> {
        let n = self.fwd.len();
        let mut phi: Vec<f64> = (0..n).map(|i| 1.0 + 0.1 * ((i as f64) * 0.7548776662).fract()).collect();
        for _ in 0..iterations {
            let next = self.solve(&phi)?;
            let norm = next.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return Err(SolveError::NonFinite);
            }
            phi = next.iter().map(|v| v / norm).collect();
        }
        Ok(phi)
    }
}

/// Fill-reducing ordering of the tangent's symbolic analysis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Ordering {
    /// faer's approximate minimum degree
    Amd,
    /// METIS nested dissection (METIS_NodeND on the graph of the tangent)
    NestedDissection,
}

impl Default for Ordering {
    /// Nested dissection where METIS is built in, else AMD.
    fn default() -> Self {
        if cfg!(feature = "metis") {
            Ordering::NestedDissection
        } else {
            Ordering::Amd
        }
    }
}

impl Ordering {
    /// The ordering for a tangent of n unknowns, by the `ordering` benchmark on the Hex27 sector:
    /// up to the `fine` mesh (23 k DOFs) AMD and METIS ND factor equally fast within the noise of
    /// two runs (Cholesky 55–245 ms vs 72–272 ms at 9 k / 15 k DOFs) and AMD's fill is 2–6 %
    /// lower; on large meshes ND halves the fill and is 4–5× faster (85 k DOFs: 57 M vs 120 M,
    /// 3.8–5.3 s vs 19.5–20.7 s).
    pub fn for_size(n: usize) -> Ordering {
        if n > 40_000 {
            Ordering::default()
        } else {
            Ordering::Amd
        }
    }
}

/// The pattern renumbered by a fill-reducing ordering, and its symbolic Cholesky analysis (with
/// the identity ordering: the numeric factorisations then need no permutation).
fn symbolic_analysis(pattern: &Pattern, ordering: Ordering) -> Result<(Pattern, Arc<SymbolicCholesky<u32>>), ModelError> {
    // the pattern in the model's own order
    let identity: Vec<u32> = (0..pattern.n as u32).collect();
    let original = pattern.permuted(identity);
    let n = original.n;
    let fwd: Vec<u32> = match ordering {
        Ordering::Amd => {
            let sym = original.symbolic();
            let mut perm = vec![0u32; n];
            let mut perm_inv = vec![0u32; n];
            let mut mem = MemBuffer::new(faer::sparse::linalg::amd::order_scratch::<u32>(n, original.row_idx.len()));
            faer::sparse::linalg::amd::order(&mut perm, &mut perm_inv, sym.as_ref(), Default::default(), MemStack::new(&mut mem)).map_err(|e| ModelError::Symbolic(format!("{e:?}")))?;
            perm
        }
        Ordering::NestedDissection => nested_dissection(&original).ok_or_else(|| ModelError::Symbolic("nested dissection ordering failed".into()))?.0,
    };
    let permuted = original.permuted(fwd);
    // (the analysis reads the upper triangle: the transpose of the stored lower one)
    let upper = permuted.symbolic().as_ref().transpose().to_col_major().map_err(|e| ModelError::Symbolic(format!("{e:?}")))?;
    let sym = factorize_symbolic_cholesky(upper.as_ref(), Side::Upper, SymmetricOrdering::Identity, CholeskySymbolicParams::default()).map_err(|e| ModelError::Symbolic(format!("{e:?}")))?;
    Ok((permuted, Arc::new(sym)))
}

/// METIS nested-dissection permutation (fwd, inv) of the tangent's graph.
#[cfg(feature = "metis")]
fn nested_dissection(pattern: &Pattern) -> Option<(Vec<u32>, Vec<u32>)> {
    let n = pattern.n;
    if n <= 1 {
        return Some(((0..n as u32).collect(), (0..n as u32).collect()));
    }
    // symmetric adjacency without the diagonal
    let mut adj: Vec<Vec<i32>> = vec![Vec::new(); n];
    for c in 0..n {
        for s in pattern.col_ptr[c] as usize..pattern.col_ptr[c + 1] as usize {
            let r = pattern.row_idx[s] as usize;
            if r != c {
                adj[r].push(c as i32);
                adj[c].push(r as i32);
            }
        }
    }
    for a in adj.iter_mut() {
        a.sort_unstable();
        a.dedup();
    }
    // dense rows (e.g. a rigid body's DOFs, coupled to all its nodes) go last: they would
    // otherwise join every separator
    let mut degs: Vec<usize> = adj.iter().map(|a| a.len()).collect();
    degs.sort_unstable();
    let median = degs[n / 2].max(1);
    let dense: Vec<bool> = adj.iter().map(|a| a.len() > 10 * median && a.len() > 200).collect();
    let keep: Vec<usize> = (0..n).filter(|&i| !dense[i]).collect();
    let mut local = vec![usize::MAX; n];
    for (k, &i) in keep.iter().enumerate() {
        local[i] = k;
    }
    // group the DOFs that share their adjacency (the components of a node) into one vertex
    let mut group_of = vec![usize::MAX; keep.len()];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    {
        let mut seen: std::collections::HashMap<Vec<i32>, usize> = std::collections::HashMap::new();
        for (k, &i) in keep.iter().enumerate() {
            let mut key: Vec<i32> = adj[i].iter().copied().filter(|&j| !dense[j as usize]).collect();
            key.push(i as i32);
            key.sort_unstable();
            let g = *seen.entry(key).or_insert_with(|| {
                groups.push(Vec::new());
                groups.len() - 1
            });
            groups[g].push(i);
            group_of[k] = g;
        }
    }
    let ng = groups.len();
    let mut xadj = Vec::with_capacity(ng + 1);
    let mut adjncy = Vec::new();
    xadj.push(0i32);
    for g in &groups {
        let mut nb: Vec<i32> = adj[g[0]].iter().filter(|&&j| !dense[j as usize]).map(|&j| group_of[local[j as usize]] as i32).collect();
        nb.sort_unstable();
        nb.dedup();
        let me = group_of[local[g[0]]] as i32;
        nb.retain(|&x| x != me);
        adjncy.extend_from_slice(&nb);
        xadj.push(adjncy.len() as i32);
    }
    let mut vwgt: Vec<i32> = groups.iter().map(|g| g.len() as i32).collect();
    let mut nv = ng as i32;
    let mut perm = vec![0i32; ng];
    let mut iperm = vec![0i32; ng];
    let mut options = [0i32; metis_sys::METIS_NOPTIONS as usize];
    // SAFETY: METIS_SetDefaultOptions fills the options array it is given; METIS_NodeND reads the
    // CSR graph (n + 1 offsets, adjncy.len() neighbours) and writes n entries to perm and iperm,
    // all of which are allocated above with those sizes.
    let ok = unsafe {
        metis_sys::METIS_SetDefaultOptions(options.as_mut_ptr());
        metis_sys::METIS_NodeND(&mut nv, xadj.as_mut_ptr(), adjncy.as_mut_ptr(), vwgt.as_mut_ptr(), options.as_mut_ptr(), perm.as_mut_ptr(), iperm.as_mut_ptr())
    };
    if ok != metis_sys::rstatus_et_METIS_OK {
        return None;
    }
    // METIS: perm[new] = old group; expand the groups, then the dense DOFs; faer: fwd[new] = old
    let mut fwd: Vec<u32> = Vec::with_capacity(n);
    for &g in &perm {
        fwd.extend(groups[g as usize].iter().map(|&i| i as u32));
    }
    fwd.extend((0..n).filter(|&i| dense[i]).map(|i| i as u32));
    let mut inv = vec![0u32; n];
    for (new, &old) in fwd.iter().enumerate() {
        inv[old as usize] = new as u32;
    }
    Some((fwd, inv))
}

#[cfg(not(feature = "metis"))]
fn nested_dissection(_pattern: &Pattern) -> Option<(Vec<u32>, Vec<u32>)> {
    None
}

/// Cached scatter: the coefficients come from the current rows (same order as the pattern).
fn scatter_cached(t: &ElemScatter, rows: &[Vec<(u32, f64)>], ke: &[f64], kv: &mut [f64]) {
    let nd = rows.len();
    let coef: Vec<f64> = rows.iter().flat_map(|r| r.iter().map(|x| x.1)).collect();
    let nt = coef.len();
    debug_assert_eq!(nt, t.local.len());
    for p in 0..nt {
        let cp = coef[p];
        if cp == 0.0 {
            continue;
        }
        let krow = &ke[t.local[p] as usize * nd..(t.local[p] as usize + 1) * nd];
        let srow = &t.slots[p * nt..(p + 1) * nt];
        for q in 0..nt {
            let s = srow[q];
            if s != u32::MAX {
                kv[s as usize] += cp * coef[q] * krow[t.local[q] as usize];
            }
        }
    }
}

pub(crate) fn relabel(e: ElementError, el: usize) -> ElementError {
    match e {
        ElementError::BadReference(_) => ElementError::BadReference(el),
        ElementError::Inverted(_) => ElementError::Inverted(el),
        ElementError::NonFinite(_) => ElementError::NonFinite(el),
        ElementError::Setup => ElementError::Setup,
        ElementError::Penetration(n) => ElementError::Penetration(n),
    }
}

/// The pattern of the elements, the rigid bodies' DOFs and the extra node groups (e.g. contact
/// pairs), each group coupling all of its nodes.
fn build_pattern(mesh: &Mesh, dofs: &DofMap, groups: &[Vec<usize>]) -> Pattern {
    let n = dofs.n_reduced();
    let mut cols: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut idx = Vec::new();
    for e in (0..mesh.n_elements()).map(|e| mesh.element(e)).chain(groups.iter().map(|g| g.as_slice())) {
        idx.clear();
        for &node in e {
            for c in 0..3 {
                dofs.row_pattern(node, c, &mut idx);
            }
        }
        idx.sort_unstable();
        idx.dedup();
        for (a, &k) in idx.iter().enumerate() {
            for &l in &idx[a..] {
                cols[l as usize].push(k);
            }
        }
    }
    for b in 0..dofs.bodies.len() {
        let free: Vec<u32> = dofs.body_dofs[b].iter().filter_map(|d| if let crate::dofmap::BodyDof::Free(i) = d { Some(*i as u32) } else { None }).collect();
        for (a, &k) in free.iter().enumerate() {
            for &l in &free[a..] {
                cols[l.max(k) as usize].push(k.min(l));
            }
        }
    }
    let mut col_ptr = vec![0u32];
    let mut row_idx = Vec::new();
    for (c, col) in cols.iter_mut().enumerate() {
        col.push(c as u32); // diagonal always present
        col.sort_unstable();
        col.dedup();
        row_idx.extend_from_slice(col);
        col_ptr.push(row_idx.len() as u32);
    }
    let identity: Arc<Vec<u32>> = Arc::new((0..n as u32).collect());
    Pattern { n, col_ptr, row_idx, fwd: identity.clone(), inv: identity }
}

/// Moment about a point and force of the nodal reactions of a node set, in the current configuration.
pub fn resultant(nodes: &[usize], x0: &[[f64; 3]], u: &[[f64; 3]], r_full: &[f64], about: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut f = [0.0; 3];
    let mut m = [0.0; 3];
    for &n in nodes {
        let rv = [r_full[3 * n], r_full[3 * n + 1], r_full[3 * n + 2]];
        let x = [x0[n][0] + u[n][0] - about[0], x0[n][1] + u[n][1] - about[1], x0[n][2] + u[n][2] - about[2]];
        for i in 0..3 {
            f[i] += rv[i];
        }
        let c = crate::scalar::cross(x, rv);
        for i in 0..3 {
            m[i] += c[i];
        }
    }
    (f, m)
}
