//! Symplectic, time-reversible ray tracing (Störmer–Verlet / leapfrog) through index fields.
//!
//! We integrate Hamilton's equations in the σ-form `dx/dσ = v`, `dv/dσ = n∇n = ∇(n²)/2` with
//! `|v| = n`, so that arc length is `ds = n dσ` and the optical path length is `∫ n ds = ∫ n² dσ`
//! (paper 002, Eqs. 1–2 rescaled; for `n² = 2 − r²` the motion is the harmonic oscillator
//! `x(σ) = x0 cos σ + v0 sin σ`). Outside the field's bounds rays are straight; the exit point is
//! found by bisection on the last step, and where `n` jumps at the boundary rays refract (Snell) or
//! are totally reflected.

use super::field::{BoundedField, IndexField};
use glam::{DMat3, DVec3};

/// A ray state in the σ-form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub x: DVec3,
    pub v: DVec3,
}

/// Where a traced ray leaves the field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayEnd {
    /// Exit position (on the boundary) or the last position if the step budget ran out.
    pub x: DVec3,
    /// Unit propagation direction at the exit.
    pub direction: DVec3,
    /// Optical path length inside the field, `∫ n² dσ` (trapezoid rule per step).
    pub optical_path: f64,
    pub steps: usize,
    /// False if the ray never entered the field or the step budget ran out inside.
    pub exited: bool,
    pub entered: bool,
}

/// Leapfrog tracer with step `h` in σ.
pub struct Tracer<'f> {
    pub field: &'f BoundedField,
    pub step: f64,
    pub max_steps: usize,
}

