//! Index fields sampled on a regular grid: trilinear (cheap) or tricubic B-spline (C², prefiltered
//! so that it interpolates the samples; paper 002 Eq. 13), with analytic gradients and Hessians.
//! Outside the grid the nearest coefficients are repeated (clamped).

use crate::math::simd::Width;
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

/// The taps of a grid at one point: coefficient offsets per axis and `(w, w', w'')` per axis.
struct Stencil<const N: usize> {
    offsets: [[usize; N]; 3],
    weights: [[[f64; N]; 3]; 3],
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

    /// The clamped coefficient offsets along each axis (y premultiplied by the row length, z by
    /// the plane size) and the per-axis weights `(w, w', w'')` of the `N` taps a side at `x`
    /// (`N` = 4 tricubic, 2 trilinear).
    #[inline(always)]
    fn stencil<const N: usize>(&self, x: DVec3) -> Stencil<N> {
        let u = (x - self.origin) / self.spacing;
        let base = u.floor();
        let t = u - base;
        let off = if N == 4 { -1 } else { 0 };
        let [nx, ny, nz] = self.dims;
        let axis = |b: f64, n: usize, stride: usize| -> [usize; N] {
            std::array::from_fn(|a| {
                (b as isize + off + a as isize).clamp(0, n as isize - 1) as usize * stride
            })
        };
        let weights = |t: f64| -> [[f64; N]; 3] {
            if N == 4 {
                let (w, d, dd) = bspline(t);
                [
                    std::array::from_fn(|i| w[i]),
                    std::array::from_fn(|i| d[i]),
                    std::array::from_fn(|i| dd[i]),
                ]
            } else {
                [
                    std::array::from_fn(|i| if i == 0 { 1.0 - t } else { t }),
                    std::array::from_fn(|i| if i == 0 { -1.0 } else { 1.0 }),
                    [0.0; N],
                ]
            }
        };
        Stencil {
            offsets: [
                axis(base.x, nx, 1),
                axis(base.y, ny, nx),
                axis(base.z, nz, nx * ny),
            ],
            weights: [weights(t.x), weights(t.y), weights(t.z)],
        }
    }

    /// Value, gradient and (with `HESSIAN`) Hessian at `x`, contracted one axis at a time: along
    /// y and z with the four x-taps side by side (independent lanes the compiler vectorises, the
    /// same operations in every lane), then along x. About 5× fewer operations than summing the 64
    /// tap products; value and gradient are the same bits with and without the Hessian.
    #[inline(always)]
    fn contract<const N: usize, const HESSIAN: bool>(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        let Stencil {
            offsets: [ix, iy, iz],
            weights: [[wx, dx, ddx], [wy, dy, ddy], [wz, dz, ddz]],
        } = self.stencil::<N>(x);
        let c = &self.coef;
        // a_yz[l]: the x-tap l contracted with the y- and z-derivatives of orders y and z
        let (mut a00, mut a10, mut a01) = ([0.0; N], [0.0; N], [0.0; N]);
        let (mut a20, mut a11, mut a02) = ([0.0; N], [0.0; N], [0.0; N]);
        for k in 0..N {
            let (mut s0, mut s1, mut s2) = ([0.0; N], [0.0; N], [0.0; N]);
            for j in 0..N {
                let row = iz[k] + iy[j];
                let cv: [f64; N] = std::array::from_fn(|i| c[row + ix[i]]);
                for l in 0..N {
                    s0[l] += cv[l] * wy[j];
                    s1[l] += cv[l] * dy[j];
                    if HESSIAN && N == 4 {
                        s2[l] += cv[l] * ddy[j];
                    }
                }
            }
            for l in 0..N {
                a00[l] += s0[l] * wz[k];
                a10[l] += s1[l] * wz[k];
                a01[l] += s0[l] * dz[k];
                if HESSIAN {
                    a11[l] += s1[l] * dz[k];
                }
                // trilinear weights are linear along each axis: no second derivative
                if HESSIAN && N == 4 {
                    a20[l] += s2[l] * wz[k];
                    a02[l] += s0[l] * ddz[k];
                }
            }
        }
        let dot = |a: &[f64; N], w: &[f64; N]| {
            let mut s = 0.0;
            for l in 0..N {
                s += a[l] * w[l];
            }
            s
        };
        let s = self.spacing;
        let grad = DVec3::new(dot(&a00, &dx), dot(&a10, &wx), dot(&a01, &wx)) / s;
        let hess = if HESSIAN {
            let (xy, xz, yz) = (dot(&a10, &dx), dot(&a01, &dx), dot(&a11, &wx));
            let (xx, yy, zz) = if N == 4 {
                (dot(&a00, &ddx), dot(&a20, &wx), dot(&a02, &wx))
            } else {
                (0.0, 0.0, 0.0)
            };
            DMat3::from_cols_array(&[xx, xy, xz, xy, yy, yz, xz, yz, zz]) * (1.0 / (s * s))
        } else {
            DMat3::ZERO
        };
        (dot(&a00, &wx), grad, hess)
    }

