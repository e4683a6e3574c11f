"""The Python results are the command line's: same numbers bit for bit for the same config, samples
and seed (whatever the thread count), same JSON, same files."""

from __future__ import annotations

import numpy as np
import pytest

import lightpath as lp
from conftest import read_json, read_toml


def nested_complex(d: dict, re: str, im: str) -> np.ndarray:
    return np.array(d[re]) + 1j * np.array(d[im])


def test_covariance_equals_the_command_line_bit_for_bit(repo, run_cli):
    config = repo / "configs" / "covariance_box.toml"
    out = run_cli("covariance", str(config), "--samples", "20000", "--seed", "7", "--threads", "1")
    cli = read_json(out / "covariance.json")
    py = lp.covariance(config, samples=20000, seed=7, threads=2)

    assert py.covariance.shape == (2, 2, 72, 72)
    assert py.covariance.dtype == np.complex128
    assert np.array_equal(py.covariance, nested_complex(cli, "re", "im"))
    assert np.array_equal(py.stderr, np.array(cli["stderr"]))
    assert np.array_equal(py.single, nested_complex(cli, "single_re", "single_im"))
    assert np.array_equal(py.multiple, nested_complex(cli, "multiple_re", "multiple_im"))
    assert np.array_equal(py.single_stderr, np.array(cli["single_stderr"]))
    assert np.array_equal(py.multiple_stderr, np.array(cli["multiple_stderr"]))
    assert np.array_equal(py.mean, nested_complex(cli, "mean_re", "mean_im"))
    assert py.mean_stderr is None and py.solver is None
    assert np.array_equal(py.intensity, np.einsum("llvv->lv", py.covariance).real)
    assert py.run.samples == cli["samples"] == 20000
    assert py.run.seed == cli["seed"] == 7

    # the JSON text is the command's, up to the wall time
    mine = __import__("json").loads(py.to_json())
    assert mine.pop("seconds") > 0 and cli.pop("seconds") > 0
    assert mine == cli


def test_memory_effect_and_speckle_equal_the_command_line(repo, run_cli, tmp_path):
    config = repo / "configs" / "quickstart.toml"
    out = run_cli("memory-effect", str(config), "--samples", "20000", "--seed", "3")
    cli = read_json(out / "memory_effect.json")
    py = lp.memory_effect(config, samples=20000, seed=3, threads=1)
    for key in ["angles_deg", "correlation", "correlation_stderr", "field_correlation", "diffusion_eq39"]:
        assert np.array_equal(getattr(py, key), np.array(cli[key])), key
    assert py.thickness == cli["thickness"]
    files = py.save(tmp_path / "saved")
    assert sorted(f.name for f in files) == ["memory_effect.json", "memory_effect.png"]

    grid = repo / "configs" / "speckle_grid.toml"
    out = run_cli("speckle", str(grid), "--samples", "500", "--seed", "5")
    cli = read_json(out / "speckle.json")
    py = lp.speckle(grid, paths=500, seed=5)
    assert py.fields.shape == (2, 3, 64 * 64)
    assert py.images.shape == (2, 3, 64, 64)
    assert np.array_equal(py.fields, nested_complex(cli, "re", "im").reshape(2, 3, -1))
    assert np.array_equal(py.images[1, 2].ravel(), py.fields[1, 2])
    saved = py.save(tmp_path / "speckle")
    assert (tmp_path / "speckle" / "speckle.json").is_file()
    assert len([f for f in saved if f.suffix == ".exr"]) >= 2


WAVE_SCENE = {
    "wavelength": 1.0,
    "medium": {"box": [3.0, 3.0, 3.0], "mfp": 3.0},
    "light": [{"kind": "plane_wave", "direction": [0.0, 0.0, 1.0]}],
    "view": [
        {"kind": "far_field_ring", "start": [0.0, 0.0, 1.0], "axis": [0.0, 1.0, 0.0], "count": 5}
    ],
}


def test_wave_solver_equals_the_command_line(run_cli, tmp_path):
    config = tmp_path / "wave.toml"
    config.write_text(
        'wavelength = 1.0\n[medium]\nbox = [3.0, 3.0, 3.0]\nmfp = 3.0\n'
        '[[light]]\nkind = "plane_wave"\ndirection = [0.0, 0.0, 1.0]\n'
        '[[view]]\nkind = "far_field_ring"\nstart = [0.0, 0.0, 1.0]\naxis = [0.0, 1.0, 0.0]\ncount = 5\n'
    )
    out = run_cli("wave", str(config), "--realizations", "8", "--seed", "2")
    cli = read_json(out / "covariance.json")
    py = lp.wave(WAVE_SCENE, realizations=8, seed=2)
    assert py.solver == "foldy-lax" and py.realizations == 8
    assert np.array_equal(py.covariance, nested_complex(cli, "re", "im"))
    assert np.array_equal(py.mean_stderr, np.array(cli["mean_stderr"]))
    with pytest.raises(ValueError, match="realizations 1"):
        lp.wave(WAVE_SCENE, realizations=1)


