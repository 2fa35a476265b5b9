#!/usr/bin/env bash
# Reproduce this study's first run (coarse fidelity only — `optimise.stages=[]` switches off the
# problem's coarse → default stages; MMA and SLSQP from three space-filling starts, at most 12 FE
# evaluations per run: the time available when it was run). Writes history.json, best.json and
# plots into this folder. The multi-fidelity run is run-staged.sh.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release -- optimise problems/energy-density.toml \
    --set 'optimise.stages=[]' --set optimise.max_evaluations=12 \
    --out studies/optimise-energy-density 2>&1 | tee studies/optimise-energy-density/log.txt
