//! A drive's EDS or DCF (CiA 306) read in full: the object dictionary with
//! data types, access and default values, identity, the CiA 402 objects of
//! every axis and the default PDO mappings — what `sparkout can describe`
//! lists, so a commissioning engineer sees what a vendor's file declares
//! before the replay talks to that drive.
//!
//! Vendor files differ in ways the standard allows, and each is read as
//! written: `$NODEID` arithmetic with or without spaces
//! (`$NODEID + 0x200`, `0x180+$NODEID`), decimal, `0x` hex and leading-zero
//! octal numbers, sub-indexed RECORDs and ARRAYs (`[1018sub1]`),
//! `CompactSubObj` arrays (their names and values in `[XXXXName]` and
//! `[XXXXValue]`), a DCF's `ParameterValue` over `DefaultValue`, and further
//! axes of a multi-axis drive at the CiA 402 offset (0x800 per axis). A
//! standard CiA 402 object declared with another width (0x6041 as
//! UNSIGNED32) is read with a warning; an unknown data type code, a
//! malformed line or a missing object the master needs is an error naming
//! the file and the line or object.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;

use crate::error::InputError;

/// A CiA 301 data type (the codes of CiA 306 table 1 that drives use).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DataType {
    pub code: u16,
    pub name: &'static str,
    /// Bits of a fixed-size type; 0 for strings and domains.
    pub bits: u16,
}

/// The shipped EDS of the drive profile (the simulated drive's and the
/// master's default).
pub const DRIVE_EDS: &str = include_str!("../configs/can/cia402_drive.eds");

const DATA_TYPES: [(u16, &str, u16); 25] = [
    (0x0001, "BOOLEAN", 1),
    (0x0002, "INTEGER8", 8),
    (0x0003, "INTEGER16", 16),
    (0x0004, "INTEGER32", 32),
    (0x0005, "UNSIGNED8", 8),
    (0x0006, "UNSIGNED16", 16),
    (0x0007, "UNSIGNED32", 32),
    (0x0008, "REAL32", 32),
    (0x0009, "VISIBLE_STRING", 0),
    (0x000A, "OCTET_STRING", 0),
    (0x000B, "UNICODE_STRING", 0),
    (0x000C, "TIME_OF_DAY", 48),
    (0x000D, "TIME_DIFFERENCE", 48),
    (0x000F, "DOMAIN", 0),
    (0x0010, "INTEGER24", 24),
    (0x0011, "REAL64", 64),
    (0x0012, "INTEGER40", 40),
    (0x0013, "INTEGER48", 48),
    (0x0014, "INTEGER56", 56),
    (0x0015, "INTEGER64", 64),
    (0x0016, "UNSIGNED24", 24),
    (0x0018, "UNSIGNED40", 40),
    (0x0019, "UNSIGNED48", 48),
    (0x001A, "UNSIGNED56", 56),
    (0x001B, "UNSIGNED64", 64),
];

/// Codes of complex, manufacturer- and profile-defined data types
/// (CiA 301: 0x0020–0x025F), which the file's own DEFTYPE/DEFSTRUCT objects
/// define: read as DOMAIN (opaque bytes) with a warning.
const DEFINED_TYPES: std::ops::RangeInclusive<u16> = 0x0020..=0x025F;

pub fn data_type(code: u16) -> Option<DataType> {
    DATA_TYPES
        .iter()
        .find(|t| t.0 == code)
        .map(|&(code, name, bits)| DataType { code, name, bits })
}

/// One object or sub-object.
#[derive(Debug, Clone, Serialize)]
pub struct Entry {
    pub index: u16,
    pub sub: u8,
    pub name: String,
    pub data_type: Option<DataType>,
    pub access: String,
    pub pdo_mapping: bool,
    /// The value as written (DCF `ParameterValue`, else `DefaultValue`).
    pub value_text: Option<String>,
    /// The value evaluated for the node (when it is a number).
    pub value: Option<i128>,
}

/// One PDO's default mapping.
#[derive(Debug, Clone, Serialize)]
pub struct PdoMapping {
    /// "RPDO1" … "TPDO4" (and beyond, for drives with more).
    pub pdo: String,
    pub cob_id: Option<i128>,
    pub transmission_type: Option<i128>,
    /// (index, sub, bits, name).
    pub entries: Vec<(u16, u8, u8, String)>,
}

