#!/usr/bin/env bash
# The translucent ring-and-bead ornament of configs/render_sdf.toml with its index graded by depth
# (1.1 at the surface to 1.5 inside) and with a constant index of 1.3, rendered alike.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/lightpath
[ -x "$bin" ] || (cd ../.. && cargo build --release)
samples=${SAMPLES:-100000}
sed 's/profiles = \[{ kind = "sdf_luneburg".*\]/profiles = [{ kind = "constant", n = 1.3 }]/' \
    ../../configs/render_sdf.toml > out/homogeneous.toml
cp ../../configs/render_sdf.toml out/graded.toml
for case in graded homogeneous; do
    "$bin" render "out/$case.toml" --out "out/$case" --samples "$samples" --quiet
    python3 - "$case" <<'PY'
import json, sys
case = sys.argv[1]
r = json.load(open(f"out/{case}/render.json"))
screen = {s["name"]: s["power"] for s in r["sensors"]}["floor_light"]
view = {c["name"]: c for c in r["cameras"]}["view"]["irradiance"]
floor = {s["name"]: s for s in r["surfaces"]}["floor"]["incident"]
st = r["statistics"]
print(f"| {case} | {screen['mean']:.4f} ± {screen['stderr']:.4f} | {floor['mean']:.4f} ± {floor['stderr']:.4f} "
      f"| {view['mean']:.4e} ± {view['stderr']:.1e} | {st['events_per_photon']:.2f} | {st['steps_per_photon']:.0f} "
      f"| {r['seconds']:.1f} |")
PY
done
