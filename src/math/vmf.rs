//! Complex von Mises–Fisher functions `h(ω) = exp(c + μ·ω)` on the unit sphere, `μ` a complex
//! 3-vector (paper 000, Sec. 5, Eq. 19): evaluation, the sphere integral (Eq. 29), products, and the
//! convolution with a real lobe `exp(κ ω·ψ)`, exact and as a vMF (Eqs. 31–32).
//!
//! Values are kept as logarithms: a focused aperture `e^{-γ} e^{γ a·ω}` with `γ` in the hundreds
//! multiplies numbers near `e^{±γ}`, and only their product is of order one. The complex logarithm's
//! branch is immaterial because every result is exponentiated in the end.

use crate::math::{C64, CVec3};
use glam::DVec3;
use std::f64::consts::PI;

/// `h(ω) = exp(log_scale + μ·ω)`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vmf {
    pub log_scale: C64,
    pub mu: CVec3,
}

/// The principal square root (`Re ≥ 0`) without the polar form: `num_complex`'s goes through
/// `atan2` and `sincos`, which dominated the focused connections.
#[inline]
pub fn csqrt(z: C64) -> C64 {
    let (a, b) = (z.re, z.im);
    if a == 0.0 && b == 0.0 {
        return C64::default();
    }
    let t = (0.5 * (a.abs() + (a * a + b * b).sqrt())).sqrt();
    if a >= 0.0 {
        C64::new(t, b / (2.0 * t))
    } else {
        C64::new(b.abs() / (2.0 * t), t.copysign(b))
    }
}

/// `ln ∫ exp(μ·ω) dω = ln(4π sinh(q)/q)` with `q² = μ·μ` (paper 000, Eq. 29, Eq. 30).
///
/// `sinh(q)/q` is even in `q`, so either square root serves; the principal one (`Re q ≥ 0`) keeps
/// `e^{-2q}` bounded. Near `q = 0` a series replaces the 0/0 form.
#[inline]
pub fn log_sphere_integral(q2: C64) -> C64 {
    if q2.norm_sqr() < 1e-4 {
        // sinh(q)/q = Σ q^{2n}/(2n+1)!, truncated where the next term is below 1e-18
        let s = C64::new(1.0, 0.0) + q2 * (1.0 / 6.0 + q2 * (1.0 / 120.0 + q2 * (1.0 / 5040.0)));
        return s.ln() + (4.0 * PI).ln();
    }
    let q = csqrt(q2);
    // 4π sinh(q)/q = 2π e^{q} (1 − e^{−2q}) / q
    q + (C64::new(1.0, 0.0) - (-2.0 * q).exp()).ln() - q.ln() + (2.0 * PI).ln()
}

/// `(coth β − 1/β)/β`: the derivative of `ln(sinh β/β)` with respect to `β²/2`, the slope that
/// makes the vMF of [`Vmf::convolve`] match the exact convolution's logarithmic derivative at `w_o`.
/// Where `sinh β` vanishes (nearly imaginary `β`, far outside a focused beam) it falls back to the
/// large-`β` slope `1/β` of Eq. 32.
#[inline]
pub fn log_sinhc_slope(beta: C64) -> C64 {
    let one = C64::new(1.0, 0.0);
    if beta.norm() < 1e-2 {
        let b2 = beta * beta;
        return one / 3.0 - b2 / 45.0 + b2 * b2 * (2.0 / 945.0);
    }
    let e = (-2.0 * beta).exp();
    let denominator = one - e;
    if denominator.norm() < 1e-8 {
        return one / beta;
    }
    ((one + e) / denominator - one / beta) / beta
}

