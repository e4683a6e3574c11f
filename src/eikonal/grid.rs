//! Index fields sampled on a regular grid: trilinear (cheap) or tricubic B-spline (C², prefiltered
//! so that it interpolates the samples; paper 002 Eq. 13), with analytic gradients and Hessians.
//! Outside the grid the nearest coefficients are repeated (clamped).

use glam::{DMat3, DVec3};

/// Interpolation of a grid field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interp {
    Trilinear,
    Tricubic,
}

/// A regular grid of `dims` nodes, node `(i, j, k)` at `origin + spacing·(i, j, k)`; `coef` holds
/// samples (trilinear) or B-spline coefficients (tricubic), x fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct GridField {
    pub origin: DVec3,
    pub spacing: f64,
    pub dims: [usize; 3],
    pub coef: Vec<f64>,
    pub interp: Interp,
}

/// Cubic B-spline weights and their first and second derivatives at fraction `t`.
fn bspline(t: f64) -> ([f64; 4], [f64; 4], [f64; 4]) {
    let (t2, t3) = (t * t, t * t * t);
    let w = [
        (1.0 - t).powi(3) / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
        t3 / 6.0,
    ];
    let d = [
        -(1.0 - t).powi(2) / 2.0,
        (3.0 * t2 - 4.0 * t) / 2.0,
        (-3.0 * t2 + 2.0 * t + 1.0) / 2.0,
        t2 / 2.0,
    ];
    let dd = [1.0 - t, 3.0 * t - 2.0, -3.0 * t + 1.0, t];
    (w, d, dd)
}

impl GridField {
    /// A grid that interpolates `samples` (x fastest); for tricubic the samples are prefiltered into
    /// B-spline coefficients (clamped boundaries).
    pub fn from_samples(
        origin: DVec3,
        spacing: f64,
        dims: [usize; 3],
        samples: Vec<f64>,
        interp: Interp,
    ) -> crate::Result<Self> {
        let count = dims[0] * dims[1] * dims[2];
        if samples.len() != count {
            return Err(format!(
                "grid: {} values given, {}×{}×{} = {count} expected",
                samples.len(),
                dims[0],
                dims[1],
                dims[2]
            )
            .into());
        }
        if dims.iter().any(|&d| d < 2) || !(spacing > 0.0 && spacing.is_finite()) {
            return Err(format!(
                "grid: dims {dims:?} must be ≥ 2 each and spacing {spacing} positive"
            )
            .into());
        }
        let mut g = GridField {
            origin,
            spacing,
            dims,
            coef: samples,
            interp,
        };
        if interp == Interp::Tricubic {
            for axis in 0..3 {
                g.prefilter(axis);
            }
        }
        Ok(g)
    }

    #[inline]
    fn index(&self, i: isize, j: isize, k: isize) -> usize {
        let c = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        c(i, self.dims[0]) + self.dims[0] * (c(j, self.dims[1]) + self.dims[1] * c(k, self.dims[2]))
    }

    /// Solve `(c_{i-1} + 4 c_i + c_{i+1})/6 = s_i` (clamped ends) along every line of `axis`.
    fn prefilter(&mut self, axis: usize) {
        let n = self.dims[axis];
        let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
        let mut line = vec![0.0; n];
        let (mut cp, mut dp) = (vec![0.0; n], vec![0.0; n]);
        for a in 0..self.dims[o1] {
            for b in 0..self.dims[o2] {
                let dims = self.dims;
                let idx = move |m: usize| {
                    let mut p = [0usize; 3];
                    p[axis] = m;
                    p[o1] = a;
                    p[o2] = b;
                    p[0] + dims[0] * (p[1] + dims[1] * p[2])
                };
                for (m, v) in line.iter_mut().enumerate() {
                    *v = self.coef[idx(m)];
                }
                // Thomas algorithm; diagonal 4/6 (5/6 at clamped ends), off-diagonals 1/6
                let diag = |m: usize| {
                    if m == 0 || m == n - 1 {
                        5.0 / 6.0
                    } else {
                        4.0 / 6.0
                    }
                };
                let off = 1.0 / 6.0;
                cp[0] = off / diag(0);
                dp[0] = line[0] / diag(0);
                for m in 1..n {
                    let den = diag(m) - off * cp[m - 1];
                    cp[m] = off / den;
                    dp[m] = (line[m] - off * dp[m - 1]) / den;
                }
                line[n - 1] = dp[n - 1];
                for m in (0..n - 1).rev() {
                    line[m] = dp[m] - cp[m] * line[m + 1];
                }
                for (m, v) in line.iter().enumerate() {
                    let i = idx(m);
                    self.coef[i] = *v;
                }
            }
        }
    }

