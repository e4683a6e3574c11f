//! Speckle covariance by Monte Carlo path sampling (paper 001, Algorithm 1, Eqs. 31–36).
//!
//! Each sampled subpath `x1 → … → xB` adds, for every vertex `xB`, a rank-1 term `w a aᴴ` to the
//! covariance of all light×view pairs, where `a_j = A_l B'_v + B_l A'_v` joins the subpath's ends to
//! light `l` and view `v` forwards and (for coherent backscattering) reversed (Eq. 38). The rank-1
//! terms are gathered into a batch and applied as one matrix product.

use crate::math::{C64, Rng};
use crate::mc::Estimator;
use crate::speckle::Scene;
use crate::speckle::paths::{EventSink, PathScratch, SubpathSampler};

/// Events gathered before one batched update.
const BATCH: usize = 64;

/// Row blocks of the real part's accumulator: only blocks on or above the diagonal are multiplied
/// (the imaginary part's product covers every entry).
const TILES: usize = 4;

/// Real floating-point operations the batched update spends on one event of `j` fields: its two
/// columns of `X Xᵀ` on the tiles on or above the diagonal, and its column of `M` over all `J²`
/// entries (see [`Batch`]). A complex rank-1 update of every entry would cost `8 J²`.
pub fn flops_per_event(j: usize) -> f64 {
    (4.0 * tile_fraction(j) + 2.0) * (j * j) as f64
}

/// Fraction of the `J×J` entries of the real part the batched update multiplies (tiles on or
/// above the diagonal); the rest follow by symmetry.
fn tile_fraction(j: usize) -> f64 {
    let tile = j.div_ceil(TILES);
    let n = j.div_ceil(tile);
    let mut done = 0;
    for a in 0..n {
        for b in a..n {
            done += tile.min(j - a * tile) * tile.min(j - b * tile);
        }
    }
    done as f64 / (j * j) as f64
}

/// Covariance of the fields `u_j` of the given (light, view) pairs. Outputs three `J×J` row-major
/// blocks: single scattering (B = 1), multiple scattering (B ≥ 2), and their sum; entry
/// `[j1·J + j2]` is `E[u_j1 u_j2*]`.
pub struct Covariance<'a> {
    sampler: SubpathSampler<'a>,
}

/// Per-thread working memory of [`Covariance`].
pub struct CovScratch {
    path: PathScratch,
    sink: CovSink,
}

struct CovSink {
    single: Batch,
    multi: Batch,
    /// Pairs of estimates (Monte Carlo apertures): `(a bᴴ + b aᴴ)/2 = p pᴴ − q qᴴ` with
    /// `p = (a + b)/2`, `q = (a − b)/2`; the `q qᴴ` terms gather here, `p` and `q` in the buffers.
    pairs: Option<PairBatches>,
}

struct PairBatches {
    single: Batch,
    multi: Batch,
    p: Vec<C64>,
    q: Vec<C64>,
}

impl EventSink for CovSink {
    #[inline]
    fn event(&mut self, multiple: bool, a: &[C64], _: &mut Rng) {
        if multiple {
            &mut self.multi
        } else {
            &mut self.single
        }
        .push(a);
    }

    #[inline]
    fn event_pair(&mut self, multiple: bool, a: &[C64], b: &[C64], _: &mut Rng) {
        let pairs = self
            .pairs
            .as_mut()
            .expect("pair batches when the sampler draws apertures");
        for ((p, q), (a, b)) in pairs.p.iter_mut().zip(&mut pairs.q).zip(a.iter().zip(b)) {
            *p = 0.5 * (a + b);
            *q = 0.5 * (a - b);
        }
        let (plus, minus) = if multiple {
            (&mut self.multi, &mut pairs.multi)
        } else {
            (&mut self.single, &mut pairs.single)
        };
        plus.push(&pairs.p);
        minus.push(&pairs.q);
    }
}

/// A batch of event vectors `a_e` and the accumulator `acc += Σ_e a_e a_eᴴ` (J × J), computed in
/// real arithmetic, whose matrix products run at about twice the rate of complex ones: with
/// `X = [Re a_e, Im a_e]_e` (J × 2n, the two columns of each event side by side),
/// `Re acc += X Xᵀ`, and `Im acc = M − Mᵀ` with `M += Im A · Re Aᵀ` (the same columns read with a
/// stride). The real part is symmetric, so only its tiles on or above the diagonal are
/// multiplied; the antisymmetric imaginary part comes from the whole of `M`, one product of half
/// the depth, formed once when the batch is drained.
pub struct Batch {
    j: usize,
    cols: usize,
    x: Vec<f64>,
    re: Vec<f64>,
    /// `M = Σ Im a_e · Re a_eᵀ`, all of it.
    m: Vec<f64>,
}

