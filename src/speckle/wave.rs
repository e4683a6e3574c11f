//! Wave-optics ground truth: scalar Foldy–Lax multiple scattering by resonant point scatterers,
//! averaged over random scatterer placements (the validation of paper 001, Sec. 6.1, in 3-D).
//!
//! Scatterers have amplitude `f = i/k` (`Re f = 0`, lossless: `c_s = 4π|f|² = λ²/π`) and are drawn as
//! a Poisson process of density `σ_s / c_s` in the box. For one placement the exciting fields solve
//! `u_j = u_inc(o_j) + Σ_{l≠j} f G(o_j, o_l) u_l`, `G = exp(ikr)/r`, by one dense LU factorisation
//! (faer) with every light as a right-hand side. A view measures `Σ_j f ξ_v(o_j) u_j` plus the incident
//! field it sees directly (nothing for a plane wave seen in the far field), with the same `ξ` as the
//! Monte Carlo estimators, so both compute the same field.

use crate::math::{C64, Rng, uniform};
use crate::medium::{Geometry, PhaseFunction};
use crate::speckle::{Light, Scene, View};
use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use glam::DVec3;
use std::f64::consts::PI;

/// Scattering cross-section of the resonant point scatterer, `c_s = 4π/k² = λ²/π`.
pub fn cross_section(k: f64) -> f64 {
    4.0 * PI / (k * k)
}

/// `4π e^{-γ} sinh(q)/q` with `q = sqrt(μ·μ)` for complex `μ` (even in `q`, so the branch is free).
pub fn vmf_integral(gamma: f64, mu_re: DVec3, mu_im: DVec3) -> C64 {
    let q2 = C64::new(mu_re.dot(mu_re) - mu_im.dot(mu_im), 2.0 * mu_re.dot(mu_im));
    let q = q2.sqrt();
    if q.norm() < 1e-6 {
        (C64::new(1.0, 0.0) + q2 / 6.0) * (4.0 * PI * (-gamma).exp())
    } else {
        // e^{-γ} sinh(q) = (e^{q-γ} − e^{-q-γ})/2 stays finite for large γ
        ((q - gamma).exp() - (-q - gamma).exp()) / (2.0 * q) * (4.0 * PI)
    }
}

/// Incident field of `light` at `x`.
pub fn incident(light: &Light, x: DVec3, k: f64) -> C64 {
    match *light {
        Light::PlaneWave { direction } => C64::from_polar(1.0, k * direction.dot(x)),
        Light::Point { position } => {
            let r = (x - position).length();
            C64::from_polar(1.0 / r, k * r)
        }
        Light::Focused { focus, axis, gamma } => vmf_integral(gamma, axis * gamma, (x - focus) * k),
    }
}

/// `ξ(x → v)`: the field a view measures from a unit point source at `x`.
pub fn sensor(view: &View, x: DVec3, k: f64) -> C64 {
    match *view {
        View::FarField { direction } => C64::from_polar(1.0, -k * direction.dot(x)),
        View::Point { position } => {
            let r = (position - x).length();
            C64::from_polar(1.0 / r, k * r)
        }
        View::Focused { focus, axis, gamma } => vmf_integral(gamma, axis * gamma, -(x - focus) * k),
    }
}

/// The incident field as a view sees it without scattering. A plane wave in the far field is a
/// delta in its own direction and contributes nothing; a focused beam's outgoing far field is
/// `(2π/ik) m(v) exp(-ik v·focus)`.
pub fn direct(light: &Light, view: &View, k: f64) -> C64 {
    let two_pi_over_ik = C64::new(0.0, -2.0 * PI / k);
    match (*light, *view) {
        (Light::Point { position }, v) => sensor(&v, position, k),
        (l, View::Point { position }) => incident(&l, position, k),
        (Light::PlaneWave { .. }, View::FarField { .. }) => C64::default(),
        (Light::Focused { focus, axis, gamma }, View::FarField { direction }) => {
            two_pi_over_ik
                * (gamma * (direction.dot(axis) - 1.0)).exp()
                * C64::from_polar(1.0, -k * direction.dot(focus))
        }
        (Light::PlaneWave { direction }, View::Focused { focus, axis, gamma }) => {
            two_pi_over_ik
                * (gamma * (direction.dot(axis) - 1.0)).exp()
                * C64::from_polar(1.0, k * direction.dot(focus))
        }
        (
            Light::Focused {
                focus: pl,
                axis: al,
                gamma: gl,
            },
            View::Focused {
                focus: pv,
                axis: av,
                gamma: gv,
            },
        ) => {
            two_pi_over_ik
                * vmf_integral(0.0, al * gl + av * gv, (pv - pl) * k)
                * (-(gl + gv)).exp()
        }
    }
}

