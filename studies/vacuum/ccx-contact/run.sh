#!/usr/bin/env bash
# The CalculiX cross-check under vacuum with contact (issue 19), as in ../README.md
# (§ CalculiX under vacuum, with contact). From the project root:
#   bash studies/vacuum/ccx-contact/run.sh [OUT_DIR]
# Writes OUT_DIR/{24x16x1,coarse}/crosscheck.json and the surface-gap tables. About 20 min for
# 24x16x1 and 7 min for the coarse mesh on 2 cores.
set -euo pipefail
out=${1:-out/ccx-contact}
bin=${TWISTOPT_BIN:-target/release/twistopt}
p='load.pressures_kPa=[-10,-20,-30,-35,-40,-45]'
"$bin" crosscheck problems/vacuum-contact.toml --scene blocked --scene free --twistopt-element matched \
  --set fidelity.mesh=24x16x1 --set "$p" --out "$out/24x16x1"
"$bin" crosscheck problems/vacuum-contact.toml --scene blocked --scene free --twistopt-element matched \
  --contact-patch-mm 1.0 --set "$p" --out "$out/coarse"
# node-on-triangle gap (twistopt's contact proxy) against the quadratic surfaces' gap, without contact
python3 studies/vacuum/ccx-contact/surface_gap.py "$out/24x16x1/blocked/blocked.inp" "$out/24x16x1/gap" > "$out/24x16x1/surface_gap.txt"
python3 studies/vacuum/ccx-contact/surface_gap.py "$out/coarse/blocked/blocked.inp" "$out/coarse/gap" > "$out/coarse/surface_gap.txt"
# the same two gaps on twistopt's own states with contact (blocked scene)
python3 studies/vacuum/ccx-contact/surface_gap.py "$out/24x16x1/blocked/blocked.inp" --positions "$out/24x16x1/blocked/twistopt-deformed.json" > "$out/24x16x1/surface_gap_twistopt.txt"
python3 studies/vacuum/ccx-contact/surface_gap.py "$out/coarse/blocked/blocked.inp" --positions "$out/coarse/blocked/twistopt-deformed.json" > "$out/coarse/surface_gap_twistopt.txt"
