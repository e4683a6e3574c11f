//! Particle (light) tracing through a refractive, scattering volume.
//!
//! Photons leave the light with equal power, refract or reflect at the volume's surface with the
//! Fresnel probabilities, fly along curved rays (free-flight lengths drawn over geometric length,
//! paper 002 Eq. 5), scatter by the phase function with their weight times the albedo (the rest is
//! tallied as absorbed), and play Russian roulette once their weight is small. A photon that leaves
//! the volume travels straight and is recorded by every sensor plane it crosses, in the time bin of
//! its optical path length (Eq. 14). Each output is a fraction of the emitted power, so flux sensors
//! give total reflectance and transmittance, and `absorbed + escaped + unfinished = 1` in
//! expectation (and exactly for each photon when no roulette is played).
//!
//! Flux is conserved along ray tubes, so a photon's power needs no `n²` factor; connections to
//! probes and cameras carry the tube's exact cross-section (see [`super::connect`]), which is what
//! the conservation of basic radiance `L/n²` of the RRTE expresses.

use super::connect::{Connector, Sampled};
use super::flight::{Flight, Flyer, fresnel, reflect};
use super::scene::{Connections, Modulation, RenderScene, Volume};
use crate::eikonal::Ray;
use crate::eikonal::trace::refract;
use crate::math::{C64, Rng, uniform};
use crate::mc::Estimator;
use crate::speckle::paths::{ROULETTE_BELOW, ROULETTE_SURVIVAL};
use glam::DVec3;

/// Scattering events after which a photon is given up (counted as unfinished).
pub const MAX_EVENTS: usize = 1_000_000;

/// Indices of the totals after the sensors' outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Total {
    /// Power absorbed inside the volume.
    Absorbed = 0,
    /// Power that left the volume (recorded by a sensor or not).
    Escaped = 1,
    /// Power of photons given up: trapped beyond the step budget or [`MAX_EVENTS`].
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
}

/// How many totals follow the sensors.
pub const TOTALS: usize = 10;

/// The integrators of one volume: free flights and connections.
struct Tools<'v> {
    flyer: Flyer<'v>,
    connector: Connector<'v>,
}

impl<'v> Tools<'v> {
    fn new(volume: &'v Volume, scene: &RenderScene) -> Self {
        Tools {
            flyer: Flyer::new(volume, scene.step, scene.max_steps),
            connector: Connector::new(volume, scene.step, scene.max_steps),
        }
    }
}

/// The particle tracer of a scene, as an engine estimator.
pub struct ParticleTracer<'s> {
    scene: &'s RenderScene,
    tools: Tools<'s>,
    /// First output of each sensor, then of each probe.
    offsets: Vec<usize>,
    totals: usize,
}

impl<'s> ParticleTracer<'s> {
    pub fn new(scene: &'s RenderScene) -> Self {
        let mut offsets = Vec::with_capacity(scene.sensors.len());
        let mut at = 0;
        // with time bins, images hold the time-integrated frame first (its own errors: one
        // photon can reach a camera in several bins)
        let frames = scene.bins() + usize::from(scene.bins() > 1);
        for s in &scene.sensors {
            // the sensor's total power, then its images
            offsets.push(at + 1);
            at += 1 + s.pixel_count() * frames;
        }
        for _ in &scene.probes {
            // the probe's total fluence rate, then its time bins
            offsets.push(at + 1);
            at += 1 + scene.bins();
        }
        for c in &scene.cameras {
            // the camera's radiance summed over its pixels and bins, then its images
            offsets.push(at + 1);
            at += 1 + c.pixel_count() * frames;
        }
        for c in &scene.pinholes {
            // the irradiance at the pinhole from its field of view, then its images
            offsets.push(at + 1);
            at += 1 + c.pixel_count() * frames;
        }
        ParticleTracer {
            scene,
            tools: Tools::new(&scene.volume, scene),
            offsets,
            totals: at,
        }
    }

    /// The first output of probe `i` (its time bins).
    pub fn probe_offset(&self, i: usize) -> usize {
        self.offsets[self.scene.sensors.len() + i]
    }

    /// The first output of camera `i` (its images, time bin after time bin).
    pub fn camera_offset(&self, i: usize) -> usize {
        self.offsets[self.scene.sensors.len() + self.scene.probes.len() + i]
    }

    /// The first output of pinhole camera `i` (its images).
    pub fn pinhole_offset(&self, i: usize) -> usize {
        let s = self.scene;
        self.offsets[s.sensors.len() + s.probes.len() + s.cameras.len() + i]
    }

    /// The output holding the irradiance at pinhole `i` from its field of view.
    pub fn pinhole_total(&self, i: usize) -> usize {
        self.pinhole_offset(i) - 1
    }

