//! The phase function read from speckle images (Alterman, Bar, Gkioulekas, Levin 2022 — "paper
//! 004"): a slab in a 4f relay, two illuminations `Δ` apart, one camera in the Fourier plane.
//!
//! - Windowed empirical correlation (Eq. 4): for a window `W` of `N` pixels at `i¹ + τ` in the first
//!   image and `i¹ + τ + Δ` in the second, `C(τ) = ⟨I¹ I²⟩_W − ⟨I¹⟩_W ⟨I²⟩_W`.
//! - `τ` runs along the line through the first illumination perpendicular to `Δ` (Eq. 6), where the
//!   single-scattering correlation is `C = (ρ(|τ|) L σ_s e^{−σ_t L})²` with no sinc loss (Claim 1,
//!   Eq. 3): `ρ ∝ √C`. Windows touching the ballistic peaks are masked.
//! - Error bars from the SNR model (Eq. 5 and App. C): `sd(C) = √(Var X / N_eff)`, with
//!   `N_eff = N / A_c` independent speckles in the window, `A_c` the speckle grain area in pixels
//!   measured from the first image's intensity autocorrelation, and `X = (I¹ − Ī¹)(I² − Ī²)`. For
//!   Gaussian speckle `Var X = Ī¹²Ī²² (1 + 4r + 3r²)` with `r = C / (Ī¹Ī²)` (from the bivariate
//!   exponential moments `E[I₁ᵐI₂ⁿ] = m! n! Σ_k C(m,k) C(n,k) rᵏ`); its `r → 0` limit is Eq. 5.
//! - The normalised reading `r = C / (Ī¹Ī²)` estimates `|C12|² / (C11 C22)` (a model's quantity,
//!   free of the camera's scale). Its window means bias it: `E[C] = |C12|² (1 − a)` with `a =
//!   A_c / N` (the means share `A_c` speckles' worth of covariance), and the ratio adds `(2 + r) a`
//!   from `Var Ī / Ī² = a`, `Cov(Ī¹, Ī²) = r a Ī¹Ī²`, less `4 r a` from `Cov(X, Ī) = 2 r a Ī¹Ī²Ī`
//!   (Gaussian moments above): `E[r̂] ≈ r (1 − (3 − r) a)`, which the reading divides out. Its
//!   variance by the same expansion is `a (1 + 4r − 3r² + 2r³)`: below `Var X / (Ī¹Ī²)²`, since
//!   the means move with the product.
//! - The naive (intensity) reading is `ρ ∝ ⟨I¹⟩_W`, which is right only for single scattering.
//! - Pixels map to directions through the relay (`tan θ = r · pitch / f` in air) and into the sample
//!   by Snell's law (`n_out sin θ_out = n_sample sin θ_in`, flat parallel faces).
//!
//! Fits: Henyey–Greenstein to the correlation (`C ∝ HG²`) and to the naive reading (`I ∝ HG`), by
//! profiling the linear scale out and scanning `g` (the error from `Δχ² = 1`); vMF lobes to the
//! amplitude `√C ∝ Σ a_m e^{κ_m (μ − 1)}` (paper 000, Eq. 28) by non-negative least squares over a
//! grid of concentrations.

use glam::DVec3;

/// A grey camera image, row-major (`data[y * width + x]`); read from files by `io::images`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f64>,
    /// The largest code an integer format can hold (a pixel there is saturated); `None` for float.
    pub full_scale: Option<f64>,
}

impl Image {
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f64 {
        self.data[y * self.width + x]
    }
}

/// The relay and sample: what maps pixels to directions inside the sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Relay {
    pub focal_length: f64,
    pub pixel_pitch: f64,
    pub n_sample: f64,
    pub n_outside: f64,
    /// The optical axis on the sensor, in pixels.
    pub axis_px: [f64; 2],
}

impl Relay {
    /// The propagation direction inside the sample of the light reaching pixel `(x, y)`.
    pub fn direction(&self, x: f64, y: f64) -> DVec3 {
        let s = self.pixel_pitch / self.focal_length;
        let air = DVec3::new((x - self.axis_px[0]) * s, (y - self.axis_px[1]) * s, 1.0).normalize();
        // the lateral components are n sin θ, conserved across flat faces
        let lateral = glam::DVec2::new(air.x, air.y) * (self.n_outside / self.n_sample);
        let z = (1.0 - lateral.length_squared()).max(0.0).sqrt();
        DVec3::new(lateral.x, lateral.y, z)
    }
}

