//! The commands: one file per command family. Each takes a loaded task (see [`crate::config`]),
//! runs it on the library (the `mc` engine, the inverse drivers), and writes typed result files
//! (see [`crate::io::results`]). This is the executor's side of the design: estimators never print,
//! spawn threads or write files; the app layer does, and nothing below imports it.
//!
//! - [`run`]: `covariance`, `speckle`, `memory-effect` (Monte Carlo), shards and `merge`
//! - [`wave`]: the Foldy–Lax wave solver, as an estimator under the same engine
//! - [`compare`]: agreement of two `covariance.json`
//! - [`fit`]: material and phase-function fits
//! - [`grin`]: `trace`, `design` (grid designs and parameter fits)
//! - [`mie`]: spheres by Lorenz–Mie theory
//! - [`render`]: refractive, scattering volumes by particle tracing
//! - [`acquire_phase`]: the phase function read from speckle images
//! - [`check`]: validate a config without running it
//! - [`bench`](mod@bench): throughput figures

pub mod acquire_phase;
pub mod bench;
pub mod budget;
pub mod check;
pub mod compare;
pub mod correlation_map;
pub mod fit;
pub mod grin;
pub mod mie;
pub mod render;
pub mod render_design;
pub mod run;
pub mod tilt_shift;
pub mod wave;

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

/// What a finished command reports to the user.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub files: Vec<PathBuf>,
    pub summary: String,
    /// Set when a fit or design did not converge: printed on stderr, and the command exits with
    /// status 3 (its files are written, marked `"converged": false`).
    pub not_converged: Option<String>,
}

impl Outcome {
    /// A summary with no files.
    pub fn text(summary: impl Into<String>) -> Self {
        Outcome {
            files: vec![],
            summary: summary.into(),
            not_converged: None,
        }
    }
}

/// Run `f` on a pool of `threads` workers (default: rayon's global pool, all cores). Results never
/// depend on the count.
pub fn with_threads<T: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> Result<T> + Send,
) -> Result<T> {
    match threads {
        None => f(),
        Some(0) => Err(Error::input("--threads 0: must be at least 1")),
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| Error::input(format!("--threads {n}: {e}")))?
            .install(f),
    }
}

/// Prepare the output folder `out` before any work: create it (and its parents), check that files
/// can be written there (so an unwritable folder is reported now, not after the computation), and
/// remove the files an earlier run of the same command left (`owned`: names, or `prefix*suffix`
/// patterns) together with any half-written staging file, so no stale result sits beside a new one.
/// Other files in the folder are left alone.
pub fn create_out(out: &Path, owned: &[&str]) -> Result<()> {
    let io = |action: &'static str, path: &Path| {
        let path = path.to_path_buf();
        move |source| Error::Io {
            action,
            path,
            source,
        }
    };
    std::fs::create_dir_all(out).map_err(io("create output folder", out))?;
    let probe = out.join(format!(
        "{}write-check-{}",
        crate::io::STAGING_PREFIX,
        std::process::id()
    ));
    std::fs::write(&probe, b"")
        .and_then(|()| std::fs::remove_file(&probe))
        .map_err(io("write into output folder", out))?;
    let entries = std::fs::read_dir(out).map_err(io("read output folder", out))?;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale = name.starts_with(crate::io::STAGING_PREFIX)
            || owned.iter().any(|p| matches_pattern(&name, p));
        if stale && entry.file_type().is_ok_and(|t| t.is_file()) {
            std::fs::remove_file(entry.path()).map_err(io("remove stale output", &entry.path()))?;
        }
    }
    Ok(())
}

/// How a fit or design saves and resumes (`--resume DIR`, `--checkpoint-every N`).
#[derive(Clone, Debug, Default)]
pub struct Resume {
    /// Continue the killed run whose `checkpoint.bin` is in this folder.
    pub from: Option<PathBuf>,
    /// Save after this many evaluations (Adam: iterations); default every two minutes.
    pub every: Option<u64>,
}

