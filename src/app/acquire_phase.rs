//! `lightpath acquire-phase`: the phase function read from speckle images of a slab under tilted
//! illuminations (paper 004) → `phase_acquisition.json` + `phase_acquisition.png`; with `[fit]`,
//! also `fit_scene.toml` + `fit_target.json`, the readings as a target of `lightpath fit` (thick
//! samples, where the single-scattering reading is biased).

use super::{Outcome, create_out};
use crate::config::AcquireConfig;
use crate::config::acquire::HandoffConfig;
use crate::config::{LightConfig, ViewConfig};
use crate::error::{Error, Result};
use crate::inverse::phase_from_speckle::{
    Curve, PairError, correlation_points, fit_hg, fit_vmf, flatness, hg, read_curves, significant,
};
use crate::io::ResultFile;
use crate::io::images::{Image, read_image};
use crate::io::results::{
    AcquiredCurve, AcquiredReading, Consistency, HgRecord, PhaseAcquisitionFile, VmfRecord,
};
use glam::DVec3;
use std::path::Path;

/// Read the images, compute the curves and fits, write the results into `out`.
pub fn run(config: &AcquireConfig, out: &Path) -> Result<Outcome> {
    let file = acquire(config)?;
    create_out(
        out,
        &[
            "phase_acquisition.json",
            "phase_acquisition.png",
            SCENE,
            TARGET,
        ],
    )?;
    write(&file, out)
}

/// Read the images and compute the correlation curves and their fits.
pub fn acquire(config: &AcquireConfig) -> Result<PhaseAcquisitionFile> {
    let start = std::time::Instant::now();
    let mut images: Vec<[Image; 2]> = Vec::with_capacity(config.pair.len());
    for p in &config.pair {
        images.push([read_image(&p.first)?, read_image(&p.second)?]);
    }
    let first = &images[0][0];
    let centre = [
        0.5 * (first.width as f64 - 1.0),
        0.5 * (first.height as f64 - 1.0),
    ];
    let (relay, settings) = config.relay_and_settings(centre)?;
    for (i, [a, b]) in images.iter().enumerate() {
        for (im, f) in [(a, &config.pair[i].first), (b, &config.pair[i].second)] {
            if (im.width, im.height) != (first.width, first.height) {
                return Err(Error::input(format!(
                    "pair[{i}]: {} is {}×{} but {} is {}×{}; every image must have the same size",
                    f.display(),
                    im.width,
                    im.height,
                    config.pair[0].first.display(),
                    first.width,
                    first.height
                )));
            }
        }
    }
    let mut warnings = Vec::new();
    let pairs: Vec<crate::inverse::phase_from_speckle::Pair> = images
        .iter()
        .enumerate()
        .map(|(i, [a, b])| crate::inverse::phase_from_speckle::Pair {
            first: a,
            second: b,
            peaks: peaks(config, i, [a, b], &mut warnings),
        })
        .collect();
    let curves = read_curves(&pairs, &relay, &settings).map_err(|(i, e)| {
        let p = &config.pair[i];
        let [p1, p2] = pairs[i].peaks;
        Error::input(match e {
            PairError::Sizes => format!(
                "pair[{i}]: {} and {} differ in size",
                p.first.display(),
                p.second.display()
            ),
            PairError::NoDisplacement if p.source_shift.is_some() => format!(
                "pair[{i}].source_shift = {:?} moves the illumination by less than a pixel ({p1:?} → {p2:?}): the correlation reading needs two illuminations Δ ≠ 0 apart",
                p.source_shift.unwrap_or_default()
            ),
            PairError::NoDisplacement => format!(
                "pair[{i}]: the illuminations coincide (ballistic peaks at {p1:?} in {} and {p2:?} in {}): the correlation reading needs two illuminations Δ ≠ 0 apart (give pair[{i}].peaks if the brightest pixels are not the ballistic peaks)",
                p.first.display(),
                p.second.display()
            ),
            PairError::Saturated { image, count } => format!(
                "pair[{i}]: {} has {count} saturated pixel(s) inside the windows read; lower the exposure or widen acquisition.ballistic_radius",
                if image == 0 { &p.first } else { &p.second }.display()
            ),
            PairError::NoWindows => format!(
                "pair[{i}]: no {}-pixel window fits inside both images along the line ⟂ Δ outside the ballistic disks; use a smaller acquisition.window or ballistic_radius",
                settings.window
            ),
        })
    })?;
    let mut records: Vec<AcquiredCurve> = curves.iter().map(|c| record(c, &settings)).collect();
    // sort by displacement: the largest last
    records.sort_by(|a, b| a.delta_deg.total_cmp(&b.delta_deg));
    let consistency = consistency(&records);
    Ok(PhaseAcquisitionFile {
        format_version: crate::io::results::FORMAT_VERSION,
        axis_px: relay.axis_px,
        warnings,
        curves: records,
        consistency,
        seconds: start.elapsed().as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").to_string(),
        config: config.clone(),
    })
}

