//! Helpers shared by the integration tests.
#![allow(dead_code)]

use lightpath::mc::{Estimate, Estimator, Plan, merge, run};
use lightpath::speckle::{Scene, wave};

/// Run every chunk of `plan` and reduce to means with standard errors.
pub fn estimate<E: Estimator>(e: &E, plan: &Plan) -> Estimate {
    Estimate::from_block(
        &merge(run(e, plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap(),
        plan,
    )
}

/// Mean and covariance over `reals` scatterer placements, as `lightpath wave` computes them:
/// placements as an engine estimator (one per chunk, every field kept), reduced by
/// `WaveStatistics`.
pub fn wave_statistics(scene: &Scene, reals: u64, seed: u64) -> wave::WaveStatistics {
    let est = wave::Realizations::new(scene);
    let plan = Plan {
        seed,
        chunk_paths: 1,
        chunks: reals,
    };
    let root = merge(
        run(&est, &plan, 0..reals, &est.kept_outputs(), &|_| {}),
        reals,
    )
    .unwrap();
    wave::WaveStatistics::from_fields(&root.kept, est.fields())
}

/// A box of half-extents `half` about the origin, of constant index `n` in air, holding a
/// homogeneous medium with a Henyey–Greenstein phase function.
pub fn hg_box(
    n: f64,
    half: glam::DVec3,
    sigma_s: f64,
    sigma_a: f64,
    g: f64,
) -> lightpath::rrte::Volume {
    use lightpath::eikonal::{BoundedField, Bounds, Profile};
    use lightpath::medium::{PhaseFunction, Scattering};
    lightpath::rrte::Volume {
        field: BoundedField::single(Profile::Constant { n }, Bounds::Box { half }, 1.0),
        sigma_s,
        sigma_a,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g }),
        density: None,
        parts: Vec::new(),
    }
}

/// A render scene with nothing but its step set: a clear unit sphere of `n = 1`, a point light at
/// its centre, no sensors; tests give what they need (`RenderScene { volume, light,
/// ..bare_scene(step) }`).
pub fn bare_scene(step: f64) -> lightpath::rrte::RenderScene {
    use glam::DVec3;
    use lightpath::eikonal::{BoundedField, Bounds, Profile};
    use lightpath::medium::{PhaseFunction, Scattering};
    use lightpath::rrte::{Light, RenderScene, Volume};
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Constant { n: 1.0 },
                Bounds::Sphere { radius: 1.0 },
                1.0,
            ),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Point {
            position: DVec3::ZERO,
        },
        sensors: vec![],
        probes: vec![],
        cameras: vec![],
        pinholes: vec![],
        surfaces: vec![],
        modulation: None,
        connections: Default::default(),
        reflections: 0,
        derivatives: vec![],
        tracing: Default::default(),
        transient: None,
        spectrum: None,
        step,
        max_steps: 100_000,
    }
}

/// A flux sensor on the plane `z`, facing +z, infinite.
pub fn flux(name: &str, z: f64) -> lightpath::rrte::Sensor {
    lightpath::rrte::Sensor::new(
        name.into(),
        lightpath::rrte::SensorKind::Flux,
        glam::DVec3::new(0.0, 0.0, z),
        glam::DVec3::Z,
        None,
        [1, 1],
    )
}

/// Render `scene` with `samples` photons (or camera paths) in 64 chunks from `seed`.
pub fn render(
    scene: &lightpath::rrte::RenderScene,
    samples: u64,
    seed: u64,
) -> (Estimate, lightpath::rrte::ParticleTracer<'_>) {
    let est = lightpath::rrte::ParticleTracer::new(scene);
    let e = estimate(&est, &Plan::new(seed, samples, samples / 64));
    (e, est)
}

/// The mean of the four probes of [`probes_about`] and its error, taken at its largest (the same
/// photons light them all).
pub fn probes_mean(e: &Estimate, est: &lightpath::rrte::ParticleTracer) -> (f64, f64) {
    let mean = |f: &dyn Fn(usize) -> f64| (0..4).map(f).sum::<f64>() / 4.0;
    (
        mean(&|i| e.mean[est.probe_total(i)].re),
        mean(&|i| e.stderr[est.probe_total(i)]),
    )
}