/// How the images are read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Side of the square averaging window, pixels.
    pub window: usize,
    /// Distance between readings along `τ`, pixels.
    pub step: usize,
    /// Radius of the disk masked around each ballistic peak, pixels.
    pub ballistic_radius: f64,
    /// Largest local shift of the second image's windows searched to register them (0: none).
    pub register_px: usize,
}

/// One image pair, with its ballistic peaks (the illumination directions) in pixels.
#[derive(Clone, Debug)]
pub struct Pair<'a> {
    pub first: &'a Image,
    pub second: &'a Image,
    pub peaks: [[f64; 2]; 2],
}

/// One reading at offset `t` (pixels along the line ⟂ Δ).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Reading {
    pub offset_px: f64,
    /// Scattering angle inside the sample between the first illumination and the window centre.
    pub angle_deg: f64,
    /// Eq. 4, averaged over the pairs.
    pub correlation: f64,
    /// Its standard error (Eq. 5).
    pub stderr: f64,
    /// `⟨I¹⟩_W`: the naive (intensity) reading.
    pub intensity: f64,
    /// Eq. 4 divided by the window means `⟨I¹⟩_W ⟨I²⟩_W`, averaged over the pairs: the camera's
    /// scale cancels, so a model can be fitted to it (`normalised_intensity_correlation`).
    pub normalised: f64,
    /// Its standard error, `√((1 + 4r − 3r² + 2r³) / N_eff)` per pair (module docs).
    pub normalised_stderr: f64,
    /// Pairs averaged.
    pub pairs: usize,
}

/// Readings of pairs that share one `Δ`.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    /// The first illumination's ballistic peak (of the group's first pair), pixels.
    pub first_px: [f64; 2],
    /// `Δ` in pixels (second peak minus first).
    pub delta_px: [f64; 2],
    /// The angle between the two illuminations inside the sample.
    pub delta_deg: f64,
    pub readings: Vec<Reading>,
    /// Speckle grain area, pixels (mean over the pairs).
    pub grain_px: f64,
}

/// The brightest pixel: where the ballistic light focuses.
pub fn brightest(image: &Image) -> [f64; 2] {
    let (mut best, mut at) = (f64::NEG_INFINITY, 0);
    for (i, &v) in image.data.iter().enumerate() {
        if v > best {
            (best, at) = (v, i);
        }
    }
    [(at % image.width) as f64, (at / image.width) as f64]
}

