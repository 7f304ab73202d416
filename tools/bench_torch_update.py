#!/usr/bin/env python3
"""Reference speed of the policy's PPO update step in PyTorch on CPU (eager).

The same network, loss, clipping and Adam as tools/bench_jax_update.py (and the Rust trainer,
trainer/src/network.rs): conv 1->16->32->32 (3x3, stride 2, pad 1, ReLU) over a 1x32x32 height
map, flatten (512) ++ state (4), dense 516->128 ReLU, action head 128->15 (5 heads x 3), value
head 128->1. Measures forward + backward + Adam at minibatch 256 (samples/s) and the batch-64
forward under no_grad (samples/s), with torch's own thread count (`--threads` sets it).

Usage (installs its own packages in a virtualenv; PyPI's wheel brings CUDA libraries it does
not use here, `--index-url https://download.pytorch.org/whl/cpu` the CPU-only one):
    python3 -m venv /tmp/torchvenv && /tmp/torchvenv/bin/pip install -r tools/requirements-torch.txt
    /tmp/torchvenv/bin/python tools/bench_torch_update.py [--seconds 10] [--threads 2] [--json]
"""
import argparse
import json
import os
import time

import torch
from torch import nn

MB = 256


class Net(nn.Module):
    def __init__(self):
        super().__init__()
        self.convs = nn.ModuleList(
            [nn.Conv2d(i, o, 3, stride=2, padding=1) for i, o in ((1, 16), (16, 32), (32, 32))]
        )
        self.hidden = nn.Linear(516, 128)
        self.actions = nn.Linear(128, 15)
        self.value = nn.Linear(128, 1)

    def forward(self, heights, states):
        x = heights[:, None, :, :]
        for conv in self.convs:
            x = torch.relu(conv(x))
        x = torch.cat([x.flatten(1), states], dim=1)
        h = torch.relu(self.hidden(x))
        logits = self.actions(h).view(-1, 5, 3)
        return torch.log_softmax(logits, dim=-1), self.value(h)[:, 0]


def loss_fn(net, batch):
    log_probs, values = net(batch["heights"], batch["states"])
    new_lp = (log_probs * batch["one_hot"]).sum(dim=(1, 2))
    ratio = torch.exp(new_lp - batch["old_lp"])
    adv = batch["adv"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    surrogate = torch.minimum(ratio * adv, torch.clamp(ratio, 0.8, 1.2) * adv).mean()
    value_loss = ((values - batch["ret"]) ** 2).mean()
    entropy = -(torch.exp(log_probs) * log_probs).sum(dim=(1, 2)).mean()
    return -surrogate + 0.5 * value_loss - 0.01 * entropy


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    net = Net()
    opt = torch.optim.Adam(net.parameters(), lr=3e-4, eps=1e-5)
    actions = torch.randint(0, 3, (MB, 5))
    batch = {
        "heights": torch.rand(MB, 32, 32) * 0.3,
        "states": torch.rand(MB, 4) * 2 - 1,
        "one_hot": nn.functional.one_hot(actions, 3).float(),
        "old_lp": torch.full((MB,), -5.5),
        "adv": torch.rand(MB) * 2 - 1,
        "ret": torch.rand(MB) * 2 - 1,
    }

    def update():
        opt.zero_grad(set_to_none=True)
        loss = loss_fn(net, batch)
        loss.backward()
        nn.utils.clip_grad_norm_(net.parameters(), 0.5)
        opt.step()

    h64, s64 = batch["heights"][:64], batch["states"][:64]

    def forward():
        with torch.no_grad():
            net(h64, s64)

    def rate(fn, samples):
        for _ in range(5):
            fn()
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            fn()
            n += 1
        return n * samples / (time.perf_counter() - t0)

    result = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpus": os.cpu_count(),
        "update_minibatch_256_samples_per_s": round(rate(update, MB)),
        "forward_batch_64_samples_per_s": round(rate(forward, 64)),
    }
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))


if __name__ == "__main__":
    main()
