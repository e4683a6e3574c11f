#!/usr/bin/env bash
# Wave solver vs Monte Carlo: the OD 2 comparison with plots, and the density sweep at OD 1.
set -euo pipefail
cd "$(dirname "$0")"
lp() { cargo run --release -q -- "$@"; }
lp wave od2.toml --out out/od2-wave --realizations 3000 --quiet
lp covariance od2.toml --out out/od2-mc --quiet
lp compare out/od2-mc/covariance.json out/od2-wave/covariance.json --plot out/od2-plots || true
# optical depth 1 cubes of side L (density falls as 1/L at fixed optical depth)
for L in 4 6 9 12; do
  sed "s/box = \[6.0, 6.0, 6.0\]/box = [$L.0, $L.0, $L.0]/; s/mfp = 3.0/mfp = $L.0/; s/count = 36/count = 12/" od2.toml > out/od1-L$L.toml
  R=8000; [ $L = 9 ] && R=4000; [ $L = 12 ] && R=2000
  lp wave out/od1-L$L.toml --out out/od1-L$L-wave --realizations $R --quiet
  lp covariance out/od1-L$L.toml --out out/od1-L$L-mc --quiet
done
python3 analyse.py
# the 20 λ cube (~1260 scatterers, ~4 min): uncomment to add it to the table
# sed "s/box = \[6.0, 6.0, 6.0\]/box = [20.0, 20.0, 20.0]/; s/mfp = 3.0/mfp = 20.0/; s/count = 36/count = 12/" od2.toml > out/od1-L20.toml
# lp wave out/od1-L20.toml --out out/od1-L20-wave --realizations 600 --quiet && lp covariance out/od1-L20.toml --out out/od1-L20-mc --quiet
