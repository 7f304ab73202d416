#!/usr/bin/env python3
"""Reference speed of the policy's PPO update step in JAX on CPU (XLA, jit).

Same network as the Rust trainer (trainer/src/network.rs): conv 1->16->32->32 (3x3, stride 2,
pad 1, ReLU) over a 1x32x32 height map, flatten (512) ++ state (4), dense 516->128 ReLU,
action head 128->15 (5 heads x 3), value head 128->1; the same loss (clipped surrogate, value
MSE, entropy bonus), global-norm clipping and Adam. Measures forward + backward + Adam at
minibatch 256 (samples/s) and batch-64 forward (samples/s).

Usage (installs its own packages in a virtualenv):
    python3 -m venv /tmp/jaxvenv && /tmp/jaxvenv/bin/pip install -r tools/requirements-bench.txt
    /tmp/jaxvenv/bin/python tools/bench_jax_update.py [--seconds 10] [--json]
"""
import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import optax

MB = 256


def init(key):
    def he(key, shape, fan_in):
        bound = (6.0 / fan_in) ** 0.5
        return jax.random.uniform(key, shape, minval=-bound, maxval=bound)

    ks = jax.random.split(key, 6)
    return {
        "c1": (he(ks[0], (16, 1, 3, 3), 9), jnp.zeros(16)),
        "c2": (he(ks[1], (32, 16, 3, 3), 144), jnp.zeros(32)),
        "c3": (he(ks[2], (32, 32, 3, 3), 288), jnp.zeros(32)),
        "h": (he(ks[3], (516, 128), 516), jnp.zeros(128)),
        "a": (0.01 * he(ks[4], (128, 15), 128), jnp.zeros(15)),
        "v": (he(ks[5], (128, 1), 128), jnp.zeros(1)),
    }


def forward(p, heights, states):
    x = heights[:, None, :, :]
    for name in ("c1", "c2", "c3"):
        w, b = p[name]
        x = jax.lax.conv_general_dilated(x, w, (2, 2), ((1, 1), (1, 1)), dimension_numbers=("NCHW", "OIHW", "NCHW"))
        x = jax.nn.relu(x + b[None, :, None, None])
    x = jnp.concatenate([x.reshape(x.shape[0], -1), states], axis=1)
    h = jax.nn.relu(x @ p["h"][0] + p["h"][1])
    logits = (h @ p["a"][0] + p["a"][1]).reshape(-1, 5, 3)
    value = (h @ p["v"][0] + p["v"][1])[:, 0]
    return jax.nn.log_softmax(logits, axis=-1), value


def loss_fn(p, batch):
    log_probs, values = forward(p, batch["heights"], batch["states"])
    new_lp = jnp.sum(log_probs * batch["one_hot"], axis=(1, 2))
    ratio = jnp.exp(new_lp - batch["old_lp"])
    adv = batch["adv"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 0.8, 1.2) * adv).mean()
    value_loss = jnp.mean((values - batch["ret"]) ** 2)
    entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=(1, 2)).mean()
    return -surrogate + 0.5 * value_loss - 0.01 * entropy


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    key = jax.random.PRNGKey(0)
    params = init(key)
    opt = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(3e-4, eps=1e-5))
    opt_state = opt.init(params)
    k = jax.random.split(key, 6)
    actions = jax.random.randint(k[0], (MB, 5), 0, 3)
    batch = {
        "heights": jax.random.uniform(k[1], (MB, 32, 32), maxval=0.3),
        "states": jax.random.uniform(k[2], (MB, 4), minval=-1, maxval=1),
        "one_hot": jax.nn.one_hot(actions, 3),
        "old_lp": jnp.full((MB,), -5.5),
        "adv": jax.random.uniform(k[3], (MB,), minval=-1, maxval=1),
        "ret": jax.random.uniform(k[4], (MB,), minval=-1, maxval=1),
    }

    @jax.jit
    def step(params, opt_state, batch):
        loss, grads = jax.value_and_grad(loss_fn)(params, batch)
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    fwd = jax.jit(forward)
    h64, s64 = batch["heights"][:64], batch["states"][:64]

    def rate(fn, samples):
        for _ in range(5):
            jax.block_until_ready(fn())
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            jax.block_until_ready(fn())
            n += 1
        return n * samples / (time.perf_counter() - t0)

    state = {"p": params, "o": opt_state}

    def update():
        state["p"], state["o"], loss = step(state["p"], state["o"], batch)
        return loss

    update_rate = rate(update, MB)
    forward_rate = rate(lambda: fwd(state["p"], h64, s64), 64)
    result = {
        "jax": jax.__version__,
        "cpus": os.cpu_count(),
        "update_minibatch_256_samples_per_s": round(update_rate),
        "forward_batch_64_samples_per_s": round(forward_rate),
    }
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))


if __name__ == "__main__":
    main()
