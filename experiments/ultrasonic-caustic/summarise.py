"""Power through the spot and between-spot windows with the ultrasound on and off (render.json)."""
import json
import math

runs = {case: json.load(open(f"out/{case}/render.json")) for case in ("on", "off")}
power = {case: {s["name"]: s["power"] for s in r["sensors"]} for case, r in runs.items()}


def total(case, names):
    mean = sum(power[case][n]["mean"] for n in names)
    stderr = math.sqrt(sum(power[case][n]["stderr"] ** 2 for n in names))
    return mean, stderr


spots = ["spot_east", "spot_north", "spot_west", "spot_south"]
between = ["between_ne", "between_sw"]
print("| window | ultrasound on | off | on / off |")
print("| --- | --- | --- | --- |")
for label, names in [("4 spots", spots), ("2 between", between), ("whole face (4×4 mm screen)", ["depth_30mm"])]:
    (a, sa), (b, sb) = total("on", names), total("off", names)
    ratio = a / b
    sr = ratio * math.hypot(sa / a, sb / b)
    print(f"| {label} | {a:.4e} ± {sa:.1e} | {b:.4e} ± {sb:.1e} | {ratio:.3f} ± {sr:.3f} |")
for case, r in runs.items():
    st = r["statistics"]
    print(f"{case}: {r['samples']} photons, {st['events_per_photon']:.2f} events and "
          f"{st['steps_per_photon']:.0f} steps per photon, {r['seconds']:.1f} s")
