//! Refractive-index fields `n(x)` with analytic gradients and Hessians, bounded by a
//! geometry outside which `n` is the constant `n_out`.

use super::sdf::SdfGrid;
use glam::{DMat3, DVec3};
use std::sync::Arc;

/// An index field: value, gradient and Hessian of `n`.
pub trait IndexField: Sync {
    fn n(&self, x: DVec3) -> f64;
    fn grad(&self, x: DVec3) -> DVec3;
    fn hessian(&self, x: DVec3) -> DMat3;
    /// `(n, ∇n, ∇²n)` in one evaluation (override when the parts share work, as grids do).
    fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        (self.n(x), self.grad(x), self.hessian(x))
    }
}

/// Analytic index profiles (centred at the origin; radial profiles use `r = |x|`, fibre profiles the
/// distance from the z axis).
#[derive(Clone, Debug, PartialEq)]
pub enum Profile {
    Constant {
        n: f64,
    },
    /// `n = n0 + g·x`.
    Linear {
        n0: f64,
        gradient: DVec3,
    },
    /// Luneburg lens `n = sqrt(2 − (r/R)²)`.
    Luneburg {
        radius: f64,
    },
    /// Maxwell fish-eye `n = 2 / (1 + (r/R)²)`.
    MaxwellFishEye {
        radius: f64,
    },
    /// Parabolic GRIN fibre `n² = n0² (1 − α² ρ²)`, `ρ` the distance from the z axis.
    ParabolicFibre {
        n0: f64,
        alpha: f64,
    },
    /// Hyperbolic-secant GRIN fibre `n = n0 sech(α ρ)`.
    SechFibre {
        n0: f64,
        alpha: f64,
    },
    /// Radial polynomial about the z axis, `n = n0 + Σ_k c_k ρ^{2k}` (`k = 1, 2, …`): a free-form
    /// GRIN-fibre profile whose coefficients a design can fit (sech: `c₂/c₁² = 5/(6 n0)`...).
    RadialPolynomial {
        n0: f64,
        coefficients: Vec<f64>,
    },
    /// Spherically symmetric polynomial `n = n0 + Σ_k c_k r^k` (`k = 1, 2, …`, `r` the distance from
    /// the origin): `c1 = (n_s − n_c)/R` mixes two glasses linearly from centre to surface, as the
    /// heterogeneous crown/flint sphere of paper 002 (Sec. 7.1).
    SphericalPolynomial {
        n0: f64,
        coefficients: Vec<f64>,
    },
    /// Ultrasonically sculpted index `n = n0 + n_max J_m(k_r r) cos(m φ)` (paper 002, Eq. 15; `r`, `φ`
    /// cylindrical about the z axis; the time factor `sin Ωt` folded into `n_max`).
    Ultrasonic {
        n0: f64,
        n_max: f64,
        k_r: f64,
        m: u32,
    },
    /// The index a phased ultrasound array sculpts, `n0 + (dn/dp) Re[P(x) e^{−iΩt}]`, at the
    /// instant `omega_t` (π/2 unless a modulation sets it, as the ultrasonic profile's full
    /// amplitude `sin Ωt = 1`); see [`super::acoustic`].
    PhasedArray {
        array: Arc<super::acoustic::PhasedArray>,
        omega_t: f64,
    },
    /// Sampled field (trilinear or prefiltered tricubic B-spline); parameters are its coefficients.
    Grid(super::grid::GridField),
    /// A Luneburg-like profile graded by the depth below a signed-distance shape's surface (paper
    /// 002, Fig. 9: the distance as a proxy for the radius): `n² = n_s² + (n_c² − n_s²)(2u − u²)`
    /// with `u = min(−d(x)/depth, 1)`, so `n = n_surface` on the surface rising smoothly to
    /// `n_core` at `depth` and beyond. A sphere's distance with `depth = R`, `n_s = 1`,
    /// `n_c = √2` gives the Luneburg lens.
    SdfLuneburg {
        sdf: Arc<SdfGrid>,
        n_surface: f64,
        n_core: f64,
        depth: f64,
    },
    /// Several disjoint volumes, each with its own profiles (summed, in its own frame: at
    /// `x − center`): the index of whichever part holds `x` (the nearest where round-off puts `x`
    /// just outside them all). The same parts bound the field ([`Bounds::Parts`]).
    Parts(Arc<[Part]>),
}

/// One of several disjoint volumes of a field: its shape and index profiles, both centred on
/// `center` (each is given as if the part sat at the origin).
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    /// A sphere, box, cylinder or signed-distance shape (not `Everywhere`, not `Parts`).
    pub shape: Bounds,
    pub center: DVec3,
    pub profiles: Vec<Profile>,
    /// Inside, `n = offset + scale · Σ profiles`: 1 and 0 except in a dispersive render, which
    /// maps each part's field, given at a reference wavelength, to the photon's wavelength by
    /// the part's own materials (as [`BoundedField::scale`] does for a field of one volume).
    pub scale: f64,
    pub offset: f64,
}

/// The most parts a field may have (volumes of a scene).
pub const MAX_PARTS: usize = 16;

impl Part {
    /// A part of `shape` holding `profiles`, both moved to `center`.
    pub fn new(shape: Bounds, center: DVec3, profiles: Vec<Profile>) -> Self {
        Part {
            shape,
            center,
            profiles,
            scale: 1.0,
            offset: 0.0,
        }
    }

    /// How deep `x` lies inside the part's shape: positive inside (a lower bound on the distance
    /// to its surface), negative outside; the part holding a point, or the nearest, has the
    /// largest depth among disjoint parts.
    #[inline]
    fn depth(&self, x: DVec3) -> f64 {
        let local = x - self.center;
        match self.shape {
            Bounds::Sdf(ref g) => {
                let (lo, hi) = g.corners();
                let off_grid = (lo - local).max(local - hi).max(DVec3::ZERO).length();
                -g.grid().value(local.clamp(lo, hi)) - off_grid
            }
            ref shape => shape.clearance(local),
        }
    }

    /// The part's index at `x` (scene coordinates).
    pub fn index(&self, x: DVec3) -> f64 {
        self.eval(x).0
    }

    /// The part's `(n, ∇n)` at `x` (scene coordinates; the bits of [`BoundedField::value_grad`]
    /// at a point inside the part, whose field map is the identity).
    #[inline]
    pub fn value_grad(&self, x: DVec3) -> (f64, DVec3) {
        let (n, g, _) = self.eval(x);
        (n, g)
    }

    /// Whether `n` is constant inside the part (rays are straight in it).
    pub fn is_constant(&self) -> bool {
        self.profiles.iter().all(Profile::is_constant)
    }

    /// Whether `x` (scene coordinates) is inside the part, and then how far it may run before
    /// testing again (as [`Bounds::inside_clearance`] of the part's shape).
    #[inline]
    pub fn inside_clearance(&self, x: DVec3) -> Option<f64> {
        self.shape.inside_clearance(x - self.center)
    }

    /// [`Bounds::clearance`] of the part's shape at `x` (scene coordinates, inside).
    #[inline]
    pub fn clearance(&self, x: DVec3) -> f64 {
        self.shape.clearance(x - self.center)
    }

