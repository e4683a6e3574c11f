"""How a camera image's pixel noise falls with the photons, over one fixed set of pixels: the
bright pixels of the largest run (at least a hundredth of the mean of its brightest one per cent,
as render.json's bright_pixel_noise takes them), whose median relative standard error is read in
every run. A median over each run's own bright set can rise with more photons, as pixels that one
rare large contribution had lit join the set; over a fixed set it falls as 1/sqrt(photons) once
every pixel's estimate has settled.

    python3 converge.py RUN [RUN ...]     runs in out/, fewest photons first (camera "view"; of a
                                          colour image, its red channel as render.json's noise
                                          figures); RUN+RUN pools runs made at different seeds
"""
import json
import math
import struct
import sys


def unrle(src, size):
    """OpenEXR's RLE: runs and literals, then its predictor and byte interleaving undone."""
    out, i = bytearray(), 0
    while len(out) < size:
        count = struct.unpack("b", src[i : i + 1])[0]
        i += 1
        if count < 0:
            out += src[i : i - count]
            i -= count
        else:
            out += bytes([src[i]]) * (count + 1)
            i += 1
    for k in range(1, len(out)):
        out[k] = (out[k - 1] + out[k] - 128) & 0xFF
    half = (len(out) + 1) // 2
    plain = bytearray(len(out))
    plain[0::2], plain[1::2] = out[:half], out[half:]
    return bytes(plain)


def read_exr(path):
    """The channels of a one-level tiled float32 EXR (no compression or RLE, as lightpath
    writes them), each as a flat row-major list."""
    data = open(path, "rb").read()
    i, attrs = 8, {}
    while data[i] != 0:
        j = data.index(b"\0", i)
        k = data.index(b"\0", j + 1)
        size = struct.unpack("<i", data[k + 1 : k + 5])[0]
        attrs[data[i:j].decode()] = data[k + 5 : k + 5 + size]
        i = k + 5 + size
    i += 1
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"])
    width, height = x1 - x0 + 1, y1 - y0 + 1
    tile_w, tile_h = struct.unpack("<2I", attrs["tiles"][:8])
    names, c = [], attrs["channels"]
    while c[0] != 0:
        end = c.index(b"\0")
        assert struct.unpack("<i", c[end + 1 : end + 5])[0] == 2, "float32 channels only"
        names.append(c[:end].decode())
        c = c[end + 17 :]
    chunks = struct.unpack("<i", attrs["chunkCount"])[0]
    image = {n: [0.0] * (width * height) for n in names}
    for offset in struct.unpack(f"<{chunks}Q", data[i : i + 8 * chunks]):
        tx, ty, _, _, size = struct.unpack("<5i", data[offset : offset + 20])
        w, h = min(tile_w, width - tx * tile_w), min(tile_h, height - ty * tile_h)
        raw = data[offset + 20 : offset + 20 + size]
        if size < w * h * 4 * len(names):
            raw = unrle(raw, w * h * 4 * len(names))
        p = 0
        for row in range(h):
            for name in names:
                start = (ty * tile_h + row) * width + tx * tile_w
                image[name][start : start + w] = struct.unpack(f"<{w}f", raw[p : p + 4 * w])
                p += 4 * w
    return image


def median(values):
    v = sorted(values)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def bright(y):
    top = sorted(y, reverse=True)[: -(-len(y) // 100)]
    threshold = 0.01 * sum(top) / len(top)
    return [i for i, v in enumerate(y) if v > 0 and v >= threshold]


def relative(y, s, i):
    return s[i] / y[i] if y[i] > 0 else math.inf


runs = sys.argv[1:]
if not runs:
    sys.exit(__doc__)
images, photons = {}, {}
for run in runs:
    # runs at different seeds joined by "+" are pooled: each pixel's mean weighted by the
    # photons, its variance of the mean likewise
    total, sums, squares = 0, None, None
    for part in run.split("+"):
        exr = read_exr(f"out/{part}/camera_view.exr")
        # render.json's noise figures read the first channel: Y, or R of a colour image
        channel, error = ("Y", "stderr") if "Y" in exr else ("R", "stderr.R")
        n = json.load(open(f"out/{part}/render.json"))["samples"]
        y, e = exr[channel], exr[error]
        if sums is None:
            sums, squares = [0.0] * len(y), [0.0] * len(y)
        sums = [a + n * v for a, v in zip(sums, y)]
        squares = [a + (n * v) ** 2 for a, v in zip(squares, e)]
        total += n
    images[run] = ([v / total for v in sums], [math.sqrt(v) / total for v in squares])
    photons[run] = total
largest = images[runs[-1]][0]
fixed = bright(largest)
# the brightest pixels alone (along a beam, the beam itself)
brightest = sorted(range(len(largest)), key=lambda i: -largest[i])[:48]
print(f"fixed set: the {len(fixed)} bright pixels of {runs[-1]}")
print("| run | photons | own bright set: pixels, median | fixed set: median, unlit | slope "
      "| 48 brightest: median |")
print("| --- | --- | --- | --- | --- | --- |")
previous = None
for run in runs:
    y, s = images[run]
    own = bright(y)
    noise = median(relative(y, s, i) for i in fixed)
    slope = ""
    if previous:
        slope = f"{math.log(noise / previous[1]) / math.log(photons[run] / previous[0]):.2f}"
    unlit = sum(1 for i in fixed if y[i] <= 0)
    print(f"| {run} | {photons[run]} | {len(own)}, {median(relative(y, s, i) for i in own):.3f} "
          f"| {noise:.3f}, {unlit} | {slope} | {median(relative(y, s, i) for i in brightest):.3f} |")
    previous = (photons[run], noise)
if len(runs) > 1:
    (ya, sa), (yb, sb) = images[runs[0]], images[runs[-1]]
    lit = [i for i in fixed if ya[i] > 0]
    ratios = sorted(relative(yb, sb, i) / relative(ya, sa, i) for i in lit)
    quartiles = [ratios[int(f * (len(ratios) - 1))] for f in (0.25, 0.5, 0.75)]
    expected = math.sqrt(photons[runs[0]] / photons[runs[-1]])
    print(f"per pixel, {runs[-1]}'s relative error over {runs[0]}'s: quartiles "
          + ", ".join(f"{q:.2f}" for q in quartiles) + f" (1/sqrt(photons): {expected:.2f})")
