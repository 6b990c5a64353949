//! Candidate sets η for every D_R rollout, from one generator.

use std::fmt::Write;

use osms_core::Artifact;
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::candidates::{CandidateSet, SearchParams};

/// One D_R rollout's entry: its η, or why it has none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateItem {
    /// Which draw of D_R's condition stream: (item, attempt).
    pub item: u32,
    pub attempt: u32,
    pub variant: String,
    /// The teacher's original outcome: refine a success, repair a failure.
    pub success: bool,
    /// Whether the window has all H_OS steps; incomplete windows get no search (Alg. 1).
    pub complete: bool,
    pub set: Option<CandidateSet>,
}

/// η for every D_R rollout with a complete window, from one generator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateSets {
    pub params: SearchParams,
    pub items: Vec<CandidateItem>,
}

impl Artifact for CandidateSets {
    const TYPE_TAG: &'static str = "method.candidates";
    const SCHEMA_VERSION: u16 = 1;
}

impl osms_make::Sharded for CandidateSets {
    type Item = CandidateItem;
    fn take_items(&mut self) -> Vec<CandidateItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<CandidateItem>) {
        self.items = items;
    }
}

/// Counts and means behind `osms show` on candidate sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateStats {
    pub generator: String,
    pub rollouts: usize,
    pub sets: usize,
    pub skipped_incomplete: usize,
    pub refine: usize,
    pub repair: usize,
    pub candidates: usize,
    pub mean_projection_residual: Option<f64>,
    pub mean_deviation: f64,
    pub mean_max_deviation: f64,
    pub mean_geodesic_length: Option<f64>,
    pub directions_shrunk: u64,
    pub unmatched: usize,
    pub mean_scale: f64,
}

impl CandidateSets {
    pub fn stats(&self) -> CandidateStats {
        let sets: Vec<(&CandidateItem, &CandidateSet)> = self
            .items
            .iter()
            .filter_map(|i| i.set.as_ref().map(|s| (i, s)))
            .collect();
        let n = sets.len().max(1) as f64;
        let mean =
            |f: &dyn Fn(&CandidateSet) -> f64| sets.iter().map(|(_, s)| f(s)).sum::<f64>() / n;
        let residuals: Vec<f64> = sets
            .iter()
            .filter_map(|(_, s)| s.projection.as_ref().map(|p| p.residual))
            .collect();
        let lengths: Vec<f64> = sets
            .iter()
            .flat_map(|(_, s)| {
                s.candidates
                    .iter()
                    .skip(1)
                    .filter_map(|c| c.geodesic_length)
            })
            .collect();
        let avg = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        CandidateStats {
            generator: self.params.generator.name().into(),
            rollouts: self.items.len(),
            sets: sets.len(),
            skipped_incomplete: self.items.iter().filter(|i| !i.complete).count(),
            refine: sets.iter().filter(|(i, _)| i.success).count(),
            repair: sets.iter().filter(|(i, _)| !i.success).count(),
            candidates: sets.iter().map(|(_, s)| s.candidates.len()).sum(),
            mean_projection_residual: avg(&residuals),
            mean_deviation: mean(&|s| s.mean_deviation()),
            mean_max_deviation: mean(&|s| s.max_deviation()),
            mean_geodesic_length: avg(&lengths),
            directions_shrunk: sets.iter().map(|(_, s)| u64::from(s.shrunk)).sum(),
            unmatched: sets.iter().filter(|(_, s)| !s.matched).count(),
            mean_scale: mean(&|s| s.scale),
        }
    }
}

impl Summarize for CandidateSets {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self.stats()).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        let st = self.stats();
        let opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.3}"));
        let mut s = String::new();
        let _ = writeln!(
            s,
            "generator {}: {} candidate sets of |η| = {} for {} D_R rollouts ({} to refine, {} to repair); {} incomplete windows skipped",
            st.generator,
            st.sets,
            2 * self.params.directions + 1,
            st.rollouts,
            st.refine,
            st.repair,
            st.skipped_incomplete
        );
        let _ = writeln!(
            s,
            "mean projection residual ‖G(z⁰) − ζ_org‖_W_a {}, mean deviation ‖ζ − ζ_org‖_W_a {:.3} (largest per set {:.3}), mean geodesic length {}",
            opt(st.mean_projection_residual),
            st.mean_deviation,
            st.mean_max_deviation,
            opt(st.mean_geodesic_length)
        );
        let _ = writeln!(
            s,
            "directions shrunk to stay in Z: {}; sets not matched to the geodesic deviation: {}; mean matching scale {:.3}",
            st.directions_shrunk, st.unmatched, st.mean_scale
        );
        let _ = writeln!(s, "per-candidate rows: `osms export` writes candidates.csv");
        Some(s)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "item,attempt,variant,success,candidate,direction,sign,latent_displacement,geodesic_length,deviation,shrink,scale,matched\n",
        );
        for item in &self.items {
            let Some(set) = &item.set else { continue };
            for (k, c) in set.candidates.iter().enumerate() {
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{},{},{},{},{},{},{},{},{}",
                    item.item,
                    item.attempt,
                    item.variant,
                    item.success,
                    k,
                    c.direction,
                    c.sign,
                    c.latent_displacement,
                    c.geodesic_length.map_or(String::new(), |v| v.to_string()),
                    c.deviation,
                    c.shrink,
                    set.scale,
                    set.matched
                );
            }
        }
        vec![("candidates.csv".into(), csv.into_bytes())]
    }
}
