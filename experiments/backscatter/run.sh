#!/usr/bin/env bash
# Coherent backscattering (paper 001, Fig. 7): intensity vs angle from exact backscatter, with and
# without reversed paths, for a box of optical depth 8.
set -euo pipefail
cd "$(dirname "$0")"
for v in reversed forward_only; do
  cargo run --release -q -- covariance $v.toml --out out/$v --quiet >/dev/null
done
python3 - <<'PY'
import json
r = json.load(open("out/reversed/covariance.json"))
f = json.load(open("out/forward_only/covariance.json"))
print("angle  reversed            forward-only        ratio")
for a in [0, 1, 2, 3, 5, 7, 10, 15, 20, 30, 45, 60, 71]:
    ir, er = r["re"][0][0][a][a], r["stderr"][0][0][a][a]
    i_f, ef = f["re"][0][0][a][a], f["stderr"][0][0][a][a]
    print(f"{a:5d}  {ir:.4f} ± {er:.4f}   {i_f:.4f} ± {ef:.4f}   {ir/i_f:.3f}")
PY
