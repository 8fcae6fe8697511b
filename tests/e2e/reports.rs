//! The demo's pages are self-contained, linked from the index,
//! answer "where, which, how far" per observable, and render in headless
//! Chromium (screenshot not blank, no element wider than the viewport).
//! The render check is skipped, with a message, when Chromium is absent;
//! .ci/run installs it.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::common::sparkout;

pub(crate) const CHROMIUM: &str = "/usr/bin/chromium";
const MAX_PAGE_BYTES: u64 = 2 << 20;
/// The demo's fleet page budget (docs/reports.md "Page weight").
const FLEET_PAGE_BUDGET: u64 = 400_000;

fn demo(dir: &Path) -> PathBuf {
    let r = sparkout(&["demo", "--out", dir.to_str().unwrap()]);
    assert!(
        r.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr)
    );
    dir.join("out")
}

/// Every `href="…"` of a page that points at a local file.
fn local_links(html: &str) -> Vec<String> {
    html.split("href=\"")
        .skip(1)
        .filter_map(|s| s.split('"').next())
        .filter(|h| !h.starts_with('#') && !h.contains("://"))
        .map(|h| h.split('#').next().unwrap_or(h).replace("&amp;", "&"))
        .collect()
}

/// Every `.html` file under `dir` (pages, fragments, the trend page),
/// sorted.
fn all_html(dir: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "html") {
                v.push(p);
            }
        }
    }
    v.sort();
    v
}

/// The text a reader sees: tags (with their attributes, SVG path data
/// and coordinates), comments, and style and script blocks removed; the
/// text of SVG `<text>` elements (axis ticks, labels) kept.
fn visible_text(html: &str) -> String {
    let mut out = String::with_capacity(html.len());
    let mut rest = html;
    while let Some(i) = rest.find('<') {
        out.push_str(&rest[..i]);
        out.push(' ');
        let r = &rest[i..];
        let end = if r.starts_with("<!--") {
            r.find("-->").map(|j| j + 3)
        } else if r.starts_with("<style") {
            r.find("</style>").map(|j| j + 8)
        } else if r.starts_with("<script") {
            r.find("</script>").map(|j| j + 9)
        } else {
            r.find('>').map(|j| j + 1)
        };
        match end {
            Some(j) => rest = &r[j..],
            None => return out,
        }
    }
    out.push_str(rest);
    out
}

/// Numbers an engineer should not have to read: scientific notation
/// (`6.29e-4`, `1e5`) and six or more decimals (`180.202276`). A token is
/// a run of letters, digits, `.`, `+` and `-`; only a whole token of the
/// form `[-]d[.d]e[±]d` counts as scientific, so identifiers that contain
/// such a run (a blake3 prefix like `338e9c639116`, a column name) do
/// not.
fn unreadable_numbers(text: &str) -> Vec<String> {
    fn scientific(t: &str) -> bool {
        let t = t.strip_prefix(['-', '+']).unwrap_or(t);
        let Some((m, e)) = t.split_once(['e', 'E']) else {
            return false;
        };
        let e = e.strip_prefix(['-', '+']).unwrap_or(e);
        let m_ok = match m.split_once('.') {
            Some((a, b)) => !a.is_empty() && a.chars().chain(b.chars()).all(|c| c.is_ascii_digit()),
            None => !m.is_empty() && m.chars().all(|c| c.is_ascii_digit()),
        };
        m_ok && !e.is_empty() && e.chars().all(|c| c.is_ascii_digit())
    }
    fn long_tail(t: &str) -> bool {
        let b = t.as_bytes();
        (1..b.len()).any(|i| {
            b[i] == b'.'
                && b[i - 1].is_ascii_digit()
                && b.len() >= i + 7
                && b[i + 1..i + 7].iter().all(u8::is_ascii_digit)
        })
    }
    let mut bad: Vec<String> = text
        .split(|c: char| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '+' | '-')))
        .map(|t| t.trim_end_matches('.'))
        .filter(|t| scientific(t) || long_tail(t))
        .map(str::to_string)
        .collect();
    bad.dedup();
    bad
}

