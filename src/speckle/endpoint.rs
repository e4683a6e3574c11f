//! Lights and views as path endpoints: the complex transmission `ξ` and attenuation `τ` of a
//! connection from a vertex inside the medium (paper 001, Eqs. 13 and 19), and for focused lights
//! and views the aperture integrals `Υ` of paper 000 (Eqs. 15–18) in closed form.

use crate::math::simd::Width;
use crate::math::vmf::{
    Vmf, csqrt, log_sinhc_slope, log_sinhc_slope_derivative, log_sphere_integral,
};
use crate::math::{C64, CVec3, cis};
use crate::medium::lobes::Lobes;
use crate::medium::{Medium, PhaseFunction};
use glam::DVec3;

/// A light (source) of unit amplitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Plane wave `exp(i k d·x)` propagating along unit `direction`.
    PlaneWave { direction: DVec3 },
    /// Isotropic point source `exp(i k r) / r` at `position`.
    Point { position: DVec3 },
    /// Focused beam: plane waves apodised by the von Mises–Fisher mask `exp(γ (w·axis − 1))`,
    /// `u(x) = ∫ m(w) exp(i k w·(x − focus)) dw = 4π e^{-γ} sinh(q)/q`, `q² = μ·μ`,
    /// `μ = γ axis + i k (x − focus)` (paper 000, Eqs. 10, 24, 29).
    Focused {
        focus: DVec3,
        axis: DVec3,
        gamma: f64,
    },
}

/// A view (sensor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    /// Far-field sensor collecting light leaving along unit `direction`: `ξ(x → v) = exp(-i k v·x)`.
    FarField { direction: DVec3 },
    /// Point sensor at `position`: `ξ(x → v) = exp(i k r) / r`.
    Point { position: DVec3 },
    /// Focused sensor collecting far-field directions `w` with the mask `exp(γ (w·axis − 1))`,
    /// refocused at `focus`: `ξ(x → v) = 4π e^{-γ} sinh(q)/q`, `μ = γ axis − i k (x − focus)`.
    Focused {
        focus: DVec3,
        axis: DVec3,
        gamma: f64,
    },
}

/// An endpoint seen from a vertex: either "far" (a direction) or "near" (a point). By reciprocity a
/// plane-wave light propagating along `d` is the far endpoint with outgoing direction `-d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Endpoint {
    /// Far endpoint reached by leaving along unit `dir`.
    Far { dir: DVec3 },
    /// Near endpoint at `pos`.
    Near { pos: DVec3 },
}

/// A connection from a vertex to an endpoint: `prop = τ ξ` and the unit direction `dir` in which the
/// light leaves the vertex towards the endpoint.
#[derive(Clone, Copy, Debug, Default)]
pub struct Connection {
    pub prop: C64,
    pub dir: DVec3,
    /// Length of the connection inside the medium (`τ = exp(-σ_t inside / 2)`).
    pub inside: f64,
}

impl Endpoint {
    /// `τ(x, e) ξ(x → e)` and the leaving direction, for a vertex `x` inside the medium.
    #[inline]
    pub fn connect(&self, x: DVec3, medium: &Medium, k: f64) -> Connection {
        match *self {
            Endpoint::Far { dir } => {
                let inside = medium.geometry.exit_distance(x, dir);
                Connection {
                    prop: cis(-k * dir.dot(x)) * medium.amplitude_attenuation(inside),
                    dir,
                    inside,
                }
            }
            Endpoint::Near { pos } => {
                let d = pos - x;
                let r = d.length();
                let dir = d / r;
                let inside = medium.geometry.exit_distance(x, dir).min(r);
                let tau = medium.amplitude_attenuation(inside);
                Connection {
                    prop: cis(k * r) * (tau / r),
                    dir,
                    inside,
                }
            }
        }
    }
}

/// A focused light or view as the Monte Carlo estimators see it (paper 000, Sec. 5.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lens {
    pub focus: DVec3,
    pub axis: DVec3,
    pub gamma: f64,
    /// `+1` for a light (the aperture sends plane waves), `−1` for a view (it collects them).
    pub sign: f64,
}

impl Lens {
    /// The aperture function at vertex `x` as a vMF over propagation directions `ω` (Eqs. 17, 26–27):
    /// `exp(−γ − σ_t h + ((γ + σ_t h/2) a + i σ k (x − focus))·ω)`, `σ` the sign. The attenuation
    /// `e^{−σ_t d(ω)/2}` of each direction is taken to first order about the axis, where the path
    /// inside is `h`: a boundary across the axis gives `d = h/(ω·a) ≈ h (2 − ω·a)`, which keeps the
    /// vMF form. Paper 000 takes `d = h` for every direction (Eq. 25); on a 6 λ cube at optical
    /// depth 1 that overestimates focused intensities by 8.6 % (`σ_a = 0.5`) and 2.7 % (0.25)
    /// against the exact attenuation, the first-order form by 2.2 % and 0.4 %.
    #[inline]
    pub fn aperture(&self, x: DVec3, medium: &Medium, k: f64) -> Vmf {
        self.aperture_and_path(x, medium, k).0
    }

    /// The aperture and the length `h` of the axis path inside the medium (its attenuation).
    #[inline]
    pub fn aperture_and_path(&self, x: DVec3, medium: &Medium, k: f64) -> (Vmf, f64) {
        let inside = medium.geometry.exit_distance(x, self.axis * -self.sign);
        let half = 0.5 * medium.sigma_t() * inside;
        (
            Vmf::new(
                C64::new(-self.gamma - 2.0 * half, 0.0),
                CVec3::new(
                    self.axis * (self.gamma + half),
                    (x - self.focus) * (self.sign * k),
                ),
            ),
            inside,
        )
    }
}

