"""Tabulate the fibre's and the face's light for every case of run.sh (markdown)."""
import json
import math

CASES = [
    ("none", "no ultrasound, collimated beam"),
    ("default", "default waveguide (813 kHz, 2 MPa each)"),
    ("designed", "drive designed for the fibre"),
    ("lens", "lens focused on the fibre, no ultrasound"),
    ("lens_default", "lens + default waveguide"),
    ("lens_designed", "lens + drive designed with the lens"),
]


def power(case, sensor):
    d = json.load(open(f"out/{case}/render.json"))
    p = next(s for s in d["sensors"] if s["name"] == sensor)["power"]
    return p["mean"], p["stderr"]


def ratio(a, b):
    r = a[0] / b[0]
    return r, r * math.hypot(a[1] / a[0], b[1] / b[0])


none = power("none", "fibre")
print("| case | fibre | / no ultrasound | face |")
print("| --- | --- | --- | --- |")
for case, label in CASES:
    f, face = power(case, "fibre"), power(case, "face")
    r = ratio(f, none)
    print(f"| {label} | {f[0]:.4f} ± {f[1]:.4f} | {r[0]:.2f} ± {r[1]:.2f} | {face[0]:.4f} ± {face[1]:.4f} |")
for design in ["design", "lens_design"]:
    d = json.load(open(f"out/{design}/render_design.json"))
    parts = ", ".join(f"{p['name']} {p['designed']:.4g}" for p in d["parameters"])
    print(f"\n{design}: {parts}; {d['convergence']}; {d['seconds']:.0f} s")
