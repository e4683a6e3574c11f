//! Mie theory against published reference values: Wiscombe's MIEV0 test cases (NCAR TN-140, 1979;
//! his `m = n − iκ` and amplitudes are the complex conjugates of Bohren & Huffman's, which we use)
//! and Bohren & Huffman's BHMIE example (App. A); the Rayleigh limit in closed form; the
//! size-distribution average and the phase-function table built from it.

use lightpath::math::C64;
use lightpath::medium::PhaseFunction;
use lightpath::medium::mie::{Particles, Polarisation, Sphere, angle_grid};
use std::f64::consts::PI;

fn sphere(x: f64, m: (f64, f64)) -> Sphere {
    Sphere::new(x, C64::new(m.0, m.1)).unwrap()
}

/// `|a − b| ≤ tol`, printing the case on failure.
fn near(what: &str, a: f64, b: f64, tol: f64) {
    assert!(
        (a - b).abs() <= tol,
        "{what}: {a} vs expected {b} (tolerance {tol})"
    );
}

/// Backscattering efficiency from Wiscombe's tabulated `S1(180°)`.
fn q_back_from(s1: (f64, f64), x: f64) -> f64 {
    4.0 * (s1.0 * s1.0 + s1.1 * s1.1) / (x * x)
}

#[test]
fn wiscombe_test_cases() {
    // (case, x, m, Q_sca, g, S1(180°) if tabulated); tabulated to 1e-6
    let tol = 1e-6;
    let cases = [
        (
            5,
            0.099,
            (0.75, 0.0),
            0.000007,
            0.001448,
            Some((1.81756e-8, -1.64810e-4)),
        ),
        (
            6,
            0.101,
            (0.75, 0.0),
            0.000008,
            0.001507,
            Some((2.04875e-8, -1.74965e-4)),
        ),
        (
            7,
            10.0,
            (0.75, 0.0),
            2.232265,
            0.896473,
            Some((-1.07857, -3.60881e-2)),
        ),
        (
            8,
            1000.0,
            (0.75, 0.0),
            1.997908,
            0.844944,
            Some((1.70578e1, 4.84251e2)),
        ),
        (9, 1.0, (1.33, 1e-5), 0.093923, 0.184517, None),
        (10, 100.0, (1.33, 1e-5), 2.096594, 0.868959, None),
        (11, 10000.0, (1.33, 1e-5), 1.723857, 0.907840, None),
        (12, 0.055, (1.5, 1.0), 0.000011, 0.000491, None),
        (13, 0.056, (1.5, 1.0), 0.000012, 0.000509, None),
        (14, 1.0, (1.5, 1.0), 0.6634538, 0.192136, None),
        (16, 10000.0, (1.5, 1.0), 1.236575, 0.846309, None),
        (18, 100.0, (10.0, 10.0), 1.836785, 0.556215, None),
        (19, 10000.0, (10.0, 10.0), 1.795393, 0.548194, None),
    ];
    for (case, x, m, q_sca, g, s1_back) in cases {
        let q = sphere(x, m).efficiencies();
        near(&format!("case {case} Q_sca"), q.sca, q_sca, tol);
        near(&format!("case {case} g"), q.g, g, tol);
        if let Some(s1) = s1_back {
            let b = q_back_from(s1, x);
            near(&format!("case {case} Q_back"), q.back, b, 2e-5 * b);
        }
    }
    // extinction where the tables give it
    near(
        "case 16 Q_ext",
        sphere(10000.0, (1.5, 1.0)).efficiencies().ext,
        2.004368,
        1e-6,
    );
    near(
        "case 12 Q_ext",
        sphere(0.055, (1.5, 1.0)).efficiencies().ext,
        0.101491,
        1e-6,
    );
    near(
        "case 13 Q_ext",
        sphere(0.056, (1.5, 1.0)).efficiencies().ext,
        0.103347,
        1e-6,
    );
}

