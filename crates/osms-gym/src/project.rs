//! A project (pipeline.toml, a profile and the store beside it) and the evaluation protocols
//! its stages define.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use osms_core::Artifact;
use osms_core::rng::{self, StreamRng};
use osms_make::{InstanceId, Pipeline, Plan, Sharded, State, StoreObjects};
use osms_policy::protocol::EvalProtocol;
use osms_policy::stages::{TeacherParams, evaluation_kinds};
use osms_sim::World;
use osms_sim::artifacts::{Conditions, WorldArtifact};
use osms_sim::conditions::TaskCondition;
use osms_store::Store;

use crate::error::{GymError, Result};

/// The stage kinds a protocol builds itself when missing: seconds of work, no training.
const CHEAP_KINDS: [&str; 2] = ["world", "conditions"];

/// A pipeline under one profile, with its store: where protocols and policies are read from.
pub struct Project {
    pipeline_path: PathBuf,
    store: Store,
    plan: Plan,
}

impl Project {
    /// Opens `pipeline` (else the pipeline.toml of the working directory or its nearest parent)
    /// under `profile` (else the pipeline's default), with `store` (else `store/` beside the
    /// pipeline). A store directory that does not exist yet is created, empty (said on stderr):
    /// opening builds nothing, a [`Project::protocol`] builds its world and condition set if
    /// they are missing, anything else is `osms make`'s.
    pub fn open(
        pipeline: Option<&Path>,
        store: Option<&Path>,
        profile: Option<&str>,
    ) -> Result<Self> {
        let pipeline_path = match pipeline {
            Some(p) => p.to_path_buf(),
            None => find_pipeline()?,
        };
        let loaded = Pipeline::load(&pipeline_path, profile)?;
        let plan = Plan::new(&loaded, &osms_kinds::registry())?;
        let store_path = match store {
            Some(s) => s.to_path_buf(),
            None => pipeline_path
                .parent()
                .unwrap_or(Path::new("."))
                .join("store"),
        };
        let created = !store_path.exists();
        let store = Store::open(&store_path).map_err(|e| unwritable(&store_path, e))?;
        if created {
            eprintln!(
                "osms: created an empty store at {} (a protocol builds its world and conditions there on first use)",
                store_path.display()
            );
        }
        Ok(Project {
            store,
            pipeline_path,
            plan,
        })
    }

    pub fn profile(&self) -> &str {
        &self.plan.profile
    }

    pub fn pipeline_path(&self) -> &Path {
        &self.pipeline_path
    }

    pub fn store_path(&self) -> &Path {
        self.store.root()
    }

    /// Whether `name`'s stage (`stage`, `stage@seed`, `stage#fold`) is in the pipeline.
    pub fn has_stage(&self, name: &str) -> bool {
        self.stage_index(name).is_some()
    }

    fn stage_index(&self, name: &str) -> Option<usize> {
        let stage = name.split(['@', '#']).next().unwrap_or(name);
        self.plan.stage_index(stage)
    }

    /// `name` is not `what` (`a stage`, `a policy`, …) here; `known` are the valid names.
    pub fn unknown<S: std::borrow::Borrow<str>>(
        &self,
        name: &str,
        what: &'static str,
        known: &[S],
    ) -> GymError {
        GymError::UnknownStage {
            name: name.to_string(),
            what,
            pipeline: self.pipeline_path.display().to_string(),
            known: known.join(", "),
        }
    }

    /// The instance `name` names (`stage`, `stage@seed`, `stage#fold`), and its kind.
    pub fn instance(&self, name: &str) -> Result<(InstanceId, &str)> {
        let Some(index) = self.stage_index(name) else {
            return Err(self.unknown(name, "a stage", &self.plan.stage_names()));
        };
        let id = self
            .plan
            .instance_named(name, &self.seeds_for(name))
            .ok_or_else(|| {
                let examples: Vec<String> = self
                    .plan
                    .stage_instances(index, &self.plan.default_seeds)
                    .into_iter()
                    .map(|id| self.plan.display(id))
                    .collect();
                GymError::Project(format!(
                    "`{name}` names no instance of stage `{}`\nhint: its instances are {}",
                    self.plan.stages[index].name,
                    examples.join(", ")
                ))
            })?;
        Ok((id, self.plan.stages[index].info.name))
    }

    /// The run seeds a name can refer to: the pipeline's, and the one it names.
    fn seeds_for(&self, name: &str) -> Vec<u64> {
        let mut seeds = self.plan.default_seeds.clone();
        if let Some(seed) = name.rsplit_once('@').and_then(|(_, s)| s.parse().ok()) {
            seeds.push(seed);
        }
        seeds.sort_unstable();
        seeds.dedup();
        seeds
    }

