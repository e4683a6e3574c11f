//! `lightpath covariance | speckle | memory-effect | wave` runs on the engine, whole or as shards,
//! and `lightpath merge`: a shard writes `state.bin` (the engine's blocks and the run's header);
//! merging the shards reproduces the single run bit for bit.

use super::{Outcome, Progress, create_out};
use crate::config::{Config, EstimatorConfig, SceneTask, SpeckleConfig};
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{
    CorrelationMapFile, CovarianceFile, MemoryEffectFile, RunEcho, SpeckleFile, TiltShiftFile,
    nest2, nest4,
};
use crate::io::state::{StateHeader, read_state, write_state};
use crate::math::{C64, splitmix64};
use crate::mc::{Block, Checkpoint, Estimate, Plan, merge, resume};
use crate::speckle::covariance::Order;
use crate::speckle::mean::mean_field;
use crate::speckle::memory::{MemoryCurve, MemoryScan};
use crate::speckle::paths::SubpathSampler;
use crate::speckle::{Covariance, FieldSampler, Scene};
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a run computes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Covariance,
    MemoryEffect,
    Speckle,
    /// Near-field `C(Δ, τ)` maps (see [`super::correlation_map`]).
    CorrelationMap,
    /// Tilt-shift correlations (see [`super::tilt_shift`]).
    TiltShift,
    /// Foldy–Lax realisations (see [`super::wave`]).
    Wave,
    /// Refractive renders (see [`super::render`]).
    Render,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Covariance => "covariance",
            Kind::MemoryEffect => "memory-effect",
            Kind::Speckle => "speckle",
            Kind::CorrelationMap => "correlation-map",
            Kind::TiltShift => "tilt-shift",
            Kind::Wave => "wave",
            Kind::Render => "render",
        }
    }

    /// The result files a run of this kind writes (see [`super::create_out`]); a shard writes
    /// `state.bin` instead.
    pub fn files(self) -> &'static [&'static str] {
        match self {
            Kind::Covariance | Kind::Wave => &["covariance.json"],
            Kind::MemoryEffect => &["memory_effect.json", "memory_effect.png"],
            Kind::Speckle => &["speckle.json", "speckle_*.exr"],
            Kind::CorrelationMap => &["correlation_map.json", "correlation_map.png"],
            Kind::TiltShift => &["tilt_shift.json", "tilt_shift.png"],
            Kind::Render => super::render::FILES,
        }
    }

    /// What a run (or shard) of this kind owns in its output folder: its results and `state.bin`.
    pub(crate) fn owned(self) -> Vec<&'static str> {
        let mut v = self.files().to_vec();
        v.push(STATE_FILE);
        v
    }

    fn from_name(s: &str) -> Option<Kind> {
        [
            Kind::Covariance,
            Kind::MemoryEffect,
            Kind::Speckle,
            Kind::CorrelationMap,
            Kind::TiltShift,
            Kind::Wave,
            Kind::Render,
        ]
        .into_iter()
        .find(|k| k.name() == s)
    }
}

/// What a run works on: a speckle scene, or a refractive render.
#[derive(Clone, Copy)]
pub(crate) enum Job<'a> {
    Scene(&'a SceneTask),
    Render(&'a crate::config::RenderTask),
}

impl<'a> Job<'a> {
    /// The config as the run's header records it.
    fn config_json(self) -> Result<serde_json::Value> {
        match self {
            Job::Scene(t) => serde_json::to_value(&t.config),
            Job::Render(t) => serde_json::to_value(&t.config),
        }
        .map_err(|e| Error::input(format!("the run's config cannot be recorded: {e}")))
    }

    /// The speckle scene of every kind but `Render`.
    fn scene(self) -> Result<&'a SceneTask> {
        match self {
            Job::Scene(t) => Ok(t),
            Job::Render(_) => Err(Error::input(
                "a render config cannot run as a speckle command",
            )),
        }
    }

    /// Units of work of the whole run (speckle: realisations; else chunks).
    fn units(self, kind: Kind, plan: &Plan) -> u64 {
        match (kind, self) {
            (Kind::Speckle, Job::Scene(t)) => realisations(&t.config),
            _ => plan.chunks,
        }
    }
}

/// The shard state file in a shard's output folder.
const STATE_FILE: &str = "state.bin";
/// The engine state an unfinished run saves in its output folder (same format as `state.bin`).
pub const CHECKPOINT_FILE: &str = "checkpoint.bin";