#[test]
fn wiscombe_amplitudes_case_14() {
    // x = 1, m = 1.5 + i: S1, S2 at 0°, 30°, …, 180° (conjugated from Wiscombe's table)
    let s = sphere(1.0, (1.5, 1.0));
    let table = [
        ((0.584080, 0.190515), (0.584080, 0.190515)),
        ((0.565702, 0.187200), (0.500161, 0.145611)),
        ((0.517525, 0.178443), (0.287964, 0.041054)),
        ((0.456340, 0.167167), (0.0362285, -0.0618265)),
        ((0.400212, 0.156643), (-0.174875, -0.122959)),
        ((0.362157, 0.149391), (-0.305682, -0.143846)),
        ((0.348844, 0.146829), (-0.348844, -0.146829)),
    ];
    for (i, (s1, s2)) in table.into_iter().enumerate() {
        let theta = (30.0 * i as f64).to_radians();
        let (a, b) = s.amplitudes(theta.cos());
        let what = format!("θ = {}°", 30 * i);
        near(&format!("{what} Re S1"), a.re, s1.0, 1e-6);
        near(&format!("{what} Im S1"), a.im, -s1.1, 1e-6);
        near(&format!("{what} Re S2"), b.re, s2.0, 1e-6);
        near(&format!("{what} Im S2"), b.im, -s2.1, 1e-6);
    }
}

#[test]
fn bohren_huffman_examples() {
    // BHMIE: radius 0.525, λ 0.6328, m = 1.55: Q_ext = Q_sca = 3.10543, Q_back = 2.92534
    let x = 2.0 * PI * 0.525 / 0.6328;
    let q = sphere(x, (1.55, 0.0)).efficiencies();
    near("Q_ext", q.ext, 3.10543, 1e-5);
    near("Q_sca", q.sca, 3.10543, 1e-5);
    near("Q_back", q.back, 2.92534, 1e-5);
    near("g", q.g, 0.63314, 1e-5);
    near("Q_abs", q.abs, 0.0, 1e-12);
    // the same sphere absorbing, m = 1.55 + 0.1i (values to 11 digits from an independent code)
    let q = sphere(x, (1.55, 0.1)).efficiencies();
    near("Q_ext", q.ext, 2.86165188243, 1e-9);
    near("Q_sca", q.sca, 1.66424911991, 1e-9);
    near("Q_back", q.back, 0.20599534080, 1e-9);
    near("g", q.g, 0.80128972639, 1e-9);
    let q = sphere(2.5, (1.5, 0.5)).efficiencies();
    near("Q_ext", q.ext, 2.562873497454734, 1e-9);
    near("Q_sca", q.sca, 1.097071819088392, 1e-9);
    near("Q_back", q.back, 0.123586468179818, 1e-9);
    near("g", q.g, 0.748905978948507, 1e-9);
}

#[test]
fn rayleigh_limit() {
    // Q_sca = 8/3 x⁴ |K|², Q_abs = 4 x Im K, K = (m² − 1)/(m² + 2) (BH Eqs. 5.8–5.9); the next
    // order is O(x²) relative
    for m in [C64::new(1.33, 0.0), C64::new(1.5, 1.0), C64::new(3.0, 0.2)] {
        for x in [1e-4, 1e-3] {
            let q = Sphere::new(x, m).unwrap().efficiencies();
            let k = (m * m - 1.0) / (m * m + 2.0);
            let sca = 8.0 / 3.0 * x.powi(4) * k.norm_sqr();
            near(
                &format!("m {m} x {x} Q_sca"),
                q.sca / sca,
                1.0,
                10.0 * x * x,
            );
            if m.im > 0.0 {
                near(
                    &format!("m {m} x {x} Q_abs"),
                    q.abs / (4.0 * x * k.im),
                    1.0,
                    10.0 * x * x,
                );
            }
            near(&format!("m {m} x {x} g"), q.g, 0.0, x);
        }
    }
}

#[test]
fn energy_is_conserved_across_sizes() {
    // Q_ext = Q_sca + Q_abs (exact by construction for absorbing spheres, so check the
    // non-absorbing ones have Q_ext = Q_sca) and Q_sca → 2 (extinction paradox) for large x
    for x in [0.1, 1.0, 10.0, 100.0, 500.0] {
        let q = sphere(x, (1.2, 0.0)).efficiencies();
        near(
            &format!("x {x} Q_ext − Q_sca"),
            q.ext - q.sca,
            0.0,
            1e-10 * q.ext,
        );
    }
    let q = sphere(5000.0, (1.33, 0.0)).efficiencies();
    near("x 5000 Q_ext", q.ext, 2.0, 0.01);
}

