//! The last build of every instance (`state/heads/<instance>.json`), DVC's lock file in
//! spirit: what status compares against to say *why* an instance would run.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::fmt;

use osms_store::{Hash, Record, Store};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::plan::{InstanceId, Plan};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Head {
    pub key: Hash,
    pub content_hash: Hash,
    pub kind: String,
    pub code_version: u32,
    pub seed: Option<u64>,
    pub params: serde_json::Value,
    pub inputs: Vec<(String, Hash)>,
}

impl From<&Record> for Head {
    fn from(r: &Record) -> Self {
        Head {
            key: r.key,
            content_hash: r.content_hash,
            kind: r.kind.clone(),
            code_version: r.code_version,
            seed: r.seed,
            params: r.params.clone(),
            inputs: r.inputs.clone(),
        }
    }
}

/// One param whose value differs from the last build.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamChange {
    pub param: String,
    pub old: Option<serde_json::Value>,
    pub new: Option<serde_json::Value>,
}

/// Why an instance is not up to date (DVC's closed set of reasons, in osms's terms).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Reason {
    New,
    KindChanged {
        old: String,
        new: String,
    },
    CodeVersionBumped {
        old: u32,
        new: u32,
    },
    ParamsChanged {
        changes: Vec<ParamChange>,
    },
    InputChanged {
        slot: String,
        old: Option<Hash>,
        new: Hash,
    },
    SeedChanged {
        old: Option<u64>,
        new: Option<u64>,
    },
    NotInStore,
    ObjectMissing {
        hash: Hash,
    },
    ObjectDamaged {
        hash: Hash,
    },
    RecordUnreadable {
        key: Hash,
    },
    UpstreamNotUpToDate {
        input: String,
    },
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let short = |h: &Option<Hash>| h.map(|h| h.short()).unwrap_or_else(|| "none".into());
        match self {
            Reason::New => write!(f, "new: never built"),
            Reason::KindChanged { old, new } => write!(f, "kind changed: {old} -> {new}"),
            Reason::CodeVersionBumped { old, new } => {
                write!(f, "code version changed: {old} -> {new}")
            }
            Reason::ParamsChanged { changes } => {
                let parts: Vec<String> = changes
                    .iter()
                    .map(|c| {
                        let show = |v: &Option<serde_json::Value>| {
                            v.as_ref()
                                .map(|v| v.to_string())
                                .unwrap_or_else(|| "unset".into())
                        };
                        format!("{} ({} -> {})", c.param, show(&c.old), show(&c.new))
                    })
                    .collect();
                write!(f, "params changed: {}", parts.join(", "))
            }
            Reason::InputChanged { slot, old, new } => {
                write!(
                    f,
                    "input `{slot}` changed: {} -> {}",
                    short(old),
                    new.short()
                )
            }
            Reason::SeedChanged { old, new } => write!(f, "seed changed: {old:?} -> {new:?}"),
            Reason::NotInStore => write!(f, "not in the store"),
            Reason::ObjectMissing { hash } => write!(f, "object {} is missing", hash.short()),
            Reason::ObjectDamaged { hash } => write!(f, "object {} is damaged", hash.short()),
            Reason::RecordUnreadable { key } => {
                write!(f, "index record {} is unreadable", key.short())
            }
            Reason::UpstreamNotUpToDate { input } => write!(f, "input `{input}` is not up to date"),
        }
    }
}

