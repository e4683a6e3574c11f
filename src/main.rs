//! The `lightpath` command line: parse, call the library, print.

use clap::{Args, Parser, Subcommand};
use lightpath::io::Config;
use lightpath::jobs::{self, Kind, Options};
use std::path::PathBuf;
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
        /// Refuse scenes with more expected scatterers than this
        #[arg(long, default_value_t = 6000.0)]
        max_scatterers: f64,
        /// Refuse scenes whose dense solves need more memory than this (all threads)
        #[arg(long, default_value_t = 8.0)]
        max_memory_gb: f64,
        /// Refuse runs whose timed estimate exceeds this many minutes
        #[arg(long, default_value_t = 240.0)]
        max_minutes: f64,
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
        /// Proposal re-centring stages
        #[arg(long, default_value_t = 3)]
        stages: usize,
        /// L-BFGS iterations per stage (default 15), or Adam iterations (default 150)
        #[arg(long)]
        iterations: Option<usize>,
        /// lbfgs (few parameters, deterministic objective) or adam (many parameters, burn);
        /// default: adam when fitting `phase`
        #[arg(long)]
        optimizer: Option<String>,
        /// Adam step size in the unconstrained variables (log ρ, log mfp, …)
        #[arg(long, default_value_t = 0.05)]
        learning_rate: f64,
        /// Weight of the smoothness prior Σ (Δ² log ρ)² on a fitted phase function
        #[arg(long, default_value_t = 0.0)]
        smooth: f64,
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
    },
    /// Check a config and print the scene it describes, without running anything
    Check { config: PathBuf },
    /// Measure paths/s, covariance entry-updates/s, field pixel-updates/s and the GEMM rate
    Bench {
        /// Shorter measurement (for a smoke test)
        #[arg(long)]
        quick: bool,
        /// Instead, time one GRIN design iteration at the published GPU scale (128³ grid, 128² × 10
        /// rays, 400 steps; a few minutes)
        #[arg(long)]
        design_iteration: bool,
    },
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
    /// No progress bar
    #[arg(long)]
    quiet: bool,
}

fn parse_shard(s: &str) -> Result<(u64, u64), String> {
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

fn with_threads<T: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> Result<T, String> {
    match threads {
        None => Ok(f()),
        Some(0) => Err("--threads 0: must be at least 1".into()),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| e.to_string())?;
            Ok(pool.install(f))
        }
    }
}

fn run(kind: Kind, a: RunArgs) -> Result<jobs::Outcome, String> {
    let cfg = Config::from_file(&a.config).map_err(|e| e.0)?;
    let opts = Options {
        samples: a.samples,
        seed: a.seed,
        shard: a.shard,
        progress: !a.quiet,
    };
    with_threads(a.threads, || jobs::run_job(kind, cfg, &opts, &a.out))?
}

/// Whether a config file is a `trace` config (it has a top-level `[field]` table).
/// `(has [field], has [[beam]])`: a trace config has the first, a design config both.
fn eikonal_config_kind(path: &std::path::Path) -> (bool, bool) {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| t.parse::<toml::Table>().ok())
        .map_or((false, false), |t| {
            (t.contains_key("field"), t.contains_key("beam"))
        })
}

