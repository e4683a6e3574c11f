//! Configs of `lightpath design`: bounds and background of the index field, the designed grid
//! (levels coarse to fine), collimated beams with their foci, and the optimiser settings.

use crate::config::ConfigError;
use crate::config::trace::FieldConfig;
use crate::config::{err, positive as pos, unit};
use crate::inverse::grin_design::{Beam, FocusDesign};
use glam::DVec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DesignConfig {
    pub field: FieldConfig,
    pub grid: GridConfig,
    pub beam: Vec<BeamConfig>,
    pub trace: crate::config::trace::TraceSettings,
    pub design: OptimiserConfig,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GridConfig {
    /// Nodes per side at each level, coarse to fine.
    pub levels: Vec<u64>,
    #[serde(default = "tricubic")]
    pub interp: String,
    /// Starting value of the grid's own contribution to `n`.
    pub initial: f64,
}

fn tricubic() -> String {
    "tricubic".into()
}

/// A beam: `count × count` rays on a square lattice across the unit disk, mapped to positions
/// `center + radius·(u e1 + w e2)` and directions `direction + tan(half_angle)·(u e1 + w e2)` —
/// collimated (`half_angle_deg = 0`), a cone from a point (`radius = 0`) or both; all meant to
/// pass through `focus`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BeamConfig {
    pub center: [f64; 3],
    pub direction: [f64; 3],
    #[serde(default)]
    pub radius: f64,
    #[serde(default)]
    pub half_angle_deg: f64,
    pub count: u64,
    pub focus: [f64; 3],
}

/// The beams of a design or fit config, every value checked.
/// The most beams a design traces.
const MAX_BEAMS: usize = 64;

