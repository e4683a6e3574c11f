//! Volumes bounded by a signed-distance grid (paper 002, Sec. 5): any closed shape, convex or not,
//! given by samples of its signed distance (negative inside) on a regular grid, interpolated
//! tricubically (C², so its gradient is a smooth surface normal) or trilinearly.
//!
//! The distance also says how far a ray may travel before it can reach the surface. Rays are
//! sphere-traced to the surface (Hart 1996) with steps `|d| / L`, `L` a bound on the interpolant's
//! `|∇d|` over a brick of cells and its neighbours (exact: from the differences of its
//! coefficients), and free flights skip the inside–outside test until they have travelled that far
//! (the step skipping of Sec. 5).

use super::grid::{GridField, Interp};
use glam::DVec3;

/// Sphere-tracing steps never shorter than this fraction of the grid spacing (a ray grazing the
/// surface still advances).
const MIN_STEP: f64 = 1e-4;

/// Sphere-tracing steps per crossing before the search gives up (a ray running along the surface).
const MAX_MARCH: usize = 1 << 16;

/// Cells per side of the bricks over which `|∇d|` is bounded (locally, so that the steep ringing
/// of the interpolant at a kink of the distance, e.g. a sphere's centre, does not shorten every
/// step elsewhere).
const BRICK: usize = 4;

/// A shape given by its signed distance on a grid.
#[derive(Clone, PartialEq)]
pub struct SdfGrid {
    grid: GridField,
    /// Bricks of [`BRICK`] cells per side: how many along each axis, and for each the bound on
    /// `|∇d|` over it and its 26 neighbours (x fastest).
    bricks: [usize; 3],
    brick_slope: Vec<f64>,
    /// The bound on the curvature `|wᵀ ∇²d w|` along unit `w` over each brick and its neighbours
    /// (infinite for trilinear grids).
    brick_bend: Vec<f64>,
    /// Corners of a box holding the shape (the nodes within a cell of it, one spacing out).
    lo: DVec3,
    hi: DVec3,
}

impl std::fmt::Debug for SdfGrid {
    /// The grid's layout, not its samples.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SdfGrid")
            .field("origin", &self.grid.origin)
            .field("spacing", &self.grid.spacing)
            .field("dims", &self.grid.dims)
            .field("interp", &self.grid.interp)
            .field("shape_within", &(self.lo, self.hi))
            .finish()
    }
}

