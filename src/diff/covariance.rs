//! Re-weighted covariance (Algorithm 1 with paths from a proposal medium) and its path-space
//! gradient contracted with a loss adjoint.
//!
//! For a subpath `x1 → … → xB` drawn from the proposal (`σ_s⁰, σ_t⁰, ρ⁰`), the target weight is
//! `w = 4π V σ_s^B e^{-σ_t D} / (σ_t⁰^{B-1} e^{-σ_t⁰ D}) Π ρ/ρ⁰` (`D` the summed hop lengths, the
//! product over interior vertices; `V = Vol/Area`, halved with reversed paths, times any Russian
//! roulette factor), and `w = σ_s V` for single scattering (paper 001, Eqs. 31–36). Every endpoint
//! amplitude `A = ξ e^{-σ_t ℓ/2} s(μ)` has `∂A/∂θ = A λ` with `λ = -ℓ/2` for `σ_s, σ_a` and
//! `λ = ½ ∂log ρ/∂g` for HG `g`, so `∂a/∂θ` and `∂log w/∂θ` are cheap per event. A focused
//! endpoint's aperture integral `Υ` (paper 000) carries the linearised attenuation
//! `e^{−σ_t h} e^{(σ_t h/2) a·ω}`, differentiated in closed form. `Υ` is linear in the amplitude's vMF lobes (paper 000, Eq. 28):
//! at the target it is `Σ_l w_l(θ) Υ_{κ_l}`, with a vMF mixture's own lobes (whose weights and
//! concentrations are differentiated exactly), and for other phase functions the target amplitude
//! projected onto the proposal's lobe concentrations (least squares on the fit's quadrature:
//! exactly the fitted lobes at the proposal, and linear in `s`, so `∂w/∂θ` is the projection of
//! `∂s/∂θ = s ½ ∂log ρ/∂θ`).

use super::Param;
use crate::math::{C64, Rng, uniform};
use crate::mc::Estimator;
use crate::medium::lobes::Lobes;
use crate::medium::{Medium, PhaseFunction};
use crate::speckle::Scene;
use crate::speckle::covariance::Batch;
use crate::speckle::endpoint::{Connection, Seen, lens_pair_lobe, log_aperture_mass};
use crate::speckle::paths::Terminals;
use glam::DVec3;

/// Paths from `proposal`, contributions evaluated for the medium `target` with derivatives with
/// respect to `params`.
pub struct Reweighted<'a> {
    proposal: &'a Scene,
    target: Medium,
    /// Lights, views, lobes and first-vertex sampling, as the covariance estimator has them (the
    /// first-vertex density does not depend on `θ`).
    terminals: Terminals,
    pairs: Vec<(usize, usize)>,
    reversed: bool,
    params: Vec<Param>,
    /// Per particle type, the target's amplitude lobes for focused terminals and their derivatives.
    target_lobes: Vec<TargetLobes>,
}

/// The target's amplitude lobes of one particle type, as focused terminals use them, with the
/// derivatives of every lobe's weight and concentration with respect to each parameter
/// (`[p · lobes + l]`; zero for parameters of other types).
#[derive(Clone, Debug, Default)]
struct TargetLobes {
    lobes: Lobes,
    dweight: Vec<C64>,
    dkappa: Vec<f64>,
}

