//! `lightpath render`: a refractive, scattering volume rendered by particle tracing on the engine
//! (whole, as shards for `merge`, resumable) → `render.json` (every sensor's power, flux per time
//! bin, absorbed/escaped totals, statistics) and, per screen, EXR images with their standard error
//! and a PNG preview.

use super::run::{Job, Kind, RunOptions, check_finite, execute};
use super::{Outcome, Progress};
use crate::config::RenderTask;
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{
    CameraRecord, ConnectionStatistics, Measured, ProbeRecord, RenderFile, RenderStatistics,
    SensorRecord, StrategyRecord, SurfaceRecord, TargetRecord, WindowRecord,
};
use crate::mc::{Block, Checkpoint, Estimate, Plan, merge, resume};
use crate::medium::{Geometry, Medium};
use crate::rrte::{
    Filter, ImageLayout, MAX_REFLECTIONS, ParticleTracer, Region, STRATEGY_EVENTS, SensorKind,
    Total,
};
use std::path::Path;

/// The files a render writes (screens add `screen_<name>.exr`, `screen_<name>.png` and, with time
/// bins, `screen_<name>_t<bin>.exr`; cameras the same as `camera_<name>…`).
pub const FILES: &[&str] = &[
    "render.json",
    "screen_*.exr",
    "screen_*.png",
    "camera_*.exr",
    "camera_*.png",
];

/// Run the render of `task` into `out`.
pub fn run(mut task: RenderTask, opts: &RunOptions, out: &Path) -> Result<Outcome> {
    let r = &mut task.config.render;
    if let Some(s) = opts.samples {
        if s == 0 {
            return Err(Error::input("--samples 0: must be at least 1"));
        }
        r.samples = s;
    }
    if let Some(s) = opts.seed {
        r.seed = s;
    }
    let plan = Plan::new(r.seed, r.samples, r.chunk);
    execute(Kind::Render, Job::Render(&task), plan, opts, out)
}

/// Render `task` in memory (nothing written), with `samples` and `seed` overriding the config's;
/// progress (in chunks) and the stop flag go through `watch`.
pub fn evaluate(
    mut task: RenderTask,
    samples: Option<u64>,
    seed: Option<u64>,
    budget: &super::budget::Budget,
    watch: &super::Watch,
) -> Result<Rendered> {
    let r = &mut task.config.render;
    if let Some(s) = samples {
        if s == 0 {
            return Err(Error::input("samples = 0: must be at least 1"));
        }
        r.samples = s;
    }
    if let Some(s) = seed {
        r.seed = s;
    }
    let plan = Plan::new(r.seed, r.samples, r.chunk);
    let bar = Progress::watched(watch, plan.chunks);
    let t0 = std::time::Instant::now();
    let blocks = compute(
        &task,
        &plan,
        0..plan.chunks,
        Vec::new(),
        Checkpoint::stop_only(Some(&watch.stop)),
        budget,
        &bar,
    )?;
    rendered(&task, &plan, blocks, t0.elapsed().as_secs_f64())
}

/// The median of `stderr/mean` over the pixels of `image`'s time-integrated first channel that
/// received light (`None` if none did).
fn pixel_noise(e: &Estimate, image: ImageLayout) -> Option<f64> {
    median_noise(&lit_pixels(e, image), 0.0)
}

/// [`pixel_noise`] over the bright pixels: those at least [`BRIGHT`] of the mean of the image's
/// brightest one per cent (unlit pixels counted). Faint pixels that more samples keep lighting (a
/// halo of light scattered once out of a beam) neither enter it nor move its threshold, so its
/// pixel set settles as the image converges.
fn bright_pixel_noise(e: &Estimate, image: ImageLayout) -> Option<f64> {
    let lit = lit_pixels(e, image);
    let mut means: Vec<f64> = lit.iter().map(|p| p.0).collect();
    means.sort_by(|a, b| b.total_cmp(a));
    let top = image.pixels.div_ceil(100);
    let reference = means.iter().take(top).sum::<f64>() / top as f64;
    median_noise(&lit, BRIGHT * reference)
}

/// The fraction of the brightest pixels' mean from which [`bright_pixel_noise`] counts.
const BRIGHT: f64 = 0.01;

/// `(mean, stderr)` of the pixels of `image`'s time-integrated first channel that received light.
fn lit_pixels(e: &Estimate, image: ImageLayout) -> Vec<(f64, f64)> {
    let first = image.plane(None, 0);
    (first..first + image.pixels)
        .filter(|&k| e.mean[k].re > 0.0)
        .map(|k| (e.mean[k].re, e.stderr[k]))
        .collect()
}

