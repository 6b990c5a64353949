#!/usr/bin/env python3
"""How much of a teacher's arm command a student's inputs can predict (issue 54).

Usage: offline-r2.py EXPORT_DIR [--fit N] [--seed S] [--json]

EXPORT_DIR is `osms export-dataset d_e --format lerobot --out EXPORT_DIR` of a teacher's D_E
(successful rollouts, privileged frames kept). Regressors map the student's observation at
each step (the default student's: 8 deployable frames, oldest repeated before the start; the
palm's position and velocity and the observed object's offset from it; the observed
positions' 7 frame-to-frame differences) to the teacher's intended arm command (the 7 arm
channels of `osms.intended_action`). The first N episodes fit (default 400), the rest are held
out. Per phase (the phase known when the action is chosen: the previous step's, approach at
step 0), on the held-out steps: R² = 1 - SSE / SST over the 7 channels (SST around the
phase's held-out mean) and the slope of the prediction on the truth, Cov(ŷ, y) / Var(y),
pooled over channels: the regression dilution a student shows as an arm gain S < 1.

Two regressors, numpy only (no new dependency): ridge regression on the standardised inputs,
and a one-hidden-layer MLP (256 tanh units, Adam, minibatches, early stopping on a tenth of the
fit episodes). Both are seeded, so a rerun prints the same numbers.
"""

import json
import sys

import numpy as np
import pyarrow.parquet as pq

PHASES = ["approach", "velocity matching", "contact", "follow-through", "grasping"]
HISTORY = 8
FRAME = 7 + 7 + 17 + 17 + 3 + 24
OBJECT = 48
PALM = 48 + 13  # in the privileged frame: position, normal (+3), velocity (+6)


def load(root):
    table = pq.read_table(f"{root}/data/chunk-000/file-000.parquet")
    cols = table.column_names
    for need in ("observation.state", "osms.intended_action", "osms.phase", "osms.privileged"):
        if need not in cols:
            sys.exit(f"offline-r2: {root} has no column {need!r} (export a rollout dataset "
                     "whose privileged frames were kept, e.g. d_e)")
    state = np.asarray(table.column("observation.state").to_pylist(), dtype=np.float64)
    intended = np.asarray(table.column("osms.intended_action").to_pylist(), dtype=np.float64)
    phase = np.asarray(table.column("osms.phase").to_pylist(), dtype=np.int64).reshape(-1)
    privileged = np.asarray(table.column("osms.privileged").to_pylist(), dtype=np.float64)
    episode = np.asarray(table.column("episode_index").to_pylist(), dtype=np.int64)
    return state, intended, phase, privileged, episode


def features(state, privileged, rows):
    """The student's observation at every step of one episode (rows in step order)."""
    out = []
    for n in range(len(rows)):
        frames = [state[rows[max(n + h + 1 - HISTORY, 0)]] for h in range(HISTORY)]
        palm_pos = privileged[rows[n], PALM:PALM + 3]
        palm_vel = privileged[rows[n], PALM + 6:PALM + 9]
        obj = state[rows[n], OBJECT:OBJECT + 3]
        diffs = [frames[h][OBJECT:OBJECT + 3] - frames[h - 1][OBJECT:OBJECT + 3]
                 for h in range(1, HISTORY)]
        out.append(np.concatenate(frames + [palm_pos, palm_vel, obj - palm_pos] + diffs))
    return np.asarray(out)


def dataset(root):
    state, intended, phase, privileged, episode = load(root)
    xs, ys, ps, es = [], [], [], []
    for e in np.unique(episode):
        rows = np.flatnonzero(episode == e)
        xs.append(features(state, privileged, rows))
        ys.append(intended[rows, :7])
        online = np.concatenate([[0], phase[rows][:-1]])
        ps.append(online)
        es.append(np.full(len(rows), e))
    return np.vstack(xs), np.vstack(ys), np.concatenate(ps), np.concatenate(es)


def ridge(x, y, x_test, lam=1.0):
    w = np.linalg.solve(x.T @ x + lam * np.eye(x.shape[1]), x.T @ y)
    return x_test @ w


