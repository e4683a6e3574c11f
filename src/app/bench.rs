//! `lightpath bench`: throughput of the estimators on the reference scene (`lightpath bench`) (box 10×10×10 λ,
//! mfp 5 λ, isotropic, 4 plane-wave lights, 72 far-field views, reversed paths) and the machine's
//! matrix-multiply rates for comparison. Timings are measured, never asserted.

use crate::math::{C64, Rng, rotate, stream_rng};
use crate::mc::{self, Plan};
use crate::medium::{Geometry, Medium, PhaseFunction, Scattering};
use crate::speckle::paths::{EventSink, SubpathSampler};
use crate::speckle::{Covariance, FieldSampler, Light, Scene, View};
use glam::DVec3;
use rayon::prelude::*;
use std::time::Instant;

/// The benchmark scene.
pub fn reference_scene() -> Scene {
    let medium = Medium {
        geometry: Geometry::boxed([10.0; 3]),
        sigma_s: 0.2,
        sigma_a: 0.0,
        scattering: Scattering::single(PhaseFunction::Isotropic),
    };
    let lights = [0.0f64, 2.0, 5.0, 20.0]
        .iter()
        .map(|a| Light::PlaneWave {
            direction: rotate(DVec3::Z, DVec3::Y, a.to_radians()),
        })
        .collect();
    let views = (0..72)
        .map(|i| View::FarField {
            direction: rotate(DVec3::Z, DVec3::Y, (5.0 * i as f64).to_radians()),
        })
        .collect();
    Scene::new(1.0, medium, lights, views)
}

struct Count(u64);
impl EventSink for Count {
    fn event(&mut self, _: bool, _: &[C64], _: &mut Rng) {
        self.0 += 1;
    }
    fn event_pair(&mut self, _: bool, _: &[C64], _: &[C64], _: &mut Rng) {
        self.0 += 1;
    }
}

/// Mean number of events (rank-1 updates) per path.
fn events_per_path(scene: &Scene) -> f64 {
    let s = SubpathSampler::new(scene, SubpathSampler::all_pairs(scene), true)
        .expect("reference scene");
    let mut sc = s.scratch();
    let mut rng = stream_rng(99, 0);
    let mut c = Count(0);
    let n = 100_000;
    for _ in 0..n {
        s.trace(&mut rng, &mut sc, &mut c);
    }
    c.0 as f64 / n as f64
}

/// GFLOP/s of square real and complex GEMMs of size `n`, one per thread on every thread at once.
fn gemm_rates(n: usize, reps: usize) -> (f64, f64) {
    let threads = rayon::current_num_threads();
    let a = vec![1.0e-3f64; 2 * n * n];
    let time = |complex: bool| {
        let t0 = Instant::now();
        (0..threads).into_par_iter().for_each(|_| {
            let mut c = vec![0.0f64; 2 * n * n];
            for _ in 0..reps {
                // SAFETY: a and c hold n×n (complex: 2n×n f64) matrices in row-major order.
                unsafe {
                    if complex {
                        matrixmultiply::zgemm(
                            matrixmultiply::CGemmOption::Standard,
                            matrixmultiply::CGemmOption::Standard,
                            n,
                            n,
                            n,
                            [1.0, 0.0],
                            a.as_ptr() as *const [f64; 2],
                            n as isize,
                            1,
                            a.as_ptr() as *const [f64; 2],
                            n as isize,
                            1,
                            [1.0, 0.0],
                            c.as_mut_ptr() as *mut [f64; 2],
                            n as isize,
                            1,
                        );
                    } else {
                        matrixmultiply::dgemm(
                            n,
                            n,
                            n,
                            1.0,
                            a.as_ptr(),
                            n as isize,
                            1,
                            a.as_ptr(),
                            n as isize,
                            1,
                            1.0,
                            c.as_mut_ptr(),
                            n as isize,
                            1,
                        );
                    }
                }
            }
            std::hint::black_box(&c);
        });
        t0.elapsed().as_secs_f64()
    };
    let flops = (threads * reps) as f64 * 2.0 * (n * n * n) as f64;
    // best of three: the rate the machine can reach
    let best = |complex| (0..3).map(|_| time(complex)).fold(f64::INFINITY, f64::min);
    let d = flops / best(false) / 1e9;
    let z = 4.0 * flops / best(true) / 1e9;
    (d, z)
}

