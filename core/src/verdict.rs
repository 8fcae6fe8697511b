//! The verdict at the top of every run page: each plugin names its key
//! figure(s) — before → after, the tolerance, the model's prediction — and
//! one rule here turns the numbers into OK / CHECK / FAIL with the reason.
//! The word is always printed (a grey print loses the colour); a
//! disagreement between measurement and model gets its own box.

use std::fmt::Write;

use crate::html::esc;

/// The outcome of a verdict, worst last (so `max` is the page's status).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Status {
    Ok,
    Check,
    Fail,
}

impl Status {
    pub fn word(self) -> &'static str {
        match self {
            Status::Ok => "OK",
            Status::Check => "CHECK",
            Status::Fail => "FAIL",
        }
    }
    fn class(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Check => "check",
            Status::Fail => "bad",
        }
    }
}

/// CHECK when a figure uses more than this share of its tolerance.
pub const NEAR_LIMIT: f64 = 0.8;

/// One key figure of a run, larger is worse (a magnitude: flatness, RMS
/// error, stock left). Built by a plugin from its artifacts; judged by
/// [`Verdict::judge`] only.
#[derive(Debug, Clone)]
pub struct Verdict {
    /// What is judged, e.g. "flatness (minimum zone)".
    pub figure: String,
    pub unit: String,
    /// The state before the step (label, value), if the run measured it.
    pub before: Option<(String, f64)>,
    /// The state the verdict is about (label, value).
    pub after: (String, f64),
    /// The tolerance key and its limit.
    pub limit: Option<(String, f64)>,
    /// The model's prediction of `after` and the uncertainty within which
    /// measurement and model agree.
    pub model: Option<(f64, f64)>,
    /// The disagreement itself when a difference of the two summaries
    /// hides it (e.g. the RMS of the pointwise measured − model difference:
    /// two errors of equal size and opposite sign have equal RMS).
    pub model_gap: Option<f64>,
    /// A fact the numbers alone do not carry (e.g. a chart that cannot
    /// show what its table says): always a FAIL with this reason.
    pub defect: Option<String>,
}

/// A judged verdict.
#[derive(Debug, Clone, PartialEq)]
pub struct Judged {
    pub status: Status,
    pub reason: String,
    /// Measurement and model disagree beyond their uncertainty.
    pub contradiction: Option<String>,
}

fn n(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1}")
    } else {
        "—".into()
    }
}

impl Verdict {
    pub fn new(figure: &str, unit: &str, after_label: &str, after: f64) -> Self {
        Verdict {
            figure: figure.into(),
            unit: unit.into(),
            before: None,
            after: (after_label.into(), after),
            limit: None,
            model: None,
            model_gap: None,
            defect: None,
        }
    }
    pub fn before(mut self, label: &str, v: f64) -> Self {
        self.before = v.is_finite().then(|| (label.to_string(), v));
        self
    }
    pub fn limit(mut self, key: &str, v: f64) -> Self {
        self.limit = v.is_finite().then(|| (key.to_string(), v));
        self
    }
    pub fn model(mut self, predicted: f64, uncertainty: f64) -> Self {
        self.model = predicted
            .is_finite()
            .then_some((predicted, uncertainty.abs()));
        self
    }
    pub fn model_gap(mut self, gap: f64) -> Self {
        self.model_gap = gap.is_finite().then_some(gap);
        self
    }
    pub fn defect(mut self, why: String) -> Self {
        self.defect = Some(why);
        self
    }