    /// Whether instance `id` is built and current, and if not why.
    fn status(&self, id: InstanceId) -> Result<osms_make::InstanceStatus> {
        let display = self.plan.display(id);
        osms_make::status(
            &self.plan,
            &self.store,
            std::slice::from_ref(&display),
            &self.seeds_for(&display),
        )?
        .into_iter()
        .find(|s| s.id == id)
        .ok_or_else(|| GymError::Project(format!("no status for `{display}`")))
    }

    /// The stored bytes of `name`'s current build, and whether they are a manifest.
    fn built(&self, name: &str) -> Result<(Vec<u8>, bool)> {
        let (id, _) = self.instance(name)?;
        let display = self.plan.display(id);
        let status = self.status(id)?;
        match (status.state, status.content_hash) {
            (State::Cached, Some(hash)) => Ok((
                self.store.get(&hash)?,
                self.plan.stages[id.stage].info.itemised,
            )),
            _ => Err(GymError::NotBuilt {
                instance: display,
                pipeline: self.pipeline_path.display().to_string(),
                store: self.store.root().display().to_string(),
                profile: self.plan.profile.clone(),
                reason: osms_make::describe(&status.reasons),
            }),
        }
    }

    /// The artifact of `name`'s current build (a stage whose kind stores it whole).
    pub fn load<A: Artifact>(&self, name: &str) -> Result<A> {
        let (bytes, manifest) = self.built(name)?;
        if manifest {
            return Err(GymError::Decode {
                instance: name.to_string(),
                message: "it is stored sharded".to_string(),
            });
        }
        osms_core::decode(&bytes).map_err(|e| GymError::Decode {
            instance: name.to_string(),
            message: e.to_string(),
        })
    }

    /// The whole artifact of `name`'s current build, items included, sharded or not.
    pub fn load_sharded<A: Sharded>(&self, name: &str) -> Result<A> {
        let (bytes, manifest) = self.built(name)?;
        let decoded = if manifest {
            osms_make::assemble(&bytes, &StoreObjects(&self.store)).map_err(|e| e.to_string())
        } else {
            osms_core::decode(&bytes).map_err(|e| e.to_string())
        };
        decoded.map_err(|message| GymError::Decode {
            instance: name.to_string(),
            message,
        })
    }

    /// The instance wired to `slot` of `id`, by name.
    pub fn input(&self, id: InstanceId, slot: &str) -> Option<String> {
        self.plan
            .input_instances(id, &self.seeds_for(&self.plan.display(id)))
            .into_iter()
            .find(|i| i.slot == slot)
            .map(|i| self.plan.display(i.id))
    }

    /// The protocol of evaluation stage `name` (an instance of kind `eval_teacher`,
    /// `eval_student`, `eval_scripted` or `evaluate`): its world, conditions, rollout spec and
    /// random streams. The stage itself need not be built, nor any policy it rolls out (an
    /// `eval_teacher`'s rollout spec is its teacher's task, which the teacher stage's params
    /// fix before any training); its world and conditions are built here if missing.
    pub fn protocol(&self, name: &str) -> Result<Protocol> {
        if !self.has_stage(name) {
            return Err(self.unknown(name, "an evaluation stage", &self.evaluation_stages()));
        }
        let (id, kind) = self.instance(name)?;
        let kinds = evaluation_kinds();
        let Some(evaluation) = kinds.iter().find(|k| k.kind == kind) else {
            return Err(GymError::WrongKind {
                name: name.to_string(),
                kind: kind.to_string(),
                expected: format!(
                    "a protocol is an evaluation stage (kind {})\nhint: evaluation stages here are {}",
                    evaluation_kind_names().join(", "),
                    self.evaluation_stages().join(", ")
                ),
            });
        };
        let input = |slot: &str| {
            self.input(id, slot)
                .ok_or_else(|| GymError::Project(format!("stage `{name}` has no `{slot}` input")))
        };
        let teacher = if evaluation.reads_teacher_task {
            Some(self.teacher_task(&input("teacher")?)?)
        } else {
            None
        };
        let protocol = evaluation
            .protocol(&self.plan.stages[id.stage].params.json, teacher.as_ref())
            .map_err(|e| GymError::Decode {
                instance: name.to_string(),
                message: format!("params: {e}"),
            })?;
        let conditions_name = input("conditions")?;
        let world_name = input("world")?;
        self.build_cheap(&[world_name.clone(), conditions_name.clone()])?;
        let conditions: Conditions = self.load_sharded(&conditions_name)?;
        let world = self
            .load::<WorldArtifact>(&world_name)?
            .world()
            .map_err(|e| GymError::Decode {
                instance: world_name,
                message: e.to_string(),
            })?;
        Ok(Protocol {
            name: self.plan.display(id),
            kind: kind.to_string(),
            world: Arc::new(world),
            conditions_name,
            conditions: Arc::new(conditions.items),
            rules: protocol,
            seed: self.plan.effective_seed(id),
            stream: self.plan.stream_name(id),
        })
    }

