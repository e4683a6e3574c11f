//! Phase-function sampling matches its pdf (χ² on histograms of cos θ) and every kind normalises
//! to 1 (∫ρ dω by quadrature). Catches: a wrong inverse CDF (e.g. g sign flipped in HG), a
//! tabulated sampler that ignores the linear slope within a bin, a mixture that picks types with the
//! wrong weights.

use glam::DVec3;
use lightpath::math::{stream_rng, uniform};
use lightpath::medium::{PhaseFunction, Scattering, Table};
use std::f64::consts::PI;

/// Simpson's rule for `f` over `[a, b]` with `m` (even) panels.
fn simpson(f: &dyn Fn(f64) -> f64, a: f64, b: f64, m: usize) -> f64 {
    let h = (b - a) / m as f64;
    let weight = |i: usize| {
        if i == 0 || i == m {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        }
    };
    (0..=m)
        .map(|i| weight(i) * f(a + i as f64 * h))
        .sum::<f64>()
        * h
        / 3.0
}

/// χ² statistic of `n` samples of μ in `bins` equal bins against the exact bin probabilities.
fn chi2(
    mut sample: impl FnMut(f64, f64) -> f64,
    pdf: impl Fn(f64) -> f64,
    n: usize,
    bins: usize,
    seed: u64,
) -> f64 {
    let mut rng = stream_rng(seed, 0);
    let mut counts = vec![0usize; bins];
    for _ in 0..n {
        let mu = sample(uniform(&mut rng), uniform(&mut rng));
        assert!((-1.0..=1.0).contains(&mu), "μ = {mu} outside [-1, 1]");
        counts[(((mu + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1)] += 1;
    }
    let mut stat = 0.0;
    for (b, &c) in counts.iter().enumerate() {
        // bin probability by Simpson's rule on 2π ρ(μ)
        let (a, z) = (
            -1.0 + 2.0 * b as f64 / bins as f64,
            -1.0 + 2.0 * (b + 1) as f64 / bins as f64,
        );
        let p = simpson(&pdf, a, z, 64);
        let e = p * n as f64;
        stat += (c as f64 - e).powi(2) / e;
    }
    stat
}

/// For `bins − 1 = 49` degrees of freedom the 99.9 % quantile of χ² is 85.35.
const CHI2_49_999: f64 = 85.35;

fn check(p: &PhaseFunction, seed: u64) {
    // normalisation
    let total = 2.0 * PI * simpson(&|mu| p.eval(mu), -1.0, 1.0, 20000);
    assert!((total - 1.0).abs() < 1e-6, "{p:?}: ∫ρ dω = {total}");
    let s = chi2(
        |u, _| p.sample_mu(u),
        |mu| 2.0 * PI * p.eval(mu),
        200_000,
        50,
        seed,
    );
    assert!(s < CHI2_49_999, "{p:?}: χ² = {s}");
    // the full 3-D sampler agrees with the μ sampler about an arbitrary axis
    let w = DVec3::new(0.3, -0.5, 0.8).normalize();
    let s3 = chi2(
        |u1, u2| p.sample(w, u1, u2).dot(w),
        |mu| 2.0 * PI * p.eval(mu),
        100_000,
        50,
        seed + 1,
    );
    assert!(s3 < CHI2_49_999, "{p:?}: 3-D χ² = {s3}");
}

#[test]
fn isotropic() {
    check(&PhaseFunction::Isotropic, 1);
}

#[test]
fn henyey_greenstein() {
    for (i, g) in [0.9, 0.5, -0.4, 1e-8].iter().enumerate() {
        check(
            &PhaseFunction::HenyeyGreenstein { g: *g },
            10 + i as u64 * 2,
        );
    }
}

#[test]
fn tabulated_real_and_complex() {
    let t = Table::from_rho(
        Some(vec![-1.0, -0.2, 0.3, 0.9, 1.0]),
        vec![0.5, 0.1, 2.0, 6.0, 0.0],
    )
    .unwrap();
    check(&PhaseFunction::Tabulated(t), 20);
    let s = [(1.0, 0.0), (0.2, 0.5), (-1.0, 1.0), (0.0, -3.0)]
        .map(|(a, b)| num_complex::Complex64::new(a, b));
    let t = Table::from_amplitude(None, s.to_vec()).unwrap();
    check(&PhaseFunction::Tabulated(t), 22);
}

#[test]
fn a_detuned_sampler_fails_the_test() {
    // the χ² test is sharp enough to see g = 0.5 sampled as g = 0.45
    let p = PhaseFunction::HenyeyGreenstein { g: 0.5 };
    let wrong = PhaseFunction::HenyeyGreenstein { g: 0.45 };
    let s = chi2(
        |u, _| wrong.sample_mu(u),
        |mu| 2.0 * PI * p.eval(mu),
        200_000,
        50,
        30,
    );
    assert!(s > 10.0 * CHI2_49_999, "χ² = {s}");
}

#[test]
fn mixture_picks_types_by_weight() {
    let mix = Scattering::mixture(vec![
        (3.0, PhaseFunction::HenyeyGreenstein { g: 0.8 }),
        (1.0, PhaseFunction::HenyeyGreenstein { g: -0.6 }),
    ]);
    let mut rng = stream_rng(40, 7);
    let s = chi2(
        |u1, _| {
            let k = mix.pick(|| uniform(&mut rng));
            mix.phase(k).sample_mu(u1)
        },
        |mu| 2.0 * PI * mix.eval(mu),
        200_000,
        50,
        41,
    );
    assert!(s < CHI2_49_999, "χ² = {s}");
}
