//! Configs of `lightpath trace`: an index field and a bundle of rays.

use crate::config::ConfigError;
use crate::config::{err, finite, positive as pos, unit};
use crate::eikonal::{BoundedField, Bounds, Profile};
use glam::DVec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TraceConfig {
    pub field: FieldConfig,
    pub rays: RaysConfig,
    #[serde(default)]
    pub trace: TraceSettings,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FieldConfig {
    /// Profiles summed inside the bounds.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub profiles: Vec<ProfileConfig>,
    #[serde(default)]
    pub bounds: BoundsConfig,
    #[serde(default = "one")]
    pub n_out: f64,
}

fn one() -> f64 {
    1.0
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProfileConfig {
    Constant {
        n: f64,
    },
    Linear {
        n0: f64,
        gradient: [f64; 3],
    },
    Luneburg {
        radius: f64,
    },
    MaxwellFishEye {
        radius: f64,
    },
    ParabolicFibre {
        n0: f64,
        alpha: f64,
    },
    SechFibre {
        n0: f64,
        alpha: f64,
    },
    /// `n = n0 + Σ_k c_k ρ^{2k}` about the z axis (`coefficients = [c1, c2, …]`).
    RadialPolynomial {
        n0: f64,
        coefficients: Vec<f64>,
    },
    /// `n = n0 + Σ_k c_k r^k` about the origin (`coefficients = [c1, c2, …]`).
    SphericalPolynomial {
        n0: f64,
        coefficients: Vec<f64>,
    },
    /// `n = n0 + n_max J_m(k_r r) cos(m φ)` (paper 002, Eq. 15): `n_max` and `k_r` given, or
    /// in physical units from the peak `pressure` (Pa), `frequency` (Hz), `sound_speed` (m/s),
    /// the scene's `length_unit` and `piezo_optic` (dn/dp per pascal) or `density` (kg/m³, for
    /// the Lorentz–Lorenz relation).
    Ultrasonic {
        n0: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        n_max: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        k_r: Option<f64>,
        m: u64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pressure: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        frequency: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sound_speed: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        length_unit: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        piezo_optic: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        density: Option<f64>,
    },
    /// The index sculpted by a phased ultrasound array of line elements parallel to z, in
    /// physical units: `n = n0 + piezo_optic · Re[P(x) e^{−iΩt}]` (see `eikonal::acoustic`).
    PhasedArray {
        n0: f64,
        /// Hz.
        frequency: f64,
        /// m/s.
        sound_speed: f64,
        /// The scene's length unit: "m", "cm", "mm" or "um".
        length_unit: String,
        /// dn/dp per pascal; absent: from the Lorentz–Lorenz relation and `density`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        piezo_optic: Option<f64>,
        /// kg/m³ (only without `piezo_optic`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        density: Option<f64>,
        /// dB/(cm·MHz), linear in frequency (0: lossless).
        #[serde(default)]
        attenuation: f64,
        /// The distance from an element at which its amplitude is stated, scene units.
        reference_distance: f64,
        elements: Vec<ElementConfig>,
    },
    /// Samples on a regular grid (x fastest), interpolated tricubically (default) or trilinearly.
    Grid {
        dims: [u64; 3],
        origin: [f64; 3],
        spacing: f64,
        values: Vec<f64>,
        #[serde(default = "tricubic")]
        interp: String,
    },
    /// The grid of a `lightpath design` result (`design.json`).
    GridFile {
        path: String,
    },
    /// Luneburg-like, graded by the depth below the surface of a signed-distance `field.bounds`:
    /// `n_surface` on the surface to `n_core` at `depth` and beyond.
    SdfLuneburg {
        n_surface: f64,
        n_core: f64,
        depth: f64,
    },
}

/// One element of a phased array: a line source through `position` (x, y) parallel to z.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ElementConfig {
    pub position: [f64; 2],
    /// The pressure amplitude at the array's reference distance, Pa.
    pub amplitude: f64,
    #[serde(default)]
    pub phase_deg: f64,
}

/// The most elements a phased array may hold (each adds two Hankel functions to every
/// evaluation of n).
const MAX_ELEMENTS: usize = 256;

/// Metres per scene length unit.
fn metres_per_unit(k: &str, unit: &str) -> Result<f64, ConfigError> {
    match unit {
        "m" => Ok(1.0),
        "cm" => Ok(1e-2),
        "mm" => Ok(1e-3),
        "um" => Ok(1e-6),
        other => err(format!(
            "{k}.length_unit = \"{other}\": expected \"m\", \"cm\", \"mm\" or \"um\" (the scene's length unit)"
        )),
    }
}

/// `dn/dp` per pascal: given, or from the Lorentz–Lorenz relation and the density.
fn piezo_optic_of(
    k: &str,
    n0: f64,
    sound_speed: f64,
    given: Option<f64>,
    density: Option<f64>,
) -> Result<f64, ConfigError> {
    match (given, density) {
        (Some(c), None) if c.is_finite() => Ok(c),
        (Some(c), None) => err(format!(
            "{k}.piezo_optic = {c}: must be finite (dn/dp per pascal)"
        )),
        (None, Some(rho)) => Ok(crate::eikonal::acoustic::lorentz_lorenz(
            n0,
            pos(&format!("{k}.density"), rho)?,
            sound_speed,
        )),
        _ => err(format!(
            "{k}: give piezo_optic (dn/dp per pascal) or density (kg/m³, for the Lorentz–Lorenz relation), one of the two"
        )),
    }
}

/// The physical keys of an ultrasonic standing wave.
struct Physical<'a> {
    pressure: Option<f64>,
    frequency: Option<f64>,
    sound_speed: Option<f64>,
    length_unit: Option<&'a str>,
    piezo_optic: Option<f64>,
    density: Option<f64>,
}

