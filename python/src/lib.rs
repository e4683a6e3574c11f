//! `lightpath._lightpath`: the Python face of the lightpath library. Configs come from TOML files,
//! TOML text or dictionaries (validated by the one config loader, with its messages); the speckle
//! commands run in memory ([`lightpath::app::run::evaluate`]) and return their typed results,
//! whose arrays are numpy arrays. Runs release the GIL, stop on Ctrl-C between two waves of
//! chunks, and report progress to an optional callback, always on the caller's thread.
//!
//! The pure-Python package `lightpath` (in `python/lightpath/`) wraps this module: it turns
//! dictionaries into JSON and accepts a path, a dictionary or a loaded `Task` wherever a config
//! is expected.

use glam::DVec3;
use lightpath::Error;
use lightpath::app::budget::{Budget, check as check_budget};
use lightpath::app::run::{Kind, Results, evaluate};
use lightpath::app::wave::WaveLimits;
use lightpath::app::{Watch, create_out, with_threads};
use lightpath::config::{self, EstimatorConfig, SceneTask};
use lightpath::diff::{CovarianceEvaluation, CovarianceOp, ExitVjp, Param, Proposal, medium_at};
use lightpath::eikonal::FieldParam;
use lightpath::io::results::{
    CovarianceFile, MemoryEffectFile, MieFile, Nested2, Nested4, RunEcho, SpeckleFile,
};
use lightpath::mc::Plan;
use lightpath::speckle::memory::MemoryCurve;
use numpy::{Complex64, PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

mod inverse;
mod render;

/// How often a waiting call looks at Ctrl-C and the progress (well within a second).
const POLL: Duration = Duration::from_millis(50);

/// A lightpath error as the Python exception of its kind: config and input errors are
/// `ValueError` (the message names the key, the value and what is allowed), files `OSError`,
/// failed computations `RuntimeError`.
fn py_err(e: Error) -> PyErr {
    let message = python_names(&e.to_string());
    match e {
        Error::Config(_) | Error::Input(_) => PyValueError::new_err(message),
        Error::Io { .. } => PyOSError::new_err(message),
        Error::Numerical(_) => PyRuntimeError::new_err(message),
        Error::Interrupted => PyKeyboardInterrupt::new_err(message),
    }
}

/// A message of the command line as Python says it: its flags (`--max-minutes`) are the keyword
/// arguments (`max_minutes`).
fn python_names(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find("--") {
        let (before, flag) = rest.split_at(at);
        out.push_str(before);
        let name: String = flag[2..]
            .chars()
            .take_while(|c| c.is_ascii_lowercase() || *c == '-')
            .collect();
        let starts_a_word = before.is_empty() || before.ends_with([' ', '(', '`', '"', '\'']);
        if name.starts_with(|c: char| c.is_ascii_lowercase()) && starts_a_word {
            out.push_str(&name.replace('-', "_"));
            rest = &flag[2 + name.len()..];
        } else {
            out.push_str("--");
            rest = &flag[2..];
        }
    }
    out.push_str(rest);
    out
}

fn config_err(e: config::ConfigError) -> PyErr {
    py_err(Error::Config(e))
}

/// A validated config and what it describes (built once). Load one with `lightpath.load`.
#[pyclass(frozen, module = "lightpath")]
struct Task {
    task: config::Task,
    /// Where it came from, for messages and `repr`.
    origin: String,
}

#[pymethods]
impl Task {
    /// What the config holds: "scene", "trace", "design", "param_fit", "acquire" or "render".
    #[getter]
    fn kind(&self) -> &'static str {
        match self.task.kind() {
            config::TaskKind::Scene => "scene",
            config::TaskKind::Trace => "trace",
            config::TaskKind::Design => "design",
            config::TaskKind::ParamFit => "param_fit",
            config::TaskKind::Acquire => "acquire",
            config::TaskKind::Render => "render",
        }
    }

    /// What the config describes, in one line (as `lightpath check` prints it).
    fn describe(&self) -> PyResult<String> {
        lightpath::app::check::describe(&self.task).map_err(py_err)
    }

    /// The validated config as JSON text, every default filled in (what result files echo).
    fn config_json(&self) -> PyResult<String> {
        use config::Task as T;
        match &self.task {
            T::Scene(t) => serde_json::to_string(&t.config),
            T::Trace(t) => serde_json::to_string(&t.config),
            T::Design(t) => serde_json::to_string(&t.config),
            T::ParamFit(t) => serde_json::to_string(&t.config),
            T::Acquire(t) => serde_json::to_string(&**t),
            T::Render(t) => serde_json::to_string(&t.config),
        }
        .map_err(|e| PyRuntimeError::new_err(format!("the config cannot be written: {e}")))
    }

    fn __repr__(&self) -> String {
        format!("<lightpath.Task {} from {}>", self.kind(), self.origin)
    }
}

impl Task {
    /// The speckle scene, or a `ValueError` saying what the config holds instead.
    fn scene(&self, command: &str) -> PyResult<SceneTask> {
        self.task.clone().into_scene(command).map_err(config_err)
    }
}

/// Load a TOML config file; relative paths in it resolve against its folder.
#[pyfunction]
fn load_path(path: PathBuf) -> PyResult<Task> {
    let task = config::load(&path).map_err(config_err)?;
    Ok(Task {
        task,
        origin: path.display().to_string(),
    })
}

/// Load TOML text; relative paths in it resolve against the current folder.
#[pyfunction]
fn load_toml(text: &str) -> PyResult<Task> {
    let task = config::load_text(text).map_err(config_err)?;
    Ok(Task {
        task,
        origin: "TOML text".into(),
    })
}

/// Load a config given as a dict of the TOML's shape (nested dicts, lists, numbers, strings,
/// booleans; numpy arrays and scalars too); relative paths resolve against the folder `base`.
#[pyfunction]
fn load_dict(config: &Bound<'_, PyAny>, base: PathBuf) -> PyResult<Task> {
    let value = toml_value(config, &mut String::new())?;
    let task = config::load_value(value, &base).map_err(config_err)?;
    Ok(Task {
        task,
        origin: "a dict".into(),
    })
}

/// A Python value as TOML, or a `ValueError` naming its key (`at`, dotted as in messages).
fn toml_value(x: &Bound<'_, PyAny>, at: &mut String) -> PyResult<toml::Value> {
    use pyo3::types::{PyBool, PyDict, PyFloat, PyList, PyString, PyTuple};
    let key = |at: &str| {
        if at.is_empty() {
            "the config".to_string()
        } else {
            at.to_string()
        }
    };
    if x.is_none() {
        return Err(PyValueError::new_err(format!(
            "{} = None: give the key a value or leave it out",
            key(at)
        )));
    }
    if let Ok(b) = x.cast::<PyBool>() {
        return Ok(toml::Value::Boolean(b.is_true()));
    }
    if x.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(x.extract::<f64>()?));
    }
    if let Ok(i) = x.extract::<i64>() {
        return Ok(toml::Value::Integer(i));
    }
    if let Ok(f) = x.extract::<f64>() {
        return Ok(toml::Value::Float(f));
    }
    if let Ok(s) = x.cast::<PyString>() {
        return Ok(toml::Value::String(s.to_cow()?.into_owned()));
    }
    if let Ok(d) = x.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in d.iter() {
            let Ok(k) = k.extract::<String>() else {
                return Err(PyValueError::new_err(format!(
                    "{}: keys are strings, not {}",
                    key(at),
                    k.get_type().name()?
                )));
            };
            let len = at.len();
            if !at.is_empty() {
                at.push('.');
            }
            at.push_str(&k);
            let value = toml_value(&v, at)?;
            at.truncate(len);
            table.insert(k, value);
        }
        return Ok(toml::Value::Table(table));
    }
    let items: Option<Vec<Bound<'_, PyAny>>> = if let Ok(l) = x.cast::<PyList>() {
        Some(l.iter().collect())
    } else if let Ok(t) = x.cast::<PyTuple>() {
        Some(t.iter().collect())
    } else {
        None
    };
    if let Some(items) = items {
        let mut out = Vec::with_capacity(items.len());
        for (i, v) in items.iter().enumerate() {
            let len = at.len();
            at.push_str(&format!("[{i}]"));
            out.push(toml_value(v, at)?);
            at.truncate(len);
        }
        return Ok(toml::Value::Array(out));
    }
    // numpy arrays and anything else that lists itself
    if x.hasattr("tolist")? {
        return toml_value(&x.call_method0("tolist")?, at);
    }
    Err(PyValueError::new_err(format!(
        "{}: a {} is not a config value (dicts, lists, numbers, strings and booleans are)",
        key(at),
        x.get_type().name()?
    )))
}

