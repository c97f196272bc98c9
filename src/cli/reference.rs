//! The command-line reference, docs/cli.md, generated from the CLI's own definitions
//! (clap-markdown over the clap command tree): the test fails when the checked-in file
//! differs from what the binary says, and `make cli-reference` writes it anew.
#![cfg(test)]

use std::path::Path;

use clap::CommandFactory;

/// The reference as the CLI defines it today.
fn reference() -> String {
    let options = clap_markdown::MarkdownOptions::new()
        .title("Command-line reference".to_string())
        .show_footer(false);
    let generated = clap_markdown::help_markdown_custom::<super::Cli>(&options);
    format!(
        "<!-- Generated from the CLI's definitions (src/cli/); do not edit: `make cli-reference` \
         writes it, and a test fails when it differs. How-to: docs/usage.md. -->\n\n{}",
        generated.trim_start()
    )
}

#[test]
fn the_checked_in_cli_reference_is_what_the_binary_says() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cli.md");
    let text = reference();
    if std::env::var_os("IASTGCN_WRITE_CLI_REFERENCE").is_some() {
        std::fs::write(&path, &text).unwrap();
        return;
    }
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    if on_disk != text {
        let line = on_disk
            .lines()
            .zip(text.lines())
            .position(|(a, b)| a != b)
            .map_or(on_disk.lines().count().min(text.lines().count()), |i| i);
        panic!(
            "docs/cli.md differs from the CLI's definitions from line {}: run `make cli-reference`",
            line + 1
        );
    }
}

#[test]
fn the_reference_names_every_command() {
    let text = reference();
    for command in super::Cli::command().get_subcommands() {
        let heading = format!("## `iastgcn {}`", command.get_name());
        assert!(text.contains(&heading), "no {heading} in the reference");
    }
}
