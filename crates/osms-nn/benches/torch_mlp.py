"""PyTorch's side of the osms-nn MLP benchmark (run by benches/mlp.rs through scripts/bench-nn).

Same shapes as the Rust side: MLP 64-256-256-256-24, SiLU, batch 256, MSE, Adam, one thread.
Prints `name value` lines; the Rust bench turns them into ratios.
"""

import time

import torch


def best(runs, f):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    torch.set_num_threads(1)
    torch.manual_seed(0)
    sizes = [64, 256, 256, 256, 24]
    layers = []
    for i, (a, b) in enumerate(zip(sizes, sizes[1:])):
        layers.append(torch.nn.Linear(a, b))
        if i + 2 < len(sizes):
            layers.append(torch.nn.SiLU())
    net = torch.nn.Sequential(*layers)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    x = torch.rand(256, 64) * 2 - 1
    y = torch.rand(256, 24) * 2 - 1

    def step():
        opt.zero_grad(set_to_none=True)
        loss = torch.nn.functional.mse_loss(net(x), y)
        loss.backward()
        opt.step()

    for _ in range(5):
        step()
    print("train_step_ms", best(50, step) * 1e3)

    one = x[:1].clone()
    with torch.no_grad():
        for _ in range(20):
            net(one)
        print("infer_us", best(1000, lambda: net(one)) * 1e6)

    a = torch.rand(256, 256)
    b = torch.rand(256, 256)
    print("matmul_256_ms", best(50, lambda: a @ b) * 1e3)
    print("torch_version", torch.__version__)


if __name__ == "__main__":
    main()
