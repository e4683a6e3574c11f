//! Light in media whose refractive index varies continuously (issue #5, paper 002 Sec. 3): index
//! fields, a time-reversible symplectic ray tracer and its constant-memory adjoint.

pub mod adjoint;
pub mod bessel;
pub mod design;
pub mod field;
pub mod fit;
pub mod grid;
pub mod ops;
pub mod trace;

pub use adjoint::{ExitGradient, FieldParam, GridAdjoint, RayGradient};
pub use field::{BoundedField, Bounds, IndexField, Profile};
pub use ops::TraceOp;
pub use trace::{Ray, RayEnd, Tracer};
