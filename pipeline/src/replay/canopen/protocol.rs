//! The CANopen wire protocol the replay speaks: CiA 301 COB-IDs, NMT,
//! SYNC, heartbeat, EMCY and expedited SDO frames, the CiA 402 controlword /
//! statusword state machine and PDO layout, and the check of the shipped EDS
//! against them. No state, no bus: the [`super::Master`] drives these.

use crate::replay::bus::CanFrame;
use anyhow::{bail, Result};

pub const NMT_ID: u32 = 0x000;
pub const SYNC_ID: u32 = 0x080;
pub const EMCY_BASE: u32 = 0x080;
pub const TPDO1_BASE: u32 = 0x180;
pub const RPDO1_BASE: u32 = 0x200;
/// SDO server → client (responses).
pub const SDO_TX_BASE: u32 = 0x580;
/// SDO client → server (requests).
pub const SDO_RX_BASE: u32 = 0x600;
pub const HEARTBEAT_BASE: u32 = 0x700;

/// CiA 301 NMT commands (byte 0 of the NMT frame).
pub mod nmt {
    pub const START: u8 = 0x01;
    pub const STOP: u8 = 0x02;
    pub const PRE_OPERATIONAL: u8 = 0x80;
    pub const RESET_NODE: u8 = 0x81;
    pub const RESET_COMMUNICATION: u8 = 0x82;
    /// Heartbeat states (the heartbeat's single byte).
    pub const HB_BOOTUP: u8 = 0x00;
    pub const HB_STOPPED: u8 = 0x04;
    pub const HB_OPERATIONAL: u8 = 0x05;
    pub const HB_PRE_OPERATIONAL: u8 = 0x7F;
}

/// CiA 402 controlword commands (0x6040).
pub mod cw {
    pub const DISABLE_VOLTAGE: u16 = 0x0000;
    pub const QUICK_STOP: u16 = 0x0002;
    pub const SHUTDOWN: u16 = 0x0006;
    pub const SWITCH_ON: u16 = 0x0007;
    pub const DISABLE_OPERATION: u16 = 0x0007;
    pub const ENABLE_OPERATION: u16 = 0x000F;
    pub const FAULT_RESET: u16 = 0x0080;
}

/// Objects used (CiA 301 / CiA 402).
pub mod obj {
    pub const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
    pub const CONTROLWORD: u16 = 0x6040;
    pub const STATUSWORD: u16 = 0x6041;
    pub const MODES_OF_OPERATION: u16 = 0x6060;
    pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
    pub const POSITION_ACTUAL_VALUE: u16 = 0x6064;
    pub const TARGET_POSITION: u16 = 0x607A;
    /// Cyclic synchronous position mode (0x6060 value).
    pub const MODE_CSP: u8 = 8;
}

/// Statusword bit 13 in CSP: following error detected by the drive.
pub const SW_FOLLOWING_ERROR: u16 = 1 << 13;

/// CiA 402 drive states, decoded from the statusword per CiA 402 table 30.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriveState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

impl DriveState {
    pub fn from_statusword(sw: u16) -> DriveState {
        use DriveState::*;
        match (sw & 0x4F, sw & 0x6F) {
            (0x00, _) => NotReadyToSwitchOn,
            (0x40, _) => SwitchOnDisabled,
            (_, 0x21) => ReadyToSwitchOn,
            (_, 0x23) => SwitchedOn,
            (_, 0x27) => OperationEnabled,
            (_, 0x07) => QuickStopActive,
            (0x0F, _) => FaultReactionActive,
            (0x08, _) => Fault,
            _ => NotReadyToSwitchOn,
        }
    }
    /// The statusword bits a drive in this state reports (bit 9 remote set).
    pub fn statusword(self) -> u16 {
        use DriveState::*;
        0x0200
            | match self {
                NotReadyToSwitchOn => 0x00,
                SwitchOnDisabled => 0x40,
                ReadyToSwitchOn => 0x21,
                SwitchedOn => 0x23,
                OperationEnabled => 0x27,
                QuickStopActive => 0x07,
                FaultReactionActive => 0x0F,
                Fault => 0x08,
            }
    }
    /// The controlword that moves a drive one step towards Operation enabled.
    pub fn next_command(self) -> Option<u16> {
        use DriveState::*;
        match self {
            Fault => Some(cw::FAULT_RESET),
            SwitchOnDisabled => Some(cw::SHUTDOWN),
            ReadyToSwitchOn => Some(cw::SWITCH_ON),
            SwitchedOn => Some(cw::ENABLE_OPERATION),
            OperationEnabled => None,
            // Wait (the drive is booting or reacting to a fault).
            NotReadyToSwitchOn | FaultReactionActive => Some(cw::DISABLE_VOLTAGE),
            QuickStopActive => Some(cw::DISABLE_VOLTAGE),
        }
    }
}

