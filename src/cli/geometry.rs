//! `twistopt geometry`: closed-form geometry summary, mesh and exports for one design.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use serde_json::{json, Value};
use twistopt_solver::mesh::ElementKind;

use crate::export::{cavity_surface, outer_surface, write_inp, write_stl_binary, write_vtu, DataArray};
use crate::geometry::{ActuatorGeometry, Design, RangePolicy};
use crate::meshing::{build_mesh, element_scaled_jacobians, mesh_shape_derivatives, MeshSpec};

/// Element order of the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Order {
    /// 8-node trilinear hexahedra (Hex8 / C3D8)
    Linear,
    /// 27-node triquadratic hexahedra (Hex27; exported to INP as C3D20)
    Quadratic,
}

#[derive(Debug, Args)]
pub struct GeometryArgs {
    /// Design parameter r_mm: arc radius r of the horseshoe section in mm (Table I: 5√3 ≈ 8.660254 … 20).
    #[arg(long = "r", value_name = "MM", allow_negative_numbers = true, required_unless_present = "design")]
    pub r: Option<f64>,
    /// Design parameter l_mm: waist radius l of the bellows profile in mm (Table I: 10 … 20).
    #[arg(long = "l", value_name = "MM", allow_negative_numbers = true, required_unless_present = "design")]
    pub l: Option<f64>,
    /// Design parameter alpha_deg: pre-twist α of the top face in degrees (Table I: 60 … 360;
    /// counter-clockwise about +z).
    #[arg(long = "alpha", value_name = "DEG", allow_negative_numbers = true, required_unless_present = "design")]
    pub alpha: Option<f64>,
    /// Any design parameter by name, e.g. a freeform mode: --param twist_2_deg=-10 (repeatable;
    /// problems/README.md lists them). Applied after --design.
    #[arg(long = "param", value_name = "NAME=VALUE", allow_hyphen_values = true)]
    pub params: Vec<String>,
    /// A design from JSON: an object of parameter values by name, or an optimiser's best.json
    /// (its best run's design). --r/--l/--alpha and --param override its values.
    #[arg(long, value_name = "FILE.json")]
    pub design: Option<PathBuf>,
    /// Mesh: a preset (coarse = 24x8x1, default = 48x16x2, fine = 60x20x2, sweep = 48x16x1) or an explicit
    /// <Na>x<Nz>x<Nt> (elements around, along, through; Na a multiple of 3, Nz of 4). The same
    /// element counts are used with --order linear.
    #[arg(long, value_name = "PRESET|NAxNZxNT", default_value = "default")]
    pub mesh: String,
    /// Element order.
    #[arg(long, value_enum, default_value_t = Order::Quadratic)]
    pub order: Order,
    /// Mesh only the 120° sector (cyclic symmetry); the STLs are still built from the full mesh.
    #[arg(long)]
    pub sector: bool,
    /// Uniform arc-length split around instead of the arc-aligned split (nodes on the six
    /// curvature jumps).
    #[arg(long)]
    pub uniform_around: bool,
    /// Accept the wider range the construction supports (r ≥ R√21/14 ≈ 6.547 mm, l down to the
    /// offset-validity bound, any finite α) instead of the Table I box.
    #[arg(long)]
    pub extended_range: bool,
    /// Geometry variant: "spec" (GEOMETRY.md, default) or any of tips-on-r | midpoint-centres,
    /// outward, twist-first joined by '+' (studies/letter-calibration/VARIANTS.md).
    #[arg(long, value_name = "NAME", default_value = "spec")]
    pub variant: String,
    /// Optional design parameter end_tangent_deg: the lateral profile's end-tangent angle from
    /// the vertical in degrees (absent = the spec's vertical ends).
    #[arg(long = "end-tangent", value_name = "DEG", allow_negative_numbers = true)]
    pub end_tangent: Option<f64>,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// Design values from a JSON file: a flat object of numbers by name (p_kPa and non-numbers are
/// skipped), or an optimiser's best.json (the design of its run with the best objective).
fn design_values_from_json(path: &Path) -> Result<std::collections::BTreeMap<String, f64>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("--design: cannot read {}", path.display()))?;
    let v: Value = serde_json::from_str(&text).with_context(|| format!("--design: {} is not JSON", path.display()))?;
    let obj = match v.get("runs").and_then(Value::as_array) {
        Some(runs) => runs
            .iter()
            .filter(|r| r.get("design").is_some_and(Value::is_object))
            .max_by(|a, b| a["objective"].as_f64().unwrap_or(f64::NEG_INFINITY).total_cmp(&b["objective"].as_f64().unwrap_or(f64::NEG_INFINITY)))
            .map(|r| r["design"].clone())
            .ok_or_else(|| anyhow::anyhow!("--design: {} has no run with a design", path.display()))?,
        None => v,
    };
    let obj = obj.as_object().ok_or_else(|| anyhow::anyhow!("--design: expected a JSON object of parameter values in {}", path.display()))?;
    Ok(obj.iter().filter(|(k, _)| k.as_str() != "p_kPa").filter_map(|(k, v)| v.as_f64().map(|x| (k.clone(), x))).collect())
}

