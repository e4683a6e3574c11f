//! A scattering amplitude as a sum of von Mises–Fisher lobes about the forward direction,
//! `s(μ) ≈ Σ_m w_m exp(κ_m (μ − 1))` (paper 000, Eq. 28), so that the aperture integrals of focused
//! lights and views have closed forms (Eqs. 29–32).
//!
//! The concentrations start from expectation–maximisation of a vMF mixture (Banerjee et al. 2005)
//! with `|s|` as the weighting of directions, the axis fixed at the forward pole, and are then
//! refined to the least-squares optimum of `s` itself, with the (complex) weights eliminated by
//! linear least squares (variable projection), which also fits complex amplitudes. The
//! number of lobes grows until the relative `L²` error of `s` over the sphere is below the
//! tolerance. Quadrature is composite Gauss–Legendre on geometrically shrinking intervals towards
//! `μ = 1`, where forward-peaked amplitudes (HG `g = 0.98` has width `~(1 − g)²`) live.

use crate::math::{C64, gauss_legendre};
use crate::medium::PhaseFunction;
use std::f64::consts::PI;

/// One lobe `w exp(κ (μ − 1))`: 1 in the forward direction when `w = 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lobe {
    pub weight: C64,
    pub kappa: f64,
}

/// The lobes of an amplitude and how well they fit it. Henyey–Greenstein needs 3 lobes for
/// `g = 0.3`, 5 for `g = 0.7`, 6 for `g = 0.9` and 8 for `g = 0.98` at the default tolerance.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lobes {
    pub lobes: Vec<Lobe>,
    /// Relative `L²` error over the sphere, `‖s − ŝ‖ / ‖s‖`.
    pub error: f64,
}

/// Relative `L²` error the fit aims for.
pub const TOLERANCE: f64 = 2e-3;

/// Most lobes tried before settling for the best fit.
const MAX_LOBES: usize = 10;

impl Lobes {
    /// `ŝ(μ)`.
    pub fn eval(&self, mu: f64) -> C64 {
        eval(&self.lobes, mu)
    }

    /// The lobes of `p`'s amplitude: exact for isotropic scattering and vMF mixtures, fitted
    /// otherwise. Fits are cached for the life of the process (fits and scans rebuild samplers for
    /// the same phase function many times).
    pub fn of(p: &PhaseFunction) -> Lobes {
        match p {
            PhaseFunction::Isotropic => Lobes {
                lobes: vec![Lobe {
                    weight: C64::new((0.25 / PI).sqrt(), 0.0),
                    kappa: 0.0,
                }],
                error: 0.0,
            },
            PhaseFunction::VmfMixture(v) => Lobes {
                lobes: v
                    .lobes
                    .iter()
                    .map(|&(w, kappa)| Lobe {
                        weight: C64::new(w, 0.0),
                        kappa,
                    })
                    .collect(),
                error: 0.0,
            },
            _ => {
                use std::collections::HashMap;
                use std::sync::{Mutex, OnceLock};
                static CACHE: OnceLock<Mutex<HashMap<String, Lobes>>> = OnceLock::new();
                let key = format!("{p:?}");
                let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
                if let Some(l) = cache.lock().ok().and_then(|c| c.get(&key).cloned()) {
                    return l;
                }
                let l = fit(|mu| p.amplitude(mu), TOLERANCE);
                if let Ok(mut c) = cache.lock() {
                    if c.len() > 256 {
                        c.clear();
                    }
                    c.insert(key, l.clone());
                }
                l
            }
        }
    }
}

/// A phase function given by its amplitude as real vMF lobes about the forward direction,
/// `s(μ) = Σ w_m exp(κ_m (μ − 1))` normalised to `∫ s² dω = 1` (paper 000, Eq. 28; config
/// `kind = "vmf_mixture"`). Its `ρ = s²` is itself a mixture of vMF distributions with
/// concentrations `κ_m + κ_n`, so it is sampled exactly.
#[derive(Clone, Debug, PartialEq)]
pub struct VmfMixture {
    /// `(w_m, κ_m)`, normalised.
    lobes: Vec<(f64, f64)>,
    /// `ρ`'s components `(cumulative probability, concentration κ_m + κ_n)`.
    components: Vec<(f64, f64)>,
}

