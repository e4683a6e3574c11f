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


def sample_scene(od_guess, g_guess, samples):
    """The sample as the differentiable fit starts from it: the slab's thickness and window are
    known, its mean free path and HG g are guesses."""
    return f"""wavelength = {LAMBDA}
[medium]
slab = {THICKNESS}
slab_window = {WINDOW_UM}
mfp = {THICKNESS / od_guess}
albedo = 1.0
phase = {{ kind = "hg", g = {g_guess} }}
[render]
samples = {samples}
seed = 11
"""


def handoff_fit(folder, od, samples, params):
    """Hand the readings to `lightpath fit` (acquire-phase's `[fit]`: normalised intensity
    correlations over windows that share no pixel, every order of scattering in the model) and fit
    `params` from g = 0.8 and half the optical depth (`mfp,g`), or with the mean free path known
    (`g`: the optical depth measured by ballistic transmission). Returns the fit file."""
    od_start = od / 2 if "mfp" in params else od
    with open(os.path.join(folder, "sample.toml"), "w") as f:
        f.write(sample_scene(od_start, 0.8, samples))
    acq = os.path.join(folder, "acquire.toml")
    text = open(acq).read().split("[fit]")[0]
    text += '[fit]\nscene = "sample.toml"\n'
    with open(acq, "w") as f:
        f.write(text)
    phase = os.path.join(folder, "phase")
    subprocess.run([BIN, "acquire-phase", acq, "--out", phase], check=True, stdout=subprocess.DEVNULL)
    fit = os.path.join(folder, "fit-" + params.replace(",", "-"))
    subprocess.run([BIN, "fit", os.path.join(phase, "fit_scene.toml"), "--target",
                    os.path.join(phase, "fit_target.json"), "--fit", params, "--out", fit, "--quiet"],
                   check=True, stdout=subprocess.DEVNULL)
    return json.load(open(os.path.join(fit, "fit.json")))


def hg(g, mu):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)


def true_rho(material):
    """The true ρ(θ°): HG, or Mie theory (`lightpath mie`, 0.05° steps, linear interpolation)."""
    if material == "hg-0.9":
        return lambda a: hg(0.9, math.cos(math.radians(a))), None
    d, n = (10.0, 1.457) if material.startswith("silica") else (4.0, 1.587)
    out = os.path.join(OUT, material + "-mie")
    subprocess.run(
        [BIN, "mie", "--diameter", str(d), "--n-particle", str(n), "--n-medium", str(N_AGAROSE),
         "--wavelength", "0.6328", "--angles", "3601", "--out", out],
        check=True, stdout=subprocess.DEVNULL)
    m = json.load(open(os.path.join(out, "mie.json")))

    def rho(a):
        x = a / 0.05
        i = min(int(x), len(m["phase"]) - 2)
        return m["phase"][i] + (x - i) * (m["phase"][i + 1] - m["phase"][i])

    return rho, m["g"]


def window_model(rho, delta_px, offset_px):
    """What a reading sees of the true ρ: Claim 1's C ∝ ρ(θ)² sinc²(kL/2 Δ·τ) averaged over the
    8-pixel window (its angular extent smooths Mie's lobes), as an amplitude √⟨C⟩."""
    p1 = PEAKS[0]
    norm = math.hypot(*delta_px)
    u = (-delta_px[1] / norm, delta_px[0] / norm)
    cx, cy = round(p1[0] + offset_px * u[0]), round(p1[1] + offset_px * u[1])
    i1 = pixel_direction(*p1)
    d = [a - b for a, b in zip(pixel_direction(p1[0] + delta_px[0], p1[1] + delta_px[1]), i1)]
    k_half = math.pi * THICKNESS / LAMBDA
    total = 0.0
    for y in range(cy - 4, cy + 4):
        for x in range(cx - 4, cx + 4):
            v = pixel_direction(x, y)
            mu = max(-1.0, min(1.0, sum(a * b for a, b in zip(i1, v))))
            tau = [a - b for a, b in zip(v, i1)]
            arg = k_half * (d[0] * tau[0] + d[1] * tau[1])
            sinc = 1.0 if abs(arg) < 1e-12 else math.sin(arg) / arg
            total += (rho(math.degrees(math.acos(mu))) * sinc) ** 2
    return math.sqrt(total / 64)


def truth_g_same_fit(curve, rho):
    """The g that the same weighted HG fit (C ∝ HG², the readings' errors) gives on the noise-free
    window model of the true ρ: what a perfect reading would report."""
    pts = [(math.cos(math.radians(r["angle_deg"])), window_model(rho, curve["delta_px"], r["offset_px"]) ** 2,
            r["stderr"] / max(r["correlation"], 1e-300)) for r in curve["readings"] if r["correlation"] > 0]
    best = None
    for i in range(1, 4000):
        g = 0.5 + 0.4999 * i / 4000
        f = [hg(g, mu) ** 2 for mu, _, _ in pts]
        # relative errors, so the scale of C does not matter
        w = [1 / (rel * c) ** 2 for (_, c, rel) in pts]
        a = sum(wi * fi * c for wi, fi, (_, c, _) in zip(w, f, pts)) / sum(wi * fi * fi for wi, fi in zip(w, f))
        cost = sum(wi * (c - a * fi) ** 2 for wi, fi, (_, c, _) in zip(w, f, pts))
        if best is None or cost < best[0]:
            best = (cost, g)
    return best[1]


