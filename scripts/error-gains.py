#!/usr/bin/env python3
"""Where Eq. 7's arm gains S come from: regressions of π̄'s arm actions on the teacher's.

Usage: error-gains.py PAIRS_CSV [PAIRS_CSV ...]

Reads the (π̄ action, teacher action) pairs of one or more error_pairs folds
(`osms export 'error_pairs#0' --out DIR` -> DIR/pairs.csv) and prints, per phase, the mean over
the 7 arm channels of the least-squares slope Cov(a, ā) / Var(ā) of π̄'s action a on the
teacher's ā (the gain S of Eq. 7 without its delay and AR terms), on:
  - every step, and both actions first smoothed by a centred moving average of 3 and 5 steps
    within each rollout (if S < 1 came from step-to-step jitter in the teacher's commands that
    a student averages out, smoothing would lift it towards 1);
  - the steps of successful and of failed rollouts;
  - the first 6 steps of every rollout (before a student's states can drift far from the
    teacher's), with the mean standard deviation of both actions there.
Prints Markdown. Standard library only.
"""

import csv
import sys
from collections import defaultdict

PHASES = ["approach", "velocity matching", "contact", "follow-through", "grasping"]
ARM = 7


def read(paths):
    rollouts = defaultdict(list)
    for p in paths:
        with open(p, newline="") as f:
            for r in csv.DictReader(f):
                rollouts[(p, int(r["item"]))].append(
                    (
                        int(r["step"]),
                        r["phase"],
                        r["success"] == "true",
                        [float(r[f"student_{k}"]) for k in range(ARM)],
                        [float(r[f"teacher_{k}"]) for k in range(ARM)],
                    )
                )
    for steps in rollouts.values():
        steps.sort(key=lambda s: s[0])
    return list(rollouts.values())


def smooth(rows, w):
    n = len(rows)
    out = []
    for i in range(n):
        lo, hi = max(0, i - w // 2), min(n, i + w // 2 + 1)
        out.append([sum(r[k] for r in rows[lo:hi]) / (hi - lo) for k in range(ARM)])
    return out


def mean(xs):
    return sum(xs) / len(xs)


def sd(xs):
    m = mean(xs)
    return (sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) ** 0.5


def slope(a, t):
    """Mean over channels of Cov(a, t) / Var(t), with the standard deviations of both."""
    slopes, sds_a, sds_t = [], [], []
    for k in range(ARM):
        ak, tk = [x[k] for x in a], [x[k] for x in t]
        ma, mt = mean(ak), mean(tk)
        cov = sum((x - ma) * (y - mt) for x, y in zip(ak, tk)) / (len(ak) - 1)
        var = sum((y - mt) ** 2 for y in tk) / (len(tk) - 1)
        slopes.append(cov / var if var > 0 else float("nan"))
        sds_a.append(sd(ak))
        sds_t.append(sd(tk))
    return mean(slopes), mean(sds_a), mean(sds_t)


def row(label, groups, with_sd=False):
    cells = []
    for p in PHASES:
        a, t = groups[p]
        if len(a) < 30:
            cells.append("–")
            continue
        s, sa, st = slope(a, t)
        cells.append(f"{s:.2f} (n {len(a)}, sd {sa:.3f} / {st:.3f})" if with_sd else f"{s:.2f}")
    print(f"| {label} | " + " | ".join(cells) + " |")


def main(paths):
    rollouts = read(paths)
    print("| steps | " + " | ".join(PHASES) + " |")
    print("|---" * (len(PHASES) + 1) + "|")
    for w in (1, 3, 5):
        groups = defaultdict(lambda: ([], []))
        for steps in rollouts:
            a = smooth([s[3] for s in steps], w)
            t = smooth([s[4] for s in steps], w)
            for s, ai, ti in zip(steps, a, t):
                groups[s[1]][0].append(ai)
                groups[s[1]][1].append(ti)
        row("all" if w == 1 else f"all, smoothed over {w}", groups)
    for label, keep in (
        ("successful rollouts", lambda s: s[2]),
        ("failed rollouts", lambda s: not s[2]),
        ("first 6 steps (sd π̄ / teacher)", lambda s: s[0] < 6),
    ):
        groups = defaultdict(lambda: ([], []))
        for steps in rollouts:
            for s in steps:
                if keep(s):
                    groups[s[1]][0].append(s[3])
                    groups[s[1]][1].append(s[4])
        row(label, groups, with_sd=label.startswith("first"))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
