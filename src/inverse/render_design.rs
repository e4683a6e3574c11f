//! Designing a refractive render's index field (an ultrasound array's drive, frequency and phases,
//! a profile's coefficients) so that it delivers the most light to a target or into a spot, or the
//! most relative to another one (contrast), each parameter kept within its physical range, with gradients
//! from the render operation ([`crate::diff::RenderOp`]: forward sensitivities of the photons).
//! The objective is `ln F_target − ln F_reference` (`F_reference` = 1 without a reference), whose
//! gradient is `∂F/F`. Two methods:
//!
//! - **Adam** (many parameters, or noisy objectives): fresh photons at every step. Each parameter
//!   moves as `θ = lo + (hi − lo) σ(u)` (σ the logistic function), so a step never leaves the
//!   range; Adam moves `u`. The design returned is the mean of `u` over the last third of the
//!   iterations (stochastic steps scatter about the optimum); the run converged when its
//!   objective stopped improving beyond its noise.
//! - **L-BFGS** (a few parameters): the photons are held ([`RenderOp::hold`]), so the objective is
//!   a deterministic, smooth sample-average approximation with its exact gradient, minimised by
//!   the projected L-BFGS driver in `s = (θ − lo)/(hi − lo) ∈ [0, 1]` (a parameter may end on
//!   its bound). The design is optimal for the photons held; the checking renders at a fresh
//!   seed say how much of its gain is real.

use super::Convergence;
use super::adam::{Iterate, minimise};
use super::journal::{Journal, Numbers, recall};
use super::lbfgs::{self, Bounds};
use crate::diff::RenderOp;
use crate::diff::bridge::{apply, tensor};
use crate::mc::StopFlag;
use crate::rrte::RenderScene;
use burn::tensor::activation::sigmoid;
use serde::{Deserialize, Serialize};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// How a render design moves its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DesignMethod {
    /// Adam on fresh photons every iteration.
    Adam,
    /// L-BFGS on held photons (a sample-average approximation).
    Lbfgs,
}

/// A design problem on a render.
#[derive(Clone, Debug)]
pub struct RenderDesign {
    /// The scene, its `derivatives` the parameters designed.
    pub scene: RenderScene,
    /// The parameters' names, ranges and starting values.
    pub names: Vec<String>,
    pub ranges: Vec<(f64, f64)>,
    pub start: Vec<f64>,
    /// The sensor (a target or spot) whose output is maximised, and the one it is taken relative
    /// to.
    pub maximize: usize,
    pub relative_to: Option<usize>,
    pub method: DesignMethod,
    /// Adam's iterations, or L-BFGS's.
    pub iterations: usize,
    /// Photons per iteration (per evaluation, held, for L-BFGS), per chunk, and the seed of the
    /// first iteration.
    pub photons: u64,
    pub chunk: u64,
    pub seed: u64,
    /// Adam's step in the unconstrained variables.
    pub learning_rate: f64,
    /// Photons of each checking render at a fresh seed (start and design).
    pub verify_photons: u64,
}