/// A CiA 402 object of one axis as the file declares it.
#[derive(Debug, Clone, Serialize)]
pub struct AxisObject {
    pub axis: u8,
    pub index: u16,
    pub name: String,
    pub data_type: Option<DataType>,
    pub access: String,
}

/// A whole EDS or DCF.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceDescription {
    pub file: String,
    pub is_dcf: bool,
    /// The node id the values were evaluated for (a DCF's
    /// `[DeviceComissioning] NodeID`, or the caller's).
    pub node: u8,
    pub vendor_name: Option<String>,
    pub product_name: Option<String>,
    /// 0x1018 sub 1–4.
    pub identity: BTreeMap<String, i128>,
    pub entries: Vec<Entry>,
    pub axes: Vec<Vec<AxisObject>>,
    pub pdos: Vec<PdoMapping>,
    pub warnings: Vec<String>,
}

/// The CiA 402 objects the replay master needs, with their standard types.
pub const MASTER_OBJECTS: [(u16, &str, u16); 6] = [
    (0x6040, "controlword", 0x0006),
    (0x6041, "statusword", 0x0006),
    (0x6060, "modes of operation", 0x0002),
    (0x6061, "modes of operation display", 0x0002),
    (0x6064, "position actual value", 0x0004),
    (0x607A, "target position", 0x0004),
];

/// The CiA 402 offset of a further axis' objects.
pub const AXIS_OFFSET: u16 = 0x800;

/// A number as EDS files write them, with `$NODEID` evaluated for `node`:
/// sums and differences of terms, each decimal, `0x` hex, leading-zero
/// octal or `$NODEID`.
pub fn eval_value(text: &str, node: u8) -> Option<i128> {
    let s: String = text.chars().filter(|c| !c.is_whitespace()).collect();
    if s.is_empty() {
        return None;
    }
    let mut total: i128 = 0;
    let mut sign = 1i128;
    let mut term = String::new();
    let flush = |term: &mut String, sign: i128, total: &mut i128| -> Option<()> {
        if term.is_empty() {
            return None;
        }
        let t = term.to_ascii_lowercase();
        let v = if t == "$nodeid" {
            node as i128
        } else if let Some(h) = t.strip_prefix("0x") {
            i128::from_str_radix(h, 16).ok()?
        } else if t.len() > 1 && t.starts_with('0') {
            i128::from_str_radix(&t[1..], 8).ok()?
        } else {
            t.parse::<i128>().ok()?
        };
        *total += sign * v;
        term.clear();
        Some(())
    };
    for (i, c) in s.chars().enumerate() {
        if (c == '+' || c == '-') && i > 0 {
            flush(&mut term, sign, &mut total)?;
            sign = if c == '+' { 1 } else { -1 };
        } else if c == '-' && i == 0 {
            sign = -1;
        } else {
            term.push(c);
        }
    }
    flush(&mut term, sign, &mut total)?;
    Some(total)
}

/// INI sections (lower-case names) with their keys (lower-case) and values,
/// and the line each key was on.
type Sections = BTreeMap<String, BTreeMap<String, (String, usize)>>;

fn parse_ini(path: &str, text: &str) -> Result<Sections, InputError> {
    let mut out: Sections = BTreeMap::new();
    let mut cur: Option<String> = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with(';') || line.starts_with('#') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[') {
            let name = s.strip_suffix(']').ok_or_else(|| {
                InputError::new(
                    path,
                    format!("line {}: a section header must end with `]`", i + 1),
                )
                .row(i + 1)
            })?;
            let name = name.trim().to_ascii_lowercase();
            out.entry(name.clone()).or_default();
            cur = Some(name);
            continue;
        }
        let Some((k, v)) = line.split_once('=') else {
            return Err(InputError::new(
                path,
                format!(
                    "line {}: expected `Key=Value`, `[Section]` or a `;` comment, found `{line}`",
                    i + 1
                ),
            )
            .row(i + 1));
        };
        let Some(sec) = &cur else {
            return Err(InputError::new(
                path,
                format!("line {}: `{}` before any [section]", i + 1, k.trim()),
            )
            .row(i + 1));
        };
        out.get_mut(sec)
            .expect("entered")
            .insert(k.trim().to_ascii_lowercase(), (v.trim().to_string(), i + 1));
    }
    Ok(out)
}

