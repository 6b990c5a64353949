//! The API a stage kind is written against: the [`Kind`] trait with [`Stage`] or [`ItemStage`]
//! on top, their input [`Slot`]s and what its output implements ([`Summarize`]; an itemised
//! output's [`Sharded`](super::Sharded) is the store's). A running stage reads a
//! [`Ctx`](super::Ctx).

use osms_core::Artifact;
use osms_core::check::Check;
use osms_core::rng::StreamRng;
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::StageError;
use super::ctx::Ctx;
use super::stored::Sharded;

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

/// What every stage kind declares, whether it computes one artifact ([`Stage`]) or a list of
/// independent items ([`ItemStage`]): its name, version, inputs and params, and what the planner
/// reads from its params before anything runs.
pub trait Kind: Send + Sync + 'static {
    const KIND: &'static str;
    const CODE_VERSION: u32;
    /// Whether the stage can draw random numbers; if not, its key ignores the seed and seed
    /// sweeps share one build.
    const USES_RNG: bool;
    const INPUTS: &'static [Slot];
    const DOC: &'static str;
    /// Its [`Check`] refuses params that make no sense at plan time, naming the field and its
    /// valid range; non-finite numbers are refused for every kind before it runs.
    type Params: Serialize + DeserializeOwned + Check + Send + Sync + 'static;

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

/// A stage that computes one artifact.
pub trait Stage: Kind {
    type Output: Artifact + Summarize;

    fn run(&self, ctx: &Ctx<'_, Self::Params>) -> Result<Self::Output, StageError>;
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
pub trait ItemStage: Kind {
    /// Decoded inputs and anything built once per stage (e.g. a simulator model).
    type Prepared: Send + Sync;
    type Item: Serialize + DeserializeOwned + Send;
    /// Stored as a [`Manifest`](super::Manifest) of its items, each an object of its own.
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
