//! Rendering and acquisition from Python: `render` (a refractive, scattering volume by particle or
//! camera path tracing, as `lightpath render`), `render_vjp` (its sensors' outputs as a
//! differentiable function of the medium's and the index field's parameters) and `acquire_phase`
//! (the phase function read from speckle images, as `lightpath acquire-phase`).

use crate::{Task, budget, json_text, json_value, py_err, real, run_watched};
use lightpath::app::create_out;
use lightpath::app::render::{FILES, Image, Rendered};
use lightpath::config;
use lightpath::io::results::PhaseAcquisitionFile;
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyRuntimeError;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// `[channels, height, width]` planes (top row first) of one frame: values or standard errors.
fn planes(frame: &[(Vec<f64>, Vec<f64>)], errors: bool) -> Vec<f64> {
    frame
        .iter()
        .flat_map(|(v, e)| if errors { e } else { v }.iter().copied())
        .collect()
}

/// One image as a dict of float64 arrays: `value` and `stderr` `[C, H, W]` (time-integrated),
/// and with time bins `bins` and `bins_stderr` `[B, C, H, W]`.
fn image_dict<'py>(py: Python<'py>, image: &Image) -> PyResult<Bound<'py, PyDict>> {
    let (c, h, w) = (image.total.len(), image.height, image.width);
    let d = PyDict::new(py);
    d.set_item(
        "value",
        real(py, (planes(&image.total, false), vec![c, h, w]))?,
    )?;
    d.set_item(
        "stderr",
        real(py, (planes(&image.total, true), vec![c, h, w]))?,
    )?;
    if !image.bins.is_empty() {
        let b = image.bins.len();
        let all = |errors: bool| -> Vec<f64> {
            image.bins.iter().flat_map(|f| planes(f, errors)).collect()
        };
        d.set_item("bins", real(py, (all(false), vec![b, c, h, w]))?)?;
        d.set_item("bins_stderr", real(py, (all(true), vec![b, c, h, w]))?)?;
    }
    Ok(d)
}

/// A render of a refractive, scattering volume (`lightpath render`), as `render.json` and its
/// images hold it.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct Render {
    rendered: Rendered,
}

#[pymethods]
impl Render {
    /// `render.json` as Python values (dicts, lists, floats): every sensor's power and per-bin
    /// flux, probes, targets, cameras, surfaces, absorbed/escaped totals, statistics and the
    /// config.
    #[getter]
    fn result<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.rendered.file)
    }

    /// dict: image name (`screen_<name>`, `camera_<name>`) → dict of float64 arrays: `value` and
    /// `stderr` `[C, H, W]` (C = 1, or 3 for R, G, B; the top row first, as the EXR files hold
    /// them; irradiance for screens, radiance for cameras) and, with time bins, `bins` and
    /// `bins_stderr` `[B, C, H, W]`.
    #[getter]
    fn images<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for image in &self.rendered.images {
            d.set_item(&image.stem, image_dict(py, image)?)?;
        }
        Ok(d)
    }

    /// Photons (or camera paths) traced.
    #[getter]
    fn samples(&self) -> u64 {
        self.rendered.file.samples
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> Option<f64> {
        self.rendered.file.seconds
    }

    /// What the command prints.
    #[getter]
    fn summary(&self) -> String {
        self.rendered.summary.clone()
    }

    /// A warning when a noticeable share of the power was given up, else None.
    #[getter]
    fn warning(&self) -> Option<String> {
        self.rendered.warning.clone()
    }

    /// `render.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.rendered.file)
    }

    /// Write `render.json` and every image's EXR files and PNG preview into `folder`; the paths
    /// written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, FILES).map_err(py_err)?;
        Ok(self.rendered.write(&folder).map_err(py_err)?.files)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.Render {} samples, {} image(s)>",
            self.rendered.file.samples,
            self.rendered.images.len()
        )
    }
}

