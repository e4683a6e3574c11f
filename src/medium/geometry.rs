//! Medium geometry: an axis-aligned box centred at the origin, or a slab `|z| ≤ L/2` unbounded in x, y.

use glam::DVec3;

/// The region filled by the scattering medium (homogeneous inside, vacuum outside; no interfaces).
#[derive(Clone, Debug, PartialEq)]
pub enum Geometry {
    /// Box with full side lengths `size`, centred at the origin.
    Box { half: DVec3 },
    /// Slab of thickness `2·half_thickness` normal to z, infinite in x and y. Quantities are per unit
    /// illuminated area; first vertices are drawn over a lateral `window` (see [`Geometry::sample_volume`]).
    Slab { half_thickness: f64, window: f64 },
}

impl Geometry {
    pub fn boxed(size: [f64; 3]) -> Self {
        Geometry::Box {
            half: DVec3::from_array(size) * 0.5,
        }
    }

    pub fn slab(thickness: f64, window: f64) -> Self {
        Geometry::Slab {
            half_thickness: 0.5 * thickness,
            window,
        }
    }

    /// Whether `x` is inside (closed set).
    #[inline]
    pub fn contains(&self, x: DVec3) -> bool {
        match self {
            Geometry::Box { half } => x.abs().cmple(*half).all(),
            Geometry::Slab { half_thickness, .. } => x.z.abs() <= *half_thickness,
        }
    }

    /// Distance from `x` (inside) along unit `w` to the boundary; `f64::INFINITY` if it never leaves.
    #[inline]
    pub fn exit_distance(&self, x: DVec3, w: DVec3) -> f64 {
        #[inline]
        fn axis(x: f64, w: f64, h: f64) -> f64 {
            if w > 0.0 {
                ((h - x) / w).max(0.0)
            } else if w < 0.0 {
                ((-h - x) / w).max(0.0)
            } else {
                f64::INFINITY
            }
        }
        match self {
            Geometry::Box { half } => axis(x.x, w.x, half.x)
                .min(axis(x.y, w.y, half.y))
                .min(axis(x.z, w.z, half.z)),
            Geometry::Slab { half_thickness, .. } => axis(x.z, w.z, *half_thickness),
        }
    }

    /// Length of the part of the segment from `x` (inside) to `p` that lies inside (convexity).
    #[inline]
    pub fn inside_length(&self, x: DVec3, p: DVec3) -> f64 {
        let d = p - x;
        let r = d.length();
        if r == 0.0 {
            return 0.0;
        }
        self.exit_distance(x, d / r).min(r)
    }

    /// Entry and exit parameters `(t0, t1)` of the ray `o + t w` (any origin), if it crosses the medium.
    pub fn ray_interval(&self, o: DVec3, w: DVec3) -> Option<(f64, f64)> {
        let (lo, hi) = match self {
            Geometry::Box { half } => (-*half, *half),
            Geometry::Slab {
                half_thickness: h, ..
            } => (
                DVec3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, -h),
                DVec3::new(f64::INFINITY, f64::INFINITY, *h),
            ),
        };
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            if w[a] == 0.0 {
                if o[a] < lo[a] || o[a] > hi[a] {
                    return None;
                }
                continue;
            }
            let (ta, tb) = ((lo[a] - o[a]) / w[a], (hi[a] - o[a]) / w[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// Volume over which first vertices are drawn: the box, or the slab's `window × window` patch.
    pub fn sampling_volume(&self) -> f64 {
        match self {
            Geometry::Box { half } => 8.0 * half.x * half.y * half.z,
            Geometry::Slab {
                half_thickness,
                window,
            } => 2.0 * half_thickness * window * window,
        }
    }

    /// Area that results are divided by: 1 for a box (absolute far-field values), the lateral window
    /// for a slab (values per unit illuminated area).
    pub fn normalising_area(&self) -> f64 {
        match self {
            Geometry::Box { .. } => 1.0,
            Geometry::Slab { window, .. } => window * window,
        }
    }

    /// Whether `x` lies in the region [`Geometry::sample_volume`] draws from (the box, or the
    /// slab's window).
    #[inline]
    pub fn in_sampling_volume(&self, x: DVec3) -> bool {
        match self {
            Geometry::Box { half } => x.abs().cmple(*half).all(),
            Geometry::Slab {
                half_thickness,
                window,
            } => {
                x.z.abs() <= *half_thickness
                    && x.x.abs() <= 0.5 * window
                    && x.y.abs() <= 0.5 * window
            }
        }
    }

    /// Uniform point in the sampling volume from three uniform numbers.
    #[inline]
    pub fn sample_volume(&self, u: [f64; 3]) -> DVec3 {
        let c = DVec3::from_array(u) * 2.0 - DVec3::ONE;
        match self {
            Geometry::Box { half } => c * *half,
            Geometry::Slab {
                half_thickness,
                window,
            } => DVec3::new(0.5 * window * c.x, 0.5 * window * c.y, half_thickness * c.z),
        }
    }

    /// The smallest side (box) or the thickness (slab): the distance that decides how long light
    /// stays inside.
    pub fn smallest_extent(&self) -> f64 {
        match self {
            Geometry::Box { half } => 2.0 * half.min_element(),
            Geometry::Slab { half_thickness, .. } => 2.0 * half_thickness,
        }
    }

    /// Radius of a sphere about the origin containing the medium (boxes only).
    pub fn bounding_radius(&self) -> f64 {
        match self {
            Geometry::Box { half } => half.length(),
            Geometry::Slab { .. } => f64::INFINITY,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_distance_box() {
        let g = Geometry::boxed([2.0, 4.0, 6.0]);
        assert_eq!(g.exit_distance(DVec3::ZERO, DVec3::X), 1.0);
        assert_eq!(g.exit_distance(DVec3::ZERO, -DVec3::Z), 3.0);
        let w = DVec3::new(1.0, 1.0, 0.0).normalize();
        assert!((g.exit_distance(DVec3::ZERO, w) - 2f64.sqrt()).abs() < 1e-12);
        assert!((g.inside_length(DVec3::ZERO, DVec3::new(0.5, 0.0, 0.0)) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn slab_is_unbounded_laterally() {
        let g = Geometry::slab(2.0, 1.0);
        assert_eq!(g.exit_distance(DVec3::ZERO, DVec3::X), f64::INFINITY);
        assert!((g.exit_distance(DVec3::ZERO, DVec3::new(0.6, 0.0, 0.8)) - 1.25).abs() < 1e-12);
        let (t0, t1) = g
            .ray_interval(DVec3::new(0.0, 0.0, -5.0), DVec3::Z)
            .unwrap();
        assert!((t0 - 4.0).abs() < 1e-12 && (t1 - 6.0).abs() < 1e-12);
    }
}
