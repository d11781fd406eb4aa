//! The library's layers point only downwards: every `crate::MODULE` a module of `src/` names
//! (outside comments and its unit tests) must be in a lower layer of the table declared in
//! docs/ARCHITECTURE.md (the fenced `layers` block). A new import against the order fails
//! here, so the picture in the docs stays the code.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Module -> layer number, from the `layers` block of docs/ARCHITECTURE.md.
fn declared_layers(root: &Path) -> HashMap<String, usize> {
    let doc = std::fs::read_to_string(root.join("docs/ARCHITECTURE.md")).unwrap();
    let start = doc
        .find("```layers\n")
        .expect("docs/ARCHITECTURE.md has no ```layers block");
    let body = &doc[start + "```layers\n".len()..];
    let body = &body[..body.find("```").expect("unterminated layers block")];
    let mut layers = HashMap::new();
    for (n, line) in body.lines().enumerate() {
        let names = line.split_once(':').map_or(line, |(_, r)| r);
        for m in names
            .split([',', ' '])
            .map(str::trim)
            .filter(|m| !m.is_empty())
        {
            assert!(
                layers.insert(m.to_string(), n).is_none(),
                "{m} declared twice"
            );
        }
    }
    layers
}

/// The Rust files of module `m` (a folder or one file), unit-test files left out.
fn files_of(src: &Path, m: &str) -> Vec<PathBuf> {
    let dir = src.join(m);
    if !dir.is_dir() {
        return vec![src.join(format!("{m}.rs"))];
    }
    let mut out = Vec::new();
    let mut stack = vec![dir];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs")
                && p.file_name().is_some_and(|n| n != "tests.rs")
            {
                out.push(p);
            }
        }
    }
    out
}

/// The `crate::NAME` references of a file's code (comments and `#[cfg(test)]` items cut).
fn crate_refs(text: &str) -> Vec<(usize, String)> {
    let code = text.split("#[cfg(test)]").next().unwrap_or("");
    let mut refs = Vec::new();
    for (i, line) in code.lines().enumerate() {
        let line = line.split("//").next().unwrap_or("");
        let mut rest = line;
        while let Some(k) = rest.find("crate::") {
            let name: String = rest[k + 7..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            refs.push((i + 1, name));
            rest = &rest[k + 7..];
        }
    }
    refs
}

#[test]
fn every_library_import_points_to_a_lower_layer() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let src = root.join("src");
    let layers = declared_layers(root);
    // Every module of lib.rs is declared (a new module must take its place in the table).
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    let modules: Vec<String> = lib
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub mod "))
        .map(|m| m.trim_end_matches(';').to_string())
        .collect();
    assert!(modules.len() > 10, "lib.rs lists {modules:?}");
    let mut wrong = Vec::new();
    for m in &modules {
        let Some(&mine) = layers.get(m) else {
            wrong.push(format!(
                "module {m} is not in docs/ARCHITECTURE.md's layers block"
            ));
            continue;
        };
        for f in files_of(&src, m) {
            let text = std::fs::read_to_string(&f).unwrap();
            for (line, used) in crate_refs(&text) {
                if used == *m || !modules.contains(&used) {
                    continue;
                }
                match layers.get(&used) {
                    Some(&theirs) if theirs < mine => {}
                    _ => wrong.push(format!(
                        "{}:{line}: {m} (layer {mine}) uses crate::{used} (layer {:?})",
                        f.strip_prefix(root).unwrap_or(&f).display(),
                        layers.get(&used)
                    )),
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the declared layers:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn the_checker_sees_imports_and_ignores_comments_and_tests() {
    let text = "use crate::map::Map; // crate::io here is a comment\nfn f() { crate::geometry::Se3::identity(); }\n#[cfg(test)]\nmod tests { use crate::io; }\n";
    let refs: Vec<String> = crate_refs(text).into_iter().map(|(_, n)| n).collect();
    assert_eq!(refs, ["map", "geometry"]);
}
