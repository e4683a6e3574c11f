//! Lorenz–Mie scattering by homogeneous spheres (Bohren & Huffman 1983, Ch. 4; the recurrences and
//! series length of Wiscombe 1980), and averages over log-normal size distributions.
//!
//! Conventions are Bohren & Huffman's: time dependence `exp(-iωt)`, relative index
//! `m = (n + iκ)/n_medium` with `κ ≥ 0` absorbing, size parameter `x = π d / λ` with `λ` the
//! wavelength *in the medium*. The amplitudes `S1` (polarisation perpendicular to the scattering
//! plane) and `S2` (parallel) give `dC_sca/dΩ = (|S1|² + |S2|²) / (2k²)` for unpolarised light.
//!
//! The speckle estimators use one scalar amplitude `s(μ)` with `|s|² = ρ` and `∫ρ dω = 1`. The
//! scattered far field is `f = i S / k` times the incident one (`E_s = e^{ikr} / (−ikr) S E_i`), so
//! [`Polarisation::Perpendicular`] and [`Polarisation::Parallel`] take `s ∝ i S1` and `s ∝ i S2`
//! exactly. Unpolarised light has no scalar amplitude; [`Polarisation::Unpolarised`] takes the
//! magnitude from `(|S1|² + |S2|²)/2` and the phase of `i S1`, which equals `i S2` forward and,
//! unlike `S1 + S2`, stays defined at backscatter (where `S2 = −S1`).

use crate::math::C64;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Why a Mie computation was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum MieError {
    SizeParameter(f64),
    Index(C64),
    Spread(f64),
}

impl std::fmt::Display for MieError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MieError::SizeParameter(x) => write!(
                f,
                "size parameter π d / λ = {x}: must be within [1e-6, 20000] (smaller spheres are \
                 Rayleigh scatterers; larger ones need geometric optics)"
            ),
            MieError::Index(m) => write!(
                f,
                "relative index {m}: the real part must be positive and the imaginary part (absorption) >= 0"
            ),
            MieError::Spread(s) => write!(
                f,
                "diameter spread {s}: must be >= 0 and below 3 × the mean diameter"
            ),
        }
    }
}

/// Efficiencies (cross-sections over the geometric cross-section `π d²/4`) and the asymmetry `g`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Efficiencies {
    pub ext: f64,
    pub sca: f64,
    pub abs: f64,
    /// Radar backscattering efficiency `|Σ (2n+1)(−1)ⁿ (aₙ − bₙ)|² / x²` (BH Eq. 4.82).
    pub back: f64,
    /// Mean cosine of the scattering angle.
    pub g: f64,
}

/// The Mie coefficients `aₙ, bₙ` of one sphere (BH Eq. 4.88).
#[derive(Clone, Debug)]
pub struct Sphere {
    x: f64,
    absorbing: bool,
    a: Vec<C64>,
    b: Vec<C64>,
}

