//! Graded-index design through the burn bridge: tracing as a burn operation whose
//! backward is the constant-memory adjoint over every grid coefficient.

use burn::module::{Module, Param as Variable};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Tensor;
use glam::DVec3;
use lightpath::diff::TraceOp;
use lightpath::diff::bridge::{apply, device, tensor, values};
use lightpath::eikonal::grid::{GridField, Interp};
use lightpath::eikonal::{BoundedField, Bounds, IndexField, Profile, Ray};

fn grid(interp: Interp, n_of: impl Fn(DVec3) -> f64) -> GridField {
    let dims = [8, 8, 10];
    let (origin, spacing) = (DVec3::new(-1.75, -1.75, -0.5), 0.5);
    let mut samples = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                samples.push(n_of(
                    origin + DVec3::new(i as f64, j as f64, k as f64) * spacing,
                ));
            }
        }
    }
    GridField::from_samples(origin, spacing, dims, samples, interp).unwrap()
}

/// A collimated bundle along z (started inside cells, off the faces).
fn op(g: GridField, steps: usize) -> TraceOp {
    let field = BoundedField::single(Profile::Grid(g), Bounds::Everywhere, 1.0);
    let rays = (0..9)
        .map(|i| {
            let x = DVec3::new(
                -0.61 + 0.15 * (i % 3) as f64 * 4.0,
                -0.43 + 0.41 * (i / 3) as f64,
                0.013,
            );
            Ray {
                x,
                v: DVec3::Z * field.n(x),
            }
        })
        .collect();
    TraceOp {
        field,
        profile: 0,
        rays,
        steps,
        step: 0.01,
        to_exit: false,
        stop: Default::default(),
    }
}

/// Transverse spread at the end plus a small pull on the final directions: a loss on positions and
/// velocities, so both halves of the adjoint seed are exercised.
fn loss(y: Tensor<1>) -> Tensor<1> {
    let n = y.dims()[0];
    let mask: Vec<f64> = (0..n)
        .map(|i| match i % 6 {
            0 | 1 => 1.0,
            3 | 4 => 0.3,
            _ => 0.0,
        })
        .collect();
    (y.clone() * y * tensor(&mask, &device())).sum()
}

/// The bridge gradient of [`loss`] through `op` at coefficients `coef` against central differences
/// on the six coefficients with the largest gradients (relative tolerance `tol`); returns the
/// largest gradient magnitude.
fn check_against_finite_differences(op: &TraceOp, coef: &[f64], tol: f64, what: &str) -> f64 {
    let dev = device();
    let c = tensor(coef, &dev).require_grad();
    let l = loss(apply(op, c.clone()).unwrap());
    let grad = values(&c.grad(&l.backward()).unwrap());
    let at = |coef: &[f64]| values(&loss(apply(op, tensor(coef, &dev)).unwrap()))[0];
    let mut order: Vec<usize> = (0..grad.len()).collect();
    order.sort_by(|a, b| grad[*b].abs().total_cmp(&grad[*a].abs()));
    for &i in order.iter().take(6) {
        let h = 1e-6;
        let (mut up, mut down) = (coef.to_vec(), coef.to_vec());
        up[i] += h;
        down[i] -= h;
        let fd = (at(&up) - at(&down)) / (2.0 * h);
        eprintln!(
            "{what} coefficient {i}: bridge {:.8e}, finite difference {fd:.8e}",
            grad[i]
        );
        assert!(
            (grad[i] - fd).abs() <= tol * fd.abs().max(1e-3),
            "{what} coefficient {i}: {} vs {fd}",
            grad[i]
        );
    }
    grad[order[0]].abs()
}

