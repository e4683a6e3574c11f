//! Derivatives of what next-event connections carry to fluence probes and cameras, with respect
//! to the medium's and the index field's parameters (particle tracing's `render.derivatives`).
//!
//! A probe receives `W ρ(w_in·d) e^{−σ_t L} R / (dA⊥/dω)` along each stationary path from a
//! scattering event (power `W` arriving along `w_in`; see [`ParticleTracer::connect`]), times
//! Alg. 3's inverse probability. Its derivative is that value times the score of the photon's path
//! before the event, plus the derivative of the connection itself:
//! - a medium parameter: `∂ log` of the phase function evaluated along the connection (the
//!   mixture's, [`crate::medium::params::Param::dlog_mixture`]), and `−L` for σ_s and σ_a (the
//!   transmittance);
//! - an index-field parameter: the connection moves with the field — its direction, length and
//!   ray-tube spread are implicit functions of `n` through the boundary-value problem (paper 002,
//!   Sec. 4) — and with the event, which moves along the photon's forward sensitivities. The
//!   derivative is the central difference of the connection solved again in the field moved by
//!   `±h`, from the event moved by `±h δx` (its incoming direction by `±h δw`), Newton starting
//!   from the path found: the same stationary path, polished by one more Newton step once within
//!   the tolerance (its residual squared, at round-off). `h` moves `n` by at most 1e-5 of its
//!   variation over the volume, so the quotient's truncation is about 1e-10 of the slope; its
//!   round-off is that of the value (about 1e-12 of it where the path reflects inside the
//!   surface, whose sensitivities are central differences of the mirror) over the step, some
//!   1e-7 of the value. (In closed form the spread's derivative would need the ray's
//!   second-order sensitivities, and so third derivatives of `n`.)
//!
//! A camera's connection leaves the volume, refracted at the surface (`T (1 − R) / (dω_out/dω)`
//! or `/ (dA⊥/dω)` for a pinhole), and lands where it lands in the image: solved again at `±h`
//! it lands a little elsewhere, so a tent filter's shares, which move continuously with it, are
//! what makes each pixel's central difference its derivative.
//!
//! The inverse probability multiplies a path's value and its derivative alike: the estimate of
//! `Σ_k f(C_k)` differentiates into the estimate of `Σ_k ∂f(C_k)`.

use super::connect::{Connector, InsidePath};
use super::particle::{CameraLink, ParticleTracer, Tools};
use super::scene::{Derivative, FieldDerivative, MAX_DERIVATIVES, RenderScene, Volume};
use crate::eikonal::{IndexField, part_at};
use crate::math::{C64, Rng};
use glam::DVec3;

const P: usize = MAX_DERIVATIVES;

/// The most `n` moves anywhere for the central differences of a connection, as a fraction of
/// how much it varies over the volume (of `n` itself where it is constant).
const INDEX_STEP: f64 = 1e-5;

/// Points per axis of the grid over which the largest `|∂n/∂θ|` is found.
const GRID: usize = 7;

/// The volume with its index field moved a step each way along every differentiated field
/// parameter, for the central differences of connections (none where nothing is connected: no
/// probes or cameras).
#[derive(Clone, Default)]
pub(super) struct ShiftedFields {
    /// Per index-field parameter, in the order of the scene's derivatives: its slot among them.
    pub slots: Vec<usize>,
    /// Its step `h` (0 where it does not move `n`).
    pub steps: Vec<f64>,
    /// The volume at `θ − h` and at `θ + h`.
    pub volumes: Vec<[Volume; 2]>,
}

impl ShiftedFields {
    pub fn new(scene: &RenderScene) -> Self {
        let mut s = ShiftedFields::default();
        if scene.probes.is_empty() && scene.cameras.is_empty() && scene.pinholes.is_empty() {
            return s;
        }
        for (slot, d) in scene.derivatives.iter().enumerate() {
            let Derivative::Field(f) = d else { continue };
            // a trial step finds how fast the parameter moves n, then the step that moves it by
            // INDEX_STEP at most
            let value = f.stored(&scene.volume.field);
            let trial = 1e-6 * value.map_or(1.0, |v| (v / f.scale).abs().max(1.0));
            let (change, variation) = largest_change(scene, f, &shifted(&scene.volume, f, trial));
            let rate = change / trial;
            let h = if rate > 0.0 && rate.is_finite() {
                INDEX_STEP * variation / rate
            } else {
                0.0
            };
            s.slots.push(slot);
            s.steps.push(h);
            s.volumes
                .push([shifted(&scene.volume, f, -h), shifted(&scene.volume, f, h)]);
        }
        s
    }
}

