//! Jobs behind the command line: run an estimator on a config with the engine, write results, run
//! shards, merge shards. (The "executor" of the design: estimators never do I/O themselves.)

use crate::io::state::{StateHeader, read_state, write_state};
use crate::io::{Config, write_json};
use crate::math::{C64, rotate, splitmix64};
use crate::mc::{Block, Estimate, Plan, merge, run};
use crate::speckle::endpoint::FOCUSED_UNSUPPORTED;
use crate::speckle::mean::mean_field;
use crate::speckle::{Covariance, FieldSampler, Light, Scene, View};
use glam::DVec3;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Covariance,
    MemoryEffect,
    Speckle,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Covariance => "covariance",
            Kind::MemoryEffect => "memory-effect",
            Kind::Speckle => "speckle",
        }
    }

    fn from_name(s: &str) -> Option<Kind> {
        [Kind::Covariance, Kind::MemoryEffect, Kind::Speckle]
            .into_iter()
            .find(|k| k.name() == s)
    }
}

/// Command-line overrides and run options.
#[derive(Clone, Debug, Default)]
pub struct Options {
    pub samples: Option<u64>,
    pub seed: Option<u64>,
    /// `(i, n)`: run shard `i` of `n` and write `state.bin` instead of results.
    pub shard: Option<(u64, u64)>,
    /// Show a progress bar (only when stderr is a terminal).
    pub progress: bool,
}

/// What a finished job reports to the user.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub files: Vec<PathBuf>,
    pub summary: String,
}

type JobResult = Result<Outcome, String>;

/// Run `kind` on `cfg` and write into `out`.
pub fn run_job(kind: Kind, mut cfg: Config, opts: &Options, out: &Path) -> JobResult {
    if let Some(s) = opts.samples {
        if s == 0 {
            return Err("--samples 0: must be at least 1".into());
        }
        match kind {
            Kind::Speckle => cfg.speckle.get_or_insert_with(default_speckle).paths = s,
            _ => cfg.render.samples = s,
        }
    }
    if let Some(s) = opts.seed {
        cfg.render.seed = s;
    }
    if kind == Kind::MemoryEffect && cfg.memory_effect.is_none() {
        return Err("memory-effect needs a [memory_effect] table with angles_deg = [...]".into());
    }
    cfg.validate().map_err(|e| e.0)?;
    create_out(out)?;
    let plan = plan_of(kind, &cfg);
    let units = match kind {
        Kind::Speckle => plan.chunks * cfg.speckle.as_ref().map_or(1, |s| s.realisations),
        _ => plan.chunks,
    };
    let (range, shard) = match opts.shard {
        Some((i, n)) => {
            if n == 0 || i >= n {
                return Err(format!("--shard {i}/{n}: need 0 <= i < n"));
            }
            let whole = match kind {
                Kind::Speckle => cfg.speckle.as_ref().map_or(1, |s| s.realisations),
                _ => plan.chunks,
            };
            if n > whole {
                return Err(format!(
                    "--shard {i}/{n}: the run has only {whole} units of work; use at most {whole} shards"
                ));
            }
            ((whole * i / n)..(whole * (i + 1) / n), [i, n])
        }
        None => (0..u64::MAX, [0, 1]),
    };
    let t0 = Instant::now();
    let bar = Progress::new(opts.progress, units, kind.name());
    let blocks = compute(kind, &cfg, &plan, range, &bar)?;
    bar.finish();
    if shard[1] > 1 {
        let header = StateHeader {
            kind: kind.name().into(),
            config: cfg,
            seed: plan.seed,
            chunk_paths: plan.chunk_paths,
            chunks: plan.chunks,
            shard,
            version: env!("CARGO_PKG_VERSION").into(),
        };
        let path = out.join("state.bin");
        write_state(&path, &header, &blocks)
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        return Ok(Outcome {
            summary: format!(
                "shard {}/{} of {} done in {:.1} s; combine all shards with `lightpath merge`",
                shard[0],
                shard[1],
                kind.name(),
                t0.elapsed().as_secs_f64()
            ),
            files: vec![path],
        });
    }
    finish(kind, &cfg, &plan, blocks, t0.elapsed().as_secs_f64(), out)
}

/// Merge shard folders (each with `state.bin`) into the results of the single run.
pub fn merge_job(inputs: &[PathBuf], out: &Path) -> JobResult {
    if inputs.is_empty() {
        return Err("merge: give at least one shard folder".into());
    }
    let mut first: Option<StateHeader> = None;
    let mut blocks = Vec::new();
    let mut seen = Vec::new();
    for dir in inputs {
        let path = if dir.is_dir() {
            dir.join("state.bin")
        } else {
            dir.clone()
        };
        let (h, b) = read_state(&path)?;
        if first.as_ref().is_some_and(|f| !f.same_run(&h)) {
            return Err(format!(
                "{}: this shard belongs to a different run than {} (config, seed, samples, shard count or version differ)",
                path.display(),
                inputs[0].display()
            ));
        }
        if seen.contains(&h.shard[0]) {
            return Err(format!(
                "{}: shard {}/{} is given twice",
                path.display(),
                h.shard[0],
                h.shard[1]
            ));
        }
        seen.push(h.shard[0]);
        blocks.extend(b);
        first.get_or_insert(h);
    }
    let h = first.expect("one input");
    if seen.len() as u64 != h.shard[1] {
        let missing: Vec<u64> = (0..h.shard[1]).filter(|i| !seen.contains(i)).collect();
        return Err(format!(
            "merge: shards {missing:?} of {} are missing",
            h.shard[1]
        ));
    }
    let kind = Kind::from_name(&h.kind).ok_or_else(|| format!("unknown run kind {:?}", h.kind))?;
    let plan = Plan {
        seed: h.seed,
        chunk_paths: h.chunk_paths,
        chunks: h.chunks,
    };
    create_out(out)?;
    finish(kind, &h.config, &plan, blocks, f64::NAN, out)
}

fn default_speckle() -> crate::io::config::SpeckleConfig {
    crate::io::config::SpeckleConfig {
        realisations: 1,
        paths: 100_000,
    }
}

fn plan_of(kind: Kind, cfg: &Config) -> Plan {
    match kind {
        Kind::Speckle => {
            let paths = cfg.speckle.as_ref().map_or(100_000, |s| s.paths);
            Plan::new(cfg.render.seed, paths, cfg.render.chunk)
        }
        _ => Plan::new(cfg.render.seed, cfg.render.samples, cfg.render.chunk),
    }
}

/// The seed of speckle realisation `r` (independent streams per image).
fn realisation_seed(seed: u64, r: u64) -> u64 {
    splitmix64(seed ^ splitmix64(r.wrapping_add(0xF1E1D)))
}

