//! Volumes bounded by signed-distance grids in the refractive renderer: a ring (not convex) that a
//! beam crosses twice, against its closed-form attenuation; a sampled sphere with the depth-graded
//! Luneburg profile against the analytic Luneburg sphere (flux and camera totals); a glass ball
//! given as a triangle mesh against the analytic ball; and free flights with the inside–outside
//! tests skipped by the clearance equal, bit for bit, to flights testing after every step.

use crate::common;

use common::bare_scene;
use glam::DVec3;
use lightpath::eikonal::grid::Interp;
use lightpath::eikonal::mesh::Mesh;
use lightpath::eikonal::sdf::{SdfGrid, Shape};
use lightpath::eikonal::{BoundedField, Bounds, Profile, Ray};
use lightpath::math::{stream_rng, uniform};
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::flight::Flyer;
use lightpath::rrte::{Camera, Light, Pinhole, RenderScene, Sensor, SensorKind, Volume};
use std::sync::Arc;

fn sdf(shapes: &[Shape], spacing: f64) -> Arc<SdfGrid> {
    Arc::new(SdfGrid::from_shapes(shapes, 0.0, spacing, Interp::Tricubic).unwrap())
}

fn flux(name: &str, center: DVec3, normal: DVec3) -> Sensor {
    Sensor::new(name.into(), SensorKind::Flux, center, normal, None, [1, 1])
}

/// A pencil beam along x through both arms of a clear absorbing ring (major radius 1, tube 0.3,
/// index-matched): it leaves the first arm, crosses the hole and enters the second, so it
/// transmits `exp(−σ_a · 4r)` = e^{−1.2}; a renderer that took the ring for convex (no
/// re-entry) would report e^{−0.6}.
#[test]
fn a_beam_crosses_both_arms_of_a_ring() {
    let ring = sdf(
        &[Shape::Torus {
            center: DVec3::ZERO,
            axis: DVec3::Z,
            major: 1.0,
            minor: 0.3,
        }],
        0.03,
    );
    for n in [1.0, 1.33] {
        let scene = RenderScene {
            volume: Volume {
                field: BoundedField::single(Profile::Constant { n }, Bounds::Sdf(ring.clone()), n),
                sigma_s: 0.0,
                sigma_a: 1.0,
                scattering: Scattering::single(PhaseFunction::Isotropic),
                density: None,
                parts: Vec::new(),
            },
            light: Light::Beam {
                center: DVec3::new(-2.0, 0.0, 0.0),
                direction: DVec3::X,
                radius: 0.0,
            },
            sensors: vec![flux("T", DVec3::new(2.0, 0.0, 0.0), DVec3::X)],
            ..bare_scene(0.01)
        };
        let photons = 20_000;
        let (e, est) = common::render(&scene, photons, 5);
        let t = e.mean[est.power(0)].re;
        let want = (-1.2f64).exp();
        // 4 reported standard errors (absorption is analog), and the sampled ring's chord error
        // (the four crossings each within 2e-4 on a 0.03 grid: 3e-5 of T at most)
        let sigma = e.stderr[est.power(0)];
        assert!(
            (t - want).abs() < 4.0 * sigma + 1e-4,
            "n = {n}: T = {t}, exp(−4 σ_a r) = {want} ± {sigma}"
        );
    }
}

