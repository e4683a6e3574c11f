//! Focused apertures by quadrature over their far-field directions: the reference for the vMF closed
//! forms. A focused field is the far-field one integrated over the aperture (paper 000, Eq. 9), so
//! per path the near-field contribution is the far-field connections `ξ(î → o) e^{−σ_t d(î)/2}
//! s(î·ω)` summed over aperture directions with the weights `m(î) e^{∓ik î·focus}` (Eqs. 15–17):
//! Eq. 11 evaluated path by path. With `Attenuation::Exact` every direction is attenuated over its
//! own length inside the medium, and the amplitude is the phase function's own, so this drops the
//! approximations of Sec. 5 (the attenuation model, Eq. 25; vMF lobes, Eq. 28; the vMF convolution,
//! Eqs. 31–32) for `Υ`. `Attenuation::Linearised` keeps the closed forms' attenuation model (the
//! axis path `h` as `d(ω) = h (2 − a·ω)`) and isolates its bias; `Attenuation::Axis` is paper
//! 000's Eq. 25, `d(ω) = h`.
//!
//! The two-lens single-scattering term (Eq. 18) is a double integral; it is summed over the light's
//! directions, each paired with the view's aperture integral of an amplitude lobe in closed form
//! (Eq. 29), so there the view side keeps the axis attenuation and the amplitude's lobes.
//!
//! `ApertureModel::MonteCarlo` is paper 000's other far-field route (Sec. 8, "F.F. M.C."): the
//! same sums over directions drawn at random from each aperture's mask, afresh at every vertex.
//! Each `Υ` is then an unbiased estimate, but a product of an estimate with its own conjugate is
//! not (`E|Υ̂|² = |Υ|² + Var Υ̂`), so the sampler draws two independent sets per event and the
//! second moments take `(a bᴴ + b aᴴ)/2` (`EventSink::event_pair`). The two-lens term pairs the
//! light's and the view's drawn directions one to one, each attenuated over its own length.

use crate::math::vmf::sample_cosine;
use crate::math::{C64, Rng, cis, gauss_legendre, orthonormal_basis, uniform};
use crate::medium::lobes::Lobes;
use crate::medium::{Medium, PhaseFunction};
use crate::speckle::endpoint::{Lens, Seen};
use glam::DVec3;

/// How a quadrature aperture attenuates its directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Attenuation {
    /// Each direction over its own path inside the medium (Eq. 11 without approximation).
    Exact,
    /// The closed forms' model: the axis path `h` linearised in the direction, `h (2 − a·ω)`.
    Linearised,
    /// Every direction over the axis path (paper 000, Eq. 25).
    Axis,
}

/// How focused apertures are integrated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ApertureModel {
    /// vMF closed forms (paper 000, Sec. 5): fast, the default.
    #[default]
    Vmf,
    /// Quadrature over the aperture's far-field directions: a slow reference.
    Quadrature(Attenuation),
    /// This many far-field directions per aperture and vertex, drawn from its mask, each
    /// attenuated over its own length (paper 000's "F.F. M.C.").
    MonteCarlo(usize),
}

/// Most directions `aperture_directions` may ask for per aperture and vertex.
pub const MAX_RANDOM_DIRECTIONS: usize = 100_000;

/// Mask below which aperture directions are left out (`e^{−30}` of the axis).
const MASK_FLOOR: f64 = 30.0;

/// Quadrature nodes of one lens: propagation directions and weights `dω · m(ω)`.
#[derive(Clone, Debug, Default)]
pub struct ApertureGrid {
    dirs: Vec<DVec3>,
    weights: Vec<f64>,
}

impl ApertureGrid {
    /// Gauss–Legendre in `cos θ` about the axis (down to where the mask falls below `e^{−30}`)
    /// times the trapezoid rule in `φ`, resolving the phase `e^{ik ω·(x − focus)}` for `|x − focus|
    /// ≤ reach` and amplitude lobes as sharp as `sharpest` (their width `1/√κ`): node counts grow
    /// with `k·reach` and `√κ`, plus a margin that makes both rules converge spectrally.
    pub fn new(lens: &Lens, reach: f64, k: f64, sharpest: f64) -> Self {
        let t_min = (1.0 - MASK_FLOOR / lens.gamma.max(1e-12)).max(-1.0);
        let sin_max = if t_min <= 0.0 {
            1.0
        } else {
            (1.0 - t_min * t_min).sqrt()
        };
        let theta_max = t_min.acos();
        let lobe = 4.0 * sharpest.max(1.0).sqrt();
        let kr = k * reach;
        let n_t = (0.5 * kr * (1.0 - t_min) + lobe * theta_max) as usize + 24;
        let n_phi = (kr * sin_max + lobe * 2.0 * std::f64::consts::PI * sin_max) as usize + 24;
        let (x, w) = gauss_legendre(n_t);
        let (e1, e2) = orthonormal_basis(lens.axis);
        let mut dirs = Vec::with_capacity(n_t * n_phi);
        let mut weights = Vec::with_capacity(n_t * n_phi);
        let d_phi = 2.0 * std::f64::consts::PI / n_phi as f64;
        for (xi, wi) in x.iter().zip(&w) {
            let t = t_min + (1.0 - t_min) * (xi + 1.0) / 2.0;
            let s = (1.0 - t * t).max(0.0).sqrt();
            let mask = (lens.gamma * (t - 1.0)).exp();
            for j in 0..n_phi {
                let phi = d_phi * j as f64;
                dirs.push(e1 * (s * phi.cos()) + e2 * (s * phi.sin()) + lens.axis * t);
                weights.push(wi * (1.0 - t_min) / 2.0 * d_phi * mask);
            }
        }
        ApertureGrid { dirs, weights }
    }

