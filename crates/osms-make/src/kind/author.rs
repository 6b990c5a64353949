//! The API a stage kind is written against: the [`Stage`] and [`ItemStage`] traits, their
//! input [`Slot`]s, the [`Ctx`] a running stage reads its params, inputs and random streams
//! from, and what its output implements ([`Summarize`], [`Sharded`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use osms_core::rng::{self, StreamRng};
use osms_core::{Artifact, decode};
use osms_store::Hash;
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::stored::{Manifest, assemble, load_item};

/// What a stage's `run` returns on failure; any error type converts into it.
pub type StageError = Box<dyn std::error::Error + Send + Sync>;

/// Reports progress of a running stage.
pub trait Progress: Send + Sync {
    fn set_total(&self, total: u64);
    fn inc(&self, n: u64);
}

/// Progress that goes nowhere (tests, `--no-progress`).
pub struct NoProgress;
impl Progress for NoProgress {
    fn set_total(&self, _: u64) {}
    fn inc(&self, _: u64) {}
}

/// A short, human-readable description of an artifact for `osms show`.
pub trait Summarize {
    fn summary(&self) -> serde_json::Value;
    /// A longer text rendering (e.g. a Markdown table), if the artifact has one.
    fn text(&self) -> Option<String> {
        None
    }
    /// Files `osms export` writes for this artifact (name, bytes), e.g. a table as Markdown,
    /// CSV and JSON.
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        Vec::new()
    }
}

/// The one table model of osms-core shows itself: its JSON, its Markdown under its title, and
/// its Markdown, CSV and JSON files.
impl Summarize for osms_core::table::Table {
    fn summary(&self) -> serde_json::Value {
        self.json()
    }
    fn text(&self) -> Option<String> {
        Some(format!("{}\n\n{}", self.title, self.markdown()))
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        osms_core::table::Table::files(self)
    }
}

/// One input slot of a kind: its name, the artifact type it takes and, for kinds that tell
/// artifacts of one type apart by role (datasets: D_M, D_E, D_R), the roles it accepts.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Slot {
    pub name: &'static str,
    /// The type tag of the artifact the slot takes ([`Artifact::TYPE_TAG`]).
    pub tag: &'static str,
    /// Roles it accepts; empty accepts any.
    pub roles: &'static [&'static str],
    /// A gather slot receives every instance its reference names (`stage@*`, `stage#*`),
    /// in a fixed order; a plain slot receives exactly one.
    pub gather: bool,
    /// A stage may leave an optional slot unwired ([`Ctx::has_input`] tells).
    pub optional: bool,
}

impl Slot {
    /// A slot that takes one artifact of type `A`.
    pub const fn one<A: Artifact>(name: &'static str) -> Slot {
        Slot {
            name,
            tag: A::TYPE_TAG,
            roles: &[],
            gather: false,
            optional: false,
        }
    }

    /// A slot that takes every instance its reference names (seeds, folds), each of type `A`.
    pub const fn gather<A: Artifact>(name: &'static str) -> Slot {
        Slot {
            gather: true,
            ..Slot::one::<A>(name)
        }
    }

    /// Only artifacts whose producing stage declares one of `roles`.
    pub const fn roles(self, roles: &'static [&'static str]) -> Slot {
        Slot { roles, ..self }
    }

    /// A slot the stage may leave unwired (the kind decides, from its params, whether it
    /// needs it).
    pub const fn optional(self) -> Slot {
        Slot {
            optional: true,
            ..self
        }
    }
}

/// A version that enters the keys of every kind whose output depends on it: a crate's
/// numerics (bump when its metrics, episode or kernel code may change bytes) or a library
/// loaded at run time (MuJoCo's own version string).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Numerics {
    pub name: &'static str,
    pub version: String,
}

/// The output of an itemised kind: a head plus the items, in index order. The store keeps each
/// item once, as an object of its own, and the head in a [`Manifest`] that lists them, so a
/// large dataset is stored once and consumers can read it item by item ([`Ctx::items`]).
/// Objects per item, not per shard, keep the manifest (and so every key downstream) the same
/// whatever the shard count.
pub trait Sharded: Artifact {
    type Item: Serialize + DeserializeOwned + Send + 'static;
    /// Moves the items out, leaving the head.
    fn take_items(&mut self) -> Vec<Self::Item>;
    /// Puts the items back into a head.
    fn set_items(&mut self, items: Vec<Self::Item>);
}

