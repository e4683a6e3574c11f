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
//! axis_px = [2048.0, 2048.0]  # optical axis on the sensor (default: the image centre)
//! [[pair]]
//! first = "img_000.png"     # EXR, 8/16-bit PNG or TIFF (relative to this file)
//! second = "img_001.png"
//! peaks = [[2048.0, 2048.0], [2048.0, 2300.0]]   # optional: else the brightest pixels
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
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis_px: Option<[f64; 2]>,
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
}

impl AcquireConfig {
    /// Image paths relative to the config's folder.
    pub(crate) fn resolve_paths(&mut self, base: &Path) {
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
        for (i, p) in self.pair.iter().enumerate() {
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
