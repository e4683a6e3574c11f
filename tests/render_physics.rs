//! The refractive renderer against closed forms and an independent tracer: energy balance, the
//! Fresnel slab (with its multiple internal reflections and their arrival times), a scattering slab
//! with mismatched faces against the plain layered tracer of `common`, a Luneburg lens focusing a beam
//! on its antipode, and a beam bending along the closed-form ray of a linear-gradient tank.

use crate::common;

use common::{Layer, bare_scene, flux, intensity_in_cone, plain_layers, render};
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Profile};
use lightpath::math::{Rng, stream_rng, uniform};
use lightpath::mc::Estimate;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{
    Light, ParticleTracer, RenderScene, Sensor, SensorKind, Total, Transient, Volume,
};

fn slab_volume(
    profile: Profile,
    n_out: f64,
    thickness: f64,
    sigma_s: f64,
    sigma_a: f64,
    g: f64,
) -> Volume {
    Volume {
        field: BoundedField::single(
            profile,
            Bounds::Box {
                half: DVec3::new(500.0, 500.0, 0.5 * thickness),
            },
            n_out,
        ),
        sigma_s,
        sigma_a,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g }),
        density: None,
        parts: Vec::new(),
    }
}

fn beam(z: f64, radius: f64) -> Light {
    Light::Beam {
        center: DVec3::new(0.0, 0.0, z),
        direction: DVec3::Z,
        radius,
    }
}

fn value(e: &Estimate, i: usize) -> (f64, f64) {
    (e.mean[i].re, e.stderr[i])
}

/// Non-scattering slab of index `n` between faces at ±L/2 in air: transmittance and reflectance of
/// the incoherent Fresnel series, `T = (1−R)² t / (1 − R² t²)` with `t = exp(−σ_a L)`, and the
/// arrival of each pass at optical path `z_gap + n L (2k + 1) + ...`, weight `(1−R)² R^{2k} t^{2k+1}`.
fn fresnel_slab(profile: Profile, n: f64) {
    let (l, sigma_a) = (1.0, 0.3);
    let volume = slab_volume(profile, 1.0, l, 0.0, sigma_a, 0.0);
    let scene = RenderScene {
        volume,
        light: beam(-1.1, 0.2),
        sensors: vec![flux("transmittance", 0.5), flux("reflectance", -0.5)],
        transient: Some(Transient {
            bins: 40,
            max_path: 20.0,
        }),
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 200_000, 7);
    let r = ((n - 1.0) / (n + 1.0)).powi(2);
    let t = (-sigma_a * l).exp();
    let trans = (1.0 - r).powi(2) * t / (1.0 - r * r * t * t);
    let refl = r + (1.0 - r).powi(2) * r * t * t / (1.0 - r * r * t * t);
    let sum = |sensor: usize| -> (f64, f64) {
        let o = est.sensor_image(sensor);
        let m: f64 = (0..40).map(|b| e.mean[o.plane(Some(b), 0)].re).sum();
        // the bins of one photon are exclusive: the total's error is that of a Bernoulli mean
        (m, (m * (1.0 - m) / e.samples as f64).sqrt())
    };
    let (tm, ts) = sum(0);
    let (rm, rs) = sum(1);
    assert!(
        (tm - trans).abs() < 4.0 * ts,
        "T = {tm} ± {ts}, closed form {trans}"
    );
    assert!(
        (rm - refl).abs() < 4.0 * rs,
        "R = {rm} ± {rs}, closed form {refl}"
    );
    let (am, as_) = value(&e, est.total(Total::Absorbed));
    assert!(
        (tm + rm + am - 1.0).abs() < 1e-12 + 4.0 * as_,
        "T + R + A = {}",
        tm + rm + am
    );
    // pass k (k = 0, 1, …) arrives at optical path 0.6 (air) + (2k + 1) n L
    let bin_width = 20.0 / 40.0;
    let pass = |k: usize| ((0.6 + (2 * k + 1) as f64 * n * l) / bin_width) as usize;
    let o = est.sensor_image(0);
    let bin = |b: usize| o.plane(Some(b), 0);
    let (m1, s1) = value(&e, bin(pass(0)));
    let (m2, s2) = value(&e, bin(pass(1)));
    let p1 = (1.0 - r).powi(2) * t;
    let p2 = p1 * r * r * t * t;
    assert!((m1 - p1).abs() < 4.0 * s1, "first pass {m1} ± {s1} vs {p1}");
    // few photons make the second pass: the error of a Bernoulli mean at p2
    let s2 = s2.max((p2 / e.samples as f64).sqrt());
    assert!(
        (m2 - p2).abs() < 4.0 * s2,
        "second pass {m2} ± {s2} vs {p2}"
    );
    let passes: Vec<usize> = (0..10).map(pass).collect();
    for b in (0..40).filter(|b| !passes.contains(b)) {
        assert_eq!(e.mean[bin(b)].re, 0.0, "light in time bin {b}");
    }
}

