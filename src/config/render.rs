//! Configs of `lightpath render`: a refractive, scattering volume (`[field]` + `[medium]`), one
//! `[light]`, `[[sensor]]` planes outside the volume, optional `[transient]` bins and `[render]`
//! settings → [`RenderScene`].

use super::scene::{MediumConfig, positive, unit};
use super::trace::{FieldConfig, check_positive};
use super::{ConfigError, err};
use crate::eikonal::Bounds;
use crate::medium::{PhaseFunction, Scattering};
use crate::rrte::{
    Camera, Connections, Light, Modulation, Probe, RenderScene, Sensor, SensorKind, Transient,
    Volume,
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
    /// Bulk scattering inside the field's bounds (absent: a clear volume).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub medium: Option<MediumConfig>,
    pub light: LightConfig,
    #[serde(default)]
    pub sensor: Vec<SensorConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transient: Option<TransientConfig>,
    /// How the ultrasonic profiles' amplitudes change in time (absent: static).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulation: Option<ModulationConfig>,
    #[serde(default)]
    pub render: RenderSettings,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightConfig {
    /// A collimated laser beam, uniform over a disc (`radius = 0`: one ray).
    Beam {
        center: [f64; 3],
        direction: [f64; 3],
        #[serde(default)]
        radius: f64,
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
    /// Irradiance on a rectangle of pixels.
    Screen {
        name: String,
        center: [f64; 3],
        normal: [f64; 3],
        size: [f64; 2],
        pixels: [u64; 2],
    },
    /// Fluence rate at a point inside the volume, by connections along curved rays.
    Fluence { name: String, position: [f64; 3] },
    /// An orthographic camera: the radiance travelling along `direction` (it looks along
    /// `−direction`) over `size` about `center` in `pixels`, by connections through the surface.
    Camera {
        name: String,
        center: [f64; 3],
        direction: [f64; 3],
        size: [f64; 2],
        pixels: [u64; 2],
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
    },
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

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            samples: default_samples(),
            seed: default_seed(),
            chunk: default_chunk(),
            step: default_step(),
            max_steps: default_max_steps(),
            connections: ConnectionsConfig::Unbiased,
        }
    }
}

/// The most sensors, pixels per sensor side and time bins a render takes.
const MAX_SENSORS: usize = 64;
const MAX_PIXELS: u64 = 4096;
const MAX_BINS: u64 = 10_000;

fn finite(key: &str, v: [f64; 3]) -> Result<DVec3, ConfigError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(DVec3::from_array(v))
    } else {
        err(format!("{key} = {v:?}: must be finite"))
    }
}