impl TargetLobes {
    /// `proposal`: the proposal's lobes of this type (empty without focused terminals).
    fn new(
        proposal: &Lobes,
        proposal_phase: &PhaseFunction,
        target: &PhaseFunction,
        kind: usize,
        params: &[Param],
    ) -> Self {
        let n = proposal.lobes.len();
        if n == 0 {
            return TargetLobes::default();
        }
        let ours = |p: &Param| p.phase_component() == Some(kind);
        if let PhaseFunction::VmfMixture(v) = target {
            let lobes = Lobes::of(target);
            let n = lobes.lobes.len();
            let mut dweight = vec![C64::default(); params.len() * n];
            let mut dkappa = vec![0.0; params.len() * n];
            for (i, p) in params.iter().enumerate() {
                if let Some((dw, dk)) = p.vmf_lobe_derivatives(v).filter(|_| ours(p)) {
                    for l in 0..n {
                        dweight[i * n + l] = C64::new(dw[l], 0.0);
                        dkappa[i * n + l] = dk[l];
                    }
                }
            }
            return TargetLobes {
                lobes,
                dweight,
                dkappa,
            };
        }
        let lobes = if target == proposal_phase {
            proposal.clone()
        } else {
            proposal.project(|mu| target.amplitude(mu))
        };
        let mut dweight = vec![C64::default(); params.len() * n];
        for (i, p) in params.iter().enumerate().filter(|(_, p)| ours(p)) {
            let d = proposal.project(|mu| {
                let s = target.amplitude(mu);
                if s == C64::default() {
                    return s;
                }
                s * (0.5 * p.dlog_phase(kind, target, mu))
            });
            for (l, lobe) in d.lobes.iter().enumerate() {
                dweight[i * n + l] = lobe.weight;
            }
        }
        TargetLobes {
            lobes,
            dweight,
            dkappa: vec![0.0; params.len() * n],
        }
    }
}

/// Receives weighted events with derivatives: `w`, `∂log w/∂θ_p`, `a` (J) and `∂a/∂θ_p` (P×J).
trait DiffSink {
    fn event(&mut self, w: f64, dlogw: &[f64], a: &[C64], da: &[C64]);
}

/// Per-thread working memory.
pub struct DiffScratch {
    first_l: Vec<Seen>,
    first_v: Vec<Seen>,
    /// Endpoint amplitudes at the first and current vertex, and their derivatives (P per endpoint).
    amp1_l: Vec<C64>,
    amp1_v: Vec<C64>,
    d1_l: Vec<C64>,
    d1_v: Vec<C64>,
    ampb_l: Vec<C64>,
    ampb_v: Vec<C64>,
    db_l: Vec<C64>,
    db_v: Vec<C64>,
    a: Vec<C64>,
    da: Vec<C64>,
    dlogw: Vec<f64>,
    /// Σ ∂log ρ/∂g over interior vertices, per parameter.
    interior: Vec<f64>,
    dsingle: Vec<C64>,
    proposal: Vec<(f64, DVec3, f64)>,
}

impl<'a> Reweighted<'a> {
    /// Errors if an endpoint is unsupported or a parameter does not exist in the medium.
    pub fn new(
        proposal: &'a Scene,
        target: Medium,
        pairs: Vec<(usize, usize)>,
        reversed: bool,
        params: Vec<Param>,
    ) -> crate::Result<Self> {
        for p in &params {
            if p.get(&target).is_none() {
                return Err(format!(
                    "parameter {} does not exist in this medium (only Henyey–Greenstein components have g)",
                    p.name()
                ).into());
            }
        }
        if target.geometry != proposal.medium.geometry {
            return Err("the target medium must have the proposal's geometry".into());
        }
        if proposal.aperture != crate::speckle::aperture_quadrature::ApertureModel::Vmf {
            return Err(crate::Error::input(
                "gradients use the vMF closed forms of focused apertures: render.aperture = \"quadrature\" and \"monte_carlo\" are references for forward runs; use aperture = \"vmf\"",
            ));
        }
        let terminals = Terminals::new(proposal)?;
        let (from, to) = (
            proposal.medium.scattering.components(),
            target.scattering.components(),
        );
        if from.len() != to.len() {
            return Err("the target medium must have the proposal's particle types".into());
        }
        let target_lobes = terminals
            .lobes
            .iter()
            .enumerate()
            .map(|(kind, lobes)| TargetLobes::new(lobes, &from[kind].1, &to[kind].1, kind, &params))
            .collect();
        Ok(Reweighted {
            proposal,
            target,
            terminals,
            pairs,
            reversed,
            params,
            target_lobes,
        })
    }

    pub fn fields(&self) -> usize {
        self.pairs.len()
    }

    pub fn params(&self) -> &[Param] {
        &self.params
    }

