//! `lightpath trace` (rays through a graded-index field → rays.json + rays.png) and `lightpath
//! design`: a grid field shaped by Adam through the adjoint (→ design.json, loss.png, profile.png,
//! grid_slice_z.exr), or analytic field parameters fitted by L-BFGS (→ fit.json, loss.png, rays.png).

use super::{Outcome, create_out};
use crate::config::{DesignTask, ParamFitTask, TraceTask};
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{
    DesignFile, DesignLogLine, GridRecord, GrinFitFile, GrinFitLogLine, RadialProfile, RayRecord,
    RaysFile,
};
use crate::mc::StopFlag;
use glam::DVec3;
use std::path::Path;
use std::time::Instant;

/// `lightpath design`: shape a grid index field so beams pass through their foci → design.json
/// (loss history, final grid, radial profile), loss.png, profile.png and a central EXR slice.
pub fn design(
    task: &DesignTask,
    show: bool,
    budget: &super::budget::Budget,
    resume: &super::Resume,
    out: &Path,
) -> Result<Outcome> {
    check_design(task, budget)?;
    let journal = super::journal("design", identity(&task.config)?, resume, out)?;
    create_out(
        out,
        &["design.json", "loss.png", "profile.png", "grid_slice_z.exr"],
    )?;
    let iterations = task.problem.iterations;
    let designed = run_design(
        task,
        &|s| {
            if show && (s.iteration % 10 == 0 || s.iteration + 1 == iterations) {
                eprintln!(
                    "level {} iteration {:>5} loss {:.5e} mean miss² {:.5e}",
                    s.level, s.iteration, s.loss, s.miss2
                );
            }
        },
        &StopFlag::default(),
        &journal,
    )?;
    let outcome = designed.write(out)?;
    super::remove_checkpoint(out)?;
    Ok(outcome)
}

/// What a design's result depends on: its config (a checkpoint is resumed only by the same
/// design).
pub fn identity(config: &impl serde::Serialize) -> Result<serde_json::Value> {
    serde_json::to_value(config)
        .map_err(|e| Error::input(format!("the design's config cannot be recorded: {e}")))
}

/// Refuse a design whose iterations would not fit the time or memory budget.
pub fn check_design(task: &DesignTask, budget: &super::budget::Budget) -> Result<()> {
    let problem = &task.problem;
    // each iteration traces every ray forward and runs the adjoint over every coefficient:
    // about one pilot pass on the Luneburg design experiment; three leave room for finer grids,
    // whose adjoint scatters into more memory
    super::budget::check_rays(
        "design",
        "each iteration a forward pass and the adjoint over every coefficient, ~3 passes",
        &problem.initial_field()?,
        &crate::inverse::grin_design::all_rays(&problem.beams),
        problem.step,
        problem.steps,
        !problem.to_exit,
        3.0 * (problem.levels.len() * problem.iterations) as f64,
        budget,
    )
}

/// A finished grid design: design.json's content and the grid sizes of its levels.
pub struct Designed {
    pub file: DesignFile,
    levels: Vec<usize>,
    pub summary: String,
}

