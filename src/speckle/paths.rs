//! Subpath sampling shared by the covariance and field estimators (paper 001, Sec. 5.1).
//!
//! The first vertex `x1` is drawn with density `σ_s / V` (Eq. 35), the first direction uniformly, the
//! rest by volume path tracing; with focused lights the first vertex and direction are importance
//! sampled from their beams instead (`first_vertex.rs`, paper 000 Sec. 6) and the weights below
//! carry `1/p(x1)` and `1/p(w1)` in place of `V` and `4π`. Every vertex `xB` yields an event: the vector
//! `a_j = A_l B'_v + B_l A'_v` over (light, view) pairs (Eq. 38; forward-only drops the second term),
//! scaled by the square root of its Monte Carlo weight. With `q(x) = f(x) / (4π V)` and the reversed
//! subpath equally likely, the weight is `4π V albedo^{B-1} / 2` for `B ≥ 2` (`4π V albedo^{B-1}`
//! forward-only), and `V` for the single-scattering event `B = 1` (Algorithm 1).

use crate::math::{C64, Rng, uniform};
use crate::medium::PhaseFunction;
use crate::medium::lobes::Lobes;
use crate::speckle::Scene;
use crate::speckle::aperture_quadrature::{
    ApertureGrid, ApertureModel, Attenuation, Quadrature, lens_pair, lens_pair_drawn, upsilon,
    weighted_aperture,
};
use crate::speckle::endpoint::{
    ConvolvedLobe, Lens, PairBatch, Seen, SphereBatch, Terminal, convolve_lobe, lens_pair_from,
    lens_pair_queue, log_aperture_mass,
};
use crate::speckle::first_vertex::FirstVertex;
use glam::DVec3;

/// The cost of connecting a vertex to one light or view, in output updates (a phase, an
/// attenuation and, for focused ends, a sphere integral).
pub const CONNECTION_COST: f64 = 100.0;

/// Throughput below which a subpath plays Russian roulette, and the chance it survives.
pub(crate) const ROULETTE_BELOW: f64 = 1e-3;
pub(crate) const ROULETTE_SURVIVAL: f64 = 0.1;

/// The order of magnitude of the mean number of scattering events on a subpath — the cost of one
/// path. A path started inside a medium of optical thickness `τ = σ_s d` (`d` the smallest extent)
/// diffuses out after about `1 + τ + τ²(1 − g)` events (`(τ(1 − g))²` transport steps of
/// `1/(1 − g)` events each); absorption and the Russian roulette end it after about
/// `(ln(1/t) + ln(1/s)/(1 − s)) / ln(1/a)` events (`t`, `s`: the roulette threshold and survival
/// chance, `a` the albedo), whichever is fewer. Used to refuse runs that cannot finish.
pub fn expected_events(medium: &crate::medium::Medium) -> f64 {
    let tau = medium.sigma_s * medium.geometry.smallest_extent();
    let g = medium.mean_cosine().clamp(-1.0, 1.0);
    let diffusive = 1.0 + tau + tau * tau * (1.0 - g);
    let a = medium.albedo();
    let absorbed = if a < 1.0 {
        let s = ROULETTE_SURVIVAL;
        ((1.0 / ROULETTE_BELOW).ln() + (1.0 / s).ln() / (1.0 - s)) / (1.0 / a).ln()
    } else {
        f64::INFINITY
    };
    1.0 + diffusive.min(absorbed)
}

/// Receives the events of a subpath.
pub trait EventSink {
    /// `a` is the weighted event vector over pairs; `multiple` is false for the `B = 1` event.
    fn event(&mut self, multiple: bool, a: &[C64], rng: &mut Rng);

    /// Two independent unbiased estimates `a`, `b` of the event vector (apertures by Monte Carlo
    /// directions): second moments take `(a bᴴ + b aᴴ)/2`, whose mean is the event's where that of
    /// `a aᴴ` is not. Sinks that need one vector per event (fields) are refused such scenes.
    fn event_pair(&mut self, multiple: bool, a: &[C64], b: &[C64], rng: &mut Rng);
}

/// Samples subpaths of a scene for a list of (light, view) pairs.
pub struct SubpathSampler<'a> {
    scene: &'a Scene,
    terminals: Terminals,
    /// The axis all focused views share, if they do (an image of foci): single scattering between
    /// two lenses then convolves each light's aperture once per vertex, not once per view.
    view_axis: Option<DVec3>,
    /// Most amplitude lobes of any particle type.
    max_lobes: usize,
    pairs: Vec<(usize, usize)>,
    reversed: bool,
}

