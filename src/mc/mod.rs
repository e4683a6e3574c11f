//! The Monte Carlo engine: deterministic chunked sampling, estimates with standard errors, shards.
//!
//! Work is cut into `chunks` of `chunk_paths` samples; chunk `c` draws from its own stream
//! `stream_rng(seed, c)`. Chunk results are combined along a fixed binary tree over chunk indices
//! (aligned dyadic blocks), so a result is bit-for-bit the same whatever the thread count, and a run
//! cut into shards and merged equals the single run: each shard reports the aligned blocks of its
//! range, and the merge combines them along the same tree.

use crate::math::{C64, Rng, stream_rng};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// A sampler of complex-valued quantities: the estimator ("solver") the engine ("executor") drives.
/// Estimators never spawn threads, print or write files.
pub trait Estimator: Sync {
    /// Per-thread working memory, reused from chunk to chunk.
    type Scratch: Send;
    /// Number of complex outputs.
    fn outputs(&self) -> usize;
    fn scratch(&self) -> Self::Scratch;
    /// Trace `paths` samples drawn from `rng` and add their summed contributions to `out`.
    fn run_chunk(&self, rng: &mut Rng, paths: u64, scratch: &mut Self::Scratch, out: &mut [C64]);
    /// Bytes of one [`Self::Scratch`] beyond a few output-sized buffers (for memory estimates).
    fn scratch_bytes(&self) -> usize {
        0
    }
    /// The work of one sample's unit step (a scattering event), in output updates (for time
    /// estimates); by default every output once.
    fn event_cost(&self) -> f64 {
        self.outputs() as f64
    }
}

/// Bytes the engine holds to run chunks `range` of an estimator with `outputs` outputs on
/// `threads` threads, keeping `kept` outputs per chunk: the chunk buffers, the reducer's blocks, the
/// kept per-chunk means and each thread's scratch.
pub fn working_bytes(
    outputs: usize,
    scratch_bytes: usize,
    kept: usize,
    chunks: u64,
    threads: usize,
) -> f64 {
    let c = std::mem::size_of::<C64>() as f64;
    let outputs = outputs as f64;
    let blocks = 2.0 + (chunks.max(1) as f64).log2();
    // a wave's chunk buffers and the reducer's blocks (sums and squares); the spare buffers are
    // those of absorbed blocks, allocated only when none is spare, so they add nothing
    (WAVE as f64 + blocks) * outputs * (c + 8.0)
        + chunks as f64 * kept as f64 * c
        + threads as f64 * scratch_bytes as f64
}

/// How a run is cut into chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    pub seed: u64,
    pub chunk_paths: u64,
    pub chunks: u64,
}

impl Plan {
    /// At least `samples` samples in chunks of `chunk_paths` (rounded up to whole chunks). A chunk
    /// larger than half the samples is cut to that, so the run stays `samples` long (at least two
    /// chunks, for the batch-means errors) whatever the configured chunk.
    pub fn new(seed: u64, samples: u64, chunk_paths: u64) -> Self {
        let chunk_paths = chunk_paths.clamp(1, samples.div_ceil(2).max(1));
        Plan {
            seed,
            chunk_paths,
            chunks: samples.div_ceil(chunk_paths).max(2),
        }
    }

    pub fn samples(&self) -> u64 {
        self.chunks * self.chunk_paths
    }

    /// Chunk range of shard `i` of `n` (contiguous, as even as possible).
    pub fn shard_range(&self, i: u64, n: u64) -> Range<u64> {
        (self.chunks * i / n)..(self.chunks * (i + 1) / n)
    }
}

/// Sums over an aligned dyadic block of chunks `[start, start + len)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    pub start: u64,
    pub len: u64,
    /// Sum of the chunk sums.
    pub sum: Vec<C64>,
    /// Sum over chunks of `|chunk mean|²` (for batch-means standard errors).
    pub sq: Vec<f64>,
    /// Per-chunk means of the kept outputs, chunk after chunk (for derived quantities' errors).
    pub kept: Vec<C64>,
}

