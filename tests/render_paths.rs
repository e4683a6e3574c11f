//! Path tracing from the cameras against particle tracing from the light: two independent
//! estimators of the same images (camera paths connected to the light, photons connected to the
//! camera), on index-matched volumes where both estimate every path: a scattering sphere with
//! straight rays and a point light outside, a scattering Luneburg lens with curved rays and a point
//! light inside, and a white floor beside a scattering sphere; then bidirectional tracing too,
//! with Fresnel faces and surfaces, and light crossing a volume between two points outside it (a
//! floor seen and lit through a lens, a wall lit through a glass ball), and light reflected off
//! its outside (a floor seen in a dark glass ball's mirror image, the lamp's reflection on it);
//! and a glass shape that is not convex, one part of it seen through another.

use crate::common;

use common::{bare_scene, render};
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Profile};
use lightpath::mc::Estimate;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{
    Camera, ImageLayout, Light, Pinhole, Probe, RenderScene, STRATEGY_EVENTS, Sensor, SensorKind,
    Surface, Total, Tracing, Volume,
};

fn scene(profile: Profile, light: Light, camera: Pinhole) -> RenderScene {
    RenderScene {
        volume: Volume {
            field: BoundedField::single(profile, Bounds::Sphere { radius: 1.0 }, 1.0),
            sigma_s: 1.5,
            sigma_a: 0.1,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
            density: None,
            parts: Vec::new(),
        },
        light,
        pinholes: vec![camera],
        ..bare_scene(0.004)
    }
}

/// A white floor (albedo 0.7), 8 × 8, half a radius below the sphere.
fn floor() -> Surface {
    Surface::new(
        "floor".into(),
        DVec3::new(0.0, 0.0, -1.5),
        DVec3::Z,
        Some([8.0, 8.0]),
        0.7,
    )
}

fn camera(position: DVec3, target: DVec3, fov_deg: f64) -> Pinhole {
    Pinhole::looking_at(
        "cam".into(),
        position,
        target,
        DVec3::Z,
        fov_deg.to_radians(),
        [10, 10],
    )
    .unwrap()
}

/// Render `s` both ways and compare the pinhole's irradiance and every pixel (within 4 combined
/// standard errors; one pixel in a hundred may stray as far by chance, none beyond 5), or with
/// `blocks`, the image's four quadrants instead of its pixels; likewise an orthographic camera's
/// when the scene has one.
fn agree(mut s: RenderScene, photons: u64, paths: u64, blocks: bool) {
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, photons, 1);
    let mut p = s.clone();
    p.tracing = Tracing::FromCameras;
    let (b, _) = render(&p, paths, 2);
    let mut images = vec![est.pinhole_image(0)];
    if !s.cameras.is_empty() {
        images.push(est.camera_image(0));
    }
    for &image in &images {
        compare_images(&a, &b, image, blocks);
    }
    p.tracing = Tracing::Bidirectional;
    let (c, _) = render(&p, paths, 3);
    for &image in &images {
        compare_images(&a, &c, image, blocks);
        compare_images(&b, &c, image, blocks);
    }
    for i in 0..s.surfaces.len() {
        // the light reaching each surface, which the light subpaths record
        totals_agree(&a, &c, est.surface_power(i), &format!("surface {i}"));
    }
}

/// Assert that output `k` of two renders is positive and agrees within 4 combined standard
/// errors.
fn totals_agree(a: &Estimate, b: &Estimate, k: usize, what: &str) {
    let (x, y) = (a.mean[k].re, b.mean[k].re);
    let se = a.stderr[k].hypot(b.stderr[k]);
    assert!(
        x > 0.0 && (x - y).abs() < 4.0 * se,
        "{what}: particles {x}, against {y} (± {se})"
    );
}

