//! Results do not depend on the thread count, and shards merged equal the single run bit for bit
//! (engine level and through the command line, for every run kind).

use lightpath::mc::{Plan, merge, run};
use lightpath::speckle::Covariance;
use std::path::{Path, PathBuf};
use std::process::Command;

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
[[light]]
kind = "point"
position = [1.0, 0.0, -6.0]
[[view]]
kind = "far_field_ring"
start = [0.0, 0.0, 1.0]
axis = [0.0, 1.0, 0.0]
count = 6
[memory_effect]
angles_deg = [1.0, 3.0]
[speckle]
realisations = 3
paths = 900
[render]
samples = 7000
chunk = 300
seed = 4
"#;

#[test]
fn one_and_two_threads_agree_bitwise() {
    let cfg = lightpath::config::Config::from_toml(SCENE, None).unwrap();
    let scene = cfg.scene().unwrap();
    let est = Covariance::all_pairs(&scene, true).unwrap();
    let plan = Plan::new(4, 7000, 300);
    let go = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            merge(
                run(&est, &plan, 0..plan.chunks, &[0, 5], &|_| {}),
                plan.chunks,
            )
            .unwrap()
        })
    };
    assert_eq!(go(1), go(2));
}

fn lightpath(args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn numbers(path: &Path, keys: &[&str]) -> Vec<String> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    keys.iter().map(|k| v[k].to_string()).collect()
}