    /// [`Self::contract`] for trilinear grids, x first (two taps a side leave no lanes to fill):
    /// value, gradient and (with `HESSIAN`) Hessian, the same bits with and without it, and the
    /// bits of [`Self::trilinear`] (which takes several points at once; alone, this is faster).
    #[inline(always)]
    fn contract_rows<const N: usize, const HESSIAN: bool>(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        let Stencil {
            offsets: [ix, iy, iz],
            weights: [[wx, dx, ddx], [wy, dy, ddy], [wz, dz, ddz]],
        } = self.stencil::<N>(x);
        let c = &self.coef;
        let (mut v, mut gx, mut gy, mut gz) = (0.0, 0.0, 0.0, 0.0);
        let mut h = [0.0; 6]; // xx, xy, xz, yy, yz, zz
        for k in 0..N {
            let (mut t00, mut t10, mut t01) = (0.0, 0.0, 0.0);
            let (mut t20, mut t11, mut t02) = (0.0, 0.0, 0.0);
            for j in 0..N {
                let row = iz[k] + iy[j];
                let (mut r0, mut r1, mut r2) = (0.0, 0.0, 0.0);
                for i in 0..N {
                    let cv = c[row + ix[i]];
                    r0 += cv * wx[i];
                    r1 += cv * dx[i];
                    if HESSIAN && N == 4 {
                        r2 += cv * ddx[i];
                    }
                }
                t00 += r0 * wy[j];
                t10 += r1 * wy[j];
                t01 += r0 * dy[j];
                if HESSIAN {
                    t11 += r1 * dy[j];
                }
                if HESSIAN && N == 4 {
                    t20 += r2 * wy[j];
                    t02 += r0 * ddy[j];
                }
            }
            v += t00 * wz[k];
            gx += t10 * wz[k];
            gy += t01 * wz[k];
            gz += t00 * dz[k];
            if HESSIAN {
                h[1] += t11 * wz[k];
                h[2] += t10 * dz[k];
                h[4] += t01 * dz[k];
            }
            // trilinear weights are linear along each axis: no second derivative
            if HESSIAN && N == 4 {
                h[0] += t20 * wz[k];
                h[3] += t02 * wz[k];
                h[5] += t00 * ddz[k];
            }
        }
        let s = self.spacing;
        let hess = if HESSIAN {
            DMat3::from_cols_array(&[h[0], h[1], h[2], h[1], h[3], h[4], h[2], h[4], h[5]])
                * (1.0 / (s * s))
        } else {
            DMat3::ZERO
        };
        (v, DVec3::new(gx, gy, gz) / s, hess)
    }

