//! CalculiX (`ccx`) decks of the actuator scenes, running ccx, and reading what it writes.
//!
//! [`build_deck`] writes a complete, runnable deck for one scene on the full 360° mesh: the
//! problem's structured mesh (Hex27 → C3D20R through its first 20 nodes, or C3D20 / C3D8I /
//! C3D8), `*HYPERELASTIC, NEO HOOKE` with C10 = μ/2 and D1 = 2/κ (the same decoupled law as
//! twistopt's), bottom face fixed, the top face a `*RIGID BODY` whose REF NODE (translations) and
//! ROT NODE (rotations) sit on the axis at z = L, the cap force p·A_cap on the REF NODE (`*CLOAD`
//! in z), the follower pressure `*DLOAD` on the cavity faces, and one `*STEP` (`*STATIC`,
//! NLGEOM) per requested pressure so that ccx ends a step exactly at every requested pressure.
//!
//! Constraints of the cap: its lateral translations and tilts are held (the loads are 3-fold
//! symmetric, so the 120° sector model twistopt runs by default holds them by symmetry); its
//! axial translation and its rotation about z are free or held as the scene says.
//!
//! Units: mm, N, MPa (kPa × 1e-3). Outputs (`*NODE PRINT` into `<job>.dat`): U of the REF NODE
//! (axial displacement), U and RF of the ROT NODE (rotation about z, the support's moment about
//! z), U of the outer-wall nodes (max deformed radius), U of one top node (an independent check
//! of the cap rotation).

pub mod compare;
pub mod contact;
pub mod dat;

use anyhow::{anyhow, bail, Context, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::export::inp::inp_string_with_type;
use crate::geometry::{ActuatorGeometry, L_TUBE};
use crate::meshing::{build_mesh, MeshSpec};
use crate::scene::SceneKind;
use twistopt_solver::material::Material;
use twistopt_solver::mesh::{ElementKind, Mesh};
use twistopt_solver::surface::{edge_area, Cavity};

/// CalculiX element used for the structured mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum CcxElement {
    /// 20-node hexahedron, reduced (2×2×2) integration — the default.
    C3D20R,
    /// 20-node hexahedron, full (3×3×3) integration.
    C3D20,
    /// 8-node hexahedron with incompatible modes (corner nodes of the quadratic mesh).
    C3D8I,
    /// 8-node hexahedron (ccx uses its B-bar form).
    C3D8,
}

impl CcxElement {
    pub fn parse(s: &str) -> Result<CcxElement> {
        match s.trim().to_ascii_uppercase().as_str() {
            "C3D20R" => Ok(CcxElement::C3D20R),
            "C3D20" => Ok(CcxElement::C3D20),
            "C3D8I" => Ok(CcxElement::C3D8I),
            "C3D8" => Ok(CcxElement::C3D8),
            _ => bail!("unknown CalculiX element '{s}' (expected C3D20R, C3D20, C3D8I or C3D8)"),
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            CcxElement::C3D20R => "C3D20R",
            CcxElement::C3D20 => "C3D20",
            CcxElement::C3D8I => "C3D8I",
            CcxElement::C3D8 => "C3D8",
        }
    }
    /// twistopt's formulation with the same discretisation as this ccx element: the same nodes,
    /// pure displacement (no pressure projection), the same Gauss rule (C3D20R: 2×2×2; C3D20:
    /// 3×3×3). None for C3D8I/C3D8, whose enhanced/B-bar forms twistopt does not have.
    pub fn matched_formulation(self) -> Option<twistopt_solver::element::Formulation> {
        use twistopt_solver::element::{Formulation, PressureSpace};
        match self {
            CcxElement::C3D20R => Some(Formulation { kind: ElementKind::Hex20, pressure: PressureSpace::None, ngauss: 2 }),
            CcxElement::C3D20 => Some(Formulation { kind: ElementKind::Hex20, pressure: PressureSpace::None, ngauss: 3 }),
            CcxElement::C3D8I | CcxElement::C3D8 => None,
        }
    }
    pub fn kind(self) -> ElementKind {
        match self {
            CcxElement::C3D20R | CcxElement::C3D20 => ElementKind::Hex20,
            CcxElement::C3D8I | CcxElement::C3D8 => ElementKind::Hex8,
        }
    }
}

