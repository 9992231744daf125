#!/bin/bash
# 16 shards of one generation run as a Slurm array; every task writes its own samples into
# the same folder on a shared filesystem. Resubmitting skips finished samples.
#SBATCH --job-name=assist-generate
#SBATCH --array=0-15
#SBATCH --cpus-per-task=2
#SBATCH --mem=8G
set -euo pipefail
assist generate --spec generate.toml --out /shared/assist-gen   # shard from SLURM_ARRAY_*
# When the array is done:  assist generate merge /shared/assist-gen