/// The probes' mean `(value, error)` agrees with a target's within 4 combined standard errors,
/// each error below its share `bounds` of its value.
pub fn assert_probes_count_as_target(probes: (f64, f64), target: (f64, f64), bounds: (f64, f64)) {
    let ((probe, sp), (target, st)) = (probes, target);
    eprintln!("fluence: probes {probe} ± {sp}, target {target} ± {st}");
    assert!(sp < bounds.0 * probe && st < bounds.1 * target, "{sp} {st}");
    assert!(
        (probe - target).abs() < 4.0 * sp.hypot(st),
        "probes {probe} ± {sp}, target {target} ± {st}"
    );
}

/// Channel `name` of an EXR file's first layer (top row first) and the image's (width, height).
pub fn exr_channel(path: &std::path::Path, name: &str) -> ((usize, usize), Vec<f32>) {
    let img = exr::prelude::read_first_flat_layer_from_file(path).unwrap();
    let size = (img.layer_data.size.0, img.layer_data.size.1);
    let c = img.layer_data.channel_data.list.iter();
    let c = c.clone().find(|c| c.name.to_string() == name).unwrap();
    match &c.sample_data {
        exr::prelude::FlatSamples::F32(v) => (size, v.clone()),
        _ => panic!("{name} is not f32"),
    }
}

/// A layer of the plain tracer: its faces `z0 < z1`, index, coefficients and HG `g`.
#[derive(Clone, Copy)]
pub struct Layer {
    pub z: [f64; 2],
    pub n: f64,
    pub sigma_s: f64,
    pub sigma_a: f64,
    pub g: f64,
}

