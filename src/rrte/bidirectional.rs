//! Bidirectional path tracing with multiple importance sampling (paper 002 Sec. 3, after Veach
//! and Guibas 1995 and Lafortune and Willems 1996): the same camera images as particle and path
//! tracing, from every way of joining a subpath from the light to one from the camera.
//!
//! Each sample traces one subpath from the light (a photon: power after the albedo at each event)
//! and, per camera, one from the camera (throughput in basic radiance), both with the free flights,
//! Fresnel splits, phase-function sampling and diffuse surfaces of the other two tracers (under a
//! thin collimated beam, a camera subpath's flights from its events draw half their collisions in
//! the beam's tube, and in an optically thin volume its first leg in half along the leg and half
//! its scattering directions aimed at the tube: see `beam_tube`). A path of `k` scattering events
//! `v_1 … v_k` (inside the volume or on a surface) can then be made `k + 1` ways: `s` events from
//! the light and `t = k − s` from the camera, joined by a connection: the light to a camera event
//! (`s = 0`, path tracing's next event), a light event to the camera (`t = 0`, particle tracing's),
//! or a light event to a camera event (the light event seen as a point source of intensity `w ρ`,
//! or `w cos θ / π` on a surface, the camera event as a point sensor). Between two events inside
//! the volume the connection runs along curved rays (see [`super::connect`]), reflected inside the
//! surface up to `render.reflections` times (between two events in one of several volumes, also out
//! of it and back in, having reflected inside another or, in a shape that is not convex,
//! unreflected and across other stretches of it); between an event inside and one on a surface it
//! leaves the volume through its surface, refracted once; between two surfaces it is straight, past
//! the volume only where it is index-matched, runs across the volume, refracted in and out, or
//! reflects off its outside. Leaving or across, it also crosses every part of a shape that is not
//! convex it meets again on the way (refracted in and out of each). Unscattered light from a light
//! inside the volume is connected to the cameras directly (the one way to make it). Flux sensors,
//! screens, fluence probes and the light reaching each surface are estimated by the light subpaths
//! alone, as in particle tracing: the sensor planes they cross, their events connected to the
//! probes, the surfaces they meet.
//!
//! The estimates are weighted by the balance heuristic over the strategies that can make the path:
//! `w_s = p_s / Σ_j p_j`, with `p_j` the density strategy `j` gives the path's vertices. A
//! connection reflects inside the surface at most `render.reflections` times, between two points
//! inside or on its way between a point inside and one outside (refracted once there, then in and
//! out of each part it meets again), where it meets the surface no other way; between two points
//! outside a volume that is not index-matched it refracts never, or in and out of each part it
//! crosses, or reflects once off its outside (and no more). Which segments a connection makes is
//! read from the surface events met while tracing them, in order (`Meetings`). A
//! segment that no connection makes is made only by tracing: the strategies that would connect
//! across it are left out of the sum; for a beam the light's own (`s = 0`, its disc joined to a
//! camera event as path tracing joins it) is tried and counted only near the beam
//! ([`super::scene::BEAM_REACH`]). The weights use the straight-ray density of each segment —
//! `ρ σ_t e^{−σ_t ℓ}/ℓ²` over its geometric length `ℓ` (the tube of parallel rays from a beam or an
//! orthographic camera: no `1/ℓ²`; `ℓ` from the focus of a focused beam, whose density is per
//! solid angle there; per unit area at a surface, times `|cos θ|` there), the phase
//! functions or the surfaces' `cos θ / π` at both ends, and the sources' own densities — so in a
//! graded index they are an approximation of the true densities; any weights that sum to one over
//! the strategies that can make each path keep the estimate unbiased, and these are the same
//! function of the path whichever strategy made it. The contributions themselves carry the exact
//! connections (ray tubes, transmittance, Fresnel).
//!
//! What no strategy makes: paths on which every segment reflects at the surface, or refracts
//! there, more often than a connection does (with an index-matched surface there are none).

use super::beam_tube::{FREE_SHARE, Forced, PHASE_SHARE};
use super::connect::{Aim, InsidePath, MAX_AGAIN};
use super::particle::{Leg, MAX_EVENTS, ParticleTracer, Reflections, Stop, Tools, Way, roulette};
use super::scene::{Connections, Light, PartLengths, Rays, Volume};
use crate::eikonal::Ray;
use crate::math::{C64, Rng, uniform};
use glam::DVec3;

/// A scattering event of a subpath: inside the volume, or on a diffuse surface.
#[derive(Clone, Copy, Debug)]
pub(super) struct Vertex {
    x: DVec3,
    /// Unit direction of travel arriving at `x` (the subpath's own).
    arrive: DVec3,
    /// Unit direction the subpath left along (unset at its last event).
    leave: DVec3,
    /// The subpath's density of leaving along `leave`, per solid angle: the phase function
    /// between `arrive` and it (for a camera subpath aiming at a beam's tube, the mixture with
    /// the aimed draws), or on a surface `cos θ / π` (unset at its last event).
    rho: f64,
    /// The phase function between `arrive` and `leave` (on a surface `cos θ / π`): the density
    /// of a light subpath, the same both ways.
    phase: f64,
    /// The weight after the albedo at `x`: a photon's power, or a camera path's throughput.
    beta: f64,
    /// Optical path (group delay) from the subpath's start.
    opl: f64,
    /// The segment that reached `x`.
    segment: Segment,
    /// On a surface: its unit normal on the lit side.
    facing: Option<DVec3>,
}

impl Vertex {
    /// The density of leaving `x` along unit `d` given the arrival, per solid angle: the phase
    /// function, or a surface's `cos θ / π`.
    fn rho_towards(&self, volume: &Volume, d: DVec3) -> f64 {
        match self.facing {
            Some(n) => lambert(n, d),
            None => volume.scattering_at(self.x).eval(self.arrive.dot(d)),
        }
    }

    /// A camera subpath's density of leaving this event of its own along unit `d`, whose
    /// [`Self::rho_towards`] is `phase`: with the draws aimed at a beam's tube (`aimed`) where
    /// there are any.
    fn camera_rho(&self, phase: f64, d: DVec3, aimed: Option<AimDensity>) -> f64 {
        match self.facing {
            Some(_) => phase,
            None => camera_density(phase, aimed.map(|q| q(self.x, self.arrive, d))),
        }
    }
}

/// A Lambertian surface's density of leaving along unit `d` (its unit normal `n` on the lit
/// side): `cos θ / π`, zero below it.
fn lambert(n: DVec3, d: DVec3) -> f64 {
    n.dot(d).max(0.0) / std::f64::consts::PI
}

/// The density of a camera subpath aiming at a beam's tube of drawing a unit direction aimed at
/// it from an event inside, `(x, arrive, d)` ([`super::beam_tube::BeamTube::aim_density`]).
type AimDensity<'a> = &'a dyn Fn(DVec3, DVec3, DVec3) -> f64;

/// A camera subpath's density of leaving an event inside along a direction whose phase
/// function is `phase`: that, or where it aims at a beam's tube (`aimed`, the aimed draw's
/// density of it), the mixture.
fn camera_density(phase: f64, aimed: Option<f64>) -> f64 {
    match aimed {
        Some(q) => PHASE_SHARE * phase + (1.0 - PHASE_SHARE) * q,
        None => phase,
    }
}

/// Whether a connection reflected off the volume's outside (`way`) then runs `inside` through
/// parts of it (a shape that is not convex): no strategy's weight counts it as a connection
/// ([`Meetings::connectible`]), so it is made by tracing alone.
fn crosses_after_mirror(way: Way, inside: f64) -> bool {
    way == Way::Mirror && inside > 0.0
}

