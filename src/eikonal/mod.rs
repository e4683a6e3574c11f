//! Light in media whose refractive index varies continuously (paper 002 Sec. 3): index
//! fields, a time-reversible symplectic ray tracer and its constant-memory adjoint. Forward and adjoint only:
//! the burn operation lives in `diff::trace_op`, the fits and designs in `inverse::grin_*`.

pub mod acoustic;
pub mod adjoint;
pub mod bessel;
pub mod field;
pub mod grid;
pub mod mesh;
pub mod sdf;
pub mod trace;

pub use adjoint::{ExitGradient, FieldParam, GridAdjoint, RayGradient};
pub use field::{
    BoundedField, Bounds, IndexField, MAX_PARTS, Part, Profile, part_at, turning_angle,
};
pub use trace::{Ray, RayEnd, Tracer};
