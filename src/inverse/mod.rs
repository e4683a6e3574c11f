//! Inverse problems, named by what they fit, and the two drivers they share.
//!
//! - [`material_fit`]: speckle medium parameters (mfp, albedo, g, σ_s, σ_a) by L-BFGS in an adaptive
//!   trust region on re-weighted paths, with Gauss–Newton uncertainties;
//! - [`phase_fit`]: tabulated phase functions (and scalars) by Adam through the burn bridge;
//! - [`grin_fit`]: analytic index-field parameters by L-BFGS on the exit adjoint;
//! - [`grin_design`]: grid index fields by Adam through the ray-tracing operation;
//! - [`lbfgs`], [`adam`]: the drivers (the loop, bounds, stopping rules, observers);
//! - [`target`]: what fits are fitted to, the losses and their adjoints; [`shortcut`]: the
//!   single-scattering reading of paper 004 from correlation targets; [`phase_from_speckle`]: the
//!   same reading from camera images (windowed correlations, error bars, HG and vMF fits).
//!
//! Every fit reports a [`Convergence`]: whether it converged, why it stopped, the final gradient norm
//! and the number of evaluations.

pub mod adam;
pub mod grin_design;
pub mod grin_fit;
pub mod journal;
pub mod lbfgs;
pub mod material_fit;
pub mod phase_fit;
pub mod phase_from_speckle;
pub mod render_design;
pub mod shortcut;
pub mod target;

pub use crate::medium::params::{FitParam, check_params, medium_with};
pub use material_fit::{Fit, FitResult, FitSettings};
pub use phase_fit::{AdamFit, AdamResult, AdamSettings};
pub use target::{Entry, Measured, Target};

use serde::{Deserialize, Serialize};

/// One logged evaluation of a speckle fit (an L-BFGS evaluation in stage `stage`, or Adam
/// iteration `stage`).
#[derive(Clone, Debug)]
pub struct LogEntry {
    pub stage: usize,
    pub loss: f64,
    pub params: Vec<f64>,
    pub grad_norm: f64,
}

/// Why a fit stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FitStop {
    /// The gradient vanished (below tolerance).
    GradientTolerance,
    /// The step left to the optimum (Gauss–Newton, inside the trust region) is below tolerance.
    StepTolerance,
    /// The loss no longer changed between iterations.
    CostChange,
    /// The loss stopped decreasing beyond its noise (Adam: last third vs the third before it).
    LossPlateau,
    /// The iteration limit was reached first.
    IterationLimit,
    /// The stage limit was reached first (raise `--stages`).
    StageLimit,
    /// The trust region shrank to nothing: no step was confirmed by fresh paths.
    TrustRegion,
    /// The line search found no acceptable step.
    LineSearch,
}

impl FitStop {
    pub fn converged(self) -> bool {
        matches!(
            self,
            FitStop::GradientTolerance
                | FitStop::StepTolerance
                | FitStop::CostChange
                | FitStop::LossPlateau
        )
    }

    pub fn describe(self) -> &'static str {
        match self {
            FitStop::GradientTolerance => "the gradient vanished",
            FitStop::StepTolerance => "the step left is below tolerance",
            FitStop::CostChange => "the loss no longer changed",
            FitStop::LossPlateau => "the loss reached a plateau",
            FitStop::IterationLimit => {
                "the iteration limit was reached (raise it: `lightpath fit --iterations`, or `iterations` of the config's [design] or [parameters] table)"
            }
            FitStop::StageLimit => "the stage limit was reached (raise --stages)",
            FitStop::TrustRegion => {
                "no step could be confirmed with fresh paths (the trust region collapsed; more --samples help)"
            }
            FitStop::LineSearch => "the line search found no acceptable step",
        }
    }
}

impl From<&lbfgs::Stop> for FitStop {
    fn from(s: &lbfgs::Stop) -> Self {
        match s {
            lbfgs::Stop::GradientTolerance => FitStop::GradientTolerance,
            lbfgs::Stop::CostChange => FitStop::CostChange,
            lbfgs::Stop::IterationLimit => FitStop::IterationLimit,
            lbfgs::Stop::LineSearch(_) => FitStop::LineSearch,
        }
    }
}

