//! Importance sampling of a subpath's first vertex and direction for focused lights (paper 000,
//! Sec. 6, Eqs. 39–41).
//!
//! The first vertex is drawn from the Gaussian beams of the focused lights (Eqs. 34–35): along the
//! axis half uniformly over the medium's extent and half from the beam's peak intensity
//! `∝ 1/w(z)²` (not in the paper: single scattering between a light and a view focused on one
//! point lives near the focus), across it from a planar Gaussian of width
//! `w(z)² = (γ_a + γ_s)/k² + z²/γ_a`, with `z` the distance from the focus along the axis. The
//! first direction is drawn from a vMF approximation of `|Υ(ω | x₁, i)|²` (Eq. 41): each lobe's
//! convolution with the aperture (Eqs. 31–32) is a complex vMF whose squared magnitude is a real
//! one. Focused views add beams too (one per group sharing an axis and aperture), where reversed
//! paths start: a path's last vertex is not steered, so without them the views' beams are reached
//! by chance, which gave large volumes a heavy-tailed error. Both proposals are defensive mixtures with a uniform part, and their densities are
//! evaluated exactly, so the estimator stays unbiased whatever the approximations' quality.

use crate::math::vmf::Vmf;
use crate::math::{C64, Rng, direction_about, orthonormal_basis, uniform, uniform_sphere};
use crate::medium::lobes::Lobes;
use crate::medium::{Geometry, Medium};
use crate::speckle::endpoint::Lens;
use glam::DVec3;
use std::f64::consts::PI;

/// Share of first vertices (and directions) drawn uniformly, so no region has a vanishing density.
const DEFENSIVE: f64 = 0.1;

/// How a subpath's first vertex and direction are drawn (`[render] first_vertex` and
/// `first_direction`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Sampling {
    /// Uniform first vertex and direction (paper 001's estimator).
    Uniform,
    /// First vertex from the focused lights' and views' Gaussian beams, direction uniform.
    Beam,
    /// First vertex from the beams and direction from `|Υ|²` (the default).
    #[default]
    BeamAndAperture,
}

/// One focused light's beam, or a group of focused views' (then the reversed paths start in it).
struct Beam {
    lens: Lens,
    /// A views' beam: first directions point against the view's `|Υ|²` lobes (the reversed path
    /// leaves the first vertex towards the view).
    view: bool,
    /// Frame across the axis.
    across: (DVec3, DVec3),
    /// Waist variance `(γ_a + γ_s)/k²`.
    waist2: f64,
    /// Extent of the medium along the axis, relative to the focus.
    z_range: (f64, f64),
    /// The Cauchy half of [`axial_pdf`]: scale `c = w₀ √γ` and `atan(z/c)` at the extent's ends.
    cauchy: (f64, f64, f64),
}

/// Draws first vertices and directions for one scene.
pub struct FirstVertex {
    beams: Vec<Beam>,
    directions: bool,
    /// Volume of the uniform draw: absolute with beams (their results are absolute, in a slab
    /// too), per unit area of a slab without.
    volume: f64,
    geometry: Geometry,
    k: f64,
}

/// A drawn first vertex and `1/p(x₁)`.
pub struct Drawn {
    pub x: DVec3,
    pub inv_pdf: f64,
}

