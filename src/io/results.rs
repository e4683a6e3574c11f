//! Typed result files: one serde struct per file with its writer ([`ResultFile::write`]) and reader
//! ([`ResultFile::read`]), each carrying `format_version` (documented in `docs/formats.md`).
//! `compare`, fit targets and grid files read results through these types only.

use crate::config::{Config, LightConfig, ViewConfig};
use crate::math::C64;
use crate::speckle::{Light, Scene, View};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The version of every result format written by this build. Files without the field (written
/// before it existed) read as version 0, whose keys are the same.
pub const FORMAT_VERSION: u32 = 1;

/// A result file: written atomically as JSON, read back with its version checked.
pub trait ResultFile: Serialize + DeserializeOwned {
    /// The file name the commands use (`covariance.json`, …).
    const NAME: &'static str;

    fn format_version(&self) -> u32;

    /// Write to `path` (atomically), or say which file could not be written.
    fn write(&self, path: &Path) -> crate::Result<()> {
        super::write_json(path, self).map_err(|source| crate::Error::Io {
            action: "write",
            path: path.to_path_buf(),
            source,
        })
    }

    /// Read `path`, naming the file and the key in any error; refuses newer format versions.
    fn read(path: &Path) -> crate::Result<Self> {
        let bytes =
            std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let de = &mut serde_json::Deserializer::from_slice(&bytes);
        let file: Self = serde_path_to_error::deserialize(de).map_err(|e| {
            format!(
                "{}: not a {} ({}: {})",
                path.display(),
                Self::NAME,
                e.path(),
                e.inner()
            )
        })?;
        if file.format_version() > FORMAT_VERSION {
            return Err(format!(
                "{}: format_version = {}: this build reads {} up to version {FORMAT_VERSION}; update lightpath",
                path.display(),
                file.format_version(),
                Self::NAME
            ).into());
        }
        Ok(file)
    }
}

macro_rules! result_file {
    ($t:ty, $name:literal) => {
        impl ResultFile for $t {
            const NAME: &'static str = $name;
            fn format_version(&self) -> u32 {
                self.format_version
            }
        }
    };
}

/// `[l][l'][v][v']` nested arrays (JSON's natural shape for a covariance).
pub type Nested4 = Vec<Vec<Vec<Vec<f64>>>>;
/// `[l][v]` nested arrays (mean fields).
pub type Nested2 = Vec<Vec<f64>>;

/// Nest a `J×J` row-major block (`j = l·V + v`) as `[l1][l2][v1][v2]`.
pub fn nest4(nl: usize, nv: usize, f: impl Fn(usize) -> f64) -> Nested4 {
    let j = nl * nv;
    (0..nl)
        .map(|l1| {
            (0..nl)
                .map(|l2| {
                    (0..nv)
                        .map(|v1| {
                            (0..nv)
                                .map(|v2| f((l1 * nv + v1) * j + l2 * nv + v2))
                                .collect()
                        })
                        .collect()
                })
                .collect()
        })
        .collect()
}

/// Nest `J` values (`j = l·V + v`) as `[l][v]`.
pub fn nest2(nl: usize, nv: usize, f: impl Fn(usize) -> f64) -> Nested2 {
    (0..nl)
        .map(|l| (0..nv).map(|v| f(l * nv + v)).collect())
        .collect()
}

/// What every speckle result echoes: the scene's endpoints (expanded), the run and the config.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RunEcho {
    #[serde(default)]
    pub format_version: u32,
    pub wavelength: f64,
    pub lights: Vec<LightConfig>,
    pub views: Vec<ViewConfig>,
    /// Paths (Monte Carlo) or realisations (wave solver).
    pub samples: u64,
    pub seed: u64,
    /// Paths per chunk (Monte Carlo only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chunk: Option<u64>,
    /// Whether reversed paths were included (Monte Carlo only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reversed: Option<bool>,
    /// Wall time; `null` for merged shards.
    pub seconds: Option<f64>,
    pub version: String,
    pub config: Config,
}

