//! The speckle mean `m = E[u]` in closed form (paper 001, Eq. 20 and App. 9.2, Eq. 48).
//!
//! With a point at either end the mean is the attenuated direct field `τ(i, v) ξ(i → v)` (Eq. 47).
//! With a plane-wave light and a far-field view it is the coherent single-scattering integral
//! `m = ∫ n f(i·v) exp(i k (i − v)·x) τ(x, −i) dx`: the far field radiated with the free-space Green's
//! function by the scatterers' sources `n f u_coh`, where the coherent exciting field `u_coh` is the
//! incident wave attenuated on its way in (Foldy; paper 001 Eq. 48 puts the single `τ` on the outgoing
//! leg instead, which agrees in the forward direction). This form satisfies the optical theorem for
//! the whole box, `(4π/k) Im m(i → i) = 2A(1 − exp(−σ_t L/2))` for a slab-like box, which the wave
//! solver confirms (`experiments/wave-vs-mc`). The forward amplitude
//! follows from the optical theorem for non-absorbing particles with purely imaginary forward
//! amplitude: `n f(μ) = (i k σ_s / 4π) Σ β_ι s_ι(μ) / s_ι(1)` (any absorption is the host's). This
//! matches resonant point scatterers (`f = i/k`) exactly. For a box the integral is in closed form
//! (exponentials integrated exactly over convex cells); for a slab the off-specular mean per unit
//! area vanishes (the specular part is a delta) and 0 is returned.

use crate::math::{C64, INV_4PI, cis};
use crate::medium::{Geometry, Medium};
use crate::speckle::Scene;
use crate::speckle::endpoint::{Light, View};
use crate::speckle::single::box_exit_integral;
use glam::DVec3;

/// Mean field of `light` seen by `view`.
pub fn mean_field(scene: &Scene, light: &Light, view: &View) -> C64 {
    let m = &scene.medium;
    let k = scene.k;
    match (*light, *view) {
        (Light::Point { position: p }, View::Point { position: q }) => {
            let r = (q - p).length();
            let len = chord(&m.geometry, p, (q - p) / r, r);
            cis(k * r) * (m.amplitude_attenuation(len) / r)
        }
        (Light::Point { position: p }, View::FarField { direction: v }) => {
            cis(-k * v.dot(p)) * m.amplitude_attenuation(chord(&m.geometry, p, v, f64::INFINITY))
        }
        (Light::PlaneWave { direction: d }, View::Point { position: q }) => {
            cis(k * d.dot(q)) * m.amplitude_attenuation(chord(&m.geometry, q, -d, f64::INFINITY))
        }
        (Light::PlaneWave { direction: d }, View::FarField { direction: v }) => far_far(m, k, d, v),
        (Light::Focused { .. }, _) | (_, View::Focused { .. }) => focused(scene, light, view),
    }
}

/// The mean field with a focused end: the unscattered field between the endpoints (as the wave
/// solver defines it), every plane-wave component attenuated by the same `e^{−σ_t ℓ/2}` (paper 000,
/// Eq. 25; App. A.1): `ℓ` is the chord of the medium along the beam through the focal region (the
/// foci's midpoint, along the mean axis), or from a point endpoint back along the lens axis.
fn focused(scene: &Scene, light: &Light, view: &View) -> C64 {
    let (unattenuated, len) = focused_parts(scene, light, view);
    unattenuated * scene.medium.amplitude_attenuation(len)
}

/// The unscattered field of a pair with a focused end and the length `ℓ` it is attenuated over.
fn focused_parts(scene: &Scene, light: &Light, view: &View) -> (C64, f64) {
    use crate::speckle::wave::{direct, incident, sensor};
    let k = scene.k;
    let g = &scene.medium.geometry;
    match (*light, *view) {
        (Light::Focused { axis, .. }, View::Point { position }) => (
            incident(light, position, k),
            chord(g, position, -axis, f64::INFINITY),
        ),
        (Light::Point { position }, View::Focused { axis, .. }) => (
            sensor(view, position, k),
            chord(g, position, axis, f64::INFINITY),
        ),
        (Light::Focused { focus, .. }, View::FarField { direction })
        | (Light::PlaneWave { direction }, View::Focused { focus, .. }) => {
            (direct(light, view, k), line_chord(g, focus, direction))
        }
        (
            Light::Focused {
                focus: fl,
                axis: al,
                ..
            },
            View::Focused {
                focus: fv,
                axis: av,
                ..
            },
        ) => (
            direct(light, view, k),
            line_chord(g, (fl + fv) * 0.5, (al + av).normalize_or(al)),
        ),
        _ => (direct(light, view, k), 0.0),
    }
}