impl Sphere {
    /// Coefficients for size parameter `x` and relative index `m`: `Dₙ(mx)` by downward
    /// recurrence (BH Eq. 4.89), `ψₙ`, `ξₙ` upward, `x + 4.05 x^{1/3} + 2` terms (Wiscombe). The
    /// recurrence starts `16 + 16 |mx|^{1/3}` orders above `max(nstop, |mx|)`: BHMIE's `+15` loses
    /// digits from x ≈ 100 on (Q_sca 3e-4 off at x = 1000), as its start value 0 is only forgotten
    /// past the turning point, whose width grows as `|mx|^{1/3}`.
    pub fn new(x: f64, m: C64) -> Result<Sphere, MieError> {
        if !(x.is_finite() && (1e-6..=2e4).contains(&x)) {
            return Err(MieError::SizeParameter(x));
        }
        if !(m.re.is_finite() && m.im.is_finite() && m.re > 0.0 && m.im >= 0.0) {
            return Err(MieError::Index(m));
        }
        let nstop = (x + 4.05 * x.cbrt() + 2.0) as usize;
        let mx = m * x;
        let nmx = nstop.max(mx.norm() as usize) + 16 + (16.0 * mx.norm().cbrt()) as usize;
        let mut d = vec![C64::new(0.0, 0.0); nmx + 1];
        for n in (1..=nmx).rev() {
            let r = C64::new(n as f64, 0.0) / mx;
            d[n - 1] = r - 1.0 / (d[n] + r);
        }
        let (sin, cos) = x.sin_cos();
        // ψ₋₁ = cos x, ψ₀ = sin x; χ₋₁ = −sin x, χ₀ = cos x; ξ = ψ − iχ.
        let (mut psi0, mut psi1) = (cos, sin);
        let (mut chi0, mut chi1) = (-sin, cos);
        let (mut a, mut b) = (Vec::with_capacity(nstop), Vec::with_capacity(nstop));
        for (n, &dn) in d.iter().enumerate().take(nstop + 1).skip(1) {
            let nf = n as f64;
            let mut psi = (2.0 * nf - 1.0) / x * psi1 - psi0;
            if n == 1 && x < 0.1 {
                // ψ₁ = sin x / x − cos x cancels for small x: its series instead
                let x2 = x * x;
                psi = x2 / 3.0 * (1.0 - x2 / 10.0 * (1.0 - x2 / 28.0 * (1.0 - x2 / 54.0)));
            }
            let chi = (2.0 * nf - 1.0) / x * chi1 - chi0;
            let xi = C64::new(psi, -chi);
            let xi1 = C64::new(psi1, -chi1);
            let da = dn / m + nf / x;
            let db = dn * m + nf / x;
            a.push((da * psi - psi1) / (da * xi - xi1));
            b.push((db * psi - psi1) / (db * xi - xi1));
            (psi0, psi1) = (psi1, psi);
            (chi0, chi1) = (chi1, chi);
        }
        Ok(Sphere {
            x,
            absorbing: m.im > 0.0,
            a,
            b,
        })
    }

    /// Size parameter `π d / λ`.
    pub fn size_parameter(&self) -> f64 {
        self.x
    }

    /// `(aₙ, bₙ)` for `n ≥ 1`.
    pub fn coefficients(&self, n: usize) -> (C64, C64) {
        (self.a[n - 1], self.b[n - 1])
    }

    /// Number of terms of the series.
    pub fn terms(&self) -> usize {
        self.a.len()
    }

    /// `Q_ext`, `Q_sca`, `Q_abs`, `Q_back` and `g` (BH Eqs. 4.61, 4.62, 4.82, 4.74).
    pub fn efficiencies(&self) -> Efficiencies {
        let (mut ext, mut sca, mut g, mut back) = (0.0, 0.0, 0.0, C64::new(0.0, 0.0));
        let n_terms = self.a.len();
        for i in 0..n_terms {
            let n = (i + 1) as f64;
            let (a, b) = (self.a[i], self.b[i]);
            ext += (2.0 * n + 1.0) * (a + b).re;
            sca += (2.0 * n + 1.0) * (a.norm_sqr() + b.norm_sqr());
            let sign = if i % 2 == 0 { -1.0 } else { 1.0 };
            back += (2.0 * n + 1.0) * sign * (a - b);
            g += (2.0 * n + 1.0) / (n * (n + 1.0)) * (a * b.conj()).re;
            if i + 1 < n_terms {
                let (a1, b1) = (self.a[i + 1], self.b[i + 1]);
                g += n * (n + 2.0) / (n + 1.0) * (a * a1.conj() + b * b1.conj()).re;
            }
        }
        let x2 = self.x * self.x;
        let (ext, sca) = (2.0 * ext / x2, 2.0 * sca / x2);
        Efficiencies {
            ext,
            sca,
            // exactly 0 without absorption (the series' round-off would leave ~1e-16)
            abs: if self.absorbing {
                (ext - sca).max(0.0)
            } else {
                0.0
            },
            back: back.norm_sqr() / x2,
            g: if sca > 0.0 { 4.0 * g / (x2 * sca) } else { 0.0 },
        }
    }

