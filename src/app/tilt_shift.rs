//! `lightpath tilt-shift`: the tilt-shift memory effect (paper 000, Eq. 49) beside the model of
//! Eq. 50, on a grid of shifts and tilts, a list of cells, or as the refocusing scan of Sec. 9.1
//! → JSON + PNG.

use super::Outcome;
use crate::config::SceneTask;
use crate::error::{Error, Result};
use crate::io::results::{Refocus, ResultFile, TiltShiftCell, TiltShiftFile, TiltShiftGrid};
use crate::mc::{Block, Estimate, Plan, merge};
use crate::speckle::tilt_shift::{TiltShift, best_tilt, model};
use std::path::Path;

/// The error for a config without the scan's table.
pub(crate) const NEEDS_TABLE: &str = "tilt-shift needs a [tilt_shift] table with tau_width, taus and one of: shifts = [...] with angles_deg = [...], cells = [[shift, angle_deg], ...] or refocus = [displacement, ...]";

/// The scan a scene task asks for (its `[tilt_shift]` table).
pub(crate) fn scan_of(task: &SceneTask) -> Result<TiltShift> {
    let t = task
        .config
        .tilt_shift
        .as_ref()
        .ok_or_else(|| Error::input(NEEDS_TABLE))?;
    // the depth decides the refocusing tilts
    let depth = TiltShift::depth_of(&task.scene)?;
    let cells: Vec<(f64, f64)> = if !t.refocus.is_empty() {
        t.refocus
            .iter()
            .flat_map(|&d| {
                let theta = best_tilt(depth, d);
                [(d, 0.0), (d + depth * theta, theta)]
            })
            .collect()
    } else if !t.cells.is_empty() {
        t.cells.iter().map(|c| (c[0], c[1].to_radians())).collect()
    } else {
        t.shifts
            .iter()
            .flat_map(|&s| t.angles_deg.iter().map(move |a| (s, a.to_radians())))
            .collect()
    };
    TiltShift::new(&task.scene, &cells, t.tau_width, t.taus as usize)
}

/// Standard errors of `r = |C|/√(I₁ I₂)` per cell by batch means of its linearisation
/// `δr = Re(C̄ δC)/(|C| √(I₁I₂)) − r (δI₁/I₁ + δI₂/I₂)/2` over the chunks (`kept`: every output,
/// chunk after chunk), so the correlation of `C` with the intensities counts (at `C = I`, `r = 1`
/// exactly and its error is 0).
fn normalised_stderr(
    kept: &[crate::math::C64],
    mean: &[crate::math::C64],
    cells: usize,
) -> Vec<f64> {
    let outputs = 3 * cells;
    let chunks = kept.len() / outputs.max(1);
    (0..cells)
        .map(|c| {
            let (cm, i1, i2) = (mean[c], mean[cells + 2 * c].re, mean[cells + 2 * c + 1].re);
            let (norm, size) = ((i1 * i2).sqrt(), cm.norm());
            if chunks < 2 || norm <= 0.0 || size <= 0.0 {
                return 0.0;
            }
            let r = size / norm;
            let y: Vec<f64> = (0..chunks)
                .map(|k| {
                    let at = |i: usize| kept[k * outputs + i];
                    let dc = at(c) - cm;
                    let (d1, d2) = (at(cells + 2 * c).re - i1, at(cells + 2 * c + 1).re - i2);
                    (cm.conj() * dc).re / (size * norm) - 0.5 * r * (d1 / i1 + d2 / i2)
                })
                .collect();
            let var = y.iter().map(|v| v * v).sum::<f64>() / (chunks - 1) as f64;
            (var / chunks as f64).sqrt()
        })
        .collect()
}

/// `ℓ_tr = 1/(σ_s (1 − g) + σ_a)`, `g` the medium's mean cosine.
fn transport_mfp(task: &SceneTask) -> f64 {
    let m = &task.scene.medium;
    let g: f64 = m
        .scattering
        .components()
        .iter()
        .map(|(w, p)| w * p.mean_cosine())
        .sum();
    1.0 / (m.sigma_s * (1.0 - g) + m.sigma_a)
}