impl RunEcho {
    pub fn new(config: &Config, scene: &Scene, samples: u64, seed: u64, seconds: f64) -> Self {
        RunEcho {
            format_version: FORMAT_VERSION,
            wavelength: config.wavelength,
            lights: scene.lights.iter().map(light_record).collect(),
            views: scene.views.iter().map(view_record).collect(),
            samples,
            seed,
            chunk: None,
            reversed: None,
            seconds: seconds.is_finite().then_some(seconds),
            version: env!("CARGO_PKG_VERSION").into(),
            config: config.clone(),
        }
    }
}

/// A light as the config key that describes it (what result files echo).
pub fn light_record(l: &Light) -> LightConfig {
    match *l {
        Light::PlaneWave { direction } => LightConfig::PlaneWave {
            direction: direction.to_array(),
        },
        Light::Point { position } => LightConfig::Point {
            position: position.to_array(),
        },
        Light::Focused { focus, axis, gamma } => LightConfig::Focused {
            focus: focus.to_array(),
            axis: axis.to_array(),
            aperture_sigma: 1.0 / gamma.sqrt(),
        },
    }
}

/// A view as the config key that describes it (what result files echo).
pub fn view_record(v: &View) -> ViewConfig {
    match *v {
        View::FarField { direction } => ViewConfig::FarField {
            direction: direction.to_array(),
        },
        View::Point { position } => ViewConfig::Point {
            position: position.to_array(),
        },
        View::Focused { focus, axis, gamma } => ViewConfig::Focused {
            focus: focus.to_array(),
            axis: axis.to_array(),
            aperture_sigma: 1.0 / gamma.sqrt(),
        },
    }
}

/// `covariance.json`: `C[l1][l2][v1][v2] = E[u ū'] − m m̄'` with standard errors, the mean fields,
/// and (Monte Carlo) the single- and multiple-scattering parts, or (wave solver) the placements.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CovarianceFile {
    #[serde(flatten)]
    pub run: RunEcho,
    pub re: Nested4,
    pub im: Nested4,
    pub stderr: Nested4,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_re: Option<Nested4>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_im: Option<Nested4>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_stderr: Option<Nested4>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multiple_re: Option<Nested4>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multiple_im: Option<Nested4>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multiple_stderr: Option<Nested4>,
    pub mean_re: Nested2,
    pub mean_im: Nested2,
    /// Standard error of the mean field (wave solver; the Monte Carlo mean is a closed form).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_stderr: Option<Nested2>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub realizations: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatterers_mean: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatterers_expected: Option<f64>,
}

impl ResultFile for CovarianceFile {
    const NAME: &'static str = "covariance.json";
    fn format_version(&self) -> u32 {
        self.run.format_version
    }
}

/// A covariance as one `J×J` row-major block (`j = l·V + v`) with its standard errors.
#[derive(Clone, Debug, PartialEq)]
pub struct CovarianceMatrix {
    pub lights: usize,
    pub views: usize,
    pub value: Vec<C64>,
    pub stderr: Vec<f64>,
}

impl CovarianceFile {
    /// A covariance `cov` (`J×J`, `j = l·V + v`) with standard errors `stderr` and mean fields
    /// `mean`; the optional parts (scattering orders, wave-solver statistics) empty.
    pub fn new(
        run: RunEcho,
        nl: usize,
        nv: usize,
        cov: &[C64],
        stderr: &[f64],
        mean: &[C64],
    ) -> Self {
        CovarianceFile {
            run,
            re: nest4(nl, nv, |i| cov[i].re),
            im: nest4(nl, nv, |i| cov[i].im),
            stderr: nest4(nl, nv, |i| stderr[i]),
            single_re: None,
            single_im: None,
            single_stderr: None,
            multiple_re: None,
            multiple_im: None,
            multiple_stderr: None,
            mean_re: nest2(nl, nv, |a| mean[a].re),
            mean_im: nest2(nl, nv, |a| mean[a].im),
            mean_stderr: None,
            realizations: None,
            solver: None,
            scatterers_mean: None,
            scatterers_expected: None,
        }
    }

