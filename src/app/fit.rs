//! `lightpath fit`: fit medium parameters (mfp, albedo, g, σ_s, σ_a, mixture weights) and
//! tabulated phase functions so rendered statistics match a target (a memory-effect curve, a
//! covariance, or measured entries): L-BFGS on the deterministic re-weighted objective for a few
//! parameters, Adam through the burn bridge for many (phase-function node values).

use super::{Outcome, create_out};
use crate::config::{MemoryEffectConfig, SceneTask};
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{FitFile, FitLogLine, ReadingRecord};
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
}

/// `lightpath fit`: fit medium parameters so rendered statistics match a target.
pub fn fit(task: SceneTask, target_path: &Path, opts: &FitOptions, out: &Path) -> Result<Outcome> {
    let SceneTask {
        config: mut cfg,
        scene,
    } = task;
    use crate::inverse::{Fit, FitParam, FitSettings, Target, check_params};
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
    create_out(out, &["fit.json", "fit.png", "phase.png"])?;
    let model = crate::inverse::ModelSettings {
        samples: cfg.render.samples,
        chunk: cfg.render.chunk,
        seed: cfg.render.seed,
        reversed: cfg.render.reversed,
    };
    if adam {
        let settings = crate::inverse::AdamSettings {
            model,
            iterations,
            learning_rate: opts.learning_rate,
            smooth: opts.smooth,
        };
        let fit = crate::inverse::AdamFit {
            scene: &scene,
            target: &target,
            params,
            phase,
            settings,
        };
        return adam_fit(&cfg, &fit, target_path, opts.progress, out);
    }
    let settings = FitSettings {
        model,
        stages: opts.stages,
        iterations,
    };
    let fit = Fit {
        scene: &scene,
        target: &target,
        params: params.clone(),
        settings,
    };
    let t0 = Instant::now();
    let show = opts.progress;
    let names: Vec<&str> = params.iter().map(|p| p.name()).collect();
    let res = fit.run(&|e| {
        if show {
            let p: Vec<String> = names
                .iter()
                .zip(&e.params)
                .map(|(n, v)| format!("{n} = {v:.5}"))
                .collect();
            eprintln!(
                "stage {} loss {:.6e} |grad| {:.3e}  {}",
                e.stage,
                e.loss,
                e.grad_norm,
                p.join(", ")
            );
        }
    })?;
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
        target: target_path.display().to_string(),
        config: cfg.clone(),
    };
    let path = out.join(FitFile::NAME);
    file.write(&path)?;
    let mut files = vec![path];
    files.extend(memory_fit_plot(
        &target,
        &res.model_initial,
        &res.model_fitted,
        out,
    )?);
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
    Ok(Outcome {
        files,
        summary,
        not_converged: res.convergence.warning(),
    })
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

/// The Adam branch of `lightpath fit`: fit.json (log, fitted values ± sd, the single-scattering
/// reading where it applies), phase.png for a phase-function fit, fit.png for a memory curve.
fn adam_fit(
    cfg: &crate::config::Config,
    fit: &crate::inverse::AdamFit,
    target_path: &Path,
    show: bool,
    out: &Path,
) -> Result<Outcome> {
    let t0 = Instant::now();
    let res = fit.run(&|e| {
        if show {
            eprintln!(
                "iteration {:>4} loss {:.6e} |grad| {:.3e}",
                e.stage, e.loss, e.grad_norm
            );
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
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
        target: target_path.display().to_string(),
        config: cfg.clone(),
    };
    let path = out.join(FitFile::NAME);
    file.write(&path)?;
    let mut files = vec![path];
    let scalars = fit.params.len();
    if fit.phase {
        let png = out.join("phase.png");
        crate::io::plot::phase_fit(
            &png,
            &angles,
            &res.initial[scalars..],
            &res.fitted[scalars..],
            &res.stddev[scalars..],
            readings.as_deref().unwrap_or(&[]),
        )?;
        files.push(png);
    }
    files.extend(memory_fit_plot(
        fit.target,
        &res.model_initial,
        &res.model_fitted,
        out,
    )?);
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
    Ok(Outcome {
        files,
        summary,
        not_converged: res.convergence.warning(),
    })
}
