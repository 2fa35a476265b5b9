#!/usr/bin/env bash
# Reproduce the letter-calibration study (issue 10): fit each geometry reading's continuous
# parameter (end-tangent angle γ; μ for the diagnostic case) to the letter's simulated figures
# (../shared/reference/paper.json) with SLSQP and adjoint gradients, on the coarse mesh, then
# write table.md, summary.json and the θ(p) plots into this folder. Resumable: finished cases in
# results.jsonl are skipped (delete it to start over). About 30 min on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release --example letter_calibration -- run --out studies/letter-calibration --threads 2 --max-evals 10 "$@"
