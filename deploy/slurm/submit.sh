#!/usr/bin/env bash
# Submit a lightpath run as a Slurm job array of shards plus a merge job that starts once every
# shard has succeeded:
#   deploy/slurm/submit.sh COMMAND CONFIG OUT SHARDS [lightpath options...]
# e.g. deploy/slurm/submit.sh covariance scene.toml runs/big 64 --samples 100000000
# Shard i writes OUT/shard-i/state.bin (and checkpoint.bin while it runs); the merged results go to
# OUT/merged, bit-identical to one run. Prints the array's and the merge's job ids.
# LIGHTPATH (default: lightpath on PATH, else target/release/lightpath) picks the binary;
# SBATCH_OPTIONS adds sbatch options (partition, time limit, account) to both jobs.
set -euo pipefail
if [[ $# -lt 4 ]]; then
    sed -n '2,9p' "$0" >&2
    exit 2
fi
command=$1 config=$2 out=$3 shards=$4
shift 4
here=$(cd "$(dirname "$0")" && pwd)
bin=${LIGHTPATH:-$(command -v lightpath || echo "$here/../../target/release/lightpath")}
bin=$(realpath "$bin")
config=$(realpath "$config")
mkdir -p "$out"
out=$(realpath "$out")
export LP_BIN="$bin" LP_COMMAND="$command" LP_CONFIG="$config" LP_OUT="$out" \
    LP_SHARDS="$shards" LP_ARGS="$*"
# shellcheck disable=SC2086 # SBATCH_OPTIONS holds several options
array=$(sbatch --parsable ${SBATCH_OPTIONS:-} --job-name "lightpath-$command" \
    --array "0-$((shards - 1))" --output "$out/slurm-%A_%a.log" --export ALL \
    "$here/shard.sbatch")
# shellcheck disable=SC2086
merge=$(sbatch --parsable ${SBATCH_OPTIONS:-} --job-name "lightpath-merge" \
    --dependency "afterok:${array%%;*}" --output "$out/slurm-merge-%j.log" --export ALL \
    "$here/merge.sbatch")
echo "$array $merge"
