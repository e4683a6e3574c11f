#!/usr/bin/env bash
# Recover a tabulated phase function from speckle intensity correlations of a slab at optical depth
# 3 (paper 004's setup), next to the single-scattering reading of paper 004.
set -euo pipefail
cd "$(dirname "$0")"
lp() { cargo run --release -q -- "$@"; }
python3 make_configs.py
lp covariance truth.toml --samples 400000 --out out/target --quiet
python3 make_target.py out/target/covariance.json out/target.json
time lp fit start.toml --target out/target.json --fit phase --samples 10000 --iterations 300 \
  --learning-rate 0.1 --smooth 0.01 --out out/fit