/// RPDO1: controlword (0x6040, u16) + target position (0x607A, i32), little endian.
pub fn rpdo1(node: u8, controlword: u16, target: i32) -> CanFrame {
    let mut d = [0u8; 6];
    d[..2].copy_from_slice(&controlword.to_le_bytes());
    d[2..].copy_from_slice(&target.to_le_bytes());
    CanFrame::new(0, RPDO1_BASE + node as u32, &d)
}
/// TPDO1: statusword (0x6041, u16) + position actual value (0x6064, i32).
pub fn tpdo1(node: u8, statusword: u16, actual: i32) -> CanFrame {
    let mut d = [0u8; 6];
    d[..2].copy_from_slice(&statusword.to_le_bytes());
    d[2..].copy_from_slice(&actual.to_le_bytes());
    CanFrame::new(0, TPDO1_BASE + node as u32, &d)
}
/// (word, position) of a 6-byte PDO of the layout above.
pub fn decode_pdo(f: &CanFrame) -> Option<(u16, i32)> {
    let d = f.payload();
    (d.len() == 6).then(|| {
        (
            u16::from_le_bytes([d[0], d[1]]),
            i32::from_le_bytes([d[2], d[3], d[4], d[5]]),
        )
    })
}
pub fn nmt_frame(command: u8, node: u8) -> CanFrame {
    CanFrame::new(0, NMT_ID, &[command, node])
}
pub fn sync_frame() -> CanFrame {
    CanFrame::new(0, SYNC_ID, &[])
}
pub fn heartbeat(node: u8, state: u8) -> CanFrame {
    CanFrame::new(0, HEARTBEAT_BASE + node as u32, &[state])
}
pub fn emcy(node: u8, code: u16, register: u8) -> CanFrame {
    let c = code.to_le_bytes();
    CanFrame::new(
        0,
        EMCY_BASE + node as u32,
        &[c[0], c[1], register, 0, 0, 0, 0, 0],
    )
}

