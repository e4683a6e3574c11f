//! Spectral rendering: dispersive indices, the wavelengths photons carry, and their colour.
//!
//! Paper 002 renders its dispersive spheres (Sec. 7.1, Fig. 10) as a hyperspectral cube turned
//! into RGB. Here every photon draws its own vacuum wavelength from the light's spectrum, meets the
//! index field at that wavelength, and adds to each image channel with the weight of its colour, so
//! one run gives the RGB images (each channel white-balanced to the light: a wavelength-independent
//! scene reads the same in all three) while every scalar result stays a fraction of the emitted
//! power.
//!
//! The field is given at a reference wavelength and mapped to the photon's affinely,
//! `n(x, λ) = a(λ) + b(λ) n(x, λ_ref)`: one material scales it by `n_m(λ)/n_m(λ_ref)`; two
//! materials mixed in place (paper 002's crown/flint spheres) keep at every point the mixing ratio
//! the reference field gives it.

use crate::eikonal::{BoundedField, MAX_PARTS};

/// A dispersion formula (wavelength in micrometres, as glass catalogues give them).
#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    /// `n = a + b/λ² + c/λ⁴` (`b` in µm², `c` in µm⁴).
    Cauchy { a: f64, b: f64, c: f64 },
    /// `n² = 1 + Σ_i B_i λ² / (λ² − C_i)` (`C_i` in µm²).
    Sellmeier { terms: Vec<(f64, f64)> },
}

impl Material {
    /// A glass from the catalogue by name: `bk7` (Schott N-BK7, n_d = 1.5168), `f2` (Schott F2,
    /// n_d = 1.6200) or `fused_silica` (Malitson 1965, n_d = 1.4585).
    pub fn named(name: &str) -> Option<Material> {
        let terms = match name {
            "bk7" => vec![
                (1.03961212, 0.00600069867),
                (0.231792344, 0.0200179144),
                (1.01046945, 103.560653),
            ],
            "f2" => vec![
                (1.34533359, 0.00997743871),
                (0.209073176, 0.0470450767),
                (0.937357162, 111.886764),
            ],
            "fused_silica" => vec![
                (0.6961663, 0.0684043f64.powi(2)),
                (0.4079426, 0.1162414f64.powi(2)),
                (0.8974794, 9.896161f64.powi(2)),
            ],
            _ => return None,
        };
        Some(Material::Sellmeier { terms })
    }

    /// The catalogue's names.
    pub const NAMES: [&'static str; 3] = ["bk7", "f2", "fused_silica"];

    /// The index at vacuum wavelength `lambda_nm` (NaN where the formula has no real index).
    pub fn index(&self, lambda_nm: f64) -> f64 {
        let l2 = (lambda_nm * 1e-3).powi(2);
        match self {
            Material::Cauchy { a, b, c } => a + b / l2 + c / (l2 * l2),
            Material::Sellmeier { terms } => {
                let n2 = 1.0 + terms.iter().map(|(b, c)| b * l2 / (l2 - c)).sum::<f64>();
                n2.sqrt()
            }
        }
    }
}

/// How the index inside the volume depends on wavelength.
#[derive(Clone, Debug, PartialEq)]
pub enum Dispersion {
    /// One material: `n(x, λ) = n(x, λ_ref) · n_m(λ) / n_m(λ_ref)`.
    Scaled(Material),
    /// Two materials mixed in place: where the reference field is `t n_1 + (1 − t) n_2` (at
    /// `λ_ref`), the index at `λ` is `t n_1(λ) + (1 − t) n_2(λ)`.
    Mixed(Material, Material),
}

impl Dispersion {
    /// `(b, a)` of `n(x, λ) = a + b n(x, λ_ref)`.
    pub fn affine(&self, lambda_nm: f64, reference_nm: f64) -> (f64, f64) {
        match self {
            Dispersion::Scaled(m) => (m.index(lambda_nm) / m.index(reference_nm), 0.0),
            Dispersion::Mixed(m1, m2) => {
                let (n1, n2) = (m1.index(lambda_nm), m2.index(lambda_nm));
                let (r1, r2) = (m1.index(reference_nm), m2.index(reference_nm));
                let b = (n1 - n2) / (r1 - r2);
                (b, n2 - b * r2)
            }
        }
    }
}

/// How a photon's time of flight follows from its optical path: a pulse travels at the group
/// velocity, so its delay (times `c`) is `∫ n_g ds` with `n_g = n − λ dn/dλ`. With the affine map
/// `n = a + b n_ref`, `n_g = α n + β` inside (`α = 1 − λ b'/b`, `β = λ (a b'/b − a')`), and
/// `n_g = γ n` outside; without dispersion `α = γ = 1`, `β = 0`. A volume of several parts
/// (volumes of their own materials) has an `(α, β)` per part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Delay {
    /// `(α, β)` inside the volume (entry 0), or inside each part of a volume of several.
    inside: [(f64, f64); MAX_PARTS],
    pub gamma: f64,
}

