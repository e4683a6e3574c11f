//! Mutants of every shipped config and of fit targets, run through the command line as a new user
//! would: deleted keys, wrong types, NaN/±inf/huge/tiny/negative/zero values, empty and very long
//! arrays, unknown keys, truncated files. Every mutant must end in a result with finite numbers or
//! in a clear refusal (exit 2 naming the key, the file position or the limit to change): never a
//! panic, an abort, a hang past the stated budget or a non-finite number written. A deterministic
//! sample runs with the tests; the full corpus (over 3 000 mutants) is `#[ignore]`d:
//! `cargo test --release --test fuzz -- --ignored --nocapture`. The extreme-physics sweep (legal
//! but far from the usual values) runs with the tests.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A run that takes longer than this is a hang (the runs are asked for a 0.5-minute budget).
const HANG: Duration = Duration::from_secs(90);

/// The shipped configs and the command each one is run with.
const CONFIGS: &[(&str, &str)] = &[
    ("configs/backscatter.toml", "covariance"),
    ("configs/correlation_map.toml", "correlation-map"),
    ("configs/covariance_box.toml", "covariance"),
    ("configs/luneburg.toml", "trace"),
    ("configs/near_field_speckle.toml", "speckle"),
    ("configs/quickstart.toml", "memory-effect"),
    ("configs/render_camera.toml", "render"),
    ("configs/render_density.toml", "render"),
    ("configs/render_fluence.toml", "render"),
    ("configs/render_glass.toml", "render"),
    ("configs/render_luneburg.toml", "render"),
    ("configs/render_path.toml", "render"),
    ("configs/render_sdf.toml", "render"),
    ("configs/render_slab.toml", "render"),
    ("configs/render_spectral.toml", "render"),
    ("configs/render_tank.toml", "render"),
    ("configs/render_ultrasonic.toml", "render"),
    ("configs/speckle_grid.toml", "speckle"),
    ("configs/tabulated.toml", "covariance"),
    ("configs/tilt_shift.toml", "tilt-shift"),
    ("configs/ultrasonic_lens.toml", "trace"),
    ("experiments/grin-fibre/fibre.toml", "design"),
];

/// One step into a TOML document.
#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

/// A mutant: what was changed (for reports), the key names an error may mention (the mutated
/// path's, or any key of the file written as a key reference: `key.`, `key[`, `key =`, `key:`),
/// and the text.
struct Mutant {
    what: String,
    keys: Vec<String>,
    text: String,
}

/// Every key name in a TOML document.
fn key_names(v: &toml::Value, out: &mut Vec<String>) {
    match v {
        toml::Value::Table(t) => {
            for (k, x) in t {
                if !out.contains(k) {
                    out.push(k.clone());
                }
                key_names(x, out);
            }
        }
        toml::Value::Array(a) => a.iter().for_each(|x| key_names(x, out)),
        _ => {}
    }
}

/// Whether `err` names a key: one of `keys` anywhere, or one of `refs` as a key reference.
fn names_a_key(err: &str, keys: &[String], refs: &[String]) -> bool {
    keys.iter().any(|k| err.contains(k.as_str()))
        || refs.iter().any(|k| {
            [".", "[", " =", ":"]
                .iter()
                .any(|end| err.contains(&format!("{k}{end}")))
        })
        || ["line ", "--max-", "missing field", "TOML parse error"]
            .iter()
            .any(|n| err.contains(n))
}

fn at<'a>(v: &'a mut toml::Value, path: &[Step]) -> &'a mut toml::Value {
    path.iter().fold(v, |v, s| match s {
        Step::Key(k) => v.get_mut(k.as_str()).expect("key"),
        Step::Index(i) => v.get_mut(*i).expect("index"),
    })
}

