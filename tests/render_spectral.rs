//! Spectral rendering against closed forms: a tilted glass plate displaces a beam by each
//! wavelength's refraction (one line at a time, and white light in R, G, B against the colour
//! weights integrated over the spectrum), and a render at one line of a dispersive crown/flint
//! mixture equals the render of the field written out by hand at that wavelength.

use crate::common;

use common::bare_scene;
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Profile};
use lightpath::mc::Estimate;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{
    Dispersion, Light, Material, ParticleTracer, RenderScene, Sensor, SensorKind, Spectrum, Volume,
};

const REFERENCE_NM: f64 = 587.56;

fn render(scene: &RenderScene, samples: u64) -> (Estimate, ParticleTracer<'_>) {
    common::render(scene, samples, 7)
}

fn bk7() -> Material {
    Material::named("bk7").unwrap()
}

/// Angle of incidence on the plate, its thickness, and where the screen's pixels start.
const THETA: f64 = std::f64::consts::FRAC_PI_3;
const THICKNESS: f64 = 10.0;
const PIXELS: usize = 400;
const PIXEL: f64 = 0.001;
const X0: f64 = 6.73;

/// A clear N-BK7 plate (faces at z = ±5) in air, a thin beam entering its front face at the origin
/// at 60°, and a strip of pixels along x on its back face.
fn plate(spectrum: Spectrum) -> RenderScene {
    let (s, c) = THETA.sin_cos();
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Constant {
                    n: bk7().index(REFERENCE_NM),
                },
                Bounds::Box {
                    half: DVec3::new(50.0, 50.0, 0.5 * THICKNESS),
                },
                1.0,
            ),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(-5.0 * s / c, 0.0, -10.0),
            direction: DVec3::new(s, 0.0, c),
            radius: 0.0,
        },
        sensors: vec![Sensor {
            name: "strip".into(),
            kind: SensorKind::Screen,
            center: DVec3::new(X0 + 0.5 * PIXEL * PIXELS as f64, 0.0, 0.5 * THICKNESS),
            normal: DVec3::Z,
            right: DVec3::X,
            up: DVec3::Y,
            size: Some([PIXEL * PIXELS as f64, 0.02]),
            pixels: [PIXELS, 1],
            acceptance: None,
            region: None,
            window: None,
            filter: lightpath::rrte::Filter::Box,
        }],
        spectrum: Some(spectrum),
        ..bare_scene(0.01)
    }
}

/// Where the beam of wavelength `l` leaves the plate (Snell), and the fraction passing both faces
/// (unpolarised Fresnel, the same at both).
fn plate_closed_form(l: f64) -> (f64, f64) {
    let n = bk7().index(l);
    let (s, ci) = THETA.sin_cos();
    let ct = (1.0 - (s / n).powi(2)).sqrt();
    let rs = (ci - n * ct) / (ci + n * ct);
    let rp = (n * ci - ct) / (n * ci + ct);
    let r = 0.5 * (rs * rs + rp * rp);
    (THICKNESS * (s / n) / ct, (1.0 - r) * (1.0 - r))
}

/// The x of pixel `i`'s centre.
fn pixel_x(i: usize) -> f64 {
    X0 + (i as f64 + 0.5) * PIXEL
}

/// One channel's power-weighted centroid along the strip and its summed power (the tracer's
/// screen images hold power per pixel).
fn centroid(e: &Estimate, est: &ParticleTracer, channel: usize) -> (f64, f64) {
    let o = est.sensor_image(0).plane(None, channel);
    let (mut p, mut px) = (0.0, 0.0);
    for i in 0..PIXELS {
        let v = e.mean[o + i].re;
        p += v;
        px += v * pixel_x(i);
    }
    (px / p, p)
}

/// One line at a time: the spot sits where Snell puts that wavelength (within a pixel, 1 µm of
/// a 70 µm spread between 450 and 650 nm), with the Fresnel transmission of both faces.
#[test]
fn a_line_refracts_at_its_own_index() {
    let n = 20_000;
    let mut spots = Vec::new();
    for l in [450.0, 650.0] {
        let scene = plate(Spectrum::new(
            [l, l],
            REFERENCE_NM,
            Some(Dispersion::Scaled(bk7())),
            None,
        ));
        let (e, est) = render(&scene, n);
        assert_eq!(est.sensor_image(0).channels, 1);
        let (x, power) = centroid(&e, &est, 0);
        let (want, t) = plate_closed_form(l);
        let sigma = (t * (1.0 - t) / n as f64).sqrt();
        assert!(
            (x - want).abs() < PIXEL,
            "{l} nm: spot at {x}, Snell {want}"
        );
        assert!(
            (power - t).abs() < 4.0 * sigma,
            "{l} nm: transmitted {power}, Fresnel {t} ± {sigma}"
        );
        spots.push(x);
    }
    // blue bends more: its spot is nearer the entry point
    assert!(spots[1] - spots[0] > 0.06, "{spots:?}");
}

