#!/bin/bash
# Example Slurm job array: the starts of a multi-start optimisation, one array task per start
# (all optimisers of the problem from that start), then a merge.
#
#   sbatch --array=0-2 studies/optimise-multistart/slurm-array.sh    # optimise.starts = 3
#   # when all tasks are done (or as a dependent job):
#   twistopt optimise-merge out/optimise-multistart/start-* --out out/optimise-multistart/merged
#
# Task I runs `twistopt optimise --start I`: start I of the problem's optimise.starts, the same
# starting point and run names as in a single-process multi-start, into its own directory. A task
# that is killed or preempted (--requeue) resumes when it runs again: the evaluations already in
# its evaluations.jsonl are replayed instead of recomputed (the optimisers are deterministic).
# The merge writes history.json with every run and best.json with the best feasible design over
# them; runs that are missing or unfinished are reported, and `twistopt optimise PROBLEM --resume
# --out MERGED` (same problem and --set options) completes them.
#
# Arguments after the script go to `twistopt optimise` (the same in every task), e.g.
#   sbatch --array=0-2 studies/optimise-multistart/slurm-array.sh --set fidelity.mesh=12x4x1 --optimiser mma
# Environment (exported to the tasks by sbatch): TWISTOPT (binary), PROBLEM, OUT.
# Adjust partition, time and the twistopt path to your cluster.
#
#SBATCH --job-name=twistopt-optimise
#SBATCH --cpus-per-task=2
#SBATCH --mem-per-cpu=1G
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --open-mode=append
#SBATCH --output=slurm-%A_%a.out

set -euo pipefail
: "${SLURM_ARRAY_TASK_ID:?run with sbatch --array=0-(starts-1)}"
TWISTOPT=${TWISTOPT:-target/release/twistopt}
PROBLEM=${PROBLEM:-problems/energy-density.toml}
OUT=${OUT:-out/optimise-multistart}
DIR="$OUT/start-$(printf '%04d' "$SLURM_ARRAY_TASK_ID")"

mkdir -p "$OUT"
# a rerun (requeue after preemption) continues the run recorded in its directory
RESUME=()
if [ -s "$DIR/input.json" ]; then RESUME=(--resume); fi
# the optimisers of one start run in parallel (one thread each)
export RAYON_NUM_THREADS=${SLURM_CPUS_PER_TASK:-1}
srun "$TWISTOPT" optimise "$PROBLEM" \
    --start "$SLURM_ARRAY_TASK_ID" \
    --out "$DIR" \
    "${RESUME[@]}" \
    "$@"

# The merge as a dependent job:
#   sbatch --dependency=afterok:<array job id> --wrap \
#     "$TWISTOPT optimise-merge $OUT/start-* --out $OUT/merged"
