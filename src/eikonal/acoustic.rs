//! Ultrasound in physical units and the index it sculpts (paper 002, Sec. 7.2, Eq. 15).
//!
//! A phased array of transducer elements, each a line source parallel to the z axis (the
//! infinite-length transducer Eq. 15 assumes), radiates into the medium. The complex pressure
//! amplitude is the superposition of the elements' cylindrical waves,
//!
//! `P(x) = Σ_j c_j H₀⁽¹⁾(k ρ_j) e^{−α ρ_j}`, `ρ_j` the distance from element `j`'s line,
//!
//! `p(x, t) = Re[P(x) e^{−iΩt}]`, and the index follows the pressure through the piezo-optic
//! coefficient, `n = n0 + (dn/dp) p`. Each element is given by the pressure amplitude it alone
//! produces at a reference distance and its phase. A ring of elements driven with phases
//! `m θ_j` gives inside the ring the Bessel pattern `J_m(k r) cos(m φ)` of Eq. 15 (Graf's
//! addition theorem), plus orders `m ± N, m ± 2N, …` that a ring of `N` elements aliases in.
//!
//! Attenuation multiplies each wave by `e^{−α ρ}`: the far-field form of the Hankel function of
//! the complex wavenumber `k + iα`, exact to `O(α/k)` (10⁻³ in tissue at 1 MHz).

use glam::{DMat3, DVec3};
use num_complex::Complex64 as C64;

/// Ultrasound of one frequency in a medium, and the scene's length unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ultrasound {
    /// Drive frequency, Hz.
    pub frequency: f64,
    /// Speed of sound, m/s.
    pub sound_speed: f64,
    /// Amplitude attenuation per metre and hertz (nepers; linear in frequency, as tissue's).
    pub attenuation: f64,
    /// Metres per scene length unit.
    pub unit: f64,
}

impl Ultrasound {
    /// The wavenumber `2π f / c`, per scene length unit.
    pub fn wavenumber(&self) -> f64 {
        std::f64::consts::TAU * self.frequency / self.sound_speed * self.unit
    }

    /// The amplitude attenuation at this frequency, nepers per scene length unit.
    pub fn alpha(&self) -> f64 {
        self.attenuation * self.frequency * self.unit
    }
}

/// Nepers per metre and hertz of an attenuation given in dB/(cm·MHz).
pub fn nepers_per_metre_hertz(db_per_cm_mhz: f64) -> f64 {
    db_per_cm_mhz * 1e-6 * 100.0 / (20.0 * std::f64::consts::LOG10_E)
}

/// The piezo-optic coefficient `dn/dp` (per pascal) of the Lorentz–Lorenz relation: the index
/// follows the density, `dn/dρ = (n² − 1)(n² + 2)/(6 n ρ)`, and the density the pressure
/// adiabatically, `dρ/dp = 1/c²`.
pub fn lorentz_lorenz(n0: f64, density: f64, sound_speed: f64) -> f64 {
    let n2 = n0 * n0;
    (n2 - 1.0) * (n2 + 2.0) / (6.0 * n0 * density * sound_speed * sound_speed)
}

/// One element: a line source through `(x, y)` parallel to z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Element {
    pub x: f64,
    pub y: f64,
    /// The pressure amplitude this element alone produces at the array's reference distance, Pa.
    pub amplitude: f64,
    /// Drive phase, radians.
    pub phase: f64,
}

/// A phased array of line elements and the index its pressure gives (`n0` where it is silent).
#[derive(Clone, Debug, PartialEq)]
pub struct PhasedArray {
    pub n0: f64,
    /// `dn/dp`, per pascal.
    pub piezo_optic: f64,
    pub ultrasound: Ultrasound,
    /// The distance from an element at which its `amplitude` is stated, scene units.
    pub reference: f64,
    /// A common factor on every element's amplitude (the drive's gain; 1 as given).
    pub gain: f64,
    pub elements: Vec<Element>,
}

/// An element's parameters: amplitude, phase, x, y.
const ELEMENT_PARAMS: usize = 4;