#[test]
fn unreadable_numbers_are_found_in_visible_text_only() {
    let page = r#"<style>a{color:#1e3a8a}</style><svg><path d="M1e-5 0.1234567"/><text x="1.5e3">6.29e-4</text></svg><p title="3e5">blake3 338e9c639116, 180.202276 mm, 0.435 µm, 1.5e3, v0.1.0, 2026-11-20T08:00:00Z</p>"#;
    assert_eq!(
        unreadable_numbers(&visible_text(page)),
        ["6.29e-4", "180.202276", "1.5e3"]
    );
}

/// The pages of the demo checked for rendering: index, fleet, one run page
/// per machine (the plugins' sections differ, the runs of one machine do
/// not).
fn pages(out: &Path) -> Vec<PathBuf> {
    let mut v = vec![out.join("index.html"), out.join("fleet/report.html")];
    let mut machines: Vec<PathBuf> = std::fs::read_dir(out)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() && p.file_name().unwrap() != "fleet")
        .collect();
    machines.sort();
    for m in machines {
        let mut runs: Vec<PathBuf> = std::fs::read_dir(&m)
            .unwrap()
            .flatten()
            .map(|e| e.path().join("report.html"))
            .filter(|p| p.is_file())
            .collect();
        runs.sort();
        v.extend(runs.into_iter().next());
    }
    v
}

