//! Stage kinds: the typed traits a stage implements, and their type-erased form in a
//! [`Registry`].
//!
//! A kind is registered in code with a name, an explicit code version (bump it whenever the
//! output for the same inputs may change), its input slots and a params struct. Plain kinds
//! ([`Stage`]) compute one artifact; itemised kinds ([`ItemStage`]) compute a list of
//! independent items that the executor can split into shards.

use std::any::Any;
use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;
use std::time::Instant;

use osms_core::{Artifact, decode, encode};
use osms_store::Hash;
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use osms_core::rng::{self, StreamRng};

/// What a stage's `run` returns on failure; any error type converts into it.
pub type StageError = Box<dyn std::error::Error + Send + Sync>;

/// Reports progress of a running stage.
pub trait Progress: Sync {
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

/// The stored form of an itemised stage's output: the object of every item, in index order,
/// and the head (the output without its items). Its type tag and schema are the head's: a
/// manifest is told from a plain artifact by the kind that produced it.
#[derive(Serialize, Deserialize)]
pub struct Manifest<H> {
    pub items: Vec<Hash>,
    pub head: H,
}

impl<H: Artifact> Artifact for Manifest<H> {
    const TYPE_TAG: &'static str = H::TYPE_TAG;
    const SCHEMA_VERSION: u16 = H::SCHEMA_VERSION;
}

/// Reads and writes objects of the store (verified by hash) for kinds that store or stream
/// items.
pub trait Objects: Sync {
    fn get(&self, hash: &Hash) -> Result<Vec<u8>, StageError>;
    fn put(&self, bytes: &[u8]) -> Result<Hash, StageError>;
}

/// The stored form of one item.
#[derive(Serialize, Deserialize)]
#[serde(transparent)]
struct StoredItem<I>(I);
impl<I: Serialize + DeserializeOwned> Artifact for StoredItem<I> {
    const TYPE_TAG: &'static str = "item";
    const SCHEMA_VERSION: u16 = 1;
}

fn load_item<I: Serialize + DeserializeOwned>(
    objects: &dyn Objects,
    hash: &Hash,
) -> Result<I, StageError> {
    Ok(decode::<StoredItem<I>>(&objects.get(hash)?)
        .map_err(|e| format!("item {}: {e}", hash.short()))?
        .0)
}

/// A sharded artifact with its items put back (what `osms show` and `export` render).
pub fn assemble<A: Sharded>(bytes: &[u8], objects: &dyn Objects) -> Result<A, StageError> {
    let manifest: Manifest<A> = decode(bytes)?;
    let items = manifest
        .items
        .iter()
        .map(|h| load_item::<A::Item>(objects, h))
        .collect::<Result<Vec<_>, _>>()?;
    let mut head = manifest.head;
    head.set_items(items);
    Ok(head)
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
    stage: &'a str,
    seed: Option<u64>,
    fold: Option<Fold>,
    inputs: &'a BTreeMap<String, Vec<InputBytes>>,
    objects: &'a dyn Objects,
    progress: &'a dyn Progress,
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
}

/// Canonical, typed params of one stage.
pub struct ParsedParams {
    /// postcard encoding of the typed struct, defaults included: this is what keys hash.
    pub canonical: Vec<u8>,
    /// The same values as JSON, for records, `status` diffs and `show`.
    pub json: serde_json::Value,
    typed: Arc<dyn Any + Send + Sync>,
}

/// Where an itemised stage keeps and finds its shards.
pub trait ShardIo: Sync {
    /// Splits `n_items` into the ranges that become shards.
    fn ranges(&self, n_items: usize) -> Vec<Range<usize>>;
    /// A previously stored shard, if one is intact.
    fn load(&self, range: &Range<usize>) -> Option<Vec<u8>>;
    /// Stores shard `index` (the list of its items' objects, `items`), computed in
    /// `wall_secs`, so a killed make resumes from it.
    fn save(
        &self,
        index: usize,
        range: &Range<usize>,
        bytes: Vec<u8>,
        items: Vec<Hash>,
        wall_secs: f64,
    ) -> Result<(), StageError>;
}

/// Everything a type-erased kind needs to run once.
pub struct RunEnv<'a> {
    /// The stream name of the instance (the stage, with `#fold` for folds).
    pub stage: &'a str,
    pub seed: Option<u64>,
    pub fold: Option<Fold>,
    pub params: &'a ParsedParams,
    pub inputs: &'a BTreeMap<String, Vec<InputBytes>>,
    pub objects: &'a dyn Objects,
    pub progress: &'a dyn Progress,
    pub shards: &'a dyn ShardIo,
}