/// One element's wave `f(ρ) = H₀⁽¹⁾(k ρ) e^{−α ρ}` at a point: `ρ`, the unit vector from the
/// element's line (in the xy plane), `f`, `f'`, `f''`.
struct Radial {
    rho: f64,
    e: [f64; 2],
    f: C64,
    f1: C64,
    f2: C64,
}

/// `(H₀⁽¹⁾(z), H₁⁽¹⁾(z))` for `z > 0`.
#[inline]
fn hankel01(z: f64) -> (C64, C64) {
    (
        C64::new(libm::j0(z), libm::y0(z)),
        C64::new(libm::j1(z), libm::y1(z)),
    )
}

/// `H_n⁽¹⁾(z)` for any integer order, `z > 0`.
pub fn hankel(n: i32, z: f64) -> C64 {
    C64::new(libm::jn(n, z), libm::yn(n, z))
}

/// A complex scalar field's value, gradient and Hessian (in the xy plane: nothing depends on z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wave {
    pub value: C64,
    pub grad: [C64; 2],
    /// `[∂xx, ∂xy, ∂yy]`.
    pub hessian: [C64; 3],
}

impl Wave {
    const ZERO: Wave = Wave {
        value: C64::new(0.0, 0.0),
        grad: [C64::new(0.0, 0.0); 2],
        hessian: [C64::new(0.0, 0.0); 3],
    };

    fn add_scaled(&mut self, c: C64, w: &Wave) {
        self.value += c * w.value;
        for i in 0..2 {
            self.grad[i] += c * w.grad[i];
        }
        for i in 0..3 {
            self.hessian[i] += c * w.hessian[i];
        }
    }

    /// `Re[s · self]` as an index increment: value, gradient, Hessian.
    fn real_part(&self, s: C64) -> (f64, DVec3, DMat3) {
        let re = |z: C64| (s * z).re;
        let (hxx, hxy, hyy) = (
            re(self.hessian[0]),
            re(self.hessian[1]),
            re(self.hessian[2]),
        );
        (
            re(self.value),
            DVec3::new(re(self.grad[0]), re(self.grad[1]), 0.0),
            DMat3::from_cols(
                DVec3::new(hxx, hxy, 0.0),
                DVec3::new(hxy, hyy, 0.0),
                DVec3::ZERO,
            ),
        )
    }
}

impl PhasedArray {
    /// The wave of one element at distance `rho` from its line: `f`, `f'`, `f''`.
    fn radial_at(&self, rho: f64) -> (C64, C64, C64) {
        let (k, alpha) = (self.ultrasound.wavenumber(), self.ultrasound.alpha());
        let z = k * rho;
        let (h0, h1) = hankel01(z);
        let decay = (-alpha * rho).exp();
        // H₁' = H₀ − H₁/z
        (
            h0 * decay,
            (-h1 * k - h0 * alpha) * decay,
            (-(h0 - h1 / z) * (k * k) + h1 * (2.0 * alpha * k) + h0 * (alpha * alpha)) * decay,
        )
    }

    fn radial(&self, e: &Element, x: DVec3) -> Radial {
        let (dx, dy) = (x.x - e.x, x.y - e.y);
        let rho = dx.hypot(dy);
        let (f, f1, f2) = self.radial_at(rho);
        Radial {
            rho,
            e: [dx / rho, dy / rho],
            f,
            f1,
            f2,
        }
    }

    /// The wave of one element of unit weight, `H₀⁽¹⁾(k ρ) e^{−α ρ}`, at `x`.
    fn element_wave(&self, e: &Element, x: DVec3) -> Wave {
        let Radial {
            rho,
            e: [ex, ey],
            f,
            f1,
            f2,
        } = self.radial(e, x);
        let t = f1 / rho;
        Wave {
            value: f,
            grad: [f1 * ex, f1 * ey],
            hessian: [
                f2 * (ex * ex) + t * (1.0 - ex * ex),
                (f2 - t) * (ex * ey),
                f2 * (ey * ey) + t * (1.0 - ey * ey),
            ],
        }
    }

