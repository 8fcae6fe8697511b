//! The CANopen wire protocol the replay speaks: CiA 301 COB-IDs, NMT,
//! SYNC, heartbeat, EMCY and expedited SDO frames, the CiA 402 controlword /
//! statusword state machine and PDO layout, and the check of the shipped EDS
//! against them. No state, no bus: the [`super::Master`] drives these.

use crate::bus::CanFrame;
use crate::error::{Error, Result};

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

pub use crate::eds::DRIVE_EDS;

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
    let expect = |section: &'static str, value: &'static str| -> Result<()> {
        let got = sections
            .get(section)
            .and_then(|s| s.get("defaultvalue"))
            .map(|s| s.as_str());
        if got != Some(value) {
            return Err(Error::EdsMapping {
                section,
                got: got.map(str::to_string),
                expected: value,
            });
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
            return Err(Error::EdsNoObject { object: o });
        }
    }
    Ok(())
}

/// SDO abort codes (CiA 301 table 22), one table for the master's errors,
/// the simulated drive and `can decode`.
pub const ABORT_CODES: [(u32, &str); 31] = [
    (0x0503_0000, "toggle bit not alternated"),
    (0x0504_0000, "SDO protocol timed out"),
    (0x0504_0001, "command specifier not valid or unknown"),
    (0x0504_0002, "invalid block size"),
    (0x0504_0003, "invalid sequence number"),
    (0x0504_0004, "CRC error"),
    (0x0504_0005, "out of memory"),
    (0x0601_0000, "unsupported access to an object"),
    (0x0601_0001, "attempt to read a write only object"),
    (0x0601_0002, "attempt to write a read only object"),
    (0x0602_0000, "object does not exist in the object dictionary"),
    (0x0604_0041, "object cannot be mapped to the PDO"),
    (0x0604_0042, "number and length of the objects to be mapped would exceed the PDO length"),
    (0x0604_0043, "general parameter incompatibility"),
    (0x0604_0047, "general internal incompatibility in the device"),
    (0x0606_0000, "access failed due to a hardware error"),
    (0x0607_0010, "data type does not match, length of service parameter does not match"),
    (0x0607_0012, "data type does not match, length of service parameter too high"),
    (0x0607_0013, "data type does not match, length of service parameter too low"),
    (0x0609_0011, "sub-index does not exist"),
    (0x0609_0030, "invalid value for parameter (download only)"),
    (0x0609_0031, "value of parameter written too high"),
    (0x0609_0032, "value of parameter written too low"),
    (0x0609_0036, "maximum value is less than minimum value"),
    (0x060A_0023, "resource not available: SDO connection"),
    (0x0800_0000, "general error"),
    (0x0800_0020, "data cannot be transferred or stored to the application"),
    (0x0800_0021, "data cannot be transferred or stored to the application because of local control"),
    (0x0800_0022, "data cannot be transferred or stored to the application because of the present device state"),
    (0x0800_0023, "object dictionary dynamic generation fails or no object dictionary is present"),
    (0x0800_0024, "no data available"),
];

/// An SDO abort code by name.
pub fn abort_name(code: u32) -> &'static str {
    ABORT_CODES
        .iter()
        .find(|(c, _)| *c == code)
        .map(|(_, n)| *n)
        .unwrap_or("unknown abort code")
}

pub mod abort {
    pub const TOGGLE: u32 = 0x0503_0000;
    pub const TIMEOUT: u32 = 0x0504_0000;
    pub const COMMAND: u32 = 0x0504_0001;
    pub const READ_ONLY: u32 = 0x0601_0002;
    pub const NO_OBJECT: u32 = 0x0602_0000;
    pub const NOT_MAPPABLE: u32 = 0x0604_0041;
    pub const PDO_LENGTH: u32 = 0x0604_0042;
    pub const LENGTH: u32 = 0x0607_0010;
    pub const NO_SUB: u32 = 0x0609_0011;
    pub const DEVICE_STATE: u32 = 0x0800_0022;
}

/// What one SDO transfer delivered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoDone {
    Downloaded,
    Uploaded(Vec<u8>),
}

