"""Checks of the Python package osms against a project whose store holds the tiny profile's
default make, seed 0 current, and the stages of the identity check (tests/tests/pipeline.rs
builds them and writes the `rollouts.csv` of each protocol in PROTOCOLS as `osms export` does
into REFERENCE/<stage>.csv).

    python check_package.py PIPELINE REFERENCE

Every check is explicit (no `assert`, so `python -O` skips none) and exits non-zero with what
failed; on success prints one JSON object of what was measured.
"""

import copy
import hashlib
import json
import os
import pickle
import struct
import sys
import tempfile
import threading
import warnings

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import osms
import osms.gym
from osms import eval as oe
from osms._native import Pool

pipeline, reference = sys.argv[1], sys.argv[2]
store = os.path.join(os.path.dirname(pipeline), "store")
project = osms.Project(pipeline, None, "tiny")
out = {}

# (policy, protocol) pairs whose rows must equal osms export's: a teacher, a student without
# and with noise (and the noisy one under a chunk execution horizon of 3 and under the temporal
# ensemble), the scripted catcher with default and with other gains and inputs.
PROTOCOLS = [
    ("teacher", "eval_teacher"),
    ("student_il#0", "eval_student_il"),
    ("student_noisy", "eval_student_noisy"),
    ("student_noisy", "eval_student_h3"),
    ("student_noisy", "eval_student_ensemble"),
    ("scripted", "eval_scripted"),
    ("scripted", "eval_scripted_tuned"),
]


def check(condition, message):
    """Exits non-zero with `message` unless `condition` holds."""
    if not condition:
        print(f"check_package.py: check failed: {message}", file=sys.stderr)
        sys.exit(1)


def raises(kind, call, *fragments):
    """The message of the `kind` exception `call()` raises; exits non-zero if it raises none,
    another kind, or a message without each of `fragments`."""
    try:
        call()
    except kind as e:
        message = str(e)
        for fragment in fragments:
            check(fragment in message, f"{kind.__name__} without {fragment!r}: {message}")
        return message
    except Exception as e:  # noqa: BLE001  (any other kind is the finding)
        check(False, f"expected {kind.__name__}, got {type(e).__name__}: {e}")
    check(False, f"expected {kind.__name__} ({fragments}), nothing was raised")


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
for policy_name, protocol in PROTOCOLS:
    with open(os.path.join(reference, f"{protocol}.csv"), encoding="utf-8") as f:
        expected = f.read()
    policy = osms.policies.load(policy_name, project=project)
    for n_envs in (1, 3, 16):
        result = oe.evaluate(policy, protocol=protocol, n_envs=n_envs, project=project)
        check(
            result.csv == expected,
            f"{policy_name} on {protocol} with n_envs={n_envs}: rows differ from osms export's",
        )
        identity[f"{policy_name}@{protocol}/n_envs={n_envs}"] = result.n
out["identity"] = identity
before = store_digest()


# 2. A policy written in Python: the same rows whatever the batching, and the same as stepping
#    the gymnasium environment one rollout at a time.
def reach(obs):
    """A NumPy policy, row by row: hold the hand, move the arm a little toward the object."""
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
check(rows[1] == rows[2] == rows[16], "a Python policy's rows depend on n_envs")
env = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project)
lines = []
header = None
for i in indices:
    obs, info = env.reset(options={"index": i})
    check(info["condition"] == i, f"reset to condition {i} reports {info['condition']}")
    done = False
    steps = 0
    while not done:
        batch = {k: v[None, :] for k, v in obs.items()}
        obs, reward, done, truncated, info = env.step(reach(batch)[0])
        check(not truncated, "an episode was truncated")
        steps += 1
    check(steps == info["steps"], f"{steps} steps taken, info says {info['steps']}")
    text = env.unwrapped.row_csv().splitlines()
    header = text[0]
    lines.append(text[1])
check("\n".join([header] + lines) + "\n" == rows[1], "the environment's rows differ from evaluate's")
typed = oe.evaluate(reach, "heldout", protocol="eval_teacher", indices=[3], project=project).rows[0]
check(
    isinstance(typed["condition"], int) and isinstance(typed["success"], bool)
    and isinstance(typed["steps"], int) and isinstance(typed["dr_gain_scale"], float),
    f"rows.csv's columns parsed to the wrong types: {typed}",
)
out["python_policy"] = {"conditions": len(indices), "n_envs": [1, 2, 16]}

# 3. Conditions are keyed by index, never by how many resets came before: every observation of
#    a rollout, not only its first.
def trajectory(e, index, steps=12, **reset):
    obs, _ = e.reset(**reset) if reset else e.reset(options={"index": index})
    frames = [obs["agent_pos"].copy()]
    for _ in range(steps):
        obs, _, done, _, _ = e.step(reach({k: v[None, :] for k, v in obs.items()})[0])
        if done:
            break
        frames.append(obs["agent_pos"].copy())
    return np.stack(frames)


