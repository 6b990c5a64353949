//! Checkpoints of long trainings: the state a training hands out every few steps, so a build
//! killed midway (a full disk, an I/O error, a lost node) resumes from it. Each training's
//! state holds everything its remaining steps read, so a resumed training's bytes equal an
//! uninterrupted one's.

/// Where a training hands its state every `every` steps (never after the last: the caller
/// stores the result itself). `save`'s error stops the training.
pub struct Checkpoints<'a, S> {
    pub every: u32,
    pub save: &'a dyn Fn(&S) -> Result<(), String>,
}

impl<S> Checkpoints<'_, S> {
    /// Whether a checkpoint is due once `done` of `total` steps are done.
    pub fn due(&self, done: u32, total: u32) -> bool {
        done.is_multiple_of(self.every.max(1)) && done < total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoints_fall_every_k_steps_and_never_after_the_last() {
        let save = |_: &()| Ok(());
        let c = Checkpoints {
            every: 3,
            save: &save,
        };
        let due: Vec<u32> = (1..=9).filter(|&d| c.due(d, 9)).collect();
        assert_eq!(due, [3, 6]);
        let zero = Checkpoints {
            every: 0,
            save: &save,
        };
        assert!(zero.due(1, 2) && !zero.due(2, 2));
    }
}