/// Length inside the medium of the whole line through `p` along `w`.
fn line_chord(g: &Geometry, p: DVec3, w: DVec3) -> f64 {
    match g.ray_interval(p, w) {
        Some((t0, t1)) => (t1 - t0).max(0.0),
        None => 0.0,
    }
}

/// Length inside the medium of the segment `o + t w`, `t ∈ [0, t_max]`.
fn chord(g: &Geometry, o: DVec3, w: DVec3, t_max: f64) -> f64 {
    match g.ray_interval(o, w) {
        Some((t0, t1)) => (t1.min(t_max) - t0.max(0.0)).max(0.0),
        None => 0.0,
    }
}

/// Forward-amplitude density `n f(μ)` from the optical theorem (see module docs).
fn amplitude_density(m: &Medium, k: f64, mu: f64) -> C64 {
    let ratio: C64 = m
        .scattering
        .components()
        .iter()
        .map(|(b, p)| forward_ratio(p, mu) * *b)
        .sum();
    C64::new(0.0, k * m.sigma_s * INV_4PI) * ratio
}

/// `s(μ)/s(1)` of one particle type (0 when its forward amplitude vanishes).
fn forward_ratio(p: &crate::medium::PhaseFunction, mu: f64) -> C64 {
    let s1 = p.amplitude(1.0);
    if s1.norm() > 0.0 {
        p.amplitude(mu) / s1
    } else {
        C64::default()
    }
}

fn far_far(m: &Medium, k: f64, d: DVec3, v: DVec3) -> C64 {
    let half = match m.geometry {
        Geometry::Box { half } => half,
        Geometry::Slab { .. } => return C64::default(),
    };
    let nf = amplitude_density(m, k, d.dot(v));
    nf * box_integral(half, k, C64::new(m.sigma_t(), 0.0), d, v)
}

/// The mean field and its derivatives with respect to `params` (every pair of endpoints).
///
/// Closed form like [`mean_field`], differentiated factor by factor: a point endpoint's
/// attenuation `e^{−σ_t ℓ/2}` gives `−ℓ/2`; for plane wave → far field, `m = n f(μ) B(σ_t)` with
/// `n f ∝ σ_s Σ β_ι s_ι(μ)/s_ι(1)` differentiated analytically (σ_s, HG `g`, table nodes, shares)
/// and `B' = dB/dσ_t` from Cauchy's integral formula: `B` is entire in `σ_t` (an integral of
/// exponentials affine in it), so the trapezoid rule on a circle of radius `1/L` converges
/// geometrically and 16 nodes give it to round-off.
pub fn mean_field_gradient(
    scene: &Scene,
    light: &Light,
    view: &View,
    params: &[crate::medium::Param],
) -> (C64, Vec<C64>) {
    use crate::medium::Param;
    let m = &scene.medium;
    if let (Light::PlaneWave { direction: d }, View::FarField { direction: v }) = (*light, *view) {
        return far_far_gradient(m, scene.k, d, v, params);
    }
    let value = mean_field(scene, light, view);
    let len = match (*light, *view) {
        (Light::Point { position: p }, View::Point { position: q }) => {
            let r = (q - p).length();
            chord(&m.geometry, p, (q - p) / r, r)
        }
        (Light::Point { position: p }, View::FarField { direction: v }) => {
            chord(&m.geometry, p, v, f64::INFINITY)
        }
        (Light::PlaneWave { direction: d }, View::Point { position: q }) => {
            chord(&m.geometry, q, -d, f64::INFINITY)
        }
        // a focused end: the unscattered field attenuated along the beam (no phase function);
        // plane wave → far field returned above
        _ => focused_parts(scene, light, view).1,
    };
    // the attenuated direct field e^{−σ_t ℓ/2}: only σ_s and σ_a enter
    let grad = params
        .iter()
        .map(|p| match p {
            Param::SigmaS | Param::SigmaA => value * (-0.5 * len),
            _ => C64::default(),
        })
        .collect();
    (value, grad)
}