/// Every path in the document (tables' keys and arrays' elements), depth first.
fn paths(v: &toml::Value, prefix: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    match v {
        toml::Value::Table(t) => {
            for (k, x) in t {
                prefix.push(Step::Key(k.clone()));
                out.push(prefix.clone());
                paths(x, prefix, out);
                prefix.pop();
            }
        }
        toml::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                prefix.push(Step::Index(i));
                // elements of number arrays are mutated through their array
                if x.is_table() || x.is_array() {
                    out.push(prefix.clone());
                }
                paths(x, prefix, out);
                prefix.pop();
            }
        }
        _ => {}
    }
}

fn describe(path: &[Step]) -> String {
    path.iter()
        .map(|s| match s {
            Step::Key(k) => format!(".{k}"),
            Step::Index(i) => format!("[{i}]"),
        })
        .collect()
}

/// The mutants of one document.
fn mutants(text: &str) -> Vec<Mutant> {
    let doc: toml::Value = toml::from_str(text).expect("shipped configs parse");
    let mut all = Vec::new();
    paths(&doc, &mut Vec::new(), &mut all);
    let mut out = Vec::new();
    let mut push = |path: &[Step], what: &str, doc: toml::Value| {
        let keys = path
            .iter()
            .filter_map(|s| match s {
                Step::Key(k) => Some(k.clone()),
                Step::Index(_) => None,
            })
            .collect();
        out.push(Mutant {
            what: format!("{} {what}", describe(path)),
            keys,
            text: toml::to_string(&doc).expect("mutants serialise"),
        });
    };
    for path in &all {
        let (parent, last) = path.split_at(path.len() - 1);
        let original = at(&mut doc.clone(), path).clone();
        let replaced = |v: toml::Value| {
            let mut d = doc.clone();
            *at(&mut d, path) = v;
            d
        };
        if let Step::Key(k) = &last[0] {
            let mut d = doc.clone();
            at(&mut d, parent).as_table_mut().expect("table").remove(k);
            push(path, "deleted", d);
        }
        push(
            path,
            "= \"oops\"",
            replaced(toml::Value::String("oops".into())),
        );
        push(path, "= true", replaced(toml::Value::Boolean(true)));
        match &original {
            toml::Value::Float(_) | toml::Value::Integer(_) => {
                for x in [
                    f64::NAN,
                    f64::INFINITY,
                    -f64::INFINITY,
                    1e308,
                    -1e308,
                    1e15,
                    1e12,
                    1e-12,
                    1e-308,
                    0.0,
                    -1.0,
                ] {
                    push(path, &format!("= {x:e}"), replaced(toml::Value::Float(x)));
                }
                for x in [0i64, -1, i64::MAX, 7200] {
                    push(path, &format!("= {x}"), replaced(toml::Value::Integer(x)));
                }
            }
            toml::Value::Array(a) => {
                push(path, "= []", replaced(toml::Value::Array(vec![])));
                if a.len() > 1 {
                    push(
                        path,
                        "cut to one",
                        replaced(toml::Value::Array(a[..1].to_vec())),
                    );
                }
                if let Some(first) = a.first() {
                    let long = vec![first.clone(); 1000];
                    push(path, "× 1000", replaced(toml::Value::Array(long)));
                    if first.is_float() || first.is_integer() {
                        let mut b = a.clone();
                        b[0] = toml::Value::Float(f64::NAN);
                        push(path, "[0] = nan", replaced(toml::Value::Array(b.clone())));
                        b[0] = toml::Value::Float(1e308);
                        push(path, "[0] = 1e308", replaced(toml::Value::Array(b)));
                    }
                }
            }
            toml::Value::Table(_) => {
                let mut d = doc.clone();
                at(&mut d, path)
                    .as_table_mut()
                    .expect("table")
                    .insert("bogus".into(), toml::Value::Float(1.0));
                push(path, "+ bogus key", d);
                push(path, "= 1.5", replaced(toml::Value::Float(1.5)));
            }
            toml::Value::String(_) => {
                push(path, "= \"\"", replaced(toml::Value::String(String::new())));
            }
            _ => {}
        }
    }
    // truncated files
    let n = text.len();
    for k in 1..=9 {
        let mut cut = n * k / 10;
        while !text.is_char_boundary(cut) {
            cut -= 1;
        }
        out.push(Mutant {
            what: format!("truncated at byte {cut}"),
            keys: vec![],
            text: text[..cut].to_string(),
        });
    }
    out
}