/// A segment of a path as the weights see it.
#[derive(Clone, Copy, Debug)]
struct Segment {
    /// `e^{−∫σ_t}/ℓ²` over its geometric length (`∫σ_t` inside: through several volumes each
    /// stretch at its own volume's `σ_t`; `ℓ` counts the straight stretches outside too), without
    /// the `1/ℓ²` from a collimated beam or an orthographic camera, `ℓ` from the focus of a
    /// focused beam.
    g: f64,
    /// `|cos θ|` at its start and at its end where they lie on a surface (1 elsewhere): the
    /// density per unit area there is the solid angle's times `g` times it.
    cos_start: f64,
    cos_end: f64,
    /// Whether a connection can make it.
    connectible: bool,
    /// Where it runs between two events inside the volume meeting the surface only by reflecting
    /// inside it, and the camera subpaths draw such flights' legs from a beam's tube
    /// ([`super::beam_tube`]): the factor the tube's mixture gives the density of its end from
    /// the camera's side (1 elsewhere).
    forced: f64,
}

impl Segment {
    fn new(
        volume: &Volume,
        inside: &PartLengths,
        outside: f64,
        rays: Rays,
        connectible: bool,
    ) -> Self {
        let spread = rays.spread(inside.total() + outside);
        Segment {
            g: (-inside.depth(volume)).exp() / spread,
            cos_start: 1.0,
            cos_end: 1.0,
            connectible,
            forced: 1.0,
        }
    }

    /// The segment with the tube's factor of the density of its end from the camera's side.
    fn with_forced(self, forced: f64) -> Self {
        Segment { forced, ..self }
    }

    /// The segment with the cosines at its ends.
    fn with_cos(self, cos_start: f64, cos_end: f64) -> Self {
        Segment {
            cos_start,
            cos_end,
            ..self
        }
    }

    /// The same segment run the other way.
    fn reversed(self) -> Self {
        Segment {
            cos_start: self.cos_end,
            cos_end: self.cos_start,
            ..self
        }
    }
}

/// The parts holding the two ends of a segment between two points inside a volume of several
/// parts or a shape that is not convex, as far as a connection's reach needs them.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Ends {
    /// Two parts (`from`, `to`).
    Apart(usize, usize),
    /// One part that is not convex.
    Around(usize),
    /// One convex part beside others.
    Back(usize),
}

impl Ends {
    /// The parts the segment starts and ends in.
    fn parts(self) -> (usize, usize) {
        match self {
            Ends::Apart(from, to) => (from, to),
            Ends::Around(k) | Ends::Back(k) => (k, k),
        }
    }
}

/// The surface events of a traced segment, as far as a connection's reach needs them.
#[derive(Clone, Copy, Debug, Default)]
struct Meetings {
    /// Every meeting with the volume's surface: refractions in and out, reflections inside
    /// (`bounces`) and off the outside (`glances`).
    all: usize,
    bounces: usize,
    glances: usize,
    /// Whether the segment has left the volume, the reflections inside before it first did (all
    /// of them while it has not), and those since it last entered.
    left: bool,
    bounces_before_leaving: usize,
    bounces_since_entry: usize,
    /// Of several volumes, the ones entered before the last entry (bits), and the last entered.
    entered_before: u32,
    last_entered: Option<usize>,
}

impl Meetings {
    /// The segment met the surface from outside: entered `part` (of several volumes), or
    /// reflected off it (`glanced`).
    fn met_outside(&mut self, glanced: bool, part: Option<usize>) {
        self.all += 1;
        if glanced {
            self.glances += 1;
            return;
        }
        self.bounces_since_entry = 0;
        if let Some(k) = self.last_entered {
            self.entered_before |= 1 << k;
        }
        self.last_entered = part;
    }

    /// The segment met the surface from inside: left, or reflected inside (`bounced`).
    fn met_inside(&mut self, bounced: bool) {
        self.all += 1;
        if !bounced {
            self.left = true;
            return;
        }
        self.bounces += 1;
        self.bounces_since_entry += 1;
        if !self.left {
            self.bounces_before_leaving += 1;
        }
    }

    /// Whether a connection makes the segment, from a point inside or outside the volume
    /// (`began_inside`) to one inside or outside (`ends_inside`), given the most reflections
    /// inside it follows and whether the volume is index-matched. Between a point inside and one
    /// outside a connection reflects inside the part it starts from and then refracts out, into
    /// and out of the parts it meets (of several volumes or a shape that is not convex),
    /// reflecting inside them too, `most_bounces` times in all, each stretch inside a part
    /// crossed one of [`MAX_AGAIN`] at most; it reflects nowhere outside; between two points
    /// inside one volume it only reflects
    /// inside, as often; between points inside two of several volumes ([`Ends::Apart`])
    /// it leaves the one, crosses any other it meets (in and out) and enters the other,
    /// reflecting inside any of them `most_bounces` times in all, its stretches after the one it
    /// starts with (each part crossed one and one per reflection inside it, the end's part one
    /// and its reflections) [`MAX_AGAIN`] at most from either end (so the connection, which
    /// keeps to that, makes the same paths from either end); between two points in one part
    /// that is not convex ([`Ends::Around`]) it either stays within it, only reflecting
    /// inside, or leaves it, crosses any other part it meets (and other stretches of its own)
    /// and enters it again, reflecting as between two parts; between two points in one convex
    /// part of several ([`Ends::Back`]) likewise, but it comes back only having reflected, and
    /// fewer times in the part before it leaves and after it comes back than in all (so that
    /// it makes the same paths from either end); between two points
    /// outside it either never meets the surface (straight, also across an index-matched
    /// volume), refracts into and out of the parts it meets, reflecting inside them
    /// `most_bounces` times in all, with `1 + MAX_AGAIN` stretches inside at most, or only
    /// reflects once off the outside. (A path off the outside that then crosses parts is made by
    /// particle and path tracing, not here: its reflection would have to come first from
    /// whichever end the connection starts.)
    fn connectible(
        &self,
        (began_inside, ends_inside): (bool, bool),
        between: Option<Ends>,
        most_bounces: usize,
        matched: bool,
    ) -> bool {
        let refractions = self.all - self.bounces - self.glances;
        if let Some(ends) = between {
            let (from, to) = ends.parts();
            if from == to && !self.left {
                return self.all == self.bounces && self.bounces <= most_bounces;
            }
            let fewest_at_an_end = self.bounces_before_leaving.min(self.bounces_since_entry);
            let most_at_an_end = self.bounces_before_leaving.max(self.bounces_since_entry);
            if matches!(ends, Ends::Back(_)) && most_at_an_end >= self.bounces {
                return false;
            }
            // out of one part and into the other: two refractions more than the parts crossed
            let crossed = refractions.saturating_sub(2) / 2;
            return ends_inside
                && self.glances == 0
                && self.bounces <= most_bounces
                && (matches!(ends, Ends::Around(_))
                    || self.entered_before & (1 << from | 1 << to) == 0)
                && crossed + 1 + self.bounces - fewest_at_an_end <= MAX_AGAIN;
        }
        if began_inside != ends_inside {
            let first_part = if began_inside {
                self.bounces_before_leaving
            } else {
                self.bounces_since_entry
            };
            // after it leaves the start's part: two refractions and the reflections inside
            // each part it crosses, a stretch inside for each
            let crossed = refractions.saturating_sub(1) / 2;
            self.glances == 0
                && self.bounces <= most_bounces
                && crossed + self.bounces - first_part <= MAX_AGAIN
        } else if ends_inside {
            self.all == self.bounces && self.bounces <= most_bounces
        } else {
            self.all == 0
                || matched
                || (self.glances == 0
                    && self.bounces <= most_bounces
                    && refractions / 2 + self.bounces <= 1 + MAX_AGAIN)
                || (self.all == 1 && self.glances == 1)
        }
    }
}

/// The subpaths of one sample, kept between samples (tracing allocates nothing once they have
/// grown).
#[derive(Debug, Default)]
pub struct Subpaths {
    light: Vec<Vertex>,
    camera: Vec<Vertex>,
}

