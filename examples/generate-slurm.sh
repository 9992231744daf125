#!/bin/bash
# 16 shards of one generation run as a Slurm array; every task writes its own samples into
# the same folder on a shared filesystem (docs/cluster.md). A resubmitted task remakes only
# what does not hold; a finished shard does nothing.
#SBATCH --job-name=assist-generate
#SBATCH --array=0-15
#SBATCH --cpus-per-task=2
#SBATCH --mem=8G
set -euo pipefail
export RAYON_NUM_THREADS="${SLURM_CPUS_PER_TASK:-2}"
assist generate --spec generate.toml --out /shared/assist-gen   # shard from SLURM_ARRAY_*
# Which shards are complete, partial or missing:  assist generate status /shared/assist-gen
# Resubmit only those:  sbatch --array=$(assist generate status /shared/assist-gen --rerun) generate-slurm.sh
# When every shard is complete:  assist generate merge /shared/assist-gen
