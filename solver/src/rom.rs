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
use crate::material::Hyperelastic;
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
    #[error("the Piola frame needs the reference mesh's {0} node positions, the basis has {1}")]
    Reference(usize, usize),
    #[error("the map from the reference mesh is singular or inverted at node {0} (det {1:.3e})")]
    MapJacobian(usize, f64),
    #[error("the pressure basis has {0} rows, the mesh needs {1} ({2} per element)")]
    PressureSize(usize, usize, usize),
    #[error("the reduced pressure space's mass matrix is singular on this sample")]
    PressureMass,
    #[error("element {0} in the sample, but the mesh has {1} elements")]
    SampleElement(usize, usize),
    #[error("element evaluation failed: {0}")]
    Element(#[from] ElementError),
    #[error("sensitivity: the reduced model has {0} coordinates, the perturbed ones {1} and {2}")]
    SensitivityDims(usize, usize, usize),
    #[error("sensitivity: the reduced tangent's factor cannot be solved with (singular)")]
    SingularTangent,
    #[error("a quadrature-level sample needs a reduced pressure space (an element's own pressure is condensed over all its points)")]
    PointsWithoutPressure,
    #[error("sample entry {0}: quadrature point {1}, but the element rule has {2}")]
    SamplePoint(usize, usize, usize),
    #[error("the quadrature-level ECSW fit does not take tangent directions")]
    PointsWithTangents,
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
    /// Components on a reference mesh of the same topology ([`Basis::reference`]), pushed
    /// forward to each model by the contravariant Piola map of the nodal map X_ref → X:
    /// u = J ũ / det J with J = ∂X/∂X_ref at each node (averaged over the elements that share
    /// it). div u = div ũ / det J, so a mode that is isochoric on the reference stays nearly
    /// isochoric on every geometry of the family: without it, a basis shared by geometries locks
    /// volumetrically when the material is nearly incompressible (the reduced model is too stiff
    /// and misses its limit points).
    Piola,
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
    /// the reference mesh's node positions (the [`Frame::Piola`] frame only; empty otherwise)
    #[serde(default)]
    pub reference: Vec<[f64; 3]>,
    /// row-major: entry (i, j) at v[i k + j]
    pub v: Vec<f64>,
    /// every singular value of the snapshot matrix (not only the kept ones)
    pub singular_values: Vec<f64>,
    /// a reduced pressure space (None: each element condenses its own pressure, as the full model)
    #[serde(default)]
    pub pressure: Option<PressureBasis>,
    /// singular values of the modes [`Basis::append_directions`] appended after the POD modes
    /// (the last `appended_singular_values.len()` columns; empty: none)
    #[serde(default)]
    pub appended_singular_values: Vec<f64>,
}

/// A reduced pressure space: modes of the elements' discontinuous pressure coefficients
/// (`np` per element, element-major: row e·np + r), shared by every geometry of the mesh. With
/// it, the reduced model projects the dilatation J and the pressure U'(θ) on these kp modes
/// (a global three-field Hu–Washizu condensation) instead of each element's own pressure
/// space: the incompressibility constraint then has kp components, not np per element, and a
/// basis shared by many geometries no longer locks.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PressureBasis {
    /// pressure coefficients per element
    pub np: usize,
    pub kp: usize,
    /// row-major ((n_elements · np) × kp)
    pub psi: Vec<f64>,
    pub singular_values: Vec<f64>,
}

impl PressureBasis {
    /// POD of pressure snapshots ([`crate::element::pressure_coefficients`] of every element,
    /// element-major), with `np` coefficients per element.
    ///
    /// The first mode is the element-wise constant field (coefficient 1 on each element's
    /// constant pressure function, normalised), the others the POD of the snapshots with that
    /// field removed (`trunc` counts both): the reduced dilatation, the L2 projection of det F on
    /// the space, then holds det F = 1 exactly. Without it, a space whose modes carry no mean (the
    /// pure-twist scenes' pressure varies in sign over the wall) projected det F ≈ 1 to a field
    /// that is negative in places: every state of such a model read as inverted.
    pub fn pod(snapshots: &[Vec<f64>], np: usize, trunc: Truncation) -> Result<PressureBasis, RomError> {
        let Some(first) = snapshots.first() else { return Err(RomError::NoSnapshots) };
        let len = first.len();
        let np = np.max(1);
        let mut c = vec![0.0; len];
        for e in 0..len / np {
            c[e * np] = 1.0;
        }
        let cn = (c.iter().map(|x| x * x).sum::<f64>()).sqrt().max(f64::MIN_POSITIVE);
        c.iter_mut().for_each(|x| *x /= cn);
        let mut along = 0.0;
        let deflated: Vec<Vec<f64>> = snapshots
            .iter()
            .map(|s| {
                let a: f64 = s.iter().zip(&c).map(|(x, y)| x * y).sum();
                along += a * a;
                s.iter().zip(&c).map(|(x, y)| x - a * y).collect()
            })
            .collect();
        let rest = match trunc {
            Truncation::Modes(k) => Truncation::Modes(k.saturating_sub(1)),
            Truncation::Tail { tol, max } => Truncation::Tail { tol, max: max.saturating_sub(1) },
        };
        let b = Basis::pod(&deflated, rest)?;
        let kp = b.k + 1;
        let mut psi = vec![0.0; len * kp];
        for i in 0..len {
            psi[i * kp] = c[i];
            psi[i * kp + 1..(i + 1) * kp].copy_from_slice(&b.v[i * b.k..(i + 1) * b.k]);
        }
        let mut singular_values = vec![along.sqrt()];
        singular_values.extend(b.singular_values);
        Ok(PressureBasis { np, kp, psi, singular_values })
    }
    /// Ψ_e (np × kp, row-major): element e's block.
    #[inline]
    pub fn block(&self, e: usize) -> &[f64] {
        &self.psi[e * self.np * self.kp..(e + 1) * self.np * self.kp]
    }
    /// The first kp modes only.
    pub fn truncated(&self, kp: usize) -> PressureBasis {
        let kp = kp.min(self.kp);
        let rows = self.psi.len() / self.kp.max(1);
        let mut psi = vec![0.0; rows * kp];
        for i in 0..rows {
            psi[i * kp..(i + 1) * kp].copy_from_slice(&self.psi[i * self.kp..i * self.kp + kp]);
        }
        PressureBasis { np: self.np, kp, psi, singular_values: self.singular_values.clone() }
    }
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
        Ok(Basis { frame: Frame::Cartesian, n, k, reference: Vec::new(), v, singular_values: s, pressure: None, appended_singular_values: Vec::new() })
    }

    /// Append directions that the snapshots do not span (e.g. the tangent's null vectors at the
    /// training paths' instabilities, which no converged state contains): each direction is
    /// normalised, its component in the basis removed (two Gram–Schmidt passes), and the POD of
    /// what is left gives at most `max` new modes, those whose singular value is above `tol`
    /// (a direction entirely outside the basis counts 1). Returns the singular values of the
    /// appended modes. The basis stays orthonormal; the first k modes are unchanged.
    pub fn append_directions(&mut self, directions: &[Vec<f64>], max: usize, tol: f64) -> Result<Vec<f64>, RomError> {
        let (n, k) = (self.n, self.k);
        let mut rest: Vec<Vec<f64>> = Vec::new();
        for (i, d) in directions.iter().enumerate() {
            if d.len() != n {
                return Err(RomError::SnapshotSize(i, d.len(), n));
            }
            if !d.iter().all(|v| v.is_finite()) {
                return Err(RomError::NonFinite(i));
            }
            let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm == 0.0 {
                continue;
            }
            let mut r: Vec<f64> = d.iter().map(|v| v / norm).collect();
            for _ in 0..2 {
                let a = self.project(&r);
                for (ri, i) in r.iter_mut().zip(0..n) {
                    *ri -= self.row(i).iter().zip(&a).map(|(v, x)| v * x).sum::<f64>();
                }
            }
            rest.push(r);
        }
        if rest.is_empty() || max == 0 {
            return Ok(Vec::new());
        }
        let extra = Basis::pod(&rest, Truncation::Modes(max))?;
        let m = extra.singular_values.iter().take(extra.k).take_while(|&&s| s > tol).count();
        if m == 0 {
            return Ok(Vec::new());
        }
        let mut v = vec![0.0; n * (k + m)];
        for i in 0..n {
            v[i * (k + m)..i * (k + m) + k].copy_from_slice(self.row(i));
            v[i * (k + m) + k..(i + 1) * (k + m)].copy_from_slice(&extra.row(i)[..m]);
        }
        // re-orthogonalise the new columns against the old ones and each other (round-off)
        for j in k..k + m {
            for _ in 0..2 {
                for c in 0..j {
                    let dot: f64 = (0..n).map(|i| v[i * (k + m) + c] * v[i * (k + m) + j]).sum();
                    for i in 0..n {
                        v[i * (k + m) + j] -= dot * v[i * (k + m) + c];
                    }
                }
            }
            let norm = (0..n).map(|i| v[i * (k + m) + j].powi(2)).sum::<f64>().sqrt();
            for i in 0..n {
                v[i * (k + m) + j] /= norm;
            }
        }
        self.v = v;
        self.k = k + m;
        self.appended_singular_values.extend_from_slice(&extra.singular_values[..m]);
        Ok(extra.singular_values[..m].to_vec())
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
        Basis {
            frame: self.frame,
            n: self.n,
            k,
            reference: self.reference.clone(),
            v,
            singular_values: self.singular_values.clone(),
            pressure: self.pressure.clone(),
            appended_singular_values: {
                let pod = self.k - self.appended_singular_values.len();
                self.appended_singular_values[..k.saturating_sub(pod)].to_vec()
            },
        }
    }
}

/// The ECSW sample: elements and their non-negative weights, or (with `points`) quadrature
/// points: entry i is then point `points[i]` of element `elements[i]` (an element may appear once
/// per sampled point) with weight `weights[i]`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample {
    pub elements: Vec<usize>,
    pub weights: Vec<f64>,
    /// the quadrature point of each entry (empty: whole elements)
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub points: Vec<usize>,
}

impl Sample {
    /// Every element with weight 1 (no hyper-reduction).
    pub fn all(n_elements: usize) -> Sample {
        Sample { elements: (0..n_elements).collect(), weights: vec![1.0; n_elements], points: Vec::new() }
    }
    /// Every quadrature point of every element with weight 1 (the same reduced model as [`Sample::all`]).
    pub fn all_points(n_elements: usize, points_per_element: usize) -> Sample {
        let n = n_elements * points_per_element;
        Sample { elements: (0..n).map(|i| i / points_per_element).collect(), weights: vec![1.0; n], points: (0..n).map(|i| i % points_per_element).collect() }
    }
    /// A quadrature-level sample.
    pub fn is_points(&self) -> bool {
        !self.points.is_empty()
    }
    /// "140 of 256 elements", or "745 quadrature points in 224 of 256 elements".
    pub fn describe(&self, n_elements: usize) -> String {
        if self.is_points() {
            format!("{} quadrature points in {} of {} elements", self.points.len(), self.distinct_elements().len(), n_elements)
        } else {
            format!("{} of {} elements", self.elements.len(), n_elements)
        }
    }
    /// The distinct elements of the sample, in order of first appearance.
    pub fn distinct_elements(&self) -> Vec<usize> {
        let mut seen = std::collections::HashSet::new();
        self.elements.iter().copied().filter(|e| seen.insert(*e)).collect()
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
    /// the frame's per-node maps (None: Cartesian)
    maps: Option<FrameMaps>,
    /// Φ column-major (for the lift: k column updates stream through Φ once, where n row dot
    /// products of length k each end in a horizontal sum; measured 9 % of a reduced run)
    phi_cols: Vec<f64>,
}

/// Per-node frame maps: for each free node, its three unknowns, the 3×3 matrix T (model
/// components = T · frame components) and T⁻¹.
type FrameMaps = Vec<([usize; 3], [[f64; 3]; 3], [[f64; 3]; 3])>;

fn inv3(m: &[[f64; 3]; 3]) -> ([[f64; 3]; 3], f64) {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let (i1, i2) = ((j + 1) % 3, (j + 2) % 3);
            let (j1, j2) = ((i + 1) % 3, (i + 2) % 3);
            r[i][j] = (m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]) / det;
        }
    }
    (r, det)
}

/// J = ∂X/∂X_ref at every node of `mesh` for the nodal map from `reference` (node positions of
/// a mesh with the same connectivity): the isoparametric ∂X/∂ξ (∂X_ref/∂ξ)⁻¹ at each element's
/// nodes, averaged over the elements that share a node.
pub fn nodal_map_jacobians(mesh: &crate::mesh::Mesh, reference: &[[f64; 3]]) -> Result<Vec<[[f64; 3]; 3]>, RomError> {
    if reference.len() != mesh.n_nodes() {
        return Err(RomError::Reference(mesh.n_nodes(), reference.len()));
    }
    let kind = mesh.kind;
    let shapes: Vec<Vec<[f64; 3]>> = kind.natural_coords().iter().map(|c| crate::shape::hex_shape(kind, [c[0] as f64, c[1] as f64, c[2] as f64]).1).collect();
    let mut sum = vec![[[0.0; 3]; 3]; mesh.n_nodes()];
    let mut count = vec![0u32; mesh.n_nodes()];
    for e in 0..mesh.n_elements() {
        let el = mesh.element(e);
        for (a, dn) in shapes.iter().enumerate() {
            let (mut gx, mut gr) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
            for (b, &nb) in el.iter().enumerate() {
                for i in 0..3 {
                    for j in 0..3 {
                        gx[i][j] += mesh.nodes[nb][i] * dn[b][j];
                        gr[i][j] += reference[nb][i] * dn[b][j];
                    }
                }
            }
            let (gri, det) = inv3(&gr);
            if !(det.is_finite() && det > 0.0) {
                return Err(RomError::MapJacobian(el[a], det));
            }
            let n = el[a];
            for i in 0..3 {
                for j in 0..3 {
                    sum[n][i][j] += (0..3).map(|m| gx[i][m] * gri[m][j]).sum::<f64>();
                }
            }
            count[n] += 1;
        }
    }
    Ok(sum
        .into_iter()
        .zip(count)
        .map(|(mut m, c)| {
            let c = c.max(1) as f64;
            m.iter_mut().flatten().for_each(|x| *x /= c);
            m
        })
        .collect())
}