/// One iteration (Adam: the objective at the parameters before the step) or evaluation (L-BFGS).
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
    /// The design: Adam's mean of the last third of the iterates, or L-BFGS's best point.
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

    /// `θ` from the range-scaled variables `s = (θ − lo)/(hi − lo)`.
    fn in_range(&self, s: &[f64]) -> Vec<f64> {
        s.iter()
            .zip(&self.ranges)
            .map(|(s, (lo, hi))| lo + (hi - lo) * s)
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
        progress: &(dyn Fn(&DesignIterate) + Sync),
        stop: &StopFlag,
        journal: &Journal,
    ) -> crate::Result<RenderDesigned> {
        match self.method {
            DesignMethod::Adam => self.run_adam(progress, stop, journal),
            DesignMethod::Lbfgs => self.run_lbfgs(progress, stop, journal),
        }
    }

    /// L-BFGS on held photons in `s = (θ − lo)/(hi − lo)`, within [0, 1].
    fn run_lbfgs(
        &self,
        progress: &(dyn Fn(&DesignIterate) + Sync),
        stop: &StopFlag,
        journal: &Journal,
    ) -> crate::Result<RenderDesigned> {
        let n = self.names.len();
        let mut op =
            RenderOp::from_scene(self.scene.clone(), (self.photons, self.chunk, self.seed))?;
        op.stop = stop.clone();
        op.hold()?;
        let theta = |s: &[f64]| self.in_range(s);
        let s0: Vec<f64> = self
            .start
            .iter()
            .zip(&self.ranges)
            .map(|(t, (lo, hi))| (t - lo) / (hi - lo))
            .collect();
        let mut objective = Held {
            design: self,
            op: &op,
            journal,
            start: None,
            scale: 1.0,
        };
        let (noise, first) = objective.evaluate(&s0)?;
        // L-BFGS's first step is the gradient itself: scaled so that it moves a tenth of the
        // ranges at most (a jump across a whole range lands in whichever basin is there)
        let g0 = first.1.iter().map(|g| g * g).sum::<f64>().sqrt();
        objective.scale = if g0 > FIRST_STEP {
            FIRST_STEP / g0
        } else {
            1.0
        };
        objective.start = Some((s0.clone(), first));
        let scale = objective.scale;
        let log = Mutex::new(Vec::new());
        // evaluations of earlier runs (after a restart the driver counts from 0 again)
        let before = AtomicUsize::new(0);
        let observe = |e: &lbfgs::Evaluation| {
            let d = DesignIterate {
                iteration: before.load(Ordering::Relaxed) + e.index,
                objective: -e.loss / scale,
                grad_norm: e.grad_norm / scale,
                theta: theta(&e.x),
            };
            progress(&d);
            if let Ok(mut log) = log.lock() {
                log.push(d);
            }
        };
        // a line search that ends on a kink of the held objective restarts from the best point
        // with a fresh memory, while that still improves it
        let mut best: Option<lbfgs::Outcome> = None;
        let (mut from, mut left, mut restarts) = (s0, self.iterations, 0);
        let (mut evaluations, mut iterations) = (0, 0);
        loop {
            // converged once the gradient would change the objective by less than a hundredth
            // of its standard error across the whole ranges (the held sample's own optimum is
            // only known to about its standard error); an iteration that changes it little is
            // no sign of the end here, where some directions are far flatter than others
            let settings = lbfgs::Settings {
                max_iters: left,
                grad_tol: 0.01 * noise * scale,
                cost_tol: 1e-12 * scale,
                bounds: Some(Bounds {
                    lower: vec![0.0; n],
                    upper: vec![1.0; n],
                }),
            };
            let out =
                lbfgs::minimise(&objective, &from, &settings, &observe).map_err(|e| match e {
                    crate::Error::Interrupted => e,
                    e => format!("render design: {e}").into(),
                })?;
            before.fetch_add(out.evaluations, Ordering::Relaxed);
            evaluations += out.evaluations;
            iterations += out.iterations;
            left = left.saturating_sub(out.iterations.max(1));
            let improved = best.as_ref().is_none_or(|b| out.loss < b.loss);
            let kink = matches!(out.stop, lbfgs::Stop::LineSearch(_));
            if improved {
                best = Some(out);
            }
            if !(kink && improved && left > 0 && restarts < MAX_RESTARTS) {
                break;
            }
            restarts += 1;
            from = best.as_ref().map(|b| b.x.clone()).unwrap_or_default();
        }
        let out = best.ok_or_else(|| crate::Error::input("render design: no evaluation"))?;
        let stop = super::FitStop::from(&out.stop);
        Ok(RenderDesigned {
            log: log.into_inner().unwrap_or_default(),
            designed: theta(&out.x),
            convergence: Convergence {
                converged: stop.converged(),
                stop,
                grad_norm: out.grad_norm / scale,
                evaluations,
                iterations,
            },
        })
    }

    /// Adam on fresh photons every iteration, in the logistic coordinates.
    fn run_adam(
        &self,
        progress: &(dyn Fn(&DesignIterate) + Sync),
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

/// The design's objective on held photons, as L-BFGS minimises it: `−(ln F − ln F_ref)` at
/// `θ(s)` and its gradient in `s`, through the journal.
struct Held<'a> {
    design: &'a RenderDesign,
    op: &'a RenderOp,
    journal: &'a Journal,
    /// The starting point's value and gradient, evaluated before the driver starts.
    start: Option<(Vec<f64>, ValueAndGradient)>,
    /// The factor on the objective the driver sees.
    scale: f64,
}

/// An objective's value and gradient.
type ValueAndGradient = (f64, Vec<f64>);

/// The longest first step of L-BFGS, in the range-scaled coordinates.
const FIRST_STEP: f64 = 0.1;
/// Restarts of L-BFGS after line searches that end on kinks.
const MAX_RESTARTS: usize = 3;

impl Held<'_> {
    /// The standard error of the objective at `s`, its value and its gradient.
    fn evaluate(&self, s: &[f64]) -> crate::Result<(f64, ValueAndGradient)> {
        recall(self.journal, s, || {
            let d = self.design;
            let e = self.op.evaluate(&d.in_range(s))?;
            let (f, df) = (e.power[d.maximize], &e.jacobian[d.maximize]);
            let mut value = f.ln();
            let mut variance = (e.stderr[d.maximize] / f).powi(2);
            let mut grad: Vec<f64> = df.iter().map(|g| g / f).collect();
            if let Some(r) = d.relative_to {
                value -= e.power[r].ln();
                variance += (e.stderr[r] / e.power[r]).powi(2);
                for (g, dr) in grad.iter_mut().zip(&e.jacobian[r]) {
                    *g -= dr / e.power[r];
                }
            }
            if !(value.is_finite() && variance.is_finite()) {
                return Err(crate::Error::Numerical(format!(
                    "render design: the objective at θ = {:?} is {value} (no light reached the target: more photons, or a narrower range)",
                    d.in_range(s)
                )));
            }
            let scaled = grad
                .iter()
                .zip(&d.ranges)
                .map(|(g, (lo, hi))| -g * (hi - lo))
                .collect();
            Ok((variance.sqrt(), (-value, scaled)))
        })
    }
}

impl lbfgs::Objective for Held<'_> {
    fn eval(&self, s: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
        let (value, grad) = match &self.start {
            Some((at, first)) if at.as_slice() == s => first.clone(),
            _ => self.evaluate(s)?.1,
        };
        Ok((
            value * self.scale,
            grad.iter().map(|g| g * self.scale).collect(),
        ))
    }
}
