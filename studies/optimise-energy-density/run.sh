#!/usr/bin/env bash
# Reproduce this study: maximise the combined-mode energy density (problems/energy-density.toml)
# with MMA and SLSQP from three space-filling starts, each run coarse (≤ 50 evaluations) → default
# mesh (≤ 40), then map Ω over (α, l) at the best r and p on the coarse mesh with the design
# paths. Writes history.json, best.json, objective/constraint/map plots and log.txt here.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release -- optimise problems/energy-density.toml --map 7x6 \
    --out studies/optimise-energy-density "$@" 2>&1 | tee studies/optimise-energy-density/log.txt