    /// The rules (docs/reports.md "Verdict"): FAIL when the figure is
    /// outside its tolerance or worse than before; CHECK when it uses more
    /// than 80 % of the tolerance, or measurement and model disagree
    /// beyond their uncertainty, or it cannot be computed; else OK.
    pub fn judge(&self) -> Judged {
        let u = &self.unit;
        let (after_label, after) = (&self.after.0, self.after.1);
        let contradiction = self.model.and_then(|(m, unc)| {
            let gap = self.model_gap.unwrap_or((after - m).abs());
            (gap > unc).then(|| {
                format!(
                    "{}: {} {u} {after_label}, the model predicts {} {u}; they differ by {} {u}{} where they should agree within ±{} {u}. One of them is wrong — check the model's inputs and the measurement before acting on either.",
                    self.figure,
                    n(after),
                    n(m),
                    n(gap),
                    if self.model_gap.is_some() { " point by point (RMS)" } else { "" },
                    n(unc)
                )
            })
        });
        let mut reasons: Vec<(Status, String)> = Vec::new();
        if let Some(d) = &self.defect {
            reasons.push((Status::Fail, d.clone()));
        }
        if !after.is_finite() {
            reasons.push((
                Status::Check,
                format!("{} {after_label} could not be computed", self.figure),
            ));
        }
        if let Some((label, b)) = &self.before {
            if after > *b {
                reasons.push((
                    Status::Fail,
                    format!(
                        "worse {after_label}: {} → {} {u} ({label} → {after_label})",
                        n(*b),
                        n(after)
                    ),
                ));
            }
        }
        if let Some((key, l)) = &self.limit {
            if after > *l {
                reasons.push((
                    Status::Fail,
                    format!(
                        "outside tolerance: {} {u} > {} {u} ({key})",
                        n(after),
                        n(*l)
                    ),
                ));
            } else if after > NEAR_LIMIT * l {
                reasons.push((
                    Status::Check,
                    format!(
                        "within 20 % of the tolerance: {} {u} of {} {u} ({key})",
                        n(after),
                        n(*l)
                    ),
                ));
            }
        }
        if contradiction.is_some() {
            reasons.push((Status::Check, "measurement and model disagree".into()));
        }
        let status = reasons.iter().map(|r| r.0).max().unwrap_or(Status::Ok);
        let reason = if reasons.is_empty() {
            match &self.limit {
                Some((key, l)) => {
                    format!("within tolerance: {} {u} ≤ {} {u} ({key})", n(after), n(*l))
                }
                None => "no tolerance applies; nothing contradicts".into(),
            }
        } else {
            // The worst reasons first: the FAIL is what to read.
            let mut r = reasons;
            r.sort_by_key(|x| std::cmp::Reverse(x.0));
            r.into_iter().map(|(_, t)| t).collect::<Vec<_>>().join("; ")
        };
        Judged {
            status,
            reason,
            contradiction,
        }
    }
}

/// The verdict box: the page's overall status word, a table of every
/// figure with its status and reason, then a box per contradiction.
/// A run's verdict as `verdict.json` beside its report: the page's status
/// word and the reasons of every figure that is not OK, so the index can
/// show a status column without re-reading the run's artifacts.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunVerdict {
    /// "OK", "CHECK" or "FAIL" (CHECK when the run has no key figure).
    pub status: String,
    /// "figure: reason" for every figure judged CHECK or FAIL, worst first.
    pub reasons: Vec<String>,
}

pub const RUN_VERDICT_FILE: &str = "verdict.json";

impl RunVerdict {
    pub fn of(verdicts: &[Verdict]) -> RunVerdict {
        let mut judged: Vec<(Status, String)> = verdicts
            .iter()
            .map(|v| {
                let j = v.judge();
                (j.status, format!("{}: {}", v.figure, j.reason))
            })
            .collect();
        let status = judged.iter().map(|j| j.0).max().unwrap_or(Status::Check);
        judged.sort_by_key(|j| std::cmp::Reverse(j.0));
        RunVerdict {
            status: status.word().to_string(),
            reasons: judged
                .into_iter()
                .filter(|(s, _)| *s != Status::Ok)
                .map(|(_, r)| r)
                .collect(),
        }
    }

    /// verdict.json's bytes (pretty, newline-terminated): what the engine
    /// writes and [`RunVerdict::read`] reads back.
    pub fn to_bytes(&self) -> crate::Result<Vec<u8>> {
        let mut b = serde_json::to_vec_pretty(self)?;
        b.push(b'\n');
        Ok(b)
    }

