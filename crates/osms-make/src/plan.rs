//! The typed stage graph: a [`Pipeline`] checked against a [`Registry`], in dependency order,
//! and its instantiation for one or more run seeds.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use osms_store::Hash;
use serde::Serialize;

use crate::error::{Error, Result, list};
use crate::kind::{DynKind, Fold, KindInfo, Member, ParamError, ParsedParams, Registry};
use crate::overrides::{Field, Override};
use crate::pipeline::Pipeline;

/// One stage of the graph, independent of the run seed.
pub struct PlannedStage {
    pub name: String,
    pub kind: Arc<dyn DynKind>,
    pub info: KindInfo,
    pub params: ParsedParams,
    /// One entry per input slot, in the kind's slot order.
    pub inputs: Vec<PlannedInput>,
    pub shards: u32,
    /// `Some(n)`: instances `name#0` .. `name#n-1` per run seed.
    pub folds: Option<u32>,
    pub fixed_seed: Option<u64>,
    /// `checkpoint_every` as declared (`None`: the kind's own interval).
    pub checkpoint_every: Option<u32>,
    /// Whether the stage draws random numbers with these params.
    pub uses_rng: bool,
    /// The role its output plays (e.g. `d_m`), as its kind reads it from the params.
    pub role: Option<&'static str>,
    /// Whether the stage's output depends on the run seed, directly or through an input that
    /// is not a gather over seeds.
    pub seed_dependent: bool,
    /// Hash of what the declaration says (kind, code version, output schema, numerics,
    /// params, seed rule, folds, input wiring): independent of any computed content, so
    /// identical on every platform.
    pub definition: Hash,
    /// `~k` for a variant of the stage that a sweep's point k introduced ([`Plan::merge`]):
    /// part of how its instances are shown and targeted, never of its keys or streams.
    pub variant: Option<String>,
}

/// Which folds of a folded upstream an input takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FoldRef {
    /// The consumer's own fold (or the upstream's only instance, if it has no folds).
    Same,
    /// `stage#k`.
    Fixed(u32),
    /// `stage#*`.
    All,
}

/// One input slot, wired to an upstream stage by a reference such as `d_e`, `pibar#*`,
/// `eval_student@*`.
pub struct PlannedInput {
    pub slot: String,
    pub upstream: usize,
    /// The reference as written in pipeline.toml.
    pub reference: String,
    pub folds: FoldRef,
    /// `@*`: every run seed of the sweep (a gather).
    pub all_seeds: bool,
    pub gather: bool,
}

/// The stage graph in dependency order (ties broken by name).
pub struct Plan {
    pub stages: Vec<PlannedStage>,
    pub profile: String,
    /// The run seeds when none are given.
    pub default_seeds: Vec<u64>,
    /// The targets of a make given none (empty: every stage).
    pub default_targets: Vec<String>,
    /// The targets of an experiment given none.
    pub experiment_targets: Vec<String>,
    /// `[pipeline] held_out`: stages experiments should not read.
    pub held_out: Vec<String>,
    /// `[executor]` of the pipeline (a user config may overlay it).
    pub executor: crate::executor::ExecutorConfig,
    /// `[remotes.NAME]` of the pipeline (a user config may add or replace some).
    pub remotes: BTreeMap<String, crate::remotes::RemoteSpec>,
    /// `[pipeline] remote`.
    pub default_remote: Option<String>,
    /// Whether a make of this plan records what it built as the instances' heads (what
    /// `status` compares against). Off for experiments, whose variants leave them be.
    pub record_heads: bool,
    index: BTreeMap<String, usize>,
}

/// A stage instantiated for a run seed and fold. Seed-independent stages have one instance
/// (per fold) shared by every seed of a sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct InstanceId {
    pub stage: usize,
    pub fold: Option<u32>,
    pub run_seed: Option<u64>,
}

impl InstanceId {
    pub fn member(&self) -> Member {
        Member {
            fold: self.fold,
            seed: self.run_seed,
        }
    }
}

/// One input instance of an instance: the slot, the label its content hash is recorded
/// under (the slot, or `slot[#fold@seed]` for a gather's members) and the instance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputInstance {
    pub slot: String,
    pub label: String,
    pub id: InstanceId,
}