/// Command-line overrides and run options.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    pub samples: Option<u64>,
    pub seed: Option<u64>,
    /// `(i, n)`: run shard `i` of `n` and write `state.bin` instead of results.
    pub shard: Option<(u64, u64)>,
    /// Show a progress bar (only when stderr is a terminal).
    pub progress: bool,
    /// Refuse runs estimated beyond this time or memory.
    pub budget: super::budget::Budget,
    /// Continue the interrupted run whose `checkpoint.bin` is in this folder.
    pub resume: Option<PathBuf>,
    /// Save a checkpoint every this many chunks (speckle: realisations); without it, every two
    /// minutes.
    pub checkpoint_every: Option<u64>,
}

/// Run `kind` (not `Wave`: see [`super::wave::run`]) on `task` and write into `out`.
pub fn run_scene(
    kind: Kind,
    mut task: SceneTask,
    opts: &RunOptions,
    out: &Path,
) -> Result<Outcome> {
    match prepare(kind, &mut task, opts.samples, opts.seed)? {
        Some(plan) => execute(kind, Job::Scene(&task), plan, opts, out),
        None => {
            if opts.shard.is_some() {
                return Err(Error::input(
                    "--shard: render.estimator = \"single_scattering\" is a closed form with nothing to split",
                ));
            }
            let file = single_scattering_file(&task)?;
            create_out(out, &Kind::Covariance.owned())?;
            write_covariance(&file, out)
        }
    }
}

/// Apply the command-line overrides to `task` and check it can run as `kind`: the engine's plan,
/// or `None` for the closed-form single-scattering covariance.
fn prepare(
    kind: Kind,
    task: &mut SceneTask,
    samples: Option<u64>,
    seed: Option<u64>,
) -> Result<Option<Plan>> {
    let cfg = &mut task.config;
    if let Some(s) = samples {
        if s == 0 {
            return Err(Error::input("--samples 0: must be at least 1"));
        }
        match kind {
            Kind::Speckle => cfg.speckle.get_or_insert_with(default_speckle).paths = s,
            _ => cfg.render.samples = s,
        }
    }
    if let Some(s) = seed {
        cfg.render.seed = s;
    }
    if kind == Kind::MemoryEffect && cfg.memory_effect.is_none() {
        return Err(Error::input(
            "memory-effect needs a [memory_effect] table with angles_deg = [...]",
        ));
    }
    if kind == Kind::CorrelationMap && cfg.correlation_map.is_none() {
        return Err(Error::input(super::correlation_map::NEEDS_TABLE));
    }
    if kind == Kind::TiltShift && cfg.tilt_shift.is_none() {
        return Err(Error::input(super::tilt_shift::NEEDS_TABLE));
    }
    cfg.check_settings()?;
    if cfg.render.estimator == EstimatorConfig::SingleScattering {
        if kind != Kind::Covariance {
            return Err(Error::input(format!(
                "render.estimator = \"single_scattering\": only `lightpath covariance` has a closed form; {} needs \"monte_carlo\"",
                kind.name()
            )));
        }
        return Ok(None);
    }
    Ok(Some(plan_of(kind, cfg)))
}

/// `[render] estimator = "single_scattering"`: the covariance of paths that scatter once, in closed
/// form (no paths, no standard error; `solver` says so). Only `covariance` (see [`prepare`]).
fn single_scattering_file(task: &SceneTask) -> Result<CovarianceFile> {
    let start = Instant::now();
    let scene = &task.scene;
    if let Some(why) = crate::speckle::single::unsupported(scene) {
        return Err(Error::input(format!(
            "render.estimator = \"single_scattering\": {why}"
        )));
    }
    let cov = crate::speckle::single::covariance(scene)?;
    check_finite("covariance", &cov)?;
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let zeros = vec![0.0; cov.len()];
    let seconds = start.elapsed().as_secs_f64();
    let echo = RunEcho::new(&task.config, scene, 0, task.config.render.seed, seconds);
    let mut file = CovarianceFile::new(echo, nl, nv, &cov, &zeros, &mean_fields(scene));
    file.single_re = Some(nest4(nl, nv, |i| cov[i].re));
    file.single_im = Some(nest4(nl, nv, |i| cov[i].im));
    file.single_stderr = Some(nest4(nl, nv, |_| 0.0));
    file.solver = Some("single_scattering".into());
    Ok(file)
}

