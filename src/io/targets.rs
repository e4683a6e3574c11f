//! Reading fit targets from files: our `covariance.json` (through its typed format) and
//! `memory_effect.json`, a measured memory curve as JSON or CSV (`angle_deg,correlation[,stderr]`),
//! or measured entries (`{"entries": [...]}`); see [`crate::inverse::target`] for what they mean.

use crate::inverse::target::{Entry, Measured, Target};
use crate::math::C64;
use serde_json::Value;
use std::path::Path;

fn floats(v: &Value, key: &str, path: &Path) -> crate::Result<Vec<f64>> {
    v[key]
        .as_array()
        .ok_or_else(|| format!("{}: missing array {key:?}", path.display()))?
        .iter()
        .map(|x| {
            x.as_f64().ok_or_else(|| {
                crate::Error::input(format!("{}: {key} holds a non-number", path.display()))
            })
        })
        .collect()
}

/// Read a target file (format by content: covariance.json, memory curve JSON, or CSV). A file
/// whose first character is `{` or `[` is JSON, and a malformed one is reported with its line and
/// column rather than read as CSV.
pub fn read(path: &Path) -> crate::Result<Target> {
    let text = std::fs::read_to_string(path).map_err(|source| crate::Error::Io {
        action: "read target",
        path: path.to_path_buf(),
        source,
    })?;
    let json = text.trim_start().starts_with(['{', '[']);
    let parsed = if json {
        Some(
            serde_json::from_str::<Value>(&text)
                .map_err(|e| format!("target {}: not valid JSON: {e}", path.display()))?,
        )
    } else {
        None
    };
    let t = if let Some(v) = parsed {
        if v.get("entries").is_some() {
            entries_json(&v, path)?
        } else if ["re", "im", "stderr", "mean_re", "mean_im"]
            .iter()
            .any(|k| v.get(*k).is_some())
        {
            // a covariance.json, read through its type so a missing or malformed key is named
            covariance_json(path)?
        } else {
            let angles_deg = floats(&v, "angles_deg", path)?;
            let correlation = floats(&v, "correlation", path)?;
            let key = ["correlation_stderr", "stderr"]
                .into_iter()
                .find(|k| v.get(*k).is_some());
            let stderr = key.map(|k| floats(&v, k, path)).transpose()?;
            if let (Some(k), Some(s)) = (key, &stderr)
                && s.len() != angles_deg.len()
            {
                return Err(crate::Error::input(format!(
                    "{}: {k} has {} values for {} angles in angles_deg",
                    path.display(),
                    s.len(),
                    angles_deg.len()
                )));
            }
            if let (Some(k), Some(s)) = (key, &stderr)
                && let Some((i, x)) = s
                    .iter()
                    .enumerate()
                    .find(|(_, x)| !(**x > 0.0 && x.is_finite()))
            {
                return Err(crate::Error::input(format!(
                    "{}: {k}[{i}] = {x}: a standard error must be positive and finite",
                    path.display()
                )));
            }
            if let Some((i, c)) = correlation
                .iter()
                .enumerate()
                .find(|(_, c)| c.abs() > MAX_TARGET)
            {
                return Err(crate::Error::input(format!(
                    "{}: correlation[{i}] = {c:e}: must be within ±{MAX_TARGET:e}",
                    path.display()
                )));
            }
            Target::Memory {
                angles_deg,
                correlation,
                stderr,
            }
        }
    } else {
        csv(&text, path)?
    };
    t.validate(path)?;
    Ok(t)
}