/// Run `job` on a worker thread (on `threads` workers) while this thread, without the GIL, waits
/// for it; every [`POLL`] it takes the GIL back to look at Ctrl-C and report progress to
/// `progress(done, total)`. Ctrl-C (or an exception from the callback) stops the run at its next
/// wave of chunks and is raised once the run has stopped, so nothing is left running.
fn run_watched<T: Send + 'static>(
    py: Python<'_>,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    job: impl FnOnce(&Watch) -> lightpath::Result<T> + Send + 'static,
) -> PyResult<T> {
    let watch = Arc::new(Watch::default());
    let (tx, rx) = channel();
    let rx = Mutex::new(rx);
    let worker = Arc::clone(&watch);
    std::thread::Builder::new()
        .name("lightpath".into())
        .spawn(move || {
            let _ = tx.send(with_threads(threads, || job(&worker)));
        })
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start the run's thread: {e}")))?;
    let mut reported = None;
    let mut report = |py: Python<'_>| -> PyResult<()> {
        if let Some(callback) = &progress {
            let now = watch.progress();
            if reported != Some(now) {
                reported = Some(now);
                callback.call1(py, now)?;
            }
        }
        Ok(())
    };
    loop {
        match py.detach(|| recv(&rx, Some(POLL))) {
            Ok(result) => {
                let value = result.map_err(py_err)?;
                report(py)?;
                return Ok(value);
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err(
                    "the run stopped without a result (an internal error); please report it with its config",
                ));
            }
            Err(RecvTimeoutError::Timeout) => {}
        }
        if let Err(e) = py.check_signals().and_then(|()| report(py)) {
            watch.stop();
            // wait until the run has stopped: nothing keeps computing after the exception
            let _ = py.detach(|| recv(&rx, None));
            return Err(e);
        }
    }
}

/// The worker's result, waiting at most `timeout` (forever without).
fn recv<T>(rx: &Mutex<Receiver<T>>, timeout: Option<Duration>) -> Result<T, RecvTimeoutError> {
    let rx = rx.lock().map_err(|_| RecvTimeoutError::Disconnected)?;
    match timeout {
        Some(t) => rx.recv_timeout(t),
        None => rx.recv().map_err(|_| RecvTimeoutError::Disconnected),
    }
}

/// Flatten `[a][b][c][d]` nested arrays into one row-major vector with their shape.
fn flat4(x: &Nested4) -> (Vec<f64>, Vec<usize>) {
    let shape = vec![
        x.len(),
        x.first().map_or(0, |a| a.len()),
        x.first().and_then(|a| a.first()).map_or(0, |b| b.len()),
        x.first()
            .and_then(|a| a.first())
            .and_then(|b| b.first())
            .map_or(0, |c| c.len()),
    ];
    let v = x.iter().flatten().flatten().flatten().copied().collect();
    (v, shape)
}

/// A result file (or any serialisable value) as JSON text, as the command writes it.
fn json_text(x: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(x).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// A serialisable value as the Python value `json.loads` makes of it (dicts, lists, floats).
fn json_value<'py>(py: Python<'py>, x: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (json_text(x)?,))
}

fn flat2(x: &Nested2) -> (Vec<f64>, Vec<usize>) {
    let shape = vec![x.len(), x.first().map_or(0, |a| a.len())];
    (x.iter().flatten().copied().collect(), shape)
}

fn real<'py>(
    py: Python<'py>,
    (v, shape): (Vec<f64>, Vec<usize>),
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    PyArray1::from_vec(py, v).reshape(shape)
}

fn complex<'py>(
    py: Python<'py>,
    (re, shape): (Vec<f64>, Vec<usize>),
    (im, _): (Vec<f64>, Vec<usize>),
) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
    let v: Vec<Complex64> = re
        .iter()
        .zip(&im)
        .map(|(&a, &b)| Complex64::new(a, b))
        .collect();
    PyArray1::from_vec(py, v).reshape(shape)
}

/// Write `results` into `folder` as the command would (clearing that command's stale files);
/// the paths written.
fn save(results: &Results, kind: Kind, folder: &Path) -> PyResult<Vec<PathBuf>> {
    create_out(folder, kind.files()).map_err(py_err)?;
    Ok(results.write(folder).map_err(py_err)?.files)
}

/// How a result was computed: samples, seed, wall time, wavelength, the config (what every result
/// file echoes). A result's `run`.
#[pyclass(frozen, module = "lightpath")]
struct Run {
    run: RunEcho,
}

#[pymethods]
impl Run {
    /// Paths (Monte Carlo), realisations (wave solver) or 0 (closed form).
    #[getter]
    fn samples(&self) -> u64 {
        self.run.samples
    }

    /// The seed of the run's random streams.
    #[getter]
    fn seed(&self) -> u64 {
        self.run.seed
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> Option<f64> {
        self.run.seconds
    }

    /// The vacuum wavelength, in the scene's length unit.
    #[getter]
    fn wavelength(&self) -> f64 {
        self.run.wavelength
    }

    /// The lightpath version that computed it.
    #[getter]
    fn version(&self) -> String {
        self.run.version.clone()
    }

    /// The config the run used, as JSON text (every default filled in).
    fn config_json(&self) -> PyResult<String> {
        json_text(&self.run.config)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.Run {} samples, seed {}, {}>",
            self.run.samples,
            self.run.seed,
            self.run
                .seconds
                .map_or("merged".into(), |s| format!("{s:.3} s"))
        )
    }
}

/// A covariance `C[l1, l2, v1, v2] = E[u ū'] − m m̄'` of the fields of every light × view
/// (Monte Carlo, closed-form single scattering, or the wave solver), as `covariance.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct Covariance {
    file: CovarianceFile,
}

#[pymethods]
impl Covariance {
    /// How it was computed (samples, seed, seconds, wavelength, config).
    #[getter]
    fn run(&self) -> Run {
        Run {
            run: self.file.run.clone(),
        }
    }

    /// complex128 `[L, L, V, V]`: the covariance of every pair of light × view fields.
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        complex(py, flat4(&self.file.re), flat4(&self.file.im))
    }

    /// float64 `[L, L, V, V]`: the standard error of `covariance` (of its real and imaginary
    /// parts alike; zeros for a closed form).
    #[getter]
    fn stderr<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, flat4(&self.file.stderr))
    }

    /// float64 `[L, V]`: the speckle intensity `C[l, l, v, v]` (the diagonal).
    #[getter]
    fn intensity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let re = &self.file.re;
        let nested: Nested2 = (0..re.len())
            .map(|l| (0..re[l][l].len()).map(|v| re[l][l][v][v]).collect())
            .collect();
        real(py, flat2(&nested))
    }

    /// complex128 `[L, V]`: the mean field `m[l, v]`.
    #[getter]
    fn mean<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        complex(py, flat2(&self.file.mean_re), flat2(&self.file.mean_im))
    }

    /// float64 `[L, V]`: the mean field's standard error (wave solver), else None.
    #[getter]
    fn mean_stderr<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.file
            .mean_stderr
            .as_ref()
            .map(|m| real(py, flat2(m)))
            .transpose()
    }

    /// complex128 `[L, L, V, V]`: the part of paths that scatter once (Monte Carlo, closed
    /// form), else None.
    #[getter]
    fn single<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<Complex64>>>> {
        match (&self.file.single_re, &self.file.single_im) {
            (Some(re), Some(im)) => complex(py, flat4(re), flat4(im)).map(Some),
            _ => Ok(None),
        }
    }

    /// float64 `[L, L, V, V]`: the standard error of `single`, else None.
    #[getter]
    fn single_stderr<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.file
            .single_stderr
            .as_ref()
            .map(|m| real(py, flat4(m)))
            .transpose()
    }

    /// complex128 `[L, L, V, V]`: the part of paths that scatter twice or more (Monte Carlo),
    /// else None.
    #[getter]
    fn multiple<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, PyArrayDyn<Complex64>>>> {
        match (&self.file.multiple_re, &self.file.multiple_im) {
            (Some(re), Some(im)) => complex(py, flat4(re), flat4(im)).map(Some),
            _ => Ok(None),
        }
    }

    /// float64 `[L, L, V, V]`: the standard error of `multiple`, else None.
    #[getter]
    fn multiple_stderr<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.file
            .multiple_stderr
            .as_ref()
            .map(|m| real(py, flat4(m)))
            .transpose()
    }

    /// "foldy-lax" (wave solver), "single_scattering" (closed form) or None (Monte Carlo).
    #[getter]
    fn solver(&self) -> Option<String> {
        self.file.solver.clone()
    }

    /// Scatterer placements (wave solver), else None.
    #[getter]
    fn realizations(&self) -> Option<u64> {
        self.file.realizations
    }

    /// `covariance.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `covariance.json` into `folder` (created if needed); the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        let results = Results::Covariance(Box::new(self.file.clone()));
        save(&results, Kind::Covariance, &folder)
    }

    fn __repr__(&self) -> String {
        let nl = self.file.re.len();
        let nv = self.file.mean_re.first().map_or(0, |m| m.len());
        format!(
            "<lightpath.Covariance {nl} light(s) × {nv} view(s), {} {}>",
            self.file.run.samples,
            if self.file.solver.as_deref() == Some("foldy-lax") {
                "realisations"
            } else {
                "paths"
            }
        )
    }
}

