#!/usr/bin/env python3
"""Paper 000 Table 2's equal-time rows on its small volume: the closed forms (N.F.), the
far-field estimator integrated over a tabulated aperture (F.F. Tab., `aperture = "quadrature"`)
and over directions drawn at random from each aperture (F.F. M.C., `aperture = "monte_carlo"`,
with the number of directions per aperture and vertex that gives the lowest error per second)
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


def config(aperture, chunk, directions):
    text = open(os.path.join(HERE, "small.toml")).read()
    extra = f"\naperture_directions = {directions}" if directions else ""
    text = text.replace("chunk = 200", f"chunk = {chunk}\naperture = \"{aperture}\"{extra}")
    path = os.path.join(OUT, f"{aperture}-{chunk}-{directions}.toml")
    with open(path, "w") as f:
        f.write(text)
    return path


def run(aperture, samples, seed, name, directions=None, chunks=8):
    chunk = max(1, min(200, samples // chunks))
    out = os.path.join(OUT, name)
    subprocess.run([BIN, "correlation-map", config(aperture, chunk, directions), "--samples", str(samples),
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
    # drawn directions: the count with the lowest error per second (own RMSE × √seconds), from
    # runs of about 3 s each
    print("F.F. M.C.: directions per aperture and vertex | paths/s | own RMSE × √s")
    best = None
    for d in (16, 64, 256, 512, 1024, 2048):
        m = run("monte_carlo", max(160, 400_000 // d), 1002, f"monte-carlo-{d}", d, chunks=16)
        cost = own(m, peak) * math.sqrt(m["seconds"])
        print(f"  {d} | {m['samples'] / m['seconds']:.0f} | {cost:.4f}")
        if best is None or cost < best[1]:
            best = (d, cost, m["samples"] / m["seconds"])
    directions, _, rate["monte_carlo"] = best
    print(f"paths/s: closed forms {rate['vmf']:.0f}, far-field tabulated {rate['quadrature']:.1f}, "
          f"far-field Monte Carlo ({directions} directions) {rate['monte_carlo']:.0f}")
    print()
    print("| estimator | budget | paths | seconds | RMSE vs reference | own RMSE (std. errors) |")
    print("| --- | --- | --- | --- | --- | --- |")
    rows = (("vmf", "N.F. (closed forms)", None), ("quadrature", "F.F. Tab. (quadrature)", None),
            ("monte_carlo", f"F.F. M.C. ({directions} directions)", directions))
    for aperture, label, d in rows:
        for k, t in enumerate(budgets):
            n = max(8, round(rate[aperture] * t))
            m = run(aperture, n, 2000 + k, f"{aperture}-{t:g}s", d)
            print(f"| {label} | {t:g} s | {n} | {m['seconds']:.2f} | {rmse(m, ref, peak):.4f} | "
                  f"{own(m, peak):.4f} |")


if __name__ == "__main__":
    main()
