"""A laser beam through a tank whose index rises with height (a sugar gradient, n = 1.33 + 0.02 y)
in a weakly scattering liquid: the beam bends upwards, towards the higher index, and leaves the far
wall 0.75 higher than it entered. The far wall's irradiance image, rendered by particle tracing from
Python, with its standard error per pixel.

    python python/examples/render_tank.py [out.png]

Plots with matplotlib when it is installed; prints the totals either way.
"""

import sys
from pathlib import Path

import numpy as np

import lightpath as lp

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    render = lp.render(REPO / "configs" / "render_tank.toml", samples=100_000)
    print(render.summary)
    (name, image), = render.images.items()
    value, stderr = image["value"][0], image["stderr"][0]  # [H, W], top row first
    lit = value > 0
    print(f"{name}: {value.shape[1]}×{value.shape[0]} pixels, mean relative error of the lit "
          f"pixels {float((stderr[lit] / value[lit]).mean()):.3f}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(install matplotlib for the plot)")
        return
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("render_tank.png")
    fig, ax = plt.subplots(figsize=(5, 5))
    # log scale: the beam's spot (0.75 above the centre) and the faint halo of scattered light
    ax.imshow(np.log10(value + 1e-5 * value.max()), cmap="inferno")
    ax.set_title(f"{name}: log10 irradiance")
    ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
