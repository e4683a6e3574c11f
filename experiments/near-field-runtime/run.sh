#!/usr/bin/env bash
# Time to RMSE < 0.01 for the three scenes of paper 000's Table 1 (see README.md).
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
mkdir -p out
for s in small medium large; do
    "$bin" correlation-map "$s.toml" --out "out/$s" --quiet
    ./analyse.py "out/$s"
done
# each against a reference with 20× the paths
for s in small medium large; do
    "$bin" correlation-map "$s.toml" --samples 400000 --out "out/$s-reference" --quiet
    ./analyse.py "out/$s" "out/$s-reference"
done