/// Render a render config (`[volume]`, lights, sensors, cameras) (`lightpath render`).
#[pyfunction]
#[pyo3(signature = (task, *, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn render(
    py: Python<'_>,
    task: &Task,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<Render> {
    let config::Task::Render(t) = &task.task else {
        return Err(PyValueError::new_err(format!(
            "render: needs a render config ([volume] with lights and sensors), but the config holds {}",
            task.task.kind().describe()
        )));
    };
    let t = (**t).clone();
    let limits = budget(max_minutes, max_memory_gb);
    let rendered = run_watched(py, threads, progress, move |w| {
        lightpath::app::render::evaluate(t, samples, seed, &limits, w)
    })?;
    Ok(Render { rendered })
}

/// A render's sensor outputs (powers of flux sensors, screens and spots, targets' and fluence
/// probes' fluences, camera windows' sums) at
/// `theta` with their Jacobian, from one particle-tracing run (`render_vjp`); calling it with
/// `∂L/∂outputs` gives `∂L/∂θ`.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct RenderVjp {
    params: Vec<String>,
    sensors: Vec<String>,
    theta: Vec<f64>,
    value: Vec<f64>,
    stderr: Vec<f64>,
    /// `[S, P]`, row-major.
    jacobian: Vec<f64>,
    jacobian_stderr: Vec<f64>,
    held: bool,
}

#[pymethods]
impl RenderVjp {
    /// float64 `[S]`: every sensor's output at `theta`, in the config's order (the fluence probes
    /// after the other sensors).
    #[getter]
    fn value<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.value)
    }

    /// float64 `[S]`: the standard error of `value`.
    #[getter]
    fn stderr<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.stderr)
    }

    /// float64 `[S, P]`: `∂ value_i / ∂θ_p`.
    #[getter]
    fn jacobian<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(
            py,
            (
                self.jacobian.clone(),
                vec![self.sensors.len(), self.params.len()],
            ),
        )
    }

    /// float64 `[S, P]`: the standard error of `jacobian`.
    #[getter]
    fn jacobian_stderr<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(
            py,
            (
                self.jacobian_stderr.clone(),
                vec![self.sensors.len(), self.params.len()],
            ),
        )
    }

    /// The sensors' names, in the order of `value` (the fluence probes after the other sensors).
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.sensors.clone()
    }

    /// The parameters' names, in the order of `theta` and of the gradient.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.params.clone()
    }

    /// float64 `[P]`: the parameter values the render was evaluated at.
    #[getter]
    fn theta<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.theta)
    }

    /// Whether the photons were held (the same random numbers for any `theta`).
    #[getter]
    fn held(&self) -> bool {
        self.held
    }

    /// `∂L/∂θ` (float64 `[P]`) for the adjoint `∂L/∂value` (float `[S]`).
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        adjoint: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let kwargs = PyDict::new(py);
        kwargs.set_item("dtype", "float64")?;
        let array = py
            .import("numpy")?
            .call_method("asarray", (adjoint,), Some(&kwargs))?;
        let adjoint = array
            .cast::<PyArrayDyn<f64>>()
            .map_err(|_| PyValueError::new_err("adjoint: not an array of real numbers"))?
            .readonly();
        let s = self.sensors.len();
        if adjoint.shape() != [s] {
            return Err(PyValueError::new_err(format!(
                "adjoint: shape {:?}, but the render has [S] = [{s}] outputs ({:?})",
                adjoint.shape(),
                self.sensors
            )));
        }
        let dy: Vec<f64> = adjoint.as_array().iter().copied().collect();
        if dy.iter().any(|x| !x.is_finite()) {
            return Err(PyValueError::new_err(
                "adjoint: holds non-finite values (NaN or infinity)",
            ));
        }
        let p = self.params.len();
        let gradient = (0..p)
            .map(|k| (0..s).map(|i| dy[i] * self.jacobian[i * p + k]).sum())
            .collect();
        Ok(PyArray1::from_vec(py, gradient))
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.RenderVjp {:?} at {:?}, {} output(s){}>",
            self.params,
            self.theta,
            self.sensors.len(),
            if self.held { ", held" } else { "" }
        )
    }
}

