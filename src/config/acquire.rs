//! `[acquisition]` + `[[pair]]`: speckle images of a slab in a 4f relay, read by
//! `lightpath acquire-phase` (paper 004). Lengths in one unit (µm, say).
//!
//! ```toml
//! [acquisition]
//! focal_length = 105000.0   # of the lens in front of the camera
//! pixel_pitch = 5.5
//! n_sample = 1.335          # the sample's index (Snell correction; flat parallel faces)
//! n_outside = 1.0           # default 1 (air)
//! window = 100              # side of the averaging window, pixels
//! step = 100                # between readings along τ, pixels (default: window)
//! ballistic_radius = 20     # masked around each ballistic peak, pixels
//! register_px = 3           # search ±3 px to register each window (optics' distortion; default 0)
//! axis_px = [2048.0, 2048.0]  # optical axis on the sensor (default: the image centre)
//! source_focal_length = 105000.0  # of the lens in front of the source (with pair.source_shift)
//! [[pair]]
//! first = "img_000.png"     # EXR, 8/16-bit PNG or TIFF (relative to this file)
//! second = "img_001.png"
//! peaks = [[2048.0, 2048.0], [2048.0, 2300.0]]   # optional: else the brightest pixels
//! # or: source_shift = [0.0, 1400.0]  # the point source's translation (second − first): the
//! #     relay images it onto the sensor, Δ = −(focal_length / source_focal_length) shift / pitch
//! [fit]                     # optional: hand the readings to `lightpath fit`
//! scene = "slab.toml"       # a speckle scene of the sample (wavelength, [medium], [render])
//! window_points = 2         # Gauss–Legendre points per window side in the model (1–4)
//! ```

use super::scene::positive;
use super::{ConfigError, err};
use crate::inverse::phase_from_speckle::{Relay, Settings};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AcquireConfig {
    pub acquisition: AcquisitionConfig,
    pub pair: Vec<PairConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<HandoffConfig>,
}

/// `[fit]`: write the readings as a `lightpath fit` target (normalised intensity correlations over
/// each window) with the scene it is fitted on (`scene`'s, its lights and views replaced by the
/// illuminations and the windows' directions inside the sample).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HandoffConfig {
    pub scene: PathBuf,
    #[serde(default = "two")]
    pub window_points: f64,
}

