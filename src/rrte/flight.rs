//! Free flights along curved rays and the dielectric interface of the volume.
//!
//! Transmittance depends on the *geometric* length travelled (paper 002, Eq. 5), so a free flight
//! of sampled length `d` is stepped with the symplectic integrator of [`crate::eikonal`] until its
//! chords add up to `d` or the ray meets the boundary (found by bisection, as in `trace`). Where
//! `n` is constant the ray is a straight line and the flight is exact.

use super::scene::Volume;
use crate::eikonal::{IndexField, Part, Ray, Tracer, part_at};
use glam::DVec3;

/// How a free flight ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flight {
    /// The sampled distance ran out inside: a collision at `ray.x`, after the optical path
    /// `∫ n ds` and the geometric `length`.
    Collision {
        ray: Ray,
        optical_path: f64,
        length: f64,
    },
    /// The ray reached the boundary first: `ray` is the last state inside (within round-off of
    /// the surface).
    Boundary {
        ray: Ray,
        optical_path: f64,
        length: f64,
    },
    /// The step budget ran out before either (a ray trapped in the field).
    Stuck { ray: Ray, optical_path: f64 },
}

/// The free-flight integrator of a volume.
pub struct Flyer<'v> {
    pub volume: &'v Volume,
    tracer: Tracer<'v>,
    straight: bool,
    /// Skip the inside–outside test while the distance run since the last one is below the
    /// clearance found there (paper 002, Sec. 5); off only to measure what it saves.
    skip_tests: bool,
}

impl<'v> Flyer<'v> {
    pub fn new(volume: &'v Volume, step: f64, max_steps: usize) -> Self {
        Flyer {
            volume,
            tracer: Tracer {
                field: &volume.field,
                step,
                max_steps,
            },
            straight: volume.homogeneous(),
            skip_tests: true,
        }
    }

    /// The same integrator testing inside–outside after every step (`false`) or only where the
    /// clearance requires (`true`, the default): results are identical, only the work differs.
    pub fn skipping_tests(mut self, skip: bool) -> Self {
        self.skip_tests = skip;
        self
    }

    /// `n` at `x`.
    #[inline]
    pub fn n(&self, x: DVec3) -> f64 {
        self.volume.field.n(x)
    }

    /// The ray that reached the surface at `end` mirrored back inside it (the law of
    /// reflection), as a reflection inside follows it on.
    pub fn reflected_inside(&self, end: Ray) -> Ray {
        let d = end.v.normalize();
        let normal = self.volume.field.bounds.normal(end.x).unwrap_or(d);
        Ray {
            x: end.x,
            v: reflect(d, normal) * self.n(end.x),
        }
    }

    /// Fly from `r` (inside, `|v| = n`) for geometric length `distance` (may be infinite), and the
    /// leapfrog steps it took.
    pub fn fly(&self, r: Ray, distance: f64) -> (Flight, usize) {
        self.fly_visiting(r, distance, |_, _| {})
    }

