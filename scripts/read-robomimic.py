#!/usr/bin/env python3
"""Reads an osms robomimic HDF5 export with h5py and prints ONE JSON summary on stdout.

Usage: read-robomimic.py FILE.hdf5

An independent check of osms's HDF5 writer (crates/osms-export/src/robomimic.rs): it reads
the file the way robomimic does (data/demo_<i>, num_samples, env_args, mask/<key> as byte
strings) and prints

  {"total": T, "env_args": {...}, "demos": [{"name", "num_samples", "actions_shape",
   "states_shape" (or null), "obs_keys" (sorted), "next_obs_keys" (sorted), "osms_keys"
   (sorted), "task_index", "first_action" (24 floats, null for an
   empty demo), "last_reward", "last_done", "success", "variant",
   "first_state_first3" (or null)}, ...], "mask": {"train": [...], "valid": [...]}}

with demos in index order (demo_0, demo_1, ..., demo_10). Exits 1 with a message on stderr
when the layout is broken: missing groups, datasets or attributes, shapes that disagree with
num_samples, num_samples not adding up to total, masks naming unknown demos, a next_obs
that is not obs one step on (the last step repeating the last observation).
Needs python3 with h5py and numpy (scripts/setup-python).
"""

import json
import sys

import h5py
import numpy as np

ACTION_DIM = 24
OBS_KEYS = ["arm_qpos", "arm_qvel", "hand_qpos", "hand_qvel", "object_pos", "prev_action"]


class Broken(Exception):
    pass


def need(group, name, kind):
    """Returns group[name], which must be a `kind` (h5py.Group or h5py.Dataset)."""
    if name not in group:
        raise Broken(f"{group.name}: missing {name}")
    obj = group[name]
    if not isinstance(obj, kind):
        raise Broken(f"{obj.name}: expected a {kind.__name__.lower()}")
    return obj


def attr(obj, name):
    if name not in obj.attrs:
        raise Broken(f"{obj.name}: missing attribute {name}")
    return obj.attrs[name]


def text(value, where):
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, str):
        return value
    raise Broken(f"{where}: expected a string, found {type(value).__name__}")


def integer(value, where):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise Broken(f"{where}: expected an integer, found {type(value).__name__}")
    return int(value)


def shape_is(ds, shape):
    if tuple(ds.shape) != tuple(shape):
        raise Broken(f"{ds.name}: shape {list(ds.shape)}, expected {list(shape)}")


def demo_index(name):
    if not name.startswith("demo_") or not name[5:].isdigit():
        raise Broken(f"/data/{name}: not a demo_<i> group")
    return int(name[5:])


