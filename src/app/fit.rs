//! `lightpath fit`: fit medium parameters (mfp, albedo, g, σ_s, σ_a, mixture weights) and
//! tabulated phase functions so rendered statistics match a target (a memory-effect curve, a
//! covariance, or measured entries): L-BFGS on the deterministic re-weighted objective for a few
//! parameters, Adam through the burn bridge for many (phase-function node values).

use super::{Outcome, create_out};
use crate::config::{MemoryEffectConfig, SceneTask};
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{FitFile, FitLogLine, ReadingRecord};
use crate::mc::StopFlag;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `lightpath fit`.
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub fit: String,
    pub samples: Option<u64>,
    pub seed: Option<u64>,
    pub stages: usize,
    /// L-BFGS iterations per stage, or Adam iterations (defaults 15 and 150).
    pub iterations: Option<usize>,
    /// `lbfgs` or `adam` (default: adam when fitting `phase`, else lbfgs).
    pub optimizer: Option<String>,
    pub learning_rate: f64,
    pub smooth: f64,
    pub progress: bool,
    /// Refuse fits whose single objective evaluation is estimated beyond this time or memory.
    pub budget: super::budget::Budget,
    /// Checkpoints (`checkpoint.bin` in the output folder) and resuming from them.
    pub resume: super::Resume,
}

/// `lightpath fit`: fit medium parameters so rendered statistics match a target → fit.json,
/// fit.png (a memory-curve target), phase.png (a phase-function fit).
pub fn fit(task: SceneTask, target_path: &Path, opts: &FitOptions, out: &Path) -> Result<Outcome> {
    let prepared = prepare(task, target_path, opts)?;
    let journal = super::journal("fit", prepared.identity()?, &opts.resume, out)?;
    create_out(out, &["fit.json", "fit.png", "phase.png"])?;
    let show = opts.progress;
    let fitted = prepared.run(
        &|e| {
            if show {
                eprintln!("{}", prepared.line(e));
            }
        },
        &StopFlag::default(),
        &journal,
    )?;
    let outcome = fitted.write(out)?;
    super::remove_checkpoint(out)?;
    Ok(outcome)
}

/// A validated fit, ready to run: the scene the target needs, the target, and how to fit.
pub struct Prepared {
    cfg: crate::config::Config,
    scene: crate::speckle::Scene,
    target: crate::inverse::Target,
    target_name: String,
    /// CRC-32 of the target file (what a checkpoint is checked against).
    target_crc: u32,
    params: Vec<crate::inverse::FitParam>,
    phase: bool,
    adam: bool,
    iterations: usize,
    stages: usize,
    learning_rate: f64,
    smooth: f64,
}

/// A finished fit: what fit.json holds, and what its plots need.
pub struct Fitted {
    pub file: FitFile,
    target: crate::inverse::Target,
    /// For phase.png: the number of scalar parameters before the phase nodes, and the
    /// single-scattering reading of the target where it applies.
    phase_plot: Option<(usize, Vec<crate::inverse::shortcut::Reading>)>,
    pub summary: String,
}

