//! The module graph of docs/architecture.md, checked on the source: every top-level
//! module imports only what its row of the table allows, no two files of one folder
//! import each other in a cycle, and nothing in the library uses `anyhow` (the binary's
//! alone). Reads `src/` as text; needs no build of anything else and no GPU.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// What each top-level module may import (docs/architecture.md "Modules"). `error` sits
/// at the bottom and names no module (docs/architecture.md "Errors"): every module may
/// return it, and each marks its own error types as `error::StageError`.
const ALLOWED: &[(&str, &[&str])] = &[
    ("atomic", &[]),
    ("stats", &[]),
    ("plot", &["atomic", "error"]),
    ("progress", &[]),
    ("gpu", &["error"]),
    ("graph", &["error"]),
    ("robot", &["error"]),
    ("ops", &["gpu"]),
    ("testing", &["gpu", "ops", "error"]),
    ("smoke", &["gpu", "ops", "model", "testing", "error"]),
    ("twin", &["robot", "atomic"]),
    ("calibrate", &["robot", "atomic", "error"]),
    (
        "model",
        &["gpu", "ops", "graph", "testing", "atomic", "error"],
    ),
    (
        "data",
        &[
            "robot",
            "twin",
            "calibrate",
            "graph",
            "plot",
            "progress",
            "atomic",
            "error",
        ],
    ),
    (
        "train",
        &[
            "data", "model", "ops", "gpu", "graph", "plot", "progress", "atomic", "error", "stats",
        ],
    ),
    ("interop", &["model", "train", "gpu", "graph", "error"]),
    (
        "compensate",
        &[
            "twin",
            "calibrate",
            "data",
            "train",
            "model",
            "gpu",
            "graph",
            "robot",
            "plot",
            "progress",
            "stats",
            "atomic",
            "error",
        ],
    ),
    (
        "polish",
        &["compensate", "twin", "robot", "ops", "gpu", "error"],
    ),
    (
        "experiment",
        &[
            "polish",
            "compensate",
            "twin",
            "calibrate",
            "data",
            "train",
            "model",
            "gpu",
            "graph",
            "robot",
            "plot",
            "progress",
            "stats",
            "atomic",
            "error",
        ],
    ),
    // `embed` may import what `experiment` may, and `experiment` (INHERITS).
    ("embed", &["experiment"]),
    ("error", &["atomic"]),
];

/// Modules that may import whatever another module may, on top of their own row:
/// `embed` hands the whole pipeline to other languages.
const INHERITS: &[(&str, &str)] = &[("embed", "experiment")];

