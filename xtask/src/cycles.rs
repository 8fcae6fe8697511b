//! `cargo xtask cycles` — import cycles between the modules of each crate.
//!
//! A module *imports* another when its source names it by path
//! (`use crate::a::b`, `crate::a::b::f()`, `super::x`, or a sibling through
//! `self::`). The graph is drawn between the top-level modules of a crate
//! (the files and folders directly under `src/`: `engine`, `diagnose`,
//! `report`, `traits`, …) — the layers a reader meets first — so a cycle
//! is two layers each needing the other: neither can be read, tested or
//! moved into its own crate alone. Inside a top-level module, a child
//! using its parent (`super::`) is how Rust modules are written and is not
//! counted. docs/design.md ("Layers") lists the layers in order.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A crate's top-level modules and, for each, the other top-level modules
/// its files name.
pub type Graph = BTreeMap<String, BTreeSet<String>>;

/// Every `.rs` file under `dir`, sorted.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = rd.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file under `src` belongs to (`None`: the crate
/// root, lib.rs or main.rs, which declares the modules).
fn top_module(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel
        .components()
        .next()?
        .as_os_str()
        .to_string_lossy()
        .into_owned();
    if rel.components().count() == 1 {
        let stem = first.trim_end_matches(".rs");
        if stem == "lib" || stem == "main" {
            return None;
        }
        return Some(stem.to_string());
    }
    Some(first)
}

/// The module path of a file relative to `src` (`engine/shard.rs` →
/// `["engine", "shard"]`, `engine/mod.rs` → `["engine"]`).
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap_or(file);
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if let Some(last) = parts.pop() {
        let stem = last.trim_end_matches(".rs").to_string();
        if stem != "mod" && stem != "lib" && stem != "main" {
            parts.push(stem);
        }
    }
    parts
}

/// Removes comments and string literals (a path in a doc comment or a
/// message is not an import).
fn strip_comments_and_strings(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'r'
            && (b.get(i + 1) == Some(&b'"') || b.get(i + 1) == Some(&b'#'))
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'))
        {
            // A raw string r"…" or r#"…"#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                out.push('r');
                i += 1;
                continue;
            }
            j += 1;
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            while j < b.len() && !b[j..].starts_with(&close) {
                j += 1;
            }
            i = j + close.len();
            out.push_str("\"\"");
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            // A char literal such as '"'.
            out.push_str("' '");
            i += 3;
        } else if b[i] == b'\'' && b.get(i + 1) == Some(&b'\\') {
            let end = src[i + 2..].find('\'').map_or(b.len(), |k| i + 3 + k);
            out.push_str("' '");
            i = end;
        } else {
            let ch = src[i..].chars().next().unwrap_or(' ');
            out.push(ch);
            i += ch.len_utf8();
        }
    }
    out
}

/// The paths a source names, as module-path segments resolved against the
/// file's own module path: `crate::a::b` → `[a, b]`, `super::x` from
/// `[m, n]` → `[m, x]`, including every name inside `use a::{b, c::d}`.
fn named_paths(code: &str, here: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let is_ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut i = 0;
    while i < bytes.len() {
        let rest = &bytes[i..];
        let starts = ["crate::", "super::"]
            .iter()
            .find(|p| rest.starts_with(p.as_bytes()))
            .filter(|_| i == 0 || !is_ident(bytes[i - 1]) && bytes[i - 1] != b':');
        let Some(prefix) = starts else {
            i += 1;
            continue;
        };
        // Resolve the base.
        let mut base: Vec<String> = if *prefix == "crate::" {
            Vec::new()
        } else {
            here[..here.len().saturating_sub(1)].to_vec()
        };
        let mut j = i + prefix.len();
        while bytes[j..].starts_with(b"super::") {
            base.pop();
            j += "super::".len();
        }
        let (paths, end) = expand(code, j);
        for p in paths {
            let mut full = base.clone();
            full.extend(p);
            out.push(full);
        }
        i = end.max(i + 1);
    }
    out
}

