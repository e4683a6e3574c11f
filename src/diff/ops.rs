//! Speckle estimators as differentiable functions of a parameter vector, for the burn bridge
//! ([`super::bridge`]) and any other reverse-mode user.
//!
//! [`CovarianceOp`] maps `θ` (values of [`Param`]s) to chosen covariance entries `C_ab(θ)` (real and
//! imaginary parts) and pulls a loss adjoint back through the path-space gradient
//! ([`CovarianceGradient`]), contracted per event, so memory does not depend on the entry count.

use super::bridge::{Differentiable, Pullback};
use super::{CovarianceGradient, Param, Reweighted, ReweightedCovariance};
use crate::math::C64;
use crate::mc::{Plan, StopFlag, Watch, estimate_until, estimate_watched};
use crate::medium::{Medium, PhaseFunction, Scattering};
use crate::speckle::Scene;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// The medium `base` with `params` set to `theta`, and per parameter the factor that turns the
/// gradient the estimators compute into `∂/∂θ`.
///
/// Node values of a tabulated phase function and particle-type shares are *unnormalised*: the
/// table (shares) is renormalised after all of them are set, and the estimators' derivative (taken
/// with the normalisation kept, at unit total) is divided by the total `Z` (`W`), which is the exact
/// derivative with respect to an unnormalised value.
pub fn medium_at(
    base: &Medium,
    params: &[Param],
    theta: &[f64],
) -> crate::Result<(Medium, Vec<f64>)> {
    if params.len() != theta.len() {
        return Err(format!(
            "{} parameter values for {} parameters",
            theta.len(),
            params.len()
        )
        .into());
    }
    let mut m = base.clone();
    let mut factor = vec![1.0; params.len()];
    let comps = base.scattering.components();
    let mut weights: Vec<f64> = comps.iter().map(|c| c.0).collect();
    let mut phases: Vec<PhaseFunction> = comps.iter().map(|c| c.1.clone()).collect();
    let mut node_values: Vec<Option<Vec<f64>>> = vec![None; comps.len()];
    // vMF-mixture lobes (weights, concentrations) being set, per component
    let mut vmf_lobes: Vec<Option<(Vec<f64>, Vec<f64>)>> = vec![None; comps.len()];
    for (p, &v) in params.iter().zip(theta) {
        let bad = |allowed: &str| {
            Err(crate::Error::input(format!(
                "{} = {v}: must be {allowed}",
                p.name()
            )))
        };
        if p.get(base).is_none() {
            return Err(format!("parameter {} does not exist in this medium", p.name()).into());
        }
        match *p {
            Param::SigmaS if !(v > 0.0 && v.is_finite()) => return bad("> 0"),
            Param::SigmaS => m.sigma_s = v,
            Param::SigmaA if !(v >= 0.0 && v.is_finite()) => return bad(">= 0"),
            Param::SigmaA => m.sigma_a = v,
            Param::G(_) if v.is_nan() || v.abs() >= 1.0 => return bad("within (-1, 1)"),
            Param::G(c) => phases[c] = PhaseFunction::HenyeyGreenstein { g: v },
            Param::Weight(_) if !(v > 0.0 && v.is_finite()) => return bad("> 0"),
            Param::Weight(c) => weights[c] = v,
            Param::VmfWeight(..) if !(v > 0.0 && v.is_finite()) => return bad("> 0"),
            Param::VmfKappa(..) if !(v.is_finite() && v.abs() <= 1e5) => {
                return bad("within [-1e5, 1e5]");
            }
            Param::VmfWeight(c, l) | Param::VmfKappa(c, l) => {
                let PhaseFunction::VmfMixture(x) = &comps[c].1 else {
                    unreachable!("Param::get checked the component is a vMF mixture")
                };
                let (w, k) = vmf_lobes[c].get_or_insert_with(|| x.lobes().iter().copied().unzip());
                if matches!(p, Param::VmfWeight(..)) {
                    w[l] = v;
                } else {
                    k[l] = v;
                }
            }
            Param::Bin(c, k) => {
                let PhaseFunction::Tabulated(t) = &comps[c].1 else {
                    unreachable!("Param::get checked the component is tabulated")
                };
                node_values[c].get_or_insert_with(|| t.nodes().1.to_vec())[k] = v;
            }
        }
    }
    for (c, values) in node_values.iter().enumerate() {
        if let (Some(values), PhaseFunction::Tabulated(t)) = (values, &comps[c].1) {
            let table = t
                .with_node_values(values)
                .map_err(|e| format!("phase-function node values: {e}"))?;
            let z = t.integral(values);
            for (p, f) in params.iter().zip(factor.iter_mut()) {
                if matches!(p, Param::Bin(pc, _) if *pc == c) {
                    *f = 1.0 / z;
                }
            }
            phases[c] = PhaseFunction::Tabulated(table);
        }
    }
    for (c, lobes) in vmf_lobes.iter().enumerate() {
        if let Some((w, k)) = lobes {
            let mixture = crate::medium::lobes::VmfMixture::new(w, k)
                .map_err(|e| crate::Error::input(format!("vMF-mixture lobes: {e}")))?;
            // the gradient is taken at the normalised weights; s is invariant to their scale, so
            // the derivative at the unnormalised ones is 1/scale of it
            let scale = w[0] / mixture.lobes()[0].0;
            for (p, f) in params.iter().zip(factor.iter_mut()) {
                if matches!(p, Param::VmfWeight(pc, _) if *pc == c) {
                    *f = 1.0 / scale;
                }
            }
            phases[c] = PhaseFunction::VmfMixture(mixture);
        }
    }
    let total: f64 = weights.iter().sum();
    for (p, f) in params.iter().zip(factor.iter_mut()) {
        if matches!(p, Param::Weight(_)) {
            *f = 1.0 / total;
        }
    }
    m.scattering = Scattering::mixture(weights.into_iter().zip(phases).collect());
    Ok((m, factor))
}