    /// The output holding the sum of camera `i`'s pixels over all time bins.
    pub fn camera_total(&self, i: usize) -> usize {
        self.camera_offset(i) - 1
    }

    /// The output holding probe `i`'s fluence rate over all time bins.
    pub fn probe_total(&self, i: usize) -> usize {
        self.probe_offset(i) - 1
    }

    /// Whether scattering events are connected to probes or cameras.
    fn connects(&self) -> bool {
        !self.scene.probes.is_empty()
            || !self.scene.cameras.is_empty()
            || !self.scene.pinholes.is_empty()
    }

    /// Next-event connections from `x` (inside) to every probe and camera: power `weight` leaving
    /// `x` with angular density `emit(d)` per steradian along unit `d`, having travelled the
    /// optical path `opl`. A probe receives `weight · emit(d) · T / (dA⊥/dω)` over the stationary
    /// paths; a camera's pixel `weight · emit(d) · T · (1 − R) / (dω_out/dω) / pixel area`.
    #[allow(clippy::too_many_arguments)]
    fn connect(
        &self,
        t: &Tools,
        x: DVec3,
        weight: f64,
        opl: f64,
        emit: impl Fn(DVec3) -> f64,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let sigma_t = self.scene.volume.sigma_t();
        for (i, probe) in self.scene.probes.iter().enumerate() {
            let s = match self.scene.connections {
                Connections::Unbiased => t.connector.sample(x, probe.position, rng),
                Connections::First => t.connector.sample_first(x, probe.position, rng),
            };
            let Some((c, inverse_p)) = self.tally(s, out) else {
                continue;
            };
            let value =
                weight * emit(c.direction) * (-sigma_t * c.length).exp() / c.spread * inverse_p;
            if !(value > 0.0 && value.is_finite()) {
                continue;
            }
            let Some(bin) = self.bin(opl + c.optical_path) else {
                continue;
            };
            let o = self.probe_offset(i);
            out[o + bin].re += value;
            out[o - 1].re += value;
        }
        let first_only = self.scene.connections == Connections::First;
        let n_out = self.scene.volume.field.n_out;
        for (i, cam) in self.scene.cameras.iter().enumerate() {
            let s = t.connector.sample_exit(x, cam.direction, first_only, rng);
            let Some((e, inverse_p)) = self.tally(s, out) else {
                continue;
            };
            let Some(pixel) = cam.pixel(e.surface) else {
                continue;
            };
            let value = weight * emit(e.direction) * (-sigma_t * e.length).exp() * e.transmission
                / e.jacobian
                / cam.pixel_area()
                * inverse_p;
            if !(value > 0.0 && value.is_finite()) {
                continue;
            }
            let outside = n_out * (cam.center - e.surface).dot(cam.direction).max(0.0);
            let Some(bin) = self.bin(opl + e.optical_path + outside) else {
                continue;
            };
            self.record(
                out,
                self.camera_offset(i),
                cam.pixel_count(),
                bin,
                pixel,
                value,
            );
        }
        for (i, cam) in self.scene.pinholes.iter().enumerate() {
            let s = t.connector.sample_through(x, cam.position, first_only, rng);
            let Some((e, inverse_p)) = self.tally(s, out) else {
                continue;
            };
            let Some((pixel, cos)) = cam.pixel(e.outgoing) else {
                continue;
            };
            // irradiance at the pinhole, and radiance over the pixel's image-plane area
            // (dω = cos³θ dA at unit distance)
            let irradiance =
                weight * emit(e.direction) * (-sigma_t * e.length).exp() * e.transmission
                    / e.jacobian
                    * inverse_p;
            if !(irradiance > 0.0 && irradiance.is_finite()) {
                continue;
            }
            let Some(bin) = self.bin(opl + e.optical_path) else {
                continue;
            };
            let o = self.pinhole_offset(i);
            let radiance = irradiance / (cos * cos * cos * cam.pixel_area());
            self.record_image(out, o, cam.pixel_count(), bin, pixel, radiance);
            out[o - 1].re += irradiance;
        }
    }

    /// Count a connection's work in the statistics, and return its path and inverse probability.
    fn tally<T>(&self, s: Sampled<T>, out: &mut [C64]) -> Option<(T, f64)> {
        out[self.total(Total::Connections)].re += 1.0;
        out[self.total(Total::Solves)].re += s.solves as f64;
        out[self.total(Total::Iterations)].re += s.iterations as f64;
        if s.path.is_some() {
            out[self.total(Total::Connected)].re += 1.0;
            out[self.total(Total::Distinct)].re += s.distinct as f64;
        }
        s.path
    }

