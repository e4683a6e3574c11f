//! Refusing runs that cannot finish or fit, before any work: the engine's memory for the outputs
//! and the time for the paths (a short timed pilot, or for very long paths the cheapest event
//! cost, scaled by the expected number of scattering events per path), against `--max-memory-gb`
//! and `--max-minutes`. The error says what the estimate is made of and what to change.

use crate::error::{Error, Result};
use crate::math::{C64, stream_rng};
use crate::mc::{Estimator, working_bytes};
use crate::medium::Medium;
use crate::speckle::paths::expected_events;
use std::time::Instant;

/// What a run may use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    pub max_minutes: f64,
    pub max_memory_gb: f64,
}

impl Default for Budget {
    fn default() -> Self {
        Budget {
            max_minutes: 240.0,
            max_memory_gb: 8.0,
        }
    }
}

/// Work (paths × events × outputs updated per event) below which no pilot is timed: such runs
/// take well under a second.
const NO_PILOT_BELOW: f64 = 1e8;
/// Events a pilot traces (a few tens of milliseconds).
const PILOT_EVENTS: f64 = 1e5;
/// Output updates a pilot makes (tens of milliseconds).
const PILOT_UPDATES: f64 = 3e7;
/// The cheapest scattering event seen on any scene (one light, one view), in seconds, and the
/// cheapest update of one output: the floor of a time estimate when paths are too long to time.
const FASTEST_EVENT: f64 = 1e-8;
const FASTEST_UPDATE: f64 = 2e-10;

/// How much a run of `paths` subpaths of `est` in `medium` would take (chunks `chunks`, `kept`
/// outputs kept per chunk); an error naming `what` and the limit when beyond `budget`.
pub fn check<E: Estimator>(
    what: &str,
    est: &E,
    medium: &Medium,
    paths: f64,
    chunks: u64,
    kept: usize,
    budget: &Budget,
) -> Result<()> {
    for (flag, v) in [
        ("--max-minutes", budget.max_minutes),
        ("--max-memory-gb", budget.max_memory_gb),
    ] {
        if v.is_nan() || v <= 0.0 {
            return Err(Error::input(format!("{flag} {v}: must be > 0")));
        }
    }
    let threads = rayon::current_num_threads();
    let gb = working_bytes(est.outputs(), est.scratch_bytes(), kept, chunks, threads) / 1e9;
    if gb > budget.max_memory_gb {
        return Err(Error::input(format!(
            "{what}: {} outputs (from the lights × views asked for) need an estimated {gb:.1} GB on {threads} threads, beyond --max-memory-gb {}. Use fewer lights or views (a coarser ring or grid), fewer --threads, or raise --max-memory-gb",
            est.outputs(),
            budget.max_memory_gb
        )));
    }
    let events = expected_events(medium);
    let work = paths * events * est.outputs() as f64;
    if work < NO_PILOT_BELOW {
        return Ok(());
    }
    let outputs = est.outputs().max(1) as f64;
    let floor = events * (FASTEST_EVENT + outputs * FASTEST_UPDATE);
    let per_path = if floor > 1.0 {
        // a single path takes more than a second: time nothing, take the cheapest costs
        floor
    } else {
        let pilot = (PILOT_EVENTS / events)
            .min(PILOT_UPDATES / (events * outputs))
            .clamp(1.0, 10_000.0)
            .round() as u64;
        let mut scratch = est.scratch();
        let mut out = vec![C64::default(); est.outputs()];
        let mut rng = stream_rng(0x0050_494c_4f54, 0);
        let t0 = Instant::now();
        est.run_chunk(&mut rng, pilot, &mut scratch, &mut out);
        (t0.elapsed().as_secs_f64() / pilot as f64).max(floor)
    };
    let seconds = paths * per_path / threads as f64;
    if seconds > 60.0 * budget.max_minutes {
        let tau = medium.sigma_s * medium.geometry.smallest_extent();
        return Err(Error::input(format!(
            "{what}: {paths:.3e} paths of ~{events:.3e} scattering events each, updating {} outputs at each (optical thickness σ_s·d = {tau:.3e} over the smallest extent, albedo {:.6}, g = {:.3}) would take an estimated {} on {threads} threads, beyond --max-minutes {}. Use fewer samples, a thinner or more absorbing medium (a longer mfp), fewer lights or views, more --threads or shards, or raise --max-minutes",
            est.outputs(),
            medium.albedo(),
            medium.mean_cosine(),
            duration(seconds),
            budget.max_minutes
        )));
    }
    Ok(())
}

/// A duration in the unit that reads best.
fn duration(seconds: f64) -> String {
    if seconds < 120.0 {
        format!("{seconds:.0} s")
    } else if seconds < 7200.0 {
        format!("{:.0} min", seconds / 60.0)
    } else if seconds < 2.0 * 86400.0 * 365.0 {
        format!("{:.1} h", seconds / 3600.0)
    } else {
        format!("{:.1e} years", seconds / (86400.0 * 365.0))
    }
}
