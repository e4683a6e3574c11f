//! Several volumes in one scene, each its own shape, index and bulk: two slabs apart against the
//! plain layered tracer of `common` (Fresnel at all four faces, the gap between them; with and
//! without a density), particle, path and bidirectional tracing on the same images of a glass
//! ball beside a glass cube (the lamp above them or inside the ball), fluence probes in one
//! glass ball lit from another against a target about them (values and derivatives), and in a
//! ball lit only off a glass slab's outside, cameras against a collimated detector through a
//! second volume, a sampled volume against the analytic one, a volume placed away from the
//! origin against the same volume at the origin with the rest of the scene moved, and the three
//! estimators on light seen after reflections inside a glass slab or off its outside.

use crate::common;

use common::{Layer, bare_scene, flux, intensity_in_cone, plain_layers, render};
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Part, Profile};
use lightpath::math::stream_rng;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{Bulk, Camera, Light, Pinhole, RenderScene, Sensor, Surface, Total, Volume};

/// A part and its bulk: a shape at `center` of constant index `n`.
fn part(shape: Bounds, center: DVec3, n: f64, bulk: (f64, f64, f64)) -> (Part, Bulk) {
    (
        Part::new(shape, center, vec![Profile::Constant { n }]),
        Bulk {
            sigma_s: bulk.0,
            sigma_a: bulk.1,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: bulk.2 }),
        },
    )
}

/// Two slabs apart, with different indices, coefficients, albedos and phase functions.
const LAYERS: [Layer; 2] = [
    Layer {
        z: [-1.05, -0.05],
        n: 1.4,
        sigma_s: 1.5,
        sigma_a: 0.2,
        g: 0.5,
    },
    Layer {
        z: [0.45, 1.05],
        n: 1.2,
        sigma_s: 3.0,
        sigma_a: 0.05,
        g: 0.85,
    },
];

/// The density `0.6 + 0.5 z` that scales both slabs in [`slabs_apart_scaled_by_a_density`].
fn linear(z: f64) -> f64 {
    0.6 + 0.5 * z
}

/// Render [`LAYERS`] (scaled by `density`, if any) under a pencil beam, and check their
/// transmittance and reflectance against the plain layered tracer's with the density `plain`
/// (within 4 combined standard errors), and that every photon is accounted for. Returns the
/// plain tracer's transmittance.
fn slabs_against_the_plain_tracer(
    density: Option<lightpath::rrte::Density>,
    plain: (&dyn Fn(f64) -> f64, f64),
) -> f64 {
    let photons = 100_000;
    let (r_ref, t_ref) = plain_layers(&LAYERS, plain, photons, &mut stream_rng(21, 0));
    let slab = |l: &Layer| {
        let half = DVec3::new(500.0, 500.0, 0.5 * (l.z[1] - l.z[0]));
        let center = DVec3::new(0.0, 0.0, 0.5 * (l.z[0] + l.z[1]));
        part(
            Bounds::Box { half },
            center,
            l.n,
            (l.sigma_s, l.sigma_a, l.g),
        )
    };
    let mut volume = Volume::several(LAYERS.iter().map(slab).collect(), 1.0);
    volume.density = density;
    let scene = RenderScene {
        volume,
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.0,
        },
        sensors: vec![flux("T", 1.05), flux("R", -1.05)],
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, photons, 7);
    let value = |k: usize| (e.mean[k].re, e.stderr[k]);
    let (t, st) = value(est.sensor_image(0).first);
    let (r, sr) = value(est.sensor_image(1).first);
    let (a, _) = value(est.total(Total::Absorbed));
    let lost = 1.0 - t - r - a;
    assert!(
        lost.abs() < 0.01,
        "light lost sideways or unaccounted: {lost}"
    );
    let ref_err = |p: f64| (p * (1.0 - p) / photons as f64).sqrt();
    for (what, x, sx, y) in [("T", t, st, t_ref), ("R", r, sr, r_ref)] {
        let tol = 4.0 * sx.hypot(ref_err(y));
        assert!(
            (x - y).abs() < tol,
            "{what} {x} ± {sx} vs the plain layered tracer's {y}"
        );
    }
    t_ref
}

#[test]
fn two_slabs_apart_match_a_plain_layered_tracer() {
    let uniform: (&dyn Fn(f64) -> f64, f64) = (&|_| 1.0, 1.0);
    let t_ref = slabs_against_the_plain_tracer(None, uniform);
    // the second slab matters: without it much more light would pass
    let photons = 100_000;
    let (_, t_one) = plain_layers(&LAYERS[..1], uniform, photons, &mut stream_rng(22, 0));
    let err = (t_ref * (1.0 - t_ref) / photons as f64).sqrt();
    assert!(
        t_one - t_ref > 20.0 * err,
        "one slab {t_one} vs two {t_ref}"
    );
}

/// A density scales every volume's own coefficients: the slabs under `0.6 + 0.5 z` (a trilinear
/// grid with nodes on the outer faces, exact for a linear function) against the plain tracer's
/// delta tracking of the same density, and unlike the slabs without it.
#[test]
fn slabs_apart_scaled_by_a_density_match_the_plain_tracer() {
    use lightpath::eikonal::grid::{GridField, Interp};
    let (spacing, lateral) = (2.1, 240);
    let corner = -(lateral as f64) * spacing;
    let n = 2 * lateral + 1;
    let mut values = Vec::with_capacity(2 * n * n);
    for z in [-1.05, 1.05] {
        values.extend(std::iter::repeat_n(linear(z), n * n));
    }
    let grid = GridField::from_samples(
        DVec3::new(corner, corner, -1.05),
        spacing,
        [n, n, 2],
        values,
        Interp::Trilinear,
    )
    .unwrap();
    let density = lightpath::rrte::Density::new(grid).unwrap();
    let t_ref = slabs_against_the_plain_tracer(Some(density), (&linear, linear(1.05)));
    let uniform: (&dyn Fn(f64) -> f64, f64) = (&|_| 1.0, 1.0);
    let (_, t_plain) = plain_layers(&LAYERS, uniform, 100_000, &mut stream_rng(23, 0));
    let err = (t_ref * (1.0 - t_ref) / 1e5).sqrt();
    assert!(
        (t_ref - t_plain).abs() > 20.0 * err,
        "with the density {t_ref}, without {t_plain}"
    );
}