env2 = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project)
first = trajectory(env2, 7)
for i in (3, 1, 9):
    trajectory(env2, i, steps=3)
again = trajectory(env2, 7)
check(np.array_equal(first, again), "condition 7's rollout depends on earlier resets")
fresh_env = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", project=project)
check(
    np.array_equal(trajectory(env2, 0, seed=12), trajectory(fresh_env, 0, seed=12)),
    "reset(seed=12) depends on the environment's history",
)
# LeRobot (>= 0.5) marks a new rollout with a reset option; it is the same reset.
check(
    np.array_equal(
        trajectory(env2, 0, seed=12, options={"lerobot_new_rollout": True}), trajectory(fresh_env, 0, seed=12)
    ),
    "LeRobot's lerobot_new_rollout reset differs from a plain one",
)
out["reset_keyed"] = {"steps_compared": int(first.shape[0])}

# 4. gymnasium's own checker, render modes included, with and without the privileged frame.
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    for privileged in (False, True):
        checked = gymnasium.make("osms/Catch-v0", protocol="eval_teacher", privileged=privileged, project=project)
        check_env(checked.unwrapped)
        check_env(gymnasium.make("osms/Catch-v0", protocol="eval_teacher", privileged=privileged,
                                 render_mode="rgb_array", project=project).unwrapped)
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
check(frame.shape == (480, 480, 3) and frame.dtype == np.uint8, f"a frame of {frame.shape} {frame.dtype}")
check(frame.reshape(-1, 3).std(axis=0).min() > 1.0, "a rendered frame is flat")
out["render"] = list(frame.shape)
# The renderer is bound to its thread: another thread gets an error, not a crash.
from_thread = {}


def step_elsewhere():
    try:
        renv.step(np.zeros(osms.N_ACTION))
    except Exception as e:  # noqa: BLE001  (the kind is checked below)
        from_thread["error"] = e


worker = threading.Thread(target=step_elsewhere)
worker.start()
worker.join()
check(isinstance(from_thread.get("error"), osms.OsmsError), f"another thread's step(): {from_thread}")


# 6. Bad actions: a clear ActionError naming the condition and the step; nothing written.
def evaluate_bad(policy):
    return lambda: oe.evaluate(policy, protocol="eval_teacher", indices=[4, 6], n_envs=2, project=project)


def late_nan(obs):
    a = np.zeros((obs["agent_pos"].shape[0], 24))
    a[obs["condition"] == 6, 3] = np.where(obs["step"][obs["condition"] == 6] >= 2, np.nan, 0.0)
    return a


def width(obs):
    return obs["agent_pos"].shape[0]


bad = {
    "nan": (late_nan, "not finite"),
    "range": (lambda o: np.full((width(o), 24), 1.5), "outside [-1, 1]"),
    "shape": (lambda o: np.zeros((width(o), 7)), "shape (2, 7)"),
    "one_row_for_two": (lambda o: np.zeros(24), "shape (24,)"),
    "trailing_axis": (lambda o: np.zeros((width(o), 24, 1)), "shape (2, 24, 1)"),
    "nan_scalar": (lambda o: np.nan, "shape ()"),
    "none": (lambda o: None, "None"),
    "text": (lambda o: [["a"] * 24] * width(o), "not real numbers"),
    "complex": (lambda o: np.zeros((width(o), 24)) + 0.5j, "not real numbers"),
    "ragged": (lambda o: [[0.0] * 24, [0.0] * 23], "not"),
}
errors = {}
for key, (policy, fragment) in bad.items():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's ComplexWarning would be a silent half-accept
        errors[key] = raises(osms.ActionError, evaluate_bad(policy), "condition", "control step", fragment)
check("condition 6 at control step 2" in errors["nan"], errors["nan"])

# A refused action moves nothing: retried with good actions, the rows are those of a run that
# never saw the bad one (the pool and the environment alike).
proto = project.protocol("eval_teacher")
pool = Pool(proto, [4, 6], 2)
refusals = 0
while True:
    obs = pool.observe()
    if obs is None:
        break
    if obs["step"][0] in (0, 5):
        for wrong in (np.full((width(obs), 24), 2.0), np.zeros((width(obs), 23))):
            raises(osms.ActionError, lambda w=wrong: pool.act(oe.as_actions(w, obs)), "control step")
            refusals += 1
    pool.act(oe.as_actions(reach(obs), obs))
clean = oe.evaluate(reach, protocol="eval_teacher", indices=[4, 6], n_envs=2, project=project)
check(pool.rows_csv() == clean.csv, "a pool that refused actions parts from a clean run")
renv.reset(options={"index": 4})
raises(osms.ActionError, lambda: renv.step(np.full(24, np.inf)), "condition 4", "not finite")
raises(osms.ActionError, lambda: renv.step(None), "condition 4", "None")
obs, _ = renv.reset(options={"index": 4})
done = False
while not done:
    obs, _, done, _, _ = renv.step(reach({k: v[None, :] for k, v in obs.items()})[0])