/// `d/dβ` of [`log_sinhc_slope`] on the same branches: `(1 + 1/β² − coth²β)/β − S/β` with
/// `S = (coth β − 1/β)/β`; its series below `|β| = 0.1`, `−1/β²` where the fallback `1/β` is taken.
#[inline]
pub fn log_sinhc_slope_derivative(beta: C64) -> C64 {
    let one = C64::new(1.0, 0.0);
    if beta.norm() < 0.1 {
        // S = 1/3 − β²/45 + 2β⁴/945 − β⁶/4725 + 2β⁸/93555 − …: the closed form below cancels
        // to ~1e-13/|β|³ here
        let b2 = beta * beta;
        return beta
            * (-2.0 / 45.0 + b2 * (8.0 / 945.0 + b2 * (-6.0 / 4725.0 + b2 * (16.0 / 93555.0))));
    }
    let e = (-2.0 * beta).exp();
    let denominator = one - e;
    if denominator.norm() < 1e-8 {
        return -one / (beta * beta);
    }
    let coth = (one + e) / denominator;
    let s = (coth - one / beta) / beta;
    (one + one / (beta * beta) - coth * coth) / beta - s / beta
}

/// A cosine `μ` about the mean direction of the real vMF distribution of concentration `κ`
/// (density `∝ e^{κμ}`, any sign of `κ`) from one uniform number, by inverting its CDF.
#[inline]
pub fn sample_cosine(kappa: f64, u: f64) -> f64 {
    if kappa.abs() < 1e-8 {
        return 1.0 - 2.0 * u;
    }
    // about the pole the lobe points to, so e^{−2|κ|} never overflows
    let a = kappa.abs();
    let t = (1.0 + (u + (1.0 - u) * (-2.0 * a).exp()).ln() / a).clamp(-1.0, 1.0);
    if kappa > 0.0 { t } else { -t }
}

impl Vmf {
    pub fn new(log_scale: C64, mu: CVec3) -> Self {
        Vmf { log_scale, mu }
    }

    /// `h(ω)`.
    #[inline]
    pub fn eval(&self, w: DVec3) -> C64 {
        (self.log_scale + self.mu.dot_real(w)).exp()
    }

    /// `ln ∫ h(ω) dω` (Eq. 29).
    #[inline]
    pub fn log_integral(&self) -> C64 {
        self.log_scale + log_sphere_integral(self.mu.dot_self())
    }

    /// `∫ h(ω) dω` (Eq. 29).
    #[inline]
    pub fn integral(&self) -> C64 {
        self.log_integral().exp()
    }

    /// The pointwise product, itself a vMF: parameters add.
    #[inline]
    pub fn product(&self, other: &Vmf) -> Vmf {
        Vmf {
            log_scale: self.log_scale + other.log_scale,
            mu: self.mu + other.mu,
        }
    }

    /// `ln ∫ h(ψ) exp(κ ω·ψ) dψ`: the exact convolution with a real lobe of concentration `κ`,
    /// evaluated at the unit direction `w`. As a function of `w` it is not a vMF.
    #[inline]
    pub fn log_convolve_at(&self, kappa: f64, w: DVec3) -> C64 {
        self.log_scale + log_sphere_integral(self.mu.add_real(w * kappa).dot_self())
    }

