//! `lightpath check`: load a config as every command would (the one loader), build what it
//! describes, and say what it holds — without running anything.

use super::Outcome;
use crate::config::{self, Task};
use crate::error::Result;
use std::path::Path;

pub fn check(path: &Path) -> Result<Outcome> {
    let what = describe(&config::load(path)?)?;
    Ok(Outcome::text(format!("{}: ok — {what}", path.display())))
}

/// What a loaded task holds, in one line (what `check` prints after `ok —`).
pub fn describe(task: &Task) -> Result<String> {
    let rays = |beams: &[crate::inverse::grin_design::Beam]| -> usize {
        beams.iter().map(|b| b.rays.len()).sum()
    };
    Ok(match task {
        Task::Scene(t) => {
            let s = &t.scene;
            let mut what = format!(
                "{} light(s), {} view(s), σ_s = {}, σ_a = {}, k = {:.6}",
                s.lights.len(),
                s.views.len(),
                s.medium.sigma_s,
                s.medium.sigma_a,
                s.k
            );
            // what a covariance of every light × view field would cost
            let est = crate::speckle::Covariance::all_pairs(s, t.config.render.reversed)?;
            let plan = crate::mc::Plan::new(0, t.config.render.samples, t.config.render.chunk);
            let gb = super::budget::memory_gb(&est, 0, plan.chunks);
            what += &format!(
                "; ~{:.3} scattering events per path; `covariance` holds {} light×view fields (~{gb:.2} GB)",
                crate::speckle::paths::expected_events(&s.medium),
                est.fields()
            );
            let limit = super::budget::Budget::default().max_memory_gb;
            if gb > limit {
                what += &format!(
                    " — beyond the default --max-memory-gb {limit}: `covariance` would refuse it (`speckle` needs far less)"
                );
            }
            // focused endpoints see the amplitude through its vMF lobes: say how well they fit
            let focused = s
                .lights
                .iter()
                .any(|l| matches!(l, crate::speckle::Light::Focused { .. }))
                || s.views
                    .iter()
                    .any(|v| matches!(v, crate::speckle::View::Focused { .. }));
            if focused {
                for (i, (_, p)) in s.medium.scattering.components().iter().enumerate() {
                    let l = crate::medium::lobes::Lobes::of(p);
                    what += &format!(
                        "; particle type {i}: amplitude as {} vMF lobe(s), relative L² error {:.1e}",
                        l.lobes.len(),
                        l.error
                    );
                }
            }
            what
        }
        Task::Trace(t) => format!("trace config, {} ray(s)", t.rays.len()),
        Task::Render(t) => super::render::describe(t),
        Task::Design(t) => format!(
            "design config, {} beam(s), {} ray(s), levels {:?}",
            t.problem.beams.len(),
            rays(&t.problem.beams),
            t.problem.levels
        ),
        Task::ParamFit(t) => format!(
            "parameter fit config, {} beam(s), {} ray(s), fitting {}",
            t.problem.beams.len(),
            rays(&t.problem.beams),
            t.problem.names.join(", ")
        ),
        Task::Acquire(t) => {
            for (i, p) in t.pair.iter().enumerate() {
                for (key, f) in [("first", &p.first), ("second", &p.second)] {
                    if !f.is_file() {
                        return Err(crate::Error::input(format!(
                            "pair[{i}].{key} = {}: no such file",
                            f.display()
                        )));
                    }
                }
            }
            format!(
                "speckle acquisition, {} image pair(s), {}-pixel windows",
                t.pair.len(),
                t.acquisition.window
            )
        }
    })
}