/// A freeform design's lateral profile and twist law against the letter's three-arc profile
/// and linear twist at the same (r, l, α): shape.csv and the plots profile.{png,svg},
/// twist.{png,svg}. Returns the file names.
fn write_freeform_shape(dir: &Path, geom: &ActuatorGeometry) -> Result<Vec<String>> {
    use crate::geometry::L_TUBE;
    use crate::plot::{line_plot, LinePlot, Series};
    let act = &geom.act;
    let spec = crate::geometry::Actuator::with_variant(act.section.r, act.profile.l, act.alpha, act.profile.gamma, act.variant);
    let n = 201;
    let mut csv = String::from("z_mm,rho_mm,rho_letter_mm,twist_deg,twist_linear_deg\n");
    let (mut prof, mut prof0, mut tw, mut tw0) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..n {
        let z = L_TUBE * i as f64 / (n - 1) as f64;
        let (r, r0) = (act.profile.eval(z).rho, spec.profile.eval(z).rho);
        let (t, t0) = (act.twist_angle(z).0.to_degrees(), spec.twist_angle(z).0.to_degrees());
        csv.push_str(&format!("{z},{r},{r0},{t},{t0}\n"));
        prof.push((z, r));
        prof0.push((z, r0));
        tw.push((z, t));
        tw0.push((z, t0));
    }
    std::fs::write(dir.join("shape.csv"), csv).with_context(|| format!("cannot write {}", dir.join("shape.csv").display()))?;
    let line = |name: &str, pts: Vec<(f64, f64)>| Series { name: name.into(), points: pts, markers: false, line: true };
    line_plot(
        &dir.join("profile"),
        &LinePlot::new("Lateral profile (rest radius of the designed surface)", "z (mm)", "rho (mm)").with(line("freeform", prof)).with(line("letter's three arcs (same l)", prof0)),
    )?;
    line_plot(&dir.join("twist"), &LinePlot::new("Twist law", "z (mm)", "twist angle (deg)").with(line("freeform", tw)).with(line("letter's linear twist (same alpha)", tw0)))?;
    Ok(["shape.csv", "profile.png", "profile.svg", "twist.png", "twist.svg"].map(String::from).to_vec())
}

