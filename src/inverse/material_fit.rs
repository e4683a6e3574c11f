//! The speckle material fit: medium parameters (mfp, albedo, g, σ_s, σ_a) fitted to a target
//! (memory-effect curve, covariance, measured entries) by L-BFGS on a deterministic objective from
//! re-weighted proposal paths, inside an adaptive trust region, with a Gauss–Newton uncertainty.
//!
//! The objective at parameters θ re-weights a fixed set of subpaths drawn from a proposal medium θ₀
//! (common random numbers), so it is smooth in θ and its gradient is exact for it
//! ([`crate::diff`]). Re-weighting is accurate only near the proposal, so each stage minimises
//! inside a box of half-width [`TRUST`] (in the unconstrained variables) about the proposal, by
//! the projected L-BFGS driver, and the next stage re-centres the proposal on the best point the
//! stage *evaluated* (fresh paths are drawn there; where they cannot evaluate it, the box shrinks).
//! Once a re-centred point is within one standard deviation of the optimum (the Gauss–Newton step
//! left, see [`NEAR`]), a last stage holds that proposal and runs L-BFGS to its convergence test
//! inside the box: the fit has converged. Otherwise it stops at the stage limit and says so.

use super::journal::{Journal, Numbers, recall};
use super::lbfgs::{self, Bounds};
use super::{Convergence, FitParam, FitStop, LogEntry, Target, medium_with};
use crate::diff::{CovarianceGradient, Param, Reweighted, ReweightedCovariance};
use crate::math::C64;
use crate::mc::{Estimate, Projected, kept_covariance, merge, run};
use crate::speckle::Scene;
use std::sync::Mutex;

/// Half-width of a stage's trust region in the unconstrained variables: re-weighting stays
/// accurate only near the proposal (the weights multiply a phase-function ratio per interior vertex).
pub const TRUST: f64 = 0.25;
/// Smallest trust-region half-width.
const TRUST_MIN: f64 = 1e-4;
/// When the Gauss–Newton step left from a re-centred point is shorter than one reported standard
/// deviation (squared Mahalanobis length below this, correlations included), the proposal is close
/// enough to the optimum: re-centring further would only move it by Monte Carlo noise, so the last
/// stage holds the proposal and minimises to convergence.
pub const NEAR: f64 = 1.0;

/// Standard deviations, correlations, the damped loss and the Gauss–Newton decrement.
type Uncertainty = (Vec<f64>, Vec<Vec<f64>>, f64, f64);

impl Numbers for Uncertainty {
    fn to_numbers(&self) -> Vec<f64> {
        let mut v = vec![self.2, self.3];
        v.extend(&self.0);
        self.1.iter().for_each(|row| v.extend(row));
        v
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        // p standard deviations and p² correlations after the two numbers: ⌊√(p + p²)⌋ = p
        let p = (v.len().checked_sub(2)? as f64).sqrt() as usize;
        let (head, rest) = v.split_at_checked(2)?;
        if rest.len() != p + p * p {
            return None;
        }
        let (stddev, correlation) = rest.split_at(p);
        Some((
            stddev.to_vec(),
            correlation.chunks(p.max(1)).map(|r| r.to_vec()).collect(),
            head[0],
            head[1],
        ))
    }
}

/// Settings of the Monte Carlo inside the objective.
#[derive(Clone, Copy, Debug)]
pub struct FitSettings {
    pub model: super::ModelSettings,
    /// At most this many re-centring stages.
    pub stages: usize,
    /// L-BFGS iterations per stage.
    pub iterations: usize,
}

/// The fit problem: a scene (its lights/views and pairs as the target needs), a target and the
/// parameters to fit.
pub struct Fit<'a> {
    pub scene: &'a Scene,
    pub target: &'a Target,
    pub params: Vec<FitParam>,
    pub settings: FitSettings,
    /// Stops the fit at its next wave of chunks with [`crate::Error::Interrupted`].
    pub stop: crate::mc::StopFlag,
}

