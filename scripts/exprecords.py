"""Shared by the issue 74 table scripts: read `osms exp` records and format their numbers.

Not a command; `issue74-regime-table.py` and `issue74-chain-table.py` import it from beside
them. Standard library only.
"""

import json
import math
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def osms(store, *args):
    """Runs `./osms --store STORE ARGS…` beside pipeline.toml and parses its JSON output."""
    out = subprocess.run(
        [os.path.join(ROOT, "osms"), "--store", os.path.abspath(store), "--no-progress", *args],
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout)


def wilson(k, n, z=1.959963984540054):
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def mean_success(row, stage):
    """A stage's success in an `exp show --json` row, averaged over the run seeds."""
    values = row["metrics"][f"success ({stage})"]
    return sum(values) / len(values)


def success(row, stage):
    """A stage's success in an `exp show --json` row: mean ± sd over the run seeds (one seed:
    the value alone), with the Wilson 95 % interval over the pooled rollouts."""
    values = row["metrics"][f"success ({stage})"]
    k, n = row["counts"][f"success ({stage})"]
    lo, hi = wilson(k, n)
    mean = mean_success(row, stage)
    if len(values) == 1:
        return f"{100 * mean:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    return f"{100 * mean:.1f} % ± {100 * sd:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]"


def paired(store, name, baseline):
    """Ours-IL (`dev_student`) − BASELINE in one experiment, paired by condition with the run
    seeds' spread (`osms exp diff --paired`), in points."""
    d = osms(store, "exp", "diff", name, name, "--paired", f"{baseline}:dev_student", "--json")
    e = d["difference"]
    text = f"{100 * e['estimate']:+.1f} [{100 * e['low']:+.1f}, {100 * e['high']:+.1f}]"
    return text.replace("-", "−")
