//! Particle (light) tracing through a refractive, scattering volume.
//!
//! Photons leave the light with equal power, refract or reflect at the volume's surface with the
//! Fresnel probabilities, fly along curved rays (free-flight lengths drawn over geometric length,
//! paper 002 Eq. 5; against the majorant in a heterogeneous medium, kept where the density says),
//! scatter by the phase function with their weight times the albedo (the rest is tallied as
//! absorbed), and play Russian roulette once their weight is small. A photon that leaves the
//! volume travels straight to the next surface (diffusely reflected from there) or away, and is
//! recorded by every sensor plane it crosses, in the time bin of its optical path length (Eq. 14).
//! Each output is a fraction of the emitted power, so flux sensors give total reflectance and
//! transmittance, and the power absorbed (in the volume and by surfaces), escaped and unfinished
//! adds up to 1 in expectation (and exactly for each photon when no roulette is played).
//!
//! Flux is conserved along ray tubes, so a photon's power needs no `n²` factor; connections to
//! probes and cameras carry the tube's exact cross-section (see [`super::connect`]), which is what
//! the conservation of basic radiance `L/n²` of the RRTE expresses.

use super::beam_tube::BeamTube;
use super::bidirectional::Subpaths;
use super::connect::{Aim, Bounces, Connector, Exit, InsidePath, Sampled};
use super::connection_slopes::{ShiftedFields, Vertex, emitted};
use super::flight::{Flight, Flyer, fresnel, reflect};
use super::scene::{
    Connections, Filter, MAX_DERIVATIVES, MAX_TARGETS, Modulation, PartLengths, Region,
    RenderScene, SensorKind, Shares, Tracing, Volume, shares,
};
use super::spectrum::Delay;
use crate::eikonal::trace::refract;
use crate::eikonal::{BoundedField, Ray};
use crate::math::{C64, Rng, uniform};
use crate::mc::Estimator;
use crate::medium::params::Param;
use crate::speckle::paths::{ROULETTE_BELOW, ROULETTE_SURVIVAL};
use glam::DVec3;

/// Scattering events after which a photon is given up (counted as unfinished).
pub const MAX_EVENTS: usize = 1_000_000;

/// Reflections inside the surface a photon or path makes between two events (or before its
/// first) before it is given up: light trapped by total internal reflection in a nearly clear
/// volume would otherwise bounce for `1/σ_t` of length, and a ray held at one point of a surface
/// by round-off for ever. A photon given up counts as unfinished.
pub const MAX_REFLECTIONS: usize = 100_000;

/// Track lengths through each target during one flight.
pub(super) type Tracks = [f64; MAX_TARGETS];

/// Indices of the totals after the sensors' outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Total {
    /// Power absorbed inside the volume.
    Absorbed = 0,
    /// Power that left the scene for good (recorded by a sensor or not).
    Escaped = 1,
    /// Power of photons given up: trapped beyond the step budget, [`MAX_EVENTS`] or
    /// [`MAX_REFLECTIONS`].
    Unfinished = 2,
    /// Scattering events (a count per photon, for statistics).
    Events = 3,
    /// Leapfrog steps (a count per photon, for statistics).
    Steps = 4,
    /// Connections to probes asked for, found, Newton solves run, Newton iterations, and distinct
    /// stationary paths met (counts per photon, for statistics).
    Connections = 5,
    Connected = 6,
    Solves = 7,
    Iterations = 8,
    Distinct = 9,
    /// Power absorbed by the surfaces.
    SurfaceAbsorbed = 10,
}

/// How many totals follow the sensors.
pub const TOTALS: usize = 11;

/// Bidirectional tracing tallies each camera's total by strategy for paths of up to this many
/// scattering events (`s` of `k` events from the light, `s = 0 … k`), longer ones together.
pub const STRATEGY_EVENTS: usize = 4;

/// The strategy tallies per camera: `k + 1` for each `k = 1 … STRATEGY_EVENTS`, and one more.
pub const STRATEGY_SLOTS: usize = STRATEGY_EVENTS * (STRATEGY_EVENTS + 3) / 2 + 1;

/// The integrators of one volume (free flights and connections), and the photon's weights in
/// the colour channels (its wavelength's, see [`super::spectrum`]).
pub(super) struct Tools<'v> {
    pub(super) flyer: Flyer<'v>,
    pub(super) connector: Connector<'v>,
    pub(super) colour: [f64; 3],
    /// The photon's group delay per optical path (its wavelength's dispersion).
    pub(super) delay: Delay,
    /// The instant `Ωt` of the ultrasound period the photon meets (under a sinusoidal
    /// modulation).
    pub(super) instant: Option<f64>,
}

impl<'v> Tools<'v> {
    pub(super) fn new(
        volume: &'v Volume,
        scene: &'v RenderScene,
        colour: [f64; 3],
        delay: Delay,
    ) -> Self {
        Tools {
            flyer: Flyer::new(volume, scene.step, scene.max_steps),
            connector: Connector::new(volume, scene.step, scene.max_steps)
                .blocked_by(&scene.surfaces),
            colour,
            delay,
            instant: None,
        }
    }
}

impl Tools<'_> {
    /// The group delay of a stretch inside the part of the volume that holds `x`, of optical
    /// path `optical_path` and geometric `length` (a flight or a path within one part).
    #[inline]
    pub(super) fn delay_inside(&self, x: DVec3, optical_path: f64, length: f64) -> f64 {
        let part = self.flyer.volume.part_index(x).unwrap_or(0);
        self.delay.inside(part, optical_path, length)
    }

    /// The group delay along the path `path` between two points inside.
    pub(super) fn path_delay(&self, path: &InsidePath) -> f64 {
        match path {
            InsidePath::Within(c, _) => self.delay_inside(c.arrival.x, c.optical_path, c.length),
            InsidePath::Between(e, _) => {
                self.exit_delay(e, self.flyer.volume.field.n_out * e.outside())
            }
        }
    }

    /// The group delay of the path `e` through the surface, whose optical path holds
    /// `outside` of straight stretches outside the volume: each part's stretch inside at that
    /// part's dispersion.
    pub(super) fn exit_delay(&self, e: &Exit, outside: f64) -> f64 {
        let again = e.again.parts();
        let first = (
            e.optical_path - outside - again.iter().map(|p| p.optical_path).sum::<f64>(),
            e.first_length(),
        );
        again.iter().fold(
            self.delay.outside(outside) + self.delay_inside(e.inside_from, first.0, first.1),
            |delay, p| delay + self.delay_inside(p.inside, p.optical_path, p.length),
        )
    }

    /// A free-flight distance from `x` over geometric length, against the majorant there
    /// (infinite in a clear volume).
    pub(super) fn free_path(&self, x: DVec3, rng: &mut Rng) -> f64 {
        let majorant = self.flyer.volume.majorant_at(x);
        if majorant > 0.0 {
            -(1.0 - uniform(rng)).ln() / majorant
        } else {
            f64::INFINITY
        }
    }

    /// Delta tracking: whether the tentative collision at `x` is real (probability `ρ(x)/max ρ`;
    /// always in a homogeneous medium). A null collision lets the flight go on unchanged.
    pub(super) fn real_collision(&self, x: DVec3, rng: &mut Rng) -> bool {
        match &self.flyer.volume.density {
            Some(density) => uniform(rng) * density.max < density.at(x),
            None => true,
        }
    }

    /// Fly from `ray` to the next real collision (flying on through delta tracking's null
    /// ones) or to the surface, and how far that took.
    pub(super) fn next_event(&self, ray: Ray, rng: &mut Rng) -> (Stop, Travelled) {
        self.next_event_visiting(ray, rng, |_, _| {})
    }

    /// [`Self::next_event`], reporting every chord flown (null collisions' flights included) to
    /// `chord`.
    #[inline]
    pub(super) fn next_event_visiting(
        &self,
        mut ray: Ray,
        rng: &mut Rng,
        mut chord: impl FnMut(DVec3, DVec3),
    ) -> (Stop, Travelled) {
        let mut travelled = Travelled::default();
        // a flight stays in the part it starts in
        let part = self.flyer.volume.part_index(ray.x).unwrap_or(0);
        loop {
            let (flight, k) = self
                .flyer
                .fly_visiting(ray, self.free_path(ray.x, rng), &mut chord);
            travelled.steps += k;
            match flight {
                Flight::Collision {
                    ray: hit,
                    optical_path,
                    length,
                } => {
                    travelled.add(self, part, optical_path, length);
                    if self.real_collision(hit.x, rng) {
                        return (Stop::Collision(hit), travelled);
                    }
                    ray = hit;
                }
                Flight::Boundary {
                    ray: end,
                    optical_path,
                    length,
                } => {
                    travelled.add(self, part, optical_path, length);
                    return (Stop::Boundary(end), travelled);
                }
                Flight::Stuck { .. } => return (Stop::Stuck, travelled),
            }
        }
    }

    /// The ray leaving a scattering event at `x` where the light arrived along unit `u`, its
    /// direction drawn from the phase function.
    pub(super) fn scatter(&self, x: DVec3, u: DVec3, rng: &mut Rng) -> Ray {
        self.scatter_by(x, u, rng).0
    }

    /// [`Self::scatter`], and the particle type whose phase function drew the direction.
    fn scatter_by(&self, x: DVec3, u: DVec3, rng: &mut Rng) -> (Ray, usize) {
        let scattering = self.flyer.volume.scattering_at(x);
        let kind = scattering.pick(|| uniform(rng));
        let w = scattering.phase(kind).sample(u, uniform(rng), uniform(rng));
        let ray = Ray {
            x,
            v: w * self.flyer.n(x),
        };
        (ray, kind)
    }
}

