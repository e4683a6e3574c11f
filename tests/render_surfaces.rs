//! Diffuse and black surfaces in the refractive renderer: a Lambertian floor lit by a beam has the
//! radiance `albedo · E / π` in a pinhole camera, whose irradiance is the closed-form integral over
//! the lit disc; the caustic a glass sphere throws on the floor, measured by a screen just above
//! it, predicts what the camera sees of the floor; a black floor stops light from reaching what
//! lies behind it; and the power balance holds with light bouncing between floor and volume.

use crate::common;

use common::bare_scene;
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Profile};
use lightpath::mc::Estimate;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{
    Light, ParticleTracer, Pinhole, RenderScene, Sensor, SensorKind, Surface, Total, Volume,
};
use std::f64::consts::PI;

const FLOOR: f64 = -1.0;

/// A sphere of radius 0.5 and index `n` at the origin (clear, or scattering with `sigma_s`), a
/// floor of `albedo` at z = −1 and a beam of radius 0.3 coming straight down through `(x, 0)`.
fn scene(n: f64, sigma_s: f64, albedo: f64, x: f64) -> RenderScene {
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Constant { n },
                Bounds::Sphere { radius: 0.5 },
                1.0,
            ),
            sigma_s,
            sigma_a: 0.1 * sigma_s,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(x, 0.0, 2.0),
            direction: -DVec3::Z,
            radius: 0.3,
        },
        surfaces: vec![Surface::new(
            "floor".into(),
            DVec3::new(0.0, 0.0, FLOOR),
            DVec3::Z,
            Some([10.0, 10.0]),
            albedo,
        )],
        ..bare_scene(0.005)
    }
}

fn render(scene: &RenderScene, samples: u64) -> (Estimate, ParticleTracer<'_>) {
    common::render(scene, samples, 5)
}

/// A pinhole at `position` looking at the floor point `target`.
fn camera(position: DVec3, target: DVec3) -> Pinhole {
    Pinhole::looking_at(
        "cam".into(),
        position,
        target,
        DVec3::Z,
        20f64.to_radians(),
        [41, 41],
    )
    .unwrap()
}

/// The floor lit by a beam beside the sphere: the pixel at the spot's centre sees the Lambertian
/// radiance `a E / π` (E = 1/(π r²) per unit power), and the pinhole's irradiance equals the lit
/// disc's `∫ a E cos θ_q / (π d²) dA` by quadrature.
#[test]
fn a_lit_floor_has_lambertian_radiance() {
    let albedo = 0.7;
    let spot = DVec3::new(2.0, 0.0, FLOOR);
    // an index-matched ball: light the floor reflects passes it unchanged
    let mut s = scene(1.0, 0.0, albedo, 2.0);
    let position = DVec3::new(2.0, -3.0, 1.0);
    s.pinholes.push(camera(position, spot));
    let n = 100_000;
    let (e, est) = render(&s, n);
    let image = est.pinhole_image(0);
    let centre = image.plane(None, 0) + 20 * 41 + 20;
    let radiance = albedo / (PI * 0.09) / PI;
    let (m, se) = (e.mean[centre].re, e.stderr[centre]);
    assert!(
        (m - radiance).abs() < 4.0 * se && se < 0.1 * radiance,
        "centre pixel {m} ± {se}, Lambertian {radiance}"
    );
    // the disc by the midpoint rule in polar coordinates
    let (nr, nphi) = (400, 400);
    let mut want = 0.0;
    for i in 0..nr {
        let r = 0.3 * (i as f64 + 0.5) / nr as f64;
        for j in 0..nphi {
            let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
            let q = spot + DVec3::new(r * phi.cos(), r * phi.sin(), 0.0);
            let v = position - q;
            let d2 = v.length_squared();
            let cos_q = v.z / d2.sqrt();
            let da = r * (0.3 / nr as f64) * (2.0 * PI / nphi as f64);
            want += albedo / (PI * 0.09) * cos_q / (PI * d2) * da;
        }
    }
    let (m, se) = (e.mean[image.total()].re, e.stderr[image.total()]);
    assert!(
        (m - want).abs() < 4.0 * se + 1e-9,
        "pinhole irradiance {m} ± {se}, disc integral {want}"
    );
    // every photon reaches the floor once, then leaves or is absorbed there
    let incident = e.mean[est.surface_power(0)].re;
    assert!((incident - 1.0).abs() < 1e-12, "incident {incident}");
}