/// Run the units of work of `kind` in this shard (all of them without `--shard`); write the shard's
/// state or the results.
pub(crate) fn execute(
    kind: Kind,
    task: Job,
    plan: Plan,
    opts: &RunOptions,
    out: &Path,
) -> Result<Outcome> {
    let whole = task.units(kind, &plan);
    let (range, shard) = match opts.shard {
        Some((i, n)) => {
            if n == 0 || i >= n {
                return Err(Error::input(format!("--shard {i}/{n}: need 0 <= i < n")));
            }
            if n > whole {
                return Err(Error::input(format!(
                    "--shard {i}/{n}: the run has only {whole} units of work; use at most {whole} shards"
                )));
            }
            ((whole * i / n)..(whole * (i + 1) / n), [i, n])
        }
        None => (0..whole, [0, 1]),
    };
    let header = StateHeader {
        format_version: crate::io::results::FORMAT_VERSION,
        kind: kind.name().into(),
        config: task.config_json()?,
        seed: plan.seed,
        chunk_paths: plan.chunk_paths,
        chunks: plan.chunks,
        shard,
        version: env!("CARGO_PKG_VERSION").into(),
    };
    let done = match &opts.resume {
        Some(dir) => resumed_blocks(kind, task, &header, whole, dir)?,
        None => Vec::new(),
    };
    let mut owned = kind.owned();
    if opts.resume.is_none() {
        // a fresh run replaces any earlier checkpoint; a resumed one keeps it until it saves its own
        owned.push(CHECKPOINT_FILE);
    }
    create_out(out, &owned)?;
    let units = progress_units(kind, range.end.saturating_sub(range.start), &plan);
    let unit = if kind == Kind::Wave {
        "placements"
    } else {
        "chunks"
    };
    let t0 = Instant::now();
    let bar = Progress::new(opts.progress, units, kind.name(), unit);
    let checkpoint_path = out.join(CHECKPOINT_FILE);
    let mut save = |blocks: &[Block]| -> Result<()> {
        write_state(&checkpoint_path, &header, blocks).map_err(|source| Error::Io {
            action: "write",
            path: checkpoint_path.clone(),
            source,
        })
    };
    let checkpoint = Checkpoint::new(opts.checkpoint_every, &mut save);
    let work = Work {
        plan: &plan,
        range,
        done,
        checkpoint,
    };
    let blocks = compute(kind, task, work, &opts.budget, &bar)?;
    bar.finish();
    let outcome = if shard[1] > 1 {
        let path = out.join(STATE_FILE);
        write_state(&path, &header, &blocks).map_err(|source| Error::Io {
            action: "write",
            path: path.clone(),
            source,
        })?;
        Outcome {
            not_converged: None,
            summary: format!(
                "shard {}/{} of {} done in {:.1} s; combine all shards with `lightpath merge`",
                shard[0],
                shard[1],
                kind.name(),
                t0.elapsed().as_secs_f64()
            ),
            files: vec![path],
        }
    } else {
        finish(kind, task, &plan, blocks, t0.elapsed().as_secs_f64(), out)?
    };
    // the run is complete: its checkpoint has nothing left to resume
    super::remove_checkpoint(out)?;
    Ok(outcome)
}

/// What a progress bar counts for `units` units of work of `kind`: chunks (speckle: chunks of
/// every realisation).
fn progress_units(kind: Kind, units: u64, plan: &Plan) -> u64 {
    match kind {
        Kind::Speckle => units * plan.chunks,
        _ => units,
    }
}

/// The blocks saved in `dir/checkpoint.bin`, if it belongs to the run `header` describes.
fn resumed_blocks(
    kind: Kind,
    task: Job,
    header: &StateHeader,
    whole: u64,
    dir: &Path,
) -> Result<Vec<Block>> {
    let (saved, blocks) = read_state(&super::saved_checkpoint(dir)?)?;
    if !saved.same_run(header) || saved.shard != header.shard {
        return Err(Error::input(format!(
            "--resume {}: the checkpoint belongs to another run (command, config, seed, samples, shard or version differ); resume with the command and config that started it",
            dir.display()
        )));
    }
    check_blocks(&blocks, shape(kind, task)?, whole)?;
    Ok(blocks)
}

/// The chunks a run computes: its plan, its range, the blocks already done (resumed), and when to
/// save checkpoints.
struct Work<'a> {
    plan: &'a Plan,
    range: std::ops::Range<u64>,
    done: Vec<Block>,
    checkpoint: Checkpoint<'a>,
}

