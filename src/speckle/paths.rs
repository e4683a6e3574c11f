//! Subpath sampling shared by the covariance and field estimators (paper 001, Sec. 5.1).
//!
//! The first vertex `x1` is drawn with density `σ_s / V` (Eq. 35), the first direction uniformly, the
//! rest by volume path tracing. Every vertex `xB` yields an event: the vector
//! `a_j = A_l B'_v + B_l A'_v` over (light, view) pairs (Eq. 38; forward-only drops the second term),
//! scaled by the square root of its Monte Carlo weight. With `q(x) = f(x) / (4π V)` and the reversed
//! subpath equally likely, the weight is `4π V albedo^{B-1} / 2` for `B ≥ 2` (`4π V albedo^{B-1}`
//! forward-only), and `V` for the single-scattering event `B = 1` (Algorithm 1).

use crate::math::{C64, INV_4PI, Rng, uniform, uniform_sphere};
use crate::speckle::Scene;
use crate::speckle::endpoint::{Connection, Endpoint};
use glam::DVec3;

/// Receives the events of a subpath.
pub trait EventSink {
    /// `a` is the weighted event vector over pairs; `multiple` is false for the `B = 1` event.
    fn event(&mut self, multiple: bool, a: &[C64], rng: &mut Rng);
}

/// Samples subpaths of a scene for a list of (light, view) pairs.
pub struct SubpathSampler<'a> {
    scene: &'a Scene,
    lights: Vec<Endpoint>,
    views: Vec<Endpoint>,
    pairs: Vec<(usize, usize)>,
    reversed: bool,
}

/// Per-thread working memory of a [`SubpathSampler`].
pub struct PathScratch {
    first_l: Vec<Connection>,
    first_v: Vec<Connection>,
    amp_first_l: Vec<C64>,
    amp_first_v: Vec<C64>,
    amp_last_l: Vec<C64>,
    amp_last_v: Vec<C64>,
    a: Vec<C64>,
}

impl<'a> SubpathSampler<'a> {
    /// Errors if the scene has endpoints the Monte Carlo estimators do not support (focused).
    pub fn new(
        scene: &'a Scene,
        pairs: Vec<(usize, usize)>,
        reversed: bool,
    ) -> crate::Result<Self> {
        let lights = scene
            .lights
            .iter()
            .map(|&l| Endpoint::try_from(l))
            .collect::<Result<_, _>>()?;
        let views = scene
            .views
            .iter()
            .map(|&v| Endpoint::try_from(v))
            .collect::<Result<_, _>>()?;
        Ok(SubpathSampler {
            scene,
            lights,
            views,
            pairs,
            reversed,
        })
    }

    /// All light×view pairs, `j = l·V + v`.
    pub fn all_pairs(scene: &Scene) -> Vec<(usize, usize)> {
        (0..scene.lights.len())
            .flat_map(|l| (0..scene.views.len()).map(move |v| (l, v)))
            .collect()
    }

    pub fn pairs(&self) -> &[(usize, usize)] {
        &self.pairs
    }

    pub fn scratch(&self) -> PathScratch {
        let (nl, nv) = (self.lights.len(), self.views.len());
        PathScratch {
            first_l: vec![Connection::default(); nl],
            first_v: vec![Connection::default(); nv],
            amp_first_l: vec![C64::default(); nl],
            amp_first_v: vec![C64::default(); nv],
            amp_last_l: vec![C64::default(); nl],
            amp_last_v: vec![C64::default(); nv],
            a: vec![C64::default(); self.pairs.len()],
        }
    }

    /// Trace one subpath and report its events to `sink`.
    pub fn trace<S: EventSink>(&self, rng: &mut Rng, sc: &mut PathScratch, sink: &mut S) {
        let s = self.scene;
        let m = &s.medium;
        let geo = &m.geometry;
        let sigma_t = m.sigma_t();
        let albedo = m.albedo();
        let volume = m.sigma_s * geo.sampling_volume() / geo.normalising_area();

        let x1 = geo.sample_volume([uniform(rng), uniform(rng), uniform(rng)]);
        let phase1 = m.scattering.phase(m.scattering.pick(|| uniform(rng)));
        for (e, c) in self.lights.iter().zip(sc.first_l.iter_mut()) {
            *c = e.connect(x1, m, s.k);
        }
        for (e, c) in self.views.iter().zip(sc.first_v.iter_mut()) {
            *c = e.connect(x1, m, s.k);
        }

        // B = 1: a_j = sqrt(V) υ(i→x1) υ(i→x1→v).
        let root = volume.sqrt();
        for (a, &(l, v)) in sc.a.iter_mut().zip(&self.pairs) {
            let (cl, cv) = (&sc.first_l[l], &sc.first_v[v]);
            *a = cl.prop * cv.prop * phase1.amplitude(-cl.dir.dot(cv.dir)) * root;
        }
        sink.event(false, &sc.a, rng);

        // B ≥ 2: uniform first direction, then volume path tracing with next-event connections.
        let w1 = uniform_sphere(uniform(rng), uniform(rng));
        let d = -(1.0 - uniform(rng)).ln() / sigma_t;
        if d >= geo.exit_distance(x1, w1) {
            return;
        }
        for (c, a) in sc.first_l.iter().zip(sc.amp_first_l.iter_mut()) {
            *a = c.prop * phase1.amplitude(-w1.dot(c.dir));
        }
        for (c, a) in sc.first_v.iter().zip(sc.amp_first_v.iter_mut()) {
            *a = c.prop * phase1.amplitude(-w1.dot(c.dir));
        }
        let scale = volume / INV_4PI * if self.reversed { 0.5 } else { 1.0 };
        let mut x = x1 + w1 * d;
        let mut w_in = w1;
        let mut throughput = albedo;
        loop {
            let phase = m.scattering.phase(m.scattering.pick(|| uniform(rng)));
            self.connect_all(x, w_in, phase, &mut sc.amp_last_l, &mut sc.amp_last_v);
            let root = (scale * throughput).sqrt();
            for (a, &(l, v)) in sc.a.iter_mut().zip(&self.pairs) {
                let mut z = sc.amp_first_l[l] * sc.amp_last_v[v];
                if self.reversed {
                    z += sc.amp_last_l[l] * sc.amp_first_v[v];
                }
                *a = z * root;
            }
            sink.event(true, &sc.a, rng);

            let w_out = phase.sample(w_in, uniform(rng), uniform(rng));
            let d = -(1.0 - uniform(rng)).ln() / sigma_t;
            if d >= geo.exit_distance(x, w_out) {
                return;
            }
            x += w_out * d;
            w_in = w_out;
            throughput *= albedo;
            if throughput < 1e-3 {
                // Russian roulette keeps absorbing media cheap without bias.
                if uniform(rng) >= 0.1 {
                    return;
                }
                throughput *= 10.0;
            }
        }
    }

    /// `B_l = τ ξ s(w_in · dir)` to every light and view from vertex `x` reached along `w_in`.
    #[inline]
    fn connect_all(
        &self,
        x: DVec3,
        w_in: DVec3,
        phase: &crate::medium::PhaseFunction,
        al: &mut [C64],
        av: &mut [C64],
    ) {
        let s = self.scene;
        for (e, a) in self.lights.iter().zip(al.iter_mut()) {
            let c = e.connect(x, &s.medium, s.k);
            *a = c.prop * phase.amplitude(w_in.dot(c.dir));
        }
        for (e, a) in self.views.iter().zip(av.iter_mut()) {
            let c = e.connect(x, &s.medium, s.k);
            *a = c.prop * phase.amplitude(w_in.dot(c.dir));
        }
    }
}
