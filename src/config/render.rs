//! Configs of `lightpath render`: a refractive, scattering volume (`[field]` + `[medium]`), one
//! `[light]`, `[[sensor]]` planes outside the volume, optional `[transient]` bins and `[render]`
//! settings → [`RenderScene`].

use super::scene::{MediumConfig, finite, positive, unit};
use super::trace::BoundsConfig;
use super::trace::{FieldConfig, check_positive};
use super::{ConfigError, err};
use crate::eikonal::{BoundedField, Bounds, Part};
use crate::medium::{PhaseFunction, Scattering};
use crate::rrte::{
    Bulk, Camera, Connections, Density, Derivative, Dispersion, FieldDerivative, Filter, Light,
    MAX_DERIVATIVES, MAX_TARGETS, Material, MediumDerivative, Modulation, Probe, Region,
    RenderScene, Sensor, SensorKind, Spectrum, Surface, Tracing, Transient, Volume,
};
use glam::DVec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderConfig {
    /// Wavelength in the scene's length unit (needed only by Mie phase functions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wavelength: Option<f64>,
    pub field: FieldConfig,
    /// Several disjoint volumes instead of one (`[field]` then gives `n_out` alone, and
    /// `[medium]` is left out): each its own shape, index profiles and bulk, placed at its centre.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub volume: Vec<VolumeConfig>,
    /// Bulk scattering inside the field's bounds (absent: a clear volume).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub medium: Option<MediumConfig>,
    /// A density on a grid scaling the medium's coefficients (absent: homogeneous).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<DensityConfig>,
    pub light: LightConfig,
    #[serde(default)]
    pub sensor: Vec<SensorConfig>,
    /// Diffuse or black surfaces outside the volume (a floor, walls).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub surface: Vec<SurfaceConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transient: Option<TransientConfig>,
    /// How the ultrasonic profiles' amplitudes change in time (absent: static).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulation: Option<ModulationConfig>,
    /// Each photon's vacuum wavelength and the dispersion of the indices (absent: one unnamed
    /// wavelength, the field as given, one-channel images).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spectrum: Option<SpectrumConfig>,
    #[serde(default)]
    pub render: RenderSettings,
    /// A design of the index field toward a target (`lightpath design`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub design: Option<RenderDesignConfig>,
}

/// `[design]` of a render config: the index field's parameters moved by Adam or L-BFGS, each
/// within its range, to deliver the most light to a target (or the most relative to another:
/// contrast).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderDesignConfig {
    /// The target, spot, fluence probe or camera window (by name) whose output is maximised.
    pub maximize: String,
    /// An output the maximised one is taken relative to (the objective is then the ratio: a
    /// spot's contrast against a wider one, a window's against the camera's whole image).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_to: Option<String>,
    pub parameters: Vec<DesignParameterConfig>,
    /// "adam" (fresh photons every iteration; many parameters) or "lbfgs" (held photons: a
    /// deterministic sample-average objective; a few parameters).
    #[serde(default = "default_design_method")]
    pub method: String,
    #[serde(default = "default_design_iterations")]
    pub iterations: u64,
    /// Photons per iteration (fresh ones every Adam iteration; the same ones for every L-BFGS
    /// evaluation).
    #[serde(default = "default_design_photons")]
    pub photons: u64,
    /// Adam's step in each parameter's logistic coordinate (0.1 moves a parameter in the middle
    /// of its range by about 2.5 % of the range per step).
    #[serde(default = "default_design_learning_rate")]
    pub learning_rate: f64,
    /// Photons of the renders at a fresh seed that check the design against the start.
    #[serde(default = "default_verify_photons")]
    pub verify_photons: u64,
}

/// `[[volume]]`: one of several disjoint volumes of a scene. Its bounds and profiles are given as
/// if it sat at the origin, and moved to `center`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VolumeConfig {
    #[serde(default)]
    pub center: [f64; 3],
    pub bounds: super::trace::BoundsConfig,
    /// Profiles summed inside the bounds.
    pub profiles: Vec<super::trace::ProfileConfig>,
    /// Bulk scattering inside (absent: clear).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub medium: Option<MediumConfig>,
    /// With `[spectrum]`, what the volume is made of, as `spectrum.inside` names it for a
    /// volume of its own: one material (the profiles scaled with it) or two mixed in place
    /// (absent: the same index at every wavelength).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub materials: Vec<String>,
}

/// The coefficients and scattering law of a render's `[medium]` keys (at `wavelength`, NaN if
/// none is given).
fn medium_bulk(m: &MediumConfig, wavelength: f64) -> Result<(f64, f64, Scattering), ConfigError> {
    for (key, given) in [
        ("box", m.box_size.is_some()),
        ("slab", m.slab.is_some()),
        ("slab_window", m.slab_window.is_some()),
    ] {
        if given {
            return err(format!(
                "medium.{key}: a render's volume is the field's bounds (field.bounds); leave {key} out"
            ));
        }
    }
    let bulk = m.bulk(wavelength)?;
    if !(bulk.0.is_finite() && bulk.1.is_finite()) {
        return err(
            "wavelength: missing; Mie spheres need the wavelength (in the scene's length unit)",
        );
    }
    Ok(bulk)
}

/// Volumes must not overlap: no sample of one (on a grid over its bounding box) lies in another.
fn check_apart(parts: &[Part]) -> Result<(), ConfigError> {
    let m = 24;
    for (i, a) in parts.iter().enumerate() {
        let Some(half) = a.shape.half_extent() else {
            continue;
        };
        for u in 0..=m {
            for v in 0..=m {
                for w in 0..=m {
                    let f = DVec3::new(u as f64, v as f64, w as f64) / m as f64 * 2.0 - DVec3::ONE;
                    let local = f * half;
                    if !a.shape.contains(local) {
                        continue;
                    }
                    let x = a.center + local;
                    if let Some(j) = (0..parts.len())
                        .find(|&j| j != i && parts[j].shape.contains(x - parts[j].center))
                    {
                        return err(format!(
                            "volume[{i}] and volume[{j}] overlap (both hold {:?}): volumes must lie apart",
                            x.to_array()
                        ));
                    }
                }
            }
        }
    }
    Ok(())
}

/// The most volumes a scene holds (each is asked which holds a point at every step).
const MAX_VOLUMES: usize = crate::eikonal::MAX_PARTS;

/// An error of `[field]` or `[medium]` keys, told of `[[volume]]` entry `i`.
fn of_volume(i: usize, e: ConfigError) -> ConfigError {
    let key = format!("volume[{i}]");
    ConfigError(
        e.0.replace("field.", &format!("{key}."))
            .replace("field:", &format!("{key}:"))
            .replace("medium.", &format!("{key}.medium."))
            .replace("medium:", &format!("{key}.medium:")),
    )
}

/// Whether `field` has an ultrasonic profile or a phased array, whose index could oscillate.
fn oscillates(field: &BoundedField) -> bool {
    field.profiles.iter().any(|p| {
        matches!(
            p,
            crate::eikonal::Profile::Ultrasonic { .. }
                | crate::eikonal::Profile::PhasedArray { .. }
        )
    })
}

/// `[modulation]` on `field`: a strobe freezes it at its phase; a continuous modulation is left
/// to each photon's instant, after every eighth of the period has been checked to give a valid
/// field. Whether photons sample the period.
fn modulated(
    m: &ModulationConfig,
    field: &mut BoundedField,
) -> Result<Option<Modulation>, ConfigError> {
    let base = field.clone();
    match *m {
        ModulationConfig::Sinusoidal {} => {
            for i in 0..8 {
                let omega_t = std::f64::consts::TAU * i as f64 / 8.0;
                crate::rrte::particle::modulate(field, &base, omega_t);
                check_positive(field)?;
            }
            *field = base;
            Ok(Some(Modulation::Sinusoidal))
        }
        ModulationConfig::Strobed { phase_deg } => {
            if !phase_deg.is_finite() || phase_deg.abs() > 360.0 {
                return err(format!(
                    "modulation.phase_deg = {phase_deg}: must be within [-360, 360]"
                ));
            }
            crate::rrte::particle::modulate(field, &base, phase_deg.to_radians());
            Ok(None)
        }
    }
}

/// `volume[k].profiles[…]` of a scene of several volumes: `k` and the `profiles[…]` that
/// follows (an index-field parameter of volume `k`).
fn volume_profile<'n>(name: &'n str, volume: &Volume) -> Option<(usize, &'n str)> {
    let (k, rest) = name.strip_prefix("volume[")?.split_once("].")?;
    let k = k.trim().parse::<usize>().ok()?;
    (k < volume.parts.len() && rest.trim().starts_with("profiles[")).then_some((k, rest.trim()))
}