impl SdfGrid {
    /// The shape whose signed distance has `samples` at the nodes (x fastest; negative inside).
    /// The shape must lie inside the grid: every sample on the grid's faces is positive.
    pub fn from_samples(
        origin: DVec3,
        spacing: f64,
        dims: [usize; 3],
        samples: Vec<f64>,
        interp: Interp,
    ) -> Result<Self, String> {
        if dims.iter().any(|&d| d < 3) {
            return Err(format!("dims {dims:?}: at least 3 nodes per axis"));
        }
        if samples.len() != dims[0] * dims[1] * dims[2] {
            return Err(format!(
                "{} values given, {}×{}×{} = {} expected",
                samples.len(),
                dims[0],
                dims[1],
                dims[2],
                dims[0] * dims[1] * dims[2]
            ));
        }
        let at = |i: usize, j: usize, k: usize| samples[i + dims[0] * (j + dims[1] * k)];
        let mut inside = false;
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let v = at(i, j, k);
                    if !v.is_finite() {
                        return Err(format!(
                            "the value {v} at node ({i}, {j}, {k}) is not finite"
                        ));
                    }
                    inside |= v < 0.0;
                    let face = [i, j, k]
                        .iter()
                        .zip(dims)
                        .any(|(&m, d)| m == 0 || m == d - 1);
                    if face && v <= 0.0 {
                        return Err(format!(
                            "the value {v} at node ({i}, {j}, {k}) on the grid's faces is not positive: the shape must lie inside the grid, with positive distances all round"
                        ));
                    }
                }
            }
        }
        if !inside {
            return Err("no value is negative: the shape is empty".into());
        }
        let grid = GridField::from_samples(origin, spacing, dims, samples.clone(), interp)
            .map_err(|e| e.to_string())?;
        let (bricks, brick_slope, brick_bend) = brick_bounds(&grid);
        // the shape lies within a cell's half diagonal of nodes whose distance is at most the
        // local slope bound times it (the half diagonal stays within a node's brick neighbours)
        let half_diagonal = spacing * 0.5 * 3f64.sqrt();
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let at_node = [i, j, k];
                    let b = [0, 1, 2].map(|a| (at_node[a] / BRICK).min(bricks[a] - 1));
                    let slope = brick_slope[b[0] + bricks[0] * (b[1] + bricks[1] * b[2])];
                    if at(i, j, k) <= slope * half_diagonal {
                        let x = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                        lo = lo.min(x);
                        hi = hi.max(x);
                    }
                }
            }
        }
        let extent = DVec3::new(
            (dims[0] - 1) as f64,
            (dims[1] - 1) as f64,
            (dims[2] - 1) as f64,
        ) * spacing;
        let pad = DVec3::splat(spacing);
        Ok(SdfGrid {
            grid,
            bricks,
            brick_slope,
            brick_bend,
            lo: (lo - pad).max(origin),
            hi: (hi + pad).min(origin + extent),
        })
    }

    /// Corners of a box holding the shape.
    pub fn corners(&self) -> (DVec3, DVec3) {
        (self.lo, self.hi)
    }

    /// The grid of signed distances.
    pub fn grid(&self) -> &GridField {
        &self.grid
    }

    #[inline]
    fn in_grid(&self, x: DVec3) -> bool {
        x.cmpge(self.lo).all() && x.cmple(self.hi).all()
    }

    /// Whether `x` is inside the shape.
    #[inline]
    pub fn contains(&self, x: DVec3) -> bool {
        self.in_grid(x) && self.grid.value(x) <= 0.0
    }

    /// A lower bound on the distance from `x` (inside) to the surface: how far any path from `x`
    /// may run before it needs testing again.
    #[inline]
    pub fn clearance(&self, x: DVec3) -> f64 {
        self.reach(x, self.grid.value(x))
    }

    /// How far from `x`, where the distance is `d`, the sign of the distance cannot change:
    /// `|d| / L` with `L` bounding `|∇d|` over `x`'s brick and its neighbours, and no farther
    /// than those neighbours reach.
    #[inline]
    fn reach(&self, x: DVec3, d: f64) -> f64 {
        let (brick, room) = self.neighbourhood(x);
        (d.abs() / self.brick_slope[brick]).min(room)
    }

    /// [`SdfGrid::reach`] along a line on which `d` changes at `rate` per unit length: also as
    /// far as `|d| + a t − M t²/2` stays positive, with `a` the rate at which `|d|` grows and `M`
    /// the brick's curvature bound, which is much farther where the line leaves the surface at a
    /// grazing angle (there `|d| / L` grows the steps only by the factor `1 + a/L`).
    #[inline]
    fn reach_along(&self, x: DVec3, d: f64, rate: f64) -> f64 {
        let (brick, room) = self.neighbourhood(x);
        let lipschitz = d.abs() / self.brick_slope[brick];
        let (m, away) = (self.brick_bend[brick], if d <= 0.0 { -rate } else { rate });
        let root = (away * away + 2.0 * m * d.abs()).sqrt();
        // the positive root of |d| + a t − M t²/2, in the form without cancellation; a margin
        // for the rounding of `rate`
        let taylor = if !m.is_finite() {
            0.0
        } else if away > 0.0 {
            (away + root) / m.max(1e-300)
        } else {
            2.0 * d.abs() / (root - away)
        };
        lipschitz.max(0.99 * taylor).min(room)
    }

    /// The brick holding `x` and how far `x` is from the faces of its neighbours.
    #[inline]
    fn neighbourhood(&self, x: DVec3) -> (usize, f64) {
        let u = (x - self.grid.origin) / (self.grid.spacing * BRICK as f64);
        let mut index = 0;
        let mut room = f64::INFINITY;
        for a in (0..3).rev() {
            let b = (super::grid::floor(u[a]).max(0.0) as usize).min(self.bricks[a] - 1);
            index = index * self.bricks[a] + b;
            // to the faces of the neighbourhood: one brick beyond this brick's faces
            let f = u[a] - b as f64;
            room = room.min((f + 1.0).min(2.0 - f));
        }
        (index, room.max(0.0) * self.grid.spacing * BRICK as f64)
    }

    /// Whether `x` is inside, and then its [`SdfGrid::clearance`].
    #[inline]
    pub fn inside_clearance(&self, x: DVec3) -> Option<f64> {
        if !self.in_grid(x) {
            return None;
        }
        let d = self.grid.value(x);
        (d <= 0.0).then(|| self.reach(x, d))
    }

    /// The outward unit normal at `x` (on or near the surface): `∇d / |∇d|`.
    pub fn normal(&self, x: DVec3) -> DVec3 {
        let g = self.grid.eval(x).1;
        g.try_normalize().unwrap_or(DVec3::Z)
    }

    /// Where the line `o + t w` (unit `w`) runs inside the box holding the shape.
    fn box_interval(&self, o: DVec3, w: DVec3) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            if w[a] == 0.0 {
                if o[a] < self.lo[a] || o[a] > self.hi[a] {
                    return None;
                }
                continue;
            }
            let (p, q) = ((self.lo[a] - o[a]) / w[a], (self.hi[a] - o[a]) / w[a]);
            t0 = t0.max(p.min(q));
            t1 = t1.min(p.max(q));
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// Sphere-trace `o + t w` from `from` towards `to` (either way) while it stays on the side
    /// `inside`: the last parameter on that side and the first beyond it (within `1e-14` relative
    /// of each other), or `None` if the side does not change before `to`.
    fn crossing(&self, o: DVec3, w: DVec3, from: f64, to: f64, inside: bool) -> Option<(f64, f64)> {
        let sign = if to >= from { 1.0 } else { -1.0 };
        let span = (to - from).abs();
        let min_step = MIN_STEP * self.grid.spacing;
        let at = |s: f64| o + w * (from + sign * s);
        let (mut prev, mut v_prev, mut s) = (0.0, f64::NAN, 0.0);
        for _ in 0..MAX_MARCH {
            let x = at(s);
            let (v, g) = self.grid.value_grad(x);
            if (v <= 0.0) != inside {
                let (lo, hi) = narrow(
                    prev,
                    v_prev,
                    s,
                    v,
                    |t| {
                        let v = self.grid.value(at(t));
                        ((v <= 0.0) == inside, v)
                    },
                    |hi| 1e-14 * (1.0 + (from + sign * hi).abs()),
                );
                return Some((from + sign * lo, from + sign * hi));
            }
            if s >= span {
                return None;
            }
            (prev, v_prev) = (s, v);
            s = (s + self.reach_along(x, v, sign * g.dot(w)).max(min_step)).min(span);
        }
        None
    }

    /// Entry and exit parameters of the first stretch of `o + t w` inside the shape that ends
    /// ahead of `o` (`t0 ≤ 0` if `o` is inside), as the convex bounds report theirs.
    pub fn interval(&self, o: DVec3, w: DVec3) -> Option<(f64, f64)> {
        let (ta, tb) = self.box_interval(o, w)?;
        if self.contains(o) {
            let t0 = self.crossing(o, w, 0.0, ta, true).map_or(ta, |c| c.0);
            let t1 = self.crossing(o, w, 0.0, tb, true).map_or(tb, |c| c.0);
            return Some((t0, t1));
        }
        if tb <= 0.0 {
            return None;
        }
        let (_, t0) = self.crossing(o, w, ta.max(0.0), tb, false)?;
        let t1 = self.crossing(o, w, t0, tb, true).map_or(tb, |c| c.0);
        Some((t0, t1))
    }

    /// The smooth union of `shapes` ([`sample_shapes`]) sampled every `spacing` and interpolated
    /// by `interp`.
    pub fn from_shapes(
        shapes: &[Shape],
        blend: f64,
        spacing: f64,
        interp: Interp,
    ) -> Result<Self, String> {
        let (origin, dims, samples) = sample_shapes(shapes, blend, spacing);
        Self::from_samples(origin, spacing, dims, samples, interp)
    }

    /// The parameter where `o + t w` (unit `w`, `o` outside) first enters the shape, if it does
    /// (the start of [`SdfGrid::interval`]'s stretch, without marching across it).
    pub fn entry(&self, o: DVec3, w: DVec3) -> Option<f64> {
        let (ta, tb) = self.box_interval(o, w)?;
        if tb <= 0.0 || self.contains(o) {
            return None;
        }
        self.crossing(o, w, ta.max(0.0), tb, false).map(|c| c.1)
    }

    /// The parameter where `o + t w` (unit `w`, `o` inside) first leaves the shape.
    pub fn exit(&self, o: DVec3, w: DVec3) -> Option<f64> {
        if !self.contains(o) {
            return self.interval(o, w).map(|(_, t1)| t1);
        }
        let (_, tb) = self.box_interval(o, w)?;
        Some(self.crossing(o, w, 0.0, tb, true).map_or(tb, |c| c.0))
    }

    /// The value, gradient and Hessian of the signed distance at `x`.
    #[inline]
    pub fn eval(&self, x: DVec3) -> (f64, DVec3, glam::DMat3) {
        self.grid.eval(x)
    }
}

