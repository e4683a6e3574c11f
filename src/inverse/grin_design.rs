//! Graded-index design (lecture 003's GRIN optimisation targets): shape a grid index
//! field so collimated beams pass through their foci, by Adam through [`TraceOp`], coarse to
//! fine.
//!
//! The loss is the mean squared miss distance — the distance from each beam's focus to the
//! straight line a ray follows after its last step (outside the bounds `n` is constant, so rays
//! are straight there) — plus `smooth` times the squared differences of neighbouring grid
//! coefficients along each axis. Each level starts from the previous level's field sampled on a
//! finer grid.

use super::journal::{Journal, Numbers, recall};
use crate::diff::TraceOp;
use crate::diff::bridge::{apply, device, tensor, values};
use crate::eikonal::grid::{GridField, Interp};
use crate::eikonal::{BoundedField, IndexField, Profile, Ray};
use burn::tensor::Tensor;
use glam::DVec3;

/// A bundle of rays (origins, unit directions) that should pass through `focus`.
#[derive(Clone, Debug, PartialEq)]
pub struct Beam {
    pub rays: Vec<(DVec3, DVec3)>,
    pub focus: DVec3,
}

/// Every ray of every beam, as `(origin, unit direction)`.
pub fn all_rays(beams: &[Beam]) -> Vec<(DVec3, DVec3)> {
    beams.iter().flat_map(|b| b.rays.iter().copied()).collect()
}

/// The design problem.
#[derive(Clone, Debug)]
pub struct FocusDesign {
    /// Bounds, `n_out` and any fixed background profiles; the designed grid is added to them.
    pub background: BoundedField,
    /// Grid nodes per side at each level, coarse to fine.
    pub levels: Vec<usize>,
    pub interp: Interp,
    /// Starting value of the grid's samples.
    pub initial: f64,
    pub beams: Vec<Beam>,
    pub step: f64,
    /// Leapfrog steps per ray, or with `to_exit` the most a ray may take before it leaves.
    pub steps: usize,
    /// Trace each ray to where it leaves the bounds (refraction at jumps of `n` included) instead of
    /// a fixed number of steps.
    pub to_exit: bool,
    pub iterations: usize,
    pub learning_rate: f64,
    pub smooth: f64,
}

/// One iteration's record.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignStep {
    pub level: usize,
    pub iteration: usize,
    /// Mean squared miss distance (without the smoothness term).
    pub miss2: f64,
    pub loss: f64,
}

impl Numbers for DesignStep {
    fn to_numbers(&self) -> Vec<f64> {
        vec![
            self.level as f64,
            self.iteration as f64,
            self.miss2,
            self.loss,
        ]
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        match *v {
            [level, iteration, miss2, loss] => Some(DesignStep {
                level: level as usize,
                iteration: iteration as usize,
                miss2,
                loss,
            }),
            _ => None,
        }
    }
}

/// The designed field and the history.
#[derive(Clone, Debug)]
pub struct DesignResult {
    pub field: BoundedField,
    /// The designed grid (samples of its own contribution at the nodes are `grid_samples`).
    pub grid: GridField,
    pub grid_samples: Vec<f64>,
    pub log: Vec<DesignStep>,
    /// RMS miss distance of the starting and the final field.
    pub rms_miss_initial: f64,
    pub rms_miss_final: f64,
    /// Adam runs a fixed number of iterations per level: converged when the last level's loss has
    /// reached a plateau.
    pub convergence: super::Convergence,
}

impl FocusDesign {
    /// Half extents of the bounds (the grid spans them, padded by two cells).
    fn half(&self) -> crate::Result<DVec3> {
        self.background
            .bounds
            .half_extent()
            .ok_or_else(|| "design: the field needs bounds (sphere, cylinder or box)".into())
    }

    fn grid_at(&self, n: usize, samples: Vec<f64>) -> crate::Result<GridField> {
        let half = self.half()?;
        let extent = half.max_element() * 2.0 * (1.0 + 2.0 / n as f64);
        let spacing = extent / (n - 1) as f64;
        GridField::from_samples(
            DVec3::splat(-0.5 * extent),
            spacing,
            [n; 3],
            samples,
            self.interp,
        )
    }

