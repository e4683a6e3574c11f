//! Derivatives of rendered powers with respect to the medium (path-space scores in particle
//! tracing): a pure absorber's transmission against Beer–Lambert per photon, and a scattering
//! slab with Fresnel faces against finite differences of independent renders (the expectation's
//! slope), for σ_s, σ_a and the Henyey–Greenstein g, on both sides; bad keys refused by name, and
//! `render.json` carrying them.

mod common;

use common::{bare_scene, flux, render};
use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, Profile};
use lightpath::medium::params::Param;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{Derivative, Light, RenderScene, Volume};

/// A slab (faces at z = ±0.5, wide beyond where light spreads) of index `n` in air under a normal
/// beam, with flux sensors on both faces: transmitted (0) and reflected (1).
fn slab(n: f64, sigma_s: f64, sigma_a: f64, g: f64, derivatives: Vec<Param>) -> RenderScene {
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Constant { n },
                Bounds::Box {
                    half: DVec3::new(30.0, 30.0, 0.5),
                },
                1.0,
            ),
            sigma_s,
            sigma_a,
            scattering: Scattering::single(PhaseFunction::HenyeyGreenstein { g }),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -1.0),
            direction: DVec3::Z,
            radius: 0.0,
        },
        sensors: vec![flux("T", 0.5), flux("R", -0.5)],
        derivatives: derivatives.into_iter().map(Derivative::Medium).collect(),
        ..bare_scene(0.01)
    }
}

/// A pure absorber (σ_a = 2, no scattering) transmits `e^{−σ_a}` of a normal beam, each
/// transmitted photon with the score `−L = −1` of its flight: the derivative is minus the
/// transmission photon for photon.
#[test]
fn an_absorber_differentiates_as_beer_lambert() {
    let s = slab(1.0, 0.0, 2.0, 0.0, vec![Param::SigmaA]);
    let (e, est) = render(&s, 20_000, 3);
    let (t, st) = (e.mean[est.power(0)].re, e.stderr[est.power(0)]);
    let d = e.mean[est.power_derivative(0, 0)].re;
    assert!((t - (-2.0f64).exp()).abs() < 4.0 * st, "T = {t} ± {st}");
    assert!((d + t).abs() < 1e-12, "dT/dσ_a = {d}, −T = {}", -t);
}

/// A scattering slab with Fresnel faces (n = 1.33, σ_s = 2, σ_a = 0.3, g = 0.6): the estimated
/// derivatives of T and R against central differences of independent renders at θ ± h (4
/// combined standard errors; the differences' own error, O(h²), is far below them).
#[test]
fn a_scattering_slab_differentiates_as_its_differences() {
    let (sigma_s, sigma_a, g) = (2.0, 0.3, 0.6);
    let params = vec![Param::SigmaS, Param::SigmaA, Param::G(0)];
    let s = slab(1.33, sigma_s, sigma_a, g, params.clone());
    let (e, est) = render(&s, 400_000, 11);
    for (j, (param, h)) in params.iter().zip([0.1, 0.05, 0.05]).enumerate() {
        let at = |v: f64, seed: u64| {
            let (mut ss, mut sa, mut gg) = (sigma_s, sigma_a, g);
            match param {
                Param::SigmaS => ss = v,
                Param::SigmaA => sa = v,
                _ => gg = v,
            }
            let scene = slab(1.33, ss, sa, gg, vec![]);
            let (e, est) = render(&scene, 1_000_000, seed);
            [0, 1].map(|i| (e.mean[est.power(i)].re, e.stderr[est.power(i)]))
        };
        let v0 = [sigma_s, sigma_a, g][j];
        let (up, down) = (at(v0 + h, 100 + j as u64), at(v0 - h, 200 + j as u64));
        for i in 0..2 {
            let fd = (up[i].0 - down[i].0) / (2.0 * h);
            let sfd = up[i].1.hypot(down[i].1) / (2.0 * h);
            let k = est.power_derivative(i, j);
            let (d, sd) = (e.mean[k].re, e.stderr[k]);
            eprintln!(
                "d{}/d{}: {d:.5} ± {sd:.5}, differences {fd:.5} ± {sfd:.5}",
                ["T", "R"][i],
                param.name()
            );
            assert!(
                (d - fd).abs() < 4.0 * sd.hypot(sfd),
                "d{}/d{}: {d} ± {sd}, differences {fd} ± {sfd}",
                ["T", "R"][i],
                param.name()
            );
        }
    }
}