/// A glass ball (n = 1.5, forward scattering) beside a glass cube (n = 1.3, isotropic, more
/// absorbing), lit by a lamp above them and seen by a pinhole in front.
fn ball_and_cube() -> RenderScene {
    ball_and_cube_of(1.3)
}

/// [`ball_and_cube`] with the cube's index `n_cube`.
fn ball_and_cube_of(n_cube: f64) -> RenderScene {
    let volume = Volume::several(
        vec![
            part(
                Bounds::Sphere { radius: 0.8 },
                DVec3::new(-1.1, 0.0, 0.0),
                1.5,
                (2.0, 0.1, 0.7),
            ),
            part(
                Bounds::Box {
                    half: DVec3::new(0.5, 0.6, 0.5),
                },
                DVec3::new(1.1, 0.2, 0.0),
                n_cube,
                (0.8, 0.3, 0.0),
            ),
        ],
        1.0,
    );
    let camera = Pinhole::looking_at(
        "cam".into(),
        DVec3::new(0.0, 0.5, 5.0),
        DVec3::ZERO,
        DVec3::Y,
        45f64.to_radians(),
        [12, 8],
    )
    .unwrap();
    RenderScene {
        volume,
        light: Light::Point {
            position: DVec3::new(0.0, 2.5, 1.5),
        },
        pinholes: vec![camera],
        reflections: 2,
        ..bare_scene(0.01)
    }
}

/// Particle tracing, path tracing and bidirectional tracing agree on the pinhole's image of two
/// volumes: its total and its two halves, each holding one volume (within 4 combined standard
/// errors). Light reaches each volume past the other, and connections run out of one, and with
/// the reflections inside, past the other too.
#[test]
fn particle_path_and_bidirectional_tracing_agree_on_two_volumes() {
    common::three_estimators_agree(&ball_and_cube(), 400_000, 60_000);
}

/// With the lamp inside the glass ball (off its centre, the ball now clear), particle, path
/// and bidirectional tracing agree on the pinhole's image as above: path tracing connects the
/// events in the cube to the lamp by paths out of the cube, into the ball and on to the lamp
/// (refracted at both, reflected inside either), bidirectional tracing by the unreflected ones
/// and its other strategies.
#[test]
fn the_three_estimators_agree_with_the_lamp_inside_one_of_two_volumes() {
    let mut s = ball_and_cube();
    s.light = Light::Point {
        position: DVec3::new(-1.2, 0.15, 0.1),
    };
    s.volume.parts[0].sigma_s = 0.0;
    common::three_estimators_agree(&s, 400_000, 60_000);
}

/// A beam that starts between the two volumes, towards the cube (index-matched here, so that no
/// light reflects off its face into the ball before it scatters, which path tracing does not
/// make): the glass ball lies upstream of the beam's disc, so the path from an event in the cube
/// back along the beam ends at the disc, not past it through the ball, and a connection that
/// ends before a part beyond its end counts the draw of no reflections inside that part. The
/// three estimators agree as above.
#[test]
fn the_three_estimators_agree_under_a_beam_between_two_volumes() {
    let mut s = ball_and_cube_of(1.0);
    s.light = Light::Beam {
        center: DVec3::new(0.0, 0.2, 0.0),
        direction: DVec3::X,
        radius: 0.4,
    };
    common::three_estimators_agree(&s, 200_000, 40_000);
}

/// A graded lens (a Luneburg profile raised by 0.2, so that every face refracts) placed at `c`
/// renders as the lens at the origin with the light and the sensors moved by `c` too: its
/// profile and bounds move with it. The same photons (one seed) take the same paths up to
/// round-off, so the two agree far within their standard errors (the focus falls on a pixel's
/// centre, not on an edge that round-off would decide).
#[test]
fn a_placed_volume_renders_as_the_same_volume_at_the_origin() {
    let c = DVec3::new(0.7, -0.4, 1.3);
    let lens = |center: DVec3| {
        Part::new(
            Bounds::Sphere { radius: 1.0 },
            center,
            vec![
                Profile::Luneburg { radius: 1.0 },
                Profile::Constant { n: 0.2 },
            ],
        )
    };
    let bulk = Bulk {
        sigma_s: 0.4,
        sigma_a: 0.1,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.6 }),
    };
    let scene = |volume: Volume, shift: DVec3| {
        let mut screen = Sensor::new(
            "screen".into(),
            lightpath::rrte::SensorKind::Screen,
            DVec3::new(0.0, 0.0, 1.05) + shift,
            DVec3::Z,
            Some([1.4, 1.4]),
            [7, 7],
        );
        screen.normal = DVec3::Z;
        RenderScene {
            volume,
            light: Light::Beam {
                center: DVec3::new(0.0, 0.0, -2.0) + shift,
                direction: DVec3::Z,
                radius: 0.8,
            },
            sensors: vec![screen, flux("down", -1.5 + shift.z)],
            ..bare_scene(0.01)
        }
    };
    let placed = scene(Volume::several(vec![(lens(c), bulk.clone())], 1.0), c);
    let origin = scene(
        Volume {
            field: BoundedField::new(
                vec![
                    Profile::Luneburg { radius: 1.0 },
                    Profile::Constant { n: 0.2 },
                ],
                Bounds::Sphere { radius: 1.0 },
                1.0,
            ),
            sigma_s: bulk.sigma_s,
            sigma_a: bulk.sigma_a,
            scattering: bulk.scattering.clone(),
            density: None,
            parts: Vec::new(),
        },
        DVec3::ZERO,
    );
    let (a, est) = render(&placed, 20_000, 4);
    let (b, _) = render(&origin, 20_000, 4);
    let focus = est.sensor_image(0);
    let mut compared = 0;
    for k in (focus.first..focus.first + focus.pixels).chain([est.sensor_image(1).first]) {
        let (x, y, s) = (a.mean[k].re, b.mean[k].re, b.stderr[k]);
        assert!(
            (x - y).abs() <= 0.05 * s + 1e-12,
            "output {k}: placed {x}, at the origin {y} ± {s}"
        );
        compared += (y > 0.0) as usize;
    }
    assert!(compared > 20, "only {compared} outputs lit");
}

