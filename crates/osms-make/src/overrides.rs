//! `--set STAGE.PATH=VALUE`: one change to a stage's declaration, applied after the profile,
//! before the params are parsed into the kind's typed struct (so a wrong path or type fails
//! there, named by the override rather than by a line of pipeline.toml).

use std::fmt;
use std::str::FromStr;

use crate::error::{Error, Result, list};

/// What an override changes.
#[derive(Debug, Clone, PartialEq)]
pub enum Field {
    /// A param, by its dotted path inside the stage's `params` (tables are created as needed).
    Param(Vec<String>),
    Shards,
    Seed,
    /// How often a long stage checkpoints (not part of its key: the output is the same).
    CheckpointEvery,
}

/// One `STAGE.PATH=VALUE`. `PATH` is `shards`, `seed`, `checkpoint_every`, or a dotted path
/// into the stage's params (`params.` in front is allowed, and needed for a param of one of
/// those names).
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    pub stage: String,
    pub field: Field,
    pub value: toml::Value,
    /// As the user wrote it, for messages.
    pub text: String,
    /// The flag it came from (`--set`, or `--sweep` for one value of an axis).
    pub flag: &'static str,
}

impl Override {
    /// The path after the stage, as written in `STAGE.PATH` (without a `params.` prefix).
    pub fn path(&self) -> String {
        match &self.field {
            Field::Param(p) => p.join("."),
            Field::Shards => "shards".into(),
            Field::Seed => "seed".into(),
            Field::CheckpointEvery => "checkpoint_every".into(),
        }
    }

    /// `STAGE.PATH`, the name of the knob.
    pub fn knob(&self) -> String {
        format!("{}.{}", self.stage, self.path())
    }

    /// The value as TOML writes it (`200`, `"paper"`, `{ a = 1 }`).
    pub fn value_text(&self) -> String {
        value_text(&self.value)
    }

    pub(crate) fn desc(&self) -> String {
        format!("{} `{}`", self.flag, self.text)
    }

    pub(crate) fn integer(&self, what: &str, min: i64) -> Result<i64> {
        match self.value.as_integer() {
            Some(n) if n >= min => Ok(n),
            _ => Err(Error::invalid(
                None,
                format!(
                    "{}: `{what}` of stage `{}` takes an integer of at least {min}, not {}",
                    self.desc(),
                    self.stage,
                    self.value_text()
                ),
                Some(format!("e.g. `--set {}.{what}={}`", self.stage, min.max(1))),
            )),
        }
    }
}

impl fmt::Display for Override {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}={}", self.knob(), self.value_text())
    }
}

/// A TOML value on one line, as an inline table would hold it.
pub fn value_text(value: &toml::Value) -> String {
    let mut t = toml::Table::new();
    t.insert("v".into(), value.clone());
    toml::to_string(&t)
        .ok()
        .and_then(|s| s.trim().strip_prefix("v = ").map(str::to_string))
        .unwrap_or_else(|| value.to_string())
}