fn compare_images(a: &Estimate, b: &Estimate, image: ImageLayout, blocks: bool) {
    let compare = |k: usize| {
        let (x, sx, y, sy) = (a.mean[k].re, a.stderr[k], b.mean[k].re, b.stderr[k]);
        (
            (x - y).abs() / (sx * sx + sy * sy).sqrt().max(1e-300),
            x,
            sx,
            y,
            sy,
        )
    };
    let (z, x, sx, y, sy) = compare(image.total());
    assert!(
        z < 4.0 && y > 0.0,
        "total: particles {x} ± {sx}, paths {y} ± {sy}"
    );
    if blocks {
        // sums over the quadrants of the 10 × 10 image, their pixels' errors added in quadrature
        // (one path reaching several pixels correlates them; the 4σ allowance covers it)
        for (qx, qy) in [(0, 0), (5, 0), (0, 5), (5, 5)] {
            let (mut x, mut vx, mut y, mut vy) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for j in qy..qy + 5 {
                for i in qx..qx + 5 {
                    let k = image.plane(None, 0) + j * 10 + i;
                    x += a.mean[k].re;
                    vx += a.stderr[k].powi(2);
                    y += b.mean[k].re;
                    vy += b.stderr[k].powi(2);
                }
            }
            assert!(
                (x - y).abs() < 4.0 * (vx + vy).sqrt(),
                "quadrant ({qx}, {qy}): particles {x} ± {}, paths {y} ± {}",
                vx.sqrt(),
                vy.sqrt()
            );
        }
        return;
    }
    let mut stray = 0;
    let mut lit = 0;
    for k in 0..image.pixels {
        let (z, x, sx, y, sy) = compare(image.plane(None, 0) + k);
        if y > 0.0 {
            lit += 1;
        }
        assert!(z < 5.0, "pixel {k}: particles {x} ± {sx}, paths {y} ± {sy}");
        if z > 4.0 {
            stray += 1;
        }
    }
    assert!(stray <= 1, "{stray} pixels beyond 4 standard errors");
    assert!(lit > image.pixels / 4, "only {lit} pixels lit");
}

/// Straight rays: a point light outside a scattering sphere (index-matched), seen from the side
/// by a pinhole and from above by an orthographic camera.
#[test]
fn straight_rays_agree() {
    let mut s = scene(
        Profile::Constant { n: 1.0 },
        Light::Point {
            position: DVec3::new(0.0, 0.0, -2.5),
        },
        camera(DVec3::new(3.0, 1.0, 2.0), DVec3::ZERO, 45.0),
    );
    s.cameras.push(Camera::new(
        "top".into(),
        DVec3::Z,
        DVec3::new(0.0, 0.0, 2.0),
        [2.4, 2.4],
        [10, 10],
    ));
    agree(s, 400_000, 40_000, false);
}

/// Curved rays: a point light inside a scattering Luneburg lens (n = 1 at its surface).
#[test]
fn curved_rays_agree() {
    let s = scene(
        Profile::Luneburg { radius: 1.0 },
        Light::Point {
            position: DVec3::new(0.2, -0.3, -0.5),
        },
        camera(DVec3::new(3.0, 1.0, 2.0), DVec3::ZERO, 45.0),
    );
    agree(s, 60_000, 12_000, true);
}

/// A white floor beside the sphere, lit by a spot light above: the camera sees the floor and
/// the light it sends back into the sphere (all three estimators); and an orthographic camera
/// looking down at 45° from just beyond the sphere, whose image plane the floor reaches through
/// (the floor beyond it is out of its view, as a path from the camera never meets it).
#[test]
fn a_floor_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.0 },
        Light::Spot {
            position: DVec3::new(0.0, 0.0, 2.5),
            axis: -DVec3::Z,
            half_angle: 50f64.to_radians(),
        },
        camera(DVec3::new(2.5, -2.0, 1.0), DVec3::new(1.5, 0.0, -1.3), 40.0),
    );
    s.surfaces.push(floor());
    s.cameras.push(Camera::new(
        "slanted".into(),
        DVec3::new(1.0, 0.0, 1.0).normalize(),
        DVec3::new(1.2, 0.0, 0.3),
        [7.0, 7.0],
        [10, 10],
    ));
    agree(s, 400_000, 40_000, false);
}

/// A beam: a collimated beam straight down through the side of a scattering sphere
/// (index-matched) onto a white floor, seen by a pinhole and from above by an orthographic
/// camera. Path tracing connects its events to the beam's disc (in the sphere, and on the floor
/// lit straight or through the sphere), as bidirectional tracing now does too (the light's own
/// strategy).
#[test]
fn a_beam_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.0 },
        Light::Beam {
            center: DVec3::new(0.6, 0.0, 2.5),
            direction: -DVec3::Z,
            radius: 0.8,
        },
        camera(DVec3::new(2.5, -2.0, 2.5), DVec3::new(0.5, 0.0, -0.8), 30.0),
    );
    s.surfaces.push(floor());
    s.cameras.push(Camera::new(
        "top".into(),
        DVec3::Z,
        DVec3::new(0.5, 0.0, 2.0),
        [3.0, 3.0],
        [10, 10],
    ));
    agree(s, 400_000, 40_000, false);
}