/// GFLOP/s of the batched covariance update alone: `events` vectors of `j` fields pushed into a
/// [`Batch`](crate::speckle::covariance::Batch) and drained, on every thread at once, counting
/// the multiplications it performs ([`flops_per_event`](crate::speckle::covariance::flops_per_event);
/// best of three).
fn batch_rate(j: usize, events: usize) -> f64 {
    use crate::speckle::covariance::{Batch, flops_per_event};
    let threads = rayon::current_num_threads();
    let mut rng = stream_rng(5, 0);
    let vectors: Vec<Vec<C64>> = (0..256)
        .map(|_| {
            (0..j)
                .map(|_| {
                    C64::from_polar(
                        1.0,
                        std::f64::consts::TAU * rand::RngExt::random::<f64>(&mut rng),
                    )
                })
                .collect()
        })
        .collect();
    let time = || {
        let t0 = Instant::now();
        (0..threads).into_par_iter().for_each(|_| {
            let mut batch = Batch::new(j);
            let mut out = vec![C64::default(); j * j];
            for e in 0..events {
                batch.push(&vectors[e % vectors.len()]);
            }
            batch.drain_into(&mut out);
            std::hint::black_box(&out);
        });
        t0.elapsed().as_secs_f64()
    };
    let best = (0..3).map(|_| time()).fold(f64::INFINITY, f64::min);
    (threads * events) as f64 * flops_per_event(j) / best / 1e9
}