/// The ballistic peaks of pair `i`: as given; or the first image's brightest pixel and, with a
/// `source_shift`, the second placed from it through the relay — noting in `warnings` when the
/// second image's brightest pixel is elsewhere (a flipped axis or a wrong focal length) —; else
/// both brightest pixels.
fn peaks(
    config: &AcquireConfig,
    i: usize,
    [a, b]: [&Image; 2],
    warnings: &mut Vec<String>,
) -> [[f64; 2]; 2] {
    use crate::inverse::phase_from_speckle::brightest;
    if let Some(p) = config.pair[i].peaks {
        return p;
    }
    let first = brightest(a);
    let Some(d) = config.source_delta_px(i) else {
        return [first, brightest(b)];
    };
    let second = [first[0] + d[0], first[1] + d[1]];
    let seen = brightest(b);
    let miss = (seen[0] - second[0]).hypot(seen[1] - second[1]);
    if miss > config.acquisition.ballistic_radius.max(3.0) {
        warnings.push(format!(
            "pair[{i}]: source_shift puts the second illumination at {second:?} but the brightest pixel of {} is at {seen:?} ({miss:.0} px away); check the stage's axes against the sensor's and acquisition.source_focal_length",
            config.pair[i].second.display()
        ));
    }
    [first, second]
}

/// Write phase_acquisition.json and its plot into `out` (which must exist).
pub fn write(file: &PhaseAcquisitionFile, out: &Path) -> Result<Outcome> {
    // the hand-off first: a scene it cannot use stops the command before any file is written
    let handoff = file
        .config
        .fit
        .as_ref()
        .map(|fit| handoff(file, fit))
        .transpose()?;
    let json = out.join(PhaseAcquisitionFile::NAME);
    let png = out.join("phase_acquisition.png");
    file.write(&json)?;
    plot(file, &png)?;
    let mut files = vec![json, png];
    if let Some((scene, target)) = handoff {
        for (name, text) in [(SCENE, scene), (TARGET, target)] {
            let path = out.join(name);
            crate::io::write_atomic(&path, text.as_bytes()).map_err(|source| Error::Io {
                action: "write",
                path: path.clone(),
                source,
            })?;
            files.push(path);
        }
    }
    let mut summary = String::new();
    for w in &file.warnings {
        summary += &format!("warning: {w}\n");
    }
    for c in &file.curves {
        let (fit, naive) = (c.hg.as_ref(), c.hg_intensity.as_ref());
        summary += &format!(
            "Δ = {:.3}° ({} pair(s), {} readings {:.2}°–{:.2}°): {}{}\n",
            c.delta_deg,
            c.pairs,
            c.readings.len(),
            c.readings
                .iter()
                .map(|r| r.reading.angle_deg)
                .fold(f64::INFINITY, f64::min),
            c.readings
                .iter()
                .map(|r| r.reading.angle_deg)
                .fold(0.0, f64::max),
            match (c.significant, fit) {
                (false, _) => format!(
                    "no significant correlation (χ² {:.1} over {} readings): the reading is flat, consistent with noise",
                    c.chi2_flat, c.dof
                ),
                (true, Some(f)) => format!("correlation g = {:.4} ± {:.4}", f.g, f.g_stderr),
                (true, None) => "too few readings to fit".to_string(),
            },
            naive
                .map(|n| format!(", intensity g = {:.4}", n.g))
                .unwrap_or_default()
        );
    }
    if let Some(c) = &file.consistency {
        summary += &format!(
            "the two largest displacements {} (χ² {:.1} over {})",
            if c.consistent {
                "agree: single scattering isolated"
            } else {
                "disagree: multiple scattering still correlates; use larger Δ"
            },
            c.chi2,
            c.dof
        );
    }
    if file.config.fit.is_some() {
        summary += &format!(
            "\nfit on: lightpath fit {} --target {} --fit mfp,g",
            out.join(SCENE).display(),
            out.join(TARGET).display()
        );
    }
    Ok(Outcome {
        files,
        summary: summary.trim_end().to_string(),
        not_converged: None,
    })
}

