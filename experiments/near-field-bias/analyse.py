#!/usr/bin/env python3
"""RMSE between C(Δ, τ) maps rendered on the same paths (paper 000, Table 2's measure): over every
entry of the map, C normalised by the peak intensity of the unshifted map of the reference.

usage: analyse.py VMF_DIR EXACT_DIR EQ25_DIR
"""
import json
import math
import sys


def load(d):
    with open(f"{d}/correlation_map.json") as f:
        return json.load(f)


def entries(a):
    return [complex(x, y) for dx, dy in zip(a["re"], a["im"])
            for rx, ry in zip(dx, dy) for x, y in zip(rx, ry)]


vmf, exact, eq25 = (load(d) for d in sys.argv[1:4])
peak = max(v for row in exact["re"][0] for v in row)


def rmse(a, b):
    d = [x - y for x, y in zip(entries(a), entries(b))]
    return math.sqrt(sum(abs(x) ** 2 for x in d) / len(d)) / peak


se = [s for delta in exact["stderr"] for row in delta for s in row]
print(f"{exact['samples']} paths; the reference's own RMSE (standard errors) "
      f"{math.sqrt(sum(s * s for s in se) / len(se)) / peak:.4f}")
print(f"closed forms (linearised attenuation) vs exact attenuation: {rmse(vmf, exact):.4f}")
print(f"Eq. 25 (axis attenuation) vs exact attenuation:            {rmse(eq25, exact):.4f}")
print(f"seconds: closed forms {vmf['seconds']:.2f}, exact {exact['seconds']:.1f}, "
      f"Eq. 25 {eq25['seconds']:.1f}")