#[test]
fn a_clear_fresnel_slab_matches_its_closed_form_and_arrival_times() {
    // straight rays in closed form
    fresnel_slab(Profile::Constant { n: 1.5 }, 1.5);
    // the same slab stepped by the leapfrog integrator (a linear profile of zero gradient)
    fresnel_slab(
        Profile::Linear {
            n0: 1.5,
            gradient: DVec3::ZERO,
        },
        1.5,
    );
}

#[test]
fn every_photon_is_absorbed_escapes_or_is_reported() {
    // no absorption, no roulette: each photon escapes, exactly
    let volume = Volume {
        field: BoundedField::single(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.33,
        ),
        sigma_s: 2.0,
        sigma_a: 0.0,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.7 }),
        density: None,
        parts: Vec::new(),
    };
    let scene = RenderScene {
        volume,
        light: beam(-2.0, 0.9),
        sensors: vec![],
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 20_000, 3);
    assert_eq!(e.mean[est.total(Total::Escaped)].re, 1.0);
    assert_eq!(e.stderr[est.total(Total::Escaped)], 0.0);
    assert_eq!(e.mean[est.total(Total::Unfinished)].re, 0.0);
    // with absorption (and roulette): absorbed + escaped = 1 within the standard error
    let mut absorbing = scene.clone();
    absorbing.volume.sigma_a = 0.5;
    let (e, est) = render(&absorbing, 20_000, 3);
    let (a, sa) = value(&e, est.total(Total::Absorbed));
    let (x, sx) = value(&e, est.total(Total::Escaped));
    assert!(a > 0.1 && x > 0.1, "absorbed {a}, escaped {x}");
    assert!(
        (a + x - 1.0).abs() < 4.0 * (sa * sa + sx * sx).sqrt(),
        "{a} + {x}"
    );
}

/// A lamp inside a clear glass cube (n = 1.5, nothing scattering or absorbing): a direction whose
/// cosine with some axis exceeds `c = √(1 − 1/n²)` reaches that pair of faces within the escape
/// cone, keeps its cosines' sizes at every reflection and leaves in the end; every other
/// direction is held by total internal reflection for ever. With `c > 1/√2` the six cones do
/// not overlap, so `3 (1 − c)` of the light escapes and the rest is trapped. The trapped photons
/// are given up after `MAX_REFLECTIONS` reflections and counted as unfinished (without the
/// limit the render does not end), and the two add up to 1.
#[test]
fn light_trapped_in_a_clear_glass_cube_is_given_up_as_unfinished() {
    let n = 1.5;
    // the bare scene's clear volume, made a glass cube
    let mut scene = bare_scene(0.01);
    scene.volume.field = BoundedField::single(
        Profile::Constant { n },
        Bounds::Box {
            half: DVec3::splat(0.5),
        },
        1.0,
    );
    scene.light = Light::Point {
        position: DVec3::new(0.1, 0.05, -0.02),
    };
    let (e, est) = render(&scene, 2_000, 5);
    let (x, sx) = value(&e, est.total(Total::Escaped));
    let (u, su) = value(&e, est.total(Total::Unfinished));
    let c = (1.0 - 1.0 / (n * n)).sqrt();
    let escapes = 3.0 * (1.0 - c);
    assert!(
        (x - escapes).abs() < 4.0 * sx && (u - (1.0 - escapes)).abs() < 4.0 * su,
        "escaped {x} ± {sx}, unfinished {u} ± {su}; closed form {escapes}"
    );
    assert!((x + u - 1.0).abs() < 1e-12, "{x} + {u}");
}

