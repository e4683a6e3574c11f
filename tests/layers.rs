//! The layering of ARCHITECTURE.md holds: each top-level module of `src/` imports only modules
//! below it (no import cycles, nothing below `app` imports `app`). Would catch a lower layer reaching
//! up, such as an estimator importing the fit code or a result type importing the command layer.

use std::collections::BTreeSet;
use std::path::Path;

/// Layers from the bottom; a module may use modules of strictly lower rank.
const RANKS: [(&str, u32); 12] = [
    ("error", 0),
    ("math", 0),
    ("mc", 1),
    ("medium", 1),
    ("speckle", 2),
    ("eikonal", 2),
    ("rrte", 3),
    ("diff", 4),
    ("inverse", 5),
    ("config", 6),
    ("io", 7),
    ("app", 8),
];

fn rank(m: &str) -> Option<u32> {
    RANKS.iter().find(|(n, _)| *n == m).map(|(_, r)| *r)
}

fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The modules `crate::X` that a text names (the root re-exports `Error`, `Result` of `error`).
fn used(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in text.match_indices("crate::") {
        let rest = &text[i + 7..];
        let name: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let name = match name.as_str() {
            "Error" | "Result" => "error".to_string(),
            _ => name,
        };
        out.insert(name);
    }
    out
}

#[test]
fn modules_import_only_lower_layers() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut violations = Vec::new();
    let mut checked = 0;
    for (module, r) in RANKS {
        let mut files = Vec::new();
        let dir = src.join(module);
        if dir.is_dir() {
            sources(&dir, &mut files);
        }
        let file = src.join(format!("{module}.rs"));
        if file.is_file() {
            files.push(file);
        }
        assert!(!files.is_empty(), "no sources for module {module}");
        for f in files {
            checked += 1;
            let text = std::fs::read_to_string(&f).unwrap();
            for u in used(&text) {
                if u == module {
                    continue;
                }
                match rank(&u) {
                    Some(ru) if ru < r => {}
                    Some(_) => violations.push(format!("{} uses crate::{u}", f.display())),
                    None => violations.push(format!("{} uses unknown crate::{u}", f.display())),
                }
            }
        }
    }
    assert!(checked > 40, "only {checked} files checked");
    assert!(violations.is_empty(), "{}", violations.join("\n"));
}