/// Reads and writes objects of the store (verified by hash) for kinds that store or stream
/// items.
pub trait Objects: Sync {
    fn get(&self, hash: &Hash) -> Result<Vec<u8>, StageError>;
    fn put(&self, bytes: &[u8]) -> Result<Hash, StageError>;
}

/// Where a long build keeps its latest checkpoint, under its stage key, so a build killed or
/// failed midway (a full disk, an I/O error) resumes from it instead of starting over.
pub trait CheckpointIo: Sync {
    /// The pipeline's `checkpoint_every` for the stage, if it declares one.
    fn every(&self) -> Option<u32>;
    /// The latest checkpoint of this stage key, as (steps done, bytes), if one is stored intact.
    fn load(&self) -> Option<(u64, Vec<u8>)>;
    /// Stores `bytes` as the checkpoint after `done` steps, replacing the previous one.
    fn save(&self, done: u64, bytes: Vec<u8>) -> Result<(), StageError>;
}

/// A stage that computes one artifact.
pub trait Stage: Send + Sync + 'static {
    const KIND: &'static str;
    const CODE_VERSION: u32;
    /// Whether the stage can draw random numbers; if not, its key ignores the seed and seed
    /// sweeps share one build.
    const USES_RNG: bool;
    const INPUTS: &'static [Slot];
    const DOC: &'static str;
    type Params: Serialize + DeserializeOwned + Send + Sync + 'static;
    type Output: Artifact + Summarize;

    fn run(&self, ctx: &Ctx<'_, Self::Params>) -> Result<Self::Output, StageError>;

    /// Whether a stage with these params draws random numbers (e.g. an evaluation with domain
    /// randomisation off draws none): if not, it is shared by every seed of a sweep.
    fn draws_randomness(_params: &Self::Params) -> bool {
        Self::USES_RNG
    }

    /// The role of the output (e.g. `d_m`), checked against the roles of the slots it feeds.
    fn output_role(_params: &Self::Params) -> Option<&'static str> {
        None
    }

    /// The numerics versions this kind's output depends on.
    fn numerics() -> Vec<Numerics> {
        Vec::new()
    }

    /// How large a build with these params and inputs is, for `osms plan`'s estimates.
    fn scale(_params: &Self::Params, inputs: &[(&str, f64)]) -> Scale {
        Scale::follow(inputs)
    }

    /// Refuses params that make no sense at plan time, naming the field and its valid range
    /// (`osms_core::check`). Non-finite numbers are refused for every kind before this runs.
    fn check_params(_params: &Self::Params) -> osms_core::check::Checked {
        Ok(())
    }
}

/// How large one build is, in units its kind chooses, for scaling a measured build's
/// core-seconds to another profile (`osms plan`): `work` is what its run time is proportional
/// to, `size` what the work of the stages it feeds grows with (e.g. a dataset's rollouts).
/// Only ratios between builds of one stage matter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Scale {
    pub work: f64,
    pub size: f64,
}

impl Scale {
    /// A stage that does as much work as its largest input is large, and is as large: an
    /// evaluation over conditions, a validation over rollouts, a table over evaluations.
    pub fn follow(inputs: &[(&str, f64)]) -> Scale {
        let largest = inputs.iter().map(|(_, s)| *s).fold(1.0, f64::max);
        Scale {
            work: largest,
            size: largest,
        }
    }

    /// `n` items, each one unit of work.
    pub fn items(n: f64) -> Scale {
        Scale { work: n, size: n }
    }

    /// The size of input slot `slot` (1 if absent).
    pub fn input(inputs: &[(&str, f64)], slot: &str) -> f64 {
        inputs
            .iter()
            .filter(|(s, _)| *s == slot)
            .map(|(_, v)| *v)
            .fold(0.0, f64::max)
            .max(1.0)
    }
}

