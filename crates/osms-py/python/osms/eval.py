"""Evaluate any policy on osms's condition sets, with osms's own protocol and metrics.

:func:`evaluate` steps many rollouts in Rust (the GIL released while MuJoCo runs) and calls the
policy once per control step with the batch of running rollouts' observations. Rollout ``i`` is
the protocol's rollout on condition ``i``: its domain randomisation comes from the protocol
stage's stream for that condition, and the store's own policies reproduce ``osms export``'s
rows bit for bit. A policy's rows do not depend on ``n_envs`` when its action for a rollout
depends only on that rollout's observations, bit for bit: true of the store's policies and of
row-wise NumPy code, not of code whose arithmetic depends on the batch (a BLAS matrix product
may sum a row in another order when the batch is larger, which moves the last bits of an
action and so, in a chaotic catch, possibly a row).

A policy is any callable ``policy(obs) -> actions``:

``obs`` (a dict)
    ``agent_pos``: ``(n, 76)`` float32, the deployable frame a student sees (channel names:
    ``osms.channels()["agent_pos"]``); ``environment_state``: ``(n, 84)`` float32, the
    privileged frame, only with ``privileged=True``; ``condition`` and ``step``: ``(n,)``
    int64, which condition each row is and its control step (0 starts a rollout: reset any
    per-rollout memory there); ``osms_batch``: what the store's policies read.
``actions``
    ``(n, 24)`` real numbers in [-1, 1], any integer or float dtype (float32 converts
    exactly), in the world's channel order (``osms.channels()["action"]``), one row per
    observation row; a ``(24,)`` row when one rollout runs. Anything else raises
    :class:`osms.ActionError`.
"""

import csv
import io
import json
import operator
import os
import time

import numpy as np

from osms._actions import real_array
from osms._native import N_ACTION, ActionError, NativePolicy, Pool, row_column_types
from osms._native import wilson as _wilson
from osms._project import project as _project
from osms._project import protocol as _protocol

# How each column of rollouts.csv parses (int, float, bool, text): osms-export's own table.
_COLUMN_TYPES = dict(row_column_types())


def wilson(successes, n, z=None):
    """The Wilson score interval of ``successes`` out of ``n`` (95 % unless ``z`` is given), as
    ``(low, high)``: exactly 0 (1) at the lower (upper) end for 0 (``n``) successes, ``(nan,
    nan)`` for ``n = 0``. osms's own tables use the same function (it is the Rust crates')."""
    return _wilson(operator.index(successes), operator.index(n), z)


def _cell(column, text):
    if text == "":
        return None
    kind = _COLUMN_TYPES.get(column, "text")
    if kind == "int":
        return int(text)
    if kind == "bool":
        return text == "true"
    if kind == "float":
        return float(text)
    return text


def as_actions(raw, obs):
    """The policy's answer ``raw`` to the observation batch ``obs`` as the ``(n, 24)`` float64
    array the world runs, or :class:`osms.ActionError` naming the condition, the control step
    and what was expected. Values are checked (finite, in [-1, 1]) per rollout by the world."""
    n = obs["agent_pos"].shape[0]
    expected = f"({n}, {N_ACTION})" + (f" or ({N_ACTION},)" if n == 1 else "")

    def refuse(problem):
        where = f"condition {int(obs['condition'][0])} at control step {int(obs['step'][0])}"
        return ActionError(
            f"the policy's actions for {where} {problem}; expected real numbers in [-1, 1] "
            f"of shape {expected}: one row per observed rollout"
        )

    actions = real_array(raw, refuse, many=True)
    if actions.shape == (N_ACTION,) and n == 1:
        actions = actions[None, :]
    if actions.shape != (n, N_ACTION):
        raise refuse(f"have shape {actions.shape}")
    return np.ascontiguousarray(actions, dtype=np.float64)


def _indices(indices, proto):
    if indices is None:
        return list(range(proto.n_conditions))
    if isinstance(indices, (str, bytes)):
        raise ValueError(f"indices is {indices!r}; expected condition indices such as [0, 3, 7] or range(100)")
    # An empty list, out-of-range or repeated indices are the pool's to refuse (ValueError).
    try:
        return [operator.index(i) for i in indices]
    except TypeError as e:
        raise ValueError(f"indices must be integers (condition indices of `{proto.conditions}`): {e}") from None


def _n_envs(n_envs):
    # Only the type here: the pool refuses a count below 1 (ValueError).
    try:
        return operator.index(n_envs)
    except TypeError:
        raise ValueError(f"n_envs is {n_envs!r}; expected an integer of at least 1") from None


