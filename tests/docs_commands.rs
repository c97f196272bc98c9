//! The command lines the docs show are ones the program accepts: every `iastgcn …` line
//! of the ```sh blocks of README.md, docs/usage.md and docs/arms.md is parsed by the
//! binary itself (`--help` appended, so clap checks every subcommand, flag and value
//! before it prints the help and stops, and nothing runs). A doc that names a flag that
//! does not exist, a value a flag refuses or a command that is gone fails here, naming
//! the file and line. The whole check takes well under a second. The blocks a doc marks
//! with `<!-- tests/docs_commands.rs runs the next block -->` (the arm quick start and
//! the real arms, seconds each) also run for real, as written.

use std::path::Path;
use std::process::Command;

/// One command line of a doc: where it starts and its arguments after `iastgcn`.
struct DocCommand {
    at: String,
    args: Vec<String>,
}

/// Splits a shell line into words, honouring '…' and "…" quoting; `(` and `)` end a word.
fn words(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let (mut word, mut quote, mut started) = (String::new(), None, false);
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                started = true;
            }
            (None, c) if c.is_whitespace() || c == '(' || c == ')' => {
                if started || !word.is_empty() {
                    out.push(std::mem::take(&mut word));
                }
                started = false;
            }
            (None, c) => word.push(c),
        }
    }
    if started || !word.is_empty() {
        out.push(word);
    }
    out
}

/// The arguments of every `iastgcn` invocation in `text` (a shell line, continuation
/// lines already joined), also those quoted inside another command (`sbatch --wrap
/// "iastgcn …"`). Shell variables become `1`; `[…]` marks optional arguments and `…` an
/// elided list, both dropped as marks. None for a line with a `<placeholder>`.
fn invocations(text: &str) -> Vec<Option<Vec<String>>> {
    let mut found = Vec::new();
    let mut pending: Vec<Vec<String>> = Vec::new();
    for word in words(text) {
        // A quoted command comes back as one word: split it again.
        let inner = words(&word);
        if inner.len() > 1 && inner[0].ends_with("iastgcn") {
            pending.push(inner);
            continue;
        }
        if word.ends_with("iastgcn") && (word == "iastgcn" || word.ends_with("/iastgcn")) {
            pending.push(vec![word]);
        } else if let Some(last) = pending.last_mut() {
            if [";", "&&", "||", "|", "&"].contains(&word.as_str()) || word == "done" {
                found.append(&mut pending);
            } else {
                last.push(word);
            }
        }
    }
    found.append(&mut pending);
    found
        .into_iter()
        .map(|cmd| {
            let mut args = Vec::new();
            for w in &cmd[1..] {
                if w.contains('<') || w.contains('>') {
                    return None;
                }
                let w = w.trim_start_matches('[').trim_end_matches(']');
                if w.is_empty() || w == "..." || w == "…" || w.ends_with('…') {
                    continue;
                }
                args.push(shell_variables(w));
            }
            Some(args)
        })
        .collect()
}

/// `$x`, `${x}` and `$((…))` replaced by `1`.
fn shell_variables(w: &str) -> String {
    let mut out = String::new();
    let mut rest = w;
    while let Some(i) = rest.find('$') {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        let skip = if let Some(body) = after.strip_prefix("((") {
            body.find("))").map_or(after.len(), |j| j + 4)
        } else if let Some(body) = after.strip_prefix('{') {
            body.find('}').map_or(after.len(), |j| j + 2)
        } else {
            after
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(after.len())
        };
        out.push('1');
        rest = &after[skip..];
    }
    out.push_str(rest);
    out
}

/// Every `iastgcn` command of the ```sh blocks of `file` (relative to the crate).
fn doc_commands(file: &str) -> Vec<DocCommand> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(file);
    commands_in(&std::fs::read_to_string(&path).unwrap(), file)
}