/// A light or view of any kind, as the path samplers connect to it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Terminal {
    Ray(Endpoint),
    Lens(Lens),
}

impl From<Light> for Terminal {
    fn from(l: Light) -> Self {
        match l {
            // by reciprocity a plane wave along `d` is the far endpoint left along `-d`
            Light::PlaneWave { direction } => Terminal::Ray(Endpoint::Far { dir: -direction }),
            Light::Point { position } => Terminal::Ray(Endpoint::Near { pos: position }),
            Light::Focused { focus, axis, gamma } => Terminal::Lens(Lens {
                focus,
                axis,
                gamma,
                sign: 1.0,
            }),
        }
    }
}

impl From<View> for Terminal {
    fn from(v: View) -> Self {
        match v {
            View::FarField { direction } => Terminal::Ray(Endpoint::Far { dir: direction }),
            View::Point { position } => Terminal::Ray(Endpoint::Near { pos: position }),
            View::Focused { focus, axis, gamma } => Terminal::Lens(Lens {
                focus,
                axis,
                gamma,
                sign: -1.0,
            }),
        }
    }
}

/// A terminal seen from one vertex: a ray connection, or a lens's aperture function there.
#[derive(Clone, Copy, Debug)]
pub enum Seen {
    Ray(Connection),
    Aperture {
        vmf: Vmf,
        /// `μ·μ`, shared by every direction and lobe.
        mu2: C64,
        sign: f64,
        axis: DVec3,
        /// Length of the axis path inside the medium (attenuated as `e^{−σ_t d/2}`).
        inside: f64,
    },
}

impl Default for Seen {
    fn default() -> Self {
        Seen::Ray(Connection::default())
    }
}

impl Terminal {
    /// What the terminal looks like from vertex `x`.
    #[inline]
    pub fn seen_from(&self, x: DVec3, medium: &Medium, k: f64) -> Seen {
        match self {
            Terminal::Ray(e) => Seen::Ray(e.connect(x, medium, k)),
            Terminal::Lens(lens) => {
                let (vmf, inside) = lens.aperture_and_path(x, medium, k);
                Seen::Aperture {
                    mu2: vmf.mu.dot_self(),
                    vmf,
                    sign: lens.sign,
                    axis: lens.axis,
                    inside,
                }
            }
        }
    }

    pub fn is_lens(&self) -> bool {
        matches!(self, Terminal::Lens(_))
    }
}

/// `e^{c} 4π sinh(q)/q` for `q² = q2` (Eq. 29) without logarithms: the hot path of every focused
/// connection. The same lane as [`SphereBatch`], so both give the same bits.
#[inline]
fn sphere_integral_scaled(c: C64, q2: C64) -> C64 {
    let (re, im, held) = sphere_lane(c.re, q2.re, q2.im);
    let value = if held {
        C64::new(re, im)
    } else {
        sphere_integral_special(c.re, q2)
    };
    turned(value, c.im)
}

/// `value e^{i angle}`, untouched (bit for bit) at angle 0: the imaginary part of a lobe's scale
/// applied after the real-scale lane.
#[inline]
fn turned(value: C64, angle: f64) -> C64 {
    if angle == 0.0 {
        value
    } else {
        value * cis(angle)
    }
}

/// One lobe's `e^{c} 4π sinh(q)/q` for a real `c` and `q² = a + ib`, without a branch:
/// `2π (e^{c+q} − e^{c−q}) / q` with the principal root (`Re q ≥ 0`); both exponentials turn by
/// `Im q` (opposite ways), so one sine and cosine serve, and exponents below −708 (terms below
/// `e^{−708}` of the aperture's scale) are clamped there. The flag is false where the kernels do
/// not hold (`|q²| < 1e-2`, where a series takes over; `|Im q| > 2²⁰`; `c + Re q > 708`; NaN):
/// [`sphere_integral_special`] redoes those.
#[inline(always)]
fn sphere_lane(c: f64, a: f64, b: f64) -> (f64, f64, bool) {
    use crate::math::elementary::{exp_in_range, sin_cos_in_range};
    let norm2 = a * a + b * b;
    let t = (0.5 * (a.abs() + norm2.sqrt())).sqrt();
    let u = b / (2.0 * t);
    let (qr, qi) = if a >= 0.0 {
        (t, u)
    } else {
        (u.abs(), t.copysign(b))
    };
    let ahead_exponent = c + qr;
    let held = norm2 >= 1e-4 && qi.abs() <= 1_048_576.0 && ahead_exponent <= 708.0;
    let ahead = exp_in_range(ahead_exponent.max(-708.0));
    let behind = exp_in_range((c - qr).max(-708.0));
    let (sin, cos) = sin_cos_in_range(qi);
    let (sinh_re, sinh_im) = ((ahead - behind) * cos, (ahead + behind) * sin);
    // × 2π q̄ / |q|²
    let f = 2.0 * std::f64::consts::PI / (qr * qr + qi * qi);
    (
        (sinh_re * qr + sinh_im * qi) * f,
        (sinh_im * qr - sinh_re * qi) * f,
        held,
    )
}

/// The cases [`sphere_lane`] leaves: `q² ≈ 0` by the series of `sinh q/q`, the rest with the
/// standard library's exponentials.
#[cold]
fn sphere_integral_special(c: f64, q2: C64) -> C64 {
    if q2.norm_sqr() < 1e-4 {
        return (log_sphere_integral(q2) + c).exp();
    }
    let q = csqrt(q2);
    (c + q).exp() * (C64::new(1.0, 0.0) - (-2.0 * q).exp()) * (2.0 * std::f64::consts::PI) / q
}

