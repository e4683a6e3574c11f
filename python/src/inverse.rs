//! Fits and designs from Python: `fit` (medium parameters and phase functions to a target, as
//! `lightpath fit`) and `design` (a grid index field by Adam, or analytic field parameters by
//! L-BFGS, as `lightpath design`). Each returns the command's result file as an object with
//! numpy arrays; `save` writes the command's files.

use crate::{Task, budget, json_text, json_value, py_err, real, run_watched};
use lightpath::app::create_out;
use lightpath::app::fit::{FitOptions, Fitted};
use lightpath::app::grin::{Designed, ParamFitted};
use lightpath::config;
use lightpath::inverse::journal::Journal;
use numpy::{PyArray1, PyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::Ordering;

/// A fit of medium parameters (and a tabulated phase function) to a target (`lightpath fit`), as
/// `fit.json` holds it. Values are natural (mfp and σ in the scene's length unit, g, albedo,
/// ρ normalised to `∫ρ dω = 1`).
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct Fit {
    fitted: Fitted,
}

#[pymethods]
impl Fit {
    /// The fitted parameters' names (`mfp`, `g`, …, then `rho(θ°)` per phase node).
    #[getter]
    fn params(&self) -> Vec<String> {
        self.fitted.file.params.clone()
    }

    /// float64 `[P]`: the starting values.
    #[getter]
    fn initial<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.initial)
    }

    /// float64 `[P]`: the fitted values.
    #[getter]
    fn fitted<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.fitted)
    }

    /// float64 `[P]`: one standard deviation of each fitted value (Gauss–Newton).
    #[getter]
    fn stddev<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.stddev)
    }

    /// float64 `[P, P]`: the parameters' correlation matrix (L-BFGS fits), else None.
    #[getter]
    fn correlation<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.fitted
            .file
            .correlation
            .as_ref()
            .map(|c| {
                let p = c.len();
                real(py, (c.iter().flatten().copied().collect(), vec![p, p]))
            })
            .transpose()
    }

    /// The final loss (L-BFGS: weighted by the target's errors; Adam: per residual).
    #[getter]
    fn loss(&self) -> f64 {
        self.fitted.file.loss
    }

    /// Whether the fit converged (see `convergence` for why it stopped).
    #[getter]
    fn converged(&self) -> bool {
        self.fitted.file.convergence.is_some_and(|c| c.converged)
    }

    /// dict: `converged`, `stop` (why it stopped), `grad_norm`, `evaluations`, `iterations`.
    #[getter]
    fn convergence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.fitted.file.convergence)
    }

    /// float64 `[K]`: the target's statistics (memory curve or covariance entries, as the
    /// target lists them) modelled at the starting values.
    #[getter]
    fn model_initial<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.model_initial)
    }

    /// float64 `[K]`: the same at the fitted values.
    #[getter]
    fn model_fitted<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.model_fitted)
    }

    /// float64 `[N]`: the phase function's node angles in degrees (phase fits), else None.
    #[getter]
    fn phase_angle_deg<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.fitted
            .file
            .phase_angle_deg
            .as_ref()
            .map(|v| PyArray1::from_slice(py, v))
    }

    /// float64 `[E]`: the loss of every logged evaluation (L-BFGS) or iteration (Adam).
    #[getter]
    fn log_loss<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.fitted.file.log.iter().map(|l| l.loss).collect();
        PyArray1::from_vec(py, v)
    }

    /// float64 `[E, P]`: the parameter values of every logged evaluation.
    #[getter]
    fn log_params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let log = &self.fitted.file.log;
        let p = self.fitted.file.params.len();
        let v: Vec<f64> = log.iter().flat_map(|l| l.params.iter().copied()).collect();
        real(py, (v, vec![log.len(), p]))
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.fitted.file.seconds
    }

    /// What the command prints: values `initial → fitted ± sd`, correlations, convergence.
    #[getter]
    fn summary(&self) -> String {
        self.fitted.summary.trim_end().to_string()
    }

    /// `fit.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.fitted.file)
    }

    /// Write `fit.json`, `fit.png` (a memory-curve target) and `phase.png` (a phase fit) into
    /// `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, &["fit.json", "fit.png", "phase.png"]).map_err(py_err)?;
        Ok(self.fitted.write(&folder).map_err(py_err)?.files)
    }

    fn __repr__(&self) -> String {
        let f = &self.fitted.file;
        let values: Vec<String> = f
            .params
            .iter()
            .zip(&f.fitted)
            .zip(&f.stddev)
            .take(4)
            .map(|((n, v), s)| format!("{n} = {v:.5} ± {s:.5}"))
            .collect();
        format!(
            "<lightpath.Fit {}{}, {}>",
            values.join(", "),
            if f.params.len() > 4 { ", …" } else { "" },
            if self.converged() {
                "converged"
            } else {
                "NOT converged"
            }
        )
    }
}

