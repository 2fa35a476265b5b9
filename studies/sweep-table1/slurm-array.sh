#!/bin/bash
# Example Slurm job array: the Table-I grid in N shards, one array task per shard, then a merge.
#
#   sbatch --array=0-63 studies/sweep-table1/slurm-array.sh          # 64 shards
#   # when all tasks are done (or as a dependent job):
#   twistopt sweep-merge out/sweep-table1/shard-* --out out/sweep-table1/merged
#
# Each task writes its own directory; a task that is killed or preempted (--requeue) resumes
# where it stopped when it runs again (rows already in results.jsonl are skipped). Shard I holds
# the designs whose Table-I index i has i mod N = I, so the shards are balanced in r, l and α.
# Adjust partition, time and the twistopt path to your cluster; check the count first with
#   twistopt sweep studies/sweep-table1/problem.toml --shard 0/64 --count
#
# Arguments after the script go to `twistopt sweep` (the same in every task), e.g. a subsample
# at the coarse mesh, as scripts/cluster-test.sh runs this file on a local single-node Slurm:
#   sbatch --array=0-3 --cpus-per-task=1 studies/sweep-table1/slurm-array.sh --grid every=22 --fidelity coarse
# Environment (exported to the tasks by sbatch): TWISTOPT (binary), PROBLEM, OUT, SHARDS.
#
#SBATCH --job-name=twistopt-sweep
#SBATCH --cpus-per-task=4
#SBATCH --mem-per-cpu=1G
#SBATCH --time=12:00:00
#SBATCH --requeue
#SBATCH --output=slurm-%A_%a.out

set -euo pipefail
: "${SLURM_ARRAY_TASK_ID:?run with sbatch --array=0-(N-1)}"
N=$(( ${SLURM_ARRAY_TASK_MAX:-$SLURM_ARRAY_TASK_ID} + 1 ))   # shards = size of the array (--array=0-(N-1))
N=${SHARDS:-$N}                                                # or export SHARDS=N explicitly
TWISTOPT=${TWISTOPT:-target/release/twistopt}
PROBLEM=${PROBLEM:-studies/sweep-table1/problem.toml}
OUT=${OUT:-out/sweep-table1}

mkdir -p "$OUT"
srun "$TWISTOPT" sweep "$PROBLEM" \
    --shard "${SLURM_ARRAY_TASK_ID}/${N}" \
    --threads "${SLURM_CPUS_PER_TASK:-1}" \
    --out "$OUT/shard-$(printf '%04d' "$SLURM_ARRAY_TASK_ID")" \
    "$@"

# The last task to finish could merge; simpler is a dependent job:
#   sbatch --dependency=afterok:<array job id> --wrap \
#     "$TWISTOPT sweep-merge $OUT/shard-* --out $OUT/merged"