/// Many lobes' terms `e^{c} 4π sinh(q)/q` (Eq. 29, real `c`) at once, laid out by component so
/// the loop vectorises (with AVX2 or AVX-512 where the CPU has them: the same operations in the same order,
/// so the same bits as `sphere_integral_scaled` and [`Seen::amplitude`]); the rare lanes the
/// kernels do not cover are redone one by one. A vertex's connections to every focused light and
/// view go through one batch.
#[derive(Clone, Debug, Default)]
pub struct SphereBatch {
    c: Vec<f64>,
    a: Vec<f64>,
    b: Vec<f64>,
    re: Vec<f64>,
    im: Vec<f64>,
}

impl SphereBatch {
    pub fn clear(&mut self) {
        self.c.clear();
        self.a.clear();
        self.b.clear();
    }

    /// Queues one term; its index for [`Self::value`].
    #[inline]
    pub fn push(&mut self, c: f64, q2: C64) -> usize {
        self.c.push(c);
        self.a.push(q2.re);
        self.b.push(q2.im);
        self.c.len() - 1
    }

    /// Evaluates every queued term, with the widest vectors the CPU offers.
    pub fn evaluate(&mut self) {
        self.evaluate_at(Width::widest());
    }

    /// [`Self::evaluate`] with vectors of `width` (which the CPU must offer): the same bits at
    /// every width.
    pub fn evaluate_at(&mut self, width: Width) {
        let n = self.c.len();
        self.re.resize(n, 0.0);
        self.im.resize(n, 0.0);
        match width {
            // SAFETY: the width is one the CPU offers (`Width::widest`, `Width::available`).
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.lanes_avx512() },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.lanes_avx2() },
            _ => self.lanes(),
        }
        for i in 0..n {
            if self.re[i].is_nan() {
                let v = sphere_integral_special(self.c[i], C64::new(self.a[i], self.b[i]));
                (self.re[i], self.im[i]) = (v.re, v.im);
            }
        }
    }

    /// Term `i` of the last [`Self::evaluate`].
    #[inline]
    pub fn value(&self, i: usize) -> C64 {
        C64::new(self.re[i], self.im[i])
    }

    /// Every lane, lanes the kernels do not cover marked NaN.
    #[inline(always)]
    fn lanes(&mut self) {
        let n = self.c.len();
        let (c, a, b) = (&self.c[..n], &self.a[..n], &self.b[..n]);
        let (re, im) = (&mut self.re[..n], &mut self.im[..n]);
        for i in 0..n {
            let (r, j, held) = sphere_lane(c[i], a[i], b[i]);
            re[i] = if held { r } else { f64::NAN };
            im[i] = j;
        }
    }

    /// The same operations in the same order with 256-bit vectors: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn lanes_avx2(&mut self) {
        self.lanes();
    }

    /// The same with 512-bit vectors: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn lanes_avx512(&mut self) {
        self.lanes();
    }
}

/// One unit-weight lobe's `Υ` for an aperture `vmf` with `μ·μ = mu2` and `μ·w = mw` (Eq. 29), and
/// its `q²`.
#[inline]
fn lobe_integral(vmf: &Vmf, mu2: C64, mw: C64, kappa: f64) -> (C64, C64) {
    let q2 = lobe_q2(mu2, mw, kappa);
    (sphere_integral_scaled(vmf.log_scale - kappa, q2), q2)
}

/// `q² = μ·μ + 2κ μ·w + κ²` of a lobe of concentration `κ` about `w` (Eq. 29).
#[inline]
fn lobe_q2(mu2: C64, mw: C64, kappa: f64) -> C64 {
    mu2 + mw * (2.0 * kappa) + kappa * kappa
}

impl Seen {
    /// Length inside the medium over which this connection is attenuated.
    #[inline]
    pub fn inside(&self) -> f64 {
        match self {
            Seen::Ray(c) => c.inside,
            Seen::Aperture { inside, .. } => *inside,
        }
    }

    /// The amplitude joining the terminal to a path at this vertex, where the path's direction
    /// there is given by `u` with scattering cosine `u·dir` for a ray terminal (`u = −w₁` at the
    /// first vertex, `u = w_in` at the last). For a lens it is `Υ` (Eqs. 15–16): the aperture
    /// convolved with the amplitude's vMF lobes, exactly (Eq. 29 applied per lobe).
    #[inline]
    pub fn amplitude(&self, u: DVec3, phase: &PhaseFunction, lobes: &Lobes) -> C64 {
        match self {
            Seen::Ray(c) => c.prop * phase.amplitude(u.dot(c.dir)),
            Seen::Aperture { vmf, mu2, sign, .. } => {
                // the path direction the aperture's plane waves scatter into (light) or from (view)
                let mw = vmf.mu.dot_real(u * -*sign);
                lobes
                    .lobes
                    .iter()
                    .map(|l| l.weight * lobe_integral(vmf, *mu2, mw, l.kappa).0)
                    .sum()
            }
        }
    }

    /// [`Self::amplitude`] of a lens in two steps: its lobes' terms queued in `batch` (the index
    /// of the first returned), then [`Self::amplitude_from`] once the batch is evaluated. `None`
    /// for a ray terminal. Needs a real aperture scale, as apertures seen from a vertex have.
    #[inline]
    pub fn queue_lobes(&self, u: DVec3, lobes: &Lobes, batch: &mut SphereBatch) -> Option<usize> {
        let Seen::Aperture { vmf, mu2, sign, .. } = self else {
            return None;
        };
        debug_assert!(vmf.log_scale.im == 0.0);
        let mw = vmf.mu.dot_real(u * -*sign);
        let first = batch.c.len();
        for l in &lobes.lobes {
            batch.push(vmf.log_scale.re - l.kappa, lobe_q2(*mu2, mw, l.kappa));
        }
        Some(first)
    }