/// `volume` with field parameter `f` moved by `by` (in the parameter's units).
fn shifted(volume: &Volume, f: &FieldDerivative, by: f64) -> Volume {
    let mut v = volume.clone();
    f.change(&mut v.field, |x| *x += by * f.scale);
    v
}

/// The largest change of `n` from the scene's field to `other` over a grid of points inside the
/// volume whose field `f` is a parameter of, at several instants of the period under a
/// modulation; and how much the scene's `n` varies over them (`n` itself where it is constant).
fn largest_change(scene: &RenderScene, f: &FieldDerivative, other: &Volume) -> (f64, f64) {
    let (base, moved) = (&scene.volume.field, &other.field);
    let (center, half) = match (f.volume, base.bounds.parts()) {
        (Some(k), Some(parts)) => (parts[k].center, parts[k].shape.half_extent()),
        _ => (DVec3::ZERO, base.bounds.half_extent()),
    };
    let half = half.unwrap_or(DVec3::ONE);
    let instants: Vec<Option<f64>> = match scene.modulation {
        Some(_) => (0..8)
            .map(|k| Some(std::f64::consts::TAU * (k as f64 + 0.5) / 8.0 - std::f64::consts::PI))
            .collect(),
        None => vec![None],
    };
    let (mut a, mut b) = (base.clone(), moved.clone());
    let mut largest: f64 = 0.0;
    let (mut lowest, mut highest) = (f64::INFINITY, f64::NEG_INFINITY);
    for instant in instants {
        if let Some(omega_t) = instant {
            super::particle::modulate(&mut a, base, omega_t);
            super::particle::modulate(&mut b, moved, omega_t);
        }
        for i in 0..GRID * GRID * GRID {
            let at = |k: usize| ((k % GRID) as f64 + 0.5) / GRID as f64 * 2.0 - 1.0;
            let x = center + half * DVec3::new(at(i), at(i / GRID), at(i / (GRID * GRID)));
            // inside the volume whose field moves (of several, not another in its box)
            let inside = match (f.volume, base.bounds.parts()) {
                (Some(k), Some(parts)) => base.bounds.contains(x) && part_at(parts, x) == k,
                _ => base.bounds.contains(x),
            };
            if inside {
                let n = a.n(x);
                largest = largest.max((b.n(x) - n).abs());
                (lowest, highest) = (lowest.min(n), highest.max(n));
            }
        }
    }
    let variation = highest - lowest;
    (
        largest,
        if variation > 0.0 {
            variation
        } else {
            highest.abs()
        },
    )
}

/// Where connections leave from: a scattering event (`w_in`: the unit direction the light
/// arrived along) or the light's own point inside the volume (`None`), with the sensitivities of
/// its position and incoming direction to each index-field parameter (in the order of
/// [`ShiftedFields`]; zero for the light's point).
pub(super) struct Vertex {
    pub x: DVec3,
    pub w_in: Option<DVec3>,
    pub dx: [DVec3; P],
    pub dw: [DVec3; P],
}

impl Vertex {
    /// A vertex that does not move with the field.
    pub fn fixed(x: DVec3, w_in: Option<DVec3>) -> Self {
        Vertex {
            x,
            w_in,
            dx: [DVec3::ZERO; P],
            dw: [DVec3::ZERO; P],
        }
    }

    /// Its position and incoming direction moved by `by` along index-field parameter `k`.
    fn moved(&self, k: usize, by: f64) -> (DVec3, Option<DVec3>) {
        let w_in = self.w_in.map(|w| (w + self.dw[k] * by).normalize());
        (self.x + self.dx[k] * by, w_in)
    }
}

/// The intensity per unit power a vertex at `x` with incoming direction `w_in` (`None`: the
/// light's own point) sends along unit `d`: the bulk phase function of `volume` there, or the
/// light's intensity.
pub(super) fn emitted(
    scene: &RenderScene,
    volume: &Volume,
    (x, w_in): (DVec3, Option<DVec3>),
    d: DVec3,
) -> f64 {
    match w_in {
        Some(w) => volume.scattering_at(x).eval(w.dot(d)),
        None => scene.light.intensity(d),
    }
}