/// An orthographic camera and a far pinhole see the intensity a collimated detector counts,
/// through a second volume: light scattered in a glass ball leaves it towards the camera through
/// an absorbing glass block beside it, so each connection runs through the ball's medium, out,
/// across the block's and out again, and photons are traced the same way. Intensity = power in
/// the detector's 10° cone over its solid angle (up to the cone's angular average). With a
/// density, the connections' transmittances are ratio-tracked volume by volume.
#[test]
fn cameras_see_through_a_second_volume_what_a_collimated_detector_counts() {
    use lightpath::eikonal::grid::{GridField, Interp};
    // a density rising along x, the camera's direction: 0.5 at x = −1 to 1.9 at x = 2.5
    let values = [-1.0, 2.5].map(|x| 0.5 + 0.4 * (x + 1.0)).repeat(4);
    let grid = GridField::from_samples(
        DVec3::new(-1.0, -1.75, -1.75),
        3.5,
        [2, 2, 2],
        values,
        Interp::Trilinear,
    )
    .unwrap();
    let density = lightpath::rrte::Density::new(grid).unwrap();
    collimated_and_cameras(None);
    collimated_and_cameras(Some(density));
}

/// The scene of [`cameras_see_through_a_second_volume_what_a_collimated_detector_counts`], its
/// volumes scaled by `density`.
fn collimated_and_cameras(density: Option<lightpath::rrte::Density>) {
    let mut volume = Volume::several(
        vec![
            part(
                Bounds::Sphere { radius: 0.8 },
                DVec3::ZERO,
                1.4,
                (1.5, 0.1, 0.0),
            ),
            part(
                Bounds::Box {
                    half: DVec3::new(0.4, 1.2, 1.2),
                },
                DVec3::new(1.8, 0.0, 0.0),
                1.3,
                (0.3, 0.6, 0.5),
            ),
        ],
        1.0,
    );
    volume.density = density;
    let mut detector = Sensor::new(
        "collimated".into(),
        lightpath::rrte::SensorKind::Flux,
        DVec3::new(2.2, 0.0, 0.0),
        DVec3::X,
        None,
        [1, 1],
    );
    let alpha = 10f64.to_radians();
    detector.acceptance = Some(alpha);
    let base = RenderScene {
        volume,
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.5,
        },
        sensors: vec![detector],
        reflections: 2,
        ..bare_scene(0.01)
    };
    let (reference, ref_se) = intensity_in_cone(&base, alpha, 400_000, 41);
    let mut scene = base.clone();
    scene.sensors.clear();
    scene.cameras.push(lightpath::rrte::Camera::new(
        "side".into(),
        DVec3::X,
        DVec3::new(3.0, 0.0, 0.0),
        [2.6, 2.6],
        [13, 13],
    ));
    let distance = 30.0;
    scene.pinholes.push(
        Pinhole::looking_at(
            "far".into(),
            DVec3::new(distance, 0.0, 0.0),
            DVec3::ZERO,
            DVec3::Y,
            6f64.to_radians(),
            [11, 11],
        )
        .unwrap(),
    );
    let (e, est) = render(&scene, 20_000, 43);
    let value = |k: usize| (e.mean[k].re, e.stderr[k]);
    let area = scene.cameras[0].pixel_area();
    let (sum, s_sum) = value(est.camera_image(0).total());
    let (irr, s_irr) = value(est.pinhole_image(0).total());
    let d2 = distance * distance;
    for (what, i, si) in [
        ("orthographic camera", sum * area, s_sum * area),
        ("pinhole irradiance × D²", irr * d2, s_irr * d2),
    ] {
        assert!(
            (i - reference).abs() < 4.0 * si.hypot(ref_se),
            "{what}: intensity {i} ± {si} vs collimated detector {reference} ± {ref_se}"
        );
    }
}

