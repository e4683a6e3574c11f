"""A config from a dict is the config from its TOML: same validation, same messages, same task."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lightpath as lp
from conftest import read_toml


def test_dict_and_toml_give_the_same_task_and_numbers(repo):
    path = repo / "configs" / "covariance_box.toml"
    from_file = lp.load(path)
    from_dict = lp.load(read_toml(path))
    from_text = lp.loads(path.read_text())
    assert from_file.kind == from_dict.kind == from_text.kind == "scene"
    assert json.loads(from_file.config_json()) == json.loads(from_dict.config_json())
    assert from_file.describe() == from_dict.describe() == from_text.describe()
    a = lp.covariance(from_file, samples=5000, seed=4)
    b = lp.covariance(read_toml(path), samples=5000, seed=4)
    assert np.array_equal(a.covariance, b.covariance)


def test_numpy_values_and_integers_are_read_like_toml(repo):
    config = read_toml(repo / "configs" / "quickstart.toml")
    config["medium"]["slab"] = np.float64(200.0)
    config["medium"]["mfp"] = 20  # an integer where TOML would write 20.0
    config["light"][0]["direction"] = np.array([0.0, 0.0, 1.0])
    config["memory_effect"]["angles_deg"] = np.linspace(0.01, 0.2, 5)
    config["render"]["samples"] = np.int64(2000)
    task = lp.load(config)
    echoed = json.loads(task.config_json())
    assert echoed["medium"]["mfp"] == 20.0
    assert echoed["render"]["samples"] == 2000
    assert echoed["memory_effect"]["angles_deg"] == pytest.approx(np.linspace(0.01, 0.2, 5))


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda c: c["medium"].update(albedo=1.3), r"medium\.albedo = 1\.3: must be within \[0, 1\]"),
        (lambda c: c["medium"].update(slab=None), r"medium\.slab = None"),
        (lambda c: c["medium"].update(colour="red"), r"unknown field `colour`"),
        (lambda c: c["light"][0].update(direction=[0.0, 1.0]), r"light\[0\]\.direction"),
        (lambda c: c["medium"].update(mfp=1e308), r"medium\.mfp = 1e308"),
        (lambda c: c["medium"].update(phase={"kind": "isotropic", "g": 0.9}), r"medium\.phase"),
        (lambda c: c["medium"].update(mfp=object()), r"medium\.mfp: a object is not a config value"),
        (lambda c: c.pop("wavelength"), r"wavelength"),
    ],
)
def test_bad_values_raise_value_errors_naming_the_key(repo, edit, message):
    config = read_toml(repo / "configs" / "quickstart.toml")
    edit(config)
    with pytest.raises(ValueError, match=message):
        lp.load(config)


def test_the_wrong_kind_of_config_or_file(repo, tmp_path):
    with pytest.raises(ValueError, match="needs a speckle scene"):
        lp.covariance(repo / "configs" / "luneburg.toml")
    with pytest.raises(OSError, match="no such config file"):
        lp.load(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="invalid TOML"):
        lp.loads("wavelength = = 1")
    with pytest.raises(TypeError, match="a path, a dict or a lightpath.Task"):
        lp.load(3.0)
    with pytest.raises(ValueError, match="^samples 0"):
        lp.covariance(repo / "configs" / "quickstart.toml", samples=0)
    with pytest.raises(ValueError, match="memory-effect needs a \\[memory_effect\\] table"):
        lp.memory_effect(repo / "configs" / "covariance_box.toml")
    with pytest.raises(ValueError, match="threads 0"):
        lp.covariance(repo / "configs" / "quickstart.toml", samples=100, threads=0)
    # the command line's flags are named as the keyword arguments
    with pytest.raises(ValueError, match="max_minutes 0.01") as e:
        lp.covariance(repo / "configs" / "quickstart.toml", samples=10**12, max_minutes=0.01)
    assert "--" not in str(e.value), e.value


def test_relative_paths_in_a_dict_resolve_against_base(repo, tmp_path, monkeypatch):
    config = read_toml(repo / "configs" / "tabulated.toml")
    from_file = lp.load(repo / "configs" / "tabulated.toml")
    from_dict = lp.load(config, base=repo / "configs")
    assert json.loads(from_dict.config_json()) == json.loads(from_file.config_json())
    # without base, the current folder: here the table is not there
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="phase_table.csv"):
        lp.load(config)
