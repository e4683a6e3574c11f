//! Phase functions `ρ(cos θ)` and scattering amplitude functions `s(cos θ)` with `|s|² = ρ` and
//! `∫ ρ dω = 1` (paper 001, Eq. 1 and Sec. 3), plus mixtures of particle types (paper 001, App. 9.1).
//!
//! `cos θ` is the cosine between the incoming and outgoing *propagation* directions, so `g > 0`
//! scatters forward.

use crate::math::{C64, INV_4PI, cis, direction_about};
use glam::DVec3;
use std::f64::consts::PI;

/// One particle type's angular scattering law.
#[derive(Clone, Debug, PartialEq)]
pub enum PhaseFunction {
    Isotropic,
    /// Henyey–Greenstein with anisotropy `g ∈ (-1, 1)`; real, positive amplitude `s = √ρ`.
    HenyeyGreenstein {
        g: f64,
    },
    /// Piecewise-linear `ρ` (and linearly interpolated amplitude phase) on a grid of cosines.
    Tabulated(Table),
    /// Amplitude as real vMF lobes (paper 000, Eq. 28).
    VmfMixture(crate::medium::lobes::VmfMixture),
}

/// A tabulated phase function on nodes `cos[0] = -1 < … < cos[n-1] = 1`, normalised to `∫ρ dω = 1`.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    cos: Vec<f64>,
    rho: Vec<f64>,
    /// Phase of the amplitude `s` at the nodes (zero for a real table), unwrapped along the grid.
    arg: Vec<f64>,
    /// Cumulative distribution of `μ` at the nodes (`cdf[0] = 0`, `cdf[n-1] = 1`).
    cdf: Vec<f64>,
}

/// A cosine located in a [`Table`]: segment `i`, fraction `t` and the interpolated `ρ`.
#[derive(Clone, Copy, Debug)]
pub struct Located {
    i: usize,
    t: f64,
    rho: f64,
}

/// Why a table was rejected.
#[derive(Clone, Debug, PartialEq)]
pub enum TableError {
    Length(usize, usize),
    TooShort(usize),
    CosRange(f64, f64),
    NotIncreasing(usize),
    Negative(usize, f64),
    NotFinite(usize),
    ZeroIntegral,
}

impl std::fmt::Display for TableError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TableError::Length(a, b) => write!(
                f,
                "cos has {a} entries but the values have {b}; they must match"
            ),
            TableError::TooShort(n) => write!(f, "{n} entries: a table needs at least 2"),
            TableError::CosRange(a, b) => {
                write!(f, "cos runs from {a} to {b}; it must run from -1 to 1")
            }
            TableError::NotIncreasing(i) => write!(
                f,
                "cos[{i}] is not larger than cos[{}]; cos must increase strictly",
                i - 1
            ),
            TableError::Negative(i, v) => {
                write!(f, "entry {i} is {v}; a phase function must be >= 0")
            }
            TableError::NotFinite(i) => write!(f, "entry {i} is not a finite number"),
            TableError::ZeroIntegral => write!(
                f,
                "the table integrates to 0; it must integrate to a positive value"
            ),
        }
    }
}

impl Table {
    /// Build from unnormalised `ρ` values (`cos = None`: uniform grid over [-1, 1]).
    pub fn from_rho(cos: Option<Vec<f64>>, rho: Vec<f64>) -> Result<Self, TableError> {
        let arg = vec![0.0; rho.len()];
        Self::build(cos, rho, arg)
    }

    /// Build from an unnormalised complex amplitude table `s` (so `ρ = |s|²`).
    pub fn from_amplitude(cos: Option<Vec<f64>>, s: Vec<C64>) -> Result<Self, TableError> {
        for (i, z) in s.iter().enumerate() {
            if !(z.re.is_finite() && z.im.is_finite()) {
                return Err(TableError::NotFinite(i));
            }
        }
        let rho = s.iter().map(|z| z.norm_sqr()).collect();
        let mut arg: Vec<f64> = s.iter().map(|z| z.arg()).collect();
        for i in 1..arg.len() {
            // unwrap so that linear interpolation takes the short way round
            let d = arg[i] - arg[i - 1];
            arg[i] -= 2.0 * PI * (d / (2.0 * PI)).round();
        }
        Self::build(cos, rho, arg)
    }

