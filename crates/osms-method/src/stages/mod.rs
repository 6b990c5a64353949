//! The method's stage kinds, one file each: the manifold and the candidates (`manifold`,
//! `candidates`, `candidate_table`), the error model (`error_model`) and its closed-loop
//! calibration (`calibrate_error_model`, `error_calibration`), validation and D_*
//! (`validate`, `dstar`), the baselines (`naive`, `normal`, `construction_table`; beyond the
//! paper `dart`) and the IOS
//! profile (`ios_profile`).

mod calibrate_error_model;
mod candidate_table;
mod candidates;
mod checks;
mod closed_loop;
mod construction_table;
mod dart;
mod dstar;
mod error_calibration;
mod error_model;
mod ios_profile;
mod manifold;
mod naive;
mod normal;
mod validate;

pub use calibrate_error_model::{CalibrateErrorModelStage, CalibrateParams};
pub use candidate_table::CandidateTableStage;
pub use candidates::CandidatesStage;
pub use construction_table::ConstructionTableStage;
pub use dart::{DartParams, DartStage};
pub use dstar::{DstarParams, DstarStage};
pub use error_calibration::{CalibrationParams, CalibrationStage};
pub use error_model::ErrorModelStage;
pub use ios_profile::IosProfileStage;
pub use manifold::ManifoldStage;
pub use naive::NaiveStage;
pub use normal::{NormalInputs, NormalStage};
pub use validate::ValidateStage;

use osms_make::{Ctx, Numerics, Scale, StageError};
use osms_policy::artifacts::{Dataset, DemoSet, Teacher};
use osms_sim::artifacts::WorldArtifact;
use serde::{Deserialize, Serialize};

use crate::artifacts::{CandidateSets, ErrorModelArtifact};
use crate::construct::Inputs;
use crate::validate::ValidateParams;

/// The kinds that train or run networks without simulating depend on osms-nn's kernels (and
/// nothing of MuJoCo).
fn nn_numerics() -> Vec<Numerics> {
    vec![Numerics {
        name: "osms-nn",
        version: osms_nn::NUMERICS_VERSION.to_string(),
    }]
}

/// Settings of both baselines. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaselineParams {
    /// Extend to the `target` set's number of demonstrations (false: D_R only).
    pub extend: bool,
    /// Extend to this many demonstrations instead of the `target` set's (issue 74's data
    /// curve); absent, as by default, it is left out of the encoded params.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub demos: Option<usize>,
    /// Attempts an extension item of `naive` may take to find a teacher success.
    pub max_attempts: u32,
    /// `normal` runs this many times the extension conditions its D_R yield predicts, and
    /// keeps the first ones that reach the target.
    pub margin: f64,
}

impl Default for BaselineParams {
    fn default() -> Self {
        BaselineParams {
            extend: true,
            demos: None,
            max_attempts: 100,
            margin: 1.15,
        }
    }
}

impl BaselineParams {
    /// `has_target`: whether the `target` input is wired.
    fn check(&self, has_target: bool) -> crate::Result<()> {
        if self.demos.is_some() && !self.extend {
            return Err(crate::Error::Params(
                "params.demos sets the size an extension reaches, but `extend = false`\nhint: remove `demos` or set `extend = true`".into(),
            ));
        }
        if self.extend && !has_target && self.demos.is_none() {
            return Err(crate::Error::Params("`extend = true` needs the `target` input (D_*)\nhint: wire `target = \"dstar\"` or set params.extend = false".into()));
        }
        <Self as osms_core::check::Check>::check(self).map_err(crate::Error::from)
    }
}

/// How many demonstrations the extension has to add.
fn deficit(
    ctx: &Ctx<'_, BaselineParams>,
    base: usize,
) -> Result<(Option<usize>, usize), StageError> {
    if !ctx.params.extend {
        return Ok((None, 0));
    }
    let n = match ctx.params.demos {
        Some(n) => n,
        None => ctx.sharded::<DemoSet>("target")?.len(),
    };
    Ok((Some(n), n.saturating_sub(base)))
}

/// The fit `variant` of an error-model artifact (absent: the model it adopts), or the error
/// naming the param.
fn fit_of(
    artifact: ErrorModelArtifact,
    variant: Option<crate::error_model::ErrorVariant>,
) -> Result<crate::error_model::ErrorModel, StageError> {
    let Some(v) = variant else {
        return Ok(artifact.model);
    };
    artifact
        .variants
        .into_iter()
        .find(|f| f.model.variant == v)
        .map(|f| f.model)
        .ok_or_else(|| {
            format!(
                "params.error_model = `{}`: the error-model artifact has no such fit",
                v.name()
            )
            .into()
        })
}

