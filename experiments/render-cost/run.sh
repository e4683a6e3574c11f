#!/usr/bin/env bash
# What the scenes of the refractive-rendering paper (Figs. 2, 9, 10 in spirit) cost here: each is
# rendered once, and the median pixel noise of its camera image gives the time to a stated noise
# at a stated resolution (the noise falls as 1/√time; per pixel it rises as √pixels).
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
scale=${SCALE:-1}
mkdir -p out
# Fig. 2: the sugar-gradient tank seen from the side
cp tank.toml out/tank.toml
# Fig. 9: the ornament graded by depth, and the same with a constant index
cp ../../configs/render_sdf.toml out/ornament_graded.toml
sed 's/profiles = \[{ kind = "sdf_luneburg".*\]/profiles = [{ kind = "constant", n = 1.3 }]/' \
    ../../configs/render_sdf.toml > out/ornament_homogeneous.toml
# Fig. 10: the crown/flint sphere in white light, and a sphere of crown glass alone
cp ../../configs/render_spectral.toml out/sphere_heterogeneous.toml
sed -e 's/profiles = \[{ kind = "spherical_polynomial".*\]/profiles = [{ kind = "constant", n = 1.5168 }]/' \
    -e 's/inside = \["bk7", "f2"\]/inside = ["bk7"]/' \
    ../../configs/render_spectral.toml > out/sphere_homogeneous.toml
run() {
    "$bin" render "out/$1.toml" --out "out/$1" --samples "$(($2 * scale))" --quiet
}
run tank 400000
run ornament_homogeneous 400000
run ornament_graded 100000
run sphere_homogeneous 400000
run sphere_heterogeneous 200000
python3 summarise.py