    /// The amplitude from the lobes [`Self::queue_lobes`] queued at `first`: the same bits as
    /// [`Self::amplitude`].
    #[inline]
    pub fn amplitude_from(batch: &SphereBatch, first: usize, lobes: &Lobes) -> C64 {
        lobes
            .lobes
            .iter()
            .enumerate()
            .map(|(m, l)| l.weight * batch.value(first + m))
            .sum()
    }

    /// One unit-weight lobe `exp(κ(μ − 1))` of `Υ` for a lens (Eq. 29) and, when `slope` is set,
    /// its derivatives with respect to `κ` and to `t`, a concentration added along the lens axis
    /// (`μ → μ + t a`: how the linearised attenuation moves with `σ_t`): with
    /// `q² = μ·μ + 2κ μ·w + κ²`, `∂ ln Υ_κ/∂κ = −1 + S(q) (μ·w + κ)` and
    /// `∂ ln Υ_κ/∂t = S(q) (μ·a + κ w·a)`, `S` the log-slope of `sinh q/q` in `q²/2`. Zero for a
    /// ray terminal.
    #[inline]
    pub fn aperture_lobe(&self, u: DVec3, kappa: f64, slope: bool) -> LobeValue {
        let Seen::Aperture {
            vmf,
            mu2,
            sign,
            axis,
            ..
        } = self
        else {
            return LobeValue::default();
        };
        let w = u * -*sign;
        let mw = vmf.mu.dot_real(w);
        let (value, q2) = lobe_integral(vmf, *mu2, mw, kappa);
        if !slope {
            return LobeValue {
                value,
                ..Default::default()
            };
        }
        let s = log_sinhc_slope(csqrt(q2));
        LobeValue {
            value,
            d_kappa: value * (s * (mw + kappa) - 1.0),
            d_axis: value * s * (vmf.mu.dot_real(*axis) + kappa * w.dot(*axis)),
            d_axis_view: C64::default(),
        }
    }

    /// The single-scattering amplitude of light `self` and view `view` at one vertex (Eq. 5 for
    /// rays, Eq. 18 for lenses). Two lenses need the vMF convolution approximation (Eqs. 31–32),
    /// taken about the view's axis (see [`convolve_lobe`]).
    #[inline]
    pub fn single(&self, view: &Seen, phase: &PhaseFunction, lobes: &Lobes) -> C64 {
        match (self, view) {
            (l, Seen::Ray(cv)) => l.amplitude(-cv.dir, phase, lobes) * cv.prop,
            (Seen::Ray(cl), v) => v.amplitude(-cl.dir, phase, lobes) * cl.prop,
            (
                Seen::Aperture { vmf: al, .. },
                Seen::Aperture {
                    vmf: av, axis: ax, ..
                },
            ) => {
                let view_bound = log_aperture_mass(av);
                lobes
                    .lobes
                    .iter()
                    .map(|l| lens_pair_term(&convolve_lobe(al, l, *ax), av, view_bound))
                    .sum()
            }
        }
    }
}

/// One amplitude lobe's share of Eq. 18 for a light lens, prepared once per vertex: the weight,
/// the light's aperture convolved with the lobe as a vMF about the view axis (Eqs. 31–32), and the
/// light's part of the magnitude bound.
#[derive(Clone, Copy, Debug, Default)]
pub struct ConvolvedLobe {
    weight: C64,
    vmf: Vmf,
    bound: f64,
}

/// The light aperture `al` convolved with lobe `l` about `axis` (the view's). Expanding about the
/// view axis or about the peak of the product changes Eq. 18 by less than 1e-4 of its value in the
/// quadrature checks, so the cheaper choice is taken.
#[inline]
pub fn convolve_lobe(al: &Vmf, l: &crate::medium::lobes::Lobe, axis: DVec3) -> ConvolvedLobe {
    let mut lobe = *al;
    lobe.log_scale -= l.kappa;
    // |Υ_l| ≤ e^{Re c} 4π sinh(γ+κ)/(γ+κ)
    let reach = al.mu.re.length() + l.kappa;
    ConvolvedLobe {
        weight: l.weight,
        vmf: lobe.convolve(l.kappa, axis),
        bound: lobe.log_scale.re + log_sphere_integral(C64::new(reach * reach, 0.0)).re,
    }
}

/// `ln ∫ |ã_v| dω`, the view's part of the magnitude bound of Eq. 18.
#[inline]
pub fn log_aperture_mass(av: &Vmf) -> f64 {
    av.log_scale.re + log_sphere_integral(C64::new(av.mu.re.length_squared(), 0.0)).re
}

/// A unit-weight lobe's share of an aperture integral and its derivatives: with respect to the
/// lobe's `κ`, and to a concentration added along the (light's) axis and along the view's axis.
#[derive(Clone, Copy, Debug, Default)]
pub struct LobeValue {
    pub value: C64,
    pub d_kappa: C64,
    pub d_axis: C64,
    pub d_axis_view: C64,
}