/// The path `y_1 … y_s` (from the light), a connecting segment, `z_t … z_1` (from the camera),
/// as the balance heuristic sees it: `v_i = y_i` for `i ≤ s`, `v_i = z_{k+1−i}` beyond.
struct Joined<'a> {
    light: &'a [Vertex],
    camera: &'a [Vertex],
    /// The light's density of the first segment's direction (for a collimated beam, of its start
    /// per unit area of the disc; for a focused one, per solid angle at its focus), the camera's
    /// of the last.
    light_pdf: f64,
    camera_pdf: f64,
    /// The connecting segment, from `y_s` (or the light) to `z_t` (or the camera).
    link: Segment,
    /// The densities of leaving along the link at its ends, `y_s` and `z_t`, each its own
    /// subpath's.
    rho_light: f64,
    rho_camera: f64,
    /// The unit direction leaving `y_s` along the link, and the phase function at `z_t` between
    /// its arrival and the link (on a surface `cos θ / π`): the light's density there.
    leave_light: DVec3,
    phase_camera: f64,
    /// Where the camera subpaths aim at a beam's tube, the aimed draws' density.
    aimed: Option<AimDensity<'a>>,
}

impl Joined<'_> {
    fn s(&self) -> usize {
        self.light.len()
    }

    fn k(&self) -> usize {
        self.light.len() + self.camera.len()
    }

    /// Segment `j`, from `v_j` to `v_{j+1}` (`v_0` the light, `v_{k+1}` the camera).
    fn segment(&self, j: usize) -> Segment {
        let s = self.s();
        if j < s {
            self.light[j].segment
        } else if j == s {
            self.link
        } else {
            // traced from the camera: from v_{j+1} to v_j
            self.camera[self.k() - j].segment.reversed()
        }
    }

    /// The density at `v_i` of leaving towards `v_{i+1}` (`ahead`, as the light subpath
    /// would) or towards `v_{i−1}` (as the camera subpath would), per solid angle (the phase
    /// function is the same both ways: reversing both directions keeps their angle; a surface's
    /// `cos θ / π` is not, nor are a camera subpath's draws aimed at a beam's tube).
    fn rho(&self, i: usize, ahead: bool) -> f64 {
        let s = self.s();
        if i <= s {
            let y = &self.light[i - 1];
            let (traced, leave) = if i == s {
                (self.rho_light, self.leave_light)
            } else {
                (y.rho, y.leave)
            };
            match (ahead, y.facing) {
                (true, _) => traced,
                (false, Some(n)) => lambert(n, -y.arrive),
                // the camera arrives along −leave and leaves along −arrive
                (false, None) => {
                    camera_density(traced, self.aimed.map(|q| q(y.x, -leave, -y.arrive)))
                }
            }
        } else {
            let z = &self.camera[self.k() - i];
            let link = i == s + 1;
            match (ahead, z.facing) {
                (false, _) if link => self.rho_camera,
                (false, _) => z.rho,
                (true, Some(n)) => lambert(n, -z.arrive),
                (true, None) if link => self.phase_camera,
                (true, None) => z.phase,
            }
        }
    }

    /// The density of `v_i` traced from the light (per unit volume, without `σ_t(v_i)`, which
    /// the density from the camera has too; per unit area on a surface).
    fn forward(&self, i: usize) -> f64 {
        let start = if i == 1 {
            self.light_pdf
        } else {
            self.rho(i - 1, true)
        };
        let segment = self.segment(i - 1);
        start * segment.g * segment.cos_end
    }

    /// The density of `v_i` traced from the camera (a flight from an event inside drawn from
    /// the beam's tube where there is one).
    fn backward(&self, i: usize) -> f64 {
        let start = if i == self.k() {
            self.camera_pdf
        } else {
            self.rho(i + 1, false)
        };
        let segment = self.segment(i);
        start * segment.g * segment.forced * segment.cos_start
    }

    /// Whether strategy `j` (connecting segment `j`) can make the path.
    fn available(&self, j: usize) -> bool {
        self.segment(j).connectible && (j > 0 || self.light_pdf > 0.0)
    }

    /// The balance heuristic's weight of the strategy that made the path, `p_s / Σ_j p_j`, from
    /// the ratios of neighbouring strategies' densities, `p_j / p_{j−1} = forward(j) /
    /// backward(j)`.
    fn weight(&self) -> f64 {
        let (s, k) = (self.s(), self.k());
        let mut sum = 1.0;
        let mut ratio = 1.0;
        for j in s + 1..=k {
            ratio *= self.forward(j) / self.backward(j);
            if self.available(j) {
                sum += ratio;
            }
        }
        ratio = 1.0;
        for j in (0..s).rev() {
            ratio *= self.backward(j + 1) / self.forward(j + 1);
            if self.available(j) {
                sum += ratio;
            }
        }
        if sum.is_nan() { 0.0 } else { 1.0 / sum }
    }
}

/// Where a subpath starts.
struct Start {
    x: DVec3,
    d: DVec3,
    /// How its rays spread (parallel from a collimated beam or an orthographic camera, through
    /// the focus of a focused beam).
    rays: Rays,
    /// A subpath from the light: it records the sensor planes it crosses and connects its events
    /// to the probes, as particle tracing does (the one way to make those paths).
    photon: bool,
}

