//! The tube a collimated beam fills inside the volume, and the free flights of bidirectional
//! tracing's camera subpaths that draw their collision in it.
//!
//! In a weakly scattering medium a camera subpath's flight lands in a thin beam only now and
//! then (with chance `σ_t` times the chord), so the paths that scatter twice — in the beam, then
//! on the camera's line of sight — are made mostly by joining a light event in the beam to a
//! camera event, and the phase function's forward peak at the camera event makes the few joins
//! that land behind it carry much. So a flight from a camera event inside the volume draws its
//! collision from a mixture: a free flight with chance [`FREE_SHARE`], else a point uniformly on
//! the first stretch where its ray runs through the beam's tube (the forced collisions of
//! Monte Carlo transport, aimed at the beam), each leg after a reflection inside the surface
//! again. The flight's weight divides by the mixture's density, so the estimate stays unbiased
//! for any tube; the balance heuristic's densities of an event from the camera's side take the
//! mixture too, along the curved (and reflected) path between the events however the segment
//! was made ([`BeamTube::factor_along`]).
//!
//! Where the whole volume is optically thin ([`THIN_VOLUME_DEPTH`]) most camera rays cross it
//! without an event, and the paths that scatter twice near the beam need one on the camera's
//! line of sight in front of it. So a camera subpath's first leg into the volume draws its
//! collision from the same kind of mixture, the forced draw uniform along the whole leg to the
//! surface ([`Forced::Leg`]); the density of an event on that leg made by a connection to the
//! camera takes it too ([`BeamTube::first_leg_factor`]).
//!
//! There the camera's events in front of the beam still reach it only where the phase
//! function's draw runs into the thin tube. So a camera subpath scatters from its events inside
//! by a mixture too: the phase function with chance [`PHASE_SHARE`], else a direction aimed at
//! a point of the tube drawn by the phase function towards each slice of it times the solid
//! angle the slice subtends (a product of the two, slice by slice), the slices moved against
//! the bend of the rays in a graded index so that the curved ray reaches them
//! ([`BeamTube::aiming`]). The weight divides by the mixture's density over the phase function's,
//! and the balance heuristic's densities of a direction from the camera's side take it, at a
//! light event as at a camera event ([`BeamTube::aim_density`]).

use super::flight::{Flight, Flyer};
use super::particle::{Stop, Tools, Travelled};
use super::scene::Light;
use crate::eikonal::trace::{entry_parameter, refract};
use crate::eikonal::{Bounds, Ray};
use crate::math::{Rng, uniform};
use crate::medium::Scattering;
use glam::DVec3;
use std::f64::consts::PI;

/// The chance that a camera subpath's flight through the beam's tube is a plain free flight;
/// otherwise its collision is drawn uniformly on the tube's first stretch.
pub(super) const FREE_SHARE: f64 = 0.5;

/// The optical depth across a beam (its diameter times `σ_t` where it enters) below which the
/// camera paths' flights draw from its tube: a free flight that crosses a thicker beam collides
/// in it often enough, and the draws would only cost flights (on a wide beam into a scattering
/// Luneburg lens they took a fifth more time for no less noise).
const THIN_BEAM_DEPTH: f64 = 0.25;

/// The optical depth across the volume (`σ_t` times its bounding box's diagonal) up to which
/// camera subpaths draw their first leg's collision from a mixture uniform along the leg: there
/// a free flight across collides less than every other time. (In a thicker volume the draws
/// take camera paths from the light that passes the first leg, reflected inside or out to a
/// surface: on a small graded tank of depth 1.2 they cost 11 % to 17 % more time, and the
/// noise moved either way.)
const THIN_VOLUME_DEPTH: f64 = 1.0;

/// The most pieces of the tube's polyline.
const MAX_PIECES: usize = 64;

/// The share of a camera event's scattering directions drawn from its phase function where
/// the camera subpaths aim at the tube; the rest are aimed at it ([`BeamTube::aiming`]).
pub(super) const PHASE_SHARE: f64 = 0.5;

/// How many slices of about equal length the tube is cut into for aiming at it (a piece of the
/// polyline shorter than that is one slice).
const SLICES: usize = 64;

/// The most slices: [`SLICES`] and one more for each piece.
const MAX_SLICES: usize = SLICES + MAX_PIECES;

/// A straight stretch of the tube: the cylinder of the beam's radius about `start + s axis`,
/// `0 ≤ s ≤ length`.
#[derive(Clone, Copy, Debug)]
struct Slice {
    start: DVec3,
    axis: DVec3,
    length: f64,
}

/// The tube's slices as aimed at from one camera event, with their weights
/// ([`BeamTube::aiming`]): the aimed draw ([`Self::draw`]) and its density ([`Self::density`]).
pub(super) struct Aiming {
    x: DVec3,
    radius: f64,
    slices: [Slice; MAX_SLICES],
    weights: [f64; MAX_SLICES],
    count: usize,
    total: f64,
}

impl Aiming {
    /// A direction aimed at the tube: a slice drawn by its weight (the phase function times its
    /// solid angle, a discrete product of the two), a point drawn evenly in its cylinder, the
    /// unit direction to it (`fallback` should that be the event itself).
    pub(super) fn draw(&self, fallback: DVec3, rng: &mut Rng) -> DVec3 {
        let mut pick = uniform(rng) * self.total;
        let mut i = 0;
        while i + 1 < self.count && pick >= self.weights[i] {
            pick -= self.weights[i];
            i += 1;
        }
        let slice = self.slices[i];
        let (e1, e2) = crate::math::orthonormal_basis(slice.axis);
        let (r, phi) = (self.radius * uniform(rng).sqrt(), 2.0 * PI * uniform(rng));
        let z = slice.start
            + slice.axis * (slice.length * uniform(rng))
            + (e1 * phi.cos() + e2 * phi.sin()) * r;
        (z - self.x).try_normalize().unwrap_or(fallback)
    }