/// The per-node maps of a frame for a model's free nodes (None for the Cartesian frame).
/// `reference`: the reference mesh's node positions ([`Frame::Piola`] only).
fn frame_maps(model: &Model, frame: Frame, reference: &[[f64; 3]]) -> Result<Option<FrameMaps>, RomError> {
    match frame {
        Frame::Cartesian => Ok(None),
        Frame::Cylindrical => Ok(Some(
            model
                .dofs
                .free_nodes()
                .into_iter()
                .map(|(n, k)| {
                    let x = model.mesh.nodes[n];
                    let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
                    let (c, s) = if r > 1e-12 { (x[0] / r, x[1] / r) } else { (1.0, 0.0) };
                    // columns e_r, e_θ, e_z; T⁻¹ = Tᵀ
                    (k, [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
                })
                .collect(),
        )),
        Frame::Piola => {
            let jac = nodal_map_jacobians(&model.mesh, reference)?;
            let mut out = Vec::new();
            for (n, k) in model.dofs.free_nodes() {
                let (ji, det) = inv3(&jac[n]);
                if !(det.is_finite() && det > 0.0) {
                    return Err(RomError::MapJacobian(n, det));
                }
                // T = J / det J, T⁻¹ = det J · J⁻¹
                let t = jac[n].map(|r| r.map(|x| x / det));
                let ti = ji.map(|r| r.map(|x| x * det));
                out.push((k, t, ti));
            }
            Ok(Some(out))
        }
    }
}

/// A pressure snapshot of a model state (q, prescribed values): every element's discrete
/// pressure coefficients ([`element::pressure_coefficients`]), element-major, `np` = max(1, the
/// pressure space's dimension) per element (a pure-displacement element's pressure U'(J) is
/// reported by its mean).
pub fn pressure_snapshot(model: &Model, q: &[f64], presc: &[f64]) -> Result<Vec<f64>, ElementError> {
    let x0 = &model.mesh.nodes;
    let kin = model.dofs.body_kinematics(q, presc);
    let u = model.dofs.expand(x0, q, presc, &kin);
    let rule = model.form.rule();
    let np = model.form.pressure.dim();
    let mut out = Vec::with_capacity(model.mesh.n_elements() * np.max(1));
    for e in 0..model.mesh.n_elements() {
        let conn = model.mesh.element(e);
        let xe: Vec<[f64; 3]> = conn.iter().map(|&n| x0[n]).collect();
        let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
        if np == 0 {
            let (b, m, _) = element::dilatation_moments(&model.form, &rule, &xe, &ue).map_err(|err| crate::model::relabel(err, e))?;
            out.push(model.material.u_vol(&model.params, b[0] / m[0])[1]);
        } else {
            out.extend(element::pressure_coefficients(&model.form, &rule, &model.material, &model.params, &xe, &ue).map_err(|err| crate::model::relabel(err, e))?);
        }
    }
    Ok(out)
}

/// The nodal unknowns q (first n_nodal entries of a model state) in the components of `frame`:
/// T⁻¹ q (what POD snapshots of a frame are). `reference`: see [`Basis::reference`].
pub fn to_frame(model: &Model, frame: Frame, reference: &[[f64; 3]], q: &[f64]) -> Result<Vec<f64>, RomError> {
    let n = model.dofs.n_nodal();
    let mut y = q[..n].to_vec();
    if let Some(maps) = frame_maps(model, frame, reference)? {
        for (k, _, ti) in maps {
            if k.iter().all(|&i| i < n) {
                for r in 0..3 {
                    y[k[r]] = (0..3).map(|c| ti[r][c] * q[k[c]]).sum();
                }
            }
        }
    }
    Ok(y)
}

impl<'a> Reduction<'a> {
    pub fn new(model: &'a Model, basis: &'a Basis) -> Result<Self, RomError> {
        let nn = model.dofs.n_nodal();
        if basis.n != nn {
            return Err(RomError::BasisSize(basis.n, nn));
        }
        let maps = frame_maps(model, basis.frame, &basis.reference)?;
        let phi = match &maps {
            None => std::borrow::Cow::Borrowed(basis.v.as_slice()),
            Some(rots) => {
                let k = basis.k;
                let mut phi = basis.v.clone();
                for &(idx, t, _) in rots {
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
        let (n, k) = (basis.n, basis.k);
        let mut phi_cols = vec![0.0; n * k];
        for i in 0..n {
            for j in 0..k {
                phi_cols[j * n + i] = phi[i * k + j];
            }
        }
        Ok(Reduction { model, basis, phi, maps, phi_cols })
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
        let (n, k) = (self.basis.n, self.basis.k);
        let mut q = vec![0.0; n];
        let phi = faer::MatRef::from_column_major_slice(&self.phi_cols, n, k);
        let zm = faer::MatRef::from_column_major_slice(&z[..k], k, 1);
        faer::linalg::matmul::matmul(faer::MatMut::from_column_major_slice_mut(&mut q, n, 1), faer::Accum::Replace, phi, zm, 1.0, faer::Par::Seq);
        q.extend_from_slice(&z[k..]);
        q
    }
    /// z of q's nodal unknowns in the frame's components (T⁻¹ q), projected orthogonally on V:
    /// z = Vᵀ T⁻¹ q (the orthogonal projection of q on Φ when T is a rotation; in every frame,
    /// project(lift(z)) = z).
    pub fn project(&self, q: &[f64]) -> Vec<f64> {
        let k = self.basis.k;
        let n = self.basis.n;
        let mut y = q[..n].to_vec();
        if let Some(maps) = &self.maps {
            for &(idx, _, ti) in maps {
                if idx.iter().all(|&i| i < n) {
                    for r in 0..3 {
                        y[idx[r]] = (0..3).map(|c| ti[r][c] * q[idx[c]]).sum();
                    }
                }
            }
        }
        let mut z = vec![0.0; k];
        for (i, &yi) in y.iter().enumerate() {
            if yi != 0.0 {
                for (zj, vj) in z.iter_mut().zip(self.basis.row(i)) {
                    *zj += vj * yi;
                }
            }
        }
        z.extend_from_slice(&q[n..]);
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
    /// Sample quadrature points instead of whole elements (needs a reduced pressure space): the
    /// candidates are every point of every element, each with its own weight.
    #[serde(default)]
    pub points: bool,
    /// Fit on at most this many snapshots, evenly spaced (0: all; applied by the caller that
    /// feeds the accumulator).
    #[serde(default)]
    pub max_snapshots: usize,
}

/// The result of an ECSW fit.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EcswFit {
    pub sample: Sample,
    /// the relative residual ‖G ξ − b‖ / ‖b‖ reached
    pub residual: f64,
    pub rows: usize,
    /// snapshots left out because their projection onto the basis inverts an element (the
    /// reduced space cannot hold that state; no reduced force is defined there)
    pub skipped: usize,
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
    acc.points = opts.points;
    acc.add(basis, snapshots)?;
    Ok(acc.fit(opts))
}

/// The normal equations of the ECSW fit, accumulated over snapshots.
#[derive(Clone, Debug, Default)]
pub struct EcswAccumulator {
    /// tangent directions per snapshot (see [`EcswOptions::tangent_directions`])
    pub tangent_directions: usize,
    /// candidates are quadrature points (see [`EcswOptions::points`])
    pub points: bool,
    /// quadrature points per element (with `points`)
    points_per_element: usize,
    a: Option<Mat<f64>>,
    c: Vec<f64>,
    bb: f64,
    rows: usize,
    skipped: usize,
}

impl EcswAccumulator {
    pub fn new(tangent_directions: usize) -> Self {
        EcswAccumulator { tangent_directions, ..Default::default() }
    }

    /// Add the rows of these snapshots (all of models with the same mesh).
    pub fn add(&mut self, basis: &Basis, snapshots: &[Snapshot]) -> Result<(), RomError> {
        use rayon::prelude::*;
        let Some(first) = snapshots.first() else { return Ok(()) };
        if self.points && self.tangent_directions > 0 {
            return Err(RomError::PointsWithTangents);
        }
        let ngp = first.model.form.rule().weights.len();
        self.points_per_element = ngp;
        let ncand = first.model.mesh.n_elements() * if self.points { ngp } else { 1 };
        let nt = self.tangent_directions;
        let points = self.points;
        // a few snapshots at a time: each block is rows × candidates
        for chunk in snapshots.chunks(16) {
            let blocks: Vec<Result<(Mat<f64>, Vec<f64>), RomError>> = chunk.par_iter().map(|s| snapshot_rows(basis, s, nt, points)).collect();
            for blk in blocks {
                let (g, bs) = match blk {
                    Ok(b) => b,
                    Err(RomError::Element(ElementError::Inverted(_))) => {
                        self.skipped += 1;
                        continue;
                    }
                    Err(e) => return Err(e),
                };
                let a = self.a.get_or_insert_with(|| Mat::<f64>::zeros(ncand, ncand));
                if a.nrows() != g.ncols() {
                    return Err(RomError::SampleElement(g.ncols(), a.nrows()));
                }
                faer::linalg::matmul::matmul(a.as_mut(), faer::Accum::Add, g.transpose(), g.as_ref(), 1.0, faer::Par::rayon(0));
                if self.c.is_empty() {
                    self.c = vec![0.0; ncand];
                }
                let bm = faer::MatRef::from_column_major_slice(&bs, bs.len(), 1);
                let gb = g.transpose() * bm;
                for (j, x) in self.c.iter_mut().enumerate() {
                    *x += gb[(j, 0)];
                }
                self.bb += bs.iter().map(|x| x * x).sum::<f64>();
                self.rows += g.nrows();
            }
        }
        Ok(())
    }

    /// The weights by the τ-stopped NNLS.
    pub fn fit(&self, opts: &EcswOptions) -> EcswFit {
        let Some(a) = &self.a else {
            return EcswFit { sample: Sample { elements: Vec::new(), weights: Vec::new(), points: Vec::new() }, residual: 1.0, rows: 0, skipped: self.skipped };
        };
        let (xi, res) = nnls_gram(a, &self.c, self.bb, opts.tau, opts.max_elements);
        let mut sample = Sample { elements: Vec::new(), weights: Vec::new(), points: Vec::new() };
        for (col, &w) in xi.iter().enumerate() {
            if w > 0.0 {
                if self.points {
                    sample.elements.push(col / self.points_per_element);
                    sample.points.push(col % self.points_per_element);
                } else {
                    sample.elements.push(col);
                }
                sample.weights.push(w);
            }
        }
        EcswFit { sample, residual: res, rows: self.rows, skipped: self.skipped }
    }
}

/// One snapshot's scaled rows of G and of b = G 1: columns are the candidates (elements, or
/// with `points` each element's quadrature points, element-major). The rows are the candidate's
/// reduced force on the modes and on every rigid-body DOF, then (with a pressure space) its
/// dilatation-change moments on the pressure modes, then (with `tangent_dirs`, elements only)
/// its reduced tangent times fixed pseudo-random unit directions; each block is scaled by the
/// norm of its sum over the candidates.
fn snapshot_rows(basis: &Basis, s: &Snapshot, tangent_dirs: usize, points: bool) -> Result<(Mat<f64>, Vec<f64>), RomError> {
    let ne = s.model.mesh.n_elements();
    let red = Reduction::new(s.model, basis)?;
    let q = red.lift(&red.project(&s.q));
    let kin = s.model.dofs.body_kinematics(&q, &s.presc);
    let u = s.model.dofs.expand(&s.model.mesh.nodes, &q, &s.presc, &kin);
    let nb = s.model.dofs.bodies.len();
    let m = red.dim();
    let rule = s.model.form.rule();
    let ngp = rule.weights.len();
    if points && basis.pressure.is_none() {
        return Err(RomError::PointsWithoutPressure);
    }
    let per = if points { ngp } else { 1 };
    let ncand = ne * per;
    // a reduced pressure space: the elements' forces under the reduced pressure (all elements),
    // and their dilatation-change moments on the pressure modes as a block of rows of their own
    let all = Sample::all(ne);
    let mixed = basis.pressure.as_ref().map(|pb| Mixed::new(s.model, pb, &all, &rule).map(|mx| (pb, mx))).transpose()?;
    let pressure = match &mixed {
        Some((pb, mx)) => {
            let (mut energy, mut min_det) = (0.0, f64::INFINITY);
            let mom = element_moments(s.model, &rule, &all, &u, &mut min_det)?;
            Some(reduced_pressure(s.model, &all, mx, pb, &mom, &mut energy, &mut min_det)?.0)
        }
        None => None,
    };
    let kp = mixed.as_ref().map_or(0, |(pb, _)| pb.kp);
    let nforce = basis.k + 6 * nb;
    let nf = nforce + kp;
    let rows = nf + tangent_dirs * m;
    let mut g = Mat::<f64>::zeros(rows, ncand);
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
    let mut f = vec![0.0; nd * per];
    for e in 0..ne {
        let conn = s.model.mesh.element(e);
        let xe: Vec<[f64; 3]> = conn.iter().map(|&n| s.model.mesh.nodes[n]).collect();
        let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
        let given = pressure.as_ref().map(|p| &p[e][..]);
        let relabel = |err| crate::model::relabel(err, e);
        if points {
            element::residual_points_with(&s.model.form, &rule, &s.model.material, &s.model.params, &xe, &ue, given, &mut f).map_err(relabel)?;
        } else if tangent_dirs > 0 {
            element::tangent_with(&s.model.form, &rule, &s.model.material, &s.model.params, &xe, &ue, None, given, &mut f, &mut ke, None).map_err(relabel)?;
        } else {
            element::residual_with(&s.model.form, &rule, &s.model.material, &s.model.params, &xe, &ue, given, &mut f).map_err(relabel)?;
        }
        if let Some((pb, _)) = &mixed {
            let pe = pb.block(e);
            if points {
                // each point's φ_r (J − 1) w det J₀
                for (gp, d) in element::gather(&s.model.form, &rule, &xe, &ue).map_err(relabel)?.iter().enumerate() {
                    for r in 0..pb.np {
                        let dv = d.q[r] * (d.j - 1.0) * d.wj0;
                        for j in 0..kp {
                            g[(nforce + j, e * per + gp)] += pe[r * kp + j] * dv;
                        }
                    }
                }
            } else {
                let zero = vec![[0.0; 3]; xe.len()];
                let b1 = element::dilatation_moments(&s.model.form, &rule, &xe, &ue).map_err(relabel)?.0;
                let b0 = element::dilatation_moments(&s.model.form, &rule, &xe, &zero).map_err(relabel)?.0;
                for r in 0..pb.np {
                    let d = b1[r] - b0[r];
                    for j in 0..kp {
                        g[(nforce + j, e)] += pe[r * kp + j] * d;
                    }
                }
            }
        }
        red.jacobian(conn, &kin, &mut scratch, &mut jac);
        for c in 0..per {
            let col = e * per + c;
            let fc = &f[c * nd..(c + 1) * nd];
            for (r, fr) in fc.iter().enumerate() {
                if *fr != 0.0 {
                    for j in 0..basis.k {
                        g[(j, col)] += jac[r * m + j] * fr;
                    }
                }
            }
            bf.iter_mut().for_each(|v| *v = 0.0);
            body_forces_of(s.model, &kin, conn, fc, 1.0, &mut bf);
            for (j, v) in bf.iter().enumerate() {
                g[(basis.k + j, col)] = *v;
            }
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
    let b: Vec<f64> = (0..rows).map(|i| (0..ncand).map(|e| g[(i, e)]).sum()).collect();
    // block scales: forces, dilatation moments, then each tangent direction
    let mut blocks = vec![(0, nforce)];
    if kp > 0 {
        blocks.push((nforce, nf));
    }
    blocks.extend((0..tangent_dirs).map(|t| (nf + t * m, nf + (t + 1) * m)));
    let mut bs = b.clone();
    for (lo, hi) in blocks {
        let n: f64 = b[lo..hi].iter().map(|x| x * x).sum::<f64>().sqrt();
        let sc = if n > 0.0 { 1.0 / n } else { 1.0 };
        for i in lo..hi {
            bs[i] *= sc;
            for j in 0..ncand {
                g[(i, j)] *= sc;
            }
        }
    }
    Ok((g, bs))
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
        let nz: Vec<usize> = (0..n).filter(|&i| x[i] != 0.0).collect();
        for &i in &nz {
            cx += c[i] * x[i];
            for &j in &nz {
                ax += x[i] * a[(i, j)] * x[j];
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
        let mut w = c.to_vec();
        for &j in &active {
            if x[j] != 0.0 {
                let col = a.col(j);
                for (i, wi) in w.iter_mut().enumerate() {
                    *wi -= col[i] * x[j];
                }
            }
        }
        let is_active: std::collections::HashSet<usize> = active.iter().copied().collect();
        let cand = (0..n).filter(|i| !is_active.contains(i)).max_by(|&i, &j| w[i].total_cmp(&w[j]));
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
            for &i in &active {
                if x[i] <= 1e-14 {
                    x[i] = 0.0;
                }
            }
            active.retain(|&i| x[i] > 0.0);
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
    /// the reduced pressure space's data on this geometry and sample
    mixed: Option<Mixed>,
    /// J_e = ∂u_e/∂z of each sampled element where it does not depend on the state (no node on
    /// a rigid body or a rotating periodic pair); None where it does (rebuilt at each evaluation)
    jac_const: Vec<Option<Vec<f64>>>,
    /// the state of the last tangent evaluation (z, λ), which `outputs` reads instead of
    /// evaluating again
    last: std::sync::Mutex<Option<(Vec<f64>, f64, RomState)>>,
    /// the element of each element item of `jac_const` (the sample's distinct elements)
    elem_items: Vec<usize>,
    /// a quadrature-level sample's per-design data
    points: Option<PointSample>,
    /// the cavity's surface-node data
    cavity: Option<CavityProj>,
    /// see [`RomPath::set_cavity_hessian_lag`] (0: exact)
    cavity_lag: f64,
    /// the cavity volume's Hessian ∂²V/∂z² (lower triangle, the part not reduced as an exact
    /// cubic) and the state it was computed at
    cavity_hessian: std::sync::Mutex<Option<(Vec<f64>, Mat<f64>)>>,
}

/// K += α A B where A B is symmetric: only its lower triangle is computed, into the lower
/// triangle of K (mirrored by [`mirror_lower`] once every such term is in).
fn lower_product(k: &mut Mat<f64>, a: faer::MatRef<'_, f64>, b: faer::MatRef<'_, f64>, alpha: f64) {
    use faer::linalg::matmul::triangular::{matmul, BlockStructure};
    matmul(k.as_mut(), BlockStructure::TriangularLower, faer::Accum::Add, a, BlockStructure::Rectangular, b, BlockStructure::Rectangular, alpha, faer::Par::Seq);
}

/// K += L + Lᵀ − diag(L) for L holding lower-triangle terms only.
fn mirror_lower(k: &mut Mat<f64>, l: &Mat<f64>) {
    for j in 0..l.ncols() {
        for i in j..l.nrows() {
            let v = l[(i, j)];
            k[(i, j)] += v;
            if i != j {
                k[(j, i)] += v;
            }
        }
    }
}

/// Sampled points per block of the reduced tangent's Σ Gᵀ (A G) (A G of 64 points is 370 kB at
/// 82 columns: it stays in cache between its computation and its product).
const POINT_CHUNK: usize = 64;

thread_local! {
    /// the quadrature-level evaluation's A G (one chunk of points) and state-dependent G blocks
    static POINT_BUFFERS: std::cell::RefCell<(Vec<f64>, Vec<f64>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// The per-design data of a quadrature-level sample: for each entry, its element item (index
/// into `elem_items`), ∇_X N_a at the point, w·det J₀ and the pressure-basis values; and
/// G = ∂F/∂z (9 × m, F row-major: row 3i + J is ∂F_iJ/∂z) of the entries whose element's J does
/// not depend on the state, stacked in `order`'s first `n_const` entries.
struct PointSample {
    item: Vec<usize>,
    grad: Vec<Vec<[f64; 3]>>,
    wj0: Vec<f64>,
    phi: Vec<[f64; 4]>,
    /// entries whose element has a rigid-body component (their nodal forces feed reactions)
    rigid: Vec<bool>,
    /// evaluation order: constant-G entries, then the others (grouped by element)
    order: Vec<usize>,
    n_const: usize,
    /// G of order[..n_const], stacked (9·n_const × m, row-major)
    g_const: Vec<f64>,
    /// G of order[n_const..] from their elements' static nodes only, stacked likewise (the
    /// other nodes' sparse rows of J are added at each evaluation)
    g_dyn_static: Vec<f64>,
    /// per element item, its nodes whose rows of J depend on the state: (local index, node)
    dyn_nodes: Vec<Vec<(usize, usize)>>,
}

/// Runs `$body` (a call of an `#[inline(always)]` function) compiled with AVX2 and FMA where
/// the CPU has them (detected once at run time), else as compiled: the reduced model's hot
/// loops over m columns vectorise 2× wider.
macro_rules! simd_dispatch {
    ($body:expr) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2,fma")]
            unsafe fn wide<R>(f: impl FnOnce() -> R) -> R {
                f()
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the features were detected on this CPU
                return unsafe { wide(|| $body) };
            }
        }
        $body
    }};
}

/// H Φ for H of skew 3 × 3 node blocks (CSR: `row_ptr`, (column node, block) in `row_ent`,
/// block vectors `vb`): row block a += Σ_b v_ab × Φ_b, Φ's rows in `phi_static` (nodes below
/// `nst`) and `phi_dyn` (3 rows of m per node, row-major).
#[allow(clippy::too_many_arguments)]
fn skew_blocks_times(row_ptr: &[usize], row_ent: &[(u32, u32)], vb: &[[f64; 3]], phi_static: &[f64], phi_dyn: &[f64], nst: usize, m: usize, out: &mut [f64]) {
    simd_dispatch!(skew_blocks_times_impl(row_ptr, row_ent, vb, phi_static, phi_dyn, nst, m, out))
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn skew_blocks_times_impl(row_ptr: &[usize], row_ent: &[(u32, u32)], vb: &[[f64; 3]], phi_static: &[f64], phi_dyn: &[f64], nst: usize, m: usize, out: &mut [f64]) {
    for a in 0..row_ptr.len() - 1 {
        let o = &mut out[3 * a * m..3 * (a + 1) * m];
        let (o0, rest) = o.split_at_mut(m);
        let (o1, o2) = rest.split_at_mut(m);
        for &(b, id) in &row_ent[row_ptr[a]..row_ptr[a + 1]] {
            let v = vb[id as usize];
            let b = b as usize;
            let w = if b < nst { &phi_static[3 * b * m..3 * (b + 1) * m] } else { &phi_dyn[3 * (b - nst) * m..3 * (b - nst + 1) * m] };
            let (w0, w1, w2) = (&w[..m], &w[m..2 * m], &w[2 * m..3 * m]);
            // skew(v) w = v × w
            for j in 0..m {
                o0[j] += v[1] * w2[j] - v[2] * w1[j];
                o1[j] += v[2] * w0[j] - v[0] * w2[j];
                o2[j] += v[0] * w1[j] - v[1] * w0[j];
            }
        }
    }
}

/// A sampled point's reduced force c = Gᵀ p_w (p_w = the weighted P, row-major) in one pass
/// over the columns of G (9 × m, row-major).
fn point_force_columns(g: &[f64], m: usize, pw: &[f64; 9], c: &mut [f64]) {
    simd_dispatch!(point_force_columns_impl(g, m, pw, c))
}

#[inline(always)]
fn point_force_columns_impl(g: &[f64], m: usize, pw: &[f64; 9], c: &mut [f64]) {
    let g: [&[f64]; 9] = std::array::from_fn(|r| &g[r * m..(r + 1) * m]);
    let c = &mut c[..m];
    for col in 0..m {
        let mut s = 0.0;
        for r in 0..9 {
            s += pw[r] * g[r][col];
        }
        c[col] = s;
    }
}

/// [`point_force_columns`] with the tangent's terms in the same pass: the rows of A_w G
/// (9 × m, into `ag`) and ∂J/∂z = Gᵀ f_v (into `dj`, f_v = J F⁻ᵀ row-major).
#[allow(clippy::too_many_arguments)]
fn point_tangent_columns(g: &[f64], m: usize, pw: &[f64; 9], wa: &[[f64; 9]; 9], fv: &[f64; 9], c: &mut [f64], dj: &mut [f64], ag: &mut [f64]) {
    simd_dispatch!(point_tangent_columns_impl(g, m, pw, wa, fv, c, dj, ag))
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn point_tangent_columns_impl(g: &[f64], m: usize, pw: &[f64; 9], wa: &[[f64; 9]; 9], fv: &[f64; 9], c: &mut [f64], dj: &mut [f64], ag: &mut [f64]) {
    // blocks of 8 columns (one or two SIMD registers per row of G), then the rest one by one
    let (c, dj, ag) = (&mut c[..m], &mut dj[..m], &mut ag[..9 * m]);
    let mut col0 = 0;
    while col0 + 8 <= m {
        point_tangent_block::<8>(g, m, col0, pw, wa, fv, c, dj, ag);
        col0 += 8;
    }
    for col in col0..m {
        point_tangent_block::<1>(g, m, col, pw, wa, fv, c, dj, ag);
    }
}

/// [`point_tangent_columns_impl`] on the W columns from `col0`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn point_tangent_block<const W: usize>(g: &[f64], m: usize, col0: usize, pw: &[f64; 9], wa: &[[f64; 9]; 9], fv: &[f64; 9], c: &mut [f64], dj: &mut [f64], ag: &mut [f64]) {
    let gc: [[f64; W]; 9] = std::array::from_fn(|r| std::array::from_fn(|l| g[r * m + col0 + l]));
    let (mut s, mut d) = ([0.0; W], [0.0; W]);
    for r in 0..9 {
        for l in 0..W {
            s[l] += pw[r] * gc[r][l];
            d[l] += fv[r] * gc[r][l];
        }
    }
    c[col0..col0 + W].copy_from_slice(&s);
    dj[col0..col0 + W].copy_from_slice(&d);
    for (rr, row) in wa.iter().enumerate() {
        let mut v = [0.0; W];
        for (ss, &w) in row.iter().enumerate() {
            for l in 0..W {
                v[l] += w * gc[ss][l];
            }
        }
        ag[rr * m + col0..rr * m + col0 + W].copy_from_slice(&v);
    }
}

/// G = ∂F/∂z (9 × m, row-major) at a point of gradients `grad` from its element's
/// J = ∂u_e/∂z (3nn × m, row-major), into `out`.
fn point_g(grad: &[[f64; 3]], jac: &[f64], m: usize, out: &mut [f64]) {
    simd_dispatch!(point_g_impl(grad, jac, m, out))
}

#[inline(always)]
fn point_g_impl(grad: &[[f64; 3]], jac: &[f64], m: usize, out: &mut [f64]) {
    out.iter_mut().for_each(|v| *v = 0.0);
    for (a, ga) in grad.iter().enumerate() {
        for i in 0..3 {
            let row = &jac[(3 * a + i) * m..(3 * a + i + 1) * m];
            for cj in 0..3 {
                let o = &mut out[(3 * i + cj) * m..(3 * i + cj + 1) * m];
                let c = ga[cj];
                for (x, y) in o.iter_mut().zip(row) {
                    *x += c * y;
                }
            }
        }
    }
}

/// The cavity's exact volume terms in reduced coordinates, over the cavity's surface nodes
/// (the wall faces' and boundary edges' nodes): V, ∂V/∂z = Φ_sᵀ g and ∂²V/∂z² = Φ_sᵀ H Φ_s with
/// g and H assembled on the surface nodes. H's 3 × 3 node blocks are skew on the faces
/// ([`surface::face_volume_hessian_skew`]), so H Φ_s costs 6 row operations per block, and the
/// product with Φ_sᵀ is one matrix product over the assembled rows (not one per face: each node
/// is shared by up to four faces).
struct CavityProj {
    /// mesh node of each surface node: those whose rows of J = ∂u/∂z do not depend on the state
    /// first (`n_static` of them), then the others (rebuilt at each evaluation)
    nodes: Vec<usize>,
    n_static: usize,
    /// rows of J of the static nodes (3 n_static × m, row-major)
    phi_static: Vec<f64>,
    /// each face's and each edge's nodes as surface-node indices
    faces: Vec<Vec<u32>>,
    edges: Vec<Vec<u32>>,
    /// per face, the skew block of each node pair (d, e) (nf × nf)
    face_blocks: Vec<Vec<u32>>,
    /// the blocks of each surface node's row: (column node, block), CSR
    row_ptr: Vec<usize>,
    row_ent: Vec<(u32, u32)>,
    n_blocks: usize,
    /// the faces whose nodes all move linearly with z, as an exact cubic of z (the faces and
    /// edges above are then only the others)
    cubic: Option<CubicCavity>,
}

/// The volume enclosed by faces whose nodes all move linearly with z, x = X + Φ z: a
/// homogeneous cubic of the nodal positions, so exactly
/// V(z) = V₀ + g₀·z + ½ zᵀA₀z + ⅙ T[z,z,z], ∂V/∂z = g₀ + A₀z + ½ T[z]z, ∂²V/∂z² = A₀ + T[z],
/// with g₀ = Φᵀ∇V(X), A₀ = ΦᵀH(X)Φ and T_r = ΦᵀH(Φ_r)Φ (H is linear in x). T depends on the
/// basis and the faces' topology only, not on the design ([`CavityTensors`] keeps it per model).
struct CubicCavity {
    v0: f64,
    g0: Vec<f64>,
    /// A₀ (m × m, column-major)
    a0: Vec<f64>,
    /// T_r (m × m, column-major) for r < `t_cols` (the columns beyond are zero on these faces)
    t: std::sync::Arc<Vec<f64>>,
    t_cols: usize,
}

/// The cavity volume tensors T of [`CubicCavity`], built once per basis and dof layout and shared
/// by every design's reduced paths (a Rom's paths look them up here).
#[derive(Default)]
pub struct CavityTensors {
    cache: std::sync::Mutex<Vec<(u64, std::sync::Arc<Vec<f64>>)>>,
}

impl Clone for CavityTensors {
    fn clone(&self) -> Self {
        CavityTensors { cache: std::sync::Mutex::new(self.cache.lock().unwrap_or_else(|e| e.into_inner()).clone()) }
    }
}

impl std::fmt::Debug for CavityTensors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "CavityTensors({} cached)", self.cache.lock().map(|c| c.len()).unwrap_or(0))
    }
}

/// (a cache: every two compare equal)
impl PartialEq for CavityTensors {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl CavityTensors {
    fn get(&self, key: u64, build: impl FnOnce() -> Vec<f64>) -> std::sync::Arc<Vec<f64>> {
        if let Some((_, t)) = self.cache.lock().unwrap_or_else(|e| e.into_inner()).iter().find(|(k, _)| *k == key) {
            return t.clone();
        }
        let t = std::sync::Arc::new(build());
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if !c.iter().any(|(k, _)| *k == key) {
            c.push((key, t.clone()));
        }
        t
    }
}

impl CavityProj {
    /// The cavity's data at the path's reference state u0 (z = 0). With `cubic_ok` (the rows of
    /// J of the static nodes and u0 do not move along the path), the faces of static nodes only
    /// are reduced as an exact cubic of z ([`CubicCavity`]); the rest as below.
    #[allow(clippy::too_many_arguments)]
    fn new(red: &Reduction, cav: &surface::Cavity, is_static: &dyn Fn(usize) -> bool, kin0: &[BodyKin], cubic_ok: bool, u0: &[[f64; 3]], tensors: Option<&CavityTensors>) -> CavityProj {
        let all: Vec<usize> = (0..cav.face_nodes.len()).collect();
        if !cubic_ok {
            return CavityProj::over(red, cav, &all, true, is_static, kin0, None);
        }
        let (lin, other): (Vec<usize>, Vec<usize>) = all.into_iter().partition(|&f| cav.face_nodes[f].iter().all(|&n| is_static(n)));
        let m = red.dim();
        if crate::continuation::trace_enabled() {
            eprintln!("[rom] cavity: {} faces reduced as a cubic, {} (with rigid-body nodes) per evaluation, {} boundary edges", lin.len(), other.len(), cav.edges.len());
        }
        let sub = CavityProj::over(red, cav, &lin, false, is_static, kin0, None);
        let x0 = &red.model.mesh.nodes;
        let xs: Vec<[f64; 3]> = sub.nodes.iter().map(|&n| [x0[n][0] + u0[n][0], x0[n][1] + u0[n][1], x0[n][2] + u0[n][2]]).collect();
        // V₀, g₀ and A₀ at X
        let mut v0 = 0.0;
        let mut gs = vec![0.0; 3 * xs.len()];
        let mut gl = Vec::new();
        let mut xl = Vec::new();
        for loc in &sub.faces {
            xl.clear();
            xl.extend(loc.iter().map(|&a| xs[a as usize]));
            gl.clear();
            gl.resize(3 * loc.len(), 0.0);
            v0 += surface::face_volume_grad(&cav.rule, &xl, &mut gl);
            for (d, &a) in loc.iter().enumerate() {
                for c in 0..3 {
                    gs[3 * a as usize + c] += gl[3 * d + c];
                }
            }
        }
        let mut g0 = vec![0.0; m];
        {
            let gm = faer::MatMut::from_column_major_slice_mut(&mut g0, m, 1);
            let phi = faer::MatRef::from_row_major_slice(&sub.phi_static, sub.phi_static.len() / m.max(1), m);
            faer::linalg::matmul::matmul(gm, faer::Accum::Replace, phi.transpose(), faer::MatRef::from_column_major_slice(&gs, gs.len(), 1), 1.0, faer::Par::Seq);
        }
        let a0 = sub.static_hessian(&cav.rule, &xs, m);
        // the columns of Φ_s that are not zero (the modes; rigid-body coordinates move no static node)
        let nrow = sub.phi_static.len() / m.max(1);
        let t_cols = (0..m).rev().find(|&r| (0..nrow).any(|i| sub.phi_static[i * m + r] != 0.0)).map_or(0, |r| r + 1);
        let build = || {
            let mut t = vec![0.0; m * m * t_cols];
            for r in 0..t_cols {
                let dir: Vec<[f64; 3]> = (0..sub.nodes.len()).map(|a| [0, 1, 2].map(|c| sub.phi_static[(3 * a + c) * m + r])).collect();
                t[r * m * m..(r + 1) * m * m].copy_from_slice(&sub.static_hessian(&cav.rule, &dir, m));
            }
            t
        };
        let t = match tensors {
            Some(cache) => {
                use std::hash::{Hash, Hasher};
                let mut h = std::collections::hash_map::DefaultHasher::new();
                (m, t_cols, sub.nodes.len(), sub.faces.len()).hash(&mut h);
                sub.faces.hash(&mut h);
                sub.phi_static.iter().for_each(|v| v.to_bits().hash(&mut h));
                cav.rule.weights.iter().for_each(|v| v.to_bits().hash(&mut h));
                cache.get(h.finish(), build)
            }
            None => std::sync::Arc::new(build()),
        };
        CavityProj::over(red, cav, &other, true, is_static, kin0, Some(CubicCavity { v0, g0, a0, t, t_cols }))
    }

    /// The surface-node data of the given faces (and, with `edges`, the boundary edges).
    #[allow(clippy::too_many_arguments)]
    fn over(red: &Reduction, cav: &surface::Cavity, face_ids: &[usize], with_edges: bool, is_static: &dyn Fn(usize) -> bool, kin0: &[BodyKin], cubic: Option<CubicCavity>) -> CavityProj {
        let face_nodes: Vec<&Vec<usize>> = face_ids.iter().map(|&f| &cav.face_nodes[f]).collect();
        let edge_nodes: Vec<&Vec<usize>> = if with_edges { cav.edges.iter().map(|e| &e.0).collect() } else { Vec::new() };
        let mut seen = std::collections::BTreeSet::new();
        for n in face_nodes.iter().chain(&edge_nodes).flat_map(|v| v.iter()) {
            seen.insert(*n);
        }
        let (mut nodes, dynamic): (Vec<usize>, Vec<usize>) = seen.into_iter().partition(|&n| is_static(n));
        let n_static = nodes.len();
        nodes.extend(dynamic);
        let local: std::collections::HashMap<usize, u32> = nodes.iter().enumerate().map(|(i, &n)| (n, i as u32)).collect();
        let faces: Vec<Vec<u32>> = face_nodes.iter().map(|f| f.iter().map(|n| local[n]).collect()).collect();
        let edges: Vec<Vec<u32>> = edge_nodes.iter().map(|e| e.iter().map(|n| local[n]).collect()).collect();
        let mut ids: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
        let mut face_blocks = Vec::with_capacity(faces.len());
        for f in &faces {
            let mut b = Vec::with_capacity(f.len() * f.len());
            for &d in f {
                for &e in f {
                    let next = ids.len() as u32;
                    b.push(*ids.entry((d, e)).or_insert(next));
                }
            }
            face_blocks.push(b);
        }
        let n_blocks = ids.len();
        let mut rows: Vec<Vec<(u32, u32)>> = vec![Vec::new(); nodes.len()];
        for (&(d, e), &id) in &ids {
            rows[d as usize].push((e, id));
        }
        let mut row_ptr = vec![0];
        let mut row_ent = Vec::with_capacity(n_blocks);
        for mut r in rows {
            r.sort_unstable();
            row_ent.extend(r);
            row_ptr.push(row_ent.len());
        }
        let (mut scratch, mut phi_static) = (Vec::new(), Vec::new());
        red.jacobian(&nodes[..n_static], kin0, &mut scratch, &mut phi_static);
        CavityProj { nodes, n_static, phi_static, faces, edges, face_blocks, row_ptr, row_ent, n_blocks, cubic }
    }

    /// Φ_sᵀ H(x) Φ_s (m × m, column-major) over the faces, every node static (x per surface node).
    fn static_hessian(&self, rule: &crate::shape::FaceRule, xs: &[[f64; 3]], m: usize) -> Vec<f64> {
        let ns = self.nodes.len();
        let vb = self.face_skew_blocks(rule, xs);
        let mut hphi = vec![0.0; 3 * ns * m];
        skew_blocks_times(&self.row_ptr, &self.row_ent, &vb, &self.phi_static, &[], ns, m, &mut hphi);
        let mut out = Mat::<f64>::zeros(m, m);
        let phi = faer::MatRef::from_row_major_slice(&self.phi_static[..3 * ns * m], 3 * ns, m);
        let hp = faer::MatRef::from_row_major_slice(&hphi, 3 * ns, m);
        faer::linalg::matmul::matmul(out.as_mut(), faer::Accum::Replace, phi.transpose(), hp, 1.0, faer::Par::Seq);
        let mut v = vec![0.0; m * m];
        for j in 0..m {
            for i in 0..m {
                // (symmetrised: the product is symmetric up to round-off)
                v[j * m + i] = 0.5 * (out[(i, j)] + out[(j, i)]);
            }
        }
        v
    }

    /// The faces' skew Hessian blocks at positions xs (per surface node), summed per node pair.
    fn face_skew_blocks(&self, rule: &crate::shape::FaceRule, xs: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let mut vb = vec![[0.0f64; 3]; self.n_blocks];
        let (mut xl, mut vl) = (Vec::new(), Vec::new());
        for (loc, ids) in self.faces.iter().zip(&self.face_blocks) {
            xl.clear();
            xl.extend(loc.iter().map(|&a| xs[a as usize]));
            vl.resize(loc.len() * loc.len(), [0.0; 3]);
            surface::face_volume_hessian_skew(rule, &xl, &mut vl);
            for (v, &id) in vl.iter().zip(ids) {
                let b = &mut vb[id as usize];
                b[0] += v[0];
                b[1] += v[1];
                b[2] += v[2];
            }
        }
        vb
    }

    /// Adds the cavity terms at displacement u (bodies at `kin`, pressure p) into r (−p ∂V/∂z),
    /// r_body (the pressure forces at rigid-body nodes) and kl (the lower triangle of
    /// −p ∂²V/∂z², when given and p ≠ 0). Returns (V, ∂V/∂z).
    #[allow(clippy::too_many_arguments)]
    #[allow(clippy::type_complexity)]
    fn add(
        &self,
        red: &Reduction,
        cav: &surface::Cavity,
        z: &[f64],
        u: &[[f64; 3]],
        kin: &[BodyKin],
        p: f64,
        r: &mut [f64],
        r_body: &mut [f64],
        kl: Option<&mut Mat<f64>>,
        lagged: Option<(&std::sync::Mutex<Option<(Vec<f64>, Mat<f64>)>>, f64)>,
    ) -> (f64, Vec<f64>) {
        let model = red.model;
        let x0 = &model.mesh.nodes;
        let m = red.dim();
        let ns = self.nodes.len();
        let nst = self.n_static;
        let xs: Vec<[f64; 3]> = self.nodes.iter().map(|&n| [x0[n][0] + u[n][0], x0[n][1] + u[n][1], x0[n][2] + u[n][2]]).collect();
        let (mut scratch, mut phi_dyn) = (Vec::new(), Vec::new());
        red.jacobian(&self.nodes[nst..], kin, &mut scratch, &mut phi_dyn);
        // volume and its gradient on the surface nodes
        let mut volume = 0.0;
        let mut g = vec![0.0; 3 * ns];
        let mut gl = Vec::new();
        let mut xl = Vec::new();
        for (loc, is_face) in self.faces.iter().map(|f| (f, true)).chain(self.edges.iter().map(|e| (e, false))) {
            xl.clear();
            xl.extend(loc.iter().map(|&a| xs[a as usize]));
            gl.clear();
            gl.resize(3 * loc.len(), 0.0);
            volume += surface::item_volume_grad(&cav.rule, &xl, is_face, &mut gl);
            for (d, &a) in loc.iter().enumerate() {
                for c in 0..3 {
                    g[3 * a as usize + c] += gl[3 * d + c];
                }
            }
        }
        let mut dvol = vec![0.0; m];
        if ns > 0 {
            let mut dm = faer::MatMut::from_column_major_slice_mut(&mut dvol, m, 1);
            let gs = faer::MatRef::from_column_major_slice(&g[..3 * nst], 3 * nst, 1);
            faer::linalg::matmul::matmul(dm.as_mut(), faer::Accum::Replace, faer::MatRef::from_row_major_slice(&self.phi_static, 3 * nst, m).transpose(), gs, 1.0, faer::Par::Seq);
            if ns > nst {
                let gd = faer::MatRef::from_column_major_slice(&g[3 * nst..], 3 * (ns - nst), 1);
                faer::linalg::matmul::matmul(dm, faer::Accum::Add, faer::MatRef::from_row_major_slice(&phi_dyn, 3 * (ns - nst), m).transpose(), gd, 1.0, faer::Par::Seq);
            }
        }
        // the static faces' exact cubic: T[z] = Σ_r z_r T_r, then M = A₀ + T[z]
        let mut kl = kl;
        if let Some(cu) = &self.cubic {
            let mut tz = vec![0.0; m * m];
            for (rr, &zr) in z.iter().enumerate().take(cu.t_cols) {
                if zr != 0.0 {
                    for (a, b) in tz.iter_mut().zip(&cu.t[rr * m * m..(rr + 1) * m * m]) {
                        *a += zr * b;
                    }
                }
            }
            let mut az = vec![0.0; m];
            let mut tzz = vec![0.0; m];
            for j in 0..m {
                let zj = z[j];
                if zj != 0.0 {
                    for i in 0..m {
                        az[i] += cu.a0[j * m + i] * zj;
                        tzz[i] += tz[j * m + i] * zj;
                    }
                }
            }
            let dot = |a: &[f64]| a.iter().zip(z).map(|(x, y)| x * y).sum::<f64>();
            volume += cu.v0 + dot(&cu.g0) + 0.5 * dot(&az) + dot(&tzz) / 6.0;
            for i in 0..m {
                dvol[i] += cu.g0[i] + az[i] + 0.5 * tzz[i];
            }
            if p != 0.0 {
                if let Some(kl) = kl.as_mut() {
                    for j in 0..m {
                        for i in j..m {
                            kl[(i, j)] -= p * (cu.a0[j * m + i] + tz[j * m + i]);
                        }
                    }
                }
            }
        }
        for (ri, dv) in r.iter_mut().zip(&dvol) {
            *ri -= p * dv;
        }
        if p == 0.0 {
            return (volume, dvol);
        }
        add_body_nodal(model, &self.nodes, &g, -p, r_body);
        let Some(kl) = kl else { return (volume, dvol) };
        // the lagged Hessian, where the state is near the one it was computed at
        if let Some((cache, tol)) = lagged {
            if let Ok(mut c) = cache.lock() {
                let near = c.as_ref().is_some_and(|(zc, _)| {
                    let (d, n) = zc.iter().zip(z).fold((0.0, 0.0), |(d, n), (a, b)| (d + (a - b) * (a - b), n + a * a));
                    n > 0.0 && d <= tol * tol * n
                });
                if !near {
                    let mut h = Mat::<f64>::zeros(m, m);
                    self.hessian_lower(red, cav, &xs, &phi_dyn, &mut h, 1.0);
                    *c = Some((z.to_vec(), h));
                }
                if let Some((_, h)) = c.as_ref() {
                    for j in 0..m {
                        for i in j..m {
                            kl[(i, j)] -= p * h[(i, j)];
                        }
                    }
                    return (volume, dvol);
                }
            }
        }
        self.hessian_lower(red, cav, &xs, &phi_dyn, kl, -p);
        (volume, dvol)
    }

    /// kl += alpha ∂²V/∂z² (lower triangle) of the faces and edges of this projection (without
    /// the exact cubic's part), at the surface-node positions `xs`.
    fn hessian_lower(&self, red: &Reduction, cav: &surface::Cavity, xs: &[[f64; 3]], phi_dyn: &[f64], kl: &mut Mat<f64>, alpha: f64) {
        let m = red.dim();
        let ns = self.nodes.len();
        let nst = self.n_static;
        let row = |a: usize| -> &[f64] {
            if a < nst {
                &self.phi_static[3 * a * m..3 * (a + 1) * m]
            } else {
                &phi_dyn[3 * (a - nst) * m..3 * (a - nst + 1) * m]
            }
        };
        let mut xl = Vec::new();
        // H on the surface nodes: the faces' skew blocks, then H Φ_s
        let vb = self.face_skew_blocks(&cav.rule, &xs);
        let mut hphi = vec![0.0; 3 * ns * m];
        let axpy = |o: &mut [f64], c: f64, x: &[f64]| {
            for (a, b) in o.iter_mut().zip(x) {
                *a += c * b;
            }
        };
        skew_blocks_times(&self.row_ptr, &self.row_ent, &vb, &self.phi_static, &phi_dyn, nst, m, &mut hphi);
        // the boundary edges' cap terms (few): dense blocks
        let mut h = Vec::new();
        for loc in &self.edges {
            xl.clear();
            xl.extend(loc.iter().map(|&a| xs[a as usize]));
            let nd = 3 * loc.len();
            h.clear();
            h.resize(nd * nd, 0.0);
            surface::edge_volume_hessian(&xl, &mut h);
            for (d, &a) in loc.iter().enumerate() {
                for (e, &b) in loc.iter().enumerate() {
                    let w = row(b as usize);
                    for i in 0..3 {
                        let o = &mut hphi[(3 * a as usize + i) * m..(3 * a as usize + i + 1) * m];
                        for jj in 0..3 {
                            let c = h[(3 * d + i) * nd + 3 * e + jj];
                            if c != 0.0 {
                                axpy(o, c, &w[jj * m..(jj + 1) * m]);
                            }
                        }
                    }
                }
            }
        }
        fn rm(v: &[f64], rows: usize, m: usize) -> faer::MatRef<'_, f64> {
            faer::MatRef::from_row_major_slice(v, rows, m)
        }
        lower_product(kl, rm(&self.phi_static, 3 * nst, m).transpose(), rm(&hphi[..3 * nst * m], 3 * nst, m), alpha);
        if ns > nst {
            lower_product(kl, rm(&phi_dyn, 3 * (ns - nst), m).transpose(), rm(&hphi[3 * nst * m..], 3 * (ns - nst), m), alpha);
        }
    }
}

/// State-independent data of a reduced pressure space on one geometry and sample: for each
/// sampled element its quadrature (pressure-basis values, weight × det) and mass Ψ_eᵀ-ready
/// moments, and the inverse of the weighted reduced mass Σ w Ψ_eᵀ M_e Ψ_e.
struct Mixed {
    quad: Vec<Vec<([f64; 4], f64)>>,
    mass_inv: Mat<f64>,
}

impl Mixed {
    fn new(model: &Model, pb: &PressureBasis, sample: &Sample, rule: &HexRule) -> Result<Mixed, RomError> {
        let ne = model.mesh.n_elements();

        let need = ne * pb.np;
        if pb.psi.len() != need * pb.kp || pb.np != model.form.pressure.dim().max(1) {
            return Err(RomError::PressureSize(pb.psi.len() / pb.kp.max(1), need, model.form.pressure.dim().max(1)));
        }
        let np = pb.np;
        let kp = pb.kp;
        let mut quad = Vec::with_capacity(sample.elements.len());
        let mut mr = Mat::<f64>::zeros(kp, kp);
        // (a quadrature-level sample lists an element once per sampled point: its rule once)
        let mut by_element: std::collections::HashMap<usize, Vec<([f64; 4], f64)>> = std::collections::HashMap::new();
        for (i, (&e, &w)) in sample.elements.iter().zip(&sample.weights).enumerate() {
            let mut qd = match by_element.entry(e) {
                std::collections::hash_map::Entry::Occupied(o) => o.get().clone(),
                std::collections::hash_map::Entry::Vacant(v) => {
                    let xe = model.mesh.element_coords(e);
                    v.insert(element::pressure_quadrature(&model.form, rule, &xe).map_err(|err| RomError::Element(crate::model::relabel(err, e)))?).clone()
                }
            };
            if let Some(&gp) = sample.points.get(i) {
                if gp >= qd.len() {
                    return Err(RomError::SamplePoint(i, gp, qd.len()));
                }
                qd = vec![qd[gp]];
            }
            let mut me = vec![0.0; np * np];
            for (phi, wj) in &qd {
                for r in 0..np {
                    for c in 0..np {
                        me[r * np + c] += phi[r] * phi[c] * wj;
                    }
                }
            }
            let pe = faer::MatRef::from_row_major_slice(pb.block(e), np, kp);
            let mm = faer::MatRef::from_row_major_slice(&me, np, np);
            faer::linalg::matmul::matmul(mr.as_mut(), faer::Accum::Add, pe.transpose(), (mm * pe).as_ref(), w, faer::Par::Seq);
            quad.push(qd);
        }
        let llt = Llt::new(mr.as_ref(), Side::Lower).map_err(|_| RomError::PressureMass)?;
        let mass_inv = llt.solve(Mat::<f64>::identity(kp, kp));
        Ok(Mixed { quad, mass_inv })
    }
}

/// A factorised reduced tangent.
pub enum DenseFactor {
    Llt(Llt<f64>),
    Lu(PartialPivLu<f64>),
}

/// What one reduced evaluation computes besides the residual and tangent.
#[derive(Clone)]
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
        RomPath::with_tensors(model, basis, sample, from, to, functionals, None)
    }

    /// [`RomPath::new`], the cavity's design-independent tensors looked up in (and added to)
    /// `tensors` instead of built for this path alone.
    pub fn with_tensors(model: &'a Model, basis: &'a Basis, sample: &'a Sample, from: Loads, to: Loads, functionals: Vec<Functional>, tensors: Option<&CavityTensors>) -> Result<Self, RomError> {
        let red = Reduction::new(model, basis)?;
        let ne = model.mesh.n_elements();
        if let Some(&e) = sample.elements.iter().find(|&&e| e >= ne) {
            return Err(RomError::SampleElement(e, ne));
        }
        let rule = model.form.rule();
        if sample.is_points() {
            if basis.pressure.is_none() {
                return Err(RomError::PointsWithoutPressure);
            }
            if sample.points.len() != sample.elements.len() || sample.weights.len() != sample.elements.len() {
                return Err(RomError::SamplePoint(sample.points.len(), sample.elements.len(), rule.weights.len()));
            }
            if let Some((i, &gp)) = sample.points.iter().enumerate().find(|(_, &gp)| gp >= rule.weights.len()) {
                return Err(RomError::SamplePoint(i, gp, rule.weights.len()));
            }
        }
        let mixed = basis.pressure.as_ref().map(|pb| Mixed::new(model, pb, sample, &rule)).transpose()?;
        // a periodic pair's rotation depends on the prescribed values only (not on z): along a
        // path whose prescribed values do not move, its rows of J are constant too
        let presc_fixed = from.presc == to.presc;
        let kin0 = model.dofs.body_kinematics(&vec![0.0; model.n_reduced()], &from.presc);
        // a node's rows of J do not depend on the state (periodic ones: on the prescribed values,
        // through the source node's rows)
        fn static_comp(model: &Model, n: usize, c: usize, presc_fixed: bool) -> bool {
            match model.dofs.comps[3 * n + c] {
                Comp::Free(_) | Comp::Presc(_) | Comp::Lin(..) => true,
                Comp::Periodic(k) => presc_fixed && (0..3).all(|j| static_comp(model, model.dofs.per_pairs[k as usize].0 as usize, j, presc_fixed)),
                Comp::Rigid(_) => false,
            }
        }
        let is_static = |n: usize| (0..3).all(|c| static_comp(model, n, c, presc_fixed));
        let linear = |nodes: &[usize]| nodes.iter().all(|&n| is_static(n));
        let mut scratch = Vec::new();
        let mut jac_const = Vec::new();
        let elem_items = if sample.is_points() { sample.distinct_elements() } else { sample.elements.clone() };
        let cavity = model.cavity.as_ref().map(|cav| {
            let q0 = vec![0.0; model.n_reduced()];
            let u0 = model.dofs.expand(&model.mesh.nodes, &q0, &from.presc, &kin0);
            // the cubic's tensor T is design-independent only where Φ's Cartesian rows are (the
            // Cylindrical and Piola frames rotate/stretch them with each design's geometry, and
            // rebuilding T per path costs more than the Hessian products it replaces)
            let cubic_ok = presc_fixed && basis.frame == Frame::Cartesian;
            CavityProj::new(&red, cav, &is_static, &kin0, cubic_ok, &u0, tensors)
        });
        for nodes in elem_items.iter().map(|&e| model.mesh.element(e)) {
            jac_const.push(linear(nodes).then(|| {
                let mut j = Vec::new();
                red.jacobian(nodes, &kin0, &mut scratch, &mut j);
                j
            }));
        }
        let points = if sample.is_points() {
            let m = red.dim();
            let pos: std::collections::HashMap<usize, usize> = elem_items.iter().enumerate().map(|(i, &e)| (e, i)).collect();
            let (mut item, mut grad, mut wj0, mut phi, mut rigid) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
            let zero = vec![[0.0; 3]; model.mesh.kind.nodes_per_element()];
            for (&e, &gp) in sample.elements.iter().zip(&sample.points) {
                let xe = model.mesh.element_coords(e);
                let d = element::gather_point(&model.form, &rule, &xe, &zero, gp).map_err(|err| RomError::Element(crate::model::relabel(err, e)))?;
                item.push(pos[&e]);
                grad.push(d.g);
                wj0.push(d.wj0);
                phi.push(d.q);
                rigid.push(model.mesh.element(e).iter().any(|&n| (0..3).any(|c| matches!(model.dofs.comps[3 * n + c], Comp::Rigid(_)))));
            }
            let mut order: Vec<usize> = (0..item.len()).filter(|&i| jac_const[item[i]].is_some()).collect();
            let n_const = order.len();
            let mut dynamic: Vec<usize> = (0..item.len()).filter(|&i| jac_const[item[i]].is_none()).collect();
            dynamic.sort_by_key(|&i| item[i]);
            order.extend(dynamic);
            let mut g_const = vec![0.0; 9 * n_const * m];
            for (slot, &i) in order[..n_const].iter().enumerate() {
                point_g(&grad[i], jac_const[item[i]].as_deref().unwrap_or(&[]), m, &mut g_const[9 * slot * m..9 * (slot + 1) * m]);
            }
            let dyn_nodes: Vec<Vec<(usize, usize)>> =
                elem_items.iter().map(|&e| model.mesh.element(e).iter().enumerate().filter(|&(_, &nd)| !is_static(nd)).map(|(a, &nd)| (a, nd)).collect()).collect();
            let mut g_dyn_static = vec![0.0; 9 * (item.len() - n_const) * m];
            let mut jac = Vec::new();
            for (d, &i) in order[n_const..].iter().enumerate() {
                red.jacobian(model.mesh.element(elem_items[item[i]]), &kin0, &mut scratch, &mut jac);
                for &(a, _) in &dyn_nodes[item[i]] {
                    jac[3 * a * m..3 * (a + 1) * m].iter_mut().for_each(|v| *v = 0.0);
                }
                point_g(&grad[i], &jac, m, &mut g_dyn_static[9 * d * m..9 * (d + 1) * m]);
            }
            Some(PointSample { item, grad, wj0, phi, rigid, order, n_const, g_const, g_dyn_static, dyn_nodes })
        } else {
            None
        };
        Ok(RomPath {
            red,
            sample,
            from,
            to,
            functionals,
            volume_control: model.cavity.is_some(),
            rule,
            mixed,
            jac_const,
            last: Default::default(),
            elem_items,
            points,
            cavity,
            cavity_lag: 0.0,
            cavity_hessian: Default::default(),
        })
    }

    /// Let the path follower's tangents (the [`PathModel`] evaluations) reuse the cavity's load
    /// stiffness −p ∂²V/∂z² while the state is within `tol` (relative, in z) of where it was last
    /// computed: within one step's Newton corrections it is then computed once. The residual,
    /// the volume and ∂V/∂z stay exact, so converged states are the same (to the solver's
    /// tolerance); only the corrector's convergence rate and the converged states' tangents
    /// (stability, dλ/dc) change, by O(tol). [`RomPath::evaluate`] (sensitivities, factors handed
    /// on) stays exact. 0 (the default): exact everywhere.
    pub fn set_cavity_hessian_lag(&mut self, tol: f64) {
        self.cavity_lag = if tol.is_finite() && tol > 0.0 { tol } else { 0.0 };
    }

    /// J of item `i` (see `jac_const`): the cached one, or built into `buf`.
    fn item_jacobian<'b>(&'b self, i: usize, nodes: &[usize], kin: &[BodyKin], scratch: &mut Vec<(u32, f64)>, buf: &'b mut Vec<f64>) -> &'b [f64] {
        match &self.jac_const[i] {
            Some(j) => j,
            None => {
                self.red.jacobian(nodes, kin, scratch, buf);
                buf
            }
        }
    }

    pub fn loads(&self, lam: f64) -> Loads {
        Loads::lerp(&self.from, &self.to, lam)
    }

    /// Residual, tangent and state at (z, loads).
    pub fn evaluate(&self, z: &[f64], loads: &Loads, want_k: bool) -> Result<(Vec<f64>, Option<Mat<f64>>, RomState, f64, f64), ElementError> {
        self.evaluate_with(z, loads, want_k, false)
    }

    /// [`RomPath::evaluate`]; with `lag`, the cavity Hessian as [`RomPath::set_cavity_hessian_lag`] allows.
    fn evaluate_with(&self, z: &[f64], loads: &Loads, want_k: bool, lag: bool) -> Result<(Vec<f64>, Option<Mat<f64>>, RomState, f64, f64), ElementError> {
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
        // the symmetric products' lower triangles (mirrored into kz at the end)
        let mut kl = want_k.then(|| Mat::<f64>::zeros(m, m));
        match &self.points {
            Some(ps) => self.internal_points(ps, &u, &kin, &mut r, kz.as_mut().zip(kl.as_mut()), &mut r_body, &mut energy, &mut min_det, &mut scale_sq)?,
            None => self.internal_elements(&u, &kin, &mut r, kz.as_mut(), &mut r_body, &mut energy, &mut min_det, &mut scale_sq)?,
        }
        // cavity: exact volume, −p ∂V/∂z and −p ∂²V/∂z² over every face and boundary edge
        let p = loads.pressure;
        let (volume, dvol) = match (&model.cavity, &self.cavity) {
            (Some(cav), Some(cp)) => {
                let lagged = (lag && self.cavity_lag > 0.0).then_some((&self.cavity_hessian, self.cavity_lag));
                cp.add(&self.red, cav, z, &u, &kin, p, &mut r, &mut r_body, kl.as_mut(), lagged)
            }
            _ => (0.0, vec![0.0; m]),
        };
        let k = self.red.basis.k;
        let nb = self.red.basis.n;
        let zi = |i: usize| k + i - nb;
        // the caps' pressure correction and the bodies' dead forces (the full model's terms, on
        // the rigid coordinates)
        for (i, v) in model.rigid_load_terms(x0, p, &loads.body_forces) {
            r[zi(i)] += v;
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
        if let (Some(kz), Some(kl)) = (kz.as_mut(), kl.as_ref()) {
            mirror_lower(kz, kl);
        }
        if !r.iter().all(|v| v.is_finite()) || kz.as_ref().is_some_and(|k| !(0..m).all(|j| (0..m).all(|i| k[(i, j)].is_finite()))) {
            return Err(ElementError::NonFinite(usize::MAX));
        }
        let scale = scale_sq.sqrt().max(p.abs() * dvol.iter().map(|x| x * x).sum::<f64>().sqrt());
        Ok((r, kz, RomState { q, u, kin, r_body, volume, dvol, energy }, scale, min_det))
    }

    /// The sampled elements' internal forces (and tangent) in reduced coordinates, with the
    /// reduced pressure space's volumetric terms, added into r (kz, r_body, energy, min_det,
    /// scale_sq).
    #[allow(clippy::too_many_arguments)]
    fn internal_elements(
        &self,
        u: &[[f64; 3]],
        kin: &[BodyKin],
        r: &mut [f64],
        mut kz: Option<&mut Mat<f64>>,
        r_body: &mut [f64],
        energy: &mut f64,
        min_det: &mut f64,
        scale_sq: &mut f64,
    ) -> Result<(), ElementError> {
        let model = self.red.model;
        let x0 = &model.mesh.nodes;
        let m = self.red.dim();
        let want_k = kz.is_some();
        let mut scratch = Vec::new();
        let mut jac = Vec::new();
        let nn = model.mesh.kind.nodes_per_element();
        let nd = 3 * nn;
        let mut f = vec![0.0; nd];
        let mut ke = vec![0.0; if want_k { nd * nd } else { 0 }];
        // a reduced pressure space: project J, then U'(θ), on it (the volumetric energy, the
        // element pressures, and the low-rank volumetric stiffness B_rᵀ M⁻¹ H M⁻¹ B_r)
        let pressure = match (&self.mixed, &self.red.basis.pressure) {
            (Some(mx), Some(pb)) => {
                let mom = element_moments(model, &self.rule, self.sample, u, min_det)?;
                Some(reduced_pressure(model, self.sample, mx, pb, &mom, energy, min_det).map(|(a, b, _)| (a, b))?)
            }
            _ => None,
        };
        let kp = self.red.basis.pressure.as_ref().map_or(0, |p| p.kp);
        let mut b_red = (want_k && pressure.is_some()).then(|| Mat::<f64>::zeros(kp, m));
        let mut bv = Vec::new();
        // products into reused buffers, sequentially (faer's operators use the global
        // parallelism, whose dispatch costs more than these small products)
        let mut kj = Mat::<f64>::zeros(nd, m);
        let mut re = Mat::<f64>::zeros(m, 1);
        for (s_i, (&e, &w)) in self.sample.elements.iter().zip(&self.sample.weights).enumerate() {
            let conn = model.mesh.element(e);
            let xe: Vec<[f64; 3]> = conn.iter().map(|&n| x0[n]).collect();
            let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
            let given = pressure.as_ref().map(|p| &p.0[s_i][..]);
            let info = if want_k {
                element::tangent_with(&model.form, &self.rule, &model.material, &model.params, &xe, &ue, None, given, &mut f, &mut ke, given.map(|_| &mut bv))
            } else {
                element::residual_with(&model.form, &self.rule, &model.material, &model.params, &xe, &ue, given, &mut f)
            }
            .map_err(|err| crate::model::relabel(err, e))?;
            *energy += w * info.energy;
            *min_det = min_det.min(info.min_det_f);
            let jac = self.item_jacobian(s_i, conn, kin, &mut scratch, &mut jac);
            let jm = faer::MatRef::from_row_major_slice(jac, nd, m);
            let fm = faer::MatRef::from_column_major_slice(&f, nd, 1);
            faer::linalg::matmul::matmul(re.as_mut(), faer::Accum::Replace, jm.transpose(), fm, 1.0, faer::Par::Seq);
            let mut re2 = 0.0;
            for i in 0..m {
                r[i] += w * re[(i, 0)];
                re2 += re[(i, 0)] * re[(i, 0)];
            }
            *scale_sq += w * re2;
            add_body_nodal(model, conn, &f, w, r_body);
            if let Some(kz) = kz.as_mut() {
                let km = faer::MatRef::from_row_major_slice(&ke, nd, nd);
                faer::linalg::matmul::matmul(kj.as_mut(), faer::Accum::Replace, km, jm, 1.0, faer::Par::Seq);
                faer::linalg::matmul::matmul(kz.as_mut(), faer::Accum::Add, jm.transpose(), kj.as_ref(), w, faer::Par::Seq);
            }
            if let (Some(br), Some(pb)) = (b_red.as_mut(), &self.red.basis.pressure) {
                // B_r += w Ψ_eᵀ (Bv_e J_e)
                let np = pb.np;
                let bvm = faer::MatRef::from_row_major_slice(&bv, np, nd);
                let pe = faer::MatRef::from_row_major_slice(pb.block(e), np, kp);
                let mut bj = Mat::<f64>::zeros(np, m);
                faer::linalg::matmul::matmul(bj.as_mut(), faer::Accum::Replace, bvm, jm, 1.0, faer::Par::Seq);
                faer::linalg::matmul::matmul(br.as_mut(), faer::Accum::Add, pe.transpose(), bj.as_ref(), w, faer::Par::Seq);
            }
        }
        if let (Some(kz), Some(br), Some((_, h)), Some(mx)) = (kz.as_mut(), b_red.as_ref(), pressure.as_ref(), self.mixed.as_ref()) {
            let c = &mx.mass_inv * h * &mx.mass_inv;
            faer::linalg::matmul::matmul(kz.as_mut(), faer::Accum::Add, br.transpose(), (&c * br).as_ref(), 1.0, faer::Par::Seq);
        }
        Ok(())
    }

    /// [`RomPath::internal_elements`] for a quadrature-level sample: at each sampled point
    /// F = I + Σ u_a ⊗ ∇N_a, P and A = ∂P/∂F under the reduced pressure, the reduced force
    /// w Gᵀ P and tangent w Gᵀ A G (one product over all points), G = ∂F/∂z precomputed per
    /// design where it does not depend on the state.
    #[allow(clippy::too_many_arguments)]
    fn internal_points(
        &self,
        ps: &PointSample,
        u: &[[f64; 3]],
        kin: &[BodyKin],
        r: &mut [f64],
        tangent: Option<(&mut Mat<f64>, &mut Mat<f64>)>,
        r_body: &mut [f64],
        energy: &mut f64,
        min_det: &mut f64,
        scale_sq: &mut f64,
    ) -> Result<(), ElementError> {
        let _ftz = crate::fpenv::FlushDenormals::new();
        let model = self.red.model;
        let m = self.red.dim();
        let n = ps.item.len();
        let (Some(mx), Some(pb)) = (&self.mixed, &self.red.basis.pressure) else {
            // (refused by `RomPath::new`)
            return Err(ElementError::NonFinite(usize::MAX));
        };
        let (np, kp) = (pb.np, pb.kp);
        // kinematics and dilatation moments at every sampled point
        let mut kinem = Vec::with_capacity(n);
        let mut moments = Vec::with_capacity(n);
        for i in 0..n {
            let (f, j) = self.point_f(ps, i, u)?;
            *min_det = min_det.min(j);
            kinem.push((f, crate::scalar::inv3(&f, j), j));
            moments.push((0..np).map(|rr| ps.phi[i][rr] * j * ps.wj0[i]).collect::<Vec<f64>>());
        }
        let (pcs, h, _) = reduced_pressure(model, self.sample, mx, pb, &moments, energy, min_det)?;
        let want_k = tangent.is_some();
        // row-major 9 × m blocks: A G of a chunk of points (their product with G goes into the
        // tangent chunk by chunk, while A G is in cache), G of the state-dependent points
        // (reused per thread: fresh multi-megabyte buffers cost page faults at every evaluation;
        // every entry used is overwritten below)
        let (mut ag, mut g_dyn) = POINT_BUFFERS.with(|b| std::mem::take(&mut *b.borrow_mut()));
        if want_k && ag.len() < 9 * POINT_CHUNK * m {
            ag.resize(9 * POINT_CHUNK * m, 0.0);
        }
        let (kz, mut kl) = match tangent {
            Some((kz, kl)) => (Some(kz), Some(kl)),
            None => (None, None),
        };
        // G of the state-dependent points: the static nodes' part, then the others' sparse rows
        g_dyn.clear();
        g_dyn.extend_from_slice(&ps.g_dyn_static);
        {
            let x0 = &model.mesh.nodes;
            let (k, nb) = (self.red.basis.k, self.red.basis.n);
            let mut rows: Vec<Vec<(u32, f64)>> = Vec::new();
            let mut item = usize::MAX;
            for (d, &i) in ps.order[ps.n_const..].iter().enumerate() {
                let dn = &ps.dyn_nodes[ps.item[i]];
                if item != ps.item[i] {
                    item = ps.item[i];
                    rows.resize(3 * dn.len(), Vec::new());
                    for (t_, &(_, node)) in dn.iter().enumerate() {
                        for cc in 0..3 {
                            rows[3 * t_ + cc].clear();
                            model.dofs.row(x0, kin, node, cc, &mut rows[3 * t_ + cc]);
                        }
                    }
                }
                let gd = &mut g_dyn[9 * d * m..9 * (d + 1) * m];
                for (t_, &(a_, _)) in dn.iter().enumerate() {
                    for cc in 0..3 {
                        for cj in 0..3 {
                            let coef = ps.grad[i][a_][cj];
                            if coef == 0.0 {
                                continue;
                            }
                            let grow = &mut gd[(3 * cc + cj) * m..(3 * cc + cj + 1) * m];
                            for &(ii, cf) in &rows[3 * t_ + cc] {
                                let ii = ii as usize;
                                if ii < nb {
                                    for (x, y) in grow.iter_mut().zip(self.red.phi_row(ii)) {
                                        *x += coef * cf * y;
                                    }
                                } else {
                                    grow[k + ii - nb] += coef * cf;
                                }
                            }
                        }
                    }
                }
            }
        }
        let mut djs = vec![0.0; if want_k { n * m } else { 0 }];
        let mut psiw = vec![0.0; if want_k { n * kp } else { 0 }];
        let nd = 3 * model.mesh.kind.nodes_per_element();
        let mut fnod = vec![0.0; nd];
        let mut c = vec![0.0; m];
        // per element item: the sum of its points' weighted reduced forces and their weight
        // (indexed by item, not hashed: the sum's order, and so the Newton test, is deterministic)
        let mut groups: Vec<(Vec<f64>, f64)> = vec![(Vec::new(), 0.0); self.elem_items.len()];
        let ngp = self.rule.weights.len() as f64;
        let axpy = |o: &mut [f64], c: f64, x: &[f64]| {
            for (a, b) in o.iter_mut().zip(x) {
                *a += c * b;
            }
        };
        let mut chunk_start = 0;
        for (slot, &i) in ps.order.iter().enumerate() {
            let e = self.elem_items[ps.item[i]];
            let conn = model.mesh.element(e);
            let g: &[f64] = if slot < ps.n_const {
                &ps.g_const[9 * slot * m..9 * (slot + 1) * m]
            } else {
                let d = slot - ps.n_const;
                &g_dyn[9 * d * m..9 * (d + 1) * m]
            };
            let (f, fi, j) = &kinem[i];
            let p: f64 = pcs[i].iter().zip(&ps.phi[i]).map(|(a, b)| a * b).sum();
            let w = self.sample.weights[i];
            let wj0 = ps.wj0[i];
            let wt = w * wj0;
            let (wiso, pk) = if want_k {
                let (wiso, pk, a) = element::point_tangent(&model.material, &model.params, f, fi, *j, p, p * j);
                let pw = [pk[0][0], pk[0][1], pk[0][2], pk[1][0], pk[1][1], pk[1][2], pk[2][0], pk[2][1], pk[2][2]].map(|v| v * wt);
                let wa = a.map(|row| row.map(|v| v * wt));
                // ∂J/∂z = J F⁻ᵀ : G (F⁻ᵀ[i][J] = F⁻¹[J][i])
                let fv = [fi[0][0], fi[1][0], fi[2][0], fi[0][1], fi[1][1], fi[2][1], fi[0][2], fi[1][2], fi[2][2]].map(|v| v * j);
                let cs = slot;
                let a = slot - chunk_start;
                point_tangent_columns(g, m, &pw, &wa, &fv, &mut c, &mut djs[cs * m..(cs + 1) * m], &mut ag[9 * a * m..9 * (a + 1) * m]);
                let pe = pb.block(e);
                for jp in 0..kp {
                    psiw[cs * kp + jp] = (0..np).map(|rr| pe[rr * kp + jp] * ps.phi[i][rr]).sum::<f64>() * wt;
                }
                (wiso, pk)
            } else {
                let (wiso, pk) = element::point_stress(&model.material, &model.params, f, fi, *j, p);
                let pw = [pk[0][0], pk[0][1], pk[0][2], pk[1][0], pk[1][1], pk[1][2], pk[2][0], pk[2][1], pk[2][2]].map(|v| v * wt);
                point_force_columns(g, m, &pw, &mut c);
                (wiso, pk)
            };
            *energy += wt * wiso;
            let grp = &mut groups[ps.item[i]];
            if grp.0.is_empty() {
                grp.0 = vec![0.0; m];
            }
            axpy(r, 1.0, &c);
            axpy(&mut grp.0, 1.0, &c);
            grp.1 += w;
            if ps.rigid[i] {
                for (a_, ga) in ps.grad[i].iter().enumerate() {
                    for ci in 0..3 {
                        fnod[3 * a_ + ci] = wj0 * (pk[ci][0] * ga[0] + pk[ci][1] * ga[1] + pk[ci][2] * ga[2]);
                    }
                }
                add_body_nodal(model, conn, &fnod, w, r_body);
            }
            // the chunk's Gᵀ (A G), at its end (chunks do not straddle the constant-G entries' end)
            let end = slot + 1;
            if let Some(kl) = kl.as_mut().filter(|_| end == n || end == ps.n_const || end - chunk_start == POINT_CHUNK) {
                let rows = 9 * (end - chunk_start);
                let gs = if chunk_start < ps.n_const { &ps.g_const[9 * chunk_start * m..9 * end * m] } else { &g_dyn[9 * (chunk_start - ps.n_const) * m..9 * (end - ps.n_const) * m] };
                let gm = faer::MatRef::from_row_major_slice(&gs[..rows * m], rows, m);
                let agm = faer::MatRef::from_row_major_slice(&ag[..rows * m], rows, m);
                lower_product(kl, gm.transpose(), agm, 1.0);
                chunk_start = end;
            }
        }
        if let Some(kz) = kz {
            fn rm(v: &[f64], rows: usize, m: usize) -> faer::MatRef<'_, f64> {
                faer::MatRef::from_row_major_slice(v, rows, m)
            }
            // B = Σ (w Ψ_eᵀ φ) ⊗ ∂J/∂z over the points
            let mut b_red = Mat::<f64>::zeros(kp, m);
            faer::linalg::matmul::matmul(b_red.as_mut(), faer::Accum::Replace, rm(&psiw, n, kp).transpose(), rm(&djs, n, m), 1.0, faer::Par::Seq);
            let cm = &mx.mass_inv * &h * &mx.mass_inv;
            faer::linalg::matmul::matmul(kz.as_mut(), faer::Accum::Add, b_red.transpose(), (&cm * &b_red).as_ref(), 1.0, faer::Par::Seq);
        }
        for (re, wsum) in &groups {
            if *wsum > 0.0 {
                *scale_sq += re.iter().map(|x| x * x).sum::<f64>() * ngp / wsum;
            }
        }
        POINT_BUFFERS.with(|b| *b.borrow_mut() = (ag, g_dyn));
        Ok(())
    }

    /// The sample entries' dilatation moments at displacement u (see [`element_moments`]).
    fn moments(&self, u: &[[f64; 3]], min_det: &mut f64) -> Result<Vec<Vec<f64>>, ElementError> {
        let Some(ps) = &self.points else { return element_moments(self.red.model, &self.rule, self.sample, u, min_det) };
        let np = self.red.basis.pressure.as_ref().map_or(1, |p| p.np);
        (0..ps.item.len())
            .map(|i| {
                let j = self.point_f(ps, i, u)?.1;
                *min_det = min_det.min(j);
                Ok((0..np).map(|rr| ps.phi[i][rr] * j * ps.wj0[i]).collect())
            })
            .collect()
    }

    /// F = I + Σ u_a ⊗ ∇N_a and J = det F at sample entry i (an error where J ≤ 0).
    fn point_f(&self, ps: &PointSample, i: usize, u: &[[f64; 3]]) -> Result<([[f64; 3]; 3], f64), ElementError> {
        let e = self.elem_items[ps.item[i]];
        let mut f = [[0.0f64; 3]; 3];
        for (c, row) in f.iter_mut().enumerate() {
            row[c] = 1.0;
        }
        for (a, &nd) in self.red.model.mesh.element(e).iter().enumerate() {
            let ga = ps.grad[i][a];
            for c in 0..3 {
                for cj in 0..3 {
                    f[c][cj] += u[nd][c] * ga[cj];
                }
            }
        }
        let j = crate::scalar::det3(&f);
        if !(j > 0.0) {
            return Err(ElementError::Inverted(e));
        }
        Ok((f, j))
    }

    /// The error indicator of a reduced state: the full model's momentum residual at the lifted
    /// displacement under the reduced model's own pressure field (every element, no
    /// factorisation), on the nodal unknowns, relative to the element forces' scale
    /// √Σ‖f_e‖². (Under each element's own condensed pressure instead, the residual is of the
    /// order of the forces for any reduced state of a nearly incompressible material: the
    /// reduced pressure space does not enforce the element-wise constraints, by design.)
    pub fn indicator(&self, z: &[f64], lam: f64) -> Result<f64, ElementError> {
        let model = self.red.model;
        let x0 = &model.mesh.nodes;
        let loads = self.loads(lam);
        let q = self.red.lift(z);
        let kin = model.dofs.body_kinematics(&q, &loads.presc);
        let u = model.dofs.expand(x0, &q, &loads.presc, &kin);
        let pi = match (&self.mixed, &self.red.basis.pressure) {
            (Some(mx), Some(pb)) => {
                let (mut en, mut md) = (0.0, f64::INFINITY);
                let mom = self.moments(&u, &mut md)?;
                Some(reduced_pressure(model, self.sample, mx, pb, &mom, &mut en, &mut md)?.2)
            }
            _ => None,
        };
        let n = self.red.basis.n;
        let mut r = vec![0.0; model.n_reduced()];
        let mut scale = 0.0;
        let mut scratch = Vec::new();
        let nd = 3 * model.mesh.kind.nodes_per_element();
        let mut f = vec![0.0; nd];
        let mut scatter = |nodes: &[usize], f: &[f64], c: f64, r: &mut [f64]| {
            for (a, &nn) in nodes.iter().enumerate() {
                for comp in 0..3 {
                    scratch.clear();
                    model.dofs.row(x0, &kin, nn, comp, &mut scratch);
                    for &(i, cf) in scratch.iter() {
                        r[i as usize] += c * cf * f[3 * a + comp];
                    }
                }
            }
        };
        for e in 0..model.mesh.n_elements() {
            let conn = model.mesh.element(e);
            let xe: Vec<[f64; 3]> = conn.iter().map(|&nn| x0[nn]).collect();
            let ue: Vec<[f64; 3]> = conn.iter().map(|&nn| u[nn]).collect();
            let given = match (&pi, &self.red.basis.pressure) {
                (Some(pi), Some(pb)) => Some(element_pressure(pb, e, pi)),
                _ => None,
            };
            element::residual_with(&model.form, &self.rule, &model.material, &model.params, &xe, &ue, given.as_deref(), &mut f).map_err(|err| crate::model::relabel(err, e))?;
            scale += f.iter().map(|x| x * x).sum::<f64>();
            scatter(conn, &f, 1.0, &mut r);
        }
        if let Some(cav) = &model.cavity {
            let mut g = vec![0.0; 3 * x0.len()];
            surface::volume_and_gradient(cav, |nn| [x0[nn][0] + u[nn][0], x0[nn][1] + u[nn][1], x0[nn][2] + u[nn][2]], &mut g, |_, _, _, _| {});
            for (nn, gn) in g.chunks_exact(3).enumerate().filter(|(_, gn)| gn.iter().any(|v| *v != 0.0)) {
                scatter(&[nn], gn, -loads.pressure, &mut r);
            }
        }
        let rn = r[..n].iter().map(|x| x * x).sum::<f64>().sqrt();
        Ok(rn / scale.sqrt().max(1e-300))
    }

    /// The reduced load of a unit cavity pressure, ∂V/∂z less the caps' areas when they carry no
    /// pressure (as [`Model::unit_pressure_load`]).
    fn unit_pressure_load(&self, dvol: &[f64]) -> Vec<f64> {
        let model = self.red.model;
        let mut l = dvol.to_vec();
        for (i, a) in model.rigid_load_terms(&model.mesh.nodes, 1.0, &[]) {
            l[self.red.basis.k + i - self.red.basis.n] -= a;
        }
        l
    }

    /// The factor of the reduced tangent at (z, λ): Cholesky, or LU where it is indefinite.
    pub fn tangent_factor(&self, z: &[f64], lam: f64) -> Result<DenseFactor, RomError> {
        let k = self.evaluate(z, &self.loads(lam), true)?.1.ok_or(RomError::SingularTangent)?;
        self.factor(&k, true).or_else(|_| self.factor(&k, false)).map_err(|_| RomError::SingularTangent)
    }

    /// The reduced tangent's eigenvalue nearest zero at (z, λ) and its unit eigenvector (at a
    /// fold, the null vector).
    pub fn null_vector(&self, z: &[f64], lam: f64) -> Result<(f64, Vec<f64>), RomError> {
        let k = self.evaluate(z, &self.loads(lam), true)?.1.ok_or(RomError::SingularTangent)?;
        let eig = k.as_ref().self_adjoint_eigen(Side::Lower).map_err(|_| RomError::SingularTangent)?;
        let s = eig.S();
        let j = (0..k.nrows()).min_by(|&a, &b| s[a].abs().total_cmp(&s[b].abs())).ok_or(RomError::SingularTangent)?;
        Ok((s[j], (0..k.nrows()).map(|i| eig.U()[(i, j)]).collect()))
    }

    /// The functionals' values at (z, λ) (NaN where one cannot be evaluated).
    pub fn functional_values(&self, z: &[f64], lam: f64) -> Result<Vec<f64>, ElementError> {
        let st = self.evaluate(z, &self.loads(lam), false)?.2;
        let fs = self.functional_state(&st);
        Ok(self.functionals.iter().map(|f| f.eval(self.red.model, &fs).unwrap_or(f64::NAN)).collect())
    }

    /// The sensitivity of a reduced equilibrium z* (R(z*) = 0 at λ) and of its functionals to
    /// one input s, by the direct method on the reduced tangent: dz/ds = −K⁻¹ ∂R/∂s with `factor`
    /// the factor of K at z*. `plus` and `minus` are the same reduced model (same basis, sample
    /// and functionals) with the input at s ± h, each with its λ: the meshes of a design
    /// parameter ± h, or this path at λ ± h/(dp/dλ) for the pressure. ∂R/∂s is the central
    /// difference of their residuals at fixed z, and dF/ds the central difference of the
    /// functionals along (dz/ds, ds): F(z + h dz/ds; s + h) − F(z − h dz/ds; s − h), over 2h.
    /// (With a reduced space of tens of coordinates the direct method costs one dense solve per
    /// input, the adjoint one per functional: the same here.) Returns (dz/ds, dF/ds).
    pub fn direct_sensitivity(&self, z: &[f64], factor: &DenseFactor, plus: (&RomPath, f64), minus: (&RomPath, f64), h: f64) -> Result<(Vec<f64>, Vec<f64>), RomError> {
        let m = self.red.dim();
        if plus.0.red.dim() != m || minus.0.red.dim() != m || z.len() != m {
            return Err(RomError::SensitivityDims(m, plus.0.red.dim(), minus.0.red.dim()));
        }
        let el = |e: ElementError| RomError::Element(e);
        let rp = plus.0.evaluate(z, &plus.0.loads(plus.1), false).map_err(el)?.0;
        let rm = minus.0.evaluate(z, &minus.0.loads(minus.1), false).map_err(el)?.0;
        let dr: Vec<f64> = rp.iter().zip(&rm).map(|(a, b)| (a - b) / (2.0 * h)).collect();
        let dz: Vec<f64> = self.solve(factor, &dr).map_err(|_| RomError::SingularTangent)?.into_iter().map(|v| -v).collect();
        let zp: Vec<f64> = z.iter().zip(&dz).map(|(a, d)| a + h * d).collect();
        let zm: Vec<f64> = z.iter().zip(&dz).map(|(a, d)| a - h * d).collect();
        let fp = plus.0.functional_values(&zp, plus.1).map_err(el)?;
        let fm = minus.0.functional_values(&zm, minus.1).map_err(el)?;
        Ok((dz, fp.iter().zip(&fm).map(|(a, b)| (a - b) / (2.0 * h)).collect()))
    }

    /// The full-model state of the functionals at a reduced evaluation.
    pub fn functional_state(&self, st: &RomState) -> State<f64> {
        let bodies = st.kin.iter().map(|k| BodyState { c: k.c, psi: k.psi, r: k.r, dr: k.dr }).collect();
        State { x0: self.red.model.mesh.nodes.clone(), u: st.u.clone(), r_full: st.r_body.clone(), r: Vec::new(), volume: st.volume, gvol_full: Vec::new(), bodies }
    }
}

/// The projections on a reduced pressure space at displacement u (given by the sample entries'
/// dilatation moments, see [`element_moments`]): θ = Π_r J, then
/// p = Π_r U'(θ). Returns each sampled element's pressure coefficients and the reduced
/// H = Σ w Ψ_eᵀ (∫ φ φᵀ U″(θ)) Ψ_e and the reduced pressure coordinates π; adds the volumetric energy.
/// The dilatation moments ∫ φ_r J dV of each entry of an element sample at displacement u
/// (the smallest det F into `min_det`).
fn element_moments(model: &Model, rule: &HexRule, sample: &Sample, u: &[[f64; 3]], min_det: &mut f64) -> Result<Vec<Vec<f64>>, ElementError> {
    let x0 = &model.mesh.nodes;
    let mut out = Vec::with_capacity(sample.elements.len());
    for &e in &sample.elements {
        let conn = model.mesh.element(e);
        let xe: Vec<[f64; 3]> = conn.iter().map(|&n| x0[n]).collect();
        let ue: Vec<[f64; 3]> = conn.iter().map(|&n| u[n]).collect();
        let (be, _, mj) = element::dilatation_moments(&model.form, rule, &xe, &ue).map_err(|err| crate::model::relabel(err, e))?;
        *min_det = min_det.min(mj);
        out.push(be);
    }
    Ok(out)
}

/// [`element_moments`] with `moments` given per sample entry (its element's, or its point's
/// φ_r J w det J₀).
fn reduced_pressure(
    model: &Model,
    sample: &Sample,
    mx: &Mixed,
    pb: &PressureBasis,
    moments: &[Vec<f64>],
    energy: &mut f64,
    min_det: &mut f64,
) -> Result<(Vec<Vec<f64>>, Mat<f64>, Vec<f64>), ElementError> {
    let (np, kp) = (pb.np, pb.kp);
    let mut b = vec![0.0; kp];
    for ((&e, &w), be) in sample.elements.iter().zip(&sample.weights).zip(moments) {
        let pe = pb.block(e);
        for r in 0..np {
            for (bj, psi) in b.iter_mut().zip(&pe[r * kp..(r + 1) * kp]) {
                *bj += w * psi * be[r];
            }
        }
    }
    let coef = |v: &[f64]| -> Vec<f64> { (0..kp).map(|i| (0..kp).map(|j| mx.mass_inv[(i, j)] * v[j]).sum()).collect() };
    let c = coef(&b);
    let mut rr = vec![0.0; kp];
    let mut h = Mat::<f64>::zeros(kp, kp);
    let mut th = vec![0.0; np];
    let mut psi = vec![0.0; kp];
    for (s_i, (&e, &w)) in sample.elements.iter().zip(&sample.weights).enumerate() {
        let pe = pb.block(e);
        for (r, t) in th.iter_mut().enumerate() {
            *t = pe[r * kp..(r + 1) * kp].iter().zip(&c).map(|(a, b)| a * b).sum();
        }
        // per quadrature point: ψ = Ψ_eᵀ φ, then rr += w U' wj ψ and H += w U'' wj ψ ψᵀ
        for (phi, wj) in &mx.quad[s_i] {
            let t: f64 = (0..np).map(|r| th[r] * phi[r]).sum();
            if !(t > 0.0) {
                return Err(ElementError::Inverted(e));
            }
            *min_det = min_det.min(t);
            let [uv, up, upp] = model.material.u_vol(&model.params, t);
            *energy += w * uv * wj;
            for (j, v) in psi.iter_mut().enumerate() {
                *v = (0..np).map(|r| pe[r * kp + j] * phi[r]).sum();
            }
            let (cr, ch) = (w * up * wj, w * upp * wj);
            for j in 0..kp {
                rr[j] += cr * psi[j];
                let hj = ch * psi[j];
                for i in 0..kp {
                    h[(i, j)] += hj * psi[i];
                }
            }
        }
    }
    let pi = coef(&rr);
    let pcs = sample.elements.iter().map(|&e| element_pressure(pb, e, &pi));
    Ok((pcs.collect(), h, pi))
}

/// Element e's pressure coefficients Ψ_e π of reduced pressure coordinates π.
fn element_pressure(pb: &PressureBasis, e: usize, pi: &[f64]) -> Vec<f64> {
    let (np, kp) = (pb.np, pb.kp);
    let pe = pb.block(e);
    (0..np).map(|r| pe[r * kp..(r + 1) * kp].iter().zip(pi).map(|(a, b)| a * b).sum()).collect()
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
        let (r, k, st, scale, min_det) = self.evaluate_with(z, &loads, tangent, true).map_err(elem_eval)?;
        let control = (self.volume_control && self.red.model.cavity.is_some()).then(|| (st.volume, st.dvol.clone()));
        // (residual-only evaluations too: Newton's converged iterate is often one)
        if !self.functionals.is_empty() {
            if let Ok(mut last) = self.last.lock() {
                *last = Some((z.to_vec(), lam, st));
            }
        }
        Ok(Eval { r, scale, control, min_det, k, potential: None })
    }
    fn diagonal(&self, k: &Mat<f64>) -> Option<Vec<f64>> {
        Some((0..k.nrows()).map(|i| k[(i, i)]).collect())
    }
    fn shifted(&self, k: &Mat<f64>, d: &[f64]) -> Option<Mat<f64>> {
        let mut m = k.clone();
        for (i, di) in d.iter().enumerate() {
            m[(i, i)] += di;
        }
        Some(m)
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
        // the converged state's tangent evaluation is usually the last one (else evaluate)
        let cached = self.last.lock().ok().and_then(|l| l.as_ref().filter(|(lz, ll, _)| *ll == lam && lz.as_slice() == z).map(|(_, _, st)| st.clone()));
        match cached.map(Ok).unwrap_or_else(|| self.evaluate(z, &self.loads(lam), false).map(|e| e.2)) {
            Ok(st) => {
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
    /// the cavity tensors of its paths, built on first use per dof layout
    #[serde(skip)]
    pub tensors: CavityTensors,
}

impl Rom {
    pub fn new(basis: Basis, sample: Sample) -> Rom {
        Rom { basis, sample, tensors: CavityTensors::default() }
    }

    /// The reduced path model of `model` under loads from `from` (λ = 0) to `to` (λ = 1).
    pub fn path<'a>(&'a self, model: &'a Model, from: Loads, to: Loads, functionals: Vec<Functional>) -> Result<RomPath<'a>, RomError> {
        RomPath::with_tensors(model, &self.basis, &self.sample, from, to, functionals, Some(&self.tensors))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn append_directions_adds_only_what_the_basis_lacks() {
        // snapshots span e0, e1 of R^6; directions: one inside the span, one along e2 + e0
        let e = |i: usize| (0..6).map(|j| if j == i { 1.0 } else { 0.0 }).collect::<Vec<f64>>();
        let snaps = vec![e(0), e(1), vec![1.0, 1.0, 0.0, 0.0, 0.0, 0.0]];
        let mut b = Basis::pod(&snaps, Truncation::Modes(4)).unwrap();
        assert_eq!(b.k, 2);
        let inside = vec![3.0, -2.0, 0.0, 0.0, 0.0, 0.0];
        let outside = vec![1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let s = b.append_directions(&[inside.clone(), outside], 3, 1e-3).unwrap();
        assert_eq!(s.len(), 1, "only the new direction: {s:?}");
        assert!((s[0] - 0.5f64.sqrt()).abs() < 1e-12, "its part outside the span: {}", s[0]);
        assert_eq!(b.k, 3);
        // orthonormal, and the new mode is ±e2
        for a in 0..3 {
            for c in 0..3 {
                let dot: f64 = (0..6).map(|i| b.row(i)[a] * b.row(i)[c]).sum();
                assert!((dot - if a == c { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!((b.row(2)[2].abs() - 1.0).abs() < 1e-12);
        // a direction already in the span adds nothing
        let s = b.append_directions(&[inside], 3, 1e-3).unwrap();
        assert!(s.is_empty());
        assert_eq!(b.k, 3);
        // malformed input is an error, not a panic
        assert!(b.append_directions(&[vec![1.0; 5]], 3, 1e-3).is_err());
        assert!(b.append_directions(&[vec![f64::NAN; 6]], 3, 1e-3).is_err());
    }
}