/// `name`, `name#k`, `name#*`, each optionally followed by `@*`.
struct Reference<'a> {
    stage: &'a str,
    folds: FoldRef,
    all_seeds: bool,
}

fn parse_reference(text: &str) -> std::result::Result<Reference<'_>, String> {
    let (rest, all_seeds) = match text.split_once('@') {
        Some((rest, "*")) => (rest, true),
        Some((_, other)) => {
            return Err(format!(
                "`@{other}`: an input takes every run seed (`@*`) or the consumer's own (no `@`)"
            ));
        }
        None => (text, false),
    };
    let (stage, folds) = match rest.split_once('#') {
        Some((stage, "*")) => (stage, FoldRef::All),
        Some((stage, k)) => match k.parse::<u32>() {
            Ok(k) => (stage, FoldRef::Fixed(k)),
            Err(_) => {
                return Err(format!(
                    "`#{k}` is not a fold: write `#0`, `#1`, ... or `#*`"
                ));
            }
        },
        None => (rest, FoldRef::Same),
    };
    Ok(Reference {
        stage,
        folds,
        all_seeds,
    })
}

impl Plan {
    pub fn new(pipeline: &Pipeline, registry: &Registry) -> Result<Self> {
        let order = topo_order(pipeline)?;
        let mut stages: Vec<PlannedStage> = Vec::with_capacity(order.len());
        let mut index: BTreeMap<String, usize> = BTreeMap::new();
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
            let slot_names = || list(info.inputs.iter().map(|s| s.name));

            for slot in spec.inputs.keys() {
                if !info.inputs.iter().any(|s| s.name == slot) {
                    return Err(Error::invalid(
                        pipeline.locate(&["stages", &name, "inputs", slot]),
                        format!("{stage_desc} has no input slot `{slot}`"),
                        Some(format!("its input slots are {}", slot_names())),
                    ));
                }
            }
            if spec.folds == Some(0) {
                return Err(Error::invalid(
                    pipeline.locate(&["stages", &name, "folds"]),
                    format!("{stage_desc}: folds must be at least 1"),
                    Some("remove `folds` or set it to 2 or more".into()),
                ));
            }

            let params = parse_params(pipeline, &name, &stage_desc, kind.as_ref())?;

            let mut inputs = Vec::new();
            for slot in info.inputs {
                if slot.optional && !spec.inputs.contains_key(slot.name) {
                    continue;
                }
                let reference = spec.inputs.get(slot.name).ok_or_else(|| {
                    Error::invalid(
                        pipeline.locate(&["stages", &name]),
                        format!("{stage_desc} is missing input `{}`", slot.name),
                        Some(format!(
                            "add `inputs = {{ {} = \"<stage>\" }}` to it",
                            slot.name
                        )),
                    )
                })?;
                let at = || pipeline.locate(&["stages", &name, "inputs", slot.name]);
                let input_desc = format!("{stage_desc}, input `{}` = \"{reference}\"", slot.name);
                // topo_order already checked the reference and that its stage comes first.
                let r = parse_reference(reference)
                    .map_err(|e| Error::invalid(at(), format!("{input_desc}: {e}"), None))?;
                let up = &stages[index[r.stage]];
                if up.info.output_tag != slot.tag {
                    return Err(Error::invalid(
                        at(),
                        format!(
                            "{input_desc}: the slot takes a `{}` artifact, but stage `{}` (kind `{}`) produces a `{}`",
                            slot.tag, up.name, up.info.name, up.info.output_tag
                        ),
                        Some(format!(
                            "wire a stage whose kind produces `{}` ({})",
                            slot.tag,
                            list(
                                stages
                                    .iter()
                                    .filter(|s| s.info.output_tag == slot.tag)
                                    .map(|s| s.name.as_str())
                            )
                        )),
                    ));
                }
                if !slot.roles.is_empty() && !up.role.is_some_and(|r| slot.roles.contains(&r)) {
                    return Err(Error::invalid(
                        at(),
                        format!(
                            "{input_desc}: the slot takes role {}, but stage `{}` produces {}",
                            list(slot.roles),
                            up.name,
                            up.role
                                .map(|r| format!("role `{r}`"))
                                .unwrap_or_else(|| "an artifact without a role".into())
                        ),
                        Some(format!("wire a stage with role {}", list(slot.roles))),
                    ));
                }
                match (r.folds, up.folds, spec.folds) {
                    (FoldRef::Same, Some(n), consumer) if consumer != Some(n) => {
                        return Err(Error::invalid(
                            at(),
                            format!(
                                "{input_desc}: stage `{}` has {n} folds, and this stage {}",
                                up.name,
                                match consumer {
                                    Some(m) => format!("has {m}"),
                                    None => "has none".to_string(),
                                }
                            ),
                            Some(format!(
                                "take every fold with `{0}#*` (a gather slot) or one with `{0}#0`",
                                up.name
                            )),
                        ));
                    }
                    (FoldRef::Fixed(_) | FoldRef::All, None, _) => {
                        return Err(Error::invalid(
                            at(),
                            format!("{input_desc}: stage `{}` has no folds", up.name),
                            Some(format!("write `{}`", r.stage)),
                        ));
                    }
                    (FoldRef::Fixed(k), Some(n), _) if k >= n => {
                        return Err(Error::invalid(
                            at(),
                            format!(
                                "{input_desc}: stage `{}` has folds #0 to #{}",
                                up.name,
                                n - 1
                            ),
                            None,
                        ));
                    }
                    _ => {}
                }
                if !slot.gather && (r.all_seeds || r.folds == FoldRef::All) {
                    return Err(Error::invalid(
                        at(),
                        format!(
                            "{input_desc}: `{}` takes one artifact, but the reference names several",
                            slot.name
                        ),
                        Some(format!("remove `@*` / `#*`: write `{}`", r.stage)),
                    ));
                }
                inputs.push(PlannedInput {
                    slot: slot.name.to_string(),
                    upstream: index[r.stage],
                    reference: reference.clone(),
                    folds: r.folds,
                    all_seeds: r.all_seeds,
                    gather: slot.gather,
                });
            }

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
            if spec.checkpoint_every == Some(0) {
                return Err(Error::invalid(
                    pipeline
                        .locate(&["stages", &name, "checkpoint_every"])
                        .or_else(|| pipeline.locate(&["stages", &name])),
                    format!("{stage_desc}: checkpoint_every must be at least 1"),
                    Some("remove `checkpoint_every` to use the kind's own interval".into()),
                ));
            }
            let uses_rng = kind.draws_randomness(&params);
            if spec.fixed_seed.is_some() && !uses_rng {
                return Err(Error::invalid(
                    pipeline.locate(&["stages", &name, "seed"]),
                    format!(
                        "{stage_desc} draws no random numbers with these params, so a fixed `seed` means nothing"
                    ),
                    Some("remove `seed` from it".into()),
                ));
            }
            let role = kind.output_role(&params);

            let seed_dependent = (uses_rng && spec.fixed_seed.is_none())
                || inputs
                    .iter()
                    .any(|i| !i.all_seeds && stages[i.upstream].seed_dependent);
            let definition = {
                let mut h = blake3::Hasher::new_derive_key("osms stage definition v2");
                put_kind(&mut h, &info);
                put_bytes(&mut h, &params.canonical);
                put_seed_rule(&mut h, uses_rng, spec.fixed_seed);
                if uses_rng {
                    put_str(&mut h, &name);
                }
                put_folds(&mut h, spec.folds.map(|n| (None, n)));
                h.update(&(inputs.len() as u64).to_le_bytes());
                for i in &inputs {
                    put_str(&mut h, &i.slot);
                    put_str(&mut h, &i.reference);
                    h.update(stages[i.upstream].definition.0.as_slice());
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
                folds: spec.folds,
                fixed_seed: spec.fixed_seed,
                checkpoint_every: spec.checkpoint_every,
                uses_rng,
                role,
                seed_dependent,
                definition,
                variant: None,
            });
        }
        let lists = [
            ("targets", &pipeline.default_targets),
            ("experiment_targets", &pipeline.experiment_targets),
            ("held_out", &pipeline.held_out),
        ];
        for (field, targets) in lists {
            for target in targets {
                let name = target.split(['#', '@']).next().unwrap_or_default();
                if !index.contains_key(name) {
                    return Err(Error::invalid(
                        pipeline.locate(&["pipeline", field]),
                        format!("[pipeline] {field}: `{target}` is not a declared stage"),
                        Some(format!(
                            "declared stages are {}",
                            crate::error::list(index.keys())
                        )),
                    ));
                }
            }
        }
        Ok(Plan {
            stages,
            profile: pipeline.profile.clone(),
            default_seeds: pipeline.default_seeds.clone(),
            default_targets: pipeline.default_targets.clone(),
            experiment_targets: pipeline.experiment_targets.clone(),
            held_out: pipeline.held_out.clone(),
            executor: pipeline.executor.clone(),
            remotes: pipeline.remotes.clone(),
            default_remote: pipeline.default_remote.clone(),
            record_heads: true,
            index,
        })
    }

    /// One graph for the points of a sweep: a stage whose definition is the same in several
    /// points is planned once (so its instances build once), and one that differs becomes a
    /// variant `name~k`, k the first point that declares it so. Keys and random streams are
    /// those of each point's own plan. Returns, per point, its stage names -> merged indices.
    pub fn merge(points: Vec<Plan>) -> Result<(Plan, Vec<BTreeMap<String, usize>>)> {
        let mut points = points.into_iter();
        let mut merged = points
            .next()
            .ok_or_else(|| Error::usage("a sweep needs at least one point"))?;
        merged.record_heads = false;
        let first = merged.index.clone();
        let mut maps = vec![first];
        for (k, plan) in points.enumerate() {
            let mut map: BTreeMap<String, usize> = BTreeMap::new();
            let mut local: Vec<usize> = Vec::with_capacity(plan.stages.len());
            for mut stage in plan.stages {
                for input in &mut stage.inputs {
                    input.upstream = local[input.upstream];
                }
                let same = merged
                    .stages
                    .iter()
                    .position(|m| m.name == stage.name && m.definition == stage.definition);
                let at = match same {
                    Some(at) => at,
                    None => {
                        stage.variant = Some(format!("~{}", k + 1));
                        merged
                            .index
                            .insert(format!("{}~{}", stage.name, k + 1), merged.stages.len());
                        merged.stages.push(stage);
                        merged.stages.len() - 1
                    }
                };
                map.insert(merged.stages[at].name.clone(), at);
                local.push(at);
            }
            maps.push(map);
        }
        Ok((merged, maps))
    }

    /// `target` (`name`, `name#k`, `name@s`) of one sweep point, as the merged plan names it.
    pub fn point_target(&self, map: &BTreeMap<String, usize>, target: &str) -> String {
        let cut = target.find(['#', '@']).unwrap_or(target.len());
        let (name, rest) = target.split_at(cut);
        match map.get(name) {
            Some(&i) => format!("{}{}{rest}", self.stages[i].name, self.variant(i)),
            None => target.to_string(),
        }
    }

    fn variant(&self, stage: usize) -> &str {
        self.stages[stage].variant.as_deref().unwrap_or("")
    }

    pub fn stage_index(&self, name: &str) -> Option<usize> {
        self.index.get(name).copied()
    }

    /// The instance that [`Plan::display`] names `name`, among those of a make with `seeds`.
    pub fn instance_named(&self, name: &str, seeds: &[u64]) -> Option<InstanceId> {
        let stage = name.split(['#', '@']).next()?;
        let index = self.stage_index(stage)?;
        self.stage_instances(index, seeds)
            .into_iter()
            .find(|id| self.display(*id) == name)
    }

    pub fn stage_names(&self) -> Vec<&str> {
        self.stages.iter().map(|s| s.name.as_str()).collect()
    }

    /// The instances of `stage` for the run seeds `seeds`: every fold, and every seed if the
    /// stage depends on it; (fold, seed) order.
    pub fn stage_instances(&self, stage: usize, seeds: &[u64]) -> Vec<InstanceId> {
        let s = &self.stages[stage];
        let folds: Vec<Option<u32>> = match s.folds {
            Some(n) => (0..n).map(Some).collect(),
            None => vec![None],
        };
        let run_seeds: Vec<Option<u64>> = if s.seed_dependent {
            sweep(seeds)
        } else {
            vec![None]
        };
        folds
            .iter()
            .flat_map(|&fold| {
                run_seeds.iter().map(move |&run_seed| InstanceId {
                    stage,
                    fold,
                    run_seed,
                })
            })
            .collect()
    }

    /// The seed a stage's random streams use, or `None` if it draws none.
    pub fn effective_seed(&self, id: InstanceId) -> Option<u64> {
        let s = &self.stages[id.stage];
        if !s.uses_rng {
            None
        } else {
            Some(
                s.fixed_seed
                    .or(id.run_seed)
                    .expect("seeded instances carry their run seed"),
            )
        }
    }

    /// The fold of an instance, with the stage's fold count.
    pub fn fold(&self, id: InstanceId) -> Option<Fold> {
        Some(Fold {
            index: id.fold?,
            count: self.stages[id.stage].folds?,
        })
    }

    /// How instances are named to people: `stage`, `stage#fold`, `stage@seed`,
    /// `stage#fold@seed`. The name without `@seed` also names the instance's random streams.
    pub fn display(&self, id: InstanceId) -> String {
        format!(
            "{}{}{}",
            self.stages[id.stage].name,
            self.variant(id.stage),
            id.member().suffix()
        )
    }

    /// The name that names an instance's random streams: the stage, with `#fold` for folds.
    pub fn stream_name(&self, id: InstanceId) -> String {
        let name = &self.stages[id.stage].name;
        match id.fold {
            Some(f) => format!("{name}#{f}"),
            None => name.clone(),
        }
    }

    /// The input instances of `id` in a make for `seeds`, slot by slot; a gather slot's
    /// members in (fold, seed) order.
    pub fn input_instances(&self, id: InstanceId, seeds: &[u64]) -> Vec<InputInstance> {
        let mut out = Vec::new();
        for input in &self.stages[id.stage].inputs {
            let up = &self.stages[input.upstream];
            let folds: Vec<Option<u32>> = match (input.folds, up.folds) {
                (_, None) => vec![None],
                (FoldRef::Same, Some(_)) => vec![id.fold],
                (FoldRef::Fixed(k), Some(_)) => vec![Some(k)],
                (FoldRef::All, Some(n)) => (0..n).map(Some).collect(),
            };
            let run_seeds: Vec<Option<u64>> = if !up.seed_dependent {
                vec![None]
            } else if input.all_seeds {
                sweep(seeds)
            } else {
                vec![id.run_seed]
            };
            for &fold in &folds {
                for &run_seed in &run_seeds {
                    let up_id = InstanceId {
                        stage: input.upstream,
                        fold,
                        run_seed,
                    };
                    let label = if input.gather {
                        format!("{}[{}]", input.slot, up_id.member().suffix())
                    } else {
                        input.slot.clone()
                    };
                    out.push(InputInstance {
                        slot: input.slot.clone(),
                        label,
                        id: up_id,
                    });
                }
            }
        }
        out
    }

    /// The instances needed to build `targets` for `seeds`, in dependency order, each once. A
    /// target is a stage name (every fold and seed of `seeds`), optionally narrowed to a fold
    /// (`name#1`) and a seed (`name@3`, `name#1@3`); no targets means every stage.
    pub fn instances(&self, targets: &[String], seeds: &[u64]) -> Result<Vec<InstanceId>> {
        let mut stack: Vec<InstanceId> = Vec::new();
        if targets.is_empty() {
            for stage in 0..self.stages.len() {
                stack.extend(self.stage_instances(stage, seeds));
            }
        }
        for target in targets {
            let (rest, seed) = match target.split_once('@') {
                Some((rest, seed)) => {
                    let seed = seed.parse::<u64>().map_err(|_| {
                        Error::usage(format!(
                            "target `{target}`: `{seed}` is not a seed\nhint: write `stage@3`"
                        ))
                    })?;
                    (rest, Some(seed))
                }
                None => (target.as_str(), None),
            };
            let (name, fold) = match rest.split_once('#') {
                Some((name, fold)) => {
                    let fold = fold.parse::<u32>().map_err(|_| {
                        Error::usage(format!(
                            "target `{target}`: `{fold}` is not a fold\nhint: write `stage#0`"
                        ))
                    })?;
                    (name, Some(fold))
                }
                None => (rest, None),
            };
            let stage = self.stage_index(name).ok_or_else(|| {
                Error::usage(format!(
                    "unknown target `{target}`\nhint: stages are {}",
                    list(self.stage_names())
                ))
            })?;
            let s = &self.stages[stage];
            if let Some(fold) = fold {
                match s.folds {
                    None => {
                        return Err(Error::usage(format!(
                            "target `{target}`: stage `{name}` has no folds\nhint: write `{name}`"
                        )));
                    }
                    Some(n) if fold >= n => {
                        return Err(Error::usage(format!(
                            "target `{target}`: stage `{name}` has folds #0 to #{}",
                            n - 1
                        )));
                    }
                    Some(_) => {}
                }
            }
            let target_seeds = match seed {
                Some(seed) => vec![seed],
                None => seeds.to_vec(),
            };
            stack.extend(
                self.stage_instances(stage, &target_seeds)
                    .into_iter()
                    .filter(|id| fold.is_none() || id.fold == fold),
            );
        }
        let mut wanted = BTreeSet::new();
        while let Some(id) = stack.pop() {
            if wanted.insert(id) {
                stack.extend(self.input_instances(id, seeds).into_iter().map(|i| i.id));
            }
        }
        // Stage order is a topological order; folds, then seeds, ascending within a stage.
        Ok(wanted.into_iter().collect())
    }

    /// The stage key (ARCHITECTURE.md, "Keys, hashes, seeds"): kind, code version, output
    /// schema, numerics versions, canonical params, input content hashes (by label, so a
    /// gather's members in order), fold, effective seed and, for stages that draw random
    /// numbers, the name that names their streams.
    pub fn key(&self, id: InstanceId, input_hashes: &[(String, Hash)]) -> Hash {
        let s = &self.stages[id.stage];
        let mut h = blake3::Hasher::new_derive_key("osms stage key v2");
        put_kind(&mut h, &s.info);
        put_bytes(&mut h, &s.params.canonical);
        h.update(&(input_hashes.len() as u64).to_le_bytes());
        for (label, hash) in input_hashes {
            put_str(&mut h, label);
            h.update(hash.0.as_slice());
        }
        put_folds(&mut h, s.folds.map(|n| (id.fold, n)));
        match self.effective_seed(id) {
            Some(seed) => {
                h.update(&[1]);
                h.update(&seed.to_le_bytes());
                put_str(&mut h, &self.stream_name(id));
            }
            None => {
                h.update(&[0]);
            }
        }
        Hash::from(h.finalize())
    }
}

