//! Shards on a real scheduler: `deploy/slurm/test.sh` installs and starts a one-node Slurm
//! (Debian's slurm-wlm and munge), submits covariance, speckle, wave-solver and refractive-render
//! runs as 4-task job arrays with dependent merge jobs, and checks the merged results equal one run
//! number for number. Needs root
//! and the package registry, so it is ignored in the normal run:
//! `cargo test --release --test slurm -- --ignored --nocapture`.

#[test]
#[ignore = "installs and starts Slurm (root, apt): cargo test --release --test slurm -- --ignored"]
fn slurm_job_arrays_merge_to_the_single_run() {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/deploy/slurm/test.sh");
    let o = std::process::Command::new(script).output().unwrap();
    let text =
        String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    eprintln!("{text}");
    assert!(o.status.success(), "{text}");
    assert_eq!(text.matches("merged equal one run").count(), 4, "{text}");
}