    /// `S1(μ)` and `S2(μ)` at `μ = cos θ` (BH Eq. 4.74, angular functions by Eqs. 4.47).
    pub fn amplitudes(&self, mu: f64) -> (C64, C64) {
        let (mut s1, mut s2) = (C64::new(0.0, 0.0), C64::new(0.0, 0.0));
        let (mut pi0, mut pi1) = (0.0, 1.0);
        for i in 0..self.a.len() {
            let n = (i + 1) as f64;
            let tau = n * mu * pi1 - (n + 1.0) * pi0;
            let f = (2.0 * n + 1.0) / (n * (n + 1.0));
            s1 += f * (self.a[i] * pi1 + self.b[i] * tau);
            s2 += f * (self.a[i] * tau + self.b[i] * pi1);
            let pi = ((2.0 * n + 1.0) * mu * pi1 - (n + 1.0) * pi0) / n;
            (pi0, pi1) = (pi1, pi);
        }
        (s1, s2)
    }
}

/// Which scalar amplitude the speckle estimators get (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Polarisation {
    #[default]
    Unpolarised,
    Perpendicular,
    Parallel,
}

/// A suspension of spheres: diameter (mean of a log-normal number distribution when `spread > 0`),
/// the particle's complex index, the host's index and the wavelength in the host, all lengths in
/// the scene's unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Particles {
    pub diameter: f64,
    /// Standard deviation of the diameter (0: all spheres equal).
    pub spread: f64,
    pub n_particle: C64,
    pub n_medium: f64,
    /// Wavelength in the host medium (vacuum wavelength / `n_medium`).
    pub wavelength: f64,
}

/// Number of size nodes and their (normalised) weights for a log-normal distribution.
fn size_nodes(p: &Particles) -> Vec<(f64, f64)> {
    if p.spread == 0.0 {
        return vec![(p.diameter, 1.0)];
    }
    // ln d ~ N(μ, s²) with mean `diameter` and standard deviation `spread`
    let s2 = (1.0 + (p.spread / p.diameter).powi(2)).ln();
    let (s, mu) = (s2.sqrt(), p.diameter.ln() - 0.5 * s2);
    // trapezoid over ±5 s, size parameter steps of at most 0.25 (interference ripples average out)
    let x_mean = PI * p.diameter / p.wavelength;
    let count = ((10.0 * s * x_mean / 0.25).ceil() as usize + 1).clamp(41, 401);
    let nodes: Vec<(f64, f64)> = (0..count)
        .map(|i| {
            let t = -5.0 + 10.0 * i as f64 / (count - 1) as f64;
            ((mu + s * t).exp(), (-0.5 * t * t).exp())
        })
        .collect();
    let total: f64 = nodes.iter().map(|n| n.1).sum();
    nodes.into_iter().map(|(d, w)| (d, w / total)).collect()
}

/// The optics of a suspension: per-particle mean cross-sections and volume, `g`, and on a grid of
/// cosines the mean intensities `⟨|S1|²⟩`, `⟨|S2|²⟩` and the mean amplitudes `⟨S1⟩`, `⟨S2⟩`.
#[derive(Clone, Debug)]
pub struct Optics {
    pub particles: Particles,
    /// Mean size parameter `π d / λ` (of the mean diameter).
    pub size_parameter: f64,
    /// Number of series terms of the largest sphere.
    pub terms: usize,
    /// Efficiencies of the mean cross-sections over the mean geometric cross-section.
    pub efficiencies: Efficiencies,
    pub c_ext: f64,
    pub c_sca: f64,
    pub c_abs: f64,
    pub c_back: f64,
    pub g: f64,
    /// Mean particle volume `⟨π d³ / 6⟩`.
    pub mean_volume: f64,
    pub cos: Vec<f64>,
    pub i1: Vec<f64>,
    pub i2: Vec<f64>,
    pub s1: Vec<C64>,
    pub s2: Vec<C64>,
}