/// Merge shard folders (each with `state.bin`) into the results of the single run.
pub fn merge_shards(inputs: &[PathBuf], out: &Path) -> Result<Outcome> {
    if inputs.is_empty() {
        return Err(Error::input("merge: give at least one shard folder"));
    }
    let mut first: Option<StateHeader> = None;
    let mut blocks = Vec::new();
    let mut seen = Vec::new();
    for dir in inputs {
        let path = if dir.is_dir() {
            dir.join(STATE_FILE)
        } else {
            dir.clone()
        };
        let (h, b) = read_state(&path)?;
        if first.as_ref().is_some_and(|f| !f.same_run(&h)) {
            return Err(Error::input(format!(
                "{}: this shard belongs to a different run than {} (config, seed, samples, shard count or version differ)",
                path.display(),
                inputs[0].display()
            )));
        }
        if seen.contains(&h.shard[0]) {
            return Err(Error::input(format!(
                "{}: shard {}/{} is given twice",
                path.display(),
                h.shard[0],
                h.shard[1]
            )));
        }
        seen.push(h.shard[0]);
        blocks.extend(b);
        first.get_or_insert(h);
    }
    let h = first.expect("one input");
    if seen.len() as u64 != h.shard[1] {
        let missing: Vec<u64> = (0..h.shard[1]).filter(|i| !seen.contains(i)).collect();
        return Err(Error::input(format!(
            "merge: shards {missing:?} of {} are missing",
            h.shard[1]
        )));
    }
    let kind = Kind::from_name(&h.kind)
        .ok_or_else(|| Error::input(format!("unknown run kind {:?}", h.kind)))?;
    let plan = Plan {
        seed: h.seed,
        chunk_paths: h.chunk_paths,
        chunks: h.chunks,
    };
    let recorded = |e: serde_json::Error| {
        Error::input(format!(
            "merge: the shards' recorded config cannot be read ({e}); they were written by another version"
        ))
    };
    if kind == Kind::Render {
        let config: crate::config::RenderConfig =
            serde_json::from_value(h.config).map_err(recorded)?;
        let scene = config.build()?;
        let task = crate::config::RenderTask {
            config,
            scene,
            design: None,
        };
        return merged(kind, Job::Render(&task), &plan, blocks, out);
    }
    let config: Config = serde_json::from_value(h.config).map_err(recorded)?;
    let scene = config.build()?;
    let task = SceneTask { config, scene };
    merged(kind, Job::Scene(&task), &plan, blocks, out)
}

/// Check merged blocks against the run and write its results.
fn merged(kind: Kind, task: Job, plan: &Plan, blocks: Vec<Block>, out: &Path) -> Result<Outcome> {
    check_blocks(&blocks, shape(kind, task)?, task.units(kind, plan))?;
    create_out(out, kind.files())?;
    finish(kind, task, plan, blocks, f64::NAN, out)
}

/// What each engine block of a run holds: `outputs` sums (and as many squares, except for speckle
/// realisations) and `kept` values per chunk.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Shape {
    outputs: usize,
    squares: usize,
    kept: usize,
}

/// The block shape of `kind` on `task`, from the estimator the run would build.
fn shape(kind: Kind, job: Job) -> Result<Shape> {
    use crate::mc::Estimator;
    if let Job::Render(r) = job {
        let outputs = crate::rrte::ParticleTracer::new(&r.scene).outputs();
        return Ok(Shape {
            outputs,
            squares: outputs,
            kept: 0,
        });
    }
    let task = job.scene()?;
    let reversed = task.config.render.reversed;
    let scene = &task.scene;
    let all = |outputs| Shape {
        outputs,
        squares: outputs,
        kept: 0,
    };
    Ok(match kind {
        Kind::Covariance => all(Covariance::all_pairs(scene, reversed)?.outputs()),
        Kind::MemoryEffect => {
            let scan = memory_scan(task)?;
            let est = Covariance::with_pairs(&scan.scene, scan.pairs(), reversed)?;
            Shape {
                kept: scan.kept_outputs().len(),
                ..all(est.outputs())
            }
        }
        Kind::CorrelationMap => {
            let map = super::correlation_map::map_of(task)?;
            all(crate::speckle::correlation_map::MapEstimator::new(&map, reversed)?.outputs())
        }
        Kind::TiltShift => {
            let scan = super::tilt_shift::scan_of(task)?;
            let n = crate::speckle::tilt_shift::TiltShiftEstimator::new(&scan, reversed)?.outputs();
            Shape { kept: n, ..all(n) }
        }
        Kind::Wave => {
            let est = crate::speckle::wave::Realizations::new(scene);
            Shape {
                kept: est.kept_outputs().len(),
                ..all(est.outputs())
            }
        }
        Kind::Render => return Err(Error::input("a speckle config cannot run as a render")),
        Kind::Speckle => Shape {
            squares: 0,
            ..all(FieldSampler::new(scene, SubpathSampler::all_pairs(scene), reversed)?.outputs())
        },
    })
}