    fn node(g: &GridField, i: usize) -> DVec3 {
        let [nx, ny, _] = g.dims;
        g.origin
            + DVec3::new(
                (i % nx) as f64,
                (i / nx % ny) as f64,
                (i / (nx * ny)) as f64,
            ) * g.spacing
    }

    fn field_with(&self, g: &GridField) -> BoundedField {
        let mut f = self.background.clone();
        f.profiles.push(Profile::Grid(g.clone()));
        f
    }

    fn rays(&self, field: &BoundedField) -> Vec<Ray> {
        self.beams
            .iter()
            .flat_map(|b| b.rays.iter())
            .map(|(x, d)| Ray {
                x: *x,
                // exit mode takes origin and unit direction; fixed steps the σ-form state
                v: if self.to_exit { *d } else { *d * field.n(*x) },
            })
            .collect()
    }

    /// `(mean miss², total loss)` in burn from the final states `y` and coefficients `c`.
    fn loss(
        &self,
        y: Tensor<1>,
        c: Tensor<1>,
        foci: &Tensor<2>,
        n: usize,
    ) -> (Tensor<1>, Tensor<1>) {
        let r = y.dims()[0] / 6;
        let y = y.reshape([r, 6]);
        let x = y.clone().narrow(1, 0, 3);
        let v = y.narrow(1, 3, 3);
        let d = foci.clone() - x;
        let dd = (d.clone() * d.clone()).sum_dim(1);
        let dv = (d * v.clone()).sum_dim(1);
        let vv = (v.clone() * v).sum_dim(1);
        let miss2 = (dd - dv.clone() * dv / vv).mean().reshape([1]);
        if self.smooth == 0.0 {
            return (miss2.clone(), miss2);
        }
        let g = c.reshape([n, n, n]);
        let mut rough = Tensor::<1>::zeros([1], (&g.device(), burn::tensor::DType::F64));
        for axis in 0..3 {
            let diff = g.clone().narrow(axis, 1, n - 1) - g.clone().narrow(axis, 0, n - 1);
            rough = rough + (diff.clone() * diff).sum().reshape([1]);
        }
        (miss2.clone(), miss2 + rough * self.smooth)
    }

    /// The field the design starts from (the grid at the first level, every sample `initial`):
    /// what a time estimate traces.
    pub fn initial_field(&self) -> crate::Result<BoundedField> {
        let n = *self.levels.first().ok_or("design: no grid levels")?;
        Ok(self.field_with(&self.grid_at(n, vec![self.initial; n * n * n])?))
    }