/// A volume bounded by a signed-distance shape (a sampled glass ball) beside a glass block, lit
/// through the ball into the block, renders as the analytic ball beside the same block:
/// transmitted and reflected flux and a side camera's total (connections through the sampled
/// surface and the block) agree within 4 combined standard errors (the grid's interpolation error
/// stays below them).
#[test]
fn a_sampled_volume_beside_another_renders_as_the_analytic_one() {
    use lightpath::eikonal::grid::Interp;
    use lightpath::eikonal::sdf::{SdfGrid, Shape};
    let sphere = [Shape::Sphere {
        center: DVec3::ZERO,
        radius: 0.8,
    }];
    let ball = SdfGrid::from_shapes(&sphere, 0.0, 0.04, Interp::Tricubic).unwrap();
    let scene = |shape: Bounds| {
        let volume = Volume::several(
            vec![
                part(shape, DVec3::new(-1.1, 0.0, 0.0), 1.5, (1.2, 0.1, 0.6)),
                part(
                    Bounds::Box {
                        half: DVec3::new(0.5, 0.9, 0.9),
                    },
                    DVec3::new(1.1, 0.0, 0.0),
                    1.3,
                    (0.6, 0.3, 0.0),
                ),
            ],
            1.0,
        );
        let plane = |name: &str, x: f64| {
            Sensor::new(
                name.into(),
                lightpath::rrte::SensorKind::Flux,
                DVec3::new(x, 0.0, 0.0),
                DVec3::X * x.signum(),
                None,
                [1, 1],
            )
        };
        RenderScene {
            volume,
            light: Light::Beam {
                center: DVec3::new(-3.0, 0.0, 0.0),
                direction: DVec3::X,
                radius: 0.5,
            },
            sensors: vec![plane("T", 2.0), plane("R", -2.0)],
            cameras: vec![lightpath::rrte::Camera::new(
                "side".into(),
                DVec3::Y,
                DVec3::new(0.0, 3.0, 0.0),
                [4.4, 2.2],
                [8, 4],
            )],
            ..bare_scene(0.01)
        }
    };
    let analytic = scene(Bounds::Sphere { radius: 0.8 });
    let sampled = scene(Bounds::Sdf(std::sync::Arc::new(ball)));
    let (a, est) = render(&analytic, 40_000, 5);
    let (b, _) = render(&sampled, 40_000, 6);
    for (what, k) in [
        ("T", est.power(0)),
        ("R", est.power(1)),
        ("camera", est.camera_image(0).total()),
    ] {
        let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], b.mean[k].re, b.stderr[k]);
        assert!(
            x > 0.0 && (x - y).abs() < 4.0 * sx.hypot(sy),
            "{what}: analytic {x} ± {sx}, sampled {y} ± {sy}"
        );
    }
}

/// A lens of profile `lens` in a water cylinder (10 long) beside a glass block that the light
/// crosses after it, from a config with `modulation` (a table, or nothing).
fn lens_beside_a_block(lens: &str, modulation: &str) -> Result<RenderScene, String> {
    let text = format!(
        "[field]\nn_out = 1.33\n\
         [[volume]]\nbounds = {{ kind = \"cylinder\", radius = 3.0, half_length = 5.0 }}\n\
         profiles = [{lens}]\n\
         [[volume]]\ncenter = [0.0, 0.0, 6.5]\nbounds = {{ kind = \"box\", size = [4.0, 4.0, 1.0] }}\n\
         profiles = [{{ kind = \"constant\", n = 1.5 }}]\nmedium = {{ sigma_s = 0.05, sigma_a = 0.3 }}\n\
         [light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -6.0]\ndirection = [0.0, 0.0, 1.0]\nradius = 0.4\n\
         [[sensor]]\nkind = \"flux\"\nname = \"window\"\ncenter = [0.0, 0.0, 8.0]\n\
         normal = [0.0, 0.0, 1.0]\nsize = [0.2, 0.2]\n\
         [render]\nstep = 0.05\n{modulation}"
    );
    match lightpath::config::load_text(&text) {
        Ok(lightpath::config::Task::Render(t)) => Ok(t.scene),
        Ok(_) => panic!("not a render"),
        Err(e) => Err(e.to_string()),
    }
}

/// [`lens_beside_a_block`] with an ultrasonic lens (m = 0) of amplitude `n_max`.
fn ultrasonic_beside_a_block(n_max: f64, modulation: &str) -> RenderScene {
    let lens = format!("{{ kind = \"ultrasonic\", n0 = 1.33, n_max = {n_max}, k_r = 2.0, m = 0 }}");
    lens_beside_a_block(&lens, modulation).unwrap_or_else(|e| panic!("{e}"))
}