/// What a kind's run produced: the encoded artifact and, for itemised kinds, the shard objects
/// its manifest lists.
pub struct RunOutput {
    pub bytes: Vec<u8>,
    pub parts: Vec<Hash>,
}

/// What [`DynKind::run_shard`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardRun {
    Computed {
        items: u64,
    },
    /// The shard was already in the store.
    Stored,
    /// The stage has fewer items than shards, and so no shard of this index.
    NoSuchShard {
        shards: u32,
    },
}

/// Static facts about a kind.
#[derive(Debug, Clone, Serialize)]
pub struct KindInfo {
    pub name: &'static str,
    pub code_version: u32,
    pub uses_rng: bool,
    pub inputs: &'static [Slot],
    pub doc: &'static str,
    pub itemised: bool,
    pub output_tag: &'static str,
    pub output_schema: u16,
    pub numerics: Vec<Numerics>,
}

/// A kind with its types erased.
pub trait DynKind: Send + Sync {
    fn info(&self) -> KindInfo;
    fn parse_params(&self, value: toml::Value) -> Result<ParsedParams, ParamError>;
    /// Whether a stage with these params draws random numbers.
    fn draws_randomness(&self, params: &ParsedParams) -> bool;
    /// The role of the output of a stage with these params.
    fn output_role(&self, params: &ParsedParams) -> Option<&'static str>;
    /// How large a build with these params and input sizes is ([`Stage::scale`]).
    fn scale(&self, params: &ParsedParams, inputs: &[(&str, f64)]) -> Scale;
    /// Runs the stage and returns the encoded output artifact.
    fn run(&self, env: &RunEnv<'_>) -> Result<RunOutput, StageError>;
    /// Computes and stores one shard of an itemised stage (a cluster array task); the merge
    /// is a later [`DynKind::run`], which finds every shard stored.
    fn run_shard(&self, _env: &RunEnv<'_>, _index: u32) -> Result<ShardRun, StageError> {
        Err(format!(
            "kind `{}` is not itemised: it has no shards",
            self.info().name
        )
        .into())
    }
    /// Decodes an output artifact of this kind (reading its shards from `objects`) and
    /// summarises it.
    fn summarize(
        &self,
        bytes: &[u8],
        objects: &dyn Objects,
    ) -> Result<serde_json::Value, StageError>;
    /// Decodes an output artifact of this kind and renders its text, if it has one.
    fn text(&self, bytes: &[u8], objects: &dyn Objects) -> Result<Option<String>, StageError>;
    /// Decodes an output artifact of this kind and renders its export files.
    fn files(
        &self,
        bytes: &[u8],
        objects: &dyn Objects,
    ) -> Result<Vec<(String, Vec<u8>)>, StageError>;
}

/// A param that did not deserialize: where (path of keys inside `params`) and why.
#[derive(Debug, Clone)]
pub struct ParamError {
    pub path: Vec<String>,
    pub message: String,
}

fn parse_typed<P: Serialize + DeserializeOwned + Send + Sync + 'static>(
    value: toml::Value,
) -> Result<ParsedParams, ParamError> {
    let typed: P = serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e
            .path()
            .iter()
            .filter_map(|seg| match seg {
                serde_path_to_error::Segment::Map { key } => Some(key.clone()),
                serde_path_to_error::Segment::Seq { index } => Some(index.to_string()),
                _ => None,
            })
            .collect();
        ParamError {
            path,
            message: e.into_inner().message().trim_end().to_string(),
        }
    })?;
    let canonical = postcard::to_stdvec(&typed).map_err(|e| ParamError {
        path: vec![],
        message: format!("params cannot be encoded canonically: {e}"),
    })?;
    let json = serde_json::to_value(&typed).map_err(|e| ParamError {
        path: vec![],
        message: format!("params cannot be shown as JSON: {e}"),
    })?;
    Ok(ParsedParams {
        canonical,
        json,
        typed: Arc::new(typed),
    })
}

impl ParsedParams {
    fn typed<P: 'static>(&self) -> &P {
        self.typed
            .downcast_ref::<P>()
            .expect("params were parsed by the same kind")
    }
}