    /// Whether `x` (scene coordinates) is inside the part.
    #[inline]
    pub fn contains(&self, x: DVec3) -> bool {
        self.shape.contains(x - self.center)
    }

    /// `(n, ∇n, ∇²n)` of the part at `x` (scene coordinates): its profiles' sum, mapped.
    #[inline]
    fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        mapped_sum(&self.profiles, x - self.center, self.scale, self.offset)
    }
}

/// `(n, ∇n, ∇²n)` of `offset + scale · Σ profiles` at `x`.
#[inline]
fn mapped_sum(profiles: &[Profile], x: DVec3, scale: f64, offset: f64) -> (f64, DVec3, DMat3) {
    let (n, g, h) = profiles
        .iter()
        .fold((0.0, DVec3::ZERO, DMat3::ZERO), |(n, g, h), p| {
            let (pn, pg, ph) = p.eval(x);
            (n + pn, g + pg, h + ph)
        });
    if scale == 1.0 && offset == 0.0 {
        return (n, g, h);
    }
    (offset + scale * n, g * scale, h * scale)
}

/// The index of the part of `parts` that holds `x`, or the nearest one.
#[inline]
pub fn part_at(parts: &[Part], x: DVec3) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for (k, p) in parts.iter().enumerate() {
        let depth = p.depth(x);
        if depth > best.1 {
            best = (k, depth);
        }
    }
    best.0
}

/// `(u, q(u) = 2u − u², q'(u), q''(u))` of [`Profile::SdfLuneburg`] at signed distance `d`.
#[inline]
fn depth_grading(d: f64, depth: f64) -> (f64, f64, f64, f64) {
    let u = -d / depth;
    if u >= 1.0 {
        (u, 1.0, 0.0, 0.0)
    } else {
        (u, u * (2.0 - u), 2.0 - 2.0 * u, -2.0)
    }
}

/// `n = f(q)` of a quadratic form `q = xᵀ D x` (D diagonal): value, `f'`, `f''` give all derivatives.
fn quadratic(f: (f64, f64, f64), d: DVec3, x: DVec3) -> (f64, DVec3, DMat3) {
    let (v, f1, f2) = f;
    let dq = 2.0 * d * x; // ∇q
    let grad = dq * f1;
    let hess = DMat3::from_diagonal(2.0 * d) * f1 + outer(dq, dq) * f2;
    (v, grad, hess)
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

impl Profile {
    /// A short name for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Profile::Constant { .. } => "constant",
            Profile::Linear { .. } => "linear",
            Profile::Luneburg { .. } => "luneburg",
            Profile::MaxwellFishEye { .. } => "maxwell_fish_eye",
            Profile::ParabolicFibre { .. } => "parabolic_fibre",
            Profile::SechFibre { .. } => "sech_fibre",
            Profile::Ultrasonic { .. } => "ultrasonic",
            Profile::PhasedArray { .. } => "phased_array",
            Profile::RadialPolynomial { .. } => "radial_polynomial",
            Profile::SphericalPolynomial { .. } => "spherical_polynomial",
            Profile::Grid(_) => "grid",
            Profile::SdfLuneburg { .. } => "sdf_luneburg",
            Profile::Parts(_) => "parts",
        }
    }

    /// Whether `n` is constant wherever the profile applies (in each part, for parts): rays are
    /// straight there.
    pub fn is_constant(&self) -> bool {
        match self {
            Profile::Constant { .. } => true,
            Profile::Parts(parts) => parts.iter().all(Part::is_constant),
            _ => false,
        }
    }

    /// Value and gradient (grids skip the Hessian; the same bits as [`Self::eval`]'s).
    #[inline(always)]
    fn value_grad(&self, x: DVec3) -> (f64, DVec3) {
        match self {
            Profile::Grid(g) => g.value_grad(x),
            p => {
                let (n, g, _) = p.eval(x);
                (n, g)
            }
        }
    }

    fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        match *self {
            Profile::Constant { n } => (n, DVec3::ZERO, DMat3::ZERO),
            Profile::Linear { n0, gradient } => (n0 + gradient.dot(x), gradient, DMat3::ZERO),
            Profile::Luneburg { radius } => {
                // n = sqrt(2 − q), q = r²/R²
                let d = DVec3::splat(1.0 / (radius * radius));
                let q = (d * x).dot(x);
                let n = (2.0 - q).sqrt();
                quadratic((n, -0.5 / n, -0.25 / (n * n * n)), d, x)
            }
            Profile::MaxwellFishEye { radius } => {
                let d = DVec3::splat(1.0 / (radius * radius));
                let q = (d * x).dot(x);
                let n = 2.0 / (1.0 + q);
                quadratic((n, -2.0 / (1.0 + q).powi(2), 4.0 / (1.0 + q).powi(3)), d, x)
            }
            Profile::ParabolicFibre { n0, alpha } => {
                // n = n0 sqrt(1 − q), q = α² ρ²
                let d = DVec3::new(alpha * alpha, alpha * alpha, 0.0);
                let q = (d * x).dot(x);
                let s = (1.0 - q).sqrt();
                quadratic((n0 * s, -0.5 * n0 / s, -0.25 * n0 / (s * s * s)), d, x)
            }
            Profile::Grid(ref g) => g.eval(x),
            Profile::SdfLuneburg {
                ref sdf,
                n_surface,
                n_core,
                depth,
            } => {
                // N = n² = a + b q(u), u = −d/depth; n = √N
                let (d, dd, hd) = sdf.eval(x);
                let (_, q, q1, q2) = depth_grading(d, depth);
                let b = n_core * n_core - n_surface * n_surface;
                let n = (n_surface * n_surface + b * q).sqrt();
                let gu = dd * (-1.0 / depth);
                let g_big = gu * (b * q1);
                let h_big = outer(gu, gu) * (b * q2) + hd * (-b * q1 / depth);
                let grad = g_big / (2.0 * n);
                (n, grad, h_big * (0.5 / n) - outer(grad, grad) * (1.0 / n))
            }
            Profile::Ultrasonic { n0, n_max, k_r, m } => {
                let h = super::bessel::harmonic(k_r, m, x);
                (n0 + n_max * h.u, h.grad * n_max, h.hessian * n_max)
            }
            Profile::PhasedArray { ref array, omega_t } => array.eval(x, omega_t),
            Profile::Parts(ref parts) => parts[part_at(parts, x)].eval(x),
            Profile::RadialPolynomial {
                n0,
                ref coefficients,
            } => {
                let q = x.x * x.x + x.y * x.y;
                let (mut f, mut f1, mut f2) = (n0, 0.0, 0.0);
                // q^{k-2}, q^{k-1} as k runs up
                let (mut qm2, mut qm1) = (0.0, 1.0);
                for (i, c) in coefficients.iter().enumerate() {
                    let k = (i + 1) as f64;
                    f += c * qm1 * q;
                    f1 += k * c * qm1;
                    f2 += k * (k - 1.0) * c * qm2;
                    (qm2, qm1) = (qm1, qm1 * q);
                }
                quadratic((f, f1, f2), DVec3::new(1.0, 1.0, 0.0), x)
            }
            Profile::SphericalPolynomial {
                n0,
                ref coefficients,
            } => {
                let r = x.length();
                let (mut f, mut f1, mut f2) = (n0, 0.0, 0.0);
                // r^{k-2}, r^{k-1} as k runs up (r^{-1} never used: its factor k − 1 is 0)
                let (mut rm2, mut rm1) = (0.0, 1.0);
                for (i, c) in coefficients.iter().enumerate() {
                    let k = (i + 1) as f64;
                    f += c * rm1 * r;
                    f1 += k * c * rm1;
                    f2 += k * (k - 1.0) * c * rm2;
                    (rm2, rm1) = (rm1, rm1 * r);
                }
                if r < 1e-12 {
                    // the centre: smooth when c1 = 0 (∇²n → 2 c2 I); a cone point otherwise
                    return (n0, DVec3::ZERO, DMat3::from_diagonal(DVec3::splat(f2)));
                }
                let e = x / r;
                let perp = DMat3::IDENTITY - outer(e, e);
                (f, e * f1, outer(e, e) * f2 + perp * (f1 / r))
            }
            Profile::SechFibre { n0, alpha } => {
                let rho = (x.x * x.x + x.y * x.y).sqrt();
                let t = alpha * rho;
                let sech = 1.0 / t.cosh();
                let n = n0 * sech;
                // dn/dρ = −n0 α sech tanh; d²n/dρ² = n0 α² sech (1 − 2 sech²)
                let d1 = -n0 * alpha * sech * t.tanh();
                let d2 = n0 * alpha * alpha * sech * (1.0 - 2.0 * sech * sech);
                if rho < 1e-12 {
                    return (
                        n,
                        DVec3::ZERO,
                        DMat3::from_diagonal(DVec3::new(d2, d2, 0.0)),
                    );
                }
                let e = DVec3::new(x.x / rho, x.y / rho, 0.0);
                let perp = DMat3::from_diagonal(DVec3::new(1.0, 1.0, 0.0)) - outer(e, e);
                (n, e * d1, outer(e, e) * d2 + perp * (d1 / rho))
            }
        }
    }
}

