//! Many-parameter fits with Adam through the burn bridge: typically every node
//! value of a tabulated phase function, optionally with `mfp`, `albedo`, `g`.
//!
//! The loss is written in burn tensors: the covariance entries are a burn operation
//! ([`CovarianceOp`], backward = path-space gradient), the target's weighted least squares another
//! ([`TargetLoss`], backward = its analytic adjoint), and the reparameterisation (`ρ_k = e^{u_k}`,
//! `mfp = e^u`, `albedo = sigmoid u`, `g = tanh u`) and the smoothness prior on `log ρ` are ordinary
//! burn operations. Each iteration draws fresh paths from the current parameters (unbiased
//! stochastic gradients, as Adam expects) with a step decaying to 1/20 of the initial one; the
//! estimate is the average of the iterates over the last third (Polyak–Ruppert), and its uncertainty is Gauss–Newton on a fixed-proposal objective
//! at that point, with the target's and the model's Monte Carlo errors.

use super::{Convergence, FitParam, LogEntry, Target, covariance_matrix};
use crate::diff::bridge::{Differentiable, Pullback, apply, tensor, values};
use crate::diff::{CovarianceOp, Param, Proposal, medium_at};
use crate::math::C64;
use crate::medium::{Medium, PhaseFunction};
use crate::speckle::Scene;
use burn::tensor::{Device, Tensor};
use std::f64::consts::PI;
use std::sync::Arc;

/// Settings of an Adam fit.
#[derive(Clone, Copy, Debug)]
pub struct AdamSettings {
    pub model: super::ModelSettings,
    pub iterations: usize,
    pub learning_rate: f64,
    /// Weight of the smoothness prior `Σ (Δ² log ρ)²` over consecutive nodes.
    pub smooth: f64,
}

/// The fit problem: scalar parameters and/or the node values of the tabulated phase function of
/// particle type 0.
pub struct AdamFit<'a> {
    pub scene: &'a Scene,
    pub target: &'a Target,
    pub params: Vec<FitParam>,
    pub phase: bool,
    pub settings: AdamSettings,
    /// Stops the fit at its next wave of chunks with [`crate::Error::Interrupted`].
    pub stop: crate::mc::StopFlag,
}

/// Result of [`AdamFit::run`]. Values are natural: scalar parameters, then the normalised phase
/// function `ρ` at the table's nodes.
#[derive(Clone, Debug)]
pub struct AdamResult {
    pub names: Vec<String>,
    pub initial: Vec<f64>,
    pub fitted: Vec<f64>,
    pub stddev: Vec<f64>,
    /// Cosines of the phase-function nodes (empty without `phase`).
    pub cos: Vec<f64>,
    /// Weighted loss at the fitted values (fixed proposal, with the model's error), per residual.
    pub loss: f64,
    pub dof: f64,
    pub log: Vec<LogEntry>,
    /// Adam runs a fixed number of iterations: converged when the loss has reached a plateau.
    pub convergence: Convergence,
    pub model_initial: Vec<f64>,
    pub model_fitted: Vec<f64>,
}

/// A target's weighted least-squares loss as a function of the model's needed entries
/// (`[Re, Im]` per entry), with the target's analytic adjoint as its pullback.
pub struct TargetLoss<'t> {
    pub target: &'t Target,
    /// Number of (light, view) pairs of the model covariance.
    pub j: usize,
    /// `(a, b)` entries, in the order of the input.
    pub entries: Vec<(usize, usize)>,
}

struct Scaled(Vec<f64>);

impl Pullback for Scaled {
    fn pullback(&self, dy: &[f64]) -> Vec<f64> {
        self.0.iter().map(|g| g * dy[0]).collect()
    }
}

impl TargetLoss<'_> {
    /// The model covariance (`J×J`, zero where not needed) from the entries.
    pub fn covariance(&self, y: &[f64]) -> Vec<C64> {
        let mut c = vec![C64::default(); self.j * self.j];
        for (e, (a, b)) in self.entries.iter().enumerate() {
            c[a * self.j + b] = C64::new(y[2 * e], y[2 * e + 1]);
        }
        c
    }
}

impl Differentiable for TargetLoss<'_> {
    fn forward(&self, y: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
        let (loss, adj) = self.target.loss(&self.covariance(y));
        let grad = self
            .entries
            .iter()
            .flat_map(|(a, b)| {
                let z = adj[a * self.j + b];
                [z.re, z.im]
            })
            .collect();
        Ok((vec![loss], Arc::new(Scaled(grad))))
    }
}