    /// The density per solid angle of [`Self::draw`] drawing unit `d`: the points it aims at
    /// have the density `P_i / V_i` in slice `i` (its chance over its volume), so the
    /// direction's is `Σ_i P_i / V_i ∫ t² dt` over the stretch of the ray `x + t d`, `t ≥ 0`,
    /// inside that slice's cylinder.
    pub(super) fn density(&self, d: DVec3) -> f64 {
        let area = PI * self.radius * self.radius;
        let mut sum = 0.0;
        for (slice, w) in self.slices.iter().zip(&self.weights).take(self.count) {
            let end = slice.start + slice.axis * slice.length;
            if let Some((t0, t1)) = cylinder(slice.start, end, self.radius, self.x, d) {
                let t0 = t0.max(0.0);
                if t0 < t1 {
                    sum += w * (t1.powi(3) - t0.powi(3)) / (3.0 * slice.length * area);
                }
            }
        }
        sum / self.total
    }
}

/// Where a flight's forced draw is uniform: on the first stretch of its ray through the tube
/// (a flight from an event inside), or along its whole leg to the surface (a camera subpath's
/// first leg into a thin volume).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Forced {
    Tube,
    Leg,
}

/// The beam's central ray inside the volume, as a polyline of few corners (within a tenth of
/// the radius of the ray), widened by the beam's radius: the region the beam's unscattered light
/// fills (up to the spread of its rays in a graded index).
#[derive(Clone, Debug)]
pub(super) struct BeamTube {
    corners: Vec<DVec3>,
    radius: f64,
    /// The tube's bounding box, for a quick miss.
    lo: DVec3,
    hi: DVec3,
    /// Whether camera subpaths draw their first leg's collision along it, and aim half their
    /// scattering directions at it: one convex volume, optically thin across
    /// ([`THIN_VOLUME_DEPTH`]).
    first_legs: bool,
    /// The polyline cut into slices, for aiming at it.
    slices: Vec<Slice>,
}

impl BeamTube {
    /// The tube of a collimated beam of non-zero radius through the volume `flyer` flies in:
    /// its central ray refracted in where it meets the surface, and flown on to the surface
    /// (along curved rays in a graded index). `None` for other lights, a beam that misses the
    /// volume, or one that is not thin for the medium where it enters ([`THIN_BEAM_DEPTH`]).
    pub(super) fn trace(light: &Light, flyer: &Flyer) -> Option<Self> {
        let Light::Beam {
            center,
            direction,
            radius,
        } = *light
        else {
            return None;
        };
        if radius <= 0.0 {
            return None;
        }
        let field = &flyer.volume.field;
        let (t0, _) = field
            .bounds
            .interval(center, direction)
            .filter(|&(t0, t1)| t1 > 0.0 && t0 >= 0.0)?;
        let at = center + direction * t0;
        let inside = center + direction * entry_parameter(t0);
        if 2.0 * radius * flyer.volume.sigma_t_at(inside) >= THIN_BEAM_DEPTH {
            return None;
        }
        let n_in = flyer.n(inside);
        let normal = field.bounds.normal(at).unwrap_or(-direction);
        let w = refract(direction, normal, field.n_out / n_in).ok()?;
        let mut points = vec![inside];
        let ray = Ray {
            x: inside,
            v: w * n_in,
        };
        flyer.fly_visiting(ray, f64::INFINITY, |_, to| points.push(to));
        // at most MAX_PIECES pieces: a coarser polyline where the ray curves much
        let mut tolerance = 0.1 * radius;
        let mut corners = simplify(&points, tolerance);
        while corners.len() > MAX_PIECES + 1 {
            tolerance *= 2.0;
            corners = simplify(&points, tolerance);
        }
        let (mut lo, mut hi) = (corners[0], corners[0]);
        for &c in &corners {
            lo = lo.min(c);
            hi = hi.max(c);
        }
        let first_legs = flyer.volume.parts.is_empty()
            && field.bounds.is_convex()
            && field.bounds.half_extent().is_some_and(|half| {
                2.0 * half.length() * flyer.volume.sigma_t() <= THIN_VOLUME_DEPTH
            });
        let slices = slice(&corners);
        Some(BeamTube {
            corners,
            radius,
            lo: lo - DVec3::splat(radius),
            hi: hi + DVec3::splat(radius),
            first_legs,
            slices,
        })
    }

    /// Whether camera subpaths aim half the scattering directions of their events inside the
    /// volume at it ([`Self::aim`]): where they draw their first legs along themselves.
    pub(super) fn aims(&self) -> bool {
        self.first_legs && !self.slices.is_empty()
    }

    /// The same tube, not aimed at.
    pub(super) fn without_aiming(self) -> Self {
        BeamTube {
            slices: Vec::new(),
            ..self
        }
    }