/// The memory-effect curve: the correlation of speckle intensities as the light and view tilt
/// together, against the diffusion prediction of Eq. 39, as `memory_effect.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct MemoryEffect {
    file: MemoryEffectFile,
    curve: MemoryCurve,
}

#[pymethods]
impl MemoryEffect {
    /// How it was computed (samples, seed, seconds, wavelength, config).
    #[getter]
    fn run(&self) -> Run {
        Run {
            run: self.file.run.clone(),
        }
    }

    /// float64 `[A]`: the tilt angles, in degrees.
    #[getter]
    fn angles_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.angles_deg)
    }

    /// float64 `[A]`: the normalised intensity correlation at each angle.
    #[getter]
    fn correlation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.correlation)
    }

    /// float64 `[A]`: the standard error of `correlation`.
    #[getter]
    fn correlation_stderr<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.correlation_stderr)
    }

    /// float64 `[A]`: the normalised field correlation at each angle.
    #[getter]
    fn field_correlation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.field_correlation)
    }

    /// float64 `[A]`: the diffusion prediction `((kθL)/sinh(kθL))²` (Eq. 39).
    #[getter]
    fn diffusion_eq39<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.diffusion_eq39)
    }

    /// `L` of Eq. 39: the slab thickness, or the box chord along the first light.
    #[getter]
    fn thickness(&self) -> f64 {
        self.file.thickness
    }

    /// `memory_effect.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `memory_effect.json` and `memory_effect.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        let results =
            Results::MemoryEffect(Box::new(self.file.clone()), Box::new(self.curve.clone()));
        save(&results, Kind::MemoryEffect, &folder)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.MemoryEffect {} angle(s), {} paths>",
            self.file.angles_deg.len(),
            self.file.run.samples
        )
    }
}

/// Speckle fields: independent realisations of every light × view field, as `speckle.json`
/// holds (images of a view grid in `images`).
#[pyclass(frozen, module = "lightpath")]
struct Speckle {
    file: SpeckleFile,
}

impl Speckle {
    fn shape(&self) -> [usize; 3] {
        let f = &self.file;
        [f.re.len(), f.run.lights.len(), f.run.views.len()]
    }
}

#[pymethods]
impl Speckle {
    /// How it was computed (samples, seed, seconds, wavelength, config).
    #[getter]
    fn run(&self) -> Run {
        Run {
            run: self.file.run.clone(),
        }
    }

    /// complex128 `[R, L, V]`: the field of realisation `r`, light `l`, view `v`.
    #[getter]
    fn fields<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        let f = &self.file;
        let flat = |x: &Vec<Nested2>| -> (Vec<f64>, Vec<usize>) {
            (
                x.iter().flatten().flatten().copied().collect(),
                self.shape().to_vec(),
            )
        };
        complex(py, flat(&f.re), flat(&f.im))
    }

    /// complex128 `[R, L, H, W]`: the fields as images of the view grid (`H = 1`, `W = V` for
    /// views given one by one).
    #[getter]
    fn images<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        let [r, l, v] = self.shape();
        let (w, h) = lightpath::io::image_shape(&self.file.run.config, v);
        self.fields(py)?.reshape(vec![r, l, h, w])
    }

    /// Paths per image.
    #[getter]
    fn paths_per_image(&self) -> u64 {
        self.file.paths_per_image
    }

    /// `speckle.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `speckle.json` and one `speckle_NNNN.exr` per realisation into `folder`; the paths
    /// written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        save(
            &Results::Speckle(Box::new(self.file.clone())),
            Kind::Speckle,
            &folder,
        )
    }

    fn __repr__(&self) -> String {
        let [r, l, v] = self.shape();
        format!("<lightpath.Speckle {r} realisation(s) of {l} light(s) × {v} view(s)>")
    }
}

/// A covariance at `theta` with its vector–Jacobian product (`covariance_vjp`). Calling it with
/// a loss adjoint `∂L/∂Re C + i ∂L/∂Im C` (complex [L, L, V, V]) gives `∂L/∂θ`, from the same
/// paths as the value (paper 001's path-space gradient, contracted per event).
#[pyclass(frozen, module = "lightpath")]
struct CovarianceVjp {
    params: Vec<String>,
    theta: Vec<f64>,
    shape: [usize; 4],
    value: Vec<Complex64>,
    stderr: Vec<f64>,
    evaluation: Arc<CovarianceEvaluation>,
    threads: Option<usize>,
}

#[pymethods]
impl CovarianceVjp {
    /// complex128 `[L, L, V, V]`: the covariance at `theta`.
    #[getter]
    fn value<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        PyArray1::from_slice(py, &self.value).reshape(self.shape.to_vec())
    }

    /// float64 `[L, L, V, V]`: the standard error of `value`.
    #[getter]
    fn stderr<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        PyArray1::from_slice(py, &self.stderr).reshape(self.shape.to_vec())
    }

    /// The parameters' names, in the order of `theta` and of the gradient.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.params.clone()
    }

    /// float64 `[P]`: the parameter values the covariance was evaluated at.
    #[getter]
    fn theta<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.theta)
    }

    /// `∂L/∂θ` (float64 `[P]`) for the adjoint `∂L/∂Re C + i ∂L/∂Im C` (complex or real
    /// `[L, L, V, V]`); `progress(done, total)` counts chunks.
    #[pyo3(signature = (adjoint, *, progress=None))]
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        adjoint: &Bound<'py, PyAny>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        // any array-like of real or complex numbers, as complex128
        let kwargs = pyo3::types::PyDict::new(py);
        kwargs.set_item("dtype", "complex128")?;
        let array = py
            .import("numpy")?
            .call_method("asarray", (adjoint,), Some(&kwargs))?;
        let adjoint = array
            .cast::<PyArrayDyn<Complex64>>()
            .map_err(|_| PyValueError::new_err("adjoint: not an array of numbers"))?
            .readonly();
        if adjoint.shape() != self.shape {
            return Err(PyValueError::new_err(format!(
                "adjoint: shape {:?}, but the covariance is [L, L, V, V] = {:?}",
                adjoint.shape(),
                self.shape
            )));
        }
        let dy: Vec<f64> = adjoint
            .as_array()
            .iter()
            .flat_map(|z| [z.re, z.im])
            .collect();
        if dy.iter().any(|x| !x.is_finite()) {
            return Err(PyValueError::new_err(
                "adjoint: holds non-finite values (NaN or infinity)",
            ));
        }
        let evaluation = Arc::clone(&self.evaluation);
        let gradient = run_watched(py, self.threads, progress, move |w| {
            evaluation.pullback_until(&dy, Some(w))
        })?;
        if gradient.iter().any(|g| !g.is_finite()) {
            return Err(PyRuntimeError::new_err(
                "the gradient is not finite (no path reached a view with non-zero weight)",
            ));
        }
        Ok(PyArray1::from_vec(py, gradient))
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.CovarianceVjp {:?} at {:?}, covariance {:?}>",
            self.params, self.theta, self.shape
        )
    }
}

