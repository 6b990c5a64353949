//! The reachable follow-through: how far the palm can carry a caught object along its incoming
//! direction within the evaluation window Δt_eval after first contact, when the arm does
//! nothing but that at the fastest rate the control allows. The paper's teacher averages
//! ℓ_max = 0.42 m; the success criterion asks for δ_ℓ = 0.2 m. What the probe reaches bounds
//! the world's ceiling from below (a cleverer motion may reach further), measured with the same
//! evaluator as every rollout.

use crate::catcher::{CatcherSpec, PALM_MOTION_DAMPING, ScriptedCatcher, palm_motion_channels};
use crate::control::{Action, ControlSpec, N_ARM};
use crate::policy::{Policy, PolicyView};
use crate::vec3::{norm, sub};

/// The scripted catcher until first contact, then every arm channel at full scale along the
/// frozen incoming direction until Δt_eval has passed, then the arm holds its targets (the
/// hand keeps closing as the catcher closes it). With
/// `start_distance_m`, the palm already starts moving along the object's velocity once the
/// object is that close, as a velocity-matching catch would.
pub struct FollowThroughProbe {
    catcher: ScriptedCatcher,
    /// Weight of the palm's orientation against its position in the follow-through's IK
    /// (see [`palm_motion_channels`]).
    pub orientation_weight: f64,
    pub start_distance_m: Option<f64>,
    /// How long after first contact the palm keeps moving: Δt_eval by default.
    pub window_secs: f64,
    started: bool,
}

impl FollowThroughProbe {
    pub fn new(catcher: CatcherSpec, control: ControlSpec, orientation_weight: f64) -> Self {
        FollowThroughProbe {
            catcher: ScriptedCatcher::new(catcher, control),
            orientation_weight,
            start_distance_m: None,
            window_secs: crate::metrics::SuccessSpec::default().eval_window_secs,
            started: false,
        }
    }

    /// The same, moving from when the object is `distance` from the palm.
    pub fn starting_at(mut self, distance: f64) -> Self {
        self.start_distance_m = Some(distance);
        self
    }
}

impl Policy for FollowThroughProbe {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let mut action = self.catcher.act_increments(view);
        let moving = match view.first_contact {
            // Past the evaluation window the arm holds its targets, as a catch that ends its
            // follow-through does, instead of folding onto itself.
            Some(contact) => view.time_secs - contact.time_secs <= self.window_secs,
            None => {
                let palm = view.data.site_xpos()[view.world.ids.palm_site];
                let gap = norm(sub(view.object.pos, palm));
                self.started |= self.start_distance_m.is_some_and(|s| gap < s);
                self.started
            }
        };
        if moving {
            let dir = self.catcher.follow_through_direction(view);
            let g = palm_motion_channels(view, dir, self.orientation_weight, PALM_MOTION_DAMPING);
            action[..N_ARM].copy_from_slice(&g);
        }
        view.arm_from_increments(self.catcher.control(), &mut action);
        action
    }

    fn reads_contact_force(&self) -> bool {
        false
    }
}
