"""Checks of the Python package osms against a project whose store holds the tiny profile's
default make, seed 0 current (tests/tests/pipeline.rs builds it and writes the `rollouts.csv` of
`eval_teacher`, `eval_student_il` and `eval_scripted` as `osms export` does into
REFERENCE/<stage>.csv).

    python check_package.py PIPELINE REFERENCE

Prints one JSON object of what was compared; exits non-zero on the first check that fails.
"""

import hashlib
import io
import json
import os
import sys
import warnings

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import osms
import osms.gym
from osms import eval as oe

pipeline, reference = sys.argv[1], sys.argv[2]
store = os.path.join(os.path.dirname(pipeline), "store")
project = osms.Project(pipeline, None, "tiny")
out = {}


def store_digest(bookkeeping=True):
    """Every file of the store with its content hash: what a check must leave unchanged.
    Without ``bookkeeping``, the stat cache is left out: the first look at the store's status
    records which objects it verified, as ``osms status`` does."""
    digest = {}
    for root, _, files in os.walk(store):
        for name in files:
            path = os.path.join(root, name)
            rel = os.path.relpath(path, store)
            if not bookkeeping and rel == os.path.join("state", "statcache"):
                continue
            with open(path, "rb") as f:
                digest[rel] = hashlib.sha256(f.read()).hexdigest()
    return digest


artifacts_before = store_digest(bookkeeping=False)

# 1. The store's policies through Python give the rows of osms's own evaluations, bit for bit,
#    whatever the number of rollouts stepped at once.
identity = {}
for policy_name, protocol in [
    ("teacher", "eval_teacher"),
    ("student_il#0", "eval_student_il"),
    ("scripted", "eval_scripted"),
]:
    with open(os.path.join(reference, f"{protocol}.csv"), encoding="utf-8") as f:
        expected = f.read()
    policy = osms.policies.load(policy_name, project=project)
    for n_envs in (1, 3, 16):
        result = oe.evaluate(policy, protocol=protocol, n_envs=n_envs, project=project)
        assert result.csv == expected, (
            f"{policy_name} on {protocol} with n_envs={n_envs}: rows differ from osms export's"
        )
        identity[f"{policy_name}@{protocol}/n_envs={n_envs}"] = result.n
out["identity"] = identity
before = store_digest()


# 2. A policy written in Python: the same rows whatever the batching, and the same as stepping
#    the gymnasium environment one rollout at a time.
def reach(obs):
    """A NumPy policy: hold the hand, move the arm a little toward the observed object."""
    n = obs["agent_pos"].shape[0]
    actions = np.zeros((n, osms.N_ACTION), dtype=np.float32)
    obj = obs["agent_pos"][:, 48:51]
    actions[:, 0] = np.clip(3.0 * obj[:, 1], -1, 1)
    actions[:, 1] = np.clip(-2.0 * (obj[:, 2] - 1.0), -1, 1)
    return actions


indices = [0, 3, 5, 7, 11, 19]
rows = {
    n: oe.evaluate(reach, "heldout", protocol="eval_teacher", indices=indices, n_envs=n, project=project).csv
    for n in (1, 2, 16)
}
assert rows[1] == rows[2] == rows[16], "a Python policy's rows depend on n_envs"
env = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project)
lines = []
header = None
for i in indices:
    obs, info = env.reset(options={"index": i})
    assert info["condition"] == i
    done = False
    steps = 0
    while not done:
        batch = {k: v[None, :] for k, v in obs.items()}
        action = reach(batch)[0]
        obs, reward, done, truncated, info = env.step(action)
        assert not truncated
        steps += 1
    assert steps == info["steps"], (steps, info)
    text = env.unwrapped.row_csv().splitlines()
    header = text[0]
    lines.append(text[1])
assert "\n".join([header] + lines) + "\n" == rows[1], "the environment's rows differ from evaluate's"
out["python_policy"] = {"conditions": len(indices), "n_envs": [1, 2, 16], "env_rows_match": True}

# 3. Conditions are keyed by index, never by how many resets came before.
env2 = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project)
first, _ = env2.reset(options={"index": 7})
for i in (3, 1, 9):
    env2.reset(options={"index": i})
again, _ = env2.reset(options={"index": 7})
assert np.array_equal(first["agent_pos"], again["agent_pos"]), "reset(index=7) depends on earlier resets"
seeded_a, _ = env2.reset(seed=12)
seeded_b, _ = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project).reset(seed=12)
assert np.array_equal(seeded_a["agent_pos"], seeded_b["agent_pos"])
out["reset_keyed"] = True

# 4. gymnasium's own checker, with and without the privileged frame.
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    for privileged in (False, True):
        check_env(osms.gym.CatchEnv(protocol="eval_teacher", privileged=privileged, project=project), skip_render_check=True)