/// The bricks of `grid` and, for each, bounds on the interpolant over it and its 26 neighbours:
/// on `|∇d|`, and (tricubic grids) on `|wᵀ ∇²d w|` for unit `w`, the curvature of `d` along any
/// line. The derivative of a B-spline series is the series of its coefficients' differences one
/// degree lower (weights ≥ 0 summing to 1), so `|∂d/∂x_a| ≤ max |Δ_a c| / h` and
/// `|∂²d/∂x_a∂x_b| ≤ max |Δ_a Δ_b c| / h²` over the coefficients a point depends on (likewise for
/// the slope of trilinear interpolation, whose kinks between cells bound no curvature: infinite).
/// The clamped margin repeats the edge coefficients.
fn brick_bounds(grid: &GridField) -> ([usize; 3], Vec<f64>, Vec<f64>) {
    let dims = grid.dims;
    let c = &grid.coef;
    let at = |i: isize, j: isize, k: isize| {
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        c[clamp(i, dims[0]) + dims[0] * (clamp(j, dims[1]) + dims[1] * clamp(k, dims[2]))]
    };
    let bricks = dims.map(|d| (d - 1).div_ceil(BRICK).max(1));
    // the coefficients a cell depends on: one before to two after (tricubic), or its corners
    let (before, after) = match grid.interp {
        Interp::Tricubic => (1, 2),
        Interp::Trilinear => (0, 1),
    };
    let count = bricks[0] * bricks[1] * bricks[2];
    let (mut raw_slope, mut raw_bend) = (vec![0.0; count], vec![f64::INFINITY; count]);
    for bk in 0..bricks[2] {
        for bj in 0..bricks[1] {
            for bi in 0..bricks[0] {
                // the brick's coefficients: first and last index along each axis
                let span = |b: usize, d: usize| {
                    (
                        (b * BRICK).saturating_sub(before) as isize,
                        ((b + 1) * BRICK + after).min(d - 1) as isize,
                    )
                };
                let ((i0, i1), (j0, j1), (k0, k1)) =
                    (span(bi, dims[0]), span(bj, dims[1]), span(bk, dims[2]));
                let mut steepest = DVec3::ZERO;
                // |Δ_a Δ_b c|: the diagonal (a = b) and the mixed pairs xy, xz, yz
                let (mut second, mut mixed) = (DVec3::ZERO, DVec3::ZERO);
                for k in k0..=k1 {
                    for j in j0..=j1 {
                        for i in i0..=i1 {
                            let here = at(i, j, k);
                            let (dx, dy, dz) = (
                                at(i + 1, j, k) - here,
                                at(i, j + 1, k) - here,
                                at(i, j, k + 1) - here,
                            );
                            if i < i1 {
                                steepest.x = steepest.x.max(dx.abs());
                            }
                            if j < j1 {
                                steepest.y = steepest.y.max(dy.abs());
                            }
                            if k < k1 {
                                steepest.z = steepest.z.max(dz.abs());
                            }
                            second = second.max(
                                DVec3::new(
                                    dx - (here - at(i - 1, j, k)),
                                    dy - (here - at(i, j - 1, k)),
                                    dz - (here - at(i, j, k - 1)),
                                )
                                .abs(),
                            );
                            mixed = mixed.max(
                                DVec3::new(
                                    at(i + 1, j + 1, k) - at(i, j + 1, k) - dx,
                                    at(i + 1, j, k + 1) - at(i, j, k + 1) - dx,
                                    at(i, j + 1, k + 1) - at(i, j, k + 1) - dy,
                                )
                                .abs(),
                            );
                        }
                    }
                }
                let b = bi + bricks[0] * (bj + bricks[1] * bk);
                raw_slope[b] = (steepest.length() / grid.spacing).max(1e-300);
                if grid.interp == Interp::Tricubic {
                    // |wᵀHw| ≤ ‖H‖ ≤ its Frobenius norm
                    let frobenius = (second.length_squared() + 2.0 * mixed.length_squared()).sqrt();
                    raw_bend[b] = frobenius / (grid.spacing * grid.spacing);
                }
            }
        }
    }
    // each brick's bounds cover its neighbours too: a clearance may reach into them
    let spread = |raw: &[f64]| {
        let mut out = raw.to_vec();
        for bk in 0..bricks[2] {
            for bj in 0..bricks[1] {
                for bi in 0..bricks[0] {
                    let mut m: f64 = 0.0;
                    for k in bk.saturating_sub(1)..=(bk + 1).min(bricks[2] - 1) {
                        for j in bj.saturating_sub(1)..=(bj + 1).min(bricks[1] - 1) {
                            for i in bi.saturating_sub(1)..=(bi + 1).min(bricks[0] - 1) {
                                m = m.max(raw[i + bricks[0] * (j + bricks[1] * k)]);
                            }
                        }
                    }
                    out[bi + bricks[0] * (bj + bricks[1] * bk)] = m;
                }
            }
        }
        out
    };
    (bricks, spread(&raw_slope), spread(&raw_bend))
}

