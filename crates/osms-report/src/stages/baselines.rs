//! `baselines`: DART-IL and DAgger-IL beside Table II, with Ours-IL's claims against each
//! (issue 68, beyond the paper).

use osms_core::NoParams;
use osms_core::table::Value;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::{ConstructionStats, DemoSet};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::artifacts::Baselines;
use crate::baselines::{baselines_claims, baselines_table};

pub struct BaselinesStage;
impl Kind for BaselinesStage {
    const KIND: &'static str = "baselines";
    /// 2: the table's note says which of its statements are defaults.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Evaluation>("teacher"),
        Slot::one::<DemoSet>("naive_demos"),
        Slot::one::<DemoSet>("normal_demos"),
        Slot::one::<DemoSet>("ours_demos"),
        Slot::one::<DemoSet>("dart_demos"),
        Slot::gather::<DemoSet>("dagger1_demos"),
        Slot::gather::<DemoSet>("dagger3_demos"),
        Slot::gather::<Evaluation>("naive"),
        Slot::gather::<Evaluation>("normal"),
        Slot::gather::<Evaluation>("ours"),
        Slot::gather::<Evaluation>("dart"),
        Slot::gather::<Evaluation>("dagger1"),
        Slot::gather::<Evaluation>("dagger3"),
    ];
    const DOC: &'static str = "beyond the paper: DART-IL and DAgger-IL (1 and 3 rounds) beside Table II's rows, with Ours-IL's claims against each";
    type Params = NoParams;
}

impl Stage for BaselinesStage {
    type Output = Baselines;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Baselines, StageError> {
        let stats: Vec<ConstructionStats> = ["naive_demos", "normal_demos", "ours_demos"]
            .iter()
            .map(|s| ctx.sharded::<DemoSet>(s).map(|d| d.stats()))
            .collect::<Result<_, _>>()?;
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let [naive, normal, ours, dart, dagger1, dagger3] =
            ["naive", "normal", "ours", "dart", "dagger1", "dagger3"]
                .map(|slot| seed_evals(ctx, slot));
        let (naive, normal, ours) = (naive?, normal?, ours?);
        let (dart, dagger1, dagger3) = (dart?, dagger1?, dagger3?);
        let per_seed_demos = |slot: &str| -> Result<Value, StageError> {
            let sets = ctx.gathered_sharded::<DemoSet>(slot)?;
            Ok(Value::seeds(sets.iter().map(|(_, d)| Some(d.len() as f64))))
        };
        let demos = [
            Value::One(ctx.sharded::<DemoSet>("dart_demos")?.len() as f64),
            per_seed_demos("dagger1_demos")?,
            per_seed_demos("dagger3_demos")?,
        ];
        let baselines = [dart.as_slice(), &dagger1, &dagger3];
        Ok(Baselines {
            table: baselines_table(
                [&stats[0], &stats[1], &stats[2]],
                &teacher,
                [&naive, &normal, &ours],
                demos,
                baselines,
            ),
            claims: baselines_claims(&ours, baselines),
        })
    }
}
