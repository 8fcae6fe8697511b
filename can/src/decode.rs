//! `sparkout can decode LOG`: a recorded bus log as CiA 301/402 events, so a
//! commissioning engineer can read what a real drive answered.
//!
//! Reads the candump formats (can-utils): the log-file format of
//! `candump -l`/`-L` (`(1690000000.123456) can0 183#3702`, RTR `123#R`,
//! extended and error-frame ids of 8 hex digits) and the screen format
//! (`can0  183   [2]  37 02`, with or without a `-ta`/`-td`/`-tz` timestamp
//! in parentheses in front; `remote request` for RTR). CAN FD frames
//! (`##`) are out of scope: counted, not decoded. Each frame becomes one
//! [`BusEvent`] by the pre-defined connection set (NMT, SYNC, EMCY,
//! PDO1–4, SDO, heartbeat); PDO1 is decoded through the mapping the replay
//! master uses (RPDO1 controlword + target position, TPDO1 statusword +
//! actual position), and statuswords are followed per node as CiA 402
//! state transitions. With a node's EDS/DCF (`--eds NODE=FILE`) every
//! RPDO/TPDO it declares is decoded into named objects through its
//! mapping; SDO writes to a PDO's COB-ID or mapping seen in the log (a
//! master configuring the drive) take over from the frame they are
//! confirmed on, with or without a file.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::canopen::pdo::{object_name, object_signed, sign_extend, Mapped, PdoMap, COB_INVALID};
use super::canopen::DriveState;
use super::eds::DeviceDescription;
use crate::error::InputError;

/// One mapped object's value in a PDO.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PdoValue {
    pub name: String,
    pub index: u16,
    pub subindex: u8,
    pub value: i64,
}

/// One PDO as the decoder currently knows it (CiA 301 parameters).
#[derive(Debug, Clone, Default)]
struct LivePdo {
    cob: u32,
    count: u8,
    slots: [u32; 8],
}

impl LivePdo {
    fn map(&self) -> PdoMap {
        PdoMap {
            cob_id: self.cob,
            transmission: 1,
            entries: self.slots[..self.count.min(8) as usize]
                .iter()
                .map(|&r| Mapped::from_raw(r))
                .collect(),
        }
    }
}

/// One frame as a log holds it.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedFrame {
    /// Seconds as the log gives them (absolute, delta or from the first
    /// frame, whichever the recorder wrote); `None` without a timestamp.
    pub t_s: Option<f64>,
    pub iface: String,
    pub id: u32,
    pub extended: bool,
    pub rtr: bool,
    pub error: bool,
    /// CAN FD: not decoded.
    pub fd: bool,
    pub data: Vec<u8>,
}

const CAN_ERR_FLAG: u32 = 0x2000_0000;

fn hex_bytes(s: &str) -> Result<Vec<u8>, String> {
    if !s.len().is_multiple_of(2) || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!("data `{s}` is not pairs of hex digits"));
    }
    if s.len() > 128 {
        return Err(format!("data `{s}` is longer than 64 bytes"));
    }
    Ok((0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).expect("checked hex"))
        .collect())
}

fn parse_id(id: &str) -> Result<(u32, bool, bool), String> {
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_hexdigit()) || id.len() > 8 {
        return Err(format!("id `{id}` is not 1–8 hex digits"));
    }
    let raw = u32::from_str_radix(id, 16).map_err(|_| format!("id `{id}` is not hex"))?;
    let extended = id.len() > 3;
    let error = extended && raw & CAN_ERR_FLAG != 0;
    let id = if error {
        raw & !CAN_ERR_FLAG
    } else {
        raw & 0x1FFF_FFFF
    };
    if !extended && id > 0x7FF {
        return Err(format!("id `{id:X}` is above 0x7FF for a standard id"));
    }
    Ok((id, extended, error))
}

fn parse_stamp(s: &str) -> Result<f64, String> {
    let inner = s
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or_else(|| format!("timestamp `{s}` must look like (sec.usec)"))?;
    inner
        .parse::<f64>()
        .ok()
        .filter(|t| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| format!("timestamp `{s}` is not a number of seconds"))
}