impl ParticleTracer<'_> {
    /// The density of the camera subpaths' draws aimed at the beam's tube
    /// ([`super::beam_tube::BeamTube::aims`]), where they aim at it.
    fn aimed<'a>(&'a self, t: &'a Tools) -> Option<impl Fn(DVec3, DVec3, DVec3) -> f64 + 'a> {
        let volume = t.flyer.volume;
        let tube = self.tube.as_ref().filter(|tube| tube.aims())?;
        Some(move |x, arrive, d| {
            let bend = volume.bend(x);
            tube.aim_density(volume.scattering_at(x), (x, bend), arrive, d)
        })
    }

    /// How the rays of camera `camera` spread (the orthographic cameras first, then the
    /// pinholes): parallel from an orthographic camera, from the point of a pinhole.
    fn camera_rays(&self, camera: usize) -> Rays {
        if camera < self.scene.cameras.len() {
            Rays::Parallel
        } else {
            Rays::Spreading
        }
    }

    /// One bidirectional sample: a subpath from the light, one from each camera, every way of
    /// joining them, weighted.
    pub(super) fn bidirectional(
        &self,
        t: &Tools,
        subpaths: &mut Subpaths,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let scene = self.scene;
        let light = &scene.light;
        let (x, d) = light.sample([uniform(rng), uniform(rng), uniform(rng), uniform(rng)]);
        let inside = t.flyer.volume.field.bounds.contains(x);
        if inside {
            // cameras and probes: unscattered light is made one way
            self.connect(t, x, 1.0, 0.0, |d| light.intensity(d), rng, out);
        }
        // a beam's per unit area of its disc, or per solid angle at its focus, where the camera
        // subpaths can connect to it: from outside the volume
        let (mut light_pdf, rays) = light.start_density(x, d);
        if inside && light.beam_aim().is_some() {
            light_pdf = 0.0;
        }
        let start = Start {
            x,
            d,
            rays,
            photon: true,
        };
        self.subpath(t, &start, &mut subpaths.light, rng, out);
        for camera in 0..scene.cameras.len() + scene.pinholes.len() {
            let (x, d, pixel) = self.camera_ray(camera, rng);
            let start = Start {
                x,
                d,
                rays: self.camera_rays(camera),
                photon: false,
            };
            self.subpath(t, &start, &mut subpaths.camera, rng, out);
            let (ys, zs) = (&subpaths.light, &subpaths.camera);
            for j in 0..zs.len() {
                self.light_to_camera_event(t, &zs[..=j], &pixel, rng, out);
            }
            for i in 0..ys.len() {
                self.light_event_to_camera(t, (&ys[..=i], light_pdf), camera, rng, out);
                for j in 0..zs.len() {
                    self.join(t, (&ys[..=i], light_pdf), (&zs[..=j], &pixel), rng, out);
                }
            }
        }
    }

    /// The light connected to the camera subpath's last event `z_t` (`s = 0`, path tracing's
    /// next event): its phase function, or a surface's Lambertian `1/π` times the irradiance.
    fn light_to_camera_event(
        &self,
        t: &Tools,
        zs: &[Vertex],
        pixel: &super::path::Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let z = zs[zs.len() - 1];
        // a beam's rays are parallel: the first segment's tube does not spread; it is tried only
        // near the beam (as `subpath` counts the light's own strategy)
        let beam = matches!(self.scene.light, Light::Beam { .. });
        if beam && !self.scene.light.near_beam(z.x) {
            return;
        }
        let aim = self.aimed(t);
        let aimed = aim.as_ref().map(|q| q as AimDensity);
        for way in self.ways(t, z.facing.is_some()) {
            let link = match z.facing {
                // between two of several volumes, as it fits from either end (see
                // `Meetings::connectible`)
                None => self.light_link(t, z.x, way, true, rng, out),
                Some(n) => self.surface_light_link(t, z.x, n, way, rng, out),
            };
            let Some(link) = link.filter(|l| !crosses_after_mirror(way, l.inside.total())) else {
                continue;
            };
            let volume = t.flyer.volume;
            let phase_camera = z.rho_towards(volume, link.direction);
            let cos_z = z.facing.map_or(1.0, |n| n.dot(link.direction));
            let joined = Joined {
                light: &[],
                camera: zs,
                light_pdf: link.pdf,
                camera_pdf: pixel.pdf,
                link: Segment::new(volume, &link.inside, link.outside, link.rays, true)
                    .with_cos(1.0, cos_z),
                rho_light: f64::NAN,
                rho_camera: z.camera_rho(phase_camera, link.direction, aimed),
                leave_light: DVec3::NAN,
                phase_camera,
                aimed,
            };
            let scatters = if z.facing.is_some() {
                std::f64::consts::FRAC_1_PI
            } else {
                phase_camera
            };
            let radiance = joined.weight() * z.beta * scatters * link.radiance;
            let added = self.record_sample(t, pixel, radiance, z.opl + link.delay, out);
            out[self.strategy_total(pixel.camera, zs.len(), 0)].re += added;
        }
    }

    /// The light subpath's last event `y_s` connected to camera `camera` (`t = 0`, particle
    /// tracing's connection), as a point source of intensity `w ρ` (on a surface `w cos θ / π`).
    fn light_event_to_camera(
        &self,
        t: &Tools,
        (ys, light_pdf): (&[Vertex], f64),
        camera: usize,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let y = ys[ys.len() - 1];
        let aim = self.aimed(t);
        let aimed = aim.as_ref().map(|q| q as AimDensity);
        for way in self.ways(t, y.facing.is_some()) {
            let link = match y.facing {
                None => self.camera_link(t, y.x, camera, way, rng, out),
                Some(n) => self.surface_camera_link(t, y.x, n, camera, way, rng, out),
            };
            let Some(link) = link.filter(|l| !crosses_after_mirror(way, l.inside.total())) else {
                continue;
            };
            let volume = t.flyer.volume;
            let rho_light = y.rho_towards(volume, link.direction);
            let rays = self.camera_rays(camera);
            let cos_y = y.facing.map_or(1.0, |n| n.dot(link.direction));
            // the camera's density of y where its first leg into the volume draws along it: an
            // event on that leg, or reached after it passed to the surface
            let forced = match &self.tube {
                Some(tube) if tube.draws_first_legs() && y.facing.is_none() => {
                    if link.bounces == 0 {
                        let length = link.inside.total();
                        tube.first_leg_factor(t, y.x, -link.direction, length).0
                    } else {
                        FREE_SHARE
                    }
                }
                _ => 1.0,
            };
            let joined = Joined {
                light: ys,
                camera: &[],
                light_pdf,
                camera_pdf: link.pdf,
                link: Segment::new(volume, &link.inside, link.outside, rays, true)
                    .with_cos(cos_y, 1.0)
                    .with_forced(forced),
                rho_light,
                rho_camera: f64::NAN,
                leave_light: link.direction,
                phase_camera: f64::NAN,
                aimed,
            };
            let scale = joined.weight() * y.beta * rho_light;
            if let Some(added) = self.record_link(t, &link, scale, y.opl, out) {
                out[self.strategy_total(camera, ys.len(), ys.len())].re += added;
            }
        }
    }

    /// Join the light subpath's last event `y_s` to the camera subpath's last `z_t` (the light
    /// event a point source of intensity `w ρ`, the camera event a point sensor; see
    /// [`super::path`] for the basic radiance a point source brings).
    fn join(
        &self,
        t: &Tools,
        (ys, light_pdf): (&[Vertex], f64),
        (zs, pixel): (&[Vertex], &super::path::Pixel),
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let (y, z) = (ys[ys.len() - 1], zs[zs.len() - 1]);
        let aim = self.aimed(t);
        let aimed = aim.as_ref().map(|q| q as AimDensity);
        for way in self.ways(t, y.facing.is_some() || z.facing.is_some()) {
            let Some(j) = self.joint(t, &y, &z, way, rng, out) else {
                continue;
            };
            let volume = t.flyer.volume;
            let rho_light = y.rho_towards(volume, j.leave_y);
            let phase_camera = z.rho_towards(volume, j.leave_z);
            let joined = Joined {
                light: ys,
                camera: zs,
                light_pdf,
                camera_pdf: pixel.pdf,
                link: j.segment,
                rho_light,
                rho_camera: z.camera_rho(phase_camera, j.leave_z, aimed),
                leave_light: j.leave_y,
                phase_camera,
                aimed,
            };
            let scatters = if z.facing.is_some() {
                std::f64::consts::FRAC_1_PI
            } else {
                phase_camera
            };
            let radiance = joined.weight() * z.beta * scatters * y.beta * rho_light * j.carried;
            let added = self.record_sample(t, pixel, radiance, y.opl + j.delay + z.opl, out);
            out[self.strategy_total(pixel.camera, ys.len() + zs.len(), ys.len())].re += added;
        }
    }

    /// The connection between a light event `y` and a camera event `z`: two-point inside the
    /// volume, through its surface between a point inside and one on a surface (see
    /// [`super::connect`]), or between two surfaces a straight line (past the volume only where
    /// it is index-matched) or a path `across` the volume (refracted in and out).
    fn joint(
        &self,
        t: &Tools,
        y: &Vertex,
        z: &Vertex,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Joint> {
        let volume = t.flyer.volume;
        let n_out = volume.field.n_out;
        // the far end of a straight stretch lies on a surface: stop short of it
        const SHORT: f64 = 1.0 - 1e-9;
        match (y.facing, z.facing, way) {
            (Some(facing_y), Some(facing_z), Way::Across | Way::Mirror) => {
                // from z across the volume (or off its outside) to y: y's intensity brings z the
                // irradiance `T (1 − R_in)(1 − R_out) cos θ_z / (dA⊥/dω)` (`R cos θ_z / (dA⊥/dω)`
                // off the outside; reciprocity: both ends in n_out)
                let (e, carried) = self.across(t, z.x, Aim::Point(y.x), way, rng, out)?;
                if crosses_after_mirror(way, e.length) {
                    return None;
                }
                let to_y = (y.x - e.surface).dot(e.outgoing);
                let (cos_y, cos_z) = (-facing_y.dot(e.outgoing), facing_z.dot(e.direction));
                if cos_y <= 0.0
                    || cos_z <= 0.0
                    || self.scene.blocked(e.surface, e.outgoing, to_y * SHORT)
                {
                    return None;
                }
                let outside = n_out * (e.outside() + to_y);
                Some(Joint {
                    leave_y: -e.outgoing,
                    leave_z: e.direction,
                    carried: carried * cos_z,
                    delay: t.exit_delay(&e, outside),
                    segment: Segment::new(
                        volume,
                        &e.lengths(volume),
                        e.outside() + to_y,
                        Rays::Spreading,
                        true,
                    )
                    .with_cos(cos_y, cos_z),
                })
            }
            (None, None, Way::Bounces(bounces)) => {
                let first_only = self.scene.connections == Connections::First;
                let sampled =
                    t.connector
                        .sample_inside(z.x, y.x, (bounces, false), first_only, rng);
                let (path, inverse_p) = self.tally(sampled, out)?;
                if !path.fits_either_way() {
                    return None;
                }
                let transmittance = self.path_transmittance(t, z.x, &path, rng);
                let n_y = t.flyer.n(y.x);
                // the camera's density of y where its flights from z draw from the tube
                let forced = match (&self.tube, &path) {
                    (Some(tube), InsidePath::Within(c, bounces)) => {
                        tube.factor_along(t, z.x, c.direction, *bounces, c.length).0
                    }
                    _ => 1.0,
                };
                Some(Joint {
                    leave_y: -path.arrival().1,
                    leave_z: path.direction(),
                    carried: n_out * n_out * transmittance * path.fresnel()
                        / (n_y * n_y * path.spread())
                        * inverse_p,
                    delay: t.path_delay(&path),
                    segment: Segment::new(
                        volume,
                        &path.lengths(volume),
                        path.outside(),
                        Rays::Spreading,
                        true,
                    )
                    .with_forced(forced),
                })
            }
            (None, Some(facing), Way::Bounces(bounces)) => {
                // from y inside through z: z's irradiance, `T (1 − R) cos θ / (dA⊥/dω)`
                let o = self.out_to_surface(t, y.x, z.x, facing, bounces, rng, out)?;
                Some(Joint {
                    leave_y: o.exit.direction,
                    leave_z: -o.exit.outgoing,
                    carried: o.carried * o.cos,
                    delay: o.delay,
                    segment: o.segment.with_cos(1.0, o.cos),
                })
            }
            (Some(facing), None, Way::Bounces(bounces)) => {
                // from z inside through y: y a point source outside, as a light in path tracing
                let o = self.out_to_surface(t, z.x, y.x, facing, bounces, rng, out)?;
                Some(Joint {
                    leave_y: -o.exit.outgoing,
                    leave_z: o.exit.direction,
                    carried: o.carried,
                    delay: o.delay,
                    segment: o.segment.with_cos(o.cos, 1.0),
                })
            }
            (Some(facing_y), Some(facing_z), Way::Bounces(0)) => {
                let v = y.x - z.x;
                let distance = v.length();
                let w = v / distance;
                let (cos_y, cos_z) = (-facing_y.dot(w), facing_z.dot(w));
                if distance <= 0.0
                    || cos_y <= 0.0
                    || cos_z <= 0.0
                    || self.scene.blocked(z.x, w, distance * SHORT)
                {
                    return None;
                }
                let (transmittance, inside) = self.past_volume(t, z.x, w, distance, rng)?;
                Some(Joint {
                    leave_y: -w,
                    leave_z: w,
                    carried: transmittance * cos_z / (distance * distance),
                    delay: t.delay.outside(n_out * distance),
                    segment: Segment::new(
                        volume,
                        &inside,
                        distance - inside.total(),
                        Rays::Spreading,
                        true,
                    )
                    .with_cos(cos_y, cos_z),
                })
            }
            _ => None,
        }
    }

    /// The connection from `x` inside the volume out through its surface, after `bounces`
    /// reflections inside it, to the point `p` of a surface (unit `facing` normal on the lit
    /// side), past no other surface: what it carries either way per unit intensity, `T (1 − R) /
    /// (dA⊥/dω)` (without the cosine at `p`; `R` with the reflectances of the reflections).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn out_to_surface(
        &self,
        t: &Tools,
        x: DVec3,
        p: DVec3,
        facing: DVec3,
        bounces: usize,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<OutToSurface> {
        let volume = t.flyer.volume;
        let first_only = self.scene.connections == Connections::First;
        let bounces = self.exit_bounces(t, bounces, rng);
        let s = t
            .connector
            .sample_through(x, Aim::Point(p), &bounces, first_only, rng);
        let (exit, inverse_p) = self.tally(s, out)?;
        let to_p = (p - exit.surface).dot(exit.outgoing);
        let cos = -facing.dot(exit.outgoing);
        // p lies on a surface: stop the check short of it
        if cos <= 0.0
            || self
                .scene
                .blocked(exit.surface, exit.outgoing, to_p * (1.0 - 1e-9))
        {
            return None;
        }
        let transmittance = self.exit_transmittance(t, &exit, bounces.first, rng);
        let outside = volume.field.n_out * (exit.outside() + to_p);
        Some(OutToSurface {
            carried: transmittance * exit.transmission / exit.jacobian * inverse_p,
            delay: t.exit_delay(&exit, outside),
            segment: Segment::new(
                volume,
                &exit.lengths(volume),
                exit.outside() + to_p,
                Rays::Spreading,
                true,
            ),
            outside: exit.outside() + to_p,
            cos,
            exit,
        })
    }

    /// Trace a subpath from `start` into `vertices` (cleared first): its scattering events
    /// inside the volume and on surfaces, until it leaves the scene, is given up, or loses the
    /// roulette.
    fn subpath(
        &self,
        t: &Tools,
        start: &Start,
        vertices: &mut Vec<Vertex>,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        vertices.clear();
        let volume = t.flyer.volume;
        let n_out = volume.field.n_out;
        let matched = t.connector.matched();
        let (mut beta, mut opl, mut steps) = (1.0, 0.0, 0);
        // the segment so far: geometric length inside and outside, its meetings with the
        // surface, whether it began inside the volume, the cosine where it left a surface
        let (mut inside, mut outside) = (PartLengths::default(), 0.0);
        let mut met = Meetings::default();
        // a camera subpath's segment from an event inside, reflecting inside only: the product
        // of its legs' factors from the beam's tube (see `Segment::forced`)
        let mut tube_factor = 1.0;
        // reflections inside since the last vertex (see `MAX_REFLECTIONS`)
        let mut reflections = Reflections::default();
        let most_bounces = self.most_bounces(t);
        // of several parts, a segment may leave its part and come back into it
        let beside_others = t.connector.beside_others();
        let mut began_inside = volume.field.bounds.contains(start.x);
        // of several volumes, the one the segment began in (0 for a volume of one part)
        let mut began_in = Some(t.connector.part_of(start.x)).filter(|_| began_inside);
        let mut cos_start = 1.0;
        let connectible = |met: &Meetings, began_inside: bool, ends_inside: bool| {
            met.connectible((began_inside, ends_inside), None, most_bounces, matched)
        };
        // a beam's first segment is connected only to events near it
        // (see `light_to_camera_event`)
        let beam = start.photon && start.rays == Rays::Parallel;
        let reached = |first: bool, x: DVec3| !(first && beam) || self.scene.light.near_beam(x);
        let mut leg = if began_inside {
            Leg::Inside(Ray {
                x: start.x,
                v: start.d * t.flyer.n(start.x),
            })
        } else {
            Leg::Outside {
                x: start.x,
                d: start.d,
                left_volume: false,
            }
        };
        loop {
            let ray = match leg {
                Leg::Outside { x, d, left_volume } => {
                    let (entry, surface) = self.ahead(t, x, d, left_volume);
                    let end = super::particle::nearest(entry, surface);
                    if start.photon {
                        self.cross_sensors(t, x, d, end, beta, opl, &[], out);
                    }
                    match (entry, surface) {
                        (Some(t0), _) if t0 == end => {
                            opl += t.delay.outside(n_out * t0);
                            outside += t0;
                            leg = Leg::enter(t, x, d, t0, rng);
                            match leg {
                                Leg::Inside(r) => {
                                    met.met_outside(false, Some(t.connector.part_of(r.x)))
                                }
                                Leg::Outside { .. } => met.met_outside(true, None),
                            }
                            continue;
                        }
                        (_, Some((i, distance))) => {
                            let s = &self.scene.surfaces[i];
                            opl += t.delay.outside(n_out * distance);
                            outside += distance;
                            if start.photon {
                                out[self.surface_power(i)].re += beta;
                            }
                            beta *= s.albedo;
                            if beta <= 0.0 {
                                break;
                            }
                            let facing = if d.dot(s.normal) < 0.0 {
                                s.normal
                            } else {
                                -s.normal
                            };
                            let first = vertices.is_empty();
                            let at = x + d * distance;
                            let segment = Segment::new(
                                volume,
                                &inside,
                                outside,
                                if first { start.rays } else { Rays::Spreading },
                                connectible(&met, began_inside, false) && reached(first, at),
                            );
                            vertices.push(Vertex {
                                x: at,
                                arrive: d,
                                leave: DVec3::NAN,
                                rho: f64::NAN,
                                phase: f64::NAN,
                                beta,
                                opl,
                                segment: segment.with_cos(cos_start, -facing.dot(d)),
                                facing: Some(facing),
                            });
                            (inside, outside, met) =
                                (PartLengths::default(), 0.0, Meetings::default());
                            tube_factor = 1.0;
                            reflections = Reflections::default();
                            (began_inside, began_in) = (false, None);
                            if !roulette(&mut beta, rng) || vertices.len() >= MAX_EVENTS {
                                break;
                            }
                            // Lambertian: leave cosine-distributed
                            let mu = uniform(rng).sqrt();
                            let next = crate::math::direction_about(
                                facing,
                                mu,
                                2.0 * std::f64::consts::PI * uniform(rng),
                            );
                            cos_start = mu;
                            if let Some(last) = vertices.last_mut() {
                                last.leave = next;
                                last.rho = lambert(facing, next);
                                last.phase = last.rho;
                                leg = Leg::Outside {
                                    x: last.x,
                                    d: next,
                                    left_volume: false,
                                };
                            }
                            continue;
                        }
                        _ => break,
                    }
                }
                Leg::Inside(ray) => ray,
            };
            // one leg on from an event inside (or a reflection inside since): a camera
            // subpath's is drawn from the tube
            let tube = self.tube.as_ref();
            let direct =
                tube.filter(|_| !vertices.is_empty() && began_inside && met.all == met.bounces);
            // a camera subpath's first leg, just entered (see `BeamTube::draws_first_legs`)
            let first_leg = tube.filter(|tube| {
                tube.draws_first_legs()
                    && vertices.is_empty()
                    && !began_inside
                    && met.all == 1
                    && met.glances == 0
            });
            let forced = match (direct, first_leg) {
                (Some(tube), _) => Some((tube, Forced::Tube)),
                (None, Some(tube)) => Some((tube, Forced::Leg)),
                (None, None) => None,
            };
            let (stop, travelled) = match forced {
                Some((tube, forced)) if !start.photon => {
                    let (stop, travelled, factor) = tube.flight(t, ray, forced, rng);
                    beta /= factor;
                    tube_factor *= factor;
                    (stop, travelled)
                }
                _ => t.next_event(ray, rng),
            };
            steps += travelled.steps;
            opl += travelled.opl;
            inside.add(volume.part_index(ray.x), travelled.length);
            match stop {
                Stop::Collision(hit) => {
                    beta *= volume.albedo_at(hit.x);
                    let first = vertices.is_empty();
                    let u = hit.v.normalize();
                    let forced = match direct {
                        // as a camera subpath would have drawn the event before from this one
                        Some(tube) if start.photon => {
                            let (factor, k) =
                                tube.factor_along(t, hit.x, -u, met.bounces, inside.total());
                            steps += k;
                            factor
                        }
                        // a camera subpath's own draws (1 where it drew none)
                        _ => tube_factor,
                    };
                    let ends_in = Some(t.connector.part_of(hit.x));
                    // out of one part into another, or in a part that is not convex
                    let between = match (began_in, ends_in) {
                        (Some(a), Some(b)) if a != b => Some(Ends::Apart(a, b)),
                        (Some(a), Some(_)) if t.connector.not_convex(a) => Some(Ends::Around(a)),
                        (Some(a), Some(_)) if beside_others => Some(Ends::Back(a)),
                        _ => None,
                    };
                    let made = (began_inside, true);
                    let segment = Segment::new(
                        volume,
                        &inside,
                        outside,
                        if first { start.rays } else { Rays::Spreading },
                        met.connectible(made, between, most_bounces, matched)
                            && reached(first, hit.x),
                    )
                    .with_forced(forced);
                    vertices.push(Vertex {
                        x: hit.x,
                        arrive: u,
                        leave: DVec3::NAN,
                        rho: f64::NAN,
                        phase: f64::NAN,
                        beta,
                        opl,
                        segment: segment.with_cos(cos_start, 1.0),
                        facing: None,
                    });
                    (inside, outside, met) = (PartLengths::default(), 0.0, Meetings::default());
                    tube_factor = 1.0;
                    reflections = Reflections::default();
                    (began_inside, began_in, cos_start) = (true, ends_in, 1.0);
                    if start.photon {
                        let phase = |d: DVec3| volume.scattering_at(hit.x).eval(u.dot(d));
                        self.connect_probes(t, hit.x, beta, opl, phase, rng, out);
                    }
                    if !roulette(&mut beta, rng) || vertices.len() >= MAX_EVENTS {
                        break;
                    }
                    // a camera subpath aiming at the beam's tube draws half its directions
                    // aimed at it, its weight divided by the mixture's density over the phase
                    // function's
                    let scattering = volume.scattering_at(hit.x);
                    let aiming = (self.tube.as_ref())
                        .filter(|tube| tube.aims() && !start.photon)
                        .map(|tube| tube.aiming(scattering, (hit.x, volume.bend(hit.x)), u));
                    let next = match &aiming {
                        Some(aiming) if uniform(rng) >= PHASE_SHARE => Ray {
                            x: hit.x,
                            v: aiming.draw(u, rng) * t.flyer.n(hit.x),
                        },
                        _ => t.scatter(hit.x, u, rng),
                    };
                    let leave = next.v.normalize();
                    let phase = scattering.eval(u.dot(leave));
                    let rho = camera_density(phase, aiming.map(|a| a.density(leave)));
                    beta *= if rho > 0.0 { phase / rho } else { 0.0 };
                    if let Some(last) = vertices.last_mut() {
                        (last.leave, last.rho, last.phase) = (leave, rho, phase);
                    }
                    leg = Leg::Inside(next);
                }
                Stop::Boundary(end) => {
                    leg = Leg::leave(t, end, rng);
                    let bounced = matches!(leg, Leg::Inside(_));
                    met.met_inside(bounced);
                    if bounced && !reflections.another() {
                        // given up, as a flight out of steps
                        break;
                    }
                }
                Stop::Stuck => break,
            }
        }
        out[self.total(super::Total::Events)].re += vertices.len() as f64;
        out[self.total(super::Total::Steps)].re += steps as f64;
    }
}

