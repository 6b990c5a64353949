//! `ablations`: the ablations of paper 6.4 and the label ablation beyond it, with their claims.

use osms_core::NoParams;
use osms_make::{Ctx, Slot, Stage, StageError};
use osms_policy::artifacts::{ConstructionStats, DemoSet};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::ablations::{
    generator_claim, generators, labels, labels_claim, refine_repair, refine_repair_claim,
};
use crate::artifacts::Ablations;

const SETS: [&str; 4] = ["direct", "unconditional", "euclidean", "geodesic"];

/// Each row's construction statistics and per-seed evaluations.
type Rows = (Vec<ConstructionStats>, Vec<Vec<Evaluation>>);
const CONSTRUCTIONS: [&str; 4] = ["filtering", "refine_only", "repair_only", "both"];
/// D_* as the paper builds it (`both`), with ā labels, and without its perturbed survivors.
const LABELS: [&str; 3] = ["both", "intended", "omitted"];

pub struct AblationsStage;
impl Stage for AblationsStage {
    const KIND: &'static str = "ablations";
    // 2: the claims decided by intervals. 3: the label ablation.
    const CODE_VERSION: u32 = 3;
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
    ];
    const DOC: &'static str = "the ablations of paper 6.4 (refinement/repair, candidate generation) and D_*'s labels, with their claims";
    type Params = NoParams;
    type Output = Ablations;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Ablations, StageError> {
        let load = |names: &[&str]| -> Result<Rows, StageError> {
            let mut stats = Vec::new();
            let mut evals = Vec::new();
            for n in names {
                stats.push(ctx.sharded::<DemoSet>(&format!("{n}_demos"))?.stats());
                evals.push(seed_evals(ctx, n)?);
            }
            Ok((stats, evals))
        };
        let (s, e) = load(&CONSTRUCTIONS)?;
        let students = [&e[0][..], &e[1], &e[2], &e[3]];
        let rr = refine_repair([&s[0], &s[1], &s[2], &s[3]], students);
        let mut claims = vec![refine_repair_claim(students)];
        let (s, e) = load(&SETS)?;
        let (sets, students) = (
            [&s[0], &s[1], &s[2], &s[3]],
            [&e[0][..], &e[1], &e[2], &e[3]],
        );
        let gen_ = generators(sets, students);
        claims.push(generator_claim(sets, students));
        let (s, e) = load(&LABELS)?;
        let (sets, students) = ([&s[0], &s[1], &s[2]], [&e[0][..], &e[1], &e[2]]);
        let lab = labels(sets, students);
        claims.push(labels_claim(students));
        Ok(Ablations {
            tables: vec![rr, gen_, lab],
            claims,
        })
    }
}
