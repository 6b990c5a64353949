//! Candidate selection of paper 4.4 and Alg. 1: which validated candidate, if any, replaces a
//! D_R rollout's OSW motion.
//!
//! - Refinement (the original succeeded): a candidate is eligible if it succeeds unperturbed,
//!   improves the quality, J < J_org, and is at least as robust, SR ≥ SR_org.
//! - Repair (the original failed): eligible if it succeeds unperturbed and SR ≥ δ_SR.
//! - Among the eligible: lowest J, then higher SR, then shorter geodesic distance, then the
//!   lower index (so the choice never depends on anything but the table).
//! - No eligible candidate: a successful original is kept, a failed one dropped.

/// J of Eq. 9: λ_f f_max + λ_d ‖ζ − ζ_org‖_{W_a}.
pub fn quality(max_force_n: f64, deviation: f64, lambda_f: f64, lambda_d: f64) -> f64 {
    lambda_f * max_force_n + lambda_d * deviation
}

/// One candidate's validation so far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateOutcome {
    pub unperturbed_success: bool,
    /// J of the unperturbed rollout (meaningful when it succeeded).
    pub j: f64,
    /// SR of Eq. 8 over the perturbed rollouts evaluated (`None`: not evaluated).
    pub sr: Option<f64>,
    /// Geodesic distance from the search centre (the tie-break after SR).
    pub distance: f64,
}

/// The original rollout's validation: success, and for a success its J and SR.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OriginalOutcome {
    pub success: bool,
    pub j: f64,
    pub sr: f64,
}

/// What becomes of a D_R rollout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    /// A successful original replaced by candidate `index`.
    Refine { index: usize },
    /// A failed original replaced by candidate `index`.
    Repair { index: usize },
    /// No eligible candidate; the successful original stays.
    KeepOriginal,
    /// No eligible candidate; the failed original is dropped.
    Drop,
}

impl Decision {
    /// The selected candidate, if any.
    pub fn selected(self) -> Option<usize> {
        match self {
            Decision::Refine { index } | Decision::Repair { index } => Some(index),
            Decision::KeepOriginal | Decision::Drop => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Decision::Refine { .. } => "refine",
            Decision::Repair { .. } => "repair",
            Decision::KeepOriginal => "keep original",
            Decision::Drop => "drop",
        }
    }
}

/// Whether candidate `c` may replace `original` (δ_SR for repairs).
pub fn eligible(original: &OriginalOutcome, c: &CandidateOutcome, delta_sr: f64) -> bool {
    let Some(sr) = c.sr else { return false };
    if !c.unperturbed_success {
        return false;
    }
    if original.success {
        c.j < original.j && sr >= original.sr
    } else {
        sr >= delta_sr
    }
}

/// The decision of Alg. 1 for one rollout.
pub fn select(
    original: &OriginalOutcome,
    candidates: &[CandidateOutcome],
    delta_sr: f64,
) -> Decision {
    let better = |a: &(usize, &CandidateOutcome), b: &(usize, &CandidateOutcome)| {
        let (ia, a) = *a;
        let (ib, b) = *b;
        a.j.total_cmp(&b.j)
            .then_with(|| {
                b.sr.unwrap_or(f64::NEG_INFINITY)
                    .total_cmp(&a.sr.unwrap_or(f64::NEG_INFINITY))
            })
            .then_with(|| a.distance.total_cmp(&b.distance))
            .then_with(|| ia.cmp(&ib))
    };
    let best = candidates
        .iter()
        .enumerate()
        .filter(|(_, c)| eligible(original, c, delta_sr))
        .min_by(better);
    match (best, original.success) {
        (Some((index, _)), true) => Decision::Refine { index },
        (Some((index, _)), false) => Decision::Repair { index },
        (None, true) => Decision::KeepOriginal,
        (None, false) => Decision::Drop,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(success: bool, j: f64, sr: f64, distance: f64) -> CandidateOutcome {
        CandidateOutcome {
            unperturbed_success: success,
            j,
            sr: Some(sr),
            distance,
        }
    }

    const DELTA: f64 = 0.75;

    #[test]
    fn refinement_needs_lower_j_and_no_less_robustness() {
        let org = OriginalOutcome {
            success: true,
            j: 10.0,
            sr: 0.5,
        };
        let table = [
            c(true, 12.0, 1.0, 0.1), // worse J
            c(true, 8.0, 0.4, 0.1),  // less robust
            c(false, 1.0, 1.0, 0.1), // fails unperturbed
            c(true, 9.0, 0.5, 0.7),  // eligible
            c(true, 9.5, 0.9, 0.1),  // eligible, higher J
        ];
        assert_eq!(select(&org, &table, DELTA), Decision::Refine { index: 3 });
        assert_eq!(select(&org, &table[..3], DELTA), Decision::KeepOriginal);
        // J equal to J_org is no improvement.
        assert_eq!(
            select(&org, &[c(true, 10.0, 1.0, 0.0)], DELTA),
            Decision::KeepOriginal
        );
    }

    #[test]
    fn repair_needs_the_robustness_threshold() {
        let org = OriginalOutcome {
            success: false,
            j: f64::NAN,
            sr: 0.0,
        };
        let table = [c(true, 5.0, 0.6875, 0.1), c(true, 7.0, 0.75, 0.2)];
        assert_eq!(select(&org, &table, DELTA), Decision::Repair { index: 1 });
        assert_eq!(select(&org, &table[..1], DELTA), Decision::Drop);
        assert_eq!(select(&org, &[], DELTA), Decision::Drop);
        // A candidate whose perturbed rollouts were never run is not eligible.
        let unevaluated = CandidateOutcome {
            sr: None,
            ..c(true, 1.0, 1.0, 0.0)
        };
        assert_eq!(select(&org, &[unevaluated], DELTA), Decision::Drop);
    }

    #[test]
    fn ties_go_to_higher_sr_then_shorter_distance_then_the_lower_index() {
        let org = OriginalOutcome {
            success: false,
            j: 0.0,
            sr: 0.0,
        };
        let sr_tie = [c(true, 3.0, 0.8, 0.1), c(true, 3.0, 0.9, 0.5)];
        assert_eq!(select(&org, &sr_tie, DELTA), Decision::Repair { index: 1 });
        let distance_tie = [c(true, 3.0, 0.9, 0.5), c(true, 3.0, 0.9, 0.2)];
        assert_eq!(
            select(&org, &distance_tie, DELTA),
            Decision::Repair { index: 1 }
        );
        let full_tie = [c(true, 3.0, 0.9, 0.2), c(true, 3.0, 0.9, 0.2)];
        assert_eq!(
            select(&org, &full_tie, DELTA),
            Decision::Repair { index: 0 }
        );
    }

    #[test]
    fn quality_is_eq_9() {
        assert_eq!(quality(40.0, 2.0, 0.5, 3.0), 26.0);
    }
}
