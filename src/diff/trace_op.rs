//! Ray tracing as a differentiable operation for the burn bridge ([`crate::diff::bridge`]): the
//! coefficients of a grid index field in, the final ray states out, the constant-memory adjoint
//! (accumulated over every coefficient) as the backward pass. A user writes the design loss and
//! regularisers in burn and optimises the field with burn's Adam.

use crate::diff::bridge::{Differentiable, Pullback};
use crate::eikonal::{BoundedField, GridAdjoint, Profile, Ray, Tracer};
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
}

/// Ray groups of the backward pass (memory: one coefficient vector per group).
const GROUPS: usize = 16;

struct TracePullback {
    field: BoundedField,
    profile: usize,
    rays: Vec<Ray>,
    steps: usize,
    step: f64,
    to_exit: bool,
    coefficients: usize,
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
                .map(|r| tracer.trace(r.x, r.v))
                .collect();
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
            self.rays
                .par_iter()
                .map(|r| tracer.steps(*r, self.steps, self.step))
                .collect()
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
        };
        Ok((y, Arc::new(pullback)))
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
                for i in g * per..((g + 1) * per).min(self.rays.len()) {
                    let d = &dy[6 * i..6 * i + 6];
                    let seed = (DVec3::new(d[0], d[1], d[2]), DVec3::new(d[3], d[4], d[5]));
                    let grid = Some(GridAdjoint {
                        profile: self.profile,
                        grad: &mut acc,
                    });
                    let r = self.rays[i];
                    let ok = if self.to_exit {
                        tracer.exit_adjoint(r.x, r.v, &[], grid, |_| seed).is_ok()
                    } else {
                        tracer
                            .adjoint_with_grid(r, self.steps, self.step, &[], grid, |_| seed)
                            .is_ok()
                    };
                    if !ok {
                        acc.iter_mut().for_each(|x| *x = f64::NAN);
                    }
                }
                acc
            })
            .collect();
        let mut total = vec![0.0; n];
        for p in &parts {
            total.iter_mut().zip(p).for_each(|(t, x)| *t += x);
        }
        total
    }
}
