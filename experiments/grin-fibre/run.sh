#!/usr/bin/env bash
# GRIN fibre: fit a radial polynomial profile that re-images an on-axis point after half a pitch, then
# trace it (and the analytic sech and parabolic fibres of the same pitch) over three half pitches.
# Usage: experiments/grin-fibre/run.sh [OUT]   (from the repository root; a few seconds)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-runs/grin-fibre}"
mkdir -p "$out"
cargo build --release -q
bin=target/release/lightpath
"$bin" design "$here/fibre.toml" --out "$out/fit" --quiet
python3 "$here/analyse.py" "$out" "$bin"