/// Reads `a::b::{c, d::e}` starting at `at`: every path it names (the
/// group's prefix alone too), and where it ends.
fn expand(code: &str, at: usize) -> (Vec<Vec<String>>, usize) {
    let b = code.as_bytes();
    let mut prefix = Vec::new();
    let mut i = at;
    loop {
        let start = i;
        while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
            i += 1;
        }
        if i > start {
            prefix.push(code[start..i].to_string());
        }
        let group = if code[i..].starts_with("::{") {
            Some(3)
        } else if i == at && code[i..].starts_with('{') {
            // `crate::{a, b}`: a group right after the base.
            Some(1)
        } else {
            None
        };
        if let Some(skip) = group {
            i += skip;
            let mut out = vec![prefix.clone()];
            loop {
                while i < b.len() && (b[i].is_ascii_whitespace() || b[i] == b',') {
                    i += 1;
                }
                if i >= b.len() || b[i] == b'}' {
                    return (out, i + 1);
                }
                let (inner, end) = expand(code, i);
                for p in inner {
                    let mut full = prefix.clone();
                    full.extend(p);
                    out.push(full);
                }
                // Skip `as name` and anything up to the next item.
                i = end;
                while i < b.len() && b[i] != b',' && b[i] != b'}' {
                    i += 1;
                }
            }
        } else if code[i..].starts_with("::") {
            i += 2;
        } else {
            return (vec![prefix], i);
        }
    }
}

/// The graph between the top-level modules of the crate whose sources are
/// under `src`.
pub fn crate_graph(src: &Path) -> Graph {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let tops: BTreeSet<String> = files.iter().filter_map(|f| top_module(src, f)).collect();
    let mut g: Graph = tops.iter().map(|t| (t.clone(), BTreeSet::new())).collect();
    for f in &files {
        let Some(from) = top_module(src, f) else {
            continue;
        };
        let Ok(text) = std::fs::read_to_string(f) else {
            continue;
        };
        let code = strip_comments_and_strings(&text);
        let here = module_path(src, f);
        for p in named_paths(&code, &here) {
            if let Some(to) = p.first().filter(|t| tops.contains(*t) && **t != from) {
                g.get_mut(&from)
                    .expect("every top module")
                    .insert(to.clone());
            }
        }
    }
    g
}

/// Every cycle of `g`, one per strongly connected component with more
/// than one module, as a path that returns to its start.
pub fn cycles(g: &Graph) -> Vec<Vec<String>> {
    // Tarjan's strongly connected components.
    struct T<'a> {
        g: &'a Graph,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        next: usize,
        sccs: Vec<Vec<&'a str>>,
    }
    impl<'a> T<'a> {
        fn visit(&mut self, v: &'a str) {
            self.index.insert(v, self.next);
            self.low.insert(v, self.next);
            self.next += 1;
            self.stack.push(v);
            self.on.insert(v);
            for w in self.g.get(v).into_iter().flatten() {
                let w = w.as_str();
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low[v];
                    self.low.insert(v, lv.min(lw));
                } else if self.on.contains(w) {
                    let iw = self.index[w];
                    let lv = self.low[v];
                    self.low.insert(v, lv.min(iw));
                }
            }
            if self.low[v] == self.index[v] {
                let mut scc = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on.remove(w);
                    scc.push(w);
                    if w == v {
                        break;
                    }
                }
                if scc.len() > 1 {
                    scc.sort();
                    self.sccs.push(scc);
                }
            }
        }
    }
    let mut t = T {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        sccs: Vec::new(),
    };
    for v in g.keys() {
        if !t.index.contains_key(v.as_str()) {
            t.visit(v);
        }
    }
    // A shortest cycle through each component's first module, for the message.
    t.sccs
        .iter()
        .map(|scc| {
            let inside: BTreeSet<&str> = scc.iter().copied().collect();
            let start = scc[0];
            let mut prev: BTreeMap<&str, &str> = BTreeMap::new();
            let mut queue = std::collections::VecDeque::from([start]);
            let mut found = None;
            while let Some(v) = queue.pop_front() {
                for w in &g[v] {
                    let w = w.as_str();
                    if !inside.contains(w) {
                        continue;
                    }
                    if w == start {
                        found = Some(v);
                        break;
                    }
                    if !prev.contains_key(w) {
                        prev.insert(w, v);
                        queue.push_back(w);
                    }
                }
                if found.is_some() {
                    break;
                }
            }
            let mut path = vec![start.to_string()];
            let mut v = found.expect("a strongly connected component has a cycle");
            let mut back = vec![v.to_string()];
            while v != start {
                v = prev[v];
                if v != start {
                    back.push(v.to_string());
                }
            }
            back.reverse();
            path.extend(back);
            path.push(start.to_string());
            path
        })
        .collect()
}

