//! Bad input gets a clear error: the key, the value and what is allowed; exit code ≠ 0; no panic;
//! no result file written.

use std::path::PathBuf;
use std::process::Command;

const GOOD: &str = r#"
wavelength = 1.0
[medium]
box = [4.0, 4.0, 4.0]
mfp = 2.0
albedo = 1.0
phase = { kind = "hg", g = 0.3 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
[render]
samples = 2000
seed = 1
chunk = 500
"#;

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("lightpath-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Run `covariance` on `text`; return (exit success, stderr, whether covariance.json exists).
fn run_config(name: &str, text: &str) -> (bool, String, bool) {
    let d = tmpdir(name);
    let cfg = d.join("scene.toml");
    std::fs::write(&cfg, text).unwrap();
    let out = d.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "covariance",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ])
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        out.join("covariance.json").exists(),
    )
}

fn expect_error(name: &str, text: &str, needles: &[&str]) {
    let (ok, err, wrote) = run_config(name, text);
    assert!(!ok, "{name}: should fail");
    assert!(!wrote, "{name}: wrote a result despite the error");
    assert!(!err.contains("panicked"), "{name}: panicked: {err}");
    for n in needles {
        assert!(err.contains(n), "{name}: error should mention {n:?}: {err}");
    }
}

#[test]
fn good_config_runs() {
    let (ok, err, wrote) = run_config("good", GOOD);
    assert!(ok && wrote, "{err}");
}

#[test]
fn negative_or_zero_lengths() {
    expect_error(
        "box",
        &GOOD.replace("box = [4.0, 4.0, 4.0]", "box = [4.0, -1.0, 4.0]"),
        &["medium.box[1]", "-1", "positive"],
    );
    expect_error(
        "mfp",
        &GOOD.replace("mfp = 2.0", "mfp = 0.0"),
        &["medium.mfp", "0", "positive"],
    );
    expect_error(
        "wavelength",
        &GOOD.replace("wavelength = 1.0", "wavelength = -2.0"),
        &["wavelength", "-2", "positive"],
    );
    expect_error(
        "slab",
        &GOOD.replace("box = [4.0, 4.0, 4.0]", "slab = -3.0"),
        &["medium.slab", "-3", "positive"],
    );
}

#[test]
fn albedo_out_of_range() {
    expect_error(
        "albedo",
        &GOOD.replace("albedo = 1.0", "albedo = 1.3"),
        &["medium.albedo", "1.3", "[0, 1]"],
    );
    expect_error(
        "albedo-neg",
        &GOOD.replace("albedo = 1.0", "albedo = -0.1"),
        &["medium.albedo", "-0.1", "[0, 1]"],
    );
}

#[test]
fn anisotropy_out_of_range() {
    expect_error(
        "g",
        &GOOD.replace("g = 0.3", "g = 1.0"),
        &["medium.phase.g", "1", "(-1, 1)"],
    );
    expect_error(
        "g-neg",
        &GOOD.replace("g = 0.3", "g = -1.5"),
        &["medium.phase.g", "-1.5", "(-1, 1)"],
    );
}

#[test]
fn bad_directions() {
    expect_error(
        "zero-dir",
        &GOOD.replacen(
            "direction = [0.0, 0.0, 1.0]",
            "direction = [0.0, 0.0, 0.0]",
            1,
        ),
        &["light[0].direction", "non-zero finite"],
    );
    expect_error(
        "nan-dir",
        &GOOD.replace(
            "kind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]",
            "kind = \"far_field\"\ndirection = [0.0, nan, 1.0]",
        ),
        &["view[0].direction", "NaN", "non-zero finite"],
    );
}

#[test]
fn empty_lists() {
    let no_light = GOOD.replace(
        "[[light]]\nkind = \"plane_wave\"\ndirection = [0.0, 0.0, 1.0]\n",
        "",
    );
    expect_error("no-light", &no_light, &["light", "empty"]);
    let no_view = GOOD.replace(
        "[[view]]\nkind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]\n",
        "",
    );
    expect_error("no-view", &no_view, &["view", "empty"]);
}

#[test]
fn unknown_keys() {
    expect_error(
        "unknown-top",
        &format!("colour = 3\n{GOOD}"),
        &["unknown field", "colour"],
    );
    expect_error(
        "unknown-medium",
        &GOOD.replace("mfp = 2.0", "mfp = 2.0\nmpf = 3.0"),
        &["medium", "mpf"],
    );
    expect_error(
        "unknown-kind",
        &GOOD.replace("kind = \"hg\"", "kind = \"rayleigh\""),
        &["medium.phase", "rayleigh"],
    );
    // an isotropic phase function has no g: a g there is a mistake, not ignored
    expect_error(
        "isotropic-with-g",
        &GOOD.replace("kind = \"hg\", g = 0.3", "kind = \"isotropic\", g = 0.9"),
        &["medium.phase", "unknown field `g`"],
    );
}