/// Run the benchmark and describe the figures.
pub fn run(quick: bool) -> crate::Result<String> {
    let scene = reference_scene();
    let threads = rayon::current_num_threads();
    let j = scene.lights.len() * scene.views.len();
    let events = events_per_path(&scene);
    let paths = if quick { 4_000 } else { 60_000 };

    let cov = Covariance::all_pairs(&scene, true)?;
    let plan = Plan::new(1, paths, 500);
    let t0 = Instant::now();
    std::hint::black_box(mc::run(&cov, &plan, 0..plan.chunks, &[], &|_| {}));
    let t_cov = t0.elapsed().as_secs_f64();
    let cov_paths = plan.samples() as f64 / t_cov;
    let cov_updates = cov_paths * events * (j * j) as f64;

    let field = FieldSampler::new(&scene, SubpathSampler::all_pairs(&scene), true)?;
    let plan_f = Plan::new(1, paths * 10, 5000);
    let t0 = Instant::now();
    std::hint::black_box(mc::run(&field, &plan_f, 0..plan_f.chunks, &[], &|_| {}));
    let t_field = t0.elapsed().as_secs_f64();
    let field_paths = plan_f.samples() as f64 / t_field;
    let field_updates = field_paths * events * j as f64;

    // gradient (σ_s, σ_a) contracted with a dense adjoint, against the forward estimate, same paths
    let grad_paths = if quick { 2_000 } else { 20_000 };
    let plan_g = Plan::new(1, grad_paths, 500);
    let pairs = SubpathSampler::all_pairs(&scene);
    let time_of = |f: &dyn Fn()| {
        let t0 = Instant::now();
        f();
        t0.elapsed().as_secs_f64()
    };
    let t_plain = time_of(&|| {
        std::hint::black_box(mc::run(&cov, &plan_g, 0..plan_g.chunks, &[], &|_| {}));
    });
    let adjoint: Vec<C64> = (0..j * j)
        .map(|i| C64::new((i % 7) as f64 - 3.0, (i % 5) as f64 - 2.0))
        .collect();
    let params = vec![crate::diff::Param::SigmaS, crate::diff::Param::SigmaA];
    let rw = crate::diff::Reweighted::new(&scene, scene.medium.clone(), pairs, true, params)?;
    let grad = crate::diff::CovarianceGradient::new(rw, &adjoint);
    let t_grad = time_of(&|| {
        std::hint::black_box(mc::run(&grad, &plan_g, 0..plan_g.chunks, &[], &|_| {}));
    });

    // the same with a 16-node tabulated phase function and every node a parameter (Adam fits)
    let (t_tab_plain, t_tab_grad) = {
        use crate::medium::{PhaseFunction, Scattering, Table};
        let cos: Vec<f64> = (0..16)
            .map(|i| -1.0 + 2.0 * (i as f64 / 15.0).powi(2))
            .collect();
        let rho = cos.iter().map(|c| 1.0 / (1.25 - c).powf(1.5)).collect();
        let table =
            Table::from_rho(Some(cos), rho).map_err(|e| crate::Error::input(e.to_string()))?;
        let mut tab = scene.clone();
        tab.medium.scattering = Scattering::single(PhaseFunction::Tabulated(table));
        let cov_tab = Covariance::all_pairs(&tab, true)?;
        let t_plain = time_of(&|| {
            std::hint::black_box(mc::run(&cov_tab, &plan_g, 0..plan_g.chunks, &[], &|_| {}));
        });
        let mut params = vec![crate::diff::Param::SigmaS, crate::diff::Param::SigmaA];
        params.extend((0..16).map(|k| crate::diff::Param::Bin(0, k)));
        let pairs = SubpathSampler::all_pairs(&tab);
        let rw = crate::diff::Reweighted::new(&tab, tab.medium.clone(), pairs, true, params)?;
        let grad = crate::diff::CovarianceGradient::new(rw, &adjoint);
        let t_grad = time_of(&|| {
            std::hint::black_box(mc::run(&grad, &plan_g, 0..plan_g.chunks, &[], &|_| {}));
        });
        (t_plain, t_grad)
    };

    let eikonal = eikonal_rates(quick);

    let (dgemm, zgemm) = gemm_rates(2 * j, if quick { 2 } else { 8 });
    let batch = batch_rate(j, if quick { 2_000 } else { 40_000 });
    let cov_flops = cov_updates * 8.0 / 1e9;
    // the share of the complex updates' arithmetic the real products actually do
    let done = crate::speckle::covariance::flops_per_event(j) / (8.0 * (j * j) as f64);
    Ok(format!(
        "reference scene: box 10×10×10 λ, mfp 5 λ, isotropic, 4 plane-wave lights × 72 far-field views (J = {j}), reversed paths; {threads} thread(s), {} vectors\n\
         events (rank-1 updates) per path: {events:.3}\n\
         covariance: {cov_paths:.0} paths/s ({:.0} per thread), {:.3e} entry-updates/s = {cov_flops:.2} GFLOP/s\n\
         fields:     {field_paths:.0} paths/s ({:.0} per thread), {:.3e} pixel-updates/s\n\
         GEMM ({}², all threads): real dgemm {dgemm:.2} GFLOP/s, complex zgemm {zgemm:.2} GFLOP/s\n\
         covariance estimate: {:.0} % of dgemm counting all J² entries as complex updates; the real products do \
         {:.0} % of that arithmetic (the real part's tiles on or above the diagonal, the imaginary part from one \
         product of half the depth), so the multiplications run at {:.0} % of dgemm over the whole estimate, path \
         sampling included\n\
         batched rank-1 update alone (push + real products + drain): {batch:.2} GFLOP/s of the multiplications done = {:.0} % of dgemm\n\
         gradient (σ_s, σ_a) of a loss over all J² entries: {:.2}× the cost of the forward covariance estimate ({} paths: {:.2} s vs {:.2} s)\n\
         gradient (σ_s, σ_a, 16 phase-table nodes), tabulated medium: {:.2}× its forward estimate ({:.2} s vs {:.2} s)",
        crate::math::simd::Width::widest().name(),
        cov_paths / threads as f64,
        cov_updates,
        field_paths / threads as f64,
        field_updates,
        2 * j,
        100.0 * cov_flops / dgemm,
        100.0 * done,
        100.0 * cov_flops * done / dgemm,
        100.0 * batch / dgemm,
        t_grad / t_plain,
        plan_g.samples(),
        t_grad,
        t_plain,
        t_tab_grad / t_tab_plain,
        t_tab_grad,
        t_tab_plain,
    ) + &eikonal)
}