/// Where each evaluation's paths come from.
#[derive(Clone, Debug)]
pub enum Proposal {
    /// From the medium at `θ` itself, with a fresh seed per evaluation: unbiased stochastic
    /// gradients of `E[C](θ)`, as stochastic optimisers (Adam) expect.
    AtTheta,
    /// From a fixed medium with a fixed seed: a deterministic objective, smooth in `θ`, whose
    /// gradient is exact for it (common random numbers).
    Fixed(Medium),
}

/// `θ ↦ (Re C_e, Im C_e)` for chosen entries `e = (a, b)` of the covariance of the (light, view)
/// `pairs` (Algorithm 1 of paper 001 with re-weighted paths), with its path-space pullback.
pub struct CovarianceOp {
    pub scene: Scene,
    pub params: Vec<Param>,
    pub pairs: Vec<(usize, usize)>,
    /// `(a, b)` indices into `pairs`: output `2e` is `Re C_ab`, `2e + 1` is `Im C_ab`.
    pub entries: Vec<(usize, usize)>,
    pub reversed: bool,
    pub samples: u64,
    pub chunk: u64,
    pub seed: u64,
    pub proposal: Proposal,
    /// Stops every forward and pullback of this operation once set (none from [`Self::new`]).
    pub stop: StopFlag,
    evaluations: AtomicU64,
}

/// The covariance entries of one evaluation with their standard errors.
#[derive(Clone, Debug)]
pub struct Entries {
    pub value: Vec<C64>,
    pub stderr: Vec<f64>,
}

