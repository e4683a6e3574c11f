//! The phase function read from speckle images (paper 004): on images rendered by Algorithm 2 for a
//! slab of known phase function, on pure noise, and through `lightpath acquire-phase`.

use lightpath::inverse::phase_from_speckle::{
    Pair, Relay, Settings, correlation_points, fit_correlation, fit_hg, flatness, read_curves,
    significant,
};
use lightpath::io::images::Image;
use lightpath::mc::{Plan, merge, run};
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering};
use lightpath::speckle::paths::SubpathSampler;
use lightpath::speckle::{FieldSampler, Light, Scene, View};

const SIDE: usize = 64;

/// A relay with 0.15° pixels in a sample of the outside's index (no refraction).
fn relay() -> Relay {
    Relay {
        focal_length: 1.0,
        pixel_pitch: 0.15f64.to_radians().tan(),
        n_sample: 1.0,
        n_outside: 1.0,
        axis_px: [31.5, 31.5],
    }
}

/// `realisations` speckle image pairs of a slab (thickness 10 λ at optical depth `od`, HG `g`)
/// under two plane waves focused by the relay on pixels `p1` and `p2`.
fn render(od: f64, g: f64, p1: [f64; 2], p2: [f64; 2], realisations: u64) -> Vec<[Image; 2]> {
    let r = relay();
    let medium = Medium {
        // the window sets the speckle grain: λ / 200 rad ≈ 2 pixels
        geometry: Geometry::slab(10.0, 200.0),
        sigma_s: od / 10.0,
        sigma_a: 0.0,
        scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g }),
    };
    let lights = [p1, p2]
        .iter()
        .map(|p| Light::PlaneWave {
            direction: r.direction(p[0], p[1]),
        })
        .collect();
    let views = (0..SIDE * SIDE)
        .map(|i| View::FarField {
            direction: r.direction((i % SIDE) as f64, (i / SIDE) as f64),
        })
        .collect();
    let scene = Scene::new(1.0, medium, lights, views);
    let est = FieldSampler::new(&scene, SubpathSampler::all_pairs(&scene), true).unwrap();
    (0..realisations)
        .map(|k| {
            let plan = Plan::new(1000 + k, 3000, 500);
            let root = merge(run(&est, &plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap();
            let image = |l: usize| Image {
                width: SIDE,
                height: SIDE,
                data: root.sum[l * SIDE * SIDE..(l + 1) * SIDE * SIDE]
                    .iter()
                    .map(|z| z.norm_sqr())
                    .collect(),
                full_scale: None,
            };
            [image(0), image(1)]
        })
        .collect()
}

fn settings() -> Settings {
    Settings {
        window: 8,
        step: 3,
        ballistic_radius: 0.0,
        register_px: 0,
    }
}

const P1: [f64; 2] = [32.0, 12.0];
const P2: [f64; 2] = [32.0, 32.0];

/// OD 1, g = 0.9; illuminations 20 pixels (3°) apart; rendered once for every test here.
fn rendered() -> &'static [[Image; 2]] {
    static IMAGES: std::sync::OnceLock<Vec<[Image; 2]>> = std::sync::OnceLock::new();
    IMAGES.get_or_init(|| render(1.0, 0.9, P1, P2, 40))
}

#[test]
fn reads_the_phase_function_of_rendered_images() {
    // readings along the row ⟂ Δ through the first illumination
    let pairs = pairs_of(rendered());
    let curves = read_curves(&pairs, &relay(), &settings()).unwrap();
    assert_eq!(curves.len(), 1);
    let c = &curves[0];
    assert!(significant(c, &settings()), "{:?}", flatness(c));
    let fit = fit_correlation(c).unwrap();
    let (mu, _, _) = correlation_points(c);
    let naive_sd: Vec<f64> = c.readings.iter().map(|r| 0.02 * r.intensity).collect();
    let naive_y: Vec<f64> = c.readings.iter().map(|r| r.intensity).collect();
    let naive = fit_hg(&mu, &naive_y, &naive_sd, 1).unwrap();
    eprintln!(
        "{} readings over {:.1}°…{:.1}°, grain {:.2} px: correlation g = {:.4} ± {:.4} (χ²/dof {:.2}), intensity g = {:.4}",
        c.readings.len(),
        c.readings
            .iter()
            .map(|r| r.angle_deg)
            .fold(f64::INFINITY, f64::min),
        c.readings.iter().map(|r| r.angle_deg).fold(0.0, f64::max),
        c.grain_px,
        fit.g,
        fit.g_stderr,
        fit.chi2_dof,
        naive.g
    );
    assert!(
        (fit.g - 0.9).abs() < 3.0 * fit.g_stderr,
        "g {} ± {}",
        fit.g,
        fit.g_stderr
    );
    assert!(fit.g_stderr < 0.02, "too noisy to tell: ± {}", fit.g_stderr);
    assert!(
        fit.chi2_dof < 2.0,
        "the error bars do not describe the scatter: {}",
        fit.chi2_dof
    );
}

