//! The interventional outcome sensitivity profile (Eq. 1) as an artifact, and S_IOS per offset.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::{Sharded, Summarize};
use serde::{Deserialize, Serialize};

use crate::ios::{IosItem, IosParams, IosSample};

/// S_IOS at one offset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IosRow {
    pub offset: i64,
    /// Interventions measured (windows that fit inside the rollout).
    pub n: usize,
    pub sensitivity: f64,
    pub ci_low: f64,
    pub ci_high: f64,
    /// Fraction of interventions that flipped success.
    pub success_change_rate: f64,
    pub mean_abs_force_change_n: f64,
}

/// The profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IosProfile {
    pub params: IosParams,
    /// δ_f used to normalise f_max (N).
    pub force_scale_n: f64,
    pub items: Vec<IosItem>,
}

impl Artifact for IosProfile {
    const TYPE_TAG: &'static str = "method.ios_profile";
    const SCHEMA_VERSION: u16 = 1;
}

impl Sharded for IosProfile {
    type Item = IosItem;
    fn take_items(&mut self) -> Vec<IosItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<IosItem>) {
        self.items = items;
    }
}

impl IosProfile {
    /// S_IOS per offset, in offset order.
    pub fn rows(&self) -> Vec<IosRow> {
        self.params
            .offsets()
            .into_iter()
            .map(|offset| {
                let s: Vec<&IosSample> = self
                    .items
                    .iter()
                    .flat_map(|i| &i.samples)
                    .filter(|s| s.offset == offset)
                    .collect();
                let n = s.len();
                let v: Vec<f64> = s
                    .iter()
                    .map(|s| {
                        (f64::from(u8::from(s.success_changed))
                            + s.force_change_n.abs() / self.force_scale_n)
                            / s.norm
                    })
                    .collect();
                let nf = n.max(1) as f64;
                let mean = v.iter().sum::<f64>() / nf;
                let var = if n > 1 {
                    v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1) as f64
                } else {
                    0.0
                };
                let half = 1.96 * (var / nf).sqrt();
                IosRow {
                    offset,
                    n,
                    sensitivity: mean,
                    ci_low: mean - half,
                    ci_high: mean + half,
                    success_change_rate: s.iter().filter(|s| s.success_changed).count() as f64 / nf,
                    mean_abs_force_change_n: s.iter().map(|s| s.force_change_n.abs()).sum::<f64>()
                        / nf,
                }
            })
            .collect()
    }

    /// The offset with the highest sensitivity.
    pub fn peak(&self) -> Option<IosRow> {
        self.rows()
            .into_iter()
            .filter(|r| r.n > 0)
            .max_by(|a, b| a.sensitivity.total_cmp(&b.sensitivity))
    }
}