/// Would catch a wrong sparse accumulation (taps, scaling by the spacing), a dropped velocity seed,
/// or a bridge that mixes rays up. Fixed steps make the map smooth: central differences agree to
/// their O(h²) truncation, 1e-5 relative, on coefficients the rays pass.
#[test]
fn trace_op_gradient_matches_finite_differences() {
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let g = grid(interp, |p| {
            1.5 - 0.05 * (p.x * p.x + p.y * p.y) + 0.01 * p.z
        });
        let op = op(g.clone(), 250);
        let largest = check_against_finite_differences(&op, &g.coef, 1e-5, &format!("{interp:?}"));
        assert!(largest > 1e-3, "the rays must depend on the grid");
    }
}

/// Exit mode: rays from outside a sphere holding the grid (n ≈ 1.3 inside, 1 outside: refraction on
/// entry and exit) traced to where they leave; outputs exit position and direction, backward the
/// exit adjoint over every coefficient. Against central differences on the coefficients with the
/// largest gradients.
#[test]
fn trace_op_to_exit_matches_finite_differences() {
    let g = grid(Interp::Tricubic, |p| {
        1.3 - 0.05 * (p.x * p.x + p.y * p.y) + 0.02 * p.z
    });
    let field = BoundedField::single(
        Profile::Grid(g.clone()),
        Bounds::Sphere { radius: 1.2 },
        1.0,
    );
    let rays = (0..9)
        .map(|i| Ray {
            x: DVec3::new(
                -0.5 + 0.33 * (i % 3) as f64,
                -0.4 + 0.37 * (i / 3) as f64,
                -2.0,
            ),
            v: DVec3::new(0.02, -0.01, 1.0).normalize(),
        })
        .collect();
    let op = TraceOp {
        field,
        profile: 0,
        rays,
        steps: 100_000,
        step: 0.01,
        to_exit: true,
        stop: Default::default(),
    };
    let largest = check_against_finite_differences(&op, &g.coef, 2e-6, "exit mode");
    assert!(largest > 1e-3, "the rays must depend on the grid");
}

#[derive(Module, Debug)]
struct Field {
    c: Variable<Tensor<1>>,
}

/// A small design run: burn's Adam shapes a uniform 8×8×10 grid so a collimated bundle converges
/// on the axis at the end plane, with a burn-side penalty keeping the coefficients near 1.5. Would
/// catch a backward that does not descend (sign, scaling, stale state between iterations).
#[test]
fn adam_designs_a_converging_lens() {
    let g = grid(Interp::Tricubic, |_| 1.5);
    let c0 = g.coef.clone();
    let op = op(g, 250);
    let dev = device();
    let reference = tensor(&c0, &dev);
    let mut field = Field {
        c: Variable::from_tensor(tensor(&c0, &dev)),
    };
    let mut optimiser = AdamConfig::new().init();
    let spread = |c: &[f64]| values(&loss(apply(&op, tensor(c, &device())).unwrap()))[0];
    let first = spread(&c0);
    for _ in 0..40 {
        let c = field.c.val();
        let d = c.clone() - reference.clone();
        let l = loss(apply(&op, c).unwrap()) + (d.clone() * d).sum() * 0.01;
        let grads = GradientsParams::from_grads(l.backward(), &field);
        field = optimiser.step(0.01, field, grads);
    }
    let last = spread(&values(&field.c.val()));
    eprintln!("spread loss {first:.4e} → {last:.4e}");
    assert!(last < 0.2 * first, "{first} → {last}");
}

