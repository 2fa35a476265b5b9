#!/usr/bin/env bash
# The multi-fidelity pure-twist run: problems/pure-twist.toml as it stands (MMA and SLSQP from
# three space-filling starts, each coarse ≤ 50 evaluations → default mesh ≤ 40), then the map of
# Ω over (α, l) at the best r and p with the design paths. Output: studies/optimise-pure-twist/staged/
# (evaluations.jsonl grows during the run; history.json and best.json after each finished run).
# An interrupted run goes on with `studies/optimise-pure-twist/run-staged.sh --resume` (the recorded
# evaluations are replayed, the log is appended to).
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p studies/optimise-pure-twist/staged
cargo run --release -- optimise problems/pure-twist.toml --map 7x6 \
    --out studies/optimise-pure-twist/staged "$@" 2>&1 | tee -a studies/optimise-pure-twist/staged/log.txt