    /// The slices as aimed at from `x`, where rays bend by `bend` (`∇n / n`, the curvature of a
    /// ray across the gradient) and the camera subpath arrived along unit `arrive`. Each slice
    /// is moved by `−bend r² / 2`, `r` the distance to its middle, so that a ray aimed straight
    /// at the moved slice reaches the slice itself (to first order in the bend); its weight is
    /// the phase function towards the moved slice's middle times the solid angle it subtends
    /// there (its side and end seen from `x`, at most 2π; the phase function kept above zero,
    /// so that every slice can be drawn).
    pub(super) fn aiming(
        &self,
        scattering: &Scattering,
        (x, bend): (DVec3, DVec3),
        arrive: DVec3,
    ) -> Aiming {
        let rho = self.radius;
        let mut aiming = Aiming {
            x,
            radius: rho,
            slices: [Slice {
                start: DVec3::ZERO,
                axis: DVec3::Z,
                length: 0.0,
            }; MAX_SLICES],
            weights: [0.0; MAX_SLICES],
            count: self.slices.len(),
            total: 0.0,
        };
        for (i, slice) in self.slices.iter().enumerate() {
            let middle = slice.start + slice.axis * (0.5 * slice.length);
            let shift = bend * (0.5 * (middle - x).length_squared());
            let v = middle - shift - x;
            let r2 = v.length_squared();
            let u = v / r2.sqrt().max(f64::MIN_POSITIVE);
            let (sin, cos) = (u.cross(slice.axis).length(), u.dot(slice.axis).abs());
            let solid = if r2 <= rho * rho {
                2.0 * PI
            } else {
                ((2.0 * rho * slice.length * sin + PI * rho * rho * cos) / r2).min(2.0 * PI)
            };
            aiming.slices[i] = Slice {
                start: slice.start - shift,
                ..*slice
            };
            aiming.weights[i] = scattering.eval(arrive.dot(u)).max(f64::MIN_POSITIVE) * solid;
            aiming.total += aiming.weights[i];
        }
        aiming
    }

    /// [`Aiming::density`] of unit `d` from `x` ([`Self::aiming`]'s arguments), zero at once
    /// where `d` misses the tube's box widened by the most any slice is moved.
    pub(super) fn aim_density(
        &self,
        scattering: &Scattering,
        (x, bend): (DVec3, DVec3),
        arrive: DVec3,
        d: DVec3,
    ) -> f64 {
        let reach = (x - self.lo)
            .abs()
            .max((x - self.hi).abs())
            .length_squared();
        let pad = DVec3::splat(0.5 * reach * bend.length());
        if !box_meets(self.lo - pad, self.hi + pad, x, d, f64::INFINITY) {
            return 0.0;
        }
        self.aiming(scattering, (x, bend), arrive).density(d)
    }

    /// Whether camera subpaths draw their first leg's collision along it ([`Forced::Leg`]).
    pub(super) fn draws_first_legs(&self) -> bool {
        self.first_legs
    }

    /// The first stretch `[a, b]` of the segment `p + t d`, `0 ≤ t ≤ length` (unit `d`), that
    /// runs inside the tube.
    pub(super) fn first_stretch(&self, p: DVec3, d: DVec3, length: f64) -> Option<(f64, f64)> {
        if !box_meets(self.lo, self.hi, p, d, length) {
            return None;
        }
        // the capsules about each piece of the polyline: the first stretch is the earliest
        // interval with every interval overlapping it merged in
        let mut pieces = [(0.0, 0.0); MAX_PIECES];
        let mut count = 0;
        for pair in self.corners.windows(2) {
            let Some((a, b)) = capsule(pair[0], pair[1], self.radius, p, d) else {
                continue;
            };
            let (a, b) = (a.max(0.0), b.min(length));
            if a < b {
                pieces[count] = (a, b);
                count += 1;
            }
        }
        let pieces = &mut pieces[..count];
        pieces.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut first: Option<(f64, f64)> = None;
        for &(a, b) in pieces.iter() {
            match &mut first {
                None => first = Some((a, b)),
                Some(f) if a <= f.1 => f.1 = f.1.max(b),
                Some(_) => break,
            }
        }
        first
    }

    /// The ray flown to the surface (its steps), and the stretch `[a, b]` of it, in geometric
    /// length from its start, its forced draw is uniform on: the first that runs through the
    /// tube, or the whole leg.
    fn flown(&self, t: &Tools, ray: Ray, forced: Forced) -> (Flight, usize, Option<(f64, f64)>) {
        let (mut along, mut stretch, mut open) = (0.0, None::<(f64, f64)>, forced == Forced::Tube);
        let (flight, steps) = t.flyer.fly_visiting(ray, f64::INFINITY, |from, to| {
            let v = to - from;
            let length = v.length();
            if open && length > 0.0 {
                match (self.first_stretch(from, v / length, length), &mut stretch) {
                    (Some((a, b)), None) => stretch = Some((along + a, along + b)),
                    // the stretch runs on from the chord before
                    (Some((a, b)), Some(s)) if a <= 1e-9 * length => s.1 = along + b,
                    (_, Some(_)) => open = false,
                    (None, None) => {}
                }
                if let Some((_, b)) = stretch {
                    open &= b >= along + length * (1.0 - 1e-9);
                }
            }
            along += length;
        });
        let stretch = match flight {
            Flight::Boundary { length: exit, .. } if forced == Forced::Leg => {
                Some((0.0, exit)).filter(|_| exit > 0.0)
            }
            Flight::Boundary { length: exit, .. } => stretch
                .map(|(a, b)| (a, b.min(exit)))
                .filter(|(a, b)| a < b),
            _ => None,
        };
        (flight, steps, stretch)
    }