def mlp(x, y, x_val, y_val, x_test, seed, hidden=256, lr=1e-3, batch=256, epochs=200):
    rng = np.random.default_rng(seed)
    d, k = x.shape[1], y.shape[1]
    w1 = rng.uniform(-1, 1, (d, hidden)) / np.sqrt(d)
    b1 = np.zeros(hidden)
    w2 = rng.uniform(-1, 1, (hidden, k)) / np.sqrt(hidden)
    b2 = np.zeros(k)
    params = [w1, b1, w2, b2]
    m = [np.zeros_like(p) for p in params]
    v = [np.zeros_like(p) for p in params]
    step = 0

    def forward(ps, a):
        h = np.tanh(a @ ps[0] + ps[1])
        return h, h @ ps[2] + ps[3]

    best, best_params, since = np.inf, [p.copy() for p in params], 0
    for _ in range(epochs):
        order = rng.permutation(len(x))
        for s in range(0, len(x), batch):
            i = order[s:s + batch]
            h, out = forward(params, x[i])
            g_out = 2 * (out - y[i]) / len(i)
            g_h = (g_out @ params[2].T) * (1 - h * h)
            grads = [x[i].T @ g_h, g_h.sum(0), h.T @ g_out, g_out.sum(0)]
            step += 1
            for j, g in enumerate(grads):
                m[j] = 0.9 * m[j] + 0.1 * g
                v[j] = 0.999 * v[j] + 0.001 * g * g
                mh = m[j] / (1 - 0.9 ** step)
                vh = v[j] / (1 - 0.999 ** step)
                params[j] -= lr * mh / (np.sqrt(vh) + 1e-8)
        loss = np.mean((forward(params, x_val)[1] - y_val) ** 2)
        if loss < best - 1e-6:
            best, best_params, since = loss, [p.copy() for p in params], 0
        else:
            since += 1
            if since >= 10:
                break
    return forward(best_params, x_test)[1]


def per_phase(pred, y, phase):
    rows = []
    for p, name in enumerate(PHASES):
        i = phase == p
        if i.sum() < 2:
            rows.append({"phase": name, "steps": int(i.sum()), "r2": None, "slope": None})
            continue
        yt, yp = y[i], pred[i]
        dy = yt - yt.mean(0)
        sst = (dy ** 2).sum()
        sse = ((yt - yp) ** 2).sum()
        slope = ((yp - yp.mean(0)) * dy).sum() / sst
        rows.append({"phase": name, "steps": int(i.sum()), "r2": 1 - sse / sst, "slope": slope})
    return rows


def main(argv):
    args = [a for i, a in enumerate(argv)
            if not a.startswith("--") and (i == 0 or argv[i - 1] not in ("--fit", "--seed"))]
    opts = dict(zip(argv, argv[1:]))
    if len(args) < 1:
        sys.exit(__doc__)
    root = args[0]
    fit_n = int(opts.get("--fit", 400))
    seed = int(opts.get("--seed", 0))
    x, y, phase, episode = dataset(root)
    episodes = np.unique(episode)
    if len(episodes) <= fit_n:
        fit_n = len(episodes) * 4 // 5
    fit_eps = episodes[:fit_n]
    val_eps = fit_eps[-max(fit_n // 10, 1):]
    train = np.isin(episode, fit_eps) & ~np.isin(episode, val_eps)
    val = np.isin(episode, val_eps)
    test = ~np.isin(episode, fit_eps)
    mu, sd = x[train].mean(0), x[train].std(0)
    sd[sd < 1e-8] = 1.0
    z = np.clip((x - mu) / sd, -5, 5)
    y_mu = y[train].mean(0)
    lin = ridge(z[train], y[train] - y_mu, z[test]) + y_mu
    net = mlp(z[train], y[train] - y_mu, z[val], y[val] - y_mu, z[test], seed) + y_mu
    result = {
        "export": root,
        "fit_episodes": int(fit_n),
        "held_out_episodes": int(len(episodes) - fit_n),
        "ridge": per_phase(lin, y[test], phase[test]),
        "mlp": per_phase(net, y[test], phase[test]),
    }
    if "--json" in argv:
        print(json.dumps(result, indent=1))
        return
    print(f"{root}: {result['fit_episodes']} episodes fit, {result['held_out_episodes']} held out")
    print("| regressor | " + " | ".join(PHASES) + " |")
    print("|---|" + "---:|" * len(PHASES))
    for name in ("ridge", "mlp"):
        cells = [f"{r['r2']:.2f} / {r['slope']:.2f}" if r["r2"] is not None else "–"
                 for r in result[name]]
        print(f"| {name} (R² / slope) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
