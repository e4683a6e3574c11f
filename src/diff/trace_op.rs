//! Ray tracing as a differentiable operation for the burn bridge ([`crate::diff::bridge`]): the
//! coefficients of a grid index field in, the final ray states out, the constant-memory adjoint
//! (accumulated over every coefficient) as the backward pass. A user writes the design loss and
//! regularisers in burn and optimises the field with burn's Adam.

use crate::diff::bridge::{Differentiable, Pullback};
use crate::eikonal::{BoundedField, FieldParam, GridAdjoint, Profile, Ray, RayEnd, Tracer};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::Arc;

/// `c ↦ (x_final, v_final)` per ray (6 outputs a ray) for the coefficients `c` of grid profile
/// `profile` of `field`, each ray run `steps` leapfrog steps of size `step` (the σ-form of
/// [`Tracer`]: `|v| = n`). With `to_exit`, each ray is instead traced from origin `x` along unit
/// direction `v` until it leaves the bounds (at most `steps` steps; refraction and reflections
/// included) and the outputs are its exit position and exit direction, differentiated by
/// [`Tracer::exit_adjoint`].
pub struct TraceOp {
    pub field: BoundedField,
    pub profile: usize,
    pub rays: Vec<Ray>,
    pub steps: usize,
    pub step: f64,
    pub to_exit: bool,
    /// Stops the forward pass (an error) and the pullback (the rays left out) once set.
    pub stop: crate::mc::StopFlag,
}

/// Ray groups of the backward pass (memory: one coefficient vector per group).
const GROUPS: usize = 16;

/// Rays stepped together by the fixed-step forward: one ray's steps are a chain of dependent field
/// evaluations, several chains overlap in the processor.
const INTERLEAVED: usize = 4;

/// Rays whose reverse steps the backward pass interleaves (their field evaluations side by side
/// in vector lanes for trilinear grids, their scatters one after the other).
const REVERSED_TOGETHER: usize = 8;

struct TracePullback {
    field: BoundedField,
    profile: usize,
    rays: Vec<Ray>,
    steps: usize,
    step: f64,
    to_exit: bool,
    coefficients: usize,
    stop: crate::mc::StopFlag,
    /// The forward's final states (fixed-step mode): the reverse pass starts from them instead of
    /// tracing every ray again.
    ends: Vec<Ray>,
}

impl TraceOp {
    /// The field with grid profile `profile` holding coefficients `c`.
    pub fn field_with(&self, c: &[f64]) -> crate::Result<BoundedField> {
        let mut field = self.field.clone();
        let Some(Profile::Grid(g)) = field.profiles.get_mut(self.profile) else {
            return Err(format!("profile {} is not a grid", self.profile).into());
        };
        if c.len() != g.coef.len() {
            return Err(format!(
                "{} grid coefficients given, the grid has {}",
                c.len(),
                g.coef.len()
            )
            .into());
        }
        if let Some(i) = c.iter().position(|x| !x.is_finite()) {
            return Err(format!("grid coefficient {i} is {}", c[i]).into());
        }
        g.coef.copy_from_slice(c);
        Ok(field)
    }
}

impl Differentiable for TraceOp {
    fn forward(&self, c: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
        let field = self.field_with(c)?;
        let tracer = Tracer {
            field: &field,
            step: self.step,
            max_steps: self.steps,
        };
        let ends: Vec<Ray> = if self.to_exit {
            let ends: Vec<_> = self
                .rays
                .par_iter()
                .map(|r| self.stop.check().map(|()| tracer.trace(r.x, r.v)))
                .collect::<crate::Result<_>>()?;
            if let Some(i) = ends.iter().position(|e| !e.entered) {
                return Err(format!(
                    "ray {i} from {} never enters the field: check the beam's center and direction",
                    self.rays[i].x
                )
                .into());
            }
            if let Some(i) = ends.iter().position(|e| !e.exited) {
                return Err(format!(
                    "ray {i} did not leave the field within {} steps",
                    self.steps
                )
                .into());
            }
            ends.iter()
                .map(|e| Ray {
                    x: e.x,
                    v: e.direction,
                })
                .collect()
        } else {
            // INTERLEAVED rays at a time (the same bits as one by one)
            let batches: Vec<Vec<Ray>> = self
                .rays
                .par_chunks(INTERLEAVED)
                .map(|b| {
                    self.stop.check()?;
                    Ok(match <[Ray; INTERLEAVED]>::try_from(b) {
                        Ok(batch) => tracer
                            .steps_interleaved(batch, self.steps, self.step)
                            .to_vec(),
                        Err(_) => b
                            .iter()
                            .map(|r| tracer.steps(*r, self.steps, self.step))
                            .collect(),
                    })
                })
                .collect::<crate::Result<_>>()?;
            batches.concat()
        };
        if let Some(i) = ends
            .iter()
            .position(|r| !(r.x.is_finite() && r.v.is_finite()))
        {
            return Err(format!(
                "ray {i} left the finite numbers (n ≤ 0 or a diverging field on its path)"
            )
            .into());
        }
        let y = ends
            .iter()
            .flat_map(|r| r.x.to_array().into_iter().chain(r.v.to_array()))
            .collect();
        let pullback = TracePullback {
            field,
            profile: self.profile,
            rays: self.rays.clone(),
            steps: self.steps,
            step: self.step,
            to_exit: self.to_exit,
            coefficients: c.len(),
            stop: self.stop.clone(),
            ends: if self.to_exit { Vec::new() } else { ends },
        };
        Ok((y, Arc::new(pullback)))
    }
}