/// A focused beam through the side of the index-matched scattering sphere onto the white floor,
/// seen by a pinhole and from above by an orthographic camera. Focused below the floor, its rays
/// converge through the sphere onto the floor: paths from the cameras leave along lines through
/// the focus, which lies ahead of the beam, behind where they leave. Focused inside the sphere, its rays
/// meet at a point of the scattering medium, where the irradiance grows as `1/r²` (path
/// tracing's variance without bound): bidirectional tracing, whose weights count the light's
/// rays spreading from the focus, against particle tracing.
#[test]
fn a_focused_beam_agrees() {
    let focused = |focus: DVec3| {
        let mut s = scene(
            Profile::Constant { n: 1.0 },
            Light::FocusedBeam {
                center: DVec3::new(0.3, 0.0, 2.5),
                direction: -DVec3::Z,
                radius: 0.8,
                focus,
            },
            camera(DVec3::new(2.5, -2.0, 2.5), DVec3::new(0.3, 0.0, -0.8), 30.0),
        );
        s.surfaces.push(floor());
        s.cameras.push(Camera::new(
            "top".into(),
            DVec3::Z,
            DVec3::new(0.3, 0.0, 2.0),
            [3.0, 3.0],
            [10, 10],
        ));
        s
    };
    agree(focused(DVec3::new(0.2, 0.0, -4.5)), 400_000, 40_000, false);
    let mut s = focused(DVec3::new(0.2, 0.0, 0.0));
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 400_000, 1);
    let mut b = s.clone();
    b.tracing = Tracing::Bidirectional;
    let (c, _) = render(&b, 40_000, 3);
    for image in [est.pinhole_image(0), est.camera_image(0)] {
        compare_images(&a, &c, image, false);
    }
}

/// A focused beam and curved rays: a beam focused below a scattering Luneburg lens, which
/// bends its converging rays further on the way, and a beam focused before a glass sphere
/// (n = 1.3, Fresnel at its surface: its rays cross at a real focus, then spread into it); the
/// connections solve for the path out of the volume whose line passes through the focus.
#[test]
fn focused_beams_through_curved_and_glass_agree() {
    let focused = |focus: DVec3| Light::FocusedBeam {
        center: DVec3::new(0.0, 0.0, 3.0),
        direction: -DVec3::Z,
        radius: 0.5,
        focus,
    };
    let s = scene(
        Profile::Luneburg { radius: 1.0 },
        focused(DVec3::new(0.0, 0.0, -1.5)),
        camera(DVec3::new(3.0, 1.0, 2.0), DVec3::ZERO, 45.0),
    );
    agree(s, 30_000, 6_000, true);
    let s = scene(
        Profile::Constant { n: 1.3 },
        focused(DVec3::new(0.0, 0.0, 1.8)),
        camera(DVec3::new(3.0, 1.0, 2.0), DVec3::ZERO, 45.0),
    );
    agree(s, 200_000, 40_000, true);
}

/// Fresnel faces: a scattering slab of n = 1.4 in air under a beam at normal incidence, seen
/// along its normal by orthographic cameras on both sides. A plane keeps `|cos|` of a ray it
/// reflects, so no path reaching these cameras reflects inside a face on its last segment
/// (only rays along the normal leave along it): particle tracing makes every path, and so does
/// bidirectional path tracing, whose strategies skip the segments that reflect inside (the
/// light's own strategy, the beam's disc connected to a camera path's event, follows no
/// reflection). Path tracing, which connects its events to the beam's disc, misses the light
/// that reflects inside a face more often than `render.reflections` before its first event:
/// with one reflection, a fraction of 10⁻⁴ here. Flux sensors on both sides and a fluence probe
/// inside agree too.
#[test]
fn fresnel_faces_agree() {
    let volume = Volume {
        field: BoundedField::single(
            Profile::Constant { n: 1.4 },
            Bounds::Box {
                half: DVec3::new(50.0, 50.0, 0.5),
            },
            1.0,
        ),
        sigma_s: 1.5,
        sigma_a: 0.1,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.5 }),
        density: None,
        parts: Vec::new(),
    };
    let side = |direction: DVec3| {
        Camera::new(
            "face".into(),
            direction,
            direction * 1.0,
            [2.0, 2.0],
            [4, 4],
        )
    };
    let mut s = RenderScene {
        volume,
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -1.0),
            direction: DVec3::Z,
            radius: 0.4,
        },
        cameras: vec![side(DVec3::Z), side(-DVec3::Z)],
        // and flux sensors and a fluence probe, which the light subpaths of bidirectional
        // tracing record as photons do
        probes: vec![Probe {
            name: "middle".into(),
            position: DVec3::new(0.1, 0.0, 0.0),
        }],
        sensors: vec![
            Sensor::new(
                "T".into(),
                SensorKind::Flux,
                DVec3::new(0.0, 0.0, 0.8),
                DVec3::Z,
                None,
                [1, 1],
            ),
            Sensor::new(
                "R".into(),
                SensorKind::Flux,
                DVec3::new(0.0, 0.0, -0.8),
                -DVec3::Z,
                None,
                [1, 1],
            ),
        ],
        ..bare_scene(0.01)
    };
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 100_000, 4);
    let mut p = s.clone();
    p.tracing = Tracing::Bidirectional;
    let (b, _) = render(&p, 20_000, 5);
    p.tracing = Tracing::FromCameras;
    p.reflections = 1;
    let (c, _) = render(&p, 20_000, 6);
    for i in 0..2 {
        compare_images(&a, &b, est.camera_image(i), false);
        compare_images(&a, &c, est.camera_image(i), false);
        totals_agree(&a, &b, est.power(i), &format!("flux {i}"));
    }
    totals_agree(&a, &b, est.probe_total(0), "probe");
}