/// Increment control of every `*STEP` (fractions of the step).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct Increments {
    pub initial: f64,
    pub min: f64,
    pub max: f64,
    /// maximum number of increments per step (`*STEP, INC=`)
    pub max_count: usize,
}

impl Default for Increments {
    fn default() -> Self {
        Increments { initial: 0.1, min: 1e-5, max: 0.5, max_count: 1000 }
    }
}

/// Deck options.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct DeckOptions {
    pub element: CcxElement,
    pub increments: Increments,
    /// apply the cap force p·A_cap (default true; false = pressure on the lateral wall only, as
    /// `scenes.cap_load = false`)
    pub cap_load: bool,
    /// slope of the linear pressure–overclosure law of contact pairs (MPa/mm): 10 gives the
    /// contact pressure of twistopt's barrier (0.1 MPa) at 0.01 mm of overclosure
    pub contact_slope_mpa_per_mm: f64,
    /// contact pairs take the cavity faces within this distance (mm) of a facing wall in the
    /// deepest state twistopt computed ([`compare::vacuum_patches`])
    pub contact_patch_mm: f64,
}

impl Default for DeckOptions {
    fn default() -> Self {
        DeckOptions { element: CcxElement::C3D20R, increments: Increments::default(), cap_load: true, contact_slope_mpa_per_mm: 10.0, contact_patch_mm: 0.3 }
    }
}

/// A deck and what is needed to read its results.
#[derive(Clone, Debug)]
pub struct Deck {
    pub text: String,
    pub scene: SceneKind,
    pub element: CcxElement,
    /// the mesh written to the deck (1-based ids in the deck = index + 1)
    pub mesh: Mesh,
    pub ref_node: usize,
    pub rot_node: usize,
    /// a top node (1-based) used to check the cap rotation
    pub probe_node: usize,
    /// area enclosed by the cavity's top boundary curve of the mesh (mm²); the cap force is p·A
    pub cap_area_mm2: f64,
    /// pressure (kPa) at the end of each step, in step order
    pub step_pressures_kpa: Vec<f64>,
    /// the cavity faces with a node on the cap (indices into the mesh's cavity face set)
    pub cap_faces: Vec<twistopt_solver::mesh::Face>,
}

impl Deck {
    /// Gauss points per direction ccx integrates a distributed load with on this element's faces
    /// (its `mint2d`: 2×2 for C3D20R, C3D8 and C3D8I, 3×3 for C3D20).
    pub fn load_rule(&self) -> usize {
        match self.element {
            CcxElement::C3D20 => 3,
            CcxElement::C3D20R | CcxElement::C3D8 | CcxElement::C3D8I => 2,
        }
    }

    /// The moment about z (N·mm) of the follower pressure's nodal forces on the cap's nodes, with
    /// the nodes at `x` (deformed, mesh order; only the nodes of [`Deck::cap_faces`] are read),
    /// at `p_mpa`. ccx's reaction at the rigid body's rotation node sums the internal forces of
    /// its nodes only; the torque the cap carries also takes the load applied on them, so
    /// τ = (−RF + this) · 1e-3 N·m. Measured on the coarse example at ±1 kPa: this term is the
    /// whole 0.9 % (C3D20R) and 1.1 % (C3D20) by which RF alone differed from twistopt's
    /// reaction, which is the generalised force of the cap's rotation (internal minus external).
    pub fn cap_pressure_moment(&self, x: &dyn Fn(usize) -> [f64; 3], p_mpa: f64) -> f64 {
        let top: std::collections::HashSet<usize> = self.mesh.node_sets.get("top").map(|v| v.iter().copied().collect()).unwrap_or_default();
        let mut m = 0.0;
        for f in &self.cap_faces {
            let nodes = self.mesh.face_nodes(*f);
            let rule = twistopt_solver::shape::FaceRule::new(nodes.len(), self.load_rule());
            let xs: Vec<[f64; 3]> = nodes.iter().map(|&n| x(n)).collect();
            for (q, w) in rule.weights.iter().enumerate() {
                let mut t = [[0.0; 3]; 2];
                for (a, xa) in xs.iter().enumerate() {
                    for d in 0..2 {
                        for c in 0..3 {
                            t[d][c] += xa[c] * rule.dn[q][a][d];
                        }
                    }
                }
                // outward normal of the wall element (into the cavity) times dA
                let nv = twistopt_solver::scalar::cross(t[0], t[1]);
                for (a, &n) in nodes.iter().enumerate() {
                    if top.contains(&n) {
                        // the cavity pressure pushes the wall away from the cavity: −p n dA
                        let fa = [-p_mpa * rule.n[q][a] * nv[0] * w, -p_mpa * rule.n[q][a] * nv[1] * w];
                        m += xs[a][0] * fa[1] - xs[a][1] * fa[0];
                    }
                }
            }
        }
        m
    }
}

