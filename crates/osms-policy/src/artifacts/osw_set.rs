//! The OSW windows of a dataset.

use osms_core::Artifact;
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::osw::OswSpec;

/// One rollout's outcome-sensitive window and conditioning, without the rest of its record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OswSample {
    /// Which draw of the dataset's condition stream the rollout came from: (item, attempt).
    pub item: u32,
    pub attempt: u32,
    pub variant: String,
    pub success: bool,
    /// Whether the window has all H_OS steps.
    pub complete: bool,
    /// ζ_org, step-major (`[step][arm channel]`).
    pub zeta_org: Vec<f32>,
    /// ω̄: ω's features, the DR draws and the privileged state at the window's start.
    pub omega_bar: Vec<f32>,
}

/// The OSW windows of a dataset: what the manifold and the candidate search read, a small
/// fraction of the dataset's bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OswSet {
    pub osw: OswSpec,
    pub windows: Vec<OswSample>,
}

impl Artifact for OswSet {
    const TYPE_TAG: &'static str = "policy.osw_set";
    /// 2: ω̄ ends with the arm's servo targets.
    const SCHEMA_VERSION: u16 = 2;
}

impl Summarize for OswSet {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "windows": self.windows.len(),
            "complete": self.windows.iter().filter(|w| w.complete).count(),
            "successes": self.windows.iter().filter(|w| w.success).count(),
            "h_os": self.osw.h_os,
            "omega_bar_len": self.windows.first().map_or(0, |w| w.omega_bar.len()),
        })
    }
}