/// The lights and views of a scene as the path samplers connect to them, with what focused ones
/// need: the vMF lobes of every particle type's amplitude (paper 000, Eq. 28) and the first-vertex
/// sampler of their beams. Shared by the covariance/field sampler and the gradient estimator.
pub struct Terminals {
    pub lights: Vec<Terminal>,
    pub views: Vec<Terminal>,
    /// Lobes per particle type (empty unless a terminal is focused).
    pub lobes: Vec<Lobes>,
    /// Draws first vertices and directions (from the focused lights' beams when there are any).
    pub first: FirstVertex,
    /// Quadrature grids of the focused terminals when the scene asks for the quadrature reference.
    pub quadrature: Option<Quadrature>,
    /// Directions drawn per focused terminal and vertex when the scene asks for Monte Carlo
    /// apertures.
    pub drawn: Option<usize>,
}

impl Terminals {
    /// Errors for focused terminals in a slab.
    pub fn new(scene: &Scene) -> crate::Result<Self> {
        let lights: Vec<Terminal> = scene.lights.iter().map(|&l| l.into()).collect();
        let views: Vec<Terminal> = scene.views.iter().map(|&v| v.into()).collect();
        let focused = lights.iter().chain(&views).any(Terminal::is_lens);
        if focused && matches!(scene.medium.geometry, crate::medium::Geometry::Slab { .. }) {
            // the vMF aperture's side lobes (amplitude e^{−γ} at 90°) are attenuated over 2h at
            // most by the closed forms' model, and fall off only as 1/distance across the slab, so
            // their share grows with the lateral extent without bound
            return Err(crate::Error::input(
                "focused lights and views need a bounded medium: use medium.box instead of medium.slab, a few defocused beam widths wide (the results converge with the box width for aperture_sigma ≤ 0.2)",
            ));
        }
        let lobes: Vec<Lobes> = scene
            .medium
            .scattering
            .components()
            .iter()
            .map(|(_, p)| {
                if focused {
                    Lobes::of(p)
                } else {
                    Lobes::default()
                }
            })
            .collect();
        let lens = |t: &Terminal| match t {
            Terminal::Lens(l) => Some(*l),
            Terminal::Ray(_) => None,
        };
        let light_lenses: Vec<Lens> = lights.iter().filter_map(lens).collect();
        let view_lenses: Vec<Lens> = views.iter().filter_map(lens).collect();
        let first = FirstVertex::new(
            scene.sampling,
            &light_lenses,
            &view_lenses,
            &scene.medium,
            &lobes[0],
            scene.k,
        );
        let quadrature = match scene.aperture {
            ApertureModel::Quadrature(attenuation) if focused => {
                let lens_l: Vec<_> = lights.iter().map(lens).collect();
                let lens_v: Vec<_> = views.iter().map(lens).collect();
                let sharpest = lobes
                    .iter()
                    .flat_map(|l| l.lobes.iter().map(|l| l.kappa.abs()))
                    .fold(0.0, f64::max);
                Some(Quadrature::new(
                    attenuation,
                    &lens_l,
                    &lens_v,
                    &scene.medium,
                    scene.k,
                    sharpest,
                ))
            }
            _ => None,
        };
        let drawn = match scene.aperture {
            ApertureModel::MonteCarlo(n) if focused => Some(n),
            _ => None,
        };
        Ok(Terminals {
            lights,
            views,
            lobes,
            first,
            quadrature,
            drawn,
        })
    }

    /// How apertures integrated over nodes attenuate their directions.
    fn attenuation(&self) -> Attenuation {
        self.quadrature
            .as_ref()
            .map_or(Attenuation::Exact, |q| q.attenuation)
    }

    /// Whether focused terminals are integrated over nodes (quadrature or drawn directions)
    /// rather than in closed form.
    fn by_nodes(&self) -> bool {
        self.quadrature.is_some() || self.drawn.is_some()
    }

    /// Whether any light or view is focused.
    pub fn focused(&self) -> bool {
        self.lights.iter().chain(&self.views).any(Terminal::is_lens)
    }
}

