//! `lightpath correlation-map`: near-field `C(Δ, τ)` maps (paper 000, Eq. 48) → JSON + PNG.

use super::Outcome;
use crate::config::SceneTask;
use crate::error::{Error, Result};
use crate::io::results::{CorrelationMapFile, ResultFile};
use crate::mc::{Block, Estimate, Plan, merge};
use crate::speckle::correlation_map::CorrelationMap;
use std::path::Path;

/// The error for a config without the map's table.
pub(crate) const NEEDS_TABLE: &str = "correlation-map needs a [correlation_map] table with deltas = [[x, y], ...], tau_width and pixels";

/// The map a scene task asks for (its `[correlation_map]` table).
pub(crate) fn map_of(task: &SceneTask) -> Result<CorrelationMap> {
    let m = task
        .config
        .correlation_map
        .as_ref()
        .ok_or_else(|| Error::input(NEEDS_TABLE))?;
    CorrelationMap::new(
        &task.scene,
        &m.deltas,
        m.tau_width,
        [m.pixels[0] as usize, m.pixels[1] as usize],
    )
}

/// `correlation_map.json` from the run's blocks, and the peak intensity of the unshifted map (the
/// plot's scale).
pub(crate) fn map_file(
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<(CorrelationMapFile, f64)> {
    let map = map_of(task)?;
    let root = merge(blocks, plan.chunks)?;
    let e = Estimate::from_block(&root, plan);
    super::run::check_finite("correlation-map", &e.mean)?;
    let (k, t) = (map.deltas.len(), map.taus.len());
    let [nx, ny] = map.pixels;
    let grid = |f: &dyn Fn(usize, usize) -> f64| -> Vec<Vec<Vec<f64>>> {
        (0..k)
            .map(|d| {
                (0..ny)
                    .map(|y| (0..nx).map(|x| f(d, y * nx + x)).collect())
                    .collect()
            })
            .collect()
    };
    let c = |d: usize, p: usize| e.mean[d * t + p];
    let intensity = |d: usize, p: usize| e.mean[k * t + d * t + p].re;
    let normalised = |d: usize, p: usize| {
        let n = (intensity(0, p) * intensity(d, p)).sqrt();
        if n > 0.0 { c(d, p).norm() / n } else { 0.0 }
    };
    let file = CorrelationMapFile {
        run: super::run::mc_echo(task, &map.scene, plan, seconds),
        deltas: map.deltas.iter().map(|d| d.to_array()).collect(),
        taus: (0..ny)
            .map(|y| (0..nx).map(|x| map.taus[y * nx + x].to_array()).collect())
            .collect(),
        re: grid(&|d, p| c(d, p).re),
        im: grid(&|d, p| c(d, p).im),
        stderr: grid(&|d, p| e.stderr[d * t + p]),
        normalised: grid(&normalised),
    };
    // one scale for all panels: the peak intensity of the unshifted map
    let peak = (0..t).map(|p| intensity(0, p)).fold(0.0, f64::max);
    Ok((file, peak))
}

/// Write `correlation_map.json` and `correlation_map.png` (every `|C(Δ, τ)|` over `peak`) into
/// `out`.
pub(crate) fn write_map(file: &CorrelationMapFile, peak: f64, out: &Path) -> Result<Outcome> {
    let path = out.join(CorrelationMapFile::NAME);
    file.write(&path)?;
    let png = out.join("correlation_map.png");
    let ny = file.taus.len();
    let nx = file.taus.first().map_or(0, |r| r.len());
    let panels: Vec<(String, Vec<f64>)> = file
        .deltas
        .iter()
        .zip(file.re.iter().zip(&file.im))
        .map(|(m, (re, im))| {
            (
                format!("Δ = ({:.2}, {:.2}, {:.2})", m[0], m[1], m[2]),
                re.iter()
                    .flatten()
                    .zip(im.iter().flatten())
                    .map(|(a, b)| if peak > 0.0 { a.hypot(*b) / peak } else { 0.0 })
                    .collect(),
            )
        })
        .collect();
    crate::io::plot::heat_maps(&png, "|C(Δ, τ)| / max I over τ", &panels, nx, ny)
        .map_err(|err| Error::input(format!("cannot write {}: {err}", png.display())))?;
    Ok(Outcome {
        not_converged: None,
        summary: format!(
            "C(Δ, τ) for {} shift(s) over {nx} × {ny} τ from {} paths",
            file.deltas.len().saturating_sub(1),
            file.run.samples
        ),
        files: vec![path, png],
    })
}