/// Reads `VALUE` as TOML (`200`, `1e-3`, `true`, `"text"`, `[1, 2]`, `{ a = 1 }`); anything
/// that is not TOML is a bare string, as in `dvc exp run -S dr=paper`.
pub fn parse_value(text: &str) -> toml::Value {
    format!("v = {text}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(text.to_string()))
}

impl FromStr for Override {
    type Err = Error;

    fn from_str(text: &str) -> Result<Self> {
        let bad = |why: String| {
            Error::usage(format!(
                "--set `{text}`: {why}\nhint: write STAGE.PATH=VALUE, e.g. `--set student_ours.steps=2000` or `--set heldout.shards=2`"
            ))
        };
        let (knob, value) = text.split_once('=').ok_or_else(|| bad("no `=`".into()))?;
        let mut parts: Vec<&str> = knob.trim().split('.').collect();
        if parts.len() < 2 || parts.iter().any(|p| p.is_empty()) {
            return Err(bad(format!(
                "`{knob}` names no field: a stage and a path, joined by `.`"
            )));
        }
        let stage = parts.remove(0).to_string();
        let field = match parts.as_slice() {
            ["shards"] => Field::Shards,
            ["seed"] => Field::Seed,
            ["checkpoint_every"] => Field::CheckpointEvery,
            ["params", rest @ ..] if !rest.is_empty() => {
                Field::Param(rest.iter().map(|s| s.to_string()).collect())
            }
            ["inputs" | "kind" | "folds", ..] => {
                return Err(bad(format!(
                    "`{}` changes the graph, not a knob; edit pipeline.toml for that",
                    parts[0]
                )));
            }
            rest => Field::Param(rest.iter().map(|s| s.to_string()).collect()),
        };
        Ok(Override {
            stage,
            field,
            value: parse_value(value.trim()),
            text: text.to_string(),
            flag: "--set",
        })
    }
}

/// Sets `value` at `path` inside `table`, creating tables on the way.
pub(crate) fn set_path(
    table: &mut toml::Table,
    path: &[String],
    value: toml::Value,
    o: &Override,
) -> Result<()> {
    let (last, parents) = path.split_last().expect("a param path has a segment");
    let mut at = table;
    for (depth, key) in parents.iter().enumerate() {
        let entry = at
            .entry(key.clone())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        at = match entry {
            toml::Value::Table(t) => t,
            other => {
                return Err(Error::invalid(
                    None,
                    format!(
                        "{}: param `{}` of stage `{}` is {}, not a table, so it has no `{}`",
                        o.desc(),
                        path[..=depth].join("."),
                        o.stage,
                        value_text(other),
                        path[depth + 1]
                    ),
                    Some(format!(
                        "set `{}.{}` itself",
                        o.stage,
                        path[..=depth].join(".")
                    )),
                ));
            }
        };
    }
    at.insert(last.clone(), value);
    Ok(())
}

/// The error of an override naming an undeclared stage.
pub(crate) fn unknown_stage<'a>(
    o: &Override,
    stages: impl IntoIterator<Item = &'a String>,
) -> Error {
    Error::invalid(
        None,
        format!("{}: no stage `{}` in the pipeline", o.desc(), o.stage),
        Some(format!("declared stages are {}", list(stages))),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Override {
        text.parse().expect("parses")
    }

    #[test]
    fn values_are_toml_else_strings() {
        assert_eq!(parse("a.n=200").value, toml::Value::Integer(200));
        assert_eq!(parse("a.lr=1e-3").value, toml::Value::Float(1e-3));
        assert_eq!(
            parse("a.dr=paper").value,
            toml::Value::String("paper".into())
        );
        assert_eq!(
            parse("a.dr=\"paper\"").value,
            toml::Value::String("paper".into())
        );
        assert_eq!(parse("a.on=true").value, toml::Value::Boolean(true));
        let t = parse("a.dr={ actuation_noise = 0.05 }");
        assert_eq!(t.value["actuation_noise"].as_float(), Some(0.05));
        assert_eq!(t.to_string(), "a.dr={ actuation_noise = 0.05 }");
    }

    #[test]
    fn paths_name_params_or_stage_fields() {
        assert_eq!(parse("s.shards=2").field, Field::Shards);
        assert_eq!(parse("s.checkpoint_every=5").field, Field::CheckpointEvery);
        assert_eq!(parse("s.seed=3").field, Field::Seed);
        assert_eq!(
            parse("s.params.seed=3").field,
            Field::Param(vec!["seed".into()])
        );
        assert_eq!(
            parse("s.ppo.iterations=10").field,
            Field::Param(vec!["ppo".into(), "iterations".into()])
        );
        assert_eq!(parse("s.ppo.iterations=10").knob(), "s.ppo.iterations");
        for bad in [
            "s",
            "s=1",
            "s.=1",
            ".n=1",
            "s..n=1",
            "s.inputs.world=w",
            "s.folds=2",
        ] {
            let err = bad.parse::<Override>().expect_err(bad).to_string();
            assert!(err.starts_with(&format!("--set `{bad}`: ")), "{err}");
            assert!(err.contains("hint: "), "{err}");
        }
    }

    #[test]
    fn set_path_creates_tables_and_refuses_to_descend_into_a_value() {
        let mut t: toml::Table = "n = 1\n[ppo]\nlr = 0.1\n".parse().expect("toml");
        let o = parse("s.ppo.iterations=5");
        set_path(
            &mut t,
            &["ppo".into(), "iterations".into()],
            o.value.clone(),
            &o,
        )
        .expect("set");
        set_path(&mut t, &["a".into(), "b".into()], o.value.clone(), &o).expect("set");
        assert_eq!(t["ppo"]["iterations"].as_integer(), Some(5));
        assert_eq!(t["ppo"]["lr"].as_float(), Some(0.1));
        assert_eq!(t["a"]["b"].as_integer(), Some(5));
        let err = set_path(&mut t, &["n".into(), "x".into()], o.value.clone(), &o)
            .expect_err("n is a number")
            .to_string();
        assert!(
            err.contains("param `n` of stage `s` is 1, not a table"),
            "{err}"
        );
    }
}