/// Per-thread working memory of a [`SubpathSampler`].
pub struct PathScratch {
    first_l: Vec<Seen>,
    first_v: Vec<Seen>,
    proposal: Vec<(f64, DVec3, f64)>,
    convolved: Vec<ConvolvedLobe>,
    view_bound: Vec<f64>,
    /// Working memory of the connections at the current vertex.
    here: Here,
    /// The event vector and what it is built of, per independent estimate: two with Monte Carlo
    /// apertures, only the first otherwise.
    sides: [Side; 2],
}

/// The amplitudes in closed form of every light (into `al`) and view (`av`), seen from a vertex
/// as `seen(i)` (lights first, then views), where the path's direction is `u`: every focused
/// terminal's lobes evaluated in one batch.
fn closed_amplitudes(
    seen: impl Fn(usize) -> Seen,
    u: DVec3,
    (phase, lobes): (&PhaseFunction, &Lobes),
    here: &mut Here,
    (al, av): (&mut [C64], &mut [C64]),
) {
    let nl = al.len();
    let mut put = |i: usize, a: C64| {
        if i < nl {
            al[i] = a;
        } else {
            av[i - nl] = a;
        }
    };
    here.batch.clear();
    for i in 0..here.starts.len() {
        let seen = seen(i);
        here.starts[i] = seen.queue_lobes(u, lobes, &mut here.batch);
        if here.starts[i].is_none() {
            put(i, seen.amplitude(u, phase, lobes));
        }
    }
    here.batch.evaluate();
    for (i, first) in here.starts.iter().enumerate() {
        if let Some(first) = first {
            put(i, Seen::amplitude_from(&here.batch, *first, lobes));
        }
    }
}

/// Working memory of the connections at one vertex.
#[derive(Default)]
struct Here {
    /// Aperture weights (apertures by nodes).
    weights: Vec<C64>,
    /// Every focused terminal's lobes (closed forms), and where each terminal's terms start.
    batch: SphereBatch,
    starts: Vec<Option<usize>>,
    /// Every pair's two-lens terms (single scattering), and where each pair's terms start.
    pairs: PairBatch,
    pair_starts: Vec<Option<usize>>,
}

/// One estimate of a subpath's event vectors.
#[derive(Clone, Default)]
struct Side {
    a: Vec<C64>,
    amp_first_l: Vec<C64>,
    amp_first_v: Vec<C64>,
    amp_last_l: Vec<C64>,
    amp_last_v: Vec<C64>,
    /// Aperture weights at the first vertex per light and view (apertures by nodes).
    first_l: Vec<Vec<C64>>,
    first_v: Vec<Vec<C64>>,
    /// Directions drawn at the first vertex per light and view, and at the current vertex
    /// (Monte Carlo apertures).
    drawn_l: Vec<ApertureGrid>,
    drawn_v: Vec<ApertureGrid>,
    drawn_here: ApertureGrid,
}

