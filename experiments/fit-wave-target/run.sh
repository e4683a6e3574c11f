#!/usr/bin/env bash
# Recover the mean free path from a wave-solver covariance: the target is exact wave optics
# (Foldy–Lax, 8000 placements), the model is the Monte Carlo covariance.
set -euo pipefail
cd "$(dirname "$0")"
lp() { cargo run --release -q -- "$@"; }
lp wave truth.toml --out out/wave --realizations 8000 --quiet
time lp fit start.toml --target out/wave/covariance.json --fit mfp --out out/fit --quiet
# the same fit from 2x above and 2x below the truth: one optimum
for m in 12.0 3.0; do
  sed "s/mfp = 9.0/mfp = $m/" start.toml > out/start_$m.toml
  lp fit out/start_$m.toml --target out/wave/covariance.json --fit mfp --out out/fit_$m --quiet
done