/// A connection from a point inside the volume to a point on a surface, as
/// [`ParticleTracer::out_to_surface`] finds it.
pub(super) struct OutToSurface {
    pub(super) exit: super::connect::Exit,
    /// `T (1 − R) / (dA⊥/dω)` over the inverse probability of drawing the path.
    pub(super) carried: f64,
    /// Group delay along it, and its straight length outside the volume.
    pub(super) delay: f64,
    pub(super) outside: f64,
    /// As the weights see it, from the point inside (without the cosine at the surface).
    segment: Segment,
    /// The cosine at the surface point.
    pub(super) cos: f64,
}

/// A connection between a light event and a camera event, as [`ParticleTracer::join`] uses it.
struct Joint {
    /// Unit directions leaving each end along the connection.
    leave_y: DVec3,
    leave_z: DVec3,
    /// What reaches `z` per unit intensity leaving `y`: for an event inside, per unit phase
    /// function in the camera's radiance; on a surface, its irradiance.
    carried: f64,
    /// Group delay along it.
    delay: f64,
    /// As the weights see it, from `y` to `z`.
    segment: Segment,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::stream_rng;

    /// A segment through two volumes is weighed by each one's extinction over its stretch inside
    /// it (not by one extinction over the whole length), and its spread by its whole length.
    #[test]
    fn a_segment_through_two_volumes_takes_each_ones_extinction() {
        use crate::eikonal::{Bounds, Part, Profile};
        use crate::medium::{PhaseFunction, Scattering};
        let ball = |x: f64, sigma_s: f64, sigma_a: f64| {
            (
                Part::new(
                    Bounds::Sphere { radius: 0.5 },
                    DVec3::new(x, 0.0, 0.0),
                    vec![Profile::Constant { n: 1.3 }],
                ),
                super::super::scene::Bulk {
                    sigma_s,
                    sigma_a,
                    scattering: Scattering::single(PhaseFunction::Isotropic),
                },
            )
        };
        let volume = Volume::several(vec![ball(-1.0, 2.0, 0.1), ball(1.0, 0.8, 0.3)], 1.0);
        let mut inside = PartLengths::one(Some(0), 0.4);
        inside.add(Some(1), 0.7);
        let s = Segment::new(&volume, &inside, 0.9, Rays::Spreading, true);
        let want = (-(2.1 * 0.4 + 1.1 * 0.7f64)).exp() / (2.0f64 * 2.0);
        assert!((s.g - want).abs() < 1e-15 * want, "{} vs {want}", s.g);
        let parallel = Segment::new(&volume, &inside, 0.9, Rays::Parallel, true);
        assert!((parallel.g - want * 4.0).abs() < 1e-15 * want);
    }