#[test]
fn a_scattering_slab_with_fresnel_faces_matches_a_plain_slab_tracer() {
    let (n, l, sigma_s, sigma_a, g) = (1.4, 1.0, 1.8, 0.2, 0.6);
    let photons = 100_000;
    // the plain layered tracer of `common`: one layer, no density
    let slab = Layer {
        z: [-0.5 * l, 0.5 * l],
        n,
        sigma_s,
        sigma_a,
        g,
    };
    let no_density: (&dyn Fn(f64) -> f64, f64) = (&|_| 1.0, 1.0);
    let (r_ref, t_ref) = plain_layers(&[slab], no_density, photons, &mut stream_rng(11, 0));
    let ref_err = |p: f64| (p * (1.0 - p) / photons as f64).sqrt();
    for profile in [
        Profile::Constant { n },
        Profile::Linear {
            n0: n,
            gradient: DVec3::ZERO,
        },
    ] {
        let scene = RenderScene {
            volume: slab_volume(profile, 1.0, l, sigma_s, sigma_a, g),
            light: beam(-1.0, 0.0),
            sensors: vec![flux("T", 0.5), flux("R", -0.5)],
            ..bare_scene(0.01)
        };
        let (e, est) = render(&scene, photons, 5);
        let (t, st) = value(&e, est.sensor_image(0).first);
        let (r, sr) = value(&e, est.sensor_image(1).first);
        let (a, _) = value(&e, est.total(Total::Absorbed));
        let lost = 1.0 - t - r - a;
        assert!(
            lost.abs() < 0.01,
            "light lost sideways or unaccounted: {lost}"
        );
        let tol_t = 4.0 * (st * st + ref_err(t_ref).powi(2)).sqrt();
        let tol_r = 4.0 * (sr * sr + ref_err(r_ref).powi(2)).sqrt();
        assert!(
            (t - t_ref).abs() < tol_t,
            "T {t} ± {st} vs plain tracer {t_ref}"
        );
        assert!(
            (r - r_ref).abs() < tol_r,
            "R {r} ± {sr} vs plain tracer {r_ref}"
        );
    }
}

/// Power-weighted centroid and RMS radius of a screen image about its centre.
fn spot(e: &Estimate, est: &ParticleTracer, sensor: &Sensor) -> (DVec3, f64, f64) {
    let o = est.sensor_image(0).first;
    let [nx, ny] = sensor.pixels;
    let size = sensor.size.unwrap();
    let (mut total, mut c, mut r2) = (0.0, DVec3::ZERO, 0.0);
    for j in 0..ny {
        for i in 0..nx {
            let w = e.mean[o + j * nx + i].re;
            let a = ((i as f64 + 0.5) / nx as f64 - 0.5) * size[0];
            let b = ((j as f64 + 0.5) / ny as f64 - 0.5) * size[1];
            let p = sensor.center + sensor.right * a + sensor.up * b;
            total += w;
            c += p * w;
            r2 += w * (a * a + b * b);
        }
    }
    (c / total, (r2 / total).sqrt(), total)
}

#[test]
fn a_scattering_luneburg_lens_focuses_a_beam_on_its_antipode() {
    let volume = Volume {
        field: BoundedField::single(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.0,
        ),
        sigma_s: 0.05,
        sigma_a: 0.0,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.9 }),
        density: None,
        parts: Vec::new(),
    };
    let screen = Sensor::new(
        "screen".into(),
        SensorKind::Screen,
        DVec3::new(0.0, 0.0, 1.0),
        DVec3::Z,
        Some([0.5, 0.5]),
        [51, 51],
    );
    let scene = RenderScene {
        volume,
        light: beam(-2.0, 0.4),
        sensors: vec![screen.clone()],
        ..bare_scene(0.002)
    };
    let (e, est) = render(&scene, 40_000, 9);
    let (c, rms, total) = spot(&e, &est, &screen);
    // most light (all but what scattered out of the focus) lands in a spot far smaller than the beam
    assert!(total > 0.85, "fraction on the screen {total}");
    assert!(c.truncate().length() < 0.01, "centroid {c}");
    assert!(rms < 0.05, "RMS spot radius {rms} (beam radius 0.4)");
    // the brightest pixel is the one at the antipode
    let o = est.sensor_image(0).first;
    let centre = 25 * 51 + 25;
    let max = (0..51 * 51).max_by(|&a, &b| e.mean[o + a].re.total_cmp(&e.mean[o + b].re));
    assert_eq!(max, Some(centre));
}

