//! `candidates`: η for every D_R rollout, by one of the four generators (paper 4.1, 6.4).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use osms_policy::artifacts::OswSet;

use crate::artifacts::{CandidateItem, CandidateSets};
use crate::candidates::{CandidateSet, Generator, SearchParams, candidate_set};
use crate::cvae::Cvae;

/// The geodesic sets per rollout, in the windows' order (none for the geodesic generator).
type Reference = Vec<Option<CandidateSet>>;

/// Candidate sets for every D_R rollout (paper Alg. 1, line "generate η"). Rollout i's
/// projection draws its multi-start samples from stream ("projection", i).
pub struct CandidatesStage;
impl Kind for CandidatesStage {
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

    fn numerics() -> Vec<Numerics> {
        super::nn_numerics()
    }
}

impl ItemStage for CandidatesStage {
    type Prepared = (Cvae, OswSet, Reference);
    type Item = CandidateItem;
    type Output = CandidateSets;

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
