#!/usr/bin/env bash
# End to end on a real workload manager: a single-node Slurm started here
# (scripts/slurm-local.sh), the project's own job-array scripts submitted to it unchanged.
#
#  1. sweep: studies/sweep-table1/slurm-array.sh as a 4-task array over a 14-design subsample of
#     Table I at the coarse mesh (--grid every=22 --fidelity coarse, ~3 CPU s per design), with
#     a single-process sweep of the same grid beside it as the reference;
#  2. fault: one task is requeued (`scontrol requeue`: SIGTERM/SIGKILL to its processes, as a
#     preemption does) after it wrote its first row and before its last; Slurm reruns it, the
#     shard resumes, skipping the rows it has;
#  3. merge: `sweep-merge` as a job depending on the array (afterok); the merged rows must equal
#     the reference (every field but the wall times), each shard's results.jsonl must hold each
#     of its designs exactly once, the rerun must have skipped the finished rows;
#  4. multi-start optimisation: studies/optimise-multistart/slurm-array.sh, one task per start
#     (torque over α and l, 18x8x1 mesh, 3 starts × MMA and SQP), one task requeued mid-way (its
#     rerun must replay the recorded evaluations and go on), `optimise-merge` as a dependent job;
#     history.json and best.json must equal a single-process multi-start (all but wall times).
#
# The Slurm instance is private to the work directory and stopped on exit, also on failure.
#
#   bash scripts/cluster-test.sh                    # builds target/release/twistopt if needed
#   TWISTOPT=path/to/twistopt CLUSTER_TEST_DIR=DIR bash scripts/cluster-test.sh
#
# Needs root (slurmd), apt-get (installs munge and Slurm if missing) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
T0=$(date +%s)

log() { echo "cluster-test [$(($(date +%s) - T0)) s]: $*"; }
fail() {
    echo "cluster-test: FAILED: $*" >&2
    exit 1
}

if [ -z "${TWISTOPT:-}" ]; then
    TWISTOPT="${CARGO_TARGET_DIR:-$ROOT/target}/release/twistopt"
    [ -x "$TWISTOPT" ] || cargo build --release
fi
TWISTOPT=$(realpath "$TWISTOPT")
[ -x "$TWISTOPT" ] || fail "no twistopt binary at $TWISTOPT"
command -v python3 >/dev/null || fail "python3 is needed (scripts/setup.sh installs it)"