impl Block {
    /// The block of one chunk whose summed outputs are `sum`; `sq` is overwritten (any length).
    fn leaf(chunk: u64, sum: Vec<C64>, mut sq: Vec<f64>, paths: u64, keep: &[usize]) -> Self {
        let inv = 1.0 / paths as f64;
        sq.clear();
        sq.extend(sum.iter().map(|z| (z * inv).norm_sqr()));
        Block {
            start: chunk,
            len: 1,
            kept: keep.iter().map(|&i| sum[i] * inv).collect(),
            sum,
            sq,
        }
    }

    /// Add the next block's sums to this one; returns the right block's buffers for reuse. Large
    /// blocks are added on every thread: each entry is one addition, so the bits do not depend on
    /// how the entries are split.
    fn absorb(&mut self, right: Block) -> (Vec<C64>, Vec<f64>) {
        debug_assert_eq!(self.start + self.len, right.start);
        const PIECE: usize = 1 << 14;
        self.sum
            .par_iter_mut()
            .with_min_len(PIECE)
            .zip(right.sum.par_iter().with_min_len(PIECE))
            .for_each(|(a, b)| *a += b);
        self.sq
            .par_iter_mut()
            .with_min_len(PIECE)
            .zip(right.sq.par_iter().with_min_len(PIECE))
            .for_each(|(a, b)| *a += b);
        self.kept.extend_from_slice(&right.kept);
        self.len += right.len;
        (right.sum, right.sq)
    }

    fn is_left_sibling_of(&self, right: &Block) -> bool {
        self.len == right.len
            && self.start.is_multiple_of(2 * self.len)
            && self.start + self.len == right.start
    }
}

/// Combines blocks pushed in chunk order along the canonical tree (a binary counter).
#[derive(Default, Debug)]
pub struct Reducer {
    stack: Vec<Block>,
    /// Buffers of absorbed blocks, for the next leaves (a run of large outputs would otherwise
    /// allocate, and fault in, two output-sized vectors per chunk).
    spare: Vec<(Vec<C64>, Vec<f64>)>,
}

impl Reducer {
    pub fn push(&mut self, block: Block) {
        self.stack.push(block);
        while self.stack.len() >= 2 {
            let n = self.stack.len();
            if !self.stack[n - 2].is_left_sibling_of(&self.stack[n - 1]) {
                break;
            }
            let right = self.stack.pop().expect("two blocks");
            let buffers = self.stack.last_mut().expect("one block").absorb(right);
            if self.spare.len() < WAVE {
                self.spare.push(buffers);
            }
        }
    }

    /// Buffers for a leaf of `n` outputs: an absorbed block's, else new ones. Their contents are
    /// arbitrary.
    fn spare(&mut self, n: usize) -> (Vec<C64>, Vec<f64>) {
        match self.spare.pop() {
            Some((sum, sq)) if sum.len() == n => (sum, sq),
            _ => (vec![C64::default(); n], Vec::with_capacity(n)),
        }
    }

    /// The maximal aligned blocks pushed so far (what a shard reports).
    pub fn into_blocks(self) -> Vec<Block> {
        self.stack
    }

    /// Fold all blocks left to right into one (they must be contiguous).
    pub fn finish(self) -> Option<Block> {
        let mut it = self.stack.into_iter();
        let mut acc = it.next()?;
        for b in it {
            if acc.start + acc.len != b.start {
                return None;
            }
            acc.absorb(b);
        }
        Some(acc)
    }
}

/// Where one chunk of a wave runs: its sums and the buffer for their squares (handed to the chunk's
/// block, then refilled from the reducer's spare buffers), and a thread's scratch. The block is
/// built on the thread that ran the chunk; only the ordered reduction waits for the wave.
struct Slot<S> {
    sum: Vec<C64>,
    sq: Vec<f64>,
    scratch: Option<S>,
}

/// Chunks traced at once between two ordered reductions; fixed so that results do not depend on the
/// number of threads.
const WAVE: usize = 8;

