#!/bin/bash
# A Monte Carlo tolerance study split over a Slurm array job, then merged.
#
#   sbatch examples/slurm/tolerance-array.sh            # 16 shards of a 10,000-trial study
#   # when all shards are done (or: sbatch --dependency=afterok:<jobid> ...):
#   tolray merge results/shard-*.json --json results/report.json --png results/histogram.png
#
# Every shard samples its own disjoint range of trial indices from the same seed, so the merged
# report is exactly the report one big run on one machine gives.
#SBATCH --job-name=tolray-mc
#SBATCH --array=0-15
#SBATCH --cpus-per-task=8
#SBATCH --time=01:00:00
#SBATCH --output=results/slurm-%A_%a.out

set -euo pipefail
N=16
mkdir -p results
export RAYON_NUM_THREADS="${SLURM_CPUS_PER_TASK:-1}"
tolray tolerance lens2 \
    --trials 10000 --seed 7 --compensate focus \
    --fields 0,0.7,1 --pupil grid:32 \
    --shard "${SLURM_ARRAY_TASK_ID}/${N}" \
    --json "results/shard-${SLURM_ARRAY_TASK_ID}.json"