    fn scratch(&self) -> DiffScratch {
        let (nl, nv, j, p) = (
            self.terminals.lights.len(),
            self.terminals.views.len(),
            self.pairs.len(),
            self.params.len(),
        );
        DiffScratch {
            first_l: vec![Seen::default(); nl],
            first_v: vec![Seen::default(); nv],
            amp1_l: vec![C64::default(); nl],
            amp1_v: vec![C64::default(); nv],
            d1_l: vec![C64::default(); nl * p],
            d1_v: vec![C64::default(); nv * p],
            ampb_l: vec![C64::default(); nl],
            ampb_v: vec![C64::default(); nv],
            db_l: vec![C64::default(); nl * p],
            db_v: vec![C64::default(); nv * p],
            a: vec![C64::default(); j],
            da: vec![C64::default(); j * p],
            dlogw: vec![0.0; p],
            interior: vec![0.0; p],
            dsingle: vec![C64::default(); p],
            proposal: Vec::new(),
        }
    }

    /// `∂σ_t/∂θ_p` (1 for σ_s and σ_a).
    #[inline]
    fn dsigma_t(p: &Param) -> f64 {
        match p {
            Param::SigmaS | Param::SigmaA => 1.0,
            _ => 0.0,
        }
    }

    /// Target amplitude `A = prop s_θ(μ)` of a connection at a vertex of type `kind` (seen from
    /// the target medium), with the path direction `u` (scattering cosine `u·dir`), and its
    /// derivatives `dA`; for a focused endpoint `Σ_l w_l Υ_{κ_l}` with the target's lobes, whose
    /// linearised attenuation `e^{−σ_t h} e^{(σ_t h/2) a·ω}` gives
    /// `∂Υ/∂σ_t = −h Υ + (h/2) ∂Υ/∂t` (`t` a concentration added along the axis).
    #[inline]
    fn amplitude(&self, c: &Seen, u: DVec3, kind: usize, da: &mut [C64]) -> C64 {
        let phase = self.target.scattering.phase(kind);
        let inside = c.inside();
        let Seen::Ray(ray) = c else {
            let t = &self.target_lobes[kind];
            let n = t.lobes.lobes.len();
            da.iter_mut().for_each(|d| *d = C64::default());
            let (mut a, mut d_axis) = (C64::default(), C64::default());
            for (l, lobe) in t.lobes.lobes.iter().enumerate() {
                // derivatives only when some are asked for (a fit's model evaluations need none)
                let y = c.aperture_lobe(u, lobe.kappa, !self.params.is_empty());
                a += lobe.weight * y.value;
                d_axis += lobe.weight * y.d_axis;
                for (p, d) in da.iter_mut().enumerate() {
                    *d += t.dweight[p * n + l] * y.value
                        + lobe.weight * y.d_kappa * t.dkappa[p * n + l];
                }
            }
            for (d, p) in da.iter_mut().zip(&self.params) {
                *d += (a * -inside + d_axis * (0.5 * inside)) * Self::dsigma_t(p);
            }
            return a;
        };
        let mu = u.dot(ray.dir);
        // a tabulated law is located once for all its node parameters (hot: every connection)
        let located = match phase {
            PhaseFunction::Tabulated(t) => Some((t, t.locate(mu))),
            _ => None,
        };
        let a = ray.prop * phase.amplitude(mu);
        for (d, p) in da.iter_mut().zip(&self.params) {
            let lambda = match (p, located) {
                (Param::SigmaS | Param::SigmaA, _) => -0.5 * inside,
                (Param::Bin(pc, k), Some((t, at))) if *pc == kind => {
                    0.5 * t.dlog_rho_dnode_at(at, *k)
                }
                (p, _) => 0.5 * p.dlog_phase(kind, phase, mu),
            };
            *d = a * lambda;
        }
        a
    }

