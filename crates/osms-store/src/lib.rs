//! Content-addressed artifact store: blake3 hashes, atomic verified reads and writes of encoded
//! artifacts, an index of stage records, locks, verify and gc.
//!
//! Entry points: [`Store`] (objects, records, lock, verify, gc), [`Hash`] (content hashes and
//! stage keys). The artifact codec the objects are written in is `osms_core`'s.

mod error;
mod fscheck;
mod hash;
mod statcache;
mod store;

pub use error::{Error, Result};
pub use fscheck::{FsCheck, FsClass, classify};
pub use hash::Hash;
pub use store::{
    Batch, GcReport, ObjectState, Record, ShardOf, Store, StoreLock, UnreadableRecord,
    VerifyProblem, VerifyReport, host_name,
};