/// `∫ exp(K (μ − 1)) dω = 2π (1 − e^{−2K})/K` (4π at `K = 0`), for any real `K`.
fn lobe_mass(k: f64) -> f64 {
    if k.abs() < 1e-8 {
        4.0 * PI
    } else {
        2.0 * PI * -(-2.0 * k).exp_m1() / k
    }
}

/// `dM/dK` of [`lobe_mass`]: `2π (2K e^{−2K} − 1 + e^{−2K})/K²` (`−4π` at `K = 0`).
fn lobe_mass_slope(k: f64) -> f64 {
    if k.abs() < 1e-4 {
        // M(K) = 4π (1 − K + 2K²/3 − K³/3 + …)
        4.0 * PI * (-1.0 + 4.0 * k / 3.0 - k * k)
    } else {
        let e = (-2.0 * k).exp();
        2.0 * PI * (2.0 * k * e + (-2.0 * k).exp_m1()) / (k * k)
    }
}

/// Which parameter of a vMF-mixture lobe.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VmfParam {
    Weight,
    Kappa,
}

impl VmfMixture {
    /// From positive weights and finite concentrations (`|κ| ≤ 1e5`; negative ones are backward
    /// lobes); the message names the offending entry.
    pub fn new(weights: &[f64], kappas: &[f64]) -> Result<Self, String> {
        if weights.is_empty() || weights.len() != kappas.len() {
            return Err(format!(
                "weights has {} entries and kappas {}: give the same, at least one",
                weights.len(),
                kappas.len()
            ));
        }
        for (i, w) in weights.iter().enumerate() {
            if !w.is_finite() || *w <= 0.0 {
                return Err(format!("weights[{i}] = {w}: must be positive"));
            }
        }
        for (i, k) in kappas.iter().enumerate() {
            if !k.is_finite() || k.abs() > 1e5 {
                return Err(format!(
                    "kappas[{i}] = {k}: must be finite, within [-1e5, 1e5]"
                ));
            }
        }
        // ∫ s² dω = Σ_mn w_m w_n ∫ e^{(κ_m+κ_n)(μ−1)} dω
        let mut masses = Vec::new();
        let mut total = 0.0;
        for (wm, km) in weights.iter().zip(kappas) {
            for (wn, kn) in weights.iter().zip(kappas) {
                let m = wm * wn * lobe_mass(km + kn);
                masses.push((m, km + kn));
                total += m;
            }
        }
        let scale = 1.0 / total.sqrt();
        let mut acc = 0.0;
        let components = masses
            .into_iter()
            .map(|(m, k)| {
                acc += m / total;
                (acc, k)
            })
            .collect();
        Ok(VmfMixture {
            lobes: weights
                .iter()
                .zip(kappas)
                .map(|(w, k)| (w * scale, *k))
                .collect(),
            components,
        })
    }

    /// The normalised lobes `(w_m, κ_m)` of the amplitude.
    pub fn lobes(&self) -> &[(f64, f64)] {
        &self.lobes
    }

    /// A copy with lobe `m`'s (unnormalised) weight or concentration replaced by `v`, normalised
    /// again.
    pub fn with(&self, m: usize, which: VmfParam, v: f64) -> Result<Self, String> {
        let (mut w, mut k): (Vec<f64>, Vec<f64>) = self.lobes.iter().copied().unzip();
        match which {
            VmfParam::Weight => w[m] = v,
            VmfParam::Kappa => k[m] = v,
        }
        VmfMixture::new(&w, &k)
    }