/// One unit-weight lobe's term of Eq. 18 for the light aperture `al` (axis `a_l`) and view
/// aperture `av` (axis `a`, about which the convolution is expanded), and, when `slope` is set,
/// its derivatives through the convolution approximation (Eqs. 31–32 with the exact slope):
/// `m = μ_l + κ a`, `β² = m·m`, slope `t = κ S(β)`, product `μ_p = t μ_l + μ_v`,
/// `ln P = c_l − κ + ln(4π sinh β/β) − t μ_l·a + c_v + ln(4π sinh q/q)`, `q² = μ_p·μ_p`.
/// With respect to `κ`: `−1 + S(β) m·a − t′ μ_l·a + S(q)(μ_p·μ_l) t′`,
/// `t′ = S(β) + κ S′(β) m·a/β`; to `μ_l → μ_l + ε a_l`: `S(β) m·a_l − t_ε μ_l·a − t a_l·a +
/// S(q) μ_p·(a_l t + μ_l t_ε)`, `t_ε = κ S′(β) m·a_l/β`; to `μ_v → μ_v + ε a`: `S(q) μ_p·a`.
/// Dropped terms (see [`lens_pair_term`]) have zero slope.
pub fn lens_pair_lobe(
    al: &Vmf,
    light_axis: DVec3,
    kappa: f64,
    axis: DVec3,
    av: &Vmf,
    view_bound: f64,
    slope: bool,
) -> LobeValue {
    let lobe = crate::medium::lobes::Lobe {
        weight: C64::new(1.0, 0.0),
        kappa,
    };
    let value = lens_pair_term(&convolve_lobe(al, &lobe, axis), av, view_bound);
    if !slope || value == C64::default() {
        return LobeValue {
            value,
            ..Default::default()
        };
    }
    let mw = al.mu.dot_real(axis);
    let m_vec = al.mu.add_real(axis * kappa);
    let m = mw + kappa;
    let beta = csqrt(m_vec.dot_self());
    let s_beta = log_sinhc_slope(beta);
    let s_prime = log_sinhc_slope_derivative(beta);
    let t = s_beta * kappa;
    let dt = s_beta + s_prime * kappa * m / beta;
    let p_mu = al.mu.scale(t) + av.mu;
    let s_q = log_sinhc_slope(csqrt(p_mu.dot_self()));
    let d_kappa = s_beta * m - 1.0 - dt * mw + s_q * p_mu.dot(&al.mu) * dt;
    let m_al = m_vec.dot_real(light_axis);
    let t_eps = s_prime * kappa * m_al / beta;
    let d_axis = s_beta * m_al - t_eps * mw - t * light_axis.dot(axis)
        + s_q * (p_mu.dot_real(light_axis) * t + p_mu.dot(&al.mu) * t_eps);
    let d_axis_view = s_q * p_mu.dot_real(axis);
    LobeValue {
        value,
        d_kappa: value * d_kappa,
        d_axis: value * d_axis,
        d_axis_view: value * d_axis_view,
    }
}

/// One lobe's term of Eq. 18: `w ∫ ã_v(ω) Υ_l(ω) dω` with `Υ_l` the convolved vMF. Where the
/// linearisation fails (`|β|` small, far off the beam, where the true value is below `e^{−30}` of
/// the peak) it can exceed the bound `max|Υ_l| ∫|ã_v|`: the term is dropped there.
#[inline]
pub fn lens_pair_term(c: &ConvolvedLobe, av: &Vmf, view_bound: f64) -> C64 {
    let p = c.vmf.product(av);
    let value = sphere_integral_scaled(C64::new(p.log_scale.re, 0.0), p.mu.dot_self());
    c.weight * kept(value, p.log_scale.im, c.bound + view_bound)
}

/// [`lens_pair_term`] in two steps: its sphere integral queued in `batch` (its index returned),
/// then [`lens_pair_from`] once the batch is evaluated.
#[inline]
pub fn lens_pair_queue(
    c: &ConvolvedLobe,
    av: &Vmf,
    view_bound: f64,
    batch: &mut PairBatch,
) -> usize {
    let p = c.vmf.product(av);
    batch.turn.push(p.log_scale.im);
    batch.bound.push(c.bound + view_bound);
    batch.sphere.push(p.log_scale.re, p.mu.dot_self())
}

/// The term [`lens_pair_queue`] queued at `i`: the same bits as [`lens_pair_term`].
#[inline]
pub fn lens_pair_from(c: &ConvolvedLobe, i: usize, batch: &PairBatch) -> C64 {
    c.weight * C64::new(batch.re[i], batch.im[i])
}

/// Two-lens terms (Eq. 18) in one batch: their sphere integrals ([`SphereBatch`]), then each turned
/// by its phase and kept within the window below its magnitude bound, in a loop the compiler
/// vectorises as well; terms near the window's edges are decided one by one.
#[derive(Clone, Debug, Default)]
pub struct PairBatch {
    sphere: SphereBatch,
    turn: Vec<f64>,
    bound: Vec<f64>,
    re: Vec<f64>,
    im: Vec<f64>,
}

impl PairBatch {
    pub fn clear(&mut self) {
        self.sphere.clear();
        self.turn.clear();
        self.bound.clear();
    }

    /// Evaluates every queued term, with the widest vectors the CPU offers.
    pub fn evaluate(&mut self) {
        self.evaluate_at(Width::widest());
    }

    /// [`Self::evaluate`] with vectors of `width` (which the CPU must offer): the same bits at
    /// every width.
    pub fn evaluate_at(&mut self, width: Width) {
        self.sphere.evaluate_at(width);
        self.keep_at(width);
    }