impl CovarianceOp {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        scene: Scene,
        params: Vec<Param>,
        pairs: Vec<(usize, usize)>,
        entries: Vec<(usize, usize)>,
        reversed: bool,
        (samples, chunk, seed): (u64, u64, u64),
        proposal: Proposal,
    ) -> crate::Result<Self> {
        if let Some(&(a, b)) = entries
            .iter()
            .find(|(a, b)| *a >= pairs.len() || *b >= pairs.len())
        {
            return Err(format!(
                "covariance entry ({a}, {b}) is outside the {} (light, view) pairs",
                pairs.len()
            )
            .into());
        }
        Ok(CovarianceOp {
            scene,
            params,
            pairs,
            entries,
            reversed,
            samples,
            chunk,
            seed,
            proposal,
            stop: StopFlag::default(),
            evaluations: AtomicU64::new(0),
        })
    }

    /// How many evaluations have been made (each `AtTheta` evaluation uses the next seed).
    pub fn evaluations(&self) -> u64 {
        self.evaluations.load(Ordering::Relaxed)
    }

    /// Continue as if `evaluations` had been made: the next `AtTheta` evaluation draws its paths
    /// with `seed + evaluations` (a resumed fit picks up its seeds where it stopped).
    pub fn seek(&self, evaluations: u64) {
        self.evaluations.store(evaluations, Ordering::Relaxed);
    }

    fn prepare(&self, theta: &[f64]) -> crate::Result<CovarianceEvaluation> {
        let (target, factor) = medium_at(&self.scene.medium, &self.params, theta)?;
        let n = self.evaluations.fetch_add(1, Ordering::Relaxed);
        let (proposal, seed) = match &self.proposal {
            Proposal::AtTheta => (target.clone(), self.seed.wrapping_add(n)),
            Proposal::Fixed(m) => (m.clone(), self.seed),
        };
        let e = CovarianceEvaluation {
            proposal: Scene {
                medium: proposal,
                ..self.scene.clone()
            },
            target,
            factor,
            params: self.params.clone(),
            pairs: self.pairs.clone(),
            entries: self.entries.clone(),
            reversed: self.reversed,
            plan: Plan::new(seed, self.samples, self.chunk),
            stop: self.stop.clone(),
        };
        // validate once here, so the pullback cannot meet an error the forward did not report
        e.reweighted(e.params.clone())?;
        Ok(e)
    }

    /// The entries at `θ` with their standard errors and the evaluation, whose
    /// [`CovarianceEvaluation::pullback_until`] gives the VJP (one forward pass for both),
    /// observed through `watch` (chunks done; a stop with [`crate::Error::Interrupted`]).
    /// `afford` sees the estimator and its plan before any path is traced and may refuse the run
    /// (a time or memory budget).
    pub fn forward_until(
        &self,
        theta: &[f64],
        watch: &Watch,
        afford: &dyn Fn(&ReweightedCovariance<'_>, &Plan) -> crate::Result<()>,
    ) -> crate::Result<(Entries, CovarianceEvaluation)> {
        let e = self.prepare(theta)?;
        afford(&ReweightedCovariance(e.reweighted(vec![])?), &e.plan)?;
        let entries = e.entries(Some(watch))?;
        Ok((entries, e))
    }

    /// The entries at `θ` with their standard errors (one evaluation, no pullback).
    pub fn evaluate(&self, theta: &[f64]) -> crate::Result<Entries> {
        self.prepare(theta).and_then(|e| e.entries(None))
    }
}

/// One evaluation of a [`CovarianceOp`]: everything its pullback needs, owned.
pub struct CovarianceEvaluation {
    proposal: Scene,
    target: Medium,
    factor: Vec<f64>,
    params: Vec<Param>,
    pairs: Vec<(usize, usize)>,
    entries: Vec<(usize, usize)>,
    reversed: bool,
    plan: Plan,
    stop: StopFlag,
}

impl CovarianceEvaluation {
    /// The evaluation's plan of `est`, observed through `watch` if given, else stopped by the
    /// operation's flag.
    fn estimate<E: crate::mc::Estimator>(
        &self,
        est: &E,
        watch: Option<&Watch>,
    ) -> crate::Result<crate::mc::Estimate> {
        match watch {
            Some(w) => estimate_watched(est, &self.plan, w),
            None => estimate_until(est, &self.plan, self.stop.get()),
        }
    }

    fn reweighted(&self, params: Vec<Param>) -> crate::Result<Reweighted<'_>> {
        Reweighted::new(
            &self.proposal,
            self.target.clone(),
            self.pairs.clone(),
            self.reversed,
            params,
        )
    }

    fn entries(&self, watch: Option<&Watch>) -> crate::Result<Entries> {
        let est = self.estimate(&ReweightedCovariance(self.reweighted(vec![])?), watch)?;
        let j = self.pairs.len();
        Ok(Entries {
            value: self
                .entries
                .iter()
                .map(|(a, b)| est.mean[a * j + b])
                .collect(),
            stderr: self
                .entries
                .iter()
                .map(|(a, b)| est.stderr[a * j + b])
                .collect(),
        })
    }
}