    /// The single-scattering amplitude of light `cl` and view `cv` at a vertex of type `kind`
    /// and its derivatives.
    #[inline]
    fn single(&self, cl: &Seen, cv: &Seen, kind: usize, da: &mut [C64]) -> C64 {
        match (cl, cv) {
            (Seen::Ray(rl), Seen::Ray(rv)) => {
                let both = Seen::Ray(Connection {
                    prop: rl.prop * rv.prop,
                    dir: rv.dir,
                    inside: rl.inside + rv.inside,
                });
                self.amplitude(&both, -rl.dir, kind, da)
            }
            // a lens and a ray: the lens's Υ toward the ray times the ray's connection
            (lens, Seen::Ray(ray)) | (Seen::Ray(ray), lens) => {
                let a = self.amplitude(lens, -ray.dir, kind, da) * ray.prop;
                for (d, p) in da.iter_mut().zip(&self.params) {
                    *d = *d * ray.prop + a * (-0.5 * ray.inside * Self::dsigma_t(p));
                }
                a
            }
            (
                Seen::Aperture {
                    vmf: al,
                    axis: light_axis,
                    inside: hl,
                    ..
                },
                Seen::Aperture {
                    vmf: av,
                    axis,
                    inside: hv,
                    ..
                },
            ) => {
                let t = &self.target_lobes[kind];
                let n = t.lobes.lobes.len();
                let view_bound = log_aperture_mass(av);
                da.iter_mut().for_each(|d| *d = C64::default());
                let (mut a, mut d_sigma) = (C64::default(), C64::default());
                for (l, lobe) in t.lobes.lobes.iter().enumerate() {
                    let y = lens_pair_lobe(
                        al,
                        *light_axis,
                        lobe.kappa,
                        *axis,
                        av,
                        view_bound,
                        !self.params.is_empty(),
                    );
                    a += lobe.weight * y.value;
                    d_sigma += lobe.weight
                        * (y.value * -(hl + hv)
                            + y.d_axis * (0.5 * hl)
                            + y.d_axis_view * (0.5 * hv));
                    for (p, d) in da.iter_mut().enumerate() {
                        *d += t.dweight[p * n + l] * y.value
                            + lobe.weight * y.d_kappa * t.dkappa[p * n + l];
                    }
                }
                for (d, p) in da.iter_mut().zip(&self.params) {
                    *d += d_sigma * Self::dsigma_t(p);
                }
                a
            }
        }
    }

