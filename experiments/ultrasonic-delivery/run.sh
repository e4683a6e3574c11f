#!/usr/bin/env bash
# Delivered light vs depth with no waveguide, an external lens focusing the beam on the 25 mm
# target, the default waveguide (2 MPa per element at 813 kHz), the drive designed for the 25 mm
# target, and the drive, phases and placement designed together; see README.md.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
mkdir -p out
amplitudes() { sed "s/@A0@/$1/; s/@A1@/$2/; s/@A2@/$3/; s/@A3@/$4/" scene.toml.in; }
amplitudes 2e6 2e6 2e6 2e6 > out/default.toml
cp out/default.toml out/drive_design.toml
python3 configure.py full
# a design is made once (delete its folder to make it again): each takes tens of minutes
for design in drive full; do
    if [ ! -f "out/${design}_design/render_design.json" ]; then
        "$bin" design "out/${design}_design.toml" --out "out/${design}_design" --quiet || [ $? -eq 3 ]
    fi
    python3 configure.py designed "$design"
done
# without ultrasound (and without the design table, whose ranges start above zero)
amplitudes 0.0 0.0 0.0 0.0 | sed "/^\[design\]/,\$d" > out/none.toml
python3 configure.py lens
for case in none lens default drive full; do
    # a fresh seed, away from the design's iterations and its check
    "$bin" render "out/$case.toml" --out "out/$case" --samples "$samples" --seed 20261126 --quiet
done
python3 summarise.py
