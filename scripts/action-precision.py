#!/usr/bin/env python3
"""How precisely π̄ reproduces its teacher's arm actions, in the action's units and in radians.

Usage: action-precision.py --arm increment|absolute PAIRS_CSV [PAIRS_CSV ...]

Reads the (π̄ action, teacher action) pairs of one or more error_pairs folds (`osms export
'error_pairs#0' --out DIR` -> DIR/pairs.csv: π̄ rolled out on its held-out D_E conditions, the
frozen teacher queried at every state it visits) and prints, per arm joint, Markdown rows of:
  - the sd of the teacher's label over all steps (the unit in which the student standardises
    the channel, up to D_E's states being the teacher's own rather than π̄'s);
  - the RMS of π̄'s action minus the teacher's, in action units and in those standard units;
  - that RMS as radians of servo target: an increment moves the target by 0.15 rad per unit
    (`--arm increment`); an absolute action spans the joint's range, so one unit is half of it
    (`--arm absolute`);
  - the mean |change| of the teacher's target between consecutive steps, in radians, and the
    RMS error in those steps (how many steps' motion one step's error puts the target off).
The question (docs/students.md, "The absolute arm on `dev`"): is a student's error, relative to
its labels' spread, the same on both arms, so that the absolute arm's coarser unit alone puts
its targets many steps' motion off? Standard library only.
"""

import argparse
import csv
import math
from collections import defaultdict

ARM = 7
STEP_RAD = 0.15
# Half of each xArm7 joint's range in the world (osms_sim::robot::ARM; j1, j3, j5, j7 narrowed to ±π).
HALF_RANGE = [
    math.pi,
    (2.0944 + 2.059) / 2,
    math.pi,
    (3.927 + 0.19198) / 2,
    math.pi,
    (3.14159 + 1.69297) / 2,
    math.pi,
]


def read(paths):
    rollouts = defaultdict(list)
    for p in paths:
        with open(p, newline="") as f:
            for r in csv.DictReader(f):
                rollouts[(p, int(r["item"]))].append(
                    (
                        int(r["step"]),
                        [float(r[f"student_{k}"]) for k in range(ARM)],
                        [float(r[f"teacher_{k}"]) for k in range(ARM)],
                    )
                )
    for steps in rollouts.values():
        steps.sort(key=lambda s: s[0])
    return list(rollouts.values())


def sd(xs):
    m = sum(xs) / len(xs)
    return (sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) ** 0.5


def rms(xs):
    return (sum(x * x for x in xs) / len(xs)) ** 0.5


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", choices=["increment", "absolute"], required=True)
    ap.add_argument("pairs", nargs="+", help="pairs.csv of an exported error_pairs fold")
    args = ap.parse_args()
    rollouts = read(args.pairs)
    steps = [s for r in rollouts for s in r]
    if len(steps) < 2:
        ap.error("fewer than two pairs in the files given")
    rad = [STEP_RAD] * ARM if args.arm == "increment" else HALF_RANGE
    cols = {
        "teacher label sd (action units)": [],
        "RMS error (action units)": [],
        "RMS error ÷ label sd": [],
        "RMS error as target (rad)": [],
        "teacher's target motion per step (rad)": [],
        "RMS error ÷ one step's motion": [],
    }
    for k in range(ARM):
        t = [s[2][k] for s in steps]
        e = [s[1][k] - s[2][k] for s in steps]
        label_sd, err = sd(t), rms(e)
        if args.arm == "increment":
            motion = [abs(s[2][k]) * STEP_RAD for s in steps]
        else:
            motion = [
                abs(b[2][k] - a[2][k]) * rad[k] for r in rollouts for a, b in zip(r, r[1:])
            ]
        per_step = sum(motion) / len(motion)
        cols["teacher label sd (action units)"].append(f"{label_sd:.4f}")
        cols["RMS error (action units)"].append(f"{err:.4f}")
        cols["RMS error ÷ label sd"].append(f"{err / label_sd:.3f}" if label_sd > 0 else "—")
        cols["RMS error as target (rad)"].append(f"{err * rad[k]:.4f}")
        cols["teacher's target motion per step (rad)"].append(f"{per_step:.4f}")
        cols["RMS error ÷ one step's motion"].append(
            f"{err * rad[k] / per_step:.2f}" if per_step > 0 else "—"
        )
    print(f"{args.arm} arm: {len(rollouts)} rollouts, {len(steps)} steps\n")
    print("| arm joint | " + " | ".join(str(k + 1) for k in range(ARM)) + " |")
    print("|---|" + "---:|" * ARM)
    for name, cells in cols.items():
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