# The frames are physical quantities without finite bounds (as in gymnasium's own MuJoCo
# environments), which the checker notes; any other warning is a finding.
unbounded = ("maximum value is infinity", "minimum value is -infinity")
out["check_env_warnings"] = sorted(
    {str(w.message)[:160] for w in caught if not any(u in str(w.message) for u in unbounded)}
)

# 5. Rendering through MuJoCo's offscreen renderer.
renv = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", render_mode="rgb_array", project=project)
renv.reset(options={"index": 0})
frame = renv.render()
assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8, (frame.shape, frame.dtype)
assert frame.reshape(-1, 3).std(axis=0).min() > 1.0, "a rendered frame is flat"
out["render"] = list(frame.shape)


# 6. Bad actions: a clear error naming the condition and the step; nothing written.
def expect_action_error(policy, fragment):
    try:
        oe.evaluate(policy, protocol="eval_teacher", indices=[4, 6], n_envs=2, project=project)
    except osms.ActionError as e:
        message = str(e)
        assert "condition" in message and "control step" in message and fragment in message, message
        return message
    raise AssertionError(f"no ActionError for {fragment!r}")


def late_nan(obs):
    a = np.zeros((obs["agent_pos"].shape[0], 24))
    a[obs["condition"] == 6, 3] = np.where(obs["step"][obs["condition"] == 6] >= 2, np.nan, 0.0)
    return a


errors = {
    "nan": expect_action_error(late_nan, "not finite"),
    "range": expect_action_error(lambda o: np.full((o["agent_pos"].shape[0], 24), 1.5), "outside [-1, 1]"),
    "shape": expect_action_error(lambda o: np.zeros((o["agent_pos"].shape[0], 7)), "shape"),
    "text": expect_action_error(lambda o: [["a"] * 24] * o["agent_pos"].shape[0], "not numbers"),
}
assert "condition 6 at control step 2" in errors["nan"], errors["nan"]
try:
    oe.evaluate(reach, protocol="teacher", project=project)
    raise AssertionError("a protocol that is no evaluation stage was accepted")
except osms.OsmsError as e:
    errors["protocol"] = str(e)
    assert "evaluation stage" in str(e), str(e)
try:
    osms.policies.load("student_naive@7", project=project)
    raise AssertionError("a policy that was never built was loaded")
except osms.OsmsError as e:
    errors["not_built"] = str(e)
    assert "osms make" in str(e), str(e)
# A store policy on a pool that runs another policy's spec, or on observations from elsewhere.
from osms._native import Pool

proto = project.protocol("eval_teacher")
pool = Pool(proto, [0, 1], 2)
obs = pool.observe()
teacher = osms.policies.load("teacher", project=project)
try:
    teacher(obs)
    raise AssertionError("the teacher acted on a pool run under another spec")
except osms.OsmsError as e:
    errors["foreign_pool"] = str(e)
    assert "rollout spec of its own" in str(e), str(e)
try:
    teacher({"agent_pos": obs["agent_pos"]})
    raise AssertionError("the teacher acted on bare arrays")
except osms.OsmsError as e:
    errors["bare_arrays"] = str(e)
    assert "osms_batch" in str(e), str(e)
out["errors"] = errors
assert store_digest() == before, "the store changed"
assert store_digest(bookkeeping=False) == artifacts_before, "the store's artifacts changed"
out["store_unchanged"] = True

# 7. LeRobot's eval_info.json and the rows written together.
tmp = os.path.join(os.path.dirname(pipeline), "eval_out")
result = oe.evaluate(osms.policies.load("teacher", project=project), protocol="eval_teacher", project=project, out=tmp)
with open(os.path.join(tmp, "eval_info.json"), encoding="utf-8") as f:
    info = json.load(f)
assert abs(info["overall"]["pc_success"] - 100 * result.success) < 1e-9
assert info["overall"]["n_episodes"] == result.n
with open(os.path.join(tmp, "rollouts.csv"), encoding="utf-8") as f:
    assert f.read() == result.csv
out["eval_info"] = {"pc_success": info["overall"]["pc_success"], "groups": len(info["per_group"])}

# 8. In an empty store, the world and the condition set are built on first use, as `osms make dev`
#    builds them (seconds): a fresh clone's `gymnasium.make("osms/Catch-v0")` needs nothing else.
empty = os.path.join(os.path.dirname(pipeline), "empty-store")
os.makedirs(empty)
fresh = gymnasium.make("osms/Catch-v0", project=osms.Project(pipeline, empty, "tiny"))
obs, info = fresh.reset(seed=0)
assert fresh.unwrapped.protocol.conditions == "dev", fresh.unwrapped.protocol
assert obs["agent_pos"].shape == (76,)
assert any(files for _, _, files in os.walk(os.path.join(empty, "objects"))), "nothing was built"
out["dev_built_on_use"] = fresh.unwrapped.protocol.n_conditions

print(json.dumps(out))
