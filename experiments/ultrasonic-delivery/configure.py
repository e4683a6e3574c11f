"""Writes the run's configs into out/ from default.toml (scene.toml.in at 2 MPa per element):

    python3 configure.py full           out/full_design.toml: the design's parameters extended
                                        to the elements' phases and radial placements
    python3 configure.py designed NAME  out/NAME.toml: the default with the drive, phases and
                                        placement out/NAME_design/render_design.json found
    python3 configure.py lens           out/lens.toml: no ultrasound, the beam focused on the
                                        25 mm target by a lens outside the medium
    python3 configure.py continued      out/continued_design.toml: the full design again for 40
                                        steps, starting where out/full_design ended
"""
import json
import math
import re
import sys

ELEMENTS = [(10.0, 0.0), (0.0, 10.0), (-10.0, 0.0), (0.0, -10.0)]
PI = 3.14159


def elements(amplitudes, phases, positions):
    lines = [
        f"  {{ position = [{x!r}, {y!r}], amplitude = {a!r}, phase_deg = {math.degrees(p)!r} }},"
        for (x, y), a, p in zip(positions, amplitudes, phases)
    ]
    return "elements = [\n" + "\n".join(lines) + "\n]"


def with_elements(text, amplitudes, phases, positions):
    return re.sub(r"elements = \[\n(.*\n)*?\]", elements(amplitudes, phases, positions), text, count=1)


def without_design(text):
    return text[: text.index("\n[design]\n") + 1]


default = open("out/default.toml").read()
what = sys.argv[1]
if what == "full":
    more = [f'  {{ name = "profiles[0].phase_{j}", min = {-PI}, max = {PI} }},' for j in range(4)]
    for j, (x, y) in enumerate(ELEMENTS):
        axis, v = ("x", x) if x != 0.0 else ("y", y)
        lo, hi = sorted((math.copysign(6.0, v), math.copysign(14.0, v)))
        more.append(f'  {{ name = "profiles[0].{axis}_{j}", min = {lo}, max = {hi} }},')
    last = '  { name = "profiles[0].amplitude_3", min = 0.0, max = 4e6 },\n'
    assert last in default
    open("out/full_design.toml", "w").write(default.replace(last, last + "\n".join(more) + "\n"))
elif what in ("designed", "continued"):
    name = sys.argv[2] if what == "designed" else "full"
    d = json.load(open(f"out/{name}_design/render_design.json"))
    p = {q["name"].removeprefix("profiles[0]."): q["designed"] for q in d["parameters"]}
    amplitudes = [p.get(f"amplitude_{j}", 2e6) for j in range(4)]
    phases = [p.get(f"phase_{j}", 0.0) for j in range(4)]
    positions = [(p.get(f"x_{j}", x), p.get(f"y_{j}", y)) for j, (x, y) in enumerate(ELEMENTS)]
    if what == "designed":
        text = with_elements(default, amplitudes, phases, positions)
        text = text.replace("frequency = 813e3", f"frequency = {p['frequency']!r}")
        open(f"out/{name}.toml", "w").write(without_design(text))
    else:
        text = with_elements(open("out/full_design.toml").read(), amplitudes, phases, positions)
        text = text.replace("frequency = 813e3", f"frequency = {p['frequency']!r}")
        assert "iterations = 60" in text
        text = text.replace("iterations = 60", "iterations = 40")
        open("out/continued_design.toml", "w").write(text)
elif what == "lens":
    text = with_elements(default, [0.0] * 4, [0.0] * 4, ELEMENTS)
    text = text.replace("radius = 2.0\n", "radius = 2.0\nfocus = [0.0, 0.0, 10.0]\n", 1)
    assert "focus" in text
    open("out/lens.toml", "w").write(without_design(text))
else:
    sys.exit(__doc__)