/// Fit medium parameters (and a phase function) of a speckle scene so its statistics match the
/// target file (`lightpath fit`).
#[pyfunction]
#[pyo3(signature = (task, target, fit, *, samples=None, seed=None, stages=30, iterations=None, optimizer=None, learning_rate=0.05, smooth=0.0, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None, checkpoint=None, checkpoint_every=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit(
    py: Python<'_>,
    task: &Task,
    target: PathBuf,
    fit: String,
    samples: Option<u64>,
    seed: Option<u64>,
    stages: usize,
    iterations: Option<usize>,
    optimizer: Option<String>,
    learning_rate: f64,
    smooth: f64,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
    checkpoint: Option<PathBuf>,
    checkpoint_every: Option<u64>,
) -> PyResult<Fit> {
    let scene = task.scene("fit")?;
    let opts = FitOptions {
        fit,
        samples,
        seed,
        stages,
        iterations,
        optimizer,
        learning_rate,
        smooth,
        progress: false,
        budget: budget(max_minutes, max_memory_gb),
        resume: Default::default(),
    };
    let prepared = lightpath::app::fit::prepare(scene, &target, &opts).map_err(py_err)?;
    let journal = journal(
        "fit",
        prepared.identity(),
        checkpoint.as_deref(),
        checkpoint_every,
    )?;
    let fitted = run_watched(py, threads, progress, move |w| {
        w.total
            .store(prepared.total().unwrap_or(0) as u64, Ordering::Relaxed);
        let stop = w.stop_flag();
        prepared.run(&|_| w.tick(), &stop, &journal)
    })?;
    finished(checkpoint.as_deref())?;
    Ok(Fit { fitted })
}

/// The journal of a fit or design: kept in `checkpoint` (continuing the run saved there) when
/// given, else in memory only.
fn journal(
    kind: &str,
    identity: lightpath::Result<serde_json::Value>,
    checkpoint: Option<&std::path::Path>,
    every: Option<u64>,
) -> PyResult<Journal> {
    match checkpoint {
        Some(dir) => {
            lightpath::app::resumable(kind, identity.map_err(py_err)?, dir, every).map_err(py_err)
        }
        None => Ok(Journal::default()),
    }
}

/// A finished run's checkpoint has nothing left to resume.
fn finished(checkpoint: Option<&std::path::Path>) -> PyResult<()> {
    checkpoint.map_or(Ok(()), |dir| {
        lightpath::app::remove_checkpoint(dir).map_err(py_err)
    })
}

/// A grid index field designed by Adam so beams pass through their foci (`lightpath design`),
/// as `design.json` holds it.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct Design {
    designed: Designed,
}

impl Design {
    /// numpy's order of the grid's nodes: `[nz, ny, nx]` (x fastest).
    fn grid_shape(&self) -> Vec<usize> {
        let [nx, ny, nz] = self.designed.file.grid.dims;
        vec![nz as usize, ny as usize, nx as usize]
    }
}