    /// [`Self::fly`], reporting every chord of the flight (from, to) to `chord`: the path the
    /// flight's length is measured along, for track-length tallies.
    #[inline]
    pub fn fly_visiting(
        &self,
        r: Ray,
        distance: f64,
        mut chord: impl FnMut(DVec3, DVec3),
    ) -> (Flight, usize) {
        let field = &self.volume.field;
        // of several volumes, the one holding the start: a flight never leaves it without
        // reaching the surface, so it is tested and evaluated alone (straight if its `n` is
        // constant)
        let part = field
            .bounds
            .parts()
            .map(|parts| &parts[part_at(parts, r.x)]);
        if self.straight || part.is_some_and(Part::is_constant) {
            let flight = self.fly_straight(r, distance);
            let end = match flight {
                Flight::Collision { ray, .. } | Flight::Boundary { ray, .. } => ray.x,
                Flight::Stuck { ray, .. } => ray.x,
            };
            chord(r.x, end);
            return (flight, 1);
        }
        let t = &self.tracer;
        let h = t.step;
        let (mut r, mut s, mut opl) = (r, 0.0, 0.0);
        // the force at the end of a step starts the next (one field evaluation per step, the same
        // numbers as `Tracer::leapfrog`)
        let (mut n0, g0) = field.value_grad(r.x);
        let mut force = g0 * n0;
        // distance that may still be run before the next inside–outside test
        let mut clear = self.clearance(part, r.x);
        for k in 0..t.max_steps {
            let v_half = r.v + force * (0.5 * h);
            let x = r.x + v_half * h;
            clear -= (x - r.x).length();
            let inside = if clear > 0.0 {
                true
            } else if self.skip_tests {
                let found = match part {
                    Some(p) => p.inside_clearance(x),
                    None => field.bounds.inside_clearance(x),
                };
                clear = found.map_or(0.0, safe_clearance);
                found.is_some()
            } else {
                part.map_or_else(|| field.bounds.contains(x), |p| p.contains(x))
            };
            let (next, tau, boundary, n_next, force_next) = if inside {
                let (n1, g1) = match part {
                    // a field of parts has no map of its own (each part has)
                    Some(p) if field.scale == 1.0 && field.offset == 0.0 => p.value_grad(x),
                    _ => field.value_grad_inside(x),
                };
                let f1 = g1 * n1;
                let next = Ray {
                    x,
                    v: v_half + f1 * (0.5 * h),
                };
                (next, h, false, n1, f1)
            } else {
                let tau = t.boundary_step(r, h);
                let next = t.leapfrog(r, tau);
                (next, tau, true, self.n(next.x), DVec3::ZERO)
            };
            let length = (next.x - r.x).length();
            if s + length >= distance {
                // the collision falls inside this step: shorten it in proportion to the chord
                let frac = if length > 0.0 {
                    (distance - s) / length
                } else {
                    0.0
                };
                let hit = t.leapfrog(r, tau * frac);
                chord(r.x, hit.x);
                let n1 = self.n(hit.x);
                let last = (hit.x - r.x).length();
                let optical_path = opl + 0.5 * (n0 + n1) * last;
                return (
                    Flight::Collision {
                        ray: hit,
                        optical_path,
                        length: s + last,
                    },
                    k + 1,
                );
            }
            opl += 0.5 * (n0 + n_next) * length;
            s += length;
            chord(r.x, next.x);
            r = next;
            n0 = n_next;
            force = force_next;
            if boundary {
                return (
                    Flight::Boundary {
                        ray: r,
                        optical_path: opl,
                        length: s,
                    },
                    k + 1,
                );
            }
        }
        (
            Flight::Stuck {
                ray: r,
                optical_path: opl,
            },
            t.max_steps,
        )
    }

    /// The distance a flight from `x` (inside, in `part` if the volume has parts) may run before
    /// testing again.
    fn clearance(&self, part: Option<&Part>, x: DVec3) -> f64 {
        if !self.skip_tests {
            return 0.0;
        }
        safe_clearance(
            part.map_or_else(|| self.volume.field.bounds.clearance(x), |p| p.clearance(x)),
        )
    }

    /// A straight flight through constant `n`, in closed form.
    fn fly_straight(&self, r: Ray, distance: f64) -> Flight {
        let n = r.v.length();
        let w = r.v / n;
        let exit = self
            .volume
            .field
            .bounds
            .exit(r.x, w)
            .map_or(0.0, |t1| t1.max(0.0));
        if distance < exit {
            Flight::Collision {
                ray: Ray {
                    x: r.x + w * distance,
                    v: r.v,
                },
                optical_path: n * distance,
                length: distance,
            }
        } else {
            // the last point inside: step back from the surface by round-off
            let t = exit * (1.0 - 1e-12) - 1e-15;
            Flight::Boundary {
                ray: Ray {
                    x: r.x + w * t.max(0.0),
                    v: r.v,
                },
                optical_path: n * exit,
                length: exit,
            }
        }
    }
}

/// A clearance shortened by round-off: a point judged inside by it is inside by the exact test.
#[inline]
fn safe_clearance(c: f64) -> f64 {
    c * (1.0 - 1e-9) - 1e-12
}