    /// The task a teacher instance trains on, stored realised in its artifact: read from its
    /// stage's params, so that no training is needed to know how its evaluations roll out.
    fn teacher_task(&self, teacher: &str) -> Result<osms_policy::catch::CatchTaskSpec> {
        let (id, kind) = self.instance(teacher)?;
        if kind != "teacher" {
            return Err(GymError::WrongKind {
                name: teacher.to_string(),
                kind: kind.to_string(),
                expected: "an `eval_teacher` stage's `teacher` input is a `teacher` stage"
                    .to_string(),
            });
        }
        let p: TeacherParams = serde_json::from_value(
            self.plan.stages[id.stage].params.json.clone(),
        )
        .map_err(|e| GymError::Decode {
            instance: teacher.to_string(),
            message: format!("params: {e}"),
        })?;
        Ok(p.task.realised())
    }

    /// Builds those of `names` that are the world or a condition set and not built yet (seconds,
    /// exactly as `osms make` builds them): a protocol needs them, and a fresh clone has none.
    /// Anything costlier is left to `osms make`.
    fn build_cheap(&self, names: &[String]) -> Result<()> {
        let mut targets = Vec::new();
        for name in names {
            let (id, kind) = self.instance(name)?;
            if !CHEAP_KINDS.contains(&kind) {
                continue;
            }
            if self.status(id)?.state != State::Cached {
                targets.push(self.plan.display(id));
            }
        }
        if targets.is_empty() {
            return Ok(());
        }
        let opts = osms_make::MakeOptions {
            targets,
            seeds: self.plan.default_seeds.clone(),
            jobs: std::thread::available_parallelism().map_or(1, |n| n.get()),
            stages: 1,
            dry_run: false,
        };
        let observer = FirstUse {
            targets: &opts.targets,
            store: self.store.root(),
        };
        let report = osms_make::make(&self.plan, &self.store, &opts, &observer)?;
        let failed = report.instances.iter().find_map(|r| match &r.outcome {
            osms_make::Outcome::Failed { error } => Some((r.instance.as_str(), error.as_str())),
            _ => None,
        });
        match failed {
            None => Ok(()),
            Some((instance, error)) => Err(GymError::Project(format!(
                "building `{instance}` failed: {error}"
            ))),
        }
    }

    /// The evaluation stages of the pipeline, in its order.
    pub fn evaluation_stages(&self) -> Vec<String> {
        self.stages_of(&evaluation_kind_names())
    }

    /// The pipeline's stages of the kinds in `kinds`, in its order.
    pub fn stages_of(&self, kinds: &[&str]) -> Vec<String> {
        self.plan
            .stages
            .iter()
            .filter(|s| kinds.contains(&s.info.name))
            .map(|s| s.name.clone())
            .collect()
    }

    /// The pipeline's condition sets (stages of kind `conditions`), in its order.
    pub fn condition_sets(&self) -> Vec<String> {
        self.stages_of(&["conditions"])
    }

    /// The protocol osms uses by default for condition set `conditions` (`dev`, `heldout`): the
    /// first evaluation stage on it that rolls out a teacher, else the first on it.
    pub fn default_protocol(&self, conditions: &str) -> Result<String> {
        let set = match self.instance(conditions) {
            Ok((set, "conditions")) => set,
            _ => {
                return Err(self.unknown(conditions, "a condition set", &self.condition_sets()));
            }
        };
        let kinds = evaluation_kind_names();
        let on_set: Vec<&osms_make::PlannedStage> = self
            .plan
            .stages
            .iter()
            .filter(|s| kinds.contains(&s.info.name))
            .filter(|s| {
                s.inputs
                    .iter()
                    .any(|i| i.slot == "conditions" && i.upstream == set.stage)
            })
            .collect();
        on_set
            .iter()
            .find(|s| s.inputs.iter().any(|i| i.slot == "teacher"))
            .or(on_set.first())
            .map(|s| s.name.clone())
            .ok_or_else(|| {
                GymError::Project(format!(
                    "no evaluation stage reads the conditions `{conditions}`\nhint: evaluation stages here are {}",
                    self.evaluation_stages().join(", ")
                ))
            })
    }
}