    /// The verdict a run's output directory holds, if it has one.
    pub fn read(run_out: &std::path::Path) -> Option<RunVerdict> {
        let bytes = std::fs::read(run_out.join(RUN_VERDICT_FILE)).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    /// The status cell of the index: the word, coloured as an aid.
    pub fn cell(&self) -> String {
        let class = match self.status.as_str() {
            "OK" => "ok",
            "FAIL" => "bad",
            _ => "check",
        };
        format!(
            "<b class=\"{class}\" title=\"{}\">{}</b>",
            esc(&self.reasons.join("; ")),
            esc(&self.status)
        )
    }
}

pub fn verdict_box(verdicts: &[Verdict]) -> String {
    let judged: Vec<Judged> = verdicts.iter().map(Verdict::judge).collect();
    let overall = judged.iter().map(|j| j.status).max();
    let mut s = String::from("<section class=\"verdict\" id=\"verdict\">");
    match overall {
        None => s.push_str(
            "<p><b>Verdict: CHECK</b> — this run has no key figure to judge (a stage that produces it did not run).</p>",
        ),
        Some(st) => {
            let _ = write!(
                s,
                "<p><b>Verdict: <span class=\"{}\">{}</span></b></p>",
                st.class(),
                st.word()
            );
        }
    }
    if !verdicts.is_empty() {
        s.push_str("<table class=\"glance\"><thead><tr><th>figure</th><th>status</th><th>before</th><th>after</th><th>model</th><th>tolerance</th><th class=\"why\">reason</th></tr></thead><tbody>");
        for (v, j) in verdicts.iter().zip(&judged) {
            let u = esc(&v.unit);
            let cell = |x: Option<(&str, f64)>| match x {
                Some((l, x)) => format!("{} {u} <span class=\"note\">{}</span>", n(x), esc(l)),
                None => "—".into(),
            };
            let _ = write!(
                s,
                "<tr><td>{}</td><td><b class=\"{}\">{}</b></td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"why\">{}</td></tr>",
                esc(&v.figure),
                j.status.class(),
                j.status.word(),
                cell(v.before.as_ref().map(|(l, x)| (l.as_str(), *x))),
                cell(Some((v.after.0.as_str(), v.after.1))),
                v.model
                    .map(|(m, unc)| format!("{} ± {} {u}", n(m), n(unc)))
                    .unwrap_or_else(|| "—".into()),
                v.limit
                    .as_ref()
                    .map(|(k, l)| format!("{} {u} <span class=\"note\">{}</span>", n(*l), esc(k)))
                    .unwrap_or_else(|| "—".into()),
                esc(&j.reason)
            );
        }
        s.push_str("</tbody></table>");
    }
    for j in &judged {
        if let Some(c) = &j.contradiction {
            let _ = write!(
                s,
                "<div class=\"warn contradiction\" role=\"alert\">Contradiction: {}</div>",
                esc(c)
            );
        }
    }
    s.push_str("</section>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// verdict.json: written, read back through the same type, equal.
    #[test]
    fn the_run_verdict_round_trips_through_its_type() {
        let v = RunVerdict::of(&[Verdict::new("flatness", "µm", "after polishing", 90.6)
            .before("after grinding", 60.8)
            .limit("flatness_um", 100.0)]);
        assert_eq!(v.status, "FAIL");
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join(RUN_VERDICT_FILE), v.to_bytes().unwrap()).unwrap();
        assert_eq!(RunVerdict::read(d.path()), Some(v));
    }

    #[test]
    fn rules() {
        let v = Verdict::new("flatness", "µm", "after polishing", 90.6)
            .before("after grinding", 60.8)
            .limit("flatness_um", 100.0);
        let j = v.judge();
        assert_eq!(j.status, Status::Fail);
        assert!(j.reason.contains("worse after polishing"), "{}", j.reason);
        let ok = Verdict::new("f", "µm", "after", 10.0)
            .limit("k", 100.0)
            .judge();
        assert_eq!(ok.status, Status::Ok);
        let near = Verdict::new("f", "µm", "after", 85.0)
            .limit("k", 100.0)
            .judge();
        assert_eq!(near.status, Status::Check);
        let out = Verdict::new("f", "µm", "after", 101.0)
            .limit("k", 100.0)
            .judge();
        assert_eq!(out.status, Status::Fail);
        let c = Verdict::new("f", "µm", "after", 102.4)
            .model(-24.8, 5.0)
            .judge();
        assert_eq!(c.status, Status::Check);
        assert!(c.contradiction.is_some());
        let opposite = Verdict::new("f", "µm", "after", 20.0)
            .model(20.0, 5.0)
            .model_gap(40.0)
            .judge();
        assert!(opposite.contradiction.is_some());
        let agree = Verdict::new("f", "µm", "after", 10.0)
            .model(12.0, 5.0)
            .judge();
        assert!(agree.contradiction.is_none());
        let html = verdict_box(&[v]);
        assert!(html.contains("FAIL") && html.contains("Verdict"));
    }
}
