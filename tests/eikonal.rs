//! Ray tracing in graded-index media: integrator order on an exact solution, Luneburg and
//! Maxwell fish-eye imaging, exact time reversibility.

use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, GridAdjoint, Profile, Ray, Tracer};

fn luneburg() -> BoundedField {
    BoundedField::single(
        Profile::Luneburg { radius: 1.0 },
        Bounds::Sphere { radius: 1.0 },
        1.0,
    )
}

/// For `n² = 2 − r²` the σ-form motion is `x(σ) = x0 cos σ + v0 sin σ`: the leapfrog error at σ = 1
/// falls by 4 when the step halves (second order).
#[test]
fn leapfrog_is_second_order() {
    let f = BoundedField::single(Profile::Luneburg { radius: 1.0 }, Bounds::Everywhere, 1.0);
    let x0 = DVec3::new(0.3, -0.1, 0.2);
    let v0 = DVec3::new(0.2, 0.9, -0.4).normalize() * (2.0 - x0.length_squared()).sqrt();
    let exact = x0 * 1f64.cos() + v0 * 1f64.sin();
    let mut errs = Vec::new();
    for n in [10usize, 20, 40, 80] {
        let t = Tracer {
            field: &f,
            step: 1.0 / n as f64,
            max_steps: 0,
        };
        let r = t.steps(Ray { x: x0, v: v0 }, n, 1.0 / n as f64);
        errs.push((r.x - exact).length());
    }
    for w in errs.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!(
            (order - 2.0).abs() < 0.1,
            "observed order {order} from errors {errs:?}"
        );
    }
}

/// Forward then backward (negated step) returns to the start to round-off.
#[test]
fn time_reversible() {
    let f = BoundedField::single(
        Profile::SechFibre {
            n0: 1.5,
            alpha: 0.8,
        },
        Bounds::Everywhere,
        1.0,
    );
    let t = Tracer {
        field: &f,
        step: 0.01,
        max_steps: 0,
    };
    let r0 = Ray {
        x: DVec3::new(0.4, -0.2, 0.0),
        v: DVec3::new(0.1, 0.2, 1.0).normalize() * f_n(&f, DVec3::new(0.4, -0.2, 0.0)),
    };
    let r1 = t.steps(r0, 5000, 0.01);
    let back = t.steps(Ray { x: r1.x, v: r1.v }, 5000, -0.01);
    assert!(
        (back.x - r0.x).length() < 1e-10 && (back.v - r0.v).length() < 1e-10,
        "{back:?} vs {r0:?}"
    );
    assert!((r1.x - r0.x).length() > 1.0, "the ray must have moved");
}

fn f_n(f: &BoundedField, x: DVec3) -> f64 {
    use lightpath::eikonal::IndexField;
    f.n(x)
}

/// A collimated beam through a Luneburg lens focuses at the antipodal point of the sphere; the error
/// falls with the step.
#[test]
fn luneburg_focuses_a_collimated_beam() {
    let f = luneburg();
    let mut worst_prev = f64::INFINITY;
    for step in [0.02, 0.005] {
        let t = Tracer {
            field: &f,
            step,
            max_steps: 100_000,
        };
        let mut worst: f64 = 0.0;
        for b in [0.05, 0.3, 0.6, 0.85] {
            for phi in [0.0f64, 2.0] {
                let o = DVec3::new(b * phi.cos(), b * phi.sin(), -3.0);
                let end = t.trace(o, DVec3::Z);
                assert!(end.entered && end.exited);
                worst = worst.max((end.x - DVec3::Z).length());
            }
        }
        assert!(worst < 2e-3, "step {step}: focus error {worst}");
        assert!(worst < worst_prev, "error must fall with the step");
        worst_prev = worst;
    }
}

/// The Maxwell fish-eye images a point on its surface to the antipodal point.
#[test]
fn maxwell_fish_eye_images_to_the_antipode() {
    let f = BoundedField::single(
        Profile::MaxwellFishEye { radius: 1.0 },
        Bounds::Sphere { radius: 1.0 },
        1.0,
    );
    let t = Tracer {
        field: &f,
        step: 0.002,
        max_steps: 1_000_000,
    };
    let src = DVec3::new(0.0, 0.0, -1.0 + 1e-9);
    for (a, phi) in [(0.2f64, 0.0f64), (0.7, 1.0), (1.2, 2.5)] {
        let dir = DVec3::new(a.sin() * phi.cos(), a.sin() * phi.sin(), a.cos());
        let end = t.trace(src, dir);
        assert!(end.exited, "ray did not exit");
        assert!(
            (end.x - DVec3::Z).length() < 2e-3,
            "angle {a}: exit at {}",
            end.x
        );
        assert!(end.optical_path > 0.0);
    }
}