/// Run the chunks in `range` of `plan` in parallel (on the current rayon pool) and return the aligned
/// blocks covering it. `keep` lists outputs whose per-chunk means are retained; `progress` is called
/// with the number of chunks finished so far.
pub fn run<E: Estimator>(
    est: &E,
    plan: &Plan,
    range: Range<u64>,
    keep: &[usize],
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<Block> {
    resume(est, plan, range, keep, progress, Vec::new(), None)
        .expect("a run without checkpoints cannot fail")
}

/// What saves a checkpoint's blocks.
pub type Save<'a> = &'a mut dyn FnMut(&[Block]) -> crate::Result<()>;

/// Saving a run's blocks so far (see [`resume`]) through `save`: after every `every` units of work
/// when given, else every two minutes.
pub struct Checkpoint<'a> {
    every: u64,
    interval: std::time::Duration,
    /// `None`: never saves (a run that can only be stopped).
    save: Option<Save<'a>>,
    saved_at: u64,
    saved_when: std::time::Instant,
    stop: Option<&'a AtomicBool>,
}

impl<'a> Checkpoint<'a> {
    pub fn new(every: Option<u64>, save: Save<'a>) -> Self {
        let (every, interval) = match every {
            Some(n) => (n.max(1), std::time::Duration::MAX),
            None => (u64::MAX, std::time::Duration::from_secs(120)),
        };
        Checkpoint {
            every,
            interval,
            save: Some(save),
            saved_at: 0,
            saved_when: std::time::Instant::now(),
            stop: None,
        }
    }

    /// A checkpoint that never saves and stops the run once `stop` (if any) is set: a run in
    /// memory that can be interrupted.
    pub fn stop_only(stop: Option<&'a AtomicBool>) -> Self {
        Checkpoint {
            every: u64::MAX,
            interval: std::time::Duration::MAX,
            save: None,
            saved_at: 0,
            saved_when: std::time::Instant::now(),
            stop,
        }
    }

    /// The flag that stops the run, if any (for runs nested inside this one).
    pub fn stop_flag(&self) -> Option<&'a AtomicBool> {
        self.stop
    }

    /// Count from `done` units of work (where the run starts or resumes).
    pub fn start(&mut self, done: u64) {
        (self.saved_at, self.saved_when) = (done, std::time::Instant::now());
    }

    /// `done` units are finished and reduced into `blocks`: save them if a checkpoint is due.
    pub fn offer(&mut self, done: u64, blocks: &[Block]) -> crate::Result<()> {
        if self.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            return Err(crate::Error::Interrupted);
        }
        if let Some(save) = self.save.as_mut()
            && (done - self.saved_at >= self.every || self.saved_when.elapsed() >= self.interval)
        {
            save(blocks)?;
            self.start(done);
        }
        Ok(())
    }
}

/// [`run`], continuing from `done`: the blocks an interrupted run of the same range had reduced
/// (contiguous from `range.start`, as `Checkpoint::save` received them), and saving checkpoints
/// on the way. The blocks come out as the uninterrupted run's, bit for bit: the reduction tree
/// depends only on chunk indices.
pub fn resume<E: Estimator>(
    est: &E,
    plan: &Plan,
    range: Range<u64>,
    keep: &[usize],
    progress: &(dyn Fn(u64) + Sync),
    done: Vec<Block>,
    mut checkpoint: Option<Checkpoint>,
) -> crate::Result<Vec<Block>> {
    let n = est.outputs();
    let mut reducer = Reducer::default();
    let mut next = range.start;
    for b in done {
        if b.start != next || b.len == 0 {
            return Err(crate::Error::input(format!(
                "checkpoint: chunks {}..+{} do not continue the run at chunk {next}",
                b.start, b.len
            )));
        }
        next = b.start + b.len;
        reducer.push(b);
    }
    if next > range.end {
        return Err(crate::Error::input(format!(
            "checkpoint: it covers chunks up to {next}, beyond this run's {}",
            range.end
        )));
    }
    let mut slots: Vec<Slot<E::Scratch>> = (0..WAVE)
        .map(|_| Slot {
            sum: vec![C64::default(); n],
            sq: Vec::with_capacity(n),
            scratch: None,
        })
        .collect();
    if let Some(c) = checkpoint.as_mut() {
        c.start(next);
    }
    let stop = checkpoint.as_ref().and_then(|c| c.stop_flag());
    let stopped = || stop.is_some_and(|s| s.load(Ordering::Relaxed));
    progress(next - range.start);
    while next < range.end {
        let count = ((range.end - next) as usize).min(WAVE);
        let leaves = slots[..count]
            .par_iter_mut()
            .enumerate()
            .map(|(i, slot)| {
                // once asked to stop, chunks not yet begun are skipped: the wave is discarded
                // below, so a stop waits for one chunk, not a whole wave
                if stopped() {
                    return None;
                }
                let chunk = next + i as u64;
                slot.sum.iter_mut().for_each(|z| *z = C64::default());
                let s = slot.scratch.get_or_insert_with(|| est.scratch());
                let mut rng = stream_rng(plan.seed, chunk);
                est.run_chunk(&mut rng, plan.chunk_paths, s, &mut slot.sum);
                let (sum, sq) = (std::mem::take(&mut slot.sum), std::mem::take(&mut slot.sq));
                Some(Block::leaf(chunk, sum, sq, plan.chunk_paths, keep))
            })
            .collect::<Vec<_>>();
        if stopped() {
            return Err(crate::Error::Interrupted);
        }
        for (leaf, slot) in leaves.into_iter().zip(&mut slots) {
            reducer.push(leaf.expect("every chunk of the wave ran"));
            (slot.sum, slot.sq) = reducer.spare(n);
        }
        next += count as u64;
        progress(next - range.start);
        if let Some(c) = checkpoint.as_mut()
            && next < range.end
        {
            c.offer(next, &reducer.stack)?;
        }
    }
    Ok(reducer.into_blocks())
}

