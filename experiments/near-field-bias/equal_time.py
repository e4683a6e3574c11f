#!/usr/bin/env python3
"""Paper 000 Table 2's equal-time rows on its small volume: the closed forms (N.F.) and the
far-field estimator integrated over a tabulated aperture (F.F. Tab., `aperture = "quadrature"`)
each given the same seconds, their C(Δ, τ) maps compared (RMSE over every entry, C divided by the
peak intensity) with a converged run of the closed forms. That reference's own error is printed;
its bias against the exact attenuation is what run.sh measures on the same paths (0.0002).

usage: equal_time.py [SECONDS ...]   (default 1 60, the paper's budgets for this volume)
"""
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
BIN = os.path.join(HERE, "..", "..", "target", "release", "lightpath")
OUT = os.path.join(HERE, "out", "equal-time")


def config(aperture, chunk):
    text = open(os.path.join(HERE, "small.toml")).read()
    text = text.replace("chunk = 200", f"chunk = {chunk}\naperture = \"{aperture}\"")
    path = os.path.join(OUT, f"{aperture}-{chunk}.toml")
    with open(path, "w") as f:
        f.write(text)
    return path


def run(aperture, samples, seed, name):
    chunk = max(1, min(200, samples // 8))
    out = os.path.join(OUT, name)
    subprocess.run([BIN, "correlation-map", config(aperture, chunk), "--samples", str(samples),
                    "--seed", str(seed), "--out", out, "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "correlation_map.json")) as f:
        return json.load(f)


def entries(a):
    return [complex(x, y) for dx, dy in zip(a["re"], a["im"])
            for rx, ry in zip(dx, dy) for x, y in zip(rx, ry)]


def rmse(a, ref, peak):
    d = [x - y for x, y in zip(entries(a), entries(ref))]
    return math.sqrt(sum(abs(x) ** 2 for x in d) / len(d)) / peak


def own(a, peak):
    se = [s for delta in a["stderr"] for row in delta for s in row]
    return math.sqrt(sum(s * s for s in se) / len(se)) / peak


def main():
    budgets = [float(x) for x in sys.argv[1:]] or [1.0, 60.0]
    os.makedirs(OUT, exist_ok=True)
    ref = run("vmf", 20_000_000, 1000, "reference")
    peak = max(v for row in ref["re"][0] for v in row)
    # rates from runs long enough that start-up does not count
    rate = {"vmf": ref["samples"] / ref["seconds"]}
    probe = run("quadrature", 200, 1001, "quadrature-rate")
    rate["quadrature"] = probe["samples"] / probe["seconds"]
    print(f"reference: closed forms, {ref['samples']} paths in {ref['seconds']:.1f} s, "
          f"own RMSE {own(ref, peak):.4f}")
    print(f"paths/s: closed forms {rate['vmf']:.0f}, far-field tabulated {rate['quadrature']:.1f}")
    print()
    print("| estimator | budget | paths | seconds | RMSE vs reference | own RMSE (std. errors) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for aperture, label in (("vmf", "N.F. (closed forms)"), ("quadrature", "F.F. Tab. (quadrature)")):
        for k, t in enumerate(budgets):
            n = max(8, round(rate[aperture] * t))
            m = run(aperture, n, 2000 + k, f"{aperture}-{t:g}s")
            print(f"| {label} | {t:g} s | {n} | {m['seconds']:.2f} | {rmse(m, ref, peak):.4f} | "
                  f"{own(m, peak):.4f} |")


if __name__ == "__main__":
    main()