/// Names of the node sets the results are printed for.
pub const SET_REF: &str = "REFNODE";
pub const SET_ROT: &str = "ROTNODE";
pub const SET_OUTER: &str = "OUTER";
/// The nodes of the cavity faces that touch the cap: the pressure's nodal forces on the cap's
/// nodes are found from their positions ([`Deck::cap_pressure_moment`]).
pub const SET_CAPFACES: &str = "CAPFACES";
pub const SET_PROBE: &str = "PROBE";

/// The step schedule for the requested pressures: the positive ones in increasing order, then
/// (when there are negative ones) back to 0 and the negative ones in decreasing order.
pub fn step_schedule(pressures_kpa: &[f64]) -> Vec<f64> {
    let mut pos: Vec<f64> = pressures_kpa.iter().copied().filter(|p| *p > 0.0).collect();
    let mut neg: Vec<f64> = pressures_kpa.iter().copied().filter(|p| *p < 0.0).collect();
    pos.sort_by(f64::total_cmp);
    pos.dedup();
    neg.sort_by(|a, b| b.total_cmp(a));
    neg.dedup();
    let mut s = pos.clone();
    if !neg.is_empty() {
        if !pos.is_empty() {
            s.push(0.0);
        }
        s.extend(neg);
    }
    s
}

/// Area enclosed by the top boundary curve of the cavity faces (z = L) of a full mesh.
pub fn cap_area(mesh: &Mesh) -> Result<f64> {
    let faces = mesh.face_sets.get("cavity").ok_or_else(|| anyhow!("the mesh has no 'cavity' face set"))?;
    let cav = Cavity::new(mesh, faces);
    let mut a = 0.0;
    let mut n = 0;
    for e in &cav.edges {
        let x: Vec<[f64; 3]> = e.0.iter().map(|&i| mesh.nodes[i]).collect();
        if x.iter().all(|p| (p[2] - L_TUBE).abs() < 1e-9) {
            a += edge_area(&x);
            n += 1;
        }
    }
    if n == 0 {
        bail!("the cavity has no boundary edges at z = L");
    }
    Ok(a.abs())
}

/// What a deck may add to a scene: contact pairs and a prescribed cap rotation.
#[derive(Clone, Debug, Default)]
pub struct DeckExtras {
    /// frictionless face-to-face penalty contact pairs (faces of the deck's mesh,
    /// [`contact::contact_patches`])
    pub contact: Vec<contact::PatchPair>,
    /// slope of the linear pressure–overclosure law (MPa/mm)
    pub contact_slope_mpa_per_mm: f64,
    /// the cap rotation about z prescribed at the end of each step (degrees, one per step of the
    /// schedule), for a scene whose rotation is free: ccx's `*RIGID BODY` with a free rotation
    /// node converges linearly under vacuum (studies/vacuum § CalculiX under vacuum), so the free
    /// twist is found as the rotation at which ccx's cap torque vanishes
    pub rotation_deg: Option<Vec<f64>>,
}

/// Build the deck of one scene. `mesh_spec` is the problem's mesh (Hex27 in twistopt); the deck
/// always models the full 360° actuator.
pub fn build_deck(geom: &ActuatorGeometry, mesh_spec: &MeshSpec, material: &Material, scene: SceneKind, pressures_kpa: &[f64], opts: &DeckOptions) -> Result<Deck> {
    build_deck_with(geom, mesh_spec, material, scene, pressures_kpa, opts, &DeckExtras::default())
}

