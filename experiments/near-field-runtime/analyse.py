#!/usr/bin/env python3
"""Time to RMSE < 0.01 of C(Δ, τ) maps (paper 000, Table 1), from lightpath correlation-map runs.

RMSE is over every entry of the map (all Δ, all τ) of C normalised by the peak intensity of the
unshifted map, against the converged value: the Monte Carlo estimate is unbiased, so its RMSE is
the root-mean-square standard error, which falls as 1/√paths. With a reference run (more paths)
the measured RMSE against it is reported too, as a check.

usage: analyse.py RUN_DIR [REFERENCE_DIR]
"""
import json
import math
import sys


def load(d):
    with open(f"{d}/correlation_map.json") as f:
        return json.load(f)


def flat(a, key):
    return [v for delta in a[key] for row in delta for v in row]


run = load(sys.argv[1])
peak = max(v for row in run["re"][0] for v in row)
se = flat(run, "stderr")
rmse = math.sqrt(sum(s * s for s in se) / len(se)) / peak
seconds = run["seconds"]
paths = run["samples"]
needed = paths * (rmse / 0.01) ** 2
print(f"{sys.argv[1]}: {paths} paths in {seconds:.2f} s, RMSE {rmse:.4f}; "
      f"RMSE < 0.01 needs {needed:.0f} paths = {seconds * needed / paths:.2f} s")
if len(sys.argv) > 2:
    ref = load(sys.argv[2])
    d = [complex(a, b) - complex(c, e) for a, b, c, e in
         zip(flat(run, "re"), flat(run, "im"), flat(ref, "re"), flat(ref, "im"))]
    measured = math.sqrt(sum(abs(x) ** 2 for x in d) / len(d)) / peak
    ref_se = flat(ref, "stderr")
    ref_rmse = math.sqrt(sum(s * s for s in ref_se) / len(ref_se)) / peak
    print(f"  against the reference ({ref['samples']} paths, its own RMSE {ref_rmse:.4f}): "
          f"{measured:.4f}, expected √(RMSE² + ref²) = {math.hypot(rmse, ref_rmse):.4f}; "
          f"RMSE < 0.01 by this measure: {seconds * (measured / 0.01) ** 2:.2f} s")