/// Refuse shard blocks that do not fit the run their header describes (sizes, chunk ranges), so a
/// damaged or hand-edited state is an error and never a relabelled result or a panic.
fn check_blocks(blocks: &[Block], shape: Shape, whole: u64) -> Result<()> {
    for b in blocks {
        let end = b
            .start
            .checked_add(b.len)
            .filter(|&e| b.len > 0 && e <= whole);
        let kept = usize::try_from(b.len)
            .ok()
            .and_then(|n| n.checked_mul(shape.kept));
        if end.is_none()
            || b.sum.len() != shape.outputs
            || b.sq.len() != shape.squares
            || kept != Some(b.kept.len())
        {
            return Err(Error::input(format!(
                "merge: a shard block (units {}..+{}, {} sums, {} squares, {} kept) does not fit the run its header describes ({whole} units, {} outputs, {} squares, {} kept per unit); the shard files do not belong together or were edited",
                b.start,
                b.len,
                b.sum.len(),
                b.sq.len(),
                b.kept.len(),
                shape.outputs,
                shape.squares,
                shape.kept
            )));
        }
    }
    Ok(())
}

fn default_speckle() -> SpeckleConfig {
    SpeckleConfig {
        realisations: 1,
        paths: 100_000,
    }
}

fn realisations(cfg: &Config) -> u64 {
    cfg.speckle.as_ref().map_or(1, |s| s.realisations)
}

fn plan_of(kind: Kind, cfg: &Config) -> Plan {
    match kind {
        Kind::Speckle => {
            let paths = cfg.speckle.as_ref().map_or(100_000, |s| s.paths);
            Plan::new(cfg.render.seed, paths, cfg.render.chunk)
        }
        _ => Plan::new(cfg.render.seed, cfg.render.samples, cfg.render.chunk),
    }
}

/// The seed of speckle realisation `r` (independent streams per image).
fn realisation_seed(seed: u64, r: u64) -> u64 {
    splitmix64(seed ^ splitmix64(r.wrapping_add(0xF1E1D)))
}

/// The memory-effect scan of a scene task (its `[memory_effect]` table).
pub(crate) fn memory_scan(task: &SceneTask) -> Result<MemoryScan> {
    let me = task
        .config
        .memory_effect
        .as_ref()
        .ok_or_else(|| Error::input("missing [memory_effect]"))?;
    MemoryScan::new(&task.scene, DVec3::from_array(me.axis), &me.angles_deg)
}

fn compute(
    kind: Kind,
    job: Job,
    work: Work,
    budget: &super::budget::Budget,
    bar: &Progress,
) -> Result<Vec<Block>> {
    if let Job::Render(r) = job {
        let Work {
            plan,
            range,
            done,
            checkpoint,
        } = work;
        return super::render::compute(r, plan, range, done, checkpoint, budget, bar);
    }
    let task = job.scene()?;
    let reversed = task.config.render.reversed;
    let scene = &task.scene;
    let Work {
        plan,
        range,
        done,
        mut checkpoint,
    } = work;
    let progress = |n| bar.set(n);
    // what is left to run (after a resumed checkpoint)
    let next = done.last().map_or(range.start, |b| b.start + b.len);
    let chunks = range.end.saturating_sub(next);
    let paths = (chunks * plan.chunk_paths) as f64;
    let what = kind.name();
    let medium = &scene.medium;
    use super::budget::check as afford_run;
    Ok(match kind {
        Kind::Render => return Err(Error::input("a speckle config cannot run as a render")),
        Kind::Covariance => {
            let est = Covariance::all_pairs(scene, reversed)?;
            afford_run(what, &est, medium, paths, chunks, 0, budget)?;
            resume(&est, plan, range, &[], &progress, done, Some(checkpoint))?
        }
        Kind::MemoryEffect => {
            let scan = memory_scan(task)?;
            let est = Covariance::with_pairs(&scan.scene, scan.pairs(), reversed)?;
            let keep = scan.kept_outputs();
            afford_run(what, &est, medium, paths, chunks, keep.len(), budget)?;
            resume(&est, plan, range, &keep, &progress, done, Some(checkpoint))?
        }
        Kind::CorrelationMap => {
            let map = super::correlation_map::map_of(task)?;
            let est = crate::speckle::correlation_map::MapEstimator::new(&map, reversed)?;
            afford_run(what, &est, medium, paths, chunks, 0, budget)?;
            resume(&est, plan, range, &[], &progress, done, Some(checkpoint))?
        }
        Kind::TiltShift => {
            let scan = super::tilt_shift::scan_of(task)?;
            let est = crate::speckle::tilt_shift::TiltShiftEstimator::new(&scan, reversed)?;
            // every output per chunk: the normalised correlations' errors by batch means
            let keep: Vec<usize> = (0..crate::mc::Estimator::outputs(&est)).collect();
            afford_run(what, &est, medium, paths, chunks, keep.len(), budget)?;
            resume(&est, plan, range, &keep, &progress, done, Some(checkpoint))?
        }
        Kind::Wave => {
            // the wave solver checks its own limits (scatterers, dense solves, timed estimate)
            let est = crate::speckle::wave::Realizations::new(scene);
            let keep = est.kept_outputs();
            resume(&est, plan, range, &keep, &progress, done, Some(checkpoint))?
        }
        Kind::Speckle => {
            // one unit of work per realisation (an image of `plan.samples()` paths)
            let est = FieldSampler::new(scene, SubpathSampler::all_pairs(scene), reversed)?;
            let images = (plan.samples() * chunks) as f64;
            afford_run(what, &est, medium, images, plan.chunks, 0, budget)?;
            let mut out = done;
            checkpoint.start(next);
            for r in next..range.end {
                let p = Plan {
                    seed: realisation_seed(plan.seed, r),
                    ..*plan
                };
                let before = (r - range.start) * plan.chunks;
                let within = Checkpoint::stop_only(checkpoint.stop_flag());
                let blocks = resume(
                    &est,
                    &p,
                    0..p.chunks,
                    &[],
                    &|c| bar.set(before + c),
                    Vec::new(),
                    Some(within),
                )?;
                let root = merge(blocks, p.chunks)?;
                out.push(Block {
                    start: r,
                    len: 1,
                    sum: root.sum,
                    sq: vec![],
                    kept: vec![],
                });
                if r + 1 < range.end {
                    checkpoint.offer(r + 1, &out)?;
                }
            }
            out
        }
    })
}

