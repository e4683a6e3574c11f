//! Path-space gradients of the covariance: re-weighting to the proposal reproduces
//! Algorithm 1; every gradient matches central finite differences with common random numbers; and the
//! gradient is unbiased for the gradient of the expectation.

use glam::DVec3;
use lightpath::diff::{CovarianceGradient, Param, Reweighted, ReweightedCovariance};
use lightpath::math::{C64, rotate, stream_rng, uniform};
use lightpath::mc::{Estimate, Estimator, Plan, merge, run};
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering};
use lightpath::speckle::{Covariance, Light, Scene, View};

fn scene(scattering: Scattering, sigma_a: f64) -> Scene {
    let m = Medium {
        geometry: Geometry::boxed([4.0, 5.0, 3.0]),
        sigma_s: 0.45,
        sigma_a,
        scattering,
    };
    let lights = vec![
        Light::PlaneWave {
            direction: DVec3::Z,
        },
        Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::Y, 0.1),
        },
        Light::Point {
            position: DVec3::new(0.5, 0.0, -5.0),
        },
    ];
    let views = vec![
        View::FarField {
            direction: DVec3::new(0.3, 0.0, 1.0).normalize(),
        },
        View::FarField {
            direction: -DVec3::Z,
        },
        View::Point {
            position: DVec3::new(0.0, 4.0, 1.0),
        },
    ];
    Scene::new(1.0, m, lights, views)
}

fn pairs(s: &Scene) -> Vec<(usize, usize)> {
    lightpath::speckle::paths::SubpathSampler::all_pairs(s)
}

fn estimate<E: Estimator>(e: &E, samples: u64, seed: u64) -> Estimate {
    let plan = Plan::new(seed, samples, 500);
    Estimate::from_block(
        &merge(run(e, &plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap(),
        &plan,
    )
}

/// A fixed random Hermitian adjoint, so `L = Re Σ conj(Ā) C` exercises every entry.
fn adjoint(j: usize) -> Vec<C64> {
    let mut rng = stream_rng(123, 0);
    let mut a = vec![C64::default(); j * j];
    for x in a.iter_mut() {
        *x = C64::new(uniform(&mut rng) - 0.5, uniform(&mut rng) - 0.5);
    }
    a
}

fn loss(c: &[C64], adj: &[C64]) -> f64 {
    c.iter().zip(adj).map(|(c, a)| (a.conj() * c).re).sum()
}

#[test]
fn reweighting_at_the_proposal_is_algorithm_1() {
    let s = scene(
        Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.4 }),
        0.1,
    );
    let r = Reweighted::new(&s, s.medium.clone(), pairs(&s), true, vec![]).unwrap();
    let a = estimate(&ReweightedCovariance(r), 20_000, 3);
    let b = estimate(&Covariance::all_pairs(&s, true).unwrap(), 20_000, 3);
    let j2 = 81;
    for i in 0..j2 {
        let (x, y) = (a.mean[i], b.mean[2 * j2 + i]);
        assert!(
            (x - y).norm() <= 1e-9 * y.norm().max(1e-12),
            "entry {i}: {x} vs {y}"
        );
    }
}

