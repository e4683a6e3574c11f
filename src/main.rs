//! The `lightpath` command line: parse, call the library, print.

use clap::{Args, Parser, Subcommand, ValueEnum};
use lightpath::app::{self, Outcome, with_threads};
use lightpath::config::{self, Task, TaskKind};
use lightpath::{Error, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The quick-start scene run by `lightpath` with no arguments.
const QUICKSTART: &str = include_str!("../configs/quickstart.toml");

#[derive(Parser)]
#[command(
    name = "lightpath",
    version,
    about = "Speckle statistics of light in scattering media (paper: Bar et al. 2019).\n\nWith no command, runs the embedded quick start (a memory-effect curve) into ./lightpath-out/."
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Speckle covariance C[l1][l2][v1][v2] with standard errors (Algorithm 1) → covariance.json
    Covariance(RunArgs),
    /// Jointly correlated speckle images for all lights (Algorithm 2) → speckle.json + EXR
    Speckle(RunArgs),
    /// Intensity correlation vs tilt angle, against Eq. 39 → memory_effect.json + PNG
    MemoryEffect(RunArgs),
    /// Near-field correlation maps C(Δ, τ) of focused lights and views (paper 000, Eq. 48) → correlation_map.json + PNG
    CorrelationMap(RunArgs),
    /// Tilt-shift memory-effect correlations C(Δa, Δb, θ) of two focused beams (paper 000, Eq. 49) beside the model of Eq. 50 → tilt_shift.json + PNG
    TiltShift(RunArgs),
    /// Render a refractive, scattering volume (curved rays, Fresnel surfaces) by particle tracing
    /// → render.json + screen EXR/PNG images
    Render(RunArgs),
    /// Merge the shards of one run (folders holding state.bin) into the single run's results
    Merge {
        /// Shard folders (or state.bin files)
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        #[arg(long)]
        out: PathBuf,
    },
    /// Wave-optics ground truth: Foldy–Lax solutions averaged over scatterer placements → covariance.json
    Wave {
        /// Scene config (TOML), the same as for the Monte Carlo commands
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Number of independent scatterer placements
        #[arg(long, default_value_t = 200)]
        realizations: u64,
        #[arg(long)]
        seed: Option<u64>,
        #[arg(long)]
        threads: Option<usize>,
        /// Run shard i of n (e.g. 2/8) and write state.bin for `lightpath merge`
        #[arg(long, value_parser = parse_shard)]
        shard: Option<(u64, u64)>,
        /// Refuse scenes with more expected scatterers than this
        #[arg(long, default_value_t = 6000.0)]
        max_scatterers: f64,
        /// Refuse scenes whose dense solves need more memory than this (all threads)
        #[arg(long, default_value_t = 8.0)]
        max_memory_gb: f64,
        /// Refuse runs whose timed estimate exceeds this many minutes
        #[arg(long, default_value_t = 240.0)]
        max_minutes: f64,
        #[command(flatten)]
        checkpoints: CheckpointArgs,
        #[arg(long)]
        quiet: bool,
    },
    /// Compare two covariance.json files (e.g. Monte Carlo vs wave); exit 1 if they disagree
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Largest acceptable ‖A − B‖ / ‖B‖ per light pair
        #[arg(long, default_value_t = 0.1)]
        tolerance: f64,
        /// Write diagonal and matrix plots (PNG) into this folder
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Fit medium parameters (mfp, albedo, g, sigma_s, sigma_a, phase) so rendered statistics match a target
    Fit {
        config: PathBuf,
        /// memory_effect.json / covariance.json of a run, or a measured curve (CSV angle_deg,correlation[,stderr])
        #[arg(long)]
        target: PathBuf,
        /// Parameters to fit, comma separated, e.g. mfp,g; `phase` fits every node value of a
        /// tabulated phase function (with Adam)
        #[arg(long)]
        fit: String,
        #[arg(long)]
        out: PathBuf,
        /// Subpaths per objective evaluation (default: render.samples)
        #[arg(long)]
        samples: Option<u64>,
        #[arg(long)]
        seed: Option<u64>,
        #[arg(long)]
        threads: Option<usize>,
        /// At most this many trust-region stages (each re-centres the proposal); the fit stops
        /// earlier when it has converged
        #[arg(long, default_value_t = 30)]
        stages: usize,
        /// L-BFGS iterations per stage (default 15), or Adam iterations (default 150)
        #[arg(long)]
        iterations: Option<usize>,
        /// lbfgs (few parameters, deterministic objective) or adam (many parameters, burn);
        /// default: adam when fitting `phase`
        #[arg(long, value_enum)]
        optimizer: Option<Optimizer>,
        /// Adam step size in the unconstrained variables (log ρ, log mfp, …)
        #[arg(long, default_value_t = 0.05)]
        learning_rate: f64,
        /// Weight of the smoothness prior Σ (Δ² log ρ)² on a fitted phase function
        #[arg(long, default_value_t = 0.0)]
        smooth: f64,
        /// Limits on one objective evaluation
        #[command(flatten)]
        budget: BudgetArgs,
        #[command(flatten)]
        checkpoints: CheckpointArgs,
        #[arg(long)]
        quiet: bool,
    },
    /// Trace rays through a graded-index field (eikonal) → rays.json + rays.png
    Trace {
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        threads: Option<usize>,
        /// Refuse runs whose estimated time (a timed pilot of a few rays) exceeds this many minutes
        #[arg(long, default_value_t = 240.0)]
        max_minutes: f64,
    },
    /// Design a graded-index field so beams pass through their foci: a grid (coarse to fine) by
    /// Adam through the adjoint → design.json + loss.png + profile.png + grid_slice_z.exr; or, with
    /// a `[parameters]` table, analytic parameters by L-BFGS → fit.json + loss.png + rays.png
    Design {
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        threads: Option<usize>,
        #[arg(long)]
        quiet: bool,
        /// Refuse designs whose estimated time (every iteration at the timed pilot's cost) exceeds
        /// this many minutes
        #[arg(long, default_value_t = 240.0)]
        max_minutes: f64,
        #[command(flatten)]
        checkpoints: CheckpointArgs,
    },
    /// Spheres by Lorenz–Mie theory: efficiencies, cross-sections, g, amplitudes S1/S2 and the
    /// phase function (one diameter, or a log-normal distribution) → mie.json + mie.png
    Mie {
        /// Sphere diameter (the mean, with --diameter-spread), in the unit of --wavelength
        #[arg(long)]
        diameter: f64,
        /// Standard deviation of a log-normal diameter distribution (default: all spheres equal)
        #[arg(long, default_value_t = 0.0)]
        diameter_spread: f64,
        /// Real part of the particle's refractive index
        #[arg(long)]
        n_particle: f64,
        /// Imaginary part of the particle's refractive index (absorption, >= 0)
        #[arg(long, default_value_t = 0.0)]
        k_particle: f64,
        /// Refractive index of the host medium
        #[arg(long, default_value_t = 1.0)]
        n_medium: f64,
        /// Vacuum wavelength
        #[arg(long)]
        wavelength: f64,
        /// Number of scattering angles from 0° to 180° in the output
        #[arg(long, default_value_t = 361)]
        angles: usize,
        /// Also give σ_s, σ_a, mfp and albedo of this volume fraction of spheres
        #[arg(long)]
        volume_fraction: Option<f64>,
        #[arg(long)]
        out: PathBuf,
    },
    /// Read a phase function from speckle image pairs under tilted illuminations (windowed
    /// correlations ⟂ Δ, paper 004) → phase_acquisition.json + PNG
    AcquirePhase {
        /// Acquisition config ([acquisition] + [[pair]])
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Check a config and print the scene it describes, without running anything
    Check { config: PathBuf },
    /// Measure paths/s, covariance entry-updates/s, field pixel-updates/s and the GEMM rate
    Bench {
        /// Shorter measurement (for a smoke test)
        #[arg(long)]
        quick: bool,
        /// Instead, time one GRIN design iteration at the published GPU scale (128³ grid, 128² × 10
        /// rays, 400 steps; with its dgemm reference, about 15 s on 2 cores)
        #[arg(long)]
        design_iteration: bool,
    },
}

/// The optimiser of `lightpath fit`.
#[derive(Clone, Copy, ValueEnum)]
enum Optimizer {
    Lbfgs,
    Adam,
}

#[derive(Args)]
struct RunArgs {
    /// Scene config (TOML)
    config: PathBuf,
    /// Output folder
    #[arg(long)]
    out: PathBuf,
    /// Override render.samples (speckle: subpaths per image)
    #[arg(long)]
    samples: Option<u64>,
    /// Override render.seed
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores); results do not depend on it
    #[arg(long)]
    threads: Option<usize>,
    /// Run shard i of n (e.g. 2/8) and write state.bin for `lightpath merge`
    #[arg(long, value_parser = parse_shard)]
    shard: Option<(u64, u64)>,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    checkpoints: CheckpointArgs,
    /// No progress bar
    #[arg(long)]
    quiet: bool,
}