/// Speckle grain area in pixels, `Σ_δ |μ(δ)|²`: the intensity correlation coefficients at one
/// pixel's lag along x and y, `c = e^{−1/ℓ²}`, fix a Gaussian grain `|μ(δ)|² = e^{−δx²/ℓx² − δy²/ℓy²}`
/// summed over the lattice. Intensities are taken relative to their mean over a box four windows
/// wide (so the phase function's slow envelope does not count as grain), away from `avoid` (the
/// ballistic peak). At least 1 (uncorrelated pixels).
pub fn grain_area(image: &Image, window: usize, avoid: [f64; 2], radius: f64) -> f64 {
    let (w, h) = (image.width, image.height);
    let half = 2 * window.max(2);
    if w <= 2 * half + 4 || h <= 2 * half + 4 {
        return 1.0;
    }
    // summed-area table for the local means
    let mut table = vec![0.0; (w + 1) * (h + 1)];
    for y in 0..h {
        for x in 0..w {
            table[(y + 1) * (w + 1) + x + 1] =
                image.at(x, y) + table[y * (w + 1) + x + 1] + table[(y + 1) * (w + 1) + x]
                    - table[y * (w + 1) + x];
        }
    }
    let local = |x: usize, y: usize| {
        let (x0, y0, x1, y1) = (x - half, y - half, x + half + 1, y + half + 1);
        let s = table[y1 * (w + 1) + x1] - table[y0 * (w + 1) + x1] - table[y1 * (w + 1) + x0]
            + table[y0 * (w + 1) + x0];
        s / ((x1 - x0) * (y1 - y0)) as f64
    };
    let mut f = vec![f64::NAN; w * h];
    for y in half..h - half {
        for x in half..w - half {
            let m = local(x, y);
            let far = (x as f64 - avoid[0]).hypot(y as f64 - avoid[1]) > radius + 2.0;
            if m > 0.0 && far {
                f[y * w + x] = image.at(x, y) / m - 1.0;
            }
        }
    }
    let cov = |dx: usize, dy: usize| {
        let (mut s, mut c) = (0.0, 0.0);
        for y in 0..h - dy {
            for x in 0..w - dx {
                let (a, b) = (f[y * w + x], f[(y + dy) * w + x + dx]);
                if a.is_finite() && b.is_finite() {
                    s += a * b;
                    c += 1.0;
                }
            }
        }
        if c > 0.0 { s / c } else { 0.0 }
    };
    let c0 = cov(0, 0);
    if c0 <= 0.0 {
        return 1.0;
    }
    // 1/ℓ² along each axis; uncorrelated neighbours (c ≤ e^{−8}) count as no spread
    let inv = |c: f64| if c > (-8.0f64).exp() { -c.ln() } else { 8.0 };
    let (ax, ay) = (inv(cov(1, 0) / c0), inv(cov(0, 1) / c0));
    let line = |a: f64| -> f64 { (-20..=20).map(|d: i32| (-(d * d) as f64 * a).exp()).sum() };
    (line(ax) * line(ay)).max(1.0)
}

/// Why a pair cannot be read.
#[derive(Clone, Debug, PartialEq)]
pub enum PairError {
    Sizes,
    NoDisplacement,
    Saturated { image: usize, count: usize },
    NoWindows,
}

/// Pixel sums of a window read in parts: `Σ I¹`, `Σ I²`, `Σ I¹I²`, the pixel count, and the
/// saturated pixels met (per image, as `y · width + x`).
#[derive(Default)]
struct Sums {
    m1: f64,
    m2: f64,
    m12: f64,
    n: f64,
    sat: [Vec<i64>; 2],
}

impl Sums {
    /// Add the rows `rows` of the window centred at `c1` in the first image and `c2` in the
    /// second; `false` (nothing usable) where either leaves its image or touches a ballistic disk.
    fn add(
        &mut self,
        pair: &Pair,
        s: &Settings,
        c1: [i64; 2],
        c2: [i64; 2],
        rows: std::ops::Range<i64>,
    ) -> bool {
        let (a, b) = (pair.first, pair.second);
        let [p1, p2] = pair.peaks;
        let (w, half) = (s.window as i64, (s.window / 2) as i64);
        let fits = |c: [i64; 2]| {
            c[0] - half >= 0
                && c[1] - half + rows.start >= 0
                && c[0] - half + w <= a.width as i64
                && c[1] - half + rows.end <= a.height as i64
        };
        if !fits(c1) || !fits(c2) {
            return false;
        }
        let masked = |x: i64, y: i64, peak: [f64; 2]| {
            (x as f64 - peak[0]).hypot(y as f64 - peak[1]) <= s.ballistic_radius
        };
        for dy in rows {
            for dx in 0..w {
                let (x1, y1) = (c1[0] - half + dx, c1[1] - half + dy);
                let (x2, y2) = (c2[0] - half + dx, c2[1] - half + dy);
                if masked(x1, y1, p1) || masked(x2, y2, p2) || masked(x1, y1, p2) {
                    return false;
                }
                let (v1, v2) = (
                    a.at(x1 as usize, y1 as usize),
                    b.at(x2 as usize, y2 as usize),
                );
                if a.full_scale.is_some_and(|f| v1 >= f) {
                    self.sat[0].push(y1 * a.width as i64 + x1);
                }
                if b.full_scale.is_some_and(|f| v2 >= f) {
                    self.sat[1].push(y2 * b.width as i64 + x2);
                }
                self.m1 += v1;
                self.m2 += v2;
                self.m12 += v1 * v2;
                self.n += 1.0;
            }
        }
        true
    }

