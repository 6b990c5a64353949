//! A figure of the report as an artifact.

use osms_core::Artifact;
use osms_make::Summarize;

use crate::plot::Figure;

impl Artifact for Figure {
    const TYPE_TAG: &'static str = "report.figure";
    const SCHEMA_VERSION: u16 = 1;
}

impl Summarize for Figure {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "id": self.id,
            "title": self.title,
            "panels": self.panels.iter().map(|p| serde_json::json!({
                "title": p.title,
                "series": p.series.iter().map(|s| (s.name.clone(), s.points.len())).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
        })
    }
    fn text(&self) -> Option<String> {
        Some(format!(
            "{}\n\n{}\n\n`osms export` writes it as SVG, PNG and CSV.",
            self.title, self.caption
        ))
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        // A rendering failure leaves the data, which is what the CSV holds.
        Figure::files(self)
            .unwrap_or_else(|_| vec![(format!("{}.csv", self.id), self.csv().into_bytes())])
    }
}