#[test]
fn missing_or_unreadable_files() {
    let d = tmpdir("missing");
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "covariance",
            d.join("nope.toml").to_str().unwrap(),
            "--out",
            d.join("o").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("cannot read config file") && err.contains("nope.toml"),
        "{err}"
    );
    // a folder is unreadable as a file
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "covariance",
            d.to_str().unwrap(),
            "--out",
            d.join("o").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        !o.status.success()
            && String::from_utf8_lossy(&o.stderr).contains("cannot read config file")
    );
    // a tabulated phase function file that does not exist
    expect_error(
        "table-file",
        &GOOD.replace(
            "phase = { kind = \"hg\", g = 0.3 }",
            "phase = { kind = \"tabulated\", file = \"missing.csv\" }",
        ),
        &["medium.phase.file", "missing.csv", "cannot read"],
    );
}

#[test]
fn bad_tabulated_phase_functions() {
    expect_error(
        "table-negative",
        &GOOD.replace(
            "phase = { kind = \"hg\", g = 0.3 }",
            "phase = { kind = \"tabulated\", values = [1.0, -0.5, 2.0] }",
        ),
        &["medium.phase", "entry 1", "-0.5", ">= 0"],
    );
    expect_error(
        "table-zero",
        &GOOD.replace(
            "phase = { kind = \"hg\", g = 0.3 }",
            "phase = { kind = \"tabulated\", values = [0.0, 0.0, 0.0] }",
        ),
        &["medium.phase", "integrates to 0", "positive"],
    );
    expect_error(
        "table-range",
        &GOOD.replace(
            "phase = { kind = \"hg\", g = 0.3 }",
            "phase = { kind = \"tabulated\", cos = [-1.0, 0.0, 0.5], values = [1.0, 1.0, 1.0] }",
        ),
        &["medium.phase", "from -1 to 1"],
    );
}

#[test]
fn conflicting_and_missing_coefficients() {
    expect_error(
        "both",
        &GOOD.replace("mfp = 2.0", "mfp = 2.0\nsigma_s = 0.5"),
        &["medium", "either"],
    );
    expect_error(
        "none",
        &GOOD.replace("mfp = 2.0\nalbedo = 1.0\n", ""),
        &["medium", "mfp", "sigma_s"],
    );
    expect_error(
        "sigma-a",
        &GOOD.replace("mfp = 2.0\nalbedo = 1.0", "sigma_s = 0.5\nsigma_a = -0.1"),
        &["medium.sigma_a", "-0.1", ">= 0"],
    );
}

#[test]
fn bad_flags() {
    let d = tmpdir("flags");
    let cfg = d.join("scene.toml");
    std::fs::write(&cfg, GOOD).unwrap();
    for args in [
        vec!["--shard", "3/2"],
        vec!["--samples", "0"],
        vec!["--threads", "0"],
        vec!["--max-minutes", "0"],
        vec!["--max-memory-gb", "0"],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args([
                "covariance",
                cfg.to_str().unwrap(),
                "--out",
                d.join("o").to_str().unwrap(),
            ])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && !err.contains("panicked"),
            "{args:?}: {err}"
        );
        assert!(err.contains(args[0]), "{args:?}: {err}");
    }
}