/// How a fit ended; written to every `fit.json` and `design.json`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Convergence {
    pub converged: bool,
    /// Why it stopped.
    pub stop: FitStop,
    /// Norm of the loss gradient at the result (in the variables the optimiser moved).
    pub grad_norm: f64,
    /// Loss (and gradient) evaluations.
    pub evaluations: usize,
    /// Stages (material fit), iterations (L-BFGS, Adam).
    pub iterations: usize,
}

impl Convergence {
    /// One line for summaries: `converged (why), N evaluations` or `NOT converged (why), …`.
    pub fn line(&self) -> String {
        format!(
            "{} ({}), {} evaluations, |gradient| {:.3e}",
            if self.converged {
                "converged"
            } else {
                "NOT converged"
            },
            self.stop.describe(),
            self.evaluations,
            self.grad_norm
        )
    }

    /// The warning a user sees when the fit did not converge.
    pub fn warning(&self) -> Option<String> {
        (!self.converged).then(|| {
            format!(
                "warning: the fit did NOT converge: {} after {} evaluations (|gradient| = {:.3e}); the values and uncertainties are not an optimum",
                self.stop.describe(),
                self.evaluations,
                self.grad_norm
            )
        })
    }
}

/// `(JᵀJ)⁻¹ × scale`: the Gauss–Newton covariance of the parameters.
pub(crate) fn covariance_matrix(jac: &[Vec<f64>], scale: f64) -> faer::Mat<f64> {
    use faer::linalg::solvers::Solve;
    let p = jac.first().map_or(0, |r| r.len());
    let jtj = faer::Mat::<f64>::from_fn(p, p, |a, b| jac.iter().map(|r| r[a] * r[b]).sum());
    let id = faer::Mat::<f64>::identity(p, p);
    jtj.partial_piv_lu().solve(&id) * faer::Scale(scale)
}

/// Standard deviations and correlations of a parameter covariance matrix (NaN correlations where
/// it is singular: not identifiable).
pub(crate) fn standard_deviations(cov: &faer::Mat<f64>) -> (Vec<f64>, Vec<Vec<f64>>) {
    let p = cov.nrows();
    let sd: Vec<f64> = (0..p).map(|a| cov[(a, a)].max(0.0).sqrt()).collect();
    let corr = (0..p)
        .map(|a| {
            (0..p)
                .map(|b| cov[(a, b)] / (cov[(a, a)] * cov[(b, b)]).sqrt())
                .collect()
        })
        .collect();
    (sd, corr)
}

/// How every fit's model statistics are rendered: paths per evaluation, paths per chunk, seed, and
/// whether reversed paths (coherent backscattering) are included.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelSettings {
    pub samples: u64,
    pub chunk: u64,
    pub seed: u64,
    pub reversed: bool,
}

impl ModelSettings {
    /// The engine's plan of one evaluation.
    pub fn plan(&self) -> crate::mc::Plan {
        crate::mc::Plan::new(self.seed, self.samples, self.chunk)
    }
}

/// The model covariance of `target`'s pairs for `medium`, re-weighted from paths of `proposal`,
/// with the per-chunk means of the outputs the target keeps (for its model errors).
pub(crate) fn model_with_chunks(
    proposal: &crate::speckle::Scene,
    medium: crate::medium::Medium,
    target: &Target,
    scene: &crate::speckle::Scene,
    model: &ModelSettings,
    stop: &crate::mc::StopFlag,
) -> crate::Result<(crate::mc::Estimate, Vec<crate::math::C64>)> {
    use crate::diff::{Reweighted, ReweightedCovariance};
    use crate::mc::{Estimate, merge, run};
    let r = Reweighted::new(
        proposal,
        medium,
        target.pairs(scene),
        model.reversed,
        vec![],
    )?;
    let plan = model.plan();
    stop.check()?;
    let root = merge(
        run(
            &ReweightedCovariance(r),
            &plan,
            0..plan.chunks,
            &target.keep(),
            &|_| {},
        ),
        plan.chunks,
    )?;
    Ok((Estimate::from_block(&root, &plan), root.kept))
}