/// White light: every channel's centroid and power equal the colour-weighted averages of the
/// closed form over the spectrum (each photon carries one wavelength and its R, G, B weights), and
/// the blue channel's spot lies nearest the entry point, the red one farthest.
#[test]
fn white_light_splits_into_its_colours() {
    let spectrum = Spectrum::new(
        [380.0, 780.0],
        REFERENCE_NM,
        Some(Dispersion::Scaled(bk7())),
        None,
    );
    let scene = plate(spectrum.clone());
    let n = 40_000;
    let (e, est) = render(&scene, n);
    assert_eq!(est.sensor_image(0).channels, 3);
    // the colour-weighted closed form, by the midpoint rule over the spectrum
    let nodes = 4000;
    let mut want = [[0.0; 2]; 3];
    let mut power = 0.0;
    for k in 0..nodes {
        let l = spectrum.sample((k as f64 + 0.5) / nodes as f64);
        let (x, t) = plate_closed_form(l);
        let w = spectrum.colour(l);
        for c in 0..3 {
            want[c][0] += w[c] * t * x / nodes as f64;
            want[c][1] += w[c] * t / nodes as f64;
        }
        power += t / nodes as f64;
    }
    let mut xs = [0.0; 3];
    for c in 0..3 {
        let (x, p) = centroid(&e, &est, c);
        let wx = want[c][0] / want[c][1];
        assert!(
            (x - wx).abs() < 2.0 * PIXEL,
            "channel {c}: centroid {x}, expected {wx}"
        );
        // each photon lands in one pixel: the channel's error is its pixels' in quadrature
        let plane = est.sensor_image(0).plane(None, c);
        let se = (0..PIXELS)
            .map(|i| e.stderr[plane + i].powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            (p - want[c][1]).abs() < 4.0 * se,
            "channel {c}: power {p} ± {se}, expected {}",
            want[c][1]
        );
        xs[c] = x;
    }
    assert!(
        xs[2] + 0.01 < xs[1] && xs[1] + 0.005 < xs[0],
        "R, G, B at {xs:?}"
    );
    // the uncoloured total is the transmitted fraction of the emitted power
    let total = est.sensor_image(0).total();
    let (p, se) = (e.mean[total].re, e.stderr[total]);
    assert!((p - power).abs() < 4.0 * se + 1e-9, "{p} ± {se} vs {power}");
}

/// A scattering sphere mixing crown glass (surface) into flint (centre) linearly in radius, as
/// paper 002's heterogeneous sphere, in a dispersive outer medium: rendered at one line through
/// the dispersion maps, and with both indices written out at that wavelength, the images agree to
/// round-off (the same random numbers: a line draws no wavelength).
#[test]
fn a_mixture_at_one_line_is_the_field_at_that_line() {
    let flint = Material::named("f2").unwrap();
    let water = Material::Cauchy {
        a: 1.324,
        b: 0.00306,
        c: 0.0,
    };
    let l = 450.0;
    let sphere = |n_centre: f64, n_surface: f64, n_out: f64, spectrum| RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::SphericalPolynomial {
                    n0: n_centre,
                    coefficients: vec![n_surface - n_centre],
                },
                Bounds::Sphere { radius: 1.0 },
                n_out,
            ),
            sigma_s: 0.3,
            sigma_a: 0.05,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.6 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.7,
        },
        sensors: vec![Sensor::new(
            "back".into(),
            SensorKind::Screen,
            DVec3::new(0.0, 0.0, 1.6),
            DVec3::Z,
            Some([2.0, 2.0]),
            [21, 21],
        )],
        spectrum,
        ..bare_scene(0.005)
    };
    let r = REFERENCE_NM;
    let n_out = 1.333;
    let mapped = sphere(
        flint.index(r),
        bk7().index(r),
        n_out,
        Some(Spectrum::new(
            [l, l],
            r,
            Some(Dispersion::Mixed(bk7(), flint.clone())),
            Some(water.clone()),
        )),
    );
    let by_hand = sphere(
        flint.index(l),
        bk7().index(l),
        n_out * water.index(l) / water.index(r),
        None,
    );
    let (a, est) = render(&mapped, 4_000);
    let (b, _) = render(&by_hand, 4_000);
    let image = est.sensor_image(0);
    let mut total = 0.0;
    for i in 0..image.pixels {
        let (x, y) = (a.mean[image.first + i].re, b.mean[image.first + i].re);
        assert!(
            (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
            "pixel {i}: {x} vs {y}"
        );
        total += y;
    }
    assert!(total > 0.0);
    // and the reference line differs: dispersion moved the light
    let (c, _) = render(&sphere(flint.index(r), bk7().index(r), n_out, None), 4_000);
    let moved = (0..image.pixels)
        .filter(|&i| (c.mean[image.first + i].re - b.mean[image.first + i].re).abs() > 1e-9)
        .count();
    assert!(moved > image.pixels / 4, "only {moved} pixels changed");
}