    /// The total covariance as a flat matrix; errors if the nested arrays are ragged.
    pub fn matrix(&self, path: &Path) -> crate::Result<CovarianceMatrix> {
        let nl = self.re.len();
        let nv = self
            .re
            .first()
            .and_then(|r| r.first())
            .map_or(0, |r| r.len());
        if nl == 0 || nv == 0 {
            return Err(format!(
                "{}: `re` is empty: a covariance needs at least one light and one view",
                path.display()
            )
            .into());
        }
        let j = nl * nv;
        let mut value = vec![C64::default(); j * j];
        let mut stderr = vec![0.0; j * j];
        for (name, arr) in [("re", &self.re), ("im", &self.im), ("stderr", &self.stderr)] {
            let ok = arr.len() == nl
                && arr.iter().all(|a| {
                    a.len() == nl
                        && a.iter()
                            .all(|b| b.len() == nv && b.iter().all(|c| c.len() == nv))
                });
            if !ok {
                return Err(format!(
                    "{}: `{name}` is not a {nl}×{nl}×{nv}×{nv} array like `re`",
                    path.display()
                )
                .into());
            }
        }
        for l1 in 0..nl {
            for l2 in 0..nl {
                for v1 in 0..nv {
                    for v2 in 0..nv {
                        let i = (l1 * nv + v1) * j + l2 * nv + v2;
                        value[i] = C64::new(self.re[l1][l2][v1][v2], self.im[l1][l2][v1][v2]);
                        stderr[i] = self.stderr[l1][l2][v1][v2];
                    }
                }
            }
        }
        Ok(CovarianceMatrix {
            lights: nl,
            views: nv,
            value,
            stderr,
        })
    }
}

/// `memory_effect.json`: the memory-effect curve against Eq. 39.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MemoryEffectFile {
    #[serde(flatten)]
    pub run: RunEcho,
    pub angles_deg: Vec<f64>,
    pub correlation: Vec<f64>,
    pub correlation_stderr: Vec<f64>,
    pub field_correlation: Vec<f64>,
    pub diffusion_eq39: Vec<f64>,
    pub thickness: f64,
}

impl ResultFile for MemoryEffectFile {
    const NAME: &'static str = "memory_effect.json";
    fn format_version(&self) -> u32 {
        self.run.format_version
    }
}

/// `correlation_map.json`: near-field `C(Δ, τ)` maps (paper 000, Eq. 48), `[delta][y][x]`, with
/// `delta` 0 the unshifted pair (its `C` is the intensity), and `|C| / √(I(0, τ) I(Δ, τ + Δ))`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CorrelationMapFile {
    #[serde(flatten)]
    pub run: RunEcho,
    /// Shifts `Δ` (3-vectors in the scene's frame), the first 0.
    pub deltas: Vec<[f64; 3]>,
    /// `τ` of pixel `[y][x]`.
    pub taus: Vec<Vec<[f64; 3]>>,
    pub re: Vec<Vec<Vec<f64>>>,
    pub im: Vec<Vec<Vec<f64>>>,
    pub stderr: Vec<Vec<Vec<f64>>>,
    pub normalised: Vec<Vec<Vec<f64>>>,
}

impl ResultFile for CorrelationMapFile {
    const NAME: &'static str = "correlation_map.json";
    fn format_version(&self) -> u32 {
        self.run.format_version
    }
}

/// `tilt_shift.json`: the tilt-shift correlation `C(Δa, Δb, θ)` (paper 000, Eq. 49) of every
/// cell, normalised by the fields' summed intensities, beside the model of Eq. 50; for a grid the
/// normalised values as `[shift][angle]`, for a refocusing scan (Sec. 9.1) the power curves.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TiltShiftFile {
    #[serde(flatten)]
    pub run: RunEcho,
    /// Depth `L` between the input and output planes, and the transport mean free path.
    pub depth: f64,
    pub transport_mfp: f64,
    pub cells: Vec<TiltShiftCell>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<TiltShiftGrid>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refocus: Option<Refocus>,
}

