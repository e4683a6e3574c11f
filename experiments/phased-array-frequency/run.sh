#!/usr/bin/env bash
# The four-spot caustic against the drive frequency of a four-element transducer (paper 002,
# Fig. 1 setup, 3 mean free paths).
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
mkdir -p out
for f in ${FREQUENCIES:-500000 650000 813000 1000000 1200000}; do
    # the first maximum of J_2 (k r = 3.0542) and the point at 45° at the same radius
    r=$(python3 -c "import math; print(f'{3.0542 / (2 * math.pi * $f / 1480 * 1e-3):.4f}')")
    d=$(python3 -c "print(f'{$r / 2 ** 0.5:.4f}')")
    sed "s/@FREQ@/$f/; s/@R@/$r/g; s/@D@/$d/g" scene.toml.in > "out/f$f.toml"
    "$bin" render "out/f$f.toml" --out "out/f$f" --samples "$samples" --quiet
done
python3 summarise.py