/// How a mutant ended.
#[derive(Debug, PartialEq)]
enum Verdict {
    Ok,
    Refused,
    /// Refused without naming a key, a file position or a limit.
    Unnamed(String),
    Panic(String),
    Abort,
    Hang,
    NonFinite(String),
}

/// Whether a JSON result holds a null where a number belongs (what a NaN becomes).
fn null_inside(v: &serde_json::Value, key: &str) -> bool {
    match v {
        serde_json::Value::Null => key != "seconds",
        serde_json::Value::Array(a) => a.iter().any(|x| null_inside(x, key)),
        serde_json::Value::Object(o) => o.iter().any(|(k, x)| null_inside(x, k)),
        _ => false,
    }
}

/// Run `args` with a time limit and judge it (`keys`, `refs`: see [`names_a_key`]).
fn judge(args: &[String], out: &Path, keys: &[String], refs: &[String]) -> Verdict {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightpath"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > HANG {
            let _ = child.kill();
            let _ = child.wait();
            return Verdict::Hang;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut err = String::new();
    use std::io::Read;
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    match status.code() {
        None => Verdict::Abort,
        Some(101) => Verdict::Panic(err),
        Some(0) | Some(3) => {
            for entry in std::fs::read_dir(out).into_iter().flatten().flatten() {
                let p = entry.path();
                if p.extension().is_some_and(|e| e == "json") {
                    let v: serde_json::Value =
                        serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
                    if null_inside(&v, "") {
                        return Verdict::NonFinite(p.display().to_string());
                    }
                }
            }
            Verdict::Ok
        }
        Some(_) if err.contains("panicked") => Verdict::Panic(err),
        Some(_) => {
            if names_a_key(&err, keys, refs) {
                Verdict::Refused
            } else {
                Verdict::Unnamed(err)
            }
        }
    }
}

/// The command line of a mutant run: small, bounded runs.
fn command(cmd: &str, cfg: &Path, out: &Path) -> Vec<String> {
    let mut a: Vec<String> = vec![cmd.into(), cfg.display().to_string()];
    a.extend(["--out".into(), out.display().to_string()]);
    if !matches!(cmd, "trace" | "design" | "check") {
        a.extend(
            [
                "--samples",
                "400",
                "--max-minutes",
                "0.5",
                "--max-memory-gb",
                "2",
                "--quiet",
            ]
            .map(String::from),
        );
    }
    if cmd != "check" {
        a.extend(["--threads".into(), "1".into()]);
    }
    a
}

