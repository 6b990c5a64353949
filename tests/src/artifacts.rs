//! The test kinds' artifact types.

use osms_core::Artifact;
use osms_make::{Sharded, Summarize};
use serde::{Deserialize, Serialize};

/// Rows of numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Numbers {
    pub rows: Vec<Vec<f64>>,
}
impl Artifact for Numbers {
    const TYPE_TAG: &'static str = "test.numbers";
    /// 2: itemised kinds store it as a manifest of their shards.
    const SCHEMA_VERSION: u16 = 2;
}
impl Sharded for Numbers {
    type Item = Vec<f64>;
    fn take_items(&mut self) -> Vec<Vec<f64>> {
        std::mem::take(&mut self.rows)
    }
    fn set_items(&mut self, items: Vec<Vec<f64>>) {
        self.rows = items;
    }
}
impl Summarize for Numbers {
    fn summary(&self) -> serde_json::Value {
        let n: usize = self.rows.iter().map(Vec::len).sum();
        let sum: f64 = self.rows.iter().flatten().sum();
        serde_json::json!({ "rows": self.rows.len(), "values": n, "mean": if n > 0 { sum / n as f64 } else { 0.0 } })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Total {
    pub count: u64,
    pub sum: f64,
}
impl Artifact for Total {
    const TYPE_TAG: &'static str = "test.total";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Total {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({ "count": self.count, "sum": self.sum })
    }
}

/// Final states of boxes thrown onto a plane in MuJoCo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Drops {
    /// Per drop: final qpos (7) of the free joint.
    pub finals: Vec<Vec<f64>>,
}
impl Artifact for Drops {
    const TYPE_TAG: &'static str = "test.drops";
    /// 2: itemised kinds store it as a manifest of their shards.
    const SCHEMA_VERSION: u16 = 2;
}
impl Sharded for Drops {
    type Item = Vec<f64>;
    fn take_items(&mut self) -> Vec<Vec<f64>> {
        std::mem::take(&mut self.finals)
    }
    fn set_items(&mut self, items: Vec<Vec<f64>>) {
        self.finals = items;
    }
}
impl Summarize for Drops {
    fn summary(&self) -> serde_json::Value {
        let n = self.finals.len().max(1) as f64;
        let mean_z: f64 = self.finals.iter().map(|q| q[2]).sum::<f64>() / n;
        serde_json::json!({ "drops": self.finals.len(), "mean_final_z_m": mean_z })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Combined {
    pub total: f64,
    pub drops: u64,
    pub reference_rows: u64,
}
impl Artifact for Combined {
    const TYPE_TAG: &'static str = "test.combined";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Combined {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

/// Every gathered total, with the instance it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gathered {
    /// (`#fold@seed` of the member, its sum), in the order the slot received them.
    pub members: Vec<(String, f64)>,
}
impl Artifact for Gathered {
    const TYPE_TAG: &'static str = "test.gathered";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Gathered {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}