WORK=${CLUSTER_TEST_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/twistopt-cluster.XXXXXX")}
mkdir -p "$WORK"
WORK=$(realpath "$WORK")
rm -rf "$WORK/sweep" "$WORK/optimise"
# the Slurm instance's state (munge's socket path must stay short: under /tmp)
SLURM_DIR=$(mktemp -d /tmp/twistopt-slurm.XXXXXX)
REF_PID=""

cleanup() {
    local rc=$?
    if [ -n "$REF_PID" ] && kill -0 "$REF_PID" 2>/dev/null; then kill "$REF_PID" 2>/dev/null || true; fi
    if [ $rc -ne 0 ] && [ -d "$SLURM_DIR/log" ]; then
        echo "--- squeue / slurmctld log tail (for the failure above) ---" >&2
        SLURM_CONF="$SLURM_DIR/slurm.conf" squeue >&2 2>/dev/null || true
        tail -n 15 "$SLURM_DIR/log/slurmctld.log" >&2 2>/dev/null || true
    fi
    bash "$ROOT/scripts/slurm-local.sh" stop "$SLURM_DIR" || true
    if [ $rc -eq 0 ]; then rm -rf "$SLURM_DIR"; else echo "cluster-test: Slurm state and logs kept in $SLURM_DIR, outputs in $WORK" >&2; fi
    exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

bash scripts/slurm-local.sh start "$SLURM_DIR"
# shellcheck disable=SC1091
. "$SLURM_DIR/env"

# the state of a job or array task ("" once it has left the queue); `sacct` needs accounting,
# which this instance has not: scontrol knows finished jobs for MinJobAge (600 s)
job_state() { scontrol show job "$1" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p' | head -n 1; }

# wait until job $1 (a single job) is COMPLETED; fail on any other end state or after $2 s
wait_completed() {
    local job=$1 limit=$2 t=0 s
    while :; do
        s=$(job_state "$job")
        case "$s" in
            COMPLETED) return 0 ;;
            FAILED | CANCELLED | TIMEOUT | NODE_FAIL | OUT_OF_MEMORY | BOOT_FAIL | DEADLINE) fail "job $job ended $s" ;;
        esac
        t=$((t + 1))
        [ "$t" -le "$limit" ] || fail "job $job not done after $limit s (state '${s:-gone}')"
        sleep 1
    done
}

complete_lines() { if [ -f "$1" ]; then tr -cd '\n' <"$1" | wc -c; else echo 0; fi; }

# ---------------------------------------------------------------- 1-3: sharded sweep + fault
SW="$WORK/sweep"
mkdir -p "$SW/logs"
SWEEP_ARGS=(--grid every=22 --fidelity coarse)
PROBLEM="$ROOT/studies/sweep-table1/problem.toml"
SHARDS=4
N_DESIGNS=$("$TWISTOPT" sweep "$PROBLEM" "${SWEEP_ARGS[@]}" --count | sed -n 's/^grid [^:]*: \([0-9]*\) designs.*/\1/p') ||
    fail "$TWISTOPT sweep --count failed"
[ "${N_DESIGNS:-0}" -ge 8 ] || fail "unexpected grid size '${N_DESIGNS:-}'"
log "sweep: $N_DESIGNS designs in $SHARDS shards through Slurm, and a single-process reference"

# the reference, one process, as a user would run it on one machine (beside the array: 2 cores)
"$TWISTOPT" sweep "$PROBLEM" "${SWEEP_ARGS[@]}" --threads 1 --out "$SW/single" >"$SW/logs/single.log" 2>&1 &
REF_PID=$!

# the project's job-array script, unchanged; one CPU per task (the script asks for 4 by default)
ARRAY=$(cd "$SW" && TWISTOPT="$TWISTOPT" PROBLEM="$PROBLEM" OUT="$SW/out" \
    sbatch --parsable --array=0-$((SHARDS - 1)) --cpus-per-task=1 --mem-per-cpu=500M --open-mode=append \
    --output="$SW/logs/shard-%a.out" "$ROOT/studies/sweep-table1/slurm-array.sh" "${SWEEP_ARGS[@]}")
ARRAY=${ARRAY%%;*}
MERGE=$(cd "$SW" && sbatch --parsable --dependency=afterok:"$ARRAY" --output="$SW/logs/merge.out" \
    --wrap "'$TWISTOPT' sweep-merge '$SW'/out/shard-* --out '$SW/merged'")
MERGE=${MERGE%%;*}
log "submitted array job $ARRAY (tasks 0-$((SHARDS - 1))) and merge job $MERGE (afterok)"

# the fault: requeue the first task seen with 1 <= rows < its shard size
VICTIM="" t=0
while [ -z "$VICTIM" ]; do
    for i in $(seq 0 $((SHARDS - 1))); do
        size=$(((N_DESIGNS - i + SHARDS - 1) / SHARDS))
        rows=$(complete_lines "$SW/out/shard-$(printf '%04d' "$i")/results.jsonl")
        if [ "$rows" -ge 1 ] && [ "$rows" -lt "$size" ] && [ "$(job_state "${ARRAY}_$i")" = RUNNING ]; then
            scontrol requeue "${ARRAY}_$i"
            VICTIM=$i
            log "requeued task ${ARRAY}_$i with $rows of $size rows written"
            break
        fi
    done
    t=$((t + 1))
    [ "$t" -le 1200 ] || fail "no task was seen mid-way within 120 s"
    [ -n "$VICTIM" ] || sleep 0.1
done
# a requeued job waits (BeginTime, about 2 min) before it is eligible again: release it now
for _ in $(seq 1 50); do
    [ "$(job_state "${ARRAY}_$VICTIM")" = PENDING ] && break
    sleep 0.2
done
[ "$(job_state "${ARRAY}_$VICTIM")" = PENDING ] || fail "task ${ARRAY}_$VICTIM did not go back to PENDING after the requeue (state $(job_state "${ARRAY}_$VICTIM"))"
scontrol update JobId="${ARRAY}_$VICTIM" StartTime=now

wait_completed "$MERGE" 900
for i in $(seq 0 $((SHARDS - 1))); do
    s=$(job_state "${ARRAY}_$i")
    [ "$s" = COMPLETED ] || fail "task ${ARRAY}_$i is $s"
done
wait "$REF_PID" || fail "the single-process sweep failed (see $SW/logs/single.log)"
REF_PID=""
log "array, rerun and merge done"

restarts=$(scontrol show job "${ARRAY}_$VICTIM" | sed -n 's/.*Restarts=\([0-9]*\).*/\1/p')
[ "${restarts:-0}" -ge 1 ] || fail "task ${ARRAY}_$VICTIM shows Restarts=${restarts:-?}: it was not rerun"
VLOG="$SW/logs/shard-$VICTIM.out"
runs=$(grep -c "^grid .*shard $VICTIM/$SHARDS" "$VLOG" || true)
[ "$runs" -eq 2 ] || fail "$VLOG shows $runs runs of shard $VICTIM, expected 2 (killed + rerun)"
resumed=$(grep "^grid .*shard $VICTIM/$SHARDS" "$VLOG" | tail -n 1)
echo "$resumed" | grep -Eq "; done [1-9][0-9]*; to run [1-9][0-9]* " ||
    fail "the rerun of shard $VICTIM did not resume mid-way: $resumed"
log "shard $VICTIM rerun: ${resumed#*shard }"

python3 - "$SW" "$SHARDS" "$N_DESIGNS" <<'EOF'
import json, sys
from pathlib import Path

sw, shards, n = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])