/// Check the fit `opts` ask for against `task` and the target file (same scene, same setup,
/// parameters the medium has, one evaluation within the budget) before any path is traced.
pub fn prepare(task: SceneTask, target_path: &Path, opts: &FitOptions) -> Result<Prepared> {
    let SceneTask {
        config: mut cfg,
        scene,
    } = task;
    use crate::inverse::{FitParam, Target, check_params};
    // a C(Δ, τ) map is fitted with the map's scene, built from the config's [correlation_map]
    let map_target = if crate::io::targets::is_correlation_map(target_path) {
        Some(crate::io::targets::correlation_map(target_path)?)
    } else {
        None
    };
    let target = match &map_target {
        Some(m) => m.target.clone(),
        None => crate::io::targets::read(target_path)?,
    };
    let phase = opts.fit.split(',').any(|p| p.trim() == "phase");
    let params: Vec<FitParam> = opts
        .fit
        .split(',')
        .filter(|p| p.trim() != "phase")
        .map(FitParam::parse)
        .collect::<Result<_, _>>()?;
    if params.is_empty() && !phase {
        return Err(Error::input("--fit: give at least one parameter"));
    }
    let adam = match opts.optimizer.as_deref() {
        None => phase,
        Some("adam") => true,
        Some("lbfgs") if phase => {
            return Err(Error::input(
                "--optimizer lbfgs: fitting `phase` (many node values) needs --optimizer adam",
            ));
        }
        Some("lbfgs") => false,
        Some(other) => {
            return Err(Error::input(format!(
                "--optimizer {other:?}: allowed: adam, lbfgs"
            )));
        }
    };
    if let Some(s) = opts.samples {
        cfg.render.samples = s;
    }
    if let Some(s) = opts.seed {
        cfg.render.seed = s;
    }
    cfg.check_settings()?;
    let scene = match (&target, &map_target) {
        (Target::Memory { angles_deg, .. }, _) => {
            let axis = cfg
                .memory_effect
                .as_ref()
                .map_or([0.0, 1.0, 0.0], |m| m.axis);
            cfg.memory_effect = Some(MemoryEffectConfig {
                angles_deg: angles_deg.clone(),
                axis,
            });
            cfg.check_settings()?;
            let task = SceneTask {
                config: cfg.clone(),
                scene,
            };
            super::run::memory_scan(&task)?.scene
        }
        (_, Some(shape)) => {
            let task = SceneTask {
                config: cfg.clone(),
                scene,
            };
            let map = super::correlation_map::map_of(&task).map_err(|_| {
                Error::input(format!(
                    "target {} is a C(Δ, τ) map: the config needs the [correlation_map] table it was rendered with",
                    target_path.display()
                ))
            })?;
            let same_shifts = map.deltas.len() == shape.deltas.len()
                && map.deltas.iter().zip(&shape.deltas).all(|(a, b)| {
                    (*a - glam::DVec3::from_array(*b)).length() <= 1e-9 * (1.0 + a.length())
                });
            if !same_shifts || map.taus.len() != shape.pixels {
                return Err(Error::input(format!(
                    "target {} has shifts {:?} over {} τ, but the config's [correlation_map] gives {:?} over {}: fit with the config the map was rendered with",
                    target_path.display(),
                    shape.deltas,
                    shape.pixels,
                    map.deltas.iter().map(|d| d.to_array()).collect::<Vec<_>>(),
                    map.taus.len()
                )));
            }
            target.check_scene(&map.scene, target_path)?;
            map.scene
        }
        (Target::Covariance { .. } | Target::Entries { .. }, None) => {
            target.check_scene(&scene, target_path)?;
            scene
        }
    };
    crate::io::targets::check_setup(target_path, cfg.wavelength, &scene)?;
    check_params(&params, &scene.medium)?;
    let iterations = opts.iterations.unwrap_or(if adam { 150 } else { 15 });
    if opts.stages == 0 || iterations == 0 {
        return Err(Error::input("--stages and --iterations must be at least 1"));
    }
    // one objective evaluation (the covariance of the pairs the target needs) must fit the budget
    let probe =
        crate::speckle::Covariance::with_pairs(&scene, target.pairs(&scene), cfg.render.reversed)?;
    super::budget::check(
        "fit (one objective evaluation)",
        &probe,
        &scene.medium,
        cfg.render.samples as f64,
        cfg.render.samples.div_ceil(cfg.render.chunk),
        0,
        &opts.budget,
    )?;
    Ok(Prepared {
        cfg,
        scene,
        target,
        target_name: target_path.display().to_string(),
        target_crc: crc32fast::hash(&std::fs::read(target_path).map_err(|source| Error::Io {
            action: "read",
            path: target_path.to_path_buf(),
            source,
        })?),
        params,
        phase,
        adam,
        iterations,
        stages: opts.stages,
        learning_rate: opts.learning_rate,
        smooth: opts.smooth,
    })
}

impl Prepared {
    /// A logged evaluation as a line for a terminal: iteration (Adam) or stage (L-BFGS), loss,
    /// gradient norm and, for L-BFGS, the values.
    pub fn line(&self, e: &crate::inverse::LogEntry) -> String {
        if self.adam {
            return format!(
                "iteration {:>4} loss {:.6e} |grad| {:.3e}",
                e.stage, e.loss, e.grad_norm
            );
        }
        let values: Vec<String> = self
            .params
            .iter()
            .zip(&e.params)
            .map(|(p, v)| format!("{} = {v:.5}", p.name()))
            .collect();
        format!(
            "stage {} loss {:.6e} |grad| {:.3e}  {}",
            e.stage,
            e.loss,
            e.grad_norm,
            values.join(", ")
        )
    }

    /// Logged evaluations the fit will make: Adam's iterations; `None` for L-BFGS, whose
    /// evaluation count is not known in advance.
    pub fn total(&self) -> Option<usize> {
        self.adam.then_some(self.iterations)
    }