#[test]
fn demo_pages_are_linked_self_contained_and_answer_per_observable() {
    let d = tempfile::tempdir().unwrap();
    let out = demo(d.path());
    let index = std::fs::read_to_string(out.join("index.html")).expect("out/index.html");
    // The night's failures come first, then the fleet page and every run.
    let fail_at = index.find("id=\"failures\"").expect("failures section");
    let fleet_at = index
        .find("href=\"fleet/report.html\"")
        .expect("fleet link");
    assert!(fail_at < fleet_at, "failures are not at the top");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    for r in manifest["runs"].as_array().unwrap() {
        let link = format!(
            "href=\"{}/{}/report.html\"",
            r["machine"].as_str().unwrap(),
            r["run"].as_str().unwrap()
        );
        assert!(index.contains(&link), "index lacks {link}");
    }
    for f in [
        "fleet/diagnosis.json",
        "fleet/diagnosis.parquet",
        "fleet/observations.parquet",
    ] {
        assert!(index.contains(&format!("href=\"{f}\"")), "index lacks {f}");
    }
    for page in pages(&out) {
        let html = std::fs::read_to_string(&page).unwrap();
        let name = page.strip_prefix(&out).unwrap().display().to_string();
        // Self-contained: no script, nothing fetched, printable.
        assert!(!html.contains("<script"), "{name} has a script");
        for attr in ["src=\"http", "href=\"http", "url(http", "@import"] {
            assert!(
                !html.contains(attr),
                "{name} fetches from the network: {attr}"
            );
        }
        assert!(
            html.contains("@media print") && html.contains("size:A4"),
            "{name}: no print stylesheet"
        );
        assert!(
            std::fs::metadata(&page).unwrap().len() < MAX_PAGE_BYTES,
            "{name} ≥ 2 MB"
        );
        // Every local link resolves.
        let dir = page.parent().unwrap();
        for l in local_links(&html) {
            assert!(
                dir.join(&l).exists(),
                "{name} links {l}, which does not exist"
            );
        }
        // Raw JSON is linked, never dumped inline.
        assert!(!html.contains("<pre>{"), "{name} dumps JSON inline");
    }
    // Engineer numbers on every page: no scientific notation and no long
    // float tail anywhere a reader sees text.
    for page in all_html(&out) {
        let html = std::fs::read_to_string(&page).unwrap();
        let name = page.strip_prefix(&out).unwrap().display().to_string();
        let bad = unreadable_numbers(&visible_text(&html));
        assert!(bad.is_empty(), "{name} shows {bad:?}");
    }
    let fleet = std::fs::read_to_string(out.join("fleet/report.html")).unwrap();
    // No pooled number across observables of different scales.
    assert!(
        !fleet.contains("of the gap energy unexplained"),
        "pooled headline is back"
    );
    assert!(
        !fleet.contains("all observables:"),
        "pooled headline is back"
    );
    // Type → machine → observable, each with a verdict in its own unit.
    for t in ["robot", "gantry", "guideway", "mill", "form", "servo"] {
        assert!(
            fleet.contains(&format!("<h2>Machine type {t}</h2>")),
            "no {t} section"
        );
    }
    let verdicts = fleet.matches("<p class=\"verdict\">").count();
    let diag: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap();
    assert!(
        verdicts >= diag["per_observable"].as_array().unwrap().len(),
        "{verdicts} verdicts for {} observables",
        diag["per_observable"].as_array().unwrap().len()
    );
    let vel = fleet
        .split("id=\"servo-mill--velocity-error-x\"")
        .nth(1)
        .and_then(|s| s.split("</p>").next())
        .expect("velocity_error_x section of servo-mill");
    assert!(
        vel.contains(" mm/s") && !vel.contains("µm"),
        "velocity in the wrong unit: {vel}"
    );
    // The gantry's thermal bow: a gap map with its colour bar in µm, before
    // and after on one scale, and the covariate curve of the named effect.
    let gantry = fleet
        .split("id=\"aplm-gantry--surface-z\"")
        .nth(1)
        .and_then(|s| s.split("</section>").next())
        .expect("surface_z section of aplm-gantry");
    assert!(
        gantry.contains("surface_z: gap RMS per cell, before"),
        "no gap map"
    );
    assert!(
        gantry.contains("surface_z: held-out gap RMS per cell, after"),
        "no after map"
    );
    // The significant cells are outlined on the before map only.
    let after_map = gantry
        .split("held-out gap RMS per cell, after")
        .nth(1)
        .and_then(|s| s.split("<svg class=\"chart\"").next())
        .unwrap_or("");
    assert!(
        gantry.contains("class=\"outline\"") && !after_map.contains("class=\"outline\""),
        "outline not on the before map alone"
    );
    assert!(gantry.contains(">µm</text>"), "no colour bar in µm");
    assert!(
        gantry.contains("Explained by <b>thermal_bow:y_mm,t_s</b> with"),
        "{gantry}"
    );
    assert!(gantry.contains(" ± "), "named effect without its interval");
    assert!(
        gantry.contains("<details><summary>All "),
        "candidates not folded"
    );
    // A per-run RMS chart per explained observable.
    assert!(fleet.contains("RMS per run, before and held-out after"));
    // Above the fold : the at-a-glance table answers
    // where (a gap-map thumbnail), which (the gap against the named
    // effect's covariate) and how far (bars) for the explained observables.
    let glance = fleet
        .split("<table class=\"glance\">")
        .nth(1)
        .and_then(|s| s.split("</table>").next())
        .expect("at-a-glance table");
    let row = |anchor: &str| -> &str {
        glance
            .split(&format!("href=\"#{anchor}\""))
            .nth(1)
            .and_then(|s| s.split("</tr>").next())
            .unwrap_or_else(|| panic!("no glance row for {anchor}"))
    };
    let g = row("aplm-gantry--surface-z");
    assert!(
        g.contains("aria-label=\"gap RMS of") && g.matches("<rect").count() >= 9,
        "no gap-map thumbnail for the gantry: {g}"
    );
    assert!(
        g.contains("aria-label=\"gap of surface_z against t_s\""),
        "no covariate thumbnail for the gantry: {g}"
    );
    let f = row("form-grinder--profile-error");
    assert!(
        f.contains("aria-label=\"gap of profile_error against removed_mm3\"")
            && f.contains("<polyline"),
        "no covariate thumbnail for the form grinder: {f}"
    );
    assert!(f.contains("aria-label=\"gap, after, noise floor\""), "{f}");
    // Ranked by gap over noise floor, largest first.
    let ratios: Vec<f64> = glance
        .split("<tr><td><a href=\"#")
        .skip(1)
        .map(|r| {
            let cell = r.split("</td><td>").nth(1).unwrap();
            cell.trim_end_matches('×').parse().unwrap_or(f64::NAN)
        })
        .collect();
    assert!(ratios.len() >= 10, "{ratios:?}");
    assert!(
        ratios.windows(2).all(|w| w[0] >= w[1] || w[1].is_nan()),
        "not ranked by gap ÷ floor: {ratios:?}"
    );
    // The robot's touch probes are at their noise floor: one line for the
    // machine, no row, no pictures, their verdicts folded.
    let floor: Vec<&str> = glance
        .split("<tr class=\"floor\">")
        .skip(1)
        .filter(|l| l.contains("(robot / kr16-lab)"))
        .collect();
    assert_eq!(floor.len(), 1, "{glance}");
    for o in [
        "touch-normal",
        "touch-normal-ae",
        "touch-normal-electrical",
        "touch-normal-mechanical",
    ] {
        let a = format!("kr16-lab--{o}");
        assert!(floor[0].contains(&format!("href=\"#{a}\"")), "{}", floor[0]);
        assert!(
            !glance.contains(&format!("<tr><td><a href=\"#{a}\"")),
            "{a} has a row"
        );
        let section = fleet
            .split(&format!("id=\"{a}\""))
            .nth(1)
            .and_then(|s| s.split("</section>").next())
            .unwrap();
        assert!(
            section.contains("At the noise floor") && !section.contains("<svg"),
            "{a}: {section}"
        );
    }
    let folded = fleet
        .split("<details class=\"floor\"><summary>")
        .skip(1)
        .find(|d| d.starts_with("At the noise floor, nothing to explain: touch_normal,"))
        .expect("the robot's floor observables folded");
    assert!(folded.contains("id=\"kr16-lab--touch-normal\""));
    // The night's date first on both pages (the demo has no history: the
    // runs date it), then the FAIL/CHECK runs linked.
    for (page, html) in [("index", &index), ("fleet", &fleet)] {
        let news = html.find("id=\"news\"").expect("news");
        assert!(
            news < html.find("<table").unwrap(),
            "{page}: news not first"
        );
        assert!(
            html[news..].starts_with("id=\"news\" class=\"news\"><h2>Night 2026-11-20</h2>"),
            "{page}"
        );
    }
    assert!(fleet
        .contains("FAIL</b> aplm-gantry (6 runs): <a href=\"../aplm-gantry/r0000/report.html\">"));
    // Page weight: within the budget docs/reports.md states.
    let bytes = std::fs::metadata(out.join("fleet/report.html"))
        .unwrap()
        .len();
    assert!(
        bytes <= FLEET_PAGE_BUDGET,
        "the demo's fleet page is {bytes} B, over its {FLEET_PAGE_BUDGET} B budget"
    );
}