/// The medium parameter `volume[k].name` names (`rest`: what follows `volume[`), checked against
/// the scene's several volumes.
fn volume_parameter(rest: &str, volume: &Volume) -> Result<MediumDerivative, String> {
    use crate::medium::params::Param;
    let count = volume.parts.len();
    if count == 0 {
        return Err("volume[i].name names a parameter of one of several volumes ([[volume]]); this scene has one ([field], [medium]): name it alone (sigma_s, g, …)".into());
    }
    let (k, name) = rest
        .split_once("].")
        .and_then(|(k, name)| Some((k.trim().parse::<usize>().ok()?, name.trim())))
        .ok_or("write volume[i].name, e.g. volume[0].sigma_s")?;
    if k >= count {
        return Err(format!(
            "volume[{k}]: the scene has {count} volumes, volume[0] to volume[{}]",
            count - 1
        ));
    }
    let param = Param::parse(name).map_err(|e| e.to_string())?;
    let b = &volume.parts[k];
    if param
        .value_in(b.sigma_s, b.sigma_a, &b.scattering)
        .is_none()
    {
        return Err(format!(
            "volume[{k}]'s medium has no such parameter (phase-function parameters need a component of that kind: g an \"hg\" one, bin a table, vmf_* a vMF mixture)"
        ));
    }
    Ok(MediumDerivative {
        param,
        volume: Some(k),
    })
}

/// A designed transducer position keeps its element's line outside the volume over its whole
/// range, where its wave is singular.
fn check_placement(
    key: &str,
    p: &DesignParameterConfig,
    derivative: &Derivative,
    volume: &Volume,
) -> Result<(), ConfigError> {
    let Derivative::Field(f) = derivative else {
        return Ok(());
    };
    let Some((crate::eikonal::Profile::PhasedArray { array, .. }, shape)) =
        f.profile(&volume.field)
    else {
        return Ok(());
    };
    let Some((j, axis)) = array.position_param(f.param.which) else {
        return Ok(());
    };
    let e = &array.elements[j];
    let other = if axis == 0 { e.y } else { e.x };
    let bounds = f.volume.map_or("field.bounds".to_string(), |k| {
        format!("volume[{k}].bounds")
    });
    match super::trace::element_blocked(shape, axis, other) {
        Some((a, b)) if a <= p.max && p.min <= b => err(format!(
            "{key} ({}): (min, max) = ({}, {}) reaches ({a}, {b}), where element {j}'s line (parallel to z) meets {bounds}; keep the range outside the volume",
            p.name, p.min, p.max
        )),
        _ => Ok(()),
    }
}

/// A designed parameter: its name (as `render.derivatives` names it) and its range.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DesignParameterConfig {
    pub name: String,
    pub min: f64,
    pub max: f64,
}

fn default_design_method() -> String {
    "adam".into()
}
fn default_design_iterations() -> u64 {
    60
}
fn default_design_photons() -> u64 {
    5_000
}
fn default_design_learning_rate() -> f64 {
    0.1
}
fn default_verify_photons() -> u64 {
    100_000
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightConfig {
    /// A collimated laser beam, uniform over a disc (`radius = 0`: one ray); with `focus`,
    /// focused there by a lens outside the volume (each ray from the disc aimed at it).
    Beam {
        center: [f64; 3],
        direction: [f64; 3],
        #[serde(default)]
        radius: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        focus: Option<[f64; 3]>,
    },
    Point {
        position: [f64; 3],
    },
    Spot {
        position: [f64; 3],
        axis: [f64; 3],
        half_angle_deg: f64,
    },
    /// A Lambertian rectangle emitting to the side of `normal`.
    Area {
        center: [f64; 3],
        normal: [f64; 3],
        size: [f64; 2],
    },
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SensorConfig {
    /// The power crossing a plane away from the volume (a rectangle when `size` is given; within
    /// `acceptance_deg` of the normal when given).
    Flux {
        name: String,
        center: [f64; 3],
        normal: [f64; 3],
        #[serde(default, skip_serializing_if = "Option::is_none")]
        size: Option<[f64; 2]>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        acceptance_deg: Option<f64>,
    },
    /// The power crossing a plane weighted by a Gaussian aperture of `1/e²` radius `radius`
    /// about `center`: a focal spot's power, differentiable as the field moves the light.
    Spot {
        name: String,
        center: [f64; 3],
        normal: [f64; 3],
        radius: f64,
    },
    /// Irradiance on a rectangle of pixels, each crossing given to the pixel it falls in
    /// (`filter = "box"`) or shared bilinearly among the four about it (`"tent"`, which index-
    /// field derivatives need).
    Screen {
        name: String,
        center: [f64; 3],
        normal: [f64; 3],
        size: [f64; 2],
        pixels: [u64; 2],
        #[serde(default, skip_serializing_if = "FilterConfig::is_box")]
        filter: FilterConfig,
    },
    /// Fluence rate at a point inside the volume, by connections along curved rays.
    Fluence { name: String, position: [f64; 3] },
    /// The mean fluence rate over a region inside the volume (a sphere of `radius` or an
    /// axis-aligned box of `size` about `center`): the light delivered there.
    Target {
        name: String,
        center: [f64; 3],
        #[serde(default, skip_serializing_if = "Option::is_none")]
        radius: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        size: Option<[f64; 3]>,
    },
    /// An orthographic camera: the radiance travelling along `direction` (it looks along
    /// `−direction`) over `size` about `center` in `pixels`, by connections through the surface.
    Camera {
        name: String,
        center: [f64; 3],
        direction: [f64; 3],
        size: [f64; 2],
        pixels: [u64; 2],
        #[serde(default, skip_serializing_if = "FilterConfig::is_box")]
        filter: FilterConfig,
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        window: Vec<WindowConfig>,
    },
    /// A pinhole camera at `position` looking at `look_at` (`up`: the image's vertical), with a
    /// vertical field of view `fov_deg`: radiance through the pinhole, by connections through the
    /// surface.
    Pinhole {
        name: String,
        position: [f64; 3],
        look_at: [f64; 3],
        #[serde(default = "default_up")]
        up: [f64; 3],
        fov_deg: f64,
        pixels: [u64; 2],
        #[serde(default, skip_serializing_if = "FilterConfig::is_box")]
        filter: FilterConfig,
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        window: Vec<WindowConfig>,
    },
}

/// `[[sensor.window]]` of a camera: a named window of its pixels whose sum is an output of its
/// own (`render.json`, a design objective).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct WindowConfig {
    pub name: String,
    /// First and last column (0-based), from the image's left.
    pub columns: [u64; 2],
    /// First and last row (0-based), from the image's top as the files show it.
    pub rows: [u64; 2],
}

/// `sensor.filter` of a screen or a camera: each pixel takes what lands in it (`box`), or the
/// pixels share it bilinearly (`tent`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum FilterConfig {
    #[default]
    Box,
    Tent,
}

impl FilterConfig {
    fn is_box(&self) -> bool {
        *self == FilterConfig::Box
    }

    fn build(self) -> Filter {
        match self {
            FilterConfig::Box => Filter::Box,
            FilterConfig::Tent => Filter::Tent,
        }
    }
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

/// `[render] connections`.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum ConnectionsConfig {
    #[default]
    Unbiased,
    First,
}

impl ConnectionsConfig {
    fn is_default(&self) -> bool {
        *self == ConnectionsConfig::Unbiased
    }
}

/// `[modulation]`: the ultrasonic amplitudes as `n_max sin Ωt`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ModulationConfig {
    /// Continuous light integrated over whole periods: every phase equally (paper 002, Eq. 22).
    Sinusoidal {},
    /// Light pulsed in step with the ultrasound: the field frozen at `phase_deg` (90: the peak).
    Strobed { phase_deg: f64 },
}

/// `[[surface]]`: a Lambertian plane or rectangle outside the volume reflecting `albedo` of the
/// light reaching it (0: black), on both sides.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SurfaceConfig {
    pub name: String,
    pub center: [f64; 3],
    pub normal: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<[f64; 2]>,
    pub albedo: f64,
}

/// `[density]`: samples of `ρ(x)` on a regular grid (x fastest), interpolated trilinearly (default)
/// or tricubically, scaling `σ_s` and `σ_a` of `[medium]`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DensityConfig {
    pub dims: [u64; 3],
    pub origin: [f64; 3],
    pub spacing: f64,
    pub values: Vec<f64>,
    #[serde(default = "trilinear")]
    pub interp: String,
}

fn trilinear() -> String {
    "trilinear".into()
}

