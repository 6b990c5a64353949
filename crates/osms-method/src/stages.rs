//! The method's stage kinds: `manifold` (the OSW motion manifold from D_M's windows) and
//! `candidates` (η for every D_R rollout, by one of the four generators).

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Numerics, Slot, Stage, StageError, Summarize};
use osms_policy::artifacts::OswSet;
use serde::{Deserialize, Serialize};

use crate::candidates::{CandidateSet, Generator, SearchParams, candidate_set};
use crate::cvae::{Cvae, ManifoldParams, Window, train};

/// The method's kinds run osms-nn's kernels (and nothing of MuJoCo).
fn method_numerics() -> Vec<Numerics> {
    vec![Numerics {
        name: "osms-nn",
        version: osms_nn::NUMERICS_VERSION.to_string(),
    }]
}

impl Summarize for Cvae {
    fn summary(&self) -> serde_json::Value {
        let last = self.curve.last();
        serde_json::json!({
            "conditional": self.params.conditional,
            "latent": self.params.latent,
            "h_os": self.h_os,
            "omega_bar_len": self.omega_mean.len(),
            "windows_train": self.windows_train,
            "windows_heldout": self.windows_heldout,
            "epochs": self.curve.len(),
            "train_reconstruction": last.map(|c| c.reconstruction),
            "heldout_reconstruction": last.map(|c| c.heldout_reconstruction),
            "heldout_prior_reconstruction": last.map(|c| c.heldout_prior_reconstruction),
            "kl": last.map(|c| c.kl),
        })
    }

    fn text(&self) -> Option<String> {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} manifold: latent {}, ζ = {} steps × {} channels, trained on {} windows, {} held out",
            if self.params.conditional {
                "conditional"
            } else {
                "unconditional"
            },
            self.params.latent,
            self.h_os,
            self.channels,
            self.windows_train,
            self.windows_heldout
        );
        let _ = writeln!(
            s,
            "errors are ‖·‖²_{{W_a}} per element: 1.0 = predicting each channel's mean\n"
        );
        let _ = writeln!(
            s,
            "| epoch | train rec | smooth | KL | held-out rec (encoder mean) | held-out rec (prior mean) |"
        );
        let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|");
        let step = self.curve.len().div_ceil(10).max(1);
        let mut shown: Vec<&crate::cvae::CurvePoint> = self.curve.iter().step_by(step).collect();
        if let Some(last) = self.curve.last()
            && shown.last().is_none_or(|s| s.epoch != last.epoch)
        {
            shown.push(last);
        }
        for c in shown {
            let _ = writeln!(
                s,
                "| {} | {:.4} | {:.4} | {:.3} | {:.4} | {:.4} |",
                c.epoch,
                c.reconstruction,
                c.smoothness,
                c.kl,
                c.heldout_reconstruction,
                c.heldout_prior_reconstruction
            );
        }
        Some(s)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "epoch,train_reconstruction,smoothness,kl,heldout_reconstruction,heldout_prior_reconstruction\n",
        );
        for c in &self.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{}",
                c.epoch,
                c.reconstruction,
                c.smoothness,
                c.kl,
                c.heldout_reconstruction,
                c.heldout_prior_reconstruction
            );
        }
        vec![("manifold_curve.csv".into(), csv.into_bytes())]
    }
}

/// Trains the OSW motion manifold on the complete windows of D_M (paper 4.1).
pub struct ManifoldStage;
impl Stage for ManifoldStage {
    const KIND: &'static str = "manifold";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::one::<OswSet>("windows")];
    const DOC: &'static str =
        "the OSW motion manifold: a conditional VAE over D_M's arm-action snippets (paper 4.1)";
    type Params = ManifoldParams;
    type Output = Cvae;

    fn numerics() -> Vec<Numerics> {
        method_numerics()
    }

    fn run(&self, ctx: &Ctx<'_, ManifoldParams>) -> Result<Cvae, StageError> {
        let set: OswSet = ctx.input("windows")?;
        let windows: Vec<Window<'_>> = set
            .windows
            .iter()
            .filter(|w| w.complete && w.success)
            .map(|w| Window {
                zeta: &w.zeta_org,
                omega_bar: &w.omega_bar,
            })
            .collect();
        let channels = osms_sim::N_ARM;
        let progress = ctx.progress();
        progress.set_total(u64::from(ctx.params.epochs));
        let seed = ctx.seed().unwrap_or_default();
        train(
            &windows,
            set.osw.h_os,
            channels,
            ctx.params,
            (seed, ctx.stage()),
            &|| progress.inc(1),
        )
        .map_err(|e| {
            format!("{e}\nhint: the `windows` input must be the OSW windows of a successes-only dataset (D_M)").into()
        })
    }
}

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

