//! lightpath: forward and inverse rendering of light in scattering and refractive media.
//!
//! The layers, from the bottom: `math` → `medium` → `mc` (the engine) → `speckle`, `eikonal` (the
//! estimators and ray integrators) → `rrte` (refractive rendering) → `diff` (gradients, the burn bridge) → `inverse` (fits and
//! designs) → `config` (the one loader), `io` (typed result files, images, plots) → `app` (one file
//! per command). `ARCHITECTURE.md` is the map.

pub mod app;
pub mod config;
pub mod diff;
pub mod eikonal;
pub mod error;
pub mod inverse;
pub mod io;
pub mod math;
pub mod mc;
pub mod medium;
pub mod rrte;
pub mod speckle;

pub use error::{Error, Result};