/// `(n_max, k_r)` of Eq. 15: given as they are, or from the peak pressure, `n_max = (dn/dp)
/// p_max`, and the wavenumber `k_r = 2π f / c` (n does not vary along z, so the whole wave
/// vector is radial).
fn standing_wave(
    k: &str,
    n0: f64,
    n_max: Option<f64>,
    k_r: Option<f64>,
    p: &Physical,
) -> Result<(f64, f64), ConfigError> {
    let any_physical = p.pressure.is_some()
        || p.frequency.is_some()
        || p.sound_speed.is_some()
        || p.length_unit.is_some()
        || p.piezo_optic.is_some()
        || p.density.is_some();
    match (n_max, k_r, any_physical) {
        (Some(n_max), Some(k_r), false) => {
            if !n_max.is_finite() {
                return err(format!("{k}.n_max = {n_max}: must be finite"));
            }
            Ok((n_max, pos(&format!("{k}.k_r"), k_r)?))
        }
        (None, None, true) => {
            let need = |key: &str, v: Option<f64>| {
                v.ok_or_else(|| {
                    ConfigError(format!(
                        "{k}.{key}: missing (the physical form needs pressure, frequency, sound_speed and length_unit)"
                    ))
                })
            };
            let pressure = need("pressure", p.pressure)?;
            if !pressure.is_finite() {
                return err(format!("{k}.pressure = {pressure}: must be finite (Pa)"));
            }
            let frequency = pos(&format!("{k}.frequency"), need("frequency", p.frequency)?)?;
            let sound_speed = pos(
                &format!("{k}.sound_speed"),
                need("sound_speed", p.sound_speed)?,
            )?;
            let unit = metres_per_unit(
                k,
                p.length_unit.ok_or_else(|| {
                    ConfigError(format!(
                        "{k}.length_unit: missing (\"m\", \"cm\", \"mm\" or \"um\")"
                    ))
                })?,
            )?;
            let piezo = piezo_optic_of(k, n0, sound_speed, p.piezo_optic, p.density)?;
            Ok((
                piezo * pressure,
                std::f64::consts::TAU * frequency / sound_speed * unit,
            ))
        }
        _ => err(format!(
            "{k}: give n_max and k_r, or the physical pressure, frequency, sound_speed, length_unit and piezo_optic (or density); not a mix"
        )),
    }
}

/// Whether a phased array's element at `(x, y)` keeps its line (parallel to z) outside the
/// volume: its wave is singular on the line.
pub(crate) fn element_clear(bounds: &Bounds, x: f64, y: f64) -> bool {
    element_blocked(bounds, 0, y).is_none_or(|(a, b)| x < a || x > b)
}

/// The interval of an element's coordinate `axis` (0: x, 1: y) over which its line meets the
/// volume, its other coordinate at `other`; `None` if it meets it nowhere.
pub(crate) fn element_blocked(bounds: &Bounds, axis: usize, other: f64) -> Option<(f64, f64)> {
    match *bounds {
        Bounds::Everywhere => Some((f64::NEG_INFINITY, f64::INFINITY)),
        Bounds::Sphere { radius } | Bounds::Cylinder { radius, .. } => {
            let w = (radius * radius - other * other).max(0.0).sqrt();
            (other.abs() <= radius).then_some((-w, w))
        }
        _ => bounds.half_extent().and_then(|h| {
            let (along, across) = if axis == 0 { (h.x, h.y) } else { (h.y, h.x) };
            (other.abs() <= across).then_some((-along, along))
        }),
    }
}

