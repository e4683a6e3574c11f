//! Fits that converge or say they did not. A far-field box target (a Monte Carlo covariance at
//! 10× the model's samples, another seed) fitted for the mean free path from starts 2× above, 2×
//! below and 4× above the truth, through the command line as a user runs it.
//!
//! What this would catch: a fit that returns a point it never evaluated (beyond its trust region),
//! stops after a fixed number of stages wherever it is, or reports an error bar far smaller than
//! the distance between fits of the same data. The same scene once gave fits from different starts
//! that disagreed by many times their reported standard deviations.

use std::path::Path;
use std::process::Command;

const TRUTH: &str = r#"
wavelength = 1.0
[medium]
box = [6.0, 6.0, 6.0]
mfp = 5.0
phase = { kind = "isotropic" }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field_ring"
start = [0.0, 0.0, 1.0]
axis = [0.0, 1.0, 0.0]
count = 12
[render]
samples = 200000
chunk = 1000
seed = 11
"#;

fn lightpath(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .output()
        .unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// Render the target covariance of `truth` into `d/target`; returns its covariance.json.
fn target(d: &Path, truth: &str) -> std::path::PathBuf {
    std::fs::create_dir_all(d).unwrap();
    std::fs::write(d.join("truth.toml"), truth).unwrap();
    let out = d.join("target");
    let o = lightpath(&[
        "covariance",
        d.join("truth.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out.join("covariance.json")
}

/// A scene config that starts the fit at `mfp` with the model's own samples and seed.
fn start(d: &Path, mfp: f64) -> String {
    let text = TRUTH
        .replace("mfp = 5.0", &format!("mfp = {mfp}"))
        .replace("samples = 200000", "samples = 20000")
        .replace("seed = 11", "seed = 2");
    let p = d.join(format!("start_{mfp}.toml"));
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn starts_above_and_below_reach_one_optimum_and_the_truth() {
    let d = std::env::temp_dir().join(format!("lightpath-fitconv-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let target = target(&d, TRUTH);
    let mut fits = Vec::new();
    for mfp in [10.0, 2.5, 20.0] {
        let out = d.join(format!("fit_{mfp}"));
        let o = lightpath(&[
            "fit",
            &start(&d, mfp),
            "--target",
            target.to_str().unwrap(),
            "--fit",
            "mfp",
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(
            o.status.success(),
            "start {mfp}: {}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        let v = json(&out.join("fit.json"));
        assert_eq!(v["convergence"]["converged"], true, "start {mfp}: {v}");
        let (f, s) = (
            v["fitted"][0].as_f64().unwrap(),
            v["stddev"][0].as_f64().unwrap(),
        );
        eprintln!("start {mfp}: {f:.5} ± {s:.5}");
        // the truth within 3 reported sd (target and model Monte Carlo errors both enter)
        assert!((f - 5.0).abs() < 3.0 * s, "start {mfp}: {f} ± {s} vs 5");
        fits.push((f, s));
    }
    // one optimum: every pair of starts agrees well within the reported sd
    for (a, sa) in &fits {
        for (b, _) in &fits {
            assert!((a - b).abs() < 0.25 * sa, "{fits:?}");
        }
    }
}

/// A fit that runs out of stages says so: `"converged": false` with the reason in fit.json, a
/// warning on stderr, exit status 3, and the result files still written.
#[test]
fn a_fit_that_hits_its_limit_says_so() {
    let d = std::env::temp_dir().join(format!("lightpath-fitlimit-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let target = target(&d, &TRUTH.replace("200000", "20000"));
    let out = d.join("fit");
    let o = lightpath(&[
        "fit",
        &start(&d, 10.0),
        "--target",
        target.to_str().unwrap(),
        "--fit",
        "mfp",
        "--stages",
        "1",
        "--iterations",
        "2",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(o.status.code(), Some(3));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("did NOT converge") && err.contains("stage limit"),
        "{err}"
    );
    let v = json(&out.join("fit.json"));
    assert_eq!(v["convergence"]["converged"], false);
    assert_eq!(v["convergence"]["stop"], "stage_limit");
}

/// A wave-solver target (exact Foldy–Lax optics, experiments/fit-wave-target in small): fits from 2×
/// above and 2× below agree to a quarter of their sd and converge. The residual bias against the
/// wave truth is the radiative-transfer model gap of boxes a few wavelengths wide: the fitted MFP
/// is ≈ 4 % short (5.76 for 6 with 8000 placements), which this test pins between 2 and 8 %.
#[test]
fn wave_target_starts_agree_with_the_stated_model_bias() {
    let d = std::env::temp_dir().join(format!("lightpath-fitwave-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/experiments/fit-wave-target");
    let o = lightpath(&[
        "wave",
        &format!("{dir}/truth.toml"),
        "--realizations",
        "3000",
        "--out",
        d.join("wave").to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let start = std::fs::read_to_string(format!("{dir}/start.toml")).unwrap();
    let mut fits = Vec::new();
    for mfp in [12.0, 3.0] {
        let cfg = d.join(format!("start_{mfp}.toml"));
        std::fs::write(&cfg, start.replace("mfp = 9.0", &format!("mfp = {mfp}"))).unwrap();
        let out = d.join(format!("fit_{mfp}"));
        let o = lightpath(&[
            "fit",
            cfg.to_str().unwrap(),
            "--target",
            d.join("wave/covariance.json").to_str().unwrap(),
            "--fit",
            "mfp",
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v = json(&out.join("fit.json"));
        let (f, s) = (
            v["fitted"][0].as_f64().unwrap(),
            v["stddev"][0].as_f64().unwrap(),
        );
        eprintln!("wave target, start {mfp}: {f:.5} ± {s:.5}");
        assert!(
            f > 6.0 * 0.92 && f < 6.0 * 0.98,
            "bias outside 2–8 %: {f} ± {s}"
        );
        fits.push((f, s));
    }
    let ((a, sa), (b, _)) = (fits[0], fits[1]);
    assert!((a - b).abs() < 0.25 * sa, "{fits:?}");
}