impl RenderConfig {
    /// The scene these keys describe, every value checked.
    pub fn build(&self) -> Result<RenderScene, ConfigError> {
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
            Some(m) => {
                let base = field.clone();
                let ultrasonic = field
                    .profiles
                    .iter()
                    .any(|p| matches!(p, crate::eikonal::Profile::Ultrasonic { .. }));
                if !ultrasonic {
                    return err(
                        "modulation: the field has no ultrasonic profile whose amplitude could oscillate",
                    );
                }
                match *m {
                    ModulationConfig::Sinusoidal {} => {
                        // every phase must give a valid field: check the amplitude's sign flipped
                        crate::rrte::particle::modulate(&mut field, &base, -1.0);
                        check_positive(&field)?;
                        field = base;
                        Some(Modulation::Sinusoidal)
                    }
                    ModulationConfig::Strobed { phase_deg } => {
                        if !phase_deg.is_finite() || phase_deg.abs() > 360.0 {
                            return err(format!(
                                "modulation.phase_deg = {phase_deg}: must be within [-360, 360]"
                            ));
                        }
                        let s = phase_deg.to_radians().sin();
                        crate::rrte::particle::modulate(&mut field, &base, s);
                        None
                    }
                }
            }
        };
        check_positive(&field)?;
        field.n_out = positive("field.n_out", field.n_out)?;
        let (sigma_s, sigma_a, scattering) = match &self.medium {
            None => (0.0, 0.0, Scattering::single(PhaseFunction::Isotropic)),
            Some(m) => {
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
                let wavelength = match self.wavelength {
                    Some(w) => positive("wavelength", w)?,
                    None => f64::NAN,
                };
                let bulk = m.bulk(wavelength)?;
                if !(bulk.0.is_finite() && bulk.1.is_finite()) {
                    return err(
                        "wavelength: missing; Mie spheres need the wavelength (in the scene's length unit)",
                    );
                }
                bulk
            }
        };
        let volume = Volume {
            field,
            sigma_s,
            sigma_a,
            scattering,
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
                | SensorConfig::Screen { name, .. }
                | SensorConfig::Fluence { name, .. }
                | SensorConfig::Camera { name, .. }
                | SensorConfig::Pinhole { name, .. } => name,
            };
            check_name(i, name)?;
            if names.contains(&name.as_str()) {
                return err(format!(
                    "sensor[{i}].name = {name:?}: another sensor has this name"
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
                pinholes.push(camera);
            } else if let SensorConfig::Camera {
                name,
                center,
                direction,
                size,
                pixels,
            } = s
            {
                let key = |k: &str| format!("sensor[{i}].{k}");
                let direction = unit(&key("direction"), *direction)?;
                let center = finite(&key("center"), *center)?;
                for (a, v) in size.iter().enumerate() {
                    positive(&key(&format!("size[{a}]")), *v)?;
                }
                let pixels = check_pixels(i, *pixels)?;
                cameras.push(Camera::new(name.clone(), direction, center, *size, pixels));
            } else if let SensorConfig::Fluence { name, position } = s {
                let position = finite(&format!("sensor[{i}].position"), *position)?;
                if !volume.field.bounds.contains(position) {
                    return err(format!(
                        "sensor[{i}].position = {:?}: a fluence probe must lie inside the volume (field.bounds)",
                        position.to_array()
                    ));
                }
                probes.push(Probe {
                    name: name.clone(),
                    position,
                });
            } else {
                sensors.push(sensor(i, s, &volume)?);
            }
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
        let scene = RenderScene {
            volume,
            light,
            sensors,
            probes,
            cameras,
            pinholes,
            modulation,
            connections: match r.connections {
                ConnectionsConfig::Unbiased => Connections::Unbiased,
                ConnectionsConfig::First => Connections::First,
            },
            transient,
            step,
            max_steps: r.max_steps as usize,
        };
        check_step(&scene)?;
        Ok(scene)
    }

    fn light(&self) -> Result<Light, ConfigError> {
        Ok(match self.light {
            LightConfig::Beam {
                center,
                direction,
                radius,
            } => Light::Beam {
                center: finite("light.center", center)?,
                direction: unit("light.direction", direction)?,
                radius: if radius.is_finite() && radius >= 0.0 {
                    radius
                } else {
                    return err(format!("light.radius = {radius}: must be >= 0"));
                },
            },
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

/// Sensor `i`, checked to lie outside the volume (it records light that has left it).
fn sensor(i: usize, s: &SensorConfig, volume: &Volume) -> Result<Sensor, ConfigError> {
    let key = |k: &str| format!("sensor[{i}].{k}");
    let mut acceptance = None;
    let (name, kind, center, normal, size, pixels) = match s {
        SensorConfig::Fluence { .. }
        | SensorConfig::Camera { .. }
        | SensorConfig::Pinhole { .. } => {
            return err("a fluence probe or camera is not a plane");
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
        SensorConfig::Screen {
            name,
            center,
            normal,
            size,
            pixels,
        } => (
            name,
            SensorKind::Screen,
            center,
            normal,
            Some(*size),
            *pixels,
        ),
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
    // the volume lies within x·n ≤ h(n) and x·n ≥ −h(−n): the plane must not cut it
    let offset = center.dot(normal);
    let (h_plus, h_minus) = (volume.support(normal), volume.support(-normal));
    let slack = 1e-9 * (1.0 + offset.abs());
    if offset < h_plus - slack && offset > -h_minus + slack {
        return err(format!(
            "{} = {:?}: the sensor's plane cuts through the volume; sensors record light after it leaves, so place the plane outside the field's bounds or on a face",
            key("center"),
            center.to_array()
        ));
    }
    let mut sensor = Sensor::new(
        name.clone(),
        kind,
        center,
        normal,
        size,
        [pixels[0] as usize, pixels[1] as usize],
    );
    sensor.acceptance = acceptance;
    Ok(sensor)
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

/// A sensor's name: it names files.
fn check_name(i: usize, name: &str) -> Result<(), ConfigError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        err(format!(
            "sensor[{i}].name = {name:?}: use 1 to 64 letters, digits, '_' or '-' (it names the sensor's files)"
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
    let n_max = v.field.n_out.max(1.0);
    // geometric length per step is about n · step; n is of order n_out or the profile's values
    let length = scene.step * n_max;
    let widest = 2.0 * half.max_element();
    if length * scene.max_steps as f64 <= widest {
        return err(format!(
            "render.step = {}: {} steps of about {length:.3e} cannot cross the volume ({widest:.3e} across); raise render.step or render.max_steps",
            scene.step, scene.max_steps
        ));
    }
    if length > size / 20.0 {
        return err(format!(
            "render.step = {}: about {length:.3e} per step against a volume {size:.3e} across; use a step of at most {:.3e} (20 steps across)",
            scene.step,
            size / 20.0 / n_max
        ));
    }
    Ok(())
}