/// The scene and pairs a memory-effect scan uses: light 0 and view 0 rotated together.
fn memory_scene(cfg: &Config) -> Result<(Scene, Vec<f64>), String> {
    let scene = cfg.scene().map_err(|e| e.0)?;
    let me = cfg
        .memory_effect
        .as_ref()
        .ok_or("missing [memory_effect]")?;
    let Light::PlaneWave { direction: d } = scene.lights[0] else {
        return Err("memory-effect: light[0] must be a plane_wave".into());
    };
    let View::FarField { direction: v } = scene.views[0] else {
        return Err("memory-effect: view[0] must be far_field".into());
    };
    let axis = DVec3::from_array(me.axis).normalize();
    let mut angles = vec![0.0];
    angles.extend(&me.angles_deg);
    let lights = angles
        .iter()
        .map(|a| Light::PlaneWave {
            direction: rotate(d, axis, a.to_radians()),
        })
        .collect();
    let views = angles
        .iter()
        .map(|a| View::FarField {
            direction: rotate(v, axis, a.to_radians()),
        })
        .collect();
    Ok((
        Scene::new(scene.wavelength, scene.medium, lights, views),
        angles,
    ))
}

fn compute(
    kind: Kind,
    cfg: &Config,
    plan: &Plan,
    range: std::ops::Range<u64>,
    bar: &Progress,
) -> Result<Vec<Block>, String> {
    let reversed = cfg.render.reversed;
    match kind {
        Kind::Covariance => {
            let scene = cfg.scene().map_err(|e| e.0)?;
            let est = Covariance::all_pairs(&scene, reversed)?;
            let range = range.start..range.end.min(plan.chunks);
            Ok(run(&est, plan, range, &[], &|n| bar.set(n)))
        }
        Kind::MemoryEffect => {
            let (scene, angles) = memory_scene(cfg)?;
            let n = angles.len();
            let est = Covariance::with_pairs(&scene, (0..n).map(|j| (j, j)).collect(), reversed)?;
            let range = range.start..range.end.min(plan.chunks);
            Ok(run(&est, plan, range, &memory_keep(n), &|c| bar.set(c)))
        }
        Kind::Speckle => {
            let scene = cfg.scene().map_err(|e| e.0)?;
            let est = FieldSampler::new(
                &scene,
                crate::speckle::paths::SubpathSampler::all_pairs(&scene),
                reversed,
            )?;
            let reals = cfg.speckle.as_ref().map_or(1, |s| s.realisations);
            let mut out = Vec::new();
            for r in range.start..range.end.min(reals) {
                let p = Plan {
                    seed: realisation_seed(plan.seed, r),
                    ..*plan
                };
                let done = (r - range.start) * plan.chunks;
                let root = merge(
                    run(&est, &p, 0..p.chunks, &[], &|c| bar.set(done + c)),
                    p.chunks,
                )?;
                out.push(Block {
                    start: r,
                    len: 1,
                    sum: root.sum,
                    sq: vec![],
                    kept: vec![],
                });
            }
            Ok(out)
        }
    }
}

/// Kept outputs of a memory-effect run (indices into the total block): `C00`, `Ctt`, `C0t`.
fn memory_keep(n: usize) -> Vec<usize> {
    let base = 2 * n * n;
    let mut keep: Vec<usize> = (0..n).map(|t| base + t * n + t).collect();
    keep.extend((1..n).map(|t| base + t));
    keep
}