impl DensityConfig {
    fn build(&self, field: &crate::eikonal::BoundedField) -> Result<Density, ConfigError> {
        let grid = match super::trace::grid_profile(
            "density",
            self.dims,
            self.origin,
            self.spacing,
            self.values.clone(),
            &self.interp,
        )? {
            crate::eikonal::Profile::Grid(g) => g,
            _ => unreachable!("grid_profile builds grids"),
        };
        // the grid must cover the volume (outside it the edge values would be repeated silently)
        if let Some(half) = field.bounds.half_extent() {
            let lo = grid.origin;
            let hi = lo
                + DVec3::new(
                    (grid.dims[0] - 1) as f64,
                    (grid.dims[1] - 1) as f64,
                    (grid.dims[2] - 1) as f64,
                ) * grid.spacing;
            let slack = 1e-9 * half.max_element();
            if (lo - (-half)).max_element() > slack || (half - hi).max_element() > slack {
                return err(format!(
                    "density: the grid spans {:?} to {:?}, which does not cover the volume's bounds ±{:?} (field.bounds)",
                    lo.to_array(),
                    hi.to_array(),
                    half.to_array()
                ));
            }
        }
        Density::new(grid).map_err(|e| ConfigError(format!("density.values: {e}")))
    }
}

/// `[spectrum]`: white light over `range_nm` (RGB images) or one line `wavelength_nm`; the field
/// and `n_out` are given at `reference_nm` and follow the materials named in `inside` (one, or
/// two mixed in place) and `outside`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpectrumConfig {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range_nm: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wavelength_nm: Option<f64>,
    #[serde(default = "default_reference_nm")]
    pub reference_nm: f64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inside: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outside: Option<String>,
    /// Materials beyond the catalogue, by name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub material: Vec<MaterialConfig>,
}

/// The helium d line, where glass catalogues quote `n_d`.
fn default_reference_nm() -> f64 {
    587.56
}

/// `[[spectrum.material]]`: a dispersion formula (wavelength in µm, as catalogues quote them).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MaterialConfig {
    /// `n = a + b/λ² + c/λ⁴`.
    Cauchy {
        name: String,
        a: f64,
        #[serde(default)]
        b: f64,
        #[serde(default)]
        c: f64,
    },
    /// `n² = 1 + Σ b_i λ²/(λ² − c_i)`.
    Sellmeier {
        name: String,
        b: Vec<f64>,
        c: Vec<f64>,
    },
}

impl SpectrumConfig {
    /// The spectrum, with each volume's dispersion where the scene has `volumes`.
    fn build(&self, volumes: &[VolumeConfig]) -> Result<Spectrum, ConfigError> {
        let range = match (self.range_nm, self.wavelength_nm) {
            (Some(_), Some(_)) => {
                return err(
                    "spectrum: range_nm (white light, RGB images) and wavelength_nm (one line) exclude each other",
                );
            }
            (None, Some(l)) => {
                if !(200.0..=20_000.0).contains(&l) {
                    return err(format!(
                        "spectrum.wavelength_nm = {l}: must be within [200, 20000] nm"
                    ));
                }
                [l, l]
            }
            (Some([lo, hi]), None) => {
                if !(360.0 <= lo && lo < hi && hi <= 830.0) {
                    return err(format!(
                        "spectrum.range_nm = [{lo}, {hi}]: must be an increasing range within [360, 830] nm (where the eye's colour matching functions are defined)"
                    ));
                }
                [lo, hi]
            }
            (None, None) => [380.0, 780.0],
        };
        let reference = self.reference_nm;
        if !(200.0..=20_000.0).contains(&reference) {
            return err(format!(
                "spectrum.reference_nm = {reference}: must be within [200, 20000] nm"
            ));
        }
        let mut custom = Vec::new();
        for (i, m) in self.material.iter().enumerate() {
            let key = format!("spectrum.material[{i}]");
            let (name, material) = match m {
                MaterialConfig::Cauchy { name, a, b, c } => {
                    if ![a, b, c].iter().all(|v| v.is_finite()) {
                        return err(format!("{key}: a, b and c must be finite"));
                    }
                    (
                        name,
                        Material::Cauchy {
                            a: *a,
                            b: *b,
                            c: *c,
                        },
                    )
                }
                MaterialConfig::Sellmeier { name, b, c } => {
                    if b.len() != c.len() || !(1..=6).contains(&b.len()) {
                        return err(format!(
                            "{key}: b has {} terms and c {}: they must pair up, 1 to 6 terms",
                            b.len(),
                            c.len()
                        ));
                    }
                    if !b.iter().chain(c).all(|v| v.is_finite()) {
                        return err(format!("{key}: b and c must be finite"));
                    }
                    let terms = b.iter().copied().zip(c.iter().copied()).collect();
                    (name, Material::Sellmeier { terms })
                }
            };
            check_name(&format!("{key}.name"), name)?;
            if custom.iter().any(|(n, _)| n == name) {
                return err(format!("{key}.name = \"{name}\": defined twice"));
            }
            custom.push((name.clone(), material));
        }
        // a material by name, its index checked over the wavelengths photons will carry
        let material = |key: &str, name: &str| -> Result<Material, ConfigError> {
            let m = custom
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, m)| m.clone())
                .or_else(|| Material::named(name));
            let Some(m) = m else {
                let mut known: Vec<&str> = Material::NAMES.to_vec();
                known.extend(custom.iter().map(|(n, _)| n.as_str()));
                return err(format!(
                    "{key} = \"{name}\": no such material; known: {} (or define it in [[spectrum.material]])",
                    known.join(", ")
                ));
            };
            let nodes = (0..=64).map(|k| range[0] + (range[1] - range[0]) * k as f64 / 64.0);
            for l in nodes.chain([reference]) {
                let n = m.index(l);
                if !(n > 0.0 && n <= 10.0) {
                    return err(format!(
                        "{key} = \"{name}\": its index at {l:.1} nm is {n}: it must be a real index within (0, 10] over spectrum.range_nm and at reference_nm"
                    ));
                }
            }
            Ok(m)
        };
        // the materials a volume is made of (named under `key`)
        let dispersion = |key: &str, names: &[String]| -> Result<_, ConfigError> {
            Ok(match names {
                [] => None,
                [one] => Some(Dispersion::Scaled(material(&format!("{key}[0]"), one)?)),
                [first, second] => {
                    let (m1, m2) = (
                        material(&format!("{key}[0]"), first)?,
                        material(&format!("{key}[1]"), second)?,
                    );
                    if (m1.index(reference) - m2.index(reference)).abs() < 1e-6 {
                        return err(format!(
                            "{key} = [\"{first}\", \"{second}\"]: the two materials have the same index at reference_nm, so the field cannot say how they mix"
                        ));
                    }
                    Some(Dispersion::Mixed(m1, m2))
                }
                more => {
                    return err(format!(
                        "{key} names {} materials: one (the field scaled with it) or two (mixed in place)",
                        more.len()
                    ));
                }
            })
        };
        let inside = dispersion("spectrum.inside", &self.inside)?;
        let outside = match &self.outside {
            Some(name) => Some(material("spectrum.outside", name)?),
            None => None,
        };
        let spectrum = Spectrum::new(range, reference, inside, outside);
        if volumes.is_empty() {
            return Ok(spectrum);
        }
        if !self.inside.is_empty() {
            return err(
                "spectrum.inside: with [[volume]], each volume names what it is made of (volume[i].materials)",
            );
        }
        let parts = volumes
            .iter()
            .enumerate()
            .map(|(i, v)| dispersion(&format!("volume[{i}].materials"), &v.materials))
            .collect::<Result<_, _>>()?;
        Ok(spectrum.with_parts(parts))
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TransientConfig {
    pub bins: u64,
    /// Optical path length `∫ n ds` covered by the bins, from the light.
    pub max_path: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderSettings {
    #[serde(default = "default_samples")]
    pub samples: u64,
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Photons per chunk (the unit of parallel work and of batch-means errors).
    #[serde(default = "default_chunk")]
    pub chunk: u64,
    /// Leapfrog step in the σ-form (geometric length ≈ `n · step`) where `n` varies.
    #[serde(default = "default_step")]
    pub step: f64,
    /// Most leapfrog steps of one free flight (a photon past it is reported unfinished).
    #[serde(default = "default_max_steps")]
    pub max_steps: u64,
    /// Connections to fluence probes: `"unbiased"` (a random stationary path weighted by its
    /// inverse probability, Alg. 3) or `"first"` (the path found, unweighted).
    #[serde(default, skip_serializing_if = "ConnectionsConfig::is_default")]
    pub connections: ConnectionsConfig,
    /// Reflections inside the volume's surface a connection through it follows at most, each
    /// tried as a path of its own (0: connections leave the volume directly).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub reflections: u64,
    /// Medium parameters whose derivatives particle tracing estimates for every sensor's power:
    /// `"sigma_s"`, `"sigma_a"`, `"g"`, `"g[c]"`, `"bin[c][k]"`, `"weight[c]"`, … (path-space
    /// scores; see the render docs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub derivatives: Vec<String>,
    /// `"particle"` (photons from the light; every sensor kind), `"path"` (paths from the
    /// cameras, connected to the light) or `"bidirectional"` (both, joined every way and weighted
    /// by multiple importance sampling; no surfaces).
    #[serde(default, skip_serializing_if = "EstimatorConfig::is_default")]
    pub estimator: EstimatorConfig,
}

/// `[render] estimator`.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorConfig {
    #[default]
    Particle,
    Path,
    Bidirectional,
}

