//! Single scattering in closed form: the covariance of paths that scatter once (paper 001, Eq. 41),
//!
//! `C = σ_s S(i1·v1, i2·v2) ∫_V exp(i k ((i1 − v1) − (i2 − v2))·x) η(x) dx`,
//! `η(x) = exp(−σ_t (D(x, −i1) + D(x, v1) + D(x, −i2) + D(x, v2)) / 2)`,
//!
//! with `S = Σ β_ι s_ι(i1·v1) s_ι(i2·v2)*` over particle types (Eq. 44) and `D(x, w)` the distance
//! from `x` to the surface along `w`. Outside the memory effect this is the whole covariance, even in
//! optically thick media (paper 001, Sec. 7; paper 004, Sec. 3), at no Monte Carlo cost.
//!
//! With plane-wave lights and far-field views the integral is exact. In a box the exponent is linear on the convex cells
//! where each of the four legs leaves through a fixed face; every cell is integrated exactly
//! ([`Polyhedron::integrate_exp`]). A slab is per unit area over the `slab_window` the Monte Carlo
//! draws first vertices from, exactly as that estimator normalises it: the lateral integral is
//! `sinc(q_x W/2) sinc(q_y W/2)` and the depth integral an exponential. For near-normal legs through
//! a slab this is paper 004's Claim 1 (Eq. 3) without its paraxial approximation.
//!
//! Point and focused lights and views (in a box) have no such closed form: the integral
//! `C = ∫_V σ_s Σ_ι β_ι A_ι(x) A_ι(x)ᴴ dx` is taken by composite Gauss–Legendre quadrature over
//! the box, with `A_ι(x)` the very vertex amplitudes the Monte Carlo's first event uses
//! ([`SubpathSampler::single_at`]: spherical waves, `Υ` of a lens, Eqs. 14–18). The panels are at
//! most `λ/2` (a pair's phase moves by at most `4k` per unit length: under `2π` per panel, 4 nodes
//! each) and half the narrowest beam waist `√γ/k`; doubling them changes the result by under
//! 1e-4 in the tests. Deterministic and free of Monte Carlo noise, at a cost of one event per node.

use crate::math::polytope::Polyhedron;
use crate::math::{C64, CVec3};
use crate::medium::Geometry;
use crate::speckle::covariance::Batch;
use crate::speckle::paths::SubpathSampler;
use crate::speckle::{Light, Scene, View};
use glam::DVec3;

/// The exit distance from `x` along `w` to each box face it can reach, as `α + β·x`.
///
/// A face nearly parallel to `w` is the exit only within a sliver of thickness at most
/// `|w_a|·2|half|` beside it; where that is below 1e-12 of the box's side (`w` from `cos 90°`
/// is `6e-17`, not 0) the face is left out: its sliver weighs less than round-off, while its
/// planes, with coefficients `1/|w_a|`, would wreck the cells' integrals.
pub(crate) fn face_distances(half: DVec3, w: DVec3) -> Vec<(f64, DVec3)> {
    let reach = 2.0 * half.length();
    (0..3)
        .filter(|&a| w[a].abs() * reach > 1e-12 * half[a])
        .map(|a| {
            let mut beta = DVec3::ZERO;
            beta[a] = -1.0 / w[a];
            (half[a] / w[a].abs(), beta)
        })
        .collect()
}

