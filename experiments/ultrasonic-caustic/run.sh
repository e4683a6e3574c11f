#!/usr/bin/env bash
# Paper 002, Fig. 1 at 3 mean free paths: the four-spot caustic with the ultrasound on and off.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-400000}
mkdir -p out
for case in on off; do
    n_max=$([ "$case" = on ] && echo 1.2e-3 || echo 0.0)
    sed "s/@N_MAX@/$n_max/" scene.toml.in > "out/$case.toml"
    "$bin" render "out/$case.toml" --out "out/$case" --samples "$samples" --quiet
done
python3 summarise.py
