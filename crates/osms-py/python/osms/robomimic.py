"""``osms/Catch-v0`` as a robomimic environment (``robomimic.envs.env_base.EnvBase``).

Observations carry the keys of osms's robomimic export (``arm_qpos``, ``arm_qvel``,
``hand_qpos``, ``hand_qvel``, ``object_pos``, ``palm_touch``, ``prev_action``), so a policy trained
on ``osms export-dataset … --format robomimic`` runs as it is, e.g. with robomimic's
``run_rollout``::

    from osms.robomimic import OsmsEnv
    env = OsmsEnv("osms/Catch-v0", conditions="dev")
    env.reset_to({"index": 7})          # condition 7 of dev, osms's own protocol
    ob, reward, done, info = env.step(action)

``reset()`` runs the next condition (0 first); ``reset_to({"index": i})`` condition ``i``.
``OsmsEnv`` needs robomimic; the module itself imports without it, so that a plugin loader
importing every submodule of ``osms`` (LeRobot's ``--env.discover_packages_path=osms``) does
not need robomimic.
"""

import numpy as np

try:
    from robomimic.envs.env_base import EnvBase
except ImportError as _missing:  # OsmsEnv says so when it is used
    _ROBOMIMIC_MISSING = _missing
    EnvBase = object
else:
    _ROBOMIMIC_MISSING = None

from osms._native import N_ACTION, robomimic_keys
from osms.gym import CatchEnv

# The robomimic export's observation keys, in the deployable frame's order, with their widths
# (osms-export's own list).
KEYS = [tuple(k) for k in robomimic_keys()]


def split(agent_pos):
    """The deployable frame as robomimic's observation dict (float64, as robomimic reads)."""
    out, at = {}, 0
    for key, width in KEYS:
        out[key] = np.asarray(agent_pos[at:at + width], dtype=np.float64)
        at += width
    return out


class OsmsEnv(EnvBase):
    """The catching world for robomimic (see the module's doc)."""

    def __init__(self, env_name="osms/Catch-v0", render=False, render_offscreen=False,
                 use_image_obs=False, postprocess_visual_obs=True, **kwargs):
        if _ROBOMIMIC_MISSING is not None:
            raise ImportError(
                f"osms.robomimic.OsmsEnv needs robomimic ({_ROBOMIMIC_MISSING}): pip install robomimic"
            )
        if use_image_obs:
            raise ValueError("osms/Catch-v0 has low-dimensional observations only (use_image_obs=False)")
        self._env_name = env_name
        self._kwargs = dict(kwargs)
        render_mode = "rgb_array" if (render or render_offscreen) else None
        self.env = CatchEnv(render_mode=render_mode, **kwargs)
        self._obs = None
        self._info = {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(np.asarray(action, dtype=np.float64))
        self._obs, self._info = obs, info
        return self.get_observation(), reward, bool(terminated or truncated), info

    def reset(self):
        self._obs, self._info = self.env.reset()
        return self.get_observation()

    def reset_to(self, state):
        """``state``: ``{"index": i}``, condition ``i`` of the set (osms's rollouts are keyed
        by their condition; there is no free-form simulator state to load)."""
        if not isinstance(state, dict) or "index" not in state:
            keys = sorted(state) if isinstance(state, dict) else type(state).__name__
            raise ValueError(
                f"reset_to({keys}): osms/Catch-v0 resets to a condition, {{'index': i}} "
                "(get_state() gives the running one's); there is no simulator state to load"
            )
        self._obs, self._info = self.env.reset(options={"index": int(state["index"])})
        return self.get_observation()

    def render(self, mode="rgb_array", height=None, width=None, camera_name=None):
        return self.env.render()

    def get_observation(self):
        return split(self._obs["agent_pos"])

    def get_state(self):
        return {"index": self._info.get("condition", 0)}

    def get_reward(self):
        return 1.0 if self._info.get("done") and self._info.get("is_success") else 0.0

    def get_goal(self):
        return None

    def set_goal(self, **kwargs):
        raise NotImplementedError("osms/Catch-v0 has no goals")

    def is_done(self):
        return bool(self._info.get("done", False))

    def is_success(self):
        return {"task": bool(self._info.get("done") and self._info.get("is_success"))}

    @property
    def action_dimension(self):
        return N_ACTION

    @property
    def name(self):
        return self._env_name

    @property
    def type(self):
        # Not one of robomimic's own simulators: EnvUtils does not build it from a dataset's
        # env_meta, so construct it directly.
        return "osms"

    def serialize(self):
        return {"env_name": self._env_name, "type": self.type, "env_kwargs": dict(self._kwargs)}

    @classmethod
    def create_for_data_processing(cls, env_name, camera_names, camera_height, camera_width,
                                   reward_shaping, **kwargs):
        return cls(env_name=env_name, **kwargs)

    @property
    def rollout_exceptions(self):
        return ()
