//! Targets (the mean fluence over a region inside the volume, by track lengths) and derivatives
//! of rendered targets with respect to the index field's parameters (forward sensitivities of
//! every photon's path, its choices scored):
//! - a target's fluence against the closed form of a point source in an absorber, by particle
//!   tracing and by the differentiating tracer;
//! - the derivatives against the difference quotients of the estimate itself (every choice drawn
//!   evenly, so the estimate is smooth in θ for fixed random numbers): a scattering graded ball
//!   under a beam (refraction in, curved flights, collisions, reflection inside), an ultrasound
//!   array's drive, phase and frequency under a sinusoidal modulation, Eq. 15's amplitude under
//!   a strobe;
//! - the derivatives against central differences of independent particle-tracing renders (the
//!   expectation's slope, common random numbers per seed pair) for the graded ball's index
//!   parameters and the medium's σ_s;
//! - scenes the derivatives do not cover refused by key.

use crate::common;

use common::render;
use lightpath::config::{Task, load_text};
use lightpath::rrte::{ParticleTracer, RenderScene, SensorKind};

fn scene(text: &str) -> RenderScene {
    match load_text(text) {
        Ok(Task::Render(t)) => t.scene,
        Ok(_) => panic!("not a render"),
        Err(e) => panic!("{e}"),
    }
}

/// A scattering ball (radius 1, `σ_a = 0.2`, HG `g`) graded `n = n0 + c2 r²` in air under a beam,
/// with three targets: a sphere near the top, a box in the middle, and a sphere filling most of
/// the ball.
fn graded_ball(n0: f64, c2: f64, sigma_s: f64, derivatives: &str) -> String {
    format!(
        r#"
[field]
bounds = {{ kind = "sphere", radius = 1.0 }}
n_out = 1.0
[[field.profiles]]
kind = "spherical_polynomial"
n0 = {n0}
coefficients = [0.0, {c2}]
[medium]
sigma_s = {sigma_s}
sigma_a = 0.2
phase = {{ kind = "hg", g = 0.5 }}
[light]
kind = "beam"
center = [0.0, 0.0, -2.0]
direction = [0.0, 0.0, 1.0]
radius = 0.6
[[sensor]]
kind = "target"
name = "spot"
center = [0.0, 0.1, 0.55]
radius = 0.3
[[sensor]]
kind = "target"
name = "core"
center = [0.0, 0.0, 0.0]
size = [0.5, 0.5, 0.5]
[[sensor]]
kind = "target"
name = "shell"
center = [0.0, 0.0, 0.0]
radius = 0.95
[render]
step = 0.01
derivatives = [{derivatives}]
"#
    )
}

/// Every output the tests compare, with the output holding its derivative in parameter `j`
/// (0 without one): each sensor's power, and each screen's pixels (time-integrated); each
/// probe's fluence rate; each camera's total, pixels and windows.
fn outputs(s: &RenderScene, est: &ParticleTracer, j: Option<usize>) -> Vec<(String, usize, usize)> {
    let mut all = Vec::new();
    for (i, sensor) in s.sensors.iter().enumerate() {
        let d = j.map(|j| est.derivative_image(i, j));
        all.push((
            sensor.name.clone(),
            est.power(i),
            d.map_or(0, |d| d.total()),
        ));
        if sensor.kind == SensorKind::Screen {
            let image = est.sensor_image(i);
            for p in 0..sensor.pixel_count() {
                let name = format!("{} pixel {p}", sensor.name);
                all.push((
                    name,
                    image.plane(Some(0), 0) + p,
                    d.map_or(0, |d| d.first + p),
                ));
            }
        }
    }
    for (i, probe) in s.probes.iter().enumerate() {
        all.push((
            probe.name.clone(),
            est.probe_total(i),
            j.map_or(0, |j| est.probe_derivative(i, j)),
        ));
    }
    let cameras = s.cameras.iter().map(|c| (c.name.clone(), c.pixel_count()));
    let pinholes = s.pinholes.iter().map(|c| (c.name.clone(), c.pixel_count()));
    for (i, (name, pixels)) in cameras.chain(pinholes).enumerate() {
        let image = est.images_of_camera(i);
        let d = j.map(|j| est.camera_derivative(i, j));
        all.push((name.clone(), image.total(), d.map_or(0, |d| d.total())));
        for p in 0..pixels {
            all.push((
                format!("{name} pixel {p}"),
                image.plane(Some(0), 0) + p,
                d.map_or(0, |d| d.first + p),
            ));
        }
        for (k, w) in s.camera_windows(i).iter().enumerate() {
            all.push((
                w.name.clone(),
                est.window_total(i, k),
                j.map_or(0, |j| est.window_derivative(i, k, j)),
            ));
        }
    }
    all
}

/// The outputs' values and derivatives in parameter `j` of `samples` photons from `seed`,
/// drawing evenly.
fn evenly(s: &RenderScene, samples: u64, seed: u64, j: usize) -> Vec<(String, f64, f64)> {
    let mut est = ParticleTracer::new(s);
    est.even_draws = true;
    let e = common::estimate(&est, &lightpath::mc::Plan::new(seed, samples, samples / 8));
    outputs(s, &est, Some(j))
        .into_iter()
        .map(|(name, v, d)| (name, e.mean[v].re, e.mean[d].re))
        .collect()
}

/// Derivative `j` of every output equals the central difference quotient (step `h`) of the
/// estimate at the same random numbers, to `1e-5` of its size (the closed forms' central
/// differences inside are good to about 1e-10). Every sensor must have a slope; a pixel the
/// photons miss is left out.
fn is_the_difference_quotient(at: impl Fn(f64) -> RenderScene, theta: f64, h: f64, j: usize) {
    is_the_difference_quotient_within(at, theta, h, j, 1e-5);
}

