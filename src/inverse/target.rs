//! Fit targets: memory-effect curves (our `memory_effect.json`, or a measured curve as CSV
//! `angle_deg,correlation[,stderr]` or JSON `{"angles_deg": [...], "correlation": [...],
//! "stderr": [...]}`), covariances (our `covariance.json`, from Monte Carlo or the wave solver), and
//! arbitrary sets of measured entries (`{"entries": [{"light": [l1, l2], "view": [v1, v2], "re": ..,
//! "im": .., "stderr": ..}, {"light": .., "view": .., "intensity_correlation": .., "stderr": ..}]}`,
//! indices into the config's lights and views): complex field covariances `C = E[u1 ū2] − m1 m̄2`, or
//! intensity correlations `E[I1 I2] − E[I1] E[I2] = |C|²` (Gaussian speckle; paper 004, Eqs. 4, 8),
//! which is what a camera measures.
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

/// One measured entry: lights `(l1, l2)`, views `(v1, v2)` and what was measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub light: [usize; 2],
    pub view: [usize; 2],
    pub value: Measured,
}

/// A measured field covariance `C`, or an intensity correlation `|C|²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Measured {
    Field(C64),
    Intensity(f64),
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
                        Measured::Intensity(c) => c.is_finite(),
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
                    if e.light.iter().any(|l| *l >= nl) || e.view.iter().any(|v| *v >= nv) {
                        return Err(format!(
                            "target {}: entries[{i}] has light {:?}, view {:?}; the config has {nl} light(s) and {nv} view(s) (indices from 0)",
                            path.display(),
                            e.light,
                            e.view
                        ).into());
                    }
                }
                Ok(())
            }
        }
    }

    /// For an entries target: each entry's `(a, b)` indices into [`Self::pairs`].
    pub fn entry_indices(&self) -> Vec<(usize, usize)> {
        match self {
            Target::Entries { entries, .. } => {
                let pairs = entry_pairs(entries);
                let at = |l: usize, v: usize| pairs.binary_search(&(l, v)).unwrap_or(0);
                entries
                    .iter()
                    .map(|e| (at(e.light[0], e.view[0]), at(e.light[1], e.view[1])))
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
            Target::Entries { .. } => self.entry_indices(),
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
                    Measured::Intensity(c) => c,
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
                    .zip(self.entry_indices())
                    .map(|(e, (a, b))| match e.value {
                        Measured::Field(_) => c[a * j + b].re,
                        Measured::Intensity(_) => c[a * j + b].norm_sqr(),
                    })
                    .collect()
            }
        }
    }

    /// Outputs whose per-chunk means the model's error estimate needs (memory: `C00, Ctt, C0t`).
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
            Target::Covariance { .. } | Target::Entries { .. } => vec![],
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
                let mut out = Vec::new();
                for ((i, e), (a, b)) in entries.iter().enumerate().zip(self.entry_indices()) {
                    let (m, sd) = (est.mean[a * j + b], est.stderr[a * j + b]);
                    let s = stderr.as_ref().map_or(1.0, |s| s[i]);
                    match e.value {
                        Measured::Field(_) => out.extend([sd / s / 2f64.sqrt(); 2]),
                        // |C|² by the delta method: Var ≈ 4 (re² Var re + im² Var im) = 2 |C|² sd²
                        Measured::Intensity(_) => out.push(2f64.sqrt() * m.norm() * sd / s),
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
                for ((i, e), (a, b)) in entries.iter().enumerate().zip(self.entry_indices()) {
                    let (m, s) = (c[a * j + b], stderr.as_ref().map_or(1.0, |s| s[i]));
                    match e.value {
                        Measured::Field(t) => {
                            let d = (m - t) / s;
                            out.extend([d.re, d.im]);
                        }
                        Measured::Intensity(t) => out.push((m.norm_sqr() - t) / s),
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
                let idx = self.entry_indices();
                let mut r = 0;
                for (i, (e, (p, q))) in entries.iter_mut().zip(idx).enumerate() {
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
                for ((i, e), (a, b)) in entries.iter().enumerate().zip(self.entry_indices()) {
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
        .flat_map(|e| [(e.light[0], e.view[0]), (e.light[1], e.view[1])])
        .collect();
    p.sort_unstable();
    p.dedup();
    p
}
