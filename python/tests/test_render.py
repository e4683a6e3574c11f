"""Rendering a refractive, scattering volume and reading a phase function from speckle images, from
Python: the commands' JSON and files, and images whose pixels add up to the sensors' power."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import lightpath as lp
from conftest import read_json, read_toml
from test_inverse import write_toml


def test_render_equals_the_command_line_and_its_images_add_up(repo, run_cli, tmp_path):
    # the tank's screen, with four time-of-flight bins added through the dict
    tank = read_toml(repo / "configs" / "render_tank.toml")
    tank["transient"] = {"bins": 4, "max_path": 60.0}
    write_toml(tank, tmp_path / "tank.toml")
    out = run_cli("render", str(tmp_path / "tank.toml"), "--samples", "20000", "--seed", "5")
    cli = read_json(out / "render.json")
    seen = []
    py = lp.render(tank, samples=20_000, seed=5, threads=2, progress=lambda d, n: seen.append((d, n)))
    mine = json.loads(py.to_json())
    for d in (mine, cli):
        d.pop("seconds")
        d["statistics"].pop("photons_per_second")
        d["statistics"].pop("steps_per_second")
    assert mine == cli
    assert py.result["sensors"][0]["power"] == cli["sensors"][0]["power"]
    screen = cli["sensors"][0]
    image = py.images["screen_" + screen["name"]]
    h, w = screen["pixels"][1], screen["pixels"][0]
    assert image["value"].shape == (1, h, w) and image["bins_stderr"].shape == (4, 1, h, w)
    # irradiance × pixel area summed over the screen is its power; the bins add up to the whole
    total = image["value"].sum() * screen["pixel_area"]
    assert total == pytest.approx(screen["power"]["mean"], rel=1e-9)
    assert np.allclose(image["bins"].sum(axis=0), image["value"], rtol=1e-9, atol=1e-15)
    assert seen and seen[-1][0] == seen[-1][1] > 0
    # the files are the command's, byte for byte (the EXR of every frame)
    py.save(tmp_path / "py")
    for name in screen["files"]:
        assert (tmp_path / "py" / name).read_bytes() == (out / name).read_bytes(), name
    with pytest.raises(ValueError, match="needs a render config"):
        lp.render(repo / "configs" / "quickstart.toml")


def test_render_takes_several_volumes_from_a_dict(repo):
    # the example's three volumes, rendered by particle tracing; then two of them made to overlap
    scene = read_toml(repo / "configs" / "render_volumes.toml")
    scene["render"]["estimator"] = "particle"
    r = lp.render(scene, samples=2000, seed=3, threads=2)
    assert len(r.result["config"]["volume"]) == 3
    assert r.result["cameras"][0]["irradiance"]["mean"] > 0
    scene["volume"][1]["center"] = [-1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"volume\[0\] and volume\[1\] overlap"):
        lp.render(scene, samples=100)


def test_a_bidirectional_render_splits_each_cameras_total_by_strategy(repo):
    # the glass ball over its floor, lit from above: every path the camera sees scatters at least
    # once (in the ball or on the floor), so the strategies' parts sum to its irradiance
    scene = read_toml(repo / "configs" / "render_glass.toml")
    scene["light"]["position"] = [0.0, 0.0, 2.0]
    camera = lp.render(scene, samples=2000, seed=3, threads=2).result["cameras"][0]
    parts = camera["strategies"]
    assert [(p["events"], p.get("from_light")) for p in parts[:3]] == [(1, 0), (1, 1), (2, 0)]
    assert len(parts) == 15 and parts[-1]["events"] == 5 and "from_light" not in parts[-1]
    total = sum(p["irradiance"]["mean"] for p in parts)
    assert total == pytest.approx(camera["irradiance"]["mean"], rel=1e-9)
    # a one-event path is made both ways here: the lamp joined to a camera event, a lamp event
    # seen by the camera
    assert parts[0]["irradiance"]["mean"] > 0 and parts[1]["irradiance"]["mean"] > 0
    # particle tracing makes every path one way: no split
    scene["render"]["estimator"] = "particle"
    camera = lp.render(scene, samples=500, seed=3, threads=2).result["cameras"][0]
    assert "strategies" not in camera


def test_render_vjp_differentiates_each_volumes_medium(repo):
    # the example's three volumes, the view's left half a window (an output of its own)
    scene = read_toml(repo / "configs" / "render_volumes.toml")
    scene["render"].update(estimator="particle", samples=3000, chunk=500, seed=3)
    scene["sensor"][0]["window"] = [{"name": "left", "columns": [0, 47], "rows": [0, 63]}]
    params = ["volume[2].sigma_a", "volume[0].g", "volume[0].sigma_s"]
    vjp = lp.render_vjp(scene, params, threads=2)
    assert vjp.sensors == ["left"] and list(vjp.theta) == [0.8, 0.6, 3.0]
    assert np.all(np.isfinite(vjp.jacobian)) and np.all(vjp.jacobian_stderr > 0)
    # theta sets each volume's own medium: the same photons as the config with those values
    theta = [1.1, 0.5, 2.5]
    moved = lp.render_vjp(scene, params, theta=theta, threads=2)
    scene["volume"][2]["medium"]["sigma_a"] = 1.1
    scene["volume"][0]["medium"]["phase"]["g"] = 0.5
    scene["volume"][0]["medium"]["sigma_s"] = 2.5
    written = lp.render_vjp(scene, params, threads=2)
    assert list(written.theta) == theta
    assert np.array_equal(moved.value, written.value)
    assert np.array_equal(moved.jacobian, written.jacobian)
    assert not np.array_equal(moved.value, vjp.value)
    with pytest.raises(ValueError, match=r"volume\[i\]\.sigma_s"):
        lp.render_vjp(scene, ["sigma_s"])
    with pytest.raises(ValueError, match=r"volume\[0\]"):
        lp.render_vjp(scene, params, theta=[1.1, 0.5, -2.0])


def test_render_derivatives_give_the_gradient_of_a_loss(tmp_path):
    # a Fresnel slab's transmission and reflection with their derivatives by the medium; the
    # gradient of a loss on the powers is the chain rule through them
    text = """
