//! Reading `pipeline.toml`: the declaration of stages, their params and inputs, and the
//! profiles that overlay params.
//!
//! ```toml
//! [pipeline]
//! default_profile = "small"   # used when --profile is not given
//! seeds = [0, 1, 2]           # run seeds when --seed/--seeds are not given (or `seed = 0`)
//! targets = ["summary"]       # what `osms make` builds when given no targets [default: all]
//! experiment_targets = ["dev_eval"] # what `osms exp run` builds when given no targets
//! held_out = ["heldout"]      # stages an experiment is warned for reading
//!
//! [stages.rollouts]
//! kind = "collect"            # a kind registered in code
//! inputs = { world = "world" }# input slot -> upstream stage
//! shards = 4                  # itemised kinds only: items split into 4 artifacts
//! seed = 7                    # optional: a fixed seed, shared by every run of a seed sweep
//! checkpoint_every = 50       # optional: long kinds checkpoint every 50 of their steps
//! params = { n = 1000 }
//!
//! [stages.student]
//! kind = "train"
//! folds = 2                   # instances student#0, student#1, each told its fold index
//! inputs = { data = "rollouts" }
//!
//! [stages.summary]
//! kind = "aggregate"
//! inputs = { runs = "student#*@*" }  # a gather slot: every fold, every run seed
//!
//! [profiles.tiny.rollouts]    # profile `tiny` overlays params (deep merge) and shards
//! params = { n = 10 }
//!
//! [profiles.decide]
//! seeds = [0, 1, 2, 3, 4]     # a profile's own run seeds replace [pipeline]'s
//!
//! [remotes.lab]               # a remote artifact cache (`osms push`, `osms pull`)
//! url = "s3://bucket/osms"    # s3://, http(s):// or file:///; credentials from AWS_*
//! ```
//!
//! `[pipeline] remote = "lab"` makes a remote the default of push, pull and `make --remote`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Location, Result, key_location, list, location_of};
use crate::executor::ExecutorConfig;
use crate::overrides::{Field, Override, set_path, unknown_stage};
use crate::remotes::RemoteSpec;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPipeline {
    #[serde(default)]
    pipeline: RawMeta,
    #[serde(default)]
    stages: BTreeMap<String, RawStage>,
    #[serde(default)]
    profiles: BTreeMap<String, RawProfile>,
    #[serde(default)]
    executor: ExecutorConfig,
    #[serde(default)]
    remotes: BTreeMap<String, RemoteSpec>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMeta {
    #[serde(default = "default_profile")]
    default_profile: String,
    seed: Option<u64>,
    seeds: Option<Vec<u64>>,
    #[serde(default)]
    targets: Vec<String>,
    #[serde(default)]
    experiment_targets: Vec<String>,
    #[serde(default)]
    held_out: Vec<String>,
    remote: Option<String>,
}

fn default_profile() -> String {
    "small".to_string()
}

impl Default for RawMeta {
    fn default() -> Self {
        RawMeta {
            default_profile: default_profile(),
            seed: None,
            seeds: None,
            targets: Vec::new(),
            experiment_targets: Vec::new(),
            held_out: Vec::new(),
            remote: None,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStage {
    kind: String,
    #[serde(default)]
    inputs: BTreeMap<String, String>,
    #[serde(default)]
    params: toml::Table,
    shards: Option<u32>,
    folds: Option<u32>,
    seed: Option<u64>,
    checkpoint_every: Option<u32>,
}

/// `[profiles.NAME]`: the profile's run seeds (an array, so it cannot be mistaken for a stage's
/// overlay table) and one overlay per stage.
#[derive(Default)]
struct RawProfile {
    seeds: Option<Vec<u64>>,
    overlays: BTreeMap<String, RawOverlay>,
}

impl<'de> Deserialize<'de> for RawProfile {
    fn deserialize<D: serde::Deserializer<'de>>(
        deserializer: D,
    ) -> std::result::Result<Self, D::Error> {
        deserializer.deserialize_map(RawProfileVisitor)
    }
}

struct RawProfileVisitor;

impl<'de> serde::de::Visitor<'de> for RawProfileVisitor {
    type Value = RawProfile;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a profile: `seeds = [...]` and one table per overlaid stage")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(
        self,
        mut map: A,
    ) -> std::result::Result<RawProfile, A::Error> {
        let mut profile = RawProfile::default();
        while let Some(key) = map.next_key::<String>()? {
            // Read the value by its own type so that an overlay's errors keep their spans.
            if key == "seeds" {
                profile.seeds = Some(map.next_value()?);
            } else {
                let overlay = map.next_value()?;
                profile.overlays.insert(key, overlay);
            }
        }
        Ok(profile)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOverlay {
    #[serde(default)]
    params: toml::Table,
    shards: Option<u32>,
    folds: Option<u32>,
    checkpoint_every: Option<u32>,
}

/// One stage as declared, with the chosen profile applied.
#[derive(Debug, Clone)]
pub struct StageSpec {
    pub name: String,
    pub kind: String,
    pub inputs: BTreeMap<String, String>,
    pub params: toml::Table,
    pub shards: u32,
    /// `Some(n)`: the stage has n instances per run seed, `name#0` .. `name#n-1`.
    pub folds: Option<u32>,
    pub fixed_seed: Option<u64>,
    /// How many of its steps (PPO iterations, training steps) a kind that checkpoints runs
    /// between checkpoints; `None`: the kind's own default. Not part of the stage's key.
    pub checkpoint_every: Option<u32>,
    /// The params as `[stages.NAME]` declares them, if the chosen profile overlays any: checked
    /// by themselves too, so a mistyped base value that a profile happens to overlay does not
    /// pass unseen.
    pub base_params: Option<toml::Table>,
    /// The params with the profile applied, if `--set` changed them (for hints about valid
    /// values).
    pub declared_params: Option<toml::Table>,
    /// The `--set` overrides applied to this stage, in order.
    pub overrides: Vec<Override>,
}

/// A parsed `pipeline.toml` with one profile applied.
#[derive(Debug, Clone)]
pub struct Pipeline {
    pub path: PathBuf,
    pub profile: String,
    pub profiles: Vec<String>,
    /// The run seeds of a make given no `--seed`/`--seeds`: sorted, distinct, at least one.
    pub default_seeds: Vec<u64>,
    /// What a make given no targets builds (empty: every stage).
    pub default_targets: Vec<String>,
    /// What `osms exp run` builds when given no targets (a development stream's evaluations).
    pub experiment_targets: Vec<String>,
    /// Stages whose conditions are held out for the final tables: an experiment that reads
    /// them is warned, since tuning on them would leak.
    pub held_out: Vec<String>,
    pub stages: BTreeMap<String, StageSpec>,
    /// `[executor]`: where stages run (never part of a key).
    pub executor: ExecutorConfig,
    /// `[remotes.NAME]`: remote artifact caches (never part of a key).
    pub remotes: BTreeMap<String, RemoteSpec>,
    /// `[pipeline] remote`: the remote push, pull and `make --remote` use when given none.
    pub default_remote: Option<String>,
    source: String,
    doc: toml_edit::Document<String>,
}

impl Pipeline {
    /// Reads `path` and applies `profile` (or the file's default profile).
    pub fn load(path: &Path, profile: Option<&str>) -> Result<Self> {
        let source = std::fs::read_to_string(path).map_err(|source| Error::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, source, profile)
    }

    pub fn parse(path: &Path, source: String, profile: Option<&str>) -> Result<Self> {
        let located = |span: Option<std::ops::Range<usize>>| {
            span.map(|s| location_of(path, &source, s.start))
        };
        let doc = toml_edit::Document::parse(source.clone()).map_err(|e| {
            Error::invalid(located(e.span()), e.message().trim_end().to_string(), None)
        })?;
        let raw: RawPipeline = toml::from_str(&source).map_err(|e| {
            let hint = e
                .message()
                .contains("unknown field")
                .then(|| "see the pipeline.toml section of README.md for the fields".to_string());
            Error::invalid(located(e.span()), e.message().trim_end().to_string(), hint)
        })?;

        let meta_location = |key: &str| key_location(path, &source, &doc, &["pipeline", key]);
        let default_seeds = match (raw.pipeline.seed, &raw.pipeline.seeds) {
            (Some(_), Some(_)) => {
                return Err(Error::invalid(
                    meta_location("seeds"),
                    "[pipeline] sets both `seed` and `seeds`".to_string(),
                    Some(
                        "keep one: `seeds = [0, 1, 2]` for a sweep, `seed = 0` for one run".into(),
                    ),
                ));
            }
            (_, Some(seeds)) if seeds.is_empty() => {
                return Err(Error::invalid(
                    meta_location("seeds"),
                    "[pipeline] `seeds` is empty".to_string(),
                    Some("name at least one run seed, e.g. `seeds = [0, 1, 2]`".into()),
                ));
            }
            (_, Some(seeds)) => distinct_sorted(seeds),
            (seed, None) => vec![seed.unwrap_or(0)],
        };
        let mut profiles: Vec<String> = raw.profiles.keys().cloned().collect();
        if !profiles.contains(&raw.pipeline.default_profile) {
            profiles.push(raw.pipeline.default_profile.clone());
            profiles.sort();
        }
        let profile = profile.unwrap_or(&raw.pipeline.default_profile).to_string();
        if !profiles.contains(&profile) {
            return Err(Error::usage(format!(
                "unknown profile `{profile}` in {}\nhint: declared profiles are {}",
                path.display(),
                list(&profiles)
            )));
        }

        let profile_seeds = raw.profiles.get(&profile).and_then(|p| p.seeds.as_ref());
        if profile_seeds.is_some_and(|s| s.is_empty()) {
            return Err(Error::invalid(
                key_location(path, &source, &doc, &["profiles", &profile, "seeds"]),
                format!("profile `{profile}`'s `seeds` is empty"),
                Some("name at least one run seed, or leave `seeds` out to use [pipeline]'s".into()),
            ));
        }
        let default_seeds = profile_seeds.map_or(default_seeds, |s| distinct_sorted(s));

        let mut stages = BTreeMap::new();
        for (name, s) in raw.stages {
            if !valid_name(&name) {
                return Err(Error::invalid(
                    key_location(path, &source, &doc, &["stages", &name]),
                    format!("stage name `{name}` is not allowed"),
                    Some("use letters, digits, `_` and `-`, starting with a letter".into()),
                ));
            }
            if name == "seeds" {
                return Err(Error::invalid(
                    key_location(path, &source, &doc, &["stages", &name]),
                    "stage name `seeds` is reserved: `[profiles.NAME] seeds = [...]` is a profile's run seeds".to_string(),
                    Some("rename the stage".into()),
                ));
            }
            stages.insert(
                name.clone(),
                StageSpec {
                    name,
                    kind: s.kind,
                    inputs: s.inputs,
                    base_params: None,
                    declared_params: None,
                    params: s.params,
                    shards: s.shards.unwrap_or(1),
                    folds: s.folds,
                    fixed_seed: s.seed,
                    checkpoint_every: s.checkpoint_every,
                    overrides: Vec::new(),
                },
            );
        }
        if let Some(raw_profile) = raw.profiles.get(&profile) {
            for (name, overlay) in &raw_profile.overlays {
                let Some(stage) = stages.get_mut(name) else {
                    let loc = key_location(path, &source, &doc, &["profiles", &profile, name]);
                    return Err(Error::invalid(
                        loc,
                        format!(
                            "profile `{profile}` overlays stage `{name}`, which is not declared"
                        ),
                        Some(format!(
                            "declared stages are {}",
                            list(raw_stage_names(&doc))
                        )),
                    ));
                };
                if !overlay.params.is_empty() {
                    stage.base_params = Some(stage.params.clone());
                }
                merge(&mut stage.params, &overlay.params);
                if let Some(shards) = overlay.shards {
                    stage.shards = shards;
                }
                if let Some(folds) = overlay.folds {
                    stage.folds = Some(folds);
                }
                if let Some(every) = overlay.checkpoint_every {
                    stage.checkpoint_every = Some(every);
                }
            }
        }
        let names: Vec<&str> = stages.keys().map(String::as_str).collect();
        raw.executor
            .validate(&names, &|keys| key_location(path, &source, &doc, keys))?;
        for name in raw.remotes.keys() {
            if !valid_name(name) {
                return Err(Error::invalid(
                    key_location(path, &source, &doc, &["remotes", name]),
                    format!("remote name `{name}` is not allowed"),
                    Some("use letters, digits, `_` and `-`, starting with a letter".into()),
                ));
            }
        }
        Ok(Pipeline {
            path: path.to_path_buf(),
            profile,
            profiles,
            default_seeds,
            default_targets: raw.pipeline.targets,
            experiment_targets: raw.pipeline.experiment_targets,
            held_out: raw.pipeline.held_out,
            stages,
            executor: raw.executor,
            remotes: raw.remotes,
            default_remote: raw.pipeline.remote,
            source,
            doc,
        })
    }

    /// Applies `--set` overrides on top of the profile, in order (a later one wins). Their
    /// params are checked when the plan parses them into the kinds' types.
    pub fn apply(&mut self, overrides: &[Override]) -> Result<()> {
        for o in overrides {
            let names: Vec<String> = self.stages.keys().cloned().collect();
            let stage = self
                .stages
                .get_mut(&o.stage)
                .ok_or_else(|| unknown_stage(o, &names))?;
            match &o.field {
                Field::Param(path) => {
                    if stage.declared_params.is_none() {
                        stage.declared_params = Some(stage.params.clone());
                    }
                    set_path(&mut stage.params, path, o.value.clone(), o)?
                }
                Field::Shards => {
                    stage.shards = u32::try_from(o.integer("shards", 1)?).unwrap_or(u32::MAX)
                }
                Field::Seed => stage.fixed_seed = Some(o.integer("seed", 0)? as u64),
                Field::CheckpointEvery => {
                    stage.checkpoint_every =
                        Some(u32::try_from(o.integer("checkpoint_every", 1)?).unwrap_or(u32::MAX))
                }
            }
            stage.overrides.push(o.clone());
        }
        Ok(())
    }

    /// The location of the deepest key of `keys` that exists in the file.
    pub fn locate(&self, keys: &[&str]) -> Option<Location> {
        key_location(&self.path, &self.source, &self.doc, keys)
    }

    /// The location of a stage's param, looking at the profile's overlay first.
    pub fn locate_param(&self, stage: &str, param_path: &[String]) -> Option<Location> {
        let mut overlay = vec!["profiles", self.profile.as_str(), stage, "params"];
        overlay.extend(param_path.iter().map(String::as_str));
        let mut base = vec!["stages", stage, "params"];
        base.extend(param_path.iter().map(String::as_str));
        // Point at whichever table names more of the param's path; ties go to the overlay,
        // because its value is the one in force.
        let matched = |keys: &[&str], prefix: usize| key_depth(&self.doc, keys).checked_sub(prefix);
        match (matched(&overlay, 4), matched(&base, 3)) {
            (Some(o), Some(b)) if o >= b => self.locate(&overlay),
            (Some(_), None) => self.locate(&overlay),
            _ => self.locate(&base),
        }
    }
}

fn distinct_sorted(seeds: &[u64]) -> Vec<u64> {
    let mut s = seeds.to_vec();
    s.sort_unstable();
    s.dedup();
    s
}

fn valid_name(name: &str) -> bool {
    name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

fn raw_stage_names(doc: &toml_edit::Document<String>) -> Vec<String> {
    doc.get("stages")
        .and_then(|s| s.as_table_like())
        .map(|t| t.iter().map(|(k, _)| k.to_string()).collect())
        .unwrap_or_default()
}

/// Deep merge: tables merge key by key, anything else is replaced.
fn merge(base: &mut toml::Table, overlay: &toml::Table) {
    for (key, value) in overlay {
        match (base.get_mut(key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            _ => {
                base.insert(key.clone(), value.clone());
            }
        }
    }
}

fn key_depth(doc: &toml_edit::Document<String>, keys: &[&str]) -> usize {
    let mut item: &toml_edit::Item = doc.as_item();
    for (depth, key) in keys.iter().enumerate() {
        match item.as_table_like().and_then(|t| t.get(key)) {
            Some(next) => item = next,
            None => return depth,
        }
    }
    keys.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str, profile: Option<&str>) -> Result<Pipeline> {
        Pipeline::parse(Path::new("pipeline.toml"), text.to_string(), profile)
    }

    const TEXT: &str = r#"
[pipeline]
default_profile = "small"
seed = 3

[stages.gen]
kind = "numbers"
shards = 2
params = { n = 100, scale = { a = 1.0, b = 2.0 } }

[stages.sum]
kind = "sum"
inputs = { values = "gen" }

[profiles.tiny.gen]
params = { n = 10, scale = { b = 5.0 } }
shards = 3

[profiles.small]
[profiles.paper]
"#;

    #[test]
    fn profiles_overlay_params_deeply() {
        let p = parse(TEXT, Some("tiny")).expect("parse");
        let gen_ = &p.stages["gen"];
        assert_eq!(gen_.shards, 3);
        assert_eq!(gen_.params["n"].as_integer(), Some(10));
        assert_eq!(gen_.params["scale"]["a"].as_float(), Some(1.0));
        assert_eq!(gen_.params["scale"]["b"].as_float(), Some(5.0));
        assert_eq!(p.default_seeds, [3]);
        assert!(p.default_targets.is_empty());
        let small = parse(TEXT, None).expect("parse");
        assert_eq!(small.profile, "small");
        assert_eq!(small.stages["gen"].params["n"].as_integer(), Some(100));
        assert_eq!(small.profiles, ["paper", "small", "tiny"]);
    }

    #[test]
    fn checkpoint_intervals_come_from_the_stage_its_profile_and_set() {
        let text = format!(
            "{TEXT}[profiles.quick.gen]\ncheckpoint_every = 2\n[stages.long]\nkind = \"x\"\ncheckpoint_every = 50\n"
        );
        let p = parse(&text, Some("tiny")).expect("parse");
        assert_eq!(p.stages["gen"].checkpoint_every, None);
        assert_eq!(p.stages["long"].checkpoint_every, Some(50));
        let mut quick = parse(&text, Some("quick")).expect("parse");
        assert_eq!(quick.stages["gen"].checkpoint_every, Some(2));
        let set: Override = "long.checkpoint_every=7".parse().expect("override");
        quick.apply(&[set]).expect("apply");
        assert_eq!(quick.stages["long"].checkpoint_every, Some(7));
        let zero: Override = "long.checkpoint_every=0".parse().expect("override");
        let err = quick.apply(&[zero]).expect_err("zero");
        assert!(err.to_string().contains("at least 1"), "{err}");
    }

    #[test]
    fn run_seeds_and_default_targets() {
        let p = parse(
            "[pipeline]\nseeds = [2, 0, 1, 0]\ntargets = [\"a\"]\n[stages.a]\nkind = \"x\"\n",
            None,
        )
        .expect("parse");
        assert_eq!(p.default_seeds, [0, 1, 2]);
        assert_eq!(p.default_targets, ["a"]);
        assert_eq!(parse("", None).expect("parse").default_seeds, [0]);
        let err = parse("[pipeline]\nseed = 1\nseeds = [1]\n", None).expect_err("both");
        assert!(
            err.to_string()
                .starts_with("pipeline.toml:3:1: [pipeline] sets both `seed` and `seeds`"),
            "{err}"
        );
        let err = parse("[pipeline]\nseeds = []\n", None).expect_err("empty");
        assert!(err.to_string().contains("`seeds` is empty"), "{err}");
    }

    #[test]
    fn a_profile_can_name_its_own_run_seeds() {
        let text = format!(
            "{TEXT}[profiles.decide]\nseeds = [4, 0, 4, 1]\n[profiles.decide.gen]\nshards = 5\n"
        );
        let p = parse(&text, Some("decide")).expect("parse");
        assert_eq!(p.default_seeds, [0, 1, 4]);
        assert_eq!(p.stages["gen"].shards, 5);
        assert_eq!(
            parse(&text, Some("tiny")).expect("parse").default_seeds,
            [3]
        );
        let err = parse(
            &format!("{TEXT}[profiles.decide]\nseeds = []\n"),
            Some("decide"),
        )
        .expect_err("empty");
        assert!(
            err.to_string()
                .starts_with("pipeline.toml:22:1: profile `decide`'s `seeds` is empty"),
            "{err}"
        );
        let err = parse("[stages.seeds]\nkind = \"x\"\n", None).expect_err("reserved");
        assert!(err.to_string().contains("`seeds` is reserved"), "{err}");
        let err = parse(
            "[stages.a]\nkind = \"x\"\n[profiles.small.a]\nshard = 2\n",
            None,
        )
        .expect_err("unknown overlay field");
        assert!(
            err.to_string()
                .starts_with("pipeline.toml:4:1: unknown field `shard`"),
            "{err}"
        );
    }

    #[test]
    fn malformed_toml_is_located() {
        let err =
            parse("[stages.a]\nkind = \"x\"\nparams = { n = }\n", None).expect_err("bad toml");
        let Error::Invalid(inv) = err else {
            panic!("not located: {err}")
        };
        let loc = inv.location.clone().expect("location");
        assert_eq!((loc.line, loc.column), (3, 16), "{inv}");
    }

    #[test]
    fn unknown_field_and_unknown_profile() {
        let err = parse("[stages.a]\nkind = \"x\"\nshard = 2\n", None).expect_err("unknown field");
        let text = err.to_string();
        assert!(
            text.starts_with("pipeline.toml:3:1: unknown field `shard`"),
            "{text}"
        );
        assert!(text.contains("`shards`"), "{text}");
        let err = parse(TEXT, Some("huge")).expect_err("unknown profile");
        assert!(
            err.to_string().contains("`paper`, `small`, `tiny`"),
            "{err}"
        );
    }

    #[test]
    fn overlay_of_undeclared_stage_is_located() {
        let err = parse(
            "[stages.a]\nkind = \"x\"\n[profiles.small.b]\nshards = 2\n",
            None,
        )
        .expect_err("bad overlay");
        assert!(
            err.to_string()
                .starts_with("pipeline.toml:3:17: profile `small` overlays stage `b`"),
            "{err}"
        );
    }

    #[test]
    fn an_unreadable_pipeline_path_is_the_users_error_and_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mistyped = dir.path().join("pipline.toml");
        for path in [mistyped.as_path(), dir.path()] {
            let err = Pipeline::load(path, None).expect_err("nothing to read");
            assert!(matches!(err, Error::Read { .. }), "{err:?}");
            assert!(err.is_user_error(), "{err:?}");
            assert!(
                err.to_string()
                    .starts_with(&format!("cannot read {}: ", path.display())),
                "{err}"
            );
        }
    }

    #[test]
    fn param_locations_prefer_the_overlay() {
        let p = parse(TEXT, Some("tiny")).expect("parse");
        let loc = p.locate_param("gen", &["n".into()]).expect("loc");
        assert_eq!(loc.line, 16);
        let loc = p
            .locate_param("gen", &["scale".into(), "a".into()])
            .expect("loc");
        assert_eq!(loc.line, 9);
    }
}