/// The Luneburg sphere (`n = √(2 − r²)`, scattering and absorbing) bounded by a sphere and by a
/// sampled sphere with the depth-graded profile (`n_s = 1`, `n_c = √2`, `depth = R`): the same
/// medium up to the grid's interpolation error. Transmitted and reflected flux and an
/// orthographic camera's total (connections through the sampled surface) agree within 4 standard
/// errors (the 0.05 grid's interpolation error stays below them).
#[test]
fn a_sampled_luneburg_sphere_renders_as_the_analytic_one() {
    let sphere = sdf(
        &[Shape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        }],
        0.05,
    );
    let scene = |profile: Profile, bounds: Bounds| RenderScene {
        volume: Volume {
            field: BoundedField::single(profile, bounds, 1.0),
            sigma_s: 0.8,
            sigma_a: 0.2,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.7,
        },
        sensors: vec![
            flux("T", DVec3::new(0.0, 0.0, 1.5), DVec3::Z),
            flux("R", DVec3::new(0.0, 0.0, -1.5), -DVec3::Z),
        ],
        cameras: vec![Camera::new(
            "side".into(),
            DVec3::X,
            DVec3::new(3.0, 0.0, 0.0),
            [2.4, 2.4],
            [4, 4],
        )],
        ..bare_scene(0.01)
    };
    let analytic = scene(
        Profile::Luneburg { radius: 1.0 },
        Bounds::Sphere { radius: 1.0 },
    );
    let sampled = scene(
        Profile::SdfLuneburg {
            sdf: sphere.clone(),
            n_surface: 1.0,
            n_core: 2f64.sqrt(),
            depth: 1.0,
        },
        Bounds::Sdf(sphere),
    );
    let photons = 12_800;
    let (a, est) = common::render(&analytic, photons, 11);
    let (b, _) = common::render(&sampled, photons, 12);
    let camera = est.camera_image(0).total();
    for (what, i) in [
        ("transmitted", est.power(0)),
        ("reflected", est.power(1)),
        ("camera total", camera),
    ] {
        let (x, y) = (a.mean[i].re, b.mean[i].re);
        let se = a.stderr[i].hypot(b.stderr[i]);
        assert!(x > 0.0 && y > 0.0, "{what}: {x} {y}");
        assert!(
            (x - y).abs() < 4.0 * se,
            "{what}: analytic {x}, sampled {y} (± {se})"
        );
    }
}

/// Free flights that skip the inside–outside test while within the clearance end exactly where
/// flights testing after every step do (collisions and boundary hits), in a sampled sphere with
/// the depth-graded profile and in the analytic Luneburg sphere.
#[test]
fn skipped_tests_change_no_flight() {
    let sphere = sdf(
        &[Shape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        }],
        0.05,
    );
    let fields = [
        BoundedField::single(
            Profile::SdfLuneburg {
                sdf: sphere.clone(),
                n_surface: 1.1,
                n_core: 1.5,
                depth: 0.6,
            },
            Bounds::Sdf(sphere),
            1.0,
        ),
        BoundedField::single(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.0,
        ),
    ];
    for field in fields {
        let volume = Volume {
            field,
            sigma_s: 1.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        };
        let skipping = Flyer::new(&volume, 0.01, 100_000);
        let testing = Flyer::new(&volume, 0.01, 100_000).skipping_tests(false);
        let mut rng = stream_rng(7, 0);
        let mut boundaries = 0;
        for _ in 0..400 {
            let x = loop {
                let x = DVec3::new(uniform(&mut rng), uniform(&mut rng), uniform(&mut rng)) * 2.0
                    - DVec3::ONE;
                if x.length() < 0.95 {
                    break x;
                }
            };
            let d = DVec3::new(uniform(&mut rng), uniform(&mut rng), uniform(&mut rng)) * 2.0
                - DVec3::ONE;
            let r = Ray {
                x,
                v: d.normalize() * skipping.n(x),
            };
            let distance = if uniform(&mut rng) < 0.5 {
                f64::INFINITY
            } else {
                2.0 * uniform(&mut rng)
            };
            let (a, b) = (skipping.fly(r, distance), testing.fly(r, distance));
            assert_eq!(a, b, "from {x} along {d} for {distance}");
            boundaries += matches!(a.0, lightpath::rrte::flight::Flight::Boundary { .. }) as usize;
        }
        assert!(boundaries > 100, "{boundaries} flights reached the surface");
    }
}

