//! The documents name only what exists (issue #50 point 5). For each
//! document below, every code span (`...`) and every line of a fenced code
//! block is read, and:
//!
//! - (a) a relative path that starts with a top-level folder of the
//!   repository (`crates/`, `firmware/`, ...) or is a top-level `*.md` must
//!   exist. Paths with placeholders (`<id>`, `NAME`, `*`, `...`, `{`, `$`)
//!   and generated ones (`out/`, `eval/results/`, `bench/results/`, anything
//!   under a `target/` or `out/` folder) are not checked;
//! - (b) a `models/NAME` must be a folder of `models/` unless the lines of
//!   that code span say "retired", "git archive" or "not in the tree". Two
//!   exceptions, each for one document. models/README.md has one section
//!   per model and keeps a retired model's commands and figures in it; the
//!   section says once that the model is retired and how `git archive`
//!   restores it, so there the section (heading to heading) counts. A second,
//!   narrower one: eval/README.md names the retired models whose
//!   comparisons a current decision rests on without saying so each time; there
//!   (only there) a model is accepted when models/README.md gives the
//!   `git archive COMMIT models/NAME` that restores it;
//! - (c) a command's program (the first word of a code span with arguments,
//!   or of a line in a fenced block marked `sh`, `bash`, `shell` or
//!   `console`, after `sudo`, `VAR=value`, `./target/release/`) that looks
//!   like one of ours (`dbt-*`, `dbtor-*`, `host-sim`, `*-bench`) must be a
//!   binary of the workspace; `cargo run -p P --bin B` must name a package
//!   and a binary that exist. A lone name (`dbtor-x4t3`) is not a command:
//!   models, runs and crates share the prefix. Unmarked fenced blocks are
//!   diagrams (ARCHITECTURE.md), not commands; their paths are checked.
//!
//! No cargo invocation: the binaries are read from the `Cargo.toml` files'
//! `[[bin]]` names, `src/main.rs` and `src/bin/*.rs`.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

/// Top-level folders whose paths the documents name.
const TOP: &[&str] = &[
    "crates/",
    "firmware/",
    "host-sim/",
    "eval/",
    "models/",
    "training/",
    "scripts/",
    "hil-tests/",
    "bench/",
    "fuzz/",
    "docs/",
    "phantoms/",
];

/// Generated paths: written by a command, not committed.
const GENERATED: &[&str] = &["out/", "eval/results/", "bench/results/"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// The documents checked, relative to the root.
fn documents(root: &Path) -> Vec<String> {
    let mut docs: Vec<String> = [
        "README.md",
        "ARCHITECTURE.md",
        "eval/README.md",
        "eval/ladder.md",
        "models/README.md",
        "training/README.md",
        "host-sim/README.md",
        "hil-tests/README.md",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut pages: Vec<String> = fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".md"))
        .map(|n| format!("docs/{n}"))
        .collect();
    pages.sort();
    docs.extend(pages);
    docs
}

/// The workspace's binaries and packages.
struct Targets {
    bins: BTreeSet<String>,
    packages: BTreeSet<String>,
}

fn targets(root: &Path) -> Targets {
    let mut dirs: Vec<PathBuf> = ["firmware", "host-sim", "eval", "bench", "hil-tests"]
        .iter()
        .map(|d| root.join(d))
        .collect();
    for e in fs::read_dir(root.join("crates"))
        .expect("crates/ exists")
        .flatten()
    {
        dirs.push(e.path());
    }
    let mut bins = BTreeSet::new();
    let mut packages = BTreeSet::new();
    for dir in dirs {
        let Ok(toml) = fs::read_to_string(dir.join("Cargo.toml")) else {
            continue;
        };
        // `name = "..."` in [package] and in each [[bin]].
        let mut section = String::new();
        let mut package = None;
        for line in toml.lines() {
            let t = line.trim();
            if t.starts_with('[') {
                section = t.to_string();
                continue;
            }
            if let Some(v) = t.strip_prefix("name") {
                let v = v.trim_start();
                if let Some(v) = v.strip_prefix('=') {
                    let name = v.trim().trim_matches('"').to_string();
                    match section.as_str() {
                        "[package]" => package = Some(name),
                        "[[bin]]" => {
                            bins.insert(name);
                        }
                        _ => {}
                    }
                }
            }
        }
        let package = package.expect("a [package] name");
        if dir.join("src/main.rs").exists() {
            bins.insert(package.clone());
        }
        if let Ok(rd) = fs::read_dir(dir.join("src/bin")) {
            for e in rd.flatten() {
                let n = e.file_name().to_string_lossy().into_owned();
                if let Some(stem) = n.strip_suffix(".rs") {
                    bins.insert(stem.to_string());
                }
            }
        }
        packages.insert(package);
    }
    Targets { bins, packages }
}

/// A code span or a fenced line: its text, the document lines it covers
/// (1-based, inclusive), whether it is a line of a fenced block and
/// whether that block is marked as shell.
struct Span {
    text: String,
    first: usize,
    last: usize,
    fenced: bool,
    fenced_shell: bool,
}

