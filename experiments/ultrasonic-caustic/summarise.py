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
# noise per second: the screen's median relative pixel error, and the time it implies for 5 %
# (noise ∝ 1/√time) on this 32² screen and on a 512² image of the same face (16² times the pixels:
# at a fixed photon count each pixel's error grows 16×, so 256× the time)
for case, r in runs.items():
    screen = next(s for s in r["sensors"] if s["name"] == "depth_30mm")
    noise = screen.get("pixel_noise")
    if noise:
        t5 = r["seconds"] * (noise / 0.05) ** 2
        print(f"{case}: screen pixel noise {noise:.3f}; 5 % needs {t5:.0f} s on this machine at "
              f"32², {t5 * 256 / 3600:.1f} h at 512²")
