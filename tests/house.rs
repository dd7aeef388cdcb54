//! The repository's own rules, checked so that they hold after every change: every relative
//! link in the front door, the manual and the maps resolves; the README and ARCHITECTURE.md stay
//! short; the library's layers point down; no source file grows past 1,200 lines; the unit tests'
//! package depends on what the library depends on.

use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn markdown_files() -> Vec<PathBuf> {
    let root = Path::new(ROOT);
    let mut files = vec![
        root.join("README.md"),
        root.join("ARCHITECTURE.md"),
        root.join("scripts/README.md"),
    ];
    for dir in ["docs", "validation", "tests/data", "examples"] {
        let mut stack = vec![root.join(dir)];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.extension().is_some_and(|x| x == "md") {
                    files.push(p);
                }
            }
        }
    }
    files.sort();
    files
}

/// The targets of `[text](target)` and `![alt](target)` links in Markdown, code spans and
/// fenced blocks left out.
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Drop code spans: a link inside backticks is text.
        let mut plain = String::new();
        for (i, part) in line.split('`').enumerate() {
            if i % 2 == 0 {
                plain.push_str(part);
            }
        }
        let mut rest = plain.as_str();
        while let Some(k) = rest.find("](") {
            let after = &rest[k + 2..];
            let Some(end) = after.find(')') else { break };
            out.push(after[..end].to_string());
            rest = &after[end..];
        }
    }
    out
}

#[test]
fn every_relative_link_resolves() {
    let mut broken = Vec::new();
    let files = markdown_files();
    assert!(files.len() > 20, "{files:?}");
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        for target in links(&text) {
            let path = target.split('#').next().unwrap_or("").trim();
            if path.is_empty() || path.contains("://") || path.starts_with("mailto:") {
                continue;
            }
            let resolved = f.parent().unwrap().join(path);
            if !resolved.exists() {
                broken.push(format!("{}: {target}", f.display()));
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_front_door_stays_short() {
    for (file, limit) in [("README.md", 25_000), ("ARCHITECTURE.md", 10_000)] {
        let n = std::fs::metadata(Path::new(ROOT).join(file)).unwrap().len();
        assert!(
            n < limit,
            "{file} is {n} bytes; keep it under {limit} (the manual is docs/)"
        );
    }
}

/// The library's modules from the bottom up: a module may use only those before it. `lib.rs`
/// sits on top of them, and the packages in cli/ (the command) and embree/ (the Embree
/// cross-check) on top of the library.
const LAYERS: [&str; 17] = [
    "error",
    "files",
    "real",
    "math",
    "fft",
    "lens",
    "trace",
    "psf",
    "wave",
    "analysis",
    "tolerance",
    "figures",
    "optim",
    "image",
    "decoder",
    "deep",
    "ffi",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn layers_point_down() {
    let src = Path::new(ROOT).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let rank = |m: &str| LAYERS.iter().position(|l| *l == m);
    let mut up = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs");
        if module == "lib" {
            continue;
        }
        let own = rank(module).unwrap_or_else(|| panic!("src/{module} is in no layer: add it"));
        let text = std::fs::read_to_string(f).unwrap();
        for (n, line) in text.lines().enumerate() {
            // Code only: a doc link to a higher layer is a pointer for the reader.
            let code = line.split("//").next().unwrap_or("");
            for (k, _) in code.match_indices("crate::") {
                let name: String = code[k + 7..]
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if let Some(r) = rank(&name) {
                    if r > own {
                        up.push(format!(
                            "src/{}:{}: {module} uses {name}",
                            rel.display(),
                            n + 1
                        ));
                    }
                }
            }
        }
    }
    assert!(
        up.is_empty(),
        "a layer uses one above it (ARCHITECTURE.md, Codemap):\n{}",
        up.join("\n")
    );
}

#[test]
fn no_source_file_grows_past_1200_lines() {
    let mut files = Vec::new();
    for dir in ["src", "tests", "benches", "examples", "cli", "embree"] {
        rust_files(&Path::new(ROOT).join(dir), &mut files);
    }
    let mut long = Vec::new();
    for f in &files {
        // The generated glass table is data, one glass a line.
        if f.ends_with("lens/catalog_data.rs") {
            continue;
        }
        let n = std::fs::read_to_string(f).unwrap().lines().count();
        if n > 1200 {
            long.push(format!("{}: {n} lines", f.display()));
        }
    }
    assert!(long.is_empty(), "split these by job:\n{}", long.join("\n"));
}

/// The `[dependencies]` table of a manifest, as its lines.
fn dependencies(manifest: &str) -> Vec<String> {
    let text = std::fs::read_to_string(Path::new(ROOT).join(manifest)).unwrap();
    text.lines()
        .skip_while(|l| l.trim() != "[dependencies]")
        .skip(1)
        .take_while(|l| !l.starts_with('['))
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(String::from)
        .collect()
}

/// unit/ builds the library's own sources for their unit tests: it must depend on the same
/// crates with the same features, or the tests would run against another build of them.
#[test]
fn the_unit_test_package_has_the_librarys_dependencies() {
    let (lib, unit) = (dependencies("Cargo.toml"), dependencies("unit/Cargo.toml"));
    assert!(!lib.is_empty());
    assert_eq!(
        lib, unit,
        "unit/Cargo.toml's [dependencies] differ from the library's"
    );
}