/// A phased array's keys, checked: units converted, every element outside the bounds.
#[allow(clippy::too_many_arguments)]
fn phased_array(
    k: &str,
    n0: f64,
    frequency: f64,
    sound_speed: f64,
    length_unit: &str,
    piezo_optic: Option<f64>,
    density: Option<f64>,
    attenuation: f64,
    reference_distance: f64,
    elements: &[ElementConfig],
    bounds: &Bounds,
) -> Result<Profile, ConfigError> {
    use crate::eikonal::acoustic::{Element, PhasedArray, Ultrasound, nepers_per_metre_hertz};
    let n0 = pos(&format!("{k}.n0"), n0)?;
    let frequency = pos(&format!("{k}.frequency"), frequency)?;
    let sound_speed = pos(&format!("{k}.sound_speed"), sound_speed)?;
    let unit = metres_per_unit(k, length_unit)?;
    let piezo_optic = piezo_optic_of(k, n0, sound_speed, piezo_optic, density)?;
    if !(attenuation >= 0.0 && attenuation.is_finite()) {
        return err(format!(
            "{k}.attenuation = {attenuation}: must be finite and >= 0 (dB/(cm·MHz))"
        ));
    }
    if elements.is_empty() || elements.len() > MAX_ELEMENTS {
        return err(format!(
            "{k}.elements holds {} elements: give 1 to {MAX_ELEMENTS}",
            elements.len()
        ));
    }
    let clear = |x: f64, y: f64| element_clear(bounds, x, y);
    let mut array = Vec::with_capacity(elements.len());
    for (j, e) in elements.iter().enumerate() {
        let key = format!("{k}.elements[{j}]");
        let [x, y] = e.position;
        if !(x.is_finite() && y.is_finite()) {
            return err(format!("{key}.position = [{x}, {y}]: must be finite"));
        }
        if !clear(x, y) {
            return err(format!(
                "{key}.position = [{x}, {y}]: the element's line (parallel to z) meets field.bounds; place elements outside the volume"
            ));
        }
        if !(e.amplitude >= 0.0 && e.amplitude.is_finite()) {
            return err(format!(
                "{key}.amplitude = {}: must be finite and >= 0 (Pa)",
                e.amplitude
            ));
        }
        if !e.phase_deg.is_finite() {
            return err(format!("{key}.phase_deg = {}: must be finite", e.phase_deg));
        }
        array.push(Element {
            x,
            y,
            amplitude: e.amplitude,
            phase: e.phase_deg.to_radians(),
        });
    }
    Ok(Profile::PhasedArray {
        array: std::sync::Arc::new(PhasedArray {
            n0,
            piezo_optic,
            ultrasound: Ultrasound {
                frequency,
                sound_speed,
                attenuation: nepers_per_metre_hertz(attenuation),
                unit,
            },
            reference: pos(&format!("{k}.reference_distance"), reference_distance)?,
            gain: 1.0,
            elements: array,
        }),
        omega_t: std::f64::consts::FRAC_PI_2,
    })
}

fn tricubic() -> String {
    "tricubic".into()
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
// read once per config: the signed-distance variant's size costs nothing
#[allow(clippy::large_enum_variant)]
pub enum BoundsConfig {
    #[default]
    Everywhere,
    Sphere {
        radius: f64,
    },
    Cylinder {
        radius: f64,
        half_length: f64,
    },
    Box {
        size: [f64; 3],
    },
    /// Any closed shape by its signed distance (negative inside) on a grid: sampled from `shapes`
    /// (their smooth union over `blend`) or from a triangle `mesh` every `spacing`, or given as
    /// `values` at `dims` nodes from `origin` every `spacing` (x fastest), or read from `path` (a
    /// JSON file with those keys).
    Sdf {
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        shapes: Vec<ShapeConfig>,
        #[serde(default)]
        blend: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        spacing: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        dims: Option<[u64; 3]>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        origin: Option<[f64; 3]>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        values: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        path: Option<String>,
        /// A triangle mesh (OBJ, STL or PLY), scaled by `scale` about the origin and moved by
        /// `offset`, sampled every `spacing`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        mesh: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        scale: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        offset: Option<[f64; 3]>,
        #[serde(default = "tricubic")]
        interp: String,
    },
}

/// The keys of a signed-distance shape read from a mesh file.
struct MeshKeys<'a> {
    path: Option<&'a String>,
    scale: Option<f64>,
    offset: Option<[f64; 3]>,
}

/// A shape in closed form for a signed-distance `field.bounds`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ShapeConfig {
    Sphere {
        center: [f64; 3],
        radius: f64,
    },
    /// A ring: a tube of radius `minor` about the circle of radius `major` around `axis`.
    Torus {
        center: [f64; 3],
        #[serde(default = "z_axis")]
        axis: [f64; 3],
        major: f64,
        minor: f64,
    },
    /// A box of full `size`, its edges rounded by `rounding`.
    Box {
        center: [f64; 3],
        size: [f64; 3],
        #[serde(default)]
        rounding: f64,
    },
    /// The points within `radius` of the segment `from`–`to`.
    Capsule {
        from: [f64; 3],
        to: [f64; 3],
        radius: f64,
    },
}

fn z_axis() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

/// The most nodes of a signed-distance grid (2²⁴, 256³: 128 MB of samples).
const MAX_SDF_NODES: f64 = 16_777_216.0;

/// A signed-distance grid in a JSON file: the keys of inline `values`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SdfFile {
    dims: [u64; 3],
    origin: [f64; 3],
    spacing: f64,
    values: Vec<f64>,
}