/// Run every `stride`-th mutant of every config (on `workers` threads); the verdicts that fail.
fn corpus(stride: usize, workers: usize) -> (usize, Vec<(String, Verdict)>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let base: PathBuf =
        std::env::temp_dir().join(format!("lightpath-fuzz-{}-{stride}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    let mut jobs = Vec::new();
    for (c, cmd) in CONFIGS {
        let text = std::fs::read_to_string(root.join(c)).unwrap();
        let dir = root.join(c).parent().unwrap().to_path_buf();
        let mut refs = Vec::new();
        key_names(&toml::from_str(&text).unwrap(), &mut refs);
        for m in mutants(&text) {
            jobs.push((c.to_string(), cmd.to_string(), dir.clone(), refs.clone(), m));
        }
    }
    let jobs: Vec<_> = jobs.into_iter().step_by(stride).collect();
    let total = jobs.len();
    let jobs = Arc::new(jobs);
    let next = Arc::new(AtomicUsize::new(0));
    let bad = Arc::new(Mutex::new(Vec::new()));
    let handles: Vec<_> = (0..workers)
        .map(|w| {
            let (jobs, next, bad, base) = (jobs.clone(), next.clone(), bad.clone(), base.clone());
            std::thread::spawn(move || {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some((name, cmd, dir, refs, m)) = jobs.get(i) else {
                        break;
                    };
                    let work = base.join(format!("w{w}"));
                    let _ = std::fs::remove_dir_all(&work);
                    std::fs::create_dir_all(&work).unwrap();
                    // beside the original, so relative paths (tables, grids) still resolve
                    let cfg = dir.join(format!(".fuzz-{}-{w}.toml", std::process::id()));
                    std::fs::write(&cfg, &m.text).unwrap();
                    let out = work.join("out");
                    let v = judge(&command(cmd, &cfg, &out), &out, &m.keys, refs);
                    let _ = std::fs::remove_file(&cfg);
                    if !matches!(v, Verdict::Ok | Verdict::Refused) {
                        bad.lock().unwrap().push((format!("{name}: {}", m.what), v));
                    }
                }
            })
        })
        .collect();
    for h in handles {
        h.join().unwrap();
    }
    let _ = std::fs::remove_dir_all(&base);
    let bad = Arc::try_unwrap(bad).unwrap().into_inner().unwrap();
    (total, bad)
}

/// A small scene for fit-target mutants (its memory-effect curve and covariance are the targets).
const FIT_SCENE: &str = r#"
wavelength = 1.0
[medium]
slab = 20.0
mfp = 10.0
phase = { kind = "hg", g = 0.3 }
[[light]]
kind = "plane_wave"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.0, 1.0]
[[view]]
kind = "far_field"
direction = [0.0, 0.05, 1.0]
[memory_effect]
angles_deg = [0.1, 0.3]
[render]
samples = 2000
chunk = 250
"#;

/// Mutants of a JSON target: each key deleted, set to a string, null or an empty array; its first
/// number set to a string, negative or zero; an inner array cut short; the file truncated.
fn json_mutants(text: &str) -> Vec<Mutant> {
    let doc: serde_json::Value = serde_json::from_str(text).unwrap();
    let mut out = Vec::new();
    let obj = doc.as_object().unwrap();
    for key in obj.keys() {
        let mut edit = |what: &str, f: &dyn Fn(&mut serde_json::Value)| {
            let mut d = doc.clone();
            f(&mut d);
            out.push(Mutant {
                what: format!("{key} {what}"),
                keys: vec![key.clone()],
                text: d.to_string(),
            });
        };
        edit("deleted", &|d| {
            d.as_object_mut().unwrap().remove(key);
        });
        edit("= \"oops\"", &|d| d[key] = "oops".into());
        edit("= null", &|d| d[key] = serde_json::Value::Null);
        edit("= []", &|d| d[key] = serde_json::json!([]));
        // the first number inside, replaced
        for (what, v) in [
            ("first number = \"nan\"", serde_json::json!("nan")),
            ("first number = -1", serde_json::json!(-1.0)),
            ("first number = 0", serde_json::json!(0.0)),
            ("first number = 1e308", serde_json::json!(1e308)),
        ] {
            edit(what, &|d| {
                let mut ptr = format!("/{key}");
                while d
                    .pointer(&ptr)
                    .and_then(|x| x.as_array())
                    .is_some_and(|a| !a.is_empty())
                {
                    ptr += "/0";
                }
                if let Some(x) = d.pointer_mut(&ptr).filter(|x| x.is_number()) {
                    *x = v.clone();
                }
            });
        }
        edit("innermost array cut short", &|d| {
            let mut ptr = format!("/{key}");
            while d.pointer(&format!("{ptr}/0")).is_some_and(|f| f.is_array()) {
                ptr += "/0";
            }
            if let Some(a) = d.pointer_mut(&ptr).and_then(|x| x.as_array_mut()) {
                a.pop();
            }
        });
    }
    for k in 1..=4 {
        out.push(Mutant {
            what: format!("truncated to {k}/5"),
            keys: vec![],
            text: text[..text.len() * k / 5].to_string(),
        });
    }
    out
}