    fn build(cos: Option<Vec<f64>>, mut rho: Vec<f64>, arg: Vec<f64>) -> Result<Self, TableError> {
        let n = rho.len();
        if n < 2 {
            return Err(TableError::TooShort(n));
        }
        let cos = match cos {
            Some(c) => c,
            None => (0..n)
                .map(|i| -1.0 + 2.0 * i as f64 / (n - 1) as f64)
                .collect(),
        };
        if cos.len() != n {
            return Err(TableError::Length(cos.len(), n));
        }
        for (i, &c) in cos.iter().enumerate() {
            if !c.is_finite() {
                return Err(TableError::NotFinite(i));
            }
            if i > 0 && c <= cos[i - 1] {
                return Err(TableError::NotIncreasing(i));
            }
        }
        if (cos[0] + 1.0).abs() > 1e-9 || (cos[n - 1] - 1.0).abs() > 1e-9 {
            return Err(TableError::CosRange(cos[0], cos[n - 1]));
        }
        for (i, &v) in rho.iter().enumerate() {
            if !v.is_finite() {
                return Err(TableError::NotFinite(i));
            }
            if v < 0.0 {
                return Err(TableError::Negative(i, v));
            }
        }
        let mut cdf = vec![0.0; n];
        for i in 1..n {
            cdf[i] = cdf[i - 1] + 0.5 * (rho[i] + rho[i - 1]) * (cos[i] - cos[i - 1]);
        }
        let total = 2.0 * PI * cdf[n - 1];
        if total <= 0.0 || !total.is_finite() {
            return Err(TableError::ZeroIntegral);
        }
        for v in &mut rho {
            *v /= total;
        }
        let last = cdf[n - 1];
        for c in &mut cdf {
            *c /= last;
        }
        Ok(Table { cos, rho, arg, cdf })
    }

    #[inline]
    fn segment(&self, mu: f64) -> (usize, f64) {
        let mu = mu.clamp(-1.0, 1.0);
        let i = self
            .cos
            .partition_point(|&c| c <= mu)
            .clamp(1, self.cos.len() - 1)
            - 1;
        let t = (mu - self.cos[i]) / (self.cos[i + 1] - self.cos[i]);
        (i, t)
    }

    fn rho(&self, mu: f64) -> f64 {
        self.locate(mu).rho
    }

    fn arg(&self, mu: f64) -> f64 {
        let (i, t) = self.segment(mu);
        self.arg[i] + t * (self.arg[i + 1] - self.arg[i])
    }

    fn sample_mu(&self, u: f64) -> f64 {
        let n = self.cos.len();
        let i = self.cdf.partition_point(|&c| c <= u).clamp(1, n - 1) - 1;
        let h = self.cos[i + 1] - self.cos[i];
        // pdf over μ on this segment: p(t) = p0 + a t (t ∈ [0, h]), p = 2π ρ
        let p0 = 2.0 * PI * self.rho[i];
        let a = 2.0 * PI * (self.rho[i + 1] - self.rho[i]) / h;
        let r = (u - self.cdf[i]).max(0.0);
        let disc = (p0 * p0 + 2.0 * a * r).max(0.0);
        let denom = p0 + disc.sqrt();
        let t = if denom > 0.0 { 2.0 * r / denom } else { 0.0 };
        (self.cos[i] + t.clamp(0.0, h)).clamp(-1.0, 1.0)
    }

    /// The normalised value `ρ_k` at node `k`.
    pub fn node_value(&self, k: usize) -> Option<f64> {
        self.rho.get(k).copied()
    }