impl<'a> SubpathSampler<'a> {
    /// Focused terminals get the vMF lobes of every particle type's amplitude (paper 000, Eq. 28).
    pub fn new(
        scene: &'a Scene,
        pairs: Vec<(usize, usize)>,
        reversed: bool,
    ) -> crate::Result<Self> {
        let terminals = Terminals::new(scene)?;
        let view_axes: Vec<DVec3> = terminals
            .views
            .iter()
            .filter_map(|t| match t {
                Terminal::Lens(l) => Some(l.axis),
                Terminal::Ray(_) => None,
            })
            .collect();
        let view_axis = view_axes
            .first()
            .filter(|a| view_axes.iter().all(|b| a.dot(*b) > 1.0 - 1e-12))
            .copied();
        let max_lobes = terminals
            .lobes
            .iter()
            .map(|l| l.lobes.len())
            .max()
            .unwrap_or(0);
        Ok(SubpathSampler {
            scene,
            terminals,
            view_axis,
            max_lobes,
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

    /// The work of one scattering event, in units of one output update: each light and view is
    /// connected (an aperture integral, about [`CONNECTION_COST`] updates), then each pair formed.
    pub fn event_cost(&self) -> f64 {
        let ends = self.terminals.lights.len() + self.terminals.views.len();
        (ends as f64) * CONNECTION_COST + self.pairs.len() as f64
    }

    pub fn pairs(&self) -> &[(usize, usize)] {
        &self.pairs
    }

    pub fn scratch(&self) -> PathScratch {
        let (nl, nv) = (self.terminals.lights.len(), self.terminals.views.len());
        let side = Side {
            a: vec![C64::default(); self.pairs.len()],
            amp_first_l: vec![C64::default(); nl],
            amp_first_v: vec![C64::default(); nv],
            amp_last_l: vec![C64::default(); nl],
            amp_last_v: vec![C64::default(); nv],
            first_l: vec![Vec::new(); nl],
            first_v: vec![Vec::new(); nv],
            drawn_l: vec![ApertureGrid::default(); nl],
            drawn_v: vec![ApertureGrid::default(); nv],
            drawn_here: ApertureGrid::default(),
        };
        PathScratch {
            first_l: vec![Seen::default(); nl],
            first_v: vec![Seen::default(); nv],
            proposal: Vec::new(),
            convolved: vec![ConvolvedLobe::default(); nl * self.max_lobes],
            view_bound: vec![0.0; nv],
            here: Here {
                starts: vec![None; nl + nv],
                pair_starts: vec![None; self.pairs.len()],
                ..Here::default()
            },
            sides: [side.clone(), side],
        }
    }

    /// Whether focused apertures are estimated from drawn directions: events then come as two
    /// independent estimates ([`EventSink::event_pair`]).
    pub fn draws_apertures(&self) -> bool {
        self.terminals.drawn.is_some()
    }

    /// Estimates per event: two independent ones with Monte Carlo apertures.
    fn sides(&self) -> usize {
        if self.terminals.drawn.is_some() { 2 } else { 1 }
    }

    /// Reports the event vectors of `sc` to `sink`.
    fn emit<S: EventSink>(&self, multiple: bool, sc: &PathScratch, sink: &mut S, rng: &mut Rng) {
        let [a, b] = &sc.sides;
        if self.sides() == 2 {
            sink.event_pair(multiple, &a.a, &b.a, rng);
        } else {
            sink.event(multiple, &a.a, rng);
        }
    }

    /// The single-scattering (`B = 1`) amplitudes of every pair at vertex `x1`, scattered by a
    /// particle of type `kind`, into the event vector: `υ(i→x₁) υ(x₁→v)` (Eq. 5; `Υ` for lenses,
    /// Eq. 18), before the first vertex's `√(σ_s / p(x₁))`. Leaves what each terminal looks like
    /// from `x1` in `sc` for the rest of the path. The closed-form single scattering integrates
    /// these; it needs apertures that draw nothing (it refuses Monte Carlo ones).
    pub fn single_at<'s>(&self, x1: DVec3, kind: usize, sc: &'s mut PathScratch) -> &'s [C64] {
        self.see_first(x1, sc);
        self.single_side(x1, kind, 0, None, sc);
        &sc.sides[0].a
    }

    /// What every terminal looks like from the first vertex `x1` (closed forms).
    fn see_first(&self, x1: DVec3, sc: &mut PathScratch) {
        let (s, t) = (self.scene, &self.terminals);
        for (e, c) in t.lights.iter().zip(sc.first_l.iter_mut()) {
            *c = e.seen_from(x1, &s.medium, s.k);
        }
        for (e, c) in t.views.iter().zip(sc.first_v.iter_mut()) {
            *c = e.seen_from(x1, &s.medium, s.k);
        }
    }

    /// [`Self::single_at`] for one estimate (`side`), after [`Self::see_first`]; Monte Carlo
    /// apertures draw their directions at `x1` from `rng`.
    fn single_side(
        &self,
        x1: DVec3,
        kind: usize,
        side: usize,
        rng: Option<&mut Rng>,
        sc: &mut PathScratch,
    ) {
        let t = &self.terminals;
        let (phase1, lobes1) = (self.scene.medium.scattering.phase(kind), &t.lobes[kind]);
        if t.by_nodes() {
            let sd = &mut sc.sides[side];
            self.weigh_first_nodes(x1, sd, rng);
            let mut a = std::mem::take(&mut sd.a);
            for (a, &(l, v)) in a.iter_mut().zip(&self.pairs) {
                *a = self.single_by_nodes(l, v, (&sc.first_l, &sc.first_v), sd, phase1, lobes1);
            }
            sd.a = a;
            return;
        }
        let nlobes = lobes1.lobes.len();
        if let Some(axis) = self.view_axis {
            for (l, seen) in sc.first_l.iter().enumerate() {
                if let Seen::Aperture { vmf, .. } = seen {
                    for (m, lobe) in lobes1.lobes.iter().enumerate() {
                        sc.convolved[l * self.max_lobes + m] = convolve_lobe(vmf, lobe, axis);
                    }
                }
            }
            // the bound depends on the scale and |Re μ| alone, which views sharing an axis and
            // aperture share: computed once per run of equal ones
            let mut last: Option<((f64, f64), f64)> = None;
            for (seen, b) in sc.first_v.iter().zip(sc.view_bound.iter_mut()) {
                if let Seen::Aperture { vmf, .. } = seen {
                    let key = (vmf.log_scale.re, vmf.mu.re.length_squared());
                    *b = match last {
                        Some((k, bound)) if k == key => bound,
                        _ => log_aperture_mass(vmf),
                    };
                    last = Some((key, *b));
                }
            }
        }
        // two lenses about a shared view axis: every pair's lobes evaluated in one batch
        let here = &mut sc.here;
        here.pairs.clear();
        for (n, &(l, v)) in self.pairs.iter().enumerate() {
            here.pair_starts[n] = match (&sc.first_l[l], &sc.first_v[v], self.view_axis) {
                (Seen::Aperture { .. }, Seen::Aperture { vmf: av, .. }, Some(_)) => {
                    let convolved = &sc.convolved[l * self.max_lobes..l * self.max_lobes + nlobes];
                    let mut first = None;
                    for c in convolved {
                        let i = lens_pair_queue(c, av, sc.view_bound[v], &mut here.pairs);
                        first.get_or_insert(i);
                    }
                    first
                }
                _ => None,
            };
        }
        here.pairs.evaluate();
        for (n, (a, &(l, v))) in sc.sides[side].a.iter_mut().zip(&self.pairs).enumerate() {
            *a = match here.pair_starts[n] {
                Some(first) => sc.convolved[l * self.max_lobes..l * self.max_lobes + nlobes]
                    .iter()
                    .enumerate()
                    .map(|(m, c)| lens_pair_from(c, first + m, &here.pairs))
                    .sum(),
                None => sc.first_l[l].single(&sc.first_v[v], phase1, lobes1),
            };
        }
    }

    /// Trace one subpath and report its events to `sink`.
    pub fn trace<S: EventSink>(&self, rng: &mut Rng, sc: &mut PathScratch, sink: &mut S) {
        let s = self.scene;
        let m = &s.medium;
        let geo = &m.geometry;
        let sigma_t = m.sigma_t();
        let albedo = m.albedo();
        let t = &self.terminals;
        let drawn = t.first.draw(geo, rng);
        if !geo.contains(drawn.x) {
            return;
        }
        let x1 = drawn.x;
        // σ_s / p(x₁): σ_s V for a uniform first vertex (V per unit area for a slab)
        let volume = m.sigma_s * drawn.inv_pdf;
        let kind1 = m.scattering.pick(|| uniform(rng));
        let (phase1, lobes1) = (m.scattering.phase(kind1), &t.lobes[kind1]);
        // B = 1: a_j = sqrt(V) υ(i→x1) υ(i→x1→v).
        self.see_first(x1, sc);
        let root = volume.sqrt();
        for side in 0..self.sides() {
            self.single_side(x1, kind1, side, Some(rng), sc);
            sc.sides[side].a.iter_mut().for_each(|a| *a *= root);
        }
        self.emit(false, sc, sink, rng);

        // B ≥ 2: the first direction (uniform, or from |Υ|²), then volume path tracing with
        // next-event connections.
        let (w1, inv_pdf_w1) = t.first.direction(x1, m, &t.lobes[0], rng, &mut sc.proposal);
        let d = -(1.0 - uniform(rng)).ln() / sigma_t;
        if d >= geo.exit_distance(x1, w1) {
            return;
        }
        // at the first vertex the aperture weights are already at hand (single scattering)
        if !t.by_nodes() {
            let (first_l, first_v) = (&sc.first_l, &sc.first_v);
            let nl = first_l.len();
            let seen = |i: usize| if i < nl { first_l[i] } else { first_v[i - nl] };
            let sd = &mut sc.sides[0];
            let out = (&mut sd.amp_first_l[..], &mut sd.amp_first_v[..]);
            closed_amplitudes(seen, -w1, (phase1, lobes1), &mut sc.here, out);
        } else {
            for sd in &mut sc.sides[..self.sides()] {
                for i in 0..t.lights.len() {
                    sd.amp_first_l[i] = match (&t.lights[i], self.first_nodes(sd, true, i)) {
                        (Terminal::Lens(lens), Some((g, c))) => upsilon(lens, g, c, -w1, phase1),
                        _ => sc.first_l[i].amplitude(-w1, phase1, lobes1),
                    };
                }
                for i in 0..t.views.len() {
                    sd.amp_first_v[i] = match (&t.views[i], self.first_nodes(sd, false, i)) {
                        (Terminal::Lens(lens), Some((g, c))) => upsilon(lens, g, c, -w1, phase1),
                        _ => sc.first_v[i].amplitude(-w1, phase1, lobes1),
                    };
                }
            }
        }
        let scale = volume * inv_pdf_w1 * if self.reversed { 0.5 } else { 1.0 };
        let mut x = x1 + w1 * d;
        let mut w_in = w1;
        let mut throughput = albedo;
        loop {
            let kind = m.scattering.pick(|| uniform(rng));
            let root = (scale * throughput).sqrt();
            for sd in &mut sc.sides[..self.sides()] {
                self.connect_all(x, w_in, kind, sd, &mut sc.here, rng);
                for (a, &(l, v)) in sd.a.iter_mut().zip(&self.pairs) {
                    let mut z = sd.amp_first_l[l] * sd.amp_last_v[v];
                    if self.reversed {
                        z += sd.amp_last_l[l] * sd.amp_first_v[v];
                    }
                    *a = z * root;
                }
            }
            self.emit(true, sc, sink, rng);

            let w_out = m
                .scattering
                .phase(kind)
                .sample(w_in, uniform(rng), uniform(rng));
            let d = -(1.0 - uniform(rng)).ln() / sigma_t;
            if d >= geo.exit_distance(x, w_out) {
                return;
            }
            x += w_out * d;
            w_in = w_out;
            throughput *= albedo;
            if throughput < ROULETTE_BELOW {
                // Russian roulette keeps absorbing media cheap without bias.
                if uniform(rng) >= ROULETTE_SURVIVAL {
                    return;
                }
                throughput *= 1.0 / ROULETTE_SURVIVAL;
            }
        }
    }

    /// The nodes and first-vertex weights of focused light (`light`) or view `i` in `sd`: the
    /// scene's quadrature grid or the directions drawn there (`None` for other terminals, or
    /// apertures in closed form).
    fn first_nodes<'g>(
        &'g self,
        sd: &'g Side,
        light: bool,
        i: usize,
    ) -> Option<(&'g ApertureGrid, &'g [C64])> {
        let t = &self.terminals;
        let (grids, drawn, weights) = match (light, &t.quadrature) {
            (true, q) => (q.as_ref().map(|q| &q.lights), &sd.drawn_l, &sd.first_l),
            (false, q) => (q.as_ref().map(|q| &q.views), &sd.drawn_v, &sd.first_v),
        };
        let grid = match grids {
            Some(g) => g[i].as_ref()?,
            None if t.drawn.is_some() => &drawn[i],
            None => return None,
        };
        Some((grid, &weights[i]))
    }

