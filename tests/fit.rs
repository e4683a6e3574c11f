//! End-to-end fits: recover (mfp, g) of a slab from a memory-effect curve rendered at
//! another seed, within the uncertainty the fit reports; a malformed request is a clear error.

use lightpath::app::fit::{FitOptions, fit};
use lightpath::app::run::{Kind, RunOptions, run_scene};
use lightpath::config::scene_from_text;

const TRUTH: &str = r#"
wavelength = 1.0
[medium]
slab = 40.0
mfp = 20.0
phase = { kind = "hg", g = 0.3 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
[memory_effect]
angles_deg = [0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8]
[render]
samples = 20000
chunk = 500
seed = 7
"#;

/// A fresh folder holding the memory-effect curve of `TRUTH` (the fit target) in `target/`.
fn folder_with_target(name: &str) -> std::path::PathBuf {
    folder_with(name, Kind::MemoryEffect, TRUTH)
}

/// A fresh folder holding the `kind` run of config `text` in `target/`.
fn folder_with(name: &str, kind: Kind, text: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("lightpath-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    run_scene(
        kind,
        scene_from_text(text).unwrap(),
        &RunOptions::default(),
        &d.join("target"),
    )
    .unwrap();
    d
}

/// Fit options with the defaults a user gets, for `fit` with `optimizer` and its iterations.
fn options(
    fit: &str,
    optimizer: Option<&str>,
    iterations: usize,
    learning_rate: f64,
) -> FitOptions {
    FitOptions {
        fit: fit.into(),
        samples: None,
        seed: None,
        stages: 30,
        iterations: Some(iterations),
        optimizer: optimizer.map(Into::into),
        learning_rate,
        smooth: 0.0,
        progress: false,
        budget: Default::default(),
        resume: Default::default(),
    }
}

/// Fits from above and from below the truth converge (and say so), recover (mfp, g) within 3
/// reported sd, and agree with each other within their sd. Would catch a fit that stops where it
/// started, returns a point it never evaluated, or reports an error bar that misses the truth.
#[test]
fn recovers_mfp_and_g_from_a_memory_effect_curve() {
    let d = folder_with_target("fit");
    let mut fitted = Vec::new();
    for (name, mfp) in [("above", "28.0"), ("below", "10.0")] {
        let start = TRUTH
            .replace("mfp = 20.0", &format!("mfp = {mfp}"))
            .replace("g = 0.3", "g = 0.1")
            .replace("seed = 7", "seed = 1");
        let opts = options("mfp,g", None, 5, 0.05);
        let out = fit(
            scene_from_text(&start).unwrap(),
            &d.join("target/memory_effect.json"),
            &opts,
            &d.join(name),
        )
        .unwrap();
        eprintln!("{name}: {}", out.summary);
        assert!(out.not_converged.is_none(), "{name}: {}", out.summary);
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(name).join("fit.json")).unwrap()).unwrap();
        assert_eq!(v["convergence"]["converged"], true);
        let get = |k: &str, i: usize| v[k][i].as_f64().unwrap();
        for (i, truth) in [(0, 20.0), (1, 0.3)] {
            let (f, s) = (get("fitted", i), get("stddev", i));
            assert!(s > 0.0 && s.is_finite());
            assert!(
                (f - truth).abs() < 3.0 * s,
                "{name} {}: {f} ± {s} vs {truth}",
                v["params"][i]
            );
        }
        // the start was far off, so the fit must have moved: the loss fell by orders of magnitude
        let log = v["log"].as_array().unwrap();
        let first = log.first().unwrap()["loss"].as_f64().unwrap();
        assert!(
            first > 20.0 * v["loss"].as_f64().unwrap(),
            "loss {first} → {}",
            v["loss"]
        );
        assert!(d.join(name).join("fit.png").exists());
        // transmission memory-effect curves barely separate mfp from g (similarity): reported
        assert!(v["correlation"][0][1].as_f64().unwrap().abs() > 0.8);
        fitted.push((get("fitted", 0), get("stddev", 0)));
    }
    let ((a, sa), (b, sb)) = (fitted[0], fitted[1]);
    assert!(
        (a - b).abs() < sa.max(sb),
        "starts disagree: {a} ± {sa} vs {b} ± {sb}"
    );
}