impl FirstVertex {
    /// Beams for the focused lights and groups of focused views with a real aperture (`γ ≥ 1`;
    /// wider ones are sampled uniformly like isotropic sources). `lobes` are those of the first particle type, whose mean
    /// concentration widens the beam (Eq. 35).
    pub fn new(
        sampling: Sampling,
        lights: &[Lens],
        views: &[Lens],
        medium: &Medium,
        lobes: &Lobes,
        k: f64,
    ) -> Self {
        let gamma_s = {
            let total: f64 = lobes.lobes.iter().map(|l| l.weight.norm()).sum();
            if total > 0.0 {
                lobes
                    .lobes
                    .iter()
                    .map(|l| l.weight.norm() * l.kappa.max(0.0))
                    .sum::<f64>()
                    / total
            } else {
                0.0
            }
        };
        let beam = |lens: Lens, spread2: f64, view: bool| {
            let waist2 = (lens.gamma + gamma_s) / (k * k) + spread2;
            let z_range = extent(&medium.geometry, lens.focus, lens.axis);
            let c = (waist2 * lens.gamma).sqrt();
            Beam {
                lens,
                view,
                across: orthonormal_basis(lens.axis),
                waist2,
                z_range,
                cauchy: (c, (z_range.0 / c).atan(), (z_range.1 / c).atan()),
            }
        };
        let beams = if sampling == Sampling::Uniform {
            Vec::new()
        } else {
            let mut beams: Vec<Beam> = lights
                .iter()
                .filter(|l| l.gamma >= 1.0)
                .map(|lens| beam(*lens, 0.0, false))
                .collect();
            // views sharing an axis and aperture (an image of foci) share one beam about their
            // mean focus, widened by the foci's spread across the axis
            let mut groups: Vec<Vec<Lens>> = Vec::new();
            for v in views.iter().filter(|l| l.gamma >= 1.0) {
                match groups
                    .iter_mut()
                    .find(|g| g[0].axis.dot(v.axis) > 1.0 - 1e-12 && g[0].gamma == v.gamma)
                {
                    Some(g) => g.push(*v),
                    None => groups.push(vec![*v]),
                }
            }
            for g in groups {
                let n = g.len() as f64;
                let mean = g.iter().map(|l| l.focus).sum::<DVec3>() / n;
                let axis = g[0].axis;
                let spread2 = g
                    .iter()
                    .map(|l| {
                        let d = l.focus - mean;
                        (d - axis * d.dot(axis)).length_squared()
                    })
                    .sum::<f64>()
                    / (2.0 * n);
                beams.push(beam(
                    Lens {
                        focus: mean,
                        ..g[0]
                    },
                    spread2,
                    true,
                ));
            }
            beams
        };
        let g = &medium.geometry;
        FirstVertex {
            volume: if beams.is_empty() {
                g.sampling_volume() / g.normalising_area()
            } else {
                g.sampling_volume()
            },
            beams,
            directions: sampling == Sampling::BeamAndAperture,
            geometry: g.clone(),
            k,
        }
    }

    fn beam_pdf(&self, b: &Beam, x: DVec3) -> f64 {
        let d = x - b.lens.focus;
        let z = d.dot(b.lens.axis);
        if z < b.z_range.0 || z > b.z_range.1 {
            return 0.0;
        }
        let r2 = (d - b.lens.axis * z).length_squared();
        let w2 = b.waist2 + z * z / b.lens.gamma;
        (-0.5 * r2 / w2).exp() / (2.0 * PI * w2) * axial_pdf(b, z)
    }

    /// `p(x₁)`: the defensive mixture of the uniform density and the beams.
    fn pdf(&self, x: DVec3) -> f64 {
        let beams: f64 = self.beams.iter().map(|b| self.beam_pdf(b, x)).sum();
        let uniform = if self.geometry.in_sampling_volume(x) {
            DEFENSIVE / self.volume
        } else {
            0.0
        };
        uniform + (1.0 - DEFENSIVE) * beams / self.beams.len() as f64
    }

    /// Draw `x₁` (it may fall outside the medium: the caller then has an empty path).
    pub fn draw(&self, geo: &Geometry, rng: &mut Rng) -> Drawn {
        if self.beams.is_empty() {
            return Drawn {
                x: geo.sample_volume([uniform(rng), uniform(rng), uniform(rng)]),
                inv_pdf: self.volume,
            };
        }
        let x = if uniform(rng) < DEFENSIVE {
            geo.sample_volume([uniform(rng), uniform(rng), uniform(rng)])
        } else {
            let b = &self.beams
                [((uniform(rng) * self.beams.len() as f64) as usize).min(self.beams.len() - 1)];
            let z = sample_axial(b, uniform(rng), uniform(rng));
            let w = (b.waist2 + z * z / b.lens.gamma).sqrt();
            // Box–Muller
            let r = w * (-2.0 * (1.0 - uniform(rng)).ln()).sqrt();
            let phi = 2.0 * PI * uniform(rng);
            b.lens.focus
                + b.lens.axis * z
                + b.across.0 * (r * phi.cos())
                + b.across.1 * (r * phi.sin())
        };
        Drawn {
            x,
            inv_pdf: 1.0 / self.pdf(x),
        }
    }