/// Ray-steps/s of the graded-index tracer and its adjoint on a 64³ grid (tricubic and trilinear),
/// rays in parallel.
fn eikonal_rates(quick: bool) -> String {
    use crate::eikonal::grid::{GridField, Interp};
    use crate::eikonal::{BoundedField, Bounds, IndexField, Profile, Ray, Tracer};
    let n = 64;
    let spacing = 2.0 / (n - 1) as f64;
    let origin = DVec3::splat(-1.0);
    let mut samples = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                samples.push((2.0 - p.length_squared().min(1.0)).sqrt());
            }
        }
    }
    let rays = if quick { 512 } else { 4096 };
    let steps = 200;
    let mut out = String::new();
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let Ok(grid) = GridField::from_samples(origin, spacing, [n, n, n], samples.clone(), interp)
        else {
            continue;
        };
        let field = BoundedField::single(Profile::Grid(grid), Bounds::Everywhere, 1.0);
        let t = Tracer {
            field: &field,
            step: 0.005,
            max_steps: 0,
        };
        let start = |r: usize| {
            let x = DVec3::new(
                -0.5 + (r % 64) as f64 / 64.0,
                -0.5 + (r / 64 % 64) as f64 / 64.0,
                -0.5,
            );
            Ray {
                x,
                v: DVec3::Z * field.n(x),
            }
        };
        let t0 = Instant::now();
        let sum: f64 = (0..rays)
            .into_par_iter()
            .map(|r| t.steps(start(r), steps, 0.005).x.z)
            .sum();
        let fwd = (rays * steps) as f64 / t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let adj: f64 = (0..rays)
            .into_par_iter()
            .map(|r| {
                t.adjoint(start(r), steps, 0.005, &[], |f| (f.x, DVec3::ZERO))
                    .map_or(0.0, |g| g.dx0.z)
            })
            .sum();
        let back = (rays * steps) as f64 / t0.elapsed().as_secs_f64();
        // the gradient with respect to every grid coefficient: one accumulator per thread, summed
        // (few rays here: more accumulators would time their allocation rather than the adjoint)
        let t0 = Instant::now();
        let coefs = n * n * n;
        let groups = rayon::current_num_threads();
        let per = rays.div_ceil(groups);
        let full: Vec<f64> = (0..groups)
            .into_par_iter()
            .map(|g| {
                let mut acc = vec![0.0; coefs];
                for r in g * per..((g + 1) * per).min(rays) {
                    let grid = Some(crate::eikonal::GridAdjoint {
                        profile: 0,
                        grad: &mut acc,
                    });
                    let _ = t.adjoint_with_grid(start(r), steps, 0.005, &[], grid, |f| {
                        (f.x, DVec3::ZERO)
                    });
                }
                acc
            })
            .reduce(
                || vec![0.0; coefs],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let grid_rate = (rays * steps) as f64 / t0.elapsed().as_secs_f64();
        std::hint::black_box((sum, adj, full[coefs / 2]));
        // the published GPU benchmark: 128³ grid, 128² rays × 10, ~400 steps each
        // a design iteration's forward and its reverse pass (which starts from the forward's final
        // states) together cost one adjoint with the grid (which traces the ray forward first)
        let per_iteration = (128.0 * 128.0 * 10.0 * 400.0) / grid_rate;
        out += &format!(
            "\neikonal {interp:?} 64³ grid: forward {fwd:.3e} ray-steps/s, adjoint (initial state) {back:.3e} ray-steps/s, \
             adjoint with every grid coefficient {grid_rate:.3e} ray-steps/s \
             (so 128² rays × 10 × 400 steps, forward + adjoint: ≈ {per_iteration:.0} s per design iteration)"
        );
    }
    out + &ultrasonic_rates(quick) + &flight_rates(quick)
}

