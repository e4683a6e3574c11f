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
        let (bricks, brick_slope) = brick_slopes(&grid);
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
        let u = (x - self.grid.origin) / (self.grid.spacing * BRICK as f64);
        let mut index = 0;
        let mut room = f64::INFINITY;
        for a in (0..3).rev() {
            let b = (u[a].floor().max(0.0) as usize).min(self.bricks[a] - 1);
            index = index * self.bricks[a] + b;
            // to the faces of the neighbourhood: one brick beyond this brick's faces
            let f = u[a] - b as f64;
            room = room.min((f + 1.0).min(2.0 - f));
        }
        let room = room.max(0.0) * self.grid.spacing * BRICK as f64;
        (d.abs() / self.brick_slope[index]).min(room)
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
        let side = |s: f64| {
            let x = o + w * (from + sign * s);
            let v = self.grid.value(x);
            (v <= 0.0, v, x)
        };
        let (mut prev, mut s) = (0.0, 0.0);
        for _ in 0..MAX_MARCH {
            let (now_inside, v, x) = side(s);
            if now_inside != inside {
                // bisect between the last point on the side and the first beyond
                let (mut lo, mut hi) = (prev, s);
                for _ in 0..200 {
                    if hi - lo <= 1e-14 * (1.0 + (from + sign * hi).abs()) {
                        break;
                    }
                    let mid = 0.5 * (lo + hi);
                    if side(mid).0 == inside {
                        lo = mid
                    } else {
                        hi = mid
                    }
                }
                return Some((from + sign * lo, from + sign * hi));
            }
            if s >= span {
                return None;
            }
            prev = s;
            s = (s + self.reach(x, v).max(min_step)).min(span);
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

/// The bricks of `grid` and, for each, a bound on the interpolant's `|∇d|` over it and its 26
/// neighbours: `|∂d/∂x_a| ≤ max |Δ_a c| / h` over the coefficients a point depends on, since the
/// derivative of a B-spline series is the series of its coefficients' differences one degree lower
/// (weights ≥ 0 summing to 1), and likewise for trilinear interpolation; the clamped margin adds
/// zero differences.
fn brick_slopes(grid: &GridField) -> ([usize; 3], Vec<f64>) {
    let dims = grid.dims;
    let c = &grid.coef;
    let node = |i: usize, j: usize, k: usize| i + dims[0] * (j + dims[1] * k);
    let bricks = dims.map(|d| (d - 1).div_ceil(BRICK).max(1));
    // the coefficients a cell depends on: one before to two after (tricubic), or its corners
    let (before, after) = match grid.interp {
        Interp::Tricubic => (1, 2),
        Interp::Trilinear => (0, 1),
    };
    let mut raw = vec![0.0; bricks[0] * bricks[1] * bricks[2]];
    for bk in 0..bricks[2] {
        for bj in 0..bricks[1] {
            for bi in 0..bricks[0] {
                // the brick's coefficients: first and last index along each axis
                let span = |b: usize, d: usize| {
                    (
                        (b * BRICK).saturating_sub(before),
                        ((b + 1) * BRICK + after).min(d - 1),
                    )
                };
                let ((i0, i1), (j0, j1), (k0, k1)) =
                    (span(bi, dims[0]), span(bj, dims[1]), span(bk, dims[2]));
                let mut steepest = DVec3::ZERO;
                for k in k0..=k1 {
                    for j in j0..=j1 {
                        for i in i0..=i1 {
                            let here = c[node(i, j, k)];
                            if i < i1 {
                                steepest.x = steepest.x.max((c[node(i + 1, j, k)] - here).abs());
                            }
                            if j < j1 {
                                steepest.y = steepest.y.max((c[node(i, j + 1, k)] - here).abs());
                            }
                            if k < k1 {
                                steepest.z = steepest.z.max((c[node(i, j, k + 1)] - here).abs());
                            }
                        }
                    }
                }
                raw[bi + bricks[0] * (bj + bricks[1] * bk)] =
                    (steepest.length() / grid.spacing).max(1e-300);
            }
        }
    }
    // each brick's bound covers its neighbours too: a clearance may reach into them
    let mut slope = raw.clone();
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
                slope[bi + bricks[0] * (bj + bricks[1] * bk)] = m;
            }
        }
    }
    (bricks, slope)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere_grid(interp: Interp) -> SdfGrid {
        let shapes = [Shape::Sphere {
            center: DVec3::new(0.1, -0.2, 0.05),
            radius: 1.0,
        }];
        let (origin, dims, samples) = sample_shapes(&shapes, 0.0, 0.05);
        SdfGrid::from_samples(origin, 0.05, dims, samples, interp).unwrap()
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
        let (origin, dims, samples) = sample_shapes(&shapes, 0.0, 0.04);
        let g = SdfGrid::from_samples(origin, 0.04, dims, samples, Interp::Tricubic).unwrap();
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
