//! Fitting material parameters to measured speckle statistics: losses on rendered vs
//! target statistics, a deterministic objective from re-weighted proposal paths, L-BFGS (argmin), and
//! a Gauss–Newton uncertainty estimate.
//!
//! The objective at parameters θ re-weights a fixed set of subpaths drawn from a proposal medium θ₀
//! (common random numbers), so it is smooth in θ and its gradient is exact for it
//! ([`crate::diff`]). The proposal is re-centred on the current estimate between stages, which keeps
//! the re-weighting variance small while the parameters move.

pub mod adam;
pub mod grin_design;
pub mod grin_fit;
pub mod shortcut;
pub mod target;

pub use crate::medium::params::{FitParam, check_params, medium_with};
pub use adam::{AdamFit, AdamResult, AdamSettings};
pub use target::{Entry, Measured, Target};

use crate::diff::{CovarianceGradient, Param, Reweighted, ReweightedCovariance};
use crate::math::C64;
use crate::mc::{Estimate, Plan, merge, run};
use crate::speckle::Scene;
use argmin::core::{CostFunction, Error as ArgminError, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use std::sync::Mutex;

/// Half-width of a stage's trust region in the unconstrained variables: re-weighting stays accurate
/// only near the proposal (the weights multiply a phase-function ratio per interior vertex).
const TRUST: f64 = 0.25;

/// Settings of the Monte Carlo inside the objective.
#[derive(Clone, Copy, Debug)]
pub struct FitSettings {
    pub samples: u64,
    pub chunk: u64,
    pub seed: u64,
    pub reversed: bool,
    pub stages: usize,
    pub iterations: usize,
}

/// One logged evaluation.
#[derive(Clone, Debug)]
pub struct LogEntry {
    pub stage: usize,
    pub loss: f64,
    pub params: Vec<f64>,
    pub grad_norm: f64,
}

/// The fit problem: a scene (its lights/views and pairs as the target needs), a target and the
/// parameters to fit.
pub struct Fit<'a> {
    pub scene: &'a Scene,
    pub target: &'a Target,
    pub params: Vec<FitParam>,
    pub settings: FitSettings,
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
    /// Model statistics (as the target lists them) at the initial and fitted parameters.
    pub model_initial: Vec<f64>,
    pub model_fitted: Vec<f64>,
}

