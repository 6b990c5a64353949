//! A trained teacher and its learning curve.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::catch::CatchTaskSpec;
use crate::ppo::{Agent, IterationStats};

/// A trained teacher: the task it was trained on (needed to replay it) and the agent, whose
/// learning curve is kept with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Teacher {
    pub task: CatchTaskSpec,
    pub agent: Agent,
}

impl Artifact for Teacher {
    const TYPE_TAG: &'static str = "policy.teacher";
    /// 2: the task has `actor_inputs` and the reward `residual_rate` (issue 54).
    const SCHEMA_VERSION: u16 = 2;
}

/// Means of the curve's points over consecutive blocks of iterations.
fn curve_blocks(curve: &[IterationStats], rows: usize) -> Vec<(u32, u32, [f64; 5])> {
    let block = curve.len().div_ceil(rows.max(1)).max(1);
    curve
        .chunks(block)
        .map(|c| {
            let n = c.len() as f64;
            let mean = |f: &dyn Fn(&IterationStats) -> f64| c.iter().map(f).sum::<f64>() / n;
            let f_max: Vec<f64> = c.iter().filter_map(|s| s.mean_f_max_n).collect();
            (
                c[0].iteration,
                c[c.len() - 1].iteration,
                [
                    mean(&|s| s.mean_return),
                    mean(&|s| s.success_rate),
                    mean(&|s| s.completion_rate),
                    if f_max.is_empty() {
                        f64::NAN
                    } else {
                        f_max.iter().sum::<f64>() / f_max.len() as f64
                    },
                    mean(&|s| s.clip_fraction),
                ],
            )
        })
        .collect()
}

impl Summarize for Teacher {
    fn summary(&self) -> serde_json::Value {
        let curve = &self.agent.curve;
        let last = curve_blocks(curve, 10).pop();
        serde_json::json!({
            "iterations": curve.len(),
            "env_steps": curve.iter().map(|s| s.steps).sum::<u64>(),
            "episodes": curve.iter().map(|s| u64::from(s.episodes)).sum::<u64>(),
            "obs_len": self.agent.obs_norm.mean.len(),
            "actor_inputs": self.task.actor_inputs,
            "actor_obs_len": self.agent.actor_obs_len(),
            "act_len": self.agent.log_std.len(),
            "last_tenth": last.map(|(a, b, m)| serde_json::json!({
                "iterations": [a, b],
                "return": m[0],
                "success_rate": m[1],
                "completion_rate": m[2],
                "f_max_n": m[3].is_finite().then_some(m[3]),
            })),
            "note": "curve rates are under exploration noise; eval_teacher measures the deterministic policy",
        })
    }

    fn text(&self) -> Option<String> {
        let mut t = Table::new(
            "curve",
            "Learning curve",
            vec![
                Column::new("return", Unit::Number(2)),
                Column::new("success", Unit::Percent),
                Column::new("completion", Unit::Percent),
                Column::new("f_max (N)", Unit::Number(1)),
                Column::new("clip fraction", Unit::Number(3)),
            ],
        );
        for (a, b, m) in curve_blocks(&self.agent.curve, 20) {
            t.push(
                format!("{a}–{b}"),
                vec![
                    Cell::one(m[0]),
                    Cell::one(m[1]),
                    Cell::one(m[2]),
                    Cell::opt(m[3].is_finite().then_some(m[3])),
                    Cell::one(m[4]),
                ],
            );
        }
        Some(format!(
            "Learning curve (means over blocks of iterations, under exploration noise):\n\n{}",
            t.markdown_with(Layout::plain("iterations"))
        ))
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "iteration,episodes,steps,return,length,success_rate,completion_rate,f_max_n,policy_loss,value_loss,entropy,approx_kl,clip_fraction,action_std\n",
        );
        for s in &self.agent.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                s.iteration,
                s.episodes,
                s.steps,
                s.mean_return,
                s.mean_length,
                s.success_rate,
                s.completion_rate,
                s.mean_f_max_n.map(|f| f.to_string()).unwrap_or_default(),
                s.policy_loss,
                s.value_loss,
                s.entropy,
                s.approx_kl,
                s.clip_fraction,
                s.action_std
            );
        }
        vec![("curve.csv".into(), csv.into_bytes())]
    }
}
