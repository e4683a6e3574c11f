//! The single-scattering closed form (paper 001 Eq. 41; `[render] estimator = "single_scattering"`)
//! against the Monte Carlo estimator's single-scattering part (boxes and slabs, reflection and
//! transmission, a mixture of complex amplitudes, absorption), against paper 004's Claim 1 (Eq. 3)
//! in its paraxial regime, and through the command line.

use crate::common;

use common::estimate;
use glam::DVec3;
use lightpath::math::C64;
use lightpath::mc::Plan;
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering, Table};
use lightpath::speckle::covariance::Order;
use lightpath::speckle::{Covariance, Light, Scene, View, single};

fn mixture() -> Scattering {
    let s1 = [(1.0, 0.0), (0.3, 0.8), (-0.5, 1.5), (0.2, -2.0)].map(|(a, b)| C64::new(a, b));
    let p1 = PhaseFunction::Tabulated(Table::from_amplitude(None, s1.to_vec()).unwrap());
    Scattering::mixture(vec![
        (0.7, p1),
        (0.3, PhaseFunction::HenyeyGreenstein { g: 0.6 }),
    ])
}

fn plane(d: [f64; 3]) -> Light {
    Light::PlaneWave {
        direction: DVec3::from_array(d).normalize(),
    }
}

fn far(d: [f64; 3]) -> View {
    View::FarField {
        direction: DVec3::from_array(d).normalize(),
    }
}

/// Every entry of the closed form against the Monte Carlo single-scattering block: worst |z| and
/// the largest relative standard error (so the test cannot pass by being noisy).
fn against_monte_carlo(scene: &Scene, samples: u64) -> (f64, f64) {
    let closed = single::covariance(scene).unwrap();
    let est = Covariance::all_pairs(scene, true).unwrap();
    let e = estimate(&est, &Plan::new(5, samples, samples / 100));
    let j = scene.lights.len() * scene.views.len();
    let (mc, se) = (
        Order::Single.block(j, &e.mean),
        Order::Single.block(j, &e.stderr),
    );
    let (mut worst, mut noise) = (0.0f64, 0.0f64);
    for i in 0..j * j {
        let z = (mc[i] - closed[i]).norm() / se[i];
        eprintln!(
            "entry {i}: MC {:.5e} ± {:.1e}, closed {:.5e}, |z| {z:.2}",
            mc[i], se[i], closed[i]
        );
        worst = worst.max(z);
        if closed[i].norm() > 0.2 * closed[0].norm() {
            noise = noise.max(se[i] / closed[i].norm());
        }
    }
    (worst, noise)
}

#[test]
fn box_matches_monte_carlo_single_scattering() {
    let m = Medium {
        geometry: Geometry::boxed([2.0, 3.0, 1.5]),
        sigma_s: 0.4,
        sigma_a: 0.1,
        scattering: mixture(),
    };
    // a transmitted and a reflected view, two illuminations: entries with Δ = 0 and Δ ≠ 0
    let scene = Scene::new(
        1.0,
        m,
        vec![plane([0.0, 0.0, 1.0]), plane([0.2, 0.1, 1.0])],
        vec![far([0.5, 0.0, 1.0]), far([0.4, -0.3, -1.0])],
    );
    let (worst, noise) = against_monte_carlo(&scene, 400_000);
    assert!(worst < 4.5, "worst |z| {worst}");
    assert!(noise < 0.05, "test too noisy: {noise}");
}

#[test]
fn slab_matches_monte_carlo_single_scattering() {
    let m = Medium {
        geometry: Geometry::slab(2.0, 4.0),
        sigma_s: 0.5,
        sigma_a: 0.05,
        scattering: mixture(),
    };
    let scene = Scene::new(
        1.0,
        m,
        vec![plane([0.0, 0.0, 1.0]), plane([0.05, 0.0, 1.0])],
        vec![
            far([0.3, 0.0, 1.0]),
            far([0.35, 0.0, 1.0]),
            far([0.2, 0.1, -1.0]),
        ],
    );
    let (worst, noise) = against_monte_carlo(&scene, 400_000);
    assert!(worst < 4.5, "worst |z| {worst}");
    assert!(noise < 0.05, "test too noisy: {noise}");
}

#[test]
fn slab_transmission_is_claim_1_when_paraxial() {
    // |C| = ρ(|τ|) L σ_s e^{−σ_t L} sinc(kL/2 Δ·τ) (paper 004 Eq. 3, its square root) for
    // illuminations Δ apart and views τ from them, at small angles (corrections O(θ²))
    let (l, sigma_s, sigma_a, g) = (2000.0, 5e-4, 1e-4, 0.8);
    let hg = PhaseFunction::HenyeyGreenstein { g };
    let m = Medium {
        geometry: Geometry::slab(l, 4.0 * l),
        sigma_s,
        sigma_a,
        scattering: Scattering::single(hg.clone()),
    };
    let lateral = |a: [f64; 2]| DVec3::new(a[0], a[1], (1.0 - a[0] * a[0] - a[1] * a[1]).sqrt());
    let (i1, delta) = ([0.0, 0.0], [0.0, 0.01]);
    let mut checked = 0;
    // kL/2 Δ·τ = 0, 1.3, 2.2, 2.8: through the sinc's first lobe
    for tau in [[0.02, 0.0], [0.02, 0.02], [0.01, 0.035], [0.0, 0.045]] {
        let i2 = [i1[0] + delta[0], i1[1] + delta[1]];
        let v1 = [i1[0] + tau[0], i1[1] + tau[1]];
        let v2 = [i2[0] + tau[0], i2[1] + tau[1]];
        let scene = Scene::new(
            1.0,
            m.clone(),
            vec![
                Light::PlaneWave {
                    direction: lateral(i1),
                },
                Light::PlaneWave {
                    direction: lateral(i2),
                },
            ],
            vec![
                View::FarField {
                    direction: lateral(v1),
                },
                View::FarField {
                    direction: lateral(v2),
                },
            ],
        );
        let c = single::covariance(&scene).unwrap();
        // entry (l1 = 0, l2 = 1, v1 = 0, v2 = 1): j1 = 0, j2 = 1·2 + 1
        let got = c[3].norm();
        let angle = lateral(i1).dot(lateral(v1));
        let dot = delta[0] * tau[0] + delta[1] * tau[1];
        let x = scene.k * l / 2.0 * dot;
        let sinc = if x == 0.0 { 1.0 } else { x.sin() / x };
        let scale = hg.eval(angle) * l * sigma_s * (-(sigma_s + sigma_a) * l).exp();
        let claim = scale * sinc.abs();
        eprintln!("τ {tau:?}: closed {got:.6e}, Claim 1 {claim:.6e}, sinc {sinc:.4}");
        // the paraxial approximation drops O(θ²) ≈ 0.25 % at these angles
        assert!(
            (got - claim).abs() < 0.005 * scale,
            "τ {tau:?}: {got} vs {claim}"
        );
        checked += 1;
    }
    assert_eq!(checked, 4);
}

