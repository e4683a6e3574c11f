"""Delivered fluence vs depth for every case, and the gains, from out/*/render.json."""
import json

cases = {
    "none": "no lens, no waveguide",
    "ideal": "ideal lens",
    "lens": "GRIN lens designed",
    "full": "waveguide designed",
    "lens_full": "GRIN lens + waveguide",
    "joint": "GRIN lens + drive designed together",
}
runs = {c: json.load(open(f"out/{c}/render.json")) for c in cases}
for name in ["lens", "joint"]:
    design = json.load(open(f"out/{name}_design/render_design.json"))
    gain = design["verification"]["gain"]
    print(f"{name} design (its own check: gain {gain['mean']:.3f} ± {gain['stderr']:.3f}):")
    for p in design["parameters"]:
        print(f"  {p['name']}: {p['start']:.4g} -> {p['designed']:.4g}")
print()


def fluence(c, i):
    return runs[c]["targets"][i]["fluence"]


def ratio(a, b, i):
    fa, fb = fluence(a, i), fluence(b, i)
    r = fa["mean"] / fb["mean"]
    e = r * ((fa["stderr"] / fa["mean"]) ** 2 + (fb["stderr"] / fb["mean"]) ** 2) ** 0.5
    return f"{r:.3f} ± {e:.3f}"


print("| depth | " + " | ".join(cases.values()) + " |")
print("| --- |" + " --- |" * len(cases))
names = [t["name"].removeprefix("depth_") for t in runs["none"]["targets"]]
for i, name in enumerate(names):
    cells = " | ".join(f"{fluence(c, i)['mean']:.4e} ± {fluence(c, i)['stderr']:.1e}" for c in cases)
    print(f"| {name} | {cells} |")
print()
pairs = [("lens", "none"), ("ideal", "none"), ("lens", "ideal"), ("full", "lens"), ("lens_full", "lens"), ("joint", "lens"), ("joint", "full")]
print("| depth | " + " | ".join(f"{a} / {b}" for a, b in pairs) + " |")
print("| --- |" + " --- |" * len(pairs))
for i, name in enumerate(names):
    print(f"| {name} | " + " | ".join(ratio(a, b, i) for a, b in pairs) + " |")
