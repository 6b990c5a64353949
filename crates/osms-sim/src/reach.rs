//! The reachable follow-through: how far the palm can carry a caught object along its incoming
//! direction within the evaluation window Δt_eval after first contact, when the arm does
//! nothing but that at the fastest rate the control allows. The paper's teacher averages
//! ℓ_max = 0.42 m; the success criterion asks for δ_ℓ = 0.2 m. This is the world's ceiling for
//! any policy, measured with the same evaluator as every rollout.

use crate::catcher::{CatcherSpec, ScriptedCatcher, palm_motion_channels};
use crate::control::{Action, ControlSpec, N_ARM};
use crate::episode::{Policy, PolicyView};

/// Damping of the follow-through's damped-least-squares step (as the teacher's channel).
pub const FOLLOW_THROUGH_DAMPING: f64 = 0.05;

/// The scripted catcher until first contact, then every arm channel at full scale along the
/// frozen incoming direction (the hand keeps closing as the catcher closes it).
pub struct FollowThroughProbe {
    catcher: ScriptedCatcher,
    /// Weight of the palm's orientation against its position in the follow-through's IK
    /// (see [`palm_motion_channels`]).
    pub orientation_weight: f64,
}

impl FollowThroughProbe {
    pub fn new(catcher: CatcherSpec, control: ControlSpec, orientation_weight: f64) -> Self {
        FollowThroughProbe {
            catcher: ScriptedCatcher::new(catcher, control),
            orientation_weight,
        }
    }
}

impl Policy for FollowThroughProbe {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let mut action = self.catcher.act(view);
        if let Some(contact) = view.first_contact {
            let g = palm_motion_channels(
                view,
                contact.incoming_dir,
                self.orientation_weight,
                FOLLOW_THROUGH_DAMPING,
            );
            action[..N_ARM].copy_from_slice(&g);
        }
        action
    }

    fn reads_contact_force(&self) -> bool {
        false
    }
}
