#!/usr/bin/env bash
# Delivered light vs depth with no waveguide, the default waveguide (2 MPa per element at
# 813 kHz) and the drive designed for the 25 mm target; see README.md.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
mkdir -p out
amplitudes() { sed "s/@A0@/$1/; s/@A1@/$2/; s/@A2@/$3/; s/@A3@/$4/" scene.toml.in; }
amplitudes 2e6 2e6 2e6 2e6 > out/default.toml
"$bin" design out/default.toml --out out/design --quiet || [ $? -eq 3 ]
# the designed drive: frequency and amplitudes from render_design.json
python3 - <<'PY'
import json, re
d = json.load(open("out/design/render_design.json"))
p = {q["name"]: q["designed"] for q in d["parameters"]}
text = open("out/default.toml").read()
text = text.replace("frequency = 813e3", f"frequency = {p['profiles[0].frequency']!r}")
for j in range(4):
    text = re.sub(rf"(amplitude = )2e6(, phase_deg = 0.0 }},?\n)", lambda m, v=p[f'profiles[0].amplitude_{j}']: f"{m.group(1)}{v!r}{m.group(2)}", text, count=1)
open("out/designed.toml", "w").write(text)
PY
# without ultrasound (and without the design table, whose ranges start above zero)
amplitudes 0.0 0.0 0.0 0.0 | sed "/^\[design\]/,\$d" > out/none.toml
for case in none default designed; do
    # a fresh seed, away from the design's iterations and its check
    "$bin" render "out/$case.toml" --out "out/$case" --samples "$samples" --seed 20261126 --quiet
done
python3 summarise.py