/// The rules of an evaluation stage's rollouts: rollout `i` runs condition `i` of its set under
/// its rollout spec, with its domain randomisation from the stage's ("item", i) stream and a
/// stochastic policy's noise from its ("policy", i) stream.
#[derive(Clone)]
pub struct Protocol {
    /// The stage instance (`eval_naive@1`).
    pub name: String,
    pub kind: String,
    pub world: Arc<World>,
    /// The condition set's instance (`heldout`).
    pub conditions_name: String,
    pub conditions: Arc<Vec<TaskCondition>>,
    /// What the stage's params say its rollouts are: the rollout spec, the scripted catcher,
    /// the chunk execution.
    pub rules: EvalProtocol,
    /// The seed of the stage's streams; `None` when the stage draws nothing (no DR).
    pub seed: Option<u64>,
    /// The name the stage's streams go by (the stage, with `#fold` for folds).
    pub stream: String,
}

impl Protocol {
    /// The generator of rollout `index`'s domain randomisation, as the executor makes it.
    pub fn dr_rng(&self, index: usize) -> StreamRng {
        match self.seed {
            Some(seed) => rng::stream(seed, &self.stream, "item", index as u64),
            None => rng::stream(0, "", "item", index as u64),
        }
    }

    /// The generator of a stochastic policy's noise in rollout `index` (a student's).
    pub fn policy_rng(&self, index: usize) -> StreamRng {
        rng::stream(self.seed.unwrap_or(0), &self.stream, "policy", index as u64)
    }

    /// Condition `index`, or an error naming the valid range.
    pub fn condition(&self, index: i64) -> Result<&TaskCondition> {
        usize::try_from(index)
            .ok()
            .and_then(|i| self.conditions.get(i))
            .ok_or_else(|| GymError::Condition {
                index,
                conditions: self.conditions_name.clone(),
                n: self.conditions.len(),
            })
    }
}

/// The kinds of the stages that can serve as protocols.
fn evaluation_kind_names() -> Vec<&'static str> {
    evaluation_kinds().iter().map(|k| k.kind).collect()
}

fn find_pipeline() -> Result<PathBuf> {
    let cwd = std::env::current_dir()
        .map_err(|e| GymError::Project(format!("cannot read the current directory: {e}")))?;
    cwd.ancestors()
        .map(|dir| dir.join("pipeline.toml"))
        .find(|p| p.is_file())
        .ok_or_else(|| {
            GymError::Project(format!(
                "no pipeline.toml in {} or any parent directory\nhint: run inside an osms project, or pass pipeline=PATH; `osms init DIR` writes a project (pipeline.toml and an empty store) into DIR",
                cwd.display()
            ))
        })
}

/// A store that cannot be created or written gets a hint; other store errors pass as they are.
fn unwritable(path: &Path, e: osms_store::Error) -> GymError {
    match &e {
        osms_store::Error::Io { source, .. }
            if matches!(
                source.kind(),
                std::io::ErrorKind::PermissionDenied | std::io::ErrorKind::ReadOnlyFilesystem
            ) =>
        {
            GymError::Project(format!(
                "{e}\nhint: the store at {} cannot be written, and a new or empty store needs its world and conditions built there on first use; pass store= a writable directory, or a store that already holds them (read-only stores are served as they are)",
                path.display()
            ))
        }
        _ => e.into(),
    }
}

/// The make that builds a condition set on first use: silent, except that it says why it waits
/// when another process (a running `osms make`) holds the store's lock, which it keeps for the
/// whole make.
struct FirstUse<'a> {
    targets: &'a [String],
    store: &'a Path,
}

impl osms_make::Observer for FirstUse<'_> {
    fn waiting_for_lock(&self) {
        eprintln!(
            "osms: waiting for another osms process (a running `osms make`?) to release the store lock of {} before building {} (its first use)",
            self.store.display(),
            self.targets.join(", ")
        );
    }
    fn started(&self, _: &str, _: &str) -> Box<dyn osms_make::Progress + '_> {
        Box::new(osms_make::NoProgress)
    }
    fn finished(&self, _: &osms_make::InstanceReport) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    fn io(kind: std::io::ErrorKind) -> osms_store::Error {
        osms_store::Error::Io {
            path: "/ro/store/OSMS_STORE".into(),
            source: std::io::Error::from(kind),
        }
    }

    #[test]
    fn a_store_that_cannot_be_written_gets_a_hint_and_other_errors_pass_as_they_are() {
        for kind in [
            std::io::ErrorKind::PermissionDenied,
            std::io::ErrorKind::ReadOnlyFilesystem,
        ] {
            let text = unwritable(Path::new("/ro/store"), io(kind)).to_string();
            assert!(
                text.starts_with("I/O error on /ro/store/OSMS_STORE"),
                "{text}"
            );
            assert!(
                text.contains("hint: the store at /ro/store cannot be written"),
                "{text}"
            );
            assert!(text.contains("store= a writable directory"), "{text}");
        }
        let other = unwritable(Path::new("/ro/store"), io(std::io::ErrorKind::NotFound));
        assert!(!other.to_string().contains("hint"), "{other}");
    }
}