/// Central differences of the re-weighted estimate (same paths) against the analytic gradient, for
/// σ_s, σ_a and the g of both components of a Henyey–Greenstein mixture. With fixed random numbers
/// the objective is smooth, so the agreement is limited only by the O(h²) truncation: 1e-5 relative.
#[test]
fn gradients_match_finite_differences() {
    let mix = Scattering::mixture(vec![
        (0.7, PhaseFunction::HenyeyGreenstein { g: 0.6 }),
        (0.3, PhaseFunction::HenyeyGreenstein { g: -0.3 }),
    ]);
    let s = scene(mix, 0.08);
    let params = vec![Param::SigmaS, Param::SigmaA, Param::G(0), Param::G(1)];
    // evaluate away from the proposal, so re-weighting factors are exercised
    let mut target = s.medium.clone();
    for (p, v) in params.iter().zip([0.5, 0.06, 0.55, -0.2]) {
        target = p.set(&target, v);
    }
    let adj = adjoint(9);
    let grad = {
        let r = Reweighted::new(&s, target.clone(), pairs(&s), true, params.clone()).unwrap();
        estimate(&CovarianceGradient::new(r, &adj), 4000, 8)
    };
    for (i, p) in params.iter().enumerate() {
        let v = p.get(&target).unwrap();
        let h = 1e-4 * v.abs().max(0.1);
        let at = |x: f64| {
            let r = Reweighted::new(&s, p.set(&target, x), pairs(&s), true, vec![]).unwrap();
            loss(&estimate(&ReweightedCovariance(r), 4000, 8).mean, &adj)
        };
        let fd = (at(v + h) - at(v - h)) / (2.0 * h);
        let g = grad.mean[i].re;
        eprintln!("{}: gradient {g:.8e}, finite difference {fd:.8e}", p.name());
        assert!(
            (g - fd).abs() < 1e-5 * fd.abs().max(1e-3 * g.abs()) + 1e-12,
            "{}: {g} vs {fd}",
            p.name()
        );
        assert!(g.abs() > 0.0);
    }
}

/// Unbiasedness: the mean of many gradient estimates (paths from the parameters themselves) equals a
/// finite difference of high-sample *standard* estimates at θ ± h (Algorithm 1 with its own sampling
/// at each θ; the same seed keeps the two correlated), within the combined standard errors. h is
/// small enough that the O(h²) bias is below the noise (the HG dependence is strongly curved).
#[test]
fn gradient_is_unbiased() {
    let s = scene(
        Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
        0.05,
    );
    let adj = adjoint(9);
    for (p, h) in [(Param::SigmaS, 0.01), (Param::G(0), 0.01)] {
        let r = Reweighted::new(&s, s.medium.clone(), pairs(&s), true, vec![p]).unwrap();
        let g = estimate(&CovarianceGradient::new(r, &adj), 200_000, 31);
        let v = p.get(&s.medium).unwrap();
        let (sp, sm) = (
            Scene {
                medium: p.set(&s.medium, v + h),
                ..s.clone()
            },
            Scene {
                medium: p.set(&s.medium, v - h),
                ..s.clone()
            },
        );
        let fd_est = FiniteDifference {
            plus: Covariance::all_pairs(&sp, true).unwrap(),
            minus: Covariance::all_pairs(&sm, true).unwrap(),
            adj: &adj,
            h,
        };
        let e = estimate(&fd_est, 1_500_000, 41);
        let (fd, fd_se) = (e.mean[0].re, e.stderr[0]);
        let z = (g.mean[0].re - fd) / (g.stderr[0].powi(2) + fd_se.powi(2)).sqrt();
        eprintln!(
            "{}: gradient {:.5} ± {:.5}, finite difference of expectations {fd:.5} ± {fd_se:.5}, z = {z:.2}",
            p.name(),
            g.mean[0].re,
            g.stderr[0]
        );
        assert!(z.abs() < 4.0, "{}: z = {z}", p.name());
        assert!(
            g.stderr[0] < 0.2 * g.mean[0].re.abs(),
            "test too noisy to be meaningful"
        );
    }
}

/// `(L(θ+h) − L(θ−h)) / 2h` of standard covariance runs (Algorithm 1 sampling at each θ) on the
/// same random stream per chunk, so the difference has an honest batch-means error.
struct FiniteDifference<'a> {
    plus: Covariance<'a>,
    minus: Covariance<'a>,
    adj: &'a [C64],
    h: f64,
}