/// Merge shard blocks (in any order) into the single-run root block; errors if they do not tile
/// `[0, chunks)` exactly.
pub fn merge(mut blocks: Vec<Block>, chunks: u64) -> crate::Result<Block> {
    blocks.sort_by_key(|b| b.start);
    let mut expect = 0;
    for b in &blocks {
        if b.start != expect {
            return Err(if b.start < expect {
                format!(
                    "chunks {}..{} are covered twice (overlapping shards)",
                    b.start,
                    expect.min(b.start + b.len)
                )
                .into()
            } else {
                format!(
                    "chunks {expect}..{} are missing (a shard is missing)",
                    b.start
                )
                .into()
            });
        }
        expect = b.start + b.len;
    }
    if expect != chunks {
        return Err(format!("chunks {expect}..{chunks} are missing (a shard is missing)").into());
    }
    let mut r = Reducer::default();
    for b in blocks {
        r.push(b);
    }
    r.finish()
        .ok_or_else(|| crate::Error::input("shard blocks are not contiguous"))
}

/// Run every chunk of `plan` (no progress, nothing kept) and return the estimate: the whole-run
/// convenience used inside objectives and differentiable operations.
pub fn estimate<E: Estimator>(est: &E, plan: &Plan) -> Estimate {
    let blocks = run(est, plan, 0..plan.chunks, &[], &|_| {});
    let root = merge(blocks, plan.chunks).expect("run covers every chunk of the plan");
    Estimate::from_block(&root, plan)
}

/// [`estimate`] that stops with [`crate::Error::Interrupted`] once `stop` is set and the chunks
/// already begun end (the same bits when it is not, or when there is no flag).
pub fn estimate_until<E: Estimator>(
    est: &E,
    plan: &Plan,
    stop: Option<&AtomicBool>,
) -> crate::Result<Estimate> {
    match stop {
        Some(stop) => estimate_observed(est, plan, stop, &|_| {}),
        None => Ok(estimate(est, plan)),
    }
}

/// The whole plan with `progress(chunks done)`, stopping once `stop` is set.
fn estimate_observed<E: Estimator>(
    est: &E,
    plan: &Plan,
    stop: &AtomicBool,
    progress: &(dyn Fn(u64) + Sync),
) -> crate::Result<Estimate> {
    let blocks = resume(
        est,
        plan,
        0..plan.chunks,
        &[],
        progress,
        Vec::new(),
        Some(Checkpoint::stop_only(Some(stop))),
    )?;
    let root = merge(blocks, plan.chunks)?;
    Ok(Estimate::from_block(&root, plan))
}

