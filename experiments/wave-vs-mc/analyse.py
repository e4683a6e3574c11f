"""Summarise the density sweep: wave/MC intensity ratio and forward mean ratio at optical depth 1."""
import json, math

print("L [λ]  n·λ³   k·mfp   wave/MC intensity (non-forward views)   forward Im m: wave / closed form")
for L in [4, 6, 9, 12]:
    a = json.load(open(f"out/od1-L{L}-mc/covariance.json"))
    b = json.load(open(f"out/od1-L{L}-wave/covariance.json"))
    num = den = var = 0.0
    for v in range(1, 12):
        num += b["re"][0][0][v][v]
        den += a["re"][0][0][v][v]
        var += b["stderr"][0][0][v][v] ** 2
    mw, ms, mm = b["mean_im"][0][0], b["mean_stderr"][0][0], a["mean_im"][0][0]
    n = (1.0 / L) * math.pi  # σ_s / c_s with c_s = λ²/π
    print(f"{L:<6} {n:.3f}  {2 * math.pi * L:6.1f}  {num / den:.4f} ± {math.sqrt(var) / den:.4f}"
          f"                     {mw / mm:.4f} ± {ms / mm:.4f}")
