#!/usr/bin/env python3
"""Read twistopt exports back with meshio (a reader nobody here wrote) and check them.

usage: check_exports.py OUTDIR [RTOL]

OUTDIR must contain summary.json, mesh.vtu, outer.stl and cavity.stl written by
`twistopt geometry`. Checks:
  * mesh.vtu: node and cell counts and the cell type match summary.json;
  * outer.stl / cavity.stl: closed (every edge shared by exactly two triangles), consistently
    oriented (each directed edge used once, its reverse once) and enclosing a positive volume that
    matches the closed-form outer / chamber volume within the discretisation tolerance
    RTOL (relative, default 0.02), and equal to the exporter's own meshed volumes in
    summary.json up to f32 STL round-off.
Exit code 0 on success, 1 on a failed check, 3 when meshio/numpy are missing.
"""
import json
import os
import sys

try:
    import meshio
    import numpy as np
except ImportError as e:  # pragma: no cover
    print(f"meshio/numpy not importable ({e}): run `bash scripts/setup.sh` first", file=sys.stderr)
    sys.exit(3)

VTK_NAMES = {"Hex8": "hexahedron", "Hex20": "hexahedron20", "Hex27": "hexahedron27"}


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def check_closed_surface(path, label):
    m = meshio.read(path)
    tris = np.concatenate([c.data for c in m.cells if c.type == "triangle"])
    pts = np.asarray(m.points, dtype=float)
    if len(tris) == 0:
        fail(f"{label}: no triangles")
    # undirected edge multiplicity
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    und = np.sort(e, axis=1)
    _, counts = np.unique(und, axis=0, return_counts=True)
    if not np.all(counts == 2):
        bad = int(np.sum(counts != 2))
        fail(f"{label}: {bad} edges not shared by exactly two triangles (not watertight)")
    # orientation: every directed edge exactly once
    _, dcounts = np.unique(e, axis=0, return_counts=True)
    if not np.all(dcounts == 1):
        fail(f"{label}: inconsistent triangle orientation ({int(np.sum(dcounts != 1))} repeated directed edges)")
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    vol = float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)
    # Euler characteristic of a sphere
    n_e = len(und) // 2
    chi = len(pts) - n_e + len(tris)
    if chi != 2:
        fail(f"{label}: Euler characteristic {chi} != 2 (not a single closed sphere-like surface)")
    return vol, len(tris), len(pts)


def main():
    if len(sys.argv) not in (2, 3):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    d = sys.argv[1]
    with open(os.path.join(d, "summary.json")) as f:
        s = json.load(f)

    vtu = meshio.read(os.path.join(d, "mesh.vtu"))
    n_cells = sum(len(c.data) for c in vtu.cells)
    if len(vtu.points) != s["nodes"]:
        fail(f"mesh.vtu: {len(vtu.points)} points, summary says {s['nodes']}")
    if n_cells != s["elements"]:
        fail(f"mesh.vtu: {n_cells} cells, summary says {s['elements']}")
    types = {c.type for c in vtu.cells}
    want = VTK_NAMES[s["element_kind"]]
    if types != {want}:
        fail(f"mesh.vtu: cell types {types}, expected {{{want}}}")
    for name in ("dX_dr_mm", "dX_dl_mm", "dX_dalpha_deg"):
        arr = vtu.point_data.get(name)
        if arr is None or arr.shape != (len(vtu.points), 3) or not np.all(np.isfinite(arr)):
            fail(f"mesh.vtu: point data {name} missing or malformed")
    # the bottom face does not move with alpha; the top ring turns by alpha: dX/dalpha = (pi/180) e_z x X
    top = np.abs(vtu.points[:, 2] - 40.0) < 1e-9
    rot = np.stack([-vtu.points[:, 1], vtu.points[:, 0], 0 * vtu.points[:, 0]], axis=1) * np.pi / 180.0
    if not np.allclose(vtu.point_data["dX_dalpha_deg"][top], rot[top], atol=1e-9):
        fail("mesh.vtu: dX_dalpha_deg on the top face is not the rigid rotation rate")
    sj = np.concatenate(vtu.cell_data.get("min_scaled_jacobian", [np.zeros(0)]))
    if len(sj) != n_cells or not (sj.min() > 0) or abs(sj.min() - s["min_scaled_jacobian"]) > 1e-9:
        fail("mesh.vtu: cell data min_scaled_jacobian missing or inconsistent with summary.json")
    zmin, zmax = float(vtu.points[:, 2].min()), float(vtu.points[:, 2].max())
    if abs(zmin) > 1e-9 or abs(zmax - 40.0) > 1e-9:
        fail(f"mesh.vtu: z range [{zmin}, {zmax}] is not [0, 40]")

    checks = [
        ("outer.stl", "outer_volume_mm3", "meshed_outer_volume_mm3"),
        ("cavity.stl", "chamber_volume_mm3", "meshed_chamber_volume_mm3"),
    ]
    for fname, exact_key, meshed_key in checks:
        vol, ntri, npts = check_closed_surface(os.path.join(d, fname), fname)
        exact = s[exact_key]
        meshed = s[meshed_key]
        if vol <= 0:
            fail(f"{fname}: enclosed volume {vol} is not positive (normals inward?)")
        # the reader's volume must equal the writer's (f32 round-off) ...
        if abs(vol - meshed) > 1e-5 * exact:
            fail(f"{fname}: meshio volume {vol:.6f} differs from the exporter's {meshed:.6f}")
        # ... and the closed form within the mesh discretisation error
        tol = float(sys.argv[2]) if len(sys.argv) == 3 else 0.02
        rel = abs(vol - exact) / exact
        if rel > tol:
            fail(f"{fname}: volume {vol:.3f} vs closed form {exact:.3f} (relative {rel:.2e} > {tol})")
        print(f"{fname}: {ntri} triangles, {npts} points, closed and oriented, volume {vol:.4f} "
              f"(closed form {exact:.4f}, rel. diff {rel:.2e})")
    print(f"mesh.vtu: {len(vtu.points)} points, {n_cells} {want} cells")
    print("OK")


if __name__ == "__main__":
    main()