[field]
profiles = [{ kind = "constant", n = 1.33 }]
bounds = { kind = "box", size = [60.0, 60.0, 1.0] }
[medium]
sigma_s = 2.0
sigma_a = 0.3
phase = { kind = "hg", g = 0.6 }
[light]
kind = "beam"
center = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, 1.0]
[[sensor]]
kind = "flux"
name = "T"
center = [0.0, 0.0, 0.5]
normal = [0.0, 0.0, 1.0]
[[sensor]]
kind = "flux"
name = "R"
center = [0.0, 0.0, -0.5]
normal = [0.0, 0.0, 1.0]
[render]
samples = 200000
chunk = 5000
derivatives = ["sigma_s", "sigma_a", "g"]
"""
    r = lp.render(lp.loads(text), threads=2).result
    sensors = {s["name"]: s for s in r["sensors"]}
    jac = np.array([[sensors[n]["derivatives"][p]["mean"] for p in ("sigma_s", "sigma_a", "g")]
                    for n in ("T", "R")])
    err = np.array([[sensors[n]["derivatives"][p]["stderr"] for p in ("sigma_s", "sigma_a", "g")]
                    for n in ("T", "R")])
    # absorption lowers both; forward scattering (g) lets more through and sends less back
    assert (jac[:, 1] < -4 * err[:, 1]).all()
    assert jac[0, 2] > 4 * err[0, 2] and jac[1, 2] < -4 * err[1, 2]
    # the derivatives come with the powers, from the same photons
    assert sensors["T"]["power"]["mean"] > 0.2
    with pytest.raises(ValueError, match="render.derivatives"):
        lp.loads(text.replace('"g"]', '"g", "bin[2]"]'))


GRADED_BALL = """
[field]
bounds = { kind = "sphere", radius = 1.0 }
n_out = 1.0
[[field.profiles]]
kind = "spherical_polynomial"
n0 = 1.3
coefficients = [0.0, 0.05]
[medium]
sigma_s = 1.5
sigma_a = 0.2
phase = { kind = "hg", g = 0.5 }
[light]
kind = "beam"
center = [0.0, 0.0, -2.0]
direction = [0.0, 0.0, 1.0]
radius = 0.6
[[sensor]]
kind = "target"
name = "spot"
center = [0.0, 0.1, 0.55]
radius = 0.3
[[sensor]]
kind = "target"
name = "core"
center = [0.0, 0.0, 0.0]
size = [0.5, 0.5, 0.5]
[render]
samples = 4000
chunk = 500
seed = 7
step = 0.01
derivatives = ["profiles[0].c2", "sigma_s", "profiles[0].n0"]
"""


def test_render_vjp_is_the_renders_jacobian_and_held_photons_differentiate_exactly():
    config = lp.loads(GRADED_BALL)
    params = ["profiles[0].c2", "sigma_s", "profiles[0].n0"]
    vjp = lp.render_vjp(config, params, threads=2)
    assert isinstance(vjp, lp.RenderVjp)
    assert vjp.sensors == ["spot", "core"] and vjp.params == params
    assert list(vjp.theta) == [0.05, 1.5, 1.3] and not vjp.held
    # the same photons as the command's render with these derivatives: the same numbers
    targets = lp.render(config, threads=2).result["targets"]
    for i, t in enumerate(targets):
        assert vjp.value[i] == pytest.approx(t["fluence"]["mean"], rel=1e-12)
        assert vjp.stderr[i] == pytest.approx(t["fluence"]["stderr"], rel=1e-12)
        for k, name in enumerate(params):
            d = t["derivatives"][name]
            assert vjp.jacobian[i, k] == pytest.approx(d["mean"], rel=1e-9, abs=1e-15), name
            assert vjp.jacobian_stderr[i, k] == pytest.approx(d["stderr"], rel=1e-9), name
    # the VJP contracts the Jacobian with the adjoint
    adjoint = np.array([1.0 / vjp.value[0], -0.5])
    assert np.allclose(vjp(adjoint), adjoint @ vjp.jacobian, rtol=1e-12, atol=0)
    # held photons: the same bits at the same theta, and the Jacobian is the derivative of the
    # outputs (central differences of 1e-7 on the same photons)
    field = ["profiles[0].n0", "profiles[0].c2"]
    held = lp.render_vjp(config, field, theta=[1.4, -0.1], photons=2000, held=True, threads=2)
    again = lp.render_vjp(config, field, theta=[1.4, -0.1], photons=2000, held=True, threads=2)
    assert held.held and np.array_equal(held.value, again.value)
    for k in range(2):
        step = np.zeros(2)
        step[k] = 1e-7
        up, down = (
            lp.render_vjp(config, field, theta=list(np.array([1.4, -0.1]) + s), photons=2000,
                          held=True, threads=2).value
            for s in (step, -step)
        )
        fd = (up - down) / 2e-7
        assert np.allclose(held.jacobian[:, k], fd, rtol=1e-4, atol=0), (k, held.jacobian, fd)
    with pytest.raises(ValueError, match="sigma_s"):
        lp.render_vjp(config, ["sigma_s"], held=True)
    with pytest.raises(ValueError, match="params"):
        lp.render_vjp(config, ["profiles[0].c7"])
    with pytest.raises(ValueError, match="adjoint"):
        vjp([1.0, 2.0, 3.0])


def test_a_spots_power_and_its_field_derivatives_come_through_render_vjp():
    spot = """[[sensor]]
