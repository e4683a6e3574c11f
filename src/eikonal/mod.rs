//! Light in media whose refractive index varies continuously (issue #5, paper 002 Sec. 3): index
//! fields and a time-reversible symplectic ray tracer.

pub mod field;
pub mod trace;

pub use field::{BoundedField, Bounds, IndexField, Profile};
pub use trace::{Ray, RayEnd, Tracer};
