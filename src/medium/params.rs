//! Medium parameters in one place: the differentiable parameters of a homogeneous medium
//! ([`Param`]: what path-space gradients are taken with respect to), the parameters a user fits
//! ([`FitParam`]: natural units with their unconstrained reparameterisation), the map from
//! `(mfp, albedo)` to `(σ_s, σ_a)` and its Jacobian, and "this medium with these values".

use crate::medium::{Medium, PhaseFunction};

/// `(σ_s, σ_a)` of a mean free path `1/σ_t` and an albedo `σ_s/σ_t`.
pub fn sigmas(mfp: f64, albedo: f64) -> (f64, f64) {
    (albedo / mfp, (1.0 - albedo) / mfp)
}

/// `∂(σ_s, σ_a)/∂(mfp, albedo)`: rows σ_s, σ_a; columns mfp, albedo.
pub fn sigmas_jacobian(mfp: f64, albedo: f64) -> [[f64; 2]; 2] {
    let m2 = mfp * mfp;
    [
        [-albedo / m2, 1.0 / mfp],
        [-(1.0 - albedo) / m2, -1.0 / mfp],
    ]
}

/// A differentiable parameter of a homogeneous medium.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// Scattering coefficient `σ_s`.
    SigmaS,
    /// Absorption coefficient `σ_a`.
    SigmaA,
    /// Henyey–Greenstein `g` of mixture component `c` (0 for a single type).
    G(usize),
    /// Value at node `k` of the tabulated phase function of component `c` (normalisation kept).
    Bin(usize, usize),
    /// Share `β_c` of σ_s of particle type `c` (paper 001, Eq. 44); the shares stay normalised, so
    /// this is the derivative with respect to `c`'s unnormalised weight at `Σ = 1`.
    Weight(usize),
    /// Unnormalised weight of lobe `m` of the vMF-mixture amplitude of component `c` (the
    /// mixture stays normalised; derivative at the normalised point).
    VmfWeight(usize, usize),
    /// Concentration `κ` of lobe `m` of the vMF-mixture amplitude of component `c`.
    VmfKappa(usize, usize),
}

impl Param {
    pub fn name(&self) -> String {
        match self {
            Param::SigmaS => "sigma_s".into(),
            Param::SigmaA => "sigma_a".into(),
            Param::G(0) => "g".into(),
            Param::G(c) => format!("g[{c}]"),
            Param::Bin(c, k) => format!("bin[{c}][{k}]"),
            Param::Weight(c) => format!("weight[{c}]"),
            Param::VmfWeight(0, m) => format!("vmf_weight[{m}]"),
            Param::VmfWeight(c, m) => format!("vmf_weight[{c}][{m}]"),
            Param::VmfKappa(0, m) => format!("vmf_kappa[{m}]"),
            Param::VmfKappa(c, m) => format!("vmf_kappa[{c}][{m}]"),
        }
    }

    /// The parameter a name from [`Param::name`] gives (`sigma_s`, `sigma_a`, `g`, `g[c]`,
    /// `bin[c][k]` or `bin[k]`, `weight[c]`, `vmf_weight[c][m]` or `vmf_weight[m]`, `vmf_kappa[…]`;
    /// a missing type index means type 0).
    pub fn parse(s: &str) -> crate::Result<Param> {
        let s = s.trim();
        let (head, rest) = s.split_at(s.find('[').unwrap_or(s.len()));
        let mut index = Vec::new();
        let mut tail = rest;
        while let Some(open) = tail.strip_prefix('[') {
            let close = open.find(']');
            let parsed = close.and_then(|c| open[..c].trim().parse::<usize>().ok());
            match (close, parsed) {
                (Some(c), Some(i)) => {
                    index.push(i);
                    tail = &open[c + 1..];
                }
                _ => {
                    tail = "?";
                    break;
                }
            }
        }
        let p = match (head, index.as_slice(), tail.is_empty()) {
            ("sigma_s", [], true) => Some(Param::SigmaS),
            ("sigma_a", [], true) => Some(Param::SigmaA),
            ("g", [], true) => Some(Param::G(0)),
            ("g", &[c], true) => Some(Param::G(c)),
            ("bin", &[k], true) => Some(Param::Bin(0, k)),
            ("bin", &[c, k], true) => Some(Param::Bin(c, k)),
            ("weight", &[c], true) => Some(Param::Weight(c)),
            ("vmf_weight", &[m], true) => Some(Param::VmfWeight(0, m)),
            ("vmf_weight", &[c, m], true) => Some(Param::VmfWeight(c, m)),
            ("vmf_kappa", &[m], true) => Some(Param::VmfKappa(0, m)),
            ("vmf_kappa", &[c, m], true) => Some(Param::VmfKappa(c, m)),
            _ => None,
        };
        p.ok_or_else(|| {
            format!(
                "{s:?} is not a parameter; allowed: sigma_s, sigma_a, g, g[c], bin[c][k], weight[c], vmf_weight[c][m], vmf_kappa[c][m] (c: particle type, k: table node, m: lobe)"
            )
            .into()
        })
    }

