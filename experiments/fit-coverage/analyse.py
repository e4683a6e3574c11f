"""Coverage table from out/<set>/<seed>/fit/fit.json: the fraction of fits whose truth lies within
1 and 2 reported standard deviations, per parameter (nominal: 68.3 % and 95.4 %)."""
import json
import math
import pathlib
import sys

TRUTH = {"mfp": 5.0, "albedo": {"mfp,albedo": 0.8}, "g": {"mfp,g": 0.5}}
root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "out")
print("| fitted | parameter | fits | converged | within 1 sd | within 2 sd | median sd | RMS error / RMS sd |")
print("| --- | --- | --- | --- | --- | --- | --- | --- |")
for set_dir in sorted(p for p in root.iterdir() if p.is_dir()):
    name = set_dir.name
    fits = [json.loads(p.read_text()) for p in sorted(set_dir.glob("*/fit/fit.json"))]
    if not fits:
        continue
    conv = sum(1 for f in fits if f.get("convergence", {}).get("converged"))
    for i, p in enumerate(fits[0]["params"]):
        t = TRUTH[p] if p == "mfp" else TRUTH[p][name]
        z = [abs(f["fitted"][i] - t) / f["stddev"][i] for f in fits if f["stddev"][i] > 0]
        sds = sorted(f["stddev"][i] for f in fits)
        rms_err = math.sqrt(sum((f["fitted"][i] - t) ** 2 for f in fits) / len(fits))
        rms_sd = math.sqrt(sum(f["stddev"][i] ** 2 for f in fits) / len(fits))
        print(
            f"| {name} | {p} | {len(fits)} | {conv} | {100 * sum(x < 1 for x in z) / len(z):.0f} % "
            f"| {100 * sum(x < 2 for x in z) / len(z):.0f} % | {sds[len(sds) // 2]:.4g} | {rms_err / rms_sd:.2f} |"
        )