impl RunEnv<'_> {
    fn ctx<P: 'static>(&self) -> Ctx<'_, P> {
        Ctx {
            params: self.params.typed(),
            stage: self.stage,
            seed: self.seed,
            fold: self.fold,
            inputs: self.inputs,
            objects: self.objects,
            progress: self.progress,
        }
    }
}

struct Plain<S>(S);
struct Itemised<S>(S);

/// The stored form of one shard: the objects of the items it holds, in index order.
#[derive(Serialize, Deserialize)]
#[serde(transparent)]
struct ShardItems(Vec<Hash>);
impl Artifact for ShardItems {
    const TYPE_TAG: &'static str = "shard";
    const SCHEMA_VERSION: u16 = 2;
}

/// The `DynKind` methods that read only the kind's constants and types, the same for plain and
/// itemised kinds; `S` is the kind's type parameter at the call site, `$open` decodes its
/// output (itemised outputs are manifests whose items live in shards).
macro_rules! shared_kind_methods {
    ($itemised:expr, $open:expr) => {
        fn info(&self) -> KindInfo {
            KindInfo {
                name: S::KIND,
                code_version: S::CODE_VERSION,
                uses_rng: S::USES_RNG,
                inputs: S::INPUTS,
                doc: S::DOC,
                itemised: $itemised,
                output_tag: <S::Output as Artifact>::TYPE_TAG,
                output_schema: <S::Output as Artifact>::SCHEMA_VERSION,
                numerics: S::numerics(),
            }
        }
        fn parse_params(&self, value: toml::Value) -> Result<ParsedParams, ParamError> {
            parse_typed::<S::Params>(value)
        }
        fn draws_randomness(&self, params: &ParsedParams) -> bool {
            S::USES_RNG && S::draws_randomness(params.typed::<S::Params>())
        }
        fn output_role(&self, params: &ParsedParams) -> Option<&'static str> {
            S::output_role(params.typed::<S::Params>())
        }
        fn scale(&self, params: &ParsedParams, inputs: &[(&str, f64)]) -> Scale {
            S::scale(params.typed::<S::Params>(), inputs)
        }
        fn summarize(
            &self,
            bytes: &[u8],
            objects: &dyn Objects,
        ) -> Result<serde_json::Value, StageError> {
            let open: fn(&[u8], &dyn Objects) -> Result<S::Output, StageError> = $open;
            Ok(open(bytes, objects)?.summary())
        }
        fn text(&self, bytes: &[u8], objects: &dyn Objects) -> Result<Option<String>, StageError> {
            let open: fn(&[u8], &dyn Objects) -> Result<S::Output, StageError> = $open;
            Ok(open(bytes, objects)?.text())
        }
        fn files(
            &self,
            bytes: &[u8],
            objects: &dyn Objects,
        ) -> Result<Vec<(String, Vec<u8>)>, StageError> {
            let open: fn(&[u8], &dyn Objects) -> Result<S::Output, StageError> = $open;
            Ok(open(bytes, objects)?.files())
        }
    };
}

impl<S: Stage> DynKind for Plain<S> {
    shared_kind_methods!(false, |bytes, _| Ok(decode(bytes)?));
    fn run(&self, env: &RunEnv<'_>) -> Result<RunOutput, StageError> {
        let ctx = env.ctx::<S::Params>();
        Ok(RunOutput {
            bytes: encode(&self.0.run(&ctx)?)?,
            parts: Vec::new(),
        })
    }
}

impl<S: ItemStage> DynKind for Itemised<S> {
    shared_kind_methods!(true, assemble);
    fn run(&self, env: &RunEnv<'_>) -> Result<RunOutput, StageError> {
        let ctx = env.ctx::<S::Params>();
        let prepared = self.0.prepare(&ctx)?;
        let n = self.0.n_items(&ctx, &prepared);
        env.progress.set_total(n as u64);
        let mut items = Vec::with_capacity(n);
        let mut hashes = Vec::with_capacity(n);
        for (index, range) in env.shards.ranges(n).into_iter().enumerate() {
            let (shard_hashes, shard_items) = match self.stored_shard(env, &range) {
                Some(stored) => {
                    env.progress.inc(range.len() as u64);
                    stored
                }
                None => self.compute_shard(env, &ctx, &prepared, index, &range)?,
            };
            hashes.extend(shard_hashes);
            items.extend(shard_items);
        }
        let mut head = self.0.merge(&ctx, prepared, items)?;
        // The items live in objects of their own; the manifest keeps the rest.
        drop(head.take_items());
        Ok(RunOutput {
            bytes: encode(&Manifest {
                items: hashes.clone(),
                head,
            })?,
            parts: hashes,
        })
    }