    /// `|H₀⁽¹⁾(k d)| e^{−α d}` at the reference distance: an element of unit weight's amplitude
    /// there.
    fn reference_amplitude(&self) -> f64 {
        let (k, alpha) = (self.ultrasound.wavenumber(), self.ultrasound.alpha());
        let z = k * self.reference;
        libm::j0(z).hypot(libm::y0(z)) * (-alpha * self.reference).exp()
    }

    /// Element `j`'s weight `c_j = g A_j e^{iψ_j} / (|H₀(k d)| e^{−α d})`.
    fn weight(&self, e: &Element, reference: f64) -> C64 {
        C64::from_polar(self.gain * e.amplitude / reference, e.phase)
    }

    /// The complex pressure amplitude `P` (Pa) with its gradient and Hessian at `x`.
    pub fn pressure(&self, x: DVec3) -> Wave {
        let reference = self.reference_amplitude();
        let mut p = Wave::ZERO;
        for e in &self.elements {
            p.add_scaled(self.weight(e, reference), &self.element_wave(e, x));
        }
        p
    }

    /// `n = n0 + (dn/dp) Re[P e^{−iΩt}]` at the instant `omega_t`, with gradient and Hessian.
    pub fn eval(&self, x: DVec3, omega_t: f64) -> (f64, DVec3, DMat3) {
        let s = C64::from_polar(self.piezo_optic, -omega_t);
        let (n, g, h) = self.pressure(x).real_part(s);
        (self.n0 + n, g, h)
    }

    /// Parameter `which` of the design: `n0`, the gain, the frequency (Hz), then each element's
    /// amplitude, phase (radians) and position `x`, `y` (scene units: the transducer's
    /// placement) at `3 + 4j` … `6 + 4j`.
    pub fn param_mut(&mut self, which: usize) -> Option<&mut f64> {
        match which {
            0 => Some(&mut self.n0),
            1 => Some(&mut self.gain),
            2 => Some(&mut self.ultrasound.frequency),
            _ => {
                let e = self.elements.get_mut((which - 3) / ELEMENT_PARAMS)?;
                Some(match (which - 3) % ELEMENT_PARAMS {
                    0 => &mut e.amplitude,
                    1 => &mut e.phase,
                    2 => &mut e.x,
                    _ => &mut e.y,
                })
            }
        }
    }

    /// The element and axis (0: x, 1: y) parameter `which` places, if it is a position.
    pub fn position_param(&self, which: usize) -> Option<(usize, usize)> {
        let j = which.checked_sub(3)? / ELEMENT_PARAMS;
        let k = (which - 3) % ELEMENT_PARAMS;
        (j < self.elements.len() && k >= 2).then_some((j, k - 2))
    }

    /// The names of [`Self::param_mut`]'s parameters: `n0`, `gain`, `frequency`,
    /// `amplitude_j`, `phase_j`, `x_j`, `y_j`.
    pub fn param_index(&self, name: &str) -> Option<usize> {
        match name {
            "n0" => return Some(0),
            "gain" => return Some(1),
            "frequency" => return Some(2),
            _ => {}
        }
        let (field, j) = name.rsplit_once('_')?;
        let j: usize = j.parse().ok().filter(|j| *j < self.elements.len())?;
        let k = ["amplitude", "phase", "x", "y"]
            .iter()
            .position(|f| *f == field)?;
        Some(3 + ELEMENT_PARAMS * j + k)
    }

