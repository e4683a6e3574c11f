//! Speckle fields by Monte Carlo (paper 001, Algorithm 2): every sampled subpath updates all
//! light×view pairs at once with a random phase, so fields under nearby lights are correlated copies
//! (memory effect) and the covariance of many renderings converges to Algorithm 1's (Eq. 37).

use crate::math::{C64, Rng, cis, uniform};
use crate::mc::Estimator;
use crate::speckle::Scene;
use crate::speckle::paths::{EventSink, PathScratch, SubpathSampler};

/// Zero-mean speckle field over (light, view) pairs; a chunk adds `Σ z_e a_e` over its events.
/// A rendering from `N` subpaths is `m + (Σ z a) / √N`.
pub struct FieldSampler<'a> {
    sampler: SubpathSampler<'a>,
}

impl<'a> FieldSampler<'a> {
    pub fn new(
        scene: &'a Scene,
        pairs: Vec<(usize, usize)>,
        reversed: bool,
    ) -> crate::Result<Self> {
        let sampler = SubpathSampler::new(scene, pairs, reversed)?;
        if sampler.draws_apertures() {
            return Err(crate::Error::input(
                "render.aperture = \"monte_carlo\" estimates second moments (covariance, correlation-map, tilt-shift), not speckle fields: a field per path needs one aperture integral per vertex; use aperture = \"quadrature\" or \"vmf\"",
            ));
        }
        Ok(FieldSampler { sampler })
    }
}

/// Adds each event with a uniformly random phase.
struct PhasedSum<'o> {
    out: &'o mut [C64],
}

impl EventSink for PhasedSum<'_> {
    #[inline]
    fn event(&mut self, _multiple: bool, a: &[C64], rng: &mut Rng) {
        let z = cis(2.0 * std::f64::consts::PI * uniform(rng));
        for (u, x) in self.out.iter_mut().zip(a) {
            *u += z * x;
        }
    }

    /// Never called: [`FieldSampler::new`] refuses Monte Carlo apertures, whose two estimates
    /// per event give second moments but no single field.
    fn event_pair(&mut self, multiple: bool, a: &[C64], _: &[C64], rng: &mut Rng) {
        self.event(multiple, a, rng);
    }
}

impl Estimator for FieldSampler<'_> {
    type Scratch = PathScratch;

    fn event_cost(&self) -> f64 {
        self.sampler.event_cost()
    }

    fn outputs(&self) -> usize {
        self.sampler.pairs().len()
    }

    fn scratch(&self) -> PathScratch {
        self.sampler.scratch()
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut PathScratch, out: &mut [C64]) {
        let mut sink = PhasedSum { out };
        for _ in 0..paths {
            self.sampler.trace(rng, sc, &mut sink);
        }
    }
}