    /// The cells of `L` points of a trilinear grid: per axis and point the fraction `t`, and per
    /// point the coefficient numbers of the cell's eight corners, corner `m` taking the second
    /// node along axis `i` where bit `i` of `m` is set (clamped outside the grid). The nodes are
    /// whole numbers in floating point, clamped there (NaN to 0), so that every point takes the
    /// same vector operations.
    #[inline(always)]
    fn trilinear_cells<const L: usize>(&self, x: [DVec3; L]) -> ([[f64; L]; 3], [[usize; 8]; L]) {
        let [nx, ny, nz] = self.dims;
        let strides = [1.0, nx as f64, (nx * ny) as f64];
        let mut t = [[0.0; L]; 3];
        // per axis and point: the first node's and the second node's offsets (equal if clamped)
        let (mut first, mut step) = ([[0.0; L]; 3], [[0.0; L]; 3]);
        for (a, n) in [nx, ny, nz].into_iter().enumerate() {
            let top = (n - 1) as f64;
            for l in 0..L {
                let u = (x[l][a] - self.origin[a]) / self.spacing;
                let b = u.floor();
                t[a][l] = u - b;
                let (i0, i1) = (b.max(0.0).min(top), (b + 1.0).max(0.0).min(top));
                first[a][l] = i0 * strides[a];
                step[a][l] = (i1 - i0) * strides[a];
            }
        }
        let mut taps = [[0usize; 8]; L];
        for (l, taps) in taps.iter_mut().enumerate() {
            let base = first[0][l] + first[1][l] + first[2][l];
            for (m, tap) in taps.iter_mut().enumerate() {
                let bit = |i: usize| if m >> i & 1 == 1 { step[i][l] } else { 0.0 };
                *tap = whole(base + bit(0) + bit(1) + bit(2));
            }
        }
        (t, taps)
    }

    /// Trilinear value, gradient and (with `HESSIAN`) Hessian at `L` points at once: each lane
    /// the operations of one point (x first, then y, then z; two taps a side leave no lanes
    /// within a point to fill), the points side by side in vector lanes. Every lane gets the bits
    /// of `L = 1`, with and without the Hessian.
    #[inline(always)]
    fn trilinear<const L: usize, const HESSIAN: bool>(
        &self,
        x: [DVec3; L],
    ) -> [(f64, DVec3, DMat3); L] {
        let s = self.spacing;
        let ([tx, ty, tz], taps) = self.trilinear_cells(x);
        let c = &self.coef;
        let mut corner = [[0.0; L]; 8];
        for l in 0..L {
            for (m, v) in corner.iter_mut().enumerate() {
                v[l] = c[taps[l][m]];
            }
        }
        // weights (1 − t, t), derivatives (−1, 1); accumulators start at zero as in a tap sum
        let w = |t: &[f64; L], i: usize| -> [f64; L] {
            std::array::from_fn(|l| if i == 0 { 1.0 - t[l] } else { t[l] })
        };
        let d = |i: usize| if i == 0 { -1.0 } else { 1.0 };
        let (mut v, mut gx, mut gy, mut gz) = ([0.0; L], [0.0; L], [0.0; L], [0.0; L]);
        let (mut hxy, mut hxz, mut hyz) = ([0.0; L], [0.0; L], [0.0; L]);
        let (wx0, wx1) = (w(&tx, 0), w(&tx, 1));
        for k in 0..2 {
            let wz = w(&tz, k);
            let (mut t00, mut t10, mut t01, mut t11) = ([0.0; L], [0.0; L], [0.0; L], [0.0; L]);
            for j in 0..2 {
                let wy = w(&ty, j);
                let (c0, c1) = (&corner[2 * j + 4 * k], &corner[1 + 2 * j + 4 * k]);
                for l in 0..L {
                    let r0 = 0.0 + c0[l] * wx0[l] + c1[l] * wx1[l];
                    let r1 = 0.0 + c0[l] * d(0) + c1[l] * d(1);
                    t00[l] += r0 * wy[l];
                    t10[l] += r1 * wy[l];
                    t01[l] += r0 * d(j);
                    if HESSIAN {
                        t11[l] += r1 * d(j);
                    }
                }
            }
            for l in 0..L {
                v[l] += t00[l] * wz[l];
                gx[l] += t10[l] * wz[l];
                gy[l] += t01[l] * wz[l];
                gz[l] += t00[l] * d(k);
                if HESSIAN {
                    hxy[l] += t11[l] * wz[l];
                    hxz[l] += t10[l] * d(k);
                    hyz[l] += t01[l] * d(k);
                }
            }
        }
        std::array::from_fn(|l| {
            // trilinear weights are linear along each axis: no second derivative
            let hess = if HESSIAN {
                let (xy, xz, yz) = (hxy[l], hxz[l], hyz[l]);
                DMat3::from_cols_array(&[0.0, xy, xz, xy, 0.0, yz, xz, yz, 0.0]) * (1.0 / (s * s))
            } else {
                DMat3::ZERO
            };
            (v[l], DVec3::new(gx[l], gy[l], gz[l]) / s, hess)
        })
    }