    /// `C / (Ī¹Ī²)` of what was added.
    fn normalised(&self) -> f64 {
        let (m1, m2) = (self.m1 / self.n, self.m2 / self.n);
        (self.m12 / self.n - m1 * m2) / (m1 * m2)
    }
}

/// The registration shift of each window half, keyed by (step index, half).
type Shifts = std::collections::BTreeMap<(i64, usize), [i64; 2]>;

/// A candidate shift and its summed normalised correlation.
type Scored = ([i64; 2], f64);

/// Registration shifts (paper 004, App. A: optics distort the pixel-to-direction map, so a window
/// of the second image can sit a few pixels from where `Δ` puts it): per step index along the line
/// and window half (top, bottom), the shift within `±register_px` that maximises the normalised
/// correlation summed over the pairs and over the windows within two window widths — chosen on
/// the *other* half, so that the maximum of noisy correlations does not read as correlation (on
/// pure noise the readings stay flat).
fn registration(pairs: &[&Pair], s: &Settings) -> Shifts {
    let r = s.register_px as i64;
    let h = (s.window as i64 / 2).max(1);
    let halves = [0..h, h..s.window as i64];
    // per (step, half, shift): the summed normalised correlation
    let mut score: std::collections::BTreeMap<(i64, usize), Vec<Scored>> = Default::default();
    for pair in pairs {
        let [p1, p2] = pair.peaks;
        let delta = [(p2[0] - p1[0]).round(), (p2[1] - p1[1]).round()];
        let norm = delta[0].hypot(delta[1]).max(1.0);
        let u = [-delta[1] / norm, delta[0] / norm];
        let reach = (pair.first.width + pair.first.height) as i64;
        for k in -reach..=reach {
            let t = k as f64 * s.step as f64;
            let c1 = [
                (p1[0] + t * u[0]).round() as i64,
                (p1[1] + t * u[1]).round() as i64,
            ];
            for (half, rows) in halves.iter().enumerate() {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let c2 = [c1[0] + delta[0] as i64 + dx, c1[1] + delta[1] as i64 + dy];
                        let mut sums = Sums::default();
                        if !sums.add(pair, s, c1, c2, rows.clone()) {
                            continue;
                        }
                        let list = score.entry((k, half)).or_default();
                        match list.iter_mut().find(|(d, _)| *d == [dx, dy]) {
                            Some((_, v)) => *v += sums.normalised(),
                            None => list.push(([dx, dy], sums.normalised())),
                        }
                    }
                }
            }
        }
    }
    let best = |list: &Vec<Scored>| {
        list.iter()
            .filter(|(_, v)| v.is_finite())
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
            .map_or([0, 0], |(d, _)| *d)
    };
    // distortion varies slowly across the image: a window's shift is chosen on the scores of its
    // neighbours within two window widths too, so weak windows borrow the strong ones' evidence
    let reach = (2 * s.window).div_ceil(s.step.max(1)) as i64;
    let mut out = std::collections::BTreeMap::new();
    for &(k, half) in score.keys() {
        // the top half's shift from the bottom half's scores, and the other way round
        let mut pooled: Vec<Scored> = Vec::new();
        for j in k - reach..=k + reach {
            for &(d, v) in score.get(&(j, 1 - half)).into_iter().flatten() {
                match pooled.iter_mut().find(|(e, _)| *e == d) {
                    Some((_, w)) => *w += v,
                    None => pooled.push((d, v)),
                }
            }
        }
        if !pooled.is_empty() {
            out.insert((k, half), best(&pooled));
        }
    }
    out
}

/// One pair's readings `(step index, Ī¹Ī², reading)` and its speckle grain area.
type PairReadings = (Vec<(i64, f64, Reading)>, f64);