#[test]
fn a_beam_in_a_linear_gradient_tank_follows_the_closed_form_ray() {
    // n = n0 + a y: a ray launched along z at y = 0 follows y(z) = (n0/a)(cosh(a z/n0) − 1)
    let (n0, a, length) = (1.33, 0.02, 10.0);
    let volume = Volume {
        field: BoundedField::single(
            Profile::Linear {
                n0,
                gradient: DVec3::new(0.0, a, 0.0),
            },
            Bounds::Box {
                half: DVec3::new(5.0, 5.0, 0.5 * length),
            },
            1.0,
        ),
        sigma_s: 0.02,
        sigma_a: 0.01,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.95 }),
        density: None,
        parts: Vec::new(),
    };
    let y_exit = n0 / a * ((a * length / n0).cosh() - 1.0);
    let screen = Sensor::new(
        "exit".into(),
        SensorKind::Screen,
        DVec3::new(0.0, y_exit, 0.5 * length),
        DVec3::Z,
        Some([0.6, 0.6]),
        [61, 61],
    );
    let scene = RenderScene {
        volume,
        light: beam(-6.0, 0.02),
        sensors: vec![screen.clone()],
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 40_000, 13);
    let (c, _, total) = spot(&e, &est, &screen);
    assert!(total > 0.7, "fraction near the predicted exit {total}");
    assert!(y_exit > 0.7, "the test needs a visible bend: {y_exit}");
    assert!(
        (c.y - y_exit).abs() < 0.01,
        "centroid y {} vs closed-form ray {y_exit}",
        c.y
    );
    assert!(c.x.abs() < 0.01, "centroid x {}", c.x);
}

fn probe_scene(profile: Profile, sigma_s: f64, g: f64, light: Light, probe: DVec3) -> RenderScene {
    RenderScene {
        volume: Volume {
            field: BoundedField::single(profile, Bounds::Sphere { radius: 1.0 }, 1.0),
            sigma_s,
            sigma_a: 0.1 * sigma_s,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g }),
            density: None,
            parts: Vec::new(),
        },
        light,
        sensors: vec![],
        probes: vec![lightpath::rrte::Probe {
            name: "probe".into(),
            position: probe,
        }],
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
        step: 0.004,
        max_steps: 100_000,
    }
}

/// Fluence rate at `y` by brute force: straight flights in a sphere of radius 1 (index matched),
/// isotropic point source at `x0`, HG scattering (`σ_s`, `σ_a`, `g`), and the track length inside
/// a ball of radius `eps` about `y` divided by its volume. Independent of the renderer.
fn ball_fluence(
    (x0, y, eps): (DVec3, DVec3, f64),
    (sigma_s, sigma_a, g): (f64, f64, f64),
    photons: u64,
    rng: &mut Rng,
) -> (f64, f64) {
    let sigma_t = sigma_s + sigma_a;
    let ball = 4.0 / 3.0 * std::f64::consts::PI * eps.powi(3);
    let (mut sum, mut sq) = (0.0, 0.0);
    for _ in 0..photons {
        let mut x = x0;
        let z = 1.0 - 2.0 * uniform(rng);
        let phi = 2.0 * std::f64::consts::PI * uniform(rng);
        let r = (1.0 - z * z).sqrt();
        let mut d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        let mut tally = 0.0;
        loop {
            let s = -(1.0 - uniform(rng)).ln() / sigma_t;
            // distance to the unit sphere along d
            let b = x.dot(d);
            let exit = -b + (b * b - (x.length_squared() - 1.0)).sqrt();
            let len = s.min(exit);
            // chord of the segment [0, len] inside the ball about y
            let p = y - x;
            let t = p.dot(d);
            let h2 = p.length_squared() - t * t;
            if h2 < eps * eps {
                let half = (eps * eps - h2).sqrt();
                let (a, c) = ((t - half).max(0.0), (t + half).min(len));
                if c > a {
                    tally += c - a;
                }
            }
            if s >= exit || uniform(rng) >= sigma_s / sigma_t {
                break;
            }
            x += d * s;
            // HG about d
            let f = (1.0 - g * g) / (1.0 - g + 2.0 * g * uniform(rng));
            let c = ((1.0 + g * g - f * f) / (2.0 * g)).clamp(-1.0, 1.0);
            let phi = 2.0 * std::f64::consts::PI * uniform(rng);
            let (e1, e2) = lightpath::math::orthonormal_basis(d);
            let sn = (1.0 - c * c).sqrt();
            d = (d * c + e1 * (sn * phi.cos()) + e2 * (sn * phi.sin())).normalize();
        }
        let v = tally / ball;
        sum += v;
        sq += v * v;
    }
    let n = photons as f64;
    let mean = sum / n;
    (mean, ((sq / n - mean * mean) / n).sqrt())
}

