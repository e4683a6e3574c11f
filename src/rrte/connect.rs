//! Point-to-point connections through an index field (paper 002, Sec. 4): the curved rays from a
//! point `x` inside the volume that pass through a point `y` inside it — boundary-value problems
//! solved as initial-value problems. The same solver joins a point inside to a point outside or
//! to a direction (refracted once at the surface, [`Connector::sample_through`],
//! [`Connector::sample_exit`]), and two points outside across the volume (refracted in and out,
//! [`Connector::sample_across`]): a surface seen or lit through it; and two points outside by the
//! path reflected off the volume's outside ([`Connector::sample_mirror`]): a surface seen or lit
//! in its mirror image. A path that has left its part crosses the parts it meets after, or
//! reflects off their outside ([`Bounces`]).
//!
//! A ray from `x` with unit direction `w` (velocity `v0 = n(x) w` in the σ-form) is traced to its
//! closest approach to `y`, where `(x_s − y)·v_s = 0` (the type-2 condition of Sec. 4 and App. B).
//! The residual is the miss perpendicular to the arriving direction; its Jacobian with respect to
//! `w` comes from the forward sensitivities `∂x/∂v0` carried along the leapfrog (Alg. 2) and
//! projected perpendicular to the ray, which removes the `∂s*/∂v0` term of Eq. 20. Newton's method
//! on this 2×2 system (the paper uses BFGS on `½|x_s − y|²`) converges quadratically near a
//! solution; the same 2×2 matrix at the solution is the ray tube's spreading `dA⊥/dω` at `y`, the
//! exact geometry term of a curved connection (`s²` for a straight one).
//!
//! Between two points there can be several stationary paths. [`Connector::sample`] draws one by
//! starting Newton from a random direction and estimates the inverse probability of having drawn
//! it by restarting until the same path is found again (Alg. 3, after Booth 2007 and Zeltner et
//! al. 2020): `Σ_k f(C_k)` is then estimated without bias by `f(C)/p(C)`.

use super::flight::{fresnel, reflect};
use super::scene::{PartLengths, Surface, Volume};
use crate::eikonal::trace::{entry_parameter, jacobian_of, refract};
use crate::eikonal::{BoundedField, Bounds, IndexField, Ray, Tracer, part_at, turning_angle};
use crate::math::{Rng, direction_about, orthonormal_basis, uniform, uniform_sphere};
use glam::{DMat3, DVec3};
use std::f64::consts::{FRAC_PI_2, TAU};

/// A stationary path from `x` to `y`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Connection {
    /// Unit direction leaving `x`.
    pub direction: DVec3,
    /// The ray's state at its closest approach to `y` (within the tolerance of it).
    pub arrival: Ray,
    /// Geometric length `∫ ds` (for transmittance) and optical path `∫ n ds`.
    pub length: f64,
    pub optical_path: f64,
    /// The ray tube's cross-section at `y` per unit solid angle at `x`, `dA⊥/dω`: the
    /// irradiance at `y` of a source of unit intensity at `x` is `reflectance/spread`.
    pub spread: f64,
    /// The product of the Fresnel reflectances of its reflections inside the surface (1 for a
    /// path that meets no surface, [`Connector::solve_bounced`]).
    pub reflectance: f64,
    /// Newton iterations it took.
    pub iterations: usize,
}

/// A path from a point inside the volume that leaves it travelling along a given direction (an
/// orthographic camera's): the direction BVP of a connection through the surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exit {
    /// Unit direction leaving `x`.
    pub direction: DVec3,
    /// Where the path leaves the volume, and its direction after refraction there.
    pub surface: DVec3,
    pub outgoing: DVec3,
    /// Where the path inside the volume begins and its unit direction there: `x` and
    /// `direction` for a path from inside; the entry point and the refracted direction for one
    /// from outside ([`Connector::solve_across`]), which first runs `before` in a straight line.
    pub inside_from: DVec3,
    pub inside_along: DVec3,
    pub before: f64,
    /// Geometric length inside (all parts), and the optical path (to the point, for a path
    /// through one).
    pub length: f64,
    pub optical_path: f64,
    /// `1 − R` of the Fresnel reflectance at the exit (times that at the entry, from outside,
    /// and the transmittances of every part entered again).
    pub transmission: f64,
    /// The parts of a non-convex volume the path enters again after it first leaves (seen
    /// through another part of the shape), and the geometric length outside between them.
    pub again: Again,
    pub between: f64,
    /// For [`Connector::solve_exit`], `dω_out/dω_x`: how the solid angle of directions leaving
    /// `x` maps onto outgoing directions (1 for straight rays through a matched surface); a source
    /// of intensity `I` at `x` has intensity `I · transmission / jacobian` along the outgoing
    /// direction. For [`Connector::solve_through`], the ray tube's cross-section at the point per
    /// unit solid angle at `x`, `dA⊥/dω`.
    pub jacobian: f64,
    pub iterations: usize,
}

impl Exit {
    /// The geometric length outside the volume up to where the path last leaves it.
    pub fn outside(&self) -> f64 {
        self.before + self.between
    }

    /// The length inside of the path's first part: from `inside_from` along `inside_along` (and
    /// its reflections inside the surface) to where it first leaves.
    pub fn first_length(&self) -> f64 {
        self.length - self.again.parts().iter().map(|p| p.length).sum::<f64>()
    }

    /// Add a stretch inside a part entered again to the path (its length and optical path);
    /// `false` if it has [`MAX_AGAIN`] already.
    fn enter(&mut self, stretch: Reentry) -> bool {
        self.length += stretch.length;
        self.optical_path += stretch.optical_path;
        self.again.push(stretch)
    }

    /// The geometric length inside, part by part where `volume` is several.
    pub fn lengths(&self, volume: &Volume) -> PartLengths {
        let mut lengths = PartLengths::default();
        lengths.add(volume.part_index(self.inside_from), self.first_length());
        for p in self.again.parts() {
            lengths.add(volume.part_index(p.inside), p.length);
        }
        lengths
    }

    /// `e^{−∫σ_t}` along the path in a homogeneous `volume`: `e^{−σ_t L}`, or where the bounds
    /// are several volumes, each stretch inside at its own part's `σ_t`.
    pub fn attenuation(&self, volume: &Volume) -> f64 {
        (-self.lengths(volume).depth(volume)).exp()
    }
}

/// Parts of a non-convex volume, or of several volumes, that a path through its surface enters
/// again: the stretches inside each (one per reflection inside it, and one more), and how many
/// parts it has crossed (entered and left) on the way.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Again {
    parts: [Reentry; MAX_AGAIN],
    count: usize,
    crossed: usize,
    /// Whether the path ended before a part of the volume it would meet beyond its end (a part
    /// it would reflect inside could bring it back): it took the draw of no reflections there.
    declined: bool,
    /// Whether the path ended inside the part it met after its crossings (between two points
    /// inside): it took the draw of not reflecting off that part's outside.
    entered: bool,
    /// The crossings (bits by index) that crossed the part the path ends in, drawn to pass it
    /// ([`Bounces::passes`]).
    passed: u8,
}

/// A path's way across a part it enters again: the entry point (just inside), the unit
/// direction there, and the geometric length and optical path across.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Reentry {
    pub inside: DVec3,
    pub along: DVec3,
    pub length: f64,
    pub optical_path: f64,
}

impl Again {
    pub fn parts(&self) -> &[Reentry] {
        &self.parts[..self.count]
    }

    /// The parts crossed: entered and left again (a path's last part, where it ends inside, is
    /// not counted).
    pub fn crossed(&self) -> usize {
        self.crossed
    }

    /// Add a part; `false` if there are [`MAX_AGAIN`] already.
    fn push(&mut self, part: Reentry) -> bool {
        if self.count == MAX_AGAIN {
            return false;
        }
        self.parts[self.count] = part;
        self.count += 1;
        true
    }
}

/// The most stretches inside parts of a volume a path through its surface enters again after it
/// first leaves (a part it reflects inside counts once more per reflection).
pub const MAX_AGAIN: usize = 4;

/// The reflections at the surface a connection through it follows: `first` inside the part
/// it starts from before it first leaves; then, inside each part it crosses after that (or, where
/// drawn so, one off the outside of a part it meets instead), a number drawn before Newton's
/// method runs (the path must be one function of its start's direction),
/// from the `after` left of its budget; and inside the part it ends in (between two points
/// inside) what the crossings have left. A path is drawn with the chance of its crossings'
/// numbers ([`Bounces::inverse_probability`]) — and a path that ends before a part lying beyond
/// its end (a point, a beam's disc) with the chance that the part's number is none, since a
/// part it would reflect inside could bring it back and it would go on into it — so the
/// estimate divided by it counts every path with at most `first + after` reflections once.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bounces {
    pub first: usize,
    after: usize,
    across: [usize; MAX_AGAIN],
    /// The parts crossed the path reflects off from outside instead of entering (one
    /// reflection of the budget, counted in `across`).
    mirrored: [bool; MAX_AGAIN],
    /// Whether the draw offered that reflection off the outside of each part met; a path so
    /// drawn (particle and path tracing's) also crosses the part it started from where it meets
    /// it again.
    mirrors: bool,
    /// For a path into a part that is not convex, the crossings (bits by index) at which, if
    /// that part is the one met, the path crosses it and goes on instead of ending in it (drawn
    /// each with chance [`PASS`], where `passing`).
    passes: u8,
    passing: bool,
}

/// The chance, drawn for each part a path meets, that a path into a shape that is not convex
/// crosses it there if it is that shape, and ends in it only where it meets it again (a
/// stretch of the shape lies between its ends).
const PASS: f64 = 0.25;

/// The chance that a connection crosses a part without reflecting inside it where its budget
/// lets it reflect (the other numbers share the rest evenly): most light crosses a dielectric
/// unreflected, and it is the path most often there.
const THROUGH: f64 = 0.75;

impl Bounces {
    /// `first` reflections inside the start's part, none after it.
    pub fn first(first: usize) -> Self {
        Bounces {
            first,
            ..Bounces::default()
        }
    }

    /// `first` reflections inside the start's part, then up to `after` more: inside each part
    /// crossed none with chance `THROUGH`, else one of `1 ..= left` evenly; the end's part
    /// takes what is left. Draws nothing where `after` is 0.
    pub fn draw(first: usize, after: usize, rng: &mut Rng) -> Self {
        Self::drawn(first, after, false, rng)
    }

    /// As [`Self::draw`], with one more way to meet each part crossed where the budget lets it
    /// reflect: off its outside (a reflection of the budget), the other ways of not going
    /// through unreflected sharing the rest evenly with it.
    pub fn draw_with_mirrors(first: usize, after: usize, rng: &mut Rng) -> Self {
        Self::drawn(first, after, true, rng)
    }

    fn drawn(first: usize, after: usize, mirrors: bool, rng: &mut Rng) -> Self {
        let mut b = Bounces {
            first,
            after,
            mirrors,
            ..Bounces::default()
        };
        for i in 0..MAX_AGAIN {
            let left = b.left_after(i);
            if left == 0 {
                break;
            }
            let u = uniform(rng);
            if u >= THROUGH {
                let share = (u - THROUGH) / (1.0 - THROUGH);
                let ways = b.ways(i);
                let way = ((share * ways as f64) as usize).min(ways - 1);
                // ways 0 … left − 1 reflect inside 1 … left times, way `left` off the outside
                b.mirrored[i] = way == left;
                b.across[i] = if b.mirrored[i] { 1 } else { 1 + way };
            }
        }
        b
    }

    /// Draw, for a path that ends in a part that is not convex, where it crosses that part
    /// instead of ending in it (`PASS` at each crossing).
    pub fn draw_passes(&mut self, rng: &mut Rng) {
        self.passing = true;
        for i in 0..MAX_AGAIN {
            if uniform(rng) < PASS {
                self.passes |= 1 << i;
            }
        }
    }

    /// Whether the path crosses the part it ends in if that is the `i`th part it meets.
    fn passes(&self, i: usize) -> bool {
        i < MAX_AGAIN && self.passes & (1 << i) != 0
    }

    /// `first` reflections inside the start's part, `across` inside the parts crossed, `end`
    /// inside the end's part: one way, chosen.
    #[cfg(test)]
    fn with(first: usize, across: [usize; MAX_AGAIN], end: usize) -> Self {
        Bounces {
            first,
            after: across.iter().sum::<usize>() + end,
            across,
            ..Bounces::default()
        }
    }

    /// Reflections at the surface of the `i`th part crossed: inside it, or its one off its
    /// outside ([`Self::mirrored`]).
    fn across(&self, i: usize) -> usize {
        self.across.get(i).copied().unwrap_or(0)
    }

    /// Whether the path reflects off the outside of the `i`th part it meets after leaving its
    /// own, instead of crossing it.
    fn mirrored(&self, i: usize) -> bool {
        self.mirrored.get(i).copied().unwrap_or(false)
    }

    /// Whether the draw offers a reflection off the outside of the `i`th part met (drawn
    /// after the first `i`): one per path at most (a second, between two convex outsides, is
    /// rare and found by Newton's method seldom, its weight large).
    fn offers_mirror(&self, i: usize) -> bool {
        self.mirrors && i < MAX_AGAIN && !self.mirrored[..i].contains(&true)
    }

    /// The ways the draw for the `i`th part met shares the chance `1 − THROUGH` among evenly:
    /// 1 … `left` reflections inside, and off its outside where offered.
    fn ways(&self, i: usize) -> usize {
        self.left_after(i) + usize::from(self.offers_mirror(i))
    }

    /// What is left of the budget after the first `crossed` parts crossed.
    pub fn left_after(&self, crossed: usize) -> usize {
        self.after - self.across[..crossed.min(MAX_AGAIN)].iter().sum::<usize>()
    }

    /// `1/p` of having drawn the numbers of the first `crossed` parts crossed, and, for a path
    /// that `declined` a part beyond its end, no reflections inside the next.
    pub fn inverse_probability(&self, crossed: usize, declined: bool) -> f64 {
        let declined = declined && crossed < MAX_AGAIN;
        (0..crossed.min(MAX_AGAIN) + usize::from(declined))
            .map(|i| match (self.left_after(i), self.across[i]) {
                (0, _) => 1.0,
                (_, 0) => 1.0 / THROUGH,
                _ => self.ways(i) as f64 / (1.0 - THROUGH),
            })
            .product()
    }

    /// `1/p` of having drawn the numbers the path `again` describes took: its parts crossed and
    /// any it declined beyond its end ([`Self::inverse_probability`]), and, for a path that
    /// entered the part it ends in where the draw offered a reflection off its outside, not
    /// that reflection.
    pub fn inverse_probability_of(&self, again: &Again) -> f64 {
        let mut crossings = self.inverse_probability(again.crossed, again.declined);
        if self.passing {
            crossings /= PASS.powi(again.passed.count_ones() as i32);
            if again.entered && again.crossed < MAX_AGAIN {
                crossings /= 1.0 - PASS;
            }
        }
        let i = again.crossed;
        if !(again.entered && self.offers_mirror(i) && self.left_after(i) > 0) {
            return crossings;
        }
        // the reflection off the outside is one of the ways past `THROUGH`
        crossings / (1.0 - (1.0 - THROUGH) / self.ways(i) as f64)
    }
}

/// Between two points in one part that is not convex, the chance of drawing a path that leaves
/// it and comes back where the straight line between them leaves it (one minus it where the
/// line stays inside; [`Connector::sample_inside`]).
const AROUND_LIKELY: f64 = 0.9;

/// Between two points in one convex part beside others, where the budget lets a path reflect,
/// the chance of drawing one that leaves the part and comes back (off another part's outside,
/// or reflected inside one) rather than one that reflects inside the part alone.
const RETURN_CHANCE: f64 = 0.5;

/// How a [`Connector::sample`] went: the path (if the solver converged) with its inverse
/// probability, and the work done.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sampled<T = Connection> {
    pub path: Option<(T, f64)>,
    /// Solver runs and Newton iterations in total.
    pub solves: usize,
    pub iterations: usize,
    /// Distinct stationary paths met while estimating the inverse probability.
    pub distinct: usize,
}

impl<T> Sampled<T> {
    /// No path, and no work done.
    pub fn none() -> Self {
        Sampled {
            path: None,
            solves: 0,
            iterations: 0,
            distinct: 0,
        }
    }

    /// The same draw with its path turned by `f`.
    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> Sampled<U> {
        Sampled {
            path: self.path.map(|(p, inverse_p)| (f(p), inverse_p)),
            solves: self.solves,
            iterations: self.iterations,
            distinct: self.distinct,
        }
    }
}

/// A path between two points inside the volume ([`Connector::sample_inside`]), with the
/// reflections it takes inside the surface of the start's volume before it leaves it (all of
/// them, for a path within it).
#[derive(Clone, Copy, Debug, PartialEq)]
// on the stack for one connection at a time: boxing the larger would allocate per connection
#[allow(clippy::large_enum_variant)]
pub enum InsidePath {
    /// Along curved rays within the part holding both, after reflections inside its surface.
    Within(Connection, usize),
    /// Out of one of several volumes, across any between, into the other
    /// ([`Connector::solve_into`]), after reflections inside the first and inside the other:
    /// its stretches inside the other after the reflections there are parts entered again.
    Between(Exit, Bounces),
}

impl InsidePath {
    /// Unit direction leaving the start.
    pub fn direction(&self) -> DVec3 {
        match self {
            InsidePath::Within(c, _) => c.direction,
            InsidePath::Between(e, _) => e.direction,
        }
    }

    /// Where it arrives (its closest approach to the far point), and its unit direction there.
    pub fn arrival(&self) -> (DVec3, DVec3) {
        match self {
            InsidePath::Within(c, _) => (c.arrival.x, c.arrival.v.normalize()),
            InsidePath::Between(e, _) => (e.surface, e.outgoing),
        }
    }

    /// The ray tube's cross-section at the far point per unit solid angle at the start,
    /// `dA⊥/dω`.
    pub fn spread(&self) -> f64 {
        match self {
            InsidePath::Within(c, _) => c.spread,
            InsidePath::Between(e, _) => e.jacobian,
        }
    }

    /// The product of its Fresnel factors: reflectances inside the surface, and `1 − R` of
    /// every surface it crosses.
    pub fn fresnel(&self) -> f64 {
        match self {
            InsidePath::Within(c, _) => c.reflectance,
            InsidePath::Between(e, _) => e.transmission,
        }
    }

    /// Whether a path between two parts (or out of one part and back in) keeps within
    /// [`MAX_AGAIN`] stretches after its first from either end: run the other way, its first
    /// part's reflections and its last part's trade places. A path within one part always does.
    pub fn fits_either_way(&self) -> bool {
        match self {
            InsidePath::Within(..) => true,
            InsidePath::Between(e, bounces) => {
                let end = bounces.left_after(e.again.crossed);
                e.again.parts().len() + bounces.first <= MAX_AGAIN + end
            }
        }
    }

    /// Its geometric length inside, part by part where `volume` is several.
    pub fn lengths(&self, volume: &Volume) -> PartLengths {
        match self {
            InsidePath::Within(c, _) => PartLengths::one(volume.part_index(c.arrival.x), c.length),
            InsidePath::Between(e, _) => e.lengths(volume),
        }
    }

    /// Its geometric length outside the volume, between the volumes it joins.
    pub fn outside(&self) -> f64 {
        match self {
            InsidePath::Within(..) => 0.0,
            InsidePath::Between(e, _) => e.outside(),
        }
    }
}

/// Solves connections in one volume.
pub struct Connector<'v> {
    volume: &'v Volume,
    tracer: Tracer<'v>,
    straight: bool,
    /// `n` constant inside and equal to `n_out`: paths leaving the volume are straight lines.
    matched: bool,
    /// Largest perpendicular miss accepted as a hit.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// Take one more Newton step once within the tolerance ([`Self::polished`]).
    polish: bool,
    /// Restarts at most, when estimating an inverse probability (beyond it the count so far is
    /// used: a bias only for paths drawn less often than once in this many tries).
    pub max_restarts: usize,
    /// Geometric length after which a ray traced to its exit is taken as trapped (a graded index
    /// can hold rays in orbits that never reach the surface): where it would be attenuated below
    /// `e^−30`, and at most [`TRAPPED_CROSSINGS`] widths of the volume.
    max_length: f64,
    /// Surfaces outside that block a path between the parts of a non-convex volume.
    surfaces: &'v [Surface],
}

/// Optical depth beyond which a connection's transmittance (`< e^−30`) is dropped.
const TRAPPED_DEPTH: f64 = 30.0;
/// Widths of the volume a connection ray may run before it is taken as trapped.
const TRAPPED_CROSSINGS: f64 = 100.0;

/// A ray with its sensitivities to the initial velocity, `∂x/∂v0` and `∂v/∂v0`, and the field at
/// its position (`n`, the force `n∇n` and its Jacobian), so that a step evaluates the field once.
#[derive(Clone, Copy)]
struct Tangent {
    r: Ray,
    xv: DMat3,
    vv: DMat3,
    n: f64,
    force: DVec3,
    jacobian: DMat3,
}

impl Tangent {
    /// The ray leaving `x` along unit `w` (`|v| = n(x)`).
    fn start(field: &BoundedField, x: DVec3, w: DVec3) -> Self {
        let (n, g, h) = field.eval(x);
        Tangent {
            r: Ray { x, v: w * n },
            xv: DMat3::ZERO,
            vv: DMat3::IDENTITY,
            n,
            force: g * n,
            jacobian: jacobian_of(n, g, h),
        }
    }

    /// The ray leaving `x` along unit `w` with the sensitivities `xv`, `vv` to some perturbation
    /// of its start (columns), carried like `∂x/∂v0`, `∂v/∂v0`: the tangent equations are linear.
    fn with(field: &BoundedField, x: DVec3, w: DVec3, xv: DMat3, vv: DMat3) -> Self {
        Tangent {
            xv,
            vv,
            ..Tangent::start(field, x, w)
        }
    }

    /// One leapfrog step of size `h` with the sensitivities (paper 002, Alg. 2); the position and
    /// velocity are those of [`Tracer::leapfrog`], bit for bit.
    fn step(&self, field: &BoundedField, h: f64) -> Self {
        let v_half = self.r.v + self.force * (0.5 * h);
        let x = self.r.x + v_half * h;
        let (n, g, hess) = field.eval(x);
        let force = g * n;
        let jacobian = jacobian_of(n, g, hess);
        let hv = self.vv + self.jacobian * (0.5 * h) * self.xv;
        let xv = self.xv + hv * h;
        Tangent {
            r: Ray {
                x,
                v: v_half + force * (0.5 * h),
            },
            xv,
            vv: hv + jacobian * (0.5 * h) * xv,
            n,
            force,
            jacobian,
        }
    }
}

/// A ray traced to its closest approach to a point ([`Connector::approach`]).
#[derive(Clone, Copy, Debug)]
struct Approach {
    /// The ray there, `∂x/∂v0` there, the geometric length and optical path to it.
    end: Ray,
    xv: DMat3,
    length: f64,
    optical_path: f64,
    /// Whether the ray left the volume before it and was carried on in a straight line: a
    /// Newton iterate, never a path.
    beyond: bool,
}

