#!/usr/bin/env bash
# The multi-fidelity run: problems/energy-density.toml as it stands (MMA and SLSQP from three
# space-filling starts, each coarse ≤ 50 evaluations → default mesh ≤ 40), then the map of Ω over
# (α, l) at the best r and p with the design paths. Output: studies/optimise-energy-density/staged/
# (evaluations.jsonl grows during the run; history.json and best.json after each finished run).
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p studies/optimise-energy-density/staged
cargo run --release -- optimise problems/energy-density.toml --map 7x6 \
    --out studies/optimise-energy-density/staged "$@" 2>&1 | tee studies/optimise-energy-density/staged/log.txt