    /// Replaces the nodes with `n` directions drawn from the mask `m(ω) = e^{γ(ω·a − 1)}` (a vMF
    /// law about the axis), each weighing `∫m dω / n = 2π(1 − e^{−2γ})/(γ n)`, so sums over them
    /// are unbiased estimates of the aperture integrals.
    pub fn draw(&mut self, lens: &Lens, n: usize, rng: &mut Rng) {
        let g = lens.gamma;
        let mass = if g < 1e-8 {
            4.0 * std::f64::consts::PI
        } else {
            2.0 * std::f64::consts::PI * -(-2.0 * g).exp_m1() / g
        };
        let (e1, e2) = orthonormal_basis(lens.axis);
        self.dirs.clear();
        self.weights.clear();
        for _ in 0..n {
            let t = sample_cosine(g, uniform(rng));
            let s = (1.0 - t * t).max(0.0).sqrt();
            let phi = 2.0 * std::f64::consts::PI * uniform(rng);
            self.dirs
                .push(e1 * (s * phi.cos()) + e2 * (s * phi.sin()) + lens.axis * t);
            self.weights.push(mass / n as f64);
        }
    }
}

/// The quadrature grids of a scene's focused lights and views (`None` for the others).
pub struct Quadrature {
    pub attenuation: Attenuation,
    pub lights: Vec<Option<ApertureGrid>>,
    pub views: Vec<Option<ApertureGrid>>,
}

impl Quadrature {
    /// Grids that resolve every vertex of `medium` (a box) for amplitude lobes up to `sharpest`.
    pub fn new(
        attenuation: Attenuation,
        lights: &[Option<Lens>],
        views: &[Option<Lens>],
        medium: &Medium,
        k: f64,
        sharpest: f64,
    ) -> Self {
        let reach = |l: &Lens| match medium.geometry {
            crate::medium::Geometry::Box { half } => (l.focus.abs() + half).length(),
            crate::medium::Geometry::Slab { .. } => f64::INFINITY,
        };
        let grids = |lenses: &[Option<Lens>]| {
            lenses
                .iter()
                .map(|l| {
                    l.as_ref()
                        .map(|l| ApertureGrid::new(l, reach(l), k, sharpest))
                })
                .collect()
        };
        Quadrature {
            attenuation,
            lights: grids(lights),
            views: grids(views),
        }
    }
}

/// A lens's aperture seen from one vertex: the weights `ã(ω_q)` of Eq. 17 at every node.
pub fn weighted_aperture(
    lens: &Lens,
    grid: &ApertureGrid,
    attenuation: Attenuation,
    x: DVec3,
    medium: &Medium,
    k: f64,
    out: &mut Vec<C64>,
) {
    out.clear();
    let sigma_t = medium.sigma_t();
    let rel = (x - lens.focus) * (lens.sign * k);
    let axis_path = medium.geometry.exit_distance(x, lens.axis * -lens.sign);
    for (w, m) in grid.dirs.iter().zip(&grid.weights) {
        let inside = match attenuation {
            Attenuation::Exact => medium.geometry.exit_distance(x, *w * -lens.sign),
            Attenuation::Linearised => axis_path * (2.0 - w.dot(lens.axis)),
            Attenuation::Axis => axis_path,
        };
        out.push(cis(rel.dot(*w)) * (m * (-0.5 * sigma_t * inside).exp()));
    }
}