/// The median of `stderr/mean` over the pixels whose mean is at least `floor`.
fn median_noise(pixels: &[(f64, f64)], floor: f64) -> Option<f64> {
    let mut noise: Vec<f64> = pixels
        .iter()
        .filter(|p| p.0 >= floor)
        .map(|&(mean, stderr)| stderr / mean)
        .collect();
    if noise.is_empty() {
        return None;
    }
    noise.sort_by(f64::total_cmp);
    Some(noise[noise.len() / 2])
}

/// What `check` says of a render config.
pub fn describe(task: &RenderTask) -> String {
    let s = &task.scene;
    let v = &s.volume;
    format!(
        "render config{}: {} index profile(s) ({}) in {}, {}, {} sensor plane(s), {} target(s), {} probe(s), {} camera(s), {} surface(s), {} output(s){}{}{}; ~{:.3} scattering events per photon",
        match s.tracing {
            crate::rrte::Tracing::FromLight => "",
            crate::rrte::Tracing::FromCameras => " (path tracing from the cameras)",
            crate::rrte::Tracing::Bidirectional => " (bidirectional path tracing)",
        },
        v.field.profiles.len(),
        if v.homogeneous() {
            "constant n: straight rays"
        } else {
            "curved rays"
        },
        bounds_text(&v.field.bounds),
        bulk_text(v),
        s.sensors.iter().filter(|x| x.region.is_none()).count(),
        s.sensors.iter().filter(|x| x.region.is_some()).count(),
        s.probes.len(),
        s.cameras.len() + s.pinholes.len(),
        s.surfaces.len(),
        crate::mc::Estimator::outputs(&ParticleTracer::new(s)),
        if s.derivatives.is_empty() {
            String::new()
        } else {
            let names: Vec<String> = s.derivatives.iter().map(|d| d.name()).collect();
            format!(", derivatives by {}", names.join(", "))
        },
        s.transient
            .map_or(String::new(), |t| format!(", {} time bins", t.bins)),
        s.spectrum
            .as_ref()
            .map_or(String::new(), |sp| match sp.channels() {
                1 => format!(", one line at {} nm", sp.range_nm[0]),
                _ => format!(
                    ", white light over {}–{} nm in RGB",
                    sp.range_nm[0], sp.range_nm[1]
                ),
            }),
        crate::speckle::paths::expected_events(&proxy_medium(&task.scene)),
    )
}

/// The volume's coefficients in words: one volume's, or each of several volumes' in order.
fn bulk_text(v: &crate::rrte::Volume) -> String {
    if v.parts.is_empty() {
        return format!("σ_s = {}, σ_a = {}", v.sigma_s, v.sigma_a);
    }
    let list = |f: fn(&crate::rrte::Bulk) -> f64| {
        let each: Vec<String> = v.parts.iter().map(|b| f(b).to_string()).collect();
        format!("[{}]", each.join(", "))
    };
    format!(
        "σ_s = {}, σ_a = {} (volume by volume)",
        list(|b| b.sigma_s),
        list(|b| b.sigma_a)
    )
}

/// The volume's bounds in words.
fn bounds_text(bounds: &crate::eikonal::Bounds) -> String {
    use crate::eikonal::Bounds;
    match bounds {
        Bounds::Everywhere => "all space".into(),
        Bounds::Sphere { radius } => format!("a sphere of radius {radius}"),
        Bounds::Cylinder {
            radius,
            half_length,
        } => format!(
            "a cylinder of radius {radius} and length {}",
            2.0 * half_length
        ),
        Bounds::Box { half } => format!("a box of {:?}", (*half * 2.0).to_array()),
        Bounds::Parts(parts) => {
            let each: Vec<String> = parts
                .iter()
                .map(|p| {
                    let c = p.center;
                    format!(
                        "{} at [{:.3}, {:.3}, {:.3}]",
                        bounds_text(&p.shape),
                        c.x,
                        c.y,
                        c.z
                    )
                })
                .collect();
            format!("{} volumes: {}", parts.len(), each.join("; "))
        }
        Bounds::Sdf(sdf) => {
            let g = sdf.grid();
            let (lo, hi) = sdf.corners();
            let corner = |v: glam::DVec3| format!("[{:.3}, {:.3}, {:.3}]", v.x, v.y, v.z);
            format!(
                "a signed-distance shape within {} to {} ({}×{}×{} nodes every {}, {})",
                corner(lo),
                corner(hi),
                g.dims[0],
                g.dims[1],
                g.dims[2],
                g.spacing,
                match g.interp {
                    crate::eikonal::grid::Interp::Tricubic => "tricubic",
                    crate::eikonal::grid::Interp::Trilinear => "trilinear",
                }
            )
        }
    }
}