/// The shape of `field.bounds.kind = "sdf"`, checked.
#[allow(clippy::too_many_arguments)]
fn sdf_bounds(
    shapes: &[ShapeConfig],
    blend: f64,
    spacing: Option<f64>,
    dims: Option<[u64; 3]>,
    origin: Option<[f64; 3]>,
    values: Option<&Vec<f64>>,
    path: Option<&String>,
    mesh: MeshKeys,
    interp: &str,
) -> Result<Bounds, ConfigError> {
    use crate::eikonal::sdf::{SdfGrid, Shape, sample_shapes};
    const K: &str = "field.bounds";
    let interp = interpolation(K, interp)?;
    let sources = [
        !shapes.is_empty(),
        values.is_some(),
        path.is_some(),
        mesh.path.is_some(),
    ];
    if sources.iter().filter(|s| **s).count() != 1 {
        return err(format!(
            "{K}: give the shape once: as shapes = [...] (with spacing), as mesh = an OBJ, STL or PLY file (with spacing), as values (with dims, origin and spacing), or as path = a JSON file of dims, origin, spacing and values"
        ));
    }
    if mesh.path.is_none() && (mesh.scale.is_some() || mesh.offset.is_some()) {
        return err(format!(
            "{K}: scale and offset place a mesh; give mesh = an OBJ, STL or PLY file, or drop them"
        ));
    }
    let (origin, spacing, dims, samples) = if let Some(file) = mesh.path {
        let spacing = pos(
            &format!("{K}.spacing"),
            spacing.ok_or_else(|| {
                ConfigError(format!(
                    "{K}.spacing: missing (the grid step the mesh's distance is sampled at)"
                ))
            })?,
        )?;
        if blend != 0.0 {
            return err(format!("{K}.blend = {blend}: only for shapes"));
        }
        if dims.is_some() || origin.is_some() {
            return err(format!(
                "{K}: dims and origin are set from the mesh's extent; give only spacing"
            ));
        }
        let scale = pos(&format!("{K}.scale"), mesh.scale.unwrap_or(1.0))?;
        let offset = finite(&format!("{K}.offset"), mesh.offset.unwrap_or([0.0; 3]))?;
        let m = super::mesh::read_mesh(file)
            .map_err(|e| ConfigError(format!("{K}.mesh = \"{file}\": {e}")))?
            .transformed(scale, offset);
        let (lo, hi) = m.extent();
        let nodes = ((hi - lo) / spacing + DVec3::splat(7.0)).element_product();
        if nodes.is_nan() || nodes > MAX_SDF_NODES {
            return err(format!(
                "{K}.spacing = {spacing}: the mesh spans {:?} to {:?}, about {nodes:.3e} grid nodes; at most {MAX_SDF_NODES:e} (256³): use a coarser spacing",
                lo.to_array(),
                hi.to_array()
            ));
        }
        let (origin, dims, samples) = m.signed_distance_grid(spacing);
        (origin, spacing, dims, samples)
    } else if !shapes.is_empty() {
        let spacing = pos(
            &format!("{K}.spacing"),
            spacing.ok_or_else(|| {
                ConfigError(format!(
                    "{K}.spacing: missing (the grid step the shapes are sampled at)"
                ))
            })?,
        )?;
        if !(blend.is_finite() && blend >= 0.0) {
            return err(format!("{K}.blend = {blend}: must be ≥ 0 and finite"));
        }
        if dims.is_some() || origin.is_some() {
            return err(format!(
                "{K}: dims and origin are set from the shapes' extent; give only spacing"
            ));
        }
        let mut built = Vec::new();
        for (i, s) in shapes.iter().enumerate() {
            let k = format!("{K}.shapes[{i}]");
            built.push(match *s {
                ShapeConfig::Sphere { center, radius } => Shape::Sphere {
                    center: finite(&format!("{k}.center"), center)?,
                    radius: pos(&format!("{k}.radius"), radius)?,
                },
                ShapeConfig::Torus {
                    center,
                    axis,
                    major,
                    minor,
                } => Shape::Torus {
                    center: finite(&format!("{k}.center"), center)?,
                    axis: unit(&format!("{k}.axis"), axis)?,
                    major: pos(&format!("{k}.major"), major)?,
                    minor: pos(&format!("{k}.minor"), minor)?,
                },
                ShapeConfig::Box {
                    center,
                    size,
                    rounding,
                } => {
                    for (a, v) in size.iter().enumerate() {
                        pos(&format!("{k}.size[{a}]"), *v)?;
                    }
                    let half = DVec3::from_array(size) * 0.5;
                    if !(rounding.is_finite() && rounding >= 0.0 && rounding <= half.min_element())
                    {
                        return err(format!(
                            "{k}.rounding = {rounding}: must be within [0, {}] (half the smallest size)",
                            half.min_element()
                        ));
                    }
                    Shape::Box {
                        center: finite(&format!("{k}.center"), center)?,
                        half,
                        rounding,
                    }
                }
                ShapeConfig::Capsule { from, to, radius } => Shape::Capsule {
                    from: finite(&format!("{k}.from"), from)?,
                    to: finite(&format!("{k}.to"), to)?,
                    radius: pos(&format!("{k}.radius"), radius)?,
                },
            });
        }
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for s in &built {
            let (a, b) = s.extent();
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let nodes =
            ((hi - lo + DVec3::splat(2.0 * blend)) / spacing + DVec3::splat(7.0)).element_product();
        if nodes.is_nan() || nodes > MAX_SDF_NODES {
            return err(format!(
                "{K}.spacing = {spacing}: the shapes span {:?} to {:?}, about {nodes:.3e} grid nodes; at most {MAX_SDF_NODES:e} (256³): use a coarser spacing",
                lo.to_array(),
                hi.to_array()
            ));
        }
        let (origin, dims, samples) = sample_shapes(&built, blend, spacing);
        (origin, spacing, dims, samples)
    } else {
        if blend != 0.0 {
            return err(format!("{K}.blend = {blend}: only for shapes"));
        }
        let (dims, origin, spacing, values, key) = match path {
            Some(p) => {
                let key = format!("{K}.path = \"{p}\"");
                let text = std::fs::read_to_string(p)
                    .map_err(|e| ConfigError(format!("{key}: cannot read: {e}")))?;
                let f: SdfFile = serde_json::from_str(&text).map_err(|e| {
                    ConfigError(format!(
                        "{key}: not a signed-distance grid (a JSON object of dims, origin, spacing and values): {e}"
                    ))
                })?;
                if spacing.is_some() || dims.is_some() || origin.is_some() {
                    return err(format!(
                        "{K}: the file gives dims, origin and spacing; do not give them here too"
                    ));
                }
                (f.dims, f.origin, f.spacing, f.values, key)
            }
            None => {
                let missing = |what: &str| {
                    ConfigError(format!(
                        "{K}.{what}: missing (values need dims, origin and spacing)"
                    ))
                };
                (
                    dims.ok_or_else(|| missing("dims"))?,
                    origin.ok_or_else(|| missing("origin"))?,
                    spacing.ok_or_else(|| missing("spacing"))?,
                    values.cloned().unwrap_or_default(),
                    format!("{K}.values"),
                )
            }
        };
        let spacing = pos(&format!("{K}.spacing"), spacing)?;
        let origin = finite(&format!("{K}.origin"), origin)?;
        if dims.iter().map(|&d| d as f64).product::<f64>() > MAX_SDF_NODES {
            return err(format!(
                "{K}.dims = {dims:?}: at most {MAX_SDF_NODES:e} nodes (256³)"
            ));
        }
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return err(format!("{key}: {v} is not a finite number"));
        }
        (origin, spacing, dims.map(|d| d as usize), values)
    };
    let grid = SdfGrid::from_samples(origin, spacing, dims, samples, interp)
        .map_err(|e| ConfigError(format!("{K}: {e}")))?;
    Ok(Bounds::Sdf(std::sync::Arc::new(grid)))
}