impl Delay {
    /// No dispersion: the delay is the optical path.
    pub const NONE: Delay = Delay {
        inside: [(1.0, 0.0); MAX_PARTS],
        gamma: 1.0,
    };

    /// The group path of a stretch inside `part` (0 for a volume of one) of optical path
    /// `optical_path` and geometric `length`.
    #[inline]
    pub fn inside(&self, part: usize, optical_path: f64, length: f64) -> f64 {
        let (alpha, beta) = self.inside[part];
        alpha * optical_path + beta * length
    }

    /// The group path of a straight stretch outside of optical path `optical_path`.
    #[inline]
    pub fn outside(&self, optical_path: f64) -> f64 {
        self.gamma * optical_path
    }
}

/// The light's spectrum and the scene's dispersion.
#[derive(Clone, Debug, PartialEq)]
pub struct Spectrum {
    /// The light is white (equal energy per wavelength) over `[lo, hi]` nm; `lo == hi`: one line,
    /// and images keep one channel.
    pub range_nm: [f64; 2],
    /// The wavelength at which the scene's field (and `n_out`) are given.
    pub reference_nm: f64,
    /// The dispersion inside: of the volume (one entry), or of each part of a volume of several
    /// (`None`: the index is the same at every wavelength).
    inside: Vec<Option<Dispersion>>,
    pub outside: Option<Material>,
    /// The mean linear-sRGB response over the range, for the white balance.
    white: [f64; 3],
}

impl Spectrum {
    pub fn new(
        range_nm: [f64; 2],
        reference_nm: f64,
        inside: Option<Dispersion>,
        outside: Option<Material>,
    ) -> Self {
        let [lo, hi] = range_nm;
        // midpoint rule at ~0.1 nm: the colour matching functions are smooth on that scale
        let nodes = (((hi - lo) * 10.0).ceil() as usize).max(1);
        let mut white = [0.0; 3];
        for k in 0..nodes {
            let rgb = linear_srgb(lo + (hi - lo) * (k as f64 + 0.5) / nodes as f64);
            for c in 0..3 {
                white[c] += rgb[c] / nodes as f64;
            }
        }
        Spectrum {
            range_nm,
            reference_nm,
            inside: vec![inside],
            outside,
            white,
        }
    }

    /// The spectrum with a dispersion for each part of a volume of several (at most
    /// [`MAX_PARTS`]), in place of the one volume's.
    pub fn with_parts(self, parts: Vec<Option<Dispersion>>) -> Self {
        assert!(parts.len() <= MAX_PARTS);
        Spectrum {
            inside: parts,
            ..self
        }
    }

    /// Colour channels of the images: 3 (linear sRGB) for white light, 1 for a single line.
    pub fn channels(&self) -> usize {
        if self.range_nm[0] < self.range_nm[1] {
            3
        } else {
            1
        }
    }

    /// A wavelength (nm) drawn from the light's spectrum with uniform `u`.
    pub fn sample(&self, u: f64) -> f64 {
        let [lo, hi] = self.range_nm;
        lo + (hi - lo) * u
    }

    /// The weights of a photon of wavelength `lambda_nm` in the R, G, B channels: its linear-sRGB
    /// response over the light's mean response, so each has mean 1 over the spectrum.
    pub fn colour(&self, lambda_nm: f64) -> [f64; 3] {
        if self.channels() == 1 {
            return [1.0; 3];
        }
        let rgb = linear_srgb(lambda_nm);
        [0, 1, 2].map(|c| rgb[c] / self.white[c])
    }

