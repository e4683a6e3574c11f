"""Mie spheres and ray tracing from Python equal the commands' JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lightpath as lp
from conftest import read_json


def test_mie_equals_the_command_line(run_cli, tmp_path):
    out = run_cli("mie", "--diameter", "4", "--n-particle", "1.59", "--n-medium", "1.335",
                  "--wavelength", "0.6328", "--angles", "181", "--volume-fraction", "0.01", quiet=False)
    cli = read_json(out / "mie.json")
    py = lp.mie(4.0, 1.59, 0.6328, n_medium=1.335, angles=181, volume_fraction=0.01)
    for key in ["size_parameter", "terms", "q_ext", "q_sca", "q_abs", "q_back", "g", "c_sca", "c_back"]:
        assert getattr(py, key) == cli[key], key
    assert np.array_equal(py.theta_deg, cli["theta_deg"])
    assert np.array_equal(py.phase, cli["phase"])
    assert np.array_equal(py.s1, np.array(cli["s1_re"]) + 1j * np.array(cli["s1_im"]))
    assert py.bulk == cli["bulk"]
    # the phase function is normalised over the sphere (on a grid fine enough for its forward peak)
    fine = lp.mie(4.0, 1.59, 0.6328, n_medium=1.335, angles=7201)
    mu = np.cos(np.radians(fine.theta_deg))
    trapezoid = getattr(np, "trapezoid", None) or np.trapz
    assert trapezoid(fine.phase, -mu) * 2 * np.pi == pytest.approx(1.0, rel=1e-4)
    assert fine.g == py.g
    assert [f.name for f in py.save(tmp_path / "m")] == ["mie.json", "mie.png"]
    with pytest.raises(ValueError, match="--diameter -1"):
        lp.mie(-1.0, 1.59, 0.6328)


def test_trace_equals_the_command_line(repo, run_cli, tmp_path):
    config = repo / "configs" / "luneburg.toml"
    out = run_cli("trace", str(config), quiet=False)
    cli = read_json(out / "rays.json")
    py = lp.trace(config, threads=1)
    n = len(cli["rays"])
    assert py.exit_position.shape == (n, 3)
    assert np.array_equal(py.exit_position, [r["exit_position"] for r in cli["rays"]])
    assert np.array_equal(py.exit_direction, [r["exit_direction"] for r in cli["rays"]])
    assert np.array_equal(py.optical_path, [r["optical_path"] for r in cli["rays"]])
    assert py.exited.all() and py.step_error == cli["step_error"]
    assert len(py.paths) == n and py.paths[0].shape[1] == 3
    mine = json.loads(py.to_json())
    mine.pop("seconds"), cli.pop("seconds")
    assert mine == cli
    with pytest.raises(ValueError, match="needs a trace config"):
        lp.trace(repo / "configs" / "quickstart.toml")