/// The crates of the workspace: (name, src directory) — the root package
/// and every `[workspace] members` entry of the root Cargo.toml, so a new
/// crate is checked the day it is added.
pub fn workspace_crates(root: &Path) -> Vec<(String, PathBuf)> {
    let members: Vec<String> = std::fs::read_to_string(root.join("Cargo.toml"))
        .ok()
        .and_then(|t| t.parse::<toml::Table>().ok())
        .and_then(|t| {
            let m = t.get("workspace")?.get("members")?.as_array()?.clone();
            Some(
                m.iter()
                    .filter_map(|v| v.as_str().map(str::to_string))
                    .collect(),
            )
        })
        .unwrap_or_default();
    members
        .into_iter()
        .map(|c| (c.clone(), root.join(&c).join("src")))
        .chain(std::iter::once(("sparkout".to_string(), root.join("src"))))
        .filter(|(_, src)| src.is_dir())
        .collect()
}

/// Every crate's cycles, as `crate: a → b → a`.
pub fn workspace_cycles(root: &Path) -> Vec<String> {
    let mut all = Vec::new();
    for (name, src) in workspace_crates(root) {
        let g = crate_graph(&src);
        for c in cycles(&g) {
            all.push(format!("{name}: {}", c.join(" → ")));
        }
        if std::env::var_os("SPARKOUT_CYCLES_EDGES").is_some() {
            for (from, to) in &g {
                eprintln!(
                    "{name}: {from} → {}",
                    to.iter().cloned().collect::<Vec<_>>().join(", ")
                );
            }
        }
    }
    all
}

/// `cargo xtask cycles`: prints each crate's cycles; an error if any.
pub fn check(root: &Path) -> anyhow::Result<()> {
    let all = workspace_cycles(root);
    if all.is_empty() {
        println!("no import cycle between the top-level modules of any crate");
        return Ok(());
    }
    anyhow::bail!(
        "{} import cycle(s) between top-level modules (each layer must only name layers below it; docs/design.md \"Layers\"):\n  {}",
        all.len(),
        all.join("\n  ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(edges: &[(&str, &str)]) -> Graph {
        let mut g = Graph::new();
        for (a, b) in edges {
            g.entry(a.to_string()).or_default().insert(b.to_string());
            g.entry(b.to_string()).or_default();
        }
        g
    }

    #[test]
    fn a_cycle_is_found_and_a_chain_is_not() {
        assert!(cycles(&graph(&[("a", "b"), ("b", "c")])).is_empty());
        let c = cycles(&graph(&[("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")]));
        assert_eq!(c, vec![vec!["a", "b", "c", "a"]]);
    }

    #[test]
    fn paths_are_read_from_use_groups_super_and_inline_calls_not_comments() {
        let here: Vec<String> = vec!["report".into(), "fleet".into()];
        let code = strip_comments_and_strings(
            "use crate::{engine::run, diagnose::{fit, select as s}};\n\
             // crate::traits in a comment\n\
             let x = \"crate::storage in a string\";\n\
             let y = super::svg::heat(crate::units::Unit::Mm);",
        );
        let tops: BTreeSet<String> = named_paths(&code, &here)
            .into_iter()
            .filter_map(|p| p.first().cloned())
            .collect();
        let want: BTreeSet<String> = ["engine", "diagnose", "report", "units"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(tops, want);
    }

    /// The workspace itself: no crate has a cycle between its layers.
    #[test]
    fn the_workspace_has_no_import_cycle() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        let names: Vec<String> = workspace_crates(root).into_iter().map(|c| c.0).collect();
        for c in [
            "core", "diagnose", "report", "can", "pipeline", "plugins", "sparkout",
        ] {
            assert!(names.iter().any(|n| n == c), "{c} not checked: {names:?}");
        }
        check(root).unwrap();
    }
}