    /// `∂(w_n, κ_n)/∂θ` of the normalised lobes for `θ` lobe `m`'s unnormalised weight (at the
    /// normalised point, where `N = ∫ s² dω = 1`) or its concentration: with `N = Σ w_i w_j
    /// M(κ_i + κ_j)`, `M(K) = ∫ e^{K(μ−1)} dω`, the weights are `w/√N`, so
    /// `∂w_n/∂w_m = δ_nm − w_n Σ_j w_j M(κ_m + κ_j)` and
    /// `∂w_n/∂κ_m = −w_n w_m Σ_j w_j M'(κ_m + κ_j)`.
    pub fn lobe_derivatives(&self, m: usize, which: VmfParam) -> (Vec<f64>, Vec<f64>) {
        let n = self.lobes.len();
        let (wm, km) = self.lobes[m];
        let mut dw = vec![0.0; n];
        let mut dk = vec![0.0; n];
        match which {
            VmfParam::Weight => {
                let half_dn: f64 = self.lobes.iter().map(|(w, k)| w * lobe_mass(km + k)).sum();
                for (i, (d, (w, _))) in dw.iter_mut().zip(&self.lobes).enumerate() {
                    *d = f64::from(u8::from(i == m)) - w * half_dn;
                }
            }
            VmfParam::Kappa => {
                let half_dn: f64 = wm
                    * self
                        .lobes
                        .iter()
                        .map(|(w, k)| w * lobe_mass_slope(km + k))
                        .sum::<f64>();
                for (d, (w, _)) in dw.iter_mut().zip(&self.lobes) {
                    *d = -w * half_dn;
                }
                dk[m] = 1.0;
            }
        }
        (dw, dk)
    }

    /// `∂ log ρ(μ)/∂θ = 2 ∂s/∂θ / s` for `θ` lobe `m`'s weight or concentration, without
    /// allocating (the derivatives of [`VmfMixture::lobe_derivatives`] summed in place):
    /// `∂s/∂w_m = e_m − s Σ_j w_j M(κ_m+κ_j)`, `∂s/∂κ_m = w_m ((μ−1) e_m − s Σ_j w_j M'(κ_m+κ_j))`
    /// with `e_m = e^{κ_m(μ−1)}`.
    #[inline]
    pub fn dlog_rho(&self, mu: f64, m: usize, which: VmfParam) -> f64 {
        let Some(&(wm, km)) = self.lobes.get(m) else {
            return 0.0;
        };
        let s = self.amplitude(mu);
        let em = (km * (mu - 1.0)).exp();
        match which {
            VmfParam::Weight => {
                let h: f64 = self.lobes.iter().map(|(w, k)| w * lobe_mass(km + k)).sum();
                2.0 * (em / s - h)
            }
            VmfParam::Kappa => {
                let h: f64 = self
                    .lobes
                    .iter()
                    .map(|(w, k)| w * lobe_mass_slope(km + k))
                    .sum();
                2.0 * wm * ((mu - 1.0) * em / s - h)
            }
        }
    }

    /// `s(μ)`, real and positive.
    pub fn amplitude(&self, mu: f64) -> f64 {
        self.lobes
            .iter()
            .map(|(w, k)| w * (k * (mu - 1.0)).exp())
            .sum()
    }

    /// `ρ(μ) = s(μ)²`.
    pub fn eval(&self, mu: f64) -> f64 {
        self.amplitude(mu).powi(2)
    }

    /// `μ` with density `2π ρ(μ)` from one uniform number: a component of `ρ`, then its vMF.
    pub fn sample_mu(&self, u: f64) -> f64 {
        let i = self
            .components
            .partition_point(|c| c.0 <= u)
            .min(self.components.len() - 1);
        let lo = if i == 0 {
            0.0
        } else {
            self.components[i - 1].0
        };
        let v = ((u - lo) / (self.components[i].0 - lo)).clamp(0.0, 1.0);
        crate::math::vmf::sample_cosine(self.components[i].1, v)
    }

    /// Mean cosine: `Σ p_mn (coth K − 1/K)`.
    pub fn mean_cosine(&self) -> f64 {
        let mut prev = 0.0;
        self.components
            .iter()
            .map(|&(c, k)| {
                let p = c - prev;
                prev = c;
                p * mean_cosine(k)
            })
            .sum()
    }
}