    fn trace<S: DiffSink>(&self, rng: &mut Rng, sc: &mut DiffScratch, sink: &mut S) {
        let s = self.proposal;
        let m0 = &s.medium;
        let m = &self.target;
        let geo = &m0.geometry;
        let np = self.params.len();
        let (sigma_t0, albedo0) = (m0.sigma_t(), m0.albedo());
        let drawn = self.terminals.first.draw(geo, rng);
        if !geo.contains(drawn.x) {
            return;
        }
        let x1 = drawn.x;
        // 1/p(x₁): the volume (per unit area of a slab) for a uniform first vertex
        let vol = drawn.inv_pdf;
        let kind1 = m0.scattering.pick(|| uniform(rng));
        // connections and apertures as the target sees them (its attenuation)
        for (e, c) in self.terminals.lights.iter().zip(sc.first_l.iter_mut()) {
            *c = e.seen_from(x1, m, s.k);
        }
        for (e, c) in self.terminals.views.iter().zip(sc.first_v.iter_mut()) {
            *c = e.seen_from(x1, m, s.k);
        }

        // single scattering: a_j = υ(i→x1) υ(i→x1→v), w = σ_s V
        for (n, &(l, v)) in self.pairs.iter().enumerate() {
            let (cl, cv) = (&sc.first_l[l], &sc.first_v[v]);
            sc.a[n] = self.single(cl, cv, kind1, &mut sc.dsingle);
            for p in 0..np {
                sc.da[p * self.pairs.len() + n] = sc.dsingle[p];
            }
        }
        // particle types are drawn with the proposal's shares β⁰; the target's β enters as a ratio
        let beta = |med: &Medium, k: usize| med.scattering.components()[k].0;
        let type_ratio = |k: usize| (beta(m, k) / beta(m0, k)).ln();
        let dlog_beta = |p: &Param, k: usize| match p {
            Param::Weight(c) => f64::from(u8::from(*c == k)) / beta(m, k) - 1.0,
            _ => 0.0,
        };
        for (p, d) in self.params.iter().zip(sc.dlogw.iter_mut()) {
            *d = if *p == Param::SigmaS {
                1.0 / m.sigma_s
            } else {
                dlog_beta(p, kind1)
            };
        }
        sink.event(
            m.sigma_s * vol * type_ratio(kind1).exp(),
            &sc.dlogw,
            &sc.a,
            &sc.da,
        );

        // multiple scattering
        let t = &self.terminals;
        let (w1, inv_pdf_w1) = t
            .first
            .direction(x1, m0, &t.lobes[0], rng, &mut sc.proposal);
        let d = -(1.0 - uniform(rng)).ln() / sigma_t0;
        if d >= geo.exit_distance(x1, w1) {
            return;
        }
        for (i, c) in sc.first_l.iter().enumerate() {
            sc.amp1_l[i] = self.amplitude(c, -w1, kind1, &mut sc.d1_l[i * np..(i + 1) * np]);
        }
        for (i, c) in sc.first_v.iter().enumerate() {
            sc.amp1_v[i] = self.amplitude(c, -w1, kind1, &mut sc.d1_v[i * np..(i + 1) * np]);
        }
        let base = vol * inv_pdf_w1 * if self.reversed { 0.5 } else { 1.0 };
        let mut x = x1 + w1 * d;
        let mut w_in = w1;
        let mut hops = d;
        let mut bounces = 2u32; // B of the current vertex
        let mut log_ratio = 0.0; // Σ log(ρ/ρ⁰) over interior vertices
        let mut roulette = 1.0;
        let mut throughput0 = albedo0;
        sc.interior.iter_mut().for_each(|v| *v = 0.0);
        loop {
            let kind = m0.scattering.pick(|| uniform(rng));
            for (i, e) in self.terminals.lights.iter().enumerate() {
                let c = e.seen_from(x, m, s.k);
                sc.ampb_l[i] = self.amplitude(&c, w_in, kind, &mut sc.db_l[i * np..(i + 1) * np]);
            }
            for (i, e) in self.terminals.views.iter().enumerate() {
                let c = e.seen_from(x, m, s.k);
                sc.ampb_v[i] = self.amplitude(&c, w_in, kind, &mut sc.db_v[i * np..(i + 1) * np]);
            }
            let b = bounces as f64;
            let log_w = b * m.sigma_s.ln() - m.sigma_t() * hops - (b - 1.0) * sigma_t0.ln()
                + sigma_t0 * hops
                + log_ratio
                + type_ratio(kind1)
                + type_ratio(kind);
            let w = base * roulette * log_w.exp();
            for (i, p) in self.params.iter().enumerate() {
                sc.dlogw[i] = match p {
                    Param::SigmaS => b / m.sigma_s - hops,
                    Param::SigmaA => -hops,
                    Param::G(_) | Param::Bin(..) | Param::VmfWeight(..) | Param::VmfKappa(..) => {
                        sc.interior[i]
                    }
                    Param::Weight(_) => sc.interior[i] + dlog_beta(p, kind1) + dlog_beta(p, kind),
                };
            }
            let j = self.pairs.len();
            for (n, &(l, v)) in self.pairs.iter().enumerate() {
                let fwd = sc.amp1_l[l] * sc.ampb_v[v];
                let rev = if self.reversed {
                    sc.ampb_l[l] * sc.amp1_v[v]
                } else {
                    C64::default()
                };
                sc.a[n] = fwd + rev;
                for p in 0..np {
                    let mut z =
                        sc.d1_l[l * np + p] * sc.ampb_v[v] + sc.amp1_l[l] * sc.db_v[v * np + p];
                    if self.reversed {
                        z +=
                            sc.db_l[l * np + p] * sc.amp1_v[v] + sc.ampb_l[l] * sc.d1_v[v * np + p];
                    }
                    sc.da[p * j + n] = z;
                }
            }
            sink.event(w, &sc.dlogw, &sc.a, &sc.da);

            // continue with the proposal's sampling; the vertex becomes interior
            let phase0 = m0.scattering.phase(kind);
            let w_out = phase0.sample(w_in, uniform(rng), uniform(rng));
            let d = -(1.0 - uniform(rng)).ln() / sigma_t0;
            if d >= geo.exit_distance(x, w_out) {
                return;
            }
            let mu = w_in.dot(w_out);
            let phase = m.scattering.phase(kind);
            log_ratio += (phase.eval(mu) / phase0.eval(mu)).ln() + type_ratio(kind);
            for (v, p) in sc.interior.iter_mut().zip(&self.params) {
                *v += p.dlog_phase(kind, phase, mu) + dlog_beta(p, kind);
            }
            x += w_out * d;
            w_in = w_out;
            hops += d;
            bounces += 1;
            throughput0 *= albedo0;
            if throughput0 < 1e-3 {
                if uniform(rng) >= 0.1 {
                    return;
                }
                throughput0 *= 10.0;
                roulette *= 10.0;
            }
        }
    }
}