#[pymethods]
impl Design {
    /// The RMS distance of the beams' foci from the rays' exit lines, before and after.
    #[getter]
    fn rms_miss_initial(&self) -> f64 {
        self.designed.file.rms_miss_initial
    }

    #[getter]
    fn rms_miss_final(&self) -> f64 {
        self.designed.file.rms_miss_final
    }

    /// float64 `[nz, ny, nx]`: the designed grid's contribution to `n` at its nodes.
    #[getter]
    fn grid<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(
            py,
            (self.designed.file.grid.samples.clone(), self.grid_shape()),
        )
    }

    /// float64 `[nz, ny, nx]`: its interpolation coefficients (what `trace_vjp(grid=True)`
    /// differentiates; equal to `grid` for trilinear interpolation).
    #[getter]
    fn coefficients<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(
            py,
            (
                self.designed.file.grid.coefficients.clone(),
                self.grid_shape(),
            ),
        )
    }

    /// float64 `[3]`: the grid's first node (x, y, z), in the length unit.
    #[getter]
    fn origin<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.designed.file.grid.origin)
    }

    /// The node spacing, in the length unit.
    #[getter]
    fn spacing(&self) -> f64 {
        self.designed.file.grid.spacing
    }

    /// dict of float64 `[R]` arrays: `r`, and the designed `n` along 26 radial directions at
    /// each `r`: `mean`, `min`, `max`.
    #[getter]
    fn radial_profile<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let p = &self.designed.file.radial_profile;
        let d = pyo3::types::PyDict::new(py);
        for (k, v) in [
            ("r", &p.r),
            ("mean", &p.mean),
            ("min", &p.min),
            ("max", &p.max),
        ] {
            d.set_item(k, PyArray1::from_slice(py, v))?;
        }
        Ok(d.into_any())
    }

    /// int `[I]`: each iteration's level (coarse to fine).
    #[getter]
    fn log_level<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        let v: Vec<u64> = self
            .designed
            .file
            .log
            .iter()
            .map(|l| l.level as u64)
            .collect();
        PyArray1::from_vec(py, v)
    }

    /// float64 `[I]`: each iteration's mean squared miss distance.
    #[getter]
    fn log_mean_miss2<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self
            .designed
            .file
            .log
            .iter()
            .map(|l| l.mean_miss2)
            .collect();
        PyArray1::from_vec(py, v)
    }

    /// float64 `[I]`: each iteration's loss (miss² plus the smoothness term).
    #[getter]
    fn log_loss<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.designed.file.log.iter().map(|l| l.loss).collect();
        PyArray1::from_vec(py, v)
    }

    /// Whether the last level's loss reached a plateau.
    #[getter]
    fn converged(&self) -> bool {
        self.designed.file.convergence.is_some_and(|c| c.converged)
    }

    /// dict: `converged`, `stop`, `grad_norm`, `evaluations`, `iterations`.
    #[getter]
    fn convergence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.designed.file.convergence)
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.designed.file.seconds
    }

    /// What the command prints.
    #[getter]
    fn summary(&self) -> String {
        self.designed.summary.clone()
    }

    /// `design.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.designed.file)
    }

    /// Write `design.json`, `loss.png`, `profile.png` and `grid_slice_z.exr` into `folder`; the
    /// paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(
            &folder,
            &["design.json", "loss.png", "profile.png", "grid_slice_z.exr"],
        )
        .map_err(py_err)?;
        Ok(self.designed.write(&folder).map_err(py_err)?.files)
    }

    fn __repr__(&self) -> String {
        let f = &self.designed.file;
        format!(
            "<lightpath.Design {:?} grid, RMS miss {:.3e} → {:.3e}>",
            f.grid.dims, f.rms_miss_initial, f.rms_miss_final
        )
    }
}

/// Analytic index-field parameters fitted by L-BFGS so beams pass through their foci
/// (`lightpath design` with a `[parameters]` table), as its `fit.json` holds them.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct GrinFit {
    fitted: ParamFitted,
}