/// The covariance at `theta` (values of `params`, default: the config's) and its VJP. Paths are
/// drawn from the medium at `proposal` (default: the config's values) with a fixed seed and
/// re-weighted to `theta`: common random numbers, so the value is smooth in `theta` and the VJP is
/// its exact gradient. `proposal = theta` gives unbiased gradients of the expectation instead.
#[pyfunction]
#[pyo3(signature = (task, params, *, theta=None, proposal=None, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn covariance_vjp(
    py: Python<'_>,
    task: &Task,
    params: Vec<String>,
    theta: Option<Vec<f64>>,
    proposal: Option<Vec<f64>>,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<CovarianceVjp> {
    let scene_task = task.scene("covariance_vjp")?;
    let render = &scene_task.config.render;
    if render.estimator != EstimatorConfig::MonteCarlo {
        return Err(PyValueError::new_err(
            "render.estimator: covariance_vjp differentiates the Monte Carlo estimator; use \"monte_carlo\"",
        ));
    }
    let mut parsed: Vec<Param> = Vec::with_capacity(params.len());
    for name in &params {
        let p = Param::parse(name).map_err(|e| PyValueError::new_err(format!("params: {e}")))?;
        if parsed.contains(&p) {
            return Err(PyValueError::new_err(format!(
                "params: {name} is given twice"
            )));
        }
        parsed.push(p);
    }
    if parsed.is_empty() {
        return Err(PyValueError::new_err("params: give at least one parameter"));
    }
    let scene = scene_task.scene;
    let medium = &scene.medium;
    let start = parsed
        .iter()
        .map(|p| {
            p.get(medium).ok_or_else(|| {
                PyValueError::new_err(format!(
                    "params: {} does not exist in this medium (its phase function or particle types have no such parameter)",
                    p.name()
                ))
            })
        })
        .collect::<PyResult<Vec<f64>>>()?;
    let values = |key: &str, given: Option<Vec<f64>>| -> PyResult<Vec<f64>> {
        let v = given.unwrap_or_else(|| start.clone());
        if v.len() != parsed.len() {
            return Err(PyValueError::new_err(format!(
                "{key}: {} values for {} parameter(s) {params:?}",
                v.len(),
                parsed.len()
            )));
        }
        Ok(v)
    };
    let theta = values("theta", theta)?;
    let proposal = values("proposal", proposal)?;
    fn name(key: &'static str) -> impl Fn(Error) -> PyErr {
        move |e| PyValueError::new_err(format!("{key}: {e}"))
    }
    let (proposal_medium, _) = medium_at(medium, &parsed, &proposal).map_err(name("proposal"))?;
    let budget = budget(max_minutes, max_memory_gb);
    let paths_from = proposal_medium.clone();
    medium_at(medium, &parsed, &theta).map_err(name("theta"))?;
    let samples = samples.unwrap_or(render.samples);
    if samples == 0 {
        return Err(PyValueError::new_err("samples = 0: must be at least 1"));
    }
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let pairs: Vec<(usize, usize)> = (0..nl).flat_map(|l| (0..nv).map(move |v| (l, v))).collect();
    // entries in the order of `covariance.json`: [l1][l2][v1][v2]
    let mut entries = Vec::with_capacity(pairs.len() * pairs.len());
    for l1 in 0..nl {
        for l2 in 0..nl {
            for v1 in 0..nv {
                for v2 in 0..nv {
                    entries.push((l1 * nv + v1, l2 * nv + v2));
                }
            }
        }
    }
    let plan = (samples, render.chunk, seed.unwrap_or(render.seed));
    let reversed = render.reversed;
    let op = CovarianceOp::new(
        scene,
        parsed,
        pairs,
        entries,
        reversed,
        plan,
        Proposal::Fixed(proposal_medium),
    )
    .map_err(py_err)?;
    let at = theta.clone();
    let (entries, evaluation) = run_watched(py, threads, progress, move |w| {
        // the covariance's own time and memory estimate, before any path
        let afford = |est: &lightpath::diff::ReweightedCovariance<'_>, plan: &Plan| {
            let paths = plan.samples() as f64;
            check_budget(
                "covariance_vjp",
                est,
                &paths_from,
                paths,
                plan.chunks,
                0,
                &budget,
            )
        };
        op.forward_until(&at, w, &afford)
    })?;
    Ok(CovarianceVjp {
        params,
        theta,
        shape: [nl, nl, nv, nv],
        value: entries.value,
        stderr: entries.stderr,
        evaluation: Arc::new(evaluation),
        threads,
    })
}

/// A near-field correlation map `C(Δ, τ)` (paper 000, Eq. 48) of focused light and camera, as
/// `correlation_map.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct CorrelationMap {
    file: lightpath::io::results::CorrelationMapFile,
    peak: f64,
}

impl CorrelationMap {
    fn flat3(x: &[Vec<Vec<f64>>]) -> (Vec<f64>, Vec<usize>) {
        let shape = vec![
            x.len(),
            x.first().map_or(0, |a| a.len()),
            x.first().and_then(|a| a.first()).map_or(0, |b| b.len()),
        ];
        (x.iter().flatten().flatten().copied().collect(), shape)
    }
}

#[pymethods]
impl CorrelationMap {
    /// How it was computed (samples, seed, seconds, wavelength, config).
    #[getter]
    fn run(&self) -> Run {
        Run {
            run: self.file.run.clone(),
        }
    }

    /// float64 `[K, 3]`: the shifts `Δ` (the first is 0).
    #[getter]
    fn deltas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let v = self.file.deltas.iter().flatten().copied().collect();
        real(py, (v, vec![self.file.deltas.len(), 3]))
    }

    /// float64 `[H, W, 3]`: `τ` of each pixel.
    #[getter]
    fn taus<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let t = &self.file.taus;
        let (h, w) = (t.len(), t.first().map_or(0, |r| r.len()));
        real(
            py,
            (
                t.iter().flatten().flatten().copied().collect(),
                vec![h, w, 3],
            ),
        )
    }

    /// complex128 `[K, H, W]`: `C(Δ, τ)`.
    #[getter]
    fn correlation<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        complex(py, Self::flat3(&self.file.re), Self::flat3(&self.file.im))
    }

    /// float64 `[K, H, W]`: the standard error of `correlation`.
    #[getter]
    fn stderr<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, Self::flat3(&self.file.stderr))
    }

    /// float64 `[K, H, W]`: `|C(Δ, τ)| / √(I(0, τ) I(Δ, τ))`.
    #[getter]
    fn normalised<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, Self::flat3(&self.file.normalised))
    }

    /// `correlation_map.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `correlation_map.json` and `correlation_map.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        let results = Results::CorrelationMap(Box::new(self.file.clone()), self.peak);
        save(&results, Kind::CorrelationMap, &folder)
    }

    fn __repr__(&self) -> String {
        let (h, w) = (
            self.file.taus.len(),
            self.file.taus.first().map_or(0, |r| r.len()),
        );
        format!(
            "<lightpath.CorrelationMap {} shift(s) over {w} × {h} τ, {} paths>",
            self.file.deltas.len(),
            self.file.run.samples
        )
    }
}

/// The near-field `C(Δ, τ)` maps of a scene with a `[correlation_map]` table
/// (`lightpath correlation-map`).
#[pyfunction]
#[pyo3(signature = (task, *, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn correlation_map(
    py: Python<'_>,
    task: &Task,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<CorrelationMap> {
    let budget = budget(max_minutes, max_memory_gb);
    let overrides = (samples, seed);
    match run_scene(
        py,
        task,
        "correlation_map",
        Kind::CorrelationMap,
        overrides,
        threads,
        budget,
        progress,
    )? {
        Results::CorrelationMap(file, peak) => Ok(CorrelationMap { file: *file, peak }),
        _ => Err(other_result("correlation_map")),
    }
}