#[test]
fn a_fluence_probe_matches_a_track_length_tally_with_straight_and_curved_connections() {
    let (x0, y) = (DVec3::new(0.1, -0.2, 0.0), DVec3::new(0.3, 0.35, -0.2));
    let (sigma_s, g) = (2.0, 0.5);
    let (reference, ref_se) = ball_fluence(
        (x0, y, 0.05),
        (sigma_s, 0.1 * sigma_s, g),
        400_000,
        &mut stream_rng(21, 0),
    );
    for profile in [
        Profile::Constant { n: 1.0 },
        Profile::Linear {
            n0: 1.0,
            gradient: DVec3::ZERO,
        },
    ] {
        let straight = matches!(profile, Profile::Constant { .. });
        let scene = probe_scene(profile, sigma_s, g, Light::Point { position: x0 }, y);
        let photons = if straight { 100_000 } else { 5_000 };
        let (e, est) = render(&scene, photons, 17);
        let (f, se) = value(&e, est.probe_total(0));
        let tol = 4.0 * (se * se + ref_se * ref_se).sqrt();
        assert!(
            (f - reference).abs() < tol,
            "{} connections: fluence {f} ± {se} vs track length in a ball {reference} ± {ref_se}",
            if straight { "straight" } else { "curved" }
        );
        // a straight connection always exists; Newton from a random start finds the curved one
        // mostly (a start pointing away from the probe is a null path of Alg. 3)
        let found =
            e.mean[est.total(Total::Connected)].re / e.mean[est.total(Total::Connections)].re;
        if straight {
            assert_eq!(found, 1.0);
        } else {
            assert!(found > 0.7, "success rate {found}");
        }
    }
}

/// A lamp and a fluence probe inside a clear, absorbing glass cube (n = 1.5 in air, half-width
/// 1): with `render.reflections = 1` the probe sees the lamp directly and once in each of the six
/// faces, each path from the lamp's mirror image in the face, `e^{−σ_a s} R / (4π s²)` with `s`
/// the distance from the image and `R` the Fresnel reflectance inside (total beyond the critical
/// angle); without reflections, directly only.
#[test]
fn a_probe_in_a_glass_cube_sees_the_lamp_reflected_in_each_face() {
    let (q, y) = (DVec3::new(0.3, -0.2, 0.1), DVec3::new(-0.5, 0.4, -0.3));
    let mut scene = probe_scene(
        Profile::Constant { n: 1.5 },
        0.0,
        0.0,
        Light::Point { position: q },
        y,
    );
    scene.volume.field = BoundedField::single(
        Profile::Constant { n: 1.5 },
        Bounds::Box {
            half: DVec3::splat(1.0),
        },
        1.0,
    );
    scene.volume.sigma_a = 0.2;
    let seen = |s: f64, r: f64| r * (-0.2 * s).exp() / (4.0 * std::f64::consts::PI * s * s);
    let direct = seen((y - q).length(), 1.0);
    let mut reflected = 0.0;
    for axis in 0..3 {
        for side in [-1.0, 1.0] {
            let mut image = q;
            image[axis] = 2.0 * side - q[axis];
            let to = y - image;
            let cos_i = to[axis].abs() / to.length();
            let sin2_t = 1.5 * 1.5 * (1.0 - cos_i * cos_i);
            let r = if sin2_t >= 1.0 {
                1.0
            } else {
                let cos_t = (1.0 - sin2_t).sqrt();
                let rs = (1.5 * cos_i - cos_t) / (1.5 * cos_i + cos_t);
                let rp = (cos_i - 1.5 * cos_t) / (cos_i + 1.5 * cos_t);
                0.5 * (rs * rs + rp * rp)
            };
            reflected += seen(to.length(), r);
        }
    }
    let (e, est) = render(&scene, 20_000, 9);
    let (f, se) = value(&e, est.probe_total(0));
    assert!((f - direct).abs() < 1e-12 * direct, "{f} vs {direct}");
    scene.reflections = 1;
    let (e, est) = render(&scene, 20_000, 9);
    let (f, se1) = value(&e, est.probe_total(0));
    let want = direct + reflected;
    assert!(
        (f - want).abs() < 4.0 * se1 && se1 < 0.02 * reflected,
        "{f} ± {se1} vs {want} ({direct} directly, ± {se})"
    );
}