/// The rules docs/architecture.md states as "never", checked on their own so that a
/// change to the table above cannot quietly drop them.
const NEVER: &[(&str, &[&str])] = &[
    (
        "gpu",
        &[
            "robot",
            "twin",
            "calibrate",
            "data",
            "model",
            "train",
            "compensate",
            "experiment",
        ],
    ),
    (
        "ops",
        &[
            "robot",
            "twin",
            "calibrate",
            "data",
            "model",
            "train",
            "compensate",
            "experiment",
        ],
    ),
    (
        "robot",
        &[
            "gpu",
            "ops",
            "model",
            "train",
            "data",
            "compensate",
            "experiment",
        ],
    ),
    (
        "twin",
        &[
            "gpu",
            "ops",
            "model",
            "train",
            "calibrate",
            "data",
            "compensate",
            "experiment",
        ],
    ),
    (
        "calibrate",
        &[
            "gpu",
            "ops",
            "model",
            "train",
            "data",
            "compensate",
            "experiment",
        ],
    ),
    ("compensate", &["experiment", "polish"]),
    ("polish", &["experiment", "model", "train", "data"]),
];

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir` (or `dir` itself when it is a file).
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if dir.is_file() {
        out.push(dir.to_path_buf());
    } else if let Ok(entries) = fs::read_dir(dir) {
        for e in entries.flatten() {
            out.extend(rust_files(&e.path()));
        }
    }
    out.retain(|p| p.extension().is_some_and(|x| x == "rs"));
    out.sort();
    out
}

/// The code of a file without its comments (doc links are not imports).
fn code(path: &Path) -> String {
    let text = fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The identifiers that follow `prefix` (`crate::`, `super::`) in `code`.
fn paths_after(code: &str, prefix: &str) -> BTreeSet<String> {
    code.match_indices(prefix)
        .filter(|(i, _)| {
            // A whole path segment: not `xcrate::` or `a::super::`.
            !code[..*i].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':')
        })
        .map(|(i, _)| {
            code[i + prefix.len()..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect()
        })
        .filter(|s: &String| !s.is_empty())
        .collect()
}

/// Top-level modules of the library (as `lib.rs` declares them) and what each imports.
fn module_imports() -> BTreeMap<String, BTreeSet<String>> {
    let lib = code(&src().join("lib.rs"));
    let mut out = BTreeMap::new();
    for line in lib.lines() {
        let Some(name) = line.trim().strip_prefix("pub mod ") else {
            continue;
        };
        let name = name.trim_end_matches(';').to_string();
        let (dir, file) = (src().join(&name), src().join(format!("{name}.rs")));
        let files = if dir.is_dir() {
            rust_files(&dir)
        } else {
            vec![file]
        };
        let mut imports = BTreeSet::new();
        for f in files {
            imports.extend(paths_after(&code(&f), "crate::"));
        }
        imports.remove(&name);
        out.insert(name, imports);
    }
    out
}

#[test]
fn every_module_imports_only_what_the_architecture_allows() {
    let modules = module_imports();
    let mut allowed: BTreeMap<&str, Vec<&str>> =
        ALLOWED.iter().map(|(m, a)| (*m, a.to_vec())).collect();
    for (heir, from) in INHERITS {
        let more = allowed[from].clone();
        allowed
            .get_mut(heir)
            .expect("an heir in ALLOWED")
            .extend(more);
    }
    let mut wrong = Vec::new();
    for (module, imports) in &modules {
        let Some(ok) = allowed.get(module.as_str()) else {
            wrong.push(format!("{module}: not in docs/architecture.md's table"));
            continue;
        };
        for i in imports {
            if !ok.contains(&i.as_str()) {
                wrong.push(format!("{module} imports {i}"));
            }
        }
    }
    for (module, never) in NEVER {
        for i in modules.get(*module).into_iter().flatten() {
            if never.contains(&i.as_str()) {
                wrong.push(format!("{module} imports {i}, which it must never do"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the architecture:\n{}",
        wrong.join("\n")
    );
    // The table and the code name the same modules, so the check covers the whole crate.
    for (module, _) in ALLOWED {
        assert!(
            modules.contains_key(*module),
            "{module} is in the table but not in lib.rs"
        );
    }
}

/// The paths that follow `prefix` (`super::`, `crate::model::`) in `code`, as segments,
/// a `{…}` group opened into one path per member (`a::{b, c::d}` is `a::b` and
/// `a::c::d`).
fn full_paths_after(code: &str, prefix: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for (i, _) in code.match_indices(prefix) {
        // A whole path segment: not `xcrate::` or `a::super::`.
        if code[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        expand(&code[i + prefix.len()..], &[], &mut out);
    }
    out
}

/// The paths written at the start of `text` after `head`, groups opened.
fn expand(text: &str, head: &[String], out: &mut Vec<Vec<String>>) {
    let mut path = head.to_vec();
    let mut rest = text;
    loop {
        let word: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if word.is_empty() {
            break;
        }
        path.push(word.clone());
        rest = &rest[word.len()..];
        match rest.strip_prefix("::") {
            Some(after) => rest = after,
            None => break,
        }
    }
    if let Some(group) = rest.strip_prefix('{') {
        // The group's members, split at the commas of its own level.
        let (mut depth, mut from) = (0usize, 0usize);
        for (j, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => {
                    expand(group[from..j].trim_start(), &path, out);
                    return;
                }
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    expand(group[from..j].trim_start(), &path, out);
                    from = j + 1;
                }
                _ => {}
            }
        }
    } else if !path.is_empty() {
        out.push(path);
    }
}

/// The file below `dir` that a path below `dir`'s module names, as a node of the folder's
/// import graph: the deepest file or sub-folder the path reaches (`gated_dcc::kernel` for
/// `gated_dcc::kernel::Unfold`, `gated_dcc` for an item of `gated_dcc/mod.rs`).
fn resolve(dir: &Path, segments: &[String]) -> Option<String> {
    let (mut at, mut node) = (dir.to_path_buf(), Vec::new());
    for seg in segments {
        if at.join(format!("{seg}.rs")).is_file() {
            node.push(seg.as_str());
            break;
        } else if at.join(seg).is_dir() {
            node.push(seg.as_str());
            at = at.join(seg);
        } else {
            break;
        }
    }
    (!node.is_empty()).then(|| node.join("::"))
}

/// The node of `file` in the import graph of `dir`: its path below `dir` (`native`,
/// `gated_dcc::kernel`; a sub-folder's `mod.rs` is the sub-folder, `gated_dcc`).
fn node_of(dir: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(dir).expect("a file below its folder");
    let mut parts: Vec<String> = rel
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.len() > 1 && parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts.join("::")
}

/// Edges between the files of one folder (its sub-folders' files included, each a node
/// of its own, as the rule reads: no two files import each other around a loop):
/// `super::x` from a file directly in the folder and `crate::m::x…` from any file below
/// it, where `x…` names a file (or a sub-folder's `mod.rs`) below the folder.
fn sibling_edges(dir: &Path, module_path: &str) -> Vec<(String, String)> {
    let mut edges = Vec::new();
    for f in rust_files(dir) {
        if f == dir.join("mod.rs") {
            continue;
        }
        let from = node_of(dir, &f);
        let text = code(&f);
        // From a file of a sub-folder, `super::` is that sub-folder, not this one.
        let mut targets = if f.parent() == Some(dir) {
            full_paths_after(&text, "super::")
        } else {
            Vec::new()
        };
        if !module_path.is_empty() {
            targets.extend(full_paths_after(&text, &format!("crate::{module_path}::")));
        }
        for t in targets {
            if let Some(to) = resolve(dir, &t) {
                if to != from && !edges.contains(&(from.clone(), to.clone())) {
                    edges.push((from.clone(), to));
                }
            }
        }
    }
    edges
}

/// A cycle in `edges`, if there is one.
fn find_cycle(edges: &[(String, String)]) -> Option<Vec<String>> {
    let mut next: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (a, b) in edges {
        next.entry(a).or_default().push(b);
    }
    fn walk<'a>(
        at: &'a str,
        next: &BTreeMap<&'a str, Vec<&'a str>>,
        stack: &mut Vec<&'a str>,
        done: &mut BTreeSet<&'a str>,
    ) -> Option<Vec<String>> {
        if let Some(i) = stack.iter().position(|s| *s == at) {
            let mut cycle: Vec<String> = stack[i..].iter().map(|s| s.to_string()).collect();
            cycle.push(at.to_string());
            return Some(cycle);
        }
        if !done.insert(at) {
            return None;
        }
        stack.push(at);
        for n in next.get(at).into_iter().flatten() {
            if let Some(c) = walk(n, next, stack, done) {
                return Some(c);
            }
        }
        stack.pop();
        None
    }
    let mut done = BTreeSet::new();
    for start in next.keys() {
        if let Some(c) = walk(start, &next, &mut Vec::new(), &mut done) {
            return Some(c);
        }
    }
    None
}

/// Every folder under `src/` with its module path (`twin`, `twin::sources`).
fn folders(dir: &Path, path: &str, out: &mut Vec<(PathBuf, String)>) {
    out.push((dir.to_path_buf(), path.to_string()));
    for e in fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned());
            let name = name.unwrap_or_default();
            let sub = if path.is_empty() {
                name
            } else {
                format!("{path}::{name}")
            };
            folders(&p, &sub, out);
        }
    }
}

#[test]
fn no_two_files_of_a_folder_import_each_other_in_a_cycle() {
    let mut all = Vec::new();
    folders(&src(), "", &mut all);
    let mut cycles = Vec::new();
    for (dir, path) in &all {
        // The crate root's files are the top-level modules, checked by the table above
        // and by `no_top_level_module_imports_another_that_imports_it_back`.
        if path.is_empty() {
            continue;
        }
        if let Some(c) = find_cycle(&sibling_edges(dir, path)) {
            cycles.push(format!("{path}: {}", c.join(" → ")));
        }
    }
    assert!(cycles.is_empty(), "import cycles:\n{}", cycles.join("\n"));
}

#[test]
fn no_top_level_module_imports_another_that_imports_it_back() {
    let edges: Vec<(String, String)> = module_imports()
        .into_iter()
        .flat_map(|(m, imports)| imports.into_iter().map(move |i| (m.clone(), i)))
        .collect();
    assert_eq!(
        find_cycle(&edges),
        None,
        "a circle of imports between top-level modules"
    );
}

#[test]
fn the_cycle_check_finds_a_cycle_and_none_in_a_chain() {
    let e = |a: &str, b: &str| (a.to_string(), b.to_string());
    let cycle = find_cycle(&[e("simulate", "truth"), e("truth", "simulate")]);
    assert_eq!(cycle.map(|c| c.len()), Some(3));
    assert_eq!(find_cycle(&[e("a", "b"), e("b", "c"), e("a", "c")]), None);
}

#[test]
fn grouped_imports_are_read_member_by_member() {
    let code = "use crate::m::{a::B, c::{d, e::F}};\nuse crate::m::g;\nlet x = xcrate::m::h;";
    let paths: Vec<String> = full_paths_after(code, "crate::m::")
        .iter()
        .map(|p| p.join("::"))
        .collect();
    assert_eq!(paths, ["a::B", "c::d", "c::e::F", "g"]);
    // A path resolves to the deepest file it reaches: a step's kernel file, not its folder.
    let block = src().join("model").join("block");
    let words = |p: &str| p.split("::").map(String::from).collect::<Vec<_>>();
    assert_eq!(
        resolve(&block, &words("gated_dcc::kernel::Unfold")).as_deref(),
        Some("gated_dcc::kernel")
    );
    assert_eq!(
        resolve(&block, &words("wgsl::Block")).as_deref(),
        Some("wgsl")
    );
    assert_eq!(resolve(&block, &words("Nothing")), None);
}

#[test]
fn the_library_leaves_anyhow_to_the_binary() {
    let mut users = Vec::new();
    for f in rust_files(&src()) {
        let in_binary = f.starts_with(src().join("cli")) || f == src().join("main.rs");
        if !in_binary && code(&f).contains("anyhow") {
            users.push(f.display().to_string());
        }
    }
    assert!(users.is_empty(), "library files using anyhow: {users:?}");
}

/// The command-line flags (`--name`) that the string literals of `source` name, with their
/// lines: text meant for a person at a terminal. Comments and doc comments are not
/// strings (a doc may say which flag reaches a function).
fn flags_named(source: &str) -> Vec<(usize, String)> {
    fn walk(tokens: proc_macro2::TokenStream, out: &mut Vec<(usize, String)>) {
        let mut after_hash = false;
        for tree in tokens {
            match tree {
                proc_macro2::TokenTree::Group(g) => {
                    // `#[…]` and `#![…]`: attributes, doc comments among them.
                    let attribute = after_hash && g.delimiter() == proc_macro2::Delimiter::Bracket;
                    if !attribute {
                        walk(g.stream(), out);
                    }
                    after_hash = false;
                }
                proc_macro2::TokenTree::Punct(p) => {
                    after_hash = p.as_char() == '#' || (after_hash && p.as_char() == '!');
                }
                proc_macro2::TokenTree::Literal(l) => {
                    after_hash = false;
                    let text = l.to_string();
                    if !(text.starts_with('"') || text.starts_with('r')) {
                        continue;
                    }
                    let bytes = text.as_bytes();
                    for (i, _) in text.match_indices("--") {
                        let before = i.checked_sub(1).map(|j| bytes[j]);
                        let starts_word = before
                            .is_none_or(|b| !(b.is_ascii_alphanumeric() || b == b'-' || b == b'_'));
                        let name: String = text[i + 2..]
                            .chars()
                            .take_while(|c| {
                                c.is_ascii_lowercase() || c.is_ascii_digit() || *c == '-'
                            })
                            .collect();
                        if starts_word && name.starts_with(|c: char| c.is_ascii_lowercase()) {
                            out.push((l.span().start().line, format!("--{name}")));
                        }
                    }
                }
                proc_macro2::TokenTree::Ident(_) => after_hash = false,
            }
        }
    }
    let tokens: proc_macro2::TokenStream = source.parse().expect("the file tokenizes");
    let mut out = Vec::new();
    walk(tokens, &mut out);
    out
}