fn finish(
    kind: Kind,
    job: Job,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> Result<Outcome> {
    if let Job::Render(r) = job {
        return super::render::finish(r, plan, blocks, seconds, out);
    }
    let task = job.scene()?;
    match kind {
        Kind::Render => Err(Error::input("a speckle config cannot run as a render")),
        Kind::Covariance
        | Kind::MemoryEffect
        | Kind::Speckle
        | Kind::Wave
        | Kind::CorrelationMap
        | Kind::TiltShift => results(kind, task, plan, blocks, seconds)?.write(out),
    }
}

/// A finished speckle run's results, typed, before anything is written: what [`evaluate`]
/// returns and what the commands write.
#[derive(Clone, Debug)]
pub enum Results {
    /// `covariance.json`: Monte Carlo, closed form or wave solver.
    Covariance(Box<CovarianceFile>),
    /// `memory_effect.json` and its plot.
    MemoryEffect(Box<MemoryEffectFile>, Box<MemoryCurve>),
    /// `speckle.json` and one EXR image per realisation.
    Speckle(Box<SpeckleFile>),
    /// `correlation_map.json` and its plot, scaled by the unshifted map's peak intensity.
    CorrelationMap(Box<CorrelationMapFile>, f64),
    /// `tilt_shift.json` and its plot.
    TiltShift(Box<TiltShiftFile>),
}

impl Results {
    /// Write the result files into `out` (which exists) and say what they hold.
    pub fn write(&self, out: &Path) -> Result<Outcome> {
        match self {
            Results::Covariance(file) => write_covariance(file, out),
            Results::MemoryEffect(file, curve) => write_memory(file, curve, out),
            Results::Speckle(file) => write_speckle(file, out),
            Results::CorrelationMap(file, peak) => {
                super::correlation_map::write_map(file, *peak, out)
            }
            Results::TiltShift(file) => super::tilt_shift::write_tilt(file, out),
        }
    }
}

/// The results of `kind` (covariance, memory effect, speckle, wave, correlation map or
/// tilt-shift) from the run's blocks.
fn results(
    kind: Kind,
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<Results> {
    Ok(match kind {
        Kind::Covariance => {
            Results::Covariance(Box::new(covariance_file(task, plan, blocks, seconds)?))
        }
        Kind::MemoryEffect => {
            let (file, curve) = memory_file(task, plan, blocks, seconds)?;
            Results::MemoryEffect(Box::new(file), Box::new(curve))
        }
        Kind::Speckle => Results::Speckle(Box::new(speckle_file(task, plan, blocks, seconds)?)),
        Kind::CorrelationMap => {
            let (file, peak) = super::correlation_map::map_file(task, plan, blocks, seconds)?;
            Results::CorrelationMap(Box::new(file), peak)
        }
        Kind::TiltShift => Results::TiltShift(Box::new(super::tilt_shift::tilt_file(
            task, plan, blocks, seconds,
        )?)),
        Kind::Wave => Results::Covariance(Box::new(super::wave::covariance_file(
            task, plan, blocks, seconds,
        )?)),
        other => {
            return Err(Error::input(format!(
                "{} writes its own result files",
                other.name()
            )));
        }
    })
}

/// Run `kind` (covariance, memory effect, speckle, correlation map, tilt-shift; wave through
/// [`super::wave::evaluate`]) on
/// `task` whole and in memory: no shards, no checkpoint, nothing written. `watch` reports the
/// progress and stops the run when asked. The library's entry (the Python binding's): the
/// results are those the command writes, bit for bit, for the same config, samples and seed.
pub fn evaluate(
    kind: Kind,
    mut task: SceneTask,
    samples: Option<u64>,
    seed: Option<u64>,
    budget: &super::budget::Budget,
    watch: &super::Watch,
) -> Result<Results> {
    let plan = prepare(kind, &mut task, samples, seed)?;
    let Some(plan) = plan else {
        return Ok(Results::Covariance(Box::new(single_scattering_file(
            &task,
        )?)));
    };
    evaluate_plan(kind, &task, plan, budget, watch)
}

/// [`evaluate`] once the plan is made (wave: one placement per chunk).
pub(crate) fn evaluate_plan(
    kind: Kind,
    task: &SceneTask,
    plan: Plan,
    budget: &super::budget::Budget,
    watch: &super::Watch,
) -> Result<Results> {
    let job = Job::Scene(task);
    let whole = job.units(kind, &plan);
    let bar = Progress::watched(watch, progress_units(kind, whole, &plan));
    let checkpoint = Checkpoint::stop_only(Some(&watch.stop));
    let t0 = Instant::now();
    let work = Work {
        plan: &plan,
        range: 0..whole,
        done: Vec::new(),
        checkpoint,
    };
    let blocks = compute(kind, job, work, budget, &bar)?;
    results(kind, task, &plan, blocks, t0.elapsed().as_secs_f64())
}

/// The Monte Carlo run's echo (chunking and path reversal included).
pub(crate) fn mc_echo(task: &SceneTask, scene: &Scene, plan: &Plan, seconds: f64) -> RunEcho {
    let mut echo = RunEcho::new(&task.config, scene, plan.samples(), plan.seed, seconds);
    echo.chunk = Some(plan.chunk_paths);
    echo.reversed = Some(task.config.render.reversed);
    echo
}

/// The mean fields `m[l][v]` of every pair (closed form, paper 001 Eq. 20).
fn mean_fields(scene: &Scene) -> Vec<C64> {
    scene
        .lights
        .iter()
        .flat_map(|l| scene.views.iter().map(move |v| mean_field(scene, l, v)))
        .collect()
}

/// Refuse to write a result holding non-finite numbers.
pub(crate) fn check_finite<'a>(
    what: &str,
    values: impl IntoIterator<Item = &'a C64>,
) -> Result<()> {
    if values
        .into_iter()
        .any(|z| !z.re.is_finite() || !z.im.is_finite())
    {
        return Err(Error::Numerical(format!(
            "{what}: the estimate holds non-finite values; nothing was written"
        )));
    }
    Ok(())
}

/// `covariance.json` of a Monte Carlo run: total, single- and multiple-scattering parts.
fn covariance_file(
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<CovarianceFile> {
    let scene = &task.scene;
    let root = merge(blocks, plan.chunks)?;
    let e = Estimate::from_block(&root, plan);
    check_finite("covariance", &e.mean)?;
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let j = nl * nv;
    let part = |order: Order| {
        let (m, s) = (order.block(j, &e.mean), order.block(j, &e.stderr));
        (
            Some(nest4(nl, nv, |i| m[i].re)),
            Some(nest4(nl, nv, |i| m[i].im)),
            Some(nest4(nl, nv, |i| s[i])),
        )
    };
    let mut file = CovarianceFile::new(
        mc_echo(task, scene, plan, seconds),
        nl,
        nv,
        Order::Total.block(j, &e.mean),
        Order::Total.block(j, &e.stderr),
        &mean_fields(scene),
    );
    (file.single_re, file.single_im, file.single_stderr) = part(Order::Single);
    (file.multiple_re, file.multiple_im, file.multiple_stderr) = part(Order::Multiple);
    Ok(file)
}

fn write_covariance(file: &CovarianceFile, out: &Path) -> Result<Outcome> {
    let path = out.join(CovarianceFile::NAME);
    file.write(&path)?;
    let (nl, nv) = (file.re.len(), file.mean_re.first().map_or(0, |m| m.len()));
    let diag = (0..nl).flat_map(|l| (0..nv).map(move |v| file.re[l][l][v][v]));
    let (lo, hi) = diag.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    });
    let run = &file.run;
    let summary = match file.solver.as_deref() {
        Some("foldy-lax") => format!(
            "{} placements, ~{:.0} scatterers each; {}",
            run.samples,
            file.scatterers_mean.unwrap_or(0.0),
            run.seconds
                .map_or("merged from shards".into(), |s| format!("took {s:.1} s"))
        ),
        Some("single_scattering") => format!(
            "single-scattering covariance of {nl} light(s) × {nv} view(s) in closed form ({:.3} s)",
            run.seconds.unwrap_or(0.0)
        ),
        _ => format!(
            "covariance of {nl} light(s) × {nv} view(s) from {} paths; intensity range {lo:.4e} … {hi:.4e}",
            run.samples
        ),
    };
    Ok(Outcome {
        not_converged: None,
        files: vec![path],
        summary,
    })
}

