//! The typed stage graph: a [`Pipeline`] checked against a [`Registry`], in dependency order,
//! and its instantiation for one or more run seeds.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use osms_store::Hash;
use serde::Serialize;

use crate::error::{Error, Result, list};
use crate::kind::{DynKind, KindInfo, ParsedParams, Registry};
use crate::pipeline::Pipeline;

/// One stage of the graph, independent of the run seed.
pub struct PlannedStage {
    pub name: String,
    pub kind: Arc<dyn DynKind>,
    pub info: KindInfo,
    pub params: ParsedParams,
    /// Input slot -> index of the upstream stage in [`Plan::stages`], in slot order.
    pub inputs: Vec<(String, usize)>,
    pub shards: u32,
    pub fixed_seed: Option<u64>,
    /// Whether the stage's output depends on the run seed, directly or through an input.
    pub seed_dependent: bool,
    /// Hash of what the declaration says (kind, code version, params, seed rule, input
    /// wiring): independent of any computed content, so identical on every platform.
    pub definition: Hash,
}

/// The stage graph in dependency order (ties broken by name).
pub struct Plan {
    pub stages: Vec<PlannedStage>,
    pub profile: String,
    pub default_seed: u64,
    index: BTreeMap<String, usize>,
}

/// A stage instantiated for a run seed. Seed-independent stages have one instance shared by
/// every seed of a sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct InstanceId {
    pub stage: usize,
    pub run_seed: Option<u64>,
}

impl Plan {
    pub fn new(pipeline: &Pipeline, registry: &Registry) -> Result<Self> {
        let order = topo_order(pipeline)?;
        let mut stages: Vec<PlannedStage> = Vec::with_capacity(order.len());
        let mut index = BTreeMap::new();
        for name in order {
            let spec = &pipeline.stages[&name];
            let kind = registry.get(&spec.kind).ok_or_else(|| {
                Error::invalid(
                    pipeline.locate(&["stages", &name, "kind"]),
                    format!("stage `{name}` has unknown kind `{}`", spec.kind),
                    Some(format!("known kinds are {}", list(registry.names()))),
                )
            })?;
            let info = kind.info();
            let stage_desc = format!("stage `{name}` (kind `{}`)", info.name);

            let declared: BTreeSet<&str> = info.inputs.iter().copied().collect();
            for slot in spec.inputs.keys() {
                if !declared.contains(slot.as_str()) {
                    return Err(Error::invalid(
                        pipeline.locate(&["stages", &name, "inputs", slot]),
                        format!("{stage_desc} has no input slot `{slot}`"),
                        Some(format!("its input slots are {}", list(info.inputs))),
                    ));
                }
            }
            let mut inputs = Vec::new();
            for slot in info.inputs {
                let upstream = spec.inputs.get(*slot).ok_or_else(|| {
                    Error::invalid(
                        pipeline.locate(&["stages", &name]),
                        format!("{stage_desc} is missing input `{slot}`"),
                        Some(format!("add `inputs = {{ {slot} = \"<stage>\" }}` to it")),
                    )
                })?;
                // topo_order already checked that every upstream exists and comes first.
                inputs.push((slot.to_string(), index[upstream]));
            }

            let params_value = toml::Value::Table(spec.params.clone());
            let params = kind.parse_params(params_value).map_err(|e| {
                let shown = if e.path.is_empty() {
                    String::new()
                } else {
                    format!(" `{}`", e.path.join("."))
                };
                let mut path = e.path.clone();
                // serde reports an unknown field at its parent; point at the field itself.
                if e.message.starts_with("unknown field")
                    && let Some(field) = e.message.split('`').nth(1)
                {
                    path.push(field.to_string());
                }
                Error::invalid(
                    pipeline.locate_param(&name, &path),
                    format!("{stage_desc}, param{shown}: {}", e.message),
                    None,
                )
            })?;

            if spec.shards == 0 || (spec.shards > 1 && !info.itemised) {
                let why = if spec.shards == 0 {
                    "shards must be at least 1".to_string()
                } else {
                    format!(
                        "kind `{}` computes one artifact and cannot be sharded",
                        info.name
                    )
                };
                return Err(Error::invalid(
                    pipeline
                        .locate(&["stages", &name, "shards"])
                        .or_else(|| pipeline.locate(&["stages", &name])),
                    format!("{stage_desc}: {why}"),
                    Some("remove `shards` or set it to 1".into()),
                ));
            }
            if spec.fixed_seed.is_some() && !info.uses_rng {
                return Err(Error::invalid(
                    pipeline.locate(&["stages", &name, "seed"]),
                    format!(
                        "{stage_desc} draws no random numbers, so a fixed `seed` means nothing"
                    ),
                    Some("remove `seed` from it".into()),
                ));
            }

            let seed_dependent = (info.uses_rng && spec.fixed_seed.is_none())
                || inputs
                    .iter()
                    .any(|(_, up): &(String, usize)| stages[*up].seed_dependent);
            let definition = {
                let mut h = blake3::Hasher::new_derive_key("osms stage definition v1");
                put_str(&mut h, info.name);
                h.update(&info.code_version.to_le_bytes());
                put_bytes(&mut h, &params.canonical);
                put_seed_rule(&mut h, info.uses_rng, spec.fixed_seed);
                if info.uses_rng {
                    put_str(&mut h, &name);
                }
                h.update(&(inputs.len() as u64).to_le_bytes());
                for (slot, up) in &inputs {
                    put_str(&mut h, slot);
                    h.update(stages[*up].definition.0.as_slice());
                }
                Hash::from(h.finalize())
            };
            index.insert(name.clone(), stages.len());
            stages.push(PlannedStage {
                name,
                kind: kind.clone(),
                info,
                params,
                inputs,
                shards: spec.shards,
                fixed_seed: spec.fixed_seed,
                seed_dependent,
                definition,
            });
        }
        Ok(Plan {
            stages,
            profile: pipeline.profile.clone(),
            default_seed: pipeline.default_seed,
            index,
        })
    }

