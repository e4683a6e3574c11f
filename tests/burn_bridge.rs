//! The burn bridge: the covariance estimator as a burn autodiff operation whose backward
//! is our path-space gradient. Checked against central finite differences of the same loss with
//! common random numbers, for tabulated phase-function nodes (unnormalised), HG g, σ_s and
//! particle-type shares at once, composed with ordinary burn operations.

use glam::DVec3;
use lightpath::diff::bridge::{apply, device, tensor, values};
use lightpath::diff::{CovarianceOp, Param, Proposal, medium_at};
use lightpath::math::rotate;
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering, Table};
use lightpath::speckle::{Light, Scene, View};

fn scene() -> Scene {
    scene_with(false)
}

/// The bridge's scene; `focused` makes light 0 and view 0 focused lenses (paper 000).
fn scene_with(focused: bool) -> Scene {
    let table = Table::from_rho(None, vec![0.5, 0.7, 1.0, 1.6, 2.8, 5.0]).unwrap();
    let m = Medium {
        geometry: Geometry::boxed([4.0, 4.0, 3.0]),
        sigma_s: 0.5,
        sigma_a: 0.05,
        scattering: Scattering::mixture(vec![
            (0.6, PhaseFunction::Tabulated(table)),
            (0.4, PhaseFunction::HenyeyGreenstein { g: 0.3 }),
        ]),
    };
    let lights = vec![
        Light::PlaneWave {
            direction: DVec3::Z,
        },
        Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::X, 0.05),
        },
    ];
    let views = vec![
        View::FarField {
            direction: rotate(DVec3::Z, DVec3::Y, 0.3),
        },
        View::FarField {
            direction: rotate(rotate(DVec3::Z, DVec3::Y, 0.3), DVec3::X, 0.05),
        },
        View::FarField {
            direction: -DVec3::Z,
        },
    ];
    let mut s = Scene::new(1.0, m, lights, views);
    if focused {
        s.lights[0] = Light::Focused {
            focus: DVec3::new(0.0, 0.0, 1.5),
            axis: DVec3::Z,
            gamma: 1.0 / (0.4 * 0.4),
        };
        s.views[0] = View::Focused {
            focus: DVec3::new(0.3, 0.0, 1.5),
            axis: DVec3::Z,
            gamma: 1.0 / (0.4 * 0.4),
        };
    }
    s
}

fn params() -> Vec<Param> {
    let mut p: Vec<Param> = (0..6).map(|k| Param::Bin(0, k)).collect();
    p.extend([Param::SigmaS, Param::G(1), Param::Weight(1)]);
    p
}

/// Pairs j = l·3 + v; entries: the intensity of (0, 0), the memory-effect entry between light 0 →
/// view 0 and light 1 → view 1, and a backscattering entry.
fn op(proposal: Proposal) -> CovarianceOp {
    op_for(scene(), proposal)
}

fn op_for(s: Scene, proposal: Proposal) -> CovarianceOp {
    let pairs = lightpath::speckle::paths::SubpathSampler::all_pairs(&s);
    CovarianceOp::new(
        s,
        params(),
        pairs,
        vec![(0, 0), (0, 4), (2, 5), (5, 5)],
        true,
        (6000, 500, 11),
        proposal,
    )
    .unwrap()
}

/// The same with a focused light and view: the bridge backward is the focused path-space gradient
/// (lobe weights projected on the proposal's concentrations for the table and g). The steps differ
/// by parameter: the two-lens guard makes the estimate piecewise smooth in σ_t (short steps), and
/// the projection's least squares on nearly equal concentrations rounds at ~1e-10 of the objective
/// (long steps, agreement to 1e-4 for the table's nodes).
#[test]
fn bridge_gradient_with_focused_endpoints_matches_finite_differences() {
    let s = scene_with(true);
    let op = op_for(s.clone(), Proposal::Fixed(s.medium.clone()));
    let (short, long) = (
        bridge_and_finite_differences(&op, 1e-6),
        bridge_and_finite_differences(&op, 1e-4),
    );
    let scale = short.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    for (p, (a, b)) in params().iter().zip(short.into_iter().zip(long)) {
        let ((name, g, fd), tolerance) = if matches!(p, Param::Bin(..)) {
            (b, 1e-4)
        } else {
            (a, 1e-5)
        };
        assert!(
            (g - fd).abs() <= tolerance * fd.abs().max(1e-3 * scale),
            "{name}: {g} vs {fd}"
        );
    }
}

/// A nonlinear loss in burn: Σ w_e y_e² + Σ y_e, so the adjoint differs per entry and component.
fn loss(y: burn::tensor::Tensor<1>) -> burn::tensor::Tensor<1> {
    let n = y.dims()[0];
    let w: Vec<f64> = (0..n).map(|i| 1.0 + 0.37 * i as f64).collect();
    let w = tensor(&w, &y.device());
    (y.clone() * y.clone() * w).sum() + y.sum()
}

/// θ away from the proposal: node values in unnormalised units (×2.5) and perturbed.
fn theta() -> Vec<f64> {
    let base = scene().medium;
    let mut t: Vec<f64> = params().iter().map(|p| p.get(&base).unwrap()).collect();
    for (k, x) in t.iter_mut().take(6).enumerate() {
        *x *= 2.5 * (1.0 + 0.1 * (k as f64 - 2.5) / 2.5);
    }
    t[6] = 0.55;
    t[7] = 0.2;
    t[8] = 0.5;
    t
}

