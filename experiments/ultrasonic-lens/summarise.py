"""Table of the ultrasonic-lens fits against the paraxial closed form
n_max = 2 n0 α² / (k_r² − 2 α²), α = π / (2 d)."""
import json, math, pathlib, sys

out = pathlib.Path(sys.argv[1])
n0 = 1.33
print(f"{'depth mm':>8} {'beam r mm':>9} {'k_r /mm':>7} {'n_max fit':>11} {'paraxial':>11} {'fit/parax':>9} {'RMS miss µm':>12} {'evals':>5}")
for d in (20, 30, 40):
    for r in ("0.05", "0.3"):
        f = json.load(open(out / f"d{d}_r{r}" / "fit.json"))
        k = 4.0
        a = math.pi / (2 * d)
        want = 2 * n0 * a * a / (k * k - 2 * a * a)
        got = f["fitted"][0]
        print(f"{d:>8} {r:>9} {k:>7.3f} {got:>11.4e} {want:>11.4e} {got / want:>9.4f} {1e3 * f['rms_miss_final']:>12.3f} {len(f['log']):>5}")
f = json.load(open(out / "both" / "fit.json"))
nm, k = f["fitted"]
d, a = 30, math.pi / 60
print(f"\nboth parameters, depth 30 mm, beam radius 0.3 mm: n_max {f['initial'][0]:.4e} → {nm:.4e}, "
      f"k_r {f['initial'][1]:.3f} → {k:.3f} /mm")
print(f"  n_max k_r² = {nm * k * k:.4e} (paraxial requirement 2 (n0 + n_max) α² = {2 * (n0 + nm) * a * a:.4e}); "
      f"RMS miss {1e3 * f['rms_miss_initial']:.1f} → {1e3 * f['rms_miss_final']:.3f} µm in {len(f['log'])} evaluations")