/// `∫_box exp(i q·x − σ_t Σ_j D(x, w_j) / 2) dx` exactly, for any number of legs `w_j`: the box
/// splits into convex cells on which every leg's exit face is fixed, where the exponent is linear.
/// `σ_t` may be complex (the integral is entire in it).
pub(crate) fn box_exit_integral(half: DVec3, q: DVec3, sigma_t: C64, legs: &[DVec3]) -> C64 {
    // equal legs (an intensity's in and out pairs) count twice on one split: clipping a cell
    // again by its own boundary planes would leave degenerate slivers
    let mut distinct: Vec<(DVec3, f64)> = Vec::new();
    for &w in legs {
        match distinct.iter_mut().find(|(d, _)| *d == w) {
            Some((_, n)) => *n += 1.0,
            None => distinct.push((w, 1.0)),
        }
    }
    let faces: Vec<Vec<(f64, DVec3)>> = distinct
        .iter()
        .map(|&(w, n)| {
            face_distances(half, w)
                .into_iter()
                .map(|(a, b)| (a * n, b * n))
                .collect()
        })
        .collect();
    let st = sigma_t * 0.5;
    let mut total = C64::default();
    // depth-first over the legs: (cell, leg index, Σ α, Σ β)
    let mut stack = vec![(Polyhedron::cuboid(-half, half), 0usize, 0.0, DVec3::ZERO)];
    while let Some((cell, j, alpha, beta)) = stack.pop() {
        if j == faces.len() {
            let b = CVec3 {
                re: -beta * st.re,
                im: q - beta * st.im,
            };
            total += cell.integrate_exp(b, -st * alpha);
            continue;
        }
        for (i, &(ai, bi)) in faces[j].iter().enumerate() {
            // the part of the cell where face i is the nearest along leg j
            let mut part = Some(cell.clone());
            for (_, &(a, b)) in faces[j].iter().enumerate().filter(|(n, _)| *n != i) {
                part = part.and_then(|c| c.clip(bi - b, a - ai));
            }
            if let Some(part) = part {
                stack.push((part, j + 1, alpha + ai, beta + bi));
            }
        }
    }
    total
}

/// `sin(x)/x`, 1 at 0.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-8 { 1.0 } else { x.sin() / x }
}

/// `(e^{a h} − e^{−a h}) / a`: `∫_{−h}^{h} e^{a z} dz`, accurate for small `|a h|`.
fn symmetric_exp_integral(a: C64, h: f64) -> C64 {
    let x = a * h;
    if x.norm() < 1e-4 {
        C64::new(2.0 * h, 0.0) * (1.0 + x * x / 6.0)
    } else {
        ((x).exp() - (-x).exp()) / a
    }
}

/// The slab's per-unit-area integral over its window (see module docs): 0 when a leg runs parallel
/// to the faces (it never leaves).
fn slab_integral(half_thickness: f64, window: f64, q: DVec3, sigma_t: f64, legs: &[DVec3]) -> C64 {
    let (mut alpha, mut beta) = (0.0, 0.0);
    for w in legs {
        if w.z == 0.0 {
            return C64::default();
        }
        // distance to the face ahead: (h − z)/w_z going up, (h + z)/|w_z| going down
        alpha += half_thickness / w.z.abs();
        beta -= 1.0 / w.z;
    }
    let st = 0.5 * sigma_t;
    let a = C64::new(-st * beta, q.z);
    let lateral = sinc(0.5 * q.x * window) * sinc(0.5 * q.y * window);
    symmetric_exp_integral(a, half_thickness) * (-st * alpha).exp() * lateral
}

/// The first light that is not a plane wave and the first view that is not a far-field view.
fn not_far(scene: &Scene) -> (Option<usize>, Option<usize>) {
    let light = scene
        .lights
        .iter()
        .position(|l| !matches!(l, Light::PlaneWave { .. }));
    let view = scene
        .views
        .iter()
        .position(|v| !matches!(v, View::FarField { .. }));
    (light, view)
}

/// Why a scene has no single-scattering closed form here: point and focused endpoints need a box
/// (a slab's lateral integral is unbounded for them).
pub fn unsupported(scene: &Scene) -> Option<String> {
    let (light, view) = not_far(scene);
    if !matches!(scene.medium.geometry, Geometry::Slab { .. }) {
        return None;
    }
    let what = match (light, view) {
        (Some(i), _) => format!("light[{i}] is not a plane wave"),
        (_, Some(i)) => format!("view {i} is not a far-field view"),
        _ => return None,
    };
    Some(format!(
        "{what}; in a slab the single-scattering closed form takes plane-wave lights and far-field views (use medium.box for point and focused ones, or the Monte Carlo estimator)"
    ))
}

