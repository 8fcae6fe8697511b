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
//!   (`cargo package` would not carry the file).

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
