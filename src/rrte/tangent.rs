//! Derivatives of particle tracing's outputs with respect to the index field's parameters
//! (an ultrasound array's drive, frequency and phases, a profile's coefficients): forward
//! sensitivities of every photon's path.
//!
//! For fixed random numbers a photon's path is a smooth function of the field's parameters `θ`
//! once every choice whose probability depends on `θ` is scored rather than followed:
//! - a free flight ends in a collision with probability `q = 1 − e^{−σ_t L}`, `L` the geometric
//!   length to the surface along the curved ray (paper 002, Eq. 5). The choice adds `∂ log q` or
//!   `∂ log (1 − q) = −σ_t ∂L` to the path's score, and a collision's distance
//!   `s = −ln(1 − u' q)/σ_t` (`u'` uniform) moves with `q`. Drawn as `u = u' q`, this is
//!   particle tracing's own free flight `s = −ln(1 − u)/σ_t`: the same photons;
//! - at the surface, Fresnel's reflect-or-refract adds `∂ log R` or `∂ log (1 − R)`.
//!
//! Everything else moves with `θ` and is carried by the sensitivities `∂(x, v)/∂θ`: through each
//! leapfrog step (`δv½ = δv + (J δx + ∂F/∂θ) h/2`, `δx' = δx + δv½ h`, `F = n∇n`,
//! `J = ∇F`: the tangent map of paper 002's Alg. 2, driven by the parameters), through the
//! step that meets the surface (its length moves so the end stays on it), refraction and
//! reflection, and scattering directions drawn in the frame of the incoming direction. Each
//! output then receives `∂f/∂θ + f · score`: the pathwise derivative of what the photon tallies
//! (a target's track length, a spot's aperture weight `e^{−2ρ²/w²}` or a tent-filtered pixel's
//! share where the photon crosses the plane, which moves with the exit point and the direction
//! leaving) plus its value times
//! the score of the choices made before it. Both parts are unbiased, so the sum is `∂E[f]/∂θ`.
//!
//! At each scattering event (and at a light inside the volume) the photon connects to the fluence
//! probes; what the connections carry is differentiated from the event's position and incoming
//! direction with their sensitivities, and through the boundary-value problem's dependence on the
//! field, by `connection_slopes`.
//!
//! Sensors must not have edges that move with the light (a flux plane's rectangle or its
//! grazing edge, box-filtered pixels, an acceptance cone: their crossings' share is not
//! estimated), and volumes are convex: a photon leaving one goes straight on to the next ahead
//! (the entry moving along the leg so that it stays on the surface) or for good
//! (the config refuses the rest). The derivatives of closed forms at the surface (Fresnel,
//! refraction, the surface normal's turn) and of a scattering direction's frame are central
//! differences of those closed forms, accurate to about 1e-10.

// the sensitivities are parallel arrays, one entry per field parameter, read together by index
#![allow(clippy::needless_range_loop)]

use super::connection_slopes::Vertex;
use super::particle::{
    ParticleTracer, Reflections, Tools, Total, albedo_score, flight_score, roulette, roulette_by,
};
use super::scene::{Derivative, FieldDerivative, MAX_DERIVATIVES, MAX_TARGETS, Volume};
use crate::eikonal::trace::{entry_parameter, jacobian_of, refract};
use crate::eikonal::{BoundedField, IndexField, Profile, Ray, Tracer, part_at};
use crate::math::{C64, Rng, direction_about_continuously, uniform};
use glam::{DMat3, DVec3};

use super::flight::{fresnel, reflect};

const P: usize = MAX_DERIVATIVES;

/// The least probability an outcome of a scored choice is drawn with (see
/// [`ParticleTracer::choose`]).
const LEAST_DRAWN: f64 = 0.1;

/// Per field parameter (`k < count`), a vector's sensitivity.
type Vectors = [DVec3; P];

/// Per target, per field parameter: a track's sensitivity.
type TrackSlopes = [[f64; P]; MAX_TARGETS];

/// A ray state's sensitivities to the field parameters.
#[derive(Clone, Copy)]
struct Tangent {
    x: Vectors,
    v: Vectors,
}

impl Tangent {
    const ZERO: Tangent = Tangent {
        x: [DVec3::ZERO; P],
        v: [DVec3::ZERO; P],
    };
}