/// A covariance as a flat matrix, from a `Covariance` or the path of a `covariance.json`.
fn covariance_matrix(
    x: &Bound<'_, PyAny>,
    key: &str,
) -> PyResult<lightpath::io::results::CovarianceMatrix> {
    use lightpath::io::ResultFile;
    if let Ok(c) = x.cast::<Covariance>() {
        return c.get().file.matrix(Path::new(key)).map_err(py_err);
    }
    let Ok(path) = x.extract::<PathBuf>() else {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "{key}: a lightpath.Covariance or the path of a covariance.json, not {}",
            x.get_type().name()?
        )));
    };
    CovarianceFile::read(&path)
        .and_then(|f| f.matrix(&path))
        .map_err(py_err)
}

/// The agreement of two covariances (`lightpath compare`): per light pair `‖A − B‖/‖B‖`, the share
/// of entries within 3 combined standard errors and the worst entries.
#[pyfunction]
#[pyo3(signature = (a, b, *, tolerance=0.1))]
fn compare<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
    tolerance: f64,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    if !(tolerance.is_finite() && tolerance > 0.0) {
        return Err(PyValueError::new_err(format!(
            "tolerance = {tolerance}: must be a positive number"
        )));
    }
    let (ma, mb) = (covariance_matrix(a, "a")?, covariance_matrix(b, "b")?);
    let pairs = lightpath::app::compare::agreement(&ma, &mb).map_err(py_err)?;
    let (report, agree) = lightpath::app::compare::report(&pairs, tolerance);
    let out = pyo3::types::PyDict::new(py);
    out.set_item("agree", agree)?;
    out.set_item("report", report)?;
    let list = pyo3::types::PyList::empty(py);
    for p in &pairs {
        let d = pyo3::types::PyDict::new(py);
        d.set_item("lights", p.lights)?;
        d.set_item("error", p.error)?;
        d.set_item("within_3se", p.within_3se)?;
        d.set_item("worst", p.worst.clone())?;
        list.append(d)?;
    }
    out.set_item("pairs", list)?;
    Ok(out)
}

/// The tilt-shift memory effect (paper 000, Eq. 49, against the model of Eq. 50): the
/// correlation of every scanned cell, and the refocusing curves or the `(Δb, θ)` grid, as
/// `tilt_shift.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct TiltShift {
    file: lightpath::io::results::TiltShiftFile,
}

#[pymethods]
impl TiltShift {
    /// How it was computed (samples, seed, seconds, wavelength, config).
    #[getter]
    fn run(&self) -> Run {
        Run {
            run: self.file.run.clone(),
        }
    }

    /// Depth `L` between the input and output planes, in the length unit.
    #[getter]
    fn depth(&self) -> f64 {
        self.file.depth
    }

    /// The transport mean free path `ℓ_tr = 1/(σ_s(1 − g) + σ_a)`.
    #[getter]
    fn transport_mfp(&self) -> f64 {
        self.file.transport_mfp
    }

    /// The scanned cells as a dict of float64 `[C]` arrays: `shift` (output shift `Δb`),
    /// `angle_deg` (relative tilt `θ`), `input_shift` (`Δa = Δb − Lθ`), `stderr`, `normalised`
    /// (`|C| / √(I₁ I₂)`), `normalised_stderr`, `model` (Eq. 50), and `correlation` (complex128).
    #[getter]
    fn cells<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        use lightpath::io::results::TiltShiftCell as Cell;
        let c = &self.file.cells;
        let out = pyo3::types::PyDict::new(py);
        let column = |f: fn(&Cell) -> f64| PyArray1::from_vec(py, c.iter().map(f).collect());
        out.set_item("shift", column(|x| x.shift))?;
        out.set_item("angle_deg", column(|x| x.angle_deg))?;
        out.set_item("input_shift", column(|x| x.input_shift))?;
        out.set_item("stderr", column(|x| x.stderr))?;
        out.set_item("normalised", column(|x| x.normalised))?;
        out.set_item("normalised_stderr", column(|x| x.normalised_stderr))?;
        out.set_item("model", column(|x| x.model))?;
        let z: Vec<Complex64> = c.iter().map(|x| Complex64::new(x.re, x.im)).collect();
        out.set_item("correlation", PyArray1::from_vec(py, z))?;
        Ok(out)
    }

    /// A `(Δb, θ)` scan as a dict: `shifts` `[S]`, `angles_deg` `[A]`, `normalised` and `model`
    /// `[S, A]`; else None.
    #[getter]
    fn grid<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, pyo3::types::PyDict>>> {
        let Some(g) = &self.file.grid else {
            return Ok(None);
        };
        let out = pyo3::types::PyDict::new(py);
        out.set_item("shifts", PyArray1::from_slice(py, &g.shifts))?;
        out.set_item("angles_deg", PyArray1::from_slice(py, &g.angles_deg))?;
        out.set_item("normalised", real(py, flat2(&g.normalised))?)?;
        out.set_item("model", real(py, flat2(&g.model))?)?;
        Ok(Some(out))
    }

    /// Refocusing curves as a dict of float64 `[D]` arrays: `displacements`, `power_shift`,
    /// `power_shift_stderr`, `power_tilt`, `power_tilt_stderr`, `tilts_deg`, `model_shift`,
    /// `model_tilt`; else None.
    #[getter]
    fn refocus<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, pyo3::types::PyDict>>> {
        let Some(r) = &self.file.refocus else {
            return Ok(None);
        };
        let out = pyo3::types::PyDict::new(py);
        for (key, v) in [
            ("displacements", &r.displacements),
            ("power_shift", &r.power_shift),
            ("power_shift_stderr", &r.power_shift_stderr),
            ("power_tilt", &r.power_tilt),
            ("power_tilt_stderr", &r.power_tilt_stderr),
            ("tilts_deg", &r.tilts_deg),
            ("model_shift", &r.model_shift),
            ("model_tilt", &r.model_tilt),
        ] {
            out.set_item(key, PyArray1::from_slice(py, v))?;
        }
        Ok(Some(out))
    }

    /// `tilt_shift.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `tilt_shift.json` and `tilt_shift.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        save(
            &Results::TiltShift(Box::new(self.file.clone())),
            Kind::TiltShift,
            &folder,
        )
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.TiltShift {} cell(s), L = {}, {} paths>",
            self.file.cells.len(),
            self.file.depth,
            self.file.run.samples
        )
    }
}

/// The tilt-shift memory effect of a scene with a `[tilt_shift]` table (`lightpath tilt-shift`).
#[pyfunction]
#[pyo3(signature = (task, *, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn tilt_shift(
    py: Python<'_>,
    task: &Task,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<TiltShift> {
    let budget = budget(max_minutes, max_memory_gb);
    let overrides = (samples, seed);
    let kind = Kind::TiltShift;
    match run_scene(
        py,
        task,
        "tilt_shift",
        kind,
        overrides,
        threads,
        budget,
        progress,
    )? {
        Results::TiltShift(file) => Ok(TiltShift { file: *file }),
        _ => Err(other_result("tilt_shift")),
    }
}

/// Run `kind` on the speckle scene of `task` in memory ([`evaluate`] under [`run_watched`]);
/// `command` names the Python function in messages.
#[allow(clippy::too_many_arguments)]
fn run_scene(
    py: Python<'_>,
    task: &Task,
    command: &'static str,
    kind: Kind,
    (samples, seed): (Option<u64>, Option<u64>),
    threads: Option<usize>,
    budget: Budget,
    progress: Option<Py<PyAny>>,
) -> PyResult<Results> {
    let scene = task.scene(command)?;
    run_watched(py, threads, progress, move |w| {
        evaluate(kind, scene, samples, seed, &budget, w)
    })
}

/// The error for a run that returned another kind of result (not expected to happen).
fn other_result(command: &str) -> PyErr {
    PyRuntimeError::new_err(format!("{command}: the run gave another kind of result"))
}

fn budget(max_minutes: f64, max_memory_gb: f64) -> Budget {
    Budget {
        max_minutes,
        max_memory_gb,
    }
}

/// The covariance of every light × view field of a speckle scene (`lightpath covariance`).
#[pyfunction]
#[pyo3(signature = (task, *, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn covariance(
    py: Python<'_>,
    task: &Task,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<Covariance> {
    let budget = budget(max_minutes, max_memory_gb);
    let overrides = (samples, seed);
    match run_scene(
        py,
        task,
        "covariance",
        Kind::Covariance,
        overrides,
        threads,
        budget,
        progress,
    )? {
        Results::Covariance(file) => Ok(Covariance { file: *file }),
        _ => Err(other_result("covariance")),
    }
}