/// Whether a design config fits analytic parameters (a `[parameters]` table) instead of a grid.
fn has_parameters(path: &std::path::Path) -> bool {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| t.parse::<toml::Table>().ok())
        .is_some_and(|t| t.contains_key("parameters"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        None => {
            let cfg = Config::from_toml(QUICKSTART, None)
                .map_err(|e| format!("embedded quick start: {e}"));
            let out = PathBuf::from("lightpath-out");
            eprintln!(
                "lightpath quick start: memory effect of a slab (L = 200 λ, optical depth 10) → {}/",
                out.display()
            );
            cfg.and_then(|cfg| {
                jobs::run_job(
                    Kind::MemoryEffect,
                    cfg,
                    &Options {
                        progress: true,
                        ..Default::default()
                    },
                    &out,
                )
            })
        }
        Some(Command::Covariance(a)) => run(Kind::Covariance, a),
        Some(Command::Speckle(a)) => run(Kind::Speckle, a),
        Some(Command::MemoryEffect(a)) => run(Kind::MemoryEffect, a),
        Some(Command::Merge { shards, out }) => jobs::merge_job(&shards, &out),
        Some(Command::Wave {
            config,
            out,
            realizations,
            seed,
            threads,
            max_scatterers,
            max_memory_gb,
            max_minutes,
            quiet,
        }) => Config::from_file(&config).map_err(|e| e.0).and_then(|cfg| {
            let limits = jobs::WaveLimits {
                max_scatterers,
                max_memory_gb,
                max_minutes,
            };
            with_threads(threads, || {
                jobs::wave_job(cfg, realizations, seed, limits, !quiet, &out)
            })?
        }),
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
            quiet,
        }) => Config::from_file(&config).map_err(|e| e.0).and_then(|cfg| {
            let opts = jobs::FitOptions {
                fit,
                samples,
                seed,
                stages,
                iterations,
                optimizer,
                learning_rate,
                smooth,
                progress: !quiet,
            };
            with_threads(threads, || jobs::fit_job(cfg, &target, &opts, &out))?
        }),
        Some(Command::Trace {
            config,
            out,
            threads,
        }) => lightpath::io::trace_config::TraceConfig::from_file(&config)
            .map_err(|e| e.0)
            .and_then(|cfg| with_threads(threads, || jobs::trace_job(&cfg, &out))?),
        Some(Command::Design {
            config,
            out,
            threads,
            quiet,
        }) if has_parameters(&config) => {
            lightpath::io::design_config::ParamFitConfig::from_file(&config)
                .map_err(|e| e.0)
                .and_then(|cfg| with_threads(threads, || jobs::param_fit_job(&cfg, !quiet, &out))?)
        }
        Some(Command::Design {
            config,
            out,
            threads,
            quiet,
        }) => lightpath::io::design_config::DesignConfig::from_file(&config)
            .map_err(|e| e.0)
            .and_then(|cfg| with_threads(threads, || jobs::design_job(&cfg, !quiet, &out))?),
        Some(Command::Compare {
            a,
            b,
            tolerance,
            plot,
        }) => {
            return match jobs::compare_job(&a, &b, tolerance, plot.as_deref()) {
                Ok((report, agree)) => {
                    println!("{report}");
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
        Some(Command::Check { config })
            if eikonal_config_kind(&config) == (true, true) && has_parameters(&config) =>
        {
            lightpath::io::design_config::ParamFitConfig::from_file(&config)
                .map_err(|e| e.0)
                .and_then(|c| {
                    let p = c.problem().map_err(|e| e.0)?;
                    Ok(jobs::Outcome {
                        files: vec![],
                        summary: format!(
                            "{}: ok — parameter fit config, {} beam(s), {} ray(s), fitting {}",
                            config.display(),
                            p.beams.len(),
                            p.beams.iter().map(|b| b.rays.len()).sum::<usize>(),
                            p.names.join(", ")
                        ),
                    })
                })
        }
        Some(Command::Check { config }) if eikonal_config_kind(&config) == (true, true) => {
            lightpath::io::design_config::DesignConfig::from_file(&config)
                .map_err(|e| e.0)
                .and_then(|c| {
                    let p = c.problem().map_err(|e| e.0)?;
                    Ok(jobs::Outcome {
                        files: vec![],
                        summary: format!(
                            "{}: ok — design config, {} beam(s), {} ray(s), levels {:?}",
                            config.display(),
                            p.beams.len(),
                            p.beams.iter().map(|b| b.rays.len()).sum::<usize>(),
                            p.levels
                        ),
                    })
                })
        }
        Some(Command::Check { config }) if eikonal_config_kind(&config).0 => {
            lightpath::io::trace_config::TraceConfig::from_file(&config)
                .map_err(|e| e.0)
                .and_then(|c| {
                    c.field().map_err(|e| e.0)?;
                    let rays = c.rays().map_err(|e| e.0)?;
                    Ok(jobs::Outcome {
                        files: vec![],
                        summary: format!(
                            "{}: ok — trace config, {} ray(s)",
                            config.display(),
                            rays.len()
                        ),
                    })
                })
        }
        Some(Command::Check { config }) => {
            Config::from_file(&config).map_err(|e| e.0).and_then(|c| {
                let s = c.scene().map_err(|e| e.0)?;
                Ok(jobs::Outcome {
                    files: vec![],
                    summary: format!(
                        "{}: ok — {} light(s), {} view(s), σ_s = {}, σ_a = {}, k = {:.6}",
                        config.display(),
                        s.lights.len(),
                        s.views.len(),
                        s.medium.sigma_s,
                        s.medium.sigma_a,
                        s.k
                    ),
                })
            })
        }
        Some(Command::Bench {
            design_iteration: true,
            ..
        }) => lightpath::bench::design_iteration().map(|summary| jobs::Outcome {
            files: vec![],
            summary,
        }),
        Some(Command::Bench { quick, .. }) => {
            lightpath::bench::run(quick).map(|summary| jobs::Outcome {
                files: vec![],
                summary,
            })
        }
    };
    match result {
        Ok(o) => {
            println!("{}", o.summary.trim_end());
            for f in o.files {
                println!("wrote {}", f.display());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}