    /// Everything the fit's result depends on (config, target file, parameters, optimiser and its
    /// settings): a checkpoint is resumed only by the same fit.
    pub fn identity(&self) -> Result<serde_json::Value> {
        let params: Vec<&str> = self.params.iter().map(|p| p.name()).collect();
        let config = serde_json::to_value(&self.cfg)
            .map_err(|e| Error::input(format!("the fit's config cannot be recorded: {e}")))?;
        Ok(serde_json::json!({
            "config": config,
            "target_crc32": self.target_crc,
            "params": params,
            "phase": self.phase,
            "adam": self.adam,
            "iterations": self.iterations,
            "stages": self.stages,
            "learning_rate": self.learning_rate,
            "smooth": self.smooth,
        }))
    }

    /// Run the fit; `progress` sees every logged evaluation, `stop` ends it early with
    /// [`Error::Interrupted`], `journal` records it (and replays the run it was saved from; an
    /// [`Journal::default`](crate::inverse::journal::Journal) when nothing is saved).
    pub fn run(
        &self,
        progress: &(dyn Fn(&crate::inverse::LogEntry) + Sync),
        stop: &StopFlag,
        journal: &crate::inverse::journal::Journal,
    ) -> Result<Fitted> {
        let cfg = &self.cfg;
        let model = crate::inverse::ModelSettings {
            samples: cfg.render.samples,
            chunk: cfg.render.chunk,
            seed: cfg.render.seed,
            reversed: cfg.render.reversed,
        };
        let t0 = Instant::now();
        if self.adam {
            let settings = crate::inverse::AdamSettings {
                model,
                iterations: self.iterations,
                learning_rate: self.learning_rate,
                smooth: self.smooth,
            };
            let fit = crate::inverse::AdamFit {
                scene: &self.scene,
                target: &self.target,
                params: self.params.clone(),
                phase: self.phase,
                settings,
                stop: stop.clone(),
            };
            let res = fit.run(progress, journal)?;
            return Ok(self.adam_fitted(&fit, res, t0.elapsed().as_secs_f64()));
        }
        let fit = crate::inverse::Fit {
            scene: &self.scene,
            target: &self.target,
            params: self.params.clone(),
            settings: crate::inverse::FitSettings {
                model,
                stages: self.stages,
                iterations: self.iterations,
            },
            stop: stop.clone(),
        };
        let names: Vec<&str> = self.params.iter().map(|p| p.name()).collect();
        let res = fit.run(progress, journal)?;
        let seconds = t0.elapsed().as_secs_f64();
        let file = FitFile {
            format_version: crate::io::results::FORMAT_VERSION,
            optimizer: None,
            params: names.iter().map(|n| n.to_string()).collect(),
            initial: res.initial.clone(),
            fitted: res.fitted.clone(),
            stddev: res.stddev.clone(),
            correlation: Some(res.correlation.clone()),
            loss: res.loss,
            dof: None,
            phase_cos: None,
            phase_angle_deg: None,
            target_values: None,
            model_initial: res.model_initial.clone(),
            model_fitted: res.model_fitted.clone(),
            single_scattering_reading: None,
            log: res
                .log
                .iter()
                .map(|e| FitLogLine {
                    stage: Some(e.stage),
                    iteration: None,
                    loss: e.loss,
                    params: e.params.clone(),
                    grad_norm: e.grad_norm,
                })
                .collect(),
            learning_rate: None,
            smooth: None,
            convergence: Some(res.convergence),
            samples: cfg.render.samples,
            seed: cfg.render.seed,
            seconds,
            version: env!("CARGO_PKG_VERSION").into(),
            target: self.target_name.clone(),
            config: cfg.clone(),
        };
        let mut summary = format!(
            "fit in {seconds:.1} s, final loss {:.4e}; {}\n",
            res.loss,
            res.convergence.line()
        );
        for (i, n) in names.iter().enumerate() {
            summary += &format!(
                "  {n:>8}: {:.5} → {:.5} ± {:.5}\n",
                res.initial[i], res.fitted[i], res.stddev[i]
            );
        }
        for a in 0..names.len() {
            for b in a + 1..names.len() {
                let r = res.correlation[a][b];
                summary += &format!("  correlation({}, {}) = {r:.3}", names[a], names[b]);
                if r.abs() > 0.95 || !r.is_finite() {
                    summary += "  — strongly correlated: the data barely separate them (e.g. similarity σ_s(1 − g) ≈ const)";
                }
                summary += "\n";
            }
        }
        Ok(Fitted {
            file,
            target: self.target.clone(),
            phase_plot: None,
            summary,
        })
    }