/// Would catch: a wrong normalisation factor for unnormalised nodes or shares, a transposed or
/// conjugated adjoint (entries are complex), a bridge that drops the custom backward, or any
/// factor's derivative being off. With common random numbers the objective is smooth, so only the
/// O(h²) truncation limits agreement: 1e-5 relative.
#[test]
fn bridge_gradient_matches_finite_differences() {
    let op = op(Proposal::Fixed(scene().medium));
    let rows = bridge_and_finite_differences(&op, 1e-6);
    let scale = rows.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    for (name, g, fd) in rows {
        assert!(
            (g - fd).abs() <= 1e-5 * fd.abs().max(1e-3 * scale),
            "{name}: {g} vs {fd}"
        );
    }
}

/// Per parameter: the burn backward of [`loss`] through `op` at [`theta`], and the central
/// difference of the same loss with relative step `rel`.
fn bridge_and_finite_differences(
    op: &dyn lightpath::diff::bridge::Differentiable,
    rel: f64,
) -> Vec<(String, f64, f64)> {
    let dev = device();
    let t = theta();
    let x = tensor(&t, &dev).require_grad();
    let l = loss(apply(op, x.clone()).unwrap());
    let g = values(&x.grad(&l.backward()).unwrap());
    let at = |v: &[f64]| values(&loss(apply(op, tensor(v, &dev)).unwrap()))[0];
    params()
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let h = rel * t[i].abs().max(0.05);
            let (mut up, mut down) = (t.clone(), t.clone());
            up[i] += h;
            down[i] -= h;
            let fd = (at(&up) - at(&down)) / (2.0 * h);
            eprintln!(
                "{}: bridge {:.8e}, finite difference {fd:.8e}",
                p.name(),
                g[i]
            );
            (p.name(), g[i], fd)
        })
        .collect()
}

/// Node values are unnormalised: scaling them all leaves the covariance unchanged, and (Euler) the
/// gradient is orthogonal to them. Would catch a missing or wrong `1/Z` factor.
#[test]
fn node_values_are_scale_free() {
    let op = op(Proposal::Fixed(scene().medium));
    let t = theta();
    let mut scaled = t.clone();
    scaled.iter_mut().take(6).for_each(|x| *x *= 3.0);
    let (a, b) = (op.evaluate(&t).unwrap(), op.evaluate(&scaled).unwrap());
    for (x, y) in a.value.iter().zip(&b.value) {
        assert!((x - y).norm() <= 1e-12 * y.norm().max(1e-300), "{x} vs {y}");
    }
    let dev = device();
    let x = tensor(&t, &dev).require_grad();
    let g = values(
        &x.grad(&loss(apply(&op, x.clone()).unwrap()).backward())
            .unwrap(),
    );
    let euler: f64 = (0..6).map(|k| g[k] * t[k]).sum();
    let size: f64 = (0..6).map(|k| (g[k] * t[k]).abs()).sum();
    assert!(
        euler.abs() <= 1e-9 * size,
        "Σ θ_k ∂L/∂θ_k = {euler} (terms {size})"
    );
}

/// `AtTheta` draws from the medium at θ with a fresh seed per evaluation: its first evaluation
/// equals a fixed proposal at that medium and seed, and the next one differs (new random numbers).
#[test]
fn proposal_at_theta_uses_the_current_medium_and_fresh_seeds() {
    let t = theta();
    let (m, _) = medium_at(&scene().medium, &params(), &t).unwrap();
    let stochastic = op(Proposal::AtTheta);
    let first = stochastic.evaluate(&t).unwrap();
    let second = stochastic.evaluate(&t).unwrap();
    let fixed = op(Proposal::Fixed(m)).evaluate(&t).unwrap();
    assert_eq!(first.value, fixed.value);
    assert_ne!(first.value, second.value);
    // the two independent estimates agree within their errors (|z| < 4 on the intensity)
    let z = (first.value[0] - second.value[0]).re
        / (first.stderr[0].powi(2) + second.stderr[0].powi(2)).sqrt();
    assert!(z.abs() < 4.0, "z = {z}");
    assert_eq!(stochastic.evaluations(), 2);
}

#[test]
fn bad_parameter_values_are_errors() {
    let op = op(Proposal::AtTheta);
    let mut t = theta();
    t[2] = -1.0;
    let e = op.evaluate(&t).unwrap_err().to_string();
    assert!(e.contains("-1"), "{e}");
    let mut t = theta();
    t[7] = 1.2;
    let e = op.evaluate(&t).unwrap_err().to_string();
    assert!(e.contains("g[1] = 1.2") && e.contains("(-1, 1)"), "{e}");
    let e = op.evaluate(&t[..3]).unwrap_err().to_string();
    assert!(e.contains("3 parameter values for 9"), "{e}");
}

/// The speckle mean as a burn operation: its pullback (analytic, with the unnormalised-node and
/// share factors) against central differences of the same burn loss. Deterministic (closed form),
/// so 1e-6 relative.
#[test]
fn mean_op_gradient_matches_finite_differences() {
    use lightpath::diff::MeanOp;
    let op = MeanOp {
        scene: scene(),
        params: params(),
        pairs: vec![(0, 0), (1, 1), (0, 2), (1, 0)],
    };
    let rows = bridge_and_finite_differences(&op, 1e-5);
    let scale = rows.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    for (name, g, fd) in rows {
        assert!(
            (g - fd).abs() <= 1e-6 * fd.abs() + 1e-9 * scale,
            "{name}: {g} vs {fd}"
        );
    }
}