/// Run a design: `progress` sees every iteration, `stop` ends it with [`Error::Interrupted`],
/// `journal` records it (and replays the run it was saved from).
pub fn run_design(
    task: &DesignTask,
    progress: &dyn Fn(&crate::inverse::grin_design::DesignStep),
    stop: &StopFlag,
    journal: &crate::inverse::journal::Journal,
) -> Result<Designed> {
    use crate::inverse::grin_design::radial_profile;
    let (cfg, problem) = (&task.config, &task.problem);
    let t0 = Instant::now();
    let res = problem.run(progress, stop, journal)?;
    let seconds = t0.elapsed().as_secs_f64();
    crate::config::trace::check_positive(&res.field)
        .map_err(|e| Error::Numerical(format!("design result: {}", e.0)))?;
    let r_max = match res.field.bounds {
        crate::eikonal::Bounds::Sphere { radius } => radius,
        crate::eikonal::Bounds::Cylinder { radius, .. } => radius,
        crate::eikonal::Bounds::Box { half } => half.min_element(),
        crate::eikonal::Bounds::Everywhere => 1.0,
        crate::eikonal::Bounds::Sdf(ref g) => {
            let (lo, hi) = g.corners();
            lo.abs().min(hi.abs()).min_element()
        }
        crate::eikonal::Bounds::Parts(_) => res.field.bounds.clearance(glam::DVec3::ZERO).abs(),
    };
    let profile = radial_profile(&res.field, r_max * 0.999, 41);
    let g = &res.grid;
    let file = DesignFile {
        format_version: crate::io::results::FORMAT_VERSION,
        rms_miss_initial: res.rms_miss_initial,
        rms_miss_final: res.rms_miss_final,
        log: res
            .log
            .iter()
            .map(|s| DesignLogLine {
                level: s.level,
                iteration: s.iteration,
                loss: s.loss,
                mean_miss2: s.miss2,
            })
            .collect(),
        grid: GridRecord {
            dims: g.dims.map(|d| d as u64),
            origin: g.origin.to_array(),
            spacing: g.spacing,
            interp: format!("{:?}", g.interp).to_lowercase(),
            samples: res.grid_samples.clone(),
            coefficients: g.coef.clone(),
        },
        radial_profile: RadialProfile {
            r: profile.iter().map(|p| p.0).collect(),
            mean: profile.iter().map(|p| p.1).collect(),
            min: profile.iter().map(|p| p.2).collect(),
            max: profile.iter().map(|p| p.3).collect(),
        },
        convergence: Some(res.convergence),
        seconds,
        version: env!("CARGO_PKG_VERSION").into(),
        config: cfg.clone(),
    };
    let summary = format!(
        "design in {seconds:.1} s ({} iterations over {} level(s); {}): RMS miss distance {:.4e} → {:.4e}",
        res.log.len(),
        problem.levels.len(),
        res.convergence.line(),
        res.rms_miss_initial,
        res.rms_miss_final
    );
    Ok(Designed {
        file,
        levels: problem.levels.clone(),
        summary,
    })
}

impl Designed {
    /// Write design.json, loss.png, profile.png and grid_slice_z.exr into `out`, which must exist.
    pub fn write(&self, out: &Path) -> Result<Outcome> {
        let file = &self.file;
        let path = out.join(DesignFile::NAME);
        file.write(&path)?;
        let loss_png = out.join("loss.png");
        let levels = file.log.iter().map(|s| s.level).max().unwrap_or(0);
        let series: Vec<(String, Vec<(f64, f64)>)> = (0..=levels)
            .map(|l| {
                let n = self.levels[l];
                (
                    format!("level {l} ({n}³)"),
                    file.log
                        .iter()
                        .enumerate()
                        .filter(|(_, s)| s.level == l)
                        .map(|(i, s)| (i as f64, s.mean_miss2))
                        .collect(),
                )
            })
            .collect();
        crate::io::plot::lines(
            &loss_png,
            "Design: mean squared miss distance",
            "iteration",
            "mean miss²",
            &series,
            true,
        )?;
        let profile_png = out.join("profile.png");
        let p = &file.radial_profile;
        let curve =
            |v: &[f64]| -> Vec<(f64, f64)> { p.r.iter().copied().zip(v.iter().copied()).collect() };
        crate::io::plot::lines(
            &profile_png,
            "Designed index along 26 radial directions",
            "r",
            "n",
            &[
                ("mean".to_string(), curve(&p.mean)),
                ("min".to_string(), curve(&p.min)),
                ("max".to_string(), curve(&p.max)),
            ],
            false,
        )?;
        let [nx, ny, nz] = file.grid.dims.map(|d| d as usize);
        let slice = &file.grid.samples[nx * ny * (nz / 2)..nx * ny * (nz / 2 + 1)];
        let exr_path = out.join("grid_slice_z.exr");
        crate::io::exr::write_scalar(&exr_path, slice, nx, ny, "n")?;
        Ok(Outcome {
            not_converged: file.convergence.and_then(|c| c.warning()),
            files: vec![path, loss_png, profile_png, exr_path],
            summary: self.summary.clone(),
        })
    }
}