/// A unit icosphere: an icosahedron whose triangles are split in four `levels` times, every
/// vertex pushed onto the sphere; faces outwards.
fn icosphere(levels: usize) -> Mesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<DVec3> = [
        [-1.0, p, 0.0],
        [1.0, p, 0.0],
        [-1.0, -p, 0.0],
        [1.0, -p, 0.0],
        [0.0, -1.0, p],
        [0.0, 1.0, p],
        [0.0, -1.0, -p],
        [0.0, 1.0, -p],
        [p, 0.0, -1.0],
        [p, 0.0, 1.0],
        [-p, 0.0, -1.0],
        [-p, 0.0, 1.0],
    ]
    .iter()
    .map(|v| DVec3::from_array(*v).normalize())
    .collect();
    let mut triangles = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut split = Vec::new();
        for [a, b, c] in triangles {
            let mut mid = |i: usize, j: usize| {
                *midpoints.entry((i.min(j), i.max(j))).or_insert_with(|| {
                    vertices.push(((vertices[i] + vertices[j]) * 0.5).normalize());
                    vertices.len() - 1
                })
            };
            let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
            split.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = split;
    }
    Mesh::new(vertices, triangles).unwrap()
}

/// A scattering glass ball (n = 1.3 in air, Fresnel at its surface) given as an icosphere mesh of
/// 5 120 triangles: its distance is the sphere's within the facets' sagitta, and it transmits,
/// reflects and shows a camera what the analytic ball does.
#[test]
fn a_mesh_ball_renders_as_the_analytic_one() {
    let mesh = icosphere(4);
    assert_eq!(mesh.triangles.len(), 5120);
    let spacing = 0.05;
    let (origin, dims, samples) = mesh.signed_distance_grid(spacing);
    let mut worst: f64 = 0.0;
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let x = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                let d = samples[i + dims[0] * (j + dims[1] * k)];
                worst = worst.max((d - (x.length() - 1.0)).abs());
            }
        }
    }
    // the polyhedron lies between the sphere and its facets' planes: the distances differ by at
    // most the largest gap between a plane and the sphere
    let gap = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|k| mesh.vertices[k]);
            1.0 - a.dot((b - a).cross(c - a).normalize())
        })
        .fold(0.0, f64::max);
    assert!(gap < 2e-3, "facets up to {gap} inside the sphere");
    assert!(
        worst <= gap + 1e-12,
        "largest distance error {worst}, facets' gap {gap}"
    );
    let grid = SdfGrid::from_samples(origin, spacing, dims, samples, Interp::Tricubic).unwrap();
    let scene = |bounds: Bounds| RenderScene {
        volume: Volume {
            field: BoundedField::single(Profile::Constant { n: 1.3 }, bounds, 1.0),
            sigma_s: 1.0,
            sigma_a: 0.1,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.8,
        },
        sensors: vec![
            flux("T", DVec3::new(0.0, 0.0, 1.5), DVec3::Z),
            flux("R", DVec3::new(0.0, 0.0, -1.5), -DVec3::Z),
        ],
        cameras: vec![Camera::new(
            "side".into(),
            DVec3::X,
            DVec3::new(3.0, 0.0, 0.0),
            [2.4, 2.4],
            [4, 4],
        )],
        ..bare_scene(0.01)
    };
    let analytic = scene(Bounds::Sphere { radius: 1.0 });
    let meshed = scene(Bounds::Sdf(Arc::new(grid)));
    let photons = 20_000;
    let (a, est) = common::render(&analytic, photons, 21);
    let (b, _) = common::render(&meshed, photons, 22);
    for (what, i) in [
        ("transmitted", est.power(0)),
        ("reflected", est.power(1)),
        ("camera total", est.camera_image(0).total()),
    ] {
        let (x, y) = (a.mean[i].re, b.mean[i].re);
        let se = a.stderr[i].hypot(b.stderr[i]);
        assert!(x > 0.0 && y > 0.0, "{what}: {x} {y}");
        assert!(
            (x - y).abs() < 4.0 * se,
            "{what}: analytic {x}, mesh {y} (± {se})"
        );
    }
}

