//! Adjoint gradients of losses on final ray states (lecture 003, Eqs. 15, 19–22 in discrete form):
//! the exact discrete adjoint of the leapfrog map, integrated backwards while the ray itself is
//! reconstructed by reversing the (time-reversible) integrator, so memory does not grow with the
//! number of steps. A stored-path (tape) reverse pass is kept to cross-check it.
//!
//! For `F = n∇n` one step is `v½ = v + h/2 F(x)`, `x' = x + h v½`, `v' = v½ + h/2 F(x')`; its
//! adjoint uses `J_F = ∇n∇nᵀ + n ∇²n` (symmetric) and `∂F/∂θ = (∂n/∂θ)∇n + n ∇(∂n/∂θ)`.
//! [`Tracer::adjoint`] runs a fixed number of steps inside the field; [`Tracer::exit_adjoint`]
//! follows [`Tracer::trace`] to the exit, with refraction, reflections and boundary crossings
//! differentiated too. Gradients with respect to *every* coefficient of a grid profile are accumulated
//! sparsely: each field evaluation touches only its 8 (trilinear) or 64 (tricubic) taps, so the
//! cost per step does not depend on the grid size.

use super::field::{BoundedField, Bounds, IndexField};
use super::trace::{Ray, RayEnd, Segment, Tracer};
use glam::DVec3;

/// An analytic field parameter: parameter `which` of profile `profile` (see `Profile::dparam`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldParam {
    pub profile: usize,
    pub which: usize,
}

/// Gradients of a loss with respect to the initial state and field parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct RayGradient {
    pub final_ray: Ray,
    pub dx0: DVec3,
    pub dv0: DVec3,
    pub dparams: Vec<f64>,
}

/// Where the adjoint accumulates `∂L/∂c` for every coefficient of grid profile `profile`.
pub struct GridAdjoint<'a> {
    pub profile: usize,
    /// One entry per coefficient (added to, so many rays can share it).
    pub grad: &'a mut [f64],
}

/// What the adjoint pass accumulates: analytic parameters and, optionally, a whole grid.
struct Accumulators<'p, 'g> {
    params: &'p [FieldParam],
    dp: Vec<f64>,
    grid: Option<GridAdjoint<'g>>,
}

/// `grad[i] += (∂F/∂c_i)(x)·a` for every tap `i` of the grid at `x`, with
/// `∂F/∂c_i = w_i ∇n + n ∇w_i` (`F = n∇n`), given `(n, ∇n)` at `x`.
fn accumulate_grid(
    f: &BoundedField,
    x: DVec3,
    (n, gn): (f64, DVec3),
    a: DVec3,
    grid: &mut Option<GridAdjoint>,
) {
    let Some(GridAdjoint { profile, grad }) = grid else {
        return;
    };
    if !f.bounds.contains(x) {
        return;
    }
    let Some(super::field::Profile::Grid(g)) = f.profiles.get(*profile) else {
        return;
    };
    g.scatter(x, gn.dot(a), a * n, grad);
}

use super::trace::force_jacobian as jacobian;

/// `∂F/∂θ = (∂n/∂θ)∇n + n ∇(∂n/∂θ)` at `x`, given `(n, ∇n)` there.
fn dforce(f: &BoundedField, x: DVec3, n: f64, g: DVec3, p: &FieldParam) -> crate::Result<DVec3> {
    if !f.bounds.contains(x) {
        return Ok(DVec3::ZERO);
    }
    let prof = f
        .profiles
        .get(p.profile)
        .ok_or_else(|| format!("no profile {}", p.profile))?;
    let (dn, dgrad) = prof.dparam(x, p.which).ok_or_else(|| {
        format!(
            "parameter {} of the {} profile is not differentiable",
            p.which,
            prof.kind()
        )
    })?;
    Ok(g * dn + dgrad * n)
}

/// `(n, ∇n, J_F)` at `x` from one field evaluation.
fn local(f: &BoundedField, x: DVec3) -> (f64, DVec3, glam::DMat3) {
    let (n, g, h) = f.eval(x);
    (n, g, super::trace::jacobian_of(n, g, h))
}