/// `lightpath design` with a `[parameters]` table: fit analytic field parameters by L-BFGS on
/// exit-adjoint gradients → fit.json (values, log), loss.png and rays.png of the fitted field.
pub fn param_fit(
    task: &ParamFitTask,
    show: bool,
    budget: &super::budget::Budget,
    resume: &super::Resume,
    out: &Path,
) -> Result<Outcome> {
    check_param_fit(task, budget)?;
    let journal = super::journal("design", identity(&task.config)?, resume, out)?;
    create_out(out, &["fit.json", "loss.png", "rays.png"])?;
    let fitted = run_param_fit(
        task,
        &|s| {
            if show {
                eprintln!(
                    "evaluation {:>4} mean miss² {:.5e} parameters {:?}",
                    s.evaluation, s.mean_miss2, s.params
                );
            }
        },
        &StopFlag::default(),
        &journal,
    )?;
    let outcome = fitted.write(out)?;
    super::remove_checkpoint(out)?;
    Ok(outcome)
}

/// Refuse a parameter fit whose iterations would not fit the time or memory budget.
pub fn check_param_fit(task: &ParamFitTask, budget: &super::budget::Budget) -> Result<()> {
    let problem = &task.problem;
    // an L-BFGS iteration evaluates the loss once or twice, each a trace and its exit adjoint
    // (measured on the GRIN-fibre experiment: 5.5 of the pilot's passes per iteration)
    super::budget::check_rays(
        "design (parameter fit)",
        "each iteration one or two evaluations of a trace and its exit adjoint, ~6 passes",
        &problem.field,
        &crate::inverse::grin_design::all_rays(&problem.beams),
        problem.step,
        problem.max_steps,
        false,
        6.0 * problem.iterations as f64,
        budget,
    )
}

/// A finished parameter fit: fit.json's content and the fitted field's ray paths (for rays.png).
pub struct ParamFitted {
    pub file: GrinFitFile,
    paths: Vec<Vec<DVec3>>,
    pub summary: String,
}

/// Run a parameter fit: `progress` sees every evaluation, `stop` ends it with
/// [`Error::Interrupted`], `journal` records it (and replays the run it was saved from).
pub fn run_param_fit(
    task: &ParamFitTask,
    progress: &(dyn Fn(&crate::inverse::grin_fit::FitStep) + Sync),
    stop: &StopFlag,
    journal: &crate::inverse::journal::Journal,
) -> Result<ParamFitted> {
    use crate::eikonal::Tracer;
    let (cfg, problem) = (&task.config, &task.problem);
    let t0 = Instant::now();
    let res = problem.run(progress, stop, journal)?;
    let seconds = t0.elapsed().as_secs_f64();
    let file = GrinFitFile {
        format_version: crate::io::results::FORMAT_VERSION,
        parameters: problem.names.clone(),
        initial: res.initial.clone(),
        fitted: res.fitted.clone(),
        rms_miss_initial: res.rms_miss_initial,
        rms_miss_final: res.rms_miss_final,
        log: res
            .log
            .iter()
            .map(|s| GrinFitLogLine {
                evaluation: s.evaluation,
                parameters: s.params.clone(),
                mean_miss2: s.mean_miss2,
            })
            .collect(),
        convergence: Some(res.convergence),
        seconds,
        version: env!("CARGO_PKG_VERSION").into(),
        config: cfg.clone(),
    };
    let tracer = Tracer {
        field: &res.field,
        step: problem.step,
        max_steps: problem.max_steps,
    };
    let paths: Vec<Vec<DVec3>> = problem
        .beams
        .iter()
        .flat_map(|b| b.rays.iter().map(move |r| (r, b.focus)))
        .map(|(&(o, d), focus)| {
            let mut p = vec![o];
            let mut k = 0usize;
            let e = tracer.trace_with(o, d, |x| {
                if k.is_multiple_of(16) {
                    p.push(x);
                }
                k += 1;
            });
            p.push(e.x);
            p.push(e.x + e.direction * (focus - e.x).length().max(0.2 * (e.x - o).length()));
            p
        })
        .collect();
    let mut summary = format!(
        "L-BFGS fit in {seconds:.1} s ({}): RMS miss distance {:.4e} → {:.4e}\n",
        res.convergence.line(),
        res.rms_miss_initial,
        res.rms_miss_final
    );
    for (i, n) in problem.names.iter().enumerate() {
        summary += &format!("  {n}: {:.6e} → {:.6e}\n", res.initial[i], res.fitted[i]);
    }
    Ok(ParamFitted {
        file,
        paths,
        summary: summary.trim_end().to_string(),
    })
}

