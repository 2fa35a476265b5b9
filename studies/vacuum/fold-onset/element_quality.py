#!/usr/bin/env python3
"""Element quality along a vacuum ramp, from `twistopt evaluate`'s VTU series (Hex27).

For each recorded step below -9.9 kPa of the free scene: the least det(dx/dxi) on a 9^3 grid of
each element relative to its centre's (as twistopt's `least_jacobian_ratio`), and at the
3x3x3 Gauss points the least principal stretch of the isochoric part J^(-1/3) F and the least
J = det F. Usage: element_quality.py OUT_DIR [OUT_DIR ...] (each an `evaluate --out` directory
with free/step_NNN.vtu and result.json). Needs numpy and meshio.
"""
import json
import os
import sys

import meshio
import numpy as np

# VTK_TRIQUADRATIC_HEXAHEDRON node positions in xi (corners, mid-edges, mid-faces y-, x+, y+, x-,
# z-, z+, centre)
P = np.array([(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1),
              (0, -1, -1), (1, 0, -1), (0, 1, -1), (-1, 0, -1), (0, -1, 1), (1, 0, 1), (0, 1, 1), (-1, 0, 1),
              (-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (0, -1, 0), (1, 0, 0), (0, 1, 0), (-1, 0, 0),
              (0, 0, -1), (0, 0, 1), (0, 0, 0)], int)


def dshape(xi):
    """Derivatives of the 27 Lagrange shape functions at xi: (27, 3)."""
    l = lambda x, i: [x * (x - 1) / 2, 1 - x * x, x * (x + 1) / 2][i + 1]
    d = lambda x, i: [x - 0.5, -2 * x, x + 0.5][i + 1]
    out = np.zeros((27, 3))
    for a, p in enumerate(P):
        L = [l(xi[k], p[k]) for k in range(3)]
        D = [d(xi[k], p[k]) for k in range(3)]
        out[a] = [D[0] * L[1] * L[2], L[0] * D[1] * L[2], L[0] * L[1] * D[2]]
    return out


g = np.linspace(-1, 1, 9)
GRID = [dshape((a, b, c)) for a in g for b in g for c in g]
CENTRE = dshape((0, 0, 0))
q = np.sqrt(0.6)
GAUSS = [dshape((a, b, c)) for a in (-q, 0, q) for b in (-q, 0, q) for c in (-q, 0, q)]


def analyse(vtu):
    m = meshio.read(vtu)
    cells = [c for c in m.cells if c.type == "hexahedron27"][0].data
    X = m.points
    x = X + m.point_data["displacement"]
    least_j, least_s, least_det_f = np.inf, np.inf, np.inf
    for c in cells:
        jc = np.linalg.det(x[c].T @ CENTRE)
        least_j = min(least_j, min(np.linalg.det(x[c].T @ d) for d in GRID) / jc)
        for d in GAUSS:
            F = (x[c].T @ d) @ np.linalg.inv(X[c].T @ d)
            J = np.linalg.det(F)
            least_s = min(least_s, np.linalg.svd(F, compute_uv=False)[-1] * J ** (-1 / 3))
            least_det_f = min(least_det_f, J)
    return least_j, least_s, least_det_f


for out in sys.argv[1:]:
    steps = json.load(open(os.path.join(out, "result.json")))["scenes"]["free"]["steps"]
    for k, st in enumerate(steps):
        if st["p_kPa"] < -9.9:
            lj, ls, lf = analyse(os.path.join(out, "free", "step_%03d.vtu" % k))
            print("%-10s p %8.3f kPa  theta %7.3f deg  least relative det J %.3f  least isochoric stretch %.3f  least det F %.3f"
                  % (os.path.basename(out.rstrip("/")), st["p_kPa"], st["theta_deg"], lj, ls, lf))