/// Shapes in closed form whose signed distances are sampled onto a grid (the blend of several is
/// their smooth union).
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Sphere {
        center: DVec3,
        radius: f64,
    },
    /// A ring of tube radius `minor` about the circle of radius `major` around `axis`.
    Torus {
        center: DVec3,
        axis: DVec3,
        major: f64,
        minor: f64,
    },
    /// A box of half extents `half` with edges rounded by `rounding`.
    Box {
        center: DVec3,
        half: DVec3,
        rounding: f64,
    },
    /// The points within `radius` of the segment `from`–`to`.
    Capsule {
        from: DVec3,
        to: DVec3,
        radius: f64,
    },
}

impl Shape {
    /// The signed distance from `x`.
    pub fn distance(&self, x: DVec3) -> f64 {
        match *self {
            Shape::Sphere { center, radius } => (x - center).length() - radius,
            Shape::Torus {
                center,
                axis,
                major,
                minor,
            } => {
                let p = x - center;
                let h = p.dot(axis);
                let rho = (p - axis * h).length();
                (rho - major).hypot(h) - minor
            }
            Shape::Box {
                center,
                half,
                rounding,
            } => {
                let q = (x - center).abs() - (half - DVec3::splat(rounding));
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0) - rounding
            }
            Shape::Capsule { from, to, radius } => {
                let (p, a) = (x - from, to - from);
                let t = (p.dot(a) / a.length_squared().max(1e-300)).clamp(0.0, 1.0);
                (p - a * t).length() - radius
            }
        }
    }

    /// Corners of a box holding the shape.
    pub fn extent(&self) -> (DVec3, DVec3) {
        match *self {
            Shape::Sphere { center, radius } => {
                (center - DVec3::splat(radius), center + DVec3::splat(radius))
            }
            Shape::Torus {
                center,
                major,
                minor,
                ..
            } => {
                let r = DVec3::splat(major + minor);
                (center - r, center + r)
            }
            Shape::Box { center, half, .. } => (center - half, center + half),
            Shape::Capsule { from, to, radius } => (
                from.min(to) - DVec3::splat(radius),
                from.max(to) + DVec3::splat(radius),
            ),
        }
    }
}