/// One line of a candump log, in either format; `None` for a blank line.
pub fn parse_any_line(line: &str) -> Result<Option<LoggedFrame>, String> {
    let line = line.trim();
    if line.is_empty() {
        return Ok(None);
    }
    let mut words: Vec<&str> = line.split_whitespace().collect();
    let t_s = if words[0].starts_with('(') {
        // `-ta` may print a date in front of a screen line: `(2026-11-27 …)`.
        let stamp = words.remove(0);
        Some(parse_stamp(stamp)?)
    } else {
        None
    };
    let iface = words
        .first()
        .ok_or("missing the interface name")?
        .to_string();
    let frame = words
        .get(1)
        .ok_or("missing the frame (ID#DATA or ID [n] bytes)")?;
    if let Some((id, data)) = frame.split_once('#') {
        // Log-file format.
        let (id, extended, error) = parse_id(id)?;
        let mut f = LoggedFrame {
            t_s,
            iface,
            id,
            extended,
            rtr: false,
            error,
            fd: false,
            data: Vec::new(),
        };
        if let Some(rest) = data.strip_prefix('#') {
            f.fd = true;
            f.data = hex_bytes(rest.get(1..).unwrap_or(""))?;
        } else if let Some(len) = data.strip_prefix('R') {
            f.rtr = true;
            if !len.is_empty() && len.parse::<u8>().ok().filter(|n| *n <= 8).is_none() {
                return Err(format!("remote frame length `{len}` is not 0–8"));
            }
        } else {
            f.data = hex_bytes(data)?;
            if f.data.len() > 8 {
                return Err(format!(
                    "`{frame}`: {} data bytes in a classic CAN frame (at most 8)",
                    f.data.len()
                ));
            }
        }
        return Ok(Some(f));
    }
    // Screen format: IFACE ID [LEN] BYTES… | remote request.
    let (id, extended, error) = parse_id(frame)?;
    let len_word = words.get(2).ok_or("missing the length `[n]`")?;
    let fd = len_word.starts_with("[[") || words.contains(&"##");
    let len: usize = len_word
        .trim_start_matches('[')
        .trim_end_matches(']')
        .parse()
        .map_err(|_| format!("length `{len_word}` must look like [n]"))?;
    let rest: Vec<&str> = words[3..].to_vec();
    let rtr = rest.first().is_some_and(|w| *w == "remote");
    let mut data = Vec::new();
    if !rtr {
        for w in rest.iter().take_while(|w| w.len() == 2) {
            data.extend(hex_bytes(w)?);
        }
        if data.len() != len {
            return Err(format!(
                "length [{len}] but {} data bytes follow",
                data.len()
            ));
        }
        if !fd && len > 8 {
            return Err(format!(
                "[{len}] data bytes in a classic CAN frame (at most 8)"
            ));
        }
    }
    Ok(Some(LoggedFrame {
        t_s,
        iface,
        id,
        extended,
        rtr,
        error,
        fd,
        data,
    }))
}

/// One decoded frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BusEvent {
    /// 1-based line of the log.
    pub line: usize,
    pub t_s: Option<f64>,
    pub cob_id: u32,
    /// The node the frame is from or for (None for NMT to all, SYNC).
    pub node: Option<u8>,
    /// nmt, sync, emcy, rpdo1…rpdo4, tpdo1…tpdo4, sdo_request, sdo_response,
    /// sdo_abort, bootup, heartbeat, error_frame, remote, fd, other.
    pub kind: String,
    /// Object index and sub-index (SDO).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub index: Option<u16>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub subindex: Option<u8>,
    /// A value the frame carries (SDO data, EMCY code, abort code, …).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub value: Option<i64>,
    /// A CiA 402 state the frame reports, and the transition from the
    /// node's previous one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub state: Option<String>,
    /// The event in words.
    pub text: String,
    /// A PDO's mapped objects by name (when its mapping is known).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub objects: Vec<PdoValue>,
}

/// What a whole log held.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Decoded {
    pub events: Vec<BusEvent>,
    pub frames: usize,
    pub error_frames: usize,
    pub fd_frames: usize,
}

/// SDO abort codes by name (CiA 301 table 22): the master's table.
pub use super::canopen::abort_name;