/// One cell of a tilt-shift scan.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TiltShiftCell {
    /// Output shift `Δb`, relative tilt `θ` and input shift `Δa = Δb − Lθ`.
    pub shift: f64,
    pub angle_deg: f64,
    pub input_shift: f64,
    pub re: f64,
    pub im: f64,
    pub stderr: f64,
    /// `|C| / √(I₁ I₂)` with `I` the fields' intensities summed over the same `τ`.
    pub normalised: f64,
    pub normalised_stderr: f64,
    /// Eq. 50 at the cell.
    pub model: f64,
}

/// A grid scan: `normalised[shift][angle]` and the model there.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TiltShiftGrid {
    pub shifts: Vec<f64>,
    pub angles_deg: Vec<f64>,
    pub normalised: Vec<Vec<f64>>,
    pub model: Vec<Vec<f64>>,
}

/// Refocusing through the medium (paper 000, Sec. 9.1): the expected power `|C|²/(I₁ I₂)` at a
/// focus displaced by each `Δ` with the shifted wavefront alone and shifted and tilted by Eq. 50's
/// best tilt, with Eq. 50's predictions.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Refocus {
    pub displacements: Vec<f64>,
    pub power_shift: Vec<f64>,
    pub power_shift_stderr: Vec<f64>,
    pub power_tilt: Vec<f64>,
    pub power_tilt_stderr: Vec<f64>,
    /// The tilts used (degrees).
    pub tilts_deg: Vec<f64>,
    pub model_shift: Vec<f64>,
    pub model_tilt: Vec<f64>,
}

impl ResultFile for TiltShiftFile {
    const NAME: &'static str = "tilt_shift.json";
    fn format_version(&self) -> u32 {
        self.run.format_version
    }
}

/// `speckle.json`: speckle fields `u[r][l][v]` of every realisation.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SpeckleFile {
    #[serde(flatten)]
    pub run: RunEcho,
    pub re: Vec<Nested2>,
    pub im: Vec<Nested2>,
    pub realisations: u64,
    pub paths_per_image: u64,
}

impl ResultFile for SpeckleFile {
    const NAME: &'static str = "speckle.json";
    fn format_version(&self) -> u32 {
        self.run.format_version
    }
}

/// One line of a fit's log: an L-BFGS stage (`stage`) or an Adam iteration (`iteration`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FitLogLine {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iteration: Option<usize>,
    pub loss: f64,
    pub params: Vec<f64>,
    pub grad_norm: f64,
}

/// A single-scattering reading of the phase function (phase-function fits).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ReadingRecord {
    pub delta_deg: f64,
    pub angle_deg: f64,
    pub rho: f64,
    pub stderr: f64,
}

/// `fit.json` of `lightpath fit`: fitted medium parameters with Gauss–Newton standard deviations.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FitFile {
    #[serde(default)]
    pub format_version: u32,
    /// `lbfgs` or `adam`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimizer: Option<String>,
    pub params: Vec<String>,
    pub initial: Vec<f64>,
    pub fitted: Vec<f64>,
    pub stddev: Vec<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correlation: Option<Vec<Vec<f64>>>,
    pub loss: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dof: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phase_cos: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phase_angle_deg: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_values: Option<Vec<f64>>,
    pub model_initial: Vec<f64>,
    pub model_fitted: Vec<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_scattering_reading: Option<Vec<ReadingRecord>>,
    pub log: Vec<FitLogLine>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learning_rate: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth: Option<f64>,
    /// How the fit ended (absent in files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub convergence: Option<crate::inverse::Convergence>,
    pub samples: u64,
    pub seed: u64,
    pub seconds: f64,
    pub version: String,
    pub target: String,
    pub config: Config,
}
result_file!(FitFile, "fit.json");

/// One traced ray of `rays.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RayRecord {
    pub origin: [f64; 3],
    pub direction: [f64; 3],
    pub exit_position: [f64; 3],
    pub exit_direction: [f64; 3],
    pub optical_path: f64,
    pub steps: usize,
    pub entered: bool,
    pub exited: bool,
}