/// A pulse through a clear N-BK7 plate arrives after the group path `∫ n_g ds` (`n_g = n − λ
/// dn/dλ`), not the phase path: at 450 nm the two differ by 0.45 over 10 of glass, 4.5 time bins.
#[test]
fn a_pulse_arrives_at_the_group_delay() {
    let l = 450.0;
    let glass = bk7();
    let h = 1e-3;
    let n = glass.index(l);
    let n_g = n - l * (glass.index(l + h) - glass.index(l - h)) / (2.0 * h);
    let mut scene = plate(Spectrum::new(
        [l, l],
        REFERENCE_NM,
        Some(Dispersion::Scaled(bk7())),
        None,
    ));
    // normal incidence from 1 before the plate to a flux sensor 1 behind it
    scene.light = Light::Beam {
        center: DVec3::new(0.0, 0.0, -6.0),
        direction: DVec3::Z,
        radius: 0.0,
    };
    scene.sensors = vec![Sensor::new(
        "behind".into(),
        SensorKind::Flux,
        DVec3::new(0.0, 0.0, 6.0),
        DVec3::Z,
        None,
        [1, 1],
    )];
    let width = 0.1;
    scene.transient = Some(lightpath::rrte::Transient {
        bins: 400,
        max_path: 400.0 * width,
    });
    let (e, est) = render(&scene, 4_000);
    let image = est.sensor_image(0);
    let brightest = (0..400)
        .max_by(|&a, &b| {
            e.mean[image.plane(Some(a), 0)]
                .re
                .total_cmp(&e.mean[image.plane(Some(b), 0)].re)
        })
        .unwrap();
    let group = 2.0 + THICKNESS * n_g;
    let phase = 2.0 + THICKNESS * n;
    assert_eq!(
        brightest,
        (group / width) as usize,
        "group path {group}, phase path {phase}"
    );
    assert!(((group - phase) / width) > 4.0);
}

/// A part and its bulk for the scenes of several volumes below.
fn part(
    shape: Bounds,
    center: DVec3,
    profiles: Vec<Profile>,
    sigma_s: f64,
) -> (lightpath::eikonal::Part, lightpath::rrte::Bulk) {
    (
        lightpath::eikonal::Part::new(shape, center, profiles),
        lightpath::rrte::Bulk {
            sigma_s,
            sigma_a: 0.02,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
        },
    )
}

