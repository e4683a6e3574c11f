//! Every shipped config parses and validates (`lightpath check`), so examples never rot.

use std::process::Command;

#[test]
fn shipped_configs_check() {
    let dirs = [
        concat!(env!("CARGO_MANIFEST_DIR"), "/configs"),
        concat!(env!("CARGO_MANIFEST_DIR"), "/experiments"),
    ];
    let mut n = 0;
    for dir in dirs {
        for entry in walk(std::path::Path::new(dir)) {
            if entry.extension().is_some_and(|e| e == "toml") {
                let o = Command::new(env!("CARGO_BIN_EXE_lightpath"))
                    .arg("check")
                    .arg(&entry)
                    .output()
                    .unwrap();
                assert!(
                    o.status.success(),
                    "{}: {}",
                    entry.display(),
                    String::from_utf8_lossy(&o.stderr)
                );
                n += 1;
            }
        }
    }
    assert!(n >= 5, "found only {n} configs");
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                // experiments write their generated configs and results into out/ (not shipped)
                if !p.ends_with("out") {
                    out.extend(walk(&p))
                }
            } else {
                out.push(p)
            }
        }
    }
    out
}
