#!/usr/bin/env bash
# Reproduce studies/paper-example: the letter's example design at three mesh fidelities, then the
# fidelity plots and the table in README.md. Run from the repository root.
set -euo pipefail
cd "$(dirname "$0")/../.."
B="cargo run --release --"
$B evaluate problems/paper-example.toml --set fidelity.preset=coarse  --set output.vtu=false --out studies/paper-example/coarse
$B evaluate problems/paper-example.toml --set fidelity.preset=default --set output.vtu=false --out studies/paper-example/default
$B evaluate problems/paper-example.toml --set fidelity.preset=fine    --set output.vtu=false --out studies/paper-example/fine
cargo run --release --example paper_example_study -- studies/paper-example coarse default fine
