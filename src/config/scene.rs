//! Scene configs: the TOML schema, its validation, and conversion to a [`Scene`].
//!
//! Unknown keys and unphysical values are errors naming the key, the value and what is allowed,
//! e.g. `medium.albedo = 1.3: must be within [0, 1]`. Nothing here panics on user input.

use crate::math::rotate;
use crate::medium::Geometry;
use crate::speckle::first_vertex::Sampling;
use crate::speckle::{Light, Scene, View};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::error::ConfigError;

pub(crate) fn err<T>(msg: impl Into<String>) -> Result<T, ConfigError> {
    Err(ConfigError(msg.into()))
}

/// The config file as written (see `configs/` for examples).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Wavelength, in the scene's length unit.
    pub wavelength: f64,
    pub medium: MediumConfig,
    #[serde(default)]
    pub light: Vec<LightConfig>,
    #[serde(default)]
    pub view: Vec<ViewConfig>,
    #[serde(default)]
    pub render: RenderConfig,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub memory_effect: Option<MemoryEffectConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speckle: Option<SpeckleConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correlation_map: Option<CorrelationMapConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_shift: Option<TiltShiftConfig>,
}

/// Tilt-shift scan (paper 000, Eq. 49): light 0 focused on the input plane and view 0 on the
/// output plane; each cell shifts and tilts a pair of beams and sums the fields' products over
/// `taus` positions `tau_width` wide. The cells are one of: the grid `shifts` (output `Δb`) ×
/// `angles_deg` (`θ` between the beams); a list `cells = [[Δb, θ_deg], ...]`; or `refocus = [Δ,
/// ...]`, the adaptive-optics refocusing of Sec. 9.1: for each focus displacement `Δ` (the input
/// shift) a shift-only cell and a shift + tilt cell with Eq. 50's best tilt.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TiltShiftConfig {
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub shifts: Vec<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub angles_deg: Vec<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cells: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refocus: Vec<f64>,
    pub tau_width: f64,
    pub taus: u64,
}

/// `C(Δ, τ)` map (paper 000, Eq. 48): light 0 and view 0 (both focused) shifted by each `Δ`
/// (`[x, y]` across the light's axis) and the view by a `pixels` grid of `τ`, `tau_width` wide.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CorrelationMapConfig {
    pub deltas: Vec<[f64; 2]>,
    pub tau_width: f64,
    pub pixels: [u64; 2],
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct MediumConfig {
    /// Full side lengths of a box centred at the origin.
    #[serde(rename = "box", default, skip_serializing_if = "Option::is_none")]
    pub box_size: Option<[f64; 3]>,
    /// Thickness of a slab `|z| ≤ slab/2`, unbounded in x and y (results per unit area).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slab: Option<f64>,
    /// Lateral side of the patch over which a slab's first vertices are drawn (default: 4 × thickness).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slab_window: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mfp: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_a: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phase: Option<PhaseConfig>,
    /// Volume fraction of Mie spheres (`phase.kind = "mie"`): `σ_s`, `σ_a` from their number
    /// density and cross-sections, instead of `mfp` or `sigma_s`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume_fraction: Option<f64>,
}