fn spans(doc: &str) -> Vec<Span> {
    let mut out = Vec::new();
    let mut fence: Option<bool> = None; // Some(is_shell) inside a fence
    let mut para: Vec<(usize, &str)> = Vec::new();
    let flush = |para: &mut Vec<(usize, &str)>, out: &mut Vec<Span>| {
        inline_spans(para, out);
        para.clear();
    };
    for (i, line) in doc.lines().enumerate() {
        let n = i + 1;
        let t = line.trim_start();
        if let Some(info) = t.strip_prefix("```") {
            if fence.is_some() {
                fence = None;
            } else {
                flush(&mut para, &mut out);
                let info = info.trim();
                fence = Some(matches!(info, "sh" | "bash" | "shell" | "console"));
            }
            continue;
        }
        match fence {
            Some(shell) => out.push(Span {
                text: line.to_string(),
                first: n,
                last: n,
                fenced: true,
                fenced_shell: shell,
            }),
            None if t.is_empty() => flush(&mut para, &mut out),
            None => para.push((n, line)),
        }
    }
    flush(&mut para, &mut out);
    out
}

/// For each line (0-based), the text of the section it is in: from the
/// heading before it (outside fenced blocks) to the next, lower-cased.
fn sections(doc: &str) -> Vec<std::rc::Rc<String>> {
    let lines: Vec<&str> = doc.lines().collect();
    let mut starts = vec![0];
    let mut fenced = false;
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim_start();
        if t.starts_with("```") {
            fenced = !fenced;
        } else if !fenced && t.starts_with('#') && i > 0 {
            starts.push(i);
        }
    }
    starts.push(lines.len());
    let mut out = Vec::with_capacity(lines.len());
    for w in starts.windows(2) {
        let text = std::rc::Rc::new(lines[w[0]..w[1]].join(" ").to_lowercase());
        for _ in w[0]..w[1] {
            out.push(text.clone());
        }
    }
    out
}

fn says_retired(text: &str) -> bool {
    text.contains("retired") || text.contains("git archive") || text.contains("not in the tree")
}

/// The code spans of one paragraph (a span may run over a line break).
fn inline_spans(para: &[(usize, &str)], out: &mut Vec<Span>) {
    let mut chars: Vec<(usize, char)> = Vec::new();
    for (n, line) in para {
        chars.extend(line.chars().map(|c| (*n, c)));
        chars.push((*n, '\n'));
    }
    let mut i = 0;
    while i < chars.len() {
        if chars[i].1 != '`' {
            i += 1;
            continue;
        }
        let run = chars[i..].iter().take_while(|c| c.1 == '`').count();
        let start = i + run;
        // The closing run of the same length.
        let mut j = start;
        let mut close = None;
        while j < chars.len() {
            if chars[j].1 == '`' {
                let r = chars[j..].iter().take_while(|c| c.1 == '`').count();
                if r == run {
                    close = Some(j);
                    break;
                }
                j += r;
            } else {
                j += 1;
            }
        }
        let Some(end) = close else {
            i = start;
            continue;
        };
        out.push(Span {
            text: chars[start..end]
                .iter()
                .map(|c| c.1)
                .collect::<String>()
                .replace('\n', " "),
            first: chars[i].0,
            last: chars[end].0,
            fenced: false,
            fenced_shell: false,
        });
        i = end + run;
    }
}

/// A word cut to the path it names: quotes, brackets and trailing
/// punctuation off, a `::item` or `:line` suffix off.
fn clean(word: &str) -> &str {
    let w = word.trim_matches(|c: char| "`\"'()[],;".contains(c));
    let w = w.split("::").next().unwrap();
    let w = w.split('#').next().unwrap();
    let w = match w.find(':') {
        Some(k) => &w[..k],
        None => w,
    };
    w.trim_end_matches(['.', ',', ';', ':'])
}

fn is_placeholder(p: &str) -> bool {
    p.contains('<')
        || p.contains('>')
        || p.contains('*')
        || p.contains("...")
        || p.contains("NAME")
        || p.contains('{')
        || p.contains('$')
        || p.contains('|')
}

fn is_generated(p: &str) -> bool {
    GENERATED.iter().any(|g| p.starts_with(g)) || p.split('/').any(|c| c == "out" || c == "target")
}

fn looks_ours(program: &str) -> bool {
    program.starts_with("dbt-")
        || program.starts_with("dbtor-")
        || program == "host-sim"
        || program.ends_with("-bench")
}