impl Tracer<'_> {
    /// Adjoint of one step from state `r` (before) with adjoints `(lx, lv)` of the state after.
    fn adjoint_step(
        &self,
        r: Ray,
        h: f64,
        lx: DVec3,
        lv: DVec3,
        acc: &mut Accumulators,
    ) -> crate::Result<(DVec3, DVec3)> {
        let Accumulators { params, dp, grid } = acc;
        let f = self.field;
        let (n0, g0, j0) = local(f, r.x);
        let v_half = r.v + g0 * (n0 * 0.5 * h);
        let x1 = r.x + v_half * h;
        let (n1, g1, j1) = local(f, x1);
        // v' = v½ + h/2 F(x'): x' collects J_F(x') λ_v' h/2 on top of λ_x'
        let lx1 = lx + j1 * lv * (0.5 * h);
        for (g, p) in dp.iter_mut().zip(params.iter()) {
            *g += 0.5 * h * dforce(f, x1, n1, g1, p)?.dot(lv);
        }
        accumulate_grid(f, x1, (n1, g1), lv * (0.5 * h), grid);
        // x' = x + h v½: v½ collects λ_v' (direct) and h λ_x'
        let l_half = lv + lx1 * h;
        // v½ = v + h/2 F(x)
        let lx0 = lx1 + j0 * l_half * (0.5 * h);
        for (g, p) in dp.iter_mut().zip(params.iter()) {
            *g += 0.5 * h * dforce(f, r.x, n0, g0, p)?.dot(l_half);
        }
        accumulate_grid(f, r.x, (n0, g0), l_half * (0.5 * h), grid);
        let lv0 = l_half;
        Ok((lx0, lv0))
    }

    /// `steps` leapfrog steps of size `h` from `r0`, then the adjoint pass in constant memory:
    /// `loss_grad(final)` gives `(∂L/∂x, ∂L/∂v)` at the final state.
    pub fn adjoint(
        &self,
        r0: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> crate::Result<RayGradient> {
        self.adjoint_with_grid(r0, steps, h, params, None, loss_grad)
    }

    /// [`Self::adjoint`], also accumulating `∂L/∂c` for every coefficient of a grid profile.
    pub fn adjoint_with_grid(
        &self,
        r0: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        grid: Option<GridAdjoint>,
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> crate::Result<RayGradient> {
        let final_ray = self.steps(r0, steps, h);
        self.adjoint_from_end(final_ray, steps, h, params, grid, loss_grad)
    }

    /// [`Self::adjoint_with_grid`] from the state `steps` steps of `h` led to (what
    /// [`Self::steps`] returned): the reverse pass alone.
    pub fn adjoint_from_end(
        &self,
        final_ray: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        grid: Option<GridAdjoint>,
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> crate::Result<RayGradient> {
        let (lx, lv) = loss_grad(final_ray);
        let mut acc = Accumulators {
            params,
            dp: vec![0.0; params.len()],
            grid,
        };
        let (_, lx, lv) = self.reverse_steps(final_ray, steps, h, lx, lv, &mut acc)?;
        Ok(RayGradient {
            final_ray,
            dx0: lx,
            dv0: lv,
            dparams: acc.dp,
        })
    }

    /// [`Self::adjoint_from_end`] for `K` rays at once (their reverse steps interleaved), each
    /// with the adjoints `(∂L/∂x, ∂L/∂v)` of its final state: the same per-ray bits as one by
    /// one, the parameter and grid sums accumulated in another order (a round-off difference).
    pub fn adjoint_from_ends<const K: usize>(
        &self,
        ends: [(Ray, DVec3, DVec3); K],
        steps: usize,
        h: f64,
        params: &[FieldParam],
        grid: Option<GridAdjoint>,
    ) -> crate::Result<[(DVec3, DVec3); K]> {
        let mut acc = Accumulators {
            params,
            dp: vec![0.0; params.len()],
            grid,
        };
        let first = self.reverse_steps_interleaved(ends, steps, h, &mut acc)?;
        Ok(first.map(|(_, lx, lv)| (lx, lv)))
    }

    /// The adjoint of `steps` full leapfrog steps of `h` that ended in `r`, given the adjoints
    /// `(lx, lv)` of the state after them, reconstructing the states by reversing the integrator;
    /// returns the first state and its adjoints. The same map as repeated [`Self::adjoint_step`]
    /// on the reconstructed states, arranged for one field evaluation and one accumulation a
    /// step: the evaluation at each reconstructed state serves its reconstruction and both
    /// adjoint steps that meet there (taking the next state's end point as reconstructed rather
    /// than re-stepped, a round-off difference), and the two parameter contributions at a state
    /// are accumulated together (they are linear in the adjoint).
    fn reverse_steps(
        &self,
        r: Ray,
        steps: usize,
        h: f64,
        lx: DVec3,
        lv: DVec3,
        acc: &mut Accumulators,
    ) -> crate::Result<(Ray, DVec3, DVec3)> {
        let [(r, lx, lv)] = self.reverse_steps_interleaved([(r, lx, lv)], steps, h, acc)?;
        Ok((r, lx, lv))
    }

    /// [`Self::reverse_steps`] for `K` rays at once, their steps interleaved so that the
    /// independent field evaluations overlap in the processor (one ray's reverse steps form a
    /// chain of dependent evaluations, as its forward steps do). Each ray's states and adjoints
    /// are the same bits as alone; the accumulations alternate between the rays step by step.
    fn reverse_steps_interleaved<const K: usize>(
        &self,
        start: [(Ray, DVec3, DVec3); K],
        steps: usize,
        h: f64,
        acc: &mut Accumulators,
    ) -> crate::Result<[(Ray, DVec3, DVec3); K]> {
        if steps == 0 {
            return Ok(start);
        }
        let f = self.field;
        let mut r = start.map(|s| s.0);
        let (mut lx, mut lv) = (start.map(|s| s.1), start.map(|s| s.2));
        let (mut n1, mut g1, mut j1) = ([0.0; K], [DVec3::ZERO; K], [glam::DMat3::ZERO; K]);
        for (k, (n, g, hess)) in f.eval_lanes(r.map(|r| r.x)).into_iter().enumerate() {
            (n1[k], g1[k], j1[k]) = (n, g, super::trace::jacobian_of(n, g, hess));
        }
        // the adjoint vector waiting to be accumulated at `r` (from the step after it)
        let mut pending = [DVec3::ZERO; K];
        let back = -h;
        for _ in 0..steps {
            // reverse the steps: exactly `leapfrog(r, -h)`, the force at r from the last
            // evaluation
            let v_half: [DVec3; K] = std::array::from_fn(|k| r[k].v + g1[k] * n1[k] * (0.5 * back));
            let x0: [DVec3; K] = std::array::from_fn(|k| r[k].x + v_half[k] * back);
            let at_x0 = f.eval_lanes(x0);
            let (x1, n_g1) = (r.map(|r| r.x), std::array::from_fn(|k| (n1[k], g1[k])));
            let mut force_adjoint = [DVec3::ZERO; K];
            for k in 0..K {
                let (n0, g0, hess) = at_x0[k];
                let prev = Ray {
                    x: x0[k],
                    v: v_half[k] + g0 * n0 * (0.5 * back),
                };
                let j0 = super::trace::jacobian_of(n0, g0, hess);
                // v' = v½ + h/2 F(x'): x' collects J_F(x') λ_v' h/2 on top of λ_x'
                let lx1 = lx[k] + j1[k] * lv[k] * (0.5 * h);
                force_adjoint[k] = pending[k] + lv[k] * (0.5 * h);
                // x' = x + h v½ and v½ = v + h/2 F(x)
                let l_half = lv[k] + lx1 * h;
                lx[k] = lx1 + j0 * l_half * (0.5 * h);
                lv[k] = l_half;
                pending[k] = l_half * (0.5 * h);
                (r[k], n1[k], g1[k], j1[k]) = (prev, n0, g0, j0);
            }
            self.accumulate_forces(x1, n_g1, force_adjoint, acc)?;
        }
        let n_g1 = std::array::from_fn(|k| (n1[k], g1[k]));
        self.accumulate_forces(r.map(|r| r.x), n_g1, pending, acc)?;
        Ok(std::array::from_fn(|k| (r[k], lx[k], lv[k])))
    }

    /// `λ·∂F/∂θ` at `x` into the accumulators (analytic parameters and grid taps), given
    /// `(n, ∇n)` there.
    fn accumulate_force(
        &self,
        x: DVec3,
        (n, g): (f64, DVec3),
        a: DVec3,
        acc: &mut Accumulators,
    ) -> crate::Result<()> {
        let Accumulators { params, dp, grid } = acc;
        for (d, p) in dp.iter_mut().zip(params.iter()) {
            *d += dforce(self.field, x, n, g, p)?.dot(a);
        }
        accumulate_grid(self.field, x, (n, g), a, grid);
        Ok(())
    }

    /// [`Self::accumulate_force`] at `K` points in turn, a single grid's taps weighted side by
    /// side in vector lanes ([`super::grid::GridField::scatter_lanes`]).
    fn accumulate_forces<const K: usize>(
        &self,
        x: [DVec3; K],
        n_g: [(f64, DVec3); K],
        a: [DVec3; K],
        acc: &mut Accumulators,
    ) -> crate::Result<()> {
        let f = self.field;
        if K > 1
            && let Some(GridAdjoint { profile, grad }) = &mut acc.grid
            && acc.params.is_empty()
            && let Some(super::field::Profile::Grid(g)) = f.profiles.get(*profile)
            && x.iter().all(|&x| f.bounds.contains(x))
        {
            let dot = std::array::from_fn(|k| n_g[k].1.dot(a[k]));
            g.scatter_lanes(x, dot, std::array::from_fn(|k| a[k] * n_g[k].0), grad);
            return Ok(());
        }
        for k in 0..K {
            self.accumulate_force(x[k], n_g[k], a[k], acc)?;
        }
        Ok(())
    }

    /// The same gradient from a stored path (tape), for cross-checking the reversal.
    pub fn adjoint_tape(
        &self,
        r0: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> crate::Result<RayGradient> {
        self.adjoint_tape_with_grid(r0, steps, h, params, None, loss_grad)
    }

    /// [`Self::adjoint_tape`] with a grid accumulator (cross-check of [`Self::adjoint_with_grid`]).
    pub fn adjoint_tape_with_grid(
        &self,
        r0: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        grid: Option<GridAdjoint>,
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> crate::Result<RayGradient> {
        let mut tape = Vec::with_capacity(steps + 1);
        let mut r = r0;
        tape.push(r);
        for _ in 0..steps {
            r = self.leapfrog(r, h);
            tape.push(r);
        }
        let final_ray = r;
        let (mut lx, mut lv) = loss_grad(final_ray);
        let mut acc = Accumulators {
            params,
            dp: vec![0.0; params.len()],
            grid,
        };
        for k in (0..steps).rev() {
            (lx, lv) = self.adjoint_step(tape[k], h, lx, lv, &mut acc)?;
        }
        Ok(RayGradient {
            final_ray,
            dx0: lx,
            dv0: lv,
            dparams: acc.dp,
        })
    }
}

/// Gradients of a loss on where a ray leaves the field (see [`Tracer::exit_adjoint`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ExitGradient {
    pub end: RayEnd,
    /// `∂L/∂origin` and `∂L/∂direction` of the ray as given to [`Tracer::trace`]; directions are
    /// unit vectors, so the direction gradient is tangential (`⟂ direction`).
    pub d_origin: DVec3,
    pub d_direction: DVec3,
    pub dparams: Vec<f64>,
}

/// `λ·∂n/∂θ` into the accumulators (analytic parameters and grid taps) for a loss that depends on
/// the value `n(x)` with adjoint `ln`; returns `ln ∇n(x)`, the part for `x`.
fn accumulate_dn(f: &BoundedField, x: DVec3, ln: f64, acc: &mut Accumulators) -> DVec3 {
    if !f.bounds.contains(x) {
        return DVec3::ZERO;
    }
    for (g, p) in acc.dp.iter_mut().zip(acc.params.iter()) {
        if let Some((dn, _)) = f.profiles.get(p.profile).and_then(|q| q.dparam(x, p.which)) {
            *g += ln * dn;
        }
    }
    if let Some(GridAdjoint { profile, grad }) = &mut acc.grid
        && let Some(super::field::Profile::Grid(g)) = f.profiles.get(*profile)
    {
        g.scatter(x, ln, DVec3::ZERO, grad);
    }
    f.grad(x) * ln
}

/// Adjoint of the surface normal `ν(x)` of `bounds` (curved surfaces only): `λν ↦ λx`.
fn normal_adjoint(bounds: &Bounds, x: DVec3, l_normal: DVec3) -> DVec3 {
    let project = |nu: DVec3, l: DVec3, r: f64| (l - nu * l.dot(nu)) / r;
    match (bounds, bounds.normal(x)) {
        (Bounds::Sphere { .. }, Some(nu)) => project(nu, l_normal, x.length()),
        (Bounds::Cylinder { .. }, Some(nu)) if nu.z == 0.0 => {
            let l = DVec3::new(l_normal.x, l_normal.y, 0.0);
            project(nu, l, (x.x * x.x + x.y * x.y).sqrt())
        }
        // ν = ∇d/|∇d|: ∂ν/∂x = (I − ννᵀ) ∇²d / |∇d|, and ∇²d is symmetric
        (Bounds::Sdf(g), Some(nu)) => {
            let (_, grad, hessian) = g.eval(x);
            hessian * project(nu, l_normal, grad.length())
        }
        _ => DVec3::ZERO,
    }
}

/// Adjoint of [`refract`] (refracted branch) at unit `d`, unit `normal`, ratio `eta`: `λt ↦ (λd,
/// λnormal, λη)`, from `t = η d + (η c − k) n`, `c = −n·d`, `k = sqrt(1 − η²(1 − c²))`.
fn refract_adjoint(d: DVec3, normal: DVec3, eta: f64, lt: DVec3) -> (DVec3, DVec3, f64) {
    let sign = if normal.dot(d) > 0.0 { -1.0 } else { 1.0 };
    let n = normal * sign;
    let c = -n.dot(d);
    let k = (1.0 - eta * eta * (1.0 - c * c)).max(1e-300).sqrt();
    let a = lt.dot(n);
    let lc = a * (eta - eta * eta * c / k);
    let ld = lt * eta - n * lc;
    let ln = lt * (eta * c - k) - d * lc;
    let leta = lt.dot(d) + a * (c + eta * (1.0 - c * c) / k);
    (ld, ln * sign, leta)
}

/// Adjoint of `d = v/|v|`.
fn unit_adjoint(v: DVec3, ld: DVec3) -> DVec3 {
    let d = v.normalize();
    (ld - d * ld.dot(d)) / v.length()
}

impl Tracer<'_> {
    /// Gradient of a loss on the exit of [`Tracer::trace`] — `loss_grad(end)` gives `∂L/∂x` and
    /// `∂L/∂direction` at the exit — with respect to the ray's origin and direction, analytic
    /// parameters and (optionally) every coefficient of a grid profile. Everything the tracer does
    /// is differentiated: refraction on entry and exit (Snell), total internal reflections, the
    /// implicit dependence of each boundary-crossing step on the parameters (`c(x(τ)) = 0` ⇒
    /// `λx += s ν`, `s = −λ·∂(x, v)/∂τ / (ν·∂x/∂τ)`), and the leapfrog steps, reversed in constant
    /// memory as in [`Tracer::adjoint`]. Memory grows only with the number of reflections.
    pub fn exit_adjoint(
        &self,
        origin: DVec3,
        dir: DVec3,
        params: &[FieldParam],
        grid: Option<GridAdjoint>,
        loss_grad: impl FnOnce(&RayEnd) -> (DVec3, DVec3),
    ) -> crate::Result<ExitGradient> {
        let f = self.field;
        let mut segments: Vec<Segment> = Vec::new();
        let end = self.walk(origin, dir, |_| {}, |s| segments.push(s));
        let (lx_end, lt_end) = loss_grad(&end);
        let mut acc = Accumulators {
            params,
            dp: vec![0.0; params.len()],
            grid,
        };
        if !end.entered {
            if end.x == origin && end.direction == dir {
                // missed the field: a straight line
                return Ok(ExitGradient {
                    end,
                    d_origin: lx_end,
                    d_direction: lt_end - dir * lt_end.dot(dir),
                    dparams: acc.dp,
                });
            }
            return Err("the ray is reflected off the field's surface on entry".into());
        }
        if !end.exited {
            return Err(format!(
                "the ray did not leave the field within max_steps = {}",
                self.max_steps
            )
            .into());
        }
        let (mut lx, mut lv) = (DVec3::ZERO, DVec3::ZERO);
        for (i, seg) in segments.iter().enumerate().rev() {
            let e = self.leapfrog(seg.last, seg.tau);
            let n_in = f.n(e.x);
            let d = e.v.normalize();
            let nu = f.bounds.normal(e.x).unwrap_or(DVec3::Z);
            // adjoint of what follows the boundary state e: exit refraction or a reflection
            let (mut ex, ev) = if i + 1 == segments.len() {
                let (ld, lnormal, leta) = refract_adjoint(d, -nu, n_in / f.n_out, lt_end);
                let ex = lx_end + normal_adjoint(&f.bounds, e.x, -lnormal);
                let ex = ex + accumulate_dn(f, e.x, leta / f.n_out, &mut acc);
                (ex, unit_adjoint(e.v, ld))
            } else {
                // next start: x = e.x, v = R n_in, R = d − 2(ν·d)ν
                let refl = d - nu * (2.0 * nu.dot(d));
                let lr = lv * n_in;
                let ld = lr - nu * (2.0 * nu.dot(lr));
                let lnu = -(d * lr.dot(nu) + lr * nu.dot(d)) * 2.0;
                let ex = lx + normal_adjoint(&f.bounds, e.x, lnu);
                let ex = ex + accumulate_dn(f, e.x, lv.dot(refl), &mut acc);
                (ex, unit_adjoint(e.v, ld))
            };
            // the crossing step's length τ depends on everything upstream through c(e.x) = 0
            let f0 = self.force(seg.last.x);
            let xdot = seg.last.v + f0 * seg.tau;
            let vdot = (f0 + self.force(e.x)) * 0.5 + jacobian(f, e.x) * xdot * (0.5 * seg.tau);
            let s = -(ex.dot(xdot) + ev.dot(vdot)) / nu.dot(xdot);
            ex += nu * s;
            (lx, lv) = self.adjoint_step(seg.last, seg.tau, ex, ev, &mut acc)?;
            (_, lx, lv) = self.reverse_steps(seg.last, seg.steps, self.step, lx, lv, &mut acc)?;
        }
        // the first state inside: v = d_in n(x_in)
        let start = segments[0].start;
        let n_in = f.n(start.x);
        let d_in = start.v / n_in;
        let (d_origin, d_direction) = if f.bounds.contains(origin) {
            let lo = lx + accumulate_dn(f, origin, lv.dot(d_in), &mut acc);
            (lo, lv * n_in)
        } else {
            // x_in = o + t_in w on the surface (t0 from c(o + t0 w) = 0), d_in = refract(w, ν, η)
            let (t0, _) = f
                .bounds
                .interval(origin, dir)
                .ok_or("the ray's entry could not be found again")?;
            let surface = origin + dir * t0;
            let nu = f.bounds.normal(surface).unwrap_or(DVec3::Z);
            let (ld, lnormal, leta) = refract_adjoint(dir, nu, f.n_out / n_in, lv * n_in);
            let ln = lv.dot(d_in) - leta * f.n_out / (n_in * n_in);
            let lx_in = lx
                + accumulate_dn(f, start.x, ln, &mut acc)
                + normal_adjoint(&f.bounds, surface, lnormal);
            let (a, nw) = (lx_in.dot(dir), nu.dot(dir));
            let lo = lx_in - nu * (a / nw);
            let lw = ld + lx_in * super::trace::entry_parameter(t0) - nu * (a * t0 / nw);
            (lo, lw)
        };
        Ok(ExitGradient {
            end,
            d_origin,
            d_direction: d_direction - dir * d_direction.dot(dir),
            dparams: acc.dp,
        })
    }
}