/// An EMCY error code in words (CiA 301 table 21, the families and the
/// communication codes).
pub fn emcy_name(code: u16) -> &'static str {
    match code {
        0x0000 => "error reset or no error",
        0x8110 => "CAN overrun (objects lost)",
        0x8120 => "CAN in error passive mode",
        0x8130 => "life guard error or heartbeat error",
        0x8140 => "recovered from bus off",
        0x8150 => "CAN-ID collision",
        0x8210 => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        0x8611 => "following error",
        _ => match code >> 12 {
            0x1 => "generic error",
            0x2 => "current",
            0x3 => "voltage",
            0x4 => "temperature",
            0x5 => "device hardware",
            0x6 => "device software",
            0x7 => "additional modules",
            0x8 => "monitoring",
            0x9 => "external error",
            0xF if code >> 8 == 0xFF => "device specific",
            _ => "unknown error code",
        },
    }
}

fn state_name(s: DriveState) -> &'static str {
    use DriveState::*;
    match s {
        NotReadyToSwitchOn => "not ready to switch on",
        SwitchOnDisabled => "switch on disabled",
        ReadyToSwitchOn => "ready to switch on",
        SwitchedOn => "switched on",
        OperationEnabled => "operation enabled",
        QuickStopActive => "quick stop active",
        FaultReactionActive => "fault reaction active",
        Fault => "fault",
    }
}

/// A controlword's command (CiA 402 table 28).
pub fn controlword_command(cw: u16) -> &'static str {
    if cw & 0x80 != 0 {
        "fault reset"
    } else if cw & 0x02 == 0 {
        "disable voltage"
    } else if cw & 0x06 == 0x02 {
        "quick stop"
    } else if cw & 0x0F == 0x06 {
        "shutdown"
    } else if cw & 0x0F == 0x07 {
        "switch on / disable operation"
    } else if cw & 0x0F == 0x0F {
        "enable operation"
    } else {
        "no command"
    }
}

fn le(bytes: &[u8]) -> i64 {
    bytes
        .iter()
        .rev()
        .fold(0i64, |acc, &b| (acc << 8) | b as i64)
}

fn le_signed(bytes: &[u8]) -> i64 {
    let n = bytes.len().min(8);
    if n == 0 {
        return 0;
    }
    let v = le(&bytes[..n]);
    let shift = 64 - 8 * n as u32;
    if shift == 0 {
        v
    } else {
        (v << shift) >> shift
    }
}

#[derive(Default)]
struct Decoder {
    /// Last CiA 402 state per node.
    states: BTreeMap<u8, DriveState>,
    /// The node's EDS/DCF (names and types of mapped objects).
    files: BTreeMap<u8, DeviceDescription>,
    /// PDO parameters per (node, transmit, PDO number − 1).
    pdos: BTreeMap<(u8, bool, u16), LivePdo>,
    /// The last expedited SDO write per node, applied once confirmed.
    pending: BTreeMap<u8, (u16, u8, u32)>,
}

impl Decoder {
    fn new(files: &BTreeMap<u8, DeviceDescription>) -> Decoder {
        let mut d = Decoder {
            files: files.clone(),
            ..Default::default()
        };
        for (node, f) in files {
            for p in &f.pdos {
                let (tx, k) = match (p.pdo.strip_prefix("TPDO"), p.pdo.strip_prefix("RPDO")) {
                    (Some(k), _) => (true, k),
                    (_, Some(k)) => (false, k),
                    _ => continue,
                };
                let Some(k) = k.parse::<u16>().ok().and_then(|k| k.checked_sub(1)) else {
                    continue;
                };
                let mut live = LivePdo {
                    cob: p
                        .cob_id
                        .and_then(|c| u32::try_from(c).ok())
                        .unwrap_or(COB_INVALID),
                    count: p.entries.len().min(8) as u8,
                    slots: [0; 8],
                };
                for (i, (index, sub, bits, _)) in p.entries.iter().take(8).enumerate() {
                    live.slots[i] = Mapped::new(*index, *sub, *bits).raw();
                }
                d.pdos.insert((*node, tx, k), live);
            }
        }
        d
    }

