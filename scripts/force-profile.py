#!/usr/bin/env python3
"""When, after first contact, a rollout dataset's contact force peaks (osms export-dataset --format robomimic).

Usage: force-profile.py [--steps K] [--threshold N] DATASET_HDF5

Splits the episodes that reach an admissible contact by f_max (the episode attribute
`max_force_n`) above or below THRESHOLD (default 80 N, the paper's delta_f) and prints, per
group, per control step k = 0..K-1 after the first contact step (default K = 25; Delta_t_eval =
0.2 s is k = 10 at 50 Hz): the mean summed admissible normal force observed at the step's start,
the mean finger joint position, and the palm's and object's speed along the pre-contact
incoming direction; then the step of each episode's largest observed force within K, as counts,
and the share of large objects. The observed force is a sample at the control step's start,
so its peaks sit below f_max, which is the largest over every physics step. Needs h5py and numpy
(the test environment's Python, .venv-test, has both).
"""

import sys
from collections import Counter

import h5py
import numpy as np

# The privileged frame's layout (osms_sim::episode): robot q, q̇ (48), observed object position,
# quaternion, linear and angular velocity (13), palm position, normal, velocity (9), admissible
# normal force, contact count.
OBJECT_VEL = slice(48 + 7, 48 + 10)
PALM_VEL = slice(48 + 13 + 6, 48 + 13 + 9)
FORCE = 48 + 13 + 9
CONTACT = 2  # osms_sim::Phase::Contact


def profiles(path, steps):
    groups = {}
    with h5py.File(path, "r") as f:
        for demo in f["data"].values():
            phase = demo["osms/phase"][:]
            touched = np.nonzero(phase >= CONTACT)[0]
            if len(touched) == 0 or touched[0] == 0:
                continue
            k0 = touched[0]
            priv = demo["osms/privileged"][:]
            fingers = demo["obs/hand_qpos"][:, 1:]
            v = priv[k0 - 1, OBJECT_VEL]
            incoming = v / max(np.linalg.norm(v), 1e-12)
            at = [min(k0 + k, len(phase) - 1) for k in range(steps)]
            attrs = demo.attrs
            yield {
                "f_max": float(attrs["max_force_n"]),
                "large": "large" in str(attrs["variant"]),
                "force": priv[at, FORCE],
                "fingers": fingers[at].mean(axis=1),
                "palm": priv[at, PALM_VEL] @ incoming,
                "object": priv[at, OBJECT_VEL] @ incoming,
            }


def main(argv):
    steps, threshold, paths = 25, 80.0, []
    it = iter(argv)
    try:
        for a in it:
            if a == "--steps":
                steps = int(next(it))
            elif a == "--threshold":
                threshold = float(next(it))
            else:
                paths.append(a)
    except (StopIteration, ValueError):
        print("--steps takes a whole number and --threshold a number of newtons\n", file=sys.stderr)
        paths = []
    if len(paths) != 1 or steps < 1:
        print(__doc__, file=sys.stderr)
        return 2
    try:
        rows = list(profiles(paths[0], steps))
    except (OSError, KeyError) as e:
        print(f"{paths[0]}: not an osms robomimic export: {e}", file=sys.stderr)
        return 1
    np.set_printoptions(precision=1, suppress=True, linewidth=200)
    for name, keep in [
        (f"f_max > {threshold:g} N", lambda r: r["f_max"] > threshold),
        (f"f_max <= {threshold:g} N", lambda r: r["f_max"] <= threshold),
    ]:
        g = [r for r in rows if keep(r)]
        print(f"## {name}: {len(g)} episodes, {100 * np.mean([r['large'] for r in g]) if g else 0:.0f} % large objects")
        if not g:
            continue
        for key, label in [
            ("force", "force (N)"),
            ("fingers", "finger q (rad)"),
            ("palm", "palm speed along incoming (m/s)"),
            ("object", "object speed along incoming (m/s)"),
        ]:
            print(f"{label:>34}: {np.mean([r[key] for r in g], axis=0)}")
        peaks = Counter(int(np.argmax(r["force"])) for r in g)
        print(f"{'step of the largest force':>34}: {dict(sorted(peaks.items()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
