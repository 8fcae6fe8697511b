//! The `log:<file>` backend: every frame on the bus, both directions, in the
//! candump -l format `(sec.usec) iface ID#DATA` that can-utils (`canplayer`,
//! `log2asc`) and python-can's `CanutilsLogReader` read; and the reader that
//! turns such a log back into frames (a replay source, the interop check).
//!
//! A log has no drives on the other end, so `LogBus` wraps another bus (the
//! simulated drives) and records its traffic: the file is what a `candump -l`
//! on the real bus would have shown. It is written to a temporary name and
//! renamed into place by `finish` (docs/formats.md §8: never a partial file
//! under a final name).

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::bus::{CanBus, CanFrame, CAN_ERR_FLAG};
use crate::error::{Error, InputError, Result};

/// Interface name written into the log (candump needs one; replay has one bus).
pub const LOG_IFACE: &str = "can0";

/// One candump -l line, without the newline.
pub fn format_line(f: &CanFrame, iface: &str) -> String {
    let mut s = format!(
        "({:010}.{:06}) {iface} ",
        f.t_us / 1_000_000,
        f.t_us % 1_000_000
    );
    if f.error {
        s.push_str(&format!("{:08X}#", f.id | CAN_ERR_FLAG));
    } else {
        s.push_str(&format!("{:03X}#", f.id));
    }
    for b in f.payload() {
        s.push_str(&format!("{b:02X}"));
    }
    s
}

/// Parse one candump -l line; `None` for blank lines. Errors say what is wrong.
pub fn parse_line(line: &str) -> std::result::Result<Option<CanFrame>, String> {
    let line = line.trim();
    if line.is_empty() {
        return Ok(None);
    }
    let mut parts = line.split_whitespace();
    let stamp = parts.next().unwrap_or_default();
    let _iface = parts.next().ok_or("missing interface name")?;
    let body = parts.next().ok_or("missing ID#DATA")?;
    let stamp = stamp
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or("timestamp must look like (sec.usec)")?;
    let (sec, usec) = stamp
        .split_once('.')
        .ok_or("timestamp must look like (sec.usec)")?;
    let sec: u64 = sec.parse().map_err(|_| format!("bad seconds `{sec}`"))?;
    if usec.len() != 6 {
        return Err(format!("microseconds `{usec}` must have 6 digits"));
    }
    let usec: u64 = usec
        .parse()
        .map_err(|_| format!("bad microseconds `{usec}`"))?;
    let t_us = sec
        .checked_mul(1_000_000)
        .and_then(|s| s.checked_add(usec))
        .ok_or_else(|| format!("timestamp `{stamp}` is out of range"))?;
    let (id, data) = body.split_once('#').ok_or("frame must look like ID#DATA")?;
    if data.starts_with('R') || data.starts_with('#') {
        return Err("remote and CAN FD frames are not used by the replay".into());
    }
    // Hex digits only (a multi-byte character would split the pairs below).
    if !data.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!("data `{data}` is not hex"));
    }
    if !id.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!("id `{id}` is not hex"));
    }
    if data.len() % 2 != 0 || data.len() > 16 {
        return Err(format!("data `{data}` must be 0–8 bytes of hex pairs"));
    }
    let bytes: Vec<u8> = (0..data.len() / 2)
        .map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16))
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("data `{data}` is not hex"))?;
    let raw = u32::from_str_radix(id, 16).map_err(|_| format!("id `{id}` is not hex"))?;
    match id.len() {
        3 if raw <= 0x7FF => Ok(Some(CanFrame::new(t_us, raw, &bytes))),
        8 if raw & CAN_ERR_FLAG != 0 => {
            let mut f = CanFrame::error(t_us, raw & !CAN_ERR_FLAG);
            f.len = bytes.len() as u8;
            f.data[..bytes.len()].copy_from_slice(&bytes);
            Ok(Some(f))
        }
        _ => Err(format!(
            "id `{id}`: only 11-bit ids (3 hex digits) and error frames are used by CANopen"
        )),
    }
}

/// Read a whole candump -l log; errors name the file and the line (as the row).
pub fn read_log(path: &Path) -> std::result::Result<Vec<CanFrame>, InputError> {
    let file = File::open(path).map_err(|e| InputError::new(path, format!("cannot open: {e}")))?;
    let mut out = Vec::new();
    for (i, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| InputError::new(path, format!("cannot read: {e}")).row(i))?;
        match parse_line(&line) {
            Ok(Some(f)) => out.push(f),
            Ok(None) => {}
            Err(m) => {
                return Err(InputError::new(path, format!("not a candump -l line: {m}")).row(i))
            }
        }
    }
    Ok(out)
}

/// Streams candump lines into a temporary file beside `path`; `finish`
/// renames it into place.
pub struct LogWriter {
    path: PathBuf,
    tmp: PathBuf,
    out: Option<BufWriter<File>>,
    pub frames: u64,
    /// Replace an existing file (by rename) instead of refusing.
    force: bool,
}

impl LogWriter {
    /// A new log at `path`; an existing file there is never overwritten (a
    /// recorded bus log is evidence: refuse, and say how to proceed).
    pub fn create(path: &Path) -> Result<LogWriter> {
        Self::create_with(path, false)
    }