    /// A confirmed SDO write: PDO parameters change what later PDOs carry.
    fn apply_write(&mut self, node: u8, index: u16, sub: u8, v: u32) {
        let (tx, comm, base) = match index {
            0x1400..=0x15FF => (false, true, 0x1400),
            0x1600..=0x17FF => (false, false, 0x1600),
            0x1800..=0x19FF => (true, true, 0x1800),
            0x1A00..=0x1BFF => (true, false, 0x1A00),
            _ => return,
        };
        let k = index - base;
        let p = self.pdos.entry((node, tx, k)).or_insert_with(|| LivePdo {
            // The pre-defined connection set until told otherwise.
            cob: if k < 4 {
                (if tx { 0x180 } else { 0x200 }) + 0x100 * k as u32 + node as u32
            } else {
                COB_INVALID
            },
            ..Default::default()
        });
        match (comm, sub) {
            (true, 1) => p.cob = v,
            (false, 0) => p.count = (v as u8).min(8),
            (false, s @ 1..=8) => p.slots[s as usize - 1] = v,
            _ => {}
        }
    }

    /// The mapping a PDO frame is decoded through, if known.
    fn pdo_map(&self, node: u8, id: u32) -> Option<PdoMap> {
        self.pdos
            .iter()
            .filter(|((n, _, _), p)| {
                *n == node && p.cob & COB_INVALID == 0 && p.cob & 0x7FF == id && p.count > 0
            })
            .map(|(_, p)| p.map())
            .next()
    }

    /// Name and signedness of a mapped object: the file's type and name
    /// when it declares the object, else the CiA 402 standard.
    fn describe_object(&self, node: u8, m: &Mapped) -> (String, bool) {
        let entry = self.files.get(&node).and_then(|f| {
            f.entries
                .iter()
                .find(|e| e.index == m.index && e.sub == m.sub)
        });
        let signed = match entry.and_then(|e| e.data_type) {
            Some(t) => matches!(t.code, 0x02..=0x04 | 0x10 | 0x12..=0x15),
            None => object_signed(m.index),
        };
        let name = object_name(m.index)
            .filter(|_| m.sub == 0)
            .or_else(|| {
                entry.map(|e| {
                    e.name
                        .to_ascii_lowercase()
                        .split(|c: char| !c.is_ascii_alphanumeric())
                        .filter(|w| !w.is_empty())
                        .collect::<Vec<_>>()
                        .join("_")
                })
            })
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| format!("0x{:04X}:{:02X}", m.index, m.sub));
        (name, signed)
    }
}

