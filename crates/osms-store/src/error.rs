use std::path::PathBuf;
use std::str::FromStr;

use crate::Hash;

/// Everything that can go wrong in the store.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("I/O error on {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("object {hash} is missing from the store")]
    Missing { hash: Hash },
    #[error("object {hash} is damaged: its bytes hash to {actual} (at {path})")]
    Damaged {
        hash: Hash,
        actual: Hash,
        path: PathBuf,
    },
    #[error("not an osms artifact: {reason}")]
    Foreign { reason: String },
    #[error(transparent)]
    Codec(#[from] osms_core::Error),
    #[error("index record {path} is unreadable: {reason}")]
    BadRecord { path: PathBuf, reason: String },
    #[error(
        "{root} is not an osms store as seen from host {host} (no OSMS_STORE marker); \
         hint: a cluster task must see the same store as `osms make`: put the store on a \
         filesystem shared by the submit host and the compute nodes (e.g. --store /shared/...)"
    )]
    NotShared { root: PathBuf, host: String },
    #[error(
        "the store at {root} is on {name}, which cannot hold a cluster build: {why}; \
         hint: put the store on NFS, Lustre, GPFS, BeeGFS or CephFS (--store DIR), or build \
         locally without --executor slurm"
    )]
    UnsafeFilesystem {
        root: PathBuf,
        name: String,
        why: String,
    },
    #[error("`{text}` is not a hash: expected 64 hexadecimal digits")]
    BadHash { text: String },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

// Parsing a hash is where a `Hash` meets the error type; it lives here so that hash.rs needs
// nothing of this module (no import circle between the two).
impl FromStr for Hash {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self, Error> {
        blake3::Hash::from_hex(s)
            .map(Hash::from)
            .map_err(|_| Error::BadHash {
                text: s.to_string(),
            })
    }
}