#[test]
fn documents_name_only_what_exists() {
    let root = root();
    let t = targets(&root);
    assert!(
        t.bins.contains("dbtor-diag") && t.bins.contains("dbt-eval"),
        "binaries found: {:?}",
        t.bins
    );
    let models: BTreeSet<String> = fs::read_dir(root.join("models"))
        .expect("models/ exists")
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();

    // The retired models models/README.md says how to restore.
    let models_readme =
        fs::read_to_string(root.join("models/README.md")).expect("models/README.md");
    let words: Vec<&str> = models_readme.split_whitespace().map(clean).collect();
    let restorable: BTreeSet<String> = words
        .windows(4)
        .filter(|w| w[0] == "git" && w[1] == "archive")
        .filter_map(|w| w[3].strip_prefix("models/"))
        .map(|n| n.trim_end_matches('/').to_string())
        .collect();
    assert!(
        restorable.contains("dbtor-x4t"),
        "restorable models found: {restorable:?}"
    );

    let mut missing = Vec::new();
    for doc in documents(&root) {
        let text = fs::read_to_string(root.join(&doc)).unwrap_or_else(|e| panic!("{doc}: {e}"));
        let lines: Vec<&str> = text.lines().collect();
        let section = sections(&text);
        for span in spans(&text) {
            let covered = lines[span.first - 1..span.last].join(" ").to_lowercase();
            let retired = says_retired(&covered)
                || (doc == "models/README.md" && says_retired(&section[span.first - 1]));
            let at = format!("{doc}:{}", span.first);

            // (a) and (b): paths and models.
            for word in span.text.split_whitespace() {
                let p = clean(word);
                let p = p.strip_prefix("./").unwrap_or(p);
                let top_md = !p.contains('/')
                    && p.ends_with(".md")
                    && p.chars().next().is_some_and(|c| c.is_ascii_uppercase())
                    && p[..p.len() - 3]
                        .chars()
                        .all(|c| c.is_ascii_uppercase() || c == '_');
                if !(TOP.iter().any(|d| p.starts_with(d)) || top_md) {
                    continue;
                }
                if is_placeholder(p) || is_generated(p) {
                    continue;
                }
                if let Some(rest) = p.strip_prefix("models/") {
                    let name = rest.split('/').next().unwrap();
                    if name.is_empty() || name.ends_with(".md") {
                        // models/ itself, models/README.md: a path like any other.
                    } else if retired || (doc == "eval/README.md" && restorable.contains(name)) {
                        continue;
                    } else if !models.contains(name) {
                        missing.push(format!(
                            "{at}: model `models/{name}` is not a folder of models/ (say it is retired, with its `git archive` command, or name a model that exists)"
                        ));
                        continue;
                    }
                }
                if !root.join(p).exists() {
                    missing.push(format!("{at}: path `{p}` does not exist"));
                }
            }

            // (c): programs, not in diagrams.
            if span.fenced && !span.fenced_shell {
                continue;
            }
            let text = if span.fenced_shell {
                span.text.split(" #").next().unwrap().to_string()
            } else {
                span.text.clone()
            };
            for command in text.split(&['|', ';'][..]).flat_map(|c| c.split("&&")) {
                let words: Vec<&str> = command.split_whitespace().collect();
                let mut k = 0;
                while k < words.len()
                    && (words[k] == "sudo"
                        || words[k].split_once('=').is_some_and(|(v, _)| {
                            !v.is_empty() && v.chars().all(|c| c.is_ascii_uppercase() || c == '_')
                        }))
                {
                    k += 1;
                }
                let Some(first) = words.get(k) else { continue };
                let program = first
                    .trim_start_matches("./")
                    .trim_start_matches("target/release/")
                    .trim_start_matches("target/debug/");
                let program = program.trim_end_matches([',', ';', ':', '.']);
                if program == "cargo" && words.get(k + 1) == Some(&"run") {
                    for (flag, set, what) in
                        [("-p", &t.packages, "package"), ("--bin", &t.bins, "binary")]
                    {
                        if let Some(i) = words.iter().position(|w| *w == flag) {
                            if let Some(name) = words.get(i + 1) {
                                if !is_placeholder(name) && !set.contains(*name) {
                                    missing.push(format!("{at}: `cargo run {flag} {name}`: no {what} `{name}` in the workspace"));
                                }
                            }
                        }
                    }
                    continue;
                }
                if !looks_ours(program)
                    || program.contains('/')
                    || program.contains('.')
                    || is_placeholder(program)
                {
                    continue;
                }
                let command_like = span.fenced_shell || words.len() > k + 1;
                if command_like && !t.bins.contains(program) {
                    missing.push(format!(
                        "{at}: command `{program}` is not a binary of the workspace"
                    ));
                }
            }
        }
    }
    assert!(
        missing.is_empty(),
        "{} name(s) in the documents that do not exist:\n{}",
        missing.len(),
        missing.join("\n")
    );
}

#[test]
fn spans_are_read_across_a_line_break_and_in_shell_blocks() {
    let doc = "a `crates/x\ny` b ``c`d``\n\n```sh\ndbtor-diag x # c\n```\n```\ndiagram\n```\n";
    let s = spans(doc);
    let got: Vec<(&str, usize, usize, bool, bool)> = s
        .iter()
        .map(|s| (s.text.as_str(), s.first, s.last, s.fenced, s.fenced_shell))
        .collect();
    assert_eq!(
        got,
        vec![
            ("crates/x y", 1, 2, false, false),
            ("c`d", 2, 2, false, false),
            ("dbtor-diag x # c", 5, 5, true, true),
            ("diagram", 8, 8, true, false),
        ]
    );
    assert_eq!(clean("`crates/dbt-dicom::bounds`),"), "crates/dbt-dicom");
    assert_eq!(
        clean("firmware/src/daemon.rs:12."),
        "firmware/src/daemon.rs"
    );
}