    /// The table with node `k` set to `v` (amplitude phases kept) and renormalised.
    pub fn with_node_value(&self, k: usize, v: f64) -> Result<Table, TableError> {
        let mut values = self.rho.clone();
        if let Some(x) = values.get_mut(k) {
            *x = v;
        }
        self.with_node_values(&values)
    }

    /// The table with all node values replaced by (unnormalised) `values`, amplitude phases kept,
    /// and renormalised. The derivative of the result with respect to an unnormalised value is
    /// [`Self::dlog_rho_dnode`]` / Z` with `Z` = [`Self::integral`]`(values)`.
    pub fn with_node_values(&self, values: &[f64]) -> Result<Table, TableError> {
        if values.len() != self.rho.len() {
            return Err(TableError::Length(self.rho.len(), values.len()));
        }
        for (i, &v) in values.iter().enumerate() {
            if !v.is_finite() {
                return Err(TableError::NotFinite(i));
            }
            if v < 0.0 {
                return Err(TableError::Negative(i, v));
            }
        }
        let s = values
            .iter()
            .zip(&self.arg)
            .map(|(v, a)| cis(*a) * v.sqrt())
            .collect();
        Table::from_amplitude(Some(self.cos.clone()), s)
    }

    /// `Z = 2π ∫ ρ̃ dμ` of unnormalised node values on this table's grid (trapezoid, as `build`).
    pub fn integral(&self, values: &[f64]) -> f64 {
        2.0 * PI
            * self
                .cos
                .windows(2)
                .zip(values.windows(2))
                .map(|(c, v)| 0.5 * (v[0] + v[1]) * (c[1] - c[0]))
                .sum::<f64>()
    }

    /// `∂ log ρ(μ) / ∂v_k` for the node value `v_k` with the normalisation kept:
    /// `hat_k(μ)/ρ(μ) − 2π w_k` (`w_k` the trapezoid weight of node k; the table is normalised).
    pub fn dlog_rho_dnode(&self, mu: f64, k: usize) -> f64 {
        self.dlog_rho_dnode_at(self.locate(mu), k)
    }

    /// Where `μ` falls in the table, for [`Self::dlog_rho_dnode_at`]: one lookup serves every node.
    #[inline]
    pub fn locate(&self, mu: f64) -> Located {
        let (i, t) = self.segment(mu);
        Located {
            i,
            t,
            rho: self.rho[i] + t * (self.rho[i + 1] - self.rho[i]),
        }
    }

    /// [`Self::dlog_rho_dnode`] at a located `μ`.
    #[inline]
    pub fn dlog_rho_dnode_at(&self, at: Located, k: usize) -> f64 {
        let n = self.cos.len();
        let hat = if k == at.i {
            1.0 - at.t
        } else if k == at.i + 1 {
            at.t
        } else {
            0.0
        };
        let left = if k > 0 {
            self.cos[k] - self.cos[k - 1]
        } else {
            0.0
        };
        let right = if k + 1 < n {
            self.cos[k + 1] - self.cos[k]
        } else {
            0.0
        };
        let ratio = if at.rho > 0.0 { hat / at.rho } else { 0.0 };
        ratio - 2.0 * PI * 0.5 * (left + right)
    }

    /// The nodes (cosines) and normalised `ρ` values.
    pub fn nodes(&self) -> (&[f64], &[f64]) {
        (&self.cos, &self.rho)
    }
}

impl PhaseFunction {
    /// `ρ(μ)`, normalised so that `∫ ρ dω = 2π ∫ ρ dμ = 1`.
    #[inline]
    pub fn eval(&self, mu: f64) -> f64 {
        match self {
            PhaseFunction::Isotropic => INV_4PI,
            PhaseFunction::HenyeyGreenstein { g } => {
                let d = 1.0 + g * g - 2.0 * g * mu;
                INV_4PI * (1.0 - g * g) / (d * d.sqrt())
            }
            PhaseFunction::Tabulated(t) => t.rho(mu),
            PhaseFunction::VmfMixture(v) => v.eval(mu),
        }
    }

