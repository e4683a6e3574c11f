//! Fitting analytic index parameters by L-BFGS on exit-adjoint gradients: the
//! ultrasonic lens's `n_max`, and the gain of the transducer ring that sculpts it, for a requested
//! focal depth against the paraxial closed form.

use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, FieldParam, Profile};
use lightpath::inverse::grin_design::Beam;
use lightpath::inverse::grin_fit::ParamFit;

/// The lens problem of both tests below: in a water cylinder of length `DEPTH` a thin collimated
/// beam along z must focus on the exit face, by fitting parameter `which` of `profile`. Returns
/// the fitted value and asserts the miss fell by 10³.
const DEPTH: f64 = 30.0;

fn focus_on_the_exit_face(profile: Profile, which: usize, name: &str) -> f64 {
    let field = BoundedField::single(
        profile,
        Bounds::Cylinder {
            radius: 5.0,
            half_length: DEPTH / 2.0,
        },
        1.33,
    );
    let rays = (1..=4)
        .map(|i| {
            (
                DVec3::new(0.003 * i as f64, 0.0, -DEPTH / 2.0 - 1.0),
                DVec3::Z,
            )
        })
        .collect();
    let fit = ParamFit {
        field,
        params: vec![FieldParam { profile: 0, which }],
        names: vec![name.into()],
        beams: vec![Beam {
            rays,
            focus: DVec3::new(0.0, 0.0, DEPTH / 2.0),
        }],
        step: 0.02,
        max_steps: 100_000,
        iterations: 40,
    };
    let res = fit
        .run(&|_| {}, &Default::default(), &Default::default())
        .unwrap();
    eprintln!(
        "{name} fitted {:.6e}; RMS miss {:.3e} → {:.3e}",
        res.fitted[0], res.rms_miss_initial, res.rms_miss_final
    );
    assert!(res.rms_miss_final < 1e-3 * res.rms_miss_initial);
    res.fitted[0]
}

/// Paraxially `n ≈ n_c − n_max k² r²/4` (`n_c = n0 + n_max`) for `n0 + n_max J_0(k r)`, so rays
/// obey `r'' = −α² r` with `α² = n_max k² / (2 n_c)` and first cross the axis at `π/(2α)`: the
/// `n_max` focusing at `DEPTH` is `2 n0 α²/(k² − 2α²)` with `α = π/(2 DEPTH)`.
fn paraxial_n_max(n0: f64, k: f64) -> f64 {
    let alpha = std::f64::consts::PI / (2.0 * DEPTH);
    2.0 * n0 * alpha * alpha / (k * k - 2.0 * alpha * alpha)
}

/// The ultrasonic lens `n = n0 + n_max J_0(k_r r)` fitted from half the paraxial `n_max` must land
/// on it up to the spherical aberration of `J_0` (`x⁴/64` term), which shifts the best focus by
/// ∝ aperture²: measured 1.6e-4 at this aperture (12 µm) and 4.0e-3 at 5× it.
#[test]
fn ultrasonic_focal_depth_matches_paraxial_closed_form() {
    let (n0, k_r) = (1.33, 4.0);
    let profile = Profile::Ultrasonic {
        n0,
        n_max: 2.2e-4,
        k_r,
        m: 0,
    };
    let got = focus_on_the_exit_face(profile, 1, "n_max");
    let want = paraxial_n_max(n0, k_r);
    eprintln!(
        "n_max {got:.6e}, paraxial {want:.6e}, rel {:.2e}",
        got / want - 1.0
    );
    assert!((got / want - 1.0).abs() < 5e-4, "{got} vs {want}");
}

/// The same lens sculpted by its transducer: a ring of 24 line elements (radius 8 mm, 955 kHz in
/// water: `k = 4` per mm) phased so the static field is `n0 + g n_max J_0(k r)` (Graf's theorem;
/// the orders it aliases in are `J_24(k r)`, nothing near the axis), with `n_max = (dn/dp) N A`
/// when each element's amplitude `A` is stated at the ring's radius. Fitting the drive's gain `g`
/// by the exit adjoint through the array's analytic parameter derivatives must land on the same
/// paraxial `n_max` as the ultrasonic profile does.
#[test]
fn a_phased_ring_fitted_for_a_focal_depth_matches_paraxial_closed_form() {
    use lightpath::eikonal::acoustic::{Element, PhasedArray, Ultrasound, hankel};
    let (n0, k, ring, count) = (1.33, 4.0, 8.0, 24);
    let (piezo, start) = (1e-10, 2.2e-4);
    let ultrasound = Ultrasound {
        frequency: k * 1500.0 / (std::f64::consts::TAU * 1e-3),
        sound_speed: 1500.0,
        attenuation: 0.0,
        unit: 1e-3,
    };
    let phase = std::f64::consts::FRAC_PI_2 - hankel(0, k * ring).arg();
    let array = PhasedArray {
        n0,
        piezo_optic: piezo,
        ultrasound,
        reference: ring,
        gain: 1.0,
        elements: (0..count)
            .map(|j| {
                let t = std::f64::consts::TAU * j as f64 / count as f64;
                Element {
                    x: ring * t.cos(),
                    y: ring * t.sin(),
                    amplitude: start / (piezo * count as f64),
                    phase,
                }
            })
            .collect(),
    };
    let profile = Profile::PhasedArray {
        array: std::sync::Arc::new(array),
        omega_t: std::f64::consts::FRAC_PI_2,
    };
    let gain = profile.param_index("gain").unwrap();
    let got = focus_on_the_exit_face(profile, gain, "gain") * start;
    let want = paraxial_n_max(n0, k);
    eprintln!(
        "g n_max {got:.6e}, paraxial {want:.6e}, rel {:.2e}",
        got / want - 1.0
    );
    assert!((got / want - 1.0).abs() < 5e-4, "{got} vs {want}");
}