/// The re-weighted covariance `C(θ)` (total, `J×J` row-major) from proposal paths.
pub struct ReweightedCovariance<'a>(pub Reweighted<'a>);

struct Accumulate<'b>(&'b mut Batch, &'b mut Vec<C64>);

impl DiffSink for Accumulate<'_> {
    fn event(&mut self, w: f64, _: &[f64], a: &[C64], _: &[C64]) {
        let r = w.sqrt();
        self.1.iter_mut().zip(a).for_each(|(d, s)| *d = s * r);
        self.0.push(self.1);
    }
}

impl Estimator for ReweightedCovariance<'_> {
    type Scratch = (DiffScratch, Batch, Vec<C64>);

    fn outputs(&self) -> usize {
        self.0.fields() * self.0.fields()
    }

    fn scratch(&self) -> Self::Scratch {
        (
            self.0.scratch(),
            Batch::new(self.0.fields()),
            vec![C64::default(); self.0.fields()],
        )
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut Self::Scratch, out: &mut [C64]) {
        let (d, batch, tmp) = sc;
        for _ in 0..paths {
            self.0.trace(rng, d, &mut Accumulate(batch, tmp));
        }
        batch.drain_into(out);
    }
}

/// `∂L/∂θ_p = Σ_events [∂_p w Re Q(a, a) + 2 w Re Q(∂_p a, a)]` with `Q(x, y) = Σ conj(Ā_ij) x_i conj(y_j)`
/// for a Hermitian loss adjoint `Ā = ∂L/∂C` (`dL = Re Σ conj(Ā_ij) dC_ij`). Outputs one value per
/// parameter (real part).
pub struct CovarianceGradient<'a> {
    pub inner: Reweighted<'a>,
    /// `conj(Ā)` made Hermitian, row-major `J×J`.
    adjoint_conj: Vec<C64>,
}

impl<'a> CovarianceGradient<'a> {
    /// `adjoint[i·J + j] = ∂L/∂C_ij`; only its Hermitian part matters (C is Hermitian).
    pub fn new(inner: Reweighted<'a>, adjoint: &[C64]) -> Self {
        let j = inner.fields();
        let mut adjoint_conj = vec![C64::default(); j * j];
        for a in 0..j {
            for b in 0..j {
                adjoint_conj[a * j + b] =
                    (0.5 * (adjoint[a * j + b] + adjoint[b * j + a].conj())).conj();
            }
        }
        CovarianceGradient {
            inner,
            adjoint_conj,
        }
    }
}

/// Events gathered before one batched contraction `Y = conj(Ā) conj(A)` (a matrix product).
const BATCH: usize = 64;

