//! PDO mappings (CiA 301 §7.4.2, objects 0x1400–0x1BFF): what one PDO
//! carries, how its payload packs (little-endian, bit by bit, in mapping
//! order), and which mapping the master needs for one drive axis. Shared
//! by the master, the simulated drive and `can decode`.

use crate::eds::{DeviceDescription, AXIS_OFFSET};

/// One mapping entry: object, sub-index and length in bits (the UNSIGNED32
/// `0xIIIISSLL` of 0x16xx / 0x1Axx).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Mapped {
    pub index: u16,
    pub sub: u8,
    pub bits: u8,
}

impl Mapped {
    pub fn new(index: u16, sub: u8, bits: u8) -> Mapped {
        Mapped { index, sub, bits }
    }
    pub fn raw(&self) -> u32 {
        (self.index as u32) << 16 | (self.sub as u32) << 8 | self.bits as u32
    }
    pub fn from_raw(v: u32) -> Mapped {
        Mapped::new((v >> 16) as u16, (v >> 8) as u8, v as u8)
    }
    /// A dummy entry (CiA 301: indices 0x0001–0x0007 pad a PDO).
    pub fn is_dummy(&self) -> bool {
        (1..=7).contains(&self.index)
    }
}

impl std::fmt::Display for Mapped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "0x{:04X}:{:02X} ({} bit{})",
            self.index,
            self.sub,
            self.bits,
            object_name(self.index)
                .map(|n| format!(", {n}"))
                .unwrap_or_default()
        )
    }
}

/// One PDO: its COB-ID (bit 31 set = not valid), transmission type and
/// mapped objects.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct PdoMap {
    pub cob_id: u32,
    pub transmission: u8,
    pub entries: Vec<Mapped>,
}

/// COB-ID bit 31: the PDO does not exist / is not valid.
pub const COB_INVALID: u32 = 1 << 31;

impl PdoMap {
    pub fn bits(&self) -> u32 {
        self.entries.iter().map(|e| e.bits as u32).sum()
    }
    pub fn id(&self) -> u32 {
        self.cob_id & 0x7FF
    }
    pub fn valid(&self) -> bool {
        self.cob_id & COB_INVALID == 0
    }
    /// The entry carrying `index` (sub 0), if mapped.
    pub fn find(&self, index: u16) -> Option<&Mapped> {
        self.entries.iter().find(|e| e.index == index && e.sub == 0)
    }
    /// Pack the values `value(index, sub)` gives into a payload.
    pub fn encode(&self, value: impl Fn(u16, u8) -> i64) -> Vec<u8> {
        let bits = self.bits().min(64);
        let mut acc: u128 = 0;
        let mut at = 0u32;
        for e in &self.entries {
            let v = if e.is_dummy() {
                0
            } else {
                value(e.index, e.sub)
            };
            let mask: u128 = if e.bits >= 64 {
                u64::MAX as u128
            } else {
                (1u128 << e.bits) - 1
            };
            acc |= ((v as u64 as u128) & mask) << at;
            at += e.bits as u32;
        }
        let n = bits.div_ceil(8) as usize;
        acc.to_le_bytes()[..n].to_vec()
    }
    /// Unpack a payload: each entry with its raw (unsigned) value; `None`
    /// when the payload is shorter than the mapping.
    pub fn decode(&self, payload: &[u8]) -> Option<Vec<(Mapped, u64)>> {
        if (payload.len() as u32) * 8 < self.bits() || payload.len() > 8 {
            return None;
        }
        let mut b = [0u8; 16];
        b[..payload.len()].copy_from_slice(payload);
        let acc = u128::from_le_bytes(b);
        let mut at = 0u32;
        let mut out = Vec::new();
        for e in &self.entries {
            let mask: u128 = if e.bits >= 64 {
                u64::MAX as u128
            } else {
                (1u128 << e.bits) - 1
            };
            out.push((*e, ((acc >> at) & mask) as u64));
            at += e.bits as u32;
        }
        Some(out)
    }
    /// The raw value of `index` (sub 0) in a payload.
    pub fn value_of(&self, payload: &[u8], index: u16) -> Option<u64> {
        self.decode(payload)?
            .into_iter()
            .find(|(e, _)| e.index == index && e.sub == 0)
            .map(|(_, v)| v)
    }
}

/// A raw value of `bits` bits as a signed number.
pub fn sign_extend(raw: u64, bits: u8) -> i64 {
    if bits == 0 || bits >= 64 {
        return raw as i64;
    }
    let shift = 64 - bits as u32;
    ((raw << shift) as i64) >> shift
}