    /// The first output of sensor `i` (its images follow, see [`ParticleTracer::frame`]; each a
    /// row-major image).
    pub fn offset(&self, i: usize) -> usize {
        self.offsets[i]
    }

    /// The first output of a frame of an image of `pixels` pixels starting at `first` (a sensor's
    /// or camera's offset): time bin `bin`, or (`None`) the time-integrated frame.
    pub fn frame(&self, first: usize, pixels: usize, bin: Option<usize>) -> usize {
        let binned = usize::from(self.scene.bins() > 1);
        match bin {
            None => first,
            Some(b) => first + (b + binned) * pixels,
        }
    }

    /// Add `value` to `pixel` of the image at `first` in time bin `bin` (and to the integrated
    /// frame and the total before it).
    fn record(
        &self,
        out: &mut [C64],
        first: usize,
        pixels: usize,
        bin: usize,
        pixel: usize,
        value: f64,
    ) {
        self.record_image(out, first, pixels, bin, pixel, value);
        out[first - 1].re += value;
    }

    /// [`ParticleTracer::record`] without the total.
    fn record_image(
        &self,
        out: &mut [C64],
        first: usize,
        pixels: usize,
        bin: usize,
        pixel: usize,
        value: f64,
    ) {
        out[self.frame(first, pixels, Some(bin)) + pixel].re += value;
        if self.scene.bins() > 1 {
            out[first + pixel].re += value;
        }
    }

    /// The time bin of optical path `path` (`None` past the last bin).
    fn bin(&self, path: f64) -> Option<usize> {
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
        self.offsets[i] - 1
    }

    /// The output index of total `t`.
    pub fn total(&self, t: Total) -> usize {
        self.totals + t as usize
    }

    /// Record a photon of `weight` that left the volume at `x` along unit `d`, having travelled the
    /// optical path `opl`.
    fn escape(&self, x: DVec3, d: DVec3, weight: f64, opl: f64, out: &mut [C64]) {
        out[self.total(Total::Escaped)].re += weight;
        let n_out = self.scene.volume.field.n_out;
        for (s, &offset) in self.scene.sensors.iter().zip(&self.offsets) {
            let Some((pixel, t)) = s.hit(x, d) else {
                continue;
            };
            let Some(bin) = self.bin(opl + n_out * t) else {
                continue;
            };
            self.record(out, offset, s.pixel_count(), bin, pixel, weight);
        }
    }

    /// Trace one photon, adding its contributions to `out`.
    fn photon(&self, t: &Tools, rng: &mut Rng, out: &mut [C64]) {
        let volume = &self.scene.volume;
        let bounds = &volume.field.bounds;
        let n_out = volume.field.n_out;
        let (mut x, mut d) =
            self.scene
                .light
                .sample([uniform(rng), uniform(rng), uniform(rng), uniform(rng)]);
        let mut opl = 0.0;
        let mut steps = 0usize;
        let mut events = 0usize;
        let mut weight = 1.0;
        // enter the volume from outside, or start inside it
        let mut ray = if bounds.contains(x) {
            if self.connects() {
                let light = &self.scene.light;
                self.connect(t, x, weight, 0.0, |d| light.intensity(d), rng, out);
            }
            Ray {
                x,
                v: d * t.flyer.n(x),
            }
        } else {
            match bounds.interval(x, d) {
                Some((t0, t1)) if t1 > 0.0 && t0 >= 0.0 => {
                    let surface = x + d * t0;
                    opl += n_out * t0;
                    let inside = x + d * crate::eikonal::trace::entry_parameter(t0);
                    let n_in = t.flyer.n(inside);
                    let normal = bounds.normal(surface).unwrap_or(-d);
                    let r = fresnel(d.dot(normal), n_out / n_in);
                    if r > 0.0 && uniform(rng) < r {
                        self.escape(surface, reflect(d, normal), weight, opl, out);
                        return;
                    }
                    match refract(d, normal, n_out / n_in) {
                        Ok(t) => d = t,
                        Err(reflected) => {
                            self.escape(surface, reflected, weight, opl, out);
                            return;
                        }
                    }
                    x = inside;
                    Ray { x, v: d * n_in }
                }
                // it misses the volume
                _ => {
                    self.escape(x, d, weight, opl, out);
                    return;
                }
            }
        };
        let sigma_t = volume.sigma_t();
        let albedo = volume.albedo();
        let finish = |out: &mut [C64], events: usize, steps: usize| {
            out[self.total(Total::Events)].re += events as f64;
            out[self.total(Total::Steps)].re += steps as f64;
        };
        loop {
            let distance = if sigma_t > 0.0 {
                -(1.0 - uniform(rng)).ln() / sigma_t
            } else {
                f64::INFINITY
            };
            let (flight, k) = t.flyer.fly(ray, distance);
            steps += k;
            match flight {
                Flight::Collision {
                    ray: hit,
                    optical_path,
                } => {
                    opl += optical_path;
                    events += 1;
                    out[self.total(Total::Absorbed)].re += weight * (1.0 - albedo);
                    weight *= albedo;
                    let w_in = hit.v.normalize();
                    if self.connects() {
                        let phase = |d: DVec3| volume.scattering.eval(w_in.dot(d));
                        self.connect(t, hit.x, weight, opl, phase, rng, out);
                    }
                    if weight < ROULETTE_BELOW {
                        if uniform(rng) >= ROULETTE_SURVIVAL {
                            break;
                        }
                        weight /= ROULETTE_SURVIVAL;
                    }
                    if events >= MAX_EVENTS {
                        out[self.total(Total::Unfinished)].re += weight;
                        break;
                    }
                    let kind = volume.scattering.pick(|| uniform(rng));
                    let w = volume
                        .scattering
                        .phase(kind)
                        .sample(w_in, uniform(rng), uniform(rng));
                    ray = Ray {
                        x: hit.x,
                        v: w * t.flyer.n(hit.x),
                    };
                }
                Flight::Boundary {
                    ray: end,
                    optical_path,
                } => {
                    opl += optical_path;
                    let n_in = t.flyer.n(end.x);
                    let d = end.v.normalize();
                    let normal = bounds.normal(end.x).unwrap_or(d);
                    let r = fresnel(d.dot(normal), n_in / n_out);
                    let leaves = match refract(d, -normal, n_in / n_out) {
                        Ok(t) if r == 0.0 || uniform(rng) >= r => Some(t),
                        _ => None,
                    };
                    match leaves {
                        Some(t) => {
                            self.escape(end.x, t, weight, opl, out);
                            break;
                        }
                        None => {
                            // Fresnel or total internal reflection: back inside
                            ray = Ray {
                                x: end.x,
                                v: reflect(d, normal) * n_in,
                            };
                        }
                    }
                }
                Flight::Stuck { .. } => {
                    out[self.total(Total::Unfinished)].re += weight;
                    break;
                }
            }
        }
        finish(out, events, steps);
    }
}

