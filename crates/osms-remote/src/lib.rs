//! Remote artifact caches: push and pull a store's objects and stage records to S3-compatible
//! storage, HTTP (WebDAV) or a shared directory, every download verified against its blake3 name.
//!
//! A remote mirrors the store's two tables: objects by content hash (`cas/`) and stage records
//! by stage key (`ac/`, Bazel's action cache). [`Remote::push`] writes objects before records,
//! so a record never names an object the remote lacks; [`Remote::fetch`] checks every object
//! against its name before the store's own atomic write takes it, then writes the record. A
//! remote's writers are trusted for what a record says (key → content hash), as Bazel trusts
//! its action cache; the bytes are never trusted.
//!
//! Entry points: [`Remote::open`], [`Remote::check`], [`Remote::push`], [`Remote::fetch`] (one
//! key), [`Remote::record`] and [`Remote::download`] (many keys' objects at once).

mod error;
mod remote;

pub use error::{Error, Result};
pub use remote::{DEFAULT_JOBS, Fetched, NoProgress, Progress, PushReport, Received, Remote};
