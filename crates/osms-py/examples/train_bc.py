"""A student written against standard libraries, trained on osms's exported data and evaluated
in osms's world: PyTorch behaviour cloning on the LeRobot export of D_E's training fold of π̄_0,
evaluated with osms.eval.evaluate on the development conditions.

    ./osms export-dataset d_e --format lerobot --out exports/d_e
    python crates/osms-py/examples/train_bc.py exports/d_e --out out/bc

The policy reads what π̄ reads, and only that: the deployable frames `observation.state` (the
current one and its difference to the previous one, oldest frames repeated at a rollout's
start). Its label is the teacher's command `osms.intended_action`, π̄'s label too. π̄_0 trains
on the D_E items outside fold 0 (item % 2 == 1; episode i of the export is D_E's item i), and so
does this. Needs torch and pyarrow besides the osms package (not part of the tests).
"""

import argparse
import json
import os
import time

import numpy as np
import pyarrow.parquet as pq
import torch
from torch import nn

import osms
from osms.eval import evaluate

FOLDS = 2


def frames(export_dir):
    """Per training episode: (states, labels), in step order."""
    table = pq.read_table(os.path.join(export_dir, "data", "chunk-000", "file-000.parquet"))
    cols = table.to_pydict()
    episodes = {}
    for ep, idx, state, label in zip(
        cols["episode_index"], cols["frame_index"], cols["observation.state"], cols["osms.intended_action"]
    ):
        if ep % FOLDS == 0:  # fold 0 is held out from π̄_0
            continue
        episodes.setdefault(ep, []).append((idx, state, label))
    out = []
    for ep in sorted(episodes):
        rows = sorted(episodes[ep])
        out.append(
            (np.asarray([r[1] for r in rows], np.float32), np.asarray([r[2] for r in rows], np.float32))
        )
    return out


def features(current, previous):
    return np.concatenate([current, current - previous], axis=-1)


def dataset(episodes):
    xs, ys = [], []
    for states, labels in episodes:
        previous = np.concatenate([states[:1], states[:-1]], axis=0)
        xs.append(features(states, previous))
        ys.append(labels)
    return np.concatenate(xs), np.concatenate(ys)


class Mlp(nn.Module):
    def __init__(self, n_in, n_out, width=256):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(n_in, width), nn.SiLU(), nn.Linear(width, width), nn.SiLU(),
            nn.Linear(width, width), nn.SiLU(), nn.Linear(width, n_out),
        )

    def forward(self, x):
        return self.net(x)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("export", help="a LeRobot export of d_e (osms export-dataset d_e --format lerobot)")
    ap.add_argument("--steps", type=int, default=15000, help="training steps (π̄'s: 15,000)")
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--conditions", default="dev", help="where to evaluate (tune on dev only)")
    ap.add_argument("--out", default=None, help="write rollouts.csv, eval_info.json and summary.json here")
    args = ap.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(os.cpu_count() or 1)
    rng = np.random.default_rng(args.seed)

    episodes = frames(args.export)
    x, y = dataset(episodes)
    mean, std = x.mean(0), x.std(0) + 1e-6
    y_mean, y_std = y.mean(0), y.std(0) + 1e-6
    xt = torch.from_numpy((x - mean) / std)
    yt = torch.from_numpy((y - y_mean) / y_std)
    model = Mlp(x.shape[1], y.shape[1])
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    started = time.perf_counter()
    for step in range(args.steps):
        idx = torch.from_numpy(rng.integers(0, len(xt), args.batch))
        loss = nn.functional.mse_loss(model(xt[idx]), yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 1000 == 0 or step == args.steps - 1:
            print(f"step {step}: loss {loss.item():.4f}", flush=True)
    train_secs = time.perf_counter() - started
    model.eval()

    previous = {}

    def policy(obs):
        state = obs["agent_pos"]
        prev = np.stack([
            state[i] if step == 0 else previous[c]
            for i, (c, step) in enumerate(zip(obs["condition"].tolist(), obs["step"].tolist()))
        ])
        for c, s in zip(obs["condition"].tolist(), state):
            previous[c] = s
        with torch.no_grad():
            a = model(torch.from_numpy((features(state, prev) - mean) / std)).numpy()
        return np.clip(a * y_std + y_mean, -1.0, 1.0)

    result = evaluate(policy, args.conditions, out=args.out)
    print(result)
    summary = {
        "episodes": len(episodes),
        "frames": int(len(x)),
        "steps": args.steps,
        "train_secs": train_secs,
        "eval_secs": result.wall_secs,
        "protocol": result.protocol,
        "n": result.n,
        "success": result.success,
        "success_ci95": result.success_ci,
        "completion": result.completion,
        "completion_ci95": result.completion_ci,
    }
    print(json.dumps(summary))
    if args.out:
        with open(os.path.join(args.out, "summary.json"), "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=2)


if __name__ == "__main__":
    main()
