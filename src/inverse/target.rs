//! Fit targets: memory-effect curves (our `memory_effect.json`, or a measured curve as CSV
//! `angle_deg,correlation[,stderr]` or JSON `{"angles_deg": [...], "correlation": [...],
//! "stderr": [...]}`), covariances (our `covariance.json`, from Monte Carlo or the wave solver), and
//! arbitrary sets of measured entries (`{"entries": [{"light": [l1, l2], "view": [v1, v2], "re": ..,
//! "im": .., "stderr": ..}, {"light": .., "view": .., "intensity_correlation": .., "stderr": ..}]}`,
//! indices into the config's lights and views): complex field covariances `C = E[u1 ū2] − m1 m̄2`,
//! intensity correlations `E[I1 I2] − E[I1] E[I2] = |C|²` (Gaussian speckle; paper 004, Eqs. 4, 8),
//! which is what a camera measures, or — when the camera's scale is unknown — normalised intensity
//! correlations over a window of view pairs `(v1ₖ, v2ₖ)` (`{"light": .., "views": [[v1, v2], ..],
//! "normalised_intensity_correlation": ..}`): `⟨|C12|²⟩ₖ / (⟨C11⟩ₖ ⟨C22⟩ₖ)`, Eq. 4 divided by the
//! window means, as `lightpath acquire-phase` writes it.
//! Each gives the loss (weighted least squares, by the target's standard errors when it has them),
//! its adjoint `∂L/∂C` and the residuals.

use crate::math::C64;
use crate::speckle::Scene;
use std::path::Path;

/// What to fit to.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// Intensity correlation `|C12|²/(C11 C22)` of light 0 and view 0 tilted together by each angle.
    Memory {
        angles_deg: Vec<f64>,
        correlation: Vec<f64>,
        stderr: Option<Vec<f64>>,
    },
    /// Covariance entries, `J×J` in the pair order `j = l·V + v` (`J = lights × views`).
    Covariance {
        lights: usize,
        views: usize,
        value: Vec<C64>,
        stderr: Vec<f64>,
    },
    /// Chosen entries between (light, view) pairs, each a field covariance or an intensity
    /// correlation; `stderr` for all entries or none.
    Entries {
        entries: Vec<Entry>,
        stderr: Option<Vec<f64>>,
    },
}

/// One measured entry: lights `(l1, l2)`, view pairs `(v1, v2)` and what was measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub light: [usize; 2],
    /// One view pair; a normalised correlation may average several (the points of a window).
    pub views: Vec<[usize; 2]>,
    pub value: Measured,
}

/// A measured field covariance `C`, an intensity correlation `|C|²`, or a normalised intensity
/// correlation `⟨|C12|²⟩ₖ / (⟨C11⟩ₖ ⟨C22⟩ₖ)` over the entry's view pairs `k`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Measured {
    Field(C64),
    Intensity(f64),
    Normalised(f64),
}

/// The covariance indices one entry reads: per view pair, `(a, b)` into the target's pairs.
type Terms = Vec<(usize, usize)>;

/// A normalised correlation `r = K Σ|C_ab|² / (Σ C_aa · Σ C_bb)` over the terms of one entry, and
/// its adjoint for `∂L/∂r = g` added into `adj` (`dL = Re Σ conj(Ā) dC`).
fn normalised(c: &[C64], j: usize, terms: &[(usize, usize)], g: f64, adj: &mut [C64]) -> f64 {
    let k = terms.len() as f64;
    let (mut s, mut a, mut b) = (0.0, 0.0, 0.0);
    for &(p, q) in terms {
        s += c[p * j + q].norm_sqr();
        a += c[p * j + p].re;
        b += c[q * j + q].re;
    }
    let r = k * s / (a * b);
    if g != 0.0 {
        for &(p, q) in terms {
            // d|C|² = Re(conj(2C) dC); dr/d|C|² = K / (A B)
            adj[p * j + q] += c[p * j + q] * (2.0 * g * k / (a * b));
            adj[p * j + p] += C64::new(-g * r / a, 0.0);
            adj[q * j + q] += C64::new(-g * r / b, 0.0);
        }
    }
    r
}