/// A stage's params parsed into its kind's type. An error names the `--set` that reaches the
/// field if one does, else the line of pipeline.toml. The declaration without the profile is
/// parsed too, so a wrong base value hidden by the profile's overlay is still an error.
fn parse_params(
    pipeline: &Pipeline,
    name: &str,
    stage_desc: &str,
    kind: &dyn DynKind,
) -> Result<ParsedParams> {
    let spec = &pipeline.stages[name];
    let field_path = |e: &ParamError| {
        let mut path = e.path.clone();
        // serde reports an unknown field at its parent; point at the field itself.
        if e.message.starts_with("unknown field")
            && let Some(field) = e.message.split('`').nth(1)
            && path.last().map(String::as_str) != Some(field)
        {
            path.push(field.to_string());
        }
        path
    };
    let shown = |path: &[String]| {
        if path.is_empty() {
            String::new()
        } else {
            format!(" `{}`", path.join("."))
        }
    };
    let parsed = kind.parse_params(toml::Value::Table(spec.params.clone()));
    let e = match parsed {
        Ok(params) => {
            if let Some(base) = &spec.base_params
                && let Err(e) = kind.parse_params(toml::Value::Table(base.clone()))
                // The profile may supply what the base leaves out.
                && !e.message.starts_with("missing field")
            {
                let path = field_path(&e);
                let mut keys = vec!["stages", name, "params"];
                keys.extend(path.iter().map(String::as_str));
                return Err(Error::invalid(
                    pipeline.locate(&keys),
                    format!(
                        "{stage_desc}, param{} as [stages.{name}] declares it: {}",
                        shown(&path),
                        e.message
                    ),
                    Some(format!(
                        "profile `{}` overlays this param, but the declaration must hold by itself (other profiles read it)",
                        pipeline.profile
                    )),
                ));
            }
            return Ok(params);
        }
        Err(e) => e,
    };
    let path = field_path(&e);
    let reaches = |o: &&Override| match &o.field {
        Field::Param(p) => p.starts_with(&path) || path.starts_with(p),
        _ => false,
    };
    let message = format!("{stage_desc}, param{}: {}", shown(&path), e.message);
    match spec.overrides.iter().rev().find(reaches) {
        Some(o) => {
            let declared = spec
                .declared_params
                .as_ref()
                .and_then(|d| kind.parse_params(toml::Value::Table(d.clone())).ok());
            Err(Error::invalid(
                None,
                format!("{}: {message}", o.desc()),
                Some(valid_here(declared.as_ref().map(|p| &p.json), &path, name)),
            ))
        }
        None => Err(Error::invalid(
            pipeline.locate_param(name, &path),
            message,
            None,
        )),
    }
}

