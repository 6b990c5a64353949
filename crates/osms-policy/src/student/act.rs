//! Acting: chunks sampled from the flow, the executed action of a chunk, and the observation a
//! live rollout gives the student.

use osms_core::rng::StreamRng;
use osms_nn::Matrix;
use osms_sim::policy::{OBSERVED_OBJECT, PRIVILEGED_PALM};
use osms_sim::{Action, N_ACTION, N_ARM, PolicyView};

use crate::flow::{FlowSampler, normals};

use super::chunks::ChunkRunner;
use super::demo::{
    ARM_STEP_RAD, Current, NOMINAL_CONTROL_PERIOD_SECS, push_features, tracked_features,
};
use super::train::Student;

impl Student {
    /// The first action of a sampled chunk for a raw observation (the policy's output),
    /// drawing the initial noise from `rng`.
    pub fn act(&self, obs: &[f32], rng: &mut StreamRng) -> Action {
        self.act_with(&self.net.sampler(), obs, rng)
    }

    /// [`Student::act`] through a sampler prepared once ([`FlowNet::sampler`]).
    pub fn act_with(&self, sampler: &FlowSampler<'_>, obs: &[f32], rng: &mut StreamRng) -> Action {
        let [action] = self
            .act_batch_with(sampler, std::slice::from_ref(&obs), [rng])
            .try_into()
            .unwrap_or_else(|_| unreachable!("one observation, one action"));
        action
    }

    /// [`Student::act`] on many observations at once, observation i drawing its noise from the
    /// i-th stream: action i is bit for bit `act(obs[i], rng_i)` (the flow network's batch
    /// invariance, [`FlowNet::sample_batch`]), at matrix-product instead of matrix-vector speed.
    pub fn act_batch<'r, O: AsRef<[f32]>>(
        &self,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Action> {
        self.act_batch_with(&self.net.sampler(), obs, rngs)
    }

    /// [`Student::act_batch`] through a sampler of this student's network prepared once
    /// ([`FlowNet::sampler`]) for many actions, with the same bits.
    pub fn act_batch_with<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Action> {
        self.chunks_batch_with(sampler, obs, rngs)
            .iter()
            .zip(obs)
            .map(|(chunk, o)| self.executable(&chunk[..N_ACTION], o.as_ref()))
            .collect()
    }

    /// The sampled chunks for `obs`, each de-standardised (`chunk` steps of [`N_ACTION`]
    /// values), observation i drawing its noise from the i-th stream.
    fn chunks_batch_with<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Vec<f64>> {
        let (c_len, x_len) = (self.params.obs_len(), self.params.chunk_len());
        let mut cond = Vec::with_capacity(obs.len() * c_len);
        let mut noise = Vec::with_capacity(obs.len() * x_len);
        for (o, rng) in obs.iter().zip(rngs) {
            cond.extend(self.obs_norm.apply(o.as_ref()));
            noise.extend(
                normals(rng, x_len)
                    .into_iter()
                    .map(|x| x * self.params.noise_scale),
            );
        }
        assert_eq!(
            noise.len(),
            obs.len() * x_len,
            "student: one stream per observation"
        );
        let rows = obs.len();
        if rows == 0 {
            return Vec::new();
        }
        let x = sampler.sample_batch(
            &Matrix::from_vec(rows, c_len, cond),
            Matrix::from_vec(rows, x_len, noise),
            self.params.euler_steps,
        );
        (0..rows)
            .map(|i| {
                x.row(i)
                    .iter()
                    .enumerate()
                    .map(|(j, &v)| {
                        let k = j % N_ACTION;
                        f64::from(v * self.act_norm.std[k] + self.act_norm.mean[k])
                    })
                    .collect()
            })
            .collect()
    }

    /// The action executed for a de-standardised chunk step at the observation `obs` of the step
    /// it runs in: a target label turned into the increment from the current target, clamped
    /// to [−1, 1].
    fn executable(&self, step: &[f64], obs: &[f32]) -> Action {
        let mut action: Action = std::array::from_fn(|k| step[k]);
        if self.params.target_labels {
            // The arm target features close the observation (`push_features`).
            let current = &obs[obs.len() - N_ARM..];
            for (a, t) in action[..N_ARM].iter_mut().zip(current) {
                *a = (*a - f64::from(*t)) / ARM_STEP_RAD;
            }
        }
        action.map(|a| a.clamp(-1.0, 1.0))
    }

    /// One control step of many running episodes, each with its own noise stream and chunk
    /// state ([`ChunkRunner`]): the episodes whose runner samples this step get a chunk in one
    /// batched sample, then every runner gives its step's action. With the paper's execution
    /// (h = 1) action i is bit for bit [`Student::act_batch_with`]'s.
    pub fn act_executed<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        states: impl IntoIterator<Item = (&'r mut StreamRng, &'r mut ChunkRunner)>,
    ) -> Vec<Action> {
        let mut runners: Vec<&mut ChunkRunner> = Vec::with_capacity(obs.len());
        let mut sampling = Vec::new();
        let mut rngs = Vec::new();
        for (i, (rng, runner)) in states.into_iter().enumerate() {
            if runner.samples() {
                sampling.push(i);
                rngs.push(rng);
            }
            runners.push(runner);
        }
        assert_eq!(
            runners.len(),
            obs.len(),
            "student: one runner per observation"
        );
        let sampled_obs: Vec<&[f32]> = sampling.iter().map(|&i| obs[i].as_ref()).collect();
        let chunks = self.chunks_batch_with(sampler, &sampled_obs, rngs);
        for (&i, chunk) in sampling.iter().zip(chunks) {
            runners[i].push(chunk);
        }
        runners
            .into_iter()
            .zip(obs)
            .map(|(runner, o)| self.executable(&runner.next(), o.as_ref()))
            .collect()
    }

    /// The observation of a running rollout: its history of deployable frames, the oldest
    /// repeated to `history` frames, then the current step's features (as the record keeps
    /// them: in f32).
    pub fn observation(&self, view: &PolicyView<'_>) -> Vec<f32> {
        let p = &self.params;
        let h = p.history;
        let frames = view.history;
        let mut out = Vec::with_capacity(p.obs_len());
        for i in 0..h {
            let k = (frames.len() + i).saturating_sub(h);
            out.extend(frames[k][..p.frame_len()].iter().map(|&v| v as f32));
        }
        let f32s = |v: &[f64]| -> [f32; 3] { std::array::from_fn(|c| v[c] as f32) };
        let palm_pos = f32s(&view.privileged[PRIVILEGED_PALM..]);
        let palm_vel = f32s(&view.privileged[PRIVILEGED_PALM + 6..]);
        let object = f32s(&view.deployable[OBSERVED_OBJECT..]);
        let velocity = f32s(&view.data.qvel()[view.world.ids.object_dof..]);
        let targets = view.arm_targets.map(|v| v as f32);
        let tracked = if p.tracked_object {
            tracked_features(view.tracker.estimate(NOMINAL_CONTROL_PERIOD_SECS))
        } else {
            [0.0; 6]
        };
        let now = Current {
            palm_pos: &palm_pos,
            palm_vel: &palm_vel,
            object: &object,
            object_vel: &velocity,
            arm_targets: &targets,
            tracked: &tracked,
        };
        push_features(p, 0, &now, &mut out);
        out
    }
}