impl MediumConfig {
    /// Make phase-table file paths relative to `base` (the config file's folder).
    pub(crate) fn resolve_paths(&mut self, base: &Path) {
        fn fix(p: &mut PhaseConfig, base: &Path) {
            match p {
                PhaseConfig::Tabulated { file: Some(f), .. } if f.is_relative() => {
                    *f = base.join(&*f)
                }
                PhaseConfig::Mixture { components } => {
                    components.iter_mut().for_each(|c| fix(&mut c.phase, base))
                }
                _ => {}
            }
        }
        if let Some(p) = &mut self.phase {
            fix(p, base);
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum PhaseConfig {
    /// Scatters equally in all directions (a table, so unknown keys such as `g` are refused).
    Isotropic {},
    Hg {
        g: f64,
    },
    /// `ρ(cos θ)` values (`values`) or a complex amplitude (`amplitude_re`, `amplitude_im`) on the
    /// grid `cos` (default: uniform over [-1, 1]), inline or from a CSV `file` with columns
    /// `cos,value` or `cos,re,im`. Normalised here.
    Tabulated {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        cos: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        values: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        amplitude_re: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        amplitude_im: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        file: Option<PathBuf>,
    },
    /// Amplitude as vMF lobes `s(μ) ∝ Σ w_m exp(κ_m (μ − 1))` (paper 000, Eq. 28), normalised here.
    VmfMixture {
        weights: Vec<f64>,
        kappas: Vec<f64>,
    },
    /// Homogeneous spheres by Lorenz–Mie theory: `diameter` (the mean of a log-normal distribution
    /// whose standard deviation is `diameter_spread`, default 0), index `n_particle + i k_particle`
    /// in a host of index `n_medium`. The scene's `wavelength` is the wavelength in the host
    /// (vacuum wavelength / `n_medium`). `polarisation`: `"unpolarised"` (default),
    /// `"perpendicular"` or `"parallel"` (which of `S1`, `S2` the scalar amplitude follows).
    Mie {
        diameter: f64,
        #[serde(default)]
        diameter_spread: f64,
        n_particle: f64,
        #[serde(default)]
        k_particle: f64,
        n_medium: f64,
        #[serde(default)]
        polarisation: PolarisationConfig,
    },
    /// Several particle types; `weight` is each type's share of `σ_s` (paper 001, App. 9.1), or
    /// every component is Mie spheres with its own `volume_fraction`.
    Mixture {
        components: Vec<ComponentConfig>,
    },
}

/// A number that may be infinite (`aperture_sigma = inf`, an unapodised aperture): written to JSON
/// as the text `"inf"`, which JSON numbers cannot hold, and read back from a number or that text.
mod unbounded {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_str(&v.to_string())
        }
    }

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum NumberOrText {
        Number(f64),
        Text(String),
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        match NumberOrText::deserialize(d)? {
            NumberOrText::Number(x) => Ok(x),
            NumberOrText::Text(t) => match t.as_str() {
                "inf" | "+inf" | "Infinity" => Ok(f64::INFINITY),
                _ => Err(serde::de::Error::custom(format!(
                    "invalid value {t:?}: expected a number or \"inf\""
                ))),
            },
        }
    }
}

/// `phase.polarisation` of Mie spheres.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum PolarisationConfig {
    #[default]
    Unpolarised,
    Perpendicular,
    Parallel,
}

