//! Derivatives of rendered powers with respect to the medium (path-space scores in particle
//! tracing): a pure absorber's transmission against Beer–Lambert per photon, and a scattering
//! slab with Fresnel faces against finite differences of independent renders (the expectation's
//! slope), for σ_s, σ_a and the Henyey–Greenstein g, on both sides; bad keys refused by name, and
//! `render.json` carrying them; a share between equal phase functions changing no probe or
//! camera; several volumes, each differentiated by its own medium (an absorber before a slab
//! exactly per photon, two slabs apart against central differences).

use crate::common;

use common::{bare_scene, flux, hg_box, render};
use glam::DVec3;
use lightpath::eikonal::{Bounds, Profile};
use lightpath::medium::params::Param;
use lightpath::medium::{PhaseFunction, Scattering};
use lightpath::rrte::{Derivative, Light, MediumDerivative, ParticleTracer, RenderScene, Volume};

/// A slab (faces at z = ±0.5, wide beyond where light spreads) of index `n` in air under a normal
/// beam, with flux sensors on both faces: transmitted (0) and reflected (1).
fn slab(n: f64, sigma_s: f64, sigma_a: f64, g: f64, derivatives: Vec<Param>) -> RenderScene {
    RenderScene {
        volume: hg_box(n, DVec3::new(30.0, 30.0, 0.5), sigma_s, sigma_a, g),
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -1.0),
            direction: DVec3::Z,
            radius: 0.0,
        },
        sensors: vec![flux("T", 0.5), flux("R", -0.5)],
        derivatives: derivatives
            .into_iter()
            .map(|p| Derivative::Medium(MediumDerivative::of_one(p)))
            .collect(),
        ..bare_scene(0.01)
    }
}

/// `lightpath render` on the config file `cfg` into `out`, with `args`: its `render.json`.
fn render_json(cfg: &std::path::Path, out: &std::path::Path, args: &[&str]) -> serde_json::Value {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .arg("render")
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .args(args)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).unwrap()).unwrap()
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
    let json = render_json(&cfg, &dir.join("out"), &[]);
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

/// Two slabs apart (faces at z = −1.05, −0.05 and 0.45, 1.05) under a normal pencil beam, each
/// `(n, σ_s, σ_a, scattering)`, with flux sensors beyond them (T) and before them (R) and an
/// orthographic camera looking back along −z at the lit side: what the second slab sends it
/// crosses the first.
fn two_slabs(
    slabs: [(f64, f64, f64, Scattering); 2],
    derivatives: Vec<(usize, Param)>,
) -> RenderScene {
    use lightpath::eikonal::Part;
    use lightpath::rrte::{Bulk, Camera};
    let parts = [(-1.05, -0.05), (0.45, 1.05)]
        .into_iter()
        .zip(slabs)
        .map(|((z0, z1), (n, sigma_s, sigma_a, scattering))| {
            let half = DVec3::new(500.0, 500.0, 0.5 * (z1 - z0));
            let center = DVec3::new(0.0, 0.0, 0.5 * (z0 + z1));
            let part = Part::new(Bounds::Box { half }, center, vec![Profile::Constant { n }]);
            (
                part,
                Bulk {
                    sigma_s,
                    sigma_a,
                    scattering,
                },
            )
        })
        .collect();
    RenderScene {
        volume: Volume::several(parts, 1.0),
        light: Light::Beam {
            center: DVec3::new(0.0, 0.0, -2.0),
            direction: DVec3::Z,
            radius: 0.0,
        },
        sensors: vec![flux("T", 1.1), flux("R", -1.1)],
        cameras: vec![Camera::new(
            "back".into(),
            -DVec3::Z,
            DVec3::new(0.0, 0.0, -1.5),
            [3.0, 3.0],
            [2, 2],
        )],
        derivatives: derivatives
            .into_iter()
            .map(|(k, param)| {
                Derivative::Medium(MediumDerivative {
                    param,
                    volume: Some(k),
                })
            })
            .collect(),
        ..bare_scene(0.01)
    }
}

fn hg(g: f64) -> Scattering {
    Scattering::single(PhaseFunction::HenyeyGreenstein { g })
}

