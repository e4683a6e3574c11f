#!/usr/bin/env bash
# Where the wave/Monte Carlo intensity gap lives (optical depth 1 along the beam):
#  - cubes vs wide slabs of the same depth, hence the same density n·λ³ and k·mfp;
#  - the coherent and incoherent field on a line just behind the exit face, centre → edge → outside.
# ~20 min on 2 cores; uncomment the last line for the 30 λ cube (~8 min more).
set -euo pipefail
cd "$(dirname "$0")"
mkdir -p out
lp() { cargo run --release -q -- "$@"; }
# box BX BY BZ with mfp = BZ (optical depth 1 along z), 36 far-field views every 10° in the x-z plane
shape() {
  sed "s/box = \[6.0, 6.0, 6.0\]/box = [$2, $3, $4]/; s/mfp = 3.0/mfp = $4/" od2.toml > "out/$1.toml"
  lp covariance "out/$1.toml" --out "out/$1-mc" --quiet
  lp wave "out/$1.toml" --out "out/$1-wave" --realizations "$5" --quiet
}
shape cube4 4.0 4.0 4.0 8000
shape slab16x4 16.0 16.0 4.0 4000
# denser: the same 804 scatterers in thinner slabs (n·λ³ = π/depth)
shape slab16x2 16.0 16.0 2.0 4000
shape slab16x1 16.0 16.0 1.0 4000
shape cube6 6.0 6.0 6.0 8000
shape slab24x6 24.0 24.0 6.0 1500
shape cube20 20.0 20.0 20.0 800
# point views on the line y = 0, half a wavelength behind the exit face
exit_line() {
  python3 - "$@" <<'PY'
import sys
name, half, depth = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
xs = sys.argv[4:]
views = "".join(f'[[view]]\nkind = "point"\nposition = [{x}, 0.0, {depth / 2 + 0.5}]\n' for x in xs)
open(f"out/{name}.toml", "w").write(f"""wavelength = 1.0
[medium]
box = [{2 * half}, {2 * half}, {depth}]
mfp = {depth}
albedo = 1.0
phase = {{ kind = "isotropic" }}
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
{views}
[render]
samples = 1000000
seed = 1
""")
PY
}
exit_line exit-cube4 2.0 4.0 0.0 0.5 1.0 1.5 1.75 2.0 2.5 3.0
exit_line exit-slab16x4 8.0 4.0 0.0 2.0 4.0 6.0 7.0 7.5 7.75 8.0 8.5 9.0
for name in exit-cube4 exit-slab16x4; do
  lp covariance "out/$name.toml" --out "out/$name-mc" --quiet
done
lp wave out/exit-cube4.toml --out out/exit-cube4-wave --realizations 8000 --quiet
lp wave out/exit-slab16x4.toml --out out/exit-slab16x4-wave --realizations 1500 --quiet
python3 shape.py
# shape cube30 30.0 30.0 30.0 400 && python3 shape.py