    /// `(∂n/∂θ, ∇(∂n/∂θ))` for parameter `which` at the instant `omega_t`. The index is linear in
    /// the gain and in each element's weight (`∂c_j/∂A_j = c_j/A_j`, `∂c_j/∂ψ_j = i c_j`); an
    /// element's wave depends on its position `p_j` through `x − p_j`, so `∂/∂p_j = −∇` (its
    /// gradient for the value, its Hessian for the gradient). An
    /// element's wave depends on the frequency `s` only through `s ρ` (both `k` and `α` are
    /// proportional to it), so `∂f/∂s = (ρ/s) f'`; the weights' normalisation at the reference
    /// distance moves likewise.
    pub fn dparam(&self, x: DVec3, omega_t: f64, which: usize) -> Option<(f64, DVec3)> {
        let s = C64::from_polar(self.piezo_optic, -omega_t);
        let reference = self.reference_amplitude();
        let real = |w: &Wave, c: C64| {
            let (d, g, _) = w.real_part(s * c);
            Some((d, g))
        };
        match which {
            0 => Some((1.0, DVec3::ZERO)),
            1 => real(&self.pressure(x), C64::new(1.0 / self.gain, 0.0)),
            2 => {
                let freq = self.ultrasound.frequency;
                let (fr, fr1, _) = self.radial_at(self.reference);
                // ∂ ln|f(d)| / ∂s: the weights' normalisation
                let dlog_ref = self.reference / freq * (fr.conj() * fr1).re / fr.norm_sqr();
                // per element `c (∂f/∂s − f ∂ln|f(d)|/∂s)` with `∂f/∂s = (ρ/s) f'`, and its
                // radial derivative `c ((f' + ρ f'')/s − f' ∂ln|f(d)|/∂s)`
                let mut dp = Wave::ZERO;
                for e in &self.elements {
                    let c = self.weight(e, reference);
                    let r = self.radial(e, x);
                    dp.value += c * (r.f1 * (r.rho / freq) - r.f * dlog_ref);
                    let radial = c * ((r.f1 + r.f2 * r.rho) / freq - r.f1 * dlog_ref);
                    dp.grad[0] += radial * r.e[0];
                    dp.grad[1] += radial * r.e[1];
                }
                real(&dp, C64::new(1.0, 0.0))
            }
            _ => {
                let e = self.elements.get((which - 3) / ELEMENT_PARAMS)?;
                let w = self.element_wave(e, x);
                let axis = match (which - 3) % ELEMENT_PARAMS {
                    0 => return real(&w, C64::from_polar(self.gain / reference, e.phase)),
                    1 => return real(&w, C64::i() * self.weight(e, reference)),
                    k => k - 2,
                };
                // −∂_axis of the element's wave: value from its gradient, gradient from its
                // Hessian's row
                let row = if axis == 0 {
                    [w.hessian[0], w.hessian[1]]
                } else {
                    [w.hessian[1], w.hessian[2]]
                };
                let shifted = Wave {
                    value: -w.grad[axis],
                    grad: [-row[0], -row[1]],
                    hessian: [C64::new(0.0, 0.0); 3],
                };
                real(&shifted, self.weight(e, reference))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `H₀⁽¹⁾` and `H₁⁽¹⁾` against tabulated values (Abramowitz & Stegun, Table 9.1).
    #[test]
    fn hankel_values_match_tables() {
        let (h0, h1) = hankel01(1.0);
        assert!((h0 - C64::new(0.765_197_686_557_966_6, 0.088_256_964_215_676_96)).norm() < 1e-14);
        assert!((h1 - C64::new(0.440_050_585_744_933_5, -0.781_212_821_300_288_7)).norm() < 1e-14);
        let (h0, _) = hankel01(10.0);
        assert!((h0 - C64::new(-0.245_935_764_451_348_3, 0.055_671_167_283_599_39)).norm() < 1e-14);
        assert!(
            (hankel(2, 1.0) - C64::new(0.114_903_484_931_900_5, -1.650_682_606_816_254)).norm()
                < 1e-13
        );
    }

    fn array(alpha: f64) -> PhasedArray {
        PhasedArray {
            n0: 1.33,
            piezo_optic: 1.5e-10,
            ultrasound: Ultrasound {
                frequency: 813e3,
                sound_speed: 1480.0,
                // alpha nepers per metre at 813 kHz
                attenuation: alpha / 813e3,
                unit: 1e-3,
            },
            reference: 2.0,
            gain: 1.0,
            elements: vec![
                Element {
                    x: 6.0,
                    y: 0.5,
                    amplitude: 2e6,
                    phase: 0.3,
                },
                Element {
                    x: -1.0,
                    y: 7.0,
                    amplitude: 1e6,
                    phase: -2.0,
                },
                Element {
                    x: -4.0,
                    y: -5.0,
                    amplitude: 3e6,
                    phase: 1.1,
                },
            ],
        }
    }

    /// The paper's 813 kHz in water is `k = 3.45` per mm (paper 002, Fig. 1 and Eq. 15).
    #[test]
    fn wavenumber_in_physical_units() {
        let k = array(0.0).ultrasound.wavenumber();
        assert!((k - 3.4515).abs() < 1e-4, "{k}");
        // 0.5 dB/(cm·MHz) at 2 MHz: 1 dB/cm = 11.51 Np/m
        assert!((nepers_per_metre_hertz(0.5) * 2e6 - 11.512_925_464_970_229).abs() < 1e-9);
        // Lorentz–Lorenz, (n² − 1)/(n² + 2) = K ρ, solved for n and differenced in ρ = ρ0 + p/c²
        let (n0, rho0, c) = (1.33, 1000.0, 1480.0);
        let big_k = (n0 * n0 - 1.0) / (n0 * n0 + 2.0) / rho0;
        let n = |rho: f64| ((1.0 + 2.0 * big_k * rho) / (1.0 - big_k * rho)).sqrt();
        let dp = 1e5;
        let fd = (n(rho0 + dp / (c * c)) - n(rho0 - dp / (c * c))) / (2.0 * dp);
        let ll = lorentz_lorenz(n0, rho0, c);
        assert!((ll / fd - 1.0).abs() < 1e-8, "{ll} vs {fd}");
    }

    /// An element's pressure amplitude at the reference distance is its `amplitude`.
    #[test]
    fn amplitude_is_stated_at_the_reference_distance() {
        for alpha in [0.0, 40.0] {
            let mut a = array(alpha);
            a.elements.truncate(1);
            let e = a.elements[0];
            for angle in [0.0f64, 1.0, 2.5] {
                let x = DVec3::new(e.x + 2.0 * angle.cos(), e.y + 2.0 * angle.sin(), 0.7);
                let p = a.pressure(x).value.norm();
                assert!((p / e.amplitude - 1.0).abs() < 1e-13, "{p}");
            }
        }
    }

    /// The gradient and Hessian against central differences (with and without attenuation), and
    /// the lossless pressure solves the Helmholtz equation `∇²P + k²P = 0`.
    #[test]
    fn derivatives_match_differences_and_helmholtz() {
        let x = DVec3::new(0.31, -0.22, 0.4);
        let h = 1e-5;
        for alpha in [0.0, 40.0] {
            // the excursion alone (n0 = 0), so differences keep its digits
            let a = PhasedArray {
                n0: 0.0,
                ..array(alpha)
            };
            for omega_t in [0.0, 1.3] {
                let (_, g, hs) = a.eval(x, omega_t);
                for axis in 0..3 {
                    let mut e = DVec3::ZERO;
                    e[axis] = h;
                    let (up, down) = (a.eval(x + e, omega_t), a.eval(x - e, omega_t));
                    let fd = (up.0 - down.0) / (2.0 * h);
                    assert!(
                        (g[axis] - fd).abs() < 1e-8 * g.length(),
                        "grad {axis}: {} vs {fd}",
                        g[axis]
                    );
                    let fdg = (up.1 - down.1) / (2.0 * h);
                    assert!(
                        (hs.col(axis) - fdg).length() < 1e-7 * g.length(),
                        "hessian col {axis}: {} vs {fdg}",
                        hs.col(axis)
                    );
                }
            }
        }
        let a = array(0.0);
        let k = a.ultrasound.wavenumber();
        let p = a.pressure(x);
        let residual = p.hessian[0] + p.hessian[2] + p.value * (k * k);
        assert!(
            residual.norm() < 1e-9 * (k * k * p.value.norm()),
            "{residual}"
        );
    }

    /// `N` elements on a ring of radius `R` driven with phases `m θ_j` give inside the ring
    /// (Graf's addition theorem) `P = N c Σ_{n ≡ m mod N} H_n(kR) J_n(kr) e^{inφ}`: the Bessel
    /// pattern of Eq. 15 and the orders the ring aliases in, summed here from `J_n`, `Y_n` of
    /// every order.
    #[test]
    fn a_ring_drives_the_bessel_pattern_of_graf() {
        let (big_r, m, count) = (9.0, 2, 6usize);
        let mut a = array(0.0);
        a.elements = (0..count)
            .map(|j| {
                let t = std::f64::consts::TAU * j as f64 / count as f64;
                Element {
                    x: big_r * t.cos(),
                    y: big_r * t.sin(),
                    amplitude: 1e5,
                    phase: m as f64 * t,
                }
            })
            .collect();
        let k = a.ultrasound.wavenumber();
        let c = 1e5 / a.reference_amplitude();
        for (r, phi) in [(0.0, 0.0), (0.7, 0.4), (2.5, -1.9), (4.1, 2.2)] {
            let x = DVec3::new(r * f64::cos(phi), r * f64::sin(phi), -3.0);
            // orders n = m + l N for all l: e^{inφ} H_n(kR) J_n(kr), summed to |n| ≤ 60
            let mut want = C64::new(0.0, 0.0);
            for l in -12i32..=12 {
                let n = m + l * count as i32;
                if n.abs() > 60 {
                    continue;
                }
                want += C64::from_polar(1.0, n as f64 * phi)
                    * hankel(n, k * big_r)
                    * libm::jn(n, k * r);
            }
            want *= c * count as f64;
            let got = a.pressure(x).value;
            assert!(
                (got - want).norm() < 1e-10 * want.norm().max(c),
                "at r = {r}: {got} vs {want}"
            );
        }
    }

    /// A ring of many elements driven in a standing pattern, amplitudes `|cos mθ_j|` with phases
    /// 0 or π (the paper's four elements (π, 0, π, 0) are the coarsest such ring, m = 2), is
    /// Eq. 15 inside the ring at every instant: `n = n0 + n_max J_m(k r) cos(mφ) cos(Ωt − arg H_m(kR))`
    /// with `n_max = (dn/dp) N c |H_m(kR)|` (Graf; the orders `±m + lN` it aliases in vanish for
    /// `N = 48` here), against the Bessel harmonic of the ultrasonic profile.
    #[test]
    fn a_standing_ring_is_the_ultrasonic_profile_of_eq_15() {
        let (big_r, m, count) = (9.0, 2u32, 48usize);
        let mut a = array(0.0);
        a.elements = (0..count)
            .map(|j| {
                let t = std::f64::consts::TAU * j as f64 / count as f64;
                let c = (m as f64 * t).cos();
                Element {
                    x: big_r * t.cos(),
                    y: big_r * t.sin(),
                    amplitude: 1e5 * c.abs(),
                    phase: if c < 0.0 { std::f64::consts::PI } else { 0.0 },
                }
            })
            .collect();
        let k = a.ultrasound.wavenumber();
        let h = hankel(m as i32, k * big_r);
        let n_max = a.piezo_optic * count as f64 * 1e5 / a.reference_amplitude() * h.norm();
        for omega_t in [0.0, 0.9, 2.0, 4.4] {
            let eq15 = crate::eikonal::Profile::Ultrasonic {
                n0: a.n0,
                n_max: n_max * (omega_t - h.arg()).cos(),
                k_r: k,
                m,
            };
            for x in [
                DVec3::new(0.3, 0.1, 0.0),
                DVec3::new(-1.2, 0.8, 5.0),
                DVec3::new(0.5, -1.7, -2.0),
            ] {
                let (n, g, hs) = a.eval(x, omega_t);
                let want = crate::eikonal::IndexField::eval(
                    &crate::eikonal::BoundedField::single(
                        eq15.clone(),
                        crate::eikonal::Bounds::Everywhere,
                        1.0,
                    ),
                    x,
                );
                assert!(
                    (n - want.0).abs() < 1e-12 * n_max,
                    "n at {x}: {n} vs {}",
                    want.0
                );
                assert!((g - want.1).length() < 1e-11 * n_max * k, "∇n at {x}");
                let dh = (hs - want.2)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f64, |a, b| a.max(b.abs()));
                assert!(dh < 1e-10 * n_max * k * k, "∇²n at {x}: {dh}");
            }
        }
    }
}
