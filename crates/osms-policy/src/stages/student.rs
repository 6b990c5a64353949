//! `student`: a flow-matching student, cross-fitted when the stage has folds.

use osms_make::{Ctx, Kind, Numerics, Scale, Slot, Stage, StageError};

use super::in_fold;
use crate::artifacts::{Dataset, DemoSet, StudentArtifact};
use crate::checkpoint::Checkpoints;
use crate::student::{ARM_STEP_RAD, Demo, Student, StudentParams, StudentState};
use osms_sim::control::ArmAction;

/// Gradient steps between checkpoints (pipeline.toml's `checkpoint_every` overrides it): the
/// default 15,000 steps take ≈ 20 minutes on 2 cores, so a kill loses ≈ 1.5 minutes.
const CHECKPOINT_EVERY: u32 = 1_000;

/// A flow-matching student trained on a dataset's rollouts. With `folds = F` instance `#f`
/// trains on the items outside fold f (item index mod F ≠ f): the cross-fitted IL students π̄.
pub struct StudentStage;
impl Kind for StudentStage {
    const KIND: &'static str = "student";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Dataset>("data").optional(),
        Slot::one::<DemoSet>("demos").optional(),
        Slot::one::<DemoSet>("size_match").optional(),
    ];
    const DOC: &'static str = "a flow-matching student on a rollout dataset (`data`) or a constructed demonstration set (`demos`, optionally cut to the size of `size_match`); cross-fitted with folds";
    type Params = StudentParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }

    /// Training steps times batch size (the network's width is not counted).
    fn scale(params: &StudentParams, _: &[(&str, f64)]) -> Scale {
        Scale {
            work: f64::from(params.steps) * params.batch as f64,
            size: 1.0,
        }
    }
}

impl Stage for StudentStage {
    type Output = StudentArtifact;

    fn run(&self, ctx: &Ctx<'_, StudentParams>) -> Result<StudentArtifact, StageError> {
        ctx.params.check()?;
        let fold = ctx.fold();
        let mut demos = Vec::new();
        let mut items = Vec::new();
        let slot = match (ctx.has_input("data"), ctx.has_input("demos")) {
            (true, false) => "data",
            (false, true) => "demos",
            _ => {
                return Err("a student trains on exactly one of `data` (a rollout dataset) and `demos` (a demonstration set)\nhint: wire one of them in the stage's inputs".into());
            }
        };
        if slot == "data" && ctx.has_input("size_match") {
            return Err("`size_match` cuts a demonstration set; it needs `demos`, not `data`\nhint: remove `size_match` or train on `demos`".into());
        }
        if slot == "data" {
            let head = ctx.head::<Dataset>("data")?;
            if ctx.params.target_labels && head.arm_action != ArmAction::Increment {
                return Err(format!(
                    "params.target_labels turns arm increments into targets, but input `data` ran on an arm of `{}` actions, whose labels are targets already\nhint: leave `target_labels` off",
                    head.arm_action.name()
                )
                .into());
            }
            let control = head.task.rollout.control;
            if ctx.params.target_labels && control.arm_max_delta_rad != ARM_STEP_RAD {
                return Err(format!(
                    "params.target_labels assumes an arm step of {ARM_STEP_RAD} rad, but input `data` ran with `control.arm_max_delta_rad` = {}\nhint: train on a dataset of the default control spec or leave `target_labels` off",
                    control.arm_max_delta_rad
                )
                .into());
            }
            for item in ctx.items::<Dataset>("data")? {
                let r = item?.rollout;
                if fold.is_some_and(|f| in_fold(r.item, f)) {
                    continue;
                }
                items.push(r.item);
                demos.push(Demo::from_record(&r.record));
            }
        } else {
            let used = ctx.head::<DemoSet>("demos")?.used.unwrap_or(usize::MAX);
            // Matched dataset size (paper 6.4): the leading groups that hold at most the other
            // set's number of demonstrations.
            let cap = if ctx.has_input("size_match") {
                ctx.sharded::<DemoSet>("size_match")?.len()
            } else {
                usize::MAX
            };
            for group in ctx.items::<DemoSet>("demos")?.take(used) {
                let g = group?;
                if g.demos.is_empty() || fold.is_some_and(|f| in_fold(g.item, f)) {
                    continue;
                }
                if demos.len() + g.demos.len() > cap {
                    break;
                }
                items.push(g.item);
                demos.extend(g.demos.into_iter().map(|e| e.demo));
            }
        }
        if ctx.params.oracle_object_velocity {
            tracing::warn!(
                "{}: `oracle_object_velocity` gives the student the object's true velocity, a privileged input: a diagnostic, not a deployable student",
                ctx.stage()
            );
        }
        let progress = ctx.progress();
        progress.set_total(u64::from(ctx.params.steps));
        let resume = ctx.resume::<StudentState>();
        progress.inc(resume.as_ref().map_or(0, |r| u64::from(r.step)));
        let save = |s: &StudentState| {
            ctx.checkpoint(u64::from(s.step), s)
                .map_err(|e| e.to_string())
        };
        let checkpoints = Checkpoints {
            every: ctx.checkpoint_every(CHECKPOINT_EVERY),
            save: &save,
        };
        let student = Student::train_resumable(
            &demos,
            ctx.params,
            (ctx.seed().unwrap_or_default(), ctx.stage()),
            &|| progress.inc(1),
            resume,
            Some(checkpoints),
        )
        .map_err(|e| match e {
            crate::Error::Checkpoint { .. } => e.to_string(),
            e => format!("input `data`: {e}"),
        })?;
        Ok(StudentArtifact {
            student,
            fold: fold.map(|f| (f.index, f.count)),
            items,
        })
    }
}