/// Saving and resuming long runs.
#[derive(Args)]
struct CheckpointArgs {
    /// Continue the interrupted run whose checkpoint.bin is in this folder (give the same
    /// command, config and options that started it); the result is bit-identical to an
    /// uninterrupted run
    #[arg(long, value_name = "DIR")]
    resume: Option<PathBuf>,
    /// Save checkpoint.bin every N chunks (speckle: every N images; fit and design: every N
    /// evaluations or iterations); default: every two minutes
    #[arg(long, value_name = "N")]
    checkpoint_every: Option<u64>,
}

impl CheckpointArgs {
    fn resume(&self) -> app::Resume {
        app::Resume {
            from: self.resume.clone(),
            every: self.checkpoint_every,
        }
    }
}

/// What a run may use: refused before any work when the estimate is beyond it.
#[derive(Args)]
struct BudgetArgs {
    /// Refuse runs whose estimated time (this shard's share) exceeds this many minutes
    #[arg(long, default_value_t = 240.0)]
    max_minutes: f64,
    /// Refuse runs whose estimated memory exceeds this many GB (all threads)
    #[arg(long, default_value_t = 8.0)]
    max_memory_gb: f64,
}

impl BudgetArgs {
    fn budget(&self) -> app::budget::Budget {
        app::budget::Budget {
            max_minutes: self.max_minutes,
            max_memory_gb: self.max_memory_gb,
        }
    }
}

