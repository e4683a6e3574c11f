//! Physics of the speckle estimators against independent references: coherent backscattering,
//! the single-scattering closed form (paper 001, Eq. 41) with a mixture of complex-amplitude particle
//! types, the memory-effect diffusion formula (Eq. 39), and Algorithm 2's fields against Algorithm 1.

use glam::DVec3;
use lightpath::config::Config;
use lightpath::math::{C64, rotate};
use lightpath::mc::{Estimate, Plan, merge, run};
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering, Table};
use lightpath::speckle::mean::mean_field;
use lightpath::speckle::memory::MemoryScan;
use lightpath::speckle::paths::SubpathSampler;
use lightpath::speckle::{Covariance, FieldSampler, Light, Scene, View};

fn medium(geometry: Geometry, mfp: f64, scattering: Scattering) -> Medium {
    Medium {
        geometry,
        sigma_s: 1.0 / mfp,
        sigma_a: 0.0,
        scattering,
    }
}

fn estimate(est: &Covariance, samples: u64, chunk: u64, seed: u64) -> Estimate {
    let plan = Plan::new(seed, samples, chunk);
    Estimate::from_block(
        &merge(run(est, &plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap(),
        &plan,
    )
}

/// Coherent backscattering: with reversed paths the exact-backscatter intensity of an optically
/// thick box (optical depth 8) is enhanced towards 2× the background; forward-only paths show no peak. Catches a
/// missing or mis-phased reversed term (Eq. 38), or reversed paths weighted without the 1/2 of Eq. 36.
#[test]
fn coherent_backscattering_peak() {
    let m = medium(
        Geometry::boxed([10.0, 10.0, 10.0]),
        1.25,
        Scattering::single(PhaseFunction::Isotropic),
    );
    let d = DVec3::Z;
    let angles = [0.0, 30.0, 90.0];
    let views = angles
        .iter()
        .map(|a| View::FarField {
            direction: rotate(-d, DVec3::Y, f64::to_radians(*a)),
        })
        .collect();
    let scene = Scene::new(1.0, m, vec![Light::PlaneWave { direction: d }], views);
    let j = 3;
    let rev = estimate(
        &Covariance::all_pairs(&scene, true).unwrap(),
        60_000,
        1000,
        5,
    );
    let fwd = estimate(
        &Covariance::all_pairs(&scene, false).unwrap(),
        60_000,
        1000,
        5,
    );
    let total = |e: &Estimate, v: usize| {
        (
            e.mean[2 * j * j + v * j + v].re,
            e.stderr[2 * j * j + v * j + v],
        )
    };
    let multi = |e: &Estimate, v: usize| e.mean[j * j + v * j + v].re;
    let single = |e: &Estimate, v: usize| e.mean[v * j + v].re;

    // exact backscatter: reversed multiple scattering is exactly twice the forward-only one, sample
    // by sample (same random numbers), and single scattering is unchanged
    assert!((multi(&rev, 0) / multi(&fwd, 0) - 2.0).abs() < 1e-9);
    assert_eq!(single(&rev, 0), single(&fwd, 0));

    let (r0, r0e) = total(&rev, 0);
    let (r20, r20e) = total(&rev, 1);
    let (f0, _) = total(&fwd, 0);
    let (f20, _) = total(&fwd, 1);
    let peak = r0 / r20;
    let enhancement = r0 / f0;
    eprintln!(
        "optical depth 8: backscatter / 30°: reversed {peak:.3}, forward-only {:.3}; enhancement over the incoherent background {enhancement:.3}; single-scattering share {:.3}",
        f0 / f20,
        single(&fwd, 0) / f0
    );
    let peak_se = peak * ((r0e / r0).powi(2) + (r20e / r20).powi(2)).sqrt();
    // the enhancement is 1 + M/(S + M): below 2 by the single-scattering share, which no reversed
    // path exists for; the peak stands clearly above the background 30° away
    assert!((enhancement - (2.0 - single(&fwd, 0) / f0)).abs() < 1e-9);
    assert!(
        enhancement > 1.7 && enhancement < 2.0,
        "enhancement {enhancement}"
    );
    assert!(
        peak > 1.55 && peak < 2.0 + 3.0 * peak_se,
        "peak ratio {peak}"
    );
    assert!(
        (f0 / f20 - 1.0).abs() < 0.1,
        "forward-only must show no peak: {}",
        f0 / f20
    );
    // far from backscatter the reversed term averages out: both variants agree within errors
    let (r90, r90e) = total(&rev, 2);
    let (f90, f90e) = total(&fwd, 2);
    assert!(
        (r90 - f90).abs() < 4.0 * (r90e * r90e + f90e * f90e).sqrt(),
        "{r90} vs {f90}"
    );
}

/// Composite 8-point Gauss–Legendre nodes over [a, b].
fn gauss(a: f64, b: f64, panels: usize) -> Vec<(f64, f64)> {
    let x = [
        0.183_434_642_495_649_8,
        0.525_532_409_916_329,
        0.796_666_477_413_626_7,
        0.960_289_856_497_536_3,
    ];
    let w = [
        0.362_683_783_378_362,
        0.313_706_645_877_887_3,
        0.222_381_034_453_374_5,
        0.101_228_536_290_376_3,
    ];
    let h = (b - a) / panels as f64;
    let mut out = Vec::new();
    for p in 0..panels {
        let c = a + (p as f64 + 0.5) * h;
        for i in 0..4 {
            out.push((c + 0.5 * h * x[i], 0.5 * h * w[i]));
            out.push((c - 0.5 * h * x[i], 0.5 * h * w[i]));
        }
    }
    out
}

/// The single-scattering block equals Eq. 41, `S(i1·v1, i2·v2) ∫ σ_s exp(ik((i1−v1)−(i2−v2))·x) η dx`
/// with `S = Σ β s_ι s_ι*` (Eq. 44) over two particle types with complex amplitude tables, integrated
/// here by brute-force quadrature. Catches wrong amplitude arguments or phases at the first vertex,
/// a mixture that mixes amplitudes of different types in one product, and wrong attenuation.
#[test]
fn single_scattering_matches_eq41_with_mixture() {
    let s1 = [(1.0, 0.0), (0.3, 0.8), (-0.5, 1.5), (0.2, -2.0)].map(|(a, b)| C64::new(a, b));
    let s2 = [(0.1, 0.0), (1.0, 1.0), (0.0, 0.5), (3.0, 0.0)].map(|(a, b)| C64::new(a, b));
    let p1 = PhaseFunction::Tabulated(Table::from_amplitude(None, s1.to_vec()).unwrap());
    let p2 = PhaseFunction::Tabulated(Table::from_amplitude(None, s2.to_vec()).unwrap());
    let mix = Scattering::mixture(vec![(0.7, p1.clone()), (0.3, p2.clone())]);
    let half = DVec3::new(1.0, 1.5, 0.75);
    let m = Medium {
        geometry: Geometry::boxed((half * 2.0).to_array()),
        sigma_s: 0.4,
        sigma_a: 0.1,
        scattering: mix,
    };
    let lights = vec![
        Light::PlaneWave {
            direction: DVec3::Z,
        },
        Light::PlaneWave {
            direction: DVec3::new(0.2, 0.1, 1.0).normalize(),
        },
    ];
    let views = vec![
        View::FarField {
            direction: DVec3::new(0.5, 0.0, 1.0).normalize(),
        },
        View::FarField {
            direction: DVec3::new(0.4, -0.3, 1.0).normalize(),
        },
    ];
    let scene = Scene::new(1.0, m.clone(), lights.clone(), views.clone());
    let est = Covariance::all_pairs(&scene, true).unwrap();
    let e = estimate(&est, 400_000, 4000, 9);
    let k = scene.k;
    let nodes: Vec<Vec<(f64, f64)>> = (0..3).map(|a| gauss(-half[a], half[a], 12)).collect();
    let dir = |l: &Light| match l {
        Light::PlaneWave { direction } => *direction,
        _ => unreachable!(),
    };
    let vdir = |v: &View| match v {
        View::FarField { direction } => *direction,
        _ => unreachable!(),
    };
    let mut worst: f64 = 0.0;
    for (l1, l2, v1, v2) in [
        (0, 0, 0, 0),
        (0, 1, 0, 1),
        (0, 1, 1, 0),
        (1, 1, 0, 1),
        (0, 0, 0, 1),
    ] {
        let (i1, i2, w1, w2) = (
            dir(&lights[l1]),
            dir(&lights[l2]),
            vdir(&views[v1]),
            vdir(&views[v2]),
        );
        let q = ((i1 - w1) - (i2 - w2)) * k;
        let mut integral = C64::default();
        for &(x, wx) in &nodes[0] {
            for &(y, wy) in &nodes[1] {
                for &(z, wz) in &nodes[2] {
                    let p = DVec3::new(x, y, z);
                    let path = m.geometry.exit_distance(p, -i1)
                        + m.geometry.exit_distance(p, w1)
                        + m.geometry.exit_distance(p, -i2)
                        + m.geometry.exit_distance(p, w2);
                    let eta = (-0.5 * m.sigma_t() * path).exp();
                    let (sn, cs) = q.dot(p).sin_cos();
                    integral += C64::new(cs, sn) * (wx * wy * wz * eta);
                }
            }
        }
        let s = 0.7 * p1.amplitude(i1.dot(w1)) * p1.amplitude(i2.dot(w2)).conj()
            + 0.3 * p2.amplitude(i1.dot(w1)) * p2.amplitude(i2.dot(w2)).conj();
        let expect = s * integral * m.sigma_s;
        let (j1, j2) = (l1 * 2 + v1, l2 * 2 + v2);
        let idx = j1 * 4 + j2;
        let (got, se) = (e.mean[idx], e.stderr[idx]);
        let z = (got - expect).norm() / se;
        eprintln!(
            "({l1},{l2},{v1},{v2}): MC {got:.5e} ± {se:.1e}, Eq. 41 {expect:.5e}, |z| = {z:.2}"
        );
        assert!(z < 4.5, "z = {z}");
        worst = worst.max(se / expect.norm());
    }
    assert!(worst < 0.05, "test too noisy: relative error {worst}");
}

/// Memory effect of an optically thick slab (L = 2000 λ, MFP = 200 λ, g = 0) in transmission against
/// the diffusion formula ((kθL)/sinh(kθL))² (Eq. 39) for θ ∈ [0.001°, 0.02°]. Stated tolerance:
/// within 0.05 of Eq. 39 and, within 3 standard errors, between Eq. 39 with the physical thickness L
/// and with the diffusion thickness L + 2·0.7104·MFP (extrapolated boundaries), as diffusion theory
/// brackets it. Catches phase errors across the path (wrong k, wrong tilt handling) and weighting errors
/// that change the path-length distribution.
#[test]
fn memory_effect_matches_diffusion() {
    let text = r#"
wavelength = 1.0
[medium]
slab = 2000.0
mfp = 200.0
phase = { kind = "isotropic" }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
[memory_effect]
angles_deg = [0.001, 0.002, 0.004, 0.006, 0.008, 0.01, 0.012, 0.015, 0.02]
[render]
samples = 120000
chunk = 500
seed = 3
"#;
    // through the library: the scan, the covariance estimator over its pairs, the curve
    let cfg = Config::from_toml(text, None).unwrap();
    let me = cfg.memory_effect.clone().unwrap();
    let scan = MemoryScan::new(
        &cfg.scene().unwrap(),
        glam::DVec3::from_array(me.axis),
        &me.angles_deg,
    )
    .unwrap();
    let est = Covariance::with_pairs(&scan.scene, scan.pairs(), cfg.render.reversed).unwrap();
    let plan = Plan::new(cfg.render.seed, cfg.render.samples, cfg.render.chunk);
    let root = merge(
        run(&est, &plan, 0..plan.chunks, &scan.kept_outputs(), &|_| {}),
        plan.chunks,
    )
    .unwrap();
    let curve = scan.curve(&root, &plan);
    let (ang, c, se, eq39) = (
        curve.angles_deg,
        curve.correlation,
        curve.stderr,
        curve.diffusion,
    );
    let kl_eff = 2.0 * std::f64::consts::PI * (2000.0 + 2.0 * 0.7104 * 200.0);
    for i in 0..ang.len() {
        let x = kl_eff * ang[i].to_radians();
        let eff = (x / x.sinh()).powi(2);
        eprintln!(
            "θ = {:.3}°: MC {:.4} ± {:.4}, Eq. 39 {:.4} (L_eff: {:.4})",
            ang[i], c[i], se[i], eq39[i], eff
        );
        assert!(
            (c[i] - eq39[i]).abs() < 0.05,
            "θ = {}: {} vs {}",
            ang[i],
            c[i],
            eq39[i]
        );
        assert!(
            c[i] < eq39[i] + 3.0 * se[i] + 1e-3 && c[i] > eff - 3.0 * se[i] - 1e-3,
            "θ = {}: {} outside [{eff}, {}]",
            ang[i],
            c[i],
            eq39[i]
        );
    }
    assert!(se.iter().all(|s| *s < 0.01), "test too noisy");
}

/// Algorithm 2: the empirical covariance of many rendered fields matches Algorithm 1's covariance
/// (paper 001, Fig. 9), including the cross-light block. Catches fields built from independent paths
/// per pair (no cross correlation), a wrong 1/√N scale, a missing random phase.
#[test]
fn field_covariance_matches_algorithm_1() {
    let m = medium(
        Geometry::boxed([6.0, 6.0, 4.0]),
        2.0,
        Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
    );
    let lights = vec![
        Light::PlaneWave {
            direction: DVec3::Z,
        },
        Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::Y, 4f64.to_radians()),
        },
    ];
    let views = (0..4)
        .map(|i| View::FarField {
            direction: rotate(DVec3::Z, DVec3::Y, (4.0 * i as f64 - 6.0).to_radians()),
        })
        .collect();
    let scene = Scene::new(1.0, m, lights, views);
    let j = 8;
    let cov = estimate(
        &Covariance::all_pairs(&scene, true).unwrap(),
        200_000,
        2000,
        21,
    );
    let fields = FieldSampler::new(&scene, SubpathSampler::all_pairs(&scene), true).unwrap();
    let reals = 3000u64;
    let paths = 40u64;
    let mut us = Vec::new();
    for r in 0..reals {
        let plan = Plan {
            seed: 1000 + r,
            chunk_paths: paths,
            chunks: 1,
        };
        let root = merge(run(&fields, &plan, 0..1, &[], &|_| {}), 1).unwrap();
        us.push(
            root.sum
                .iter()
                .map(|z| z / (paths as f64).sqrt())
                .collect::<Vec<C64>>(),
        );
    }
    let mut worst: f64 = 0.0;
    for a in 0..j {
        for b in 0..j {
            let prods: Vec<C64> = us.iter().map(|u| u[a] * u[b].conj()).collect();
            let mean = prods.iter().sum::<C64>() / reals as f64;
            let var = prods.iter().map(|p| (p - mean).norm_sqr()).sum::<f64>() / (reals - 1) as f64;
            let se = (var / reals as f64 + cov.stderr[2 * j * j + a * j + b].powi(2)).sqrt();
            let z = (mean - cov.mean[2 * j * j + a * j + b]).norm() / se;
            worst = worst.max(z);
        }
    }
    eprintln!("worst |z| over {} entries: {worst:.2}", j * j);
    assert!(worst < 4.5, "worst z = {worst}");
    // and the fields really are correlated across lights (the test is not vacuous)
    let c01 = cov.mean[2 * j * j + 1]; // (light 0, view 0) × (light 0, view 1)
    let cross = cov.mean[2 * j * j + 4 * j + 1]; // (light 1, view 0) × (light 0, view 1)
    assert!(c01.norm() > 0.0 && cross.norm() > 10.0 * cov.stderr[2 * j * j + 4 * j + 1]);
}

