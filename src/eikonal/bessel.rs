//! Cylindrical harmonics `u = J_m(k r) cos(m φ)` (the ultrasonic index model of paper 002, Eq. 15)
//! with their gradient, Hessian and `k`-derivatives, from the plane-wave (Jacobi–Anger) integral
//!
//! `J_m(k r) e^{i m φ} = (i^{-m} / 2π) ∫₀^{2π} e^{i k (x cos t + y sin t)} e^{i m t} dt`.
//!
//! The integrand is periodic and entire, so the trapezoid rule converges exponentially: with `N`
//! nodes the error is the aliased orders `J_{m ± N}(k r)`, negligible once `N` exceeds
//! `k r + m` by a margin that grows like `(k r)^{1/3}`. Derivatives in `x`, `y` and `k` only bring
//! down factors `i k cos t`, `i k sin t`, `i (x cos t + y sin t)`, so there are no `1/r`
//! singularities at the axis (unlike the cylindrical-coordinate formulas of paper 002, Eqs. 26–31).

use glam::{DMat3, DVec3};

/// `u`, `∇u`, `∇²u` and the `k`-derivatives `∂u/∂k`, `∇(∂u/∂k)` of `J_m(k r) cos(m φ)`, with `r`,
/// `φ` the cylindrical coordinates about the z axis (`u` does not depend on z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Harmonic {
    pub u: f64,
    pub grad: DVec3,
    pub hessian: DMat3,
    pub du_dk: f64,
    pub dgrad_dk: DVec3,
}

/// Number of trapezoid nodes for argument `z = k r` and order `m`: aliasing error below 1e-16.
pub(crate) fn nodes(z: f64, m: u32) -> usize {
    (z + m as f64 + 12.0 * z.cbrt() + 24.0).ceil() as usize
}

/// The cylindrical harmonic of order `m` and radial wavenumber `k` at `x`.
pub fn harmonic(k: f64, m: u32, x: DVec3) -> Harmonic {
    let r = (x.x * x.x + x.y * x.y).sqrt();
    let n = nodes(k.abs() * r, m);
    let (s0, c0) = (-(m as f64) * std::f64::consts::FRAC_PI_2).sin_cos(); // i^{-m}
    let (sd, cd) = (std::f64::consts::TAU / n as f64).sin_cos();
    let (mut ct, mut st) = (1.0, 0.0); // cos t_j, sin t_j by rotation
    let (mut u, mut gx, mut gy) = (0.0, 0.0, 0.0);
    let (mut hxx, mut hxy, mut hyy) = (0.0, 0.0, 0.0);
    let (mut du, mut dgx, mut dgy) = (0.0, 0.0, 0.0);
    for j in 0..n {
        let p = x.x * ct + x.y * st;
        let (sp, cp) = (k * p + m as f64 * std::f64::consts::TAU * j as f64 / n as f64).sin_cos();
        // term = i^{-m} e^{i phase} = a + i b
        let a = c0 * cp - s0 * sp;
        let b = c0 * sp + s0 * cp;
        u += a;
        gx -= ct * b;
        gy -= st * b;
        hxx -= ct * ct * a;
        hxy -= ct * st * a;
        hyy -= st * st * a;
        du -= p * b;
        let db = b + k * p * a;
        dgx -= ct * db;
        dgy -= st * db;
        (ct, st) = (ct * cd - st * sd, st * cd + ct * sd);
    }
    let w = 1.0 / n as f64;
    let k2 = k * k * w;
    Harmonic {
        u: u * w,
        grad: DVec3::new(gx, gy, 0.0) * (k * w),
        hessian: DMat3::from_cols(
            DVec3::new(hxx * k2, hxy * k2, 0.0),
            DVec3::new(hxy * k2, hyy * k2, 0.0),
            DVec3::ZERO,
        ),
        du_dk: du * w,
        dgrad_dk: DVec3::new(dgx, dgy, 0.0) * w,
    }
}

/// The Bessel function of the first kind `J_m(z)` (the harmonic on the positive x axis).
pub fn bessel_j(m: u32, z: f64) -> f64 {
    harmonic(1.0, m, DVec3::new(z, 0.0, 0.0)).u
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tabulated values (Abramowitz & Stegun, Table 9.1) to 1e-14.
    #[test]
    fn bessel_values_match_tables() {
        let table = [
            (0, 1.0, 0.765_197_686_557_966_6),
            (1, 1.0, 0.440_050_585_744_933_5),
            (0, 5.0, -0.177_596_771_314_338_3),
            (1, 5.0, -0.327_579_137_591_465_2),
            (2, 1.0, 0.114_903_484_931_900_5),
            (0, 10.0, -0.245_935_764_451_348_3),
            (1, 10.0, 0.043_472_746_168_861_44),
        ];
        for (m, z, want) in table {
            let got = bessel_j(m, z);
            assert!(
                (got - want).abs() < 1e-14,
                "J_{m}({z}) = {got}, want {want}"
            );
        }
        // J_m(0) = δ_m0 and the recurrence J_{m-1} + J_{m+1} = (2m/z) J_m at a large argument
        assert!((bessel_j(0, 0.0) - 1.0).abs() < 1e-15 && bessel_j(3, 0.0).abs() < 1e-15);
        let z = 37.3;
        for m in 1..8 {
            let lhs = bessel_j(m - 1, z) + bessel_j(m + 1, z);
            let rhs = 2.0 * m as f64 / z * bessel_j(m, z);
            assert!(
                (lhs - rhs).abs() < 1e-13,
                "recurrence at m = {m}: {lhs} vs {rhs}"
            );
        }
    }

    /// Derivatives against central differences, and the 2-D Helmholtz equation `∇²u = −k² u`.
    #[test]
    fn harmonic_derivatives() {
        let (k, h) = (3.7, 1e-5);
        for m in [0, 1, 2, 5] {
            for x in [
                DVec3::new(0.31, -0.22, 0.4),
                DVec3::new(0.0, 0.0, 1.0),
                DVec3::new(-1.3, 2.1, 0.0),
            ] {
                let hm = harmonic(k, m, x);
                let trace = hm.hessian.x_axis.x + hm.hessian.y_axis.y;
                assert!((trace + k * k * hm.u).abs() < 1e-11, "Helmholtz m = {m}");
                for a in 0..3 {
                    let mut e = DVec3::ZERO;
                    e[a] = h;
                    let (p, q) = (harmonic(k, m, x + e), harmonic(k, m, x - e));
                    let fd = (p.u - q.u) / (2.0 * h);
                    assert!((hm.grad[a] - fd).abs() < 1e-8, "m = {m} grad[{a}]");
                    let fdg = (p.grad - q.grad) / (2.0 * h);
                    assert!(
                        (hm.hessian.col(a) - fdg).length() < 1e-7,
                        "m = {m} hess {a}"
                    );
                }
                let (p, q) = (harmonic(k + h, m, x), harmonic(k - h, m, x));
                assert!((hm.du_dk - (p.u - q.u) / (2.0 * h)).abs() < 1e-8);
                assert!((hm.dgrad_dk - (p.grad - q.grad) / (2.0 * h)).length() < 1e-7);
                // cos(m φ) angular dependence
                let r = (x.x * x.x + x.y * x.y).sqrt();
                let want = bessel_j(m, k * r) * (m as f64 * x.y.atan2(x.x)).cos();
                assert!((hm.u - want).abs() < 1e-14, "m = {m}: {} vs {want}", hm.u);
            }
        }
    }
}
