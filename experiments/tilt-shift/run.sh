#!/usr/bin/env bash
# The tilt-shift memory effect (paper 000, Fig. 12) and adaptive-optics refocusing (Fig. 13); see
# README.md.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
mkdir -p out
for s in phantom od1 od3 od3-same-transport; do
    /usr/bin/time -f "$s: %e s" "$bin" tilt-shift "$s.toml" --out "out/$s" --quiet
done