    /// As [`LogWriter::create`]; with `force` an existing regular file is
    /// replaced at the end (atomically, by rename), never a directory or a link.
    pub fn create_with(path: &Path, force: bool) -> Result<LogWriter> {
        if force && (path.is_dir() || path.is_symlink()) {
            return Err(Error::LogNotAFile {
                path: path.to_path_buf(),
            });
        }
        if !force && (path.exists() || path.is_symlink()) {
            return Err(Error::LogExists {
                path: path.to_path_buf(),
            });
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(Error::io("cannot create", dir))?;
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "replay.log".into());
        let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
        let file = File::create(&tmp).map_err(Error::io("cannot create", &tmp))?;
        Ok(LogWriter {
            path: path.to_path_buf(),
            tmp,
            out: Some(BufWriter::new(file)),
            frames: 0,
            force,
        })
    }
    pub fn write(&mut self, f: &CanFrame) -> Result<()> {
        if let Some(out) = self.out.as_mut() {
            writeln!(out, "{}", format_line(f, LOG_IFACE))
                .map_err(Error::io("cannot write", &self.tmp))?;
            self.frames += 1;
        }
        Ok(())
    }
    pub fn finish(&mut self) -> Result<()> {
        if let Some(out) = self.out.take() {
            let file = out.into_inner().map_err(|e| Error::Bus {
                target: self.tmp.display().to_string(),
                message: format!("cannot flush {}: {e}", self.tmp.display()),
                source: None,
            })?;
            file.sync_all().map_err(|error| Error::IoAt {
                path: self.tmp.clone(),
                error,
            })?;
            if self.force {
                // Asked for: the old log is replaced in one rename.
                return std::fs::rename(&self.tmp, &self.path)
                    .map_err(Error::io("cannot write", &self.path));
            }
            // A hard link fails where a file appeared meanwhile: never
            // clobbered, even by a race.
            match std::fs::hard_link(&self.tmp, &self.path) {
                Ok(()) => {
                    let _ = std::fs::remove_file(&self.tmp);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    return Err(Error::LogAppeared {
                        path: self.path.clone(),
                        kept: self.tmp.clone(),
                        source: e,
                    });
                }
                // A file system without hard links.
                Err(_) if !self.path.exists() => std::fs::rename(&self.tmp, &self.path)
                    .map_err(Error::io("cannot write", &self.path))?,
                Err(e) => return Err(Error::io("cannot write", &self.path)(e)),
            }
        }
        Ok(())
    }
}

impl Drop for LogWriter {
    fn drop(&mut self) {
        // Not finished (an error unwound past us): leave no partial file.
        if self.out.take().is_some() {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// `log:<file>`: the traffic of `inner` (sent and received) logged in
/// candump -l format.
pub struct LogBus<B: CanBus> {
    inner: B,
    log: LogWriter,
}

impl<B: CanBus> LogBus<B> {
    pub fn new(inner: B, path: &Path) -> Result<LogBus<B>> {
        Self::create(inner, path, false)
    }
    /// With `force`, an existing log file at `path` is replaced at the end.
    pub fn create(inner: B, path: &Path, force: bool) -> Result<LogBus<B>> {
        Ok(LogBus {
            inner,
            log: LogWriter::create_with(path, force)?,
        })
    }
    pub fn path(&self) -> &Path {
        &self.log.path
    }
    /// The wrapped bus (tests look at the simulated drives' state).
    pub fn into_inner(self) -> B {
        self.inner
    }
}

impl<B: CanBus> CanBus for LogBus<B> {
    fn describe(&self) -> String {
        format!(
            "log:{} (over {})",
            self.log.path.display(),
            self.inner.describe()
        )
    }
    fn now_us(&self) -> u64 {
        self.inner.now_us()
    }
    fn send(&mut self, mut frame: CanFrame) -> Result<()> {
        frame.t_us = self.inner.now_us();
        self.log.write(&frame)?;
        self.inner.send(frame)
    }
    fn recv(&mut self) -> Result<Option<CanFrame>> {
        let f = self.inner.recv()?;
        if let Some(f) = &f {
            self.log.write(f)?;
        }
        Ok(f)
    }
    fn wait_until(&mut self, t_us: u64) -> Result<()> {
        self.inner.wait_until(t_us)
    }
    fn finish(&mut self) -> Result<()> {
        self.inner.finish()?;
        self.log.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::CAN_ERR_BUSOFF;

    #[test]
    fn line_round_trip() {
        let frames = [
            CanFrame::new(4000, 0x080, &[]),
            CanFrame::new(1_234_567_890, 0x201, &[0x0F, 0, 0x10, 0x27, 0, 0]),
            CanFrame::new(5, 0x701, &[0x05]),
            CanFrame::error(8000, CAN_ERR_BUSOFF),
        ];
        for f in frames {
            let line = format_line(&f, LOG_IFACE);
            assert_eq!(parse_line(&line).unwrap(), Some(f), "{line}");
        }
        assert_eq!(
            format_line(&frames[1], "can0"),
            "(0000001234.567890) can0 201#0F0010270000"
        );
        assert_eq!(
            format_line(&frames[3], "can0"),
            "(0000000000.008000) can0 20000040#0000000000000000"
        );
    }

    #[test]
    fn bad_lines_are_rejected() {
        for bad in [
            "0.1 can0 080#",
            "(0.1) can0 080#",
            "(1.000001) can0 1234ABCD#00",
            "(1.000001) can0 201#0",
            "(1.000001) can0 201#ZZ",
            "(1.000001) can0",
        ] {
            assert!(parse_line(bad).is_err(), "{bad}");
        }
    }
}