/// What the stage's params hold around `path`, for an override that missed: the fields of its
/// parent table and the value in force.
fn valid_here(declared: Option<&serde_json::Value>, path: &[String], stage: &str) -> String {
    let Some(root) = declared else {
        return format!("`osms show {stage}` prints the stage's params");
    };
    let (parent_path, field) = match path.split_last() {
        Some((field, parent)) => (parent, Some(field)),
        None => (path, None),
    };
    let parent = parent_path.iter().try_fold(root, |v, k| v.get(k));
    let current = field.and_then(|f| parent.and_then(|p| p.get(f)));
    let prefix = |k: &str| {
        let mut p = parent_path.to_vec();
        p.push(k.to_string());
        format!("{stage}.{}", p.join("."))
    };
    match (current, parent.and_then(|p| p.as_object())) {
        (Some(v), _) => format!("`{}` is {v} now", prefix(field.map_or("", |f| f.as_str()))),
        (None, Some(fields)) => format!(
            "the fields here are {}",
            list(fields.keys().map(|k| prefix(k)))
        ),
        (None, None) => format!("`osms show {stage}` prints the stage's params"),
    }
}

/// The run seeds of a sweep as instances see them: ascending, each once.
fn sweep(seeds: &[u64]) -> Vec<Option<u64>> {
    let mut sorted = seeds.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    sorted.into_iter().map(Some).collect()
}