impl PolarisationConfig {
    pub fn model(self) -> crate::medium::mie::Polarisation {
        use crate::medium::mie::Polarisation;
        match self {
            PolarisationConfig::Unpolarised => Polarisation::Unpolarised,
            PolarisationConfig::Perpendicular => Polarisation::Perpendicular,
            PolarisationConfig::Parallel => Polarisation::Parallel,
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ComponentConfig {
    /// The component's share of `σ_s`; or, for Mie spheres, give `volume_fraction` instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weight: Option<f64>,
    /// Volume fraction of this component's Mie spheres: its `σ_s`, `σ_a` (and so its share) follow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume_fraction: Option<f64>,
    pub phase: PhaseConfig,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightConfig {
    PlaneWave {
        direction: [f64; 3],
    },
    Point {
        position: [f64; 3],
    },
    /// vMF-apodised beam focused at `focus`, mean propagation direction `axis`, mask
    /// `exp((w·axis − 1) / aperture_sigma²)`.
    Focused {
        focus: [f64; 3],
        axis: [f64; 3],
        #[serde(with = "unbounded")]
        aperture_sigma: f64,
    },
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ViewConfig {
    FarField {
        direction: [f64; 3],
    },
    Point {
        position: [f64; 3],
    },
    /// vMF-apodised sensor focused at `focus` collecting light propagating along `axis`.
    Focused {
        focus: [f64; 3],
        axis: [f64; 3],
        #[serde(with = "unbounded")]
        aperture_sigma: f64,
    },
    /// A `pixels[0] × pixels[1]` image of sensor foci `spacing` apart on the plane through `center`
    /// across `axis` (row-major, x along the frame's first axis), each a focused view: a
    /// near-field speckle image (paper 000, Sec. 7).
    FocusedGrid {
        center: [f64; 3],
        axis: [f64; 3],
        #[serde(with = "unbounded")]
        aperture_sigma: f64,
        spacing: f64,
        pixels: [u64; 2],
    },
    /// `count` far-field directions: `start` rotated about `axis` by `i · span_deg / count` degrees.
    FarFieldRing {
        start: [f64; 3],
        axis: [f64; 3],
        count: u64,
        #[serde(default = "full_turn")]
        span_deg: f64,
    },
    /// A `pixels[0] × pixels[1]` image of far-field directions about `center`, spanning
    /// `width_deg` degrees across (row-major, x along the frame's first axis).
    FarFieldGrid {
        center: [f64; 3],
        width_deg: f64,
        pixels: [u64; 2],
    },
}

fn full_turn() -> f64 {
    360.0
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderConfig {
    #[serde(default = "default_samples")]
    pub samples: u64,
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Paths per chunk (the unit of parallel work and of batch-means errors).
    #[serde(default = "default_chunk")]
    pub chunk: u64,
    /// Include reversed paths (coherent backscattering); `false` is the forward-only (CTE) variant.
    #[serde(default = "yes")]
    pub reversed: bool,
    /// First vertices near focused lights and views: `"beam"` (their Gaussian beams) or
    /// `"uniform"`.
    #[serde(default)]
    pub first_vertex: FirstVertexConfig,
    /// First directions: `"aperture"` (from `|Υ|²`, needs `first_vertex = "beam"`) or `"uniform"`.
    #[serde(default)]
    pub first_direction: FirstDirectionConfig,
    /// Focused apertures: `"vmf"` (closed forms, the default), `"quadrature"` (far-field
    /// connections summed over the aperture, each direction attenuated over its own length: the
    /// reference of paper 000, Eq. 11), `"quadrature_linearised"` (the same with the closed forms'
    /// linearised attenuation), `"quadrature_axis"` (with paper 000's Eq. 25) or `"monte_carlo"`
    /// (`aperture_directions` directions drawn from the mask per aperture and vertex, each
    /// attenuated over its own length: paper 000's "F.F. M.C.").
    #[serde(default)]
    pub aperture: ApertureConfig,
    /// Directions per aperture and vertex with `aperture = "monte_carlo"` (default 16).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aperture_directions: Option<usize>,
    /// `"monte_carlo"` (default) or `"single_scattering"`: `covariance` in closed form from paths
    /// that scatter once (paper 001 Eq. 41; plane-wave lights and far-field views).
    #[serde(default, skip_serializing_if = "EstimatorConfig::is_default")]
    pub estimator: EstimatorConfig,
}

/// `[render] estimator`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorConfig {
    #[default]
    MonteCarlo,
    SingleScattering,
}

impl EstimatorConfig {
    fn is_default(&self) -> bool {
        *self == EstimatorConfig::MonteCarlo
    }
}

/// `[render] aperture`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ApertureConfig {
    #[default]
    Vmf,
    Quadrature,
    QuadratureLinearised,
    QuadratureAxis,
    MonteCarlo,
}

/// Directions per aperture and vertex when `aperture = "monte_carlo"` leaves them unsaid.
const DEFAULT_APERTURE_DIRECTIONS: usize = 16;

/// `[render] first_vertex`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FirstVertexConfig {
    #[default]
    Beam,
    Uniform,
}

/// `[render] first_direction`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FirstDirectionConfig {
    #[default]
    Aperture,
    Uniform,
}

impl RenderConfig {
    /// The aperture model `aperture` and `aperture_directions` ask for.
    pub fn aperture_model(
        &self,
    ) -> Result<crate::speckle::aperture_quadrature::ApertureModel, ConfigError> {
        use crate::speckle::aperture_quadrature::{
            ApertureModel, Attenuation, MAX_RANDOM_DIRECTIONS,
        };
        if let (Some(n), false) = (
            self.aperture_directions,
            self.aperture == ApertureConfig::MonteCarlo,
        ) {
            return err(format!(
                "render.aperture_directions = {n}: only used with render.aperture = \"monte_carlo\"; remove it or set that aperture"
            ));
        }
        Ok(match self.aperture {
            ApertureConfig::Vmf => ApertureModel::Vmf,
            ApertureConfig::Quadrature => ApertureModel::Quadrature(Attenuation::Exact),
            ApertureConfig::QuadratureLinearised => {
                ApertureModel::Quadrature(Attenuation::Linearised)
            }
            ApertureConfig::QuadratureAxis => ApertureModel::Quadrature(Attenuation::Axis),
            ApertureConfig::MonteCarlo => {
                let n = self
                    .aperture_directions
                    .unwrap_or(DEFAULT_APERTURE_DIRECTIONS);
                if !(1..=MAX_RANDOM_DIRECTIONS).contains(&n) {
                    return err(format!(
                        "render.aperture_directions = {n}: must be 1 to {MAX_RANDOM_DIRECTIONS}"
                    ));
                }
                ApertureModel::MonteCarlo(n)
            }
        })
    }

    /// The importance sampling these settings ask for (paper 000, Sec. 6).
    pub fn sampling(&self) -> Result<Sampling, ConfigError> {
        Ok(match (self.first_vertex, self.first_direction) {
            (FirstVertexConfig::Beam, FirstDirectionConfig::Aperture) => Sampling::BeamAndAperture,
            (FirstVertexConfig::Beam, FirstDirectionConfig::Uniform) => Sampling::Beam,
            (FirstVertexConfig::Uniform, FirstDirectionConfig::Uniform) => Sampling::Uniform,
            (FirstVertexConfig::Uniform, FirstDirectionConfig::Aperture) => {
                return err(
                    "render.first_direction = \"aperture\" needs render.first_vertex = \"beam\": the direction is drawn from the beam the vertex came from; set first_direction = \"uniform\" or first_vertex = \"beam\"",
                );
            }
        })
    }
}

fn default_samples() -> u64 {
    100_000
}
fn default_seed() -> u64 {
    1
}
fn default_chunk() -> u64 {
    1000
}
fn yes() -> bool {
    true
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            samples: default_samples(),
            seed: default_seed(),
            chunk: default_chunk(),
            reversed: true,
            first_vertex: FirstVertexConfig::default(),
            first_direction: FirstDirectionConfig::default(),
            aperture: ApertureConfig::default(),
            aperture_directions: None,
            estimator: EstimatorConfig::default(),
        }
    }
}