/// A stage whose work is a list of independent items (e.g. rollouts). Item `i` draws from the
/// stream `("item", i)`, so the output does not depend on how items are split into shards or
/// threads.
pub trait ItemStage: Send + Sync + 'static {
    const KIND: &'static str;
    const CODE_VERSION: u32;
    const USES_RNG: bool;
    const INPUTS: &'static [Slot];
    const DOC: &'static str;
    type Params: Serialize + DeserializeOwned + Send + Sync + 'static;
    /// Decoded inputs and anything built once per stage (e.g. a simulator model).
    type Prepared: Send + Sync;
    type Item: Serialize + DeserializeOwned + Send;
    /// Stored as a [`Manifest`] of its items, each an object of its own.
    type Output: Sharded<Item = Self::Item> + Summarize;

    fn prepare(&self, ctx: &Ctx<'_, Self::Params>) -> Result<Self::Prepared, StageError>;
    fn n_items(&self, ctx: &Ctx<'_, Self::Params>, prepared: &Self::Prepared) -> usize;
    fn run_item(
        &self,
        ctx: &Ctx<'_, Self::Params>,
        prepared: &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<Self::Item, StageError>;
    fn merge(
        &self,
        ctx: &Ctx<'_, Self::Params>,
        prepared: Self::Prepared,
        items: Vec<Self::Item>,
    ) -> Result<Self::Output, StageError>;

    /// How many consecutive items one [`ItemStage::run_batch`] call computes (1: one by one).
    fn batch_len(&self, _prepared: &Self::Prepared) -> usize {
        1
    }

    /// Items `first .. first + rngs.len()`, item `first + k` drawing from `rngs[k]` (its
    /// `("item", i)` stream). A kind that batches (e.g. many episodes stepped in lockstep so a
    /// network acts on all of them at once) must return exactly what [`ItemStage::run_item`]
    /// would for each, so the output does not depend on the batch length; this default is
    /// [`items_one_by_one`].
    fn run_batch(
        &self,
        ctx: &Ctx<'_, Self::Params>,
        prepared: &Self::Prepared,
        first: usize,
        rngs: Vec<StreamRng>,
    ) -> Result<Vec<Self::Item>, StageError> {
        items_one_by_one(self, ctx, prepared, first, rngs)
    }

    /// As [`Stage::draws_randomness`].
    fn draws_randomness(_params: &Self::Params) -> bool {
        Self::USES_RNG
    }

    /// As [`Stage::output_role`].
    fn output_role(_params: &Self::Params) -> Option<&'static str> {
        None
    }

    /// As [`Stage::numerics`].
    fn numerics() -> Vec<Numerics> {
        Vec::new()
    }

    /// As [`Stage::scale`].
    fn scale(_params: &Self::Params, inputs: &[(&str, f64)]) -> Scale {
        Scale::follow(inputs)
    }

    /// As [`Stage::check_params`].
    fn check_params(_params: &Self::Params) -> osms_core::check::Checked {
        Ok(())
    }
}

/// Items `first ..` by [`ItemStage::run_item`], one by one: [`ItemStage::run_batch`]'s
/// default, and what an override that batches only some of its work runs for the rest.
pub fn items_one_by_one<S: ItemStage + ?Sized>(
    stage: &S,
    ctx: &Ctx<'_, S::Params>,
    prepared: &S::Prepared,
    first: usize,
    rngs: Vec<StreamRng>,
) -> Result<Vec<S::Item>, StageError> {
    rngs.into_iter()
        .enumerate()
        .map(|(k, mut rng)| stage.run_item(ctx, prepared, first + k, &mut rng))
        .collect()
}

/// Which fold of a stage declared with `folds = count` an instance is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Fold {
    pub index: u32,
    pub count: u32,
}

/// Which instance of its stage an input is: the run seed (seed-dependent stages) and the fold
/// (folded stages). Gather slots list their members in (fold, seed) order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct Member {
    pub fold: Option<u32>,
    pub seed: Option<u64>,
}

impl Member {
    /// `#fold@seed`, the suffix of the instance's name (empty for a stage's only instance).
    pub fn suffix(&self) -> String {
        let mut s = String::new();
        if let Some(f) = self.fold {
            s.push_str(&format!("#{f}"));
        }
        if let Some(seed) = self.seed {
            s.push_str(&format!("@{seed}"));
        }
        s
    }
}

/// One input artifact, encoded, with the instance it came from.
#[derive(Debug, Clone)]
pub struct InputBytes {
    pub member: Member,
    pub bytes: Arc<Vec<u8>>,
    /// The bytes are a [`Manifest`] (the producer is itemised).
    pub manifest: bool,
}