/// Plane wave → far field: `m = n f(μ) B(σ_t)` and its derivatives (see [`mean_field_gradient`]).
fn far_far_gradient(
    m: &Medium,
    k: f64,
    d: DVec3,
    v: DVec3,
    params: &[crate::medium::Param],
) -> (C64, Vec<C64>) {
    use crate::medium::Param;
    let Geometry::Box { half } = m.geometry else {
        // a slab's off-specular mean per unit area is 0, and so are its derivatives
        return (C64::default(), vec![C64::default(); params.len()]);
    };
    let mu = d.dot(v);
    let b = box_integral(half, k, C64::new(m.sigma_t(), 0.0), d, v);
    let db = box_integral_dsigma(half, k, m.sigma_t(), d, v);
    let nf = amplitude_density(m, k, mu);
    let coefficient = C64::new(0.0, k * INV_4PI);
    // ratio_ι = s_ι(μ)/s_ι(1) and ∂ log ratio_ι = ½ (∂ log ρ_ι(μ) − ∂ log ρ_ι(1))
    let comps = m.scattering.components();
    let ratio = |c: usize| forward_ratio(&comps[c].1, mu);
    let total: C64 = (0..comps.len()).map(|c| ratio(c) * comps[c].0).sum();
    let grad = params
        .iter()
        .map(|p| match *p {
            Param::SigmaS => nf / m.sigma_s * b + nf * db,
            Param::SigmaA => nf * db,
            Param::G(c) | Param::Bin(c, _) | Param::VmfWeight(c, _) | Param::VmfKappa(c, _) => {
                let ph = &comps[c].1;
                let dlog = 0.5 * (p.dlog_phase(c, ph, mu) - p.dlog_phase(c, ph, 1.0));
                coefficient * m.sigma_s * comps[c].0 * ratio(c) * dlog * b
            }
            // β normalised: ∂β_j/∂w_c = δ_jc − β_j at unit total
            Param::Weight(c) => coefficient * m.sigma_s * (ratio(c) - total) * b,
        })
        .collect();
    (nf * b, grad)
}

/// `dB/dσ_t` of [`box_integral`] by Cauchy's formula on a circle of radius `1/L` (`L` the box
/// diagonal): `B'(σ) = (1/N r) Σ_n B(σ + r e^{iθ_n}) e^{−iθ_n}`, exact to round-off for N = 16.
fn box_integral_dsigma(half: DVec3, k: f64, sigma_t: f64, d: DVec3, v: DVec3) -> C64 {
    const N: usize = 16;
    let r = 1.0 / (2.0 * half.length());
    let mut acc = C64::default();
    for n in 0..N {
        let w = cis(2.0 * std::f64::consts::PI * n as f64 / N as f64);
        acc += box_integral(half, k, C64::new(sigma_t, 0.0) + w * r, d, v) * w.conj();
    }
    acc / (N as f64 * r)
}