/// Adjoint gradients (constant memory, ray reconstructed backwards) equal the stored-path (tape)
/// gradients to ~1e-10 and central differences to their accuracy, for the initial state and for
/// analytic parameters of a composed field (parabolic fibre + linear perturbation), and for the
/// Luneburg radius. Loss: `L = |x_N − t|² + c·v_N`.
#[test]
fn adjoint_matches_tape_and_finite_differences() {
    use lightpath::eikonal::FieldParam;
    let fibre = BoundedField {
        profiles: vec![
            Profile::ParabolicFibre {
                n0: 1.5,
                alpha: 0.3,
            },
            Profile::Linear {
                n0: 0.0,
                gradient: DVec3::new(0.01, -0.02, 0.005),
            },
        ],
        bounds: Bounds::Everywhere,
        n_out: 1.0,
        scale: 1.0,
        offset: 0.0,
    };
    let lune = BoundedField::single(Profile::Luneburg { radius: 1.3 }, Bounds::Everywhere, 1.0);
    let ultrasonic = BoundedField::single(
        Profile::Ultrasonic {
            n0: 1.33,
            n_max: 0.05,
            k_r: 2.1,
            m: 2,
        },
        Bounds::Everywhere,
        1.33,
    );
    let target = DVec3::new(0.2, -0.1, 3.0);
    let c = DVec3::new(0.3, 0.1, -0.2);
    let loss = |r: Ray| (r.x - target).length_squared() + c.dot(r.v);
    let loss_grad = |r: Ray| ((r.x - target) * 2.0, c);
    for (field, params, start) in [
        (
            &fibre,
            vec![
                FieldParam {
                    profile: 0,
                    which: 0,
                },
                FieldParam {
                    profile: 0,
                    which: 1,
                },
                FieldParam {
                    profile: 1,
                    which: 2,
                },
            ],
            DVec3::new(0.4, 0.1, 0.0),
        ),
        (
            &lune,
            vec![FieldParam {
                profile: 0,
                which: 0,
            }],
            DVec3::new(0.3, -0.2, 0.1),
        ),
        (
            &ultrasonic,
            (0..3)
                .map(|which| FieldParam { profile: 0, which })
                .collect(),
            DVec3::new(0.35, 0.2, -0.5),
        ),
    ] {
        let t = Tracer {
            field,
            step: 0.01,
            max_steps: 0,
        };
        let n0 = f_n(field, start);
        let r0 = Ray {
            x: start,
            v: DVec3::new(0.1, 0.05, 1.0).normalize() * n0,
        };
        let steps = 300;
        let adj = t.adjoint(r0, steps, 0.01, &params, loss_grad).unwrap();
        let tape = t.adjoint_tape(r0, steps, 0.01, &params, loss_grad).unwrap();
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1e-12);
        for k in 0..3 {
            assert!(
                rel(adj.dx0[k], tape.dx0[k]) < 1e-9 && rel(adj.dv0[k], tape.dv0[k]) < 1e-9,
                "state: {adj:?} vs {tape:?}"
            );
        }
        for (a, b) in adj.dparams.iter().zip(&tape.dparams) {
            assert!(rel(*a, *b) < 1e-9, "params: {a} vs {b}");
        }
        // finite differences: initial state
        let h = 1e-6;
        for k in 0..3 {
            let mut e = DVec3::ZERO;
            e[k] = h;
            let fx = (loss(t.steps(
                Ray {
                    x: r0.x + e,
                    v: r0.v,
                },
                steps,
                0.01,
            )) - loss(t.steps(
                Ray {
                    x: r0.x - e,
                    v: r0.v,
                },
                steps,
                0.01,
            ))) / (2.0 * h);
            let fv = (loss(t.steps(
                Ray {
                    x: r0.x,
                    v: r0.v + e,
                },
                steps,
                0.01,
            )) - loss(t.steps(
                Ray {
                    x: r0.x,
                    v: r0.v - e,
                },
                steps,
                0.01,
            ))) / (2.0 * h);
            assert!(
                (adj.dx0[k] - fx).abs() < 1e-6 * fx.abs().max(1.0),
                "dL/dx0[{k}]: {} vs {fx}",
                adj.dx0[k]
            );
            assert!(
                (adj.dv0[k] - fv).abs() < 1e-6 * fv.abs().max(1.0),
                "dL/dv0[{k}]: {} vs {fv}",
                adj.dv0[k]
            );
        }
        // finite differences: field parameters
        for (i, p) in params.iter().enumerate() {
            let shifted = |d: f64| {
                let mut f2 = field.clone();
                f2.profiles[p.profile] = bump(&f2.profiles[p.profile], p.which, d);
                let t2 = Tracer {
                    field: &f2,
                    step: 0.01,
                    max_steps: 0,
                };
                loss(t2.steps(r0, steps, 0.01))
            };
            let fd = (shifted(h) - shifted(-h)) / (2.0 * h);
            eprintln!(
                "param {p:?}: adjoint {:.8e}, finite difference {fd:.8e}",
                adj.dparams[i]
            );
            assert!(
                (adj.dparams[i] - fd).abs() < 1e-5 * fd.abs().max(1e-3),
                "{p:?}: {} vs {fd}",
                adj.dparams[i]
            );
        }
    }
}

