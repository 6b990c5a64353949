//! Stage kinds with their types erased ([`DynKind`]): params parsed into their canonical
//! encoding, and a kind run (whole, or one shard of an itemised kind) over encoded inputs.

use std::any::Any;
use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;
use std::time::Instant;

use osms_core::check::Check;
use osms_core::rng;
use osms_core::{Artifact, decode, encode};
use osms_store::Hash;
use rayon::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::StageError;
use super::author::{ItemStage, Numerics, Scale, Slot, Stage, Summarize};
use super::ctx::{CheckpointIo, Ctx, Fold, InputBytes, Progress};
use super::stored::{Manifest, Objects, ShardItems, Sharded as _, StoredItem, assemble, load_item};

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
    pub checkpoints: &'a dyn CheckpointIo,
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
    /// How large a build with these params and input sizes is
    /// ([`Kind::scale`](super::Kind::scale)).
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
    /// Whether stored bytes still decode as this kind's output: for an itemised kind the
    /// manifest's head and its first item (items share one layout), for a plain kind the whole
    /// artifact. An artifact whose Rust layout changed without a schema bump fails here.
    fn check_output(&self, bytes: &[u8], objects: &dyn Objects) -> Result<(), StageError>;
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

/// The first non-finite number in `value` (a `nan` or `inf` given in TOML or by `--set`):
/// no param of any kind takes one.
fn non_finite(value: &toml::Value, path: &mut Vec<String>) -> Option<ParamError> {
    match value {
        toml::Value::Float(x) if !x.is_finite() => Some(ParamError {
            path: path.clone(),
            message: format!(
                "{} is not valid here: every param is a finite number",
                osms_core::check::shown(*x)
            ),
        }),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| {
            path.push(k.clone());
            let e = non_finite(v, path);
            path.pop();
            e
        }),
        toml::Value::Array(a) => a.iter().enumerate().find_map(|(i, v)| {
            path.push(i.to_string());
            let e = non_finite(v, path);
            path.pop();
            e
        }),
        _ => None,
    }
}

fn parse_typed<P: Serialize + DeserializeOwned + Check + Send + Sync + 'static>(
    value: toml::Value,
) -> Result<ParsedParams, ParamError> {
    if let Some(e) = non_finite(&value, &mut Vec::new()) {
        return Err(e);
    }
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
    typed.check().map_err(|e| ParamError {
        path: e.path,
        message: e.message,
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
            checkpoints: self.checkpoints,
        }
    }
}

pub(super) struct Plain<S>(pub(super) S);
pub(super) struct Itemised<S>(pub(super) S);

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
    fn check_output(&self, bytes: &[u8], _: &dyn Objects) -> Result<(), StageError> {
        decode::<S::Output>(bytes)?;
        Ok(())
    }
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
    fn check_output(&self, bytes: &[u8], objects: &dyn Objects) -> Result<(), StageError> {
        let manifest: Manifest<S::Output> = decode(bytes)?;
        if let Some(first) = manifest.items.first() {
            load_item::<S::Item>(objects, first)?;
        }
        Ok(())
    }
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
        let item_rng = |i: usize| match env.seed {
            Some(seed) => rng::stream(seed, env.stage, "item", i as u64),
            // Kinds without randomness still get a generator so the signature stays uniform. It
            // must not depend on the stage name, which such kinds' keys leave out.
            None => rng::stream(0, "", "item", i as u64),
        };
        let batch = self.0.batch_len(prepared).max(1);
        let batches = range
            .clone()
            .step_by(batch)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|first| {
                let end = (first + batch).min(range.end);
                let rngs = (first..end).map(item_rng).collect();
                let items = self.0.run_batch(ctx, prepared, first, rngs)?;
                if items.len() != end - first {
                    return Err(StageError::from(format!(
                        "items {first}..{end} came back as {} items",
                        items.len()
                    )));
                }
                env.progress.inc(items.len() as u64);
                Ok(items)
            })
            .collect::<Result<Vec<_>, StageError>>()?;
        let computed: Vec<S::Item> = batches.into_iter().flatten().collect();
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
