//! The covariance diagonal is the incoherent intensity (paper 001, Sec. 3): check it against an
//! independent plain radiometric volumetric path tracer written here (its own sampling, its own
//! attenuation and phase-function code), for far-field and point lights and views, isotropic and
//! Henyey–Greenstein scattering, with and without absorption.
//!
//! Catches: a wrong 4π or V factor in Algorithm 1's weights, wrong attenuation (τ vs τ²), a wrong
//! phase-function argument at the path ends, broken absorption handling.

use glam::DVec3;
use lightpath::math::{C64, Rng, stream_rng, uniform};
use lightpath::mc::{Estimate, Plan, merge, run};
use lightpath::medium::{Geometry, Medium, PhaseFunction, Scattering};
use lightpath::speckle::{Covariance, Light, Scene, View};
use std::f64::consts::PI;

fn hg(g: f64, mu: f64) -> f64 {
    (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * mu).powf(1.5))
}

fn sample_hg(g: f64, w: DVec3, rng: &mut Rng) -> DVec3 {
    let (u1, u2) = (uniform(rng), uniform(rng));
    let mu = if g == 0.0 {
        2.0 * u1 - 1.0
    } else {
        let t = (1.0 - g * g) / (1.0 + g - 2.0 * g * u1);
        (1.0 + g * g - t * t) / (2.0 * g)
    };
    // frame by Gram–Schmidt against the least aligned axis
    let a = if w.x.abs() < 0.6 { DVec3::X } else { DVec3::Y };
    let t = (a - w * a.dot(w)).normalize();
    let b = w.cross(t);
    let s = (1.0 - mu * mu).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    w * mu + t * (s * phi.cos()) + b * (s * phi.sin())
}

/// Distance from inside point x along w to the surface of the box |x_a| ≤ h_a.
fn exit(h: DVec3, x: DVec3, w: DVec3) -> f64 {
    let mut t = f64::INFINITY;
    for a in 0..3 {
        if w[a] != 0.0 {
            let face = if w[a] > 0.0 { h[a] } else { -h[a] };
            t = t.min((face - x[a]) / w[a]);
        }
    }
    t.max(0.0)
}

