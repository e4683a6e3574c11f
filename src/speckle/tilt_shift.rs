//! The tilt-shift memory effect (paper 000, Sec. 9; Osnabrugge et al. 2017): two beams focused on
//! an input plane `a`, `Δa` apart and tilted by `∓θ/2`, and a camera focused on a plane `b` a depth
//! `L` further along the axis. The correlation of the two speckle fields (Eq. 49)
//!
//! `C(Δa, Δb, θ) = Σ_τ E[u¹(τ − Δb/2) ū²(τ + Δb/2)] e^{ikτθ}`
//!
//! over a line of `τ` across the axis, with `Δa = Δb − Lθ`: the input shift that keeps the beams'
//! geometric offset (the support of Eq. 50's delta). The analytic model of Eq. 50 is
//! [`model`]. As with the correlation maps only the products `C` needs are accumulated.

use crate::math::{C64, Rng, orthonormal_basis};
use crate::mc::Estimator;
use crate::speckle::correlation_map::focused_templates;
use crate::speckle::endpoint::Lens;
use crate::speckle::paths::{EventSink, PathScratch, SubpathSampler};
use crate::speckle::{Light, Scene, View};

/// One cell of a scan: the output shift `Δb` and the relative tilt `θ` (radians); the input
/// shift is `Δa = Δb − Lθ`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    pub shift: f64,
    pub angle: f64,
    /// Index of `shift` in [`TiltShift::shifts`] (cells with the same `Δb` share their views).
    view_set: usize,
}

/// The lights and views of a tilt-shift scan. Cell `c` has lights `2c` (shifted by `−Δa/2`,
/// axis tilted by `−θ/2`) and `2c + 1` (`+Δa/2`, `+θ/2`); the views of output shift `s` are
/// `2(s·T + p)` at `τ_p − Δb/2` and `2(s·T + p) + 1` at `τ_p + Δb/2` on plane `b`.
#[derive(Clone, Debug)]
pub struct TiltShift {
    pub scene: Scene,
    pub cells: Vec<Cell>,
    /// The distinct output shifts `Δb`, along the frame's first axis across the light's axis.
    pub shifts: Vec<f64>,
    /// Positions `τ` along the frame's first axis.
    pub taus: Vec<f64>,
    /// Depth `L` of plane `b` behind plane `a` along the axis.
    pub depth: f64,
}

/// Light 0 and view 0 of a tilt-shift scan and the depth `L` of the output plane behind the
/// input plane along the light's axis (it must be positive).
fn templates(base: &Scene) -> crate::Result<(Lens, Lens, f64)> {
    let (light, view) = focused_templates(
        base,
        "tilt-shift",
        " (on the input plane)",
        " (on the output plane)",
    )?;
    let depth = (view.focus - light.focus).dot(light.axis);
    if depth.is_nan() || depth <= 0.0 {
        return Err(format!(
            "tilt-shift: view[0] must be focused behind light[0] along its axis (depth {depth})"
        )
        .into());
    }
    Ok((light, view, depth))
}

impl TiltShift {
    /// The depth `L` of `base`'s output plane behind its input plane.
    pub fn depth_of(base: &Scene) -> crate::Result<f64> {
        Ok(templates(base)?.2)
    }

    /// From light 0 (focused: plane `a`, axis, aperture) and view 0 (focused: plane `b`, aperture)
    /// of `base`, cells `(Δb, θ)` (θ in radians) and `taus` positions over `tau_width`.
    pub fn new(
        base: &Scene,
        cells: &[(f64, f64)],
        tau_width: f64,
        taus: usize,
    ) -> crate::Result<Self> {
        let (light, view, depth) = templates(base)?;
        let (focus, axis, gamma) = (light.focus, light.axis, light.gamma);
        let (view_axis, view_gamma) = (view.axis, view.gamma);
        let (across, _) = orthonormal_basis(axis);
        // the view's focus projected on the light's axis: the scan is about the beam's centre line
        let centre = focus + axis * depth;
        let taus: Vec<f64> = (0..taus)
            .map(|p| {
                if taus > 1 {
                    tau_width * (p as f64 / (taus - 1) as f64 - 0.5)
                } else {
                    0.0
                }
            })
            .collect();
        let tilt = |angle: f64| {
            let (s, c) = angle.sin_cos();
            (axis * c + across * s).normalize()
        };
        let mut shifts: Vec<f64> = Vec::new();
        let mut out = Vec::with_capacity(cells.len());
        let mut lights = Vec::with_capacity(2 * cells.len());
        for &(db, theta) in cells {
            let view_set = match shifts.iter().position(|s| *s == db) {
                Some(i) => i,
                None => {
                    shifts.push(db);
                    shifts.len() - 1
                }
            };
            out.push(Cell {
                shift: db,
                angle: theta,
                view_set,
            });
            let da = db - depth * theta;
            for sign in [-1.0, 1.0] {
                lights.push(Light::Focused {
                    focus: focus + across * (0.5 * sign * da),
                    axis: tilt(0.5 * sign * theta),
                    gamma,
                });
            }
        }
        let mut views = Vec::new();
        for &db in &shifts {
            for &t in &taus {
                for sign in [-1.0, 1.0] {
                    views.push(View::Focused {
                        focus: centre + across * (t + 0.5 * sign * db),
                        axis: view_axis,
                        gamma: view_gamma,
                    });
                }
            }
        }
        Ok(TiltShift {
            scene: Scene {
                lights,
                views,
                ..base.clone()
            },
            cells: out,
            shifts,
            taus,
            depth,
        })
    }

