#!/usr/bin/env bash
# Reproduce studies/optimise-pure-twist: maximise the pure-twist energy density (rigid axle:
# pure-twist + pure-twist-blocked scenes) over r, l, α, p at coarse fidelity, MMA and SLSQP from
# three Halton starts, 25 evaluations per run (the problem's coarse → default stages switched
# off). Run from the repository root.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release -- optimise problems/pure-twist.toml --set 'optimise.stages=[]' --set optimise.max_evaluations=25 \
  --out studies/optimise-pure-twist 2>&1 | tee studies/optimise-pure-twist/log.txt