impl EstimatorConfig {
    fn is_default(&self) -> bool {
        *self == EstimatorConfig::Particle
    }
}

fn default_samples() -> u64 {
    1_000_000
}
fn default_seed() -> u64 {
    1
}
fn default_chunk() -> u64 {
    10_000
}
fn default_step() -> f64 {
    0.005
}
fn default_max_steps() -> u64 {
    1_000_000
}
fn is_zero(n: &u64) -> bool {
    *n == 0
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            samples: default_samples(),
            seed: default_seed(),
            chunk: default_chunk(),
            step: default_step(),
            max_steps: default_max_steps(),
            connections: ConnectionsConfig::Unbiased,
            reflections: 0,
            derivatives: Vec::new(),
            estimator: EstimatorConfig::Particle,
        }
    }
}

/// The most reflections inside the surface a connection follows (each costs a connection).
const MAX_REFLECTIONS: u64 = 8;

/// The most sensors, pixels per sensor side and time bins a render takes.
const MAX_SENSORS: usize = 64;
const MAX_PIXELS: u64 = 4096;
const MAX_BINS: u64 = 10_000;

impl RenderConfig {
    /// Make the file paths of the field, the medium and every volume (grids, signed-distance
    /// shapes and meshes, phase tables) relative to the config file's folder.
    pub fn resolve_paths(&mut self, config: &std::path::Path) {
        let dir = config.parent().unwrap_or(std::path::Path::new(""));
        self.field.resolve_paths(config);
        if let Some(m) = &mut self.medium {
            m.resolve_paths(dir);
        }
        for v in &mut self.volume {
            let mut keys = FieldConfig {
                profiles: std::mem::take(&mut v.profiles),
                bounds: std::mem::take(&mut v.bounds),
                n_out: 1.0,
            };
            keys.resolve_paths(config);
            (v.profiles, v.bounds) = (keys.profiles, keys.bounds);
            if let Some(m) = &mut v.medium {
                m.resolve_paths(dir);
            }
        }
    }

    /// The scene these keys describe, every value checked.
    pub fn build(&self) -> Result<RenderScene, ConfigError> {
        let (volume, modulation) = if self.volume.is_empty() {
            self.one_volume()?
        } else {
            self.several_volumes()?
        };
        let light = self.light()?;
        if self.sensor.len() > MAX_SENSORS {
            return err(format!(
                "sensor: {} sensors; at most {MAX_SENSORS}",
                self.sensor.len()
            ));
        }
        let mut sensors = Vec::with_capacity(self.sensor.len());
        let mut probes = Vec::new();
        let mut cameras = Vec::new();
        let mut pinholes = Vec::new();
        let mut names: Vec<&str> = Vec::new();
        for (i, s) in self.sensor.iter().enumerate() {
            let name = match s {
                SensorConfig::Flux { name, .. }
                | SensorConfig::Spot { name, .. }
                | SensorConfig::Screen { name, .. }
                | SensorConfig::Fluence { name, .. }
                | SensorConfig::Target { name, .. }
                | SensorConfig::Camera { name, .. }
                | SensorConfig::Pinhole { name, .. } => name,
            };
            check_name(&format!("sensor[{i}].name"), name)?;
            if names.contains(&name.as_str()) {
                return err(format!(
                    "sensor[{i}].name = {name:?}: another sensor or a camera's window has this name"
                ));
            }
            names.push(name);
            if let SensorConfig::Pinhole {
                name,
                position,
                look_at,
                up,
                fov_deg,
                pixels,
                filter,
                window,
            } = s
            {
                let key = |k: &str| format!("sensor[{i}].{k}");
                let position = finite(&key("position"), *position)?;
                let target = finite(&key("look_at"), *look_at)?;
                let up = unit(&key("up"), *up)?;
                if !(*fov_deg > 0.0 && *fov_deg < 170.0) {
                    return err(format!(
                        "{} = {fov_deg}: must be within (0, 170)",
                        key("fov_deg")
                    ));
                }
                let pixels = check_pixels(i, *pixels)?;
                if volume.field.bounds.contains(position) {
                    return err(format!(
                        "{} = {:?}: the pinhole must lie outside the volume (field.bounds)",
                        key("position"),
                        position.to_array()
                    ));
                }
                let camera = crate::rrte::Pinhole::looking_at(
                    name.clone(),
                    position,
                    target,
                    up,
                    fov_deg.to_radians(),
                    pixels,
                )
                .ok_or_else(|| {
                    super::ConfigError(format!(
                        "{}: look_at must differ from position, and up must not be parallel to the view",
                        key("look_at")
                    ))
                })?;
                pinholes.push(crate::rrte::Pinhole {
                    filter: filter.build(),
                    windows: pixel_windows(i, window, pixels, &mut names)?,
                    ..camera
                });
            } else if let SensorConfig::Camera {
                name,
                center,
                direction,
                size,
                pixels,
                filter,
                window,
            } = s
            {
                let key = |k: &str| format!("sensor[{i}].{k}");
                let direction = unit(&key("direction"), *direction)?;
                let center = finite(&key("center"), *center)?;
                // the light it records leaves the volume along `direction` and runs on to the
                // image plane: all of the volume lies behind the plane
                let ahead = center.dot(direction) - volume.support(direction);
                if ahead < -1e-9 * (1.0 + center.dot(direction).abs()) {
                    return err(format!(
                        "{} = {:?}: the camera's image plane (through its center, normal to {} = {:?}) must lie beyond the volume along that direction, which the light it records travels; this one {} it (move it {ahead:.3} along the direction, or more)",
                        key("center"),
                        center.to_array(),
                        key("direction"),
                        direction.to_array(),
                        if center.dot(direction) > -volume.support(-direction) {
                            "cuts"
                        } else {
                            "lies before"
                        },
                        ahead = -ahead
                    ));
                }
                for (a, v) in size.iter().enumerate() {
                    positive(&key(&format!("size[{a}]")), *v)?;
                }
                let pixels = check_pixels(i, *pixels)?;
                cameras.push(Camera {
                    filter: filter.build(),
                    windows: pixel_windows(i, window, pixels, &mut names)?,
                    ..Camera::new(name.clone(), direction, center, *size, pixels)
                });
            } else if let SensorConfig::Fluence { name, position } = s {
                let position = finite(&format!("sensor[{i}].position"), *position)?;
                if !volume.field.bounds.contains(position) {
                    return err(format!(
                        "sensor[{i}].position = {:?}: a fluence probe must lie inside the volume (field.bounds, or one of the [[volume]]s)",
                        position.to_array()
                    ));
                }
                probes.push(Probe {
                    name: name.clone(),
                    position,
                });
            } else if let SensorConfig::Target {
                name,
                center,
                radius,
                size,
            } = s
            {
                if sensors
                    .iter()
                    .filter(|s: &&Sensor| s.region.is_some())
                    .count()
                    == MAX_TARGETS
                {
                    return err(format!(
                        "sensor[{i}].kind = \"target\": at most {MAX_TARGETS} targets"
                    ));
                }
                let region = target_region(i, *center, *radius, *size, &volume)?;
                sensors.push(Sensor::target(name.clone(), region));
            } else {
                sensors.push(sensor(i, s, &volume)?);
            }
        }
        if self.surface.len() > MAX_SENSORS {
            return err(format!(
                "surface: {} surfaces; at most {MAX_SENSORS}",
                self.surface.len()
            ));
        }
        let mut surfaces: Vec<Surface> = Vec::with_capacity(self.surface.len());
        for (i, s) in self.surface.iter().enumerate() {
            let made = surface(i, s, &volume)?;
            if surfaces.iter().any(|o| o.name == made.name) {
                return err(format!(
                    "surface[{i}].name = \"{}\": two surfaces share it",
                    made.name
                ));
            }
            surfaces.push(made);
        }
        let transient = match &self.transient {
            None => None,
            Some(t) => {
                if !(1..=MAX_BINS).contains(&t.bins) {
                    return err(format!(
                        "transient.bins = {}: must be within [1, {MAX_BINS}]",
                        t.bins
                    ));
                }
                Some(Transient {
                    bins: t.bins as usize,
                    max_path: positive("transient.max_path", t.max_path)?,
                })
            }
        };
        let r = &self.render;
        if r.samples == 0 {
            return err("render.samples = 0: must be at least 1");
        }
        if r.chunk == 0 {
            return err("render.chunk = 0: must be at least 1");
        }
        let step = positive("render.step", r.step)?;
        if !(1..=10_000_000).contains(&r.max_steps) {
            return err(format!(
                "render.max_steps = {}: must be within [1, 10000000]",
                r.max_steps
            ));
        }
        if r.reflections > MAX_REFLECTIONS {
            return err(format!(
                "render.reflections = {}: must be within [0, {MAX_REFLECTIONS}]",
                r.reflections
            ));
        }
        let derivatives = self.derivatives(&volume, &sensors)?;
        let scene = RenderScene {
            volume,
            light,
            sensors,
            probes,
            cameras,
            pinholes,
            surfaces,
            modulation,
            connections: match r.connections {
                ConnectionsConfig::Unbiased => Connections::Unbiased,
                ConnectionsConfig::First => Connections::First,
            },
            reflections: r.reflections as usize,
            derivatives,
            tracing: match r.estimator {
                EstimatorConfig::Particle => Tracing::FromLight,
                EstimatorConfig::Path => Tracing::FromCameras,
                EstimatorConfig::Bidirectional => Tracing::Bidirectional,
            },
            transient,
            spectrum: self.spectrum()?,
            step,
            max_steps: r.max_steps as usize,
        };
        check_step(&scene)?;
        if scene.tracing != Tracing::FromLight {
            self.check_path_tracing(&scene)?;
        }
        Ok(scene)
    }

