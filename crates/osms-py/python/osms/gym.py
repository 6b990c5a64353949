"""``osms/Catch-v0``: one catch at a time, as a gymnasium environment.

Each episode is a condition of an osms condition set, rolled out under an evaluation stage's
protocol: the condition, its domain randomisation and its noise are those osms's own
evaluation uses for that condition, whatever came before. ``reset(options={"index": i})``
picks condition ``i``; ``reset(seed=s)`` picks condition ``s mod n``; with neither, the next
condition after the last one (0 first).
"""

import threading

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from osms._actions import real_array
from osms._native import DEFAULT_CONTROL_HZ, DEPLOYABLE_LEN, N_ACTION, PRIVILEGED_LEN
from osms._native import ActionError, OsmsError
from osms._native import Env as _Env
from osms._native import channels as _channels
from osms._project import project as _project
from osms._project import protocol as _protocol

# LeRobot (>= 0.5) marks the reset that starts a new rollout with this option, to tell it
# from gymnasium's automatic resets; here every reset starts the condition it names anyway.
LEROBOT_NEW_ROLLOUT = "lerobot_new_rollout"
_RESET_OPTIONS = ("conditions", "protocol", "index", LEROBOT_NEW_ROLLOUT)


class CatchEnv(gym.Env):
    """The catching world (an xArm7 with a 17-DoF hand catching thrown objects).

    Observation: a dict with ``agent_pos`` (the 76-channel deployable frame a student sees,
    float32) and, with ``privileged=True``, ``environment_state`` (the 84-channel privileged
    frame). Action: 24 values in [-1, 1] (7 arm target increments, 17 hand targets; names in
    ``env.unwrapped.channels["action"]``); anything else raises :class:`osms.ActionError`
    and leaves the episode where it was. An episode ends by the world's rules (the catch is
    decided, or the object is lost, at the latest after ``env.unwrapped.protocol.max_steps``
    control steps): ``terminated`` then, never ``truncated``. The step that ends it returns
    the last observation before the end again (the world observes nothing after it); a
    ``step()`` after the end raises :class:`osms.OsmsError` until ``reset()`` starts the next
    condition. The reward is 1 at the end of a successful catch, else 0. ``info``:
    ``is_success``, ``completion``, ``v_rel_mps``, ``f_max_n``, ``l_max_m``, ``failures``,
    ``condition``, ``steps``.

    ``conditions`` (``"dev"``, ``"heldout"``) runs under osms's default protocol for the set,
    ``protocol`` (an evaluation stage, ``"eval_teacher"``) under that one. ``pipeline``,
    ``profile`` and ``store`` name the osms project (default: the ``pipeline.toml`` of the
    working directory or a parent, its default profile, the store beside it; a store that does
    not exist yet is created), or ``project`` passes an opened :class:`osms.Project`. An environment
    holds MuJoCo's renderer, bound to the thread that made it: use it from that thread (one
    environment per thread, as gymnasium's vector environments do).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(DEFAULT_CONTROL_HZ))}

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
        self._thread = threading.get_ident()
        self._project = _project(pipeline, store, profile, project)
        self._privileged = bool(privileged)
        self._set_protocol(_protocol(self._project, conditions, protocol))
        names = _channels()
        self.channels = names if privileged else {k: v for k, v in names.items() if k != "environment_state"}
        spaces_ = {"agent_pos": spaces.Box(-np.inf, np.inf, (DEPLOYABLE_LEN,), np.float32)}
        if self._privileged:
            spaces_["environment_state"] = spaces.Box(-np.inf, np.inf, (PRIVILEGED_LEN,), np.float32)
        self.observation_space = spaces.Dict(spaces_)
        self.action_space = spaces.Box(-1.0, 1.0, (N_ACTION,), np.float32)
        self._next = 0
        self._last_obs = None
        self.task = self.task_description = ""

    def _set_protocol(self, proto):
        self.protocol = proto
        self.metadata = dict(self.metadata, render_fps=int(round(proto.control_hz)))
        self._core = _Env(proto, self._privileged)

    def _same_thread(self, call):
        if threading.get_ident() != self._thread:
            raise OsmsError(
                f"CatchEnv.{call}() from another thread than the one that made the environment: "
                "its MuJoCo renderer is bound to that thread; make one environment per thread"
            )

    def reset(self, *, seed=None, options=None):
        """Starts a condition: ``options={"index": i}``, else ``seed mod n``, else the next
        one. ``options`` may also switch ``conditions`` or ``protocol``; LeRobot's
        ``lerobot_new_rollout`` is accepted (every reset is a new rollout here)."""
        self._same_thread("reset")
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(_RESET_OPTIONS)
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; known: {', '.join(_RESET_OPTIONS)}")
        if "conditions" in options or "protocol" in options:
            self._set_protocol(
                _protocol(self._project, options.get("conditions", "dev"), options.get("protocol"))
            )
        n = self.protocol.n_conditions
        if n == 0:
            raise OsmsError(f"the condition set `{self.protocol.conditions}` of `{self.protocol.name}` is empty")
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
        self._same_thread("step")
        obs, info = self._core.step(_as_action(action, self._core.info()))
        terminated = bool(info["done"])
        if terminated:
            obs = self._last_obs
        else:
            self._last_obs = obs
        reward = 1.0 if terminated and info["is_success"] else 0.0
        return obs, reward, terminated, False, info

    def render(self):
        self._same_thread("render")
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array'")
            return None
        return self._core.render()

    def row_csv(self):
        """The ended episode's row of ``rollouts.csv`` (with its header), else None."""
        self._same_thread("row_csv")
        return self._core.row_csv()


def _as_action(action, info):
    """One rollout's action as the (24,) float64 array the world runs, or ActionError."""

    def refuse(problem):
        return ActionError(
            f"the policy's action for condition {info['condition']} at control step {info['steps']} "
            f"{problem}; expected {N_ACTION} real numbers in [-1, 1], shape ({N_ACTION},)"
        )

    a = real_array(action, refuse, many=False)
    if a.shape != (N_ACTION,):
        raise refuse(f"has shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)