/// An index-matched absorber (σ_a = 0.7, 1.0 thick) before a matched scattering slab under a
/// normal beam: every photon crossed the absorber once along the normal on its way in, and every
/// connection from the second slab to the back camera crosses it again along the normal. So
/// `∂/∂σ_a` of the absorber is, photon for photon, `−1.0 T` for the transmission and `−2.0` times
/// the camera's image (its connections' stretches inside the absorber alone count, not those
/// inside the scattering slab); light reflected back crosses it aslant, more than twice its
/// thickness.
#[test]
fn an_absorber_before_a_slab_differentiates_by_its_own_thickness() {
    let s = two_slabs(
        [(1.0, 0.0, 0.7, hg(0.0)), (1.0, 3.0, 0.05, hg(0.85))],
        vec![(0, Param::SigmaA), (1, Param::SigmaA)],
    );
    let (e, est) = render(&s, 20_000, 3);
    let camera = est.camera_image(0);
    let d_camera = est.camera_derivative(0, 0);
    let pairs = [
        (est.power(0), est.power_derivative(0, 0), -1.0),
        (camera.total(), d_camera.total(), -2.0),
    ]
    .into_iter()
    .chain((0..camera.pixels).map(|k| (camera.first + k, d_camera.first + k, -2.0)));
    for (value, derivative, crossings) in pairs {
        let (v, d) = (e.mean[value].re, e.mean[derivative].re);
        assert!(v > 0.0, "output {value} is empty");
        assert!(
            (d - crossings * v).abs() < 1e-9 * v,
            "output {value}: derivative {d}, {crossings} × {v}"
        );
    }
    // light reflected crosses the absorber twice, mostly aslant: more than twice its thickness
    let (r, d) = (
        e.mean[est.power(1)].re,
        e.mean[est.power_derivative(1, 0)].re,
    );
    assert!(d < -2.2 * r, "dR/dvolume[0].sigma_a = {d}, R = {r}");
    // the scattering slab's absorption weighs its own tracks
    let d = e.mean[est.power_derivative(1, 1)].re;
    assert!(
        d < -0.05 * e.mean[est.power(1)].re,
        "dR/dvolume[1].sigma_a = {d}"
    );
}

