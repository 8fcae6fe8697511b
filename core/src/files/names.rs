//! Names are not paths. A run id, a machine name or a plugin name read from a
//! run.toml (or a shard manifest) becomes a path component of the output
//! (`<out>/<machine>/<id>/`); a name such as `..` or `a/b` would point the
//! writer — and the clean-up of a rejected run — outside `--out`. Every such
//! name is checked here at the edge, and every output path is checked to lie
//! inside its root (symbolic links resolved) before anything is written or
//! deleted there. docs/formats.md "Names" documents the character set.

use std::path::{Component, Path, PathBuf};

/// The longest name accepted (bytes): file systems allow 255, and a run
/// directory's files add their own names to the path.
pub const NAME_MAX_LEN: usize = 64;

/// Why `name` cannot be a path component, or `None` when it can. The rule:
/// 1 to [`NAME_MAX_LEN`] ASCII letters, digits, `_`, `-` and `.`, starting
/// with a letter or a digit (so never `.`, `..`, a hidden name or an option).
pub fn name_problem(name: &str) -> Option<String> {
    if name.is_empty() {
        return Some("is empty".into());
    }
    if name.len() > NAME_MAX_LEN {
        return Some(format!(
            "is {} bytes long (at most {NAME_MAX_LEN})",
            name.len()
        ));
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.')))
    {
        let shown = if c.is_control() || c.is_whitespace() {
            format!("{:?}", c)
        } else {
            format!("`{c}`")
        };
        return Some(format!(
            "contains {shown}; only ASCII letters, digits, `_`, `-` and `.` are allowed"
        ));
    }
    if !name.starts_with(|c: char| c.is_ascii_alphanumeric()) {
        return Some("must start with a letter or a digit".into());
    }
    None
}

/// [`name_problem`] as a sentence about `what` (e.g. "[run].id").
pub fn check_name(what: &str, name: &str) -> Result<(), String> {
    match name_problem(name) {
        None => Ok(()),
        Some(p) => Err(format!(
            "{what} `{}` {p} (it names an output directory, so it must be a plain name: docs/formats.md \"Names\")",
            name.escape_debug()
        )),
    }
}

/// Whether `name` is a single plain file name (no separator, not `.`/`..`),
/// as the names a run's cache file lists must be before they are deleted.
pub fn is_plain_file_name(name: &str) -> bool {
    let mut parts = Path::new(name).components();
    matches!(parts.next(), Some(Component::Normal(_))) && parts.next().is_none()
}

/// `path` made absolute and resolved as far as it exists: the longest
/// existing ancestor is canonicalised (symbolic links followed) and the
/// rest appended. `..` in the part that does not exist yet is refused by
/// returning `None`.
pub fn resolve(path: &Path) -> Option<PathBuf> {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().ok()?.join(path)
    };
    let mut existing = abs.as_path();
    let mut rest: Vec<&std::ffi::OsStr> = Vec::new();
    loop {
        if let Ok(c) = existing.canonicalize() {
            let mut out = c;
            for part in rest.iter().rev() {
                match Path::new(part).components().next() {
                    Some(Component::Normal(_)) => out.push(part),
                    Some(Component::CurDir) => {}
                    _ => return None,
                }
            }
            return Some(out);
        }
        rest.push(existing.file_name()?);
        existing = existing.parent()?;
    }
}

/// `root/<parts…>`, checked: every part is a plain name ([`name_problem`]),
/// and the path — symbolic links resolved as far as it exists — lies
/// strictly inside `root`. Use it for every output path built from a name
/// that came from the input.
pub fn inside(root: &Path, parts: &[(&str, &str)]) -> Result<PathBuf, String> {
    let mut p = root.to_path_buf();
    for (what, name) in parts {
        check_name(what, name)?;
        p.push(name);
    }
    let (Some(r), Some(q)) = (resolve(root), resolve(&p)) else {
        return Err(format!(
            "cannot resolve {} inside {}",
            p.display(),
            root.display()
        ));
    };
    if q == r || !q.starts_with(&r) {
        return Err(format!(
            "{} resolves to {}, which is not inside the output directory {} (a symbolic link there points elsewhere); remove the link",
            p.display(),
            q.display(),
            r.display()
        ));
    }
    Ok(p)
}