/// A bundle of rays: a collimated line of `count` rays across `width` through `center`, or a fan
/// from `origin` spanning `half_angle_deg` about `axis`; both in the x-z plane about the axis.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RaysConfig {
    Collimated {
        center: [f64; 3],
        direction: [f64; 3],
        width: f64,
        count: u64,
    },
    Fan {
        origin: [f64; 3],
        axis: [f64; 3],
        half_angle_deg: f64,
        count: u64,
    },
}

/// The most profiles a field may sum.
const MAX_PROFILES: usize = 64;

/// The largest `k_r · r` of an ultrasonic profile inside its bounds (about as many plane waves per
/// evaluation; 10⁵ wavelengths across is far beyond any acousto-optic lens).
const MAX_BESSEL_ARGUMENT: f64 = 1e5;

/// The `[trace]` table of every GRIN config: the leapfrog step and when a ray stops.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TraceSettings {
    #[serde(default = "default_step")]
    pub step: f64,
    /// Leapfrog steps per ray, fixed (grid designs only; rays must have left the bounds by then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    /// Without `steps`: rays are traced to where they leave the bounds (refracting where `n` jumps),
    /// at most this many steps (default 1 000 000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_steps: Option<u64>,
}

fn default_step() -> f64 {
    0.005
}

impl Default for TraceSettings {
    fn default() -> Self {
        TraceSettings {
            step: default_step(),
            steps: None,
            max_steps: None,
        }
    }
}

/// How rays are stepped: `(step, steps, to_exit)` — `steps` fixed, or at most `steps` to the exit.
pub type Stepping = (f64, usize, bool);

impl TraceSettings {
    /// The checked stepping: a fixed count (`steps`) or to the exit (`max_steps`).
    pub fn stepping(&self) -> Result<Stepping, ConfigError> {
        let step = pos("trace.step", self.step)?;
        match (self.steps, self.max_steps) {
            (Some(_), Some(_)) => err(
                "trace: give either steps (a fixed number per ray) or max_steps (trace to the exit), not both",
            ),
            (Some(s), None) if (1..=100_000).contains(&s) => Ok((step, s as usize, false)),
            (Some(s), None) => err(format!("trace.steps = {s}: must be within [1, 100000]")),
            (None, m) => {
                let m = m.unwrap_or(1_000_000);
                if !(1..=10_000_000).contains(&m) {
                    return err(format!(
                        "trace.max_steps = {m}: must be within [1, 10000000]"
                    ));
                }
                Ok((step, m as usize, true))
            }
        }
    }

    /// The checked stepping of commands that trace every ray to its exit: `(step, max_steps)`.
    pub fn to_exit(&self, command: &str) -> Result<(f64, usize), ConfigError> {
        match self.stepping()? {
            (step, max_steps, true) => Ok((step, max_steps)),
            (_, s, false) => err(format!(
                "trace.steps = {s}: {command} traces every ray to where it leaves the field; give max_steps instead"
            )),
        }
    }
}

impl FieldConfig {
    /// Make grid-file paths relative to the config file's folder.
    pub fn resolve_paths(&mut self, config: &std::path::Path) {
        let dir = config.parent().unwrap_or(std::path::Path::new(""));
        for p in &mut self.profiles {
            if let ProfileConfig::GridFile { path } = p {
                *path = dir.join(&*path).to_string_lossy().into_owned();
            }
        }
        if let BoundsConfig::Sdf { path, mesh, .. } = &mut self.bounds {
            for file in [path, mesh].into_iter().flatten() {
                *file = dir.join(&*file).to_string_lossy().into_owned();
            }
        }
    }