/// A sinusoidally modulated ultrasonic lens beside a glass block renders as the average of the
/// lens frozen at its phases (the light crosses the block after the lens, to a small window
/// whose power depends on how strongly the lens focuses); a strobe freezes the volume's field
/// at its phase; a modulation with no ultrasonic volume is refused.
#[test]
fn an_ultrasonic_volume_beside_another_averages_its_phases() {
    let n_max = 0.01;
    let sinusoidal = "[modulation]\nkind = \"sinusoidal\"\n";
    let modulated = ultrasonic_beside_a_block(n_max, sinusoidal);
    assert_eq!(
        modulated.modulation,
        Some(lightpath::rrte::Modulation::Sinusoidal)
    );
    let (e, est) = render(&modulated, 40_000, 41);
    let value = |e: &lightpath::mc::Estimate| (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
    let (m, sm) = value(&e);
    // against the midpoint rule over 16 frozen phases θ in (−π/2, π/2), n_max sin θ
    let k = 16;
    let (mut avg, mut var) = (0.0, 0.0);
    for i in 0..k {
        let theta = std::f64::consts::PI * ((i as f64 + 0.5) / k as f64 - 0.5);
        let frozen = ultrasonic_beside_a_block(n_max * theta.sin(), "");
        let (p, sp) = value(&render(&frozen, 5_000, 43 + i as u64).0);
        avg += p / k as f64;
        var += sp * sp / (k * k) as f64;
    }
    assert!(
        (m - avg).abs() < 4.0 * (sm * sm + var).sqrt(),
        "modulated {m} ± {sm} vs phase average {avg} ± {}",
        var.sqrt()
    );
    // the static lens at full amplitude focuses more: the test sees the modulation
    let fixed = ultrasonic_beside_a_block(n_max, "");
    let (st, sst) = value(&render(&fixed, 20_000, 47).0);
    assert!(
        st - m > 4.0 * (sst * sst + sm * sm).sqrt(),
        "static {st} ± {sst} vs modulated {m}"
    );
    // a strobe at 30° is the lens at half its amplitude, and leaves the block as it is
    let strobed = ultrasonic_beside_a_block(
        n_max,
        "[modulation]\nkind = \"strobed\"\nphase_deg = 30.0\n",
    );
    assert_eq!(strobed.modulation, None);
    let parts = |s: &RenderScene| s.volume.field.bounds.parts().unwrap().to_vec();
    let (a, b) = (
        parts(&strobed),
        parts(&ultrasonic_beside_a_block(0.5 * n_max, "")),
    );
    let Profile::Ultrasonic { n_max: got, .. } = a[0].profiles[0] else {
        panic!("ultrasonic")
    };
    assert!((got - 0.5 * n_max).abs() < 1e-15, "{got}");
    assert_eq!(a[1], b[1]);
    // nothing to modulate
    let Err(e) = lens_beside_a_block("{ kind = \"constant\", n = 1.33 }", sinusoidal) else {
        panic!("a modulation of constant volumes was taken")
    };
    assert!(e.contains("modulation: no [[volume]]"), "{e}");
}

/// Two glass balls (n = 1.5 and 1.3, both scattering) with a lamp inside the first:
/// `(scene, the point inside the second where it is measured)`.
fn lamp_in_a_ball_beside_another() -> (RenderScene, DVec3) {
    let volume = Volume::several(
        vec![
            part(
                Bounds::Sphere { radius: 0.8 },
                DVec3::new(-1.0, 0.0, 0.0),
                1.5,
                (1.0, 0.1, 0.5),
            ),
            part(
                Bounds::Sphere { radius: 0.7 },
                DVec3::new(1.0, 0.2, 0.0),
                1.3,
                (0.3, 0.05, 0.0),
            ),
        ],
        1.0,
    );
    let scene = RenderScene {
        volume,
        light: Light::Point {
            position: DVec3::new(-1.1, 0.1, 0.05),
        },
        reflections: 2,
        ..bare_scene(0.01)
    };
    (scene, DVec3::new(0.9, 0.25, 0.1))
}

/// Fluence probes in one glass ball count the light of a lamp inside another as a target does:
/// the probes by connections out of the lamp's ball (and out of every scattering event there)
/// into the probes', refracted at both and reflected inside either, and within the probes' own
/// ball from the events there; the target by the photons' tracks through it, an estimator that
/// connects nothing. The mean of four probes at the corners of a regular tetrahedron `r √0.6`
/// about the target's centre is its mean over the ball of radius `r` to second order (exact for
/// a quadratic field), so the two agree within 4 combined standard errors, and so do their derivatives with
/// respect to each ball's absorption: the probes' connections count their stretch inside each
/// ball at that ball's coefficient alone (counting a connection's whole length for either ball
/// fails).
#[test]
fn probes_in_one_volume_count_the_light_from_another_as_a_target_does() {
    let (mut scene, p) = lamp_in_a_ball_beside_another();
    scene.derivatives = (0..2)
        .map(|k| {
            lightpath::rrte::Derivative::Medium(lightpath::rrte::MediumDerivative {
                param: lightpath::medium::params::Param::SigmaA,
                volume: Some(k),
            })
        })
        .collect();
    let radius = 0.3;
    scene.probes = common::probes_about(p, radius);
    let region = lightpath::rrte::Region::Sphere { center: p, radius };
    scene.sensors = vec![Sensor::target("around".into(), region)];
    let (e, est) = render(&scene, 64_000, 8);
    // the probes' mean, its error from the errors of each (their covariance left out: the
    // same photons light them all, so it is taken at its largest, the errors added)
    let probes = |k: &dyn Fn(usize) -> usize| {
        let mean = (0..4).map(|i| e.mean[k(i)].re).sum::<f64>() / 4.0;
        let err = (0..4).map(|i| e.stderr[k(i)]).sum::<f64>() / 4.0;
        (mean, err)
    };
    let (probe, sp) = probes(&|i| est.probe_total(i));
    let (target, st) = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
    eprintln!("fluence: probes {probe} ± {sp}, target {target} ± {st}");
    assert!(sp < 0.03 * probe && st < 0.05 * target, "{sp} {st}");
    assert!(
        (probe - target).abs() < 4.0 * sp.hypot(st),
        "probes {probe} ± {sp}, target {target} ± {st}"
    );
    for j in 0..2 {
        let (dp, sdp) = probes(&|i| est.probe_derivative(i, j));
        let l = est.power_derivative(0, j);
        let (dt, sdt) = (e.mean[l].re, e.stderr[l]);
        eprintln!("volume[{j}].sigma_a: probes {dp} ± {sdp}, target {dt} ± {sdt}");
        assert!(
            dp < -4.0 * sdp && dt < -4.0 * sdt,
            "volume[{j}]: {dp} ± {sdp}, {dt} ± {sdt}"
        );
        assert!(
            (dp - dt).abs() < 4.0 * sdp.hypot(sdt),
            "volume[{j}].sigma_a: probes {dp} ± {sdp}, target {dt} ± {sdt}"
        );
    }
}

/// Fluence probes in a scattering ball lit only off a glass slab's outside count the light as a
/// target does: a spot at the centre of a clear glass ball beside it shines at the slab's
/// underside above the two, and a black card between the balls hides each from the other. The
/// probes' connections from the lamp (and the events in the probes' ball) leave the lamp's
/// ball, reflect off the slab's outside or cross it reflecting inside it, and enter the
/// probes' ball; the target counts the photons' tracks. The probes' mean and the target agree
/// within 4 combined standard errors (without the reflection off the outside the probes read
/// 0.54 of the target).
#[test]
fn probes_lit_off_a_glass_slab_count_the_light_as_a_target_does() {
    let clear = (0.0, 0.0, 0.0);
    let volume = Volume::several(
        vec![
            part(Bounds::Sphere { radius: 0.5 }, -DVec3::X, 1.3, clear),
            part(
                Bounds::Sphere { radius: 0.6 },
                DVec3::X,
                1.0,
                (0.5, 0.05, 0.0),
            ),
            part(
                Bounds::Box {
                    half: DVec3::new(2.0, 1.0, 0.25),
                },
                DVec3::new(0.0, 0.0, 1.25),
                1.5,
                clear,
            ),
        ],
        1.0,
    );
    let radius = 0.3;
    let scene = RenderScene {
        volume,
        light: Light::Spot {
            position: -DVec3::X,
            axis: DVec3::new(1.0, 0.0, 1.0).normalize(),
            half_angle: 0.35,
        },
        surfaces: vec![Surface::new(
            "card".into(),
            DVec3::ZERO,
            DVec3::X,
            Some([1.4, 1.4]),
            0.0,
        )],
        probes: common::probes_about(DVec3::X, radius),
        sensors: vec![Sensor::target(
            "around".into(),
            lightpath::rrte::Region::Sphere {
                center: DVec3::X,
                radius,
            },
        )],
        reflections: 1,
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 100_000, 11);
    let target = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
    common::assert_probes_count_as_target(common::probes_mean(&e, &est), target, (0.06, 0.06));
}

/// Fluence probes in a clear glass cube (n = 1.2) lit off a glass slab above it (n = 2.5) count
/// the light as a target does: a spot at the cube's centre shines up at the slab, and the
/// probes sit below the spot, outside its cone. The spot's connections to them leave the cube,
/// come back off the slab's outside or from inside it (one reflection) and enter the cube
/// again; the only other light, reflected inside the cube's top face, is 0.8 % at normal
/// incidence. The probes' mean and the target agree within 4 combined standard errors (without
/// the paths back into the cube the probes read 0.06 of the target: that reflection alone).
#[test]
fn probes_lit_off_a_glass_slab_from_their_own_cube_count_the_light_as_a_target_does() {
    let clear = (0.0, 0.0, 0.0);
    let volume = Volume::several(
        vec![
            part(
                Bounds::Box {
                    half: DVec3::splat(0.6),
                },
                DVec3::ZERO,
                1.2,
                clear,
            ),
            part(
                Bounds::Box {
                    half: DVec3::new(2.0, 2.0, 0.25),
                },
                DVec3::new(0.0, 0.0, 1.1),
                2.5,
                clear,
            ),
        ],
        1.0,
    );
    let (center, radius) = (DVec3::new(0.0, 0.0, -0.3), 0.15);
    let scene = RenderScene {
        volume,
        light: Light::Spot {
            position: DVec3::ZERO,
            axis: DVec3::Z,
            half_angle: 0.35,
        },
        probes: common::probes_about(center, radius),
        sensors: vec![Sensor::target(
            "below".into(),
            lightpath::rrte::Region::Sphere { center, radius },
        )],
        reflections: 1,
        ..bare_scene(0.01)
    };
    let (e, est) = render(&scene, 100_000, 11);
    let target = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
    common::assert_probes_count_as_target(common::probes_mean(&e, &est), target, (0.06, 0.06));
}

/// Particle tracing, path tracing and bidirectional tracing agree on the image of a glass block
/// (n = 1.2, scattering in its lower half) lit by a spot at its centre that shines up at a glass
/// slab above it (n = 2.5): the camera, beside the block, sees the scattering half, lit almost
/// only by light the slab sends back (off its outside or from inside it). Path tracing joins
/// the events there to the spot by paths out of the block and back (particle and bidirectional
/// tracing trace them). The camera's total and pixels, within 4 combined standard errors
/// (without those paths path tracing reads 0.037 of the others).
#[test]
fn a_block_lit_off_a_glass_slab_by_its_own_lamp_renders_alike_three_ways() {
    use lightpath::eikonal::grid::{GridField, Interp};
    use lightpath::rrte::Tracing;
    let cube = part(
        Bounds::Box {
            half: DVec3::new(1.2, 1.2, 0.6),
        },
        DVec3::ZERO,
        1.2,
        (0.3, 0.0, 0.0),
    );
    let slab = part(
        Bounds::Box {
            half: DVec3::new(3.0, 3.0, 0.25),
        },
        DVec3::new(0.0, 0.0, 1.1),
        2.5,
        (0.0, 0.0, 0.0),
    );
    let below = DVec3::new(0.0, 0.0, -0.3);
    let side = Camera::new(
        "side".into(),
        DVec3::X,
        below + DVec3::X * 3.0,
        [0.5, 0.5],
        [2, 2],
    );
    // the medium scatters below z = -0.1 only: no event lies near the lamp, where path
    // tracing's connections to a point would bring 1/r² (an estimate of infinite variance)
    let (spacing, lateral, tall) = (0.1, 27, 14);
    let corner = DVec3::new(-1.3, -1.3, -0.7);
    let rho = |k: usize| f64::from(corner.z + k as f64 * spacing < -0.05);
    let values = (0..tall)
        .flat_map(|k| std::iter::repeat_n(rho(k), lateral * lateral))
        .collect();
    let grid = GridField::from_samples(
        corner,
        spacing,
        [lateral, lateral, tall],
        values,
        Interp::Trilinear,
    )
    .unwrap();
    let mut volume = Volume::several(vec![cube, slab], 1.0);
    volume.density = Some(lightpath::rrte::Density::new(grid).unwrap());
    let scene = RenderScene {
        volume,
        light: Light::Spot {
            position: DVec3::ZERO,
            axis: DVec3::Z,
            half_angle: 0.2,
        },
        cameras: vec![side],
        reflections: 1,
        ..bare_scene(0.01)
    };
    let samples = [100_000, 50_000, 50_000];
    let estimates: Vec<_> = [
        Tracing::FromLight,
        Tracing::FromCameras,
        Tracing::Bidirectional,
    ]
    .into_iter()
    .zip(samples)
    .zip(1..)
    .map(|((tracing, samples), seed)| {
        let mut t = scene.clone();
        t.tracing = tracing;
        (tracing, render(&t, samples, seed).0)
    })
    .collect();
    let image = lightpath::rrte::ParticleTracer::new(&scene).camera_image(0);
    let pixels = (0..4).map(|k| (format!("pixel {k}"), image.plane(None, 0) + k));
    for (what, k) in std::iter::once(("total".to_string(), image.total())).chain(pixels) {
        for (i, (ta, a)) in estimates.iter().enumerate() {
            eprintln!("{what}: {ta:?} {} ± {}", a.mean[k].re, a.stderr[k]);
            assert!(a.mean[k].re > 5.0 * a.stderr[k], "{what}: {ta:?}");
            for (tb, b) in &estimates[i + 1..] {
                let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], b.mean[k].re, b.stderr[k]);
                assert!(
                    (x - y).abs() < 4.0 * sx.hypot(sy),
                    "{what}: {ta:?} {x} ± {sx}, {tb:?} {y} ± {sy}"
                );
            }
        }
    }
}

