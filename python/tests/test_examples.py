"""The examples run as a new user runs them (without matplotlib they print and skip the plot)."""

from __future__ import annotations

import re
import subprocess
import sys


def run(repo, name: str, tmp_path) -> str:
    done = subprocess.run([sys.executable, str(repo / "python" / "examples" / name), str(tmp_path / "plot.png")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_luneburg_design_recovers_the_lens_shape(repo, tmp_path):
    out = run(repo, "luneburg_design.py", tmp_path)
    shape = float(re.search(r"for r ≤ 0.9: ([0-9.]+)", out).group(1))
    assert shape < 0.03, out  # the designed profile has the Luneburg shape to a few per cent


def test_render_tank_prints_the_far_wall(repo, tmp_path):
    out = run(repo, "render_tank.py", tmp_path)
    assert "far_wall" in out and "screen_far_wall: 120×120 pixels" in out, out
