//! Content-addressed artifact store: blake3 hashes, a versioned postcard+zstd codec, atomic
//! verified reads and writes, an index of stage records, locks, verify and gc.
//!
//! Entry points: [`Store`] (objects, records, lock, verify, gc), [`encode`]/[`decode`] (the
//! artifact codec), [`Hash`] (content hashes and stage keys).

mod codec;
mod error;
mod fscheck;
mod hash;
mod statcache;
mod store;

pub use codec::{Artifact, FORMAT_VERSION, Header, MAGIC, decode, encode, read_header};
pub use error::{Error, Result};
pub use fscheck::{FsCheck, FsClass, classify};
pub use hash::Hash;
pub use store::{
    GcReport, ObjectState, Record, ShardOf, Store, StoreLock, UnreadableRecord, VerifyProblem,
    VerifyReport, host_name,
};