    /// The volume of `[field]`, `[medium]` and `[density]`, and how its field is modulated.
    fn one_volume(&self) -> Result<(Volume, Option<Modulation>), ConfigError> {
        let mut field = self.field.build()?;
        if field.profiles.is_empty() {
            return err("field.profiles = []: give at least one profile");
        }
        if field.bounds == Bounds::Everywhere {
            return err(
                "field.bounds: a render needs a bounded volume (kind = \"sphere\", \"box\" or \"cylinder\") for light to leave",
            );
        }
        let modulation = match &self.modulation {
            None => None,
            Some(_) if !oscillates(&field) => {
                return err(
                    "modulation: the field has no ultrasonic profile or phased array whose index could oscillate",
                );
            }
            Some(m) => modulated(m, &mut field)?,
        };
        check_positive(&field)?;
        field.n_out = positive("field.n_out", field.n_out)?;
        let (sigma_s, sigma_a, scattering) = match &self.medium {
            None => (0.0, 0.0, Scattering::single(PhaseFunction::Isotropic)),
            Some(m) => {
                let wavelength = match self.wavelength {
                    Some(w) => positive("wavelength", w)?,
                    None => f64::NAN,
                };
                medium_bulk(m, wavelength)?
            }
        };
        let density = match &self.density {
            None => None,
            Some(_) if self.medium.is_none() => {
                return err(
                    "density: the volume has no [medium] whose coefficients it could scale",
                );
            }
            Some(d) => Some(d.build(&field)?),
        };
        let volume = Volume {
            field,
            sigma_s,
            sigma_a,
            scattering,
            density,
            parts: Vec::new(),
        };
        Ok((volume, modulation))
    }

    /// `[spectrum]`, with each volume's materials; a volume's materials without it are refused.
    fn spectrum(&self) -> Result<Option<Spectrum>, ConfigError> {
        match &self.spectrum {
            Some(s) => s.build(&self.volume).map(Some),
            None => match self.volume.iter().position(|v| !v.materials.is_empty()) {
                Some(i) => err(format!(
                    "volume[{i}].materials: what a volume is made of sets its dispersion, which needs [spectrum] (the light's wavelengths)"
                )),
                None => Ok(None),
            },
        }
    }

    /// The volumes of `[[volume]]`, as one volume of several parts (with `[modulation]` on those
    /// holding an ultrasonic field).
    fn several_volumes(&self) -> Result<(Volume, Option<Modulation>), ConfigError> {
        let n = self.volume.len();
        if n > MAX_VOLUMES {
            return err(format!("volume: {n} volumes; at most {MAX_VOLUMES}"));
        }
        if !self.field.profiles.is_empty() || self.field.bounds != BoundsConfig::Everywhere {
            return err(
                "field: with [[volume]], each volume gives its own bounds and profiles; [field] gives n_out alone",
            );
        }
        if self.medium.is_some() {
            return err("medium: not with [[volume]]: each [[volume]] gives its own medium");
        }
        let wavelength = self
            .wavelength
            .map_or(Ok(f64::NAN), |w| positive("wavelength", w))?;
        let mut parts = Vec::with_capacity(n);
        let mut bulks = Vec::with_capacity(n);
        let (mut modulation, mut oscillating) = (None, false);
        for (i, v) in self.volume.iter().enumerate() {
            let center = finite(&format!("volume[{i}].center"), v.center)?;
            if v.profiles.is_empty() {
                return err(format!(
                    "volume[{i}].profiles = []: give at least one profile"
                ));
            }
            if v.bounds == BoundsConfig::Everywhere {
                return err(format!(
                    "volume[{i}].bounds: a volume needs bounds (kind = \"sphere\", \"box\", \"cylinder\" or \"sdf\")"
                ));
            }
            let keys = FieldConfig {
                profiles: v.profiles.clone(),
                bounds: v.bounds.clone(),
                n_out: self.field.n_out,
            };
            let mut field = keys.build().map_err(|e| of_volume(i, e))?;
            if let Some(m) = self.modulation.as_ref().filter(|_| oscillates(&field)) {
                modulation = modulated(m, &mut field).map_err(|e| of_volume(i, e))?;
                oscillating = true;
            }
            check_positive(&field).map_err(|e| of_volume(i, e))?;
            parts.push(Part::new(field.bounds, center, field.profiles));
            bulks.push(match &v.medium {
                None => Bulk {
                    sigma_s: 0.0,
                    sigma_a: 0.0,
                    scattering: Scattering::single(PhaseFunction::Isotropic),
                },
                Some(m) => {
                    let (sigma_s, sigma_a, scattering) =
                        medium_bulk(m, wavelength).map_err(|e| of_volume(i, e))?;
                    Bulk {
                        sigma_s,
                        sigma_a,
                        scattering,
                    }
                }
            });
        }
        if self.modulation.is_some() && !oscillating {
            return err(
                "modulation: no [[volume]] has an ultrasonic profile or phased array whose index could oscillate",
            );
        }
        check_apart(&parts)?;
        let n_out = positive("field.n_out", self.field.n_out)?;
        let mut volume = Volume::several(parts.into_iter().zip(bulks).collect(), n_out);
        volume.density = match &self.density {
            None => None,
            Some(_) if volume.parts.iter().all(|b| b.sigma_t() == 0.0) => {
                return err(
                    "density: no [[volume]] has a medium whose coefficients it could scale",
                );
            }
            Some(d) => Some(d.build(&volume.field)?),
        };
        Ok((volume, modulation))
    }

    /// The parameters `render.derivatives` names, checked: medium parameters (`sigma_s`, `g`, …)
    /// of a homogeneous medium that has them, and index-field parameters (`profiles[i].name`),
    /// for particle tracing.
    fn derivatives(
        &self,
        volume: &Volume,
        sensors: &[Sensor],
    ) -> Result<Vec<Derivative>, ConfigError> {
        let names = &self.render.derivatives;
        if names.is_empty() {
            return Ok(Vec::new());
        }
        self.parameters("render.derivatives", names, volume, sensors)
    }

    /// The parameters `names` (listed under `list`) names, checked as
    /// `Self::derivatives` says (for `render.derivatives`, a design, Python's `render_vjp`).
    pub fn parameters(
        &self,
        list: &str,
        names: &[String],
        volume: &Volume,
        sensors: &[Sensor],
    ) -> Result<Vec<Derivative>, ConfigError> {
        use crate::medium::params::Param;
        let key = |i: usize| format!("{list}[{i}] = {:?}", names[i]);
        if names.len() > MAX_DERIVATIVES {
            return err(format!(
                "{list} names {} parameters: at most {MAX_DERIVATIVES}",
                names.len()
            ));
        }
        if self.render.estimator != EstimatorConfig::Particle {
            return err(format!(
                "{list}: the derivatives come from particle tracing; set render.estimator = \"particle\" (the default)",
            ));
        }
        if volume.density.is_some() {
            return err(format!(
                "{list}: derivatives need a homogeneous medium, and [density] makes it heterogeneous; drop [density]",
            ));
        }
        let several = !volume.parts.is_empty();
        let mut params = Vec::new();
        for (i, name) in names.iter().enumerate() {
            let trimmed = name.trim();
            let p = if let Some((k, field)) = volume_profile(trimmed, volume) {
                let f = self
                    .field_derivative(field, volume, Some(k))
                    .map_err(|e| ConfigError(format!("{}: volume[{k}]: {e}", key(i))))?;
                self.check_field_derivative(&key(i), volume, sensors)?;
                Derivative::Field(f)
            } else if let Some(rest) = trimmed.strip_prefix("volume[") {
                let m = volume_parameter(rest, volume)
                    .map_err(|e| ConfigError(format!("{}: {e}", key(i))))?;
                Derivative::Medium(m)
            } else if several && trimmed.starts_with("profiles[") {
                return err(format!(
                    "{}: with [[volume]], name the volume whose index field it is: volume[i].{trimmed}",
                    key(i)
                ));
            } else if several {
                return err(format!(
                    "{}: with [[volume]], name the volume whose medium it is: volume[i].{trimmed}",
                    key(i)
                ));
            } else if trimmed.starts_with("profiles[") {
                let f = self
                    .field_derivative(name, volume, None)
                    .map_err(|e| ConfigError(format!("{}: {e}", key(i))))?;
                self.check_field_derivative(&key(i), volume, sensors)?;
                Derivative::Field(f)
            } else {
                let p = Param::parse(name).map_err(|e| ConfigError(format!("{}: {e}", key(i))))?;
                if p.value_in(volume.sigma_s, volume.sigma_a, &volume.scattering)
                    .is_none()
                {
                    return err(format!(
                        "{}: the medium has no such parameter (phase-function parameters need a component of that kind: g an \"hg\" one, bin a table, vmf_* a vMF mixture; index-field parameters are named profiles[i].name)",
                        key(i)
                    ));
                }
                Derivative::Medium(MediumDerivative::of_one(p))
            };
            if params.iter().any(|q: &Derivative| q.name() == p.name()) {
                return err(format!(
                    "{}: already listed; name each parameter once",
                    key(i)
                ));
            }
            params.push(p);
        }
        Ok(params)
    }

