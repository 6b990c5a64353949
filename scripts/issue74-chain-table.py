#!/usr/bin/env python3
"""Issue 74's link-by-link chain table (docs/students.md) from recorded chain experiments.

    python3 scripts/issue74-chain-table.py STORE:EXPERIMENT [STORE:EXPERIMENT ...]

Each argument names a chain recorded by `scripts/issue74-experiments` (`chain-increment`,
`chain-increment-nodr`, `chain-absolute`, `chain-absolute-nodr`) and the store holding it; each
becomes a column: the teacher and π̄_0 on `dev`, the calibrated model's scale, mean SR_org, D_*'s
make-up, the three students (mean ± sd over the run seeds, Wilson 95 % over the pooled rollouts)
and Ours-IL's paired differences against Naive-IL and DART-IL (`osms exp diff --paired`, the
seeds' spread held). Read from `osms exp show --json`; prints Markdown.
"""

import sys

from exprecords import mean_success, osms, paired, success

METRICS = [
    "success",
    "calibration.pooled.scale",
    "mean_sr_org",
    "original_successes",
    "kept",
    "refined",
    "repaired",
    "dropped",
    "demonstrations",
    "coverage",
    "refinement_rate",
    "unperturbed_max_force_n",
]


def column(store, name):
    row = osms(store, "exp", "show", name, "--json", "--metrics", ",".join(METRICS))["rows"][0]
    m = {k.split(" (")[0]: v[0] for k, v in row["metrics"].items() if not k.startswith("success")}
    ratio = mean_success(row, "dev_student_il") / mean_success(row, "dev_teacher")
    repaired, dropped = int(m["repaired"]), int(m["dropped"])
    failed = repaired + dropped
    share = f" ({100 * repaired / failed:.1f} %)" if failed else ""
    return {
        "teacher on `dev`": success(row, "dev_teacher"),
        "π̄_0 on `dev` (÷ teacher)": f"{success(row, 'dev_student_il')} ({ratio:.2f})",
        "calibrated deviation scale (pooled)": f"{m['calibration.pooled.scale']:.3f}",
        "teacher successes on D_R": f"{int(m['original_successes']):,} of "
        f"{int(m['original_successes']) + failed:,}",
        "mean SR_org at κ = 1.5": f"{m['mean_sr_org']:.3f}",
        "decisions (keep / refine / repair / drop)": f"{int(m['kept'])} / {int(m['refined'])} / "
        f"{repaired} / {dropped}",
        "repair": f"{repaired} of {failed}{share}",
        "D_* demonstrations (coverage, refinement rate)": f"{int(m['demonstrations']):,} "
        f"({m['coverage']:.3f}, {m['refinement_rate']:.3f})",
        "unperturbed f_max of D_*": f"{m['unperturbed_max_force_n']:.1f} N",
        "Ours-IL": success(row, "dev_student"),
        "Naive-IL": success(row, "dev_student_naive"),
        "DART-IL": success(row, "dev_student_dart"),
        "Ours-IL − Naive-IL, paired": paired(store, name, "dev_student_naive"),
        "Ours-IL − DART-IL, paired": paired(store, name, "dev_student_dart"),
        "wall of the experiment (s)": f"{row['wall_secs']:,.0f}",
    }


def main():
    if len(sys.argv) < 2 or any(":" not in a for a in sys.argv[1:]):
        sys.exit(__doc__)
    chains = [a.split(":", 1) for a in sys.argv[1:]]
    cols = [column(store, name) for store, name in chains]
    print("| link | " + " | ".join(f"`{name}`" for _, name in chains) + " |")
    print("|---|" + "---|" * len(chains))
    for link in cols[0]:
        print(f"| {link} | " + " | ".join(c[link] for c in cols) + " |")


if __name__ == "__main__":
    main()