/// A connector of `volume` for central differences of paths already found: polished to
/// round-off ([`Connector::polished`]).
fn polished<'v>(scene: &'v RenderScene, volume: &'v Volume) -> Connector<'v> {
    Connector::new(volume, scene.step, scene.max_steps)
        .blocked_by(&scene.surfaces)
        .polished()
}

impl ParticleTracer<'_> {
    /// What a vertex at `x` with incoming direction `w_in` and power `weight` sends along
    /// `path` through `volume` (homogeneous): `weight · emit · e^{−∫σ_t} · F / (dA⊥/dω)`, `F` its
    /// Fresnel factors.
    fn carried(
        &self,
        volume: &Volume,
        (x, w_in): (DVec3, Option<DVec3>),
        weight: f64,
        path: &InsidePath,
    ) -> f64 {
        let emit = emitted(self.scene, volume, (x, w_in), path.direction());
        let attenuation = (-path.lengths(volume).depth(volume)).exp();
        weight * emit * attenuation * path.fresnel() / path.spread()
    }

    /// Next-event connections from `v` (inside) to every probe, carrying `weight` after the
    /// optical path `opl` (as [`Self::connect_probes`] in a homogeneous medium), with the
    /// derivatives of what each probe receives (see the module's documentation): `score` is the
    /// photon's path's so far per derivative, `shifted` the photon's volume moved along each
    /// index-field parameter (empty without them).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn connect_probes_scored(
        &self,
        t: &Tools,
        v: &Vertex,
        weight: f64,
        opl: f64,
        score: &[f64],
        shifted: &[[Volume; 2]],
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let volume = t.flyer.volume;
        let derivatives = &self.scene.derivatives;
        self.probe_paths(t, v.x, rng, out, |out, i, c, inverse_p, _| {
            let value = self.carried(volume, (v.x, v.w_in), weight, c) * inverse_p;
            if !(value > 0.0 && value.is_finite() && self.add_to_probe(t, i, c, value, opl, out)) {
                return;
            }
            // the event scatters by its own volume's phase function; the connection is
            // attenuated in every volume it runs through
            let part = volume.part_index(v.x);
            let lengths = c.lengths(volume);
            for (j, d) in derivatives.iter().enumerate() {
                let Derivative::Medium(m) = d else {
                    out[self.probe_derivative(i, j)].re += value * score[j];
                    continue;
                };
                let phase = match (d.medium_in(part), v.w_in) {
                    (Some(m), Some(w)) => {
                        m.dlog_mixture(volume.scattering_of(part), w.dot(c.direction()))
                    }
                    _ => 0.0,
                };
                let attenuation = if m.param.is_coefficient() {
                    -lengths.within(m.volume)
                } else {
                    0.0
                };
                out[self.probe_derivative(i, j)].re += value * (score[j] + phase + attenuation);
            }
            let y = self.scene.probes[i].position;
            for (k, volumes) in shifted.iter().enumerate() {
                let h = self.shifted.steps[k];
                if h == 0.0 {
                    continue;
                }
                let moved = [(0, -h), (1, h)].map(|(side, by)| {
                    let (x, w_in) = v.moved(k, by);
                    let volume = &volumes[side];
                    let connector = polished(self.scene, volume);
                    // the same path, solved again: within one volume or between two
                    let path = match *c {
                        InsidePath::Within(_, bounces) => InsidePath::Within(
                            connector.solve_bounced(x, y, c.direction(), bounces)?,
                            bounces,
                        ),
                        InsidePath::Between(_, bounces) => InsidePath::Between(
                            connector.solve_into(x, y, c.direction(), &bounces)?,
                            bounces,
                        ),
                    };
                    Some(self.carried(volume, (x, w_in), weight, &path))
                });
                if let [Some(down), Some(up)] = moved {
                    let slope = (up - down) / (2.0 * h) * inverse_p;
                    out[self.probe_derivative(i, self.shifted.slots[k])].re += slope;
                }
            }
        });
    }
}