#[test]
fn a_probe_in_a_clear_luneburg_lens_sees_the_ray_tube_of_its_curved_path() {
    // a point source and a probe inside the lens, nothing scattering: the fluence is the source's
    // intensity over the ray tube's cross-section per solid angle, 1/(4π dA⊥/dω); brute force
    // counts the rays from the source passing within eps of the probe
    let (x0, y) = (DVec3::new(0.05, 0.0, -0.85), DVec3::new(-0.05, 0.1, 0.6));
    let mut scene = probe_scene(
        Profile::Luneburg { radius: 1.0 },
        0.0,
        0.0,
        Light::Point { position: x0 },
        y,
    );
    scene.volume.sigma_a = 0.0;
    let (e, est) = render(&scene, 2000, 3);
    // one path; its weight varies only through Alg. 3's count of restarts
    let (f, se) = value(&e, est.probe_total(0));
    let tracer = lightpath::eikonal::Tracer {
        field: &scene.volume.field,
        step: 0.01,
        max_steps: 100_000,
    };
    let eps = 0.08;
    let rays = 300_000;
    let mut rng = stream_rng(4, 0);
    let mut hits = 0u64;
    for _ in 0..rays {
        let d = lightpath::math::uniform_sphere(uniform(&mut rng), uniform(&mut rng));
        let mut prev = x0;
        let mut close = false;
        tracer.trace_with(x0, d, |p| {
            // distance from y to the chord prev → p
            let (a, b) = (prev, p);
            let ab = b - a;
            let t = ((y - a).dot(ab) / ab.length_squared().max(1e-300)).clamp(0.0, 1.0);
            close |= (a + ab * t - y).length() < eps;
            prev = p;
        });
        hits += close as u64;
    }
    let p = hits as f64 / rays as f64;
    let brute = p / (std::f64::consts::PI * eps * eps);
    let brute_se = (p * (1.0 - p) / rays as f64).sqrt() / (std::f64::consts::PI * eps * eps);
    // the straight-line value 1/(4π s²) differs: the lens bends the tube
    let straight = 1.0 / (4.0 * std::f64::consts::PI * (y - x0).length_squared());
    assert!(
        (f - straight).abs() > 8.0 * brute_se,
        "the test must see the bending: {f} vs {straight}"
    );
    let tol = 4.0 * (brute_se * brute_se + se * se).sqrt();
    assert!(
        (f - brute).abs() < tol,
        "probe {f} ± {se} vs brute force {brute} ± {brute_se}"
    );
}

