//! One batch per output directory: `<out>/.sparkout.lock`. Two batches on
//! one `--out` would mix their artifacts under one manifest, so the second
//! refuses.
//!
//! The lock is an exclusive `flock` on that file, held by the open file for
//! the whole batch: the kernel releases it the moment its process ends — a
//! kill -9, a crash, a zombie not yet reaped — so a dead holder is known at
//! once and its lock taken over atomically (there is no "remove the stale
//! file, then create mine" window in which two batches could both get in).
//! The file also says who holds it (pid, host, the process's start time and
//! the boot it started in), for the messages and for one rule the kernel
//! cannot give: a lock written on another host (an output directory shared
//! over NFS, where flock may not reach across hosts) is never taken over
//! automatically; the message says how to clear it.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use crate::{bail, Context};

use crate::error::Result;

pub use crate::files::LOCK_FILE;

/// Held for the whole batch; removes the lock file when dropped.
#[derive(Debug)]
pub struct BatchLock {
    path: PathBuf,
    /// The locked file: closing it releases the lock.
    file: Option<File>,
}

/// This machine's name (the lock says where its batch runs: a pid means
/// nothing on another host sharing the directory over NFS).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .or_else(|| std::env::var("COMPUTERNAME").ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown-host".to_string())
}

/// The start time of a process (clock ticks since boot, field 22 of
/// /proc/PID/stat) and whether it is a zombie; `None` when there is no such
/// process (or no /proc).
fn proc_start(pid: u32) -> Option<(u64, bool)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // rest starts at field 3 (state); field 22 is index 19 here.
    let zombie = fields.first().is_some_and(|s| *s == "Z" || *s == "X");
    Some((fields.get(19)?.parse().ok()?, zombie))
}

fn boot_id() -> String {
    std::fs::read_to_string("/proc/sys/kernel/random/boot_id")
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// Who holds (or held) a lock.
#[derive(Debug, Clone, PartialEq)]
struct Holder {
    pid: u32,
    host: String,
    start_ticks: Option<u64>,
    boot: String,
}

impl Holder {
    fn me() -> Holder {
        let pid = std::process::id();
        Holder {
            pid,
            host: host_name(),
            start_ticks: proc_start(pid).map(|(t, _)| t),
            boot: boot_id(),
        }
    }

    fn parse(text: &str) -> Option<Holder> {
        let mut h = Holder {
            pid: 0,
            host: String::new(),
            start_ticks: None,
            boot: String::new(),
        };
        let (mut pid, mut host) = (false, false);
        for line in text.lines() {
            let Some((k, v)) = line.split_once('=') else {
                continue;
            };
            let v = v.trim();
            match k.trim() {
                "pid" => {
                    h.pid = v.parse().ok()?;
                    pid = true;
                }
                "host" => {
                    h.host = v.to_string();
                    host = true;
                }
                "start_ticks" => h.start_ticks = v.parse().ok(),
                "boot_id" => h.boot = v.to_string(),
                _ => {}
            }
        }
        (pid && host).then_some(h)
    }

    fn text(&self) -> String {
        format!(
            "pid={}\nhost={}\nstart_ticks={}\nboot_id={}\n",
            self.pid,
            self.host,
            self.start_ticks.map(|t| t.to_string()).unwrap_or_default(),
            self.boot
        )
    }

    /// On this host, whether that very process still runs (not a zombie, not
    /// a later process that reused the pid, not a process of an earlier
    /// boot). Used where the file system cannot lock.
    fn alive_here(&self) -> bool {
        if !Path::new("/proc/self").exists() {
            return true; // cannot tell: refusing is the safe side
        }
        if !self.boot.is_empty() && self.boot != boot_id() {
            return false;
        }
        match proc_start(self.pid) {
            None => false,
            Some((_, true)) => false,
            Some((t, false)) => self.start_ticks.is_none_or(|s| s == t),
        }
    }
}

/// The device and inode a path or an open file refers to.
fn identity(m: &std::fs::Metadata) -> (u64, u64) {
    use std::os::unix::fs::MetadataExt;
    (m.dev(), m.ino())
}

impl BatchLock {
    /// Take the lock of `out` (created if needed) or explain who holds it.
    pub fn acquire(out: &Path) -> Result<BatchLock> {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        let path = out.join(LOCK_FILE);
        let me = Holder::me();
        // A few attempts: a holder may remove the file between our open and
        // our lock, leaving us a lock on a file that no longer has the name.
        for _ in 0..8 {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .with_context(|| format!("cannot open {}", path.display()))?;
            let mut text = String::new();
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    let _ = file.read_to_string(&mut text);
                    return Err(held_by(out, &path, Holder::parse(&text)));
                }
                Err(std::fs::TryLockError::Error(e)) => {
                    // A file system without locks: judge by what the file says.
                    tracing::warn!(
                        "{} cannot be locked ({e}); judging a holder by its pid and start time",
                        path.display()
                    );
                    let _ = file.read_to_string(&mut text);
                    if let Some(h) = Holder::parse(&text) {
                        if h.host != me.host || h.alive_here() {
                            return Err(held_by(out, &path, Some(h)));
                        }
                    }
                    write_holder(&mut file, &path, &me)?;
                    return Ok(BatchLock {
                        path,
                        file: Some(file),
                    });
                }
            }
            // Locked: is it still the file under that name?
            let same = match (std::fs::metadata(&path), file.metadata()) {
                (Ok(a), Ok(b)) => identity(&a) == identity(&b),
                _ => false,
            };
            if !same {
                continue;
            }
            file.read_to_string(&mut text)
                .with_context(|| format!("cannot read {}", path.display()))?;
            if !text.trim().is_empty() {
                match Holder::parse(&text) {
                    None => bail!(
                        "{} exists but is not a sparkout lock (expected pid=/host= lines); if no batch is running there, delete it",
                        path.display()
                    ),
                    // Written on another host: its batch may hold an flock
                    // that does not reach us. Never taken over automatically.
                    Some(h) if h.host != me.host => return Err(held_by(out, &path, Some(h))),
                    Some(h) => tracing::warn!(
                        "taking over the lock {} of a batch that is no longer running (pid {} on {})",
                        path.display(),
                        h.pid,
                        h.host
                    ),
                }
            }
            write_holder(&mut file, &path, &me)?;
            return Ok(BatchLock {
                path,
                file: Some(file),
            });
        }
        bail!(
            "cannot take the lock {} (other batches keep replacing it)",
            path.display()
        )
    }
}