    /// Per-axis tap weights `(w, w', w'')` at fraction `t`, and the first tap's offset.
    fn basis(&self, t: f64) -> [(f64, f64, f64); 4] {
        match self.interp {
            Interp::Tricubic => {
                let (w, d, dd) = bspline(t);
                [0, 1, 2, 3].map(|i| (w[i], d[i], dd[i]))
            }
            Interp::Trilinear => [
                (1.0 - t, -1.0, 0.0),
                (t, 1.0, 0.0),
                (0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0),
            ],
        }
    }

    /// Visit the taps at `x`: `(coefficient index, w, ∇w, ∇²w)` in grid units (divide by spacing).
    #[inline]
    fn taps(&self, x: DVec3, mut visit: impl FnMut(usize, f64, DVec3, [[f64; 3]; 3])) {
        let u = (x - self.origin) / self.spacing;
        let base = u.floor();
        let t = u - base;
        let (bx, by, bz) = (self.basis(t.x), self.basis(t.y), self.basis(t.z));
        let (n, off) = if self.interp == Interp::Tricubic {
            (4, -1)
        } else {
            (2, 0)
        };
        let start = [
            base.x as isize + off,
            base.y as isize + off,
            base.z as isize + off,
        ];
        for (c, &(z0, z1, z2)) in bz.iter().enumerate().take(n) {
            for (b, &(y0, y1, y2)) in by.iter().enumerate().take(n) {
                for (a, &(x0, x1, x2)) in bx.iter().enumerate().take(n) {
                    let idx = self.index(
                        start[0] + a as isize,
                        start[1] + b as isize,
                        start[2] + c as isize,
                    );
                    let hess = [
                        [x2 * y0 * z0, x1 * y1 * z0, x1 * y0 * z1],
                        [x1 * y1 * z0, x0 * y2 * z0, x0 * y1 * z1],
                        [x1 * y0 * z1, x0 * y1 * z1, x0 * y0 * z2],
                    ];
                    visit(
                        idx,
                        x0 * y0 * z0,
                        DVec3::new(x1 * y0 * z0, x0 * y1 * z0, x0 * y0 * z1),
                        hess,
                    );
                }
            }
        }
    }