/// Eq. 4 over `window`-pixel squares along the line ⟂ Δ through the first peak, for one pair.
/// Returns readings keyed by their step index along the line.
fn read_pair(
    pair: &Pair,
    relay: &Relay,
    s: &Settings,
    shift: &dyn Fn(i64, usize) -> [i64; 2],
) -> Result<PairReadings, PairError> {
    let (a, b) = (pair.first, pair.second);
    if (a.width, a.height) != (b.width, b.height) {
        return Err(PairError::Sizes);
    }
    let [p1, p2] = pair.peaks;
    let delta = [(p2[0] - p1[0]).round(), (p2[1] - p1[1]).round()];
    let norm = delta[0].hypot(delta[1]);
    if norm < 1.0 {
        return Err(PairError::NoDisplacement);
    }
    let u = [-delta[1] / norm, delta[0] / norm];
    let half = (s.window / 2) as i64;
    let i1 = relay.direction(p1[0], p1[1]);
    let grain = grain_area(a, s.window, p1, s.ballistic_radius);
    let reach = (a.width + a.height) as i64;
    let mut out = Vec::new();
    // saturated pixels inside any window read (each counted once)
    let mut saturated: [std::collections::BTreeSet<i64>; 2] = Default::default();
    for k in -reach..=reach {
        let t = k as f64 * s.step as f64;
        let c1 = [
            (p1[0] + t * u[0]).round() as i64,
            (p1[1] + t * u[1]).round() as i64,
        ];
        let c2 = [c1[0] + delta[0] as i64, c1[1] + delta[1] as i64];
        let inside = |c: [i64; 2]| {
            c[0] - half >= 0
                && c[1] - half >= 0
                && c[0] - half + (s.window as i64) <= a.width as i64
                && c[1] - half + (s.window as i64) <= a.height as i64
        };
        if !inside(c1) || !inside(c2) {
            continue;
        }
        // the window's two halves, each against the second image at its registration shift
        let h = half.max(1);
        let mut sums = Sums::default();
        let read = [(0..h, shift(k, 0)), (h..s.window as i64, shift(k, 1))]
            .into_iter()
            .all(|(rows, d)| sums.add(pair, s, c1, [c2[0] + d[0], c2[1] + d[1]], rows));
        if !read {
            continue;
        }
        let Sums {
            m1,
            m2,
            m12,
            n,
            sat,
        } = sums;
        saturated[0].extend(&sat[0]);
        saturated[1].extend(&sat[1]);
        let (m1, m2) = (m1 / n, m2 / n);
        let c = m12 / n - m1 * m2;
        // the variance without correlation, (Ī¹Ī²)² / N_eff; read_curves adds the r terms from the
        // pooled correlation (weights must not depend on each pair's noisy C)
        let var = (m1 * m2).powi(2) / (n / grain);
        let v = relay.direction(c1[0] as f64, c1[1] as f64);
        out.push((
            k,
            m1 * m2,
            Reading {
                offset_px: t,
                angle_deg: i1.dot(v).clamp(-1.0, 1.0).acos().to_degrees(),
                correlation: c,
                stderr: var.sqrt(),
                intensity: m1,
                normalised: if m1 * m2 > 0.0 { c / (m1 * m2) } else { 0.0 },
                normalised_stderr: (grain / n).sqrt(),
                pairs: 1,
            },
        ));
    }
    for (image, set) in saturated.iter().enumerate() {
        if !set.is_empty() {
            return Err(PairError::Saturated {
                image,
                count: set.len(),
            });
        }
    }
    if out.is_empty() {
        return Err(PairError::NoWindows);
    }
    Ok((out, grain))
}

/// The mean of column `value` of the pairs' parts with weights `1 / part[var]`, and its variance
/// `Σ w² part[var] factor(mean, part) / (Σ w)²`.
fn pooled(
    parts: &[[f64; 6]],
    value: usize,
    var: usize,
    factor: impl Fn(f64, &[f64; 6]) -> f64,
) -> (f64, f64) {
    let w: Vec<f64> = parts
        .iter()
        .map(|p| 1.0 / p[var].max(f64::MIN_POSITIVE))
        .collect();
    let total: f64 = w.iter().sum();
    let mean = parts.iter().zip(&w).map(|(p, w)| w * p[value]).sum::<f64>() / total;
    let spread = parts
        .iter()
        .zip(&w)
        .map(|(p, w)| w * w * p[var] * factor(mean, p))
        .sum::<f64>()
        / (total * total);
    (mean, spread)
}