    /// Value, gradient and Hessian at `x`.
    pub fn eval(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        self.eval_at(Width::widest(), x)
    }

    /// [`Self::eval`] with vectors of `width` (which the CPU must offer): the same bits at every
    /// width.
    pub fn eval_at(&self, width: Width, x: DVec3) -> (f64, DVec3, DMat3) {
        match width {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.eval_avx512(x) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.eval_avx2(x) },
            _ => self.eval_portable(x),
        }
    }

    #[inline(always)]
    fn eval_portable(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        match self.interp {
            Interp::Tricubic => self.contract::<4, true>(x),
            Interp::Trilinear => self.contract_rows::<2, true>(x),
        }
    }

    /// The same operations in the same order with 256-bit vectors: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn eval_avx2(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        self.eval_portable(x)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn eval_avx512(&self, x: DVec3) -> (f64, DVec3, DMat3) {
        self.eval_portable(x)
    }

    /// Value and gradient at `x` (the same bits as [`Self::eval`]'s, without the Hessian): what
    /// ray tracing needs.
    pub fn value_grad(&self, x: DVec3) -> (f64, DVec3) {
        self.value_grad_at(Width::widest(), x)
    }

    /// [`Self::value_grad`] with vectors of `width` (which the CPU must offer): the same bits at every
    /// width.
    pub fn value_grad_at(&self, width: Width, x: DVec3) -> (f64, DVec3) {
        match width {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.value_grad_avx512(x) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.value_grad_avx2(x) },
            _ => self.value_grad_portable(x),
        }
    }

    #[inline(always)]
    fn value_grad_portable(&self, x: DVec3) -> (f64, DVec3) {
        let (v, g, _) = match self.interp {
            Interp::Tricubic => self.contract::<4, false>(x),
            Interp::Trilinear => self.contract_rows::<2, false>(x),
        };
        (v, g)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn value_grad_avx2(&self, x: DVec3) -> (f64, DVec3) {
        self.value_grad_portable(x)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn value_grad_avx512(&self, x: DVec3) -> (f64, DVec3) {
        self.value_grad_portable(x)
    }

    /// [`Self::eval`] at `L` points at once (trilinear grids side by side in vector lanes): each
    /// point the bits of [`Self::eval`].
    pub fn eval_lanes<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3, DMat3); L] {
        match Width::widest() {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.eval_lanes_avx512(x) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.eval_lanes_avx2(x) },
            _ => self.eval_lanes_portable(x),
        }
    }

    #[inline(always)]
    fn eval_lanes_portable<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3, DMat3); L] {
        match self.interp {
            Interp::Tricubic => {
                // a loop, not `map`: its closure would not be inlined into the vector builds
                let mut out = [(0.0, DVec3::ZERO, DMat3::ZERO); L];
                for (out, &x) in out.iter_mut().zip(&x) {
                    *out = self.contract::<4, true>(x);
                }
                out
            }
            Interp::Trilinear if L > 1 => self.trilinear::<L, true>(x),
            Interp::Trilinear => {
                let mut out = [(0.0, DVec3::ZERO, DMat3::ZERO); L];
                out[0] = self.contract_rows::<2, true>(x[0]);
                out
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn eval_lanes_avx2<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3, DMat3); L] {
        self.eval_lanes_portable(x)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn eval_lanes_avx512<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3, DMat3); L] {
        self.eval_lanes_portable(x)
    }

    /// [`Self::value_grad`] at `L` points at once (trilinear grids side by side in vector lanes):
    /// each point the bits of [`Self::value_grad`].
    pub fn value_grad_lanes<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3); L] {
        match Width::widest() {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.value_grad_lanes_avx512(x) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.value_grad_lanes_avx2(x) },
            _ => self.value_grad_lanes_portable(x),
        }
    }

    #[inline(always)]
    fn value_grad_lanes_portable<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3); L] {
        match self.interp {
            Interp::Tricubic => {
                // a loop, not `map`: its closure would not be inlined into the vector builds
                let mut out = [(0.0, DVec3::ZERO); L];
                for (out, &x) in out.iter_mut().zip(&x) {
                    let (v, g, _) = self.contract::<4, false>(x);
                    *out = (v, g);
                }
                out
            }
            Interp::Trilinear if L == 1 => {
                let (v, g, _) = self.contract_rows::<2, false>(x[0]);
                [(v, g); L]
            }
            Interp::Trilinear => {
                let all = self.trilinear::<L, false>(x);
                let mut out = [(0.0, DVec3::ZERO); L];
                for (out, &(v, g, _)) in out.iter_mut().zip(&all) {
                    *out = (v, g);
                }
                out
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn value_grad_lanes_avx2<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3); L] {
        self.value_grad_lanes_portable(x)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn value_grad_lanes_avx512<const L: usize>(&self, x: [DVec3; L]) -> [(f64, DVec3); L] {
        self.value_grad_lanes_portable(x)
    }

    /// `grad[i] += a·w_i(x) + b·∇w_i(x)` for every tap `i` at `x` (`w_i = ∂n/∂c_i`; clamped taps
    /// repeat an index and add): the adjoint's sparse accumulation into every coefficient, one
    /// axis at a time.
    pub fn scatter(&self, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        self.scatter_at(Width::widest(), x, a, b, grad)
    }

    /// [`Self::scatter`] with vectors of `width` (which the CPU must offer): the same bits at every
    /// width.
    pub fn scatter_at(&self, width: Width, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        match width {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.scatter_avx512(x, a, b, grad) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.scatter_avx2(x, a, b, grad) },
            _ => self.scatter_portable(x, a, b, grad),
        }
    }

    #[inline(always)]
    fn scatter_portable(&self, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        match self.interp {
            Interp::Tricubic => self.scatter_n::<4>(x, a, b, grad),
            Interp::Trilinear => self.scatter_n::<2>(x, a, b, grad),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn scatter_avx2(&self, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        self.scatter_portable(x, a, b, grad)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn scatter_avx512(&self, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        self.scatter_portable(x, a, b, grad)
    }

    #[inline(always)]
    fn scatter_n<const N: usize>(&self, x: DVec3, a: f64, b: DVec3, grad: &mut [f64]) {
        let Stencil {
            offsets: [ix, iy, iz],
            weights: [[wx, dx, _], [wy, dy, _], [wz, dz, _]],
        } = self.stencil::<N>(x);
        let b = b / self.spacing;
        let contiguous = ix[N - 1] == ix[0] + N - 1;
        for k in 0..N {
            // w_i = wx wy wz, ∇w_i = (dx wy wz, wx dy wz, wx wy dz): per row, wx·α + dx·β
            let (az, bz) = (wz[k] * a + dz[k] * b.z, wz[k] * b.y);
            for j in 0..N {
                let alpha = wy[j] * az + dy[j] * bz;
                let beta = wy[j] * wz[k] * b.x;
                let row = iz[k] + iy[j];
                if contiguous {
                    // the N taps of the row side by side (no clamped repeats): vector lanes
                    let start = row + ix[0];
                    for (l, g) in grad[start..start + N].iter_mut().enumerate() {
                        *g += wx[l] * alpha + dx[l] * beta;
                    }
                } else {
                    for i in 0..N {
                        grad[row + ix[i]] += wx[i] * alpha + dx[i] * beta;
                    }
                }
            }
        }
    }

    /// [`Self::scatter`] at `L` points, one after the other (the same additions in the same
    /// order), trilinear grids' weights computed side by side in vector lanes.
    pub fn scatter_lanes<const L: usize>(
        &self,
        x: [DVec3; L],
        a: [f64; L],
        b: [DVec3; L],
        grad: &mut [f64],
    ) {
        match Width::widest() {
            // SAFETY: the width is one the CPU offers.
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.scatter_lanes_avx512(x, a, b, grad) },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.scatter_lanes_avx2(x, a, b, grad) },
            _ => self.scatter_lanes_portable(x, a, b, grad),
        }
    }

    #[inline(always)]
    fn scatter_lanes_portable<const L: usize>(
        &self,
        x: [DVec3; L],
        a: [f64; L],
        b: [DVec3; L],
        grad: &mut [f64],
    ) {
        if self.interp == Interp::Tricubic || L == 1 {
            for l in 0..L {
                self.scatter_portable(x[l], a[l], b[l], grad);
            }
            return;
        }
        let ([tx, ty, tz], taps) = self.trilinear_cells(x);
        // per corner and point: w a + ∇w·b, as [`Self::scatter_n`] forms it
        let mut add = [[0.0; 8]; L];
        for l in 0..L {
            let w = |t: f64, i: usize| if i == 0 { 1.0 - t } else { t };
            let d = |i: usize| if i == 0 { -1.0 } else { 1.0 };
            let b = b[l] / self.spacing;
            for k in 0..2 {
                let wz = w(tz[l], k);
                let (az, bz) = (wz * a[l] + d(k) * b.z, wz * b.y);
                for j in 0..2 {
                    let wy = w(ty[l], j);
                    let alpha = wy * az + d(j) * bz;
                    let beta = wy * wz * b.x;
                    for i in 0..2 {
                        add[l][i + 2 * j + 4 * k] = w(tx[l], i) * alpha + d(i) * beta;
                    }
                }
            }
        }
        for (taps, add) in taps.iter().zip(&add) {
            for (&tap, &v) in taps.iter().zip(add) {
                grad[tap] += v;
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn scatter_lanes_avx2<const L: usize>(
        &self,
        x: [DVec3; L],
        a: [f64; L],
        b: [DVec3; L],
        grad: &mut [f64],
    ) {
        self.scatter_lanes_portable(x, a, b, grad)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn scatter_lanes_avx512<const L: usize>(
        &self,
        x: [DVec3; L],
        a: [f64; L],
        b: [DVec3; L],
        grad: &mut [f64],
    ) {
        self.scatter_lanes_portable(x, a, b, grad)
    }

    /// The value alone at `x` (no derivatives): the inside–outside test of a signed-distance grid.
    pub fn value(&self, x: DVec3) -> f64 {
        let u = (x - self.origin) / self.spacing;
        let base = DVec3::new(floor(u.x), floor(u.y), floor(u.z));
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

/// A whole number `0 ≤ x < 2⁵²` held in an `f64` as an integer, by the bits of `x + 2⁵²` (whose
/// mantissa then holds `x` exactly): a vector add and subtract, where a conversion would check
/// for overflow lane by lane.
#[inline(always)]
fn whole(x: f64) -> usize {
    const TWO52: f64 = 4_503_599_627_370_496.0;
    ((x + TWO52).to_bits() - TWO52.to_bits()) as usize
}

/// `x.floor()` without a call into libm, which the baseline x86-64 build makes (it has no rounding
/// instruction): exact for `|x| < 2⁶³`, where grid coordinates lie.
#[inline(always)]
pub(crate) fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points inside the test grid, in its clamped margin, and near its far corner.
    const POINTS: [DVec3; 3] = [
        DVec3::new(-0.41, 0.23, 0.77),
        DVec3::new(-1.7, 1.4, -0.6),
        DVec3::new(0.49, 0.69, 1.79),
    ];

    /// A 6×5×7 grid of smooth samples.
    fn test_grid(interp: Interp) -> GridField {
        let dims = [6, 5, 7];
        GridField::from_samples(
            DVec3::new(-1.0, -0.5, 0.0),
            0.3,
            dims,
            samples(dims),
            interp,
        )
        .unwrap()
    }

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

    /// The vectorised kernels (AVX2, AVX-512, as the CPU offers) give the portable kernels' bits:
    /// the same operations in the same order, in wider registers.
    #[test]
    fn vector_kernels_equal_the_portable_ones() {
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g = test_grid(interp);
            for width in Width::available() {
                for x in POINTS {
                    let at = format!("{interp:?} {width:?} at {x}");
                    assert_eq!(g.eval_at(width, x), g.eval_portable(x), "{at}");
                    assert_eq!(g.value_grad_at(width, x), g.value_grad_portable(x), "{at}");
                    let (mut a, mut b) = (vec![0.0; g.coef.len()], vec![0.0; g.coef.len()]);
                    g.scatter_at(width, x, 0.7, DVec3::new(-0.3, 1.1, 0.4), &mut a);
                    g.scatter_portable(x, 0.7, DVec3::new(-0.3, 1.1, 0.4), &mut b);
                    assert_eq!(a, b, "{at}");
                }
            }
        }
    }

    /// The value-only evaluation equals the full one, inside the grid and in its clamped margin.
    #[test]
    fn lane_kernels_equal_one_point_at_a_time() {
        // inside, in the clamped margin, on nodes and faces, and far outside on every side
        let points = [
            POINTS[0],
            POINTS[1],
            POINTS[2],
            DVec3::new(-1.0, -0.5, 0.0),
            DVec3::new(0.5, 0.7, 1.8),
            DVec3::new(-0.1, 0.1, 0.9),
            DVec3::new(1e9, -1e9, 3.0),
            DVec3::new(-7.0, 9.0, -1e12),
        ];
        let (a, b) = ([0.7, -1.3, 0.2, 2.0], DVec3::new(-0.3, 1.1, 0.4));
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g = test_grid(interp);
            for start in 0..points.len() - 3 {
                let x: [DVec3; 4] = std::array::from_fn(|l| points[start + l]);
                let at = format!("{interp:?} at {x:?}");
                assert_eq!(g.eval_lanes(x), x.map(|x| g.eval_portable(x)), "{at}");
                assert_eq!(
                    g.value_grad_lanes(x),
                    x.map(|x| g.value_grad_portable(x)),
                    "{at}"
                );
                let (mut lanes, mut one) = (vec![0.0; g.coef.len()], vec![0.0; g.coef.len()]);
                let bs = [b, -b, b * 2.0, DVec3::X];
                g.scatter_lanes(x, a, bs, &mut lanes);
                for l in 0..4 {
                    g.scatter_portable(x[l], a[l], bs[l], &mut one);
                }
                assert_eq!(lanes, one, "{at}");
            }
        }
    }

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

    /// The axis-by-axis contraction equals the sum over the 64 (8) tap products, and the scatter
    /// adds each coefficient's `a ∂n/∂c + b·∇∂n/∂c` ([`GridField::dcoef`]), in the clamped margin
    /// (repeated taps) too; `value_grad` is `eval`'s value and gradient, bit for bit.
    #[test]
    fn contraction_and_scatter_equal_the_tap_sums() {
        for interp in [Interp::Tricubic, Interp::Trilinear] {
            let g = test_grid(interp);
            for x in POINTS {
                let (mut v, mut gr, mut h) = (0.0, DVec3::ZERO, [[0.0; 3]; 3]);
                g.taps(x, |i, w, dw, hw| {
                    v += g.coef[i] * w;
                    gr += dw * g.coef[i];
                    for r in 0..3 {
                        for c in 0..3 {
                            h[r][c] += g.coef[i] * hw[r][c];
                        }
                    }
                });
                let (ev, eg, eh) = g.eval(x);
                let s = g.spacing;
                assert!((ev - v).abs() < 1e-13, "{interp:?} {x}: {ev} vs {v}");
                assert!(
                    (eg - gr / s).length() < 1e-12,
                    "{interp:?} {x}: {eg} vs {gr}"
                );
                for (r, row) in h.iter().enumerate() {
                    for (c, want) in row.iter().enumerate() {
                        let want = want / (s * s);
                        assert!(
                            (eh.col(c)[r] - want).abs() < 1e-11,
                            "{interp:?} H[{r}][{c}]"
                        );
                    }
                }
                assert_eq!(g.value_grad(x), (ev, eg));
                let (a, b) = (0.7, DVec3::new(-0.3, 1.1, 0.4));
                let mut grad = vec![0.0; g.coef.len()];
                g.scatter(x, a, b, &mut grad);
                for (i, got) in grad.iter().enumerate() {
                    let (w, dw) = g.dcoef(x, i);
                    let want = a * w + b.dot(dw);
                    assert!(
                        (got - want).abs() < 1e-12,
                        "{interp:?} coefficient {i}: {got} vs {want}"
                    );
                }
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
