//! The integration tests, one module per subject, built as one test binary (one link, and one
//! pool of test threads across every subject): `cargo test --release` runs them all, and
//! `cargo test --release render_volumes::` the tests of one subject.

mod acoustic;
mod acquire_phase;
mod adjoint_memory;
mod burn_bridge;
mod cli_errors;
mod common;
mod configs;
mod determinism;
mod eikonal;
mod eikonal_design;
mod eikonal_fit;
mod fit;
mod fit_convergence;
mod fuzz;
mod gradients;
mod intensity_vs_path_tracer;
mod kubernetes;
mod layers;
mod mie;
mod near_field;
mod outputs;
mod phase_fit;
mod phase_sampling;
mod render_cli;
mod render_density;
mod render_derivatives;
mod render_field_derivatives;
mod render_paths;
mod render_physics;
mod render_sdf;
mod render_spectral;
mod render_surfaces;
mod render_volumes;
mod single_scattering;
mod slurm;
mod speckle_physics;
mod wave;