/// The volume as a homogeneous medium in its bounding box (for the expected path length).
pub fn proxy_medium(scene: &crate::rrte::RenderScene) -> Medium {
    let v = &scene.volume;
    let mut half = v.field.bounds.half_extent().unwrap_or(glam::DVec3::ONE);
    let (mut sigma_s, mut sigma_a, mut scattering) = (v.sigma_s, v.sigma_a, &v.scattering);
    // of several volumes, the most extinguishing one in its own box (the estimate errs towards
    // more work)
    let parts = v.field.bounds.parts().unwrap_or(&[]);
    if let Some((part, b)) = parts
        .iter()
        .zip(&v.parts)
        .max_by(|a, b| a.1.sigma_t().total_cmp(&b.1.sigma_t()))
    {
        half = part.shape.half_extent().unwrap_or(half);
        (sigma_s, sigma_a, scattering) = (b.sigma_s, b.sigma_a, &b.scattering);
    }
    Medium {
        geometry: Geometry::boxed((half * 2.0).to_array()),
        sigma_s,
        sigma_a,
        scattering: scattering.clone(),
    }
}

/// Trace the chunks of `range` (after the resumed `done`), refusing runs beyond `budget`.
pub(crate) fn compute(
    task: &RenderTask,
    plan: &Plan,
    range: std::ops::Range<u64>,
    done: Vec<Block>,
    checkpoint: Checkpoint,
    budget: &super::budget::Budget,
    bar: &Progress,
) -> Result<Vec<Block>> {
    let est = ParticleTracer::new(&task.scene);
    let next = done.last().map_or(range.start, |b| b.start + b.len);
    let chunks = range.end.saturating_sub(next);
    let photons = (chunks * plan.chunk_paths) as f64;
    let medium = proxy_medium(&task.scene);
    super::budget::check("render", &est, &medium, photons, chunks, 0, budget)?;
    let progress = |n| bar.set(n);
    resume(&est, plan, range, &[], &progress, done, Some(checkpoint))
}

/// Write the results of a whole run (or merged shards) into `out`.
pub(crate) fn finish(
    task: &RenderTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
    out: &Path,
) -> Result<Outcome> {
    let r = rendered(task, plan, blocks, seconds)?;
    if let Some(w) = &r.warning {
        eprintln!("{w}");
    }
    r.write(out)
}

/// A finished render: `render.json`'s content and every screen's and camera's image.
pub struct Rendered {
    pub file: RenderFile,
    pub images: Vec<Image>,
    pub summary: String,
    /// Set when a noticeable share of the power was given up (photons trapped too long).
    pub warning: Option<String>,
}

/// One screen's or camera's image: per channel its values and standard errors, the top row
/// first (`height × width`, row-major), time-integrated and, with time bins, per bin.
pub struct Image {
    /// `screen_<name>` or `camera_<name>`: the stem of its files.
    pub stem: String,
    /// What the preview shows (`√irradiance`, `√radiance`).
    pub label: &'static str,
    pub width: usize,
    pub height: usize,
    /// `[channel] → (values, standard errors)`, time-integrated.
    pub total: Vec<(Vec<f64>, Vec<f64>)>,
    /// `[bin][channel] → (values, standard errors)`; empty without time bins.
    pub bins: Vec<Vec<(Vec<f64>, Vec<f64>)>>,
    /// Values of either sign (a derivative): the preview shows 0 as mid-grey.
    pub signed: bool,
}

