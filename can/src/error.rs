//! The replay's error type: what went wrong, with the data a caller can act
//! on (the flag and its value, the config file and key, the EDS object, the
//! path). Every Display text is the message the CLI prints (tests and users
//! match on it); a wrapped cause is the error's `source()`, so `{:#}` prints
//! `message: cause` as before.

use std::path::PathBuf;

pub use sparkout_core::error::InputError;

/// The crate's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A replay option out of range or malformed: `flag` as on the command
    /// line (`--bus`, `--sim-fault`, `--nodes`, `--axis`, `--cycle-ms`…),
    /// `value` as given.
    #[error("{message}")]
    BadOption {
        flag: &'static str,
        value: String,
        message: String,
    },
    /// A machine config's `[replay]` table: `key` is the dotted key
    /// (`replay`, `replay.eds."1"`, `replay.axes.x`…).
    #[error("{message}")]
    MachineConfig {
        file: String,
        key: String,
        message: String,
    },
    /// A device description lacks an object the master needs to drive
    /// axis `drive_axis` (1–4) of `node`.
    #[error("{file}: no object 0x{index:04X}:{sub:02X} ({what}); the replay master needs it to drive {}", drive_name(*node, *drive_axis))]
    EdsMissingObject {
        file: String,
        index: u16,
        sub: u8,
        what: String,
        node: u8,
        drive_axis: u8,
    },
    /// The shipped EDS no longer maps what the master encodes.
    #[error("EDS [{section}] DefaultValue is {got:?}, the replay master encodes {expected}: fix configs/can/cia402_drive.eds or the master together")]
    EdsMapping {
        section: &'static str,
        got: Option<String>,
        expected: &'static str,
    },
    /// The shipped EDS lacks an object (`object` is its hex index).
    #[error("EDS has no object [{object}] (the replay master uses it)")]
    EdsNoObject { object: &'static str },
    /// A master configuration that cannot drive the axes.
    #[error("{0}")]
    Master(String),
    /// An envelope limit that is not a finite number > 0.
    #[error("envelope limit {limit} = {value}: it must be a finite number > 0 (mm)")]
    EnvelopeLimit { limit: &'static str, value: f64 },
    /// The plan leaves the envelope at `setpoint` (`t_s`): nothing was sent.
    #[error(
        "the replay would leave the safety envelope at setpoint {setpoint} (t = {t_s:.6} s): {why}; nothing was sent. \
         Check the compensation or widen the limit (--max-comp-mm, --max-step-mm, --max-step-change-mm)"
    )]
    EnvelopeRefused {
        setpoint: usize,
        t_s: f64,
        why: String,
    },
    /// `--bus log:FILE` names a file that exists (a bus log is evidence).
    #[error("{} already exists; a bus log is never overwritten — name a new file (e.g. {}) or move the old one away (--force replaces it)", path.display(), path.with_extension("2.log").display())]
    LogExists { path: PathBuf },
    /// `--force` on a directory or a link.
    #[error("{}: --force replaces a regular file only, not a directory or a link", path.display())]
    LogNotAFile { path: PathBuf },
    /// Another file took the log's name while the replay ran; the new log is
    /// kept at `kept`.
    #[error("{} appeared while the replay ran; not overwritten (the new log is kept as {})", path.display(), kept.display())]
    LogAppeared {
        path: PathBuf,
        kept: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The bus (an interface, or a log file) failed: `target` is
    /// `socketcan:IFACE` or the log's path.
    #[error("{message}")]
    Bus {
        target: String,
        message: String,
        #[source]
        source: Option<std::io::Error>,
    },
    /// The binary was built without the `socketcan` feature.
    #[error("this sparkout binary has no SocketCAN support: the backend is the cargo feature `socketcan`, off by default — rebuild with `cargo build --release --features socketcan` (Linux), or use --bus sim / --dry-run")]
    NoSocketCan,
    /// A file operation failed: `action` is e.g. `cannot write`.
    #[error("{action} {}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// An I/O error whose text is the message (no context was ever added).
    #[error("{error}")]
    IoAt {
        path: PathBuf,
        error: std::io::Error,
    },
    /// A copy of `from` to `to` failed.
    #[error("cannot copy {} to {}", from.display(), to.display())]
    Copy {
        from: PathBuf,
        to: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// `--record` had nothing to write: no cycle had feedback from every drive.
    #[error("nothing to record: no cycle was streamed with feedback from every drive ({outcome})")]
    NothingToRecord { outcome: String },
    /// The source run's run.toml did not parse.
    #[error("source run.toml")]
    SourceRunToml(#[source] toml::de::Error),
    /// The recorded run's run.toml could not be written out as TOML.
    #[error(transparent)]
    TomlWrite(#[from] toml::ser::Error),
    /// A bad input file (run, motion, compensation, EDS, candump log).
    #[error(transparent)]
    Input(#[from] InputError),
    /// An error from sparkout-core (writing a file, reading a Parquet):
    /// kept whole, its chain is this error's.
    #[error(transparent)]
    Core(sparkout_core::Error),
}

impl Error {
    pub(crate) fn bad_option(flag: &'static str, value: impl ToString, message: String) -> Error {
        Error::BadOption {
            flag,
            value: value.to_string(),
            message,
        }
    }
    pub(crate) fn io(
        action: &'static str,
        path: &std::path::Path,
    ) -> impl FnOnce(std::io::Error) -> Error {
        let path = path.to_path_buf();
        move |source| Error::Io {
            action,
            path,
            source,
        }
    }
}

/// A drive axis as `canopen::AxisRef` shows it (`node 1`, `node 1 axis 2`);
/// the error keeps node and axis as numbers so that this module, which
/// every other one uses, depends on none of them (no import cycle).
fn drive_name(node: u8, axis: u8) -> String {
    if axis == 1 {
        format!("node {node}")
    } else {
        format!("node {node} axis {axis}")
    }
}