fn put_kind(h: &mut blake3::Hasher, info: &KindInfo) {
    put_str(h, info.name);
    h.update(&info.code_version.to_le_bytes());
    put_str(h, info.output_tag);
    h.update(&info.output_schema.to_le_bytes());
    h.update(&(info.numerics.len() as u64).to_le_bytes());
    for n in &info.numerics {
        put_str(h, n.name);
        put_str(h, &n.version);
    }
}

fn put_folds(h: &mut blake3::Hasher, folds: Option<(Option<u32>, u32)>) {
    match folds {
        None => h.update(&[0]),
        Some((fold, count)) => h
            .update(&[1])
            .update(&fold.map_or(u32::MAX, |f| f).to_le_bytes())
            .update(&count.to_le_bytes()),
    };
}

/// The key of the shard holding items `[start, end)` of the stage with key `stage_key`.
pub fn shard_key(stage_key: &Hash, start: u64, end: u64) -> Hash {
    let mut h = blake3::Hasher::new_derive_key("osms shard key v1");
    h.update(stage_key.0.as_slice());
    h.update(&start.to_le_bytes());
    h.update(&end.to_le_bytes());
    Hash::from(h.finalize())
}

/// The key of the checkpoint record of the build of `stage_key` (one per build: each
/// checkpoint replaces the last).
pub fn checkpoint_key(stage_key: &Hash) -> Hash {
    let mut h = blake3::Hasher::new_derive_key("osms checkpoint key v1");
    h.update(stage_key.0.as_slice());
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
        for (slot, reference) in &spec.inputs {
            let upstream = parse_reference(reference)
                .map_err(|e| {
                    Error::invalid(
                        pipeline.locate(&["stages", name, "inputs", slot]),
                        format!("stage `{name}`, input `{slot}` = \"{reference}\": {e}"),
                        None,
                    )
                })?
                .stage;
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
        for reference in pipeline.stages[name].inputs.values() {
            let upstream = parse_reference(reference)
                .map(|r| r.stage)
                .unwrap_or(reference);
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
