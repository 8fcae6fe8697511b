//! Deliberate changes on a machine — a wheel change, a dressing, a repair, a
//! config change — are events, not alarms: the trend starts a new baseline
//! at each one. They come from `<history>/events.toml` (kept with the
//! history, appended to by `run --history --event`), from `--event` on
//! `sparkout trend` (this report only), and from the history itself: a night
//! whose config differs from the night before is a `config` event.

use std::path::Path;

use crate::{bail, Context};
use serde::{Deserialize, Serialize};

use super::check_night;
use crate::contracts::write_atomic;
use crate::error::Result;

/// The events file inside a history directory.
pub const EVENTS_FILE: &str = "events.toml";

/// What an event may be.
pub const EVENT_KINDS: [&str; 5] = ["wheel_change", "dressing", "repair", "config", "other"];

/// One deliberate change.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Event {
    /// The first night of the new baseline (YYYY-MM-DD).
    pub night: String,
    /// The machine it concerns; "" for the whole fleet.
    #[serde(default)]
    pub machine: String,
    /// One of [`EVENT_KINDS`].
    pub kind: String,
    #[serde(default)]
    pub note: String,
    /// Where the trend learnt of it: `events.toml`, `--event` or `history`
    /// (a config change between two nights). Not written to events.toml.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub source: String,
}

impl Event {
    fn check(&self) -> std::result::Result<(), String> {
        check_night(&self.night).map_err(|e| e.to_string())?;
        if !EVENT_KINDS.contains(&self.kind.as_str()) {
            return Err(format!(
                "kind `{}`: expected one of {}",
                self.kind,
                EVENT_KINDS.join(", ")
            ));
        }
        Ok(())
    }

    /// Does a fleet-wide series of an observable measured on `machines`, or
    /// a series of machine `machine`, start a new baseline here?
    pub fn resets(&self, machine: &str, machines: &[String]) -> bool {
        self.machine.is_empty()
            || self.machine == machine
            || (machine.is_empty() && machines.contains(&self.machine))
    }
}

/// `--event night=2026-11-03,machine=form-1,kind=dressing,note=new wheel`:
/// comma-separated key=value; `note` is last and takes the rest of the text
/// (commas included). `night` defaults to `default_night` (the night being
/// run, for `run --history`).
pub fn parse_event(spec: &str, default_night: Option<&str>) -> Result<Event> {
    let usage = "expected --event night=YYYY-MM-DD,machine=ID,kind=KIND[,note=TEXT] (machine omitted: the whole fleet)";
    let mut e = Event {
        night: default_night.unwrap_or("").to_string(),
        machine: String::new(),
        kind: String::new(),
        note: String::new(),
        source: "--event".into(),
    };
    let mut rest = spec.trim();
    while !rest.is_empty() {
        let Some((key, after)) = rest.split_once('=') else {
            bail!("--event `{spec}`: `{rest}` is not key=value; {usage}");
        };
        let key = key.trim();
        if key == "note" {
            e.note = after.trim().to_string();
            break;
        }
        let (value, next) = after.split_once(',').unwrap_or((after, ""));
        let value = value.trim().to_string();
        match key {
            "night" => e.night = value,
            "machine" => e.machine = value,
            "kind" => e.kind = value,
            other => bail!("--event `{spec}`: unknown key `{other}`; {usage}"),
        }
        rest = next.trim();
    }
    if e.night.is_empty() {
        bail!("--event `{spec}`: no night; {usage}");
    }
    e.check()
        .map_err(|m| crate::err!("--event `{spec}`: {m}; {usage}"))?;
    Ok(e)
}

#[derive(Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct EventsFile {
    #[serde(default)]
    event: Vec<Event>,
}

/// `<history>/events.toml`, checked; none when the file is absent. A bad
/// entry is an error naming the file and the entry (`[[event]]` number,
/// from 1).
pub fn read_events(history: &Path) -> Result<Vec<Event>> {
    let path = history.join(EVENTS_FILE);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let file: EventsFile = toml::from_str(&text).map_err(|e| {
        crate::InputError::new(
            &path,
            format!("not an events file ([[event]] night, machine, kind, note): {e}"),
        )
    })?;
    let mut out = Vec::with_capacity(file.event.len());
    for (i, mut e) in file.event.into_iter().enumerate() {
        e.check().map_err(|m| {
            crate::InputError::new(&path, format!("[[event]] number {}: {m}", i + 1)).row(i + 1)
        })?;
        e.source = EVENTS_FILE.into();
        out.push(e);
    }
    Ok(out)
}

/// Adds `events` to `<history>/events.toml` (atomically; an event already
/// there is not repeated).
pub fn append_events(history: &Path, events: &[Event]) -> Result<()> {
    if events.is_empty() {
        return Ok(());
    }
    let mut all = read_events(history)?;
    for e in events {
        let e = Event {
            source: String::new(),
            ..e.clone()
        };
        if !all.iter().any(|a| {
            Event {
                source: String::new(),
                ..a.clone()
            } == e
        }) {
            all.push(e);
        }
    }
    for e in &mut all {
        e.source.clear();
    }
    all.sort();
    let text = toml::to_string(&EventsFile { event: all })?;
    write_atomic(&history.join(EVENTS_FILE), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_parse_check_and_round_trip() {
        let e = parse_event(
            "machine=form-1,kind=dressing,note=new wheel, 400 mm",
            Some("2026-11-03"),
        )
        .unwrap();
        assert_eq!(
            (
                e.night.as_str(),
                e.machine.as_str(),
                e.kind.as_str(),
                e.note.as_str()
            ),
            ("2026-11-03", "form-1", "dressing", "new wheel, 400 mm")
        );
        assert!(parse_event("kind=dressing", None)
            .unwrap_err()
            .to_string()
            .contains("no night"));
        assert!(parse_event("night=2026-11-03,kind=nap", None)
            .unwrap_err()
            .to_string()
            .contains("wheel_change"));
        assert!(parse_event("night=2026-11-03,kind=repair,who=me", None).is_err());
        let d = tempfile::tempdir().unwrap();
        append_events(d.path(), &[e.clone(), e.clone()]).unwrap();
        let back = read_events(d.path()).unwrap();
        assert_eq!(back.len(), 1);
        assert_eq!(back[0].note, e.note);
        assert_eq!(back[0].source, EVENTS_FILE);
        std::fs::write(
            d.path().join(EVENTS_FILE),
            "[[event]]\nnight = \"2026-11-03\"\nkind = \"dressing\"\n[[event]]\nnight = \"3 Nov\"\nkind = \"repair\"\n",
        )
        .unwrap();
        let err = read_events(d.path()).unwrap_err().to_string();
        assert!(
            err.contains("events.toml") && err.contains("number 2"),
            "{err}"
        );
    }
}