    /// The second pass of [`Self::evaluate_at`], on the sphere integrals.
    fn keep_at(&mut self, width: Width) {
        let n = self.turn.len();
        self.re.resize(n, 0.0);
        self.im.resize(n, 0.0);
        match width {
            // SAFETY: the width is one the CPU offers (`Width::widest`, `Width::available`).
            #[cfg(target_arch = "x86_64")]
            Width::Avx512 => unsafe { self.keep_avx512() },
            #[cfg(target_arch = "x86_64")]
            Width::Avx2 => unsafe { self.keep_avx2() },
            _ => self.keep(),
        }
        for i in 0..n {
            if self.re[i].is_nan() {
                let v = kept_special(self.sphere.value(i), self.turn[i], self.bound[i]);
                (self.re[i], self.im[i]) = (v.re, v.im);
            }
        }
    }

    /// Every term turned and kept, undecided terms marked NaN.
    #[inline(always)]
    fn keep(&mut self) {
        let n = self.turn.len();
        let (vr, vi) = (&self.sphere.re[..n], &self.sphere.im[..n]);
        let (turn, bound) = (&self.turn[..n], &self.bound[..n]);
        let (re, im) = (&mut self.re[..n], &mut self.im[..n]);
        for i in 0..n {
            let (r, j, decided) = kept_lane(vr[i], vi[i], turn[i], bound[i]);
            re[i] = if decided { r } else { f64::NAN };
            im[i] = j;
        }
    }

    /// The same operations in the same order with 256-bit vectors: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn keep_avx2(&mut self) {
        self.keep();
    }

    /// The same with 512-bit vectors: the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn keep_avx512(&mut self) {
        self.keep();
    }
}

/// A two-lens term's sphere integral `value` turned by `angle` (`Im c`) and kept if `ln|value|`
/// lies in `[bound − 60, bound]`, zero otherwise.
#[inline]
fn kept(value: C64, angle: f64, bound: f64) -> C64 {
    match kept_lane(value.re, value.im, angle, bound) {
        (re, im, true) => C64::new(re, im),
        _ => kept_special(value, angle, bound),
    }
}

/// [`kept`] without a branch: the window's test on `ln|value|` from the exponent bits (within
/// 0.06 of the logarithm), so it decides as the logarithm would except within 0.1 of an edge;
/// the flag is false there, for angles beyond the sine's kernel, and for a zero, subnormal or
/// non-finite magnitude: [`kept_special`] redoes those.
#[inline(always)]
fn kept_lane(re: f64, im: f64, angle: f64, bound: f64) -> (f64, f64, bool) {
    let (sin, cos) = crate::math::elementary::sin_cos_in_range(angle);
    // `value · cis(angle)` as the complex product computes it, untouched at angle 0
    let (tr, ti) = if angle == 0.0 {
        (re, im)
    } else {
        (re * cos - im * sin, re * sin + im * cos)
    };
    let squared = tr * tr + ti * ti;
    let rough = 0.5 * rough_ln(squared);
    let inside = rough < bound - 0.1 && rough > bound - 59.9;
    let outside = rough > bound + 0.1 || rough < bound - 60.1;
    let normal = (f64::MIN_POSITIVE..f64::INFINITY).contains(&squared);
    let decided = (inside || outside) && normal && angle.abs() <= 1_048_576.0;
    if inside {
        (tr, ti, decided)
    } else {
        (0.0, 0.0, decided)
    }
}

/// [`kept`] by the logarithm itself.
#[cold]
fn kept_special(value: C64, angle: f64, bound: f64) -> C64 {
    let value = turned(value, angle);
    let log = 0.5 * value.norm_sqr().ln();
    if log <= bound && log >= bound - 60.0 {
        value
    } else {
        C64::default()
    }
}