/// Two volumes of their own glasses side by side in water, a crown ball and a ball mixing crown
/// (surface) into flint (centre): rendered at one line through each volume's dispersion map, and
/// with each volume's index written out at that wavelength, the screen and the pinhole camera
/// (reached by connections through both balls) agree to round-off.
#[test]
fn volumes_of_their_own_glasses_at_one_line_are_their_fields_at_that_line() {
    let flint = Material::named("f2").unwrap();
    let water = Material::Cauchy {
        a: 1.324,
        b: 0.00306,
        c: 0.0,
    };
    let (l, r, radius) = (450.0, REFERENCE_NM, 0.7);
    let ball = Bounds::Sphere { radius };
    // indices of the crown ball, and of the mixture's centre and surface, at wavelength `at`
    let balls = |at: f64, n_out: f64, spectrum| {
        let (crown, centre) = (bk7().index(at), flint.index(at));
        let volume = Volume::several(
            vec![
                part(
                    ball.clone(),
                    DVec3::new(-0.9, 0.0, 0.0),
                    vec![Profile::Constant { n: crown }],
                    0.4,
                ),
                part(
                    ball.clone(),
                    DVec3::new(0.9, 0.0, 0.0),
                    vec![Profile::SphericalPolynomial {
                        n0: centre,
                        coefficients: vec![(crown - centre) / radius],
                    }],
                    0.2,
                ),
            ],
            n_out,
        );
        RenderScene {
            volume,
            light: Light::Beam {
                center: DVec3::new(0.0, 0.0, -2.0),
                direction: DVec3::Z,
                radius: 1.7,
            },
            sensors: vec![Sensor::new(
                "back".into(),
                SensorKind::Screen,
                DVec3::new(0.0, 0.0, 1.2),
                DVec3::Z,
                Some([4.0, 2.0]),
                [40, 20],
            )],
            pinholes: vec![
                lightpath::rrte::Pinhole::looking_at(
                    "view".into(),
                    DVec3::new(0.5, -4.0, 1.0),
                    DVec3::ZERO,
                    DVec3::Z,
                    20f64.to_radians(),
                    [16, 8],
                )
                .unwrap(),
            ],
            spectrum,
            ..bare_scene(0.005)
        }
    };
    let n_out = 1.333;
    let mapped = balls(
        r,
        n_out,
        Some(
            Spectrum::new([l, l], r, None, Some(water.clone())).with_parts(vec![
                Some(Dispersion::Scaled(bk7())),
                Some(Dispersion::Mixed(bk7(), flint.clone())),
            ]),
        ),
    );
    let by_hand = balls(l, n_out * water.index(l) / water.index(r), None);
    let (a, est) = render(&mapped, 3_000);
    let (b, _) = render(&by_hand, 3_000);
    for (what, image) in [
        ("screen", est.sensor_image(0)),
        ("pinhole", est.images_of_camera(0)),
    ] {
        let mut total = 0.0;
        for i in 0..image.pixels {
            let (x, y) = (a.mean[image.first + i].re, b.mean[image.first + i].re);
            assert!(
                (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                "{what} pixel {i}: {x} vs {y}"
            );
            total += y;
        }
        assert!(total > 0.0, "{what} saw nothing");
    }
    // and the reference line differs: dispersion moved the light
    let (c, _) = render(&balls(r, n_out, None), 3_000);
    let image = est.sensor_image(0);
    let pixel = |e: &lightpath::mc::Estimate, i: usize| e.mean[image.first + i].re;
    let lit = (0..image.pixels).filter(|&i| pixel(&b, i) > 0.0).count();
    let moved = (0..image.pixels)
        .filter(|&i| (pixel(&c, i) - pixel(&b, i)).abs() > 1e-9)
        .count();
    assert!(moved > lit / 10, "only {moved} of {lit} lit pixels changed");
}

/// A pulse through a weakly scattering N-BK7 slab and then a clear F2 slab arrives after the
/// group path of each glass at its own dispersion, `4 + 3 n_g(BK7) + 4 n_g(F2)`: at a flux
/// detector behind (the flights through each slab) and at an orthographic camera behind (the
/// light scattered forward on the beam, connected out of the first slab and across the second,
/// which it enters again). Taking the first slab's group factors for the second would be three
/// bins early, the phase path seven.
#[test]
fn a_pulse_through_two_glasses_arrives_at_each_ones_group_delay() {
    let flint = Material::named("f2").unwrap();
    let (l, r) = (450.0, REFERENCE_NM);
    let h = 1e-3;
    let group = |m: &Material| m.index(l) - l * (m.index(l + h) - m.index(l - h)) / (2.0 * h);
    let slab = |from: f64, to: f64, n: f64, sigma_s: f64| {
        part(
            Bounds::Box {
                half: DVec3::new(50.0, 50.0, 0.5 * (to - from)),
            },
            DVec3::new(0.0, 0.0, 0.5 * (from + to)),
            vec![Profile::Constant { n }],
            sigma_s,
        )
    };
    let mut volume = Volume::several(
        vec![
            slab(-5.0, -2.0, bk7().index(r), 0.05),
            slab(-1.0, 3.0, flint.index(r), 0.0),
        ],
        1.0,
    );
    volume.parts[0].sigma_a = 0.0;
    volume.parts[0].scattering = Scattering::single(PhaseFunction::Isotropic);
    volume.parts[1].sigma_a = 0.0;
    let group_path = 4.0 + 3.0 * group(&bk7()) + 4.0 * group(&flint);
    let phase_path = 4.0 + 3.0 * bk7().index(l) + 4.0 * flint.index(l);
    // the bins put the group path in the middle of one
    let width = group_path / 200.5;
    let bins = 260;
    let scene = RenderScene {
        volume,
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -6.0),
            direction: DVec3::Z,
            radius: 0.0,
        },
        sensors: vec![Sensor::new(
            "behind".into(),
            SensorKind::Flux,
            DVec3::new(0.0, 0.0, 5.0),
            DVec3::Z,
            None,
            [1, 1],
        )],
        cameras: vec![lightpath::rrte::Camera::new(
            "behind".into(),
            DVec3::Z,
            DVec3::new(0.0, 0.0, 5.0),
            [4.0, 4.0],
            [1, 1],
        )],
        spectrum: Some(Spectrum::new([l, l], r, None, None).with_parts(vec![
            Some(Dispersion::Scaled(bk7())),
            Some(Dispersion::Scaled(flint.clone())),
        ])),
        transient: Some(lightpath::rrte::Transient {
            bins,
            max_path: bins as f64 * width,
        }),
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 4_000);
    let brightest = |image: lightpath::rrte::ImageLayout| {
        (0..bins)
            .max_by(|&a, &b| {
                e.mean[image.plane(Some(a), 0)]
                    .re
                    .total_cmp(&e.mean[image.plane(Some(b), 0)].re)
            })
            .unwrap()
    };
    for (what, image) in [
        ("flux detector", est.sensor_image(0)),
        ("orthographic camera", est.camera_image(0)),
    ] {
        assert_eq!(
            brightest(image),
            200,
            "{what}: group path {group_path}, phase path {phase_path}"
        );
    }
    // the second slab at the first one's group factors, n_g = α n
    let alpha = group(&bk7()) / bk7().index(l);
    let wrong = 4.0 * (group(&flint) - alpha * flint.index(l));
    assert!(
        wrong / width > 2.5 && (group_path - phase_path) / width > 6.0,
        "{wrong} and {} against bins of {width}",
        group_path - phase_path
    );
}