impl AdamFit<'_> {
    fn nodes(&self) -> crate::Result<Vec<f64>> {
        if !self.phase {
            return Ok(vec![]);
        }
        match self.scene.medium.scattering.components().first() {
            Some((_, PhaseFunction::Tabulated(t))) => Ok(t.nodes().0.to_vec()),
            _ => Err("--fit phase needs medium.phase = { kind = \"tabulated\", ... } (or a mixture whose first component is tabulated)".into()),
        }
    }

    /// The estimator's parameters: σ_s, σ_a, g (if fitted), then the node values.
    fn op_params(&self, nodes: usize) -> Vec<Param> {
        let mut p = vec![Param::SigmaS, Param::SigmaA];
        if self.params.contains(&FitParam::G) {
            p.push(Param::G(0));
        }
        p.extend((0..nodes).map(|k| Param::Bin(0, k)));
        p
    }

    /// `θ(u)` in burn operations: scalar reparameterisations, `σ_s, σ_a` from `mfp, albedo`, and
    /// `ρ_k = e^{u_k}` (unnormalised; the estimator renormalises).
    fn theta(&self, u: Tensor<1>, nodes: usize) -> Tensor<1> {
        let dev = u.device();
        let m = &self.scene.medium;
        let konst = |x: f64| tensor(&[x], &dev);
        let at = |p: FitParam| {
            self.params
                .iter()
                .position(|q| *q == p)
                .map(|i| u.clone().narrow(0, i, 1))
        };
        let (sigma_s, sigma_a) = if at(FitParam::Mfp).is_some() || at(FitParam::Albedo).is_some() {
            let mfp = at(FitParam::Mfp).map_or_else(|| konst(1.0 / m.sigma_t()), Tensor::exp);
            let a = at(FitParam::Albedo)
                .map_or_else(|| konst(m.albedo()), burn::tensor::activation::sigmoid);
            (a.clone() / mfp.clone(), a.neg().add_scalar(1.0) / mfp)
        } else {
            (
                at(FitParam::SigmaS).map_or_else(|| konst(m.sigma_s), Tensor::exp),
                at(FitParam::SigmaA).map_or_else(|| konst(m.sigma_a), Tensor::exp),
            )
        };
        let mut parts = vec![sigma_s, sigma_a];
        if let Some(g) = at(FitParam::G) {
            parts.push(g.tanh());
        }
        if nodes > 0 {
            let s = self.params.len();
            parts.push(u.narrow(0, s, nodes).exp());
        }
        Tensor::cat(parts, 0)
    }

    /// `smooth · Σ (u_{k+1} − 2u_k + u_{k−1})²` over the node variables.
    fn prior(&self, u: Tensor<1>, nodes: usize) -> Option<Tensor<1>> {
        if nodes < 3 || self.settings.smooth == 0.0 {
            return None;
        }
        let s = self.params.len();
        let d2 = u.clone().narrow(0, s + 2, nodes - 2)
            - u.clone().narrow(0, s + 1, nodes - 2) * 2.0
            + u.narrow(0, s, nodes - 2);
        Some((d2.clone() * d2).sum() * self.settings.smooth)
    }

    fn op(&self, nodes: usize, proposal: Proposal, seed: u64) -> crate::Result<CovarianceOp> {
        let mut entries = self.target.needed();
        entries.sort_unstable();
        entries.dedup();
        let mut op = CovarianceOp::new(
            self.scene.clone(),
            self.op_params(nodes),
            self.target.pairs(self.scene),
            entries,
            self.settings.model.reversed,
            (self.settings.model.samples, self.settings.model.chunk, seed),
            proposal,
        )?;
        op.stop = self.stop.clone();
        Ok(op)
    }

    /// Natural values (scalars, then normalised ρ at the nodes) and the medium at `u`.
    fn natural(&self, u: &[f64], nodes: usize) -> crate::Result<(Vec<f64>, Medium)> {
        let theta = values(&self.theta(tensor(u, &Device::flex()), nodes));
        let (m, _) = medium_at(&self.scene.medium, &self.op_params(nodes), &theta)?;
        let mut v: Vec<f64> = self.params.iter().map(|p| p.value(&m)).collect();
        if let Some((_, PhaseFunction::Tabulated(t))) = m.scattering.components().first()
            && nodes > 0
        {
            v.extend_from_slice(t.nodes().1);
        }
        Ok((v, m))
    }

    /// Run Adam from the scene's current values; `progress` sees every iteration; `journal`
    /// records the run (and replays the run it was saved from).
    pub fn run(
        &self,
        progress: &(dyn Fn(&LogEntry) + Sync),
        journal: &super::journal::Journal,
    ) -> crate::Result<AdamResult> {
        let cos = self.nodes()?;
        let nodes = cos.len();
        let m = &self.scene.medium;
        let mut u0: Vec<f64> = self
            .params
            .iter()
            .map(|p| p.unconstrained(p.value(m)))
            .collect();
        if let Some((_, PhaseFunction::Tabulated(t))) = m.scattering.components().first()
            && nodes > 0
        {
            if let Some(k) = t.nodes().1.iter().position(|v| *v <= 0.0) {
                return Err(format!(
                    "--fit phase: node {k} of the starting phase function is 0; start from positive values (they are fitted on a log scale)"
                ).into());
            }
            u0.extend(t.nodes().1.iter().map(|v| v.ln()));
        }
        let s = &self.settings;
        if s.iterations == 0 || !(s.learning_rate > 0.0 && s.learning_rate.is_finite()) {
            return Err(format!(
                "Adam needs --iterations ≥ 1 and --learning-rate > 0 (got {} and {})",
                s.iterations, s.learning_rate
            )
            .into());
        }
        let stochastic = self.op(nodes, Proposal::AtTheta, s.model.seed)?;
        let loss_op = TargetLoss {
            target: self.target,
            j: stochastic.pairs.len(),
            entries: stochastic.entries.clone(),
        };
        let mut log = Vec::with_capacity(s.iterations);
        let tail = s.iterations - (s.iterations / 3).max(1);
        // the step decays geometrically to 1/20 of --learning-rate over the run, so the noisy
        // stochastic gradients settle and the averaged tail is not still travelling
        let learning_rate = |it: usize| {
            s.learning_rate * 20f64.powf(-(it as f64) / (s.iterations.max(2) - 1) as f64)
        };
        let average = super::adam::minimise(
            &u0,
            s.iterations,
            &learning_rate,
            tail,
            journal,
            &mut |it, u| {
                // iteration `it` draws its paths with seed + it, also when resumed
                stochastic.seek(it as u64);
                let params = self.natural(&values(&u), nodes)?.0;
                let y = apply(&stochastic, self.theta(u.clone(), nodes)).map_err(|e| {
                    if self.stop.is_set() {
                        crate::Error::Interrupted
                    } else {
                        format!("Adam iteration {it}: {e}").into()
                    }
                })?;
                let data = apply(&loss_op, y)?;
                let loss = values(&data)[0];
                let total = match self.prior(u, nodes) {
                    Some(p) => data + p,
                    None => data,
                };
                Ok((total, (loss, params)))
            },
            &mut |it| {
                // a pullback stopped by the flag leaves a NaN gradient: report the stop instead
                self.stop.check()?;
                let (loss, params) = it.observed;
                if !(loss.is_finite() && it.grad_norm.is_finite()) {
                    return Err(format!(
                        "Adam iteration {}: the loss or its gradient is not finite (loss {loss}); try a smaller --learning-rate",
                        it.iteration
                    ).into());
                }
                let entry = LogEntry {
                    stage: it.iteration,
                    loss,
                    params,
                    grad_norm: it.grad_norm,
                };
                progress(&entry);
                log.push(entry);
                Ok(())
            },
        )?
        .average;
        self.finish(&u0, &average, &cos, log)
    }

    /// Gauss–Newton uncertainty at the averaged iterate, on a fixed-proposal objective.
    fn finish(
        &self,
        u0: &[f64],
        u: &[f64],
        cos: &[f64],
        log: Vec<LogEntry>,
    ) -> crate::Result<AdamResult> {
        let nodes = cos.len();
        let (initial, _) = self.natural(u0, nodes)?;
        let (fitted, medium) = self.natural(u, nodes)?;
        let fixed = self.op(
            nodes,
            Proposal::Fixed(medium.clone()),
            self.settings.model.seed,
        )?;
        let loss_op = TargetLoss {
            target: self.target,
            j: fixed.pairs.len(),
            entries: fixed.entries.clone(),
        };
        let model = |u: &[f64]| -> crate::Result<(Vec<C64>, Vec<f64>)> {
            let theta = values(&self.theta(tensor(u, &Device::flex()), nodes));
            let e = fixed.evaluate(&theta)?;
            let y: Vec<f64> = e.value.iter().flat_map(|z| [z.re, z.im]).collect();
            let mut sd = vec![0.0; loss_op.j * loss_op.j];
            for ((a, b), s) in fixed.entries.iter().zip(&e.stderr) {
                sd[a * loss_op.j + b] = *s;
            }
            Ok((loss_op.covariance(&y), sd))
        };
        let (c, sd) = model(u)?;
        let r0 = self.target.residuals(&c);
        // the model's own Monte Carlo error damps each residual (as in the L-BFGS fit); a memory
        // curve's and normalised correlations' come from the per-chunk estimates of a run at the
        // fitted medium (delta method)
        let model_error = if !self.target.keep().is_empty() {
            let scene = Scene {
                medium: medium.clone(),
                ..self.scene.clone()
            };
            let (est, kept) = super::model_with_chunks(
                &scene,
                medium.clone(),
                self.target,
                self.scene,
                &self.settings.model,
                &self.stop,
            )?;
            self.target.model_stderr(&est, &kept)
        } else {
            let est = crate::mc::Estimate {
                mean: c.clone(),
                stderr: sd,
                samples: self.settings.model.samples,
                chunks: 0,
            };
            self.target.model_stderr(&est, &[])
        };
        let damp: Vec<f64> = model_error
            .iter()
            .map(|m| 1.0 / (1.0 + m * m).sqrt())
            .collect();
        let n = u.len();
        let mut jac = vec![vec![0.0; n]; r0.len()];
        for k in 0..n {
            let h = 1e-3;
            let (mut up, mut down) = (u.to_vec(), u.to_vec());
            up[k] += h;
            down[k] -= h;
            let (rp, rm) = (
                self.target.residuals(&model(&up)?.0),
                self.target.residuals(&model(&down)?.0),
            );
            for t in 0..r0.len() {
                jac[t][k] = (rp[t] - rm[t]) / (2.0 * h) * damp[t];
            }
        }
        let loss: f64 = r0.iter().zip(&damp).map(|(r, d)| (r * d).powi(2)).sum();
        // the smoothness prior as residual rows; the gauge (a common shift of log ρ changes
        // nothing) fixed by one row, which leaves the covariance of the normalised ρ unchanged
        let s0 = self.params.len();
        if nodes >= 3 && self.settings.smooth > 0.0 {
            let w = self.settings.smooth.sqrt();
            for k in 0..nodes - 2 {
                let mut row = vec![0.0; n];
                row[s0 + k] = w;
                row[s0 + k + 1] = -2.0 * w;
                row[s0 + k + 2] = w;
                jac.push(row);
            }
        }
        if nodes > 0 {
            let mut row = vec![0.0; n];
            row[s0..].iter_mut().for_each(|x| *x = 1.0);
            jac.push(row);
        }
        let dof = (r0.len() as f64 - n as f64 + f64::from(u8::from(nodes > 0))).max(1.0);
        let scale = if self.target.has_errors() {
            (loss / dof).max(1.0)
        } else {
            loss / dof
        };
        let cov_u = covariance_matrix(&jac, scale);
        // natural values: v = f(u) per scalar; ρ_k = v_k / Z with ∂ρ_k/∂u_j = ρ_k (δ_kj − 2π w_j ρ_j)
        let mut grad = vec![vec![0.0; n]; n];
        for (i, p) in self.params.iter().enumerate() {
            grad[i][i] = p.dv_du(fitted[i]);
        }
        let rho = &fitted[s0..];
        for k in 0..nodes {
            for j in 0..nodes {
                let w = 0.5 * (cos[(j + 1).min(nodes - 1)] - cos[j.saturating_sub(1)]);
                grad[s0 + k][s0 + j] =
                    rho[k] * (f64::from(u8::from(k == j)) - 2.0 * PI * w * rho[j]);
            }
        }
        let stddev = (0..n)
            .map(|a| {
                let mut var = 0.0;
                for i in 0..n {
                    for j in 0..n {
                        var += grad[a][i] * cov_u[(i, j)] * grad[a][j];
                    }
                }
                var.max(0.0).sqrt()
            })
            .collect();
        let mut names: Vec<String> = self.params.iter().map(|p| p.name().to_string()).collect();
        names.extend(
            cos.iter()
                .map(|c| format!("rho({:.2}°)", c.clamp(-1.0, 1.0).acos().to_degrees())),
        );
        let model_initial = {
            let start = self.op(
                nodes,
                Proposal::Fixed(self.scene.medium.clone()),
                self.settings.model.seed,
            )?;
            let theta = values(&self.theta(tensor(u0, &Device::flex()), nodes));
            let e = start.evaluate(&theta)?;
            let y: Vec<f64> = e.value.iter().flat_map(|z| [z.re, z.im]).collect();
            self.target.model_values(&loss_op.covariance(&y))
        };
        let losses: Vec<f64> = log.iter().map(|e| e.loss).collect();
        let grad_norm = log.last().map_or(f64::NAN, |e| e.grad_norm);
        let convergence = super::adam::convergence(&losses, grad_norm, log.len());
        Ok(AdamResult {
            names,
            initial,
            fitted,
            stddev,
            cos: cos.to_vec(),
            loss,
            dof,
            log,
            convergence,
            model_initial,
            model_fitted: self.target.model_values(&c),
        })
    }
}