/// Where a profile applies; outside it `n = n_out`. Analytic regions are centred at the origin.
#[derive(Clone, Debug, PartialEq)]
pub enum Bounds {
    Everywhere,
    Sphere {
        radius: f64,
    },
    /// Cylinder about the z axis, `|z| ≤ half_length`.
    Cylinder {
        radius: f64,
        half_length: f64,
    },
    Box {
        half: DVec3,
    },
    /// Any closed shape, by its signed distance on a grid (paper 002, Sec. 5).
    Sdf(Arc<SdfGrid>),
    /// Several disjoint volumes, each placed at its centre: the region is their union (not
    /// convex: a ray leaving one part may enter another).
    Parts(Arc<[Part]>),
}

impl Bounds {
    pub fn contains(&self, x: DVec3) -> bool {
        match *self {
            Bounds::Everywhere => true,
            Bounds::Sphere { radius } => x.length_squared() <= radius * radius,
            Bounds::Cylinder {
                radius,
                half_length,
            } => x.x * x.x + x.y * x.y <= radius * radius && x.z.abs() <= half_length,
            Bounds::Box { half } => x.abs().cmple(half).all(),
            Bounds::Sdf(ref g) => g.contains(x),
            Bounds::Parts(ref parts) => parts.iter().any(|p| p.shape.contains(x - p.center)),
        }
    }

    /// Whether `x` is inside, and then its [`Bounds::clearance`] (one evaluation of a grid's
    /// distance for both).
    #[inline]
    pub fn inside_clearance(&self, x: DVec3) -> Option<f64> {
        match *self {
            Bounds::Sdf(ref g) => g.inside_clearance(x),
            Bounds::Parts(ref parts) => parts
                .iter()
                .find_map(|p| p.shape.inside_clearance(x - p.center)),
            _ => self.contains(x).then(|| self.clearance(x)),
        }
    }

    /// A lower bound on the distance from `x` (inside) to the surface: how far a ray from `x` may
    /// run before it needs the inside–outside test again (infinite for `Everywhere`).
    #[inline]
    pub fn clearance(&self, x: DVec3) -> f64 {
        match *self {
            Bounds::Everywhere => f64::INFINITY,
            Bounds::Sphere { radius } => radius - x.length(),
            Bounds::Cylinder {
                radius,
                half_length,
            } => (radius - x.x.hypot(x.y)).min(half_length - x.z.abs()),
            Bounds::Box { half } => (half - x.abs()).min_element(),
            Bounds::Sdf(ref g) => g.clearance(x),
            // the parts are disjoint: the surface nearest a point inside one is that part's
            Bounds::Parts(ref parts) => {
                let p = &parts[part_at(parts, x)];
                p.shape.clearance(x - p.center)
            }
        }
    }

    /// Whether a straight line meets the region in one stretch at most (all but signed-distance
    /// shapes): a ray that has left it cannot come back.
    pub fn is_convex(&self) -> bool {
        match self {
            Bounds::Sdf(_) => false,
            Bounds::Parts(parts) => parts.len() == 1 && parts[0].shape.is_convex(),
            _ => true,
        }
    }

    /// The parts of a region made of several ([`Bounds::Parts`]).
    pub fn parts(&self) -> Option<&[Part]> {
        match self {
            Bounds::Parts(parts) => Some(parts),
            _ => None,
        }
    }

    /// The parameter where `o + t w` (unit `w`, `o` inside) leaves the region.
    pub fn exit(&self, o: DVec3, w: DVec3) -> Option<f64> {
        match self {
            Bounds::Sdf(g) => g.exit(o, w),
            Bounds::Parts(parts) => {
                let p = &parts[part_at(parts, o)];
                p.shape.exit(o - p.center, w)
            }
            _ => self.interval(o, w).map(|(_, t1)| t1),
        }
    }

    /// Where the straight ray from `x` along unit `d`, which has just left the region at `x`,
    /// enters it again (never for convex regions).
    pub fn reentry(&self, x: DVec3, d: DVec3) -> Option<f64> {
        if let Bounds::Parts(parts) = self {
            // the nearest part ahead: a convex one only if it starts past round-off of the
            // surface just left (which a convex part left has behind it or at the start)
            return parts
                .iter()
                .filter_map(|p| {
                    let local = x - p.center;
                    if !p.shape.is_convex() {
                        return p.shape.reentry(local, d);
                    }
                    let size = p.shape.half_extent().map_or(1.0, |h| h.max_element());
                    let skip = 1e-9 * (size + local.length());
                    p.shape
                        .interval(local, d)
                        .and_then(|(t0, _)| (t0 > skip).then_some(t0))
                })
                .min_by(f64::total_cmp);
        }
        let Bounds::Sdf(g) = self else {
            return None;
        };
        // start past the surface it left, by a small fraction of the grid spacing
        let skip = 1e-6 * g.grid().spacing;
        g.entry(x + d * skip, d).map(|t0| t0 + skip)
    }