/// [`build_deck`] with contact pairs and a prescribed rotation.
pub fn build_deck_with(geom: &ActuatorGeometry, mesh_spec: &MeshSpec, material: &Material, scene: SceneKind, pressures_kpa: &[f64], opts: &DeckOptions, extras: &DeckExtras) -> Result<Deck> {
    let schedule = step_schedule(pressures_kpa);
    if schedule.is_empty() {
        bail!("no non-zero pressure to apply");
    }
    let (mu, kappa) = match material {
        Material::NeoHookean(nh) => {
            if nh.law != twistopt_solver::material::VolumetricLaw::Quadratic {
                bail!("CalculiX NEO HOOKE has U = κ/2 (J − 1)²; the material uses another volumetric law");
            }
            (nh.mu, nh.kappa)
        }
        other => {
            bail!("only the Neo-Hookean material has a CalculiX counterpart here (got {other:?})")
        }
    };
    // the twistopt mesh (Hex27 by default) on the full 360°, then its CalculiX element kind
    let spec = mesh_spec.with_sector(false);
    let am = build_mesh(geom, &spec)?;
    let cap_area_mm2 = cap_area(&am.mesh)?;
    let kind = opts.element.kind();
    let mesh = if am.mesh.kind == kind {
        am.mesh.clone()
    } else if am.mesh.kind.nodes_per_element() > kind.nodes_per_element() {
        am.mesh.to_kind(kind)
    } else {
        bail!("cannot write a {:?} mesh with {} elements", am.mesh.kind, opts.element.name());
    };
    let n = mesh.n_nodes();
    let ref_node = n + 1;
    let rot_node = n + 2;
    // probe: the top node farthest from the axis
    let probe = mesh.node_sets["top"]
        .iter()
        .copied()
        .max_by(|&a, &b| {
            let r = |i: usize| mesh.nodes[i][0].hypot(mesh.nodes[i][1]);
            r(a).total_cmp(&r(b))
        })
        .ok_or_else(|| anyhow!("the mesh has no top nodes"))?;

    let heading = format!(
        "twistopt scene '{}': r = {} mm, l = {} mm, alpha = {} deg, mesh {} ({}), mu = {} MPa, kappa = {} MPa; units mm, N, MPa",
        scene.name(),
        geom.design.r_mm(),
        geom.design.l_mm(),
        geom.design.alpha_deg(),
        mesh_spec.size_string(),
        opts.element.name(),
        mu,
        kappa
    );
    let mut s = inp_string_with_type(&mesh, &heading, Some(opts.element.name()));
    let w = &mut s;
    let _ = writeln!(w, "** cap: rigid body on the top face; reference node (translations) and rotation node on the axis at z = L");
    let _ = writeln!(w, "*NODE, NSET={SET_REF}\n{ref_node}, 0.0, 0.0, {L_TUBE:.12e}");
    let _ = writeln!(w, "*NODE, NSET={SET_ROT}\n{rot_node}, 0.0, 0.0, {L_TUBE:.12e}");
    let _ = writeln!(w, "*NSET, NSET={SET_PROBE}\n{}", probe + 1);
    let top_nodes: std::collections::HashSet<usize> = mesh.node_sets.get("top").map(|v| v.iter().copied().collect()).unwrap_or_default();
    let cap_faces: Vec<twistopt_solver::mesh::Face> =
        mesh.face_sets.get("cavity").map(|fs| fs.iter().copied().filter(|f| mesh.face_nodes(*f).iter().any(|n| top_nodes.contains(n))).collect()).unwrap_or_default();
    let mut cap_face_nodes: Vec<usize> = cap_faces.iter().flat_map(|f| mesh.face_nodes(*f)).collect();
    cap_face_nodes.sort();
    cap_face_nodes.dedup();
    let _ = writeln!(w, "*NSET, NSET={SET_CAPFACES}");
    for c in cap_face_nodes.chunks(16) {
        let _ = writeln!(w, "{}", c.iter().map(|n| (n + 1).to_string()).collect::<Vec<_>>().join(", "));
    }
    // cavity faces grouped by face label (all ζ− = S1 for the structured mesh)
    let faces = &mesh.face_sets["cavity"];
    let mut labels: Vec<&str> = faces.iter().map(|f| f.side.abaqus_label()).collect();
    labels.sort();
    labels.dedup();
    for lab in &labels {
        let _ = writeln!(w, "*ELSET, ELSET=CAVITY_{lab}");
        let ids: Vec<String> = faces.iter().filter(|f| f.side.abaqus_label() == *lab).map(|f| (f.element + 1).to_string()).collect();
        for c in ids.chunks(16) {
            let _ = writeln!(w, "{}", c.join(", "));
        }
    }
    let _ = writeln!(w, "*MATERIAL, NAME=SILICONE");
    let _ = writeln!(w, "** Neo-Hooke: W = C10 (I1bar - 3) + (J - 1)^2 / D1, C10 = mu/2, D1 = 2/kappa");
    let _ = writeln!(w, "*HYPERELASTIC, NEO HOOKE\n{:.12e}, {:.12e}", mu / 2.0, 2.0 / kappa);
    let _ = writeln!(w, "*SOLID SECTION, ELSET=EALL, MATERIAL=SILICONE");
    if !extras.contact.is_empty() {
        let _ = writeln!(w, "** frictionless contact: face-to-face penalty pairs of facing cavity patches (from a deformed state computed by twistopt)");
        let _ = writeln!(w, "*SURFACE INTERACTION, NAME=CAVCONTACT\n*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR\n{:e}", extras.contact_slope_mpa_per_mm);
        for (k, pair) in extras.contact.iter().enumerate() {
            for (name, set) in [("S", &pair.slave), ("M", &pair.master)] {
                let _ = writeln!(w, "*SURFACE, NAME=C{k}{name}, TYPE=ELEMENT");
                for f in set.iter() {
                    let _ = writeln!(w, "{}, {}", f.element + 1, f.side.abaqus_label());
                }
            }
            let _ = writeln!(w, "*CONTACT PAIR, INTERACTION=CAVCONTACT, TYPE=SURFACE TO SURFACE\nC{k}S, C{k}M");
        }
    }
    let _ = writeln!(w, "*RIGID BODY, NSET=TOP, REF NODE={ref_node}, ROT NODE={rot_node}");
    let _ = writeln!(w, "*BOUNDARY\nBOTTOM, 1, 3");
    let _ = writeln!(
        w,
        "** cap: lateral translations and tilts held; axial translation {}, rotation about z {}",
        if scene.axial_free() { "free" } else { "held" },
        if scene.rotation_free() { "free" } else { "held" }
    );
    let _ = writeln!(w, "{ref_node}, 1, 2");
    if !scene.axial_free() {
        let _ = writeln!(w, "{ref_node}, 3, 3");
    }
    let _ = writeln!(w, "{rot_node}, 1, 2");
    if !scene.rotation_free() {
        let _ = writeln!(w, "{rot_node}, 3, 3");
    }
    let inc = &opts.increments;
    if let Some(rot) = &extras.rotation_deg {
        // One step of duration n through the schedule's pressures and rotations at times 1 … n
        // (amplitudes), printed at those times: ccx rejects the first increment of a new step
        // whose rigid-body rotation is prescribed anew (measured: "residual force too large" down
        // to increments of 6e-6 of the step), while one step through the same values converges.
        if rot.len() != schedule.len() {
            bail!("{} prescribed rotations for {} pressures", rot.len(), schedule.len());
        }
        let n = schedule.len() as f64;
        let table = |vals: &[f64]| -> String {
            let mut t = vec![format!("0.0, 0.0")];
            t.extend(vals.iter().enumerate().map(|(k, v)| format!("{}, {:.12e}", k + 1, v)));
            t.join("\n")
        };
        let _ = writeln!(w, "*AMPLITUDE, NAME=APRESS\n{}", table(&schedule.iter().map(|p| p * 1e-3).collect::<Vec<_>>()));
        let _ = writeln!(w, "*AMPLITUDE, NAME=AROT\n{}", table(&rot.iter().map(|r| r.to_radians()).collect::<Vec<_>>()));
        let _ = writeln!(w, "*TIME POINTS, NAME=TSTEPS\n{}", (1..=schedule.len()).map(|k| k.to_string()).collect::<Vec<_>>().join(", "));
        let _ = writeln!(w, "** one step through the pressures {schedule:?} kPa (at times 1 … {n}) with the cap rotation prescribed (the free twist is where the cap torque vanishes)");
        let _ = writeln!(w, "*STEP, NLGEOM, INC={}", inc.max_count * schedule.len());
        let _ = writeln!(w, "*CONTROLS, PARAMETERS=TIME INCREMENTATION\n16, 24, 24, 60, 30, 8, , 16");
        let _ = writeln!(w, "*STATIC\n{:e}, {n:e}, {:e}, {:e}", inc.initial, inc.min, inc.max);
        let _ = writeln!(w, "*BOUNDARY, AMPLITUDE=AROT\n{rot_node}, 3, 3, 1.0");
        let _ = writeln!(w, "*DLOAD, AMPLITUDE=APRESS");
        for lab in &labels {
            let _ = writeln!(w, "CAVITY_{lab}, P{}, 1.0", &lab[1..]);
        }
        if opts.cap_load {
            let _ = writeln!(w, "** cap force p*A_cap, A_cap = {cap_area_mm2:.9} mm^2\n*CLOAD, AMPLITUDE=APRESS\n{ref_node}, 3, {cap_area_mm2:.12e}");
        }
        for (set, what) in [(SET_REF, "U"), (SET_ROT, "U, RF"), (SET_PROBE, "U"), (SET_OUTER, "U"), (SET_CAPFACES, "U")] {
            let _ = writeln!(w, "*NODE PRINT, NSET={set}, TIME POINTS=TSTEPS\n{what}");
        }
        let _ = writeln!(w, "*END STEP");
        return Ok(Deck { text: s, scene, element: opts.element, mesh, ref_node, rot_node, probe_node: probe + 1, cap_area_mm2, step_pressures_kpa: schedule, cap_faces });
    }
    for (k, &p) in schedule.iter().enumerate() {
        let pm = p * 1e-3;
        let _ = writeln!(w, "** step {}: cavity pressure to {p} kPa (linear ramp from the previous step's value)", k + 1);
        let _ = writeln!(w, "*STEP, NLGEOM, INC={}", inc.max_count);
        // ccx's default divergence check (residuals rising twice after iteration 4) cuts the
        // increments of the free-rotation scenes down to ~1e-3: its rigid-body MPC converges
        // linearly, with oscillating moment residuals. Allow more iterations before that check.
        let _ = writeln!(w, "*CONTROLS, PARAMETERS=TIME INCREMENTATION\n16, 24, 24, 60, 30, 8, , 16");
        let _ = writeln!(w, "*STATIC\n{:e}, 1.0, {:e}, {:e}", inc.initial, inc.min, inc.max);
        let _ = writeln!(w, "** follower pressure on the cavity wall (positive = inflation)");
        let _ = writeln!(w, "*DLOAD");
        for lab in &labels {
            let _ = writeln!(w, "CAVITY_{lab}, P{}, {:.12e}", &lab[1..], pm);
        }
        if opts.cap_load {
            let _ = writeln!(w, "** cap force p*A_cap, A_cap = {cap_area_mm2:.9} mm^2");
            let _ = writeln!(w, "*CLOAD\n{ref_node}, 3, {:.12e}", pm * cap_area_mm2);
        } else {
            let _ = writeln!(w, "** no cap force (scenes.cap_load = false: the pressure acts on the lateral wall only)");
        }
        let _ = writeln!(w, "*NODE PRINT, NSET={SET_REF}\nU");
        let _ = writeln!(w, "*NODE PRINT, NSET={SET_ROT}\nU, RF");
        let _ = writeln!(w, "*NODE PRINT, NSET={SET_PROBE}\nU");
        let _ = writeln!(w, "*NODE PRINT, NSET={SET_OUTER}\nU");
        let _ = writeln!(w, "*NODE PRINT, NSET={SET_CAPFACES}\nU");
        let _ = writeln!(w, "*END STEP");
    }
    Ok(Deck { text: s, scene, element: opts.element, mesh, ref_node, rot_node, probe_node: probe + 1, cap_area_mm2, step_pressures_kpa: schedule, cap_faces })
}