/// Read every pair and average the pairs that share a `Δ` (within a pixel), reading by reading
/// (inverse-variance weights). Errors name the pair by its index.
pub fn read_curves(
    pairs: &[Pair],
    relay: &Relay,
    s: &Settings,
) -> Result<Vec<Curve>, (usize, PairError)> {
    struct Group {
        delta: [f64; 2],
        /// The first illumination's peak in the group's first pair.
        first: [f64; 2],
        /// per step index: the first pair's reading, and every pair's (C, Var₀, Ī¹Ī², Ī¹, C/Ī¹Ī²,
        /// Var₀/(Ī¹Ī²)²)
        sums: std::collections::BTreeMap<i64, (Reading, Vec<[f64; 6]>)>,
        grain: f64,
        count: usize,
    }
    let displacement = |p: &Pair| {
        [
            (p.peaks[1][0] - p.peaks[0][0]).round(),
            (p.peaks[1][1] - p.peaks[0][1]).round(),
        ]
    };
    let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() <= 1.0 && (a[1] - b[1]).abs() <= 1.0;
    // registration shifts per group of pairs (the first pair's Δ stands for the group)
    let mut registered: Vec<([f64; 2], Shifts)> = Vec::new();
    if s.register_px > 0 {
        for p in pairs {
            let d = displacement(p);
            if !registered.iter().any(|(g, _)| near(*g, d)) {
                let members: Vec<&Pair> =
                    pairs.iter().filter(|q| near(displacement(q), d)).collect();
                registered.push((d, registration(&members, s)));
            }
        }
    }
    let mut groups: Vec<Group> = Vec::new();
    for (i, p) in pairs.iter().enumerate() {
        let d = displacement(p);
        let shifts = registered.iter().find(|(g, _)| near(*g, d)).map(|(_, m)| m);
        let shift = |k: i64, half: usize| {
            shifts
                .and_then(|m| m.get(&(k, half)).copied())
                .unwrap_or([0, 0])
        };
        let (readings, grain) = read_pair(p, relay, s, &shift).map_err(|e| (i, e))?;
        let g = match groups.iter_mut().position(|g| near(g.delta, d)) {
            Some(g) => g,
            None => {
                groups.push(Group {
                    delta: d,
                    first: p.peaks[0],
                    sums: Default::default(),
                    grain: 0.0,
                    count: 0,
                });
                groups.len() - 1
            }
        };
        let g = &mut groups[g];
        g.grain += grain;
        g.count += 1;
        for (k, product, r) in readings {
            let e = g.sums.entry(k).or_insert((r, Vec::new()));
            e.1.push([
                r.correlation,
                r.stderr * r.stderr,
                product,
                r.intensity,
                r.normalised,
                r.normalised_stderr.powi(2),
            ]);
        }
    }
    Ok(groups
        .into_iter()
        .map(|g| {
            let first = g.first;
            // the window's own means bias C / Ī¹Ī² by −(3 − r) A_c/N to first order (module docs)
            let grain = g.grain / g.count as f64;
            let a = grain / (s.window * s.window) as f64;
            let i1 = relay.direction(first[0], first[1]);
            let i2 = relay.direction(first[0] + g.delta[0], first[1] + g.delta[1]);
            Curve {
                first_px: first,
                delta_px: g.delta,
                delta_deg: i1.dot(i2).clamp(-1.0, 1.0).acos().to_degrees(),
                readings: g
                    .sums
                    .into_values()
                    .map(|(mut r, parts)| {
                        // weights 1/Var₀; then Var X = Var₀ (1 + 4r + 3r²) with the pooled C
                        // (Gaussian speckle, module docs)
                        let (c, var) = pooled(&parts, 0, 1, |c, p| {
                            let r = (c / p[2]).clamp(0.0, 1.0);
                            1.0 + 4.0 * r + 3.0 * r * r
                        });
                        r.correlation = c;
                        r.stderr = var.sqrt();
                        // the same for C / Ī¹Ī², whose pooled value is r itself; its variance by the
                        // delta method (module docs)
                        let (x, var) = pooled(&parts, 4, 5, |x, _| {
                            let r = x.clamp(0.0, 1.0);
                            1.0 + 4.0 * r - 3.0 * r * r + 2.0 * r.powi(3)
                        });
                        let rr = x.clamp(0.0, 1.0);
                        let unbias = 1.0 / (1.0 - (3.0 - rr) * a).max(0.5);
                        r.normalised = x * unbias;
                        r.normalised_stderr = var.sqrt() * unbias;
                        r.intensity = parts.iter().map(|p| p[3]).sum::<f64>() / parts.len() as f64;
                        r.pairs = parts.len();
                        r
                    })
                    .collect(),
                grain_px: grain,
            }
        })
        .collect())
}