    /// Half extents of the bounding box of the region (`None` for `Everywhere`).
    pub fn half_extent(&self) -> Option<DVec3> {
        match *self {
            Bounds::Everywhere => None,
            Bounds::Sphere { radius } => Some(DVec3::splat(radius)),
            Bounds::Cylinder {
                radius,
                half_length,
            } => Some(DVec3::new(radius, radius, half_length)),
            Bounds::Box { half } => Some(half),
            Bounds::Sdf(ref g) => {
                let (lo, hi) = g.corners();
                Some(lo.abs().max(hi.abs()))
            }
            Bounds::Parts(ref parts) => parts
                .iter()
                .map(|p| p.shape.half_extent().map(|h| p.center.abs() + h))
                .try_fold(DVec3::ZERO, |acc, h| h.map(|h| acc.max(h))),
        }
    }

    /// Outward unit normal of the surface nearest to `x` (a point on or near it); `None` for
    /// `Everywhere`.
    pub fn normal(&self, x: DVec3) -> Option<DVec3> {
        match *self {
            Bounds::Everywhere => None,
            Bounds::Sphere { .. } => Some(x.normalize()),
            Bounds::Cylinder {
                radius,
                half_length,
            } => {
                let rho = (x.x * x.x + x.y * x.y).sqrt();
                Some(
                    if (x.z.abs() - half_length) > (rho - radius) || rho == 0.0 {
                        DVec3::Z * x.z.signum()
                    } else {
                        DVec3::new(x.x / rho, x.y / rho, 0.0)
                    },
                )
            }
            Bounds::Box { half } => {
                let r = x / half;
                let a = r.abs().max_position();
                let mut n = DVec3::ZERO;
                n[a] = r[a].signum();
                Some(n)
            }
            Bounds::Sdf(ref g) => Some(g.normal(x)),
            Bounds::Parts(ref parts) => {
                let p = &parts[part_at(parts, x)];
                p.shape.normal(x - p.center)
            }
        }
    }

    /// Entry and exit parameters of the ray `o + t w` (unit `w`), if it meets the region.
    pub fn interval(&self, o: DVec3, w: DVec3) -> Option<(f64, f64)> {
        match *self {
            Bounds::Everywhere => Some((f64::NEG_INFINITY, f64::INFINITY)),
            Bounds::Sphere { radius } => {
                let b = o.dot(w);
                let c = o.length_squared() - radius * radius;
                let disc = b * b - c;
                (disc > 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
            }
            Bounds::Box { half } => crate::medium::Geometry::Box { half }.ray_interval(o, w),
            Bounds::Cylinder {
                radius,
                half_length,
            } => {
                let (a, b, c) = (
                    w.x * w.x + w.y * w.y,
                    o.x * w.x + o.y * w.y,
                    o.x * o.x + o.y * o.y - radius * radius,
                );
                let (mut t0, mut t1) = if a < 1e-300 {
                    if c > 0.0 {
                        return None;
                    }
                    (f64::NEG_INFINITY, f64::INFINITY)
                } else {
                    let disc = b * b - a * c;
                    if disc <= 0.0 {
                        return None;
                    }
                    ((-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a)
                };
                if w.z != 0.0 {
                    let (za, zb) = ((-half_length - o.z) / w.z, (half_length - o.z) / w.z);
                    t0 = t0.max(za.min(zb));
                    t1 = t1.min(za.max(zb));
                } else if o.z.abs() > half_length {
                    return None;
                }
                (t0 < t1).then_some((t0, t1))
            }
            Bounds::Sdf(ref g) => g.interval(o, w),
            // the part the ray is in, or the first it meets
            Bounds::Parts(ref parts) => parts
                .iter()
                .filter_map(|p| p.shape.interval(o - p.center, w))
                .filter(|&(_, t1)| t1 > 0.0)
                .min_by(|a, b| a.0.total_cmp(&b.0)),
        }
    }
}

/// A bounded analytic field, optionally the sum of a background and perturbations (`n = Σ n_i`
/// inside, each profile contributing its value).
#[derive(Clone, Debug, PartialEq)]
pub struct BoundedField {
    pub profiles: Vec<Profile>,
    pub bounds: Bounds,
    pub n_out: f64,
    /// Inside, `n = offset + scale · Σ profiles`: 1 and 0 except in a dispersive render, which
    /// maps the field given at a reference wavelength to each photon's wavelength (the parameter
    /// derivatives of [`Profile::dparam`] are of the profiles alone).
    pub scale: f64,
    pub offset: f64,
}

impl BoundedField {
    pub fn new(profiles: Vec<Profile>, bounds: Bounds, n_out: f64) -> Self {
        BoundedField {
            profiles,
            bounds,
            n_out,
            scale: 1.0,
            offset: 0.0,
        }
    }

    pub fn single(profile: Profile, bounds: Bounds, n_out: f64) -> Self {
        Self::new(vec![profile], bounds, n_out)
    }

    /// The work of one evaluation of `(n, ∇n, ∇²n)` inside the bounds, in evaluations of a
    /// simple analytic profile (for time estimates): an ultrasonic profile sums as many plane
    /// waves as its Bessel argument needs at the bounds' widest radius, a grid its taps.
    pub fn evaluation_cost(&self) -> f64 {
        let radius = self
            .bounds
            .half_extent()
            .map_or(0.0, |h| (h.x * h.x + h.y * h.y).sqrt());
        profiles_cost(&self.profiles, radius)
    }
}

/// [`BoundedField::evaluation_cost`] of `profiles` within `radius` of the axis.
fn profiles_cost(profiles: &[Profile], radius: f64) -> f64 {
    profiles
        .iter()
        .map(|p| match p {
            Profile::Ultrasonic { k_r, m, .. } => {
                super::bessel::nodes(k_r.abs() * radius, *m) as f64
            }
            // an element's four Bessel functions cost a few simple profiles
            Profile::PhasedArray { array, .. } => 4.0 * array.elements.len() as f64,
            Profile::Grid(g) => match g.interp {
                super::grid::Interp::Tricubic => 64.0,
                super::grid::Interp::Trilinear => 8.0,
            },
            // finding the part, then its own profiles
            Profile::Parts(parts) => parts
                .iter()
                .map(|part| {
                    let r = part.shape.half_extent().map_or(0.0, |h| h.x.hypot(h.y));
                    parts.len() as f64 * 0.5 + profiles_cost(&part.profiles, r)
                })
                .fold(0.0, f64::max),
            _ => 1.0,
        })
        .sum()
}

impl IndexField for BoundedField {
    fn n(&self, x: DVec3) -> f64 {
        if !self.bounds.contains(x) {
            return self.n_out;
        }
        self.offset + self.scale * self.profiles.iter().map(|p| p.eval(x).0).sum::<f64>()
    }
    fn grad(&self, x: DVec3) -> DVec3 {
        if !self.bounds.contains(x) {
            return DVec3::ZERO;
        }
        self.scale * self.profiles.iter().map(|p| p.eval(x).1).sum::<DVec3>()
    }
    fn hessian(&self, x: DVec3) -> DMat3 {
        if !self.bounds.contains(x) {
            return DMat3::ZERO;
        }
        self.scale
            * self
                .profiles
                .iter()
                .fold(DMat3::ZERO, |acc, p| acc + p.eval(x).2)
    }
    #[inline]
    fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        if !self.bounds.contains(x) {
            return (self.n_out, DVec3::ZERO, DMat3::ZERO);
        }
        self.eval_inside(x)
    }
}

/// Bounds on `|∇n|` and on `n` (below and above) over the box `|x_i| ≤ half_i` of the sum of
/// `profiles` mapped as `offset + scale · Σ`, where each profile gives them in closed form
/// (constant, linear, polynomial and ultrasonic profiles); `None` otherwise.
fn slope_and_range(
    profiles: &[Profile],
    half: DVec3,
    scale: f64,
    offset: f64,
) -> Option<(f64, f64, f64)> {
    if scale <= 0.0 {
        return None;
    }
    // Σ_k |c_k| k t^{k-1} and Σ_k |c_k| t^k of a polynomial in t ≥ 0 without its constant
    let polynomial = |c: &[f64], t: f64| {
        c.iter()
            .enumerate()
            .fold((0.0, 0.0), |(slope, size), (i, c)| {
                let k = (i + 1) as i32;
                (
                    slope + c.abs() * f64::from(k) * t.powi(k - 1),
                    size + c.abs() * t.powi(k),
                )
            })
    };
    let (radius, rho) = (half.length(), half.x.hypot(half.y));
    // each profile: its slope bound, its value at the centre, how far it strays from that
    let mut bounds = profiles.iter().map(|p| match *p {
        Profile::Constant { n } => Some((0.0, n, 0.0)),
        Profile::Linear { n0, gradient } => Some((gradient.length(), n0, gradient.abs().dot(half))),
        Profile::SphericalPolynomial {
            n0,
            ref coefficients,
        } => {
            let (slope, size) = polynomial(coefficients, radius);
            Some((slope, n0, size))
        }
        // in q = ρ²: |dn/dρ| = 2ρ |dn/dq|
        Profile::RadialPolynomial {
            n0,
            ref coefficients,
        } => {
            let (slope, size) = polynomial(coefficients, rho * rho);
            Some((2.0 * rho * slope, n0, size))
        }
        // |∇(J_m(k r) cos mφ)|² ≤ k² (J_m'² + (m J_m / k r)²) = k² (J_{m−1}² + J_{m+1}²)/2 ≤ k²
        Profile::Ultrasonic { n0, n_max, k_r, .. } => Some(((n_max * k_r).abs(), n0, n_max.abs())),
        _ => None,
    });
    let (slope, centre, spread) = bounds.try_fold((0.0, 0.0, 0.0), |(g, n, d), b| {
        b.map(|(bg, bn, bd)| (g + bg, n + bn, d + bd))
    })?;
    Some((
        scale * slope,
        offset + scale * (centre - spread),
        offset + scale * (centre + spread),
    ))
}

/// `θ₁`, the least root of `θ cos θ = bend`: how far a ray of curvature at most `κ` may have
/// turned while it stays in a region of diameter `D`, `bend = κ D` (see
/// [`BoundedField::start_cone`]); `None` past 0.5 (the root nears the hump of `θ cos θ`, 0.561
/// at θ = 0.86, where no cone narrower than a hemisphere is proved).
pub fn turning_angle(bend: f64) -> Option<f64> {
    if !(bend.is_finite() && (0.0..=0.5).contains(&bend)) {
        return None;
    }
    // the fixed point θ ← κD / cos θ, a contraction there
    let mut theta = bend;
    for _ in 0..200 {
        let next = bend / theta.cos();
        if (next - theta).abs() < 1e-12 {
            break;
        }
        theta = next;
    }
    Some(theta)
}

impl BoundedField {
    /// A bound on how much a ray turns inside the region it starts in (the volume, or the
    /// part of several holding `x`): `(κ, D)`, the ray's curvature `|∇n − (∇n·t)t|/n` at most
    /// `κ = max|∇n| / min n` and the region within a box of diagonal `D`. `None` where the
    /// profiles give no closed-form bound (see [`Self::start_cone`]).
    pub fn turning_bound(&self, x: DVec3) -> Option<(f64, f64)> {
        let (half, (slope, floor, _)) = self.region_bounds(x)?;
        (floor > 0.0).then_some((slope / floor, 2.0 * half.length()))
    }

