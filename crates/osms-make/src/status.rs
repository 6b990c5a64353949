//! `osms status` and `osms why`: what is up to date, what is not and why, and where an
//! artifact came from. Read-only: takes no lock, builds nothing.

use std::collections::BTreeMap;

use osms_store::{Hash, ObjectState, Store};
use serde::Serialize;

use crate::error::Result;
use crate::exec::{readable_record, record_state};
use crate::heads::{Heads, Reason};
use crate::plan::{InstanceId, Plan};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Its key is in the store and the object is intact.
    Cached,
    /// Built before, but something it depends on changed.
    Stale,
    /// Never built, or its object is gone or damaged, or its index record unreadable.
    Missing,
}

#[derive(Debug, Clone, Serialize)]
pub struct InstanceStatus {
    pub instance: String,
    pub stage: String,
    pub kind: String,
    pub state: State,
    /// Unknown while an input is not up to date (the key hashes the input's content).
    pub key: Option<Hash>,
    pub content_hash: Option<Hash>,
    pub reasons: Vec<Reason>,
    #[serde(skip)]
    pub id: InstanceId,
}

/// The status of every instance needed for `targets` and `seeds`, in dependency order.
pub fn status(
    plan: &Plan,
    store: &Store,
    targets: &[String],
    seeds: &[u64],
) -> Result<Vec<InstanceStatus>> {
    let heads = Heads::load(store)?;
    let mut out: Vec<InstanceStatus> = Vec::new();
    let mut known: BTreeMap<InstanceId, Hash> = BTreeMap::new();
    for id in plan.instances(targets, seeds)? {
        let stage = &plan.stages[id.stage];
        let instance = plan.display(id);
        let mut input_hashes = Vec::new();
        let mut reasons = Vec::new();
        for input in plan.input_instances(id, seeds) {
            match known.get(&input.id) {
                Some(h) => input_hashes.push((input.label, *h)),
                None => reasons.push(Reason::UpstreamNotUpToDate {
                    input: plan.display(input.id),
                }),
            }
        }
        let mut st = InstanceStatus {
            instance: instance.clone(),
            stage: stage.name.clone(),
            kind: stage.info.name.to_string(),
            state: State::Stale,
            key: None,
            content_hash: None,
            reasons: Vec::new(),
            id,
        };
        if !reasons.is_empty() {
            // Built before under any key? Then it is stale rather than missing.
            st.state = if heads.get(&instance)?.is_some() {
                State::Stale
            } else {
                State::Missing
            };
            st.reasons = reasons;
            out.push(st);
            continue;
        }
        let key = plan.key(id, &input_hashes);
        st.key = Some(key);
        match readable_record(store, &key)? {
            Err(unreadable) => {
                st.state = State::Missing;
                st.reasons = vec![unreadable];
            }
            Ok(Some(rec)) => match record_state(store, &rec)? {
                (_, ObjectState::Present) => {
                    st.state = State::Cached;
                    st.content_hash = Some(rec.content_hash);
                    known.insert(id, rec.content_hash);
                }
                (hash, ObjectState::Missing) => {
                    st.state = State::Missing;
                    st.reasons = vec![Reason::ObjectMissing { hash }];
                }
                (hash, ObjectState::Damaged { .. }) => {
                    st.state = State::Missing;
                    st.reasons = vec![Reason::ObjectDamaged { hash }];
                }
            },
            Ok(None) => {
                st.reasons = heads.reasons(plan, id, &instance, &input_hashes);
                st.state = if st.reasons == [Reason::New] {
                    State::Missing
                } else {
                    State::Stale
                };
            }
        }
        out.push(st);
    }
    store.save_stat_cache();
    Ok(out)
}

/// One node of a lineage tree.
#[derive(Debug, Clone, Serialize)]
pub struct Lineage {
    pub slot: Option<String>,
    #[serde(flatten)]
    pub status: InstanceStatus,
    pub inputs: Vec<Lineage>,
}

/// The lineage of `target` (a stage name, optionally with `#fold` and `@seed`) for `seeds`
/// (a gather over run seeds takes every one of them).
pub fn why(plan: &Plan, store: &Store, target: &str, seeds: &[u64]) -> Result<Lineage> {
    let statuses = status(plan, store, &[target.to_string()], seeds)?;
    // `status` resolved the target; its instance comes last in dependency order.
    let root = statuses
        .last()
        .map(|s| s.id)
        .expect("a target has at least one instance");
    let by_id: BTreeMap<InstanceId, &InstanceStatus> = statuses.iter().map(|s| (s.id, s)).collect();
    fn node(
        plan: &Plan,
        seeds: &[u64],
        by_id: &BTreeMap<InstanceId, &InstanceStatus>,
        id: InstanceId,
        slot: Option<String>,
    ) -> Lineage {
        Lineage {
            slot,
            status: by_id[&id].clone(),
            inputs: plan
                .input_instances(id, seeds)
                .into_iter()
                .map(|i| node(plan, seeds, by_id, i.id, Some(i.label)))
                .collect(),
        }
    }
    Ok(node(plan, seeds, &by_id, root, None))
}
