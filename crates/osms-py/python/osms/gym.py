"""``osms/Catch-v0``: one catch at a time, as a gymnasium environment.

Each episode is a condition of an osms condition set, rolled out under an evaluation stage's
protocol: the condition, its domain randomisation and its noise are those osms's own
evaluation uses for that condition, whatever came before. ``reset(options={"index": i})``
picks condition ``i``; ``reset(seed=s)`` picks condition ``s mod n``; with neither, the next
condition after the last one (0 first).
"""

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from osms._native import Env as _Env
from osms._native import channels as _channels
from osms._project import project as _project
from osms._project import protocol as _protocol

_DEPLOYABLE = len(_channels()["agent_pos"])
_PRIVILEGED = len(_channels()["environment_state"])


class CatchEnv(gym.Env):
    """The catching world (an xArm7 with a 17-DoF hand catching thrown objects).

    Observation: a dict with ``agent_pos`` (the 76-channel deployable frame a student sees,
    float32) and, with ``privileged=True``, ``environment_state`` (the 85-channel privileged
    frame). Action: 24 values in [-1, 1] (7 arm target increments, 17 hand targets; names in
    ``env.unwrapped.channels["action"]``). An episode ends by the world's rules (the catch is
    decided, or the object is lost): ``terminated`` then, never ``truncated``. The reward is
    1 at the end of a successful catch, else 0. ``info``: ``is_success``, ``completion``,
    ``v_rel_mps``, ``f_max_n``, ``l_max_m``, ``failures``, ``condition``, ``steps``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        conditions="dev",
        protocol=None,
        privileged=False,
        render_mode=None,
        profile=None,
        pipeline=None,
        store=None,
        project=None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode {render_mode!r} is not supported; use one of {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode
        self._project = _project(pipeline, store, profile, project)
        self._privileged = bool(privileged)
        self._set_protocol(_protocol(self._project, conditions, protocol))
        names = _channels()
        self.channels = names if privileged else {k: v for k, v in names.items() if k != "environment_state"}
        spaces_ = {"agent_pos": spaces.Box(-np.inf, np.inf, (_DEPLOYABLE,), np.float32)}
        if self._privileged:
            spaces_["environment_state"] = spaces.Box(-np.inf, np.inf, (_PRIVILEGED,), np.float32)
        self.observation_space = spaces.Dict(spaces_)
        self.action_space = spaces.Box(-1.0, 1.0, (len(names["action"]),), np.float32)
        self._next = 0
        self._last_obs = None
        self.task = self.task_description = ""

    def _set_protocol(self, proto):
        self.protocol = proto
        self.metadata = dict(self.metadata, render_fps=int(round(proto.control_hz)))
        self._core = _Env(proto, self._privileged)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"conditions", "protocol", "index"}
        if unknown:
            raise ValueError(
                f"unknown reset options {sorted(unknown)}; known: conditions, protocol, index"
            )
        if "conditions" in options or "protocol" in options:
            self._set_protocol(
                _protocol(self._project, options.get("conditions", "dev"), options.get("protocol"))
            )
        n = self.protocol.n_conditions
        if options.get("index") is not None:
            index = int(options["index"])
        elif seed is not None:
            index = int(seed) % n
        else:
            index = self._next % n
        obs = self._core.reset(index)
        # LeRobot's evaluation reads these (language-conditioned policies get the task).
        self.task = self.task_description = self.protocol.task(index)
        self._next = index + 1
        self._last_obs = obs
        return obs, self._core.info()

    def step(self, action):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        obs, info = self._core.step(action)
        terminated = bool(info["done"])
        if terminated:
            obs = self._last_obs
        else:
            self._last_obs = obs
        reward = 1.0 if terminated and info["is_success"] else 0.0
        return obs, reward, terminated, False, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array'")
            return None
        return self._core.render()

    def row_csv(self):
        """The ended episode's row of ``rollouts.csv`` (with its header), else None."""
        return self._core.row_csv()