fn bump(p: &Profile, which: usize, d: f64) -> Profile {
    let mut p = p.clone();
    *p.param_mut(which).expect("a parameter") += d;
    p
}

/// An 8×8×10 grid of a weak parabolic lens, spacing 0.5, from (−1.75, −1.75, −0.5).
fn lens_grid(interp: lightpath::eikonal::grid::Interp) -> lightpath::eikonal::grid::GridField {
    let dims = [8, 8, 10];
    let (origin, spacing) = (DVec3::new(-1.75, -1.75, -0.5), 0.5);
    let mut samples = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                samples.push(1.5 - 0.05 * (p.x * p.x + p.y * p.y) + 0.01 * p.z);
            }
        }
    }
    lightpath::eikonal::grid::GridField::from_samples(origin, spacing, dims, samples, interp)
        .unwrap()
}

fn grid_of(g: &mut [f64]) -> Option<GridAdjoint<'_>> {
    Some(GridAdjoint {
        profile: 0,
        grad: g,
    })
}

/// Rays stepped and reversed together (interleaved, a trilinear grid's evaluations side by side
/// in vector lanes) get the bits each gets alone, forward and reverse; the coefficient gradient
/// they share is the sum of theirs to round-off.
#[test]
fn rays_stepped_and_reversed_together_equal_rays_alone() {
    use lightpath::eikonal::grid::Interp;
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let grid = lens_grid(interp);
        let field = BoundedField::single(Profile::Grid(grid.clone()), Bounds::Everywhere, 1.0);
        let t = Tracer {
            field: &field,
            step: 0.01,
            max_steps: 0,
        };
        let (steps, h) = (250, 0.01);
        let rays: [Ray; 8] = std::array::from_fn(|k| {
            let x = DVec3::new(0.3 - 0.09 * k as f64, -0.1 + 0.05 * k as f64, 0.013);
            Ray {
                x,
                v: DVec3::new(0.05, 0.02 * k as f64, 1.0).normalize() * f_n(&field, x),
            }
        });
        let ends = t.steps_interleaved(rays, steps, h);
        for k in 0..8 {
            assert_eq!(ends[k], t.steps(rays[k], steps, h), "{interp:?} ray {k}");
        }
        let target = DVec3::new(0.0, 0.0, 3.0);
        let seed = |r: Ray| ((r.x - target) * 2.0, r.v * 0.5);
        let mut together = vec![0.0; grid.coef.len()];
        let first = t
            .adjoint_from_ends(
                ends.map(|e| (e, seed(e).0, seed(e).1)),
                steps,
                h,
                &[],
                grid_of(&mut together),
            )
            .unwrap();
        let mut alone = vec![0.0; grid.coef.len()];
        for k in 0..8 {
            let g = t
                .adjoint_from_end(ends[k], steps, h, &[], grid_of(&mut alone), seed)
                .unwrap();
            assert_eq!((g.dx0, g.dv0), first[k], "{interp:?} ray {k}");
        }
        let scale = alone.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(scale > 0.1, "{interp:?}: gradient {scale}");
        for (a, b) in together.iter().zip(&alone) {
            assert!((a - b).abs() <= 1e-13 * scale, "{interp:?}: {a} vs {b}");
        }
    }
}