/// Result of [`Fit::run`].
#[derive(Clone, Debug)]
pub struct FitResult {
    pub initial: Vec<f64>,
    pub fitted: Vec<f64>,
    /// One standard deviation per parameter (Gauss–Newton), and their correlation matrix.
    pub stddev: Vec<f64>,
    pub correlation: Vec<Vec<f64>>,
    pub loss: f64,
    pub log: Vec<LogEntry>,
    pub convergence: Convergence,
    /// Model statistics (as the target lists them) at the initial and fitted parameters.
    pub model_initial: Vec<f64>,
    pub model_fitted: Vec<f64>,
}

impl Fit<'_> {
    fn estimate<E: crate::mc::Estimator>(&self, e: &E) -> crate::Result<Estimate> {
        let plan = self.settings.model.plan();
        crate::mc::estimate_until(e, &plan, self.stop.get())
    }

    fn diff_params(&self) -> Vec<Param> {
        let mut p = vec![Param::SigmaS, Param::SigmaA];
        if self.params.contains(&FitParam::G) {
            p.push(Param::G(0));
        }
        p
    }

    /// Covariance at natural values `v` from paths of `proposal`.
    fn covariance(&self, proposal: &Scene, v: &[f64]) -> crate::Result<Vec<C64>> {
        let target = medium_with(&self.scene.medium, &self.params, v);
        let r = Reweighted::new(
            proposal,
            target,
            self.target.pairs(self.scene),
            self.settings.model.reversed,
            vec![],
        )?;
        Ok(self.estimate(&ReweightedCovariance(r))?.mean)
    }

    /// Loss and its gradient with respect to the natural parameters.
    fn loss_and_gradient(&self, proposal: &Scene, v: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
        let c = self.covariance(proposal, v)?;
        let (loss, adjoint) = self.target.loss(&c);
        let m = medium_with(&self.scene.medium, &self.params, v);
        let dp = self.diff_params();
        let r = Reweighted::new(
            proposal,
            m.clone(),
            self.target.pairs(self.scene),
            self.settings.model.reversed,
            dp.clone(),
        )?;
        let g = self.estimate(&CovarianceGradient::new(r, &adjoint))?.mean;
        let (ds, da) = (g[0].re, g[1].re);
        let jac = crate::medium::params::sigmas_jacobian(1.0 / m.sigma_t(), m.albedo());
        let grad = self
            .params
            .iter()
            .map(|p| match p {
                FitParam::Mfp => ds * jac[0][0] + da * jac[1][0],
                FitParam::Albedo => ds * jac[0][1] + da * jac[1][1],
                FitParam::SigmaS => ds,
                FitParam::SigmaA => da,
                FitParam::G => g[2].re,
            })
            .collect();
        Ok((loss, grad))
    }

    /// The scene with the medium at natural values `v` (a proposal).
    fn proposal(&self, v: &[f64]) -> Scene {
        Scene {
            medium: medium_with(&self.scene.medium, &self.params, v),
            ..self.scene.clone()
        }
    }

    /// `compute(proposal)` for the parameters `v`, with paths of the proposal at natural values
    /// `centre`, through `journal` (`what` tells the kinds of record apart in its check).
    fn recorded<T: Numbers>(
        &self,
        journal: &Journal,
        what: f64,
        (centre, v): (&[f64], &[f64]),
        compute: impl FnOnce(&Scene) -> crate::Result<T>,
    ) -> crate::Result<T> {
        let inputs: Vec<f64> = [what].iter().chain(centre).chain(v).copied().collect();
        recall(journal, &inputs, || compute(&self.proposal(centre)))
    }

    /// [`Self::loss_and_gradient`] through `journal`.
    fn recorded_loss_and_gradient(
        &self,
        journal: &Journal,
        centre: &[f64],
        v: &[f64],
    ) -> crate::Result<(f64, Vec<f64>)> {
        self.recorded(journal, 0.0, (centre, v), |p| self.loss_and_gradient(p, v))
    }

    /// [`Self::uncertainty`] through `journal`.
    fn recorded_uncertainty(
        &self,
        journal: &Journal,
        centre: &[f64],
        v: &[f64],
    ) -> crate::Result<Uncertainty> {
        self.recorded(journal, 1.0, (centre, v), |p| self.uncertainty(v, p))
    }

    /// The gradient in the unconstrained variables from the natural one.
    fn unconstrained_gradient(&self, v: &[f64], g: &[f64]) -> Vec<f64> {
        self.params
            .iter()
            .zip(v)
            .zip(g)
            .map(|((p, v), g)| g * p.dv_du(*v))
            .collect()
    }

    /// Gauss–Newton standard deviations and correlations at natural values `v`, and the loss with
    /// each residual damped by its model error: the Jacobian of the residuals by central differences
    /// of the smooth re-weighted objective (proposal at `v`).
    fn uncertainty(&self, v: &[f64], proposal: &Scene) -> crate::Result<Uncertainty> {
        // uncertainty: Gauss–Newton at the optimum, Jacobian of the residuals by central differences
        // of the re-weighted objective (proposal at the optimum), with a step of 5 % in the
        // unconstrained variables: the two-lens terms of focused endpoints are piecewise smooth in
        // σ_t (their linearisation guard), and a short step would turn a tiny jump into a steep
        // Jacobian and a far too small error bar; the truncation error is ~1e-3 relative
        let (at_opt, kept) = super::model_with_chunks(
            proposal,
            medium_with(&self.scene.medium, &self.params, v),
            self.target,
            self.scene,
            &self.settings.model,
            &self.stop,
        )?;
        let r0 = self.target.residuals(&at_opt.mean);
        // the model's per-residual Monte Carlo error (residual units) only sets the expected size
        // of the loss (the Birge ratio below); how the model noise moves the parameters, correlated
        // across entries as it is (shared paths), enters through the sandwich term
        let model = self.target.model_stderr(&at_opt, &kept);
        let damp: Vec<f64> = model.iter().map(|m| 1.0 / (1.0 + m * m).sqrt()).collect();
        let p = self.params.len();
        let mut jac = vec![vec![0.0; p]; r0.len()];
        for (k, q) in self.params.iter().enumerate() {
            let h = 5e-2 * q.unconstrained(v[k]).abs().max(1.0);
            let mut vp = v.to_vec();
            let mut vm = v.to_vec();
            vp[k] = q.natural(q.unconstrained(v[k]) + h);
            vm[k] = q.natural(q.unconstrained(v[k]) - h);
            let (rp, rm) = (
                self.target.residuals(&self.covariance(proposal, &vp)?),
                self.target.residuals(&self.covariance(proposal, &vm)?),
            );
            let dv = vp[k] - vm[k];
            for t in 0..r0.len() {
                jac[t][k] = (rp[t] - rm[t]) / dv;
            }
        }
        let loss: f64 = r0.iter().zip(&damp).map(|(r, d)| (r * d).powi(2)).sum();
        let dof = (r0.len() as f64 - p as f64).max(1.0);
        let a = super::covariance_matrix(&jac, 1.0);
        // model noise: the parameters move by δθ = −A Jᵀ ε for model residual noise ε; Jᵀε per
        // chunk is a linear functional of the chunk's covariance estimate
        let weights: Vec<Vec<C64>> = (0..p)
            .map(|k| {
                let col: Vec<f64> = jac.iter().map(|row| row[k]).collect();
                self.target.residual_vjp(&at_opt.mean, &col)
            })
            .collect();
        let m = {
            let r = Reweighted::new(
                proposal,
                medium_with(&self.scene.medium, &self.params, v),
                self.target.pairs(self.scene),
                self.settings.model.reversed,
                vec![],
            )?;
            let plan = self.settings.model.plan();
            let est = Projected {
                inner: ReweightedCovariance(r),
                weights: &weights,
            };
            let keep: Vec<usize> = (0..p).collect();
            self.stop.check()?;
            let root = merge(
                run(&est, &plan, 0..plan.chunks, &keep, &|_| {}),
                plan.chunks,
            )?;
            kept_covariance(&root.kept, p)
        };
        // with errors, the target's part is A (residuals in units of its errors), inflated by the
        // Birge ratio when the fit is worse than target and model errors allow; without them, the
        // residual variance stands for the target's errors
        let (target_scale, model_scale) = if self.target.has_errors() {
            let birge = (loss / dof).max(1.0);
            (birge, birge)
        } else {
            (loss / dof, 1.0)
        };
        let ama = |i: usize, j: usize| -> f64 {
            (0..p)
                .flat_map(|k| (0..p).map(move |l| (k, l)))
                .map(|(k, l)| a[(i, k)] * m[k][l] * a[(l, j)])
                .sum()
        };
        let cov = faer::Mat::<f64>::from_fn(p, p, |i, j| {
            target_scale * a[(i, j)] + model_scale * ama(i, j)
        });
        let (stddev, correlation) = super::standard_deviations(&cov);
        // the Gauss–Newton step left, δ = (JᵀJ)⁻¹ Jᵀr, and its squared Mahalanobis length in the
        // uncertainty before any Birge inflation (which a poor point would earn itself): target
        // and model errors, so that Monte Carlo jitter between proposals does not look like a step
        let jtr: Vec<f64> = (0..p)
            .map(|k| jac.iter().zip(&r0).map(|(row, r)| row[k] * r).sum())
            .collect();
        let delta =
            faer::Mat::<f64>::from_fn(p, 1, |i, _| (0..p).map(|j| a[(i, j)] * jtr[j]).sum::<f64>());
        let unscaled = faer::Mat::<f64>::from_fn(p, p, |i, j| {
            let t = if self.target.has_errors() {
                1.0
            } else {
                loss / dof
            };
            t * a[(i, j)] + ama(i, j)
        });
        let decrement = {
            use faer::linalg::solvers::Solve;
            let x = unscaled.partial_piv_lu().solve(&delta);
            (0..p).map(|i| delta[(i, 0)] * x[(i, 0)]).sum::<f64>()
        };
        Ok((stddev, correlation, loss, decrement))
    }

    /// One stage: minimise the objective re-weighted from the proposal at natural values `centre`
    /// inside the trust box about it, from `centre`; `grad_u` is the gradient there.
    fn stage(
        &self,
        stage: usize,
        centre: &[f64],
        grad_u: &[f64],
        (iterations, radius): (usize, f64),
        record: &(dyn Fn(LogEntry) + Sync),
        journal: &Journal,
    ) -> crate::Result<(lbfgs::Outcome, f64)> {
        let g0u = grad_u.iter().map(|g| g * g).sum::<f64>().sqrt();
        if !g0u.is_finite() {
            return Err(
                format!("fit stage {stage}: the gradient is not finite at {centre:?}").into(),
            );
        }
        let u0: Vec<f64> = self
            .params
            .iter()
            .zip(centre)
            .map(|(p, v)| p.unconstrained(*v))
            .collect();
        let objective = StageObjective {
            fit: self,
            centre,
            journal,
            scale: if g0u > 0.0 { 0.5 / g0u } else { 1.0 },
        };
        let settings = lbfgs::Settings {
            max_iters: iterations,
            grad_tol: 1e-7,
            cost_tol: 1e-12,
            bounds: Some(Bounds {
                lower: u0.iter().map(|u| u - radius).collect(),
                upper: u0.iter().map(|u| u + radius).collect(),
            }),
        };
        let observe = |e: &lbfgs::Evaluation| {
            record(LogEntry {
                stage,
                loss: e.loss / objective.scale,
                params: objective.natural(&e.x),
                grad_norm: e.grad_norm / objective.scale,
            })
        };
        let out = lbfgs::minimise(&objective, &u0, &settings, &observe)
            .map_err(|e| format!("fit stage {stage}: {e}"))?;
        Ok((out, objective.scale))
    }

    /// Run the fit from the scene's current parameter values: trust-region stages that re-centre
    /// the proposal until the Gauss–Newton step left is within a standard deviation, then a final
    /// stage with the proposal held fixed, minimised to convergence; or the stage limit.
    /// `journal` records the fit's evaluations (and replays the run it was saved from).
    pub fn run(
        &self,
        progress: &(dyn Fn(&LogEntry) + Sync),
        journal: &Journal,
    ) -> crate::Result<FitResult> {
        let initial: Vec<f64> = self
            .params
            .iter()
            .map(|p| p.value(&self.scene.medium))
            .collect();
        let log = Mutex::new(Vec::new());
        let record = |entry: LogEntry| {
            progress(&entry);
            if let Ok(mut l) = log.lock() {
                l.push(entry);
            }
        };
        let mut current = initial.clone();
        let (loss_0, g) = self.recorded_loss_and_gradient(journal, &current, &current)?;
        if !loss_0.is_finite() {
            return Err(format!(
                "fit: the loss is not finite at the start {current:?} (does light reach the views?)"
            )
            .into());
        }
        let mut grad_u = self.unconstrained_gradient(&current, &g);
        let mut grad_norm = grad_u.iter().map(|g| g * g).sum::<f64>().sqrt();
        let mut evaluations = 1;
        let mut radius = TRUST;
        let mut stop = FitStop::StageLimit;
        let mut uncertainty = None;
        let mut near = false;
        let mut stages = 0;
        for stage in 0..self.settings.stages {
            stages = stage + 1;
            if grad_norm == 0.0 {
                stop = FitStop::GradientTolerance;
                break;
            }
            // near the optimum the last stage holds its proposal and runs L-BFGS to convergence
            let iterations = self.settings.iterations * if near { 4 } else { 1 };
            let (out, scale) = self.stage(
                stage,
                &current,
                &grad_u,
                (iterations, radius),
                &record,
                journal,
            )?;
            evaluations += out.evaluations;
            let interior = !out.at_bound.iter().any(|b| *b);
            let next: Vec<f64> = self
                .params
                .iter()
                .zip(&out.x)
                .map(|(p, u)| p.natural(*u))
                .collect();
            if near && interior && out.stop.converged() {
                uncertainty = Some(self.recorded_uncertainty(journal, &current, &next)?);
                current = next;
                grad_norm = out.grad_norm / scale;
                stop = FitStop::from(&out.stop);
                break;
            }
            // fresh paths at the stage's best evaluated point
            let (loss_n, g_n) = self.recorded_loss_and_gradient(journal, &next, &next)?;
            evaluations += 1;
            if !(loss_n.is_finite() && g_n.iter().all(|g| g.is_finite())) {
                radius /= 4.0;
                if radius < TRUST_MIN {
                    stop = FitStop::TrustRegion;
                    break;
                }
                continue;
            }
            current = next;
            grad_u = self.unconstrained_gradient(&current, &g_n);
            grad_norm = grad_u.iter().map(|g| g * g).sum::<f64>().sqrt();
            near = false;
            uncertainty = None;
            if interior {
                let u = self.recorded_uncertainty(journal, &current, &current)?;
                near = u.3 < NEAR;
                uncertainty = Some(u);
            }
        }
        let (stddev, correlation, loss, _) = match uncertainty {
            Some(u) => u,
            None => self.recorded_uncertainty(journal, &current, &current)?,
        };
        let model_initial = self.target.model_values(&self.covariance(
            &Scene {
                medium: medium_with(&self.scene.medium, &self.params, &initial),
                ..self.scene.clone()
            },
            &initial,
        )?);
        let model_fitted = self
            .target
            .model_values(&self.covariance(&self.proposal(&current), &current)?);
        Ok(FitResult {
            initial,
            fitted: current,
            stddev,
            correlation,
            loss,
            log: log.into_inner().unwrap_or_default(),
            convergence: Convergence {
                converged: stop.converged(),
                stop,
                grad_norm,
                evaluations,
                iterations: stages,
            },
            model_initial,
            model_fitted,
        })
    }
}

/// One stage's objective in the unconstrained variables `u`, with paths of a fixed proposal,
/// scaled so its first gradient has norm ½ (a modest first trial step).
struct StageObjective<'f, 'a> {
    fit: &'f Fit<'a>,
    /// Natural values of the proposal medium.
    centre: &'f [f64],
    journal: &'f Journal,
    scale: f64,
}

impl StageObjective<'_, '_> {
    fn natural(&self, u: &[f64]) -> Vec<f64> {
        self.fit
            .params
            .iter()
            .zip(u)
            .map(|(p, u)| p.natural(*u))
            .collect()
    }
}

impl lbfgs::Objective for StageObjective<'_, '_> {
    fn eval(&self, u: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
        let v = self.natural(u);
        let (loss, g) = self
            .fit
            .recorded_loss_and_gradient(self.journal, self.centre, &v)?;
        let gu = self.fit.unconstrained_gradient(&v, &g);
        Ok((
            loss * self.scale,
            gu.iter().map(|g| g * self.scale).collect(),
        ))
    }
}