/// Two scattering slabs apart (index-matched), the second a mixture of a
/// forward Henyey–Greenstein type and an isotropic one: the estimated derivatives of T, R and
/// the back camera's total with respect to each slab's own parameters (the first's σ_a and g,
/// the second's σ_s, σ_a, HG g and share) against central differences of independent renders at
/// θ ± h with common random numbers (mean and error over 16 seeds; 4 combined standard errors). The camera's connections from the second slab cross the
/// first, so its σ_a's derivative holds their stretches inside the first slab alone; each
/// derivative is also far from zero, so the comparison can fail.
#[test]
fn slabs_apart_differentiate_each_by_its_own_medium() {
    let mixture = |g: f64, share: f64| {
        // the share of the HG type, unnormalised: the types renormalised
        let total = share + 0.5;
        Scattering::mixture(vec![
            (share / total, PhaseFunction::HenyeyGreenstein { g }),
            (0.5 / total, PhaseFunction::Isotropic),
        ])
    };
    // θ: volume[0] σ_a, g; volume[1] σ_s, σ_a, g, share
    let theta = [0.2, 0.5, 3.0, 0.05, 0.85, 0.5];
    let params = vec![
        (0, Param::SigmaA),
        (0, Param::G(0)),
        (1, Param::SigmaS),
        (1, Param::SigmaA),
        (1, Param::G(0)),
        (1, Param::Weight(0)),
    ];
    let scene = |t: [f64; 6], derivatives| {
        two_slabs(
            [
                (1.0, 1.5, t[0], hg(t[1])),
                (1.0, t[2], t[3], mixture(t[4], t[5])),
            ],
            derivatives,
        )
    };
    let s = scene(theta, params.clone());
    let (e, est) = render(&s, 400_000, 11);
    let outputs = |e: &lightpath::mc::Estimate, est: &ParticleTracer, j: Option<usize>| {
        let index = [
            j.map_or(est.power(0), |j| est.power_derivative(0, j)),
            j.map_or(est.power(1), |j| est.power_derivative(1, j)),
            j.map_or(est.camera_image(0), |j| est.camera_derivative(0, j))
                .total(),
        ];
        index.map(|k| (e.mean[k].re, e.stderr[k]))
    };
    let steps = [0.05, 0.05, 0.3, 0.03, 0.03, 0.1];
    for (j, h) in steps.into_iter().enumerate() {
        // central differences with common random numbers: each pair from one seed
        let at = |sign: f64, seed: u64| {
            let mut t = theta;
            t[j] += sign * h;
            let s = scene(t, vec![]);
            let (e, est) = render(&s, 64_000, seed);
            outputs(&e, &est, None).map(|o| o.0)
        };
        let pairs: Vec<[f64; 3]> = (0..16)
            .map(|k| {
                let (up, down) = (at(1.0, 100 + k), at(-1.0, 100 + k));
                [0, 1, 2].map(|i| (up[i] - down[i]) / (2.0 * h))
            })
            .collect();
        let got = outputs(&e, &est, Some(j));
        let name = s.derivatives[j].name();
        for (i, what) in ["T", "R", "camera"].into_iter().enumerate() {
            let fd = pairs.iter().map(|p| p[i]).sum::<f64>() / 16.0;
            let var = pairs.iter().map(|p| (p[i] - fd).powi(2)).sum::<f64>() / 15.0;
            let sfd = (var / 16.0).sqrt();
            let (d, sd) = got[i];
            eprintln!("d{what}/d{name}: {d:.5} ± {sd:.5}, differences {fd:.5} ± {sfd:.5}");
            assert!(d.abs() > 4.0 * sd, "d{what}/d{name}: {d} ± {sd}");
            assert!(
                (d - fd).abs() < 4.0 * sd.hypot(sfd),
                "d{what}/d{name}: {d} ± {sd}, differences {fd} ± {sfd}"
            );
        }
    }
}

/// A share between two equal phase functions changes nothing: the derivatives of a probe's
/// fluence and a camera's image with respect to it are zero within their errors. What each
/// connection carries does not depend on the share (only the photons' scores do, with mean
/// zero), and it is not attenuated by it: a share scored as a coefficient (`−L` along each
/// connection) reads many standard errors below zero.
#[test]
fn a_share_between_equal_phase_functions_changes_nothing() {
    use lightpath::rrte::{Camera, Probe};
    let mut s = slab(1.0, 2.0, 0.3, 0.0, vec![Param::Weight(0)]);
    let hg = PhaseFunction::HenyeyGreenstein { g: 0.6 };
    s.volume.scattering = Scattering::mixture(vec![(0.4, hg.clone()), (0.6, hg)]);
    s.probes = vec![Probe {
        name: "mid".into(),
        position: DVec3::new(0.4, 0.0, 0.1),
    }];
    s.cameras = vec![Camera::new(
        "back".into(),
        -DVec3::Z,
        DVec3::new(0.0, 0.0, -1.0),
        [2.0, 2.0],
        [1, 1],
    )];
    let (e, est) = render(&s, 100_000, 5);
    let camera = (
        est.camera_image(0).total(),
        est.camera_derivative(0, 0).total(),
    );
    let probe = (est.probe_total(0), est.probe_derivative(0, 0));
    for (what, (value, derivative)) in [("probe", probe), ("camera", camera)] {
        let (v, d, sd) = (
            e.mean[value].re,
            e.mean[derivative].re,
            e.stderr[derivative],
        );
        eprintln!("{what}: {v:.5}, derivative {d:.6} ± {sd:.6}");
        assert!(
            v > 0.0 && d.abs() < 4.0 * sd,
            "{what}: {v}, derivative {d} ± {sd}"
        );
    }
}

