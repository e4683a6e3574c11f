//! The memory effect (paper 001, Sec. 6.2, Eq. 39): the intensity correlation of speckle patterns
//! when the light and the view are tilted together, `|C(θ)|² / (C(0,0) C(θ,θ))`, from a covariance
//! run over the tilted pairs, with delta-method standard errors over the run's chunks.

use crate::math::rotate;
use crate::mc::{Block, Estimate, Plan};
use crate::medium::Geometry;
use crate::speckle::covariance::Order;
use crate::speckle::{Light, Scene, View};
use glam::DVec3;

/// A memory-effect scan: the scene whose light `t` and view `t` are light 0 and view 0 of the base
/// scene tilted by `angles_deg[t]` about `axis` (angle 0 first), and the estimator pairs `(t, t)`.
#[derive(Clone, Debug)]
pub struct MemoryScan {
    pub scene: Scene,
    /// Tilt angles, 0 first, then the requested ones.
    pub angles_deg: Vec<f64>,
}

impl MemoryScan {
    /// Tilt light 0 (a plane wave) and view 0 (far field) of `base` together about `axis`.
    pub fn new(base: &Scene, axis: DVec3, angles_deg: &[f64]) -> crate::Result<Self> {
        let Some(&Light::PlaneWave { direction: d }) = base.lights.first() else {
            return Err("memory-effect: light[0] must be a plane_wave".into());
        };
        let Some(&View::FarField { direction: v }) = base.views.first() else {
            return Err("memory-effect: view[0] must be far_field".into());
        };
        let axis = axis.normalize();
        let mut angles = vec![0.0];
        angles.extend(angles_deg);
        let lights = angles
            .iter()
            .map(|a| Light::PlaneWave {
                direction: rotate(d, axis, a.to_radians()),
            })
            .collect();
        let views = angles
            .iter()
            .map(|a| View::FarField {
                direction: rotate(v, axis, a.to_radians()),
            })
            .collect();
        Ok(MemoryScan {
            scene: Scene::new(base.wavelength, base.medium.clone(), lights, views),
            angles_deg: angles,
        })
    }

    /// The (light, view) pairs of the covariance estimator: `(t, t)` for every angle.
    pub fn pairs(&self) -> Vec<(usize, usize)> {
        (0..self.angles_deg.len()).map(|t| (t, t)).collect()
    }

    /// Outputs whose per-chunk means the run keeps for the curve's errors: `C00`, `Ctt`, then `C0t`
    /// (indices into the covariance estimator's outputs).
    pub fn kept_outputs(&self) -> Vec<usize> {
        let n = self.angles_deg.len();
        let mut keep: Vec<usize> = (0..n).map(|t| Order::Total.index(n, t, t)).collect();
        keep.extend((1..n).map(|t| Order::Total.index(n, 0, t)));
        keep
    }

    /// The curve from the run's root block (merged over every chunk, with [`Self::kept_outputs`]).
    pub fn curve(&self, root: &Block, plan: &Plan) -> MemoryCurve {
        let n = self.angles_deg.len();
        let e = Estimate::from_block(root, plan);
        let keep = self.kept_outputs();
        let chunks = root.len as usize;
        let nk = keep.len();
        let thickness = thickness(&self.scene);
        let mut curve = MemoryCurve {
            angles_deg: vec![],
            correlation: vec![],
            stderr: vec![],
            field_correlation: vec![],
            diffusion: vec![],
            kl: self.scene.k * thickness,
            thickness,
        };
        for (t, angle) in self.angles_deg.iter().enumerate().skip(1) {
            let (ia, ib, ic) = (0, t, n - 1 + t);
            let a = e.mean[keep[ia]].re;
            let b = e.mean[keep[ib]].re;
            let c = e.mean[keep[ic]];
            let r = c.norm_sqr() / (a * b);
            // delta method over chunk means
            let (ga, gb, gc) = (-r / a, -r / b, c * (2.0 / (a * b)));
            let mut var = 0.0;
            for k in 0..chunks {
                let row = &root.kept[k * nk..(k + 1) * nk];
                let dc = row[ic] - c;
                let lin =
                    ga * (row[ia].re - a) + gb * (row[ib].re - b) + gc.re * dc.re + gc.im * dc.im;
                var += lin * lin;
            }
            var /= (chunks as f64 - 1.0) * chunks as f64;
            curve.angles_deg.push(*angle);
            curve.correlation.push(r);
            curve.stderr.push(var.sqrt());
            curve.field_correlation.push(r.sqrt());
            curve
                .diffusion
                .push(diffusion_correlation(curve.kl, angle.to_radians()));
        }
        curve
    }
}

/// Memory-effect curve: intensity correlation `|C0t|² / (C00 Ctt)` with delta-method errors.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryCurve {
    pub angles_deg: Vec<f64>,
    pub correlation: Vec<f64>,
    pub stderr: Vec<f64>,
    pub field_correlation: Vec<f64>,
    /// `((kθL)/sinh(kθL))²` (paper 001, Eq. 39).
    pub diffusion: Vec<f64>,
    /// `k L` of Eq. 39.
    pub kl: f64,
    /// `L` of Eq. 39: the slab thickness, or the box chord along light 0.
    pub thickness: f64,
}

/// The diffusion prediction `((kθL)/sinh(kθL))²` of paper 001, Eq. 39 (`θ` in radians).
pub fn diffusion_correlation(kl: f64, theta: f64) -> f64 {
    let x = kl * theta.abs();
    if x < 1e-8 {
        1.0
    } else {
        (x / x.sinh()).powi(2)
    }
}

/// Thickness used in Eq. 39: slab thickness, or the chord of a box along light 0.
pub fn thickness(scene: &Scene) -> f64 {
    match (&scene.medium.geometry, scene.lights.first()) {
        (Geometry::Slab { half_thickness, .. }, _) => 2.0 * half_thickness,
        (g, Some(Light::PlaneWave { direction })) => 2.0 * g.exit_distance(DVec3::ZERO, *direction),
        _ => f64::NAN,
    }
}
