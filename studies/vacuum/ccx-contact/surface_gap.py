#!/usr/bin/env python3
"""How far apart the facing cavity patches of a ccx vacuum deck are, measured two ways.

twistopt's contact proxy measures the gap from the *nodes* of one wall to flat triangles between
the *nodes* of the other (6 per 8-node face, 8 per 9-node face). The walls themselves are the
quadratic faces, which bulge between their nodes. This script takes a deck written by
`twistopt crosscheck` under vacuum with contact (its pairs C<k>S / C<k>M), removes the contact
pairs, prints the cavity's displacements, runs ccx, and reports for every pair and every step:

  * node gap: the smallest distance from a slave-patch node to the master patch's node triangles
    (what twistopt's contact sees);
  * surface gap: the smallest distance between the two quadratic surfaces, each sampled on an
    M × M grid per face (what ccx's face-to-face contact sees), negative where a slave sample
    point lies inside the master wall.

Only the first pair is measured (the decks' pairs are rotated copies of each other).

Usage (from the project root; needs ccx and numpy):
  python3 studies/vacuum/ccx-contact/surface_gap.py OUT/blocked/blocked.inp WORKDIR [M]
or, on twistopt's own states with contact (no ccx run):
  python3 studies/vacuum/ccx-contact/surface_gap.py OUT/blocked/blocked.inp --positions OUT/blocked/twistopt-deformed.json [M]
"""
import os
import re
import subprocess
import sys

import numpy as np


def read_deck(text):
    nodes = {}
    blk = text.split("*NODE, NSET=NALL\n")[1].split("\n*")[0]
    for line in blk.strip().split("\n"):
        a = line.split(",")
        nodes[int(a[0])] = np.array([float(x) for x in a[1:4]])
    m = re.search(r"\*ELEMENT, TYPE=(C3D20R?), ELSET=EALL\n", text)
    eb = text[m.end():].split("\n*")[0]
    toks = [int(x) for x in re.findall(r"-?\d+", eb)]
    els = {toks[i]: toks[i + 1:i + 21] for i in range(0, len(toks), 21)}
    surfaces = {}
    for m in re.finditer(r"\*SURFACE, NAME=(C\d+[SM]), TYPE=ELEMENT\n((?:\d+, S1\n)+)", text):
        surfaces[m.group(1)] = [int(l.split(",")[0]) for l in m.group(2).strip().split("\n")]
    return nodes, els, surfaces


def face_nodes(els, e):
    # S1 (zeta-) face of a C3D20: corners 1-4, midsides 9-12
    c = els[e]
    return [c[0], c[1], c[2], c[3], c[8], c[9], c[10], c[11]]


TRIS = [(0, 4, 7), (4, 1, 5), (5, 2, 6), (7, 6, 3), (4, 5, 6), (4, 6, 7)]


def shp8(xi, et):
    c = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    n = [0.25 * (1 + a * xi) * (1 + b * et) * (a * xi + b * et - 1) for (a, b) in c]
    n += [0.5 * (1 - xi * xi) * (1 - et), 0.5 * (1 + xi) * (1 - et * et), 0.5 * (1 - xi * xi) * (1 + et), 0.5 * (1 - xi) * (1 - et * et)]
    return np.array(n)


def point_triangle(p, a, b, c):
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return np.linalg.norm(p - a)
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return np.linalg.norm(p - b)
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return np.linalg.norm(p - (a + d1 / (d1 - d3) * ab))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return np.linalg.norm(p - c)
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return np.linalg.norm(p - (a + d2 / (d2 - d6) * ac))
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return np.linalg.norm(p - (b + w * (c - b)))
    den = 1 / (va + vb + vc)
    return np.linalg.norm(p - (a + ab * vb * den + ac * vc * den))