impl Target {
    /// Check a target read from `path`: lengths agree, values and errors are finite and positive
    /// where they must be.
    pub fn validate(&self, path: &Path) -> crate::Result<()> {
        match self {
            Target::Memory {
                angles_deg,
                correlation,
                stderr,
            } => {
                if angles_deg.is_empty() || angles_deg.len() != correlation.len() {
                    return Err(format!(
                        "{}: angles_deg and correlation must be non-empty and of equal length",
                        path.display()
                    )
                    .into());
                }
                if let Some(s) = stderr
                    && (s.len() != angles_deg.len()
                        || s.iter().any(|x| !(*x > 0.0 && x.is_finite())))
                {
                    return Err(format!(
                        "{}: stderr must have one positive value per angle",
                        path.display()
                    )
                    .into());
                }
                if angles_deg.iter().chain(correlation).any(|x| !x.is_finite()) {
                    return Err(
                        format!("{}: non-finite angle or correlation", path.display()).into(),
                    );
                }
            }
            Target::Covariance { value, .. } => {
                if value.iter().any(|z| !z.re.is_finite() || !z.im.is_finite()) {
                    return Err(format!("{}: non-finite covariance entries", path.display()).into());
                }
            }
            Target::Entries { entries, stderr } => {
                for (i, e) in entries.iter().enumerate() {
                    let finite = match e.value {
                        Measured::Field(z) => z.re.is_finite() && z.im.is_finite(),
                        Measured::Intensity(c) | Measured::Normalised(c) => c.is_finite(),
                    };
                    if !finite {
                        return Err(
                            format!("{}: entries[{i}] is not finite", path.display()).into()
                        );
                    }
                    if let Some(s) = stderr
                        && !(s[i] > 0.0 && s[i].is_finite())
                    {
                        return Err(format!(
                            "{}: entries[{i}].stderr = {}: must be > 0",
                            path.display(),
                            s[i]
                        )
                        .into());
                    }
                }
            }
        }
        Ok(())
    }

    /// Check the target against the scene it is fitted with (light and view counts, indices).
    pub fn check_scene(&self, scene: &Scene, path: &Path) -> crate::Result<()> {
        let (nl, nv) = (scene.lights.len(), scene.views.len());
        match self {
            Target::Memory { .. } => Ok(()),
            Target::Covariance { lights, views, .. } if (*lights, *views) != (nl, nv) => {
                Err(format!(
                    "target {} has {lights} light(s) × {views} view(s) but the config has {nl} × {nv}",
                    path.display()
                ).into())
            }
            Target::Covariance { .. } => Ok(()),
            Target::Entries { entries, .. } => {
                for (i, e) in entries.iter().enumerate() {
                    if e.light.iter().any(|l| *l >= nl)
                        || e.views.iter().flatten().any(|v| *v >= nv)
                    {
                        return Err(format!(
                            "target {}: entries[{i}] has light {:?}, views {:?}; the config has {nl} light(s) and {nv} view(s) (indices from 0)",
                            path.display(),
                            e.light,
                            e.views
                        ).into());
                    }
                }
                Ok(())
            }
        }
    }

    /// For an entries target: per entry, each view pair's `(a, b)` indices into [`Self::pairs`].
    pub fn entry_terms(&self) -> Vec<Terms> {
        match self {
            Target::Entries { entries, .. } => {
                let pairs = entry_pairs(entries);
                let at = |l: usize, v: usize| pairs.binary_search(&(l, v)).unwrap_or(0);
                entries
                    .iter()
                    .map(|e| {
                        e.views
                            .iter()
                            .map(|v| (at(e.light[0], v[0]), at(e.light[1], v[1])))
                            .collect()
                    })
                    .collect()
            }
            _ => vec![],
        }
    }

    /// Whether residuals are weighted by target errors (else the fit scales by the residual variance).
    pub fn has_errors(&self) -> bool {
        match self {
            Target::Memory { stderr, .. } | Target::Entries { stderr, .. } => stderr.is_some(),
            Target::Covariance { stderr, .. } => stderr.iter().all(|s| *s > 0.0),
        }
    }

    /// The (light, view) pairs whose covariance the target needs.
    pub fn pairs(&self, scene: &Scene) -> Vec<(usize, usize)> {
        match self {
            Target::Memory { angles_deg, .. } => (0..=angles_deg.len()).map(|j| (j, j)).collect(),
            Target::Covariance { .. } => crate::speckle::paths::SubpathSampler::all_pairs(scene),
            Target::Entries { entries, .. } => entry_pairs(entries),
        }
    }

