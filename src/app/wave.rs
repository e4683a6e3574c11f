//! `lightpath wave`: Foldy–Lax solutions over scatterer placements ([`crate::speckle::wave`]), run
//! on the Monte Carlo engine (one placement per chunk), reduced to the mean, the covariance and
//! their standard errors in the format of `covariance.json`. Shards and `merge` work as for every
//! other run.

use super::Outcome;
use super::run::{Kind, RunOptions, execute};
use crate::config::SceneTask;
use crate::error::{Error, Result};
use crate::io::results::{CovarianceFile, RunEcho, nest2};
use crate::mc::{Block, Plan, merge};
use crate::speckle::wave::{self, WaveStatistics};
use std::path::Path;

/// Limits of the wave solver's dense solves.
#[derive(Clone, Copy, Debug)]
pub struct WaveLimits {
    pub max_scatterers: f64,
    pub max_memory_gb: f64,
    pub max_minutes: f64,
}

/// Options of `lightpath wave`.
#[derive(Clone, Debug)]
pub struct WaveOptions {
    pub realizations: u64,
    pub seed: Option<u64>,
    pub shard: Option<(u64, u64)>,
    pub limits: WaveLimits,
    pub progress: bool,
    /// Continue the interrupted run whose checkpoint is in this folder.
    pub resume: Option<std::path::PathBuf>,
    /// Save a checkpoint every this many placements (default: every two minutes).
    pub checkpoint_every: Option<u64>,
}

/// Check the scene and the limits (size, memory, timed estimate), then run.
pub fn run(mut task: SceneTask, opts: &WaveOptions, out: &Path) -> Result<Outcome> {
    let share = opts.shard.map_or(1.0, |(_, n)| 1.0 / n as f64);
    let (plan, size) = prepare(&mut task, opts.realizations, opts.seed, &opts.limits, share)?;
    if opts.progress {
        eprintln!("wave: {size}");
    }
    let run_opts = RunOptions {
        samples: None,
        seed: None,
        shard: opts.shard,
        progress: opts.progress,
        resume: opts.resume.clone(),
        checkpoint_every: opts.checkpoint_every,
        ..Default::default()
    };
    let mut outcome = execute(
        Kind::Wave,
        super::run::Job::Scene(&task),
        plan,
        &run_opts,
        out,
    )?;
    if opts.shard.is_none() {
        outcome.summary = format!("wave solver: {size}; {}", outcome.summary);
    }
    Ok(outcome)
}

/// The wave solver's `covariance.json` in memory (see [`super::run::evaluate`]): the same
/// checks and limits as `lightpath wave`, nothing written, stopped through `watch`.
pub fn evaluate(
    mut task: SceneTask,
    realizations: u64,
    seed: Option<u64>,
    limits: &WaveLimits,
    watch: &super::Watch,
) -> Result<CovarianceFile> {
    let (plan, _) = prepare(&mut task, realizations, seed, limits, 1.0)?;
    let budget = super::budget::Budget {
        max_minutes: limits.max_minutes,
        max_memory_gb: limits.max_memory_gb,
    };
    match super::run::evaluate_plan(Kind::Wave, &task, plan, &budget, watch)? {
        super::run::Results::Covariance(file) => Ok(*file),
        _ => Err(Error::input("wave: the run gave no covariance")),
    }
}

/// Check the scene and the limits for `share` of `realizations` placements: the plan (one
/// placement per chunk) and what the solves will take, in words.
fn prepare(
    task: &mut SceneTask,
    realizations: u64,
    seed: Option<u64>,
    limits: &WaveLimits,
    share: f64,
) -> Result<(Plan, String)> {
    if realizations < 2 {
        return Err(Error::input(format!(
            "--realizations {realizations}: need at least 2 for a covariance"
        )));
    }
    if let Some(s) = seed {
        task.config.render.seed = s;
    }
    let scene = &task.scene;
    wave::check_scene(scene)?;
    let n = wave::expected_scatterers(scene);
    let n_hi = n + 6.0 * n.sqrt() + 10.0;
    let threads = rayon::current_num_threads() as f64;
    let gb = threads * (2.0 * 16.0 * n_hi * n_hi) / 1e9;
    let size = format!(
        "the scene has ~{n:.0} scatterers (σ_s·V/c_s with c_s = λ²/π = {:.4}): dense solves need ~{gb:.2} GB with {threads} threads",
        wave::cross_section(scene.k)
    );
    if n > limits.max_scatterers || gb > limits.max_memory_gb {
        return Err(Error::input(format!(
            "wave: {size}, beyond the limits (--max-scatterers {}, --max-memory-gb {}). The count grows as σ_s·V/λ²: shrink the box, lower σ_s (raise mfp), or raise the limits",
            limits.max_scatterers, limits.max_memory_gb
        )));
    }
    let mut rng = crate::math::stream_rng(task.config.render.seed ^ 0x7469_6d65, 0);
    let secs = share * realizations as f64 * wave::seconds_per_solve(scene, n, &mut rng) / threads;
    let size =
        format!("{size}, and ~{secs:.0} s for {realizations} realizations (timed on this machine)");
    if secs > 60.0 * limits.max_minutes {
        return Err(Error::input(format!(
            "wave: {size}, beyond --max-minutes {}. Use fewer --realizations, a smaller or sparser scene, more --threads, or raise --max-minutes",
            limits.max_minutes
        )));
    }
    let plan = Plan {
        seed: task.config.render.seed,
        chunk_paths: 1,
        chunks: realizations,
    };
    Ok((plan, size))
}

/// Reduce the placements' fields (kept one per chunk) to `covariance.json`.
pub(crate) fn covariance_file(
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<CovarianceFile> {
    let scene = &task.scene;
    let root = merge(blocks, plan.chunks)?;
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let j = nl * nv;
    let stats = WaveStatistics::from_fields(&root.kept, j);
    super::run::check_finite("wave", stats.covariance.iter().chain(&stats.mean)).map_err(
        |_| {
            Error::Numerical("wave: the solve produced non-finite fields (a singular Foldy–Lax system); nothing was written".into())
        },
    )?;
    let r = plan.chunks;
    let mut echo = RunEcho::new(&task.config, scene, r, plan.seed, seconds);
    echo.chunk = None;
    let mut file = CovarianceFile::new(
        echo,
        nl,
        nv,
        &stats.covariance,
        &stats.covariance_stderr,
        &stats.mean,
    );
    file.mean_stderr = Some(nest2(nl, nv, |a| stats.mean_stderr[a]));
    file.realizations = Some(r);
    file.solver = Some("foldy-lax".into());
    file.scatterers_mean = Some(root.sum[j].re / r as f64);
    file.scatterers_expected = Some(wave::expected_scatterers(scene));
    Ok(file)
}
