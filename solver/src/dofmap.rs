//! Constraints and the map from the reduced unknowns q to nodal displacements u(q).
//!
//! Each nodal displacement component is one of:
//! * free: its own reduced unknown;
//! * prescribed: a value set by the load path (0 = fixed);
//! * linear: Σ c_k q_k — a cyclic-symmetry slave u_b = Q u_a of a free master node;
//! * rigid: the component of c + (R(ψ) − I)(X − X_ref) of a rigid body with translation c and
//!   rotation vector ψ (exact large rotations, R = exp[ψ×]).
//!
//! Rigid-body DOFs (3 translations, 3 rotation-vector components) are themselves free or
//! prescribed. The reduced residual is r = (∂u/∂q)ᵀ R(u) and the reduced tangent
//! (∂u/∂q)ᵀ K (∂u/∂q) + Σ R_i ∂²u_i/∂q² (the last term from the rotations).

use crate::scalar::Scalar;
use num_dual::HyperDual64;

/// How one scalar DOF is treated.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum DofSpec {
    Free,
    /// Held at a value (scaled along the load path like every prescribed value).
    Prescribed(f64),
}

/// A rigid body: a reference point with 6 DOFs (translation x,y,z; rotation vector x,y,z) to which
/// the components `mask` of a node set are kinematically coupled.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RigidBody {
    pub name: String,
    pub reference: [f64; 3],
    pub nodes: Vec<usize>,
    pub mask: [bool; 3],
    pub dofs: [DofSpec; 6],
}

/// Rotational periodicity: u(b) = Q u(a) for each pair (a, b), Q = rotation by `angle` about +z.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Cyclic {
    pub pairs: Vec<(usize, usize)>,
    pub angle: f64,
}

/// Affine (helical) periodicity between two node sets: for each pair (a, b)
///
///   x_b = Q(angle0 + α) x_a + (Z_b − Z_a + s) e_z,
///
/// Q(φ) the rotation by φ about +z, x the current positions. `angle0` is the fixed reference
/// rotation from a to b (0 for the two end faces of an axial slice, 2π/n for a cyclic sector) —
/// the reference nodes must satisfy X_b = Q(angle0) X_a + (Z_b − Z_a) e_z. The extra rotation α
/// (`twist`, the value at the end of the load path) is a prescribed slot interpolated along the
/// path like every prescribed value; the axial shift s is free or prescribed.
///
/// In displacements u_b = Q u_a + Q X_a + (Z_b − Z_a + s) e_z − X_b: linear in the master's
/// displacement, whatever that is (free, prescribed or a cyclic slave), so the master may carry
/// other constraints; a slave must be otherwise unconstrained, and a master may be neither a
/// periodic slave nor rigid-body coupled.
///
/// With a = the bottom face and b = the top face of an axial slice of height h, α = ψ h and
/// s = (λ_z − 1) h, it represents exactly a helically invariant field (uniform torsion, extension,
/// inflation of an infinitely long tube): the slice is a period of the infinite tube.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Periodic {
    pub pairs: Vec<(usize, usize)>,
    pub angle0: f64,
    pub twist: f64,
    pub shift: DofSpec,
}

/// All kinematic constraints of a model.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Constraints {
    /// (node, component, prescribed value at the end of the load path; 0 = fixed)
    pub prescribed: Vec<(usize, usize, f64)>,
    pub cyclic: Option<Cyclic>,
    pub bodies: Vec<RigidBody>,
    #[serde(default)]
    pub periodic: Vec<Periodic>,
}

