"""The quick start from Python: the memory effect of a slab of optical depth 10 in transmission,
against the diffusion prediction of Eq. 39 (``cargo run --release`` runs the same config).

    python python/examples/memory_effect.py [out.png]

Plots with matplotlib when it is installed; prints the curve either way.
"""

import sys
from pathlib import Path

import lightpath as lp

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    task = lp.load(REPO / "configs" / "quickstart.toml")
    print(task.describe())
    curve = lp.memory_effect(task, progress=lambda done, total: print(f"\r{done}/{total} chunks", end=""))
    print(f"\n{curve.run.samples} paths in {curve.run.seconds:.1f} s")
    print("angle [deg]   correlation ± stderr   Eq. 39")
    for a, c, s, d in zip(curve.angles_deg, curve.correlation, curve.correlation_stderr, curve.diffusion_eq39):
        print(f"{a:>10.3f}   {c:.4f} ± {s:.4f}      {d:.4f}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(install matplotlib for the plot)")
        return
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("memory_effect.png")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.errorbar(curve.angles_deg, curve.correlation, 2 * curve.correlation_stderr, fmt="o", label="Monte Carlo (±2 SE)")
    ax.plot(curve.angles_deg, curve.diffusion_eq39, "-", label="diffusion, Eq. 39")
    ax.set_xlabel("tilt angle θ [deg]")
    ax.set_ylabel("intensity correlation")
    ax.set_title(f"memory effect, slab L = {curve.thickness:g} λ")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