    /// Draw the first direction at `x` and return it with `1/p(ω₁ | x₁)`.
    pub fn direction(
        &self,
        x: DVec3,
        medium: &Medium,
        lobes: &Lobes,
        rng: &mut Rng,
        scratch: &mut Vec<(f64, DVec3, f64)>,
    ) -> (DVec3, f64) {
        if !self.directions || self.beams.is_empty() {
            return (uniform_sphere(uniform(rng), uniform(rng)), 4.0 * PI);
        }
        // the proposal: real vMF lobes (weight, mean direction, concentration) over all beams,
        // each beam weighted by its share of p(x₁)
        scratch.clear();
        let total_share: f64 = self.beams.iter().map(|b| self.beam_pdf(b, x)).sum();
        if total_share > 0.0 {
            for b in &self.beams {
                // recomputed rather than collected: no allocation per path
                let share = self.beam_pdf(b, x);
                if share == 0.0 {
                    continue;
                }
                let start = scratch.len();
                let aperture: Vmf = b.lens.aperture(x, medium, self.k);
                for l in &lobes.lobes {
                    let mut a = aperture;
                    a.log_scale -= l.kappa;
                    let v = a.convolve(l.kappa, b.lens.axis);
                    let re = v.mu.re;
                    let kappa = 2.0 * re.length();
                    let dir = re.normalize_or(b.lens.axis) * if b.view { -1.0 } else { 1.0 };
                    // ∫ |w e^{L + μ·ω}|² dω = |w|² e^{2 Re L} ∫ e^{2 Re μ·ω} dω
                    let log_mass = 2.0 * (v.log_scale.re + l.weight.norm().max(1e-300).ln())
                        + crate::math::vmf::log_sphere_integral(C64::new(kappa * kappa, 0.0)).re;
                    scratch.push((log_mass, dir, kappa));
                }
                let top = scratch[start..]
                    .iter()
                    .map(|s| s.0)
                    .fold(f64::NEG_INFINITY, f64::max);
                let sum: f64 = scratch[start..].iter().map(|s| (s.0 - top).exp()).sum();
                for s in &mut scratch[start..] {
                    s.0 = (s.0 - top).exp() / sum * share / total_share;
                }
            }
        }
        let w = if scratch.is_empty() || uniform(rng) < DEFENSIVE {
            uniform_sphere(uniform(rng), uniform(rng))
        } else {
            let mut u = uniform(rng);
            let mut pick = scratch.len() - 1;
            for (i, s) in scratch.iter().enumerate() {
                if u < s.0 {
                    pick = i;
                    break;
                }
                u -= s.0;
            }
            let (_, dir, kappa) = scratch[pick];
            sample_vmf(dir, kappa, uniform(rng), uniform(rng))
        };
        let lobes_pdf: f64 = scratch
            .iter()
            .map(|(p, dir, kappa)| p * vmf_pdf(*dir, *kappa, w))
            .sum();
        let pdf = if scratch.is_empty() {
            1.0 / (4.0 * PI)
        } else {
            DEFENSIVE / (4.0 * PI) + (1.0 - DEFENSIVE) * lobes_pdf
        };
        (w, 1.0 / pdf)
    }
}

