//! The foundation of osms: seeded RNG streams and samplers, the Artifact trait and its canonical
//! postcard+zstd encoding, NoParams, and the one table model (Markdown, CSV, JSON; the paper's
//! value beside ours; mean ± sd over seeds).
//!
//! Everything above depends on it and it on nothing of osms: the numeric core (`osms-nn`)
//! draws its initial weights from [`rng`] and stores networks as [`Artifact`]s without
//! pulling in the store or the engine.

pub mod check;
mod codec;
mod error;
mod params;
pub mod rng;
pub mod stats;
pub mod table;

pub use codec::{Artifact, FORMAT_VERSION, Header, MAGIC, decode, encode, encode_as, read_header};
pub use error::{Error, Result};
pub use params::NoParams;
