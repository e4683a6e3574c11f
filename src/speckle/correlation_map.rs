//! Near-field correlation maps `C(Δ, τ)` (paper 000, Eq. 48): the covariance of the field under a
//! light focused at `i` seen by a sensor focused at `i + τ` with the field under a light at `i + Δ`
//! seen at `i + τ + Δ`, over a grid of `τ` and a list of `Δ`, all in the plane across the light's
//! axis. The memory effect makes `C` large near `τ = 0` for small `Δ`.
//!
//! Only the products the map needs are accumulated, `a_{0,τ} ā_{Δ,τ+Δ}` per event, so the cost is
//! linear in the number of map entries (a full covariance of the same fields would be quadratic).

use crate::math::{C64, Rng, orthonormal_basis};
use crate::mc::Estimator;
use crate::speckle::endpoint::{Lens, Terminal};
use crate::speckle::paths::{EventSink, PathScratch, SubpathSampler};
use crate::speckle::{Light, Scene, View};
use glam::DVec3;

/// Light 0 and view 0 of `base` as the lenses a scan of `command` shifts and tilts; both must be
/// focused (`light_hint`, `view_hint` say where, in the error).
pub fn focused_templates(
    base: &Scene,
    command: &str,
    light_hint: &str,
    view_hint: &str,
) -> crate::Result<(Lens, Lens)> {
    let light = match base.lights.first().map(|&l| Terminal::from(l)) {
        Some(Terminal::Lens(l)) => l,
        _ => return Err(format!("{command}: light[0] must be focused{light_hint}").into()),
    };
    let view = match base.views.first().map(|&v| Terminal::from(v)) {
        Some(Terminal::Lens(v)) => v,
        _ => return Err(format!("{command}: view[0] must be focused{view_hint}").into()),
    };
    Ok((light, view))
}

/// The lights and views of a map: light `k` is focused at `i + Δ_k` (`Δ_0 = 0`), view `k·T + p`
/// at `v + τ_p + Δ_k`, with `i`, `v` the foci of light 0 and view 0 of the base scene.
#[derive(Clone, Debug)]
pub struct CorrelationMap {
    pub scene: Scene,
    /// Shifts `Δ` in the focal plane (`Δ_0 = 0` first), as 3-vectors.
    pub deltas: Vec<DVec3>,
    /// The `τ` grid, row-major, `pixels[0] × pixels[1]`.
    pub taus: Vec<DVec3>,
    pub pixels: [usize; 2],
}

impl CorrelationMap {
    /// From light 0 and view 0 of `base` (both focused), 2-D shifts `deltas` along the frame across
    /// the light's axis, and a square `τ` grid `tau_width` wide.
    pub fn new(
        base: &Scene,
        deltas: &[[f64; 2]],
        tau_width: f64,
        pixels: [usize; 2],
    ) -> crate::Result<Self> {
        let (light, view) = focused_templates(base, "correlation-map", "", "")?;
        let (i, axis, gamma) = (light.focus, light.axis, light.gamma);
        let (v, view_axis, view_gamma) = (view.focus, view.axis, view.gamma);
        let (ex, ey) = orthonormal_basis(axis);
        let mut shifts = vec![DVec3::ZERO];
        shifts.extend(deltas.iter().map(|d| ex * d[0] + ey * d[1]));
        let [nx, ny] = pixels;
        let step = if nx.max(ny) > 1 {
            tau_width / (nx.max(ny) - 1) as f64
        } else {
            0.0
        };
        let taus: Vec<DVec3> = (0..ny)
            .flat_map(|y| {
                (0..nx).map(move |x| {
                    ex * ((x as f64 - 0.5 * (nx as f64 - 1.0)) * step)
                        + ey * ((y as f64 - 0.5 * (ny as f64 - 1.0)) * step)
                })
            })
            .collect();
        let lights = shifts
            .iter()
            .map(|d| Light::Focused {
                focus: i + *d,
                axis,
                gamma,
            })
            .collect();
        let views = shifts
            .iter()
            .flat_map(|d| {
                taus.iter().map(move |t| View::Focused {
                    focus: v + *t + *d,
                    axis: view_axis,
                    gamma: view_gamma,
                })
            })
            .collect();
        Ok(CorrelationMap {
            scene: Scene {
                lights,
                views,
                ..base.clone()
            },
            deltas: shifts,
            taus,
            pixels,
        })
    }

    /// The (light, view) pairs: `(k, k·T + p)`, index `k·T + p`.
    pub fn pairs(&self) -> Vec<(usize, usize)> {
        let t = self.taus.len();
        (0..self.deltas.len())
            .flat_map(|k| (0..t).map(move |p| (k, k * t + p)))
            .collect()
    }
}

/// Accumulates `C(Δ_k, τ_p)` (outputs `k·T + p`) and the intensities `I(Δ_k, τ_p)` of the shifted
/// pairs (outputs `K·T + k·T + p`, real).
pub struct MapEstimator<'a> {
    sampler: SubpathSampler<'a>,
    deltas: usize,
    taus: usize,
}

impl<'a> MapEstimator<'a> {
    pub fn new(map: &'a CorrelationMap, reversed: bool) -> crate::Result<Self> {
        Ok(MapEstimator {
            sampler: SubpathSampler::new(&map.scene, map.pairs(), reversed)?,
            deltas: map.deltas.len(),
            taus: map.taus.len(),
        })
    }
}

struct Products<'o> {
    out: &'o mut [C64],
    deltas: usize,
    taus: usize,
}

impl EventSink for Products<'_> {
    #[inline]
    fn event(&mut self, _multiple: bool, a: &[C64], _: &mut Rng) {
        let (k, t) = (self.deltas, self.taus);
        let (c, i) = self.out.split_at_mut(k * t);
        for d in 0..k {
            for p in 0..t {
                let shifted = a[d * t + p];
                c[d * t + p] += a[p] * shifted.conj();
                i[d * t + p] += shifted.norm_sqr();
            }
        }
    }

    #[inline]
    fn event_pair(&mut self, _multiple: bool, a: &[C64], b: &[C64], _: &mut Rng) {
        let (k, t) = (self.deltas, self.taus);
        let (c, i) = self.out.split_at_mut(k * t);
        for d in 0..k {
            for p in 0..t {
                let (sa, sb) = (a[d * t + p], b[d * t + p]);
                c[d * t + p] += 0.5 * (a[p] * sb.conj() + b[p] * sa.conj());
                i[d * t + p] += (sa * sb.conj()).re;
            }
        }
    }
}

impl Estimator for MapEstimator<'_> {
    type Scratch = PathScratch;

    fn event_cost(&self) -> f64 {
        // the connections, then every output's product
        self.sampler.event_cost() + crate::mc::Estimator::outputs(self) as f64
    }

    fn outputs(&self) -> usize {
        2 * self.deltas * self.taus
    }

    fn scratch(&self) -> PathScratch {
        self.sampler.scratch()
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut PathScratch, out: &mut [C64]) {
        let mut sink = Products {
            out,
            deltas: self.deltas,
            taus: self.taus,
        };
        for _ in 0..paths {
            self.sampler.trace(rng, sc, &mut sink);
        }
    }
}