/// Adam on a memory-effect curve: the uncertainty counts the model's own Monte Carlo error
/// (delta method over the chunks of a run at the fitted medium), the truth lies within 3 sd, and the
/// fixed-length run reports whether its loss reached a plateau.
#[test]
fn adam_fits_a_memory_curve_with_model_errors() {
    let d = folder_with_target("fit-adam");
    let start = TRUTH
        .replace("mfp = 20.0", "mfp = 28.0")
        .replace("seed = 7", "seed = 1");
    let opts = options("mfp", Some("adam"), 80, 0.1);
    let out = fit(
        scene_from_text(&start).unwrap(),
        &d.join("target/memory_effect.json"),
        &opts,
        &d.join("fit"),
    )
    .unwrap();
    eprintln!("{}", out.summary);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("fit/fit.json")).unwrap()).unwrap();
    let (f, s) = (
        v["fitted"][0].as_f64().unwrap(),
        v["stddev"][0].as_f64().unwrap(),
    );
    assert!(
        s > 0.0 && s.is_finite() && (f - 20.0).abs() < 3.0 * s,
        "{f} ± {s}"
    );
    assert_eq!(v["convergence"]["converged"], true, "{}", out.summary);
    assert_eq!(v["convergence"]["stop"], "loss_plateau");
}

