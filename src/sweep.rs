//! Grid sweeps: a problem's scenes on every design of a grid (the letter's Table I, a
//! subsample, or custom axes), each ramped to failure or to the ballooning limit, one JSON line
//! per design; resumable, shardable, parallel over designs.
//!
//! * [`Grid`]: named axes (one per design parameter of the [`DesignSpace`]); designs are indexed
//!   in mixed radix with the last axis (α) varying fastest. [`Grid::table1`] is the letter's
//!   Table I grid: r = 5√3 + 0.5k mm (k = 0 … 22) and r = 20, l = 10 … 20 mm step 1,
//!   α = 60 … 360° step 2 — 24 × 11 × 151 = 39 864 designs. An axis `{from, to, step}` holds
//!   from + k·step up to `to`, and `to` itself when the steps do not land on it (that is how the
//!   letter's r axis reaches 20, shown in its Fig. 5).
//! * [`evaluate_design`]: one design → one [`Row`] (never an error: invalid geometry, model
//!   errors and panics are rows with a status).
//! * [`run_sweep`]: runs the designs of one shard that are not yet in `DIR/results.jsonl`
//!   (appends one line per design: a single `write` + flush + fsync; a truncated last line left
//!   by a kill is dropped on resume), then writes `results.csv`, `summary.json` and the maps.
//! * [`merge`]: joins the directories of the shards of one sweep.
//!
//! Maps (the letter's Fig. 5) are in [`maps`]; the optimiser check in [`verify`].

pub mod maps;
pub mod verify;

use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{IsTerminal, Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use crate::evaluate::{common_pressure, interpolate, omega_at_pressure, select_steps};
use crate::geometry::{ActuatorGeometry, Design, DesignSpace, RangePolicy, P_ALPHA, P_L, P_R};
use crate::problem::{apply_override, LoadPlan, Problem, Validated};
use crate::scene::{run_pressure_warm, SceneKind, SceneOptions, SceneResult, SceneStatus, StepRecord, WarmStart};

/// Format tag of manifests and rows.
pub const FORMAT: &str = "twistopt-sweep/1";
/// Rows file in a sweep directory.
pub const RESULTS: &str = "results.jsonl";
/// Manifest file in a sweep directory.
pub const MANIFEST: &str = "manifest.json";

/// The letter's Table I steps by parameter name (bounds come from [`DesignSpace::actuator`]).
pub const TABLE1_STEPS: &[(&str, f64)] = &[(P_R, 0.5), (P_L, 1.0), (P_ALPHA, 2.0)];

/// Relative tolerance of the ballooning test `max radius ≤ limit`. A scene that stops at the
/// ballooning limit has its last state located on the path to `locate_tol` (1e-6 relative in
/// the load), so its radius lands within a few nm of the limit, on either side (measured on the
/// Table-I grid: up to 2.8e-9 mm above). A test at round-off (1e-12) called 5 060 of its 39 864
/// designs infeasible for that; 1e-6 of 28.75 mm is 29 nm.
pub const RADIUS_LIMIT_RTOL: f64 = 1e-6;

/// `radius ≤ limit` to [`RADIUS_LIMIT_RTOL`].
pub fn within_radius_limit(radius_mm: f64, limit_mm: f64) -> bool {
    radius_mm <= limit_mm * (1.0 + RADIUS_LIMIT_RTOL)
}

/// Largest number of designs a grid may have.
const MAX_DESIGNS: u64 = 100_000_000;

// ------------------------------------------------------------------------------------------
// Grid

/// One axis of a grid: a design parameter and its values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Axis {
    pub name: String,
    pub values: Vec<f64>,
}

/// A full-factorial grid over named design parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    /// `table1`, `table1/every=K`, `custom`, `custom/every=K`
    pub name: String,
    /// design box the designs are validated against (`TableI` or `Extended`)
    pub range: RangePolicy,
    pub axes: Vec<Axis>,
}

/// from, from + step, … up to `to` (within round-off), and `to` when the steps miss it.
pub fn stepped_values(name: &str, from: f64, to: f64, step: f64) -> Result<Vec<f64>> {
    if !(from.is_finite() && to.is_finite() && step.is_finite()) {
        bail!("sweep.{name}: from, to and step must be finite numbers (got from = {from}, to = {to}, step = {step})");
    }
    if step <= 0.0 {
        bail!("sweep.{name}: step = {step} must be > 0");
    }
    if to < from {
        bail!("sweep.{name}: to = {to} is below from = {from}");
    }
    let tol = 1e-9 * (1.0 + from.abs().max(to.abs()));
    let n = ((to - from + tol) / step).floor();
    if n > 1e7 {
        bail!("sweep.{name}: {n} steps from {from} to {to} by {step} is too many");
    }
    let mut v: Vec<f64> = (0..=n as u64).map(|k| from + k as f64 * step).collect();
    if let Some(last) = v.last_mut() {
        if (*last - to).abs() <= tol {
            *last = to;
        } else if *last < to {
            v.push(to);
        }
    }
    Ok(v)
}

impl Grid {
    /// The letter's Table I grid (bounds from the design space, steps from [`TABLE1_STEPS`]).
    pub fn table1() -> Grid {
        let space = DesignSpace::actuator();
        let axes = space
            .params
            .iter()
            .map(|p| {
                let step = TABLE1_STEPS.iter().find(|s| s.0 == p.name).map(|s| s.1).expect("every parameter has a Table-I step");
                Axis { name: p.name.clone(), values: stepped_values(&p.name, p.min, p.max, step).expect("Table-I bounds are valid") }
            })
            .collect();
        Grid { name: "table1".into(), range: RangePolicy::TableI, axes }
    }

    /// Every K-th value of each axis (starting with the first).
    pub fn every(&self, k: usize) -> Result<Grid> {
        if k == 0 {
            bail!("grid every=0: K must be a positive integer");
        }
        if k == 1 {
            return Ok(self.clone());
        }
        Ok(Grid {
            name: format!("{}/every={k}", self.name),
            range: self.range,
            axes: self.axes.iter().map(|a| Axis { name: a.name.clone(), values: a.values.iter().copied().step_by(k).collect() }).collect(),
        })
    }

    /// Number of designs.
    pub fn len(&self) -> u64 {
        self.axes.iter().map(|a| a.values.len() as u64).product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// "r_mm 24 × l_mm 11 × alpha_deg 151"
    pub fn shape(&self) -> String {
        self.axes.iter().map(|a| format!("{} {}", a.name, a.values.len())).collect::<Vec<_>>().join(" × ")
    }

    /// The design with this index (last axis fastest).
    pub fn design(&self, index: u64) -> Design {
        let mut rem = index;
        let mut values = BTreeMap::new();
        for a in self.axes.iter().rev() {
            let n = a.values.len() as u64;
            values.insert(a.name.clone(), a.values[(rem % n) as usize]);
            rem /= n;
        }
        Design { values, variant: Default::default() }
    }

    /// Check the axes against the design space: every parameter exactly once, finite values,
    /// no duplicates, not too many designs.
    pub fn check(&self) -> Result<()> {
        let space = DesignSpace::actuator();
        for a in &self.axes {
            if space.get(&a.name).is_none() {
                bail!("sweep.{}: unknown design parameter (known: {})", a.name, space.names().join(", "));
            }
            if a.values.is_empty() {
                bail!("sweep.{}: no values", a.name);
            }
            if let Some(x) = a.values.iter().find(|x| !x.is_finite()) {
                bail!("sweep.{}: value {x} is not a finite number", a.name);
            }
            let mut s = a.values.clone();
            s.sort_by(f64::total_cmp);
            if s.windows(2).any(|w| w[0] == w[1]) {
                bail!("sweep.{}: a value is listed twice", a.name);
            }
        }
        for p in &space.params {
            match self.axes.iter().filter(|a| a.name == p.name).count() {
                0 => bail!("sweep: no axis for design parameter {} (give every one of {}; a fixed value is a one-element list)", p.name, space.names().join(", ")),
                1 => {}
                _ => bail!("sweep.{}: given twice", p.name),
            }
        }
        if self.len() > MAX_DESIGNS {
            bail!("sweep: the grid has {} designs (limit {MAX_DESIGNS})", self.len());
        }
        Ok(())
    }

    /// Parse a `--grid` value: `table1` or `every=K` (Table I subsampled).
    pub fn parse_spec(spec: &str) -> Result<Grid> {
        let s = spec.trim();
        if s == "table1" {
            return Ok(Grid::table1());
        }
        if let Some(k) = s.strip_prefix("every=") {
            let k: usize = k.trim().parse().map_err(|_| anyhow!("--grid '{spec}': K in every=K must be a positive integer"))?;
            return Grid::table1().every(k).map_err(|e| anyhow!("--grid '{spec}': {e}"));
        }
        bail!("--grid '{spec}': expected table1 or every=K (custom axes go in the problem file's [sweep] section)")
    }
}

/// The `[sweep]` section of a problem file.
///
/// ```toml
/// [sweep]
/// # either a named grid …
/// grid = "table1"                            # or "every=K"
/// # … or one axis per design parameter: {from, to, step} or a list
/// r_mm = [8.660254037844386]
/// l_mm = { from = 10, to = 20, step = 5 }
/// alpha_deg = { from = 60, to = 360, step = 60 }
/// every = 1                                  # optional: keep every K-th value of each axis
/// range = "table1"                           # or "extended": the box designs are checked against
/// ```
pub fn grid_from_section(section: &toml::Table) -> Result<Grid> {
    let mut named: Option<Grid> = None;
    let mut axes = Vec::new();
    let mut every = 1usize;
    let mut range = RangePolicy::TableI;
    let space = DesignSpace::actuator();
    for (k, v) in section {
        match k.as_str() {
            "grid" => {
                let s = v.as_str().ok_or_else(|| anyhow!("sweep.grid must be a string (\"table1\" or \"every=K\")"))?;
                named = Some(Grid::parse_spec(s).map_err(|e| anyhow!("sweep.grid: {e}"))?);
            }
            "every" => {
                every = v.as_integer().filter(|k| *k >= 1).ok_or_else(|| anyhow!("sweep.every must be a positive integer"))? as usize;
            }
            "range" => {
                range = match v.as_str() {
                    Some("table1") => RangePolicy::TableI,
                    Some("extended") => RangePolicy::Extended,
                    _ => bail!("sweep.range must be \"table1\" or \"extended\""),
                }
            }
            // (read by SweepConfig::new)
            "warm_start" | "vacuum_kPa" => {}
            name if space.get(name).is_some() => axes.push(Axis { name: name.to_string(), values: axis_values(name, v)? }),
            other => bail!("sweep.{other}: unknown key (expected grid, every, range, warm_start, vacuum_kPa or a design parameter: {})", space.names().join(", ")),
        }
    }
    let grid = match (named, axes.is_empty()) {
        (Some(_), false) => bail!("sweep: give either sweep.grid or axes per parameter, not both"),
        (Some(g), true) => g,
        (None, false) => {
            // keep the design-space order so that α varies fastest
            axes.sort_by_key(|a| space.params.iter().position(|p| p.name == a.name));
            Grid { name: "custom".into(), range, axes }
        }
        (None, true) => bail!("sweep: the [sweep] section has no grid (give grid = \"table1\" or axes such as r_mm = [..])"),
    };
    let mut grid = grid.every(every)?;
    grid.range = range;
    grid.check()?;
    Ok(grid)
}

fn axis_values(name: &str, v: &toml::Value) -> Result<Vec<f64>> {
    let num = |x: &toml::Value, what: &str| -> Result<f64> { x.as_float().or_else(|| x.as_integer().map(|i| i as f64)).ok_or_else(|| anyhow!("sweep.{name}.{what} must be a number")) };
    match v {
        toml::Value::Array(list) => list.iter().map(|x| num(x, "values")).collect(),
        toml::Value::Table(t) => {
            for k in t.keys() {
                if !["from", "to", "step"].contains(&k.as_str()) {
                    bail!("sweep.{name}.{k}: unknown key (expected from, to, step)");
                }
            }
            let get = |k: &str| -> Result<f64> { num(t.get(k).ok_or_else(|| anyhow!("sweep.{name}: missing '{k}' (expected {{from, to, step}})"))?, k) };
            stepped_values(name, get("from")?, get("to")?, get("step")?)
        }
        _ => bail!("sweep.{name} must be a list of values or {{from = .., to = .., step = ..}}"),
    }
}

/// Shard `I/N` (0 ≤ I < N): the designs whose grid index i has ⌊i / block⌋ mod N = I (block 1
/// but with warm starts, where it is a line of the grid's last axis: a line stays in one shard).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub block: u64,
}