impl Batch {
    pub fn new(j: usize) -> Self {
        Batch {
            j,
            cols: 0,
            x: vec![0.0; 2 * j * BATCH],
            re: vec![0.0; j * j],
            m: vec![0.0; j * j],
        }
    }

    #[inline]
    pub fn push(&mut self, a: &[C64]) {
        if self.cols == BATCH {
            self.flush();
        }
        let (j, c) = (self.j, self.cols);
        let (x_re, x_im) = self.x[2 * c * j..2 * (c + 1) * j].split_at_mut(j);
        for ((re, im), z) in x_re.iter_mut().zip(x_im).zip(a) {
            (*re, *im) = (z.re, z.im);
        }
        self.cols += 1;
    }

    fn flush(&mut self) {
        if self.cols == 0 {
            return;
        }
        let (j, n) = (self.j, self.cols);
        let tile = j.div_ceil(TILES);
        // SAFETY (both products): X is j × 2n column-major (element (r, e) at e·j + r); the
        // operands start at offsets below 2j, and k columns at their stride stay within 2n·j; the
        // accumulators are j × j row-major.
        for r0 in (0..j).step_by(tile) {
            // Re += X Xᵀ over all 2n columns, each row block times every column from its own
            // diagonal tile on: one product (the row block packed once), tiles on or above the
            // diagonal only
            unsafe {
                matrixmultiply::dgemm(
                    tile.min(j - r0),
                    2 * n,
                    j - r0,
                    1.0,
                    self.x.as_ptr().add(r0),
                    1,
                    j as isize,
                    self.x.as_ptr().add(r0),
                    j as isize,
                    1,
                    1.0,
                    self.re.as_mut_ptr().add(r0 * j + r0),
                    j as isize,
                    1,
                );
            }
        }
        // M += Im A · Re Aᵀ (every other column of X, from the second and the first)
        unsafe {
            matrixmultiply::dgemm(
                j,
                n,
                j,
                1.0,
                self.x.as_ptr().add(j),
                1,
                2 * j as isize,
                self.x.as_ptr(),
                2 * j as isize,
                1,
                1.0,
                self.m.as_mut_ptr(),
                j as isize,
                1,
            );
        }
        self.cols = 0;
    }

    /// Add the accumulated matrix (lower tiles filled by Hermitian symmetry) to `out`; clear it.
    pub fn drain_into(&mut self, out: &mut [C64]) {
        self.drain_scaled(1.0, out);
    }

    /// Add `sign` times the accumulated matrix to `out`; clear it.
    fn drain_scaled(&mut self, sign: f64, out: &mut [C64]) {
        self.flush();
        let j = self.j;
        let tile = j.div_ceil(TILES);
        for a in 0..j {
            for b in 0..j {
                let re = if b / tile >= a / tile {
                    self.re[a * j + b]
                } else {
                    self.re[b * j + a]
                };
                let im = self.m[a * j + b] - self.m[b * j + a];
                out[a * j + b] += C64::new(re, im) * sign;
            }
        }
        self.re.iter_mut().for_each(|v| *v = 0.0);
        self.m.iter_mut().for_each(|v| *v = 0.0);
    }
}

/// The scattering orders a covariance output block counts: the estimator writes the blocks in
/// this order (single, multiple, total).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// Subpaths of one vertex (B = 1).
    Single = 0,
    /// Subpaths of two or more vertices (B ≥ 2).
    Multiple = 1,
    /// Their sum: the covariance.
    Total = 2,
}

impl Order {
    /// Every block, in output order.
    pub const ALL: [Order; 3] = [Order::Single, Order::Multiple, Order::Total];

    /// Index of entry `[a][b]` of this block among the outputs of a covariance of `j` fields.
    pub fn index(self, j: usize, a: usize, b: usize) -> usize {
        (self as usize * j + a) * j + b
    }