/// A radial polynomial fibre fitted so an on-axis point re-images on the axis half a pitch later
/// (rays up to 20°) must find the sech profile's coefficients — exactly periodic for meridional
/// rays — not the parabolic ones: `c1 = −n0 α²/2`, `c2 = +5 n0 α⁴/24` (parabolic: `−n0 α⁴/8`).
/// Deterministic; measured deviations 3e-5 (c1) and 0.3 % (c2, the ρ⁴ term the rays barely probe).
#[test]
fn fibre_fit_finds_the_sech_profile() {
    let (n0, half) = (1.5, std::f64::consts::PI);
    let alpha = std::f64::consts::PI / (2.0 * half);
    let field = BoundedField::single(
        Profile::RadialPolynomial {
            n0,
            coefficients: vec![-0.15, -0.01, -0.001],
        },
        Bounds::Cylinder {
            radius: 2.0,
            half_length: half,
        },
        1.0,
    );
    let rays = (1..=6)
        .map(|i| {
            let t = (20.0f64 * i as f64 / 6.0).to_radians();
            (
                DVec3::new(0.0, 0.0, -half),
                DVec3::new(t.sin(), 0.0, t.cos()),
            )
        })
        .collect();
    let fit = ParamFit {
        field,
        params: (1..=3)
            .map(|which| FieldParam { profile: 0, which })
            .collect(),
        names: vec!["c1".into(), "c2".into(), "c3".into()],
        beams: vec![Beam {
            rays,
            focus: DVec3::new(0.0, 0.0, half),
        }],
        step: 0.005,
        max_steps: 100_000,
        iterations: 100,
    };
    let res = fit
        .run(&|_| {}, &Default::default(), &Default::default())
        .unwrap();
    let (c1, c2) = (res.fitted[0], res.fitted[1]);
    let (s1, s2) = (-n0 * alpha.powi(2) / 2.0, 5.0 * n0 * alpha.powi(4) / 24.0);
    eprintln!("c1 {c1:.6e} (sech {s1:.6e}), c2 {c2:.6e} (sech {s2:.6e})");
    assert!((c1 / s1 - 1.0).abs() < 2e-4, "c1 = {c1}, sech {s1}");
    assert!((c2 / s2 - 1.0).abs() < 0.01, "c2 = {c2}, sech {s2}");
    assert!(res.rms_miss_final < 1e-4, "RMS miss {}", res.rms_miss_final);
}

/// `lightpath design` with a `[parameters]` table runs the fit and writes fit.json, loss.png and
/// rays.png; a parameter the profile lacks, or a profile that does not exist, is a clear error.
#[test]
fn design_command_fits_parameters() {
    let bin = env!("CARGO_BIN_EXE_lightpath");
    let d = std::env::temp_dir().join(format!("lightpath-pfit-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let cfg = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/experiments/grin-fibre/fibre.toml"
    );
    let o = std::process::Command::new(bin)
        .args([
            "design",
            cfg,
            "--quiet",
            "--out",
            d.join("fit").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("fit/fit.json")).unwrap()).unwrap();
    let c1 = v["fitted"][0].as_f64().unwrap();
    assert!((c1 / -0.1875 - 1.0).abs() < 1e-3, "c1 = {c1}");
    assert!(d.join("fit/loss.png").exists() && d.join("fit/rays.png").exists());
    assert_eq!(v["convergence"]["converged"], true, "{}", v["convergence"]);
    let text = std::fs::read_to_string(cfg).unwrap();
    // one L-BFGS iteration cannot converge: said in fit.json, on stderr and by exit status 3
    let short = d.join("short.toml");
    std::fs::write(&short, text.replace("iterations = 100", "iterations = 1")).unwrap();
    let o = std::process::Command::new(bin)
        .args(["design", short.to_str().unwrap(), "--quiet", "--out"])
        .arg(d.join("short"))
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("iteration limit"));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("short/fit.json")).unwrap()).unwrap();
    assert_eq!(v["convergence"]["stop"], "iteration_limit");
    for (name, bad, needle) in [
        (
            "name.toml",
            text.replace(r#"name = "c3""#, r#"name = "c9""#),
            r#"parameters.fit[2].name = "c9""#,
        ),
        (
            "profile.toml",
            text.replace(
                r#"{ profile = 0, name = "c1" }"#,
                r#"{ profile = 3, name = "c1" }"#,
            ),
            "parameters.fit[0].profile = 3",
        ),
        (
            "miss.toml",
            text.replace(
                "center = [0.0, 0.0, -3.141592653589793]",
                "center = [5.0, 0.0, -3.141592653589793]",
            ),
            "never enters the field",
        ),
    ] {
        std::fs::write(d.join(name), bad).unwrap();
        let o = std::process::Command::new(bin)
            .args([
                "design",
                d.join(name).to_str().unwrap(),
                "--out",
                d.join("bad").to_str().unwrap(),
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(needle) && !err.contains("panicked"),
            "{name}: {err}"
        );
        assert!(!d.join("bad/fit.json").exists());
    }
}
