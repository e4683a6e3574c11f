//! The single-scattering reading of a phase function from speckle correlations (paper 004,
//! Claim 1, Eq. 3): for a slab, the covariance between illuminations `i1, i2` and views `v1, v2`
//! with `i2 − i1 = v2 − v1` (lateral components) is, if only single scattering correlates,
//! `C = σ_s ρ(θ) ∫_0^L e^{−σ_t (z a + (L − z) b)} e^{i k q z} dz` — so `ρ(θ) = |C| / |∫…|`.
//!
//! We evaluate the integral exactly for each entry's directions (`a, b` the mean inverse direction
//! cosines of the two incoming and two outgoing legs, `q` the residual axial phase), so the only
//! approximation left is the one the paper makes: that multiple scattering does not correlate. At
//! small illumination displacements `Δ` it does, and the reading is biased; that bias is what a
//! full fit removes.

use super::target::{Measured, Target};
use crate::medium::Geometry;
use crate::speckle::{Light, Scene, View};

/// One reading: the phase function at scattering angle `angle_deg` from an entry whose
/// illuminations are `delta_deg` apart.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    pub delta_deg: f64,
    pub angle_deg: f64,
    pub rho: f64,
    /// Standard error of `rho` from the target's (NaN without target errors).
    pub stderr: f64,
}

/// Readings for every entry of an entries target on a slab lit by plane waves and seen by
/// far-field views (`None` for other scenes or targets). Entries with `i1 = i2` (`Δ = 0`) read
/// the intensity, which the paper shows to be the most biased.
pub fn single_scattering_readings(scene: &Scene, target: &Target) -> Option<Vec<Reading>> {
    let Target::Entries { entries, stderr } = target else {
        return None;
    };
    let Geometry::Slab { half_thickness, .. } = scene.medium.geometry else {
        return None;
    };
    let thickness = 2.0 * half_thickness;
    let m = &scene.medium;
    let mut out = Vec::with_capacity(entries.len());
    for (i, e) in entries.iter().enumerate() {
        let (
            Light::PlaneWave { direction: d1 },
            Light::PlaneWave { direction: d2 },
            View::FarField { direction: v1 },
            View::FarField { direction: v2 },
        ) = (
            scene.lights[e.light[0]],
            scene.lights[e.light[1]],
            scene.views[e.views[0][0]],
            scene.views[e.views[0][1]],
        )
        else {
            return None;
        };
        // illuminated from the face the light enters; a view leaves through either face
        let depth = |w: f64| 1.0 / w.abs().max(1e-9);
        let a = 0.5 * (depth(d1.z) + depth(d2.z));
        // transmitted light leaves through the far face (the remaining depth L − z); reflected
        // light leaves through the entrance face (depth z), which adds to the entrance rate
        let transmitted = v1.z * d1.z > 0.0;
        let b = 0.5 * (depth(v1.z) + depth(v2.z));
        let q = scene.k * ((d1.z - v1.z) - (d2.z - v2.z));
        let (rate_z, rate_rest) = if transmitted {
            (m.sigma_t() * (a - b), m.sigma_t() * b * thickness)
        } else {
            (m.sigma_t() * (a + b), 0.0)
        };
        // ∫_0^L e^{−rate_z z + i q z} dz (times e^{−rate_rest})
        let s = num_complex::Complex64::new(-rate_z, q);
        let integral = if s.norm() * thickness < 1e-8 {
            num_complex::Complex64::new(thickness, 0.0)
        } else {
            ((s * thickness).exp() - 1.0) / s
        } * (-rate_rest).exp();
        let single = m.sigma_s * integral.norm();
        let (c, sd) = match e.value {
            Measured::Field(z) => (z.norm(), stderr.as_ref().map_or(f64::NAN, |s| s[i])),
            // a normalised correlation has no scale to read ρ against
            Measured::Normalised(_) => return None,
            Measured::Intensity(x) => {
                let c = x.max(0.0).sqrt();
                // d sqrt(x) = dx / (2 sqrt x)
                let sd = stderr
                    .as_ref()
                    .map_or(f64::NAN, |s| s[i] / (2.0 * c.max(1e-300)));
                (c, sd)
            }
        };
        out.push(Reading {
            delta_deg: d1.dot(d2).clamp(-1.0, 1.0).acos().to_degrees(),
            angle_deg: d1.dot(v1).clamp(-1.0, 1.0).acos().to_degrees(),
            rho: c / single,
            stderr: sd / single,
        });
    }
    Some(out)
}
