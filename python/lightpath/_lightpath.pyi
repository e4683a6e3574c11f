"""Type stubs of the compiled module `lightpath._lightpath` (use it through `lightpath`)."""

from os import PathLike
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str

Progress = Optional[Callable[[int, int], Any]]

class Task:
    """A validated config and what it describes (built once)."""

    @property
    def kind(self) -> str:
        """"scene", "trace", "design", "param_fit", "acquire" or "render"."""
    def describe(self) -> str:
        """What the config describes, in one line (as `lightpath check` prints it)."""
    def config_json(self) -> str:
        """The validated config as JSON text, every default filled in."""

class Run:
    """How a result was computed."""

    @property
    def samples(self) -> int:
        """Paths (Monte Carlo), realisations (wave solver) or 0 (closed form)."""
    @property
    def seed(self) -> int: ...
    @property
    def seconds(self) -> Optional[float]:
        """Wall time, in seconds."""
    @property
    def wavelength(self) -> float:
        """Vacuum wavelength, in the scene's length unit."""
    @property
    def version(self) -> str: ...
    def config_json(self) -> str:
        """The config the run used, as JSON text."""

class Covariance:
    """`C[l1, l2, v1, v2] = E[u ū'] − m m̄'` of every light × view field (`covariance.json`)."""

    @property
    def run(self) -> Run: ...
    @property
    def covariance(self) -> npt.NDArray[np.complex128]:
        """complex128 [L, L, V, V]."""
    @property
    def stderr(self) -> npt.NDArray[np.float64]:
        """float64 [L, L, V, V]: standard error of `covariance` (zeros for a closed form)."""
    @property
    def intensity(self) -> npt.NDArray[np.float64]:
        """float64 [L, V]: the speckle intensity C[l, l, v, v]."""
    @property
    def mean(self) -> npt.NDArray[np.complex128]:
        """complex128 [L, V]: the mean field."""
    @property
    def mean_stderr(self) -> Optional[npt.NDArray[np.float64]]:
        """float64 [L, V] (wave solver), else None."""
    @property
    def single(self) -> Optional[npt.NDArray[np.complex128]]:
        """complex128 [L, L, V, V]: paths that scatter once (Monte Carlo, closed form)."""
    @property
    def single_stderr(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def multiple(self) -> Optional[npt.NDArray[np.complex128]]:
        """complex128 [L, L, V, V]: paths that scatter twice or more (Monte Carlo)."""
    @property
    def multiple_stderr(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def solver(self) -> Optional[str]:
        """"foldy-lax", "single_scattering" or None (Monte Carlo)."""
    @property
    def realizations(self) -> Optional[int]:
        """Scatterer placements (wave solver), else None."""
    def to_json(self) -> str:
        """`covariance.json` as text, exactly as the command writes it."""
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]:
        """Write `covariance.json` into `folder`; the paths written."""

class MemoryEffect:
    """The memory-effect curve against Eq. 39 (`memory_effect.json`)."""

    @property
    def run(self) -> Run: ...
    @property
    def angles_deg(self) -> npt.NDArray[np.float64]:
        """float64 [A]: tilt angles, degrees."""
    @property
    def correlation(self) -> npt.NDArray[np.float64]:
        """float64 [A]: normalised intensity correlation."""
    @property
    def correlation_stderr(self) -> npt.NDArray[np.float64]: ...
    @property
    def field_correlation(self) -> npt.NDArray[np.float64]:
        """float64 [A]: normalised field correlation."""
    @property
    def diffusion_eq39(self) -> npt.NDArray[np.float64]:
        """float64 [A]: ((kθL)/sinh(kθL))²."""
    @property
    def thickness(self) -> float:
        """L of Eq. 39, in the scene's length unit."""
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]:
        """Write `memory_effect.json` and `memory_effect.png`; the paths written."""

class Speckle:
    """Speckle field realisations (`speckle.json` and EXR images)."""

    @property
    def run(self) -> Run: ...
    @property
    def fields(self) -> npt.NDArray[np.complex128]:
        """complex128 [R, L, V]."""
    @property
    def images(self) -> npt.NDArray[np.complex128]:
        """complex128 [R, L, H, W] (H = 1, W = V for views given one by one)."""
    @property
    def paths_per_image(self) -> int: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]:
        """Write `speckle.json` and `speckle_NNNN.exr`; the paths written."""