/// [`estimate`] observed through `watch`: chunks done of the plan's (its `total`), and a stop once
/// the chunks begun end, with [`crate::Error::Interrupted`] (the same bits otherwise).
pub fn estimate_watched<E: Estimator>(
    est: &E,
    plan: &Plan,
    watch: &Watch,
) -> crate::Result<Estimate> {
    watch.total.store(plan.chunks, Ordering::Relaxed);
    watch.done.store(0, Ordering::Relaxed);
    estimate_observed(est, plan, &watch.stop, &|n| {
        watch.done.store(n, Ordering::Relaxed)
    })
}

/// A flag another thread may set to stop a long computation (a fit, a design, an estimate) at
/// its next chunk, ray or iteration, with [`crate::Error::Interrupted`]; none by default.
#[derive(Clone, Debug, Default)]
pub struct StopFlag(Option<Arc<AtomicBool>>);

impl StopFlag {
    pub fn new(flag: Arc<AtomicBool>) -> Self {
        StopFlag(Some(flag))
    }

    /// The flag, for [`estimate_until`] and [`Checkpoint::stop_only`].
    pub fn get(&self) -> Option<&AtomicBool> {
        self.0.as_deref()
    }

    pub fn is_set(&self) -> bool {
        self.get().is_some_and(|s| s.load(Ordering::Relaxed))
    }

    /// `Err(Interrupted)` once the flag is set.
    pub fn check(&self) -> crate::Result<()> {
        if self.is_set() {
            Err(crate::Error::Interrupted)
        } else {
            Ok(())
        }
    }
}

/// A run observed and stopped from another thread (the Python binding polls it while the run
/// works): units of work done and in all, and a flag that stops the run at its next chunk, ray
/// or iteration with [`crate::Error::Interrupted`].
#[derive(Debug, Default)]
pub struct Watch {
    pub done: AtomicU64,
    pub total: AtomicU64,
    pub stop: Arc<AtomicBool>,
}

impl Watch {
    /// Ask the run to stop.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// The stop flag for fits and designs, which hold it beyond a borrow.
    pub fn stop_flag(&self) -> StopFlag {
        StopFlag::new(Arc::clone(&self.stop))
    }

    /// One more unit of work done.
    pub fn tick(&self) {
        self.done.fetch_add(1, Ordering::Relaxed);
    }

    /// `Err(Interrupted)` once the run was asked to stop.
    pub fn check(&self) -> crate::Result<()> {
        if self.stop.load(Ordering::Relaxed) {
            Err(crate::Error::Interrupted)
        } else {
            Ok(())
        }
    }

    /// `(done, total)` units of work so far.
    pub fn progress(&self) -> (u64, u64) {
        (
            self.done.load(Ordering::Relaxed),
            self.total.load(Ordering::Relaxed),
        )
    }
}

/// Real linear functionals `x_k = Re Σ_e conj(w_ke) out_e` of another estimator's outputs, so that
/// the chunk-to-chunk covariance of a few projections (e.g. how a fit's parameters respond to the
/// model's Monte Carlo noise) is estimated without keeping every output of every chunk.
pub struct Projected<'w, E> {
    pub inner: E,
    pub weights: &'w [Vec<C64>],
}

impl<E: Estimator> Estimator for Projected<'_, E> {
    type Scratch = (E::Scratch, Vec<C64>);

    fn outputs(&self) -> usize {
        self.weights.len()
    }

    fn scratch(&self) -> Self::Scratch {
        (
            self.inner.scratch(),
            vec![C64::default(); self.inner.outputs()],
        )
    }

    fn run_chunk(&self, rng: &mut Rng, paths: u64, s: &mut Self::Scratch, out: &mut [C64]) {
        s.1.iter_mut().for_each(|z| *z = C64::default());
        self.inner.run_chunk(rng, paths, &mut s.0, &mut s.1);
        for (o, w) in out.iter_mut().zip(self.weights) {
            *o += w
                .iter()
                .zip(&s.1)
                .map(|(w, z)| (w.conj() * z).re)
                .sum::<f64>();
        }
    }
}