/// A render config's sensor outputs at `theta` (values of `params`, default: the config's) and
/// their VJP, by particle tracing with the path-space scores and forward sensitivities
/// `render.derivatives` uses. Fresh photons give unbiased gradients of the expected outputs
/// (Adam); `held = True` draws every scored choice evenly from the same random numbers for any
/// `theta`, so the outputs are a deterministic function whose Jacobian is its exact derivative
/// (L-BFGS; index-field parameters only).
#[pyfunction]
#[pyo3(signature = (task, params, *, theta=None, photons=None, seed=None, held=false, threads=None, max_minutes=240.0, max_memory_gb=8.0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_vjp(
    py: Python<'_>,
    task: &Task,
    params: Vec<String>,
    theta: Option<Vec<f64>>,
    photons: Option<u64>,
    seed: Option<u64>,
    held: bool,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
) -> PyResult<RenderVjp> {
    use lightpath::rrte::{Derivative, ParticleTracer};
    let config::Task::Render(t) = &task.task else {
        return Err(PyValueError::new_err(format!(
            "render_vjp: needs a render config ([volume] with lights and sensors), but the config holds {}",
            task.task.kind().describe()
        )));
    };
    if params.is_empty() {
        return Err(PyValueError::new_err("params: give at least one parameter"));
    }
    let derivatives = t
        .config
        .parameters("params", &params, &t.scene.volume, &t.scene.sensors)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let r = &t.config.render;
    let photons = photons.unwrap_or(r.samples);
    if photons == 0 {
        return Err(PyValueError::new_err("photons = 0: must be at least 1"));
    }
    let mut scene = t.scene.clone();
    scene.derivatives = derivatives.clone();
    let chunk = r.chunk.min(photons).max(1);
    let mut op = lightpath::diff::RenderOp::from_scene(
        scene.clone(),
        (photons, chunk, seed.unwrap_or(r.seed)),
    )
    .map_err(py_err)?;
    if held {
        op.hold()
            .map_err(|e| PyValueError::new_err(format!("params: {e}: use held = False")))?;
    }
    // the operation's θ holds the medium's parameters first, then the field's: slot k of it is
    // the caller's parameter order[k]
    let is_medium = |i: &usize| matches!(derivatives[*i], Derivative::Medium(_));
    let order: Vec<usize> = (0..params.len())
        .filter(is_medium)
        .chain((0..params.len()).filter(|i| !is_medium(i)))
        .collect();
    let theta = match theta {
        Some(v) if v.len() != params.len() => {
            return Err(PyValueError::new_err(format!(
                "theta: {} values for {} parameter(s) {params:?}",
                v.len(),
                params.len()
            )));
        }
        Some(v) => v,
        None => {
            let mut v = vec![0.0; params.len()];
            for (k, x) in op.values().into_iter().enumerate() {
                v[order[k]] = x;
            }
            v
        }
    };
    let at: Vec<f64> = order.iter().map(|&u| theta[u]).collect();
    let limits = budget(max_minutes, max_memory_gb);
    lightpath::app::budget::check(
        "render_vjp",
        &ParticleTracer::new(&scene),
        &lightpath::app::render::proxy_medium(&scene),
        photons as f64,
        photons.div_ceil(chunk),
        0,
        &limits,
    )
    .map_err(py_err)?;
    let e = run_watched(py, threads, None, move |w| {
        op.stop = w.stop_flag();
        op.evaluate(&at)
    })?;
    let p = params.len();
    let mut jacobian = vec![0.0; e.power.len() * p];
    let mut jacobian_stderr = vec![0.0; e.power.len() * p];
    for i in 0..e.power.len() {
        for (k, &u) in order.iter().enumerate() {
            jacobian[i * p + u] = e.jacobian[i][k];
            jacobian_stderr[i * p + u] = e.jacobian_stderr[i][k];
        }
    }
    if e.power.iter().any(|v| !v.is_finite()) {
        return Err(PyRuntimeError::new_err(
            "render_vjp: an output is not finite",
        ));
    }
    Ok(RenderVjp {
        params,
        sensors: t.scene.objectives(),
        theta,
        value: e.power,
        stderr: e.stderr,
        jacobian,
        jacobian_stderr,
        held,
    })
}