/// The memory-effect curve of a speckle scene with a `[memory_effect]` table
/// (`lightpath memory-effect`).
#[pyfunction]
#[pyo3(signature = (task, *, samples=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn memory_effect(
    py: Python<'_>,
    task: &Task,
    samples: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<MemoryEffect> {
    let budget = budget(max_minutes, max_memory_gb);
    let overrides = (samples, seed);
    match run_scene(
        py,
        task,
        "memory_effect",
        Kind::MemoryEffect,
        overrides,
        threads,
        budget,
        progress,
    )? {
        Results::MemoryEffect(file, curve) => Ok(MemoryEffect {
            file: *file,
            curve: *curve,
        }),
        _ => Err(other_result("memory_effect")),
    }
}

/// Speckle field realisations of a speckle scene (`lightpath speckle`).
#[pyfunction]
#[pyo3(signature = (task, *, paths=None, seed=None, threads=None, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn speckle(
    py: Python<'_>,
    task: &Task,
    paths: Option<u64>,
    seed: Option<u64>,
    threads: Option<usize>,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<Speckle> {
    let budget = budget(max_minutes, max_memory_gb);
    let overrides = (paths, seed);
    match run_scene(
        py,
        task,
        "speckle",
        Kind::Speckle,
        overrides,
        threads,
        budget,
        progress,
    )? {
        Results::Speckle(file) => Ok(Speckle { file: *file }),
        _ => Err(other_result("speckle")),
    }
}

/// The covariance by the Foldy–Lax wave solver over scatterer placements (`lightpath wave`).
#[pyfunction]
#[pyo3(signature = (task, *, realizations=200, seed=None, threads=None, max_scatterers=6000.0, max_minutes=240.0, max_memory_gb=8.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn wave(
    py: Python<'_>,
    task: &Task,
    realizations: u64,
    seed: Option<u64>,
    threads: Option<usize>,
    max_scatterers: f64,
    max_minutes: f64,
    max_memory_gb: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<Covariance> {
    let scene = task.scene("wave")?;
    let limits = WaveLimits {
        max_scatterers,
        max_memory_gb,
        max_minutes,
    };
    let file = run_watched(py, threads, progress, move |w| {
        lightpath::app::wave::evaluate(scene, realizations, seed, &limits, w)
    })?;
    Ok(Covariance { file })
}

/// Spheres by Lorenz–Mie theory (`lightpath mie`): efficiencies, cross-sections (in the squared
/// length unit of the diameter), `g`, the phase function and the amplitudes, as `mie.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct Mie {
    file: MieFile,
}

#[pymethods]
impl Mie {
    /// The size parameter `x = π d n_medium / λ`.
    #[getter]
    fn size_parameter(&self) -> f64 {
        self.file.size_parameter
    }

    /// Series terms summed (Wiscombe's length).
    #[getter]
    fn terms(&self) -> usize {
        self.file.terms
    }

    /// Extinction efficiency.
    #[getter]
    fn q_ext(&self) -> f64 {
        self.file.q_ext
    }

    /// Scattering efficiency.
    #[getter]
    fn q_sca(&self) -> f64 {
        self.file.q_sca
    }

    /// Absorption efficiency.
    #[getter]
    fn q_abs(&self) -> f64 {
        self.file.q_abs
    }

    /// Backscattering efficiency.
    #[getter]
    fn q_back(&self) -> f64 {
        self.file.q_back
    }

    /// Asymmetry parameter (mean cosine).
    #[getter]
    fn g(&self) -> f64 {
        self.file.g
    }

    /// Extinction cross-section, in the diameter's length unit squared.
    #[getter]
    fn c_ext(&self) -> f64 {
        self.file.c_ext
    }

    /// Scattering cross-section.
    #[getter]
    fn c_sca(&self) -> f64 {
        self.file.c_sca
    }

    /// Absorption cross-section.
    #[getter]
    fn c_abs(&self) -> f64 {
        self.file.c_abs
    }

    /// Backscattering cross-section.
    #[getter]
    fn c_back(&self) -> f64 {
        self.file.c_back
    }

    /// Mean particle volume (over the size distribution).
    #[getter]
    fn mean_volume(&self) -> f64 {
        self.file.mean_volume
    }

    /// float64 `[N]`: scattering angles from 0° to 180°.
    #[getter]
    fn theta_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.theta_deg)
    }

    /// float64 `[N]`: the unpolarised phase function, `∫ρ dω = 1` (per steradian).
    #[getter]
    fn phase<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.phase)
    }

    /// float64 `[N]`: each polarisation's share, `|S1|²` (perpendicular) over the unpolarised
    /// `C_sca`.
    #[getter]
    fn phase_perpendicular<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.phase_perpendicular)
    }

    /// float64 `[N]`: `|S2|²` (parallel) over the unpolarised `C_sca`.
    #[getter]
    fn phase_parallel<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.file.phase_parallel)
    }

    /// complex128 `[N]`: the amplitude `S1` (Bohren & Huffman), dimensionless.
    #[getter]
    fn s1<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        let n = self.file.s1_re.len();
        complex(
            py,
            (self.file.s1_re.clone(), vec![n]),
            (self.file.s1_im.clone(), vec![n]),
        )
    }

    /// complex128 `[N]`: the amplitude `S2`.
    #[getter]
    fn s2<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<Complex64>>> {
        let n = self.file.s2_re.len();
        complex(
            py,
            (self.file.s2_re.clone(), vec![n]),
            (self.file.s2_im.clone(), vec![n]),
        )
    }

    /// With a `volume_fraction`: the bulk medium as a dict (`number_density`, `sigma_s`,
    /// `sigma_a`, `mfp`, `albedo`, in the diameter's length unit), else None.
    #[getter]
    fn bulk(&self) -> Option<std::collections::BTreeMap<&'static str, f64>> {
        self.file.bulk.as_ref().map(|b| {
            [
                ("volume_fraction", b.volume_fraction),
                ("number_density", b.number_density),
                ("sigma_s", b.sigma_s),
                ("sigma_a", b.sigma_a),
                ("mfp", b.mfp),
                ("albedo", b.albedo),
            ]
            .into_iter()
            .collect()
        })
    }

    /// `mie.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.file)
    }

    /// Write `mie.json` and the polar plot `mie.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, &["mie.json", "mie.png"]).map_err(py_err)?;
        Ok(lightpath::app::mie::write(&self.file, &folder)
            .map_err(py_err)?
            .files)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.Mie x = {:.4}, Q_sca = {:.6}, g = {:.6}>",
            self.file.size_parameter, self.file.q_sca, self.file.g
        )
    }
}

/// Spheres by Lorenz–Mie theory (`lightpath mie`).
#[pyfunction]
#[pyo3(signature = (diameter, n_particle, wavelength, *, n_medium=1.0, k_particle=0.0, diameter_spread=0.0, angles=361, volume_fraction=None))]
#[allow(clippy::too_many_arguments)]
fn mie(
    diameter: f64,
    n_particle: f64,
    wavelength: f64,
    n_medium: f64,
    k_particle: f64,
    diameter_spread: f64,
    angles: usize,
    volume_fraction: Option<f64>,
) -> PyResult<Mie> {
    let request = lightpath::app::mie::MieRequest {
        diameter,
        diameter_spread,
        n_particle,
        k_particle,
        n_medium,
        vacuum_wavelength: wavelength,
        angles,
        volume_fraction,
    };
    let file = lightpath::app::mie::compute(&request).map_err(py_err)?;
    Ok(Mie { file })
}

/// Rays traced through an index field (`lightpath trace`), as `rays.json` holds.
#[pyclass(frozen, module = "lightpath")]
struct Rays {
    traced: lightpath::app::grin::Traced,
}

impl Rays {
    fn column(
        &self,
        f: impl Fn(&lightpath::io::results::RayRecord) -> [f64; 3],
    ) -> (Vec<f64>, Vec<usize>) {
        let rays = &self.traced.file.rays;
        (rays.iter().flat_map(&f).collect(), vec![rays.len(), 3])
    }
}

