//! The one config loader: a TOML file (or text) → a validated [`Task`] that owns what it describes,
//! built once (the speckle [`Scene`], or the GRIN field with its rays, design or fit problem).
//!
//! Which task a file holds is said by its tables, not guessed from its values:
//!
//! | tables                          | task                                   | commands                      |
//! |---------------------------------|----------------------------------------|-------------------------------|
//! | `[medium]` (no `[field]`)       | [`Task::Scene`]: a speckle scene       | covariance, speckle, memory-effect, wave, fit |
//! | `[field]` + `[rays]`            | [`Task::Trace`]: rays through a field  | trace                         |
//! | `[field]` + `[[beam]]` + `[grid]` | [`Task::Design`]: shape a grid field | design                        |
//! | `[field]` + `[[beam]]` + `[parameters]` | [`Task::ParamFit`]: fit analytic parameters | design           |
//! | `[acquisition]` + `[[pair]]`    | [`Task::Acquire`]: speckle images to read a phase function from | acquire-phase |
//!
//! Unknown keys and unphysical values are errors naming the key, the value and what is allowed,
//! e.g. `medium.albedo = 1.3: must be within [0, 1]`. Nothing here panics on user input.

pub mod acquire;
pub mod design;
mod medium;
mod scene;
pub mod trace;

pub use acquire::AcquireConfig;
pub use design::{DesignConfig, ParamFitConfig};
pub use scene::*;
pub use trace::{TraceConfig, TraceSettings};

use crate::eikonal::BoundedField;
use crate::inverse::grin_design::FocusDesign;
use crate::speckle::Scene;
use glam::DVec3;
use std::path::Path;

/// A speckle scene as written and as built.
#[derive(Clone, Debug)]
pub struct SceneTask {
    pub config: Config,
    pub scene: Scene,
}

/// Rays through an index field.
#[derive(Clone, Debug)]
pub struct TraceTask {
    pub config: TraceConfig,
    pub field: BoundedField,
    /// Ray origins and unit directions.
    pub rays: Vec<(DVec3, DVec3)>,
    pub step: f64,
    pub max_steps: usize,
}

/// A grid design: beams to bring to their foci by shaping a grid index field.
#[derive(Clone, Debug)]
pub struct DesignTask {
    pub config: DesignConfig,
    pub problem: FocusDesign,
}

/// A fit of analytic field parameters so beams pass through their foci.
#[derive(Clone, Debug)]
pub struct ParamFitTask {
    pub config: ParamFitConfig,
    pub problem: crate::inverse::grin_fit::ParamFit,
}

/// What a config file holds, validated and built.
#[derive(Clone, Debug)]
pub enum Task {
    Scene(Box<SceneTask>),
    Trace(Box<TraceTask>),
    Design(Box<DesignTask>),
    ParamFit(Box<ParamFitTask>),
    Acquire(Box<AcquireConfig>),
}

/// The kinds of task, named as in messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskKind {
    Scene,
    Trace,
    Design,
    ParamFit,
    Acquire,
}

impl TaskKind {
    /// What the kind is, and the command that runs it.
    pub fn describe(self) -> &'static str {
        match self {
            TaskKind::Scene => {
                "a speckle scene ([medium]; run it with covariance, speckle, memory-effect, wave or fit)"
            }
            TaskKind::Trace => "a trace config ([field] + [rays]; run it with `lightpath trace`)",
            TaskKind::Design => {
                "a grid design ([field] + [[beam]] + [grid]; run it with `lightpath design`)"
            }
            TaskKind::ParamFit => {
                "a parameter fit ([field] + [[beam]] + [parameters]; run it with `lightpath design`)"
            }
            TaskKind::Acquire => {
                "speckle images ([acquisition] + [[pair]]; read them with `lightpath acquire-phase`)"
            }
        }
    }

    /// The kind a file's top-level tables declare.
    fn of(table: &toml::Table) -> TaskKind {
        if table.contains_key("acquisition") {
            return TaskKind::Acquire;
        }
        match (
            table.contains_key("field"),
            table.contains_key("beam"),
            table.contains_key("parameters"),
        ) {
            (false, _, _) => TaskKind::Scene,
            (true, false, _) => TaskKind::Trace,
            (true, true, true) => TaskKind::ParamFit,
            (true, true, false) => TaskKind::Design,
        }
    }
}