    /// Amplitude function `s(μ)` with `|s|² = ρ`.
    #[inline]
    pub fn amplitude(&self, mu: f64) -> C64 {
        match self {
            PhaseFunction::Tabulated(t) => cis(t.arg(mu)) * t.rho(mu).sqrt(),
            PhaseFunction::VmfMixture(v) => C64::new(v.amplitude(mu), 0.0),
            _ => C64::new(self.eval(mu).sqrt(), 0.0),
        }
    }

    /// `∂ log ρ(μ) / ∂g` for Henyey–Greenstein (`None` for other kinds: they have no `g`).
    #[inline]
    pub fn dlog_rho_dg(&self, mu: f64) -> Option<f64> {
        match self {
            PhaseFunction::HenyeyGreenstein { g } => {
                Some(-2.0 * g / (1.0 - g * g) - 3.0 * (g - mu) / (1.0 + g * g - 2.0 * g * mu))
            }
            _ => None,
        }
    }

    /// Sample `μ = cos θ` with density `2π ρ(μ)` from one uniform number.
    #[inline]
    pub fn sample_mu(&self, u: f64) -> f64 {
        match self {
            PhaseFunction::Isotropic => 1.0 - 2.0 * u,
            PhaseFunction::HenyeyGreenstein { g } => {
                let g = *g;
                if g.abs() < 1e-6 {
                    1.0 - 2.0 * u
                } else {
                    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
                    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
                }
            }
            PhaseFunction::Tabulated(t) => t.sample_mu(u),
            PhaseFunction::VmfMixture(v) => v.sample_mu(u),
        }
    }

    /// Sample an outgoing direction about incoming `w` (pdf `ρ(w·w')` per unit solid angle).
    #[inline]
    pub fn sample(&self, w: DVec3, u1: f64, u2: f64) -> DVec3 {
        direction_about(w, self.sample_mu(u1), 2.0 * PI * u2)
    }

    /// Mean cosine `g = 2π ∫ μ ρ(μ) dμ` (exact for isotropic and HG, trapezoid-exact for tables).
    pub fn mean_cosine(&self) -> f64 {
        match self {
            PhaseFunction::Isotropic => 0.0,
            PhaseFunction::HenyeyGreenstein { g } => *g,
            PhaseFunction::VmfMixture(v) => v.mean_cosine(),
            PhaseFunction::Tabulated(t) => {
                // exact integral of μ·(linear ρ) on each segment
                let mut acc = 0.0;
                for i in 1..t.cos.len() {
                    let (a, b) = (t.cos[i - 1], t.cos[i]);
                    let (ra, rb) = (t.rho[i - 1], t.rho[i]);
                    let h = b - a;
                    acc += h * (ra * (2.0 * a + b) + rb * (a + 2.0 * b)) / 6.0;
                }
                2.0 * PI * acc
            }
        }
    }
}

/// The scattering law of the medium: particle types mixed with weights `β` (fractions of `σ_s`,
/// paper 001 Eq. 44). A single type is a mixture of one.
#[derive(Clone, Debug, PartialEq)]
pub struct Scattering {
    components: Vec<(f64, PhaseFunction)>,
    cumulative: Vec<f64>,
}

impl Scattering {
    pub fn single(p: PhaseFunction) -> Self {
        Scattering {
            components: vec![(1.0, p)],
            cumulative: vec![1.0],
        }
    }

    /// Mixture from positive weights (normalised here to sum to one).
    pub fn mixture(components: Vec<(f64, PhaseFunction)>) -> Self {
        let total: f64 = components.iter().map(|c| c.0).sum();
        let components: Vec<_> = components
            .into_iter()
            .map(|(w, p)| (w / total, p))
            .collect();
        let mut acc = 0.0;
        let cumulative = components
            .iter()
            .map(|c| {
                acc += c.0;
                acc
            })
            .collect();
        Scattering {
            components,
            cumulative,
        }
    }