/// [`is_the_difference_quotient`] to `tolerance` of each derivative's size.
fn is_the_difference_quotient_within(
    at: impl Fn(f64) -> RenderScene,
    theta: f64,
    h: f64,
    j: usize,
    tolerance: f64,
) {
    let here = evenly(&at(theta), 64, 3, j);
    let up = evenly(&at(theta + h), 64, 3, j);
    let down = evenly(&at(theta - h), 64, 3, j);
    let param = at(theta).derivatives[j].name();
    for (((name, _, d), (_, up, _)), (_, down, _)) in here.iter().zip(&up).zip(&down) {
        let fd = (up - down) / (2.0 * h);
        if name.contains(" pixel ") && fd == 0.0 && *d == 0.0 {
            continue;
        }
        assert!(fd != 0.0, "{param}, {name}: no slope to compare");
        assert!(
            (d - fd).abs() < tolerance * fd.abs().max(d.abs()),
            "{param}, {name}: estimate {d:.9e}, difference quotient {fd:.9e}"
        );
    }
}

#[test]
fn derivatives_are_the_estimates_difference_quotients_in_a_scattering_graded_ball() {
    let names = "\"profiles[0].n0\", \"profiles[0].c2\", \"sigma_s\"";
    let (n0, c2) = (1.3, -0.25);
    is_the_difference_quotient(|v| scene(&graded_ball(v, c2, 1.5, names)), n0, 1e-7, 0);
    is_the_difference_quotient(|v| scene(&graded_ball(n0, v, 1.5, names)), c2, 1e-7, 1);
}

/// A spot above the ball: the light crossing `z = 1.4` weighted by a Gaussian aperture of
/// `1/e²` radius 0.3 about the axis (where the graded ball focuses the beam).
const SPOT: &str = "[[sensor]]\nkind = \"spot\"\nname = \"focus\"\ncenter = [0.0, 0.0, 1.4]\nnormal = [0.0, 0.0, 1.0]\nradius = 0.3\n[render]";

/// A screen on the same plane, 0.6 wide in 4 × 4 pixels, sharing each crossing bilinearly.
const SCREEN: &str = "[[sensor]]\nkind = \"screen\"\nname = \"image\"\ncenter = [0.0, 0.0, 1.4]\nnormal = [0.0, 0.0, 1.0]\nsize = [0.6, 0.6]\npixels = [4, 4]\nfilter = \"tent\"\n[render]";

/// `text` with the spot and the screen added.
fn with_planes(text: &str) -> String {
    text.replacen("[render]", SPOT, 1)
        .replacen("[render]", SCREEN, 1)
}

#[test]
fn a_spots_and_screens_derivatives_are_their_estimates_difference_quotients() {
    let names = "\"profiles[0].n0\", \"profiles[0].c2\", \"sigma_s\"";
    let (n0, c2) = (1.3, -0.25);
    let ball = |n0, c2| scene(&with_planes(&graded_ball(n0, c2, 0.5, names)));
    is_the_difference_quotient(|v| ball(v, c2), n0, 1e-7, 0);
    is_the_difference_quotient(|v| ball(n0, v), c2, 1e-7, 1);
}

/// The spot's and the screen's slopes in the grading and the ball's index against the slopes
/// of the expectation: no edge is missed (light leaving sideways crosses the plane far out,
/// where the aperture's weight has fallen to nothing; a pixel's share falls to 0 at its tent's
/// edge). The steps are small: at `c2` − 0.05 the focused beam's edge sweeps into the outer
/// pixels, and a difference over that step is not the slope at `c2`.
#[test]
fn spots_and_screens_differentiate_as_their_differences() {
    let (n0, c2, sigma_s) = (1.3, -0.25, 0.5);
    let names = "\"profiles[0].n0\", \"profiles[0].c2\"";
    let with = |d: bool| if d { names } else { "" };
    let ball = |n0, c2, d| scene(&with_planes(&graded_ball(n0, c2, sigma_s, with(d))));
    let sizes = (100_000, 16, 20_000);
    agrees_with_differences(|v, d| ball(n0, v, d), c2, 0.01, 1, sizes);
    agrees_with_differences(|v, d| ball(v, c2, d), n0, 0.01, 0, sizes);
}

/// Two fluence probes inside the ball: one above the centre where the grading gathers the beam,
/// one off to the side near the entry.
const PROBES: &str = "[[sensor]]\nkind = \"fluence\"\nname = \"deep\"\nposition = [0.0, 0.1, 0.4]\n[[sensor]]\nkind = \"fluence\"\nname = \"side\"\nposition = [0.5, 0.0, -0.2]\n[render]";

/// `text` with the probes added.
fn with_probes(text: &str) -> String {
    text.replacen("[render]", PROBES, 1)
}

/// A probe's connections move with the field (the boundary-value problem's implicit dependence
/// on `n`) and with the scattering events (the photons' sensitivities): their derivatives equal
/// the estimate's difference quotients, with and without reflections inside the surface joining
/// the events to the probes. A reflected connection's value is smooth only to about 1e-12 of
/// itself (the reflection's sensitivities are central differences of the mirror, whose round-off
/// varies with θ), so its difference quotient is taken over a larger step.
#[test]
fn a_probes_derivatives_are_its_estimates_difference_quotients() {
    let names = "\"profiles[0].n0\", \"profiles[0].c2\", \"sigma_s\"";
    let (n0, c2) = (1.3, -0.25);
    for (reflections, h) in [("", 1e-7), ("reflections = 1\n", 1e-5)] {
        let ball = |n0, c2| {
            let text = with_probes(&graded_ball(n0, c2, 1.5, names));
            scene(&text.replacen("[render]\n", &format!("[render]\n{reflections}"), 1))
        };
        is_the_difference_quotient(|v| ball(v, c2), n0, h, 0);
        is_the_difference_quotient(|v| ball(n0, v), c2, h, 1);
    }
}

/// The probes' slopes in the grading and in the medium's σ_s and `g` (which particle tracing
/// estimates without following the field when no field parameter is asked for) against the slopes
/// of the expectation. One path joins an event to a probe in this ball, so Newton's first is
/// taken (`connections = "first"`).
#[test]
fn probes_differentiate_as_their_differences() {
    let (n0, c2, sigma_s, g) = (1.3, -0.25, 1.5, 0.5);
    let ball = |c2, sigma_s, g: f64, names: &str| {
        let text = with_probes(&graded_ball(n0, c2, sigma_s, names))
            .replace("g = 0.5", &format!("g = {g}"))
            .replacen("[render]\n", "[render]\nconnections = \"first\"\n", 1);
        scene(&text)
    };
    let sizes = (24_000, 6, 6_000);
    let names = |d: bool, names: &'static str| if d { names } else { "" };
    let field = "\"profiles[0].c2\"";
    agrees_with_differences(
        |v, d| ball(v, sigma_s, g, names(d, field)),
        c2,
        0.05,
        0,
        sizes,
    );
    let medium = "\"sigma_s\", \"g\"";
    agrees_with_differences(
        |v, d| ball(c2, v, g, names(d, medium)),
        sigma_s,
        0.1,
        0,
        sizes,
    );
    agrees_with_differences(
        |v, d| ball(c2, sigma_s, v, names(d, medium)),
        g,
        0.05,
        1,
        sizes,
    );
}

