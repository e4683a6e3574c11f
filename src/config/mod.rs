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
//! | `[field]` + `[light]`           | [`Task::Render`]: a refractive, scattering volume and its sensors | render |
//!
//! Unknown keys and unphysical values are errors naming the key, the value and what is allowed,
//! e.g. `medium.albedo = 1.3: must be within [0, 1]`. Nothing here panics on user input.

pub mod acquire;
pub mod design;
mod medium;
mod mesh;
pub mod render;
mod scene;
pub mod trace;

pub use acquire::AcquireConfig;
pub use design::{DesignConfig, ParamFitConfig};
pub use render::RenderConfig;
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

/// A refractive render: the config and the scene it describes.
#[derive(Clone, Debug)]
pub struct RenderTask {
    pub config: RenderConfig,
    pub scene: crate::rrte::RenderScene,
    /// The design its `[design]` table describes (`lightpath design`).
    pub design: Option<crate::inverse::render_design::RenderDesign>,
}

/// What a config file holds, validated and built.
#[derive(Clone, Debug)]
pub enum Task {
    Scene(Box<SceneTask>),
    Trace(Box<TraceTask>),
    Design(Box<DesignTask>),
    ParamFit(Box<ParamFitTask>),
    Acquire(Box<AcquireConfig>),
    Render(Box<RenderTask>),
}