single = oe.evaluate(reach, protocol="eval_teacher", indices=[4], project=project).csv
check(renv.unwrapped.row_csv() == single, "an environment that refused actions parts from a clean run")
out["refused_then_clean"] = refusals

# 7. Every other user error: a ValueError or an OsmsError with what would be valid.
sets = ", ".join(project.condition_sets())
errors["set"] = raises(osms.OsmsError, lambda: oe.evaluate(reach, "devv", project=project), "`devv`", sets)
check("eval_teacher" not in errors["set"], f"a misspelt set lists stages: {errors['set']}")
errors["protocol"] = raises(
    osms.OsmsError, lambda: oe.evaluate(reach, protocol="eval_teacherr", project=project), "eval_scripted"
)
check("d_e" not in errors["protocol"].split("valid here:")[-1], f"lists non-evaluations: {errors['protocol']}")
errors["not_evaluation"] = raises(
    osms.OsmsError, lambda: oe.evaluate(reach, protocol="teacher", project=project), "evaluation stage"
)
errors["not_built"] = raises(
    osms.OsmsError, lambda: osms.policies.load("student_naive@7", project=project), "osms make"
)
errors["policy"] = raises(osms.OsmsError, lambda: osms.policies.load("teacherr", project=project), "scripted")
errors["empty"] = raises(ValueError, lambda: oe.evaluate(reach, indices=[], project=project), "empty")
errors["n_envs"] = raises(ValueError, lambda: oe.evaluate(reach, indices=[0], n_envs=-1, project=project), "n_envs")
errors["n_envs_zero"] = raises(ValueError, lambda: Pool(proto, [0], 0), "n_envs")
errors["index"] = raises(ValueError, lambda: env2.reset(options={"index": 10**6}), "out of range")
errors["indices"] = raises(ValueError, lambda: oe.evaluate(reach, indices=[0, 10**6], project=project), "out of range")
errors["repeated"] = raises(ValueError, lambda: oe.evaluate(reach, indices=[1, 1], project=project), "listed twice")
check(
    osms.OsmsError.__module__ == "osms" and osms.OsmsError.__name__ == "OsmsError",
    f"OsmsError is named {osms.OsmsError.__module__}.{osms.OsmsError.__name__}",
)
check(osms.ActionError.__module__ == "osms", f"ActionError is named {osms.ActionError.__module__}.ActionError")
check(osms.CatchEnv is osms.gym.CatchEnv, f"osms.CatchEnv is {osms.CatchEnv}")
errors["option"] = raises(ValueError, lambda: env2.reset(options={"indx": 3}), "index")
# A store policy: on a pool that runs another policy's spec, on observations from elsewhere,
# twice on one batch, and from a second load that never saw the rollout's start.
teacher = osms.policies.load("teacher", project=project)
foreign = Pool(proto, [0, 1], 2)
errors["foreign_pool"] = raises(osms.OsmsError, lambda: teacher(foreign.observe()), "rollout spec of its own")
errors["bare_arrays"] = raises(osms.OsmsError, lambda: teacher({"agent_pos": np.zeros((1, 76))}), "osms_batch")
noisy_a = osms.policies.load("student_noisy", project=project)
noisy_b = osms.policies.load("student_noisy", project=project)
noisy_pool = Pool(project.protocol("eval_student_noisy"), [0, 1], 2, noisy_a)
obs = noisy_pool.observe()
noisy_pool.act(noisy_a(obs))
obs = noisy_pool.observe()
errors["second_load"] = raises(osms.OsmsError, lambda: noisy_b(obs), "first saw condition", "control step 1")
noisy_pool.act(noisy_a(obs))
obs = noisy_pool.observe()
answer = noisy_a(obs)
errors["twice"] = raises(osms.OsmsError, lambda: noisy_a(obs), "already acted")
noisy_pool.act(answer)
# A protocol whose chunk execution the student cannot run: a horizon past its chunks.
errors["horizon"] = raises(
    osms.OsmsError,
    lambda: oe.evaluate(noisy_a, protocol="eval_student_h9", indices=[0], project=project),
    "execution.horizon = 9",
    "chunk length",
)
check(
    all(name in ("scripted", "teacher") or "student" in name or "teacher" in name
        for name in errors["policy"].split("valid here: ")[-1].split(", ")),
    f"a misspelt policy lists other stages: {errors['policy']}",
)
out["errors"] = errors
def changed(then, now):
    return sorted(k for k in set(then) | set(now) if then.get(k) != now.get(k))