fn silica(spread: f64) -> Particles {
    // 10 µm SiO₂ in agarose at 632.8 nm (lengths in µm)
    Particles {
        diameter: 10.0,
        spread,
        n_particle: C64::new(1.457, 0.0),
        n_medium: 1.335,
        wavelength: 0.6328 / 1.335,
    }
}

#[test]
fn table_integrates_to_one_with_the_series_g() {
    for pol in [
        Polarisation::Unpolarised,
        Polarisation::Perpendicular,
        Polarisation::Parallel,
    ] {
        let p = silica(0.0);
        let o = p.optics(&p.default_grid()).unwrap();
        let t = o.table(pol).unwrap();
        let rho = o.phase(pol);
        // the table normalises by the trapezoid, the phase by the series' C_sca: equal to 1e-4
        let h: f64 = o
            .cos
            .windows(2)
            .zip(rho.windows(2))
            .map(|(c, r)| PI * (r[0] + r[1]) * (c[1] - c[0]))
            .sum();
        near(&format!("{pol:?} ∫ρ dω"), h, 1.0, 1e-4);
        let f = PhaseFunction::Tabulated(t);
        if pol == Polarisation::Unpolarised {
            near("table g", f.mean_cosine(), o.g, 2e-4);
        }
        for (j, mu) in [(0usize, -1.0), (o.cos.len() - 1, 1.0)] {
            near(&format!("{pol:?} ρ({mu})"), f.eval(mu) / rho[j], 1.0, 1e-3);
        }
    }
}

#[test]
fn size_average() {
    // a tiny spread is the monodisperse sphere; a real one is the log-normal average of single
    // spheres (here by an independent midpoint rule on 4000 sizes in d); ⟨V⟩ is the log-normal's
    // third moment
    let cos = angle_grid(721);
    let mono = silica(0.0).optics(&cos).unwrap();
    let tiny = silica(1e-6).optics(&cos).unwrap();
    near("C_sca", tiny.c_sca / mono.c_sca, 1.0, 1e-5);
    near("g", tiny.g, mono.g, 1e-6);
    let p = silica(0.5);
    let poly = p.optics(&cos).unwrap();
    let s2 = (1.0 + (0.5f64 / 10.0).powi(2)).ln();
    let mu = 10f64.ln() - 0.5 * s2;
    near(
        "⟨V⟩",
        poly.mean_volume / (PI / 6.0 * (3.0 * mu + 4.5 * s2).exp()),
        1.0,
        1e-6,
    );
    let (s, m) = (s2.sqrt(), p.relative_index());
    let (mut w_sum, mut c_sca, mut g_c) = (0.0, 0.0, 0.0);
    let (d0, d1, n) = (7.0, 14.0, 4000);
    for i in 0..n {
        let d = d0 + (d1 - d0) * (i as f64 + 0.5) / n as f64;
        let w = (-0.5 * ((d.ln() - mu) / s).powi(2)).exp() / d;
        let q = Sphere::new(PI * d / p.wavelength, m)
            .unwrap()
            .efficiencies();
        let c = q.sca * PI * d * d / 4.0;
        (w_sum, c_sca, g_c) = (w_sum + w, c_sca + w * c, g_c + w * c * q.g);
    }
    near("⟨C_sca⟩", poly.c_sca / (c_sca / w_sum), 1.0, 1e-3);
    near("g", poly.g, g_c / c_sca, 1e-4);
    assert!(poly.g > 0.9 && poly.g < 1.0, "g {}", poly.g);
}

#[test]
fn refuses_bad_particles() {
    assert!(Sphere::new(0.0, C64::new(1.5, 0.0)).is_err());
    assert!(Sphere::new(f64::NAN, C64::new(1.5, 0.0)).is_err());
    assert!(Sphere::new(1.0, C64::new(1.5, -0.1)).is_err());
    assert!(Sphere::new(1.0, C64::new(-1.5, 0.0)).is_err());
    let mut p = silica(0.0);
    p.spread = -1.0;
    assert!(p.optics(&[0.0]).is_err());
    p.spread = 0.0;
    p.diameter = 1e9;
    let e = p.optics(&[0.0]).unwrap_err().to_string();
    assert!(e.contains("size parameter"), "{e}");
}

