"""lightpath from Python: speckle statistics of light in scattering media as numpy arrays.

A config is a TOML file, TOML text, or a dict of the same shape (``{"medium": {...},
"light": [...], "view": [...]}``); it is validated by the same loader as the command line, and a
bad value raises ``ValueError`` naming the key, the value and what is allowed. Every function that
takes a config accepts any of a path, a dict, or a :class:`Task` from :func:`load`.

The computations are the command line's, run in memory: for the same config, samples and seed
the arrays equal the numbers in the command's JSON bit for bit, whatever the thread count. Long
runs release the GIL, stop on Ctrl-C (``KeyboardInterrupt``) and can report progress through a
callback ``progress(done, total)``.

Lengths are in the scene's unit (the unit of ``wavelength``); complex fields follow the project's
normalisation (``docs/speckle.md`` in the repository).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence, Union

from . import _lightpath
from ._lightpath import (
    CorrelationMap,
    Covariance,
    CovarianceVjp,
    Design,
    Fit,
    GrinFit,
    MemoryEffect,
    Mie,
    PhaseAcquisition,
    Rays,
    Render,
    RenderDesign,
    RenderVjp,
    Run,
    Speckle,
    Task,
    TiltShift,
    TraceVjp,
    __version__,
)

__all__ = [
    "CorrelationMap",
    "Covariance",
    "CovarianceVjp",
    "Design",
    "Fit",
    "GrinFit",
    "MemoryEffect",
    "Mie",
    "PhaseAcquisition",
    "Rays",
    "Render",
    "RenderDesign",
    "RenderVjp",
    "Run",
    "Speckle",
    "Task",
    "TiltShift",
    "TraceVjp",
    "__version__",
    "acquire_phase",
    "compare",
    "correlation_map",
    "covariance",
    "covariance_vjp",
    "design",
    "fit",
    "load",
    "loads",
    "memory_effect",
    "mie",
    "render",
    "render_vjp",
    "speckle",
    "tilt_shift",
    "trace",
    "trace_vjp",
    "wave",
]

Config = Union[Task, Mapping[str, Any], str, "os.PathLike[str]"]
Progress = Optional[Callable[[int, int], Any]]


def load(config: Config, *, base: Union[str, "os.PathLike[str]", None] = None) -> Task:
    """Validate a config and build what it describes.

    ``config`` is a path to a TOML file (relative paths inside it resolve against its folder), a
    dict of the TOML's shape (relative paths resolve against ``base``, default the current
    folder), or a :class:`Task` (returned as is). Raises ``ValueError`` naming the key of the first
    bad value, ``OSError`` if the file cannot be read.
    """
    if isinstance(config, Task):
        return config
    if isinstance(config, Mapping):
        return _lightpath.load_dict(dict(config), Path(base) if base is not None else Path.cwd())
    if isinstance(config, (str, os.PathLike)):
        path = Path(config)
        if not path.is_file():
            raise OSError(f"{path}: no such config file (pass TOML text to lightpath.loads)")
        return _lightpath.load_path(path)
    raise TypeError(
        f"a config is a path, a dict or a lightpath.Task, not {type(config).__name__}"
    )


def loads(text: str) -> Task:
    """Validate TOML text (relative paths resolve against the current folder)."""
    return _lightpath.load_toml(text)


def covariance(
    config: Config,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Covariance:
    """The speckle covariance of every light × view field (``lightpath covariance``).

    ``samples`` (paths) and ``seed`` override ``[render]``; ``threads`` defaults to all cores.
    A run estimated beyond ``max_minutes`` or ``max_memory_gb`` is refused before any work
    (``ValueError``). Returns a :class:`Covariance`: ``covariance`` complex128 ``[L, L, V, V]``,
    ``stderr``, ``single``/``multiple`` parts, ``mean`` ``[L, V]``.
    """
    return _lightpath.covariance(
        load(config),
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def memory_effect(
    config: Config,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> MemoryEffect:
    """The memory-effect curve of a scene with a ``[memory_effect]`` table
    (``lightpath memory-effect``): correlation against tilt angle, with the diffusion prediction
    of Eq. 39. Arguments as :func:`covariance`.
    """
    return _lightpath.memory_effect(
        load(config),
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def speckle(
    config: Config,
    *,
    paths: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Speckle:
    """Speckle field realisations (``lightpath speckle``): ``paths`` per image overrides
    ``[speckle] paths``. Returns a :class:`Speckle` with ``fields`` complex128 ``[R, L, V]`` and
    ``images`` ``[R, L, H, W]``.
    """
    return _lightpath.speckle(
        load(config),
        paths=paths,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def compare(
    a: Union[Covariance, str, "os.PathLike[str]"],
    b: Union[Covariance, str, "os.PathLike[str]"],
    *,
    tolerance: float = 0.1,
) -> dict:
    """The agreement of two covariances (``lightpath compare``), each a :class:`Covariance` or the
    path of a ``covariance.json``: a dict with ``agree`` (every light pair's ``‖A − B‖/‖B‖`` within
    ``tolerance``), ``report`` (the command's text) and ``pairs``, one dict per light pair with
    ``lights`` ``(l1, l2)``, ``error`` ``‖A − B‖/‖B‖``, ``within_3se`` (the share of entries within
    3 combined standard errors) and ``worst`` (the three worst entries as ``(z, v1, v2)``).
    """
    return _lightpath.compare(a, b, tolerance=tolerance)


def correlation_map(
    config: Config,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> CorrelationMap:
    """Near-field correlation maps ``C(Δ, τ)`` (Eq. 48 of the near-field paper) of a scene with
    focused light and view and a ``[correlation_map]`` table (``lightpath correlation-map``).
    Arguments as :func:`covariance`. Returns a :class:`CorrelationMap`: ``deltas`` ``[K, 3]``,
    ``taus`` ``[H, W, 3]``, ``correlation`` complex128 ``[K, H, W]``, ``stderr``, ``normalised``.
    """
    return _lightpath.correlation_map(
        load(config),
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def tilt_shift(
    config: Config,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> TiltShift:
    """The tilt-shift memory effect of a scene with a ``[tilt_shift]`` table
    (``lightpath tilt-shift``): the correlation of every scanned (shift, tilt) cell against the
    model of Eq. 50, as refocusing curves or a ``(Δb, θ)`` grid. Arguments as :func:`covariance`.
    Returns a :class:`TiltShift`: ``cells`` (a dict of ``[C]`` arrays), ``grid`` or ``refocus``
    (dicts of arrays), ``depth``, ``transport_mfp``.
    """
    return _lightpath.tilt_shift(
        load(config),
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def wave(
    config: Config,
    *,
    realizations: int = 200,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_scatterers: float = 6000.0,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Covariance:
    """The covariance by the Foldy–Lax wave solver over ``realizations`` scatterer placements
    (``lightpath wave``), in the same normalisation as :func:`covariance`, with the mean field's
    standard error in ``mean_stderr``. Scenes beyond ``max_scatterers``, ``max_memory_gb`` or
    ``max_minutes`` are refused before any work (``ValueError``).
    """
    return _lightpath.wave(
        load(config),
        realizations=realizations,
        seed=seed,
        threads=threads,
        max_scatterers=max_scatterers,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def covariance_vjp(
    config: Config,
    params: Sequence[str],
    *,
    theta: Optional[Sequence[float]] = None,
    proposal: Optional[Sequence[float]] = None,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> CovarianceVjp:
    """The covariance at ``theta`` and its vector–Jacobian product.

    ``params`` names medium parameters: ``sigma_s``, ``sigma_a`` (per length unit), ``g`` (or
    ``g[c]`` for particle type ``c``), ``bin[c][k]`` (node ``k`` of a tabulated phase function, an
    unnormalised value), ``weight[c]`` (a particle type's unnormalised share),
    ``vmf_weight[c][m]``, ``vmf_kappa[c][m]`` (lobes of a vMF-mixture amplitude). ``theta``
    defaults to the config's values.

    Paths are drawn from the medium at ``proposal`` (default: the config's values) with a fixed
    ``seed`` and re-weighted to ``theta`` (common random numbers): the value is a smooth function
    of ``theta`` and the VJP is its exact gradient, which is what deterministic optimisers (L-BFGS)
    need; keep ``theta`` near ``proposal`` (re-centre it between optimiser stages) for low
    variance. ``proposal=theta`` with a new ``seed`` per call gives unbiased stochastic gradients
    (Adam). A forward pass estimated beyond ``max_minutes`` or ``max_memory_gb`` is refused
    before any path is traced (``ValueError``), as for :func:`covariance`.

    Returns a :class:`CovarianceVjp`: ``value`` (complex128 ``[L, L, V, V]``), ``stderr``,
    ``params``, ``theta``, and calling it with the loss adjoint ``∂L/∂Re C + i ∂L/∂Im C`` (the
    shape of ``value``) returns ``∂L/∂θ`` (float64 ``[P]``).
    """
    return _lightpath.covariance_vjp(
        load(config),
        list(params),
        theta=None if theta is None else [float(x) for x in theta],
        proposal=None if proposal is None else [float(x) for x in proposal],
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def mie(
    diameter: float,
    n_particle: float,
    wavelength: float,
    *,
    n_medium: float = 1.0,
    k_particle: float = 0.0,
    diameter_spread: float = 0.0,
    angles: int = 361,
    volume_fraction: Optional[float] = None,
) -> Mie:
    """Spheres by Lorenz–Mie theory (``lightpath mie``).

    ``diameter`` and ``wavelength`` (in vacuum) in one length unit; ``n_particle + i k_particle``
    the particles' complex index, ``n_medium`` the host's; ``diameter_spread`` the relative spread
    (σ/mean) of a log-normal size distribution (0: one size); ``angles`` scattering angles from 0°
    to 180°; ``volume_fraction`` adds the bulk medium (``bulk``: σ_s, σ_a, mfp, albedo). Returns a
    :class:`Mie`: efficiencies ``q_*``, cross-sections ``c_*`` (length unit squared), ``g``,
    ``theta_deg``, ``phase`` (∫ρ dω = 1), ``s1``/``s2``.
    """
    return _lightpath.mie(
        diameter,
        n_particle,
        wavelength,
        n_medium=n_medium,
        k_particle=k_particle,
        diameter_spread=diameter_spread,
        angles=angles,
        volume_fraction=volume_fraction,
    )


def trace(
    config: Config,
    *,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    progress: Progress = None,
) -> Rays:
    """Rays through an index field (``lightpath trace``), from a trace config (``[field]`` +
    ``[rays]``). A bundle estimated beyond ``max_minutes`` is refused (``ValueError``), as is a
    step too coarse for the field. Returns :class:`Rays`: ``exit_position``, ``exit_direction``
    (float64 ``[N, 3]``), ``optical_path`` ``[N]``, ``entered``/``exited``, ``paths``.
    """
    return _lightpath.trace(load(config), threads=threads, max_minutes=max_minutes, progress=progress)


def trace_vjp(
    config: Config,
    params: Sequence[str] = (),
    *,
    theta: Optional[Sequence[float]] = None,
    grid: bool = False,
    coefficients: Any = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    progress: Progress = None,
) -> TraceVjp:
    """A trace config's rays traced to where they leave the field, with the vector–Jacobian
    product of their exits.

    ``params`` names analytic field parameters as ``"profiles[i].name"`` (``n_max``, ``k_r``,
    ``radius``, ``n0``, ``alpha``, ``gx``, ``c2``, … by profile kind), evaluated at ``theta``
    (default: the config's values). ``grid=True`` adds the gradient with respect to every
    coefficient of the field's grid profile, evaluated at ``coefficients`` (float ``[dz, dy, dx]``,
    default: the config's). Returns a :class:`TraceVjp`: ``exit_position``, ``exit_direction``
    (float64 ``[N, 3]``), ``optical_path``; calling it with ``∂L/∂(exit position)`` and
    ``∂L/∂(exit direction)`` (``[N, 3]`` each) returns a dict of gradients: ``params`` ``[P]``,
    ``grid`` ``[dz, dy, dx]`` or None, ``origin`` and ``direction`` ``[N, 3]``. Deterministic, and
    the same for any thread count.
    """
    import numpy as np

    return _lightpath.trace_vjp(
        load(config),
        list(params),
        theta=None if theta is None else [float(x) for x in theta],
        grid=grid,
        coefficients=None if coefficients is None else np.asarray(coefficients, dtype=np.float64).ravel().tolist(),
        threads=threads,
        max_minutes=max_minutes,
        progress=progress,
    )


def fit(
    config: Config,
    target: Any,
    fit: Union[str, Sequence[str]],
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    stages: int = 30,
    iterations: Optional[int] = None,
    optimizer: Optional[str] = None,
    learning_rate: float = 0.05,
    smooth: float = 0.0,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
    checkpoint: Union[str, "os.PathLike[str]", None] = None,
    checkpoint_every: Optional[int] = None,
) -> Fit:
    """Fit medium parameters (and a tabulated phase function) so the scene's statistics match a
    target (``lightpath fit``).

    ``target`` is a file (``memory_effect.json`` or ``covariance.json`` of a run, a measured
    memory curve as CSV ``angle_deg,correlation[,stderr]`` or JSON, measured entries
    ``{"entries": [...]}``, or a C(Δ, τ) map's ``correlation_map.json``) or a result object of
    this package (a :class:`MemoryEffect`, :class:`Covariance` or :class:`CorrelationMap`, saved
    to a temporary folder and read from there). ``fit`` names the parameters (``"mfp,g"`` or
    ``["mfp", "g"]``; ``mfp``, ``albedo``, ``g``, ``sigma_s``, ``sigma_a``, ``weight[c]``,
    ``phase`` for every node of a tabulated phase function). L-BFGS in re-centred stages for
    scalars (``stages``, ``iterations`` per stage, default 15); Adam for ``phase``
    (``iterations``, default 150; ``learning_rate``, ``smooth``). ``samples``/``seed`` set the
    paths of one objective evaluation. ``progress(done, total)`` counts logged evaluations
    (``total`` 0 for L-BFGS, whose count is not known in advance). With ``checkpoint``, a folder,
    the fit saves its progress there (``checkpoint.bin``, every two minutes or every
    ``checkpoint_every`` evaluations) and, called again with the same arguments after an
    interruption (Ctrl-C, an exception in ``progress``, a crash), continues from it to the same
    result as an uninterrupted fit; the file is removed when the fit finishes. Returns a
    :class:`Fit`.
    """
    import tempfile

    names = fit if isinstance(fit, str) else ",".join(fit)
    task = load(config)
    options = dict(
        samples=samples,
        seed=seed,
        stages=stages,
        iterations=iterations,
        optimizer=optimizer,
        learning_rate=learning_rate,
        smooth=smooth,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
        checkpoint=None if checkpoint is None else Path(checkpoint),
        checkpoint_every=checkpoint_every,
    )
    if hasattr(target, "save") and not isinstance(target, (str, os.PathLike)):
        with tempfile.TemporaryDirectory(prefix="lightpath-target-") as folder:
            written = [Path(p) for p in target.save(folder)]
            json_files = [p for p in written if p.suffix == ".json"]
            if not json_files:
                raise ValueError(f"target: a {type(target).__name__} writes no JSON result to fit")
            return _lightpath.fit(task, json_files[0], names, **options)
    return _lightpath.fit(task, Path(target), names, **options)


def design(
    config: Config,
    *,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
    checkpoint: Union[str, "os.PathLike[str]", None] = None,
    checkpoint_every: Optional[int] = None,
) -> Union[Design, GrinFit, RenderDesign]:
    """Run a design config (``lightpath design``): a grid index field shaped by Adam so the beams
    pass through their foci (returns a :class:`Design`); with a ``[parameters]`` table, the
    analytic field parameters fitted by L-BFGS (returns a :class:`GrinFit`); or a render config's
    ``[design]``: the index field's parameters moved by Adam toward the most light on a target
    (returns a :class:`RenderDesign`). A design estimated
    beyond ``max_minutes`` or ``max_memory_gb`` is refused before any work (``ValueError``).
    ``progress(done, total)`` counts Adam iterations over every level, or L-BFGS evaluations
    (``total`` 0: not known in advance). Ctrl-C stops it within one ray's trace. ``checkpoint``
    and ``checkpoint_every`` (iterations or evaluations) save and resume it as in :func:`fit`.
    """
    return _lightpath.design(
        load(config),
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
        checkpoint=None if checkpoint is None else Path(checkpoint),
        checkpoint_every=checkpoint_every,
    )


def render(
    config: Config,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Render:
    """Render a refractive, scattering volume (``lightpath render``): particle tracing from the
    lights, or path tracing from the cameras, through curved rays. ``samples`` (photons or camera
    paths) and ``seed`` override ``[render]``. ``progress(done, total)`` counts chunks. Returns a
    :class:`Render`: ``result`` (``render.json`` as a dict: sensors' power and flux per time bin,
    probes, cameras, surfaces, totals, statistics) and ``images`` (name → ``value``/``stderr``
    float64 ``[C, H, W]``, top row first, and ``bins``/``bins_stderr`` ``[B, C, H, W]`` with time
    bins).
    """
    return _lightpath.render(
        load(config),
        samples=samples,
        seed=seed,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
        progress=progress,
    )


def render_vjp(
    config: Config,
    params: Sequence[str],
    *,
    theta: Optional[Sequence[float]] = None,
    photons: Optional[int] = None,
    seed: Optional[int] = None,
    held: bool = False,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
) -> RenderVjp:
    """A render config's sensor outputs at ``theta`` and their vector–Jacobian product, by
    particle tracing (as ``render.derivatives``).

    ``params`` names what ``render.derivatives`` accepts: the medium's ``sigma_s``, ``sigma_a``,
    ``g``, … and the index field's ``"profiles[i].name"`` (a phased array's ``frequency``,
    ``amplitude_j``, ``phase_j``, ``x_j``, ``y_j``; an ultrasonic profile's ``n_max``; any
    analytic profile's coefficients; with index-field parameters every sensor must follow the
    light continuously: a target, a fluence probe, a spot, or a tent-filtered screen or camera).
    ``theta`` defaults to the config's values, ``photons`` and ``seed`` to ``[render]``'s.

    Fresh photons (a new ``seed`` per call) give unbiased stochastic gradients of the expected
    outputs (Adam). ``held=True`` draws every scored choice evenly from the same random numbers
    for any ``theta``: the outputs are then a deterministic function whose Jacobian is its exact
    derivative (L-BFGS; index-field parameters only).

    Returns a :class:`RenderVjp`: ``value`` and ``stderr`` (float64 ``[S]``, the sensors in the
    config's order, then the fluence probes, then the cameras' windows; ``sensors`` their
    names), ``jacobian`` and ``jacobian_stderr`` (``[S, P]``), ``params``, ``theta``; calling it
    with ``∂L/∂value`` (``[S]``) returns ``∂L/∂θ`` (``[P]``).
    """
    return _lightpath.render_vjp(
        load(config),
        list(params),
        theta=None if theta is None else [float(x) for x in theta],
        photons=photons,
        seed=seed,
        held=held,
        threads=threads,
        max_minutes=max_minutes,
        max_memory_gb=max_memory_gb,
    )


def acquire_phase(config: Config) -> PhaseAcquisition:
    """Read the phase function from speckle images of a slab under tilted illuminations
    (``lightpath acquire-phase``), from an acquisition config (``[acquisition]`` relay geometry +
    ``[[pair]]`` image files; relative paths resolve against the config's folder, or ``base`` of
    :func:`load` for a dict). Returns a :class:`PhaseAcquisition`: ``curves`` (one dict per
    displacement with the readings as arrays and the HG / vMF fits) and ``consistency``.
    """
    return _lightpath.acquire_phase(load(config))
