//! `lightpath design` on a render config with a `[design]` table: the index field's parameters
//! moved by Adam or L-BFGS, within their ranges, to deliver the most light to a target or into
//! a spot (or the most relative to another), then the start and the design rendered at a fresh seed to check the
//! gain → render_design.json and loss.png.

use super::{Outcome, create_out};
use crate::config::RenderTask;
use crate::error::{Error, Result};
use crate::inverse::render_design::{DesignIterate, DesignMethod, RenderDesign};
use crate::io::ResultFile;
use crate::io::results::{
    DesignVerification, DesignedParameter, Measured, RenderDesignFile, RenderDesignLogLine,
};
use crate::mc::{Plan, StopFlag, estimate_until};
use crate::rrte::ParticleTracer;
use std::path::Path;
use std::time::Instant;

/// The seed of the checking renders: away from every iteration's.
const CHECK_SEED: u64 = 0x6368_6563_6b65_6421;

/// `lightpath design` on a render config: run its design and write render_design.json and
/// loss.png into `out`.
pub fn design(
    task: &RenderTask,
    show: bool,
    budget: &super::budget::Budget,
    resume: &super::Resume,
    out: &Path,
) -> Result<Outcome> {
    let problem = task.design.as_ref().ok_or_else(|| {
        Error::input("this render config has no [design] table: add one (maximize, parameters) to design with it, or run it with `lightpath render`")
    })?;
    check(problem, budget)?;
    let journal = super::journal(
        "render design",
        super::grin::identity(&task.config)?,
        resume,
        out,
    )?;
    create_out(out, &[RenderDesignFile::NAME, "loss.png"])?;
    let iterations = problem.iterations;
    // Adam's iterations are many and cheap; L-BFGS's evaluations few
    let (every, step) = match problem.method {
        DesignMethod::Adam => (10, "iteration"),
        DesignMethod::Lbfgs => (1, "evaluation"),
    };
    let file = run(
        task,
        problem,
        &|d: &DesignIterate| {
            if show && (d.iteration.is_multiple_of(every) || d.iteration + 1 == iterations) {
                eprintln!(
                    "{step} {:>5} objective {:.5e} parameters {:?}",
                    d.iteration, d.objective, d.theta
                );
            }
        },
        &StopFlag::default(),
        &journal,
    )?;
    let outcome = write(&file, out)?;
    super::remove_checkpoint(out)?;
    Ok(outcome)
}

/// Refuse a design whose renders would not fit the time budget: every iteration's photons with
/// their derivatives (L-BFGS: three evaluations per iteration, its line searches' usual count
/// on kinked held objectives), and the two checking renders.
pub fn check(problem: &RenderDesign, budget: &super::budget::Budget) -> Result<()> {
    let est = ParticleTracer::new(&problem.scene);
    let medium = super::render::proxy_medium(&problem.scene);
    let evaluations = match problem.method {
        DesignMethod::Adam => problem.iterations as u64,
        DesignMethod::Lbfgs => 3 * problem.iterations as u64,
    };
    let photons = (evaluations * problem.photons + 2 * problem.verify_photons) as f64;
    let chunks = (photons / problem.chunk as f64).ceil() as u64;
    super::budget::check("render design", &est, &medium, photons, chunks, 0, budget)
}