    /// The aperture weights of every focused terminal at the first vertex `x` (apertures by
    /// nodes), drawing the directions first for Monte Carlo apertures.
    fn weigh_first_nodes(&self, x: DVec3, sd: &mut Side, mut rng: Option<&mut Rng>) {
        let (s, t) = (self.scene, &self.terminals);
        let attenuation = t.attenuation();
        let q = t.quadrature.as_ref();
        let sides = [
            (
                &t.lights,
                q.map(|q| &q.lights),
                &mut sd.drawn_l,
                &mut sd.first_l,
            ),
            (
                &t.views,
                q.map(|q| &q.views),
                &mut sd.drawn_v,
                &mut sd.first_v,
            ),
        ];
        for (terms, grids, drawn, out) in sides {
            for (i, term) in terms.iter().enumerate() {
                let Terminal::Lens(lens) = term else { continue };
                let grid = match (grids, t.drawn, rng.as_deref_mut()) {
                    (Some(g), _, _) => g[i].as_ref().expect("a grid per focused terminal"),
                    (None, Some(n), Some(rng)) => {
                        drawn[i].draw(lens, n, rng);
                        &drawn[i]
                    }
                    _ => continue,
                };
                weighted_aperture(lens, grid, attenuation, x, &s.medium, s.k, &mut out[i]);
            }
        }
    }

