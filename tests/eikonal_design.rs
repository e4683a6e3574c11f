//! Graded-index design through the burn bridge (issue #5): tracing as a burn operation whose
//! backward is the constant-memory adjoint over every grid coefficient.

use burn::module::{Module, Param as Variable};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Tensor;
use glam::DVec3;
use lightpath::diff::bridge::{apply, device, tensor, values};
use lightpath::eikonal::grid::{GridField, Interp};
use lightpath::eikonal::{BoundedField, Bounds, IndexField, Profile, Ray, TraceOp};

fn grid(interp: Interp, n_of: impl Fn(DVec3) -> f64) -> GridField {
    let dims = [8, 8, 10];
    let (origin, spacing) = (DVec3::new(-1.75, -1.75, -0.5), 0.5);
    let mut samples = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                samples.push(n_of(
                    origin + DVec3::new(i as f64, j as f64, k as f64) * spacing,
                ));
            }
        }
    }
    GridField::from_samples(origin, spacing, dims, samples, interp).unwrap()
}

/// A collimated bundle along z (started inside cells, off the faces).
fn op(g: GridField, steps: usize) -> TraceOp {
    let field = BoundedField::single(Profile::Grid(g), Bounds::Everywhere, 1.0);
    let rays = (0..9)
        .map(|i| {
            let x = DVec3::new(
                -0.61 + 0.15 * (i % 3) as f64 * 4.0,
                -0.43 + 0.41 * (i / 3) as f64,
                0.013,
            );
            Ray {
                x,
                v: DVec3::Z * field.n(x),
            }
        })
        .collect();
    TraceOp {
        field,
        profile: 0,
        rays,
        steps,
        step: 0.01,
    }
}

/// Transverse spread at the end plus a small pull on the final directions: a loss on positions and
/// velocities, so both halves of the adjoint seed are exercised.
fn loss(y: Tensor<1>) -> Tensor<1> {
    let n = y.dims()[0];
    let mask: Vec<f64> = (0..n)
        .map(|i| match i % 6 {
            0 | 1 => 1.0,
            3 | 4 => 0.3,
            _ => 0.0,
        })
        .collect();
    (y.clone() * y * tensor(&mask, &device())).sum()
}

/// Would catch a wrong sparse accumulation (taps, scaling by the spacing), a dropped velocity seed,
/// or a bridge that mixes rays up. Fixed steps make the map smooth: central differences agree to
/// their O(h²) truncation, 1e-5 relative, on coefficients the rays pass.
#[test]
fn trace_op_gradient_matches_finite_differences() {
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let g = grid(interp, |p| {
            1.5 - 0.05 * (p.x * p.x + p.y * p.y) + 0.01 * p.z
        });
        let op = op(g.clone(), 250);
        let dev = device();
        let c = tensor(&g.coef, &dev).require_grad();
        let l = loss(apply(&op, c.clone()).unwrap());
        let grad = values(&c.grad(&l.backward()).unwrap());
        let at = |coef: &[f64]| values(&loss(apply(&op, tensor(coef, &dev)).unwrap()))[0];
        let mut order: Vec<usize> = (0..grad.len()).collect();
        order.sort_by(|a, b| grad[*b].abs().total_cmp(&grad[*a].abs()));
        for &i in order.iter().take(6) {
            let h = 1e-6;
            let (mut up, mut down) = (g.coef.clone(), g.coef.clone());
            up[i] += h;
            down[i] -= h;
            let fd = (at(&up) - at(&down)) / (2.0 * h);
            eprintln!(
                "{interp:?} coefficient {i}: bridge {:.8e}, finite difference {fd:.8e}",
                grad[i]
            );
            assert!(
                (grad[i] - fd).abs() <= 1e-5 * fd.abs().max(1e-6),
                "{interp:?} coefficient {i}: {} vs {fd}",
                grad[i]
            );
        }
        assert!(
            grad[order[0]].abs() > 1e-3,
            "the rays must depend on the grid"
        );
    }
}

#[derive(Module, Debug)]
struct Field {
    c: Variable<Tensor<1>>,
}

/// A small design run: burn's Adam shapes a uniform 8×8×10 grid so a collimated bundle converges
/// on the axis at the end plane, with a burn-side penalty keeping the coefficients near 1.5. Would
/// catch a backward that does not descend (sign, scaling, stale state between iterations).
#[test]
fn adam_designs_a_converging_lens() {
    let g = grid(Interp::Tricubic, |_| 1.5);
    let c0 = g.coef.clone();
    let op = op(g, 250);
    let dev = device();
    let reference = tensor(&c0, &dev);
    let mut field = Field {
        c: Variable::from_tensor(tensor(&c0, &dev)),
    };
    let mut optimiser = AdamConfig::new().init();
    let spread = |c: &[f64]| values(&loss(apply(&op, tensor(c, &device())).unwrap()))[0];
    let first = spread(&c0);
    for _ in 0..40 {
        let c = field.c.val();
        let d = c.clone() - reference.clone();
        let l = loss(apply(&op, c).unwrap()) + (d.clone() * d).sum() * 0.01;
        let grads = GradientsParams::from_grads(l.backward(), &field);
        field = optimiser.step(0.01, field, grads);
    }
    let last = spread(&values(&field.c.val()));
    eprintln!("spread loss {first:.4e} → {last:.4e}");
    assert!(last < 0.2 * first, "{first} → {last}");
}