/// A white floor under a scattering glass ball (n = 1.5 in air) with a lamp inside, seen only
/// where no view passes through the glass: from straight above by an orthographic camera and
/// by a pinhole looking down. Particle tracing makes every path these cameras see (the last
/// segment runs straight from the floor), and so does bidirectional tracing, which also joins
/// the floor to events inside through the glass (one refraction) and the lamp to the floor; the
/// light the floor receives agrees too. Path tracing misses light that reflects inside the
/// glass before reaching the floor, and is left out.
#[test]
fn a_floor_under_glass_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.5 },
        Light::Point {
            position: DVec3::new(0.2, -0.1, 0.3),
        },
        camera(DVec3::new(2.6, 0.3, -0.3), DVec3::new(2.9, 0.3, -1.5), 50.0),
    );
    s.cameras.push(Camera::new(
        "above".into(),
        DVec3::Z,
        DVec3::new(2.5, 0.0, 0.0),
        [1.6, 1.6],
        [4, 4],
    ));
    s.surfaces.push(floor());
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 400_000, 6);
    let mut p = s.clone();
    p.tracing = Tracing::Bidirectional;
    let (b, _) = render(&p, 60_000, 7);
    compare_images(&a, &b, est.pinhole_image(0), false);
    compare_images(&a, &b, est.camera_image(0), false);
    totals_agree(&a, &b, est.surface_power(0), "floor");
}

/// A white floor under a weakly scattering Luneburg lens, lit from above through the lens (a
/// caustic on the floor) and seen through it by a pinhole looking down past its centre: light
/// reaches the floor and the camera across the lens, refracted in and out along curved rays.
/// `n` = 1 at its surface, so nothing reflects there and all three estimators make every
/// path: particle tracing joins the floor to the camera across the lens, path tracing the light
/// to the floor, bidirectional tracing both and floor to floor.
#[test]
fn a_floor_seen_and_lit_through_a_lens_agrees() {
    let mut s = scene(
        Profile::Luneburg { radius: 1.0 },
        Light::Point {
            position: DVec3::new(0.3, 0.0, 3.0),
        },
        camera(
            DVec3::new(2.5, -1.0, 1.0),
            DVec3::new(-0.5, 0.2, -0.8),
            60.0,
        ),
    );
    s.volume.sigma_s = 0.3;
    s.volume.sigma_a = 0.05;
    s.step = 0.01;
    s.surfaces.push(floor());
    agree(s, 200_000, 20_000, false);
}

