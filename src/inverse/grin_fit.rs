//! Fitting a few analytic field parameters (ultrasonic `n_max`, `k_r`; fibre profile coefficients;
//! lens radii) so that beams focus where requested: L-BFGS (argmin) on the exact gradient of the
//! traced exits ([`Tracer::exit_adjoint`]: refraction, reflections and boundary crossings included).
//!
//! Loss: the mean over rays of the squared distance from each beam's focus to the ray's exit line
//! `x_exit + t d_exit` — a focus may lie on the exit face or beyond it.

use super::grin_design::Beam;
use super::lbfgs;
use crate::eikonal::FieldParam;
use crate::eikonal::{BoundedField, Tracer};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::Mutex;

/// A parameter fit: `params` of `field` (named for reports) start at their values in `field`.
#[derive(Clone, Debug)]
pub struct ParamFit {
    pub field: BoundedField,
    pub params: Vec<FieldParam>,
    pub names: Vec<String>,
    pub beams: Vec<Beam>,
    pub step: f64,
    pub max_steps: usize,
    pub iterations: usize,
}

/// One evaluation of the loss during the fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FitStep {
    pub evaluation: usize,
    pub params: Vec<f64>,
    pub mean_miss2: f64,
}

/// What a fit found.
#[derive(Clone, Debug)]
pub struct ParamFitResult {
    pub initial: Vec<f64>,
    pub fitted: Vec<f64>,
    pub field: BoundedField,
    pub log: Vec<FitStep>,
    pub rms_miss_initial: f64,
    pub rms_miss_final: f64,
    pub convergence: super::Convergence,
}

/// Squared distance of `focus` from the line `x + t d` (unit `d`) and its gradients in `x`, `d`.
fn line_miss(focus: DVec3, x: DVec3, d: DVec3) -> (f64, DVec3, DVec3) {
    let q = focus - x;
    let p = q - d * q.dot(d);
    (p.length_squared(), -p * 2.0, -p * (2.0 * q.dot(d)))
}

impl ParamFit {
    /// The field with the fitted parameters set to `theta`.
    pub fn field_with(&self, theta: &[f64]) -> crate::Result<BoundedField> {
        let mut f = self.field.clone();
        for ((p, v), name) in self.params.iter().zip(theta).zip(&self.names) {
            if !v.is_finite() {
                return Err(format!("{name} = {v}").into());
            }
            let slot = f
                .profiles
                .get_mut(p.profile)
                .and_then(|q| q.param_mut(p.which))
                .ok_or_else(|| format!("no parameter {name}"))?;
            *slot = *v;
        }
        Ok(f)
    }

    /// The parameters' values in the starting field.
    pub fn initial(&self) -> crate::Result<Vec<f64>> {
        let mut f = self.field.clone();
        self.params
            .iter()
            .zip(&self.names)
            .map(|(p, name)| {
                f.profiles
                    .get_mut(p.profile)
                    .and_then(|q| q.param_mut(p.which))
                    .map(|v| *v)
                    .ok_or_else(|| crate::Error::input(format!("no parameter {name}")))
            })
            .collect()
    }

    /// Mean squared miss distance over all rays and its gradient in the parameters (rays in
    /// parallel, summed in ray order: deterministic).
    pub fn loss_and_gradient(&self, theta: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
        self.loss_and_gradient_until(theta, &crate::mc::StopFlag::default())
    }

    /// [`Self::loss_and_gradient`], stopped with [`crate::Error::Interrupted`] at the next ray
    /// once `stop` is set.
    fn loss_and_gradient_until(
        &self,
        theta: &[f64],
        stop: &crate::mc::StopFlag,
    ) -> crate::Result<(f64, Vec<f64>)> {
        let field = self.field_with(theta)?;
        let tracer = Tracer {
            field: &field,
            step: self.step,
            max_steps: self.max_steps,
        };
        let rays: Vec<(DVec3, DVec3, DVec3)> = self
            .beams
            .iter()
            .flat_map(|b| b.rays.iter().map(|&(o, d)| (o, d, b.focus)))
            .collect();
        let parts: Vec<crate::Result<(f64, Vec<f64>)>> = rays
            .par_iter()
            .enumerate()
            .map(|(i, &(o, d, focus))| {
                stop.check()?;
                let mut miss = 0.0;
                let g = tracer
                    .exit_adjoint(o, d, &self.params, None, |e| {
                        let (m, dx, dd) = line_miss(focus, e.x, e.direction);
                        miss = m;
                        (dx, dd)
                    })
                    .map_err(|e| crate::Error::input(format!("ray {i} from {o}: {e}")))?;
                if !g.end.entered {
                    return Err(crate::Error::input(format!(
                        "ray {i} from {o} along {d} never enters the field: check the beam's center and direction"
                    )));
                }
                Ok((miss, g.dparams))
            })
            .collect();
        let (mut loss, mut grad) = (0.0, vec![0.0; theta.len()]);
        for p in parts {
            let (m, g) = p?;
            loss += m;
            grad.iter_mut().zip(&g).for_each(|(a, b)| *a += b);
        }
        let n = rays.len().max(1) as f64;
        Ok((loss / n, grad.iter().map(|g| g / n).collect()))
    }