#[test]
fn bad_near_field_settings() {
    let vmf = GOOD.replace(
        r#"phase = { kind = "hg", g = 0.3 }"#,
        r#"phase = { kind = "vmf_mixture", weights = [1.0, 0.3], kappas = [20.0, 2.0] }"#,
    );
    let (ok, err, wrote) = run_config("vmf-good", &vmf);
    assert!(ok && wrote, "{err}");
    expect_error(
        "vmf-weight",
        &vmf.replace("weights = [1.0, 0.3]", "weights = [1.0, -0.3]"),
        &["medium.phase.weights[1]", "-0.3", "positive"],
    );
    expect_error(
        "vmf-len",
        &vmf.replace("weights = [1.0, 0.3]", "weights = [1.0]"),
        &["medium.phase.weights", "kappas"],
    );
    expect_error(
        "first-direction",
        &GOOD.replace(
            "chunk = 500",
            "chunk = 500\nfirst_vertex = \"uniform\"\nfirst_direction = \"aperture\"",
        ),
        &["render.first_direction", "aperture", "first_vertex"],
    );
    let focused_slab = GOOD.replace("box = [4.0, 4.0, 4.0]", "slab = 4.0").replace(
        "kind = \"plane_wave\"\ndirection = [0.0, 0.0, 1.0]",
        "kind = \"focused\"\nfocus = [0.0, 0.0, 2.0]\naxis = [0.0, 0.0, 1.0]\naperture_sigma = 0.4",
    );
    expect_error("focused-slab", &focused_slab, &["focused", "medium.box"]);
    expect_error(
        "focused-grid",
        &GOOD.replace(
            "kind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]",
            "kind = \"focused_grid\"\ncenter = [0.0, 0.0, 2.0]\naxis = [0.0, 0.0, 1.0]\naperture_sigma = 0.4\nspacing = 0.0\npixels = [4, 4]",
        ),
        &["view[0].spacing", "0", "positive"],
    );
}

/// A `[tilt_shift]` table with two forms of cells, a tilt beyond 45°, no τ, or a
/// `[render] aperture` that does not exist is refused with the key and what is allowed.
#[test]
fn bad_tilt_shift_and_aperture_settings() {
    let table = |body: &str| format!("{GOOD}\n[tilt_shift]\ntau_width = 1.0\n{body}\n");
    expect_error(
        "ts-two-forms",
        &table("taus = 3\nrefocus = [0.0, 1.0]\ncells = [[0.0, 1.0]]"),
        &["tilt_shift", "exactly one of"],
    );
    expect_error(
        "ts-angle",
        &table("taus = 3\nshifts = [0.0]\nangles_deg = [0.0, 60.0]"),
        &["tilt_shift.angles_deg[1]", "60", "[-45, 45]"],
    );
    expect_error(
        "ts-taus",
        &table("taus = 0\nrefocus = [0.0]"),
        &["tilt_shift.taus", "at least 1"],
    );
    expect_error(
        "ts-none",
        &table("taus = 3"),
        &["tilt_shift", "exactly one of"],
    );
    expect_error(
        "aperture",
        &GOOD.replace("chunk = 500", "chunk = 500\naperture = \"gauss\""),
        &["render.aperture", "gauss", "vmf", "quadrature"],
    );
    let drawn = |n: &str| GOOD.replace("chunk = 500", &format!("chunk = 500\n{n}"));
    expect_error(
        "aperture-directions",
        &drawn("aperture = \"monte_carlo\"\naperture_directions = 0"),
        &["render.aperture_directions", "0", "1 to 100000"],
    );
    expect_error(
        "aperture-directions-unused",
        &drawn("aperture_directions = 8"),
        &["render.aperture_directions", "8", "monte_carlo"],
    );
}

/// Legal physics that no run could finish (a diffusive box 10⁵ λ wide, mfp 10⁻⁶, σ_s 10⁶, a 10¹¹ λ
/// slab) or whose outputs cannot fit in memory (7200 views: 9.95 GB once) is refused before any
/// work, with the estimate and the flag to change; each of these once hung or aborted. Numbers
/// beyond any quantity (mfp 10⁻³⁰⁰, a box of 10³⁰⁸) are refused by key.
#[test]
fn runs_beyond_the_budget_are_refused_up_front() {
    // (replacements in GOOD, the flag the refusal must name)
    let cases: [(&[(&str, &str)], &str); 5] = [
        (
            &[
                ("samples = 2000", "samples = 100000"),
                (
                    "box = [4.0, 4.0, 4.0]\nmfp = 2.0",
                    "box = [1e5, 1e5, 1e5]\nmfp = 5.0",
                ),
            ],
            "--max-minutes",
        ),
        (&[("mfp = 2.0", "mfp = 1e-6")], "--max-minutes"),
        (
            &[("mfp = 2.0\nalbedo = 1.0", "sigma_s = 1e6\nsigma_a = 0.0")],
            "--max-minutes",
        ),
        (&[("box = [4.0, 4.0, 4.0]", "slab = 1e11")], "--max-minutes"),
        (
            &[(
                "kind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]",
                "kind = \"far_field_ring\"\nstart = [0.0, 0.0, 1.0]\naxis = [0.0, 1.0, 0.0]\ncount = 7200",
            )],
            "--max-memory-gb",
        ),
    ];
    for (i, (edits, flag)) in cases.into_iter().enumerate() {
        let mut text = GOOD.to_string();
        for (from, to) in edits {
            assert!(text.contains(from), "case {i}: {from:?} not in the config");
            text = text.replace(from, to);
        }
        expect_error(&format!("budget-{i}"), &text, &[flag, "estimate", "Use"]);
    }
    expect_error(
        "tiny-mfp",
        &GOOD.replace("mfp = 2.0", "mfp = 1e-300"),
        &["medium.mfp = 1e-300", "magnitudes"],
    );
    expect_error(
        "huge-box",
        &GOOD.replace("box = [4.0, 4.0, 4.0]", "box = [1e308, 4.0, 4.0]"),
        &["medium.box[0] = 1e308"],
    );
}

