"""Compare the fitted GRIN-fibre profile with the sech profile (exactly periodic for meridional rays,
n0 sech(αρ) = n0 (1 − (αρ)²/2 + 5(αρ)⁴/24 − 61(αρ)⁶/720 …)) and the parabolic one
(n² = n0²(1 − α²ρ²): n0 (1 − (αρ)²/2 − (αρ)⁴/8 − (αρ)⁶/16 …)), and trace all three over three half
pitches (fan of rays up to 20° from an on-axis point): the refocus spread at z = 3L tells how periodic
each is."""
import json, math, pathlib, subprocess, sys

out, bin_ = pathlib.Path(sys.argv[1]), sys.argv[2]
fit = json.load(open(out / "fit" / "fit.json"))
n0, L = 1.5, 2 * math.pi
alpha = math.pi / L
c = fit["fitted"]
sech = [-n0 * alpha**2 / 2, 5 * n0 * alpha**4 / 24, -61 * n0 * alpha**6 / 720]
para = [-n0 * alpha**2 / 2, -n0 * alpha**4 / 8, -n0 * alpha**6 / 16]
print(f"fit: {fit['log'].__len__()} evaluations, RMS miss {fit['rms_miss_initial']:.3e} → {fit['rms_miss_final']:.3e} mm")
print(f"{'':>4} {'fitted':>12} {'sech':>12} {'parabolic':>12} {'fit/sech':>9}")
for k in range(3):
    print(f"c{k + 1:<3} {c[k]:>12.5e} {sech[k]:>12.5e} {para[k]:>12.5e} {c[k] / sech[k]:>9.4f}")
a_fit = math.sqrt(-2 * c[0] / n0)
print(f"pitch from the fitted c1: 2π/α = {2 * math.pi / a_fit:.5f} mm (design: 2L = {2 * L:.5f} mm)")

profiles = {
    "fitted": f'{{ kind = "radial_polynomial", n0 = {n0}, coefficients = {json.dumps(c)} }}',
    "sech": f'{{ kind = "sech_fibre", n0 = {n0}, alpha = {alpha} }}',
    "parabolic": f'{{ kind = "parabolic_fibre", n0 = {n0}, alpha = {alpha} }}',
}
print(f"\nthree half pitches (z = −3L/2 → +3L/2), fan of 41 rays up to 20°: spread at the exit face")
for name, prof in profiles.items():
    cfg = out / f"trace_{name}.toml"
    cfg.write_text(f"""[field]
profiles = [{prof}]
bounds = {{ kind = "cylinder", radius = 1.9, half_length = {1.5 * L} }}
n_out = 1.0
[rays]
kind = "fan"
origin = [0.0, 0.0, {-1.5 * L}]
axis = [0.0, 0.0, 1.0]
half_angle_deg = 20.0
count = 41
[trace]
step = 0.005
""")
    subprocess.run([bin_, "trace", str(cfg), "--out", str(out / f"trace_{name}")], check=True,
                   capture_output=True)
    rays = json.load(open(out / f"trace_{name}" / "rays.json"))["rays"]
    rho = [math.hypot(r["exit_position"][0], r["exit_position"][1]) for r in rays]
    z = [r["exit_position"][2] for r in rays]
    rms = math.sqrt(sum(x * x for x in rho) / len(rho))
    print(f"  {name:>9}: RMS ρ {1e3 * rms:9.3f} µm, max ρ {1e3 * max(rho):9.3f} µm, all exit at z = 3L/2: {all(abs(v - 1.5 * L) < 1e-9 for v in z)}")