/// `rays.json` of `lightpath trace`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RaysFile {
    #[serde(default)]
    pub format_version: u32,
    pub rays: Vec<RayRecord>,
    /// Estimated error of the exit positions from the step (a few rays traced again at half the
    /// step; 4/3 of the largest change, the leapfrog being second order).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step_error: Option<f64>,
    pub seconds: f64,
    pub version: String,
    pub config: crate::config::TraceConfig,
}
result_file!(RaysFile, "rays.json");

/// One line of a grid design's log.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DesignLogLine {
    pub level: usize,
    pub iteration: usize,
    pub loss: f64,
    pub mean_miss2: f64,
}

pub use crate::config::trace::GridRecord;

/// The designed index along radial directions: mean, min and max over 26 directions.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RadialProfile {
    pub r: Vec<f64>,
    pub mean: Vec<f64>,
    pub min: Vec<f64>,
    pub max: Vec<f64>,
}

/// `design.json` of `lightpath design` (grid designs).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DesignFile {
    #[serde(default)]
    pub format_version: u32,
    pub rms_miss_initial: f64,
    pub rms_miss_final: f64,
    pub log: Vec<DesignLogLine>,
    /// How the fit ended (absent in files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub convergence: Option<crate::inverse::Convergence>,
    pub grid: GridRecord,
    pub radial_profile: RadialProfile,
    pub seconds: f64,
    pub version: String,
    pub config: crate::config::DesignConfig,
}
result_file!(DesignFile, "design.json");

/// One evaluation of a GRIN parameter fit.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct GrinFitLogLine {
    pub evaluation: usize,
    pub parameters: Vec<f64>,
    pub mean_miss2: f64,
}

/// `fit.json` of `lightpath design` with a `[parameters]` table.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct GrinFitFile {
    #[serde(default)]
    pub format_version: u32,
    pub parameters: Vec<String>,
    pub initial: Vec<f64>,
    pub fitted: Vec<f64>,
    pub rms_miss_initial: f64,
    pub rms_miss_final: f64,
    pub log: Vec<GrinFitLogLine>,
    /// How the fit ended (absent in files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub convergence: Option<crate::inverse::Convergence>,
    pub seconds: f64,
    pub version: String,
    pub config: crate::config::ParamFitConfig,
}
result_file!(GrinFitFile, "fit.json");

/// `render_design.json` of `lightpath design` on a render config with a `[design]` table.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RenderDesignFile {
    #[serde(default)]
    pub format_version: u32,
    /// The target maximised, and the one it is taken relative to.
    pub maximize: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_to: Option<String>,
    /// Adam (fresh photons every iteration) or L-BFGS (held photons).
    #[serde(default = "adam")]
    pub method: crate::inverse::render_design::DesignMethod,
    pub parameters: Vec<DesignedParameter>,
    /// Per Adam iteration or L-BFGS evaluation: the objective `ln F (− ln F_reference)` of its
    /// photons, and the parameters.
    pub log: Vec<RenderDesignLogLine>,
    /// Renders at a fresh seed of the start and of the design.
    pub verification: DesignVerification,
    pub convergence: crate::inverse::Convergence,
    pub seconds: f64,
    pub version: String,
    pub config: crate::config::RenderConfig,
}
result_file!(RenderDesignFile, "render_design.json");

fn adam() -> crate::inverse::render_design::DesignMethod {
    crate::inverse::render_design::DesignMethod::Adam
}

/// A designed parameter: its range, where it started and where the design put it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DesignedParameter {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub start: f64,
    pub designed: f64,
}

/// One iteration (Adam) or evaluation (L-BFGS) of a render design.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RenderDesignLogLine {
    pub iteration: usize,
    pub objective: f64,
    pub grad_norm: f64,
    pub parameters: Vec<f64>,
}

/// The independent check of a design: the target's fluence or the spot's power (and the
/// reference's, and their ratio, with one) at the start and at the design, from `photons` photons each at `seed`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DesignVerification {
    pub photons: u64,
    pub seed: u64,
    pub start: Measured,
    pub designed: Measured,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_start: Option<Measured>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_designed: Option<Measured>,
    /// The objective's gain, `F_designed / F_start` (of the ratios, with a reference), with its
    /// standard error.
    pub gain: Measured,
}