    /// The parameter's value in `m` (`None` if `m` has no such parameter).
    pub fn get(&self, m: &Medium) -> Option<f64> {
        self.value_in(m.sigma_s, m.sigma_a, &m.scattering)
    }

    /// The parameter's value in a medium of these coefficients and particles.
    pub fn value_in(
        &self,
        sigma_s: f64,
        sigma_a: f64,
        scattering: &crate::medium::Scattering,
    ) -> Option<f64> {
        match self {
            Param::SigmaS => Some(sigma_s),
            Param::SigmaA => Some(sigma_a),
            Param::G(c) => match scattering.components().get(*c).map(|x| &x.1) {
                Some(PhaseFunction::HenyeyGreenstein { g }) => Some(*g),
                _ => None,
            },
            Param::Bin(c, k) => match scattering.components().get(*c).map(|x| &x.1) {
                Some(PhaseFunction::Tabulated(t)) => t.node_value(*k),
                _ => None,
            },
            Param::Weight(c) => scattering.components().get(*c).map(|x| x.0),
            Param::VmfWeight(c, l) | Param::VmfKappa(c, l) => {
                match scattering.components().get(*c).map(|x| &x.1) {
                    Some(PhaseFunction::VmfMixture(v)) => v.lobes().get(*l).map(|&(w, k)| {
                        if matches!(self, Param::VmfWeight(..)) {
                            w
                        } else {
                            k
                        }
                    }),
                    _ => None,
                }
            }
        }
    }

    /// `∂ log (β_kind ρ_kind(μ)) / ∂θ`: the score of a scattering event that picked particle type
    /// `kind` by its share and drew the cosine `μ` from its phase function (0 for the
    /// coefficients, which enter through flights and weights).
    pub fn dlog_event(&self, scattering: &crate::medium::Scattering, kind: usize, mu: f64) -> f64 {
        match *self {
            Param::Weight(c) => f64::from(u8::from(c == kind)) / scattering.components()[c].0 - 1.0,
            _ => self.dlog_phase(kind, scattering.phase(kind), mu),
        }
    }

    /// `∂ log ρ_kind(μ) / ∂θ` for phase-function parameters of component `kind` (0 for others).
    #[inline]
    pub fn dlog_phase(&self, kind: usize, phase: &PhaseFunction, mu: f64) -> f64 {
        match (self, phase) {
            (Param::G(c), PhaseFunction::HenyeyGreenstein { .. }) if *c == kind => {
                phase.dlog_rho_dg(mu).unwrap_or(0.0)
            }
            (Param::Bin(c, k), PhaseFunction::Tabulated(t)) if *c == kind => {
                t.dlog_rho_dnode(mu, *k)
            }
            (Param::VmfWeight(c, m), PhaseFunction::VmfMixture(v)) if *c == kind => {
                v.dlog_rho(mu, *m, crate::medium::lobes::VmfParam::Weight)
            }
            (Param::VmfKappa(c, m), PhaseFunction::VmfMixture(v)) if *c == kind => {
                v.dlog_rho(mu, *m, crate::medium::lobes::VmfParam::Kappa)
            }
            _ => 0.0,
        }
    }

