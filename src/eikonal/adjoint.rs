//! Adjoint gradients of losses on final ray states (lecture 003, Eqs. 15, 19–22 in discrete form):
//! the exact discrete adjoint of the leapfrog map, integrated backwards while the ray itself is
//! reconstructed by reversing the (time-reversible) integrator, so memory does not grow with the
//! number of steps. A stored-path (tape) reverse pass is kept to cross-check it.
//!
//! For `F = n∇n` one step is `v½ = v + h/2 F(x)`, `x' = x + h v½`, `v' = v½ + h/2 F(x')`; its
//! adjoint uses `J_F = ∇n∇nᵀ + n ∇²n` (symmetric) and `∂F/∂θ = (∂n/∂θ)∇n + n ∇(∂n/∂θ)`.
//! Rays run a fixed number of steps inside the field (the boundary-crossing derivative is not
//! included yet). Gradients with respect to *every* coefficient of a grid profile are accumulated
//! sparsely: each field evaluation touches only its 8 (trilinear) or 64 (tricubic) taps, so the
//! cost per step does not depend on the grid size.

use super::field::{BoundedField, IndexField};
use super::trace::{Ray, Tracer};
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
/// `∂F/∂c_i = w_i ∇n + n ∇w_i` (`F = n∇n`).
fn accumulate_grid(f: &BoundedField, x: DVec3, a: DVec3, grid: &mut Option<GridAdjoint>) {
    let Some(GridAdjoint { profile, grad }) = grid else {
        return;
    };
    if !f.bounds.contains(x) {
        return;
    }
    let Some(super::field::Profile::Grid(g)) = f.profiles.get(*profile) else {
        return;
    };
    let (n, gn, _) = f.eval(x);
    let ga = gn.dot(a);
    g.visit_dcoef(x, |i, w, dw| grad[i] += w * ga + n * dw.dot(a));
}

use super::trace::force_jacobian as jacobian;

fn dforce(f: &BoundedField, x: DVec3, p: &FieldParam) -> Result<DVec3, String> {
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
    Ok(f.grad(x) * dn + dgrad * f.n(x))
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
    ) -> Result<(DVec3, DVec3), String> {
        let Accumulators { params, dp, grid } = acc;
        let f = self.field;
        let v_half = r.v + f.grad(r.x) * (f.n(r.x) * 0.5 * h);
        let x1 = r.x + v_half * h;
        // v' = v½ + h/2 F(x'): x' collects J_F(x') λ_v' h/2 on top of λ_x'
        let lx1 = lx + jacobian(f, x1) * lv * (0.5 * h);
        for (g, p) in dp.iter_mut().zip(params.iter()) {
            *g += 0.5 * h * dforce(f, x1, p)?.dot(lv);
        }
        accumulate_grid(f, x1, lv * (0.5 * h), grid);
        // x' = x + h v½: v½ collects λ_v' (direct) and h λ_x'
        let l_half = lv + lx1 * h;
        // v½ = v + h/2 F(x)
        let lx0 = lx1 + jacobian(f, r.x) * l_half * (0.5 * h);
        for (g, p) in dp.iter_mut().zip(params.iter()) {
            *g += 0.5 * h * dforce(f, r.x, p)?.dot(l_half);
        }
        accumulate_grid(f, r.x, l_half * (0.5 * h), grid);
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
    ) -> Result<RayGradient, String> {
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
    ) -> Result<RayGradient, String> {
        let final_ray = self.steps(r0, steps, h);
        let (mut lx, mut lv) = loss_grad(final_ray);
        let mut acc = Accumulators {
            params,
            dp: vec![0.0; params.len()],
            grid,
        };
        let mut r = final_ray;
        for _ in 0..steps {
            let prev = self.leapfrog(r, -h); // reconstruct by reversing the integrator
            (lx, lv) = self.adjoint_step(prev, h, lx, lv, &mut acc)?;
            r = prev;
        }
        Ok(RayGradient {
            final_ray,
            dx0: lx,
            dv0: lv,
            dparams: acc.dp,
        })
    }

    /// The same gradient from a stored path (tape), for cross-checking the reversal.
    pub fn adjoint_tape(
        &self,
        r0: Ray,
        steps: usize,
        h: f64,
        params: &[FieldParam],
        loss_grad: impl FnOnce(Ray) -> (DVec3, DVec3),
    ) -> Result<RayGradient, String> {
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
    ) -> Result<RayGradient, String> {
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