/// Covariance matrix of the means of the kept outputs' real parts, by batch means over the chunks
/// of a root block (`kept`: chunk after chunk, `n` outputs each).
pub fn kept_covariance(kept: &[C64], n: usize) -> Vec<Vec<f64>> {
    let chunks = kept.len() / n.max(1);
    let mean: Vec<f64> = (0..n)
        .map(|k| (0..chunks).map(|c| kept[c * n + k].re).sum::<f64>() / chunks as f64)
        .collect();
    let norm = ((chunks as f64 - 1.0) * chunks as f64).max(1.0);
    (0..n)
        .map(|a| {
            (0..n)
                .map(|b| {
                    (0..chunks)
                        .map(|c| (kept[c * n + a].re - mean[a]) * (kept[c * n + b].re - mean[b]))
                        .sum::<f64>()
                        / norm
                })
                .collect()
        })
        .collect()
}

/// Mean and standard error (batch means over chunks) of every output.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    pub mean: Vec<C64>,
    /// Standard error of the complex mean: `sqrt(Var(re) + Var(im)) / sqrt(chunks)`.
    pub stderr: Vec<f64>,
    pub samples: u64,
    pub chunks: u64,
}

impl Estimate {
    pub fn from_block(b: &Block, plan: &Plan) -> Self {
        let k = b.len as f64;
        let n = plan.samples() as f64;
        let mean: Vec<C64> = b.sum.iter().map(|z| z / n).collect();
        let stderr = mean
            .iter()
            .zip(&b.sq)
            .map(|(m, &sq)| {
                let var = ((sq / k - m.norm_sqr()) * k / (k - 1.0)).max(0.0);
                (var / k).sqrt()
            })
            .collect();
        Estimate {
            mean,
            stderr,
            samples: plan.samples(),
            chunks: b.len,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::uniform;

    /// Estimates E[u] = 1/2 and E[u²] = 1/3.
    struct Moments;
    impl Estimator for Moments {
        type Scratch = ();
        fn outputs(&self) -> usize {
            2
        }
        fn scratch(&self) {}
        fn run_chunk(&self, rng: &mut Rng, paths: u64, _: &mut (), out: &mut [C64]) {
            for _ in 0..paths {
                let u = uniform(rng);
                out[0] += u;
                out[1] += C64::new(0.0, u * u);
            }
        }
    }

    #[test]
    fn a_large_chunk_does_not_lengthen_the_run() {
        // a chunk far beyond the samples asked for is cut to half of them: two chunks, the run
        // as long as asked (it once ran two whole chunks: 9.2e18 paths for 2000 asked)
        let p = Plan::new(1, 2000, 9_200_000_000_000_000_000);
        assert_eq!((p.chunks, p.chunk_paths, p.samples()), (2, 1000, 2000));
        let p = Plan::new(1, 2000, 300);
        assert_eq!((p.chunks, p.chunk_paths), (7, 300));
        assert_eq!(Plan::new(1, 1, 10).samples(), 2);
    }

    #[test]
    fn estimates_are_unbiased_with_honest_errors() {
        let plan = Plan::new(7, 200_000, 1000);
        let b = merge(
            run(&Moments, &plan, 0..plan.chunks, &[], &|_| {}),
            plan.chunks,
        )
        .unwrap();
        let e = Estimate::from_block(&b, &plan);
        let se0 = (1.0f64 / 12.0 / plan.samples() as f64).sqrt();
        assert!(
            (e.stderr[0] / se0 - 1.0).abs() < 0.2,
            "{} vs {se0}",
            e.stderr[0]
        );
        assert!((e.mean[0].re - 0.5).abs() < 4.0 * e.stderr[0]);
        assert!((e.mean[1].im - 1.0 / 3.0).abs() < 4.0 * e.stderr[1]);
    }

    #[test]
    fn shards_merge_bit_for_bit() {
        let plan = Plan::new(3, 37 * 50, 50);
        let whole = merge(
            run(&Moments, &plan, 0..plan.chunks, &[0], &|_| {}),
            plan.chunks,
        )
        .unwrap();
        for n in [2, 3, 5] {
            let mut blocks = Vec::new();
            for i in (0..n).rev() {
                blocks.extend(run(&Moments, &plan, plan.shard_range(i, n), &[0], &|_| {}));
            }
            assert_eq!(merge(blocks, plan.chunks).unwrap(), whole);
        }
        let missing = run(&Moments, &plan, plan.shard_range(0, 2), &[], &|_| {});
        assert!(
            merge(missing, plan.chunks)
                .unwrap_err()
                .to_string()
                .contains("missing")
        );
    }
}