/// The longest a point or focused single-scattering quadrature may take, seconds on two cores by
/// [`quadrature_seconds`].
const MAX_SECONDS: f64 = 20.0;

/// Estimated seconds on two cores for `nodes` quadrature nodes, `terminals` lights and views and
/// `entries` outputs: each node connects every terminal (about 0.4 µs each, focused ones
/// included) and adds its rank-1 term to every entry (about 0.4 ns each); measured on a 4 × 4 × 3 λ
/// box, 5 terminals (0.35 s) and 103 (7.2 s).
fn quadrature_seconds(nodes: f64, terminals: usize, entries: usize) -> f64 {
    nodes * (4e-7 * terminals as f64 + 4e-10 * entries as f64)
}

/// The single-scattering covariance `C[j1·J + j2]` (`j = l·V + v`) of every light and view pair.
pub fn covariance(scene: &Scene) -> crate::Result<Vec<C64>> {
    if let Some(why) = unsupported(scene) {
        return Err(crate::Error::input(why));
    }
    if not_far(scene) != (None, None) {
        return quadrature(scene, 1.0);
    }
    let dir = |l: &Light| match *l {
        Light::PlaneWave { direction } => direction,
        _ => unreachable!("checked above"),
    };
    let vdir = |v: &View| match *v {
        View::FarField { direction } => direction,
        _ => unreachable!("checked above"),
    };
    let pairs: Vec<(DVec3, DVec3)> = scene
        .lights
        .iter()
        .flat_map(|l| scene.views.iter().map(move |v| (dir(l), vdir(v))))
        .collect();
    let m = &scene.medium;
    let j = pairs.len();
    use rayon::prelude::*;
    let c: Vec<C64> = (0..j * j)
        .into_par_iter()
        .map(|idx| {
            let ((i1, v1), (i2, v2)) = (pairs[idx / j], pairs[idx % j]);
            let q = ((i1 - v1) - (i2 - v2)) * scene.k;
            let legs = [-i1, v1, -i2, v2];
            let integral = match m.geometry {
                Geometry::Box { half } => {
                    box_exit_integral(half, q, C64::new(m.sigma_t(), 0.0), &legs)
                }
                Geometry::Slab {
                    half_thickness,
                    window,
                } => slab_integral(half_thickness, window, q, m.sigma_t(), &legs),
            };
            m.scattering.amplitude_product(i1.dot(v1), i2.dot(v2)) * integral * m.sigma_s
        })
        .collect();
    Ok(c)
}

