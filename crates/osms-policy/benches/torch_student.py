"""PyTorch's side of the student benchmark (run by benches/student.rs through scripts/bench-nn).

Same shapes as the Rust side: velocity MLP 824-256-256-256-192, SiLU, batch 256, the conditional
flow-matching loss (linear path, masked mean squared error), Adam, one thread; and one batch-1
action: 10 Euler steps of the network. Prints `name value` lines.
"""

import math
import time

import torch


def best(runs, f):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def embed(t, dim=32, scale=100.0, max_period=1000.0):
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half) / half)
    arg = (t * scale)[:, None] * freqs[None, :]
    return torch.cat([torch.sin(arg), torch.cos(arg)], dim=1)


def main():
    torch.set_num_threads(1)
    torch.manual_seed(0)
    obs_len, emb, x_len, batch = 600, 32, 192, 256
    sizes = [obs_len + emb + x_len, 256, 256, 256, x_len]
    layers = []
    for i, (a, b) in enumerate(zip(sizes, sizes[1:])):
        layers.append(torch.nn.Linear(a, b))
        if i + 2 < len(sizes):
            layers.append(torch.nn.SiLU())
    net = torch.nn.Sequential(*layers)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    x1 = torch.randn(batch, x_len)
    x0 = torch.randn(batch, x_len)
    cond = torch.randn(batch, obs_len)
    mask = torch.ones(batch, x_len)
    t = torch.rand(batch)

    def step():
        opt.zero_grad(set_to_none=True)
        xt = (1 - t)[:, None] * x0 + t[:, None] * x1
        pred = net(torch.cat([cond, embed(t), xt], dim=1))
        loss = (((pred - (x1 - x0)) * mask) ** 2).sum() / mask.sum()
        loss.backward()
        opt.step()

    for _ in range(5):
        step()
    print("train_step_ms", best(30, step) * 1e3)

    one = cond[:1].clone()

    def act():
        x = torch.randn(1, x_len)
        for k in range(10):
            tk = torch.full((1,), k / 10.0)
            x = x + 0.1 * net(torch.cat([one, embed(tk), x], dim=1))
        return x

    with torch.no_grad():
        for _ in range(20):
            act()
        print("act_us", best(300, act) * 1e6)
    print("torch_version", torch.__version__)


if __name__ == "__main__":
    main()
