"""Spot contrast against drive frequency (render.json of each run)."""
import glob
import json
import math

print("| frequency | spot radius | 4 spots | 2 between | spot / between (per window) |")
print("| --- | --- | --- | --- | --- |")
runs = []
for path in glob.glob("out/f*/render.json"):
    r = json.load(open(path))
    runs.append((r["config"]["field"]["profiles"][0]["frequency"], r))
for freq, r in sorted(runs, key=lambda x: x[0]):
    p = {s["name"]: s["power"] for s in r["sensors"]}

    def total(names):
        return (sum(p[n]["mean"] for n in names),
                math.sqrt(sum(p[n]["stderr"] ** 2 for n in names)))

    (a, sa), (b, sb) = total(["spot_east", "spot_north", "spot_west", "spot_south"]), \
        total(["between_ne", "between_sw"])
    ratio = (a / 4) / (b / 2)
    sr = ratio * math.hypot(sa / a, sb / b)
    radius = 3.0542 / (2 * math.pi * freq / 1480 * 1e-3)
    print(f"| {freq / 1e3:.0f} kHz | {radius:.3f} mm | {a:.4e} ± {sa:.1e} | {b:.4e} ± {sb:.1e} "
          f"| {ratio:.3f} ± {sr:.3f} |")
print(f"{runs[0][1]['samples']} photons each; {sum(r['seconds'] for _, r in runs):.0f} s in all")