/// A clear, absorbing ball (n = 1.2 in air) between a point light and a white wall: the wall
/// lies in the ball's shadow, lit only by the light the ball focuses through itself. A pinhole
/// beside the ball sees the middle of that spot directly (not the ball, nor the spot's bright
/// rim, where the focused rays fold and a camera path's estimate has unbounded variance).
/// Particle tracing makes every path it sees (the last segment runs straight from the wall);
/// path tracing joins the light to the wall across the ball (two refractions, both Fresnel
/// transmissions, the attenuation inside), and without that connection sees nothing;
/// bidirectional tracing does both. What path tracing does not join, light reflected inside the
/// ball on its way, carries a reflectance of about 1 % at this index (0.8 % at normal
/// incidence), below the noise of this comparison.
#[test]
fn a_wall_lit_through_glass_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.2 },
        Light::Point {
            position: DVec3::new(-3.0, 0.0, 0.1),
        },
        camera(DVec3::new(0.2, -2.5, 0.3), DVec3::new(1.2, 0.0, -0.05), 6.0),
    );
    s.volume.sigma_s = 0.0;
    s.volume.sigma_a = 0.3;
    s.surfaces.push(Surface::new(
        "wall".into(),
        DVec3::new(1.2, 0.0, 0.0),
        -DVec3::X,
        Some([4.0, 4.0]),
        0.7,
    ));
    agree(s, 4_000_000, 40_000, false);
}

/// A dark glass ball (n = 1.5 in air, absorbing all it lets in) over a white floor lit by a
/// lamp beside it, seen by a pinhole that takes in the ball and the floor around it. The ball
/// shows the floor's mirror image (the Fresnel reflectance off its outside), and throws the
/// lamp's reflection onto the floor. Particle tracing joins the floor to the camera off the
/// ball's outside, path tracing the lamp to the floor so; the other half of each is traced
/// (a photon reflected on its way to the floor, a camera path on its way from the camera), and
/// bidirectional tracing weighs both. Without the connection off the outside particle tracing
/// sees a black ball.
#[test]
fn a_floor_mirrored_in_a_dark_glass_ball_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.5 },
        Light::Point {
            position: DVec3::new(2.2, 1.8, 1.2),
        },
        camera(DVec3::new(3.0, -0.6, 0.2), DVec3::new(0.0, 0.0, -0.4), 40.0),
    );
    s.volume.sigma_s = 0.0;
    s.volume.sigma_a = 200.0;
    s.surfaces.push(floor());
    agree(s, 2_000_000, 200_000, true);
}

/// Light leaving a scattering glass cube (n = 1.5 in air) after reflecting inside it, with a lamp
/// inside and a pinhole looking at a corner. A cube keeps the size of each component of a direction
/// it reflects, so light that meets one face beyond the critical angle leaves through another: much
/// of what the camera sees has reflected inside before leaving. Particle tracing with `reflections
/// = 3` joins every event to the camera after up to three reflections inside, and agrees with
/// bidirectional tracing (which joins them so too, and makes the rest by tracing; paths reflecting
/// more often on their last segment carry less than the noise here); with none it reads 9 % less
/// (7 standard errors). Path tracing is left out: a cube traps light by total internal reflection on every face, so much of
/// what reaches the first event has reflected more often than any connection does.
#[test]
fn light_reflected_inside_a_glass_cube_agrees() {
    let mut s = scene(
        Profile::Constant { n: 1.5 },
        Light::Point {
            position: DVec3::new(0.1, -0.05, 0.15),
        },
        camera(DVec3::new(2.0, 1.2, 1.5), DVec3::ZERO, 40.0),
    );
    s.volume.field = BoundedField::single(
        Profile::Constant { n: 1.5 },
        Bounds::Box {
            half: DVec3::splat(0.5),
        },
        1.0,
    );
    s.volume.sigma_s = 1.0;
    s.reflections = 3;
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 120_000, 11);
    let mut p = s.clone();
    p.tracing = Tracing::Bidirectional;
    let (b, _) = render(&p, 24_000, 12);
    compare_images(&a, &b, est.pinhole_image(0), false);
}

/// A lamp near the middle of a weakly scattering ball of high index (n = 3 in air: 25 %
/// reflected at normal incidence), seen by a pinhole. The lamp's light meets the surface too
/// steeply to be trapped, and much of it reaches its first event only after reflecting inside.
/// With `reflections = 2` path tracing joins the lamp to every event after up to two reflections
/// inside (each order a set of stationary paths of its own, drawn by Alg. 3 from uniform starts),
/// and particle tracing every event to the camera so: the two agree (image quadrants and total;
/// the restart counts are heavy-tailed, so single pixels are not compared). Without the
/// reflected connections from the lamp, path tracing reads 7 % low (8 standard errors).
#[test]
fn light_reflected_inside_a_ball_before_its_first_event_agrees() {
    let mut s = scene(
        Profile::Constant { n: 3.0 },
        Light::Point {
            position: DVec3::new(0.1, -0.05, 0.15),
        },
        camera(DVec3::new(2.6, 1.2, 0.8), DVec3::ZERO, 50.0),
    );
    s.volume.sigma_s = 0.6;
    s.reflections = 2;
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 100_000, 14);
    let mut p = s.clone();
    p.tracing = Tracing::FromCameras;
    let (b, _) = render(&p, 100_000, 15);
    compare_images(&a, &b, est.pinhole_image(0), true);
}

