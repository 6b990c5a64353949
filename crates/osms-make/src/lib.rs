//! The pipeline engine: pipeline.toml to a typed stage graph, the stage-kind API, stage keys, a
//! sharded deterministic executor (local or Slurm), status, lineage, seed sweeps, overrides,
//! named experiments and cost estimates.
//!
//! Entry points: [`Pipeline::load`] reads the declaration, [`Plan::new`] checks it against a
//! [`Registry`] of stage kinds, [`make`] builds, [`status`] and [`why`] explain.

pub mod cost;
mod cpu;
mod error;
mod estimate;
mod exec;
pub mod executor;
pub mod experiment;
mod heads;
mod kind;
pub mod overrides;
mod pipeline;
mod plan;
mod remotes;
pub mod slurm;
mod status;

pub use cpu::{free_bytes, thread_secs as thread_cpu_secs};
pub use error::{Error, Invalid, Location, Result};
pub use estimate::{Estimate, InstanceEstimate, Measured, estimate, scales};
pub use exec::{
    Fetch, InstanceReport, MakeOptions, MakeReport, Observer, Outcome, Silent, StoreObjects, make,
    make_fetching, make_holding, storage_hint,
};
pub use heads::{ParamChange, Reason, describe};
pub use kind::{
    CHECKPOINT_TAG, CheckpointIo, Ctx, DynKind, Fold, InputBytes, ItemStage, Kind, KindInfo,
    Manifest, Member, NoProgress, Numerics, Objects, ParamError, ParsedParams, Progress, Registry,
    RunOutput, Scale, ShardRun, Sharded, Slot, Stage, StageError, Summarize, assemble,
    items_one_by_one,
};
pub use pipeline::{Pipeline, StageSpec};
pub use plan::{
    FoldRef, InputInstance, InstanceId, Plan, PlannedInput, PlannedStage, checkpoint_key,
    shard_key, shard_ranges,
};
pub use remotes::RemoteSpec;
pub use status::{InstanceStatus, Lineage, State, status, why};

/// The osms version recorded in every artifact's metadata.
pub const OSMS_VERSION: &str = exec::OSMS_VERSION;