def gaps(x, els, slave, master, m):
    node_gap = min(
        point_triangle(x[n], *(x[face_nodes(els, f)[i]] for i in t))
        for e in slave for n in face_nodes(els, e) for f in master for t in TRIS)
    g = np.linspace(-1, 1, m)

    def grid(e):
        p = np.array([x[n] for n in face_nodes(els, e)])
        return np.array([[shp8(a, b) @ p for b in g] for a in g])

    grids = {f: grid(f) for f in master}
    # each sample's own nearest sub-triangle gives its signed gap; the least of those is the
    # result (before 2026-12-07 the sign was taken at the globally nearest sample only, which
    # hid samples inside the master wall whenever another sample was nearer to it in front)
    signed = np.inf
    for e in slave:
        for p in grid(e).reshape(-1, 3):
            near, sg = np.inf, np.inf
            for f, G in grids.items():
                if np.min(np.linalg.norm(G.reshape(-1, 3) - p, axis=1)) > near + 2.0:
                    continue
                for i in range(m - 1):
                    for j in range(m - 1):
                        a, b, c, d = G[i, j], G[i + 1, j], G[i + 1, j + 1], G[i, j + 1]
                        for t in ((a, b, c), (a, c, d)):
                            dd = point_triangle(p, *t)
                            if dd < near:
                                # the S1 face's (ξ, η) normal points into its element: a point on
                                # that side of the closest sub-triangle is inside the master wall
                                n = np.cross(t[1] - t[0], t[2] - t[0])
                                near, sg = dd, (-dd if (p - t[0]) @ n > 0 else dd)
            signed = min(signed, sg)
    return node_gap, signed


def main():
    if len(sys.argv) > 2 and sys.argv[2] == "--positions":
        return main_positions(sys.argv[1], sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 7)
    deck, work = sys.argv[1], sys.argv[2]
    m = int(sys.argv[3]) if len(sys.argv) > 3 else 7
    text = open(deck).read()
    nodes, els, surfaces = read_deck(text)
    # the same deck without its contact pairs, printing the cavity's displacements
    plain = re.sub(r"\*CONTACT PAIR[^\n]*\n[^\n]*\n", "", text)
    plain = plain.replace("*END STEP", "*NODE PRINT, NSET=CAVITY\nU\n*END STEP")
    os.makedirs(work, exist_ok=True)
    open(os.path.join(work, "plain.inp"), "w").write(plain)
    subprocess.run(["ccx", "-i", "plain"], cwd=work, stdout=open(os.path.join(work, "plain.log"), "w"), stderr=subprocess.STDOUT, check=False)
    dat = open(os.path.join(work, "plain.dat")).read()
    # the pairs of a 3-fold symmetric deck are rotated copies: the first stands for all
    pairs = sorted({k[:-1] for k in surfaces})[:1]
    print("time  pair  node_gap_mm  surface_gap_mm")
    for blk in re.finditer(r"displacements \(vx,vy,vz\) for set CAVITY and time\s+(\S+)\n\n((?:.*\n)+?)\n", dat):
        t = float(blk.group(1))
        if abs(t - round(t)) > 1e-9:
            continue
        u = {int(l.split()[0]): np.array([float(v) for v in l.split()[1:4]]) for l in blk.group(2).strip().split("\n")}
        x = {n: nodes[n] + u.get(n, 0.0) for n in nodes}
        for k in pairs:
            ng, sg = gaps(x, els, surfaces[k + "S"], surfaces[k + "M"], m)
            print(f"{t:4.0f}  {k}  {ng:.4f}  {sg:.4f}", flush=True)


def main_positions(deck, positions, m):
    """The same two gaps on twistopt's own states with contact (`twistopt-deformed.json`, written
    by `crosscheck` next to the deck): every node is kept off the facing wall by the barrier;
    this shows whether the quadratic surfaces between the nodes are."""
    import json
    nodes, els, surfaces = read_deck(open(deck).read())
    d = json.load(open(positions))
    pairs = sorted({k[:-1] for k in surfaces})[:1]
    print("p_kPa  pair  node_gap_mm  surface_gap_mm")
    for p, xs in zip(d["p_kPa"], d["x"]):
        x = {i + 1: np.array(v) for i, v in enumerate(xs)}
        for k in pairs:
            ng, sg = gaps(x, els, surfaces[k + "S"], surfaces[k + "M"], m)
            print(f"{p:6.1f}  {k}  {ng:.4f}  {sg:.4f}", flush=True)


if __name__ == "__main__":
    main()
