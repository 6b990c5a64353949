"""Python-driven evaluation against the Rust-native evaluation of the same rollouts, in one run.

The same rollouts (a condition set's first N conditions under one evaluation stage's protocol,
the action all zeros) three ways:

  python     osms.eval.evaluate with a NumPy policy: Rust steps the pool with the GIL released,
             Python is called once per control step with the batch of observations;
  pool       the same pool stepped in Rust alone (no Python call);
  per_thread one rollout per rayon task, as osms's evaluation stages run rollouts.

and two vector environments of `--n-envs` sub-environments, stepped from Python with the same
zero actions until N episodes have ended (the sub-environments that already started further
episodes keep stepping meanwhile, so they step more control steps than the rollouts above; their
rate counts every control step the world ran):

  vector     osms.CatchVectorEnv: Rust steps every sub-environment, GIL released;
  sync       gymnasium's SyncVectorEnv of osms/Catch-v0 environments, one after another.

Each is timed `--repeat` times, interleaved; the best wall time counts. Prints control steps per
second and the ratios python / per_thread and python / pool (issue 56's target: >= 0.8),
vector / pool and vector / sync.
Run through scripts/bench-python, which installs the release build first.
"""

import argparse
import json
import time

import numpy as np

import gymnasium
import osms
import osms.gym
from osms import eval as oe
from osms._native import bench_constant


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default=None, help="the pipeline's profile (default: its default)")
    ap.add_argument("--conditions", default="dev", help="condition set (default: dev)")
    ap.add_argument("--protocol", default=None, help="evaluation stage (default: osms's for the set)")
    ap.add_argument("--n", type=int, default=200, help="conditions to roll out (default: 200)")
    ap.add_argument("--n-envs", type=int, default=16, help="rollouts at once (default: 16)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each (default: 3)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()

    project = osms.Project(None, None, args.profile)
    protocol = project.protocol(args.protocol or project.default_protocol(args.conditions))
    indices = list(range(min(args.n, protocol.n_conditions)))
    zero = [0.0] * osms.N_ACTION

    def policy(obs):
        return np.zeros((obs["agent_pos"].shape[0], osms.N_ACTION), dtype=np.float32)

    def python():
        started = time.perf_counter()
        result = oe.evaluate(policy, protocol=protocol.name, indices=indices, n_envs=args.n_envs, project=project)
        return sum(r["steps"] for r in result.rows), time.perf_counter() - started

    def vector_steps(env):
        """Steps ``env`` (NEXT_STEP autoreset) until len(indices) episodes have ended."""
        started = time.perf_counter()
        env.reset(seed=0)
        action = np.zeros((args.n_envs, osms.N_ACTION), dtype=np.float32)
        ended, steps = 0, 0
        pending = np.zeros(args.n_envs, dtype=bool)
        while ended < len(indices):
            _, _, terminated, truncated, _ = env.step(action)
            steps += int((~pending).sum())
            pending = terminated | truncated
            ended += int(pending.sum())
        return steps, time.perf_counter() - started

    vector_env = osms.gym.CatchVectorEnv(args.n_envs, protocol=protocol.name, project=project)
    sync_env = gymnasium.vector.SyncVectorEnv(
        [lambda: osms.gym.CatchEnv(protocol=protocol.name, project=project)] * args.n_envs
    )
    runs = {
        "python": python,
        "pool": lambda: bench_constant(protocol, indices, args.n_envs, zero),
        "per_thread": lambda: bench_constant(protocol, indices, args.n_envs, zero, per_thread=True),
        "vector": lambda: vector_steps(vector_env),
        "sync": lambda: vector_steps(sync_env),
    }
    best = {}
    for _ in range(args.repeat):
        for name, run in runs.items():
            steps, secs = run()
            if name in best:
                assert best[name][0] == steps, f"{name}: {steps} control steps, {best[name][0]} before"
            best[name] = (steps, min(secs, best.get(name, (0, float("inf")))[1]))
    steps = {s for name, (s, _) in best.items() if name not in ("vector", "sync")}
    assert len(steps) == 1, f"the three runs stepped different rollouts: {best}"
    rate = {name: s / secs for name, (s, secs) in best.items()}
    report = {
        "protocol": protocol.name,
        "conditions": len(indices),
        "n_envs": args.n_envs,
        "control_steps": steps.pop(),
        "vector_control_steps": best["vector"][0],
        "best_wall_secs": {k: v[1] for k, v in best.items()},
        "steps_per_sec": rate,
        "python_over_per_thread": rate["python"] / rate["per_thread"],
        "python_over_pool": rate["python"] / rate["pool"],
        "vector_over_pool": rate["vector"] / rate["pool"],
        "vector_over_sync": rate["vector"] / rate["sync"],
    }
    if args.json:
        print(json.dumps(report))
        return
    print(f"{report['control_steps']} control steps: {len(indices)} rollouts of {protocol.name}, "
          f"{args.n_envs} at a time, best of {args.repeat}")
    for name in runs:
        print(f"  {name:<11} {best[name][1]:8.3f} s  {rate[name]:10.0f} steps/s")
    print(f"  python / per_thread = {report['python_over_per_thread']:.3f}, "
          f"python / pool = {report['python_over_pool']:.3f}  (target >= 0.8)")
    print(f"  vector / pool = {report['vector_over_pool']:.3f}, vector / sync = {report['vector_over_sync']:.3f}"
          f"  (the vector environments stepped {report['vector_control_steps']} control steps)")


if __name__ == "__main__":
    main()
