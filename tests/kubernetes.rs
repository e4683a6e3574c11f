//! The Kubernetes manifests' commands, run as their pods would run them: `deploy/kubernetes/
//! shards.yaml`'s shell command once per completion index (with `JOB_COMPLETION_INDEX` set, the
//! shared volume and the scene's config map as folders), one pod killed part-way and restarted
//! as `backoffLimitPerIndex` would restart it (resuming from its checkpoint), then `merge.yaml`'s
//! command. The merged result must equal one run of the same scene number for number. (No cluster
//! here: what Kubernetes itself does — scheduling, the index variable, restarts — is assumed.)

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const SCENE: &str = r#"
wavelength = 1.0
[medium]
box = [5.0, 5.0, 3.0]
mfp = 2.0
albedo = 0.9
phase = { kind = "hg", g = 0.4 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field_ring"
start = [0.0, 0.0, 1.0]
axis = [0.0, 1.0, 0.0]
count = 6
[render]
samples = 1600000
chunk = 2000
seed = 4
"#;

/// The folded block scalar (`- >-`) that follows the line holding `marker`: its lines joined
/// by spaces (what the manifest hands `sh -c`).
fn folded_after(yaml: &str, marker: &str) -> String {
    let mut lines = yaml.lines().skip_while(|l| !l.contains(marker)).skip(1);
    assert_eq!(
        lines.next().map(str::trim),
        Some("- >-"),
        "{marker} holds no folded block"
    );
    let head = lines.next().expect("the block's first line");
    let indent = head.len() - head.trim_start().len();
    std::iter::once(head)
        .chain(
            lines.take_while(|l| l.len() - l.trim_start().len() >= indent && !l.trim().is_empty()),
        )
        .map(str::trim)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The value of the first `key: value` line.
fn value<'a>(yaml: &'a str, key: &str) -> &'a str {
    yaml.lines()
        .find_map(|l| l.trim().strip_prefix(key))
        .expect(key)
        .trim()
}

/// `sh -c script` as a pod runs it: the volume and the config map at `root`, `lightpath` on the
/// path, and the completion index in the environment.
fn pod(script: &str, root: &Path, index: Option<usize>) -> Command {
    let script = script
        .replace("/runs", root.join("runs").to_str().unwrap())
        .replace("/config", root.join("config").to_str().unwrap());
    let bin = Path::new(env!("CARGO_BIN_EXE_lightpath")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut c = Command::new("sh");
    c.args(["-c", &script])
        .env("PATH", path)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    if let Some(i) = index {
        c.env("JOB_COMPLETION_INDEX", i.to_string());
    }
    c
}

fn numbers(path: &Path) -> Vec<String> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    ["re", "im", "stderr", "paths"]
        .iter()
        .map(|k| v[k].to_string())
        .collect()
}

#[test]
fn indexed_job_pods_and_merge_equal_one_run() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let shards = std::fs::read_to_string(repo.join("deploy/kubernetes/shards.yaml")).unwrap();
    let merge = std::fs::read_to_string(repo.join("deploy/kubernetes/merge.yaml")).unwrap();
    let root: PathBuf =
        std::env::temp_dir().join(format!("lightpath-kubernetes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("config")).unwrap();
    std::fs::create_dir_all(root.join("runs")).unwrap();
    std::fs::write(root.join("config/scene.toml"), SCENE).unwrap();

    let script = folded_after(&shards, "args:");
    let n: usize = value(&shards, "completions:").parse().unwrap();
    assert!(
        script.contains(&format!("--shard $JOB_COMPLETION_INDEX/{n}")),
        "{script}"
    );
    assert_eq!(value(&shards, "completionMode:"), "Indexed");

    // pod 3 saves a checkpoint and is killed, once with another seed: a pod restarted onto that
    // checkpoint must pass --resume (and be refused), and then resume its own
    let (killed, dir) = (3, root.join("runs/shard-3"));
    let interrupted = |extra: &str| {
        let script = format!("{script} --checkpoint-every 1 {extra}");
        let mut first = pod(&script, &root, Some(killed)).spawn().unwrap();
        while !dir.join("checkpoint.bin").exists() && first.try_wait().unwrap().is_none() {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        first.kill().unwrap();
        first.wait().unwrap();
        assert!(
            dir.join("checkpoint.bin").exists(),
            "the first attempt saved no checkpoint"
        );
    };
    interrupted("--seed 5");
    let o = pod(&script, &root, Some(killed)).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("another run"), "{err}");
    std::fs::remove_file(dir.join("checkpoint.bin")).unwrap();
    interrupted("");
    for i in 0..n {
        let status = pod(&script, &root, Some(i)).status().unwrap();
        assert!(status.success(), "pod {i}: {status}");
        assert!(!root.join(format!("runs/shard-{i}/checkpoint.bin")).exists());
    }

    let merge_script = merge
        .lines()
        .find_map(|l| l.trim().strip_prefix("command: [\"sh\", \"-c\", \""))
        .and_then(|l| l.strip_suffix("\"]"))
        .expect("merge.yaml's command");
    let status = pod(merge_script, &root, None).status().unwrap();
    assert!(status.success(), "merge: {status}");

    let one = root.join("one");
    let status = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "covariance",
            root.join("config/scene.toml").to_str().unwrap(),
            "--out",
        ])
        .arg(&one)
        .arg("--quiet")
        .status()
        .unwrap();
    assert!(status.success());
    assert_eq!(
        numbers(&root.join("runs/merged/covariance.json")),
        numbers(&one.join("covariance.json")),
        "the merged pods differ from one run"
    );
}