    fn run_shard(&self, env: &RunEnv<'_>, index: u32) -> Result<ShardRun, StageError> {
        let ctx = env.ctx::<S::Params>();
        let prepared = self.0.prepare(&ctx)?;
        let n = self.0.n_items(&ctx, &prepared);
        let ranges = env.shards.ranges(n);
        let Some(range) = ranges.get(index as usize) else {
            return Ok(ShardRun::NoSuchShard {
                shards: ranges.len() as u32,
            });
        };
        env.progress.set_total(range.len() as u64);
        if self.stored_shard(env, range).is_some() {
            return Ok(ShardRun::Stored);
        }
        self.compute_shard(env, &ctx, &prepared, index as usize, range)?;
        Ok(ShardRun::Computed {
            items: range.len() as u64,
        })
    }
}

impl<S: ItemStage> Itemised<S> {
    /// A finished shard of an interrupted make: its items' objects, if all are intact.
    fn stored_shard(
        &self,
        env: &RunEnv<'_>,
        range: &Range<usize>,
    ) -> Option<(Vec<Hash>, Vec<S::Item>)> {
        let bytes = env.shards.load(range)?;
        let shard = decode::<ShardItems>(&bytes).ok()?;
        let loaded = shard
            .0
            .iter()
            .map(|h| load_item::<S::Item>(env.objects, h))
            .collect::<Result<Vec<_>, _>>()
            .ok()?;
        (loaded.len() == range.len()).then_some((shard.0, loaded))
    }

    /// Computes the items of one shard in parallel, stores each and the shard.
    fn compute_shard(
        &self,
        env: &RunEnv<'_>,
        ctx: &Ctx<'_, S::Params>,
        prepared: &S::Prepared,
        index: usize,
        range: &Range<usize>,
    ) -> Result<(Vec<Hash>, Vec<S::Item>), StageError> {
        let started = Instant::now();
        let computed = range
            .clone()
            .into_par_iter()
            .map(|i| {
                let mut rng = match env.seed {
                    Some(seed) => rng::stream(seed, env.stage, "item", i as u64),
                    // Kinds without randomness still get a generator so the signature stays
                    // uniform. It must not depend on the stage name, which such kinds' keys
                    // leave out.
                    None => rng::stream(0, "", "item", i as u64),
                };
                let item = self.0.run_item(ctx, prepared, i, &mut rng);
                env.progress.inc(1);
                item
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut shard_hashes = Vec::with_capacity(computed.len());
        let mut shard_items = Vec::with_capacity(computed.len());
        for item in computed {
            let stored = StoredItem(item);
            shard_hashes.push(env.objects.put(&encode(&stored)?)?);
            shard_items.push(stored.0);
        }
        env.shards.save(
            index,
            range,
            encode(&ShardItems(shard_hashes.clone()))?,
            shard_hashes.clone(),
            started.elapsed().as_secs_f64(),
        )?;
        Ok((shard_hashes, shard_items))
    }
}

/// The stage kinds a program knows, by name.
#[derive(Default, Clone)]
pub struct Registry {
    kinds: BTreeMap<&'static str, Arc<dyn DynKind>>,
}

impl Registry {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn register<S: Stage>(&mut self, stage: S) -> &mut Self {
        self.insert(S::KIND, Arc::new(Plain(stage)))
    }

    pub fn register_itemised<S: ItemStage>(&mut self, stage: S) -> &mut Self {
        self.insert(S::KIND, Arc::new(Itemised(stage)))
    }

    fn insert(&mut self, name: &'static str, kind: Arc<dyn DynKind>) -> &mut Self {
        let previous = self.kinds.insert(name, kind);
        assert!(
            previous.is_none(),
            "stage kind `{name}` is registered twice"
        );
        self
    }

    pub fn get(&self, name: &str) -> Option<&Arc<dyn DynKind>> {
        self.kinds.get(name)
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.kinds.keys().copied().collect()
    }

    pub fn infos(&self) -> Vec<KindInfo> {
        self.kinds.values().map(|k| k.info()).collect()
    }
}