/// Memory-effect scan: light 0 and view 0 tilted together about `axis` by each angle.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MemoryEffectConfig {
    pub angles_deg: Vec<f64>,
    #[serde(default = "y_axis")]
    pub axis: [f64; 3],
}

fn y_axis() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

/// Speckle images: `realisations` independent images, each from `paths` subpaths (Algorithm 2).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpeckleConfig {
    #[serde(default = "one")]
    pub realisations: u64,
    #[serde(default = "default_paths")]
    pub paths: u64,
}

fn one() -> u64 {
    1
}
fn default_paths() -> u64 {
    100_000
}

/// Keys that hold whole numbers; everything else numeric is read as a float.
const INTEGER_KEYS: [&str; 22] = [
    "samples",
    "reflections",
    "aperture_directions",
    "bins",
    "seed",
    "chunk",
    "count",
    "pixels",
    "columns",
    "rows",
    "realisations",
    "paths",
    "taus",
    "max_steps",
    "levels",
    "steps",
    "iterations",
    "m",
    "dims",
    "profile",
    "photons",
    "verify_photons",
];

/// Let `1` stand for `1.0` in float keys and `1e6` for `1000000` in integer keys.
pub(crate) fn normalise_numbers(v: &mut toml::Value, key: &str) {
    match v {
        toml::Value::Integer(i) if !INTEGER_KEYS.contains(&key) => {
            *v = toml::Value::Float(*i as f64)
        }
        toml::Value::Float(f)
            if INTEGER_KEYS.contains(&key) && f.fract() == 0.0 && *f >= 0.0 && *f < 9.0e15 =>
        {
            *v = toml::Value::Integer(*f as i64)
        }
        toml::Value::Array(a) => a.iter_mut().for_each(|x| normalise_numbers(x, key)),
        toml::Value::Table(t) => t.iter_mut().for_each(|(k, x)| normalise_numbers(x, k)),
        _ => {}
    }
}

impl Config {
    /// Parse and validate TOML text; `base` resolves relative file paths (tabulated phase functions).
    pub fn from_toml(text: &str, base: Option<&Path>) -> Result<Config, ConfigError> {
        let mut value: toml::Value =
            toml::from_str(text).map_err(|e| ConfigError(format!("invalid TOML: {e}")))?;
        normalise_numbers(&mut value, "");
        super::check_magnitudes(&value, &mut Vec::new())?;
        let mut cfg: Config = serde_path_to_error::deserialize(value).map_err(|e| {
            let path = e.path().to_string();
            let inner = e.into_inner().to_string();
            ConfigError(if path == "." {
                inner
            } else {
                format!("{path}: {inner}")
            })
        })?;
        if let Some(base) = base {
            cfg.resolve_paths(base);
        }
        cfg.validate()?;
        Ok(cfg)
    }