#[pymethods]
impl Rays {
    /// float64 `[N, 3]`: where each ray starts.
    #[getter]
    fn origin<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, self.column(|r| r.origin))
    }

    /// float64 `[N, 3]`: each ray's initial unit direction.
    #[getter]
    fn direction<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, self.column(|r| r.direction))
    }

    /// float64 `[N, 3]`: where each ray left the field (or stopped).
    #[getter]
    fn exit_position<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, self.column(|r| r.exit_position))
    }

    /// float64 `[N, 3]`: each ray's unit direction there.
    #[getter]
    fn exit_direction<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        real(py, self.column(|r| r.exit_direction))
    }

    /// float64 `[N]`: the optical path `∫ n ds` of each ray, in the length unit.
    #[getter]
    fn optical_path<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self
            .traced
            .file
            .rays
            .iter()
            .map(|r| r.optical_path)
            .collect();
        PyArray1::from_vec(py, v)
    }

    /// uint64 `[N]`: integrator steps per ray.
    #[getter]
    fn steps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        let v: Vec<u64> = self
            .traced
            .file
            .rays
            .iter()
            .map(|r| r.steps as u64)
            .collect();
        PyArray1::from_vec(py, v)
    }

    /// bool `[N]`: whether each ray entered the field's bounds.
    #[getter]
    fn entered<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        let v: Vec<bool> = self.traced.file.rays.iter().map(|r| r.entered).collect();
        PyArray1::from_vec(py, v)
    }

    /// bool `[N]`: whether each ray left them again.
    #[getter]
    fn exited<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        let v: Vec<bool> = self.traced.file.rays.iter().map(|r| r.exited).collect();
        PyArray1::from_vec(py, v)
    }

    /// A list of float64 `[K, 3]` arrays: each ray's path (every 16th step, its exit point, then a
    /// stretch along its exit direction), as `rays.png` draws it.
    #[getter]
    fn paths<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArrayDyn<f64>>>> {
        self.traced
            .paths
            .iter()
            .map(|p| {
                let v: Vec<f64> = p.iter().flat_map(|x| x.to_array()).collect();
                real(py, (v, vec![p.len(), 3]))
            })
            .collect()
    }

    /// How far the exit points would move at half the step (4/3 of the difference for a few
    /// rays), in the length unit.
    #[getter]
    fn step_error(&self) -> Option<f64> {
        self.traced.file.step_error
    }

    /// Wall time, in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.traced.file.seconds
    }

    /// A warning when the step's error exceeds 0.1 % of the field's size, else None.
    #[getter]
    fn warning(&self) -> Option<String> {
        self.traced.warning.as_ref().map(|w| w.trim().to_string())
    }

    /// `rays.json` as text, exactly as the command writes it.
    fn to_json(&self) -> PyResult<String> {
        json_text(&self.traced.file)
    }

    /// Write `rays.json` and `rays.png` into `folder`; the paths written.
    fn save(&self, folder: PathBuf) -> PyResult<Vec<PathBuf>> {
        create_out(&folder, &["rays.json", "rays.png"]).map_err(py_err)?;
        Ok(lightpath::app::grin::write_trace(&self.traced, &folder)
            .map_err(py_err)?
            .files)
    }

    fn __repr__(&self) -> String {
        let f = &self.traced.file;
        let through = f.rays.iter().filter(|r| r.entered && r.exited).count();
        format!(
            "<lightpath.Rays {} ray(s), {through} through the field>",
            f.rays.len()
        )
    }
}

/// Rays through an index field (`lightpath trace`), from a trace config (`[field]` + `[rays]`).
#[pyfunction]
#[pyo3(signature = (task, *, threads=None, max_minutes=240.0, progress=None))]
fn trace(
    py: Python<'_>,
    task: &Task,
    threads: Option<usize>,
    max_minutes: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<Rays> {
    let config::Task::Trace(t) = &task.task else {
        return Err(PyValueError::new_err(format!(
            "trace: needs a trace config ([field] + [rays]), but the config holds {}",
            task.task.kind().describe()
        )));
    };
    let t = (**t).clone();
    let budget = budget(max_minutes, Budget::default().max_memory_gb);
    let traced = run_watched(py, threads, progress, move |w| {
        lightpath::app::grin::trace_rays(&t, &budget, w)
    })?;
    Ok(Rays { traced })
}

/// Ray exits with their vector–Jacobian product (`trace_vjp`). Calling it with `∂L/∂(exit
/// position)` and `∂L/∂(exit direction)` (float64 [N, 3] each) gives a dict of `∂L/∂·`: `params`
/// [P], `grid` (the grid profile's coefficients, [dz, dy, dx]) or None, `origin` and `direction`
/// [N, 3].
#[pyclass(frozen, module = "lightpath")]
struct TraceVjp {
    vjp: Arc<ExitVjp>,
    params: Vec<String>,
    theta: Vec<f64>,
    /// The grid's `[dz, dy, dx]` (numpy order: x fastest), when its gradient is asked for.
    grid_shape: Option<Vec<usize>>,
    threads: Option<usize>,
}

/// `[N, 3]` vectors from an array-like, or a `ValueError` naming `key`.
fn vectors(py: Python<'_>, x: &Bound<'_, PyAny>, n: usize, key: &str) -> PyResult<Vec<DVec3>> {
    let kwargs = pyo3::types::PyDict::new(py);
    kwargs.set_item("dtype", "float64")?;
    let array = py
        .import("numpy")?
        .call_method("asarray", (x,), Some(&kwargs))?;
    let array = array
        .cast::<PyArrayDyn<f64>>()
        .map_err(|_| PyValueError::new_err(format!("{key}: not an array of numbers")))?
        .readonly();
    if array.shape() != [n, 3] {
        return Err(PyValueError::new_err(format!(
            "{key}: shape {:?}, but there are [N, 3] = [{n}, 3] rays",
            array.shape()
        )));
    }
    let v: Vec<f64> = array.as_array().iter().copied().collect();
    if v.iter().any(|x| !x.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{key}: holds non-finite values (NaN or infinity)"
        )));
    }
    Ok(v.chunks(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect())
}

#[pymethods]
impl TraceVjp {
    /// float64 `[N, 3]`: where each ray left the field.
    #[getter]
    fn exit_position<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let v = self.vjp.ends.iter().flat_map(|e| e.x.to_array()).collect();
        real(py, (v, vec![self.vjp.ends.len(), 3]))
    }

    /// float64 `[N, 3]`: each ray's unit direction there.
    #[getter]
    fn exit_direction<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let v = self
            .vjp
            .ends
            .iter()
            .flat_map(|e| e.direction.to_array())
            .collect();
        real(py, (v, vec![self.vjp.ends.len(), 3]))
    }

    /// float64 `[N]`: each ray's optical path `∫ n ds`.
    #[getter]
    fn optical_path<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = self.vjp.ends.iter().map(|e| e.optical_path).collect();
        PyArray1::from_vec(py, v)
    }

    /// The analytic parameters' names, in the order of `theta` and of the gradient.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.params.clone()
    }

    /// float64 `[dz, dy, dx]`: the coefficients of the field's grid profile the rays were traced
    /// through (B-spline coefficients for tricubic grids, the samples for trilinear ones), or
    /// None without a grid.
    #[getter]
    fn coefficients<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        let grid = self.vjp.field().profiles.iter().find_map(|p| match p {
            lightpath::eikonal::Profile::Grid(g) => Some(g),
            _ => None,
        });
        grid.map(|g| real(py, (g.coef.clone(), vec![g.dims[2], g.dims[1], g.dims[0]])))
            .transpose()
    }

    /// float64 `[P]`: the values the rays were traced at.
    #[getter]
    fn theta<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.theta)
    }

    /// `∂L/∂·` for `∂L/∂(exit position)` and `∂L/∂(exit direction)`, float64 `[N, 3]` each;
    /// `progress(done, total)` counts rays.
    #[pyo3(signature = (d_position, d_direction, *, progress=None))]
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        d_position: &Bound<'py, PyAny>,
        d_direction: &Bound<'py, PyAny>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let n = self.vjp.ends.len();
        let dx = vectors(py, d_position, n, "d_position")?;
        let dd = vectors(py, d_direction, n, "d_direction")?;
        let vjp = Arc::clone(&self.vjp);
        let g = run_watched(py, self.threads, progress, move |w| {
            vjp.pullback(&dx, &dd, w)
        })?;
        let all_finite = g
            .params
            .iter()
            .chain(g.grid.iter().flatten())
            .all(|x| x.is_finite());
        if !all_finite {
            return Err(PyRuntimeError::new_err(
                "the gradient is not finite (a ray grazes a surface or the field diverges on its path)",
            ));
        }
        let out = pyo3::types::PyDict::new(py);
        out.set_item("params", PyArray1::from_vec(py, g.params))?;
        match (g.grid, &self.grid_shape) {
            (Some(grid), Some(shape)) => {
                out.set_item("grid", PyArray1::from_vec(py, grid).reshape(shape.clone())?)?
            }
            _ => out.set_item("grid", py.None())?,
        }
        let rows = |v: Vec<DVec3>| -> (Vec<f64>, Vec<usize>) {
            let len = v.len();
            (v.iter().flat_map(|x| x.to_array()).collect(), vec![len, 3])
        };
        out.set_item("origin", real(py, rows(g.origin))?)?;
        out.set_item("direction", real(py, rows(g.direction))?)?;
        Ok(out)
    }

    fn __repr__(&self) -> String {
        format!(
            "<lightpath.TraceVjp {} ray(s), params {:?}{}>",
            self.vjp.ends.len(),
            self.params,
            if self.grid_shape.is_some() {
                " and the grid"
            } else {
                ""
            }
        )
    }
}

