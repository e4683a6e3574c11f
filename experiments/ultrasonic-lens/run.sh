#!/usr/bin/env bash
# Ultrasonic lens: fit the Bessel model's n_max (and k_r) so a collimated beam focuses at a requested
# depth, for three depths and two beam radii; compare with the paraxial closed form.
# Usage: experiments/ultrasonic-lens/run.sh [OUT]   (from the repository root; ~1 min on 2 cores)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-runs/ultrasonic-lens}"
mkdir -p "$out"
cargo build --release -q
bin=target/release/lightpath
for depth in 20 30 40; do
  for radius in 0.05 0.3; do
    name="d${depth}_r${radius}"
    python3 - "$here/focus_30mm.toml" "$out/$name.toml" "$depth" "$radius" <<'PY'
import sys
src, dst, depth, radius = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
t = open(src).read()
t = t.replace("half_length = 15.0", f"half_length = {depth / 2}")
t = t.replace("center = [0.0, 0.0, -16.0]", f"center = [0.0, 0.0, {-depth / 2 - 1}]")
t = t.replace("focus = [0.0, 0.0, 15.0]", f"focus = [0.0, 0.0, {depth / 2}]")
t = t.replace("radius = 0.3\n", f"radius = {radius}\n")
open(dst, "w").write(t)
PY
    "$bin" design "$out/$name.toml" --out "$out/$name" --quiet
  done
done
"$bin" design "$here/focus_30mm_nmax_kr.toml" --out "$out/both" --quiet
python3 "$here/summarise.py" "$out"