/// A scattering glass ball (n = 1.5, radius 0.5) and a scattering glass plate 0.2 thick beside
/// it, as one signed-distance shape that does not hold the origin; a lamp below the ball throws a
/// cone up into it, and cameras beyond the plate see the ball only through it. A connection from
/// an event in the ball leaves it, crosses the gap and is refracted through the plate on its way
/// to the camera; path tracing traces the camera's rays through both and joins events to the lamp
/// straight out of the part they are in (nothing hides the lamp from either). Both follow one
/// reflection inside the part a connection leaves; light reflected inside the plate reaches the
/// cameras again only after two reflections (R² ≈ 0.2 %), which the connections through it leave
/// out. Bidirectional tracing joins the ball's events to the cameras through the plate, and the
/// lamp to the events of camera rays traced through it; its weights count both as connections.
/// The totals of a pinhole and an orthographic camera agree within 4 combined standard
/// errors (about 4 % each). Particle tracing that dropped the connections meeting the shape again
/// reads a tenth of them, and a connector that took the shape for index-matched (it once read `n`
/// at the origin, outside the shape) twice them. Bidirectional weights that took the segments
/// through the plate for traced alone (each counts its own strategy, so both made the path in
/// full) read 1.4 times them.
#[test]
fn a_glass_ball_seen_through_a_glass_plate_agrees() {
    use lightpath::eikonal::grid::Interp;
    use lightpath::eikonal::sdf::{SdfGrid, Shape};
    let shapes = [
        Shape::Sphere {
            center: DVec3::new(-0.6, 0.0, 0.0),
            radius: 0.5,
        },
        Shape::Box {
            center: DVec3::new(0.5, 0.0, 0.0),
            half: DVec3::new(0.1, 0.7, 0.7),
            rounding: 0.0,
        },
    ];
    let spacing = 0.04;
    let sdf = SdfGrid::from_shapes(&shapes, 0.0, spacing, Interp::Tricubic).unwrap();
    let mut s = scene(
        Profile::Constant { n: 1.5 },
        Light::Spot {
            position: DVec3::new(-0.6, -1.5, 0.0),
            axis: DVec3::Y,
            half_angle: 25f64.to_radians(),
        },
        camera(DVec3::new(3.0, 0.3, 0.2), DVec3::ZERO, 30.0),
    );
    s.volume.field = BoundedField::single(
        Profile::Constant { n: 1.5 },
        Bounds::Sdf(std::sync::Arc::new(sdf)),
        1.0,
    );
    s.volume.sigma_s = 1.0;
    s.volume.sigma_a = 0.2;
    s.reflections = 1;
    s.cameras.push(Camera::new(
        "beyond".into(),
        DVec3::X,
        DVec3::new(3.0, 0.0, 0.0),
        [1.6, 1.6],
        [10, 10],
    ));
    s.tracing = Tracing::FromLight;
    let (a, est) = render(&s, 10_000, 1);
    let mut p = s.clone();
    p.tracing = Tracing::FromCameras;
    let (b, _) = render(&p, 10_000, 2);
    p.tracing = Tracing::Bidirectional;
    let (c, _) = render(&p, 10_000, 3);
    for image in [est.pinhole_image(0), est.camera_image(0)] {
        totals_agree(&a, &b, image.total(), "camera total");
        totals_agree(&a, &c, image.total(), "camera total, bidirectional");
    }
}

