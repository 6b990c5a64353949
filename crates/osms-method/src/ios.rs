//! The interventional outcome sensitivity profile (paper Eq. 1, measured rather than assumed):
//! how much a small change of the arm's actions in an H-step window changes the rollout's
//! outcome, as a function of where the window sits relative to the event step k_e.
//!
//! For a D_R rollout and a window W = {k_e + o, …, k_e + o + H − 1}, the window's recorded arm
//! actions ζ_W are replaced open loop by clip(ζ_W + Δζ, −1, 1), Δζ uniform on the sphere of
//! radius `size` (Euclidean over the window's arm entries); the teacher keeps the hand inside
//! the window and everything outside it, and the snippet runs through contact (unlike the
//! event-aligned intervention, which hands back at contact). The rollout's own DR stream is
//! reused, so without Δζ the rollout is the recorded one and every change is the
//! intervention's. With ‖Δζ‖ the norm after clipping,
//!
//! d_Y = |I_succ(τ') − I_succ(τ)| + |f_max(τ') − f_max(τ)| / δ_f,
//! S_IOS(o) = mean over rollouts and draws of d_Y / ‖Δζ‖,
//!
//! with a normal-approximation 95 % interval. f_max is 0 for a rollout without contact.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::rng::{self, StreamRng};
use osms_make::{Ctx, ItemStage, Numerics, Scale, Slot, StageError, Summarize};
use osms_policy::artifacts::Dataset;
use osms_policy::artifacts::Teacher;
use osms_policy::stages::numerics as policy_numerics;
use osms_sim::artifacts::WorldArtifact;
use osms_sim::{N_ACTION, N_ARM, World};
use serde::{Deserialize, Serialize};

use crate::intervene::{Intervention, Snippet};

/// The profile's settings. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IosParams {
    /// D_R rollouts profiled (the first ones of the dataset).
    pub rollouts: usize,
    /// Window starts relative to k_e: first_offset, first_offset + stride, …, up to
    /// last_offset. The paper's OSW is the offset −H.
    pub first_offset: i64,
    pub last_offset: i64,
    pub stride: usize,
    /// H: the window's length in control steps (the paper's H_OS).
    pub window: usize,
    /// Random Δζ per rollout and offset.
    pub draws: usize,
    /// ‖Δζ‖ before clipping (action units; every channel spans [−1, 1]).
    pub size: f64,
}

impl Default for IosParams {
    fn default() -> Self {
        IosParams {
            rollouts: 100,
            first_offset: -40,
            last_offset: 8,
            stride: 4,
            window: 8,
            draws: 4,
            size: 0.5,
        }
    }
}

impl IosParams {
    fn check(&self) -> Result<(), String> {
        if self.stride == 0 || self.window == 0 || self.draws == 0 {
            return Err("params.stride, params.window and params.draws must be at least 1".into());
        }
        if self.first_offset > self.last_offset {
            return Err(format!(
                "params.first_offset = {} is after params.last_offset = {}",
                self.first_offset, self.last_offset
            ));
        }
        if !(self.size > 0.0 && self.size.is_finite()) {
            return Err(format!("params.size = {} must be positive", self.size));
        }
        Ok(())
    }

    pub fn offsets(&self) -> Vec<i64> {
        (self.first_offset..=self.last_offset)
            .step_by(self.stride)
            .collect()
    }
}

/// One intervention's effect.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IosSample {
    pub offset: i64,
    /// ‖Δζ‖ after clipping.
    pub norm: f64,
    pub success_changed: bool,
    /// f_max(τ') − f_max(τ) (N).
    pub force_change_n: f64,
}

/// One rollout's interventions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IosItem {
    pub item: u32,
    pub event_step: usize,
    pub success: bool,
    pub samples: Vec<IosSample>,
}

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

impl osms_make::Sharded for IosProfile {
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
        let _ = writeln!(
            out,
            "| offset | window | n | S_IOS | 95% CI | success flips | mean |Δ f_max| (N) |\n|---:|---|---:|---:|---|---:|---:|"
        );
        let peak = self.peak().map(|r| r.offset);
        for r in self.rows() {
            let mark = match (Some(r.offset) == peak, r.offset == -(p.window as i64)) {
                (true, true) => " (peak, paper's OSW)",
                (true, false) => " (peak)",
                (false, true) => " (paper's OSW)",
                (false, false) => "",
            };
            if r.n == 0 {
                let _ = writeln!(
                    out,
                    "| {:+}{mark} | k_e{:+} … k_e{:+} | 0 | - | - | - | - |",
                    r.offset,
                    r.offset,
                    r.offset + p.window as i64 - 1
                );
                continue;
            }
            let _ = writeln!(
                out,
                "| {:+}{mark} | k_e{:+} … k_e{:+} | {} | {:.3} | [{:.3}, {:.3}] | {:.1}% | {:.2} |",
                r.offset,
                r.offset,
                r.offset + p.window as i64 - 1,
                r.n,
                r.sensitivity,
                r.ci_low,
                r.ci_high,
                100.0 * r.success_change_rate,
                r.mean_abs_force_change_n
            );
        }
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

/// One offset's window start and its perturbed snippets with their ‖Δζ‖.
type Plan = (i64, usize, Vec<(Vec<f32>, f64)>);

/// Δζ uniform on the sphere of radius `size` in `len` dimensions.
fn direction(rng: &mut StreamRng, len: usize, size: f64) -> Vec<f64> {
    loop {
        let v: Vec<f64> = (0..len).map(|_| rng::normal(rng)).collect();
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if n > 1e-12 {
            return v.into_iter().map(|x| x * size / n).collect();
        }
    }
}

/// The IOS profile of the first `rollouts` D_R rollouts; rollout i draws its Δζ from stream
/// ("item", i).
pub struct IosProfileStage;
impl ItemStage for IosProfileStage {
    const KIND: &'static str = "ios_profile";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data"),
    ];
    const DOC: &'static str =
        "the interventional outcome sensitivity profile (Eq. 1) around the event step k_e";
    type Params = IosParams;
    type Prepared = (World, Teacher, Dataset);
    type Item = IosItem;
    type Output = IosProfile;