    /// The field these keys describe (profiles may be empty: `n = 0 + …` inside, for a design's
    /// background), each value checked.
    pub fn build(&self) -> Result<BoundedField, ConfigError> {
        let f = self;
        if f.profiles.len() > MAX_PROFILES {
            return err(format!(
                "field.profiles holds {} profiles: at most {MAX_PROFILES} (each adds to every evaluation of n)",
                f.profiles.len()
            ));
        }
        let bounds = match f.bounds {
            BoundsConfig::Everywhere => Bounds::Everywhere,
            BoundsConfig::Sphere { radius } => Bounds::Sphere {
                radius: pos("field.bounds.radius", radius)?,
            },
            BoundsConfig::Cylinder {
                radius,
                half_length,
            } => Bounds::Cylinder {
                radius: pos("field.bounds.radius", radius)?,
                half_length: pos("field.bounds.half_length", half_length)?,
            },
            BoundsConfig::Box { size } => {
                for (a, v) in size.iter().enumerate() {
                    pos(&format!("field.bounds.size[{a}]"), *v)?;
                }
                Bounds::Box {
                    half: DVec3::from_array(size) * 0.5,
                }
            }
            BoundsConfig::Sdf {
                ref shapes,
                blend,
                spacing,
                dims,
                origin,
                ref values,
                ref path,
                ref mesh,
                scale,
                offset,
                ref interp,
            } => sdf_bounds(
                shapes,
                blend,
                spacing,
                dims,
                origin,
                values.as_ref(),
                path.as_ref(),
                MeshKeys {
                    path: mesh.as_ref(),
                    scale,
                    offset,
                },
                interp,
            )?,
        };
        let mut profiles = Vec::new();
        for (i, p) in f.profiles.iter().enumerate() {
            let k = format!("field.profiles[{i}]");
            profiles.push(match *p {
                ProfileConfig::Constant { n } => Profile::Constant { n },
                ProfileConfig::Linear { n0, gradient } => Profile::Linear {
                    n0,
                    gradient: DVec3::from_array(gradient),
                },
                ProfileConfig::Luneburg { radius } => Profile::Luneburg {
                    radius: pos(&format!("{k}.radius"), radius)?,
                },
                ProfileConfig::MaxwellFishEye { radius } => Profile::MaxwellFishEye {
                    radius: pos(&format!("{k}.radius"), radius)?,
                },
                ProfileConfig::ParabolicFibre { n0, alpha } => Profile::ParabolicFibre {
                    n0: pos(&format!("{k}.n0"), n0)?,
                    alpha: pos(&format!("{k}.alpha"), alpha)?,
                },
                ProfileConfig::SechFibre { n0, alpha } => Profile::SechFibre {
                    n0: pos(&format!("{k}.n0"), n0)?,
                    alpha: pos(&format!("{k}.alpha"), alpha)?,
                },
                ProfileConfig::Ultrasonic {
                    n0,
                    n_max,
                    k_r,
                    m,
                    pressure,
                    frequency,
                    sound_speed,
                    ref length_unit,
                    piezo_optic,
                    density,
                } => {
                    if m > 64 {
                        return err(format!("{k}.m = {m}: must be within [0, 64]"));
                    }
                    let n0 = pos(&format!("{k}.n0"), n0)?;
                    let physical = Physical {
                        pressure,
                        frequency,
                        sound_speed,
                        length_unit: length_unit.as_deref(),
                        piezo_optic,
                        density,
                    };
                    let (n_max, k_r) = standing_wave(&k, n0, n_max, k_r, &physical)?;
                    Profile::Ultrasonic {
                        n0,
                        n_max,
                        k_r,
                        m: m as u32,
                    }
                }
                ProfileConfig::PhasedArray {
                    n0,
                    frequency,
                    sound_speed,
                    ref length_unit,
                    piezo_optic,
                    density,
                    attenuation,
                    reference_distance,
                    ref elements,
                } => phased_array(
                    &k,
                    n0,
                    frequency,
                    sound_speed,
                    length_unit,
                    piezo_optic,
                    density,
                    attenuation,
                    reference_distance,
                    elements,
                    &bounds,
                )?,
                ProfileConfig::RadialPolynomial {
                    n0,
                    ref coefficients,
                } => Profile::RadialPolynomial {
                    n0: pos(&format!("{k}.n0"), n0)?,
                    coefficients: polynomial(&k, coefficients)?,
                },
                ProfileConfig::SphericalPolynomial {
                    n0,
                    ref coefficients,
                } => Profile::SphericalPolynomial {
                    n0: pos(&format!("{k}.n0"), n0)?,
                    coefficients: polynomial(&k, coefficients)?,
                },
                ProfileConfig::Grid {
                    dims,
                    origin,
                    spacing,
                    ref values,
                    ref interp,
                } => grid_profile(&k, dims, origin, spacing, values.clone(), interp)?,
                ProfileConfig::GridFile { ref path } => grid_file(&k, path)?,
                ProfileConfig::SdfLuneburg {
                    n_surface,
                    n_core,
                    depth,
                } => {
                    let Bounds::Sdf(ref sdf) = bounds else {
                        return err(format!(
                            "{k}: sdf_luneburg grades n by the depth below a signed-distance shape's surface; give field.bounds.kind = \"sdf\""
                        ));
                    };
                    Profile::SdfLuneburg {
                        sdf: sdf.clone(),
                        n_surface: pos(&format!("{k}.n_surface"), n_surface)?,
                        n_core: pos(&format!("{k}.n_core"), n_core)?,
                        depth: pos(&format!("{k}.depth"), depth)?,
                    }
                }
            });
        }
        // the ultrasonic harmonic is a sum of ~k_r·r plane waves (eikonal::bessel): bound its cost
        let r_max = match bounds {
            Bounds::Everywhere => None,
            Bounds::Sphere { radius } | Bounds::Cylinder { radius, .. } => Some(radius),
            Bounds::Box { half } => Some(half.x.hypot(half.y)),
            Bounds::Sdf(_) | Bounds::Parts(_) => bounds.half_extent().map(|h| h.x.hypot(h.y)),
        };
        if let Some(r_max) = r_max {
            for (i, p) in profiles.iter().enumerate() {
                if let Profile::Ultrasonic { k_r, .. } = p
                    && k_r * r_max > MAX_BESSEL_ARGUMENT
                {
                    return err(format!(
                        "field.profiles[{i}].k_r = {k_r} within {r_max:.4e} of the axis (field.bounds): k_r·r reaches {:.3e}, beyond {MAX_BESSEL_ARGUMENT:e} (each evaluation sums ~k_r·r plane waves); check the units of k_r and field.bounds",
                        k_r * r_max
                    ));
                }
            }
        }
        let field = BoundedField {
            profiles,
            bounds,
            n_out: pos("field.n_out", f.n_out)?,
            scale: 1.0,
            offset: 0.0,
        };
        Ok(field)
    }
}

