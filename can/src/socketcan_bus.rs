//! The `socketcan:<iface>` backend: real hardware through Linux SocketCAN
//! (the `socketcan` crate). Time is the wall clock since the bus was opened;
//! `wait_until` sleeps. Error frames are enabled so a bus-off reaches the
//! master as a [`CanFrame`] with [`CAN_ERR_BUSOFF`] set.
//!
//! These machines' kernels have no AF_CAN (no vcan either), so this backend
//! is compiled and type-checked in CI but exercised only on hardware; the
//! replay logic it drives is tested through the `sim` and `log` backends.

use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use socketcan::{CanError, EmbeddedFrame, ErrorCause, Socket, SocketOptions, StandardId};

use super::bus::{CanBus, CanFrame, CAN_ERR_BUSOFF};

pub struct SocketCanBus {
    iface: String,
    socket: socketcan::CanSocket,
    start: Instant,
}

impl SocketCanBus {
    pub fn open(iface: &str) -> Result<SocketCanBus> {
        let failed = |message: String, source: std::io::Error| Error::Bus {
            target: format!("socketcan:{iface}"),
            message,
            source: Some(source),
        };
        let socket = socketcan::CanSocket::open(iface).map_err(|e| {
            failed(
                format!("cannot open SocketCAN interface `{iface}` (is it up? `ip link set {iface} up type can bitrate 1000000`)"),
                e,
            )
        })?;
        // Set up an open socket: the io error was the whole message.
        let setup = |error: std::io::Error| Error::IoAt {
            path: iface.into(),
            error,
        };
        socket.set_nonblocking(true).map_err(setup)?;
        socket.set_error_filter_accept_all().map_err(setup)?;
        Ok(SocketCanBus {
            iface: iface.to_string(),
            socket,
            start: Instant::now(),
        })
    }

    /// The bus failed: `message` as the CLI prints it, the cause if any.
    fn bus_error(&self, message: String, source: Option<std::io::Error>) -> Error {
        Error::Bus {
            target: format!("socketcan:{}", self.iface),
            message,
            source,
        }
    }
}

impl CanBus for SocketCanBus {
    fn describe(&self) -> String {
        format!("socketcan:{}", self.iface)
    }
    fn now_us(&self) -> u64 {
        self.start.elapsed().as_micros() as u64
    }
    fn send(&mut self, frame: CanFrame) -> Result<()> {
        let id = StandardId::new(frame.id as u16).ok_or_else(|| {
            self.bus_error(format!("id 0x{:X} is not an 11-bit id", frame.id), None)
        })?;
        let f = socketcan::CanFrame::new(id, frame.payload()).ok_or_else(|| {
            self.bus_error(
                format!("cannot build a CAN frame of {} bytes", frame.len),
                None,
            )
        })?;
        self.socket
            .write_frame(&f)
            .map_err(|e| self.bus_error(format!("cannot send on {}", self.iface), Some(e)))
    }
    fn recv(&mut self) -> Result<Option<CanFrame>> {
        match self.socket.read_frame() {
            Ok(socketcan::CanFrame::Data(f)) => {
                let id = match f.id() {
                    socketcan::Id::Standard(s) => s.as_raw() as u32,
                    // CANopen uses 11-bit ids only; skip anything else on the bus.
                    socketcan::Id::Extended(_) => return self.recv(),
                };
                Ok(Some(CanFrame::new(self.now_us(), id, f.data())))
            }
            Ok(socketcan::CanFrame::Remote(_)) => self.recv(),
            Ok(socketcan::CanFrame::Error(e)) => {
                let err: CanError = e.into_error();
                let bus_off = err.causes().any(|c| matches!(c, ErrorCause::BusOff));
                let class = if bus_off { CAN_ERR_BUSOFF } else { 0 };
                Ok(Some(CanFrame::error(self.now_us(), class)))
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(None),
            Err(e) => Err(self.bus_error(format!("cannot read from {}", self.iface), Some(e))),
        }
    }
    fn wait_until(&mut self, t_us: u64) -> Result<()> {
        let now = self.now_us();
        if t_us > now {
            std::thread::sleep(Duration::from_micros(t_us - now));
        }
        Ok(())
    }
}