/// `n` cosines uniform in angle from 180° to 0° (so `cos` increases), dense where a large sphere's
/// forward peak is narrow.
pub fn angle_grid(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            if i == 0 {
                -1.0
            } else if i == n - 1 {
                1.0
            } else {
                (PI * (1.0 - i as f64 / (n - 1) as f64)).cos()
            }
        })
        .collect()
}

impl Particles {
    /// The relative index `m = n_particle / n_medium`.
    pub fn relative_index(&self) -> C64 {
        self.n_particle / self.n_medium
    }

    /// Check the numbers and the size parameter range of every sphere of the distribution.
    pub fn validate(&self) -> Result<(), MieError> {
        if !(self.spread.is_finite() && self.spread >= 0.0 && self.spread < 3.0 * self.diameter) {
            return Err(MieError::Spread(self.spread));
        }
        let m = self.relative_index();
        if !(m.re.is_finite() && m.im.is_finite() && m.re > 0.0 && m.im >= 0.0) {
            return Err(MieError::Index(m));
        }
        let nodes = size_nodes(self);
        for (d, _) in [nodes[0], nodes[nodes.len() - 1]] {
            let x = PI * d / self.wavelength;
            if !(x.is_finite() && (1e-6..=2e4).contains(&x)) {
                return Err(MieError::SizeParameter(x));
            }
        }
        Ok(())
    }

    /// A cosine grid fine enough for the phase function's oscillations and forward peak: 120
    /// nodes per unit size parameter (at least 1441, at most 60001), so that the piecewise-linear
    /// table integrates to 1 within 1e-4 of the series' `C_sca`.
    pub fn default_grid(&self) -> Vec<f64> {
        let x_max = PI * (self.diameter + 5.0 * self.spread) / self.wavelength;
        angle_grid(((120.0 * x_max).ceil() as usize).clamp(1441, 60001))
    }

    /// Cross-sections, `g` and amplitudes on `cos`, averaged over the size distribution.
    pub fn optics(&self, cos: &[f64]) -> Result<Optics, MieError> {
        self.validate()?;
        let m = self.relative_index();
        let k = 2.0 * PI / self.wavelength;
        let nodes = size_nodes(self);
        let spheres = nodes
            .par_iter()
            .map(|&(d, w)| {
                let sphere = Sphere::new(PI * d / self.wavelength, m)?;
                let q = sphere.efficiencies();
                let area = PI * d * d / 4.0;
                let amps: Vec<(C64, C64)> = cos.iter().map(|&mu| sphere.amplitudes(mu)).collect();
                Ok((d, w, sphere.terms(), q, area, amps))
            })
            .collect::<Result<Vec<_>, MieError>>()?;
        let n = cos.len();
        let mut o = Optics {
            particles: *self,
            size_parameter: PI * self.diameter / self.wavelength,
            terms: 0,
            efficiencies: Efficiencies {
                ext: 0.0,
                sca: 0.0,
                abs: 0.0,
                back: 0.0,
                g: 0.0,
            },
            c_ext: 0.0,
            c_sca: 0.0,
            c_abs: 0.0,
            c_back: 0.0,
            g: 0.0,
            mean_volume: 0.0,
            cos: cos.to_vec(),
            i1: vec![0.0; n],
            i2: vec![0.0; n],
            s1: vec![C64::new(0.0, 0.0); n],
            s2: vec![C64::new(0.0, 0.0); n],
        };
        let mut mean_area = 0.0;
        for (d, w, terms, q, area, amps) in spheres {
            o.terms = o.terms.max(terms);
            o.c_ext += w * q.ext * area;
            o.c_sca += w * q.sca * area;
            o.c_abs += w * q.abs * area;
            o.c_back += w * q.back * area;
            o.g += w * q.g * q.sca * area;
            o.mean_volume += w * PI * d * d * d / 6.0;
            mean_area += w * area;
            // amplitudes in units of the scattered field: f = i S / k
            for (j, (s1, s2)) in amps.into_iter().enumerate() {
                o.i1[j] += w * s1.norm_sqr() / (k * k);
                o.i2[j] += w * s2.norm_sqr() / (k * k);
                o.s1[j] += w * s1 / k;
                o.s2[j] += w * s2 / k;
            }
        }
        o.g /= o.c_sca;
        o.efficiencies = Efficiencies {
            ext: o.c_ext / mean_area,
            sca: o.c_sca / mean_area,
            abs: o.c_abs / mean_area,
            back: o.c_back / mean_area,
            g: o.g,
        };
        Ok(o)
    }
}