/// Two scattering glass balls (index `n` in air, radius 0.6, centres 1.8 apart) joined by a thin
/// rod (radius 0.08) as one shape, not convex, with a lamp in one ball: `(scene, a point in the
/// other ball)`.
fn lamp_in_a_dumbbell(n: f64) -> (RenderScene, DVec3) {
    let (a, b) = (DVec3::new(-0.9, 0.0, 0.0), DVec3::new(0.9, 0.0, 0.0));
    let dumbbell = sdf(
        &[
            Shape::Sphere {
                center: a,
                radius: 0.6,
            },
            Shape::Sphere {
                center: b,
                radius: 0.6,
            },
            Shape::Capsule {
                from: a,
                to: b,
                radius: 0.08,
            },
        ],
        0.02,
    );
    let scene = RenderScene {
        volume: Volume {
            field: BoundedField::single(Profile::Constant { n }, Bounds::Sdf(dumbbell), 1.0),
            sigma_s: 1.0,
            sigma_a: 0.2,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Point {
            position: a + DVec3::new(0.1, 0.15, 0.05),
        },
        ..bare_scene(0.01)
    };
    (scene, b)
}

/// Fluence probes in one ball of a scattering glass dumbbell count the light of a lamp in the
/// other ball as a target does. The probes by connections from the lamp and from every
/// scattering event: within the probes' ball from the events there, and out of the shape and
/// back into it from the events in the other ball (refracted at both surfaces; in a straight
/// line when the shape is index-matched); the target by the photons' tracks through it, an
/// estimator that connects nothing (rendered apart, with more photons). The mean of four probes
/// at the corners of a regular tetrahedron `r √0.6` about the target's centre is its mean over
/// the ball of radius `r` to second order, so the two agree within 4 combined standard errors.
/// Without the paths out and back in the probes read 0.43 of the target (n = 1.1).
#[test]
fn probes_in_one_ball_of_a_dumbbell_count_the_light_from_the_other_as_a_target_does() {
    for n in [1.1, 1.0] {
        let (scene, p) = lamp_in_a_dumbbell(n);
        let radius = 0.3;
        let region = lightpath::rrte::Region::Sphere { center: p, radius };
        let mut targeted = scene.clone();
        targeted.sensors = vec![Sensor::target("around".into(), region)];
        let (e, est) = common::render(&targeted, 200_000, 7);
        let (target, st) = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
        let mut probed = scene;
        probed.probes = common::probes_about(p, radius);
        // each photon's events connect to every probe by Newton's method where n ≠ 1
        let photons = if n == 1.0 { 60_000 } else { 20_000 };
        let (e, est) = common::render(&probed, photons, 8);
        eprintln!("n = {n}");
        // a point's estimate from events near it is heavy-tailed: its error falls slowly
        let probes = common::probes_mean(&e, &est);
        common::assert_probes_count_as_target(probes, (target, st), (0.12, 0.04));
    }
}

/// Fluence probes in the last of three clear glass balls in a row (n = 1.1, radius 0.5, centres
/// 1.4 apart), one shape, count the light of a lamp in the first as a target does: every
/// straight line from the lamp to them runs through the middle ball, so the connections from
/// the lamp leave the shape, cross it (the middle ball, refracted in and out) and enter it
/// again; index-matched (n = 1), along the straight line through it. The mean of four probes
/// against the target's tracks, within 4 combined standard errors (without the crossing the
/// probes read nothing).
#[test]
fn probes_in_the_last_of_three_glass_balls_count_the_light_from_the_first_through_the_middle() {
    for n in [1.1, 1.0] {
        let centres = [-1.4, 0.0, 1.4].map(|x| DVec3::new(x, 0.0, 0.0));
        let balls = centres.map(|center| Shape::Sphere {
            center,
            radius: 0.5,
        });
        let scene = RenderScene {
            volume: Volume {
                field: BoundedField::single(
                    Profile::Constant { n },
                    Bounds::Sdf(sdf(&balls, 0.02)),
                    1.0,
                ),
                sigma_s: 0.0,
                sigma_a: 0.0,
                scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
                density: None,
                parts: Vec::new(),
            },
            light: Light::Point {
                position: centres[0] + DVec3::new(0.1, 0.1, 0.05),
            },
            ..bare_scene(0.01)
        };
        let (p, radius) = (centres[2], 0.25);
        let region = lightpath::rrte::Region::Sphere { center: p, radius };
        let mut targeted = scene.clone();
        targeted.sensors = vec![Sensor::target("around".into(), region)];
        let (e, est) = common::render(&targeted, 400_000, 7);
        let (target, st) = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
        let mut probed = scene;
        probed.probes = common::probes_about(p, radius);
        let (e, est) = common::render(&probed, 20_000, 8);
        let probes = common::probes_mean(&e, &est);
        common::assert_probes_count_as_target(probes, (target, st), (0.1, 0.05));
    }
}

/// Particle tracing, path tracing and bidirectional tracing agree on a pinhole's image of the
/// glass dumbbell with the lamp in one ball (its total and each half, within 4 combined
/// standard errors). Path tracing lights the events in the other ball by connections out of
/// the shape and back into it to the lamp, bidirectional tracing by those and its other
/// strategies, weighted as what a connection can make; particle tracing makes those paths by
/// tracing alone (index-matched: straight paths, and Newton's where n ≠ 1 is the probes' test
/// above). Without the connections out and back in, path tracing reads 0.43 of particle tracing
/// on the half holding the rod; with bidirectional tracing's weights taking those segments for
/// traced alone (while connections make them too), bidirectional tracing reads 1.7 times.
#[test]
fn the_three_estimators_agree_on_a_dumbbell_lit_from_inside_one_ball() {
    let (mut scene, _) = lamp_in_a_dumbbell(1.0);
    // looking down at the ball without the lamp
    scene.pinholes = vec![
        Pinhole::looking_at(
            "above".into(),
            DVec3::new(0.9, 0.3, 3.0),
            DVec3::new(0.9, 0.0, 0.0),
            DVec3::Y,
            30f64.to_radians(),
            [12, 8],
        )
        .unwrap(),
    ];
    common::three_estimators_agree(&scene, 1_000_000, 160_000);
}

/// Three scattering glass balls in a row (n = 1.1, radius 0.5, centres 1.3 apart), one shape,
/// the middle one clear, with a lamp in the first, seen from above the last: the light reaching
/// the last ball's events comes through the middle one. Particle, path and bidirectional tracing
/// agree on the pinhole's image (its total and each half, within 4 combined standard errors):
/// bidirectional tracing joins an event in the first ball to one in the last by paths that
/// leave the shape, cross the middle ball (another stretch of it) and enter it again, its
/// weights counting those segments as what such a join makes.
#[test]
fn the_three_estimators_agree_on_three_balls_in_a_row_lit_from_the_first() {
    let centres = [-1.3, 0.0, 1.3].map(|x| DVec3::new(x, 0.0, 0.0));
    let balls = centres.map(|center| Shape::Sphere {
        center,
        radius: 0.5,
    });
    let field = BoundedField::single(
        Profile::Constant { n: 1.1 },
        Bounds::Sdf(sdf(&balls, 0.02)),
        1.0,
    );
    // the middle ball clear: a density of the medium, 1 in the outer balls, 0 in the middle
    // (the grid spans the shape: x in ±1.85)
    let (spacing, counts) = (0.05, [75, 25, 25]);
    let corner = DVec3::new(-1.85, -0.6, -0.6);
    let values = (0..counts[2])
        .flat_map(|_| (0..counts[1]).flat_map(move |_| 0..counts[0]))
        .map(|i| f64::from((corner.x + i as f64 * spacing).abs() > 0.65))
        .collect();
    let density = lightpath::eikonal::grid::GridField::from_samples(
        corner,
        spacing,
        counts,
        values,
        Interp::Trilinear,
    )
    .unwrap();
    let scene = RenderScene {
        volume: Volume {
            field,
            sigma_s: 1.5,
            sigma_a: 0.1,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: Some(lightpath::rrte::Density::new(density).unwrap()),
            parts: Vec::new(),
        },
        light: Light::Point {
            position: centres[0] + DVec3::new(0.1, 0.1, 0.05),
        },
        pinholes: vec![
            Pinhole::looking_at(
                "above".into(),
                centres[2] + DVec3::new(0.0, 0.3, 3.0),
                centres[2],
                DVec3::Y,
                30f64.to_radians(),
                [12, 8],
            )
            .unwrap(),
        ],
        ..bare_scene(0.01)
    };
    common::three_estimators_agree(&scene, 400_000, 60_000);
}