/// The readings of one displacement, with the fits.
fn record(c: &Curve, s: &crate::inverse::phase_from_speckle::Settings) -> AcquiredCurve {
    let (chi2, dof) = flatness(c);
    let sig = significant(c, s);
    let (mu, y, sd) = correlation_points(c);
    let hg_fit = if sig { fit_hg(&mu, &y, &sd, 2) } else { None };
    // the naive reading's error: ⟨I⟩ / √(pairs · N / grain) (speckle statistics)
    let n = (s.window * s.window) as f64;
    let naive_y: Vec<f64> = c.readings.iter().map(|r| r.intensity).collect();
    let naive_sd: Vec<f64> = c
        .readings
        .iter()
        .map(|r| r.intensity / (r.pairs as f64 * n / c.grain_px).sqrt())
        .collect();
    let naive = fit_hg(&mu, &naive_y, &naive_sd, 1);
    // vMF lobes on the amplitude √C where C is clearly positive
    let strong: Vec<usize> = (0..y.len()).filter(|&i| y[i] > 2.0 * sd[i]).collect();
    let vmf = sig
        .then(|| {
            fit_vmf(
                &strong.iter().map(|&i| mu[i]).collect::<Vec<_>>(),
                &strong.iter().map(|&i| y[i].sqrt()).collect::<Vec<_>>(),
                &strong
                    .iter()
                    .map(|&i| sd[i] / (2.0 * y[i].sqrt()))
                    .collect::<Vec<_>>(),
            )
        })
        .flatten();
    let readings = c
        .readings
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let rho = hg_fit
                .filter(|f| f.scale > 0.0 && r.correlation > 0.0)
                .map(|f| {
                    (
                        (r.correlation / f.scale).sqrt(),
                        r.stderr / (2.0 * (r.correlation * f.scale).sqrt()),
                    )
                });
            AcquiredReading {
                reading: *r,
                rho: rho.map(|x| x.0),
                rho_stderr: rho.map(|x| x.1),
                rho_intensity: naive
                    .filter(|f| f.scale > 0.0)
                    .map(|f| naive_y[i] / f.scale),
            }
        })
        .collect();
    let hg_record = |f: crate::inverse::phase_from_speckle::HgFit| HgRecord {
        g: f.g,
        g_stderr: f.g_stderr,
        chi2_dof: f.chi2_dof,
    };
    AcquiredCurve {
        first_px: c.first_px,
        delta_px: c.delta_px,
        delta_deg: c.delta_deg,
        grain_px: c.grain_px,
        pairs: c.readings.iter().map(|r| r.pairs).max().unwrap_or(0),
        chi2_flat: chi2,
        dof,
        significant: sig,
        readings,
        hg: hg_fit.map(hg_record),
        vmf: vmf.map(|v| VmfRecord {
            weights: v.weights,
            kappas: v.kappas,
            chi2_dof: v.chi2_dof,
        }),
        hg_intensity: naive.map(hg_record),
    }
}

/// χ² between the correlations of the two largest displacements at common offsets: under Claim 1
/// (τ ⟂ Δ) single scattering does not depend on Δ, so agreement means it is isolated.
fn consistency(curves: &[AcquiredCurve]) -> Option<Consistency> {
    let n = curves.len();
    if n < 2 || !curves[n - 1].significant {
        return None;
    }
    let (a, b) = (&curves[n - 2], &curves[n - 1]);
    let (mut chi2, mut dof) = (0.0, 0);
    for r in &a.readings {
        if let Some(q) = b
            .readings
            .iter()
            .find(|q| (q.reading.offset_px - r.reading.offset_px).abs() < 0.5)
        {
            chi2 += (r.reading.correlation - q.reading.correlation).powi(2)
                / (r.reading.stderr.powi(2) + q.reading.stderr.powi(2));
            dof += 1;
        }
    }
    (dof > 0).then(|| Consistency {
        curves: [n - 2, n - 1],
        chi2,
        dof,
        consistent: chi2 < dof as f64 + 3.0 * (2.0 * dof as f64).sqrt(),
    })
}