/// `tilt_shift.json` from the run's blocks: every cell, and the refocusing curves or the
/// `(Δb, θ)` grid the config asks for.
pub(crate) fn tilt_file(
    task: &SceneTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<TiltShiftFile> {
    let cfg = task
        .config
        .tilt_shift
        .as_ref()
        .ok_or_else(|| Error::input(NEEDS_TABLE))?;
    let scan = scan_of(task)?;
    let root = merge(blocks, plan.chunks)?;
    let e = Estimate::from_block(&root, plan);
    super::run::check_finite("tilt-shift", &e.mean)?;
    let n = scan.cells.len();
    let normalised_se = normalised_stderr(&root.kept, &e.mean, n);
    let ltr = transport_mfp(task);
    let k = task.scene.k;
    let cells: Vec<TiltShiftCell> = scan
        .cells
        .iter()
        .enumerate()
        .map(|(c, cell)| {
            let norm = (e.mean[n + 2 * c].re * e.mean[n + 2 * c + 1].re).sqrt();
            let ratio = |x: f64| if norm > 0.0 { x / norm } else { 0.0 };
            TiltShiftCell {
                shift: cell.shift,
                angle_deg: cell.angle.to_degrees(),
                input_shift: scan.input_shift(cell),
                re: e.mean[c].re,
                im: e.mean[c].im,
                stderr: e.stderr[c],
                normalised: ratio(e.mean[c].norm()),
                normalised_stderr: normalised_se[c],
                model: model(scan.depth, k, ltr, cell.shift, cell.angle),
            }
        })
        .collect();
    let (mut grid, mut refocus) = (None, None);
    if !cfg.refocus.is_empty() {
        let pick = |i: usize, f: &dyn Fn(&TiltShiftCell) -> f64| -> Vec<f64> {
            cells.iter().skip(i).step_by(2).map(f).collect()
        };
        let power = |c: &TiltShiftCell| c.normalised * c.normalised;
        let power_se = |c: &TiltShiftCell| 2.0 * c.normalised * c.normalised_stderr;
        let r = Refocus {
            displacements: cfg.refocus.clone(),
            power_shift: pick(0, &power),
            power_shift_stderr: pick(0, &power_se),
            power_tilt: pick(1, &power),
            power_tilt_stderr: pick(1, &power_se),
            tilts_deg: pick(1, &|c| c.angle_deg),
            model_shift: pick(0, &|c| c.model * c.model),
            model_tilt: pick(1, &|c| c.model * c.model),
        };
        refocus = Some(r);
    } else if !cfg.shifts.is_empty() {
        let na = cfg.angles_deg.len();
        let rows = |f: &dyn Fn(&TiltShiftCell) -> f64| -> Vec<Vec<f64>> {
            cells
                .chunks(na)
                .map(|r| r.iter().map(f).collect())
                .collect()
        };
        let g = TiltShiftGrid {
            shifts: cfg.shifts.clone(),
            angles_deg: cfg.angles_deg.clone(),
            normalised: rows(&|c| c.normalised),
            model: rows(&|c| c.model),
        };
        grid = Some(g);
    }
    let file = TiltShiftFile {
        run: super::run::mc_echo(task, &scan.scene, plan, seconds),
        depth: scan.depth,
        transport_mfp: ltr,
        cells,
        grid,
        refocus,
    };
    Ok(file)
}

/// Write `tilt_shift.json` and its plot (the refocusing curves against Eq. 50, or the scanned
/// `|C(Δb, θ)|` beside the model) into `out`.
pub(crate) fn write_tilt(file: &TiltShiftFile, out: &Path) -> Result<Outcome> {
    let png = out.join("tilt_shift.png");
    let plot_err =
        |err: crate::Error| Error::input(format!("cannot write {}: {err}", png.display()));
    if let Some(r) = &file.refocus {
        let curve = |ys: &[f64]| -> Vec<(f64, f64)> {
            r.displacements
                .iter()
                .copied()
                .zip(ys.iter().copied())
                .collect()
        };
        let series = vec![
            ("shift (Monte Carlo)".to_string(), curve(&r.power_shift)),
            (
                "shift + tilt (Monte Carlo)".to_string(),
                curve(&r.power_tilt),
            ),
            ("shift (Eq. 50)".to_string(), curve(&r.model_shift)),
            ("shift + tilt (Eq. 50)".to_string(), curve(&r.model_tilt)),
        ];
        crate::io::plot::lines(
            &png,
            "refocusing: power at the displaced focus",
            "displacement",
            "|C|² / (I₁ I₂)",
            &series,
            false,
        )
        .map_err(plot_err)?;
    } else if let Some(g) = &file.grid {
        let flat = |m: &Vec<Vec<f64>>| m.iter().flatten().copied().collect::<Vec<f64>>();
        let panels = vec![
            ("Monte Carlo (Eq. 49)".to_string(), flat(&g.normalised)),
            ("model (Eq. 50)".to_string(), flat(&g.model)),
        ];
        crate::io::plot::heat_maps(
            &png,
            "|C(Δb, θ)|: θ across, Δb up",
            &panels,
            g.angles_deg.len(),
            g.shifts.len(),
        )
        .map_err(plot_err)?;
    }
    let path = out.join(TiltShiftFile::NAME);
    file.write(&path)?;
    let mut files = vec![path];
    if png.exists() {
        files.push(png);
    }
    Ok(Outcome {
        not_converged: None,
        summary: format!(
            "tilt-shift correlation of {} cell(s), L = {:.4}, ℓ_tr = {:.4}, from {} paths",
            file.cells.len(),
            file.depth,
            file.transport_mfp,
            file.run.samples
        ),
        files,
    })
}
