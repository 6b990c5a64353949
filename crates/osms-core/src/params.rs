use serde::{Deserialize, Serialize};

use crate::check::{Check, Checked};

/// Params of kinds that take none (any given is an error).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

impl Check for NoParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}