    /// The path `v_1 … v_k` split after `s` events, as [`ParticleTracer::bidirectional`] sees it
    /// for that strategy: `rho[i − 1]` the phase function at `v_i`, `segments[j]` from `v_j` to
    /// `v_{j+1}`.
    fn split(
        rho: &[f64],
        segments: &[Segment],
        s: usize,
    ) -> (Vec<Vertex>, Vec<Vertex>, Segment, f64, f64) {
        let k = rho.len();
        let vertex = |segment: Segment, rho: f64| Vertex {
            x: DVec3::ZERO,
            arrive: DVec3::Z,
            leave: DVec3::Z,
            rho,
            phase: rho,
            beta: 1.0,
            opl: 0.0,
            segment,
            facing: None,
        };
        let light = (1..=s)
            .map(|i| vertex(segments[i - 1], rho[i - 1]))
            .collect();
        // z_m = v_{k+1−m}, reached from the camera's side by segment k + 1 − m
        let camera = (1..=k - s)
            .map(|m| vertex(segments[k + 1 - m], rho[k - m]))
            .collect();
        let rho_light = if s > 0 { rho[s - 1] } else { f64::NAN };
        let rho_camera = if s < k { rho[s] } else { f64::NAN };
        (light, camera, segments[s], rho_light, rho_camera)
    }