impl Lobes {
    /// The least-squares weights of `s` on these lobes' concentrations (the fit's last step, on
    /// its quadrature): linear in `s`, so the projection of `∂s/∂θ` is the derivative of the
    /// projected weights. Projecting the fitted amplitude reproduces the fit's weights.
    pub fn project(&self, s: impl Fn(f64) -> C64) -> Lobes {
        let (mus, ws) = nodes();
        let values: Vec<C64> = mus.iter().map(|&m| s(m)).collect();
        let kappas: Vec<f64> = self.lobes.iter().map(|l| l.kappa).collect();
        let lobes = least_squares(&mus, &ws, &values, &kappas);
        let norm2: f64 = values.iter().zip(&ws).map(|(v, w)| w * v.norm_sqr()).sum();
        let error = if norm2 > 0.0 {
            (weighted_residual(&mus, &ws, &values, &lobes) / norm2).sqrt()
        } else {
            0.0
        };
        Lobes { lobes, error }
    }
}

/// Quadrature nodes `μ` and weights (per unit `μ`) concentrated towards `μ = 1`.
fn nodes() -> (Vec<f64>, Vec<f64>) {
    let (x, w) = gauss_legendre(24);
    // intervals in t = 1 − μ: [0, 1e-8], [1e-8, 1e-7.5], …, [1, 2]
    let mut edges = vec![0.0];
    let mut e: f64 = 1e-8;
    while e < 1.0 {
        edges.push(e);
        e *= 10f64.sqrt();
    }
    edges.push(1.0);
    edges.push(2.0);
    let (mut mus, mut ws) = (Vec::new(), Vec::new());
    for pair in edges.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        for (xi, wi) in x.iter().zip(&w) {
            mus.push(1.0 - (a + (b - a) * (xi + 1.0) / 2.0));
            ws.push(wi * (b - a) / 2.0);
        }
    }
    (mus, ws)
}

/// Mean cosine `A(κ) = coth κ − 1/κ` of a vMF distribution on the sphere, and its inverse.
fn mean_cosine(kappa: f64) -> f64 {
    if kappa.abs() < 1e-4 {
        kappa / 3.0
    } else {
        1.0 / kappa.tanh() - 1.0 / kappa
    }
}

fn concentration(r: f64) -> f64 {
    let r = r.clamp(-1.0 + 1e-12, 1.0 - 1e-12);
    // Banerjee et al.'s estimate, then Newton on A(κ) = r
    let mut kappa = r * (3.0 - r * r) / (1.0 - r * r);
    for _ in 0..20 {
        let a = mean_cosine(kappa) - r;
        let slope = if kappa.abs() < 1e-4 {
            1.0 / 3.0
        } else {
            let s = kappa.sinh();
            1.0 / (kappa * kappa) - 1.0 / (s * s)
        };
        let step = a / slope.max(1e-300);
        kappa -= step;
        if step.abs() < 1e-12 * kappa.abs().max(1.0) {
            break;
        }
    }
    kappa
}

/// `ln` of the vMF density per unit `μ`, `κ/(2 sinh κ) e^{κμ}`, computed without overflow.
fn log_density(kappa: f64, mu: f64) -> f64 {
    let a = kappa.abs();
    if a < 1e-8 {
        return -(2f64).ln();
    }
    // κ e^{κμ} / (2 sinh κ) = a e^{κμ − a} / (1 − e^{−2a})
    a.ln() + kappa * mu - a - (-(-2.0 * a).exp()).ln_1p()
}

