#!/usr/bin/env python3
"""Shares of a rollout's time by part of the loop, from `perf script` output of the rollout
bench (scripts/profile-rollout). Only samples under the bench's `profiled_loop` count as the
loop; each goes to the first part whose frames appear on its call stack (innermost frame
first); "a|b" means frame b called from inside frame a."""
import re
import sys

PARTS = [
    ("setup: Episode::new (model copy, set_const, initial forward)", ["initial_data", "Episode::new", "with_draw"]),
    ("restore and snapshot", ["::restore", "::snapshot"]),
    ("observation: contact-force solve under the held controls", ["observe|mj_forwardSkip"]),
    ("observation: mj_step1 (the first half of the next physics step)", ["observe|mj_step1"]),
    ("observation: palm Jacobian, contact scan, frames", ["observe"]),
    ("physics: mj_step, mj_step2", ["mj_step2", "mj_step"]),
    ("physics-rate bookkeeping: contact scan", ["metrics::scan"]),
    ("physics-rate bookkeeping: evaluator", ["Evaluator::physics_step", "site_velocity"]),
    ("physics-rate bookkeeping: DR gain scaling, instability check", ["physics_step"]),
    ("policy: teacher network", ["act_deterministic"]),
    ("policy: student network (flow sampling)", ["sample_batch"]),
    ("policy: student observation and normalisation", ["Student::observation", "act_batch_with"]),
    ("policy: scripted prior / catcher", ["ScriptedCatcher"]),
    ("policy: follow-through channel", ["palm_motion_channels"]),
    ("policy: observation vector, residual", ["Residual", "residual_action"]),
    ("record", ["push_record"]),
    ("control step: reward, history, noise, delays, targets", ["step_with_hooks", "Episode::step"]),
]
OUTSIDE = "outside"


def part(frames):
    if not any("profiled_loop" in f for f in frames):
        return OUTSIDE
    for name, keys in PARTS:
        for key in keys:
            if "|" in key:
                outer, inner = key.split("|")
                o = [i for i, f in enumerate(frames) if outer in f]
                n = [i for i, f in enumerate(frames) if inner in f]
                if o and n and min(n) < min(o):
                    return name
            elif any(key in f for f in frames):
                return name
    return OUTSIDE


def main():
    counts = {}
    total = 0
    block = []
    for line in list(sys.stdin) + [""]:
        line = line.rstrip("\n")
        if line.strip():
            block.append(line)
            continue
        if block:
            frames = [re.sub(r"^\s*[0-9a-f]+\s+", "", f).strip() for f in block[1:]]
            name = part(frames)
            counts[name] = counts.get(name, 0) + 1
            total += 1
        block = []
    outside = counts.pop(OUTSIDE, 0)
    inside = total - outside
    if not inside:
        sys.exit("no samples inside the bench's profiled_loop")
    for name in [p[0] for p in PARTS]:
        if counts.get(name):
            print(f"{100 * counts[name] / inside:6.2f}%  {name}")
    print(f"{inside} samples in the loop ({outside} outside it, in the bench's own set-up, left out)")


main()