#[test]
fn orthographic_and_pinhole_cameras_see_the_intensity_a_collimated_detector_counts() {
    // a scattering Luneburg lens lit by a beam along z, seen from the side (+x): the camera
    // connects every scattering event through the surface to the direction +x (a direction BVP on
    // curved rays), a flux detector behind a 10° collimator counts the photons leaving along it;
    // intensity = power in the cone / its solid angle (up to the cone's angular average)
    let volume = Volume {
        field: BoundedField::single(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.0,
        ),
        sigma_s: 1.0,
        sigma_a: 0.1,
        scattering: Scattering::single(PhaseFunction::Isotropic),
        density: None,
        parts: Vec::new(),
    };
    let mut detector = flux("collimated", 0.0);
    detector = Sensor::new(
        detector.name,
        SensorKind::Flux,
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::X,
        None,
        [1, 1],
    );
    let alpha = 10f64.to_radians();
    detector.acceptance = Some(alpha);
    let base = RenderScene {
        volume,
        light: beam(-2.0, 0.6),
        sensors: vec![detector],
        ..bare_scene(0.005)
    };
    let (reference, ref_se) = intensity_in_cone(&base, alpha, 400_000, 31);
    let mut scene = base.clone();
    scene.sensors.clear();
    scene.cameras.push(lightpath::rrte::Camera::new(
        "side".into(),
        DVec3::X,
        DVec3::new(2.0, 0.0, 0.0),
        [2.2, 2.2],
        [11, 11],
    ));
    // and a pinhole far along +x: its irradiance times the distance² is the same intensity (to
    // (R/D)² = 0.25 %), through connections that end at a point outside
    let distance = 20.0;
    scene.pinholes.push(
        lightpath::rrte::Pinhole::looking_at(
            "far".into(),
            DVec3::new(distance, 0.0, 0.0),
            DVec3::ZERO,
            DVec3::Y,
            8f64.to_radians(),
            [11, 11],
        )
        .unwrap(),
    );
    let (e, est) = render(&scene, 4_000, 37);
    let cam = &scene.cameras[0];
    let (sum, s_sum) = value(&e, est.camera_image(0).total());
    let (i, si) = (sum * cam.pixel_area(), s_sum * cam.pixel_area());
    let tol = 4.0 * (si * si + ref_se * ref_se).sqrt();
    assert!(
        (i - reference).abs() < tol,
        "camera intensity {i} ± {si} vs collimated detector {reference} ± {ref_se}"
    );
    let (irr, s_irr) = value(&e, est.pinhole_image(0).total());
    let (ip, sip) = (irr * distance * distance, s_irr * distance * distance);
    let tol = 4.0 * (sip * sip + ref_se * ref_se).sqrt();
    assert!(
        (ip - reference).abs() < tol,
        "pinhole irradiance × D² {ip} ± {sip} vs collimated detector {reference} ± {ref_se}"
    );
    // its image sums to the irradiance: Σ L · cos³θ · pixel area (θ ≤ 4°)
    let pin = &scene.pinholes[0];
    let o = est.pinhole_image(0).plane(None, 0);
    let image: f64 = (0..121).map(|k| e.mean[o + k].re).sum::<f64>() * pin.pixel_area();
    assert!(
        (image - irr).abs() < 0.01 * irr,
        "image {image} vs irradiance {irr}"
    );
    // the image is of the lens: nothing outside the disc of radius 1 it projects to
    let o = est.camera_image(0).plane(None, 0);
    for j in 0..11 {
        for k in 0..11 {
            let (a, b) = ((k as f64 + 0.5) * 0.2 - 1.1, (j as f64 + 0.5) * 0.2 - 1.1);
            if a * a + b * b > 1.3 {
                assert_eq!(
                    e.mean[o + j * 11 + k].re,
                    0.0,
                    "light outside the lens at {a}, {b}"
                );
            }
        }
    }
}

/// An ultrasonic GRIN lens (m = 0) in clear water under a beam, with a small flux window at the
/// exit face whose power depends on how strongly the field focuses.
fn ultrasonic_lens(n_max: f64) -> RenderScene {
    let mut window = flux("window", 5.0);
    window.size = Some([0.2, 0.2]);
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Ultrasonic {
                    n0: 1.33,
                    n_max,
                    k_r: 2.0,
                    m: 0,
                },
                Bounds::Cylinder {
                    radius: 3.0,
                    half_length: 5.0,
                },
                1.33,
            ),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        },
        light: beam(-6.0, 0.4),
        sensors: vec![window],
        ..bare_scene(0.05)
    }
}

#[test]
fn a_modulated_ultrasonic_field_averages_its_phases() {
    let n_max = 0.01;
    // the time average by sampling a phase per photon
    let mut modulated = ultrasonic_lens(n_max);
    modulated.modulation = Some(lightpath::rrte::Modulation::Sinusoidal);
    let (e, est) = render(&modulated, 40_000, 41);
    let (m, sm) = value(&e, est.power(0));
    // against the midpoint rule over 16 frozen phases θ in (−π/2, π/2), n_max sin θ
    let k = 16;
    let (mut avg, mut var) = (0.0, 0.0);
    for i in 0..k {
        let theta = std::f64::consts::PI * ((i as f64 + 0.5) / k as f64 - 0.5);
        let frozen = ultrasonic_lens(n_max * theta.sin());
        let (e, est) = render(&frozen, 5_000, 43 + i as u64);
        let (p, sp) = value(&e, est.power(0));
        avg += p / k as f64;
        var += sp * sp / (k * k) as f64;
    }
    let tol = 4.0 * (sm * sm + var).sqrt();
    assert!(
        (m - avg).abs() < tol,
        "modulated {m} ± {sm} vs phase average {avg} ± {}",
        var.sqrt()
    );
    // the static field at full amplitude focuses more: the test sees the modulation
    let fixed = ultrasonic_lens(n_max);
    let (e, est) = render(&fixed, 20_000, 47);
    let (st, sst) = value(&e, est.power(0));
    assert!(
        st - m > 4.0 * (sst * sst + sm * sm).sqrt(),
        "static {st} ± {sst} vs modulated {m}"
    );
}

