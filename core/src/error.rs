//! Errors that tell the user what is wrong and where: file, column, row.

use std::fmt;
use std::path::{Path, PathBuf};

/// A bad input: names the file, the column and (where it applies) the first
/// offending row, per docs/formats.md §1.
#[derive(Debug, Clone, PartialEq)]
pub struct InputError {
    pub file: PathBuf,
    pub column: Option<String>,
    pub row: Option<usize>,
    pub message: String,
}

impl InputError {
    pub fn new(file: impl AsRef<Path>, message: impl Into<String>) -> Self {
        InputError {
            file: file.as_ref().to_path_buf(),
            column: None,
            row: None,
            message: message.into(),
        }
    }
    pub fn column(mut self, column: impl Into<String>) -> Self {
        self.column = Some(column.into());
        self
    }
    pub fn row(mut self, row: usize) -> Self {
        self.row = Some(row);
        self
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(c) = &self.column {
            write!(f, ", column `{c}`")?;
        }
        if let Some(r) = self.row {
            write!(f, ", row {r}")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for InputError {}

/// A bad config section (`[<plugin>.<stage>]`, `[diagnose]`): typed so a
/// caller can tell an unknown key from a bad value without reading the
/// message (`sparkout stage --flag` turns the first into "not a config key
/// of this stage", the second into "bad value for this flag").
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("unknown key `{key}` (known: {})", known_list(.known))]
    UnknownKey { key: String, known: Vec<String> },
    #[error("key `{key}` must be {want}, found {found}")]
    BadValue {
        key: String,
        want: String,
        found: String,
    },
    /// A value serde could not read (wrong type, wrong shape); the message
    /// names the key.
    #[error("{0}")]
    Invalid(String),
    /// A key's value of the wrong type or shape.
    #[error("key `{key}`: {message}")]
    WrongType { key: String, message: String },
    /// A key that must be given is not.
    #[error("required key `{key}` is missing")]
    Missing { key: String },
}

impl ConfigError {
    pub fn bad_value(key: &str, want: impl Into<String>, found: impl fmt::Display) -> Self {
        ConfigError::BadValue {
            key: key.to_string(),
            want: want.into(),
            found: found.to_string(),
        }
    }
    /// The key the error is about, when it names one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::UnknownKey { key, .. }
            | ConfigError::BadValue { key, .. }
            | ConfigError::WrongType { key, .. }
            | ConfigError::Missing { key } => Some(key),
            ConfigError::Invalid(_) => None,
        }
    }
    /// Whether an error of any kind is an unknown config key.
    pub fn is_unknown_key(e: &Error) -> bool {
        matches!(e.config(), Some(ConfigError::UnknownKey { .. }))
    }
}

fn known_list(known: &[String]) -> String {
    if known.is_empty() {
        "none".to_string()
    } else {
        known.join(", ")
    }
}