def test_single_scattering_closed_form(repo):
    config = read_toml(repo / "configs" / "covariance_box.toml")
    config["render"]["estimator"] = "single_scattering"
    closed = lp.covariance(config)
    assert closed.solver == "single_scattering"
    assert np.all(closed.stderr == 0.0)
    assert closed.multiple is None
    # the Monte Carlo's single-scattering part agrees with it within its standard errors
    config["render"]["estimator"] = "monte_carlo"
    mc = lp.covariance(config, samples=100_000, seed=11)
    diff = np.einsum("llvv->lv", np.abs(mc.single - closed.covariance))
    allowed = np.einsum("llvv->lv", 5.0 * mc.single_stderr + 1e-9 * np.abs(closed.covariance))
    assert np.all(diff <= allowed), diff / allowed


def test_correlation_map_equals_the_command_line(repo, run_cli, tmp_path):
    config = repo / "configs" / "correlation_map.toml"
    out = run_cli("correlation-map", str(config), "--samples", "4000", "--seed", "2")
    cli = read_json(out / "correlation_map.json")
    py = lp.correlation_map(config, samples=4000, seed=2)
    assert py.correlation.shape == (4, 17, 17) and py.taus.shape == (17, 17, 3)
    assert np.array_equal(py.correlation, nested_complex(cli, "re", "im"))
    assert np.array_equal(py.normalised, np.array(cli["normalised"]))
    assert np.array_equal(py.deltas, np.array(cli["deltas"]))
    saved = py.save(tmp_path / "map")
    assert sorted(f.name for f in saved) == ["correlation_map.json", "correlation_map.png"]
    assert (tmp_path / "map" / "correlation_map.png").read_bytes() == (out / "correlation_map.png").read_bytes()


def test_compare_reports_as_the_command_line(repo, cli, tmp_path):
    config = repo / "configs" / "covariance_box.toml"
    a = lp.covariance(config, samples=20_000, seed=1)
    b = lp.covariance(config, samples=20_000, seed=2)
    a.save(tmp_path / "a")
    b.save(tmp_path / "b")
    import subprocess

    run = subprocess.run(
        [str(cli), "compare", str(tmp_path / "a" / "covariance.json"), str(tmp_path / "b" / "covariance.json")],
        capture_output=True, text=True,
    )
    got = lp.compare(a, tmp_path / "b" / "covariance.json")
    assert got["report"] in run.stdout
    assert got["agree"] == (run.returncode == 0)
    assert len(got["pairs"]) == 4 and got["pairs"][1]["lights"] == (0, 1)
    # two independent runs of the same scene: most entries within 3 standard errors
    assert all(p["within_3se"] > 0.9 for p in got["pairs"])
    assert lp.compare(a, a)["pairs"][0]["error"] == 0.0
    with pytest.raises(TypeError, match="a lightpath.Covariance or the path"):
        lp.compare(a, 3)
    with pytest.raises(ValueError, match="shapes differ"):
        lp.compare(a, lp.covariance(repo / "configs" / "quickstart.toml", samples=1000))


def test_tilt_shift_equals_the_command_line(repo, run_cli, tmp_path):
    config = repo / "configs" / "tilt_shift.toml"
    out = run_cli("tilt-shift", str(config), "--samples", "4000", "--seed", "6")
    cli = read_json(out / "tilt_shift.json")
    py = lp.tilt_shift(config, samples=4000, seed=6)
    cells = py.cells
    assert cells["correlation"].shape == (81,)
    assert np.array_equal(cells["correlation"], [c["re"] + 1j * c["im"] for c in cli["cells"]])
    assert np.array_equal(cells["normalised_stderr"], [c["normalised_stderr"] for c in cli["cells"]])
    assert py.grid["normalised"].shape == (9, 9) and py.refocus is None
    assert np.array_equal(py.grid["model"], cli["grid"]["model"])
    assert py.depth == cli["depth"] and py.transport_mfp == cli["transport_mfp"]
    py.save(tmp_path / "ts")
    assert (tmp_path / "ts" / "tilt_shift.png").read_bytes() == (out / "tilt_shift.png").read_bytes()