impl CovarianceEvaluation {
    /// `∂L/∂θ` from `dy` (`∂L/∂Re C_e`, `∂L/∂Im C_e` interleaved per entry), observed through
    /// `watch` if given (chunks done; a stop with [`crate::Error::Interrupted`]).
    pub fn pullback_until(&self, dy: &[f64], watch: Option<&Watch>) -> crate::Result<Vec<f64>> {
        if dy.len() != 2 * self.entries.len() {
            return Err(format!(
                "{} adjoint values for {} complex entries",
                dy.len(),
                self.entries.len()
            )
            .into());
        }
        let j = self.pairs.len();
        let mut adjoint = vec![C64::default(); j * j];
        for (e, (a, b)) in self.entries.iter().enumerate() {
            adjoint[a * j + b] += C64::new(dy[2 * e], dy[2 * e + 1]);
        }
        let est = CovarianceGradient::new(self.reweighted(self.params.clone())?, &adjoint);
        let g = self.estimate(&est, watch)?;
        Ok(g.mean
            .iter()
            .zip(&self.factor)
            .map(|(g, f)| g.re * f)
            .collect())
    }
}

impl Pullback for CovarianceEvaluation {
    fn pullback(&self, dy: &[f64]) -> Vec<f64> {
        // `prepare` built the same estimator successfully, so only a wrong `dy` length or the
        // operation's stop flag fails (the caller checks the flag)
        self.pullback_until(dy, None)
            .unwrap_or_else(|_| vec![f64::NAN; self.params.len()])
    }
}

impl Differentiable for CovarianceOp {
    fn forward(&self, theta: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
        let e = self.prepare(theta)?;
        let y = e
            .entries(None)?
            .value
            .iter()
            .flat_map(|z| [z.re, z.im])
            .collect();
        Ok((y, Arc::new(e)))
    }
}

/// `θ ↦ (Re m, Im m)` of the speckle mean for chosen (light, view) pairs (closed form, paper 001
/// Eqs. 20, 47–48), with its analytic pullback ([`crate::speckle::mean::mean_field_gradient`]).
pub struct MeanOp {
    pub scene: Scene,
    pub params: Vec<Param>,
    /// `(light, view)` indices: output `2e` is `Re m`, `2e + 1` is `Im m`.
    pub pairs: Vec<(usize, usize)>,
}

struct MeanPullback {
    /// `∂(Re m_e, Im m_e)/∂θ_p`, scaled to unnormalised parameters.
    jacobian: Vec<Vec<C64>>,
}

impl Pullback for MeanPullback {
    fn pullback(&self, dy: &[f64]) -> Vec<f64> {
        let np = self.jacobian.first().map_or(0, Vec::len);
        (0..np)
            .map(|p| {
                self.jacobian
                    .iter()
                    .enumerate()
                    .map(|(e, row)| dy[2 * e] * row[p].re + dy[2 * e + 1] * row[p].im)
                    .sum()
            })
            .collect()
    }
}

impl Differentiable for MeanOp {
    fn forward(&self, theta: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
        let (medium, factor) = medium_at(&self.scene.medium, &self.params, theta)?;
        let scene = Scene {
            medium,
            ..self.scene.clone()
        };
        let (mut y, mut jacobian) = (Vec::new(), Vec::new());
        for &(l, v) in &self.pairs {
            let (light, view) = match (scene.lights.get(l), scene.views.get(v)) {
                (Some(a), Some(b)) => (a, b),
                _ => {
                    return Err(
                        format!("mean of light {l}, view {v}: no such light or view").into(),
                    );
                }
            };
            let (m, g) =
                crate::speckle::mean::mean_field_gradient(&scene, light, view, &self.params);
            y.extend([m.re, m.im]);
            jacobian.push(g.iter().zip(&factor).map(|(g, f)| g * f).collect());
        }
        Ok((y, Arc::new(MeanPullback { jacobian })))
    }
}