/// `mie.json` of `lightpath mie`: one sphere (or a log-normal suspension of them) by Lorenz–Mie
/// theory. Lengths in the unit of the inputs; cross-sections per particle (means over the sizes).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MieFile {
    #[serde(default)]
    pub format_version: u32,
    pub diameter: f64,
    pub diameter_spread: f64,
    /// `[n, κ]` of the particle.
    pub n_particle: [f64; 2],
    pub n_medium: f64,
    pub vacuum_wavelength: f64,
    /// `π d n_medium / λ₀` of the mean diameter.
    pub size_parameter: f64,
    /// `[re, im]` of `(n + iκ) / n_medium`.
    pub relative_index: [f64; 2],
    /// Series terms of the largest sphere.
    pub terms: usize,
    pub q_ext: f64,
    pub q_sca: f64,
    pub q_abs: f64,
    pub q_back: f64,
    pub g: f64,
    pub c_ext: f64,
    pub c_sca: f64,
    pub c_abs: f64,
    pub c_back: f64,
    pub mean_volume: f64,
    /// With `--volume-fraction`: the bulk coefficients of the suspension.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bulk: Option<MieBulk>,
    pub theta_deg: Vec<f64>,
    /// Unpolarised `ρ(θ)`, `∫ρ dω = 1`.
    pub phase: Vec<f64>,
    pub phase_perpendicular: Vec<f64>,
    pub phase_parallel: Vec<f64>,
    /// Bohren–Huffman amplitudes (time dependence `exp(−iωt)`), averaged over the sizes.
    pub s1_re: Vec<f64>,
    pub s1_im: Vec<f64>,
    pub s2_re: Vec<f64>,
    pub s2_im: Vec<f64>,
    pub seconds: f64,
    pub version: String,
}
result_file!(MieFile, "mie.json");

/// Bulk coefficients of a volume fraction of spheres (independent scattering).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MieBulk {
    pub volume_fraction: f64,
    pub number_density: f64,
    pub sigma_s: f64,
    pub sigma_a: f64,
    pub mfp: f64,
    pub albedo: f64,
}

/// A fitted Henyey–Greenstein in `phase_acquisition.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HgRecord {
    pub g: f64,
    pub g_stderr: f64,
    pub chi2_dof: f64,
}

/// Fitted vMF amplitude lobes (usable as `phase = { kind = "vmf_mixture", ... }`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct VmfRecord {
    pub weights: Vec<f64>,
    pub kappas: Vec<f64>,
    pub chi2_dof: f64,
}

/// One reading of `phase_acquisition.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AcquiredReading {
    #[serde(flatten)]
    pub reading: crate::inverse::phase_from_speckle::Reading,
    /// `√C` on the fitted HG's scale (`∫ρ dω = 1` for that HG); `null` without a fit or for `C ≤ 0`.
    pub rho: Option<f64>,
    pub rho_stderr: Option<f64>,
    /// The naive reading `⟨I¹⟩` on the intensity HG's scale.
    pub rho_intensity: Option<f64>,
}

/// The readings of the pairs sharing one illumination displacement.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AcquiredCurve {
    /// The first illumination's ballistic peak, pixels.
    #[serde(default)]
    pub first_px: [f64; 2],
    pub delta_px: [f64; 2],
    pub delta_deg: f64,
    pub grain_px: f64,
    pub pairs: usize,
    /// χ² of the correlations against 0 and the readings: a flat (noise) curve has χ² ≈ dof.
    pub chi2_flat: f64,
    pub dof: usize,
    pub significant: bool,
    pub readings: Vec<AcquiredReading>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hg: Option<HgRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vmf: Option<VmfRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hg_intensity: Option<HgRecord>,
}

/// Whether the two largest displacements read the same correlation (single scattering isolated).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Consistency {
    pub curves: [usize; 2],
    pub chi2: f64,
    pub dof: usize,
    pub consistent: bool,
}