    /// Run every level; `progress` sees each iteration; `stop` ends the run within one ray's
    /// trace with [`crate::Error::Interrupted`]; `journal` records the run (and replays the
    /// run it was saved from).
    pub fn run(
        &self,
        progress: &dyn Fn(&DesignStep),
        stop: &crate::mc::StopFlag,
        journal: &Journal,
    ) -> crate::Result<DesignResult> {
        if self.levels.is_empty() || self.levels.iter().any(|&n| n < 4) {
            return Err(format!(
                "design: levels {:?} must be grid sizes of at least 4 nodes per side",
                self.levels
            )
            .into());
        }
        if self.beams.iter().all(|b| b.rays.is_empty()) {
            return Err("design: no rays".into());
        }
        let dev = device();
        let foci: Vec<f64> = self
            .beams
            .iter()
            .flat_map(|b| b.rays.iter().flat_map(|_| b.focus.to_array()))
            .collect();
        let rays_total = foci.len() / 3;
        let foci = tensor(&foci, &dev).reshape([rays_total, 3]);
        let mut grid = self.grid_at(self.levels[0], vec![self.initial; self.levels[0].pow(3)])?;
        let mut log = Vec::new();
        let mut last_grad_norm = f64::NAN;
        let miss = |g: &GridField| -> crate::Result<f64> {
            let field = self.field_with(g);
            let op = self.op(field, stop);
            let y = values(&apply(&op, tensor(&g.coef, &burn::tensor::Device::flex()))?);
            Ok(rms_miss(&y, &self.beams))
        };
        let rms_miss_initial = recall(journal, &grid.coef, || miss(&grid))?;
        for (level, &n) in self.levels.iter().enumerate() {
            if level > 0 {
                // the previous level's contribution, sampled at the finer nodes
                let coarse = grid.clone();
                let fine = self.grid_at(n, vec![0.0; n * n * n])?;
                let samples = (0..n * n * n)
                    .map(|i| coarse.eval(Self::node(&fine, i)).0)
                    .collect();
                grid = self.grid_at(n, samples)?;
            }
            let op = self.op(self.field_with(&grid), stop);
            grid.coef = super::adam::minimise(
                &grid.coef,
                self.iterations,
                &|_| self.learning_rate,
                self.iterations,
                journal,
                &mut |iteration, c| {
                    let y = apply(&op, c.clone()).map_err(|e| {
                        if stop.is_set() {
                            crate::Error::Interrupted
                        } else {
                            format!("design level {level}, iteration {iteration}: {e}").into()
                        }
                    })?;
                    let (miss2, loss) = self.loss(y, c, &foci, n);
                    let entry = DesignStep {
                        level,
                        iteration,
                        miss2: values(&miss2)[0],
                        loss: values(&loss)[0],
                    };
                    Ok((loss, entry))
                },
                &mut |it| {
                    // a pullback cut short by the flag: report the stop, not its gradient
                    stop.check()?;
                    let entry = it.observed;
                    if !entry.loss.is_finite() {
                        return Err(format!(
                            "design level {level}, iteration {}: the loss is not finite; try a smaller learning_rate",
                            entry.iteration
                        ).into());
                    }
                    last_grad_norm = it.grad_norm;
                    progress(&entry);
                    log.push(entry);
                    Ok(())
                },
            )?
            .last;
        }
        let grid_samples = (0..grid.coef.len())
            .map(|i| grid.eval(Self::node(&grid, i)).0)
            .collect();
        let last_level: Vec<f64> = log
            .iter()
            .filter(|s| s.level + 1 == self.levels.len())
            .map(|s| s.loss)
            .collect();
        let convergence = super::adam::convergence(&last_level, last_grad_norm, log.len());
        Ok(DesignResult {
            convergence,
            field: self.field_with(&grid),
            rms_miss_final: miss(&grid)?,
            grid,
            grid_samples,
            log,
            rms_miss_initial,
        })
    }

    fn op(&self, field: BoundedField, stop: &crate::mc::StopFlag) -> TraceOp {
        let rays = self.rays(&field);
        TraceOp {
            profile: field.profiles.len() - 1,
            field,
            rays,
            steps: self.steps,
            step: self.step,
            to_exit: self.to_exit,
            stop: stop.clone(),
        }
    }
}

/// RMS distance of the beams' foci from the rays' final straight lines (`y`: 6 values a ray).
pub fn rms_miss(y: &[f64], beams: &[Beam]) -> f64 {
    let foci: Vec<DVec3> = beams
        .iter()
        .flat_map(|b| b.rays.iter().map(|_| b.focus))
        .collect();
    let mut acc = 0.0;
    for (i, f) in foci.iter().enumerate() {
        let x = DVec3::new(y[6 * i], y[6 * i + 1], y[6 * i + 2]);
        let v = DVec3::new(y[6 * i + 3], y[6 * i + 4], y[6 * i + 5]);
        acc += (*f - x).cross(v.normalize()).length_squared();
    }
    (acc / foci.len().max(1) as f64).sqrt()
}

/// `n(r)` of a field along 26 directions from the origin: `(r, mean, min, max)` for `count` radii
/// up to `r_max` (how close a design came to a radial profile such as Luneburg's).
pub fn radial_profile(field: &BoundedField, r_max: f64, count: usize) -> Vec<(f64, f64, f64, f64)> {
    let mut dirs = Vec::new();
    for i in -1i32..=1 {
        for j in -1i32..=1 {
            for k in -1i32..=1 {
                if (i, j, k) != (0, 0, 0) {
                    dirs.push(DVec3::new(i as f64, j as f64, k as f64).normalize());
                }
            }
        }
    }
    (0..count)
        .map(|s| {
            let r = r_max * s as f64 / (count - 1).max(1) as f64;
            let ns: Vec<f64> = dirs.iter().map(|d| field.n(*d * r)).collect();
            let mean = ns.iter().sum::<f64>() / ns.len() as f64;
            let (lo, hi) = ns
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(*x), b.max(*x))
                });
            (r, mean, lo, hi)
        })
        .collect()
}
