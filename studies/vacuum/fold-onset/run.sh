#!/usr/bin/env bash
# Where the example design's vacuum ramp ends (the first element folded between its quadrature
# points) on meshes of different size, free scene: `studies/vacuum/README.md` § Where the ramp ends.
# Writes out/fold-onset/<mesh>/ and prints element_quality.py's table. About 2 CPU h in all
# (24x32x2 alone about 18 min, 24x48x2 about 35 min).
set -euo pipefail
cd "$(dirname "$0")/../../.."
cargo build --release
mkdir -p out
sed 's/^preset = "coarse"/# mesh set per run/' problems/vacuum-contact.toml > out/fold-onset.toml
for m in 24x8x1 24x8x2 24x8x3 36x8x3 48x8x2 24x16x1 24x16x2 24x32x2 48x16x2; do
  target/release/twistopt evaluate out/fold-onset.toml --set "fidelity.mesh=\"$m\"" --set 'scenes.run=["free"]' --out "out/fold-onset/$m"
done
# 48 along: the default reach of 20 mm needs more than 23 GB; 8 mm gives the same ramp on 24x32x2
for m in 24x32x2 24x48x2; do
  target/release/twistopt evaluate out/fold-onset.toml --set "fidelity.mesh=\"$m\"" --set 'scenes.run=["free"]' --set 'scenes.contact={reach_mm = 8.0}' --out "out/fold-onset/$m-r8"
done
python3 studies/vacuum/fold-onset/element_quality.py out/fold-onset/*