impl Fit<'_> {
    fn estimate<E: crate::mc::Estimator>(&self, e: &E) -> Estimate {
        let plan = Plan::new(
            self.settings.seed,
            self.settings.samples,
            self.settings.chunk,
        );
        crate::mc::estimate(e, &plan)
    }

    fn diff_params(&self) -> Vec<Param> {
        let mut p = vec![Param::SigmaS, Param::SigmaA];
        if self.params.contains(&FitParam::G) {
            p.push(Param::G(0));
        }
        p
    }

    /// Covariance at natural values `v` from paths of `proposal`.
    fn covariance(&self, proposal: &Scene, v: &[f64]) -> Result<Vec<C64>, String> {
        let target = medium_with(&self.scene.medium, &self.params, v);
        let r = Reweighted::new(
            proposal,
            target,
            self.target.pairs(self.scene),
            self.settings.reversed,
            vec![],
        )?;
        Ok(self.estimate(&ReweightedCovariance(r)).mean)
    }

    /// Loss and its gradient with respect to the natural parameters.
    fn loss_and_gradient(&self, proposal: &Scene, v: &[f64]) -> Result<(f64, Vec<f64>), String> {
        let c = self.covariance(proposal, v)?;
        let (loss, adjoint) = self.target.loss(&c);
        let m = medium_with(&self.scene.medium, &self.params, v);
        let dp = self.diff_params();
        let r = Reweighted::new(
            proposal,
            m.clone(),
            self.target.pairs(self.scene),
            self.settings.reversed,
            dp.clone(),
        )?;
        let g = self.estimate(&CovarianceGradient::new(r, &adjoint)).mean;
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

    /// Run the staged L-BFGS fit from the scene's current parameter values.
    pub fn run(&self, progress: &(dyn Fn(&LogEntry) + Sync)) -> Result<FitResult, String> {
        let initial: Vec<f64> = self
            .params
            .iter()
            .map(|p| p.value(&self.scene.medium))
            .collect();
        let log = Mutex::new(Vec::new());
        let mut current = initial.clone();
        for stage in 0..self.settings.stages {
            let proposal = Scene {
                medium: medium_with(&self.scene.medium, &self.params, &current),
                ..self.scene.clone()
            };
            let u0: Vec<f64> = self
                .params
                .iter()
                .zip(&current)
                .map(|(p, v)| p.unconstrained(*v))
                .collect();
            let (_, g0) = self.loss_and_gradient(&proposal, &current)?;
            let g0u = self
                .params
                .iter()
                .zip(&current)
                .zip(&g0)
                .map(|((p, v), g)| (g * p.dv_du(*v)).powi(2))
                .sum::<f64>()
                .sqrt();
            if !g0u.is_finite() {
                return Err(format!(
                    "fit stage {stage}: the gradient is not finite at {current:?}"
                ));
            }
            if g0u == 0.0 {
                break;
            }
            let problem = Objective {
                fit: self,
                proposal: &proposal,
                stage,
                scale: 0.5 / g0u,
                centre: u0.clone(),
                log: &log,
                progress,
            };
            let line = MoreThuenteLineSearch::new()
                .with_bounds(1e-12, 4.0)
                .map_err(|e| e.to_string())?;
            let solver = LBFGS::new(line, 7)
                .with_tolerance_grad(1e-10)
                .map_err(|e| e.to_string())?
                .with_tolerance_cost(1e-12)
                .map_err(|e| e.to_string())?;
            let res = Executor::new(problem, solver)
                .configure(|s| s.param(u0).max_iters(self.settings.iterations as u64))
                .run()
                .map_err(|e| format!("fit stage {stage}: {e}"))?;
            let best = res
                .state()
                .get_best_param()
                .cloned()
                .ok_or("fit: no parameters evaluated")?;
            let next: Vec<f64> = self
                .params
                .iter()
                .zip(&best)
                .map(|(p, u)| p.natural(*u))
                .collect();
            let moved = next
                .iter()
                .zip(&current)
                .map(|(a, b)| ((a - b) / b.abs().max(1e-3)).abs())
                .fold(0.0, f64::max);
            current = next;
            if moved < 1e-4 {
                break;
            }
        }
        // uncertainty: Gauss–Newton at the optimum, Jacobian of the residuals by central differences
        // of the smooth re-weighted objective (proposal at the optimum)
        let proposal = Scene {
            medium: medium_with(&self.scene.medium, &self.params, &current),
            ..self.scene.clone()
        };
        let (at_opt, kept) = {
            let target = medium_with(&self.scene.medium, &self.params, &current);
            let r = Reweighted::new(
                &proposal,
                target,
                self.target.pairs(self.scene),
                self.settings.reversed,
                vec![],
            )?;
            let plan = Plan::new(
                self.settings.seed,
                self.settings.samples,
                self.settings.chunk,
            );
            let est = ReweightedCovariance(r);
            let root = merge(
                run(&est, &plan, 0..plan.chunks, &self.target.keep(), &|_| {}),
                plan.chunks,
            )?;
            (Estimate::from_block(&root, &plan), root.kept)
        };
        let r0 = self.target.residuals(&at_opt.mean);
        // the objective's own Monte Carlo error, in residual units: each residual's total variance is
        // target² + model², so residuals and their Jacobian are down-weighted by sqrt(1 + model²)
        let model = self.target.model_stderr(&at_opt, &kept);
        let damp: Vec<f64> = model.iter().map(|m| 1.0 / (1.0 + m * m).sqrt()).collect();
        let mut jac = vec![vec![0.0; self.params.len()]; r0.len()];
        for (k, p) in self.params.iter().enumerate() {
            let h = 1e-4 * p.unconstrained(current[k]).abs().max(1.0);
            let mut vp = current.clone();
            let mut vm = current.clone();
            vp[k] = p.natural(p.unconstrained(current[k]) + h);
            vm[k] = p.natural(p.unconstrained(current[k]) - h);
            let (rp, rm) = (
                self.target.residuals(&self.covariance(&proposal, &vp)?),
                self.target.residuals(&self.covariance(&proposal, &vm)?),
            );
            let dv = vp[k] - vm[k];
            for t in 0..r0.len() {
                jac[t][k] = (rp[t] - rm[t]) / dv * damp[t];
            }
        }
        let loss: f64 = r0.iter().zip(&damp).map(|(r, d)| (r * d).powi(2)).sum();
        let dof = (r0.len() as f64 - self.params.len() as f64).max(1.0);
        // with errors (target and model), inflate by the Birge ratio when the fit is worse than
        // they allow; without target errors, scale by the residual variance
        let scale = if self.target.has_errors() {
            (loss / dof).max(1.0)
        } else {
            loss / dof
        };
        let (stddev, correlation) = gauss_newton(&jac, scale);
        let model_initial = self.target.model_values(&self.covariance(
            &Scene {
                medium: medium_with(&self.scene.medium, &self.params, &initial),
                ..self.scene.clone()
            },
            &initial,
        )?);
        let model_fitted = self
            .target
            .model_values(&self.covariance(&proposal, &current)?);
        Ok(FitResult {
            initial,
            fitted: current,
            stddev,
            correlation,
            loss,
            log: log.into_inner().unwrap_or_default(),
            model_initial,
            model_fitted,
        })
    }
}