/// One state read back from ccx at the end of a step.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CcxState {
    #[serde(rename = "p_kPa")]
    pub p_kpa: f64,
    pub theta_deg: f64,
    /// the cap rotation from the probe node's deformed position (independent of how ccx stores rotations)
    pub theta_probe_deg: f64,
    pub axial_mm: f64,
    /// the torque the actuator exerts on the cap: −RF of the rotation node plus the moment of the
    /// pressure's nodal forces on the cap's nodes ([`Deck::cap_pressure_moment`])
    #[serde(rename = "tau_Nm")]
    pub tau_nm: f64,
    /// −RF of the rotation node alone (the internal forces of the cap's nodes)
    #[serde(rename = "tau_rf_Nm", default)]
    pub tau_rf_nm: f64,
    pub max_radius_mm: f64,
}

/// What a ccx run gave.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CcxRun {
    /// `completed`, `not-converged` (ccx stopped before the last step), `error`
    pub status: String,
    pub cause: String,
    pub states: Vec<CcxState>,
    pub wall_time_s: f64,
    /// number of equations ccx reports (its DOFs after constraints)
    pub equations: Option<usize>,
    /// converged increments
    pub increments: usize,
    /// Newton iterations, cut-back attempts included
    pub iterations: usize,
    pub threads: usize,
    pub inp: PathBuf,
}