fn one() -> u64 {
    1
}

fn is_one(b: &u64) -> bool {
    *b == 1
}

impl Default for Shard {
    fn default() -> Self {
        Shard { index: 0, count: 1, block: 1 }
    }
}

impl Shard {
    pub fn parse(s: &str) -> Result<Shard> {
        let bad = || anyhow!("--shard '{s}': expected I/N with integers 0 <= I < N (e.g. 0/4 … 3/4)");
        let (i, n) = s.trim().split_once('/').ok_or_else(bad)?;
        let (i, n): (u64, u64) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if n == 0 || i >= n {
            return Err(bad());
        }
        Ok(Shard { index: i, count: n, block: 1 })
    }

    pub fn contains(&self, index: u64) -> bool {
        (index / self.block.max(1)) % self.count == self.index
    }

    /// Number of the grid's designs in this shard.
    pub fn size(&self, n: u64) -> u64 {
        let b = self.block.max(1);
        let blocks = n.div_ceil(b);
        let full = if blocks > self.index { (blocks - self.index).div_ceil(self.count) } else { 0 };
        // the last block may be short
        let last = blocks.saturating_sub(1);
        if full > 0 && last % self.count == self.index {
            (full - 1) * b + (n - last * b)
        } else {
            full * b
        }
    }
}

// ------------------------------------------------------------------------------------------
// Sweep configuration and manifest

/// A sweep: the problem (everything but the design), the grid and the shard.
#[derive(Clone, Debug)]
pub struct SweepConfig {
    pub problem: Problem,
    pub grid: Grid,
    pub shard: Shard,
    /// ramp end (kPa): load.p_max_kPa
    pub p_max_kpa: f64,
    /// only these grid indices (sorted, distinct; `--indices`), e.g. a sweep's best designs
    /// re-run at another fidelity; None: the whole grid
    pub indices: Option<Vec<u64>>,
    /// `sweep.warm_start`: each design's positive ramps start from its predecessor's states
    /// along the grid's last axis ([`crate::scene::WarmStart`])
    pub warm_start: bool,
    /// `sweep.vacuum_kPa` = p⁻: each design's scenes are also ramped to −p⁻ (the vacuum side,
    /// [`add_vacuum_side`]); None: the positive side only
    pub vacuum_kpa: Option<f64>,
    /// what the user should know before the run (printed by the CLI)
    pub warnings: Vec<String>,
}

/// Why warm starts are not to be trusted in the pure-twist scenes (measured on the r = 5√3
/// slice: studies/sweep-table1/rom-k80-pure-twist/end-modes-enrichment/slice-warm).
const PURE_TWIST_WARM_WARNING: &str = "sweep.warm_start with the pure-twist scenes: a warm start begins 1 % below where the previous design's path ended and cannot see a pressure maximum the new design has below that; in the pure-twist mode the path then ends at a later maximum (measured: the r = 5√3 slice's 20 best designs 26-140 % too high warm, -9 to +35 % cold against full order). Set sweep.warm_start = false for this mode";

/// The problem file's text → (problem without `[sweep]`, the `[sweep]` table if any), with
/// `--set` overrides applied (they may address `sweep.*` too). A missing `[design]` (or missing
/// r/l/α in it) is filled with a placeholder (the sweep's grid gives the designs); its
/// `variant` and optional parameters (`end_tangent_deg`) apply to every grid design.
pub fn load_problem(path: &Path, overrides: &[String]) -> Result<(Problem, Option<toml::Table>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read problem file {}", path.display()))?;
    problem_from_str(&text, &path.display().to_string(), overrides)
}

/// [`load_problem`] on text (`origin` names it in errors).
pub fn problem_from_str(text: &str, origin: &str, overrides: &[String]) -> Result<(Problem, Option<toml::Table>)> {
    // parse errors are reported by Problem's own parser (with line and column)
    let mut table: toml::Table = match toml::from_str(text) {
        Ok(t) => t,
        Err(_) => {
            Problem::from_str_with(text, origin, &[])?;
            bail!("{origin}: not a valid TOML document")
        }
    };
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    let sweep = match table.remove("sweep") {
        None => None,
        Some(toml::Value::Table(t)) => Some(t),
        Some(_) => bail!("{origin}: sweep must be a section [sweep]"),
    };
    // the grid gives r, l, α: fill them in (a [design] section may still carry the geometry
    // variant and optional parameters such as end_tangent_deg, applied to every grid design)
    let design = table.entry("design").or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = design.as_table_mut() {
        for p in &DesignSpace::actuator().params {
            t.entry(p.name.clone()).or_insert(toml::Value::Float(p.min));
        }
    }
    let merged = toml::to_string(&table).map_err(|e| anyhow!("{origin}: {e}"))?;
    let problem = Problem::from_str_with(&merged, origin, &[])?;
    Ok((problem, sweep))
}

impl SweepConfig {
    /// Check the problem and build the configuration. `grid`: a `--grid` value overriding the
    /// file's `[sweep]` section.
    pub fn new(problem: Problem, section: Option<&toml::Table>, grid: Option<&str>, shard: Shard) -> Result<SweepConfig> {
        let grid = match (grid, section) {
            (Some(g), _) => Grid::parse_spec(g)?,
            (None, Some(s)) => grid_from_section(s)?,
            (None, None) => bail!("no grid: give --grid table1 | every=K, or a [sweep] section in the problem file"),
        };
        grid.check()?;
        let v = problem.validate()?;
        let p_max_kpa = match v.load {
            LoadPlan::Ramp(p) => p,
            LoadPlan::Targets(_) => bail!("load: a sweep ramps each design to failure: give load.p_max_kPa (e.g. --set load.p_max_kPa=150) instead of load.pressures_kPa"),
        };
        let warm_start = match section.and_then(|s| s.get("warm_start")) {
            None => false,
            Some(w) => w.as_bool().ok_or_else(|| anyhow!("sweep.warm_start must be true or false"))?,
        };
        let vacuum_kpa = match section.and_then(|s| s.get("vacuum_kPa")) {
            None => None,
            Some(x) => {
                let pv = x.as_float().or_else(|| x.as_integer().map(|i| i as f64)).ok_or_else(|| anyhow!("sweep.vacuum_kPa must be a number (p⁻ in kPa, > 0)"))?;
                if !(pv.is_finite() && pv > 0.0 && pv <= 100.0) {
                    bail!("sweep.vacuum_kPa = {pv} must be in (0, 100] (the vacuum side is ramped to −p⁻; below −100 kPa is not physical)");
                }
                Some(pv)
            }
        };
        let mut shard = shard;
        if warm_start {
            shard.block = grid.axes.last().map_or(1, |a| a.values.len().max(1)) as u64;
        }
        let mut warnings = Vec::new();
        if warm_start && v.scenes.iter().any(|k| matches!(k, SceneKind::PureTwist | SceneKind::PureTwistBlocked)) {
            warnings.push(PURE_TWIST_WARM_WARNING.to_string());
        }
        if vacuum_kpa.is_some() && problem.scenes.contact.is_none() {
            warnings.push("sweep.vacuum_kPa without scenes.contact: a design's vacuum ramp stops where two cavity walls meet (status self-contact)".to_string());
        }
        Ok(SweepConfig { problem, grid, shard, p_max_kpa, indices: None, warm_start, vacuum_kpa, warnings })
    }

    /// Restrict the sweep to these grid indices (sorted and de-duplicated; each must be below
    /// the grid's size).
    pub fn with_indices(mut self, mut indices: Vec<u64>) -> Result<SweepConfig> {
        if indices.is_empty() {
            bail!("--indices: no grid index given");
        }
        let n = self.grid.len();
        if let Some(i) = indices.iter().find(|i| **i >= n) {
            bail!("--indices: grid index {i} is out of range (grid '{}' has {n} designs, indices 0 … {})", self.grid.name, n - 1);
        }
        indices.sort_unstable();
        indices.dedup();
        self.indices = Some(indices);
        Ok(self)
    }

    /// Whether grid index `i` is in this sweep's selection (all when no `--indices`).
    pub fn selected(&self, i: u64) -> bool {
        self.indices.as_ref().is_none_or(|s| s.binary_search(&i).is_ok())
    }

    /// Number of designs this run covers: the shard's designs, within the selection.
    pub fn size(&self) -> u64 {
        match &self.indices {
            None => self.shard.size(self.grid.len()),
            Some(s) => s.iter().filter(|i| self.shard.contains(**i)).count() as u64,
        }
    }

    /// The effective problem as JSON without the design (and without output switches); a
    /// non-spec geometry variant or an optional design parameter is kept as `geometry`.
    pub fn problem_json(&self) -> Value {
        let mut p = serde_json::to_value(&self.problem).unwrap_or(Value::Null);
        if let Some(o) = p.as_object_mut() {
            o.remove("design");
            o.remove("output");
            let d = &self.problem.design;
            if !d.variant.is_spec() || d.end_tangent_deg.is_some() {
                let mut g = serde_json::Map::new();
                g.insert("variant".into(), json!(d.variant.name()));
                if let Some(e) = d.end_tangent_deg {
                    g.insert("end_tangent_deg".into(), json!(e));
                }
                o.insert("geometry".into(), Value::Object(g));
            }
        }
        p
    }