/// Every `iastgcn` command of the ```sh blocks of `text`, located as in `file`.
fn commands_in(text: &str, file: &str) -> Vec<DocCommand> {
    let (mut out, mut in_sh, mut joined, mut start) = (Vec::new(), false, String::new(), 0);
    for (i, line) in text.lines().enumerate() {
        let fence = line.trim_start();
        if let Some(lang) = fence.strip_prefix("```") {
            in_sh = !in_sh && (lang.trim() == "sh" || lang.trim() == "bash");
            continue;
        }
        if !in_sh {
            continue;
        }
        // A comment runs from a `#` that starts a word to the end of the line.
        let code = match line.find(" #") {
            Some(j) => &line[..j],
            None if line.trim_start().starts_with('#') => "",
            None => line,
        };
        if joined.is_empty() {
            start = i + 1;
        }
        match code.trim_end().strip_suffix('\\') {
            Some(part) => {
                joined.push_str(part);
                joined.push(' ');
            }
            None => {
                joined.push_str(code);
                for args in invocations(&joined).into_iter().flatten() {
                    out.push(DocCommand {
                        at: format!("{file}:{start}"),
                        args,
                    });
                }
                joined.clear();
            }
        }
    }
    out
}

/// Why the binary refuses `args` (parsed with `--help` appended), or None.
fn refused(args: &[String]) -> Option<String> {
    let o = Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(args)
        .arg("--help")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    if o.status.success() && err.trim().is_empty() {
        None
    } else {
        Some(err.lines().next().unwrap_or("failed").to_string())
    }
}

#[test]
fn every_documented_command_line_parses() {
    let mut commands = Vec::new();
    for file in ["README.md", "docs/usage.md", "docs/arms.md"] {
        commands.extend(doc_commands(file));
    }
    // The docs show every subcommand; far fewer lines would mean the extraction broke.
    assert!(
        commands.len() >= 30,
        "only {} command lines found",
        commands.len()
    );
    let mut seen: Vec<&str> = commands
        .iter()
        .filter_map(|c| c.args.iter().find(|a| !a.starts_with('-')))
        .map(String::as_str)
        .collect();
    seen.sort();
    seen.dedup();
    for sub in [
        "simulate",
        "calibrate",
        "train",
        "refine",
        "evaluate",
        "reproduce",
        "scale",
    ] {
        assert!(
            seen.contains(&sub),
            "no documented `iastgcn {sub}` found: {seen:?}"
        );
    }
    let bad: Vec<String> = commands
        .iter()
        .filter_map(|c| {
            refused(&c.args).map(|why| format!("{}: iastgcn {}: {why}", c.at, c.args.join(" ")))
        })
        .collect();
    assert!(
        bad.is_empty(),
        "documented commands the CLI refuses:\n{}",
        bad.join("\n")
    );
}

/// The check itself catches what it is for: a flag that does not exist, a value a flag
/// refuses, a command that does not exist, in a doc-shaped block; and passes a good one.
#[test]
fn the_check_catches_a_wrong_flag() {
    let doc = "text\n\n```sh\niastgcn train --config a.toml --max-epochs 3 \\\n    \
               --no-such-flag 1 --out m.safetensors   # a comment\n\
               iastgcn predict --stride 0 --model m --out r.csv\n\
               iastgcn trian --out x\n\
               iastgcn simulate --trajectory grid --out g.csv\n```\n\
               ```text\niastgcn --not-shell-so-not-read\n```\n";
    let commands = commands_in(doc, "inline example");
    let args: Vec<&Vec<String>> = commands.iter().map(|c| &c.args).collect();
    assert_eq!(commands.len(), 4, "{args:?}");
    assert_eq!(commands[0].at, "inline example:4");
    assert!(args[0].contains(&"--no-such-flag".to_string()), "{args:?}");
    let why: Vec<Option<String>> = commands.iter().map(|c| refused(&c.args)).collect();
    assert!(
        why[0]
            .as_deref()
            .is_some_and(|w| w.contains("--no-such-flag")),
        "{why:?}"
    );
    assert!(
        why[1].as_deref().is_some_and(|w| w.contains("--stride")),
        "{why:?}"
    );
    assert!(why[2].is_some(), "{why:?}");
    assert!(why[3].is_none(), "{why:?}");
}