impl ParamFitted {
    /// Write fit.json, loss.png and rays.png into `out`, which must exist.
    pub fn write(&self, out: &Path) -> Result<Outcome> {
        let file = &self.file;
        let path = out.join(GrinFitFile::NAME);
        file.write(&path)?;
        let loss_png = out.join("loss.png");
        crate::io::plot::lines(
            &loss_png,
            "Fit: mean squared miss distance",
            "evaluation",
            "mean miss²",
            &[(
                "L-BFGS".to_string(),
                file.log
                    .iter()
                    .map(|s| (s.evaluation as f64, s.mean_miss2))
                    .collect(),
            )],
            true,
        )?;
        let rays_png = out.join("rays.png");
        crate::io::plot::ray_paths(&rays_png, &self.paths)?;
        Ok(Outcome {
            not_converged: file.convergence.and_then(|c| c.warning()),
            files: vec![path, loss_png, rays_png],
            summary: self.summary.clone(),
        })
    }
}

/// `lightpath trace`: trace a bundle of rays through an index field → rays.json and rays.png.
pub fn trace(task: &TraceTask, budget: &super::budget::Budget, out: &Path) -> Result<Outcome> {
    let traced = trace_rays(task, budget, &super::Watch::default())?;
    create_out(out, &["rays.json", "rays.png"])?;
    write_trace(&traced, out)
}

/// A traced bundle before it is written: `rays.json`, each ray's path (every 16th step, then its
/// exit point and a stretch along its exit direction), and a warning when the step is coarse.
#[derive(Clone, Debug)]
pub struct Traced {
    pub file: RaysFile,
    pub paths: Vec<Vec<DVec3>>,
    pub warning: Option<String>,
}