    /// The design of `[design]`, checked against the built `scene`.
    pub fn design(
        &self,
        scene: &RenderScene,
    ) -> Result<Option<crate::inverse::render_design::RenderDesign>, ConfigError> {
        let Some(d) = &self.design else {
            return Ok(None);
        };
        // one output that follows the light continuously: a target's tracks, a spot's aperture,
        // a probe's connections
        let objectives = scene.objectives();
        let designable = |i: usize| {
            scene
                .sensors
                .get(i)
                .is_none_or(|s| s.follows_light_continuously() && s.kind != SensorKind::Screen)
        };
        let target = |key: &str, name: &str| {
            (0..objectives.len())
                .position(|i| objectives[i] == name && designable(i))
                .ok_or_else(|| {
                    let targets: Vec<&str> = (0..objectives.len())
                        .filter(|&i| designable(i))
                        .map(|i| objectives[i].as_str())
                        .collect();
                    ConfigError(format!(
                        "{key} = {name:?}: not a target, spot, fluence probe or camera window of this scene; its targets (kind = \"target\"), spots (kind = \"spot\"), probes (kind = \"fluence\") and cameras' windows ([[sensor.window]]): {targets:?}"
                    ))
                })
        };
        let maximize = target("design.maximize", &d.maximize)?;
        let relative_to = match &d.relative_to {
            Some(r) if *r == d.maximize => {
                return err(format!(
                    "design.relative_to = {r:?}: the output maximised; name another target, spot, probe or window, or leave it out"
                ));
            }
            Some(r) => Some(target("design.relative_to", r)?),
            None => None,
        };
        if d.parameters.is_empty() {
            return err(
                "design.parameters = []: name at least one, e.g. [{ name = \"profiles[0].n_max\", min = 0.0, max = 0.002 }]",
            );
        }
        let names: Vec<String> = d.parameters.iter().map(|p| p.name.clone()).collect();
        let params = self.parameters("design.parameters", &names, &scene.volume, &scene.sensors)?;
        let mut design_scene = scene.clone();
        design_scene.derivatives = params;
        let op = crate::diff::RenderOp::from_scene(design_scene.clone(), (1, 1, 0))
            .map_err(|e| ConfigError(format!("design: {e}")))?;
        // θ from the operation: the medium's parameters first
        let values = op.values();
        let order: Vec<usize> = (0..names.len())
            .filter(|&i| matches!(design_scene.derivatives[i], Derivative::Medium(_)))
            .chain(
                (0..names.len())
                    .filter(|&i| matches!(design_scene.derivatives[i], Derivative::Field(_))),
            )
            .collect();
        let mut ranges = Vec::new();
        let mut start = Vec::new();
        let mut ordered = Vec::new();
        for (k, &i) in order.iter().enumerate() {
            let p = &d.parameters[i];
            let key = format!("design.parameters[{i}]");
            if !(p.min.is_finite() && p.max.is_finite() && p.min < p.max) {
                return err(format!(
                    "{key}: min = {}, max = {}: give finite numbers with min < max",
                    p.min, p.max
                ));
            }
            let v = values[k];
            if !(p.min < v && v < p.max) {
                return err(format!(
                    "{key} ({}): the config's value {v} must lie inside (min, max) = ({}, {}), where the design starts",
                    p.name, p.min, p.max
                ));
            }
            check_placement(&key, p, &design_scene.derivatives[i], &scene.volume)?;
            ranges.push((p.min, p.max));
            start.push(v);
            ordered.push(design_scene.derivatives[i].name());
        }
        design_scene.derivatives = order
            .iter()
            .map(|&i| design_scene.derivatives[i].clone())
            .collect();
        use crate::inverse::render_design::DesignMethod;
        let method = match d.method.as_str() {
            "adam" => DesignMethod::Adam,
            "lbfgs" => DesignMethod::Lbfgs,
            other => {
                return err(format!(
                    "design.method = {other:?}: must be \"adam\" (fresh photons every iteration) or \"lbfgs\" (held photons, a few parameters)"
                ));
            }
        };
        if method == DesignMethod::Lbfgs
            && let Some(i) = design_scene
                .derivatives
                .iter()
                .position(|d| matches!(d, Derivative::Medium(_)))
        {
            return err(format!(
                "design.parameters[{}] ({}): method = \"lbfgs\" holds the photons and follows their paths as the index field moves; a medium parameter is differentiated by its paths' scores instead, which a held sample's objective does not follow: design it with method = \"adam\"",
                order[i], d.parameters[order[i]].name
            ));
        }
        if !(1..=100_000).contains(&d.iterations) {
            return err(format!(
                "design.iterations = {}: must be within [1, 100000]",
                d.iterations
            ));
        }
        for (key, v) in [("photons", d.photons), ("verify_photons", d.verify_photons)] {
            if !(100..=1_000_000_000).contains(&v) {
                return err(format!("design.{key} = {v}: must be within [100, 1e9]"));
            }
        }
        if !(d.learning_rate.is_finite() && d.learning_rate > 0.0 && d.learning_rate <= 10.0) {
            return err(format!(
                "design.learning_rate = {}: must be within (0, 10]",
                d.learning_rate
            ));
        }
        Ok(Some(crate::inverse::render_design::RenderDesign {
            scene: design_scene,
            names: ordered,
            ranges,
            start,
            maximize,
            relative_to,
            method,
            iterations: d.iterations as usize,
            photons: d.photons,
            chunk: self.render.chunk.min(d.photons).max(1),
            seed: self.render.seed,
            learning_rate: d.learning_rate,
            verify_photons: d.verify_photons,
        }))
    }

    /// The index-field parameter `profiles[i].name` names, of the one volume (`part` `None`)
    /// or of volume `part` of several.
    fn field_derivative(
        &self,
        name: &str,
        volume: &Volume,
        part: Option<usize>,
    ) -> Result<FieldDerivative, String> {
        use crate::eikonal::{FieldParam, Profile};
        let bad = || {
            "index-field parameters are named profiles[i].name, e.g. profiles[0].n_max".to_string()
        };
        let rest = name.trim().strip_prefix("profiles[").ok_or_else(bad)?;
        let (index, param) = rest.split_once("].").ok_or_else(bad)?;
        let profile: usize = index.parse().map_err(|_| bad())?;
        let (profiles, list) = match (part, volume.field.bounds.parts()) {
            (Some(k), Some(parts)) => (&parts[k].profiles, "profiles"),
            _ => (&volume.field.profiles, "field.profiles"),
        };
        let prof = profiles
            .get(profile)
            .ok_or_else(|| format!("{list} has {} profile(s)", profiles.len()))?;
        let which = prof
            .param_index(param)
            .ok_or_else(|| format!("the {} profile has no parameter {param:?}", prof.kind()))?;
        if prof.dparam(DVec3::ZERO, which).is_none() {
            return Err(format!(
                "the {} profile's {param} has no derivative of the index",
                prof.kind()
            ));
        }
        // under a strobe the field holds an ultrasonic profile's amplitude times sin Ωt
        let scale = match (&self.modulation, prof) {
            (Some(ModulationConfig::Strobed { phase_deg }), Profile::Ultrasonic { .. })
                if which == 1 =>
            {
                phase_deg.to_radians().sin()
            }
            _ => 1.0,
        };
        let volume_key = part.map_or(String::new(), |k| format!("volume[{k}]."));
        Ok(FieldDerivative {
            param: FieldParam { profile, which },
            name: format!("{volume_key}profiles[{profile}].{param}"),
            scale,
            volume: part,
        })
    }