/// Point and focused lights and views in a box: the quadrature of the first event's own amplitudes
/// (spherical waves, `Υ` of the lenses) against the Monte Carlo's single-scattering block, and
/// against itself on panels half as wide.
#[test]
fn point_and_focused_endpoints_match_monte_carlo_single_scattering() {
    let m = Medium {
        geometry: Geometry::boxed([4.0, 4.0, 3.0]),
        sigma_s: 0.3,
        sigma_a: 0.05,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
    };
    let axis = DVec3::Z;
    let focused = |x: f64| Light::Focused {
        focus: DVec3::new(x, 0.0, 0.0),
        axis,
        gamma: 1.0 / 0.3f64.powi(2),
    };
    let scene = Scene::new(
        1.0,
        m,
        vec![
            focused(0.0),
            focused(0.4),
            Light::Point {
                position: DVec3::new(0.5, -0.3, -4.0),
            },
        ],
        vec![
            View::Focused {
                focus: DVec3::new(0.2, 0.1, 0.5),
                axis,
                gamma: 1.0 / 0.3f64.powi(2),
            },
            far([0.3, 0.0, 1.0]),
        ],
    );
    let (worst, noise) = against_monte_carlo(&scene, 400_000);
    assert!(worst < 4.5, "worst |z| {worst}");
    assert!(noise < 0.05, "test too noisy: {noise}");
    // the panels are fine enough: halving them moves no entry by more than 1e-4 of the largest
    let (a, b) = (
        single::covariance(&scene).unwrap(),
        single::quadrature(&scene, 2.0).unwrap(),
    );
    let top = a.iter().map(|z| z.norm()).fold(0.0, f64::max);
    let moved = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).norm())
        .fold(0.0, f64::max);
    assert!(
        moved < 1e-4 * top,
        "refined quadrature moved by {moved} of {top}"
    );
}

#[test]
fn refuses_point_endpoints_in_a_slab_and_boxes_beyond_the_quadrature() {
    let m = Medium {
        geometry: Geometry::slab(2.0, 20.0),
        sigma_s: 0.4,
        sigma_a: 0.0,
        scattering: mixture(),
    };
    let scene = Scene::new(
        1.0,
        m,
        vec![Light::Point {
            position: DVec3::new(0.0, 0.0, -5.0),
        }],
        vec![far([0.0, 0.0, 1.0])],
    );
    let e = single::covariance(&scene).unwrap_err().to_string();
    assert!(e.contains("light[0]") && e.contains("medium.box"), "{e}");
    // a box too large for the quadrature is refused before any work
    let huge = Scene {
        medium: Medium {
            geometry: Geometry::boxed([400.0, 400.0, 400.0]),
            ..scene.medium.clone()
        },
        ..scene.clone()
    };
    let e = single::covariance(&huge).unwrap_err().to_string();
    assert!(
        e.contains("quadrature nodes") && e.contains("Monte Carlo"),
        "{e}"
    );
}

#[test]
fn command_writes_the_closed_form() {
    use lightpath::io::ResultFile;
    use lightpath::io::results::CovarianceFile;
    let dir = std::env::temp_dir().join(format!("lightpath-single-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let text = r#"
wavelength = 1.0
[medium]
slab = 4.0
mfp = 2.0
phase = { kind = "hg", g = 0.7 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field_ring"
start = [0.2, 0.0, 1.0]
axis = [0.0, 0.0, 1.0]
count = 6
[render]
estimator = "single_scattering"
"#;
    let cfg = dir.join("scene.toml");
    std::fs::write(&cfg, text).unwrap();
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args(args)
            .output()
            .unwrap()
    };
    let out = dir.join("out");
    let o = run(&[
        "covariance",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let f = CovarianceFile::read(&out.join("covariance.json")).unwrap();
    assert_eq!(f.solver.as_deref(), Some("single_scattering"));
    let task = lightpath::config::scene_from_text(text).unwrap();
    let c = single::covariance(&task.scene).unwrap();
    assert_eq!(f.re[0][0][2][3], c[2 * 6 + 3].re);
    assert_eq!(f.single_im, Some(f.im.clone()));
    // other commands, shards and point endpoints are refused by name
    let o = run(&[
        "memory-effect",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let o = run(&[
        "covariance",
        cfg.to_str().unwrap(),
        "--shard",
        "0/2",
        "--out",
        dir.join("shard").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("single_scattering"),
        "{err}"
    );
}