def rows(path, strict=True):
    """Rows of a results.jsonl by id, without wall times; each id must appear once."""
    out = {}
    for line in path.read_text().splitlines():
        r = json.loads(line)
        r.pop("wall_time_s")
        for s in r["scenes"].values():
            s.pop("wall_time_s")
        if r["id"] in out:
            sys.exit(f"cluster-test: FAILED: {r['id']} appears twice in {path}")
        out[r["id"]] = r
    return out

ref = rows(sw / "single" / "results.jsonl")
merged = rows(sw / "merged" / "results.jsonl")
if len(ref) != n:
    sys.exit(f"cluster-test: FAILED: the reference has {len(ref)} rows, expected {n}")
union = {}
for i in range(shards):
    part = rows(sw / "out" / f"shard-{i:04d}" / "results.jsonl")
    size = len(range(i, n, shards))
    if len(part) != size or any(r["index"] % shards != i for r in part.values()):
        sys.exit(f"cluster-test: FAILED: shard {i} holds {len(part)} rows (expected its {size} designs)")
    union.update(part)
if union != ref:
    sys.exit("cluster-test: FAILED: the shards' rows differ from the single-process run")
if merged != ref:
    missing = sorted(set(ref) - set(merged)); extra = sorted(set(merged) - set(ref))
    diff = [k for k in ref if k in merged and merged[k] != ref[k]]
    sys.exit(f"cluster-test: FAILED: merged rows differ from the single-process run (missing {missing}, extra {extra}, different {diff})")
bad = [r["id"] for r in ref.values() if r["status"] != "ok"]
print(f"cluster-test: sweep: {len(merged)} merged rows equal the single-process run ({len(ref) - len(bad)} ok, statuses {sorted({r['status'] for r in ref.values()})})")
EOF

# ---------------------------------------------------------------- 4: multi-start optimisation
OP="$WORK/optimise"
mkdir -p "$OP/logs"
OPT_PROBLEM="$ROOT/problems/max-torque.toml"
STARTS=3
OPT_ARGS=(--set fidelity.mesh=18x8x1 --set load.p_max_kPa=20 --set 'optimise.variables=["alpha_deg", "l_mm"]'
    --set 'optimise.optimisers=["mma", "sqp"]' --set "optimise.starts=$STARTS" --set optimise.max_evaluations=15)