fn two() -> f64 {
    2.0
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AcquisitionConfig {
    pub focal_length: f64,
    pub pixel_pitch: f64,
    pub n_sample: f64,
    #[serde(default = "one")]
    pub n_outside: f64,
    /// Pixels (a whole number).
    pub window: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step: Option<f64>,
    #[serde(default)]
    pub ballistic_radius: f64,
    /// Pixels (a whole number): the local shifts searched to register the windows.
    #[serde(default)]
    pub register_px: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis_px: Option<[f64; 2]>,
    /// Focal length of the lens that collimates the point source (with `pair.source_shift`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_focal_length: Option<f64>,
}

fn one() -> f64 {
    1.0
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PairConfig {
    pub first: PathBuf,
    pub second: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peaks: Option<[[f64; 2]; 2]>,
    /// The point source's translation on its stage between the two images (second − first).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_shift: Option<[f64; 2]>,
}

impl AcquireConfig {
    /// The illumination displacement on the sensor that `pair[i].source_shift` gives, pixels: the
    /// two lenses image the source plane onto the sensor with magnification `−f / f_source` (a 4f
    /// relay inverts), so a translation `s` moves the ballistic peak by `−(f / f_source) s / pitch`.
    pub fn source_delta_px(&self, i: usize) -> Option<[f64; 2]> {
        let a = &self.acquisition;
        let (s, f) = (self.pair[i].source_shift?, a.source_focal_length?);
        let m = -a.focal_length / f / a.pixel_pitch;
        Some([m * s[0], m * s[1]])
    }
}

impl AcquireConfig {
    /// Image paths relative to the config's folder.
    pub(crate) fn resolve_paths(&mut self, base: &Path) {
        if let Some(f) = &mut self.fit
            && f.scene.is_relative()
        {
            f.scene = base.join(&f.scene);
        }
        for p in &mut self.pair {
            for f in [&mut p.first, &mut p.second] {
                if f.is_relative() {
                    *f = base.join(&*f);
                }
            }
        }
    }

    /// Check every value; the relay (axis at `axis_px`, or `centre` when absent) and settings.
    pub fn relay_and_settings(&self, centre: [f64; 2]) -> Result<(Relay, Settings), ConfigError> {
        let a = &self.acquisition;
        positive("acquisition.focal_length", a.focal_length)?;
        positive("acquisition.pixel_pitch", a.pixel_pitch)?;
        positive("acquisition.n_sample", a.n_sample)?;
        positive("acquisition.n_outside", a.n_outside)?;
        if !(a.window.fract() == 0.0 && (2.0..=4096.0).contains(&a.window)) {
            return err(format!(
                "acquisition.window = {}: must be a whole number of pixels within [2, 4096]",
                a.window
            ));
        }
        let step = a.step.unwrap_or(a.window);
        if !(step.fract() == 0.0 && (1.0..=4096.0).contains(&step)) {
            return err(format!(
                "acquisition.step = {step}: must be a whole number of pixels within [1, 4096]"
            ));
        }
        if !(a.ballistic_radius.is_finite() && a.ballistic_radius >= 0.0) {
            return err(format!(
                "acquisition.ballistic_radius = {}: must be a finite number >= 0 (pixels)",
                a.ballistic_radius
            ));
        }
        if !(a.register_px.fract() == 0.0 && (0.0..=16.0).contains(&a.register_px)) {
            return err(format!(
                "acquisition.register_px = {}: must be a whole number of pixels within [0, 16]",
                a.register_px
            ));
        }
        let axis = a.axis_px.unwrap_or(centre);
        if !axis.iter().all(|v| v.is_finite()) {
            return err(format!(
                "acquisition.axis_px = {axis:?}: must be finite pixel coordinates"
            ));
        }
        Ok((
            Relay {
                focal_length: a.focal_length,
                pixel_pitch: a.pixel_pitch,
                n_sample: a.n_sample,
                n_outside: a.n_outside,
                axis_px: axis,
            },
            Settings {
                window: a.window as usize,
                step: step as usize,
                ballistic_radius: a.ballistic_radius,
                register_px: a.register_px as usize,
            },
        ))
    }

    /// Check what can be checked without the images.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.relay_and_settings([0.0, 0.0])?;
        if self.pair.is_empty() {
            return err(
                "pair: the list is empty; give at least one [[pair]] with first and second",
            );
        }
        if let Some(f) = &self.fit
            && !(f.window_points.fract() == 0.0 && (1.0..=4.0).contains(&f.window_points))
        {
            return err(format!(
                "fit.window_points = {}: must be a whole number within [1, 4]",
                f.window_points
            ));
        }
        if let Some(f) = self.acquisition.source_focal_length {
            positive("acquisition.source_focal_length", f)?;
        }
        for (i, p) in self.pair.iter().enumerate() {
            if let Some(s) = p.source_shift {
                if !s.iter().all(|v| v.is_finite()) {
                    return err(format!(
                        "pair[{i}].source_shift = {s:?}: must be a finite translation"
                    ));
                }
                if p.peaks.is_some() {
                    return err(format!(
                        "pair[{i}]: give peaks or source_shift, not both (source_shift places the second peak from the first)"
                    ));
                }
                if self.acquisition.source_focal_length.is_none() {
                    return err(format!(
                        "pair[{i}].source_shift needs acquisition.source_focal_length (the lens in front of the source) to turn the translation into a tilt"
                    ));
                }
            }
            if let Some(peaks) = p.peaks
                && !peaks.iter().flatten().all(|v| v.is_finite())
            {
                return err(format!(
                    "pair[{i}].peaks = {peaks:?}: must be finite pixel coordinates"
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    const BASE: &str =
        "[acquisition]\nfocal_length = 1.0\npixel_pitch = 0.01\nn_sample = 1.0\nwindow = 8\n";

    fn refused(extra: &str, pair: &str, needle: &str) {
        let text = format!("{BASE}{extra}[[pair]]\nfirst = \"a.exr\"\nsecond = \"b.exr\"\n{pair}");
        let e = crate::config::load_text(&text).expect_err(needle);
        assert!(e.0.contains(needle), "{needle}: {}", e.0);
    }

    #[test]
    fn hand_off_and_source_translation_are_checked_by_key() {
        refused(
            "",
            "source_shift = [0.0, 1.0]\n",
            "pair[0].source_shift needs acquisition.source_focal_length",
        );
        refused(
            "source_focal_length = 2.0\n",
            "source_shift = [0.0, 1.0]\npeaks = [[1.0, 1.0], [1.0, 9.0]]\n",
            "give peaks or source_shift, not both",
        );
        refused(
            "source_focal_length = -2.0\n",
            "",
            "acquisition.source_focal_length",
        );
        refused(
            "source_focal_length = 2.0\n",
            "source_shift = [0.0, nan]\n",
            "pair[0].source_shift = [0.0, NaN]: must be a finite translation",
        );
        refused(
            "register_px = 2.5\n",
            "",
            "acquisition.register_px = 2.5: must be a whole number of pixels within [0, 16]",
        );
        let fit =
            |f: &str| format!("{BASE}[[pair]]\nfirst = \"a.exr\"\nsecond = \"b.exr\"\n[fit]\n{f}");
        let e = crate::config::load_text(&fit("scene = \"s.toml\"\nwindow_points = 7\n"))
            .expect_err("window_points");
        assert!(
            e.0.contains("fit.window_points = 7: must be a whole number within [1, 4]"),
            "{}",
            e.0
        );
        assert!(crate::config::load_text(&fit("window_points = 2\n")).is_err());
        assert!(crate::config::load_text(&fit("scene = \"s.toml\"\n")).is_ok());
    }
}