#[test]
fn the_flag_finder_sees_strings_and_not_comments() {
    let planted = r##"
//! A module doc that names `--sessions`.
/// A doc that names --batch.
#[doc = "an attribute naming --minutes"]
fn f() -> String {
    // a comment naming --out
    let table = "|---|---|";
    let arrow = "a-->b x--y";
    let raw = r#"raw --graph"#;
    format!("--sessions: 1 to {} sessions, got {}; or --open-loop", 8, 9) + raw + table + arrow
}
"##;
    let found = flags_named(planted);
    assert_eq!(
        found,
        vec![
            (9, "--graph".to_string()),
            (10, "--sessions".to_string()),
            (10, "--open-loop".to_string()),
        ]
    );
}

/// Advice at the edge: errors and messages below `cli/` carry facts (what, where, the
/// value) and name settings as the library's configs do (`recipe.sessions`); the command
/// line turns them into advice under its flags (`cli::SETTING_FLAGS`). No string literal
/// of the library names a command-line flag.
#[test]
fn no_module_below_the_cli_names_a_command_line_flag() {
    let mut wrong = Vec::new();
    for f in rust_files(&src()) {
        if f.starts_with(src().join("cli")) || f == src().join("main.rs") {
            continue;
        }
        let text = fs::read_to_string(&f).unwrap();
        let rel = f.strip_prefix(src()).unwrap().display().to_string();
        for (line, flag) in flags_named(&text) {
            wrong.push(format!(
                "src/{rel}:{line} names {flag}: say the fact, name the setting as the \
                 library does, and let cli/ name the flag"
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