/// Fit `s` with up to `MAX_LOBES` lobes, stopping at the first count within `tolerance`.
pub fn fit(s: impl Fn(f64) -> C64, tolerance: f64) -> Lobes {
    let (mus, ws) = nodes();
    let values: Vec<C64> = mus.iter().map(|&m| s(m)).collect();
    let norm2: f64 = values.iter().zip(&ws).map(|(v, w)| w * v.norm_sqr()).sum();
    // EM weights: directions weighted by |s|
    let data: Vec<f64> = values.iter().zip(&ws).map(|(v, w)| w * v.norm()).collect();
    let total: f64 = data.iter().sum();
    // the forward half-width sets the sharpest starting lobe
    let peak = values[0].norm();
    let half = mus
        .iter()
        .zip(&values)
        .find(|(_, v)| v.norm() < 0.5 * peak)
        .map(|(m, _)| 1.0 - m)
        .unwrap_or(1.0);
    let sharpest = (2f64.ln() / half.max(1e-8)).max(1.0);
    let backward = values.last().map(|v| v.norm()).unwrap_or(0.0) > s(0.0).norm();

    let mut best: Option<Lobes> = None;
    for count in 1..=MAX_LOBES {
        let kappas = em(&mus, &data, total, count, sharpest, backward);
        let kappas = refine(&mus, &ws, &values, kappas);
        let lobes = least_squares(&mus, &ws, &values, &kappas);
        let error = (weighted_residual(&mus, &ws, &values, &lobes) / norm2).sqrt();
        if best.as_ref().is_none_or(|b| error < b.error) {
            best = Some(Lobes { lobes, error });
        }
        if error < tolerance {
            break;
        }
    }
    best.expect("at least one lobe count is tried")
}

/// EM for the concentrations of `count` lobes sharing the forward axis.
fn em(
    mus: &[f64],
    data: &[f64],
    total: f64,
    count: usize,
    sharpest: f64,
    backward: bool,
) -> Vec<f64> {
    let mut kappa: Vec<f64> = (0..count)
        .map(|m| {
            if count == 1 {
                return sharpest.sqrt();
            }
            let t = m as f64 / (count - 1) as f64;
            0.5 * (sharpest / 0.5).powf(t)
        })
        .collect();
    if backward && count >= 2 {
        kappa[0] = -kappa[0].max(2.0);
    }
    let mut alpha = vec![1.0 / count as f64; count];
    let mut resp = vec![0.0; count];
    for _ in 0..300 {
        let mut mass = vec![0.0; count];
        let mut moment = vec![0.0; count];
        for (&mu, &d) in mus.iter().zip(data) {
            if d == 0.0 {
                continue;
            }
            let mut top = f64::NEG_INFINITY;
            for m in 0..count {
                resp[m] = alpha[m].ln() + log_density(kappa[m], mu);
                top = top.max(resp[m]);
            }
            let z: f64 = resp.iter().map(|r| (r - top).exp()).sum();
            for m in 0..count {
                let r = (resp[m] - top).exp() / z * d;
                mass[m] += r;
                moment[m] += r * mu;
            }
        }
        let mut change: f64 = 0.0;
        for m in 0..count {
            if mass[m] <= 1e-300 {
                continue;
            }
            alpha[m] = mass[m] / total;
            let k = concentration(moment[m] / mass[m]);
            change = change.max((k - kappa[m]).abs() / kappa[m].abs().max(1.0));
            kappa[m] = k;
        }
        if change < 1e-9 {
            break;
        }
    }
    kappa
}

/// `ŝ(μ) = Σ w_m e^{κ_m(μ−1)}`.
fn eval(lobes: &[Lobe], mu: f64) -> C64 {
    lobes
        .iter()
        .map(|l| l.weight * (l.kappa * (mu - 1.0)).exp())
        .sum()
}

/// `Σ w |s − ŝ|²` over the quadrature nodes for the lobes `ŝ`.
fn weighted_residual(mus: &[f64], ws: &[f64], values: &[C64], lobes: &[Lobe]) -> f64 {
    mus.iter()
        .zip(ws)
        .zip(values)
        .map(|((&m, w), v)| w * (v - eval(lobes, m)).norm_sqr())
        .sum()
}

