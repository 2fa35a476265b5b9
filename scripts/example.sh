#!/usr/bin/env bash
# The letter's example design (r = 5√3 mm, l = 10 mm, α = 60°): geometry summary, mesh and exports.
# (This becomes `twistopt evaluate problems/paper-example.toml` once the FE model lands.)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo run --release -- geometry --r 8.660254037844386 --l 10 --alpha 60 --out out/paper-example
echo "example: outputs in out/paper-example (summary.json, mesh.vtu, outer.stl, cavity.stl, mesh.inp)"