impl Decoder {
    fn event(&mut self, line: usize, f: &LoggedFrame) -> BusEvent {
        let mut e = BusEvent {
            line,
            t_s: f.t_s,
            cob_id: f.id,
            node: None,
            kind: "other".into(),
            index: None,
            subindex: None,
            value: None,
            state: None,
            text: String::new(),
            objects: Vec::new(),
        };
        let d = &f.data;
        if f.error {
            e.kind = "error_frame".into();
            e.text = format!("error frame (class 0x{:X})", f.id);
            return e;
        }
        if f.fd {
            e.kind = "fd".into();
            e.text = "CAN FD frame (not decoded)".into();
            return e;
        }
        if f.extended {
            e.text = format!("extended id 0x{:08X}: not CANopen", f.id);
            return e;
        }
        let (function, node) = (f.id & 0x780, (f.id & 0x7F) as u8);
        let with_node = |e: &mut BusEvent| e.node = Some(node);
        if f.rtr {
            e.kind = "remote".into();
            with_node(&mut e);
            e.text = format!("remote request for 0x{:03X}", f.id);
            return e;
        }
        match (function, node) {
            (0x000, 0) => {
                e.kind = "nmt".into();
                let cmd = match d.first() {
                    Some(0x01) => "start",
                    Some(0x02) => "stop",
                    Some(0x80) => "enter pre-operational",
                    Some(0x81) => "reset node",
                    Some(0x82) => "reset communication",
                    _ => "unknown command",
                };
                let target = d.get(1).copied().unwrap_or(0);
                e.node = (target != 0).then_some(target);
                e.value = d.first().map(|&c| c as i64);
                e.text = format!(
                    "NMT {cmd} → {}",
                    if target == 0 {
                        "all nodes".to_string()
                    } else {
                        format!("node {target}")
                    }
                );
            }
            (0x080, 0) => {
                e.kind = "sync".into();
                e.text = match d.first() {
                    Some(c) => format!("SYNC (counter {c})"),
                    None => "SYNC".into(),
                };
            }
            (0x080, _) => {
                with_node(&mut e);
                e.kind = "emcy".into();
                let code = le(d.get(..2).unwrap_or(&[])) as u16;
                let register = d.get(2).copied().unwrap_or(0);
                e.value = Some(code as i64);
                e.index = Some(0x1001);
                e.text = format!(
                    "EMCY node {node}: 0x{code:04X} {} (error register 0x{register:02X})",
                    emcy_name(code)
                );
            }
            (0x180 | 0x280 | 0x380 | 0x480, _) | (0x200 | 0x300 | 0x400 | 0x500, _) => {
                with_node(&mut e);
                let tx = matches!(function, 0x180 | 0x280 | 0x380 | 0x480);
                // TPDOk at 0x080 + k·0x100, RPDOk at 0x100 + k·0x100.
                let k = if tx {
                    (function - 0x080) / 0x100
                } else {
                    (function - 0x100) / 0x100
                };
                e.kind = format!("{}{k}", if tx { "tpdo" } else { "rpdo" });
                e.text = format!(
                    "{} node {node}: {}",
                    e.kind.to_uppercase(),
                    d.iter()
                        .map(|b| format!("{b:02X}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                );
                if let Some(map) = self.pdo_map(node, f.id) {
                    self.mapped_pdo(&mut e, &map, node, tx, d);
                } else if k == 1 && d.len() >= 2 {
                    let word = le(&d[..2]) as u16;
                    if tx {
                        let s = DriveState::from_statusword(word);
                        let prev = self.states.insert(node, s);
                        e.index = Some(0x6041);
                        e.value = Some(word as i64);
                        let change = match prev {
                            Some(p) if p != s => format!("{} → {}", state_name(p), state_name(s)),
                            _ => state_name(s).to_string(),
                        };
                        e.state = Some(change.clone());
                        e.text = format!("TPDO1 node {node}: statusword 0x{word:04X} ({change})");
                        if d.len() >= 6 {
                            e.text += &format!(", position actual {}", le_signed(&d[2..6]));
                        }
                    } else {
                        e.index = Some(0x6040);
                        e.value = Some(word as i64);
                        e.text = format!(
                            "RPDO1 node {node}: controlword 0x{word:04X} ({})",
                            controlword_command(word)
                        );
                        if d.len() >= 6 {
                            e.text += &format!(", target position {}", le_signed(&d[2..6]));
                        }
                    }
                }
            }
            (0x580, _) | (0x600, _) => {
                with_node(&mut e);
                self.sdo(&mut e, function == 0x600, node, d);
            }
            (0x700, _) => {
                with_node(&mut e);
                let s = d.first().copied().unwrap_or(0xFF);
                e.value = Some(s as i64);
                if s == 0 {
                    e.kind = "bootup".into();
                    e.text = format!("boot-up of node {node}");
                } else {
                    e.kind = "heartbeat".into();
                    let st = match s & 0x7F {
                        0x04 => "stopped",
                        0x05 => "operational",
                        0x7F => "pre-operational",
                        _ => "unknown state",
                    };
                    e.text = format!("heartbeat node {node}: {st}");
                }
            }
            _ => {
                e.text = format!("0x{:03X}: not in the pre-defined connection set", f.id);
            }
        }
        e
    }

    /// A PDO through a known mapping: each object by name, the controlword's
    /// command and the statusword's state (followed per node).
    fn mapped_pdo(&mut self, e: &mut BusEvent, map: &PdoMap, node: u8, tx: bool, d: &[u8]) {
        let kind = e.kind.to_uppercase();
        let Some(values) = map.decode(d) else {
            e.text = format!(
                "{kind} node {node}: {} bytes, shorter than its mapping ({} bits)",
                d.len(),
                map.bits()
            );
            return;
        };
        let mut parts = Vec::new();
        for (m, raw) in values {
            if m.is_dummy() {
                continue;
            }
            let (name, signed) = self.describe_object(node, &m);
            let v = if signed {
                sign_extend(raw, m.bits)
            } else {
                raw as i64
            };
            let base = super::canopen::pdo::split_axis(m.index).1;
            let mut text = if signed {
                format!("{name} {v}")
            } else {
                format!("{name} 0x{v:04X}")
            };
            if base == 0x6040 && !tx {
                text += &format!(" ({})", controlword_command(v as u16));
                e.index.get_or_insert(m.index);
                e.value.get_or_insert(v);
            }
            if base == 0x6041 && tx {
                let s = DriveState::from_statusword(v as u16);
                let prev = self.states.insert(node, s);
                let change = match prev {
                    Some(p) if p != s => format!("{} → {}", state_name(p), state_name(s)),
                    _ => state_name(s).to_string(),
                };
                text += &format!(" ({change})");
                e.state = Some(change);
                e.index.get_or_insert(m.index);
                e.value.get_or_insert(v);
            }
            parts.push(text);
            e.objects.push(PdoValue {
                name,
                index: m.index,
                subindex: m.sub,
                value: v,
            });
        }
        e.text = format!("{kind} node {node}: {}", parts.join(", "));
    }

    fn sdo(&mut self, e: &mut BusEvent, request: bool, node: u8, d: &[u8]) {
        let dir = if request { "→" } else { "←" };
        let Some(&cmd) = d.first() else {
            e.kind = if request {
                "sdo_request"
            } else {
                "sdo_response"
            }
            .into();
            e.text = format!("SDO {dir} node {node}: empty frame");
            return;
        };
        let index = d.get(1..3).map(|b| le(b) as u16);
        let sub = d.get(3).copied();
        let obj = match (index, sub) {
            (Some(i), Some(s)) => format!("0x{i:04X}:{s:02X}"),
            _ => "?".into(),
        };
        let payload = d.get(4..8).unwrap_or(&[]);
        // Bytes of data in an expedited transfer (size indicated).
        let expedited_len = |cmd: u8| {
            if cmd & 0x02 != 0 && cmd & 0x01 != 0 {
                4 - ((cmd >> 2) & 0x03) as usize
            } else {
                4
            }
        };
        e.kind = if request {
            "sdo_request"
        } else {
            "sdo_response"
        }
        .into();
        let specifier = cmd >> 5;
        if specifier == 4 {
            let code = le(payload) as u32;
            e.kind = "sdo_abort".into();
            e.index = index;
            e.subindex = sub;
            e.value = Some(code as i64);
            e.text = format!(
                "SDO abort {dir} node {node} {obj}: 0x{code:08X} {}",
                abort_name(code)
            );
            return;
        }
        match (request, specifier) {
            // A write request and a read response carry the data.
            (true, 1) | (false, 2) => {
                e.index = index;
                e.subindex = sub;
                let verb = if request { "write" } else { "read" };
                if cmd & 0x02 != 0 {
                    let n = expedited_len(cmd).min(payload.len());
                    let v = le(&payload[..n]);
                    e.value = Some(v);
                    if let (true, Some(i), Some(s)) = (request, index, sub) {
                        self.pending.insert(node, (i, s, v as u32));
                    }
                    e.text = format!("SDO {verb} {dir} node {node} {obj} = {v} (0x{v:X})");
                    match index {
                        Some(0x6040) => {
                            e.text += &format!(" ({})", controlword_command(v as u16));
                        }
                        Some(0x6041) => {
                            let s = DriveState::from_statusword(v as u16);
                            e.state = Some(state_name(s).into());
                            e.text += &format!(" ({})", state_name(s));
                            self.states.insert(node, s);
                        }
                        _ => {}
                    }
                } else {
                    e.text = format!(
                        "SDO {verb} {dir} node {node} {obj}: segmented, {} bytes",
                        le(payload)
                    );
                }
            }
            (true, 2) => {
                e.index = index;
                e.subindex = sub;
                e.text = format!("SDO read {dir} node {node} {obj}");
            }
            (false, 3) => {
                e.index = index;
                e.subindex = sub;
                if let (Some((i, s, v)), Some(ri), Some(rs)) =
                    (self.pending.remove(&node), index, sub)
                {
                    if (i, s) == (ri, rs) {
                        self.apply_write(node, i, s, v);
                    }
                }
                e.text = format!("SDO write {dir} node {node} {obj}: done");
            }
            (_, 0) | (_, 3) | (false, 1) => {
                e.text = format!(
                    "SDO segment {dir} node {node}: {}",
                    d[1..]
                        .iter()
                        .map(|b| format!("{b:02X}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                );
            }
            _ => {
                e.text = format!("SDO {dir} node {node}: command 0x{cmd:02X} not understood");
            }
        }
    }
}

/// Decode a whole log. Errors name the file and the line (as the row).
pub fn decode_log(path: &Path) -> Result<Decoded, InputError> {
    decode_log_with(path, &BTreeMap::new())
}

/// Decode a whole log, PDOs through each node's EDS/DCF mapping.
pub fn decode_log_with(
    path: &Path,
    files: &BTreeMap<u8, DeviceDescription>,
) -> Result<Decoded, InputError> {
    use std::io::BufRead;
    let file = std::fs::File::open(path)
        .map_err(|e| InputError::new(path, format!("cannot open: {e}")))?;
    let mut out = Decoded::default();
    let mut dec = Decoder::new(files);
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line =
            line.map_err(|e| InputError::new(path, format!("cannot read: {e}")).row(i + 1))?;
        let f = match parse_any_line(&line) {
            Ok(Some(f)) => f,
            Ok(None) => continue,
            Err(m) => {
                return Err(InputError::new(
                    path,
                    format!("line {}: not a candump line ({m}); expected `(sec.usec) can0 183#3702` or `can0  183   [2]  37 02`", i + 1),
                )
                .row(i + 1))
            }
        };
        out.frames += 1;
        out.error_frames += f.error as usize;
        out.fd_frames += f.fd as usize;
        out.events.push(dec.event(i + 1, &f));
    }
    Ok(out)
}

/// The events as an Arrow table, one row per frame (for Parquet): the
/// mapped objects as `name=value` pairs joined by `; `.
pub fn events_batch(events: &[BusEvent]) -> arrow::record_batch::RecordBatch {
    use arrow::array::{ArrayRef, Float64Array, Int64Array, StringArray, UInt32Array, UInt64Array};
    use arrow::datatypes::{DataType, Field, Schema};
    use std::sync::Arc;
    let schema = Schema::new(vec![
        Field::new("line", DataType::UInt64, false),
        Field::new("t_s", DataType::Float64, true),
        Field::new("cob_id", DataType::UInt32, false),
        Field::new("node", DataType::UInt32, true),
        Field::new("kind", DataType::Utf8, false),
        Field::new("index", DataType::UInt32, true),
        Field::new("subindex", DataType::UInt32, true),
        Field::new("value", DataType::Int64, true),
        Field::new("state", DataType::Utf8, true),
        Field::new("objects", DataType::Utf8, true),
        Field::new("text", DataType::Utf8, false),
    ]);
    let cols: Vec<ArrayRef> = vec![
        Arc::new(UInt64Array::from_iter_values(
            events.iter().map(|e| e.line as u64),
        )),
        Arc::new(Float64Array::from_iter(events.iter().map(|e| e.t_s))),
        Arc::new(UInt32Array::from_iter_values(
            events.iter().map(|e| e.cob_id),
        )),
        Arc::new(UInt32Array::from_iter(
            events.iter().map(|e| e.node.map(u32::from)),
        )),
        Arc::new(StringArray::from_iter_values(
            events.iter().map(|e| e.kind.as_str()),
        )),
        Arc::new(UInt32Array::from_iter(
            events.iter().map(|e| e.index.map(u32::from)),
        )),
        Arc::new(UInt32Array::from_iter(
            events.iter().map(|e| e.subindex.map(u32::from)),
        )),
        Arc::new(Int64Array::from_iter(events.iter().map(|e| e.value))),
        Arc::new(StringArray::from_iter(
            events.iter().map(|e| e.state.as_deref()),
        )),
        Arc::new(StringArray::from_iter(events.iter().map(|e| {
            (!e.objects.is_empty()).then(|| {
                e.objects
                    .iter()
                    .map(|o| format!("{}={}", o.name, o.value))
                    .collect::<Vec<_>>()
                    .join("; ")
            })
        }))),
        Arc::new(StringArray::from_iter_values(
            events.iter().map(|e| e.text.as_str()),
        )),
    ];
    arrow::record_batch::RecordBatch::try_new(Arc::new(schema), cols)
        .expect("columns match the schema")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(line: &str) -> BusEvent {
        let f = parse_any_line(line).unwrap().unwrap();
        Decoder::default().event(1, &f)
    }

    #[test]
    fn both_formats_read_alike() {
        let a = parse_any_line("(1690000000.123456) can0 183#3702")
            .unwrap()
            .unwrap();
        let b = parse_any_line("  can0  183   [2]  37 02").unwrap().unwrap();
        let c = parse_any_line("(1690000000.123456)  can0  183   [2]  37 02")
            .unwrap()
            .unwrap();
        assert_eq!((a.id, &a.data), (b.id, &b.data));
        assert_eq!(a, c);
        assert_eq!(b.t_s, None);
        let r = parse_any_line("(0.000001) can0 701#R").unwrap().unwrap();
        assert!(r.rtr);
        let r = parse_any_line("can0  701   [0]  remote request")
            .unwrap()
            .unwrap();
        assert!(r.rtr);
        let e = parse_any_line("(1.000000) can0 20000004#0000000000000000")
            .unwrap()
            .unwrap();
        assert!(e.error);
        let fd = parse_any_line("(1.000000) can0 123##1AABB")
            .unwrap()
            .unwrap();
        assert!(fd.fd && fd.data == [0xAA, 0xBB]);
        for bad in [
            "(1.0) can0",
            "can0 183 [3] 37 02",
            "(x) can0 183#37",
            "(1.0) can0 183#3",
            "(1.0) can0 G83#37",
            "(1.0) can0 183#001122334455667788",
        ] {
            assert!(parse_any_line(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn events_of_a_cia402_start_up() {
        assert_eq!(one("can0 000 [2] 01 05").text, "NMT start → node 5");
        assert_eq!(one("can0 000 [2] 81 00").text, "NMT reset node → all nodes");
        assert_eq!(one("can0 705 [1] 00").kind, "bootup");
        assert_eq!(one("can0 705 [1] 05").text, "heartbeat node 5: operational");
        let r = one("can0 605 [8] 40 00 10 00 00 00 00 00");
        assert_eq!(r.text, "SDO read → node 5 0x1000:00");
        let r = one("can0 585 [8] 43 00 10 00 92 01 02 00");
        assert_eq!(r.value, Some(0x00020192));
        let w = one("can0 605 [8] 2B 40 60 00 06 00 00 00");
        assert!(
            w.text.contains("0x6040:00 = 6") && w.text.contains("shutdown"),
            "{}",
            w.text
        );
        let m = one("can0 605 [8] 2F 60 60 00 08 00 00 00");
        assert_eq!(m.value, Some(8));
        let a = one("can0 585 [8] 80 00 20 00 00 00 02 06");
        assert_eq!(a.kind, "sdo_abort");
        assert!(a.text.contains("object does not exist"), "{}", a.text);
        let e = one("can0 085 [8] 10 43 08 00 00 00 00 00");
        assert!(
            e.text.contains("0x4310 temperature") && e.text.contains("0x08"),
            "{}",
            e.text
        );
        let sync = one("can0 080 [0]");
        assert_eq!(sync.kind, "sync");
        // Statusword transitions are followed per node.
        let mut d = Decoder::default();
        let f = |l: &str| parse_any_line(l).unwrap().unwrap();
        let a = d.event(1, &f("can0 185 [2] 40 02"));
        assert_eq!(a.state.as_deref(), Some("switch on disabled"));
        let b = d.event(2, &f("can0 185 [6] 21 02 00 00 00 00"));
        assert_eq!(
            b.state.as_deref(),
            Some("switch on disabled → ready to switch on")
        );
        let c = d.event(3, &f("can0 205 [6] 0F 00 10 27 00 00"));
        assert!(c.text.contains("enable operation") && c.text.contains("target position 10000"));
    }
}
