#!/usr/bin/env python3
"""Replays episodes of an osms robomimic export with MuJoCo's own Python bindings.

An independent reader of osms's files: it takes the MJCF from `osms world dump` (and checks it
equals the copy in the file's env_args), applies the episode's model edits, sets the first
recorded state and drives the servos with the recorded targets for the recorded number of
physics steps, exactly as docs/export.md ("Replay outside osms") describes. It prints one JSON
object: per episode the largest deviation of the replayed full physical state from the
recorded `states`, and f_max and t_c recomputed from the replay's contacts next to the
recorded f_max.

Usage: replay-robomimic.py FILE [--demo demo_0 ...] [--osms ./osms] [--profile P]
       [--eval-window 0.2] [--mjcf-from-file]
Needs numpy, h5py and mujoco==3.17.0 (scripts/setup-python installs them).
"""

import argparse
import json
import shlex
import subprocess
import sys

import h5py
import mujoco
import numpy as np

ARM_JOINTS = [f"arm_j{i}" for i in range(1, 8)]
BIT_HAND = 4
BIT_OBJECT = 8


def fail(message):
    print(f"error: {message}", file=sys.stderr)
    sys.exit(1)


def world_dump(osms, variant, profile):
    cmd = shlex.split(osms) + ["world", "dump", "--object", variant]
    if profile:
        cmd += ["--profile", profile]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        fail(f"`{' '.join(cmd)}` failed: {done.stderr.strip()}")
    return done.stdout


def servo_joints(model):
    """qpos addresses of the servoed joints in actuator order (arm, then hand)."""
    addrs = []
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            fail(f"actuator {a} does not drive a joint")
        addrs.append(model.jnt_qposadr[model.actuator_trnid[a, 0]])
    return np.array(addrs)


def replay(xml, demo, eval_window):
    model = mujoco.MjModel.from_xml_string(xml)
    attrs = demo.attrs
    body = model.body("object").id
    geom = model.geom("object_geom").id
    mass = float(attrs["mass_kg"])
    ratio = mass / model.body_mass[body]
    model.body_mass[body] = mass
    model.body_inertia[body] *= ratio
    model.geom_friction[geom, 0] *= float(attrs["friction_scale"])
    model.geom_solref[geom, 0] *= float(attrs["contact_timeconst_scale"])
    gain = float(attrs["gain_scale"])

    data = mujoco.MjData(model)
    # Uses `data` as scratch, as osms does, before the state is set.
    mujoco.mj_setConst(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    states = demo["states"][()]
    targets = demo["osms/servo_targets"][()]
    physics_steps = demo["osms/physics_steps"][()]
    if states.shape[1] != mujoco.mj_stateSize(model, spec):
        fail(f"states have {states.shape[1]} columns, MuJoCo's full physics state {mujoco.mj_stateSize(model, spec)}")
    mujoco.mj_setState(model, data, states[0], spec)
    qadr = servo_joints(model)
    if len(qadr) != targets.shape[1]:
        fail(f"{targets.shape[1]} servo targets per step for {len(qadr)} actuators")
    contype = model.geom_contype

    state = np.empty(states.shape[1])
    max_dev = 0.0
    differing = 0
    first_dev_step = None
    t_c = None
    f_max = 0.0
    for k in range(states.shape[0]):
        mujoco.mj_forward(model, data)
        mujoco.mj_getState(model, data, state, spec)
        diff = np.abs(state - states[k])
        if np.any(state != states[k]):
            differing += 1
            if first_dev_step is None:
                first_dev_step = k
        max_dev = max(max_dev, float(np.max(diff)))
        for _ in range(int(physics_steps[k])):
            q = data.qpos[qadr]
            data.ctrl[:] = q + gain * (targets[k] - q)
            time = data.time
            mujoco.mj_step(model, data)
            # After mj_step the contacts describe the state before the integration, as the
            # osms evaluator reads them.
            force = 0.0
            touched = False
            for i in range(data.ncon):
                c = data.contact[i]
                a, b = contype[c.geom[0]], contype[c.geom[1]]
                if {a, b} == {BIT_HAND, BIT_OBJECT}:
                    touched = True
                    f = np.zeros(6)
                    mujoco.mj_contactForce(model, data, i, f)
                    force += f[0]
            if t_c is None and touched:
                t_c = time
                f_max = force
            elif t_c is not None and time - t_c <= eval_window:
                f_max = max(f_max, force)
    return {
        "steps": int(states.shape[0]),
        "max_abs_state_deviation": max_dev,
        "steps_with_differing_state": differing,
        "first_differing_step": first_dev_step,
        "bit_exact": differing == 0,
        "f_max_recorded": float(attrs["max_force_n"]),
        "f_max_replayed": f_max,
        "t_c_replayed": t_c,
        "success_recorded": bool(attrs["success"]),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("file")
    p.add_argument("--demo", action="append", help="demo name (default: every demo)")
    p.add_argument("--osms", default="osms", help="the osms command line for `osms world dump` (e.g. \"./osms --pipeline p.toml\")")
    p.add_argument("--profile", help="profile for `osms world dump` (default: the file's)")
    p.add_argument("--eval-window", type=float, default=0.2, help="Δt_eval (s) for f_max")
    p.add_argument("--mjcf-from-file", action="store_true",
                   help="take the MJCF from env_args instead of `osms world dump`")
    args = p.parse_args()
    if mujoco.__version__ != "3.17.0":
        fail(f"mujoco {mujoco.__version__} is loaded; osms records come from 3.17.0")
    with h5py.File(args.file, "r") as f:
        env = json.loads(f["data"].attrs["env_args"])
        kwargs = env["env_kwargs"]
        profile = args.profile or kwargs.get("profile")
        names = args.demo or sorted(f["data"].keys(), key=lambda n: int(n.split("_")[1]))
        xml_cache = {}
        out = {"file": args.file, "stage": kwargs.get("stage"), "mujoco": mujoco.__version__,
               "mjcf_source": "env_args" if args.mjcf_from_file else "osms world dump",
               "demos": {}}
        for name in names:
            if name not in f["data"]:
                fail(f"{args.file} has no data/{name}")
            demo = f["data"][name]
            if "states" not in demo:
                fail(f"data/{name} has no states: only rollout datasets can be replayed")
            variant = demo.attrs["variant"]
            variant = variant.decode() if isinstance(variant, bytes) else str(variant)
            if variant not in xml_cache:
                stored = kwargs["mjcf"].get(variant)
                if args.mjcf_from_file:
                    xml = stored
                else:
                    xml = world_dump(args.osms, variant, profile)
                    if stored is not None and stored != xml:
                        fail(f"`osms world dump --object {variant}` differs from the MJCF in the file's env_args")
                xml_cache[variant] = xml
            out["demos"][name] = replay(xml_cache[variant], demo, args.eval_window)
        out["bit_exact"] = all(d["bit_exact"] for d in out["demos"].values())
        out["max_abs_state_deviation"] = max(
            (d["max_abs_state_deviation"] for d in out["demos"].values()), default=0.0)
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