    /// A camera subpath's flight along `ray` in a homogeneous volume, from its event inside or
    /// its first leg in: the ray flown to the surface and the stretch of its forced draw found
    /// (`forced`), then the collision drawn from the mixture (a free flight with chance
    /// [`FREE_SHARE`], else uniformly on the stretch; a free flight alone where the ray misses
    /// the tube) and the ray flown to it again. Where it stopped, how far, and the factor the
    /// subpath's weight is divided by (the mixture's density over the free flight's,
    /// [`Self::mixture_over_free`]), which the balance heuristic's density of the collision from
    /// the camera's side takes too.
    pub(super) fn flight(
        &self,
        t: &Tools,
        ray: Ray,
        forced: Forced,
        rng: &mut Rng,
    ) -> (Stop, Travelled, f64) {
        let volume = t.flyer.volume;
        let part = volume.part_index(ray.x).unwrap_or(0);
        let sigma_t = volume.sigma_t_at(ray.x);
        let (flight, steps, stretch) = self.flown(t, ray, forced);
        let stretch = stretch.filter(|_| sigma_t > 0.0);
        let mut travelled = Travelled {
            steps,
            ..Travelled::default()
        };
        let Flight::Boundary {
            ray: end,
            optical_path,
            length: exit,
        } = flight
        else {
            return (Stop::Stuck, travelled, 1.0);
        };
        let s = match stretch {
            Some((a, b)) if uniform(rng) >= FREE_SHARE => a + (b - a) * uniform(rng),
            _ if sigma_t > 0.0 => -(1.0 - uniform(rng)).ln() / sigma_t,
            _ => f64::INFINITY,
        };
        if s < exit {
            let (again, steps) = t.flyer.fly(ray, s);
            travelled.steps += steps;
            if let Flight::Collision {
                ray: hit,
                optical_path,
                length,
            } = again
            {
                travelled.add(t, part, optical_path, length);
                let factor = Self::mixture_over_free(stretch, s, sigma_t, true);
                return (Stop::Collision(hit), travelled, factor);
            }
        }
        travelled.add(t, part, optical_path, exit);
        let factor = Self::mixture_over_free(stretch, exit, sigma_t, false);
        (Stop::Boundary(end), travelled, factor)
    }

    /// The factor [`Self::flight`] gives a collision `length` along the path from `x` inside the
    /// volume along unit `d` that reflects `bounces` times inside the surface on its way (a
    /// segment between two events made some other way, as a camera subpath would have drawn it,
    /// each leg from the last event or reflection its own flight), and the leapfrog steps that
    /// took: the product of each leg's mixture over the free flight's, the legs before the last
    /// passed through, the last ending in the collision.
    pub(super) fn factor_along(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        bounces: usize,
        length: f64,
    ) -> (f64, usize) {
        let sigma_t = t.flyer.volume.sigma_t_at(x);
        if sigma_t <= 0.0 {
            return (1.0, 0);
        }
        let mut ray = Ray {
            x,
            v: d * t.flyer.n(x),
        };
        let (mut factor, mut steps, mut left) = (1.0, 0, length);
        for leg in 0..=bounces {
            let (flight, k, stretch) = self.flown(t, ray, Forced::Tube);
            steps += k;
            let Flight::Boundary {
                ray: end, length, ..
            } = flight
            else {
                break;
            };
            if leg == bounces {
                return (
                    factor * Self::mixture_over_free(stretch, left, sigma_t, true),
                    steps,
                );
            }
            factor *= Self::mixture_over_free(stretch, length, sigma_t, false);
            left -= length;
            ray = t.flyer.reflected_inside(end);
        }
        (factor, steps)
    }

    /// The factor [`Self::flight`] gives a collision on a camera subpath's first leg into the
    /// volume ([`Forced::Leg`]) at `x`, `length` along the leg, the camera's ray arriving along
    /// unit `d` (an event connected to the camera, as the camera would have drawn it), and the
    /// leapfrog steps that took: the ray flown on from `x` to the surface gives the leg's whole
    /// length.
    pub(super) fn first_leg_factor(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        length: f64,
    ) -> (f64, usize) {
        let sigma_t = t.flyer.volume.sigma_t_at(x);
        if sigma_t <= 0.0 {
            return (1.0, 0);
        }
        let ray = Ray {
            x,
            v: d * t.flyer.n(x),
        };
        let (flight, steps) = t.flyer.fly(ray, f64::INFINITY);
        let Flight::Boundary { length: rest, .. } = flight else {
            return (1.0, steps);
        };
        let leg = Some((0.0, length + rest));
        (Self::mixture_over_free(leg, length, sigma_t, true), steps)
    }

    /// The flight's own mixture at its collision `s` along its ray (whose first stretch through
    /// the tube is `stretch`), over the free flight's density `σ_t e^{−σ_t s}` there: the factor
    /// its weight is divided by. At the surface (`s` the exit, `collided` false) the chance of
    /// reaching it, over `e^{−σ_t s}`.
    pub(super) fn mixture_over_free(
        stretch: Option<(f64, f64)>,
        s: f64,
        sigma_t: f64,
        collided: bool,
    ) -> f64 {
        let Some((a, b)) = stretch else {
            return 1.0;
        };
        if !collided {
            return FREE_SHARE;
        }
        let free = sigma_t * (-sigma_t * s).exp();
        let forced = if a <= s && s <= b { 1.0 / (b - a) } else { 0.0 };
        FREE_SHARE + (1.0 - FREE_SHARE) * forced / free
    }
}

