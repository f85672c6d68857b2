//! docs/cli.md, the command-line reference, written from the clap definitions themselves so it
//! cannot drift from `--help`: a test compares the file with what this module writes and fails
//! when it is stale (`LPMSPLAT_BLESS=1` rewrites it).

use clap::{Arg, ArgAction, Command};
use std::fmt::Write;

/// The whole reference as Markdown: the global flags once, then every subcommand (nested ones
/// under their parent) with its usage and its own flags.
pub fn markdown(root: &Command) -> String {
    let mut root = root.clone();
    root.build();
    let globals: Vec<String> = root
        .get_arguments()
        .filter(|a| a.is_global_set())
        .map(|a| a.get_id().to_string())
        .collect();
    let mut out = String::new();
    out.push_str(
        "# Command-line reference\n\n\
         Written from the program's own argument definitions (`src/cli/reference_doc.rs`); a \
         test fails when this file is stale. To rewrite it: `LPMSPLAT_BLESS=1 cargo test \
         --release --bin lpmsplat cli_reference`. `lpmsplat <command> --help` prints the same \
         text.\n\n",
    );
    let _ = writeln!(out, "## Contents\n");
    contents(&root, 0, &mut out);
    out.push('\n');
    section(&root, &[], &globals, &mut out);
    out
}

fn contents(cmd: &Command, depth: usize, out: &mut String) {
    for sub in visible_subcommands(cmd) {
        let name = full_name(sub);
        let _ = writeln!(
            out,
            "{}- [`{name}`](#{})",
            "  ".repeat(depth),
            anchor(&name)
        );
        contents(sub, depth + 1, out);
    }
}

fn section(cmd: &Command, parents: &[&str], globals: &[String], out: &mut String) {
    let name = full_name(cmd);
    let level = "#".repeat((parents.len() + 2).min(4));
    let _ = writeln!(out, "{level} `{name}`\n");
    if let Some(about) = cmd.get_long_about().or(cmd.get_about()) {
        let _ = writeln!(out, "{}\n", about.to_string().trim_end());
    }
    let usage = cmd.clone().render_usage().to_string();
    let usage = usage.trim_start_matches("Usage: ").trim_end();
    let _ = writeln!(out, "```text\n{usage}\n```\n");
    let top = parents.is_empty();
    let args: Vec<&Arg> = cmd
        .get_arguments()
        .filter(|a| !a.is_hide_set())
        .filter(|a| !matches!(a.get_action(), ArgAction::Help | ArgAction::HelpShort))
        .filter(|a| !matches!(a.get_action(), ArgAction::Version))
        .filter(|a| top || !globals.iter().any(|g| g == a.get_id().as_str()))
        .collect();
    if !args.is_empty() {
        if top {
            let _ = writeln!(out, "Global flags (before or after the subcommand):\n");
        }
        for a in args {
            argument(a, out);
        }
        out.push('\n');
    }
    let mut path: Vec<&str> = parents.to_vec();
    path.push(cmd.get_name());
    for sub in visible_subcommands(cmd) {
        section(sub, &path, globals, out);
    }
}

