//! Designing a refractive render's index field (an ultrasound array's drive, frequency and phases,
//! a profile's coefficients) so that it delivers the most light to a target, or the most relative
//! to another target (contrast): Adam over the parameters, each kept within its physical range,
//! with gradients from the render operation ([`crate::diff::RenderOp`]: forward sensitivities of
//! the photons, fresh photons at every step).
//!
//! Each parameter moves as `θ = lo + (hi − lo) σ(u)` (σ the logistic function), so a step never
//! leaves the range; Adam moves `u`. The objective is `ln F_target − ln F_reference`
//! (`F_reference` = 1 without a reference), whose gradient is `∂F/F`. The design returned is the
//! mean of `u` over the last third of the iterations (stochastic steps scatter about the
//! optimum); the run converged when its objective stopped improving beyond its noise.

use super::Convergence;
use super::adam::{Iterate, minimise};
use super::journal::{Journal, Numbers};
use crate::diff::RenderOp;
use crate::diff::bridge::{apply, tensor};
use crate::mc::StopFlag;
use crate::rrte::RenderScene;
use burn::tensor::activation::sigmoid;

/// A design problem on a render.
#[derive(Clone, Debug)]
pub struct RenderDesign {
    /// The scene, its `derivatives` the parameters designed.
    pub scene: RenderScene,
    /// The parameters' names, ranges and starting values.
    pub names: Vec<String>,
    pub ranges: Vec<(f64, f64)>,
    pub start: Vec<f64>,
    /// The sensor (a target) whose output is maximised, and the one it is taken relative to.
    pub maximize: usize,
    pub relative_to: Option<usize>,
    pub iterations: usize,
    /// Photons per iteration, per chunk, and the seed of the first iteration.
    pub photons: u64,
    pub chunk: u64,
    pub seed: u64,
    /// Adam's step in the unconstrained variables.
    pub learning_rate: f64,
    /// Photons of each checking render at a fresh seed (start and design).
    pub verify_photons: u64,
}

/// One iteration: the objective at the parameters before the step.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignIterate {
    pub iteration: usize,
    /// `ln F_target − ln F_reference` and its gradient's norm (in the unconstrained variables).
    pub objective: f64,
    pub grad_norm: f64,
    pub theta: Vec<f64>,
}

impl Numbers for DesignIterate {
    fn to_numbers(&self) -> Vec<f64> {
        let mut v = vec![self.objective];
        v.extend(&self.theta);
        v
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        let (objective, theta) = v.split_first()?;
        Some(DesignIterate {
            iteration: 0,
            objective: *objective,
            grad_norm: 0.0,
            theta: theta.to_vec(),
        })
    }
}

/// A finished design.
#[derive(Clone, Debug)]
pub struct RenderDesigned {
    pub log: Vec<DesignIterate>,
    /// The design: the mean of the last third of the iterates.
    pub designed: Vec<f64>,
    pub convergence: Convergence,
}

impl RenderDesign {
    /// `θ` from the unconstrained variables.
    fn theta(&self, u: &[f64]) -> Vec<f64> {
        u.iter()
            .zip(&self.ranges)
            .map(|(u, (lo, hi))| lo + (hi - lo) / (1.0 + (-u).exp()))
            .collect()
    }

    /// The unconstrained variables of `θ` (inside its ranges).
    fn unconstrained(&self, theta: &[f64]) -> Vec<f64> {
        theta
            .iter()
            .zip(&self.ranges)
            .map(|(t, (lo, hi))| {
                let s = (t - lo) / (hi - lo);
                (s / (1.0 - s)).ln()
            })
            .collect()
    }

    /// Run the design: `progress` sees every iteration, `stop` ends it, `journal` records it (and
    /// replays the run it was saved from).
    pub fn run(
        &self,
        progress: &dyn Fn(&DesignIterate),
        stop: &StopFlag,
        journal: &Journal,
    ) -> crate::Result<RenderDesigned> {
        let n = self.names.len();
        let dev = crate::diff::bridge::device();
        let lo = tensor(&self.ranges.iter().map(|r| r.0).collect::<Vec<_>>(), &dev);
        let width = tensor(
            &self.ranges.iter().map(|r| r.1 - r.0).collect::<Vec<_>>(),
            &dev,
        );
        let u0 = self.unconstrained(&self.start);
        let average_from = self.iterations - self.iterations / 3;
        let mut log = Vec::new();
        let mut loss = |iteration: usize, u: burn::tensor::Tensor<1>| {
            // each iteration renders its own photons, from a seed that follows the iteration (so a
            // resumed run draws what the uninterrupted one did)
            let seed = self.seed.wrapping_add(iteration as u64 * 0x9E37_79B9);
            let mut op =
                RenderOp::from_scene(self.scene.clone(), (self.photons, self.chunk, seed))?;
            op.stop = stop.clone();
            let theta = lo.clone() + width.clone() * sigmoid(u.clone());
            let theta_values = crate::diff::bridge::values(&theta);
            let y = apply(&op, theta)?;
            let mut objective = y.clone().narrow(0, self.maximize, 1).log();
            if let Some(r) = self.relative_to {
                objective = objective - y.narrow(0, r, 1).log();
            }
            let value = crate::diff::bridge::values(&objective)[0];
            if !value.is_finite() {
                return Err(crate::Error::Numerical(format!(
                    "render design: the objective at iteration {iteration} is {value} (no light reached the target: more photons per iteration, or a narrower range)"
                )));
            }
            let observed = DesignIterate {
                iteration,
                objective: value,
                grad_norm: 0.0,
                theta: theta_values,
            };
            Ok((-objective.sum(), observed))
        };
        let mut observe = |it: Iterate<DesignIterate>| {
            let mut d = it.observed;
            d.iteration = it.iteration;
            d.grad_norm = it.grad_norm;
            progress(&d);
            log.push(d);
            Ok(())
        };
        let m = minimise(
            &u0,
            self.iterations,
            &|_| self.learning_rate,
            average_from,
            journal,
            &mut loss,
            &mut observe,
        )?;
        let designed = self.theta(if m.average.len() == n {
            &m.average
        } else {
            &m.last
        });
        let objectives: Vec<f64> = log.iter().map(|d| -d.objective).collect();
        let grad_norm = log.last().map_or(f64::NAN, |d| d.grad_norm);
        let convergence = super::adam::convergence(&objectives, grad_norm, log.len());
        Ok(RenderDesigned {
            log,
            designed,
            convergence,
        })
    }
}