/// `phase_acquisition.json` of `lightpath acquire-phase`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct PhaseAcquisitionFile {
    #[serde(default)]
    pub format_version: u32,
    /// The optical axis on the sensor the directions were computed with, pixels.
    #[serde(default)]
    pub axis_px: [f64; 2],
    pub curves: Vec<AcquiredCurve>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub consistency: Option<Consistency>,
    /// What looked wrong but did not stop the reading (e.g. a peak away from where the source
    /// translation puts it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    pub seconds: f64,
    pub version: String,
    pub config: crate::config::AcquireConfig,
}
result_file!(PhaseAcquisitionFile, "phase_acquisition.json");

/// A mean with its standard error.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct Measured {
    pub mean: f64,
    pub stderr: f64,
}

/// One sensor of a render: the power it received and, per time bin, its values.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SensorRecord {
    pub name: String,
    /// `flux`, `spot` or `screen`.
    pub kind: String,
    /// Fraction of the emitted power the sensor received (all pixels and time bins); a spot's
    /// weighted by its aperture.
    pub power: Measured,
    /// Spots: the `1/e²` radius of the Gaussian aperture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Screens whose pixels share each crossing bilinearly: `"tent"` (absent: `"box"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<String>,
    /// Time bins (1 without `[transient]`).
    pub bins: usize,
    /// Flux sensors: the fraction of the emitted power per time bin, and its standard error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_bin: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_bin_stderr: Option<Vec<f64>>,
    /// Screens: pixels along the sensor's sides and the area of one pixel; the images (EXR,
    /// channels `Y` = irradiance per unit emitted power and `stderr`) are in `files`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixels: Option<[usize; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_area: Option<f64>,
    /// Screens: the median relative standard error of the image's lit pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_noise: Option<f64>,
    /// Screens: the same over the bright pixels (at least a hundredth of the 99th-percentile
    /// lit pixel), a set that settles as samples grow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bright_pixel_noise: Option<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub files: Vec<String>,
    /// `∂ power / ∂θ` for each parameter of `render.derivatives`, by name.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub derivatives: std::collections::BTreeMap<String, Measured>,
}

/// A diffuse or black surface of a render: the power reaching it and what it absorbed.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SurfaceRecord {
    pub name: String,
    pub albedo: f64,
    /// Fraction of the emitted power reaching the surface (each bounce counted).
    pub incident: Measured,
    /// `(1 − albedo)` of it.
    pub absorbed: Measured,
}

/// A fluence-rate probe of a render: power per unit area per unit emitted power.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ProbeRecord {
    pub name: String,
    pub position: [f64; 3],
    pub fluence: Measured,
    pub per_bin: Vec<f64>,
    pub per_bin_stderr: Vec<f64>,
    /// `∂ fluence/∂θ` by parameter name, with standard errors (with `render.derivatives`).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub derivatives: std::collections::BTreeMap<String, Measured>,
}

/// A target of a render: the mean fluence rate over a region inside the volume (per unit
/// emitted power), with its derivatives.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TargetRecord {
    pub name: String,
    /// `sphere` or `box`.
    pub shape: String,
    pub center: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<[f64; 3]>,
    pub volume: f64,
    pub fluence: Measured,
    /// `∂ fluence/∂θ` by parameter name, with standard errors (with `render.derivatives`).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub derivatives: std::collections::BTreeMap<String, Measured>,
}