/// `memory_effect.json` and the curve it is plotted from.
fn memory_file(
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<(MemoryEffectFile, MemoryCurve)> {
    let scan = memory_scan(task)?;
    let root = merge(blocks, plan.chunks)?;
    let curve = scan.curve(&root, plan);
    if curve
        .correlation
        .iter()
        .chain(&curve.stderr)
        .any(|x| !x.is_finite())
    {
        return Err(Error::Numerical(
            "memory-effect: the curve holds non-finite values: no light reached the view (its intensity C(0) is 0); check medium.mfp, medium.albedo, the geometry and the view's direction; nothing was written".into(),
        ));
    }
    let file = MemoryEffectFile {
        run: mc_echo(task, &scan.scene, plan, seconds),
        angles_deg: curve.angles_deg.clone(),
        correlation: curve.correlation.clone(),
        correlation_stderr: curve.stderr.clone(),
        field_correlation: curve.field_correlation.clone(),
        diffusion_eq39: curve.diffusion.clone(),
        thickness: curve.thickness,
    };
    Ok((file, curve))
}

fn write_memory(file: &MemoryEffectFile, curve: &MemoryCurve, out: &Path) -> Result<Outcome> {
    let path = out.join(MemoryEffectFile::NAME);
    file.write(&path)?;
    let png = out.join("memory_effect.png");
    crate::io::plot::memory_effect(&png, curve)
        .map_err(|e| Error::input(format!("cannot write {}: {e}", png.display())))?;
    let mut summary = String::from("angle [deg]   correlation ± stderr   Eq. 39\n");
    for i in 0..curve.angles_deg.len() {
        summary += &format!(
            "{:>10.5}   {:.4} ± {:.4}      {:.4}\n",
            curve.angles_deg[i], curve.correlation[i], curve.stderr[i], curve.diffusion[i]
        );
    }
    Ok(Outcome {
        not_converged: None,
        files: vec![path, png],
        summary,
    })
}

/// `speckle.json`: one field per light and view for every realisation.
fn speckle_file(
    task: &SceneTask,
    plan: &Plan,
    mut blocks: Vec<Block>,
    seconds: f64,
) -> Result<SpeckleFile> {
    let scene = &task.scene;
    let reals = realisations(&task.config);
    blocks.sort_by_key(|b| b.start);
    let got: Vec<u64> = blocks.iter().map(|b| b.start).collect();
    if got != (0..reals).collect::<Vec<_>>() {
        return Err(Error::input(format!(
            "speckle: realisations {got:?} do not cover 0..{reals} exactly (a shard is missing)"
        )));
    }
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let means = mean_fields(scene);
    let norm = 1.0 / (plan.samples() as f64).sqrt();
    let fields: Vec<Vec<C64>> = blocks
        .iter()
        .map(|b| {
            b.sum
                .iter()
                .zip(&means)
                .map(|(s, m)| m + s * norm)
                .collect()
        })
        .collect();
    check_finite("speckle", fields.iter().flatten())?;
    Ok(SpeckleFile {
        run: mc_echo(task, scene, plan, seconds),
        re: fields.iter().map(|u| nest2(nl, nv, |a| u[a].re)).collect(),
        im: fields.iter().map(|u| nest2(nl, nv, |a| u[a].im)).collect(),
        realisations: reals,
        paths_per_image: plan.samples(),
    })
}

fn write_speckle(file: &SpeckleFile, out: &Path) -> Result<Outcome> {
    let path = out.join(SpeckleFile::NAME);
    file.write(&path)?;
    let mut files = vec![path];
    let nl = file.run.lights.len();
    let nv = file.run.views.len();
    let (w, h) = crate::io::image_shape(&file.run.config, nv);
    for (r, (re, im)) in file.re.iter().zip(&file.im).enumerate() {
        let u: Vec<C64> = re
            .iter()
            .zip(im)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(&x, &y)| C64::new(x, y)))
            .collect();
        let p = out.join(format!("speckle_{r:04}.exr"));
        files.extend(
            crate::io::exr::write_fields(&p, &u, nl, w, h)
                .map_err(|e| Error::input(format!("cannot write {}: {e}", p.display())))?,
        );
    }
    Ok(Outcome {
        not_converged: None,
        summary: format!(
            "{} speckle image(s) of {nl} light(s) × {nv} view(s), {} paths each",
            file.realisations, file.paths_per_image
        ),
        files,
    })
}