fn write_holder(file: &mut File, path: &Path, me: &Holder) -> Result<()> {
    file.set_len(0)
        .and_then(|_| file.rewind())
        .and_then(|_| file.write_all(me.text().as_bytes()))
        .and_then(|_| file.sync_all())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

fn held_by(out: &Path, path: &Path, h: Option<Holder>) -> crate::Error {
    match h {
        Some(h) if h.host != host_name() => crate::err!(
            "another sparkout batch (pid {} on host {}) holds {}; a lock written on another host is never taken over automatically. Wait for that batch or choose another --out; if you know no batch runs on {} any more, delete {}",
            h.pid,
            h.host,
            out.display(),
            h.host,
            path.display()
        ),
        Some(h) => crate::err!(
            "another sparkout batch (pid {} on host {}) is writing to {}; wait for it to finish or choose another --out",
            h.pid,
            h.host,
            out.display()
        ),
        None => crate::err!(
            "another sparkout batch is writing to {} (it holds {}); wait for it to finish or choose another --out",
            out.display(),
            path.display()
        ),
    }
}

impl Drop for BatchLock {
    fn drop(&mut self) {
        // Remove the name first, then release: a batch that opened the old
        // file meanwhile finds it unnamed and tries again.
        let _ = std::fs::remove_file(&self.path);
        drop(self.file.take());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn second_lock_refused_dead_holder_taken_over() {
        let d = tempfile::tempdir().unwrap();
        let a = BatchLock::acquire(d.path()).unwrap();
        let text = std::fs::read_to_string(d.path().join(LOCK_FILE)).unwrap();
        let h = Holder::parse(&text).unwrap();
        assert_eq!(h.pid, std::process::id());
        assert!(h.start_ticks.is_some() && h.alive_here(), "{text}");
        let e = BatchLock::acquire(d.path()).unwrap_err().to_string();
        assert!(e.contains("another sparkout batch"), "{e}");
        assert!(e.contains(&format!("pid {}", std::process::id())), "{e}");
        drop(a);
        assert!(!d.path().join(LOCK_FILE).exists());
        // A lock file of a batch that died (nobody holds the flock): taken
        // over at once, whatever its pid.
        std::fs::write(
            d.path().join(LOCK_FILE),
            format!("pid={}\nhost={}\n", std::process::id(), host_name()),
        )
        .unwrap();
        let b = BatchLock::acquire(d.path()).unwrap();
        drop(b);
        // Another host: we cannot know, so refuse, and say how to clear it.
        std::fs::write(d.path().join(LOCK_FILE), "pid=1\nhost=elsewhere.example\n").unwrap();
        let e = BatchLock::acquire(d.path()).unwrap_err().to_string();
        assert!(e.contains("never taken over automatically"), "{e}");
        assert!(e.contains("delete"), "{e}");
        // Not a lock at all.
        std::fs::write(d.path().join(LOCK_FILE), "hello\n").unwrap();
        assert!(BatchLock::acquire(d.path()).is_err());
    }

    #[test]
    fn pid_reuse_and_other_boots_are_not_alive() {
        let mut h = Holder::me();
        assert!(h.alive_here());
        h.start_ticks = h.start_ticks.map(|t| t + 1);
        assert!(!h.alive_here(), "a later process with the same pid");
        let mut h = Holder::me();
        h.boot = "another-boot".into();
        assert!(!h.alive_here());
        let mut h = Holder::me();
        h.pid = u32::MAX;
        assert!(!h.alive_here());
    }
}
