//! The `[medium]` table: coefficients (mfp + albedo, σ_s + σ_a, or a volume fraction of Mie
//! spheres) and phase functions (isotropic, Henyey–Greenstein, tabulated inline or from a CSV file,
//! vMF mixtures, Mie spheres, mixtures of particle types) → [`Medium`].

use super::scene::{MediumConfig, PhaseConfig, positive};
use super::{ConfigError, err};
use crate::math::C64;
use crate::medium::mie::{Optics, Particles};
use crate::medium::{Geometry, Medium, PhaseFunction, Scattering, Table};
use std::path::Path;
use std::sync::{Arc, Mutex};

impl MediumConfig {
    /// The medium these keys describe, every value checked (`wavelength`: the scene's, in the host).
    pub(super) fn build(&self, wavelength: f64) -> Result<Medium, ConfigError> {
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
        let (sigma_s, sigma_a, scattering) = self.bulk(wavelength)?;
        Ok(Medium {
            geometry,
            sigma_s,
            sigma_a,
            scattering,
        })
    }

    /// `(σ_s, σ_a)` and the scattering law these keys describe (everything but the geometry).
    pub(super) fn bulk(&self, wavelength: f64) -> Result<(f64, f64, Scattering), ConfigError> {
        let by_components = self.component_coefficients(wavelength)?;
        let (sigma_s, sigma_a) = match (self.mfp, self.albedo, self.sigma_s, self.sigma_a) {
            _ if self.volume_fraction.is_some() => self.mie_coefficients(wavelength)?,
            (None, None, None, None) if let Some((s, a, _)) = &by_components => (*s, *a),
            _ if by_components.is_some() => {
                return err(
                    "medium: the components' volume_fraction give σ_s and σ_a; leave out mfp, albedo, sigma_s and sigma_a",
                );
            }
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
                return err(
                    "medium: give mfp (+ albedo), sigma_s (+ sigma_a) or volume_fraction (Mie spheres)",
                );
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
                    if let PhaseConfig::Mixture { .. } = c.phase {
                        return err(format!("{key}.phase: mixtures cannot be nested"));
                    }
                    let weight = match (&by_components, c.weight) {
                        (Some(c), _) => c.2[i],
                        (None, Some(w)) => positive(&format!("{key}.weight"), w)?,
                        (None, None) => {
                            return err(format!(
                                "{key}: give weight (its share of σ_s) or, for Mie spheres, volume_fraction"
                            ));
                        }
                    };
                    parts.push((weight, c.phase.build(&format!("{key}.phase"), wavelength)?));
                }
                Scattering::mixture(parts)
            }
            Some(p) => Scattering::single(p.build("medium.phase", wavelength)?),
        };
        Ok((sigma_s, sigma_a, scattering))
    }
}

impl MediumConfig {
    /// `(σ_s, σ_a)` of a volume fraction `f` of Mie spheres: number density `f / ⟨V⟩` times the mean
    /// cross-sections (independent scattering, so dilute suspensions).
    fn mie_coefficients(&self, wavelength: f64) -> Result<(f64, f64), ConfigError> {
        let f = self.volume_fraction.unwrap_or(0.0);
        if self.mfp.is_some()
            || self.albedo.is_some()
            || self.sigma_s.is_some()
            || self.sigma_a.is_some()
        {
            return err(
                "medium.volume_fraction: give it instead of mfp, albedo, sigma_s and sigma_a, not with them",
            );
        }
        if !(f.is_finite() && f > 0.0 && f <= 0.74) {
            return err(format!(
                "medium.volume_fraction = {f}: must be within (0, 0.74] (0.74: close-packed spheres)"
            ));
        }
        let Some(phase @ PhaseConfig::Mie { .. }) = &self.phase else {
            return err(
                "medium.volume_fraction needs medium.phase = { kind = \"mie\", ... } (the spheres' size and index)",
            );
        };
        let optics = phase.mie_optics("medium.phase", wavelength)?;
        let density = f / optics.mean_volume;
        Ok((density * optics.c_sca, density * optics.c_abs))
    }
}