/// Where light from [`IN_FRONT`] that meets a glass slab (n = 1.5, 1 thick, its front face at
/// z = 0.5) at 45° is seen after one reflection off its back face: the slab, and an orthographic
/// camera (0.5 × 0.5, 2 × 2 pixels) looking along (1, 0, 1)/√2 at where that light leaves the
/// front face, 2 tan θ_t = 1.068 further along x than it met it. The slab's mirror image of
/// `IN_FRONT` and the point itself fall outside the camera's window.
fn slab_and_camera() -> ((Part, Bulk), Camera) {
    let slab = part(
        Bounds::Box {
            half: DVec3::new(2.5, 1.5, 0.5),
        },
        DVec3::ZERO,
        1.5,
        (0.0, 0.0, 0.0),
    );
    let c = DVec3::new(1.0, 0.0, 1.0).normalize();
    let window = DVec3::new(1.068, 0.0, 0.5) + c * 2.0;
    let camera = Camera::new("slab".into(), c, window, [0.5, 0.5], [2, 2]);
    (slab, camera)
}

/// The point whose light [`slab_and_camera`]'s camera sees after a reflection inside the slab.
const IN_FRONT: DVec3 = DVec3::new(-1.5, 0.0, 2.0);

/// A small scattering ball (index-matched, lit from above by a beam) beside a glass slab (n =
/// 1.5, 1 thick), and an orthographic camera that sees the ball's light leave the slab after one
/// reflection off its back face: light that crosses the slab, reflecting inside it on the way.
/// The ball's mirror image in the slab's front face falls outside the camera's window (0.75
/// aside), and so does the ball itself.
fn ball_seen_in_a_slab_s_back_face() -> RenderScene {
    let (slab, camera) = slab_and_camera();
    let ball = part(
        Bounds::Sphere { radius: 0.15 },
        IN_FRONT,
        1.0,
        (6.0, 0.0, 0.0),
    );
    RenderScene {
        volume: Volume::several(vec![ball, slab], 1.0),
        light: Light::Beam {
            center: IN_FRONT + DVec3::Z,
            direction: -DVec3::Z,
            radius: 0.1,
        },
        cameras: vec![camera],
        reflections: 1,
        ..bare_scene(0.01)
    }
}