/// Bidirectional tracing tallies each camera's total by strategy: the tallies sum to it, and
/// the single-scattering ones (`k = 1`: the beam joined to a camera event, a light event to the
/// camera) sum to single scattering in closed form. A collimated beam (power 1) crosses a thin
/// index-matched slab (`σ_s = 0.2`, `σ_a = 0.1`, depth 0.5, HG `g = 0.5`) at normal incidence;
/// an orthographic camera records the light leaving its far face at 40° to the beam: its
/// intensity from one event at depth `z` is `σ_s p(cos 40°) e^{−σ_t z} e^{−σ_t (d − z)/cos 40°}`,
/// integrated over `z`. The camera's whole intensity, multiple scattering included, lies well
/// above it.
#[test]
fn a_thin_slabs_single_scattering_is_the_sum_of_its_one_event_strategies() {
    let (sigma_s, sigma_a, depth, g) = (0.2, 0.1, 0.5, 0.5);
    let theta = 40f64.to_radians();
    let direction = DVec3::new(theta.sin(), 0.0, theta.cos());
    let mut s = RenderScene {
        volume: common::hg_box(1.0, DVec3::new(3.0, 3.0, depth / 2.0), sigma_s, sigma_a, g),
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -1.0),
            direction: DVec3::Z,
            radius: 0.2,
        },
        ..bare_scene(0.004)
    };
    s.cameras.push(Camera::new(
        "slanted".into(),
        direction,
        DVec3::new(0.3, 0.0, 1.0),
        [2.0, 2.0],
        [8, 8],
    ));
    s.tracing = Tracing::Bidirectional;
    let (e, est) = render(&s, 800_000, 5);
    let area = s.cameras[0].pixel_area();
    let intensity = |k: usize| (e.mean[k].re * area, e.stderr[k] * area);
    let (total, total_error) = intensity(est.camera_image(0).total());
    let mut sum = 0.0;
    for k in 1..=lightpath::rrte::STRATEGY_EVENTS {
        for j in 0..=k {
            sum += intensity(est.strategy_total(0, k, j)).0;
        }
    }
    sum += intensity(est.strategy_total(0, lightpath::rrte::STRATEGY_EVENTS + 1, 0)).0;
    assert!((sum - total).abs() < 1e-12 * total, "{sum} against {total}");

    let (beam, beam_error) = intensity(est.strategy_total(0, 1, 0));
    let (photons, photons_error) = intensity(est.strategy_total(0, 1, 1));
    let single = beam + photons;
    let error = beam_error.hypot(photons_error);
    let sigma_t = sigma_s + sigma_a;
    let mu = theta.cos();
    let p = (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * mu).powf(1.5));
    let rate = sigma_t * (1.0 - 1.0 / mu);
    let closed = sigma_s * p * (-sigma_t * depth / mu).exp() * (1.0 - (-rate * depth).exp()) / rate;
    eprintln!(
        "single scattering: {single:.5e} ± {error:.1e} (beam {beam:.3e}, photons {photons:.3e}), \
         closed form {closed:.5e}; all {total:.5e} ± {total_error:.1e}"
    );
    assert!(error < 0.01 * closed, "{error}");
    assert!(
        (single - closed).abs() < 4.0 * error,
        "{single} ± {error} against {closed}"
    );
    assert!(
        total - closed > 8.0 * total_error.hypot(error),
        "{total} ± {total_error}"
    );
}

/// A thin laser beam (radius 0.05) through a weakly scattering box whose index rises with
/// height (a small sugar-gradient tank), seen from the side by a pinhole. Bidirectional tracing's
/// camera subpaths draw half the collisions of their flights from an event on the stretch where
/// the ray runs through the beam's tube: its image agrees pixel by pixel with particle
/// tracing's, its paths of two events drawn wholly from the camera (joined to the beam's disc)
/// now carry light, and the camera's total has less noise than the same samples without those
/// draws.
#[test]
fn a_thin_beam_in_a_graded_box_agrees_and_its_tube_draws_lower_the_noise() {
    let mut s = thin_beam_in_a_graded_box(0.3, 0.05);
    let (a, _) = render(&s, 200_000, 1);
    s.tracing = Tracing::Bidirectional;
    let (c, est) = render(&s, 40_000, 2);
    let image = est.pinhole_image(0);
    compare_images(&a, &c, image, false);
    let (drawn, error) = (
        c.mean[est.strategy_total(0, 2, 0)].re,
        c.stderr[est.strategy_total(0, 2, 0)],
    );
    assert!(
        drawn > 5.0 * error,
        "two events from the camera: {drawn} ± {error}"
    );
    let free = lightpath::rrte::ParticleTracer::new(&s).without_beam_tube();
    let f = common::estimate(&free, &lightpath::mc::Plan::new(2, 40_000, 40_000 / 64));
    // the error of what the strategies with camera events bring, where the draws act (those
    // wholly from the light join the same light subpaths to the camera in both runs)
    let camera_side = |e: &Estimate| {
        let strategies = (1..=STRATEGY_EVENTS).flat_map(|k| (0..k).map(move |s| (k, s)));
        let variance: f64 = strategies
            .map(|(k, s)| e.stderr[est.strategy_total(0, k, s)].powi(2))
            .sum();
        variance.sqrt()
    };
    let (with, without) = (camera_side(&c), camera_side(&f));
    eprintln!(
        "camera total: {:.4e} ± {:.2e} with the tube's draws, {:.4e} ± {:.2e} without; \
         its strategies with camera events ± {with:.2e} and {without:.2e}",
        c.mean[image.total()].re,
        c.stderr[image.total()],
        f.mean[image.total()].re,
        f.stderr[image.total()],
    );
    // each error is itself estimated from 64 batches (to about 9 %)
    assert!(with < 0.8 * without, "{with} against {without}");
}