fn parse_index(s: &str) -> Option<u16> {
    (s.len() == 4)
        .then(|| u16::from_str_radix(s, 16).ok())
        .flatten()
}

impl DeviceDescription {
    /// Read an EDS or DCF; `node` evaluates `$NODEID` unless the file is a
    /// DCF that names its node.
    pub fn load(path: &Path, node: u8) -> Result<DeviceDescription, InputError> {
        let text =
            std::fs::read(path).map_err(|e| InputError::new(path, format!("cannot read: {e}")))?;
        Self::parse(
            &path.display().to_string(),
            &String::from_utf8_lossy(&text),
            node,
        )
    }

    pub fn parse(file: &str, text: &str, node: u8) -> Result<DeviceDescription, InputError> {
        let secs = parse_ini(file, text)?;
        let get =
            |sec: &str, key: &str| secs.get(sec).and_then(|s| s.get(key)).map(|v| v.0.clone());
        let is_dcf = secs.contains_key("devicecomissioning")
            || secs.values().any(|s| s.contains_key("parametervalue"));
        let node = get("devicecomissioning", "nodeid")
            .and_then(|v| eval_value(&v, 0))
            .and_then(|v| u8::try_from(v).ok())
            .filter(|n| (1..=127).contains(n))
            .unwrap_or(node);
        let mut warnings = Vec::new();
        let defined_types = std::cell::RefCell::new(Vec::new());
        let mut entries = Vec::new();
        let err = |sec: &str, key: &str, msg: String| {
            let line = secs
                .get(sec)
                .and_then(|s| s.get(key))
                .map(|v| v.1)
                .unwrap_or(0);
            InputError::new(file, format!("line {line}: [{sec}] {msg}"))
                .column(format!("{sec}.{key}"))
                .row(line)
        };
        let dtype = |sec: &str| -> Result<Option<DataType>, InputError> {
            let Some(v) = get(sec, "datatype") else {
                return Ok(None);
            };
            let code = eval_value(&v, node)
                .and_then(|c| u16::try_from(c).ok())
                .ok_or_else(|| err(sec, "datatype", format!("DataType `{v}` is not a number")))?;
            if let Some(t) = data_type(code) {
                return Ok(Some(t));
            }
            if DEFINED_TYPES.contains(&code) {
                defined_types.borrow_mut().push(format!(
                    "[{sec}] has the complex or profile-defined data type 0x{code:04X}: read as DOMAIN (opaque bytes)"
                ));
                return Ok(data_type(0x000F));
            }
            Err(err(
                sec,
                "datatype",
                format!("unknown data type code 0x{code:04X} (CiA 301: 0x0001 BOOLEAN … 0x001B UNSIGNED64 standard, 0x0020–0x025F complex and profile-defined)"),
            ))
        };
        let entry = |sec: &str, index: u16, sub: u8| -> Result<Entry, InputError> {
            let value_text = get(sec, "parametervalue").or_else(|| get(sec, "defaultvalue"));
            Ok(Entry {
                index,
                sub,
                name: get(sec, "parametername").unwrap_or_default(),
                data_type: dtype(sec)?,
                access: get(sec, "accesstype")
                    .unwrap_or_default()
                    .to_ascii_lowercase(),
                pdo_mapping: get(sec, "pdomapping").is_some_and(|v| v.trim() == "1"),
                value: value_text.as_deref().and_then(|t| eval_value(t, node)),
                value_text,
            })
        };
        for sec in secs.keys() {
            let Some(index) = parse_index(sec) else {
                continue;
            };
            let object_type = get(sec, "objecttype")
                .and_then(|v| eval_value(&v, node))
                .unwrap_or(0x7);
            let compact = get(sec, "compactsubobj")
                .and_then(|v| eval_value(&v, node))
                .unwrap_or(0);
            // VAR, and DEFTYPE (a data type's size as a variable).
            if object_type == 0x7 || object_type == 0x5 {
                entries.push(entry(sec, index, 0)?);
            } else if compact > 0 {
                // CompactSubObj: sub 0 is the count; subs 1..n share the
                // object's type and access; names and values in
                // [XXXXName] / [XXXXValue].
                let n = u8::try_from(compact).map_err(|_| {
                    err(
                        sec,
                        "compactsubobj",
                        format!("CompactSubObj {compact} is above 254"),
                    )
                })?;
                let base = entry(sec, index, 0)?;
                let names = format!("{sec}name");
                let values = format!("{sec}value");
                entries.push(Entry {
                    sub: 0,
                    name: format!("{} (number of entries)", base.name),
                    data_type: data_type(0x0005),
                    access: "ro".into(),
                    pdo_mapping: false,
                    value_text: Some(n.to_string()),
                    value: Some(n as i128),
                    ..base.clone()
                });
                for s in 1..=n {
                    let key = s.to_string();
                    // [XXXXValue] holds a configured device's values: a
                    // DCF's, like ParameterValue.
                    let value_text = get(&values, &key)
                        .filter(|_| is_dcf)
                        .or_else(|| base.value_text.clone());
                    entries.push(Entry {
                        sub: s,
                        name: get(&names, &key).unwrap_or_else(|| format!("{}{s}", base.name)),
                        value: value_text.as_deref().and_then(|t| eval_value(t, node)),
                        value_text,
                        ..base.clone()
                    });
                }
            }
        }
        for sec in secs.keys() {
            let Some((idx, sub)) = sec.split_once("sub") else {
                continue;
            };
            let (Some(index), Some(sub)) = (parse_index(idx), u8::from_str_radix(sub, 16).ok())
            else {
                continue;
            };
            entries.push(entry(sec, index, sub)?);
        }
        entries.sort_by_key(|e| (e.index, e.sub));
        let find = |index: u16, sub: u8| entries.iter().find(|e| e.index == index && e.sub == sub);
        // Identity.
        let mut identity = BTreeMap::new();
        for (sub, name) in [
            (1, "vendor_id"),
            (2, "product_code"),
            (3, "revision"),
            (4, "serial"),
        ] {
            if let Some(v) = find(0x1018, sub).and_then(|e| e.value) {
                identity.insert(name.to_string(), v);
            }
        }
        // CiA 402 objects per axis.
        let mut axes = Vec::new();
        for axis in 0..8u8 {
            let offset = AXIS_OFFSET * axis as u16;
            let objects: Vec<AxisObject> = MASTER_OBJECTS
                .iter()
                .filter_map(|&(index, _, want)| {
                    let e = find(index + offset, 0)?;
                    if let Some(t) = e.data_type.filter(|t| t.code != want) {
                        warnings.push(format!(
                            "axis {}: 0x{:04X} {} is declared {} (CiA 402: {}); read as declared",
                            axis + 1,
                            index + offset,
                            e.name,
                            t.name,
                            data_type(want).map(|t| t.name).unwrap_or("?")
                        ));
                    }
                    Some(AxisObject {
                        axis: axis + 1,
                        index: index + offset,
                        name: e.name.clone(),
                        data_type: e.data_type,
                        access: e.access.clone(),
                    })
                })
                .collect();
            if objects.is_empty() {
                if axis == 0 {
                    axes.push(objects);
                    continue;
                }
                break;
            }
            axes.push(objects);
        }
        warnings.extend(defined_types.take());
        // Default PDO mappings.
        let mut pdos = Vec::new();
        for (kind, comm, map) in [("RPDO", 0x1400u16, 0x1600u16), ("TPDO", 0x1800, 0x1A00)] {
            for k in 0..512u16 {
                let has_comm = find(comm + k, 1).is_some();
                let count = find(map + k, 0).and_then(|e| e.value);
                if !has_comm && count.is_none() {
                    continue;
                }
                let mut mapped = Vec::new();
                for s in 1..=count.unwrap_or(0).clamp(0, 64) as u8 {
                    let Some(v) = find(map + k, s).and_then(|e| e.value) else {
                        continue;
                    };
                    let (index, sub, bits) = ((v >> 16) as u16, (v >> 8) as u8, v as u8);
                    let name = find(index, sub)
                        .or_else(|| find(index, 0))
                        .map(|e| e.name.clone())
                        .unwrap_or_else(|| "(not in this file)".into());
                    mapped.push((index, sub, bits, name));
                }
                pdos.push(PdoMapping {
                    pdo: format!("{kind}{}", k + 1),
                    cob_id: find(comm + k, 1).and_then(|e| e.value),
                    transmission_type: find(comm + k, 2).and_then(|e| e.value),
                    entries: mapped,
                });
            }
        }
        let d = DeviceDescription {
            file: file.to_string(),
            is_dcf,
            node,
            vendor_name: get("deviceinfo", "vendorname"),
            product_name: get("deviceinfo", "productname"),
            identity,
            entries,
            axes,
            pdos,
            warnings,
        };
        // Every object the master needs, on the first axis.
        for (index, name, _) in MASTER_OBJECTS {
            if find_in(&d.entries, index, 0).is_none() {
                return Err(InputError::new(
                    file,
                    format!(
                        "no object 0x{index:04X} ({name}): the replay master needs it on every axis it drives (CiA 402)"
                    ),
                )
                .column(format!("{index:04X}")));
            }
        }
        Ok(d)
    }

