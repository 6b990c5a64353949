//! The ablations of paper 6.4 (and the label and validation-model ablations beyond it) as an
//! artifact: their tables and claims.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::Table;
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::claims::{self, Claim};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ablations {
    pub tables: Vec<Table>,
    pub claims: Vec<Claim>,
}

impl Artifact for Ablations {
    const TYPE_TAG: &'static str = "report.ablations";
    // 2: claims carry intervals; the means-only verdict "does not hold" is gone.
    const SCHEMA_VERSION: u16 = 2;
}

impl Ablations {
    pub fn index(&self) -> String {
        let mut s = String::from(
            "# osms ablations\n\nThe ablations of paper 6.4 (`osms make ablations`), with the \
             paper's values beside ours, and two beyond the paper (the labels of D_*'s \
             perturbed survivors; validation's error model). `docs/report.md` explains how to \
             read them.\n\n",
        );
        for t in &self.tables {
            s.push_str(&t.section());
        }
        let _ = writeln!(s, "## Claims check\n\n{}", claims::markdown(&self.claims));
        s
    }
}

impl Summarize for Ablations {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "tables": self.tables.iter().map(Table::json).collect::<Vec<_>>(),
            "claims": self.claims,
        })
    }
    fn text(&self) -> Option<String> {
        Some(self.index())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut files = vec![("index.md".to_string(), self.index().into_bytes())];
        for t in &self.tables {
            files.extend(t.files());
        }
        let claims = serde_json::to_string_pretty(&self.claims).unwrap_or_default() + "\n";
        files.push(("claims.json".into(), claims.into_bytes()));
        files
    }
}