/// An expedited SDO request (CiA 301 §7.2.4.3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoRequest {
    /// Write 1, 2 or 4 bytes.
    Download {
        index: u16,
        sub: u8,
        data: Vec<u8>,
    },
    Upload {
        index: u16,
        sub: u8,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoResponse {
    Downloaded {
        index: u16,
        sub: u8,
    },
    Uploaded {
        index: u16,
        sub: u8,
        value: u32,
        len: u8,
    },
    Abort {
        index: u16,
        sub: u8,
        code: u32,
    },
}

impl SdoRequest {
    pub fn index_sub(&self) -> (u16, u8) {
        match self {
            SdoRequest::Download { index, sub, .. } | SdoRequest::Upload { index, sub } => {
                (*index, *sub)
            }
        }
    }
    pub fn frame(&self, node: u8) -> CanFrame {
        let mut d = [0u8; 8];
        let (index, sub) = self.index_sub();
        d[1..3].copy_from_slice(&index.to_le_bytes());
        d[3] = sub;
        match self {
            SdoRequest::Download { data, .. } => {
                assert!(
                    matches!(data.len(), 1..=4),
                    "expedited SDO carries 1–4 bytes"
                );
                // ccs=1, n = 4 − len, e=1, s=1.
                d[0] = 0x20 | (((4 - data.len()) as u8) << 2) | 0x03;
                d[4..4 + data.len()].copy_from_slice(data);
            }
            SdoRequest::Upload { .. } => d[0] = 0x40,
        }
        CanFrame::new(0, SDO_RX_BASE + node as u32, &d)
    }
    /// Parse a request frame (the server side, used by the simulated drive).
    pub fn parse(f: &CanFrame) -> Option<SdoRequest> {
        let d = f.payload();
        if d.len() != 8 {
            return None;
        }
        let index = u16::from_le_bytes([d[1], d[2]]);
        let sub = d[3];
        match d[0] & 0xE0 {
            0x20 if d[0] & 0x03 == 0x03 => {
                let len = 4 - ((d[0] >> 2) & 0x03) as usize;
                Some(SdoRequest::Download {
                    index,
                    sub,
                    data: d[4..4 + len].to_vec(),
                })
            }
            0x40 => Some(SdoRequest::Upload { index, sub }),
            _ => None,
        }
    }
}

impl SdoResponse {
    pub fn frame(&self, node: u8) -> CanFrame {
        let mut d = [0u8; 8];
        let (index, sub) = match self {
            SdoResponse::Downloaded { index, sub }
            | SdoResponse::Uploaded { index, sub, .. }
            | SdoResponse::Abort { index, sub, .. } => (*index, *sub),
        };
        d[1..3].copy_from_slice(&index.to_le_bytes());
        d[3] = sub;
        match self {
            SdoResponse::Downloaded { .. } => d[0] = 0x60,
            SdoResponse::Uploaded { value, len, .. } => {
                d[0] = 0x40 | ((4 - len) << 2) | 0x03;
                d[4..8].copy_from_slice(&value.to_le_bytes());
            }
            SdoResponse::Abort { code, .. } => {
                d[0] = 0x80;
                d[4..8].copy_from_slice(&code.to_le_bytes());
            }
        }
        CanFrame::new(0, SDO_TX_BASE + node as u32, &d)
    }
    pub fn parse(f: &CanFrame) -> Option<SdoResponse> {
        let d = f.payload();
        if d.len() != 8 {
            return None;
        }
        let index = u16::from_le_bytes([d[1], d[2]]);
        let sub = d[3];
        let word = u32::from_le_bytes([d[4], d[5], d[6], d[7]]);
        match d[0] & 0xE0 {
            0x60 => Some(SdoResponse::Downloaded { index, sub }),
            0x40 if d[0] & 0x03 == 0x03 => {
                let len = 4 - ((d[0] >> 2) & 0x03);
                let mask = if len == 4 {
                    u32::MAX
                } else {
                    (1u32 << (8 * len)) - 1
                };
                Some(SdoResponse::Uploaded {
                    index,
                    sub,
                    value: word & mask,
                    len,
                })
            }
            0x80 => Some(SdoResponse::Abort {
                index,
                sub,
                code: word,
            }),
            _ => None,
        }
    }
}

/// The shipped EDS of the drive profile.
pub const DRIVE_EDS: &str = include_str!("../../../configs/can/cia402_drive.eds");

/// Check that an EDS maps the PDOs exactly as this master encodes them:
/// RPDO1 = 0x6040 (16 bit) + 0x607A (32 bit) on COB-ID $NODEID+0x200,
/// TPDO1 = 0x6041 (16 bit) + 0x6064 (32 bit) on $NODEID+0x180, synchronous.
pub fn check_eds(text: &str) -> Result<()> {
    let mut sections: std::collections::BTreeMap<
        String,
        std::collections::BTreeMap<String, String>,
    > = Default::default();
    let mut cur = String::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            cur = s.to_ascii_lowercase();
            continue;
        }
        if let Some((k, v)) = line.split_once('=') {
            sections
                .entry(cur.clone())
                .or_default()
                .insert(k.trim().to_ascii_lowercase(), v.trim().to_ascii_lowercase());
        }
    }
    let expect = |section: &str, value: &str| -> Result<()> {
        let got = sections
            .get(section)
            .and_then(|s| s.get("defaultvalue"))
            .map(|s| s.as_str());
        if got != Some(value) {
            bail!(
                "EDS [{section}] DefaultValue is {got:?}, the replay master encodes {value}: \
                 fix configs/can/cia402_drive.eds or the master together"
            );
        }
        Ok(())
    };
    expect("1400sub1", "$nodeid+0x200")?;
    expect("1600sub0", "2")?;
    expect("1600sub1", "0x60400010")?;
    expect("1600sub2", "0x607a0020")?;
    expect("1800sub1", "$nodeid+0x180")?;
    expect("1800sub2", "1")?;
    expect("1a00sub0", "2")?;
    expect("1a00sub1", "0x60410010")?;
    expect("1a00sub2", "0x60640020")?;
    for o in ["6040", "6041", "6060", "6061", "6064", "607a", "1017"] {
        if !sections.contains_key(o) {
            bail!("EDS has no object [{o}] (the replay master uses it)");
        }
    }
    Ok(())
}