/// `lightpath check` on `text`: (success, stderr).
fn check(name: &str, text: &str) -> (bool, String) {
    let d = tmpdir(name);
    let cfg = d.join("c.toml");
    std::fs::write(&cfg, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(["check", cfg.to_str().unwrap()])
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

/// Errors inside tables tagged by `kind` (views, lights, phase functions, mixtures, profiles,
/// bounds) name the full key path, as errors in plain tables do; an array where a table belongs is
/// refused rather than read by position.
#[test]
fn errors_inside_tagged_tables_name_the_full_key() {
    let ring =
        "kind = \"far_field_ring\"\nstart = [0.0, 0.0, 1.0]\naxis = [0.0, 1.0, 0.0]\ncount = 3";
    let cases: Vec<(String, &str)> = vec![
        (
            GOOD.replace("kind = \"far_field\"", &format!("{ring}\n[[view]]\nkind = \"far_field\"")),
            "",
        ),
        (
            GOOD.replace("kind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]", &ring.replace("axis = [0.0, 1.0, 0.0]", "axis = [0.0, 1.0]")),
            "view[0].axis: invalid length 2",
        ),
        (
            GOOD.replace("kind = \"far_field\"\ndirection = [0.0, 0.0, 1.0]", &ring.replace("count = 3", "count = \"three\"")),
            "view[0].count: invalid type",
        ),
        (
            GOOD.replace("direction = [0.0, 0.0, 1.0]\n[[view]]", "position = [0.0, 0.0, 1.0]\n[[view]]"),
            "light[0].position: unknown field `position`",
        ),
        (
            GOOD.replace("kind = \"hg\", g = 0.3", "kind = \"hgx\", g = 0.3"),
            "medium.phase.kind: unknown variant `hgx`",
        ),
        (
            GOOD.replace(
                "phase = { kind = \"hg\", g = 0.3 }",
                "phase = { kind = \"mixture\", components = [{ weight = 1.0, phase = { kind = \"hg\", g = 0.3 } }, { weight = 1.0, phase = { kind = \"hg\", q = 0.3 } }] }",
            ),
            "medium.phase.components[1].phase.q: unknown field `q`",
        ),
        (
            format!("render = [2000.0]\n{}", GOOD.split("[render]").next().unwrap()),
            "render",
        ),
    ];
    let (ok, err) = check("tagged-good", &cases[0].0);
    assert!(ok, "the unmutated config must pass: {err}");
    for (i, (text, needle)) in cases.iter().enumerate().skip(1) {
        let (ok, err) = check(&format!("tagged-{i}"), text);
        assert!(!ok && !err.contains("panicked"), "{i}: {err}");
        assert!(err.contains(needle), "{i}: expected {needle:?} in {err}");
    }
    // GRIN configs: a profile's key, and `trace = [10.0]` (once read as step = 10)
    let lune = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/configs/luneburg.toml"
    ))
    .unwrap();
    let (ok, err) = check(
        "lune-radius",
        &lune.replace("radius = 1.0 }]", "radius = \"one\" }]"),
    );
    assert!(!ok && err.contains("field.profiles[0].radius"), "{err}");
    let (ok, err) = check(
        "lune-bounds",
        &lune.replace("kind = \"sphere\", radius", "kind = \"sphere\", radios"),
    );
    assert!(!ok && err.contains("field.bounds.radios"), "{err}");
    let positional = format!(
        "trace = [10.0]\n{}",
        lune.replace("[trace]\nstep = 0.002", "")
    );
    let (ok, err) = check("lune-trace", &positional);
    assert!(!ok && err.contains("trace: expected a table"), "{err}");
}