/// The next move of an SDO client after a response.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoStep {
    /// Send this request payload (the next segment).
    Send([u8; 8]),
    Done(SdoDone),
    /// The server aborted with this code.
    Aborted(u32),
    /// The response broke the protocol: the client aborts with this code
    /// (send [`sdo_abort_payload`]).
    Failed(u32),
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum ClientState {
    InitDownload {
        data: Vec<u8>,
    },
    InitUpload,
    /// Waiting for the confirmation of the segment ending at `sent`.
    DownloadSegment {
        data: Vec<u8>,
        sent: usize,
        toggle: u8,
    },
    UploadSegment {
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: u8,
    },
}

/// The client side of one SDO transfer, expedited (≤ 4 bytes) or segmented
/// (CiA 301 §7.2.4.3: initiate, then 7-byte segments with a toggle bit).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SdoTransfer {
    pub index: u16,
    pub sub: u8,
    state: ClientState,
}

fn sdo_head(cmd: u8, index: u16, sub: u8) -> [u8; 8] {
    let mut d = [0u8; 8];
    d[0] = cmd;
    d[1..3].copy_from_slice(&index.to_le_bytes());
    d[3] = sub;
    d
}

/// An abort transfer payload (either direction).
pub fn sdo_abort_payload(index: u16, sub: u8, code: u32) -> [u8; 8] {
    let mut d = sdo_head(0x80, index, sub);
    d[4..8].copy_from_slice(&code.to_le_bytes());
    d
}

impl SdoTransfer {
    /// Write `data`: expedited up to 4 bytes, segmented beyond.
    pub fn download(index: u16, sub: u8, data: Vec<u8>) -> (SdoTransfer, [u8; 8]) {
        let d = if (1..=4).contains(&data.len()) {
            let mut d = sdo_head(0x23 | (((4 - data.len()) as u8) << 2), index, sub);
            d[4..4 + data.len()].copy_from_slice(&data);
            d
        } else {
            // Segmented, size indicated.
            let mut d = sdo_head(0x21, index, sub);
            d[4..8].copy_from_slice(&(data.len() as u32).to_le_bytes());
            d
        };
        let t = SdoTransfer {
            index,
            sub,
            state: ClientState::InitDownload { data },
        };
        (t, d)
    }
    pub fn upload(index: u16, sub: u8) -> (SdoTransfer, [u8; 8]) {
        let t = SdoTransfer {
            index,
            sub,
            state: ClientState::InitUpload,
        };
        (t, sdo_head(0x40, index, sub))
    }

