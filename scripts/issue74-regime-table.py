#!/usr/bin/env python3
"""The regime map's table (docs/validation.md) from the points recorded so far.

    python3 scripts/issue74-regime-table.py [STORE]

Reads each `regime-SCALE-KAPPA` record that `scripts/issue74-experiments STORE regime` wrote
(`osms exp show --json`, `osms exp diff --paired --json`) and prints one Markdown row per
point: mean SR_org, D_*'s make-up, the three students on `dev` (mean ± sd over the run seeds,
Wilson 95 % over the pooled rollouts) and Ours-IL's paired differences (the seeds' spread
held). Points not yet recorded are listed as such.
"""

import os
import sys

from exprecords import osms, paired, success

SCALES = ["0.25", "0.5", "1"]
KAPPAS = ["1", "1.5"]
STUDENTS = ["dev_student", "dev_student_naive", "dev_student_dart"]
METRICS = [
    "success",
    "mean_sr_org",
    "kept",
    "refined",
    "repaired",
    "dropped",
    "demonstrations",
    "coverage",
    "refinement_rate",
]


def recorded(store):
    return {e["name"] for e in osms(store, "exp", "ls", "--json")}


def main():
    store = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("OSMS_STORE", "store")
    names = recorded(store)
    print(
        "| deviation scale, κ | mean SR_org | keep / refine / repair / drop | repair | "
        "D_* (coverage, refinement) | Ours-IL | Naive-IL | DART-IL | Ours − Naive, paired | "
        "Ours − DART, paired |"
    )
    print("|---|---:|---|---:|---|---|---|---|---|---|")
    for scale in SCALES:
        for kappa in KAPPAS:
            name = f"regime-{scale}-{kappa}"
            if name not in names:
                print(f"| {scale}, {kappa} | not yet recorded | | | | | | | | |")
                continue
            row = osms(store, "exp", "show", name, "--json", "--metrics", ",".join(METRICS))[
                "rows"
            ][0]
            m = {k.split(" (")[0]: v for k, v in row["metrics"].items() if "(dstar)" in k}
            m["mean_sr_org"] = row["metrics"]["mean_sr_org (validate)"]
            one = {k: v[0] for k, v in m.items()}
            repaired, dropped = int(one["repaired"]), int(one["dropped"])
            failed = repaired + dropped
            share = f" ({100 * repaired / failed:.0f} %)" if failed else ""
            cells = [
                f"{scale}, {kappa}",
                f"{one['mean_sr_org']:.3f}",
                f"{int(one['kept'])} / {int(one['refined'])} / {repaired} / {dropped}",
                f"{repaired} of {failed}{share}",
                f"{int(one['demonstrations']):,} ({one['coverage']:.3f}, "
                f"{one['refinement_rate']:.3f})",
                *(success(row, s) for s in STUDENTS),
                paired(store, name, "dev_student_naive"),
                paired(store, name, "dev_student_dart"),
            ]
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
