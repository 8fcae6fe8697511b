//! The repository stands alone (docs/design.md §12 "Checks"): a clone is all
//! a reader needs. Each test names every offending file:line, so a failure
//! says what to fix.
//!
//! - no file cites background documents kept outside the repository, or an
//!   issue tracker's numbers (a comment says what the code does and why);
//! - the repository stays small: at most [`MAX_TRACKED`] tracked files, at
//!   most [`MAX_SEEDS`] seed files per fuzz target (fuzz/regenerate-corpus.sh
//!   rebuilds the rest);
//! - the README is a front door: at most [`MAX_README_LINES`] lines, opening
//!   with the two commands for a fresh machine;
//! - relative links in the Markdown docs point at files that exist;
//! - no crate's `include_str!`/`include_bytes!` reaches outside the crate
//!   (`cargo package` would not carry the file);
//! - no source reads JSON by string key: every JSON file goes through the
//!   serde type that writes it ([`no_json_is_read_by_string_key`]).

use std::path::{Component, Path, PathBuf};
use std::process::Command;

const MAX_TRACKED: usize = 1_000;
const MAX_SEEDS: usize = 50;
const MAX_README_LINES: usize = 250;

/// The two commands the README opens with, in this order.
const FIRST_COMMANDS: [&str; 2] = ["cargo run --release -- demo", "cargo test --workspace"];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The tracked files (`git ls-files`), or — outside a git checkout, e.g. an
/// unpacked source archive — every file below the root except build output.
fn files() -> Vec<PathBuf> {
    let git = Command::new("git")
        .args(["ls-files", "-z"])
        .current_dir(root())
        .output();
    if let Ok(out) = git {
        if out.status.success() && !out.stdout.is_empty() {
            return out
                .stdout
                .split(|b| *b == 0)
                .filter(|p| !p.is_empty())
                .map(|p| PathBuf::from(String::from_utf8_lossy(p).into_owned()))
                // Deleted in the work tree but not yet committed: gone.
                .filter(|p| root().join(p).exists())
                .collect();
        }
    }
    let mut found = Vec::new();
    walk(root(), Path::new(""), &mut found);
    found
}

fn walk(dir: &Path, rel: &Path, found: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let rel = rel.join(&name);
        let skip = ["target", ".git", "out", "sparkout-demo", "artifacts"];
        if skip.iter().any(|s| name == *s) {
            continue;
        }
        match e.file_type() {
            Ok(t) if t.is_dir() => walk(&e.path(), &rel, found),
            Ok(_) => found.push(rel),
            Err(_) => {}
        }
    }
}

/// What a line may not say. Built from pieces so that this file does not
/// match itself.
fn forbidden(line: &str) -> Option<String> {
    let md = ".md";
    for doc in ["CONTRACTS", "DESIGN", "MODELS"] {
        let name = format!("{doc}{md}");
        if line.contains(&name) {
            return Some(format!("cites {name}, which is not in the repository"));
        }
        // By name and section, without the extension.
        if line.contains(&format!("{doc} §")) {
            return Some(format!("cites {doc} §…, which is not in the repository"));
        }
    }
    let shared = format!("../{}", "shared");
    if line.contains(&shared) {
        return Some(format!("points into {shared}, outside the repository"));
    }
    // An issue tracker's number means nothing to a reader
    // of a clone.
    let b = line.as_bytes();
    for (i, _) in line.match_indices("ssue ") {
        let before = i.checked_sub(1).map(|j| b[j]);
        let after = b.get(i + 5);
        if matches!(before, Some(b'I' | b'i')) && after.is_some_and(|c| c.is_ascii_digit()) {
            return Some("names an issue number; say what the code does instead".into());
        }
    }
    None
}