/// Complex weights minimising `∫ |s − Σ w_m e^{κ_m(μ−1)}|² dμ` for fixed concentrations
/// (normal equations, Cholesky with a tiny ridge for nearly equal concentrations).
fn least_squares(mus: &[f64], ws: &[f64], values: &[C64], kappas: &[f64]) -> Vec<Lobe> {
    let n = kappas.len();
    let mut g = vec![0.0; n * n];
    let mut b = vec![C64::default(); n];
    for ((&mu, &w), v) in mus.iter().zip(ws).zip(values) {
        let basis: Vec<f64> = kappas.iter().map(|k| (k * (mu - 1.0)).exp()).collect();
        for i in 0..n {
            b[i] += v * (w * basis[i]);
            for j in 0..n {
                g[i * n + j] += w * basis[i] * basis[j];
            }
        }
    }
    let y = solve_spd(&mut g, n, b);
    y.into_iter()
        .zip(kappas)
        .map(|(weight, &kappa)| Lobe { weight, kappa })
        .collect()
}

/// Solve `G y = b` for symmetric positive (semi-)definite `G` (`n × n`, row-major, overwritten):
/// Cholesky with a tiny ridge, so nearly equal concentrations do not break it.
fn solve_spd(g: &mut [f64], n: usize, b: Vec<C64>) -> Vec<C64> {
    let ridge = 1e-13 * (0..n).map(|i| g[i * n + i]).sum::<f64>();
    for i in 0..n {
        g[i * n + i] += ridge;
    }
    for j in 0..n {
        let mut d = g[j * n + j];
        for k in 0..j {
            d -= g[j * n + k] * g[j * n + k];
        }
        let d = d.max(1e-300).sqrt();
        g[j * n + j] = d;
        for i in j + 1..n {
            let mut v = g[i * n + j];
            for k in 0..j {
                v -= g[i * n + k] * g[j * n + k];
            }
            g[i * n + j] = v / d;
        }
    }
    let mut y = b;
    for i in 0..n {
        for k in 0..i {
            let t = y[k] * g[i * n + k];
            y[i] -= t;
        }
        y[i] /= g[i * n + i];
    }
    for i in (0..n).rev() {
        for k in i + 1..n {
            let t = y[k] * g[k * n + i];
            y[i] -= t;
        }
        y[i] /= g[i * n + i];
    }
    y
}

/// The weighted residual `√w (s − ŝ)` of the least-squares weights for these concentrations.
fn residual(mus: &[f64], ws: &[f64], values: &[C64], kappas: &[f64]) -> Vec<C64> {
    let lobes = least_squares(mus, ws, values, kappas);
    mus.iter()
        .zip(ws)
        .zip(values)
        .map(|((&m, w), v)| (v - eval(&lobes, m)) * w.sqrt())
        .collect()
}