impl Estimator for FiniteDifference<'_> {
    type Scratch = (<Covariance<'static> as Estimator>::Scratch, Vec<C64>);
    fn outputs(&self) -> usize {
        1
    }
    fn scratch(&self) -> Self::Scratch {
        (
            self.plus.scratch(),
            vec![C64::default(); self.plus.outputs()],
        )
    }
    fn run_chunk(
        &self,
        rng: &mut lightpath::math::Rng,
        paths: u64,
        sc: &mut Self::Scratch,
        out: &mut [C64],
    ) {
        let j2 = self.adj.len();
        let mut value = [0.0; 2];
        for (k, (cov, r)) in [(&self.plus, rng.clone()), (&self.minus, rng.clone())]
            .into_iter()
            .enumerate()
        {
            let mut r = r;
            sc.1.iter_mut().for_each(|z| *z = C64::default());
            cov.run_chunk(&mut r, paths, &mut sc.0, &mut sc.1);
            value[k] = loss(&sc.1[2 * j2..], self.adj);
        }
        out[0] += (value[0] - value[1]) / (2.0 * self.h);
    }
}

/// The memory-effect loss (curve of `|C0t|²/(C00 Ctt)` against a target) differentiated through its
/// adjoint `∂L/∂C` and the path-space gradient equals central differences of the loss with common
/// random numbers. Catches a wrong adjoint of the correlation ratio (Eq. 39's quantity).
#[test]
fn memory_loss_gradient_matches_finite_differences() {
    use lightpath::inverse::{FitParam, Target, medium_with};
    let base = Medium {
        geometry: Geometry::slab(40.0, 160.0),
        sigma_s: 0.2,
        sigma_a: 0.01,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.3 }),
    };
    let angles = [0.05f64, 0.1, 0.2];
    let mut lights = vec![Light::PlaneWave {
        direction: DVec3::Z,
    }];
    let mut views = vec![View::FarField {
        direction: DVec3::Z,
    }];
    for a in angles {
        lights.push(Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::Y, a.to_radians()),
        });
        views.push(View::FarField {
            direction: rotate(DVec3::Z, DVec3::Y, a.to_radians()),
        });
    }
    let s = Scene::new(1.0, base.clone(), lights, views);
    let target = Target::Memory {
        angles_deg: angles.to_vec(),
        correlation: vec![0.9, 0.6, 0.2],
        stderr: Some(vec![0.01, 0.02, 0.02]),
    };
    let pairs = target.pairs(&s);
    let params = [FitParam::Mfp, FitParam::G];
    let v0 = [4.5, 0.35];
    let m0 = medium_with(&base, &params, &v0);
    let c = |m: &Medium| {
        let r = Reweighted::new(&s, m.clone(), pairs.clone(), true, vec![]).unwrap();
        estimate(&ReweightedCovariance(r), 6000, 77).mean
    };
    let (_, adj) = target.loss(&c(&m0));
    let r = Reweighted::new(
        &s,
        m0.clone(),
        pairs.clone(),
        true,
        vec![Param::SigmaS, Param::SigmaA, Param::G(0)],
    )
    .unwrap();
    let g = estimate(&CovarianceGradient::new(r, &adj), 6000, 77).mean;
    // d/dmfp via σ_s = a/mfp, σ_a = (1−a)/mfp
    let mfp = v0[0];
    let grad_mfp = -(g[0].re * m0.sigma_s + g[1].re * m0.sigma_a) / mfp;
    for (k, analytic) in [(0usize, grad_mfp), (1, g[2].re)] {
        let h = 1e-4 * v0[k].abs();
        let at = |x: f64| {
            let mut v = v0;
            v[k] = x;
            target.loss(&c(&medium_with(&base, &params, &v))).0
        };
        let fd = (at(v0[k] + h) - at(v0[k] - h)) / (2.0 * h);
        eprintln!(
            "{}: gradient {analytic:.8e}, finite difference {fd:.8e}",
            params[k].name()
        );
        assert!(
            (analytic - fd).abs() < 1e-5 * fd.abs(),
            "{}: {analytic} vs {fd}",
            params[k].name()
        );
    }
}