/// Unpolarised Fresnel reflectance from index `n1` into `n2` at incidence cosine `cos_i`, by the
/// textbook amplitude formulas (1 beyond the critical angle).
pub fn fresnel(cos_i: f64, n1: f64, n2: f64) -> f64 {
    let sin_t = n1 / n2 * (1.0 - cos_i * cos_i).max(0.0).sqrt();
    if sin_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// A plain tracer of plane-parallel layers in air (index 1 between them), independent of the
/// renderer: a photon is a height `z` and a direction cosine `μ`; it flies straight to the next
/// collision or face, scatters with the layer's albedo (analog absorption) by Henyey–Greenstein,
/// and at each face reflects with the Fresnel probability or refracts by Snell's law in `μ`.
/// The layers' coefficients are scaled by `density(z)` (at most `max`), drawn by delta tracking:
/// tentative collisions against `σ_t · max`, kept with probability `density(z)/max`.
/// Returns the fractions of photons leaving below the first layer (R) and above the last (T).
pub fn plain_layers(
    layers: &[Layer],
    (density, max): (&dyn Fn(f64) -> f64, f64),
    photons: u64,
    rng: &mut lightpath::math::Rng,
) -> (f64, f64) {
    let (mut r_count, mut t_count) = (0u64, 0u64);
    for _ in 0..photons {
        // in layer `at` (None: in the air below, between or above), travelling with cosine mu
        let (mut z, mut mu, mut at) = (layers[0].z[0] - 1.0, 1.0f64, None::<usize>);
        loop {
            let Some(k) = at else {
                // in the air: straight to the next face along mu, or away
                let next = if mu > 0.0 {
                    layers.iter().position(|l| l.z[0] >= z - 1e-12)
                } else {
                    layers.iter().rposition(|l| l.z[1] <= z + 1e-12)
                };
                let Some(k) = next else {
                    if mu > 0.0 {
                        t_count += 1;
                    } else {
                        r_count += 1;
                    }
                    break;
                };
                let l = layers[k];
                z = if mu > 0.0 { l.z[0] } else { l.z[1] };
                if lightpath::math::uniform(rng) < fresnel(mu.abs(), 1.0, l.n) {
                    mu = -mu;
                    continue;
                }
                mu = mu.signum() * (1.0 - (1.0 - mu * mu) / (l.n * l.n)).sqrt();
                at = Some(k);
                continue;
            };
            let l = layers[k];
            let sigma_t = l.sigma_s + l.sigma_a;
            let s = -(1.0 - lightpath::math::uniform(rng)).ln() / (sigma_t * max);
            let z_new = z + mu * s;
            if z_new < l.z[0] || z_new > l.z[1] {
                z = if z_new > l.z[1] { l.z[1] } else { l.z[0] };
                if lightpath::math::uniform(rng) < fresnel(mu.abs(), l.n, 1.0) {
                    mu = -mu;
                    continue;
                }
                mu = mu.signum() * (1.0 - l.n * l.n * (1.0 - mu * mu)).sqrt();
                at = None;
                continue;
            }
            z = z_new;
            if lightpath::math::uniform(rng) * max >= density(z) {
                continue;
            }
            if lightpath::math::uniform(rng) >= l.sigma_s / sigma_t {
                break;
            }
            let g = l.g;
            let c = if g == 0.0 {
                1.0 - 2.0 * lightpath::math::uniform(rng)
            } else {
                let f = (1.0 - g * g) / (1.0 - g + 2.0 * g * lightpath::math::uniform(rng));
                (1.0 + g * g - f * f) / (2.0 * g)
            };
            let phi = 2.0 * std::f64::consts::PI * lightpath::math::uniform(rng);
            mu = mu * c
                + (1.0 - mu * mu).max(0.0).sqrt() * (1.0 - c * c).max(0.0).sqrt() * phi.cos();
        }
    }
    (
        r_count as f64 / photons as f64,
        t_count as f64 / photons as f64,
    )
}

/// The intensity along a collimated flux detector's axis (sensor 0 of `scene`, accepting within
/// `alpha` of its normal): its power over the cone's solid angle (up to the cone's angular
/// average), with its standard error, from `photons` photons.
pub fn intensity_in_cone(
    scene: &lightpath::rrte::RenderScene,
    alpha: f64,
    photons: u64,
    seed: u64,
) -> (f64, f64) {
    let (e, est) = render(scene, photons, seed);
    let k = est.power(0);
    let omega = 2.0 * std::f64::consts::PI * (1.0 - alpha.cos());
    (e.mean[k].re / omega, e.stderr[k] / omega)
}

/// Particle tracing (`particles` photons, seed 1), path tracing and bidirectional tracing
/// (`others` samples each, seeds 2 and 3) agree on the image of `s`'s first pinhole (12 × 8
/// pixels): its total and its two halves, within 4 combined standard errors.
pub fn three_estimators_agree(s: &lightpath::rrte::RenderScene, particles: u64, others: u64) {
    use lightpath::rrte::Tracing;
    let (a, est) = render(s, particles, 1);
    let mut p = s.clone();
    p.tracing = Tracing::FromCameras;
    let (b, _) = render(&p, others, 2);
    p.tracing = Tracing::Bidirectional;
    let (c, _) = render(&p, others, 3);
    let image = est.pinhole_image(0);
    // the sums over the left and right halves, their pixels' errors added in quadrature
    let half = |e: &Estimate, left: bool| {
        let (mut x, mut v) = (0.0, 0.0);
        for j in 0..8 {
            for i in if left { 0..6 } else { 6..12 } {
                let k = image.plane(None, 0) + j * 12 + i;
                x += e.mean[k].re;
                v += e.stderr[k].powi(2);
            }
        }
        (x, v.sqrt())
    };
    for (what, other) in [("paths", &b), ("bidirectional", &c)] {
        let k = image.total();
        let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], other.mean[k].re, other.stderr[k]);
        assert!(
            x > 0.0 && (x - y).abs() < 4.0 * sx.hypot(sy),
            "total: particles {x} ± {sx}, {what} {y} ± {sy}"
        );
        for left in [true, false] {
            let ((x, sx), (y, sy)) = (half(&a, left), half(other, left));
            assert!(
                x > 0.0 && (x - y).abs() < 4.0 * sx.hypot(sy),
                "left half {left}: particles {x} ± {sx}, {what} {y} ± {sy}"
            );
        }
    }
}

/// Four fluence probes at the corners of a regular tetrahedron `r √0.6` about `p`: their mean is
/// the mean fluence over the ball of radius `r` about `p` to second order (exact for a quadratic
/// field), what a target over that ball measures.
pub fn probes_about(p: glam::DVec3, r: f64) -> Vec<lightpath::rrte::Probe> {
    let a = r * 0.6f64.sqrt();
    let corners = [
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ];
    corners
        .iter()
        .enumerate()
        .map(|(i, c)| lightpath::rrte::Probe {
            name: format!("p{i}"),
            position: p + glam::DVec3::from_array(*c) * (a / 3f64.sqrt()),
        })
        .collect()
}