/// What a running stage sees: its params, its inputs, its random streams and a progress sink.
/// It runs inside the make's thread pool, so rayon's parallel iterators use `--jobs` threads.
pub struct Ctx<'a, P> {
    pub params: &'a P,
    pub(super) stage: &'a str,
    pub(super) seed: Option<u64>,
    pub(super) fold: Option<Fold>,
    pub(super) inputs: &'a BTreeMap<String, Vec<InputBytes>>,
    pub(super) objects: &'a dyn Objects,
    pub(super) progress: &'a dyn Progress,
    pub(super) checkpoints: &'a dyn CheckpointIo,
}

/// The type tag of checkpoints and of their records (whose `shard` names the build, and whose
/// `end` is the steps done).
pub const CHECKPOINT_TAG: &str = "checkpoint";

/// What a checkpoint holds: the state's type, so a checkpoint of another shape (a code change
/// within one code version) is not misread, and the state.
#[derive(Serialize, serde::Deserialize)]
struct CheckpointBytes<T> {
    type_name: String,
    state: T,
}

impl<T: Serialize + DeserializeOwned> Artifact for CheckpointBytes<T> {
    const TYPE_TAG: &'static str = CHECKPOINT_TAG;
    const SCHEMA_VERSION: u16 = 1;
}

impl<P> Ctx<'_, P> {
    /// The name that names this instance's random streams: the stage, with `#fold` for folds.
    pub fn stage(&self) -> &str {
        self.stage
    }

    /// The fold this instance is, for stages declared with `folds`.
    pub fn fold(&self) -> Option<Fold> {
        self.fold
    }

    /// Whether the optional input `slot` is wired.
    pub fn has_input(&self, slot: &str) -> bool {
        self.inputs.contains_key(slot)
    }

    fn slot(&self, slot: &str) -> Result<&[InputBytes], StageError> {
        self.inputs
            .get(slot)
            .map(Vec::as_slice)
            .ok_or_else(|| format!("stage `{}` has no input slot `{slot}`", self.stage).into())
    }

    fn one(&self, slot: &str) -> Result<&InputBytes, StageError> {
        match self.slot(slot)? {
            [one] => Ok(one),
            many => Err(format!(
                "input `{slot}` of stage `{}` is a gather slot with {} members: read it with `gathered`",
                self.stage,
                many.len()
            )
            .into()),
        }
    }

    /// Decodes the artifact bound to the plain input `slot`, produced by a kind that is not
    /// itemised (those are read with [`Ctx::sharded`], [`Ctx::head`] or [`Ctx::items`]).
    pub fn input<A: Artifact>(&self, slot: &str) -> Result<A, StageError> {
        let one = self.one(slot)?;
        if one.manifest {
            return Err(format!(
                "input `{slot}` of stage `{}` is sharded: read it with `sharded`, `head` or `items`",
                self.stage
            )
            .into());
        }
        decode(&one.bytes).map_err(|e| format!("input `{slot}`: {e}").into())
    }

    /// The whole artifact bound to `slot`, items included, whether its producer stored it
    /// sharded or not.
    pub fn sharded<A: Sharded>(&self, slot: &str) -> Result<A, StageError> {
        let one = self.one(slot)?;
        if one.manifest {
            assemble(&one.bytes, self.objects).map_err(|e| format!("input `{slot}`: {e}").into())
        } else {
            decode(&one.bytes).map_err(|e| format!("input `{slot}`: {e}").into())
        }
    }

    /// The artifact bound to `slot` without its items (cheap for sharded inputs).
    pub fn head<A: Sharded>(&self, slot: &str) -> Result<A, StageError> {
        let one = self.one(slot)?;
        let mut head = if one.manifest {
            decode::<Manifest<A>>(&one.bytes)
                .map_err(|e| format!("input `{slot}`: {e}"))?
                .head
        } else {
            decode::<A>(&one.bytes).map_err(|e| format!("input `{slot}`: {e}"))?
        };
        head.take_items();
        Ok(head)
    }

    /// The items of the artifact bound to `slot`, in index order, decoded one at a time.
    pub fn items<A: Sharded>(
        &self,
        slot: &str,
    ) -> Result<impl Iterator<Item = Result<A::Item, StageError>> + '_, StageError> {
        let one = self.one(slot)?;
        let (stored, whole) = if one.manifest {
            let manifest: Manifest<A> =
                decode(&one.bytes).map_err(|e| format!("input `{slot}`: {e}"))?;
            (manifest.items, Vec::new())
        } else {
            let mut whole: A = decode(&one.bytes).map_err(|e| format!("input `{slot}`: {e}"))?;
            (Vec::new(), whole.take_items())
        };
        let objects = self.objects;
        let slot = slot.to_string();
        let streamed = stored.into_iter().map(move |hash| {
            load_item::<A::Item>(objects, &hash).map_err(|e| format!("input `{slot}`: {e}").into())
        });
        Ok(whole.into_iter().map(Ok).chain(streamed))
    }

    /// Decodes every artifact of the gather slot `slot`, in (fold, seed) order.
    pub fn gathered<A: Artifact>(&self, slot: &str) -> Result<Vec<(Member, A)>, StageError> {
        self.slot(slot)?
            .iter()
            .map(|i| {
                decode(&i.bytes)
                    .map(|a| (i.member, a))
                    .map_err(|e| format!("input `{slot}{}`: {e}", i.member.suffix()).into())
            })
            .collect()
    }

    /// Every artifact of the gather slot `slot` with its items, in (fold, seed) order: for
    /// gathers of itemised stages, whose artifacts are stored as manifests.
    pub fn gathered_sharded<A: Sharded>(&self, slot: &str) -> Result<Vec<(Member, A)>, StageError> {
        self.slot(slot)?
            .iter()
            .map(|i| {
                let a: Result<A, String> = if i.manifest {
                    assemble(&i.bytes, self.objects).map_err(|e| e.to_string())
                } else {
                    decode(&i.bytes).map_err(|e| e.to_string())
                };
                a.map(|a| (i.member, a))
                    .map_err(|e| format!("input `{slot}{}`: {e}", i.member.suffix()).into())
            })
            .collect()
    }

    /// The generator of stream (`name`, `index`) of this stage.
    pub fn rng(&self, name: &str, index: u64) -> StreamRng {
        self.stream_id(name, index).rng()
    }

    /// The name of stream (`name`, `index`) of this stage, to store with what it draws.
    pub fn stream_id(&self, name: &str, index: u64) -> rng::StreamId {
        let seed = self.seed.unwrap_or_else(|| {
            panic!(
                "stage `{}` draws no random numbers (its kind's USES_RNG or draws_randomness) but asked for a stream",
                self.stage
            )
        });
        rng::StreamId {
            seed,
            stage: self.stage.to_string(),
            name: name.to_string(),
            index,
        }
    }

    /// The run seed, for code that derives its own streams with [`rng::stream`] from
    /// (seed, [`Ctx::stage`]); `None` for kinds that declare `USES_RNG = false`.
    pub fn seed(&self) -> Option<u64> {
        self.seed
    }

    pub fn progress(&self) -> &dyn Progress {
        self.progress
    }

    /// Every how many of its steps a kind that checkpoints writes one: the stage's
    /// `checkpoint_every` in pipeline.toml, else the kind's `default`.
    pub fn checkpoint_every(&self, default: u32) -> u32 {
        self.checkpoints.every().unwrap_or(default).max(1)
    }

    /// The state the last checkpoint of this very build (same stage key) holds: a build that
    /// was killed or failed resumes from it. One that does not decode as `T` is ignored with a
    /// warning, and the build starts over.
    pub fn resume<T: Serialize + DeserializeOwned>(&self) -> Option<T> {
        let (done, bytes) = self.checkpoints.load()?;
        match decode::<CheckpointBytes<T>>(&bytes) {
            Ok(c) if c.type_name == std::any::type_name::<T>() => {
                tracing::info!(
                    "{}: resuming from its checkpoint after {done} steps",
                    self.stage
                );
                Some(c.state)
            }
            _ => {
                tracing::warn!(
                    "{}: ignoring a checkpoint that does not decode as {}; starting over",
                    self.stage,
                    std::any::type_name::<T>()
                );
                None
            }
        }
    }

    /// Stores `state` as this build's checkpoint after `done` steps. It must hold everything
    /// the rest of the build reads, so that a resumed build's bytes equal an uninterrupted
    /// one's.
    pub fn checkpoint<T: Serialize>(&self, done: u64, state: &T) -> Result<(), StageError> {
        let view = CheckpointBytes {
            type_name: std::any::type_name::<T>().to_string(),
            state,
        };
        let bytes = osms_core::encode_as(
            CHECKPOINT_TAG,
            <CheckpointBytes<()> as Artifact>::SCHEMA_VERSION,
            &view,
        )
        .map_err(|e| format!("cannot encode the checkpoint after {done} steps: {e}"))?;
        self.checkpoints.save(done, bytes)
    }
}