/// Gradients with respect to the node values of a tabulated (complex-amplitude) phase function, with
/// the normalisation kept, mixed with a Henyey–Greenstein type, and to the types' shares of σ_s: central differences with common
/// random numbers agree to 1e-5. Catches a missing normalisation term or a wrong hat function.
#[test]
fn tabulated_bin_and_mixture_weight_gradients_match_finite_differences() {
    use lightpath::medium::Table;
    let s6 = [
        (1.0, 0.0),
        (0.3, 0.8),
        (0.5, 0.2),
        (0.2, -1.0),
        (1.2, 0.4),
        (2.0, 0.0),
    ]
    .map(|(a, b)| C64::new(a, b));
    let table = PhaseFunction::Tabulated(Table::from_amplitude(None, s6.to_vec()).unwrap());
    let mix = Scattering::mixture(vec![
        (0.6, table),
        (0.4, PhaseFunction::HenyeyGreenstein { g: 0.5 }),
    ]);
    let s = scene(mix, 0.05);
    let params = vec![
        Param::Bin(0, 0),
        Param::Bin(0, 2),
        Param::Weight(0),
        Param::Bin(0, 5),
        Param::G(1),
        Param::Weight(1),
    ];
    moved_gradients_match(&s, &params, 3);
}

/// Gradients with respect to a vMF-mixture phase function's lobe weights and concentrations (the
/// mixture kept normalised) with far-field and point endpoints: central differences with common
/// random numbers agree to 1e-5. Catches a missing normalisation term or a wrong lobe derivative.
#[test]
fn vmf_mixture_gradients_match_finite_differences() {
    use lightpath::medium::lobes::VmfMixture;
    let v = VmfMixture::new(&[1.0, 0.25, 0.1], &[12.0, 2.0, -1.0]).unwrap();
    let s = scene(Scattering::single(PhaseFunction::VmfMixture(v)), 0.05);
    let params = vec![
        Param::VmfWeight(0, 1),
        Param::VmfKappa(0, 0),
        Param::VmfWeight(0, 2),
        Param::VmfKappa(0, 2),
        Param::SigmaS,
    ];
    moved_gradients_match(&s, &params, 2);
}

/// Moves the first `moved` parameters 10 % from the proposal and checks the gradient of a random
/// loss there against central differences of the re-weighted covariance (common random numbers),
/// to 1e-5; no gradient may vanish.
fn moved_gradients_match(s: &Scene, params: &[Param], moved: usize) {
    let mut target = s.medium.clone();
    for p in &params[..moved] {
        let v = p.get(&target).unwrap();
        target = p.set(&target, v * 1.1);
    }
    let adj = adjoint(9);
    let r = Reweighted::new(s, target.clone(), pairs(s), true, params.to_vec()).unwrap();
    let grad = estimate(&CovarianceGradient::new(r, &adj), 4000, 12);
    for (i, p) in params.iter().enumerate() {
        let v = p.get(&target).unwrap();
        let h = 1e-5 * v.abs().max(0.01);
        let at = |x: f64| {
            let r = Reweighted::new(s, p.set(&target, x), pairs(s), true, vec![]).unwrap();
            loss(&estimate(&ReweightedCovariance(r), 4000, 12).mean, &adj)
        };
        let fd = (at(v + h) - at(v - h)) / (2.0 * h);
        let g = grad.mean[i].re;
        eprintln!("{}: gradient {g:.8e}, finite difference {fd:.8e}", p.name());
        assert!(
            (g - fd).abs() < 1e-5 * fd.abs().max(1e-6),
            "{}: {g} vs {fd}",
            p.name()
        );
        assert!(g != 0.0, "{}: the gradient vanishes", p.name());
    }
}