/// Density of the distance `z` from the focus along a beam's axis: half uniform over the medium's
/// extent (the beam's power crosses every depth), half a Cauchy law about the focus of scale
/// `c = w₀ √γ` (`∝ 1/w(z)²`, the beam's peak intensity: where the single scattering between a
/// light and a view focused near the same point lives), both truncated to the extent.
fn axial_pdf(b: &Beam, z: f64) -> f64 {
    let (z0, z1) = b.z_range;
    if z < z0 || z > z1 || z1 <= z0 {
        return 0.0;
    }
    let (c, a0, a1) = b.cauchy;
    let t = z / c;
    0.5 / (z1 - z0) + 0.5 / (c * (1.0 + t * t) * (a1 - a0))
}

/// Draw `z` from [`axial_pdf`] with two uniform numbers.
fn sample_axial(b: &Beam, u_mix: f64, u: f64) -> f64 {
    let (z0, z1) = b.z_range;
    if u_mix < 0.5 {
        return z0 + (z1 - z0) * u;
    }
    let (c, a0, a1) = b.cauchy;
    // max/min rather than clamp: degenerate (non-finite) bounds give NaN, caught before writing
    (c * (a0 + (a1 - a0) * u).tan()).max(z0).min(z1)
}

/// The extent of the medium along `axis` relative to `focus` (the projection of its bounds).
fn extent(g: &Geometry, focus: DVec3, axis: DVec3) -> (f64, f64) {
    match g {
        Geometry::Box { half } => {
            let reach = half.x * axis.x.abs() + half.y * axis.y.abs() + half.z * axis.z.abs();
            let c = -focus.dot(axis);
            (c - reach, c + reach)
        }
        Geometry::Slab { half_thickness, .. } => {
            // the slab is unbounded across: only the crossing of its faces bounds the axis
            if axis.z.abs() < 1e-9 {
                return (-*half_thickness, *half_thickness);
            }
            let a = (-half_thickness - focus.z) / axis.z;
            let b = (half_thickness - focus.z) / axis.z;
            (a.min(b), a.max(b))
        }
    }
}

/// Density of the real vMF of mean `dir` and concentration `kappa` per unit solid angle.
fn vmf_pdf(dir: DVec3, kappa: f64, w: DVec3) -> f64 {
    if kappa < 1e-8 {
        return 1.0 / (4.0 * PI);
    }
    kappa * (kappa * (dir.dot(w) - 1.0)).exp() / (2.0 * PI * -(-2.0 * kappa).exp_m1())
}

/// Draw from the real vMF of mean `dir` and concentration `kappa`.
fn sample_vmf(dir: DVec3, kappa: f64, u1: f64, u2: f64) -> DVec3 {
    direction_about(
        dir,
        crate::math::vmf::sample_cosine(kappa, u1),
        2.0 * PI * u2,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::stream_rng;

    /// The vMF density integrates to one and its sampler follows it (mean cosine `coth κ − 1/κ`).
    #[test]
    fn vmf_sampler_matches_its_density() {
        let dir = DVec3::new(0.3, -0.2, 0.9).normalize();
        for kappa in [0.5, 8.0, 300.0] {
            let mut rng = stream_rng(3, 0);
            let n = 200_000;
            let mean: f64 = (0..n)
                .map(|_| dir.dot(sample_vmf(dir, kappa, uniform(&mut rng), uniform(&mut rng))))
                .sum::<f64>()
                / n as f64;
            let expect = 1.0 / kappa.tanh() - 1.0 / kappa;
            assert!(
                (mean - expect).abs() < 3e-3,
                "κ {kappa}: {mean} vs {expect}"
            );
            // ∫ pdf dω = 1 by quadrature in μ about dir
            let (x, w) = crate::math::gauss_legendre(400);
            let integral: f64 = x
                .iter()
                .zip(&w)
                .map(|(mu, wi)| {
                    let v = direction_about(dir, *mu, 0.0);
                    wi * 2.0 * PI * vmf_pdf(dir, kappa, v)
                })
                .sum();
            assert!(
                (integral - 1.0).abs() < 1e-6,
                "κ {kappa}: ∫ pdf = {integral}"
            );
        }
    }
}