    /// `∂ log ρ(μ) / ∂θ` of the bulk phase function `ρ = Σ_c β_c ρ_c(μ)`, as a connection
    /// evaluates it (rather than picking a particle type): a share's `ρ_c/ρ − 1` (the shares
    /// stay normalised), a phase parameter's `β_c ρ_c ∂ log ρ_c / ρ`, 0 for the coefficients.
    pub fn dlog_mixture(&self, scattering: &crate::medium::Scattering, mu: f64) -> f64 {
        let rho = scattering.eval(mu);
        if rho.is_nan() || rho <= 0.0 {
            return 0.0;
        }
        let component = match *self {
            Param::Weight(c) => c,
            _ => match self.phase_component() {
                Some(c) => c,
                None => return 0.0,
            },
        };
        let Some((beta, phase)) = scattering.components().get(component) else {
            return 0.0;
        };
        match self {
            Param::Weight(_) => phase.eval(mu) / rho - 1.0,
            _ => beta * phase.eval(mu) * self.dlog_phase(component, phase, mu) / rho,
        }
    }

    /// Whether this is a coefficient, `σ_s` or `σ_a` (enters through attenuation: `−L` along a
    /// path of geometric length `L`).
    pub fn is_coefficient(&self) -> bool {
        matches!(self, Param::SigmaS | Param::SigmaA)
    }

    /// Whether this is a phase-function parameter (enters at vertices, not through coefficients).
    pub fn is_phase(&self) -> bool {
        matches!(
            self,
            Param::G(_) | Param::Bin(..) | Param::VmfWeight(..) | Param::VmfKappa(..)
        )
    }

    /// The particle type whose phase function this parameter belongs to.
    pub fn phase_component(&self) -> Option<usize> {
        match *self {
            Param::G(c) | Param::Bin(c, _) | Param::VmfWeight(c, _) | Param::VmfKappa(c, _) => {
                Some(c)
            }
            _ => None,
        }
    }

    /// For a vMF-mixture parameter, `∂(w_n, κ_n)/∂θ` of the mixture's normalised lobes.
    pub fn vmf_lobe_derivatives(
        &self,
        v: &crate::medium::lobes::VmfMixture,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        use crate::medium::lobes::VmfParam;
        match *self {
            Param::VmfWeight(_, m) if m < v.lobes().len() => {
                Some(v.lobe_derivatives(m, VmfParam::Weight))
            }
            Param::VmfKappa(_, m) if m < v.lobes().len() => {
                Some(v.lobe_derivatives(m, VmfParam::Kappa))
            }
            _ => None,
        }
    }

    /// A copy of `m` with this parameter set to `v`.
    pub fn set(&self, m: &Medium, v: f64) -> Medium {
        let mut out = m.clone();
        match self {
            Param::SigmaS => out.sigma_s = v,
            Param::SigmaA => out.sigma_a = v,
            Param::Weight(c) => {
                let comps = m
                    .scattering
                    .components()
                    .iter()
                    .enumerate()
                    .map(|(i, (w, p))| (if i == *c { v } else { *w }, p.clone()))
                    .collect();
                out.scattering = crate::medium::Scattering::mixture(comps);
            }
            Param::G(c) | Param::Bin(c, _) | Param::VmfWeight(c, _) | Param::VmfKappa(c, _) => {
                let comps = m
                    .scattering
                    .components()
                    .iter()
                    .enumerate()
                    .map(|(i, (w, p))| {
                        let q = match (self, p) {
                            (Param::G(_), _) if i == *c => PhaseFunction::HenyeyGreenstein { g: v },
                            (Param::Bin(_, k), PhaseFunction::Tabulated(t)) if i == *c => t
                                .with_node_value(*k, v)
                                .map(PhaseFunction::Tabulated)
                                .unwrap_or_else(|_| p.clone()),
                            (
                                Param::VmfWeight(_, l) | Param::VmfKappa(_, l),
                                PhaseFunction::VmfMixture(x),
                            ) if i == *c => {
                                let which = if matches!(self, Param::VmfWeight(..)) {
                                    crate::medium::lobes::VmfParam::Weight
                                } else {
                                    crate::medium::lobes::VmfParam::Kappa
                                };
                                x.with(*l, which, v)
                                    .map(PhaseFunction::VmfMixture)
                                    .unwrap_or_else(|_| p.clone())
                            }
                            _ => p.clone(),
                        };
                        (*w, q)
                    })
                    .collect();
                out.scattering = crate::medium::Scattering::mixture(comps);
            }
        }
        out
    }
}