/// Particle tracing, whose connections from the ball to the camera cross the slab reflecting
/// once inside it, and bidirectional tracing, whose camera paths trace that reflection too (and
/// whose weights count those connections), agree on the camera's image of the ball in the slab's
/// back face: its total and each of its four pixels, within 4 combined standard errors.
#[test]
fn a_ball_seen_after_a_reflection_inside_a_slab_renders_alike_from_either_end() {
    use lightpath::rrte::Tracing;
    let s = ball_seen_in_a_slab_s_back_face();
    let (a, est) = render(&s, 100_000, 1);
    let mut b = s.clone();
    b.tracing = Tracing::Bidirectional;
    let (c, _) = render(&b, 100_000, 2);
    let image = est.camera_image(0);
    let outputs = (0..4).map(|k| (format!("pixel {k}"), image.plane(None, 0) + k));
    for (what, k) in std::iter::once(("total".to_string(), image.total())).chain(outputs) {
        let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], c.mean[k].re, c.stderr[k]);
        eprintln!("{what}: particles {x} ± {sx}, bidirectional {y} ± {sy}");
        assert!(x > 5.0 * sx, "{what}: particles {x} ± {sx}");
        assert!(
            (x - y).abs() < 4.0 * sx.hypot(sy),
            "{what}: particles {x} ± {sx}, bidirectional {y} ± {sy}"
        );
    }
}

/// A white card (0.3 × 0.3, albedo 0.8) at [`IN_FRONT`] facing the slab along (1, 0, −1)/√2, lit
/// by a spot in front of it: the camera sees it edge-on, and only after one reflection inside
/// the slab.
fn card_seen_in_a_slab_s_back_face() -> RenderScene {
    let (slab, camera) = slab_and_camera();
    let facing = DVec3::new(1.0, 0.0, -1.0).normalize();
    RenderScene {
        volume: Volume::several(vec![slab], 1.0),
        light: Light::Spot {
            position: IN_FRONT + facing * 0.6,
            axis: -facing,
            half_angle: 0.4,
        },
        surfaces: vec![Surface::new(
            "card".into(),
            IN_FRONT,
            facing,
            Some([0.3, 0.3]),
            0.8,
        )],
        cameras: vec![camera],
        reflections: 1,
        ..bare_scene(0.01)
    }
}