/// `Υ` (Eqs. 15–16) at a vertex from the weights of [`weighted_aperture`]: the path direction
/// there is `u` (`u = −ω₁` at a first vertex for a light, `u = ω_in` at a last for a view), and
/// the amplitude is taken of the cosine between the aperture's direction and the path's.
pub fn upsilon(
    lens: &Lens,
    grid: &ApertureGrid,
    weights: &[C64],
    u: DVec3,
    phase: &PhaseFunction,
) -> C64 {
    let w = u * -lens.sign;
    grid.dirs
        .iter()
        .zip(weights)
        .map(|(d, c)| c * phase.amplitude(d.dot(w)))
        .sum()
}

/// Eq. 18 for a focused light and a focused view at one vertex: the light's aperture by
/// quadrature, each of its directions paired with the view's aperture integral of every
/// amplitude lobe in closed form.
pub fn lens_pair(grid: &ApertureGrid, light_weights: &[C64], view: &Seen, lobes: &Lobes) -> C64 {
    grid.dirs
        .iter()
        .zip(light_weights)
        .map(|(d, c)| {
            let y: C64 = lobes
                .lobes
                .iter()
                .map(|l| l.weight * view.aperture_lobe(*d, l.kappa, false).value)
                .sum();
            c * y
        })
        .sum()
}