    /// Design `index` of the grid with the problem's geometry variant and optional parameters.
    pub fn design(&self, index: u64) -> Design {
        let d = self.grid.design(index).with_variant(self.problem.design.variant);
        match self.problem.design.end_tangent_deg {
            Some(g) => d.with_end_tangent(g),
            None => d,
        }
    }

    /// Mesh size and element kind.
    pub fn fidelity(&self) -> Result<String> {
        let v = self.problem.validate()?;
        Ok(match (&v.rom, &self.problem.fidelity.rom) {
            (Some((rom, m)), Some(dir)) => {
                // (element samples keep the string earlier sweeps recorded)
                let sample = if rom.sample.is_points() { rom.sample.describe(m.report.elements) } else { format!("{} elements", rom.sample.elements.len()) };
                format!("{} {:?} rom:{dir} ({} modes, {} pressure modes, {})", v.mesh.size_string(), v.mesh.kind, rom.basis.k, rom.basis.pressure.as_ref().map_or(0, |p| p.kp), sample)
            }
            _ => format!("{} {:?}", v.mesh.size_string(), v.mesh.kind),
        })
    }

    pub fn manifest(&self) -> Result<Manifest> {
        let problem = self.problem_json();
        let fidelity = self.fidelity()?;
        let mut key = match &self.indices {
            // (a sweep of the whole grid keeps the hash earlier versions wrote)
            None => json!({"grid": self.grid, "problem": problem, "fidelity": fidelity}),
            Some(s) => json!({"grid": self.grid, "problem": problem, "fidelity": fidelity, "indices": s}),
        };
        if let Some(pv) = self.vacuum_kpa {
            key["vacuum_kPa"] = json!(pv);
        }
        let key = serde_json::to_string(&key)?;
        let mut h = fnv::FnvHasher::default();
        std::hash::Hasher::write(&mut h, key.as_bytes());
        Ok(Manifest {
            format: FORMAT.into(),
            n_designs: self.grid.len(),
            n_designs_shard: self.size(),
            grid: self.grid.clone(),
            indices: self.indices.clone(),
            fidelity,
            problem,
            sweep_hash: format!("{:016x}", std::hash::Hasher::finish(&h)),
            shard: self.shard,
            warm_start: self.warm_start,
            vacuum_kpa: self.vacuum_kpa,
        })
    }
}

/// `DIR/manifest.json`: what a sweep directory holds. A directory is only resumed by the same
/// grid, problem, fidelity and shard.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub grid: Grid,
    pub n_designs: u64,
    pub fidelity: String,
    /// effective problem without design and output switches
    pub problem: Value,
    /// FNV-1a 64 of grid + problem + fidelity (the same for every shard of one sweep)
    pub sweep_hash: String,
    pub shard: Shard,
    /// designs of this directory (its shard within `indices`)
    pub n_designs_shard: u64,
    /// the grid indices selected by `--indices` (absent: the whole grid)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub indices: Option<Vec<u64>>,
    /// `sweep.warm_start` (results agree with cold ramps to the path follower's tolerances: an
    /// unsharded sweep may be resumed with either; shards differ, see [`Shard`])
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub warm_start: bool,
    /// `sweep.vacuum_kPa`: the vacuum side's p⁻ (absent: positive side only)
    #[serde(default, rename = "vacuum_kPa", skip_serializing_if = "Option::is_none")]
    pub vacuum_kpa: Option<f64>,
}

impl Manifest {
    pub fn read(dir: &Path) -> Result<Option<Manifest>> {
        let p = dir.join(MANIFEST);
        if !p.exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
        let m: Manifest = serde_json::from_str(&text).map_err(|e| anyhow!("{}: not a sweep manifest ({e})", p.display()))?;
        Ok(Some(m))
    }

    /// The ballooning limit the sweep ran with (`scenes.ballooning_limit_mm`).
    pub fn ballooning_limit_mm(&self) -> Option<f64> {
        self.problem.get("scenes").and_then(|s| s.get("ballooning_limit_mm")).and_then(Value::as_f64).filter(|x| x.is_finite())
    }

    /// Write atomically (temporary file + rename).
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_atomic(&dir.join(MANIFEST), &(serde_json::to_string_pretty(self)? + "\n"))
    }

    /// Why `other` may not be resumed into a directory holding `self`; None when compatible.
    pub fn mismatch(&self, other: &Manifest) -> Option<String> {
        let mut why = Vec::new();
        if self.format != other.format {
            why.push(format!("format {} vs {}", self.format, other.format));
        }
        if self.grid != other.grid {
            why.push(format!("grid '{}' ({} designs) vs '{}' ({} designs)", self.grid.name, self.grid.len(), other.grid.name, other.grid.len()));
        }
        if self.fidelity != other.fidelity {
            why.push(format!("fidelity {} vs {}", self.fidelity, other.fidelity));
        }
        if self.problem != other.problem {
            let keys: Vec<String> = match (self.problem.as_object(), other.problem.as_object()) {
                (Some(a), Some(b)) => a.keys().chain(b.keys()).filter(|k| a.get(*k) != b.get(*k)).cloned().collect::<BTreeSet<_>>().into_iter().collect(),
                _ => vec!["problem".into()],
            };
            why.push(format!("problem sections differ: {}", keys.join(", ")));
        }
        if self.shard != other.shard {
            why.push(format!("shard {}/{} vs {}/{}", self.shard.index, self.shard.count, other.shard.index, other.shard.count));
        }
        if self.vacuum_kpa != other.vacuum_kpa {
            let d = |v: Option<f64>| v.map_or("none".to_string(), |p| format!("{p} kPa"));
            why.push(format!("sweep.vacuum_kPa {} vs {}", d(self.vacuum_kpa), d(other.vacuum_kpa)));
        }
        if self.indices != other.indices {
            let d = |s: &Option<Vec<u64>>| s.as_ref().map_or("the whole grid".to_string(), |s| format!("{} selected indices", s.len()));
            why.push(format!("--indices: {} vs {}", d(&self.indices), d(&other.indices)));
        }
        (!why.is_empty()).then(|| why.join("; "))
    }
}

/// Write a file atomically (a temporary file renamed over it), so that a reader never sees half of it.
pub fn write_atomic(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).with_context(|| format!("cannot write {}", tmp.display()))?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}

// ------------------------------------------------------------------------------------------
// Rows

/// Per-scene outcome in a row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneSummary {
    pub status: SceneStatus,
    pub cause: String,
    /// highest converged pressure (kPa)
    #[serde(rename = "p_reached_kPa")]
    pub p_reached_kpa: Option<f64>,
    pub steps: usize,
    pub dofs: usize,
    pub newton_iterations: usize,
    /// the path follower's work counts (steps, failed attempts, event location)
    #[serde(default)]
    pub path: twistopt_solver::continuation::PathStats,
    pub wall_time_s: f64,
    /// at `rom` fidelity: the reduced model's error indicator (see `SceneResult::rom_indicator`)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom_indicator: Option<f64>,
    /// at `rom` fidelity: why the scene was run again on the full model (see
    /// `SceneOptions::rom_fallback`); absent when the reduced result was kept
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rom_fallback: Option<String>,
    /// with `sweep.warm_start`: the pressure at which the positive ramp started from the
    /// previous design's state (absent: from the unloaded state)
    #[serde(default, rename = "warm_start_kPa", skip_serializing_if = "Option::is_none")]
    pub warm_start_kpa: Option<f64>,
}

/// The outputs of one mode (free + blocked, or pure-twist + pure-twist-blocked) of a design.
/// Absent values are `null` (never NaN).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModeSummary {
    /// θ (signed, about +z) at the step of largest |θ| of the free-like scene, and its pressure
    pub theta_max_deg: Option<f64>,
    #[serde(rename = "p_theta_max_kPa")]
    pub p_theta_max_kpa: Option<f64>,
    /// τ (signed) at the step of largest |τ| of the blocked-like scene, and its pressure
    #[serde(rename = "tau_max_Nm")]
    pub tau_max_nm: Option<f64>,
    #[serde(rename = "p_tau_max_kPa")]
    pub p_tau_max_kpa: Option<f64>,
    /// Ω by the letter's rule (common pressure = lower of the two scenes' highest converged
    /// pressures), with θ, τ and that pressure
    #[serde(rename = "omega_J_m3")]
    pub omega_j_m3: Option<f64>,
    #[serde(rename = "p_omega_kPa")]
    pub p_omega_kpa: Option<f64>,
    pub theta_omega_deg: Option<f64>,
    #[serde(rename = "tau_omega_Nm")]
    pub tau_omega_nm: Option<f64>,
    /// Ω at the ballooning-limited pressure: the common pressure, lowered to where either
    /// scene's max radius reaches the ballooning limit (interpolated)
    #[serde(rename = "omega_balloon_J_m3")]
    pub omega_balloon_j_m3: Option<f64>,
    #[serde(rename = "p_balloon_kPa")]
    pub p_balloon_kpa: Option<f64>,
    /// max deformed radius of the two scenes at the Ω pressure (interpolated)
    pub max_radius_mm: Option<f64>,
    /// max deformed radius over every converged step of the two scenes
    pub max_radius_reached_mm: Option<f64>,
    /// Ω available and max radius at its pressure ≤ the ballooning limit
    pub feasible: bool,
}

impl ModeSummary {
    /// Ω available and the max radius at its pressure within the ballooning limit
    /// ([`within_radius_limit`]).
    pub fn is_feasible(&self, limit_mm: f64) -> bool {
        self.omega_j_m3.is_some() && self.max_radius_mm.is_some_and(|r| within_radius_limit(r, limit_mm))
    }
}

/// One design's result: one line of `results.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// `<index>:<name=value,…>` (index in the full grid; values in shortest round-trip form)
    pub id: String,
    pub index: u64,
    pub design: BTreeMap<String, f64>,
    /// `ok`, `no-common-pressure`, `invalid-geometry`, `model-error` or `error`
    pub status: String,
    pub cause: String,
    /// `combined` (free + blocked) or `pure-twist`: the mode of the top-level values
    pub mode: Option<String>,
    #[serde(flatten)]
    pub primary: ModeSummary,
    /// every mode that ran (including the primary one)
    pub modes: BTreeMap<String, ModeSummary>,
    pub scenes: BTreeMap<String, SceneSummary>,
    #[serde(rename = "p_max_kPa")]
    pub p_max_kpa: f64,
    pub wall_time_s: f64,
    /// with `sweep.vacuum_kPa`: the scenes ramped to −p⁻ ([`add_vacuum_side`])
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vacuum: Option<VacuumSummary>,
}

/// The vacuum side of a design: every scene ramped from 0 to −p⁻ (on the full model; with
/// `scenes.contact` through the wall's collapse).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VacuumSummary {
    /// −p⁻ (kPa)
    #[serde(rename = "p_target_kPa")]
    pub p_target_kpa: f64,
    /// per mode: θ and τ at each scene's most negative converged pressure, and Ω at the common
    /// (less negative) one by the letter's rule
    pub modes: BTreeMap<String, VacuumMode>,
    pub scenes: BTreeMap<String, VacuumScene>,
    pub wall_time_s: f64,
}