log "optimise: $STARTS starts as Slurm tasks, and a single-process multi-start"
"$TWISTOPT" optimise "$OPT_PROBLEM" "${OPT_ARGS[@]}" --out "$OP/single" >"$OP/logs/single.log" 2>&1 &
REF_PID=$!
OARRAY=$(cd "$OP" && TWISTOPT="$TWISTOPT" PROBLEM="$OPT_PROBLEM" OUT="$OP/out" \
    sbatch --parsable --array=0-$((STARTS - 1)) --cpus-per-task=1 --mem-per-cpu=500M \
    --output="$OP/logs/start-%a.out" "$ROOT/studies/optimise-multistart/slurm-array.sh" "${OPT_ARGS[@]}")
OARRAY=${OARRAY%%;*}
OMERGE=$(cd "$OP" && sbatch --parsable --dependency=afterok:"$OARRAY" --output="$OP/logs/merge.out" \
    --wrap "'$TWISTOPT' optimise-merge '$OP'/out/start-* --out '$OP/merged'")
OMERGE=${OMERGE%%;*}
log "submitted array job $OARRAY (tasks 0-$((STARTS - 1))) and merge job $OMERGE (afterok)"

# the fault: requeue the first start seen with an evaluation recorded and a run unfinished
VICTIM="" t=0
while [ -z "$VICTIM" ]; do
    for i in $(seq 0 $((STARTS - 1))); do
        d="$OP/out/start-$(printf '%04d' "$i")"
        n=$(complete_lines "$d/evaluations.jsonl")
        finished=$(grep -Ec '^  [a-z]+ start [0-9]+: ' "$OP/logs/start-$i.out" 2>/dev/null || true)
        if [ "$n" -ge 1 ] && [ "${finished:-0}" -lt 2 ] && [ "$(job_state "${OARRAY}_$i")" = RUNNING ]; then
            scontrol requeue "${OARRAY}_$i"
            VICTIM=$i
            log "requeued task ${OARRAY}_$i with $n evaluations recorded"
            break
        fi
    done
    t=$((t + 1))
    [ "$t" -le 1200 ] || fail "no optimise task was seen mid-way within 120 s"
    [ -n "$VICTIM" ] || sleep 0.1
done
for _ in $(seq 1 50); do
    [ "$(job_state "${OARRAY}_$VICTIM")" = PENDING ] && break
    sleep 0.2
done
[ "$(job_state "${OARRAY}_$VICTIM")" = PENDING ] || fail "task ${OARRAY}_$VICTIM did not go back to PENDING after the requeue"
scontrol update JobId="${OARRAY}_$VICTIM" StartTime=now
wait_completed "$OMERGE" 600
VLOG="$OP/logs/start-$VICTIM.out"
resumed=$(grep -E '^resuming: [1-9][0-9]* recorded evaluations' "$VLOG" || true)
[ -n "$resumed" ] || fail "the rerun of start $VICTIM did not resume its recorded evaluations ($VLOG)"
sed -n '/^resuming: /,$p' "$VLOG" | grep -q '\] evaluation [0-9]*: ' ||
    fail "the rerun of start $VICTIM computed no new evaluation: it was not killed mid-way ($VLOG)"
log "start $VICTIM rerun: $resumed"
wait "$REF_PID" || fail "the single-process optimisation failed (see $OP/logs/single.log)"
REF_PID=""
grep -q "merged $((2 * STARTS)) of $((2 * STARTS)) runs" "$OP/logs/merge.out" || fail "optimise-merge: $(cat "$OP/logs/merge.out")"

python3 - "$OP" <<'EOF'
import json, sys
from pathlib import Path

op = Path(sys.argv[1])
def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if k not in ("wall_time_s", "time_s", "merged_from")}
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v
for f in ["history.json", "best.json"]:
    a = strip(json.loads((op / "single" / f).read_text()))
    b = strip(json.loads((op / "merged" / f).read_text()))
    if a != b:
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        sys.exit(f"cluster-test: FAILED: merged {f} differs from the single-process multi-start in {keys}")
best = json.loads((op / "merged" / "best.json").read_text())
hist = json.loads((op / "merged" / "history.json").read_text())
n = sum(len(r["evaluations"]) for r in hist["runs"])
print(f"cluster-test: optimise: merged {len(hist['runs'])} runs ({n} evaluations) equal the single-process multi-start; "
      f"best {best['objective']:.6g} at alpha = {best['alpha_deg']:.3f}, l = {best['l_mm']:.3f}")
EOF

log "passed"
