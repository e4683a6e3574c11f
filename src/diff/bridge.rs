//! The burn bridge (ARCHITECTURE.md, Derivatives): a lightpath estimator as a burn autodiff operation
//! whose backward pass is our own gradient (path-space gradients, adjoint ray equations).
//!
//! Users write losses and regularisers in burn tensors and optimise with burn's optimisers (Adam);
//! the physics does not depend on burn. An operation maps a parameter vector `θ` (a 1-D `f64`
//! tensor) to an output vector `y`; its backward receives `∂L/∂y` and returns `∂L/∂θ` through a
//! [`Pullback`] made by the very forward evaluation it belongs to (same random numbers), so the
//! gradient is exact for the value the loss saw.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::{Autodiff, Flex};
use burn::tensor::{DType, Device, Tensor, TensorData};
use std::sync::Arc;

/// A function `θ ↦ y` with a vector–Jacobian product: what the bridge needs of an estimator.
pub trait Differentiable: Send + Sync {
    /// Evaluate at `θ`. The pullback maps `∂L/∂y` to `∂L/∂θ` for this evaluation.
    fn forward(&self, theta: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)>;
}

/// The reverse-mode half of one evaluation of a [`Differentiable`].
pub trait Pullback: Send + Sync {
    /// `∂L/∂θ` from `∂L/∂y`.
    fn pullback(&self, dy: &[f64]) -> Vec<f64>;
}

/// The CPU device with reverse-mode autodiff (burn's pure-Rust `Flex` backend).
pub fn device() -> Device {
    Device::flex().autodiff()
}

/// A 1-D `f64` tensor on `device`.
pub fn tensor(values: &[f64], device: &Device) -> Tensor<1> {
    Tensor::from_data(
        TensorData::new(values.to_vec(), [values.len()]),
        (device, DType::F64),
    )
}

/// The values of a 1-D tensor as `f64`.
pub fn values(t: &Tensor<1>) -> Vec<f64> {
    t.to_data().iter::<f64>().collect()
}

/// `y = op(θ)` as a burn operation: tracked on an autodiff device (backward = the op's pullback),
/// a plain evaluation elsewhere.
pub fn apply(op: &dyn Differentiable, theta: Tensor<1>) -> crate::Result<Tensor<1>> {
    let x = values(&theta);
    let (y, pullback) = op.forward(&x)?;
    let inner = tensor(&y, &Device::flex());
    let prim = match theta.clone().try_into_primitive::<Autodiff<Flex>>() {
        Ok(p) => p,
        // not on an autodiff device: nothing to record
        Err(_) => return Ok(tensor(&y, &theta.device())),
    };
    let out = inner
        .try_into_primitive::<Flex>()
        .map_err(|e| format!("burn bridge: {e:?}"))?;
    let tracked = match PullbackStep
        .prepare::<NoCheckpointing>([prim.node()])
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => prep.finish(State(pullback, x.len()), out),
        OpsKind::UnTracked(prep) => prep.finish(out),
    };
    Ok(Tensor::from_primitive::<Autodiff<Flex>>(tracked))
}

/// The backward state: the evaluation's pullback and the input length.
#[derive(Clone)]
struct State(Arc<dyn Pullback>, usize);

impl std::fmt::Debug for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "lightpath pullback ({} inputs)", self.1)
    }
}

#[derive(Debug)]
struct PullbackStep;

impl Backward<Flex, 1> for PullbackStep {
    type State = State;

    fn backward(self, ops: Ops<State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let State(pullback, n) = ops.state;
        unary::<Flex, _>(ops.parents, ops.node, grads, |dy| {
            let dy = Tensor::<1>::from_primitive::<Flex>(dy);
            let device = dy.device();
            let mut dx = pullback.pullback(&values(&dy));
            // a pullback returns one value per input; anything else is a bug, surfaced as NaN
            dx.resize(n, f64::NAN);
            tensor(&dx, &device)
                .try_into_primitive::<Flex>()
                .unwrap_or_else(|_| unreachable!("a Flex tensor converts to its primitive"))
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `y = (θ0² + θ1, θ0 θ1)` with its exact pullback.
    struct Quadratic;
    struct QuadraticPullback(Vec<f64>);
    impl Pullback for QuadraticPullback {
        fn pullback(&self, g: &[f64]) -> Vec<f64> {
            let x = &self.0;
            vec![2.0 * x[0] * g[0] + x[1] * g[1], g[0] + x[0] * g[1]]
        }
    }
    impl Differentiable for Quadratic {
        fn forward(&self, x: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
            Ok((
                vec![x[0] * x[0] + x[1], x[0] * x[1]],
                Arc::new(QuadraticPullback(x.to_vec())),
            ))
        }
    }

    /// Catches a bridge that drops, transposes or double-counts the custom backward when it is
    /// composed with ordinary burn operations on both sides.
    #[test]
    fn custom_backward_composes_with_burn_ops() {
        let dev = device();
        let x = tensor(&[1.5, -0.5], &dev).require_grad();
        let y = apply(&Quadratic, x.clone() * 1.0).unwrap();
        let loss = (y.clone() * y).sum() + x.clone().exp().sum();
        let g = values(&x.grad(&loss.backward()).unwrap());
        // L = (x0² + x1)² + (x0 x1)² + e^x0 + e^x1
        let (a, b) = (1.5f64, -0.5f64);
        let want = [
            2.0 * (a * a + b) * 2.0 * a + 2.0 * a * b * b + a.exp(),
            2.0 * (a * a + b) + 2.0 * a * a * b + b.exp(),
        ];
        for (g, w) in g.iter().zip(want) {
            assert!((g - w).abs() < 1e-12, "{g} vs {w}");
        }
    }

    #[test]
    fn plain_device_evaluates_without_tracking() {
        let y = apply(&Quadratic, tensor(&[2.0, 3.0], &Device::flex())).unwrap();
        assert_eq!(values(&y), vec![7.0, 6.0]);
    }
}
