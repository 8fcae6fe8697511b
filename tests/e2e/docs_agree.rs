//! docs/formats.md and the plugins say the same thing: the table of
//! required tables (section 5) against each plugin's `required_tables()`
//! and `min_rows()`, the table of run.toml `[process]` keys (section 3)
//! against each plugin's `process_keys()`, the names of machine-config
//! sizes, rates and periods (section 3) against `machine_check`'s. Either
//! side changing alone fails here.

use std::collections::BTreeSet;

use sparkout_pipeline::MachinePlugin;

fn formats_md() -> String {
    std::fs::read_to_string("docs/formats.md").expect("docs/formats.md")
}

/// The body rows of the Markdown table between `<!-- NAME:begin -->` and
/// `<!-- NAME:end -->`, as trimmed cells (header and rule dropped).
fn table_rows(doc: &str, name: &str) -> Vec<Vec<String>> {
    let begin = format!("<!-- {name}:begin -->");
    let end = format!("<!-- {name}:end -->");
    let a = doc
        .find(&begin)
        .unwrap_or_else(|| panic!("docs/formats.md lacks {begin}"));
    let b = doc[a..]
        .find(&end)
        .unwrap_or_else(|| panic!("docs/formats.md lacks {end}"));
    doc[a + begin.len()..a + b]
        .lines()
        .filter(|l| l.trim_start().starts_with('|'))
        .skip(2)
        .map(|l| {
            l.trim()
                .trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

fn plugins() -> Vec<std::sync::Arc<dyn MachinePlugin>> {
    sparkout_plugins::all_plugins()
}

#[test]
fn required_tables_in_the_docs_are_the_plugins_declarations() {
    let rows = table_rows(&formats_md(), "required-tables");
    let documented: Vec<&str> = rows.iter().map(|r| r[0].as_str()).collect();
    let declared: Vec<&str> = plugins().iter().map(|p| p.name()).collect();
    assert_eq!(
        documented.iter().collect::<BTreeSet<_>>(),
        declared.iter().collect::<BTreeSet<_>>(),
        "every plugin has one row in docs/formats.md section 5"
    );
    for p in plugins() {
        let row = rows.iter().find(|r| r[0] == p.name()).unwrap();
        // `probe **or** ae + motion + plan`
        let sets: BTreeSet<BTreeSet<String>> = row[1]
            .split("**or**")
            .map(|set| set.split('+').map(|t| t.trim().to_string()).collect())
            .collect();
        let want: BTreeSet<BTreeSet<String>> = p
            .required_tables()
            .into_iter()
            .map(|set| set.into_iter().map(String::from).collect())
            .collect();
        assert_eq!(sets, want, "{}: required tables", p.name());
        // `—` or `motion 3, probe 5`
        let mins: BTreeSet<(String, usize)> = if row[2] == "—" {
            BTreeSet::new()
        } else {
            row[2]
                .split(',')
                .map(|m| {
                    let (t, n) = m.trim().rsplit_once(' ').expect("TABLE ROWS");
                    (t.to_string(), n.parse().expect("a row count"))
                })
                .collect()
        };
        let want: BTreeSet<(String, usize)> = p
            .min_rows()
            .iter()
            .map(|(t, n)| (t.to_string(), *n))
            .collect();
        assert_eq!(mins, want, "{}: minimum rows", p.name());
        // An optional table is not also required.
        let required: BTreeSet<String> = sets.iter().flatten().cloned().collect();
        for opt in row[3].split(',') {
            let name = opt.split_whitespace().next().unwrap_or("");
            assert!(
                !required.contains(name),
                "{}: `{name}` is both required and optional",
                p.name()
            );
        }
    }
}

#[test]
fn process_keys_in_the_docs_are_the_plugins_declarations() {
    let rows = table_rows(&formats_md(), "process-keys");
    let documented: Vec<(String, String, String)> = rows
        .iter()
        .map(|r| (r[0].clone(), r[1].clone(), r[2].clone()))
        .collect();
    let declared: Vec<(String, String, String)> = plugins()
        .iter()
        .flat_map(|p| {
            p.process_keys()
                .iter()
                .map(|(k, check)| (p.name().to_string(), k.to_string(), check.describe()))
                .collect::<Vec<_>>()
        })
        .collect();
    let as_set = |v: &[(String, String, String)]| v.iter().cloned().collect::<BTreeSet<_>>();
    let missing: Vec<_> = as_set(&declared)
        .difference(&as_set(&documented))
        .cloned()
        .collect();
    let stale: Vec<_> = as_set(&documented)
        .difference(&as_set(&declared))
        .cloned()
        .collect();
    assert!(
        missing.is_empty() && stale.is_empty(),
        "docs/formats.md [process] table: missing {missing:?}, not in the code {stale:?}"
    );
    assert_eq!(documented.len(), declared.len(), "a key listed twice");
}

#[test]
fn machine_config_ranges_in_the_docs_name_the_codes_positive_names() {
    use sparkout_pipeline::contracts::config_keys::POSITIVE_NAMES;
    let doc = formats_md();
    let row = doc
        .lines()
        .find(|l| l.starts_with("| positive, and the name holds"))
        .expect("docs/formats.md: the machine-config range row of sizes, rates and periods");
    let documented: BTreeSet<&str> = row.split('`').skip(1).step_by(2).collect();
    let declared: BTreeSet<&str> = POSITIVE_NAMES.iter().copied().collect();
    assert_eq!(documented, declared);
}

#[test]
fn tolerance_keys_and_defaults_in_the_docs_are_the_codes() {
    let doc = std::fs::read_to_string("docs/reports.md").expect("docs/reports.md");
    for (key, default, _) in sparkout_pipeline::contracts::tolerance::TOLERANCE_KEYS {
        let row = format!("| `{key}` | {default} |");
        assert!(doc.contains(&row), "docs/reports.md lacks the row {row}");
    }
}
