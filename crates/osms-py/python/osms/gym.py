"""``osms/Catch-v0``: the catching world as a gymnasium environment (:class:`CatchEnv`, one
catch at a time) and a native vector environment (:class:`CatchVectorEnv`, many stepped
together in Rust).

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
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from osms._actions import real_array
from osms._native import DEFAULT_CONTROL_HZ, DEPLOYABLE_LEN, N_ACTION, PRIVILEGED_LEN
from osms._native import ActionError, OsmsError
from osms._native import Env as _Env
from osms._native import VectorEnv as _VectorEnv
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
        self.channels = _channels_shown(privileged)
        self.observation_space = _observation_space(self._privileged)
        self.action_space = spaces.Box(-1.0, 1.0, (N_ACTION,), np.float32)
        self._next = 0
        self._last_obs = None
        self.task = self.task_description = ""

    def _set_protocol(self, proto):
        self.protocol = proto
        self.metadata = dict(self.metadata, render_fps=int(round(proto.control_hz)))
        self._core = _Env(proto, self._privileged)

    def _same_thread(self, call):
        _check_thread(self, call)

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


def _check_thread(env, call):
    """Refuses a call from another thread than the one that made ``env``: its MuJoCo renderers
    are bound to that thread."""
    if threading.get_ident() != env._thread:
        raise OsmsError(
            f"{type(env).__name__}.{call}() from another thread than the one that made the environment: "
            "its MuJoCo renderers are bound to that thread; make one environment per thread"
        )


def _channels_shown(privileged):
    """The channel names of the observations an environment returns."""
    names = _channels()
    return names if privileged else {k: v for k, v in names.items() if k != "environment_state"}


def _observation_space(privileged):
    spaces_ = {"agent_pos": spaces.Box(-np.inf, np.inf, (DEPLOYABLE_LEN,), np.float32)}
    if privileged:
        spaces_["environment_state"] = spaces.Box(-np.inf, np.inf, (PRIVILEGED_LEN,), np.float32)
    return spaces.Dict(spaces_)


_VECTOR_RESET_OPTIONS = ("reset_mask", "indices", LEROBOT_NEW_ROLLOUT)


class CatchVectorEnv(VectorEnv):
    """``num_envs`` catches stepped together by osms's Rust pool, the GIL released while
    MuJoCo runs: gymnasium's ``VectorEnv`` (also ``gymnasium.make_vec("osms/Catch-v0",
    num_envs=n, vectorization_mode="vector_entry_point")``).

    Conditions are handed out once each, in order, across sub-environments: ``reset()`` starts
    sub-environment ``k`` on the ``k``-th next condition, and each episode that ends is
    followed by the set's next condition (in sub-environment order when several end in one
    step), so the first ``n`` episodes are the set's ``n`` conditions whatever ``num_envs``;
    after the last condition the set starts again at 0. ``reset(seed=s)`` starts
    sub-environment ``k`` on condition ``(s + k) mod n`` (a list of seeds: one per
    sub-environment), ``options={"indices": [...]}`` on the conditions listed, and the next
    conditions follow the last one started. Each episode is the protocol's rollout of its
    condition, bit for bit the row ``osms export`` writes, whatever ``num_envs`` and whichever
    sub-environment runs it.

    Observations, actions, rewards and the end of an episode are :class:`CatchEnv`'s, batched:
    ``agent_pos`` (``num_envs`` × 76 float32), ``environment_state`` with
    ``privileged=True``; actions ``num_envs`` × 24 in [-1, 1]. ``autoreset_mode``
    (``metadata["autoreset_mode"]``) is one of gymnasium's: ``NEXT_STEP`` (default: the step
    after the end starts the next episode, ignoring that sub-environment's action),
    ``SAME_STEP`` (the ending step returns the next episode's first observation, with
    ``info["final_obs"]`` and ``info["final_info"]``), ``DISABLED`` (reset ended
    sub-environments with ``reset(options={"reset_mask": mask})``). Infos carry, per key, an
    array over sub-environments and a ``_key`` mask: ``condition``, ``steps``, ``is_success``,
    ``completion``, ``l_max_m``, ``failures``, and ``v_rel_mps``/``f_max_n`` (masked until a
    contact). ``max_episode_steps`` truncates an episode the world has not ended by then (the
    world ends every episode within ``protocol.max_steps``, the registered limit).
    ``call("_max_episode_steps")``, ``call("task_description")``, ``call("task")`` and
    ``call("render")`` answer per sub-environment, as LeRobot's evaluation asks them.

    ``native`` (a policy of the store, :func:`osms.policies.load`) runs the episodes under its
    rollout spec, so that ``env.native_actions(native)`` gives its actions for the current
    observations, as its own evaluation stage would. ``conditions``, ``protocol``, ``profile``,
    ``pipeline``, ``store`` and ``project`` are :class:`CatchEnv`'s. The environment is bound
    to the thread that made it (its renderers), as :class:`CatchEnv` is.
    """

    def __init__(
        self,
        num_envs=1,
        conditions="dev",
        protocol=None,
        privileged=False,
        autoreset_mode=AutoresetMode.NEXT_STEP,
        max_episode_steps=None,
        native=None,
        render_mode=None,
        profile=None,
        pipeline=None,
        store=None,
        project=None,
    ):
        if render_mode is not None and render_mode != "rgb_array":
            raise ValueError(f"render_mode {render_mode!r} is not supported; use one of ['rgb_array']")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(
                f"autoreset_mode {autoreset_mode!r} is not one of gymnasium's: "
                + ", ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in AutoresetMode)
            ) from None
        self._thread = threading.get_ident()
        self._project = _project(pipeline, store, profile, project)
        self.protocol = _protocol(self._project, conditions, protocol)
        if max_episode_steps is not None:
            max_episode_steps = int(max_episode_steps)
        self._core = _VectorEnv(
            self.protocol,
            int(num_envs),
            mode.value,
            policy=native,
            privileged=bool(privileged),
            max_episode_steps=max_episode_steps,
        )
        self.num_envs = self._core.num_envs
        self.render_mode = render_mode
        self._privileged = bool(privileged)
        self._max_episode_steps = max_episode_steps or self.protocol.max_steps
        self.metadata = {
            "autoreset_mode": mode,
            "render_modes": ["rgb_array"],
            "render_fps": int(round(self.protocol.control_hz)),
        }
        self.channels = _channels_shown(privileged)
        self.single_observation_space = _observation_space(self._privileged)
        self.single_action_space = spaces.Box(-1.0, 1.0, (N_ACTION,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.closed = False

    def _same_thread(self, call):
        _check_thread(self, call)

    def reset(self, *, seed=None, options=None):
        """Starts episodes in every sub-environment (or those ``options["reset_mask"]``
        marks): on conditions ``(seed + k) mod n`` for an int ``seed``, ``seed[k] mod n`` for
        a list (``None`` entries: the next condition), ``options["indices"]`` (one per reset
        sub-environment), else the next conditions in order. LeRobot's
        ``lerobot_new_rollout`` option is accepted."""
        self._same_thread("reset")
        options = dict(options or {})
        unknown = set(options) - set(_VECTOR_RESET_OPTIONS)
        if unknown:
            raise ValueError(
                f"unknown reset options {sorted(unknown)}; known: {', '.join(_VECTOR_RESET_OPTIONS)}"
            )
        mask = options.get("reset_mask")
        if mask is None:
            which = list(range(self.num_envs))
        else:
            mask = np.asarray(mask)
            if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},), "
                    f"got {mask.dtype} of shape {mask.shape}"
                )
            which = [k for k in range(self.num_envs) if mask[k]]
            if not which:
                raise ValueError("options['reset_mask'] marks no sub-environment to reset")
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + k for k in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"{len(seeds)} seeds for {self.num_envs} sub-environments: pass one per sub-environment"
                )
        n = self.protocol.n_conditions
        starts = [(k, None if seeds[k] is None else int(seeds[k]) % n) for k in which]
        if options.get("indices") is not None:
            indices = [int(i) for i in options["indices"]]
            if len(indices) != len(which):
                raise ValueError(
                    f"{len(indices)} condition indices for {len(which)} sub-environments being reset: one each"
                )
            starts = list(zip(which, indices))
        if seed is not None:
            super().reset(seed=seeds[0] if which else None)
        return self._core.reset(starts)

    def step(self, actions):
        """Runs one action per sub-environment (``num_envs`` × 24, in [-1, 1]); anything the
        world cannot run raises :class:`osms.ActionError` and moves no sub-environment."""
        self._same_thread("step")

        def refuse(problem):
            return ActionError(
                f"the policy's actions {problem}; expected real numbers in [-1, 1] of shape "
                f"({self.num_envs}, {N_ACTION}): one row per sub-environment"
            )

        a = real_array(actions, refuse, many=True)
        if a.shape != (self.num_envs, N_ACTION):
            raise refuse(f"have shape {a.shape}")
        return self._core.step(np.ascontiguousarray(a, dtype=np.float64))

    def native_actions(self, policy):
        """The store policy ``policy``'s actions for the current observations (the environment
        must have been made with ``native=policy``); zeros for ended episodes."""
        self._same_thread("native_actions")
        return self._core.native_actions(policy)

    def render(self):
        """Each sub-environment's current state as an (480, 480, 3) uint8 frame."""
        self._same_thread("render")
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array'")
            return None
        return tuple(self._core.render(k) for k in range(self.num_envs))

    def rows_csv(self):
        """The rows of the episodes that ended by the world's rules so far (truncated ones
        left out), in the order they started, as ``rollouts.csv``; None before any ended."""
        return self._core.rows_csv()

    @property
    def envs(self):
        """A view of each sub-environment (its ``task``, ``task_description``,
        ``_max_episode_steps``, ``condition``, ``render()``…), for code written against
        gymnasium's ``SyncVectorEnv`` (LeRobot 0.4 reads ``env.envs[0]``)."""
        return tuple(_SubEnv(self, k) for k in range(self.num_envs))

    def get_attr(self, name):
        """Attribute ``name`` of each sub-environment, as a tuple."""
        return tuple(getattr(sub, name) for sub in self.envs)

    def call(self, name, *args, **kwargs):
        """Calls method ``name`` of each sub-environment (or reads the attribute), as a tuple."""
        self._same_thread("call")
        values = self.get_attr(name)
        return tuple(v(*args, **kwargs) if callable(v) else v for v in values)

    def set_attr(self, name, values):
        raise AttributeError(f"the sub-environments of CatchVectorEnv have no settable attributes ({name!r})")


class _SubEnv:
    """Sub-environment ``k`` of a :class:`CatchVectorEnv`, as its attributes read."""

    _SHARED = ("channels", "metadata", "protocol", "render_mode", "spec")

    def __init__(self, vector, k):
        self._vector, self._k = vector, k

    @property
    def condition(self):
        return self._vector._core.condition(self._k)

    @property
    def task(self):
        index = self.condition
        return "" if index is None else self._vector.protocol.task(index)

    task_description = task

    @property
    def _max_episode_steps(self):
        return self._vector._max_episode_steps

    def render(self):
        self._vector._same_thread("render")
        return self._vector._core.render(self._k)

    def __getattr__(self, name):
        if name in self._SHARED:
            return getattr(self._vector, name)
        raise AttributeError(
            f"the sub-environments of CatchVectorEnv have no attribute {name!r}; known: "
            + ", ".join(sorted(("_max_episode_steps", "condition", "render", "task", "task_description") + self._SHARED))
        )

    def __repr__(self):
        return f"<sub-environment {self._k} of {self._vector!r}>"


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
