//! How an itemised stage's output is stored: each item an object of its own, listed by a
//! [`Manifest`] with the output's head, and each shard of a running make as the list of its
//! items' objects, so a killed make resumes from the shards it finished.

use osms_core::{Artifact, decode};
use osms_store::Hash;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::StageError;

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

/// The stored form of one item.
#[derive(Serialize, Deserialize)]
#[serde(transparent)]
pub(super) struct StoredItem<I>(pub(super) I);
impl<I: Serialize + DeserializeOwned> Artifact for StoredItem<I> {
    const TYPE_TAG: &'static str = "item";
    const SCHEMA_VERSION: u16 = 1;
}

pub(super) fn load_item<I: Serialize + DeserializeOwned>(
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

/// The stored form of one shard: the objects of the items it holds, in index order.
#[derive(Serialize, Deserialize)]
#[serde(transparent)]
pub(super) struct ShardItems(pub(super) Vec<Hash>);
impl Artifact for ShardItems {
    const TYPE_TAG: &'static str = "shard";
    const SCHEMA_VERSION: u16 = 2;
}

/// The output of an itemised kind: a head plus the items, in index order. The store keeps each
/// item once, as an object of its own, and the head in a [`Manifest`] that lists them, so a
/// large dataset is stored once and consumers can read it item by item ([`Ctx::items`](super::Ctx::items)).
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