    pub(crate) fn resolve_paths(&mut self, base: &Path) {
        self.medium.resolve_paths(base);
    }

    /// Check every value and build the scene (once: callers keep it).
    pub fn build(&self) -> Result<Scene, ConfigError> {
        let scene = self.scene()?;
        self.check_settings()?;
        Ok(scene)
    }

    /// Check every value (builds the scene to find all errors of substance).
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.build().map(|_| ())
    }

    /// Check the run settings (`[render]`, `[memory_effect]`, `[speckle]`), not the scene: what
    /// command-line overrides can change.
    pub fn check_settings(&self) -> Result<(), ConfigError> {
        let r = &self.render;
        if r.samples == 0 {
            return err("render.samples = 0: must be at least 1");
        }
        if r.chunk == 0 {
            return err("render.chunk = 0: must be at least 1");
        }
        if let Some(me) = &self.memory_effect {
            if me.angles_deg.is_empty() {
                return err("memory_effect.angles_deg = []: give at least one angle");
            }
            for (i, a) in me.angles_deg.iter().enumerate() {
                if !a.is_finite() || a.abs() > 180.0 {
                    return err(format!(
                        "memory_effect.angles_deg[{i}] = {a}: must be a finite angle within [-180, 180]"
                    ));
                }
            }
            unit("memory_effect.axis", me.axis)?;
        }
        if let Some(m) = &self.correlation_map {
            if m.deltas.is_empty() || m.deltas.len() > 64 {
                return err(format!(
                    "correlation_map.deltas has {} entries: give 1 to 64 shifts [x, y]",
                    m.deltas.len()
                ));
            }
            for (i, d) in m.deltas.iter().enumerate() {
                if !d[0].is_finite() || !d[1].is_finite() {
                    return err(format!(
                        "correlation_map.deltas[{i}] = {d:?}: must be finite"
                    ));
                }
            }
            if !m.tau_width.is_finite() || m.tau_width < 0.0 {
                return err(format!(
                    "correlation_map.tau_width = {}: must be a finite width ≥ 0",
                    m.tau_width
                ));
            }
            let [nx, ny] = m.pixels;
            if nx == 0 || ny == 0 || nx * ny * (m.deltas.len() as u64 + 1) > 1_000_000 {
                return err(format!(
                    "correlation_map.pixels = {:?}: each must be at least 1 and pixels × (deltas + 1) at most 1000000",
                    m.pixels
                ));
            }
        }
        if let Some(t) = &self.tilt_shift {
            let grid = !t.shifts.is_empty() || !t.angles_deg.is_empty();
            let forms = [grid, !t.cells.is_empty(), !t.refocus.is_empty()];
            if forms.iter().filter(|f| **f).count() != 1 {
                return err(
                    "tilt_shift: give exactly one of shifts + angles_deg (a grid), cells = [[shift, angle_deg], ...] or refocus = [displacement, ...]",
                );
            }
            let (cell_shifts, cell_angles): (Vec<f64>, Vec<f64>) =
                t.cells.iter().map(|c| (c[0], c[1])).unzip();
            for (key, list, limit, used) in [
                ("tilt_shift.shifts", &t.shifts, f64::INFINITY, grid),
                ("tilt_shift.angles_deg", &t.angles_deg, 45.0, grid),
                (
                    "tilt_shift.cells (shift)",
                    &cell_shifts,
                    f64::INFINITY,
                    !t.cells.is_empty(),
                ),
                (
                    "tilt_shift.cells (angle_deg)",
                    &cell_angles,
                    45.0,
                    !t.cells.is_empty(),
                ),
                (
                    "tilt_shift.refocus",
                    &t.refocus,
                    f64::INFINITY,
                    !t.refocus.is_empty(),
                ),
            ] {
                if !used {
                    continue;
                }
                if list.is_empty() || list.len() > 256 {
                    return err(format!(
                        "{key} has {} entries: give 1 to 256 values",
                        list.len()
                    ));
                }
                for (i, v) in list.iter().enumerate() {
                    if !v.is_finite() || v.abs() > limit {
                        return err(format!(
                            "{key}[{i}] = {v}: must be finite{}",
                            if limit.is_finite() {
                                format!(", within [-{limit}, {limit}]")
                            } else {
                                String::new()
                            }
                        ));
                    }
                }
            }
            if !t.tau_width.is_finite() || t.tau_width < 0.0 {
                return err(format!(
                    "tilt_shift.tau_width = {}: must be a finite width ≥ 0",
                    t.tau_width
                ));
            }
            let cells =
                (t.shifts.len() * t.angles_deg.len() + t.cells.len() + 2 * t.refocus.len()) as u64;
            if t.taus == 0 || t.taus * cells > 1_000_000 {
                return err(format!(
                    "tilt_shift.taus = {}: must be at least 1 and taus × cells at most 1000000",
                    t.taus
                ));
            }
        }
        if let Some(s) = &self.speckle {
            if s.realisations == 0 {
                return err("speckle.realisations = 0: must be at least 1");
            }
            if s.paths == 0 {
                return err("speckle.paths = 0: must be at least 1");
            }
        }
        Ok(())
    }

    /// Build the physical scene (lights and views expanded).
    pub fn scene(&self) -> Result<Scene, ConfigError> {
        positive("wavelength", self.wavelength)?;
        let medium = self.medium.build(self.wavelength)?;
        if self.light.is_empty() {
            return err("light: the list is empty; give at least one [[light]]");
        }
        if self.view.is_empty() {
            return err("view: the list is empty; give at least one [[view]]");
        }
        let mut lights = Vec::new();
        for (i, l) in self.light.iter().enumerate() {
            lights.push(match l {
                LightConfig::PlaneWave { direction } => Light::PlaneWave {
                    direction: unit(&format!("light[{i}].direction"), *direction)?,
                },
                LightConfig::Point { position } => Light::Point {
                    position: point(&format!("light[{i}].position"), *position, &medium.geometry)?,
                },
                LightConfig::Focused {
                    focus,
                    axis,
                    aperture_sigma,
                } => {
                    let (focus, axis, gamma) =
                        focused(&format!("light[{i}]"), *focus, *axis, *aperture_sigma)?;
                    Light::Focused { focus, axis, gamma }
                }
            });
        }
        let mut views = Vec::new();
        for (i, v) in self.view.iter().enumerate() {
            expand_view(i, v, &medium.geometry, &mut views)?;
        }
        let mut scene = Scene::new(self.wavelength, medium, lights, views);
        scene.sampling = self.render.sampling()?;
        scene.aperture = self.render.aperture_model()?;
        Ok(scene)
    }
}