/// The smooth union of `shapes` (polynomial smooth minimum of radius `blend`; 0: the plain
/// union) sampled every `spacing` over their extent plus three nodes all round: origin, dims and
/// samples (x fastest) for [`SdfGrid::from_samples`].
pub fn sample_shapes(shapes: &[Shape], blend: f64, spacing: f64) -> (DVec3, [usize; 3], Vec<f64>) {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for s in shapes {
        let (a, b) = s.extent();
        lo = lo.min(a);
        hi = hi.max(b);
    }
    let pad = DVec3::splat(3.0 * spacing + blend);
    let origin = lo - pad;
    let span = (hi + pad - origin) / spacing;
    let dims = [span.x, span.y, span.z].map(|s| s.ceil() as usize + 1);
    let mut samples = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let x = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                samples.push(smooth_union(shapes, blend, x));
            }
        }
    }
    (origin, dims, samples)
}

/// `min_k d_k(x)`, smoothed over `blend` (Quílez's polynomial smooth minimum).
fn smooth_union(shapes: &[Shape], blend: f64, x: DVec3) -> f64 {
    shapes
        .iter()
        .map(|s| s.distance(x))
        .reduce(|a, b| {
            if blend <= 0.0 {
                return a.min(b);
            }
            let h = (blend - (a - b).abs()).max(0.0) / blend;
            a.min(b) - h * h * blend * 0.25
        })
        .unwrap_or(f64::INFINITY)
}