/// Grid fields (tricubic and trilinear): the adjoint gradient with respect to coefficients the ray
/// passes equals the tape gradient and central differences.
#[test]
fn grid_coefficient_gradients() {
    use lightpath::eikonal::FieldParam;
    use lightpath::eikonal::grid::Interp;
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let grid = lens_grid(interp);
        let dims = grid.dims;
        let field = BoundedField::single(Profile::Grid(grid.clone()), Bounds::Everywhere, 1.0);
        let t = Tracer {
            field: &field,
            step: 0.01,
            max_steps: 0,
        };
        // start inside a cell: trilinear gradients jump at faces, and a ray starting exactly on one
        // would see a different cell after reconstruction by round-off
        let x0 = DVec3::new(0.3, -0.1, 0.013);
        let r0 = Ray {
            x: x0,
            v: DVec3::new(0.05, 0.02, 1.0).normalize() * f_n(&field, x0),
        };
        let steps = 250;
        let target = DVec3::new(0.0, 0.0, 3.0);
        let loss = |r: Ray| (r.x - target).length_squared();
        // coefficients around the ray's path: nodes (4, 3, k) and (3, 3, k) for a few k
        let coefs: Vec<usize> = [(4, 3, 2), (3, 3, 4), (4, 4, 6), (3, 2, 3)]
            .iter()
            .map(|(i, j, k)| i + dims[0] * (j + dims[1] * k))
            .collect();
        let params: Vec<FieldParam> = coefs
            .iter()
            .map(|&c| FieldParam {
                profile: 0,
                which: c,
            })
            .collect();
        let adj = t
            .adjoint(r0, steps, 0.01, &params, |r| {
                ((r.x - target) * 2.0, DVec3::ZERO)
            })
            .unwrap();
        let tape = t
            .adjoint_tape(r0, steps, 0.01, &params, |r| {
                ((r.x - target) * 2.0, DVec3::ZERO)
            })
            .unwrap();
        // every coefficient at once, accumulated sparsely (taps only): equal to the per-coefficient
        // parameters above and to the tape pass with the same accumulator
        let mut sparse = vec![0.0; grid.coef.len()];
        let mut sparse_tape = vec![0.0; grid.coef.len()];
        let lg = |r: Ray| ((r.x - target) * 2.0, DVec3::ZERO);
        t.adjoint_with_grid(r0, steps, 0.01, &[], grid_of(&mut sparse), lg)
            .unwrap();
        t.adjoint_tape_with_grid(r0, steps, 0.01, &[], grid_of(&mut sparse_tape), lg)
            .unwrap();
        for (i, &c) in coefs.iter().enumerate() {
            assert!(
                (sparse[c] - adj.dparams[i]).abs() <= 1e-12 * adj.dparams[i].abs().max(1e-9),
                "{interp:?} coefficient {c}: sparse {} vs per-coefficient {}",
                sparse[c],
                adj.dparams[i]
            );
        }
        let scale = sparse.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (a, b) in sparse.iter().zip(&sparse_tape) {
            assert!(
                (a - b).abs() <= 1e-9 * scale,
                "sparse adjoint {a} vs tape {b}"
            );
        }
        let touched = sparse.iter().filter(|x| **x != 0.0).count();
        assert!(
            touched > 20,
            "{interp:?}: only {touched} coefficients touched"
        );
        let mut any = false;
        for (i, &c) in coefs.iter().enumerate() {
            let rel = (adj.dparams[i] - tape.dparams[i]).abs() / tape.dparams[i].abs().max(1e-12);
            assert!(
                rel <= 1e-9,
                "{interp:?}: adjoint {} vs tape {}",
                adj.dparams[i],
                tape.dparams[i]
            );
            let h = 1e-6;
            let at = |d: f64| {
                let mut g2 = grid.clone();
                g2.coef[c] += d;
                let f2 = BoundedField::single(Profile::Grid(g2), Bounds::Everywhere, 1.0);
                loss(
                    Tracer {
                        field: &f2,
                        step: 0.01,
                        max_steps: 0,
                    }
                    .steps(r0, steps, 0.01),
                )
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            eprintln!(
                "{interp:?} coefficient {c}: adjoint {:.8e}, finite difference {fd:.8e}",
                adj.dparams[i]
            );
            assert!(
                (adj.dparams[i] - fd).abs() < 1e-5 * fd.abs().max(1e-4),
                "{interp:?} coefficient {c}: {} vs {fd}",
                adj.dparams[i]
            );
            any |= fd.abs() > 1e-3;
        }
        assert!(any, "the ray must pass the chosen coefficients");
    }
}