    /// `rollouts` D_R rollouts profiled, each `draws` times.
    fn scale(params: &IosParams, inputs: &[(&str, f64)]) -> Scale {
        let n = Scale::input(inputs, "data").min(params.rollouts as f64);
        Scale {
            work: n * params.draws.max(1) as f64,
            size: n,
        }
    }

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, IosParams>) -> Result<Self::Prepared, StageError> {
        ctx.params.check()?;
        let data: Dataset = ctx.sharded("data")?;
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = data.task.clone();
        teacher.task.rollout.record_privileged = false;
        Ok((ctx.input::<WorldArtifact>("world")?.world()?, teacher, data))
    }
    fn n_items(&self, ctx: &Ctx<'_, IosParams>, p: &Self::Prepared) -> usize {
        ctx.params.rollouts.min(p.2.items.len())
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, IosParams>,
        (world, teacher, data): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<IosItem, StageError> {
        let p = ctx.params;
        let r = &data.items[index].rollout;
        let rec = &r.record;
        let k_e = rec.metrics.event_step as i64;
        let success = rec.outcome.success();
        let f0 = rec.metrics.max_force_n;
        // Every Δζ first (in offset order), so the snippets outlive the branching rollout.
        let len = p.window * N_ARM;
        let mut plans: Vec<Plan> = Vec::new();
        for offset in p.offsets() {
            let start = k_e + offset;
            if start < 0 || (start as usize) + p.window > rec.steps {
                continue;
            }
            let start = start as usize;
            let original: Vec<f32> = (start..start + p.window)
                .flat_map(|k| {
                    rec.intended[k * N_ACTION..k * N_ACTION + N_ARM]
                        .iter()
                        .copied()
                })
                .collect();
            let draws = (0..p.draws)
                .map(|_| {
                    let delta = direction(rng, len, p.size);
                    let zeta: Vec<f32> = original
                        .iter()
                        .zip(&delta)
                        .map(|(&z, d)| (f64::from(z) + d).clamp(-1.0, 1.0) as f32)
                        .collect();
                    let norm = zeta
                        .iter()
                        .zip(&original)
                        .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    (zeta, norm)
                })
                .collect();
            plans.push((offset, start, draws));
        }
        let mut base = Intervention::new(
            world,
            &teacher.task,
            rec.condition.clone(),
            r.dr_stream.rng(),
            None,
        );
        base.through_contact();
        let mut samples = Vec::new();
        for (offset, start, draws) in &plans {
            base.run_until(&teacher.agent, *start);
            let n = start * N_ACTION;
            if base.step_index() != *start || base.record().intended[..n] != rec.intended[..n] {
                return Err(format!(
                    "D_R item {}: the teacher's replay up to step {start} is not the recorded rollout ({} steps)\nhint: `teacher` must be the teacher that collected `data`",
                    r.item, rec.steps
                )
                .into());
            }
            let snapshot = base.snapshot();
            for (zeta, norm) in draws.iter().filter(|(_, n)| *n > 0.0) {
                base.restore(&snapshot);
                base.set_snippet(Some(Snippet {
                    start: *start,
                    zeta,
                }));
                base.run(&teacher.agent);
                let (outcome, metrics) = base.outcome();
                samples.push(IosSample {
                    offset: *offset,
                    norm: *norm,
                    success_changed: outcome.success() != success,
                    force_change_n: metrics.max_force_n - f0,
                });
            }
            base.restore(&snapshot);
        }
        Ok(IosItem {
            item: r.item,
            event_step: rec.metrics.event_step,
            success,
            samples,
        })
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, IosParams>,
        (_, teacher, _): Self::Prepared,
        items: Vec<IosItem>,
    ) -> Result<IosProfile, StageError> {
        Ok(IosProfile {
            params: ctx.params.clone(),
            force_scale_n: teacher.task.rollout.success.max_force_n,
            items,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_have_the_requested_size() {
        let mut rng = rng::stream(0, "test", "ios", 0);
        for _ in 0..20 {
            let d = direction(&mut rng, 56, 0.5);
            let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((n - 0.5).abs() < 1e-12, "{n}");
        }
    }

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