/// Joins reasons for one-line display.
pub fn describe(reasons: &[Reason]) -> String {
    reasons
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

/// Lazily loaded heads; writes only when an instance's head changes.
pub struct Heads {
    cache: RefCell<BTreeMap<String, Option<Head>>>,
    store: Store,
}

fn file_name(instance: &str) -> String {
    format!("heads/{instance}.json")
}

impl Heads {
    pub fn load(store: &Store) -> Result<Self> {
        Ok(Heads {
            cache: RefCell::new(BTreeMap::new()),
            store: store.clone(),
        })
    }

    pub fn get(&self, instance: &str) -> Result<Option<Head>> {
        if let Some(h) = self.cache.borrow().get(instance) {
            return Ok(h.clone());
        }
        let head = self
            .store
            .read_state(&file_name(instance))?
            .and_then(|bytes| serde_json::from_slice::<Head>(&bytes).ok());
        self.cache
            .borrow_mut()
            .insert(instance.to_string(), head.clone());
        Ok(head)
    }

    pub fn update(&self, instance: &str, record: &Record) -> Result<()> {
        let head = Head::from(record);
        if self.get(instance)?.as_ref() == Some(&head) {
            return Ok(());
        }
        let mut text = serde_json::to_vec_pretty(&head).expect("heads serialise");
        text.push(b'\n');
        self.store.write_state(&file_name(instance), &text)?;
        self.cache
            .borrow_mut()
            .insert(instance.to_string(), Some(head));
        Ok(())
    }

    /// Why the instance, whose key is not in the store, must be built.
    pub fn reasons(
        &self,
        plan: &Plan,
        id: InstanceId,
        instance: &str,
        input_hashes: &[(String, Hash)],
    ) -> Vec<Reason> {
        let Ok(Some(head)) = self.get(instance) else {
            return vec![Reason::New];
        };
        let stage = &plan.stages[id.stage];
        let mut reasons = Vec::new();
        if head.kind != stage.info.name {
            reasons.push(Reason::KindChanged {
                old: head.kind.clone(),
                new: stage.info.name.to_string(),
            });
        } else if head.code_version != stage.info.code_version {
            reasons.push(Reason::CodeVersionBumped {
                old: head.code_version,
                new: stage.info.code_version,
            });
        }
        let mut changes = Vec::new();
        diff_json(
            "",
            Some(&head.params),
            Some(&stage.params.json),
            &mut changes,
        );
        if !changes.is_empty() {
            reasons.push(Reason::ParamsChanged { changes });
        }
        for (slot, new) in input_hashes {
            let old = head.inputs.iter().find(|(s, _)| s == slot).map(|(_, h)| *h);
            if old != Some(*new) {
                reasons.push(Reason::InputChanged {
                    slot: slot.clone(),
                    old,
                    new: *new,
                });
            }
        }
        let seed = plan.effective_seed(id);
        if head.seed != seed {
            reasons.push(Reason::SeedChanged {
                old: head.seed,
                new: seed,
            });
        }
        if reasons.is_empty() {
            reasons.push(Reason::NotInStore);
        }
        reasons
    }

    pub fn reason_to_build(
        &self,
        plan: &Plan,
        id: InstanceId,
        instance: &str,
        input_hashes: &[(String, Hash)],
    ) -> String {
        describe(&self.reasons(plan, id, instance, input_hashes))
    }
}

fn diff_json(
    path: &str,
    old: Option<&serde_json::Value>,
    new: Option<&serde_json::Value>,
    out: &mut Vec<ParamChange>,
) {
    use serde_json::Value;
    match (old, new) {
        (Some(Value::Object(a)), Some(Value::Object(b))) => {
            let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            for k in keys {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                diff_json(&p, a.get(k), b.get(k), out);
            }
        }
        (a, b) if a != b => out.push(ParamChange {
            param: path.to_string(),
            old: a.cloned(),
            new: b.cloned(),
        }),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_diff_names_nested_params() {
        let old = serde_json::json!({"n": 10, "scale": {"a": 1.0, "b": 2.0}, "gone": true});
        let new = serde_json::json!({"n": 20, "scale": {"a": 1.0, "b": 5.0}});
        let mut out = Vec::new();
        diff_json("", Some(&old), Some(&new), &mut out);
        let names: Vec<&str> = out.iter().map(|c| c.param.as_str()).collect();
        assert_eq!(names, ["gone", "n", "scale.b"]);
        let shown = Reason::ParamsChanged { changes: out }.to_string();
        assert_eq!(
            shown,
            "params changed: gone (true -> unset), n (10 -> 20), scale.b (2.0 -> 5.0)"
        );
    }
}