/// `∫_box exp(i k (d − v)·x − σ_t D_in(x) / 2) dx` in closed form, `D_in` the distance from `x` back
/// to the surface towards the light (one leg of [`box_exit_integral`]). `σ_t` may be complex (the
/// integral is entire in it; see [`box_integral_dsigma`]).
fn box_integral(half: DVec3, k: f64, sigma_t: C64, d: DVec3, v: DVec3) -> C64 {
    box_exit_integral(half, (d - v) * k, sigma_t, &[-d])
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Reference: exact in z, composite Gauss–Legendre across (independent of the polyhedral code).
    pub(super) fn quadrature_far_far(m: &Medium, k: f64, d: DVec3, v: DVec3) -> C64 {
        let half = match m.geometry {
            Geometry::Box { half } => half,
            Geometry::Slab { .. } => return C64::default(),
        };
        let nf = amplitude_density(m, k, d.dot(v));
        let q = (d - v) * k;
        let st = 0.5 * m.sigma_t();
        // exit distances along -d (towards the light) and v (towards the view) are
        // min(lateral constant, linear in z); integrate exp(i q·x − st (D_in + D_out)) exactly in z.
        let line = |x: f64, y: f64| -> C64 {
            let (ci, ai, bi) = split(half, DVec3::new(x, y, 0.0), -d);
            // breakpoints where the linear z part meets the lateral constant
            let mut cuts = [-half.z, half.z, half.z, half.z];
            let mut n = 1;
            for (c, a, b) in [(ci, ai, bi)] {
                if b != 0.0 && c.is_finite() {
                    let z = (c - a) / b;
                    if z > -half.z && z < half.z {
                        cuts[n] = z;
                        n += 1;
                    }
                }
            }
            cuts[n] = half.z;
            cuts[..=n].sort_by(f64::total_cmp);
            let mut acc = C64::default();
            for s in 0..n {
                let (z0, z1) = (cuts[s], cuts[s + 1]);
                if z1 <= z0 {
                    continue;
                }
                let zm = 0.5 * (z0 + z1);
                // on this piece D = const or a + b z; exponent = e0 + e1 z
                let (mut e0, mut e1) = (C64::new(-st * 0.0, q.x * x + q.y * y), C64::new(0.0, q.z));
                for (c, a, b) in [(ci, ai, bi)] {
                    if a + b * zm < c {
                        e0 -= st * a;
                        e1 -= st * b;
                    } else {
                        e0 -= st * c;
                    }
                }
                acc += if (e1 * (z1 - z0)).norm() < 1e-8 {
                    (e0 + e1 * zm).exp() * (z1 - z0)
                } else {
                    ((e0 + e1 * z1).exp() - (e0 + e1 * z0).exp()) / e1
                };
            }
            acc
        };
        let panels = |len: f64, qa: f64| -> usize {
            let waves = qa.abs() * len / (2.0 * std::f64::consts::PI) + m.sigma_t() * len;
            (4.0 + 2.0 * waves).ceil().min(200.0) as usize
        };
        let (px, py) = (panels(2.0 * half.x, q.x), panels(2.0 * half.y, q.y));
        let mut total = C64::default();
        for (x, wx) in composite_gauss(-half.x, half.x, px) {
            for (y, wy) in composite_gauss(-half.y, half.y, py) {
                total += line(x, y) * (wx * wy);
            }
        }
        nf * total
    }

    /// Exit distance from `(x, y, z)` along `w` as `min(c, a + b z)`: `c` from the lateral faces,
    /// `a + b z` from the z faces (`b = 0`, `a = ∞` when `w.z = 0`).
    fn split(half: DVec3, p: DVec3, w: DVec3) -> (f64, f64, f64) {
        let lateral = |x: f64, wa: f64, h: f64| {
            if wa > 0.0 {
                (h - x) / wa
            } else if wa < 0.0 {
                (-h - x) / wa
            } else {
                f64::INFINITY
            }
        };
        let c = lateral(p.x, w.x, half.x).min(lateral(p.y, w.y, half.y));
        if w.z > 0.0 {
            (c, half.z / w.z, -1.0 / w.z)
        } else if w.z < 0.0 {
            (c, -half.z / w.z, -1.0 / w.z)
        } else {
            (c, f64::INFINITY, 0.0)
        }
    }

    /// Nodes and weights of `panels` 8-point Gauss–Legendre panels over `[a, b]`.
    fn composite_gauss(a: f64, b: f64, panels: usize) -> impl Iterator<Item = (f64, f64)> {
        const X: [f64; 4] = [
            0.183_434_642_495_649_8,
            0.525_532_409_916_329,
            0.796_666_477_413_626_7,
            0.960_289_856_497_536_3,
        ];
        const W: [f64; 4] = [
            0.362_683_783_378_362,
            0.313_706_645_877_887_3,
            0.222_381_034_453_374_5,
            0.101_228_536_290_376_3,
        ];
        let h = (b - a) / panels as f64;
        (0..panels).flat_map(move |p| {
            let c = a + (p as f64 + 0.5) * h;
            (0..8).map(move |i| {
                let (x, w) = (X[i % 4] * if i < 4 { 1.0 } else { -1.0 }, W[i % 4]);
                (c + 0.5 * h * x, 0.5 * h * w)
            })
        })
    }

    use crate::medium::{PhaseFunction, Scattering};

    fn scene(size: [f64; 3], sigma_s: f64) -> Scene {
        Scene::new(
            1.0,
            Medium {
                geometry: Geometry::boxed(size),
                sigma_s,
                sigma_a: 0.0,
                scattering: Scattering::single(PhaseFunction::Isotropic),
            },
            vec![],
            vec![],
        )
    }

    #[test]
    fn forward_mean_obeys_the_optical_theorem() {
        // v = d = z: m = (i k σ_s / 4π) A ∫ exp(-σ_t z / 2) dz = (i k σ_s / 4π) A (2/σ_t)(1 − exp(-σ_t L / 2)),
        // i.e. the optical theorem for the whole box: (4π/k) Im m = 2A(1 − t), t = exp(-σ_t L/2).
        let s = scene([3.0, 4.0, 5.0], 0.2);
        let m = mean_field(
            &s,
            &Light::PlaneWave {
                direction: DVec3::Z,
            },
            &View::FarField {
                direction: DVec3::Z,
            },
        );
        let expect =
            C64::new(0.0, s.k * 0.2 * INV_4PI) * 12.0 * (2.0 / 0.2) * (1.0 - (-0.5f64).exp());
        assert!(
            (m - expect).norm() < 1e-9 * expect.norm(),
            "{m} vs {expect}"
        );
    }

    #[test]
    fn dilute_mean_is_sinc_product() {
        // σ_t → 0: the integral is the Fourier transform of the box.
        let s = scene([2.0, 3.0, 1.5], 1e-9);
        let d = DVec3::Z;
        let v = DVec3::new(0.3, 0.2, 0.5).normalize();
        let m = mean_field(
            &s,
            &Light::PlaneWave { direction: d },
            &View::FarField { direction: v },
        );
        let q = (d - v) * s.k;
        let sinc = |qa: f64, l: f64| {
            if qa == 0.0 {
                l
            } else {
                2.0 * (qa * l / 2.0).sin() / qa
            }
        };
        let expect =
            C64::new(0.0, s.k * 1e-9 * INV_4PI) * sinc(q.x, 2.0) * sinc(q.y, 3.0) * sinc(q.z, 1.5);
        assert!(
            (m - expect).norm() < 1e-6 * expect.norm(),
            "{m} vs {expect}"
        );
    }

    #[test]
    fn point_means_are_attenuated_direct_fields() {
        let s = scene([2.0, 2.0, 2.0], 0.5);
        let p = DVec3::new(0.0, 0.0, -3.0);
        let q = DVec3::new(0.0, 0.0, 4.0);
        let m = mean_field(
            &s,
            &Light::Point { position: p },
            &View::Point { position: q },
        );
        let expect = cis(s.k * 7.0) * ((-0.5f64 * 0.5 * 2.0).exp() / 7.0);
        assert!((m - expect).norm() < 1e-12);
    }
}