/// A glass ball focuses the beam onto the floor. A screen just above the floor measures the
/// caustic's irradiance `E(q)`; integrating `a E(q) cos θ_q / (π d²)` over its pixels predicts the
/// irradiance of a pinhole seeing the floor from the side, which the floor's own connections give.
#[test]
fn the_floor_shows_the_caustic_the_screen_measures() {
    let albedo = 0.8;
    let mut s = scene(1.5, 0.0, albedo, 0.0);
    // wide enough for the light the ball's surface reflects sideways onto the floor
    let side = 4.0;
    let pixels = 200;
    s.sensors.push(Sensor::new(
        "above floor".into(),
        SensorKind::Screen,
        DVec3::new(0.0, 0.0, FLOOR + 1e-6),
        -DVec3::Z,
        Some([side, side]),
        [pixels, pixels],
    ));
    // a low camera whose lines of sight to the lit floor pass below the ball, tilted down so
    // that the ball (and the floor's mirror image in it) lies above its field of view
    let position = DVec3::new(0.0, -4.0, -0.7);
    s.pinholes
        .push(camera(position, DVec3::new(0.0, 0.0, FLOOR - 0.4)));
    let (e, est) = render(&s, 200_000);
    let screen = est.sensor_image(0);
    let sensor = &s.sensors[0];
    let cam = &s.pinholes[0];
    let area = side * side / (pixels * pixels) as f64;
    let mut predicted = 0.0;
    for j in 0..pixels {
        for i in 0..pixels {
            let power = e.mean[screen.plane(None, 0) + j * pixels + i].re;
            let q = sensor.center
                + sensor.right * ((i as f64 + 0.5) / pixels as f64 - 0.5) * side
                + sensor.up * ((j as f64 + 0.5) / pixels as f64 - 0.5) * side;
            let v = position - DVec3::new(q.x, q.y, FLOOR);
            let d2 = v.length_squared();
            // only what the camera's field of view holds, past the ball
            let w = v / d2.sqrt();
            let b = q.dot(w);
            let passes_ball = b * b - (q.length_squared() - 0.25) > 0.0 && b < 0.0;
            if cam.pixel(w).is_none() || passes_ball {
                continue;
            }
            // E = power / area; the pixel's area cancels
            predicted += albedo * (power / area) * (v.z / d2.sqrt()) / (PI * d2) * area;
        }
    }
    let image = est.pinhole_image(0);
    let (m, se) = (e.mean[image.total()].re, e.stderr[image.total()]);
    // the screen's pixels (0.02 wide) blur the caustic slightly: 0.5 % allowed besides the noise
    assert!(
        (m - predicted).abs() < 4.0 * se + 0.005 * predicted,
        "pinhole irradiance {m} ± {se}, predicted from the screen {predicted}"
    );
    // nearly all the power lands within the screen
    let on_screen = e.mean[screen.total()].re;
    assert!(on_screen > 0.9, "{on_screen}");
}

/// A black floor absorbs everything reaching it: nothing crosses a screen below it, and the
/// powers balance. A white floor under a scattering ball sends light back into it: the ball
/// absorbs more, and absorbed + absorbed by surfaces + escaped + unfinished = 1.
#[test]
fn floors_absorb_or_send_light_back() {
    let mut black = scene(1.0, 0.0, 0.0, 2.0);
    black.sensors.push(Sensor::new(
        "below".into(),
        SensorKind::Flux,
        DVec3::new(0.0, 0.0, FLOOR - 0.5),
        -DVec3::Z,
        None,
        [1, 1],
    ));
    let (e, est) = render(&black, 10_000);
    assert_eq!(e.mean[est.power(0)].re, 0.0);
    assert!((e.mean[est.total(Total::SurfaceAbsorbed)].re - 1.0).abs() < 1e-12);
    let absorbed = |albedo: f64| {
        let s = scene(1.33, 4.0, albedo, 0.0);
        let (e, est) = render(&s, 40_000);
        let v = |t: Total| (e.mean[est.total(t)].re, e.stderr[est.total(t)]);
        let parts = [
            Total::Absorbed,
            Total::SurfaceAbsorbed,
            Total::Escaped,
            Total::Unfinished,
        ];
        let sum: f64 = parts.iter().map(|&t| v(t).0).sum();
        let se: f64 = parts.iter().map(|&t| v(t).1.powi(2)).sum::<f64>().sqrt();
        assert!(
            (sum - 1.0).abs() < 4.0 * se + 1e-12,
            "albedo {albedo}: {sum} ± {se}"
        );
        v(Total::Absorbed)
    };
    let (dark, sd) = absorbed(0.0);
    let (white, sw) = absorbed(0.9);
    assert!(
        white - dark > 4.0 * (sd * sd + sw * sw).sqrt(),
        "the ball absorbs {dark} ± {sd} over a black floor, {white} ± {sw} over a white one"
    );
}