fn finish(
    kind: Kind,
    cfg: &Config,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> JobResult {
    match kind {
        Kind::Covariance => finish_covariance(cfg, plan, blocks, seconds, out),
        Kind::MemoryEffect => finish_memory(cfg, plan, blocks, seconds, out),
        Kind::Speckle => finish_speckle(cfg, plan, blocks, seconds, out),
    }
}

fn vec3(v: DVec3) -> Value {
    json!([v.x, v.y, v.z])
}

fn light_json(l: &Light) -> Value {
    match l {
        Light::PlaneWave { direction } => {
            json!({"kind": "plane_wave", "direction": vec3(*direction)})
        }
        Light::Point { position } => json!({"kind": "point", "position": vec3(*position)}),
        Light::Focused { focus, axis, gamma } => {
            json!({"kind": "focused", "focus": vec3(*focus), "axis": vec3(*axis), "aperture_sigma": 1.0 / gamma.sqrt()})
        }
    }
}

fn view_json(v: &View) -> Value {
    match v {
        View::FarField { direction } => json!({"kind": "far_field", "direction": vec3(*direction)}),
        View::Point { position } => json!({"kind": "point", "position": vec3(*position)}),
        View::Focused { focus, axis, gamma } => {
            json!({"kind": "focused", "focus": vec3(*focus), "axis": vec3(*axis), "aperture_sigma": 1.0 / gamma.sqrt()})
        }
    }
}

fn common(
    cfg: &Config,
    scene: &Scene,
    plan: &Plan,
    seconds: f64,
) -> serde_json::Map<String, Value> {
    let mut m = serde_json::Map::new();
    m.insert("wavelength".into(), json!(cfg.wavelength));
    m.insert(
        "lights".into(),
        Value::Array(scene.lights.iter().map(light_json).collect()),
    );
    m.insert(
        "views".into(),
        Value::Array(scene.views.iter().map(view_json).collect()),
    );
    m.insert("samples".into(), json!(plan.samples()));
    m.insert("seed".into(), json!(plan.seed));
    m.insert("chunk".into(), json!(plan.chunk_paths));
    m.insert("reversed".into(), json!(cfg.render.reversed));
    m.insert(
        "seconds".into(),
        if seconds.is_finite() {
            json!(seconds)
        } else {
            Value::Null
        },
    );
    m.insert("version".into(), json!(env!("CARGO_PKG_VERSION")));
    m.insert(
        "config".into(),
        serde_json::to_value(cfg).unwrap_or(Value::Null),
    );
    m
}

/// `[l1][l2][v1][v2]` nested arrays of `f(block index)` for a `J×J` block with `j = l·V + v`.
fn nested4(nl: usize, nv: usize, f: impl Fn(usize) -> f64) -> Value {
    let j = nl * nv;
    Value::Array(
        (0..nl)
            .map(|l1| {
                Value::Array(
                    (0..nl)
                        .map(|l2| {
                            Value::Array(
                                (0..nv)
                                    .map(|v1| {
                                        Value::Array(
                                            (0..nv)
                                                .map(|v2| {
                                                    json!(f((l1 * nv + v1) * j + l2 * nv + v2))
                                                })
                                                .collect(),
                                        )
                                    })
                                    .collect(),
                            )
                        })
                        .collect(),
                )
            })
            .collect(),
    )
}

fn finish_covariance(
    cfg: &Config,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> JobResult {
    let scene = cfg.scene().map_err(|e| e.0)?;
    let root = merge(blocks, plan.chunks)?;
    let e = Estimate::from_block(&root, plan);
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let jj = (nl * nv) * (nl * nv);
    let mut m = common(cfg, &scene, plan, seconds);
    for (prefix, off) in [("", 2 * jj), ("single_", 0), ("multiple_", jj)] {
        m.insert(
            format!("{prefix}re"),
            nested4(nl, nv, |i| e.mean[off + i].re),
        );
        m.insert(
            format!("{prefix}im"),
            nested4(nl, nv, |i| e.mean[off + i].im),
        );
        m.insert(
            format!("{prefix}stderr"),
            nested4(nl, nv, |i| e.stderr[off + i]),
        );
    }
    let means: Vec<Vec<C64>> = scene
        .lights
        .iter()
        .map(|l| {
            scene
                .views
                .iter()
                .map(|v| mean_field(&scene, l, v).ok_or(FOCUSED_UNSUPPORTED))
                .collect::<Result<Vec<_>, _>>()
        })
        .collect::<Result<_, _>>()?;
    m.insert(
        "mean_re".into(),
        json!(
            means
                .iter()
                .map(|r| r.iter().map(|z| z.re).collect::<Vec<_>>())
                .collect::<Vec<_>>()
        ),
    );
    m.insert(
        "mean_im".into(),
        json!(
            means
                .iter()
                .map(|r| r.iter().map(|z| z.im).collect::<Vec<_>>())
                .collect::<Vec<_>>()
        ),
    );
    let path = out.join("covariance.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let diag: Vec<f64> = (0..nl * nv)
        .map(|j| e.mean[2 * jj + j * nl * nv + j].re)
        .collect();
    let summary = format!(
        "covariance of {nl} light(s) × {nv} view(s) from {} paths; intensity range {:.4e} … {:.4e}",
        plan.samples(),
        diag.iter().cloned().fold(f64::INFINITY, f64::min),
        diag.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
    );
    Ok(Outcome {
        files: vec![path],
        summary,
    })
}

/// Memory-effect curve: intensity correlation `|C0t|² / (C00 Ctt)` with delta-method errors.
pub struct MemoryCurve {
    pub angles_deg: Vec<f64>,
    pub correlation: Vec<f64>,
    pub stderr: Vec<f64>,
    pub field_correlation: Vec<f64>,
    /// `((kθL)/sinh(kθL))²` (paper 001, Eq. 39).
    pub diffusion: Vec<f64>,
    /// `k L` of Eq. 39.
    pub kl: f64,
}

/// The diffusion prediction `((kθL)/sinh(kθL))²` of paper 001, Eq. 39 (`θ` in radians).
pub fn diffusion_correlation(kl: f64, theta: f64) -> f64 {
    let x = kl * theta.abs();
    if x < 1e-8 {
        1.0
    } else {
        (x / x.sinh()).powi(2)
    }
}

/// Thickness used in Eq. 39: slab thickness, or the chord of a box along light 0.
fn thickness(scene: &Scene) -> f64 {
    match (&scene.medium.geometry, scene.lights.first()) {
        (crate::medium::Geometry::Slab { half_thickness, .. }, _) => 2.0 * half_thickness,
        (g, Some(Light::PlaneWave { direction })) => 2.0 * g.exit_distance(DVec3::ZERO, *direction),
        _ => f64::NAN,
    }
}

/// Compute the curve from a memory-effect run's root block.
pub fn memory_curve(scene: &Scene, angles: &[f64], root: &Block, plan: &Plan) -> MemoryCurve {
    let n = angles.len();
    let e = Estimate::from_block(root, plan);
    let keep = memory_keep(n);
    let chunks = root.len as usize;
    let nk = keep.len();
    let l = thickness(scene);
    let mut curve = MemoryCurve {
        angles_deg: vec![],
        correlation: vec![],
        stderr: vec![],
        field_correlation: vec![],
        diffusion: vec![],
        kl: scene.k * l,
    };
    for (t, angle) in angles.iter().enumerate().skip(1) {
        let (ia, ib, ic) = (0, t, n - 1 + t);
        let a = e.mean[keep[ia]].re;
        let b = e.mean[keep[ib]].re;
        let c = e.mean[keep[ic]];
        let r = c.norm_sqr() / (a * b);
        // delta method over chunk means
        let (ga, gb, gc) = (-r / a, -r / b, c * (2.0 / (a * b)));
        let mut var = 0.0;
        for k in 0..chunks {
            let row = &root.kept[k * nk..(k + 1) * nk];
            let dc = row[ic] - c;
            let lin = ga * (row[ia].re - a) + gb * (row[ib].re - b) + gc.re * dc.re + gc.im * dc.im;
            var += lin * lin;
        }
        var /= (chunks as f64 - 1.0) * chunks as f64;
        curve.angles_deg.push(*angle);
        curve.correlation.push(r);
        curve.stderr.push(var.sqrt());
        curve.field_correlation.push(r.sqrt());
        curve
            .diffusion
            .push(diffusion_correlation(curve.kl, angle.to_radians()));
    }
    curve
}

fn finish_memory(
    cfg: &Config,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> JobResult {
    let (scene, angles) = memory_scene(cfg)?;
    let root = merge(blocks, plan.chunks)?;
    let curve = memory_curve(&scene, &angles, &root, plan);
    let mut m = common(cfg, &scene, plan, seconds);
    m.insert("angles_deg".into(), json!(curve.angles_deg));
    m.insert("correlation".into(), json!(curve.correlation));
    m.insert("correlation_stderr".into(), json!(curve.stderr));
    m.insert("field_correlation".into(), json!(curve.field_correlation));
    m.insert("diffusion_eq39".into(), json!(curve.diffusion));
    m.insert("thickness".into(), json!(thickness(&scene)));
    let path = out.join("memory_effect.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let mut files = vec![path];
    let png = out.join("memory_effect.png");
    crate::io::plot::memory_effect(&png, &curve)
        .map_err(|e| format!("cannot write {}: {e}", png.display()))?;
    files.push(png);
    let mut summary = String::from("angle [deg]   correlation ± stderr   Eq. 39\n");
    for i in 0..curve.angles_deg.len() {
        summary += &format!(
            "{:>10.5}   {:.4} ± {:.4}      {:.4}\n",
            curve.angles_deg[i], curve.correlation[i], curve.stderr[i], curve.diffusion[i]
        );
    }
    Ok(Outcome { files, summary })
}

fn finish_speckle(
    cfg: &Config,
    plan: &Plan,
    mut blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> JobResult {
    let scene = cfg.scene().map_err(|e| e.0)?;
    let reals = cfg.speckle.as_ref().map_or(1, |s| s.realisations);
    blocks.sort_by_key(|b| b.start);
    let got: Vec<u64> = blocks.iter().map(|b| b.start).collect();
    if got != (0..reals).collect::<Vec<_>>() {
        return Err(format!(
            "speckle: realisations {got:?} do not cover 0..{reals} exactly (a shard is missing)"
        ));
    }
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let means: Vec<C64> = scene
        .lights
        .iter()
        .flat_map(|l| {
            scene
                .views
                .iter()
                .map(|v| mean_field(&scene, l, v).ok_or(FOCUSED_UNSUPPORTED))
        })
        .collect::<Result<_, _>>()?;
    let norm = 1.0 / (plan.samples() as f64).sqrt();
    let fields: Vec<Vec<C64>> = blocks
        .iter()
        .map(|b| {
            b.sum
                .iter()
                .zip(&means)
                .map(|(s, m)| m + s * norm)
                .collect()
        })
        .collect();
    let part = |f: fn(&C64) -> f64| -> Value {
        json!(
            fields
                .iter()
                .map(|u| (0..nl)
                    .map(|l| (0..nv).map(|v| f(&u[l * nv + v])).collect::<Vec<_>>())
                    .collect::<Vec<_>>())
                .collect::<Vec<_>>()
        )
    };
    let mut m = common(cfg, &scene, plan, seconds);
    m.insert("re".into(), part(|z| z.re));
    m.insert("im".into(), part(|z| z.im));
    m.insert("realisations".into(), json!(reals));
    m.insert("paths_per_image".into(), json!(plan.samples()));
    let path = out.join("speckle.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let mut files = vec![path];
    let (w, h) = crate::io::image_shape(cfg, nv);
    for (r, u) in fields.iter().enumerate() {
        let p = out.join(format!("speckle_{r:04}.exr"));
        files.extend(
            crate::io::exr::write_fields(&p, u, nl, w, h)
                .map_err(|e| format!("cannot write {}: {e}", p.display()))?,
        );
    }
    Ok(Outcome {
        summary: format!(
            "{reals} speckle image(s) of {nl} light(s) × {nv} view(s), {} paths each",
            plan.samples()
        ),
        files,
    })
}

/// A progress bar on a terminal; silent otherwise.
struct Progress {
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    fn new(enabled: bool, total: u64, what: &str) -> Self {
        use std::io::IsTerminal;
        let bar = (enabled && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(total);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{msg} [{bar:40}] {pos}/{len} chunks, {elapsed} (eta {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            b.set_message(what.to_string());
            b
        });
        Progress { bar }
    }
    fn set(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.set_position(n);
        }
    }
    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Create the output folder `out` (and its parents), or say which one could not be made.
fn create_out(out: &Path) -> Result<(), String> {
    std::fs::create_dir_all(out)
        .map_err(|e| format!("cannot create output folder {}: {e}", out.display()))
}

/// Limits of the wave solver's dense solves.
#[derive(Clone, Copy, Debug)]
pub struct WaveLimits {
    pub max_scatterers: f64,
    pub max_memory_gb: f64,
    pub max_minutes: f64,
}

/// `lightpath wave`: Foldy–Lax solutions over `realizations` scatterer placements, reduced to the
/// mean, covariance and standard errors in the format of `covariance.json`.
pub fn wave_job(
    mut cfg: Config,
    realizations: u64,
    seed: Option<u64>,
    limits: WaveLimits,
    progress: bool,
    out: &Path,
) -> JobResult {
    use crate::speckle::wave;
    use rayon::prelude::*;
    if realizations < 2 {
        return Err(format!(
            "--realizations {realizations}: need at least 2 for a covariance"
        ));
    }
    if let Some(s) = seed {
        cfg.render.seed = s;
    }
    let scene = cfg.scene().map_err(|e| e.0)?;
    wave::check_scene(&scene)?;
    let n = wave::expected_scatterers(&scene);
    let n_hi = n + 6.0 * n.sqrt() + 10.0;
    let threads = rayon::current_num_threads() as f64;
    let gb = threads * (2.0 * 16.0 * n_hi * n_hi) / 1e9;
    let size = format!(
        "the scene has ~{n:.0} scatterers (σ_s·V/c_s with c_s = λ²/π = {:.4}): dense solves need ~{gb:.2} GB with {threads} threads",
        wave::cross_section(scene.k)
    );
    if n > limits.max_scatterers || gb > limits.max_memory_gb {
        return Err(format!(
            "wave: {size}, beyond the limits (--max-scatterers {}, --max-memory-gb {}). The count grows as σ_s·V/λ²: shrink the box, lower σ_s (raise mfp), or raise the limits",
            limits.max_scatterers, limits.max_memory_gb
        ));
    }
    let mut rng = crate::math::stream_rng(cfg.render.seed ^ 0x7469_6d65, 0);
    let secs = realizations as f64 * wave::seconds_per_solve(&scene, n, &mut rng) / threads;
    let size =
        format!("{size}, and ~{secs:.0} s for {realizations} realizations (timed on this machine)");
    if secs > 60.0 * limits.max_minutes {
        return Err(format!(
            "wave: {size}, beyond --max-minutes {}. Use fewer --realizations, a smaller or sparser scene, more --threads, or raise --max-minutes",
            limits.max_minutes
        ));
    }
    if progress {
        eprintln!("wave: {size}");
    }
    create_out(out)?;
    let t0 = Instant::now();
    let bar = Progress::new(progress, realizations, "wave");
    let done = std::sync::atomic::AtomicU64::new(0);
    let counts = std::sync::Mutex::new(0usize);
    let fields: Vec<Vec<C64>> = (0..realizations)
        .into_par_iter()
        .map(|r| {
            let mut rng = crate::math::stream_rng(cfg.render.seed, r);
            let pos = wave::place_scatterers(&scene, &mut rng);
            *counts.lock().expect("counter") += pos.len();
            let u = wave::solve(&scene, &pos);
            bar.set(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
            u
        })
        .collect();
    bar.finish();
    let seconds = t0.elapsed().as_secs_f64();
    let (nl, nv) = (scene.lights.len(), scene.views.len());
    let j = nl * nv;
    let r = realizations as f64;
    let mean: Vec<C64> = (0..j)
        .map(|a| fields.iter().map(|u| u[a]).sum::<C64>() / r)
        .collect();
    let mut cov = vec![C64::default(); j * j];
    let mut se = vec![0.0; j * j];
    for a in 0..j {
        for b in 0..j {
            let prods: Vec<C64> = fields
                .iter()
                .map(|u| (u[a] - mean[a]) * (u[b] - mean[b]).conj())
                .collect();
            let c = prods.iter().sum::<C64>() / (r - 1.0);
            let var = prods.iter().map(|p| (p - c).norm_sqr()).sum::<f64>() / (r - 1.0);
            cov[a * j + b] = c;
            se[a * j + b] = (var / r).sqrt();
        }
    }
    let mean_se: Vec<f64> = (0..j)
        .map(|a| {
            (fields
                .iter()
                .map(|u| (u[a] - mean[a]).norm_sqr())
                .sum::<f64>()
                / (r - 1.0)
                / r)
                .sqrt()
        })
        .collect();
    // the common echo (samples = realizations); chunking and path reversal do not apply here
    let pseudo = Plan {
        seed: cfg.render.seed,
        chunk_paths: 1,
        chunks: realizations,
    };
    let mut m = common(&cfg, &scene, &pseudo, seconds);
    m.remove("chunk");
    m.remove("reversed");
    m.insert("realizations".into(), json!(realizations));
    m.insert("solver".into(), json!("foldy-lax"));
    m.insert(
        "scatterers_mean".into(),
        json!(*counts.lock().expect("counter") as f64 / r),
    );
    m.insert("scatterers_expected".into(), json!(n));
    m.insert("re".into(), nested4(nl, nv, |i| cov[i].re));
    m.insert("im".into(), nested4(nl, nv, |i| cov[i].im));
    m.insert("stderr".into(), nested4(nl, nv, |i| se[i]));
    let grid = |f: &dyn Fn(usize) -> f64| -> Value {
        json!(
            (0..nl)
                .map(|l| (0..nv).map(|v| f(l * nv + v)).collect::<Vec<_>>())
                .collect::<Vec<_>>()
        )
    };
    m.insert("mean_re".into(), grid(&|a| mean[a].re));
    m.insert("mean_im".into(), grid(&|a| mean[a].im));
    m.insert("mean_stderr".into(), grid(&|a| mean_se[a]));
    if cov
        .iter()
        .chain(&mean)
        .any(|z| !z.re.is_finite() || !z.im.is_finite())
    {
        return Err("wave: the solve produced non-finite fields (a singular Foldy–Lax system); nothing was written".into());
    }
    let path = out.join("covariance.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    Ok(Outcome {
        files: vec![path],
        summary: format!("wave solver: {size}; took {seconds:.1} s"),
    })
}

/// Agreement of two `covariance.json` files, light pair by light pair; with `plot`, write diagonal and
/// matrix plots into that folder.
pub fn compare_job(
    a: &Path,
    b: &Path,
    tolerance: f64,
    plot: Option<&Path>,
) -> Result<(String, bool), String> {
    let read = |p: &Path| -> Result<Value, String> {
        let bytes = std::fs::read(p).map_err(|e| format!("cannot read {}: {e}", p.display()))?;
        serde_json::from_slice(&bytes).map_err(|e| format!("{}: not JSON: {e}", p.display()))
    };
    let (va, vb) = (read(a)?, read(b)?);
    let dims = |v: &Value, p: &Path| -> Result<(usize, usize), String> {
        let re = v["re"]
            .as_array()
            .ok_or_else(|| format!("{}: no `re` array (not a covariance.json)", p.display()))?;
        let nl = re.len();
        let nv = re
            .first()
            .and_then(|x| x[0].as_array())
            .map_or(0, |x| x.len());
        if nl == 0 || nv == 0 {
            return Err(format!("{}: empty covariance", p.display()));
        }
        Ok((nl, nv))
    };
    let (da, db) = (dims(&va, a)?, dims(&vb, b)?);
    if da != db {
        return Err(format!(
            "shapes differ: {} has {} lights × {} views, {} has {} × {}",
            a.display(),
            da.0,
            da.1,
            b.display(),
            db.0,
            db.1
        ));
    }
    let (nl, nv) = da;
    let get = |v: &Value, key: &str, i: [usize; 4]| {
        v[key][i[0]][i[1]][i[2]][i[3]].as_f64().unwrap_or(f64::NAN)
    };
    let mut report = String::from("lights   ‖A−B‖/‖B‖   within 3σ   worst entries [v1, v2] (z)\n");
    let mut ok = true;
    for l1 in 0..nl {
        for l2 in 0..nl {
            let (mut num, mut den, mut inside, mut worst) = (0.0, 0.0, 0usize, Vec::new());
            for v1 in 0..nv {
                for v2 in 0..nv {
                    let i = [l1, l2, v1, v2];
                    let za = C64::new(get(&va, "re", i), get(&va, "im", i));
                    let zb = C64::new(get(&vb, "re", i), get(&vb, "im", i));
                    let s = (get(&va, "stderr", i).powi(2) + get(&vb, "stderr", i).powi(2)).sqrt();
                    let d = (za - zb).norm();
                    num += d * d;
                    den += zb.norm_sqr();
                    let z = if s > 0.0 {
                        d / s
                    } else if d == 0.0 {
                        0.0
                    } else {
                        f64::INFINITY
                    };
                    if z <= 3.0 {
                        inside += 1;
                    }
                    worst.push((z, v1, v2));
                }
            }
            worst.sort_by(|x, y| y.0.total_cmp(&x.0));
            let err = (num / den).sqrt();
            ok &= err <= tolerance;
            let w: Vec<String> = worst
                .iter()
                .take(3)
                .map(|(z, v1, v2)| format!("[{v1}, {v2}] ({z:.1})"))
                .collect();
            report += &format!(
                "{l1},{l2}      {err:>9.4}   {:>8.1} %   {}\n",
                100.0 * inside as f64 / (nv * nv) as f64,
                w.join(" ")
            );
        }
    }
    report += &format!(
        "{} (tolerance on ‖A−B‖/‖B‖: {tolerance})",
        if ok { "agree" } else { "DISAGREE" }
    );
    if let Some(dir) = plot {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        let mut pairs = Vec::new();
        for l1 in 0..nl {
            for l2 in 0..nl {
                let at = |v: &Value, i: usize| {
                    C64::new(
                        get(v, "re", [l1, l2, i / nv, i % nv]),
                        get(v, "im", [l1, l2, i / nv, i % nv]),
                    )
                };
                let diag = |v: &Value| -> Vec<(f64, f64)> {
                    (0..nv)
                        .map(|d| {
                            (
                                get(v, "re", [l1, l2, d, d]),
                                get(v, "stderr", [l1, l2, d, d]),
                            )
                        })
                        .collect()
                };
                pairs.push(crate::io::plot::PairBlock {
                    label: format!("{l1},{l2}"),
                    a: (0..nv * nv).map(|i| at(&va, i).norm()).collect(),
                    b: (0..nv * nv).map(|i| at(&vb, i).norm()).collect(),
                    diag_a: diag(&va),
                    diag_b: diag(&vb),
                });
            }
        }
        let name = |p: &Path| {
            p.parent()
                .and_then(|d| d.file_name())
                .and_then(|s| s.to_str())
                .unwrap_or("?")
                .to_string()
        };
        for f in crate::io::plot::compare(dir, (&name(a), &name(b)), &pairs, nv)? {
            report += &format!("\nwrote {}", f.display());
        }
    }
    Ok((report, ok))
}

/// Options of `lightpath fit`.
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub fit: String,
    pub samples: Option<u64>,
    pub seed: Option<u64>,
    pub stages: usize,
    /// L-BFGS iterations per stage, or Adam iterations (defaults 15 and 150).
    pub iterations: Option<usize>,
    /// `lbfgs` or `adam` (default: adam when fitting `phase`, else lbfgs).
    pub optimizer: Option<String>,
    pub learning_rate: f64,
    pub smooth: f64,
    pub progress: bool,
}

/// `lightpath fit`: fit medium parameters so rendered statistics match a target.
pub fn fit_job(mut cfg: Config, target_path: &Path, opts: &FitOptions, out: &Path) -> JobResult {
    use crate::inverse::{Fit, FitParam, FitSettings, Target, check_params};
    let target = Target::read(target_path)?;
    let phase = opts.fit.split(',').any(|p| p.trim() == "phase");
    let params: Vec<FitParam> = opts
        .fit
        .split(',')
        .filter(|p| p.trim() != "phase")
        .map(FitParam::parse)
        .collect::<Result<_, _>>()?;
    if params.is_empty() && !phase {
        return Err("--fit: give at least one parameter".into());
    }
    let adam = match opts.optimizer.as_deref() {
        None => phase,
        Some("adam") => true,
        Some("lbfgs") if phase => {
            return Err(
                "--optimizer lbfgs: fitting `phase` (many node values) needs --optimizer adam"
                    .into(),
            );
        }
        Some("lbfgs") => false,
        Some(other) => {
            return Err(format!("--optimizer {other:?}: allowed: adam, lbfgs"));
        }
    };
    if let Some(s) = opts.samples {
        cfg.render.samples = s;
    }
    if let Some(s) = opts.seed {
        cfg.render.seed = s;
    }
    let scene = match &target {
        Target::Memory { angles_deg, .. } => {
            let axis = cfg
                .memory_effect
                .as_ref()
                .map_or([0.0, 1.0, 0.0], |m| m.axis);
            cfg.memory_effect = Some(crate::io::config::MemoryEffectConfig {
                angles_deg: angles_deg.clone(),
                axis,
            });
            cfg.validate().map_err(|e| e.0)?;
            memory_scene(&cfg)?.0
        }
        Target::Covariance { .. } | Target::Entries { .. } => {
            let s = cfg.scene().map_err(|e| e.0)?;
            target.check_scene(&s, target_path)?;
            s
        }
    };
    check_params(&params, &scene.medium)?;
    let iterations = opts.iterations.unwrap_or(if adam { 150 } else { 15 });
    if opts.stages == 0 || iterations == 0 {
        return Err("--stages and --iterations must be at least 1".into());
    }
    create_out(out)?;
    if adam {
        let settings = crate::inverse::AdamSettings {
            samples: cfg.render.samples,
            chunk: cfg.render.chunk,
            seed: cfg.render.seed,
            reversed: cfg.render.reversed,
            iterations,
            learning_rate: opts.learning_rate,
            smooth: opts.smooth,
        };
        let fit = crate::inverse::AdamFit {
            scene: &scene,
            target: &target,
            params,
            phase,
            settings,
        };
        return adam_fit_job(&cfg, &fit, target_path, opts.progress, out);
    }
    let settings = FitSettings {
        samples: cfg.render.samples,
        chunk: cfg.render.chunk,
        seed: cfg.render.seed,
        reversed: cfg.render.reversed,
        stages: opts.stages,
        iterations,
    };
    let fit = Fit {
        scene: &scene,
        target: &target,
        params: params.clone(),
        settings,
    };
    let t0 = Instant::now();
    let show = opts.progress;
    let names: Vec<&str> = params.iter().map(|p| p.name()).collect();
    let res = fit.run(&|e| {
        if show {
            let p: Vec<String> = names
                .iter()
                .zip(&e.params)
                .map(|(n, v)| format!("{n} = {v:.5}"))
                .collect();
            eprintln!(
                "stage {} loss {:.6e} |grad| {:.3e}  {}",
                e.stage,
                e.loss,
                e.grad_norm,
                p.join(", ")
            );
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    let mut m = serde_json::Map::new();
    m.insert("params".into(), json!(names));
    m.insert("initial".into(), json!(res.initial));
    m.insert("fitted".into(), json!(res.fitted));
    m.insert("stddev".into(), json!(res.stddev));
    m.insert("correlation".into(), json!(res.correlation));
    m.insert("loss".into(), json!(res.loss));
    m.insert("model_initial".into(), json!(res.model_initial));
    m.insert("model_fitted".into(), json!(res.model_fitted));
    m.insert(
        "log".into(),
        Value::Array(res.log.iter().map(|e| json!({"stage": e.stage, "loss": e.loss, "params": e.params, "grad_norm": e.grad_norm})).collect()),
    );
    m.insert("samples".into(), json!(cfg.render.samples));
    m.insert("seed".into(), json!(cfg.render.seed));
    m.insert("seconds".into(), json!(seconds));
    m.insert("version".into(), json!(env!("CARGO_PKG_VERSION")));
    m.insert("target".into(), json!(target_path.display().to_string()));
    m.insert(
        "config".into(),
        serde_json::to_value(&cfg).unwrap_or(Value::Null),
    );
    let path = out.join("fit.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let mut files = vec![path];
    files.extend(memory_fit_plot(
        &target,
        &res.model_initial,
        &res.model_fitted,
        out,
    )?);
    let mut summary = format!("fit in {seconds:.1} s, final loss {:.4e}\n", res.loss);
    for (i, n) in names.iter().enumerate() {
        summary += &format!(
            "  {n:>8}: {:.5} → {:.5} ± {:.5}\n",
            res.initial[i], res.fitted[i], res.stddev[i]
        );
    }
    for a in 0..names.len() {
        for b in a + 1..names.len() {
            let r = res.correlation[a][b];
            summary += &format!("  correlation({}, {}) = {r:.3}", names[a], names[b]);
            if r.abs() > 0.95 || !r.is_finite() {
                summary += "  — strongly correlated: the data barely separate them (e.g. similarity σ_s(1 − g) ≈ const)";
            }
            summary += "\n";
        }
    }
    Ok(Outcome { files, summary })
}

/// fit.png for a memory-curve target: the target with error bars, the initial and fitted model.
fn memory_fit_plot(
    target: &crate::inverse::Target,
    initial: &[f64],
    fitted: &[f64],
    out: &Path,
) -> Result<Option<PathBuf>, String> {
    let crate::inverse::Target::Memory {
        angles_deg,
        correlation,
        stderr,
    } = target
    else {
        return Ok(None);
    };
    let png = out.join("fit.png");
    crate::io::plot::fit_curve(
        &png,
        angles_deg,
        correlation,
        stderr.as_deref(),
        initial,
        fitted,
    )?;
    Ok(Some(png))
}

/// The Adam branch of `lightpath fit`: fit.json (log, fitted values ± sd, the single-scattering
/// reading where it applies), phase.png for a phase-function fit, fit.png for a memory curve.
fn adam_fit_job(
    cfg: &Config,
    fit: &crate::inverse::AdamFit,
    target_path: &Path,
    show: bool,
    out: &Path,
) -> JobResult {
    let t0 = Instant::now();
    let res = fit.run(&|e| {
        if show {
            eprintln!(
                "iteration {:>4} loss {:.6e} |grad| {:.3e}",
                e.stage, e.loss, e.grad_norm
            );
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    let readings = crate::inverse::shortcut::single_scattering_readings(fit.scene, fit.target);
    let angles: Vec<f64> = res
        .cos
        .iter()
        .map(|c| c.clamp(-1.0, 1.0).acos().to_degrees())
        .collect();
    let mut m = serde_json::Map::new();
    m.insert("optimizer".into(), json!("adam"));
    m.insert("params".into(), json!(res.names));
    m.insert("initial".into(), json!(res.initial));
    m.insert("fitted".into(), json!(res.fitted));
    m.insert("stddev".into(), json!(res.stddev));
    m.insert("loss".into(), json!(res.loss));
    m.insert("dof".into(), json!(res.dof));
    m.insert("phase_cos".into(), json!(res.cos));
    m.insert("phase_angle_deg".into(), json!(angles));
    m.insert("target_values".into(), json!(fit.target.values()));
    m.insert("model_initial".into(), json!(res.model_initial));
    m.insert("model_fitted".into(), json!(res.model_fitted));
    if let Some(r) = &readings {
        m.insert(
            "single_scattering_reading".into(),
            Value::Array(
                r.iter()
                    .map(|r| json!({"delta_deg": r.delta_deg, "angle_deg": r.angle_deg, "rho": r.rho, "stderr": r.stderr}))
                    .collect(),
            ),
        );
    }
    m.insert(
        "log".into(),
        Value::Array(res.log.iter().map(|e| json!({"iteration": e.stage, "loss": e.loss, "params": e.params, "grad_norm": e.grad_norm})).collect()),
    );
    m.insert("learning_rate".into(), json!(fit.settings.learning_rate));
    m.insert("smooth".into(), json!(fit.settings.smooth));
    m.insert("samples".into(), json!(fit.settings.samples));
    m.insert("seed".into(), json!(fit.settings.seed));
    m.insert("seconds".into(), json!(seconds));
    m.insert("version".into(), json!(env!("CARGO_PKG_VERSION")));
    m.insert("target".into(), json!(target_path.display().to_string()));
    m.insert(
        "config".into(),
        serde_json::to_value(cfg).unwrap_or(Value::Null),
    );
    let path = out.join("fit.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let mut files = vec![path];
    let scalars = fit.params.len();
    if fit.phase {
        let png = out.join("phase.png");
        crate::io::plot::phase_fit(
            &png,
            &angles,
            &res.initial[scalars..],
            &res.fitted[scalars..],
            &res.stddev[scalars..],
            readings.as_deref().unwrap_or(&[]),
        )?;
        files.push(png);
    }
    files.extend(memory_fit_plot(
        fit.target,
        &res.model_initial,
        &res.model_fitted,
        out,
    )?);
    let mut summary = format!(
        "Adam fit in {seconds:.1} s ({} iterations), final loss {:.4e} over {:.0} degrees of freedom\n",
        res.log.len(),
        res.loss,
        res.dof
    );
    for (i, n) in res.names.iter().enumerate() {
        summary += &format!(
            "  {n:>14}: {:.5} → {:.5} ± {:.5}\n",
            res.initial[i], res.fitted[i], res.stddev[i]
        );
    }
    Ok(Outcome { files, summary })
}

/// `lightpath design`: shape a grid index field so beams pass through their foci → design.json
/// (loss history, final grid, radial profile), loss.png, profile.png and a central EXR slice.
pub fn design_job(
    cfg: &crate::io::design_config::DesignConfig,
    show: bool,
    out: &Path,
) -> JobResult {
    use crate::eikonal::design::radial_profile;
    let problem = cfg.problem().map_err(|e| e.0)?;
    create_out(out)?;
    let t0 = Instant::now();
    let res = problem.run(&|s| {
        if show && (s.iteration % 10 == 0 || s.iteration + 1 == problem.iterations) {
            eprintln!(
                "level {} iteration {:>5} loss {:.5e} mean miss² {:.5e}",
                s.level, s.iteration, s.loss, s.miss2
            );
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    crate::io::trace_config::check_positive(&res.field)
        .map_err(|e| format!("design result: {}", e.0))?;
    let r_max = match res.field.bounds {
        crate::eikonal::Bounds::Sphere { radius } => radius,
        crate::eikonal::Bounds::Cylinder { radius, .. } => radius,
        crate::eikonal::Bounds::Box { half } => half.min_element(),
        crate::eikonal::Bounds::Everywhere => 1.0,
    };
    let profile = radial_profile(&res.field, r_max * 0.999, 41);
    let g = &res.grid;
    let mut m = serde_json::Map::new();
    m.insert("rms_miss_initial".into(), json!(res.rms_miss_initial));
    m.insert("rms_miss_final".into(), json!(res.rms_miss_final));
    m.insert(
        "log".into(),
        Value::Array(res.log.iter().map(|s| json!({"level": s.level, "iteration": s.iteration, "loss": s.loss, "mean_miss2": s.miss2})).collect()),
    );
    m.insert(
        "grid".into(),
        json!({"dims": g.dims, "origin": g.origin.to_array(), "spacing": g.spacing,
               "interp": format!("{:?}", g.interp).to_lowercase(), "samples": res.grid_samples,
               "coefficients": g.coef}),
    );
    m.insert(
        "radial_profile".into(),
        json!({"r": profile.iter().map(|p| p.0).collect::<Vec<_>>(),
               "mean": profile.iter().map(|p| p.1).collect::<Vec<_>>(),
               "min": profile.iter().map(|p| p.2).collect::<Vec<_>>(),
               "max": profile.iter().map(|p| p.3).collect::<Vec<_>>()}),
    );
    m.insert("seconds".into(), json!(seconds));
    m.insert("version".into(), json!(env!("CARGO_PKG_VERSION")));
    m.insert(
        "config".into(),
        serde_json::to_value(cfg).unwrap_or(Value::Null),
    );
    let path = out.join("design.json");
    write_json(&path, &Value::Object(m))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let loss_png = out.join("loss.png");
    let levels = res.log.iter().map(|s| s.level).max().unwrap_or(0);
    let series: Vec<(String, Vec<(f64, f64)>)> = (0..=levels)
        .map(|l| {
            let n = problem.levels[l];
            (
                format!("level {l} ({n}³)"),
                res.log
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| s.level == l)
                    .map(|(i, s)| (i as f64, s.miss2))
                    .collect(),
            )
        })
        .collect();
    crate::io::plot::lines(
        &loss_png,
        "Design: mean squared miss distance",
        "iteration",
        "mean miss²",
        &series,
        true,
    )?;
    let profile_png = out.join("profile.png");
    crate::io::plot::lines(
        &profile_png,
        "Designed index along 26 radial directions",
        "r",
        "n",
        &[
            (
                "mean".to_string(),
                profile.iter().map(|p| (p.0, p.1)).collect(),
            ),
            (
                "min".to_string(),
                profile.iter().map(|p| (p.0, p.2)).collect(),
            ),
            (
                "max".to_string(),
                profile.iter().map(|p| (p.0, p.3)).collect(),
            ),
        ],
        false,
    )?;
    let [nx, ny, nz] = g.dims;
    let slice: Vec<f64> = res.grid_samples[nx * ny * (nz / 2)..nx * ny * (nz / 2 + 1)].to_vec();
    let exr_path = out.join("grid_slice_z.exr");
    crate::io::exr::write_scalar(&exr_path, &slice, nx, ny, "n")?;
    let summary = format!(
        "design in {seconds:.1} s ({} iterations over {} level(s)): RMS miss distance {:.4e} → {:.4e}",
        res.log.len(),
        problem.levels.len(),
        res.rms_miss_initial,
        res.rms_miss_final
    );
    Ok(Outcome {
        files: vec![path, loss_png, profile_png, exr_path],
        summary,
    })
}

/// `lightpath design` with a `[parameters]` table: fit analytic field parameters by L-BFGS on
/// exit-adjoint gradients → fit.json (values, log), loss.png and rays.png of the fitted field.
pub fn param_fit_job(
    cfg: &crate::io::design_config::ParamFitConfig,
    show: bool,
    out: &Path,
) -> JobResult {
    use crate::eikonal::Tracer;
    let problem = cfg.problem().map_err(|e| e.0)?;
    create_out(out)?;
    let t0 = Instant::now();
    let res = problem.run(&|s| {
        if show {
            eprintln!(
                "evaluation {:>4} mean miss² {:.5e} parameters {:?}",
                s.evaluation, s.mean_miss2, s.params
            );
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    let m = json!({
        "parameters": problem.names,
        "initial": res.initial,
        "fitted": res.fitted,
        "rms_miss_initial": res.rms_miss_initial,
        "rms_miss_final": res.rms_miss_final,
        "log": res.log.iter().map(|s| json!({"evaluation": s.evaluation, "parameters": s.params, "mean_miss2": s.mean_miss2})).collect::<Vec<_>>(),
        "seconds": seconds,
        "version": env!("CARGO_PKG_VERSION"),
        "config": serde_json::to_value(cfg).unwrap_or(Value::Null),
    });
    let path = out.join("fit.json");
    write_json(&path, &m).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let loss_png = out.join("loss.png");
    crate::io::plot::lines(
        &loss_png,
        "Fit: mean squared miss distance",
        "evaluation",
        "mean miss²",
        &[(
            "L-BFGS".to_string(),
            res.log
                .iter()
                .map(|s| (s.evaluation as f64, s.mean_miss2))
                .collect(),
        )],
        true,
    )?;
    let tracer = Tracer {
        field: &res.field,
        step: problem.step,
        max_steps: problem.max_steps,
    };
    let paths: Vec<Vec<DVec3>> = problem
        .beams
        .iter()
        .flat_map(|b| b.rays.iter().map(move |r| (r, b.focus)))
        .map(|(&(o, d), focus)| {
            let mut p = vec![o];
            let mut k = 0usize;
            let e = tracer.trace_with(o, d, |x| {
                if k.is_multiple_of(16) {
                    p.push(x);
                }
                k += 1;
            });
            p.push(e.x);
            p.push(e.x + e.direction * (focus - e.x).length().max(0.2 * (e.x - o).length()));
            p
        })
        .collect();
    let rays_png = out.join("rays.png");
    crate::io::plot::ray_paths(&rays_png, &paths)?;
    let mut summary = format!(
        "L-BFGS fit in {seconds:.1} s ({} evaluations): RMS miss distance {:.4e} → {:.4e}\n",
        res.log.len(),
        res.rms_miss_initial,
        res.rms_miss_final
    );
    for (i, n) in problem.names.iter().enumerate() {
        summary += &format!("  {n}: {:.6e} → {:.6e}\n", res.initial[i], res.fitted[i]);
    }
    Ok(Outcome {
        files: vec![path, loss_png, rays_png],
        summary: summary.trim_end().to_string(),
    })
}

/// `lightpath trace`: trace a bundle of rays through an index field → rays.json and rays.png.
pub fn trace_job(cfg: &crate::io::trace_config::TraceConfig, out: &Path) -> JobResult {
    use crate::eikonal::{IndexField, Tracer};
    use rayon::prelude::*;
    let field = cfg.field().map_err(|e| e.0)?;
    let rays = cfg.rays().map_err(|e| e.0)?;
    let step = cfg.trace.step;
    if !(step.is_finite() && step > 0.0) {
        return Err(format!(
            "trace.step = {step}: must be a positive finite number"
        ));
    }
    if cfg.trace.max_steps == 0 {
        return Err("trace.max_steps = 0: must be at least 1".into());
    }
    let tracer = Tracer {
        field: &field,
        step,
        max_steps: cfg.trace.max_steps as usize,
    };
    let t0 = Instant::now();
    let traced: Vec<(crate::eikonal::RayEnd, Vec<DVec3>, Option<DVec3>)> = rays
        .par_iter()
        .map(|&(o, d)| {
            let mut path = vec![o];
            let mut bad = None;
            let mut k = 0usize;
            let end = tracer.trace_with(o, d, |x| {
                let n = field.n(x);
                if bad.is_none() && !(n > 0.0 && n.is_finite()) {
                    bad = Some(x);
                }
                if k.is_multiple_of(16) {
                    path.push(x);
                }
                k += 1;
            });
            path.push(end.x);
            (end, path, bad)
        })
        .collect();
    if !traced.iter().any(|t| t.0.entered) {
        return Err(format!(
            "rays: none of the {} rays meets the field's bounds: check rays.center / rays.origin and the direction",
            traced.len()
        ));
    }
    if let Some(x) = traced.iter().find_map(|t| t.2) {
        return Err(format!(
            "field: n = {} at {x}: the refractive index must be positive and finite where rays run",
            field.n(x)
        ));
    }
    create_out(out)?;
    let seconds = t0.elapsed().as_secs_f64();
    let list: Vec<Value> = rays
        .iter()
        .zip(&traced)
        .map(|((o, d), (e, _, _))| {
            json!({"origin": vec3(*o), "direction": vec3(*d), "exit_position": vec3(e.x), "exit_direction": vec3(e.direction),
                   "optical_path": e.optical_path, "steps": e.steps, "entered": e.entered, "exited": e.exited})
        })
        .collect();
    let m = json!({"rays": list, "seconds": seconds, "version": env!("CARGO_PKG_VERSION"), "config": serde_json::to_value(cfg).unwrap_or(Value::Null)});
    let path = out.join("rays.json");
    write_json(&path, &m).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let png = out.join("rays.png");
    let paths: Vec<Vec<DVec3>> = traced
        .iter()
        .map(|(e, p, _)| {
            let mut p = p.clone();
            p.push(e.x + e.direction * 1.5 * (e.x - p[0]).length().max(1.0));
            p
        })
        .collect();
    crate::io::plot::ray_paths(&png, &paths)?;
    let exited = traced.iter().filter(|t| t.0.exited && t.0.entered).count();
    Ok(Outcome {
        files: vec![path, png],
        summary: format!(
            "traced {} rays ({exited} through the field) in {seconds:.2} s",
            rays.len()
        ),
    })
}