    pub fn stage_index(&self, name: &str) -> Option<usize> {
        self.index.get(name).copied()
    }

    pub fn stage_names(&self) -> Vec<&str> {
        self.stages.iter().map(|s| s.name.as_str()).collect()
    }

    /// The instance of `stage` for `run_seed`.
    pub fn instance(&self, stage: usize, run_seed: u64) -> InstanceId {
        let s = &self.stages[stage];
        InstanceId {
            stage,
            run_seed: s.seed_dependent.then_some(run_seed),
        }
    }

    /// The seed a stage's random streams use, or `None` if it draws none.
    pub fn effective_seed(&self, id: InstanceId) -> Option<u64> {
        let s = &self.stages[id.stage];
        if !s.info.uses_rng {
            None
        } else {
            Some(
                s.fixed_seed
                    .or(id.run_seed)
                    .expect("seeded instances carry their run seed"),
            )
        }
    }

    /// How instances are named to people: `stage`, or `stage@seed` in the seed-dependent part.
    pub fn display(&self, id: InstanceId) -> String {
        let name = &self.stages[id.stage].name;
        match id.run_seed {
            Some(seed) => format!("{name}@{seed}"),
            None => name.clone(),
        }
    }

    pub fn input_instances(&self, id: InstanceId) -> Vec<(String, InstanceId)> {
        self.stages[id.stage]
            .inputs
            .iter()
            .map(|(slot, up)| {
                (
                    slot.clone(),
                    InstanceId {
                        stage: *up,
                        run_seed: if self.stages[*up].seed_dependent {
                            id.run_seed
                        } else {
                            None
                        },
                    },
                )
            })
            .collect()
    }

    /// The instances needed to build `targets` for `seeds`, in dependency order, each once. A
    /// target is a stage name (every seed of `seeds`) or `name@seed` (that seed only); no
    /// targets means every stage.
    pub fn instances(&self, targets: &[String], seeds: &[u64]) -> Result<Vec<InstanceId>> {
        let mut stack: Vec<InstanceId> = Vec::new();
        if targets.is_empty() {
            for &seed in seeds {
                stack.extend((0..self.stages.len()).map(|stage| self.instance(stage, seed)));
            }
        }
        for target in targets {
            let (name, seed) = match target.split_once('@') {
                Some((name, seed)) => {
                    let seed = seed.parse::<u64>().map_err(|_| {
                        Error::usage(format!(
                            "target `{target}`: `{seed}` is not a seed\nhint: write `stage@3`"
                        ))
                    })?;
                    (name, Some(seed))
                }
                None => (target.as_str(), None),
            };
            let stage = self.stage_index(name).ok_or_else(|| {
                Error::usage(format!(
                    "unknown target `{target}`\nhint: stages are {}",
                    list(self.stage_names())
                ))
            })?;
            match seed {
                Some(seed) => stack.push(self.instance(stage, seed)),
                None => stack.extend(seeds.iter().map(|&seed| self.instance(stage, seed))),
            }
        }
        let mut wanted = BTreeSet::new();
        while let Some(id) = stack.pop() {
            if wanted.insert(id) {
                stack.extend(self.input_instances(id).into_iter().map(|(_, up)| up));
            }
        }
        // Stage order is a topological order; seeds in ascending order within a stage.
        Ok(wanted.into_iter().collect())
    }

