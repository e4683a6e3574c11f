//! `lightpath check`: load a config as every command would (the one loader), build what it
//! describes, and say what it holds — without running anything.

use super::Outcome;
use crate::config::{self, Task};
use crate::error::Result;
use std::path::Path;

pub fn check(path: &Path) -> Result<Outcome> {
    let rays = |beams: &[crate::inverse::grin_design::Beam]| -> usize {
        beams.iter().map(|b| b.rays.len()).sum()
    };
    let what = match config::load(path)? {
        Task::Scene(t) => {
            let s = &t.scene;
            format!(
                "{} light(s), {} view(s), σ_s = {}, σ_a = {}, k = {:.6}",
                s.lights.len(),
                s.views.len(),
                s.medium.sigma_s,
                s.medium.sigma_a,
                s.k
            )
        }
        Task::Trace(t) => format!("trace config, {} ray(s)", t.rays.len()),
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
    };
    Ok(Outcome::text(format!("{}: ok — {what}", path.display())))
}