impl Task {
    pub fn kind(&self) -> TaskKind {
        match self {
            Task::Scene(_) => TaskKind::Scene,
            Task::Trace(_) => TaskKind::Trace,
            Task::Design(_) => TaskKind::Design,
            Task::ParamFit(_) => TaskKind::ParamFit,
            Task::Acquire(_) => TaskKind::Acquire,
        }
    }

    /// The speckle scene, or an error saying what the file holds instead.
    pub fn into_scene(self, origin: &str) -> Result<SceneTask, ConfigError> {
        match self {
            Task::Scene(s) => Ok(*s),
            other => err(format!(
                "{origin}: this command needs a speckle scene ([medium], [[light]], [[view]]), but the file holds {}",
                other.kind().describe()
            )),
        }
    }
}

/// Read, parse and validate a config file; relative paths in it (phase tables, grid files) are
/// resolved against its folder. Errors name the file.
pub fn load(path: &Path) -> Result<Task, ConfigError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError(format!("cannot read config file {}: {e}", path.display())))?;
    let named = |e: ConfigError| ConfigError(format!("{}: {}", path.display(), e.0));
    let value = parse(&text).map_err(named)?;
    build(value, path).map_err(named)
}

/// Parse and validate config text (the embedded quick start, tests, the Python binding); relative
/// paths resolve against the current folder.
pub fn load_text(text: &str) -> Result<Task, ConfigError> {
    build(parse(text)?, Path::new("config.toml"))
}

/// A speckle scene from config text (the common case of [`load_text`]).
pub fn scene_from_text(text: &str) -> Result<SceneTask, ConfigError> {
    load_text(text)?.into_scene("config")
}

fn parse(text: &str) -> Result<toml::Value, ConfigError> {
    let mut value: toml::Value =
        toml::from_str(text).map_err(|e| ConfigError(format!("invalid TOML: {e}")))?;
    normalise_numbers(&mut value, "");
    Ok(value)
}

/// Deserialise `value` into `T`, naming the key of the first error.
fn typed<T: serde::de::DeserializeOwned>(value: toml::Value) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let key = e.path().to_string();
        let inner = e.into_inner().to_string();
        ConfigError(if key == "." {
            inner
        } else {
            format!("{key}: {inner}")
        })
    })
}

fn build(value: toml::Value, path: &Path) -> Result<Task, ConfigError> {
    let kind = match &value {
        toml::Value::Table(t) => TaskKind::of(t),
        _ => return err("the config must be a TOML table"),
    };
    Ok(match kind {
        TaskKind::Scene => {
            let mut config: Config = typed(value)?;
            config.resolve_paths(path.parent().unwrap_or(Path::new("")));
            let scene = config.build()?;
            Task::Scene(Box::new(SceneTask { config, scene }))
        }
        TaskKind::Trace => {
            let mut config: TraceConfig = typed(value)?;
            config.field.resolve_paths(path);
            let field = config.field()?;
            let rays = config.rays()?;
            let (step, max_steps) = config.trace.to_exit("trace")?;
            Task::Trace(Box::new(TraceTask {
                config,
                field,
                rays,
                step,
                max_steps,
            }))
        }
        TaskKind::Design => {
            let mut config: DesignConfig = typed(value)?;
            config.field.resolve_paths(path);
            let problem = config.problem()?;
            Task::Design(Box::new(DesignTask { config, problem }))
        }
        TaskKind::ParamFit => {
            let mut config: ParamFitConfig = typed(value)?;
            config.field.resolve_paths(path);
            let problem = config.problem()?;
            Task::ParamFit(Box::new(ParamFitTask { config, problem }))
        }
        TaskKind::Acquire => {
            let mut config: AcquireConfig = typed(value)?;
            config.resolve_paths(path.parent().unwrap_or(Path::new("")));
            config.validate()?;
            Task::Acquire(Box::new(config))
        }
    })
}
