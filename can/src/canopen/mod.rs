//! CANopen for the replay: CiA 301 (NMT, SYNC producer, heartbeat consumer,
//! EMCY consumer, expedited SDO client) and CiA 402 (drive state machine,
//! cyclic synchronous position mode 8, RPDO target 0x607A, TPDO statusword
//! 0x6041 + actual position 0x6064). The object dictionary and PDO mappings
//! are the shipped EDS (configs/can/cia402_drive.eds), checked here against
//! what the code encodes; configs/can/cia402_pdo.dbc describes the same
//! frames for cantools.
//!
//! `protocol` is the wire format (frames, state machine, EDS); `master` the
//! state machine of the replay that drives it.

mod master;
pub mod pdo;
mod protocol;

pub use master::*;
pub use pdo::{AxisRef, Mapped, PdoMap};
pub use protocol::*;
