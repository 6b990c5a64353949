"""Evaluate any policy on osms's condition sets, with osms's own protocol and metrics.

:func:`evaluate` steps many rollouts in Rust (the GIL released while MuJoCo runs) and calls the
policy once per control step with the batch of running rollouts' observations. Rollout ``i`` is
the protocol's rollout on condition ``i``: its domain randomisation comes from the protocol
stage's stream for that condition, so the rows do not depend on ``n_envs``, on batching or on
the order rollouts finish, and the store's own policies reproduce ``osms export``'s rows bit
for bit.

A policy is any callable ``policy(obs) -> actions``:

``obs`` (a dict)
    ``agent_pos``: ``(n, 76)`` float32, the deployable frame a student sees (channel names:
    ``osms.channels()["agent_pos"]``); ``environment_state``: ``(n, 85)`` float32, the
    privileged frame, only with ``privileged=True``; ``condition`` and ``step``: ``(n,)``
    int64, which condition each row is and its control step (0 starts a rollout: reset any
    per-rollout memory there); ``osms_batch``: what the store's policies read.
``actions``
    ``(n, 24)`` in [-1, 1], any float dtype (float32 is converted exactly), in the world's
    channel order (``osms.channels()["action"]``), one row per observation row.
"""

import csv
import io
import json
import math
import os
import time

import numpy as np

from osms._native import ActionError, NativePolicy, Pool
from osms._project import project as _project
from osms._project import protocol as _protocol

# The columns of rollouts.csv that are integers and booleans (the rest are floats or text).
_INT_COLUMNS = {
    "condition",
    "variant_index",
    "dr_observation_delay_steps",
    "dr_actuation_delay_steps",
    "event_step",
    "steps",
}


def wilson(successes, n, z=1.959963984540054):
    """The Wilson score interval of a proportion (95 % by default), as (low, high)."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = successes / n
    denominator = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    return (max(0.0, centre - half), min(1.0, centre + half))


def _cell(column, text):
    if text == "":
        return None
    if column in _INT_COLUMNS:
        return int(text)
    if text in ("true", "false"):
        return text == "true"
    try:
        return float(text)
    except ValueError:
        return text


class Evaluation:
    """The rows of an evaluation (one per rollout, ``rollouts.csv``'s columns) and its rates.

    ``rows``: a list of dicts in the order the conditions were given; ``csv``: the same as
    ``osms export`` writes it; ``success`` and ``completion``: rates with ``*_ci`` Wilson 95 %
    intervals; ``protocol``, ``policy``, ``n``, ``wall_secs``.
    """

    def __init__(self, csv_text, protocol, policy, wall_secs):
        self.csv = csv_text
        reader = csv.DictReader(io.StringIO(csv_text))
        self.columns = list(reader.fieldnames or [])
        self.rows = [{k: _cell(k, v) for k, v in row.items()} for row in reader]
        self.protocol = protocol
        self.policy = policy
        self.wall_secs = wall_secs
        self.n = len(self.rows)
        wins = sum(1 for r in self.rows if r["success"])
        caught = sum(1 for r in self.rows if r["completion"])
        self.success = wins / self.n if self.n else float("nan")
        self.completion = caught / self.n if self.n else float("nan")
        self.success_ci = wilson(wins, self.n)
        self.completion_ci = wilson(caught, self.n)

    def __repr__(self):
        lo, hi = self.success_ci
        return (
            f"Evaluation({self.policy} on {self.protocol}: success {100 * self.success:.1f} % "
            f"[{100 * lo:.1f}, {100 * hi:.1f}], n = {self.n})"
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
    """Rolls ``policy`` out on the condition set ``conditions`` (``dev``, ``heldout``) under
    osms's default protocol for it, or under the evaluation stage ``protocol``
    (``eval_teacher``, ``eval_naive@1``, ``dev_student_il``); all conditions, or those in
    ``indices``. ``n_envs`` rollouts run at once. Returns an :class:`Evaluation`; with
    ``out``, also writes its ``rollouts.csv`` and ``eval_info.json`` there.

    Raises :class:`osms.ActionError` (naming the condition and control step) for an action of
    the wrong shape, not finite or outside [-1, 1]; nothing is written then, and the store is
    only ever read.
    """
    proj = _project(pipeline, store, profile, project)
    proto = _protocol(proj, conditions, protocol)
    if indices is None:
        indices = range(proto.n_conditions)
    indices = [int(i) for i in indices]
    native = policy if isinstance(policy, NativePolicy) else None
    name = native.name if native is not None else getattr(policy, "__name__", type(policy).__name__)
    started = time.perf_counter()
    pool = Pool(proto, indices, int(n_envs), native, bool(privileged))
    while True:
        obs = pool.observe()
        if obs is None:
            break
        n = obs["agent_pos"].shape[0]
        raw = policy(obs)
        try:
            actions = np.asarray(raw, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ActionError(
                f"the policy's actions for condition {obs['condition'][0]} at control step "
                f"{obs['step'][0]} are not numbers: {e}"
            ) from None
        if actions.ndim == 1 and n == 1 and actions.shape[0] == 24:
            actions = actions[None, :]
        pool.act(np.ascontiguousarray(actions))
    wall = time.perf_counter() - started
    result = Evaluation(pool.rows_csv(), proto.name, name, wall)
    if out is not None:
        result.write(out)
    return result