pub(crate) fn positive(key: &str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        err(format!("{key} = {v}: must be a positive finite number"))
    }
}

/// The narrowest focused aperture (`γ = 1/σ² ≤ 1e8`; narrower ones overflow the vMF algebra and
/// are far-field beams in all but name).
const MIN_APERTURE_SIGMA: f64 = 1e-4;

/// A point or vector whose components are all finite.
pub(crate) fn finite(key: &str, v: [f64; 3]) -> Result<DVec3, ConfigError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(DVec3::from_array(v))
    } else {
        err(format!("{key} = {v:?}: must be finite"))
    }
}

pub(crate) fn unit(key: &str, v: [f64; 3]) -> Result<DVec3, ConfigError> {
    let d = DVec3::from_array(v);
    // scaled first, so that huge components do not overflow the length
    let largest = d.abs().max_element();
    if d.is_finite() && largest > 0.0 {
        Ok((d / largest).normalize())
    } else {
        err(format!("{key} = {v:?}: must be a non-zero finite vector"))
    }
}

fn point(key: &str, v: [f64; 3], g: &Geometry) -> Result<DVec3, ConfigError> {
    let p = DVec3::from_array(v);
    if !p.is_finite() {
        return err(format!("{key} = {v:?}: must be finite"));
    }
    if let Geometry::Slab { .. } = g {
        return err(format!(
            "{key}: point lights and views need a bounded medium; use medium.box instead of medium.slab"
        ));
    }
    if g.contains(p) {
        return err(format!(
            "{key} = {v:?}: must lie outside the medium (points inside are not supported)"
        ));
    }
    Ok(p)
}

/// Focus, unit axis and `γ = 1/σ_a²` of a focused endpoint (`aperture_sigma = inf` gives `γ = 0`).
fn focused(
    key: &str,
    focus: [f64; 3],
    axis: [f64; 3],
    sigma: f64,
) -> Result<(DVec3, DVec3, f64), ConfigError> {
    let f = DVec3::from_array(focus);
    if !f.is_finite() {
        return err(format!("{key}.focus = {focus:?}: must be finite"));
    }
    let a = unit(&format!("{key}.axis"), axis)?;
    if sigma.is_nan() || sigma < MIN_APERTURE_SIGMA {
        return err(format!(
            "{key}.aperture_sigma = {sigma}: must be at least {MIN_APERTURE_SIGMA:e} (a numerical aperture of about that; inf for an unapodised aperture)"
        ));
    }
    Ok((f, a, 1.0 / (sigma * sigma)))
}

