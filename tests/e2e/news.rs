//! The night's news first: the index and the fleet page open with the
//! night's date and a banner of its trend alerts (machine, observable,
//! effect, old → new in engineer units, share of the gap, linked to the
//! trend chart and the runs), the rejected runs and the FAIL/CHECK runs —
//! on three nights of a form grinder whose wheel wears twice as fast on the
//! third. The fleet table ranks observables by gap over noise floor, folds
//! those at their floor into one line and, with `--augment`, shows last
//! night's model on tonight's runs.

use std::path::{Path, PathBuf};

use super::common::{ok, sparkout};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Night `n` of a three-run form grinder whose wheel wears at `k` mm/mm³,
/// run with `--history` (plus `more` flags); its output directory.
fn night(dir: &Path, n: u32, k: f64, more: &[&str]) -> PathBuf {
    let root = dir.join(format!("runs{n}"));
    ok(sparkout(&[
        "generate",
        "form",
        "--runs",
        "3",
        "--seed",
        &n.to_string(),
        "--out",
        s(&root),
        "--effect",
        &format!("wheel_wear=k_mm_per_mm3={k}"),
    ]));
    if n == 3 {
        // Tonight one run is damaged: rejected, and in the news.
        let (good, bad) = (
            root.join("form-grinder/r0000"),
            root.join("form-grinder/r0003"),
        );
        std::fs::create_dir_all(&bad).unwrap();
        for f in std::fs::read_dir(&good).unwrap().flatten() {
            std::fs::copy(f.path(), bad.join(f.file_name())).unwrap();
        }
        let spec = std::fs::read_to_string(bad.join("run.toml")).unwrap();
        std::fs::write(bad.join("run.toml"), spec.replace("\"r0000\"", "\"r0003\"")).unwrap();
        std::fs::write(bad.join("profile.parquet"), b"not parquet").unwrap();
    }
    run_night(dir, n, &format!("out{n}"), more)
}

/// `sparkout run` over night `n`'s runs into `dir/<out>`, with `--history`.
fn run_night(dir: &Path, n: u32, out: &str, more: &[&str]) -> PathBuf {
    let root = dir.join(format!("runs{n}"));
    let out = dir.join(out);
    let history = dir.join("history");
    let night = format!("2026-11-0{n}");
    let mut args = vec![
        "run",
        "--input",
        s(&root),
        "--out",
        s(&out),
        "--history",
        s(&history),
        "--night",
        &night,
    ];
    args.extend_from_slice(more);
    let o = sparkout(&args);
    // Night 3 has a rejected run: exit code 2, the pages written.
    assert!(
        o.status.success() || (n == 3 && o.status.code() == Some(2)),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// The part of a page before `marker` (its first table or section after
/// the news): the banner.
fn before<'a>(html: &'a str, marker: &str) -> &'a str {
    let end = html
        .find(marker)
        .unwrap_or_else(|| panic!("no {marker} in the page"));
    &html[..end]
}

