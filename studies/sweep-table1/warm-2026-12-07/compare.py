#!/usr/bin/env python3
"""Compare a sweep's rows with the committed full-grid rows of ../rom-k80 (same reduced model,
earlier warm starts): statuses, feasibility, Omega, cost. Usage: python3 compare.py ROWS.jsonl[.gz]
[OUT.json]"""
import gzip, json, statistics as st, sys, os

def rows(path):
    op = gzip.open if path.endswith('.gz') else open
    with op(path, 'rt') as f:
        return {r['index']: r for r in map(json.loads, f)}

here = os.path.dirname(os.path.abspath(__file__))
old = rows(os.path.join(here, '..', 'rom-k80', 'results.jsonl.gz'))
new = rows(sys.argv[1])
mx = max((r['modes']['combined']['omega_J_m3'] or 0) for r in old.values())
errs, status, feas = [], [], []
for i, r in new.items():
    o = old[i]
    a, b = o['modes']['combined'], r['modes']['combined']
    diff = {k: [o['scenes'][k]['status'], r['scenes'][k]['status']] for k in o['scenes'] if o['scenes'][k]['status'] != r['scenes'][k]['status']}
    if diff:
        status.append({'index': i, 'design': r['design'], 'scenes': diff, 'max_radius_mm': [a['max_radius_mm'], b['max_radius_mm']]})
    if a['feasible'] != b['feasible']:
        feas.append(i)
    if a['omega_J_m3'] and b['omega_J_m3'] and abs(a['omega_J_m3']) > 0.01 * mx:
        errs.append((abs(a['omega_J_m3'] - b['omega_J_m3']) / abs(a['omega_J_m3']), i))
its = lambda r: sum(s['newton_iterations'] for s in r['scenes'].values())
best = max(new.values(), key=lambda r: r['modes']['combined']['omega_J_m3'] or 0)
out = {
    'designs': len(new),
    'status_differences': status,
    'feasibility_differences': feas,
    'omega_compared': len(errs),
    'omega_max_rel_difference': max(errs)[0],
    'omega_max_rel_difference_index': max(errs)[1],
    'omega_median_rel_difference': st.median(e for e, _ in errs),
    'new_seconds_per_design_mean': st.mean(r['wall_time_s'] for r in new.values()),
    'new_newton_iterations_per_design_mean': st.mean(its(r) for r in new.values()),
    'old_seconds_per_design_mean': st.mean(old[i]['wall_time_s'] for i in new),
    'old_newton_iterations_per_design_mean': st.mean(its(old[i]) for i in new),
    'best': {'index': best['index'], 'design': best['design'], 'omega_J_m3': best['modes']['combined']['omega_J_m3'], 'old_omega_J_m3': old[best['index']]['modes']['combined']['omega_J_m3']},
}
text = json.dumps(out, indent=1)
if len(sys.argv) > 2:
    open(sys.argv[2], 'w').write(text + '\n')
print(text)