/// The polyline through `corners` cut into slices of about equal length, about [`SLICES`] in
/// all (at least one per piece).
fn slice(corners: &[DVec3]) -> Vec<Slice> {
    let total: f64 = corners.windows(2).map(|p| (p[1] - p[0]).length()).sum();
    let mut slices = Vec::new();
    for pair in corners.windows(2) {
        let v = pair[1] - pair[0];
        let length = v.length();
        if length <= 0.0 {
            continue;
        }
        let count = ((SLICES as f64 * length / total).round() as usize).max(1);
        let axis = v / length;
        for k in 0..count {
            slices.push(Slice {
                start: pair[0] + v * (k as f64 / count as f64),
                axis,
                length: length / count as f64,
            });
        }
    }
    slices.truncate(MAX_SLICES);
    slices
}

/// Ramer–Douglas–Peucker: the corners of `points` that keep the polyline within `tolerance`.
fn simplify(points: &[DVec3], tolerance: f64) -> Vec<DVec3> {
    let mut keep = vec![false; points.len()];
    keep[0] = true;
    keep[points.len() - 1] = true;
    let mut stack = vec![(0, points.len() - 1)];
    while let Some((i, j)) = stack.pop() {
        if j <= i + 1 {
            continue;
        }
        let (a, b) = (points[i], points[j]);
        let (far, distance) = (i + 1..j)
            .map(|k| (k, distance_to_segment(points[k], a, b)))
            .fold((i, 0.0), |m, c| if c.1 > m.1 { c } else { m });
        if distance > tolerance {
            keep[far] = true;
            stack.push((i, far));
            stack.push((far, j));
        }
    }
    points
        .iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect()
}

fn distance_to_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    (p - a - ab * t).length()
}

/// Whether the segment `p + t d`, `0 ≤ t ≤ length`, meets the box `[lo, hi]`.
fn box_meets(lo: DVec3, hi: DVec3, p: DVec3, d: DVec3, length: f64) -> bool {
    let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
    Bounds::Box { half }
        .interval(p - centre, d)
        .is_some_and(|(t0, t1)| t0 <= length && t1 >= 0.0)
}

/// The interval of the line `p + t d` (unit `d`) within `radius` of the segment `a b`: the
/// capsule is convex, so the interval is the hull of those of its cylinder and its two balls.
fn capsule(a: DVec3, b: DVec3, radius: f64, p: DVec3, d: DVec3) -> Option<(f64, f64)> {
    [
        ball(a, radius, p, d),
        ball(b, radius, p, d),
        cylinder(a, b, radius, p, d),
    ]
    .into_iter()
    .flatten()
    .reduce(|(u, v), (x, y)| (u.min(x), v.max(y)))
}

/// The interval of the line `p + t d` (unit `d`) inside the cylinder of `radius` about the
/// segment `a b`, between its two end planes.
fn cylinder(a: DVec3, b: DVec3, radius: f64, p: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let axis = b - a;
    let length = axis.length();
    if length <= 0.0 {
        return None;
    }
    let u = axis / length;
    let (q, e) = (p - a, d - u * d.dot(u));
    let m = q - u * q.dot(u);
    let (qa, qb, qc) = (e.dot(e), 2.0 * e.dot(m), m.dot(m) - radius * radius);
    // the infinite cylinder: all of the line where it runs along the axis inside
    let (mut lo, mut hi) = if qa > 1e-300 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        ((-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa))
    } else if qc <= 0.0 {
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        return None;
    };
    // clipped to the slab 0 ≤ (x − a)·u ≤ length
    let (s0, sd) = (q.dot(u), d.dot(u));
    if sd.abs() > 1e-300 {
        let (c0, c1) = (-s0 / sd, (length - s0) / sd);
        lo = lo.max(c0.min(c1));
        hi = hi.min(c0.max(c1));
    } else if s0 < 0.0 || s0 > length {
        return None;
    }
    (lo < hi).then_some((lo, hi))
}