/// The budget of the ray commands: time only (their memory is small and bounded by the config).
fn minutes_only(max_minutes: f64) -> app::budget::Budget {
    app::budget::Budget {
        max_minutes,
        ..Default::default()
    }
}

fn parse_shard(s: &str) -> std::result::Result<(u64, u64), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("--shard {s}: expected i/n, e.g. 0/4"))?;
    let i: u64 = i
        .trim()
        .parse()
        .map_err(|_| format!("--shard {s}: i must be a whole number"))?;
    let n: u64 = n
        .trim()
        .parse()
        .map_err(|_| format!("--shard {s}: n must be a whole number"))?;
    if n == 0 || i >= n {
        return Err(format!("--shard {s}: need 0 <= i < n"));
    }
    Ok((i, n))
}

/// Load `path` and require the speckle scene the command needs.
fn scene(path: &Path, command: &str) -> Result<config::SceneTask> {
    Ok(config::load(path)?.into_scene(&format!("lightpath {command} {}", path.display()))?)
}

fn run(kind: app::run::Kind, a: RunArgs) -> Result<Outcome> {
    let task = scene(&a.config, kind.name())?;
    let opts = run_options(&a);
    with_threads(a.threads, || app::run::run_scene(kind, task, &opts, &a.out))
}

fn run_options(a: &RunArgs) -> app::run::RunOptions {
    app::run::RunOptions {
        samples: a.samples,
        seed: a.seed,
        shard: a.shard,
        progress: !a.quiet,
        budget: a.budget.budget(),
        resume: a.checkpoints.resume.clone(),
        checkpoint_every: a.checkpoints.checkpoint_every,
    }
}

