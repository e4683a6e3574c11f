//! Lights and views as path endpoints: the complex transmission `ξ` and attenuation `τ` of a
//! connection from a vertex inside the medium (paper 001, Eqs. 13 and 19), and for focused lights
//! and views the aperture integrals `Υ` of paper 000 (Eqs. 15–18) in closed form.

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
    /// `exp(−γ − σ_t d/2 + (γ a + i σ k (x − focus))·ω)`, `σ` the sign, with the attenuation `d`
    /// taken along the axis for every direction (Eq. 25).
    #[inline]
    pub fn aperture(&self, x: DVec3, medium: &Medium, k: f64) -> Vmf {
        self.aperture_and_path(x, medium, k).0
    }

    /// The aperture and the length `d` of the axis path inside the medium (its attenuation).
    #[inline]
    pub fn aperture_and_path(&self, x: DVec3, medium: &Medium, k: f64) -> (Vmf, f64) {
        let inside = medium.geometry.exit_distance(x, self.axis * -self.sign);
        (
            Vmf::new(
                C64::new(-self.gamma - 0.5 * medium.sigma_t() * inside, 0.0),
                CVec3::new(self.axis * self.gamma, (x - self.focus) * (self.sign * k)),
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
/// connection, one square root and one or two exponentials.
#[inline]
fn sphere_integral_scaled(c: C64, q2: C64) -> C64 {
    if q2.norm_sqr() < 1e-4 {
        return (log_sphere_integral(q2) + c).exp();
    }
    let q = csqrt(q2);
    // 4π sinh(q)/q = 2π e^{q} (1 − e^{−2q}) / q, Re q ≥ 0
    let head = (c + q).exp() * (2.0 * std::f64::consts::PI) / q;
    if q.re > 20.0 {
        head
    } else {
        head * (C64::new(1.0, 0.0) - (-2.0 * q).exp())
    }
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
                let w = u * -*sign;
                let mw = vmf.mu.dot_real(w);
                lobes
                    .lobes
                    .iter()
                    .map(|l| {
                        let q2 = mu2 + mw * (2.0 * l.kappa) + l.kappa * l.kappa;
                        l.weight * sphere_integral_scaled(vmf.log_scale - l.kappa, q2)
                    })
                    .sum()
            }
        }
    }

    /// One unit-weight lobe `exp(κ(μ − 1))` of `Υ` for a lens (Eq. 29) and, when `slope` is set,
    /// its derivative with respect to `κ`: with `q² = μ·μ + 2κ μ·w + κ²`,
    /// `∂ ln Υ_κ/∂κ = −1 + S(q) (μ·w + κ)`, `S` the log-slope of `sinh q/q` in `q²/2`. Zero for a
    /// ray terminal.
    #[inline]
    pub fn aperture_lobe(&self, u: DVec3, kappa: f64, slope: bool) -> (C64, C64) {
        let Seen::Aperture { vmf, mu2, sign, .. } = self else {
            return (C64::default(), C64::default());
        };
        let mw = vmf.mu.dot_real(u * -*sign);
        let q2 = mu2 + mw * (2.0 * kappa) + kappa * kappa;
        let value = sphere_integral_scaled(vmf.log_scale - kappa, q2);
        if !slope {
            return (value, C64::default());
        }
        let dlog = log_sinhc_slope(csqrt(q2)) * (mw + kappa) - 1.0;
        (value, value * dlog)
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

/// One unit-weight lobe's term of Eq. 18 for the light aperture `al` and view aperture `av`
/// (about the view's `axis`), and, when `slope` is set, its derivative with respect to the lobe's
/// concentration `κ` through the convolution approximation (Eqs. 31–32 with the exact slope):
/// `β² = (μ_l + κ a)²`, slope `t = κ S(β)`, product `μ_p = t μ_l + μ_v`, so
/// `∂ ln P/∂κ = −1 + S(β)(μ_l·a + κ) − t′ μ_l·a + S(q)(μ_p·μ_l) t′` with
/// `t′ = S(β) + κ S′(β)(μ_l·a + κ)/β`. Dropped terms (see [`lens_pair_term`]) have zero slope.
pub fn lens_pair_lobe(
    al: &Vmf,
    kappa: f64,
    axis: DVec3,
    av: &Vmf,
    view_bound: f64,
    slope: bool,
) -> (C64, C64) {
    let lobe = crate::medium::lobes::Lobe {
        weight: C64::new(1.0, 0.0),
        kappa,
    };
    let value = lens_pair_term(&convolve_lobe(al, &lobe, axis), av, view_bound);
    if !slope || value == C64::default() {
        return (value, C64::default());
    }
    let mw = al.mu.dot_real(axis);
    let m = mw + kappa;
    let beta = csqrt(al.mu.add_real(axis * kappa).dot_self());
    let s_beta = log_sinhc_slope(beta);
    let t = s_beta * kappa;
    let dt = s_beta + log_sinhc_slope_derivative(beta) * kappa * m / beta;
    let p_mu = al.mu.scale(t) + av.mu;
    let q = csqrt(p_mu.dot_self());
    let dlog = s_beta * m - 1.0 - dt * mw + log_sinhc_slope(q) * p_mu.dot(&al.mu) * dt;
    (value, value * dlog)
}

/// One lobe's term of Eq. 18: `w ∫ ã_v(ω) Υ_l(ω) dω` with `Υ_l` the convolved vMF. Where the
/// linearisation fails (`|β|` small, far off the beam, where the true value is below `e^{−30}` of
/// the peak) it can exceed the bound `max|Υ_l| ∫|ã_v|`: the term is dropped there.
#[inline]
pub fn lens_pair_term(c: &ConvolvedLobe, av: &Vmf, view_bound: f64) -> C64 {
    let p = c.vmf.product(av);
    let value = sphere_integral_scaled(p.log_scale, p.mu.dot_self());
    let log = 0.5 * value.norm_sqr().ln();
    let bound = c.bound + view_bound;
    if !(log <= bound && log >= bound - 60.0) {
        return C64::default();
    }
    c.weight * value
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::{Geometry, Scattering};

    fn lens(focus: DVec3, axis: DVec3, sigma: f64, sign: f64) -> Lens {
        Lens {
            focus,
            axis: axis.normalize(),
            gamma: 1.0 / (sigma * sigma),
            sign,
        }
    }

    /// The κ-derivatives of one lobe's `Υ` (Eq. 29) and of its two-lens term (Eqs. 18, 31–32)
    /// match central differences, on and off the beams.
    #[test]
    fn lobe_slopes_match_differences() {
        let medium = Medium {
            geometry: Geometry::boxed([6.0, 6.0, 4.0]),
            sigma_s: 0.3,
            sigma_a: 0.05,
            scattering: Scattering::single(PhaseFunction::Isotropic),
        };
        let k = 2.0 * std::f64::consts::PI;
        let light = lens(DVec3::new(0.0, 0.0, 2.0), DVec3::Z, 0.4, 1.0);
        let view = lens(
            DVec3::new(0.5, 0.0, 1.0),
            DVec3::new(0.1, 0.0, 1.0),
            0.3,
            -1.0,
        );
        for x in [
            DVec3::new(0.1, 0.2, -1.0),
            DVec3::new(1.5, -0.7, 0.5),
            DVec3::new(0.0, 0.0, 1.9),
        ] {
            let (al, _) = light.aperture_and_path(x, &medium, k);
            let (av, _) = view.aperture_and_path(x, &medium, k);
            let seen = Terminal::Lens(light).seen_from(x, &medium, k);
            let u = DVec3::new(0.2, -0.1, 1.0).normalize();
            let bound = log_aperture_mass(&av);
            for kappa in [0.5, 4.0, 30.0] {
                let h = 1e-5 * kappa;
                let (_, d) = seen.aperture_lobe(u, kappa, true);
                let fd = (seen.aperture_lobe(u, kappa + h, false).0
                    - seen.aperture_lobe(u, kappa - h, false).0)
                    / (2.0 * h);
                assert!(
                    (d - fd).norm() <= 1e-6 * fd.norm() + 1e-300,
                    "Υ at {x}, κ = {kappa}: {d} vs {fd}"
                );
                let pair = |kappa| lens_pair_lobe(&al, kappa, view.axis, &av, bound, false).0;
                let (_, d) = lens_pair_lobe(&al, kappa, view.axis, &av, bound, true);
                let fd = (pair(kappa + h) - pair(kappa - h)) / (2.0 * h);
                assert!(
                    (d - fd).norm() <= 1e-6 * fd.norm() + 1e-300,
                    "pair at {x}, κ = {kappa}: {d} vs {fd}"
                );
            }
        }
    }
}