/// The interval of the line `p + t d` (unit `d`) inside the ball about `c`.
fn ball(c: DVec3, radius: f64, p: DVec3, d: DVec3) -> Option<(f64, f64)> {
    Bounds::Sphere { radius }.interval(p - c, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Rng, stream_rng, uniform, uniform_sphere};

    /// A box of half side `half` graded upwards, `n = 1.33 + gradient · y`, scattering evenly.
    fn graded_box(
        half: f64,
        gradient: f64,
        sigma_s: f64,
        sigma_a: f64,
    ) -> super::super::scene::Volume {
        use crate::eikonal::{BoundedField, Profile};
        use crate::medium::{PhaseFunction, Scattering};
        super::super::scene::Volume {
            field: BoundedField::single(
                Profile::Linear {
                    n0: 1.33,
                    gradient: DVec3::new(0.0, gradient, 0.0),
                },
                Bounds::Box {
                    half: DVec3::splat(half),
                },
                1.0,
            ),
            sigma_s,
            sigma_a,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        }
    }

    /// Weighted tallies `(sum, sum of squares)` of `n` flights' collisions in equal bins over
    /// `[0, span]`, and with `surface` (the last entry) of their reaching the surface at `span`,
    /// against the free flight's chances there, `e^{−σ_t s_0} − e^{−σ_t s_1}` and `e^{−σ_t span}`
    /// (4σ): each bin's chance and the tally's standard error.
    fn assert_free_flight_tallies(
        tally: &[(f64, f64)],
        n: usize,
        (sigma_t, span): (f64, f64),
        surface: bool,
    ) -> Vec<(f64, f64)> {
        let bins = tally.len() - usize::from(surface);
        let width = span / bins as f64;
        let chance = |k: usize| {
            let (s0, s1) = (k as f64 * width, (k + 1) as f64 * width);
            if k < bins {
                (-sigma_t * s0).exp() - (-sigma_t * s1).exp()
            } else {
                (-sigma_t * span).exp()
            }
        };
        let mut checked = Vec::with_capacity(tally.len());
        for (k, &(sum, squares)) in tally.iter().enumerate() {
            let want = chance(k);
            let mean = sum / n as f64;
            let error = ((squares / n as f64 - mean * mean) / n as f64).sqrt();
            assert!(
                (mean - want).abs() < 4.0 * error,
                "bin {k}: {mean} ± {error} vs {want}"
            );
            checked.push((want, error));
        }
        checked
    }

    /// The flyer and connector of `volume`, step 0.01.
    fn tools(volume: &super::super::scene::Volume) -> Tools<'_> {
        Tools {
            flyer: Flyer::new(volume, 0.01, 1_000_000),
            connector: super::super::connect::Connector::new(volume, 0.01, 1_000_000),
            colour: [1.0; 3],
            delay: super::super::spectrum::Delay::NONE,
            instant: None,
        }
    }

    /// A beam of radius 0.05 along `z` from `(0, 0, z)`.
    fn beam_along_z(z: f64) -> Light {
        Light::Beam {
            center: DVec3::new(0.0, 0.0, z),
            direction: DVec3::Z,
            radius: 0.05,
        }
    }

    /// Directions aimed at a bent tube have the density `aim_density` says: it integrates to
    /// one over the sphere, and its integral over each octant (both by uniform directions)
    /// is the share of aimed directions that fall there (4σ), from points beside the tube, far
    /// from it and inside it.
    #[test]
    fn directions_aimed_at_the_tube_have_the_density_it_gives() {
        use crate::medium::{PhaseFunction, Scattering};
        let corners = vec![
            DVec3::new(0.0, 0.0, -2.0),
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.0, 0.5, 2.0),
        ];
        let tube = BeamTube {
            slices: slice(&corners),
            corners,
            radius: 0.2,
            lo: DVec3::new(-0.2, -0.2, -2.2),
            hi: DVec3::new(0.2, 0.7, 2.2),
            first_legs: true,
        };
        assert!(tube.slices.len() >= SLICES && tube.slices.len() <= MAX_SLICES);
        let hg = Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.8 });
        let octant = |d: DVec3| {
            usize::from(d.x > 0.0) + 2 * usize::from(d.y > 0.0) + 4 * usize::from(d.z > 0.0)
        };
        let mut rng: Rng = stream_rng(5, 0);
        // rays bending in a graded index: the aimed slices move away from the tube
        let bend = DVec3::new(0.0, 0.05, 0.02);
        let points = [
            (
                DVec3::new(0.6, 0.2, -1.0),
                DVec3::new(-1.0, 0.0, 0.2).normalize(),
            ),
            (DVec3::new(3.0, -1.0, 1.5), DVec3::new(0.0, 1.0, 0.0)),
            (
                DVec3::new(0.05, 0.0, -0.5),
                DVec3::new(1.0, 1.0, 1.0).normalize(),
            ),
        ];
        for (x, arrive) in points {
            // uniform directions: 4π q and its octants' integrals
            let n = 400_000;
            let (mut sum, mut squares) = (0.0, 0.0);
            let mut octants = [(0.0, 0.0); 8];
            for _ in 0..n {
                let d = uniform_sphere(uniform(&mut rng), uniform(&mut rng));
                let q = 4.0 * PI * tube.aim_density(&hg, (x, bend), arrive, d);
                sum += q;
                squares += q * q;
                let o = &mut octants[octant(d)];
                o.0 += q;
                o.1 += q * q;
            }
            let error = |(sum, squares): (f64, f64), n: usize| {
                let mean = sum / n as f64;
                (mean, ((squares / n as f64 - mean * mean) / n as f64).sqrt())
            };
            let (mean, sigma) = error((sum, squares), n);
            assert!(
                (mean - 1.0).abs() < 4.0 * sigma,
                "{x}: ∫ q = {mean} ± {sigma}"
            );
            // aimed directions: their octants
            let m = 100_000;
            let mut counts = [0usize; 8];
            for _ in 0..m {
                let d = tube.aiming(&hg, (x, bend), arrive).draw(arrive, &mut rng);
                let q = tube.aim_density(&hg, (x, bend), arrive, d);
                assert!(q > 0.0, "{x}: {d} aimed, density 0");
                counts[octant(d)] += 1;
            }
            for (k, (&count, &o)) in counts.iter().zip(&octants).enumerate() {
                let (want, sigma_want) = error(o, n);
                let share = count as f64 / m as f64;
                let sigma = (sigma_want.powi(2) + share * (1.0 - share) / m as f64).sqrt();
                assert!(
                    (share - want).abs() < 4.0 * sigma + 1e-12,
                    "{x}, octant {k}: {share} aimed vs {want} ± {sigma_want}"
                );
            }
        }
    }

    /// The first stretch through a tube of two pieces agrees with points sampled along the
    /// line: inside the tube exactly between its ends, outside just before and after.
    #[test]
    fn the_first_stretch_is_where_the_line_runs_inside_the_tube() {
        let tube = BeamTube {
            corners: vec![
                DVec3::new(0.0, 0.0, -2.0),
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(0.0, 0.5, 2.0),
            ],
            radius: 0.3,
            lo: DVec3::splat(-3.0),
            hi: DVec3::splat(3.0),
            first_legs: false,
            slices: Vec::new(),
        };
        let inside = |x: DVec3| {
            tube.corners
                .windows(2)
                .any(|w| distance_to_segment(x, w[0], w[1]) < tube.radius)
        };
        let mut rng: Rng = stream_rng(7, 0);
        let mut met = 0;
        for _ in 0..2000 {
            let p = DVec3::new(
                4.0 * uniform(&mut rng) - 2.0,
                4.0 * uniform(&mut rng) - 2.0,
                4.0 * uniform(&mut rng) - 2.0,
            );
            let d = uniform_sphere(uniform(&mut rng), uniform(&mut rng));
            let Some((a, b)) = tube.first_stretch(p, d, 5.0) else {
                // no point of the segment inside
                assert!((0..=500).all(|k| !inside(p + d * (k as f64 * 0.01))));
                continue;
            };
            met += 1;
            assert!(a < b);
            assert!((0..=20).all(|k| inside(p + d * (a + (b - a) * (k as f64 + 0.5) / 21.0))));
            if a > 1e-6 {
                assert!(!inside(p + d * (a - 1e-6)));
                assert!((0..100).all(|k| !inside(p + d * (a * k as f64 / 100.0))));
            }
            if b < 5.0 - 1e-6 {
                assert!(!inside(p + d * (b + 1e-6)), "{p} {d} {a} {b}");
            }
        }
        assert!(met > 100, "{met}");
    }

    /// A beam's tube follows its central ray, refracted in and bent upwards by a linear
    /// gradient as the closed-form ray is (`y = a z² / 2 n0` near the axis), within a tenth of
    /// the radius; a beam thick for the medium has none.
    #[test]
    fn a_thin_beams_tube_follows_its_bent_ray_and_a_thick_beam_has_none() {
        let tank = |sigma_s: f64| graded_box(5.0, 0.02, sigma_s, 0.0);
        let beam = beam_along_z(-6.0);
        let thin = tank(0.02);
        let tube = BeamTube::trace(&beam, &Flyer::new(&thin, 0.01, 1_000_000)).expect("a tube");
        assert!(
            tube.corners.len() > 2 && tube.corners.len() < 20,
            "{:?}",
            tube.corners
        );
        for c in &tube.corners {
            let z = c.z + 5.0;
            let y = 0.02 * z * z / (2.0 * 1.33);
            assert!((c.y - y).abs() < 0.01 + 0.1 * y, "{c} against y = {y}");
        }
        let last = tube.corners[tube.corners.len() - 1];
        assert!((last.z - 5.0).abs() < 1e-6 && last.y > 0.3, "{last}");
        let thick = tank(3.0);
        assert!(BeamTube::trace(&beam, &Flyer::new(&thick, 0.01, 1_000_000)).is_none());
    }

    /// A camera subpath's flight that reflects inside a graded box before it crosses the beam's
    /// tube draws each leg from its own mixture: the weights `1 / Π factors` tally the free
    /// flight's collision density `σ_t e^{−σ_t s}` along the whole reflected path (the legs'
    /// forced draws included), and the factor [`BeamTube::factor_along`] gives a collision
    /// after `k` reflections, re-flying the path, is the product the flight's legs gave.
    #[test]
    fn a_flight_reflected_inside_draws_each_leg_from_the_tube_and_its_factor_is_found_again() {
        let volume = graded_box(1.0, 0.05, 0.3, 0.05);
        let beam = beam_along_z(-1.5);
        let t = tools(&volume);
        let tube = BeamTube::trace(&beam, &t.flyer).expect("a tube");
        let sigma_t = volume.sigma_t();
        let x = DVec3::new(0.5, 0.3, -0.3);
        let ray_along = |x: DVec3, d: DVec3| Ray {
            x,
            v: d * t.flyer.n(x),
        };
        // a start whose first leg (to the wall x = 1) misses the tube and whose second crosses
        // it: aimed at the beam's mirror image in that wall, then searched about it
        let aim = (DVec3::new(2.0, 0.02, 0.0) - x).normalize();
        let mut rng: Rng = stream_rng(5, 0);
        let d = (0..20_000)
            .map(|k| {
                let spread = 0.002 * (1 + k / 200) as f64;
                (aim + uniform_sphere(uniform(&mut rng), uniform(&mut rng)) * spread).normalize()
            })
            .find(|&d| {
                let (first, _, stretch) = tube.flown(&t, ray_along(x, d), Forced::Tube);
                let Flight::Boundary { ray: end, .. } = first else {
                    return false;
                };
                stretch.is_none()
                    && tube
                        .flown(&t, t.flyer.reflected_inside(end), Forced::Tube)
                        .2
                        .is_some()
            })
            .expect("a start that crosses the tube after reflecting");
        let (n, bins, most) = (40_000, 16, 2);
        // the path's length to the third wall: the histogram's range
        let mut span = 0.0;
        let mut ray = ray_along(x, d);
        for _ in 0..=most {
            let (
                Flight::Boundary {
                    ray: end, length, ..
                },
                _,
                _,
            ) = tube.flown(&t, ray, Forced::Tube)
            else {
                panic!("stuck");
            };
            span += length;
            ray = t.flyer.reflected_inside(end);
        }
        let mut tally = vec![(0.0, 0.0); bins];
        let mut forced_draws = 0;
        for _ in 0..n {
            let (mut ray, mut along, mut product) = (ray_along(x, d), 0.0, 1.0);
            for leg in 0..=most {
                let (stop, travelled, factor) = tube.flight(&t, ray, Forced::Tube, &mut rng);
                product *= factor;
                match stop {
                    Stop::Collision(_) => {
                        let s = along + travelled.length;
                        let (again, _) = tube.factor_along(&t, x, d, leg, s);
                        assert!(
                            (again - product).abs() < 1e-6 * product,
                            "leg {leg}, {s}: {again} against the flight's {product}"
                        );
                        forced_draws += usize::from(factor > 1.0);
                        let bin = ((s / span) * bins as f64) as usize;
                        let w = 1.0 / product;
                        tally[bin].0 += w;
                        tally[bin].1 += w * w;
                        break;
                    }
                    Stop::Boundary(end) => {
                        along += travelled.length;
                        ray = t.flyer.reflected_inside(end);
                    }
                    Stop::Stuck => panic!("stuck"),
                }
            }
        }
        assert!(
            forced_draws > n / 10,
            "{forced_draws} collisions in the tube"
        );
        assert_free_flight_tallies(&tally, n, (sigma_t, span), false);
    }

    /// A camera subpath's first leg into a thin graded box draws its collision uniformly along
    /// the whole leg half the time: the weights `1 / factor` tally the free flight's collision
    /// density along the leg in 16 bins and its chance of reaching the surface (4σ), and the
    /// factor [`BeamTube::first_leg_factor`] gives each collision, flying on from it to the
    /// surface, is the one the flight gave. A box thick across draws no first legs.
    #[test]
    fn a_first_leg_draws_along_itself_and_its_factor_is_found_again() {
        let volume = graded_box(1.0, 0.05, 0.2, 0.05);
        let beam = beam_along_z(-1.5);
        let t = tools(&volume);
        let tube = BeamTube::trace(&beam, &t.flyer).expect("a tube");
        assert!(tube.draws_first_legs());
        let sigma_t = volume.sigma_t();
        // a slanted camera ray just inside the face x = 1, bending down the gradient
        let x = DVec3::new(1.0 - 1e-9, 0.2, 0.1);
        let d = DVec3::new(-1.0, -0.3, 0.2).normalize();
        let ray = Ray {
            x,
            v: d * t.flyer.n(x),
        };
        let (Flight::Boundary { length: span, .. }, _, stretch) = tube.flown(&t, ray, Forced::Leg)
        else {
            panic!("stuck");
        };
        assert_eq!(stretch, Some((0.0, span)));
        let (n, bins) = (100_000, 16);
        // per bin (the last: the surface), the weights' sum and sum of squares
        let mut tally = vec![(0.0, 0.0); bins + 1];
        let mut rng: Rng = stream_rng(9, 0);
        for _ in 0..n {
            let (stop, travelled, factor) = tube.flight(&t, ray, Forced::Leg, &mut rng);
            let bin = match stop {
                Stop::Collision(hit) => {
                    let s = travelled.length;
                    let (again, _) = tube.first_leg_factor(&t, hit.x, hit.v.normalize(), s);
                    assert!(
                        (again - factor).abs() < 1e-6 * factor,
                        "{s}: {again} against the flight's {factor}"
                    );
                    ((s / span) * bins as f64) as usize
                }
                Stop::Boundary(_) => bins,
                Stop::Stuck => panic!("stuck"),
            };
            let w = 1.0 / factor;
            tally[bin].0 += w;
            tally[bin].1 += w * w;
        }
        assert_free_flight_tallies(&tally, n, (sigma_t, span), true);
        let thick = graded_box(1.0, 0.05, 1.5, 0.05);
        let tube = BeamTube::trace(&beam, &Flyer::new(&thick, 0.01, 1_000_000)).expect("a tube");
        assert!(!tube.draws_first_legs());
    }

    /// The flight's mixture: collisions drawn from it and weighted by `1 / mixture_over_free`
    /// tally the free flight's collision density `σ_t e^{−σ_t s}` in every bin along the ray
    /// (inside the stretch and outside it), and the surface's chance `e^{−σ_t S}`.
    #[test]
    fn the_mixtures_weights_give_the_free_flights_densities() {
        let (sigma_t, exit, stretch) = (0.3, 4.0, Some((1.5, 1.7)));
        let mut rng: Rng = stream_rng(3, 0);
        let n = 400_000;
        let bins = 20;
        // per bin (the last: the surface), the weights' sum and sum of squares
        let mut tally = vec![(0.0, 0.0); bins + 1];
        for _ in 0..n {
            let s = if uniform(&mut rng) < FREE_SHARE {
                -(1.0 - uniform(&mut rng)).ln() / sigma_t
            } else {
                1.5 + 0.2 * uniform(&mut rng)
            };
            let (bin, w) = if s < exit {
                let w = 1.0 / BeamTube::mixture_over_free(stretch, s, sigma_t, true);
                (((s / exit) * bins as f64) as usize, w)
            } else {
                let w = 1.0 / BeamTube::mixture_over_free(stretch, exit, sigma_t, false);
                (bins, w)
            };
            tally[bin].0 += w;
            tally[bin].1 += w * w;
        }
        for (k, (want, error)) in assert_free_flight_tallies(&tally, n, (sigma_t, exit), true)
            .into_iter()
            .enumerate()
        {
            assert!(error < 0.03 * want, "bin {k}: error {error} of {want}");
        }
    }
}