impl Estimator for ParticleTracer<'_> {
    /// With a time-modulated field, each thread's copy of the volume, set to each photon's phase.
    type Scratch = Option<Volume>;

    fn outputs(&self) -> usize {
        self.totals + TOTALS
    }

    fn scratch(&self) -> Option<Volume> {
        self.scene.modulation.map(|_| self.scene.volume.clone())
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, scratch: &mut Option<Volume>, out: &mut [C64]) {
        for _ in 0..paths {
            match (self.scene.modulation, scratch.as_mut()) {
                (Some(Modulation::Sinusoidal), Some(volume)) => {
                    // the photon meets the field at a uniformly random time of the period
                    // (paper 002, App. C, Eq. 22): every ultrasonic amplitude times sin θ
                    let theta = std::f64::consts::PI * (uniform(rng) - 0.5);
                    modulate(&mut volume.field, &self.scene.volume.field, theta.sin());
                    let tools = Tools::new(volume, self.scene);
                    self.photon(&tools, rng, out);
                }
                _ => self.photon(&self.tools, rng, out),
            }
        }
    }

    /// A scattering event costs its flight's leapfrog steps (each about a hundred output updates'
    /// worth for analytic fields: the flight's length, a mean free path or the volume's size, over
    /// the geometric length of a step) and a pass over the sensors.
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
        // a connection: a few Newton solves of a few iterations, each a flight's worth of steps
        let connections = self.scene.probes.len() as f64 * if v.homogeneous() { 1.0 } else { 30.0 }
            + (self.scene.cameras.len() + self.scene.pinholes.len()) as f64 * 30.0;
        STEP_COST * steps * (1.0 + connections) + self.scene.sensors.len() as f64
    }
}

/// The cost of one leapfrog step of a simple analytic field, in output updates.
const STEP_COST: f64 = 100.0;

/// Set every ultrasonic profile of `field` to `scale` times its amplitude in `base` (the same
/// field unmodulated).
pub fn modulate(
    field: &mut crate::eikonal::BoundedField,
    base: &crate::eikonal::BoundedField,
    scale: f64,
) {
    use crate::eikonal::Profile;
    for (p, b) in field.profiles.iter_mut().zip(&base.profiles) {
        if let (Profile::Ultrasonic { n_max, .. }, Profile::Ultrasonic { n_max: n0, .. }) = (p, b) {
            *n_max = n0 * scale;
        }
    }
}