    /// A readable listing (what `sparkout can describe` prints).
    pub fn describe(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} ({}; values for node {})",
            self.file,
            if self.is_dcf { "DCF" } else { "EDS" },
            self.node
        );
        let _ = writeln!(
            s,
            "device: {} — {}",
            self.vendor_name.as_deref().unwrap_or("(no VendorName)"),
            self.product_name.as_deref().unwrap_or("(no ProductName)")
        );
        for (k, v) in &self.identity {
            let _ = writeln!(s, "  identity {k}: 0x{v:08X}");
        }
        for (i, axis) in self.axes.iter().enumerate() {
            let _ = writeln!(s, "CiA 402 axis {} ({} objects):", i + 1, axis.len());
            for o in axis {
                let _ = writeln!(
                    s,
                    "  0x{:04X} {:<32} {:<12} {}",
                    o.index,
                    o.name,
                    o.data_type.map(|t| t.name).unwrap_or("?"),
                    o.access
                );
            }
        }
        for p in &self.pdos {
            let cob = p
                .cob_id
                .map(|c| {
                    format!(
                        "COB-ID 0x{c:X}{}",
                        if c & (1 << 31) != 0 { " (invalid)" } else { "" }
                    )
                })
                .unwrap_or_else(|| "no COB-ID".into());
            let tt = p
                .transmission_type
                .map(|t| format!(", transmission type {t}"))
                .unwrap_or_default();
            let _ = writeln!(s, "{} {cob}{tt}: {} mapped", p.pdo, p.entries.len());
            for (index, sub, bits, name) in &p.entries {
                let _ = writeln!(s, "  0x{index:04X}:{sub:02X} {bits} bit  {name}");
            }
        }
        for w in &self.warnings {
            let _ = writeln!(s, "warning: {w}");
        }
        s
    }
}