    /// The group-delay factors at `lambda_nm` (derivatives by central differences over ±0.01 nm:
    /// the formulas are smooth on that scale).
    pub fn delay(&self, lambda_nm: f64) -> Delay {
        let h = 0.01;
        let l = lambda_nm;
        let group = |d: &Option<Dispersion>| match d {
            None => (1.0, 0.0),
            Some(d) => {
                let (b, a) = d.affine(l, self.reference_nm);
                let (bp, ap) = d.affine(l + h, self.reference_nm);
                let (bm, am) = d.affine(l - h, self.reference_nm);
                let (db, da) = ((bp - bm) / (2.0 * h), (ap - am) / (2.0 * h));
                (1.0 - l * db / b, l * (a * db / b - da))
            }
        };
        let mut inside = Delay::NONE.inside;
        for (k, d) in self.inside.iter().enumerate() {
            inside[k] = group(d);
        }
        let gamma = match &self.outside {
            None => 1.0,
            Some(m) => 1.0 - l * (m.index(l + h) - m.index(l - h)) / (2.0 * h) / m.index(l),
        };
        Delay { inside, gamma }
    }

    /// Set `field` to `base` (given at the reference wavelength) at wavelength `lambda_nm`: the
    /// field's map, or each part's.
    pub fn disperse(&self, field: &mut BoundedField, base: &BoundedField, lambda_nm: f64) {
        let map = |d: &Option<Dispersion>| match d {
            Some(d) => d.affine(lambda_nm, self.reference_nm),
            None => (1.0, 0.0),
        };
        if field.bounds.parts().is_some() {
            field.change_parts(|k, p| (p.scale, p.offset) = map(&self.inside[k]));
        } else {
            (field.scale, field.offset) = map(&self.inside[0]);
        }
        field.n_out = match &self.outside {
            Some(m) => base.n_out * m.index(lambda_nm) / m.index(self.reference_nm),
            None => base.n_out,
        };
    }
}

/// The CIE 1931 2° colour matching functions `(x̄, ȳ, z̄)` at `lambda_nm`, by the multi-lobe
/// piecewise-Gaussian fit of Wyman, Sloan and Shirley (2013), within 0.01 of the tabulated values.
pub fn cie_xyz(lambda_nm: f64) -> [f64; 3] {
    let g = |mu: f64, s1: f64, s2: f64| {
        let t = (lambda_nm - mu) / if lambda_nm < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    };
    [
        1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2),
        0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1),
        1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8),
    ]
}