/// Standard CiA 402 objects by name (first axis; further axes at +0x800),
/// and whether the standard type is signed.
const CIA402_NAMES: [(u16, &str, bool); 16] = [
    (0x603F, "error_code", false),
    (0x6040, "controlword", false),
    (0x6041, "statusword", false),
    (0x6060, "modes_of_operation", true),
    (0x6061, "modes_of_operation_display", true),
    (0x6062, "position_demand_value", true),
    (0x6064, "position_actual_value", true),
    (0x606C, "velocity_actual_value", true),
    (0x6071, "target_torque", true),
    (0x6077, "torque_actual_value", true),
    (0x607A, "target_position", true),
    (0x607F, "max_profile_velocity", false),
    (0x60B1, "velocity_offset", true),
    (0x60B2, "torque_offset", true),
    (0x60F4, "following_error_actual_value", true),
    (0x60FF, "target_velocity", true),
];

/// (axis 1-based, the first-axis index) of a CiA 402 object index.
pub fn split_axis(index: u16) -> (u8, u16) {
    if (0x6000..0xA000).contains(&index) {
        let k = (index - 0x6000) / AXIS_OFFSET;
        ((k + 1) as u8, index - k * AXIS_OFFSET)
    } else {
        (1, index)
    }
}

/// The standard name of a CiA 402 object (any axis: `_axis2` … appended).
pub fn object_name(index: u16) -> Option<String> {
    let (axis, base) = split_axis(index);
    let (_, name, _) = CIA402_NAMES.iter().find(|(i, _, _)| *i == base)?;
    Some(if axis > 1 {
        format!("{name}_axis{axis}")
    } else {
        name.to_string()
    })
}

/// Whether the standard type of a CiA 402 object is signed.
pub fn object_signed(index: u16) -> bool {
    let (_, base) = split_axis(index);
    CIA402_NAMES
        .iter()
        .find(|(i, _, _)| *i == base)
        .is_some_and(|(_, _, s)| *s)
}

/// One machine axis as the drive sees it: a node and which of its axes
/// (1 = the objects at 0x6000, 2 = at 0x6800, …). Axis k of a node uses
/// RPDOk and TPDOk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub struct AxisRef {
    pub node: u8,
    pub axis: u8,
}

impl AxisRef {
    pub fn new(node: u8, axis: u8) -> AxisRef {
        AxisRef { node, axis }
    }
    /// Offset of this axis' CiA 402 objects.
    pub fn offset(&self) -> u16 {
        AXIS_OFFSET * (self.axis as u16 - 1)
    }
    /// PDO number − 1 (0 for PDO1).
    pub fn pdo(&self) -> u16 {
        self.axis as u16 - 1
    }
    /// The pre-defined connection set's COB-IDs of RPDOk / TPDOk.
    pub fn rpdo_cob(&self) -> u32 {
        0x200 + 0x100 * self.pdo() as u32 + self.node as u32
    }
    pub fn tpdo_cob(&self) -> u32 {
        0x180 + 0x100 * self.pdo() as u32 + self.node as u32
    }
    /// Parse `NODE` or `NODE:AXIS` (AXIS 1–4: the pre-defined connection set
    /// has four PDOs each way).
    pub fn parse(s: &str) -> Result<AxisRef, String> {
        let (n, a) = match s.split_once(':') {
            Some((n, a)) => (n, a),
            None => (s, "1"),
        };
        let node: u8 = n
            .trim()
            .parse()
            .ok()
            .filter(|n| (1..=127).contains(n))
            .ok_or_else(|| format!("`{s}`: node `{n}` is not a CANopen node id 1–127"))?;
        let axis: u8 = a
            .trim()
            .parse()
            .ok()
            .filter(|a| (1..=4).contains(a))
            .ok_or_else(|| format!("`{s}`: drive axis `{a}` is not 1–4"))?;
        Ok(AxisRef { node, axis })
    }
}

impl std::fmt::Display for AxisRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.axis == 1 {
            write!(f, "node {}", self.node)
        } else {
            write!(f, "node {} axis {}", self.node, self.axis)
        }
    }
}

/// Transmission type: synchronous, every SYNC.
pub const SYNC_EVERY: u8 = 1;

/// Width in bits of an object as the description declares it (`default`
/// when not declared or of no fixed size).
pub fn declared_bits(d: &DeviceDescription, index: u16, default: u8) -> u8 {
    d.entries
        .iter()
        .find(|e| e.index == index && e.sub == 0)
        .and_then(|e| e.data_type)
        .map(|t| t.bits)
        .filter(|b| (1..=64).contains(b))
        .map(|b| b as u8)
        .unwrap_or(default)
}

/// The RPDO the master needs for an axis: controlword, target position.
pub fn needed_rpdo(a: AxisRef, d: &DeviceDescription) -> PdoMap {
    let o = a.offset();
    PdoMap {
        cob_id: a.rpdo_cob(),
        transmission: SYNC_EVERY,
        entries: vec![
            Mapped::new(0x6040 + o, 0, declared_bits(d, 0x6040 + o, 16)),
            Mapped::new(0x607A + o, 0, declared_bits(d, 0x607A + o, 32)),
        ],
    }
}