/// Steps/s of the renderer's free flights along curved rays, from random points inside to the
/// surface: the Luneburg lens bounded by its sphere, and the same lens as a sampled sphere (0.05
/// grid) with the depth-graded profile, and a linear index in that sampled sphere; testing
/// inside–outside after every step and skipping the test within the clearance (paper 002, Sec. 5).
fn flight_rates(quick: bool) -> String {
    use crate::eikonal::grid::Interp;
    use crate::eikonal::sdf::{SdfGrid, Shape};
    use crate::eikonal::{BoundedField, Bounds, Profile, Ray};
    use crate::math::uniform;
    use crate::rrte::{Volume, flight::Flyer};
    let flights = if quick { 1_000 } else { 20_000 };
    let shape = [Shape::Sphere {
        center: DVec3::ZERO,
        radius: 1.0,
    }];
    let Ok(sdf) = SdfGrid::from_shapes(&shape, 0.0, 0.05, Interp::Tricubic) else {
        return String::new();
    };
    let sdf = std::sync::Arc::new(sdf);
    let volume = |profile, bounds| Volume {
        field: BoundedField::single(profile, bounds, 1.0),
        sigma_s: 1.0,
        sigma_a: 0.0,
        scattering: Scattering::single(PhaseFunction::Isotropic),
        density: None,
        parts: Vec::new(),
    };
    let volumes = [
        (
            "Luneburg sphere",
            volume(
                Profile::Luneburg { radius: 1.0 },
                Bounds::Sphere { radius: 1.0 },
            ),
        ),
        (
            "sampled sphere, linear index",
            volume(
                Profile::Linear {
                    n0: 1.3,
                    gradient: DVec3::new(0.1, 0.05, 0.0),
                },
                Bounds::Sdf(sdf.clone()),
            ),
        ),
        (
            "sampled sphere, depth-graded index",
            volume(
                Profile::SdfLuneburg {
                    sdf: sdf.clone(),
                    n_surface: 1.0,
                    n_core: 2f64.sqrt(),
                    depth: 1.0,
                },
                Bounds::Sdf(sdf),
            ),
        ),
    ];
    let mut out = String::new();
    for (name, v) in &volumes {
        let rate = |skip: bool| {
            let flyer = Flyer::new(v, 0.005, 1_000_000).skipping_tests(skip);
            let t0 = Instant::now();
            let steps: usize = (0..flights)
                .into_par_iter()
                .map(|i| {
                    let mut rng = stream_rng(3, i as u64);
                    let mut u = || 2.0 * uniform(&mut rng) - 1.0;
                    let x = DVec3::new(u(), u(), u()) * 0.55;
                    let d = DVec3::new(u(), u(), u()).normalize_or(DVec3::Z);
                    let r = Ray {
                        x,
                        v: d * flyer.n(x),
                    };
                    flyer.fly(r, f64::INFINITY).1
                })
                .sum();
            (steps as f64 / t0.elapsed().as_secs_f64(), steps / flights)
        };
        let (testing, steps) = rate(false);
        let (skipping, _) = rate(true);
        out += &format!(
            "\nfree flights, {name} (step 0.005, ~{steps} steps each): {testing:.3e} steps/s testing inside–outside every step, \
             {skipping:.3e} skipping the test within the clearance ({:.2}×)",
            skipping / testing
        );
    }
    out
}

/// Ray-steps/s through the ultrasonic Bessel field (m = 2, plane-wave quadrature per evaluation):
/// tracing to the exit and the exit adjoint with respect to `(n0, n_max, k_r)`.
fn ultrasonic_rates(quick: bool) -> String {
    use crate::eikonal::{BoundedField, Bounds, FieldParam, Profile, Tracer};
    let field = BoundedField::single(
        Profile::Ultrasonic {
            n0: 1.33,
            n_max: 1e-3,
            k_r: 4.0,
            m: 2,
        },
        Bounds::Cylinder {
            radius: 5.0,
            half_length: 15.0,
        },
        1.33,
    );
    let t = Tracer {
        field: &field,
        step: 0.05,
        max_steps: 1_000_000,
    };
    let rays = if quick { 256 } else { 2048 };
    let origin = |r: usize| {
        DVec3::new(
            -0.5 + (r % 32) as f64 / 32.0,
            -0.5 + (r / 32 % 32) as f64 / 32.0,
            -16.0,
        )
    };
    let t0 = Instant::now();
    let steps: usize = (0..rays)
        .into_par_iter()
        .map(|r| t.trace(origin(r), DVec3::Z).steps)
        .sum();
    let fwd = steps as f64 / t0.elapsed().as_secs_f64();
    let params: Vec<FieldParam> = (0..3)
        .map(|which| FieldParam { profile: 0, which })
        .collect();
    let t0 = Instant::now();
    let g: f64 = (0..rays)
        .into_par_iter()
        .map(|r| {
            t.exit_adjoint(origin(r), DVec3::Z, &params, None, |e| (e.x, DVec3::ZERO))
                .map_or(0.0, |g| g.dparams[1])
        })
        .sum();
    let back = steps as f64 / t0.elapsed().as_secs_f64();
    std::hint::black_box(g);
    format!(
        "\neikonal ultrasonic J_2 field: trace to exit {fwd:.3e} ray-steps/s, \
         exit adjoint (forward + reverse, 3 parameters) {back:.3e} ray-steps/s"
    )
}