impl Optics {
    /// `ρ(μ)` on the grid for a polarisation, normalised so that `∫ρ dω = 1` over the true
    /// (`σ_sca`) integral: `ρ = dC_sca/dΩ / C_sca`.
    pub fn phase(&self, pol: Polarisation) -> Vec<f64> {
        let per = |j: usize| match pol {
            Polarisation::Unpolarised => 0.5 * (self.i1[j] + self.i2[j]),
            Polarisation::Perpendicular => self.i1[j],
            Polarisation::Parallel => self.i2[j],
        };
        let scale = match pol {
            Polarisation::Unpolarised => self.c_sca,
            // each linear polarisation's own total, ∫|S|² dΩ, by the trapezoid on the grid
            _ => {
                let v: Vec<f64> = (0..self.cos.len()).map(per).collect();
                2.0 * PI
                    * self
                        .cos
                        .windows(2)
                        .zip(v.windows(2))
                        .map(|(c, v)| 0.5 * (v[0] + v[1]) * (c[1] - c[0]))
                        .sum::<f64>()
            }
        };
        (0..self.cos.len()).map(|j| per(j) / scale).collect()
    }

    /// The scalar amplitude `s` with `|s|² = ρ` (unnormalised phase convention of the module docs).
    pub fn amplitude(&self, pol: Polarisation) -> Vec<C64> {
        let rho = self.phase(pol);
        let i = C64::new(0.0, 1.0);
        (0..self.cos.len())
            .map(|j| {
                let z = i * match pol {
                    Polarisation::Parallel => self.s2[j],
                    _ => self.s1[j],
                };
                let unit = if z.norm() > 0.0 {
                    z / z.norm()
                } else {
                    C64::new(1.0, 0.0)
                };
                rho[j].sqrt() * unit
            })
            .collect()
    }

    /// The amplitude as a phase-function table for the estimators.
    pub fn table(&self, pol: Polarisation) -> Result<super::Table, super::TableError> {
        super::Table::from_amplitude(Some(self.cos.clone()), self.amplitude(pol))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-300)
    }

    #[test]
    fn series_and_sphere_quadrature_agree() {
        // ∫ (|S1|² + |S2|²)/2 dΩ = π x² Q_sca and ∫ μ (…) dΩ = g π x² Q_sca
        for (x, m) in [(0.5, C64::new(1.33, 0.0)), (12.0, C64::new(1.5, 0.1))] {
            let s = Sphere::new(x, m).unwrap();
            let q = s.efficiencies();
            let cos = angle_grid(20001);
            let f: Vec<f64> = cos
                .iter()
                .map(|&mu| {
                    let (a, b) = s.amplitudes(mu);
                    0.5 * (a.norm_sqr() + b.norm_sqr())
                })
                .collect();
            let (mut i0, mut i1) = (0.0, 0.0);
            for j in 1..cos.len() {
                let h = cos[j] - cos[j - 1];
                i0 += 0.5 * h * (f[j] + f[j - 1]);
                i1 += 0.5 * h * (f[j] * cos[j] + f[j - 1] * cos[j - 1]);
            }
            let norm = PI * x * x * q.sca / (2.0 * PI);
            assert!(rel(i0, norm) < 1e-5, "x {x}: {i0} vs {norm}");
            assert!(rel(i1 / i0, q.g) < 1e-4, "x {x}: g {} vs {}", i1 / i0, q.g);
        }
    }
}