    /// The `(a, b)` covariance entries (indices into [`Self::pairs`]) the loss reads.
    pub fn needed(&self) -> Vec<(usize, usize)> {
        match self {
            Target::Memory { angles_deg, .. } => {
                let mut e = vec![(0, 0)];
                for t in 1..=angles_deg.len() {
                    e.extend([(t, t), (0, t)]);
                }
                e
            }
            Target::Covariance { lights, views, .. } => {
                let j = lights * views;
                (0..j * j).map(|i| (i / j, i % j)).collect()
            }
            Target::Entries { entries, .. } => {
                let mut e = Vec::new();
                for (entry, terms) in entries.iter().zip(self.entry_terms()) {
                    for (a, b) in terms {
                        e.push((a, b));
                        if let Measured::Normalised(_) = entry.value {
                            e.extend([(a, a), (b, b)]);
                        }
                    }
                }
                e
            }
        }
    }

    /// Target values in the units of [`Self::model_values`].
    pub fn values(&self) -> Vec<f64> {
        match self {
            Target::Memory { correlation, .. } => correlation.clone(),
            Target::Covariance {
                lights,
                views,
                value,
                ..
            } => {
                let j = lights * views;
                (0..j).map(|a| value[a * j + a].re).collect()
            }
            Target::Entries { entries, .. } => entries
                .iter()
                .map(|e| match e.value {
                    Measured::Field(z) => z.re,
                    Measured::Intensity(c) | Measured::Normalised(c) => c,
                })
                .collect(),
        }
    }

    /// Model values comparable with the target: the correlation curve, or the covariance diagonal.
    pub fn model_values(&self, c: &[C64]) -> Vec<f64> {
        match self {
            Target::Memory { angles_deg, .. } => {
                let j = angles_deg.len() + 1;
                (1..j)
                    .map(|t| c[t].norm_sqr() / (c[0].re * c[t * j + t].re))
                    .collect()
            }
            Target::Covariance { lights, views, .. } => {
                let j = lights * views;
                (0..j).map(|a| c[a * j + a].re).collect()
            }
            Target::Entries { entries, .. } => {
                let j = entry_pairs(entries).len();
                entries
                    .iter()
                    .zip(self.entry_terms())
                    .map(|(e, t)| match e.value {
                        Measured::Field(_) => c[t[0].0 * j + t[0].1].re,
                        Measured::Intensity(_) => c[t[0].0 * j + t[0].1].norm_sqr(),
                        Measured::Normalised(_) => normalised(c, j, &t, 0.0, &mut []),
                    })
                    .collect()
            }
        }
    }

    /// Outputs whose per-chunk means the model's error estimate needs (memory: `C00, Ctt, C0t`;
    /// entries: those of the normalised correlations, sorted).
    pub fn keep(&self) -> Vec<usize> {
        match self {
            Target::Memory { angles_deg, .. } => {
                let j = angles_deg.len() + 1;
                let mut k = vec![0];
                for t in 1..j {
                    k.extend([t * j + t, t]);
                }
                k
            }
            Target::Entries { entries, .. } => {
                let j = entry_pairs(entries).len();
                let mut k: Vec<usize> = entries
                    .iter()
                    .zip(self.entry_terms())
                    .filter(|(e, _)| matches!(e.value, Measured::Normalised(_)))
                    .flat_map(|(_, t)| t)
                    .flat_map(|(a, b)| [a * j + b, a * j + a, b * j + b])
                    .collect();
                k.sort_unstable();
                k.dedup();
                k
            }
            Target::Covariance { .. } => vec![],
        }
    }

