#!/usr/bin/env python3
"""Reads an osms LeRobot v3.0 export back with pyarrow alone, as an independent check.

Usage: read-lerobot.py EXPORT_DIR [--all-frames]

Prints one JSON object on stdout:
  {"info": <meta/info.json>, "frames": N, "columns": [data columns],
   "episodes": [{"episode_index", "from", "to", "length", "task", "first_action",
                 "last_state_first3"}, ...],
   "action_shape": [N, 24], "tasks": {task: task_index}, "stats_keys": [sorted features]}
With --all-frames each episode also has "actions" and "states": every frame's `action` and
`observation.state`, in frame order. Everything but "info" and "stats_keys" comes from the
Parquet files. Exits non-zero with a
message on stderr when the layout is wrong: a missing file, episode ranges that are not
contiguous or disagree with the data, an `index` column that is not 0..N-1, ...
"""

import json
import sys

import pyarrow as pa
import pyarrow.parquet as pq

INFO = "meta/info.json"
STATS = "meta/stats.json"
TASKS = "meta/tasks.parquet"
EPISODES = "meta/episodes/chunk-{c:03d}/file-{f:03d}.parquet"
DATA = "data/chunk-{c:03d}/file-{f:03d}.parquet"


class LayoutError(Exception):
    pass


def fail_if(cond, message):
    if cond:
        raise LayoutError(message)


def read_json(root, rel):
    try:
        with open(f"{root}/{rel}", encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise LayoutError(f"missing {rel}") from None
    except json.JSONDecodeError as e:
        raise LayoutError(f"{rel} is not JSON: {e}") from None


def read_parquet(root, rel):
    try:
        return pq.read_table(f"{root}/{rel}")
    except FileNotFoundError:
        raise LayoutError(f"missing {rel}") from None
    except (pa.ArrowInvalid, OSError) as e:
        raise LayoutError(f"{rel} is not readable Parquet: {e}") from None


def column(table, name, rel):
    fail_if(name not in table.column_names, f"{rel} has no column {name!r}")
    return table.column(name).to_pylist()


def summarise(root, all_frames=False):
    info = read_json(root, INFO)
    stats = read_json(root, STATS)
    fail_if(not isinstance(stats, dict), f"{STATS} is not an object")

    # Episodes metadata: every file of chunk 0 from file 0 on (osms writes one).
    rel = EPISODES.format(c=0, f=0)
    episodes = read_parquet(root, rel)
    ep_index = column(episodes, "episode_index", rel)
    ep_from = column(episodes, "dataset_from_index", rel)
    ep_to = column(episodes, "dataset_to_index", rel)
    ep_length = column(episodes, "length", rel)
    ep_tasks = column(episodes, "tasks", rel)
    ep_chunk = column(episodes, "data/chunk_index", rel)
    ep_file = column(episodes, "data/file_index", rel)
    fail_if(len(ep_index) == 0, f"{rel} has no episodes")
    fail_if(ep_index != list(range(len(ep_index))), f"{rel}: episode_index is not 0..{len(ep_index) - 1}")

    # Tasks: task_index plus the pandas index column `task`.
    tasks_table = read_parquet(root, TASKS)
    task_names = column(tasks_table, "task", TASKS)
    task_indices = column(tasks_table, "task_index", TASKS)
    fail_if(
        sorted(task_indices) != list(range(len(task_indices))),
        f"{TASKS}: task_index is not 0..{len(task_indices) - 1}",
    )
    fail_if(len(set(task_names)) != len(task_names), f"{TASKS}: tasks are not distinct")
    tasks = dict(zip(task_names, task_indices))
    task_of_index = {i: t for t, i in tasks.items()}

    # Data: the files the episodes point to, in order.
    files = sorted(set(zip(ep_chunk, ep_file)))
    tables = [read_parquet(root, DATA.format(c=c, f=f)) for c, f in files]
    names = tables[0].column_names
    for (c, f), t in zip(files, tables):
        fail_if(t.column_names != names, f"{DATA.format(c=c, f=f)}: columns differ from the first file's")
    data = pa.concat_tables(tables)
    frames = data.num_rows
    index = column(data, "index", "data")
    fail_if(index != list(range(frames)), f"data: index is not 0..{frames - 1}")
    episode_index = column(data, "episode_index", "data")
    frame_index = column(data, "frame_index", "data")
    task_index = column(data, "task_index", "data")
    actions = column(data, "action", "data")
    states = column(data, "observation.state", "data")
    widths = {len(a) for a in actions}
    fail_if(len(widths) > 1, f"data: action rows have different lengths {sorted(widths)}")
    action_width = widths.pop() if widths else 0

    fail_if(
        sum(ep_length) != frames,
        f"frame counts disagree: the episodes have {sum(ep_length)} frames, the data {frames}",
    )
    out_episodes = []
    expected_from = 0
    for i, a, b, n, ts in zip(ep_index, ep_from, ep_to, ep_length, ep_tasks):
        fail_if(a != expected_from, f"episode {i}: starts at frame {a}, expected {expected_from}")
        fail_if(b - a != n, f"episode {i}: range {a}..{b} disagrees with length {n}")
        fail_if(n <= 0, f"episode {i}: no frames")
        fail_if(b > frames, f"episode {i}: ends at frame {b}, the data has {frames}")
        fail_if(episode_index[a:b] != [i] * n, f"episode {i}: data rows {a}..{b} are not all episode {i}")
        fail_if(frame_index[a:b] != list(range(n)), f"episode {i}: frame_index is not 0..{n - 1}")
        fail_if(len(ts) != 1, f"episode {i}: {len(ts)} tasks, expected one")
        task = ts[0]
        fail_if(task not in tasks, f"episode {i}: task {task!r} is not in {TASKS}")
        rows_tasks = {task_of_index.get(k) for k in task_index[a:b]}
        fail_if(rows_tasks != {task}, f"episode {i}: data task_index disagrees with its task {task!r}")
        episode = {
            "episode_index": i,
            "from": a,
            "to": b,
            "length": n,
            "task": task,
            "first_action": actions[a],
            "last_state_first3": states[b - 1][:3],
        }
        if all_frames:
            episode["actions"] = actions[a:b]
            episode["states"] = states[a:b]
        out_episodes.append(episode)
        expected_from = b
    fail_if(expected_from != frames, f"episodes cover {expected_from} frames, the data has {frames}")

    return {
        "info": info,
        "frames": frames,
        "columns": names,
        "episodes": out_episodes,
        "action_shape": [frames, action_width],
        "tasks": tasks,
        "stats_keys": sorted(stats),
    }


def main(argv):
    all_frames = "--all-frames" in argv[2:]
    if len(argv) not in (2, 3) or (len(argv) == 3 and not all_frames):
        print("usage: read-lerobot.py EXPORT_DIR [--all-frames]", file=sys.stderr)
        return 2
    try:
        summary = summarise(argv[1].rstrip("/"), all_frames)
    except LayoutError as e:
        print(f"error: not a valid osms LeRobot v3.0 export: {e}", file=sys.stderr)
        return 1
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