/// The TPDO the master needs for an axis: statusword (as wide as the file
/// declares it: some drives declare UNSIGNED32), position actual value.
pub fn needed_tpdo(a: AxisRef, d: &DeviceDescription) -> PdoMap {
    let o = a.offset();
    PdoMap {
        cob_id: a.tpdo_cob(),
        transmission: SYNC_EVERY,
        entries: vec![
            Mapped::new(0x6041 + o, 0, declared_bits(d, 0x6041 + o, 16)),
            Mapped::new(0x6064 + o, 0, declared_bits(d, 0x6064 + o, 32)),
        ],
    }
}

/// The default mapping of PDO `number` (1-based) the description declares.
pub fn described_map(d: &DeviceDescription, tx: bool, number: u16) -> Option<PdoMap> {
    let name = format!("{}{number}", if tx { "TPDO" } else { "RPDO" });
    let p = d.pdos.iter().find(|p| p.pdo == name)?;
    Some(PdoMap {
        cob_id: p.cob_id.and_then(|c| u32::try_from(c).ok())?,
        transmission: p
            .transmission_type
            .and_then(|t| u8::try_from(t).ok())
            .unwrap_or(SYNC_EVERY),
        entries: p
            .entries
            .iter()
            .map(|(i, s, b, _)| Mapped::new(*i, *s, *b))
            .collect(),
    })
}

/// The objects a description must declare for the master to drive `a`:
/// the CiA 402 objects of the axis, and its PDO communication and mapping
/// parameters. (index, sub, what it is).
pub fn required_objects(a: AxisRef) -> Vec<(u16, u8, String)> {
    let o = a.offset();
    let k = a.pdo();
    let mut v: Vec<(u16, u8, String)> = [
        (0x6040, "controlword"),
        (0x6041, "statusword"),
        (0x6060, "modes of operation"),
        (0x6061, "modes of operation display"),
        (0x6064, "position actual value"),
        (0x607A, "target position"),
    ]
    .iter()
    .map(|(i, n)| (i + o, 0, n.to_string()))
    .collect();
    let n = a.axis;
    for (base, what) in [
        (0x1400, format!("RPDO{n} communication parameter")),
        (0x1600, format!("RPDO{n} mapping parameter")),
        (0x1800, format!("TPDO{n} communication parameter")),
        (0x1A00, format!("TPDO{n} mapping parameter")),
    ] {
        let subs: &[u8] = if base == 0x1400 || base == 0x1800 {
            &[1, 2]
        } else {
            &[0, 1, 2]
        };
        for &s in subs {
            v.push((base + k, s, what.clone()));
        }
    }
    v
}

/// Check that a description holds everything the master needs for `a`;
/// the error names the file and the first missing object.
pub fn check_description(d: &DeviceDescription, a: AxisRef) -> crate::Result<()> {
    let read_only = |index: u16| {
        d.entries
            .iter()
            .any(|e| e.index == index && e.sub == 0 && (e.access == "ro" || e.access == "const"))
    };
    for (index, sub, what) in required_objects(a) {
        // A read-only mapping is not written: its entries need not be
        // declared (the drive's own mapping is read at start-up).
        if (0x1600..0x1800).contains(&index) | (0x1A00..0x1C00).contains(&index)
            && sub > 0
            && read_only(index)
        {
            continue;
        }
        let present = d.entries.iter().any(|e| e.index == index && e.sub == sub);
        if !present {
            return Err(crate::Error::EdsMissingObject {
                file: d.file.clone(),
                index,
                sub,
                what,
                node: a.node,
                drive_axis: a.axis,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_round_trips_odd_widths_and_signs() {
        let m = PdoMap {
            cob_id: 0x201,
            transmission: 1,
            entries: vec![
                Mapped::new(0x6040, 0, 16),
                Mapped::new(0x0005, 0, 8),
                Mapped::new(0x607A, 0, 32),
            ],
        };
        let p = m.encode(|i, _| if i == 0x6040 { 0x0F } else { -2 });
        assert_eq!(p, vec![0x0F, 0, 0, 0xFE, 0xFF, 0xFF, 0xFF]);
        let d = m.decode(&p).unwrap();
        assert_eq!(sign_extend(d[2].1, 32), -2);
        assert_eq!(d[0].1, 0x0F);
        assert!(m.decode(&p[..6]).is_none());
        assert_eq!(Mapped::from_raw(0x607A_0020), Mapped::new(0x607A, 0, 32));
        assert_eq!(Mapped::new(0x6041, 0, 16).raw(), 0x6041_0010);
    }

    #[test]
    fn axes_and_names() {
        let a = AxisRef::parse("3:2").unwrap();
        assert_eq!(
            (a.offset(), a.rpdo_cob(), a.tpdo_cob()),
            (0x800, 0x303, 0x283)
        );
        assert_eq!(
            object_name(0x687A).as_deref(),
            Some("target_position_axis2")
        );
        assert_eq!(object_name(0x6041).as_deref(), Some("statusword"));
        assert!(AxisRef::parse("0").is_err());
        assert!(AxisRef::parse("1:5").is_err());
    }
}