/// How an output (as path segments) overlaps an input: "is the same
/// directory as", "is inside", "contains", or `None` when apart. One rule
/// for local paths and bucket prefixes.
pub fn overlap<T: PartialEq>(input: &[T], out: &[T]) -> Option<&'static str> {
    if input == out {
        Some("is the same directory as")
    } else if out.starts_with(input) {
        Some("is inside")
    } else if input.starts_with(out) {
        Some("contains")
    } else {
        None
    }
}

/// `--out` must be a directory of its own: equal to, inside or containing
/// `--input`, a rejected run's clean-up or an output name could reach the
/// input. Checked before any work, paths resolved through symbolic links.
pub fn check_out_apart(input: &Path, out: &Path, input_flag: &str) -> Result<(), String> {
    let (Some(i), Some(o)) = (resolve(input), resolve(out)) else {
        return Err(format!(
            "cannot resolve {input_flag} {} or --out {}",
            input.display(),
            out.display()
        ));
    };
    let (ip, op): (Vec<Component>, Vec<Component>) =
        (i.components().collect(), o.components().collect());
    let Some(why) = overlap(&ip, &op) else {
        return Ok(());
    };
    Err(format!(
        "--out {} {why} {input_flag} {}: sparkout writes and removes its own files under --out, and never next to its inputs; choose an output directory outside the input (e.g. a sibling such as {})",
        out.display(),
        input.display(),
        i.parent()
            .map(|p| p.join("out").display().to_string())
            .unwrap_or_else(|| "../out".into())
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_are_paths_are_refused() {
        for ok in ["r0001", "xfyz-mill", "A_1.b", "9"] {
            assert_eq!(name_problem(ok), None, "{ok}");
        }
        for bad in [
            "",
            ".",
            "..",
            "a/b",
            "a\\b",
            "/abs",
            ".hidden",
            "-rf",
            "a b",
            "tab\there",
            "nul\0",
            "é",
            "<script>",
            &"x".repeat(NAME_MAX_LEN + 1),
        ] {
            assert!(name_problem(bad).is_some(), "{bad:?} accepted");
        }
        assert!(check_name("[run].id", "..")
            .unwrap_err()
            .contains("[run].id `..`"));
    }

    #[test]
    fn plain_file_names() {
        assert!(is_plain_file_name("report.html"));
        for bad in ["", ".", "..", "a/b", "/etc/passwd", "../x"] {
            assert!(!is_plain_file_name(bad), "{bad}");
        }
    }

    #[test]
    fn inside_refuses_escapes_and_links_out() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("out");
        std::fs::create_dir(&out).unwrap();
        assert!(inside(&out, &[("m", "m1"), ("r", "r1")]).is_ok());
        assert!(inside(&out, &[("m", ".."), ("r", ".")]).is_err());
        // A machine directory that is a link to somewhere else.
        let elsewhere = d.path().join("elsewhere");
        std::fs::create_dir(&elsewhere).unwrap();
        std::os::unix::fs::symlink(&elsewhere, out.join("m2")).unwrap();
        let e = inside(&out, &[("m", "m2"), ("r", "r1")]).unwrap_err();
        assert!(e.contains("not inside the output directory"), "{e}");
    }

    #[test]
    fn out_apart_from_input() {
        let d = tempfile::tempdir().unwrap();
        let input = d.path().join("in");
        std::fs::create_dir(&input).unwrap();
        let same = check_out_apart(&input, &input, "--input").unwrap_err();
        assert!(same.contains("is the same directory as"), "{same}");
        let within = check_out_apart(&input, &input.join("out"), "--input").unwrap_err();
        assert!(within.contains("is inside"), "{within}");
        let contains = check_out_apart(&input, d.path(), "--input").unwrap_err();
        assert!(contains.contains("contains"), "{contains}");
        // Through `..` and a trailing dot.
        let dotted = input.join("x").join("..").join(".");
        assert!(check_out_apart(&input, &dotted, "--input").is_err());
        assert!(check_out_apart(&input, &d.path().join("out"), "--input").is_ok());
        // A link to the input is the input.
        std::os::unix::fs::symlink(&input, d.path().join("link")).unwrap();
        assert!(check_out_apart(&input, &d.path().join("link"), "--input").is_err());
    }
}