/// One mode's vacuum-side values. Absent values are `null`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VacuumMode {
    pub theta_deg: Option<f64>,
    #[serde(rename = "p_theta_kPa")]
    pub p_theta_kpa: Option<f64>,
    #[serde(rename = "tau_Nm")]
    pub tau_nm: Option<f64>,
    #[serde(rename = "p_tau_kPa")]
    pub p_tau_kpa: Option<f64>,
    #[serde(rename = "omega_J_m3")]
    pub omega_j_m3: Option<f64>,
    #[serde(rename = "p_omega_kPa")]
    pub p_omega_kpa: Option<f64>,
    pub theta_omega_deg: Option<f64>,
    #[serde(rename = "tau_omega_Nm")]
    pub tau_omega_nm: Option<f64>,
}

/// One scene's vacuum ramp.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VacuumScene {
    /// `completed` when −p⁻ was reached, else what ended the ramp
    pub status: SceneStatus,
    pub cause: String,
    /// most negative converged pressure (kPa)
    #[serde(rename = "p_reached_kPa")]
    pub p_reached_kpa: Option<f64>,
    pub steps: usize,
    pub newton_iterations: usize,
    /// where the path snapped through a lost stability (contact only)
    #[serde(rename = "snaps_kPa", default, skip_serializing_if = "Vec::is_empty")]
    pub snaps_kpa: Vec<f64>,
    /// the closest approach of two cavity walls over the ramp (contact only)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_contact_distance_mm: Option<f64>,
    pub wall_time_s: f64,
}

impl VacuumScene {
    /// A scene that could not be built or run (no steps).
    fn model_error(cause: String) -> Self {
        VacuumScene { status: SceneStatus::ModelError, cause, p_reached_kpa: None, steps: 0, newton_iterations: 0, snaps_kpa: vec![], min_contact_distance_mm: None, wall_time_s: 0.0 }
    }
}

/// Ramp each of the row's scenes from 0 to −p⁻ and record the vacuum side in `row.vacuum` (and
/// its time in `row.wall_time_s`). The reduced models cover positive pressures only: the vacuum
/// side runs on the full model of the same mesh. Never fails: a panic or a model error is the
/// scene's status.
pub fn add_vacuum_side(row: &mut Row, design: &Design, range: RangePolicy, v: &Validated, opts: &SceneOptions, p_vacuum_kpa: f64) {
    let t0 = Instant::now();
    let mut vs = VacuumSummary { p_target_kpa: -p_vacuum_kpa, modes: BTreeMap::new(), scenes: BTreeMap::new(), wall_time_s: 0.0 };
    let geom = match ActuatorGeometry::new(design, range) {
        Ok(g) => g,
        Err(_) => return, // (the row already says invalid-geometry)
    };
    let mut vopts = opts.clone();
    vopts.rom = None;
    let plan = LoadPlan::Targets(vec![-p_vacuum_kpa]);
    let mut results: Vec<SceneResult> = Vec::new();
    for &kind in &v.scenes {
        let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| crate::scene::run_pressure(&geom, &vopts, kind, &plan.targets())));
        match run {
            Ok(Ok(mut r)) => {
                select_steps(&mut r, &plan);
                results.push(r);
            }
            Ok(Err(e)) => {
                vs.scenes.insert(kind.name().into(), VacuumScene::model_error(e.to_string().replace('\n', " ")));
            }
            Err(_) => {
                vs.scenes.insert(kind.name().into(), VacuumScene::model_error("the vacuum ramp panicked".into()));
            }
        }
    }
    // Ω's common pressure as an exact step of both scenes of each pair
    for (_, fk, bk) in MODES {
        let (fi, bi) = (results.iter().position(|r| r.scene == fk.name()), results.iter().position(|r| r.scene == bk.name()));
        if let (Some(fi), Some(bi)) = (fi, bi) {
            let (a, b) = if fi < bi {
                let (l, r) = results.split_at_mut(bi);
                (&mut l[fi], &mut r[0])
            } else {
                let (l, r) = results.split_at_mut(fi);
                (&mut r[0], &mut l[bi])
            };
            crate::evaluate::complete_pair(&geom, &vopts, a, b);
        }
    }
    fn most_negative(steps: &[StepRecord]) -> Option<&StepRecord> {
        steps.iter().filter(|s| s.p_kpa < 0.0 && s.p_kpa.is_finite()).min_by(|a, b| a.p_kpa.total_cmp(&b.p_kpa))
    }
    for r in &results {
        vs.scenes.insert(
            r.scene.clone(),
            VacuumScene {
                status: r.status,
                cause: r.cause.replace('\n', " "),
                p_reached_kpa: most_negative(&r.steps).map(|s| s.p_kpa),
                steps: r.steps.len(),
                newton_iterations: r.newton_iterations,
                snaps_kpa: r.snaps_kpa.clone(),
                min_contact_distance_mm: r.min_contact_distance_mm,
                wall_time_s: r.wall_time_s,
            },
        );
    }
    let find = |k: SceneKind| results.iter().find(|r| r.scene == k.name());
    for (name, fk, bk) in MODES {
        if !(v.scenes.contains(&fk) || v.scenes.contains(&bk)) {
            continue;
        }
        let mut m = VacuumMode::default();
        if let Some(s) = find(fk).and_then(|f| most_negative(&f.steps)) {
            m.theta_deg = fin(s.theta_deg);
            m.p_theta_kpa = fin(s.p_kpa);
        }
        if let Some(s) = find(bk).and_then(|b| most_negative(&b.steps)) {
            m.tau_nm = fin(s.tau_nm);
            m.p_tau_kpa = fin(s.p_kpa);
        }
        if let (Some(f), Some(b)) = (find(fk), find(bk)) {
            if let Some(o) = common_pressure(&f.steps, &b.steps, false).and_then(|(pc, _, _)| omega_at_pressure(&f.steps, &b.steps, pc)) {
                m.omega_j_m3 = fin(o.omega_j_m3);
                m.p_omega_kpa = fin(o.p_kpa);
                m.theta_omega_deg = fin(o.theta_deg);
                m.tau_omega_nm = fin(o.tau_nm);
            }
        }
        vs.modes.insert(name.to_string(), m);
    }
    vs.wall_time_s = t0.elapsed().as_secs_f64();
    row.wall_time_s += vs.wall_time_s;
    row.vacuum = Some(vs);
}

/// The row id of a design.
pub fn design_id(index: u64, design: &Design) -> String {
    let canon: Vec<String> = design.values.iter().map(|(k, v)| format!("{k}={v}")).collect();
    format!("{index}:{}", canon.join(","))
}