/// The speckle mean's derivatives (closed form, differentiated factor by factor; `dB/dσ_t` by
/// Cauchy's formula) against central differences of the closed form, for every endpoint pairing
/// and parameter kind: σ_s, σ_a, g of an HG type, table nodes and shares of a two-type mixture.
/// Would catch a wrong attenuation length, a missing `s(1)` normalisation in the phase factor, or
/// a wrong share derivative. Agreement limited by the O(h²) truncation: 1e-6 relative.
#[test]
fn mean_gradients_match_finite_differences() {
    use lightpath::medium::Table;
    use lightpath::speckle::mean::{mean_field, mean_field_gradient};
    let table = Table::from_rho(None, vec![0.4, 0.6, 1.0, 1.9, 3.5]).unwrap();
    let vmf = lightpath::medium::lobes::VmfMixture::new(&[1.0, 0.2], &[6.0, 0.5]).unwrap();
    let mix = Scattering::mixture(vec![
        (0.45, PhaseFunction::HenyeyGreenstein { g: 0.5 }),
        (0.35, PhaseFunction::Tabulated(table)),
        (0.2, PhaseFunction::VmfMixture(vmf)),
    ]);
    let s = scene(mix, 0.07);
    let params = vec![
        Param::SigmaS,
        Param::SigmaA,
        Param::G(0),
        Param::Bin(1, 1),
        Param::Bin(1, 4),
        Param::Weight(1),
        Param::VmfWeight(2, 1),
        Param::VmfKappa(2, 0),
    ];
    for l in &s.lights {
        for v in &s.views {
            let (m0, grad) = mean_field_gradient(&s, l, v, &params);
            assert_eq!(m0, mean_field(&s, l, v));
            for (i, p) in params.iter().enumerate() {
                let x = p.get(&s.medium).unwrap();
                let h = 1e-5 * x.abs().max(0.05);
                let at = |y: f64| {
                    let t = Scene {
                        medium: p.set(&s.medium, y),
                        ..s.clone()
                    };
                    mean_field(&t, l, v)
                };
                let fd = (at(x + h) - at(x - h)) / (2.0 * h);
                assert!(
                    // relative 1e-6, with a floor for derivatives that vanish exactly (a node
                    // outside μ's segment only renormalises, which cancels in s(μ)/s(1))
                    (grad[i] - fd).norm()
                        <= 1e-6 * fd.norm() + 1e-9 * m0.norm() / x.abs().max(0.05),
                    "{:?} → {:?}, {}: {} vs {fd}",
                    l,
                    v,
                    p.name(),
                    grad[i]
                );
            }
        }
    }
}

/// Normal incidence, forward view: the optical theorem makes `(4π/k) Im m = σ_s B` with
/// `B = A·2(1 − e^{−σ_t L/2})/σ_t` exactly, so `(4π/k) Im ∂m/∂σ_a = σ_s B'(σ_t)` in closed form —
/// an independent check of the Cauchy-formula derivative of the box integral (to 1e-10).
#[test]
fn mean_attenuation_derivative_matches_the_optical_theorem() {
    use lightpath::speckle::mean::mean_field_gradient;
    let s = scene(Scattering::single(PhaseFunction::Isotropic), 0.12);
    let (a, len) = (4.0 * 5.0, 3.0);
    let (sigma_s, sigma_t) = (s.medium.sigma_s, s.medium.sigma_t());
    let (_, g) = mean_field_gradient(
        &s,
        &Light::PlaneWave {
            direction: DVec3::Z,
        },
        &View::FarField {
            direction: DVec3::Z,
        },
        &[Param::SigmaA],
    );
    let e = (-0.5 * sigma_t * len).exp();
    let db = a * (len * e / sigma_t - 2.0 * (1.0 - e) / (sigma_t * sigma_t));
    let got = 4.0 * std::f64::consts::PI / s.k * g[0].im;
    assert!(
        (got - sigma_s * db).abs() <= 1e-10 * (sigma_s * db).abs(),
        "{got} vs {}",
        sigma_s * db
    );
}