impl Summarize for IosProfile {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "rollouts": self.items.len(),
            "window": self.params.window,
            "size": self.params.size,
            "peak_offset": self.peak().map(|r| r.offset),
            "rows": self.rows(),
        })
    }

    fn text(&self) -> Option<String> {
        let p = &self.params;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "IOS profile (Eq. 1): {} D_R rollouts, {}-step arm windows starting at k_e + offset, {} draws of ‖Δζ‖ = {} each; d_Y = |Δ success| + |Δ f_max| / {} N\n",
            self.items.len(),
            p.window,
            p.draws,
            p.size,
            self.force_scale_n
        );
        let mut t = Table::new(
            "ios_profile",
            "IOS profile",
            vec![
                Column::new("window", Unit::Text),
                Column::new("n", Unit::Count),
                Column::new("S_IOS", Unit::Number(3)),
                Column::new("95% CI", Unit::Text),
                Column::new("success flips", Unit::Percent),
                Column::new("mean |Δ f_max| (N)", Unit::Number(2)),
            ],
        );
        let peak = self.peak().map(|r| r.offset);
        for r in self.rows() {
            let mark = match (Some(r.offset) == peak, r.offset == -(p.window as i64)) {
                (true, true) => " (peak, paper's OSW)",
                (true, false) => " (peak)",
                (false, true) => " (paper's OSW)",
                (false, false) => "",
            };
            let window = Cell::text(format!(
                "k_e{:+} … k_e{:+}",
                r.offset,
                r.offset + p.window as i64 - 1
            ));
            let measured = r.n > 0;
            t.push(
                format!("{:+}{mark}", r.offset),
                vec![
                    window,
                    Cell::one(r.n as f64),
                    Cell::opt(measured.then_some(r.sensitivity)),
                    if measured {
                        Cell::text(format!("[{:.3}, {:.3}]", r.ci_low, r.ci_high))
                    } else {
                        Cell::opt(None)
                    },
                    Cell::opt(measured.then_some(r.success_change_rate)),
                    Cell::opt(measured.then_some(r.mean_abs_force_change_n)),
                ],
            );
        }
        out.push_str(&t.markdown_with(Layout::numbered("offset")));
        if let Some(peak) = self.peak() {
            let paper = self
                .rows()
                .into_iter()
                .find(|r| r.offset == -(p.window as i64));
            let _ = writeln!(
                out,
                "\nsensitivity peaks at offset {:+}; the paper's window (offset {:+}) {}",
                peak.offset,
                -(p.window as i64),
                match paper {
                    Some(w) if w.offset == peak.offset => "is the peak".to_string(),
                    Some(w) if w.ci_high >= peak.ci_low => format!(
                        "is not the peak but within its interval (S_IOS {:.3} vs {:.3})",
                        w.sensitivity, peak.sensitivity
                    ),
                    Some(w) => format!(
                        "is below the peak (S_IOS {:.3} vs {:.3})",
                        w.sensitivity, peak.sensitivity
                    ),
                    None => "was not profiled (set the offsets to include it)".to_string(),
                }
            );
        }
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "offset,n,sensitivity,ci_low,ci_high,success_change_rate,mean_abs_force_change_n\n",
        );
        for r in self.rows() {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{}",
                r.offset,
                r.n,
                r.sensitivity,
                r.ci_low,
                r.ci_high,
                r.success_change_rate,
                r.mean_abs_force_change_n
            );
        }
        vec![("ios_profile.csv".into(), csv.into_bytes())]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_average_d_y_over_the_norm_per_offset() {
        let sample = |offset, norm, flip, df| IosSample {
            offset,
            norm,
            success_changed: flip,
            force_change_n: df,
        };
        let profile = IosProfile {
            params: IosParams {
                first_offset: -8,
                last_offset: 0,
                stride: 8,
                ..IosParams::default()
            },
            force_scale_n: 80.0,
            items: vec![IosItem {
                item: 0,
                event_step: 20,
                success: true,
                samples: vec![
                    // d_Y / ‖Δζ‖ = (1 + 40/80) / 0.5 = 3 and (0 + 8/80) / 0.5 = 0.2.
                    sample(-8, 0.5, true, -40.0),
                    sample(-8, 0.5, false, 8.0),
                    sample(0, 0.25, false, 2.0),
                ],
            }],
        };
        let rows = profile.rows();
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].offset, rows[0].n), (-8, 2));
        assert!((rows[0].sensitivity - 1.6).abs() < 1e-12);
        // sd of {3, 0.2} is 1.4·√2; the half-width is 1.96 · sd / √2 = 2.744.
        assert!((rows[0].ci_high - rows[0].sensitivity - 2.744).abs() < 1e-9);
        assert!((rows[0].success_change_rate - 0.5).abs() < 1e-12);
        assert!((rows[0].mean_abs_force_change_n - 24.0).abs() < 1e-12);
        assert!((rows[1].sensitivity - 0.1).abs() < 1e-12);
        assert_eq!(profile.peak().map(|r| r.offset), Some(-8));
    }
}
