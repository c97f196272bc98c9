//! No `panic!`, `unwrap()` or `expect()` on a path that input, the file system or the
//! device can reach (docs/robustness.md). Every one left in `src/` states the invariant
//! that makes it unreachable in a `// invariant:` comment on the lines just above it;
//! this test lists every site that has none. Code after `#[cfg(test)]` (unit tests at
//! the end of a file), files of unit tests alone (`#![cfg(test)]` at their top) and
//! comments are not scanned.

use std::path::{Path, PathBuf};

/// The calls that abort the process or the thread.
const PANICKING: [&str; 7] = [
    ".unwrap()",
    ".expect(",
    "panic!(",
    "unreachable!(",
    "todo!(",
    "unimplemented!(",
    ".unwrap_err()",
];

/// How many lines above a site its `// invariant:` comment may stand (a statement
/// spread over a few lines, or a short loop whose calls share one reason).
const REACH: usize = 6;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `file:line: text` of every panicking call in `text` without an invariant above it.
fn unexplained(file: &str, text: &str) -> Vec<String> {
    let lines: Vec<&str> = text.lines().collect();
    // An inner attribute stands before every item: the whole file is test code.
    let end = if lines.iter().any(|l| l.trim() == "#![cfg(test)]") {
        0
    } else {
        lines
            .iter()
            .position(|l| l.trim() == "#[cfg(test)]")
            .unwrap_or(lines.len())
    };
    let mut found = Vec::new();
    for (i, line) in lines[..end].iter().enumerate() {
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        if !PANICKING.iter().any(|p| code.contains(p)) {
            continue;
        }
        let explained = lines[i.saturating_sub(REACH)..=i]
            .iter()
            .any(|l| l.contains("// invariant:"));
        if !explained {
            found.push(format!("{file}:{}: {}", i + 1, code));
        }
    }
    found
}

#[test]
fn every_panic_left_in_src_states_its_invariant() {
    let mut files = Vec::new();
    rust_files(Path::new("src"), &mut files);
    files.sort();
    assert!(
        files.len() > 50,
        "found only {} files under src/",
        files.len()
    );
    let mut found = Vec::new();
    for path in &files {
        let text = std::fs::read_to_string(path).unwrap();
        found.extend(unexplained(&path.display().to_string(), &text));
    }
    assert!(
        found.is_empty(),
        "{} panicking calls without an `// invariant:` comment above them (return an \
         error instead, or state why input, files and the device cannot reach them):\n{}",
        found.len(),
        found.join("\n")
    );
}

#[test]
fn the_scan_finds_what_it_should() {
    let text = "fn f() {\n    let a = x.unwrap();\n    // invariant: y is Some.\n    \
                let b = y.expect(\"y\");\n    // a comment with .unwrap()\n}\n\
                #[cfg(test)]\nmod tests { fn g() { z.unwrap(); } }\n";
    let found = unexplained("f.rs", text);
    assert_eq!(found, vec!["f.rs:2: let a = x.unwrap();".to_string()]);
    let tests_only = "//! Unit tests of a module.\n#![cfg(test)]\nfn g() { z.unwrap(); }\n";
    assert!(unexplained("tests.rs", tests_only).is_empty());
}
