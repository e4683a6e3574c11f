#!/usr/bin/env bash
# Connection statistics against the spatial frequency of the index field (paper 002, Fig. 6 in
# spirit): success rate of Newton from a random start, solves per connection (Alg. 3's restarts),
# iterations per solve, and distinct stationary paths met, for radial wavenumbers 0.25–16 /mm.
set -euo pipefail
cd "$(dirname "$0")"
mkdir -p out
for k in 0.25 0.5 1 2 4 8 16; do
  sed "s/K_R/$k/" scene.toml.in > out/k$k.toml
  cargo run --release -q -- render out/k$k.toml --out out/k$k --quiet >/dev/null
done
python3 - <<'PY'
import json
print("k_r (/mm)  success  solves/connection  iterations/solve  distinct paths  fluence")
for k in ["0.25", "0.5", "1", "2", "4", "8", "16"]:
    d = json.load(open(f"out/k{k}/render.json"))
    c = d["statistics"]["connections"]
    f = d["probes"][0]["fluence"]
    print(f"{k:>9}  {c['success_rate']:7.3f}  {c['solves_per_connection']:17.2f}  "
          f"{c['iterations_per_solve']:16.2f}  {c['distinct_paths']:14.3f}  "
          f"{f['mean']:.3e} ± {f['stderr']:.1e}")
PY