check(store_digest() == before, f"the store changed: {changed(before, store_digest())}")
check(
    store_digest(bookkeeping=False) == artifacts_before,
    f"the store's artifacts changed: {changed(artifacts_before, store_digest(bookkeeping=False))}",
)

# 8. LeRobot's eval_info.json and the rows written together; Wilson's interval is osms's own.
tmp = tempfile.mkdtemp(prefix="eval_out-", dir=os.path.dirname(pipeline))
result = oe.evaluate(osms.policies.load("teacher", project=project), protocol="eval_teacher", project=project, out=tmp)
with open(os.path.join(tmp, "eval_info.json"), encoding="utf-8") as f:
    info = json.load(f)
check(abs(info["overall"]["pc_success"] - 100 * result.success) < 1e-9, "eval_info's success differs")
check(info["overall"]["n_episodes"] == result.n, "eval_info's episode count differs")
with open(os.path.join(tmp, "rollouts.csv"), encoding="utf-8") as f:
    check(f.read() == result.csv, "the rollouts.csv written differs from the rows")
out["eval_info"] = {"pc_success": info["overall"]["pc_success"], "groups": len(info["per_group"])}
# As IEEE bit patterns: a JSON reader need not round a decimal to the nearest double.
out["wilson"] = {
    f"{x}/{n}": [struct.unpack("<Q", struct.pack("<d", v))[0] for v in oe.wilson(x, n)]
    for x, n in ((0, 40), (7, 40), (40, 40))
}
check(oe.wilson(0, 40)[0] == 0.0 and oe.wilson(40, 40)[1] == 1.0, f"Wilson's ends: {out['wilson']}")

# 9. The package's surface: a version, no shadowed builtins, typing marker and stubs; a project
#    survives gymnasium's deep copy of an environment's arguments and pickling to a worker.
check(copy.deepcopy(project) is project, "a deep copy of a project is another object")
reopened = pickle.loads(pickle.dumps(project))
check(
    (reopened.pipeline, reopened.store, reopened.profile) == (project.pipeline, project.store, project.profile),
    "a pickled project reopens elsewhere",
)
namespace = {}
exec("from osms import *", namespace)
check(namespace.get("eval", eval) is eval, "`from osms import *` replaces the builtin eval")
package_dir = os.path.dirname(osms.__file__)
check(os.path.isfile(os.path.join(package_dir, "py.typed")), "no py.typed")
check(os.path.isfile(os.path.join(package_dir, "_native.pyi")), "no stubs of osms._native")
check(bool(oe.evaluate.__doc__) and "ActionError" in oe.evaluate.__doc__, "evaluate has no useful docstring")
out["version"] = osms.__version__
# Where the package and the MuJoCo library it runs on were loaded from (an editable install
# reads the checkout's; the wheel carries its own).
out["package"] = os.path.realpath(osms.__file__)
with open("/proc/self/maps", encoding="utf-8") as f:
    loaded = {line.split()[-1] for line in f if "libmujoco" in line}
check(len(loaded) == 1, f"MuJoCo loaded from {sorted(loaded)}")
out["mujoco"] = os.path.realpath(loaded.pop())

# 10. A store from nothing: a directory that does not exist yet is created on opening, the world
#     and the condition set are built on first use, as `osms make dev` builds them (seconds), and
#     `heldout` evaluates without any teacher: its default protocol, `eval_teacher`, takes its
#     rollout spec from the teacher stage's params. The rows are those of the store that holds
#     the teacher.
empty = os.path.join(tempfile.mkdtemp(prefix="fresh-", dir=os.path.dirname(pipeline)), "store")
check(not os.path.exists(empty), f"{empty} exists before the project opens it")
fresh_project = osms.Project(pipeline, empty, "tiny")
check(os.path.isfile(os.path.join(empty, "OSMS_STORE")), f"opening did not create a store at {empty}")
fresh = gymnasium.make("osms/Catch-v0", project=fresh_project)
obs, info = fresh.reset(seed=0)
check(fresh.unwrapped.protocol.conditions == "dev", f"default protocol {fresh.unwrapped.protocol}")
check(obs["agent_pos"].shape == (osms.DEPLOYABLE_LEN,), f"observation {obs['agent_pos'].shape}")
check(any(files for _, _, files in os.walk(os.path.join(empty, "objects"))), "nothing was built")
heldout_fresh = oe.evaluate(reach, "heldout", indices=[0, 3], project=fresh_project)
check(heldout_fresh.protocol == "eval_teacher", f"heldout's protocol is {heldout_fresh.protocol}")
check(
    heldout_fresh.csv == oe.evaluate(reach, "heldout", indices=[0, 3], project=project).csv,
    "heldout's rows without a teacher differ from those with it",
)
out["dev_built_on_use"] = fresh.unwrapped.protocol.n_conditions

print(json.dumps(out))
