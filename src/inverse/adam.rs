//! The one Adam driver (burn's Adam over one vector of variables) for losses written in burn
//! tensors, and the plateau rule that says whether a run of fixed length converged.

use crate::diff::bridge::{device, tensor, values};
use burn::module::{Module, Param as Variable};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Tensor;

#[derive(Module, Debug)]
struct Variables {
    x: Variable<Tensor<1>>,
}

/// One iteration as the observer sees it: the variables before the step, the norm of the loss
/// gradient there, and what the loss closure returned for observation.
pub struct Iterate<'a, O> {
    pub iteration: usize,
    pub x: &'a [f64],
    pub grad_norm: f64,
    pub observed: O,
}

/// Minimise from `x0` for `iterations` Adam steps of size `learning_rate(iteration)`. `loss(it, x)`
/// builds the loss at `x` in burn tensors and returns it with what the observer should see;
/// `observe` sees every iteration and may stop the run with an error (e.g. a non-finite loss).
/// Returns the variables after the last step.
pub fn minimise<O>(
    x0: &[f64],
    iterations: usize,
    learning_rate: &dyn Fn(usize) -> f64,
    loss: &mut dyn FnMut(usize, Tensor<1>) -> crate::Result<(Tensor<1>, O)>,
    observe: &mut dyn FnMut(Iterate<'_, O>) -> crate::Result<()>,
) -> crate::Result<Vec<f64>> {
    let mut vars = Variables {
        x: Variable::from_tensor(tensor(x0, &device())),
    };
    let mut optimiser = AdamConfig::new().init();
    for iteration in 0..iterations {
        let x = vars.x.val();
        let (total, observed) = loss(iteration, x.clone())?;
        let grads = total.backward();
        let g = x.grad(&grads).map(|g| values(&g)).unwrap_or_default();
        let grad_norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
        observe(Iterate {
            iteration,
            x: &values(&x),
            grad_norm,
            observed,
        })?;
        let gp = GradientsParams::from_grads(grads, &vars);
        vars = optimiser.step(learning_rate(iteration), vars, gp);
    }
    Ok(values(&vars.x.val()))
}

/// Whether a fixed-length run's loss has stopped decreasing: the mean over the last third is lower
/// than over the third before by at most 1 % of the whole run's decrease (its largest loss minus the
/// last third's mean) plus twice the standard error of the difference (the losses of stochastic
/// iterations scatter). Needs at least 6 losses.
pub fn plateaued(losses: &[f64]) -> bool {
    let n = losses.len() / 3;
    if n < 2 {
        return false;
    }
    let stats = |s: &[f64]| {
        let m = s.iter().sum::<f64>() / s.len() as f64;
        let v = s.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (s.len() as f64 - 1.0);
        (m, v / s.len() as f64)
    };
    let (before, v1) = stats(&losses[losses.len() - 2 * n..losses.len() - n]);
    let (last, v2) = stats(&losses[losses.len() - n..]);
    let top = losses.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    before - last <= 0.01 * (top - last).abs() + 2.0 * (v1 + v2).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quadratic bowl reaches its minimum, the observer sees every iteration, and the plateau rule
    /// tells a still-falling loss from a flat one.
    #[test]
    fn quadratic_and_plateau() {
        let target = [1.0, -2.0, 0.5];
        let mut seen = Vec::new();
        let x = minimise(
            &[0.0; 3],
            400,
            &|_| 0.05,
            &mut |_, x| {
                let d = x - tensor(&target, &device());
                let l = (d.clone() * d).sum().reshape([1]);
                let v = values(&l)[0];
                Ok((l, v))
            },
            &mut |it| {
                seen.push(it.observed);
                Ok(())
            },
        )
        .unwrap();
        assert_eq!(seen.len(), 400);
        for (a, b) in x.iter().zip(&target) {
            assert!((a - b).abs() < 1e-3, "{x:?}");
        }
        assert!(plateaued(&seen));
        assert!(!plateaued(&seen[..30]), "still falling: {:?}", &seen[..30]);
    }
}