    pub fn components(&self) -> &[(f64, PhaseFunction)] {
        &self.components
    }

    /// Pick a particle type with probability `β` (index 0 without consuming randomness for one type).
    #[inline]
    pub fn pick(&self, u: impl FnOnce() -> f64) -> usize {
        if self.components.len() == 1 {
            return 0;
        }
        let u = u();
        self.cumulative
            .partition_point(|&c| c <= u)
            .min(self.components.len() - 1)
    }

    #[inline]
    pub fn phase(&self, kind: usize) -> &PhaseFunction {
        &self.components[kind].1
    }

    /// Bulk phase function `ρ = Σ β ρ_ι` (Eq. 44 with equal angles).
    pub fn eval(&self, mu: f64) -> f64 {
        self.components.iter().map(|(b, p)| b * p.eval(mu)).sum()
    }

    /// Bulk product `S(μ1, μ2) = Σ β s_ι(μ1) s_ι(μ2)*` (Eq. 44).
    pub fn amplitude_product(&self, mu1: f64, mu2: f64) -> C64 {
        self.components
            .iter()
            .map(|(b, p)| p.amplitude(mu1) * p.amplitude(mu2).conj() * *b)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn integrate(p: &PhaseFunction) -> f64 {
        // Simpson over μ with many panels
        let n = 20000;
        let h = 2.0 / n as f64;
        let mut acc = 0.0;
        for i in 0..=n {
            let w = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            acc += w * p.eval(-1.0 + i as f64 * h);
        }
        2.0 * PI * acc * h / 3.0
    }

    #[test]
    fn normalised() {
        let t = Table::from_rho(None, vec![1.0, 2.0, 5.0, 0.5]).unwrap();
        for p in [
            PhaseFunction::Isotropic,
            PhaseFunction::HenyeyGreenstein { g: 0.7 },
            PhaseFunction::HenyeyGreenstein { g: -0.3 },
            PhaseFunction::Tabulated(t),
        ] {
            assert!((integrate(&p) - 1.0).abs() < 1e-6, "{p:?}");
        }
    }

    #[test]
    fn amplitude_squares_to_rho() {
        let s = vec![C64::new(1.0, 0.0), C64::new(0.0, 2.0), C64::new(-1.0, -1.0)];
        let p = PhaseFunction::Tabulated(Table::from_amplitude(None, s).unwrap());
        for mu in [-1.0, -0.3, 0.0, 0.4, 1.0] {
            assert!((p.amplitude(mu).norm_sqr() - p.eval(mu)).abs() < 1e-14);
        }
    }

    #[test]
    fn table_errors() {
        assert_eq!(
            Table::from_rho(None, vec![1.0, -1.0]),
            Err(TableError::Negative(1, -1.0))
        );
        assert_eq!(
            Table::from_rho(None, vec![0.0, 0.0]),
            Err(TableError::ZeroIntegral)
        );
        assert!(matches!(
            Table::from_rho(Some(vec![-1.0, 0.5]), vec![1.0, 1.0]),
            Err(TableError::CosRange(..))
        ));
        assert!(matches!(
            Table::from_rho(None, vec![1.0]),
            Err(TableError::TooShort(1))
        ));
    }

    #[test]
    fn hg_mean_cosine_of_table() {
        let g = 0.5;
        let hg = PhaseFunction::HenyeyGreenstein { g };
        let cos: Vec<f64> = (0..=4000).map(|i| -1.0 + i as f64 / 2000.0).collect();
        let rho = cos.iter().map(|&m| hg.eval(m)).collect();
        let t = PhaseFunction::Tabulated(Table::from_rho(Some(cos), rho).unwrap());
        assert!((t.mean_cosine() - g).abs() < 1e-5);
    }
}