impl TracePullback {
    /// The accumulator of the grid profile's coefficient gradient.
    fn grid<'a>(&self, grad: &'a mut [f64]) -> Option<GridAdjoint<'a>> {
        Some(GridAdjoint {
            profile: self.profile,
            grad,
        })
    }
}

impl Pullback for TracePullback {
    fn pullback(&self, dy: &[f64]) -> Vec<f64> {
        let tracer = Tracer {
            field: &self.field,
            step: self.step,
            max_steps: self.steps,
        };
        let n = self.coefficients;
        // a fixed number of ray groups, each summed in ray order and the groups in group order:
        // the gradient is bitwise the same for any thread count
        let groups = self.rays.len().clamp(1, GROUPS);
        let per = self.rays.len().div_ceil(groups);
        let parts: Vec<Vec<f64>> = (0..groups)
            .into_par_iter()
            .map(|g| {
                let mut acc = vec![0.0; n];
                let rays = g * per..((g + 1) * per).min(self.rays.len());
                let seed = |i: usize| {
                    let d = &dy[6 * i..6 * i + 6];
                    (DVec3::new(d[0], d[1], d[2]), DVec3::new(d[3], d[4], d[5]))
                };
                let end = |i: usize| {
                    let (lx, lv) = seed(i);
                    (self.ends[i], lx, lv)
                };
                // fixed-step rays REVERSED_TOGETHER at a time, their reverse steps interleaved
                let ids: Vec<usize> = rays.collect();
                let together = if self.to_exit { 1 } else { REVERSED_TOGETHER };
                let mut ok = true;
                for batch in ids.chunks(together) {
                    if self.stop.is_set() {
                        // the caller reports the stop; this gradient is not used
                        break;
                    }
                    let (steps, h) = (self.steps, self.step);
                    ok &= if self.to_exit {
                        let (i, r) = (batch[0], self.rays[batch[0]]);
                        let grid = self.grid(&mut acc);
                        tracer
                            .exit_adjoint(r.x, r.v, &[], grid, |_| seed(i))
                            .is_ok()
                    } else if let Ok(b) = <[usize; REVERSED_TOGETHER]>::try_from(batch) {
                        let grid = self.grid(&mut acc);
                        tracer
                            .adjoint_from_ends(b.map(end), steps, h, &[], grid)
                            .is_ok()
                    } else {
                        batch.iter().all(|&i| {
                            let grid = self.grid(&mut acc);
                            tracer
                                .adjoint_from_ends([end(i)], steps, h, &[], grid)
                                .is_ok()
                        })
                    };
                }
                if !ok {
                    acc.iter_mut().for_each(|x| *x = f64::NAN);
                }
                acc
            })
            .collect();
        // each coefficient summed over the groups in group order (in parallel over coefficients)
        let mut total = vec![0.0; n];
        total
            .par_chunks_mut(1 << 14)
            .enumerate()
            .for_each(|(c, chunk)| {
                let start = c << 14;
                for p in &parts {
                    let part = &p[start..start + chunk.len()];
                    chunk.iter_mut().zip(part).for_each(|(t, x)| *t += x);
                }
            });
        total
    }
}

/// The exits of a bundle of rays traced through a field (each from its origin along its unit
/// direction until it leaves the bounds), with the vector–Jacobian product of those exits with
/// respect to analytic field parameters, every coefficient of one grid profile, and each ray's
/// origin and direction ([`Tracer::exit_adjoint`]: refraction, reflections and boundary crossings
/// included). The library's and Python's `trace_vjp`.
pub struct ExitVjp {
    field: BoundedField,
    params: Vec<FieldParam>,
    grid: Option<usize>,
    rays: Vec<(DVec3, DVec3)>,
    step: f64,
    max_steps: usize,
    /// Where and along which unit direction each ray left the field.
    pub ends: Vec<RayEnd>,
}

/// `∂L/∂·` of [`ExitVjp::pullback`].
#[derive(Clone, Debug, PartialEq)]
pub struct ExitGradients {
    /// One per analytic parameter.
    pub params: Vec<f64>,
    /// One per coefficient of the grid profile (when asked for).
    pub grid: Option<Vec<f64>>,
    /// Per ray; the direction gradient is tangential (directions are unit vectors).
    pub origin: Vec<DVec3>,
    pub direction: Vec<DVec3>,
}