#[test]
fn bad_fit_requests_are_clear_errors() {
    let d = std::env::temp_dir().join(format!("lightpath-fit-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(
        d.join("curve.csv"),
        "angle_deg,correlation\n0.1,0.9\n0.2,0.7\n",
    )
    .unwrap();
    let cfg = || scene_from_text(TRUTH).unwrap();
    let opts = |fit: &str| FitOptions {
        fit: fit.into(),
        samples: Some(1000),
        seed: None,
        stages: 1,
        iterations: Some(1),
        optimizer: None,
        learning_rate: 0.05,
        smooth: 0.0,
        progress: false,
        budget: Default::default(),
        resume: Default::default(),
    };
    let err = fit(
        cfg(),
        &d.join("curve.csv"),
        &opts("mfp,colour"),
        &d.join("o"),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("colour") && err.contains("allowed"), "{err}");
    let err = fit(
        cfg(),
        &d.join("curve.csv"),
        &opts("mfp,sigma_s"),
        &d.join("o"),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("either"), "{err}");
    let err = fit(cfg(), &d.join("missing.json"), &opts("mfp"), &d.join("o"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("cannot read target"), "{err}");
    // malformed JSON is reported as JSON, with its position, not read as a CSV curve
    std::fs::write(
        d.join("broken.json"),
        "{\"angles_deg\": [1, 2],\n \"correlation\": [0.5,\n",
    )
    .unwrap();
    let err = fit(cfg(), &d.join("broken.json"), &opts("mfp"), &d.join("o"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("not valid JSON") && err.contains("line 3"),
        "{err}"
    );
    let iso = TRUTH.replace(
        "phase = { kind = \"hg\", g = 0.3 }",
        "phase = { kind = \"isotropic\" }",
    );
    let err = fit(
        scene_from_text(&iso).unwrap(),
        &d.join("curve.csv"),
        &opts("g"),
        &d.join("o"),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("hg"), "{err}");
    // a measured CSV curve is a valid target
    assert!(fit(cfg(), &d.join("curve.csv"), &opts("mfp"), &d.join("ok")).is_ok());
}

/// A `correlation_map.json` is a fit target: its `C(Δ, τ)` entries are modelled on the map's scene
/// built from the config's `[correlation_map]`, so at the truth the model matches the map within
/// the errors (a wrong entry mapping would not); a config without the table, or with other shifts,
/// is refused with a message saying what to use.
#[test]
fn correlation_map_is_a_fit_target() {
    const MAP: &str = r#"
wavelength = 1.0
[medium]
box = [6.0, 6.0, 4.0]
mfp = 4.0
phase = { kind = "hg", g = 0.6 }
[[light]]
kind = "focused"
focus = [0.0, 0.0, 2.0]
axis = [0.0, 0.0, 1.0]
aperture_sigma = 0.3
[[view]]
kind = "focused"
focus = [0.0, 0.0, 2.0]
axis = [0.0, 0.0, 1.0]
aperture_sigma = 0.3
[correlation_map]
deltas = [[1.0, 0.0]]
tau_width = 2.0
pixels = [3, 1]
[render]
samples = 40000
chunk = 1000
seed = 3
"#;
    let d = folder_with("fit-map", Kind::CorrelationMap, MAP);
    let target = d.join("target/correlation_map.json");
    let opts = FitOptions {
        fit: "mfp".into(),
        samples: Some(40_000),
        seed: Some(11),
        stages: 1,
        iterations: Some(1),
        optimizer: None,
        learning_rate: 0.05,
        smooth: 0.0,
        progress: false,
        budget: Default::default(),
        resume: Default::default(),
    };
    // one step from the truth: the model's entries are the map's
    let _ = fit(scene_from_text(MAP).unwrap(), &target, &opts, &d.join("o"));
    let f: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("o/fit.json")).unwrap()).unwrap();
    let values = |key: &str| -> Vec<f64> {
        f[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let map: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&target).unwrap()).unwrap();
    // the map's Re C(Δ, τ) and errors, shift by shift, τ by τ: the order of the fit's entries
    let flat = |key: &str| -> Vec<f64> {
        map[key]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|delta| delta.as_array().unwrap().iter())
            .flat_map(|row| row.as_array().unwrap().iter())
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (wanted, stderr) = (flat("re"), flat("stderr"));
    let model = values("model_initial");
    assert_eq!(model.len(), wanted.len());
    assert_eq!(model.len(), 6);
    // the model has as many paths as the map: combined error √2 × the map's
    for ((m, t), se) in model.iter().zip(&wanted).zip(&stderr) {
        assert!(
            (m - t).abs() < 4.0 * 2f64.sqrt() * se,
            "model {m} vs map {t} ± {se}"
        );
    }
    // without the table, and with other shifts
    let err = fit(
        scene_from_text(
            &MAP.replace(
                "deltas = [[1.0, 0.0]]\ntau_width = 2.0\npixels = [3, 1]\n",
                "",
            )
            .replace("[correlation_map]\n", ""),
        )
        .unwrap(),
        &target,
        &opts,
        &d.join("o2"),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("[correlation_map]"), "{err}");
    let err = fit(
        scene_from_text(&MAP.replace("[[1.0, 0.0]]", "[[2.0, 0.0]]")).unwrap(),
        &target,
        &opts,
        &d.join("o3"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("shifts") && err.contains("rendered with"),
        "{err}"
    );
}

/// A `covariance.json` target from another setup is refused by key, not fitted because the counts
/// match: another wavelength, another view direction; a ragged target array is refused, not cut.
#[test]
fn a_target_from_another_setup_is_refused() {
    const SCENE: &str = r#"
wavelength = 1.0
[medium]
box = [6.0, 6.0, 3.0]
mfp = 3.0
phase = { kind = "hg", g = 0.3 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.1, 1.0]
[render]
samples = 1000
chunk = 250
seed = 3
"#;
    let d = folder_with("fit-mismatch", Kind::Covariance, SCENE);
    let target = d.join("target/covariance.json");
    let opts = FitOptions {
        samples: Some(500),
        stages: 1,
        ..options("mfp", None, 1, 0.05)
    };
    let run = |text: &str, target: &std::path::Path| {
        fit(scene_from_text(text).unwrap(), target, &opts, &d.join("o"))
    };
    // the same setup is accepted
    assert!(run(SCENE, &target).is_ok());
    let err = run(
        &SCENE.replace("wavelength = 1.0", "wavelength = 0.5"),
        &target,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("wavelength = 1") && err.contains("0.5"),
        "{err}"
    );
    let err = run(
        &SCENE.replace("[0.0, 0.1, 1.0]", "[0.1, 0.0, 1.0]"),
        &target,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("views[1].direction"), "{err}");
    // a ragged [1][1][2][3] array (one extra column) is refused, not truncated to 2 × 2
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&target).unwrap()).unwrap();
    for key in ["re", "im", "stderr"] {
        for row in v[key][0][0].as_array_mut().unwrap() {
            row.as_array_mut().unwrap().push(serde_json::json!(0.0));
        }
    }
    let ragged = d.join("ragged.json");
    std::fs::write(&ragged, v.to_string()).unwrap();
    let err = run(SCENE, &ragged).unwrap_err().to_string();
    assert!(err.contains("array like `re`"), "{err}");
}
