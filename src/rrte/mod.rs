//! Refractive radiative transfer (paper 002): light that scatters *and* bends. A volume with an
//! index field `n(x)` (any [`crate::eikonal`] profile or grid, dispersive if asked) and scattering
//! (homogeneous or scaled by a density grid), bounded by a sphere, box, cylinder or signed-distance
//! shape (not necessarily convex) with a smooth dielectric surface (Fresnel reflection and refraction, total internal reflection); lights
//! outside or inside it; sensors outside it and fluence probes inside it.
//!
//! - [`scene`]: the volume, lights, sensors and time-of-flight bins;
//! - [`connect`]: point-to-point connections along curved rays (Sec. 4, Algs. 2–3);
//! - [`flight`]: free flights over geometric length along curved rays (Eq. 5), Fresnel;
//! - [`particle`]: particle (light) tracing as an engine estimator (results per emitted power),
//!   with next-event connections to fluence probes and cameras, and ultrasonic fields met at a
//!   random phase per photon;
//! - [`path`]: path tracing from pinhole cameras, connected to the light at every event;
//! - [`bidirectional`]: bidirectional path tracing, subpaths from the light and the cameras
//!   joined every way and weighted by multiple importance sampling;
//! - [`tangent`]: derivatives of particle tracing's outputs with respect to the index field's
//!   parameters, by forward sensitivities of every photon's path;
//! - `connection_slopes`: derivatives of what connections carry to fluence probes (the medium's
//!   parameters in closed form, the index field's through the boundary-value problem);
//! - [`spectrum`]: dispersive indices (Cauchy, Sellmeier, mixtures), wavelengths and colour.

mod beam_tube;
pub mod bidirectional;
pub mod connect;
mod connection_slopes;
pub mod flight;
pub mod particle;
pub mod path;
pub mod scene;
pub mod spectrum;
pub mod tangent;

pub use particle::{ImageLayout, MAX_REFLECTIONS, ParticleTracer, STRATEGY_EVENTS, Total};
pub use scene::{
    Bulk, Camera, Connections, Density, Derivative, FieldDerivative, Filter, Light,
    MAX_DERIVATIVES, MAX_TARGETS, MediumDerivative, Modulation, PartLengths, Pinhole, PixelWindow,
    Probe, Region, RenderScene, Sensor, SensorKind, Surface, Tracing, Transient, Volume,
};
pub use spectrum::{Dispersion, Material, Spectrum};