/// Entry/exit of the ray o + t w with the box (slab method).
fn hit(h: DVec3, o: DVec3, w: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (ta, tb) = ((-h[a] - o[a]) / w[a], (h[a] - o[a]) / w[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 < t1).then_some((t0, t1))
}

#[derive(Clone, Copy)]
enum Src {
    Plane(DVec3),
    Point(DVec3),
}
#[derive(Clone, Copy)]
enum Det {
    Far(DVec3),
    Point(DVec3),
}

/// Bulk coefficients and HG anisotropy.
#[derive(Clone, Copy)]
struct Mat {
    sigma_s: f64,
    sigma_a: f64,
    g: f64,
}

/// Radiometric intensity estimate (mean, stderr) by analog-direction path tracing with next events.
fn path_trace(h: DVec3, mat: Mat, src: Src, det: Det, n: usize, seed: u64) -> (f64, f64) {
    let Mat {
        sigma_s,
        sigma_a,
        g,
    } = mat;
    let st = sigma_s + sigma_a;
    let batches = 50;
    let mut means = vec![0.0; batches];
    for (bi, mean) in means.iter_mut().enumerate() {
        let mut rng = stream_rng(seed, bi as u64);
        let mut acc = 0.0;
        for _ in 0..n / batches {
            // launch
            let (o, w, weight) = match src {
                Src::Plane(d) => {
                    let r = h.length();
                    let a = if d.x.abs() < 0.6 { DVec3::X } else { DVec3::Y };
                    let t = (a - d * a.dot(d)).normalize();
                    let b = d.cross(t);
                    let rad = r * uniform(&mut rng).sqrt();
                    let phi = 2.0 * PI * uniform(&mut rng);
                    (
                        t * rad * phi.cos() + b * rad * phi.sin() - d * 2.0 * r,
                        d,
                        PI * r * r,
                    )
                }
                Src::Point(p) => {
                    let z = 1.0 - 2.0 * uniform(&mut rng);
                    let phi = 2.0 * PI * uniform(&mut rng);
                    let s = (1.0 - z * z).sqrt();
                    (p, DVec3::new(s * phi.cos(), s * phi.sin(), z), 4.0 * PI)
                }
            };
            let Some((t0, t1)) = hit(h, o, w) else {
                continue;
            };
            let t = t0 - (1.0 - uniform(&mut rng)).ln() / st;
            if t >= t1 {
                continue;
            }
            let mut x = o + w * t;
            let mut w = w;
            let mut weight = weight;
            loop {
                weight *= sigma_s / st;
                acc += match det {
                    Det::Far(v) => weight * hg(g, w.dot(v)) * (-st * exit(h, x, v)).exp(),
                    Det::Point(q) => {
                        let dq = q - x;
                        let r = dq.length();
                        let dir = dq / r;
                        weight * hg(g, w.dot(dir)) * (-st * exit(h, x, dir).min(r)).exp() / (r * r)
                    }
                };
                w = sample_hg(g, w, &mut rng);
                let d = -(1.0 - uniform(&mut rng)).ln() / st;
                if d >= exit(h, x, w) {
                    break;
                }
                x += w * d;
            }
        }
        *mean = acc / (n / batches) as f64;
    }
    let m = means.iter().sum::<f64>() / batches as f64;
    let var = means.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (batches - 1) as f64;
    (m, (var / batches as f64).sqrt())
}

fn check(size: [f64; 3], sigma_s: f64, sigma_a: f64, g: f64, src: Src, dets: &[Det]) {
    let phase = if g == 0.0 {
        PhaseFunction::Isotropic
    } else {
        PhaseFunction::HenyeyGreenstein { g }
    };
    let medium = Medium {
        geometry: Geometry::boxed(size),
        sigma_s,
        sigma_a,
        scattering: Scattering::single(phase),
    };
    let light = match src {
        Src::Plane(d) => Light::PlaneWave { direction: d },
        Src::Point(p) => Light::Point { position: p },
    };
    let views = dets
        .iter()
        .map(|d| match *d {
            Det::Far(v) => View::FarField { direction: v },
            Det::Point(q) => View::Point { position: q },
        })
        .collect();
    let scene = Scene::new(1.0, medium, vec![light], views);
    let est = Covariance::all_pairs(&scene, false).unwrap();
    let plan = Plan::new(11, 200_000, 2000);
    let block = merge(run(&est, &plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap();
    let e = Estimate::from_block(&block, &plan);
    let j = dets.len();
    let h = DVec3::from_array(size) * 0.5;
    for (v, det) in dets.iter().enumerate() {
        let idx = 2 * j * j + v * j + v; // total block, diagonal entry
        let (c, c_se): (C64, f64) = (e.mean[idx], e.stderr[idx]);
        let (pt, pt_se) = path_trace(
            h,
            Mat {
                sigma_s,
                sigma_a,
                g,
            },
            src,
            *det,
            400_000,
            5 + v as u64,
        );
        let z = (c.re - pt) / (c_se * c_se + pt_se * pt_se).sqrt();
        eprintln!(
            "view {v}: covariance {:.6e} ± {:.1e}, path tracer {:.6e} ± {:.1e}, z = {z:.2}",
            c.re, c_se, pt, pt_se
        );
        assert!(c.im.abs() < 5.0 * c_se, "diagonal must be real: {c}");
        assert!(z.abs() < 4.0, "view {v}: z = {z}");
        assert!(c_se < 0.05 * c.re, "test too noisy to catch a 10% error");
    }
}

#[test]
fn plane_wave_far_field_isotropic() {
    let d = DVec3::new(0.2, 0.0, 1.0).normalize();
    let dets = [
        DVec3::Z,
        DVec3::new(1.0, 0.0, 0.2).normalize(),
        DVec3::new(0.3, 0.4, -1.0).normalize(),
    ];
    check(
        [4.0, 5.0, 3.0],
        0.5,
        0.0,
        0.0,
        Src::Plane(d),
        &dets.map(Det::Far),
    );
}

#[test]
fn plane_wave_far_field_hg_absorbing() {
    let dets = [
        DVec3::new(0.0, 0.3, 1.0).normalize(),
        DVec3::X,
        DVec3::new(0.1, 0.0, -1.0).normalize(),
    ];
    check(
        [4.0, 4.0, 4.0],
        0.4,
        0.15,
        0.6,
        Src::Plane(DVec3::Z),
        &dets.map(Det::Far),
    );
}

#[test]
fn point_light_point_view() {
    let p = DVec3::new(0.0, 0.0, -4.0);
    let dets = [
        Det::Point(DVec3::new(0.5, 0.0, 4.0)),
        Det::Point(DVec3::new(4.0, 1.0, 0.0)),
        Det::Far(DVec3::Y),
    ];
    check([3.0, 3.0, 3.0], 0.6, 0.0, 0.3, Src::Point(p), &dets);
}
