#!/usr/bin/env bash
# Fits from focused covariance targets (see README.md): the target rendered at the truth, then
# `--fit mfp` from MFP 8 λ (g known) and `--fit mfp,g` from MFP 8 λ and g = 0.3.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
mkdir -p out
"$bin" covariance target.toml --out out/target --quiet
# the starting points: the target's scene with another mean free path (and g), another seed
sed -e 's/^mfp = 4.0/mfp = 8.0/' -e 's/^seed = 3/seed = 11/' target.toml > out/guess-mfp.toml
sed -e 's/g = 0.6 }/g = 0.3 }/' out/guess-mfp.toml > out/guess-mfp-g.toml
for fit in mfp mfp,g; do
    name=${fit/,/-}
    "$bin" fit "out/guess-$name.toml" --target out/target/covariance.json --fit "$fit" \
        --out "out/fit-$name" --quiet | tail -4
done