/// The geodesic sets per rollout, in the windows' order (none for the geodesic generator).
type Reference = Vec<Option<CandidateSet>>;

/// Candidate sets for every D_R rollout (paper Alg. 1, line "generate η"). Rollout i's
/// projection draws its multi-start samples from stream ("projection", i).
pub struct CandidatesStage;
impl ItemStage for CandidatesStage {
    const KIND: &'static str = "candidates";
    /// 2: `euclidean` starts from the reference sets' z⁰.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Cvae>("manifold"),
        Slot::one::<OswSet>("windows"),
        Slot::one::<CandidateSets>("reference").optional(),
    ];
    const DOC: &'static str = "candidate sets η per D_R rollout: geodesic search on the manifold (paper 4.1) or an ablation generator matched to it";
    type Params = SearchParams;
    type Prepared = (Cvae, OswSet, Reference);
    type Item = CandidateItem;
    type Output = CandidateSets;

    fn numerics() -> Vec<Numerics> {
        method_numerics()
    }

    fn prepare(&self, ctx: &Ctx<'_, SearchParams>) -> Result<Self::Prepared, StageError> {
        let p = ctx.params;
        if p.directions == 0 || p.directions > 127 {
            return Err("params.directions (K) must be between 1 and 127".into());
        }
        if !(p.bound > 0.0 && p.bound.is_finite() && p.radius > 0.0 && p.radius.is_finite()) {
            return Err("params.bound and params.radius must be positive".into());
        }
        if p.rk4_steps == 0 {
            return Err("params.rk4_steps must be at least 1".into());
        }
        let model: Cvae = ctx.input("manifold")?;
        let conditional_needed = matches!(p.generator, Generator::Geodesic | Generator::Euclidean);
        if p.generator == Generator::Unconditional && model.params.conditional {
            return Err("generator `unconditional` needs a manifold trained with `conditional = false`\nhint: wire `manifold` to the unconditional manifold stage".into());
        }
        if conditional_needed && !model.params.conditional {
            return Err(format!(
                "generator `{}` needs the conditional manifold, but `manifold` was trained with `conditional = false`",
                p.generator.name()
            )
            .into());
        }
        let windows: OswSet = ctx.input("windows")?;
        if windows.osw.h_os != model.h_os {
            return Err(format!(
                "the windows have H_OS = {}, the manifold {}",
                windows.osw.h_os, model.h_os
            )
            .into());
        }
        let has_reference = ctx.has_input("reference");
        let reference = match (p.generator, has_reference) {
            (Generator::Geodesic, true) => {
                return Err(
                    "generator `geodesic` builds the reference sets; remove its `reference` input"
                        .into(),
                );
            }
            (Generator::Geodesic, false) => vec![None; windows.windows.len()],
            (g, false) => {
                return Err(format!(
                    "generator `{}` is matched to the geodesic sets of the same rollouts\nhint: add `reference = \"<geodesic candidates stage>\"` to its inputs",
                    g.name()
                )
                .into());
            }
            (_, true) => {
                let r: CandidateSets = ctx.sharded("reference")?;
                if r.params.generator != Generator::Geodesic {
                    return Err(format!(
                        "the `reference` input holds `{}` sets; it must be the geodesic ones",
                        r.params.generator.name()
                    )
                    .into());
                }
                if r.items.len() != windows.windows.len()
                    || r.items
                        .iter()
                        .zip(&windows.windows)
                        .any(|(a, b)| (a.item, a.attempt) != (b.item, b.attempt))
                {
                    return Err(
                        "the `reference` sets were built for other rollouts than `windows`".into(),
                    );
                }
                if r.params.directions != p.directions {
                    return Err(format!(
                        "params.directions = {} but the reference sets have K = {} (|η| must match)",
                        p.directions, r.params.directions
                    )
                    .into());
                }
                r.items.into_iter().map(|i| i.set).collect()
            }
        };
        Ok((model, windows, reference))
    }

    fn n_items(&self, _: &Ctx<'_, SearchParams>, (_, windows, _): &Self::Prepared) -> usize {
        windows.windows.len()
    }

    fn run_item(
        &self,
        ctx: &Ctx<'_, SearchParams>,
        (model, windows, reference): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<CandidateItem, StageError> {
        let w = &windows.windows[index];
        let set = if w.complete {
            Some(
                candidate_set(
                    model,
                    &w.zeta_org,
                    &w.omega_bar,
                    reference[index].as_ref(),
                    ctx.params,
                    rng,
                )
                .map_err(|e| {
                    format!(
                        "rollout {} (item {}, attempt {}): {e}",
                        index, w.item, w.attempt
                    )
                })?,
            )
        } else {
            None
        };
        Ok(CandidateItem {
            item: w.item,
            attempt: w.attempt,
            variant: w.variant.clone(),
            success: w.success,
            complete: w.complete,
            set,
        })
    }

    fn merge(
        &self,
        ctx: &Ctx<'_, SearchParams>,
        _: Self::Prepared,
        items: Vec<CandidateItem>,
    ) -> Result<CandidateSets, StageError> {
        Ok(CandidateSets {
            params: ctx.params.clone(),
            items,
        })
    }
}

