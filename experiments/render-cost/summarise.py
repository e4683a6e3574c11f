"""The cost table of README.md from the renders in out/: time to a 5 % median pixel noise at
512 × 512 pixels, over the lit pixels and over the bright ones, against the paper's hours on a
72-core machine."""
import json

NOISE, SIDE, CORES = 0.05, 512, 2
# (case, paper figure, paper hours on 72 cores)
CASES = [
    ("tank", "Fig. 2", 5.5),
    ("ornament_homogeneous", "Fig. 9, homogeneous", 7.33),
    ("ornament_graded", "Fig. 9, graded", 39.0),
    ("sphere_homogeneous", "Fig. 10, homogeneous", 6.18),
    ("sphere_heterogeneous", "Fig. 10, heterogeneous", 12.67),
]

print("| scene | photons | seconds | photons/s | steps/photon | connections/photon | found | "
      "pixel noise: lit, bright | to 5 % at 512², core-hours: lit, bright | paper, core-hours |")
print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")


def core_hours(noise, seconds, pixels):
    """Core-hours to a median relative error of NOISE at SIDE² pixels, as 1/√time per pixel."""
    return seconds * (noise / NOISE) ** 2 * SIDE * SIDE / pixels * CORES / 3600


for case, figure, hours in CASES:
    r = json.load(open(f"out/{case}/render.json"))
    view = {c["name"]: c for c in r["cameras"]}["view"]
    st, c = r["statistics"], r["statistics"]["connections"]
    lit, bright, seconds = view["pixel_noise"], view["bright_pixel_noise"], r["seconds"]
    pixels = view["pixels"][0] * view["pixels"][1]
    print(f"| {case} ({figure}) | {r['samples']} | {seconds:.1f} | {st['photons_per_second']:.0f} "
          f"| {st['steps_per_photon']:.0f} | {c['per_photon']:.2f} | {100 * c['success_rate']:.0f} % "
          f"| {lit:.3f}, {bright:.3f} | {core_hours(lit, seconds, pixels):.1f}, "
          f"{core_hours(bright, seconds, pixels):.1f} | {hours * 72:.0f} |")