    /// `max|∇n|`, `min n` and `max n` over the bounding box of the region holding `x` (the
    /// volume, or its part of several), where the profiles bound them in closed form.
    pub fn index_bounds(&self, x: DVec3) -> Option<(f64, f64, f64)> {
        self.region_bounds(x).map(|(_, bounds)| bounds)
    }

    /// The half extents of the bounding box of the region holding `x` (in its own frame) and
    /// [`Self::index_bounds`] over it.
    fn region_bounds(&self, x: DVec3) -> Option<(DVec3, (f64, f64, f64))> {
        let (profiles, half, scale, offset) = match self.bounds.parts() {
            Some(parts) => {
                let part = &parts[part_at(parts, x)];
                let scale = self.scale * part.scale;
                let offset = self.offset + self.scale * part.offset;
                (&part.profiles[..], part.shape.half_extent()?, scale, offset)
            }
            None => (
                &self.profiles[..],
                self.bounds.half_extent()?,
                self.scale,
                self.offset,
            ),
        };
        Some((half, slope_and_range(profiles, half, scale, offset)?))
    }

    /// The half-angle of a cone about the chord from `x` to any point of its region that holds
    /// the initial direction of every ray from `x` to that point staying inside the region;
    /// `None` where no such cone narrower than a hemisphere is proved.
    ///
    /// A ray of curvature at most `κ` has turned by at most `κ s` after a length `s`; while it
    /// has turned by less than `θ` it advances along its initial direction by at least
    /// `s cos θ`, which the region's diameter `D` bounds. So a ray inside the region never
    /// turns by `θ₁`, the least root of `θ cos θ = κ D` ([`turning_angle`]), and the chord of
    /// any of its stretches, the mean of its directions, lies within `θ₁` of where it started.
    pub fn start_cone(&self, x: DVec3) -> Option<f64> {
        let (kappa, diameter) = self.turning_bound(x)?;
        turning_angle(kappa * diameter)
    }
}

impl BoundedField {
    /// Change each part of a field of several with `change(k, part)` (their shapes must stay):
    /// the parts are copied once if another field shares them, and changed in place after that.
    pub fn change_parts(&mut self, mut change: impl FnMut(usize, &mut Part)) {
        let [Profile::Parts(parts)] = self.profiles.as_mut_slice() else {
            return;
        };
        // the bounds hold the same parts: let go of them so that a field of its own is not copied
        self.bounds = Bounds::Everywhere;
        for (k, p) in Arc::make_mut(parts).iter_mut().enumerate() {
            change(k, p);
        }
        self.bounds = Bounds::Parts(parts.clone());
    }

    /// `(n, ∇n)` at `x` (what ray tracing needs): the same bits as [`IndexField::eval`]'s first two.
    #[inline(always)]
    pub fn value_grad(&self, x: DVec3) -> (f64, DVec3) {
        if !self.bounds.contains(x) {
            return (self.n_out, DVec3::ZERO);
        }
        self.value_grad_inside(x)
    }

