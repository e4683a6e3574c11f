"""A Luneburg lens by design from Python: starting from n ≡ 1 in the unit sphere, Adam shapes a
grid field (8³ → 16³ → 24³) so that six collimated beams focus on the sphere's far side, and the
designed radial profile is compared with n = sqrt(2 − r²) after the best scale (rays see n only up
to a constant factor). About a second.

    python python/examples/luneburg_design.py [out.png]

Plots with matplotlib when it is installed; prints the comparison either way.
"""

import sys
from pathlib import Path

import numpy as np

import lightpath as lp

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    task = lp.load(REPO / "experiments" / "luneburg-design" / "luneburg.toml")
    design = lp.design(task, progress=lambda done, total: print(f"\r{done}/{total} iterations", end=""))
    print(f"\n{design.summary}")
    p = design.radial_profile
    r, mean = p["r"], p["mean"]
    luneburg = np.sqrt(2.0 - r**2)
    inner = r <= 0.9
    scale = np.dot(mean[inner], luneburg[inner]) / np.dot(luneburg[inner], luneburg[inner])
    shape = np.sqrt(np.mean((mean[inner] / scale - luneburg[inner]) ** 2))
    print(f"best scale {scale:.4f}; RMS(n / scale − sqrt(2 − r²)) for r ≤ 0.9: {shape:.4f}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(install matplotlib for the plot)")
        return
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("luneburg_design.png")
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.fill_between(r, p["min"] / scale, p["max"] / scale, alpha=0.3, label="designed, 26 directions")
    a.plot(r, mean / scale, label=f"designed mean / {scale:.3f}")
    a.plot(r, luneburg, "k--", label="Luneburg sqrt(2 − r²)")
    a.set_xlabel("r")
    a.set_ylabel("n")
    a.legend()
    b.semilogy(design.log_mean_miss2)
    b.set_xlabel("Adam iteration (three levels)")
    b.set_ylabel("mean squared miss distance")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