/// The results of a whole run (or merged shards) from its blocks.
pub fn rendered(
    task: &RenderTask,
    plan: &Plan,
    blocks: Vec<Block>,
    seconds: f64,
) -> Result<Rendered> {
    let scene = &task.scene;
    let est = ParticleTracer::new(scene);
    let root = merge(blocks, plan.chunks)?;
    let e = Estimate::from_block(&root, plan);
    check_finite("render", &e.mean)?;
    let measured = |i: usize| Measured {
        mean: e.mean[i].re,
        stderr: e.stderr[i],
    };
    // output `i` times `scale` (an orthographic camera's pixel area turns its total into intensity)
    let scaled = |i: usize, scale: f64| Measured {
        mean: e.mean[i].re * scale,
        stderr: e.stderr[i] * scale,
    };
    let bins = scene.bins();
    let mut images = Vec::new();
    let mut sensors = Vec::new();
    let mut summary = Vec::new();
    let mut targets = Vec::new();
    let derivatives_of = |i: usize| {
        scene
            .derivatives
            .iter()
            .enumerate()
            .map(|(j, p)| (p.name(), measured(est.power_derivative(i, j))))
            .collect()
    };
    for (i, s) in scene.sensors.iter().enumerate() {
        if let Some(region) = s.region {
            let fluence = measured(est.power(i));
            summary.push(format!(
                "{} fluence {:.4e} ± {:.1e}",
                s.name, fluence.mean, fluence.stderr
            ));
            let (shape, radius, size) = match region {
                Region::Sphere { radius, .. } => ("sphere", Some(radius), None),
                Region::Box { half, .. } => ("box", None, Some((half * 2.0).to_array())),
            };
            targets.push(TargetRecord {
                name: s.name.clone(),
                shape: shape.into(),
                center: region.center().to_array(),
                radius,
                size,
                volume: region.volume(),
                fluence,
                derivatives: derivatives_of(i),
            });
            continue;
        }
        let image = est.sensor_image(i);
        let power = measured(est.power(i));
        summary.push(format!(
            "{} {:.4} ± {:.4}",
            s.name, power.mean, power.stderr
        ));
        let mut record = SensorRecord {
            name: s.name.clone(),
            kind: match s.kind {
                SensorKind::Flux | SensorKind::Target => "flux",
                SensorKind::Spot => "spot",
                SensorKind::Screen => "screen",
            }
            .into(),
            power,
            radius: s.window,
            filter: (s.filter == Filter::Tent).then(|| "tent".into()),
            bins,
            per_bin: None,
            per_bin_stderr: None,
            pixels: None,
            pixel_area: None,
            pixel_noise: None,
            bright_pixel_noise: None,
            files: vec![],
            derivatives: derivatives_of(i),
        };
        match (s.kind, s.pixel_area()) {
            (SensorKind::Screen, Some(area)) => {
                record.pixel_noise = pixel_noise(&e, image);
                record.bright_pixel_noise = bright_pixel_noise(&e, image);
                let frames = Frames {
                    e: &e,
                    image,
                    size: s.pixels,
                    scale: 1.0 / area,
                };
                let image = frames.image(format!("screen_{}", s.name), "√irradiance");
                record.files = image.exr_names();
                images.push(image);
                for (j, p) in scene.derivatives.iter().enumerate() {
                    let frames = Frames {
                        image: est.derivative_image(i, j),
                        ..frames
                    };
                    let mut image = frames.image(
                        format!("screen_{}_d_{}", s.name, file_name(&p.name())),
                        "∂irradiance",
                    );
                    image.signed = true;
                    record.files.extend(image.exr_names());
                    images.push(image);
                }
                record.pixels = Some(s.pixels);
                record.pixel_area = Some(area);
            }
            _ => {
                let at = |b| image.plane(Some(b), 0);
                record.per_bin = Some((0..bins).map(|b| e.mean[at(b)].re).collect());
                record.per_bin_stderr = Some((0..bins).map(|b| e.stderr[at(b)]).collect());
            }
        }
        sensors.push(record);
    }
    let mut probes = Vec::new();
    for (i, p) in scene.probes.iter().enumerate() {
        let fluence = measured(est.probe_total(i));
        summary.push(format!(
            "{} fluence {:.4e} ± {:.1e}",
            p.name, fluence.mean, fluence.stderr
        ));
        let o = est.probe_offset(i);
        probes.push(ProbeRecord {
            name: p.name.clone(),
            position: p.position.to_array(),
            fluence,
            per_bin: (o..o + bins).map(|k| e.mean[k].re).collect(),
            per_bin_stderr: (o..o + bins).map(|k| e.stderr[k]).collect(),
            derivatives: scene
                .derivatives
                .iter()
                .enumerate()
                .map(|(j, d)| (d.name(), measured(est.probe_derivative(i, j))))
                .collect(),
        });
    }
    let mut cameras = Vec::new();
    // a camera's images (its derivatives' after it), the files' names, and its total's
    // derivatives (times `scale`: the orthographic cameras' pixel area)
    let mut camera_images = |name: &str, i: usize, size: [usize; 2], scale: f64| {
        let frames = Frames {
            e: &e,
            image: est.images_of_camera(i),
            size,
            scale: 1.0,
        };
        let image = frames.image(format!("camera_{name}"), "√radiance");
        let mut names = image.exr_names();
        images.push(image);
        let mut derivatives = std::collections::BTreeMap::new();
        for (j, p) in scene.derivatives.iter().enumerate() {
            let layout = est.camera_derivative(i, j);
            let frames = Frames {
                image: layout,
                ..frames
            };
            let mut image = frames.image(
                format!("camera_{name}_d_{}", file_name(&p.name())),
                "∂radiance",
            );
            image.signed = true;
            names.extend(image.exr_names());
            images.push(image);
            derivatives.insert(p.name(), scaled(layout.total(), scale));
        }
        (names, derivatives)
    };
    let filter = |f: Filter| (f == Filter::Tent).then(|| "tent".to_string());
    // camera `i`'s windows, their sums times `scale` (as its total's), each with a summary line
    let windows = |i: usize,
                   scale: f64,
                   orthographic: bool,
                   summary: &mut Vec<String>|
     -> Vec<WindowRecord> {
        let height = scene.camera_pixels(i)[1];
        let windows = scene.camera_windows(i).iter().enumerate();
        windows
            .map(|(k, w)| {
                let sum = scaled(est.window_total(i, k), scale);
                summary.push(format!(
                    "  window {} {:.4e} ± {:.1e}",
                    w.name, sum.mean, sum.stderr
                ));
                WindowRecord {
                    name: w.name.clone(),
                    columns: w.columns,
                    rows: [height - 1 - w.rows[1], height - 1 - w.rows[0]],
                    intensity: orthographic.then_some(sum),
                    irradiance: (!orthographic).then_some(sum),
                    derivatives: scene
                        .derivatives
                        .iter()
                        .enumerate()
                        .map(|(j, p)| (p.name(), scaled(est.window_derivative(i, k, j), scale)))
                        .collect(),
                }
            })
            .collect()
    };
    // camera `i`'s total by bidirectional strategy, times `scale` (as its total's), and a
    // summary line naming the one with the largest share of the variance
    let strategies = |i: usize,
                      scale: f64,
                      orthographic: bool,
                      summary: &mut Vec<String>|
     -> Vec<StrategyRecord> {
        if scene.tracing != crate::rrte::Tracing::Bidirectional {
            return Vec::new();
        }
        let events = (1..=STRATEGY_EVENTS).flat_map(|k| (0..=k).map(move |s| (k, Some(s))));
        let records: Vec<StrategyRecord> = events
            .chain([(STRATEGY_EVENTS + 1, None)])
            .map(|(k, s)| {
                let total = scaled(est.strategy_total(i, k, s.unwrap_or(0)), scale);
                StrategyRecord {
                    events: k,
                    from_light: s,
                    intensity: orthographic.then_some(total),
                    irradiance: (!orthographic).then_some(total),
                }
            })
            .collect();
        let error = |r: &StrategyRecord| r.intensity.or(r.irradiance).map_or(0.0, |m| m.stderr);
        let variance: f64 = records.iter().map(|r| error(r).powi(2)).sum();
        if let Some(most) = records
            .iter()
            .max_by(|a, b| error(a).total_cmp(&error(b)))
            .filter(|_| variance > 0.0)
        {
            let k = most.events;
            let which = match most.from_light {
                Some(s) => format!(
                    "{k} event{}, {s} from the light",
                    if k == 1 { "" } else { "s" }
                ),
                None => format!("{k} or more events"),
            };
            summary.push(format!(
                "  most of the variance: {which} ({:.0} %)",
                100.0 * error(most).powi(2) / variance
            ));
        }
        records
    };
    for (i, c) in scene.cameras.iter().enumerate() {
        let image = est.camera_image(i);
        let intensity = Measured {
            mean: e.mean[image.total()].re * c.pixel_area(),
            stderr: e.stderr[image.total()] * c.pixel_area(),
        };
        summary.push(format!(
            "{} intensity {:.4e} ± {:.1e}",
            c.name, intensity.mean, intensity.stderr
        ));
        let (names, derivatives) = camera_images(&c.name, i, c.pixels, c.pixel_area());
        let windows = windows(i, c.pixel_area(), true, &mut summary);
        let strategies = strategies(i, c.pixel_area(), true, &mut summary);
        cameras.push(CameraRecord {
            name: c.name.clone(),
            kind: "orthographic".into(),
            direction: Some(c.direction.to_array()),
            intensity: Some(intensity),
            position: None,
            irradiance: None,
            pixels: c.pixels,
            pixel_area: c.pixel_area(),
            pixel_noise: pixel_noise(&e, image),
            bright_pixel_noise: bright_pixel_noise(&e, image),
            files: names,
            filter: filter(c.filter),
            derivatives,
            windows,
            strategies,
        });
    }
    for (i, c) in scene.pinholes.iter().enumerate() {
        let image = est.pinhole_image(i);
        let irradiance = measured(image.total());
        summary.push(format!(
            "{} irradiance {:.4e} ± {:.1e}",
            c.name, irradiance.mean, irradiance.stderr
        ));
        let camera = scene.cameras.len() + i;
        let (names, derivatives) = camera_images(&c.name, camera, c.pixels, 1.0);
        let windows = windows(camera, 1.0, false, &mut summary);
        let strategies = strategies(camera, 1.0, false, &mut summary);
        cameras.push(CameraRecord {
            name: c.name.clone(),
            kind: "pinhole".into(),
            direction: None,
            intensity: None,
            position: Some(c.position.to_array()),
            irradiance: Some(irradiance),
            pixels: c.pixels,
            pixel_area: c.pixel_area(),
            pixel_noise: pixel_noise(&e, image),
            bright_pixel_noise: bright_pixel_noise(&e, image),
            files: names,
            filter: filter(c.filter),
            derivatives,
            windows,
            strategies,
        });
    }
    // path tracing from the cameras follows no light to the surfaces; bidirectional tracing's
    // light subpaths do
    let particles = scene.tracing == crate::rrte::Tracing::FromLight;
    let lit = scene.tracing != crate::rrte::Tracing::FromCameras;
    let surfaces: Vec<SurfaceRecord> = scene
        .surfaces
        .iter()
        .filter(|_| lit)
        .enumerate()
        .map(|(i, s)| {
            let incident = measured(est.surface_power(i));
            summary.push(format!(
                "{} incident {:.4} ± {:.4}",
                s.name, incident.mean, incident.stderr
            ));
            SurfaceRecord {
                name: s.name.clone(),
                albedo: s.albedo,
                absorbed: Measured {
                    mean: incident.mean * (1.0 - s.albedo),
                    stderr: incident.stderr * (1.0 - s.albedo),
                },
                incident,
            }
        })
        .collect();
    let total = |t: Total| e.mean[est.total(t)].re;
    let connects =
        !(scene.probes.is_empty() && scene.cameras.is_empty() && scene.pinholes.is_empty());
    let connections = connects.then(|| {
        let asked = total(Total::Connections);
        let found = total(Total::Connected);
        let solves = total(Total::Solves);
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        ConnectionStatistics {
            mode: match scene.connections {
                crate::rrte::Connections::Unbiased => "unbiased",
                crate::rrte::Connections::First => "first",
            }
            .into(),
            per_photon: asked,
            success_rate: ratio(found, asked),
            solves_per_connection: ratio(solves, asked),
            iterations_per_solve: ratio(total(Total::Iterations), solves),
            distinct_paths: ratio(total(Total::Distinct), found),
        }
    });
    let events = e.mean[est.total(Total::Events)].re;
    let steps = e.mean[est.total(Total::Steps)].re;
    let timed = seconds.is_finite().then_some(seconds);
    let power = |t: Total| particles.then(|| measured(est.total(t)));
    let file = RenderFile {
        format_version: crate::io::results::FORMAT_VERSION,
        estimator: match scene.tracing {
            crate::rrte::Tracing::FromLight => "particle_tracing",
            crate::rrte::Tracing::FromCameras => "path_tracing",
            crate::rrte::Tracing::Bidirectional => "bidirectional",
        }
        .into(),
        samples: plan.samples(),
        seed: plan.seed,
        chunk: plan.chunk_paths,
        sensors,
        probes,
        targets,
        cameras,
        channels: if scene.channels() == 3 {
            RGB.0.to_vec()
        } else {
            MONO.0.to_vec()
        }
        .into_iter()
        .map(String::from)
        .collect(),
        surfaces,
        absorbed: power(Total::Absorbed),
        absorbed_by_surfaces: if scene.surfaces.is_empty() {
            None
        } else {
            power(Total::SurfaceAbsorbed)
        },
        escaped: power(Total::Escaped),
        unfinished: power(Total::Unfinished),
        statistics: RenderStatistics {
            events_per_photon: events,
            steps_per_photon: steps,
            connections,
            photons_per_second: timed.map(|t| plan.samples() as f64 / t),
            steps_per_second: timed.map(|t| steps * plan.samples() as f64 / t),
        },
        seconds: timed,
        version: env!("CARGO_PKG_VERSION").into(),
        config: task.config.clone(),
    };
    let unfinished = file.unfinished.map_or(0.0, |u| u.mean);
    let warning = (unfinished > 1e-3).then(|| {
        format!(
            "warning: {unfinished:.2e} of the power was given up (photons trapped past render.max_steps steps in one flight, or reflected inside the surface {MAX_REFLECTIONS} times between two events: light held by total internal reflection in a nearly clear volume); raise render.max_steps, check the field, or give the medium some absorption"
        )
    });
    let summary = format!(
        "rendered {} {} ({:.2} events, {:.0} steps each): {}{}{}",
        plan.samples(),
        match scene.tracing {
            crate::rrte::Tracing::FromLight => "photons",
            crate::rrte::Tracing::FromCameras => "camera paths",
            crate::rrte::Tracing::Bidirectional =>
                "bidirectional samples (light and camera subpaths)",
        },
        events,
        steps,
        if summary.is_empty() {
            "no sensors or probes".into()
        } else {
            summary.join(", ")
        },
        match (file.absorbed, file.escaped) {
            (Some(a), Some(e)) => format!("; absorbed {:.4}, escaped {:.4}", a.mean, e.mean),
            _ => String::new(),
        },
        timed.map_or(String::new(), |t| format!(" in {t:.1} s"))
    );
    Ok(Rendered {
        file,
        images,
        summary,
        warning,
    })
}

