#!/usr/bin/env bash
# The CalculiX side of the vacuum cross-check (issue 19), as far as it was taken: twistopt's
# decks of the example design (coarse mesh, full 360°) under vacuum, with and without a
# frictionless self-contact pair on the cavity surface, each ccx run cut off after LIMIT s.
# What they gave is in ../README.md (§ CalculiX under vacuum). Usage, from the project root:
#   bash studies/vacuum/ccx-contact/attempt.sh [OUT_DIR] [LIMIT_S]
set -euo pipefail
out=${1:-out/ccx-contact}
limit=${2:-300}
bin=${TWISTOPT_BIN:-target/release/twistopt}
p='load.pressures_kPa=[-10,-20,-30,-40,-50]'
contact='*SURFACE INTERACTION, NAME=SI\n*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR\n10.0\n*CONTACT PAIR, INTERACTION=SI, TYPE=SURFACE TO SURFACE\nCAVITY, CAVITY\n'
run() { # dir job
  (cd "$1" && OMP_NUM_THREADS=1 timeout "$limit" ccx -i "$2" > "$2.log" 2>&1 || true)
  local t; t=$(grep "actual step time" "$1/$2.log" | tail -1 | awk -F= '{print $2}')
  local st; st=$(grep -c "^ *S T E P" "$1/$2.log" || true)
  echo "$1/$2: step $st, step time ${t:-none} (pressure = step time × the step's end pressure)"
}
for scene in free blocked; do
  for el in C3D20R C3D20; do
    d="$out/$scene-$el"
    "$bin" export problems/vacuum-contact.toml --scene "$scene" --element "$el" --set "$p" --out "$d" > /dev/null
    # the same deck with the cavity surface in contact with itself (face-to-face penalty)
    sed "0,/^\*RIGID BODY/s//${contact//\//\\/}*RIGID BODY/" "$d/$scene.inp" > "$d/${scene}-contact.inp"
    run "$d" "$scene"
    run "$d" "${scene}-contact"
  done
done