/// Eq. 18 for a focused light and a focused view at one vertex from drawn directions (Monte Carlo
/// apertures): the light's `k`-th direction paired with the view's `k`-th, both attenuated over
/// their own lengths, `n Σ_k c_l(k) c_v(k) s(d_l·d_v)`, an unbiased estimate of the double
/// integral.
pub fn lens_pair_drawn(
    light: (&ApertureGrid, &[C64]),
    view: (&ApertureGrid, &[C64]),
    phase: &PhaseFunction,
) -> C64 {
    let n = light.0.dirs.len() as f64;
    let sum: C64 = (light.0.dirs.iter().zip(light.1))
        .zip(view.0.dirs.iter().zip(view.1))
        .map(|((dl, cl), (dv, cv))| cl * cv * phase.amplitude(dl.dot(*dv)))
        .sum();
    sum * n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::lobes::VmfMixture;
    use crate::medium::{Geometry, Scattering};
    use crate::speckle::endpoint::Terminal;

    /// A forward-peaked amplitude that is exactly a vMF mixture (so Eq. 29 is exact for it), and a
    /// light and a view focused near each other on a tilted axis.
    fn lens_pair_setup() -> (PhaseFunction, Lens, Lens) {
        let v = VmfMixture::new(&[1.0, 0.3], &[20.0, 2.0]).unwrap();
        let lens = |f: DVec3, s: f64, sign: f64| Lens {
            focus: f,
            axis: DVec3::new(0.1, 0.0, 1.0).normalize(),
            gamma: 1.0 / (s * s),
            sign,
        };
        (
            PhaseFunction::VmfMixture(v),
            lens(DVec3::new(0.0, 0.0, 2.0), 0.4, 1.0),
            lens(DVec3::new(0.5, 0.0, 2.0), 0.3, -1.0),
        )
    }

    /// With the linearised attenuation and an amplitude that is exactly a vMF mixture, the quadrature
    /// `Υ` equals the closed form of Eq. 29 to 1e-8 (so the grid resolves the phase and the lobes),
    /// and the two-lens term is within the Eqs. 31–32 approximation's error of it (< 5 %).
    #[test]
    fn quadrature_matches_the_closed_forms() {
        let (phase, light, view) = lens_pair_setup();
        let medium = Medium {
            geometry: Geometry::boxed([6.0, 6.0, 4.0]),
            sigma_s: 0.3,
            sigma_a: 0.05,
            scattering: Scattering::single(phase.clone()),
        };
        let lobes = Lobes::of(&phase);
        let k = 2.0 * std::f64::consts::PI;
        let grid = ApertureGrid::new(&light, 7.0, k, 20.0);
        let mut c = Vec::new();
        for x in [
            DVec3::new(0.1, 0.2, -1.0),
            DVec3::new(1.0, -0.7, 1.5),
            DVec3::new(0.0, 0.0, 1.9),
        ] {
            weighted_aperture(
                &light,
                &grid,
                Attenuation::Linearised,
                x,
                &medium,
                k,
                &mut c,
            );
            let seen = Terminal::Lens(light).seen_from(x, &medium, k);
            for u in [DVec3::new(0.2, -0.1, -1.0).normalize(), -DVec3::Z, DVec3::X] {
                let q = upsilon(&light, &grid, &c, u, &phase);
                let closed = seen.amplitude(u, &phase, &lobes);
                let scale = seen.aperture_lobe(-DVec3::Z, 0.0, false).value.norm();
                assert!(
                    (q - closed).norm() < 1e-8 * scale,
                    "{x}, {u}: {q} vs {closed}"
                );
            }
            let seen_view = Terminal::Lens(view).seen_from(x, &medium, k);
            let q = lens_pair(&grid, &c, &seen_view, &lobes);
            let closed = seen.single(&seen_view, &phase, &lobes);
            // measured: 0.5 % in the beam, 3.5 % at (1, −0.7, 1.5) off it
            assert!(
                (q - closed).norm() < 5e-2 * q.norm() + 1e-12,
                "{x}: {q} vs {closed}"
            );
        }
    }

    /// Drawn directions give unbiased aperture integrals: the mean of `Υ` over independent draws
    /// equals the quadrature's (each direction attenuated over its own length) within 4 standard
    /// errors, and so does the paired two-lens term with Eq. 18's double integral where the
    /// amplitude is a vMF mixture and the medium barely attenuates (the light's aperture by
    /// quadrature, the view's in closed form: exact there); the draws' weights sum to the mask's
    /// integral `2π(1 − e^{−2γ})/γ`.
    #[test]
    fn drawn_directions_are_unbiased() {
        let (phase, light, view) = lens_pair_setup();
        let lobes = Lobes::of(&phase);
        let k = 2.0 * std::f64::consts::PI;
        let mut rng = crate::math::stream_rng(3, 0);
        let mut drawn = ApertureGrid::default();
        drawn.draw(&light, 1000, &mut rng);
        let mass: f64 = drawn.weights.iter().sum();
        let g = light.gamma;
        let exact = 2.0 * std::f64::consts::PI * (1.0 - (-2.0 * g).exp()) / g;
        assert!((mass - exact).abs() < 1e-12 * exact, "{mass} vs {exact}");
        let medium = |sigma_s: f64| Medium {
            geometry: Geometry::boxed([6.0, 6.0, 4.0]),
            sigma_s,
            sigma_a: 0.05 * sigma_s / 0.3,
            scattering: Scattering::single(phase.clone()),
        };
        let (attenuating, clear) = (medium(0.3), medium(1e-9));
        let grid = ApertureGrid::new(&light, 7.0, k, 20.0);
        let (mut c, mut cv) = (Vec::new(), Vec::new());
        let mut drawn_v = ApertureGrid::default();
        let draws = 4000;
        for x in [DVec3::new(0.1, 0.2, -1.0), DVec3::new(0.3, -0.2, 1.7)] {
            let u = DVec3::new(0.2, -0.1, -1.0).normalize();
            weighted_aperture(
                &light,
                &grid,
                Attenuation::Exact,
                x,
                &attenuating,
                k,
                &mut c,
            );
            let reference = upsilon(&light, &grid, &c, u, &phase);
            // Eq. 18 with the light's aperture by quadrature and the view's in closed form (Eq.
            // 29, exact for vMF lobes): exact where nothing attenuates
            let seen_v = Terminal::Lens(view).seen_from(x, &clear, k);
            let mut c_clear = Vec::new();
            weighted_aperture(
                &light,
                &grid,
                Attenuation::Exact,
                x,
                &clear,
                k,
                &mut c_clear,
            );
            let closed = lens_pair(&grid, &c_clear, &seen_v, &lobes);
            let (mut sum, mut sum2) = (C64::default(), 0.0);
            let (mut pair, mut pair2) = (C64::default(), 0.0);
            for _ in 0..draws {
                drawn.draw(&light, 8, &mut rng);
                weighted_aperture(
                    &light,
                    &drawn,
                    Attenuation::Exact,
                    x,
                    &attenuating,
                    k,
                    &mut c,
                );
                let y = upsilon(&light, &drawn, &c, u, &phase);
                sum += y;
                sum2 += y.norm_sqr();
                drawn_v.draw(&view, 8, &mut rng);
                weighted_aperture(&light, &drawn, Attenuation::Exact, x, &clear, k, &mut c);
                weighted_aperture(&view, &drawn_v, Attenuation::Exact, x, &clear, k, &mut cv);
                let p = lens_pair_drawn((&drawn, &c), (&drawn_v, &cv), &phase);
                pair += p;
                pair2 += p.norm_sqr();
            }
            let n = draws as f64;
            for (name, s, s2, truth) in [
                ("Υ", sum, sum2, reference),
                ("two-lens", pair, pair2, closed),
            ] {
                let mean = s / n;
                let se = ((s2 / n - mean.norm_sqr()) / n).sqrt();
                eprintln!("{x} {name}: {mean:.4e} ± {se:.2e} vs {truth:.4e}");
                assert!(
                    (mean - truth).norm() < 4.0 * se,
                    "{x} {name}: {mean} vs {truth}"
                );
                // the test resolves the quantity: its error is well below its size
                assert!(se < 0.1 * truth.norm(), "{x} {name}: error {se} of {truth}");
            }
        }
    }
}