/// `lightpath trace` on the shipped Luneburg config focuses every ray at the antipode and writes its
/// outputs; a field with n ≤ 0 where rays run and a bad value are clear errors.
#[test]
fn trace_command() {
    let bin = env!("CARGO_BIN_EXE_lightpath");
    let d = std::env::temp_dir().join(format!("lightpath-trace-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/luneburg.toml");
    let o = std::process::Command::new(bin)
        .args(["trace", cfg, "--out", d.join("lune").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("lune/rays.json")).unwrap()).unwrap();
    let rays = v["rays"].as_array().unwrap();
    assert_eq!(rays.len(), 15);
    for r in rays {
        let x: Vec<f64> = r["exit_position"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(
            (x[0].powi(2) + x[1].powi(2) + (x[2] - 1.0).powi(2)).sqrt() < 1e-3,
            "exit {x:?}"
        );
    }
    assert!(d.join("lune/rays.png").exists());
    std::fs::create_dir_all(&d).unwrap();
    let negative = r#"
[field]
profiles = [{ kind = "linear", n0 = 1.0, gradient = [0.0, 0.0, -1.0] }]
bounds = { kind = "box", size = [4.0, 4.0, 4.0] }
[rays]
kind = "collimated"
center = [0.0, 0.0, -3.0]
direction = [0.0, 0.0, 1.0]
width = 0.5
count = 3
[trace]
step = 0.01
max_steps = 2000
"#;
    let radius = r#"
[field]
profiles = [{ kind = "luneburg", radius = -1.0 }]
[rays]
kind = "fan"
origin = [0.0, 0.0, -2.0]
axis = [0.0, 0.0, 1.0]
half_angle_deg = 10.0
count = 3
"#;
    let grid = r#"
[field]
profiles = [{ kind = "grid", dims = [2, 2, 2], origin = [-1.0, -1.0, -1.0], spacing = 2.0, values = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0] }]
bounds = { kind = "sphere", radius = 1.0 }
[rays]
kind = "fan"
origin = [0.0, 0.0, -2.0]
axis = [0.0, 0.0, 1.0]
half_angle_deg = 10.0
count = 3
"#;
    let grid_file = radius.replace(
        r#"{ kind = "luneburg", radius = -1.0 }"#,
        r#"{ kind = "grid_file", path = "no-such-design.json" }"#,
    );
    let miss = radius
        .replace("radius = -1.0", "radius = 1.0")
        .replace(
            "[rays]",
            "bounds = { kind = \"sphere\", radius = 1.0 }\n[rays]",
        )
        .replace("origin = [0.0, 0.0, -2.0]", "origin = [5.0, 0.0, -2.0]");
    for (name, text, needle) in [
        ("miss.toml", miss.as_str(), "none of the 3 rays meets"),
        ("neg.toml", negative, "must be positive"),
        ("radius.toml", radius, "radius = -1"),
        ("grid.toml", grid, "7 values given, 2×2×2 = 8 expected"),
        ("gridfile.toml", &grid_file, "no-such-design.json"),
    ] {
        std::fs::write(d.join(name), text).unwrap();
        let o = std::process::Command::new(bin)
            .args([
                "trace",
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
        assert!(!d.join("bad/rays.json").exists());
    }
}

/// Where `n` jumps at the bounds the ray refracts (Snell) on entry and exit: a plate of constant
/// n = 1.5 returns the incident direction and shifts the ray by `L tan θ_t` (closed form); a
/// step-index rod guides a ray by total internal reflection at its side and releases it at the
/// far end at the angle it came in with. Would catch unrefracted entry/exit or a lost reflection.
#[test]
fn refraction_at_index_jumps() {
    let deg = std::f64::consts::PI / 180.0;
    let plate = BoundedField::single(
        Profile::Constant { n: 1.5 },
        Bounds::Box {
            half: DVec3::new(20.0, 20.0, 0.5),
        },
        1.0,
    );
    let t = Tracer {
        field: &plate,
        step: 0.01,
        max_steps: 10_000,
    };
    let theta = 30.0 * deg;
    let d = DVec3::new(theta.sin(), 0.0, theta.cos());
    let end = t.trace(DVec3::new(0.0, 0.0, -2.0) - d * 0.0, d);
    let entry_x = 1.5 * theta.tan();
    let theta_t = (theta.sin() / 1.5).asin();
    assert!((end.direction - d).length() < 1e-9, "{:?}", end.direction);
    assert!((end.x.z - 0.5).abs() < 1e-9);
    assert!(
        (end.x.x - (entry_x + theta_t.tan())).abs() < 1e-9,
        "exit x {} vs {}",
        end.x.x,
        entry_x + theta_t.tan()
    );
    // optical path inside: n² ∫dσ = n · (geometric length) in the σ-form
    assert!(
        (end.optical_path - 1.5 / theta_t.cos()).abs() < 1e-6,
        "{}",
        end.optical_path
    );

    let rod = BoundedField::single(
        Profile::Constant { n: 1.5 },
        Bounds::Cylinder {
            radius: 0.5,
            half_length: 5.0,
        },
        1.0,
    );
    let t = Tracer {
        field: &rod,
        step: 0.01,
        max_steps: 100_000,
    };
    let a = 40.0 * deg;
    let d = DVec3::new(a.sin(), 0.0, a.cos());
    let end = t.trace(DVec3::new(0.0, 0.0, -5.3), d);
    assert!(end.exited && end.entered);
    assert!(
        (end.x.z - 5.0).abs() < 1e-6,
        "left through the side at {:?}",
        end.x
    );
    let out_angle = end.direction.z.acos();
    assert!(
        (out_angle - a).abs() < 1e-6,
        "exit angle {} vs {}",
        out_angle / deg,
        a / deg
    );
}

/// Forward sensitivities `∂(x, v)/∂(x0, v0)` (paper 002, Alg. 2) against central differences of the
/// same steps, and symplecticity `Mᵀ Ω M = Ω` of the 6×6 map (the leapfrog map is symplectic, so
/// this holds to round-off — an independent check of every block).
#[test]
fn forward_sensitivities() {
    let field = BoundedField::single(
        Profile::Luneburg { radius: 1.0 },
        Bounds::Sphere { radius: 1.0 },
        1.0,
    );
    let t = Tracer {
        field: &field,
        step: 0.01,
        max_steps: 0,
    };
    let r0 = Ray {
        x: DVec3::new(0.2, -0.1, -0.6),
        v: DVec3::new(0.1, 0.05, 1.0).normalize() * 1.2,
    };
    let steps = 90;
    let (end, [[xx, xv], [vx, vv]]) = t.steps_with_sensitivities(r0, steps, 0.01);
    assert_eq!(end, t.steps(r0, steps, 0.01));
    let h = 1e-6;
    for k in 0..6 {
        let mut e = [0.0; 6];
        e[k] = h;
        let shift = |s: f64| Ray {
            x: r0.x + DVec3::new(e[0], e[1], e[2]) * s,
            v: r0.v + DVec3::new(e[3], e[4], e[5]) * s,
        };
        let (p, m) = (
            t.steps(shift(1.0), steps, 0.01),
            t.steps(shift(-1.0), steps, 0.01),
        );
        let (dx, dv) = ((p.x - m.x) / (2.0 * h), (p.v - m.v) / (2.0 * h));
        let (cx, cv) = if k < 3 {
            (xx.col(k), vx.col(k))
        } else {
            (xv.col(k - 3), vv.col(k - 3))
        };
        assert!(
            (cx - dx).length() < 1e-6 * dx.length().max(1.0),
            "column {k}: {cx} vs {dx}"
        );
        assert!(
            (cv - dv).length() < 1e-6 * dv.length().max(1.0),
            "column {k}: {cv} vs {dv}"
        );
    }
    let eye = glam::DMat3::IDENTITY;
    let blocks = [
        xx.transpose() * vx - vx.transpose() * xx,
        xx.transpose() * vv - vx.transpose() * xv - eye,
        xv.transpose() * vv - vv.transpose() * xv,
    ];
    for b in blocks {
        assert!(
            b.abs_diff_eq(glam::DMat3::ZERO, 1e-11),
            "not symplectic: {b}"
        );
    }
}

/// The exit adjoint (trace to the boundary, refraction on entry and exit, total internal
/// reflections, boundary-crossing steps) against central differences of the traced exit, for the
/// ray's origin and direction, analytic parameters and grid coefficients. Cases: a Luneburg lens
/// whose profile radius differs from the sphere (index jump → refraction on the curved surface); an
/// ultrasonic Bessel field in a cylinder in air (flat caps); a glass rod guiding a tilted ray by
/// several total internal reflections; a tricubic grid in a sphere; the depth-graded profile in a
/// rounded box given by its signed distance, entered and left through rounded edges. Loss:
/// `L = |x_exit − p|² + a·d_exit`.
#[test]
fn exit_adjoint_matches_finite_differences() {
    use lightpath::eikonal::FieldParam;
    use lightpath::eikonal::grid::{GridField, Interp};
    let p = DVec3::new(0.2, -0.1, 2.5);
    let a = DVec3::new(0.3, -0.7, 0.2);
    let loss = |x: DVec3, d: DVec3| (x - p).length_squared() + a.dot(d);
    let dims = [6, 6, 6];
    let (origin, spacing) = (DVec3::splat(-1.25), 0.5);
    let samples: Vec<f64> = (0..216)
        .map(|i| {
            let q = origin
                + DVec3::new((i % 6) as f64, ((i / 6) % 6) as f64, (i / 36) as f64) * spacing;
            1.3 - 0.1 * q.length_squared() + 0.02 * q.x + 0.03 * ((i * 7919) % 13) as f64 / 13.0
        })
        .collect();
    let grid = GridField::from_samples(origin, spacing, dims, samples, Interp::Tricubic).unwrap();
    let param = |profile, which| FieldParam { profile, which };
    // a rounded box by its signed distance: the normal turns along the rounded edges
    let rounded_box = {
        use lightpath::eikonal::sdf::{SdfGrid, Shape};
        let shape = [Shape::Box {
            center: DVec3::ZERO,
            half: DVec3::new(0.8, 0.7, 0.9),
            rounding: 0.4,
        }];
        std::sync::Arc::new(SdfGrid::from_shapes(&shape, 0.0, 0.05, Interp::Tricubic).unwrap())
    };
    /// name, field, ray origin and direction, parameters, grid coefficient count
    type Case = (
        &'static str,
        BoundedField,
        DVec3,
        DVec3,
        Vec<FieldParam>,
        Option<usize>,
    );
    let cases: Vec<Case> = vec![
        (
            "luneburg",
            BoundedField::single(
                Profile::Luneburg { radius: 1.1 },
                Bounds::Sphere { radius: 1.0 },
                1.0,
            ),
            DVec3::new(0.3, 0.1, -2.0),
            DVec3::new(0.05, -0.02, 1.0).normalize(),
            vec![param(0, 0)],
            None,
        ),
        (
            "ultrasonic",
            BoundedField::single(
                Profile::Ultrasonic {
                    n0: 1.33,
                    n_max: 0.02,
                    k_r: 3.0,
                    m: 1,
                },
                Bounds::Cylinder {
                    radius: 2.0,
                    half_length: 1.0,
                },
                1.0,
            ),
            DVec3::new(0.3, 0.2, -3.0),
            DVec3::new(0.1, 0.05, 1.0).normalize(),
            vec![param(0, 0), param(0, 1), param(0, 2)],
            None,
        ),
        (
            "guided",
            BoundedField {
                profiles: vec![
                    Profile::Constant { n: 1.5 },
                    Profile::Linear {
                        n0: 0.0,
                        gradient: DVec3::new(0.01, 0.0, 0.02),
                    },
                ],
                bounds: Bounds::Cylinder {
                    radius: 0.5,
                    half_length: 3.0,
                },
                n_out: 1.0,
                scale: 1.0,
                offset: 0.0,
            },
            DVec3::new(0.05, 0.02, -3.2),
            DVec3::new(0.5, 0.03, 0.866).normalize(),
            vec![param(0, 0), param(1, 1), param(1, 3)],
            None,
        ),
        (
            "grid",
            BoundedField::single(Profile::Grid(grid), Bounds::Sphere { radius: 1.0 }, 1.0),
            DVec3::new(0.2, -0.1, -2.0),
            DVec3::new(0.03, 0.04, 1.0).normalize(),
            [(2, 2, 1), (3, 2, 2), (2, 3, 3), (3, 3, 4), (2, 2, 4)]
                .iter()
                .map(|(i, j, k)| param(0, i + 6 * (j + 6 * k)))
                .collect(),
            Some(216),
        ),
        (
            "signed distance",
            BoundedField::single(
                Profile::SdfLuneburg {
                    sdf: rounded_box.clone(),
                    n_surface: 1.2,
                    n_core: 1.4,
                    depth: 0.3,
                },
                Bounds::Sdf(rounded_box),
                1.0,
            ),
            DVec3::new(0.6, -0.15, -2.0),
            DVec3::new(0.1, 0.04, 1.0).normalize(),
            vec![param(0, 0), param(0, 1), param(0, 2)],
            None,
        ),
    ];
    for (name, field, o, w, params, grid_len) in cases {
        let trace = |f: &BoundedField, o: DVec3, w: DVec3| {
            let t = Tracer {
                field: f,
                step: 0.01,
                max_steps: 100_000,
            };
            let e = t.trace(o, w);
            assert!(e.entered && e.exited, "{name}: {e:?}");
            (loss(e.x, e.direction), e)
        };
        let t = Tracer {
            field: &field,
            step: 0.01,
            max_steps: 100_000,
        };
        let mut all = vec![0.0; grid_len.unwrap_or(0)];
        let adj = t
            .exit_adjoint(
                o,
                w,
                &params,
                grid_len.map(|_| GridAdjoint {
                    profile: 0,
                    grad: &mut all,
                }),
                |e| ((e.x - p) * 2.0, a),
            )
            .unwrap();
        let (_, end) = trace(&field, o, w);
        assert_eq!(
            adj.end, end,
            "{name}: the adjoint's forward pass differs from trace"
        );
        if name == "guided" {
            // the ray must really be guided: it leaves through the far cap, not the side
            assert!((end.x.z - 3.0).abs() < 1e-9, "guided: exit {}", end.x);
        }
        let h = 1e-6;
        let check = |what: String, got: f64, fd: f64| {
            eprintln!("{name} {what}: adjoint {got:.9e}, finite difference {fd:.9e}");
            assert!(
                (got - fd).abs() < 2e-6 * fd.abs().max(1e-2),
                "{name} {what}: {got} vs {fd}"
            );
        };
        for k in 0..3 {
            let mut e = DVec3::ZERO;
            e[k] = h;
            let fo = (trace(&field, o + e, w).0 - trace(&field, o - e, w).0) / (2.0 * h);
            check(format!("d/dorigin[{k}]"), adj.d_origin[k], fo);
            // directions are unit vectors: perturb on the sphere
            let fw = (trace(&field, o, (w + e).normalize()).0
                - trace(&field, o, (w - e).normalize()).0)
                / (2.0 * h);
            check(format!("d/ddirection[{k}]"), adj.d_direction[k], fw);
        }
        for (i, q) in params.iter().enumerate() {
            let shifted = |d: f64| {
                let mut f2 = field.clone();
                f2.profiles[q.profile] = bump(&f2.profiles[q.profile], q.which, d);
                trace(&f2, o, w).0
            };
            let fd = (shifted(h) - shifted(-h)) / (2.0 * h);
            check(format!("{q:?}"), adj.dparams[i], fd);
            if grid_len.is_some() {
                assert!((all[q.which] - adj.dparams[i]).abs() < 1e-12 * fd.abs().max(1e-6));
            }
        }
    }
}