/// A pinhole camera above the ball looking down at it, and an orthographic camera recording the
/// light leaving upwards, both 4 × 4 pixels sharing what arrives bilinearly, each with a window
/// of a few pixels.
const CAMERAS: &str = "[[sensor]]\nkind = \"pinhole\"\nname = \"eye\"\nposition = [0.3, 0.2, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov_deg = 40.0\npixels = [4, 4]\nfilter = \"tent\"\n[[sensor.window]]\nname = \"eye_window\"\ncolumns = [1, 2]\nrows = [0, 1]\n[[sensor]]\nkind = \"camera\"\nname = \"above\"\ncenter = [0.0, 0.0, 2.0]\ndirection = [0.0, 0.0, 1.0]\nsize = [1.6, 1.6]\npixels = [4, 4]\nfilter = \"tent\"\n[[sensor.window]]\nname = \"above_window\"\ncolumns = [0, 1]\nrows = [1, 3]\n[render]";

/// `text` with the cameras added.
fn with_cameras(text: &str) -> String {
    text.replacen("[render]", CAMERAS, 1)
}

/// A camera's connections leave the volume, refracted at its surface, and land in pixels whose
/// tent shares move with them: every pixel's and each camera total's derivatives equal the
/// estimate's difference quotients, to 1e-3. A connection leaving the volume ends with the
/// leapfrog's step to the surface, and where the number of whole steps before it changes, its
/// value has a kink of the integrator's size (1e-4 of it); a quotient over ±h that straddles one
/// is off by up to that, and the step must be 1e-5 (the refraction's sensitivities, central
/// differences of Snell's law, leave the value smooth only to about 1e-12 of itself). Dropping
/// the connections' own derivatives or their scores misses by far more.
#[test]
fn a_cameras_derivatives_are_its_estimates_difference_quotients() {
    let names = "\"profiles[0].n0\", \"profiles[0].c2\", \"sigma_s\"";
    let (n0, c2) = (1.3, -0.25);
    let ball = |n0, c2| scene(&with_cameras(&graded_ball(n0, c2, 1.5, names)));
    is_the_difference_quotient_within(|v| ball(v, c2), n0, 1e-5, 0, 1e-3);
    is_the_difference_quotient_within(|v| ball(n0, v), c2, 1e-5, 1, 1e-3);
}

/// The cameras' slopes in the grading and in σ_s against the slopes of the expectation. (Newton's
/// first path alone, `connections = "first"`, would be biased here in the derivative: which of
/// several paths leaving along the camera's direction Newton reaches first changes with the
/// field.)
#[test]
fn cameras_differentiate_as_their_differences() {
    let (n0, c2, sigma_s) = (1.3, -0.25, 1.5);
    let ball =
        |c2, sigma_s, names: &str| scene(&with_cameras(&graded_ball(n0, c2, sigma_s, names)));
    let sizes = (12_000, 6, 3_000);
    let names = |d: bool, names: &'static str| if d { names } else { "" };
    let field = "\"profiles[0].c2\"";
    agrees_with_differences(|v, d| ball(v, sigma_s, names(d, field)), c2, 0.05, 0, sizes);
    let medium = "\"sigma_s\"";
    agrees_with_differences(|v, d| ball(c2, v, names(d, medium)), sigma_s, 0.1, 0, sizes);
}

/// Four line elements about a scattering water cylinder (lengths in mm), the field met at a
/// random instant per photon; a target and a fluence probe at depth.
fn phased_array(amplitude: f64, phase_deg: f64, frequency: f64) -> String {
    placed_array(amplitude, phase_deg, frequency, 4.0)
}

/// [`phased_array`] with its first element at `x0` on the x axis, differentiated by its
/// placement too.
fn placed_array(amplitude: f64, phase_deg: f64, frequency: f64, x0: f64) -> String {
    format!(
        r#"
[field]
bounds = {{ kind = "cylinder", radius = 2.0, half_length = 4.0 }}
n_out = 1.33
[[field.profiles]]
kind = "phased_array"
n0 = 1.33
frequency = {frequency}
sound_speed = 1480.0
length_unit = "mm"
density = 1000.0
reference_distance = 4.0
elements = [
  {{ position = [{x0:?}, 0.0], amplitude = {amplitude}, phase_deg = 180.0 }},
  {{ position = [0.0, 4.0], amplitude = 2e6, phase_deg = {phase_deg} }},
  {{ position = [-4.0, 0.0], amplitude = 2e6, phase_deg = 180.0 }},
  {{ position = [0.0, -4.0], amplitude = 2e6, phase_deg = 0.0 }},
]
[modulation]
kind = "sinusoidal"
[medium]
sigma_s = 0.2
sigma_a = 0.01
phase = {{ kind = "hg", g = 0.85 }}
[light]
kind = "beam"
center = [0.0, 0.0, -5.0]
direction = [0.0, 0.0, 1.0]
radius = 1.0
[[sensor]]
kind = "target"
name = "deep"
center = [0.3, 0.0, 3.0]
radius = 0.5
[[sensor]]
kind = "fluence"
name = "axis"
position = [0.2, 0.1, 2.0]
[render]
step = 0.02
derivatives = ["profiles[0].amplitude_0", "profiles[0].phase_1", "profiles[0].frequency", "profiles[0].x_0"]
"#
    )
}

