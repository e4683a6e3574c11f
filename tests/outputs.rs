//! Output files are complete and consistent: speckle EXR images hold the same fields as
//! speckle.json (channels re, im and I = |u|²) on the configured pixel grid; covariance.json has the
//! documented keys and shapes.

use std::process::Command;

use crate::common;

const SCENE: &str = r#"
wavelength = 1.0
[medium]
box = [20.0, 20.0, 4.0]
mfp = 2.0
phase = { kind = "hg", g = 0.6 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[light]]
kind = "plane_wave"
direction = [0.01, 0.0, 1.0]
[[view]]
kind = "far_field_grid"
center = [0.0, 0.0, 1.0]
width_deg = 10.0
pixels = [6, 4]
[speckle]
realisations = 2
paths = 3000
[render]
samples = 3000
chunk = 500
"#;

fn run(cmd: &str, name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("lightpath-out-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("s.toml"), SCENE).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            cmd,
            d.join("s.toml").to_str().unwrap(),
            "--out",
            d.join("o").to_str().unwrap(),
            "--quiet",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    d.join("o")
}

#[test]
fn speckle_exr_matches_json() {
    let out = run("speckle", "speckle");
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("speckle.json")).unwrap()).unwrap();
    let re = &v["re"];
    assert_eq!(re.as_array().unwrap().len(), 2);
    for r in 0..2 {
        for l in 0..2 {
            let file = out.join(format!("speckle_{r:04}_l{l}.exr"));
            let chan = |name: &str| -> Vec<f32> {
                let (size, values) = common::exr_channel(&file, name);
                assert_eq!(size, (6, 4));
                values
            };
            let (cr, ci, cint) = (chan("re"), chan("im"), chan("I"));
            for p in 0..24 {
                let jr = v["re"][r][l][p].as_f64().unwrap() as f32;
                let ji = v["im"][r][l][p].as_f64().unwrap() as f32;
                assert_eq!((cr[p], ci[p]), (jr, ji));
                assert!((cint[p] - (jr * jr + ji * ji)).abs() <= 1e-5 * cint[p].max(1e-30));
            }
        }
    }
}

#[test]
fn covariance_json_has_documented_shape() {
    let out = run("covariance", "cov");
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("covariance.json")).unwrap()).unwrap();
    for key in [
        "re",
        "im",
        "stderr",
        "single_re",
        "single_im",
        "single_stderr",
        "multiple_re",
        "multiple_im",
        "multiple_stderr",
    ] {
        let a = v[key].as_array().unwrap_or_else(|| panic!("{key}"));
        assert_eq!(a.len(), 2, "{key}: lights");
        assert_eq!(a[0].as_array().unwrap().len(), 2, "{key}: lights");
        assert_eq!(a[0][1].as_array().unwrap().len(), 24, "{key}: views");
        assert_eq!(a[0][1][3].as_array().unwrap().len(), 24, "{key}: views");
    }
    assert_eq!(v["mean_re"].as_array().unwrap().len(), 2);
    assert_eq!(v["mean_im"][1].as_array().unwrap().len(), 24);
    for key in ["wavelength", "lights", "views", "samples", "seed"] {
        assert!(!v[key].is_null(), "{key}");
    }
    assert_eq!(v["views"].as_array().unwrap().len(), 24);
    assert_eq!(v["samples"].as_u64().unwrap(), 3000);
    // intensity = diagonal: positive, real, and total = single + multiple
    for j in 0..24 {
        let t = v["re"][0][0][j][j].as_f64().unwrap();
        let s = v["single_re"][0][0][j][j].as_f64().unwrap();
        let m = v["multiple_re"][0][0][j][j].as_f64().unwrap();
        assert!(t > 0.0 && (t - s - m).abs() <= 1e-12 * t);
        assert!(v["im"][0][0][j][j].as_f64().unwrap().abs() <= 1e-9 * t);
    }
}

/// Run `lightpath args…` and return (success, stderr).
fn lightpath(args: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .arg("--quiet")
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

/// A re-used output folder keeps no stale files of the same command (a run with fewer
/// realisations leaves no old images; a half-written staging file is cleared), keeps other
/// commands' files, and an output folder that cannot be made is reported before any work.
#[test]
fn reused_output_folders_hold_no_stale_results() {
    let out = run("speckle", "stale");
    let d = out.parent().unwrap().to_path_buf();
    let old = out.join("speckle_0001_l0.exr");
    assert!(old.exists(), "two realisations write speckle_0001_*");
    std::fs::write(out.join("fit.json"), "{}").unwrap();
    std::fs::write(out.join(".partial-speckle.json"), "half").unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let one = SCENE.replace("realisations = 2", "realisations = 1");
    std::fs::write(d.join("one.toml"), one).unwrap();
    let cfg = d.join("one.toml");
    let (ok, err) = lightpath(&[
        "speckle",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.join("speckle_0000_l0.exr").exists());
    assert!(!old.exists(), "a stale image of the earlier run survived");
    assert!(!out.join(".partial-speckle.json").exists());
    assert!(out.join("fit.json").exists() && out.join("notes.txt").exists());
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.starts_with(".partial")),
        "{names:?}"
    );
    // a file where the folder should be: refused up front, nothing written
    let blocked = d.join("notes.txt");
    std::fs::write(&blocked, "in the way").unwrap();
    let inside = blocked.join("o");
    let (ok, err) = lightpath(&[
        "covariance",
        cfg.to_str().unwrap(),
        "--out",
        inside.to_str().unwrap(),
        "--samples",
        "100000000000",
    ]);
    assert!(!ok && err.contains("output folder"), "{err}");
}