/// `ln x` for a positive normal `x` to within 0.06, from its bits read as a linear interpolant of
/// `log₂` (exponent plus mantissa fraction), with bit operations only so loops over it vectorise;
/// meaningless for other `x`.
#[inline(always)]
fn rough_ln(x: f64) -> f64 {
    // 1.5·2⁵² with the exponent's bits in its low mantissa bits reads 1.5·2⁵² + exponent
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let bits = x.to_bits();
    let exponent = f64::from_bits(ROUND.to_bits() | (bits >> 52)) - ROUND;
    let fraction = f64::from_bits((bits & ((1u64 << 52) - 1)) | 1f64.to_bits()) - 1.0;
    (exponent - 1023.0 + fraction) * std::f64::consts::LN_2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::{Geometry, Scattering};

    /// The batched sphere integrals (Eq. 29) equal `e^{c + ln(4π sinh q/q)}` by the logarithmic
    /// form to 1e-12, over small, moderate and large `|q²|` in every direction of the complex
    /// plane, phases beyond the sine's kernel and `q² = 0`, bit for bit the scalar form at every
    /// vector width the CPU offers; and a lens's amplitude through the batch is bit for bit
    /// [`Seen::amplitude`].
    #[test]
    fn batched_sphere_integrals_match() {
        let mut batch = SphereBatch::default();
        let mut cases = Vec::new();
        for r in [0.0, 1e-6, 0.05, 0.3, 2.0, 40.0, 900.0, 1e5, 4e12] {
            for k in 0..16 {
                let z = C64::from_polar(r, k as f64 * std::f64::consts::PI / 8.0 + 0.1);
                let c = -(z.norm().sqrt()) - 0.5;
                cases.push((c, z));
                batch.push(c, z);
            }
        }
        for width in Width::available() {
            batch.evaluate_at(width);
            for (i, (c, z)) in cases.iter().enumerate() {
                let want = (log_sphere_integral(*z) + c).exp();
                let got = batch.value(i);
                assert!(
                    (got - want).norm() <= 1e-12 * want.norm() + 1e-300,
                    "c {c}, q² {z}: {got} vs {want}"
                );
                let scalar = sphere_integral_scaled(C64::new(*c, 0.0), *z);
                assert_eq!(
                    (got.re.to_bits(), got.im.to_bits()),
                    (scalar.re.to_bits(), scalar.im.to_bits()),
                    "{width:?}"
                );
            }
        }
        let medium = Medium {
            geometry: Geometry::boxed([6.0, 6.0, 4.0]),
            sigma_s: 0.3,
            sigma_a: 0.05,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.8 }),
        };
        let lobes = Lobes::of(&medium.scattering.phase(0).clone());
        let phase = medium.scattering.phase(0).clone();
        let view = Terminal::Lens(lens(DVec3::new(0.3, 0.0, 2.0), DVec3::Z, 0.25, -1.0));
        let u = DVec3::new(0.2, -0.1, 1.0).normalize();
        batch.clear();
        let xs = [
            DVec3::new(0.1, 0.2, -1.0),
            DVec3::new(0.3, 0.0, 1.99),
            DVec3::new(2.9, -2.5, 0.0),
        ];
        let firsts: Vec<usize> = xs
            .iter()
            .map(|x| {
                view.seen_from(*x, &medium, 2.0 * std::f64::consts::PI)
                    .queue_lobes(u, &lobes, &mut batch)
                    .unwrap()
            })
            .collect();
        batch.evaluate();
        for (x, first) in xs.iter().zip(firsts) {
            let seen = view.seen_from(*x, &medium, 2.0 * std::f64::consts::PI);
            let (a, b) = (
                Seen::amplitude_from(&batch, first, &lobes),
                seen.amplitude(u, &phase, &lobes),
            );
            assert_eq!(
                (a.re.to_bits(), a.im.to_bits()),
                (b.re.to_bits(), b.im.to_bits()),
                "{x}"
            );
        }
    }

    /// The bit-level logarithm behind the two-lens window is within 0.06 of `ln` over the whole
    /// normal range, so the window's margins of 0.1 decide exactly as `ln` would.
    #[test]
    fn rough_logarithm_is_within_its_margin() {
        let mut worst = 0.0f64;
        let mut x = f64::MIN_POSITIVE;
        while x < 1e300 {
            for m in 0..64 {
                let y = x * (1.0 + m as f64 / 64.0);
                worst = worst.max((rough_ln(y) - y.ln()).abs());
            }
            x *= 1.7;
        }
        assert!(worst < 0.06, "{worst}");
        assert!(
            worst > 0.05,
            "{worst}: the interpolant's known error is about 0.0597"
        );
    }

    /// The window's vectorised decision is the logarithm's, bit for bit, at the edges too:
    /// magnitudes over the whole range (zero, subnormal, infinite and NaN included), phases zero,
    /// ordinary and beyond the sine's kernel, bounds on, near and across both edges; alone and in
    /// a batch's second pass at every vector width.
    #[test]
    fn the_two_lens_window_decides_as_the_logarithm() {
        let mut rng = crate::math::stream_rng(3, 0);
        let mut cases = Vec::new();
        for log in [-700.0, -300.0, -40.0, -1.0, 0.0, 3.0, 80.0, 700.0] {
            for angle in [0.0, 0.3, -2.5, 1e4, 3e6] {
                let phase = 2.0 * std::f64::consts::PI * crate::math::uniform(&mut rng);
                let value = C64::from_polar(f64::exp(log), phase);
                let ln = 0.5 * value.norm_sqr().ln();
                for edge in [0.0, 60.0] {
                    for off in [
                        0.0, 1e-12, -1e-12, 0.05, -0.05, 0.099, -0.099, 0.11, -0.11, 3.0,
                    ] {
                        cases.push((value, angle, ln + edge + off));
                    }
                }
            }
        }
        for value in [
            C64::default(),
            C64::new(1e-310, 0.0),
            C64::new(f64::INFINITY, 0.0),
        ] {
            cases.push((value, 0.5, 0.0));
        }
        cases.push((C64::new(f64::NAN, 1.0), 0.5, 0.0));
        let same = |a: C64, b: C64| {
            (a.re.to_bits(), a.im.to_bits()) == (b.re.to_bits(), b.im.to_bits())
                || (a.re.is_nan() && b.re.is_nan())
        };
        let mut batch = PairBatch::default();
        for (value, angle, bound) in &cases {
            let (got, want) = (
                kept(*value, *angle, *bound),
                kept_special(*value, *angle, *bound),
            );
            assert!(same(got, want), "{value} {angle} {bound}: {got} vs {want}");
            batch.turn.push(*angle);
            batch.bound.push(*bound);
        }
        batch.sphere.re = cases.iter().map(|c| c.0.re).collect();
        batch.sphere.im = cases.iter().map(|c| c.0.im).collect();
        for width in Width::available() {
            batch.keep_at(width);
            for (i, (value, angle, bound)) in cases.iter().enumerate() {
                let got = C64::new(batch.re[i], batch.im[i]);
                assert!(
                    same(got, kept(*value, *angle, *bound)),
                    "{width:?} {value} {angle} {bound}"
                );
            }
        }
    }

    /// Two-lens terms through the batch are [`lens_pair_term`] bit for bit at every vector width:
    /// a light and views focused about a box's back face, seen from vertices on and off the beams.
    #[test]
    fn batched_two_lens_terms_match() {
        let medium = Medium {
            geometry: Geometry::boxed([25.0, 25.0, 10.0]),
            sigma_s: 0.1,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.8 }),
        };
        let lobes = Lobes::of(medium.scattering.phase(0));
        let k = 2.0 * std::f64::consts::PI;
        let light = lens(DVec3::new(0.0, 0.0, 5.0), DVec3::Z, 0.25, 1.0);
        let views: Vec<Lens> = (0..9)
            .map(|i| {
                lens(
                    DVec3::new(0.5 * i as f64 - 2.0, 0.3, 5.0),
                    DVec3::Z,
                    0.25,
                    -1.0,
                )
            })
            .collect();
        let mut batch = PairBatch::default();
        let mut terms = Vec::new();
        for x in [
            DVec3::new(0.1, 0.0, 4.0),
            DVec3::new(3.0, -2.0, 0.0),
            DVec3::new(-11.0, 9.0, -4.5),
            DVec3::new(0.0, 0.2, 4.99),
        ] {
            let al = light.aperture(x, &medium, k);
            for view in &views {
                let av = view.aperture(x, &medium, k);
                let view_bound = log_aperture_mass(&av);
                for lobe in &lobes.lobes {
                    let c = convolve_lobe(&al, lobe, DVec3::Z);
                    let i = lens_pair_queue(&c, &av, view_bound, &mut batch);
                    terms.push((c, i, lens_pair_term(&c, &av, view_bound)));
                }
            }
        }
        assert!(terms.iter().all(|t| t.2 != C64::default()));
        for width in Width::available() {
            batch.evaluate_at(width);
            for (c, i, want) in &terms {
                let got = lens_pair_from(c, *i, &batch);
                assert_eq!(
                    (got.re.to_bits(), got.im.to_bits()),
                    (want.re.to_bits(), want.im.to_bits()),
                    "{width:?}"
                );
            }
        }
    }

    fn lens(focus: DVec3, axis: DVec3, sigma: f64, sign: f64) -> Lens {
        Lens {
            focus,
            axis: axis.normalize(),
            gamma: 1.0 / (sigma * sigma),
            sign,
        }
    }

    /// The derivatives of one lobe's `Υ` (Eq. 29) and of its two-lens term (Eqs. 18, 31–32) with
    /// respect to `κ` and to concentrations added along the light's and the view's axes match
    /// central differences, on and off the beams.
    #[test]
    fn lobe_slopes_match_differences() {
        let medium = Medium {
            geometry: Geometry::boxed([6.0, 6.0, 4.0]),
            sigma_s: 0.3,
            sigma_a: 0.05,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        let k = 2.0 * std::f64::consts::PI;
        let light = lens(
            DVec3::new(0.0, 0.0, 2.0),
            DVec3::new(0.05, 0.0, 1.0),
            0.4,
            1.0,
        );
        let view = lens(
            DVec3::new(0.5, 0.0, 1.0),
            DVec3::new(0.1, 0.0, 1.0),
            0.3,
            -1.0,
        );
        let close = |d: C64, fd: C64, what: &str| {
            assert!(
                (d - fd).norm() <= 1e-6 * fd.norm() + 1e-12 * d.norm().max(1e-300),
                "{what}: {d} vs {fd}"
            );
        };
        let shifted = |v: &Vmf, axis: DVec3, e: f64| Vmf::new(v.log_scale, v.mu.add_real(axis * e));
        for x in [
            DVec3::new(0.1, 0.2, -1.0),
            DVec3::new(1.5, -0.7, 0.5),
            DVec3::new(0.0, 0.0, 1.9),
        ] {
            let (al, _) = light.aperture_and_path(x, &medium, k);
            let (av, _) = view.aperture_and_path(x, &medium, k);
            let seen = Terminal::Lens(light).seen_from(x, &medium, k);
            let seen_shifted = |e: f64| match seen {
                Seen::Aperture {
                    vmf,
                    sign,
                    axis,
                    inside,
                    ..
                } => {
                    let vmf = shifted(&vmf, axis, e);
                    Seen::Aperture {
                        mu2: vmf.mu.dot_self(),
                        vmf,
                        sign,
                        axis,
                        inside,
                    }
                }
                s => s,
            };
            let u = DVec3::new(0.2, -0.1, 1.0).normalize();
            let bound = log_aperture_mass(&av);
            for kappa in [0.5, 4.0, 30.0] {
                let h = 1e-5 * kappa;
                let y = seen.aperture_lobe(u, kappa, true);
                let at = |kappa| seen.aperture_lobe(u, kappa, false).value;
                close(
                    y.d_kappa,
                    (at(kappa + h) - at(kappa - h)) / (2.0 * h),
                    "Υ κ",
                );
                let e = 1e-5;
                let at = |e| seen_shifted(e).aperture_lobe(u, kappa, false).value;
                close(y.d_axis, (at(e) - at(-e)) / (2.0 * e), "Υ axis");
                let pair = |al: &Vmf, kappa, av: &Vmf| {
                    lens_pair_lobe(al, light.axis, kappa, view.axis, av, bound, false).value
                };
                let p = lens_pair_lobe(&al, light.axis, kappa, view.axis, &av, bound, true);
                close(
                    p.d_kappa,
                    (pair(&al, kappa + h, &av) - pair(&al, kappa - h, &av)) / (2.0 * h),
                    "pair κ",
                );
                close(
                    p.d_axis,
                    (pair(&shifted(&al, light.axis, e), kappa, &av)
                        - pair(&shifted(&al, light.axis, -e), kappa, &av))
                        / (2.0 * e),
                    "pair light axis",
                );
                close(
                    p.d_axis_view,
                    (pair(&al, kappa, &shifted(&av, view.axis, e))
                        - pair(&al, kappa, &shifted(&av, view.axis, -e)))
                        / (2.0 * e),
                    "pair view axis",
                );
            }
        }
    }
}