/// A camera of a render: orthographic or pinhole.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraRecord {
    pub name: String,
    /// `orthographic` or `pinhole`.
    pub kind: String,
    /// Orthographic: the direction of the light it records, and the radiant intensity along it
    /// (the image summed times the pixel area) per unit emitted power and steradian.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<Measured>,
    /// Pinhole: where it is, and the irradiance there from its field of view, per unit emitted
    /// power.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<Measured>,
    pub pixels: [usize; 2],
    /// Orthographic: a pixel's area; pinhole: its area in the image plane at unit distance.
    pub pixel_area: f64,
    /// The median relative standard error of the lit pixels of the time-integrated image (its
    /// first channel): how noisy the image is, to compare estimators and sample counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_noise: Option<f64>,
    /// The same over the bright pixels (at least a hundredth of the 99th-percentile lit pixel):
    /// faint pixels that more samples keep lighting do not enter it, so it falls as 1/√samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bright_pixel_noise: Option<f64>,
    /// `camera_<name>.exr` (channels `Y`, radiance per unit emitted power, and `stderr`), then one
    /// per time bin; with `render.derivatives`, `camera_<name>_d_<param>.exr` per parameter.
    pub files: Vec<String>,
    /// `"tent"` when the pixels share what arrives bilinearly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<String>,
    /// The derivatives of its `intensity` or `irradiance` by parameter name, with standard errors
    /// (with `render.derivatives`).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub derivatives: std::collections::BTreeMap<String, Measured>,
    /// Its pixel windows (`[[sensor.window]]`), each summed with its own standard error.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub windows: Vec<WindowRecord>,
    /// Bidirectional tracing: the part of its `intensity` or `irradiance` each strategy brings,
    /// weighted, with its own standard error (where the noise comes from).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub strategies: Vec<StrategyRecord>,
}

/// What one strategy of bidirectional tracing brings a camera: paths of `events` scattering
/// events, `from_light` of them traced from the light (the rest from the camera), weighted by
/// the balance heuristic; without `from_light`, every strategy's paths of `events` events or
/// more.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StrategyRecord {
    pub events: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_light: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<Measured>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<Measured>,
}

/// A camera's pixel window: the part of the camera's `intensity` (orthographic) or `irradiance`
/// (pinhole) that its pixels hold.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct WindowRecord {
    pub name: String,
    /// First and last column, from the image's left, and row, from its top, as configured.
    pub columns: [usize; 2],
    pub rows: [usize; 2],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<Measured>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<Measured>,
    /// Its derivatives by parameter name, with standard errors (with `render.derivatives`).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub derivatives: std::collections::BTreeMap<String, Measured>,
}

/// How the connections to probes and cameras went.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ConnectionStatistics {
    /// `unbiased` (Alg. 3) or `first`.
    pub mode: String,
    pub per_photon: f64,
    /// Fraction of connections for which a stationary path was found.
    pub success_rate: f64,
    pub solves_per_connection: f64,
    pub iterations_per_solve: f64,
    /// Distinct stationary paths met per connection found (1 where one path joins two points).
    pub distinct_paths: f64,
}

/// How the photons went: per-photon averages and the speed.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RenderStatistics {
    pub events_per_photon: f64,
    pub steps_per_photon: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub connections: Option<ConnectionStatistics>,
    /// `null` for merged shards.
    pub photons_per_second: Option<f64>,
    pub steps_per_second: Option<f64>,
}

/// `render.json` of `lightpath render`: fractions of the emitted power.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RenderFile {
    #[serde(default)]
    pub format_version: u32,
    pub estimator: String,
    pub samples: u64,
    pub seed: u64,
    pub chunk: u64,
    pub sensors: Vec<SensorRecord>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub probes: Vec<ProbeRecord>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub targets: Vec<TargetRecord>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cameras: Vec<CameraRecord>,
    /// The channels of screen and camera images: `["Y"]`, or `["R", "G", "B"]` (linear sRGB,
    /// white-balanced to the light) with a white `[spectrum]`.
    #[serde(default)]
    pub channels: Vec<String>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub surfaces: Vec<SurfaceRecord>,
    /// Absorbed inside the volume, left it (seen by a sensor or not), and given up (trapped past
    /// the step budget): they add up to 1 within their errors.
    /// (Particle tracing only: path tracing from the cameras does not follow the light's power.)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub absorbed: Option<Measured>,
    /// Absorbed by the surfaces (with surfaces: the four add up to 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub absorbed_by_surfaces: Option<Measured>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub escaped: Option<Measured>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unfinished: Option<Measured>,
    pub statistics: RenderStatistics,
    /// Wall time; `null` for merged shards.
    pub seconds: Option<f64>,
    pub version: String,
    pub config: crate::config::RenderConfig,
}
result_file!(RenderFile, "render.json");