    /// Take the server's response payload.
    pub fn on_response(&mut self, d: &[u8]) -> SdoStep {
        if d.len() != 8 {
            return SdoStep::Failed(abort::COMMAND);
        }
        let cmd = d[0];
        if cmd & 0xE0 == 0x80 {
            return SdoStep::Aborted(u32::from_le_bytes([d[4], d[5], d[6], d[7]]));
        }
        let same_object = u16::from_le_bytes([d[1], d[2]]) == self.index && d[3] == self.sub;
        match &mut self.state {
            ClientState::InitDownload { data } => {
                if cmd & 0xE0 != 0x60 || !same_object {
                    return SdoStep::Failed(abort::COMMAND);
                }
                if data.len() <= 4 && !data.is_empty() {
                    return SdoStep::Done(SdoDone::Downloaded);
                }
                let data = std::mem::take(data);
                self.state = ClientState::DownloadSegment {
                    data,
                    sent: 0,
                    toggle: 0,
                };
                self.next_download_segment()
            }
            ClientState::DownloadSegment { data, sent, toggle } => {
                if cmd & 0xE0 != 0x20 {
                    return SdoStep::Failed(abort::COMMAND);
                }
                if (cmd >> 4) & 1 != *toggle {
                    return SdoStep::Failed(abort::TOGGLE);
                }
                *toggle ^= 1;
                if *sent >= data.len() {
                    return SdoStep::Done(SdoDone::Downloaded);
                }
                self.next_download_segment()
            }
            ClientState::InitUpload => {
                if cmd & 0xE0 != 0x40 || !same_object {
                    return SdoStep::Failed(abort::COMMAND);
                }
                if cmd & 0x02 != 0 {
                    // Expedited: the size, when indicated, in n.
                    let len = if cmd & 0x01 != 0 {
                        4 - ((cmd >> 2) & 0x03) as usize
                    } else {
                        4
                    };
                    return SdoStep::Done(SdoDone::Uploaded(d[4..4 + len].to_vec()));
                }
                let size = (cmd & 0x01 != 0)
                    .then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
                self.state = ClientState::UploadSegment {
                    buf: Vec::new(),
                    size,
                    toggle: 0,
                };
                SdoStep::Send(sdo_head(0x60, 0, 0))
            }
            ClientState::UploadSegment { buf, size, toggle } => {
                if cmd & 0xE0 != 0x00 {
                    return SdoStep::Failed(abort::COMMAND);
                }
                if (cmd >> 4) & 1 != *toggle {
                    return SdoStep::Failed(abort::TOGGLE);
                }
                let n = 7 - ((cmd >> 1) & 0x07) as usize;
                buf.extend_from_slice(&d[1..1 + n]);
                if size.is_some_and(|s| buf.len() > s) {
                    return SdoStep::Failed(abort::LENGTH);
                }
                if cmd & 0x01 != 0 {
                    if size.is_some_and(|s| buf.len() != s) {
                        return SdoStep::Failed(abort::LENGTH);
                    }
                    return SdoStep::Done(SdoDone::Uploaded(std::mem::take(buf)));
                }
                *toggle ^= 1;
                SdoStep::Send(sdo_head(0x60 | (*toggle << 4), 0, 0))
            }
        }
    }

    fn next_download_segment(&mut self) -> SdoStep {
        let ClientState::DownloadSegment { data, sent, toggle } = &mut self.state else {
            return SdoStep::Failed(abort::COMMAND);
        };
        let n = (data.len() - *sent).min(7);
        let last = *sent + n >= data.len();
        let mut d = [0u8; 8];
        d[0] = (*toggle << 4) | (((7 - n) as u8) << 1) | last as u8;
        d[1..1 + n].copy_from_slice(&data[*sent..*sent + n]);
        *sent += n;
        SdoStep::Send(d)
    }
}

/// What an SDO server must do with a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServerAction {
    /// Read this object, then call [`SdoServer::uploaded`].
    Read(u16, u8),
    /// Write this object, then call [`SdoServer::downloaded`].
    Write(u16, u8, Vec<u8>),
    /// Answer with this payload (a segment, or an abort).
    Reply([u8; 8]),
    /// Answer nothing (the client aborted).
    Nothing,
}

#[derive(Debug, Clone, Default, PartialEq, Eq)]
enum ServerState {
    #[default]
    Idle,
    Downloading {
        index: u16,
        sub: u8,
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: u8,
    },
    Uploading {
        data: Vec<u8>,
        sent: usize,
        toggle: u8,
    },
}

/// The server side of SDO (the drive's), expedited and segmented.
#[derive(Debug, Clone, Default)]
pub struct SdoServer {
    state: ServerState,
}