fn luneburg_problem(
    levels: Vec<usize>,
    iterations: usize,
) -> lightpath::inverse::grin_design::FocusDesign {
    use lightpath::inverse::grin_design::{Beam, FocusDesign};
    let axes = [DVec3::Z, DVec3::X, DVec3::Y];
    let beams = axes
        .iter()
        .map(|&a| {
            let (e1, e2) = lightpath::math::orthonormal_basis(a);
            let mut rays = Vec::new();
            for i in 0..5 {
                for j in 0..5 {
                    let (u, w) = (-0.6 + 0.3 * i as f64 + 0.011, -0.6 + 0.3 * j as f64 + 0.007);
                    if u * u + w * w <= 0.7 * 0.7 {
                        rays.push((a * -1.2 + e1 * u + e2 * w, a));
                    }
                }
            }
            Beam { rays, focus: a }
        })
        .collect();
    FocusDesign {
        background: BoundedField {
            profiles: vec![],
            bounds: Bounds::Sphere { radius: 1.0 },
            n_out: 1.0,
            scale: 1.0,
            offset: 0.0,
        },
        levels,
        interp: Interp::Tricubic,
        initial: 1.0,
        beams,
        step: 0.02,
        steps: 150,
        to_exit: false,
        iterations,
        learning_rate: 0.02,
        smooth: 1e-4,
    }
}

/// Coarse-to-fine design of a lens that focuses collimated beams from three directions at their
/// antipodes (the Luneburg lens's defining property), from n ≡ 1: the RMS miss distance must fall
/// at least five-fold and the log must cover every level. Would catch a level hand-over that loses
/// the field, or a loss whose gradient does not reach the coefficients.
#[test]
fn coarse_to_fine_design_focuses_three_beams() {
    let problem = luneburg_problem(vec![6, 9], 40);
    let res = problem
        .run(&|_| {}, &Default::default(), &Default::default())
        .unwrap();
    eprintln!(
        "RMS miss {:.4} → {:.4}; final loss {:.4e}",
        res.rms_miss_initial,
        res.rms_miss_final,
        res.log.last().unwrap().loss
    );
    assert!(res.rms_miss_final < 0.2 * res.rms_miss_initial);
    assert_eq!(res.log.len(), 80);
    assert_eq!(res.log[40].level, 1);
    assert_eq!(res.grid.dims, [9, 9, 9]);
}

