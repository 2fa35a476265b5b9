#!/usr/bin/env bash
# Reproduce studies/speed-accuracy (issue 9): fidelity variants × five designs, the report, and the
# sweep throughput of the recommended sweep mesh. Resumable: finished (variant, design) pairs in
# results.jsonl and finished sweep designs are skipped on a re-run.
#
#   bash studies/speed-accuracy/run.sh            # everything (≈ 45 CPU min + the sweep's ≈ 10; 75–90 min under load)
#   bash studies/speed-accuracy/run.sh report     # only the report from the committed results
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR=studies/speed-accuracy
cargo build --release --example speed_accuracy --bin twistopt
if [ "${1:-}" != "report" ]; then
  # 1. every (variant, design) pair of the plan, single-threaded, at 25 kPa
  target/release/examples/speed_accuracy run --out "$DIR"
  target/release/examples/speed_accuracy report --out "$DIR"
  # 2. sweep throughput of the recommended sweep mesh on 5 designs of the sample used in
  #    studies/sweep-table1 (every 8th value per axis, shard 0 of 28; a subset of its shard 0 of 7), 2 threads, ramp to failure
  MESH=$(python3 -c "import json;print(json.load(open('$DIR/summary.json'))['recommended']['sweep']['variant'])")
  OUT="$DIR/sweep-throughput/$MESH"
  if [ ! -f "$OUT/time.json" ]; then   # a finished measurement is kept (a re-run would time nothing)
  mkdir -p "$OUT"
  L0=$(cut -d' ' -f1 /proc/loadavg)
  /usr/bin/time -f '%e %U %S' -o "$OUT/time.txt" \
    target/release/twistopt sweep studies/sweep-table1/problem.toml --grid every=8 --shard 0/28 \
      --fidelity "$MESH" --threads 2 --out "$OUT" > "$OUT/run.log" 2>&1
  L1=$(cut -d' ' -f1 /proc/loadavg)
  read -r WALL USR SYS < "$OUT/time.txt"
  printf '{"wall_s": %s, "user_s": %s, "sys_s": %s, "cpu_s": %s, "loadavg": [%s, %s], "command": "twistopt sweep studies/sweep-table1/problem.toml --grid every=8 --shard 0/28 --fidelity %s --threads 2"}\n' \
    "$WALL" "$USR" "$SYS" "$(python3 -c "print($USR+$SYS)")" "$L0" "$L1" "$MESH" > "$OUT/time.json"
  rm -f "$OUT/time.txt" "$OUT"/map_*.png "$OUT"/map_*.svg   # Fig.-5 maps of 5 designs say nothing
  fi
fi
# 3. summary.json, table.md, pareto{,_theta_tau}.{png,svg}
target/release/examples/speed_accuracy report --out "$DIR"