/// `(JᵀJ)⁻¹ × scale`: the Gauss–Newton covariance of the parameters.
fn covariance_matrix(jac: &[Vec<f64>], scale: f64) -> faer::Mat<f64> {
    use faer::linalg::solvers::Solve;
    let p = jac.first().map_or(0, |r| r.len());
    let jtj = faer::Mat::<f64>::from_fn(p, p, |a, b| jac.iter().map(|r| r[a] * r[b]).sum());
    let id = faer::Mat::<f64>::identity(p, p);
    jtj.partial_piv_lu().solve(&id) * faer::Scale(scale)
}

/// Standard deviations and correlations from [`covariance_matrix`] (NaN where singular: not
/// identifiable).
fn gauss_newton(jac: &[Vec<f64>], scale: f64) -> (Vec<f64>, Vec<Vec<f64>>) {
    let cov = covariance_matrix(jac, 1.0);
    let p = cov.nrows();
    let sd: Vec<f64> = (0..p)
        .map(|a| (cov[(a, a)] * scale).max(0.0).sqrt())
        .collect();
    let corr = (0..p)
        .map(|a| {
            (0..p)
                .map(|b| cov[(a, b)] / (cov[(a, a)] * cov[(b, b)]).sqrt())
                .collect()
        })
        .collect();
    (sd, corr)
}

/// The argmin problem for one stage (unconstrained variables `u`).
struct Objective<'f, 'a> {
    fit: &'f Fit<'a>,
    proposal: &'f Scene,
    stage: usize,
    /// Loss scale making the first gradient (in `u`) of norm ½, so the first trial step is modest.
    scale: f64,
    /// The stage's start; each `u` stays within ±`TRUST` of it (a trust region: re-weighting from the
    /// proposal is accurate only nearby, and the next stage re-centres).
    centre: Vec<f64>,
    log: &'f Mutex<Vec<LogEntry>>,
    progress: &'f (dyn Fn(&LogEntry) + Sync),
}

impl Objective<'_, '_> {
    fn natural(&self, u: &[f64]) -> Vec<f64> {
        let clamp = |u: f64, c: f64| {
            if u.is_finite() {
                u.clamp(c - TRUST, c + TRUST)
            } else {
                c
            }
        };
        self.fit
            .params
            .iter()
            .zip(u)
            .zip(&self.centre)
            .map(|((p, u), c)| p.natural(clamp(*u, *c)))
            .collect()
    }
}

impl CostFunction for Objective<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, u: &Vec<f64>) -> Result<f64, ArgminError> {
        let v = self.natural(u);
        let c = self
            .fit
            .covariance(self.proposal, &v)
            .map_err(ArgminError::msg)?;
        let l = self.fit.target.loss(&c).0 * self.scale;
        // a non-finite loss (parameters far outside the data's reach) must still rank worse
        Ok(if l.is_finite() { l } else { 1e30 })
    }
}

impl Gradient for Objective<'_, '_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, u: &Vec<f64>) -> Result<Vec<f64>, ArgminError> {
        let v = self.natural(u);
        let (loss, g) = self
            .fit
            .loss_and_gradient(self.proposal, &v)
            .map_err(ArgminError::msg)?;
        // d/du of the natural value; zero where the trust region clamps u
        let gu: Vec<f64> = (0..v.len())
            .map(|i| {
                let inside = (u[i] - self.centre[i]).abs() < TRUST;
                let d = if inside {
                    g[i] * self.fit.params[i].dv_du(v[i])
                } else {
                    0.0
                };
                if d.is_finite() { d } else { 0.0 }
            })
            .collect();
        let entry = LogEntry {
            stage: self.stage,
            loss,
            params: v,
            grad_norm: gu.iter().map(|x| x * x).sum::<f64>().sqrt(),
        };
        let gu = gu.iter().map(|g| g * self.scale).collect();
        (self.progress)(&entry);
        if let Ok(mut l) = self.log.lock() {
            l.push(entry);
        }
        Ok(gu)
    }
}
