"""Checks of the Python package osms against a project whose store holds the tiny profile's
default make, seed 0 current, and the stages of the identity check (tests/tests/pipeline.rs
builds them and writes the `rollouts.csv` of each protocol in PROTOCOLS as `osms export` does
into REFERENCE/<stage>.csv).

    python check_package.py PIPELINE REFERENCE [--vector]

``--vector`` adds section 11, the native vector environment (run once, not per install: it
steps the same Rust code whichever install loads it).

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
with_vector = sys.argv[3:] == ["--vector"]
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

def check_vector():
    # 11. The native vector environment: each episode is its protocol's rollout, bit for bit the
    #     rows of `osms export` (store policies) and of `evaluate` (a NumPy policy), at 1, 3 and 16
    #     sub-environments and in each of gymnasium's autoreset modes; conditions handed out once
    #     each, in order; the calls LeRobot's evaluation makes, answered.
    def first_rows(env, n):
        """The rows of the first ``n`` episodes once all of them have ended, else None."""
        text = env.rows_csv()
        if text is None:
            return None
        lines = text.splitlines()
        col = lines[0].split(",").index("condition")
        if [int(line.split(",")[col]) for line in lines[1 : n + 1]] != list(range(n)):
            return None
        return "\n".join(lines[: n + 1]) + "\n"


    def run_vector(env, act, n):
        """Steps ``env`` with ``act(env, obs)`` until the set's first ``n`` episodes have ended;
        their rows and the conditions each reset and autoreset started, in order."""
        obs, info = env.reset()
        starts = list(info["condition"])
        mode = env.metadata["autoreset_mode"]
        pending = np.zeros(env.num_envs, dtype=bool)
        while (rows := first_rows(env, n)) is None:
            obs, _, term, trunc, info = env.step(act(env, obs))
            check(not trunc.any(), "a vector episode was truncated")
            if mode == gymnasium.vector.AutoresetMode.NEXT_STEP:
                starts += [int(c) for c, p in zip(info["condition"], pending) if p]
                pending = term
            elif mode == gymnasium.vector.AutoresetMode.SAME_STEP:
                starts += [int(c) for c, t in zip(info["condition"], term) if t]
                if term.any():
                    check(
                        bool(np.array_equal(info["_final_info"], term)) and bool(np.array_equal(info["final_info"]["_is_success"], term)),
                        "SAME_STEP's final_info masks differ from the terminations",
                    )
            elif term.any():
                obs, info = env.reset(options={"reset_mask": term})
                starts += [int(c) for c, m in zip(info["condition"], info["_condition"]) if m]
        return rows, starts


    vector = {}
    for policy_name, protocol in [PROTOCOLS[0], PROTOCOLS[3], PROTOCOLS[5]]:
        with open(os.path.join(reference, f"{protocol}.csv"), encoding="utf-8") as f:
            expected = f.read()
        policy = osms.policies.load(policy_name, project=project)
        n_conditions = project.protocol(protocol).n_conditions
        for n_envs in (1, 3, 16):
            venv = osms.CatchVectorEnv(n_envs, protocol=protocol, native=policy, project=project)
            rows, starts = run_vector(venv, lambda e, _obs: e.native_actions(policy), n_conditions)
            check(rows == expected, f"{policy_name} on {protocol} in {n_envs} sub-environments: rows differ from osms export's")
            check(
                starts[:n_conditions] == list(range(n_conditions)),
                f"{n_envs} sub-environments started conditions {starts[:n_conditions]}, not each once in order",
            )
            vector[f"{policy_name}@{protocol}/num_envs={n_envs}"] = n_conditions
    heldout_rows = oe.evaluate(reach, "heldout", n_envs=4, project=project).csv
    n_heldout = project.protocol(project.default_protocol("heldout")).n_conditions
    for mode in gymnasium.vector.AutoresetMode:
        for n_envs in (1, 3, 16):
            venv = gymnasium.make_vec(
                "osms/Catch-v0", num_envs=n_envs, vectorization_mode="vector_entry_point",
                conditions="heldout", autoreset_mode=mode, project=project,
            )
            check(isinstance(venv, osms.CatchVectorEnv), f"make_vec's vector entry point made {type(venv)}")
            rows, starts = run_vector(venv, lambda _e, obs: reach(obs), n_heldout)
            check(rows == heldout_rows, f"reach in {n_envs} sub-environments under {mode}: rows differ from evaluate's")
            check(starts[:n_heldout] == list(range(n_heldout)), f"{mode}, {n_envs} sub-environments: conditions {starts}")
            vector[f"reach@{mode.value}/num_envs={n_envs}"] = n_heldout
    out["vector"] = vector


    def lerobot_rollout(env, seeds):
        """The calls LeRobot's ``rollout()`` makes on a vector environment (lerobot/scripts/
        lerobot_eval.py, 0.5 and later), with ``reach`` for its policy: each sub-environment's
        success as LeRobot reads it, and the frames its video callback draws."""
        observation, _ = env.reset(seed=seeds, options={"lerobot_new_rollout": True})
        frames = [np.stack(env.call("render")[:1])]
        check(isinstance(env.unwrapped.metadata.get("render_fps"), int), "no render_fps")
        env.get_attr("task_description")
        env.get_attr("task")
        # LeRobot 0.4 reads the task from env.envs[0] (gymnasium 1.x's wrappers around a
        # SyncVectorEnv's environments do not forward it: LeRobot's own limitation).
        check(
            isinstance(env, gymnasium.vector.SyncVectorEnv) or hasattr(env.envs[0], "task_description"),
            "LeRobot 0.4 reads env.envs[0].task_description",
        )
        check(all(isinstance(t, str) and t for t in env.call("task_description")), "no task descriptions")
        max_steps = env.call("_max_episode_steps")[0]
        done = np.zeros(env.num_envs, dtype=bool)
        successes = [False] * env.num_envs
        step = 0
        while not np.all(done) and step < max_steps:
            action = reach(observation)
            observation, _, terminated, truncated, info = env.step(action)
            frames.append(np.stack(env.call("render")[:1]))
            if "final_info" in info:
                is_success = info["final_info"].get("is_success", [False] * env.num_envs)
                successes = is_success.tolist() if hasattr(is_success, "tolist") else [bool(is_success)] * env.num_envs
            elif "is_success" in info:
                is_success = info["is_success"]
                successes = is_success.tolist() if hasattr(is_success, "tolist") else [bool(is_success)] * env.num_envs
            else:
                successes = [False] * env.num_envs
            # LeRobot keeps each sub-environment's success from its first done step.
            for k in range(env.num_envs):
                if not done[k]:
                    lerobot_rollout.first[k] = successes[k]
            done = terminated | truncated | done
            step += 1
        check(bool(np.all(done)), f"episodes still running after the registered limit of {max_steps} steps")
        return [bool(s) for s in lerobot_rollout.first], len(frames)


    heldout_success = [row["success"] for row in oe.evaluate(reach, "heldout", indices=[4, 5, 6], project=project).rows]
    lerobot = {}
    for label, make in [
        ("native", lambda: gymnasium.make_vec(
            "osms/Catch-v0", num_envs=3, vectorization_mode="vector_entry_point", conditions="heldout",
            autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP, render_mode="rgb_array", project=project)),
        ("sync", lambda: gymnasium.vector.SyncVectorEnv(
            [lambda: gymnasium.make("osms/Catch-v0", conditions="heldout", render_mode="rgb_array", project=project)] * 3,
            autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)),
    ]:
        venv = make()
        lerobot_rollout.first = [False] * 3
        got, n_frames = lerobot_rollout(venv, [4, 5, 6])
        check(got == heldout_success, f"LeRobot's reading of {label}'s successes {got} differs from evaluate's {heldout_success}")
        check(venv.call("_max_episode_steps")[0] == osms.DEFAULT_MAX_STEPS, f"{label}: _max_episode_steps")
        lerobot[label] = n_frames
    out["lerobot_calls"] = lerobot

    venv = osms.CatchVectorEnv(3, "heldout", project=project, autoreset_mode="Disabled")
    obs, _ = venv.reset(seed=2)
    vector_errors = {
        "shape": raises(osms.ActionError, lambda: venv.step(np.zeros((2, osms.N_ACTION))), "(3, 24)"),
        "nan": raises(osms.ActionError, lambda: venv.step(np.full((3, osms.N_ACTION), np.nan)), "condition 2", "channel 0"),
        "seeds": raises(ValueError, lambda: venv.reset(seed=[1, 2]), "one per sub-environment"),
        "mask": raises(ValueError, lambda: venv.reset(options={"reset_mask": np.zeros(3, dtype=bool)}), "no sub-environment"),
        "option": raises(ValueError, lambda: venv.reset(options={"index": 3}), "reset_mask"),
        "native": raises(osms.OsmsError, lambda: venv.native_actions(teacher), "rollout spec of its own"),
        "num_envs": raises(ValueError, lambda: osms.CatchVectorEnv(0, project=project), "num_envs"),
        "mode": raises(ValueError, lambda: osms.CatchVectorEnv(2, project=project, autoreset_mode="Sometimes"), "Sometimes"),
        "attr": raises(AttributeError, lambda: venv.get_attr("velocity"), "task_description"),
    }
    while True:
        obs, _, term, _, _ = venv.step(reach(obs))
        if term.any():
            break
    vector_errors["disabled"] = raises(osms.OsmsError, lambda: venv.step(reach(obs)), "reset_mask", "autoreset is disabled")
    other = []
    worker = threading.Thread(target=lambda: other.append(raises(osms.OsmsError, lambda: venv.step(reach(obs)), "thread")))
    worker.start()
    worker.join()
    check(len(other) == 1, "a vector environment stepped from another thread raised no OsmsError")
    out["vector_errors"] = vector_errors
    check(osms.CatchVectorEnv is osms.gym.CatchVectorEnv, f"osms.CatchVectorEnv is {osms.CatchVectorEnv}")



if with_vector:
    check_vector()

print(json.dumps(out))