def read_demo(data, name):
    g = need(data, name, h5py.Group)
    n = integer(attr(g, "num_samples"), f"{g.name}/num_samples")
    if n < 0:
        raise Broken(f"{g.name}: num_samples {n} is negative")

    actions = need(g, "actions", h5py.Dataset)
    shape_is(actions, (n, ACTION_DIM))
    rewards = need(g, "rewards", h5py.Dataset)
    shape_is(rewards, (n,))
    dones = need(g, "dones", h5py.Dataset)
    shape_is(dones, (n,))

    states_shape, first3 = None, None
    if "states" in g:
        states = need(g, "states", h5py.Dataset)
        if states.ndim != 2 or states.shape[0] != n:
            raise Broken(f"{states.name}: shape {list(states.shape)}, expected [{n}, state_size]")
        if "state_size" in g.attrs:
            size = integer(g.attrs["state_size"], f"{g.name}/state_size")
            shape_is(states, (n, size))
        states_shape = list(states.shape)
        if n > 0:
            first3 = [float(x) for x in states[0, :3]]

    obs = need(g, "obs", h5py.Group)
    for key in OBS_KEYS:
        need(obs, key, h5py.Dataset)
    for key in obs:
        ds = need(obs, key, h5py.Dataset)
        if ds.ndim < 1 or ds.shape[0] != n:
            raise Broken(f"{ds.name}: shape {list(ds.shape)}, expected [{n}, ...]")

    # robomimic's load_next_obs=True reads next_obs/<key> for every obs key.
    next_obs = need(g, "next_obs", h5py.Group)
    if sorted(next_obs.keys()) != sorted(obs.keys()):
        raise Broken(f"{next_obs.name}: keys {sorted(next_obs.keys())}, obs has {sorted(obs.keys())}")
    for key in obs:
        o = np.array(obs[key])
        nx = np.array(need(next_obs, key, h5py.Dataset))
        if nx.shape != o.shape:
            raise Broken(f"{g.name}/next_obs/{key}: shape {list(nx.shape)}, obs has {list(o.shape)}")
        if n > 0 and not (np.array_equal(nx[:-1], o[1:]) and np.array_equal(nx[-1], o[-1])):
            raise Broken(f"{g.name}/next_obs/{key} is not obs/{key} one step on")
    osms = need(g, "osms", h5py.Group)

    success = attr(g, "success")
    if not isinstance(success, (bool, np.bool_)):
        raise Broken(f"{g.name}/success: expected a boolean, found {type(success).__name__}")

    return {
        "name": name,
        "num_samples": n,
        "actions_shape": list(actions.shape),
        "states_shape": states_shape,
        "obs_keys": sorted(obs.keys()),
        "next_obs_keys": sorted(next_obs.keys()),
        "osms_keys": sorted(osms.keys()),
        "task_index": integer(attr(g, "task_index"), f"{g.name}/task_index"),
        "first_action": [float(x) for x in actions[0]] if n > 0 else None,
        "last_reward": float(rewards[n - 1]) if n > 0 else None,
        "last_done": int(dones[n - 1]) if n > 0 else None,
        "success": bool(success),
        "variant": text(attr(g, "variant"), f"{g.name}/variant"),
        "first_state_first3": first3,
    }


def read(path):
    with h5py.File(path, "r") as f:
        data = need(f, "data", h5py.Group)
        total = integer(attr(data, "total"), "/data/total")
        try:
            env_args = json.loads(text(attr(data, "env_args"), "/data/env_args"))
        except json.JSONDecodeError as e:
            raise Broken(f"/data/env_args: not JSON ({e})")
        if not isinstance(env_args, dict) or not {"env_name", "type", "env_kwargs"} <= env_args.keys():
            raise Broken("/data/env_args: expected env_name, type and env_kwargs")

        names = sorted(data.keys(), key=demo_index)
        if [demo_index(n) for n in names] != list(range(len(names))):
            raise Broken("/data: demo groups are not demo_0 .. demo_<n-1>")
        demos = [read_demo(data, name) for name in names]
        samples = sum(d["num_samples"] for d in demos)
        if samples != total:
            raise Broken(f"/data: num_samples add up to {samples}, total is {total}")

        mask_group = need(f, "mask", h5py.Group)
        mask = {}
        for key in ("train", "valid"):
            ds = need(mask_group, key, h5py.Dataset)
            if ds.ndim != 1 or ds.dtype.kind != "S":
                raise Broken(f"{ds.name}: expected a 1-D array of byte strings, found {ds.dtype} {list(ds.shape)}")
            mask[key] = [e.decode("utf-8") for e in np.array(ds[()])]
            unknown = sorted(set(mask[key]) - set(names))
            if unknown:
                raise Broken(f"{ds.name}: names demos that do not exist: {unknown[:5]}")
        if set(mask["train"]) & set(mask["valid"]):
            raise Broken("/mask: train and valid share demos")
        if sorted(mask["train"] + mask["valid"], key=demo_index) != names:
            raise Broken("/mask: train and valid do not cover every demo exactly once")

        return {"total": total, "env_args": env_args, "demos": demos, "mask": mask}


def main(argv):
    if len(argv) != 2:
        print("usage: read-robomimic.py FILE.hdf5", file=sys.stderr)
        return 2
    try:
        summary = read(argv[1])
    except Broken as e:
        print(f"error: broken robomimic layout in {argv[1]}: {e}", file=sys.stderr)
        return 1
    except (OSError, KeyError, ValueError, TypeError) as e:
        print(f"error: cannot read {argv[1]}: {e}", file=sys.stderr)
        return 1
    try:
        out = json.dumps(summary, allow_nan=False)
    except ValueError as e:
        print(f"error: {argv[1]} holds a non-finite value in the summary: {e}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
