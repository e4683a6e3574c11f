#!/usr/bin/env python3
"""Turn a covariance.json of truth.toml into the 'measured' intensity correlations that paper 004
reads (Eq. 4): |C|² for (light 0 → v(τ), light k → v(τ) + Δ_k), with standard errors by the delta
method (sd |C|² ≈ √2 |C| sd C). Usage: make_target.py covariance.json target.json"""
import json, math, sys
from make_configs import DELTAS_DEG, TAUS_DEG

c = json.load(open(sys.argv[1]))
n = len(TAUS_DEG)
entries = []
for k in range(1, len(DELTAS_DEG) + 1):
    for i in range(n):
        re = c["re"][0][k][i][k * n + i]
        im = c["im"][0][k][i][k * n + i]
        sd = c["stderr"][0][k][i][k * n + i]
        mag = math.hypot(re, im)
        entries.append({"light": [0, k], "view": [i, k * n + i],
                        "intensity_correlation": mag * mag,
                        "stderr": max(math.sqrt(2) * mag * sd, 1e-300)})
json.dump({"entries": entries}, open(sys.argv[2], "w"), indent=1)
print(f"{len(entries)} entries -> {sys.argv[2]}")