    /// The Adam branch's result: the log, fitted values ± sd, and the single-scattering reading
    /// where it applies.
    fn adam_fitted(
        &self,
        fit: &crate::inverse::AdamFit,
        res: crate::inverse::AdamResult,
        seconds: f64,
    ) -> Fitted {
        let readings = crate::inverse::shortcut::single_scattering_readings(fit.scene, fit.target);
        let angles: Vec<f64> = res
            .cos
            .iter()
            .map(|c| c.clamp(-1.0, 1.0).acos().to_degrees())
            .collect();
        let file = FitFile {
            format_version: crate::io::results::FORMAT_VERSION,
            optimizer: Some("adam".into()),
            params: res.names.clone(),
            initial: res.initial.clone(),
            fitted: res.fitted.clone(),
            stddev: res.stddev.clone(),
            correlation: None,
            loss: res.loss,
            dof: Some(res.dof),
            phase_cos: Some(res.cos.clone()),
            phase_angle_deg: Some(angles.clone()),
            target_values: Some(fit.target.values()),
            model_initial: res.model_initial.clone(),
            model_fitted: res.model_fitted.clone(),
            single_scattering_reading: readings.as_ref().map(|r| {
                r.iter()
                    .map(|r| ReadingRecord {
                        delta_deg: r.delta_deg,
                        angle_deg: r.angle_deg,
                        rho: r.rho,
                        stderr: r.stderr,
                    })
                    .collect()
            }),
            log: res
                .log
                .iter()
                .map(|e| FitLogLine {
                    stage: None,
                    iteration: Some(e.stage),
                    loss: e.loss,
                    params: e.params.clone(),
                    grad_norm: e.grad_norm,
                })
                .collect(),
            learning_rate: Some(fit.settings.learning_rate),
            smooth: Some(fit.settings.smooth),
            convergence: Some(res.convergence),
            samples: fit.settings.model.samples,
            seed: fit.settings.model.seed,
            seconds,
            version: env!("CARGO_PKG_VERSION").into(),
            target: self.target_name.clone(),
            config: self.cfg.clone(),
        };
        let mut summary = format!(
            "Adam fit in {seconds:.1} s ({} iterations, {}), final loss {:.4e} over {:.0} degrees of freedom\n",
            res.log.len(),
            res.convergence.line(),
            res.loss,
            res.dof
        );
        for (i, n) in res.names.iter().enumerate() {
            summary += &format!(
                "  {n:>14}: {:.5} → {:.5} ± {:.5}\n",
                res.initial[i], res.fitted[i], res.stddev[i]
            );
        }
        Fitted {
            file,
            target: self.target.clone(),
            phase_plot: fit
                .phase
                .then(|| (fit.params.len(), readings.unwrap_or_default())),
            summary,
        }
    }
}

impl Fitted {
    /// Write fit.json, fit.png (memory-curve targets) and phase.png (phase-function fits) into
    /// `out`, which must exist.
    pub fn write(&self, out: &Path) -> Result<Outcome> {
        let f = &self.file;
        let path = out.join(FitFile::NAME);
        f.write(&path)?;
        let mut files = vec![path];
        if let (Some((scalars, readings)), Some(angles)) = (&self.phase_plot, &f.phase_angle_deg) {
            let png = out.join("phase.png");
            crate::io::plot::phase_fit(
                &png,
                angles,
                &f.initial[*scalars..],
                &f.fitted[*scalars..],
                &f.stddev[*scalars..],
                readings,
            )?;
            files.push(png);
        }
        files.extend(memory_fit_plot(
            &self.target,
            &f.model_initial,
            &f.model_fitted,
            out,
        )?);
        Ok(Outcome {
            files,
            summary: self.summary.clone(),
            not_converged: f.convergence.and_then(|c| c.warning()),
        })
    }
}

/// fit.png for a memory-curve target: the target with error bars, the initial and fitted model.
fn memory_fit_plot(
    target: &crate::inverse::Target,
    initial: &[f64],
    fitted: &[f64],
    out: &Path,
) -> Result<Option<PathBuf>> {
    let crate::inverse::Target::Memory {
        angles_deg,
        correlation,
        stderr,
    } = target
    else {
        return Ok(None);
    };
    let png = out.join("fit.png");
    crate::io::plot::fit_curve(
        &png,
        angles_deg,
        correlation,
        stderr.as_deref(),
        initial,
        fitted,
    )?;
    Ok(Some(png))
}