    /// [`Self::value_grad`] at `L` points at once: a single grid profile evaluates them side by
    /// side in vector lanes ([`super::grid::GridField::value_grad_lanes`]); each point gets the
    /// bits of [`Self::value_grad`].
    #[inline(always)]
    pub fn value_grad_lanes<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3); L] {
        if L == 1 {
            // one point: the scalar path (the same bits, and faster alone)
            return [self.value_grad(x[0]); L];
        }
        if let ([Profile::Grid(grid)], 1.0, 0.0) =
            (self.profiles.as_slice(), self.scale, self.offset)
            && x.iter().all(|&x| self.bounds.contains(x))
        {
            return grid.value_grad_lanes(x);
        }
        x.map(|x| self.value_grad(x))
    }

    /// [`IndexField::eval`] at `L` points at once, as [`Self::value_grad_lanes`].
    #[inline(always)]
    pub fn eval_lanes<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3, DMat3); L] {
        if L == 1 {
            return [self.eval(x[0]); L];
        }
        if let ([Profile::Grid(grid)], 1.0, 0.0) =
            (self.profiles.as_slice(), self.scale, self.offset)
            && x.iter().all(|&x| self.bounds.contains(x))
        {
            return grid.eval_lanes(x);
        }
        x.map(|x| self.eval(x))
    }

    /// [`Self::value_grad`] at `x` known to be inside the bounds.
    #[inline(always)]
    pub fn value_grad_inside(&self, x: DVec3) -> (f64, DVec3) {
        if let ([Profile::Grid(grid)], 1.0, 0.0) =
            (self.profiles.as_slice(), self.scale, self.offset)
        {
            return grid.value_grad(x);
        }
        let (n, g) = self.profiles.iter().fold((0.0, DVec3::ZERO), |(n, g), p| {
            let (pn, pg) = p.value_grad(x);
            (n + pn, g + pg)
        });
        if self.scale == 1.0 && self.offset == 0.0 {
            return (n, g);
        }
        (self.offset + self.scale * n, g * self.scale)
    }

    /// `(n, ∇n, ∇²n)` at `x` known to be inside the bounds (no inside–outside test: free flights
    /// that have proved it by the bounds' clearance skip it).
    #[inline]
    pub fn eval_inside(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        // one grid (a design): straight to its kernel, past the general profile dispatch
        if let ([Profile::Grid(grid)], 1.0, 0.0) =
            (self.profiles.as_slice(), self.scale, self.offset)
        {
            return grid.eval(x);
        }
        mapped_sum(&self.profiles, x, self.scale, self.offset)
    }
}

impl Profile {
    /// A mutable reference to analytic parameter `which` (numbering as in [`Profile::dparam`]).
    pub fn param_mut(&mut self, which: usize) -> Option<&mut f64> {
        match (self, which) {
            (Profile::Constant { n }, 0) => Some(n),
            (Profile::Linear { n0, .. }, 0) => Some(n0),
            (Profile::Linear { gradient, .. }, k @ 1..=3) => Some(&mut gradient[k - 1]),
            (Profile::Luneburg { radius }, 0) | (Profile::MaxwellFishEye { radius }, 0) => {
                Some(radius)
            }
            (Profile::ParabolicFibre { n0, .. }, 0) | (Profile::SechFibre { n0, .. }, 0) => {
                Some(n0)
            }
            (Profile::ParabolicFibre { alpha, .. }, 1) | (Profile::SechFibre { alpha, .. }, 1) => {
                Some(alpha)
            }
            (Profile::Ultrasonic { n0, .. }, 0)
            | (Profile::RadialPolynomial { n0, .. }, 0)
            | (Profile::SphericalPolynomial { n0, .. }, 0) => Some(n0),
            (Profile::RadialPolynomial { coefficients, .. }, k)
            | (Profile::SphericalPolynomial { coefficients, .. }, k)
                if k >= 1 =>
            {
                coefficients.get_mut(k - 1)
            }
            (Profile::Ultrasonic { n_max, .. }, 1) => Some(n_max),
            (Profile::Ultrasonic { k_r, .. }, 2) => Some(k_r),
            (Profile::Grid(g), k) => g.coef.get_mut(k),
            (Profile::PhasedArray { array, .. }, k) => Arc::make_mut(array).param_mut(k),
            (Profile::SdfLuneburg { n_surface, .. }, 0) => Some(n_surface),
            (Profile::SdfLuneburg { n_core, .. }, 1) => Some(n_core),
            (Profile::SdfLuneburg { depth, .. }, 2) => Some(depth),
            _ => None,
        }
    }

    /// Parameter `which` by name, for configs and messages (grids have no named parameters).
    pub fn param_index(&self, name: &str) -> Option<usize> {
        let names: &[&str] = match self {
            Profile::Constant { .. } => &["n"],
            Profile::Linear { .. } => &["n0", "gx", "gy", "gz"],
            Profile::Luneburg { .. } | Profile::MaxwellFishEye { .. } => &["radius"],
            Profile::ParabolicFibre { .. } | Profile::SechFibre { .. } => &["n0", "alpha"],
            Profile::Ultrasonic { .. } => &["n0", "n_max", "k_r"],
            Profile::RadialPolynomial { coefficients, .. }
            | Profile::SphericalPolynomial { coefficients, .. } => {
                return match name {
                    "n0" => Some(0),
                    _ => name
                        .strip_prefix('c')
                        .and_then(|k| k.parse::<usize>().ok())
                        .filter(|k| (1..=coefficients.len()).contains(k)),
                };
            }
            Profile::Grid(_) => &[],
            Profile::PhasedArray { array, .. } => return array.param_index(name),
            Profile::SdfLuneburg { .. } => &["n_surface", "n_core", "depth"],
            Profile::Parts(_) => &[],
        };
        names.iter().position(|n| *n == name)
    }
}