/// The library crates' result: a typed [`Error`] by default.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What went wrong, by kind. A caller tells a bad input (the run is skipped
/// and listed) from a bad config (the batch stops) from an I/O or format
/// failure by matching on it — through any number of contexts, with
/// [`Error::input`] and [`Error::config`].
#[derive(Debug, thiserror::Error)]
pub enum Kind {
    /// A bad input file, naming file, column and row.
    #[error(transparent)]
    Input(#[from] InputError),
    /// A bad config key or value.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A condition the code checks, said in words (`bail!`, `err!`).
    #[error("{0}")]
    Message(String),
    /// A message added on the way up (`.context(…)`) to the error below.
    #[error("{context}")]
    Context {
        context: String,
        #[source]
        source: Error,
    },
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Arrow(#[from] arrow::error::ArrowError),
    #[error(transparent)]
    Parquet(#[from] parquet::errors::ParquetError),
    #[error(transparent)]
    Polars(#[from] polars::error::PolarsError),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    TomlRead(#[from] toml::de::Error),
    #[error(transparent)]
    TomlWrite(#[from] toml::ser::Error),
    #[error(transparent)]
    ObjectStore(#[from] object_store::Error),
    /// Any other library's error (a crate above this one with its own
    /// error type converts into it).
    #[error(transparent)]
    Other(Box<dyn std::error::Error + Send + Sync + 'static>),
}

/// The error of every library crate but sparkout-can (which has its own):
/// a boxed [`Kind`], so `Result<T>` stays one pointer wide. Its `Display`
/// follows the convention the binary's `{:#}` relies on: `{}` prints the
/// outermost message, `{:#}` the whole chain joined by ": ".
pub struct Error(Box<Kind>);

impl Error {
    /// An error that is a message in words.
    pub fn msg(m: impl fmt::Display) -> Self {
        Error(Box::new(Kind::Message(m.to_string())))
    }
    /// Any library's error; one of this crate's own kinds (an [`Error`],
    /// an [`InputError`], a [`ConfigError`]) keeps its kind, so
    /// [`Error::input`] still finds it.
    pub fn other(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        let b: Box<dyn std::error::Error + Send + Sync> = Box::new(e);
        let b = match b.downcast::<Error>() {
            Ok(e) => return *e,
            Err(b) => b,
        };
        // Each kind with a variant of its own gets it.
        macro_rules! own_kind {
            ($b:ident, $($t:ty),*) => {$(
                let $b = match $b.downcast::<$t>() {
                    Ok(e) => return Error::from(*e),
                    Err(b) => b,
                };
            )*};
        }
        own_kind!(
            b,
            InputError,
            ConfigError,
            std::io::Error,
            arrow::error::ArrowError,
            parquet::errors::ParquetError,
            polars::error::PolarsError,
            serde_json::Error,
            toml::de::Error,
            toml::ser::Error,
            object_store::Error
        );
        Error(Box::new(Kind::Other(b)))
    }
    /// This error with `context` said above it.
    pub fn context(self, context: impl fmt::Display) -> Self {
        Error(Box::new(Kind::Context {
            context: context.to_string(),
            source: self,
        }))
    }
    pub fn kind(&self) -> &Kind {
        &self.0
    }
    /// The innermost error below every context.
    pub fn root(&self) -> &Kind {
        let mut k = self.kind();
        while let Kind::Context { source, .. } = k {
            k = source.kind();
        }
        k
    }
    /// The bad input this error reports, under any contexts.
    pub fn input(&self) -> Option<&InputError> {
        match self.root() {
            Kind::Input(i) => Some(i),
            _ => None,
        }
    }
    /// The bad config key this error reports, under any contexts.
    pub fn config(&self) -> Option<&ConfigError> {
        match self.root() {
            Kind::Config(c) => Some(c),
            _ => None,
        }
    }
}

impl fmt::Debug for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{self:#}")
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        if f.alternate() {
            let mut cause = std::error::Error::source(&*self.0);
            while let Some(c) = cause {
                write!(f, ": {c}")?;
                cause = c.source();
            }
        }
        Ok(())
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        std::error::Error::source(&*self.0)
    }
}

impl<K: Into<Kind>> From<K> for Error {
    fn from(k: K) -> Self {
        Error(Box::new(k.into()))
    }
}

impl From<String> for Kind {
    fn from(m: String) -> Self {
        Kind::Message(m)
    }
}

impl From<&str> for Kind {
    fn from(m: &str) -> Self {
        Kind::Message(m.to_string())
    }
}

impl From<Box<dyn std::error::Error + Send + Sync + 'static>> for Kind {
    fn from(e: Box<dyn std::error::Error + Send + Sync + 'static>) -> Self {
        Kind::Other(e)
    }
}

/// A thread pool that could not be built (`?` in the validation runners);
/// any other library's error reaches `Other` through [`Error::other`] or
/// `.context(…)`.
impl From<rayon::ThreadPoolBuildError> for Kind {
    fn from(e: rayon::ThreadPoolBuildError) -> Self {
        Kind::Other(Box::new(e))
    }
}

/// `.context(…)` and `.with_context(|| …)` on a result or an option: the
/// error (or the absence) said one level up.
pub trait Context<T> {
    fn context<C: fmt::Display>(self, context: C) -> Result<T>;
    fn with_context<C: fmt::Display, F: FnOnce() -> C>(self, f: F) -> Result<T>;
}

impl<T, E: std::error::Error + Send + Sync + 'static> Context<T> for std::result::Result<T, E> {
    fn context<C: fmt::Display>(self, context: C) -> Result<T> {
        self.map_err(|e| Error::other(e).context(context))
    }
    fn with_context<C: fmt::Display, F: FnOnce() -> C>(self, f: F) -> Result<T> {
        self.map_err(|e| Error::other(e).context(f()))
    }
}

impl<T> Context<T> for Option<T> {
    fn context<C: fmt::Display>(self, context: C) -> Result<T> {
        self.ok_or_else(|| Error::msg(context))
    }
    fn with_context<C: fmt::Display, F: FnOnce() -> C>(self, f: F) -> Result<T> {
        self.ok_or_else(|| Error::msg(f()))
    }
}

/// An [`Error`] from a format string (or any displayable value).
#[macro_export]
macro_rules! err {
    ($msg:literal $(,)?) => {
        $crate::error::Error::msg(format!($msg))
    };
    ($fmt:literal, $($arg:tt)*) => {
        $crate::error::Error::msg(format!($fmt, $($arg)*))
    };
    ($e:expr $(,)?) => {
        $crate::error::Error::from($e)
    };
}

/// Returns early with an [`Error`] built like [`err!`].
#[macro_export]
macro_rules! bail {
    ($($t:tt)*) => {
        return Err($crate::err!($($t)*))
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bad_row() -> Result<()> {
        Err(InputError::new("runs/a/probe.parquet", "not finite")
            .column("x_mm")
            .row(7)
            .into())
    }

    #[test]
    fn a_bad_input_stays_one_under_any_context() {
        let e = bad_row()
            .context("reading the probe log")
            .with_context(|| "run a")
            .unwrap_err();
        let i = e.input().expect("still an InputError");
        assert_eq!((i.column.as_deref(), i.row), (Some("x_mm"), Some(7)));
        assert!(e.config().is_none());
        // Wrapped as a foreign error (a closure's `Box<dyn Error>`), too.
        let boxed: Box<dyn std::error::Error + Send + Sync> = Box::new(bad_row().unwrap_err());
        assert!(Error::other(*Box::new(Error::from(boxed)))
            .input()
            .is_none());
        let e = Error::other(bad_row().unwrap_err());
        assert!(e.input().is_some(), "Error::other keeps the kind: {e:#}");
    }

    #[test]
    fn display_prints_the_outermost_message_and_alternate_the_chain() {
        let e = bad_row().context("reading the probe log").unwrap_err();
        assert_eq!(e.to_string(), "reading the probe log");
        assert_eq!(
            format!("{e:#}"),
            "reading the probe log: runs/a/probe.parquet, column `x_mm`, row 7: not finite"
        );
        // anyhow at the binary's edge walks the same chain.
        let a = std::io::Error::other("disk full");
        let e = Err::<(), _>(a).context("writing out/x.json").unwrap_err();
        assert_eq!(format!("{e:#}"), "writing out/x.json: disk full");
        assert!(matches!(e.root(), Kind::Io(_)));
    }

    #[test]
    fn the_macros_build_messages_and_keep_kinds() {
        fn f(n: usize) -> Result<usize> {
            if n == 0 {
                crate::bail!("n must be positive, got {n}");
            }
            Ok(n)
        }
        assert_eq!(f(0).unwrap_err().to_string(), "n must be positive, got 0");
        let from_string = crate::err!(String::from("plain"));
        assert!(matches!(from_string.kind(), Kind::Message(m) if m == "plain"));
        let c = crate::err!(ConfigError::Missing { key: "k".into() }).context("[x]");
        assert!(matches!(c.config(), Some(ConfigError::Missing { .. })));
        assert!(!ConfigError::is_unknown_key(&c));
        assert!(None::<u8>.context("nothing there").is_err());
        // One pointer wide, so every `Result<T>` stays small.
        assert_eq!(std::mem::size_of::<Error>(), std::mem::size_of::<usize>());
    }
}
