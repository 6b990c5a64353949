//! Stage kinds: the typed traits a stage implements, and their type-erased form in a
//! [`Registry`].
//!
//! A kind is registered in code with a name, an explicit code version (bump it whenever the
//! output for the same inputs may change), its input slots and a params struct ([`Kind`]).
//! Plain kinds ([`Stage`]) compute one artifact; itemised kinds ([`ItemStage`]) compute a list
//! of independent items that the executor can split into shards.
//!
//! [`author`] is what a kind implements; [`ctx`] what a running stage reads; [`erased`] turns a
//! kind into a [`DynKind`] the engine runs without knowing its types; [`stored`] is how itemised
//! outputs and shards sit in the store; [`Registry`] maps names to kinds.

mod author;
mod ctx;
mod erased;
mod registry;
mod stored;

/// What a stage's `run` returns on failure; any error type converts into it.
pub type StageError = Box<dyn std::error::Error + Send + Sync>;

pub use author::{ItemStage, Kind, Numerics, Scale, Slot, Stage, Summarize, items_one_by_one};
pub use ctx::{CHECKPOINT_TAG, CheckpointIo, Ctx, Fold, InputBytes, Member, NoProgress, Progress};
pub use erased::{
    DynKind, KindInfo, ParamError, ParsedParams, RunEnv, RunOutput, ShardIo, ShardRun,
};
pub use registry::Registry;
pub use stored::{Manifest, Objects, Sharded, assemble};