    /// Over the strategies that can make a path, the weights sum to one: for random paths of
    /// up to eight events, some segments not connectible, from a beam (no `s = 0`) or a point.
    #[test]
    fn weights_sum_to_one_over_the_strategies_that_make_a_path() {
        let mut rng = stream_rng(7, 0);
        for case in 0..400 {
            let k = 1 + case % 8;
            let rho: Vec<f64> = (0..k).map(|_| 0.01 + 3.0 * uniform(&mut rng)).collect();
            let segments: Vec<Segment> = (0..=k)
                .map(|_| Segment {
                    g: (-4.0 * uniform(&mut rng)).exp() / (0.05 + uniform(&mut rng)).powi(2),
                    cos_start: 1.0,
                    cos_end: 1.0,
                    connectible: uniform(&mut rng) < 0.7,
                    forced: if uniform(&mut rng) < 0.3 {
                        0.5 + 100.0 * uniform(&mut rng)
                    } else {
                        1.0
                    },
                })
                .collect();
            let light_pdf = if case % 3 == 0 {
                0.0
            } else {
                0.1 + uniform(&mut rng)
            };
            let camera_pdf = 0.1 + 10.0 * uniform(&mut rng);
            let mut sum = 0.0;
            let mut strategies = 0;
            for s in 0..=k {
                if !segments[s].connectible || (s == 0 && light_pdf == 0.0) {
                    continue;
                }
                let (light, camera, link, rho_light, rho_camera) = split(&rho, &segments, s);
                let joined = Joined {
                    light: &light,
                    camera: &camera,
                    light_pdf,
                    camera_pdf,
                    link,
                    rho_light,
                    rho_camera,
                    leave_light: DVec3::Z,
                    phase_camera: rho_camera,
                    aimed: None,
                };
                assert!(joined.available(s));
                let w = joined.weight();
                assert!(
                    w > 0.0 && w <= 1.0,
                    "case {case}: weight {w} of strategy {s}"
                );
                sum += w;
                strategies += 1;
            }
            if strategies > 0 {
                assert!(
                    (sum - 1.0).abs() < 1e-12,
                    "case {case}: weights sum to {sum} over {strategies} strategies"
                );
            }
        }
    }