fn fin(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Highest converged positive pressure of a scene.
fn p_reached(steps: &[StepRecord]) -> Option<f64> {
    steps.iter().map(|s| s.p_kpa).filter(|p| *p > 0.0 && p.is_finite()).fold(None, |a: Option<f64>, p| Some(a.map_or(p, |a| a.max(p))))
}

/// The step with the largest |value| on the positive branch.
fn max_abs(steps: &[StepRecord], value: impl Fn(&StepRecord) -> f64) -> Option<(f64, f64)> {
    steps.iter().filter(|s| s.p_kpa > 0.0 && value(s).is_finite()).max_by(|a, b| value(a).abs().total_cmp(&value(b).abs())).map(|s| (value(s), s.p_kpa))
}

/// Pressure where the max radius first reaches `limit` on the positive branch (interpolated),
/// or the highest converged pressure when it never does.
fn p_radius_limit(steps: &[StepRecord], limit: f64) -> Option<f64> {
    let mut s: Vec<&StepRecord> = steps.iter().filter(|s| s.p_kpa >= 0.0).collect();
    s.sort_by(|a, b| a.p_kpa.total_cmp(&b.p_kpa));
    for w in s.windows(2) {
        if w[1].max_radius_mm > limit {
            let (r0, r1) = (w[0].max_radius_mm, w[1].max_radius_mm);
            let t = if r1 > r0 { ((limit - r0) / (r1 - r0)).clamp(0.0, 1.0) } else { 0.0 };
            return Some(w[0].p_kpa + t * (w[1].p_kpa - w[0].p_kpa));
        }
    }
    p_reached(steps)
}

/// The summary of one mode from its free-like and blocked-like scenes (either may be missing).
pub fn mode_summary(free: Option<&SceneResult>, blocked: Option<&SceneResult>, limit_mm: f64) -> ModeSummary {
    let mut m = ModeSummary::default();
    if let Some((th, p)) = free.and_then(|f| max_abs(&f.steps, |s| s.theta_deg)) {
        m.theta_max_deg = Some(th);
        m.p_theta_max_kpa = Some(p);
    }
    if let Some((tau, p)) = blocked.and_then(|b| max_abs(&b.steps, |s| s.tau_nm)) {
        m.tau_max_nm = Some(tau);
        m.p_tau_max_kpa = Some(p);
    }
    let all: Vec<&StepRecord> = free.iter().chain(blocked.iter()).flat_map(|r| r.steps.iter()).collect();
    m.max_radius_reached_mm = all.iter().map(|s| s.max_radius_mm).filter(|x| x.is_finite()).fold(None, |a: Option<f64>, x| Some(a.map_or(x, |a| a.max(x))));
    let (Some(f), Some(b)) = (free, blocked) else {
        return m;
    };
    if let Some((pc, _, _)) = common_pressure(&f.steps, &b.steps, true) {
        if let Some(o) = omega_at_pressure(&f.steps, &b.steps, pc) {
            m.omega_j_m3 = fin(o.omega_j_m3);
            m.p_omega_kpa = fin(o.p_kpa);
            m.theta_omega_deg = fin(o.theta_deg);
            m.tau_omega_nm = fin(o.tau_nm);
            let radius = |r: &SceneResult| interpolate(&r.steps, pc, |s| s.max_radius_mm);
            m.max_radius_mm = match (radius(f), radius(b)) {
                (Some(a), Some(c)) => fin(a.max(c)),
                _ => None,
            };
            m.feasible = m.is_feasible(limit_mm);
        }
        let pb = [Some(pc), p_radius_limit(&f.steps, limit_mm), p_radius_limit(&b.steps, limit_mm)].into_iter().flatten().fold(f64::INFINITY, f64::min);
        if pb.is_finite() && pb > 0.0 {
            if let Some(o) = omega_at_pressure(&f.steps, &b.steps, pb) {
                m.omega_balloon_j_m3 = fin(o.omega_j_m3);
                m.p_balloon_kpa = fin(pb);
            }
        }
    }
    m
}

/// The two modes: (name, free-like scene, blocked-like scene).
const MODES: [(&str, SceneKind, SceneKind); 2] = [("combined", SceneKind::Free, SceneKind::Blocked), ("pure-twist", SceneKind::PureTwist, SceneKind::PureTwistBlocked)];

fn scene_summary(r: &SceneResult) -> SceneSummary {
    SceneSummary {
        status: r.status,
        cause: r.cause.replace('\n', " "),
        p_reached_kpa: p_reached(&r.steps),
        steps: r.steps.len(),
        dofs: r.dofs,
        newton_iterations: r.newton_iterations,
        path: r.path.clone(),
        wall_time_s: r.wall_time_s,
        rom_indicator: r.rom_indicator,
        rom_fallback: r.rom_fallback.clone(),
        warm_start_kpa: r.warm_start_kpa,
    }
}

fn empty_row(index: u64, design: &Design, p_max: f64) -> Row {
    Row {
        id: design_id(index, design),
        index,
        design: design.values.clone(),
        status: String::new(),
        cause: String::new(),
        mode: None,
        primary: ModeSummary::default(),
        modes: BTreeMap::new(),
        scenes: BTreeMap::new(),
        p_max_kpa: p_max,
        wall_time_s: 0.0,
        vacuum: None,
    }
}

/// Run one design's scenes (one after the other) ramped to `p_max` (or to the ballooning limit
/// or failure) and summarise them. Never fails: problems are the row's status.
pub fn evaluate_design(index: u64, design: &Design, range: RangePolicy, v: &Validated, opts: &SceneOptions, p_max: f64) -> Row {
    evaluate_design_warm(index, design, range, v, opts, p_max, None).0
}

/// Warm starts for a design's scenes (scene name → state), from a neighbouring design.
pub type DesignWarm = BTreeMap<String, WarmStart>;

/// [`evaluate_design`], each scene's positive ramp started from `warm` where it applies
/// ([`crate::scene::WarmStart`]); also returns the warm starts this design offers its neighbour.
pub fn evaluate_design_warm(index: u64, design: &Design, range: RangePolicy, v: &Validated, opts: &SceneOptions, p_max: f64, warm: Option<&DesignWarm>) -> (Row, DesignWarm) {
    let t0 = Instant::now();
    let mut row = empty_row(index, design, p_max);
    let geom = match ActuatorGeometry::new(design, range) {
        Ok(g) => g,
        Err(e) => {
            row.status = "invalid-geometry".into();
            row.cause = e.to_string().replace('\n', " ");
            row.wall_time_s = t0.elapsed().as_secs_f64();
            return (row, DesignWarm::new());
        }
    };
    let plan = LoadPlan::Ramp(p_max);
    let mut results: Vec<SceneResult> = Vec::new();
    let mut errors = Vec::new();
    for &kind in &v.scenes {
        // the partner scene of an Ω pair that already ran stopped at its failure pressure: give
        // this one a point there (the letter's Ω is taken at the lower failure pressure)
        let mut targets = plan.targets();
        for (_, fk, bk) in MODES {
            let partner = if kind == bk {
                fk
            } else if kind == fk {
                bk
            } else {
                continue;
            };
            if let Some(p) = results.iter().find(|r| r.scene == partner.name()).filter(|r| r.status != SceneStatus::Completed).and_then(|r| p_reached(&r.steps)) {
                targets.push(p);
            }
        }
        match run_pressure_warm(&geom, opts, kind, &targets, warm.and_then(|w| w.get(kind.name()))) {
            Ok(mut r) => {
                select_steps(&mut r, &plan);
                results.push(r);
            }
            Err(e) => errors.push(format!("{}: {}", kind.name(), e.to_string().replace('\n', " "))),
        }
    }
    // Ω's common pressure as an exact step of both scenes of each pair
    for (_, fk, bk) in MODES {
        let (fi, bi) = (results.iter().position(|r| r.scene == fk.name()), results.iter().position(|r| r.scene == bk.name()));
        if let (Some(fi), Some(bi)) = (fi, bi) {
            let (a, b) = if fi < bi {
                let (l, r) = results.split_at_mut(bi);
                (&mut l[fi], &mut r[0])
            } else {
                let (l, r) = results.split_at_mut(fi);
                (&mut r[0], &mut l[bi])
            };
            crate::evaluate::complete_pair(&geom, opts, a, b);
        }
    }
    row.scenes = results.iter().map(|r| (r.scene.clone(), scene_summary(r))).collect();
    let find = |k: SceneKind| results.iter().find(|r| r.scene == k.name());
    for (name, fk, bk) in MODES {
        if v.scenes.contains(&fk) || v.scenes.contains(&bk) {
            row.modes.insert(name.to_string(), mode_summary(find(fk), find(bk), opts.ballooning_limit_mm));
            if row.mode.is_none() {
                row.mode = Some(name.to_string());
            }
        }
    }
    if let Some(m) = row.mode.as_ref().and_then(|m| row.modes.get(m)) {
        row.primary = m.clone();
    }
    let ends: Vec<String> = results.iter().filter(|r| r.status != SceneStatus::Completed).map(|r| format!("{}: {} ({})", r.scene, r.status, r.cause.replace('\n', " "))).collect();
    if !errors.is_empty() {
        row.status = "model-error".into();
        row.cause = errors.into_iter().chain(ends).collect::<Vec<_>>().join("; ");
    } else {
        let pair = row.mode.as_ref().and_then(|m| MODES.iter().find(|x| x.0 == m)).is_some_and(|(_, f, b)| v.scenes.contains(f) && v.scenes.contains(b));
        row.status = if pair && row.primary.omega_j_m3.is_none() { "no-common-pressure".into() } else { "ok".into() };
        row.cause = if ends.is_empty() { format!("all scenes reached p_max = {p_max} kPa") } else { ends.join("; ") };
    }
    // the branches offered to the next design (reduced results only where the model is)
    let offer: DesignWarm = results.iter().filter(|r| r.rom_fallback.is_none()).filter_map(|r| Some((r.scene.clone(), WarmStart::of(r)?))).collect();
    row.wall_time_s = t0.elapsed().as_secs_f64();
    (row, offer)
}

/// [`evaluate_design`] with panics turned into rows with status `error`.
pub fn evaluate_design_guarded(index: u64, design: &Design, range: RangePolicy, v: &Validated, opts: &SceneOptions, p_max: f64) -> Row {
    evaluate_design_guarded_warm(index, design, range, v, opts, p_max, None).0
}

/// [`evaluate_design_warm`] with panics turned into rows with status `error` (offering no warm
/// start).
pub fn evaluate_design_guarded_warm(index: u64, design: &Design, range: RangePolicy, v: &Validated, opts: &SceneOptions, p_max: f64, warm: Option<&DesignWarm>) -> (Row, DesignWarm) {
    let t0 = Instant::now();
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| evaluate_design_warm(index, design, range, v, opts, p_max, warm))) {
        Ok(r) => r,
        Err(e) => {
            let msg = e.downcast_ref::<String>().cloned().or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string())).unwrap_or_else(|| "unknown panic".into());
            let mut row = empty_row(index, design, p_max);
            row.status = "error".into();
            row.cause = format!("the evaluation panicked: {}", msg.replace('\n', " "));
            row.wall_time_s = t0.elapsed().as_secs_f64();
            (row, DesignWarm::new())
        }
    }
}

// ------------------------------------------------------------------------------------------
// Rows file

/// Rows read from a results file.
pub struct RowsRead {
    pub rows: Vec<Row>,
    /// bytes up to the end of the last complete line (what follows is a torn tail)
    pub valid_len: u64,
    /// the file ends with a complete row whose newline is missing (a write cut just before it)
    pub missing_newline: bool,
    /// lines dropped (torn tail, unparseable, duplicate id)
    pub dropped: usize,
}

/// Read `results.jsonl`. A last line without its newline (a write cut by a kill) is dropped
/// unless it is a complete row; unparseable lines and repeated ids (the first occurrence is
/// kept) are skipped.
impl Row {
    /// Recompute `feasible` (primary mode and every mode) from the stored Ω and max radius, so
    /// that rows written before a change of the rule ([`RADIUS_LIMIT_RTOL`]) are judged by the
    /// current one.
    pub fn refresh_feasibility(&mut self, limit_mm: f64) {
        self.primary.feasible = self.primary.is_feasible(limit_mm);
        for m in self.modes.values_mut() {
            m.feasible = m.is_feasible(limit_mm);
        }
    }
}

/// [`Row::refresh_feasibility`] on every row, with the manifest's ballooning limit.
pub fn refresh_feasibility(rows: &mut [Row], manifest: &Manifest) {
    if let Some(limit) = manifest.ballooning_limit_mm() {
        for r in rows {
            r.refresh_feasibility(limit);
        }
    }
}

pub fn read_rows(path: &Path) -> Result<RowsRead> {
    let mut bytes = Vec::new();
    match std::fs::File::open(path) {
        Ok(mut f) => {
            f.read_to_end(&mut bytes).with_context(|| format!("cannot read {}", path.display()))?;
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(RowsRead { rows: vec![], valid_len: 0, missing_newline: false, dropped: 0 }),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    }
    let complete = bytes.iter().rposition(|&b| b == b'\n').map(|p| p + 1).unwrap_or(0);
    let mut rows = Vec::new();
    let mut seen = BTreeSet::new();
    let mut dropped = 0;
    let mut take = |line: &[u8], rows: &mut Vec<Row>| -> bool {
        match serde_json::from_slice::<Row>(line) {
            Ok(r) if seen.insert(r.id.clone()) => {
                rows.push(r);
                true
            }
            _ => false,
        }
    };
    for line in bytes[..complete].split(|&b| b == b'\n') {
        if line.iter().all(|b| b.is_ascii_whitespace()) {
            continue;
        }
        if !take(line, &mut rows) {
            dropped += 1;
        }
    }
    let tail = &bytes[complete..];
    let mut missing_newline = false;
    let mut valid_len = complete as u64;
    if !tail.iter().all(|b| b.is_ascii_whitespace()) {
        if take(tail, &mut rows) {
            missing_newline = true;
            valid_len = bytes.len() as u64;
        } else {
            dropped += 1;
        }
    }
    Ok(RowsRead { rows, valid_len, missing_newline, dropped })
}

/// Appends rows: one `write` of the whole line, then flush and fsync, under a lock.
pub struct RowWriter {
    file: Mutex<std::fs::File>,
}

impl RowWriter {
    /// Open for appending after cutting the file to `read.valid_len` (drops a torn last line)
    /// and completing a row whose newline is missing.
    pub fn open(path: &Path, read: &RowsRead) -> Result<RowWriter> {
        let valid_len = read.valid_len;
        let mut f = std::fs::OpenOptions::new().create(true).read(true).write(true).truncate(false).open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let len = f.metadata()?.len();
        if len > valid_len {
            f.set_len(valid_len)?;
            f.sync_all()?;
        }
        f.seek(std::io::SeekFrom::End(0))?;
        if read.missing_newline {
            f.write_all(b"\n")?;
            f.sync_data()?;
        }
        Ok(RowWriter { file: Mutex::new(f) })
    }

    pub fn append(&self, row: &Row) -> Result<()> {
        let mut line = serde_json::to_string(row)?;
        line.push('\n');
        let mut f = self.file.lock().map_err(|_| anyhow!("row writer lock poisoned"))?;
        f.write_all(line.as_bytes())?;
        f.flush()?;
        f.sync_data()?;
        Ok(())
    }
}

// ------------------------------------------------------------------------------------------
// Running

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub n_designs: u64,
    pub n_designs_shard: u64,
    pub already_done: usize,
    pub computed: usize,
    pub dropped_lines: usize,
    pub wall_time_s: f64,
    pub threads: usize,
    pub files: Vec<PathBuf>,
}