/// The generators side by side: what each proposed, matched or not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateTable {
    pub rows: Vec<CandidateStats>,
}

impl Artifact for CandidateTable {
    const TYPE_TAG: &'static str = "method.candidate_table";
    const SCHEMA_VERSION: u16 = 1;
}

const TABLE_COLUMNS: &str = "generator,sets,refine,repair,skipped_incomplete,candidates,mean_projection_residual,mean_deviation,mean_max_deviation,mean_geodesic_length,directions_shrunk,unmatched,mean_scale";

impl CandidateTable {
    fn markdown(&self) -> String {
        let opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.3}"));
        let mut s = String::from(
            "| generator | sets | refine / repair | projection residual | mean deviation | largest deviation | geodesic length | shrunk directions | unmatched sets | scale |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} / {} | {} | {:.3} | {:.3} | {} | {} | {} | {:.3} |",
                r.generator,
                r.sets,
                r.refine,
                r.repair,
                opt(r.mean_projection_residual),
                r.mean_deviation,
                r.mean_max_deviation,
                opt(r.mean_geodesic_length),
                r.directions_shrunk,
                r.unmatched,
                r.mean_scale
            );
        }
        s
    }
}

impl Summarize for CandidateTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        Some(format!(
            "candidate generators (paper 6.4), deviations ‖ζ − ζ_org‖_W_a; the ablations are scaled to the geodesic set's largest deviation per rollout\n\n{}",
            self.markdown()
        ))
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        let mut csv = format!("{TABLE_COLUMNS}\n");
        for r in &self.rows {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.generator,
                r.sets,
                r.refine,
                r.repair,
                r.skipped_incomplete,
                r.candidates,
                opt(r.mean_projection_residual),
                r.mean_deviation,
                r.mean_max_deviation,
                opt(r.mean_geodesic_length),
                r.directions_shrunk,
                r.unmatched,
                r.mean_scale
            );
        }
        vec![
            ("candidates.md".into(), self.markdown().into_bytes()),
            ("candidates.csv".into(), csv.into_bytes()),
            (
                "candidates.json".into(),
                serde_json::to_vec_pretty(&self.rows).unwrap_or_default(),
            ),
        ]
    }
}

/// The four generators' candidate sets side by side (`osms make candidates` builds them all).
pub struct CandidateTableStage;
impl Stage for CandidateTableStage {
    const KIND: &'static str = "candidate_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<CandidateSets>("geodesic"),
        Slot::one::<CandidateSets>("euclidean"),
        Slot::one::<CandidateSets>("unconditional"),
        Slot::one::<CandidateSets>("direct"),
    ];
    const DOC: &'static str =
        "the candidate generators side by side: sets, deviations, shrunk directions, matching";
    type Params = osms_core::NoParams;
    type Output = CandidateTable;

    fn run(&self, ctx: &Ctx<'_, osms_core::NoParams>) -> Result<CandidateTable, StageError> {
        let mut rows = Vec::new();
        for (slot, generator) in [
            ("geodesic", Generator::Geodesic),
            ("euclidean", Generator::Euclidean),
            ("unconditional", Generator::Unconditional),
            ("direct", Generator::Direct),
        ] {
            let sets: CandidateSets = ctx.sharded(slot)?;
            if sets.params.generator != generator {
                return Err(format!(
                    "input `{slot}` holds `{}` candidate sets\nhint: wire the stage whose params say generator = \"{slot}\"",
                    sets.params.generator.name()
                )
                .into());
            }
            rows.push(sets.stats());
        }
        Ok(CandidateTable { rows })
    }
}

/// Registers the method's stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(ManifoldStage)
        .register_itemised(CandidatesStage)
        .register(CandidateTableStage)
        .register(crate::error_stages::ErrorModelStage);
    crate::validate_stages::register(registry);
}