fn shards_equal_single(cmd: &str, file: &str, keys: &[&str]) {
    let d: PathBuf =
        std::env::temp_dir().join(format!("lightpath-shards-{}-{cmd}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let cfg = d.join("scene.toml");
    std::fs::write(&cfg, SCENE).unwrap();
    let c = cfg.to_str().unwrap();
    let single = d.join("single");
    lightpath(&[cmd, c, "--out", single.to_str().unwrap(), "--threads", "2"]);
    let mut shards = Vec::new();
    for i in 0..3 {
        let s = d.join(format!("shard-{i}"));
        lightpath(&[
            cmd,
            c,
            "--out",
            s.to_str().unwrap(),
            "--shard",
            &format!("{i}/3"),
            "--threads",
            "1",
        ]);
        assert!(!s.join(file).exists(), "a shard must not write a result");
        shards.push(s.to_str().unwrap().to_string());
    }
    let merged = d.join("merged");
    let mut args = vec!["merge"];
    args.extend(shards.iter().rev().map(|s| s.as_str()));
    args.extend(["--out", merged.to_str().unwrap()]);
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(&args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (
        numbers(&single.join(file), keys),
        numbers(&merged.join(file), keys),
    );
    assert!(a.iter().all(|s| s.len() > 20), "results missing: {a:?}");
    assert_eq!(a, b);
    // a missing shard is an error, not a silently partial result
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "merge",
            &shards[0],
            &shards[2],
            "--out",
            d.join("partial").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("missing"));
    assert!(!d.join("partial").join(file).exists());
}

#[test]
fn covariance_shards_merge_bitwise() {
    shards_equal_single(
        "covariance",
        "covariance.json",
        &["re", "im", "stderr", "single_re", "multiple_im", "mean_re"],
    );
}

#[test]
fn memory_effect_shards_merge_bitwise() {
    shards_equal_single(
        "memory-effect",
        "memory_effect.json",
        &["correlation", "correlation_stderr"],
    );
}

#[test]
fn speckle_shards_merge_bitwise() {
    shards_equal_single("speckle", "speckle.json", &["re", "im"]);
}

/// Run `lightpath` and return (exit code, stderr).
fn lightpath_status(args: &[&str]) -> (i32, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn damaged_or_edited_shards_are_refused() {
    let d: PathBuf =
        std::env::temp_dir().join(format!("lightpath-bad-shards-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let cfg = d.join("scene.toml");
    std::fs::write(&cfg, SCENE.replace("samples = 7000", "samples = 1200")).unwrap();
    let shard = |i: u32| d.join(format!("shard-{i}"));
    for i in 0..2 {
        let s = shard(i);
        lightpath(&[
            "covariance",
            cfg.to_str().unwrap(),
            "--out",
            s.to_str().unwrap(),
            "--shard",
            &format!("{i}/2"),
        ]);
    }
    let good = std::fs::read(shard(1).join("state.bin")).unwrap();
    let merge_with = |bytes: &[u8], expect: &str| {
        let bad = d.join("bad");
        std::fs::create_dir_all(&bad).unwrap();
        std::fs::write(bad.join("state.bin"), bytes).unwrap();
        let out = d.join("merged");
        let (code, err) = lightpath_status(&[
            "merge",
            shard(0).to_str().unwrap(),
            bad.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(code, 2, "{expect}: {err}");
        assert!(err.contains(expect), "expected {expect:?} in {err}");
        assert!(!out.join("covariance.json").exists());
    };
    // one flipped bit in the numbers (it once changed a merged entry 8.62 → 7.75 silently)
    let mut flipped = good.clone();
    let at = flipped.len() - 40;
    flipped[at] ^= 0x10;
    merge_with(&flipped, "checksum mismatch");
    // truncated
    merge_with(&good[..good.len() / 2], "checksum mismatch");
    merge_with(&good[..10], "truncated");
    // a header edited with its checksum recomputed (as a tool would): the blocks no longer fit
    let text = String::from_utf8_lossy(&good).into_owned();
    assert!(
        text.contains("\"count\":6"),
        "the header echoes the view count"
    );
    let start = good.windows(10).position(|w| w == b"\"count\":6,").unwrap();
    let mut edited = good.clone();
    edited[start + 8] = b'5';
    let body = edited.len() - 4;
    let crc = crc32fast::hash(&edited[..body]);
    edited[body..].copy_from_slice(&crc.to_le_bytes());
    merge_with(&edited, "different run");
    // the same edit on both shards: the header agrees with itself but not with the numbers
    let own = std::fs::read(shard(0).join("state.bin")).unwrap();
    let start0 = own.windows(10).position(|w| w == b"\"count\":6,").unwrap();
    let mut own_edited = own.clone();
    own_edited[start0 + 8] = b'5';
    let body0 = own_edited.len() - 4;
    let crc0 = crc32fast::hash(&own_edited[..body0]);
    own_edited[body0..].copy_from_slice(&crc0.to_le_bytes());
    std::fs::write(shard(0).join("state.bin"), &own_edited).unwrap();
    merge_with(&edited, "does not fit the run");
}

/// Run `args` (which write into `out`) and kill it with SIGKILL `kills` times, each a random moment
/// (0–30 ms) after it saved a new `checkpoint.bin`, resuming it from that checkpoint each time;
/// then let it finish. Returns how often it was killed and resumed.
fn kill_and_resume(args: &[&str], out: &Path, kills: usize, seed: u64) -> (usize, usize) {
    use std::os::unix::fs::MetadataExt;
    let checkpoint = out.join("checkpoint.bin");
    // checkpoints are written under another name and renamed: a new save is a new inode
    let saved = || std::fs::metadata(&checkpoint).ok().map(|m| m.ino());
    let mut rng = seed;
    let (mut killed, mut resumed) = (0, 0);
    loop {
        let mut a = args.to_vec();
        if saved().is_some() {
            a.extend(["--resume", out.to_str().unwrap()]);
            resumed += 1;
        }
        let before = saved();
        let mut child = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args(&a)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        if killed == kills {
            let status = child.wait().unwrap();
            assert!(
                status.success() || status.code() == Some(3),
                "{a:?}: {status}"
            );
            return (killed, resumed);
        }
        while child.try_wait().unwrap().is_none() && saved() == before {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        std::thread::sleep(std::time::Duration::from_millis((rng >> 33) % 30));
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap(); // SIGKILL
            killed += 1;
        }
        child.wait().unwrap();
        if !checkpoint.exists() {
            // finished before the kill: no checkpoint to resume
            return (killed, resumed);
        }
    }
}

/// A run killed with SIGKILL at arbitrary moments and resumed from its checkpoint, again and again,
/// ends with the same bytes as an uninterrupted run (covariance and speckle); a checkpoint is not
/// resumed by another run, and a finished run leaves none behind.
#[test]
fn killed_and_resumed_runs_equal_uninterrupted_ones() {
    let d: PathBuf = std::env::temp_dir().join(format!("lightpath-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let cfg = d.join("scene.toml");
    // a few seconds of chunks, so that kills land mid-run
    let text = SCENE
        .replace("samples = 7000", "samples = 12000000")
        .replace("realisations = 3", "realisations = 150")
        .replace("paths = 900", "paths = 50000");
    std::fs::write(&cfg, &text).unwrap();
    let c = cfg.to_str().unwrap();
    for (cmd, file, keys, every) in [
        (
            "covariance",
            "covariance.json",
            &["re", "im", "stderr"][..],
            "100",
        ),
        ("speckle", "speckle.json", &["re", "im"][..], "1"),
    ] {
        let whole = d.join(format!("{cmd}-whole"));
        lightpath(&[cmd, c, "--out", whole.to_str().unwrap()]);
        let out = d.join(format!("{cmd}-killed"));
        let o = out.to_str().unwrap();
        let args = [cmd, c, "--out", o, "--checkpoint-every", every, "--quiet"];
        let (kills, resumes) = kill_and_resume(&args, &out, 3, 0x9e37_79b9);
        assert!(
            kills >= 2 && resumes >= 2,
            "{cmd}: {kills} kills, {resumes} resumes: the run ended before it was interrupted twice"
        );
        assert!(out.join(file).exists(), "{cmd}: no result after resuming");
        assert!(
            !out.join("checkpoint.bin").exists(),
            "a finished run keeps no checkpoint"
        );
        assert_eq!(
            numbers(&whole.join(file), keys),
            numbers(&out.join(file), keys),
            "{cmd}: resumed after {kills} kills differs from the uninterrupted run"
        );
    }
    // a checkpoint of another run is refused
    let out = d.join("other");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args([
            "covariance",
            c,
            "--out",
            out.to_str().unwrap(),
            "--checkpoint-every",
            "1",
            "--quiet",
        ])
        .spawn()
        .unwrap();
    for _ in 0..200 {
        if out.join("checkpoint.bin").exists() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(out.join("checkpoint.bin").exists());
    let (code, err) = lightpath_status(&[
        "covariance",
        c,
        "--out",
        out.to_str().unwrap(),
        "--resume",
        out.to_str().unwrap(),
        "--seed",
        "5",
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("another run"), "{err}");
}

/// A result file as JSON without its wall-clock time.
fn without_seconds(path: &Path) -> serde_json::Value {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    v.as_object_mut().unwrap().remove("seconds");
    v
}

/// Fits and designs killed with SIGKILL just after a checkpoint, three times, and resumed each time
/// end with the same result file as an uninterrupted run: the material fit (L-BFGS stages), an Adam
/// fit (stochastic gradients, a fresh seed per iteration, tail averaging), a grid design (Adam over
/// three grid levels), a GRIN parameter fit (L-BFGS on the exit adjoint) and render designs (Adam
/// through the rendered target's forward sensitivities, fresh photons per step; L-BFGS on held
/// photons). A checkpoint is not
/// resumed with other options, and a refused resume leaves the folder's results alone.
#[test]
fn killed_and_resumed_fits_and_designs_equal_uninterrupted_ones() {
    let d: PathBuf =
        std::env::temp_dir().join(format!("lightpath-resume-fits-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let truth = SCENE
        .replace(
            "[[light]]\nkind = \"point\"\nposition = [1.0, 0.0, -6.0]\n",
            "",
        )
        .replace("samples = 7000", "samples = 100000");
    std::fs::write(d.join("truth.toml"), &truth).unwrap();
    let target = d.join("target");
    lightpath(&[
        "covariance",
        d.join("truth.toml").to_str().unwrap(),
        "--out",
        target.to_str().unwrap(),
    ]);
    let start = truth
        .replace("mfp = 2.0", "mfp = 4.0")
        .replace("samples = 100000", "samples = 20000")
        .replace("seed = 4", "seed = 2");
    std::fs::write(d.join("start.toml"), start).unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let fibre = std::fs::read_to_string(repo.join("experiments/grin-fibre/fibre.toml"))
        .unwrap()
        .replace("step = 0.005", "step = 0.001");
    std::fs::write(d.join("fibre.toml"), fibre).unwrap();
    let (s, t) = (d.join("start.toml"), target.join("covariance.json"));
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());
    let luneburg = repo.join("experiments/luneburg-design/luneburg.toml");
    let fibre = d.join("fibre.toml");
    // a render design: a graded ball's grading toward more light on a target
    let render = d.join("render.toml");
    std::fs::write(
        &render,
        "[field]\nbounds = { kind = \"sphere\", radius = 1.0 }\nn_out = 1.0\n[[field.profiles]]\nkind = \"spherical_polynomial\"\nn0 = 1.3\ncoefficients = [0.0, 0.0]\n[medium]\nsigma_s = 1.5\nsigma_a = 0.2\n[light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -2.0]\ndirection = [0.0, 0.0, 1.0]\nradius = 0.6\n[[sensor]]\nkind = \"target\"\nname = \"spot\"\ncenter = [0.0, 0.1, 0.55]\nradius = 0.3\n[render]\nstep = 0.01\n[design]\nmaximize = \"spot\"\nparameters = [{ name = \"profiles[0].c2\", min = -0.3, max = 0.3 }]\niterations = 12\nphotons = 1500\nlearning_rate = 0.3\nverify_photons = 3000\n",
    )
    .unwrap();
    // the same by L-BFGS on held photons, two parameters
    let render_lbfgs = d.join("render-lbfgs.toml");
    std::fs::write(
        &render_lbfgs,
        std::fs::read_to_string(&render).unwrap().replace(
            "parameters = [{ name = \"profiles[0].c2\", min = -0.3, max = 0.3 }]",
            "method = \"lbfgs\"\nparameters = [{ name = \"profiles[0].c2\", min = -0.3, max = 0.3 }, { name = \"profiles[0].n0\", min = 1.1, max = 1.6 }]",
        ),
    )
    .unwrap();
    let adam = [
        "fit",
        s,
        "--target",
        t,
        "--fit",
        "mfp,albedo",
        "--optimizer",
        "adam",
        "--iterations",
        "60",
        "--learning-rate",
        "0.1",
    ];
    let cases: [(&str, Vec<&str>, &str, &str); 6] = [
        (
            "lbfgs",
            vec!["fit", s, "--target", t, "--fit", "mfp,albedo"],
            "fit.json",
            "1",
        ),
        ("adam", adam.to_vec(), "fit.json", "1"),
        (
            "grid",
            vec!["design", luneburg.to_str().unwrap()],
            "design.json",
            "5",
        ),
        (
            "params",
            vec!["design", fibre.to_str().unwrap()],
            "fit.json",
            "1",
        ),
        (
            "render",
            vec!["design", render.to_str().unwrap()],
            "render_design.json",
            "1",
        ),
        (
            "render-lbfgs",
            vec!["design", render_lbfgs.to_str().unwrap()],
            "render_design.json",
            "1",
        ),
    ];
    for (name, args, file, every) in &cases {
        let whole = d.join(format!("{name}-whole"));
        let mut a = args.clone();
        a.extend(["--out", whole.to_str().unwrap(), "--quiet"]);
        let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args(&a)
            .output()
            .unwrap();
        assert!(
            o.status.success() || o.status.code() == Some(3),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let out = d.join(format!("{name}-killed"));
        let mut a = args.clone();
        a.extend([
            "--out",
            out.to_str().unwrap(),
            "--quiet",
            "--checkpoint-every",
            every,
        ]);
        let (kills, resumes) = kill_and_resume(&a, &out, 3, 0x2545_f491 + name.len() as u64);
        eprintln!("{name}: {kills} kills, {resumes} resumes");
        assert!(
            kills >= 2 && resumes >= 2,
            "{name}: {kills} kills, {resumes} resumes"
        );
        assert!(
            !out.join("checkpoint.bin").exists(),
            "{name}: a finished run keeps no checkpoint"
        );
        assert_eq!(
            without_seconds(&whole.join(file)),
            without_seconds(&out.join(file)),
            "{name}: resumed after {kills} kills differs from the uninterrupted run"
        );
    }
    // a checkpoint of a fit with other options is refused, and the refusal changes nothing
    let out = d.join("adam-killed");
    let o = out.to_str().unwrap();
    let mut a = adam.to_vec();
    a.extend(["--out", o, "--quiet", "--checkpoint-every", "1"]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(&a)
        .spawn()
        .unwrap();
    while !out.join("checkpoint.bin").exists() && child.try_wait().unwrap().is_none() {
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    std::fs::write(out.join("fit.json"), b"kept").unwrap();
    let mut other = adam.to_vec();
    other[9] = "61";
    other.extend(["--out", o, "--resume", o]);
    let (code, err) = lightpath_status(&other);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("another run"), "{err}");
    assert_eq!(std::fs::read(out.join("fit.json")).unwrap(), b"kept");
    let none = d.join("lbfgs-whole");
    let (code, err) = lightpath_status(&[
        "design",
        fibre.to_str().unwrap(),
        "--out",
        none.to_str().unwrap(),
        "--resume",
        none.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("no checkpoint.bin"), "{err}");
}