    /// Value, gradient and Hessian at `x`.
    pub fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        let (mut v, mut g, mut h) = (0.0, DVec3::ZERO, [[0.0; 3]; 3]);
        self.taps(x, |i, w, dw, hw| {
            let c = self.coef[i];
            v += c * w;
            g += dw * c;
            for r in 0..3 {
                for s in 0..3 {
                    h[r][s] += c * hw[r][s];
                }
            }
        });
        let s = self.spacing;
        let hess = DMat3::from_cols(
            DVec3::from_array(h[0]),
            DVec3::from_array(h[1]),
            DVec3::from_array(h[2]),
        ) * (1.0 / (s * s));
        (v, g / s, hess)
    }

    /// The value alone at `x` (no derivatives): the inside–outside test of a signed-distance grid.
    pub fn value(&self, x: DVec3) -> f64 {
        let u = (x - self.origin) / self.spacing;
        let base = u.floor();
        let t = u - base;
        let (weights, taps, off): ([[f64; 4]; 3], usize, isize) = match self.interp {
            Interp::Tricubic => ([bspline(t.x).0, bspline(t.y).0, bspline(t.z).0], 4, -1),
            Interp::Trilinear => ([t.x, t.y, t.z].map(|t| [1.0 - t, t, 0.0, 0.0]), 2, 0),
        };
        let start = [base.x, base.y, base.z].map(|b| b as isize + off);
        let mut v = 0.0;
        for (c, wz) in weights[2].iter().enumerate().take(taps) {
            for (b, wy) in weights[1].iter().enumerate().take(taps) {
                let mut row = 0.0;
                for (a, wx) in weights[0].iter().enumerate().take(taps) {
                    let idx = self.index(
                        start[0] + a as isize,
                        start[1] + b as isize,
                        start[2] + c as isize,
                    );
                    row += self.coef[idx] * wx;
                }
                v += row * wy * wz;
            }
        }
        v
    }

    /// Visit every coefficient that `n(x)` depends on with `(index, ∂n/∂c, ∇(∂n/∂c))` (clamped
    /// taps may repeat an index; their contributions add). This is the sparse form the adjoint
    /// accumulates over all coefficients with (8 taps trilinear, 64 tricubic).
    #[inline]
    pub fn visit_dcoef(&self, x: DVec3, mut visit: impl FnMut(usize, f64, DVec3)) {
        let s = 1.0 / self.spacing;
        self.taps(x, |i, w, dw, _| visit(i, w, dw * s));
    }

    /// `(∂n/∂c, ∇(∂n/∂c))` for coefficient `which` at `x` (clamped taps sum).
    pub fn dcoef(&self, x: DVec3, which: usize) -> (f64, DVec3) {
        let (mut v, mut g) = (0.0, DVec3::ZERO);
        self.taps(x, |i, w, dw, _| {
            if i == which {
                v += w;
                g += dw;
            }
        });
        (v, g / self.spacing)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(dims: [usize; 3]) -> Vec<f64> {
        let mut s = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    s.push(
                        1.2 + 0.1 * (0.7 * i as f64).sin() * (0.4 * j as f64).cos()
                            + 0.05 * k as f64 * 0.3,
                    );
                }
            }
        }
        s
    }

    #[test]
    fn interpolates_the_samples_and_derivatives_match() {
        let dims = [6, 5, 7];
        let s = samples(dims);
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g =
                GridField::from_samples(DVec3::new(-1.0, -0.5, 0.0), 0.3, dims, s.clone(), interp)
                    .unwrap();
            for (i, j, k) in [(0, 0, 0), (2, 3, 4), (5, 4, 6), (3, 1, 2)] {
                let x = DVec3::new(-1.0 + 0.3 * i as f64, -0.5 + 0.3 * j as f64, 0.3 * k as f64);
                let want = s[i + dims[0] * (j + dims[1] * k)];
                assert!(
                    (g.eval(x).0 - want).abs() < 1e-12,
                    "{interp:?} at node {i},{j},{k}: {} vs {want}",
                    g.eval(x).0
                );
            }
            // derivatives against central differences, away from cell faces
            let x = DVec3::new(-0.41, 0.23, 0.77);
            let h = 1e-6;
            let (_, grad, hess) = g.eval(x);
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = h;
                let fd = (g.eval(x + e).0 - g.eval(x - e).0) / (2.0 * h);
                assert!(
                    (grad[a] - fd).abs() < 1e-7,
                    "{interp:?} grad[{a}] {} vs {fd}",
                    grad[a]
                );
                let fdg = (g.eval(x + e).1 - g.eval(x - e).1) / (2.0 * h);
                assert!(
                    (hess.col(a) - fdg).length() < 1e-6,
                    "{interp:?} hessian col {a}: {} vs {fdg}",
                    hess.col(a)
                );
            }
        }
    }

    /// The value-only evaluation equals the full one, inside the grid and in its clamped margin.
    #[test]
    fn value_equals_eval() {
        let dims = [6, 5, 7];
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g = GridField::from_samples(
                DVec3::new(-1.0, -0.5, 0.0),
                0.3,
                dims,
                samples(dims),
                interp,
            )
            .unwrap();
            for x in [
                DVec3::new(-0.41, 0.23, 0.77),
                DVec3::new(0.3, 0.6, 1.9),
                DVec3::new(-1.7, 1.4, -0.6),
                DVec3::new(-1.0, -0.5, 0.0),
            ] {
                let (a, b) = (g.value(x), g.eval(x).0);
                assert!((a - b).abs() < 1e-13, "{interp:?} at {x}: {a} vs {b}");
            }
        }
    }

    /// Tricubic B-splines are C²: value, gradient and Hessian are continuous across cell faces.
    #[test]
    fn tricubic_is_c2_across_cell_faces() {
        let dims = [6, 5, 7];
        let g = GridField::from_samples(DVec3::ZERO, 0.5, dims, samples(dims), Interp::Tricubic)
            .unwrap();
        let face = DVec3::new(1.0, 0.73, 1.21); // x = 2 cells exactly
        let e = DVec3::new(1e-9, 0.0, 0.0);
        let (a, b) = (g.eval(face - e), g.eval(face + e));
        assert!(
            (a.0 - b.0).abs() < 1e-8
                && (a.1 - b.1).length() < 1e-7
                && (a.2.col(0) - b.2.col(0)).length() < 1e-6
        );
    }
}