    /// Single scattering of pair `(l, v)` at the first vertex with apertures by nodes (what the
    /// terminals look like from there in `seen`, the weights in `sd`).
    fn single_by_nodes(
        &self,
        l: usize,
        v: usize,
        seen: (&[Seen], &[Seen]),
        sd: &Side,
        phase: &PhaseFunction,
        lobes: &Lobes,
    ) -> C64 {
        let t = &self.terminals;
        let (nl, nv) = (
            self.first_nodes(sd, true, l),
            self.first_nodes(sd, false, v),
        );
        match (&t.lights[l], &t.views[v], &seen.0[l], &seen.1[v], nl, nv) {
            (Terminal::Lens(_), Terminal::Lens(_), _, _, Some(nl), Some(nv))
                if t.drawn.is_some() =>
            {
                lens_pair_drawn(nl, nv, phase)
            }
            (Terminal::Lens(_), Terminal::Lens(_), _, seen_v, Some((g, c)), _) => {
                lens_pair(g, c, seen_v, lobes)
            }
            (Terminal::Lens(lens), _, _, Seen::Ray(cv), Some((g, c)), _) => {
                upsilon(lens, g, c, -cv.dir, phase) * cv.prop
            }
            (_, Terminal::Lens(lens), Seen::Ray(cl), _, _, Some((g, c))) => {
                upsilon(lens, g, c, -cl.dir, phase) * cl.prop
            }
            (_, _, sl, sv, _, _) => sl.single(sv, phase, lobes),
        }
    }