    /// Standard errors of the model's residuals (residual units): for a memory curve by the delta
    /// method over the kept per-chunk means (correlations between `C00, Ctt, C0t` included); for a
    /// covariance from the per-entry batch-means errors.
    pub fn model_stderr(&self, est: &crate::mc::Estimate, kept: &[C64]) -> Vec<f64> {
        match self {
            Target::Memory {
                angles_deg, stderr, ..
            } => {
                let j = angles_deg.len() + 1;
                let nk = 2 * angles_deg.len() + 1;
                let chunks = kept.len() / nk;
                let c = &est.mean;
                (1..j)
                    .map(|t| {
                        let (a, b, x) = (c[0].re, c[t * j + t].re, c[t]);
                        let r = x.norm_sqr() / (a * b);
                        let (ga, gb, gx) = (-r / a, -r / b, x * (2.0 / (a * b)));
                        let (ib, ix) = (2 * t - 1, 2 * t);
                        let mut var = 0.0;
                        for k in 0..chunks {
                            let row = &kept[k * nk..(k + 1) * nk];
                            let dx = row[ix] - x;
                            let lin = ga * (row[0].re - a)
                                + gb * (row[ib].re - b)
                                + gx.re * dx.re
                                + gx.im * dx.im;
                            var += lin * lin;
                        }
                        var /= (chunks as f64 - 1.0) * chunks as f64;
                        var.sqrt() / stderr.as_ref().map_or(1.0, |s| s[t - 1])
                    })
                    .collect()
            }
            Target::Covariance { stderr, .. } => est
                .stderr
                .iter()
                .zip(stderr)
                .flat_map(|(m, s)| [m / s.max(1e-300) / 2f64.sqrt(); 2])
                .collect(),
            Target::Entries { entries, stderr } => {
                let j = entry_pairs(entries).len();
                let keep = self.keep();
                let chunks = kept.len() / keep.len().max(1);
                let mut adj = vec![C64::default(); j * j];
                let mut out = Vec::new();
                for ((i, e), t) in entries.iter().enumerate().zip(self.entry_terms()) {
                    let (a, b) = t[0];
                    let (m, sd) = (est.mean[a * j + b], est.stderr[a * j + b]);
                    let s = stderr.as_ref().map_or(1.0, |s| s[i]);
                    match e.value {
                        Measured::Field(_) => out.extend([sd / s / 2f64.sqrt(); 2]),
                        // |C|² by the delta method: Var ≈ 4 (re² Var re + im² Var im) = 2 |C|² sd²
                        Measured::Intensity(_) => out.push(2f64.sqrt() * m.norm() * sd / s),
                        // the delta method over the entry's outputs: per chunk when kept
                        // (correlations included), else as if independent
                        Measured::Normalised(_) => {
                            normalised(&est.mean, j, &t, 1.0, &mut adj);
                            let used: Vec<usize> = t
                                .iter()
                                .flat_map(|&(a, b)| [a * j + b, a * j + a, b * j + b])
                                .collect::<std::collections::BTreeSet<_>>()
                                .into_iter()
                                .collect();
                            let var = if chunks > 1 {
                                let mut v = 0.0;
                                for k in 0..chunks {
                                    let row = &kept[k * keep.len()..(k + 1) * keep.len()];
                                    let lin: f64 = used
                                        .iter()
                                        .map(|&o| {
                                            let d = row[keep.binary_search(&o).unwrap_or(0)]
                                                - est.mean[o];
                                            adj[o].re * d.re + adj[o].im * d.im
                                        })
                                        .sum();
                                    v += lin * lin;
                                }
                                v / ((chunks as f64 - 1.0) * chunks as f64)
                            } else {
                                used.iter()
                                    .map(|&o| adj[o].norm_sqr() * est.stderr[o].powi(2) / 2.0)
                                    .sum()
                            };
                            for o in used {
                                adj[o] = C64::default();
                            }
                            out.push(var.sqrt() / s);
                        }
                    }
                }
                out
            }
        }
    }

    /// Weighted residuals.
    pub fn residuals(&self, c: &[C64]) -> Vec<f64> {
        match self {
            Target::Memory {
                correlation,
                stderr,
                ..
            } => {
                let r = self.model_values(c);
                r.iter()
                    .enumerate()
                    .map(|(t, x)| (x - correlation[t]) / stderr.as_ref().map_or(1.0, |s| s[t]))
                    .collect()
            }
            Target::Covariance { value, stderr, .. } => value
                .iter()
                .zip(stderr)
                .zip(c)
                .flat_map(|((t, s), m)| {
                    let d = (m - t) / s.max(1e-300);
                    [d.re, d.im]
                })
                .collect(),
            Target::Entries { entries, stderr } => {
                let j = entry_pairs(entries).len();
                let mut out = Vec::new();
                for ((i, e), terms) in entries.iter().enumerate().zip(self.entry_terms()) {
                    let (a, b) = terms[0];
                    let (m, s) = (c[a * j + b], stderr.as_ref().map_or(1.0, |s| s[i]));
                    match e.value {
                        Measured::Field(t) => {
                            let d = (m - t) / s;
                            out.extend([d.re, d.im]);
                        }
                        Measured::Intensity(t) => out.push((m.norm_sqr() - t) / s),
                        Measured::Normalised(t) => {
                            out.push((normalised(c, j, &terms, 0.0, &mut []) - t) / s)
                        }
                    }
                }
                out
            }
        }
    }

