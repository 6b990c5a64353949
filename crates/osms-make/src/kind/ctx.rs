//! What a running stage sees: the [`Ctx`] it reads its params, inputs (with the instance each
//! came from) and random streams from, where it reports progress and keeps its checkpoints.

use std::collections::BTreeMap;
use std::sync::Arc;

use osms_core::rng::{self, StreamRng};
use osms_core::{Artifact, decode};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::StageError;
use super::stored::{Manifest, Objects, Sharded, assemble, load_item};

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
