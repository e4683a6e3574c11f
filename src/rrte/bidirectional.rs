//! Bidirectional path tracing with multiple importance sampling (paper 002 Sec. 3, after Veach
//! and Guibas 1995 and Lafortune and Willems 1996): the same camera images as particle and path
//! tracing, from every way of joining a subpath from the light to one from the camera.
//!
//! Each sample traces one subpath from the light (a photon: power after the albedo at each
//! event) and, per camera, one from the camera (throughput in basic radiance), both with the free
//! flights, Fresnel splits and phase-function sampling of the other two tracers. A path of `k`
//! scattering events `v_1 … v_k` can then be made `k + 1` ways: `s` events from the light and
//! `t = k − s` from the camera, joined by a connection along curved rays (see
//! [`super::connect`]): the light to a camera event (`s = 0`, path tracing's next event), a light
//! event to the camera (`t = 0`, particle tracing's), or a light event to a camera event (a
//! two-point connection, the light event seen as a point source of intensity `w ρ` and the camera
//! event as a point sensor). Unscattered light from a light inside the volume is connected to
//! the cameras directly (the one way to make it). Flux sensors, screens and fluence probes are
//! estimated by the light subpaths alone, as in particle tracing: the sensor planes they cross,
//! and their events connected to the probes.
//!
//! The estimates are weighted by the balance heuristic over the strategies that can make the
//! path: `w_s = p_s / Σ_j p_j`, with `p_j` the density strategy `j` gives the path's vertices. A
//! connection cannot reflect inside the surface, so a segment with such a reflection on it (or,
//! to or from a point outside, with more than its one refraction) is made only by tracing: the
//! strategies that would connect across it are left out of the sum, as is the light's own
//! (`s = 0`) for a beam, whose directions are a delta. The weights use the straight-ray density
//! of each segment — `ρ σ_t e^{−σ_t ℓ}/ℓ²` over its geometric length `ℓ` (the tube of parallel
//! rays from a beam or an orthographic camera: no `1/ℓ²`), the phase functions at both ends and
//! the sources' own densities — so in a graded index they are an approximation of the true
//! densities; any weights that sum to one over the strategies that can make each path keep the
//! estimate unbiased, and these are the same function of the path whichever strategy made it.
//! The contributions themselves carry the exact connections (ray tubes, transmittance, Fresnel).
//!
//! What no strategy makes: paths on which every segment reflects inside the surface (with an
//! index-matched surface there are none).

use super::particle::{Leg, MAX_EVENTS, ParticleTracer, Stop, Tools, roulette};
use super::scene::{Connections, Light, Volume};
use crate::eikonal::Ray;
use crate::math::{C64, Rng, uniform};
use glam::DVec3;

/// A scattering event of a subpath.
#[derive(Clone, Copy, Debug)]
pub(super) struct Vertex {
    x: DVec3,
    /// Unit direction of travel arriving at `x` (the subpath's own).
    arrive: DVec3,
    /// The phase function between `arrive` and the direction the subpath left along (unset at
    /// its last event).
    rho: f64,
    /// The weight after the albedo at `x`: a photon's power, or a camera path's throughput.
    beta: f64,
    /// Optical path (group delay) from the subpath's start.
    opl: f64,
    /// The segment that reached `x`.
    segment: Segment,
}

/// A segment of a path as the weights see it.
#[derive(Clone, Copy, Debug)]
struct Segment {
    /// `e^{−σ_t ℓ}/ℓ²` over its geometric length (inside; `ℓ` counts the straight stretch
    /// outside too), without the `1/ℓ²` from a beam or an orthographic camera.
    g: f64,
    /// Whether a connection can make it.
    connectible: bool,
}

impl Segment {
    fn new(volume: &Volume, inside: f64, outside: f64, parallel: bool, connectible: bool) -> Self {
        let length = inside + outside;
        let spread = if parallel { 1.0 } else { length * length };
        Segment {
            g: (-volume.sigma_t() * inside).exp() / spread,
            connectible,
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
    /// The light's density of the first segment's direction (0 for a beam), the camera's of
    /// the last.
    light_pdf: f64,
    camera_pdf: f64,
    link: Segment,
    /// The phase functions at the link's ends, `y_s` and `z_t`.
    rho_light: f64,
    rho_camera: f64,
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
            self.camera[self.k() - j].segment
        }
    }