/// A screen's derivative image: its pixels add up to the derivative of its power (every photon
/// adding to one adds to the other), and it is not the power's image.
#[test]
fn a_screens_derivative_image_adds_up_to_its_power() {
    let mut s = slab(1.33, 2.0, 0.3, 0.6, vec![Param::SigmaA, Param::G(0)]);
    s.sensors[0] = lightpath::rrte::Sensor::new(
        "screen".into(),
        lightpath::rrte::SensorKind::Screen,
        DVec3::new(0.0, 0.0, 0.5),
        DVec3::Z,
        Some([3.0, 3.0]),
        [8, 8],
    );
    let (e, est) = render(&s, 100_000, 4);
    for j in 0..2 {
        let d = est.derivative_image(0, j);
        let pixels: f64 = (0..d.pixels).map(|k| e.mean[d.first + k].re).sum();
        let total = e.mean[d.total()].re;
        assert!(
            (pixels - total).abs() <= 1e-12 * total.abs() && total != 0.0,
            "parameter {j}: pixels {pixels}, total {total}"
        );
    }
    // a flux sensor's derivative has no pixels
    assert_eq!(est.derivative_image(1, 0).pixels, 0);
}

/// Bad `render.derivatives` are refused by key; good ones reach `render.json`.
#[test]
fn derivatives_are_checked_and_written() {
    let text = |derivatives: &str, extra: &str| {
        format!(
            "[field]\nprofiles = [{{ kind = \"constant\", n = 1.0 }}]\nbounds = {{ kind = \"box\", size = [4.0, 4.0, 1.0] }}\n[medium]\nsigma_s = 1.0\nsigma_a = 0.1\nphase = {{ kind = \"hg\", g = 0.5 }}\n[light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -1.0]\ndirection = [0.0, 0.0, 1.0]\n[[sensor]]\nkind = \"flux\"\nname = \"T\"\ncenter = [0.0, 0.0, 0.5]\nnormal = [0.0, 0.0, 1.0]\n[[sensor]]\nkind = \"screen\"\nname = \"S\"\ncenter = [0.0, 0.0, 1.0]\nnormal = [0.0, 0.0, 1.0]\nsize = [2.0, 2.0]\npixels = [4, 4]\n[render]\nsamples = 4000\nchunk = 1000\nderivatives = {derivatives}\n{extra}"
        )
    };
    let refused = |t: String, needles: &[&str]| {
        let Err(e) = lightpath::config::load_text(&t) else {
            panic!("not refused: {t}")
        };
        let e = e.to_string();
        for n in needles {
            assert!(e.contains(n), "{n:?} not in: {e}");
        }
    };
    refused(
        text("[\"sigma_q\"]", ""),
        &["render.derivatives[0] = \"sigma_q\"", "allowed"],
    );
    refused(
        text("[\"bin[3]\"]", ""),
        &["render.derivatives[0]", "no such parameter"],
    );
    refused(
        text("[\"g\", \"g\"]", ""),
        &["render.derivatives[1]", "once"],
    );
    refused(
        text("[\"g\"]", "estimator = \"bidirectional\""),
        &["render.derivatives", "particle"],
    );
    // written to render.json beside each sensor's power
    let dir = std::env::temp_dir().join(format!("lightpath-derivatives-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("slab.toml");
    std::fs::write(&cfg, text("[\"sigma_a\", \"g\"]", "")).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "render",
            cfg.to_str().unwrap(),
            "--out",
            dir.join("out").to_str().unwrap(),
            "--quiet",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/render.json")).unwrap())
            .unwrap();
    let sensor = &json["sensors"][0];
    let power = sensor["power"]["mean"].as_f64().unwrap();
    let d = sensor["derivatives"]["sigma_a"]["mean"].as_f64().unwrap();
    // every transmitted photon crossed the slab: dT/dσ_a = −E[L] T with L ≥ 1
    assert!(d <= -power && power > 0.0, "dT/dσ_a = {d}, T = {power}");
    assert!(sensor["derivatives"]["g"]["stderr"].as_f64().unwrap() > 0.0);
    // the screen's derivative images, written and listed
    let files: Vec<&str> = json["sensors"][1]["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    for name in ["screen_S.exr", "screen_S_d_sigma_a.exr", "screen_S_d_g.exr"] {
        assert!(files.contains(&name), "{files:?}");
        assert!(dir.join("out").join(name).exists(), "{name}");
    }
    assert!(dir.join("out/screen_S_d_g.png").exists());
    let _ = std::fs::remove_dir_all(dir);
}

/// The render as a burn operation: its backward is the scores' Jacobian (bit for bit the one
/// `evaluate` gives at the same seed), and burn's Adam fits σ_s and σ_a of the Fresnel slab to
/// a measured transmission and reflection from a start a user would try (half the scattering, a
/// sixth of the absorption), with fresh photons every step.
#[test]
fn adam_fits_a_slab_through_the_render_operation() {
    use burn::module::{Module, Param as BurnParam};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Tensor;
    use lightpath::diff::RenderOp;
    use lightpath::diff::bridge::{apply, device, tensor, values};

    let params = vec![Param::SigmaS, Param::SigmaA];
    let truth = slab(1.33, 2.0, 0.3, 0.6, vec![]);
    let (e, est) = render(&truth, 2_000_000, 21);
    let target = [e.mean[est.power(0)].re, e.mean[est.power(1)].re];
    let op = |seed| {
        RenderOp::new(
            slab(1.33, 1.0, 0.05, 0.6, vec![]),
            params.clone(),
            (20_000, 1_000, seed),
        )
        .unwrap()
    };
    // the backward of Σ w_i y_i is Σ w_i ∂y_i/∂θ of the same photons
    let dev = device();
    let start = [1.0, 0.05];
    let j = op(5).evaluate(&start).unwrap().jacobian;
    let x = tensor(&start, &dev).require_grad();
    let y = apply(&op(5), x.clone()).unwrap();
    let w = tensor(&[0.7, -1.3], &dev);
    let g = values(&x.grad(&(y * w).sum().backward()).unwrap());
    for p in 0..2 {
        assert_eq!(g[p], 0.7 * j[0][p] - 1.3 * j[1][p]);
    }
    #[derive(Module, Debug)]
    struct Medium {
        theta: BurnParam<Tensor<1>>,
    }
    let fit = op(100);
    let goal = tensor(&target, &dev);
    let mut m = Medium {
        theta: BurnParam::from_tensor(tensor(&start, &dev)),
    };
    let mut adam = AdamConfig::new().init();
    for _ in 0..300 {
        let d = apply(&fit, m.theta.val()).unwrap() - goal.clone();
        let grads = GradientsParams::from_grads((d.clone() * d).sum().backward(), &m);
        m = adam.step(0.02, m, grads);
    }
    let got = values(&m.theta.val());
    eprintln!("fitted σ_s {:.4}, σ_a {:.4} (truth 2, 0.3)", got[0], got[1]);
    // Adam's last steps move each parameter by up to about its learning rate, 0.02
    assert!(
        (got[0] - 2.0).abs() < 0.05 && (got[1] - 0.3).abs() < 0.03,
        "{got:?}"
    );
}

/// Mixture parameters through the render operation: a share of two particle types (a strongly
/// forward HG and a tabulated, backward-leaning type) and a table node, both unnormalised (the
/// operation renormalises, as `lightpath fit` does), against central differences with common
/// random numbers (each pair of renders at θ ± h from one seed; mean and error over 16 seeds);
/// each derivative is also far from zero, so the comparison can fail.
#[test]
fn mixture_parameters_differentiate_as_their_differences() {
    use lightpath::diff::RenderOp;
    use lightpath::medium::Table;
    let table = Table::from_rho(None, vec![0.3, 0.3, 0.4, 0.6, 4.0, 1.5]).unwrap();
    let mut s = slab(1.33, 2.0, 0.3, 0.0, vec![]);
    s.volume.scattering = Scattering::mixture(vec![
        (0.4, PhaseFunction::HenyeyGreenstein { g: 0.9 }),
        (0.6, PhaseFunction::Tabulated(table)),
    ]);
    let params = vec![Param::Weight(0), Param::Bin(1, 4)];
    // the node's value in the normalised table
    let v = &s.volume;
    let theta = [
        0.6,
        params[1]
            .value_in(v.sigma_s, v.sigma_a, &v.scattering)
            .unwrap(),
    ];
    let op =
        |photons, seed| RenderOp::new(s.clone(), params.clone(), (photons, 10_000, seed)).unwrap();
    let d = op(400_000, 31).evaluate(&theta).unwrap();
    for (p, h) in [0.05, 0.2 * theta[1]].into_iter().enumerate() {
        let (mut up, mut down) = (theta, theta);
        up[p] += h;
        down[p] -= h;
        let pairs: Vec<[f64; 2]> = (0..16)
            .map(|k| {
                let a = op(200_000, 100 + k).evaluate(&up).unwrap().power;
                let b = op(200_000, 100 + k).evaluate(&down).unwrap().power;
                [0, 1].map(|i| (a[i] - b[i]) / (2.0 * h))
            })
            .collect();
        for i in 0..2 {
            let mean = pairs.iter().map(|x| x[i]).sum::<f64>() / 16.0;
            let var = pairs.iter().map(|x| (x[i] - mean).powi(2)).sum::<f64>() / 15.0;
            let sdiff = (var / 16.0).sqrt();
            let (got, sd) = (d.jacobian[i][p], d.jacobian_stderr[i][p]);
            eprintln!(
                "d{}/d{}: {got:.5} ± {sd:.5}, differences {mean:.5} ± {sdiff:.5}",
                ["T", "R"][i],
                params[p].name()
            );
            assert!(got.abs() > 4.0 * sd, "{}: {got} ± {sd}", params[p].name());
            assert!(
                (got - mean).abs() < 4.0 * sd.hypot(sdiff),
                "d{}/d{}: {got} ± {sd}, differences {mean} ± {sdiff}",
                ["T", "R"][i],
                params[p].name()
            );
        }
    }
}
