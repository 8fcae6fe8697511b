//! One batch per output directory: `<out>/.sparkout.lock` holds the pid and
//! host of the batch writing there. Two batches on one `--out` would mix
//! their artifacts under one manifest, so the second refuses. A lock whose
//! process is gone (same host, no such pid — a kill -9 or a power cut) is
//! stale and taken over with a warning.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use crate::error::Result;

pub const LOCK_FILE: &str = ".sparkout.lock";

/// Held for the whole batch; removes the lock file when dropped.
#[derive(Debug)]
pub struct BatchLock {
    path: PathBuf,
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

/// Whether a process of this pid runs on this host. Without /proc (not
/// Linux) we cannot tell and assume it does: refusing is the safe side.
fn pid_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new(&format!("/proc/{pid}")).exists()
}

/// What a lock file says: (pid, host).
fn parse_lock(text: &str) -> Option<(u32, String)> {
    let mut pid = None;
    let mut host = None;
    for line in text.lines() {
        if let Some(v) = line.strip_prefix("pid=") {
            pid = v.trim().parse().ok();
        } else if let Some(v) = line.strip_prefix("host=") {
            host = Some(v.trim().to_string());
        }
    }
    Some((pid?, host?))
}

impl BatchLock {
    /// Take the lock of `out` (created if needed) or explain who holds it.
    pub fn acquire(out: &Path) -> Result<BatchLock> {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        let path = out.join(LOCK_FILE);
        let me = std::process::id();
        let host = host_name();
        // Two attempts: the second after removing a stale lock.
        for _ in 0..2 {
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(mut f) => {
                    writeln!(f, "pid={me}\nhost={host}")
                        .and_then(|_| f.sync_all())
                        .with_context(|| format!("cannot write {}", path.display()))?;
                    return Ok(BatchLock { path });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let text = std::fs::read_to_string(&path).unwrap_or_default();
                    match parse_lock(&text) {
                        Some((pid, h)) if h == host && !pid_alive(pid) => {
                            tracing::warn!(
                                "removing the stale lock {} (pid {pid} on {h} is not running: a killed batch)",
                                path.display()
                            );
                            std::fs::remove_file(&path).with_context(|| {
                                format!("cannot remove stale lock {}", path.display())
                            })?;
                        }
                        Some((pid, h)) => bail!(
                            "another sparkout batch (pid {pid} on host {h}) is writing to {}; \
                             wait for it to finish or choose another --out. If no batch is running \
                             there, delete {}",
                            out.display(),
                            path.display()
                        ),
                        None => bail!(
                            "{} exists but is not a sparkout lock (expected pid=/host= lines); \
                             if no batch is running there, delete it",
                            path.display()
                        ),
                    }
                }
                Err(e) => {
                    return Err(e).with_context(|| format!("cannot create {}", path.display()))
                }
            }
        }
        bail!(
            "cannot take the lock {} (another batch took it meanwhile)",
            path.display()
        )
    }
}

impl Drop for BatchLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn second_lock_refused_stale_lock_taken_over() {
        let d = tempfile::tempdir().unwrap();
        let a = BatchLock::acquire(d.path()).unwrap();
        let e = BatchLock::acquire(d.path()).unwrap_err().to_string();
        assert!(e.contains("another sparkout batch"), "{e}");
        assert!(e.contains(&format!("pid {}", std::process::id())), "{e}");
        drop(a);
        assert!(!d.path().join(LOCK_FILE).exists());
        // A pid above the kernel's pid_max cannot be running.
        std::fs::write(
            d.path().join(LOCK_FILE),
            format!("pid=4294967295\nhost={}\n", host_name()),
        )
        .unwrap();
        let b = BatchLock::acquire(d.path()).unwrap();
        drop(b);
        // Another host: we cannot know, so refuse.
        std::fs::write(d.path().join(LOCK_FILE), "pid=1\nhost=elsewhere.example\n").unwrap();
        assert!(BatchLock::acquire(d.path()).is_err());
    }
}
