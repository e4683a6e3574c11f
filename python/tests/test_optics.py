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
    with pytest.raises(ValueError, match="^diameter -1"):
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


def exit_loss(at, a, b) -> float:
    return float(np.sum(a * at.exit_position) + np.sum(b * at.exit_direction))


def test_trace_vjp_matches_central_differences_for_a_parameter(repo):
    config = repo / "configs" / "luneburg.toml"
    rng = np.random.default_rng(1)
    at = lp.trace_vjp(config, ["profiles[0].radius"], theta=[1.05])
    assert at.theta.tolist() == [1.05] and at.exit_position.shape == (15, 3)
    a, b = rng.normal(size=(15, 3)), rng.normal(size=(15, 3))
    g = at(a, b)
    assert g["grid"] is None and g["origin"].shape == (15, 3)
    h = 1e-6
    fd = (exit_loss(lp.trace_vjp(config, ["profiles[0].radius"], theta=[1.05 + h]), a, b)
          - exit_loss(lp.trace_vjp(config, ["profiles[0].radius"], theta=[1.05 - h]), a, b)) / (2 * h)
    assert g["params"][0] == pytest.approx(fd, rel=1e-4)
    # the same for any thread count, bit for bit
    assert np.array_equal(lp.trace_vjp(config, ["profiles[0].radius"], theta=[1.05], threads=1)(a, b)["params"],
                          g["params"])
    with pytest.raises(ValueError, match="profiles\\[i\\].name"):
        lp.trace_vjp(config, ["radius"])
    with pytest.raises(ValueError, match="no grid profile"):
        lp.trace_vjp(config, grid=True)
    with pytest.raises(ValueError, match="d_position: shape"):
        at(a[:3], b)


GRID_TRACE = {
    "field": {
        "profiles": [{
            "kind": "grid", "dims": [8, 8, 8], "origin": [-1.05, -1.05, -1.05], "spacing": 0.3,
            "values": [1.3 + 0.01 * x - 0.004 * y * y for z in range(8) for y in range(8) for x in range(8)],
        }],
        "bounds": {"kind": "box", "size": [1.8, 1.8, 1.8]},
        "n_out": 1.0,
    },
    "rays": {"kind": "collimated", "center": [0.0, 0.0, -2.0], "direction": [0.0, 0.0, 1.0], "width": 1.2, "count": 5},
    "trace": {"step": 0.01},
}


def test_trace_vjp_matches_central_differences_for_grid_coefficients():
    rng = np.random.default_rng(2)
    at = lp.trace_vjp(GRID_TRACE, grid=True)
    n = at.exit_position.shape[0]
    a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    g = at(a, b)["grid"]
    assert g.shape == (8, 8, 8)
    c = at.coefficients  # B-spline coefficients (prefiltered samples), [dz, dy, dx]
    assert c.shape == (8, 8, 8)
    same = lp.trace_vjp(GRID_TRACE, coefficients=c)
    assert np.array_equal(same.exit_position, at.exit_position)
    # the two coefficients with the largest gradients, by central differences
    for k in np.argsort(-np.abs(g).ravel())[:2]:
        idx = np.unravel_index(k, g.shape)
        h = 1e-6
        up, down = c.copy(), c.copy()
        up[idx] += h
        down[idx] -= h
        fd = (exit_loss(lp.trace_vjp(GRID_TRACE, coefficients=up), a, b)
              - exit_loss(lp.trace_vjp(GRID_TRACE, coefficients=down), a, b)) / (2 * h)
        assert g[idx] == pytest.approx(fd, rel=1e-4), idx