/// Refuse a target rendered for another setup. Our result files echo the wavelength, lights and
/// views they were rendered with; those must agree with the scene the fit renders (to 1e-9
/// relative), since equal counts alone say nothing about the directions or positions behind each
/// index. Measured targets (CSV, entries, curves without an echo) pass.
pub fn check_setup(
    path: &Path,
    wavelength: f64,
    scene: &crate::speckle::Scene,
) -> crate::Result<()> {
    use crate::io::results::{light_record, view_record};
    let Some(v) = std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
    else {
        return Ok(());
    };
    let (Some(echoed), Some(lights), Some(views)) =
        (v.get("wavelength"), v.get("lights"), v.get("views"))
    else {
        return Ok(());
    };
    let lights_now: Vec<_> = scene.lights.iter().map(light_record).collect();
    let views_now: Vec<_> = scene.views.iter().map(view_record).collect();
    let expected = [
        ("wavelength", echoed, serde_json::json!(wavelength)),
        ("lights", lights, serde_json::json!(lights_now)),
        ("views", views, serde_json::json!(views_now)),
    ];
    for (key, got, want) in expected {
        if let Some((at, a, b)) = first_difference(key, got, &want) {
            return Err(crate::Error::input(format!(
                "target {} was rendered with {at} = {a}, but the fit's config gives {b}: fit with the setup the target was rendered with",
                path.display()
            )));
        }
    }
    Ok(())
}

/// The first place where two JSON values differ (numbers to 1e-9 relative), as `(key path, got,
/// expected)`.
fn first_difference(at: &str, got: &Value, want: &Value) -> Option<(String, String, String)> {
    let differ = || Some((at.to_string(), got.to_string(), want.to_string()));
    match (got, want) {
        (Value::Number(a), Value::Number(b)) => {
            let (a, b) = (a.as_f64()?, b.as_f64()?);
            ((a - b).abs() > 1e-9 * a.abs().max(b.abs()).max(1e-300)).then(differ)?
        }
        (Value::Array(a), Value::Array(b)) => {
            if a.len() != b.len() {
                return differ();
            }
            let inner = a
                .iter()
                .zip(b)
                .enumerate()
                .find_map(|(i, (x, y))| first_difference(&format!("{at}[{i}]"), x, y));
            // a vector of numbers is reported whole
            if inner.is_some() && a.iter().all(Value::is_number) {
                return differ();
            }
            inner
        }
        (Value::Object(a), Value::Object(b)) => {
            if a.len() != b.len() || a.keys().any(|k| !b.contains_key(k)) {
                return differ();
            }
            a.iter()
                .find_map(|(k, x)| first_difference(&format!("{at}.{k}"), x, &b[k]))
        }
        _ => (got != want).then(differ)?,
    }
}

/// A `correlation_map.json` read as a target: its `C(Δ_k, τ_p)` as field-covariance entries between
/// the map's pairs `(light 0, view p)` and `(light k, view k·T + p)` (the scene
/// [`crate::speckle::correlation_map::CorrelationMap`] builds from the same config), with the map's
/// shape `(shifts including 0, τ pixels)` to check against the fit's config.
pub struct MapTarget {
    pub target: Target,
    /// The shifts `Δ` (0 first) and the number of `τ` pixels.
    pub deltas: Vec<[f64; 3]>,
    pub pixels: usize,
}

/// Whether `path` holds a `correlation_map.json` (a C(Δ, τ) map rather than another target).
pub fn is_correlation_map(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .is_some_and(|v| v.get("deltas").is_some() && v.get("taus").is_some())
}