/// `lightpath design` end to end on a tiny problem (outputs written, the miss distance falls), and
/// bad design configs fail with the key and value, exit status 2 and no result file.
#[test]
fn design_command_and_bad_configs() {
    let bin = env!("CARGO_BIN_EXE_lightpath");
    let d = std::env::temp_dir().join(format!("lightpath-design-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let good = r#"
[field]
bounds = { kind = "sphere", radius = 1.0 }
profiles = []

[grid]
levels = [5, 7]
initial = 1.0

[[beam]]
center = [0.0, 0.0, -1.2]
direction = [0.0, 0.0, 1.0]
radius = 0.6
count = 3
focus = [0.0, 0.0, 1.0]

[trace]
step = 0.02
steps = 150

[design]
iterations = 15
learning_rate = 0.02
"#;
    std::fs::write(d.join("good.toml"), good).unwrap();
    let o = std::process::Command::new(bin)
        .args(["design", d.join("good.toml").to_str().unwrap(), "--out"])
        .arg(d.join("out"))
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["design.json", "loss.png", "profile.png", "grid_slice_z.exr"] {
        assert!(d.join("out").join(f).exists(), "{f} missing");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("out/design.json")).unwrap()).unwrap();
    let (a, b) = (
        v["rms_miss_initial"].as_f64().unwrap(),
        v["rms_miss_final"].as_f64().unwrap(),
    );
    assert!(b < 0.5 * a, "miss {a} → {b}");
    assert_eq!(v["log"].as_array().unwrap().len(), 30);
    assert_eq!(v["grid"]["samples"].as_array().unwrap().len(), 343);
    for (bad, expect) in [
        ("levels = [5, 7]", "levels = [2]", "grid.levels[0] = 2"),
        (
            "direction = [0.0, 0.0, 1.0]",
            "direction = [0.0, 0.0, 0.0]",
            "beam[0].direction",
        ),
        (
            "learning_rate = 0.02",
            "learning_rate = -1.0",
            "design.learning_rate = -1",
        ),
        (
            "kind = \"sphere\", radius = 1.0",
            "kind = \"everywhere\"",
            "needs bounds",
        ),
        ("steps = 150", "steps = 0", "trace.steps = 0"),
        ("steps = 150", "steps = 150\nmax_steps = 10", "not both"),
        ("initial = 1.0", "initial = 1.0\ncolour = 3", "colour"),
    ]
    .map(|(from, to, msg)| (good.replace(from, to), msg))
    {
        let path = d.join("bad.toml");
        std::fs::write(&path, &bad).unwrap();
        let out = d.join("bad-out");
        let o = std::process::Command::new(bin)
            .args(["design", path.to_str().unwrap(), "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{expect}: {err}");
        assert!(err.contains(expect), "expected {expect:?} in {err}");
        assert!(!out.join("design.json").exists());
    }
    // the designed grid read back by a trace config (`grid_file`), and a design traced to the exit
    let trace = r#"
[field]
profiles = [{ kind = "grid_file", path = "out/design.json" }]
bounds = { kind = "sphere", radius = 1.0 }
[rays]
kind = "collimated"
center = [0.0, 0.0, -1.2]
direction = [0.0, 0.0, 1.0]
width = 1.0
count = 5
"#;
    std::fs::write(d.join("trace.toml"), trace).unwrap();
    let o = std::process::Command::new(bin)
        .args(["trace", d.join("trace.toml").to_str().unwrap(), "--out"])
        .arg(d.join("traced"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::write(
        d.join("exit.toml"),
        good.replace("steps = 150", "max_steps = 100000"),
    )
    .unwrap();
    let o = std::process::Command::new(bin)
        .args([
            "design",
            d.join("exit.toml").to_str().unwrap(),
            "--quiet",
            "--out",
        ])
        .arg(d.join("exit"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("exit/design.json")).unwrap()).unwrap();
    let (a, b) = (
        v["rms_miss_initial"].as_f64().unwrap(),
        v["rms_miss_final"].as_f64().unwrap(),
    );
    assert!(b < 0.5 * a, "exit mode: miss {a} → {b}");
    let _ = std::fs::remove_dir_all(&d);
}

/// The operation's outputs and its gradient over every coefficient are the same bits on 1, 2 or 3
/// threads, and each ray's output is what tracing it alone gives (the forward steps four rays at a
/// time, interleaved; 9 rays leave a batch of one). Would catch a reduction whose order follows
/// the threads, or a batch that mixes rays up.
#[test]
fn trace_op_is_bitwise_the_same_for_any_thread_count() {
    use lightpath::diff::bridge::Differentiable;
    use lightpath::eikonal::Tracer;
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let g = grid(interp, |p| {
            1.5 - 0.05 * (p.x * p.x + p.y * p.y) + 0.01 * p.z
        });
        let op = op(g.clone(), 120);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let (y, pullback) = op.forward(&g.coef).unwrap();
                    let dy: Vec<f64> = (0..y.len()).map(|k| 0.3 + 0.01 * k as f64).collect();
                    (y, pullback.pullback(&dy))
                })
        };
        let one = run(1);
        for threads in [2, 3] {
            let other = run(threads);
            assert!(
                one.0
                    .iter()
                    .zip(&other.0)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{interp:?}: outputs differ on {threads} threads"
            );
            assert!(
                one.1
                    .iter()
                    .zip(&other.1)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{interp:?}: gradients differ on {threads} threads"
            );
        }
        let tracer = Tracer {
            field: &op.field,
            step: op.step,
            max_steps: op.steps,
        };
        for (i, r) in op.rays.iter().enumerate() {
            let alone = tracer.steps(*r, op.steps, op.step);
            let got = &one.0[6 * i..6 * i + 6];
            let want: Vec<f64> = alone
                .x
                .to_array()
                .into_iter()
                .chain(alone.v.to_array())
                .collect();
            assert_eq!(got, &want[..], "{interp:?}: ray {i}");
        }
        assert!(one.1.iter().any(|x| *x != 0.0));
    }
}
