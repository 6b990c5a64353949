use std::fmt;
use std::io::ErrorKind;
use std::path::{Path, PathBuf};

/// A place in `pipeline.toml`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub path: PathBuf,
    pub line: usize,
    pub column: usize,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}:{}", self.path.display(), self.line, self.column)
    }
}

/// A problem with the pipeline declaration, located where possible.
#[derive(Debug, Clone)]
pub struct Invalid {
    pub location: Option<Location>,
    pub message: String,
    pub hint: Option<String>,
}

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(loc) = &self.location {
            write!(f, "{loc}: ")?;
        }
        f.write_str(&self.message)?;
        if let Some(hint) = &self.hint {
            write!(f, "\nhint: {hint}")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Store(#[from] osms_store::Error),
    #[error("{0}")]
    Invalid(Invalid),
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{what}")]
    Usage { what: String },
    #[error("{failed} stage(s) failed: {names}")]
    StagesFailed { failed: usize, names: String },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn invalid(
        location: Option<Location>,
        message: impl Into<String>,
        hint: Option<String>,
    ) -> Self {
        Error::Invalid(Invalid {
            location,
            message: message.into(),
            hint,
        })
    }

    pub(crate) fn usage(what: impl Into<String>) -> Self {
        Error::Usage { what: what.into() }
    }

    /// Whether the error is the user's (exit code 1) rather than an internal failure (2).
    pub fn is_user_error(&self) -> bool {
        match self {
            Error::Store(osms_store::Error::Io { .. }) => false,
            // The pipeline file is the user's to name: a mistyped path, a directory, a file they
            // may not read or one that is not UTF-8 is theirs to fix; anything else (EIO, ...)
            // is the machine's.
            Error::Read { source, .. } => matches!(
                source.kind(),
                ErrorKind::NotFound
                    | ErrorKind::PermissionDenied
                    | ErrorKind::IsADirectory
                    | ErrorKind::NotADirectory
                    | ErrorKind::InvalidData
            ),
            _ => true,
        }
    }
}

/// Lists names as "`a`, `b`, `c`" for hints.
pub(crate) fn list(names: impl IntoIterator<Item = impl AsRef<str>>) -> String {
    let items: Vec<String> = names
        .into_iter()
        .map(|n| format!("`{}`", n.as_ref()))
        .collect();
    if items.is_empty() {
        "(none)".to_string()
    } else {
        items.join(", ")
    }
}

/// Where the key path `keys` (e.g. `["stages", "teacher", "params"]`) sits in a TOML
/// source, for errors that point at the line the user wrote.
pub(crate) fn key_location(
    path: &Path,
    source: &str,
    doc: &toml_edit::Document<String>,
    keys: &[&str],
) -> Option<Location> {
    let mut item: &toml_edit::Item = doc.as_item();
    let mut span = None;
    for key in keys {
        let Some((k, next)) = item.as_table_like().and_then(|t| t.get_key_value(key)) else {
            break;
        };
        span = k.span().or(span);
        item = next;
    }
    span.map(|s| location_of(path, source, s.start))
}

pub(crate) fn location_of(path: &Path, source: &str, offset: usize) -> Location {
    let before = &source[..offset.min(source.len())];
    let line = before.matches('\n').count() + 1;
    let column = before
        .rsplit('\n')
        .next()
        .map(|l| l.chars().count())
        .unwrap_or(0)
        + 1;
    Location {
        path: path.to_path_buf(),
        line,
        column,
    }
}