fn dispatch(command: Option<Command>) -> Result<Outcome> {
    use app::run::Kind;
    match command {
        None => {
            let task = config::scene_from_text(QUICKSTART)
                .map_err(|e| Error::input(format!("embedded quick start: {e}")))?;
            let out = PathBuf::from("lightpath-out");
            eprintln!(
                "lightpath quick start: memory effect of a slab (L = 200 λ, optical depth 10) → {}/",
                out.display()
            );
            let opts = app::run::RunOptions {
                progress: true,
                ..Default::default()
            };
            app::run::run_scene(Kind::MemoryEffect, task, &opts, &out)
        }
        Some(Command::Covariance(a)) => run(Kind::Covariance, a),
        Some(Command::Speckle(a)) => run(Kind::Speckle, a),
        Some(Command::MemoryEffect(a)) => run(Kind::MemoryEffect, a),
        Some(Command::CorrelationMap(a)) => run(Kind::CorrelationMap, a),
        Some(Command::TiltShift(a)) => run(Kind::TiltShift, a),
        Some(Command::Render(a)) => match config::load(&a.config)? {
            Task::Render(task) => {
                let opts = run_options(&a);
                with_threads(a.threads, || app::render::run(*task, &opts, &a.out))
            }
            other => Err(wrong_task(
                &a.config,
                "render",
                other.kind(),
                &[TaskKind::Render],
            )),
        },
        Some(Command::Merge { shards, out }) => app::run::merge_shards(&shards, &out),
        Some(Command::Wave {
            config,
            out,
            realizations,
            seed,
            threads,
            shard,
            max_scatterers,
            max_memory_gb,
            max_minutes,
            checkpoints,
            quiet,
        }) => {
            let task = scene(&config, "wave")?;
            let opts = app::wave::WaveOptions {
                realizations,
                seed,
                shard,
                limits: app::wave::WaveLimits {
                    max_scatterers,
                    max_memory_gb,
                    max_minutes,
                },
                progress: !quiet,
                resume: checkpoints.resume,
                checkpoint_every: checkpoints.checkpoint_every,
            };
            with_threads(threads, || app::wave::run(task, &opts, &out))
        }
        Some(Command::Fit {
            config,
            target,
            fit,
            out,
            samples,
            seed,
            threads,
            stages,
            iterations,
            optimizer,
            learning_rate,
            smooth,
            budget,
            checkpoints,
            quiet,
        }) => {
            let task = scene(&config, "fit")?;
            let opts = app::fit::FitOptions {
                fit,
                samples,
                seed,
                stages,
                iterations,
                optimizer: optimizer.map(|o| match o {
                    Optimizer::Lbfgs => "lbfgs".to_string(),
                    Optimizer::Adam => "adam".to_string(),
                }),
                learning_rate,
                smooth,
                progress: !quiet,
                budget: budget.budget(),
                resume: checkpoints.resume(),
            };
            with_threads(threads, || app::fit::fit(task, &target, &opts, &out))
        }
        Some(Command::Trace {
            config,
            out,
            threads,
            max_minutes,
        }) => match config::load(&config)? {
            Task::Trace(t) => with_threads(threads, || {
                app::grin::trace(&t, &minutes_only(max_minutes), &out)
            }),
            other => Err(wrong_task(
                &config,
                "trace",
                other.kind(),
                &[TaskKind::Trace],
            )),
        },
        Some(Command::Design {
            config,
            out,
            threads,
            quiet,
            max_minutes,
            checkpoints,
        }) => match config::load(&config)? {
            Task::Design(t) => with_threads(threads, || {
                let budget = minutes_only(max_minutes);
                app::grin::design(&t, !quiet, &budget, &checkpoints.resume(), &out)
            }),
            Task::ParamFit(t) => with_threads(threads, || {
                let budget = minutes_only(max_minutes);
                app::grin::param_fit(&t, !quiet, &budget, &checkpoints.resume(), &out)
            }),
            Task::Render(t) if t.design.is_some() => with_threads(threads, || {
                let budget = minutes_only(max_minutes);
                app::render_design::design(&t, !quiet, &budget, &checkpoints.resume(), &out)
            }),
            other => Err(wrong_task(
                &config,
                "design",
                other.kind(),
                &[TaskKind::Design, TaskKind::ParamFit],
            )),
        },
        Some(Command::Compare { .. }) => unreachable!("handled in main"),
        Some(Command::Mie {
            diameter,
            diameter_spread,
            n_particle,
            k_particle,
            n_medium,
            wavelength,
            angles,
            volume_fraction,
            out,
        }) => app::mie::run(
            &app::mie::MieRequest {
                diameter,
                diameter_spread,
                n_particle,
                k_particle,
                n_medium,
                vacuum_wavelength: wavelength,
                angles,
                volume_fraction,
            },
            &out,
        ),
        Some(Command::AcquirePhase { config, out }) => match config::load(&config)? {
            Task::Acquire(t) => app::acquire_phase::run(&t, &out),
            other => Err(wrong_task(
                &config,
                "acquire-phase",
                other.kind(),
                &[TaskKind::Acquire],
            )),
        },
        Some(Command::Check { config }) => app::check::check(&config),
        Some(Command::Bench {
            design_iteration: true,
            ..
        }) => Ok(Outcome::text(app::bench::design_iteration()?)),
        Some(Command::Bench { quick, .. }) => Ok(Outcome::text(app::bench::run(quick)?)),
    }
}

/// The file holds another task than the command runs.
fn wrong_task(path: &Path, command: &str, got: TaskKind, wanted: &[TaskKind]) -> Error {
    let wanted: Vec<&str> = wanted.iter().map(|k| k.describe()).collect();
    Error::input(format!(
        "{}: `lightpath {command}` needs {}, but the file holds {}",
        path.display(),
        wanted.join(" or "),
        got.describe()
    ))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(Command::Compare {
        a,
        b,
        tolerance,
        plot,
    }) = &cli.command
    {
        return match app::compare::compare(a, b, *tolerance, plot.as_deref()) {
            Ok((report, agree)) => {
                say(&report);
                if agree {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::from(1)
                }
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::from(2)
            }
        };
    }
    match dispatch(cli.command) {
        Ok(o) => {
            say(o.summary.trim_end());
            for f in o.files {
                say(&format!("wrote {}", f.display()));
            }
            match o.not_converged {
                Some(warning) => {
                    eprintln!("{warning}");
                    ExitCode::from(3)
                }
                None => ExitCode::SUCCESS,
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

/// Print a line of a finished command's report; a reader that went away (`| head`) is no error:
/// the results are already written.
fn say(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stdout(), "{line}");
}