/// [`covariance`] by quadrature over a box for any lights and views (module docs); `refine`
/// divides the panels (1 in use, 2 to check convergence).
pub fn quadrature(scene: &Scene, refine: f64) -> crate::Result<Vec<C64>> {
    let Geometry::Box { half } = scene.medium.geometry else {
        return Err(crate::Error::input(
            "single scattering by quadrature needs a box (medium.box)",
        ));
    };
    let sampler = SubpathSampler::new(scene, SubpathSampler::all_pairs(scene), false)?;
    if sampler.draws_apertures() {
        return Err(crate::Error::input(
            "render.estimator = \"single_scattering\" integrates the first event by quadrature: render.aperture = \"monte_carlo\" draws directions per path and needs the Monte Carlo estimator; use aperture = \"vmf\" or \"quadrature\"",
        ));
    }
    let k = scene.k;
    let lenses = scene
        .lights
        .iter()
        .filter_map(|l| match l {
            Light::Focused { gamma, .. } => Some(*gamma),
            _ => None,
        })
        .chain(scene.views.iter().filter_map(|v| match v {
            View::Focused { gamma, .. } => Some(*gamma),
            _ => None,
        }));
    let panel = lenses.fold(std::f64::consts::PI / k, |p, gamma| {
        p.min(0.5 * gamma.sqrt() / k)
    }) / refine;
    let panels = |a: usize| (2.0 * half[a] / panel).ceil().max(1.0);
    // checked before any node is laid out (a box of many wavelengths has too many to hold)
    let nodes = 64.0 * panels(0) * panels(1) * panels(2);
    let j = sampler.pairs().len();
    let seconds = quadrature_seconds(nodes, scene.lights.len() + scene.views.len(), j * j);
    if seconds > MAX_SECONDS {
        return Err(crate::Error::input(format!(
            "single scattering with point or focused endpoints in this box needs {nodes:.3e} quadrature nodes (panels of {panel:.3} for the wavelength and the narrowest beam) for {} entries, about {seconds:.0} s, beyond {MAX_SECONDS} s; use fewer lights and views, a smaller box, or the Monte Carlo estimator",
            j * j
        )));
    }
    let axis = |a: usize| -> Vec<(f64, f64)> {
        let panels = panels(a) as usize;
        let (x, w) = crate::math::gauss_legendre(4);
        let width = 2.0 * half[a] / panels as f64;
        (0..panels)
            .flat_map(|p| {
                let centre = -half[a] + (p as f64 + 0.5) * width;
                x.iter()
                    .zip(&w)
                    .map(move |(x, w)| (centre + 0.5 * width * x, 0.5 * width * w))
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let (nx, ny, nz) = (axis(0), axis(1), axis(2));
    let m = &scene.medium;
    let components = m.scattering.components();
    let slice = |z: &(f64, f64)| -> Vec<C64> {
        let (mut sc, mut batch) = (sampler.scratch(), Batch::new(j));
        let mut a = vec![C64::default(); j];
        for y in &ny {
            for x in &nx {
                let p = DVec3::new(x.0, y.0, z.0);
                for (kind, (beta, _)) in components.iter().enumerate() {
                    let root = (x.1 * y.1 * z.1 * m.sigma_s * beta).sqrt();
                    for (o, v) in a.iter_mut().zip(sampler.single_at(p, kind, &mut sc)) {
                        *o = v * root;
                    }
                    batch.push(&a);
                }
            }
        }
        let mut out = vec![C64::default(); j * j];
        batch.drain_into(&mut out);
        out
    };
    // slices in parallel, added in a fixed order: the same bits on any number of threads
    use rayon::prelude::*;
    let mut total = vec![C64::default(); j * j];
    for group in nz.chunks(8) {
        let parts: Vec<Vec<C64>> = group.par_iter().map(slice).collect();
        for part in parts {
            for (t, p) in total.iter_mut().zip(part) {
                *t += p;
            }
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gauss–Legendre nodes and weights on `[a, b]`.
    fn gauss(a: f64, b: f64, n: usize) -> Vec<(f64, f64)> {
        let (x, w) = crate::math::gauss_legendre(n);
        x.iter()
            .zip(&w)
            .map(|(x, w)| (0.5 * (a + b) + 0.5 * (b - a) * x, 0.5 * (b - a) * w))
            .collect()
    }

    #[test]
    fn box_cells_match_brute_force_quadrature() {
        // four legs leaving through different faces, a phase across the box: the cell split
        // against composite Gauss–Legendre on the raw integrand (its kinks limit it to ~1e-5)
        let half = DVec3::new(1.0, 1.5, 0.75);
        let g = Geometry::boxed((half * 2.0).to_array());
        let legs = [
            -DVec3::new(0.3, 0.1, 1.0).normalize(),
            DVec3::new(0.7, -0.2, 0.6).normalize(),
            -DVec3::new(-0.2, 0.4, 1.0).normalize(),
            DVec3::new(0.1, 0.9, -0.3).normalize(),
        ];
        let q = DVec3::new(1.3, -0.7, 2.1);
        let sigma_t = 0.8;
        let exact = box_exit_integral(half, q, C64::new(sigma_t, 0.0), &legs);
        let panels = |lo: f64, hi: f64| -> Vec<(f64, f64)> {
            (0..24)
                .flat_map(|p| {
                    let (a, b) = (
                        lo + (hi - lo) * p as f64 / 24.0,
                        lo + (hi - lo) * (p + 1) as f64 / 24.0,
                    );
                    gauss(a, b, 6)
                })
                .collect()
        };
        let (nx, ny, nz) = (
            panels(-half.x, half.x),
            panels(-half.y, half.y),
            panels(-half.z, half.z),
        );
        let mut brute = C64::default();
        for &(x, wx) in &nx {
            for &(y, wy) in &ny {
                for &(z, wz) in &nz {
                    let p = DVec3::new(x, y, z);
                    let d: f64 = legs.iter().map(|&w| g.exit_distance(p, w)).sum();
                    brute +=
                        crate::math::cis(q.dot(p)) * ((-0.5 * sigma_t * d).exp() * wx * wy * wz);
                }
            }
        }
        assert!(
            (exact - brute).norm() < 1e-5 * brute.norm(),
            "{exact} vs {brute}"
        );
    }

    #[test]
    fn legs_parallel_to_a_face_up_to_round_off() {
        // a view at 90° from the light has cos 90° = 6.1e-17 along z, not 0: the same integral
        let half = DVec3::new(10.0, 10.0, 10.0);
        let light = DVec3::new(0.0, 0.0, 1.0);
        let exact = DVec3::new(1.0, 0.0, 0.0);
        let rounded = DVec3::new(90f64.to_radians().sin(), 0.0, 90f64.to_radians().cos());
        assert!(rounded.z != 0.0);
        let sigma_t = C64::new(0.1, 0.0);
        let q = DVec3::new(0.3, 0.0, -0.3);
        let a = box_exit_integral(half, q, sigma_t, &[-light, exact, -light, exact]);
        let b = box_exit_integral(half, q, sigma_t, &[-light, rounded, -light, rounded]);
        assert!((a - b).norm() < 1e-10 * a.norm(), "{a} vs {b}");
    }

    #[test]
    fn equal_and_nearly_equal_legs() {
        // an intensity's legs come in equal pairs; nearly equal ones must not leave slivers
        let half = DVec3::new(1.0, 1.5, 0.75);
        let (a, b) = (
            -DVec3::new(0.3, 0.1, 1.0).normalize(),
            DVec3::new(0.7, -0.2, 0.6).normalize(),
        );
        let tilt = DVec3::new(1e-9, -2e-9, 0.0);
        let sigma_t = C64::new(0.8, 0.0);
        let equal = box_exit_integral(half, DVec3::ZERO, sigma_t, &[a, b, a, b]);
        let near = box_exit_integral(
            half,
            DVec3::ZERO,
            sigma_t,
            &[a, b, (a + tilt).normalize(), (b - tilt).normalize()],
        );
        let doubled = box_exit_integral(half, DVec3::ZERO, sigma_t * 2.0, &[a, b]);
        assert!(
            (equal - doubled).norm() < 1e-12 * doubled.norm(),
            "{equal} vs {doubled}"
        );
        assert!(
            (near - doubled).norm() < 1e-6 * doubled.norm(),
            "{near} vs {doubled}"
        );
        assert!(doubled.re > 0.0);
    }

    #[test]
    fn slab_depth_integral_matches_quadrature() {
        let legs = [
            -DVec3::new(0.1, 0.0, 1.0).normalize(),
            DVec3::new(0.3, 0.1, 1.0).normalize(),
            -DVec3::new(0.0, 0.2, 1.0).normalize(),
            DVec3::new(0.2, 0.3, -1.0).normalize(),
        ];
        let (h, sigma_t, q) = (2.0, 0.6, DVec3::new(0.0, 0.0, 1.7));
        let exact = slab_integral(h, 1.0, q, sigma_t, &legs);
        let g = Geometry::slab(2.0 * h, 1.0);
        let mut quad = C64::default();
        for (z, w) in gauss(-h, h, 40) {
            let p = DVec3::new(0.0, 0.0, z);
            let d: f64 = legs.iter().map(|&l| g.exit_distance(p, l)).sum();
            quad += crate::math::cis(q.z * z) * ((-0.5 * sigma_t * d).exp() * w);
        }
        assert!(
            (exact - quad).norm() < 1e-12 * quad.norm(),
            "{exact} vs {quad}"
        );
    }
}
