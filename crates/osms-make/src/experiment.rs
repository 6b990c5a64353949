//! Named experiments (`osms exp`): the overrides of a run and the instances each of its points
//! produced, kept as a small record under `state/experiments/NAME.json`. The artifacts
//! themselves are ordinary store entries; the record is what `exp show` reads and what keeps
//! them from `gc` until `exp rm`.

use std::collections::{BTreeMap, BTreeSet};

use osms_store::{Hash, Store};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::exec::{MakeOptions, MakeReport, Observer};
use crate::overrides::Override;
use crate::plan::Plan;

const DIR: &str = "experiments";
/// Bumped when the record's layout changes; older records are refused with a hint.
pub const RECORD_VERSION: u32 = 1;

/// One `--sweep STAGE.PATH=a,b,c`: a knob and its values.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    pub knob: String,
    pub values: Vec<Override>,
}

impl std::str::FromStr for Axis {
    type Err = Error;

    fn from_str(text: &str) -> Result<Self> {
        let (knob, values) = text.split_once('=').ok_or_else(|| {
            Error::usage(format!(
                "--sweep `{text}`: no `=`\nhint: write STAGE.PATH=a,b,c, e.g. `--sweep student_ours.steps=500,1000,2000`"
            ))
        })?;
        let values: Vec<Override> = top_level(values)
            .into_iter()
            .map(|v| {
                let o = format!("{knob}={}", v.trim()).parse::<Override>();
                o.map(|o| Override {
                    flag: "--sweep",
                    ..o
                })
            })
            .collect::<Result<_>>()?;
        let mut seen = Vec::new();
        for v in &values {
            let shown = v.value_text();
            if seen.contains(&shown) {
                return Err(Error::usage(format!(
                    "--sweep `{text}`: the value {shown} is listed twice\nhint: name each value once"
                )));
            }
            seen.push(shown);
        }
        Ok(Axis {
            knob: values[0].knob(),
            values,
        })
    }
}