#[pymethods]
impl GrinFit {
    /// The parameters' names, as the config's `[parameters]` gives them
    /// (`profiles[i].name`).
    #[getter]
    fn params(&self) -> Vec<String> {
        self.fitted.file.parameters.clone()
    }

    /// float64 `[P]`: the starting values.
    #[getter]
    fn initial<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.initial)
    }

    /// float64 `[P]`: the fitted values.
    #[getter]
    fn fitted<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.fitted.file.fitted)
    }

    /// The RMS distance of the beams' foci from the rays' exit lines, before and after.
    #[getter]
    fn rms_miss_initial(&self) -> f64 {
        self.fitted.file.rms_miss_initial
    }

    #[getter]
    fn rms_miss_final(&self) -> f64 {
        self.fitted.file.rms_miss_final
    }

    /// float64 `[E]`: each evaluation's mean squared miss distance.
    #[getter]
    fn log_mean_miss2<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.fitted.file.log.iter().map(|l| l.mean_miss2).collect();
        PyArray1::from_vec(py, v)
    }

    /// float64 `[E, P]`: each evaluation's parameter values.
    #[getter]
    fn log_params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let log = &self.fitted.file.log;
        let p = self.fitted.file.parameters.len();
        let v: Vec<f64> = log
            .iter()
            .flat_map(|l| l.parameters.iter().copied())
            .collect();
        real(py, (v, vec![log.len(), p]))
    }

    /// Whether L-BFGS converged.
    #[getter]
    fn converged(&self) -> bool {
        self.fitted.file.convergence.is_some_and(|c| c.converged)
    }

    /// dict: `converged`, `stop`, `grad_norm`, `evaluations`, `iterations`.
    #[getter]
    fn convergence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.fitted.file.convergence)
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.fitted.file.seconds
    }

    /// What the command prints.
    #[getter]
    fn summary(&self) -> String {
        self.fitted.summary.clone()
    }

    /// `fit.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.fitted.file)
    }

    /// Write `fit.json`, `loss.png` and `rays.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, &["fit.json", "loss.png", "rays.png"]).map_err(py_err)?;
        Ok(self.fitted.write(&folder).map_err(py_err)?.files)
    }

    fn __repr__(&self) -> String {
        let f = &self.fitted.file;
        format!(
            "<lightpath.GrinFit {} parameter(s), RMS miss {:.3e} → {:.3e}>",
            f.parameters.len(),
            f.rms_miss_initial,
            f.rms_miss_final
        )
    }
}

/// A render's index field designed toward a target (`lightpath design` on a render config with a
/// `[design]` table), as its `render_design.json` holds it.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct RenderDesign {
    file: lightpath::io::results::RenderDesignFile,
    summary: String,
}

#[pymethods]
impl RenderDesign {
    /// The parameters' names (`profiles[i].name`, or the medium's).
    #[getter]
    fn params(&self) -> Vec<String> {
        self.file
            .parameters
            .iter()
            .map(|p| p.name.clone())
            .collect()
    }

    /// `"adam"` (fresh photons every iteration) or `"lbfgs"` (held photons).
    #[getter]
    fn method(&self) -> &'static str {
        match self.file.method {
            lightpath::inverse::render_design::DesignMethod::Adam => "adam",
            lightpath::inverse::render_design::DesignMethod::Lbfgs => "lbfgs",
        }
    }

    /// float64 `[P]`: where the design started (the config's values).
    #[getter]
    fn start<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.file.parameters.iter().map(|p| p.start).collect())
    }

    /// float64 `[P]`: the design.
    #[getter]
    fn designed<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(
            py,
            self.file.parameters.iter().map(|p| p.designed).collect(),
        )
    }

    /// float64 `[I]`: the objective (`ln F`, or `ln F − ln F_reference`) of each Adam iteration
    /// or L-BFGS evaluation.
    #[getter]
    fn log_objective<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.file.log.iter().map(|l| l.objective).collect())
    }

    /// dict: the check at a fresh seed (`photons`, `seed`, `start`, `designed`, `gain`, each
    /// fluence `{mean, stderr}`).
    #[getter]
    fn verification<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.file.verification)
    }

    /// Whether the objective stopped rising beyond its noise.
    #[getter]
    fn converged(&self) -> bool {
        self.file.convergence.converged
    }

    /// What the command prints.
    #[getter]
    fn summary(&self) -> String {
        self.summary.clone()
    }

    /// `render_design.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `render_design.json` and `loss.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, &["render_design.json", "loss.png"]).map_err(py_err)?;
        Ok(lightpath::app::render_design::write(&self.file, &folder)
            .map_err(py_err)?
            .files)
    }

    fn __repr__(&self) -> String {
        let v = &self.file.verification.gain;
        format!(
            "<lightpath.RenderDesign {} parameter(s), gain {:.4} ± {:.4}>",
            self.file.parameters.len(),
            v.mean,
            v.stderr
        )
    }
}