    /// The convolution with the lobe `exp(κ ω·ψ)` approximated by a vMF in `ω` about the unit
    /// direction `w_o` (Eqs. 31–32). With `β² = (μ + κ w_o)·(μ + κ w_o)` the exact result is
    /// `4π sinh(β(ω))/β(ω)` and `β(ω)²` is affine in `μ·ω`; linearising its logarithm in `μ·ω` at
    /// `w_o` gives a vMF. Eq. 32 takes the slope `κ/β` and drops `e^{−β}` (the large-`β` limit); here
    /// the value and the slope at `w_o` are exact, `κ (coth β − 1/β)/β`, which is 10–100× more
    /// accurate for wide apertures and identical for narrow ones.
    pub fn convolve(&self, kappa: f64, w_o: DVec3) -> Vmf {
        let m = self.mu.add_real(w_o * kappa);
        let beta2 = m.dot_self();
        let at_o = self.log_scale + log_sphere_integral(beta2);
        let beta = csqrt(beta2);
        let slope = kappa * log_sinhc_slope(beta);
        Vmf {
            log_scale: at_o - slope * self.mu.dot_real(w_o),
            mu: self.mu.scale(slope),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{gauss_legendre, orthonormal_basis};

    /// `∫ f dω` by Gauss–Legendre in `cos θ` about `pole` times the trapezoid rule in `φ`
    /// (spectrally accurate for the smooth periodic integrand).
    fn quadrature(pole: DVec3, n_mu: usize, n_phi: usize, f: impl Fn(DVec3) -> C64) -> C64 {
        let (x, w) = gauss_legendre(n_mu);
        let (t, b) = orthonormal_basis(pole);
        let mut acc = C64::default();
        for (mu, wm) in x.iter().zip(&w) {
            let s = (1.0 - mu * mu).sqrt();
            for j in 0..n_phi {
                let phi = 2.0 * PI * j as f64 / n_phi as f64;
                let d = t * (s * phi.cos()) + b * (s * phi.sin()) + pole * *mu;
                acc += f(d) * *wm;
            }
        }
        acc * (2.0 * PI / n_phi as f64)
    }

    fn rel(a: C64, b: C64) -> f64 {
        (a - b).norm() / b.norm()
    }

    /// A focused aperture at a point `d` from its focus: `μ = γ a + i k d` (Eq. 27).
    fn aperture(gamma: f64, kd: DVec3) -> Vmf {
        Vmf::new(
            C64::new(-gamma, 0.0),
            CVec3::new(DVec3::new(0.1, -0.2, 1.0).normalize() * gamma, kd),
        )
    }

    #[test]
    fn sphere_integral_matches_quadrature() {
        for (gamma, kd) in [
            (0.0, DVec3::ZERO),
            (0.0, DVec3::new(3.0, 1.0, -2.0)),
            (2.0, DVec3::new(0.3, 0.0, 0.1)),
            (16.0, DVec3::new(5.0, -4.0, 9.0)),
            (60.0, DVec3::new(0.0, 20.0, 1.0)),
            (1e-4, DVec3::new(1e-4, 0.0, 0.0)),
        ] {
            let h = aperture(gamma, kd);
            let q = quadrature(h.mu.re.normalize_or(DVec3::Z), 160, 160, |w| h.eval(w));
            let e = rel(h.integral(), q);
            assert!(e < 1e-10, "γ = {gamma}, kd = {kd}: rel. error {e:e}");
        }
    }

    #[test]
    fn slope_derivative_matches_differences() {
        for beta in [
            C64::new(0.005, 0.003),
            C64::new(0.3, -0.1),
            C64::new(1.3, 0.4),
            C64::new(12.0, -30.0),
            C64::new(0.2, 5.0),
        ] {
            let h = 1e-6 * beta.norm().max(1e-2);
            let fd = (log_sinhc_slope(beta + h) - log_sinhc_slope(beta - h)) / (2.0 * h);
            let d = log_sinhc_slope_derivative(beta);
            assert!(
                (d - fd).norm() < 1e-6 * fd.norm().max(1e-3),
                "β = {beta}: {d} vs {fd}"
            );
        }
        // the series and the closed form join at |β| = 0.1
        for arg in [0.0, 1.0, 2.5] {
            let b = C64::from_polar(0.1, arg);
            let (inside, outside) = (
                log_sinhc_slope_derivative(b * (1.0 - 1e-9)),
                log_sinhc_slope_derivative(b * (1.0 + 1e-9)),
            );
            assert!(
                (inside - outside).norm() < 1e-8 * inside.norm(),
                "{b}: {inside} vs {outside}"
            );
        }
    }

    #[test]
    fn small_argument_series_joins_the_closed_form() {
        for q2 in [
            C64::new(0.0099, 0.0),
            C64::new(-0.0099, 0.0),
            C64::new(0.007, 0.007),
        ] {
            let series = log_sphere_integral(q2);
            let q = q2.sqrt();
            let closed = (q.sinh() / q * (4.0 * PI)).ln();
            assert!(
                (series - closed).norm() < 1e-13,
                "{q2}: {series} vs {closed}"
            );
        }
    }

    #[test]
    fn csqrt_is_the_principal_root() {
        for z in [
            C64::new(4.0, 0.0),
            C64::new(-4.0, 0.0),
            C64::new(-4.0, -1e-300),
            C64::new(3.0, -7.0),
            C64::new(-1e6, 2.0),
            C64::new(1e-12, -3e-12),
        ] {
            let (a, b) = (csqrt(z), z.sqrt());
            assert!(
                (a - b).norm() <= 1e-14 * b.norm().max(1e-300),
                "{z}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn product_adds_parameters() {
        let a = aperture(3.0, DVec3::new(1.0, 2.0, 0.5));
        let b = Vmf::new(C64::new(-0.5, 0.0), CVec3::new(DVec3::X * 4.0, DVec3::ZERO));
        let w = DVec3::new(0.3, 0.5, -0.2).normalize();
        assert!(rel(a.product(&b).eval(w), a.eval(w) * b.eval(w)) < 1e-14);
    }

    #[test]
    fn exact_convolution_matches_quadrature() {
        let w = DVec3::new(0.2, 0.1, 1.0).normalize();
        for (gamma, kd, kappa) in [
            (4.0, DVec3::new(2.0, 0.0, 1.0), 10.0),
            (30.0, DVec3::new(0.0, 6.0, 3.0), 80.0),
            (0.0, DVec3::new(1.0, 1.0, 1.0), 0.0),
        ] {
            let h = aperture(gamma, kd);
            let q = quadrature(
                (h.mu.re + w * kappa).normalize_or(DVec3::Z),
                200,
                200,
                |psi| h.eval(psi) * (kappa * w.dot(psi)).exp(),
            );
            let e = rel(h.log_convolve_at(kappa, w).exp(), q);
            assert!(e < 1e-10, "γ = {gamma}, κ = {kappa}: rel. error {e:e}");
        }
    }

    /// The vMF approximation of the convolution is exact at `w_o` and for `κ = 0`; about `w_o` its
    /// error grows with the angle. Over focused apertures `γ = 1, 10, 100`, points up to a few
    /// wavelengths from focus and lobes `κ = 1…1000`, the error half an aperture width `0.5/√γ`
    /// from `w_o` (relative to the peak) is below 6e-2 for the widest aperture `γ = 1` and below
    /// 5e-3 for `γ ≥ 10`; the table is in `docs/speckle.md`.
    #[test]
    fn approximate_convolution_error_over_its_range() {
        let axis = DVec3::new(0.1, -0.2, 1.0).normalize();
        for (gamma, bound) in [(1.0, 6e-2), (10.0, 5e-3), (100.0, 5e-5)] {
            for kappa in [1.0, 30.0, 1000.0] {
                for kd in [
                    DVec3::ZERO,
                    DVec3::new(2.0, 0.0, 1.0),
                    DVec3::new(0.0, 6.0, -3.0),
                ] {
                    // the lobe normalised to 1 at its peak, as a phase-function lobe is
                    let mut h = aperture(gamma, kd);
                    h.log_scale -= kappa;
                    let approx = h.convolve(kappa, axis);
                    let at_o = rel(approx.eval(axis), h.log_convolve_at(kappa, axis).exp());
                    assert!(at_o < 1e-9, "γ = {gamma}, κ = {kappa}: {at_o:e} at w_o");
                    let (t, _) = orthonormal_basis(axis);
                    let w = crate::math::rotate(axis, t, 0.5 / gamma.sqrt());
                    let exact = h.log_convolve_at(kappa, w).exp();
                    let peak = h.log_convolve_at(kappa, axis).exp().norm();
                    let err = (approx.eval(w) - exact).norm() / peak.max(exact.norm());
                    assert!(err < bound, "γ {gamma} κ {kappa} kd {kd}: {err:.2e}");
                }
            }
        }
        let h = aperture(5.0, DVec3::new(1.0, 0.0, 0.0));
        let flat = h.convolve(0.0, axis);
        let w = DVec3::new(0.5, 0.5, -0.2).normalize();
        assert!(rel(flat.eval(w), h.integral()) < 1e-12);
    }
}
