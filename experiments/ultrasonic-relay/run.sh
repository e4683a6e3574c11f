#!/usr/bin/env bash
# The light a fibre at the far face collects through 3 mean free paths: no ultrasound, the default
# waveguide, the drive designed for the fibre; a lens focusing the beam on the fibre instead, and
# the lens with a drive designed for it. See README.md.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
mkdir -p out
# the lens: the same beam, each ray aimed at the fibre's centre
python3 - <<'PY'
text = open("scene.toml").read()
lens = text.replace("radius = 2.0\n", "radius = 2.0\nfocus = [0.0, 0.0, 15.5]\n", 1)
open("out/default.toml", "w").write(text)
open("out/lens_default.toml", "w").write(lens)
PY
# designs stop at their iteration limit (exit 3) as often as they converge
"$bin" design out/default.toml --out out/design --quiet || [ $? -eq 3 ]
"$bin" design out/lens_default.toml --out out/lens_design --quiet || [ $? -eq 3 ]
python3 - <<'PY'
import json, re

def drive(text, design, zero=False):
    d = json.load(open(design)) if design else None
    p = {q["name"]: q["designed"] for q in d["parameters"]} if d else {}
    text = text[: text.index("[design]")]
    if p:
        text = text.replace("frequency = 813e3", f"frequency = {p['profiles[0].frequency']!r}")
    for j in range(4):
        v = 0.0 if zero else p.get(f"profiles[0].amplitude_{j}", 2e6)
        text = re.sub(r"amplitude = 2e6,", f"amplitude = {v!r},", text, count=1)
    return text

for name, base, design, zero in [
    ("none", "default", None, True),
    ("default", "default", None, False),
    ("designed", "default", "out/design/render_design.json", False),
    ("lens", "lens_default", None, True),
    ("lens_default", "lens_default", None, False),
    ("lens_designed", "lens_default", "out/lens_design/render_design.json", False),
]:
    text = open(f"out/{base}.toml").read()
    open(f"out/{name}.render.toml", "w").write(drive(text, design, zero))
PY
for case in none default designed lens lens_default lens_designed; do
    # a fresh seed, away from the designs' evaluations and checks
    "$bin" render "out/$case.render.toml" --out "out/$case" --samples "$samples" --seed 20261126 --quiet
done
python3 summarise.py