#[test]
fn the_citation_check_catches_each_form() {
    let md = ".md";
    for doc in ["CONTRACTS", "DESIGN", "MODELS"] {
        assert!(forbidden(&format!("// see {doc}{md} §2")).is_some());
        assert!(forbidden(&format!("// ({doc} §2: a fleet table)")).is_some());
    }
    let outside = format!("../{}/x", "shared");
    assert!(forbidden(&format!("// as in {outside}")).is_some());
    assert!(forbidden(&format!("// fixes {}ssue 12", "i")).is_some());
    assert!(forbidden("// see docs/formats.md §7 and docs/models.md §8").is_none());
}

#[test]
fn nothing_cites_what_is_not_in_the_repository() {
    let mut bad = Vec::new();
    for f in files() {
        let Ok(bytes) = std::fs::read(root().join(&f)) else {
            continue;
        };
        // Binary files too (a fuzz seed copied from an old config would
        // carry its comments): lossy text, line by line.
        let text = String::from_utf8_lossy(&bytes);
        for (n, line) in text.lines().enumerate() {
            if let Some(why) = forbidden(line) {
                bad.push(format!("{}:{}: {why}", f.display(), n + 1));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "{} line(s) refer outside the repository:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn the_repository_stays_small() {
    let files = files();
    assert!(
        files.len() <= MAX_TRACKED,
        "{} tracked files, at most {MAX_TRACKED}: keep generated data out of git \
         (fuzz/regenerate-corpus.sh, the dataset generators)",
        files.len()
    );
    let corpus = root().join("fuzz/corpus");
    let mut over = Vec::new();
    for e in std::fs::read_dir(&corpus).expect("fuzz/corpus").flatten() {
        let n = std::fs::read_dir(e.path()).map(|d| d.count()).unwrap_or(0);
        if n > MAX_SEEDS {
            over.push(format!("{}: {n} files", e.path().display()));
        }
        assert!(n > 0, "{}: an empty seed corpus", e.path().display());
    }
    assert!(
        over.is_empty(),
        "seed corpora above {MAX_SEEDS} files (keep a spread, regenerate the rest with \
         fuzz/regenerate-corpus.sh):\n{}",
        over.join("\n")
    );
}

#[test]
fn the_readme_is_a_front_door() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let lines: Vec<&str> = readme.lines().collect();
    assert!(
        lines.len() <= MAX_README_LINES,
        "README.md has {} lines, at most {MAX_README_LINES}: move detail into docs/",
        lines.len()
    );
    // The first lines that are not a heading or blank: a fenced block of
    // exactly the two commands.
    let body: Vec<&str> = lines
        .iter()
        .map(|l| l.trim())
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .take(4)
        .collect();
    let fence_open = body.first().is_some_and(|l| l.starts_with("```"));
    assert!(
        fence_open && body.get(1..3) == Some(&FIRST_COMMANDS[..]) && body.get(3) == Some(&"```"),
        "README.md must open with a code block of exactly {FIRST_COMMANDS:?}; it opens with {body:?}"
    );
}

/// `[text](target)` targets of a Markdown line.
fn link_targets(line: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        let Some(end) = after.find(')') else { break };
        out.push(&after[..end]);
        rest = &after[end..];
    }
    out
}

#[test]
fn relative_links_in_the_docs_resolve() {
    let mut bad = Vec::new();
    for f in files() {
        if f.extension().is_none_or(|e| e != "md") {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(root().join(&f)) else {
            continue;
        };
        let dir = f.parent().unwrap_or(Path::new(""));
        for (n, line) in text.lines().enumerate() {
            for t in link_targets(line) {
                let path = t.split('#').next().unwrap_or("").trim();
                if path.is_empty() || path.contains("://") || path.starts_with("mailto:") {
                    continue;
                }
                if !root().join(dir).join(path).exists() {
                    bad.push(format!("{}:{}: {t}", f.display(), n + 1));
                }
            }
        }
    }
    assert!(
        bad.is_empty(),
        "links to files that do not exist:\n{}",
        bad.join("\n")
    );
}

/// `a/b/../c` → `a/c`, without touching the file system (a symlink inside
/// the crate is fine: `cargo package` copies its contents).
fn normalise(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// The root Cargo.toml's `[workspace] members`: (directory, package name).
fn workspace_members() -> Vec<(String, String)> {
    let root_toml: toml::Table = std::fs::read_to_string(root().join("Cargo.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let members = root_toml["workspace"]["members"].as_array().unwrap();
    members
        .iter()
        .map(|m| {
            let dir = m.as_str().unwrap().to_string();
            let t: toml::Table = std::fs::read_to_string(root().join(&dir).join("Cargo.toml"))
                .unwrap()
                .parse()
                .unwrap();
            let name = t["package"]["name"].as_str().unwrap().to_string();
            (dir, name)
        })
        .collect()
}

/// Every crate of the workspace packages on its own: `cargo package --list`
/// finds its sources and every file it includes (a file outside the crate
/// would fail here), and it declares a licence.
#[test]
fn every_crate_packages() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let members = workspace_members();
    assert!(members.len() >= 8, "{members:?}");
    for (dir, name) in members {
        let out = Command::new(&cargo)
            .args([
                "package",
                "--list",
                "--allow-dirty",
                "--offline",
                "-p",
                &name,
            ])
            .current_dir(root())
            .output()
            .unwrap();
        let listed = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "cargo package --list -p {name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            listed
                .lines()
                .any(|l| l == "src/lib.rs" || l == "src/main.rs"),
            "{name} ({dir}) lists no crate root:\n{listed}"
        );
        let manifest = std::fs::read_to_string(root().join(&dir).join("Cargo.toml")).unwrap();
        assert!(
            manifest.contains("license = \"MIT OR Apache-2.0\""),
            "{dir}/Cargo.toml declares no licence"
        );
    }
}

#[test]
fn include_str_stays_inside_its_crate() {
    // The workspace's member crates; the root package is everything else.
    let members = workspace_members();
    let crates: Vec<&str> = members.iter().map(|(dir, _)| dir.as_str()).collect();
    let mut bad = Vec::new();
    for f in files() {
        if f.extension().is_none_or(|e| e != "rs") || f.starts_with("fuzz") {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(root().join(&f)) else {
            continue;
        };
        let krate = crates
            .iter()
            .find(|c| f.starts_with(c))
            .map(PathBuf::from)
            .unwrap_or_default();
        for (n, line) in text.lines().enumerate() {
            for mac in ["include_str!(\"", "include_bytes!(\""] {
                for (i, _) in line.match_indices(mac) {
                    let arg = &line[i + mac.len()..];
                    let Some(end) = arg.find('"') else { continue };
                    let target = normalise(&f.parent().unwrap().join(&arg[..end]));
                    let inside = if krate.as_os_str().is_empty() {
                        // The root package: anything not in a member crate.
                        !target.starts_with("..") && crates.iter().all(|c| !target.starts_with(c))
                    } else {
                        target.starts_with(&krate)
                    };
                    if !inside {
                        bad.push(format!(
                            "{}:{}: {} is outside crate `{}`",
                            f.display(),
                            n + 1,
                            target.display(),
                            if krate.as_os_str().is_empty() {
                                Path::new(".")
                            } else {
                                &krate
                            }
                            .display()
                        ));
                    }
                }
            }
        }
    }
    assert!(
        bad.is_empty(),
        "include_str!/include_bytes! outside the crate (cargo package would not carry it; \
         move the file into the crate or symlink it there):\n{}",
        bad.join("\n")
    );
}

/// Files allowed to read JSON by key, each with the reason. Empty: every
/// JSON file of the workspace is read through its serde type. (A versioned
/// compatibility reader of an older layout would be the one kind of file
/// listed here, by path, with the versions it upgrades.)
const JSON_BY_KEY_ALLOWED: &[(&str, &str)] = &[];

/// Plugin sources that still read or build JSON by key: their conversion
/// to serde types is under way apart from this check, and this list is
/// emptied as it lands. The check scans plugins/ like every crate; a file
/// listed here that no longer offends is reported so the list only shrinks.
const PLUGIN_FILES_NOT_YET_TYPED: &[&str] = &[];

/// The crates' source roots the JSON rule scans.
const JSON_SCANNED: [&str; 8] = [
    "src",
    "core/src",
    "diagnose/src",
    "report/src",
    "can/src",
    "pipeline/src",
    "plugins/src",
    "datasets/src",
];

/// `text` with every comment blanked and the inside of every string and
/// char literal replaced by `x` (the quotes stay, newlines stay), so a
/// pattern is looked for in code only.
fn code_only(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let blank = |out: &mut String, s: &[char], with: char| {
        for &ch in s {
            out.push(if ch == '\n' { '\n' } else { with });
        }
    };
    let mut i = 0;
    while i < c.len() {
        let at = |k: usize| c.get(k).copied().unwrap_or('\0');
        if at(i) == '/' && at(i + 1) == '/' {
            let end = (i..c.len()).find(|&k| c[k] == '\n').unwrap_or(c.len());
            blank(&mut out, &c[i..end], ' ');
            i = end;
        } else if at(i) == '/' && at(i + 1) == '*' {
            let (mut depth, mut k) = (0usize, i);
            while k < c.len() {
                if at(k) == '/' && at(k + 1) == '*' {
                    depth += 1;
                    k += 2;
                } else if at(k) == '*' && at(k + 1) == '/' {
                    depth -= 1;
                    k += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    k += 1;
                }
            }
            blank(&mut out, &c[i..k.min(c.len())], ' ');
            i = k;
        } else if at(i) == 'r'
            && (i == 0 || !ident(c[i - 1]))
            && (at(i + 1) == '"' || at(i + 1) == '#')
        {
            // A raw string r"…" / r#"…"#.
            let hashes = (i + 1..c.len()).take_while(|&k| c[k] == '#').count();
            let open = i + 1 + hashes;
            if at(open) != '"' {
                out.push(c[i]);
                i += 1;
                continue;
            }
            let mut k = open + 1;
            while k < c.len() && !(c[k] == '"' && (1..=hashes).all(|h| at(k + h) == '#')) {
                k += 1;
            }
            out.push('"');
            blank(&mut out, &c[open + 1..k.min(c.len())], 'x');
            out.push('"');
            i = k + 1 + hashes;
        } else if at(i) == '"' {
            let mut k = i + 1;
            while k < c.len() && c[k] != '"' {
                k += if c[k] == '\\' { 2 } else { 1 };
            }
            out.push('"');
            blank(&mut out, &c[i + 1..k.min(c.len())], 'x');
            out.push('"');
            i = k + 1;
        } else if at(i) == '\'' && (at(i + 1) == '\\' || at(i + 2) == '\'') {
            // A char literal ('"', '\'', '\u{7f}'), not a lifetime.
            let end = if at(i + 1) == '\\' {
                (i + 3..c.len()).find(|&k| c[k] == '\'').unwrap_or(c.len())
            } else {
                i + 2
            };
            out.push_str("'x'");
            i = end + 1;
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

/// Does `code` hold `word` as a whole identifier?
fn has_word(code: &str, word: &str) -> bool {
    let b = code.as_bytes();
    code.match_indices(word).any(|(i, _)| {
        let end = i + word.len();
        let id = |x: u8| x.is_ascii_alphanumeric() || x == b'_';
        (i == 0 || !id(b[i - 1])) && (end == b.len() || !id(b[end]))
    })
}

/// Receivers whose string-key lookups are not JSON: a stage's
/// command-line flags (`StageArgs`, a map of flag → text) and run.toml's
/// `[process]` table (TOML).
const NOT_JSON_RECEIVERS: [&str; 2] = ["args", "process"];

/// The identifier a lookup at byte `i` of `line` is made on (`args` in
/// `args.get(…)` or `args[…]`); for a chained call that starts the line,
/// the last identifier of `prev`.
fn receiver<'a>(line: &'a str, i: usize, prev: &'a str) -> &'a str {
    let head = line[..i].trim_end();
    let head = if head.is_empty() {
        prev.trim_end()
    } else {
        head
    };
    let start = head
        .rfind(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .map_or(0, |k| k + 1);
    &head[start..]
}

/// What one line of code does with JSON that the rule forbids, if anything.
/// `json_file`: the file holds JSON (string-literal lookups count); `prev`:
/// the line before (a chained call's receiver).
fn json_by_key(line: &str, prev: &str, json_file: bool) -> Option<&'static str> {
    for (pat, why) in [
        (".as_f64(", "reads a number out of a JSON value"),
        (".as_u64(", "reads a number out of a JSON value"),
        (".as_i64(", "reads a number out of a JSON value"),
        (".as_object(", "opens a JSON object to look keys up"),
        (".as_object_mut(", "opens a JSON object to look keys up"),
        (".pointer(", "looks a JSON pointer up"),
        (".pointer_mut(", "looks a JSON pointer up"),
    ] {
        if line.contains(pat) {
            return Some(why);
        }
    }
    let b = line.as_bytes();
    for (i, _) in line.match_indices("json!") {
        let before = i.checked_sub(1).map(|j| b[j]);
        let after = line[i + 5..].trim_start().as_bytes().first().copied();
        if !before.is_some_and(|x| x.is_ascii_alphanumeric() || x == b'_')
            && matches!(after, Some(b'(' | b'{' | b'['))
        {
            return Some("builds JSON by hand instead of writing a serde type");
        }
    }
    if !json_file {
        return None;
    }
    for pat in [".get(\"", ".get_mut(\""] {
        for (i, _) in line.match_indices(pat) {
            if !NOT_JSON_RECEIVERS.contains(&receiver(line, i, prev)) {
                return Some("looks a value up by a string key");
            }
        }
    }
    for (i, _) in line.match_indices('[') {
        let indexed = i
            .checked_sub(1)
            .map(|j| b[j])
            .is_some_and(|x| x.is_ascii_alphanumeric() || matches!(x, b'_' | b')' | b']' | b'?'));
        if indexed
            && line[i + 1..].trim_start().starts_with('"')
            && !NOT_JSON_RECEIVERS.contains(&receiver(line, i, prev))
        {
            return Some("indexes a value by a string key");
        }
    }
    None
}

/// The offending lines of one source file: (line number, why).
fn json_offences(text: &str) -> Vec<(usize, &'static str)> {
    let code = code_only(text);
    // Tests may build and pick apart JSON as they like: from the first
    // `#[cfg(test)]` on, the file is a test.
    let lines: Vec<&str> = code
        .lines()
        .take_while(|l| !l.trim_start().starts_with("#[cfg(test)]"))
        .collect();
    let code = lines.join("\n");
    let json_file =
        code.contains("serde_json") || (has_word(&code, "Value") && !has_word(&code, "toml"));
    lines
        .iter()
        .enumerate()
        .filter_map(|(n, l)| {
            let prev = if n > 0 { lines[n - 1] } else { "" };
            json_by_key(l, prev, json_file).map(|why| (n + 1, why))
        })
        .collect()
}

/// No JSON is read by string key (docs/design.md §12 "Checks"): every JSON
/// file the pipeline, the binary, the datasets and the plugins write or
/// read goes through a serde type that writes it and reads it back, so a
/// renamed field fails to compile or to parse instead of reading as "?" or
/// NaN.
///
/// The rule is lexical, over the code of every non-test `.rs` file under
/// [`JSON_SCANNED`] (comments and the insides of string literals blanked;
/// files under a `tests/` directory, named `tests.rs` or `*_tests.rs`, and
/// everything from a file's first `#[cfg(test)]` on, are tests and
/// skipped). A line offends when it
///
/// - calls a JSON-only accessor — `.as_f64()`, `.as_u64()`, `.as_i64()`,
///   `.as_object()`, `.pointer()` (and their `_mut` forms): a field picked
///   out of a `serde_json::Value` (TOML's accessors are `as_float`,
///   `as_integer`, `as_table`, so a config reader never trips this);
/// - builds a document with `json!` instead of serialising its type;
/// - in a file that holds JSON — its code names `serde_json`, or names
///   `Value` without naming `toml` — looks anything up by a string literal:
///   `x["key"]`, `.get("key")`, `.get_mut("key")` — except on a stage's
///   command-line flags (`args`, a `StageArgs`) or run.toml's `[process]`
///   table (`process`), which are not JSON. A file that names
///   `toml` and not `serde_json` reads config tables by key: config
///   parsing, typed by a separate effort, and left alone here.
///
/// A free-form value that is part of a format — a plugin's stage summary
/// the engine passes through, the config echoed into manifest.json — may
/// be held as a `Value`, never indexed. A file that must read JSON by key
/// (a compatibility reader of an older layout) is listed in
/// [`JSON_BY_KEY_ALLOWED`] with its reason; plugin files whose conversion is
/// under way, in [`PLUGIN_FILES_NOT_YET_TYPED`]. A listed file that no longer
/// offends fails the check too, so the lists only shrink.
#[test]
fn no_json_is_read_by_string_key() {
    let mut bad = Vec::new();
    let mut offending_files = std::collections::BTreeSet::new();
    let mut scanned = 0;
    for f in files() {
        let rel = f.to_string_lossy().replace('\\', "/");
        let name = f
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if f.extension().is_none_or(|e| e != "rs")
            || !JSON_SCANNED
                .iter()
                .any(|r| rel.starts_with(&format!("{r}/")))
            || rel.contains("/tests/")
            || name == "tests.rs"
            || name.ends_with("_tests.rs")
        {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(root().join(&f)) else {
            continue;
        };
        scanned += 1;
        let offences = json_offences(&text);
        if offences.is_empty() {
            continue;
        }
        offending_files.insert(rel.clone());
        if JSON_BY_KEY_ALLOWED.iter().any(|(p, _)| *p == rel)
            || PLUGIN_FILES_NOT_YET_TYPED.contains(&rel.as_str())
        {
            continue;
        }
        let lines: Vec<&str> = text.lines().collect();
        for (n, why) in offences {
            let shown = lines.get(n - 1).map_or("", |l| l.trim());
            bad.push(format!("{rel}:{n}: {why}: `{shown}`"));
        }
    }
    assert!(
        scanned > 100,
        "only {scanned} source files scanned: the walk looks in the wrong place"
    );
    let listed = JSON_BY_KEY_ALLOWED
        .iter()
        .map(|(p, _)| *p)
        .chain(PLUGIN_FILES_NOT_YET_TYPED.iter().copied());
    let stale: Vec<&str> = listed.filter(|p| !offending_files.contains(*p)).collect();
    let misplaced: Vec<&&str> = PLUGIN_FILES_NOT_YET_TYPED
        .iter()
        .filter(|p| !p.starts_with("plugins/src/"))
        .collect();
    assert!(
        bad.is_empty(),
        "{} line(s) read or build JSON by string key: read and write the file through a serde \
         type (`Deserialize` + `Serialize`; crate::files::json::read_json names the field of a \
         bad file), or for a stage summary `StageOutput::typed` and `ArtifactStore::summary_as`:\n{}",
        bad.len(),
        bad.join("\n")
    );
    assert!(
        stale.is_empty() && misplaced.is_empty(),
        "listed as reading JSON by key but clean now (remove from the list): {stale:?}; \
         not a plugin file: {misplaced:?}"
    );
}

#[test]
fn the_json_rule_tells_json_from_toml_and_code_from_comments() {
    let json = "use serde_json::Value;\nfn f(v: &Value) -> f64 {\n    v[\"rms_mm\"].as_f64().unwrap()\n}\n";
    assert_eq!(json_offences(json).len(), 1);
    assert_eq!(json_offences(json)[0].0, 3);
    // A glob-imported `Value` in a file that names no TOML is JSON.
    assert_eq!(
        json_offences("fn f(a: &Value) -> bool { a.get(\"held_out\").is_some() }").len(),
        1
    );
    assert_eq!(
        json_offences("let x = serde_json::json!({\"a\": 1});").len(),
        1
    );
    assert_eq!(json_offences("let x = json! ([1]);").len(), 1);
    // A TOML reader is config parsing: left alone.
    let toml = "fn f(t: &toml::Table) -> Option<&toml::Value> { t.get(\"run\")?.get(\"id\") }\nlet k = t[\"k_sigma\"].as_float();\n";
    assert!(json_offences(toml).is_empty());
    // Comments, strings, char literals, arrays of literals and tests.
    let quiet = "use serde_json::Value;\n// v[\"a\"].as_f64()\n/* m.get(\"k\") */\nlet s = \"v[\\\"a\\\"].as_f64()\";\nlet r = r#\"x.get(\"a\")\"#;\nlet q = '\"';\nlet names = vec![\"a\", \"b\"];\nlet one = [\"a\"];\nfn f<'a>(x: &'a str) {}\n#[cfg(test)]\nmod tests { fn t(v: Value) { v[\"a\"].as_f64(); } }\n";
    assert_eq!(json_offences(quiet), Vec::<(usize, &str)>::new());
    // Without serde_json, a string-keyed map lookup is not JSON.
    assert!(json_offences("fn f(m: &BTreeMap<String, f64>) -> f64 { m[\"k\"] }").is_empty());
}

/// Every library crate returns a typed error (sparkout-core's `Error`,
/// sparkout-can's own; thiserror): anyhow stays at the binary's edge
/// (`src/`) and in the developer tool `xtask`.
const TYPED_ERROR_CRATES: [&str; 7] = [
    "core", "diagnose", "report", "can", "pipeline", "plugins", "datasets",
];

#[test]
fn typed_error_crates_do_not_use_anyhow() {
    let mut bad = Vec::new();
    let mut scanned = 0;
    for f in files() {
        let rel = f.to_string_lossy().replace('\\', "/");
        if f.extension().is_none_or(|e| e != "rs")
            || !TYPED_ERROR_CRATES
                .iter()
                .any(|r| rel.starts_with(&format!("{r}/src/")))
        {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(root().join(&f)) else {
            continue;
        };
        scanned += 1;
        for (n, line) in code_only(&text).lines().enumerate() {
            if has_word(line, "anyhow") {
                bad.push(format!("{rel}:{}: `{}`", n + 1, line.trim()));
            }
        }
    }
    assert!(
        scanned > 100,
        "only {scanned} files scanned: the walk looks in the wrong place"
    );
    // Nor may a library crate depend on anyhow at all.
    for c in TYPED_ERROR_CRATES {
        let manifest = std::fs::read_to_string(root().join(c).join("Cargo.toml")).unwrap();
        let deps: toml::Table = toml::from_str(&manifest).unwrap();
        for section in ["dependencies", "dev-dependencies"] {
            if deps
                .get(section)
                .and_then(|d| d.as_table())
                .is_some_and(|d| d.contains_key("anyhow"))
            {
                bad.push(format!("{c}/Cargo.toml: [{section}] names anyhow"));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "these crates return their own error type (`crate::Error`, thiserror); anyhow stays \
         in the binary:\n{}",
        bad.join("\n")
    );
}