    /// What derivatives with respect to the index field need of the scene: photons that leave
    /// a convex volume for good (no surfaces), and sensors whose response does not jump as the
    /// light moves (targets and spots), with nothing estimated by connections.
    fn check_field_derivative(
        &self,
        key: &str,
        volume: &Volume,
        sensors: &[Sensor],
    ) -> Result<(), ConfigError> {
        let why = "the derivatives follow each photon's path as the field changes";
        let convex = match volume.field.bounds.parts() {
            Some(parts) => parts.iter().all(|p| p.shape.is_convex()),
            None => volume.field.bounds.is_convex(),
        };
        if !convex {
            return err(format!(
                "{key}: index-field derivatives need convex bounds (sphere, box, cylinder); {why}, and light leaving a non-convex shape may enter it again"
            ));
        }
        if !self.surface.is_empty() {
            return err(format!(
                "{key}: index-field derivatives are estimated without [[surface]]s; {why} to sensors and targets only"
            ));
        }
        for (i, s) in self.sensor.iter().enumerate() {
            let kind = match s {
                SensorConfig::Camera { filter, .. } if filter.is_box() => "camera",
                SensorConfig::Pinhole { filter, .. } if filter.is_box() => "pinhole",
                _ => continue,
            };
            return err(format!(
                "{key}: sensor[{i}] (kind = \"{kind}\") gives each connection to the pixel it lands in, and which pixel jumps as the light moves with the field (that share of the derivative is not estimated); give it filter = \"tent\" (pixels share what arrives bilinearly, continuously)"
            ));
        }
        let plane = |s: &&Sensor| s.region.is_none();
        if let Some(s) = sensors.iter().find(|s| !s.follows_light_continuously()) {
            let why = if s.kind == SensorKind::Screen {
                "gives each crossing to the pixel it falls in, and which pixel jumps as the light moves with the field (that share of the derivative is not estimated); give it filter = \"tent\" (pixels share crossings bilinearly, continuously)"
            } else {
                "has edges (its rectangle or acceptance cone, or the plane's own edge at grazing light), and which side of an edge light crosses jumps as the light moves with the field (that share of the derivative is not estimated); index-field derivatives are of targets (kind = \"target\"), fluence probes (kind = \"fluence\"), spots (kind = \"spot\": a Gaussian aperture) and screens with filter = \"tent\""
            };
            return err(format!("{key}: sensor {:?} {why}", s.name));
        }
        if self.transient.is_some()
            && let Some(p) = self.sensor.iter().find_map(|s| match s {
                SensorConfig::Fluence { name, .. } => Some(name),
                _ => None,
            })
        {
            return err(format!(
                "{key}: [transient] with fluence probe {p:?}: light arriving after the last time bin is not counted, an edge that moves with the field; index-field derivatives of a probe are of its time-integrated fluence: leave [transient] out"
            ));
        }
        if self.transient.is_some()
            && let Some(s) = sensors.iter().find(plane)
        {
            return err(format!(
                "{key}: [transient] with sensor {:?}: light arriving after the last time bin is not counted, an edge that moves with the field; index-field derivatives of a plane's light are of its time-integrated power: leave [transient] out",
                s.name
            ));
        }
        Ok(())
    }

    /// Path tracing renders cameras lit by a light it can connect to; bidirectional path
    /// tracing renders scenes with a camera.
    fn check_path_tracing(&self, scene: &RenderScene) -> Result<(), ConfigError> {
        let name = match scene.tracing {
            Tracing::Bidirectional => "bidirectional",
            _ => "path",
        };
        for (i, s) in self.sensor.iter().enumerate() {
            let kind = match s {
                SensorConfig::Pinhole { filter, .. } | SensorConfig::Camera { filter, .. } => {
                    if !filter.is_box() {
                        return err(format!(
                            "sensor[{i}].filter = \"tent\": render.estimator = \"{name}\" samples each pixel's own area (box filter); a tent-filtered camera is rendered by particle tracing (render.estimator = \"particle\")"
                        ));
                    }
                    continue;
                }
                SensorConfig::Target { .. } => "target",
                // the light subpaths record them, as particle tracing does
                _ if scene.tracing == Tracing::Bidirectional => continue,
                SensorConfig::Flux { .. } => "flux",
                SensorConfig::Spot { .. } => "spot",
                SensorConfig::Screen { .. } => "screen",
                SensorConfig::Fluence { .. } => "fluence",
            };
            return err(format!(
                "sensor[{i}].kind = \"{kind}\": render.estimator = \"{name}\" renders cameras only (kind = \"pinhole\" or \"camera\"); use the particle estimator for {kind} sensors"
            ));
        }
        if scene.pinholes.is_empty() && scene.cameras.is_empty() {
            return err(format!(
                "render.estimator = \"{name}\": no camera to trace paths from ([[sensor]] kind = \"pinhole\" or \"camera\")",
            ));
        }
        if scene.tracing == Tracing::Bidirectional {
            return Ok(());
        }
        if let Light::FocusedBeam { focus, .. } = scene.light {
            let volume = &scene.volume;
            if volume.field.bounds.contains(focus) && volume.homogeneous() && volume.index_matched()
            {
                return err(format!(
                    "light.focus = {:?}: the beam's rays meet at a point inside the index-matched volume, where the light's irradiance grows without bound and render.estimator = \"path\" would estimate it with unbounded variance; use render.estimator = \"bidirectional\" (its weights give the events near the focus to the light's own strategies) or \"particle\"",
                    focus.to_array()
                ));
            }
        }
        if let Light::Beam { center, radius, .. } | Light::FocusedBeam { center, radius, .. } =
            scene.light
        {
            // paths from the cameras connect to the beam's disc, from outside the volume
            if radius <= 0.0 {
                return err(format!(
                    "light.radius = {radius}: a beam of radius 0 is a single ray, which paths from the cameras never meet; give it a radius, or use render.estimator = \"particle\""
                ));
            }
            // its centre and 32 points of its rim, as the beam draws its start points
            let rim = (0..32).map(|k| scene.light.sample([1.0, k as f64 / 32.0, 0.0, 0.0]).0);
            if std::iter::once(center)
                .chain(rim)
                .any(|p| scene.volume.field.bounds.contains(p))
            {
                return err(format!(
                    "light.center = {:?}, light.radius = {radius}: render.estimator = \"{name}\" connects paths to a beam's disc outside the volume, and this one reaches inside it; move it out, or use render.estimator = \"particle\"",
                    center.to_array()
                ));
            }
        }
        Ok(())
    }

    fn light(&self) -> Result<Light, ConfigError> {
        Ok(match self.light {
            LightConfig::Beam {
                center,
                direction,
                radius,
                focus,
            } => {
                let center = finite("light.center", center)?;
                let direction = unit("light.direction", direction)?;
                if !(radius.is_finite() && radius >= 0.0) {
                    return err(format!("light.radius = {radius}: must be >= 0"));
                }
                match focus {
                    None => Light::Beam {
                        center,
                        direction,
                        radius,
                    },
                    Some(f) => {
                        let focus = finite("light.focus", f)?;
                        if (focus - center).dot(direction) <= 0.0 {
                            return err(format!(
                                "light.focus = {f:?}: must lie ahead of the beam's disc along light.direction"
                            ));
                        }
                        Light::FocusedBeam {
                            center,
                            direction,
                            radius,
                            focus,
                        }
                    }
                }
            }
            LightConfig::Point { position } => Light::Point {
                position: finite("light.position", position)?,
            },
            LightConfig::Spot {
                position,
                axis,
                half_angle_deg,
            } => {
                if !(half_angle_deg > 0.0 && half_angle_deg <= 180.0) {
                    return err(format!(
                        "light.half_angle_deg = {half_angle_deg}: must be within (0, 180]"
                    ));
                }
                Light::Spot {
                    position: finite("light.position", position)?,
                    axis: unit("light.axis", axis)?,
                    half_angle: half_angle_deg.to_radians(),
                }
            }
            LightConfig::Area {
                center,
                normal,
                size,
            } => {
                let normal = unit("light.normal", normal)?;
                for (a, v) in size.iter().enumerate() {
                    positive(&format!("light.size[{a}]"), *v)?;
                }
                Light::Area {
                    center: finite("light.center", center)?,
                    normal,
                    right: crate::math::orthonormal_basis(normal).0,
                    size,
                }
            }
        })
    }
}