/// `ρ` read from each displacement (on its HG's scale, ±1 sd), the naive reading of the largest
/// and the fitted HG, against angle (log scale); the raw correlations when nothing is significant.
fn plot(file: &PhaseAcquisitionFile, path: &Path) -> Result<()> {
    let mut points: Vec<crate::io::plot::PointSet> = Vec::new();
    let mut curves: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for c in &file.curves {
        let pts: Vec<(f64, f64, f64)> = c
            .readings
            .iter()
            .filter_map(|r| Some((r.reading.angle_deg, r.rho?, r.rho_stderr?)))
            .collect();
        if !pts.is_empty() {
            points.push((format!("correlation, Δ = {:.2}°", c.delta_deg), pts));
        }
    }
    if let Some(c) = file.curves.last() {
        let mut naive: Vec<(f64, f64)> = c
            .readings
            .iter()
            .filter_map(|r| r.rho_intensity.map(|v| (r.reading.angle_deg, v)))
            .collect();
        // readings at ±τ share an angle: one point, their mean
        naive.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut merged: Vec<(f64, f64, f64)> = Vec::new();
        for (x, y) in naive {
            match merged.last_mut() {
                Some(m) if (m.0 - x).abs() < 1e-3 => {
                    m.1 += y;
                    m.2 += 1.0;
                }
                _ => merged.push((x, y, 1.0)),
            }
        }
        let naive: Vec<(f64, f64)> = merged.into_iter().map(|m| (m.0, m.1 / m.2)).collect();
        if !naive.is_empty() {
            curves.push(("intensity (naive reading)".to_string(), naive));
        }
        if let Some(f) = &c.hg {
            let top = c
                .readings
                .iter()
                .map(|r| r.reading.angle_deg)
                .fold(0.0, f64::max);
            let line = (0..=100)
                .map(|i| {
                    let t = top * i as f64 / 100.0;
                    (t, hg(f.g, t.to_radians().cos()))
                })
                .collect();
            curves.push((format!("HG fit, g = {:.4}", f.g), line));
        }
    }
    if points.is_empty() {
        let series: Vec<(String, Vec<(f64, f64)>)> = file
            .curves
            .iter()
            .map(|c| {
                let mut v: Vec<(f64, f64)> = c
                    .readings
                    .iter()
                    .map(|r| (r.reading.offset_px, r.reading.correlation))
                    .collect();
                v.sort_by(|a, b| a.0.total_cmp(&b.0));
                (format!("C(τ), Δ = {:.2}°", c.delta_deg), v)
            })
            .collect();
        return crate::io::plot::lines(
            path,
            "speckle correlation: no significant reading",
            "offset along τ (pixels)",
            "C(τ)",
            &series,
            false,
        );
    }
    crate::io::plot::points_and_lines(
        path,
        "phase function from speckle correlations",
        "scattering angle in the sample (deg)",
        "ρ (1/sr)",
        &points,
        &curves,
    )
}

/// The hand-off files' names.
const SCENE: &str = "fit_scene.toml";
const TARGET: &str = "fit_target.json";

