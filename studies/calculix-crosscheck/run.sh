#!/usr/bin/env bash
# twistopt vs CalculiX (ccx 2.20, C3D20R) on three designs at three mesh sizes, free and blocked
# scenes at 40 kPa; both codes run one after the other in the same process (crosscheck), so
# their wall times are measured under the same load. Keeps crosscheck.json.
#   bash studies/calculix-crosscheck/run.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release --quiet
BIN=target/release/twistopt
OUT=studies/calculix-crosscheck/runs
declare -A DESIGNS=(
  [example]="8.660254037844386 10 60"
  [alpha240]="8.660254037844386 12 240"
  [r13]="13.2 14 120"
)
for name in example alpha240 r13; do
  read -r r l a <<<"${DESIGNS[$name]}"
  for mesh in 12x4x1 24x8x1 24x8x2; do
    d="$OUT/$name/$mesh"
    echo "== $name (r=$r l=$l alpha=$a) mesh $mesh"
    $BIN crosscheck problems/paper-example.toml \
      --set design.r_mm=$r --set design.l_mm=$l --set design.alpha_deg=$a \
      --set fidelity.mesh=$mesh --set "load.pressures_kPa=[40]" --set output.vtu=false \
      --out "$d"
    # keep the summary (crosscheck.json); drop the deck, ccx's result files and its log
    find "$d" \( -name '*.frd' -o -name '*.dat' -o -name '*.inp' -o -name '*.12d' -o -name '*.cvg' -o -name '*.sta' -o -name 'spooles.out' -o -name '*.log' \) -delete
  done
done
