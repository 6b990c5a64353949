//! DART-IL and DAgger-IL beside Table II (issue 68, beyond the paper) as an artifact: the table
//! and Ours-IL's claims against each.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::Table;
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::claims::{self, Claim};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Baselines {
    pub table: Table,
    pub claims: Vec<Claim>,
}

impl Artifact for Baselines {
    const TYPE_TAG: &'static str = "report.baselines";
    const SCHEMA_VERSION: u16 = 1;
}

impl Baselines {
    pub fn index(&self) -> String {
        let mut s = String::from(
            "# osms baselines\n\nBeyond the paper (`osms make baselines`): the standard remedies \
             for covariate shift, DART-IL and DAgger-IL, beside Table II's rows on the same \
             held-out conditions with the same student protocol, and Ours-IL against each. \
             `docs/report.md` explains how to read them.\n\n",
        );
        s.push_str(&self.table.section());
        let _ = writeln!(s, "## Claims check\n\n{}", claims::markdown(&self.claims));
        s
    }
}

impl Summarize for Baselines {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "tables": [self.table.json()],
            "claims": self.claims,
        })
    }
    fn text(&self) -> Option<String> {
        Some(self.index())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut files = vec![("index.md".to_string(), self.index().into_bytes())];
        files.extend(self.table.files());
        let claims = serde_json::to_string_pretty(&self.claims).unwrap_or_default() + "\n";
        files.push(("claims.json".into(), claims.into_bytes()));
        files
    }
}