#[test]
fn an_ultrasound_arrays_drive_phase_frequency_and_placement_differentiate_exactly() {
    let (a, phase, f) = (2e6, 0.0, 813e3);
    is_the_difference_quotient(|v| scene(&phased_array(v, phase, f)), a, 1.0, 0);
    // the phase in degrees in the config, its derivative per radian
    let per_degree = |v: f64| {
        let mut s = scene(&phased_array(a, v.to_degrees(), f));
        s.derivatives.truncate(2);
        s
    };
    is_the_difference_quotient(per_degree, phase, 1e-6, 1);
    is_the_difference_quotient(|v| scene(&phased_array(a, phase, v)), f, 1e-2, 2);
    // the transducer's placement
    is_the_difference_quotient(|v| scene(&placed_array(a, phase, f, v)), 4.0, 1e-6, 3);
}

/// Eq. 15's standing wave frozen by a strobe at 60°: the field holds `n_max sin 60°`, and the
/// derivative is with respect to the amplitude `n_max` itself.
#[test]
fn a_strobed_ultrasonic_amplitude_differentiates_exactly() {
    let text = |n_max: f64| {
        format!(
            r#"
[field]
bounds = {{ kind = "cylinder", radius = 1.0, half_length = 2.0 }}
n_out = 1.33
[[field.profiles]]
kind = "ultrasonic"
n0 = 1.33
n_max = {n_max}
k_r = 3.0
m = 0
[modulation]
kind = "strobed"
phase_deg = 60.0
[medium]
sigma_s = 0.5
sigma_a = 0.05
phase = {{ kind = "hg", g = 0.8 }}
[light]
kind = "beam"
center = [0.0, 0.0, -3.0]
direction = [0.0, 0.0, 1.0]
radius = 0.8
[[sensor]]
kind = "target"
name = "axis"
center = [0.0, 0.0, 1.5]
radius = 0.3
[render]
step = 0.01
derivatives = ["profiles[0].n_max"]
"#
        )
    };
    is_the_difference_quotient(|v| scene(&text(v)), 0.02, 1e-7, 0);
}

/// Point light at the centre of a clear absorbing ball (`σ_a = 0.5`, `n` = 1 inside and out):
/// the fluence is `e^{−σ_a r}/(4π r²)`, and a target's mean over a sphere of radius `a` about
/// `c` is `(1/V) ∫ e^{−σ_a r} (1 − cos θ_r)/2 dr` over the shells it cuts (`cos θ_r =
/// (r² + |c|² − a²)/(2 r |c|)`), and over a box the mean of the same by quadrature; a spot on
/// a plane above collects the escaping light by its aperture's weight where it crosses, and a
/// tent-filtered screen there each pixel's tent-weighted share of the irradiance.
#[test]
fn a_target_in_an_absorber_reads_the_point_source_closed_form() {
    let text = |derivatives: &str| {
        format!(
            r#"
[field]
bounds = {{ kind = "sphere", radius = 1.0 }}
n_out = 1.0
[[field.profiles]]
kind = "constant"
n = 1.0
[medium]
sigma_s = 1e-9
sigma_a = 0.5
[light]
kind = "point"
position = [0.0, 0.0, 0.0]
[[sensor]]
kind = "target"
name = "ball"
center = [0.5, 0.0, 0.0]
radius = 0.1
[[sensor]]
kind = "target"
name = "box"
center = [0.0, 0.4, 0.2]
size = [0.2, 0.3, 0.2]
[[sensor]]
kind = "spot"
name = "above"
center = [0.0, 0.0, 1.5]
normal = [0.0, 0.0, 1.0]
radius = 0.5
[[sensor]]
kind = "screen"
name = "tent"
center = [0.2, 0.1, 1.5]
normal = [0.0, 0.0, 1.0]
size = [0.6, 0.4]
pixels = [3, 2]
filter = "tent"
[render]
derivatives = [{derivatives}]
"#
        )
    };
    let sigma_a = 0.5;
    let fluence = |r: f64| (-sigma_a * r).exp() / (4.0 * std::f64::consts::PI * r * r);
    // the ball: over the shells it cuts
    let (c, a) = (0.5, 0.1);
    let n = 20_000;
    let mut ball = 0.0;
    for k in 0..n {
        let r = c - a + 2.0 * a * (k as f64 + 0.5) / n as f64;
        let cos = ((r * r + c * c - a * a) / (2.0 * r * c)).clamp(-1.0, 1.0);
        ball += (-sigma_a * r).exp() * (1.0 - cos) / 2.0 * (2.0 * a / n as f64);
    }
    ball /= 4.0 / 3.0 * std::f64::consts::PI * a.powi(3);
    // the box: the midpoint rule on 60³ cells
    let (m, size, centre) = (60, [0.2, 0.3, 0.2], [0.0, 0.4, 0.2]);
    let mut cube = 0.0;
    for i in 0..m {
        for j in 0..m {
            for k in 0..m {
                let p = [i, j, k].map(|q| (q as f64 + 0.5) / m as f64 - 0.5);
                let x = glam::DVec3::new(
                    centre[0] + p[0] * size[0],
                    centre[1] + p[1] * size[1],
                    centre[2] + p[2] * size[2],
                );
                cube += fluence(x.length());
            }
        }
    }
    cube /= (m * m * m) as f64;
    // the spot: light leaving along μ = cos θ crosses the plane at ρ = h tan θ, having lost
    // e^{−σ_a} on its way out; (1/2) ∫ e^{−2ρ²/w²} dμ over the upper half by the midpoint rule
    let (h, w) = (1.5, 0.5);
    let mut spot = 0.0;
    for k in 0..n {
        let mu = (k as f64 + 0.5) / n as f64;
        spot += (-2.0 * h * h * (1.0 / (mu * mu) - 1.0) / (w * w)).exp() / (2.0 * n as f64);
    }
    spot *= (-sigma_a).exp();
    // the tent-filtered screen: each pixel's share of the irradiance e^{−σ_a} h/(4π r³), its
    // tent (one pixel wide each way from its centre) by the midpoint rule
    let (pixel, pixels, corner) = (0.2, [3, 2], [-0.1, -0.1]);
    let irradiance = |x: f64, y: f64| {
        let r = (x * x + y * y + h * h).sqrt();
        (-sigma_a).exp() * h / (4.0 * std::f64::consts::PI * r.powi(3))
    };
    let steps = 200;
    let tent: Vec<f64> = (0..pixels[0] * pixels[1])
        .map(|k| {
            let centre = [
                corner[0] + (k % pixels[0]) as f64 * pixel + 0.5 * pixel,
                corner[1] + (k / pixels[0]) as f64 * pixel + 0.5 * pixel,
            ];
            let mut sum = 0.0;
            for a in 0..steps {
                for b in 0..steps {
                    let u = -1.0 + 2.0 * (a as f64 + 0.5) / steps as f64;
                    let v = -1.0 + 2.0 * (b as f64 + 0.5) / steps as f64;
                    let share = (1.0 - u.abs()) * (1.0 - v.abs());
                    let (x, y) = (centre[0] + u * pixel, centre[1] + v * pixel);
                    sum += irradiance(x, y) * share;
                }
            }
            sum * (2.0 * pixel / steps as f64).powi(2)
        })
        .collect();
    for derivatives in ["", "\"profiles[0].n\""] {
        let s = scene(&text(derivatives));
        let (e, est) = render(&s, 1_000_000, 5);
        let first = est.sensor_image(3).plane(Some(0), 0);
        let outputs = [ball, cube, spot]
            .into_iter()
            .enumerate()
            .map(|(i, v)| (est.power(i), v, 0.02));
        // a pixel receives about a thousandth of the photons
        let pixels = tent.iter().enumerate().map(|(k, &v)| (first + k, v, 0.05));
        for (o, exact, resolution) in outputs.chain(pixels) {
            let (v, se) = (e.mean[o].re, e.stderr[o]);
            assert!(se < resolution * exact, "{derivatives}: {se} for {exact}");
            assert!(
                (v - exact).abs() < 4.0 * se,
                "output {o} {derivatives}: {v} ± {se} against {exact}"
            );
        }
    }
}