def shape_chi2(curve, rho):
    """χ²/dof of the readings' √C (on any scale: one factor fitted) against the window model."""
    pts = [(window_model(rho, curve["delta_px"], r["offset_px"]), r["rho"], r["rho_stderr"])
           for r in curve["readings"] if r.get("rho")]
    if len(pts) < 2:
        return None
    num = sum(y * m / s ** 2 for m, y, s in pts)
    den = sum(m ** 2 / s ** 2 for m, y, s in pts)
    k = num / den
    return sum(((y - k * m) / s) ** 2 for m, y, s in pts) / (len(pts) - 1)


def truth_g(material, angles):
    """g of the HG that best fits the true ρ (log least squares) over the readings' angles, and
    the true g over the sphere."""
    rho, g_all = true_rho(material)
    if g_all is None:
        return 0.9, 0.9
    best = None
    for i in range(1, 2000):
        g = 0.5 + 0.4995 * i / 2000
        logs = [math.log(rho(a)) - math.log(hg(g, math.cos(math.radians(a)))) for a in angles]
        mean = sum(logs) / len(logs)
        cost = sum((x - mean) ** 2 for x in logs)
        if best is None or cost < best[0]:
            best = (cost, g, g_all)
    return best[1], best[2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--realisations", type=int, default=30)
    ap.add_argument("--paths", type=int, default=1000)
    ap.add_argument("--only")
    ap.add_argument("--analyse-only", action="store_true", help="reuse the rendered images and readings")
    ap.add_argument("--fit-samples", type=int, default=20000,
                    help="subpaths per objective evaluation of the hand-off fits")
    ap.add_argument("--skip-fits", action="store_true", help="reuse the hand-off fits (where there are any)")
    a = ap.parse_args()
    rows, fits = [], []
    for material in MATERIALS:
        if a.only and a.only != material:
            continue
        for od in (1, 4, 7):
            folder = os.path.join(OUT, f"{material}-od{od}")
            os.makedirs(folder, exist_ok=True)
            cfg = os.path.join(folder, "scene.toml")
            with open(cfg, "w") as f:
                f.write(scene(material, od, a.realisations, a.paths))
            if not a.analyse_only:
                subprocess.run([BIN, "speckle", cfg, "--out", os.path.join(folder, "render"), "--quiet"],
                               check=True, stdout=subprocess.DEVNULL)
                acq = acquire(folder, a.realisations)
                r = subprocess.run([BIN, "acquire-phase", acq, "--out", os.path.join(folder, "phase")],
                                   capture_output=True, text=True)
                if r.returncode != 0:
                    print(r.stderr, file=sys.stderr)
                    sys.exit(1)
                print(r.stdout.strip().splitlines()[-1], file=sys.stderr)
            if material == "hg-0.9" and od > 1:
                # where the single-scattering reading breaks, the differentiable fit takes over
                for params in ("mfp,g", "g"):
                    saved = os.path.join(folder, "fit-" + params.replace(",", "-"), "fit.json")
                    if not a.skip_fits:
                        fits.append((material, od, handoff_fit(folder, od, a.fit_samples, params)))
                    elif os.path.exists(saved):
                        fits.append((material, od, json.load(open(saved))))
            res = json.load(open(os.path.join(folder, "phase", "phase_acquisition.json")))
            angles = [x["angle_deg"] for x in res["curves"][-1]["readings"]]
            tg = truth_g(material, angles)
            rho, _ = true_rho(material)
            cons = res.get("consistency")
            for c in res["curves"]:
                rows.append((material, od, c["delta_deg"], c["significant"],
                             c.get("hg"), c.get("hg_intensity"), (truth_g_same_fit(c, rho), tg[1]),
                             shape_chi2(c, rho),
                             cons["consistent"] if cons else None))
    print("| material | OD | Δ | significant | √C vs true ρ: χ²/dof | largest two Δ agree | g (correlation) | g (intensity) | truth: the same HG fit to the true ρ (g over the sphere) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for m, od, d, s, h, hi, tg, chi, cons in rows:
        t = f"{tg[0]:.4f} ({tg[1]:.4f})"
        gc = f"{h['g']:.4f} ± {h['g_stderr']:.4f}" if h else "—"
        gi = f"{hi['g']:.4f}" if hi else "—"
        ch = f"{chi:.2f}" if chi is not None else "—"
        co = {True: "yes", False: "no", None: "—"}[cons]
        print(f"| {m} | {od} | {d:.2f}° | {'yes' if s else 'no'} | {ch} | {co} | {gc} | {gi} | {t} |")
    if fits:
        print()
        print("| material | OD | fitted | from | mfp (truth) | g (truth 0.9) | correlation(mfp, g) | χ² with model errors (entries) | evaluations | seconds |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for m, od, f in fits:
            fitted = dict(zip(f["params"], zip(f["fitted"], f["stddev"])))
            start = dict(zip(f["params"], f["initial"]))
            mfp = (f"{fitted['mfp'][0]:.1f} ± {fitted['mfp'][1]:.1f}" if "mfp" in fitted
                   else "known")
            g, sg = fitted["g"]
            corr = f"{f['correlation'][0][1]:.2f}" if len(f["params"]) > 1 else "—"
            begin = ", ".join(f"{k} {v:.3g}" for k, v in start.items())
            print(f"| {m} | {od} | {','.join(f['params'])} | {begin} | {mfp} ({THICKNESS / od:.1f}) | "
                  f"{g:.3f} ± {sg:.3f} | {corr} | {f['loss']:.1f} ({len(f['model_fitted'])}) | "
                  f"{f['convergence']['evaluations']} | {f['seconds']:.0f} |")


if __name__ == "__main__":
    main()