    /// The same on paths laid out in space with events on surfaces (lit on the side facing both
    /// neighbours), whose densities of leaving differ by direction (`cos θ / π`) and which take
    /// `|cos θ|` per unit area: every split of the path must see the same densities, the
    /// camera's subpath reversed; and some flights between events inside drawn, from the
    /// camera's side, from a beam's tube (a factor on the density from that side), and on half
    /// the paths the camera's directions from events inside partly aimed (a density of its
    /// own, different each way).
    #[test]
    fn weights_sum_to_one_with_surface_events() {
        let mut rng = stream_rng(11, 0);
        let hg = |c: f64| {
            let g: f64 = 0.5;
            (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * c).powf(1.5))
        };
        for case in 0..300 {
            let k = 1 + case % 6;
            // v_0 the light, v_{k+1} the camera
            let v: Vec<DVec3> = (0..k + 2)
                .map(|_| {
                    DVec3::new(uniform(&mut rng), uniform(&mut rng), uniform(&mut rng)) * 4.0 - 2.0
                })
                .collect();
            let dir = |i: usize, j: usize| (v[j] - v[i]).normalize();
            let facing: Vec<Option<DVec3>> = (0..k + 2)
                .map(|i| {
                    if i == 0 || i > k || uniform(&mut rng) < 0.5 {
                        return None;
                    }
                    // tilted off the bisector, so the two ways leave at different angles
                    let (a, b) = (dir(i, i - 1), dir(i, i + 1));
                    let tilt = crate::math::uniform_sphere(uniform(&mut rng), uniform(&mut rng));
                    let n = (a + b + tilt * 0.8).normalize();
                    Some(if n.dot(a) > 0.05 && n.dot(b) > 0.05 {
                        n
                    } else {
                        (a + b).normalize()
                    })
                })
                .collect();
            let connectible: Vec<bool> = (0..=k).map(|_| uniform(&mut rng) < 0.8).collect();
            // flights between two events inside, which a camera subpath draws from the tube
            let forced: Vec<f64> = (0..=k)
                .map(|c| {
                    let inside = c > 0 && c < k && facing[c].is_none() && facing[c + 1].is_none();
                    if inside && uniform(&mut rng) < 0.7 {
                        0.5 + 100.0 * uniform(&mut rng)
                    } else {
                        1.0
                    }
                })
                .collect();
            // the density of leaving v_i towards v_j having arrived from v_h
            let pdf = |h: usize, i: usize, j: usize| match facing[i] {
                Some(n) => lambert(n, dir(i, j)),
                None => hg(dir(h, i).dot(dir(i, j))),
            };
            // the aimed draws' density: any that differs by place and direction
            let aim = |x: DVec3, arrive: DVec3, d: DVec3| {
                0.05 + (x.x + 2.5) * (1.0 + 0.9 * d.z) * (1.2 + arrive.dot(d))
            };
            let aimed = (case % 2 == 1).then_some(&aim as AimDensity);
            // the camera's density of leaving v_i towards v_j having arrived from v_h
            let camera_pdf = |h: usize, i: usize, j: usize| match facing[i] {
                Some(_) => pdf(h, i, j),
                None => camera_density(pdf(h, i, j), aimed.map(|q| q(v[i], dir(h, i), dir(i, j)))),
            };
            // the segment traced from v_i to v_j, path segment `c`
            let segment = |i: usize, j: usize, c: usize| {
                let l = (v[j] - v[i]).length();
                let cos = |f: Option<DVec3>| f.map_or(1.0, |n| n.dot(dir(i, j)).abs());
                Segment {
                    g: (-0.7 * l).exp() / (l * l),
                    cos_start: cos(facing[i]),
                    cos_end: cos(facing[j]),
                    connectible: connectible[c],
                    forced: forced[c],
                }
            };
            let vertex = |i: usize, from: usize, to: usize, last: bool, c: usize| Vertex {
                x: v[i],
                arrive: dir(from, i),
                leave: if last { DVec3::NAN } else { dir(i, to) },
                rho: match (last, to < i) {
                    (true, _) => f64::NAN,
                    (false, true) => camera_pdf(from, i, to),
                    (false, false) => pdf(from, i, to),
                },
                phase: if last { f64::NAN } else { pdf(from, i, to) },
                beta: 1.0,
                opl: 0.0,
                segment: segment(from, i, c),
                facing: facing[i],
            };
            let mut sum = 0.0;
            let mut strategies = 0;
            for (s, _) in connectible.iter().enumerate().filter(|(_, c)| **c) {
                let light: Vec<Vertex> = (1..=s)
                    .map(|i| vertex(i, i - 1, i + 1, i == s, i - 1))
                    .collect();
                // z_m = v_{k+1−m}, reached from v_{k+2−m}
                let camera: Vec<Vertex> = (1..=k - s)
                    .map(|m| {
                        let i = k + 1 - m;
                        vertex(i, i + 1, i - 1, m == k - s, i)
                    })
                    .collect();
                let joined = Joined {
                    light: &light,
                    camera: &camera,
                    light_pdf: 0.3,
                    camera_pdf: 2.0,
                    link: segment(s, s + 1, s),
                    rho_light: if s > 0 {
                        pdf(s - 1, s, s + 1)
                    } else {
                        f64::NAN
                    },
                    rho_camera: if s < k {
                        camera_pdf(s + 2, s + 1, s)
                    } else {
                        f64::NAN
                    },
                    leave_light: dir(s, s + 1),
                    phase_camera: if s < k {
                        pdf(s + 2, s + 1, s)
                    } else {
                        f64::NAN
                    },
                    aimed,
                };
                let w = joined.weight();
                assert!(
                    w > 0.0 && w <= 1.0,
                    "case {case}: weight {w} of strategy {s}"
                );
                sum += w;
                strategies += 1;
            }
            if strategies > 0 {
                assert!(
                    (sum - 1.0).abs() < 1e-12,
                    "case {case}: weights sum to {sum} over {strategies} strategies"
                );
            }
        }
    }

    /// The surface events of a traced segment, in order: `E` enters (`E3`: the volume of index
    /// 3 among several), `L` leaves, `B` reflects inside, `G` reflects off the outside.
    fn met(events: &str) -> Meetings {
        let mut m = Meetings::default();
        let mut chars = events.chars().peekable();
        while let Some(e) = chars.next() {
            match e {
                'E' => {
                    let part = chars.next_if(char::is_ascii_digit);
                    m.met_outside(false, part.map(|d| d as usize - '0' as usize));
                }
                'G' => m.met_outside(true, None),
                'L' => m.met_inside(false),
                'B' => m.met_inside(true),
                _ => unreachable!(),
            }
        }
        m
    }

    /// A connection leaves the part it starts in after its reflections there, crossing parts
    /// met again after and reflecting inside them, two reflections in all and four stretches
    /// inside parts crossed at most; the same segment traced from outside in is the same path.
    /// Between two points outside, a path across reflects inside the parts it crosses as often.
    /// More, or a reflection off the outside, are made by tracing alone.
    #[test]
    fn segments_are_connectible_as_the_connections_run() {
        let io = |events: &str, began_inside: bool| {
            met(events).connectible((began_inside, !began_inside), None, 2, false)
        };
        // from a point inside to one outside, and the other way
        for (events, made) in [
            ("L", true),
            ("BBL", true),
            ("BBBL", false),
            ("BLEL", true),
            ("LEBL", true),
            ("BLEBL", true),
            ("LEBBL", true),
            ("BBLEBL", false),
            ("LEBLELEL", true),
            ("LEBLELELEL", false),
            ("LELELELEL", true),
            ("LELELELELEL", false),
            ("LGEL", false),
        ] {
            assert_eq!(io(events, true), made, "{events} from inside");
        }
        for (events, made) in [
            ("E", true),
            ("EBB", true),
            ("EBBB", false),
            ("ELEB", true),
            ("EBLE", true),
            ("EBLEB", true),
            ("EBLEBB", false),
            ("ELEBLELE", true),
            ("ELEBLELELE", false),
            ("ELELELELE", true),
            ("ELELELELELE", false),
            ("GE", false),
        ] {
            assert_eq!(io(events, false), made, "{events} from outside");
        }
        let inside = |events: &str| met(events).connectible((true, true), None, 2, false);
        assert!(inside("") && inside("BB") && !inside("BBB") && !inside("LE"));
        let outside =
            |events: &str, matched| met(events).connectible((false, false), None, 2, matched);
        // across: reflections inside the parts crossed, the same path from either end
        for events in [
            "",
            "EL",
            "ELEL",
            "ELELELELEL",
            "EBL",
            "EBBL",
            "ELEBBL",
            "EBLEBL",
            "ELELELEBL",
            "G",
        ] {
            assert!(outside(events, false), "{events}");
        }
        for events in [
            "ELELELELELEL",
            "EBBBL",
            "EBLEBLEBL",
            "ELELELELEBL",
            "GEL",
            "ELG",
            "EBLG",
            "GG",
        ] {
            assert!(!outside(events, false), "{events}");
        }
        assert!(outside("ELELELELELEL", true));
    }

    /// Between points in two of several volumes (0 and 1) a connection leaves the one, crosses
    /// any other it meets and enters the other, reflecting inside any of them, two reflections
    /// in all, and its stretches after the first fitting [`MAX_AGAIN`] from either end: a traced
    /// segment that enters either end's volume before its last entry, reflects more or off an
    /// outside, or runs more stretches, is made by tracing alone.
    #[test]
    fn segments_between_two_volumes_are_connectible_as_the_connections_run() {
        let between =
            |events: &str| met(events).connectible((true, true), Some(Ends::Apart(0, 1)), 2, false);
        for events in [
            "LE1",
            "LE2LE1",
            "LE2LE3LE4LE1",
            "BLE1",
            "LE1B",
            "BBLE1",
            "LE2BLE1",
            "LE2LE3BLE1",
            "BLE2LE3LE1B",
        ] {
            assert!(between(events), "{events}");
        }
        for events in [
            "BBBLE1",
            "BLE1BB",
            "LGE1",
            "LE0LE1",
            "LE1LE2LE1",
            "LE2LE3LE4LE5LE1",
            "LE2LE3LE4BLE1",
            "BLE2LE3LE4LE1",
            "LE2LE3LE4LE1B",
        ] {
            assert!(!between(events), "{events}");
        }
    }

    /// Between two points in one convex part of several (0) a connection stays in it,
    /// reflecting inside, or leaves it and comes back having reflected (inside a part it
    /// crosses, or in its own before it leaves and after it comes back, fewer times at either
    /// end than in all): two reflections in all. In a part that is not convex it may come back
    /// unreflected, and cross other stretches of it on the way.
    #[test]
    fn segments_back_into_a_convex_part_are_connectible_as_the_connections_run() {
        let back =
            |events: &str| met(events).connectible((true, true), Some(Ends::Back(0)), 2, false);
        for events in [
            "",
            "BB",
            "LE1BLE0",
            "BLE1BLE0",
            "LE1BLE0B",
            "LE1BBLE0",
            "BLE0B",
            "LE1BLE2LE0",
        ] {
            assert!(back(events), "{events}");
        }
        for events in [
            "BBB",
            "LE1LE0",
            "BLE0",
            "LE0B",
            "BLE1LE0",
            "LE1LE0B",
            "BBLE1LE0",
            "LE1LE0BB",
            "LGE0",
            "LE1BLE0BB",
            "LE1BLE2LE3LE0",
            "LE0LE1BLE0",
        ] {
            assert!(!back(events), "{events}");
        }
        let around =
            |events: &str| met(events).connectible((true, true), Some(Ends::Around(0)), 2, false);
        for events in ["LE0", "LE1LE0", "BLE0B", "LE0LE0", "LE0LE1BLE0"] {
            assert!(around(events), "{events}");
        }
        for events in ["LE0LE0LE0LE0LE0", "LGE0", "BBLE0LE0B"] {
            assert!(!around(events), "{events}");
        }
    }
}
