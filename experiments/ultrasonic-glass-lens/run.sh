#!/usr/bin/env bash
# Delivered light vs depth through a designed GRIN rod lens before the medium, against no lens,
# an ideal lens, the ultrasonic waveguide designed in ../ultrasonic-delivery, and the lens and
# the waveguide together; see README.md.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
mkdir -p out
python3 configure.py design
# each design is made once (delete out/<name>_design to make it again)
if [ ! -f out/lens_design/render_design.json ]; then
    "$bin" design out/lens_design.toml --out out/lens_design --quiet || [ $? -eq 3 ]
fi
python3 configure.py joint
if [ ! -f out/joint_design/render_design.json ]; then
    "$bin" design out/joint_design.toml --out out/joint_design --quiet || [ $? -eq 3 ]
fi
python3 configure.py renders
for case in none ideal lens full lens_full joint; do
    # a fresh seed, away from the design's iterations and its check
    "$bin" render "out/$case.toml" --out "out/$case" --samples "$samples" --seed 20261126 --quiet
done
python3 summarise.py