impl Tracer<'_> {
    /// `n∇n` at `x` (zero outside the bounds).
    #[inline(always)]
    pub(crate) fn force(&self, x: DVec3) -> DVec3 {
        let (n, g) = self.field.value_grad(x);
        g * n
    }

    /// One Störmer–Verlet step of size `h` (negative `h` steps backwards exactly).
    #[inline]
    pub fn leapfrog(&self, r: Ray, h: f64) -> Ray {
        let v_half = r.v + self.force(r.x) * (0.5 * h);
        let x = r.x + v_half * h;
        Ray {
            x,
            v: v_half + self.force(x) * (0.5 * h),
        }
    }

    /// `n` leapfrog steps (used for reversibility checks and fixed-length propagation).
    pub fn steps(&self, r: Ray, n: usize, h: f64) -> Ray {
        let [r] = self.steps_interleaved([r], n, h);
        r
    }

    /// [`Self::steps`] for `K` rays at once, their steps interleaved so that the independent field
    /// evaluations overlap in the processor (one ray's steps form a chain of dependent
    /// evaluations), side by side in vector lanes for a trilinear grid
    /// ([`BoundedField::value_grad_lanes`]); each ray gets the same bits as alone.
    pub fn steps_interleaved<const K: usize>(&self, mut r: [Ray; K], n: usize, h: f64) -> [Ray; K] {
        // the force at the end of a step starts the next: one field evaluation per step,
        // bit-identical to repeated `leapfrog`
        let forces = |x: [DVec3; K]| self.field.value_grad_lanes(x).map(|(n, g)| g * n);
        let mut f = forces(r.map(|r| r.x));
        for _ in 0..n {
            let v_half: [DVec3; K] = std::array::from_fn(|k| r[k].v + f[k] * (0.5 * h));
            let x: [DVec3; K] = std::array::from_fn(|k| r[k].x + v_half[k] * h);
            f = forces(x);
            r = std::array::from_fn(|k| Ray {
                x: x[k],
                v: v_half[k] + f[k] * (0.5 * h),
            });
        }
        r
    }

    /// `n` leapfrog steps with the forward sensitivities `∂(x, v)/∂(x0, v0)` (paper 002, Alg. 2:
    /// the tangent map that point-to-point connections solve with), as blocks
    /// `[[∂x/∂x0, ∂x/∂v0], [∂v/∂x0, ∂v/∂v0]]`. The leapfrog map is symplectic, so the 6×6 matrix
    /// is too (to round-off).
    pub fn steps_with_sensitivities(&self, mut r: Ray, n: usize, h: f64) -> (Ray, [[DMat3; 2]; 2]) {
        let (mut xx, mut xv, mut vx, mut vv) =
            (DMat3::IDENTITY, DMat3::ZERO, DMat3::ZERO, DMat3::IDENTITY);
        for _ in 0..n {
            let a0 = force_jacobian(self.field, r.x) * (0.5 * h);
            let (hx, hv) = (vx + a0 * xx, vv + a0 * xv);
            let next = self.leapfrog(r, h);
            (xx, xv) = (xx + hx * h, xv + hv * h);
            let a1 = force_jacobian(self.field, next.x) * (0.5 * h);
            (vx, vv) = (hx + a1 * xx, hv + a1 * xv);
            r = next;
        }
        (r, [[xx, xv], [vx, vv]])
    }

    /// The fraction of a step `h` from `r` (inside) that stays inside the bounds when the full step
    /// leaves them, by bisection: the last state inside is within `1e-14 h` of the surface.
    pub(crate) fn boundary_step(&self, r: Ray, h: f64) -> f64 {
        let bounds = &self.field.bounds;
        let (mut lo, mut hi) = (0.0, h);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if bounds.contains(self.leapfrog(r, mid).x) {
                lo = mid
            } else {
                hi = mid
            }
            if hi - lo < 1e-14 * h {
                break;
            }
        }
        lo
    }

    /// Trace a ray from `origin` along unit `dir` (straight outside the bounds) until it leaves.
    pub fn trace(&self, origin: DVec3, dir: DVec3) -> RayEnd {
        self.trace_with(origin, dir, |_| {})
    }

    /// [`Tracer::trace`], reporting every position inside the field to `visit` (for drawing).
    ///
    /// Where `n` jumps at the bounds (`n_out` against the profile's value there) the ray refracts
    /// by Snell's law on entry and exit; total internal reflection at the exit sends it back in.
    pub fn trace_with(&self, origin: DVec3, dir: DVec3, visit: impl FnMut(DVec3)) -> RayEnd {
        self.walk(origin, dir, visit, |_| {})
    }

    /// The tracing loop behind [`Tracer::trace_with`], also reporting each [`Segment`] (entry or
    /// reflection to the boundary) to `record`: what the exit adjoint needs to retrace the ray.
    pub(crate) fn walk(
        &self,
        origin: DVec3,
        dir: DVec3,
        mut visit: impl FnMut(DVec3),
        mut record: impl FnMut(Segment),
    ) -> RayEnd {
        let bounds = &self.field.bounds;
        let n_out = self.field.n_out;
        let mut x = origin;
        let mut dir = dir;
        let outside = |x: DVec3, d: DVec3, entered: bool| RayEnd {
            x,
            direction: d,
            optical_path: 0.0,
            steps: 0,
            exited: true,
            entered,
        };
        if !bounds.contains(origin) {
            match bounds.interval(origin, dir) {
                Some((t0, t1)) if t1 > 0.0 && t0 >= 0.0 => {
                    let surface = origin + dir * t0;
                    x = origin + dir * entry_parameter(t0);
                    if let Some(normal) = bounds.normal(surface) {
                        match refract(dir, normal, n_out / self.field.n(x)) {
                            Ok(t) => dir = t,
                            // reflected off the surface: it never enters
                            Err(reflected) => return outside(surface, reflected, false),
                        }
                    }
                }
                _ => return outside(origin, dir, false),
            }
        }
        let mut r = Ray {
            x,
            v: dir * self.field.n(x),
        };
        let mut start = r;
        let mut segment_steps = 0;
        let mut opl = 0.0;
        let h = self.step;
        // the field at the end of a step (n and the force n∇n) starts the next: one evaluation
        // per step, the same numbers as `leapfrog`
        let (mut n_r, g) = self.field.value_grad(r.x);
        let mut force = g * n_r;
        for k in 0..self.max_steps {
            let v_half = r.v + force * (0.5 * h);
            let x = r.x + v_half * h;
            if !bounds.contains(x) {
                let lo = self.boundary_step(r, h);
                let end = self.leapfrog(r, lo);
                visit(end.x);
                record(Segment {
                    start,
                    last: r,
                    steps: segment_steps,
                    tau: lo,
                });
                opl += 0.5 * lo * (n_r.powi(2) + self.field.n(end.x).powi(2));
                let n_in = self.field.n(end.x);
                let d = end.v.normalize();
                match bounds
                    .normal(end.x)
                    .map(|nrm| refract(d, -nrm, n_in / n_out))
                {
                    Some(Err(reflected)) => {
                        // total internal reflection: continue inside from the surface
                        r = Ray {
                            x: end.x,
                            v: reflected * n_in,
                        };
                        let (n, g) = self.field.value_grad(r.x);
                        (n_r, force) = (n, g * n);
                        start = r;
                        segment_steps = 0;
                        continue;
                    }
                    refracted => {
                        return RayEnd {
                            x: end.x,
                            direction: refracted.map_or(d, |t| t.unwrap_or(d)),
                            optical_path: opl,
                            steps: k + 1,
                            exited: true,
                            entered: true,
                        };
                    }
                }
            }
            let (n_next, g) = self.field.value_grad_inside(x);
            let force_next = g * n_next;
            opl += 0.5 * h * (n_r.powi(2) + n_next.powi(2));
            r = Ray {
                x,
                v: v_half + force_next * (0.5 * h),
            };
            (n_r, force) = (n_next, force_next);
            segment_steps += 1;
            visit(r.x);
        }
        RayEnd {
            x: r.x,
            direction: r.v.normalize(),
            optical_path: opl,
            steps: self.max_steps,
            exited: false,
            entered: true,
        }
    }
}