    /// The (light, view) pairs, cell by cell and `τ` by `τ`: `(2c, 2(s·T + p))` then
    /// `(2c + 1, 2(s·T + p) + 1)`, `s` the cell's output shift.
    pub fn pairs(&self) -> Vec<(usize, usize)> {
        let t = self.taus.len();
        let mut out = Vec::with_capacity(2 * self.cells.len() * t);
        for (c, cell) in self.cells.iter().enumerate() {
            for p in 0..t {
                let v = 2 * (cell.view_set * t + p);
                out.push((2 * c, v));
                out.push((2 * c + 1, v + 1));
            }
        }
        out
    }

    /// The input shift `Δa = Δb − Lθ` of a cell.
    pub fn input_shift(&self, c: &Cell) -> f64 {
        c.shift - self.depth * c.angle
    }
}

/// Eq. 50 on its support: `exp(−(L³k²/(2ℓ_tr)) (θ²/12 + (θ/2 − Δb/L)²))`, with `Δb` counted in the
/// direction beam 2 is tilted towards (Eq. 50 as printed counts it the other way), so that the
/// optimum `Δb = Lθ/2` has the beams cross half way through the medium. Equivalently
/// `exp(−(L k²/(2ℓ_tr)) (L²θ²/3 + LθΔa + Δa²))` in the input shift.
pub fn model(depth: f64, k: f64, transport_mfp: f64, shift: f64, theta: f64) -> f64 {
    let l = depth;
    let x = 0.5 * theta - shift / l;
    (-(l * l * l * k * k / (2.0 * transport_mfp)) * (theta * theta / 12.0 + x * x)).exp()
}

/// The tilt that Eq. 50 (with [`model`]'s sign) prefers for refocusing a focus displaced by `Δ`
/// on the input plane: minimising `L²θ²/3 + LθΔ + Δ²` gives `θ = −3Δ/(2L)`, with the output shift
/// `Δb = Δ + Lθ = −Δ/2` (the beams cross two thirds of the way from plane `a`), and `e^{−(Lk²/2ℓ_tr) Δ²/4}`: twice
/// the range of the shift alone.
pub fn best_tilt(depth: f64, displacement: f64) -> f64 {
    -1.5 * displacement / depth
}

/// Accumulates `C` of every cell (outputs `c`) and the summed intensities of its two fields
/// (outputs `K + 2c`, `K + 2c + 1`, real), `K` the number of cells.
pub struct TiltShiftEstimator<'a> {
    sampler: SubpathSampler<'a>,
    /// `e^{ikτθ}` per cell and `τ`.
    ramps: Vec<C64>,
    cells: usize,
    taus: usize,
}

impl<'a> TiltShiftEstimator<'a> {
    pub fn new(scan: &'a TiltShift, reversed: bool) -> crate::Result<Self> {
        let k = scan.scene.k;
        let ramps = scan
            .cells
            .iter()
            .flat_map(|c| {
                scan.taus
                    .iter()
                    .map(move |t| crate::math::cis(k * t * c.angle))
            })
            .collect();
        Ok(TiltShiftEstimator {
            sampler: SubpathSampler::new(&scan.scene, scan.pairs(), reversed)?,
            ramps,
            cells: scan.cells.len(),
            taus: scan.taus.len(),
        })
    }
}

struct Products<'o> {
    out: &'o mut [C64],
    ramps: &'o [C64],
    cells: usize,
    taus: usize,
}

impl EventSink for Products<'_> {
    #[inline]
    fn event(&mut self, _multiple: bool, a: &[C64], _: &mut Rng) {
        let (k, t) = (self.cells, self.taus);
        let (c, i) = self.out.split_at_mut(k);
        for cell in 0..k {
            let (mut acc, mut i1, mut i2) = (C64::default(), 0.0, 0.0);
            for p in 0..t {
                let (u1, u2) = (a[2 * (cell * t + p)], a[2 * (cell * t + p) + 1]);
                acc += u1 * u2.conj() * self.ramps[cell * t + p];
                i1 += u1.norm_sqr();
                i2 += u2.norm_sqr();
            }
            c[cell] += acc;
            i[2 * cell] += i1;
            i[2 * cell + 1] += i2;
        }
    }

    #[inline]
    fn event_pair(&mut self, _multiple: bool, a: &[C64], b: &[C64], _: &mut Rng) {
        let (k, t) = (self.cells, self.taus);
        let (c, i) = self.out.split_at_mut(k);
        for cell in 0..k {
            let (mut acc, mut i1, mut i2) = (C64::default(), 0.0, 0.0);
            for p in 0..t {
                let n = 2 * (cell * t + p);
                let (a1, a2, b1, b2) = (a[n], a[n + 1], b[n], b[n + 1]);
                acc += 0.5 * (a1 * b2.conj() + b1 * a2.conj()) * self.ramps[cell * t + p];
                i1 += (a1 * b1.conj()).re;
                i2 += (a2 * b2.conj()).re;
            }
            c[cell] += acc;
            i[2 * cell] += i1;
            i[2 * cell + 1] += i2;
        }
    }
}

impl Estimator for TiltShiftEstimator<'_> {
    type Scratch = PathScratch;

    fn event_cost(&self) -> f64 {
        // the connections, then every output's product
        self.sampler.event_cost() + crate::mc::Estimator::outputs(self) as f64
    }

    fn outputs(&self) -> usize {
        3 * self.cells
    }

    fn scratch(&self) -> PathScratch {
        self.sampler.scratch()
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut PathScratch, out: &mut [C64]) {
        let mut sink = Products {
            out,
            ramps: &self.ramps,
            cells: self.cells,
            taus: self.taus,
        };
        for _ in 0..paths {
            self.sampler.trace(rng, sc, &mut sink);
        }
    }
}
