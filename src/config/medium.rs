//! The `[medium]` table: coefficients (mfp + albedo or σ_s + σ_a) and phase functions (isotropic,
//! Henyey–Greenstein, tabulated inline or from a CSV file, mixtures of particle types) → [`Medium`].

use super::scene::{MediumConfig, PhaseConfig, positive};
use super::{ConfigError, err};
use crate::medium::{Geometry, Medium, PhaseFunction, Scattering, Table};
use std::path::Path;

impl MediumConfig {
    /// The medium these keys describe, every value checked.
    pub(super) fn build(&self) -> Result<Medium, ConfigError> {
        let geometry = match (self.box_size, self.slab) {
            (Some(b), None) => {
                for (a, v) in b.iter().enumerate() {
                    positive(&format!("medium.box[{a}]"), *v)?;
                }
                if self.slab_window.is_some() {
                    return err("medium.slab_window: only allowed with medium.slab");
                }
                Geometry::boxed(b)
            }
            (None, Some(l)) => {
                positive("medium.slab", l)?;
                let w = match self.slab_window {
                    Some(w) => positive("medium.slab_window", w)?,
                    None => 4.0 * l,
                };
                Geometry::slab(l, w)
            }
            (Some(_), Some(_)) => return err("medium: give either box or slab, not both"),
            (None, None) => {
                return err("medium: missing geometry; give box = [x, y, z] or slab = thickness");
            }
        };
        let (sigma_s, sigma_a) = match (self.mfp, self.albedo, self.sigma_s, self.sigma_a) {
            (Some(mfp), albedo, None, None) => {
                positive("medium.mfp", mfp)?;
                let a = albedo.unwrap_or(1.0);
                if !(0.0..=1.0).contains(&a) {
                    return err(format!("medium.albedo = {a}: must be within [0, 1]"));
                }
                if a == 0.0 {
                    return err("medium.albedo = 0: must be positive (nothing would scatter)");
                }
                crate::medium::params::sigmas(mfp, a)
            }
            (None, None, Some(s), a) => {
                positive("medium.sigma_s", s)?;
                let a = a.unwrap_or(0.0);
                if !a.is_finite() || a < 0.0 {
                    return err(format!(
                        "medium.sigma_a = {a}: must be a finite number >= 0"
                    ));
                }
                (s, a)
            }
            (None, Some(_), None, None) => return err("medium.albedo needs medium.mfp"),
            (None, None, None, Some(_)) => return err("medium.sigma_a needs medium.sigma_s"),
            (None, None, None, None) => {
                return err("medium: give mfp (+ albedo) or sigma_s (+ sigma_a)");
            }
            _ => return err("medium: give either mfp + albedo or sigma_s + sigma_a, not both"),
        };
        let scattering = match &self.phase {
            None => Scattering::single(PhaseFunction::Isotropic),
            Some(PhaseConfig::Mixture { components }) => {
                if components.is_empty() {
                    return err("medium.phase.components = []: give at least one component");
                }
                let mut parts = Vec::new();
                for (i, c) in components.iter().enumerate() {
                    let key = format!("medium.phase.components[{i}]");
                    positive(&format!("{key}.weight"), c.weight)?;
                    if let PhaseConfig::Mixture { .. } = c.phase {
                        return err(format!("{key}.phase: mixtures cannot be nested"));
                    }
                    parts.push((c.weight, c.phase.build(&format!("{key}.phase"))?));
                }
                Scattering::mixture(parts)
            }
            Some(p) => Scattering::single(p.build("medium.phase")?),
        };
        Ok(Medium {
            geometry,
            sigma_s,
            sigma_a,
            scattering,
        })
    }
}

impl PhaseConfig {
    fn build(&self, key: &str) -> Result<PhaseFunction, ConfigError> {
        match self {
            PhaseConfig::Isotropic => Ok(PhaseFunction::Isotropic),
            PhaseConfig::Hg { g } => {
                if !g.is_finite() || g.abs() >= 1.0 {
                    return err(format!("{key}.g = {g}: must be within (-1, 1)"));
                }
                Ok(PhaseFunction::HenyeyGreenstein { g: *g })
            }
            PhaseConfig::Tabulated {
                cos,
                values,
                amplitude_re,
                amplitude_im,
                file,
            } => {
                let table = match (values, amplitude_re, amplitude_im, file) {
                    (Some(v), None, None, None) => Table::from_rho(cos.clone(), v.clone()),
                    (None, Some(re), im, None) => {
                        let im = im.clone().unwrap_or_else(|| vec![0.0; re.len()]);
                        if im.len() != re.len() {
                            return err(format!(
                                "{key}.amplitude_im has {} entries but amplitude_re has {}; they must match",
                                im.len(),
                                re.len()
                            ));
                        }
                        let s = re
                            .iter()
                            .zip(&im)
                            .map(|(&a, &b)| crate::math::C64::new(a, b))
                            .collect();
                        Table::from_amplitude(cos.clone(), s)
                    }
                    (None, None, None, Some(f)) => {
                        if cos.is_some() {
                            return err(format!(
                                "{key}.cos: not allowed with {key}.file (the file has the cos column)"
                            ));
                        }
                        read_table_file(key, f)?
                    }
                    _ => {
                        return err(format!(
                            "{key}: give exactly one of values, amplitude_re (+ amplitude_im) or file"
                        ));
                    }
                };
                table
                    .map(PhaseFunction::Tabulated)
                    .map_err(|e| ConfigError(format!("{key}: {e}")))
            }
            PhaseConfig::VmfMixture { weights, kappas } => {
                crate::medium::lobes::VmfMixture::new(weights, kappas)
                    .map(PhaseFunction::VmfMixture)
                    .map_err(|e| ConfigError(format!("{key}.{e}")))
            }
            PhaseConfig::Mixture { .. } => err(format!("{key}: mixtures cannot be nested")),
        }
    }
}

/// Read a CSV table: `cos,value` or `cos,re,im` per line; `#` comments and a header line are skipped.
fn read_table_file(
    key: &str,
    path: &Path,
) -> Result<Result<Table, crate::medium::TableError>, ConfigError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError(format!("{key}.file = {}: cannot read: {e}", path.display())))?;
    let (mut cos, mut a, mut b) = (Vec::new(), Vec::new(), Vec::new());
    let mut columns = None;
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line
            .split([',', ' ', '\t', ';'])
            .filter(|s| !s.is_empty())
            .collect();
        let parsed: Result<Vec<f64>, _> = fields.iter().map(|s| s.parse::<f64>()).collect();
        let Ok(vals) = parsed else {
            if cos.is_empty() && columns.is_none() {
                continue; // header
            }
            return err(format!(
                "{key}.file = {}: line {}: not numbers: {line}",
                path.display(),
                n + 1
            ));
        };
        if *columns.get_or_insert(vals.len()) != vals.len() || !(2..=3).contains(&vals.len()) {
            return err(format!(
                "{key}.file = {}: line {}: expected 2 columns (cos,value) or 3 (cos,re,im) throughout",
                path.display(),
                n + 1
            ));
        }
        cos.push(vals[0]);
        a.push(vals[1]);
        b.push(vals.get(2).copied().unwrap_or(0.0));
    }
    Ok(if columns == Some(3) {
        Table::from_amplitude(
            Some(cos),
            a.iter()
                .zip(&b)
                .map(|(&x, &y)| crate::math::C64::new(x, y))
                .collect(),
        )
    } else {
        Table::from_rho(Some(cos), a)
    })
}
