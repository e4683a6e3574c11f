//! Small numerical helpers shared by the physics modules: complex numbers, frames, sphere sampling,
//! rotations and the deterministic per-chunk random streams of the Monte Carlo engine.

pub mod elementary;
pub mod polytope;
pub mod simd;
pub mod vmf;

use glam::DVec3;
use rand::SeedableRng;

/// Complex field values (`f64` real and imaginary parts).
pub type C64 = num_complex::Complex64;

/// The random-number generator used everywhere: xoshiro256++ (fast, 256-bit state, splittable by seed).
pub type Rng = rand_xoshiro::Xoshiro256PlusPlus;

/// `1 / (4π)`, the isotropic phase function value.
pub const INV_4PI: f64 = 1.0 / (4.0 * std::f64::consts::PI);

/// SplitMix64 finaliser: a bijective mixer used to derive independent stream seeds.
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The random stream of chunk `chunk` of a run with seed `seed` (design: "chunk `c` of a run with seed
/// `s` draws from its own RNG stream derived from `(s, c)`"), so results do not depend on scheduling.
pub fn stream_rng(seed: u64, stream: u64) -> Rng {
    Rng::seed_from_u64(splitmix64(
        splitmix64(seed) ^ splitmix64(stream.wrapping_add(0x5EED)),
    ))
}

/// Uniform `f64` in `[0, 1)` with 53 random bits.
#[inline]
pub fn uniform(rng: &mut Rng) -> f64 {
    use rand::Rng as _;
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Two unit vectors completing `n` (unit) to a right-handed orthonormal frame (Duff et al. 2017).
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0_f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Uniform direction on the unit sphere from two uniform numbers.
#[inline]
pub fn uniform_sphere(u1: f64, u2: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * u2;
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// The direction at polar cosine `mu` and azimuth `phi` about the unit axis `w`.
#[inline]
pub fn direction_about(w: DVec3, mu: f64, phi: f64) -> DVec3 {
    in_frame(orthonormal_basis(w), w, mu, phi)
}

/// [`direction_about`] in a frame continuous in `w` everywhere but at `w = −ẑ` (Frisvad 2012:
/// the rotation taking `ẑ` to `w`), where [`orthonormal_basis`] flips across `w_z = 0`. The
/// directions drawn from the same numbers then move continuously as `w` does, which a path
/// differentiated through its scattering directions needs.
#[inline]
pub fn direction_about_continuously(w: DVec3, mu: f64, phi: f64) -> DVec3 {
    let frame = if w.z > -1.0 + 1e-12 {
        let a = 1.0 / (1.0 + w.z);
        let c = -w.x * w.y * a;
        (
            DVec3::new(1.0 - w.x * w.x * a, c, -w.x),
            DVec3::new(c, 1.0 - w.y * w.y * a, -w.y),
        )
    } else {
        (DVec3::X, DVec3::NEG_Y)
    };
    in_frame(frame, w, mu, phi)
}

/// The direction at polar cosine `mu` and azimuth `phi` in the frame `(t, b, w)`.
#[inline]
fn in_frame((t, b): (DVec3, DVec3), w: DVec3, mu: f64, phi: f64) -> DVec3 {
    let s = (1.0 - mu * mu).max(0.0).sqrt();
    (t * (s * phi.cos()) + b * (s * phi.sin()) + w * mu).normalize()
}

/// Rotate `v` by `angle` (radians) about the unit `axis` (Rodrigues' formula).
pub fn rotate(v: DVec3, axis: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    v * c + axis.cross(v) * s + axis * axis.dot(v) * (1.0 - c)
}

/// `exp(i φ)`.
#[inline]
pub fn cis(phi: f64) -> C64 {
    let (s, c) = elementary::sin_cos(phi);
    C64::new(c, s)
}

/// A complex 3-vector `re + i im`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CVec3 {
    pub re: DVec3,
    pub im: DVec3,
}

impl CVec3 {
    /// `re + i im`.
    #[inline]
    pub fn new(re: DVec3, im: DVec3) -> Self {
        CVec3 { re, im }
    }

    /// `self · x` for a real vector `x`.
    #[inline]
    pub fn dot_real(&self, x: DVec3) -> C64 {
        C64::new(self.re.dot(x), self.im.dot(x))
    }

    /// The bilinear (not Hermitian) square `self · self`.
    #[inline]
    pub fn dot_self(&self) -> C64 {
        C64::new(
            self.re.length_squared() - self.im.length_squared(),
            2.0 * self.re.dot(self.im),
        )
    }

    /// The bilinear (not Hermitian) product `self · o`.
    #[inline]
    pub fn dot(&self, o: &CVec3) -> C64 {
        C64::new(
            self.re.dot(o.re) - self.im.dot(o.im),
            self.re.dot(o.im) + self.im.dot(o.re),
        )
    }

    /// `|re|² + |im|²`.
    #[inline]
    pub fn norm_sqr(&self) -> f64 {
        self.re.length_squared() + self.im.length_squared()
    }

    /// `conj(self) · x` for a real vector `x`.
    #[inline]
    pub fn conj_dot(&self, x: DVec3) -> C64 {
        C64::new(self.re.dot(x), -self.im.dot(x))
    }

    /// Component orthogonal to the unit real vector `n`.
    #[inline]
    pub fn tangential(&self, n: DVec3) -> CVec3 {
        CVec3 {
            re: self.re - n * self.re.dot(n),
            im: self.im - n * self.im.dot(n),
        }
    }

    /// `self + x` for a real vector `x`.
    #[inline]
    pub fn add_real(&self, x: DVec3) -> CVec3 {
        CVec3 {
            re: self.re + x,
            im: self.im,
        }
    }

    /// `z · self` for a complex scalar `z`.
    #[inline]
    pub fn scale(&self, z: C64) -> CVec3 {
        CVec3 {
            re: self.re * z.re - self.im * z.im,
            im: self.im * z.re + self.re * z.im,
        }
    }
}

impl std::ops::Add for CVec3 {
    type Output = CVec3;
    #[inline]
    fn add(self, o: CVec3) -> CVec3 {
        CVec3 {
            re: self.re + o.re,
            im: self.im + o.im,
        }
    }
}

/// Gauss–Legendre nodes and weights on `[-1, 1]` (Newton on `P_n`, exact for degree `2n − 1`).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for j in 2..=n {
                let p2 = ((2 * j - 1) as f64 * z * p1 - (j - 1) as f64 * p0) / j as f64;
                p0 = p1;
                p1 = p2;
            }
            let p = if n == 0 { 1.0 } else { p1 };
            dp = n as f64 * (z * p - p0) / (z * z - 1.0);
            let dz = p / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal() {
        for n in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(0.3, -0.4, 0.2).normalize(),
            DVec3::X,
        ] {
            let (t, b) = orthonormal_basis(n);
            assert!((t.length() - 1.0).abs() < 1e-12 && (b.length() - 1.0).abs() < 1e-12);
            assert!(t.dot(n).abs() < 1e-12 && b.dot(n).abs() < 1e-12 && t.dot(b).abs() < 1e-12);
            assert!((t.cross(b) - n).length() < 1e-12);
        }
    }

    #[test]
    fn rotation_keeps_length_and_angle() {
        let v = rotate(DVec3::Z, DVec3::Y, 0.3);
        assert!((v.length() - 1.0).abs() < 1e-12);
        assert!((v.dot(DVec3::Z) - 0.3f64.cos()).abs() < 1e-12);
        assert!(v.x > 0.0);
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        let (x, w) = gauss_legendre(7);
        for d in 0..14 {
            let q: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(d)).sum();
            let exact = if d % 2 == 1 {
                0.0
            } else {
                2.0 / (d + 1) as f64
            };
            assert!((q - exact).abs() < 1e-14, "degree {d}: {q} vs {exact}");
        }
    }

    #[test]
    fn streams_differ_and_repeat() {
        use rand::Rng as _;
        let a = stream_rng(1, 0).next_u64();
        assert_eq!(a, stream_rng(1, 0).next_u64());
        assert_ne!(a, stream_rng(1, 1).next_u64());
        assert_ne!(a, stream_rng(2, 0).next_u64());
    }
}