    /// The stage key (ARCHITECTURE.md, "Keys, hashes, seeds"): kind, code version, canonical
    /// params, input content hashes, effective seed and, for stages that draw random numbers,
    /// the stage name that names their streams.
    pub fn key(&self, id: InstanceId, input_hashes: &[(String, Hash)]) -> Hash {
        let s = &self.stages[id.stage];
        let mut h = blake3::Hasher::new_derive_key("osms stage key v1");
        put_str(&mut h, s.info.name);
        h.update(&s.info.code_version.to_le_bytes());
        put_bytes(&mut h, &s.params.canonical);
        h.update(&(input_hashes.len() as u64).to_le_bytes());
        for (slot, hash) in input_hashes {
            put_str(&mut h, slot);
            h.update(hash.0.as_slice());
        }
        match self.effective_seed(id) {
            Some(seed) => {
                h.update(&[1]);
                h.update(&seed.to_le_bytes());
                put_str(&mut h, &s.name);
            }
            None => {
                h.update(&[0]);
            }
        }
        Hash::from(h.finalize())
    }
}

/// The key of the shard holding items `[start, end)` of the stage with key `stage_key`.
pub fn shard_key(stage_key: &Hash, start: u64, end: u64) -> Hash {
    let mut h = blake3::Hasher::new_derive_key("osms shard key v1");
    h.update(stage_key.0.as_slice());
    h.update(&start.to_le_bytes());
    h.update(&end.to_le_bytes());
    Hash::from(h.finalize())
}

/// Splits `n` items into `shards` contiguous ranges whose sizes differ by at most one.
pub fn shard_ranges(n: usize, shards: u32) -> Vec<std::ops::Range<usize>> {
    let k = (shards as usize).clamp(1, n.max(1));
    let (base, extra) = (n / k, n % k);
    let mut start = 0;
    (0..k)
        .map(|i| {
            let len = base + usize::from(i < extra);
            let r = start..start + len;
            start += len;
            r
        })
        .collect()
}

fn put_bytes(h: &mut blake3::Hasher, bytes: &[u8]) {
    h.update(&(bytes.len() as u64).to_le_bytes());
    h.update(bytes);
}

fn put_str(h: &mut blake3::Hasher, s: &str) {
    put_bytes(h, s.as_bytes());
}

fn put_seed_rule(h: &mut blake3::Hasher, uses_rng: bool, fixed: Option<u64>) {
    match (uses_rng, fixed) {
        (false, _) => h.update(&[0]),
        (true, None) => h.update(&[1]),
        (true, Some(seed)) => h.update(&[2]).update(&seed.to_le_bytes()),
    };
}

/// Stage names in dependency order; errors name missing inputs and cycles.
fn topo_order(pipeline: &Pipeline) -> Result<Vec<String>> {
    for (name, spec) in &pipeline.stages {
        for (slot, upstream) in &spec.inputs {
            if !pipeline.stages.contains_key(upstream) {
                return Err(Error::invalid(
                    pipeline.locate(&["stages", name, "inputs", slot]),
                    format!(
                        "stage `{name}`: input `{slot}` refers to stage `{upstream}`, which is not declared"
                    ),
                    Some(format!(
                        "declared stages are {}",
                        list(pipeline.stages.keys())
                    )),
                ));
            }
        }
    }
    // Depth-first search in name order: deterministic, and a back edge gives the cycle itself.
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        name: &str,
        pipeline: &Pipeline,
        marks: &mut BTreeMap<String, Mark>,
        path: &mut Vec<String>,
        out: &mut Vec<String>,
    ) -> Result<()> {
        match marks[name] {
            Mark::Done => return Ok(()),
            Mark::Open => {
                let start = path.iter().position(|p| p == name).unwrap_or(0);
                let mut cycle: Vec<String> = path[start..].to_vec();
                cycle.push(name.to_string());
                return Err(Error::invalid(
                    pipeline.locate(&["stages", name, "inputs"]),
                    format!("stage `{name}` depends on itself: {}", cycle.join(" -> ")),
                    Some(
                        "a stage's inputs must come from stages that do not need its output".into(),
                    ),
                ));
            }
            Mark::New => {}
        }
        marks.insert(name.to_string(), Mark::Open);
        path.push(name.to_string());
        for upstream in pipeline.stages[name].inputs.values() {
            visit(upstream, pipeline, marks, path, out)?;
        }
        path.pop();
        marks.insert(name.to_string(), Mark::Done);
        out.push(name.to_string());
        Ok(())
    }
    let mut marks: BTreeMap<String, Mark> = pipeline
        .stages
        .keys()
        .map(|k| (k.clone(), Mark::New))
        .collect();
    let mut out = Vec::new();
    for name in pipeline.stages.keys() {
        visit(name, pipeline, &mut marks, &mut Vec::new(), &mut out)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_ranges_cover_in_order() {
        assert_eq!(shard_ranges(10, 3), vec![0..4, 4..7, 7..10]);
        assert_eq!(shard_ranges(2, 5), vec![0..1, 1..2]);
        assert_eq!(shard_ranges(0, 4), vec![0..0]);
        for n in 0..30 {
            for k in 1..7 {
                let r = shard_ranges(n, k);
                assert_eq!(r.first().map(|r| r.start), Some(0));
                assert_eq!(r.last().map(|r| r.end), Some(n));
                assert!(r.windows(2).all(|w| w[0].end == w[1].start));
            }
        }
    }
}