    /// The phase function at `v_i` (the same from either side: reversing both directions keeps
    /// their angle).
    fn rho(&self, i: usize) -> f64 {
        let s = self.s();
        if i < s {
            self.light[i - 1].rho
        } else if i == s {
            self.rho_light
        } else if i == s + 1 {
            self.rho_camera
        } else {
            self.camera[self.k() - i].rho
        }
    }

    /// The density of `v_i` traced from the light (per unit volume, without `σ_t(v_i)`, which
    /// the density from the camera has too).
    fn forward(&self, i: usize) -> f64 {
        let start = if i == 1 {
            self.light_pdf
        } else {
            self.rho(i - 1)
        };
        start * self.segment(i - 1).g
    }

    /// The density of `v_i` traced from the camera.
    fn backward(&self, i: usize) -> f64 {
        let start = if i == self.k() {
            self.camera_pdf
        } else {
            self.rho(i + 1)
        };
        start * self.segment(i).g
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
    /// Its rays are parallel (a beam, an orthographic camera): the first segment's tube does not
    /// spread.
    parallel: bool,
    /// A subpath from the light: it records the sensor planes it crosses and connects its events
    /// to the probes, as particle tracing does (the one way to make those paths).
    photon: bool,
}

impl ParticleTracer<'_> {
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
        if t.flyer.volume.field.bounds.contains(x) {
            // cameras and probes: unscattered light is made one way
            self.connect(t, x, 1.0, 0.0, |d| light.intensity(d), rng, out);
        }
        let light_pdf = light.intensity(d);
        let start = Start {
            x,
            d,
            parallel: matches!(light, Light::Beam { .. }),
            photon: true,
        };
        self.subpath(t, &start, &mut subpaths.light, rng, out);
        for camera in 0..scene.cameras.len() + scene.pinholes.len() {
            let (x, d, pixel) = self.camera_ray(camera, rng);
            let orthographic = camera < scene.cameras.len();
            let start = Start {
                x,
                d,
                parallel: orthographic,
                photon: false,
            };
            self.subpath(t, &start, &mut subpaths.camera, rng, out);
            let (ys, zs) = (&subpaths.light, &subpaths.camera);
            // the light to each camera event
            for (j, z) in zs.iter().enumerate() {
                let Some(link) = self.light_link(t, z.x, rng, out) else {
                    continue;
                };
                let rho_camera = t.flyer.volume.scattering.eval(link.direction.dot(z.arrive));
                let joined = Joined {
                    light: &[],
                    camera: &zs[..=j],
                    light_pdf: link.pdf,
                    camera_pdf: pixel.pdf,
                    link: Segment::new(t.flyer.volume, link.inside, link.outside, false, true),
                    rho_light: f64::NAN,
                    rho_camera,
                };
                let radiance = joined.weight() * z.beta * rho_camera * link.radiance;
                self.record_sample(t, &pixel, radiance, z.opl + link.delay, out);
            }
            for (i, y) in ys.iter().enumerate() {
                // each light event to the camera
                if let Some(link) = self.camera_link(t, y.x, camera, rng, out) {
                    let rho_light = t.flyer.volume.scattering.eval(y.arrive.dot(link.direction));
                    let joined = Joined {
                        light: &ys[..=i],
                        camera: &[],
                        light_pdf,
                        camera_pdf: link.pdf,
                        link: Segment::new(
                            t.flyer.volume,
                            link.inside,
                            link.outside,
                            orthographic,
                            true,
                        ),
                        rho_light,
                        rho_camera: f64::NAN,
                    };
                    let scale = joined.weight() * y.beta * rho_light;
                    self.record_link(t, &link, scale, y.opl, out);
                }
                // and to each camera event
                for j in 0..zs.len() {
                    self.join(t, (&ys[..=i], light_pdf), (&zs[..=j], &pixel), rng, out);
                }
            }
        }
    }

    /// Join the light subpath's last event `y_s` to the camera subpath's last `z_t` by a
    /// connection from `z_t` (the light event a point source of intensity `w ρ`, the camera
    /// event a point sensor; see [`super::path`] for the basic radiance a point source brings).
    fn join(
        &self,
        t: &Tools,
        (ys, light_pdf): (&[Vertex], f64),
        (zs, pixel): (&[Vertex], &super::path::Pixel),
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let (y, z) = (ys[ys.len() - 1], zs[zs.len() - 1]);
        let sampled = match self.scene.connections {
            Connections::Unbiased => t.connector.sample(z.x, y.x, rng),
            Connections::First => t.connector.sample_first(z.x, y.x, rng),
        };
        let Some((c, inverse_p)) = self.tally(sampled, out) else {
            return;
        };
        let volume = t.flyer.volume;
        let leaving = -c.arrival.v.normalize();
        let rho_camera = volume.scattering.eval(c.direction.dot(z.arrive));
        let rho_light = volume.scattering.eval(y.arrive.dot(leaving));
        let transmittance = self.transmittance(t, z.x, c.direction, c.length, rng);
        let (n_y, n_out) = (t.flyer.n(y.x), volume.field.n_out);
        let joined = Joined {
            light: ys,
            camera: zs,
            light_pdf,
            camera_pdf: pixel.pdf,
            link: Segment::new(volume, c.length, 0.0, false, true),
            rho_light,
            rho_camera,
        };
        let radiance = joined.weight()
            * n_out
            * n_out
            * z.beta
            * rho_camera
            * y.beta
            * rho_light
            * transmittance
            / (n_y * n_y * c.spread)
            * inverse_p;
        let delay = t.delay.inside(c.optical_path, c.length);
        self.record_sample(t, pixel, radiance, y.opl + delay + z.opl, out);
    }

    /// Trace a subpath from `start` into `vertices` (cleared first): its scattering events
    /// inside the volume, until it leaves the scene, is given up, or loses the roulette.
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
        let albedo = volume.albedo();
        let n_out = volume.field.n_out;
        let (mut beta, mut opl, mut steps) = (1.0, 0.0, 0);
        // the segment so far: geometric length inside and outside, surface crossings
        let (mut inside, mut outside, mut crossings) = (0.0, 0.0, 0);
        let from_outside = !volume.field.bounds.contains(start.x);
        let mut leg = if from_outside {
            Leg::Outside {
                x: start.x,
                d: start.d,
                left_volume: false,
            }
        } else {
            Leg::Inside(Ray {
                x: start.x,
                v: start.d * t.flyer.n(start.x),
            })
        };
        loop {
            let ray = match leg {
                Leg::Outside { x, d, left_volume } => {
                    let entry = self.ahead(t, x, d, left_volume).0;
                    if start.photon {
                        let end = entry.unwrap_or(f64::INFINITY);
                        self.cross_sensors(t, x, d, end, beta, opl, out);
                    }
                    let Some(t0) = entry else {
                        break;
                    };
                    opl += t.delay.outside(n_out * t0);
                    outside += t0;
                    crossings += 1;
                    leg = Leg::enter(t, x, d, t0, rng);
                    continue;
                }
                Leg::Inside(ray) => ray,
            };
            let (stop, travelled) = t.next_event(ray, rng);
            steps += travelled.steps;
            opl += travelled.opl;
            inside += travelled.length;
            match stop {
                Stop::Collision(hit) => {
                    beta *= albedo;
                    let first = vertices.is_empty();
                    // the first segment from outside refracts once on the way in; others never
                    // meet the surface
                    let connectible = crossings == usize::from(first && from_outside);
                    let parallel = first && start.parallel;
                    let u = hit.v.normalize();
                    vertices.push(Vertex {
                        x: hit.x,
                        arrive: u,
                        rho: f64::NAN,
                        beta,
                        opl,
                        segment: Segment::new(volume, inside, outside, parallel, connectible),
                    });
                    (inside, outside, crossings) = (0.0, 0.0, 0);
                    if start.photon {
                        let phase = |d: DVec3| volume.scattering.eval(u.dot(d));
                        self.connect_probes(t, hit.x, beta, opl, phase, rng, out);
                    }
                    if !roulette(&mut beta, rng) || vertices.len() >= MAX_EVENTS {
                        break;
                    }
                    let next = t.scatter(hit.x, u, rng);
                    let rho = volume.scattering.eval(u.dot(next.v.normalize()));
                    if let Some(last) = vertices.last_mut() {
                        last.rho = rho;
                    }
                    leg = Leg::Inside(next);
                }
                Stop::Boundary(end) => {
                    crossings += 1;
                    leg = Leg::leave(t, end, rng);
                }
                Stop::Stuck => break,
            }
        }
        out[self.total(super::Total::Events)].re += vertices.len() as f64;
        out[self.total(super::Total::Steps)].re += steps as f64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::stream_rng;

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
            rho,
            beta: 1.0,
            opl: 0.0,
            segment,
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
                    connectible: uniform(&mut rng) < 0.7,
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
}