/// The field and its parameters for one photon: which derivative slot each is, and the factor
/// from the profile's stored value to the parameter (a modulation's `sin Ωt`).
struct Sensitivity<'a> {
    field: &'a BoundedField,
    tracer: Tracer<'a>,
    /// `(slot in the scene's derivatives, parameter, factor)`.
    params: [(usize, Option<&'a FieldDerivative>, f64); P],
    count: usize,
}

/// `n`, `∇n`, the force `n∇n`, its Jacobian, and per parameter `∂n/∂θ` and `∂F/∂θ` at a point
/// inside.
struct Local {
    n: f64,
    grad: DVec3,
    force: DVec3,
    jacobian: DMat3,
    dn: [f64; P],
    dforce: Vectors,
}

impl<'a> Sensitivity<'a> {
    fn new(t: &Tools<'a>, derivatives: &'a [Derivative], step: f64, max_steps: usize) -> Self {
        let field = &t.flyer.volume.field;
        let mut params = [(0, None, 0.0); P];
        let mut count = 0;
        for (slot, d) in derivatives.iter().enumerate() {
            let Derivative::Field(f) = d else { continue };
            let mut factor = f.scale;
            if let (Some(omega_t), Some((Profile::Ultrasonic { .. }, _))) =
                (t.instant, f.profile(field))
                && f.param.which == 1
            {
                // the photon's field holds the amplitude times sin Ωt
                factor *= omega_t.sin();
            }
            params[count] = (slot, Some(f), factor);
            count += 1;
        }
        Sensitivity {
            field,
            tracer: Tracer {
                field,
                step,
                max_steps,
            },
            params,
            count,
        }
    }

    /// `(∂n/∂θ_k, ∇ ∂n/∂θ_k)` at `x` inside (in `part` of several volumes).
    #[inline]
    fn dn(&self, x: DVec3, part: Option<usize>, k: usize) -> (f64, DVec3) {
        let (_, f, factor) = self.params[k];
        let (d, g) = f.map_or((0.0, DVec3::ZERO), |f| f.dn(self.field, x, part));
        (d * factor, g * factor)
    }

    fn at(&self, x: DVec3) -> Local {
        let (n, grad, hessian) = self.field.eval_inside(x);
        let mut dn = [0.0; P];
        let mut dforce = [DVec3::ZERO; P];
        // the part holding x, once for every parameter
        let part = (self.count > 0)
            .then(|| self.field.bounds.parts().map(|parts| part_at(parts, x)))
            .flatten();
        for k in 0..self.count {
            let (d, g) = self.dn(x, part, k);
            dn[k] = d;
            dforce[k] = grad * d + g * n;
        }
        Local {
            n,
            grad,
            force: grad * n,
            jacobian: jacobian_of(n, grad, hessian),
            dn,
            dforce,
        }
    }

    /// `∂n/∂θ_k` along the state's sensitivity: `∇n · δx + ∂n/∂θ`.
    fn n_slope(&self, l: &Local, dx: &Vectors) -> [f64; P] {
        let mut s = [0.0; P];
        for k in 0..self.count {
            s[k] = l.grad.dot(dx[k]) + l.dn[k];
        }
        s
    }

    /// One leapfrog step of length `tau` from `r` (force `l0` there) with the sensitivities at
    /// fixed `tau`; the state after it, its sensitivities, the force there, and `∂(x, v)/∂τ`.
    fn step(
        &self,
        r: Ray,
        tan: &Tangent,
        l0: &Local,
        tau: f64,
    ) -> (Ray, Tangent, Local, [DVec3; 2]) {
        let half = 0.5 * tau;
        let v_half = r.v + l0.force * half;
        let x = r.x + v_half * tau;
        let l1 = self.at(x);
        let v = v_half + l1.force * half;
        let mut next = Tangent::ZERO;
        for k in 0..self.count {
            let dv_half = tan.v[k] + (l0.jacobian * tan.x[k] + l0.dforce[k]) * half;
            next.x[k] = tan.x[k] + dv_half * tau;
            next.v[k] = dv_half + (l1.jacobian * next.x[k] + l1.dforce[k]) * half;
        }
        let x_tau = r.v + l0.force * tau;
        let v_tau = (l0.force + l1.force) * 0.5 + l1.jacobian * x_tau * half;
        (Ray { x, v }, next, l1, [x_tau, v_tau])
    }

    /// Fly from `r` (sensitivities `tan`) for geometric length `distance` (sensitivities
    /// `d_distance`), reporting each chord and its ends' sensitivities to `chord`.
    fn fly(
        &self,
        r: Ray,
        tan: &Tangent,
        distance: f64,
        d_distance: &[f64; P],
        straight: bool,
        mut chord: impl FnMut(DVec3, &Vectors, DVec3, &Vectors),
    ) -> End {
        if straight {
            return self.fly_straight(r, tan, distance, d_distance, chord);
        }
        let h = self.tracer.step;
        let bounds = &self.field.bounds;
        let (mut r, mut tan) = (r, *tan);
        let mut l0 = self.at(r.x);
        let (mut s, mut ds, mut opl) = (0.0, [0.0; P], 0.0);
        for steps in 1..=self.tracer.max_steps {
            let trial = r.x + (r.v + l0.force * (0.5 * h)) * h;
            let boundary = !bounds.contains(trial);
            let tau = if boundary {
                self.tracer.boundary_step(r, h)
            } else {
                h
            };
            let (next, mut t1, l1, [x_tau, v_tau]) = self.step(r, &tan, &l0, tau);
            let mut d_tau = [0.0; P];
            if boundary {
                // the step's length keeps its end on the surface
                let m = bounds.normal(next.x).unwrap_or(x_tau);
                let rate = m.dot(x_tau);
                for k in 0..self.count {
                    d_tau[k] = if rate != 0.0 {
                        -m.dot(t1.x[k]) / rate
                    } else {
                        0.0
                    };
                    t1.x[k] += x_tau * d_tau[k];
                    t1.v[k] += v_tau * d_tau[k];
                }
            }
            let length = (next.x - r.x).length();
            let along = if length > 0.0 {
                (next.x - r.x) / length
            } else {
                DVec3::ZERO
            };
            let mut d_length = [0.0; P];
            for k in 0..self.count {
                d_length[k] = along.dot(t1.x[k] - tan.x[k]);
            }
            if s + length >= distance {
                // the collision falls inside this step: shortened in proportion to the chord
                let frac = if length > 0.0 {
                    (distance - s) / length
                } else {
                    0.0
                };
                let (hit, mut th, _, [hx, hv]) = self.step(r, &tan, &l0, tau * frac);
                for k in 0..self.count {
                    let d_frac = if length > 0.0 {
                        (d_distance[k] - ds[k] - frac * d_length[k]) / length
                    } else {
                        0.0
                    };
                    let d_sub = d_tau[k] * frac + tau * d_frac;
                    th.x[k] += hx * d_sub;
                    th.v[k] += hv * d_sub;
                }
                chord(r.x, &tan.x, hit.x, &th.x);
                let last = (hit.x - r.x).length();
                let along = if last > 0.0 {
                    (hit.x - r.x) / last
                } else {
                    DVec3::ZERO
                };
                for k in 0..self.count {
                    ds[k] += along.dot(th.x[k] - tan.x[k]);
                }
                let n1 = self.field.n(hit.x);
                return End {
                    stop: Stop::Collision,
                    ray: hit,
                    tan: th,
                    length: s + last,
                    d_length: ds,
                    optical_path: opl + 0.5 * (l0.n + n1) * last,
                    steps,
                };
            }
            chord(r.x, &tan.x, next.x, &t1.x);
            opl += 0.5 * (l0.n + l1.n) * length;
            s += length;
            for k in 0..self.count {
                ds[k] += d_length[k];
            }
            if boundary {
                // `next` is the last state inside, within round-off of the surface
                return End {
                    stop: Stop::Boundary,
                    ray: next,
                    tan: t1,
                    length: s,
                    d_length: ds,
                    optical_path: opl,
                    steps,
                };
            }
            (r, tan, l0) = (next, t1, l1);
        }
        End {
            stop: Stop::Stuck,
            ray: r,
            tan,
            length: s,
            d_length: ds,
            optical_path: opl,
            steps: self.tracer.max_steps,
        }
    }

    /// [`Self::fly`] through a constant index: a straight line in closed form.
    fn fly_straight(
        &self,
        r: Ray,
        tan: &Tangent,
        distance: f64,
        d_distance: &[f64; P],
        mut chord: impl FnMut(DVec3, &Vectors, DVec3, &Vectors),
    ) -> End {
        let n = r.v.length();
        let w = r.v / n;
        let mut dw = [DVec3::ZERO; P];
        for k in 0..self.count {
            dw[k] = (tan.v[k] - w * w.dot(tan.v[k])) / n;
        }
        let bounds = &self.field.bounds;
        let exit = bounds.exit(r.x, w).map_or(0.0, |t1| t1.max(0.0));
        let mut end = *tan;
        let (stop, length, d_length) = if distance < exit {
            (Stop::Collision, distance, *d_distance)
        } else {
            // the exit moves so that it stays on the surface
            let m = bounds.normal(r.x + w * exit).unwrap_or(w);
            let mut dl = [0.0; P];
            for k in 0..self.count {
                dl[k] = -m.dot(tan.x[k] + dw[k] * exit) / m.dot(w);
            }
            (Stop::Boundary, exit, dl)
        };
        for k in 0..self.count {
            end.x[k] = tan.x[k] + dw[k] * length + w * d_length[k];
        }
        let along = if stop == Stop::Boundary {
            // the last point inside: step back from the surface by round-off
            (length * (1.0 - 1e-12) - 1e-15).max(0.0)
        } else {
            length
        };
        let x = r.x + w * along;
        chord(r.x, &tan.x, x, &end.x);
        End {
            stop,
            ray: Ray { x, v: r.v },
            tan: end,
            length,
            d_length,
            optical_path: n * length,
            steps: 1,
        }
    }

    /// The turn of the volume's surface normal at `x` along each of `dx`.
    fn normal_turn(&self, x: DVec3, dx: &Vectors) -> Vectors {
        let bounds = &self.field.bounds;
        let mut turn = [DVec3::ZERO; P];
        for k in 0..self.count {
            turn[k] = slope(dx[k].length(), |t| {
                bounds.normal(x + dx[k] * t).unwrap_or(DVec3::ZERO)
            });
        }
        turn
    }
}

/// How a flight with sensitivities ended.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Stop {
    Collision,
    Boundary,
    Stuck,
}

