"""Tables of shape.sh: wave / Monte Carlo intensity for cubes and slabs, and the exit-face profiles."""
import json, math, os

def load(name):
    return (json.load(open(f"out/{name}-mc/covariance.json")),
            json.load(open(f"out/{name}-wave/covariance.json")))

def ratio(a, b, views):
    num = sum(b["re"][0][0][v][v] for v in views)
    den = sum(a["re"][0][0][v][v] for v in views)
    var = sum(b["stderr"][0][0][v][v] ** 2 for v in views)
    return f"{num / den:.4f} ± {math.sqrt(var) / den:.4f}"

# far-field views every 10°: forward 20°–80° and 280°–340°, backward 100°–260°, every 30° (the old table)
fwd = [v for v in range(36) if 2 <= v <= 8 or 28 <= v <= 34]
bwd = list(range(10, 27))
every30 = list(range(3, 36, 3))
print("box [λ]        n·λ³   k·mfp  scatterers  wave/MC: every 30°    forward 20–80°     backward 100–260°   forward Im m")
for name, box in [("cube4", (4, 4, 4)), ("slab16x4", (16, 16, 4)), ("slab16x2", (16, 16, 2)),
                  ("slab16x1", (16, 16, 1)), ("cube6", (6, 6, 6)),
                  ("slab24x6", (24, 24, 6)), ("cube20", (20, 20, 20)), ("cube30", (30, 30, 30))]:
    if not os.path.exists(f"out/{name}-wave/covariance.json"):
        continue
    a, b = load(name)
    depth = box[2]
    mean = b["mean_im"][0][0] / a["mean_im"][0][0]
    print(f"{'×'.join(map(str, box)):13} {math.pi / depth:.3f}  {2 * math.pi * depth:5.1f}  {b['scatterers_mean']:8.0f}"
          f"    {ratio(a, b, every30)}   {ratio(a, b, fwd)}   {ratio(a, b, bwd)}   "
          f"{mean:.4f} ± {b['mean_stderr'][0][0] / a['mean_im'][0][0]:.4f}")

for name in ["exit-cube4", "exit-slab16x4"]:
    a, b = load(name)
    print(f"\n{name}: half a wavelength behind the exit face (Beer–Lambert |mean| = e^(-1/2) = 0.6065 behind the box)")
    print("   x [λ]   |mean| MC   |mean| wave        incoherent MC       wave              wave/MC")
    for v, view in enumerate(b["views"]):
        ma = abs(complex(a["mean_re"][0][v], a["mean_im"][0][v]))
        mb = abs(complex(b["mean_re"][0][v], b["mean_im"][0][v]))
        ia, ib = a["re"][0][0][v][v], b["re"][0][0][v][v]
        print(f"  {view['position'][0]:6.2f}   {ma:.4f}      {mb:.4f} ± {b['mean_stderr'][0][v]:.4f}    "
              f"{ia:.4f} ± {a['stderr'][0][0][v][v]:.4f}   {ib:.4f} ± {b['stderr'][0][0][v][v]:.4f}   {ib / ia:.4f}")