#[test]
fn a_strobed_field_is_the_field_at_its_phase() {
    let text = |modulation: &str| {
        format!(
            "[field]\nprofiles = [{{ kind = \"ultrasonic\", n0 = 1.33, n_max = 0.01, k_r = 2.0, m = 0 }}]\nbounds = {{ kind = \"cylinder\", radius = 3.0, half_length = 5.0 }}\nn_out = 1.33\n[light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -6.0]\ndirection = [0.0, 0.0, 1.0]\n{modulation}"
        )
    };
    let scene = |m: &str| match lightpath::config::load_text(&text(m)).unwrap() {
        lightpath::config::Task::Render(t) => t.scene,
        _ => panic!("a render"),
    };
    let n_max = |s: &RenderScene| match s.volume.field.profiles[0] {
        Profile::Ultrasonic { n_max, .. } => n_max,
        _ => panic!("ultrasonic"),
    };
    // at the peak the field is the static one, bit for bit; at 30° half of it; at −90° inverted
    assert_eq!(
        scene("[modulation]\nkind = \"strobed\"\nphase_deg = 90.0\n"),
        scene("")
    );
    let half = scene("[modulation]\nkind = \"strobed\"\nphase_deg = 30.0\n");
    assert!((n_max(&half) - 0.005).abs() < 1e-15);
    assert_eq!(
        n_max(&scene(
            "[modulation]\nkind = \"strobed\"\nphase_deg = -90.0\n"
        )),
        -0.01
    );
    // a continuous modulation keeps the static amplitude and samples the phase per photon
    let cw = scene("[modulation]\nkind = \"sinusoidal\"\n");
    assert_eq!(n_max(&cw), 0.01);
    assert_eq!(cw.modulation, Some(lightpath::rrte::Modulation::Sinusoidal));
}

/// A beam focused by a lens outside on a point inside a clear, index-matched ball: every ray
/// crosses the focus, so a small target about it reads its diameter `2a` over its volume for
/// every photon; beyond the focus the rays spread uniformly over a disc of radius `R L/F` (`F`
/// from the beam's disc to the focus, `L` from the focus to the plane, along the axis), about
/// the line through the disc's centre and the focus, which a spot there reads as
/// `(w²/2R'²)(1 − e^{−2R'²/w²})`.
#[test]
fn a_focused_beam_crosses_its_focus_and_spreads_uniformly_beyond_it() {
    use lightpath::rrte::Region;
    let (centre, focus) = (DVec3::new(0.0, 0.0, -2.0), DVec3::new(0.1, 0.0, 0.4));
    let (radius, w, a, plane) = (0.5, 0.4, 0.05, 2.0);
    let ratio = (plane - focus.z) / (focus.z - centre.z);
    let beyond = focus + (focus - centre) * ratio;
    let mut spot = Sensor::new(
        "beyond".into(),
        SensorKind::Spot,
        beyond,
        DVec3::Z,
        None,
        [1, 1],
    );
    spot.window = Some(w);
    let target = Sensor::target(
        "focus".into(),
        Region::Sphere {
            center: focus,
            radius: a,
        },
    );
    let scene = RenderScene {
        light: Light::FocusedBeam {
            center: centre,
            direction: DVec3::Z,
            radius,
            focus,
        },
        sensors: vec![target, spot],
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 20_000, 3);
    let (fluence, _) = value(&e, est.power(0));
    let exact = 2.0 * a / (4.0 / 3.0 * std::f64::consts::PI * a.powi(3));
    assert!(
        (fluence / exact - 1.0).abs() < 1e-6,
        "{fluence} against {exact}"
    );
    let spread = radius * ratio;
    let exact = w * w / (2.0 * spread * spread) * (1.0 - (-2.0 * spread * spread / (w * w)).exp());
    let (v, se) = value(&e, est.power(1));
    assert!(se < 0.01 * exact, "{se} for {exact}");
    assert!((v - exact).abs() < 4.0 * se, "{v} ± {se} against {exact}");
}
