//! The valid ranges of this crate's params (`osms_core::check`), in one place so that they are
//! read together. Caps are sanity bounds far above every profile's value. It lives with the
//! stages, which check params, so that no library module imports `stages`.

use osms_core::check::{
    Check, Checked, Invalid, count, each, nested, positive, signed, unit, widths, within,
};

use super::{BaselineParams, CalibrateParams, CalibrationParams, DartParams, DstarParams};
use crate::candidates::SearchParams;
use crate::cvae::ManifoldParams;
use crate::error_model::ErrorFitParams;
use crate::error_model::ErrorVariant;
use crate::ios::IosParams;
use crate::project::ProjectionParams;
use crate::validate::ValidateParams;

impl Check for ProjectionParams {
    fn check(&self) -> Checked {
        within("lambda_p", self.lambda_p, 0.0, 1e6)?;
        count("iterations", self.iterations, 0, 1_000_000)?;
        positive("lr", self.lr, 100.0)?;
        count("samples", self.samples, 0, 10_000)
    }
}

impl Check for SearchParams {
    fn check(&self) -> Checked {
        positive("bound", self.bound, 1e3)?;
        count("directions", self.directions, 1, 1000)?;
        positive("radius", self.radius, 1e3)?;
        within("lambda_reg", self.lambda_reg, 0.0, 1e6)?;
        count("rk4_steps", self.rk4_steps, 1, 100_000)?;
        count("max_shrinks", self.max_shrinks, 0, 60)?;
        // Sobol indices are 32-bit in our generator's tables.
        count(
            "sobol_first",
            self.sobol_first,
            0,
            u64::from(u32::MAX) - 10_000,
        )?;
        count("match_iterations", self.match_iterations, 1, 1000)?;
        nested("projection", &self.projection)
    }
}

impl Check for ManifoldParams {
    fn check(&self) -> Checked {
        count("latent", self.latent, 1, 4096)?;
        widths("hidden", &self.hidden, 16_384)?;
        within("lambda_s", self.lambda_s, 0.0, 1e6)?;
        within("beta", self.beta, 0.0, 1e6)?;
        within("prior_anchor", self.prior_anchor, 0.0, 1e6)?;
        count("epochs", self.epochs, 1, 10_000_000)?;
        count("batch", self.batch, 1, 1_000_000)?;
        positive("lr", self.lr, 1.0)?;
        count("holdout_every", self.holdout_every, 0, 1_000_000)
    }
}

impl Check for ErrorFitParams {
    fn check(&self) -> Checked {
        count("max_delay", self.max_delay, 0, 100)?;
        positive("kappa", self.kappa, 100.0)?;
        // The AR process needs |a| < 1 to have a stationary distribution.
        within("max_ar", self.max_ar, 0.0, 0.999_999)
    }
}

impl Check for CalibrationParams {
    fn check(&self) -> Checked {
        if self.kappas.is_empty() {
            return Err(Invalid::new(
                "kappas",
                "empty: give at least one κ (1 is the model as fitted)",
            ));
        }
        each("kappas", &self.kappas, 0.0, 100.0)?;
        count("draws", self.draws, 1, 10_000)?;
        match &self.dr {
            Some(dr) => nested("dr", dr),
            None => Ok(()),
        }
    }
}

impl Check for CalibrateParams {
    fn check(&self) -> Checked {
        if self.scales.len() < 2 || self.scales.windows(2).any(|w| w[0] >= w[1]) {
            return Err(Invalid::new(
                "scales",
                "expected at least two scales in increasing order, e.g. [0.0, 0.5, 1.0]",
            ));
        }
        each("scales", &self.scales, 0.0, 100.0)?;
        count("draws", self.draws, 1, 10_000)?;
        if matches!(
            self.base,
            ErrorVariant::Unperturbed | ErrorVariant::Calibrated
        ) {
            return Err(Invalid::new(
                "base",
                format!(
                    "`{}` has no deviation to scale: expected one of global_iid, phase_independent, phase_correlated, unit_gain, orthogonal",
                    self.base.name()
                ),
            ));
        }
        match &self.dr {
            Some(dr) => nested("dr", dr),
            None => Ok(()),
        }
    }
}

impl Check for IosParams {
    fn check(&self) -> Checked {
        count("rollouts", self.rollouts, 1, 10_000_000)?;
        signed("first_offset", self.first_offset, -10_000, 10_000)?;
        signed("last_offset", self.last_offset, -10_000, 10_000)?;
        if self.first_offset > self.last_offset {
            return Err(Invalid::new(
                "first_offset",
                format!(
                    "{} is not valid here: expected at most last_offset ({})",
                    self.first_offset, self.last_offset
                ),
            ));
        }
        count("stride", self.stride, 1, 10_000)?;
        count("window", self.window, 1, 10_000)?;
        count("draws", self.draws, 1, 100_000)?;
        positive("size", self.size, 1e3)
    }
}

impl Check for ValidateParams {
    fn check(&self) -> Checked {
        count("q", self.q, 1, 1024)?;
        unit("delta_sr", self.delta_sr)?;
        within("lambda_f", self.lambda_f, 0.0, 1e6)?;
        within("lambda_d", self.lambda_d, 0.0, 1e6)?;
        if let Some(k) = self.kappa {
            within("kappa", k, 0.0, 100.0)?;
        }
        if let Some(s) = self.deviation_scale {
            within("deviation_scale", s, 0.0, 100.0)?;
        }
        count("rollouts", self.rollouts, 0, 10_000_000)
    }
}

impl Check for DartParams {
    fn check(&self) -> Checked {
        positive("kappa", self.kappa, 100.0)?;
        count("max_attempts", self.max_attempts, 1, 100_000)
    }
}

/// Its one knob is an enum: every value that parses is valid.
impl Check for DstarParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

impl Check for BaselineParams {
    fn check(&self) -> Checked {
        count("max_attempts", self.max_attempts, 1, 100_000)?;
        within("margin", self.margin, 1.0, 10.0)
    }
}