/// Options of [`run_sweep`].
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// worker threads (0: rayon's default, the number of cores)
    pub threads: usize,
    /// show a progress bar (only drawn when stderr is a terminal)
    pub progress: bool,
    /// write results.csv, summary.json and maps at the end
    pub outputs: bool,
}

/// Run (or resume) a sweep into `out`. `log` receives progress lines.
pub fn run_sweep(cfg: &SweepConfig, out: &Path, opts: &RunOptions, log: impl Fn(&str) + Sync) -> Result<RunReport> {
    let t0 = Instant::now();
    let v = cfg.problem.validate()?;
    let mut sopts = cfg.problem.scene_options(&v);
    sopts.keep_fields = false;
    let manifest = cfg.manifest()?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create output directory {}", out.display()))?;
    match Manifest::read(out)? {
        Some(old) => {
            if let Some(why) = old.mismatch(&manifest) {
                bail!("{} holds a different sweep ({why}); use a new --out directory or the original command", out.display());
            }
        }
        None => {
            let results = out.join(RESULTS);
            if results.exists() && std::fs::metadata(&results).map(|m| m.len() > 0).unwrap_or(false) {
                bail!("{} has {RESULTS} but no {MANIFEST}: not resuming into it", out.display());
            }
            manifest.write(out)?;
        }
    }
    let results = out.join(RESULTS);
    let read = read_rows(&results)?;
    if read.dropped > 0 {
        log(&format!("dropped {} incomplete or unreadable line(s) of {}", read.dropped, results.display()));
    }
    let done: BTreeSet<String> = read.rows.iter().map(|r| r.id.clone()).collect();
    let n = cfg.grid.len();
    let pending: Vec<(u64, Design)> = (0..n).filter(|i| cfg.shard.contains(*i) && cfg.selected(*i)).map(|i| (i, cfg.design(i))).filter(|(i, d)| !done.contains(&design_id(*i, d))).collect();
    let shard_size = cfg.size();
    log(&format!(
        "grid {}: {n} designs ({}){}; shard {}/{}: {shard_size}; done {}; to run {} at {} (p_max {} kPa, scenes {})",
        cfg.grid.name,
        cfg.grid.shape(),
        cfg.indices.as_ref().map_or(String::new(), |s| format!(", {} selected by --indices", s.len())),
        cfg.shard.index,
        cfg.shard.count,
        (shard_size as usize).saturating_sub(pending.len()),
        pending.len(),
        manifest.fidelity,
        cfg.p_max_kpa,
        v.scenes.iter().map(|k| k.name()).collect::<Vec<_>>().join("+"),
    ));
    let writer = RowWriter::open(&results, &read)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(opts.threads).build().map_err(|e| anyhow!("cannot start worker threads: {e}"))?;
    let threads = pool.current_num_threads();
    let pb = if opts.progress && std::io::stderr().is_terminal() {
        let pb = indicatif::ProgressBar::with_draw_target(Some(pending.len() as u64), indicatif::ProgressDrawTarget::stderr());
        if let Ok(style) = indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} designs, {per_sec}, ETA {eta_precise} {msg}") {
            pb.set_style(style.progress_chars("=> "));
        }
        pb
    } else {
        indicatif::ProgressBar::hidden()
    };
    let write_error: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    // with warm starts: the designs in lines along the grid's last axis, each line in order
    // (a design starts from its predecessor's states), the lines in parallel
    let line_len = if cfg.warm_start { cfg.grid.axes.last().map_or(1, |a| a.values.len().max(1)) as u64 } else { 1 };
    let mut lines: Vec<Vec<&(u64, Design)>> = Vec::new();
    for item in &pending {
        match lines.last_mut() {
            Some(l) if l.last().is_some_and(|p| p.0 / line_len == item.0 / line_len) => l.push(item),
            _ => lines.push(vec![item]),
        }
    }
    pool.install(|| {
        use rayon::prelude::*;
        lines.par_iter().for_each(|line| {
            let mut warm: Option<(u64, DesignWarm)> = None;
            for (i, d) in line.iter().map(|x| (&x.0, &x.1)) {
                if write_error.lock().map(|e| e.is_some()).unwrap_or(true) {
                    return;
                }
                // (only from the line's previous grid point)
                let from = warm.as_ref().filter(|(j, _)| *j + 1 == *i).map(|(_, w)| w);
                let (mut row, offer) = evaluate_design_guarded_warm(*i, d, cfg.grid.range, &v, &sopts, cfg.p_max_kpa, from);
                if let Some(pv) = cfg.vacuum_kpa {
                    add_vacuum_side(&mut row, d, cfg.grid.range, &v, &sopts, pv);
                }
                warm = Some((*i, offer));
                if let Err(e) = writer.append(&row) {
                    if let Ok(mut w) = write_error.lock() {
                        w.get_or_insert(e);
                    }
                }
                pb.set_message(format!("last: #{} {} {:.1} s", row.index, row.status, row.wall_time_s));
                pb.inc(1);
            }
        });
    });
    pb.finish_and_clear();
    if let Some(e) = write_error.into_inner().ok().flatten() {
        return Err(e.context(format!("cannot append to {}", results.display())));
    }
    let mut files = vec![out.join(MANIFEST), results.clone()];
    if opts.outputs {
        let rows = read_rows(&results)?.rows;
        files.extend(write_outputs(out, &manifest, &rows, Some(t0.elapsed().as_secs_f64()), Some(pending.len()), threads)?);
    }
    Ok(RunReport { n_designs: n, n_designs_shard: shard_size, already_done: done.len(), computed: pending.len(), dropped_lines: read.dropped, wall_time_s: t0.elapsed().as_secs_f64(), threads, files })
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn opt(x: Option<f64>) -> String {
    x.map(|v| format!("{v}")).unwrap_or_default()
}

/// `results.csv`: one line per row sorted by index (design parameters by name, then the
/// primary mode's values; empty = null).
pub fn write_csv(path: &Path, grid: &Grid, rows: &[Row]) -> Result<()> {
    let names: Vec<&str> = grid.axes.iter().map(|a| a.name.as_str()).collect();
    let mut s = format!(
        "index,{},status,mode,feasible,theta_max_deg,p_theta_max_kPa,tau_max_Nm,p_tau_max_kPa,omega_J_m3,p_omega_kPa,theta_omega_deg,tau_omega_Nm,omega_balloon_J_m3,p_balloon_kPa,max_radius_mm,max_radius_reached_mm,wall_time_s,cause\n",
        names.join(",")
    );
    let mut sorted: Vec<&Row> = rows.iter().collect();
    sorted.sort_by_key(|r| r.index);
    for r in sorted {
        let m = &r.primary;
        let design: Vec<String> = names.iter().map(|n| opt(r.design.get(*n).copied())).collect();
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.index,
            design.join(","),
            r.status,
            r.mode.as_deref().unwrap_or(""),
            m.feasible,
            opt(m.theta_max_deg),
            opt(m.p_theta_max_kpa),
            opt(m.tau_max_nm),
            opt(m.p_tau_max_kpa),
            opt(m.omega_j_m3),
            opt(m.p_omega_kpa),
            opt(m.theta_omega_deg),
            opt(m.tau_omega_nm),
            opt(m.omega_balloon_j_m3),
            opt(m.p_balloon_kpa),
            opt(m.max_radius_mm),
            opt(m.max_radius_reached_mm),
            r.wall_time_s,
            csv_field(&r.cause)
        ));
    }
    write_atomic(path, &s)
}

/// The best feasible row by Ω (primary mode).
pub fn best_row(rows: &[Row]) -> Option<&Row> {
    rows.iter()
        .filter(|r| r.status == "ok" && r.primary.feasible && r.primary.omega_j_m3.is_some())
        .max_by(|a, b| a.primary.omega_j_m3.unwrap_or(f64::NEG_INFINITY).total_cmp(&b.primary.omega_j_m3.unwrap_or(f64::NEG_INFINITY)).then(b.index.cmp(&a.index)))
}

/// `summary.json`, `results.csv` and the maps of a sweep directory.
pub fn write_outputs(out: &Path, manifest: &Manifest, rows: &[Row], wall_time_s: Option<f64>, computed: Option<usize>, threads: usize) -> Result<Vec<PathBuf>> {
    let mut rows = rows.to_vec();
    refresh_feasibility(&mut rows, manifest);
    let rows = &rows[..];
    let mut files = Vec::new();
    let csv = out.join("results.csv");
    write_csv(&csv, &manifest.grid, rows)?;
    files.push(csv);
    let mut by_status: BTreeMap<String, usize> = BTreeMap::new();
    for r in rows {
        *by_status.entry(r.status.clone()).or_default() += 1;
    }
    let feasible = rows.iter().filter(|r| r.primary.feasible).count();
    let cpu: f64 = rows.iter().map(|r| r.wall_time_s).sum();
    let best = best_row(rows);
    let best_by = |f: &dyn Fn(&Row) -> Option<f64>| {
        rows.iter().filter(|r| r.primary.feasible).filter_map(|r| f(r).map(|x| (x, r))).max_by(|a, b| a.0.abs().total_cmp(&b.0.abs())).map(|(x, r)| json!({"value": x, "id": r.id, "design": r.design}))
    };
    let summary = json!({
        "format": FORMAT,
        "grid": manifest.grid.name,
        "grid_shape": manifest.grid.shape(),
        "n_designs": manifest.n_designs,
        "shard": manifest.shard,
        "n_designs_shard": manifest.n_designs_shard,
        "rows": rows.len(),
        "complete": rows.len() as u64 == manifest.n_designs_shard,
        "by_status": by_status,
        "feasible": feasible,
        "fidelity": manifest.fidelity,
        "sweep_hash": manifest.sweep_hash,
        "sum_of_design_times_s": cpu,
        "rom_fallbacks": {"designs": rows.iter().filter(|r| r.scenes.values().any(|s| s.rom_fallback.is_some())).count(),
                          "scenes": rows.iter().map(|r| r.scenes.values().filter(|s| s.rom_fallback.is_some()).count()).sum::<usize>()},
        "mean_design_time_s": if rows.is_empty() { Value::Null } else { json!(cpu / rows.len() as f64) },
        "last_run": {"wall_time_s": wall_time_s, "designs_computed": computed, "threads": threads,
                     "designs_per_s": match (wall_time_s, computed) { (Some(t), Some(c)) if t > 0.0 && c > 0 => json!(c as f64 / t), _ => Value::Null }},
        "best_omega": best.map(|r| json!({"id": r.id, "design": r.design, "mode": r.mode, "values": r.primary})),
        "best_feasible_abs_theta": best_by(&|r: &Row| r.primary.theta_max_deg),
        "best_feasible_abs_tau": best_by(&|r: &Row| r.primary.tau_max_nm),
    });
    let sp = out.join("summary.json");
    write_atomic(&sp, &(serde_json::to_string_pretty(&summary)? + "\n"))?;
    files.push(sp);
    files.extend(maps::draw_maps(out, &manifest.grid, rows)?);
    Ok(files)
}