kind = "spot"
name = "focus"
center = [0.0, 0.0, 1.4]
normal = [0.0, 0.0, 1.0]
radius = 0.3
[render]"""
    config = lp.loads(GRADED_BALL.replace("[render]", spot, 1))
    sensors = {s["name"]: s for s in lp.render(config, threads=2).result["sensors"]}
    assert sensors["focus"]["kind"] == "spot" and sensors["focus"]["radius"] == 0.3
    field = ["profiles[0].n0", "profiles[0].c2"]
    theta = np.array([1.3, -0.25])
    held = lp.render_vjp(config, field, theta=list(theta), photons=2000, held=True, threads=2)
    assert held.sensors == ["spot", "core", "focus"] and held.value[2] > 0
    for k in range(2):
        step = np.zeros(2)
        step[k] = 1e-7
        up, down = (
            lp.render_vjp(config, field, theta=list(theta + s), photons=2000, held=True,
                          threads=2).value
            for s in (step, -step)
        )
        fd = (up[2] - down[2]) / 2e-7
        assert held.jacobian[2, k] == pytest.approx(fd, rel=1e-4), (k, held.jacobian, fd)
    # a box-filtered screen has edges the field derivatives do not follow
    screen = spot.replace('"spot"', '"screen"').replace("radius = 0.3", "size = [1.0, 1.0]\npixels = [4, 4]")
    with pytest.raises(ValueError, match="tent"):
        lp.render_vjp(lp.loads(GRADED_BALL.replace("[render]", screen, 1)), field)


def test_a_probes_fluence_and_its_derivatives_come_through_render_and_render_vjp():
    probe = """[[sensor]]