/// The kinds of task, named as in messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskKind {
    Scene,
    Trace,
    Design,
    ParamFit,
    Acquire,
    Render,
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
            TaskKind::Render => {
                "a refractive render ([field] + [light] + [[sensor]]; run it with `lightpath render`, or with a [design] table, `lightpath design`)"
            }
        }
    }

    /// The kind a file's top-level tables declare.
    fn of(table: &toml::Table) -> TaskKind {
        if table.contains_key("acquisition") {
            return TaskKind::Acquire;
        }
        if table.contains_key("field") && table.contains_key("light") {
            return TaskKind::Render;
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
            Task::Render(_) => TaskKind::Render,
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

/// Validate a config given as a TOML value built elsewhere (the Python binding's dictionaries),
/// with the same rules and messages as a file; relative paths resolve against the folder `base`.
pub fn load_value(mut value: toml::Value, base: &Path) -> Result<Task, ConfigError> {
    if !value.is_table() {
        return err("a config is a table of tables (a dict), not a single value");
    }
    normalise_numbers(&mut value, "");
    check_magnitudes(&value, &mut Vec::new())?;
    build(value, &base.join("config.toml"))
}

/// A speckle scene from config text (the common case of [`load_text`]).
pub fn scene_from_text(text: &str) -> Result<SceneTask, ConfigError> {
    load_text(text)?.into_scene("config")
}

fn parse(text: &str) -> Result<toml::Value, ConfigError> {
    let mut value: toml::Value =
        toml::from_str(text).map_err(|e| ConfigError(format!("invalid TOML: {e}")))?;
    normalise_numbers(&mut value, "");
    check_magnitudes(&value, &mut Vec::new())?;
    Ok(value)
}

/// The magnitudes any real-valued key may have (besides 0 and the non-finite values some keys
/// take, such as `aperture_sigma = inf`): far beyond any quantity in any unit, yet far from where
/// squares, reciprocals and `k = 2π/λ` overflow.
const MAGNITUDES: std::ops::RangeInclusive<f64> = 1e-100..=1e12;

/// Refuse a number outside [`MAGNITUDES`] wherever it is, naming its key (a box of 1e308 once
/// gave NaN results, a focus of 1e308 a panic).
pub(crate) fn check_magnitudes(v: &toml::Value, at: &mut Vec<Step>) -> Result<(), ConfigError> {
    match v {
        toml::Value::Float(x) if x.is_finite() && *x != 0.0 && !MAGNITUDES.contains(&x.abs()) => {
            Err(ConfigError(format!(
                "{} = {x:e}: beyond what lightpath accepts for any quantity (0, or magnitudes from {:e} to {:e})",
                display(at),
                MAGNITUDES.start(),
                MAGNITUDES.end()
            )))
        }
        toml::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                at.push(Step::Index(i));
                check_magnitudes(x, at)?;
                at.pop();
            }
            Ok(())
        }
        toml::Value::Table(t) => {
            for (k, x) in t {
                at.push(Step::Key(k.clone()));
                check_magnitudes(x, at)?;
                at.pop();
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Deserialise `value` into `T`, naming the key of the first error. Inside tables tagged by `kind`
/// (lights, views, phase functions, profiles, …) serde loses the key, so the error is narrowed
/// down by [`narrow`] to the key that causes it (`view[0].axis`, not `view[0]`).
fn typed<T: serde::de::DeserializeOwned + serde::Serialize>(
    value: toml::Value,
) -> Result<T, ConfigError> {
    let backup = value.clone();
    match serde_path_to_error::deserialize::<_, T>(value) {
        Ok(t) => {
            let read = serde_json::to_value(&t).map_err(|e| ConfigError(e.to_string()))?;
            tables_stay_tables(&backup, &read, &mut Vec::new())?;
            Ok(t)
        }
        Err(e) => {
            let at = segments(e.path());
            let message = e.into_inner().message().to_string();
            let (at, message) = narrow::<T>(&backup, at, message);
            Err(ConfigError(if at.is_empty() {
                message
            } else {
                format!("{}: {message}", display(&at))
            }))
        }
    }
}

/// Refuse an array where the schema has a table: serde reads a table's keys from an array by
/// position, so `trace = [10.0]` would silently mean `trace = { step = 10.0 }`. `read` is what was
/// understood (serialised back); wherever it holds a table, the input must hold one too.
fn tables_stay_tables(
    input: &toml::Value,
    read: &serde_json::Value,
    at: &mut Vec<Step>,
) -> Result<(), ConfigError> {
    use serde_json::Value as J;
    use toml::Value as T;
    match (input, read) {
        (T::Array(_), J::Object(keys)) => {
            let keys: Vec<&str> = keys.keys().map(String::as_str).collect();
            Err(ConfigError(format!(
                "{}: expected a table (keys {}), found an array",
                display(at),
                keys.join(", ")
            )))
        }
        (T::Table(t), J::Object(o)) => {
            for (k, v) in t {
                if let Some(r) = o.get(k) {
                    at.push(Step::Key(k.clone()));
                    tables_stay_tables(v, r, at)?;
                    at.pop();
                }
            }
            Ok(())
        }
        (T::Array(a), J::Array(r)) => {
            for (i, (v, r)) in a.iter().zip(r).enumerate() {
                at.push(Step::Index(i));
                tables_stay_tables(v, r, at)?;
                at.pop();
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// One step of a key path: a table key or an array index.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Step {
    Key(String),
    Index(usize),
}

fn segments(path: &serde_path_to_error::Path) -> Vec<Step> {
    use serde_path_to_error::Segment;
    path.iter()
        .filter_map(|s| match s {
            Segment::Seq { index } => Some(Step::Index(*index)),
            Segment::Map { key } => Some(Step::Key(key.clone())),
            Segment::Enum { .. } | Segment::Unknown => None,
        })
        .collect()
}

/// `view[0].axis`
fn display(at: &[Step]) -> String {
    let mut s = String::new();
    for step in at {
        match step {
            Step::Key(k) if s.is_empty() => s += k,
            Step::Key(k) => s += &format!(".{k}"),
            Step::Index(i) => s += &format!("[{i}]"),
        }
    }
    s
}

fn node_mut<'a>(v: &'a mut toml::Value, at: &[Step]) -> Option<&'a mut toml::Value> {
    at.iter().try_fold(v, |v, step| match step {
        Step::Key(k) => v.as_table_mut()?.get_mut(k),
        Step::Index(i) => v.as_array_mut()?.get_mut(*i),
    })
}

/// The first error of deserialising `value` as `T`: its path and message.
fn first_error<T: serde::de::DeserializeOwned>(value: toml::Value) -> Option<(Vec<Step>, String)> {
    serde_path_to_error::deserialize::<_, T>(value)
        .err()
        .map(|e| (segments(e.path()), e.into_inner().message().to_string()))
}

/// Narrow an error reported at a table (serde cannot see into tables tagged by `kind`) down to the
/// key that causes it: keep one key at a time (with the tag) and see which one alone still fails
/// with something other than a missing field; then look inside that key. Arrays of tables are
/// narrowed to the element. Returns the path as the user wrote it (original array indices).
fn narrow<T: serde::de::DeserializeOwned>(
    root: &toml::Value,
    at: Vec<Step>,
    message: String,
) -> (Vec<Step>, String) {
    let missing = |m: &str| m.starts_with("missing field");
    let (mut probe, mut probe_at, mut shown, mut message) = (root.clone(), at.clone(), at, message);
    for _ in 0..16 {
        if missing(&message) {
            break;
        }
        let Some(node) = node_mut(&mut probe, &probe_at).map(|n| n.clone()) else {
            break;
        };
        // if the error stays with this node emptied (its tag kept), its contents do not cause it
        let emptied = match &node {
            toml::Value::Table(t) => Some(toml::Value::Table(
                t.get("kind")
                    .map(|tag| toml::Table::from_iter([("kind".to_string(), tag.clone())]))
                    .unwrap_or_default(),
            )),
            toml::Value::Array(_) => Some(toml::Value::Array(vec![])),
            _ => None,
        };
        if let Some(emptied) = emptied {
            let mut candidate = probe.clone();
            if let Some(n) = node_mut(&mut candidate, &probe_at) {
                *n = emptied;
            }
            if first_error::<T>(candidate).is_some_and(|(_, m)| !missing(&m) && m == message) {
                break;
            }
        }
        // candidates: (replacement node, the step it narrows to, the step as shown)
        let candidates: Vec<(toml::Value, Step, Step)> = match &node {
            toml::Value::Table(t) => t
                .iter()
                .map(|(k, v)| {
                    let mut reduced = toml::Table::new();
                    if let Some(tag) = t.get("kind") {
                        reduced.insert("kind".into(), tag.clone());
                    }
                    reduced.insert(k.clone(), v.clone());
                    (
                        toml::Value::Table(reduced),
                        Step::Key(k.clone()),
                        Step::Key(k.clone()),
                    )
                })
                .collect(),
            toml::Value::Array(a) if a.iter().any(toml::Value::is_table) => a
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    (
                        toml::Value::Array(vec![v.clone()]),
                        Step::Index(0),
                        Step::Index(i),
                    )
                })
                .collect(),
            _ => break,
        };
        let found = candidates
            .into_iter()
            .find_map(|(replacement, step, show)| {
                let mut candidate = probe.clone();
                *node_mut(&mut candidate, &probe_at)? = replacement;
                let (path, m) = first_error::<T>(candidate.clone())?;
                // the error must stay on this key's lineage (serde may report it at a tagged ancestor)
                let lineage = path.starts_with(&probe_at) || probe_at.starts_with(&path);
                (!missing(&m) && lineage).then_some((candidate, step, show, path, m))
            });
        let Some((candidate, step, show, path, m)) = found else {
            break;
        };
        probe = candidate;
        probe_at.push(step);
        shown.push(show);
        message = m;
        // serde may already see deeper than the narrowed key (plain tables below it)
        if path.len() > probe_at.len() && path.starts_with(&probe_at) {
            shown.extend_from_slice(&path[probe_at.len()..]);
            probe_at = path;
        }
    }
    (shown, message)
}

fn build(value: toml::Value, path: &Path) -> Result<Task, ConfigError> {
    let kind = match &value {
        toml::Value::Table(t) => {
            // design tables without the beams they shape: say so rather than read a trace config
            if t.contains_key("field") && !t.contains_key("beam") {
                for table in ["parameters", "grid"] {
                    if t.contains_key(table) {
                        return err(format!(
                            "beam: missing: a [{table}] table designs the field for [[beam]] tables (a center, direction, spread and focus each); give at least one, or drop [{table}] to trace rays"
                        ));
                    }
                }
            }
            TaskKind::of(t)
        }
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
        TaskKind::Render => {
            let mut config: RenderConfig = typed(value)?;
            config.resolve_paths(path);
            let scene = config.build()?;
            let design = config.design(&scene)?;
            Task::Render(Box::new(RenderTask {
                config,
                scene,
                design,
            }))
        }
    })
}
