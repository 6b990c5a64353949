//! `ablations`: the ablations of paper 6.4 and the label ablation beyond it, with their claims.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::{ConstructionStats, DemoSet};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::ablations::{
    generator_claim, generators, labels, labels_claim, refine_repair, refine_repair_claim,
    validation_model, validation_model_claim,
};
use crate::artifacts::Ablations;

const SETS: [&str; 4] = ["direct", "unconditional", "euclidean", "geodesic"];

const CONSTRUCTIONS: [&str; 4] = ["filtering", "refine_only", "repair_only", "both"];
/// D_* as the paper builds it (`both`), with ā labels, and without its perturbed survivors.
const LABELS: [&str; 3] = ["both", "intended", "omitted"];
/// D_* as osms validates it (under the calibrated model) and under the paper's least squares.
const MODELS: [&str; 2] = ["both", "least_squares"];

pub struct AblationsStage;
impl Kind for AblationsStage {
    const KIND: &'static str = "ablations";
    // 2: the claims decided by intervals. 3: the label ablation. 4: validation's error model.
    const CODE_VERSION: u32 = 4;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<DemoSet>("filtering_demos"),
        Slot::one::<DemoSet>("refine_only_demos"),
        Slot::one::<DemoSet>("repair_only_demos"),
        Slot::one::<DemoSet>("both_demos"),
        Slot::gather::<Evaluation>("filtering"),
        Slot::gather::<Evaluation>("refine_only"),
        Slot::gather::<Evaluation>("repair_only"),
        Slot::gather::<Evaluation>("both"),
        Slot::one::<DemoSet>("direct_demos"),
        Slot::one::<DemoSet>("unconditional_demos"),
        Slot::one::<DemoSet>("euclidean_demos"),
        Slot::one::<DemoSet>("geodesic_demos"),
        Slot::gather::<Evaluation>("direct"),
        Slot::gather::<Evaluation>("unconditional"),
        Slot::gather::<Evaluation>("euclidean"),
        Slot::gather::<Evaluation>("geodesic"),
        Slot::one::<DemoSet>("intended_demos"),
        Slot::one::<DemoSet>("omitted_demos"),
        Slot::gather::<Evaluation>("intended"),
        Slot::gather::<Evaluation>("omitted"),
        Slot::one::<DemoSet>("least_squares_demos"),
        Slot::gather::<Evaluation>("least_squares"),
    ];
    const DOC: &'static str = "the ablations of paper 6.4 (refinement/repair, candidate generation), D_*'s labels and validation's error model, with their claims";
    type Params = NoParams;
}

impl Stage for AblationsStage {
    type Output = Ablations;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Ablations, StageError> {
        let c = Rows::load(ctx, CONSTRUCTIONS)?;
        let g = Rows::load(ctx, SETS)?;
        let l = Rows::load(ctx, LABELS)?;
        let m = Rows::load(ctx, MODELS)?;
        Ok(Ablations {
            tables: vec![
                refine_repair(c.sets(), c.students()),
                generators(g.sets(), g.students()),
                labels(l.sets(), l.students()),
                validation_model(m.sets(), m.students()),
            ],
            claims: vec![
                refine_repair_claim(c.students()),
                generator_claim(g.sets(), g.students()),
                labels_claim(l.students()),
                validation_model_claim(m.students()),
            ],
        })
    }
}

/// Each row's construction statistics and per-seed evaluations, in the order of its names.
struct Rows<const N: usize> {
    stats: Vec<ConstructionStats>,
    evals: Vec<Vec<Evaluation>>,
}

impl<const N: usize> Rows<N> {
    fn load(ctx: &Ctx<'_, NoParams>, names: [&str; N]) -> Result<Self, StageError> {
        let mut rows = Rows {
            stats: Vec::with_capacity(N),
            evals: Vec::with_capacity(N),
        };
        for n in names {
            rows.stats
                .push(ctx.sharded::<DemoSet>(&format!("{n}_demos"))?.stats());
            rows.evals.push(seed_evals(ctx, n)?);
        }
        Ok(rows)
    }

    fn sets(&self) -> [&ConstructionStats; N] {
        std::array::from_fn(|i| &self.stats[i])
    }

    fn students(&self) -> [&[Evaluation]; N] {
        std::array::from_fn(|i| self.evals[i].as_slice())
    }
}