class CovarianceVjp:
    """A covariance at `theta` with its vector–Jacobian product (`covariance_vjp`)."""

    @property
    def value(self) -> npt.NDArray[np.complex128]:
        """complex128 [L, L, V, V]: the covariance at `theta`."""
    @property
    def stderr(self) -> npt.NDArray[np.float64]:
        """float64 [L, L, V, V]."""
    @property
    def params(self) -> list[str]: ...
    @property
    def theta(self) -> npt.NDArray[np.float64]:
        """float64 [P]."""
    def __call__(self, adjoint: npt.ArrayLike, *, progress: Progress = None) -> npt.NDArray[np.float64]:
        """∂L/∂θ (float64 [P]) for the adjoint ∂L/∂Re C + i ∂L/∂Im C ([L, L, V, V])."""

class Mie:
    """Spheres by Lorenz–Mie theory (`mie.json`)."""

    size_parameter: float
    terms: int
    q_ext: float
    q_sca: float
    q_abs: float
    q_back: float
    g: float
    c_ext: float
    c_sca: float
    c_abs: float
    c_back: float
    mean_volume: float
    @property
    def theta_deg(self) -> npt.NDArray[np.float64]:
        """float64 [N]: 0° … 180°."""
    @property
    def phase(self) -> npt.NDArray[np.float64]:
        """float64 [N]: unpolarised, ∫ρ dω = 1."""
    @property
    def phase_perpendicular(self) -> npt.NDArray[np.float64]: ...
    @property
    def phase_parallel(self) -> npt.NDArray[np.float64]: ...
    @property
    def s1(self) -> npt.NDArray[np.complex128]:
        """complex128 [N]."""
    @property
    def s2(self) -> npt.NDArray[np.complex128]:
        """complex128 [N]."""
    @property
    def bulk(self) -> Optional[dict[str, float]]:
        """volume_fraction, number_density, sigma_s, sigma_a, mfp, albedo (with a volume fraction)."""
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]:
        """Write `mie.json` and `mie.png`; the paths written."""