/// Per-thread batch of events for [`CovarianceGradient`].
pub struct ContractBatch {
    j: usize,
    p: usize,
    n: usize,
    /// `conj(a)` of each event, column-major `J × BATCH`.
    conj_a: Vec<C64>,
    a: Vec<C64>,
    da: Vec<C64>,
    w: Vec<f64>,
    dlogw: Vec<f64>,
    y: Vec<C64>,
}

impl ContractBatch {
    fn new(j: usize, p: usize) -> Self {
        ContractBatch {
            j,
            p,
            n: 0,
            conj_a: vec![C64::default(); j * BATCH],
            a: vec![C64::default(); j * BATCH],
            da: vec![C64::default(); p * j * BATCH],
            w: vec![0.0; BATCH],
            dlogw: vec![0.0; p * BATCH],
            y: vec![C64::default(); j * BATCH],
        }
    }

    /// Contract the gathered events with `conj(Ā)` (row-major `J×J`) into `grad`.
    fn flush(&mut self, adj_conj: &[C64], grad: &mut [C64]) {
        let (j, p, n) = (self.j, self.p, self.n);
        if n == 0 {
            return;
        }
        // SAFETY: adj_conj is j×j row-major, conj_a holds n columns of j (column-major), y is j×n
        // column-major; all strides stay in bounds.
        unsafe {
            matrixmultiply::zgemm(
                matrixmultiply::CGemmOption::Standard,
                matrixmultiply::CGemmOption::Standard,
                j,
                j,
                n,
                [1.0, 0.0],
                adj_conj.as_ptr() as *const [f64; 2],
                j as isize,
                1,
                self.conj_a.as_ptr() as *const [f64; 2],
                1,
                j as isize,
                [0.0, 0.0],
                self.y.as_mut_ptr() as *mut [f64; 2],
                1,
                j as isize,
            );
        }
        for e in 0..n {
            let y = &self.y[e * j..(e + 1) * j];
            let qa: f64 = self.a[e * j..(e + 1) * j]
                .iter()
                .zip(y)
                .map(|(x, y)| (x * y).re)
                .sum();
            for (k, g) in grad.iter_mut().enumerate().take(p) {
                let da = &self.da[(e * p + k) * j..(e * p + k + 1) * j];
                let qd: f64 = da.iter().zip(y).map(|(x, y)| (x * y).re).sum();
                g.re += self.w[e] * (self.dlogw[e * p + k] * qa + 2.0 * qd);
            }
        }
        self.n = 0;
    }
}

struct Contract<'b> {
    adj: &'b [C64],
    batch: &'b mut ContractBatch,
    grad: &'b mut [C64],
}

impl DiffSink for Contract<'_> {
    fn event(&mut self, w: f64, dlogw: &[f64], a: &[C64], da: &[C64]) {
        if self.batch.n == BATCH {
            self.batch.flush(self.adj, self.grad);
        }
        let b = &mut *self.batch;
        let (j, p, e) = (b.j, b.p, b.n);
        b.a[e * j..(e + 1) * j].copy_from_slice(a);
        for (d, s) in b.conj_a[e * j..(e + 1) * j].iter_mut().zip(a) {
            *d = s.conj();
        }
        b.da[e * p * j..(e + 1) * p * j].copy_from_slice(da);
        b.w[e] = w;
        b.dlogw[e * p..(e + 1) * p].copy_from_slice(dlogw);
        b.n += 1;
    }
}

impl Estimator for CovarianceGradient<'_> {
    type Scratch = (DiffScratch, ContractBatch);

    fn outputs(&self) -> usize {
        self.inner.params().len()
    }

    fn scratch(&self) -> Self::Scratch {
        (
            self.inner.scratch(),
            ContractBatch::new(self.inner.fields(), self.inner.params().len()),
        )
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut Self::Scratch, out: &mut [C64]) {
        let (d, batch) = sc;
        let mut sink = Contract {
            adj: &self.adjoint_conj,
            batch,
            grad: out,
        };
        for _ in 0..paths {
            self.inner.trace(rng, d, &mut sink);
        }
        let Contract { adj, batch, grad } = sink;
        batch.flush(adj, grad);
    }
}
