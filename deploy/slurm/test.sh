#!/usr/bin/env bash
# End-to-end check on a real (one-node) Slurm: start it (single-node.sh), run a covariance, a
# speckle, a wave-solver and a refractive render run as 4-shard job arrays with dependent merges,
# and compare the merged results with one run on this machine, number for number. Needs root;
# prints the timings.
#   deploy/slurm/test.sh
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
cd "$root"
cargo build --release --quiet
"$here/single-node.sh" >/dev/null
work=$(mktemp -d /tmp/lightpath-slurm.XXXXXX)
cat > "$work/scene.toml" <<'CONF'
wavelength = 1.0
[medium]
box = [8.0, 8.0, 4.0]
mfp = 2.0
albedo = 0.95
phase = { kind = "hg", g = 0.5 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field_ring"
start = [0.0, 0.0, 1.0]
axis = [0.0, 1.0, 0.0]
count = 12
[speckle]
realisations = 8
paths = 20000
[render]
samples = 400000
chunk = 1000
seed = 11
CONF
status=0
# command, config, result file, options
runs=(
    "covariance $work/scene.toml covariance.json"
    "speckle $work/scene.toml speckle.json"
    "wave $root/experiments/wave-vs-mc/od2.toml covariance.json --realizations 64"
    "render $root/configs/render_tank.toml render.json --samples 200000"
)
for run in "${runs[@]}"; do
    read -r command config file options <<<"$run"
    # shellcheck disable=SC2086 # options holds several words
    t0=$(date +%s.%N)
    target/release/lightpath "$command" "$config" --out "$work/single-$command" --quiet $options >/dev/null
    t1=$(date +%s.%N)
    # shellcheck disable=SC2086
    read -r array merge < <(LIGHTPATH=target/release/lightpath \
        "$here/submit.sh" "$command" "$config" "$work/slurm-$command" 4 $options)
    while squeue -h -j "${array%%;*},$merge" 2>/dev/null | grep -q .; do
        sleep 1
    done
    t2=$(date +%s.%N)
    state=$(sacct -n -X -j "$merge" -o State 2>/dev/null | tr -d ' ' || true)
    if python3 - "$work/single-$command/$file" "$work/slurm-$command/merged/$file" <<'PY'
import json, sys
timings = {"seconds", "version", "photons_per_second", "steps_per_second"}
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if k not in timings}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x
a, b = (strip(json.load(open(p))) for p in sys.argv[1:3])
sys.exit(0 if a == b else 1)
PY
    then
        printf '%s: 4 Slurm shards merged equal one run (one run %.1f s; submit to merged %.1f s)\n' \
            "$command" "$(awk "BEGIN { print $t1 - $t0 }")" "$(awk "BEGIN { print $t2 - $t1 }")"
    else
        echo "$command: merged Slurm result differs from one run (merge job: ${state:-unknown}); see $work" >&2
        status=1
    fi
done
"$here/single-node.sh" stop
exit $status
