#!/usr/bin/env python3
"""Splits per-rollout evaluation results (`osms export <evaluation>` -> rollouts.csv) by one column.

Usage: split-rollouts.py COLUMN [--bins K] [--json] ROLLOUTS_CSV [ROLLOUTS_CSV ...]

Several files (e.g. one evaluation per run seed) are pooled. A column with more than K distinct
values (default 4) is cut into K bins of equal count. Per group: n, success and catch
completion with 95 % Wilson intervals, and the three most frequent failure kinds.
Prints a Markdown table, or with --json one object per group. Standard library only.
"""

import csv
import json
import math
import sys
from collections import Counter

Z = 1.959964


def wilson(x, n):
    if n == 0:
        return (float("nan"), float("nan"))
    p = x / n
    centre = (p + Z * Z / (2 * n)) / (1 + Z * Z / n)
    half = Z * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n)) / (1 + Z * Z / n)
    return (centre - half, centre + half)


def read(paths, column):
    rows = []
    for path in paths:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            if column not in (reader.fieldnames or []):
                names = ", ".join(reader.fieldnames or [])
                raise SystemExit(f"{path}: no column `{column}`; columns: {names}")
            rows.extend(reader)
    return rows


def groups(rows, column, bins):
    values = sorted({r[column] for r in rows}, key=sort_key)
    if len(values) <= bins:
        return [(v, [r for r in rows if r[column] == v]) for v in values]
    known = sorted((float(r[column]), i) for i, r in enumerate(rows) if r[column] != "")
    out = []
    for b in range(bins):
        part = known[b * len(known) // bins : (b + 1) * len(known) // bins]
        if part:
            label = f"{part[0][0]:.4g} to {part[-1][0]:.4g}"
            out.append((label, [rows[i] for _, i in part]))
    empty = [r for r in rows if r[column] == ""]
    if empty:
        out.append(("(empty)", empty))
    return out


def sort_key(v):
    try:
        return (0, float(v), "")
    except ValueError:
        return (1, 0.0, v)


def summary(label, rows):
    n = len(rows)
    succ = sum(r["success"] == "true" for r in rows)
    comp = sum(r["completion"] == "true" for r in rows)
    failures = Counter(
        k[len("failure_") :]
        for r in rows
        for k, v in r.items()
        if k.startswith("failure_") and v == "true"
    )
    return {
        "group": label,
        "n": n,
        "success": succ / n,
        "success_ci": wilson(succ, n),
        "completion": comp / n,
        "completion_ci": wilson(comp, n),
        "failures": failures.most_common(3),
    }


def main(argv):
    args = list(argv)
    as_json = "--json" in args
    if as_json:
        args.remove("--json")
    bins = 4
    if "--bins" in args:
        i = args.index("--bins")
        try:
            bins = int(args[i + 1])
        except (IndexError, ValueError):
            raise SystemExit("--bins takes a whole number, e.g. --bins 4")
        if bins < 1:
            raise SystemExit("--bins takes a whole number of at least 1")
        del args[i : i + 2]
    if len(args) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    column, paths = args[0], args[1:]
    table = [summary(label, rows) for label, rows in groups(read(paths, column), column, bins)]
    if as_json:
        print(json.dumps(table))
        return 0
    pct = lambda x: f"{100 * x:.1f} %"
    ci = lambda c: f"{100 * c[0]:.1f}–{100 * c[1]:.1f}"
    print(f"| {column} | n | success | 95 % CI | completion | 95 % CI | main failures |")
    print("|---|---:|---:|---|---:|---|---|")
    for g in table:
        fails = ", ".join(f"{k} {v}" for k, v in g["failures"])
        print(
            f"| {g['group']} | {g['n']} | {pct(g['success'])} | {ci(g['success_ci'])} | "
            f"{pct(g['completion'])} | {ci(g['completion_ci'])} | {fails} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