impl Rendered {
    /// Write render.json and every image's EXR files and PNG preview into `out` (which must
    /// exist).
    pub fn write(&self, out: &Path) -> Result<Outcome> {
        let path = out.join(RenderFile::NAME);
        self.file.write(&path)?;
        let mut files = vec![path];
        for image in &self.images {
            image.write(out, &mut files)?;
        }
        Ok(Outcome {
            not_converged: None,
            files,
            summary: self.summary.clone(),
        })
    }
}

/// The frames of one image (a screen or a camera) in an estimate, scaled by `scale` (`1/area`
/// turns a screen's power per pixel into irradiance).
struct Frames<'a> {
    e: &'a Estimate,
    image: ImageLayout,
    size: [usize; 2],
    scale: f64,
}

/// A parameter's name as part of a file name: `bin[0][3]` → `bin_0_3`.
fn file_name(param: &str) -> String {
    param.replace('[', "_").replace(']', "")
}

/// The EXR channel names of an image's planes and of their standard errors.
const MONO: ([&str; 1], [&str; 1]) = (["Y"], ["stderr"]);
const RGB: ([&str; 3], [&str; 3]) = (["R", "G", "B"], ["stderr.R", "stderr.G", "stderr.B"]);

impl Frames<'_> {
    /// The image's planes (top row first: the estimate holds rows from the bottom, along the
    /// sensor's or camera's up axis; EXR viewers show row 0 on top).
    fn image(&self, stem: String, label: &'static str) -> Image {
        let [w, h] = self.size;
        let n = w * h;
        let frame = |bin: Option<usize>| -> Vec<(Vec<f64>, Vec<f64>)> {
            (0..self.image.channels)
                .map(|c| {
                    let at = self.image.plane(bin, c);
                    let top_down = |k: usize| at + (h - 1 - k / w) * w + k % w;
                    (
                        (0..n)
                            .map(|k| self.e.mean[top_down(k)].re * self.scale)
                            .collect(),
                        (0..n)
                            .map(|k| self.e.stderr[top_down(k)] * self.scale)
                            .collect(),
                    )
                })
                .collect()
        };
        let bins = self.image.bins;
        Image {
            stem,
            label,
            width: w,
            height: h,
            total: frame(None),
            bins: if bins > 1 {
                (0..bins).map(|b| frame(Some(b))).collect()
            } else {
                vec![]
            },
            signed: false,
        }
    }
}