/// Read a `correlation_map.json` as a fit target (see [`MapTarget`]).
pub fn correlation_map(path: &Path) -> crate::Result<MapTarget> {
    use crate::io::results::{CorrelationMapFile, ResultFile};
    let m = CorrelationMapFile::read(path)?;
    let k = m.deltas.len();
    let flat = |a: &Vec<Vec<Vec<f64>>>| -> Vec<Vec<f64>> {
        a.iter()
            .map(|d| d.iter().flatten().copied().collect())
            .collect()
    };
    let (re, im, se) = (flat(&m.re), flat(&m.im), flat(&m.stderr));
    let t = re.first().map_or(0, Vec::len);
    if k == 0
        || t == 0
        || [&re, &im, &se]
            .iter()
            .any(|a| a.len() != k || a.iter().any(|d| d.len() != t))
    {
        return Err(format!(
            "{}: the map's re, im and stderr must each hold one τ grid per shift",
            path.display()
        )
        .into());
    }
    let (mut entries, mut stderr) = (Vec::new(), Vec::new());
    for d in 0..k {
        for p in 0..t {
            entries.push(Entry {
                light: [0, d],
                views: vec![[p, d * t + p]],
                value: Measured::Field(C64::new(re[d][p], im[d][p])),
            });
            stderr.push(se[d][p]);
        }
    }
    // entries whose Monte Carlo error is 0 (none sampled) carry no information: weight them by the
    // smallest positive error instead of refusing the map
    let floor = stderr
        .iter()
        .copied()
        .filter(|s| *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !floor.is_finite() {
        return Err(format!("{}: the map has no standard errors", path.display()).into());
    }
    stderr.iter_mut().for_each(|s| *s = s.max(floor));
    let target = Target::Entries {
        entries,
        stderr: Some(stderr),
    };
    target.validate(path)?;
    Ok(MapTarget {
        target,
        deltas: m.deltas,
        pixels: t,
    })
}

/// Our `covariance.json` (Monte Carlo or wave solver), read through its typed format.
fn covariance_json(path: &Path) -> crate::Result<Target> {
    use crate::io::results::{CovarianceFile, ResultFile};
    let m = CovarianceFile::read(path)?.matrix(path)?;
    let j = m.lights * m.views;
    let at = |i: usize| {
        let (a, b) = (i / j, i % j);
        let (l1, v1, l2, v2) = (a / m.views, a % m.views, b / m.views, b % m.views);
        format!("[{l1}][{l2}][{v1}][{v2}]")
    };
    if let Some(i) = m.stderr.iter().position(|s| !(*s >= 0.0 && s.is_finite())) {
        return Err(format!(
            "{}: stderr{} = {}: a standard error must be finite and ≥ 0",
            path.display(),
            at(i),
            m.stderr[i]
        )
        .into());
    }
    if let Some(i) = m
        .value
        .iter()
        .position(|z| !(z.re.abs() <= MAX_TARGET && z.im.abs() <= MAX_TARGET))
    {
        return Err(format!(
            "{}: re/im{} = {}: must be finite and within ±{MAX_TARGET:e}",
            path.display(),
            at(i),
            m.value[i]
        )
        .into());
    }
    // an entry no path reached has no error of its own: weight it like the best-known entry
    let floor = m
        .stderr
        .iter()
        .copied()
        .filter(|s| *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    let stderr = if floor.is_finite() {
        m.stderr.iter().map(|s| s.max(floor)).collect()
    } else {
        m.stderr
    };
    Ok(Target::Covariance {
        lights: m.lights,
        views: m.views,
        value: m.value,
        stderr,
    })
}

/// The largest magnitude a target value may have (squares of it must stay finite in the loss).
const MAX_TARGET: f64 = 1e100;

fn entries_json(v: &Value, path: &Path) -> crate::Result<Target> {
    let list = v["entries"]
        .as_array()
        .ok_or_else(|| format!("{}: `entries` is not an array", path.display()))?;
    let (mut entries, mut stderr) = (Vec::new(), Vec::new());
    for (i, e) in list.iter().enumerate() {
        let at = |what: &str| format!("{}: entries[{i}]: {what}", path.display());
        let two = |v: &Value| -> Option<[usize; 2]> {
            match v
                .as_array()
                .map(|a| a.iter().map(Value::as_u64).collect::<Vec<_>>())
            {
                Some(a) if a.len() == 2 && a.iter().all(Option::is_some) => {
                    Some([a[0].unwrap_or(0) as usize, a[1].unwrap_or(0) as usize])
                }
                _ => None,
            }
        };
        let index_pair = |key: &str| -> crate::Result<[usize; 2]> {
            two(&e[key])
                .ok_or_else(|| at(&format!("`{key}` must be two indices, e.g. [0, 1]")).into())
        };
        let num = |key: &str| {
            e.get(key).map(|x| {
                x.as_f64()
                    .ok_or_else(|| at(&format!("`{key}` is not a number")))
            })
        };
        let value = match (
            num("re"),
            num("im"),
            num("intensity_correlation"),
            num("normalised_intensity_correlation"),
        ) {
            (Some(re), Some(im), None, None) => Measured::Field(C64::new(re?, im?)),
            (None, None, Some(c), None) => Measured::Intensity(c?),
            (None, None, None, Some(c)) => Measured::Normalised(c?),
            _ => {
                return Err(crate::Error::input(at(
                    "give one of `re` and `im` (field covariance), `intensity_correlation` or `normalised_intensity_correlation`",
                )));
            }
        };
        // one view pair, or (normalised correlations) a window of them
        let views = match (e.get("view"), e.get("views")) {
            (Some(_), None) => vec![index_pair("view")?],
            (None, Some(list)) if matches!(value, Measured::Normalised(_)) => {
                let pairs: Option<Vec<[usize; 2]>> = list
                    .as_array()
                    .map(|a| a.iter().map(two).collect())
                    .unwrap_or(None);
                match pairs {
                    Some(p) if !p.is_empty() => p,
                    _ => {
                        return Err(crate::Error::input(at(
                            "`views` must be a non-empty list of index pairs, e.g. [[0, 1], [2, 3]]",
                        )));
                    }
                }
            }
            (None, Some(_)) => {
                return Err(crate::Error::input(at(
                    "`views` (a window of view pairs) goes with `normalised_intensity_correlation`; give one `view` pair",
                )));
            }
            _ => {
                return Err(crate::Error::input(at(
                    "give `view` (two indices) or, for a normalised correlation, `views`",
                )));
            }
        };
        if let Some(s) = num("stderr") {
            stderr.push(s?);
        }
        entries.push(Entry {
            light: index_pair("light")?,
            views,
            value,
        });
    }
    if entries.is_empty() {
        return Err(format!("{}: `entries` is empty", path.display()).into());
    }
    let stderr = match stderr.len() {
        0 => None,
        n if n == entries.len() => Some(stderr),
        _ => {
            return Err(format!(
                "{}: give a stderr on every entry or on none",
                path.display()
            )
            .into());
        }
    };
    Ok(Target::Entries { entries, stderr })
}

fn csv(text: &str, path: &Path) -> crate::Result<Target> {
    let (mut a, mut c, mut s) = (Vec::new(), Vec::new(), Vec::new());
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line
            .split([',', ';', '\t', ' '])
            .filter(|x| !x.is_empty())
            .collect();
        let nums: Result<Vec<f64>, _> = f.iter().map(|x| x.parse::<f64>()).collect();
        match nums {
            Ok(x) if x.len() == 3 && !(x[2] > 0.0 && x[2].is_finite()) => {
                return Err(format!(
                    "{}: line {}: stderr = {}: a standard error must be positive and finite",
                    path.display(),
                    n + 1,
                    x[2]
                )
                .into());
            }
            Ok(x) if x.len() == 2 || x.len() == 3 => {
                a.push(x[0]);
                c.push(x[1]);
                if x.len() == 3 {
                    s.push(x[2]);
                }
            }
            Err(_) if a.is_empty() => continue, // header
            _ => {
                return Err(format!(
                    "{}: line {}: expected angle_deg,correlation[,stderr]",
                    path.display(),
                    n + 1
                )
                .into());
            }
        }
    }
    let stderr = if s.is_empty() {
        None
    } else if s.len() == a.len() {
        Some(s)
    } else {
        return Err(format!("{}: give a stderr on every line or on none", path.display()).into());
    };
    Ok(Target::Memory {
        angles_deg: a,
        correlation: c,
        stderr,
    })
}
