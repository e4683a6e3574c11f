"""Vector–Jacobian products of the covariance: against central finite differences with common
random numbers, and a scipy fit of the mean free path that recovers the truth."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import lightpath as lp

SCENE = {
    "wavelength": 1.0,
    "medium": {"box": [20.0, 20.0, 20.0], "mfp": 10.0, "albedo": 0.9, "phase": {"kind": "hg", "g": 0.5}},
    "light": [
        {"kind": "plane_wave", "direction": [0.0, 0.0, 1.0]},
        {"kind": "plane_wave", "direction": [0.0698, 0.0, 0.9976]},
    ],
    "view": [{"kind": "far_field_ring", "start": [0.0, 0.0, 1.0], "axis": [0.0, 1.0, 0.0], "count": 12}],
    "render": {"samples": 20_000, "seed": 3, "chunk": 500},
}
PARAMS = ["sigma_s", "sigma_a", "g"]


def loss(value: np.ndarray, w: np.ndarray) -> float:
    """L = Σ Re(w) Re(C) + Im(w) Im(C): its adjoint ∂L/∂Re C + i ∂L/∂Im C is w."""
    return float(np.sum(w.real * value.real + w.imag * value.imag))


def test_vjp_matches_central_differences_with_common_random_numbers():
    rng = np.random.default_rng(0)
    theta = np.array([0.09, 0.01, 0.5])
    at = lp.covariance_vjp(SCENE, PARAMS, theta=theta)
    assert at.value.shape == (2, 2, 12, 12) and at.params == PARAMS
    w = rng.normal(size=at.value.shape) + 1j * rng.normal(size=at.value.shape)
    grad = at(w)
    assert grad.shape == (3,)
    for p, h in enumerate([1e-5, 1e-6, 1e-5]):
        step = np.zeros(3)
        step[p] = h
        up = lp.covariance_vjp(SCENE, PARAMS, theta=theta + step).value
        down = lp.covariance_vjp(SCENE, PARAMS, theta=theta - step).value
        fd = (loss(up, w) - loss(down, w)) / (2 * h)
        assert grad[p] == pytest.approx(fd, rel=1e-4, abs=1e-6 * abs(loss(at.value, w))), PARAMS[p]


def test_value_is_the_covariance_and_bad_arguments_are_named():
    plain = lp.covariance(SCENE)
    at = lp.covariance_vjp(SCENE, ["sigma_s"])
    assert at.theta.tolist() == [0.09]
    # the re-weighted estimator at its own proposal is the covariance, up to round-off
    assert np.max(np.abs(at.value - plain.covariance)) <= 1e-12 * np.max(np.abs(plain.covariance))
    assert np.allclose(at.stderr, plain.stderr, rtol=1e-9, atol=0.0)
    with pytest.raises(ValueError, match="not a parameter"):
        lp.covariance_vjp(SCENE, ["mfp"])
    with pytest.raises(ValueError, match="given twice"):
        lp.covariance_vjp(SCENE, ["g", "g"])
    with pytest.raises(ValueError, match="theta: 2 values for 1 parameter"):
        lp.covariance_vjp(SCENE, ["g"], theta=[0.1, 0.2])
    with pytest.raises(ValueError, match="g = 1.5: must be within"):
        lp.covariance_vjp(SCENE, ["g"], theta=[1.5])
    with pytest.raises(ValueError, match="adjoint"):
        at(np.zeros((2, 2, 12)))
    with pytest.raises(ValueError, match="max_minutes"):
        lp.covariance_vjp(SCENE, ["g"], samples=10**12, max_minutes=0.01)
    with pytest.raises(ValueError, match="max_memory_gb"):
        lp.covariance_vjp(SCENE, ["g"], max_memory_gb=1e-9)
    isotropic = {**SCENE, "medium": {**SCENE["medium"], "phase": {"kind": "isotropic"}}}
    with pytest.raises(ValueError, match="g does not exist"):
        lp.covariance_vjp(isotropic, ["g"])


def test_scipy_fit_recovers_the_mean_free_path(repo):
    sys.path.insert(0, str(repo / "python" / "examples"))
    try:
        from fit_mfp_scipy import SCENE as BOX, fit_mfp, intensity, with_mfp
    finally:
        sys.path.pop(0)
    measured = lp.covariance(with_mfp(BOX, 8.0), samples=100_000, seed=100)
    mfp, se, _ = fit_mfp(BOX, intensity(measured.covariance), intensity(measured.stderr), start=14.0)
    assert se < 0.1, se  # the fit can tell 8 from 8.4
    assert abs(mfp - 8.0) < 4.0 * se, (mfp, se)
