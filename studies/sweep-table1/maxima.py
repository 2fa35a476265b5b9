#!/usr/bin/env python3
"""The sweep's maxima beside the letter's Fig.-5 optima, and its 20 best designs by Omega.

usage: python3 maxima.py ROWS.jsonl[.gz] [ROWS ...] > maxima.json

Reads the rows of one or more sweep output directories (shards), keeps one row per grid index,
and reports: the number of rows and statuses, the feasible designs' max |theta|, max |tau| and
max Omega (design and pressure) beside ../../../shared/reference/paper.json's sim_optima_fig5,
the 20 best feasible designs by Omega (the full-order spot checks' list), and the distribution
of the reduced model's error indicator (the larger of the two scenes').
"""
import gzip, json, os, sys

def read(path):
    op = gzip.open if path.endswith(".gz") else open
    with op(path, "rt") as f:
        for line in f:
            line = line.strip()
            if line:
                try:
                    yield json.loads(line)
                except json.JSONDecodeError:
                    pass  # a line cut by an interruption

rows = {}
for p in sys.argv[1:]:
    for r in read(p):
        rows[r["index"]] = r
rows = list(rows.values())
feas = [r for r in rows if r.get("feasible") and r.get("omega_J_m3") is not None]

def best(key, absval=True):
    c = [r for r in feas if r.get(key) is not None]
    if not c:
        return None
    r = max(c, key=lambda r: abs(r[key]) if absval else r[key])
    return {"design": r["design"], "value": r[key], "p_kPa": r.get({"theta_max_deg": "p_theta_max_kPa", "tau_max_Nm": "p_tau_max_kPa", "omega_J_m3": "p_omega_kPa"}[key])}

here = os.path.dirname(os.path.abspath(__file__))
paper_path = os.path.join(here, "../../../shared/reference/paper.json")
paper = json.load(open(paper_path))["sim_optima_fig5"] if os.path.exists(paper_path) else None
ind = sorted(max(s.get("rom_indicator") or 0.0 for s in r.get("scenes", {}).values()) for r in rows if r.get("scenes"))
q = lambda f: ind[min(len(ind) - 1, int(f * (len(ind) - 1)))] if ind else None
statuses = {}
for r in rows:
    statuses[r.get("status", "?")] = statuses.get(r.get("status", "?"), 0) + 1
top = sorted(feas, key=lambda r: -r["omega_J_m3"])[:20]
out = {
    "rows": len(rows),
    "statuses": statuses,
    "feasible": len(feas),
    "sum_of_design_times_s": sum(r.get("wall_time_s", 0.0) for r in rows),
    "max_abs_theta": best("theta_max_deg"),
    "max_abs_tau": best("tau_max_Nm"),
    "max_omega": best("omega_J_m3", absval=False),
    "letter_fig5": paper,
    "rom_indicator": {"median": q(0.5), "p95": q(0.95), "max": q(1.0)},
    "top20_omega": [{"index": r["index"], "design": r["design"], "omega_J_m3": r["omega_J_m3"], "p_omega_kPa": r.get("p_omega_kPa"), "theta_omega_deg": r.get("theta_omega_deg"), "tau_omega_Nm": r.get("tau_omega_Nm")} for r in top],
}
json.dump(out, sys.stdout, indent=1)
print()
