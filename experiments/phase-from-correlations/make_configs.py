#!/usr/bin/env python3
"""Write truth.toml and start.toml for the phase-function experiment (paper 004's setup).

A slab of thickness 10 λ at optical depth 3, lit by plane waves i1 = z and i2 = i1 displaced by Δ
(direction cosines, along y); views v(τ) at scattering angle τ (displaced along x, so Δ ⟂ τ,
paper 004 Eq. 6) and v(τ) + Δ. Entry (i1 → v(τ), i2 → v(τ) + Δ) is the correlation Claim 1 reads.
"""
import math

DELTAS_DEG = [0.5, 2.0, 8.0]
TAUS_DEG = [2, 5, 10, 15, 20, 30, 40, 50, 60, 120, 150, 170]
NODES_DEG = [0, 3, 6, 10, 15, 20, 25, 30, 40, 50, 60, 75, 90, 120, 150, 180]
G_TRUE = 0.8


def hg(mu, g):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)


def vec(x, y, sign):
    return [x, y, sign * math.sqrt(max(0.0, 1 - x * x - y * y))]


def fmt(v):
    return "[" + ", ".join(f"{c:.12f}" for c in v) + "]"


def config(header, values):
    cos = [math.cos(math.radians(a)) for a in reversed(NODES_DEG)]
    cos[0], cos[-1] = -1.0, 1.0
    out = [header, "wavelength = 1.0", "", "[medium]", "slab = 10.0", "mfp = 3.3333333333333335",
           "albedo = 1.0", "", "[medium.phase]", 'kind = "tabulated"', f"cos = {fmt(cos)}",
           f"values = {fmt(values(cos))}", ""]
    lights = [vec(0, 0, 1)] + [vec(0, math.sin(math.radians(d)), 1) for d in DELTAS_DEG]
    for l in lights:
        out += ["[[light]]", 'kind = "plane_wave"', f"direction = {fmt(l)}", ""]
    # views: first v(τ) for every τ, then v(τ) + Δ_k for every k and τ
    shifts = [0.0] + [math.sin(math.radians(d)) for d in DELTAS_DEG]
    for dy in shifts:
        for t in TAUS_DEG:
            r = math.radians(t)
            out += ["[[view]]", 'kind = "far_field"',
                    f"direction = {fmt(vec(math.sin(r), dy, 1 if t < 90 else -1))}", ""]
    out += ["[render]", "samples = 20000", "chunk = 500", "seed = 1", "reversed = true", ""]
    return "\n".join(out)


open("truth.toml", "w").write(config(
    f"# The 'measured' material of experiments/phase-from-correlations: HG g = {G_TRUE} tabulated at\n"
    "# the fit's nodes, slab 10 λ, optical depth 3. Written by make_configs.py.",
    lambda cos: [hg(c, G_TRUE) for c in cos]))
open("start.toml", "w").write(config(
    "# The fit's starting point: the same scene with an isotropic tabulated phase function.\n"
    "# Written by make_configs.py.",
    lambda cos: [1.0] * len(cos)))