/// Fresnel reflectance of unpolarised light at a smooth interface, from the cosine of incidence
/// and `eta = n_from / n_to` (1 on total internal reflection).
pub fn fresnel(cos_i: f64, eta: f64) -> f64 {
    let cos_i = cos_i.abs().min(1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// The mirror image of unit `d` in a surface of unit normal `normal`.
#[inline]
pub fn reflect(d: DVec3, normal: DVec3) -> DVec3 {
    d - normal * (2.0 * d.dot(normal))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eikonal::{BoundedField, Bounds, Profile};
    use crate::math::{stream_rng, uniform, uniform_sphere};
    use crate::medium::{PhaseFunction, Scattering};
    use crate::rrte::Bulk;

    /// In a scene of several volumes, a flight runs in the volume holding its start alone: in a
    /// graded lens it is the same flight, bit for bit, as in the lens alone; in a glass ball
    /// beside it, a straight flight in closed form (one step, to the ball's surface).
    #[test]
    fn a_flight_among_several_volumes_is_the_flight_in_its_own() {
        let ball = |radius: f64| Bounds::Sphere { radius };
        let lens = vec![Profile::Luneburg { radius: 1.0 }];
        let clear = || Bulk {
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        let glass_at = DVec3::new(2.5, 0.0, 0.0);
        let several = Volume::several(
            vec![
                (Part::new(ball(1.0), DVec3::ZERO, lens.clone()), clear()),
                (
                    Part::new(ball(0.8), glass_at, vec![Profile::Constant { n: 1.5 }]),
                    clear(),
                ),
            ],
            1.0,
        );
        let alone = Volume {
            field: BoundedField::new(lens, ball(1.0), 1.0),
            ..several.clone()
        };
        let (flyer, flyer_alone) = (
            Flyer::new(&several, 0.01, 100_000),
            Flyer::new(&alone, 0.01, 100_000),
        );
        let mut rng = stream_rng(3, 0);
        let mut draw = || uniform(&mut rng);
        let mut stepped = 0;
        for _ in 0..200 {
            let x = uniform_sphere(draw(), draw()) * 0.9 * draw().cbrt();
            let w = uniform_sphere(draw(), draw());
            let d = -draw().ln();
            let r = Ray {
                x,
                v: w * alone.field.n(x),
            };
            let (a, b) = (flyer.fly(r, d), flyer_alone.fly(r, d));
            assert_eq!(a, b);
            stepped += a.1;
            // in the glass ball, straight to its surface
            let r = Ray {
                x: glass_at + x * 0.8,
                v: w * 1.5,
            };
            let (flight, steps) = flyer.fly(r, f64::INFINITY);
            let Flight::Boundary {
                ray,
                length,
                optical_path,
            } = flight
            else {
                panic!("{flight:?}");
            };
            let b = (x * 0.8).dot(w);
            let exit = -b + (b * b - (x * 0.8).length_squared() + 0.64).sqrt();
            assert_eq!(steps, 1);
            assert!((length - exit).abs() < 1e-9 && (optical_path - 1.5 * exit).abs() < 1e-9);
            assert!(((ray.x - glass_at).length() - 0.8).abs() < 1e-9);
        }
        // the lens's flights were stepped (about a mean free path of 1 in steps of 0.01)
        assert!(stepped > 200 * 20, "{stepped} steps");
    }

    #[test]
    fn fresnel_matches_normal_incidence_and_brewster() {
        // normal incidence: ((n1 − n2)/(n1 + n2))²
        let r = fresnel(1.0, 1.0 / 1.5);
        assert!((r - 0.04).abs() < 1e-12, "{r}");
        // the same from either side at normal incidence
        assert!((fresnel(1.0, 1.5) - r).abs() < 1e-12);
        // Brewster's angle tan θ = n2/n1: only the s polarisation reflects
        let th = 1.5f64.atan();
        let (n1, n2) = (1.0, 1.5);
        let ct = (1.0 - (n1 / n2 * th.sin()).powi(2)).sqrt();
        let rs = ((n1 * th.cos() - n2 * ct) / (n1 * th.cos() + n2 * ct)).powi(2);
        assert!((fresnel(th.cos(), n1 / n2) - 0.5 * rs).abs() < 1e-12);
        // beyond the critical angle
        assert_eq!(fresnel(0.1, 1.5), 1.0);
        assert_eq!(fresnel(1.0, 1.0), 0.0);
    }
}