/// `a,b,c` split at the commas outside brackets, braces and quotes, so an array or table
/// value (`[512, 512],[256, 256]`) stays one value.
fn top_level(values: &str) -> Vec<&str> {
    let (mut depth, mut quoted, mut start) = (0i32, None, 0);
    let mut out = Vec::new();
    for (i, c) in values.char_indices() {
        match (quoted, c) {
            (Some(q), c) if c == q => quoted = None,
            (Some(_), _) => {}
            (None, '"' | '\'') => quoted = Some(c),
            (None, '[' | '{') => depth += 1,
            (None, ']' | '}') => depth -= 1,
            (None, ',') if depth == 0 => {
                out.push(&values[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&values[start..]);
    out
}

/// The points of a sweep: the product of its axes, the first axis varying slowest; one point
/// without overrides if there are no axes.
pub fn points(axes: &[Axis]) -> Vec<Vec<Override>> {
    axes.iter().fold(vec![Vec::new()], |acc, axis| {
        acc.iter()
            .flat_map(|point| {
                axis.values.iter().map(move |v| {
                    let mut p = point.clone();
                    p.push(v.clone());
                    p
                })
            })
            .collect()
    })
}

/// A named experiment as recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    pub version: u32,
    pub name: String,
    pub profile: String,
    /// The targets as given (or the pipeline's `experiment_targets`).
    pub targets: Vec<String>,
    pub seeds: Vec<u64>,
    /// The `--set` overrides of every point, as `STAGE.PATH=VALUE`.
    pub set: Vec<String>,
    /// The swept knobs, in axis order.
    pub axes: Vec<String>,
    pub points: Vec<Point>,
    /// The held-out stages (`[pipeline] held_out`) that the targets read.
    pub reads_held_out: Vec<String>,
}

/// One point of an experiment (the only one if it sweeps nothing).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Point {
    /// The value of each swept knob at this point, in axis order.
    pub sweep: Vec<String>,
    /// Every override in force: the experiment's `--set`, then this point's sweep values.
    pub overrides: Vec<String>,
    /// Every instance the point's targets needed, in dependency order.
    pub instances: Vec<PointInstance>,
    /// Instances that failed or were skipped (the point is incomplete if any).
    pub failed: Vec<String>,
}

/// One built (or found) instance of a point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointInstance {
    /// `stage#fold@seed`, as a plain make names it.
    pub instance: String,
    pub stage: String,
    pub kind: String,
    pub run_seed: Option<u64>,
    /// Whether the point's targets name this instance's stage.
    pub target: bool,
    pub key: Hash,
    pub content_hash: Hash,
}

impl Point {
    /// The knob -> value pairs in force at this point.
    pub fn knobs(&self) -> Vec<(String, String)> {
        let mut out: Vec<(String, String)> = Vec::new();
        for o in &self.overrides {
            let (k, v) = o.split_once('=').unwrap_or((o, ""));
            match out.iter_mut().find(|(known, _)| known == k) {
                Some(slot) => slot.1 = v.to_string(),
                None => out.push((k.to_string(), v.to_string())),
            }
        }
        out
    }
}

/// Experiment names: a letter, then letters, digits, `_`, `-`, `.`.
pub fn check_name(name: &str) -> Result<()> {
    let ok = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if ok {
        Ok(())
    } else {
        Err(Error::usage(format!(
            "`{name}` is not an experiment name\nhint: use letters, digits, `_`, `-` and `.`, starting with a letter"
        )))
    }
}

fn file(name: &str) -> String {
    format!("{DIR}/{name}.json")
}

/// The names of the recorded experiments, sorted (one directory listing).
pub fn names(store: &Store) -> Result<Vec<String>> {
    Ok(store
        .list_state(DIR)?
        .into_iter()
        .filter_map(|f| f.strip_suffix(".json").map(str::to_string))
        .collect())
}

/// The record of experiment `name`, if there is one.
pub fn load(store: &Store, name: &str) -> Result<Option<Experiment>> {
    check_name(name)?;
    let Some(bytes) = store.read_state(&file(name))? else {
        return Ok(None);
    };
    let path = store.state_path(&file(name));
    let exp: Experiment = serde_json::from_slice(&bytes).map_err(|e| {
        Error::usage(format!(
            "{}: not an experiment record: {e}\nhint: `osms exp rm {name}` removes it",
            path.display()
        ))
    })?;
    if exp.version != RECORD_VERSION {
        return Err(Error::usage(format!(
            "{}: an experiment record of version {}, this osms reads version {RECORD_VERSION}\nhint: run it again with `osms exp run {name} --force ...`, or `osms exp rm {name}`",
            path.display(),
            exp.version
        )));
    }
    Ok(Some(exp))
}

/// Every recorded experiment, by name.
pub fn load_all(store: &Store) -> Result<Vec<Experiment>> {
    names(store)?
        .iter()
        .filter_map(|n| load(store, n).transpose())
        .collect()
}

/// Writes the record. Callers hold the store lock.
pub fn save(store: &Store, exp: &Experiment) -> Result<()> {
    check_name(&exp.name)?;
    let mut text = serde_json::to_vec_pretty(exp).expect("experiment records serialise");
    text.push(b'\n');
    store.write_state(&file(&exp.name), &text)?;
    Ok(())
}

/// Removes the record (its artifacts go at the next `gc` unless something else keeps them).
/// Callers hold the store lock.
pub fn remove(store: &Store, name: &str) -> Result<bool> {
    check_name(name)?;
    let existed = store.read_state(&file(name))?.is_some();
    store.remove_state(&file(name))?;
    Ok(existed)
}

/// Every stage key the recorded experiments hold: what `gc` keeps for them.
pub fn kept_keys(store: &Store) -> Result<Vec<Hash>> {
    Ok(load_all(store)?
        .iter()
        .flat_map(|e| e.points.iter())
        .flat_map(|p| p.instances.iter().map(|i| i.key))
        .collect())
}

/// Refuses to record over experiment `name` unless `force`: a run that would replace another's
/// record must say so.
pub fn check_free(store: &Store, name: &str, force: bool) -> Result<()> {
    if !force && load(store, name)?.is_some() {
        return Err(Error::usage(format!(
            "experiment `{name}` exists\nhint: `osms exp run {name} --force ...` replaces it, `osms exp rm {name}` forgets it"
        )));
    }
    Ok(())
}

/// A sweep as one graph: the points' plans merged (`Plan::merge`: shared upstream work is one
/// instance), each point's targets named in the merged plan, and the held-out stages the
/// build reads.
pub struct Sweep {
    pub plan: Plan,
    /// Point k's stage name -> the merged plan's stage index.
    pub maps: Vec<BTreeMap<String, usize>>,
    /// Point k's targets, as the merged plan names them.
    pub point_targets: Vec<Vec<String>>,
    /// The held-out stages (`[pipeline] held_out`) that any point's targets read.
    pub reads_held_out: Vec<String>,
}

impl Sweep {
    /// Names `targets` (as one point's plan names them) in each point of the merged `plan`.
    pub fn new(
        plan: Plan,
        maps: Vec<BTreeMap<String, usize>>,
        targets: &[String],
        seeds: &[u64],
    ) -> Result<Self> {
        let point_targets: Vec<Vec<String>> = maps
            .iter()
            .map(|m| targets.iter().map(|t| plan.point_target(m, t)).collect())
            .collect();
        let all: Vec<String> = point_targets.iter().flatten().cloned().collect();
        let read: BTreeSet<&str> = plan
            .instances(&all, seeds)?
            .iter()
            .map(|id| plan.stages[id.stage].name.as_str())
            .collect();
        let reads_held_out = plan
            .held_out
            .iter()
            .filter(|h| read.contains(h.as_str()))
            .cloned()
            .collect();
        Ok(Sweep {
            plan,
            maps,
            point_targets,
            reads_held_out,
        })
    }

    /// Every point's targets: what one make of the merged plan builds.
    pub fn all_targets(&self) -> Vec<String> {
        self.point_targets.iter().flatten().cloned().collect()
    }
}

/// What an experiment records beside its points' instances.
pub struct RunSpec<'a> {
    pub name: &'a str,
    pub profile: String,
    /// The targets as given (or the pipeline's `experiment_targets`).
    pub targets: Vec<String>,
    pub seeds: Vec<u64>,
    /// The `--set` overrides of every point.
    pub set: &'a [Override],
    pub axes: &'a [Axis],
    /// Each point's sweep values (`points(axes)`).
    pub points: &'a [Vec<Override>],
    /// Replace an experiment of the same name.
    pub force: bool,
}