/// χ² of the correlations against zero, and its degrees of freedom: a flat (pure noise) reading
/// has χ²/dof ≈ 1.
pub fn flatness(c: &Curve) -> (f64, usize) {
    let chi2 = c
        .readings
        .iter()
        .map(|r| (r.correlation / r.stderr).powi(2))
        .sum();
    (chi2, c.readings.len())
}

/// Whether a curve's correlation is significant: χ² against zero above its expectation by more
/// than 5 standard deviations, `dof + 5 √(2 dof · overlap)` (overlapping windows, `overlap =
/// window / step ≥ 1`, share pixels, which widens χ²'s spread).
pub fn significant(c: &Curve, s: &Settings) -> bool {
    let (chi2, dof) = flatness(c);
    let overlap = (s.window as f64 / s.step.max(1) as f64).max(1.0);
    chi2 > dof as f64 + 5.0 * (2.0 * dof as f64 * overlap).sqrt()
}

/// Henyey–Greenstein `ρ(μ)`.
pub fn hg(g: f64, mu: f64) -> f64 {
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * mu).powf(1.5))
}

/// A fitted Henyey–Greenstein: `g`, its standard error, the scale, and `χ²/dof`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HgFit {
    pub g: f64,
    pub g_stderr: f64,
    pub scale: f64,
    pub chi2_dof: f64,
}

/// A curve's readings as `(cos θ, C, standard error)` columns.
pub fn correlation_points(c: &Curve) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mu = c.readings.iter().map(|r| r.angle_deg.to_radians().cos());
    let y = c.readings.iter().map(|r| r.correlation);
    let sd = c.readings.iter().map(|r| r.stderr);
    (mu.collect(), y.collect(), sd.collect())
}

/// The HG fit of a curve's correlations (`C ∝ HG²`, Eq. 5's errors).
pub fn fit_correlation(c: &Curve) -> Option<HgFit> {
    let (mu, y, sd) = correlation_points(c);
    fit_hg(&mu, &y, &sd, 2)
}

