//! `collect`: teacher rollouts with their OSW windows, the D_M / D_E / D_R datasets.

use std::collections::BTreeMap;

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_sim::artifacts::WorldArtifact;
use osms_sim::conditions::sample;
use osms_sim::control::DrSpec;
use osms_sim::{Hooks, NoHooks, World};
use serde::{Deserialize, Serialize};

use crate::artifacts::{Dataset, DatasetItem, DemoRollout, Teacher};
use crate::catch::{ArmNoise, CatchEpisode};
use crate::osw::{OswSpec, OswWindow};

/// The three teacher datasets of paper section 4, each from its own condition stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetRole {
    /// D_M: successes, for the motion manifold.
    DM,
    /// D_E: successes, for the cross-fitted IL students behind the action-error model.
    DE,
    /// D_R: mixed outcomes, the rollouts to refine (successes) and repair (failures).
    DR,
}

impl DatasetRole {
    pub fn name(self) -> &'static str {
        match self {
            DatasetRole::DM => "d_m",
            DatasetRole::DE => "d_e",
            DatasetRole::DR => "d_r",
        }
    }

    /// Whether datasets of this role keep successes only.
    pub fn successes_only(self) -> bool {
        !matches!(self, DatasetRole::DR)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectParams {
    /// How many rollouts the dataset keeps.
    pub n: u32,
    /// Keep only successes (D_M, D_E): each item retries fresh conditions until one succeeds.
    #[serde(default)]
    pub successes_only: bool,
    /// The dataset's role in the method (`d_m`, `d_e`, `d_r`): stages that take a dataset
    /// accept only the roles they are meant for, checked before anything runs.
    #[serde(default)]
    pub role: Option<DatasetRole>,
    /// Attempts an item may take before the stage gives up on a teacher that rarely succeeds.
    #[serde(default = "default_max_attempts")]
    pub max_attempts: u32,
    #[serde(default)]
    pub osw: OswSpec,
    /// Domain randomisation of the collected rollouts (a preset name or a table); absent: the
    /// teacher's training setting. Each rollout's draws are recorded with it and enter ω̄.
    #[serde(default)]
    pub dr: Option<DrSpec>,
    /// DART noise (σ, in action units) on the executed arm channels, the teacher's intended
    /// actions kept as labels ([`ArmNoise`]); D_E only, since the method re-simulates D_M and
    /// D_R rollouts from their DR stream. 0, the default, collects the teacher's own rollouts
    /// and is left out of the encoded params, so keys built before it stay valid.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub dart_arm_noise: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn default_max_attempts() -> u32 {
    100
}

/// Teacher rollouts. Item `i` draws its conditions in turn from stream ("item", i) and the
/// domain randomisation of attempt `a` from ("attempt", i · max_attempts + a). Different
/// stages draw from different streams, so datasets never share a condition draw.
pub struct CollectStage;
impl Kind for CollectStage {
    const KIND: &'static str = "collect";
    /// 3: ω̄ carries the arm's servo targets; 4: the DR stream and the task spec are kept.
    const CODE_VERSION: u32 = 4;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "teacher rollouts with OSW alignment (D_M / D_E: successes only; D_R: mixed)";
    type Params = CollectParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }

    /// `n` rollouts.
    fn scale(params: &CollectParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(params.n as f64)
    }
    fn output_role(params: &CollectParams) -> Option<&'static str> {
        params.role.map(DatasetRole::name)
    }
}

impl ItemStage for CollectStage {
    type Prepared = (World, Teacher);
    type Item = DatasetItem;
    type Output = Dataset;

    fn prepare(&self, ctx: &Ctx<'_, CollectParams>) -> Result<Self::Prepared, StageError> {
        if let Some(role) = ctx.params.role
            && role.successes_only() != ctx.params.successes_only
        {
            return Err(format!(
                "params: a `{}` dataset has successes_only = {}\nhint: set successes_only = {} or change the role",
                role.name(),
                role.successes_only(),
                role.successes_only()
            )
            .into());
        }
        if ctx.params.max_attempts == 0 {
            return Err("params.max_attempts must be at least 1".into());
        }
        if !(ctx.params.dart_arm_noise >= 0.0 && ctx.params.dart_arm_noise <= 1.0) {
            return Err(format!(
                "params.dart_arm_noise = {} must be within [0, 1] (action units; 0 collects without noise)",
                ctx.params.dart_arm_noise
            )
            .into());
        }
        if ctx.params.dart_arm_noise > 0.0 && ctx.params.role != Some(DatasetRole::DE) {
            return Err(
                "params.dart_arm_noise: DART rollouts are student data only (role `d_e`): validation, D_* and the IOS profile re-simulate D_R and D_M rollouts from their DR stream, without the noise\nhint: set role = \"d_e\" or leave dart_arm_noise out"
                    .into(),
            );
        }
        if ctx.params.osw.h_os == 0 {
            return Err("params.osw.h_os must be at least 1".into());
        }
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = teacher.task.with_dr(&ctx.params.dr);
        // The OSW conditioning ω̄ needs the privileged state at the window's start.
        teacher.task.rollout.record_privileged = true;
        Ok((ctx.input::<WorldArtifact>("world")?.world()?, teacher))
    }
    fn n_items(&self, ctx: &Ctx<'_, CollectParams>, _: &Self::Prepared) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, CollectParams>,
        (world, teacher): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DatasetItem, StageError> {
        let p = ctx.params;
        let mut discarded_failures: BTreeMap<String, u32> = BTreeMap::new();
        for attempt in 0..p.max_attempts {
            let condition = sample(&teacher.task.conditions, world.home_palm_pos, rng)?;
            let stream_index = index as u64 * u64::from(p.max_attempts) + u64::from(attempt);
            let dr_stream = ctx.stream_id("attempt", stream_index);
            let mut dart = (p.dart_arm_noise > 0.0).then(|| ArmNoise {
                sigma: p.dart_arm_noise,
                rng: ctx.stream_id("dart", stream_index).rng(),
            });
            let hooks: &mut dyn Hooks = match &mut dart {
                Some(noise) => noise,
                None => &mut NoHooks,
            };
            let record = CatchEpisode::new(world, &teacher.task, condition, dr_stream.rng())
                .run_with_hooks(&mut |obs| teacher.agent.act_deterministic(obs), hooks);
            if p.successes_only && !record.outcome.success() {
                for f in &record.outcome.failures {
                    *discarded_failures.entry(f.name().to_string()).or_default() += 1;
                }
                continue;
            }
            let osw = OswWindow::extract(&record, &p.osw)?;
            return Ok(DatasetItem {
                rollout: DemoRollout {
                    item: index as u32,
                    attempt,
                    dr_stream,
                    record,
                    osw,
                },
                attempts: attempt + 1,
                discarded_failures,
            });
        }
        Err(format!(
            "item {index}: the teacher failed {} attempts in a row\nhint: raise params.max_attempts, or train the teacher longer (its success rate is too low for a successes-only dataset)",
            p.max_attempts
        )
        .into())
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, CollectParams>,
        (world, teacher): Self::Prepared,
        items: Vec<DatasetItem>,
    ) -> Result<Dataset, StageError> {
        Ok(Dataset {
            successes_only: ctx.params.successes_only,
            osw: ctx.params.osw.clone(),
            task: teacher.task,
            arm_action: world.spec.arm_action,
            items,
        })
    }
}
