//! Every run page opens with a verdict: the key figure before → after
//! against its tolerance or the model, with a status word (OK / CHECK /
//! FAIL) and the reason. On the demo fleet the known problems must be
//! flagged: the gantry surface worse after polishing, the robot's and the
//! form model's disagreement with the measurement, the mill's after-map
//! showing the measured residual; the servo page shows lags in ms and a
//! ballbar plot. `[tolerance]` in run.toml moves a status; an unknown key
//! is refused by name.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use super::common::{sparkout, text};

/// The demo, generated once for the tests of this file, under cargo's
/// scratch folder for integration tests (inside target/, so `cargo clean`
/// takes it; a static is never dropped, so a temporary directory would
/// outlive every run). The folders of earlier test processes that have
/// exited are removed first.
fn demo() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        const PREFIX: &str = "run-verdicts-demo-";
        let scratch = Path::new(env!("CARGO_TARGET_TMPDIR"));
        for e in std::fs::read_dir(scratch).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if let Some(pid) = name.strip_prefix(PREFIX) {
                if !Path::new("/proc").join(pid).exists() {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        let dir = scratch.join(format!("{PREFIX}{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let o = sparkout(&["demo", "--out", dir.to_str().unwrap()]);
        assert!(
            dir.join("out/index.html").exists(),
            "demo wrote no index: {}",
            text(&o)
        );
        dir
    })
}

/// (machine, run, html) of every run page under `out`.
fn run_pages(out: &Path) -> Vec<(String, String, String)> {
    let mut v = Vec::new();
    for m in std::fs::read_dir(out).unwrap().flatten() {
        if !m.path().is_dir() || m.file_name() == "fleet" || m.file_name() == "trend" {
            continue;
        }
        for r in std::fs::read_dir(m.path()).unwrap().flatten() {
            let page = r.path().join("report.html");
            if page.exists() {
                v.push((
                    m.file_name().to_string_lossy().into_owned(),
                    r.file_name().to_string_lossy().into_owned(),
                    std::fs::read_to_string(page).unwrap(),
                ));
            }
        }
    }
    v.sort();
    v
}

/// The verdict section of a page and its overall status word.
fn verdict(html: &str) -> (&str, &'static str) {
    let start = html
        .find("<section class=\"verdict\"")
        .expect("a verdict section");
    let end = start + html[start..].find("</section>").expect("closed");
    let first_h2 = html.find("<h2>").unwrap_or(html.len());
    assert!(
        start < first_h2,
        "the verdict comes before every plugin section"
    );
    let v = &html[start..end];
    let head = &v[..v.find("</p>").expect("status line")];
    let word = ["FAIL", "CHECK", "OK"]
        .into_iter()
        .find(|w| head.contains(&format!(">{w}<")))
        .unwrap_or_else(|| panic!("no status word in the verdict line: {head}"));
    (v, word)
}

#[test]
fn every_demo_run_page_opens_with_a_verdict_and_the_known_problems_are_flagged() {
    let pages = run_pages(&demo().join("out"));
    let plugins: std::collections::BTreeSet<&str> = pages.iter().map(|p| p.0.as_str()).collect();
    assert!(plugins.len() >= 6, "every machine of the demo: {plugins:?}");
    let mut contradicted = std::collections::BTreeSet::new();
    for (machine, run, html) in &pages {
        let (v, word) = verdict(html);
        if v.contains("Contradiction:") {
            contradicted.insert(machine.clone());
        }
        match machine.as_str() {
            // Polishing made every demo surface less flat than grinding left it.
            "aplm-gantry" => {
                assert_eq!(word, "FAIL", "{machine}/{run}: {v}");
                assert!(v.contains("worse after polish"), "{machine}/{run}: {v}");
            }
            "xfyz-mill" => {
                assert!(v.contains("after table compensation"), "{v}");
                // The after-map is the measured residual, not the model
                // less its own table (blank by construction).
                assert!(
                    html.contains("after table compensation (measured)")
                        && html.contains("measured residual |d − c|"),
                    "{machine}/{run}: the after-map shows the measured residual"
                );
            }
            "servo-mill" => {
                assert!(html.contains("effective lag (ms)"), "{machine}/{run}");
                assert!(html.contains("class=\"chart polar\""), "{machine}/{run}");
                assert!(v.contains("effective lag, axis x"), "{v}");
            }
            _ => {}
        }
    }
    // The robot's model predicts negative stock where the probe measures
    // ~0.1 mm; the form model misses the wheel wear; the servo's lag is
    // not the configured one.
    for m in ["kr16-lab", "form-grinder", "servo-mill"] {
        assert!(
            contradicted.contains(m),
            "{m} flags a contradiction: {contradicted:?}"
        );
    }
    // The index carries each run page's status word (from verdict.json
    // beside the page), so a FAIL is visible without opening the run.
    let out = demo().join("out");
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(index.contains("<th>status</th>"), "no status column");
    for (machine, run, html) in &pages {
        let (_, word) = verdict(html);
        let v: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join(machine).join(run).join("verdict.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(
            v["status"], word,
            "{machine}/{run}: verdict.json and the page disagree"
        );
        if word != "OK" {
            assert!(
                !v["reasons"].as_array().unwrap().is_empty(),
                "{machine}/{run}: a {word} without a reason"
            );
        }
    }
    let fails = index.matches(">FAIL</b>").count();
    let gantry_runs = pages.iter().filter(|p| p.0 == "aplm-gantry").count();
    assert!(
        fails >= gantry_runs,
        "{fails} FAIL cells for {gantry_runs} failing gantry runs"
    );
}

/// A demo mill run copied into its own input root with `extra` appended
/// to its run.toml, run; (exit output, page html if any).
fn mill_run_with(tag: &str, extra: &str) -> (String, Option<String>) {
    let src = demo().join("runs/xfyz-mill/r0000");
    let root = demo().join(format!("tol-{tag}"));
    let dst = root.join("in/xfyz-mill/r0000");
    std::fs::create_dir_all(&dst).unwrap();
    for f in std::fs::read_dir(&src).unwrap().flatten() {
        std::fs::copy(f.path(), dst.join(f.file_name())).unwrap();
    }
    let toml = std::fs::read_to_string(dst.join("run.toml")).unwrap();
    std::fs::write(dst.join("run.toml"), format!("{toml}\n{extra}\n")).unwrap();
    let out = root.join("out");
    let o = sparkout(&[
        "run",
        "--input",
        root.join("in").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let failures = std::fs::read_to_string(out.join("failures.json")).unwrap_or_default();
    let page = std::fs::read_to_string(out.join("xfyz-mill/r0000/report.html")).ok();
    (format!("{}\n{failures}", text(&o)), page)
}

#[test]
fn a_tolerance_in_run_toml_changes_the_status() {
    let pages = run_pages(&demo().join("out"));
    let (_, _, html) = pages
        .iter()
        .find(|p| p.0 == "xfyz-mill" && p.1 == "r0000")
        .expect("demo mill run");
    assert_eq!(
        verdict(html).1,
        "OK",
        "default tolerance: {}",
        verdict(html).0
    );
    let (log, page) = mill_run_with("tight", "[tolerance]\nvolumetric_um = 5");
    let page = page.unwrap_or_else(|| panic!("no page: {log}"));
    let (v, word) = verdict(&page);
    assert_eq!(word, "FAIL", "{v}");
    assert!(
        v.contains("outside tolerance") && v.contains("volumetric_um"),
        "{v}"
    );
}

#[test]
fn an_unknown_tolerance_key_is_refused_by_name() {
    let (log, page) = mill_run_with("typo", "[tolerance]\nvolumetric_mm = 5");
    assert!(
        page.is_none(),
        "a run with a typo'd tolerance is not reported"
    );
    assert!(log.contains("volumetric_mm"), "the key is named: {log}");
}