impl Profile {
    /// `(∂n/∂θ, ∇(∂n/∂θ))` for analytic parameter `which` of this profile, or `None` if not
    /// differentiable here. Parameters: Constant `[n]`; Linear `[n0, gx, gy, gz]`; Luneburg `[R]`;
    /// Maxwell fish-eye `[R]`; parabolic and sech fibres `[n0, α]`; ultrasonic
    /// `[n0, n_max, k_r]`; radial and spherical polynomials `[n0, c1, c2, …]`; phased array
    /// `[n0, gain, frequency, amplitude_0, phase_0, x_0, y_0, amplitude_1, …]`; grid: coefficient
    /// index.
    pub fn dparam(&self, x: DVec3, which: usize) -> Option<(f64, DVec3)> {
        let eval = || self.eval(x);
        match (self, which) {
            (Profile::Constant { .. }, 0) => Some((1.0, DVec3::ZERO)),
            (Profile::Linear { .. }, 0) => Some((1.0, DVec3::ZERO)),
            (Profile::Linear { .. }, k @ 1..=3) => {
                let mut e = DVec3::ZERO;
                e[k - 1] = 1.0;
                Some((x[k - 1], e))
            }
            (Profile::Luneburg { radius }, 0) => {
                let (n, grad, _) = eval();
                let r3 = radius.powi(3);
                let r2 = x.length_squared();
                let d = r2 / r3 / n;
                Some((d, x * (2.0 / r3 / n) - grad * (d / n)))
            }
            (Profile::MaxwellFishEye { radius }, 0) => {
                let (r3, q) = (radius.powi(3), x.length_squared() / (radius * radius));
                let r2 = x.length_squared();
                let d = 4.0 * r2 / (r3 * (1.0 + q).powi(2));
                let dq = x * (2.0 / (radius * radius));
                Some((
                    d,
                    (x * 2.0 / (1.0 + q).powi(2) - dq * (2.0 * r2 / (1.0 + q).powi(3)))
                        * (4.0 / r3),
                ))
            }
            (Profile::ParabolicFibre { n0, .. }, 0) | (Profile::SechFibre { n0, .. }, 0) => {
                let (n, grad, _) = eval();
                Some((n / n0, grad / *n0))
            }
            (Profile::Grid(g), k) if k < g.coef.len() => Some(g.dcoef(x, k)),
            (Profile::PhasedArray { array, omega_t }, k) => array.dparam(x, *omega_t, k),
            (
                Profile::SdfLuneburg {
                    sdf,
                    n_surface,
                    n_core,
                    depth,
                },
                k @ 0..=2,
            ) => {
                // ∂n/∂θ = (∂N/∂θ)/(2n); its gradient (∇∂N/∂θ)/(2n) − (∂N/∂θ) ∇n/(2n²)
                let (n, grad, _) = eval();
                let (d, dd, _) = sdf.eval(x);
                let (u, q, q1, q2) = depth_grading(d, *depth);
                let gu = dd * (-1.0 / depth);
                let b = n_core * n_core - n_surface * n_surface;
                let (dn2, grad_dn2) = match k {
                    0 => (2.0 * n_surface * (1.0 - q), gu * (-2.0 * n_surface * q1)),
                    1 => (2.0 * n_core * q, gu * (2.0 * n_core * q1)),
                    // ∂u/∂depth = −u/depth, ∇(∂u/∂depth) = −∇u/depth
                    _ => (-b * q1 * u / depth, gu * (-b * (q2 * u + q1) / depth)),
                };
                Some((
                    dn2 / (2.0 * n),
                    grad_dn2 / (2.0 * n) - grad * (dn2 / (2.0 * n * n)),
                ))
            }
            (Profile::Ultrasonic { .. }, 0)
            | (Profile::RadialPolynomial { .. }, 0)
            | (Profile::SphericalPolynomial { .. }, 0) => Some((1.0, DVec3::ZERO)),
            (Profile::SphericalPolynomial { coefficients, .. }, k) if k <= coefficients.len() => {
                // ∂n/∂c_k = r^k, ∇ = k r^{k−2} x (0 at the centre)
                let r = x.length();
                let g = if r > 0.0 {
                    k as f64 * r.powi(k as i32 - 2)
                } else {
                    0.0
                };
                Some((r.powi(k as i32), x * g))
            }
            (Profile::RadialPolynomial { coefficients, .. }, k) if k <= coefficients.len() => {
                // ∂n/∂c_k = ρ^{2k}, ∇ = 2k ρ^{2k−2} (x, y, 0)
                let q = x.x * x.x + x.y * x.y;
                let g = 2.0 * k as f64 * q.powi(k as i32 - 1);
                Some((q.powi(k as i32), DVec3::new(x.x * g, x.y * g, 0.0)))
            }
            (Profile::Ultrasonic { k_r, m, .. }, 1) => {
                let h = super::bessel::harmonic(*k_r, *m, x);
                Some((h.u, h.grad))
            }
            (Profile::Ultrasonic { n_max, k_r, m, .. }, 2) => {
                let h = super::bessel::harmonic(*k_r, *m, x);
                Some((h.du_dk * n_max, h.dgrad_dk * n_max))
            }
            (Profile::SechFibre { n0, alpha }, 1) => {
                // ∂n/∂α = −n0 ρ sech(t) tanh(t), t = αρ; d/dρ of it = −n0 sech (tanh + t(sech² − tanh²))
                let rho = (x.x * x.x + x.y * x.y).sqrt();
                let t = alpha * rho;
                let (sech, tanh) = (1.0 / t.cosh(), t.tanh());
                let d = -n0 * rho * sech * tanh;
                let dd = -n0 * sech * (tanh + t * (sech * sech - tanh * tanh));
                let e = if rho > 0.0 {
                    DVec3::new(x.x / rho, x.y / rho, 0.0)
                } else {
                    DVec3::ZERO
                };
                Some((d, e * dd))
            }
            (Profile::ParabolicFibre { n0, alpha }, 1) => {
                let n = eval().0;
                let rho2 = x.x * x.x + x.y * x.y;
                let s = n / n0;
                let perp = DVec3::new(x.x, x.y, 0.0);
                let ds = -perp * (alpha * alpha / s);
                Some((
                    -n0 * alpha * rho2 / s,
                    -(perp * 2.0 / s - ds * (rho2 / (s * s))) * (n0 * alpha),
                ))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One instance of every analytic profile, with parameters away from special values.
    fn analytic_profiles() -> Vec<Profile> {
        vec![
            Profile::Constant { n: 1.4 },
            Profile::Linear {
                n0: 1.3,
                gradient: DVec3::new(0.1, -0.2, 0.05),
            },
            Profile::Luneburg { radius: 1.5 },
            Profile::MaxwellFishEye { radius: 0.8 },
            Profile::ParabolicFibre {
                n0: 1.5,
                alpha: 0.4,
            },
            Profile::SechFibre {
                n0: 1.5,
                alpha: 0.7,
            },
            Profile::Ultrasonic {
                n0: 1.33,
                n_max: 0.01,
                k_r: 4.0,
                m: 2,
            },
            Profile::RadialPolynomial {
                n0: 1.5,
                coefficients: vec![-0.2, 0.05, -0.01],
            },
            Profile::SphericalPolynomial {
                n0: 1.62,
                coefficients: vec![-0.1, 0.04, -0.02],
            },
            Profile::PhasedArray {
                // excursions of a few hundredths, so differences resolve every parameter
                array: Arc::new(crate::eikonal::acoustic::PhasedArray {
                    n0: 1.33,
                    piezo_optic: 0.01,
                    ultrasound: crate::eikonal::acoustic::Ultrasound {
                        frequency: 1e6,
                        sound_speed: 1500.0,
                        attenuation: 3e-5,
                        unit: 1e-3,
                    },
                    reference: 1.0,
                    gain: 1.3,
                    elements: vec![
                        crate::eikonal::acoustic::Element {
                            x: 3.0,
                            y: 1.0,
                            amplitude: 2.0,
                            phase: 0.4,
                        },
                        crate::eikonal::acoustic::Element {
                            x: -2.0,
                            y: -4.0,
                            amplitude: 1.5,
                            phase: -1.2,
                        },
                    ],
                }),
                omega_t: 0.7,
            },
            Profile::SdfLuneburg {
                // 0.085: the test point stays off the grid's cell faces, where the Hessian is
                // only continuous (B-splines are C²) and differences of the gradient lose order
                sdf: sampled_sphere(0.085),
                n_surface: 1.1,
                n_core: 1.5,
                depth: 0.8,
            },
        ]
    }

    /// Where a profile bounds `|∇n|` and `n` over a box in closed form (what the cone of a
    /// connection's starts rests on), the bounds hold at every point drawn in the box, and are
    /// within a factor of the largest slope and the lowest index found there.
    #[test]
    fn slope_and_range_bound_the_field_in_a_box() {
        let half = DVec3::new(1.0, 0.8, 1.2);
        let mut rng = crate::math::stream_rng(4, 0);
        let mut bounded = Vec::new();
        for p in analytic_profiles() {
            let Some((slope, floor, ceil)) =
                slope_and_range(std::slice::from_ref(&p), half, 1.0, 0.0)
            else {
                continue;
            };
            let (mut steepest, mut lowest, mut highest) = (0.0f64, f64::INFINITY, 0.0f64);
            for _ in 0..20_000 {
                let u = DVec3::ZERO.map(|_| 2.0 * crate::math::uniform(&mut rng) - 1.0);
                let (n, g, _) = p.eval(u * half);
                steepest = steepest.max(g.length());
                lowest = lowest.min(n);
                highest = highest.max(n);
            }
            assert!(
                steepest <= slope * (1.0 + 1e-12),
                "{}: {steepest} > {slope}",
                p.kind()
            );
            assert!(lowest >= floor - 1e-12, "{}: {lowest} < {floor}", p.kind());
            assert!(highest <= ceil + 1e-12, "{}: {highest} > {ceil}", p.kind());
            assert!(
                slope <= 5.0 * steepest + 1e-12,
                "{}: {slope} loose",
                p.kind()
            );
            bounded.push(p.kind());
        }
        let expected = [
            "constant",
            "linear",
            "ultrasonic",
            "radial_polynomial",
            "spherical_polynomial",
        ];
        assert_eq!(bounded, expected);
        // a part of several volumes is bounded over its own shape, in its own frame, mapped
        let linear = Profile::Linear {
            n0: 1.5,
            gradient: DVec3::new(0.0, 0.1, 0.0),
        };
        let block = Bounds::Box { half };
        let mut single = BoundedField::single(linear.clone(), block.clone(), 1.0);
        (single.scale, single.offset) = (1.1, -0.05);
        let mut part = Part::new(block, DVec3::new(5.0, 0.0, 0.0), vec![linear]);
        (part.scale, part.offset) = (1.1, -0.05);
        let glass = vec![Profile::Constant { n: 1.2 }];
        let other = Part::new(Bounds::Sphere { radius: 1.0 }, DVec3::ZERO, glass);
        let parts: Arc<[Part]> = vec![other, part].into();
        let several = BoundedField::new(
            vec![Profile::Parts(parts.clone())],
            Bounds::Parts(parts),
            1.0,
        );
        let expected = (0.11 / (1.1 * (1.5 - 0.08) - 0.05), 2.0 * half.length());
        let near = |(kappa, d): (f64, f64)| {
            (kappa - expected.0).abs() < 1e-15 && (d - expected.1).abs() < 1e-15
        };
        assert!(single.turning_bound(DVec3::ZERO).is_some_and(near));
        assert!(
            several
                .turning_bound(DVec3::new(5.2, 0.3, 0.0))
                .is_some_and(near)
        );
        assert_eq!(
            several.turning_bound(DVec3::ZERO),
            Some((0.0, 2.0 * 3f64.sqrt()))
        );
    }

    /// A unit sphere's signed distance on a grid of `spacing`.
    fn sampled_sphere(spacing: f64) -> Arc<SdfGrid> {
        let shapes = [crate::eikonal::sdf::Shape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        }];
        let tricubic = super::super::grid::Interp::Tricubic;
        Arc::new(SdfGrid::from_shapes(&shapes, 0.0, spacing, tricubic).unwrap())
    }

    /// On a sphere's distance with `depth = R`, `n_s = 1` and `n_c = √2` the depth-graded profile
    /// is the Luneburg lens (to the sampled distance's interpolation error).
    #[test]
    fn sdf_luneburg_on_a_sphere_is_the_luneburg_lens() {
        let graded = Profile::SdfLuneburg {
            sdf: sampled_sphere(0.05),
            n_surface: 1.0,
            n_core: 2f64.sqrt(),
            depth: 1.0,
        };
        let lens = Profile::Luneburg { radius: 1.0 };
        for x in [
            DVec3::new(0.31, -0.22, 0.4),
            DVec3::new(0.0, 0.9, 0.1),
            DVec3::new(-0.5, -0.5, -0.5),
        ] {
            let (a, b) = (graded.eval(x), lens.eval(x));
            assert!((a.0 - b.0).abs() < 1e-4, "n at {x}: {} vs {}", a.0, b.0);
            assert!((a.1 - b.1).length() < 1e-3, "∇n at {x}: {} vs {}", a.1, b.1);
        }
    }

    /// Analytic gradients and Hessians against central differences, for every profile.
    #[test]
    fn derivatives_match_finite_differences() {
        let profiles = analytic_profiles();
        let x = DVec3::new(0.31, -0.22, 0.4);
        let h = 1e-5;
        for p in profiles {
            let (_, g, hs) = p.eval(x);
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = h;
                let fd = (p.eval(x + e).0 - p.eval(x - e).0) / (2.0 * h);
                assert!(
                    (g[a] - fd).abs() < 1e-8,
                    "{p:?} grad[{a}]: {} vs {fd}",
                    g[a]
                );
                let fdg = (p.eval(x + e).1 - p.eval(x - e).1) / (2.0 * h);
                let col = hs.col(a);
                assert!(
                    (col - fdg).length() < 1e-7,
                    "{p:?} hessian col {a}: {col} vs {fdg}"
                );
            }
        }
    }

    /// `Profile::dparam` (value and gradient) against central differences in each parameter, for
    /// every analytic profile and every parameter `param_mut` exposes (per unit change of a
    /// parameter of size up to 1, per relative change of a larger one: a frequency in hertz).
    #[test]
    fn parameter_derivatives_match_finite_differences() {
        let profiles = analytic_profiles();
        let x = DVec3::new(0.31, -0.22, 0.4);
        for p in profiles {
            let mut which = 0;
            while let Some(v) = p.clone().param_mut(which).map(|v| *v) {
                let scale = v.abs().max(1.0);
                let h = 1e-6 * scale;
                let at = |d: f64| {
                    let mut q = p.clone();
                    *q.param_mut(which).unwrap() += d;
                    q.eval(x)
                };
                let (dn, dg) = p.dparam(x, which).expect("differentiable");
                let (dn, dg) = (dn * scale, dg * scale);
                let (up, down) = (at(h), at(-h));
                let fd = (up.0 - down.0) / (2.0 * h) * scale;
                let fdg = (up.1 - down.1) / (2.0 * h) * scale;
                assert!((dn - fd).abs() < 1e-8, "{p:?} param {which}: {dn} vs {fd}");
                assert!(
                    (dg - fdg).length() < 1e-7,
                    "{p:?} param {which} gradient: {dg} vs {fdg}"
                );
                which += 1;
            }
            assert!(which > 0, "{p:?} has no parameters");
        }
    }
}