class Rays:
    """Rays traced through an index field (`rays.json`)."""

    @property
    def origin(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def direction(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def exit_position(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def exit_direction(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def optical_path(self) -> npt.NDArray[np.float64]:
        """float64 [N]: ∫ n ds."""
    @property
    def steps(self) -> npt.NDArray[np.uint64]: ...
    @property
    def entered(self) -> npt.NDArray[np.bool_]: ...
    @property
    def exited(self) -> npt.NDArray[np.bool_]: ...
    @property
    def paths(self) -> list[npt.NDArray[np.float64]]:
        """Each ray's path, float64 [K, 3]."""
    @property
    def step_error(self) -> Optional[float]: ...
    @property
    def seconds(self) -> float: ...
    @property
    def warning(self) -> Optional[str]: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]:
        """Write `rays.json` and `rays.png`; the paths written."""

class TraceVjp:
    """Ray exits with their vector–Jacobian product (`trace_vjp`)."""

    @property
    def exit_position(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def exit_direction(self) -> npt.NDArray[np.float64]:
        """float64 [N, 3]."""
    @property
    def optical_path(self) -> npt.NDArray[np.float64]:
        """float64 [N]."""
    @property
    def params(self) -> list[str]: ...
    @property
    def coefficients(self) -> Optional[npt.NDArray[np.float64]]:
        """float64 [dz, dy, dx]: the grid profile's coefficients, or None."""
    @property
    def theta(self) -> npt.NDArray[np.float64]: ...
    def __call__(
        self, d_position: npt.ArrayLike, d_direction: npt.ArrayLike, *, progress: Progress = None
    ) -> dict[str, Any]:
        """{"params": [P], "grid": [dz, dy, dx] or None, "origin": [N, 3], "direction": [N, 3]}."""

class CorrelationMap:
    """Near-field C(Δ, τ) maps (`correlation_map.json`)."""

    @property
    def run(self) -> Run: ...
    @property
    def deltas(self) -> npt.NDArray[np.float64]:
        """float64 [K, 3]: shifts, the first 0."""
    @property
    def taus(self) -> npt.NDArray[np.float64]:
        """float64 [H, W, 3]."""
    @property
    def correlation(self) -> npt.NDArray[np.complex128]:
        """complex128 [K, H, W]."""
    @property
    def stderr(self) -> npt.NDArray[np.float64]: ...
    @property
    def normalised(self) -> npt.NDArray[np.float64]:
        """float64 [K, H, W]: |C| / sqrt(I(0) I(Δ))."""
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class TiltShift:
    """The tilt-shift memory effect (`tilt_shift.json`)."""

    @property
    def run(self) -> Run: ...
    @property
    def depth(self) -> float: ...
    @property
    def transport_mfp(self) -> float: ...
    @property
    def cells(self) -> dict[str, npt.NDArray[Any]]:
        """shift, angle_deg, input_shift, stderr, normalised, normalised_stderr, model [C]; correlation complex [C]."""
    @property
    def grid(self) -> Optional[dict[str, npt.NDArray[np.float64]]]:
        """shifts [S], angles_deg [A], normalised and model [S, A]."""
    @property
    def refocus(self) -> Optional[dict[str, npt.NDArray[np.float64]]]:
        """displacements, power_shift(_stderr), power_tilt(_stderr), tilts_deg, model_shift, model_tilt [D]."""
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

def load_path(path: Union[str, PathLike[str]]) -> Task: ...
def load_toml(text: str) -> Task: ...
def load_dict(config: Mapping[str, Any], base: Union[str, PathLike[str]]) -> Task: ...
def covariance(
    task: Task,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Covariance: ...
def memory_effect(
    task: Task,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> MemoryEffect: ...
def speckle(
    task: Task,
    *,
    paths: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Speckle: ...
def wave(
    task: Task,
    *,
    realizations: int = 200,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_scatterers: float = 6000.0,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Covariance: ...
def covariance_vjp(
    task: Task,
    params: list[str],
    *,
    theta: Optional[list[float]] = None,
    proposal: Optional[list[float]] = None,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> CovarianceVjp: ...
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
) -> Mie: ...
def trace(
    task: Task,
    *,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    progress: Progress = None,
) -> Rays: ...
def trace_vjp(
    task: Task,
    params: list[str] = ...,
    *,
    theta: Optional[list[float]] = None,
    grid: bool = False,
    coefficients: Optional[list[float]] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    progress: Progress = None,
) -> TraceVjp: ...
def correlation_map(
    task: Task,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> CorrelationMap: ...
def compare(
    a: Union[Covariance, str, PathLike[str]],
    b: Union[Covariance, str, PathLike[str]],
    *,
    tolerance: float = 0.1,
) -> dict[str, Any]: ...
def tilt_shift(
    task: Task,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> TiltShift: ...

class Fit:
    """A fit of medium parameters (and a phase function) to a target, as `fit.json` holds it."""

    @property
    def params(self) -> list[str]:
        """Names: `mfp`, `g`, …, then `rho(θ°)` per phase node."""
    @property
    def initial(self) -> npt.NDArray[np.float64]:
        """[P] starting values (natural units)."""
    @property
    def fitted(self) -> npt.NDArray[np.float64]:
        """[P] fitted values."""
    @property
    def stddev(self) -> npt.NDArray[np.float64]:
        """[P] one standard deviation each (Gauss–Newton)."""
    @property
    def correlation(self) -> Optional[npt.NDArray[np.float64]]:
        """[P, P] correlation matrix (L-BFGS fits), else None."""
    @property
    def loss(self) -> float: ...
    @property
    def converged(self) -> bool: ...
    @property
    def convergence(self) -> dict[str, Any]:
        """`converged`, `stop`, `grad_norm`, `evaluations`, `iterations`."""
    @property
    def model_initial(self) -> npt.NDArray[np.float64]:
        """[K] the target's statistics modelled at the start."""
    @property
    def model_fitted(self) -> npt.NDArray[np.float64]:
        """[K] the same at the fitted values."""
    @property
    def phase_angle_deg(self) -> Optional[npt.NDArray[np.float64]]:
        """[N] phase-node angles in degrees (phase fits), else None."""
    @property
    def log_loss(self) -> npt.NDArray[np.float64]:
        """[E] loss of every logged evaluation."""
    @property
    def log_params(self) -> npt.NDArray[np.float64]:
        """[E, P] values of every logged evaluation."""
    @property
    def seconds(self) -> float: ...
    @property
    def summary(self) -> str: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class Design:
    """A grid index field designed by Adam, as `design.json` holds it."""

    @property
    def rms_miss_initial(self) -> float: ...
    @property
    def rms_miss_final(self) -> float: ...
    @property
    def grid(self) -> npt.NDArray[np.float64]:
        """[nz, ny, nx] the designed grid's contribution to n at its nodes."""
    @property
    def coefficients(self) -> npt.NDArray[np.float64]:
        """[nz, ny, nx] its interpolation coefficients."""
    @property
    def origin(self) -> npt.NDArray[np.float64]:
        """[3] first node (x, y, z)."""
    @property
    def spacing(self) -> float: ...
    @property
    def radial_profile(self) -> dict[str, npt.NDArray[np.float64]]:
        """`r`, `mean`, `min`, `max` [R]."""
    @property
    def log_level(self) -> npt.NDArray[np.uint64]: ...
    @property
    def log_mean_miss2(self) -> npt.NDArray[np.float64]: ...
    @property
    def log_loss(self) -> npt.NDArray[np.float64]: ...
    @property
    def converged(self) -> bool: ...
    @property
    def convergence(self) -> dict[str, Any]: ...
    @property
    def seconds(self) -> float: ...
    @property
    def summary(self) -> str: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class GrinFit:
    """Analytic index-field parameters fitted by L-BFGS, as the design's `fit.json` holds them."""

    @property
    def params(self) -> list[str]: ...
    @property
    def initial(self) -> npt.NDArray[np.float64]: ...
    @property
    def fitted(self) -> npt.NDArray[np.float64]: ...
    @property
    def rms_miss_initial(self) -> float: ...
    @property
    def rms_miss_final(self) -> float: ...
    @property
    def log_mean_miss2(self) -> npt.NDArray[np.float64]: ...
    @property
    def log_params(self) -> npt.NDArray[np.float64]:
        """[E, P] parameter values of every evaluation."""
    @property
    def converged(self) -> bool: ...
    @property
    def convergence(self) -> dict[str, Any]: ...
    @property
    def seconds(self) -> float: ...
    @property
    def summary(self) -> str: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class RenderDesign:
    """A render's index field designed toward a target, as `render_design.json` holds it."""

    @property
    def params(self) -> list[str]: ...
    @property
    def method(self) -> str:
        """"adam" (fresh photons every iteration) or "lbfgs" (held photons)."""
    @property
    def start(self) -> npt.NDArray[np.float64]: ...
    @property
    def designed(self) -> npt.NDArray[np.float64]: ...
    @property
    def log_objective(self) -> npt.NDArray[np.float64]:
        """[I] the objective (ln F, or ln F - ln F_reference) of every Adam iteration or L-BFGS evaluation."""
    @property
    def verification(self) -> dict[str, Any]:
        """The check at a fresh seed: photons, seed, start, designed, gain."""
    @property
    def converged(self) -> bool: ...
    @property
    def summary(self) -> str: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class RenderVjp:
    """A render's sensor outputs at `theta` with their Jacobian; calling it with d(loss)/d(value) gives d(loss)/d(theta)."""

    @property
    def value(self) -> npt.NDArray[np.float64]:
        """[S] every sensor's output (power of flux sensors, screens and spots; targets' and fluence probes' fluence), in the config's order, the probes last."""
    @property
    def stderr(self) -> npt.NDArray[np.float64]: ...
    @property
    def jacobian(self) -> npt.NDArray[np.float64]:
        """[S, P] d value_i / d theta_p."""
    @property
    def jacobian_stderr(self) -> npt.NDArray[np.float64]: ...
    @property
    def sensors(self) -> list[str]: ...
    @property
    def params(self) -> list[str]: ...
    @property
    def theta(self) -> npt.NDArray[np.float64]: ...
    @property
    def held(self) -> bool: ...
    def __call__(self, adjoint: npt.ArrayLike) -> npt.NDArray[np.float64]: ...

class Render:
    """A render of a refractive, scattering volume, as `render.json` and its images hold it."""

    @property
    def result(self) -> dict[str, Any]:
        """`render.json` as Python values."""
    @property
    def images(self) -> dict[str, dict[str, npt.NDArray[np.float64]]]:
        """Image name → `value`, `stderr` [C, H, W] (top row first) and, with time bins, `bins`,
        `bins_stderr` [B, C, H, W]."""
    @property
    def samples(self) -> int: ...
    @property
    def seconds(self) -> Optional[float]: ...
    @property
    def summary(self) -> str: ...
    @property
    def warning(self) -> Optional[str]: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

class PhaseAcquisition:
    """The phase function read from speckle images, as `phase_acquisition.json` holds it."""

    @property
    def curves(self) -> list[dict[str, Any]]:
        """One dict per displacement; the readings as float64 [R] arrays."""
    @property
    def consistency(self) -> Optional[dict[str, Any]]: ...
    @property
    def seconds(self) -> float: ...
    def to_json(self) -> str: ...
    def save(self, folder: Union[str, PathLike[str]]) -> list[Path]: ...

def fit(
    task: Task,
    target: Union[str, PathLike[str]],
    fit: str,
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
    checkpoint: Union[str, PathLike[str], None] = None,
    checkpoint_every: Optional[int] = None,
) -> Fit: ...
def design(
    task: Task,
    *,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
    checkpoint: Union[str, PathLike[str], None] = None,
    checkpoint_every: Optional[int] = None,
) -> Union[Design, GrinFit, RenderDesign]: ...
def render(
    task: Task,
    *,
    samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
    progress: Progress = None,
) -> Render: ...
def render_vjp(
    task: Task,
    params: list[str],
    *,
    theta: Optional[list[float]] = None,
    photons: Optional[int] = None,
    seed: Optional[int] = None,
    held: bool = False,
    threads: Optional[int] = None,
    max_minutes: float = 240.0,
    max_memory_gb: float = 8.0,
) -> RenderVjp: ...
def acquire_phase(task: Task) -> PhaseAcquisition: ...