impl Approach {
    /// The ray `last` (`length` along it), about to leave the volume, carried on in a straight
    /// line `x + v σ` to its closest approach to `y` (the sensitivities moving as `∂x += ∂v σ`);
    /// `None` if it is moving away from `y`.
    fn carried_on(last: &Tangent, length: f64, y: DVec3) -> Option<Self> {
        let r = last.r;
        let sigma = (y - r.x).dot(r.v) / r.v.length_squared();
        (sigma > 0.0).then(|| Approach {
            end: Ray {
                x: r.x + r.v * sigma,
                v: r.v,
            },
            xv: last.xv + last.vv * sigma,
            length: length + r.v.length() * sigma,
            optical_path: f64::NAN,
            beyond: true,
        })
    }
}

/// Cones of Newton starts for the paths that reflect inside a box of a gently graded field:
/// every such path starts within `half_angle` of one of `centers` (the direction to a mirror
/// image of the far end, or the flipped direction of the exit), so within it of the nearest
/// one. One cone is drawn evenly, its starts drawn uniformly in it (twice as wide, for the
/// stepped ray's error), and only paths whose start lies nearest its centre are taken from it:
/// the cones share the paths out, each path to one, and the count of cones times Alg. 3's
/// count in the cone drawn estimates a path's inverse probability without bias.
#[derive(Clone, Copy, Debug)]
struct Cones {
    centers: [DVec3; MAX_CONES],
    count: usize,
    half_angle: f64,
}

/// The most cones of [`Cones`]: the eight sign flips of three exit directions.
const MAX_CONES: usize = 24;

impl Cones {
    fn new(half_angle: f64) -> Self {
        Cones {
            centers: [DVec3::ZERO; MAX_CONES],
            count: 0,
            half_angle,
        }
    }

    /// Add the unit direction `c` as a centre (once: flips of a direction with a zero component
    /// coincide).
    fn push(&mut self, c: DVec3) {
        let known = self.centers[..self.count]
            .iter()
            .any(|d| (*d - c).length() < 1e-12);
        if !known && self.count < MAX_CONES {
            self.centers[self.count] = c;
            self.count += 1;
        }
    }

    /// A cone drawn evenly, and the inverse of its chance.
    fn pick(&self, rng: &mut Rng) -> (usize, f64) {
        let k = ((uniform(rng) * self.count as f64) as usize).min(self.count - 1);
        (k, self.count as f64)
    }

    /// The centre nearest the unit direction `w`.
    fn nearest(&self, w: DVec3) -> usize {
        (0..self.count)
            .max_by(|&a, &b| w.dot(self.centers[a]).total_cmp(&w.dot(self.centers[b])))
            .unwrap_or(0)
    }

    /// A start in cone `k` ([`start_in_cone`]).
    fn start(&self, k: usize, rng: &mut Rng) -> DVec3 {
        start_in_cone(self.centers[k], self.half_angle, rng)
    }
}

/// A start uniform in the cone about unit `center` twice as wide as `half_angle` (at most a
/// hemisphere), a cone proved to hold every path's start: the margin for the stepped ray's error.
fn start_in_cone(center: DVec3, half_angle: f64, rng: &mut Rng) -> DVec3 {
    let cone = (2.0 * half_angle).min(FRAC_PI_2);
    let mu = 1.0 - uniform(rng) * (1.0 - cone.cos());
    direction_about(center, mu, TAU * uniform(rng))
}

/// The diameter of the region a path reflected `bounces` times inside a box of half extents
/// `half` sweeps once unfolded (each reflection mirrors the rest of it across the face): a chain
/// of `bounces + 1` boxes, longest when all lie along the box's longest side.
fn unfolded_diameter(half: DVec3, bounces: usize) -> f64 {
    let long = 2.0 * half.max_element();
    let stretched = long * (1 + bounces) as f64;
    ((2.0 * half).length_squared() - long * long + stretched * stretched).sqrt()
}

/// The chance that a connection's Newton start is drawn near the straight line
/// ([`Connector::initial_along`]).
const NEAR: f64 = 0.5;

/// The same for a path through the surface, unreflected inside the part it starts in, from a
/// point where the field turns rays little ([`BoundedField::start_cone`] proves a cone inside):
/// the path starts near the straight line nearly always, and the uniform starts that seldom
/// find it are drawn seldom (a path reflected first starts far from that line).
const NEAR_GENTLE: f64 = 0.9;

/// Largest change of direction of one Newton step (radians): keeps the solver in the basin it
/// started in.
const MAX_TURN: f64 = 0.3;
/// Distinct stationary paths a connection tells apart (for statistics).
const MAX_DISTINCT: usize = 16;
/// Directions closer than this are the same stationary path.
const SAME_PATH: f64 = 1e-5;

impl<'v> Connector<'v> {
    pub fn new(volume: &'v Volume, step: f64, max_steps: usize) -> Self {
        let size = volume
            .field
            .bounds
            .half_extent()
            .map_or(1.0, |h| h.max_element());
        // with a density the attenuation along a ray is only bounded above: width alone
        let sigma_t = if volume.density.is_none() {
            volume.sigma_t()
        } else {
            0.0
        };
        let max_length = (TRAPPED_CROSSINGS * 2.0 * size).min(if sigma_t > 0.0 {
            TRAPPED_DEPTH / sigma_t
        } else {
            f64::INFINITY
        });
        Connector {
            volume,
            tracer: Tracer {
                field: &volume.field,
                step,
                max_steps,
            },
            straight: volume.homogeneous(),
            matched: volume.homogeneous() && volume.index_matched(),
            tolerance: 1e-9 * size,
            max_iterations: 40,
            polish: false,
            max_restarts: 10_000,
            max_length,
            surfaces: &[],
        }
    }

    /// The same connector with `surfaces` blocking the stretches outside between the parts of a
    /// non-convex volume.
    pub fn blocked_by(mut self, surfaces: &'v [Surface]) -> Self {
        self.surfaces = surfaces;
        self
    }

    /// The same connector taking one more Newton step once a path is within the tolerance, which
    /// leaves a residual at round-off (the step squares it): for central differences of a solved
    /// path, where the tolerance's share of the residual would not cancel.
    pub fn polished(mut self) -> Self {
        self.polish = true;
        self
    }

    /// Whether Newton's iteration ends at a residual of size `miss` (within `tolerance`): once
    /// within it, a polishing connector steps once more first (`polished` records that it has).
    fn converged(&self, miss: f64, tolerance: f64, polished: &mut bool) -> bool {
        if miss > tolerance {
            return false;
        }
        if self.polish && !*polished {
            *polished = true;
            return false;
        }
        true
    }

    /// Trace from `x` along unit `w` to the closest approach to `y`, carrying `∂x/∂v0`; `None` if
    /// the ray leaves the volume or runs out of steps first.
    /// Whether rays from `x` run straight: `n` is constant in the volume, or in the part of
    /// several volumes that holds `x` (a ray stays in its part until it reaches the surface).
    fn straight_from(&self, x: DVec3) -> bool {
        self.straight
            || (self.volume.field.bounds.parts())
                .is_some_and(|parts| parts[part_at(parts, x)].is_constant())
    }

    /// The straight path from `x` to `y` through constant `n`, if it reaches `y` before it
    /// leaves the volume (or the part of several holding `x`): points in two volumes, or in two
    /// lobes of a shape that is not convex, are not joined through the surroundings.
    fn straight_inside(&self, x: DVec3, y: DVec3) -> Option<Connection> {
        let c = self.straight_line(x, y)?;
        let exit = self.volume.field.bounds.exit(x, c.direction)?;
        (exit >= c.length).then_some(c)
    }

    fn shoot(&self, x: DVec3, w: DVec3, y: DVec3) -> Option<Approach> {
        self.approach(Tangent::start(&self.volume.field, x, w), y)
    }