fn find_in(entries: &[Entry], index: u16, sub: u8) -> Option<&Entry> {
    entries.iter().find(|e| e.index == index && e.sub == sub)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_as_vendors_write_them() {
        assert_eq!(eval_value("$NODEID+0x200", 5), Some(0x205));
        assert_eq!(eval_value("$NODEID + 0x200", 5), Some(0x205));
        assert_eq!(eval_value("0x180 + $NODEID", 3), Some(0x183));
        assert_eq!(eval_value("010", 1), Some(8));
        assert_eq!(eval_value("0", 1), Some(0));
        assert_eq!(eval_value("-5", 1), Some(-5));
        assert_eq!(eval_value("0x80000000", 1), Some(0x8000_0000));
        assert_eq!(eval_value("abc", 1), None);
        assert_eq!(eval_value("", 1), None);
    }

    #[test]
    fn the_shipped_eds_describes_itself() {
        let d = DeviceDescription::parse("drive.eds", super::DRIVE_EDS, 2).unwrap();
        assert_eq!(d.axes[0].len(), MASTER_OBJECTS.len());
        let r = d.pdos.iter().find(|p| p.pdo == "RPDO1").unwrap();
        assert_eq!(r.cob_id, Some(0x202));
        assert_eq!(r.entries.len(), 2);
        assert_eq!(r.entries[0].0, 0x6040);
    }
}
