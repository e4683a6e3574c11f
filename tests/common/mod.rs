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

/// A render scene with nothing but its step set: a clear unit sphere of `n = 1`, a point light at
/// its centre, no sensors; tests give what they need (`RenderScene { volume, light,
/// ..bare_scene(step) }`).
pub fn bare_scene(step: f64) -> lightpath::rrte::RenderScene {
    use glam::DVec3;
    use lightpath::eikonal::{BoundedField, Bounds, Profile};
    use lightpath::medium::{PhaseFunction, Scattering};
    use lightpath::rrte::{Light, RenderScene, Volume};
    RenderScene {
        volume: Volume {
            field: BoundedField::single(
                Profile::Constant { n: 1.0 },
                Bounds::Sphere { radius: 1.0 },
                1.0,
            ),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(PhaseFunction::Isotropic),
            density: None,
            parts: Vec::new(),
        },
        light: Light::Point {
            position: DVec3::ZERO,
        },
        sensors: vec![],
        probes: vec![],
        cameras: vec![],
        pinholes: vec![],
        surfaces: vec![],
        modulation: None,
        connections: Default::default(),
        reflections: 0,
        derivatives: vec![],
        tracing: Default::default(),
        transient: None,
        spectrum: None,
        step,
        max_steps: 100_000,
    }
}

/// A flux sensor on the plane `z`, facing +z, infinite.
pub fn flux(name: &str, z: f64) -> lightpath::rrte::Sensor {
    lightpath::rrte::Sensor::new(
        name.into(),
        lightpath::rrte::SensorKind::Flux,
        glam::DVec3::new(0.0, 0.0, z),
        glam::DVec3::Z,
        None,
        [1, 1],
    )
}

/// Render `scene` with `samples` photons (or camera paths) in 64 chunks from `seed`.
pub fn render(
    scene: &lightpath::rrte::RenderScene,
    samples: u64,
    seed: u64,
) -> (Estimate, lightpath::rrte::ParticleTracer<'_>) {
    let est = lightpath::rrte::ParticleTracer::new(scene);
    let e = estimate(&est, &Plan::new(seed, samples, samples / 64));
    (e, est)
}

/// Channel `name` of an EXR file's first layer (top row first) and the image's (width, height).
pub fn exr_channel(path: &std::path::Path, name: &str) -> ((usize, usize), Vec<f32>) {
    let img = exr::prelude::read_first_flat_layer_from_file(path).unwrap();
    let size = (img.layer_data.size.0, img.layer_data.size.1);
    let c = img.layer_data.channel_data.list.iter();
    let c = c.clone().find(|c| c.name.to_string() == name).unwrap();
    match &c.sample_data {
        exr::prelude::FlatSamples::F32(v) => (size, v.clone()),
        _ => panic!("{name} is not f32"),
    }
}
