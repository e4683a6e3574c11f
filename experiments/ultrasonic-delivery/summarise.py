"""Delivered fluence vs depth for the three drives, and the gains, from out/*/render.json."""
import json

cases = ["none", "default", "designed"]
runs = {c: json.load(open(f"out/{c}/render.json")) for c in cases}
design = json.load(open("out/design/render_design.json"))
print("designed drive:")
for p in design["parameters"]:
    print(f"  {p['name']}: {p['start']:.4g} -> {p['designed']:.4g}")
print()
print("| depth | no waveguide | default waveguide | designed | designed / none | designed / default |")
print("| --- | --- | --- | --- | --- | --- |")
for i, t in enumerate(runs["none"]["targets"]):
    f = {c: runs[c]["targets"][i]["fluence"] for c in cases}
    def ratio(a, b):
        r = f[a]["mean"] / f[b]["mean"]
        e = r * ((f[a]["stderr"] / f[a]["mean"]) ** 2 + (f[b]["stderr"] / f[b]["mean"]) ** 2) ** 0.5
        return f"{r:.3f} ± {e:.3f}"
    cells = " | ".join(f"{f[c]['mean']:.4e} ± {f[c]['stderr']:.1e}" for c in cases)
    print(f"| {t['name'].removeprefix('depth_')} | {cells} | {ratio('designed', 'none')} | {ratio('designed', 'default')} |")
