#!/usr/bin/env bash
# The letter's example design (r = 5√3 mm, l = 10 mm, α = 60°): FE evaluation of the free and
# blocked scenes from -68 to +71 kPa (problems/paper-example.toml) into out/paper-example/, plus
# the geometry summary, mesh and exports into out/paper-example/geometry/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo run --release -- evaluate problems/paper-example.toml --out out/paper-example
cargo run --release -- geometry --r 8.660254037844386 --l 10 --alpha 60 --out out/paper-example/geometry
echo "example: outputs in out/paper-example (result.json, free.csv, blocked.csv, theta_vs_p.png/svg, tau_vs_p.png/svg, free.pvd, blocked.pvd; geometry/)"