impl Image {
    /// The EXR files the image writes, the time-integrated one first.
    pub fn exr_names(&self) -> Vec<String> {
        std::iter::once(format!("{}.exr", self.stem))
            .chain((0..self.bins.len()).map(|b| format!("{}_t{b:04}.exr", self.stem)))
            .collect()
    }

    /// Write `<stem>.exr` (the time-integrated image with its standard error: channels `Y`,
    /// `stderr`, or `R`, `G`, `B` and `stderr.R`… in colour), with time bins one
    /// `<stem>_t<bin>.exr` per bin, and a preview `<stem>.png` (square root of the values,
    /// sRGB-encoded in colour); adds the integrated EXR and the PNG to `files`.
    fn write(&self, out: &Path, files: &mut Vec<std::path::PathBuf>) -> Result<()> {
        let (w, h) = (self.width, self.height);
        let n = w * h;
        let channels = self.total.len();
        let (names, errors): (&[&str], &[&str]) = if channels == 3 {
            (&RGB.0, &RGB.1)
        } else {
            (&MONO.0, &MONO.1)
        };
        let write = |name: &str, planes: &[(Vec<f64>, Vec<f64>)]| -> Result<()> {
            let mut list: Vec<(&str, &[f64])> = Vec::new();
            for (c, (v, se)) in planes.iter().enumerate() {
                list.push((names[c], v));
                list.push((errors[c], se));
            }
            crate::io::exr::write_planes(&out.join(name), &list, w, h)
        };
        let exr = self.exr_names();
        write(&exr[0], &self.total)?;
        files.push(out.join(&exr[0]));
        for (name, frame) in exr[1..].iter().zip(&self.bins) {
            write(name, frame)?;
        }
        // the preview's white: the 99.5th percentile, so that a few bright pixels (a point light
        // seen directly, fireflies) do not leave the rest black; of the magnitude when signed
        let mut sorted: Vec<f64> = self
            .total
            .iter()
            .flat_map(|(v, _)| v.iter().map(|x| if self.signed { x.abs() } else { *x }))
            .collect();
        sorted.sort_by(f64::total_cmp);
        let max = sorted
            .get((sorted.len() as f64 * 0.995) as usize)
            .or(sorted.last())
            .copied()
            .unwrap_or(0.0)
            .max(0.0);
        // the plot's rows run upwards from its bottom: back to the images' own order
        let at = |k: usize| (h - 1 - k / w) * w + k % w;
        let scaled = |v: f64| match (max > 0.0, self.signed) {
            (false, signed) => 0.5 * f64::from(u8::from(signed)),
            (true, false) => (v / max).max(0.0).sqrt(),
            (true, true) => 0.5 + 0.5 * (v / max).clamp(-1.0, 1.0),
        };
        let png = out.join(format!("{}.png", self.stem));
        let title = if self.signed {
            format!("{}, ±{max:.2e}, 0 grey", self.label)
        } else {
            format!("{}, white at {max:.2e}", self.label)
        };
        if channels == 3 {
            let rgb: Vec<[f64; 3]> = (0..n)
                .map(|k| [0, 1, 2].map(|c| scaled(self.total[c].0[at(k)])))
                .collect();
            crate::io::plot::colour_image(&png, &title, &self.stem, &rgb, w, h)?;
        } else {
            let preview: Vec<f64> = (0..n).map(|k| scaled(self.total[0].0[at(k)])).collect();
            crate::io::plot::heat_maps(&png, &title, &[(self.stem.clone(), preview)], w, h)?;
        }
        files.push(png);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::C64;

    #[test]
    fn pixel_noise_over_lit_and_over_bright_pixels() {
        // 200 pixels: three bright (relative errors 1 %, 2 %, 5 %), two faint (100 %), the rest
        // unlit; then a halo of 100 faint pixels lit as well
        let image = ImageLayout {
            first: 0,
            pixels: 200,
            channels: 1,
            bins: 1,
        };
        let estimate = |pixels: &[(f64, f64)]| {
            let mut e = Estimate {
                mean: vec![C64::new(0.0, 0.0); 200],
                stderr: vec![0.0; 200],
                samples: 1,
                chunks: 1,
            };
            for (k, &(mean, stderr)) in pixels.iter().enumerate() {
                (e.mean[k], e.stderr[k]) = (C64::new(mean, 0.0), stderr);
            }
            e
        };
        let mut pixels = vec![
            (100.0, 1.0),
            (90.0, 1.8),
            (80.0, 4.0),
            (0.5, 0.5),
            (0.2, 0.2),
        ];
        let e = estimate(&pixels);
        assert_eq!(pixel_noise(&e, image), Some(0.05));
        assert_eq!(bright_pixel_noise(&e, image), Some(0.02));
        pixels.extend([(0.01, 0.01); 100]);
        let halo = estimate(&pixels);
        assert_eq!(pixel_noise(&halo, image), Some(1.0));
        assert_eq!(bright_pixel_noise(&halo, image), Some(0.02));
        let dark = estimate(&[]);
        assert_eq!(
            (pixel_noise(&dark, image), bright_pixel_noise(&dark, image)),
            (None, None)
        );
    }
}