/// In a scene of several volumes each medium parameter names its volume (`volume[i].sigma_s`):
/// bad names are refused by key, and the example of three volumes renders them into
/// `render.json` (the clear lens's `σ_s` too, at 0: light crossing it would be scattered).
#[test]
fn derivatives_of_several_volumes_name_their_volume() {
    let example = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/configs/render_volumes.toml"
    ))
    .unwrap();
    let base = example.replace("estimator = \"bidirectional\"", "estimator = \"particle\"");
    assert_ne!(base, example);
    let with = |derivatives: &str| format!("{base}derivatives = {derivatives}\n");
    for (derivatives, needles) in [
        (
            "[\"sigma_s\"]",
            &["render.derivatives[0] = \"sigma_s\"", "volume[i].sigma_s"][..],
        ),
        ("[\"volume[3].sigma_s\"]", &["volume[3]", "3 volumes"]),
        (
            "[\"volume[0].g[1]\"]",
            &["volume[0]'s medium has no such parameter"],
        ),
        (
            "[\"volume[2].g\"]",
            &["render.derivatives[0]", "no such parameter"],
        ),
        ("[\"volume[0]sigma_s\"]", &["volume[i].name"]),
        // the floor: light moved by the field would move across its edge
        (
            "[\"volume[1].profiles[0].radius\"]",
            &["render.derivatives[0]", "[[surface]]"],
        ),
        (
            "[\"volume[1].profiles[2].radius\"]",
            &["volume[1]", "profiles has 1 profile(s)"],
        ),
        (
            "[\"volume[1].profiles[0].n0\"]",
            &["volume[1]", "luneburg profile has no parameter \"n0\""],
        ),
        (
            "[\"profiles[0].radius\"]",
            &["name the volume", "volume[i].profiles[0].radius"],
        ),
        (
            "[\"volume[0].g\", \"volume[0].g[0]\"]",
            &["render.derivatives[1]", "once"],
        ),
    ] {
        let Err(e) = lightpath::config::load_text(&with(derivatives)) else {
            panic!("not refused: {derivatives}")
        };
        let e = e.to_string();
        for n in needles {
            assert!(e.contains(n), "{derivatives}: {n:?} not in: {e}");
        }
    }
    // a parameter of one volume's medium in a scene of one volume
    let one = "[field]\nprofiles = [{ kind = \"constant\", n = 1.0 }]\nbounds = { kind = \"sphere\", radius = 1.0 }\n[medium]\nsigma_s = 1.0\nsigma_a = 0.1\n[light]\nkind = \"point\"\nposition = [0.0, 0.0, 0.0]\n[[sensor]]\nkind = \"flux\"\nname = \"T\"\ncenter = [0.0, 0.0, 2.0]\nnormal = [0.0, 0.0, 1.0]\n[render]\nderivatives = [\"volume[0].sigma_s\"]\n";
    let Err(e) = lightpath::config::load_text(one) else {
        panic!("not refused: volume[0] of one volume")
    };
    assert!(e.to_string().contains("sigma_s, g"), "{e}");

    let dir = std::env::temp_dir().join(format!("lightpath-vol-derivs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("volumes.toml");
    let names = [
        "volume[0].sigma_s",
        "volume[0].g",
        "volume[1].sigma_s",
        "volume[2].sigma_a",
    ];
    std::fs::write(&cfg, with(&format!("{names:?}"))).unwrap();
    let json = render_json(&cfg, &dir.join("out"), &["--samples", "4000"]);
    let view = &json["cameras"][0];
    for name in names {
        let d = &view["derivatives"][name];
        assert!(d["mean"].as_f64().unwrap().is_finite(), "{name}: {view}");
        assert!(d["stderr"].as_f64().unwrap() > 0.0, "{name}: {d}");
        let file = format!(
            "camera_view_d_{}.exr",
            name.replace('[', "_").replace(']', "")
        );
        assert!(dir.join("out").join(&file).exists(), "{file}");
    }
    // light absorbed more in the smoky block darkens the view: every path through it scores −L
    let smoky = view["derivatives"]["volume[2].sigma_a"]["mean"]
        .as_f64()
        .unwrap();
    assert!(smoky < 0.0, "d view/d volume[2].sigma_a = {smoky}");
    let _ = std::fs::remove_dir_all(dir);
}
