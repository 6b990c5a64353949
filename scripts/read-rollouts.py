#!/usr/bin/env python3
"""Reads an evaluation's `rollouts.parquet` (osms export) back with pyarrow, as an independent check.

Usage: read-rollouts.py ROLLOUTS_PARQUET

Prints one JSON object on stdout:
  {"rows": N, "columns": [names in order], "types": {name: arrow type},
   "nulls": {name: null count}, "condition": [the condition column],
   "t_c_secs": [the t_c column as repr() strings, which read back to the same double in any
                language (a JSON number may not: a parser is free to round it), null as null]}
Exits non-zero with a message on stderr when the file is not readable Parquet.
"""

import json
import sys

import pyarrow as pa
import pyarrow.parquet as pq


def main(path):
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as e:
        print(f"{path} is not readable Parquet: {e}", file=sys.stderr)
        return 1
    print(
        json.dumps(
            {
                "rows": table.num_rows,
                "columns": table.column_names,
                "types": {f.name: str(f.type) for f in table.schema},
                "nulls": {n: table.column(n).null_count for n in table.column_names},
                "condition": table.column("condition").to_pylist(),
                "t_c_secs": [
                    None if x is None else repr(x)
                    for x in table.column("t_c_secs").to_pylist()
                ],
            }
        )
    )
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(sys.argv[1]))