/// Trace a trace config's rays to their exits, with the VJP of the exits with respect to
/// analytic field parameters (`profiles[i].name`), the coefficients of the field's grid profile
/// (`grid=True`), and the rays' origins and directions.
#[pyfunction]
#[pyo3(signature = (task, params=Vec::new(), *, theta=None, grid=false, coefficients=None, threads=None, max_minutes=240.0, progress=None))]
#[allow(clippy::too_many_arguments)]
fn trace_vjp(
    py: Python<'_>,
    task: &Task,
    params: Vec<String>,
    theta: Option<Vec<f64>>,
    grid: bool,
    coefficients: Option<Vec<f64>>,
    threads: Option<usize>,
    max_minutes: f64,
    progress: Option<Py<PyAny>>,
) -> PyResult<TraceVjp> {
    let config::Task::Trace(t) = &task.task else {
        return Err(PyValueError::new_err(format!(
            "trace_vjp: needs a trace config ([field] + [rays]), but the config holds {}",
            task.task.kind().describe()
        )));
    };
    let field = t.field.clone();
    if matches!(field.bounds, lightpath::eikonal::Bounds::Everywhere) {
        return Err(PyValueError::new_err(
            "field.bounds: trace_vjp differentiates where rays leave the field; give bounds (sphere, cylinder, box or sdf)",
        ));
    }
    let mut parsed: Vec<FieldParam> = Vec::new();
    for name in &params {
        let found = name
            .strip_prefix("profiles[")
            .and_then(|r| r.split_once("]."))
            .and_then(|(i, p)| Some((i.parse::<usize>().ok()?, p)))
            .and_then(|(i, p)| {
                let which = field.profiles.get(i)?.param_index(p)?;
                Some(FieldParam { profile: i, which })
            });
        let Some(p) = found else {
            let kinds: Vec<String> = field
                .profiles
                .iter()
                .enumerate()
                .map(|(i, p)| format!("profiles[{i}] is {}", p.kind()))
                .collect();
            return Err(PyValueError::new_err(format!(
                "params: {name:?} is not a parameter of this field; name them \"profiles[i].name\" ({}; e.g. n_max, k_r, radius, n0, alpha)",
                kinds.join(", ")
            )));
        };
        if parsed.contains(&p) {
            return Err(PyValueError::new_err(format!(
                "params: {name} is given twice"
            )));
        }
        parsed.push(p);
    }
    // the parameter fit's own reading and setting of analytic parameters
    let fit = lightpath::inverse::grin_fit::ParamFit {
        field,
        params: parsed,
        names: params.clone(),
        beams: Vec::new(),
        step: t.step,
        max_steps: t.max_steps,
        iterations: 1,
    };
    let theta = match theta {
        None => fit
            .initial()
            .map_err(|e| PyValueError::new_err(format!("params: {e}")))?,
        Some(v) if v.len() != fit.params.len() => {
            return Err(PyValueError::new_err(format!(
                "theta: {} values for {} parameter(s) {params:?}",
                v.len(),
                fit.params.len()
            )));
        }
        Some(v) => v,
    };
    let mut field = fit
        .field_with(&theta)
        .map_err(|e| PyValueError::new_err(format!("theta: {e}")))?;
    let parsed = fit.params;
    let grid_profile = field
        .profiles
        .iter()
        .position(|p| matches!(p, lightpath::eikonal::Profile::Grid(_)));
    if (grid || coefficients.is_some()) && grid_profile.is_none() {
        return Err(PyValueError::new_err(
            "grid: the field has no grid profile ({ kind = \"grid\", ... } in field.profiles)",
        ));
    }
    let mut grid_shape = None;
    if let Some(i) = grid_profile
        && let lightpath::eikonal::Profile::Grid(g) = &mut field.profiles[i]
    {
        if let Some(c) = coefficients {
            if c.len() != g.coef.len() {
                return Err(PyValueError::new_err(format!(
                    "coefficients: {} values, but the grid has {} = {}×{}×{}",
                    c.len(),
                    g.coef.len(),
                    g.dims[2],
                    g.dims[1],
                    g.dims[0]
                )));
            }
            if c.iter().any(|x| !x.is_finite()) {
                return Err(PyValueError::new_err(
                    "coefficients: hold non-finite values",
                ));
            }
            g.coef.copy_from_slice(&c);
        }
        if grid {
            grid_shape = Some(vec![g.dims[2], g.dims[1], g.dims[0]]);
        }
    }
    let budget = budget(max_minutes, Budget::default().max_memory_gb);
    let (rays, step, max_steps) = (t.rays.clone(), t.step, t.max_steps);
    let grid_profile = grid_profile.filter(|_| grid);
    let vjp = run_watched(py, threads, progress, move |w| {
        // forward and backward: about three traces' work per ray
        lightpath::app::budget::check_rays(
            "trace_vjp",
            "once",
            &field,
            &rays,
            step,
            max_steps,
            false,
            3.0,
            &budget,
        )?;
        ExitVjp::new(field, parsed, grid_profile, rays, step, max_steps, w)
    })?;
    Ok(TraceVjp {
        vjp: Arc::new(vjp),
        params,
        theta,
        grid_shape,
        threads,
    })
}

/// The Python module `lightpath._lightpath`.
#[pymodule]
fn _lightpath(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Task>()?;
    m.add_class::<Run>()?;
    m.add_class::<Covariance>()?;
    m.add_class::<MemoryEffect>()?;
    m.add_class::<Speckle>()?;
    m.add_class::<CovarianceVjp>()?;
    m.add_class::<Mie>()?;
    m.add_class::<Rays>()?;
    m.add_class::<TraceVjp>()?;
    m.add_class::<CorrelationMap>()?;
    m.add_class::<TiltShift>()?;
    m.add_function(wrap_pyfunction!(load_path, m)?)?;
    m.add_function(wrap_pyfunction!(load_toml, m)?)?;
    m.add_function(wrap_pyfunction!(load_dict, m)?)?;
    m.add_function(wrap_pyfunction!(covariance, m)?)?;
    m.add_function(wrap_pyfunction!(memory_effect, m)?)?;
    m.add_function(wrap_pyfunction!(speckle, m)?)?;
    m.add_function(wrap_pyfunction!(wave, m)?)?;
    m.add_function(wrap_pyfunction!(covariance_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(mie, m)?)?;
    m.add_function(wrap_pyfunction!(trace, m)?)?;
    m.add_function(wrap_pyfunction!(trace_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(correlation_map, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(tilt_shift, m)?)?;
    m.add_class::<inverse::Fit>()?;
    m.add_class::<inverse::Design>()?;
    m.add_class::<inverse::GrinFit>()?;
    m.add_class::<inverse::RenderDesign>()?;
    m.add_function(wrap_pyfunction!(inverse::fit, m)?)?;
    m.add_function(wrap_pyfunction!(inverse::design, m)?)?;
    m.add_class::<render::Render>()?;
    m.add_class::<render::RenderVjp>()?;
    m.add_class::<render::PhaseAcquisition>()?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(render::acquire_phase, m)?)?;
    Ok(())
}