    /// The `J×J` block of this order in the outputs of a covariance of `j` fields.
    pub fn block<T>(self, j: usize, outputs: &[T]) -> &[T] {
        let jj = j * j;
        &outputs[self as usize * jj..(self as usize + 1) * jj]
    }
}

impl<'a> Covariance<'a> {
    /// Covariance over all light×view pairs (`j = l·V + v`).
    pub fn all_pairs(scene: &'a Scene, reversed: bool) -> crate::Result<Self> {
        Self::with_pairs(scene, SubpathSampler::all_pairs(scene), reversed)
    }

    /// Covariance over the listed (light, view) pairs.
    pub fn with_pairs(
        scene: &'a Scene,
        pairs: Vec<(usize, usize)>,
        reversed: bool,
    ) -> crate::Result<Self> {
        Ok(Covariance {
            sampler: SubpathSampler::new(scene, pairs, reversed)?,
        })
    }

    pub fn pairs(&self) -> &[(usize, usize)] {
        self.sampler.pairs()
    }

    /// Number of fields `J`.
    pub fn fields(&self) -> usize {
        self.pairs().len()
    }
}

impl Estimator for Covariance<'_> {
    type Scratch = CovScratch;

    fn event_cost(&self) -> f64 {
        self.sampler.event_cost() + crate::mc::Estimator::outputs(self) as f64 / 3.0
    }

    fn outputs(&self) -> usize {
        3 * self.fields() * self.fields()
    }

    fn scratch_bytes(&self) -> usize {
        let j = self.fields();
        // two batches (single, multiple): X (j × 2·BATCH reals) and the accumulator (j × j, its
        // real and imaginary parts); twice that for pairs of estimates
        let batches = if self.sampler.draws_apertures() { 4 } else { 2 };
        batches * (2 * j * BATCH + 2 * j * j) * std::mem::size_of::<f64>()
    }

    fn scratch(&self) -> CovScratch {
        let j = self.fields();
        CovScratch {
            path: self.sampler.scratch(),
            sink: CovSink {
                single: Batch::new(j),
                multi: Batch::new(j),
                pairs: self.sampler.draws_apertures().then(|| PairBatches {
                    single: Batch::new(j),
                    multi: Batch::new(j),
                    p: vec![C64::default(); j],
                    q: vec![C64::default(); j],
                }),
            },
        }
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, sc: &mut CovScratch, out: &mut [C64]) {
        for _ in 0..paths {
            self.sampler.trace(rng, &mut sc.path, &mut sc.sink);
        }
        let jj = self.fields() * self.fields();
        let (single, rest) = out.split_at_mut(jj);
        let (multi, total) = rest.split_at_mut(jj);
        sc.sink.single.drain_into(single);
        sc.sink.multi.drain_into(multi);
        if let Some(pairs) = &mut sc.sink.pairs {
            pairs.single.drain_scaled(-1.0, single);
            pairs.multi.drain_scaled(-1.0, multi);
        }
        for ((t, a), b) in total.iter_mut().zip(single.iter()).zip(multi.iter()) {
            *t = a + b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The batched real products equal the direct sum of the rank-1 terms `a aᴴ` (full batches,
    /// a partial one, and a size that does not divide into tiles), entry by entry.
    #[test]
    fn batch_equals_the_sum_of_rank_one_terms() {
        let j = 23;
        let mut rng = crate::math::stream_rng(7, 0);
        use rand::RngExt;
        let events: Vec<Vec<C64>> = (0..2 * BATCH + 5)
            .map(|_| {
                (0..j)
                    .map(|_| C64::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5))
                    .collect()
            })
            .collect();
        let mut batch = Batch::new(j);
        events.iter().for_each(|a| batch.push(a));
        let mut out = vec![C64::default(); j * j];
        batch.drain_into(&mut out);
        for a in 0..j {
            for b in 0..j {
                let direct: C64 = events.iter().map(|e| e[a] * e[b].conj()).sum();
                let d = (out[a * j + b] - direct).norm();
                assert!(
                    d < 1e-12 * events.len() as f64,
                    "[{a}][{b}]: {} vs {direct}",
                    out[a * j + b]
                );
            }
        }
        // drained: the accumulator starts again from zero
        let mut again = vec![C64::default(); j * j];
        batch.push(&events[0]);
        batch.drain_into(&mut again);
        assert!((again[j + 2] - events[0][1] * events[0][2].conj()).norm() < 1e-15);
    }
}