kind = "fluence"
name = "deep"
position = [0.0, 0.1, 0.4]
[render]"""
    config = lp.loads(GRADED_BALL.replace("[render]", probe, 1))
    params = ["profiles[0].c2", "sigma_s", "profiles[0].n0"]
    vjp = lp.render_vjp(config, params, threads=2)
    # the probes after the other sensors, as the command's render.json reports them
    assert vjp.sensors == ["spot", "core", "deep"]
    (deep,) = lp.render(config, threads=2).result["probes"]
    assert vjp.value[2] == pytest.approx(deep["fluence"]["mean"], rel=1e-12)
    for k, name in enumerate(params):
        d = deep["derivatives"][name]
        assert vjp.jacobian[2, k] == pytest.approx(d["mean"], rel=1e-9, abs=1e-15), name
    # held photons: the probe's Jacobian is the derivative of its fluence
    field = ["profiles[0].n0", "profiles[0].c2"]
    theta = np.array([1.3, -0.25])
    held = lp.render_vjp(config, field, theta=list(theta), photons=500, held=True, threads=2)
    for k in range(2):
        step = np.zeros(2)
        step[k] = 1e-7
        up, down = (
            lp.render_vjp(config, field, theta=list(theta + s), photons=500, held=True,
                          threads=2).value
            for s in (step, -step)
        )
        fd = (up[2] - down[2]) / 2e-7
        assert held.jacobian[2, k] == pytest.approx(fd, rel=1e-4), (k, held.jacobian, fd)


STEP_DEG = 0.15
PIXELS = 64
PEAKS = [(32, 8), (32, 40)]


def pixel_direction(ix, iy):
    c = (PIXELS - 1) / 2
    v = [math.tan(math.radians((i - c) * STEP_DEG)) for i in (ix, iy)] + [1.0]
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def test_acquire_phase_equals_the_command_line(run_cli, tmp_path):
    # speckle images of a thin HG slab under two tilted plane waves, rendered from Python
    scene = {
        "wavelength": 0.474,
        "medium": {"slab": 100.0, "slab_window": 136.0, "mfp": 100.0,
                   "phase": {"kind": "hg", "g": 0.9}},
        "light": [{"kind": "plane_wave", "direction": pixel_direction(*p)} for p in PEAKS],
        "view": [{"kind": "far_field_grid", "center": [0.0, 0.0, 1.0],
                  "width_deg": PIXELS * STEP_DEG, "pixels": [PIXELS, PIXELS]}],
        "speckle": {"realisations": 3, "paths": 3000},
        "render": {"seed": 7, "chunk": 500},
    }
    lp.speckle(scene).save(tmp_path / "render")
    acquisition = {
        "acquisition": {"focal_length": 1.0, "pixel_pitch": math.tan(math.radians(STEP_DEG)),
                        "n_sample": 1.0, "window": 8, "step": 4},
        "pair": [{"first": f"render/speckle_{r:04}_l0.exr", "second": f"render/speckle_{r:04}_l1.exr",
                  "peaks": [list(PEAKS[0]), list(PEAKS[1])]} for r in range(3)],
    }
    write_toml(acquisition, tmp_path / "acquire.toml")
    cli = read_json(run_cli("acquire-phase", str(tmp_path / "acquire.toml"), quiet=False)
                    / "phase_acquisition.json")
    py = lp.acquire_phase(lp.load(acquisition, base=tmp_path))
    mine = json.loads(py.to_json())
    assert mine.pop("seconds") >= 0 and cli.pop("seconds") >= 0
    # the echoed config holds the image paths as each loader resolved them
    mine.pop("config"), cli.pop("config")
    assert mine == cli
    curve = py.curves[0]
    readings = cli["curves"][0]["readings"]
    assert curve["delta_deg"] == cli["curves"][0]["delta_deg"]
    assert np.array_equal(curve["correlation"], [r["correlation"] for r in readings])
    assert np.array_equal(curve["angle_deg"], [r["angle_deg"] for r in readings])
    assert [p.name for p in py.save(tmp_path / "py")] == ["phase_acquisition.json", "phase_acquisition.png"]
    with pytest.raises(ValueError, match="needs an acquisition config"):
        lp.acquire_phase(scene)