/// What headless Chromium saw on a page at 1 400 × 900.
pub(crate) struct Probe {
    /// Elements wider than the viewport (outside any scrolling box and
    /// inside no SVG): the page overflows horizontally.
    pub(crate) overflow: usize,
    /// Elements visible in the first screen.
    pub(crate) visible: usize,
    /// The first few overflowing elements, for the message.
    pub(crate) which: String,
    /// The text of the first screen (text nodes whose box starts above
    /// 900 px), whitespace collapsed.
    pub(crate) first_screen: String,
}

/// Headless Chromium on a copy of `page` with a script that measures it
/// and writes the result into the DOM, which `--dump-dom` prints.
pub(crate) fn probe(page: &Path, profile: &Path) -> Probe {
    let script = r#"<script>(function(){var w=document.documentElement.clientWidth,n=0,bad=[];
document.querySelectorAll('body *').forEach(function(e){if(e.ownerSVGElement)return;
var r=e.getBoundingClientRect();if(r.width===0||r.right<=w+1)return;
for(var a=e.parentElement;a&&a!==document.body;a=a.parentElement){var o=getComputedStyle(a).overflowX;if(o==='auto'||o==='scroll'||o==='hidden')return;}
n++;if(bad.length<5)bad.push(e.tagName+'.'+e.className+' '+Math.round(r.right));});
var vis=0;document.querySelectorAll('body *').forEach(function(e){var r=e.getBoundingClientRect();if(r.width>0&&r.height>0&&r.top<innerHeight&&r.bottom>0)vis++;});
var t=[],it=document.createTreeWalker(document.body,NodeFilter.SHOW_TEXT),x;
while((x=it.nextNode())){var g=document.createRange();g.selectNodeContents(x);var b=g.getBoundingClientRect();
if(b.height>0&&b.top<innerHeight&&b.bottom>0)t.push(x.textContent);}
var d=document.createElement('pre');d.id='probe';
d.textContent='OVERFLOW='+n+';VISIBLE='+vis+';'+bad.join('|')+';FIRST='+t.join(' ').replace(/\s+/g,' ')+';END';
document.body.appendChild(d);})();</script></body>"#;
    let html = std::fs::read_to_string(page).unwrap();
    let probe_page = page.with_file_name(".probe.html");
    std::fs::write(&probe_page, html.replace("</body>", script)).unwrap();
    let o = chromium(profile)
        .arg("--dump-dom")
        .arg(&probe_page)
        .output()
        .expect("run chromium");
    let _ = std::fs::remove_file(&probe_page);
    let dom = String::from_utf8_lossy(&o.stdout).to_string();
    // The last marker: the probe's own source also spells it.
    let tail = dom
        .rsplit("OVERFLOW=")
        .next()
        .filter(|t| t.starts_with(|c: char| c.is_ascii_digit()))
        .unwrap_or_else(|| {
            panic!(
                "the probe did not run on {}: {}",
                page.display(),
                String::from_utf8_lossy(&o.stderr)
            )
        });
    let (n, rest) = tail.split_once(';').unwrap();
    let (vis, rest) = rest.trim_start_matches("VISIBLE=").split_once(';').unwrap();
    let (which, rest) = rest.split_once(";FIRST=").unwrap();
    let first = rest.rsplit_once(";END").map_or(rest, |(f, _)| f);
    Probe {
        overflow: n.trim().parse().unwrap(),
        visible: vis.trim().parse().unwrap(),
        which: which.to_string(),
        first_screen: first
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&nbsp;", " ")
            .replace("&amp;", "&"),
    }
}