    /// The residuals' vector–Jacobian product `Σ_i a_i ∂r_i/∂C` at `c`, as an adjoint in the
    /// convention of [`Self::loss`] (`d(Σ a_i r_i) = Re Σ conj(Ā) dC`): the loss adjoint of the same
    /// target with its values moved so that its residuals at `c` are `a`, halved.
    pub fn residual_vjp(&self, c: &[C64], a: &[f64]) -> Vec<C64> {
        let mut t = self.clone();
        match &mut t {
            Target::Memory {
                correlation,
                stderr,
                ..
            } => {
                let m = self.model_values(c);
                for (k, corr) in correlation.iter_mut().enumerate() {
                    *corr = m[k] - a[k] * stderr.as_ref().map_or(1.0, |s| s[k]);
                }
            }
            Target::Covariance { value, stderr, .. } => {
                for (e, (v, s)) in value.iter_mut().zip(stderr.iter()).enumerate() {
                    *v = c[e] - C64::new(a[2 * e], a[2 * e + 1]) * s.max(1e-300);
                }
            }
            Target::Entries { entries, stderr } => {
                let j = entry_pairs(entries).len();
                let idx = self.entry_terms();
                let mut r = 0;
                for (i, (e, terms)) in entries.iter_mut().zip(idx).enumerate() {
                    let (p, q) = terms[0];
                    let (m, s) = (c[p * j + q], stderr.as_ref().map_or(1.0, |s| s[i]));
                    e.value = match e.value {
                        Measured::Field(_) => {
                            r += 2;
                            Measured::Field(m - C64::new(a[r - 2], a[r - 1]) * s)
                        }
                        Measured::Intensity(_) => {
                            r += 1;
                            Measured::Intensity(m.norm_sqr() - a[r - 1] * s)
                        }
                        Measured::Normalised(_) => {
                            r += 1;
                            let x = normalised(c, j, &terms, 0.0, &mut []);
                            Measured::Normalised(x - a[r - 1] * s)
                        }
                    };
                }
            }
        }
        t.loss(c).1.into_iter().map(|z| z * 0.5).collect()
    }

    /// Loss `Σ residual²` and its adjoint `∂L/∂C` (`dL = Re Σ conj(Ā) dC`).
    pub fn loss(&self, c: &[C64]) -> (f64, Vec<C64>) {
        let mut adj = vec![C64::default(); c.len()];
        let loss = match self {
            Target::Memory {
                correlation,
                stderr,
                ..
            } => {
                let j = correlation.len() + 1;
                let a = c[0].re;
                let mut l = 0.0;
                for t in 1..j {
                    let (b, x) = (c[t * j + t].re, c[t]);
                    let r = x.norm_sqr() / (a * b);
                    let s = stderr.as_ref().map_or(1.0, |s| s[t - 1]);
                    let res = (r - correlation[t - 1]) / s;
                    l += res * res;
                    let dl_dr = 2.0 * res / s;
                    adj[t] += x * (2.0 * dl_dr / (a * b));
                    adj[0] += C64::new(-dl_dr * r / a, 0.0);
                    adj[t * j + t] += C64::new(-dl_dr * r / b, 0.0);
                }
                l
            }
            Target::Covariance { value, stderr, .. } => {
                let mut l = 0.0;
                for (i, ((t, s), m)) in value.iter().zip(stderr).zip(c).enumerate() {
                    let w = 1.0 / s.max(1e-300).powi(2);
                    let d = m - t;
                    l += d.norm_sqr() * w;
                    adj[i] = d * (2.0 * w);
                }
                l
            }
            Target::Entries { entries, stderr } => {
                let j = entry_pairs(entries).len();
                let mut l = 0.0;
                for ((i, e), terms) in entries.iter().enumerate().zip(self.entry_terms()) {
                    let (a, b) = terms[0];
                    let (m, s) = (c[a * j + b], stderr.as_ref().map_or(1.0, |s| s[i]));
                    match e.value {
                        Measured::Field(t) => {
                            let d = (m - t) / s;
                            l += d.norm_sqr();
                            adj[a * j + b] += d * (2.0 / s);
                        }
                        Measured::Intensity(t) => {
                            // d|C|² = Re(conj(2C) dC)
                            let res = (m.norm_sqr() - t) / s;
                            l += res * res;
                            adj[a * j + b] += m * (4.0 * res / s);
                        }
                        Measured::Normalised(t) => {
                            // the adjoint of r at ∂L/∂r = 2 res / s, added in place
                            let r = normalised(c, j, &terms, 0.0, &mut []);
                            let res = (r - t) / s;
                            l += res * res;
                            normalised(c, j, &terms, 2.0 * res / s, &mut adj);
                        }
                    }
                }
                l
            }
        };
        (loss, adj)
    }
}