/// A polynomial profile's coefficients, checked: finite, at most 16.
fn polynomial(key: &str, coefficients: &[f64]) -> Result<Vec<f64>, ConfigError> {
    if let Some(c) = coefficients.iter().find(|c| !c.is_finite()) {
        return err(format!("{key}.coefficients: {c} is not a finite number"));
    }
    if coefficients.len() > 16 {
        return err(format!(
            "{key}.coefficients: {} given, at most 16",
            coefficients.len()
        ));
    }
    Ok(coefficients.to_vec())
}

/// A grid's interpolation from its name (`key.interp` in messages).
pub(crate) fn interpolation(
    key: &str,
    name: &str,
) -> Result<crate::eikonal::grid::Interp, ConfigError> {
    use crate::eikonal::grid::Interp;
    match name {
        "tricubic" => Ok(Interp::Tricubic),
        "trilinear" => Ok(Interp::Trilinear),
        other => err(format!(
            "{key}.interp = \"{other}\": must be \"tricubic\" or \"trilinear\""
        )),
    }
}

/// A grid profile from its keys (`key` names it in messages).
pub(crate) fn grid_profile(
    key: &str,
    dims: [u64; 3],
    origin: [f64; 3],
    spacing: f64,
    values: Vec<f64>,
    interp: &str,
) -> Result<Profile, ConfigError> {
    use crate::eikonal::grid::GridField;
    let interp = interpolation(key, interp)?;
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return err(format!("{key}.values: {v} is not a finite number"));
    }
    if origin.iter().any(|o| !o.is_finite()) {
        return err(format!("{key}.origin = {origin:?}: must be finite"));
    }
    if dims.iter().any(|&d| d > 4096) {
        return err(format!(
            "{key}.dims = {dims:?}: at most 4096 nodes per axis"
        ));
    }
    let dims = dims.map(|d| d as usize);
    GridField::from_samples(DVec3::from_array(origin), spacing, dims, values, interp)
        .map(Profile::Grid)
        .map_err(|e| ConfigError(format!("{key}: {e}")))
}

/// The designed grid: its coefficients (what the optimiser moved) and its samples (what
/// `grid_file` profiles read back).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct GridRecord {
    pub dims: [u64; 3],
    pub origin: [f64; 3],
    pub spacing: f64,
    pub interp: String,
    pub samples: Vec<f64>,
    pub coefficients: Vec<f64>,
}

/// The grid written by `lightpath design` to `design.json` (its key `grid`, a [`GridRecord`]).
fn grid_file(key: &str, path: &str) -> Result<Profile, ConfigError> {
    #[derive(Deserialize)]
    struct Design {
        grid: GridRecord,
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError(format!("{key}.path = \"{path}\": cannot read: {e}")))?;
    let g = serde_json::from_str::<Design>(&text)
        .map_err(|e| {
            ConfigError(format!(
                "{key}.path = \"{path}\": not a design result with a grid: {e}"
            ))
        })?
        .grid;
    grid_profile(key, g.dims, g.origin, g.spacing, g.samples, &g.interp)
}

impl TraceConfig {
    /// The field, checked: `n > 0` at every sample of a coarse grid over the bounds (or where rays run).
    pub fn field(&self) -> Result<BoundedField, ConfigError> {
        if self.field.profiles.is_empty() {
            return err("field.profiles = []: give at least one profile");
        }
        let field = self.field.build()?;
        let n = check_positive(&field)?;
        if let Ok((step, max_steps)) = self.trace.to_exit("trace") {
            check_stepping(&field, n, step, max_steps)?;
        }
        Ok(field)
    }