/// A parameter a user fits, in natural units, each mapped to an unconstrained variable `u`
/// (constraints by reparameterisation: `mfp, σ = e^u`, `albedo = 1/(1+e^{-u})`, `g = tanh u`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitParam {
    Mfp,
    Albedo,
    G,
    SigmaS,
    SigmaA,
}

impl FitParam {
    pub fn parse(s: &str) -> crate::Result<FitParam> {
        match s.trim() {
            "mfp" => Ok(FitParam::Mfp),
            "albedo" => Ok(FitParam::Albedo),
            "g" => Ok(FitParam::G),
            "sigma_s" => Ok(FitParam::SigmaS),
            "sigma_a" => Ok(FitParam::SigmaA),
            other => Err(format!(
                "--fit: unknown parameter {other:?}; allowed: mfp, albedo, g, sigma_s, sigma_a"
            )
            .into()),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            FitParam::Mfp => "mfp",
            FitParam::Albedo => "albedo",
            FitParam::G => "g",
            FitParam::SigmaS => "sigma_s",
            FitParam::SigmaA => "sigma_a",
        }
    }

    /// Natural value in medium `m`.
    pub fn value(&self, m: &Medium) -> f64 {
        match self {
            FitParam::Mfp => 1.0 / m.sigma_t(),
            FitParam::Albedo => m.albedo(),
            FitParam::G => Param::G(0).get(m).unwrap_or(0.0),
            FitParam::SigmaS => m.sigma_s,
            FitParam::SigmaA => m.sigma_a,
        }
    }

    pub fn unconstrained(self, v: f64) -> f64 {
        match self {
            FitParam::Albedo => {
                let a = v.clamp(1e-6, 1.0 - 1e-6);
                (a / (1.0 - a)).ln()
            }
            FitParam::G => v.clamp(-0.999, 0.999).atanh(),
            FitParam::SigmaA => v.max(1e-12).ln(),
            _ => v.ln(),
        }
    }

    pub fn natural(self, u: f64) -> f64 {
        match self {
            FitParam::Albedo => 1.0 / (1.0 + (-u).exp()),
            FitParam::G => u.tanh(),
            _ => u.exp(),
        }
    }

    /// `d(natural)/du`.
    pub fn dv_du(&self, v: f64) -> f64 {
        match self {
            FitParam::Albedo => v * (1.0 - v),
            FitParam::G => 1.0 - v * v,
            _ => v,
        }
    }
}

/// Check a parameter set against a medium.
pub fn check_params(params: &[FitParam], m: &Medium) -> crate::Result<()> {
    let has = |p| params.contains(&p);
    if (has(FitParam::Mfp) || has(FitParam::Albedo))
        && (has(FitParam::SigmaS) || has(FitParam::SigmaA))
    {
        return Err("--fit: use either mfp/albedo or sigma_s/sigma_a, not both".into());
    }
    if has(FitParam::G) {
        match m.scattering.components() {
            [(_, PhaseFunction::HenyeyGreenstein { .. })] => {}
            _ => return Err("--fit g needs medium.phase = { kind = \"hg\", g = ... } (a single Henyey–Greenstein type)".into()),
        }
    }
    if has(FitParam::SigmaA) && m.sigma_a <= 0.0 {
        return Err(
            "--fit sigma_a: start from medium.sigma_a > 0 (it is fitted on a log scale)".into(),
        );
    }
    for (i, p) in params.iter().enumerate() {
        if params[..i].contains(p) {
            return Err(format!("--fit: {} is given twice", p.name()).into());
        }
    }
    Ok(())
}