/// A target's region: a sphere (`radius`) or a box (`size`), inside the volume.
fn target_region(
    i: usize,
    center: [f64; 3],
    radius: Option<f64>,
    size: Option<[f64; 3]>,
    volume: &Volume,
) -> Result<Region, ConfigError> {
    let key = |k: &str| format!("sensor[{i}].{k}");
    let center = finite(&key("center"), center)?;
    let region = match (radius, size) {
        (Some(r), None) => Region::Sphere {
            center,
            radius: positive(&key("radius"), r)?,
        },
        (None, Some(size)) => {
            for (a, v) in size.iter().enumerate() {
                positive(&key(&format!("size[{a}]")), *v)?;
            }
            Region::Box {
                center,
                half: DVec3::from_array(size) * 0.5,
            }
        }
        _ => {
            return err(format!(
                "sensor[{i}]: a target is a sphere (radius = r) or a box (size = [a, b, c]); give exactly one"
            ));
        }
    };
    if !volume.field.bounds.contains(center) {
        return err(format!(
            "sensor[{i}].center = {:?}: a target must lie inside the volume (field.bounds); its fluence is tallied inside",
            center.to_array()
        ));
    }
    Ok(region)
}

/// Sensor `i`, checked to lie outside the volume (it records light that has left it).
fn sensor(i: usize, s: &SensorConfig, volume: &Volume) -> Result<Sensor, ConfigError> {
    let key = |k: &str| format!("sensor[{i}].{k}");
    let mut acceptance = None;
    let mut window = None;
    let mut filter = Filter::Box;
    let (name, kind, center, normal, size, pixels) = match s {
        SensorConfig::Fluence { .. }
        | SensorConfig::Target { .. }
        | SensorConfig::Camera { .. }
        | SensorConfig::Pinhole { .. } => {
            return err("a fluence probe, target or camera is not a plane");
        }
        SensorConfig::Flux {
            name,
            center,
            normal,
            size,
            acceptance_deg,
        } => {
            if let Some(a) = *acceptance_deg {
                if !(a > 0.0 && a <= 90.0) {
                    return err(format!(
                        "sensor[{i}].acceptance_deg = {a}: must be within (0, 90]"
                    ));
                }
                acceptance = Some(a.to_radians());
            }
            (name, SensorKind::Flux, center, normal, *size, [1, 1])
        }
        SensorConfig::Spot {
            name,
            center,
            normal,
            radius,
        } => {
            window = Some(positive(&key("radius"), *radius)?);
            (name, SensorKind::Spot, center, normal, None, [1, 1])
        }
        SensorConfig::Screen {
            name,
            center,
            normal,
            size,
            pixels,
            filter: f,
        } => {
            filter = f.build();
            (
                name,
                SensorKind::Screen,
                center,
                normal,
                Some(*size),
                *pixels,
            )
        }
    };
    let center = finite(&key("center"), *center)?;
    let normal = unit(&key("normal"), *normal)?;
    if let Some(size) = size {
        for (a, v) in size.iter().enumerate() {
            positive(&key(&format!("size[{a}]")), *v)?;
        }
    }
    for (a, &p) in pixels.iter().enumerate() {
        if !(1..=MAX_PIXELS).contains(&p) {
            return err(format!(
                "{} = {p}: must be within [1, {MAX_PIXELS}]",
                key(&format!("pixels[{a}]"))
            ));
        }
    }
    outside_volume(
        &key("center"),
        center,
        normal,
        volume,
        "sensors record light after it leaves",
    )?;
    let mut sensor = Sensor::new(
        name.clone(),
        kind,
        center,
        normal,
        size,
        [pixels[0] as usize, pixels[1] as usize],
    );
    sensor.acceptance = acceptance;
    sensor.window = window;
    sensor.filter = filter;
    Ok(sensor)
}

/// Refuse a plane through `center` with unit `normal` that cuts the volume (`why` it must not).
fn outside_volume(
    key: &str,
    center: DVec3,
    normal: DVec3,
    volume: &Volume,
    why: &str,
) -> Result<(), ConfigError> {
    // the volume lies within x·n ≤ h(n) and x·n ≥ −h(−n)
    let offset = center.dot(normal);
    let (h_plus, h_minus) = (volume.support(normal), volume.support(-normal));
    let slack = 1e-9 * (1.0 + offset.abs());
    if offset < h_plus - slack && offset > -h_minus + slack {
        return err(format!(
            "{key} = {:?}: the plane cuts through the volume; {why}, so place it outside the field's bounds or on a face",
            center.to_array()
        ));
    }
    Ok(())
}

/// A surface from its keys.
fn surface(i: usize, s: &SurfaceConfig, volume: &Volume) -> Result<Surface, ConfigError> {
    let key = |k: &str| format!("surface[{i}].{k}");
    check_name(&key("name"), &s.name)?;
    let center = finite(&key("center"), s.center)?;
    let normal = unit(&key("normal"), s.normal)?;
    if let Some(size) = s.size {
        for (a, v) in size.iter().enumerate() {
            positive(&key(&format!("size[{a}]")), *v)?;
        }
    }
    if !(0.0..=1.0).contains(&s.albedo) {
        return err(format!(
            "{} = {}: must be within [0, 1] (0: black)",
            key("albedo"),
            s.albedo
        ));
    }
    outside_volume(
        &key("center"),
        center,
        normal,
        volume,
        "surfaces lie outside the volume",
    )?;
    Ok(Surface::new(
        s.name.clone(),
        center,
        normal,
        s.size,
        s.albedo,
    ))
}

/// A sensor's pixel counts.
fn check_pixels(i: usize, pixels: [u64; 2]) -> Result<[usize; 2], ConfigError> {
    for (a, &p) in pixels.iter().enumerate() {
        if !(1..=MAX_PIXELS).contains(&p) {
            return err(format!(
                "sensor[{i}].pixels[{a}] = {p}: must be within [1, {MAX_PIXELS}]"
            ));
        }
    }
    Ok([pixels[0] as usize, pixels[1] as usize])
}

/// Camera `i`'s windows (`sensor[i].window`) on its image of `pixels`, each name new among
/// `names` (the sensors' and windows' so far, which it joins): rows counted from the top in the
/// config, from the bottom in the estimate.
fn pixel_windows<'a>(
    i: usize,
    windows: &'a [WindowConfig],
    pixels: [usize; 2],
    names: &mut Vec<&'a str>,
) -> Result<Vec<crate::rrte::PixelWindow>, ConfigError> {
    let mut out = Vec::with_capacity(windows.len());
    for (k, w) in windows.iter().enumerate() {
        let key = |f: &str| format!("sensor[{i}].window[{k}].{f}");
        check_name(&key("name"), &w.name)?;
        if names.contains(&w.name.as_str()) {
            return err(format!(
                "{} = {:?}: a sensor or another window has this name (windows are named among the sensors: a design names them)",
                key("name"),
                w.name
            ));
        }
        names.push(&w.name);
        let mut ranges = [[0; 2]; 2];
        for (a, (field, [first, last])) in [("columns", w.columns), ("rows", w.rows)]
            .into_iter()
            .enumerate()
        {
            let n = pixels[a] as u64;
            if !(first <= last && last < n) {
                return err(format!(
                    "{} = [{first}, {last}]: give the first and last {} (0-based) with first <= last < {n}, the image's {}",
                    key(field),
                    &field[..field.len() - 1],
                    ["width", "height"][a]
                ));
            }
            ranges[a] = [first as usize, last as usize];
        }
        let height = pixels[1];
        let [columns, [top, bottom]] = ranges;
        out.push(crate::rrte::PixelWindow {
            name: w.name.clone(),
            columns,
            rows: [height - 1 - bottom, height - 1 - top],
        });
    }
    Ok(out)
}

/// A sensor's name: it names files.
fn check_name(key: &str, name: &str) -> Result<(), ConfigError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        err(format!(
            "{key} = {name:?}: use 1 to 64 letters, digits, '_' or '-'"
        ))
    }
}

/// Where `n` varies, the step must resolve the volume: at least 20 steps across its smallest
/// extent (rays that jump the volume in a few steps bend wrongly; `trace` has the same rule).
fn check_step(scene: &RenderScene) -> Result<(), ConfigError> {
    let v = &scene.volume;
    if v.homogeneous() {
        return Ok(());
    }
    let Some(half) = v.field.bounds.half_extent() else {
        return Ok(());
    };
    let size = 2.0 * half.min_element();
    // geometric length per step is n · step (σ-form): a ray must cross where n is smallest, and
    // the step resolve the volume where it is largest
    let n = check_positive(&v.field)?;
    let length = scene.step * n.max;
    let slowest = scene.step * n.min;
    let widest = 2.0 * half.max_element();
    if slowest * scene.max_steps as f64 <= widest {
        return err(format!(
            "render.step = {}: {} steps of about {slowest:.3e} (where n = {:.4}) cannot cross the volume ({widest:.3e} across); raise render.step or render.max_steps",
            scene.step, scene.max_steps, n.min
        ));
    }
    if length > size / 20.0 {
        return err(format!(
            "render.step = {}: about {length:.3e} per step against a volume {size:.3e} across; use a step of at most {:.3e} (20 steps across)",
            scene.step,
            size / 20.0 / n.max
        ));
    }
    Ok(())
}