impl Constraints {
    /// Prescribe components `comps` of every node in `nodes` to `value` (0 = fixed).
    pub fn prescribe_set(&mut self, nodes: &[usize], comps: &[usize], value: f64) {
        for &n in nodes {
            for &c in comps {
                self.prescribed.push((n, c, value));
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Comp {
    Free(u32),
    Presc(u32),
    /// start index and count into `terms`
    Lin(u32, u8),
    Rigid(u16),
    /// index into `per_pairs`
    Periodic(u32),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BodyDof {
    Free(usize),
    Presc(usize),
}

/// Errors in the constraint definition.
#[derive(Debug, thiserror::Error)]
pub enum ConstraintError {
    #[error("node {0} is constrained twice ({1})")]
    Conflict(usize, &'static str),
    #[error("cyclic pair ({0}, {1}): one node is constrained and the other is not")]
    CyclicMismatch(usize, usize),
    #[error("node index {0} out of range")]
    BadNode(usize),
    #[error("periodic pair ({0}, {1}): the reference nodes do not satisfy X_b = Q(angle0) X_a + Δz e_z")]
    PeriodicMismatch(usize, usize),
    #[error("non-finite value in a constraint")]
    NonFinite,
}

/// The compiled map u(q).
#[derive(Clone, Debug)]
pub struct DofMap {
    pub(crate) comps: Vec<Comp>, // 3 per node
    pub(crate) terms: Vec<(u32, f64)>,
    pub n_free: usize,
    pub body_dofs: Vec<[BodyDof; 6]>,
    pub bodies: Vec<RigidBody>,
    /// target value of each prescribed slot at the end of a load path
    pub presc_targets: Vec<f64>,
    /// (node, comp) of each prescribed nodal slot (body slots are listed in body_dofs)
    pub presc_nodes: Vec<(usize, usize)>,
    pub periodic: Vec<Periodic>,
    /// per periodic constraint: (prescribed slot of the twist α, the shift s)
    pub periodic_dofs: Vec<(usize, BodyDof)>,
    /// (master node, periodic constraint) of each periodic slave
    pub(crate) per_pairs: Vec<(u32, u32)>,
}

/// Kinematics of one rigid body at the current state.
#[derive(Clone, Debug)]
pub struct BodyKin {
    pub c: [f64; 3],
    pub psi: [f64; 3],
    pub r: [[f64; 3]; 3],
    pub dr: [[[f64; 3]; 3]; 3],
    pub d2r: [[[[f64; 3]; 3]; 3]; 3],
}

/// R(ψ) = I + a(s) K + b(s) K², K = [ψ×], s = |ψ|², generic over the scalar (Rodrigues with a
/// series near ψ = 0 so that derivatives stay exact there).
pub fn rotation<D: Scalar>(psi: [D; 3]) -> [[D; 3]; 3] {
    let s = psi[0] * psi[0] + psi[1] * psi[1] + psi[2] * psi[2];
    let (a, b) = if s.re() < 1e-2 {
        (D::one() - s / 6.0 + s * s / 120.0 - s * s * s / 5040.0 + s * s * s * s / 362880.0, D::from(0.5) - s / 24.0 + s * s / 720.0 - s * s * s / 40320.0 + s * s * s * s / 3628800.0)
    } else {
        let n = s.sqrt();
        (n.sin() / n, (D::one() - n.cos()) / s)
    };
    let k = [[D::zero(), -psi[2], psi[1]], [psi[2], D::zero(), -psi[0]], [-psi[1], psi[0], D::zero()]];
    let mut r = [[D::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let mut k2 = D::zero();
            for m in 0..3 {
                k2 += k[i][m] * k[m][j];
            }
            r[i][j] = k[i][j] * a + k2 * b;
        }
        r[i][i] += D::one();
    }
    r
}

impl BodyKin {
    pub fn new(c: [f64; 3], psi: [f64; 3]) -> Self {
        let mut dr = [[[0.0; 3]; 3]; 3];
        let mut d2r = [[[[0.0; 3]; 3]; 3]; 3];
        for a in 0..3 {
            for b in a..3 {
                let mut p = [HyperDual64::from(psi[0]), HyperDual64::from(psi[1]), HyperDual64::from(psi[2])];
                p[a].eps1 = 1.0;
                p[b].eps2 = 1.0;
                let rr = rotation(p);
                for i in 0..3 {
                    for j in 0..3 {
                        dr[a][i][j] = rr[i][j].eps1;
                        dr[b][i][j] = rr[i][j].eps2;
                        d2r[a][b][i][j] = rr[i][j].eps1eps2;
                        d2r[b][a][i][j] = rr[i][j].eps1eps2;
                    }
                }
            }
        }
        BodyKin { c, psi, r: rotation(psi), dr, d2r }
    }
    /// Displacement of a point at offset d = X − X_ref.
    pub fn disp(&self, d: [f64; 3]) -> [f64; 3] {
        let mut u = self.c;
        for i in 0..3 {
            u[i] += (0..3).map(|j| self.r[i][j] * d[j]).sum::<f64>() - d[i];
        }
        u
    }
}

impl DofMap {
    /// The nodes whose three displacement components are all free unknowns, with those
    /// unknowns' indices (x, y, z).
    pub fn free_nodes(&self) -> Vec<(usize, [usize; 3])> {
        (0..self.comps.len() / 3)
            .filter_map(|n| match (self.comps[3 * n], self.comps[3 * n + 1], self.comps[3 * n + 2]) {
                (Comp::Free(a), Comp::Free(b), Comp::Free(c)) => Some((n, [a as usize, b as usize, c as usize])),
                _ => None,
            })
            .collect()
    }

    /// Compile the constraints of a mesh with reference coordinates `x0`.
    pub fn build(x0: &[[f64; 3]], cons: &Constraints) -> Result<DofMap, ConstraintError> {
        let n_nodes = x0.len();
        #[derive(Clone, Copy, PartialEq)]
        enum Tag {
            Free,
            Presc(usize),
            Rigid(u16),
        }
        let mut tag = vec![Tag::Free; 3 * n_nodes];
        let mut presc_targets = Vec::new();
        let mut presc_nodes = Vec::new();
        for &(n, c, v) in &cons.prescribed {
            if n >= n_nodes {
                return Err(ConstraintError::BadNode(n));
            }
            if tag[3 * n + c] != Tag::Free {
                // the same DOF listed twice: keep the first unless values differ
                continue;
            }
            tag[3 * n + c] = Tag::Presc(presc_targets.len());
            presc_targets.push(v);
            presc_nodes.push((n, c));
        }
        for (bi, b) in cons.bodies.iter().enumerate() {
            for &n in &b.nodes {
                if n >= n_nodes {
                    return Err(ConstraintError::BadNode(n));
                }
                for c in 0..3 {
                    if b.mask[c] {
                        if tag[3 * n + c] != Tag::Free {
                            return Err(ConstraintError::Conflict(n, "rigid body on a constrained DOF"));
                        }
                        tag[3 * n + c] = Tag::Rigid(bi as u16);
                    }
                }
            }
        }
        // cyclic slaves
        let mut slave_of = vec![usize::MAX; n_nodes];
        if let Some(cy) = &cons.cyclic {
            for &(a, b) in &cy.pairs {
                if a >= n_nodes || b >= n_nodes {
                    return Err(ConstraintError::BadNode(a.max(b)));
                }
                let fa = (0..3).all(|c| tag[3 * a + c] == Tag::Free);
                let fb = (0..3).all(|c| tag[3 * b + c] == Tag::Free);
                let ca = (0..3).all(|c| tag[3 * a + c] != Tag::Free);
                let cb = (0..3).all(|c| tag[3 * b + c] != Tag::Free);
                if fa && fb {
                    if slave_of[b] != usize::MAX {
                        return Err(ConstraintError::Conflict(b, "cyclic slave twice"));
                    }
                    slave_of[b] = a;
                } else if !(ca && cb) {
                    return Err(ConstraintError::CyclicMismatch(a, b));
                }
            }
        }
        // periodic slaves (b of each pair): must be otherwise unconstrained
        let mut per_master = vec![(usize::MAX, 0usize); n_nodes];
        for (pi, per) in cons.periodic.iter().enumerate() {
            if !per.angle0.is_finite() || !per.twist.is_finite() || matches!(per.shift, DofSpec::Prescribed(v) if !v.is_finite()) {
                return Err(ConstraintError::NonFinite);
            }
            for &(a, b) in &per.pairs {
                if a >= n_nodes || b >= n_nodes {
                    return Err(ConstraintError::BadNode(a.max(b)));
                }
                if a == b || (0..3).any(|c| tag[3 * b + c] != Tag::Free) || slave_of[b] != usize::MAX || per_master[b].0 != usize::MAX {
                    return Err(ConstraintError::Conflict(b, "periodic slave carries another constraint"));
                }
                per_master[b] = (a, pi);
            }
        }
        for per in &cons.periodic {
            let (s0, c0) = per.angle0.sin_cos();
            for &(a, b) in &per.pairs {
                if per_master[a].0 != usize::MAX || (0..3).any(|c| matches!(tag[3 * a + c], Tag::Rigid(_))) {
                    return Err(ConstraintError::Conflict(a, "periodic master is a periodic slave or rigid"));
                }
                let (xa, xb) = (x0[a], x0[b]);
                let scale = 1.0 + xa[0].abs().max(xa[1].abs()).max(xb[0].abs()).max(xb[1].abs());
                let ex = c0 * xa[0] - s0 * xa[1] - xb[0];
                let ey = s0 * xa[0] + c0 * xa[1] - xb[1];
                if !(ex.abs() <= 1e-9 * scale && ey.abs() <= 1e-9 * scale) {
                    return Err(ConstraintError::PeriodicMismatch(a, b));
                }
            }
        }
        let mut comps = vec![Comp::Presc(0); 3 * n_nodes];
        let mut n_free = 0u32;
        let mut per_pairs = Vec::new();
        for n in 0..n_nodes {
            if slave_of[n] != usize::MAX {
                continue;
            }
            if per_master[n].0 != usize::MAX {
                for c in 0..3 {
                    comps[3 * n + c] = Comp::Periodic(per_pairs.len() as u32);
                }
                per_pairs.push((per_master[n].0 as u32, per_master[n].1 as u32));
                continue;
            }
            for c in 0..3 {
                comps[3 * n + c] = match tag[3 * n + c] {
                    Tag::Free => {
                        n_free += 1;
                        Comp::Free(n_free - 1)
                    }
                    Tag::Presc(s) => Comp::Presc(s as u32),
                    Tag::Rigid(b) => Comp::Rigid(b),
                };
            }
        }
        let mut terms = Vec::new();
        if let Some(cy) = &cons.cyclic {
            let (s, co) = cy.angle.sin_cos();
            let q = [[co, -s, 0.0], [s, co, 0.0], [0.0, 0.0, 1.0]];
            for n in 0..n_nodes {
                let a = slave_of[n];
                if a == usize::MAX {
                    continue;
                }
                if slave_of[a] != usize::MAX {
                    return Err(ConstraintError::Conflict(a, "cyclic master is itself a slave"));
                }
                for i in 0..3 {
                    let start = terms.len() as u32;
                    for j in 0..3 {
                        if q[i][j] != 0.0 {
                            if let Comp::Free(k) = comps[3 * a + j] {
                                terms.push((k, q[i][j]));
                            }
                        }
                    }
                    comps[3 * n + i] = Comp::Lin(start, (terms.len() as u32 - start) as u8);
                }
            }
        }
        let mut n_red = n_free as usize;
        let mut body_dofs = Vec::new();
        for b in &cons.bodies {
            let mut d = [BodyDof::Free(0); 6];
            for (k, spec) in b.dofs.iter().enumerate() {
                d[k] = match spec {
                    DofSpec::Free => {
                        n_red += 1;
                        BodyDof::Free(n_red - 1)
                    }
                    DofSpec::Prescribed(v) => {
                        presc_targets.push(*v);
                        BodyDof::Presc(presc_targets.len() - 1)
                    }
                };
            }
            body_dofs.push(d);
        }
        let mut periodic_dofs = Vec::new();
        for per in &cons.periodic {
            presc_targets.push(per.twist);
            let twist_slot = presc_targets.len() - 1;
            let shift = match per.shift {
                DofSpec::Free => {
                    n_red += 1;
                    BodyDof::Free(n_red - 1)
                }
                DofSpec::Prescribed(v) => {
                    presc_targets.push(v);
                    BodyDof::Presc(presc_targets.len() - 1)
                }
            };
            periodic_dofs.push((twist_slot, shift));
        }
        Ok(DofMap { comps, terms, n_free: n_red, body_dofs, bodies: cons.bodies.clone(), presc_targets, presc_nodes, periodic: cons.periodic.clone(), periodic_dofs, per_pairs })
    }

    /// Number of reduced unknowns (free nodal DOFs + free rigid-body DOFs).
    pub fn n_reduced(&self) -> usize {
        self.n_free
    }

    /// Number of free nodal unknowns: they are numbered first (0..n_nodal), the free rigid-body
    /// and periodic-shift DOFs after them. Models of one mesh whose constraints differ only in
    /// their rigid-body DOFs share this numbering (a reduced basis of the nodal unknowns serves them all).
    pub fn n_nodal(&self) -> usize {
        self.comps.iter().filter_map(|c| if let Comp::Free(k) = c { Some(*k as usize + 1) } else { None }).max().unwrap_or(0)
    }

    /// Value of body DOF k of body b.
    pub fn body_value(&self, b: usize, k: usize, q: &[f64], presc: &[f64]) -> f64 {
        match self.body_dofs[b][k] {
            BodyDof::Free(i) => q[i],
            BodyDof::Presc(s) => presc[s],
        }
    }

    /// Kinematics of the rigid bodies, followed by one entry per periodic constraint (its
    /// rotation Q(angle0 + α) about z as ψ = (0, 0, angle0 + α), and its shift as c = (0, 0, s)).
    pub fn body_kinematics(&self, q: &[f64], presc: &[f64]) -> Vec<BodyKin> {
        let mut kin: Vec<BodyKin> = (0..self.bodies.len())
            .map(|b| {
                let v: Vec<f64> = (0..6).map(|k| self.body_value(b, k, q, presc)).collect();
                BodyKin::new([v[0], v[1], v[2]], [v[3], v[4], v[5]])
            })
            .collect();
        for (per, &(slot, shift)) in self.periodic.iter().zip(&self.periodic_dofs) {
            let s = match shift {
                BodyDof::Free(i) => q[i],
                BodyDof::Presc(k) => presc[k],
            };
            let phi = per.angle0 + presc[slot];
            let (sn, cs) = phi.sin_cos();
            let mut r = [[0.0; 3]; 3];
            r[0] = [cs, -sn, 0.0];
            r[1] = [sn, cs, 0.0];
            r[2][2] = 1.0;
            // only r is used for periodic constraints (the map is linear in q for a given α)
            kin.push(BodyKin { c: [0.0, 0.0, s], psi: [0.0, 0.0, phi], r, dr: [[[0.0; 3]; 3]; 3], d2r: [[[[0.0; 3]; 3]; 3]; 3] });
        }
        kin
    }

    /// Full nodal displacements u(q) given the reference coordinates.
    pub fn expand(&self, x0: &[[f64; 3]], q: &[f64], presc: &[f64], kin: &[BodyKin]) -> Vec<[f64; 3]> {
        let n = x0.len();
        let mut u = vec![[0.0; 3]; n];
        for node in 0..n {
            for c in 0..3 {
                u[node][c] = match self.comps[3 * node + c] {
                    Comp::Free(k) => q[k as usize],
                    Comp::Presc(s) => presc[s as usize],
                    Comp::Lin(s, l) => self.terms[s as usize..(s as usize + l as usize)].iter().map(|(k, cf)| cf * q[*k as usize]).sum(),
                    Comp::Rigid(b) => {
                        let body = &self.bodies[b as usize];
                        let d = sub(x0[node], body.reference);
                        kin[b as usize].disp(d)[c]
                    }
                    Comp::Periodic(_) => 0.0, // second pass
                };
            }
        }
        // periodic slaves: u_b = Q (X_a + u_a) + (Z_b − Z_a + s) e_z − X_b (masters are done)
        if !self.per_pairs.is_empty() {
            for node in 0..n {
                if let Comp::Periodic(k) = self.comps[3 * node] {
                    let (a, p) = self.per_pairs[k as usize];
                    let (a, p) = (a as usize, p as usize);
                    let pk = &kin[self.bodies.len() + p];
                    let xa = [x0[a][0] + u[a][0], x0[a][1] + u[a][1], x0[a][2] + u[a][2]];
                    for c in 0..3 {
                        let mut v = (0..3).map(|j| pk.r[c][j] * xa[j]).sum::<f64>() - x0[node][c];
                        if c == 2 {
                            v += x0[node][2] - x0[a][2] + pk.c[2];
                        }
                        u[node][c] = v;
                    }
                }
            }
        }
        u
    }

    /// Row of ∂u/∂q for one nodal component: appends (reduced index, coefficient) pairs.
    #[inline]
    pub fn row(&self, x0: &[[f64; 3]], kin: &[BodyKin], node: usize, c: usize, out: &mut Vec<(u32, f64)>) {
        match self.comps[3 * node + c] {
            Comp::Free(k) => out.push((k, 1.0)),
            Comp::Presc(_) => {}
            Comp::Lin(s, l) => out.extend_from_slice(&self.terms[s as usize..s as usize + l as usize]),
            Comp::Rigid(b) => {
                let b = b as usize;
                let d = sub(x0[node], self.bodies[b].reference);
                for k in 0..6 {
                    if let BodyDof::Free(i) = self.body_dofs[b][k] {
                        let coef = if k < 3 {
                            if k == c {
                                1.0
                            } else {
                                0.0
                            }
                        } else {
                            let dr = &kin[b].dr[k - 3];
                            dr[c][0] * d[0] + dr[c][1] * d[1] + dr[c][2] * d[2]
                        };
                        out.push((i as u32, coef));
                    }
                }
            }
            Comp::Periodic(k) => {
                let (a, p) = self.per_pairs[k as usize];
                let pk = &kin[self.bodies.len() + p as usize];
                for j in 0..3 {
                    let qcj = pk.r[c][j];
                    if qcj != 0.0 {
                        let start = out.len();
                        self.row(x0, kin, a as usize, j, out);
                        for t in &mut out[start..] {
                            t.1 *= qcj;
                        }
                    }
                }
                if c == 2 {
                    if let BodyDof::Free(i) = self.periodic_dofs[p as usize].1 {
                        out.push((i as u32, 1.0));
                    }
                }
            }
        }
    }

    /// Reduced indices a nodal component can touch (state independent), for the sparsity pattern.
    pub fn row_pattern(&self, node: usize, c: usize, out: &mut Vec<u32>) {
        match self.comps[3 * node + c] {
            Comp::Free(k) => out.push(k),
            Comp::Presc(_) => {}
            Comp::Lin(s, l) => out.extend(self.terms[s as usize..s as usize + l as usize].iter().map(|t| t.0)),
            Comp::Rigid(b) => {
                for k in 0..6 {
                    if let BodyDof::Free(i) = self.body_dofs[b as usize][k] {
                        out.push(i as u32);
                    }
                }
            }
            Comp::Periodic(k) => {
                let (a, p) = self.per_pairs[k as usize];
                // Q couples x and y (for any α); z maps to z
                let js: &[usize] = if c == 2 { &[2] } else { &[0, 1] };
                for &j in js {
                    self.row_pattern(a as usize, j, out);
                }
                if c == 2 {
                    if let BodyDof::Free(i) = self.periodic_dofs[p as usize].1 {
                        out.push(i as u32);
                    }
                }
            }
        }
    }

    /// Whether a nodal component is a rigid slave (and of which body).
    pub fn rigid_body_of(&self, node: usize, c: usize) -> Option<usize> {
        match self.comps[3 * node + c] {
            Comp::Rigid(b) => Some(b as usize),
            _ => None,
        }
    }

    /// Whether a nodal component is held by a prescribed value.
    pub fn is_prescribed(&self, node: usize, c: usize) -> bool {
        matches!(self.comps[3 * node + c], Comp::Presc(_))
    }
}

#[inline]
pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_derivatives_match_fd() {
        for psi in [[0.0, 0.0, 0.0], [0.1, -0.3, 1.2], [0.0, 0.0, 2.5], [1e-4, 0.0, 0.0]] {
            let kin = BodyKin::new([0.0; 3], psi);
            // orthogonality
            for i in 0..3 {
                for j in 0..3 {
                    let v: f64 = (0..3).map(|m| kin.r[m][i] * kin.r[m][j]).sum();
                    assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-14);
                }
            }
            let h = 1e-6;
            for a in 0..3 {
                let mut pp = psi;
                let mut pm = psi;
                pp[a] += h;
                pm[a] -= h;
                let (kp, km) = (BodyKin::new([0.0; 3], pp), BodyKin::new([0.0; 3], pm));
                for i in 0..3 {
                    for j in 0..3 {
                        assert!(((kp.r[i][j] - km.r[i][j]) / (2.0 * h) - kin.dr[a][i][j]).abs() < 1e-8);
                        for b in 0..3 {
                            let fd = (kp.dr[b][i][j] - km.dr[b][i][j]) / (2.0 * h);
                            assert!((fd - kin.d2r[a][b][i][j]).abs() < 1e-7, "{psi:?} {a}{b}{i}{j}");
                        }
                    }
                }
            }
        }
        // rotation about z by φ
        let kin = BodyKin::new([0.0; 3], [0.0, 0.0, 0.7]);
        assert!((kin.r[0][0] - 0.7f64.cos()).abs() < 1e-15 && (kin.r[1][0] - 0.7f64.sin()).abs() < 1e-15);
    }

    #[test]
    fn periodic_constraint_errors() {
        // two nodes stacked on z, and one off-axis
        let x0 = [[1.0, 0.0, 0.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]];
        let per = |pairs: Vec<(usize, usize)>, angle0: f64, shift: DofSpec| Periodic { pairs, angle0, twist: 0.1, shift };
        let build = |p: Periodic, presc: Vec<(usize, usize, f64)>| DofMap::build(&x0, &Constraints { prescribed: presc, periodic: vec![p], ..Default::default() });
        assert!(build(per(vec![(0, 1)], 0.0, DofSpec::Free), vec![]).is_ok());
        // node 2 is node 0 rotated by 90°
        assert!(build(per(vec![(0, 2)], std::f64::consts::FRAC_PI_2, DofSpec::Free), vec![]).is_ok());
        assert!(matches!(build(per(vec![(0, 2)], 0.0, DofSpec::Free), vec![]), Err(ConstraintError::PeriodicMismatch(0, 2))));
        assert!(matches!(build(per(vec![(0, 1)], f64::NAN, DofSpec::Free), vec![]), Err(ConstraintError::NonFinite)));
        assert!(matches!(build(per(vec![(0, 1)], 0.0, DofSpec::Prescribed(f64::INFINITY)), vec![]), Err(ConstraintError::NonFinite)));
        assert!(matches!(build(per(vec![(0, 1)], 0.0, DofSpec::Free), vec![(1, 0, 0.0)]), Err(ConstraintError::Conflict(1, _))));
        assert!(matches!(build(per(vec![(0, 7)], 0.0, DofSpec::Free), vec![]), Err(ConstraintError::BadNode(7))));
        // a prescribed master is allowed: u_b = Q u_a + …, and the map is as documented
        let d = build(per(vec![(0, 1)], 0.0, DofSpec::Prescribed(0.3)), vec![(0, 2, 0.0)]).unwrap();
        let presc = vec![0.0, 0.2, 0.3]; // u_z(0), twist α, shift s
        let q: Vec<f64> = (0..d.n_reduced()).map(|i| 0.01 * (i + 1) as f64).collect();
        let kin = d.body_kinematics(&q, &presc);
        let u = d.expand(&x0, &q, &presc, &kin);
        let xa = [x0[0][0] + u[0][0], x0[0][1] + u[0][1], x0[0][2] + u[0][2]];
        let (sn, cs) = 0.2f64.sin_cos();
        let xb = [cs * xa[0] - sn * xa[1], sn * xa[0] + cs * xa[1], xa[2] + 2.0 + 0.3];
        for c in 0..3 {
            assert!((x0[1][c] + u[1][c] - xb[c]).abs() < 1e-15);
        }
    }
}
