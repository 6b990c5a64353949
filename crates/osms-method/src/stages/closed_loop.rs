//! What `error_calibration` and `calibrate_error_model` share (issue 66): both roll the frozen
//! teacher out under a model on the D_E conditions each cross-fitted π̄ was held out from (those
//! `error_pairs` ran it on), and compare with π̄'s own rollouts there, drawn with the same DR
//! streams as the teacher's.

use std::collections::{BTreeMap, BTreeSet};

use osms_core::rng::StreamRng;
use osms_make::{Ctx, Slot, StageError};
use osms_policy::artifacts::{Dataset, ErrorPairs, PairRollout, StudentArtifact, Teacher};
use osms_policy::student::{Student, paired_rollout};
use osms_sim::artifacts::{EvalRow, WorldArtifact};
use osms_sim::conditions::TaskCondition;
use osms_sim::control::DrSpec;
use osms_sim::{RolloutSpec, World};

use crate::artifacts::{ErrorModelArtifact, RunOutcome};
use crate::calibrate::{DeviationStats, teacher_under};
use crate::error_model::ErrorModel;

/// What both kinds read: the world, the teacher under the rollouts' DR, every fold's π̄
/// rollouts (fold, pair) in fold order, the D_E conditions by item, the error models and each
/// fold's π̄ with its rollout spec.
pub(super) struct Loaded {
    pub(super) world: World,
    pub(super) teacher: Teacher,
    pub(super) pairs: Vec<(u32, PairRollout)>,
    pub(super) conditions: BTreeMap<u32, TaskCondition>,
    pub(super) errors: ErrorModelArtifact,
    pub(super) students: BTreeMap<u32, (Student, RolloutSpec)>,
}

pub(super) const INPUTS: &[Slot] = &[
    Slot::one::<WorldArtifact>("world"),
    Slot::one::<Teacher>("teacher"),
    Slot::one::<Dataset>("data").roles(&["d_e"]),
    Slot::gather::<ErrorPairs>("pairs"),
    Slot::one::<ErrorModelArtifact>("error_model"),
    Slot::gather::<StudentArtifact>("students"),
];

pub(super) fn load<P>(ctx: &Ctx<'_, P>, dr: &Option<DrSpec>) -> Result<Loaded, StageError> {
    let mut teacher: Teacher = ctx.input("teacher")?;
    teacher.task = teacher.task.with_dr(dr);
    teacher.task.rollout.record_privileged = false;
    let mut conditions = BTreeMap::new();
    for item in ctx.items::<Dataset>("data")? {
        let r = item?.rollout;
        conditions.insert(r.item, r.record.condition);
    }
    let mut pairs = Vec::new();
    for (_, fold) in ctx.gathered_sharded::<ErrorPairs>("pairs")? {
        let f = fold.fold.map_or(0, |(i, _)| i);
        for p in fold.rollouts {
            if !conditions.contains_key(&p.item) {
                return Err(format!(
                    "input `pairs`: fold {f}'s rollouts ran on D_E item {}, which input `data` does not hold\nhint: wire `data` to the D_E dataset the `error_pairs` stages read",
                    p.item
                )
                .into());
            }
            pairs.push((f, p));
        }
    }
    if pairs.is_empty() {
        return Err("input `pairs`: no π̄ rollouts to compare with".into());
    }
    let errors: ErrorModelArtifact = ctx.input("error_model")?;
    let mut students = BTreeMap::new();
    for (_, s) in ctx.gathered::<StudentArtifact>("students")? {
        let Some((f, _)) = s.fold else {
            return Err("input `students`: a student that is not cross-fitted\nhint: wire `students` to the cross-fitted π̄ stage the `error_pairs` stages read (`student_il#*`)".into());
        };
        let trained: BTreeSet<u32> = s.items.iter().copied().collect();
        if let Some((_, p)) = pairs
            .iter()
            .find(|(g, p)| *g == f && trained.contains(&p.item))
        {
            return Err(format!(
                "input `students`: fold {f}'s student trained on D_E item {}, which fold {f}'s pairs hold out\nhint: wire `students` to the π̄ stage the `error_pairs` stages read",
                p.item
            )
            .into());
        }
        let spec = s.student.rollout_spec(&teacher.task.rollout);
        students.insert(f, (s.student, spec));
    }
    if let Some((f, _)) = pairs.iter().find(|(f, _)| !students.contains_key(f)) {
        return Err(format!(
            "input `students` has no student of fold {f}, whose pairs input `pairs` holds\nhint: wire `students` to the cross-fitted π̄ stage the `error_pairs` stages read (`student_il#*`)"
        )
        .into());
    }
    Ok(Loaded {
        world: ctx.input::<WorldArtifact>("world")?.world()?,
        teacher,
        pairs,
        conditions,
        errors,
        students,
    })
}

/// The DR and innovation streams of draw q on D_E item `item`: the same for every model, κ and
/// scale, and the DR stream the same for π̄ (common random numbers).
pub(super) fn draw_streams<P>(ctx: &Ctx<'_, P>, item: u32, q: usize) -> (StreamRng, StreamRng) {
    (
        ctx.rng(&format!("dr-{q}"), u64::from(item)),
        ctx.rng(&format!("errors-{q}"), u64::from(item)),
    )
}

/// The teacher under `model` on draw q of D_E item `item` (from [`draw_streams`]).
pub(super) fn teacher_draw<P>(
    ctx: &Ctx<'_, P>,
    l: &Loaded,
    condition: &TaskCondition,
    item: u32,
    q: usize,
    model: &ErrorModel,
) -> (EvalRow, DeviationStats) {
    let (dr, noise) = draw_streams(ctx, item, q);
    teacher_under(
        &l.world,
        &l.teacher.task,
        &l.teacher.agent,
        condition.clone(),
        dr,
        model,
        noise,
    )
}

/// π̄_f's own rollouts on D_E item `item`, `draws` of them: draw q with the DR stream of the
/// teacher's draw q and its policy noise from ("policy-q", item), the teacher queried at every
/// state π̄ reaches. Its rows (without the impact trace) and its arm deviation from the teacher.
pub(super) fn student_draws<P>(
    ctx: &Ctx<'_, P>,
    l: &Loaded,
    fold: u32,
    item: u32,
    draws: usize,
) -> RunOutcome {
    let (student, spec) = &l.students[&fold];
    let condition = &l.conditions[&item];
    let mut rows = Vec::with_capacity(draws);
    let mut deviation = DeviationStats::default();
    for q in 0..draws {
        let (dr, _) = draw_streams(ctx, item, q);
        let paired = paired_rollout(
            &l.world,
            spec,
            student,
            (&l.teacher.agent, &l.teacher.task),
            condition.clone(),
            dr,
            ctx.rng(&format!("policy-{q}"), u64::from(item)),
        );
        deviation.push_rollout(&paired.record.intended, &paired.teacher, &paired.phase);
        let mut row = EvalRow::of(paired.record);
        row.trace = None;
        rows.push(row);
    }
    RunOutcome { rows, deviation }
}