/// Floating-point operations of one forward and one reverse step of a design iteration, counted
/// by hand in the kernels (stencil weights, the axis-by-axis contraction, the leapfrog; the
/// reverse: the evaluation with the Hessian, the force Jacobian, the adjoint step and the scatter).
fn step_flops(interp: crate::eikonal::grid::Interp) -> (f64, f64) {
    match interp {
        crate::eikonal::grid::Interp::Tricubic => (490.0, 1320.0),
        crate::eikonal::grid::Interp::Trilinear => (110.0, 330.0),
    }
}

/// One design iteration at the published GPU benchmark's scale, measured (not extrapolated): a
/// 128³ grid (Luneburg samples), 128² rays × 10 (a collimated bundle), 400 leapfrog steps each,
/// forward and backward of [`crate::diff::TraceOp`] (the gradient of every coefficient).
pub fn design_iteration() -> crate::Result<String> {
    use crate::diff::TraceOp;
    use crate::diff::bridge::Differentiable;
    use crate::eikonal::grid::{GridField, Interp};
    use crate::eikonal::{BoundedField, Bounds, IndexField, Profile, Ray};
    let n = 128;
    let spacing = 2.0 / (n - 1) as f64;
    let origin = DVec3::splat(-1.0);
    let samples: Vec<f64> = (0..n * n * n)
        .map(|i| {
            let p = origin
                + DVec3::new((i % n) as f64, (i / n % n) as f64, (i / (n * n)) as f64) * spacing;
            (2.0 - p.length_squared().min(1.0)).sqrt()
        })
        .collect();
    let rays = 128 * 128 * 10;
    // the machine's practical FMA peak: what a tuned real GEMM reaches on every thread
    let (dgemm, _) = gemm_rates(576, 8);
    let mut out = String::new();
    for interp in [Interp::Tricubic, Interp::Trilinear] {
        let grid = GridField::from_samples(origin, spacing, [n; 3], samples.clone(), interp)?;
        let coef = grid.coef.clone();
        let field = BoundedField::single(Profile::Grid(grid), Bounds::Everywhere, 1.0);
        let starts: Vec<Ray> = (0..rays)
            .map(|r| {
                // a 405 × 405 lattice across the unit disk's bounding square, in order
                let (a, b) = ((r % 405) as f64 / 404.0, (r / 405) as f64 / 404.0);
                let x = DVec3::new(1.4 * a - 0.7, 1.4 * b - 0.7, -0.99);
                Ray {
                    x,
                    v: DVec3::Z * field.n(x),
                }
            })
            .collect();
        let op = TraceOp {
            field,
            profile: 0,
            rays: starts,
            steps: 400,
            step: 0.005,
            to_exit: false,
            stop: Default::default(),
        };
        let t0 = Instant::now();
        let (y, pullback) = op.forward(&coef)?;
        let forward = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let g = pullback.pullback(&y);
        let backward = t0.elapsed().as_secs_f64();
        std::hint::black_box(g[coef.len() / 2]);
        let ray_steps = (rays * 400) as f64;
        let (fwd_flops, back_flops) = step_flops(interp);
        let (fwd_rate, back_rate) = (
            ray_steps * fwd_flops / forward * 1e-9,
            ray_steps * back_flops / backward * 1e-9,
        );
        out += &format!(
            "design iteration, {interp:?} 128³ grid, 128² × 10 rays × 400 steps, {} vectors: forward {forward:.2} s + \
             backward (every coefficient) {backward:.2} s = {:.2} s; {:.2e} ray-steps/s forward, {:.2e} backward; \
             ~{fwd_rate:.1} and ~{back_rate:.1} GFLOP/s ({:.0} % and {:.0} % of dgemm's {dgemm:.1} GFLOP/s)\n",
            crate::math::simd::Width::widest().name(),
            forward + backward,
            ray_steps / forward,
            ray_steps / backward,
            100.0 * fwd_rate / dgemm,
            100.0 * back_rate / dgemm
        );
    }
    Ok(out)
}
