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

/// Work (paths × events × each event's cost in output updates) below which no pilot is timed:
/// such runs take well under a second.
const NO_PILOT_BELOW: f64 = 1e8;
/// Events a pilot traces (a few tens of milliseconds).
const PILOT_EVENTS: f64 = 1e5;
/// How long a pilot runs: at least the first, at most the second (past it, the batch under way
/// finishes and the pilot stops).
const PILOT_MIN_TIME: std::time::Duration = std::time::Duration::from_millis(30);
const PILOT_TIME: std::time::Duration = std::time::Duration::from_millis(100);
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
    let gb = memory_gb(est, kept, chunks);
    // what the outputs come from, and what makes a run cheaper, in the command's own terms
    let (outputs_from, fewer) = if what == "render" {
        (
            "the sensors' and cameras' pixels and time bins",
            "fewer pixels or time bins, fewer probes or cameras (each connection is a few Newton solves), a coarser render.step",
        )
    } else {
        (
            "the lights × views asked for",
            "a thinner or more absorbing medium (a longer mfp), fewer lights or views",
        )
    };
    if gb > budget.max_memory_gb {
        return Err(Error::input(format!(
            "{what}: {} outputs (from {outputs_from}) need an estimated {gb:.1} GB on {threads} threads, beyond --max-memory-gb {}. Use fewer outputs, fewer --threads, or raise --max-memory-gb",
            est.outputs(),
            budget.max_memory_gb
        )));
    }
    let events = expected_events(medium);
    let cost = est.event_cost().max(1.0);
    let work = paths * events * cost;
    if work < NO_PILOT_BELOW {
        return Ok(());
    }
    let floor = events * (FASTEST_EVENT + cost * FASTEST_UPDATE);
    let per_path = if floor > 1.0 {
        // a single path takes more than a second: time nothing, take the cheapest costs
        floor
    } else {
        // doubling batches of paths until the pilot has run long enough (or its share is done),
        // so that a cost model that is off cannot make the pilot itself long
        let cap = (PILOT_EVENTS / events)
            .min(PILOT_UPDATES / (events * cost))
            .clamp(1.0, 10_000.0) as u64;
        let mut scratch = est.scratch();
        let mut out = vec![C64::default(); est.outputs()];
        let mut rng = stream_rng(0x0050_494c_4f54, 0);
        let (mut done, mut batch) = (0u64, 1u64);
        let clock = PilotClock::start();
        // at least PILOT_MIN_TIME (one path may be far cheaper than the mean), at most PILOT_TIME
        while (done < cap || clock.wall() < PILOT_MIN_TIME) && clock.wall() < PILOT_TIME {
            est.run_chunk(&mut rng, batch, &mut scratch, &mut out);
            done += batch;
            batch *= 2;
        }
        (clock.elapsed().as_secs_f64() / done as f64).max(floor)
    };
    let seconds = paths * per_path / threads as f64;
    if seconds > 60.0 * budget.max_minutes {
        let tau = medium.sigma_s * medium.geometry.smallest_extent();
        return Err(Error::input(format!(
            "{what}: {paths:.3e} paths of ~{events:.3e} scattering events each, at a cost of {:.3e} output updates each (optical thickness σ_s·d = {tau:.3e} over the smallest extent, albedo {:.6}, g = {:.3}) would take an estimated {} on {threads} threads, beyond --max-minutes {}. Use fewer samples, {fewer}, more --threads or shards, or raise --max-minutes",
            est.event_cost().max(1.0),
            medium.albedo(),
            medium.mean_cosine(),
            duration(seconds),
            budget.max_minutes
        )));
    }
    Ok(())
}

/// Leapfrog steps a pilot ray of a ray command takes at most (a ray still inside then is counted
/// at the run's `max_steps`: trapped rays run to it).
const PILOT_STEPS: usize = 20_000;
/// Pilot rays, spread over the bundle.
const PILOT_RAYS: usize = 32;

