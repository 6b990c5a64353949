//! `manifold`: the OSW motion manifold, a conditional VAE over D_M's windows (paper 4.1).

use osms_make::{Ctx, Kind, Numerics, Slot, Stage, StageError};
use osms_policy::artifacts::OswSet;

use crate::cvae::{Cvae, ManifoldParams, Window, train};

/// Trains the OSW motion manifold on the complete windows of D_M (paper 4.1).
pub struct ManifoldStage;
impl Kind for ManifoldStage {
    const KIND: &'static str = "manifold";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::one::<OswSet>("windows")];
    const DOC: &'static str =
        "the OSW motion manifold: a conditional VAE over D_M's arm-action snippets (paper 4.1)";
    type Params = ManifoldParams;

    fn numerics() -> Vec<Numerics> {
        super::nn_numerics()
    }
}

impl Stage for ManifoldStage {
    type Output = Cvae;

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