#[test]
fn both_pages_open_with_the_nights_date_and_the_wear_alert() {
    let d = tempfile::tempdir().unwrap();
    night(d.path(), 1, 1.5e-5, &[]);
    let two = night(d.path(), 2, 1.5e-5, &[]);
    let model = two.join("fleet/augmented_model.json");
    let out = night(d.path(), 3, 3.0e-5, &["--augment", s(&model)]);
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    let fleet = std::fs::read_to_string(out.join("fleet/report.html")).unwrap();
    let trend = std::fs::read_to_string(out.join("trend/trend.html")).unwrap();
    for (name, head, base) in [
        ("index", before(&index, "id=\"failures\""), ""),
        (
            "fleet page",
            before(&fleet, "<table class=\"glance\">"),
            "../",
        ),
    ] {
        assert!(
            head.contains("Night 2026-11-03: 1 trend alert"),
            "{name}: {head}"
        );
        // The alert: machine, observable, effect, old → new in nm/mm³,
        // share of the gap, linked to its chart and its runs.
        let alert = &head[head.find("<ol><li>").expect("ranked alerts")..];
        let alert = &alert[..alert.find("</li>").unwrap()];
        for want in [
            "<b>form-grinder</b>",
            "profile_error",
            "<b>wheel_wear:removed_mm3</b> k moved",
            "nm/mm³ → <b>",
            "of the gap (",
            " µm of ",
        ] {
            assert!(alert.contains(want), "{name} lacks {want}: {alert}");
        }
        let chart = format!("href=\"{base}trend/trend.html#trend-fleet-profile_error\"");
        assert!(alert.contains(&chart), "{name}: {alert}");
        let runs = format!("href=\"{base}index.html#runs-form-grinder\"");
        assert!(alert.contains(&runs), "{name}: {alert}");
        // The rejected run and the runs whose verdict is not OK.
        assert!(head.contains("1 rejected"), "{name}: {head}");
        assert!(
            head.contains("form-grinder / r0003") && head.contains("profile.parquet"),
            "{name}: {head}"
        );
        assert!(
            head.contains(&format!("href=\"{base}form-grinder/r0000/report.html\"")),
            "{name}: {head}"
        );
    }
    // The links land: the chart's id on the trend page, the machine's runs
    // on the index.
    assert!(trend.contains("id=\"trend-fleet-profile_error\""));
    assert!(index.contains("id=\"runs-form-grinder\""));
    // With --augment: last night's model on tonight's runs, in the table.
    let glance = &fleet[fleet.find("<table class=\"glance\">").unwrap()..];
    let glance = &glance[..glance.find("</table>").unwrap()];
    assert!(
        glance.contains("last night's model on tonight's runs"),
        "{glance}"
    );
    let row = &glance[glance
        .find("href=\"#form-grinder--profile-error\"")
        .unwrap()..];
    assert!(row.contains(" µm → <b>"), "{row}");
    // The same night again: the same bytes (no clock in the page).
    let again = run_night(d.path(), 3, "again", &["--augment", s(&model)]);
    assert_eq!(
        std::fs::read(again.join("fleet/report.html")).unwrap(),
        fleet.as_bytes()
    );
    rendered_first_screens(d.path(), &out);
}

/// In headless Chromium at 1 400 × 900: the first screen of the index and
/// of the fleet page shows the night's date and the top alert; those pages
/// and the trend page do not overflow horizontally and print to PDF.
fn rendered_first_screens(dir: &Path, out: &Path) {
    use super::reports::{print_pdf, probe, CHROMIUM};
    if !Path::new(CHROMIUM).exists() {
        eprintln!("SKIPPED news::rendered_first_screens: {CHROMIUM} not installed (apt-get install -y chromium)");
        return;
    }
    let profile = dir.join("chromium-profile");
    for (page, first) in [
        ("index.html", true),
        ("fleet/report.html", true),
        ("trend/trend.html", false),
    ] {
        let path = out.join(page);
        let seen = probe(&path, &profile);
        assert_eq!(seen.overflow, 0, "{page} overflows: {}", seen.which);
        if first {
            for want in ["2026-11-03", "wheel_wear", "profile_error", "nm/mm³"] {
                assert!(
                    seen.first_screen.contains(want),
                    "{page}: `{want}` is not in the first 900 px: {}",
                    seen.first_screen
                );
            }
        }
        let pdf = dir.join(format!("{}.pdf", page.replace('/', "_")));
        assert!(
            print_pdf(&path, &pdf, &profile) >= 1,
            "{page} prints no page"
        );
    }
}

/// The demo (no history): dated from its runs, never "today".
#[test]
fn without_a_history_the_night_is_dated_from_the_runs() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    ok(sparkout(&[
        "generate",
        "form",
        "--runs",
        "2",
        "--seed",
        "5",
        "--out",
        s(&root),
    ]));
    let out = d.path().join("out");
    ok(sparkout(&["run", "--input", s(&root), "--out", s(&out)]));
    let spec = std::fs::read_to_string(root.join("form-grinder/r0000/run.toml")).unwrap();
    let started = spec
        .lines()
        .find_map(|l| l.strip_prefix("started = \""))
        .expect("the generator dates its runs");
    let date = &started[..10];
    for page in ["index.html", "fleet/report.html"] {
        let html = std::fs::read_to_string(out.join(page)).unwrap();
        let news = &html[html.find("id=\"news\"").expect("news")..];
        assert!(
            news.starts_with(&format!("id=\"news\" class=\"news\"><h2>Night {date}</h2>")),
            "{page}: {}",
            &news[..200.min(news.len())]
        );
        assert!(news.contains("No trend"), "{page}");
    }
}