    /// [`Self::loss_and_gradient`] through `journal`.
    fn recorded(
        &self,
        theta: &[f64],
        stop: &crate::mc::StopFlag,
        journal: &super::journal::Journal,
    ) -> crate::Result<(f64, Vec<f64>)> {
        super::journal::recall(journal, theta, || self.loss_and_gradient_until(theta, stop))
    }

    /// Run L-BFGS in the scaled variables `u_i = θ_i / s_i` (`s_i` the starting magnitude), so
    /// parameters of very different size (`n_max ~ 1e-4`, `k_r ~ 4`) are balanced.
    /// `stop` ends the fit within one ray's trace with [`crate::Error::Interrupted`].
    /// `journal` records the evaluations (and replays the run it was saved from).
    pub fn run(
        &self,
        progress: &(dyn Fn(&FitStep) + Sync),
        stop: &crate::mc::StopFlag,
        journal: &super::journal::Journal,
    ) -> crate::Result<ParamFitResult> {
        let initial = self.initial()?;
        let scale: Vec<f64> = initial
            .iter()
            .map(|v| if *v != 0.0 { v.abs() } else { 1.0 })
            .collect();
        let (l0, g0) = self.recorded(&initial, stop, journal)?;
        let gnorm = g0
            .iter()
            .zip(&scale)
            .map(|(g, s)| (g * s).powi(2))
            .sum::<f64>()
            .sqrt();
        let log = Mutex::new(Vec::new());
        let objective = Scaled {
            fit: self,
            scale: scale.clone(),
            loss_scale: if gnorm > 0.0 { 1.0 / gnorm } else { 1.0 },
            stop,
            journal,
        };
        let observe = |e: &lbfgs::Evaluation| {
            if let Ok(mut log) = log.lock() {
                let step = FitStep {
                    evaluation: e.index,
                    params: e.x.iter().zip(&scale).map(|(u, s)| u * s).collect(),
                    mean_miss2: e.loss / objective.loss_scale,
                };
                progress(&step);
                log.push(step);
            }
        };
        let settings = lbfgs::Settings {
            max_iters: self.iterations,
            grad_tol: 1e-12,
            cost_tol: 1e-14,
            bounds: None,
        };
        let u0: Vec<f64> = initial.iter().zip(&scale).map(|(v, s)| v / s).collect();
        let out = lbfgs::minimise(&objective, &u0, &settings, &observe).map_err(|e| match e {
            crate::Error::Interrupted => e,
            e => format!("fit: {e}").into(),
        })?;
        let best = out.x.clone();
        let reason = super::FitStop::from(&out.stop);
        let convergence = super::Convergence {
            converged: reason.converged(),
            stop: reason,
            grad_norm: out.grad_norm / objective.loss_scale,
            evaluations: out.evaluations,
            iterations: out.iterations,
        };
        let fitted: Vec<f64> = best.iter().zip(&scale).map(|(u, s)| u * s).collect();
        let (l1, _) = self.recorded(&fitted, stop, journal)?;
        Ok(ParamFitResult {
            field: self.field_with(&fitted)?,
            initial,
            fitted,
            log: log.into_inner().unwrap_or_default(),
            rms_miss_initial: l0.sqrt(),
            rms_miss_final: l1.sqrt(),
            convergence,
        })
    }
}

/// The loss in the scaled variables `u_i = θ_i / s_i`, scaled so the first gradient has unit norm.
struct Scaled<'a> {
    fit: &'a ParamFit,
    scale: Vec<f64>,
    loss_scale: f64,
    stop: &'a crate::mc::StopFlag,
    journal: &'a super::journal::Journal,
}

impl lbfgs::Objective for Scaled<'_> {
    fn eval(&self, u: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
        let theta: Vec<f64> = u.iter().zip(&self.scale).map(|(u, s)| u * s).collect();
        let (l, g) = self.fit.recorded(&theta, self.stop, self.journal)?;
        let gu = g
            .iter()
            .zip(&self.scale)
            .map(|(g, s)| g * s * self.loss_scale)
            .collect();
        Ok((l * self.loss_scale, gu))
    }
}
