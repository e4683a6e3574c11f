//! lightpath: forward and inverse rendering of light in scattering and refractive media.
//!
//! See `README.md` for the command line and `../shared/DESIGN.md` for the architecture.

pub mod bench;
pub mod diff;
pub mod eikonal;
pub mod inverse;
pub mod io;
pub mod jobs;
pub mod math;
pub mod mc;
pub mod medium;
pub mod speckle;
