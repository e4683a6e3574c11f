//! The scattering medium: geometry, bulk coefficients and the scattering law.

pub mod geometry;
pub mod lobes;
pub mod mie;
pub mod params;
pub mod phase;

pub use geometry::Geometry;
pub use params::{FitParam, Param};
pub use phase::{Located, PhaseFunction, Scattering, Table, TableError};

/// A homogeneous scattering medium (paper 001, Eqs. 7–8).
#[derive(Clone, Debug, PartialEq)]
pub struct Medium {
    pub geometry: Geometry,
    /// Scattering coefficient `σ_s` (1/length).
    pub sigma_s: f64,
    /// Absorption coefficient `σ_a` (1/length).
    pub sigma_a: f64,
    pub scattering: Scattering,
}

impl Medium {
    /// Extinction `σ_t = σ_s + σ_a`.
    #[inline]
    pub fn sigma_t(&self) -> f64 {
        self.sigma_s + self.sigma_a
    }

    /// Single-scattering albedo `σ_s / σ_t`.
    pub fn albedo(&self) -> f64 {
        self.sigma_s / self.sigma_t()
    }

    /// Mean cosine `g` of the scattering law (the mixture's weighted mean).
    pub fn mean_cosine(&self) -> f64 {
        self.scattering
            .components()
            .iter()
            .map(|(w, p)| w * p.mean_cosine())
            .sum()
    }

    /// Field (amplitude) attenuation over a length `d` inside: `τ = exp(-σ_t d / 2)` (Eq. 19).
    #[inline]
    pub fn amplitude_attenuation(&self, d: f64) -> f64 {
        (-0.5 * self.sigma_t() * d).exp()
    }
}