    /// `B_l = τ ξ s(w_in · dir)` (or `Υ` for a focused terminal, by nodes when the scene asks for
    /// them) to every light and view from vertex `x` reached along `w_in`, scattered by a particle
    /// of type `kind`, into `sd`'s last amplitudes.
    #[inline]
    fn connect_all(
        &self,
        x: DVec3,
        w_in: DVec3,
        kind: usize,
        sd: &mut Side,
        here: &mut Here,
        rng: &mut Rng,
    ) {
        let (s, t) = (self.scene, &self.terminals);
        let (phase, lobes) = (s.medium.scattering.phase(kind), &t.lobes[kind]);
        if !t.by_nodes() {
            let nl = t.lights.len();
            let seen = |i: usize| {
                let e = if i < nl {
                    &t.lights[i]
                } else {
                    &t.views[i - nl]
                };
                e.seen_from(x, &s.medium, s.k)
            };
            let out = (&mut sd.amp_last_l[..], &mut sd.amp_last_v[..]);
            closed_amplitudes(seen, w_in, (phase, lobes), here, out);
            return;
        }
        let weights = &mut here.weights;
        let q = t.quadrature.as_ref();
        let attenuation = t.attenuation();
        let drawn_here = &mut sd.drawn_here;
        let mut connect =
            |e: &Terminal, grid: Option<&Option<ApertureGrid>>| match (e, grid, t.drawn) {
                (Terminal::Lens(lens), Some(Some(g)), _) => {
                    weighted_aperture(lens, g, attenuation, x, &s.medium, s.k, weights);
                    upsilon(lens, g, weights, w_in, phase)
                }
                (Terminal::Lens(lens), None, Some(n)) => {
                    drawn_here.draw(lens, n, rng);
                    weighted_aperture(lens, drawn_here, attenuation, x, &s.medium, s.k, weights);
                    upsilon(lens, drawn_here, weights, w_in, phase)
                }
                _ => e.seen_from(x, &s.medium, s.k).amplitude(w_in, phase, lobes),
            };
        for (i, (e, a)) in t.lights.iter().zip(sd.amp_last_l.iter_mut()).enumerate() {
            *a = connect(e, q.map(|q| &q.lights[i]));
        }
        for (i, (e, a)) in t.views.iter().zip(sd.amp_last_v.iter_mut()).enumerate() {
            *a = connect(e, q.map(|q| &q.views[i]));
        }
    }
}