/// Join the directories of a sweep's shards into `out` (itself a resumable, unsharded sweep
/// directory). All must hold the same sweep (grid, problem, fidelity). Returns the merged rows
/// count and the shards missing.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<(usize, Vec<u64>, Vec<PathBuf>)> {
    if dirs.is_empty() {
        bail!("sweep-merge: give at least one shard directory");
    }
    let mut first: Option<Manifest> = None;
    let mut shards = BTreeSet::new();
    let mut rows: BTreeMap<String, Row> = BTreeMap::new();
    for d in dirs {
        let m = Manifest::read(d)?.ok_or_else(|| anyhow!("{}: no {MANIFEST} (not a sweep directory)", d.display()))?;
        if let Some(f) = &first {
            if f.sweep_hash != m.sweep_hash || f.grid != m.grid || f.problem != m.problem || f.fidelity != m.fidelity {
                let mut mm = m.clone();
                mm.shard = f.shard;
                let why = f.mismatch(&mm).unwrap_or_else(|| "sweep hash differs".into());
                bail!("{} holds a different sweep than {} ({why})", d.display(), dirs[0].display());
            }
            if f.shard.count != m.shard.count {
                bail!("{}: shard count {} differs from {} in {}", d.display(), m.shard.count, f.shard.count, dirs[0].display());
            }
        } else {
            first = Some(m.clone());
        }
        if !shards.insert(m.shard.index) {
            bail!("{}: shard {}/{} given twice", d.display(), m.shard.index, m.shard.count);
        }
        for r in read_rows(&d.join(RESULTS))?.rows {
            rows.entry(r.id.clone()).or_insert(r);
        }
    }
    let f = first.expect("at least one directory");
    let mut manifest = f.clone();
    manifest.shard = Shard::default();
    manifest.n_designs_shard = manifest.indices.as_ref().map_or(manifest.n_designs, |s| s.len() as u64);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    if let Some(old) = Manifest::read(out)? {
        if let Some(why) = old.mismatch(&manifest) {
            bail!("{} holds a different sweep ({why})", out.display());
        }
        for r in read_rows(&out.join(RESULTS))?.rows {
            rows.entry(r.id.clone()).or_insert(r);
        }
    }
    manifest.write(out)?;
    let mut list: Vec<Row> = rows.into_values().collect();
    list.sort_by_key(|r| r.index);
    refresh_feasibility(&mut list, &manifest);
    let mut text = String::new();
    for r in &list {
        text.push_str(&serde_json::to_string(r)?);
        text.push('\n');
    }
    write_atomic(&out.join(RESULTS), &text)?;
    let missing: Vec<u64> = (0..f.shard.count).filter(|i| !shards.contains(i)).collect();
    let mut files = vec![out.join(MANIFEST), out.join(RESULTS)];
    files.extend(write_outputs(out, &manifest, &list, None, None, 0)?);
    Ok((list.len(), missing, files))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table1_grid_has_the_letters_axes() {
        let g = Grid::table1();
        assert_eq!(g.len(), 39_864);
        assert_eq!(g.shape(), "r_mm 24 × l_mm 11 × alpha_deg 151");
        let r = &g.axes[0].values;
        assert_eq!(r[0], 5.0 * 3f64.sqrt());
        assert!((r[9] - 13.160254037844386).abs() < 1e-12, "Fig. 5's r = 13.2 is 5√3 + 9·0.5");
        assert!((r[22] - 19.660254037844386).abs() < 1e-12);
        assert_eq!(r[23], 20.0);
        assert_eq!(g.axes[1].values, (10..=20).map(f64::from).collect::<Vec<_>>());
        assert_eq!(g.axes[2].values.first(), Some(&60.0));
        assert_eq!(g.axes[2].values.last(), Some(&360.0));
        // last axis fastest
        let d = g.design(0);
        assert_eq!((d.r_mm(), d.l_mm(), d.alpha_deg()), (r[0], 10.0, 60.0));
        let d = g.design(151 + 3);
        assert_eq!((d.r_mm(), d.l_mm(), d.alpha_deg()), (r[0], 11.0, 66.0));
        let d = g.design(39_863);
        assert_eq!((d.r_mm(), d.l_mm(), d.alpha_deg()), (20.0, 20.0, 360.0));
        let e = g.every(4).unwrap();
        assert_eq!(e.len(), 6 * 3 * 38);
        assert_eq!(e.name, "table1/every=4");
        assert!(g.every(0).is_err());
        // every Table-I design is a valid geometry at the corners
        for i in [0, 150, 39_713, 39_863] {
            ActuatorGeometry::new(&g.design(i), RangePolicy::TableI).unwrap();
        }
    }

    #[test]
    fn shards_of_lines_cover_the_grid_once() {
        // (warm starts: a shard holds whole lines of the last axis)
        for (n, count, block) in [(39_864u64, 7u64, 151u64), (10, 3, 4), (9, 4, 3), (5, 1, 5), (3, 4, 2)] {
            let mut seen = vec![0; n as usize];
            for index in 0..count {
                let s = Shard { index, count, block };
                let members: Vec<u64> = (0..n).filter(|&i| s.contains(i)).collect();
                assert_eq!(members.len() as u64, s.size(n), "n {n} shard {index}/{count} block {block}");
                for i in members {
                    seen[i as usize] += 1;
                    assert!(((i / block) * block..(i / block + 1) * block).filter(|&j| j < n).all(|j| s.contains(j)));
                }
            }
            assert!(seen.iter().all(|&c| c == 1));
        }
    }

    #[test]
    fn stepped_values_include_the_end() {
        assert_eq!(stepped_values("x", 10.0, 20.0, 5.0).unwrap(), vec![10.0, 15.0, 20.0]);
        assert_eq!(stepped_values("x", 60.0, 360.0, 100.0).unwrap(), vec![60.0, 160.0, 260.0, 360.0]);
        assert_eq!(stepped_values("x", 0.0, 1.0, 0.4).unwrap(), vec![0.0, 0.4, 0.8, 1.0]);
        assert_eq!(stepped_values("x", 0.0, 0.3, 0.1).unwrap().len(), 4);
        assert!(stepped_values("x", 1.0, 0.0, 0.1).unwrap_err().to_string().contains("sweep.x"));
        assert!(stepped_values("x", 0.0, 1.0, 0.0).is_err());
        assert!(stepped_values("x", 0.0, f64::NAN, 1.0).is_err());
    }

    fn section(text: &str) -> Result<Grid> {
        grid_from_section(&toml::from_str::<toml::Table>(text).unwrap())
    }

    #[test]
    fn sweep_sections() {
        let g = section("r_mm = [10.0]\nl_mm = {from = 10, to = 20, step = 5}\nalpha_deg = [60, 90]\n").unwrap();
        assert_eq!(g.name, "custom");
        assert_eq!(g.len(), 6);
        assert_eq!(g.axes.iter().map(|a| a.name.as_str()).collect::<Vec<_>>(), vec!["r_mm", "l_mm", "alpha_deg"]);
        let g = section("alpha_deg = [60, 90, 120]\nr_mm = [10]\nl_mm = [12]\nevery = 2\n").unwrap();
        assert_eq!(g.axes[2].values, vec![60.0, 120.0]);
        assert_eq!(g.name, "custom/every=2");
        assert_eq!(section("grid = \"every=10\"\n").unwrap().len(), 3 * 2 * 16);
        for (text, needle) in [
            ("r_mm = [10]\nl_mm = [12]\n", "alpha_deg"),
            ("r_mm = [10]\nl_mm = [12]\nalpha_deg = [60]\nbogus = 1\n", "sweep.bogus"),
            ("r_mm = [10]\nl_mm = [12]\nalpha_deg = {from = 60, to = 90}\n", "step"),
            ("r_mm = [10]\nl_mm = [12]\nalpha_deg = [60, 60]\n", "twice"),
            ("r_mm = [10]\nl_mm = [12]\nalpha_deg = \"x\"\n", "sweep.alpha_deg"),
            ("grid = \"every=0\"\n", "every"),
            ("grid = \"table2\"\n", "sweep.grid"),
            ("grid = \"table1\"\nr_mm = [10]\n", "not both"),
            ("", "no grid"),
        ] {
            let e = section(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
    }

    #[test]
    fn shards_partition_the_grid() {
        for s in ["3/2", "2/2", "1/0", "a/2", "1", "-1/2"] {
            assert!(Shard::parse(s).is_err(), "{s}");
        }
        let n = 1001;
        let shards: Vec<Shard> = (0..7).map(|i| Shard::parse(&format!("{i}/7")).unwrap()).collect();
        assert_eq!(shards.iter().map(|s| s.size(n)).sum::<u64>(), n);
        for i in 0..n {
            assert_eq!(shards.iter().filter(|s| s.contains(i)).count(), 1);
        }
        for s in &shards {
            assert_eq!(s.size(n), (0..n).filter(|&i| s.contains(i)).count() as u64);
        }
        assert_eq!(Shard::parse("9/10").unwrap().size(5), 0);
    }

    fn rec(p: f64, theta: f64, tau: f64, radius: f64) -> StepRecord {
        StepRecord::for_test(p, theta, tau, radius, 1.0)
    }

    fn scene(name: &str, steps: Vec<StepRecord>) -> SceneResult {
        SceneResult {
            snaps_kpa: Vec::new(),
            min_contact_distance_mm: None,
            scene: name.into(),
            status: crate::scene::SceneStatus::LimitPoint,
            cause: String::new(),
            steps,
            dofs: 1,
            elements: 1,
            newton_iterations: 1,
            path: Default::default(),
            wall_time_s: 0.0,
            fields: None,
            states: Vec::new(),
            rom_indicator: None,
            rom_fallback: None,
            warm_start_kpa: None,
            warm: None,
            warm_deltas: Vec::new(),
        }
    }

    #[test]
    fn mode_summary_follows_the_letters_rule_and_the_ballooning_limit() {
        // free reaches 60 kPa, blocked 50: Ω at 50 kPa; radius crosses 28.75 at 40 + 10·(28.75−26)/(30−26) kPa
        let free = scene("free", vec![rec(0.0, 0.0, 0.0, 20.0), rec(20.0, -10.0, 0.0, 22.0), rec(40.0, -20.0, 0.0, 26.0), rec(60.0, -25.0, 0.0, 32.0)]);
        let blocked = scene("blocked", vec![rec(0.0, 0.0, 0.0, 20.0), rec(25.0, 0.0, -0.2, 21.0), rec(50.0, 0.0, -0.3, 30.0)]);
        let m = mode_summary(Some(&free), Some(&blocked), 28.75);
        assert_eq!(m.theta_max_deg, Some(-25.0));
        assert_eq!(m.p_theta_max_kpa, Some(60.0));
        assert_eq!(m.tau_max_nm, Some(-0.3));
        assert_eq!(m.p_tau_max_kpa, Some(50.0));
        assert_eq!(m.p_omega_kpa, Some(50.0));
        assert!((m.theta_omega_deg.unwrap() + 22.5).abs() < 1e-12);
        let o = crate::evaluate::omega_letter(&free.steps, &blocked.steps, true).unwrap();
        assert_eq!(m.omega_j_m3, Some(o.omega_j_m3));
        assert!((o.omega_j_m3 - crate::scene::energy_density(22.5, 0.3)).abs() < 1e-9);
        // radius at 50 kPa: free 29, blocked 30 → infeasible
        assert_eq!(m.max_radius_mm, Some(30.0));
        assert!(!m.feasible);
        assert_eq!(m.max_radius_reached_mm, Some(32.0));
        // ballooning-limited: free crosses at 40 + 20·(2.75/6) = 49.1667; blocked at 25 + 25·(7.75/9) = 46.5278
        let pb = 25.0 + 25.0 * (7.75 / 9.0);
        assert!((m.p_balloon_kpa.unwrap() - pb).abs() < 1e-9, "{:?}", m.p_balloon_kpa);
        let ob = crate::evaluate::omega_at_pressure(&free.steps, &blocked.steps, pb).unwrap();
        assert_eq!(m.omega_balloon_j_m3, Some(ob.omega_j_m3));
        // a free scene alone: twist only
        let m = mode_summary(Some(&free), None, 28.75);
        assert_eq!(m.theta_max_deg, Some(-25.0));
        assert_eq!((m.omega_j_m3, m.feasible), (None, false));
        // feasible when the limit is higher
        assert!(mode_summary(Some(&free), Some(&blocked), 40.0).feasible);
        // a scene stopped at the ballooning limit lands within the event's location tolerance of
        // it: 2.8e-9 mm above (measured on the Table-I grid) is at the limit, 1 µm above is not
        assert!(mode_summary(Some(&free), Some(&blocked), 30.0 - 2.8e-9).feasible);
        assert!(!mode_summary(Some(&free), Some(&blocked), 30.0 - 1e-3).feasible);
        // rows written under another rule are judged again from their stored values
        let mut r = row(3);
        r.primary.max_radius_mm = Some(28.75 + 2.8e-9);
        r.modes.insert("combined".into(), r.primary.clone());
        r.refresh_feasibility(28.75);
        assert!(r.primary.feasible && r.modes["combined"].feasible);
        r.primary.max_radius_mm = Some(28.76);
        r.refresh_feasibility(28.75);
        assert!(!r.primary.feasible);
        r.primary.omega_j_m3 = None;
        r.primary.max_radius_mm = Some(20.0);
        r.refresh_feasibility(28.75);
        assert!(!r.primary.feasible, "no Ω, not feasible");
    }

    fn row(index: u64) -> Row {
        let d = Design::new(10.0, 12.0, 60.0 + index as f64);
        let mut r = empty_row(index, &d, 20.0);
        r.status = "ok".into();
        r.primary.omega_j_m3 = Some(index as f64);
        r
    }

    #[test]
    fn rows_file_survives_torn_writes() {
        let dir = std::env::temp_dir().join(format!("twistopt-sweep-rows-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(RESULTS);
        let w = RowWriter::open(&p, &read_rows(&p).unwrap()).unwrap();
        for i in 0..3 {
            w.append(&row(i)).unwrap();
        }
        drop(w);
        // a write cut mid-line
        let full = serde_json::to_string(&row(3)).unwrap();
        let mut f = std::fs::OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(&full.as_bytes()[..full.len() / 2]).unwrap();
        drop(f);
        let r = read_rows(&p).unwrap();
        assert_eq!((r.rows.len(), r.dropped, r.missing_newline), (3, 1, false));
        let w = RowWriter::open(&p, &r).unwrap();
        w.append(&row(3)).unwrap();
        drop(w);
        let r = read_rows(&p).unwrap();
        assert_eq!((r.rows.len(), r.dropped), (4, 0));
        assert_eq!(r.rows.iter().map(|x| x.index).collect::<Vec<_>>(), vec![0, 1, 2, 3]);
        assert_eq!(r.rows[3], row(3));
        // a complete row whose newline was cut is kept and completed; a duplicate id is skipped
        let mut f = std::fs::OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(serde_json::to_string(&row(4)).unwrap().as_bytes()).unwrap();
        drop(f);
        let r = read_rows(&p).unwrap();
        assert_eq!((r.rows.len(), r.missing_newline), (5, true));
        let w = RowWriter::open(&p, &r).unwrap();
        w.append(&row(1)).unwrap();
        drop(w);
        let r = read_rows(&p).unwrap();
        assert_eq!((r.rows.len(), r.dropped, r.missing_newline), (5, 1, false));
        assert_eq!(std::fs::read_to_string(&p).unwrap().lines().count(), 6);
        // NaN never reaches a row: absent values are null
        let text = serde_json::to_string(&row(0)).unwrap();
        assert!(text.contains("\"theta_max_deg\":null") && !text.contains("NaN"), "{text}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn invalid_designs_are_rows() {
        let (problem, section) = problem_from_str("[load]\np_max_kPa = 10\n[fidelity]\nmesh = \"12x4x1\"\n[sweep]\nr_mm = [3.0]\nl_mm = [12]\nalpha_deg = [60]\n", "t", &[]).unwrap();
        let cfg = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).unwrap();
        let v = cfg.problem.validate().unwrap();
        let opts = cfg.problem.scene_options(&v);
        let r = evaluate_design_guarded(0, &cfg.grid.design(0), cfg.grid.range, &v, &opts, cfg.p_max_kpa);
        assert_eq!(r.status, "invalid-geometry");
        assert!(r.cause.contains("r_mm = 3"), "{}", r.cause);
        assert_eq!(r.id, "0:alpha_deg=60,l_mm=12,r_mm=3");
        assert!(r.primary.omega_j_m3.is_none() && !r.primary.feasible);
        // a list of target pressures is refused with a hint
        let (problem, section) = problem_from_str("[load]\npressures_kPa = [10]\n[sweep]\ngrid = \"table1\"\n", "t", &[]).unwrap();
        let e = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).unwrap_err().to_string();
        assert!(e.contains("load.p_max_kPa"), "{e}");
    }

    #[test]
    fn warm_starts_in_the_pure_twist_scenes_are_warned_about() {
        let cfg = |scenes: &str, warm: bool| {
            let text = format!("[load]\np_max_kPa = 10\n[fidelity]\nmesh = \"12x4x1\"\n[scenes]\nrun = {scenes}\n[sweep]\nr_mm = [10.0]\nl_mm = [12]\nalpha_deg = [60, 90]\nwarm_start = {warm}\n");
            let (problem, section) = problem_from_str(&text, "t", &[]).unwrap();
            SweepConfig::new(problem, section.as_ref(), None, Shard::default()).unwrap()
        };
        let pt = cfg("[\"pure-twist\", \"pure-twist-blocked\"]", true);
        assert_eq!(pt.warnings.len(), 1);
        assert!(pt.warnings[0].contains("sweep.warm_start = false"), "{}", pt.warnings[0]);
        assert!(cfg("[\"pure-twist\", \"pure-twist-blocked\"]", false).warnings.is_empty());
        assert!(cfg("[\"free\", \"blocked\"]", true).warnings.is_empty());
    }

    #[test]
    fn indices_select_grid_designs_and_are_part_of_the_manifest() {
        // r = 3 mm is outside the box: every design is an instant invalid-geometry row
        let text = "[load]\np_max_kPa = 10\n[fidelity]\nmesh = \"12x4x1\"\n[sweep]\nr_mm = [3.0]\nl_mm = [10, 12, 14, 16]\nalpha_deg = [60, 90]\n";
        let cfg = |idx: Option<Vec<u64>>| {
            let (problem, section) = problem_from_str(text, "t", &[]).unwrap();
            let c = SweepConfig::new(problem, section.as_ref(), None, Shard::default()).unwrap();
            match idx {
                Some(i) => c.with_indices(i),
                None => Ok(c),
            }
        };
        let e = cfg(Some(vec![8])).unwrap_err().to_string();
        assert!(e.contains("out of range") && e.contains("8 designs"), "{e}");
        assert!(cfg(Some(vec![])).is_err());
        let c = cfg(Some(vec![5, 1, 5])).unwrap();
        assert_eq!(c.indices, Some(vec![1, 5]));
        assert_eq!(c.size(), 2);
        let dir = std::env::temp_dir().join(format!("twistopt-sweep-indices-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let opts = RunOptions { threads: 1, progress: false, outputs: false };
        let rep = run_sweep(&c, &dir, &opts, |_| {}).unwrap();
        assert_eq!((rep.computed, rep.n_designs_shard), (2, 2));
        let rows = read_rows(&dir.join(RESULTS)).unwrap().rows;
        let mut got: Vec<u64> = rows.iter().map(|r| r.index).collect();
        got.sort_unstable();
        assert_eq!(got, vec![1, 5]);
        assert_eq!(rows.iter().find(|r| r.index == 5).unwrap().design["l_mm"], 14.0);
        let m = Manifest::read(&dir).unwrap().unwrap();
        assert_eq!((m.indices.clone(), m.n_designs, m.n_designs_shard), (Some(vec![1, 5]), 8, 2));
        // the whole grid's hash is unchanged by the new field; a selection has its own
        assert_ne!(m.sweep_hash, cfg(None).unwrap().manifest().unwrap().sweep_hash);
        // resuming: the same selection runs nothing; another selection or the whole grid is refused
        assert_eq!(run_sweep(&c, &dir, &opts, |_| {}).unwrap().computed, 0);
        let e = run_sweep(&cfg(Some(vec![1])).unwrap(), &dir, &opts, |_| {}).unwrap_err().to_string();
        assert!(e.contains("--indices"), "{e}");
        assert!(run_sweep(&cfg(None).unwrap(), &dir, &opts, |_| {}).is_err());
        // the manifest of a whole-grid sweep has no indices key (older directories still resume)
        let whole = serde_json::to_value(cfg(None).unwrap().manifest().unwrap()).unwrap();
        assert!(whole.get("indices").is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