/// Locate the ccx executable: `$TWISTOPT_CCX`, else `ccx` on the PATH.
pub fn ccx_command() -> String {
    std::env::var("TWISTOPT_CCX").ok().filter(|s| !s.is_empty()).unwrap_or_else(|| "ccx".to_string())
}

/// Check that ccx runs; returns its version line.
pub fn ccx_version(ccx: &str) -> Result<String> {
    let out = std::process::Command::new(ccx).arg("-v").output().map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            anyhow!("CalculiX '{ccx}' was not found (install it with `apt-get install -y calculix-ccx`, or set TWISTOPT_CCX to its path)")
        } else {
            anyhow!("cannot run CalculiX '{ccx}': {e}")
        }
    })?;
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    Ok(text.lines().map(str::trim).find(|l| l.contains("Version")).unwrap_or("unknown version").to_string())
}

/// Write the deck as `dir/<job>.inp`, run ccx there with `threads` OpenMP threads and read the
/// results. Non-convergence is a status of the run, not an error; a missing ccx is an error.
pub fn run_deck(ccx: &str, deck: &Deck, dir: &Path, job: &str, threads: usize) -> Result<CcxRun> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let inp = dir.join(format!("{job}.inp"));
    std::fs::write(&inp, &deck.text).with_context(|| format!("cannot write {}", inp.display()))?;
    let dat = dir.join(format!("{job}.dat"));
    let _ = std::fs::remove_file(&dat);
    let log_path = dir.join(format!("{job}.log"));
    let log = std::fs::File::create(&log_path).with_context(|| format!("cannot write {}", log_path.display()))?;
    let t0 = Instant::now();
    let status = std::process::Command::new(ccx)
        .arg("-i")
        .arg(job)
        .current_dir(dir)
        .env("OMP_NUM_THREADS", threads.to_string())
        .env("CCX_NPROC_EQUATION_SOLVER", threads.to_string())
        .stdout(log.try_clone()?)
        .stderr(log)
        .status()
        .map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                anyhow!("CalculiX '{ccx}' was not found (install it with `apt-get install -y calculix-ccx`, or set TWISTOPT_CCX to its path)")
            } else {
                anyhow!("cannot run CalculiX '{ccx}': {e}")
            }
        })?;
    let wall = t0.elapsed().as_secs_f64();
    let log_text = std::fs::read_to_string(&log_path).unwrap_or_default();
    let equations = dat::equations(&log_text);
    let increments = dat::increments(&log_text);
    let iterations = dat::iterations(&log_text);
    let dat_text = std::fs::read_to_string(&dat).unwrap_or_default();
    let blocks = dat::parse_dat(&dat_text)?;
    let states = states_at_step_ends(deck, &blocks);
    let error_line = log_text.lines().find(|l| l.contains("*ERROR")).map(|l| l.trim().to_string());
    let (st, cause) = if states.len() == deck.step_pressures_kpa.len() && error_line.is_none() && status.success() {
        ("completed".to_string(), String::new())
    } else {
        let reached = states.last().map(|s| s.p_kpa).unwrap_or(0.0);
        let why = error_line.unwrap_or_else(|| format!("ccx exited with {status}"));
        let st = if states.is_empty() && !log_text.contains("increment") { "error" } else { "not-converged" };
        (st.to_string(), format!("{why} (last requested pressure reached: {reached} kPa; see {})", log_path.display()))
    };
    Ok(CcxRun { status: st, cause, states, wall_time_s: wall, equations, increments, iterations, threads, inp })
}