/// The ray parameter of the first state inside the bounds after entering at `t0`.
pub(crate) fn entry_parameter(t0: f64) -> f64 {
    t0 + 1e-12 * (1.0 + t0.abs())
}

/// One stretch of a traced ray inside the field, from its entry or a reflection (`start`) through
/// `steps` full leapfrog steps (to `last`) and a final fractional step `tau` onto the boundary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Segment {
    pub start: Ray,
    pub last: Ray,
    pub steps: usize,
    pub tau: f64,
}

/// `∂F/∂x` of the force `F = n∇n`: `∇n ∇nᵀ + n ∇²n` (symmetric).
pub(crate) fn force_jacobian(f: &BoundedField, x: DVec3) -> DMat3 {
    let (n, g, h) = f.eval(x);
    jacobian_of(n, g, h)
}

/// `∇n ∇nᵀ + n ∇²n` from `(n, ∇n, ∇²n)` at one point.
#[inline]
pub(crate) fn jacobian_of(n: f64, g: DVec3, h: DMat3) -> DMat3 {
    DMat3::from_cols(g * g.x, g * g.y, g * g.z) + h * n
}

/// Snell's law for unit direction `d` meeting a surface with unit `normal` pointing back towards
/// the side `d` comes from, with `eta = n_from / n_to`: the refracted direction, or `Err` with the
/// mirror direction on total internal reflection.
pub fn refract(d: DVec3, normal: DVec3, eta: f64) -> Result<DVec3, DVec3> {
    let n = if normal.dot(d) > 0.0 { -normal } else { normal };
    let cos_i = -n.dot(d);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t > 1.0 {
        return Err(d + n * (2.0 * cos_i));
    }
    Ok((d * eta + n * (eta * cos_i - (1.0 - sin2_t).sqrt())).normalize())
}