/// The same box thinner (`σ_t` times its diagonal 0.52: most camera rays cross it without an
/// event), where bidirectional tracing's camera subpaths also draw half their first legs'
/// collisions uniformly along the leg and aim half their scattering directions at the beam:
/// its image agrees pixel by pixel with particle tracing's, its subpaths meet half as many
/// events again as the same samples without the tube's draws, and aiming gives the two-event
/// paths drawn wholly from the camera more of the light of those with camera events.
#[test]
fn a_thin_beam_in_a_thin_graded_box_agrees_with_its_first_legs_drawn() {
    let mut s = thin_beam_in_a_graded_box(0.12, 0.03);
    let (a, _) = render(&s, 400_000, 1);
    s.tracing = Tracing::Bidirectional;
    let (c, est) = render(&s, 40_000, 2);
    compare_images(&a, &c, est.pinhole_image(0), false);
    let free = lightpath::rrte::ParticleTracer::new(&s).without_beam_tube();
    let f = common::estimate(&free, &lightpath::mc::Plan::new(2, 40_000, 40_000 / 64));
    let events = |e: &Estimate| e.mean[est.total(Total::Events)].re;
    eprintln!(
        "events per sample: {:.3} with the draws, {:.3} without; camera total {:.4e} ± {:.2e}, \
         particles {:.4e} ± {:.2e}",
        events(&c),
        events(&f),
        c.mean[est.pinhole_image(0).total()].re,
        c.stderr[est.pinhole_image(0).total()],
        a.mean[est.pinhole_image(0).total()].re,
        a.stderr[est.pinhole_image(0).total()],
    );
    assert!(
        events(&c) > 1.5 * events(&f),
        "{} against {}",
        events(&c),
        events(&f)
    );
    // aiming at the beam: the two-event paths with camera events are drawn more often wholly
    // from the camera (its event in front of the beam, its direction aimed into it), so the
    // balance heuristic gives that strategy more of their light than without aiming
    let unaimed = lightpath::rrte::ParticleTracer::new(&s).without_aiming();
    let u = common::estimate(&unaimed, &lightpath::mc::Plan::new(2, 40_000, 40_000 / 64));
    let camera_share = |e: &Estimate| {
        let (drawn, joined) = (est.strategy_total(0, 2, 0), est.strategy_total(0, 2, 1));
        let (a, b) = (e.mean[drawn].re, e.mean[joined].re);
        let relative = (e.stderr[drawn] / a).hypot(e.stderr[joined] / b);
        let share = a / (a + b);
        (share, share * (1.0 - share) * relative)
    };
    let ((aimed, aimed_error), (plain, plain_error)) = (camera_share(&c), camera_share(&u));
    eprintln!(
        "two events wholly from the camera: {aimed:.3} ± {aimed_error:.3} of those with camera \
         events aiming, {plain:.3} ± {plain_error:.3} without"
    );
    assert!(
        aimed - plain > 3.0 * aimed_error.hypot(plain_error),
        "{aimed} ± {aimed_error} against {plain} ± {plain_error}"
    );
}

/// A thin laser beam (radius 0.05) through a 2-unit box whose index rises with height,
/// `n = 1.33 + 0.05 y`, scattering forward (HG g = 0.9), seen from the side by a pinhole;
/// reflections inside followed once.
fn thin_beam_in_a_graded_box(sigma_s: f64, sigma_a: f64) -> RenderScene {
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Linear {
                    n0: 1.33,
                    gradient: DVec3::new(0.0, 0.05, 0.0),
                },
                Bounds::Box {
                    half: DVec3::splat(1.0),
                },
                1.0,
            ),
            sigma_s,
            sigma_a,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.9 }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -1.5),
            direction: DVec3::Z,
            radius: 0.05,
        },
        pinholes: vec![camera(
            DVec3::new(6.0, 0.1, 0.0),
            DVec3::new(0.0, 0.1, 0.0),
            25.0,
        )],
        reflections: 1,
        ..bare_scene(0.02)
    }
}