const SUSPENSION: &str = r#"
wavelength = 0.474
[medium]
slab = 100.0
volume_fraction = 0.01
phase = { kind = "mie", diameter = 4.0, n_particle = 1.59, n_medium = 1.335 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
"#;

#[test]
fn config_phase_and_volume_fraction() {
    let task = lightpath::config::scene_from_text(SUSPENSION).unwrap();
    let p = Particles {
        diameter: 4.0,
        spread: 0.0,
        n_particle: C64::new(1.59, 0.0),
        n_medium: 1.335,
        wavelength: 0.474,
    };
    let o = p.optics(&[1.0]).unwrap();
    let density = 0.01 / (PI / 6.0 * 64.0);
    let medium = &task.scene.medium;
    near("σ_s", medium.sigma_s / (density * o.c_sca), 1.0, 1e-12);
    near("σ_a", medium.sigma_a, 0.0, 0.0);
    let phase = medium.scattering.phase(0);
    near("g of the table", phase.mean_cosine(), o.g, 2e-4);
    // the same suspension given by its coefficients has the same phase function
    let by_sigma = SUSPENSION.replace(
        "volume_fraction = 0.01",
        &format!("sigma_s = {}", medium.sigma_s),
    );
    let again = lightpath::config::scene_from_text(&by_sigma).unwrap();
    assert_eq!(again.scene.medium, *medium);
}

#[test]
fn config_errors_name_the_key() {
    let cases = [
        (
            "n_medium = 1.335",
            "n_medium = 0.0",
            "medium.phase.n_medium = 0",
        ),
        (
            "diameter = 4.0",
            "diameter = 4.0, k_particle = -0.1",
            "medium.phase.k_particle = -0.1",
        ),
        ("diameter = 4.0", "diameter = 4.0e6", "size parameter"),
        (
            "volume_fraction = 0.01",
            "volume_fraction = 0.9",
            "medium.volume_fraction = 0.9",
        ),
        (
            "volume_fraction = 0.01",
            "volume_fraction = 0.01\nmfp = 3.0",
            "not with them",
        ),
        (
            "diameter = 4.0",
            "diameter = 4.0, polarisation = \"circular\"",
            "`circular`, expected one of",
        ),
    ];
    for (from, to, needle) in cases {
        let e = lightpath::config::scene_from_text(&SUSPENSION.replace(from, to)).unwrap_err();
        assert!(e.to_string().contains(needle), "{to}: {e}");
    }
    let hg = SUSPENSION.replace(
        "phase = { kind = \"mie\", diameter = 4.0, n_particle = 1.59, n_medium = 1.335 }",
        "phase = { kind = \"hg\", g = 0.9 }",
    );
    let e = lightpath::config::scene_from_text(&hg).unwrap_err();
    assert!(e.to_string().contains("volume_fraction needs"), "{e}");
}

fn run_mie(args: &[&str], name: &str) -> (std::process::Output, std::path::PathBuf) {
    let out = std::env::temp_dir().join(format!("lightpath-mie-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .arg("mie")
        .args(args)
        .args(["--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    (o, out)
}

#[test]
fn mie_command() {
    use lightpath::io::ResultFile;
    use lightpath::io::results::MieFile;
    // Bohren & Huffman's sphere: radius 0.525 µm, λ 0.6328 µm, m = 1.55, in vacuum
    let (o, out) = run_mie(
        &[
            "--diameter",
            "1.05",
            "--n-particle",
            "1.55",
            "--wavelength",
            "0.6328",
        ]
        .iter()
        .chain(&["--angles", "3601", "--volume-fraction", "0.001"])
        .copied()
        .collect::<Vec<_>>(),
        "bh",
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let f = MieFile::read(&out.join("mie.json")).unwrap();
    near("Q_ext", f.q_ext, 3.10543, 1e-5);
    near("Q_back", f.q_back, 2.92534, 1e-5);
    near("g", f.g, 0.63314, 1e-5);
    assert!(out.join("mie.png").exists());
    let mut integral = 0.0;
    for i in 1..f.theta_deg.len() {
        let (c0, c1) = (
            f.theta_deg[i - 1].to_radians().cos(),
            f.theta_deg[i].to_radians().cos(),
        );
        integral += PI * (f.phase[i] + f.phase[i - 1]) * (c0 - c1);
        let mean = 0.5 * (f.phase_perpendicular[i] + f.phase_parallel[i]);
        near("ρ = (ρ⊥ + ρ∥)/2", f.phase[i], mean, 1e-12 * f.phase[i]);
    }
    near("∫ρ dω (trapezoid on 0.05° steps)", integral, 1.0, 1e-5);
    // forward: S1 = S2 and Re S(0) = x² Q_ext / 4 (optical theorem)
    let x = f.size_parameter;
    near(
        "Re S1(0)",
        f.s1_re[0],
        x * x * f.q_ext / 4.0,
        1e-9 * f.s1_re[0],
    );
    near("S1(0) = S2(0)", f.s1_im[0], f.s2_im[0], 1e-12);
    let b = f.bulk.unwrap();
    near(
        "σ_s",
        b.sigma_s,
        0.001 / (PI / 6.0 * 1.05f64.powi(3)) * f.c_sca,
        1e-12 * b.sigma_s,
    );
    let (o, out) = run_mie(
        &[
            "--diameter=-1",
            "--n-particle",
            "1.55",
            "--wavelength",
            "0.6328",
        ],
        "bad",
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--diameter -1"),
        "{err}"
    );
    assert!(!out.join("mie.json").exists());
}

#[test]
fn mixture_of_sphere_sizes_by_volume_fraction() {
    // 4 µm and 10 µm spheres, 1 % and 2 % by volume: σ_s adds, the shares follow
    let text = SUSPENSION.replace(
        "volume_fraction = 0.01\nphase = { kind = \"mie\", diameter = 4.0, n_particle = 1.59, n_medium = 1.335 }",
        r#"[medium.phase]
kind = "mixture"
components = [
  { volume_fraction = 0.01, phase = { kind = "mie", diameter = 4.0, n_particle = 1.59, n_medium = 1.335 } },
  { volume_fraction = 0.02, phase = { kind = "mie", diameter = 10.0, n_particle = 1.457, n_medium = 1.335, k_particle = 1e-4 } },
]"#,
    );
    let task = lightpath::config::scene_from_text(&text).unwrap();
    let part = |d: f64, n: (f64, f64), f: f64| {
        let p = Particles {
            diameter: d,
            spread: 0.0,
            n_particle: C64::new(n.0, n.1),
            n_medium: 1.335,
            wavelength: 0.474,
        };
        let o = p.optics(&[1.0]).unwrap();
        let density = f / (PI / 6.0 * d.powi(3));
        (density * o.c_sca, density * o.c_abs)
    };
    let (s1, a1) = part(4.0, (1.59, 0.0), 0.01);
    let (s2, a2) = part(10.0, (1.457, 1e-4), 0.02);
    let m = &task.scene.medium;
    near("σ_s", m.sigma_s / (s1 + s2), 1.0, 1e-12);
    near("σ_a", m.sigma_a / (a1 + a2), 1.0, 1e-12);
    assert!(a2 > 0.0);
    let shares = m.scattering.components();
    near(
        "share of the 4 µm spheres",
        shares[0].0,
        s1 / (s1 + s2),
        1e-12,
    );
    // mixing weights and volume fractions, or a volume fraction on another kind, is refused
    for (from, to, needle) in [
        (
            "{ volume_fraction = 0.01,",
            "{ weight = 0.5,",
            "every component a volume_fraction",
        ),
        (
            "{ volume_fraction = 0.02, phase = { kind = \"mie\", diameter = 10.0, n_particle = 1.457, n_medium = 1.335, k_particle = 1e-4 } }",
            "{ volume_fraction = 0.02, phase = { kind = \"hg\", g = 0.5 } }",
            "components[1].volume_fraction needs",
        ),
        ("[medium]\n", "[medium]\nmfp = 3.0\n", "leave out mfp"),
        ("volume_fraction = 0.02", "volume_fraction = 0.9", "sum to"),
    ] {
        let e = lightpath::config::scene_from_text(&text.replace(from, to)).unwrap_err();
        assert!(e.to_string().contains(needle), "{to}: {e}");
    }
}