/// Why a scene cannot be given to the wave solver.
pub fn check_scene(scene: &Scene) -> crate::Result<()> {
    if !matches!(scene.medium.geometry, Geometry::Box { .. }) {
        return Err(
            "wave: the wave solver needs a bounded medium; use medium.box instead of medium.slab"
                .into(),
        );
    }
    if scene.medium.sigma_a > 0.0 {
        return Err(format!(
            "wave: medium absorbs (sigma_a = {}, albedo = {:.4}); the wave solver models lossless resonant point scatterers: set albedo = 1 (or sigma_a = 0)",
            scene.medium.sigma_a,
            scene.medium.albedo()
        ).into());
    }
    let comps = scene.medium.scattering.components();
    if comps.len() != 1 || comps[0].1 != PhaseFunction::Isotropic {
        return Err("wave: the wave solver models isotropic point scatterers; set medium.phase = { kind = \"isotropic\" }".into());
    }
    Ok(())
}

/// Expected number of scatterers `σ_s V / c_s`.
pub fn expected_scatterers(scene: &Scene) -> f64 {
    scene.medium.sigma_s * scene.medium.geometry.sampling_volume() / cross_section(scene.k)
}

/// Poisson-distributed count with mean `lambda` (exponential gaps; cost O(lambda)).
fn poisson(rng: &mut Rng, lambda: f64) -> usize {
    let mut n = 0;
    let mut t = -(1.0 - uniform(rng)).ln();
    while t < lambda {
        n += 1;
        t += -(1.0 - uniform(rng)).ln();
    }
    n
}

/// Draw one scatterer placement.
pub fn place_scatterers(scene: &Scene, rng: &mut Rng) -> Vec<DVec3> {
    let n = poisson(rng, expected_scatterers(scene));
    (0..n)
        .map(|_| {
            scene
                .medium
                .geometry
                .sample_volume([uniform(rng), uniform(rng), uniform(rng)])
        })
        .collect()
}

/// Exciting fields `u_j` of the scatterers at `pos`, one column per light: one dense LU of the
/// Foldy–Lax matrix `I − f G` (zero diagonal) with every light as a right-hand side.
fn exciting(scene: &Scene, pos: &[DVec3]) -> Mat<c64> {
    let k = scene.k;
    let f = c64::new(0.0, 1.0 / k);
    let n = pos.len();
    let a = Mat::<c64>::from_fn(n, n, |i, j| {
        if i == j {
            c64::new(1.0, 0.0)
        } else {
            let r = (pos[i] - pos[j]).length();
            -f * C64::from_polar(1.0 / r, k * r)
        }
    });
    let b = Mat::<c64>::from_fn(n, scene.lights.len(), |i, l| {
        incident(&scene.lights[l], pos[i], k)
    });
    a.partial_piv_lu().solve(&b)
}

/// Fields `u[l·V + v]` of every light and view for scatterers at `pos` (Foldy–Lax, dense LU).
pub fn solve(scene: &Scene, pos: &[DVec3]) -> Vec<C64> {
    let k = scene.k;
    let f = c64::new(0.0, 1.0 / k);
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let mut out = vec![C64::default(); nl * nv];
    for (l, light) in scene.lights.iter().enumerate() {
        for (v, view) in scene.views.iter().enumerate() {
            out[l * nv + v] = direct(light, view, k);
        }
    }
    if pos.is_empty() {
        return out;
    }
    let u = exciting(scene, pos);
    let s = Mat::<c64>::from_fn(nv, pos.len(), |v, j| f * sensor(&scene.views[v], pos[j], k));
    let fields = &s * &u;
    for l in 0..nl {
        for v in 0..nv {
            out[l * nv + v] += fields[(v, l)];
        }
    }
    out
}