/// Path tracing, whose camera paths reflect inside the slab as Fresnel draws, particle tracing,
/// whose connections from the card to the camera cross the slab reflecting once inside it, and
/// bidirectional tracing (both, its weights counting those connections) agree on the camera's
/// image of the card in the slab's back face: its total and each of its four pixels, within 4
/// combined standard errors.
#[test]
fn a_card_seen_after_a_reflection_inside_a_slab_renders_alike_three_ways() {
    use lightpath::rrte::Tracing;
    let s = card_seen_in_a_slab_s_back_face();
    let estimates: Vec<_> = [
        Tracing::FromLight,
        Tracing::FromCameras,
        Tracing::Bidirectional,
    ]
    .into_iter()
    .zip([(400_000, 1), (400_000, 2), (400_000, 3)])
    .map(|(tracing, (samples, seed))| {
        let mut t = s.clone();
        t.tracing = tracing;
        (tracing, render(&t, samples, seed).0)
    })
    .collect();
    let est = lightpath::rrte::ParticleTracer::new(&s);
    let image = est.camera_image(0);
    let outputs = (0..4).map(|k| (format!("pixel {k}"), image.plane(None, 0) + k));
    for (what, k) in std::iter::once(("total".to_string(), image.total())).chain(outputs) {
        for (tracing, e) in &estimates {
            eprintln!("{what}: {tracing:?} {} ± {}", e.mean[k].re, e.stderr[k]);
            assert!(e.mean[k].re > 5.0 * e.stderr[k], "{what}: {tracing:?}");
        }
        for (i, (ta, a)) in estimates.iter().enumerate() {
            for (tb, b) in &estimates[i + 1..] {
                let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], b.mean[k].re, b.stderr[k]);
                assert!(
                    (x - y).abs() < 4.0 * sx.hypot(sy),
                    "{what}: {ta:?} {x} ± {sx}, {tb:?} {y} ± {sy}"
                );
            }
        }
    }
}

/// A scattering ball (index-matched, radius 0.4) at [`IN_FRONT`] above the glass slab of
/// [`slab_and_camera`], and two orthographic cameras: one looks at the ball from the side, the
/// other sees it only in the slab's top face (its light leaves the ball off the glass's
/// outside). With `off_the_face` the light is a narrow spot at the ball's mirror position
/// across the face, aimed at the point of the face between them, so that the ball is lit only
/// off the glass (its light reaches the ball's events off the glass's outside); else a beam
/// straight down onto the ball (part of it back off the face).
fn ball_above_a_glass_face(off_the_face: bool) -> RenderScene {
    let (slab, _) = slab_and_camera();
    let ball = part(
        Bounds::Sphere { radius: 0.4 },
        IN_FRONT,
        1.0,
        (3.0, 0.0, 0.3),
    );
    let mirror = DVec3::new(-IN_FRONT.x, 0.0, IN_FRONT.z);
    let face = DVec3::new(0.0, 0.0, 0.5);
    let c = (mirror - face).normalize();
    let side = Camera::new(
        "side".into(),
        -DVec3::X,
        IN_FRONT - DVec3::X * 1.5,
        [1.0, 1.0],
        [2, 2],
    );
    let in_face = Camera::new("in face".into(), c, face + c * 2.0, [1.0, 1.0], [2, 2]);
    let light = match off_the_face {
        true => Light::Spot {
            position: mirror,
            axis: -c,
            half_angle: 0.15,
        },
        false => Light::Beam {
            center: IN_FRONT + DVec3::Z,
            direction: -DVec3::Z,
            radius: 0.3,
        },
    };
    RenderScene {
        volume: Volume::several(vec![ball, slab], 1.0),
        light,
        cameras: vec![side, in_face],
        reflections: 1,
        ..bare_scene(0.01)
    }
}

/// Particle tracing, path tracing and bidirectional tracing agree on the images of a ball
/// lit and seen off a glass face: lit off it, the side camera's (path tracing's connections
/// to the spot reflect off the glass's outside; particle and bidirectional tracing trace that
/// reflection); under the beam, the image in the face (particle tracing's connections to the
/// camera reflect off the glass's outside; path and bidirectional tracing trace it; and path
/// tracing joins the ball's events to the beam back off the face). Each camera's total and
/// pixels, within 4 combined standard errors.
#[test]
fn a_ball_lit_and_seen_off_a_glass_face_renders_alike_three_ways() {
    use lightpath::rrte::Tracing;
    // samples of particle, path and bidirectional tracing (under the beam every photon
    // scatters in the ball, and makes many connections)
    let lit_off_the_face = [
        (true, 0, [400_000, 100_000, 100_000]),
        (false, 1, [100_000, 100_000, 50_000]),
    ];
    for (off_the_face, camera, samples) in lit_off_the_face {
        let s = ball_above_a_glass_face(off_the_face);
        let estimates: Vec<_> = [
            Tracing::FromLight,
            Tracing::FromCameras,
            Tracing::Bidirectional,
        ]
        .into_iter()
        .zip(samples)
        .zip(1..)
        .map(|((tracing, samples), seed)| {
            let mut t = s.clone();
            t.tracing = tracing;
            (tracing, render(&t, samples, seed).0)
        })
        .collect();
        let image = lightpath::rrte::ParticleTracer::new(&s).camera_image(camera);
        let pixels = (0..4).map(|k| (format!("pixel {k}"), image.plane(None, 0) + k));
        for (what, k) in std::iter::once(("total".to_string(), image.total())).chain(pixels) {
            let what = format!("camera {camera} {what}");
            for (i, (ta, a)) in estimates.iter().enumerate() {
                eprintln!("{what}: {ta:?} {} ± {}", a.mean[k].re, a.stderr[k]);
                assert!(a.mean[k].re > 5.0 * a.stderr[k], "{what}: {ta:?}");
                for (tb, b) in &estimates[i + 1..] {
                    let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], b.mean[k].re, b.stderr[k]);
                    assert!(
                        (x - y).abs() < 4.0 * sx.hypot(sy),
                        "{what}: {ta:?} {x} ± {sx}, {tb:?} {y} ± {sy}"
                    );
                }
            }
        }
    }
}