/// Independent exponential intensities (speckle with a one-pixel grain), uncorrelated.
fn noise(seed: u64) -> Image {
    let mut s = seed;
    let data = (0..SIDE * SIDE)
        .map(|_| {
            s = lightpath::math::splitmix64(s);
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            -(1.0 - u).ln()
        })
        .collect();
    Image {
        width: SIDE,
        height: SIDE,
        data,
        full_scale: None,
    }
}

/// 20 pairs of noise images.
fn noise_images() -> Vec<[Image; 2]> {
    (0..20)
        .map(|k| [noise(2 * k + 1), noise(2 * k + 2)])
        .collect()
}

/// The pairs of `images`, all with the illuminations at `P1` and `P2`.
fn pairs_of(images: &[[Image; 2]]) -> Vec<Pair<'_>> {
    images
        .iter()
        .map(|[a, b]| Pair {
            first: a,
            second: b,
            peaks: [P1, P2],
        })
        .collect()
}

#[test]
fn pure_noise_reads_flat() {
    let images = noise_images();
    let pairs = pairs_of(&images);
    let c = &read_curves(&pairs, &relay(), &settings()).unwrap()[0];
    let (chi2, dof) = flatness(c);
    eprintln!(
        "noise: χ² {chi2:.1} over {dof} readings, grain {:.2} px",
        c.grain_px
    );
    assert!(!significant(c, &settings()));
    // the SNR model's error bars describe the scatter (χ²/dof within 4 sd of 1)
    assert!(
        (chi2 / dof as f64 - 1.0).abs() < 4.0 * (2.0 / dof as f64).sqrt(),
        "{chi2} / {dof}"
    );
}