/// A design config run (`lightpath design`): a grid design (`Design`), with a `[parameters]`
/// table an analytic parameter fit (`GrinFit`), or a render config's `[design]`
/// (`RenderDesign`).
#[pyfunction]
#[pyo3(signature = (task, *, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None, checkpoint=None, checkpoint_every=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn design(
    py: Python<'_>,
    task: &Task,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
    checkpoint: Option<PathBuf>,
    checkpoint_every: Option<u64>,
) -> PyResult<Py<PyAny>> {
    let limits = budget(max_minutes, max_memory_gb);
    let checkpoint = checkpoint.as_deref();
    match &task.task {
        config::Task::Design(t) => {
            let t = (**t).clone();
            lightpath::app::grin::check_design(&t, &limits).map_err(py_err)?;
            let identity = lightpath::app::grin::identity(&t.config);
            let journal = journal("design", identity, checkpoint, checkpoint_every)?;
            let total = (t.problem.levels.len() * t.problem.iterations) as u64;
            let designed = run_watched(py, threads, progress, move |w| {
                w.total.store(total, Ordering::Relaxed);
                lightpath::app::grin::run_design(&t, &|_| w.tick(), &w.stop_flag(), &journal)
            })?;
            finished(checkpoint)?;
            Ok(Py::new(py, Design { designed })?.into_any())
        }
        config::Task::ParamFit(t) => {
            let t = (**t).clone();
            lightpath::app::grin::check_param_fit(&t, &limits).map_err(py_err)?;
            let identity = lightpath::app::grin::identity(&t.config);
            let journal = journal("design", identity, checkpoint, checkpoint_every)?;
            let fitted = run_watched(py, threads, progress, move |w| {
                // L-BFGS's evaluation count is not known in advance: total 0
                lightpath::app::grin::run_param_fit(&t, &|_| w.tick(), &w.stop_flag(), &journal)
            })?;
            finished(checkpoint)?;
            Ok(Py::new(py, GrinFit { fitted })?.into_any())
        }
        config::Task::Render(t) if t.design.is_some() => {
            let t = (**t).clone();
            let problem = t.design.clone().expect("a design");
            lightpath::app::render_design::check(&problem, &limits).map_err(py_err)?;
            let identity = lightpath::app::grin::identity(&t.config);
            let journal = journal("render design", identity, checkpoint, checkpoint_every)?;
            let total = problem.iterations as u64;
            let file = run_watched(py, threads, progress, move |w| {
                w.total.store(total, Ordering::Relaxed);
                lightpath::app::render_design::run(
                    &t,
                    &problem,
                    &|_| w.tick(),
                    &w.stop_flag(),
                    &journal,
                )
            })?;
            finished(checkpoint)?;
            let summary = lightpath::app::render_design::summary(&file);
            Ok(Py::new(py, RenderDesign { file, summary })?.into_any())
        }
        other => Err(PyValueError::new_err(format!(
            "design: needs a design config ([field] + [design], or [parameters] to fit, or a render config with [design]), but the config holds {}",
            other.kind().describe()
        ))),
    }
}