/// Run the design and check it: render_design.json's content.
pub fn run(
    task: &RenderTask,
    problem: &RenderDesign,
    progress: &(dyn Fn(&DesignIterate) + Sync),
    stop: &StopFlag,
    journal: &crate::inverse::journal::Journal,
) -> Result<RenderDesignFile> {
    let t0 = Instant::now();
    let designed = problem.run(progress, stop, journal)?;
    let verify = problem.verify_photons;
    let op = crate::diff::RenderOp::from_scene(problem.scene.clone(), (1, 1, 0))?;
    let outputs = |theta: &[f64]| -> Result<(Measured, Option<Measured>)> {
        let scene = op.scene_without_derivatives(theta)?;
        let est = ParticleTracer::new(&scene);
        let plan = Plan::new(CHECK_SEED, verify, problem.chunk.min(verify));
        let e = estimate_until(&est, &plan, stop.get())?;
        let at = |i: usize| Measured {
            mean: e.mean[est.objective(i)].re,
            stderr: e.stderr[est.objective(i)],
        };
        Ok((at(problem.maximize), problem.relative_to.map(at)))
    };
    let (start, reference_start) = outputs(&problem.start)?;
    let (end, reference_designed) = outputs(&designed.designed)?;
    let objective = |f: &Measured, r: &Option<Measured>| match r {
        Some(r) => Measured {
            mean: f.mean / r.mean,
            stderr: (f.mean / r.mean) * (f.stderr / f.mean).hypot(r.stderr / r.mean),
        },
        None => *f,
    };
    let (a, b) = (
        objective(&start, &reference_start),
        objective(&end, &reference_designed),
    );
    let ratio = b.mean / a.mean;
    let gain = Measured {
        mean: ratio,
        stderr: ratio * (a.stderr / a.mean).hypot(b.stderr / b.mean),
    };
    if !(gain.mean.is_finite() && gain.stderr.is_finite()) {
        return Err(Error::Numerical(format!(
            "render design: no light reached the sensor maximised in the checking renders ({verify} photons): raise design.verify_photons"
        )));
    }
    let objectives = problem.scene.objectives();
    let name = |i: usize| objectives[i].clone();
    Ok(RenderDesignFile {
        format_version: crate::io::results::FORMAT_VERSION,
        maximize: name(problem.maximize),
        relative_to: problem.relative_to.map(name),
        method: problem.method,
        parameters: problem
            .names
            .iter()
            .enumerate()
            .map(|(k, n)| DesignedParameter {
                name: n.clone(),
                min: problem.ranges[k].0,
                max: problem.ranges[k].1,
                start: problem.start[k],
                designed: designed.designed[k],
            })
            .collect(),
        log: designed
            .log
            .iter()
            .map(|d| RenderDesignLogLine {
                iteration: d.iteration,
                objective: d.objective,
                grad_norm: d.grad_norm,
                parameters: d.theta.clone(),
            })
            .collect(),
        verification: DesignVerification {
            photons: verify,
            seed: CHECK_SEED,
            start,
            designed: end,
            reference_start,
            reference_designed,
            gain,
        },
        convergence: designed.convergence,
        seconds: t0.elapsed().as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").into(),
        config: task.config.clone(),
    })
}

/// Write render_design.json and loss.png (the objective per iteration) into `out`.
pub fn write(file: &RenderDesignFile, out: &Path) -> Result<Outcome> {
    let path = out.join(RenderDesignFile::NAME);
    file.write(&path)?;
    let loss_png = out.join("loss.png");
    let objective = match &file.relative_to {
        Some(r) => format!("ln (F {} / F {r})", file.maximize),
        None => format!("ln F {}", file.maximize),
    };
    let (title, x, method) = match file.method {
        DesignMethod::Adam => (
            "Design: the objective of each iteration's photons",
            "iteration",
            "Adam",
        ),
        DesignMethod::Lbfgs => (
            "Design: the objective of the held photons",
            "evaluation",
            "L-BFGS",
        ),
    };
    crate::io::plot::lines(
        &loss_png,
        title,
        x,
        &objective,
        &[(
            method.to_string(),
            file.log
                .iter()
                .map(|d| (d.iteration as f64, d.objective))
                .collect(),
        )],
        false,
    )?;
    let summary = summary(file);
    Ok(Outcome {
        not_converged: file.convergence.warning(),
        files: vec![path, loss_png],
        summary,
    })
}

/// What the command prints of a design.
pub fn summary(file: &RenderDesignFile) -> String {
    let v = &file.verification;
    let gained = match &file.relative_to {
        Some(r) => format!("gain of the ratio to {r}"),
        None => "gain".to_string(),
    };
    let mut summary = format!(
        "render design in {:.1} s ({}): {} {:.5e} ± {:.1e} → {:.5e} ± {:.1e} ({gained} {:.4} ± {:.4}, {} photons at a fresh seed)\n",
        file.seconds,
        file.convergence.line(),
        file.maximize,
        v.start.mean,
        v.start.stderr,
        v.designed.mean,
        v.designed.stderr,
        v.gain.mean,
        v.gain.stderr,
        v.photons
    );
    for p in &file.parameters {
        summary += &format!(
            "  {}: {:.6e} → {:.6e} (range {:.3e} to {:.3e})\n",
            p.name, p.start, p.designed, p.min, p.max
        );
    }
    summary.trim_end().to_string()
}