/// `lightpath trace` refuses a step too coarse for the field (a Luneburg lens at step 10 once
/// missed its focus by 0.35 R and exited 0) or too fine to cross it within max_steps (once "0
/// through the field" as a success), warns with an estimate when the exit points are uncertain, and
/// `check` refuses an ultrasonic field whose Bessel sum would take forever (once a hang).
#[test]
fn trace_steps_are_checked_against_the_field() {
    let lune = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/configs/luneburg.toml"
    ))
    .unwrap();
    let trace = |name: &str, text: &str| {
        let d = tmpdir(name);
        let cfg = d.join("l.toml");
        std::fs::write(&cfg, text).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args([
                "trace",
                cfg.to_str().unwrap(),
                "--out",
                d.join("o").to_str().unwrap(),
            ])
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr),
            d.join("o/rays.json").exists(),
        )
    };
    let step = |s: &str| lune.replace("step = 0.002", &format!("step = {s}"));
    let (ok, err, wrote) = trace("lune-coarse", &step("10.0"));
    assert!(
        !ok && !wrote && err.contains("trace.step = 10") && err.contains("too coarse"),
        "{err}"
    );
    let (ok, err, wrote) = trace("lune-fine", &step("1e-9"));
    assert!(!ok && !wrote && err.contains("max_steps"), "{err}");
    let (ok, out, _) = trace("lune-good", &lune);
    assert!(ok && !out.contains("warning"), "{out}");
    // the step is measured in the σ-form, n · step per step: the same step in a lens of n ~ 7200
    // runs far too far (a parameter fit of this kind once trapped every ray for minutes)
    let dense = lune.replace(
        "profiles = [{ kind = \"luneburg\", radius = 1.0 }]",
        "profiles = [{ kind = \"luneburg\", radius = 1.0 }, { kind = \"constant\", n = 7200.0 }]",
    );
    assert_ne!(dense, lune);
    let (ok, err, wrote) = trace("lune-dense", &dense);
    assert!(
        !ok && !wrote && err.contains("too coarse") && err.contains("n up to 7201"),
        "{err}"
    );
    let fibre = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/experiments/grin-fibre/fibre.toml"
    ))
    .unwrap();
    let (ok, err) = check("fibre-dense", &fibre.replace("n0 = 1.5", "n0 = 7200.0"));
    assert!(
        !ok && err.contains("trace.step") && err.contains("too coarse"),
        "{err}"
    );
    // without bounds rays never exit: their ends after equal path lengths are compared (this once
    // panicked)
    let (_, err, _) = trace(
        "unbounded",
        &lune.replace("bounds = { kind = \"sphere\", radius = 1.0 }\n", ""),
    );
    assert!(!err.contains("panicked"), "{err}");
    let us = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/configs/ultrasonic_lens.toml"
    ))
    .unwrap();
    // a strong, fine ultrasonic lens at a step that resolves its 40 mm but not its ripples: the
    // exit points move by 0.17 % of the field when the step is halved
    let fine = us
        .replace("n_max = 4.56e-4, k_r = 4.0", "n_max = 0.02, k_r = 20.0")
        .replace("step = 0.02", "step = 1.0");
    assert_ne!(fine, us);
    let (ok, out, wrote) = trace("us-warn", &fine);
    assert!(
        ok && wrote && out.contains("warning") && out.contains("uncertain"),
        "{out}"
    );
    for (from, to) in [("k_r = 4.0", "k_r = 1e9"), ("radius = 5.0", "radius = 1e9")] {
        assert!(us.contains(from));
        let (ok, err) = check("us-big", &us.replace(from, to));
        assert!(
            !ok && err.contains("field.profiles[0].k_r") && err.contains("k_r·r"),
            "{err}"
        );
    }
}

/// `trace` and `design` (grid designs and parameter fits) refuse, before any work, runs whose time
/// estimate from a timed pilot of a few rays exceeds `--max-minutes`, saying what it is made of.
#[test]
fn ray_commands_are_refused_beyond_their_time_budget() {
    let root = env!("CARGO_MANIFEST_DIR");
    for (command, config, files) in [
        ("trace", "configs/luneburg.toml", "rays.json"),
        ("design", "experiments/grin-fibre/fibre.toml", "fit.json"),
        (
            "design",
            "experiments/luneburg-design/luneburg.toml",
            "design.json",
        ),
    ] {
        let d = tmpdir(&format!("budget-{command}-{files}"));
        let out = d.join("o");
        let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args([
                command,
                &format!("{root}/{config}"),
                "--out",
                out.to_str().unwrap(),
                "--max-minutes",
                "1e-7",
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{config}: {err}");
        assert!(
            err.contains("beyond --max-minutes 0.0000001")
                && err.contains("leapfrog steps each")
                && err.contains("timed on"),
            "{config}: {err}"
        );
        assert!(!out.join(files).exists(), "{config}");
    }
}