fn argument(a: &Arg, out: &mut String) {
    let value = value_name(a);
    let mut names = Vec::new();
    if a.is_positional() {
        names.push(format!("`{value}`"));
    } else {
        if let Some(s) = a.get_short() {
            names.push(format!("`-{s}`"));
        }
        if let Some(l) = a.get_long() {
            let shown = if a.get_action().takes_values() {
                format!("`--{l} <{value}>`")
            } else {
                format!("`--{l}`")
            };
            names.push(shown);
        }
    }
    let help = a
        .get_long_help()
        .or(a.get_help())
        .map(|h| h.to_string())
        .unwrap_or_default();
    let mut line = format!("- {}", names.join(", "));
    if a.is_required_set() {
        line.push_str(" (required)");
    }
    if !help.trim().is_empty() {
        // One list item: the help's later lines indented under it, blank lines kept blank.
        let body: Vec<String> = help
            .trim_end()
            .lines()
            .enumerate()
            .map(|(i, l)| match (i, l.is_empty()) {
                (0, _) | (_, true) => l.to_string(),
                _ => format!("  {l}"),
            })
            .collect();
        let _ = write!(line, ": {}", body.join("\n"));
    }
    let values: Vec<String> = a
        .get_possible_values()
        .iter()
        .filter(|v| !v.is_hide_set())
        .map(|v| format!("`{}`", v.get_name()))
        .collect();
    let is_flag = matches!(a.get_action(), ArgAction::SetTrue | ArgAction::SetFalse);
    if !values.is_empty() && !is_flag {
        let _ = write!(line, "\n  Values: {}.", values.join(", "));
    }
    let defaults: Vec<String> = a
        .get_default_values()
        .iter()
        .map(|d| d.to_string_lossy().into_owned())
        .collect();
    if !defaults.is_empty() && !is_flag && !help.contains("[default:") {
        let _ = write!(line, "\n  Default: `{}`.", defaults.join(","));
    }
    if let Some(env) = a.get_env() {
        let _ = write!(line, "\n  Environment: `{}`.", env.to_string_lossy());
    }
    out.push_str(&line);
    out.push('\n');
}

fn value_name(a: &Arg) -> String {
    match a.get_value_names() {
        Some(v) if !v.is_empty() => v
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
            .join(" "),
        _ => a.get_id().as_str().to_uppercase(),
    }
}

fn visible_subcommands(cmd: &Command) -> impl Iterator<Item = &Command> {
    cmd.get_subcommands()
        .filter(|s| !s.is_hide_set() && s.get_name() != "help")
}

fn full_name(cmd: &Command) -> String {
    cmd.get_bin_name()
        .map(str::to_string)
        .unwrap_or_else(|| cmd.get_name().to_string())
}

/// GitHub's heading anchors: lower case, spaces to hyphens, punctuation dropped.
fn anchor(title: &str) -> String {
    title
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;
    use std::path::Path;

    /// docs/cli.md is what the definitions write today. Fails when a flag, its help or a
    /// subcommand changed without the file; `LPMSPLAT_BLESS=1` rewrites it instead.
    #[test]
    fn cli_reference_is_current() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cli.md");
        let now = markdown(&crate::cli::Cli::command());
        if std::env::var_os("LPMSPLAT_BLESS").is_some() {
            std::fs::write(&path, &now).unwrap();
            return;
        }
        let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
        if on_disk != now {
            let line = on_disk
                .lines()
                .zip(now.lines())
                .position(|(a, b)| a != b)
                .map(|i| i + 1)
                .unwrap_or(on_disk.lines().count().min(now.lines().count()) + 1);
            panic!(
                "docs/cli.md is stale from line {line}: the command line changed. Fix: \
                 LPMSPLAT_BLESS=1 cargo test --release --bin lpmsplat cli_reference, then commit it"
            );
        }
    }

    /// Every subcommand and every visible flag of `train` is in the reference, and globals are
    /// listed once: a check of the writer itself, not of the file.
    #[test]
    fn the_reference_names_every_subcommand_and_flag() {
        let cmd = crate::cli::Cli::command();
        let md = markdown(&cmd);
        for sub in cmd.get_subcommands() {
            assert!(
                md.contains(&format!("`lpmsplat {}`", sub.get_name())),
                "{} missing",
                sub.get_name()
            );
        }
        let train = cmd.find_subcommand("train").unwrap();
        for a in train.get_arguments().filter(|a| !a.is_hide_set()) {
            if let Some(l) = a.get_long() {
                assert!(md.contains(&format!("`--{l}")), "--{l} missing");
            }
        }
        assert_eq!(md.matches("`--memory-limit <MIB>`").count(), 1);
    }

    #[test]
    fn anchors_follow_github() {
        assert_eq!(anchor("`lpmsplat bench trade`"), "lpmsplat-bench-trade");
    }
}
