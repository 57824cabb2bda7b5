//! The docs stay true to the binary: every `cbdam …` command in a code block of the README or of
//! a page of `docs/` names a subcommand that exists (and a sub-subcommand, as in `cbdam shard
//! plan` or `cbdam bench report`), and every `--flag` it names appears in that subcommand's
//! `--help`. The commands are not run: a command whose flags all exist may still be wrong in
//! its values. Every relative link (a file, a heading's anchor) resolves.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::util::*;

/// One `cbdam` command found in a code block: where it is, and its words after `cbdam`.
struct DocCommand {
    place: String,
    words: Vec<String>,
}

/// The words of every `cbdam …` (or `cargo run [--release] -- …`) command in the fenced code
/// blocks of `text`. Comments (`#` at a line's start or after a space) are dropped, lines ending
/// in `\` are joined to the next, and a line is split into commands at `&&`, `||`, `;` and `|`.
fn commands_in(file: &str, text: &str) -> Vec<DocCommand> {
    let mut found = Vec::new();
    let mut in_block = false;
    let mut joined = String::new();
    let mut first_line = 0;
    for (index, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            joined.clear();
            continue;
        }
        if !in_block {
            continue;
        }
        if joined.is_empty() {
            first_line = index + 1;
        }
        let code = without_comment(line);
        if let Some(continued) = code.trim_end().strip_suffix('\\') {
            joined.push_str(continued);
            joined.push(' ');
            continue;
        }
        joined.push_str(code);
        let place = format!("{file}:{first_line}");
        for segment in joined.split(['&', '|', ';']) {
            if let Some(words) = cbdam_words(segment) {
                found.push(DocCommand {
                    place: place.clone(),
                    words,
                });
            }
        }
        joined.clear();
    }
    found
}

/// `line` up to its shell comment, if any.
fn without_comment(line: &str) -> &str {
    let bytes = line.as_bytes();
    for (i, &b) in bytes.iter().enumerate() {
        if b == b'#' && (i == 0 || bytes[i - 1].is_ascii_whitespace()) {
            return &line[..i];
        }
    }
    line
}

/// The words after `cbdam` (a word of its own, or after a quote) or after `cargo run
/// [--release] --` in `segment`, if it holds such a command with at least a subcommand.
fn cbdam_words(segment: &str) -> Option<Vec<String>> {
    let words: Vec<&str> = segment.split_whitespace().collect();
    let start = (0..words.len()).find_map(|i| {
        let word = words[i].trim_start_matches(['"', '\'', '[']);
        if word == "cbdam" {
            return Some(i + 1);
        }
        if words[i] == "cargo" && words.get(i + 1) == Some(&"run") {
            let rest = &words[i + 2..];
            let dashes = rest.iter().position(|w| *w == "--")?;
            if rest[..dashes].iter().all(|w| *w == "--release") {
                return Some(i + 2 + dashes + 1);
            }
        }
        None
    })?;
    let rest: Vec<String> = words[start..]
        .iter()
        .map(|w| w.trim_end_matches(['"', '\'', ']', ',', ')']).to_string())
        .collect();
    let subcommand = rest.first()?;
    if subcommand.is_empty()
        || !subcommand
            .chars()
            .all(|c| c.is_ascii_lowercase() || c == '-')
    {
        return None;
    }
    Some(rest)
}

/// Runs `cbdam ARGS… --help` once per distinct `args`: its exit status and output.
struct Helps(HashMap<Vec<String>, (bool, String)>);

impl Helps {
    fn get(&mut self, args: &[String]) -> &(bool, String) {
        self.0.entry(args.to_vec()).or_insert_with(|| {
            let mut with_help: Vec<&str> = args.iter().map(String::as_str).collect();
            with_help.push("--help");
            let o = cbdam(&with_help);
            (o.status.success(), stdout(&o))
        })
    }
}

/// Whether `help` names `flag` (`--size` is not found in `--size-limit`).
fn help_names_flag(help: &str, flag: &str) -> bool {
    help.match_indices(flag).any(|(at, _)| {
        help[at + flag.len()..]
            .chars()
            .next()
            .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '-'))
    })
}

/// What is wrong with `command` against the binary's help, if anything.
fn check(command: &DocCommand, helps: &mut Helps) -> Vec<String> {
    let words = &command.words;
    let shown = format!("{}: `cbdam {}`", command.place, words.join(" "));
    let mut path = vec![words[0].clone()];
    let (known, help) = helps.get(&path).clone();
    if !known {
        return vec![format!("{shown}: no subcommand `{}`", words[0])];
    }
    let mut help = help;
    let mut rest = &words[1..];
    if help.contains("\nCommands:") {
        let Some(sub) = rest.first() else {
            return vec![format!("{shown}: `{}` needs a subcommand", words[0])];
        };
        path.push(sub.clone());
        let (known, sub_help) = helps.get(&path).clone();
        if !known {
            return vec![format!("{shown}: no subcommand `{} {sub}`", words[0])];
        }
        help = sub_help;
        rest = &rest[1..];
    }
    rest.iter()
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| w.split('=').next().unwrap())
        .filter(|flag| *flag != "--help" && !help_names_flag(&help, flag))
        .map(|flag| format!("{shown}: `cbdam {}` has no flag {flag}", path.join(" ")))
        .collect()
}