/// Trace the bundle in memory (the library's and Python's entry), with the checks of `trace`:
/// the time budget, rays that meet the field, a positive index, and the step's error.
/// `watch` counts traced rays (the step-error probe's few included) and stops the trace at its
/// next ray.
pub fn trace_rays(
    task: &TraceTask,
    budget: &super::budget::Budget,
    watch: &super::Watch,
) -> Result<Traced> {
    use crate::eikonal::{IndexField, Tracer};
    use rayon::prelude::*;
    let (field, rays) = (&task.field, &task.rays);
    // every ray, and a few again at half the step for the step error
    super::budget::check_rays(
        "trace",
        "once",
        field,
        rays,
        task.step,
        task.max_steps,
        false,
        1.0,
        budget,
    )?;
    let tracer = Tracer {
        field,
        step: task.step,
        max_steps: task.max_steps,
    };
    // the field's largest extent (the step was checked against it when the config was loaded)
    let size = field.bounds.half_extent().map(|h| 2.0 * h.max_element());
    let t0 = Instant::now();
    let trace_all = |tracer: &Tracer, rays: &[(DVec3, DVec3)]| {
        rays.par_iter()
            .map(|&(o, d)| {
                watch.check()?;
                let mut path = vec![o];
                let mut bad = None;
                let mut k = 0usize;
                let end = tracer.trace_with(o, d, |x| {
                    let n = field.n(x);
                    if bad.is_none() && !(n > 0.0 && n.is_finite()) {
                        bad = Some(x);
                    }
                    if k.is_multiple_of(16) {
                        path.push(x);
                    }
                    k += 1;
                });
                path.push(end.x);
                watch.tick();
                Ok((end, path, bad))
            })
            .collect::<Result<Vec<(crate::eikonal::RayEnd, Vec<DVec3>, Option<DVec3>)>>>()
    };
    let total = |n: usize| {
        watch
            .total
            .store(n as u64, std::sync::atomic::Ordering::Relaxed)
    };
    total(rays.len());
    let traced = trace_all(&tracer, rays)?;
    if !traced.iter().any(|t| t.0.entered) {
        return Err(Error::input(format!(
            "rays: none of the {} rays meets the field's bounds: check rays.center / rays.origin and the direction",
            traced.len()
        )));
    }
    if let Some(x) = traced.iter().find_map(|t| t.2) {
        return Err(Error::input(format!(
            "field: n = {} at {x}: the refractive index must be positive and finite where rays run",
            field.n(x)
        )));
    }
    if size.is_some() && !traced.iter().any(|t| t.0.entered && t.0.exited) {
        return Err(Error::input(format!(
            "no ray left the field within trace.max_steps = {} steps of {}: raise max_steps (or the step)",
            task.max_steps, task.step
        )));
    }
    // the step's error: the exit points of a few rays traced again at half the step (the leapfrog
    // is second order, so the error at `step` is about 4/3 of the difference)
    // (rays through the field, or without bounds every ray that entered, compared where it ends:
    // at half the step and twice the steps it covers the same length)
    let probe: Vec<usize> = {
        let through: Vec<usize> = (0..traced.len())
            .filter(|&i| traced[i].0.entered && (traced[i].0.exited || size.is_none()))
            .collect();
        let mut p: Vec<usize> = [0, through.len() / 2, through.len().saturating_sub(1)]
            .iter()
            .filter_map(|&k| through.get(k).copied())
            .collect();
        p.dedup();
        p
    };
    let fine = Tracer {
        field,
        step: 0.5 * task.step,
        max_steps: task.max_steps.saturating_mul(2),
    };
    total(rays.len() + probe.len());
    let again = trace_all(&fine, &probe.iter().map(|&i| rays[i]).collect::<Vec<_>>())?;
    let step_error = probe
        .iter()
        .zip(&again)
        .map(|(&i, t)| {
            if t.0.exited == traced[i].0.exited {
                4.0 / 3.0 * (t.0.x - traced[i].0.x).length()
            } else {
                f64::INFINITY
            }
        })
        .fold(0.0, f64::max);
    let scale = size.unwrap_or_else(|| {
        probe
            .iter()
            .map(|&i| (traced[i].0.x - rays[i].0).length())
            .fold(0.0, f64::max)
    });
    let relative = step_error / scale;
    // second order: the step that would bring the error to 0.1 % of the field's size
    let suggest = task.step * (1e-3 / relative).sqrt().min(1.0);
    if relative > 1e-2 {
        return Err(Error::input(format!(
            "trace.step = {} is too coarse for this field: halving it moves the rays' exit points by ~{step_error:.3e} ({:.1} % of the field's {scale:.3e} size); use a step of about {suggest:.3e} or less",
            task.step,
            100.0 * relative
        )));
    }
    let warning = (relative > 1e-3).then(|| {
        format!(
            "\nwarning: the exit points are uncertain by ~{step_error:.3e} ({:.2} % of the field's size) at trace.step = {}; a step of {suggest:.3e} brings that to 0.1 %",
            100.0 * relative,
            task.step
        )
    });

    let seconds = t0.elapsed().as_secs_f64();
    let file = RaysFile {
        format_version: crate::io::results::FORMAT_VERSION,
        rays: rays
            .iter()
            .zip(&traced)
            .map(|((o, d), (e, _, _))| RayRecord {
                origin: o.to_array(),
                direction: d.to_array(),
                exit_position: e.x.to_array(),
                exit_direction: e.direction.to_array(),
                optical_path: e.optical_path,
                steps: e.steps,
                entered: e.entered,
                exited: e.exited,
            })
            .collect(),
        step_error: Some(step_error),
        seconds,
        version: env!("CARGO_PKG_VERSION").into(),
        config: task.config.clone(),
    };
    let paths: Vec<Vec<DVec3>> = traced
        .iter()
        .map(|(e, p, _)| {
            let mut p = p.clone();
            p.push(e.x + e.direction * 1.5 * (e.x - p[0]).length().max(1.0));
            p
        })
        .collect();
    Ok(Traced {
        file,
        paths,
        warning,
    })
}

/// Write `rays.json` and `rays.png` into `out` (which exists).
pub fn write_trace(traced: &Traced, out: &Path) -> Result<Outcome> {
    let file = &traced.file;
    let path = out.join(RaysFile::NAME);
    file.write(&path)?;
    let png = out.join("rays.png");
    crate::io::plot::ray_paths(&png, &traced.paths)?;
    let exited = file.rays.iter().filter(|r| r.exited && r.entered).count();
    Ok(Outcome {
        not_converged: None,
        files: vec![path, png],
        summary: format!(
            "traced {} rays ({exited} through the field) in {:.2} s; exit points uncertain by ~{:.2e} from the step{}",
            file.rays.len(),
            file.seconds,
            file.step_error.unwrap_or(0.0),
            traced.warning.clone().unwrap_or_default()
        ),
    })
}