/// The readings as a `lightpath fit` target and the scene to fit it on: the sample's scene with
/// one plane-wave light per illumination and far-field views at `window_points²` Gauss–Legendre
/// points of every window (both images), all directions inside the sample; each reading whose
/// window overlaps no earlier one becomes a normalised intensity correlation over its window's
/// view pairs (Eq. 4 over the window means, which the camera's scale does not enter).
fn handoff(file: &PhaseAcquisitionFile, fit: &HandoffConfig) -> Result<(String, String)> {
    let path = std::path::absolute(&fit.scene)
        .map_err(|e| Error::input(format!("fit.scene = {}: {e}", fit.scene.display())))?;
    let text = std::fs::read_to_string(&path).map_err(|source| Error::Io {
        action: "read",
        path: path.clone(),
        source,
    })?;
    let mut value: toml::Value = toml::from_str(&text)
        .map_err(|e| Error::input(format!("fit.scene {}: invalid TOML: {e}", path.display())))?;
    let (relay, settings) = file
        .config
        .relay_and_settings(file.axis_px)
        .map_err(|e| Error::input(e.0))?;
    let (nodes, _) = crate::math::gauss_legendre(fit.window_points as usize);
    fn index(list: &mut Vec<DVec3>, d: DVec3) -> usize {
        list.iter()
            .position(|x| (*x - d).length() < 1e-12)
            .unwrap_or_else(|| {
                list.push(d);
                list.len() - 1
            })
    }
    let (mut lights, mut views, mut entries) = (Vec::new(), Vec::new(), Vec::new());
    let w = settings.window as f64;
    let half = (settings.window / 2) as f64;
    for c in &file.curves {
        let (p1, d) = (c.first_px, c.delta_px);
        let l1 = index(&mut lights, relay.direction(p1[0], p1[1]));
        let l2 = index(&mut lights, relay.direction(p1[0] + d[0], p1[1] + d[1]));
        let norm = d[0].hypot(d[1]);
        let u = [-d[1] / norm, d[0] / norm];
        // a window without light (both means 0) has no normalised reading
        let usable = |r: &&AcquiredReading| {
            r.reading.normalised.is_finite()
                && r.reading.normalised_stderr.is_finite()
                && r.reading.normalised_stderr > 0.0
        };
        // windows that share no pixel, so the entries' errors are independent (overlapping
        // readings would count the same speckles twice and shrink the fit's error bars)
        let mut last: Option<[f64; 2]> = None;
        for r in c.readings.iter().filter(usable) {
            let t = r.reading.offset_px;
            // the window as the reading placed it: pixels c − half … c − half + w − 1
            let centre = [(p1[0] + t * u[0]).round(), (p1[1] + t * u[1]).round()];
            if last.is_some_and(|l| (centre[0] - l[0]).abs().max((centre[1] - l[1]).abs()) < w) {
                continue;
            }
            last = Some(centre);
            let lo = [centre[0] - half - 0.5, centre[1] - half - 0.5];
            let mut pairs = Vec::new();
            for gy in &nodes {
                for gx in &nodes {
                    let (x, y) = (lo[0] + 0.5 * w * (gx + 1.0), lo[1] + 0.5 * w * (gy + 1.0));
                    let v1 = index(&mut views, relay.direction(x, y));
                    let v2 = index(&mut views, relay.direction(x + d[0], y + d[1]));
                    pairs.push([v1, v2]);
                }
            }
            entries.push(serde_json::json!({
                "light": [l1, l2],
                "views": pairs,
                "normalised_intensity_correlation": r.reading.normalised,
                "stderr": r.reading.normalised_stderr,
            }));
        }
    }
    // the sample's scene with these lights and views, checked by the one loader
    let lights: Vec<LightConfig> = lights
        .iter()
        .map(|d| LightConfig::PlaneWave {
            direction: d.to_array(),
        })
        .collect();
    let views: Vec<ViewConfig> = views
        .iter()
        .map(|d| ViewConfig::FarField {
            direction: d.to_array(),
        })
        .collect();
    let table = value
        .as_table_mut()
        .ok_or_else(|| Error::input(format!("fit.scene {}: not a table", path.display())))?;
    for (key, list) in [
        ("light", toml::Value::try_from(&lights)),
        ("view", toml::Value::try_from(&views)),
    ] {
        table.insert(key.into(), list.map_err(|e| Error::input(e.to_string()))?);
    }
    let base = path.parent().unwrap_or(Path::new("/"));
    let cfg = crate::config::load_value(value, base)
        .and_then(|t| t.into_scene("fit.scene"))
        .map_err(|e| Error::input(format!("fit.scene {}: {}", path.display(), e.0)))?
        .config;
    let scene = toml::to_string(&cfg)
        .map_err(|e| Error::input(format!("fit.scene: cannot write it back: {e}")))?;
    let target = serde_json::to_string_pretty(&serde_json::json!({ "entries": entries }))
        .map_err(|e| Error::input(e.to_string()))?;
    Ok((scene, target))
}
