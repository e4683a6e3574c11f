"""Writes the run's configs into out/ from scene.toml.in:

    python3 configure.py design         out/lens_design.toml: no ultrasound, the lens's gradient
                                        designed for the 25 mm target from alpha = 0.05 /mm
    python3 configure.py joint          out/joint_design.toml: from the designed lens and the
                                        default drive (2 MPa per element at 813 kHz), the lens's
                                        gradient, the frequency and the four amplitudes designed
                                        together
    python3 configure.py renders        out/{none,ideal,lens,full,lens_full,joint}.toml (from
                                        out/lens_design and out/joint_design)
"""
import json
import math
import sys

# the waveguide lightpath designed in ../ultrasonic-delivery (drive, phases and placement for
# the 25 mm target; its README's values): frequency, and per element its position, amplitude
# and phase
FULL_FREQUENCY = 674e3
FULL_ELEMENTS = [
    ((11.36, 0.0), 3.26e6, 1.21),
    ((0.0, 11.40), 3.73e6, 1.32),
    ((-11.32, 0.0), 3.83e6, 1.17),
    ((0.0, -11.29), 3.61e6, 1.21),
]
DEFAULT = [((10.0, 0.0), 2e6, 0.0), ((0.0, 10.0), 2e6, 0.0), ((-10.0, 0.0), 2e6, 0.0), ((0.0, -10.0), 2e6, 0.0)]
SILENT = [((10.0, 0.0), 0.0, 0.0), ((0.0, 10.0), 0.0, 0.0), ((-10.0, 0.0), 0.0, 0.0), ((0.0, -10.0), 0.0, 0.0)]
# no lens: the rod's glass replaced by water (index-matched, it does nothing)
NO_LENS = '{ kind = "constant", n = 1.33 }'


def elements(els):
    lines = [
        f"  {{ position = [{x!r}, {y!r}], amplitude = {a!r}, phase_deg = {math.degrees(p)!r} }},"
        for (x, y), a, p in els
    ]
    return "[\n" + "\n".join(lines) + "\n]"


def scene(alpha, frequency, els, lens=True, focus=False, design=False):
    text = open("scene.toml.in").read()
    text = text.replace("@ALPHA@", repr(alpha)).replace("@FREQUENCY@", repr(frequency))
    text = text.replace("@ELEMENTS@", elements(els))
    if not lens:
        rod = f'{{ kind = "parabolic_fibre", n0 = 1.5, alpha = {alpha!r} }}'
        assert rod in text
        text = text.replace(rod, NO_LENS)
    if focus:
        # an ideal lens: each ray of the beam aimed at the 25 mm target
        text = text.replace("radius = 2.0\n", "radius = 2.0\nfocus = [0.0, 0.0, 10.0]\n", 1)
        assert "focus" in text
    if not design:
        text = text[: text.index("\n[design]\n") + 1]
    return text


JOINT = """  { name = "volume[0].profiles[0].alpha", min = 0.01, max = 0.2 },
  { name = "volume[1].profiles[0].frequency", min = 5e5, max = 1.5e6 },
  { name = "volume[1].profiles[0].amplitude_0", min = 0.0, max = 4e6 },
  { name = "volume[1].profiles[0].amplitude_1", min = 0.0, max = 4e6 },
  { name = "volume[1].profiles[0].amplitude_2", min = 0.0, max = 4e6 },
  { name = "volume[1].profiles[0].amplitude_3", min = 0.0, max = 4e6 },
"""


def designed(name):
    d = json.load(open(f"out/{name}_design/render_design.json"))
    return {p["name"]: p["designed"] for p in d["parameters"]}


what = sys.argv[1]
if what == "design":
    open("out/lens_design.toml", "w").write(scene(0.05, 813e3, SILENT, design=True))
elif what == "joint":
    alpha = designed("lens")["volume[0].profiles[0].alpha"]
    text = scene(alpha, 813e3, DEFAULT, design=True)
    lens = '  { name = "volume[0].profiles[0].alpha", min = 0.01, max = 0.2 },\n'
    assert lens in text
    text = text.replace(lens, JOINT).replace("iterations = 40", "iterations = 60")
    open("out/joint_design.toml", "w").write(text)
elif what == "renders":
    alpha = designed("lens")["volume[0].profiles[0].alpha"]
    j = designed("joint")
    joint = [
        ((x, y), j[f"volume[1].profiles[0].amplitude_{k}"], 0.0)
        for k, ((x, y), _, _) in enumerate(DEFAULT)
    ]
    cases = {
        "none": scene(alpha, 813e3, SILENT, lens=False),
        "ideal": scene(alpha, 813e3, SILENT, lens=False, focus=True),
        "lens": scene(alpha, 813e3, SILENT),
        "full": scene(alpha, FULL_FREQUENCY, FULL_ELEMENTS, lens=False),
        "lens_full": scene(alpha, FULL_FREQUENCY, FULL_ELEMENTS),
        "joint": scene(
            j["volume[0].profiles[0].alpha"], j["volume[1].profiles[0].frequency"], joint
        ),
    }
    for name, text in cases.items():
        open(f"out/{name}.toml", "w").write(text)
else:
    sys.exit(__doc__)