/// Write `image` as a 16-bit grey PNG scaled by `scale` (codes clamped to 65535).
fn write_png16(path: &std::path::Path, image: &Image, scale: f64) {
    let file = std::fs::File::create(path).unwrap();
    let mut enc = png::Encoder::new(file, image.width as u32, image.height as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut w = enc.write_header().unwrap();
    let bytes: Vec<u8> = image
        .data
        .iter()
        .flat_map(|v| ((v * scale).round().min(65535.0) as u16).to_be_bytes())
        .collect();
    w.write_image_data(&bytes).unwrap();
}

fn write_tiff16(path: &std::path::Path, image: &Image, scale: f64) {
    use tiff::encoder::{TiffEncoder, colortype};
    let mut f = std::fs::File::create(path).unwrap();
    let data: Vec<u16> = image
        .data
        .iter()
        .map(|v| (v * scale).round().min(65535.0) as u16)
        .collect();
    TiffEncoder::new(&mut f)
        .unwrap()
        .write_image::<colortype::Gray16>(image.width as u32, image.height as u32, &data)
        .unwrap();
}

/// Each pair written as `a{k}.exr`, `b{k}.exr` in `dir`, listed with the peaks `P1`, `P2`.
fn write_pairs(
    dir: &std::path::Path,
    images: &[[Image; 2]],
) -> Vec<(String, String, [[f64; 2]; 2])> {
    let mut pairs = Vec::new();
    for (k, [a, b]) in images.iter().enumerate() {
        let (na, nb) = (format!("a{k}.exr"), format!("b{k}.exr"));
        lightpath::io::exr::write_scalar(&dir.join(&na), &a.data, SIDE, SIDE, "I").unwrap();
        lightpath::io::exr::write_scalar(&dir.join(&nb), &b.data, SIDE, SIDE, "I").unwrap();
        pairs.push((na, nb, [P1, P2]));
    }
    pairs
}

fn acquisition(
    dir: &std::path::Path,
    pairs: &[(String, String, [[f64; 2]; 2])],
) -> std::path::PathBuf {
    let mut text = format!(
        "[acquisition]\nfocal_length = 1.0\npixel_pitch = {}\nn_sample = 1.0\nwindow = 8\nstep = 3\n",
        0.15f64.to_radians().tan()
    );
    for (a, b, peaks) in pairs {
        text += &format!("[[pair]]\nfirst = \"{a}\"\nsecond = \"{b}\"\npeaks = {peaks:?}\n");
    }
    let cfg = dir.join("acquire.toml");
    std::fs::write(&cfg, text).unwrap();
    cfg
}

fn lightpath(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn command_reads_png_tiff_and_exr() {
    use lightpath::io::ResultFile;
    use lightpath::io::results::PhaseAcquisitionFile;
    let dir = std::env::temp_dir().join(format!("lightpath-acquire-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let images = rendered();
    let top = images
        .iter()
        .flat_map(|p| p.iter().flat_map(|i| i.data.iter()))
        .fold(0.0f64, |a, &b| a.max(b));
    let scale = 60000.0 / top;
    let mut pairs = Vec::new();
    for (k, [a, b]) in images.iter().enumerate() {
        let (na, nb) = match k % 3 {
            0 => {
                let (na, nb) = (format!("a{k}.png"), format!("b{k}.png"));
                write_png16(&dir.join(&na), a, scale);
                write_png16(&dir.join(&nb), b, scale);
                (na, nb)
            }
            1 => {
                let (na, nb) = (format!("a{k}.tif"), format!("b{k}.tif"));
                write_tiff16(&dir.join(&na), a, scale);
                write_tiff16(&dir.join(&nb), b, scale);
                (na, nb)
            }
            _ => {
                let (na, nb) = (format!("a{k}.exr"), format!("b{k}.exr"));
                lightpath::io::exr::write_scalar(&dir.join(&na), &a.data, SIDE, SIDE, "I").unwrap();
                lightpath::io::exr::write_scalar(&dir.join(&nb), &b.data, SIDE, SIDE, "I").unwrap();
                (na, nb)
            }
        };
        pairs.push((na, nb, [P1, P2]));
    }
    let cfg = acquisition(&dir, &pairs);
    let out = dir.join("out");
    let o = lightpath(&[
        "acquire-phase",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    eprintln!("{stdout}");
    let f = PhaseAcquisitionFile::read(&out.join("phase_acquisition.json")).unwrap();
    assert_eq!(f.curves.len(), 1);
    let c = &f.curves[0];
    assert!(c.significant);
    let g = c.hg.as_ref().unwrap();
    assert!((g.g - 0.9).abs() < 3.0 * g.g_stderr, "{g:?}");
    // the readings on the HG's scale follow the true HG within their errors
    let mut chi2 = 0.0;
    for r in &c.readings {
        if let (Some(rho), Some(sd)) = (r.rho, r.rho_stderr) {
            chi2 += ((rho
                - lightpath::inverse::phase_from_speckle::hg(
                    0.9,
                    r.reading.angle_deg.to_radians().cos(),
                ))
                / sd)
                .powi(2);
        }
    }
    assert!(
        chi2 / (c.readings.len() as f64) < 3.0,
        "χ²/n {}",
        chi2 / c.readings.len() as f64
    );
    assert!(c.vmf.is_some());
    assert!(out.join("phase_acquisition.png").exists());

    // bad input: each names the file or key and writes nothing
    let bad = |name: &str, pairs: &[(String, String, [[f64; 2]; 2])], needle: &str| {
        let sub = dir.join(name);
        std::fs::create_dir_all(&sub).unwrap();
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            if e.path().is_file() {
                std::fs::copy(e.path(), sub.join(e.file_name())).unwrap();
            }
        }
        let cfg = acquisition(&sub, pairs);
        let out = sub.join("out");
        let o = lightpath(&[
            "acquire-phase",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{name}: should fail");
        assert!(err.contains(needle), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(!out.join("phase_acquisition.json").exists(), "{name}");
    };
    let p0 = pairs[0].clone();
    bad(
        "zero-delta",
        &[(p0.0.clone(), p0.1.clone(), [P1, P1])],
        "Δ ≠ 0",
    );
    let small = Image {
        width: 32,
        height: 32,
        data: vec![1.0; 1024],
        full_scale: None,
    };
    write_png16(&dir.join("small.png"), &small, 1.0);
    bad(
        "sizes",
        &[(p0.0.clone(), "small.png".into(), [P1, P2])],
        "small.png is 32×32",
    );
    let mut hot = images[0][0].clone();
    hot.data[12 * SIDE + 40] = top;
    write_png16(&dir.join("hot.png"), &hot, 65535.0 / top);
    bad(
        "saturated",
        &[("hot.png".into(), p0.1.clone(), [P1, P2])],
        "hot.png has 1 saturated",
    );
    std::fs::write(dir.join("notes.png"), "not an image").unwrap();
    bad(
        "unknown",
        &[("notes.png".into(), p0.1.clone(), [P1, P2])],
        "notes.png: not an image",
    );
    let mut nan = images[0][0].clone();
    nan.data[5] = f64::NAN;
    lightpath::io::exr::write_scalar(&dir.join("nan.exr"), &nan.data, SIDE, SIDE, "I").unwrap();
    bad(
        "nan",
        &[("nan.exr".into(), p0.1.clone(), [P1, P2])],
        "pixel (5, 0) is not a finite number",
    );
}

/// `[fit]` hands the readings to `lightpath fit` as normalised correlations over each window: from
/// images of an OD 2 slab (mfp 5) and a guess of twice the true mfp, the fit recovers it.
#[test]
fn readings_become_a_fit_target() {
    use lightpath::io::ResultFile;
    use lightpath::io::results::{FitFile, PhaseAcquisitionFile};
    let dir = std::env::temp_dir().join(format!("lightpath-handoff-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let pairs = write_pairs(&dir, &render(2.0, 0.7, P1, P2, 20));
    let cfg = acquisition(&dir, &pairs);
    let mut text = std::fs::read_to_string(&cfg).unwrap();
    text += "[fit]\nscene = \"slab.toml\"\n";
    std::fs::write(&cfg, text).unwrap();
    std::fs::write(
        dir.join("slab.toml"),
        "wavelength = 1.0\n[medium]\nslab = 10.0\nslab_window = 200.0\nmfp = 10.0\nalbedo = 1.0\nphase = { kind = \"hg\", g = 0.7 }\n[render]\nsamples = 10000\nseed = 3\n",
    )
    .unwrap();
    let out = dir.join("out");
    let o = lightpath(&[
        "acquire-phase",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("lightpath fit"), "{stdout}");
    // windows of 8 pixels read every 3: every third reading shares no pixel with the one before
    let read = PhaseAcquisitionFile::read(&out.join("phase_acquisition.json")).unwrap();
    let readings = read.curves[0].readings.len();
    let target: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fit_target.json")).unwrap())
            .unwrap();
    assert_eq!(
        target["entries"].as_array().unwrap().len(),
        readings.div_ceil(3)
    );
    let fit = dir.join("fit");
    let o = lightpath(&[
        "fit",
        out.join("fit_scene.toml").to_str().unwrap(),
        "--target",
        out.join("fit_target.json").to_str().unwrap(),
        "--fit",
        "mfp",
        "--out",
        fit.to_str().unwrap(),
    ]);
    eprintln!("{}", String::from_utf8_lossy(&o.stdout));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let f = FitFile::read(&fit.join("fit.json")).unwrap();
    let (mfp, sd) = (f.fitted[0], f.stddev[0]);
    eprintln!("mfp {mfp} ± {sd} (truth 5)");
    assert!((mfp - 5.0).abs() < 3.0 * sd, "mfp {mfp} ± {sd}");
    assert!(sd < 0.2 * mfp, "too uncertain to tell: ± {sd}");
}

/// `source_shift` places the second illumination from the first through the relay (magnification
/// `−f / f_source`): the readings equal those with the peaks given by hand, and a stage axis taken
/// the wrong way round is reported.
#[test]
fn source_translation_places_the_second_illumination() {
    use lightpath::io::ResultFile;
    use lightpath::io::results::PhaseAcquisitionFile;
    let dir = std::env::temp_dir().join(format!("lightpath-source-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // the ballistic light focuses on one pixel of each image, far above the speckle
    let peaked: Vec<[Image; 2]> = rendered()
        .iter()
        .take(8)
        .map(|[a, b]| {
            let (mut a, mut b) = (a.clone(), b.clone());
            let top = a.data.iter().chain(&b.data).fold(0.0f64, |m, &v| m.max(v));
            a.data[P1[1] as usize * SIDE + P1[0] as usize] = 100.0 * top;
            b.data[P2[1] as usize * SIDE + P2[0] as usize] = 100.0 * top;
            [a, b]
        })
        .collect();
    let pairs = write_pairs(&dir, &peaked);
    let read = |name: &str, text: String| {
        let cfg = dir.join(format!("{name}.toml"));
        std::fs::write(&cfg, text).unwrap();
        let out = dir.join(name);
        let o = lightpath(&[
            "acquire-phase",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let f = PhaseAcquisitionFile::read(&out.join("phase_acquisition.json")).unwrap();
        (f, String::from_utf8_lossy(&o.stdout).to_string())
    };
    let by_hand = std::fs::read_to_string(acquisition(&dir, &pairs)).unwrap();
    // Δ = P2 − P1 = 20 px along y; with f_source = 2 f the source moved −2 · 20 pitch
    let pitch = 0.15f64.to_radians().tan();
    let shifted = |shift: [f64; 2]| {
        let mut text = by_hand
            .lines()
            .filter(|l| !l.starts_with("peaks"))
            .collect::<Vec<_>>()
            .join("\n");
        text = text.replacen("[[pair]]", "source_focal_length = 2.0\n[[pair]]", 1);
        text.replace("[[pair]]", &format!("[[pair]]\nsource_shift = {shift:?}"))
    };
    let (a, _) = read("by_hand", by_hand.clone());
    let (b, _) = read("shifted", shifted([0.0, -40.0 * pitch]));
    assert_eq!(a.curves, b.curves);
    assert!(b.warnings.is_empty(), "{:?}", b.warnings);
    // the stage's axes swapped against the sensor's: the peak is found 28 px from where the
    // translation puts it
    let (c, stdout) = read("swapped", shifted([-40.0 * pitch, 0.0]));
    assert_eq!(c.warnings.len(), 8, "{:?}", c.warnings);
    assert!(
        stdout.contains("warning: pair[0]: source_shift puts"),
        "{stdout}"
    );
    assert!(c.warnings[0].contains("(28 px away)"), "{}", c.warnings[0]);
}

/// Registration (`register_px`): the second images displaced by (2, 1) pixels, as a distorting
/// lens would, lose their correlation where the windows sit where `Δ` puts them; searching ±3
/// pixels (the shift chosen on one window half, used on the other) finds it again and reads the
/// phase function as before. Pure noise stays flat under the same search.
#[test]
fn registration_finds_displaced_windows_and_leaves_noise_flat() {
    let moved: Vec<[Image; 2]> = rendered()
        .iter()
        .map(|[a, b]| {
            let mut m = b.clone();
            for y in 0..SIDE {
                for x in 0..SIDE {
                    let (sx, sy) = (x.saturating_sub(2), y.saturating_sub(1));
                    m.data[y * SIDE + x] = b.at(sx, sy);
                }
            }
            [a.clone(), m]
        })
        .collect();
    let read = |images: &[[Image; 2]], register_px: usize| {
        let pairs = pairs_of(images);
        let s = Settings {
            register_px,
            ..settings()
        };
        let c = read_curves(&pairs, &relay(), &s).unwrap().remove(0);
        let sum: f64 = c.readings.iter().map(|r| r.correlation).sum();
        let fit = fit_correlation(&c);
        (c, fit, sum)
    };
    let (_, _, aligned) = read(rendered(), 0);
    let (_, _, lost) = read(&moved, 0);
    let (c, fit, found) = read(&moved, 3);
    let fit = fit.unwrap();
    eprintln!(
        "Σ C: aligned {aligned:.3e}, displaced {lost:.3e}, registered {found:.3e}; g = {:.4} ± {:.4}",
        fit.g, fit.g_stderr
    );
    assert!(
        lost < 0.5 * aligned,
        "the displacement should cost correlation"
    );
    assert!(found > 0.8 * aligned, "registration should find it again");
    assert!(significant(&c, &settings()));
    assert!((fit.g - 0.9).abs() < 3.0 * fit.g_stderr, "{fit:?}");
    // noise: the shift chosen on one half does not select noise on the other
    let images = noise_images();
    let pairs = pairs_of(&images);
    let s = Settings {
        register_px: 3,
        ..settings()
    };
    let c = &read_curves(&pairs, &relay(), &s).unwrap()[0];
    let (chi2, dof) = flatness(c);
    eprintln!("registered noise: χ² {chi2:.1} over {dof}");
    assert!(!significant(c, &s));
    assert!(
        (chi2 / dof as f64 - 1.0).abs() < 4.0 * (2.0 / dof as f64).sqrt(),
        "{chi2} / {dof}"
    );
    let mean: f64 = c
        .readings
        .iter()
        .map(|r| r.correlation / r.stderr)
        .sum::<f64>()
        / c.readings.len() as f64;
    assert!(
        mean.abs() < 4.0 / (dof as f64).sqrt(),
        "noise reads biased: mean z {mean}"
    );
}