/// Builds `sweep` with `opts` (not a dry run) and records the experiment, holding the store
/// lock from the make through the record: a `gc` waiting for it would otherwise run in between
/// and remove the instances the record is about to name. The name is checked again under the
/// lock, as two runs of one name started together both passed `check_free`.
pub fn run(
    store: &Store,
    sweep: &Sweep,
    spec: RunSpec<'_>,
    opts: &MakeOptions,
    observer: &dyn Observer,
) -> Result<(Experiment, MakeReport)> {
    let lock = store.lock(|| observer.waiting_for_lock())?;
    if !spec.force && load(store, spec.name)?.is_some() {
        return Err(Error::usage(format!(
            "experiment `{name}` was recorded by another osms process while this one waited for the store lock\nhint: `osms exp run {name} --force ...` replaces it, or choose another name",
            name = spec.name
        )));
    }
    let report = crate::exec::make_holding(&sweep.plan, store, &lock, opts, observer)?;
    let set: Vec<String> = spec.set.iter().map(|o| o.to_string()).collect();
    let mut recorded = Vec::with_capacity(spec.points.len());
    for (k, point) in spec.points.iter().enumerate() {
        let target_stages: Vec<usize> = spec
            .targets
            .iter()
            .filter_map(|t| {
                sweep.maps[k]
                    .get(t.split(['#', '@']).next().unwrap_or(t))
                    .copied()
            })
            .collect();
        let mut overrides = set.clone();
        overrides.extend(point.iter().map(|o| o.to_string()));
        recorded.push(point_record(
            &sweep.plan,
            &report,
            &sweep.point_targets[k],
            &spec.seeds,
            &target_stages,
            point.iter().map(|o| o.value_text()).collect(),
            overrides,
        )?);
    }
    let exp = Experiment {
        version: RECORD_VERSION,
        name: spec.name.to_string(),
        profile: spec.profile,
        targets: spec.targets,
        seeds: spec.seeds,
        set,
        axes: spec.axes.iter().map(|a| a.knob.clone()).collect(),
        points: recorded,
        reads_held_out: sweep.reads_held_out.clone(),
    };
    save(store, &exp)?;
    drop(lock);
    Ok((exp, report))
}