/// Every output's derivative `j` against central differences over `pairs` seed pairs (each
/// pair renders θ ± h by particle tracing from one seed, so the difference has little noise),
/// within 4 combined standard errors; one output's derivative at least must be resolved
/// (beyond 4 of its errors) so that the check can fail.
fn agrees_with_differences(
    at: impl Fn(f64, bool) -> RenderScene,
    theta: f64,
    h: f64,
    j: usize,
    (samples, pairs, photons): (u64, u64, u64),
) {
    let s = at(theta, true);
    let (e, est) = render(&s, samples, 7);
    let compared = outputs(&s, &est, Some(j));
    let mut fd = vec![Vec::new(); compared.len()];
    for k in 0..pairs {
        let values = |v: f64| {
            let sc = at(v, false);
            let (e, est) = render(&sc, photons, 1000 + k);
            outputs(&sc, &est, None)
                .into_iter()
                .map(|(_, o, _)| e.mean[o].re)
                .collect::<Vec<_>>()
        };
        let (up, down) = (values(theta + h), values(theta - h));
        for i in 0..compared.len() {
            fd[i].push((up[i] - down[i]) / (2.0 * h));
        }
    }
    let param = s.derivatives[j].name();
    let mut resolved = false;
    for (fd, (name, _, o)) in fd.iter().zip(&compared) {
        let (d, sd) = (e.mean[*o].re, e.stderr[*o]);
        let n = fd.len() as f64;
        let mean = fd.iter().sum::<f64>() / n;
        let sf = (fd.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        resolved |= d.abs() > 4.0 * sd;
        eprintln!(
            "{param} of {name}: estimate {d:.4e} ± {sd:.1e}, differences {mean:.4e} ± {sf:.1e}"
        );
        assert!(
            (d - mean).abs() < 4.0 * (sd * sd + sf * sf).sqrt(),
            "{param} of {name}: estimate {d:.4e} ± {sd:.1e}, differences {mean:.4e} ± {sf:.1e}"
        );
    }
    assert!(resolved, "{param}: no output's derivative is resolved");
}

/// The graded ball's targets: their slopes in the profile's `c2` (the bending inside) and `n0`
/// (the surface's index too), and in σ_s alongside, against the slopes of the expectation.
#[test]
fn a_graded_balls_targets_differentiate_as_their_differences() {
    let (n0, c2, sigma_s) = (1.3, -0.25, 1.5);
    let names = "\"profiles[0].n0\", \"profiles[0].c2\", \"sigma_s\"";
    let with = |d: bool| if d { names } else { "" };
    let sizes = (100_000, 12, 20_000);
    agrees_with_differences(
        |v, d| scene(&graded_ball(n0, v, sigma_s, with(d))),
        c2,
        0.05,
        1,
        sizes,
    );
    agrees_with_differences(
        |v, d| scene(&graded_ball(v, c2, sigma_s, with(d))),
        n0,
        0.03,
        0,
        sizes,
    );
    agrees_with_differences(
        |v, d| scene(&graded_ball(n0, c2, v, with(d))),
        sigma_s,
        0.1,
        2,
        sizes,
    );
}

fn refused(text: &str, needles: &[&str]) {
    let Err(e) = load_text(text) else {
        panic!("not refused")
    };
    let e = e.to_string();
    for n in needles {
        assert!(e.contains(n), "{n:?} not in: {e}");
    }
}

#[test]
fn scenes_the_field_derivatives_do_not_cover_are_refused_by_key() {
    let base = graded_ball(1.3, -0.25, 1.5, "\"profiles[0].c2\"");
    let flux = "[[sensor]]\nkind = \"flux\"\nname = \"T\"\ncenter = [0.0, 0.0, 1.0]\nnormal = [0.0, 0.0, 1.0]\n[render]";
    refused(
        &base.replacen("[render]", flux, 1),
        &[
            "render.derivatives[0] = \"profiles[0].c2\"",
            "\"T\"",
            "target",
        ],
    );
    let timed = SPOT.replace(
        "[render]",
        "[transient]\nbins = 4\nmax_path = 10.0\n[render]",
    );
    refused(
        &base.replacen("[render]", &timed, 1),
        &["[transient]", "\"focus\""],
    );
    refused(
        &base.replacen("[render]", &SPOT.replace("radius = 0.3", "radius = 0.0"), 1),
        &["sensor[3].radius = 0"],
    );
    refused(
        &base.replacen("[render]", &SCREEN.replace("filter = \"tent\"\n", ""), 1),
        &["sensor \"image\"", "filter = \"tent\""],
    );
    let probe =
        "[[sensor]]\nkind = \"fluence\"\nname = \"p\"\nposition = [0.0, 0.0, 0.0]\n[render]";
    assert!(load_text(&base.replacen("[render]", probe, 1)).is_ok());
    let timed = probe.replace(
        "[render]",
        "[transient]\nbins = 4\nmax_path = 10.0\n[render]",
    );
    refused(
        &base.replacen("[render]", &timed, 1),
        &["[transient]", "fluence probe \"p\""],
    );
    let pinhole = "[[sensor]]\nkind = \"pinhole\"\nname = \"eye\"\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov_deg = 40.0\npixels = [4, 4]\n[render]";
    let tent = pinhole.replace("[render]", "filter = \"tent\"\n[render]");
    assert!(load_text(&base.replacen("[render]", &tent, 1)).is_ok());
    // first among the sensors, so that it is the one refused
    let first = tent.replace("[render]", "[[sensor]]");
    refused(
        &graded_ball(1.3, -0.25, 1.5, "")
            .replacen("[[sensor]]", &first, 1)
            .replacen("[render]", "[render]\nestimator = \"bidirectional\"", 1),
        &["sensor[0].filter = \"tent\"", "particle"],
    );
    refused(
        &base.replacen("[render]", pinhole, 1),
        &["sensor[3] (kind = \"pinhole\")", "filter = \"tent\""],
    );
    let floor = "[[surface]]\nname = \"floor\"\ncenter = [0.0, -1.5, 0.0]\nnormal = [0.0, 1.0, 0.0]\nalbedo = 0.5\n[render]";
    refused(&base.replacen("[render]", floor, 1), &["[[surface]]"]);
    refused(
        &graded_ball(1.3, -0.25, 1.5, "\"profiles[1].c2\""),
        &["profiles[1].c2", "1 profile(s)"],
    );
    refused(
        &graded_ball(1.3, -0.25, 1.5, "\"profiles[0].radius\""),
        &["spherical_polynomial", "\"radius\""],
    );
    refused(
        &graded_ball(1.3, -0.25, 1.5, "\"profiles[0].c2\", \"profiles[0].c2\""),
        &["render.derivatives[1]", "already listed"],
    );
    refused(
        &graded_ball(1.3, -0.25, 1.5, "").replacen(
            "[render]",
            "[render]\nestimator = \"bidirectional\"",
            1,
        ),
        &["sensor[0].kind = \"target\"", "particle"],
    );
    refused(
        &base.replace("center = [0.0, 0.1, 0.55]", "center = [0.0, 0.1, 1.55]"),
        &["sensor[0].center", "inside the volume"],
    );
    refused(
        &base.replace("radius = 0.3", "radius = 0.3\nsize = [1.0, 1.0, 1.0]"),
        &["sensor[0]", "exactly one"],
    );
}

/// The render as a burn operation in an index-field parameter: burn's Adam raises the light the
/// graded ball delivers to its upper target by its grading `c2` (within [−0.3, 0.3]), from the
/// uniform ball a user would start with, with fresh photons every step; independent renders at a
/// fresh seed with ten times the photons confirm the gain (the grading ends at its bound here:
/// the more it bends light up, the more reaches the target).
#[test]
fn adam_designs_the_grading_that_delivers_more_light() {
    use burn::module::{Module, Param as BurnParam};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Tensor;
    use lightpath::diff::RenderOp;
    use lightpath::diff::bridge::{apply, device, tensor, values};

    let ball = |c2: f64| scene(&graded_ball(1.3, c2, 1.5, "\"profiles[0].c2\""));
    let op = RenderOp::from_scene(ball(0.0), (10_000, 1_000, 40)).unwrap();
    assert_eq!(op.values(), vec![0.0]);
    #[derive(Module, Debug)]
    struct Design {
        c2: BurnParam<Tensor<1>>,
    }
    let dev = device();
    let mut d = Design {
        c2: BurnParam::from_tensor(tensor(&[0.0], &dev)),
    };
    let mut adam = AdamConfig::new().init();
    for _ in 0..15 {
        let fluence = apply(&op, d.c2.val()).unwrap();
        // the spot's fluence (the first target), maximised through its logarithm
        let loss = -fluence.narrow(0, 0, 1).log().sum();
        let grads = GradientsParams::from_grads(loss.backward(), &d);
        d = adam.step(0.03, d, grads);
        let c2 = values(&d.c2.val())[0].clamp(-0.3, 0.3);
        d.c2 = BurnParam::from_tensor(tensor(&[c2], &dev));
    }
    let designed = values(&d.c2.val())[0];
    let spot = |c2: f64| {
        let s = ball(c2);
        let (e, est) = render(&s, 100_000, 777);
        (e.mean[est.power(0)].re, e.stderr[est.power(0)])
    };
    let ((before, sb), (after, sa)) = (spot(0.0), spot(designed));
    eprintln!("c2 {designed:.4}: spot fluence {before:.4} ± {sb:.4} → {after:.4} ± {sa:.4}");
    assert!(after - before > 4.0 * sb.hypot(sa), "{before} → {after}");
}

/// Held photons (`RenderOp::hold`): every evaluation draws the same random numbers and every
/// scored choice evenly (total internal reflection included), each photon from its own stream,
/// scattered in frames that turn continuously with it, so the estimate is a deterministic
/// function of the index field whose Jacobian is its exact derivative (what L-BFGS needs): the
/// same bits twice, and the derivatives equal the difference quotients of 4 000 photons (with
/// reflections, total internal reflection and roulette among them) at the grading and index a
/// design starts from and away from it, to 1e-4 (the numerical slopes of the Fresnel terms and
/// the scattering direction, summed over 4 000 photons).
#[test]
fn held_photons_give_a_deterministic_objective_with_its_exact_gradient() {
    use lightpath::diff::RenderOp;
    let names = "\"profiles[0].n0\", \"profiles[0].c2\"";
    let ball = with_probes(&graded_ball(1.3, 0.0, 1.5, names));
    let mut op = RenderOp::from_scene(scene(&ball), (4_000, 500, 9)).unwrap();
    op.hold().unwrap();
    assert_eq!(op.values(), vec![1.3, 0.0]);
    let a = op.evaluate(&[1.3, 0.05]).unwrap();
    // the three targets, then the two probes
    assert_eq!(a.power.len(), 5);
    let b = op.evaluate(&[1.3, 0.05]).unwrap();
    assert_eq!(a.power, b.power, "held evaluations differ");
    assert_eq!(a.jacobian, b.jacobian);
    for theta in [[1.3, 0.05], [1.45, -0.2]] {
        let d = op.evaluate(&theta).unwrap();
        for j in 0..2 {
            let h = 1e-7;
            let at = |s: f64| {
                let mut t = theta;
                t[j] += s * h;
                op.evaluate(&t).unwrap().power
            };
            let (up, down) = (at(1.0), at(-1.0));
            for i in 0..up.len() {
                let fd = (up[i] - down[i]) / (2.0 * h);
                assert!(
                    (d.jacobian[i][j] - fd).abs() < 1e-4 * fd.abs().max(d.jacobian[i][j].abs()),
                    "θ = {theta:?}, parameter {j}, output {i}: derivative {:.9e}, difference quotient {fd:.9e}",
                    d.jacobian[i][j]
                );
            }
        }
    }
}

/// With nothing scattered or absorbed and the surface index-matched (`n_out` = the ball's index
/// at its surface, so no light is reflected), the spot's power, the screen's pixels and their
/// derivatives in the ball's `n0` and `c2` equal the deterministic exit adjoint's: the beam's
/// disc by the midpoint rule (equal-area rings), each ray traced to its exit and on to the
/// plane, the gradient of its weight (the aperture's, a pixel's share) pulled back through the
/// crossing (`x̄ = ḡ − N (ḡ·d)/(N·d)`, `d̄ = t x̄`) and the trace.
#[test]
fn a_clear_spots_and_screens_derivatives_are_the_exit_adjoints() {
    use glam::DVec3;
    use lightpath::diff::ExitVjp;
    use lightpath::rrte::scene::Derivative;
    let (n0, c2) = (1.3, -0.25);
    let text = graded_ball(n0, c2, 1e-9, "\"profiles[0].n0\", \"profiles[0].c2\"")
        .replace("n_out = 1.0", &format!("n_out = {}", n0 + c2))
        .replace("sigma_a = 0.2", "sigma_a = 0.0");
    // the screen beyond the focus, off the axis, where the beam has spread over its pixels
    let screen = SCREEN
        .replace("[0.0, 0.0, 1.4]", "[0.07, 0.03, 2.5]")
        .replace("[0.6, 0.6]", "[0.8, 0.8]");
    let text = text
        .replacen("[render]", SPOT, 1)
        .replacen("[render]", &screen, 1);
    let s = scene(&text);
    let (e, est) = render(&s, 400_000, 11);
    // the beam: radius 0.6 about the axis from z = −2
    let (radius, rings, spokes) = (0.6, 200, 96);
    let mut rays = Vec::new();
    for i in 0..rings {
        let r = radius * ((i as f64 + 0.5) / rings as f64).sqrt();
        for j in 0..spokes {
            let phi = std::f64::consts::TAU * (j as f64 + 0.5) / spokes as f64;
            rays.push((DVec3::new(r * phi.cos(), r * phi.sin(), -2.0), DVec3::Z));
        }
    }
    let params = s
        .derivatives
        .iter()
        .map(|d| match d {
            Derivative::Field(f) => f.param,
            Derivative::Medium(_) => unreachable!(),
        })
        .collect();
    let watch = lightpath::mc::Watch::default();
    let field = s.volume.field.clone();
    let vjp = ExitVjp::new(field, params, None, rays, s.step, s.max_steps, &watch).unwrap();
    let share = 1.0 / vjp.ends.len() as f64;
    // an output's value and derivatives from the weight (and its gradient on the plane) each
    // crossing gets
    let by_adjoint = |plane: &lightpath::rrte::Sensor, weight: &dyn Fn(DVec3) -> (f64, DVec3)| {
        let (mut value, mut d_position, mut d_direction) = (0.0, Vec::new(), Vec::new());
        for end in &vjp.ends {
            let (x, d) = (end.x, end.direction);
            let cos = d.dot(plane.normal);
            let (mut xb, mut db) = (DVec3::ZERO, DVec3::ZERO);
            if cos > 0.0 {
                let t = (plane.center - x).dot(plane.normal) / cos;
                let (g, grad) = weight(x + d * t);
                value += g * share;
                xb = (grad - plane.normal * (grad.dot(d) / cos)) * share;
                db = xb * t;
            }
            d_position.push(xb);
            d_direction.push(db);
        }
        let grads = vjp.pullback(&d_position, &d_direction, &watch).unwrap();
        (value, grads.params)
    };
    let (spot, screen) = (&s.sensors[3], &s.sensors[4]);
    let mut compared = vec![(
        "spot".to_string(),
        est.power(3),
        (0..2)
            .map(|j| est.power_derivative(3, j))
            .collect::<Vec<_>>(),
        by_adjoint(spot, &|p| (spot.aperture(p), spot.aperture_gradient(p))),
    )];
    for pixel in 0..screen.pixel_count() {
        let exact = by_adjoint(screen, &|p| {
            let (splat, count) = screen.splat(p);
            splat[..count]
                .iter()
                .find(|&&(k, _, _)| k == pixel)
                .map_or((0.0, DVec3::ZERO), |&(_, w, g)| (w, g))
        });
        let value = est.sensor_image(4).plane(Some(0), 0) + pixel;
        let slopes = (0..2)
            .map(|j| est.derivative_image(4, j).first + pixel)
            .collect();
        compared.push((format!("pixel {pixel}"), value, slopes, exact));
    }
    let mut resolved = 0;
    for (name, value, slopes, (exact, grads)) in compared {
        let (v, se) = (e.mean[value].re, e.stderr[value]);
        // (a photon of the 1e-9 scattering lands anywhere)
        assert!(
            (v - exact).abs() < 4.0 * se + 1e-8,
            "{name}: {v} ± {se}, exit adjoint {exact}"
        );
        for (j, (&o, exact)) in slopes.iter().zip(grads).enumerate() {
            let (d, sd) = (e.mean[o].re, e.stderr[o]);
            let param = s.derivatives[j].name();
            resolved += usize::from(sd < 0.05 * exact.abs());
            assert!(
                (d - exact).abs() < 4.0 * sd + 1e-8,
                "{name}, {param}: render {d:.5e} ± {sd:.1e}, exit adjoint {exact:.5e}"
            );
        }
    }
    // the spot's and most pixels' (a few pixels' slopes are near 0)
    assert!(
        resolved >= 24,
        "only {resolved} derivatives resolved to 5 %"
    );
}

/// The graded ball of [`graded_ball`] (`n = n0 + c2 r²`, scattering) under the beam, and above it
/// a scattering glass ball of constant index `n_glass` (radius 0.5 at `z = 1.8`) that the light
/// leaving the first enters (and may come back from), as two `[[volume]]`s; a target in each, a
/// spot and a tent-filtered screen above both (at `z = 2.6`).
fn two_balls(n0: f64, c2: f64, n_glass: f64, derivatives: &str) -> String {
    format!(
        r#"
[field]
n_out = 1.0
[[volume]]
center = [0.0, 0.0, 0.0]
bounds = {{ kind = "sphere", radius = 1.0 }}
profiles = [{{ kind = "spherical_polynomial", n0 = {n0}, coefficients = [0.0, {c2}] }}]
medium = {{ sigma_s = 1.5, sigma_a = 0.2, phase = {{ kind = "hg", g = 0.5 }} }}
[[volume]]
center = [0.0, 0.0, 1.8]
bounds = {{ kind = "sphere", radius = 0.5 }}
profiles = [{{ kind = "constant", n = {n_glass} }}]
medium = {{ sigma_s = 1.0, sigma_a = 0.1, phase = {{ kind = "hg", g = 0.3 }} }}
[light]
kind = "beam"
center = [0.0, 0.0, -2.0]
direction = [0.0, 0.0, 1.0]
radius = 0.6
[[sensor]]
kind = "target"
name = "graded"
center = [0.0, 0.1, 0.55]
radius = 0.3
[[sensor]]
kind = "target"
name = "glass"
center = [0.0, 0.0, 1.8]
radius = 0.35
[[sensor]]
kind = "spot"
name = "focus"
center = [0.0, 0.0, 2.6]
normal = [0.0, 0.0, 1.0]
radius = 0.3
[[sensor]]
kind = "screen"
name = "image"
center = [0.0, 0.0, 2.6]
normal = [0.0, 0.0, 1.0]
size = [0.8, 0.8]
pixels = [4, 4]
filter = "tent"
[render]
step = 0.01
derivatives = [{derivatives}]
"#
    )
}

/// A fluence probe in each of the two balls.
const PROBES_IN_BOTH: &str = "[[sensor]]\nkind = \"fluence\"\nname = \"deep\"\nposition = [0.0, 0.1, 0.4]\n[[sensor]]\nkind = \"fluence\"\nname = \"high\"\nposition = [0.1, 0.0, 1.85]\n[render]";

/// In two volumes the photons leave one and enter the other (refracted in where the entry point
/// moves along the leg, reflected off it, or back): each output's derivative by either volume's
/// index field equals the estimate's difference quotient, the probes' included (a probe in the
/// other ball is reached by paths between the two volumes, solved again in the shifted fields).
/// Such a path leaves the graded ball by the leapfrog's step to the surface, and its value is
/// smooth only to round-off (some 1e-11 of it, as a reflected connection's): the quotient is
/// taken over `h` = 1e-5.
#[test]
fn derivatives_by_either_of_two_volumes_fields_are_the_estimates_difference_quotients() {
    let names = "\"volume[0].profiles[0].n0\", \"volume[0].profiles[0].c2\", \"volume[1].profiles[0].n\", \"volume[1].sigma_s\"";
    let (n0, c2, n_glass) = (1.3, -0.25, 1.5);
    let balls = |n0, c2, n_glass| {
        let text = two_balls(n0, c2, n_glass, names).replacen("[render]", PROBES_IN_BOTH, 1);
        scene(&text)
    };
    is_the_difference_quotient(|v| balls(v, c2, n_glass), n0, 1e-5, 0);
    is_the_difference_quotient(|v| balls(n0, v, n_glass), c2, 1e-5, 1);
    is_the_difference_quotient(|v| balls(n0, c2, v), n_glass, 1e-5, 2);
}

/// The cameras of [`CAMERAS`] over the two balls (the orthographic one's image plane raised
/// above the upper ball): connections from events in either ball leave it and cross the other
/// on their way to the camera (refracted in and out), and land in pixels whose tent shares move
/// with them; to 1e-3 over `h` = 1e-5 as for one ball (the stepped connection's kinks at the
/// integrator's size).
#[test]
fn cameras_over_two_volumes_differentiate_as_their_estimates_difference_quotients() {
    let names = "\"volume[0].profiles[0].c2\", \"volume[1].profiles[0].n\"";
    let (n0, c2, n_glass) = (1.3, -0.25, 1.5);
    let balls = |c2, n_glass| {
        let text = with_cameras(&two_balls(n0, c2, n_glass, names));
        scene(&text.replacen("center = [0.0, 0.0, 2.0]", "center = [0.0, 0.0, 2.5]", 1))
    };
    is_the_difference_quotient_within(|v| balls(v, n_glass), c2, 1e-5, 0, 1e-3);
    is_the_difference_quotient_within(|v| balls(c2, v), n_glass, 1e-5, 1, 1e-3);
}

/// The two balls' outputs by each ball's index against the slopes of the expectation: light
/// leaving one ball and grazing the other meets its surface at grazing incidence, where the
/// reflectance is 1, so the light goes on as if it had missed (nothing jumps at the other
/// ball's silhouette, whose share of the derivative is not estimated).
#[test]
fn two_volumes_outputs_differentiate_as_their_differences() {
    let (n0, c2, n_glass) = (1.3, -0.25, 1.5);
    let names = "\"volume[0].profiles[0].c2\", \"volume[1].profiles[0].n\"";
    let with = |d: bool| if d { names } else { "" };
    let balls = |c2, n_glass, d| scene(&two_balls(n0, c2, n_glass, with(d)));
    let sizes = (100_000, 16, 20_000);
    agrees_with_differences(|v, d| balls(v, n_glass, d), c2, 0.05, 0, sizes);
    agrees_with_differences(|v, d| balls(c2, v, d), n_glass, 0.05, 1, sizes);
}