impl ParticleTracer<'_> {
    /// Next-event connections from `v` (inside) to every camera, carrying `weight` after the
    /// optical path `opl` (as [`Self::connect`] in a homogeneous medium), with the derivatives of
    /// each camera's image: as the probes' ([`Self::connect_probes_scored`]), the index field's
    /// by the paths solved again in the shifted fields, each landing in its own pixels (a tent
    /// filter's shares move continuously with it).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn connect_cameras_scored(
        &self,
        t: &Tools,
        v: &Vertex,
        weight: f64,
        opl: f64,
        score: &[f64],
        shifted: &[[Volume; 2]],
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let volume = t.flyer.volume;
        let emit = |volume, at, d| emitted(self.scene, volume, at, d);
        for i in 0..self.scene.cameras.len() + self.scene.pinholes.len() {
            for way in self.ways(t, false) {
                let Some((e, inverse_p, bounces)) = self.camera_exit(t, v.x, i, way, rng, out)
                else {
                    continue;
                };
                let carried = |volume: &Volume, e: &super::connect::Exit| {
                    e.attenuation(volume) * e.transmission / e.jacobian * inverse_p
                };
                let Some(link) = self.link_to_camera(t, i, &e, || carried(volume, &e)) else {
                    continue;
                };
                let scale = weight * emit(volume, (v.x, v.w_in), link.direction);
                let event = v.w_in.map(|w| (v.x, w));
                if !self.record_link_scored(t, &link, (scale, opl), score, event, out) {
                    continue;
                }
                for (k, volumes) in shifted.iter().enumerate() {
                    let h = self.shifted.steps[k];
                    if h == 0.0 {
                        continue;
                    }
                    let moved = [(0, -h), (1, h)].map(|(side, by)| {
                        let (x, w_in) = v.moved(k, by);
                        let volume = &volumes[side];
                        let tools = Tools {
                            connector: polished(self.scene, volume),
                            ..Tools::new(volume, self.scene, t.colour, t.delay)
                        };
                        let e =
                            self.camera_exit_from(&tools.connector, x, i, e.direction, &bounces)?;
                        let link = self.link_to_camera(&tools, i, &e, || carried(volume, &e))?;
                        let scale = weight * emit(volume, (x, w_in), link.direction);
                        Some((link, scale))
                    });
                    let [Some((down, s_down)), Some((up, s_up))] = moved else {
                        continue;
                    };
                    let slot = self.shifted.slots[k];
                    self.add_link_slope(&up, s_up / (2.0 * h), slot, out);
                    self.add_link_slope(&down, -s_down / (2.0 * h), slot, out);
                }
            }
        }
    }

    /// Record `link` carrying `scale` after the optical path `opl` ([`Self::record_link`]) and,
    /// with derivatives, its value times the path's `score` plus its own medium derivatives: `∂
    /// log` of the phase function at a scattering event (`event`: its position and incoming
    /// direction; none from the light or a surface) for the medium there, `−L` inside each
    /// volume for its σ_s and σ_a. `false` if it adds nothing.
    pub(super) fn record_link_scored(
        &self,
        t: &Tools,
        link: &CameraLink,
        (scale, opl): (f64, f64),
        score: &[f64],
        event: Option<(DVec3, DVec3)>,
        out: &mut [C64],
    ) -> bool {
        if self.record_link(t, link, scale, opl, out).is_none() {
            return false;
        }
        let volume = t.flyer.volume;
        let at = event.map(|(x, w_in)| (volume.part_index(x), w_in.dot(link.direction)));
        for (j, d) in self.scene.derivatives.iter().enumerate() {
            let own = match d {
                // a coefficient attenuates the stretches inside its volume; the phase function's
                // parameters and shares weigh the scattering event's
                Derivative::Medium(m) if m.param.is_coefficient() => -link.inside.within(m.volume),
                Derivative::Medium(_) => at.map_or(0.0, |(part, mu)| {
                    d.medium_in(part)
                        .map_or(0.0, |p| p.dlog_mixture(volume.scattering_of(part), mu))
                }),
                Derivative::Field(_) => 0.0,
            };
            self.add_link_slope(link, scale * (score[j] + own), j, out);
        }
        true
    }

    /// Add `coef` times `link`'s unit values to its camera's derivative image in
    /// `scene.derivatives[j]`: each pixel's share of its radiance, and the total's and windows'.
    fn add_link_slope(&self, link: &CameraLink, coef: f64, j: usize, out: &mut [C64]) {
        if !coef.is_finite() {
            return;
        }
        let image = self.camera_derivative(link.camera, j);
        let windows = self.window_slopes(j);
        for &(pixel, share) in &link.pixels.0[..link.pixels.1] {
            out[image.first + pixel].re += coef * link.radiance * share;
            let total = coef * link.total * share;
            out[image.total()].re += total;
            self.add_to_windows(link.camera, pixel, total, windows, out);
        }
    }
}