/// Measured seconds of one realisation with `n` scatterers on this machine: the time of a solve
/// with `min(n, 600)` scatterers (best of two), scaled by `(n / n₀)³` (the LU dominates).
pub fn seconds_per_solve(scene: &Scene, n: f64, rng: &mut Rng) -> f64 {
    let n0 = n.clamp(1.0, 600.0).round() as usize;
    let pos: Vec<DVec3> = (0..n0)
        .map(|_| {
            let u = [uniform(rng), uniform(rng), uniform(rng)];
            scene.medium.geometry.sample_volume(u)
        })
        .collect();
    let best = (0..2)
        .map(|_| {
            let t = std::time::Instant::now();
            std::hint::black_box(solve(scene, &pos));
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min);
    best * (n / n0 as f64).max(1.0).powi(3)
}

/// Exciting fields `u_j` (one column per light) for scatterers at `pos`; for checks of the solve.
pub fn exciting_fields(scene: &Scene, pos: &[DVec3]) -> Vec<Vec<C64>> {
    let u = exciting(scene, pos);
    (0..scene.lights.len())
        .map(|l| (0..pos.len()).map(|j| u[(j, l)]).collect())
        .collect()
}

/// Scatterer placements as an engine estimator: each sample is one placement drawn from the
/// chunk's stream and solved; the outputs are the `J` fields `u[l·V + v]` and, last, the number
/// of scatterers. Run with one placement per chunk and every field kept, so the engine's shards,
/// merge and thread-count independence apply, and [`WaveStatistics::from_fields`] reduces the kept
/// fields to the mean and the covariance.
pub struct Realizations<'a> {
    scene: &'a Scene,
}

impl<'a> Realizations<'a> {
    pub fn new(scene: &'a Scene) -> Self {
        Realizations { scene }
    }

    /// Number of fields `J`.
    pub fn fields(&self) -> usize {
        self.scene.lights.len() * self.scene.views.len()
    }

    /// The outputs kept per chunk: every field.
    pub fn kept_outputs(&self) -> Vec<usize> {
        (0..self.fields()).collect()
    }
}

impl crate::mc::Estimator for Realizations<'_> {
    type Scratch = ();

    fn outputs(&self) -> usize {
        self.fields() + 1
    }

    fn scratch(&self) {}

    fn run_chunk(&self, rng: &mut Rng, placements: u64, _: &mut (), out: &mut [C64]) {
        let j = self.fields();
        for _ in 0..placements {
            let pos = place_scatterers(self.scene, rng);
            for (o, u) in out[..j].iter_mut().zip(solve(self.scene, &pos)) {
                *o += u;
            }
            out[j] += pos.len() as f64;
        }
    }
}

/// Sample statistics over placements: mean field, covariance `E[(u − m)(u' − m')*]` (unbiased,
/// `R − 1`) and their standard errors (of the mean over `R` placements).
#[derive(Clone, Debug, PartialEq)]
pub struct WaveStatistics {
    pub mean: Vec<C64>,
    pub mean_stderr: Vec<f64>,
    /// `J×J` row-major.
    pub covariance: Vec<C64>,
    pub covariance_stderr: Vec<f64>,
}

impl WaveStatistics {
    /// From `R` placements' fields, placement after placement (`R×J`, row-major).
    pub fn from_fields(fields: &[C64], j: usize) -> Self {
        let r = (fields.len() / j) as f64;
        let rows = || fields.chunks_exact(j);
        let mean: Vec<C64> = (0..j)
            .map(|a| rows().map(|u| u[a]).sum::<C64>() / r)
            .collect();
        let mut covariance = vec![C64::default(); j * j];
        let mut covariance_stderr = vec![0.0; j * j];
        for a in 0..j {
            for b in 0..j {
                let prod = |u: &[C64]| (u[a] - mean[a]) * (u[b] - mean[b]).conj();
                let c = rows().map(prod).sum::<C64>() / (r - 1.0);
                let var = rows().map(|u| (prod(u) - c).norm_sqr()).sum::<f64>() / (r - 1.0);
                covariance[a * j + b] = c;
                covariance_stderr[a * j + b] = (var / r).sqrt();
            }
        }
        let mean_stderr = (0..j)
            .map(|a| {
                (rows().map(|u| (u[a] - mean[a]).norm_sqr()).sum::<f64>() / (r - 1.0) / r).sqrt()
            })
            .collect();
        WaveStatistics {
            mean,
            mean_stderr,
            covariance,
            covariance_stderr,
        }
    }
}