pub fn beams(config: &[BeamConfig]) -> Result<Vec<Beam>, ConfigError> {
    if config.is_empty() {
        return err("beam: give at least one [[beam]]");
    }
    if config.len() > MAX_BEAMS {
        return err(format!(
            "beam: {} [[beam]] tables, at most {MAX_BEAMS} (each one's rays are traced at every iteration)",
            config.len()
        ));
    }
    let mut beams = Vec::new();
    for (i, b) in config.iter().enumerate() {
        let k = |s: &str| format!("beam[{i}].{s}");
        let d = unit(&k("direction"), b.direction)?;
        for (key, v) in [("center", b.center), ("focus", b.focus)] {
            if !v.iter().all(|x| x.is_finite()) {
                return err(format!("{} = {v:?}: must be finite", k(key)));
            }
        }
        if !(b.radius >= 0.0 && b.radius.is_finite()) {
            return err(format!("{} = {}: must be >= 0", k("radius"), b.radius));
        }
        if !(0.0..89.0).contains(&b.half_angle_deg) {
            return err(format!(
                "{} = {}: must be within [0, 89)",
                k("half_angle_deg"),
                b.half_angle_deg
            ));
        }
        if !(1..=64).contains(&b.count) {
            return err(format!(
                "{} = {}: must be within [1, 64]",
                k("count"),
                b.count
            ));
        }
        if b.count > 1 && b.radius == 0.0 && b.half_angle_deg == 0.0 {
            return err(format!(
                "{}: {} rays a side need a radius or a half_angle_deg > 0",
                k("count"),
                b.count
            ));
        }
        let (e1, e2) = crate::math::orthonormal_basis(d);
        let c = DVec3::from_array(b.center);
        let spread = b.half_angle_deg.to_radians().tan();
        let m = b.count as usize;
        let lattice = |i: usize| {
            if m == 1 {
                0.0
            } else {
                2.0 * i as f64 / (m - 1) as f64 - 1.0
            }
        };
        let mut rays = Vec::new();
        for a in 0..m {
            for bb in 0..m {
                let (u, w) = (lattice(a), lattice(bb));
                if u * u + w * w <= 1.0 + 1e-9 {
                    let t = e1 * u + e2 * w;
                    let dir = if spread == 0.0 {
                        d
                    } else {
                        (d + t * spread).normalize()
                    };
                    rays.push((c + t * b.radius, dir));
                }
            }
        }
        beams.push(Beam {
            rays,
            focus: DVec3::from_array(b.focus),
        });
    }
    Ok(beams)
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OptimiserConfig {
    /// Adam iterations per level.
    pub iterations: u64,
    pub learning_rate: f64,
    #[serde(default)]
    pub smooth: f64,
}

impl DesignConfig {
    /// The design problem, every value checked.
    pub fn problem(&self) -> Result<FocusDesign, ConfigError> {
        let background = self.field.build()?;
        if matches!(background.bounds, crate::eikonal::Bounds::Everywhere) {
            return err(
                "field.bounds: a design needs bounds (sphere, cylinder or box) for its grid",
            );
        }
        let g = &self.grid;
        if g.levels.is_empty() {
            return err("grid.levels = []: give at least one grid size, e.g. [8, 16]");
        }
        for (i, &n) in g.levels.iter().enumerate() {
            if !(4..=160).contains(&n) {
                return err(format!("grid.levels[{i}] = {n}: must be within [4, 160]"));
            }
        }
        let interp = crate::config::trace::interpolation("grid", &g.interp)?;
        if !g.initial.is_finite() {
            return err(format!("grid.initial = {}: must be finite", g.initial));
        }
        let beams = beams(&self.beam)?;
        let (step, steps, to_exit) = self.trace.stepping()?;
        let o = &self.design;
        if !(1..=100_000).contains(&o.iterations) {
            return err(format!(
                "design.iterations = {}: must be within [1, 100000]",
                o.iterations
            ));
        }
        let learning_rate = pos("design.learning_rate", o.learning_rate)?;
        if !(o.smooth >= 0.0 && o.smooth.is_finite()) {
            return err(format!("design.smooth = {}: must be >= 0", o.smooth));
        }
        Ok(FocusDesign {
            background,
            levels: g.levels.iter().map(|&n| n as usize).collect(),
            interp,
            initial: g.initial,
            beams,
            step,
            steps,
            to_exit,
            iterations: o.iterations as usize,
            learning_rate,
            smooth: o.smooth,
        })
    }
}

/// Configs of `lightpath design` that fit analytic field parameters (a `[parameters]` table instead
/// of `[grid]`): L-BFGS on exit-adjoint gradients so the beams pass through their foci.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ParamFitConfig {
    pub field: FieldConfig,
    pub beam: Vec<BeamConfig>,
    #[serde(default)]
    pub trace: crate::config::trace::TraceSettings,
    pub parameters: ParametersConfig,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ParametersConfig {
    /// The parameters to fit, e.g. `[{ profile = 0, name = "n_max" }]`.
    pub fit: Vec<ParamRef>,
    /// L-BFGS iterations.
    pub iterations: u64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ParamRef {
    pub profile: u64,
    pub name: String,
}

impl ParamFitConfig {
    /// The fit problem, every value checked.
    pub fn problem(&self) -> Result<crate::inverse::grin_fit::ParamFit, ConfigError> {
        use crate::eikonal::FieldParam;
        if self.field.profiles.is_empty() {
            return err("field.profiles = []: give at least one profile");
        }
        let field = self.field.build()?;
        let n = crate::config::trace::check_positive(&field)?;
        if matches!(field.bounds, crate::eikonal::Bounds::Everywhere) {
            return err(
                "field.bounds: a fit traces rays to where they leave the field; give bounds (sphere, cylinder or box)",
            );
        }
        if self.parameters.fit.is_empty() {
            return err(
                "parameters.fit = []: name at least one, e.g. [{ profile = 0, name = \"n_max\" }]",
            );
        }
        let mut params = Vec::new();
        let mut names = Vec::new();
        for (i, p) in self.parameters.fit.iter().enumerate() {
            let prof = field.profiles.get(p.profile as usize).ok_or_else(|| {
                ConfigError(format!(
                    "parameters.fit[{i}].profile = {}: there are {} profile(s)",
                    p.profile,
                    field.profiles.len()
                ))
            })?;
            let which = prof.param_index(&p.name).ok_or_else(|| {
                ConfigError(format!(
                    "parameters.fit[{i}].name = \"{}\": the {} profile has no such parameter",
                    p.name,
                    prof.kind()
                ))
            })?;
            let param = FieldParam {
                profile: p.profile as usize,
                which,
            };
            if params.contains(&param) {
                return err(format!(
                    "parameters.fit[{i}] = {{ profile = {}, name = \"{}\" }}: already listed; name each parameter once",
                    p.profile, p.name
                ));
            }
            params.push(param);
            names.push(format!("profiles[{}].{}", p.profile, p.name));
        }
        let (step, max_steps) = self.trace.to_exit("a parameter fit")?;
        crate::config::trace::check_stepping(&field, n, step, max_steps)?;
        if !(1..=10_000).contains(&self.parameters.iterations) {
            return err(format!(
                "parameters.iterations = {}: must be within [1, 10000]",
                self.parameters.iterations
            ));
        }
        Ok(crate::inverse::grin_fit::ParamFit {
            field,
            params,
            names,
            beams: beams(&self.beam)?,
            step,
            max_steps,
            iterations: self.parameters.iterations as usize,
        })
    }
}