/// Shrink a bracket of a sign change along a line to within `tol(hi)`: `lo` on the wanted side
/// (`on_side(lo)`), `hi` beyond it, `f_lo` and `f_hi` the signed distances there (`f_lo` may be
/// NaN). Regula falsi with the Illinois rule (the end that stays twice has its value halved, so
/// both ends close in), falling back to bisection after any step that did not halve the bracket:
/// about ten evaluations (measured over a render) where bisection to `1e-14` takes thirty to
/// fifty, never more than twice bisection's. `on_side(t)` returns whether `t` is on the wanted side, and its distance.
fn narrow(
    mut lo: f64,
    mut f_lo: f64,
    mut hi: f64,
    mut f_hi: f64,
    mut on_side: impl FnMut(f64) -> (bool, f64),
    tol: impl Fn(f64) -> f64,
) -> (f64, f64) {
    let mut halved = true;
    let mut kept = 0i8; // which end the last step kept: -1 lo, 1 hi
    for _ in 0..400 {
        let width = hi - lo;
        if width <= tol(hi) {
            break;
        }
        let secant = lo + width * f_lo / (f_lo - f_hi);
        let t = if halved && secant > lo && secant < hi {
            secant
        } else {
            0.5 * (lo + hi)
        };
        let (side, f) = on_side(t);
        if side {
            (lo, f_lo) = (t, f);
            if kept == 1 {
                f_hi *= 0.5;
            }
            kept = 1;
        } else {
            (hi, f_hi) = (t, f);
            if kept == -1 {
                f_lo *= 0.5;
            }
            kept = -1;
        }
        halved = hi - lo <= 0.5 * width;
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere_grid(interp: Interp) -> SdfGrid {
        let shapes = [Shape::Sphere {
            center: DVec3::new(0.1, -0.2, 0.05),
            radius: 1.0,
        }];
        SdfGrid::from_shapes(&shapes, 0.0, 0.05, interp).unwrap()
    }

    /// Intervals, exits, normals and the inside test of a sampled sphere agree with the sphere's
    /// closed forms (to the interpolation error of a 0.05 grid).
    #[test]
    fn sampled_sphere_matches_the_sphere() {
        let c = DVec3::new(0.1, -0.2, 0.05);
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g = sphere_grid(interp);
            let tol = if interp == Interp::Tricubic {
                2e-4
            } else {
                2e-3
            };
            for (o, w) in [
                (DVec3::new(-3.0, 0.1, 0.0), DVec3::X),
                (
                    DVec3::new(0.4, 2.5, -0.3),
                    DVec3::new(0.1, -1.0, 0.2).normalize(),
                ),
                (
                    DVec3::new(0.2, -0.1, 0.3),
                    DVec3::new(1.0, 1.0, 1.0).normalize(),
                ),
            ] {
                let b = (o - c).dot(w);
                let disc = b * b - ((o - c).length_squared() - 1.0);
                let want = (-b - disc.sqrt(), -b + disc.sqrt());
                let (t0, t1) = g.interval(o, w).unwrap();
                assert!(
                    (t0 - want.0).abs() < tol && (t1 - want.1).abs() < tol,
                    "{interp:?} {o} {w}: ({t0}, {t1}) vs {want:?}"
                );
                if g.contains(o) {
                    assert!((g.exit(o, w).unwrap() - want.1).abs() < tol);
                }
                let x = o + w * want.1;
                let normal_error = (g.normal(x) - (x - c).normalize()).length();
                // the trilinear gradient is constant across a cell: its normal is good to ~h/R
                let allowed = if interp == Interp::Tricubic {
                    2e-3
                } else {
                    0.05
                };
                assert!(
                    normal_error < allowed,
                    "{interp:?}: normal off by {normal_error}"
                );
            }
            // a line that misses
            assert!(g.interval(DVec3::new(-3.0, 1.3, 0.0), DVec3::X).is_none());
            // behind the ray
            assert!(g.interval(DVec3::new(3.0, 0.0, 0.0), DVec3::X).is_none());
            // the clearance never exceeds the true distance, and is not much shorter: within a
            // few bricks of the centre (the distance's kink, where the interpolant's coefficients
            // ring) the local slope bound is steep, near the surface it is about 1
            for (x, fraction) in [
                (c, 0.1),
                (c + DVec3::new(0.4, 0.1, -0.3), 0.1),
                (c + DVec3::X * 0.97, 0.5),
            ] {
                let true_distance = 1.0 - (x - c).length();
                let clearance = g.clearance(x);
                assert!(clearance > 0.0 && clearance <= true_distance + 1e-9);
                assert!(
                    clearance > fraction * true_distance,
                    "{interp:?} at {x}: {clearance} vs {true_distance}"
                );
            }
        }
    }

    /// A line through both arms of a ring crosses it twice: the first stretch, then the second
    /// when traced from beyond the first.
    #[test]
    fn a_ring_is_entered_twice() {
        let shapes = [Shape::Torus {
            center: DVec3::ZERO,
            axis: DVec3::Z,
            major: 1.0,
            minor: 0.3,
        }];
        let g = SdfGrid::from_shapes(&shapes, 0.0, 0.04, Interp::Tricubic).unwrap();
        let o = DVec3::new(-2.0, 0.0, 0.0);
        let (t0, t1) = g.interval(o, DVec3::X).unwrap();
        assert!(
            (t0 - 0.7).abs() < 1e-3 && (t1 - 1.3).abs() < 1e-3,
            "{t0} {t1}"
        );
        let (u0, u1) = g.interval(o + DVec3::X * (t1 + 1e-6), DVec3::X).unwrap();
        assert!(
            (t1 + 1e-6 + u0 - 2.7).abs() < 1e-3 && (t1 + 1e-6 + u1 - 3.3).abs() < 1e-3,
            "{u0} {u1}"
        );
        assert!(!g.contains(DVec3::ZERO) && g.contains(DVec3::new(0.0, 1.0, 0.1)));
    }

    /// The ring-and-bead ornament of the example scenes: a torus fused to a sphere.
    fn ornament() -> SdfGrid {
        let shapes = [
            Shape::Torus {
                center: DVec3::ZERO,
                axis: DVec3::Y,
                major: 0.7,
                minor: 0.25,
            },
            Shape::Sphere {
                center: DVec3::new(0.0, 0.0, 0.7),
                radius: 0.35,
            },
        ];
        SdfGrid::from_shapes(&shapes, 0.15, 0.03, Interp::Tricubic).unwrap()
    }

    /// The curvature along a line, `wᵀ ∇²d w` (a central difference of the directional
    /// derivative), never exceeds the brick's bound, and the bound is not vacuous.
    #[test]
    fn curvature_bounds_hold_along_lines() {
        use rand::RngExt;
        let g = ornament();
        let mut rng = crate::math::stream_rng(3, 0);
        let (lo, hi) = g.corners();
        let mut tightest: f64 = 0.0;
        for _ in 0..20_000 {
            let x = lo + (hi - lo) * DVec3::new(rng.random(), rng.random(), rng.random());
            let w = crate::math::uniform_sphere(rng.random(), rng.random());
            let e = 1e-5;
            let slope = |x: DVec3| g.grid.value_grad(x).1.dot(w);
            let bend = (slope(x + w * e) - slope(x - w * e)) / (2.0 * e);
            let (brick, _) = g.neighbourhood(x);
            let bound = g.brick_bend[brick];
            assert!(
                bend.abs() <= bound * (1.0 + 1e-6) + 1e-6,
                "{x} {w}: {bend} > {bound}"
            );
            tightest = tightest.max(bend.abs() / bound);
        }
        assert!(tightest > 0.1, "the bound is loose everywhere: {tightest}");
    }

    /// Lines from points on and near the surface, at every angle to it (grazing ones included),
    /// and shallow chords just under the surface find the crossings a fine march finds: the first
    /// change of side, to 1e-9. Steps beyond what the bounds allow would skip the chords.
    #[test]
    fn crossings_are_those_of_a_fine_march() {
        use rand::RngExt;
        let g = ornament();
        let mut rng = crate::math::stream_rng(4, 0);
        // the first parameter beyond `o` where the side differs from `o`'s, by steps of 2e-4
        // and bisection, within the box
        let march = |o: DVec3, w: DVec3| -> Option<f64> {
            let (_, tb) = g.box_interval(o, w)?;
            let inside = g.grid.value(o) <= 0.0;
            let mut t = 0.0;
            while t < tb {
                let next = (t + 2e-4).min(tb);
                if (g.grid.value(o + w * next) <= 0.0) != inside {
                    let (mut a, mut b) = (t, next);
                    while b - a > 1e-13 {
                        let m = 0.5 * (a + b);
                        if (g.grid.value(o + w * m) <= 0.0) == inside {
                            a = m
                        } else {
                            b = m
                        }
                    }
                    return Some(b);
                }
                t = next;
            }
            None
        };
        let mut checked = 0;
        for k in 0..1200 {
            // a point on the surface (or 1e-4 off it), and a direction at a random angle to it
            let mut x = DVec3::new(0.7, 0.0, 0.0)
                + crate::math::uniform_sphere(rng.random(), rng.random())
                    * 0.35
                    * rng.random::<f64>();
            for _ in 0..40 {
                let (v, grad) = g.grid.value_grad(x);
                x -= grad * (v / grad.length_squared());
            }
            // (a start near the tube's centre line, where the gradient vanishes, is no use)
            if !x.is_finite() || g.grid.value(x).abs() > 1e-9 {
                continue;
            }
            let n = g.normal(x);
            let random = crate::math::uniform_sphere(rng.random(), rng.random());
            let (x, w) = if k % 4 == 3 {
                // a shallow chord: a line along the tangent plane 1e-3 below the surface,
                // from 0.3 before, which crosses the shape for a short stretch
                let u = (random - n * random.dot(n)).normalize();
                (x - n * 1e-3 * rng.random::<f64>() - u * 0.3, u)
            } else {
                let w = (random + n * (2.0 * rng.random::<f64>() - 1.0)).normalize();
                (x + n * [0.0, 1e-4, -1e-4][k % 4], w)
            };
            let from = if g.grid.value(x) <= 0.0 {
                g.exit(x, w)
            } else {
                g.interval(x, w).map(|(t0, _)| t0)
            };
            let want = march(x, w);
            match (from, want) {
                (Some(t), Some(u)) if t > 1e-3 => {
                    assert!((t - u).abs() < 1e-9, "{x} {w}: {t} vs {u}");
                    checked += 1;
                }
                (None, None) => {}
                // a crossing within the first fine step is below the march's resolution
                (Some(t), _) if t <= 1e-3 => {}
                (t, u) => panic!("{x} {w}: {t:?} vs {u:?}"),
            }
        }
        assert!(checked > 250, "{checked}");
    }

    #[test]
    fn refuses_shapes_that_touch_the_grid() {
        let samples = vec![-1.0; 27];
        let e = SdfGrid::from_samples(DVec3::ZERO, 1.0, [3, 3, 3], samples, Interp::Tricubic)
            .unwrap_err();
        assert!(e.contains("on the grid's faces is not positive"), "{e}");
        let e = SdfGrid::from_samples(DVec3::ZERO, 1.0, [3, 3, 3], vec![1.0; 27], Interp::Tricubic)
            .unwrap_err();
        assert!(e.contains("empty"), "{e}");
    }
}