/// Path tracing joins a camera path's events to a beam's disc through the surface and straight
/// on outside: a pulse from the disc 28.5 in front of a weakly scattering N-BK7 slab (3 thick),
/// scattered forward into an orthographic camera 1 behind it, arrives at the group path
/// `29.5 + 3 n_g(BK7)` (air outside), from a collimated beam and from one focused beyond the
/// camera (its rays tilted by less than 1/100). Taking the stretch to the disc out of the
/// glass's share of the delay (as if the path's optical length held it) puts it 172 bins early.
#[test]
fn a_pulse_joined_to_a_beam_arrives_at_the_group_delay() {
    let l = 450.0;
    let h = 1e-3;
    let group = |m: &Material| m.index(l) - l * (m.index(l + h) - m.index(l - h)) / (2.0 * h);
    let group_path = 29.5 + 3.0 * group(&bk7());
    let width = group_path / 200.5;
    let bins = 260;
    let beam = |focus: Option<DVec3>| {
        let (center, direction, radius) = (DVec3::new(0.0, 0.0, -30.0), DVec3::Z, 0.5);
        match focus {
            None => Light::Beam {
                center,
                direction,
                radius,
            },
            Some(focus) => Light::FocusedBeam {
                center,
                direction,
                radius,
                focus,
            },
        }
    };
    for focus in [None, Some(DVec3::new(0.0, 0.0, 20.0))] {
        let scene = RenderScene {
            volume: Volume {
                field: BoundedField::single(
                    Profile::Constant {
                        n: bk7().index(REFERENCE_NM),
                    },
                    Bounds::Box {
                        half: DVec3::new(50.0, 50.0, 1.5),
                    },
                    1.0,
                ),
                sigma_s: 0.05,
                sigma_a: 0.0,
                scattering: Scattering::single(PhaseFunction::Isotropic),
                density: None,
                parts: Vec::new(),
            },
            light: beam(focus),
            cameras: vec![lightpath::rrte::Camera::new(
                "behind".into(),
                DVec3::Z,
                DVec3::new(0.0, 0.0, 2.5),
                [2.0, 2.0],
                [1, 1],
            )],
            spectrum: Some(Spectrum::new(
                [l, l],
                REFERENCE_NM,
                Some(Dispersion::Scaled(bk7())),
                None,
            )),
            transient: Some(lightpath::rrte::Transient {
                bins,
                max_path: bins as f64 * width,
            }),
            tracing: lightpath::rrte::Tracing::FromCameras,
            ..bare_scene(0.01)
        };
        let (e, est) = render(&scene, 4_000);
        let image = est.camera_image(0);
        let brightest = (0..bins)
            .max_by(|&a, &b| {
                e.mean[image.plane(Some(a), 0)]
                    .re
                    .total_cmp(&e.mean[image.plane(Some(b), 0)].re)
            })
            .unwrap();
        assert_eq!(brightest, 200, "focus {focus:?}: group path {group_path}");
    }
}