fn expand_view(
    i: usize,
    v: &ViewConfig,
    g: &Geometry,
    out: &mut Vec<View>,
) -> Result<(), ConfigError> {
    match v {
        ViewConfig::FarField { direction } => out.push(View::FarField {
            direction: unit(&format!("view[{i}].direction"), *direction)?,
        }),
        ViewConfig::Point { position } => out.push(View::Point {
            position: point(&format!("view[{i}].position"), *position, g)?,
        }),
        ViewConfig::Focused {
            focus,
            axis,
            aperture_sigma,
        } => {
            let (focus, axis, gamma) =
                focused(&format!("view[{i}]"), *focus, *axis, *aperture_sigma)?;
            out.push(View::Focused { focus, axis, gamma })
        }
        ViewConfig::FocusedGrid {
            center,
            axis,
            aperture_sigma,
            spacing,
            pixels,
        } => {
            let (c, a, gamma) = focused(&format!("view[{i}]"), *center, *axis, *aperture_sigma)?;
            if !spacing.is_finite() || *spacing <= 0.0 {
                return err(format!(
                    "view[{i}].spacing = {spacing}: must be a positive distance between foci"
                ));
            }
            let [nx, ny] = *pixels;
            if nx == 0 || ny == 0 || nx * ny > 1_000_000 {
                return err(format!(
                    "view[{i}].pixels = {pixels:?}: each must be at least 1 and nx·ny at most 1000000"
                ));
            }
            let (ex, ey) = crate::math::orthonormal_basis(a);
            for iy in 0..ny {
                for ix in 0..nx {
                    let dx = (ix as f64 - 0.5 * (nx as f64 - 1.0)) * spacing;
                    let dy = (iy as f64 - 0.5 * (ny as f64 - 1.0)) * spacing;
                    out.push(View::Focused {
                        focus: c + ex * dx + ey * dy,
                        axis: a,
                        gamma,
                    });
                }
            }
        }
        ViewConfig::FarFieldRing {
            start,
            axis,
            count,
            span_deg,
        } => {
            let s = unit(&format!("view[{i}].start"), *start)?;
            let a = unit(&format!("view[{i}].axis"), *axis)?;
            if *count == 0 || *count > 100_000 {
                return err(format!(
                    "view[{i}].count = {count}: must be within [1, 100000]"
                ));
            }
            if !span_deg.is_finite() || *span_deg <= 0.0 || *span_deg > 360.0 {
                return err(format!(
                    "view[{i}].span_deg = {span_deg}: must be within (0, 360]"
                ));
            }
            for n in 0..*count {
                let ang = (span_deg * n as f64 / *count as f64).to_radians();
                out.push(View::FarField {
                    direction: rotate(s, a, ang).normalize(),
                });
            }
        }
        ViewConfig::FarFieldGrid {
            center,
            width_deg,
            pixels,
        } => {
            let c = unit(&format!("view[{i}].center"), *center)?;
            if !width_deg.is_finite() || *width_deg <= 0.0 || *width_deg >= 180.0 {
                return err(format!(
                    "view[{i}].width_deg = {width_deg}: must be within (0, 180)"
                ));
            }
            let [nx, ny] = *pixels;
            if nx == 0 || ny == 0 || nx * ny > 1_000_000 {
                return err(format!(
                    "view[{i}].pixels = {pixels:?}: each must be at least 1 and nx·ny at most 1000000"
                ));
            }
            let (ex, ey) = crate::math::orthonormal_basis(c);
            let step = width_deg.to_radians() / nx as f64;
            for iy in 0..ny {
                for ix in 0..nx {
                    let ax = (ix as f64 - 0.5 * (nx as f64 - 1.0)) * step;
                    let ay = (iy as f64 - 0.5 * (ny as f64 - 1.0)) * step;
                    out.push(View::FarField {
                        direction: (c + ex * ax.tan() + ey * ay.tan()).normalize(),
                    });
                }
            }
        }
    }
    Ok(())
}