/// Build geometry + mesh and write all outputs; returns the summary JSON.
pub fn generate(args: &GeometryArgs) -> Result<Value> {
    let variant = crate::geometry::GeometryVariant::parse(&args.variant).map_err(|e| anyhow::anyhow!("--variant: {e}"))?;
    let mut design = Design::default().with_variant(variant);
    if let Some(path) = &args.design {
        design.values = design_values_from_json(path)?;
    }
    for (name, v) in [("r_mm", args.r), ("l_mm", args.l), ("alpha_deg", args.alpha)] {
        if let Some(v) = v {
            design.values.insert(name.into(), v);
        }
    }
    for kv in &args.params {
        let (k, v) = kv.split_once('=').ok_or_else(|| anyhow::anyhow!("--param '{kv}': expected NAME=VALUE (e.g. twist_2_deg=-10)"))?;
        let v: f64 = v.trim().parse().map_err(|_| anyhow::anyhow!("--param '{kv}': '{}' is not a number", v.trim()))?;
        design = design.with(k.trim(), v).map_err(|e| anyhow::anyhow!("--param '{kv}': {e}"))?;
    }
    if let Some(g) = args.end_tangent {
        design = design.with_end_tangent(g);
    }
    for name in ["r_mm", "l_mm", "alpha_deg"] {
        if !design.values.contains_key(name) {
            anyhow::bail!("the design has no {name} (give --{} or a --design file with it)", &name[..name.find('_').unwrap_or(name.len())]);
        }
    }
    let policy = if args.extended_range { RangePolicy::Extended } else { RangePolicy::TableI };
    let geom = ActuatorGeometry::new(&design, policy)?;
    let kind = match args.order {
        Order::Linear => ElementKind::Hex8,
        Order::Quadratic => ElementKind::Hex27,
    };
    let spec = MeshSpec::parse(&args.mesh)?.with_kind(kind).with_sector(args.sector).with_arc_aligned(!args.uniform_around);
    let t0 = std::time::Instant::now();
    let am = build_mesh(&geom, &spec)?;
    let mesh_seconds = t0.elapsed().as_secs_f64();
    let full = if spec.sector { build_mesh(&geom, &spec.with_sector(false))? } else { am.clone() };
    let outer = outer_surface(&full.mesh)?;
    let cavity = cavity_surface(&full.mesh)?;

    let dir: &Path = &args.out;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create output directory {}", dir.display()))?;
    // point data: shape derivatives dX/dp for every design parameter; cell data: quality
    let ders = mesh_shape_derivatives(&geom, &spec)?;
    let flat: Vec<(String, Vec<f64>)> = ders.iter().map(|(n, d)| (format!("dX_d{n}"), d.iter().flatten().copied().collect())).collect();
    let point_data: Vec<DataArray<'_>> = flat.iter().map(|(n, v)| DataArray::new(n, 3, v)).collect();
    let sj = element_scaled_jacobians(&am.mesh);
    write_vtu(&dir.join("mesh.vtu"), &am.mesh, &point_data, &[DataArray::new("min_scaled_jacobian", 1, &sj)])?;
    write_stl_binary(&dir.join("outer.stl"), &outer, "outer")?;
    write_stl_binary(&dir.join("cavity.stl"), &cavity, "cavity")?;
    let mut heading = format!(
        "twistopt actuator r_mm={} l_mm={} alpha_deg={} mesh={} {:?}{}",
        design.r_mm(),
        design.l_mm(),
        design.alpha_deg(),
        spec.size_string(),
        spec.kind,
        if spec.sector { " sector" } else { "" }
    );
    for (k, v) in &design.values {
        if crate::geometry::freeform::parse_param(k).is_some() {
            heading.push_str(&format!(" {k}={v}"));
        }
    }
    if !variant.is_spec() {
        heading.push_str(&format!(" variant={variant}"));
    }
    if let Some(g) = args.end_tangent {
        heading.push_str(&format!(" end_tangent_deg={g}"));
    }
    write_inp(&dir.join("mesh.inp"), &am.mesh, &heading)?;

    let mut v = serde_json::to_value(geom.summary())?;
    let m = v.as_object_mut().context("summary is an object")?;
    let ders: serde_json::Map<String, Value> = geom
        .scalar_derivatives()
        .into_iter()
        .map(|d| {
            (
                d.param.clone(),
                json!({
                    "outer_volume_mm3": d.outer_volume,
                    "chamber_volume_mm3": d.chamber_volume,
                    "wall_volume_mm3": d.wall_volume,
                    "inner_end_area_mm2": d.inner_end_area,
                    "outer_end_area_mm2": d.outer_end_area,
                }),
            )
        })
        .collect();
    m.insert("derivatives_per_parameter".into(), Value::Object(ders));
    m.insert("range_policy".into(), json!(format!("{:?}", policy)));
    m.insert("mesh".into(), json!(spec.size_string()));
    m.insert("element_kind".into(), json!(format!("{:?}", spec.kind)));
    m.insert("sector".into(), json!(spec.sector));
    m.insert("arc_aligned".into(), json!(spec.arc_aligned));
    m.insert("nodes".into(), json!(am.mesh.n_nodes()));
    m.insert("elements".into(), json!(am.mesh.n_elements()));
    m.insert("cyclic_pairs".into(), json!(am.cyclic_pairs.len()));
    m.insert("min_scaled_jacobian".into(), json!(am.quality.min_scaled_jacobian));
    m.insert("worst_element".into(), json!(am.quality.worst_element));
    m.insert("design".into(), json!(design.values));
    if geom.act.is_freeform() {
        m.insert("freeform_files".into(), json!(write_freeform_shape(dir, &geom)?));
    }
    m.insert("mesh_generation_seconds".into(), json!(mesh_seconds));
    m.insert("meshed_outer_volume_mm3".into(), json!(outer.volume()));
    m.insert("meshed_chamber_volume_mm3".into(), json!(cavity.volume()));
    m.insert("outer_stl_triangles".into(), json!(outer.triangles.len()));
    m.insert("cavity_stl_triangles".into(), json!(cavity.triangles.len()));
    m.insert("files".into(), json!(["summary.json", "mesh.vtu", "outer.stl", "cavity.stl", "mesh.inp"]));
    std::fs::write(dir.join("summary.json"), serde_json::to_string_pretty(&v)? + "\n").with_context(|| format!("cannot write {}", dir.join("summary.json").display()))?;
    Ok(v)
}

pub fn run(args: &GeometryArgs) -> Result<()> {
    let v = generate(args)?;
    println!(
        "r = {} mm, l = {} mm, alpha = {} deg: T = {:.4} mm, chamber volume = {:.3} mm3, wall volume = {:.3} mm3",
        v["r_mm"], v["l_mm"], v["alpha_deg"], v["T_mm"], v["chamber_volume_mm3"], v["wall_volume_mm3"]
    );
    println!(
        "mesh {} {}: {} nodes, {} elements, min scaled Jacobian {:.4}; wrote {}",
        v["mesh"].as_str().unwrap_or(""),
        v["element_kind"].as_str().unwrap_or(""),
        v["nodes"],
        v["elements"],
        v["min_scaled_jacobian"].as_f64().unwrap_or(f64::NAN),
        args.out.display()
    );
    Ok(())
}