impl MediumConfig {
    /// With every mixture component given by `volume_fraction` (Mie spheres): `(σ_s, σ_a, shares)`,
    /// summed over the components (independent scattering); `None` when they give weights.
    fn component_coefficients(
        &self,
        wavelength: f64,
    ) -> Result<Option<(f64, f64, Vec<f64>)>, ConfigError> {
        let Some(PhaseConfig::Mixture { components }) = &self.phase else {
            return Ok(None);
        };
        let fractions = components
            .iter()
            .filter(|c| c.volume_fraction.is_some())
            .count();
        if fractions == 0 {
            return Ok(None);
        }
        if fractions < components.len() || components.iter().any(|c| c.weight.is_some()) {
            return err(
                "medium.phase.components: give every component a volume_fraction (Mie spheres) or every one a weight, not both",
            );
        }
        if self.volume_fraction.is_some() {
            return err(
                "medium.volume_fraction: not with components' volume_fraction (each component gives its own)",
            );
        }
        let (mut s, mut a, mut shares, mut total) = (0.0, 0.0, Vec::new(), 0.0);
        for (i, c) in components.iter().enumerate() {
            let key = format!("medium.phase.components[{i}]");
            let f = c.volume_fraction.unwrap_or(0.0);
            if !(f.is_finite() && f > 0.0) {
                return err(format!(
                    "{key}.volume_fraction = {f}: must be a positive fraction"
                ));
            }
            total += f;
            if !matches!(c.phase, PhaseConfig::Mie { .. }) {
                return err(format!(
                    "{key}.volume_fraction needs {key}.phase = {{ kind = \"mie\", ... }}"
                ));
            }
            let o = c.phase.mie_optics(&format!("{key}.phase"), wavelength)?;
            let density = f / o.mean_volume;
            s += density * o.c_sca;
            a += density * o.c_abs;
            shares.push(density * o.c_sca);
        }
        if total > 0.74 {
            return err(format!(
                "medium.phase.components: volume fractions sum to {total}; at most 0.74 (close-packed spheres)"
            ));
        }
        Ok(Some((s, a, shares)))
    }
}

/// Mie optics already computed for these particles (a config is built more than once; size
/// averages take a second).
static MIE_CACHE: Mutex<Vec<(Particles, Arc<Optics>)>> = Mutex::new(Vec::new());

impl PhaseConfig {
    /// The Mie optics of a `kind = "mie"` phase, every key checked.
    fn mie_optics(&self, key: &str, wavelength: f64) -> Result<Arc<Optics>, ConfigError> {
        let PhaseConfig::Mie {
            diameter,
            diameter_spread,
            n_particle,
            k_particle,
            n_medium,
            ..
        } = self
        else {
            return err(format!("{key}: not a Mie phase function"));
        };
        positive(&format!("{key}.diameter"), *diameter)?;
        positive(&format!("{key}.n_particle"), *n_particle)?;
        positive(&format!("{key}.n_medium"), *n_medium)?;
        if !(k_particle.is_finite() && *k_particle >= 0.0) {
            return err(format!(
                "{key}.k_particle = {k_particle}: must be a finite number >= 0 (absorption)"
            ));
        }
        if !(diameter_spread.is_finite()
            && *diameter_spread >= 0.0
            && *diameter_spread < 3.0 * diameter)
        {
            return err(format!(
                "{key}.diameter_spread = {diameter_spread}: must be >= 0 and below 3 × diameter"
            ));
        }
        let particles = Particles {
            diameter: *diameter,
            spread: *diameter_spread,
            n_particle: C64::new(*n_particle, *k_particle),
            n_medium: *n_medium,
            wavelength,
        };
        let cached = |p: &Particles| {
            let cache = MIE_CACHE.lock().unwrap_or_else(|e| e.into_inner());
            cache.iter().find(|e| e.0 == *p).map(|e| e.1.clone())
        };
        if let Some(o) = cached(&particles) {
            return Ok(o);
        }
        let optics = Arc::new(
            particles
                .optics(&particles.default_grid())
                .map_err(|e| ConfigError(format!("{key}: {e}")))?,
        );
        let mut cache = MIE_CACHE.lock().unwrap_or_else(|e| e.into_inner());
        if cache.len() >= 8 {
            cache.remove(0);
        }
        cache.push((particles, optics.clone()));
        Ok(optics)
    }

    fn build(&self, key: &str, wavelength: f64) -> Result<PhaseFunction, ConfigError> {
        match self {
            PhaseConfig::Isotropic {} => Ok(PhaseFunction::Isotropic),
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
            PhaseConfig::Mie { polarisation, .. } => self
                .mie_optics(key, wavelength)?
                .table(polarisation.model())
                .map(PhaseFunction::Tabulated)
                .map_err(|e| ConfigError(format!("{key}: {e}"))),
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