#[cfg(test)]
mod closed_form_vs_quadrature {
    use super::tests::quadrature_far_far;
    use super::*;
    use crate::medium::{PhaseFunction, Scattering};

    /// The closed form agrees with the independent quadrature over oblique directions, with
    /// absorption-free and absorbing media.
    #[test]
    fn agrees() {
        let m = Medium {
            geometry: Geometry::boxed([3.0, 2.0, 2.5]),
            sigma_s: 0.6,
            sigma_a: 0.2,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g: 0.4 }),
        };
        let k = 2.0 * std::f64::consts::PI;
        let dirs = [
            (DVec3::Z, DVec3::Z),
            (DVec3::Z, DVec3::new(0.1, 0.05, 1.0).normalize()),
            (
                DVec3::new(0.3, -0.2, 1.0).normalize(),
                DVec3::new(-0.2, 0.4, 1.0).normalize(),
            ),
            (
                DVec3::new(0.5, 0.1, 0.7).normalize(),
                DVec3::new(0.6, -0.3, -0.5).normalize(),
            ),
            (DVec3::X, DVec3::new(0.9, 0.1, 0.05).normalize()),
            // nearly axial directions: huge exit distances through the side faces, which must not
            // overflow (exp(+large) × exp(−large))
            (
                DVec3::new(0.0087, 0.0, 1.0).normalize(),
                DVec3::new(-0.087, 0.0, 1.0).normalize(),
            ),
            (
                DVec3::new(1e-7, 0.0, 1.0).normalize(),
                DVec3::new(0.0, 1e-6, 1.0).normalize(),
            ),
        ];
        for (d, v) in dirs {
            let exact = far_far(&m, k, d, v);
            let quad = quadrature_far_far(&m, k, d, v);
            assert!(
                (exact - quad).norm() < 2e-4 * quad.norm().max(1e-3),
                "{d} {v}: {exact} vs {quad}"
            );
        }
    }
}