/// What validation, D_* and the Normal baseline read from their inputs: the world, the teacher,
/// the D_R rollouts with their task, their candidate sets and the error model.
fn load_inputs<P>(ctx: &Ctx<'_, P>, params: &ValidateParams) -> Result<Inputs, StageError> {
    params.check()?;
    let teacher: Teacher = ctx.input("teacher")?;
    let data: Dataset = ctx.sharded("data")?;
    let candidates: CandidateSets = ctx.sharded("candidates")?;
    if candidates.items.len() != data.items.len()
        || candidates
            .items
            .iter()
            .zip(&data.items)
            .any(|(c, d)| (c.item, c.attempt) != (d.rollout.item, d.rollout.attempt))
    {
        return Err(
            "input `candidates`: the sets were built for other rollouts than `data`\nhint: wire `candidates` to a candidates stage on the windows of the same D_R dataset".into(),
        );
    }
    let mut model = fit_of(ctx.input("error_model")?, params.error_model)?;
    if let Some(scale) = params.deviation_scale {
        model = model.with_deviation_scale(scale, model.variant);
    }
    if let Some(kappa) = params.kappa {
        model = model.with_kappa(kappa);
    }
    model
        .validate()
        .map_err(|e| format!("input `error_model`: {e}"))?;
    let mut task = data.task.clone();
    // Validation reads outcomes and commanded actions; the privileged frames were for ω̄.
    task.rollout.record_privileged = false;
    let n = match params.rollouts {
        0 => data.items.len(),
        n if n <= data.items.len() => n,
        n => {
            return Err(format!(
                "params.rollouts = {n}, but `data` holds {} rollouts\nhint: use at most {} (0 validates all)",
                data.items.len(),
                data.items.len()
            )
            .into());
        }
    };
    Ok(Inputs {
        world: ctx.input::<WorldArtifact>("world")?.world()?,
        agent: teacher.agent,
        task,
        sets: candidates
            .items
            .iter()
            .take(n)
            .map(|i| {
                i.set
                    .as_ref()
                    .map(|s| s.candidates.clone())
                    .unwrap_or_default()
            })
            .collect(),
        generator: candidates.params.generator.name().to_string(),
        rollouts: data.items.into_iter().take(n).map(|i| i.rollout).collect(),
        model,
    })
}

/// The cost-model size of a demonstration set (D_*, Naive's, Normal's, DART's): D_R's
/// rollouts, since the set is built on its conditions, whatever the size of the error model
/// (which follows D_E) or of the other inputs.
fn demonstration_set_scale(inputs: &[(&str, f64)]) -> Scale {
    Scale::items(Scale::input(inputs, "data"))
}

/// Registers the method's stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(ManifoldStage)
        .register_itemised(CandidatesStage)
        .register(CandidateTableStage)
        .register(ErrorModelStage)
        .register(CalibrateErrorModelStage)
        .register_itemised(CalibrationStage)
        .register_itemised(ValidateStage)
        .register_itemised(DstarStage)
        .register_itemised(NaiveStage)
        .register_itemised(DartStage)
        .register_itemised(NormalStage)
        .register(ConstructionTableStage)
        .register_itemised(IosProfileStage);
}

#[cfg(test)]
mod tests {
    use osms_make::Kind;

    use super::*;

    #[test]
    fn demonstration_sets_cost_what_d_r_holds_not_what_the_error_model_was_fitted_on() {
        // The error model's size follows D_E; a larger D_E must not scale D_*'s estimate.
        let small = [
            ("data", 1000.0),
            ("error_model", 500.0),
            ("validation", 1000.0),
        ];
        let de4k = [
            ("data", 1000.0),
            ("error_model", 8000.0),
            ("validation", 1000.0),
        ];
        let larger_d_r = [
            ("data", 4000.0),
            ("error_model", 500.0),
            ("validation", 4000.0),
        ];
        type Work = fn(&[(&str, f64)]) -> f64;
        let kinds: [(&str, Work); 4] = [
            ("dstar", |i| {
                DstarStage::scale(&DstarParams::default(), i).work
            }),
            ("naive", |i| {
                NaiveStage::scale(&BaselineParams::default(), i).work
            }),
            ("normal", |i| {
                NormalStage::scale(&BaselineParams::default(), i).work
            }),
            ("dart", |i| DartStage::scale(&DartParams::default(), i).work),
        ];
        for (kind, work) in kinds {
            let got = (work(&small), work(&de4k), work(&larger_d_r));
            assert_eq!(got, (1000.0, 1000.0, 4000.0), "{kind}");
        }
    }

    #[test]
    fn a_naive_set_of_a_declared_size_costs_its_demonstrations() {
        let d_r = [("data", 1000.0), ("target", 3944.0)];
        let of = |demos| {
            NaiveStage::scale(
                &BaselineParams {
                    demos,
                    ..BaselineParams::default()
                },
                &d_r,
            )
        };
        assert_eq!(of(Some(40_000)).work, 40_000.0);
        assert_eq!(of(Some(40_000)).size, 40_000.0);
        // Fewer than D_R holds: D_R's rollouts are still read.
        assert_eq!(of(Some(500)).work, 1000.0);
        assert_eq!(of(None).work, 1000.0);
    }
}
