#!/usr/bin/env python3
"""Compare a design's radial profile with the Luneburg lens n = sqrt(2 − r²)."""
import json, math, sys
d = json.load(open(sys.argv[1]))
p = d["radial_profile"]
rows = [(r, m, lo, hi, math.sqrt(2 - r * r)) for r, m, lo, hi in zip(p["r"], p["mean"], p["min"], p["max"])]
print(" r     mean n   min     max     Luneburg")
for r, m, lo, hi, t in rows[::4]:
    print(f"{r:4.2f}  {m:.4f}  {lo:.4f}  {hi:.4f}  {t:.4f}")
inner = [(m - t) for r, m, lo, hi, t in rows if r <= 0.8]
print(f"RMS(mean n − Luneburg) for r ≤ 0.8: {math.sqrt(sum(x * x for x in inner) / len(inner)):.4f}")
print(f"RMS miss distance: {d['rms_miss_initial']:.4f} → {d['rms_miss_final']:.5f}; {d['seconds']:.0f} s")
# rays in the σ-form see n only up to a constant factor (n → c n leaves every path unchanged, and the
# tracer does not refract at the bounds), so compare shapes after the best scale
sel = [(m, t) for r, m, lo, hi, t in rows if r <= 0.9]
c = sum(m * t for m, t in sel) / sum(t * t for m, t in sel)
shape = math.sqrt(sum((m / c - t) ** 2 for m, t in sel) / len(sel))
spread = max(hi - lo for r, m, lo, hi, t in rows if r <= 0.9)
print(f"best scale c = {c:.4f}; RMS(mean n / c − Luneburg) for r ≤ 0.9: {shape:.4f}; "
      f"largest angular spread (max − min over 26 directions): {spread:.4f}")
