#!/usr/bin/env bash
# The closed forms' attenuation bias on paper 000's Table 2 small volume (see README.md): the same
# 4000 paths with the vMF closed forms and with the far-field estimator integrated over the aperture
# (exact attenuation, and paper 000's Eq. 25), then the equal-time rows; about 14 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
mkdir -p out
for a in vmf quadrature quadrature_axis; do
    sed "s/^samples = 4000$/samples = 4000\naperture = \"$a\"/" small.toml > "out/$a.toml"
    "$bin" correlation-map "out/$a.toml" --out "out/$a" --quiet
done
./analyse.py out/vmf out/quadrature out/quadrature_axis
# equal time: the three estimators given 1 s and 60 s against a converged run (Table 2's rows)
./equal_time.py