    /// Ray origins and unit directions.
    pub fn rays(&self) -> Result<Vec<(DVec3, DVec3)>, ConfigError> {
        let count = |c: u64| {
            if (1..=100_000).contains(&c) {
                Ok(c as usize)
            } else {
                err(format!("rays.count = {c}: must be within [1, 100000]"))
            }
        };
        match self.rays {
            RaysConfig::Collimated {
                center,
                direction,
                width,
                count: c,
            } => {
                let d = unit("rays.direction", direction)?;
                let w = if width.is_finite() && width >= 0.0 {
                    width
                } else {
                    return err(format!("rays.width = {width}: must be >= 0"));
                };
                let n = count(c)?;
                let (e1, _) = crate::math::orthonormal_basis(d);
                let c0 = finite("rays.center", center)?;
                Ok((0..n)
                    .map(|i| {
                        (
                            c0 + e1
                                * (w * (if n == 1 {
                                    0.0
                                } else {
                                    i as f64 / (n - 1) as f64 - 0.5
                                })),
                            d,
                        )
                    })
                    .collect())
            }
            RaysConfig::Fan {
                origin,
                axis,
                half_angle_deg,
                count: c,
            } => {
                let a = unit("rays.axis", axis)?;
                if !(half_angle_deg.is_finite() && (0.0..180.0).contains(&half_angle_deg)) {
                    return err(format!(
                        "rays.half_angle_deg = {half_angle_deg}: must be within [0, 180)"
                    ));
                }
                let n = count(c)?;
                let o = finite("rays.origin", origin)?;
                let (e1, _) = crate::math::orthonormal_basis(a);
                let rot_axis = a.cross(e1).normalize();
                Ok((0..n)
                    .map(|i| {
                        let t = if n == 1 {
                            0.0
                        } else {
                            2.0 * i as f64 / (n - 1) as f64 - 1.0
                        };
                        (
                            o,
                            crate::math::rotate(a, rot_axis, (t * half_angle_deg).to_radians()),
                        )
                    })
                    .collect())
            }
        }
    }
}

/// The smallest and largest index inside a field's bounds, sampled on a 17³ grid (the largest
/// includes `n_out`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct IndexRange {
    pub min: f64,
    pub max: f64,
}

/// `n > 0` and finite at every node of a 17³ grid over the field's bounds (rays are checked again
/// along their paths); the range of `n` found.
pub(crate) fn check_positive(field: &BoundedField) -> Result<IndexRange, ConfigError> {
    use crate::eikonal::IndexField;
    let mut largest = field.n_out;
    let mut smallest = f64::INFINITY;
    let Some(half) = field.bounds.half_extent() else {
        return Ok(IndexRange {
            min: largest,
            max: largest,
        });
    };
    let m = 16;
    for i in 0..=m {
        for j in 0..=m {
            for k in 0..=m {
                let x =
                    (DVec3::new(i as f64, j as f64, k as f64) / m as f64 * 2.0 - DVec3::ONE) * half;
                if !field.bounds.contains(x) {
                    continue;
                }
                let n = field.n(x);
                if !(n > 0.0 && n.is_finite()) {
                    return err(format!(
                        "field: n = {n} at {x}: the refractive index must be positive and finite inside the bounds"
                    ));
                }
                largest = largest.max(n);
                smallest = smallest.min(n);
            }
        }
    }
    Ok(IndexRange {
        min: smallest.min(largest),
        max: largest,
    })
}

/// The fewest leapfrog steps a ray may take across the field's largest extent.
pub(crate) const MIN_STEPS_ACROSS: f64 = 20.0;

/// The step rule of the commands that trace rays to where they leave the field: in the σ-form a
/// step runs `n · step` of geometric length, so with `n` up to `n.max` the step must resolve the
/// field (at least [`MIN_STEPS_ACROSS`] steps across its largest extent) and `max_steps` steps
/// must be able to cross it where `n` is smallest.
pub(crate) fn check_stepping(
    field: &BoundedField,
    n: IndexRange,
    step: f64,
    max_steps: usize,
) -> Result<(), ConfigError> {
    let Some(size) = field.bounds.half_extent().map(|h| 2.0 * h.max_element()) else {
        return Ok(());
    };
    let n_max = n.max;
    let length = step * n_max;
    if length > size / MIN_STEPS_ACROSS {
        return err(format!(
            "trace.step = {step} is too coarse for a field {size:.3e} across with n up to {n_max:.4}: a step runs n · step ≈ {length:.3e}, so a ray would take fewer than {MIN_STEPS_ACROSS} steps through it and could not follow the index; use a step of at most {:.3e}",
            size / MIN_STEPS_ACROSS / n_max
        ));
    }
    let slowest = step * n.min * max_steps as f64;
    if slowest < size {
        return err(format!(
            "trace.step = {step} × max_steps = {max_steps} covers a path of about {slowest:.3e} where n = {:.4}, shorter than the field ({size:.3e} across): a ray there could not cross it; raise trace.max_steps or the step",
            n.min
        ));
    }
    Ok(())
}
