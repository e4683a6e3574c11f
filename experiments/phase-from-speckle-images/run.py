#!/usr/bin/env python3
"""Render speckle image stacks of slabs (Mie spheres in agarose and HG g = 0.9) at optical depths
1, 4 and 7 with `lightpath speckle`, read their phase function with `lightpath acquire-phase`, and
compare the recovered g (correlation and naive intensity readings) with the truth: an HG fitted to
the true phase function over the same angles.

Usage: python3 run.py [--realisations R] [--paths P] [--only NAME]"""

import argparse
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
BIN = os.path.join(ROOT, "target", "release", "lightpath")
OUT = os.path.join(HERE, "out")

# 632.8 nm in agarose (n = 1.335): lengths in µm, the wavelength in the host
N_AGAROSE = 1.335
LAMBDA = 0.6328 / N_AGAROSE
MATERIALS = {
    "silica-10um": 'phase = { kind = "mie", diameter = 10.0, n_particle = 1.457, n_medium = 1.335 }',
    "polystyrene-4um": 'phase = { kind = "mie", diameter = 4.0, n_particle = 1.587, n_medium = 1.335 }',
    "hg-0.9": 'phase = { kind = "hg", g = 0.9 }',
}
THICKNESS = 100.0  # µm
PIXELS = 128
STEP_DEG = 0.1  # per pixel
WINDOW_UM = 136.0  # slab window: speckle grain λ / W ≈ 2 pixels
# illumination pixels: i1, then Δ = 1° and 4° along y (readings run along x, ⟂ Δ)
PEAKS = [(64, 16), (64, 26), (64, 56)]


def pixel_direction(ix, iy):
    c = (PIXELS - 1) / 2
    ax, ay = math.radians((ix - c) * STEP_DEG), math.radians((iy - c) * STEP_DEG)
    v = (math.tan(ax), math.tan(ay), 1.0)
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def scene(material, od, realisations, paths):
    lights = "".join(
        f'[[light]]\nkind = "plane_wave"\ndirection = {pixel_direction(*p)}\n' for p in PEAKS
    )
    return f"""wavelength = {LAMBDA}
[medium]
slab = {THICKNESS}
slab_window = {WINDOW_UM}
mfp = {THICKNESS / od}
{MATERIALS[material]}
{lights}
[[view]]
kind = "far_field_grid"
center = [0.0, 0.0, 1.0]
width_deg = {PIXELS * STEP_DEG}
pixels = [{PIXELS}, {PIXELS}]
[speckle]
realisations = {realisations}
paths = {paths}
[render]
seed = 7
chunk = 500
"""


def acquire(folder, realisations):
    # the grid's pixels are tan-spaced in angle; the relay's pitch/f = tan(step) matches them to
    # 0.2 % of the angle at 6°
    text = f"""[acquisition]
focal_length = 1.0
pixel_pitch = {math.tan(math.radians(STEP_DEG))}
n_sample = 1.0
window = 8
step = 4
axis_px = [{(PIXELS - 1) / 2}, {(PIXELS - 1) / 2}]
"""
    for r in range(realisations):
        for l in (1, 2):
            text += f"""[[pair]]
first = "render/speckle_{r:04}_l0.exr"
second = "render/speckle_{r:04}_l{l}.exr"
peaks = [{list(PEAKS[0])}, {list(PEAKS[l])}]
"""
    path = os.path.join(folder, "acquire.toml")
    with open(path, "w") as f:
        f.write(text)
    return path


def hg(g, mu):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)


def truth_g(material, angles):
    """g of the HG that best fits the true ρ (log least squares) over the readings' angles."""
    if material == "hg-0.9":
        return 0.9
    d, n = (10.0, 1.457) if material.startswith("silica") else (4.0, 1.587)
    out = os.path.join(OUT, material + "-mie")
    subprocess.run(
        [BIN, "mie", "--diameter", str(d), "--n-particle", str(n), "--n-medium", str(N_AGAROSE),
         "--wavelength", "0.6328", "--angles", "3601", "--out", out],
        check=True, stdout=subprocess.DEVNULL)
    m = json.load(open(os.path.join(out, "mie.json")))
    rho = lambda a: m["phase"][min(range(len(m["theta_deg"])), key=lambda i: abs(m["theta_deg"][i] - a))]
    best = None
    for i in range(1, 2000):
        g = 0.5 + 0.4995 * i / 2000
        logs = [math.log(rho(a)) - math.log(hg(g, math.cos(math.radians(a)))) for a in angles]
        mean = sum(logs) / len(logs)
        cost = sum((x - mean) ** 2 for x in logs)
        if best is None or cost < best[0]:
            best = (cost, g, m["g"])
    return best[1], best[2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--realisations", type=int, default=30)
    ap.add_argument("--paths", type=int, default=2000)
    ap.add_argument("--only")
    a = ap.parse_args()
    rows = []
    for material in MATERIALS:
        if a.only and a.only != material:
            continue
        for od in (1, 4, 7):
            folder = os.path.join(OUT, f"{material}-od{od}")
            os.makedirs(folder, exist_ok=True)
            cfg = os.path.join(folder, "scene.toml")
            with open(cfg, "w") as f:
                f.write(scene(material, od, a.realisations, a.paths))
            subprocess.run([BIN, "speckle", cfg, "--out", os.path.join(folder, "render"), "--quiet"],
                           check=True, stdout=subprocess.DEVNULL)
            acq = acquire(folder, a.realisations)
            r = subprocess.run([BIN, "acquire-phase", acq, "--out", os.path.join(folder, "phase")],
                               capture_output=True, text=True)
            if r.returncode != 0:
                print(r.stderr, file=sys.stderr)
                sys.exit(1)
            res = json.load(open(os.path.join(folder, "phase", "phase_acquisition.json")))
            angles = [x["angle_deg"] for x in res["curves"][-1]["readings"]]
            tg = truth_g(material, angles)
            for c in res["curves"]:
                rows.append((material, od, c["delta_deg"], c["significant"],
                             c.get("hg"), c.get("hg_intensity"), tg,
                             res.get("consistency")))
            print(r.stdout.strip().splitlines()[-1], file=sys.stderr)
    print("| material | OD | Δ | significant | g (correlation) | g (intensity) | truth: HG fit over the angles (Mie g) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for m, od, d, s, h, hi, tg, cons in rows:
        t = f"{tg[0]:.4f} ({tg[1]:.4f})" if isinstance(tg, tuple) else f"{tg}"
        gc = f"{h['g']:.4f} ± {h['g_stderr']:.4f}" if h else "—"
        gi = f"{hi['g']:.4f}" if hi else "—"
        print(f"| {m} | {od} | {d:.2f}° | {'yes' if s else 'no'} | {gc} | {gi} | {t} |")


if __name__ == "__main__":
    main()