/// Fit `y ≈ A · HG(g, μ)^power` with standard errors `sd`: `A` profiled out, `g` scanned over
/// (−0.99, 0.999) and refined by a parabola; `g`'s error from `Δχ² = 1`.
pub fn fit_hg(mu: &[f64], y: &[f64], sd: &[f64], power: i32) -> Option<HgFit> {
    if mu.len() < 3 {
        return None;
    }
    let chi2 = |g: f64| -> (f64, f64) {
        let (mut sfy, mut sff) = (0.0, 0.0);
        for i in 0..mu.len() {
            let f = hg(g, mu[i]).powi(power);
            let w = 1.0 / (sd[i] * sd[i]);
            sfy += w * f * y[i];
            sff += w * f * f;
        }
        let a = sfy / sff;
        let c: f64 = (0..mu.len())
            .map(|i| ((y[i] - a * hg(g, mu[i]).powi(power)) / sd[i]).powi(2))
            .sum();
        (c, a)
    };
    let grid: Vec<f64> = (0..=2000)
        .map(|i| -0.99 + 1.989 * i as f64 / 2000.0)
        .collect();
    let values: Vec<f64> = grid.iter().map(|&g| chi2(g).0).collect();
    let best = (0..grid.len()).min_by(|&a, &b| values[a].total_cmp(&values[b]))?;
    // refine by golden section between the neighbours
    let (mut lo, mut hi) = (
        grid[best.saturating_sub(1)],
        grid[(best + 1).min(grid.len() - 1)],
    );
    for _ in 0..80 {
        let (m1, m2) = (lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo));
        if chi2(m1).0 < chi2(m2).0 {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let g = 0.5 * (lo + hi);
    let (c, a) = chi2(g);
    // curvature by a symmetric difference at a step that keeps g inside the range
    let h = 1e-3f64.min(0.999 - g).min(g + 0.99).max(1e-6);
    let curv = (chi2(g + h).0 - 2.0 * c + chi2(g - h).0) / (h * h);
    let g_stderr = if curv > 0.0 {
        (2.0 / curv).sqrt()
    } else {
        f64::NAN
    };
    Some(HgFit {
        g,
        g_stderr,
        scale: a,
        chi2_dof: c / (mu.len() as f64 - 2.0).max(1.0),
    })
}

/// Fitted vMF amplitude lobes: `√C ∝ Σ a_m e^{κ_m (μ − 1)}`, weights normalised to sum 1.
#[derive(Clone, Debug, PartialEq)]
pub struct VmfFit {
    pub weights: Vec<f64>,
    pub kappas: Vec<f64>,
    pub chi2_dof: f64,
}

/// Fit one and two non-negative vMF amplitude lobes to `amp ± sd` over a logarithmic grid of
/// concentrations (κ from 1 to 1e5), weights by non-negative least squares; the better by `χ²/dof`.
pub fn fit_vmf(mu: &[f64], amp: &[f64], sd: &[f64]) -> Option<VmfFit> {
    if mu.len() < 4 {
        return None;
    }
    let kappas: Vec<f64> = (0..=60)
        .map(|i| 10f64.powf(5.0 * i as f64 / 60.0))
        .collect();
    let basis = |k: f64| -> Vec<f64> { mu.iter().map(|&m| (k * (m - 1.0)).exp()).collect() };
    let lsq1 = |f: &[f64]| -> (f64, f64) {
        let (mut sfy, mut sff) = (0.0, 0.0);
        for i in 0..mu.len() {
            let w = 1.0 / (sd[i] * sd[i]);
            sfy += w * f[i] * amp[i];
            sff += w * f[i] * f[i];
        }
        let a = (sfy / sff).max(0.0);
        let c = (0..mu.len())
            .map(|i| ((amp[i] - a * f[i]) / sd[i]).powi(2))
            .sum();
        (a, c)
    };
    let bases: Vec<Vec<f64>> = kappas.iter().map(|&k| basis(k)).collect();
    let mut best: Option<(f64, Vec<f64>, Vec<f64>, usize)> = None;
    for (i, f) in bases.iter().enumerate() {
        let (a, c) = lsq1(f);
        if a > 0.0
            && best
                .as_ref()
                .is_none_or(|b| c / (mu.len() as f64 - 2.0) < b.0)
        {
            best = Some((
                c / (mu.len() as f64 - 2.0).max(1.0),
                vec![a],
                vec![kappas[i]],
                1,
            ));
        }
    }
    if mu.len() >= 6 {
        for i in 0..bases.len() {
            for j in i + 1..bases.len() {
                let (f, h) = (&bases[i], &bases[j]);
                let (mut ff, mut fh, mut hh, mut fy, mut hy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for n in 0..mu.len() {
                    let w = 1.0 / (sd[n] * sd[n]);
                    ff += w * f[n] * f[n];
                    fh += w * f[n] * h[n];
                    hh += w * h[n] * h[n];
                    fy += w * f[n] * amp[n];
                    hy += w * h[n] * amp[n];
                }
                let det = ff * hh - fh * fh;
                if det <= 1e-12 * ff * hh {
                    continue;
                }
                let (a, b) = ((fy * hh - hy * fh) / det, (hy * ff - fy * fh) / det);
                if a <= 0.0 || b <= 0.0 {
                    continue;
                }
                let c: f64 = (0..mu.len())
                    .map(|n| ((amp[n] - a * f[n] - b * h[n]) / sd[n]).powi(2))
                    .sum();
                let per = c / (mu.len() as f64 - 4.0);
                if best.as_ref().is_none_or(|b| per < b.0) {
                    best = Some((per, vec![a, b], vec![kappas[i], kappas[j]], 2));
                }
            }
        }
    }
    let (chi2_dof, weights, kappas, _) = best?;
    let total: f64 = weights.iter().sum();
    Some(VmfFit {
        weights: weights.iter().map(|w| w / total).collect(),
        kappas,
        chi2_dof,
    })
}