impl ExitVjp {
    /// Trace `rays` through `field` (step `step`, at most `max_steps` steps a ray); every ray must
    /// enter and leave the field. `grid` names the grid profile whose coefficients get gradients.
    pub fn new(
        field: BoundedField,
        params: Vec<FieldParam>,
        grid: Option<usize>,
        rays: Vec<(DVec3, DVec3)>,
        step: f64,
        max_steps: usize,
        watch: &crate::mc::Watch,
    ) -> crate::Result<Self> {
        if let Some(p) = grid
            && !matches!(field.profiles.get(p), Some(Profile::Grid(_)))
        {
            return Err(format!("profile {p} is not a grid").into());
        }
        let tracer = Tracer {
            field: &field,
            step,
            max_steps,
        };
        watch
            .total
            .store(rays.len() as u64, std::sync::atomic::Ordering::Relaxed);
        let ends: Vec<RayEnd> = rays
            .par_iter()
            .map(|&(o, d)| {
                watch.check()?;
                let end = tracer.trace(o, d);
                watch.tick();
                Ok(end)
            })
            .collect::<crate::Result<_>>()?;
        for (i, (e, (o, d))) in ends.iter().zip(&rays).enumerate() {
            if !e.entered {
                return Err(format!("ray {i} from {o} along {d} never enters the field").into());
            }
            if !e.exited {
                return Err(format!(
                    "ray {i} from {o} did not leave the field within {max_steps} steps of {step}"
                )
                .into());
            }
            if !(e.x.is_finite() && e.direction.is_finite()) {
                return Err(format!(
                    "ray {i} left the finite numbers (n ≤ 0 or a diverging field on its path)"
                )
                .into());
            }
        }
        Ok(ExitVjp {
            field,
            params,
            grid,
            rays,
            step,
            max_steps,
            ends,
        })
    }

    /// The field the rays were traced through.
    pub fn field(&self) -> &BoundedField {
        &self.field
    }

    /// `∂L/∂·` from `∂L/∂(exit position)` and `∂L/∂(exit direction)` per ray. Rays run in a fixed
    /// number of groups, each summed in ray order and the groups in group order: bitwise the same
    /// for any thread count. `watch` counts the rays done and stops the pass at its next ray.
    pub fn pullback(
        &self,
        d_position: &[DVec3],
        d_direction: &[DVec3],
        watch: &crate::mc::Watch,
    ) -> crate::Result<ExitGradients> {
        let n = self.rays.len();
        if d_position.len() != n || d_direction.len() != n {
            return Err(format!(
                "adjoints for {} and {} rays, but {n} rays were traced",
                d_position.len(),
                d_direction.len()
            )
            .into());
        }
        let tracer = Tracer {
            field: &self.field,
            step: self.step,
            max_steps: self.max_steps,
        };
        let coefficients = match self.grid.and_then(|p| self.field.profiles.get(p)) {
            Some(Profile::Grid(g)) => g.coef.len(),
            _ => 0,
        };
        watch
            .total
            .store(n as u64, std::sync::atomic::Ordering::Relaxed);
        let groups = n.clamp(1, GROUPS);
        let per = n.div_ceil(groups);
        type Part = (Vec<f64>, Vec<f64>, Vec<(DVec3, DVec3)>);
        let parts: Vec<crate::Result<Part>> = (0..groups)
            .into_par_iter()
            .map(|g| {
                let mut dp = vec![0.0; self.params.len()];
                let mut grid = vec![0.0; coefficients];
                let mut rays = Vec::with_capacity(per);
                for i in g * per..((g + 1) * per).min(n) {
                    watch.check()?;
                    let (o, d) = self.rays[i];
                    let adjoint = self.grid.map(|profile| GridAdjoint {
                        profile,
                        grad: &mut grid,
                    });
                    let r = tracer
                        .exit_adjoint(o, d, &self.params, adjoint, |_| {
                            (d_position[i], d_direction[i])
                        })
                        .map_err(|e| crate::Error::input(format!("ray {i} from {o}: {e}")))?;
                    dp.iter_mut().zip(&r.dparams).for_each(|(a, b)| *a += b);
                    rays.push((r.d_origin, r.d_direction));
                    watch.tick();
                }
                Ok((dp, grid, rays))
            })
            .collect();
        let mut out = ExitGradients {
            params: vec![0.0; self.params.len()],
            grid: self.grid.map(|_| vec![0.0; coefficients]),
            origin: Vec::with_capacity(n),
            direction: Vec::with_capacity(n),
        };
        for part in parts {
            let (dp, grid, rays) = part?;
            out.params.iter_mut().zip(&dp).for_each(|(a, b)| *a += b);
            if let Some(total) = out.grid.as_mut() {
                total.iter_mut().zip(&grid).for_each(|(a, b)| *a += b);
            }
            for (o, d) in rays {
                out.origin.push(o);
                out.direction.push(d);
            }
        }
        Ok(out)
    }
}
