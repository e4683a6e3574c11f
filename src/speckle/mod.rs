//! Speckle statistics: the mean, the covariance (Algorithm 1) and speckle fields (Algorithm 2) of
//! coherent light scattered by a random medium (paper 001).

pub mod aperture_quadrature;
pub mod correlation_map;
pub mod covariance;
pub mod endpoint;
pub mod field;
pub mod first_vertex;
pub mod mean;
pub mod memory;
pub mod paths;
pub mod single;
pub mod tilt_shift;
pub mod wave;

pub use covariance::Covariance;
pub use endpoint::{Endpoint, Light, View};
pub use field::FieldSampler;

use crate::medium::Medium;

/// A scene: wavelength, medium, lights and views. All lengths share one unit.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub wavelength: f64,
    /// Wavenumber `k = 2π / λ`.
    pub k: f64,
    pub medium: Medium,
    pub lights: Vec<Light>,
    pub views: Vec<View>,
    /// How subpaths start near focused lights (importance sampling, paper 000 Sec. 6).
    pub sampling: first_vertex::Sampling,
    /// How focused apertures are integrated: vMF closed forms, or quadrature (a reference).
    pub aperture: aperture_quadrature::ApertureModel,
}

impl Scene {
    pub fn new(wavelength: f64, medium: Medium, lights: Vec<Light>, views: Vec<View>) -> Self {
        Scene {
            wavelength,
            k: 2.0 * std::f64::consts::PI / wavelength,
            medium,
            lights,
            views,
            sampling: first_vertex::Sampling::default(),
            aperture: aperture_quadrature::ApertureModel::default(),
        }
    }
}