    /// Trace the ray `s` with its sensitivities on to its closest approach to `y` (in closed form
    /// through a constant index); `None` if it runs out of steps first, or leaves the volume
    /// moving away from `y`. A ray that leaves still approaching `y` is carried on in a straight
    /// line to its closest approach ([`Approach::carried_on`]): not a path, but a miss Newton's
    /// method can steer back from, where `y` lies near the surface and the ray strays across it.
    fn approach(&self, mut s: Tangent, y: DVec3) -> Option<Approach> {
        let field = &self.volume.field;
        if self.straight_from(s.r.x) {
            // x(σ) = x + v σ: the sensitivities move as ∂x += ∂v σ
            let d = s.r.v / s.n;
            let along = (y - s.r.x).dot(d);
            if along <= 0.0 || field.bounds.exit(s.r.x, d).is_none_or(|e| e < along) {
                return None;
            }
            let end = Ray {
                x: s.r.x + d * along,
                v: s.r.v,
            };
            return Some(Approach {
                end,
                xv: s.xv + s.vv * (along / s.n),
                length: along,
                optical_path: s.n * along,
                beyond: false,
            });
        }
        let t = &self.tracer;
        let h = t.step;
        let away = |r: &Ray| (r.x - y).dot(r.v);
        // a ray that starts moving away may turn back (a lens's long way round): the closest
        // approach is where it stops approaching after it has started to
        let mut approached = away(&s.r) < 0.0;
        let (mut length, mut opl) = (0.0, 0.0);
        for _ in 0..t.max_steps {
            let mut next = s.step(field, h);
            // a step across the surface may still hold the closest approach before it
            let closest = approached && away(&next.r) >= 0.0;
            if !closest && !field.bounds.contains(next.r.x) {
                return Approach::carried_on(&s, length, y);
            }
            if closest {
                // the closest approach lies in this step: bisect on (x − y)·v
                let (mut lo, mut hi) = (0.0, h);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if away(&t.leapfrog(s.r, mid)) < 0.0 {
                        lo = mid
                    } else {
                        hi = mid
                    }
                    if hi - lo < 1e-15 * h {
                        break;
                    }
                }
                next = s.step(field, lo);
                if !field.bounds.contains(next.r.x) {
                    return Approach::carried_on(&s, length, y);
                }
            }
            let chord = (next.r.x - s.r.x).length();
            length += chord;
            opl += 0.5 * (s.n + next.n) * chord;
            s = next;
            if closest {
                return Some(Approach {
                    end: s.r,
                    xv: s.xv,
                    length,
                    optical_path: opl,
                    beyond: false,
                });
            }
            approached |= away(&s.r) < 0.0;
        }
        None
    }

    /// The stationary path Newton's method reaches from the initial direction `w0`, if any.
    pub fn solve(&self, x: DVec3, y: DVec3, w0: DVec3) -> Option<Connection> {
        if self.straight_from(x) {
            return self.straight_inside(x, y);
        }
        let n_x = self.volume.field.n(x);
        let mut w = w0.normalize();
        let mut polished = false;
        for iteration in 0..self.max_iterations {
            let Approach {
                end,
                xv,
                length,
                optical_path,
                beyond,
            } = self.shoot(x, w, y)?;
            let (e1, e2) = orthonormal_basis(w);
            // ∂(miss⊥)/∂(direction angles): the sensitivities times dv0/dw = n(x)
            let miss = Miss::across(end.v.normalize(), end.x - y, [xv * e1 * n_x, xv * e2 * n_x]);
            if self.converged(miss.size(), self.tolerance, &mut polished) {
                let det = miss.det();
                return (det.abs() > 0.0 && !beyond).then_some(Connection {
                    direction: w,
                    arrival: end,
                    length,
                    optical_path,
                    spread: det.abs(),
                    reflectance: 1.0,
                    iterations: iteration + 1,
                });
            }
            w = miss.turn(w)?;
        }
        None
    }

    /// The one straight path through constant `n`.
    fn straight_line(&self, x: DVec3, y: DVec3) -> Option<Connection> {
        let d = y - x;
        let s = d.length();
        if s == 0.0 {
            return None;
        }
        let n = self.volume.field.n(x);
        let w = d / s;
        Some(Connection {
            direction: w,
            arrival: Ray { x: y, v: w * n },
            length: s,
            optical_path: n * s,
            spread: s * s,
            reflectance: 1.0,
            iterations: 0,
        })
    }

    /// A random initial direction at `x` for a path to `y`, [`Self::initial_along`] the chord.
    fn initial(&self, x: DVec3, y: DVec3, rng: &mut Rng) -> DVec3 {
        self.initial_along((y - x).normalize(), NEAR, rng)
    }

    /// A random initial direction for a path that leaves roughly along unit `toward`: within
    /// 30° of it (where most paths start) with chance `near`, else uniform (so that every
    /// stationary path can be drawn).
    fn initial_along(&self, toward: DVec3, near: f64, rng: &mut Rng) -> DVec3 {
        let u = uniform_sphere(uniform(rng), uniform(rng));
        if uniform(rng) < near {
            (toward + u * 0.5).normalize()
        } else {
            u
        }
    }

    /// The starts for a path that stays inside the region holding `x` and `y`: where the field
    /// bounds how far a ray turns there ([`BoundedField::start_cone`], worked out once for all
    /// of Alg. 3's restarts), in the cone about the chord that holds every such path's start
    /// ([`start_in_cone`]), so that each start may find a path; else [`Self::initial`].
    fn starts_inside(&self, x: DVec3, y: DVec3) -> impl Fn(&mut Rng) -> DVec3 + '_ {
        let cone = self.volume.field.start_cone(x);
        move |rng: &mut Rng| match cone {
            Some(theta) => start_in_cone((y - x).normalize(), theta, rng),
            None => self.initial(x, y, rng),
        }
    }

    /// The path Newton's method finds from one random start, counted once (the biased variant of
    /// Alg. 3: exact where a single path joins the points).
    pub fn sample_first(&self, x: DVec3, y: DVec3, rng: &mut Rng) -> Sampled {
        if self.straight_from(x) {
            return self.sample(x, y, rng);
        }
        first(
            self.starts_inside(x, y),
            |w| self.solve(x, y, w).map(|c| (c, c.direction, c.iterations)),
            rng,
        )
    }

    /// One stationary path from `x` to `y` drawn at random, with an unbiased estimate of the
    /// inverse probability of drawing it (Alg. 3; `1` where `n` is constant: one path).
    pub fn sample(&self, x: DVec3, y: DVec3, rng: &mut Rng) -> Sampled {
        if self.straight_from(x) {
            return Sampled {
                path: self.straight_inside(x, y).map(|c| (c, 1.0)),
                solves: 1,
                iterations: 0,
                distinct: 1,
            };
        }
        restarts(
            self.max_restarts,
            self.starts_inside(x, y),
            |w| self.solve(x, y, w).map(|c| (c, c.direction, c.iterations)),
            rng,
        )
    }

    /// Whether `n` is constant inside and equal to `n_out` (index-matched straight rays).
    pub fn matched(&self) -> bool {
        self.matched
    }

    /// One stationary path drawn from the starts `start` gives to `solve` (the path, its
    /// direction at the start, its Newton iterations): Alg. 3's restarts for its inverse
    /// probability, or with `first_only` the first path found, counted once.
    fn draw<T>(
        &self,
        first_only: bool,
        start: impl Fn(&mut Rng) -> DVec3,
        solve: impl Fn(DVec3) -> Option<(T, DVec3, usize)>,
        rng: &mut Rng,
    ) -> Sampled<T> {
        if first_only {
            first(start, solve, rng)
        } else {
            restarts(self.max_restarts, start, solve, rng)
        }
    }

    /// As [`Self::draw`] for a path through the surface that reflects inside the parts it crosses
    /// as `bounces` drew: its inverse probability also that of those reflections.
    fn draw_crossing(
        &self,
        first_only: bool,
        start: impl Fn(&mut Rng) -> DVec3,
        solve: impl Fn(DVec3) -> Option<(Exit, DVec3, usize)>,
        bounces: &Bounces,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        let mut s = self.draw(first_only, start, solve, rng);
        if let Some((e, inverse_p)) = &mut s.path {
            *inverse_p *= bounces.inverse_probability_of(&e.again);
        }
        s
    }

    /// The straight path from `x` inside an index-matched volume to the point `p`, through
    /// every part it meets on the way ([`Self::straight_exit`]).
    fn straight_to(&self, x: DVec3, p: DVec3) -> Sampled<Exit> {
        let d = p - x;
        let s = d.length();
        self.straight_exit(x, d / s, Some(s), s)
    }

    /// The straight path from `x` inside an index-matched volume along unit `w`, leaving it (and
    /// reaching the point `to_point` away): its exit, with `jacobian` the spread `s²` at that
    /// point (1 for a direction), through every part of a non-convex volume, or of several
    /// volumes, it enters again on the way, up to `end` from `x`.
    fn straight_exit(&self, x: DVec3, w: DVec3, to_point: Option<f64>, end: f64) -> Sampled<Exit> {
        let n = self.volume.field.n_out;
        let bounds = &self.volume.field.bounds;
        let path = bounds.exit(x, w).and_then(|t1| {
            let mut exit = t1.max(0.0);
            let (optical_path, jacobian) = match to_point {
                Some(s) if s > exit => (n * s, s * s),
                Some(_) => return None,
                None => (n * exit, 1.0),
            };
            let (mut again, mut between, mut length) = (Again::default(), 0.0, exit);
            while let Some(t0) = bounds.reentry(x + w * exit, w) {
                let entry = exit + t0;
                if entry >= end {
                    break;
                }
                let inside = x + w * (exit + entry_parameter(t0));
                let chord = bounds.exit(inside, w)?.max(0.0);
                let chord = chord.min(end - entry);
                let reentry = Reentry {
                    inside,
                    along: w,
                    length: chord,
                    optical_path: n * chord,
                };
                if !again.push(reentry) {
                    return None;
                }
                between += t0;
                length += chord;
                exit = entry + chord;
                if exit >= end {
                    break;
                }
            }
            let optical_path = match to_point {
                Some(_) => optical_path,
                None => n * exit,
            };
            Some((
                Exit {
                    direction: w,
                    surface: x + w * exit,
                    outgoing: w,
                    inside_from: x,
                    inside_along: w,
                    before: 0.0,
                    length,
                    optical_path,
                    transmission: 1.0,
                    jacobian,
                    iterations: 0,
                    again,
                    between,
                },
                1.0,
            ))
        });
        Sampled {
            path,
            solves: 1,
            iterations: 0,
            distinct: 1,
        }
    }

    /// A path from `x` leaving the volume along the unit direction `c` of `target` (an
    /// [`Aim::Along`] or [`Aim::Back`]) after `bounces` reflections inside the surface (and
    /// inside the parts it crosses after), drawn like [`Connector::sample`] (`first`: the
    /// biased variant), its inverse probability also that of the reflections drawn for the
    /// parts it crosses ([`Bounces::inverse_probability`]).
    pub fn sample_exit(
        &self,
        x: DVec3,
        target: Aim,
        bounces: &Bounces,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        let c = target.toward(x);
        if self.matched {
            // nothing reflects at an index-matched surface
            return match bounces.first {
                0 => self.straight_exit(x, c, None, target.reach(x, c)),
                _ => Sampled::none(),
            };
        }
        if let Some(s) = self.box_exit(x, c, bounces.first, rng) {
            return s;
        }
        let solve = |w| {
            self.solve_exit(x, target, w, bounces)
                .map(|e| (e, e.direction, e.iterations))
        };
        if let Some(cones) = self.flipped_cones(x, c, bounces) {
            let (k, inverse) = cones.pick(rng);
            let start = |rng: &mut Rng| cones.start(k, rng);
            let own = |w| solve(w).filter(|e: &(Exit, DVec3, usize)| cones.nearest(e.1) == k);
            let mut s = self.draw_crossing(first_only, start, own, bounces, rng);
            if let Some((_, inverse_p)) = &mut s.path {
                *inverse_p *= inverse;
            }
            return s;
        }
        let start = |rng: &mut Rng| self.initial_along(c, NEAR, rng);
        self.draw_crossing(first_only, start, solve, bounces, rng)
    }

    /// In one box of a field that turns rays little, the cones holding the starts of the paths
    /// from `x` that leave along unit `c` after reflecting inside as `bounces` drew: about the
    /// sign flips of the direction each face facing `c` refracts `c` in along (all eight; one
    /// axis flipped for one reflection, none without), as wide as a ray may turn along the path
    /// unfolded, and as the index where it leaves (anywhere between its bounds over the box)
    /// moves that direction. `None` elsewhere, and for a path without reflections where more
    /// than one face faces `c`.
    fn flipped_cones(&self, x: DVec3, c: DVec3, bounces: &Bounces) -> Option<Cones> {
        let field = &self.volume.field;
        let Bounds::Box { half } = field.bounds else {
            return None;
        };
        let (slope, floor, ceil) = field.index_bounds(x)?;
        if floor <= 0.0 {
            return None;
        }
        let turn = turning_angle(slope / floor * unfolded_diameter(half, bounces.first))?;
        let mut inward = [(DVec3::ZERO, 0.0); 3];
        let mut faces = 0;
        for axis in 0..3 {
            if c[axis] == 0.0 {
                continue;
            }
            let mut normal = DVec3::ZERO;
            normal[axis] = c[axis].signum();
            // the light arriving along −c refracts in along −w, as the index there says
            let along = |n: f64| refract(-c, normal, field.n_out / n).ok().map(|b| -b);
            let (lo, mid, hi) = (along(floor)?, along(0.5 * (floor + ceil))?, along(ceil)?);
            let spread = mid.dot(lo).min(mid.dot(hi)).clamp(-1.0, 1.0).acos();
            inward[faces] = (mid, spread);
            faces += 1;
        }
        // without reflections, only where one face faces `c` (along an axis): the cones of
        // several faces would each hold a path of one face at most, drawn a third of the time
        if bounces.first == 0 && faces != 1 {
            return None;
        }
        let spread = inward[..faces].iter().map(|f| f.1).fold(0.0, f64::max);
        let mut cones = Cones::new(turn + spread);
        for &(w, _) in &inward[..faces] {
            for flips in 0..8usize {
                let flipped = (0..3).filter(|a| flips >> a & 1 == 1).count();
                if bounces.first <= 1 && flipped != bounces.first {
                    continue;
                }
                let sign = |a: usize| if flips >> a & 1 == 1 { -1.0 } else { 1.0 };
                cones.push(w * DVec3::new(sign(0), sign(1), sign(2)));
            }
        }
        Some(cones)
    }

    /// From `x` in a box of constant index (the one volume), the paths leaving it along unit `c`
    /// after `bounces` reflections inside, in closed form instead of Alg. 3's restarts: one
    /// leaving through a face of outward normal `N` (`N·c > 0`) runs inside it along the
    /// direction `w` Snell's law gives from `c` at that face, and each reflection off a face (a
    /// plane of the axes) flips one component of the direction, so the path starts along one of
    /// the eight sign flips of `w` (`w` itself without reflections). The straight ray from each
    /// start, reflected `bounces` times, tells whether it leaves through that face; one of the
    /// starts that do is drawn evenly and solved (Newton from the exact start: the path, with
    /// its spread and Fresnel factors), its inverse probability their number: an unbiased
    /// estimate of their sum. `None` where this does not apply.
    fn box_exit(&self, x: DVec3, c: DVec3, bounces: usize, rng: &mut Rng) -> Option<Sampled<Exit>> {
        let field = &self.volume.field;
        if !matches!(field.bounds, Bounds::Box { .. }) || !self.straight {
            return None;
        }
        let eta = field.n_out / field.n(x);
        let mut starts = [DVec3::ZERO; 24];
        let (mut tried, mut found) = (0, 0);
        let mut chosen = None;
        for face in 0..6 {
            let mut normal = DVec3::ZERO;
            normal[face / 2] = if face % 2 == 0 { -1.0 } else { 1.0 };
            if normal.dot(c) <= 0.0 {
                continue;
            }
            // the light arriving along −c refracts in along −w
            let Ok(back) = refract(-c, normal, eta) else {
                continue;
            };
            let flips = if bounces == 0 { 1 } else { 8 };
            for flip in 0..flips {
                let sign = |bit: usize| if flip & bit != 0 { -1.0 } else { 1.0 };
                let start = -back * DVec3::new(sign(1), sign(2), sign(4));
                if starts[..tried]
                    .iter()
                    .any(|s| (*s - start).length() < SAME_PATH)
                {
                    continue;
                }
                starts[tried] = start;
                tried += 1;
                if self.leaves_through(x, start, bounces, (normal, -back)) {
                    // one of those found so far, each alike
                    found += 1;
                    if uniform(rng) * (found as f64) < 1.0 {
                        chosen = Some(start);
                    }
                }
            }
        }
        let mut out = Sampled::none();
        out.distinct = found;
        if let Some(start) = chosen {
            out.solves = 1;
            if let Some(e) = self.solve_exit(x, Aim::Along(c), start, &Bounces::first(bounces))
                && (e.direction - start).length() < SAME_PATH
            {
                out.iterations = e.iterations;
                out.path = Some((e, found as f64));
            }
        }
        Some(out)
    }

    /// Whether the straight ray from `x` along unit `start` inside the (box) volume, reflected
    /// off its surface `bounces` times, leaves through a face of outward normal `normal` along
    /// `w`.
    fn leaves_through(
        &self,
        x: DVec3,
        start: DVec3,
        bounces: usize,
        (normal, w): (DVec3, DVec3),
    ) -> bool {
        let bounds = &self.volume.field.bounds;
        let (mut p, mut d) = (x, start);
        for bounce in 0..=bounces {
            let Some(t) = bounds.exit(p, d) else {
                return false;
            };
            p += d * t.max(0.0);
            let Some(n) = bounds.normal(p) else {
                return false;
            };
            if bounce == bounces {
                return n.dot(normal) > 0.5 && (d - w).length() < SAME_PATH;
            }
            d = reflect(d, n);
        }
        false
    }

    /// Trace from `x` along unit `w` to where the ray leaves the volume, carrying the
    /// sensitivities `(xv, vv)` from their values at the start (`∂x/∂v0`, `∂v/∂v0` from `0` and
    /// `I`), with its length, optical path and the index just inside the exit; `None` if it
    /// runs out of steps or is trapped.
    #[allow(clippy::type_complexity)]
    fn shoot_out(
        &self,
        x: DVec3,
        w: DVec3,
        (xv, vv): (DMat3, DMat3),
    ) -> Option<(Ray, DMat3, DMat3, f64, f64, f64)> {
        let field = &self.volume.field;
        if self.straight_from(x) {
            // constant n: x(σ) = x + n w σ in closed form, so the sensitivities move as
            // ∂x += ∂v σ and ∂v stays
            let n = field.n(x);
            let exit = field.bounds.exit(x, w)?.max(0.0);
            if exit > self.max_length {
                return None;
            }
            let end = Ray {
                x: x + w * exit,
                v: w * n,
            };
            return Some((end, xv + vv * (exit / n), vv, exit, n * exit, n));
        }
        let t = &self.tracer;
        let h = t.step;
        let mut s = Tangent::with(field, x, w, xv, vv);
        let (mut length, mut opl) = (0.0, 0.0);
        for _ in 0..t.max_steps {
            let mut next = s.step(field, h);
            let leaves = !field.bounds.contains(next.r.x);
            if leaves {
                next = s.step(field, t.boundary_step(s.r, h));
            }
            let chord = (next.r.x - s.r.x).length();
            length += chord;
            opl += 0.5 * (s.n + next.n) * chord;
            s = next;
            if leaves {
                return Some((s.r, s.xv, s.vv, length, opl, s.n));
            }
            if length > self.max_length {
                return None;
            }
        }
        None
    }

    /// Where the ray inside reaching the surface at `end`, with sensitivities `xv`, `vv` to the
    /// perturbations `dv0` of its start, meets it: the outward normal there, and the moves of
    /// the point where it meets the surface and of its velocity there along the perturbations —
    /// the sensitivities carried to the surface with the time's shift (paper 002, Eqs. 11–12).
    /// `None` where the ray does not run outwards.
    #[allow(clippy::type_complexity)]
    fn at_surface(
        &self,
        end: Ray,
        (xv, vv): (DMat3, DMat3),
        dv0: [DVec3; 2],
    ) -> Option<(DVec3, [DVec3; 2], [DVec3; 2])> {
        let field = &self.volume.field;
        let normal = field.bounds.normal(end.x)?;
        let v = end.v;
        let nv = normal.dot(v);
        if nv <= 0.0 {
            return None;
        }
        let force = {
            let (n, g) = field.value_grad(end.x);
            g * n
        };
        let mut dx = [DVec3::ZERO; 2];
        let mut dv = [DVec3::ZERO; 2];
        for (k, dv0) in dv0.into_iter().enumerate() {
            let (dxs, dvs) = (xv * dv0, vv * dv0);
            // the point moves along the ray as v0 changes: g(x) = 0 fixes σ* (Eq. 11)
            let dsigma = -normal.dot(dxs) / nv;
            dx[k] = dxs + v * dsigma;
            dv[k] = dvs + force * dsigma;
        }
        Some((normal, dx, dv))
    }

    /// The ray inside reaching the surface at `end` (index `n_in` just inside), with
    /// sensitivities `xv`, `vv` to the perturbations `dv0` of its start, leaves: its outgoing
    /// direction, `1 − R`, and the derivatives of the outgoing direction and of the exit point
    /// along the perturbations ([`Self::at_surface`], then the refraction's by central
    /// differences of its closed form).
    #[allow(clippy::type_complexity)]
    fn refract_out(
        &self,
        end: Ray,
        sensitivities: (DMat3, DMat3),
        dv0: [DVec3; 2],
        n_in: f64,
    ) -> Option<(DVec3, f64, [DVec3; 2], [DVec3; 2])> {
        let (normal, moved, dv) = self.at_surface(end, sensitivities, dv0)?;
        let bounds = &self.volume.field.bounds;
        let eta = n_in / self.volume.field.n_out;
        let outgoing = |d: DVec3, at: DVec3| -> Option<DVec3> {
            let nrm = bounds.normal(at)?;
            refract(d, -nrm, eta).ok()
        };
        let v = end.v;
        let d_in = v.normalize();
        let out = outgoing(d_in, end.x)?;
        let mut deriv = [DVec3::ZERO; 2];
        for k in 0..2 {
            let (dx, dv) = (moved[k], dv[k]);
            let dd = (dv - d_in * d_in.dot(dv)) / v.length();
            let plus = outgoing((d_in + dd * DIFF_STEP).normalize(), end.x + dx * DIFF_STEP)?;
            let minus = outgoing((d_in - dd * DIFF_STEP).normalize(), end.x - dx * DIFF_STEP)?;
            deriv[k] = (plus - minus) / (2.0 * DIFF_STEP);
        }
        let transmission = 1.0 - fresnel(d_in.dot(normal), eta);
        Some((out, transmission, deriv, moved))
    }

    /// The outgoing direction of the ray leaving `x` along `w` after `bounces` reflections inside
    /// the surface, where it leaves, and the derivatives of the outgoing direction and of the
    /// exit point along the two angles of `w` (`e1`, `e2` of its frame). Its `transmission` is
    /// `1 − R` of the exit times `R` of each reflection.
    #[allow(clippy::type_complexity)]
    fn exit_map(
        &self,
        x: DVec3,
        w: DVec3,
        bounces: usize,
    ) -> Option<(Exit, [DVec3; 2], [DVec3; 2])> {
        let Reflected {
            from,
            along,
            sensitivities,
            dv0,
            length,
            optical_path,
            reflectance: reflected,
        } = self.reflect_inside(x, w, bounces)?;
        let (end, xv, vv, l, o, n_in) = self.shoot_out(from, along, sensitivities)?;
        let (outgoing, transmission, deriv, moved) = self.refract_out(end, (xv, vv), dv0, n_in)?;
        Some((
            Exit {
                direction: w,
                surface: end.x,
                outgoing,
                inside_from: x,
                inside_along: w,
                before: 0.0,
                length: length + l,
                optical_path: optical_path + o,
                transmission: transmission * reflected,
                jacobian: 0.0,
                iterations: 0,
                again: Again::default(),
                between: 0.0,
            },
            deriv,
            moved,
        ))
    }

    /// The ray leaving `x` (inside) along unit `w` after `bounces` reflections inside the surface,
    /// with its sensitivities to the two angles of `w` (`e1`, `e2` of its frame) carried through
    /// them; `None` if it leaves, or is trapped, before it has reflected so often.
    fn reflect_inside(&self, x: DVec3, w: DVec3, bounces: usize) -> Option<Reflected> {
        let n_x = self.volume.field.n(x);
        let (e1, e2) = orthonormal_basis(w);
        let mut r = Reflected {
            from: x,
            along: w,
            sensitivities: (DMat3::ZERO, DMat3::IDENTITY),
            dv0: [e1 * n_x, e2 * n_x],
            length: 0.0,
            optical_path: 0.0,
            reflectance: 1.0,
        };
        for _ in 0..bounces {
            let (end, xv, vv, l, o, n_in) = self.shoot_out(r.from, r.along, r.sensitivities)?;
            let (bounce, reflectance, dx, dv) = self.reflect_in(end, (xv, vv), r.dv0, n_in)?;
            r = Reflected {
                // a start just inside, so that the index there reads as the inside's
                from: end.x + bounce * (1e-12 * (1.0 + end.x.length())),
                along: bounce,
                sensitivities: (
                    DMat3::from_cols(dx[0], dx[1], DVec3::ZERO),
                    DMat3::from_cols(dv[0], dv[1], DVec3::ZERO),
                ),
                dv0: [DVec3::X, DVec3::Y],
                length: r.length + l,
                optical_path: r.optical_path + o,
                reflectance: r.reflectance * reflectance,
            };
        }
        Some(r)
    }

    /// The stretches inside of the path leaving `x` (inside) along unit `w` that reflects
    /// `bounces` times inside the surface and runs `length` in all (a connection's): each
    /// stretch's start (just inside, after a reflection), unit direction and geometric length, to
    /// `visit`, in order. `false` if the path does not reflect so after all (it was found, so
    /// only round-off could make it), having visited the stretches before.
    pub fn stretches(
        &self,
        x: DVec3,
        w: DVec3,
        bounces: usize,
        length: f64,
        mut visit: impl FnMut(DVec3, DVec3, f64),
    ) -> bool {
        let mut previous: Option<Reflected> = None;
        for k in 0..=bounces {
            // each traced afresh from x: no storage, and reflections are few
            let Some(r) = self.reflect_inside(x, w, k) else {
                return false;
            };
            if let Some(p) = previous {
                visit(p.from, p.along, r.length - p.length);
            }
            previous = Some(r);
        }
        if let Some(p) = previous {
            visit(p.from, p.along, length - p.length);
        }
        true
    }

    /// The stationary path Newton's method reaches from the initial direction `w0` that joins
    /// `x` to `y` (both inside) after `bounces` reflections inside the surface (as
    /// [`Self::solve`] without them): the sensitivities carried through each reflection as for a
    /// path leaving the volume, the miss at the closest approach to `y` as for a path inside.
    /// Its `reflectance` is the product of the reflections' Fresnel reflectances (1 beyond the
    /// critical angle).
    pub fn solve_bounced(
        &self,
        x: DVec3,
        y: DVec3,
        w0: DVec3,
        bounces: usize,
    ) -> Option<Connection> {
        if bounces == 0 {
            return self.solve(x, y, w0);
        }
        let field = &self.volume.field;
        let mut w = w0.normalize();
        let mut last = None;
        let mut polished = false;
        for iteration in 0..self.max_iterations {
            let traced = self.reflect_inside(x, w, bounces).and_then(|r| {
                let (xv, vv) = r.sensitivities;
                let s = Tangent::with(field, r.from, r.along, xv, vv);
                self.approach(s, y).map(|a| (r, a))
            });
            let Some((
                r,
                Approach {
                    end,
                    xv,
                    length,
                    optical_path,
                    beyond,
                },
            )) = traced
            else {
                w = step_back(last?, w)?;
                continue;
            };
            last = Some(w);
            let miss = Miss::across(end.v.normalize(), end.x - y, r.dv0.map(|dv| xv * dv));
            if self.converged(miss.size(), self.tolerance, &mut polished) {
                let det = miss.det();
                return (det.abs() > 0.0 && det.is_finite() && !beyond).then_some(Connection {
                    direction: w,
                    arrival: end,
                    length: r.length + length,
                    optical_path: r.optical_path + optical_path,
                    spread: det.abs(),
                    reflectance: r.reflectance,
                    iterations: iteration + 1,
                });
            }
            w = miss.turn(w)?;
        }
        None
    }

    /// A path from `x` to `y` (both inside) after `bounces` reflections inside the surface, drawn
    /// like [`Connector::sample`] (`first_only`: [`Connector::sample_first`]); without
    /// reflections it is one of those. Newton starts from uniform directions: a reflected path
    /// leaves in any direction. None in an index-matched volume, where nothing reflects.
    pub fn sample_bounced(
        &self,
        x: DVec3,
        y: DVec3,
        bounces: usize,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled {
        match (bounces, first_only) {
            (0, false) => return self.sample(x, y, rng),
            (0, true) => return self.sample_first(x, y, rng),
            _ if self.matched => return Sampled::none(),
            _ => {}
        }
        let solve = |w| {
            self.solve_bounced(x, y, w, bounces)
                .map(|c| (c, c.direction, c.iterations))
        };
        let start = |rng: &mut Rng| uniform_sphere(uniform(rng), uniform(rng));
        self.draw(first_only, start, solve, rng)
    }

    /// Whether `x` and `y` (both inside) lie in two of several volumes.
    pub fn apart(&self, x: DVec3, y: DVec3) -> bool {
        let parts = self.volume.field.bounds.parts();
        parts.is_some_and(|parts| part_at(parts, x) != part_at(parts, y))
    }

    /// Which of several volumes holds `x` (or is nearest); 0 for a volume of one part.
    pub fn part_of(&self, x: DVec3) -> usize {
        self.volume
            .field
            .bounds
            .parts()
            .map_or(0, |parts| part_at(parts, x))
    }

    /// Whether the part holding `x` is not convex (a signed-distance shape), so that two points
    /// in it may also be joined by a path that leaves it and comes back.
    pub fn around(&self, x: DVec3) -> bool {
        self.not_convex(self.part_of(x))
    }

    /// Whether the volume is several parts, its index unmatched somewhere: a path out of one
    /// part may come back into it, off another's outside or reflected inside it.
    pub fn beside_others(&self) -> bool {
        !self.matched
            && self
                .volume
                .field
                .bounds
                .parts()
                .is_some_and(|p| p.len() > 1)
    }

    /// Whether a path out of the part holding `x` and into the one holding `y` can exist as
    /// `bounces` drew it: between two parts, or out of a shape that is not convex and back; out
    /// of a convex part and back only by reflections after leaving it.
    fn joins_out_and_in(&self, x: DVec3, y: DVec3, bounces: &Bounces) -> bool {
        self.apart(x, y) || self.around(x) || bounces.after > 0
    }

    /// Whether part `k` ([`Self::part_of`]) is not convex.
    pub fn not_convex(&self, k: usize) -> bool {
        match self.volume.field.bounds.parts() {
            Some(parts) => !parts[k].shape.is_convex(),
            None => !self.volume.field.bounds.is_convex(),
        }
    }

    /// Between two points in one part that is not convex, the chance of drawing a path that
    /// leaves it and comes back rather than one within it. The straight line between them says
    /// which is likelier; through a constant index it settles it where it can: a straight path
    /// within exists only if the line stays inside, and an index-matched part has no other.
    fn around_chance(&self, x: DVec3, y: DVec3) -> f64 {
        let d = y - x;
        let s = d.length();
        if s == 0.0 {
            return 0.0;
        }
        let bounds = &self.volume.field.bounds;
        let leaves = bounds.exit(x, d / s).is_none_or(|e| e < s);
        match (leaves, self.straight_from(x)) {
            (true, true) => 1.0,
            (false, true) if self.matched => 0.0,
            (true, false) => AROUND_LIKELY,
            (false, _) => 1.0 - AROUND_LIKELY,
        }
    }

    /// A path from `x` to `y` (both inside) after `bounces` reflections inside the surface,
    /// drawn like [`Connector::sample`]: within the part holding both
    /// ([`Connector::sample_bounced`]); where they lie in two of several volumes, out of the one
    /// and into the other ([`Connector::sample_into`]), the reflections split at random: the
    /// first part's one of the `bounces + 1` numbers alike (the inverse probability times
    /// `bounces + 1`), the rest among the parts crossed and the other as [`Bounces::draw`]
    /// splits them (with `mirrors`, as [`Bounces::draw_with_mirrors`]: also off the outside of
    /// the parts met on the way): an unbiased estimate of the sum over the ways. In a part that
    /// is not convex a path may also leave it and come back ([`Connector::solve_into`]): one of
    /// the two kinds is drawn (`Self::around_chance`), its inverse probability divided by the
    /// kind's chance. So may one in a convex part beside others, with a reflection to spend
    /// after leaving (inside another part or, with `mirrors`, off its outside;
    /// `RETURN_CHANCE`); without `mirrors` (bidirectional tracing's joins, the same paths from
    /// either end) only one that reflects after it comes back fewer times than in all.
    pub fn sample_inside(
        &self,
        x: DVec3,
        y: DVec3,
        (bounces, mirrors): (usize, bool),
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<InsidePath> {
        let within = |rng: &mut Rng| {
            self.sample_bounced(x, y, bounces, first_only, rng)
                .map(|c| InsidePath::Within(c, bounces))
        };
        let apart = self.apart(x, y);
        let around = self.around(x);
        // out of a convex part and back: only by a reflection after leaving it
        let returns = !apart && !around && bounces > 0 && self.beside_others();
        if !apart && !around && !returns {
            return within(rng);
        }
        let chance = match (apart, returns) {
            (true, _) => 1.0,
            (false, true) => RETURN_CHANCE,
            (false, false) => self.around_chance(x, y),
        };
        if chance < 1.0 && (chance == 0.0 || uniform(rng) >= chance) {
            let mut s = within(rng);
            if let Some((_, inverse_p)) = &mut s.path {
                *inverse_p /= 1.0 - chance;
            }
            return s;
        }
        // the reflections inside the start's part before it leaves: 0 … bounces alike (one fewer
        // for a path back into a convex part, which must keep one for after)
        let ways = bounces + usize::from(!returns);
        let first = ((uniform(rng) * ways as f64) as usize).min(ways - 1);
        let mut split = match mirrors {
            true => Bounces::draw_with_mirrors(first, bounces - first, rng),
            false => Bounces::draw(first, bounces - first, rng),
        };
        // bidirectional tracing's joins (without `mirrors`) cross a stretch of the end's part on
        // the way only between two points in it (run the other way, that is the start's part)
        if self.not_convex(self.part_of(y)) && (mirrors || !apart) {
            split.draw_passes(rng);
        }
        let mut s = self.sample_into(x, y, &split, first_only, rng);
        if returns && !mirrors {
            // bidirectional tracing's, the same paths from either end: run the other way, the
            // reflections inside the part after it comes back are those before it leaves
            s.path = s
                .path
                .filter(|(e, _)| split.left_after(e.again.crossed()) < bounces);
        }
        if let Some((_, inverse_p)) = &mut s.path {
            *inverse_p *= ways as f64 / chance;
        }
        s.map(|e| InsidePath::Between(e, split))
    }

    /// The ray inside reaching the surface at `end` (index `n_in` just inside), with
    /// sensitivities `xv`, `vv` to the perturbations `dv0` of its start, reflects: its unit
    /// direction after, the Fresnel reflectance `R` (1 beyond the critical angle), and the
    /// derivatives of the reflection point and of the velocity after it along the perturbations
    /// ([`Self::at_surface`], then the mirror's by central differences: the normal turns).
    #[allow(clippy::type_complexity)]
    fn reflect_in(
        &self,
        end: Ray,
        sensitivities: (DMat3, DMat3),
        dv0: [DVec3; 2],
        n_in: f64,
    ) -> Option<(DVec3, f64, [DVec3; 2], [DVec3; 2])> {
        let (normal, dx, mut dv) = self.at_surface(end, sensitivities, dv0)?;
        let bounds = &self.volume.field.bounds;
        let mirror = |v: DVec3, at: DVec3| -> Option<DVec3> {
            let nrm = bounds.normal(at)?;
            Some(v - nrm * (2.0 * v.dot(nrm)))
        };
        let v = end.v;
        for k in 0..2 {
            let plus = mirror(v + dv[k] * DIFF_STEP, end.x + dx[k] * DIFF_STEP)?;
            let minus = mirror(v - dv[k] * DIFF_STEP, end.x - dx[k] * DIFF_STEP)?;
            dv[k] = (plus - minus) / (2.0 * DIFF_STEP);
        }
        let r = fresnel(normal.dot(v) / v.length(), n_in / self.volume.field.n_out);
        Some((mirror(v, end.x)?.normalize(), r, dx, dv))
    }

    /// Where the straight ray from `y` outside the volume along unit `w` meets its surface from
    /// outside ([`Meet`]); `None` if it misses the volume.
    fn meet(&self, y: DVec3, w: DVec3) -> Option<Meet> {
        let bounds = &self.volume.field.bounds;
        let (t0, _) = bounds.interval(y, w)?;
        if t0 <= 0.0 {
            return None;
        }
        let at = y + w * t0;
        let normal = bounds.normal(at)?;
        let cos = normal.dot(w);
        if cos >= 0.0 {
            return None;
        }
        let (e1, e2) = orthonormal_basis(w);
        // the point slides along the surface: its move along w's turn, less the part along w
        // that leaves the tangent plane
        let slide = [e1, e2].map(|e| (e - w * (normal.dot(e) / cos)) * t0);
        Some(Meet {
            t0,
            at,
            frame: [e1, e2],
            slide,
        })
    }

    /// As [`Self::exit_map`] for the ray from `y` outside the volume: straight to the volume,
    /// refracted in (the entry point sliding along the surface as `w` turns, the refraction's
    /// derivative by central differences of its closed form), across (reflected `reflections`
    /// times inside the part it meets first, each stretch after the first one of the parts
    /// entered again), refracted out; that part counts as the first crossed. `None` if it
    /// misses the volume, is reflected totally or trapped, or runs more than [`MAX_AGAIN`]
    /// stretches after the first.
    #[allow(clippy::type_complexity)]
    fn across_map(
        &self,
        y: DVec3,
        w: DVec3,
        (reflections, mirrored): (usize, bool),
    ) -> Option<(Exit, [DVec3; 2], [DVec3; 2])> {
        let Meet {
            t0,
            at,
            frame,
            slide,
            ..
        } = self.meet(y, w)?;
        if mirrored {
            // off the outside of the first part met: the path of [`Self::mirror_map`]
            return None;
        }
        let c = self.cross(
            (y + w * entry_parameter(t0), at, w),
            frame,
            slide,
            reflections,
        )?;
        let (first, after) = c.stretches.parts().split_first()?;
        let mut exit = Exit {
            direction: w,
            surface: c.end,
            outgoing: c.outgoing,
            inside_from: first.inside,
            inside_along: first.along,
            before: t0,
            length: first.length,
            optical_path: self.volume.field.n_out * t0 + first.optical_path,
            transmission: c.transmission,
            jacobian: 0.0,
            iterations: 0,
            again: Again {
                crossed: 1,
                ..Again::default()
            },
            between: 0.0,
        };
        for &stretch in after {
            if !exit.enter(stretch) {
                return None;
            }
        }
        Some((exit, c.turn, c.moved))
    }

    /// As [`Self::exit_map`] for the ray from `y` outside the volume that reflects off its
    /// surface there (a mirror image in the volume): the reflection point sliding along the
    /// surface as `w` turns, the mirror's derivative by central differences (the normal turns).
    /// Its `transmission` is the Fresnel reflectance from outside, and it runs nothing inside.
    /// `None` if it misses the volume, or nothing reflects where it meets it (`n` matched there).
    #[allow(clippy::type_complexity)]
    fn mirror_map(&self, y: DVec3, w: DVec3) -> Option<(Exit, [DVec3; 2], [DVec3; 2])> {
        let field = &self.volume.field;
        let Meet {
            t0,
            at,
            frame,
            slide: dx,
            ..
        } = self.meet(y, w)?;
        let inside = y + w * entry_parameter(t0);
        let (outgoing, reflectance, dout) = self.off_outside((inside, at, w), frame, dx)?;
        Some((
            Exit {
                direction: w,
                surface: at,
                outgoing,
                inside_from: at,
                inside_along: outgoing,
                before: t0,
                length: 0.0,
                optical_path: field.n_out * t0,
                transmission: reflectance,
                jacobian: 0.0,
                iterations: 0,
                again: Again::default(),
                between: 0.0,
            },
            dout,
            dx,
        ))
    }

    /// The straight ray along unit `w` entering the volume at `at` (`inside`: a point just past
    /// it) refracted in, across (reflected `bounces` times inside the surface, each stretch one
    /// of [`MAX_AGAIN`] at most) and refracted out, with the derivatives along two perturbations
    /// of the ray — `turn` of its direction and `slide` of the entry point along the surface —
    /// carried through: the refraction in by central differences of its closed form (`v = n d`:
    /// `|v|` follows `n` along the slide), the crossing by the forward sensitivities, the exit
    /// as [`Self::refract_out`]. `None` if it is reflected totally or trapped.
    fn cross(
        &self,
        (inside, at, w): (DVec3, DVec3, DVec3),
        turn: [DVec3; 2],
        slide: [DVec3; 2],
        bounces: usize,
    ) -> Option<Crossing> {
        let (along, sensitivities, entered) = self.refract_in(inside, at, w, turn, slide)?;
        let mut stretches = Again::default();
        let mut start = (inside, along, sensitivities);
        let mut transmission = entered;
        for _ in 0..bounces {
            let (stretch, next, reflectance) = self.bounce(start)?;
            if !stretches.push(stretch) {
                return None;
            }
            transmission *= reflectance;
            start = next;
        }
        let (from, along, sensitivities) = start;
        let (end, xv, vv, length, optical_path, n_end) =
            self.shoot_out(from, along, sensitivities)?;
        let last = Reentry {
            inside: from,
            along,
            length,
            optical_path,
        };
        if !stretches.push(last) {
            return None;
        }
        let (outgoing, out, turn, moved) =
            self.refract_out(end, (xv, vv), [DVec3::X, DVec3::Y], n_end)?;
        Some(Crossing {
            stretches,
            end: end.x,
            outgoing,
            transmission: transmission * out,
            turn,
            moved,
        })
    }

    /// The ray inside from `start` (a point, unit direction, and the sensitivities `(∂x, ∂v)`
    /// there along two perturbations, columns `x` and `y`) to the surface, where it reflects: the
    /// stretch, the next start (just inside the reflection point, the sensitivities carried
    /// through it, [`Self::reflect_in`]) and the Fresnel reflectance. `None` if it is trapped.
    fn bounce(&self, (from, along, sensitivities): Start) -> Option<(Reentry, Start, f64)> {
        let (end, xv, vv, length, optical_path, n_in) =
            self.shoot_out(from, along, sensitivities)?;
        let (bounce, reflectance, dx, dv) =
            self.reflect_in(end, (xv, vv), [DVec3::X, DVec3::Y], n_in)?;
        let stretch = Reentry {
            inside: from,
            along,
            length,
            optical_path,
        };
        let next = (
            // a start just inside, so that the index there reads as the inside's
            end.x + bounce * (1e-12 * (1.0 + end.x.length())),
            bounce,
            (
                DMat3::from_cols(dx[0], dx[1], DVec3::ZERO),
                DMat3::from_cols(dv[0], dv[1], DVec3::ZERO),
            ),
        );
        Some((stretch, next, reflectance))
    }

    /// The straight ray along unit `w` entering the volume at `at` (`inside`: a point just past
    /// it), refracted in: its unit direction inside, the sensitivities `(∂x, ∂v)` there along
    /// the two perturbations of the ray — `turn` of its direction and `slide` of the entry point
    /// along the surface (columns; the refraction's by central differences of its closed form,
    /// `v = n d`: `|v|` follows `n` along the slide) — and `1 − R` of the entry. `None` if it is
    /// reflected totally.
    #[allow(clippy::type_complexity)]
    fn refract_in(
        &self,
        inside: DVec3,
        at: DVec3,
        w: DVec3,
        turn: [DVec3; 2],
        slide: [DVec3; 2],
    ) -> Option<(DVec3, (DMat3, DMat3), f64)> {
        let field = &self.volume.field;
        let (n_in, grad) = field.value_grad(inside);
        let eta = field.n_out / n_in;
        let inward = |d: DVec3, at: DVec3| -> Option<DVec3> {
            let nrm = field.bounds.normal(at)?;
            refract(d, nrm, eta).ok()
        };
        let along = inward(w, at)?;
        let mut dv = [DVec3::ZERO; 2];
        for k in 0..2 {
            let (dw, dx) = (turn[k] * DIFF_STEP, slide[k] * DIFF_STEP);
            let plus = inward((w + dw).normalize(), at + dx)?;
            let minus = inward((w - dw).normalize(), at - dx)?;
            dv[k] = (plus - minus) * (n_in / (2.0 * DIFF_STEP)) + along * grad.dot(slide[k]);
        }
        let sensitivities = (
            DMat3::from_cols(slide[0], slide[1], DVec3::ZERO),
            DMat3::from_cols(dv[0], dv[1], DVec3::ZERO),
        );
        let cos = field.bounds.normal(at)?.dot(w);
        Some((along, sensitivities, 1.0 - fresnel(cos, eta)))
    }

    /// A path that has left the volume (its exit, and the derivatives of its outgoing direction
    /// and exit point along the two angles of its start) followed through every part of a
    /// non-convex volume it enters again before it has run `until` outside: straight to the
    /// part (the entry point sliding along the surface as the exit point moves and the direction
    /// turns), refracted in, across (reflected inside as `bounces` says), refracted out — the
    /// derivatives chained through each, the refractions' by central differences of their closed
    /// forms. `None` if it is reflected totally, trapped, blocked by a surface between the
    /// parts, or runs more than [`MAX_AGAIN`] stretches inside parts entered again.
    #[allow(clippy::type_complexity)]
    fn onwards(
        &self,
        left: Option<(Exit, [DVec3; 2], [DVec3; 2])>,
        until: impl Fn(&Exit) -> f64,
        bounces: &Bounces,
    ) -> Option<(Exit, [DVec3; 2], [DVec3; 2])> {
        let (mut exit, mut dout, mut moved) = left?;
        loop {
            let Some(t0) = self
                .volume
                .field
                .bounds
                .reentry(exit.surface, exit.outgoing)
            else {
                return Some((exit, dout, moved));
            };
            // beyond the point the path ends at, only a part it reflects inside brings it back
            if t0 >= until(&exit) && bounces.across(exit.again.crossed) == 0 {
                exit.again.declined = true;
                return Some((exit, dout, moved));
            }
            (dout, moved) = self.cross_again(&mut exit, (dout, moved), t0, bounces)?;
        }
    }

    /// The path that has left the volume (`exit`, with the derivatives `(dout, moved)` of its
    /// outgoing direction and exit point along the two angles of its start) meets a part of it
    /// `t0` ahead: where it enters (just past the surface), the entry point itself, and how it
    /// slides along the surface along the two angles. `None` if a surface outside blocks the way,
    /// or the path only grazes the part.
    fn meet_again(
        &self,
        exit: &Exit,
        (dout, moved): ([DVec3; 2], [DVec3; 2]),
        t0: f64,
    ) -> Option<(DVec3, DVec3, [DVec3; 2])> {
        let o = exit.outgoing;
        if self
            .surfaces
            .iter()
            .any(|s| s.hit(exit.surface, o).is_some_and(|t| t < t0))
        {
            return None;
        }
        let at = exit.surface + o * t0;
        let normal = self.volume.field.bounds.normal(at)?;
        let cos = normal.dot(o);
        if cos >= 0.0 {
            return None;
        }
        let slide = [0, 1].map(|k| {
            let d = moved[k] + dout[k] * t0;
            d - o * (normal.dot(d) / cos)
        });
        Some((exit.surface + o * entry_parameter(t0), at, slide))
    }

    /// The path that has left the volume (as [`Self::meet_again`]) crosses the part it meets
    /// `t0` ahead: `exit` extended across it (refracted in and out, reflected inside as often as
    /// `bounces` says for the parts crossed so far), and the derivatives of its new outgoing
    /// direction and exit point. `None` if it is blocked, reflected totally, trapped, or runs
    /// more than [`MAX_AGAIN`] stretches inside parts entered again.
    fn cross_again(
        &self,
        exit: &mut Exit,
        derivatives: ([DVec3; 2], [DVec3; 2]),
        t0: f64,
        bounces: &Bounces,
    ) -> Option<([DVec3; 2], [DVec3; 2])> {
        let (inside, at, slide) = self.meet_again(exit, derivatives, t0)?;
        if bounces.mirrored(exit.again.crossed) {
            return self.mirror_again(exit, derivatives.0, (inside, at, slide), t0);
        }
        let reflections = bounces.across(exit.again.crossed);
        let c = self.cross(
            (inside, at, exit.outgoing),
            derivatives.0,
            slide,
            reflections,
        )?;
        for &stretch in c.stretches.parts() {
            if !exit.enter(stretch) {
                return None;
            }
        }
        exit.again.crossed += 1;
        exit.between += t0;
        exit.optical_path += self.volume.field.n_out * t0;
        exit.transmission *= c.transmission;
        exit.surface = c.end;
        exit.outgoing = c.outgoing;
        Some((c.turn, c.moved))
    }

    /// The path that has left the volume (as [`Self::cross_again`]) reflects off the outside of
    /// the part it meets `t0` ahead, at `at` (`inside`: a point just past it; `slide`: how it
    /// moves along the surface along the two angles of the path's start): `exit` extended to
    /// it and turned by the law of reflection ([`Self::off_outside`]), its `transmission` times
    /// the Fresnel reflectance from outside, and the derivatives of the new outgoing direction
    /// and of the reflection point. The reflection counts as a part crossed (its draw). `None`
    /// where nothing reflects there.
    fn mirror_again(
        &self,
        exit: &mut Exit,
        dout: [DVec3; 2],
        (inside, at, slide): (DVec3, DVec3, [DVec3; 2]),
        t0: f64,
    ) -> Option<([DVec3; 2], [DVec3; 2])> {
        let (outgoing, reflectance, turn) =
            self.off_outside((inside, at, exit.outgoing), dout, slide)?;
        exit.again.crossed += 1;
        exit.between += t0;
        exit.optical_path += self.volume.field.n_out * t0;
        exit.transmission *= reflectance;
        exit.surface = at;
        exit.outgoing = outgoing;
        Some((turn, slide))
    }

    /// The straight ray along unit `w` meeting the volume's surface from outside at `at`
    /// (`inside`: a point just past it) reflects there: its unit direction after, the Fresnel
    /// reflectance from outside, and that direction's derivatives along two perturbations of
    /// the ray — `turn` of `w` and `slide` of the point along the surface — by central
    /// differences of the mirror (the normal turns as the point slides). `None` where nothing
    /// reflects (`n` matched there).
    fn off_outside(
        &self,
        (inside, at, w): (DVec3, DVec3, DVec3),
        turn: [DVec3; 2],
        slide: [DVec3; 2],
    ) -> Option<(DVec3, f64, [DVec3; 2])> {
        let field = &self.volume.field;
        let cos = field.bounds.normal(at)?.dot(w);
        let reflectance = fresnel(cos, field.n_out / field.n(inside));
        if reflectance <= 0.0 {
            return None;
        }
        let mirror = |d: DVec3, at: DVec3| Some(reflect(d, field.bounds.normal(at)?));
        let mut dout = [DVec3::ZERO; 2];
        for k in 0..2 {
            let (dw, dx) = (turn[k] * DIFF_STEP, slide[k] * DIFF_STEP);
            let plus = mirror((w + dw).normalize(), at + dx)?;
            let minus = mirror((w - dw).normalize(), at - dx)?;
            dout[k] = (plus - minus) / (2.0 * DIFF_STEP);
        }
        Some((mirror(w, at)?, reflectance, dout))
    }

    /// The path Newton's method reaches from `w0` that leaves the volume and passes through the
    /// point `p` outside it (a pinhole; `target` [`Aim::Point`]), in a straight line from the
    /// surface, or runs back along a focused beam's rays ([`Aim::Focus`]: the line through its
    /// focus `p`). Its `jacobian` is the ray tube's cross-section at `p` per unit solid angle at
    /// `x` (`dA⊥/dω`): the irradiance at `p` of a source of intensity `I` at `x` is
    /// `I · transmission / jacobian`. With `bounces`, the path reflects that many times inside
    /// the surface before it leaves and inside the parts it crosses after.
    pub fn solve_through(
        &self,
        x: DVec3,
        target: Aim,
        w0: DVec3,
        bounces: &Bounces,
    ) -> Option<Exit> {
        self.aim_at(target, w0, bounces, |w| self.exit_map(x, w, bounces.first))
    }

    /// As [`Self::solve_through`] for a path from `y` outside the volume that crosses it
    /// (refracted in and out, unscattered) on its way to `p`: a surface seen, or lit, through
    /// the volume. It reflects inside the parts it crosses as `bounces` says, the first it meets
    /// the first crossed (`bounces.first` is not used).
    pub fn solve_across(&self, y: DVec3, p: DVec3, w0: DVec3, bounces: &Bounces) -> Option<Exit> {
        let map = |w| self.across_map(y, w, (bounces.across(0), bounces.mirrored(0)));
        self.aim_at(Aim::Point(p), w0, bounces, map)
    }

    /// As [`Self::solve_across`] for a path from `y` outside the volume that reflects off its
    /// surface on its way to `p`: a surface seen, or lit, in the volume's mirror image.
    pub fn solve_mirror(&self, y: DVec3, p: DVec3, w0: DVec3) -> Option<Exit> {
        self.aim_at(Aim::Point(p), w0, &Bounces::default(), |w| {
            self.mirror_map(y, w)
        })
    }

    /// The ray from `x` (inside one of several volumes) along unit `w`, after `bounces.first`
    /// reflections inside the surface, out of its volume and across every other it meets (each
    /// refracted in and out, reflected inside as `bounces` drew, or off its outside where drawn
    /// so) until it meets the part `into`:
    /// refracted into it, reflected inside its surface as often as the budget has left, and
    /// traced to its closest approach to `y`. Returns
    /// the path as an [`Exit`] ending there (`surface`: the point of closest approach,
    /// `outgoing`: the unit direction of arrival; each stretch in `into` one of the parts
    /// entered again), the miss perpendicular to the arrival, and the miss's derivatives along
    /// the two angles of `w` (`e1`, `e2` of its frame) as a 2×2 matrix; or, if it leaves the last
    /// volume it meets without meeting `into`, where it does so, with the derivatives of its
    /// outgoing direction and of that point along the two angles. `None` if it is reflected
    /// totally, trapped or blocked, or enters `into` and passes `y` by.
    fn map_into(
        &self,
        (x, w): (DVec3, DVec3),
        (y, into): (DVec3, usize),
        bounces: &Bounces,
    ) -> Option<Toward> {
        let field = &self.volume.field;
        let from = self.part_of(x);
        let (mut exit, mut dout, mut moved) = self.exit_map(x, w, bounces.first)?;
        let t0 = loop {
            let Some(t0) = field.bounds.reentry(exit.surface, exit.outgoing) else {
                return Some(Toward::Missed(exit, dout, moved));
            };
            match self.part_of(exit.surface + exit.outgoing * entry_parameter(t0)) {
                // a part drawn to be reflected off is, whichever it is
                _ if bounces.mirrored(exit.again.crossed) => {}
                part if part == into => {
                    let crossed = exit.again.crossed;
                    if !bounces.passes(crossed) {
                        exit.again.entered = true;
                        break t0;
                    }
                    exit.again.passed |= 1 << crossed;
                }
                // bidirectional tracing's connections, the same path from either end, enter each
                // of their two parts once; tracing's cross the start's part again
                part if part == from && !bounces.mirrors => return None,
                _ => {}
            }
            (dout, moved) = self.cross_again(&mut exit, (dout, moved), t0, bounces)?;
        };
        let (inside, at, slide) = self.meet_again(&exit, (dout, moved), t0)?;
        let (along, sensitivities, entered) =
            self.refract_in(inside, at, exit.outgoing, dout, slide)?;
        exit.between += t0;
        exit.optical_path += field.n_out * t0;
        exit.transmission *= entered;
        // the stretches inside `into`, each from its start with the sensitivities there
        let mut stretch = (inside, along, sensitivities);
        for _ in 0..bounces.left_after(exit.again.crossed) {
            let (s, next, reflectance) = self.bounce(stretch)?;
            if !exit.enter(s) {
                return None;
            }
            exit.transmission *= reflectance;
            stretch = next;
        }
        let (from, along, (xv, vv)) = stretch;
        let Approach {
            end,
            xv,
            length,
            optical_path,
            beyond: false,
        } = self.approach(Tangent::with(field, from, along, xv, vv), y)?
        else {
            return None;
        };
        let last = Reentry {
            inside: from,
            along,
            length,
            optical_path,
        };
        if !exit.enter(last) {
            return None;
        }
        exit.surface = end.x;
        exit.outgoing = end.v.normalize();
        let miss = Miss::across(exit.outgoing, end.x - y, [xv * DVec3::X, xv * DVec3::Y]);
        Some(Toward::Reached(exit, miss))
    }

    /// The path Newton's method reaches from `w0` that joins `x` inside one of several volumes
    /// to `y` inside another: out of the first after `bounces.first` reflections inside its
    /// surface, across every volume it meets between them (refracted in and out, reflected inside
    /// as `bounces` drew), into the second and, after the reflections left inside its surface, on
    /// to `y` (`Self::map_into`); for
    /// `x` and `y` in one part, out of it and back into it where the path first meets it again
    /// (into a convex part only off another part's outside or reflected inside one, as
    /// `bounces` drew). Its `jacobian` is the ray tube's cross-section at `y` per unit
    /// solid angle at `x`, `dA⊥/dω` (the irradiance at `y` of a source of intensity `I` at `x`
    /// is `I · transmission / jacobian`); `surface` is `y` (within the tolerance) and
    /// `outgoing` the direction of arrival there. `None` for points in one convex part that
    /// `bounces` leaves no reflection after leaving it.
    pub fn solve_into(&self, x: DVec3, y: DVec3, w0: DVec3, bounces: &Bounces) -> Option<Exit> {
        let into = self.part_of(y);
        if !self.joins_out_and_in(x, y, bounces) {
            return None;
        }
        let mut w = w0.normalize();
        let mut last = None;
        let mut polished = false;
        // whether a ray has entered `y`'s volume yet: until then, one that leaves past it is
        // steered towards `y`; after, one that goes astray steps back
        let mut reached = false;
        let mut steers = 0;
        for iteration in 0..self.max_iterations {
            let (exit, miss) = match self.map_into((x, w), (y, into), bounces) {
                Some(Toward::Reached(exit, miss)) => (exit, miss),
                Some(Toward::Missed(exit, dout, dsurf)) if !reached => {
                    // leaving past the volume `y` is in: turn towards `y` by the angle between
                    // (`dg` follows the point it leaves from) until the path meets it; a
                    // path that cannot (out of a convex stretch of a part and back into it)
                    // is given up once the turns would have gone half round
                    steers += 1;
                    if steers > MAX_STEERS {
                        return None;
                    }
                    last = Some(w);
                    let to_y = y - exit.surface;
                    let distance = to_y.length();
                    let g = to_y / distance;
                    let dg = dsurf.map(|ds| -(ds - g * g.dot(ds)) / distance);
                    w = steer(w, exit.outgoing, g, dout, dg)?;
                    continue;
                }
                _ => {
                    w = step_back(last?, w)?;
                    continue;
                }
            };
            last = Some(w);
            reached = true;
            if self.converged(miss.size(), self.tolerance, &mut polished) {
                return miss.solved(exit, iteration);
            }
            w = miss.turn(w)?;
        }
        None
    }

    /// A path from `x` inside one of several volumes to `y` inside another
    /// ([`Self::solve_into`]), reflected inside the first, the parts it crosses and the second
    /// as `bounces` says, drawn as [`Connector::sample_exit`] (`first_only`: the biased variant);
    /// through index-matched volumes the straight line. Also between two points in one part,
    /// out of it and back in; none for points in one convex part that `bounces` leaves no
    /// reflection after leaving it.
    pub fn sample_into(
        &self,
        x: DVec3,
        y: DVec3,
        bounces: &Bounces,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        if !self.joins_out_and_in(x, y, bounces) {
            return Sampled::none();
        }
        if self.matched {
            let (from, into) = (self.part_of(x), self.part_of(y));
            // as `map_into`: into each of its two parts once, at its end (tracing's connections,
            // the one straight line, across any part on the way)
            let once = |e: &Exit| {
                if bounces.mirrors {
                    return e.again.parts().last().map(|p| self.part_of(p.inside)) == Some(into);
                }
                let entered = e.again.parts().iter().map(|p| self.part_of(p.inside));
                let last = e.again.parts().len().saturating_sub(1);
                entered
                    .enumerate()
                    .all(|(k, part)| (k == last) == (part == into) && (part != from || k == last))
            };
            let mut s = match bounces.first + bounces.after {
                0 => self.straight_to(x, y),
                _ => Sampled::none(),
            };
            s.path = s.path.filter(|(e, _)| once(e));
            return s;
        }
        let start = |rng: &mut Rng| self.initial(x, y, rng);
        let solve = |w| {
            self.solve_into(x, y, w, bounces)
                .map(|e| (e, e.direction, e.iterations))
        };
        self.draw_crossing(first_only, start, solve, bounces, rng)
    }

    /// Newton's method on the direction `w` given to `map` (from `w0`) for the path that passes
    /// through the point of `target` after leaving the volume (or whose line passes through a
    /// focused beam's focus, leaving against the beam: [`Aim::Focus`]).
    fn aim_at(
        &self,
        target: Aim,
        w0: DVec3,
        bounces: &Bounces,
        map: impl Fn(DVec3) -> Option<(Exit, [DVec3; 2], [DVec3; 2])>,
    ) -> Option<Exit> {
        let p = match target {
            Aim::Point(p) | Aim::Focus { focus: p, .. } => p,
            Aim::Along(_) | Aim::Back { .. } => return None,
        };
        let mut w = w0.normalize();
        // the last direction the map took, to step back towards when a step leaves its domain
        let mut last = None;
        let mut polished = false;
        // the path ends at p (or the beam's disc): a part of the volume beyond it is not entered
        let until = |e: &Exit| target.reach(e.surface, e.outgoing);
        for iteration in 0..self.max_iterations {
            let Some((mut exit, dout, dsurf)) = self.onwards(map(w), until, bounces) else {
                w = step_back(last?, w)?;
                continue;
            };
            last = Some(w);
            let o = exit.outgoing;
            let to_p = p - exit.surface;
            let distance = to_p.length();
            // towards p; back along a focused beam, away from a focus behind the exit
            let g = target.toward(exit.surface);
            if o.dot(g) < STEER {
                // leaving far from the wanted direction (even away from it): turn towards it by
                // the angle between them; `dg` follows the exit point's move
                let sign = g.dot(to_p).signum();
                let dg = dsurf.map(|ds| -(ds - g * g.dot(ds)) * (sign / distance));
                w = steer(w, o, g, dout, dg)?;
                continue;
            }
            // (negative for a focus behind the exit: the line's extension passes through it)
            let t = to_p.dot(o);
            // the line's displacement at p: the exit point's plus the turn of its direction
            let moved = [0, 1].map(|k| dsurf[k] + dout[k] * t);
            let miss = Miss::across(o, exit.surface + o * t - p, moved);
            if self.converged(miss.size(), self.tolerance, &mut polished) {
                exit.optical_path += self.volume.field.n_out * target.reach(exit.surface, o);
                return miss.solved(exit, iteration);
            }
            w = miss.turn(w)?;
        }
        None
    }

    /// A path from `x` through the point outside of `target` (or back along a focused beam's
    /// rays, [`Aim::Focus`]) after `bounces` reflections inside the surface (and inside the
    /// parts it crosses after), drawn as [`Connector::sample_exit`].
    pub fn sample_through(
        &self,
        x: DVec3,
        target: Aim,
        bounces: &Bounces,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        if self.matched {
            return match (bounces.first, target) {
                (0, Aim::Point(p)) => self.straight_to(x, p),
                (0, Aim::Focus { focus, .. }) => self.straight_from_focus(x, focus, target),
                _ => Sampled::none(),
            };
        }
        // Newton starts near the straight line the target asks for
        let ahead = target.toward(x);
        let near = match self.volume.field.start_cone(x) {
            Some(_) if bounces.first == 0 => NEAR_GENTLE,
            _ => NEAR,
        };
        let start = |rng: &mut Rng| self.initial_along(ahead, near, rng);
        let solve = |w| {
            self.solve_through(x, target, w, bounces)
                .map(|e| (e, e.direction, e.iterations))
        };
        self.draw_crossing(first_only, start, solve, bounces, rng)
    }

    /// The straight path from `x` inside an index-matched volume back along the ray of a beam
    /// aimed at `focus` (`target`): its `jacobian` the spread `|x − f|²` at the focus, its
    /// optical path to the beam's disc.
    fn straight_from_focus(&self, x: DVec3, focus: DVec3, target: Aim) -> Sampled<Exit> {
        let w = target.toward(x);
        let mut s = self.straight_exit(x, w, None, target.reach(x, w));
        if let Some((e, _)) = &mut s.path {
            e.jacobian = (x - focus).length_squared();
            e.optical_path += self.volume.field.n_out * target.reach(e.surface, w);
        }
        s
    }

    /// A path from `y` outside the volume across it (refracted in and out, unscattered; reflected
    /// inside the parts it crosses as `bounces` drew, [`Self::solve_across`]) to the point `p`
    /// outside, or leaving it along the unit direction `c`, drawn like [`Connector::sample`].
    /// None through an index-matched volume, which a straight line crosses.
    pub fn sample_across(
        &self,
        y: DVec3,
        target: Aim,
        bounces: &Bounces,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        // most paths across leave near the straight line
        let near = target.toward(y);
        let map = |w| self.across_map(y, w, (bounces.across(0), bounces.mirrored(0)));
        self.sample_outside(y, target, (near, 0.5), bounces, first_only, rng, map)
    }

    /// A path from `y` outside the volume reflected off its surface (outside it) to the point
    /// `p`, or along the unit direction `c`, drawn like [`Connector::sample`]. None off an
    /// index-matched volume, which reflects nothing.
    pub fn sample_mirror(
        &self,
        y: DVec3,
        target: Aim,
        first_only: bool,
        rng: &mut Rng,
    ) -> Sampled<Exit> {
        // a convex surface reflects where its normal bisects the directions to both ends: near
        // the bounding box's point along that bisector, seen from the box's centre
        let Some(half) = self.volume.field.bounds.half_extent() else {
            return Sampled::none();
        };
        let bisector = match target {
            Aim::Point(p) => y.normalize_or_zero() + p.normalize_or_zero(),
            _ => y.normalize_or_zero() + target.toward(y),
        };
        let to_near = half * bisector.normalize_or_zero() - y;
        // jittered by a fraction of the box's angular size
        let jitter = (0.25 * half.length() / to_near.length()).min(0.5);
        self.sample_outside(
            y,
            target,
            (to_near.normalize(), jitter),
            &Bounces::default(),
            first_only,
            rng,
            |w| self.mirror_map(y, w),
        )
    }

    /// A path from `y` outside the volume that `map` follows, to the point or along the
    /// direction of `target`: Newton starts half the time near the unit direction `near` (a
    /// uniform direction times `jitter` added), half the time towards a uniform point of the
    /// volume's bounding box. The path reflects inside the parts it crosses as `bounces` drew.
    #[allow(clippy::too_many_arguments)]
    fn sample_outside(
        &self,
        y: DVec3,
        target: Aim,
        (near, jitter): (DVec3, f64),
        bounces: &Bounces,
        first_only: bool,
        rng: &mut Rng,
        map: impl Fn(DVec3) -> Option<(Exit, [DVec3; 2], [DVec3; 2])>,
    ) -> Sampled<Exit> {
        let none = Sampled::none();
        let Some(half) = self.volume.field.bounds.half_extent() else {
            return none;
        };
        if self.matched {
            return none;
        }
        let start = |rng: &mut Rng| {
            if uniform(rng) < 0.5 {
                let u = uniform_sphere(uniform(rng), uniform(rng));
                (near + u * jitter).normalize()
            } else {
                let corner = DVec3::new(uniform(rng), uniform(rng), uniform(rng));
                (half * (corner * 2.0 - 1.0) - y).normalize()
            }
        };
        let solve = |w| {
            match target {
                Aim::Along(_) | Aim::Back { .. } => self.aim_along(target, w, bounces, &map),
                _ => self.aim_at(target, w, bounces, &map),
            }
            .map(|e| (e, e.direction, e.iterations))
        };
        self.draw_crossing(first_only, start, solve, bounces, rng)
    }

    /// The path Newton's method reaches from `w0` that leaves the volume along the unit
    /// direction of `target` ([`Aim::Along`], or [`Aim::Back`]: then crossing no part beyond the
    /// beam's disc). With `bounces`, the path reflects that many times inside the surface before
    /// it leaves and inside the parts it crosses after.
    pub fn solve_exit(&self, x: DVec3, target: Aim, w0: DVec3, bounces: &Bounces) -> Option<Exit> {
        self.aim_along(target, w0, bounces, |w| self.exit_map(x, w, bounces.first))
    }

    /// Newton's method on the direction `w` given to `map` (from `w0`) for the path that leaves
    /// the volume along the unit direction of `target` ([`Aim::Along`] or [`Aim::Back`]).
    fn aim_along(
        &self,
        target: Aim,
        w0: DVec3,
        bounces: &Bounces,
        map: impl Fn(DVec3) -> Option<(Exit, [DVec3; 2], [DVec3; 2])>,
    ) -> Option<Exit> {
        let c = match target {
            Aim::Along(c) | Aim::Back { back: c, .. } => c,
            _ => return None,
        };
        let mut w = w0.normalize();
        let mut last = None;
        let mut polished = false;
        // a path back along a beam ends at its disc: a part beyond it is not entered
        let until = |e: &Exit| target.reach(e.surface, e.outgoing);
        for iteration in 0..self.max_iterations {
            let Some((exit, [d1, d2], _)) = self.onwards(map(w), until, bounces) else {
                w = step_back(last?, w)?;
                continue;
            };
            last = Some(w);
            let out = exit.outgoing;
            if out.dot(c) < STEER {
                // leaving far from the camera's direction (even against it): turn towards it
                w = steer(w, out, c, [d1, d2], [DVec3::ZERO; 2])?;
                continue;
            }
            // the outgoing direction's components across `c`
            let miss = Miss::across(c, out, [d1, d2]);
            if out.dot(c) > 0.0 && self.converged(miss.size(), 1e-10, &mut polished) {
                return miss.solved(exit, iteration);
            }
            w = miss.turn(w)?;
        }
        None
    }
}

/// Where a path from one of several volumes towards a point in another goes
/// ([`Connector::map_into`]).
enum Toward {
    /// Into the other volume, to its closest approach to the point: the path, the miss
    /// perpendicular to its arrival, and the miss's derivatives along the two angles of its start.
    Reached(Exit, Miss),
    /// Out of the last volume it met, past the other: the path so far, and the derivatives of
    /// its outgoing direction and of the point where it left.
    Missed(Exit, [DVec3; 2], [DVec3; 2]),
}

/// A ray inside the volume where it starts a stretch: the point, its unit direction, and the
/// sensitivities `(∂x, ∂v)` there along two perturbations (columns `x` and `y`).
type Start = (DVec3, DVec3, (DMat3, DMat3));

/// A ray across the volume from outside ([`Connector::cross`]).
struct Crossing {
    /// Its stretches inside: from just past the entry, then from each reflection inside.
    stretches: Again,
    /// Where it leaves, and its direction after refraction there.
    end: DVec3,
    outgoing: DVec3,
    /// `(1 − R)` of the entry and the exit times the reflectance `R` of each reflection inside.
    transmission: f64,
    /// The derivatives of the outgoing direction and of the exit point along the perturbations.
    turn: [DVec3; 2],
    moved: [DVec3; 2],
}

/// Where a straight ray from outside meets the volume's surface ([`Connector::meet`]).
struct Meet {
    /// The distance to it, and the point.
    t0: f64,
    at: DVec3,
    /// The two angles of the ray's direction (`e1`, `e2` of its frame), and how the point slides
    /// along the surface as the direction turns along each.
    frame: [DVec3; 2],
    slide: [DVec3; 2],
}

/// A ray inside after reflections inside the surface ([`Connector::reflect_inside`]).
struct Reflected {
    /// Where it starts after the last reflection (just inside), and its unit direction there.
    from: DVec3,
    along: DVec3,
    /// `∂x`, `∂v` along the perturbations `dv0` of its first start (columns).
    sensitivities: (DMat3, DMat3),
    dv0: [DVec3; 2],
    /// Geometric length and optical path up to `from`, and the product of the reflectances.
    length: f64,
    optical_path: f64,
    reflectance: f64,
}

/// Where a path through the volume's surface goes once it has left it.
#[derive(Clone, Copy, Debug)]
pub enum Aim {
    /// Through a point (a pinhole, a point light, a point of a surface).
    Point(DVec3),
    /// Along a unit direction (an orthographic camera's).
    Along(DVec3),
    /// Back along a collimated beam: along unit `back` (against the beam), to the plane of its
    /// disc through `disc` (normal to `back`).
    Back { back: DVec3, disc: DVec3 },
    /// Back along the rays of a beam aimed at `focus`: along the line through the focus,
    /// against the beam's unit `direction`, to the plane of its disc through `disc` (normal to
    /// `direction`). The focus may lie behind where the path leaves, inside the volume, as the
    /// point the rays would meet without it.
    Focus {
        focus: DVec3,
        disc: DVec3,
        direction: DVec3,
    },
}

impl Aim {
    /// The unit direction the path is to take from `y`: towards the point, along the
    /// direction, or along the line through the focus against the beam.
    pub fn toward(&self, y: DVec3) -> DVec3 {
        match *self {
            Aim::Point(p) => (p - y).normalize(),
            Aim::Along(c) | Aim::Back { back: c, .. } => c,
            Aim::Focus {
                focus, direction, ..
            } => {
                let v = (focus - y).normalize();
                if v.dot(direction) <= 0.0 { v } else { -v }
            }
        }
    }

    /// How far the path leaving the volume at `y` along unit `o` runs to its end: to the point
    /// (along `o`), to the beam's disc's plane; unbounded along a camera's direction.
    pub fn reach(&self, y: DVec3, o: DVec3) -> f64 {
        match *self {
            Aim::Point(p) => (p - y).dot(o),
            Aim::Along(_) => f64::INFINITY,
            Aim::Back { back, disc } => (disc - y).dot(back) / o.dot(back),
            Aim::Focus {
                disc, direction, ..
            } => (disc - y).dot(direction) / o.dot(direction),
        }
    }
}

/// Step of the central differences of the refractions' closed forms.
const DIFF_STEP: f64 = 1e-6;

/// Below this cosine between the outgoing direction and the one wanted, exit and through
/// connections steer by the angle instead of the miss (which is undefined or points the wrong way
/// once the ray leaves away from its target).
const STEER: f64 = 0.5;

/// Turns towards the far point a connection into a volume takes at most before it is given up:
/// enough to turn it half round by [`MAX_TURN`] a step.
const MAX_STEERS: usize = 12;

/// One Newton step on the direction `w` turning the outgoing direction `o` (derivatives `dout`
/// along `w`'s two angles) towards the target direction `g` (derivatives `dg`): on the
/// stereographic residual `P_g o / (1 + o·g)` in a frame fixed at `g`, which is zero at `o = g`
/// and grows without bound towards `o = −g`, so the step never settles on the wrong side.
fn steer(w: DVec3, o: DVec3, g: DVec3, dout: [DVec3; 2], dg: [DVec3; 2]) -> Option<DVec3> {
    let (e1, e2) = orthonormal_basis(g);
    let u = 1.0 + o.dot(g);
    if u <= 1e-12 {
        // exactly opposite: any turn helps; the frame's first axis will do
        return Some((w + orthonormal_basis(w).0 * MAX_TURN).normalize());
    }
    let r = [e1.dot(o) / u, e2.dot(o) / u];
    let mut m = [[0.0; 2]; 2];
    for k in 0..2 {
        let du = dout[k].dot(g) + o.dot(dg[k]);
        for (i, e) in [e1, e2].into_iter().enumerate() {
            m[i][k] = e.dot(dout[k]) / u - e.dot(o) * du / (u * u);
        }
    }
    Miss { r, m }.turn(w)
}

/// Half a Newton step back from `w`, where the map failed (the ray missed the volume or left it
/// the wrong way), towards `last`, where it held; `None` once the step is negligible.
fn step_back(last: DVec3, w: DVec3) -> Option<DVec3> {
    let half = (last + w).normalize();
    ((half - last).length() >= 1e-3 * MAX_TURN).then_some(half)
}

/// The 2×2 system Newton's method solves on a direction `w`: a residual `r` across the path
/// (a miss at the far point, or the outgoing direction across the one wanted) and its
/// derivatives `m` along the two angles of `w`'s frame.
#[derive(Clone, Copy, Debug)]
struct Miss {
    r: [f64; 2],
    m: [[f64; 2]; 2],
}

impl Miss {
    /// The components of `d` across the unit direction `t` and of its derivatives `c`.
    fn across(t: DVec3, d: DVec3, c: [DVec3; 2]) -> Self {
        let (f1, f2) = orthonormal_basis(t);
        Miss {
            r: [f1.dot(d), f2.dot(d)],
            m: [[f1.dot(c[0]), f1.dot(c[1])], [f2.dot(c[0]), f2.dot(c[1])]],
        }
    }

    fn size(&self) -> f64 {
        (self.r[0] * self.r[0] + self.r[1] * self.r[1]).sqrt()
    }

    fn det(&self) -> f64 {
        let m = &self.m;
        m[0][0] * m[1][1] - m[0][1] * m[1][0]
    }

    /// The path `exit` solved at Newton's `iteration`: its `jacobian` the determinant's size
    /// (`dA⊥/dω` or `dω_out/dω`); `None` where that is zero or not finite.
    fn solved(&self, mut exit: Exit, iteration: usize) -> Option<Exit> {
        let det = self.det().abs();
        exit.jacobian = det;
        exit.iterations = iteration + 1;
        (det > 0.0 && det.is_finite()).then_some(exit)
    }

    /// One Newton step on `w` for `m δ = −r`, at most [`MAX_TURN`] long; `None` if `m` is
    /// singular.
    fn turn(&self, w: DVec3) -> Option<DVec3> {
        let (m, r, det) = (&self.m, self.r, self.det());
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let (e1, e2) = orthonormal_basis(w);
        let mut da = -(m[1][1] * r[0] - m[0][1] * r[1]) / det;
        let mut db = -(-m[1][0] * r[0] + m[0][0] * r[1]) / det;
        let turn = (da * da + db * db).sqrt();
        if turn > MAX_TURN {
            (da, db) = (da * MAX_TURN / turn, db * MAX_TURN / turn);
        }
        Some((w + e1 * da + e2 * db).normalize())
    }
}

/// The path found from one random start, counted once.
fn first<T>(
    start: impl Fn(&mut Rng) -> DVec3,
    solve: impl Fn(DVec3) -> Option<(T, DVec3, usize)>,
    rng: &mut Rng,
) -> Sampled<T> {
    let found = solve(start(rng));
    Sampled {
        iterations: found.as_ref().map_or(0, |f| f.2),
        path: found.map(|f| (f.0, 1.0)),
        solves: 1,
        distinct: 1,
    }
}

/// Alg. 3: a path found from a random start, and the number of restarts until the same path
/// (same initial direction) is found again — an unbiased estimate of its inverse probability.
fn restarts<T>(
    max_restarts: usize,
    start: impl Fn(&mut Rng) -> DVec3,
    solve: impl Fn(DVec3) -> Option<(T, DVec3, usize)>,
    rng: &mut Rng,
) -> Sampled<T> {
    let mut out = Sampled {
        path: None,
        solves: 1,
        iterations: 0,
        distinct: 0,
    };
    let Some((c, dir, its)) = solve(start(rng)) else {
        return out;
    };
    out.iterations += its;
    // distinct paths met, without allocating (past the array's size they are no longer told apart)
    let mut seen = [DVec3::ZERO; MAX_DISTINCT];
    seen[0] = dir;
    let mut distinct = 1;
    let mut count = 1.0;
    for _ in 0..max_restarts {
        out.solves += 1;
        match solve(start(rng)) {
            Some((_, again, its)) if (again - dir).length() < SAME_PATH => {
                out.iterations += its;
                break;
            }
            Some((_, other, its)) => {
                out.iterations += its;
                if distinct < MAX_DISTINCT
                    && !seen[..distinct]
                        .iter()
                        .any(|s| (*s - other).length() < SAME_PATH)
                {
                    seen[distinct] = other;
                    distinct += 1;
                }
            }
            None => {}
        }
        count += 1.0;
    }
    out.distinct = distinct;
    out.path = Some((c, count));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eikonal::{BoundedField, Bounds, Profile};
    use crate::medium::{PhaseFunction, Scattering};

    /// A clear box of half extents `half` in air, its index `n0 + g·x`.
    fn graded_box(n0: f64, gradient: DVec3, half: DVec3) -> Volume {
        volume(Profile::Linear { n0, gradient }, Bounds::Box { half }, 1.0)
    }

    fn volume(profile: Profile, bounds: Bounds, n_out: f64) -> Volume {
        Volume {
            field: BoundedField::single(profile, bounds, n_out),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        }
    }

    #[test]
    fn a_connection_through_a_luneburg_lens_is_the_closed_form_ellipse() {
        // n² = 2 − r²: in the σ-form x(σ) = x0 cos σ + v0 sin σ, so the path from x0 to y has
        // v0 = (y − x0 cos σ)/sin σ with |v0|² = 2 − |x0|², cos σ the positive root of
        // 2u² − 2(x0·y)u + |x0|² + |y|² − 2 = 0
        let v = volume(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let (x0, y) = (DVec3::new(0.3, -0.2, 0.1), DVec3::new(-0.1, 0.4, 0.35));
        let (a, b, p) = (y.length_squared(), x0.length_squared(), x0.dot(y));
        let u = (2.0 * p + (4.0 * p * p - 8.0 * (a + b - 2.0)).sqrt()) / 4.0;
        let sigma = u.acos();
        let v0 = (y - x0 * u) / sigma.sin();
        assert!((v0.length_squared() - (2.0 - b)).abs() < 1e-12);
        let found = c.solve(x0, y, (y - x0).normalize()).expect("converges");
        assert!(
            (found.direction - v0.normalize()).length() < 1e-5,
            "{} vs {}",
            found.direction,
            v0.normalize()
        );
        assert!((found.arrival.x - y).length() <= c.tolerance * 1.0001);
        // Hamilton's equations hold along it: |v| = n at the end (the leapfrog's invariant)
        let n_y = (2.0 - y.length_squared()).sqrt();
        assert!((found.arrival.v.length() - n_y).abs() < 1e-6);
        // the spread: x(σ) = x0 cos σ + v0 sin σ, ∂x/∂v0 = sin σ I, so dA⊥/dω = (n(x0) sin σ)²
        // times the cosine factor of the projection (σ* moves with v0 along the ray only)
        let n0 = (2.0 - b).sqrt();
        let t = found.arrival.v.normalize();
        let w = found.direction;
        let (e1, e2) = orthonormal_basis(w);
        let (f1, f2) = orthonormal_basis(t);
        let k = n0 * sigma.sin();
        let m = [
            [f1.dot(e1) * k, f1.dot(e2) * k],
            [f2.dot(e1) * k, f2.dot(e2) * k],
        ];
        let expected = (m[0][0] * m[1][1] - m[0][1] * m[1][0]).abs();
        assert!(
            (found.spread - expected).abs() < 1e-4 * expected,
            "{} vs {expected}",
            found.spread
        );
    }

    /// In a scene of several volumes, paths in a glass block beside a graded ball run straight
    /// in the block in closed form, and agree with the same paths stepped through it (the
    /// block's index written as a flat linear profile, which is stepped): within the block, out
    /// of it along a direction, and out of the graded ball across the block to a point beyond.
    #[test]
    fn paths_in_a_constant_volume_beside_a_graded_one_run_straight() {
        use crate::eikonal::Part;
        use crate::rrte::Bulk;
        let clear = || Bulk {
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        // a graded ball (n from 1.3 at the centre to 1.2 at the surface) and a glass block on
        // its right
        let lens = Part::new(
            Bounds::Sphere { radius: 1.0 },
            DVec3::ZERO,
            vec![Profile::SphericalPolynomial {
                n0: 1.3,
                coefficients: vec![0.0, -0.1],
            }],
        );
        let centre = DVec3::new(2.2, 0.0, 0.0);
        let scene = |glass: Profile| {
            let half = DVec3::new(0.5, 0.8, 0.8);
            let block = Part::new(Bounds::Box { half }, centre, vec![glass]);
            Volume::several(vec![(lens.clone(), clear()), (block, clear())], 1.0)
        };
        let closed = scene(Profile::Constant { n: 1.5 });
        let stepped = scene(Profile::Linear {
            n0: 1.5,
            gradient: DVec3::ZERO,
        });
        let (a, b) = (
            Connector::new(&closed, 1e-3, 100_000),
            Connector::new(&stepped, 1e-3, 100_000),
        );
        let close = |what: &str, u: f64, v: f64| {
            assert!(
                (u - v).abs() <= 1e-6 * v.abs().max(1.0),
                "{what}: {u} vs {v}"
            );
        };
        // within the block
        let (x, y) = (
            centre + DVec3::new(-0.3, 0.3, 0.1),
            centre + DVec3::new(0.4, -0.2, 0.3),
        );
        let w0 = (y - x).normalize();
        let (p, q) = (a.solve(x, y, w0).unwrap(), b.solve(x, y, w0).unwrap());
        assert_eq!(p.iterations, 0);
        assert!(q.iterations > 0);
        close("length", p.length, q.length);
        close("optical path", p.optical_path, q.optical_path);
        close("spread", p.spread, q.spread);
        assert!((p.direction - q.direction).length() < 1e-6);
        // no path inside from the block to a point in the other volume
        let other = DVec3::new(0.5, 0.1, 0.0);
        let towards = (other - x).normalize();
        assert!(a.solve(x, other, towards).is_none() && b.solve(x, other, towards).is_none());
        let exits = |e: &Exit, f: &Exit| {
            assert!((e.direction - f.direction).length() < 1e-6);
            assert!((e.surface - f.surface).length() < 1e-6);
            close("length", e.length, f.length);
            close("optical path", e.optical_path, f.optical_path);
            close("transmission", e.transmission, f.transmission);
            close("jacobian", e.jacobian, f.jacobian);
        };
        // out of the block along a direction, refracted at its surface
        let c = DVec3::new(0.3, 1.0, 0.2).normalize();
        exits(
            &a.solve_exit(x, Aim::Along(c), c, &Bounces::first(0))
                .unwrap(),
            &b.solve_exit(x, Aim::Along(c), c, &Bounces::first(0))
                .unwrap(),
        );
        // out of the graded ball, across the block and on to a point beyond it
        let (x, p) = (DVec3::new(0.2, 0.1, -0.1), DVec3::new(4.5, 0.4, 0.2));
        let w0 = (p - x).normalize();
        let (e, f) = (
            a.solve_through(x, Aim::Point(p), w0, &Bounces::first(0))
                .unwrap(),
            b.solve_through(x, Aim::Point(p), w0, &Bounces::first(0))
                .unwrap(),
        );
        assert_eq!(e.again.parts().len(), 1);
        exits(&e, &f);
    }

    /// Between two glass balls (constant `n` everywhere), no straight path joins a point in one
    /// to a point in the other through the air between; within one ball, the straight line does.
    #[test]
    fn straight_paths_stay_in_their_volume() {
        use crate::eikonal::Part;
        use crate::rrte::Bulk;
        let ball = |x: f64| {
            let part = Part::new(
                Bounds::Sphere { radius: 1.0 },
                DVec3::new(x, 0.0, 0.0),
                vec![Profile::Constant { n: 1.5 }],
            );
            let bulk = Bulk {
                sigma_s: 1.0,
                sigma_a: 0.0,
                scattering: Scattering::single(PhaseFunction::Isotropic),
            };
            (part, bulk)
        };
        let v = Volume::several(vec![ball(-1.5), ball(1.5)], 1.0);
        let c = Connector::new(&v, 1e-2, 1000);
        let mut rng = crate::math::stream_rng(1, 0);
        let (x, y) = (DVec3::new(-1.2, 0.1, 0.0), DVec3::new(1.3, -0.2, 0.1));
        assert!(c.solve(x, y, (y - x).normalize()).is_none());
        assert!(c.sample(x, y, &mut rng).path.is_none());
        let z = DVec3::new(-1.8, 0.4, 0.2);
        let (found, inverse_p) = c.sample(x, z, &mut rng).path.unwrap();
        assert_eq!(inverse_p, 1.0);
        assert!((found.length - (z - x).length()).abs() < 1e-12);
    }

    #[test]
    fn a_straight_connection_spreads_as_the_distance_squared() {
        let v = volume(
            Profile::Linear {
                n0: 1.4,
                gradient: DVec3::ZERO,
            },
            Bounds::Sphere { radius: 2.0 },
            1.0,
        );
        let c = Connector::new(&v, 1e-2, 100_000);
        let (x, y) = (DVec3::new(0.5, 0.1, -0.3), DVec3::new(-0.4, 0.2, 0.9));
        // a poor start, 50° off the line
        let start = ((y - x).normalize() + DVec3::X).normalize();
        let found = c.solve(x, y, start).expect("converges from a poor start");
        let s = (y - x).length();
        assert!(
            (found.spread - s * s).abs() < 1e-9 * s * s,
            "{}",
            found.spread
        );
        assert!((found.length - s).abs() < 1e-9);
        assert!((found.optical_path - 1.4 * s).abs() < 1e-9);
    }

    /// Clear glass balls `(centre, radius, n)` in air as several volumes, each of constant index
    /// in closed form, or `graded`: stepped through a linear profile of zero gradient.
    fn clear_balls(balls: &[(DVec3, f64, f64)], graded: bool) -> Volume {
        use crate::eikonal::Part;
        use crate::rrte::Bulk;
        let parts = balls.iter().map(|&(c, r, n)| {
            let profile = if graded {
                Profile::Linear {
                    n0: n,
                    gradient: DVec3::ZERO,
                }
            } else {
                Profile::Constant { n }
            };
            let clear = Bulk {
                sigma_s: 0.0,
                sigma_a: 0.0,
                scattering: Scattering::single(PhaseFunction::Isotropic),
            };
            (
                Part::new(Bounds::Sphere { radius: r }, c, vec![profile]),
                clear,
            )
        });
        Volume::several(parts.collect(), 1.0)
    }

    /// Snell's law by hand: `d` refracted at a surface with unit normal `n` facing it, `eta`
    /// the ratio of the indices before and after.
    fn snell(d: DVec3, n: DVec3, eta: f64) -> DVec3 {
        let cos_i = -n.dot(d);
        let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
        d * eta + n * (eta * cos_i - k.sqrt())
    }

    /// The unpolarised Fresnel reflectance by hand, for the cosines of incidence and refraction.
    fn reflectance(cos_i: f64, cos_t: f64, eta: f64) -> f64 {
        let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
        let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
        0.5 * (rs * rs + rp * rp)
    }

    /// By hand, the ray inside a ball `(centre, radius, n)` from `a` on its surface along unit
    /// `inside` to the surface, reflected there: the reflection point, the reflected direction, the
    /// chord's length and the Fresnel reflectance (1 beyond the critical angle).
    fn bounce_in_ball(
        (c, r, n): (DVec3, f64, f64),
        a: DVec3,
        inside: DVec3,
    ) -> (DVec3, DVec3, f64, f64) {
        let t = -2.0 * (a - c).dot(inside);
        let e = a + inside * t;
        let nrm = (e - c) / r;
        let cos_i = nrm.dot(inside);
        let sin_t2 = n * n * (1.0 - cos_i * cos_i);
        let reflected = if sin_t2 >= 1.0 {
            1.0
        } else {
            reflectance(cos_i, (1.0 - sin_t2).sqrt(), n)
        };
        (e, inside - nrm * (2.0 * cos_i), t, reflected)
    }

    /// Assert that the path `found` to the point `p` is the one `hand` traces from its direction
    /// (exit point, outgoing direction, length inside, transmission), that it passes through
    /// `p`, and that its ray tube's cross-section at `p` equals that of neighbouring rays traced
    /// by hand (central differences on the plane through `p` across the outgoing ray).
    fn traced_by_hand(found: &Exit, p: DVec3, hand: impl Fn(DVec3) -> (DVec3, DVec3, f64, f64)) {
        let (e, o, length, transmission) = hand(found.direction);
        assert!((found.surface - e).length() < 1e-9, "{found:?}");
        assert!((found.outgoing - o.normalize()).length() < 1e-9);
        assert!((found.length - length).abs() < 1e-9);
        assert!((found.transmission - transmission).abs() < 1e-12);
        let miss = (p - e) - o * (p - e).dot(o);
        assert!(miss.length() < 1e-8, "{miss}");
        let (e1, e2) = orthonormal_basis(found.direction);
        let (f1, f2) = orthonormal_basis(o);
        let h = 1e-6;
        let at_plane = |w: DVec3| {
            let (e, o, _, _) = hand(w.normalize());
            e + o * (p - e).dot(found.outgoing) / o.dot(found.outgoing)
        };
        let d1 =
            (at_plane(found.direction + e1 * h) - at_plane(found.direction - e1 * h)) / (2.0 * h);
        let d2 =
            (at_plane(found.direction + e2 * h) - at_plane(found.direction - e2 * h)) / (2.0 * h);
        let det = f1.dot(d1) * f2.dot(d2) - f1.dot(d2) * f2.dot(d1);
        assert!(
            (found.jacobian - det.abs()).abs() < 1e-6 * det.abs(),
            "{} vs {}",
            found.jacobian,
            det.abs()
        );
    }

    /// `check` on a glass ball (n = 1.5 in air, radius 1) in closed form and stepped (a linear
    /// profile of zero gradient), each with its connector.
    fn on_glass_balls(check: impl Fn(&Connector)) {
        for profile in [
            Profile::Constant { n: 1.5 },
            Profile::Linear {
                n0: 1.5,
                gradient: DVec3::ZERO,
            },
        ] {
            let v = volume(profile, Bounds::Sphere { radius: 1.0 }, 1.0);
            check(&Connector::new(&v, 1e-3, 100_000));
        }
    }

    /// Across a glass ball (n = 1.5 in air), in closed form and stepped: the path found from a
    /// point on one side to a point on the other, from a poor start, refracts by Snell's law
    /// where it enters and leaves and passes through the point; its transmission is the two
    /// Fresnel transmissions, and its ray tube's cross-section at the point per solid angle at
    /// the start equals that of neighbouring rays traced by hand (sphere intersections and
    /// Snell's law, the spread by central differences).
    #[test]
    fn a_path_across_a_glass_ball_refracts_twice_and_spreads_as_traced_by_hand() {
        let (y, p) = (DVec3::new(0.3, -0.2, -2.5), DVec3::new(-0.4, 0.5, 3.0));
        let hand = |w: DVec3| {
            let b = y.dot(w);
            let t0 = -b - (b * b - (y.length_squared() - 1.0)).sqrt();
            let a = y + w * t0;
            let d = snell(w, a, 1.0 / 1.5);
            let t1 = -2.0 * a.dot(d);
            let e = a + d * t1;
            let o = snell(d, -e, 1.5);
            let transmission = (1.0 - reflectance(-a.dot(w), -a.dot(d), 1.0 / 1.5))
                * (1.0 - reflectance(e.dot(d), e.dot(o), 1.5));
            (e, o, t1, transmission)
        };
        on_glass_balls(|c| {
            let start = ((p - y).normalize() + DVec3::X * 0.3).normalize();
            let found = c
                .solve_across(y, p, start, &Bounces::default())
                .expect("converges");
            traced_by_hand(&found, p, hand);
        });
    }

    /// Across a glass ball (n = 1.5 in air) reflected once inside it (a rainbow's path), in
    /// closed form and stepped: each path Newton finds from random starts between two points
    /// outside on the same side of the ball refracts in by Snell's law, reflects off the far side
    /// by the law of reflection, refracts out, passes through the point, carries the Fresnel
    /// factors of all three meetings, runs its two stretches inside the ball (the second as one
    /// after the first), and spreads as neighbouring rays traced by hand do. Unreflected, no
    /// such path exists.
    #[test]
    fn a_path_across_a_glass_ball_reflected_inside_it_spreads_as_traced_by_hand() {
        let (y, p) = (DVec3::new(0.3, -0.2, -2.5), DVec3::new(-0.3, 0.4, -2.8));
        let hand = |w: DVec3| {
            let b = y.dot(w);
            let t0 = -b - (b * b - (y.length_squared() - 1.0)).sqrt();
            let a = y + w * t0;
            let d = snell(w, a, 1.0 / 1.5);
            let (e, r, t1, reflected) = bounce_in_ball((DVec3::ZERO, 1.0, 1.5), a, d);
            let t2 = -2.0 * e.dot(r);
            let f = e + r * t2;
            let o = snell(r, -f, 1.5);
            let transmission = (1.0 - reflectance(-a.dot(w), -a.dot(d), 1.0 / 1.5))
                * reflected
                * (1.0 - reflectance(f.dot(r), f.dot(o), 1.5));
            (f, o, t1 + t2, transmission)
        };
        on_glass_balls(|c| {
            let mut rng = crate::math::stream_rng(5, 0);
            let start = |rng: &mut Rng| {
                let u = crate::math::uniform_sphere(uniform(rng), uniform(rng));
                (-y.normalize() + u * 0.4).normalize()
            };
            let reflected = Bounces::with(0, [1, 0, 0, 0], 0);
            let found: Vec<Exit> = (0..200)
                .filter_map(|_| c.solve_across(y, p, start(&mut rng), &reflected))
                .collect();
            assert!(found.len() >= 5, "{} of 200 starts converge", found.len());
            for f in &found {
                assert_eq!((f.again.crossed(), f.again.parts().len()), (1, 1));
                traced_by_hand(f, p, hand);
            }
            let unreflected = (0..200)
                .filter_map(|_| c.solve_across(y, p, start(&mut rng), &Bounces::default()))
                .count();
            assert_eq!(unreflected, 0);
        });
    }

    /// From inside a glass ball (n = 1.5 in air), in closed form and stepped: the path to a
    /// point outside that first reflects once inside the surface obeys the law of reflection
    /// there and Snell's law where it leaves, passes through the point, carries `R (1 − R)` of
    /// the two Fresnel formulas, and spreads as neighbouring rays traced by hand do.
    #[test]
    fn a_path_reflected_inside_a_glass_ball_spreads_as_traced_by_hand() {
        let (x, p) = (DVec3::new(0.2, -0.3, 0.1), DVec3::new(2.0, 2.5, -1.0));
        let hand = |w: DVec3| {
            let b = x.dot(w);
            let t0 = -b + (b * b - (x.length_squared() - 1.0)).sqrt();
            let a = x + w * t0;
            let d = w - a * (2.0 * w.dot(a));
            let t1 = -2.0 * a.dot(d);
            let e = a + d * t1;
            let o = snell(d, -e, 1.5);
            let cos_t = |cos_i: f64| (1.0 - 1.5 * 1.5 * (1.0 - cos_i * cos_i)).sqrt();
            let r = if 1.5 * 1.5 * (1.0 - a.dot(w).powi(2)) >= 1.0 {
                1.0
            } else {
                reflectance(a.dot(w), cos_t(a.dot(w)), 1.5)
            };
            (
                e,
                o,
                t0 + t1,
                r * (1.0 - reflectance(e.dot(d), e.dot(o), 1.5)),
            )
        };
        on_glass_balls(|c| {
            let mut rng = crate::math::stream_rng(3, 0);
            let found = (0..200)
                .find_map(|_| {
                    c.solve_through(
                        x,
                        Aim::Point(p),
                        c.initial(x, p, &mut rng),
                        &Bounces::first(1),
                    )
                })
                .expect("some start converges");
            traced_by_hand(&found, p, hand);
        });
    }

    /// Off a glass ball (n = 1.5 in air), in closed form and stepped: the path found between two
    /// points outside, from a poor start, reflects off the ball's outside by the law of
    /// reflection, passes through the point, carries the Fresnel reflectance from outside, and
    /// spreads as neighbouring rays traced by hand do (a convex mirror: wider than the straight
    /// line's `s²`). A convex ball has one such path, and Alg. 3 finds only it.
    #[test]
    fn a_path_mirrored_off_a_glass_ball_spreads_as_traced_by_hand() {
        let (y, p) = (DVec3::new(0.3, -2.2, 0.4), DVec3::new(-1.8, -1.5, -0.6));
        let hand = |w: DVec3| {
            let b = y.dot(w);
            let t0 = -b - (b * b - (y.length_squared() - 1.0)).sqrt();
            let a = y + w * t0;
            let o = w - a * (2.0 * w.dot(a));
            let cos_i = -a.dot(w);
            let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (1.5 * 1.5)).sqrt();
            (a, o, 0.0, reflectance(cos_i, cos_t, 1.0 / 1.5))
        };
        on_glass_balls(|c| {
            let start = (-y.normalize() + DVec3::X * 0.1).normalize();
            let found = c.solve_mirror(y, p, start).expect("converges");
            traced_by_hand(&found, p, hand);
            let s = (found.surface - y).length() + (p - found.surface).length();
            assert!(
                found.jacobian > 1.2 * s * s,
                "{} vs {}",
                found.jacobian,
                s * s
            );
            // Alg. 3's inverse probabilities (0 where the first start fails) average to the
            // one path's count, 1
            let mut rng = crate::math::stream_rng(5, 0);
            let draws = 4000;
            let (mut sum, mut sum2, mut found_first) = (0.0, 0.0, 0);
            for _ in 0..draws {
                let drawn = c.sample_mirror(y, Aim::Point(p), false, &mut rng);
                let Some((e, inverse_p)) = drawn.path else {
                    continue;
                };
                assert!((e.direction - found.direction).length() < 1e-8);
                assert_eq!(drawn.distinct, 1);
                (sum, sum2, found_first) = (
                    sum + inverse_p,
                    sum2 + inverse_p * inverse_p,
                    found_first + 1,
                );
            }
            let mean = sum / draws as f64;
            let se = ((sum2 / draws as f64 - mean * mean) / draws as f64).sqrt();
            eprintln!("found from {found_first} of {draws} starts; count {mean} ± {se}");
            assert!((mean - 1.0).abs() < 4.0 * se, "{mean} ± {se}");
        });
    }

    /// Out of one glass ball (n = 1.3) and off the outside of another (n = 1.5) beside it, in
    /// closed form and stepped: the path from a point inside the first to a point outside,
    /// drawn to reflect off the first part it meets, refracts out by Snell's law, reflects off
    /// the second ball by the law of reflection, passes through the point, carries `1 − R` of
    /// the exit times the reflectance from outside, and spreads as neighbouring rays traced by
    /// hand do. Drawn to reflect once inside that ball instead, a path enters it.
    #[test]
    fn a_path_out_of_one_ball_off_anothers_outside_spreads_as_traced_by_hand() {
        let (ca, cb) = (DVec3::ZERO, DVec3::new(2.6, 0.0, 0.0));
        let (x, p) = (DVec3::new(0.2, 0.1, -0.1), DVec3::new(0.5, 2.0, 0.3));
        let hand = |w: DVec3| {
            let b = (x - ca).dot(w);
            let t0 = -b + (b * b - ((x - ca).length_squared() - 1.0)).sqrt();
            let a = x + w * t0;
            let na = a - ca;
            let d = snell(w, -na, 1.3);
            let exit = 1.0 - reflectance(na.dot(w), na.dot(d), 1.3);
            let b = (a - cb).dot(d);
            let t1 = -b - (b * b - ((a - cb).length_squared() - 1.0)).sqrt();
            let m = a + d * t1;
            let nb = m - cb;
            let cos_i = -nb.dot(d);
            let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (1.5 * 1.5)).sqrt();
            let o = d + nb * (2.0 * cos_i);
            (m, o, t0, exit * reflectance(cos_i, cos_t, 1.0 / 1.5))
        };
        let off = Bounces {
            after: 1,
            across: [1, 0, 0, 0],
            mirrored: [true, false, false, false],
            mirrors: true,
            ..Bounces::default()
        };
        let across = Bounces {
            mirrored: [false; MAX_AGAIN],
            ..off
        };
        for graded in [false, true] {
            let v = clear_balls(&[(ca, 1.0, 1.3), (cb, 1.0, 1.5)], graded);
            let c = Connector::new(&v, 1e-3, 100_000);
            let mut rng = crate::math::stream_rng(7, 0);
            // (a start may find the straight path to the point too, meeting no part)
            let solve = |b: &Bounces, rng: &mut Rng| {
                c.solve_through(x, Aim::Point(p), c.initial(x, p, rng), b)
                    .filter(|e| e.again.crossed() > 0)
            };
            let found = (0..400)
                .find_map(|_| solve(&off, &mut rng))
                .expect("some start converges");
            assert_eq!((found.again.crossed(), found.again.parts().len()), (1, 0));
            traced_by_hand(&found, p, hand);
            // drawn to reflect inside the ball, a path enters it and is not the one off it
            let inside: Vec<Exit> = (0..400).filter_map(|_| solve(&across, &mut rng)).collect();
            assert!(!inside.is_empty(), "some start converges");
            for e in inside {
                assert!(!e.again.parts().is_empty());
                assert!((e.direction - found.direction).length() > 1e-3);
            }
        }
    }

    /// Off a face of a glass cube, a flat mirror: the path between two points outside it runs
    /// through the face's point on the line from the mirror image of the first point to the
    /// second, and spreads as a straight line from that image, `(|y − a| + |a − p|)²`; its
    /// transmission is the Fresnel reflectance at that angle.
    #[test]
    fn a_path_mirrored_off_a_glass_cube_runs_from_the_mirror_image() {
        let v = volume(
            Profile::Constant { n: 1.5 },
            Bounds::Box {
                half: DVec3::splat(1.0),
            },
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let (y, p) = (DVec3::new(0.3, -0.2, 2.5), DVec3::new(-0.6, 0.4, 1.6));
        let image = DVec3::new(y.x, y.y, 2.0 - y.z);
        let along = (p - image).normalize();
        let a = image + along * ((1.0 - image.z) / along.z);
        let found = c
            .solve_mirror(y, p, DVec3::new(0.1, 0.1, -1.0))
            .expect("converges");
        assert!((found.surface - a).length() < 1e-9, "{found:?}");
        assert!((found.outgoing - along).length() < 1e-9);
        let s = (a - y).length() + (p - a).length();
        assert!((found.jacobian - s * s).abs() < 1e-6 * s * s);
        let cos_i = along.z;
        let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (1.5 * 1.5)).sqrt();
        let r = reflectance(cos_i, cos_t, 1.0 / 1.5);
        assert!((found.transmission - r).abs() < 1e-12);
        assert!((found.optical_path - s).abs() < 1e-9);
    }

    /// Fresnel reflectance inside n = 1.5 against air at the cosine of incidence `cos_i`, 1 beyond
    /// the critical angle.
    fn inside_reflectance(cos_i: f64) -> f64 {
        let sin2_t = 1.5 * 1.5 * (1.0 - cos_i * cos_i);
        if sin2_t >= 1.0 {
            1.0
        } else {
            reflectance(cos_i, (1.0 - sin2_t).sqrt(), 1.5)
        }
    }

    /// Inside a glass cube (n = 1.5 in air, half-width 1), in closed form and stepped: the path
    /// between two points inside that reflects once off the top face runs from the first point's
    /// mirror image in that face, spreads as the straight line from the image (`|x' − y|²`), and
    /// carries the Fresnel reflectance inside (steeply: a few per cent; at a glancing angle:
    /// total). A point's image in each of the six faces gives one such path, and Alg. 3's
    /// estimate of `Σ R/spread` over them matches the images' sum.
    #[test]
    fn a_path_reflected_once_inside_a_glass_cube_runs_from_the_mirror_image() {
        for profile in [
            Profile::Constant { n: 1.5 },
            Profile::Linear {
                n0: 1.5,
                gradient: DVec3::ZERO,
            },
        ] {
            let v = volume(
                profile,
                Bounds::Box {
                    half: DVec3::splat(1.0),
                },
                1.0,
            );
            let c = Connector::new(&v, 1e-3, 100_000);
            for (x, y, total) in [
                (
                    DVec3::new(0.2, -0.1, 0.3),
                    DVec3::new(-0.4, 0.3, -0.2),
                    false,
                ),
                (DVec3::new(0.6, 0.0, 0.5), DVec3::new(-0.6, 0.1, 0.4), true),
            ] {
                let image = DVec3::new(x.x, x.y, 2.0 - x.z);
                let along = (y - image).normalize();
                let a = image + along * ((1.0 - image.z) / along.z);
                let leave = (a - x).normalize();
                let found = c
                    .solve_bounced(x, y, (leave + DVec3::X * 0.1).normalize(), 1)
                    .expect("converges");
                assert!((found.direction - leave).length() < 1e-8, "{found:?}");
                assert!((found.arrival.x - y).length() < 1e-8);
                let s = (y - image).length();
                assert!((found.length - s).abs() < 1e-8, "{} vs {s}", found.length);
                assert!((found.spread - s * s).abs() < 1e-6 * s * s);
                let r = inside_reflectance(leave.z);
                assert_eq!(r == 1.0, total);
                assert!((found.reflectance - r).abs() < 1e-12);
            }
        }
        let v = volume(
            Profile::Constant { n: 1.5 },
            Bounds::Box {
                half: DVec3::splat(1.0),
            },
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let (x, y) = (DVec3::new(0.2, -0.1, 0.3), DVec3::new(-0.4, 0.3, -0.2));
        let mut images = 0.0;
        for axis in 0..3 {
            for side in [-1.0, 1.0] {
                let mut image = x;
                image[axis] = 2.0 * side - x[axis];
                let to = y - image;
                images += inside_reflectance(to[axis].abs() / to.length()) / to.length_squared();
            }
        }
        let mut rng = crate::math::stream_rng(8, 0);
        let draws = 3000;
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..draws {
            if let Some((p, inverse_p)) = c.sample_bounced(x, y, 1, false, &mut rng).path {
                let f = p.reflectance / p.spread * inverse_p;
                (sum, sum2) = (sum + f, sum2 + f * f);
            }
        }
        let mean = sum / draws as f64;
        let se = ((sum2 / draws as f64 - mean * mean) / draws as f64).sqrt();
        assert!(
            (mean - images).abs() < 4.0 * se && se < 0.05 * images,
            "{mean} ± {se} vs {images}"
        );
    }

    /// Leaving a glass box (n = 1.5 in air, half-widths 1, 0.7, 0.5) along a direction, directly
    /// and after one or two reflections inside: the paths the closed form finds (a start per face
    /// and sign flip) are every path Newton finds from 3 000 random starts, and its draws
    /// average to their sum `Σ T/(dω_out/dω)`.
    #[test]
    fn paths_leaving_a_glass_box_along_a_direction_are_found_in_closed_form() {
        let v = volume(
            Profile::Constant { n: 1.5 },
            Bounds::Box {
                half: DVec3::new(1.0, 0.7, 0.5),
            },
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let mut rng = crate::math::stream_rng(5, 0);
        let mut counts = Vec::new();
        for (x, out) in [
            (DVec3::new(0.2, -0.1, 0.3), DVec3::new(0.3, 0.2, 1.0)),
            (DVec3::new(-0.7, 0.4, -0.1), DVec3::new(-1.0, 0.5, 0.2)),
            (DVec3::new(0.5, 0.3, 0.2), DVec3::new(0.2, 0.1, 0.3)),
        ] {
            let out = out.normalize();
            for bounces in 0..3 {
                // every path from random starts, told apart by direction
                let mut paths: Vec<Exit> = Vec::new();
                for _ in 0..3000 {
                    let w = uniform_sphere(uniform(&mut rng), uniform(&mut rng));
                    if let Some(e) = c.solve_exit(x, Aim::Along(out), w, &Bounces::first(bounces))
                        && !paths
                            .iter()
                            .any(|p| (p.direction - e.direction).length() < SAME_PATH)
                    {
                        paths.push(e);
                    }
                }
                let sum: f64 = paths.iter().map(|e| e.transmission / e.jacobian).sum();
                let draws = 2000;
                let (mut total, mut total2) = (0.0, 0.0);
                for _ in 0..draws {
                    let s = c.box_exit(x, out, bounces, &mut rng).expect("a glass box");
                    assert_eq!(s.distinct, paths.len(), "{x} {out} after {bounces}");
                    if let Some((e, inverse_p)) = s.path {
                        assert!(
                            paths
                                .iter()
                                .any(|p| (p.direction - e.direction).length() < 1e-9),
                            "{e:?}"
                        );
                        let f = e.transmission / e.jacobian * inverse_p;
                        (total, total2) = (total + f, total2 + f * f);
                    }
                }
                counts.push(paths.len());
                let mean = total / draws as f64;
                let se = ((total2 / draws as f64 - mean * mean).max(0.0) / draws as f64).sqrt();
                assert!(
                    (mean - sum).abs() <= 4.0 * se + 1e-9 * sum,
                    "{x} {out} after {bounces}: {mean} ± {se} vs {sum}"
                );
            }
        }
        // ten paths (1, 1, 2; 2, 0, 2; 2, 0, 0 by case and reflections), two at once in four
        assert_eq!(counts, [1, 1, 2, 2, 0, 2, 2, 0, 0]);
    }

    /// Three glass balls in a row (n = 1.5, 1.4 and 1.3 in air), in closed form and stepped: a
    /// path from a point in the first to a point in the third, found from the straight line's
    /// direction and from random starts, directly or after a reflection inside the third, is the
    /// one traced by hand through every ball it meets (sphere intersections, Snell's law and the
    /// law of reflection): it passes through the point, carries the Fresnel factors of every
    /// surface it meets, and its ray tube's cross-section at the point equals that of
    /// neighbouring rays traced by hand. Solved from the other end (its reflection now inside
    /// the volume it starts from), the same path comes back with the spread that reciprocity
    /// gives, `n_y² dA_y/dω_x = n_x² dA_x/dω_y` (the two-point étendue).
    #[test]
    fn a_path_between_two_volumes_crosses_a_third_and_spreads_as_traced_by_hand() {
        let balls = [
            (DVec3::ZERO, 1.0, 1.5),
            (DVec3::new(2.2, 0.1, 0.0), 0.7, 1.4),
            (DVec3::new(4.2, 0.2, -0.1), 0.9, 1.3),
        ];
        let scene = |graded: bool| clear_balls(&balls, graded);
        // the hand's trace from `x` in ball `from` along `w` to the plane through `y` across
        // `o`: where it crosses it, the unit direction there, the length inside and the
        // transmission, and the index at both ends
        let hand = |x: DVec3, from: usize, w: DVec3, y: DVec3, (to, bounces): (usize, usize)| {
            let (c, r, n) = balls[from];
            let local = x - c;
            let b = local.dot(w);
            let t = -b + (b * b - (local.length_squared() - r * r)).sqrt();
            let mut at = x + w * t;
            let mut normal = (at - c) / r;
            let mut d = snell(w, -normal, n);
            let mut length = t;
            let mut transmission = 1.0 - reflectance(normal.dot(w), normal.dot(d), n);
            loop {
                // the nearest ball ahead
                let (k, t0) = (0..3)
                    .filter_map(|k| {
                        let (c, r, _) = balls[k];
                        let local = at - c;
                        let b = local.dot(d);
                        let disc = b * b - (local.length_squared() - r * r);
                        let t0 = -b - disc.max(0.0).sqrt();
                        (disc > 0.0 && t0 > 1e-9).then_some((k, t0))
                    })
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("meets a ball");
                let (c, r, n) = balls[k];
                let a = at + d * t0;
                let nrm = (a - c) / r;
                let inside = snell(d, nrm, 1.0 / n);
                transmission *= 1.0 - reflectance(-nrm.dot(d), -nrm.dot(inside), 1.0 / n);
                if k == to {
                    let (mut a, mut inside) = (a, inside);
                    for _ in 0..bounces {
                        let (e, reflected, t1, r) = bounce_in_ball((c, r, n), a, inside);
                        transmission *= r;
                        length += t1;
                        (a, inside) = (e, reflected);
                    }
                    let reach = (y - a).dot(inside);
                    return (a + inside * reach, inside, length + reach, transmission);
                }
                let t1 = -2.0 * (a - c).dot(inside);
                let e = a + inside * t1;
                normal = (e - c) / r;
                let out = snell(inside, -normal, n);
                transmission *= 1.0 - reflectance(normal.dot(inside), normal.dot(out), n);
                length += t1;
                (at, d) = (e, out);
            }
        };
        let (x, y) = (DVec3::new(0.3, -0.2, 0.4), DVec3::new(4.4, 0.5, 0.2));
        for graded in [false, true] {
            let v = scene(graded);
            let connector = Connector::new(&v, 1e-3, 100_000);
            let mut rng = crate::math::stream_rng(5, 0);
            for bounces in [(0, 0), (0, 1)] {
                let found: Vec<Exit> = std::iter::once((y - x).normalize())
                    .chain((0..400).map(|_| connector.initial(x, y, &mut rng)))
                    .filter_map(|w| {
                        connector.solve_into(
                            x,
                            y,
                            w,
                            &Bounces::with(bounces.0, [0; MAX_AGAIN], bounces.1),
                        )
                    })
                    .collect();
                let least = if bounces.1 == 0 { 200 } else { 20 };
                assert!(
                    found.len() > least,
                    "{} of 401 starts converge",
                    found.len()
                );
                for f in &found[..5] {
                    let (end, o, length, transmission) = hand(x, 0, f.direction, y, (2, bounces.1));
                    assert!((f.surface - y).length() < 1e-8, "{f:?}");
                    assert!((end - y).length() < 1e-8, "{end} vs {y}");
                    assert!((f.outgoing - o).length() < 1e-8);
                    assert!((f.length - length).abs() < 1e-8, "{} vs {length}", f.length);
                    let t = transmission;
                    assert!(
                        (f.transmission - t).abs() < 1e-9 * t,
                        "{} vs {t}",
                        f.transmission
                    );
                    assert_eq!(
                        f.again.parts().len(),
                        2 + bounces.1,
                        "through the middle ball"
                    );
                    let (e1, e2) = orthonormal_basis(f.direction);
                    let (f1, f2) = orthonormal_basis(o);
                    let h = 1e-6;
                    // where the ray crosses the plane through y across the found arrival
                    let at_plane = |w: DVec3| {
                        let (e, d, _, _) = hand(x, 0, w.normalize(), y, (2, bounces.1));
                        e + d * (y - e).dot(o) / d.dot(o)
                    };
                    let turn = |e: DVec3| {
                        (at_plane(f.direction + e * h) - at_plane(f.direction - e * h)) / (2.0 * h)
                    };
                    let (d1, d2) = (turn(e1), turn(e2));
                    let det = (f1.dot(d1) * f2.dot(d2) - f1.dot(d2) * f2.dot(d1)).abs();
                    assert!(
                        (f.jacobian - det).abs() < 1e-6 * det,
                        "{} vs {det}",
                        f.jacobian
                    );
                    // back from y along the reversed arrival, its reflections now in the first
                    let back = connector
                        .solve_into(
                            y,
                            x,
                            -f.outgoing,
                            &Bounces::with(bounces.1, [0; MAX_AGAIN], bounces.0),
                        )
                        .expect("converges back");
                    assert!((back.outgoing + f.direction).length() < 1e-6);
                    assert!((back.length - f.length).abs() < 1e-8);
                    let t = f.transmission;
                    assert!(
                        (back.transmission - t).abs() < 1e-8 * t,
                        "{}",
                        back.transmission
                    );
                    let (n_x, n_y) = (1.5, 1.3);
                    let (forth, back) = (n_y * n_y * f.jacobian, n_x * n_x * back.jacobian);
                    assert!((forth - back).abs() < 1e-6 * back, "{forth} vs {back}");
                }
            }
        }
    }
    /// A dumbbell as one signed-distance shape (glass balls of radius 0.6 at `±0.9` on x, a rod
    /// of radius 0.08 between them; index `n` in air): points in the two balls are joined by
    /// paths out of the shape and back in. Index-matched, the straight line: its stretches inside
    /// and between as the spheres give them, entered again once; a line through the rod enters
    /// the shape twice and is no such path. In glass, Newton's path out and back in passes
    /// through the far point when traced by hand through the two spheres by Snell's law (the
    /// sampled surface's normals within its grid's error).
    /// From a point in one of two volumes to a point beside it by a path that reflects once
    /// inside the other (a rainbow's path through a glass ball), closed form and stepped: the path
    /// Newton finds is the one traced by hand (Snell's law and the law of reflection) through
    /// both, passes through the point, carries the Fresnel factors of all five meetings with the
    /// surface, runs two stretches in the ball it crosses, and spreads as neighbouring rays
    /// traced by hand do.
    #[test]
    fn a_path_reflected_inside_a_volume_it_crosses_spreads_as_traced_by_hand() {
        let balls = [
            (DVec3::ZERO, 0.5, 1.3),
            (DVec3::new(3.0, 0.0, 0.0), 1.0, 1.5),
        ];
        // the hand's trace from `x` along `w`: out of the first ball, into the second, reflected
        // once inside it and out: where it leaves, its direction, the length inside both, and
        // the transmission
        let hand = |x: DVec3, w: DVec3| {
            let (c, r, n) = balls[0];
            let b = (x - c).dot(w);
            let t = -b + (b * b - ((x - c).length_squared() - r * r)).sqrt();
            let at = x + w * t;
            let normal = (at - c) / r;
            let d = snell(w, -normal, n);
            let mut transmission = 1.0 - reflectance(normal.dot(w), normal.dot(d), n);
            let (c, r, n) = balls[1];
            let b = (at - c).dot(d);
            let disc = b * b - ((at - c).length_squared() - r * r);
            let t0 = -b - disc.max(0.0).sqrt();
            let a = at + d * t0;
            let nrm = (a - c) / r;
            let inside = snell(d, nrm, 1.0 / n);
            transmission *= 1.0 - reflectance(-nrm.dot(d), -nrm.dot(inside), 1.0 / n);
            let (e, inside, t1, reflected) = bounce_in_ball((c, r, n), a, inside);
            transmission *= reflected;
            let t2 = -2.0 * (e - c).dot(inside);
            let f = e + inside * t2;
            let nrm = (f - c) / r;
            let out = snell(inside, -nrm, n);
            transmission *= 1.0 - reflectance(nrm.dot(inside), nrm.dot(out), n);
            (f, out, t + t1 + t2, transmission)
        };
        let (x, p) = (DVec3::new(0.1, 0.05, -0.05), DVec3::new(0.6, 0.8, 0.1));
        for graded in [false, true] {
            let v = clear_balls(&balls, graded);
            let connector = Connector::new(&v, 1e-3, 100_000);
            let mut rng = crate::math::stream_rng(7, 0);
            let reflected = Bounces::with(0, [1, 0, 0, 0], 0);
            let found: Vec<Exit> = (0..400)
                .filter_map(|_| {
                    let w0 = connector.initial(x, p, &mut rng);
                    connector.solve_through(x, Aim::Point(p), w0, &reflected)
                })
                .collect();
            // the path straight out of the first ball to the point crosses nothing: the
            // reflection drawn for a part crossed is not taken
            let (across, straight): (Vec<Exit>, Vec<Exit>) =
                found.into_iter().partition(|f| f.again.crossed() == 1);
            assert!(across.len() >= 5, "{} of 400 starts converge", across.len());
            for f in &across {
                assert_eq!(f.again.parts().len(), 2);
                traced_by_hand(f, p, |w| hand(x, w));
            }
            assert!(!straight.is_empty());
            for f in &straight {
                assert!(f.again.parts().is_empty());
                assert!((f.direction - (f.surface - x).normalize()).length() < 1e-9);
            }
        }
    }

    /// A path out of one part, across others and into a second, reflected `first` times inside
    /// the first, `across[i]` inside the `i`th crossed and `end` inside the second, fits
    /// [`MAX_AGAIN`] stretches after its first from either end exactly when both counts do: the
    /// crossed parts' `1 + k` each, then the last part's `1 + end`, or run the other way its
    /// `1 + first`. Paths the connection cannot hold from its own end are not found at all.
    #[test]
    fn paths_between_parts_fit_from_either_end_as_their_stretches_say() {
        let exit = |across: &[usize], end: usize| -> Option<Exit> {
            let mut e = Exit {
                direction: DVec3::X,
                surface: DVec3::X,
                outgoing: DVec3::X,
                inside_from: DVec3::ZERO,
                inside_along: DVec3::X,
                before: 0.0,
                length: 1.0,
                optical_path: 1.5,
                transmission: 1.0,
                again: Again::default(),
                between: 0.0,
                jacobian: 1.0,
                iterations: 0,
            };
            for &k in across {
                for _ in 0..=k {
                    e.enter(Reentry::default()).then_some(())?;
                }
                e.again.crossed += 1;
            }
            for _ in 0..=end {
                e.enter(Reentry::default()).then_some(())?;
            }
            Some(e)
        };
        let mut checked = 0;
        for first in 0..4 {
            for end in 0..4 {
                for across in [
                    vec![],
                    vec![0],
                    vec![2],
                    vec![0, 1],
                    vec![1, 0, 0],
                    vec![0; 3],
                ] {
                    let Some(e) = exit(&across, end) else {
                        continue;
                    };
                    let mut drawn = [0; MAX_AGAIN];
                    drawn[..across.len()].copy_from_slice(&across);
                    let path = InsidePath::Between(e, Bounces::with(first, drawn, end));
                    let crossed: usize = across.iter().map(|k| 1 + k).sum();
                    let fits = crossed + 1 + first.max(end) <= MAX_AGAIN;
                    assert_eq!(path.fits_either_way(), fits, "{first} {across:?} {end}");
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 40, "paths a connection holds from its own end");
    }

    /// Between two points on the axis of a glass block (n = 1.2) under a glass slab (n = 2.5),
    /// the paths out of the block and back in after one reflection — off the slab's underside,
    /// or inside it off its top face (bidirectional tracing's joins: that one alone) — sum,
    /// drawn at random with their inverse probabilities, to what their mirror images give in
    /// closed form: `T_block² R (1 − R_slab)^k / s²`, where
    /// every face is met at normal incidence and `s`, the length that spreads the ray tube,
    /// counts each stretch at `n_x / n` of its length (Snell's law for small angles).
    #[test]
    fn paths_out_of_a_block_and_back_off_a_slab_sum_to_their_mirror_images() {
        use crate::eikonal::Part;
        use crate::rrte::Bulk;
        let clear = || Bulk {
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        let block = Bounds::Box {
            half: DVec3::new(1.2, 1.2, 0.6),
        };
        let slab = Bounds::Box {
            half: DVec3::new(3.0, 3.0, 0.25),
        };
        let constant = |n| vec![Profile::Constant { n }];
        let v = Volume::several(
            vec![
                (Part::new(block, DVec3::ZERO, constant(1.2)), clear()),
                (Part::new(slab, DVec3::Z * 1.1, constant(2.5)), clear()),
            ],
            1.0,
        );
        let c = Connector::new(&v, 1e-2, 100_000);
        let (x, q) = (DVec3::new(0.0, 0.0, -0.3), DVec3::ZERO);
        let normal = |n1: f64, n2: f64| ((n1 - n2) / (n1 + n2)).powi(2);
        let (t_block, r_slab) = (1.0 - normal(1.2, 1.0), normal(1.0, 2.5));
        // up 0.9 and back down 0.6 inside the block, 0.25 up and down in air, 1 across the slab
        let spread = |across: f64| (1.5 + 0.5 * 1.2 + across * 1.2 / 2.5).powi(2);
        let off = t_block * t_block * r_slab / spread(0.0);
        let inside = t_block * t_block * (1.0 - r_slab).powi(2) * r_slab / spread(1.0);
        let draws = 200_000;
        // bidirectional tracing's joins (without `mirrors`) come back by the reflection inside
        // the slab alone
        for mirrors in [true, false] {
            let mut sums = [[0.0; 2]; 2];
            let mut rng = crate::math::stream_rng(1, 0);
            for _ in 0..draws {
                let s = c.sample_inside(x, q, (1, mirrors), false, &mut rng);
                let Some((InsidePath::Between(e, b), inverse_p)) = s.path else {
                    continue;
                };
                let w = e.transmission / e.jacobian * inverse_p;
                let k = usize::from(!b.mirrored[0]);
                sums[k][0] += w;
                sums[k][1] += w * w;
            }
            let off = if mirrors { off } else { 0.0 };
            for (([sum, sum2], expected), what) in
                sums.into_iter().zip([off, inside]).zip(["off", "inside"])
            {
                let mean = sum / draws as f64;
                let se = ((sum2 / draws as f64 - mean * mean) / draws as f64).sqrt();
                eprintln!("{what} the slab ({mirrors}): {mean} ± {se}, mirror image {expected}");
                if expected == 0.0 {
                    assert_eq!(sum, 0.0, "{what} ({mirrors})");
                    continue;
                }
                assert!(se < 0.02 * expected, "{what} ({mirrors}): {se}");
                assert!(
                    (mean - expected).abs() < 4.0 * se,
                    "{what} ({mirrors}): {mean} ± {se} against {expected}"
                );
            }
        }
    }

    /// [`Bounces::draw`] draws each way of splitting a budget of reflections among the parts
    /// crossed as often as [`Bounces::inverse_probability`] says, and no reflections inside the
    /// part after them (where a path that ends before a part beyond its end goes) as often; so
    /// does [`Bounces::draw_with_mirrors`], whose ways also reflect off a part's outside.
    #[test]
    fn reflections_among_parts_crossed_are_drawn_as_often_as_their_probability_says() {
        let mut rng = crate::math::stream_rng(3, 0);
        let draws = 200_000;
        let cases = [(1, 0), (1, 1), (2, 1), (2, 2), (3, 3)];
        for (mirrors, (after, crossed)) in [false, true]
            .into_iter()
            .flat_map(|m| cases.map(|c| (m, c)))
        {
            let mut counts = std::collections::HashMap::new();
            let mut ended = std::collections::HashMap::new();
            let mut ends = std::collections::HashMap::new();
            // a path that enters the part after them to end there takes the draws that do not
            // reflect off its outside
            let mut entering = std::collections::HashMap::new();
            for _ in 0..draws {
                let b = match mirrors {
                    false => Bounces::draw(0, after, &mut rng),
                    true => Bounces::draw_with_mirrors(0, after, &mut rng),
                };
                let key: Vec<(usize, bool)> =
                    (0..crossed).map(|i| (b.across(i), b.mirrored(i))).collect();
                assert!(mirrors || !key.iter().any(|k| k.1));
                let p = 1.0 / b.inverse_probability(crossed, false);
                // a path that ends before a part beyond its end takes the draws that reflect
                // inside none there
                let declining = b.across(crossed) == 0;
                *ended.entry((key.clone(), declining)).or_insert(0usize) += 1;
                if declining {
                    ends.insert(key.clone(), (p, 1.0 / b.inverse_probability(crossed, true)));
                }
                if !b.mirrored(crossed) {
                    let again = Again {
                        crossed,
                        entered: true,
                        ..Again::default()
                    };
                    let p = 1.0 / b.inverse_probability_of(&again);
                    let entry = entering.entry(key.clone()).or_insert((0usize, p));
                    assert_eq!(entry.1, p, "one way, one probability");
                    entry.0 += 1;
                }
                let entry = counts.entry(key).or_insert((0usize, p));
                assert_eq!(entry.1, p, "one way, one probability");
                entry.0 += 1;
                assert_eq!(
                    b.left_after(crossed) + (0..crossed).map(|i| b.across(i)).sum::<usize>(),
                    after
                );
            }
            for ((key, declining), n) in &ended {
                let (p, declined) = ends.get(key).copied().unwrap_or((counts[key].1, 0.0));
                let p = if *declining { declined } else { p - declined };
                let expected = p * draws as f64;
                let error = (expected * (1.0 - p)).sqrt().max(1.0);
                assert!(
                    (*n as f64 - expected).abs() < 4.0 * error,
                    "{key:?}, ending before another part {declining}: {n} drawn, {expected} \
                     ± {error} expected"
                );
            }
            let total: f64 = counts.values().map(|(_, p)| p).sum();
            assert!(
                (total - 1.0).abs() < 1e-12,
                "the ways' probabilities sum to {total}"
            );
            for (key, (n, p)) in counts.iter().chain(&entering) {
                let expected = p * draws as f64;
                let error = (expected * (1.0 - p)).sqrt().max(1.0);
                assert!(
                    (*n as f64 - expected).abs() < 4.0 * error,
                    "{key:?}: {n} drawn, {expected} ± {error} expected"
                );
            }
            // every way is drawn: with mirrors one more per part the budget reaches
            fn ways(left: usize, parts: usize, mirrors: bool) -> usize {
                if parts == 0 || left == 0 {
                    return 1;
                }
                let inside: usize = (1..=left).map(|k| ways(left - k, parts - 1, mirrors)).sum();
                // one reflection off an outside at most
                let off = usize::from(mirrors) * ways(left - 1, parts - 1, false);
                ways(left, parts - 1, mirrors) + inside + off
            }
            let all = ways(after, crossed, mirrors);
            assert_eq!(counts.len(), all, "{mirrors}, {after}, {crossed}");
        }
        assert_eq!(Bounces::first(2).inverse_probability(3, true), 1.0);
    }

    #[test]
    fn paths_out_of_a_dumbbell_and_back_in_enter_it_once() {
        use crate::eikonal::grid::Interp;
        use crate::eikonal::sdf::{SdfGrid, Shape};
        let (a, b) = (DVec3::new(-0.9, 0.0, 0.0), DVec3::new(0.9, 0.0, 0.0));
        let shapes = [
            Shape::Sphere {
                center: a,
                radius: 0.6,
            },
            Shape::Sphere {
                center: b,
                radius: 0.6,
            },
            Shape::Capsule {
                from: a,
                to: b,
                radius: 0.08,
            },
        ];
        let grid = SdfGrid::from_shapes(&shapes, 0.0, 0.02, Interp::Tricubic).unwrap();
        let bounds = Bounds::Sdf(std::sync::Arc::new(grid));
        let mut rng = crate::math::stream_rng(3, 0);
        let matched = volume(Profile::Constant { n: 1.0 }, bounds.clone(), 1.0);
        let c = Connector::new(&matched, 1e-2, 1000);
        let lift = DVec3::new(0.0, 0.2, 0.0);
        let (x, y) = (a + lift, b + lift);
        let s = c.sample_inside(x, y, (0, false), false, &mut rng);
        let Some((InsidePath::Between(e, _), inverse_p)) = s.path else {
            panic!("{s:?}")
        };
        let chord = (0.36f64 - 0.04).sqrt();
        assert_eq!(inverse_p, 1.0);
        assert_eq!(e.again.parts().len(), 1);
        assert!((e.length - 2.0 * chord).abs() < 1e-3, "{e:?}");
        assert!((e.outside() - (1.8 - 2.0 * chord)).abs() < 1e-3, "{e:?}");
        // across the rod: out of the ball, into the rod, out of it and into the other ball
        let tilt = DVec3::new(0.3, 0.2, 0.0);
        assert!(
            c.sample_into(a + tilt, b - tilt, &Bounces::first(0), false, &mut rng)
                .path
                .is_none()
        );
        // within one ball, the straight line inside
        let s = c.sample_inside(x, a - lift, (0, false), false, &mut rng);
        assert!(
            matches!(s.path, Some((InsidePath::Within(..), p)) if p == 1.0),
            "{s:?}"
        );

        let n = 1.1;
        let glass = volume(Profile::Constant { n }, bounds, 1.0);
        let c = Connector::new(&glass, 1e-2, 1000);
        let x = a + DVec3::new(0.1, 0.25, 0.05);
        let y = b + DVec3::new(-0.2, -0.1, 0.15);
        let e = c
            .solve_into(x, y, (y - x).normalize(), &Bounces::first(0))
            .unwrap();
        assert!((e.surface - y).length() < 1e-8, "{e:?}");
        // by hand: out of ball a, straight to ball b, into it and on
        let out_of = |p: DVec3, w: DVec3, centre: DVec3| {
            let l = p - centre;
            let h = l.dot(w);
            p + w * (-h + (h * h - (l.length_squared() - 0.36)).sqrt())
        };
        let at = out_of(x, e.direction, a);
        let normal = (at - a) / 0.6;
        let d = snell(e.direction, -normal, n);
        let l = at - b;
        let h = l.dot(d);
        let at = at + d * (-h - (h * h - (l.length_squared() - 0.36)).sqrt());
        let d = snell(d, (at - b) / 0.6, 1.0 / n);
        let miss = (y - at) - d * (y - at).dot(d);
        assert!(miss.length() < 1e-3, "missed by {miss}");
        assert!((e.outgoing - d).length() < 1e-3, "{} {d}", e.outgoing);
    }

    /// A path from one of several volumes into another enters each of the two once (the same
    /// path from either end, as bidirectional tracing's weights take it): from one arm of a glass
    /// ring to a ball beyond its other arm, no path Newton finds from many starts runs through
    /// that other arm, which the straight line crosses.
    #[test]
    fn a_path_into_another_volume_does_not_enter_its_own_again() {
        use crate::eikonal::Part;
        use crate::eikonal::grid::Interp;
        use crate::eikonal::sdf::{SdfGrid, Shape};
        use crate::rrte::Bulk;
        let ring = [Shape::Torus {
            center: DVec3::ZERO,
            axis: DVec3::Z,
            major: 1.0,
            minor: 0.3,
        }];
        let grid = SdfGrid::from_shapes(&ring, 0.0, 0.03, Interp::Tricubic).unwrap();
        let clear = Bulk {
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        let part = |bounds, center| {
            let part = Part::new(bounds, center, vec![Profile::Constant { n: 1.2 }]);
            (part, clear.clone())
        };
        let v = Volume::several(
            vec![
                part(Bounds::Sdf(std::sync::Arc::new(grid)), DVec3::ZERO),
                part(Bounds::Sphere { radius: 0.4 }, DVec3::new(2.2, 0.0, 0.0)),
            ],
            1.0,
        );
        let c = Connector::new(&v, 1e-2, 1000);
        let (x, y) = (DVec3::new(-1.0, 0.05, 0.0), DVec3::new(2.1, 0.0, 0.05));
        let mut rng = crate::math::stream_rng(4, 0);
        let mut found = 0;
        for _ in 0..200 {
            let Some(e) = c.solve_into(x, y, c.initial(x, y, &mut rng), &Bounces::first(0)) else {
                continue;
            };
            found += 1;
            for p in e.again.parts() {
                assert_eq!(c.part_of(p.inside), 1, "{e:?}");
            }
        }
        eprintln!("{found} paths found");
    }

    #[test]
    fn two_points_in_a_maxwell_fish_eye_have_two_paths_and_alg3_counts_them() {
        // rays of n = 2/(1 + r²) are circles; through two points and the image −x/|x|² of the
        // first passes one circle, so exactly two arcs join them
        let v = volume(
            Profile::MaxwellFishEye { radius: 1.0 },
            Bounds::Sphere { radius: 4.0 },
            2.0 / 17.0,
        );
        let c = Connector::new(&v, 2e-3, 200_000);
        let (x, y) = (DVec3::new(0.5, 0.0, 0.0), DVec3::new(0.2, 0.6, 0.3));
        let mut rng = crate::math::stream_rng(5, 0);
        let mut found: Vec<Connection> = Vec::new();
        for _ in 0..200 {
            if let Some(p) = c.solve(x, y, c.initial(x, y, &mut rng))
                && !found
                    .iter()
                    .any(|f| (f.direction - p.direction).length() < SAME_PATH)
            {
                found.push(p);
            }
        }
        assert_eq!(found.len(), 2, "{found:?}");
        // both arcs lie on the circle through x, y and the image of x: equal distance from its
        // centre at every point we have (the ends)
        for p in &found {
            assert!((p.arrival.x - y).length() <= c.tolerance * 1.0001);
        }
        // Alg. 3: E[1/p(C)] over draws is the number of paths; the draws of each path average 1
        let trials = 400;
        // per draw, each path's share: 1/p when it is the one drawn, else 0
        let (mut sum, mut sq) = ([0.0f64; 2], [0.0f64; 2]);
        let mut sq_total = 0.0;
        for _ in 0..trials {
            let s = c.sample(x, y, &mut rng);
            if let Some((p, inv)) = s.path {
                let k = found
                    .iter()
                    .position(|f| (f.direction - p.direction).length() < SAME_PATH)
                    .expect("a known path");
                sum[k] += inv;
                sq[k] += inv * inv;
                sq_total += inv * inv;
            }
        }
        let n = trials as f64;
        let mean_se = |sum: f64, sq: f64| {
            let m = sum / n;
            (m, ((sq / n - m * m) / n).sqrt())
        };
        let (total, se) = mean_se(sum[0] + sum[1], sq_total);
        assert!((total - 2.0).abs() < 4.0 * se, "Σ 1/p = {total} ± {se}");
        for k in 0..2 {
            let (m, se) = mean_se(sum[k], sq[k]);
            assert!((m - 1.0).abs() < 4.0 * se, "path {k}: {m} ± {se}");
        }
    }

    /// Starts that leave the lens away from the pinhole (or the camera's direction) are steered
    /// round to the path a start near the straight line finds.
    #[test]
    fn starts_leaving_the_wrong_way_are_steered_to_the_path() {
        let v = volume(
            Profile::Luneburg { radius: 1.0 },
            Bounds::Sphere { radius: 1.0 },
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let x = DVec3::new(0.3, -0.2, 0.1);
        let p = DVec3::new(2.0, 1.0, 1.5);
        let near = c
            .solve_through(x, Aim::Point(p), p - x, &Bounces::first(0))
            .expect("the near start converges");
        let away = c
            .solve_through(x, Aim::Point(p), x - p, &Bounces::first(0))
            .expect("the opposite start is steered round");
        assert!((near.direction - away.direction).length() < 1e-6);
        assert!((near.jacobian - away.jacobian).abs() < 1e-6 * near.jacobian);
        let dir = DVec3::new(1.0, 0.0, 0.0);
        let near = c
            .solve_exit(x, Aim::Along(dir), dir, &Bounces::first(0))
            .expect("the near start converges");
        let away = c
            .solve_exit(x, Aim::Along(dir), -dir, &Bounces::first(0))
            .expect("the opposite start is steered round");
        assert!((near.direction - away.direction).length() < 1e-6);
        assert!(near.outgoing.dot(dir) > 1.0 - 1e-9);
    }

    /// From a gently graded box to a pinhole outside, the starts lean on the straight line: the
    /// first start finds the one path for 86 % of connections (Alg. 3 counting 1; 48 % with the
    /// even mixture), and Alg. 3's inverse probabilities still average to the number of paths,
    /// 1.
    #[test]
    fn paths_through_the_surface_of_a_gently_graded_box_mostly_need_one_start() {
        let v = graded_box(1.33, DVec3::new(0.0, 0.05, 0.0), DVec3::ONE);
        assert!(v.field.start_cone(DVec3::ZERO).is_some());
        let c = Connector::new(&v, 1e-3, 100_000);
        let pinhole = DVec3::new(5.0, 0.1, 0.0);
        let mut rng = crate::math::stream_rng(9, 0);
        let (mut sum, mut squares, mut ones, mut draws) = (0.0, 0.0, 0, 0);
        for _ in 0..200 {
            // points on the pinhole's side of the box, each reaching it through the face x = 1
            let x = DVec3::new(uniform(&mut rng), 0.0, 0.0)
                + DVec3::new(0.0, 1.0, 1.0) * DVec3::ZERO.map(|_| 1.6 * uniform(&mut rng) - 0.8);
            for _ in 0..10 {
                let drawn =
                    c.sample_through(x, Aim::Point(pinhole), &Bounces::first(0), false, &mut rng);
                let inverse = drawn.path.map_or(0.0, |p| p.1);
                sum += inverse;
                squares += inverse * inverse;
                ones += usize::from(inverse == 1.0);
                draws += 1;
            }
        }
        let n = draws as f64;
        let (mean, error) = (sum / n, ((squares / n - (sum / n).powi(2)) / n).sqrt());
        assert!((mean - 1.0).abs() < 4.0 * error, "{mean} ± {error} paths");
        let share = ones as f64 / n;
        assert!(
            share > 0.85,
            "Alg. 3 counted 1 for {share} of the connections"
        );
    }

    /// A linear field in a unit box, an ultrasonic one in a cylinder and a spherical polynomial
    /// in a ball (`κ D` 0.37, 0.32, 0.24): every path found from uniform starts begins inside the
    /// cone `BoundedField::start_cone` proves, and every start drawn in it (twice as wide) finds
    /// the one path, points by the surface included: Alg. 3 counts 1 every time.
    #[test]
    fn every_path_in_a_gently_graded_field_starts_within_its_proved_cone() {
        let fields = [
            (
                Profile::Linear {
                    n0: 1.4,
                    gradient: DVec3::new(0.12, 0.05, 0.0),
                },
                Bounds::Box { half: DVec3::ONE },
                0.13 / 1.23,
            ),
            (
                Profile::Ultrasonic {
                    n0: 1.33,
                    n_max: 0.04,
                    k_r: 3.0,
                    m: 2,
                },
                Bounds::Cylinder {
                    radius: 1.0,
                    half_length: 1.0,
                },
                0.12 / 1.29,
            ),
            (
                Profile::SphericalPolynomial {
                    n0: 1.6,
                    coefficients: vec![-0.1],
                },
                Bounds::Sphere { radius: 1.0 },
                0.1 / (1.6 - 0.1 * 3f64.sqrt()),
            ),
        ];
        let mut rng = crate::math::stream_rng(5, 0);
        for (profile, bounds, kappa) in fields {
            let v = volume(profile, bounds, 1.0);
            let theta = v.field.start_cone(DVec3::ZERO).expect("a bounded field");
            let bend = kappa * 2.0 * 3f64.sqrt();
            assert!(
                (theta * theta.cos() - bend).abs() < 1e-9,
                "{theta}, κD = {bend}"
            );
            let c = Connector::new(&v, 1e-3, 100_000);
            let mut inside = || loop {
                let x = DVec3::ZERO.map(|_| 2.0 * uniform(&mut rng) - 1.0);
                if v.field.bounds.contains(x) {
                    return x;
                }
            };
            let pairs: Vec<_> = (0..60).map(|_| (inside(), inside())).collect();
            let (mut found, mut widest) = (0, 0.0f64);
            for &(x, y) in &pairs {
                let chord = (y - x).normalize();
                let mut first: Option<DVec3> = None;
                for _ in 0..20 {
                    let w = uniform_sphere(uniform(&mut rng), uniform(&mut rng));
                    let Some(p) = c.solve(x, y, w) else { continue };
                    assert!((p.arrival.x - y).length() <= c.tolerance * 1.0001);
                    let angle = p.direction.dot(chord).clamp(-1.0, 1.0).acos();
                    assert!(
                        angle <= theta,
                        "a path {angle} from the chord, the cone {theta}"
                    );
                    widest = widest.max(angle / theta);
                    let first = *first.get_or_insert(p.direction);
                    assert!((p.direction - first).length() < SAME_PATH, "a second path");
                    found += 1;
                }
                let drawn = c.sample(x, y, &mut rng);
                assert_eq!(drawn.path.map(|p| p.1), Some(1.0), "{x} to {y}");
            }
            let kind = v.field.profiles[0].kind();
            eprintln!("{kind}: {found} paths, the widest {widest} of the cone");
            assert!(
                found > 300,
                "{kind}: {found} paths from 1200 uniform starts"
            );
        }
    }

    /// In a graded box, the paths from a point leaving along a direction after one reflection
    /// inside (refracted out), after two, and along an axis after none, are found from 3 000
    /// uniform starts: each starts
    /// within the cone of the nearest of the flipped exit directions, and the draws from the
    /// cones (one drawn evenly, their count times Alg. 3's count in it) average to the sum over
    /// those paths.
    #[test]
    fn paths_reflected_out_of_a_graded_box_are_drawn_from_cones_about_flipped_exits() {
        let gradient = DVec3::new(0.05, 0.06, 0.0);
        let v = graded_box(1.4, gradient, DVec3::new(1.0, 0.8, 0.6));
        let c = Connector::new(&v, 1e-3, 100_000);
        let mut rng = crate::math::stream_rng(8, 0);
        let mut found = Vec::new();
        for (x, out, reflections) in [
            (DVec3::new(0.3, -0.2, 0.1), DVec3::new(0.3, -0.2, 1.0), 1),
            (DVec3::new(-0.6, 0.5, -0.3), DVec3::new(0.0, 0.0, -1.0), 1),
            (DVec3::new(0.2, 0.1, 0.4), DVec3::new(-0.5, 0.2, 0.6), 2),
            (DVec3::new(0.5, -0.4, 0.5), DVec3::new(0.0, 0.0, -1.0), 0),
        ] {
            let out = out.normalize();
            let bounces = Bounces::first(reflections);
            let cones = c.flipped_cones(x, out, &bounces).expect("a graded box");
            let theta = cones.half_angle;
            assert!(theta > 0.05 && theta < 0.7, "{theta}");
            let mut exits: Vec<Exit> = Vec::new();
            for _ in 0..3000 {
                let w = uniform_sphere(uniform(&mut rng), uniform(&mut rng));
                if let Some(e) = c.solve_exit(x, Aim::Along(out), w, &bounces)
                    && !exits
                        .iter()
                        .any(|q| (q.direction - e.direction).length() < SAME_PATH)
                {
                    let k = cones.nearest(e.direction);
                    let angle = e.direction.dot(cones.centers[k]).clamp(-1.0, 1.0).acos();
                    assert!(
                        angle <= theta,
                        "a path {angle} from its cone's centre, {theta}"
                    );
                    exits.push(e);
                }
            }
            let sum: f64 = exits.iter().map(|e| e.transmission / e.jacobian).sum();
            let (mut total, mut total2, draws) = (0.0, 0.0, 3000);
            for _ in 0..draws {
                let s = c.sample_exit(x, Aim::Along(out), &bounces, false, &mut rng);
                if let Some((e, inverse_p)) = s.path {
                    let f = e.transmission / e.jacobian * inverse_p;
                    (total, total2) = (total + f, total2 + f * f);
                }
            }
            let mean = total / draws as f64;
            let se = ((total2 / draws as f64 - mean * mean).max(0.0) / draws as f64).sqrt();
            assert!(
                (mean - sum).abs() <= 4.0 * se + 1e-9 * sum,
                "{x} {out} after {reflections}: {mean} ± {se} vs {sum}"
            );
            found.push((exits.len(), cones.count));
        }
        eprintln!("paths and cones: {found:?}");
        assert!(found.iter().map(|f| f.0).sum::<usize>() >= 4, "{found:?}");
    }

    /// Two points above the thin neck of a graded dumbbell (two balls joined by a rod): no path
    /// joins them inside, though the ray leaving one ball along the chord, carried on in a
    /// straight line past its surface, passes through the other: Newton's method would stop
    /// there at once. Within one ball they are joined.
    #[test]
    fn no_path_is_found_that_leaves_the_volume_between_its_ends() {
        use crate::eikonal::grid::Interp;
        use crate::eikonal::sdf::{SdfGrid, Shape};
        let (a, b) = (DVec3::new(-0.9, 0.0, 0.0), DVec3::new(0.9, 0.0, 0.0));
        let ball = |center| Shape::Sphere {
            center,
            radius: 0.6,
        };
        let rod = Shape::Capsule {
            from: a,
            to: b,
            radius: 0.08,
        };
        let grid = SdfGrid::from_shapes(&[ball(a), ball(b), rod], 0.0, 0.02, Interp::Tricubic);
        let v = volume(
            Profile::Linear {
                n0: 1.3,
                gradient: DVec3::new(0.0, 0.05, 0.0),
            },
            Bounds::Sdf(std::sync::Arc::new(grid.unwrap())),
            1.0,
        );
        let c = Connector::new(&v, 1e-3, 100_000);
        let lift = DVec3::new(0.0, 0.2, 0.0);
        let (x, y) = (a + lift, b + lift);
        assert!(c.shoot(x, (y - x).normalize(), y).expect("across").beyond);
        assert_eq!(c.solve(x, y, (y - x).normalize()), None);
        let mut rng = crate::math::stream_rng(6, 0);
        for _ in 0..20 {
            assert_eq!(c.sample(x, y, &mut rng).path, None);
        }
        let p = c.solve(x, a - lift, -lift).expect("a path inside one ball");
        assert!((p.arrival.x - a + lift).length() <= c.tolerance * 1.0001);
    }

    /// In the tank of paper 002's Fig. 2, the ray started along the chord to a point 0.05 from
    /// the wall it is bound for meets the wall before its closest approach, which Newton's
    /// method then takes from the ray carried on in a straight line, and is steered back to the
    /// path.
    #[test]
    fn a_start_straying_across_the_surface_is_steered_back_to_the_path() {
        let v = graded_box(1.33, DVec3::new(0.0, 0.02, 0.0), DVec3::splat(5.0));
        let c = Connector::new(&v, 1e-2, 100_000);
        let (x, y) = (
            DVec3::new(0.0, 0.0, 0.878),
            DVec3::new(-0.284, -2.034, -4.946),
        );
        let chord = (y - x).normalize();
        assert!(c.shoot(x, chord, y).expect("approaching").beyond);
        let p = c.solve(x, y, chord).expect("steered back");
        assert!((p.arrival.x - y).length() <= c.tolerance * 1.0001);
        assert!(!c.shoot(x, p.direction, y).expect("inside").beyond);
    }
}
