#!/usr/bin/env python3
"""The reduced model's error on designs re-run at full order (the top-20 spot checks).

usage: python3 spotcheck.py ROM_ROWS.jsonl[.gz] FULL_ROWS.jsonl[.gz] [--mode combined|pure-twist] > check.json

For every grid index in FULL_ROWS that ROM_ROWS also holds: Omega by the letter's rule, its
pressure, |theta|max and |tau|max of both, and the relative differences (reduced - full) / full;
then the largest and median absolute differences and feasibility agreement.
"""
import gzip, json, statistics, sys

def read(path):
    op = gzip.open if path.endswith(".gz") else open
    out = {}
    with op(path, "rt") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut by an interruption
            out[r["index"]] = r
    return out

args = [a for a in sys.argv[1:] if not a.startswith("--")]
mode = None
if "--mode" in sys.argv:
    mode = sys.argv[sys.argv.index("--mode") + 1]
    args = [a for a in args if a != mode]
rom, full = read(args[0]), read(args[1])

def vals(r):
    m = r["modes"][mode] if mode else r
    return {"omega_J_m3": m.get("omega_J_m3"), "p_omega_kPa": m.get("p_omega_kPa"), "theta_max_deg": m.get("theta_max_deg"),
            "tau_max_Nm": m.get("tau_max_Nm"), "feasible": m.get("feasible")}

rows = []
for i in sorted(full):
    if i not in rom:
        continue
    a, b = vals(rom[i]), vals(full[i])
    rel = {k: (a[k] - b[k]) / abs(b[k]) if a[k] is not None and b[k] not in (None, 0) else None for k in ("omega_J_m3", "p_omega_kPa", "theta_max_deg", "tau_max_Nm")}
    ind = max((s.get("rom_indicator") or 0.0) for s in rom[i].get("scenes", {}).values())
    rows.append({"index": i, "design": full[i]["design"], "rom": a, "full": b, "rel_diff": rel, "rom_indicator": ind,
                 "status_full": full[i]["status"], "status_rom": rom[i]["status"]})

def stat(k):
    v = [abs(r["rel_diff"][k]) for r in rows if r["rel_diff"][k] is not None]
    return {"max": max(v), "median": statistics.median(v)} if v else None

out = {
    "rom_rows": args[0], "full_rows": args[1], "mode": mode or "primary", "compared": len(rows),
    "not_in_rom_rows": sorted(set(full) - set(rom)),
    "abs_rel_diff": {k: stat(k) for k in ("omega_J_m3", "p_omega_kPa", "theta_max_deg", "tau_max_Nm")},
    "feasibility_agrees": sum(r["rom"]["feasible"] == r["full"]["feasible"] for r in rows),
    "rows": rows,
}
json.dump(out, sys.stdout, indent=1)
print()