/// Refine the EM concentrations to the least-squares optimum of `s` (variable projection: the
/// weights are eliminated, Levenberg–Marquardt on `ln |κ|` with a central-difference Jacobian).
fn refine(mus: &[f64], ws: &[f64], values: &[C64], kappas: Vec<f64>) -> Vec<f64> {
    let n = kappas.len();
    let sign: Vec<f64> = kappas
        .iter()
        .map(|k| if *k < 0.0 { -1.0 } else { 1.0 })
        .collect();
    let to_kappa =
        |t: &[f64]| -> Vec<f64> { t.iter().zip(&sign).map(|(t, s)| s * t.exp()).collect() };
    let mut theta: Vec<f64> = kappas.iter().map(|k| k.abs().max(1e-3).ln()).collect();
    let cost = |r: &[C64]| r.iter().map(|z| z.norm_sqr()).sum::<f64>();
    let mut r = residual(mus, ws, values, &to_kappa(&theta));
    let mut f = cost(&r);
    let mut lambda = 1e-3;
    for _ in 0..60 {
        let h = 1e-5;
        let cols: Vec<Vec<C64>> = (0..n)
            .map(|m| {
                let mut up = theta.clone();
                let mut down = theta.clone();
                up[m] += h;
                down[m] -= h;
                let (a, b) = (
                    residual(mus, ws, values, &to_kappa(&up)),
                    residual(mus, ws, values, &to_kappa(&down)),
                );
                a.iter().zip(&b).map(|(a, b)| (a - b) / (2.0 * h)).collect()
            })
            .collect();
        let mut jtj = vec![0.0; n * n];
        let mut jtr = vec![C64::default(); n];
        for i in 0..n {
            jtr[i] = C64::new(
                -cols[i]
                    .iter()
                    .zip(&r)
                    .map(|(j, r)| (j.conj() * r).re)
                    .sum::<f64>(),
                0.0,
            );
            for k in 0..n {
                jtj[i * n + k] = cols[i]
                    .iter()
                    .zip(&cols[k])
                    .map(|(a, b)| (a.conj() * b).re)
                    .sum();
            }
        }
        let mut improved = false;
        while lambda < 1e8 {
            let mut a = jtj.clone();
            for i in 0..n {
                a[i * n + i] *= 1.0 + lambda;
            }
            let step = solve_spd(&mut a, n, jtr.clone());
            let trial: Vec<f64> = theta
                .iter()
                .zip(&step)
                .map(|(t, d)| t + d.re.clamp(-2.0, 2.0))
                .collect();
            let rt = residual(mus, ws, values, &to_kappa(&trial));
            let ft = cost(&rt);
            if ft < f {
                improved = ft < f * (1.0 - 1e-10);
                theta = trial;
                r = rt;
                f = ft;
                lambda = (lambda / 3.0).max(1e-9);
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    to_kappa(&theta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::phase::Table;

    /// The fit error is measured independently of the fit's own quadrature: plain Gauss–Legendre
    /// with many nodes after the substitution `1 − μ = 2 t⁴`, which resolves the forward peak.
    fn independent_error(p: &PhaseFunction, lobes: &Lobes) -> f64 {
        let (x, w) = gauss_legendre(4000);
        let (mut num, mut den) = (0.0, 0.0);
        for (xi, wi) in x.iter().zip(&w) {
            let t = (xi + 1.0) / 2.0;
            let mu = 1.0 - 2.0 * t.powi(4);
            let jac = wi / 2.0 * 8.0 * t.powi(3);
            let s = p.amplitude(mu);
            num += jac * (s - lobes.eval(mu)).norm_sqr();
            den += jac * s.norm_sqr();
        }
        (num / den).sqrt()
    }

    #[test]
    fn vmf_mixture_is_normalised_sampled_and_has_its_mean_cosine() {
        let v = VmfMixture::new(&[1.0, 0.2, 0.05], &[40.0, 3.0, -2.0]).unwrap();
        // ∫ ρ dω = 1 and g by independent quadrature
        let (x, w) = gauss_legendre(2000);
        let norm: f64 = x
            .iter()
            .zip(&w)
            .map(|(m, w)| 2.0 * PI * w * v.eval(*m))
            .sum();
        let g: f64 = x
            .iter()
            .zip(&w)
            .map(|(m, w)| 2.0 * PI * w * m * v.eval(*m))
            .sum();
        assert!((norm - 1.0).abs() < 1e-10, "∫ρ = {norm}");
        assert!(
            (v.mean_cosine() - g).abs() < 1e-10,
            "{} vs {g}",
            v.mean_cosine()
        );
        // the sampler's mean cosine and the fraction backwards
        let n = 400_000;
        let samples: Vec<f64> = (0..n)
            .map(|i| v.sample_mu((i as f64 + 0.5) / n as f64))
            .collect();
        let mean = samples.iter().sum::<f64>() / n as f64;
        assert!((mean - g).abs() < 2e-3, "sampled g {mean} vs {g}");
        let back: f64 = x
            .iter()
            .zip(&w)
            .filter(|(m, _)| **m < 0.0)
            .map(|(m, w)| 2.0 * PI * w * v.eval(*m))
            .sum();
        let sampled_back = samples.iter().filter(|m| **m < 0.0).count() as f64 / n as f64;
        assert!(
            (back - sampled_back).abs() < 2e-3,
            "{back} vs {sampled_back}"
        );
        assert!(
            VmfMixture::new(&[1.0, -1.0], &[1.0, 2.0])
                .unwrap_err()
                .contains("weights[1]")
        );
        assert!(VmfMixture::new(&[1.0], &[1.0, 2.0]).is_err());
    }

    /// `∂ log ρ/∂θ` and the lobe derivatives of a vMF mixture (normalisation included) against
    /// central differences of the renormalised mixture.
    #[test]
    fn vmf_mixture_derivatives_match_differences() {
        let v = VmfMixture::new(&[1.0, 0.3, 0.1], &[8.0, 1.5, -0.5]).unwrap();
        for m in 0..3 {
            for which in [VmfParam::Weight, VmfParam::Kappa] {
                let x = match which {
                    VmfParam::Weight => v.lobes()[m].0,
                    VmfParam::Kappa => v.lobes()[m].1,
                };
                let h = 1e-6 * x.abs().max(0.1);
                let (up, down) = (
                    v.with(m, which, x + h).unwrap(),
                    v.with(m, which, x - h).unwrap(),
                );
                let (dw, dk) = v.lobe_derivatives(m, which);
                for n in 0..3 {
                    let fd = (up.lobes()[n].0 - down.lobes()[n].0) / (2.0 * h);
                    assert!(
                        (dw[n] - fd).abs() < 1e-7,
                        "{which:?} {m}: dw[{n}] {} vs {fd}",
                        dw[n]
                    );
                    let fd = (up.lobes()[n].1 - down.lobes()[n].1) / (2.0 * h);
                    assert!(
                        (dk[n] - fd).abs() < 1e-7,
                        "{which:?} {m}: dκ[{n}] {} vs {fd}",
                        dk[n]
                    );
                }
                for mu in [-0.9, 0.0, 0.7, 0.99] {
                    let fd = (up.eval(mu).ln() - down.eval(mu).ln()) / (2.0 * h);
                    let d = v.dlog_rho(mu, m, which);
                    assert!(
                        (d - fd).abs() < 1e-6 * fd.abs().max(1.0),
                        "{which:?} {m} μ {mu}: {d} vs {fd}"
                    );
                }
            }
        }
    }

    #[test]
    fn isotropic_is_one_exact_lobe() {
        let l = Lobes::of(&PhaseFunction::Isotropic);
        assert_eq!(l.lobes.len(), 1);
        assert!((l.eval(0.3).re - PhaseFunction::Isotropic.amplitude(0.3).re).abs() < 1e-15);
    }

    #[test]
    fn concentration_inverts_the_mean_cosine() {
        for k in [-30.0, -1.0, 0.01, 0.7, 5.0, 200.0, 1e4] {
            assert!((concentration(mean_cosine(k)) - k).abs() < 1e-6 * k.abs().max(1.0));
        }
    }

    #[test]
    fn henyey_greenstein_fits_within_tolerance() {
        for g in [0.0, 0.3, 0.7, 0.9, 0.98, -0.5] {
            let p = PhaseFunction::HenyeyGreenstein { g };
            let l = Lobes::of(&p);
            let e = independent_error(&p, &l);
            assert!(
                l.error < TOLERANCE && e < 1.5 * TOLERANCE,
                "g = {g}: {} lobes, error {} (independent {e})",
                l.lobes.len(),
                l.error
            );
        }
    }

    #[test]
    fn complex_table_with_back_lobe_fits() {
        let cos: Vec<f64> = (0..=200).map(|i| -1.0 + i as f64 / 100.0).collect();
        let s: Vec<C64> = cos
            .iter()
            .map(|&m| {
                let forward = (8.0 * (m - 1.0)).exp();
                let back = 0.3 * (-3.0 * (m + 1.0)).exp();
                C64::from_polar(forward + back, 0.4 * m)
            })
            .collect();
        let p = PhaseFunction::Tabulated(Table::from_amplitude(Some(cos), s).unwrap());
        let l = Lobes::of(&p);
        let e = independent_error(&p, &l);
        assert!(
            e < 1e-2,
            "{} lobes, error {} (independent {e})",
            l.lobes.len(),
            l.error
        );
    }
}