/// The journal of a fit or design of `kind` whose results depend on `identity`, saved to
/// `out/checkpoint.bin`: fresh (any earlier checkpoint there is removed), or
/// with `resume.from` the one saved there, which must belong to the same run. Called before
/// [`create_out`], so a refused resume leaves the folder as it was.
pub fn journal(
    kind: &str,
    identity: serde_json::Value,
    resume: &Resume,
    out: &Path,
) -> Result<crate::inverse::journal::Journal> {
    use crate::inverse::journal::{Journal, Saver};
    use crate::io::state::{JournalHeader, read_journal, write_journal};
    let header = JournalHeader {
        kind: kind.into(),
        identity,
        version: env!("CARGO_PKG_VERSION").into(),
    };
    let path = out.join(run::CHECKPOINT_FILE);
    let (entries, snapshot) = match &resume.from {
        Some(dir) => {
            let saved = saved_checkpoint(dir)?;
            let (h, entries, snapshot) = read_journal(&saved)?;
            if h != header {
                return Err(Error::input(format!(
                    "{}: the checkpoint belongs to another run (command, config, target, options or version differ); resume with the command, config and options that started it, or remove it to start afresh",
                    saved.display()
                )));
            }
            (entries, snapshot)
        }
        None => {
            remove_checkpoint(out)?;
            (Vec::new(), None)
        }
    };
    let save = move |saved: &crate::inverse::journal::Saved<'_>| {
        write_journal(&path, &header, saved).map_err(|source| Error::Io {
            action: "write",
            path: path.clone(),
            source,
        })
    };
    Ok(Journal::new(
        Saver {
            every: resume.every,
            save: Box::new(save),
        },
        entries,
        snapshot,
    ))
}

/// The journal of a fit or design kept in `dir` (created if need be), for callers without a
/// `--resume` flag (the Python package): it continues the run saved there, which must be the same
/// run, or starts one. Remove the checkpoint with [`remove_checkpoint`] once the run has finished.
pub fn resumable(
    kind: &str,
    identity: serde_json::Value,
    dir: &Path,
    every: Option<u64>,
) -> Result<crate::inverse::journal::Journal> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        action: "create checkpoint folder",
        path: dir.to_path_buf(),
        source,
    })?;
    let from = dir
        .join(run::CHECKPOINT_FILE)
        .exists()
        .then(|| dir.to_path_buf());
    journal(kind, identity, &Resume { from, every }, dir)
}

/// `dir/checkpoint.bin`, which `--resume dir` needs.
fn saved_checkpoint(dir: &Path) -> Result<PathBuf> {
    let path = dir.join(run::CHECKPOINT_FILE);
    if !path.exists() {
        return Err(Error::input(format!(
            "--resume {}: no {} there (the run finished, never saved one, or wrote elsewhere)",
            dir.display(),
            run::CHECKPOINT_FILE
        )));
    }
    Ok(path)
}

/// Remove `out/checkpoint.bin`: a finished run has nothing left to resume, a fresh one replaces it.
pub fn remove_checkpoint(out: &Path) -> Result<()> {
    let path = out.join(run::CHECKPOINT_FILE);
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(Error::Io {
            action: "remove",
            path,
            source: e,
        }),
        _ => Ok(()),
    }
}

/// Whether `name` is `pattern`, or matches `prefix*suffix` when the pattern holds one `*`.
fn matches_pattern(name: &str, pattern: &str) -> bool {
    match pattern.split_once('*') {
        Some((pre, suf)) => {
            name.len() >= pre.len() + suf.len() && name.starts_with(pre) && name.ends_with(suf)
        }
        None => name == pattern,
    }
}

/// A progress bar on a terminal; silent otherwise (the engine's progress observer).
pub(crate) struct Progress<'a> {
    bar: Option<indicatif::ProgressBar>,
    watch: Option<&'a Watch>,
}

impl<'a> Progress<'a> {
    pub(crate) fn new(enabled: bool, total: u64, what: &str, unit: &str) -> Self {
        use std::io::IsTerminal;
        let bar = (enabled && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(total);
            b.set_style(
                indicatif::ProgressStyle::with_template(&format!(
                    "{{msg}} [{{bar:40}}] {{pos}}/{{len}} {unit}, {{elapsed}} (eta {{eta}})"
                ))
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            b.set_message(what.to_string());
            b
        });
        Progress { bar, watch: None }
    }

    /// Progress reported to `watch` (no bar): `total` units in all.
    pub(crate) fn watched(watch: &'a Watch, total: u64) -> Self {
        watch.total.store(total, Ordering::Relaxed);
        watch.done.store(0, Ordering::Relaxed);
        Progress {
            bar: None,
            watch: Some(watch),
        }
    }

    pub(crate) fn set(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.set_position(n);
        }
        if let Some(w) = self.watch {
            w.done.store(n, Ordering::Relaxed);
        }
    }

    pub(crate) fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

pub use crate::mc::Watch;