/// Where [`Tools::next_event`] stopped.
pub(super) enum Stop {
    /// A real collision.
    Collision(Ray),
    /// The volume's surface, reached from inside.
    Boundary(Ray),
    /// A flight ran out of leapfrog steps.
    Stuck,
}

/// What the flights to the next event covered: group delay, geometric length, leapfrog steps.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Travelled {
    pub(super) opl: f64,
    pub(super) length: f64,
    pub(super) steps: usize,
}

impl Travelled {
    pub(super) fn add(&mut self, t: &Tools, part: usize, optical_path: f64, length: f64) {
        self.opl += t.delay.inside(part, optical_path, length);
        self.length += length;
    }
}

/// A connection from an event inside the volume to a camera (see
/// [`ParticleTracer::camera_link`]): what it carries per unit intensity leaving the event, and
/// what multiple importance sampling needs of it.
pub(super) struct CameraLink {
    /// The camera (orthographic ones first, then pinholes) and the pixels it adds to, with their
    /// shares (the one it lands in, or a tent filter's four).
    pub(super) camera: usize,
    pub(super) pixels: Shares,
    /// Unit direction leaving the event.
    pub(super) direction: DVec3,
    /// The pixel's radiance, and the camera total's share (the irradiance at a pinhole).
    pub(super) radiance: f64,
    pub(super) total: f64,
    /// Group delay from the event to the camera.
    pub(super) delay: f64,
    /// Geometric length inside the volume (part by part) and straight outside it.
    pub(super) inside: PartLengths,
    pub(super) outside: f64,
    /// The density of the camera's own sampling of this path's start: per unit area of an
    /// orthographic camera's rectangle, per solid angle at a pinhole.
    pub(super) pdf: f64,
    /// From an event inside, its reflections inside the surface before it leaves (0 from a
    /// surface).
    pub(super) bounces: usize,
}

/// Where an image lies among the outputs: after its total (`first − 1`), frame after frame (with
/// time bins the time-integrated frame first, with its own errors: one photon can reach an image
/// in several bins), each frame channel after channel, each channel a row-major image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageLayout {
    pub first: usize,
    pub pixels: usize,
    pub channels: usize,
    /// Time bins (1: no transient, and no separate integrated frame).
    pub bins: usize,
}

impl ImageLayout {
    /// The first output of `channel` in time bin `bin`, or (`None`) in the time-integrated frame.
    pub fn plane(&self, bin: Option<usize>, channel: usize) -> usize {
        let frame = match bin {
            None => 0,
            Some(b) => b + usize::from(self.bins > 1),
        };
        self.first + (frame * self.channels + channel) * self.pixels
    }

    /// Outputs the image takes (its total not counted).
    fn len(&self) -> usize {
        let frames = self.bins + usize::from(self.bins > 1);
        frames * self.channels * self.pixels
    }

    /// The output holding the image's total (all pixels, bins and no colour weights).
    pub fn total(&self) -> usize {
        self.first - 1
    }

    /// Add `value` (weighted by `colour` in each channel) to `pixel` in time bin `bin`, and to the
    /// integrated frame.
    pub(super) fn add(
        &self,
        out: &mut [C64],
        bin: usize,
        pixel: usize,
        value: f64,
        colour: &[f64; 3],
    ) {
        for (c, w) in colour.iter().enumerate().take(self.channels) {
            let v = if self.channels == 1 { value } else { value * w };
            out[self.plane(Some(bin), c) + pixel].re += v;
            if self.bins > 1 {
                out[self.plane(None, c) + pixel].re += v;
            }
        }
    }
}

/// The particle tracer of a scene, as an engine estimator.
pub struct ParticleTracer<'s> {
    pub(super) scene: &'s RenderScene,
    tools: Tools<'s>,
    /// The images of the sensors, then of the cameras, then of the pinholes.
    images: Vec<ImageLayout>,
    /// The first output of each probe (its time bins; its total before).
    probes: Vec<usize>,
    /// The power reaching each surface.
    surface_offset: usize,
    totals: usize,
    /// Per differentiated parameter, sensor after sensor: the derivative of its power (the
    /// layout's total) and, for a screen, of each pixel's.
    derivative_images: Vec<ImageLayout>,
    /// The first of the probes' derivatives: per differentiated parameter, probe after probe, the
    /// derivative of its fluence rate (over all time bins).
    probe_derivatives: usize,
    /// Per differentiated parameter, camera after camera (the orthographic ones first): the
    /// derivative of its image (its total and pixels, time-integrated).
    camera_derivatives: Vec<ImageLayout>,
    /// The first output of the cameras' pixel windows (camera after camera, each one's windows
    /// in order): each window's sum over its pixels, time-integrated, without colour weights.
    pub(super) windows: usize,
    /// Per camera, the index of its first window among all.
    first_window: Vec<usize>,
    /// The first of the windows' derivatives: per differentiated parameter, window after window.
    window_derivatives: usize,
    /// The volume moved along each differentiated index-field parameter, for the derivatives of
    /// connections.
    pub(super) shifted: ShiftedFields,
    /// The sensors that are targets, with their regions.
    pub(super) targets: Vec<(usize, Region)>,
    /// Draw every scored choice of [`super::tangent`] with probability ½ (the weights take the
    /// rest): the estimate is then a smooth function of the field's parameters for fixed random
    /// numbers, and its derivative its difference quotient, which tests check. Off by default:
    /// the outcomes' own probabilities, clamped, give less noise.
    pub even_draws: bool,
    /// The first of bidirectional tracing's strategy tallies ([`Self::strategy_total`]).
    strategies: usize,
    /// Outputs in all.
    outputs: usize,
    /// Bidirectional tracing's beam tube, where its camera subpaths' flights from events draw
    /// collisions (a collimated beam thin for its medium, in a volume without a density).
    pub(super) tube: Option<BeamTube>,
}