class Evaluation:
    """The rows of an evaluation (one per rollout, ``rollouts.csv``'s columns) and its rates.

    ``rows``: a list of dicts in the order the conditions were given; ``csv``: the same as
    ``osms export`` writes it; ``success`` and ``completion``: rates with ``*_ci`` Wilson 95 %
    intervals; ``policy`` (the policy's name), ``protocol`` (the evaluation stage whose
    rollout spec ran), ``conditions`` (the condition set), ``n``, ``wall_secs``.
    """

    def __init__(self, csv_text, protocol, policy, wall_secs, conditions=None):
        self.csv = csv_text
        reader = csv.DictReader(io.StringIO(csv_text))
        self.columns = list(reader.fieldnames or [])
        self.rows = [{k: _cell(k, v) for k, v in row.items()} for row in reader]
        self.protocol = protocol
        self.policy = policy
        self.conditions = conditions
        self.wall_secs = wall_secs
        self.n = len(self.rows)
        wins = sum(1 for r in self.rows if r["success"])
        caught = sum(1 for r in self.rows if r["completion"])
        self.success = wins / self.n if self.n else float("nan")
        self.completion = caught / self.n if self.n else float("nan")
        self.success_ci = wilson(wins, self.n)
        self.completion_ci = wilson(caught, self.n)

    def __repr__(self):
        def rate(value, ci):
            return f"{100 * value:.1f} % [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"

        where = f"protocol {self.protocol}" + (f" on {self.conditions}" if self.conditions else "")
        return (
            f"Evaluation(policy {self.policy}, {where}: success {rate(self.success, self.success_ci)}, "
            f"completion {rate(self.completion, self.completion_ci)}, n = {self.n})"
        )

    def eval_info(self):
        """LeRobot's ``eval_info.json`` layout (``overall``, ``per_group`` by object variant,
        ``per_task``). A rollout's reward is 1 for a success, else 0: the catch has no dense
        evaluation reward, so ``avg_sum_reward`` = ``avg_max_reward`` = the success rate."""
        groups = {}
        for r in self.rows:
            groups.setdefault(r["variant"], []).append(r)

        def summary(rows):
            wins = [1.0 if r["success"] else 0.0 for r in rows]
            mean = float(np.mean(wins)) if wins else float("nan")
            return {
                "avg_sum_reward": mean,
                "avg_max_reward": mean,
                "pc_success": 100.0 * mean,
                "n_episodes": len(rows),
                "video_paths": [],
            }

        overall = summary(self.rows)
        overall["eval_s"] = self.wall_secs
        overall["eval_ep_s"] = self.wall_secs / self.n if self.n else float("nan")
        lo, hi = self.success_ci
        overall["pc_success_ci95"] = [100.0 * lo, 100.0 * hi]
        return {
            "overall": overall,
            "per_group": {g: summary(rows) for g, rows in sorted(groups.items())},
            "per_task": [
                {
                    "task_group": g,
                    "task_id": i,
                    "metrics": {
                        "sum_rewards": [1.0 if r["success"] else 0.0 for r in rows],
                        "max_rewards": [1.0 if r["success"] else 0.0 for r in rows],
                        "successes": [bool(r["success"]) for r in rows],
                        "conditions": [r["condition"] for r in rows],
                        "video_paths": [],
                    },
                }
                for i, (g, rows) in enumerate(sorted(groups.items()))
            ],
            "osms": {"protocol": self.protocol, "policy": self.policy},
        }

    def write(self, out_dir):
        """Writes ``rollouts.csv`` and ``eval_info.json`` into ``out_dir``; their paths."""
        os.makedirs(out_dir, exist_ok=True)
        written = []
        for name, text in (
            ("rollouts.csv", self.csv),
            ("eval_info.json", json.dumps(self.eval_info(), indent=2) + "\n"),
        ):
            path = os.path.join(out_dir, name)
            tmp = os.path.join(out_dir, f".{name}.tmp")
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(tmp, path)
            written.append(path)
        return written


def evaluate(
    policy,
    conditions="dev",
    *,
    protocol=None,
    indices=None,
    n_envs=16,
    privileged=False,
    profile=None,
    pipeline=None,
    store=None,
    project=None,
    out=None,
):
    """Rolls ``policy`` out on a condition set under one of osms's evaluation protocols and
    returns an :class:`Evaluation` (its rows and rates).

    ``policy``
        A callable from a batch of observations to a batch of actions (see the module's
        doc), or a store policy from :func:`osms.policies.load`.
    ``conditions``
        The condition set (``"dev"``, ``"heldout"``), under osms's default protocol for it:
        the first evaluation stage on it that rolls out a teacher (``dev_teacher``,
        ``eval_teacher``). No policy needs to be built for it.
    ``protocol``
        An evaluation stage instead (``"eval_teacher"``, ``"eval_naive@1"``,
        ``"dev_student_il"``): its condition set, rollout spec and random streams.
    ``indices``
        The conditions to run (indices into the set), all of them if ``None``; rows come
        back in this order.
    ``n_envs``
        Rollouts stepped at once (at least 1).
    ``privileged``
        Also observe the privileged frame (``environment_state``).
    ``profile``, ``pipeline``, ``store``, ``project``
        Which osms project (default: the ``pipeline.toml`` of the working directory or a
        parent, its default profile, the store beside it).
    ``out``
        A directory to write ``rollouts.csv`` and LeRobot's ``eval_info.json`` into.

    Raises :class:`osms.ActionError` (naming the condition and control step) for an action
    that is not a real-valued array of the right shape, not finite, or outside [-1, 1];
    ``ValueError`` for bad arguments; :class:`osms.OsmsError` for a project, set, protocol
    or policy osms cannot use (the message lists the valid ones). Nothing is written then.
    The store is written only where a protocol's world or condition set is not built yet
    (built on first use, as ``osms make`` would); no other artifact is ever changed.
    """
    proj = _project(pipeline, store, profile, project)
    proto = _protocol(proj, conditions, protocol)
    chosen = _indices(indices, proto)
    envs = _n_envs(n_envs)
    native = policy if isinstance(policy, NativePolicy) else None
    name = native.name if native is not None else getattr(policy, "__name__", type(policy).__name__)
    started = time.perf_counter()
    pool = Pool(proto, chosen, envs, native, bool(privileged))
    while True:
        obs = pool.observe()
        if obs is None:
            break
        pool.act(as_actions(policy(obs), obs))
    wall = time.perf_counter() - started
    result = Evaluation(pool.rows_csv(), proto.name, name, wall, proto.conditions)
    if out is not None:
        result.write(out)
    return result
