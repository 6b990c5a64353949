//! A trained flow-matching student and its learning curve.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::student::Student;

/// A trained student and what it was trained on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudentArtifact {
    pub student: Student,
    /// The fold this student is held out from (cross-fitted students), if any.
    pub fold: Option<(u32, u32)>,
    /// The dataset items (condition draws) the student trained on, held-out curve rollouts
    /// included, in order.
    pub items: Vec<u32>,
}

impl Artifact for StudentArtifact {
    const TYPE_TAG: &'static str = "policy.student_artifact";
    /// 3: the params have `arm_target` (issue 54).
    /// 4: the params have `target_labels` (issue 54).
    /// 5: the params choose the `network` (and carry the `unet`'s shape); the flow network
    /// holds a backbone, an MLP or a U-Net (issue 54, item 4).
    const SCHEMA_VERSION: u16 = 5;
}

impl Summarize for StudentArtifact {
    fn summary(&self) -> serde_json::Value {
        let s = &self.student;
        let last = s.curve.last();
        serde_json::json!({
            "fold": self.fold.map(|(i, n)| format!("{i} of {n}")),
            "items": self.items.len(),
            "train_rollouts": s.train_rollouts,
            "train_samples": s.train_samples,
            "heldout_rollouts": s.heldout_rollouts,
            "parameters": s.net.parameter_count(),
            "history": s.params.history,
            "chunk": s.params.chunk,
            "euler_steps": s.params.euler_steps,
            "steps": last.map(|c| c.step),
            "train_loss": last.map(|c| c.train_loss),
            "validation_loss": last.and_then(|c| c.validation_loss),
        })
    }

    fn text(&self) -> Option<String> {
        let s = &self.student;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "flow-matching student: {} frames of history, chunks of {} steps, {} Euler steps, hidden {:?} ({} parameters)",
            s.params.history,
            s.params.chunk,
            s.params.euler_steps,
            s.params.hidden,
            s.net.parameter_count()
        );
        let _ = writeln!(
            out,
            "trained on {} rollouts ({} steps), {} held out for the validation loss{}\n",
            s.train_rollouts,
            s.train_samples,
            s.heldout_rollouts,
            self.fold
                .map(|(i, n)| format!("; cross-fitted: fold {i} of {n} held out"))
                .unwrap_or_default()
        );
        let _ = writeln!(
            out,
            "Learning curve (flow-matching loss per element of the standardised chunk):\n"
        );
        let mut t = Table::new(
            "curve",
            "Learning curve",
            vec![
                Column::new("train loss", Unit::Number(4)),
                Column::new("validation loss", Unit::Number(4)),
                Column::new("lr", Unit::Scientific(2)),
            ],
        );
        let stride = s.curve.len().div_ceil(20).max(1);
        for (i, c) in s.curve.iter().enumerate() {
            if i % stride != 0 && i + 1 != s.curve.len() {
                continue;
            }
            t.push(
                c.step.to_string(),
                vec![
                    Cell::one(f64::from(c.train_loss)),
                    Cell::opt(c.validation_loss.map(f64::from)),
                    Cell::one(f64::from(c.lr)),
                ],
            );
        }
        out.push_str(&t.markdown_with(Layout::numbered("steps")));
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from("step,train_loss,validation_loss,lr\n");
        for c in &self.student.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{}",
                c.step,
                c.train_loss,
                c.validation_loss.map(|v| v.to_string()).unwrap_or_default(),
                c.lr
            );
        }
        vec![("curve.csv".into(), csv.into_bytes())]
    }
}