/// The phase function read from speckle images (`lightpath acquire-phase`), as
/// `phase_acquisition.json` holds it.
#[pyclass(frozen, module = "lightpath")]
pub(crate) struct PhaseAcquisition {
    file: PhaseAcquisitionFile,
}

#[pymethods]
impl PhaseAcquisition {
    /// One dict per illumination displacement, smallest first: `delta_deg`, `delta_px`,
    /// `first_px`, `grain_px`, `pairs`, `chi2_flat`, `dof`, `significant`, `hg` /
    /// `hg_intensity` (`g`, `g_stderr`, `chi2_dof`) and `vmf` (`weights`, `kappas`, `chi2_dof`)
    /// where fitted, and float64 `[R]` arrays of the readings: `angle_deg`, `correlation`,
    /// `stderr`, `intensity`, `normalised`, `normalised_stderr` (Eq. 4 over the window means),
    /// `rho`, `rho_stderr`, `rho_intensity` (NaN where there is none).
    #[getter]
    fn curves<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyAny>>> {
        use numpy::PyArray1;
        self.file
            .curves
            .iter()
            .map(|c| {
                let mut summary = c.clone();
                summary.readings.clear();
                let d = json_value(py, &summary)?;
                d.del_item("readings")?;
                let column = |f: &dyn Fn(&lightpath::io::results::AcquiredReading) -> f64| {
                    PyArray1::from_vec(py, c.readings.iter().map(f).collect())
                };
                d.set_item("angle_deg", column(&|r| r.reading.angle_deg))?;
                d.set_item("correlation", column(&|r| r.reading.correlation))?;
                d.set_item("stderr", column(&|r| r.reading.stderr))?;
                d.set_item("intensity", column(&|r| r.reading.intensity))?;
                d.set_item("normalised", column(&|r| r.reading.normalised))?;
                d.set_item(
                    "normalised_stderr",
                    column(&|r| r.reading.normalised_stderr),
                )?;
                d.set_item("rho", column(&|r| r.rho.unwrap_or(f64::NAN)))?;
                d.set_item("rho_stderr", column(&|r| r.rho_stderr.unwrap_or(f64::NAN)))?;
                d.set_item(
                    "rho_intensity",
                    column(&|r| r.rho_intensity.unwrap_or(f64::NAN)),
                )?;
                Ok(d)
            })
            .collect()
    }

    /// dict: whether the two largest displacements read the same correlation (`consistent`,
    /// `chi2`, `dof`, `curves`), or None with fewer than two.
    #[getter]
    fn consistency<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_value(py, &self.file.consistency)
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.file.seconds
    }

    /// `phase_acquisition.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `phase_acquisition.json` and `phase_acquisition.png` into `folder`; the paths
    /// written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(
            &folder,
            &["phase_acquisition.json", "phase_acquisition.png"],
        )
        .map_err(py_err)?;
        Ok(lightpath::app::acquire_phase::write(&self.file, &folder)
            .map_err(py_err)?
            .files)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.PhaseAcquisition {} displacement(s)>",
            self.file.curves.len()
        )
    }
}

/// Read the phase function from speckle image pairs (`lightpath acquire-phase`), from an
/// acquisition config (`[acquisition]` + `[[pair]]`).
#[pyfunction]
pub(crate) fn acquire_phase(py: Python<'_>, task: &Task) -> PyResult<PhaseAcquisition> {
    let config::Task::Acquire(c) = &task.task else {
        return Err(PyValueError::new_err(format!(
            "acquire_phase: needs an acquisition config ([acquisition] + [[pair]]), but the config holds {}",
            task.task.kind().describe()
        )));
    };
    let c = (**c).clone();
    let file = run_watched(py, None, None, move |_| {
        lightpath::app::acquire_phase::acquire(&c)
    })?;
    Ok(PhaseAcquisition { file })
}
