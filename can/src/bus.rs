//! The `CanBus` trait (docs/design.md §3: send/receive frames with
//! timestamps) and the frame type shared by every backend.
//!
//! Time is integer microseconds since the start of the replay, so the
//! virtual clock of the simulated and log backends is exact (a SYNC period
//! of 4 ms is 4000 µs, every cycle) and the candump `(sec.usec)` stamp
//! round-trips without rounding.

use crate::error::Result;

/// Linux `CAN_ERR_FLAG`: set in the id of an error frame (as candump prints it).
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Linux `CAN_ERR_BUSOFF`: the error-class bit of a bus-off error frame.
pub const CAN_ERR_BUSOFF: u32 = 0x0000_0040;

/// One classic CAN frame (11-bit id, 0–8 bytes) or an error frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    /// When the frame was put on (or seen on) the bus, µs since replay start.
    pub t_us: u64,
    /// 11-bit identifier; for an error frame the error-class bits.
    pub id: u32,
    pub len: u8,
    pub data: [u8; 8],
    /// An error frame reported by the controller (bus-off, …), not traffic.
    pub error: bool,
}

impl CanFrame {
    /// A data frame; `data` longer than 8 bytes is a programming error.
    pub fn new(t_us: u64, id: u32, data: &[u8]) -> CanFrame {
        assert!(
            data.len() <= 8,
            "a classic CAN frame carries at most 8 bytes"
        );
        assert!(id <= 0x7FF, "CANopen uses 11-bit identifiers");
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        CanFrame {
            t_us,
            id,
            len: data.len() as u8,
            data: d,
            error: false,
        }
    }
    /// An error frame with the given error-class bits (e.g. [`CAN_ERR_BUSOFF`]).
    pub fn error(t_us: u64, class: u32) -> CanFrame {
        CanFrame {
            t_us,
            id: class,
            len: 8,
            data: [0; 8],
            error: true,
        }
    }
    pub fn payload(&self) -> &[u8] {
        &self.data[..self.len as usize]
    }
    pub fn is_bus_off(&self) -> bool {
        self.error && self.id & CAN_ERR_BUSOFF != 0
    }
    /// Timestamp in seconds (for logs and records).
    pub fn t_s(&self) -> f64 {
        self.t_us as f64 * 1e-6
    }
}

/// Which way a frame went, seen from the master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dir {
    Tx,
    Rx,
}

/// A CAN bus as the replay master sees it. `send` puts a frame on the bus
/// now; `recv` returns frames already received (never blocks); `wait_until`
/// lets time pass (sleeps on hardware, advances the virtual clock in the
/// simulation). Implementations: `sim::SimBus`, `log_bus::LogBus`,
/// `socketcan_bus::SocketCanBus`.
pub trait CanBus {
    /// A short description for logs and run.toml (`sim`, `log:/tmp/x.log`, …).
    fn describe(&self) -> String;
    /// The bus clock, µs since the replay started.
    fn now_us(&self) -> u64;
    /// Put a frame on the bus (its `t_us` is overwritten with the send time).
    fn send(&mut self, frame: CanFrame) -> Result<()>;
    /// The next frame received up to now, if any.
    fn recv(&mut self) -> Result<Option<CanFrame>>;
    /// Let time pass until `t_us` (no-op if already past).
    fn wait_until(&mut self, t_us: u64) -> Result<()>;
    /// Flush and close whatever the backend writes (logs); called once at the end.
    fn finish(&mut self) -> Result<()> {
        Ok(())
    }
}