/// Linear sRGB (D65 primaries) of unit power at `lambda_nm`: the colour matching functions
/// through the XYZ → sRGB matrix (negative outside the sRGB gamut, as spectral colours are).
pub fn linear_srgb(lambda_nm: f64) -> [f64; 3] {
    let [x, y, z] = cie_xyz(lambda_nm);
    [
        3.2404542 * x - 1.5371385 * y - 0.4985314 * z,
        -0.9692660 * x + 1.8760108 * y + 0.0415560 * z,
        0.0556434 * x - 0.2040259 * y + 1.0572252 * z,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The catalogue glasses against their data sheets' d-line index and Abbe number
    /// `V_d = (n_d − 1)/(n_F − n_C)`.
    #[test]
    fn glasses_match_their_data_sheets() {
        for (name, nd, vd) in [
            ("bk7", 1.5168, 64.17),
            ("f2", 1.62004, 36.37),
            ("fused_silica", 1.4585, 67.8),
        ] {
            let m = Material::named(name).unwrap();
            let n = |l: f64| m.index(l);
            let (d, f, c) = (n(587.5618), n(486.1327), n(656.2725));
            assert!((d - nd).abs() < 1e-4, "{name}: n_d {d} vs {nd}");
            let v = (d - 1.0) / (f - c);
            assert!((v - vd).abs() < 0.1, "{name}: V_d {v} vs {vd}");
        }
        // N-BK7 at 550 nm: 1.51852
        let bk7 = Material::named("bk7").unwrap();
        assert!((bk7.index(550.0) - 1.518522).abs() < 1e-6);
    }

    /// The colour matching functions against the CIE 1931 table, and equal-energy white has
    /// X = Y = Z (each integral 106.86 nm over 360–830 nm).
    #[test]
    fn colour_matching_functions_match_the_cie_table() {
        for (l, table) in [
            (450.0, [0.3362, 0.0380, 1.77211]),
            (500.0, [0.0049, 0.3230, 0.2720]),
            (550.0, [0.4334, 0.9950, 0.0087]),
            (600.0, [1.0622, 0.6310, 0.0008]),
            (650.0, [0.2835, 0.1070, 0.0]),
        ] {
            let f = cie_xyz(l);
            for c in 0..3 {
                assert!((f[c] - table[c]).abs() < 0.01, "{l} nm [{c}]: {f:?}");
            }
        }
        let mut sum = [0.0; 3];
        for l in 360..=830 {
            let f = cie_xyz(l as f64);
            for c in 0..3 {
                sum[c] += f[c];
            }
        }
        for s in sum {
            assert!((s - 106.86).abs() < 0.15, "{sum:?}");
        }
    }

    /// The white balance: the colour weights average to 1 in each channel over the spectrum, and
    /// a single line keeps one channel of weight 1.
    #[test]
    fn colour_weights_average_to_one() {
        let s = Spectrum::new([380.0, 780.0], 587.6, None, None);
        assert_eq!(s.channels(), 3);
        let n = 40_000;
        let mut mean = [0.0; 3];
        for k in 0..n {
            let c = s.colour(s.sample((k as f64 + 0.5) / n as f64));
            for i in 0..3 {
                mean[i] += c[i] / n as f64;
            }
        }
        for m in mean {
            assert!((m - 1.0).abs() < 1e-6, "{mean:?}");
        }
        // blue light is blue, red is red
        let b = s.colour(450.0);
        let r = s.colour(650.0);
        assert!(b[2] > b[0] && b[2] > b[1] && r[0] > r[1] && r[0] > r[2]);
        let line = Spectrum::new([532.0, 532.0], 587.6, None, None);
        assert_eq!((line.channels(), line.colour(532.0)), (1, [1.0; 3]));
    }

    /// The group factors turn the affine map's index into `n − λ dn/dλ` of the materials, inside
    /// (one glass, and a mixture at its mixing ratio) and outside.
    #[test]
    fn delays_are_group_indices() {
        let (crown, flint) = (
            Material::named("bk7").unwrap(),
            Material::named("f2").unwrap(),
        );
        let group = |m: &Material, l: f64| {
            let h = 1e-3;
            m.index(l) - l * (m.index(l + h) - m.index(l - h)) / (2.0 * h)
        };
        let r = 587.56;
        let l = 450.0;
        let s = Spectrum::new(
            [l, l],
            r,
            Some(Dispersion::Mixed(crown.clone(), flint.clone())),
            Some(flint.clone()),
        );
        let d = s.delay(l);
        for t in [0.0, 0.4, 1.0] {
            let n = t * crown.index(l) + (1.0 - t) * flint.index(l);
            let want = t * group(&crown, l) + (1.0 - t) * group(&flint, l);
            // n_g = α n + β per unit length
            assert!((d.inside(0, n, 1.0) - want).abs() < 1e-6, "t = {t}");
        }
        assert!((d.outside(flint.index(l)) - group(&flint, l)).abs() < 1e-6);
        // normal dispersion: the group index exceeds the index
        assert!(group(&crown, l) > crown.index(l) + 0.03);
    }

    /// The affine maps reproduce their materials: one material everywhere its own index; a
    /// mixture at its two pure ends and at the mixing ratio in between.
    #[test]
    fn dispersion_maps_reproduce_the_materials() {
        let (crown, flint) = (
            Material::named("bk7").unwrap(),
            Material::named("f2").unwrap(),
        );
        let r = 587.6;
        for l in [400.0, 486.1, 656.3, 750.0] {
            let (b, a) = Dispersion::Scaled(crown.clone()).affine(l, r);
            assert!((a + b * crown.index(r) - crown.index(l)).abs() < 1e-12);
            let (b, a) = Dispersion::Mixed(crown.clone(), flint.clone()).affine(l, r);
            let at = |t: f64| a + b * (t * crown.index(r) + (1.0 - t) * flint.index(r));
            let want = |t: f64| t * crown.index(l) + (1.0 - t) * flint.index(l);
            for t in [0.0, 0.3, 1.0] {
                assert!((at(t) - want(t)).abs() < 1e-12, "{l} nm, t = {t}");
            }
        }
    }
}