/// The medium with the fitted parameters set to natural values `v`.
pub fn medium_with(base: &Medium, params: &[FitParam], v: &[f64]) -> Medium {
    let get = |p: FitParam| params.iter().position(|q| *q == p).map(|i| v[i]);
    let mut m = base.clone();
    if get(FitParam::Mfp).is_some() || get(FitParam::Albedo).is_some() {
        let mfp = get(FitParam::Mfp).unwrap_or(1.0 / base.sigma_t());
        let a = get(FitParam::Albedo).unwrap_or(base.albedo());
        (m.sigma_s, m.sigma_a) = sigmas(mfp, a);
    }
    if let Some(s) = get(FitParam::SigmaS) {
        m.sigma_s = s;
    }
    if let Some(s) = get(FitParam::SigmaA) {
        m.sigma_a = s;
    }
    if let Some(g) = get(FitParam::G) {
        m = Param::G(0).set(&m, g);
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bulk phase function's log-derivative against central differences of `ln ρ(μ)` of a
    /// two-type mixture, for a type's `g` and share (the shares renormalised).
    #[test]
    fn a_mixtures_log_derivative_is_its_difference_quotient() {
        use crate::medium::Scattering;
        let mixture = |g1: f64, w0: f64| {
            Scattering::mixture(vec![
                (w0, PhaseFunction::HenyeyGreenstein { g: 0.3 }),
                (0.6, PhaseFunction::HenyeyGreenstein { g: g1 }),
            ])
        };
        let s = mixture(0.8, 0.4);
        let h = 1e-6;
        for mu in [-0.9, -0.2, 0.4, 0.95] {
            let log = |s: &Scattering| s.eval(mu).ln();
            let fd_g = (log(&mixture(0.8 + h, 0.4)) - log(&mixture(0.8 - h, 0.4))) / (2.0 * h);
            let fd_w = (log(&mixture(0.8, 0.4 + h)) - log(&mixture(0.8, 0.4 - h))) / (2.0 * h);
            let (d_g, d_w) = (
                Param::G(1).dlog_mixture(&s, mu),
                Param::Weight(0).dlog_mixture(&s, mu),
            );
            assert!(
                (d_g - fd_g).abs() < 1e-7 * fd_g.abs().max(1.0),
                "μ {mu}: g {d_g} vs {fd_g}"
            );
            assert!(
                (d_w - fd_w).abs() < 1e-7 * fd_w.abs().max(1.0),
                "μ {mu}: share {d_w} vs {fd_w}"
            );
            assert_eq!(Param::SigmaS.dlog_mixture(&s, mu), 0.0);
            assert_ne!(Param::G(0).dlog_mixture(&s, mu), 0.0);
        }
    }

    #[test]
    fn parameter_names_parse_back() {
        for p in [
            Param::SigmaS,
            Param::SigmaA,
            Param::G(0),
            Param::G(2),
            Param::Bin(0, 7),
            Param::Bin(1, 3),
            Param::Weight(1),
            Param::VmfWeight(0, 2),
            Param::VmfWeight(1, 0),
            Param::VmfKappa(0, 1),
            Param::VmfKappa(2, 4),
        ] {
            assert_eq!(Param::parse(&p.name()).unwrap(), p, "{}", p.name());
        }
        assert_eq!(Param::parse(" bin[4] ").unwrap(), Param::Bin(0, 4));
        for bad in [
            "mfp",
            "g[",
            "g[x]",
            "g[1]x",
            "bin",
            "sigma_s[0]",
            "weight",
            "",
        ] {
            let e = Param::parse(bad).unwrap_err().to_string();
            assert!(e.contains("is not a parameter; allowed"), "{bad}: {e}");
        }
    }

    /// The Jacobian of the (mfp, albedo) → (σ_s, σ_a) map against central differences; would catch
    /// a sign or a swapped column in the fit's chain rule.
    #[test]
    fn sigmas_jacobian_matches_finite_differences() {
        let (mfp, a, h) = (3.7, 0.83, 1e-6);
        let j = sigmas_jacobian(mfp, a);
        let d_mfp = |k: usize| {
            let (p, m) = (sigmas(mfp + h, a), sigmas(mfp - h, a));
            ([p.0, p.1][k] - [m.0, m.1][k]) / (2.0 * h)
        };
        let d_a = |k: usize| {
            let (p, m) = (sigmas(mfp, a + h), sigmas(mfp, a - h));
            ([p.0, p.1][k] - [m.0, m.1][k]) / (2.0 * h)
        };
        for (k, row) in j.iter().enumerate() {
            assert!((row[0] - d_mfp(k)).abs() < 1e-8, "row {k} mfp");
            assert!((row[1] - d_a(k)).abs() < 1e-8, "row {k} albedo");
        }
        let (s, t) = sigmas(mfp, a);
        assert!((s + t - 1.0 / mfp).abs() < 1e-15 && (s / (s + t) - a).abs() < 1e-15);
    }
}