/// The time of a ray command, before it starts: `passes` traces of every ray in `rays` through
/// `field` (at most `max_steps` steps each, or exactly that many with `fixed_steps`), timed on a
/// pilot of a few rays spread over the bundle, each cut at `PILOT_STEPS` steps. An error naming
/// `what` (and what a pass is, `pass`) when beyond `budget.max_minutes`.
#[allow(clippy::too_many_arguments)]
pub fn check_rays(
    what: &str,
    pass: &str,
    field: &crate::eikonal::BoundedField,
    rays: &[(glam::DVec3, glam::DVec3)],
    step: f64,
    max_steps: usize,
    fixed_steps: bool,
    passes: f64,
    budget: &Budget,
) -> Result<()> {
    use crate::eikonal::Tracer;
    if budget.max_minutes.is_nan() || budget.max_minutes <= 0.0 {
        return Err(Error::input(format!(
            "--max-minutes {}: must be > 0",
            budget.max_minutes
        )));
    }
    if rays.is_empty() {
        return Ok(());
    }
    let pilot = Tracer {
        field,
        step,
        max_steps: max_steps.min(PILOT_STEPS),
    };
    let every = rays.len().div_ceil(PILOT_RAYS);
    let (mut traced, mut stepped, mut steps) = (0usize, 0usize, 0.0);
    let clock = PilotClock::start();
    for &(o, d) in rays.iter().step_by(every) {
        let end = pilot.trace(o, d);
        traced += 1;
        stepped += end.steps;
        // a ray the pilot left inside runs on to max_steps; with fixed steps every ray runs them
        steps += if fixed_steps || (end.entered && !end.exited) {
            max_steps as f64
        } else {
            end.steps as f64
        };
    }
    let per_step = clock.elapsed().as_secs_f64() / stepped.max(1) as f64;
    let per_ray = steps / traced as f64;
    let threads = rayon::current_num_threads();
    let seconds = passes * rays.len() as f64 * per_ray * per_step / threads as f64;
    if seconds > 60.0 * budget.max_minutes {
        return Err(Error::input(format!(
            "{what}: {} rays of ~{per_ray:.3e} leapfrog steps each at {:.3e} s per step (timed on {traced} rays), traced {passes:.0} times ({pass}), would take an estimated {} on {threads} threads, beyond --max-minutes {}. Use fewer rays, fewer iterations, a coarser trace.step, more --threads, or raise --max-minutes",
            rays.len(),
            per_step,
            duration(seconds),
            budget.max_minutes
        )));
    }
    Ok(())
}

/// The memory, in GB, of running `chunks` chunks of `est` on the current threads, keeping `kept`
/// outputs per chunk.
pub fn memory_gb<E: Estimator>(est: &E, kept: usize, chunks: u64) -> f64 {
    let threads = rayon::current_num_threads();
    working_bytes(est.outputs(), est.scratch_bytes(), kept, chunks, threads) / 1e9
}

/// A pilot's clock: it measures by the CPU time of the thread running it where the system
/// reports it (on a busy machine the wall clock would count the time other processes take, and
/// refuse runs that would fit), else by the wall clock; the pilot stops by the wall clock, so it
/// never holds up the run, or an interrupt, longer on a busy machine.
struct PilotClock {
    wall: Instant,
    cpu: Option<std::time::Duration>,
}

impl PilotClock {
    fn start() -> Self {
        PilotClock {
            wall: Instant::now(),
            cpu: thread_cpu_time(),
        }
    }

    /// The time the pilot's own work has taken.
    fn elapsed(&self) -> std::time::Duration {
        match (self.cpu, thread_cpu_time()) {
            (Some(start), Some(now)) => now.saturating_sub(start),
            _ => self.wall.elapsed(),
        }
    }

    /// The time since the pilot started.
    fn wall(&self) -> std::time::Duration {
        self.wall.elapsed()
    }
}

/// The CPU time the calling thread has used, where the system reports it.
#[cfg(unix)]
fn thread_cpu_time() -> Option<std::time::Duration> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `clock_gettime` only writes the `timespec` it is handed, which lives on this stack.
    let read = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (read == 0).then(|| std::time::Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32))
}

#[cfg(not(unix))]
fn thread_cpu_time() -> Option<std::time::Duration> {
    None
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The pilot's clock counts the thread's own work, not the wall clock's time: it stands
    /// still while the thread sleeps (as while other processes hold the CPUs) and runs while it
    /// computes.
    #[cfg(unix)]
    #[test]
    fn the_pilots_clock_counts_the_threads_own_time() {
        let clock = PilotClock::start();
        std::thread::sleep(std::time::Duration::from_millis(200));
        let slept = clock.elapsed();
        assert!(
            slept < std::time::Duration::from_millis(20),
            "{slept:?} counted over 200 ms asleep"
        );
        let mut x = 1.0f64;
        let wall = Instant::now();
        while clock.elapsed() <= slept + std::time::Duration::from_millis(5) {
            x = (x * 1.000_000_1).sin() + 1.0;
            assert!(wall.elapsed().as_secs() < 30, "the clock did not run");
        }
        assert!(x.is_finite());
    }
}