/// Prints `page` to PDF as the browser's print does (A4 by the page's
/// print style sheet); the number of pages.
pub(crate) fn print_pdf(page: &Path, pdf: &Path, profile: &Path) -> usize {
    let o = chromium(profile)
        .arg("--no-pdf-header-footer")
        .arg(format!("--print-to-pdf={}", pdf.display()))
        .arg(page)
        .output()
        .expect("run chromium");
    let bytes = std::fs::read(pdf).unwrap_or_else(|e| {
        panic!(
            "no PDF of {}: {e}: {}",
            page.display(),
            String::from_utf8_lossy(&o.stderr)
        )
    });
    assert!(
        bytes.starts_with(b"%PDF-"),
        "{} is not a PDF",
        pdf.display()
    );
    let text = String::from_utf8_lossy(&bytes);
    // Page objects (not the /Pages tree node).
    text.matches("/Type /Page").count() - text.matches("/Type /Pages").count()
}

fn chromium(profile: &Path) -> Command {
    let mut c = Command::new(CHROMIUM);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        "--window-size=1400,900",
    ])
    .arg(format!("--user-data-dir={}", profile.display()));
    c
}

/// Screenshot `page` (a file path or URL) to `png_path`; its size in bytes.
fn screenshot(page: &str, png_path: &Path, profile: &Path) -> u64 {
    let o = chromium(profile)
        .arg(format!("--screenshot={}", png_path.display()))
        .arg(page)
        .output()
        .expect("run chromium");
    assert!(
        png_path.is_file(),
        "no screenshot of {page}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::metadata(png_path).unwrap().len()
}

#[test]
fn demo_pages_render_in_headless_chromium() {
    if !Path::new(CHROMIUM).exists() {
        eprintln!("SKIPPED reports::demo_pages_render_in_headless_chromium: {CHROMIUM} not installed (apt-get install -y chromium)");
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let out = demo(d.path());
    let shots = d.path().join("shots");
    std::fs::create_dir_all(&shots).unwrap();
    let pages = pages(&out);
    assert!(pages.len() >= 8, "{pages:?}");
    // The blank reference: an empty page at the same window size. A
    // rendered page's PNG holds far more than a blank one compresses to
    // (no PNG decoder: the `png` crate's deflate features would rebuild
    // parquet and polars for every developer).
    let blank_page = d.path().join("blank.html");
    std::fs::write(&blank_page, "<!DOCTYPE html><html><body></body></html>").unwrap();
    let blank = screenshot(
        blank_page.to_str().unwrap(),
        &shots.join("blank.png"),
        &d.path().join("profile_blank"),
    );
    // The probe sees overflow where there is some (else it proves nothing).
    let wide = d.path().join("wide.html");
    std::fs::write(
        &wide,
        "<!DOCTYPE html><html><body><div style=\"width:3000px\">wide</div></body></html>",
    )
    .unwrap();
    let wide_seen = probe(&wide, &d.path().join("profile_blank"));
    assert_eq!(
        wide_seen.overflow, 1,
        "the overflow probe misses a 3000 px element"
    );
    assert!(
        wide_seen.first_screen.contains("wide"),
        "{}",
        wide_seen.first_screen
    );
    // Two pages at a time (the machine has two cores).
    type Seen = (String, u64, Probe, usize);
    let results: Vec<Seen> = std::thread::scope(|s| {
        let mut chunks: Vec<Vec<&PathBuf>> = vec![Vec::new(), Vec::new()];
        for (i, p) in pages.iter().enumerate() {
            chunks[i % 2].push(p);
        }
        let handles: Vec<_> = chunks
            .into_iter()
            .enumerate()
            .map(|(k, chunk)| {
                let (out, shots, root) = (&out, &shots, d.path());
                s.spawn(move || {
                    let profile = root.join(format!("profile{k}"));
                    chunk
                        .into_iter()
                        .map(|page| {
                            let name = page.strip_prefix(out).unwrap().display().to_string();
                            let png_path = shots.join(format!("{}.png", name.replace('/', "_")));
                            let bytes = screenshot(page.to_str().unwrap(), &png_path, &profile);
                            let pdf = png_path.with_extension("pdf");
                            let pages = print_pdf(page, &pdf, &profile);
                            let _ = std::fs::remove_file(&pdf);
                            (name, bytes, probe(page, &profile), pages)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    let _ = std::fs::remove_file(shots.join("blank.png"));
    for (name, bytes, seen, pdf_pages) in &results {
        let (over, visible) = (seen.overflow, seen.visible);
        eprintln!(
            "{name}: screenshot {bytes} B (blank {blank} B), {visible} elements in the first screen, {over} wider than the viewport, {pdf_pages} A4 page(s) printed"
        );
        assert!(
            *bytes > 4 * blank && visible >= 5,
            "{name} renders blank: screenshot {bytes} B against {blank} B blank, {visible} visible elements"
        );
        assert_eq!(
            over, 0,
            "{name}: elements wider than the viewport: {}",
            seen.which
        );
        assert!(*pdf_pages >= 1, "{name} prints no page");
    }
    // SPARKOUT_SCREENSHOTS=dir keeps the screenshots (docs/screenshots).
    if let Ok(keep) = std::env::var("SPARKOUT_SCREENSHOTS") {
        std::fs::create_dir_all(&keep).unwrap();
        for e in std::fs::read_dir(&shots).unwrap().flatten() {
            std::fs::copy(e.path(), Path::new(&keep).join(e.file_name())).unwrap();
        }
    }
}