impl<'s> ParticleTracer<'s> {
    pub fn new(scene: &'s RenderScene) -> Self {
        let mut images = Vec::new();
        let mut at = 0;
        let bins = scene.bins();
        let image = |pixels: usize, channels: usize, at: &mut usize| {
            // the image's total, then its planes
            let i = ImageLayout {
                first: *at + 1,
                pixels,
                channels,
                bins,
            };
            *at += 1 + i.len();
            i
        };
        for s in &scene.sensors {
            // a flux sensor's power per time bin has no colour
            let channels = match s.kind {
                SensorKind::Flux | SensorKind::Spot | SensorKind::Target => 1,
                SensorKind::Screen => scene.channels(),
            };
            images.push(image(s.pixel_count(), channels, &mut at));
        }
        let mut probes = Vec::new();
        for _ in &scene.probes {
            // the probe's total fluence rate, then its time bins
            probes.push(at + 1);
            at += 1 + bins;
        }
        for c in &scene.cameras {
            images.push(image(c.pixel_count(), scene.channels(), &mut at));
        }
        for c in &scene.pinholes {
            images.push(image(c.pixel_count(), scene.channels(), &mut at));
        }
        let surface_offset = at;
        at += scene.surfaces.len();
        let totals = at;
        at += TOTALS;
        let mut derivative_images = Vec::new();
        for _ in &scene.derivatives {
            for s in &scene.sensors {
                let pixels = match s.kind {
                    SensorKind::Flux | SensorKind::Spot | SensorKind::Target => 0,
                    SensorKind::Screen => s.pixel_count(),
                };
                derivative_images.push(ImageLayout {
                    first: at + 1,
                    pixels,
                    channels: 1,
                    bins: 1,
                });
                at += 1 + pixels;
            }
        }
        let probe_derivatives = at;
        at += scene.derivatives.len() * scene.probes.len();
        let mut camera_derivatives = Vec::new();
        for _ in &scene.derivatives {
            let counts = scene.cameras.iter().map(|c| c.pixel_count());
            for pixels in counts.chain(scene.pinholes.iter().map(|c| c.pixel_count())) {
                camera_derivatives.push(ImageLayout {
                    first: at + 1,
                    pixels,
                    channels: 1,
                    bins: 1,
                });
                at += 1 + pixels;
            }
        }
        let windows = at;
        let mut first_window = Vec::new();
        let mut count = 0;
        for c in 0..scene.cameras.len() + scene.pinholes.len() {
            first_window.push(count);
            count += scene.camera_windows(c).len();
        }
        at += count;
        let window_derivatives = at;
        at += scene.derivatives.len() * count;
        let strategies = at;
        if scene.tracing == Tracing::Bidirectional {
            at += (scene.cameras.len() + scene.pinholes.len()) * STRATEGY_SLOTS;
        }
        ParticleTracer {
            scene,
            tools: Tools::new(&scene.volume, scene, [1.0; 3], Delay::NONE),
            tube: (scene.tracing == Tracing::Bidirectional && scene.volume.density.is_none())
                .then(|| {
                    let flyer = Flyer::new(&scene.volume, scene.step, scene.max_steps);
                    BeamTube::trace(&scene.light, &flyer)
                })
                .flatten(),
            images,
            probes,
            surface_offset,
            totals,
            derivative_images,
            probe_derivatives,
            camera_derivatives,
            windows,
            first_window,
            window_derivatives,
            shifted: ShiftedFields::new(scene),
            targets: scene
                .sensors
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.region.map(|r| (i, r)))
                .collect(),
            even_draws: false,
            strategies,
            outputs: at,
        }
    }

    /// Add the chord from `a` to `b` to the track lengths through each target.
    #[inline]
    pub(super) fn track(&self, a: DVec3, b: DVec3, tracks: &mut Tracks) {
        for (k, (_, region)) in self.targets.iter().enumerate() {
            if let Some((t0, t1)) = region.clip(a, b) {
                tracks[k] += (t1 - t0) * (b - a).length();
            }
        }
    }

    /// Record a flight's track lengths through the targets (`tracks`) by a photon of `weight`
    /// with the path's `score`: each target's mean fluence rate is the power-weighted track
    /// length per unit volume.
    pub(super) fn record_tracks(
        &self,
        tracks: &Tracks,
        weight: f64,
        score: &[f64],
        out: &mut [C64],
    ) {
        for (k, &(i, region)) in self.targets.iter().enumerate() {
            if tracks[k] == 0.0 {
                continue;
            }
            let value = weight * tracks[k] / region.volume();
            out[self.images[i].total()].re += value;
            for (j, dlog) in score.iter().enumerate() {
                out[self.power_derivative(i, j)].re += value * dlog;
            }
        }
    }

    /// The derivative of sensor `i`'s image with respect to `scene.derivatives[j]`: its total
    /// (the power's derivative) and, for a screen, its pixels (one channel, time-integrated).
    pub fn derivative_image(&self, i: usize, j: usize) -> ImageLayout {
        self.derivative_images[j * self.scene.sensors.len() + i]
    }

    /// The output holding the derivative of sensor `i`'s power with respect to
    /// `scene.derivatives[j]`.
    pub fn power_derivative(&self, i: usize, j: usize) -> usize {
        self.derivative_image(i, j).total()
    }

    /// The output holding the derivative of probe `i`'s fluence rate (over all time bins) with
    /// respect to `scene.derivatives[j]`.
    pub fn probe_derivative(&self, i: usize, j: usize) -> usize {
        self.probe_derivatives + j * self.scene.probes.len() + i
    }

    /// The derivative of camera `i`'s image (the orthographic cameras first, then the pinholes)
    /// with respect to `scene.derivatives[j]`: its total and pixels, time-integrated.
    pub fn camera_derivative(&self, i: usize, j: usize) -> ImageLayout {
        let cameras = self.scene.cameras.len() + self.scene.pinholes.len();
        self.camera_derivatives[j * cameras + i]
    }

    /// The output holding the sum over window `k` of camera `i` (the orthographic cameras first,
    /// then the pinholes): what its image's total takes from those pixels.
    pub fn window_total(&self, i: usize, k: usize) -> usize {
        self.windows + self.first_window[i] + k
    }

    /// Of a bidirectional render, the output holding the part of camera `i`'s total (the
    /// orthographic cameras first) that strategy `s` brings from paths of `k ≥ 1` scattering
    /// events (`s` of them traced from the light), weighted; for `k` beyond
    /// [`STRATEGY_EVENTS`], every strategy's (`s` ignored). Unscattered light from a light
    /// inside the volume, made one way, is in none.
    pub fn strategy_total(&self, i: usize, k: usize, s: usize) -> usize {
        let slot = if k <= STRATEGY_EVENTS {
            k * (k + 1) / 2 - 1 + s.min(k)
        } else {
            STRATEGY_SLOTS - 1
        };
        self.strategies + i * STRATEGY_SLOTS + slot
    }

    /// The output holding the derivative of [`Self::window_total`] with respect to
    /// `scene.derivatives[j]`.
    pub fn window_derivative(&self, i: usize, k: usize, j: usize) -> usize {
        self.window_slopes(j) + self.first_window[i] + k
    }

    /// The first output of the windows' derivatives with respect to `scene.derivatives[j]`.
    pub(super) fn window_slopes(&self, j: usize) -> usize {
        let windows = self.window_derivatives - self.windows;
        self.window_derivatives + j * windows
    }

    /// Add `value` to output `base + w` for every window `w` (counted over all cameras) of camera
    /// `camera` that holds `pixel`.
    #[inline]
    pub(super) fn add_to_windows(
        &self,
        camera: usize,
        pixel: usize,
        value: f64,
        base: usize,
        out: &mut [C64],
    ) {
        let width = self.scene.camera_pixels(camera)[0];
        let first = self.first_window[camera];
        for (k, w) in self.scene.camera_windows(camera).iter().enumerate() {
            if w.contains(pixel, width) {
                out[base + first + k].re += value;
            }
        }
    }

    /// The output holding objective `i` of [`RenderScene::objectives`]: a sensor's power, a
    /// probe's fluence rate, then a camera window's sum.
    pub fn objective(&self, i: usize) -> usize {
        let sensors = self.scene.sensors.len();
        match i.checked_sub(sensors + self.scene.probes.len()) {
            Some(window) => self.windows + window,
            None if i < sensors => self.power(i),
            None => self.probe_total(i - sensors),
        }
    }

    /// The output holding the derivative of objective `i` with respect to
    /// `scene.derivatives[j]`.
    pub fn objective_derivative(&self, i: usize, j: usize) -> usize {
        let sensors = self.scene.sensors.len();
        match i.checked_sub(sensors + self.scene.probes.len()) {
            Some(window) => self.window_slopes(j) + window,
            None if i < sensors => self.power_derivative(i, j),
            None => self.probe_derivative(i - sensors, j),
        }
    }

    /// The image of sensor `i` (a flux sensor's: one pixel, one channel, its power per bin).
    pub fn sensor_image(&self, i: usize) -> ImageLayout {
        self.images[i]
    }

    /// The image of orthographic camera `i`; its total sums the radiance over pixels and bins.
    pub fn camera_image(&self, i: usize) -> ImageLayout {
        self.images[self.scene.sensors.len() + i]
    }

    /// The image of camera `i` (the orthographic cameras first, then the pinholes).
    pub fn images_of_camera(&self, i: usize) -> ImageLayout {
        self.images[self.scene.sensors.len() + i]
    }

    /// The image of pinhole camera `i`; its total is the irradiance at the pinhole from its field
    /// of view.
    pub fn pinhole_image(&self, i: usize) -> ImageLayout {
        self.images[self.scene.sensors.len() + self.scene.cameras.len() + i]
    }

    /// The output holding the power reaching surface `i` (it absorbs `1 − albedo` of it).
    pub fn surface_power(&self, i: usize) -> usize {
        self.surface_offset + i
    }

    /// The first output of probe `i` (its time bins).
    pub fn probe_offset(&self, i: usize) -> usize {
        self.probes[i]
    }

    /// The output holding probe `i`'s fluence rate over all time bins.
    pub fn probe_total(&self, i: usize) -> usize {
        self.probe_offset(i) - 1
    }

    /// Whether scattering events are connected to probes or cameras.
    pub(super) fn connects(&self) -> bool {
        !self.scene.probes.is_empty()
            || !self.scene.cameras.is_empty()
            || !self.scene.pinholes.is_empty()
    }

    /// Next-event connections from `x` (inside) to every probe and camera: power `weight` leaving
    /// `x` with angular density `emit(d)` per steradian along unit `d`, having travelled the
    /// optical path `opl`. A probe receives `weight · emit(d) · T / (dA⊥/dω)` over the stationary
    /// paths; a camera's pixel `weight · emit(d) · T · (1 − R) / (dω_out/dω) / pixel area`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn connect(
        &self,
        t: &Tools,
        x: DVec3,
        weight: f64,
        opl: f64,
        emit: impl Fn(DVec3) -> f64,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        self.connect_probes(t, x, weight, opl, &emit, rng, out);
        self.connect_cameras(t, x, weight, opl, emit, rng, out);
    }

    /// A photon's next-event connections from `v` (inside) with power `weight` after the optical
    /// path `opl` ([`Self::connect`]); with derivatives, the probes' and cameras' too (`score`:
    /// the path's so far, `shifted`: the photon's volume moved along each index-field parameter).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn connect_photon(
        &self,
        t: &Tools,
        v: &Vertex,
        (weight, opl): (f64, f64),
        score: &[f64],
        shifted: &[[Volume; 2]],
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        if self.scene.derivatives.is_empty() {
            let emit = |d| emitted(self.scene, t.flyer.volume, (v.x, v.w_in), d);
            self.connect(t, v.x, weight, opl, emit, rng, out);
            return;
        }
        self.connect_probes_scored(t, v, weight, opl, score, shifted, rng, out);
        self.connect_cameras_scored(t, v, weight, opl, score, shifted, rng, out);
    }

    /// Next-event connections from `x` (inside) to every camera (see [`Self::connect`]).
    #[allow(clippy::too_many_arguments)]
    fn connect_cameras(
        &self,
        t: &Tools,
        x: DVec3,
        weight: f64,
        opl: f64,
        emit: impl Fn(DVec3) -> f64,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        for i in 0..self.scene.cameras.len() + self.scene.pinholes.len() {
            for way in self.ways(t, false) {
                let Some(link) = self.camera_link(t, x, i, way, rng, out) else {
                    continue;
                };
                let scale = weight * emit(link.direction);
                self.record_link(t, &link, scale, opl, out);
            }
        }
    }

    /// Next-event connections from `x` (inside) to every probe (see [`ParticleTracer::connect`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn connect_probes(
        &self,
        t: &Tools,
        x: DVec3,
        weight: f64,
        opl: f64,
        emit: impl Fn(DVec3) -> f64,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        self.probe_paths(t, x, rng, out, |out, i, path, inverse_p, rng| {
            let transmittance = self.path_transmittance(t, x, path, rng);
            let d = path.direction();
            let value =
                weight * emit(d) * transmittance * path.fresnel() / path.spread() * inverse_p;
            if value > 0.0 && value.is_finite() {
                self.add_to_probe(t, i, path, value, opl, out);
            }
        });
    }

    /// Every stationary path drawn from `x` (inside) to each probe, after 0 … K reflections inside
    /// the surface ([`Connector::sample_inside`]), to `visit(out, probe, path, inverse
    /// probability, rng)`.
    pub(super) fn probe_paths(
        &self,
        t: &Tools,
        x: DVec3,
        rng: &mut Rng,
        out: &mut [C64],
        mut visit: impl FnMut(&mut [C64], usize, &InsidePath, f64, &mut Rng),
    ) {
        let first_only = self.scene.connections == Connections::First;
        for (i, probe) in self.scene.probes.iter().enumerate() {
            for bounces in 0..=self.most_bounces(t) {
                let s =
                    t.connector
                        .sample_inside(x, probe.position, (bounces, true), first_only, rng);
                if let Some((path, inverse_p)) = self.tally(s, out) {
                    visit(out, i, &path, inverse_p, rng);
                }
            }
        }
    }

    /// Add `value` to probe `i`, reached along `path` after the optical path `opl`: `false` if
    /// it arrives after the last time bin.
    pub(super) fn add_to_probe(
        &self,
        t: &Tools,
        i: usize,
        path: &InsidePath,
        value: f64,
        opl: f64,
        out: &mut [C64],
    ) -> bool {
        let Some(bin) = self.bin(opl + t.path_delay(path)) else {
            return false;
        };
        let o = self.probe_offset(i);
        out[o + bin].re += value;
        out[o - 1].re += value;
        true
    }

    /// Add the connection `link` to its camera's image, carrying `scale` times its unit
    /// intensity, reached after the optical path `opl`: `false` if it adds nothing (no light, or
    /// after the last time bin).
    pub(super) fn record_link(
        &self,
        t: &Tools,
        link: &CameraLink,
        scale: f64,
        opl: f64,
        out: &mut [C64],
    ) -> Option<f64> {
        let radiance = scale * link.radiance;
        if !(radiance > 0.0 && radiance.is_finite()) {
            return None;
        }
        let bin = self.bin(opl + link.delay)?;
        let image = self.images[self.scene.sensors.len() + link.camera];
        let mut added = 0.0;
        for &(pixel, share) in &link.pixels.0[..link.pixels.1] {
            image.add(out, bin, pixel, radiance * share, &t.colour);
            let total = scale * link.total * share;
            out[image.total()].re += total;
            added += total;
            self.add_to_windows(link.camera, pixel, total, self.windows, out);
        }
        Some(added)
    }

    /// The connection from `x` (inside) to camera `i` (the orthographic cameras first, then the
    /// pinholes), what it carries per unit intensity leaving `x`: a pixel's radiance `T (1 − R)
    /// / (dω_out/dω) / pixel area` for an orthographic camera, `T (1 − R) / (dA⊥/dω) / (cos³θ
    /// pixel area)` for a pinhole (its irradiance over the pixel's image-plane area at unit
    /// distance, `dω = cos³θ dA`). `R` holds the Fresnel reflectances of the `way`'s reflections
    /// inside the surface.
    pub(super) fn camera_link(
        &self,
        t: &Tools,
        x: DVec3,
        i: usize,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<CameraLink> {
        let (e, inverse_p, bounces) = self.camera_exit(t, x, i, way, rng, out)?;
        let link = self.link_to_camera(t, i, &e, || {
            let transmittance = self.exit_transmittance(t, &e, bounces.first, rng);
            transmittance * e.transmission / e.jacobian * inverse_p
        })?;
        Some(CameraLink {
            bounces: bounces.first,
            ..link
        })
    }

    /// The path from `x` (inside) out of the volume to camera `i` that [`Self::camera_link`]
    /// draws, with its inverse probability and its reflections inside the surface.
    pub(super) fn camera_exit(
        &self,
        t: &Tools,
        x: DVec3,
        i: usize,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<(Exit, f64, Bounces)> {
        let Way::Bounces(first) = way else {
            return None;
        };
        let bounces = self.exit_bounces(t, first, rng);
        let first_only = self.scene.connections == Connections::First;
        let s = match self.scene.cameras.get(i) {
            Some(cam) => {
                t.connector
                    .sample_exit(x, Aim::Along(cam.direction), &bounces, first_only, rng)
            }
            None => {
                let cam = &self.scene.pinholes[i - self.scene.cameras.len()];
                t.connector
                    .sample_through(x, Aim::Point(cam.position), &bounces, first_only, rng)
            }
        };
        self.tally(s, out)
            .map(|(e, inverse_p)| (e, inverse_p, bounces))
    }

    /// [`Self::camera_exit`] solved by Newton from the direction `w0` (polished: for central
    /// differences) with `connector`.
    pub(super) fn camera_exit_from(
        &self,
        connector: &Connector,
        x: DVec3,
        i: usize,
        w0: DVec3,
        bounces: &Bounces,
    ) -> Option<Exit> {
        match self.scene.cameras.get(i) {
            Some(cam) => connector.solve_exit(x, Aim::Along(cam.direction), w0, bounces),
            None => {
                let cam = &self.scene.pinholes[i - self.scene.cameras.len()];
                connector.solve_through(x, Aim::Point(cam.position), w0, bounces)
            }
        }
    }

    /// The link to camera `i` of the path `e` that has left the volume towards it, if it meets
    /// no surface (nor the volume again) on its way there and lands in a pixel: `carried()` is
    /// what the path carries per unit intensity at its start (`dω_out/dω` or `dA⊥/dω` with the
    /// rest), asked for only then.
    pub(super) fn link_to_camera(
        &self,
        t: &Tools,
        i: usize,
        e: &Exit,
        carried: impl FnOnce() -> f64,
    ) -> Option<CameraLink> {
        let n_out = t.flyer.volume.field.n_out;
        let before = n_out * e.outside();
        if let Some(cam) = self.scene.cameras.get(i) {
            let (a, b) = cam.fractions(e.surface);
            let pixels = shares(cam.filter, a, b, cam.pixels);
            if pixels.1 == 0 {
                return None;
            }
            let to_plane = (cam.center - e.surface).dot(cam.direction);
            if to_plane < 0.0 || self.scene.blocked(e.surface, cam.direction, to_plane) {
                return None;
            }
            let radiance = carried() / cam.pixel_area();
            return Some(CameraLink {
                camera: i,
                pixels,
                direction: e.direction,
                radiance,
                total: radiance,
                delay: t.exit_delay(e, before) + t.delay.outside(n_out * to_plane),
                inside: e.lengths(t.flyer.volume),
                outside: e.outside() + to_plane,
                pdf: 1.0 / cam.area(),
                bounces: 0,
            });
        }
        let cam = &self.scene.pinholes[i - self.scene.cameras.len()];
        let (a, b, cos) = cam.fractions(e.outgoing)?;
        let pixels = shares(cam.filter, a, b, cam.pixels);
        if pixels.1 == 0 {
            return None;
        }
        let to_pinhole = (cam.position - e.surface).dot(e.outgoing);
        if self.scene.blocked(e.surface, e.outgoing, to_pinhole) {
            return None;
        }
        let irradiance = carried();
        // the path's optical length holds its straight stretches outside
        let outside = n_out * (e.outside() + to_pinhole);
        Some(CameraLink {
            camera: i,
            pixels,
            direction: e.direction,
            radiance: irradiance / (cos * cos * cos * cam.pixel_area()),
            total: irradiance,
            delay: t.exit_delay(e, outside),
            inside: e.lengths(t.flyer.volume),
            outside: e.outside() + to_pinhole,
            pdf: 1.0 / cam.image_area(cos),
            bounces: 0,
        })
    }

    /// The transmittance along the connection leaving `x` along unit `w` for geometric length
    /// `length` inside the volume, reflected `bounces` times inside the surface on the way:
    /// `exp(−σ_t length)` in a homogeneous medium; with a density, an unbiased ratio-tracking
    /// estimate (Novák et al. 2014): tentative collisions against the majorant along the same
    /// curved ray, each keeping `1 − ρ/max ρ` of the light, stretch by stretch between the
    /// reflections (independent estimates, so their product is unbiased too).
    pub(super) fn transmittance(
        &self,
        t: &Tools,
        x: DVec3,
        w: DVec3,
        (length, bounces): (f64, usize),
        rng: &mut Rng,
    ) -> f64 {
        let volume = t.flyer.volume;
        if volume.density.is_none() {
            return (-volume.sigma_t_at(x) * length).exp();
        }
        if bounces == 0 {
            return self.ratio_tracking(t, x, w, length, rng);
        }
        let mut kept = 1.0;
        let whole = t
            .connector
            .stretches(x, w, bounces, length, |from, along, stretch| {
                kept *= self.ratio_tracking(t, from, along, stretch, rng);
            });
        if whole { kept } else { 0.0 }
    }

    /// The transmittance along `path` from `x` to a point inside ([`Self::transmittance`],
    /// [`Self::exit_transmittance`]).
    pub(super) fn path_transmittance(
        &self,
        t: &Tools,
        x: DVec3,
        path: &InsidePath,
        rng: &mut Rng,
    ) -> f64 {
        match *path {
            InsidePath::Within(c, bounces) => {
                self.transmittance(t, x, c.direction, (c.length, bounces), rng)
            }
            InsidePath::Between(e, bounces) => self.exit_transmittance(t, &e, bounces.first, rng),
        }
    }

    /// The transmittance along a connection through the surface (`bounces`: its reflections
    /// inside before it first leaves): its first part from `inside_from` along `inside_along`,
    /// then each part of a non-convex volume it enters again ([`Self::transmittance`] of each;
    /// the product of independent unbiased estimates is unbiased).
    pub(super) fn exit_transmittance(
        &self,
        t: &Tools,
        e: &Exit,
        bounces: usize,
        rng: &mut Rng,
    ) -> f64 {
        let first = (e.first_length(), bounces);
        let mut kept = self.transmittance(t, e.inside_from, e.inside_along, first, rng);
        for p in e.again.parts() {
            kept *= self.ratio_tracking(t, p.inside, p.along, p.length, rng);
        }
        kept
    }

    /// Ratio tracking along the curved ray from `x` (inside) along unit `w` for geometric length
    /// `length`: see [`Self::transmittance`].
    fn ratio_tracking(&self, t: &Tools, x: DVec3, w: DVec3, length: f64, rng: &mut Rng) -> f64 {
        let volume = t.flyer.volume;
        let Some(density) = &volume.density else {
            return (-volume.sigma_t_at(x) * length).exp();
        };
        let majorant = volume.majorant_at(x);
        if majorant <= 0.0 {
            return 1.0;
        }
        let mut ray = Ray {
            x,
            v: w * t.flyer.n(x),
        };
        let (mut travelled, mut kept) = (0.0, 1.0);
        loop {
            let d = -(1.0 - uniform(rng)).ln() / majorant;
            if travelled + d >= length {
                return kept;
            }
            match t.flyer.fly(ray, d).0 {
                Flight::Collision { ray: at, .. } => {
                    travelled += d;
                    kept *= 1.0 - density.at(at.x) / density.max;
                    ray = at;
                }
                // the path leaves the volume (round-off at an exit connection's end)
                _ => return kept,
            }
        }
    }

    /// The transmittance of the straight segment from `y` outside the volume along unit `w` for
    /// `length`, and its geometric length inside the volume: 1 if it misses the volume, its
    /// attenuation through an index-matched volume of constant `n` (the line runs straight
    /// through it), `None` through a refracting one (the path would bend: not connected).
    pub(super) fn past_volume(
        &self,
        t: &Tools,
        y: DVec3,
        w: DVec3,
        length: f64,
        rng: &mut Rng,
    ) -> Option<(f64, PartLengths)> {
        // every stretch of the line inside the volume (one if it is convex)
        let volume = t.flyer.volume;
        let bounds = &volume.field.bounds;
        let (mut from, mut transmittance) = (0.0, 1.0);
        let mut inside = PartLengths::default();
        while let Some((t0, t1)) = bounds.interval(y + w * from, w) {
            let (t0, t1) = (from + t0, from + t1);
            if t1 <= from || t0 >= length {
                break;
            }
            if !t.connector.matched() {
                return None;
            }
            let a = crate::eikonal::trace::entry_parameter(t0.max(from));
            let b = t1.min(length);
            if b > a {
                transmittance *= self.transmittance(t, y + w * a, w, (b - a, 0), rng);
                inside.add(volume.part_index(y + w * (0.5 * (a + b))), b - a);
            }
            if bounds.is_convex() || b >= length {
                break;
            }
            from = t1 + 1e-9 * (1.0 + t1.abs());
        }
        Some((transmittance, inside))
    }

    /// Count a connection's work in the statistics, and return its path and inverse probability.
    pub(super) fn tally<T>(&self, s: Sampled<T>, out: &mut [C64]) -> Option<(T, f64)> {
        out[self.total(Total::Connections)].re += 1.0;
        out[self.total(Total::Solves)].re += s.solves as f64;
        out[self.total(Total::Iterations)].re += s.iterations as f64;
        if s.path.is_some() {
            out[self.total(Total::Connected)].re += 1.0;
            out[self.total(Total::Distinct)].re += s.distinct as f64;
        }
        s.path
    }

    /// The time bin of optical path `path` (`None` past the last bin).
    pub(super) fn bin(&self, path: f64) -> Option<usize> {
        match self.scene.transient {
            None => Some(0),
            Some(tr) => {
                let b = (path / tr.max_path * tr.bins as f64).floor();
                (0.0..tr.bins as f64).contains(&b).then_some(b as usize)
            }
        }
    }

    /// Time bins of every image (1 without a transient).
    pub fn bins(&self) -> usize {
        self.scene.bins()
    }

    /// The output holding the total power sensor `i` recorded (all pixels and time bins).
    pub fn power(&self, i: usize) -> usize {
        self.images[i].total()
    }

    /// The output index of total `t`.
    pub fn total(&self, t: Total) -> usize {
        self.totals + t as usize
    }

    /// Record the sensors the straight segment from `x` along unit `d` crosses within `length`
    /// (outside the volume), at the optical path `opl` of its start; with the path's `score`
    /// (`∂ log` of its probability and weight per differentiated parameter), the derivatives of
    /// their powers too.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn cross_sensors(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        length: f64,
        weight: f64,
        opl: f64,
        score: &[f64],
        out: &mut [C64],
    ) {
        self.cross_sensors_with(t, x, d, length, weight, opl, score, out, |_, _, _, _, _| {});
    }

    /// [`Self::cross_sensors`], also reporting each share of a crossing whose weight moves with
    /// where it crosses (a spot's aperture, a tent-filtered pixel) to `moving`, as `(out, sensor,
    /// pixel, distance along d, ∂(recorded power)/∂(crossing point))`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn cross_sensors_with(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        length: f64,
        weight: f64,
        opl: f64,
        score: &[f64],
        out: &mut [C64],
        mut moving: impl FnMut(&mut [C64], usize, usize, f64, DVec3),
    ) {
        let n_out = t.flyer.volume.field.n_out;
        for (i, (s, image)) in self.scene.sensors.iter().zip(&self.images).enumerate() {
            let Some(distance) = s.crossing(x, d) else {
                continue;
            };
            if distance >= length {
                continue;
            }
            let Some(bin) = self.bin(opl + t.delay.outside(n_out * distance)) else {
                continue;
            };
            let at = x + d * distance;
            let add = |out: &mut [C64], pixel: usize, weight: f64| {
                image.add(out, bin, pixel, weight, &t.colour);
                out[image.total()].re += weight;
                for (j, dlog) in score.iter().enumerate() {
                    let d = self.derivative_image(i, j);
                    out[d.total()].re += weight * dlog;
                    if d.pixels > 0 {
                        out[d.first + pixel].re += weight * dlog;
                    }
                }
            };
            if s.filter == Filter::Tent {
                let (splat, count) = s.splat(at);
                for &(pixel, share, gradient) in &splat[..count] {
                    add(out, pixel, weight * share);
                    moving(out, i, pixel, distance, gradient * weight);
                }
            } else if let Some(pixel) = s.pixel_at(at) {
                add(out, pixel, weight * s.aperture(at));
                if s.window.is_some() {
                    moving(out, i, pixel, distance, s.aperture_gradient(at) * weight);
                }
            }
        }
    }

    /// One sample: a photon from the light, a path from each camera, or both joined. `shifted`:
    /// the photon's volume moved along each differentiated index-field parameter.
    fn sample(
        &self,
        t: &Tools,
        shifted: &[[Volume; 2]],
        subpaths: &mut Subpaths,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        match self.scene.tracing {
            Tracing::FromLight if self.scene.field_derivatives() || self.even_draws => {
                self.photon_differentiated(t, shifted, rng, out)
            }
            Tracing::FromLight => self.photon(t, rng, out),
            Tracing::FromCameras => self.camera_paths(t, rng, out),
            Tracing::Bidirectional => self.bidirectional(t, subpaths, rng, out),
        }
    }

    /// What the straight ray from `x` along unit `d` outside the volume meets: the distance to the
    /// volume's surface (none if it misses; `left_volume`: it starts where it left the volume,
    /// which only a non-convex shape can meet again), and the nearest surface with its distance.
    pub(super) fn ahead(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        left_volume: bool,
    ) -> (Option<f64>, Option<(usize, f64)>) {
        let bounds = &t.flyer.volume.field.bounds;
        let entry = if left_volume {
            bounds.reentry(x, d)
        } else {
            match bounds.interval(x, d) {
                Some((t0, t1)) if t1 > 0.0 && t0 >= 0.0 => Some(t0),
                _ => None,
            }
        };
        (entry, self.scene.surface_hit(x, d))
    }

    /// The same tracer with bidirectional tracing's camera subpaths flying freely, never
    /// drawing their collisions in a beam's tube (to measure what those draws save).
    pub fn without_beam_tube(mut self) -> Self {
        self.tube = None;
        self
    }

    /// The same tracer with bidirectional tracing's camera subpaths scattering by their phase
    /// function alone, never aiming at a beam's tube (to measure what aiming saves).
    pub fn without_aiming(mut self) -> Self {
        self.tube = self.tube.map(BeamTube::without_aiming);
        self
    }

    /// Trace one photon, adding its contributions to `out`.
    fn photon(&self, t: &Tools, rng: &mut Rng, out: &mut [C64]) {
        let (x, d) =
            self.scene
                .light
                .sample([uniform(rng), uniform(rng), uniform(rng), uniform(rng)]);
        let mut p = Photon {
            weight: 1.0,
            opl: 0.0,
            events: 0,
            steps: 0,
            score: [0.0; MAX_DERIVATIVES],
        };
        let mut leg = if t.flyer.volume.field.bounds.contains(x) {
            if self.connects() {
                let v = Vertex::fixed(x, None);
                let score = &p.score[..self.scene.derivatives.len()];
                self.connect_photon(t, &v, (1.0, 0.0), score, &[], rng, out);
            }
            Leg::Inside(Ray {
                x,
                v: d * t.flyer.n(x),
            })
        } else {
            Leg::Outside {
                x,
                d,
                left_volume: false,
            }
        };
        loop {
            let next = match leg {
                Leg::Inside(ray) => self.inside(t, ray, &mut p, rng, out),
                Leg::Outside { x, d, left_volume } => {
                    self.outside(t, x, d, left_volume, &mut p, rng, out)
                }
            };
            match next {
                Some(l) => leg = l,
                None => break,
            }
        }
        out[self.total(Total::Events)].re += p.events as f64;
        out[self.total(Total::Steps)].re += p.steps as f64;
    }

    /// A straight leg outside the volume from `x` along unit `d`: into the volume (with the Fresnel
    /// split at its surface), onto a surface (absorbed, or reflected diffusely after connecting
    /// the cameras to the lit point), or away for good, recording the sensors crossed on the way.
    /// `left_volume`: the leg starts where the photon left the volume (which it meets again only
    /// if the volume is not convex).
    #[allow(clippy::too_many_arguments)]
    fn outside(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        left_volume: bool,
        p: &mut Photon,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Leg> {
        let n_out = t.flyer.volume.field.n_out;
        let (entry, surface) = self.ahead(t, x, d, left_volume);
        let end = nearest(entry, surface);
        let score = &p.score[..self.scene.derivatives.len()];
        self.cross_sensors(t, x, d, end, p.weight, p.opl, score, out);
        match (entry, surface) {
            (Some(t0), _) if t0 == end => {
                p.opl += t.delay.outside(n_out * t0);
                Some(Leg::enter(t, x, d, t0, rng))
            }
            (_, Some((i, distance))) => {
                let s = &self.scene.surfaces[i];
                let y = x + d * distance;
                p.opl += t.delay.outside(n_out * distance);
                out[self.surface_offset + i].re += p.weight;
                out[self.total(Total::SurfaceAbsorbed)].re += p.weight * (1.0 - s.albedo);
                p.weight *= s.albedo;
                if p.weight <= 0.0 {
                    return None;
                }
                // the lit side; Lambertian: intensity cos θ / π per unit power, and the photon
                // leaves cosine-distributed
                let facing = if d.dot(s.normal) < 0.0 {
                    s.normal
                } else {
                    -s.normal
                };
                self.connect_from_surface(t, y, facing, p, rng, out);
                if !p.roulette(rng) {
                    return None;
                }
                let mu = uniform(rng).sqrt();
                let w = crate::math::direction_about(
                    facing,
                    mu,
                    2.0 * std::f64::consts::PI * uniform(rng),
                );
                Some(Leg::Outside {
                    x: y,
                    d: w,
                    left_volume: false,
                })
            }
            _ => {
                out[self.total(Total::Escaped)].re += p.weight;
                None
            }
        }
    }

    /// Connect a lit point `y` of a surface (unit `facing` normal on the lit side) to every camera
    /// it sees: in a straight line, past neither the volume (unless it is index-matched) nor
    /// another surface, and across the volume (refracted in and out). Probes are not connected.
    fn connect_from_surface(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        p: &Photon,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        for i in 0..self.scene.cameras.len() + self.scene.pinholes.len() {
            for way in self.ways(t, true) {
                if let Some(link) = self.surface_camera_link(t, y, facing, i, way, rng, out) {
                    // Lambertian: intensity cos θ / π per unit power
                    let lambert = facing.dot(link.direction) / std::f64::consts::PI;
                    let score = &p.score[..self.scene.derivatives.len()];
                    self.record_link_scored(
                        t,
                        &link,
                        (p.weight * lambert, p.opl),
                        score,
                        None,
                        out,
                    );
                }
            }
        }
    }

    /// The ways a connection from a point inside the volume, or on a surface (`from_surface`),
    /// may run: reflected up to [`Self::most_bounces`] times inside the surface before it
    /// leaves, and from a surface across the volume or off its outside. Through an index-matched
    /// volume a straight line crosses it: one way. Each connection declines the ways that do not
    /// fit its ends.
    pub(super) fn ways(&self, t: &Tools, from_surface: bool) -> impl Iterator<Item = Way> {
        let matched = t.connector.matched();
        let bounces = self.most_bounces(t);
        let outside = (from_surface && !matched).then_some([Way::Across, Way::Mirror]);
        (0..=bounces)
            .map(Way::Bounces)
            .chain(outside.into_iter().flatten())
    }

    /// The reflections of a connection through the surface that reflects `first` times inside
    /// the part it starts from: in the parts it meets after, as many as the rest of
    /// [`Self::most_bounces`] allows, drawn — inside them, or off their outside
    /// ([`Bounces::draw_with_mirrors`]); bidirectional tracing's connections, whose weights
    /// leave a reflection off an outside to its traced strategies, only inside
    /// ([`Bounces::draw`]).
    pub(super) fn exit_bounces(&self, t: &Tools, first: usize, rng: &mut Rng) -> Bounces {
        let after = self.most_bounces(t).saturating_sub(first);
        match self.scene.tracing {
            Tracing::Bidirectional => Bounces::draw(first, after, rng),
            _ => Bounces::draw_with_mirrors(first, after, rng),
        }
    }

    /// Reflections inside the surface a connection follows at most: `render.reflections`, none
    /// where nothing reflects (an index-matched volume).
    pub(super) fn most_bounces(&self, t: &Tools) -> usize {
        if t.connector.matched() {
            0
        } else {
            self.scene.reflections
        }
    }

    /// A path from `y` outside the volume to `aim` across it (refracted in and out,
    /// unscattered, reflected inside the parts it crosses as [`Self::exit_bounces`] draws from
    /// [`Self::most_bounces`]) or, with `way` = [`Way::Mirror`], reflected off its outside; its
    /// stretch before the volume past every surface (the caller checks the one after), and what it
    /// carries per unit intensity leaving `y`: `T (1 − R_in)(1 − R_out) / jacobian` (`R /
    /// jacobian` off the outside) over the inverse probability of drawing it, the `jacobian` of
    /// [`Connector::solve_across`] for a point, of [`Connector::solve_exit`] for a direction.
    pub(super) fn across(
        &self,
        t: &Tools,
        y: DVec3,
        aim: Aim,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<(Exit, f64)> {
        let first_only = self.scene.connections == Connections::First;
        let s = match way {
            Way::Mirror => t.connector.sample_mirror(y, aim, first_only, rng),
            _ => {
                let bounces = self.exit_bounces(t, 0, rng);
                t.connector.sample_across(y, aim, &bounces, first_only, rng)
            }
        };
        let (e, inverse_p) = self.tally(s, out)?;
        if self.scene.blocked(y, e.direction, e.before) {
            return None;
        }
        let transmittance = self.exit_transmittance(t, &e, 0, rng);
        Some((e, transmittance * e.transmission / e.jacobian * inverse_p))
    }

    /// The connection from the lit point `y` of a surface (unit `facing` normal on the lit side)
    /// to camera `i` (the orthographic cameras first, then the pinholes): straight, past no other
    /// surface and through the volume only where it is index-matched, or across the volume
    /// (refracted in and out: a surface seen through it); what it carries per unit intensity
    /// leaving `y`, as [`Self::camera_link`].
    #[allow(clippy::too_many_arguments)]
    pub(super) fn surface_camera_link(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        i: usize,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<CameraLink> {
        let n_out = t.flyer.volume.field.n_out;
        let orthographic = self.scene.cameras.len();
        match way {
            Way::Across | Way::Mirror => {
                return self.surface_camera_across(t, y, facing, i, way, rng, out);
            }
            Way::Bounces(0) => {}
            Way::Bounces(_) => return None,
        }
        if let Some(cam) = self.scene.cameras.get(i) {
            let w = cam.direction;
            let (a, b) = cam.fractions(y);
            let pixels = shares(cam.filter, a, b, cam.pixels);
            if pixels.1 == 0 {
                return None;
            }
            // a point beyond the image plane is not in the camera's view
            let to_plane = (cam.center - y).dot(w);
            if to_plane < 0.0 || w.dot(facing) <= 0.0 || self.scene.blocked(y, w, to_plane) {
                return None;
            }
            let (transmittance, inside) = self.past_volume(t, y, w, f64::INFINITY, rng)?;
            let radiance = transmittance / cam.pixel_area();
            return Some(CameraLink {
                camera: i,
                pixels,
                direction: w,
                radiance,
                total: radiance,
                delay: t.delay.outside(n_out * to_plane),
                inside,
                outside: to_plane - inside.total(),
                pdf: 1.0 / cam.area(),
                bounces: 0,
            });
        }
        let cam = &self.scene.pinholes[i - orthographic];
        let v = cam.position - y;
        let distance = v.length();
        let w = v / distance;
        let (a, b, cos) = cam.fractions(w)?;
        let pixels = shares(cam.filter, a, b, cam.pixels);
        if pixels.1 == 0 {
            return None;
        }
        if distance <= 0.0 || w.dot(facing) <= 0.0 || self.scene.blocked(y, w, distance) {
            return None;
        }
        let (transmittance, inside) = self.past_volume(t, y, w, distance, rng)?;
        let irradiance = transmittance / (distance * distance);
        Some(CameraLink {
            camera: i,
            pixels,
            direction: w,
            radiance: irradiance / (cos * cos * cos * cam.pixel_area()),
            total: irradiance,
            delay: t.delay.outside(n_out * distance),
            inside,
            outside: distance - inside.total(),
            pdf: 1.0 / cam.image_area(cos),
            bounces: 0,
        })
    }

    /// [`Self::surface_camera_link`] across the volume or off its outside (`way`).
    #[allow(clippy::too_many_arguments)]
    fn surface_camera_across(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        i: usize,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<CameraLink> {
        let aim = match self.scene.cameras.get(i) {
            Some(cam) => Aim::Along(cam.direction),
            None => Aim::Point(self.scene.pinholes[i - self.scene.cameras.len()].position),
        };
        let (e, carried) = self.across(t, y, aim, way, rng, out)?;
        if e.direction.dot(facing) <= 0.0 {
            return None;
        }
        self.link_to_camera(t, i, &e, || carried)
    }

    /// Free flights and scattering inside the volume from `ray` until the photon leaves (the next
    /// leg), is absorbed, or is given up.
    fn inside(
        &self,
        t: &Tools,
        mut ray: Ray,
        p: &mut Photon,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Leg> {
        let volume = t.flyer.volume;
        let derivatives = &self.scene.derivatives;
        let mut tracks: Tracks = [0.0; MAX_TARGETS];
        let mut reflections = Reflections::default();
        loop {
            tracks.fill(0.0);
            let (stop, travelled) =
                t.next_event_visiting(ray, rng, |a, b| self.track(a, b, &mut tracks));
            p.steps += travelled.steps;
            p.opl += travelled.opl;
            // the flight's score: `σ_t e^{−σ_t L}` to a collision, `e^{−σ_t L}` to the surface,
            // in the medium of the part it flew in
            let collided = matches!(stop, Stop::Collision(_));
            let part = if derivatives.is_empty() {
                None
            } else {
                volume.part_index(ray.x)
            };
            let coefficients = volume.coefficients(part);
            for (s, d) in p.score.iter_mut().zip(derivatives) {
                *s += flight_score(
                    d.medium_in(part),
                    collided,
                    coefficients.1,
                    travelled.length,
                );
            }
            // the flight's tracks count with its own score (they depend on its length)
            self.record_tracks(&tracks, p.weight, &p.score[..derivatives.len()], out);
            match stop {
                Stop::Collision(hit) => {
                    p.events += 1;
                    let albedo = volume.albedo_at(hit.x);
                    out[self.total(Total::Absorbed)].re += p.weight * (1.0 - albedo);
                    p.weight *= albedo;
                    for (s, d) in p.score.iter_mut().zip(derivatives) {
                        *s += albedo_score(d.medium_in(part), coefficients);
                    }
                    reflections = Reflections::default();
                    let w_in = hit.v.normalize();
                    if self.connects() {
                        let v = Vertex::fixed(hit.x, Some(w_in));
                        let score = &p.score[..derivatives.len()];
                        self.connect_photon(t, &v, (p.weight, p.opl), score, &[], rng, out);
                    }
                    if !p.roulette(rng) {
                        return None;
                    }
                    if p.events >= MAX_EVENTS {
                        out[self.total(Total::Unfinished)].re += p.weight;
                        return None;
                    }
                    let kind;
                    (ray, kind) = t.scatter_by(hit.x, w_in, rng);
                    if !derivatives.is_empty() {
                        // the scattering event's score: its particle type and direction
                        let mu = w_in.dot(ray.v.normalize());
                        let scattering = volume.scattering_of(part);
                        for (s, d) in p.score.iter_mut().zip(derivatives) {
                            *s += d
                                .medium_in(part)
                                .map_or(0.0, |m| m.dlog_event(scattering, kind, mu));
                        }
                    }
                }
                Stop::Boundary(end) => match Leg::leave(t, end, rng) {
                    Leg::Inside(reflected) if reflections.another() => ray = reflected,
                    Leg::Inside(_) => {
                        out[self.total(Total::Unfinished)].re += p.weight;
                        return None;
                    }
                    out => return Some(out),
                },
                Stop::Stuck => {
                    out[self.total(Total::Unfinished)].re += p.weight;
                    return None;
                }
            }
        }
    }
}

/// A free flight's score for medium parameter `param` (`∂ log` of its probability; `None`: not
/// a parameter of the medium flown through): `σ_t e^{−σ_t L}` to a collision, `e^{−σ_t L}` to
/// the surface, over geometric length `L`, in a medium of extinction `σ_t`. What the
/// flight itself tallies (a target's track) counts with it; what comes after a collision also
/// with [`albedo_score`].
pub(super) fn flight_score(param: Option<Param>, collided: bool, sigma_t: f64, length: f64) -> f64 {
    match param {
        Some(Param::SigmaS | Param::SigmaA) if collided => 1.0 / sigma_t - length,
        Some(Param::SigmaS | Param::SigmaA) => -length,
        _ => 0.0,
    }
}

/// The score of a collision's weight `σ_s/σ_t` (the albedo) for medium parameter `param`, in a
/// medium of coefficients `(σ_s, σ_t)`.
pub(super) fn albedo_score(param: Option<Param>, (sigma_s, sigma_t): (f64, f64)) -> f64 {
    match param {
        Some(Param::SigmaS) => 1.0 / sigma_s - 1.0 / sigma_t,
        Some(Param::SigmaA) => -1.0 / sigma_t,
        _ => 0.0,
    }
}

/// The distance to what a straight leg meets first, of the volume's surface `entry` and a
/// surface `(index, distance)` ([`ParticleTracer::ahead`]); infinite if neither.
pub(super) fn nearest(entry: Option<f64>, surface: Option<(usize, f64)>) -> f64 {
    let surface = surface.map_or(f64::INFINITY, |(_, b)| b);
    entry.map_or(surface, |a| a.min(surface))
}

/// Where a photon or a camera path is: inside the volume with its ray, or on a straight leg
/// outside it (`left_volume`: starting where it left the volume, so only a non-convex one can be
/// met again).
#[derive(Clone, Copy)]
pub(super) enum Leg {
    Inside(Ray),
    Outside {
        x: DVec3,
        d: DVec3,
        left_volume: bool,
    },
}

/// How a connection runs between its two ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Way {
    /// Along curved rays between two points inside, straight between two points outside, or
    /// through the surface between a point inside and one outside after this many reflections
    /// inside it.
    Bounces(usize),
    /// Across the volume between two points outside it, refracted into and out of each part it
    /// meets, reflected inside them as drawn ([`ParticleTracer::exit_bounces`]).
    Across,
    /// Off the volume's surface between two points outside it, reflected once outside it.
    Mirror,
}

impl Leg {
    /// The straight ray from `x` along unit `d` meets the volume's surface at distance `t0`:
    /// refract in, or reflect (Fresnel, total internal reflection) and stay outside.
    pub(super) fn enter(t: &Tools, x: DVec3, d: DVec3, t0: f64, rng: &mut Rng) -> Leg {
        let field = &t.flyer.volume.field;
        let n_out = field.n_out;
        let at = x + d * t0;
        let inside = x + d * crate::eikonal::trace::entry_parameter(t0);
        let n_in = t.flyer.n(inside);
        let normal = field.bounds.normal(at).unwrap_or(-d);
        let r = fresnel(d.dot(normal), n_out / n_in);
        let reflected = |d| Leg::Outside {
            x: at,
            d,
            left_volume: true,
        };
        if r > 0.0 && uniform(rng) < r {
            return reflected(reflect(d, normal));
        }
        match refract(d, normal, n_out / n_in) {
            Ok(w) => Leg::Inside(Ray {
                x: inside,
                v: w * n_in,
            }),
            Err(mirrored) => reflected(mirrored),
        }
    }

    /// The ray inside reaches the surface at `end`: leave refracted, or reflect back inside
    /// (Fresnel, total internal reflection).
    pub(super) fn leave(t: &Tools, end: Ray, rng: &mut Rng) -> Leg {
        let field = &t.flyer.volume.field;
        let n_out = field.n_out;
        let n_in = t.flyer.n(end.x);
        let d = end.v.normalize();
        let normal = field.bounds.normal(end.x).unwrap_or(d);
        let r = fresnel(d.dot(normal), n_in / n_out);
        match refract(d, -normal, n_in / n_out) {
            Ok(leaving) if r == 0.0 || uniform(rng) >= r => Leg::Outside {
                x: end.x,
                d: leaving,
                left_volume: true,
            },
            _ => Leg::Inside(Ray {
                x: end.x,
                v: reflect(d, normal) * n_in,
            }),
        }
    }
}

/// The reflections inside the surface a photon or path has made since its last event (or its
/// start), counted up to [`MAX_REFLECTIONS`], where every tracer gives it up.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Reflections(usize);

impl Reflections {
    /// Count one more reflection: `false` if there have been [`MAX_REFLECTIONS`] already (the
    /// photon or path is then given up).
    pub(super) fn another(&mut self) -> bool {
        if self.0 == MAX_REFLECTIONS {
            return false;
        }
        self.0 += 1;
        true
    }
}

/// A photon's state across its legs.
struct Photon {
    weight: f64,
    opl: f64,
    events: usize,
    steps: usize,
    /// Per differentiated parameter, `∂ log` of the path's probability and weight so far.
    score: [f64; MAX_DERIVATIVES],
}

impl Photon {
    /// Russian roulette once the weight is small: `false` if the photon dies.
    fn roulette(&mut self, rng: &mut Rng) -> bool {
        roulette(&mut self.weight, rng)
    }
}

/// Russian roulette on a photon's weight or a path's throughput once it is small: `false` if it
/// ends, else the survivor's weight raised to keep the estimate unbiased.
pub(super) fn roulette(weight: &mut f64, rng: &mut Rng) -> bool {
    *weight >= ROULETTE_BELOW || roulette_by(weight, uniform(rng))
}

/// [`roulette`] by the uniform `u`, drawn whatever the weight (so the random numbers after it do
/// not depend on whether the game was played).
pub(super) fn roulette_by(weight: &mut f64, u: f64) -> bool {
    if *weight < ROULETTE_BELOW {
        if u >= ROULETTE_SURVIVAL {
            return false;
        }
        *weight /= ROULETTE_SURVIVAL;
    }
    true
}

impl Estimator for ParticleTracer<'_> {
    /// With a time-modulated or dispersive field, each thread's copy of the volume and of the
    /// shifted volumes, set to each photon's phase and wavelength; the subpaths of bidirectional
    /// samples.
    type Scratch = (Option<(Volume, Vec<[Volume; 2]>)>, Subpaths);

    fn outputs(&self) -> usize {
        self.outputs
    }

    fn scratch(&self) -> Self::Scratch {
        let volume = (self.scene.modulation.is_some() || self.scene.spectrum.is_some())
            .then(|| (self.scene.volume.clone(), self.shifted.volumes.clone()));
        (volume, Subpaths::default())
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, scratch: &mut Self::Scratch, out: &mut [C64]) {
        use rand::{Rng as _, SeedableRng as _};
        let (volumes, subpaths) = scratch;
        for _ in 0..paths {
            // with even draws every photon draws from its own stream, so a photon drawing more or
            // fewer numbers as θ moves leaves the next photons' numbers where they were
            let mut own;
            let rng: &mut Rng = if self.even_draws {
                own = Rng::seed_from_u64(rng.next_u64());
                &mut own
            } else {
                &mut *rng
            };
            let Some((volume, shifted)) = volumes.as_mut() else {
                self.sample(&self.tools, &self.shifted.volumes, subpaths, rng, out);
                continue;
            };
            let mut instant = None;
            if let Some(Modulation::Sinusoidal) = self.scene.modulation {
                // the photon meets the field at a uniformly random instant of the period
                // (paper 002, App. C, Eq. 22)
                instant = Some(std::f64::consts::TAU * (uniform(rng) - 0.5));
            }
            let mut colour = [1.0; 3];
            let mut delay = Delay::NONE;
            let mut wavelength = None;
            if let Some(spectrum) = &self.scene.spectrum {
                // a single line draws nothing: its photons meet the random numbers of a render
                // without a spectrum
                let lambda = if spectrum.channels() == 1 {
                    spectrum.range_nm[0]
                } else {
                    spectrum.sample(uniform(rng))
                };
                colour = spectrum.colour(lambda);
                delay = spectrum.delay(lambda);
                wavelength = Some(lambda);
            }
            let at_photon = |field: &mut BoundedField, base: &BoundedField| {
                if let Some(omega_t) = instant {
                    modulate(field, base, omega_t);
                }
                if let (Some(spectrum), Some(lambda)) = (&self.scene.spectrum, wavelength) {
                    spectrum.disperse(field, base, lambda);
                }
            };
            at_photon(&mut volume.field, &self.scene.volume.field);
            for (pair, base) in shifted.iter_mut().zip(&self.shifted.volumes) {
                for (v, b) in pair.iter_mut().zip(base) {
                    at_photon(&mut v.field, &b.field);
                }
            }
            let mut tools = Tools::new(volume, self.scene, colour, delay);
            tools.instant = instant;
            self.sample(&tools, shifted, subpaths, rng, out);
        }
    }

    /// A scattering event costs at least its flight's leapfrog steps (each about a hundred output
    /// updates' worth for analytic fields: the flight's length, a mean free path or the volume's
    /// size, over the geometric length of a step), as many again for each connection (Newton's
    /// method traces the path at least once), and a pass over the sensors. A lower bound: the
    /// budget's pilot times the rest, and takes this as the floor of its measurement.
    fn event_cost(&self) -> f64 {
        let v = &self.scene.volume;
        let steps = if v.homogeneous() {
            1.0
        } else {
            let size = v
                .field
                .bounds
                .half_extent()
                .map_or(1.0, |h| 2.0 * h.max_element());
            let flight = if v.sigma_t() > 0.0 {
                size.min(1.0 / v.sigma_t())
            } else {
                size
            };
            (flight / (v.field.n_out * self.scene.step)).clamp(1.0, self.scene.max_steps as f64)
        };
        // each step evaluates the field (an ultrasonic profile sums many plane waves)
        let steps = steps * v.field.evaluation_cost();
        let mut connections =
            (self.scene.probes.len() + self.scene.cameras.len() + self.scene.pinholes.len()) as f64;
        if self.scene.tracing == Tracing::Bidirectional {
            // an event is joined to the other subpath's events too
            connections *= 2.0;
        }
        STEP_COST * steps * (1.0 + connections) + self.scene.sensors.len() as f64
    }
}

/// The cost of one leapfrog step of a simple analytic field, in output updates.
const STEP_COST: f64 = 100.0;

/// Set `field` to its instant `omega_t` of the ultrasound period: every ultrasonic amplitude
/// to `sin Ωt` times its amplitude in `base` (the same field unmodulated), every phased array to
/// the instant itself (in every part of a field of several volumes).
pub fn modulate(
    field: &mut crate::eikonal::BoundedField,
    base: &crate::eikonal::BoundedField,
    omega_t: f64,
) {
    use crate::eikonal::Profile;
    if let [Profile::Parts(base)] = base.profiles.as_slice() {
        field.change_parts(|k, p| modulate_profiles(&mut p.profiles, &base[k].profiles, omega_t));
        return;
    }
    modulate_profiles(&mut field.profiles, &base.profiles, omega_t);
}

/// [`modulate`] for the profiles of one field or part.
fn modulate_profiles(
    profiles: &mut [crate::eikonal::Profile],
    base: &[crate::eikonal::Profile],
    omega_t: f64,
) {
    use crate::eikonal::Profile;
    for (p, b) in profiles.iter_mut().zip(base) {
        match (p, b) {
            (Profile::Ultrasonic { n_max, .. }, Profile::Ultrasonic { n_max: full, .. }) => {
                *n_max = full * omega_t.sin();
            }
            (Profile::PhasedArray { omega_t: at, .. }, _) => *at = omega_t,
            _ => {}
        }
    }
}