#[test]
fn shell_words_and_variables() {
    assert_eq!(
        words(r#"sbatch --wrap "iastgcn reproduce --out /p" 'a b'"#),
        ["sbatch", "--wrap", "iastgcn reproduce --out /p", "a b"]
    );
    assert_eq!(shell_variables("seeds-m$m"), "seeds-m1");
    assert_eq!(shell_variables("${SLURM_ARRAY_TASK_ID}/12"), "1/12");
    assert_eq!(shell_variables("$((JOB_COMPLETION_INDEX + 1))/12"), "1/12");
    let inv = invocations(r#"x=$(sbatch --wrap "iastgcn reproduce --out /p --data-only")"#);
    assert_eq!(
        inv,
        [Some(vec![
            "reproduce".into(),
            "--out".into(),
            "/p".into(),
            "--data-only".into()
        ])]
    );
    assert_eq!(
        invocations("./target/release/iastgcn <command> [options]"),
        [None]
    );
}

/// The marker that a doc's next ```sh block runs for real in
/// [`marked_blocks_run_for_real`].
const RUN_MARK: &str = "<!-- tests/docs_commands.rs runs the next block -->";

/// The text of every ```sh block of `text` that follows a [`RUN_MARK`] line (blank lines
/// between them allowed), with the line its first command is on.
fn marked_blocks(text: &str) -> Vec<(usize, String)> {
    let mut out: Vec<(usize, String)> = Vec::new();
    let mut block: Option<(usize, String)> = None;
    let mut armed = false;
    for (i, line) in text.lines().enumerate() {
        if line.trim() == RUN_MARK {
            armed = true;
            continue;
        }
        let fence = line.trim_start().strip_prefix("```");
        match (&mut block, fence) {
            (Some(_), Some(_)) => out.push(block.take().unwrap()),
            (Some((_, b)), None) => {
                b.push_str(line);
                b.push('\n');
            }
            (None, Some(lang)) if armed && lang.trim() == "sh" => {
                armed = false;
                block = Some((i + 2, String::new()));
            }
            (None, Some(_)) => armed = false,
            (None, None) => armed &= line.trim().is_empty(),
        }
    }
    out
}

/// The blocks the docs mark as quick (a UR5 twin from an empty folder, the real arms)
/// run as written, in a fresh folder that has the repository's `assets/` beside it, with
/// `iastgcn` the binary under test: the docs cannot drift from what the program does.
#[test]
fn marked_blocks_run_for_real() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut ran = 0;
    for file in ["README.md", "docs/usage.md", "docs/arms.md"] {
        let text = std::fs::read_to_string(root.join(file)).unwrap();
        for (line, block) in marked_blocks(&text) {
            let dir = std::env::temp_dir().join(format!(
                "iastgcn-docs-{}-{}-{line}",
                std::process::id(),
                file.replace('/', "-")
            ));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            std::os::unix::fs::symlink(root.join("assets"), dir.join("assets")).unwrap();
            let script = format!(
                "set -e\niastgcn() {{ \"{}\" \"$@\"; }}\n{block}",
                env!("CARGO_BIN_EXE_iastgcn")
            );
            let o = Command::new("sh")
                .arg("-c")
                .arg(&script)
                .current_dir(&dir)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "{file}:{line}: the block failed:\n{block}\n{}\n{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            );
            ran += 1;
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    assert!(
        ran >= 2,
        "the docs mark {ran} blocks to run; expected the arm ones at least"
    );
}

#[test]
fn only_marked_sh_blocks_are_picked() {
    let doc = format!(
        "a\n\n{RUN_MARK}\n\n```sh\necho one\n```\n\n```sh\necho two\n```\n\n{RUN_MARK}\n\
         text between\n```sh\necho three\n```\n"
    );
    let blocks = marked_blocks(&doc);
    assert_eq!(blocks, vec![(6, "echo one\n".to_string())]);
}