/// The distinct (light, view) pairs an entries target reads, sorted.
fn entry_pairs(entries: &[Entry]) -> Vec<(usize, usize)> {
    let mut p: Vec<(usize, usize)> = entries
        .iter()
        .flat_map(|e| {
            e.views
                .iter()
                .flat_map(|v| [(e.light[0], v[0]), (e.light[1], v[1])])
        })
        .collect();
    p.sort_unstable();
    p.dedup();
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two lights × three views seen through a 2-point window, with Hermitian-looking values.
    fn window() -> (Target, Vec<C64>) {
        let entries = vec![
            Entry {
                light: [0, 1],
                views: vec![[0, 1], [1, 2]],
                value: Measured::Normalised(0.05),
            },
            Entry {
                light: [0, 1],
                views: vec![[2, 0]],
                value: Measured::Intensity(0.3),
            },
        ];
        let t = Target::Entries {
            entries,
            stderr: Some(vec![0.01, 0.2]),
        };
        let j = 6; // pairs (l, v) with l ∈ {0, 1}, v ∈ {0, 1, 2}
        let c: Vec<C64> = (0..j * j)
            .map(|i| {
                let (a, b) = (i / j, i % j);
                if a == b {
                    C64::new(1.0 + 0.3 * a as f64, 0.0)
                } else {
                    C64::new(0.1 * (a + 2 * b) as f64 % 0.7, 0.05 * (a as f64 - b as f64))
                }
            })
            .collect();
        (t, c)
    }

    #[test]
    fn normalised_correlations_have_the_adjoint_of_their_loss() {
        let (t, c) = window();
        let (_, adj) = t.loss(&c);
        let h = 1e-6;
        let mut checked = 0;
        for i in 0..c.len() {
            for (part, unit) in [(0, C64::new(h, 0.0)), (1, C64::new(0.0, h))] {
                let (mut up, mut down) = (c.clone(), c.clone());
                up[i] += unit;
                down[i] -= unit;
                let fd = (t.loss(&up).0 - t.loss(&down).0) / (2.0 * h);
                let an = if part == 0 { adj[i].re } else { adj[i].im };
                assert!(
                    (fd - an).abs() < 1e-6 * (1.0 + fd.abs()),
                    "entry {i}.{part}: {fd} vs {an}"
                );
                checked += (an != 0.0) as usize;
            }
        }
        // off-diagonals of both window points, both diagonals of each, and the intensity entry
        assert!(checked >= 8, "{checked} non-zero adjoint parts");
    }

    #[test]
    fn normalised_correlations_are_the_window_ratio() {
        let (t, c) = window();
        let j = 6;
        // pairs sorted: (0,0)=0 (0,1)=1 (0,2)=2 (1,0)=3 (1,1)=4 (1,2)=5; window terms (0,4), (1,5)
        let s = c[4].norm_sqr() + c[j + 5].norm_sqr();
        let want = 2.0 * s / ((c[0].re + c[j + 1].re) * (c[4 * j + 4].re + c[5 * j + 5].re));
        assert!((t.model_values(&c)[0] - want).abs() < 1e-15);
        // the residual vector–Jacobian product matches the residuals' finite differences
        let a = [0.7, -1.3];
        let vjp = t.residual_vjp(&c, &a);
        let h = 1e-6;
        for i in [0, 4, j + 5, 5 * j + 5] {
            let (mut up, mut down) = (c.clone(), c.clone());
            up[i].re += h;
            down[i].re -= h;
            let (ru, rd) = (t.residuals(&up), t.residuals(&down));
            let fd: f64 = (0..2).map(|k| a[k] * (ru[k] - rd[k]) / (2.0 * h)).sum();
            assert!(
                (fd - vjp[i].re).abs() < 1e-6 * (1.0 + fd.abs()),
                "{i}: {fd} vs {}",
                vjp[i].re
            );
        }
        // the model keeps what the delta method needs: the window's three outputs per point
        assert_eq!(t.keep(), vec![0, 4, j + 1, j + 5, 4 * j + 4, 5 * j + 5]);
    }
}