/// Fit-target mutants (of a memory-effect curve, a covariance and a CSV curve) run through `fit`,
/// every `stride`-th; the verdicts that fail.
fn target_corpus(stride: usize) -> (usize, Vec<(String, Verdict)>) {
    let base: PathBuf = std::env::temp_dir().join(format!(
        "lightpath-fuzz-targets-{}-{stride}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&base);
    std::fs::create_dir_all(&base).unwrap();
    let cfg = base.join("scene.toml");
    std::fs::write(&cfg, FIT_SCENE).unwrap();
    for cmd in ["memory-effect", "covariance"] {
        let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
            .args([
                cmd,
                cfg.to_str().unwrap(),
                "--out",
                base.join("t").to_str().unwrap(),
                "--quiet",
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let mut jobs = Vec::new();
    let mut refs: Vec<String> = Vec::new();
    for file in ["memory_effect.json", "covariance.json"] {
        let text = std::fs::read_to_string(base.join("t").join(file)).unwrap();
        let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
        refs.extend(doc.as_object().unwrap().keys().cloned());
        for m in json_mutants(&text) {
            jobs.push((file.to_string(), "json", m));
        }
    }
    let csv = "angle_deg,correlation,stderr\n0.1,0.9,0.01\n0.3,0.7,0.01\n";
    for (what, text) in [
        ("no rows", "angle_deg,correlation\n".to_string()),
        ("a word", csv.replace("0.9", "high")),
        ("nan", csv.replace("0.9", "nan")),
        ("stderr 0", csv.replace(",0.01\n0.3", ",0\n0.3")),
        ("stderr -1", csv.replace(",0.01\n0.3", ",-1\n0.3")),
        ("ragged", csv.replace(",0.01\n0.3", "\n0.3")),
        ("four columns", csv.replace(",0.01\n0.3", ",0.01,5\n0.3")),
        ("angle inf", csv.replace("0.3,", "inf,")),
    ] {
        jobs.push((
            "curve.csv".into(),
            "csv",
            Mutant {
                what: what.into(),
                keys: vec![
                    "line ".into(),
                    "stderr".into(),
                    "angle".into(),
                    "correlation".into(),
                ],
                text,
            },
        ));
    }
    let jobs: Vec<_> = jobs.into_iter().step_by(stride).collect();
    let mut bad = Vec::new();
    for (i, (file, ext, m)) in jobs.iter().enumerate() {
        let target = base.join(format!("target-{i}.{ext}"));
        std::fs::write(&target, &m.text).unwrap();
        let out = base.join(format!("fit-{i}"));
        let args: Vec<String> = [
            "fit",
            cfg.to_str().unwrap(),
            "--target",
            target.to_str().unwrap(),
            "--fit",
            "mfp",
            "--stages",
            "1",
            "--iterations",
            "2",
            "--samples",
            "300",
            "--threads",
            "1",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ]
        .map(String::from)
        .to_vec();
        let v = judge(&args, &out, &m.keys, &refs);
        if !matches!(v, Verdict::Ok | Verdict::Refused) {
            bad.push((format!("{file}: {}", m.what), v));
        }
    }
    let _ = std::fs::remove_dir_all(&base);
    (jobs.len(), bad)
}

fn report(total: usize, bad: &[(String, Verdict)]) {
    for (what, v) in bad {
        eprintln!("{what}: {v:?}");
    }
    assert!(
        bad.is_empty(),
        "{} of {total} mutants panicked, aborted, hung, wrote non-finite numbers or gave an error without its key",
        bad.len()
    );
}

#[test]
fn a_sample_of_the_mutant_corpus_ends_cleanly() {
    let (total, bad) = corpus(25, 2);
    report(total, &bad);
    assert!(total >= 100, "{total} mutants in the sample");
    let (total, bad) = target_corpus(7);
    report(total, &bad);
}

#[test]
#[ignore = "the full corpus takes several minutes: cargo test --release --test fuzz -- --ignored"]
fn the_full_mutant_corpus_ends_cleanly() {
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (configs, mut bad) = corpus(1, workers);
    let (targets, more) = target_corpus(1);
    bad.extend(more);
    let total = configs + targets;
    eprintln!("{configs} config mutants, {targets} target mutants");
    report(total, &bad);
    assert!(total >= 3000, "{total} mutants in the corpus");
}

/// Legal but extreme physics stays finite: g = ±0.999, optical depth 50, albedo 1e-9, a box of
/// 1e-6 λ or 1e4 λ (sparse), wavelengths 1e-6 and 1e6 of the box, grazing lights and views.
#[test]
fn extreme_physics_stays_finite() {
    let base = |medium: &str, wavelength: &str, light: &str, view: &str| {
        format!(
            "wavelength = {wavelength}\n[medium]\n{medium}\n[[light]]\nkind = \"plane_wave\"\ndirection = {light}\n[[view]]\nkind = \"far_field\"\ndirection = {view}\n[[view]]\nkind = \"far_field\"\ndirection = [0.0, 0.1, 1.0]\n[memory_effect]\nangles_deg = [0.5, 2.0]\n[render]\nsamples = 2000\nchunk = 250\n"
        )
    };
    let z = "[0.0, 0.0, 1.0]";
    let grazing = "[1.0, 0.0, 1e-6]";
    let cases = [
        (
            "g 0.999",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nphase = { kind = \"hg\", g = 0.999 }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "g -0.999",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nphase = { kind = \"hg\", g = -0.999 }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "OD 50",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 0.2\nalbedo = 0.99\nphase = { kind = \"hg\", g = 0.9 }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "albedo 1e-9",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nalbedo = 1e-9\nphase = { kind = \"isotropic\" }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "tiny box",
            base(
                "box = [1e-6, 1e-6, 1e-6]\nmfp = 5.0\nphase = { kind = \"isotropic\" }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "sparse wide box",
            base(
                "box = [1e4, 1e4, 1e4]\nmfp = 1e6\nphase = { kind = \"isotropic\" }",
                "1.0",
                z,
                z,
            ),
        ),
        (
            "short wavelength",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nphase = { kind = \"hg\", g = 0.5 }",
                "1e-5",
                z,
                z,
            ),
        ),
        (
            "long wavelength",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nphase = { kind = \"hg\", g = 0.5 }",
                "1e6",
                z,
                z,
            ),
        ),
        (
            "grazing light",
            base(
                "box = [10.0, 10.0, 10.0]\nmfp = 5.0\nphase = { kind = \"hg\", g = 0.5 }",
                "1.0",
                grazing,
                z,
            ),
        ),
        (
            "grazing view",
            base(
                "slab = 10.0\nmfp = 5.0\nphase = { kind = \"hg\", g = 0.5 }",
                "1.0",
                z,
                grazing,
            ),
        ),
    ];
    let d = std::env::temp_dir().join(format!("lightpath-extreme-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    for (name, text) in cases {
        for cmd in ["covariance", "memory-effect"] {
            let cfg = d.join("scene.toml");
            std::fs::write(&cfg, &text).unwrap();
            let out = d.join(format!("{}-{cmd}", name.replace(' ', "-")));
            let args: Vec<String> = [
                cmd,
                cfg.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--quiet",
            ]
            .map(String::from)
            .to_vec();
            let v = judge(&args, &out, &[], &[]);
            assert!(matches!(v, Verdict::Ok), "{name} ({cmd}): {v:?}");
        }
    }
}
