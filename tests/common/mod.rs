//! Helpers shared by the integration tests.
#![allow(dead_code)]

use lightpath::mc::{Estimate, Estimator, Plan, merge, run};
use lightpath::speckle::{Scene, wave};

/// Run every chunk of `plan` and reduce to means with standard errors.
pub fn estimate<E: Estimator>(e: &E, plan: &Plan) -> Estimate {
    Estimate::from_block(
        &merge(run(e, plan, 0..plan.chunks, &[], &|_| {}), plan.chunks).unwrap(),
        plan,
    )
}

/// Mean and covariance over `reals` scatterer placements, as `lightpath wave` computes them:
/// placements as an engine estimator (one per chunk, every field kept), reduced by
/// `WaveStatistics`.
pub fn wave_statistics(scene: &Scene, reals: u64, seed: u64) -> wave::WaveStatistics {
    let est = wave::Realizations::new(scene);
    let plan = Plan {
        seed,
        chunk_paths: 1,
        chunks: reals,
    };
    let root = merge(
        run(&est, &plan, 0..reals, &est.kept_outputs(), &|_| {}),
        reals,
    )
    .unwrap();
    wave::WaveStatistics::from_fields(&root.kept, est.fields())
}