/// The record of one point after a make of the merged sweep plan: its instances, named as a
/// plain make of that point would name them, with the keys the make reported.
fn point_record(
    plan: &Plan,
    report: &MakeReport,
    targets: &[String],
    seeds: &[u64],
    target_stages: &[usize],
    sweep: Vec<String>,
    overrides: Vec<String>,
) -> Result<Point> {
    let by_name: BTreeMap<&str, _> = report
        .instances
        .iter()
        .map(|r| (r.instance.as_str(), r))
        .collect();
    let mut instances = Vec::new();
    let mut failed = Vec::new();
    for id in plan.instances(targets, seeds)? {
        let shown = plan.display(id);
        let stage = &plan.stages[id.stage];
        match by_name
            .get(shown.as_str())
            .and_then(|r| Some((r.key?, r.content_hash?)))
        {
            Some((key, content_hash)) => instances.push(PointInstance {
                instance: format!("{}{}", stage.name, id.member().suffix()),
                stage: stage.name.clone(),
                kind: stage.info.name.to_string(),
                run_seed: id.run_seed,
                target: target_stages.contains(&id.stage),
                key,
                content_hash,
            }),
            None => failed.push(shown),
        }
    }
    Ok(Point {
        sweep,
        overrides,
        instances,
        failed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_are_the_product_of_the_axes_first_axis_slowest() {
        let a: Axis = "s.a=1,2,3".parse().expect("axis");
        let b: Axis = "t.b=x,y".parse().expect("axis");
        assert_eq!(a.knob, "s.a");
        let ps = points(&[a, b]);
        let shown: Vec<String> = ps
            .iter()
            .map(|p| {
                p.iter()
                    .map(|o| o.to_string())
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .collect();
        assert_eq!(
            shown,
            [
                "s.a=1 t.b=\"x\"",
                "s.a=1 t.b=\"y\"",
                "s.a=2 t.b=\"x\"",
                "s.a=2 t.b=\"y\"",
                "s.a=3 t.b=\"x\"",
                "s.a=3 t.b=\"y\""
            ]
        );
        assert_eq!(points(&[]), vec![Vec::<Override>::new()]);
        let err = "s.a=1,2,1".parse::<Axis>().expect_err("twice").to_string();
        assert!(err.contains("listed twice"), "{err}");
        let err = "s.a".parse::<Axis>().expect_err("no =").to_string();
        assert!(err.starts_with("--sweep `s.a`: no `=`"), "{err}");
        let arrays: Axis = "s.hidden=[512, 512],[256,256,256], \"a,b\""
            .parse()
            .expect("arrays");
        let shown: Vec<String> = arrays.values.iter().map(Override::value_text).collect();
        assert_eq!(shown, ["[512, 512]", "[256, 256, 256]", "\"a,b\""]);
    }

    #[test]
    fn a_later_override_of_a_knob_wins() {
        let p = Point {
            sweep: vec![],
            overrides: vec!["s.a=1".into(), "t.b=2".into(), "s.a=3".into()],
            instances: vec![],
            failed: vec![],
        };
        assert_eq!(
            p.knobs(),
            [
                ("s.a".to_string(), "3".to_string()),
                ("t.b".into(), "2".into())
            ]
        );
    }

    #[test]
    fn records_round_trip_and_names_are_checked() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("store");
        assert!(names(&store).expect("names").is_empty());
        let exp = Experiment {
            version: RECORD_VERSION,
            name: "lr-sweep".into(),
            profile: "tiny".into(),
            targets: vec!["eval".into()],
            seeds: vec![0],
            set: vec![],
            axes: vec!["s.lr".into()],
            points: vec![Point {
                sweep: vec!["0.1".into()],
                overrides: vec!["s.lr=0.1".into()],
                instances: vec![PointInstance {
                    instance: "eval@0".into(),
                    stage: "eval".into(),
                    kind: "k".into(),
                    run_seed: Some(0),
                    target: true,
                    key: Hash::of(b"key"),
                    content_hash: Hash::of(b"content"),
                }],
                failed: vec![],
            }],
            reads_held_out: vec![],
        };
        save(&store, &exp).expect("save");
        assert_eq!(names(&store).expect("names"), ["lr-sweep"]);
        assert_eq!(load(&store, "lr-sweep").expect("load"), Some(exp));
        assert_eq!(kept_keys(&store).expect("keys"), [Hash::of(b"key")]);
        assert!(remove(&store, "lr-sweep").expect("rm"));
        assert!(!remove(&store, "lr-sweep").expect("rm again"));
        assert!(load(&store, "lr-sweep").expect("load").is_none());
        for bad in ["", "1x", "a/b", "../x", "a b"] {
            assert!(check_name(bad).is_err(), "{bad}");
        }
    }
}