/// A tilted light's speckle image is a shifted copy of the untilted one (memory effect, Fig. 11):
/// the best cross-correlation shift of the two transmitted field images equals the tilt in pixels.
#[test]
fn tilted_light_shifts_the_speckle() {
    let m = medium(
        Geometry::boxed([100.0, 100.0, 8.0]),
        4.0,
        Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.3 }),
    );
    let step = 0.25f64;
    let lights = vec![
        Light::PlaneWave {
            direction: DVec3::Z,
        },
        Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::Y, (2.0 * step).to_radians()),
        },
    ];
    let n = 41;
    let views = (0..n)
        .map(|i| View::FarField {
            direction: rotate(DVec3::Z, DVec3::Y, ((i as f64 - 20.0) * step).to_radians()),
        })
        .collect();
    let scene = Scene::new(1.0, m, lights, views);
    let fields = FieldSampler::new(&scene, SubpathSampler::all_pairs(&scene), true).unwrap();
    let plan = Plan::new(77, 40_000, 1000);
    let u = merge(
        run(&fields, &plan, 0..plan.chunks, &[], &|_| {}),
        plan.chunks,
    )
    .unwrap()
    .sum;
    let means: Vec<C64> = scene
        .lights
        .iter()
        .flat_map(|l| scene.views.iter().map(move |v| (l, v)))
        .map(|(l, v)| mean_field(&scene, l, v))
        .collect();
    let u: Vec<C64> = u
        .iter()
        .zip(&means)
        .map(|(s, m)| m + s / (plan.samples() as f64).sqrt())
        .collect();
    let (u0, u1) = (&u[..n], &u[n..]);
    let corr = |s: i64| -> f64 {
        let (mut num, mut n0, mut n1) = (C64::default(), 0.0, 0.0);
        for i in 8..(n as i64 - 8) {
            let a = u0[(i - s) as usize];
            let b = u1[i as usize];
            num += b * a.conj();
            n0 += a.norm_sqr();
            n1 += b.norm_sqr();
        }
        num.norm() / (n0 * n1).sqrt()
    };
    let c: Vec<f64> = (-5..=5).map(corr).collect();
    eprintln!("field correlation vs shift -5..5: {c:.3?}");
    let best = (-5..=5)
        .max_by(|&a, &b| corr(a).total_cmp(&corr(b)))
        .unwrap();
    assert_eq!(best, 2, "best shift {best}");
    assert!(corr(2) > 0.8 && corr(0) < 0.6 * corr(2), "{c:?}");
}