impl SdoServer {
    pub fn on_request(&mut self, d: &[u8]) -> ServerAction {
        if d.len() != 8 {
            return ServerAction::Reply(sdo_abort_payload(0, 0, abort::COMMAND));
        }
        let cmd = d[0];
        let index = u16::from_le_bytes([d[1], d[2]]);
        let sub = d[3];
        match (cmd >> 5, &mut self.state) {
            (4, _) => {
                // The client aborted: forget the transfer, answer nothing.
                self.state = ServerState::Idle;
                ServerAction::Nothing
            }
            (1, _) => {
                self.state = ServerState::Idle;
                if cmd & 0x02 != 0 {
                    let len = if cmd & 0x01 != 0 {
                        4 - ((cmd >> 2) & 0x03) as usize
                    } else {
                        4
                    };
                    ServerAction::Write(index, sub, d[4..4 + len].to_vec())
                } else {
                    let size = (cmd & 0x01 != 0)
                        .then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
                    self.state = ServerState::Downloading {
                        index,
                        sub,
                        buf: Vec::new(),
                        size,
                        toggle: 0,
                    };
                    ServerAction::Reply(sdo_head(0x60, index, sub))
                }
            }
            (
                0,
                ServerState::Downloading {
                    index,
                    sub,
                    buf,
                    size,
                    toggle,
                },
            ) => {
                let (index, sub) = (*index, *sub);
                if (cmd >> 4) & 1 != *toggle {
                    self.state = ServerState::Idle;
                    return ServerAction::Reply(sdo_abort_payload(index, sub, abort::TOGGLE));
                }
                let n = 7 - ((cmd >> 1) & 0x07) as usize;
                buf.extend_from_slice(&d[1..1 + n]);
                let reply = sdo_head(0x20 | (*toggle << 4), 0, 0);
                *toggle ^= 1;
                if cmd & 0x01 != 0 {
                    let data = std::mem::take(buf);
                    let bad = size.is_some_and(|s| s != data.len());
                    self.state = ServerState::Idle;
                    if bad {
                        return ServerAction::Reply(sdo_abort_payload(index, sub, abort::LENGTH));
                    }
                    // The last segment is confirmed once written (see downloaded).
                    self.state = ServerState::Downloading {
                        index,
                        sub,
                        buf: Vec::new(),
                        size: None,
                        toggle: 0xFF ^ (reply[0] >> 4 & 1),
                    };
                    return ServerAction::Write(index, sub, data);
                }
                ServerAction::Reply(reply)
            }
            (2, _) => {
                self.state = ServerState::Idle;
                ServerAction::Read(index, sub)
            }
            (3, ServerState::Uploading { data, sent, toggle }) => {
                if (cmd >> 4) & 1 != *toggle {
                    self.state = ServerState::Idle;
                    return ServerAction::Reply(sdo_abort_payload(0, 0, abort::TOGGLE));
                }
                let n = (data.len() - *sent).min(7);
                let last = *sent + n >= data.len();
                let mut r = [0u8; 8];
                r[0] = (*toggle << 4) | (((7 - n) as u8) << 1) | last as u8;
                r[1..1 + n].copy_from_slice(&data[*sent..*sent + n]);
                *sent += n;
                *toggle ^= 1;
                if last {
                    self.state = ServerState::Idle;
                }
                ServerAction::Reply(r)
            }
            _ => {
                self.state = ServerState::Idle;
                ServerAction::Reply(sdo_abort_payload(index, sub, abort::COMMAND))
            }
        }
    }

    /// The answer to a [`ServerAction::Read`].
    pub fn uploaded(&mut self, index: u16, sub: u8, r: Result<Vec<u8>, u32>) -> [u8; 8] {
        match r {
            Err(code) => sdo_abort_payload(index, sub, code),
            Ok(v) if (1..=4).contains(&v.len()) => {
                let mut d = sdo_head(0x43 | (((4 - v.len()) as u8) << 2), index, sub);
                d[4..4 + v.len()].copy_from_slice(&v);
                d
            }
            Ok(v) => {
                let mut d = sdo_head(0x41, index, sub);
                d[4..8].copy_from_slice(&(v.len() as u32).to_le_bytes());
                self.state = ServerState::Uploading {
                    data: v,
                    sent: 0,
                    toggle: 0,
                };
                d
            }
        }
    }

    /// The answer to a [`ServerAction::Write`].
    pub fn downloaded(&mut self, index: u16, sub: u8, r: Result<(), u32>) -> [u8; 8] {
        let segmented = std::mem::take(&mut self.state);
        match (r, segmented) {
            (Err(code), _) => sdo_abort_payload(index, sub, code),
            // The last download segment: confirm it with its toggle.
            (Ok(()), ServerState::Downloading { toggle, .. }) => {
                sdo_head(0x20 | ((toggle ^ 0xFF) << 4), 0, 0)
            }
            (Ok(()), _) => sdo_head(0x60, index, sub),
        }
    }
}