/// The end of a flight with sensitivities: the state there and its sensitivities, the
/// geometric length flown and its sensitivities.
struct End {
    stop: Stop,
    ray: Ray,
    tan: Tangent,
    length: f64,
    d_length: [f64; P],
    optical_path: f64,
    steps: usize,
}

/// `d f(t)/dt` at 0 by central differences, for a smooth closed form whose argument moves at
/// rate `size` (the step is scaled to it).
#[inline]
fn slope<T>(size: f64, f: impl Fn(f64) -> T) -> T
where
    T: std::ops::Sub<Output = T> + std::ops::Mul<f64, Output = T> + Default,
{
    if size == 0.0 || !size.is_finite() {
        return T::default();
    }
    let h = 1e-6 / size;
    (f(h) - f(-h)) * (0.5 / h)
}

/// Where a photon leaves the volume and along which unit direction, with their sensitivities
/// (none for light that never entered: its path does not depend on the field).
struct Leaving {
    x: DVec3,
    d: DVec3,
    dx: Vectors,
    dd: Vectors,
}

impl Leaving {
    fn fixed(x: DVec3, d: DVec3) -> Self {
        Leaving {
            x,
            d,
            dx: [DVec3::ZERO; P],
            dd: [DVec3::ZERO; P],
        }
    }
}