/// The README and every Markdown page of `docs/`.
fn documentation() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    files.extend(pages);
    files
}

#[test]
fn every_command_in_the_readme_and_docs_parses() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut helps = Helps(HashMap::new());
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in documentation() {
        let text = std::fs::read_to_string(&file).unwrap();
        let name = file.strip_prefix(root).unwrap().display().to_string();
        for command in commands_in(&name, &text) {
            checked += 1;
            problems.extend(check(&command, &mut helps));
        }
    }
    assert!(checked >= 10, "only {checked} commands found in the docs");
    assert!(
        problems.is_empty(),
        "{} of {checked} documented commands do not parse:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

#[test]
fn the_readme_shows_the_test_command_and_the_main_job() {
    let readme = std::fs::read_to_string(documentation().remove(0)).unwrap();
    let commands = commands_in("README.md", &readme);
    assert!(readme.contains("\n./scripts/test.sh\n"));
    assert!(
        commands
            .iter()
            .any(|c| c.words.first().is_some_and(|w| w == "build")),
        "the README's quick start builds a repository"
    );
}

/// The finder itself, on the forms the docs use.
#[test]
fn commands_are_found_as_the_docs_write_them() {
    let text = "```sh\n\
        # cbdam serve in a comment is not a command\n\
        cargo run --release -- build a.tif -o a.cbdam --max-error 1 && cargo run --release -- verify a.cbdam \\\n    --against a.tif   # --not-a-flag\n\
        P=1 cbdam replay x --paced | head\n\
        command: [\"sh\", \"-c\", \"cbdam shard run --work /w --shard 3\"]\n\
        python3 s.py target/release/cbdam\n\
        ```\n\
        cbdam view outside a block\n";
    let found: Vec<String> = commands_in("t.md", text)
        .iter()
        .map(|c| format!("{} {}", c.place, c.words.join(" ")))
        .collect();
    assert_eq!(
        found,
        [
            "t.md:3 build a.tif -o a.cbdam --max-error 1",
            "t.md:3 verify a.cbdam --against a.tif",
            "t.md:5 replay x --paced",
            "t.md:6 shard run --work /w --shard 3",
        ]
    );
    assert!(help_names_flag("  --size <WxH>\n", "--size"));
    assert!(!help_names_flag("  --size-limit <N>\n", "--size"));
}

/// The relative links `](target)` of Markdown `text`, outside code blocks: `(path, anchor)`,
/// either part possibly empty; web and mail links are left out.
fn links_in(text: &str) -> Vec<(String, String)> {
    let mut found = Vec::new();
    let mut in_block = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if in_block {
            continue;
        }
        for (i, _) in line.match_indices("](") {
            let rest = &line[i + 2..];
            let Some(end) = rest.find(')') else { continue };
            let target = &rest[..end];
            if target.contains(' ') || target.starts_with("http") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = target.split_once('#').unwrap_or((target, ""));
            found.push((path.to_string(), anchor.to_string()));
        }
    }
    found
}

/// GitHub's anchor of a heading: lower case, punctuation dropped (letters, digits, `-` and
/// `_` kept), spaces as `-`.
fn anchor_of(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of the headings of Markdown `text` (outside code blocks).
fn anchors_in(text: &str) -> Vec<String> {
    let mut in_block = false;
    let mut anchors = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
        } else if !in_block && line.starts_with('#') {
            anchors.push(anchor_of(line.trim_start_matches('#')));
        }
    }
    anchors
}

#[test]
fn every_relative_link_in_the_readme_and_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in documentation() {
        let text = std::fs::read_to_string(&file).unwrap();
        let name = file.strip_prefix(root).unwrap().display().to_string();
        for (path, anchor) in links_in(&text) {
            checked += 1;
            let target = if path.is_empty() {
                file.clone()
            } else {
                file.parent().unwrap().join(&path)
            };
            if !target.exists() {
                problems.push(format!("{name}: {path} does not exist"));
                continue;
            }
            let is_markdown = target.extension().is_some_and(|e| e == "md");
            if !anchor.is_empty() && is_markdown {
                let page = std::fs::read_to_string(&target).unwrap();
                if !anchors_in(&page).contains(&anchor) {
                    problems.push(format!("{name}: {path}#{anchor}: no such heading"));
                }
            }
        }
    }
    assert!(checked >= 50, "only {checked} links found in the docs");
    assert!(
        problems.is_empty(),
        "{} of {checked} links are broken:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

/// The link finder and GitHub's anchors, on the forms the docs use.
#[test]
fn links_and_anchors_are_read_as_github_does() {
    let text = "See [a](docs/A.md#the-demo), [b](#local) and [w](https://x.org/a).\n\
        ```\n[not](a/link.md)\n```\n![pic](globe.png)\n";
    assert_eq!(
        links_in(text),
        [
            ("docs/A.md".to_string(), "the-demo".to_string()),
            (String::new(), "local".to_string()),
            ("globe.png".to_string(), String::new()),
        ]
    );
    assert_eq!(
        anchor_of(" An Earth to measure on: `cbdam synth --earth`"),
        "an-earth-to-measure-on-cbdam-synth---earth"
    );
    assert_eq!(anchor_of("Rendering offscreen"), "rendering-offscreen");
}