/// The states at the ends of the steps (exactly the requested pressures), from the printed
/// blocks at total times 1, 2, … .
pub fn states_at_step_ends(deck: &Deck, blocks: &[dat::Block]) -> Vec<CcxState> {
    let mut out = Vec::new();
    for (k, &p) in deck.step_pressures_kpa.iter().enumerate() {
        let t = (k + 1) as f64;
        let find = |what: &str, set: &str| blocks.iter().find(|b| b.what == what && b.set == set && (b.time - t).abs() < 1e-6);
        let (Some(uref), Some(urot), Some(rrot), Some(uprobe), Some(uouter)) =
            (find("displacements", SET_REF), find("displacements", SET_ROT), find("forces", SET_ROT), find("displacements", SET_PROBE), find("displacements", SET_OUTER))
        else {
            break;
        };
        let get = |b: &dat::Block, node: usize| b.values.iter().find(|(n, _)| *n == node).map(|(_, v)| *v);
        let (Some(ur), Some(uo), Some(fo), Some(up)) = (get(uref, deck.ref_node), get(urot, deck.rot_node), get(rrot, deck.rot_node), get(uprobe, deck.probe_node)) else {
            break;
        };
        // the pressure's moment on the cap's nodes, at their deformed positions
        let Some(ucap) = find("displacements", SET_CAPFACES) else {
            break;
        };
        let ucap: std::collections::HashMap<usize, [f64; 3]> = ucap.values.iter().map(|(n, v)| (*n, *v)).collect();
        let xdef = |i: usize| {
            let x0 = deck.mesh.nodes[i];
            let u = ucap.get(&(i + 1)).copied().unwrap_or([0.0; 3]);
            [x0[0] + u[0], x0[1] + u[1], x0[2] + u[2]]
        };
        let m_ext = deck.cap_pressure_moment(&xdef, p * 1e-3);
        let x = deck.mesh.nodes[deck.probe_node - 1];
        let phi0 = x[1].atan2(x[0]);
        let phi1 = (x[1] + up[1]).atan2(x[0] + up[0]);
        let mut dphi = phi1 - phi0;
        while dphi > std::f64::consts::PI {
            dphi -= 2.0 * std::f64::consts::PI;
        }
        while dphi < -std::f64::consts::PI {
            dphi += 2.0 * std::f64::consts::PI;
        }
        let max_radius = uouter
            .values
            .iter()
            .filter(|(n, _)| *n >= 1 && *n <= deck.mesh.n_nodes())
            .map(|(n, u)| {
                let x = deck.mesh.nodes[n - 1];
                (x[0] + u[0]).hypot(x[1] + u[1])
            })
            .fold(0.0, f64::max);
        out.push(CcxState {
            p_kpa: p,
            theta_deg: uo[2].to_degrees(),
            theta_probe_deg: dphi.to_degrees(),
            axial_mm: ur[2],
            // RF is the support's reaction on the cap's internal forces; the actuator's torque on
            // the cap is its negative plus the load applied on the cap's nodes
            tau_nm: (-fo[2] + m_ext) * 1e-3,
            tau_rf_nm: -fo[2] * 1e-3,
            max_radius_mm: max_radius,
        });
    }
    out
}