/// A photon's weight, score and sensitivities.
struct Photon {
    weight: f64,
    opl: f64,
    events: usize,
    steps: usize,
    /// Per derivative slot, `∂ log` of the path's probability and weight so far.
    score: [f64; P],
}

impl ParticleTracer<'_> {
    /// Trace one photon with its sensitivities to the field parameters (see the module's
    /// documentation), adding its contributions and their derivatives to `out`.
    /// `shifted`: the photon's volume moved along each index-field parameter, for the
    /// derivatives of its connections to probes.
    pub(super) fn photon_differentiated(
        &self,
        t: &Tools,
        shifted: &[[Volume; 2]],
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let scene = self.scene;
        let sens = Sensitivity::new(t, &scene.derivatives, scene.step, scene.max_steps);
        let (x, d) = scene
            .light
            .sample([uniform(rng), uniform(rng), uniform(rng), uniform(rng)]);
        let mut p = Photon {
            weight: 1.0,
            opl: 0.0,
            events: 0,
            steps: 0,
            score: [0.0; P],
        };
        let field = &t.flyer.volume.field;
        let mut start = if field.bounds.contains(x) {
            if self.connects() {
                let v = Vertex::fixed(x, None);
                self.connect_differentiated(t, &v, &p, shifted, rng, out);
            }
            let l = sens.at(x);
            let mut tan = Tangent::ZERO;
            for k in 0..sens.count {
                tan.v[k] = d * l.dn[k];
            }
            Some((Ray { x, v: d * l.n }, tan))
        } else {
            self.enter(t, &sens, Leaving::fixed(x, d), false, &mut p, rng, out)
        };
        // through each volume in turn (of several, the next ahead as it leaves one)
        while let Some(state) = start {
            let Some(leaving) =
                self.inside_differentiated(t, &sens, state, shifted, &mut p, rng, out)
            else {
                break;
            };
            start = self.enter(t, &sens, leaving, true, &mut p, rng, out);
        }
        out[self.total(Total::Events)].re += p.events as f64;
        out[self.total(Total::Steps)].re += p.steps as f64;
    }

    /// Straight legs outside the volume from `e` (`left_volume`: where the photon left one):
    /// into the volume ahead (Fresnel's choice scored; reflected off it, on to the next leg), or
    /// past every volume for good. The point of entry moves along the leg so that it stays on
    /// the surface, `δa = m − d (N·m)/(N·d)` with `m = δx + δd t`, and the surface's normal
    /// turns with it.
    #[allow(clippy::too_many_arguments)]
    fn enter(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        mut e: Leaving,
        mut left_volume: bool,
        p: &mut Photon,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<(Ray, Tangent)> {
        let field = &t.flyer.volume.field;
        let n_out = field.n_out;
        loop {
            let (x, d) = (e.x, e.d);
            let entry = match self.ahead(t, x, d, left_volume) {
                (Some(entry), _) if p.weight > 0.0 => entry,
                _ => {
                    self.leave_for_good(t, sens, &e, p, out);
                    return None;
                }
            };
            self.cross_moving(t, sens, &e, entry, p, out);
            p.opl += t.delay.outside(n_out * entry);
            let at = x + d * entry;
            let inside = x + d * entry_parameter(entry);
            let normal = field.bounds.normal(at).unwrap_or(-d);
            let cos = d.dot(normal);
            let mut moved = [DVec3::ZERO; P];
            for k in 0..sens.count {
                let m = e.dx[k] + e.dd[k] * entry;
                moved[k] = m - d * (normal.dot(m) / cos);
            }
            let turn = sens.normal_turn(at, &moved);
            let l = sens.at(inside);
            let dn = sens.n_slope(&l, &moved);
            let eta = n_out / l.n;
            let r = fresnel(cos, eta);
            let mut d_cos = [0.0; P];
            let mut d_eta = [0.0; P];
            let mut d_r = [0.0; P];
            for k in 0..sens.count {
                d_cos[k] = e.dd[k].dot(normal) + d.dot(turn[k]);
                d_eta[k] = -eta * dn[k] / l.n;
                let size = d_cos[k].abs().max(d_eta[k].abs());
                d_r[k] = slope(size, |s| fresnel(cos + d_cos[k] * s, eta + d_eta[k] * s));
            }
            let refracted = refract(d, normal, eta);
            if let Ok(w) = refracted
                && !(r > 0.0 && self.choose(sens, p, r, &d_r, uniform(rng)))
            {
                let mut tan = Tangent::ZERO;
                for k in 0..sens.count {
                    let size = e.dd[k].length().max(turn[k].length()).max(d_eta[k].abs());
                    let dw = slope(size, |s| {
                        let normal = (normal + turn[k] * s).normalize();
                        refract((d + e.dd[k] * s).normalize(), normal, eta + d_eta[k] * s)
                            .unwrap_or(w)
                    });
                    tan.x[k] = moved[k];
                    tan.v[k] = dw * l.n + w * dn[k];
                }
                return Some((
                    Ray {
                        x: inside,
                        v: w * l.n,
                    },
                    tan,
                ));
            }
            // reflected off the surface (or beyond the critical angle): on along the mirror
            let mut dd = [DVec3::ZERO; P];
            for k in 0..sens.count {
                dd[k] = e.dd[k] - (normal * d_cos[k] + turn[k] * cos) * 2.0;
            }
            e = Leaving {
                x: at,
                d: reflect(d, normal),
                dx: moved,
                dd,
            };
            left_volume = true;
        }
    }

    /// The photon's connections from `v` to the probes and cameras, with their derivatives
    /// ([`ParticleTracer::connect_photon`]). With even draws they draw from their own stream, so
    /// the photon's next numbers do not depend on how many Newton restarts they took.
    fn connect_differentiated(
        &self,
        t: &Tools,
        v: &Vertex,
        p: &Photon,
        shifted: &[[Volume; 2]],
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let score = &p.score[..self.scene.derivatives.len()];
        let mut own;
        let rng: &mut Rng = if self.even_draws {
            use rand::{Rng as _, SeedableRng as _};
            own = Rng::seed_from_u64(rng.next_u64());
            &mut own
        } else {
            rng
        };
        self.connect_photon(t, v, (p.weight, p.opl), score, shifted, rng, out);
    }

    /// The probability an outcome of probability `prob` (in (0, 1)) is drawn with.
    fn drawing(&self, prob: f64) -> f64 {
        if self.even_draws {
            0.5
        } else {
            prob.clamp(LEAST_DRAWN, 1.0 - LEAST_DRAWN)
        }
    }

    /// A choice between two outcomes of probabilities `prob` and `1 − prob` (slopes `d_prob`)
    /// by the uniform `u`: `true` for the first. It is drawn with `prob` clamped to
    /// [`LEAST_DRAWN`, 1 − `LEAST_DRAWN`] and the photon's weight takes the ratio, so that an
    /// outcome rarely chosen does not carry a score `∂ log prob` without bound (a flight ending
    /// just short of the surface, transmission near the critical angle); the score is of the
    /// outcome's own probability (the drawing probability is held fixed: its effect through
    /// the weight and through the choice cancel in expectation).
    fn choose(
        &self,
        sens: &Sensitivity,
        p: &mut Photon,
        prob: f64,
        d_prob: &[f64; P],
        u: f64,
    ) -> bool {
        // even draws draw certain outcomes evenly too (the impossible one then ends the photon
        // with weight 0), so a weight does not jump where an outcome becomes certain
        let drawn = if !self.even_draws && (prob <= 0.0 || prob >= 1.0) {
            prob.clamp(0.0, 1.0)
        } else {
            self.drawing(prob)
        };
        let first = u < drawn;
        let (value, sign, chance) = if first {
            (prob, 1.0, drawn)
        } else {
            (1.0 - prob, -1.0, 1.0 - drawn)
        };
        p.weight *= value / chance;
        if value > 0.0 {
            for k in 0..sens.count {
                p.score[sens.params[k].0] += sign * d_prob[k] / value;
            }
        }
        first
    }

    /// A photon leaving the scene: the sensors it crosses, then away for good.
    fn leave_for_good(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        e: &Leaving,
        p: &Photon,
        out: &mut [C64],
    ) {
        self.cross_moving(t, sens, e, f64::INFINITY, p, out);
        out[self.total(Total::Escaped)].re += p.weight;
    }

    /// The sensors a photon leaving `e` crosses within `length`. Where a recorded weight moves
    /// with the crossing (a spot's aperture, a tent-filtered pixel's share), its pathwise
    /// derivative too: the crossing moves on the plane as the photon's exit and direction move,
    /// `δp = m − d (N·m)/(N·d)` with `m = δx + δd t`.
    fn cross_moving(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        e: &Leaving,
        length: f64,
        p: &Photon,
        out: &mut [C64],
    ) {
        let dlog = &p.score[..self.scene.derivatives.len()];
        let sensors = &self.scene.sensors;
        let moving = |out: &mut [C64], i: usize, pixel: usize, distance: f64, grad: DVec3| {
            let normal = sensors[i].normal;
            let cos = e.d.dot(normal);
            for k in 0..sens.count {
                let m = e.dx[k] + e.dd[k] * distance;
                let slope = grad.dot(m - e.d * (normal.dot(m) / cos));
                let image = self.derivative_image(i, sens.params[k].0);
                out[image.total()].re += slope;
                if image.pixels > 0 {
                    out[image.first + pixel].re += slope;
                }
            }
        };
        let (x, d) = (e.x, e.d);
        self.cross_sensors_with(t, x, d, length, p.weight, p.opl, dlog, out, moving);
    }

    /// Free flights and scattering inside the volume from `ray` (sensitivities `tan`) until the
    /// photon leaves (where and along which direction), is absorbed or is given up.
    #[allow(clippy::too_many_arguments)]
    fn inside_differentiated(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        (mut ray, mut tan): (Ray, Tangent),
        shifted: &[[Volume; 2]],
        p: &mut Photon,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Leaving> {
        let volume = t.flyer.volume;
        // the part of several volumes the photon is in (its medium's parameters score here)
        let part = volume.part_index(ray.x);
        let coefficients = volume.coefficients(part);
        let sigma_t = coefficients.1;
        let albedo = volume.albedo_at(ray.x);
        let straight = match (part, volume.field.bounds.parts()) {
            (Some(k), Some(parts)) => parts[k].is_constant(),
            _ => volume.homogeneous(),
        };
        let derivatives = &self.scene.derivatives;
        let mut tracks = [0.0; MAX_TARGETS];
        let mut slopes: TrackSlopes = [[0.0; P]; MAX_TARGETS];
        let mut reflections = Reflections::default();
        loop {
            let u = uniform(rng);
            tracks.fill(0.0);
            slopes.iter_mut().for_each(|s| s.fill(0.0));
            let mut visit = |a, da: &Vectors, b, db: &Vectors| {
                self.track_with_slopes(sens, a, da, b, db, &mut tracks, &mut slopes)
            };
            let to_surface = sens.fly(ray, &tan, f64::INFINITY, &[0.0; P], straight, &mut visit);
            p.steps += to_surface.steps;
            if to_surface.stop == Stop::Stuck {
                out[self.total(Total::Unfinished)].re += p.weight;
                return None;
            }
            // a collision before the surface, with probability q = 1 − e^{−σ_t L}
            let q = -(-sigma_t * to_surface.length).exp_m1();
            let mut d_q = [0.0; P];
            for k in 0..sens.count {
                d_q[k] = sigma_t * (1.0 - q) * to_surface.d_length[k];
            }
            let drawn = self.drawing(q);
            let end = if q > 0.0 && self.choose(sens, p, q, &d_q, u) {
                // its distance `s = −ln(1 − u' q)/σ_t` moves with q (u' = u/drawn uniform)
                let u = u / drawn;
                let s = -(-u * q).ln_1p() / sigma_t;
                let mut d_s = [0.0; P];
                for k in 0..sens.count {
                    d_s[k] = u * d_q[k] / (sigma_t * (1.0 - u * q));
                }
                tracks.fill(0.0);
                slopes.iter_mut().for_each(|s| s.fill(0.0));
                let mut visit = |a, da: &Vectors, b, db: &Vectors| {
                    self.track_with_slopes(sens, a, da, b, db, &mut tracks, &mut slopes)
                };
                let hit = sens.fly(ray, &tan, s, &d_s, straight, &mut visit);
                p.steps += hit.steps;
                hit
            } else {
                // to the surface, with probability e^{−σ_t L}
                to_surface
            };
            p.opl += t.delay_inside(ray.x, end.optical_path, end.length);
            let collided = end.stop == Stop::Collision;
            for (s, d) in p.score.iter_mut().zip(derivatives) {
                *s += flight_score(d.medium_in(part), collided, sigma_t, end.length);
            }
            self.record_tracks_with_slopes(sens, &tracks, &slopes, p, out);
            (ray, tan) = (end.ray, end.tan);
            if !collided {
                match self.leave(t, sens, &mut ray, &mut tan, p, rng) {
                    Some(out_leg) => return Some(out_leg),
                    None if reflections.another() => continue,
                    None => {
                        out[self.total(Total::Unfinished)].re += p.weight;
                        return None;
                    }
                }
            }
            reflections = Reflections::default();
            p.events += 1;
            out[self.total(Total::Absorbed)].re += p.weight * (1.0 - albedo);
            p.weight *= albedo;
            for (s, d) in p.score.iter_mut().zip(derivatives) {
                *s += albedo_score(d.medium_in(part), coefficients);
            }
            if self.connects() {
                let speed = ray.v.length();
                let w_in = ray.v / speed;
                let mut v = Vertex::fixed(ray.x, Some(w_in));
                for k in 0..sens.count {
                    v.dx[k] = tan.x[k];
                    v.dw[k] = (tan.v[k] - w_in * w_in.dot(tan.v[k])) / speed;
                }
                self.connect_differentiated(t, &v, p, shifted, rng, out);
            }
            // with even draws the game's number is drawn always, so the photons' random numbers
            // stay where they were as θ moves
            let survives = if self.even_draws {
                roulette_by(&mut p.weight, uniform(rng))
            } else {
                roulette(&mut p.weight, rng)
            };
            if !survives {
                return None;
            }
            if p.events >= super::particle::MAX_EVENTS {
                out[self.total(Total::Unfinished)].re += p.weight;
                return None;
            }
            (ray, tan) = self.scatter(t, sens, (ray, part), &tan, p, rng);
        }
    }

    /// A scattering event at `ray.x`: the new direction drawn in the frame of the incoming one
    /// (so it turns with it), its sensitivities and the medium parameters' score.
    fn scatter(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        (ray, part): (Ray, Option<usize>),
        tan: &Tangent,
        p: &mut Photon,
        rng: &mut Rng,
    ) -> (Ray, Tangent) {
        let scattering = t.flyer.volume.scattering_of(part);
        let kind = scattering.pick(|| uniform(rng));
        let (u1, u2) = (uniform(rng), uniform(rng));
        let phase = scattering.phase(kind);
        let speed = ray.v.length();
        let w_in = ray.v / speed;
        // the direction about the incoming one in a frame that turns continuously with it
        let (mu, phi) = (phase.sample_mu(u1), std::f64::consts::TAU * u2);
        let w = direction_about_continuously(w_in, mu, phi);
        for (s, d) in p.score.iter_mut().zip(&self.scene.derivatives) {
            *s += d
                .medium_in(part)
                .map_or(0.0, |m| m.dlog_event(scattering, kind, mu));
        }
        let l = sens.at(ray.x);
        let dn = sens.n_slope(&l, &tan.x);
        let mut next = Tangent::ZERO;
        for k in 0..sens.count {
            let dw_in = (tan.v[k] - w_in * w_in.dot(tan.v[k])) / speed;
            let dw = slope(dw_in.length(), |s| {
                direction_about_continuously((w_in + dw_in * s).normalize(), mu, phi)
            });
            next.x[k] = tan.x[k];
            next.v[k] = dw * l.n + w * dn[k];
        }
        (
            Ray {
                x: ray.x,
                v: w * l.n,
            },
            next,
        )
    }

    /// At the surface from inside: leave refracted (where and along which direction, with their
    /// sensitivities), or reflect back inside (`None`: `ray` and `tan` turned in place),
    /// Fresnel's choice scored.
    fn leave(
        &self,
        t: &Tools,
        sens: &Sensitivity,
        ray: &mut Ray,
        tan: &mut Tangent,
        p: &mut Photon,
        rng: &mut Rng,
    ) -> Option<Leaving> {
        let end = *ray;
        let field = &t.flyer.volume.field;
        let n_out = field.n_out;
        let l = sens.at(end.x);
        let dn = sens.n_slope(&l, &tan.x);
        let speed = end.v.length();
        let d = end.v / speed;
        let normal = field.bounds.normal(end.x).unwrap_or(d);
        let turn = sens.normal_turn(end.x, &tan.x);
        let eta = l.n / n_out;
        let r = fresnel(d.dot(normal), eta);
        let mut dd = [DVec3::ZERO; P];
        let mut d_cos = [0.0; P];
        let mut d_r = [0.0; P];
        for k in 0..sens.count {
            dd[k] = (tan.v[k] - d * d.dot(tan.v[k])) / speed;
            d_cos[k] = dd[k].dot(normal) + d.dot(turn[k]);
            let d_eta = dn[k] / n_out;
            let size = d_cos[k].abs().max(d_eta.abs());
            d_r[k] = slope(size, |s| {
                fresnel(d.dot(normal) + d_cos[k] * s, eta + d_eta * s)
            });
        }
        let refracted = refract(d, -normal, eta);
        let reflects = match refracted {
            Ok(_) => self.choose(sens, p, r, &d_r, uniform(rng)),
            // total internal reflection, certain; with even draws drawn too, so the weight does
            // not jump as the critical angle passes
            Err(_) => !self.even_draws || self.choose(sens, p, 1.0, &d_r, uniform(rng)),
        };
        match refracted {
            Ok(leaving) if !reflects => {
                let mut dd_out = [DVec3::ZERO; P];
                for k in 0..sens.count {
                    let d_eta = dn[k] / n_out;
                    let size = dd[k].length().max(turn[k].length()).max(d_eta.abs());
                    dd_out[k] = slope(size, |s| {
                        let normal = (normal + turn[k] * s).normalize();
                        refract((d + dd[k] * s).normalize(), -normal, eta + d_eta * s)
                            .unwrap_or(leaving)
                    });
                }
                Some(Leaving {
                    x: end.x,
                    d: leaving,
                    dx: tan.x,
                    dd: dd_out,
                })
            }
            // the impossible outcome drawn: the photon ends with weight 0
            Err(_) if !reflects => Some(Leaving::fixed(end.x, d)),
            _ => {
                let w = reflect(d, normal);
                for k in 0..sens.count {
                    let dw = dd[k] - (normal * d_cos[k] + turn[k] * d.dot(normal)) * 2.0;
                    tan.v[k] = dw * l.n + w * dn[k];
                }
                ray.v = w * l.n;
                None
            }
        }
    }

    /// Add the chord from `a` to `b` (sensitivities `da`, `db`) to the track lengths through
    /// each target, with the tracks' sensitivities: the chord's ends move, and so do the points
    /// where it crosses a target's surface.
    #[allow(clippy::too_many_arguments)]
    fn track_with_slopes(
        &self,
        sens: &Sensitivity,
        a: DVec3,
        da: &Vectors,
        b: DVec3,
        db: &Vectors,
        tracks: &mut [f64; MAX_TARGETS],
        slopes: &mut TrackSlopes,
    ) {
        let chord = b - a;
        let length = chord.length();
        if length == 0.0 {
            return;
        }
        let along = chord / length;
        for (j, (_, region)) in self.targets.iter().enumerate() {
            let Some((t0, t1)) = region.clip(a, b) else {
                continue;
            };
            tracks[j] += (t1 - t0) * length;
            // a crossing at `t` of the target's surface moves by −N·δp / N·(b − a)
            let moved = |t: f64, k: usize| {
                let normal = region.normal(a + chord * t);
                let rate = normal.dot(chord);
                if rate == 0.0 {
                    0.0
                } else {
                    -normal.dot(da[k] * (1.0 - t) + db[k] * t) / rate
                }
            };
            for k in 0..sens.count {
                let d0 = if t0 > 0.0 { moved(t0, k) } else { 0.0 };
                let d1 = if t1 < 1.0 { moved(t1, k) } else { 0.0 };
                slopes[j][k] += (t1 - t0) * along.dot(db[k] - da[k]) + length * (d1 - d0);
            }
        }
    }

    /// Record a flight's tracks through the targets, with their derivatives: the tracks'
    /// sensitivities plus their value times the path's score.
    fn record_tracks_with_slopes(
        &self,
        sens: &Sensitivity,
        tracks: &[f64; MAX_TARGETS],
        slopes: &TrackSlopes,
        p: &Photon,
        out: &mut [C64],
    ) {
        let dlog = &p.score[..self.scene.derivatives.len()];
        self.record_tracks(tracks, p.weight, dlog, out);
        for (j, &(i, region)) in self.targets.iter().enumerate() {
            let scale = p.weight / region.volume();
            for k in 0..sens.count {
                out[self.power_derivative(i, sens.params[k].0)].re += scale * slopes[j][k];
            }
        }
    }
}
