"""How well the flow actor fits the offline chunks: velocity-field sizes side by side, against the data.

Usage::

    python -m experiments flow-fit DATASET_DIR [--net-arch 128,128 256,256,256] [--steps 6000]
        [--chunk-size 5] [--flow-steps 10 2]

For every ``net_arch`` it trains the velocity field of a fresh ``UA2C`` on the dataset's k-step
windows with the flow-matching term of Eq. 2 alone (λ = 0: no critic, so the fit is what is
measured), then samples 32 chunks per history for 2,000 full windows of the same dataset and
prints, in SB3's normalised action units, the mean |step change| of the first action dim inside a
chunk and from a_{t-1} into the chunk, next to the same numbers for the logged chunks (the peer:
a perfect fit reproduces them), and the ratio. An under-fitted flow leaves noise in every chunk
position, which shows as in-chunk jerk in closed loop.
"""

from __future__ import annotations

import argparse
import time

import torch as th

from envs.collection import TRAFFIC_DEFAULTS, make_traffic_env
from sb3_ua2c import UA2C
from sb3_ua2c.flow import flow_matching_loss, interpolate
from sb3_ua2c.offline import load_dataset
from sb3_ua2c.pipeline import env_settings


def step_changes(chunks: th.Tensor, previous: th.Tensor) -> tuple[float, float]:
    """Mean |x[u+1] - x[u]| inside chunks (..., k) and mean |x[0] - a_{t-1}| for previous (B,) broadcast."""
    inside = (chunks[..., 1:] - chunks[..., :-1]).abs().mean().item()
    first = (chunks[..., 0] - previous.reshape(previous.shape + (1,) * (chunks.ndim - 2))).abs().mean().item()
    return inside, first


def fit(env, episodes, net_arch: list[int], chunk_size: int, steps: int, seed: int) -> tuple[UA2C, float, float]:
    """Train the velocity field alone for ``steps`` steps; return the model, the last loss and the seconds."""
    kwargs = {**TRAFFIC_DEFAULTS, "chunk_size": chunk_size, "policy_kwargs": {"net_arch": net_arch}}
    model = UA2C("MlpPolicy", env, seed=seed, device="cpu", **kwargs)
    model.add_offline_episodes(episodes)
    policy, actor = model.policy, model.policy.actor
    start, loss = time.perf_counter(), th.zeros(())
    for _ in range(steps):
        data = model.replay_buffer.sample(model.batch_size)
        x1 = data.chunks  # (B, k, A)
        x0, tau = th.randn_like(x1), th.rand(x1.shape[0])
        cond = policy.condition(data.observation_history, data.action_history)
        loss = flow_matching_loss(actor(interpolate(x0, x1, tau), tau, cond), x0, x1)
        actor.optimizer.zero_grad()
        loss.backward()
        actor.optimizer.step()
    return model, loss.item(), time.perf_counter() - start


def main(argv: list[str] | None = None, prog: str | None = None) -> None:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", help="an offline dataset directory (sb3_ua2c.offline)")
    parser.add_argument("--net-arch", nargs="+", default=["128,128", "256,256,256"], help="comma-separated sizes")
    parser.add_argument("--steps", type=int, default=6000, help="gradient steps per velocity field")
    parser.add_argument("--chunk-size", type=int, default=5)
    parser.add_argument("--flow-steps", type=int, nargs="+", default=[10, 2], help="Euler steps N when sampling")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    ds = load_dataset(args.dataset)
    env = make_traffic_env(**env_settings(ds))
    try:
        rows = []
        for arch in args.net_arch:
            net_arch = [int(h) for h in arch.split(",")]
            th.manual_seed(args.seed)
            model, loss, seconds = fit(env, ds.episodes, net_arch, args.chunk_size, args.steps, args.seed)
            th.manual_seed(args.seed + 1)  # the same evaluation windows and noise for every size
            data = model.replay_buffer.sample(2000)
            full = data.horizons == args.chunk_size  # windows that do not end with the episode
            previous = data.action_history[full][:, -1, 0]  # a_{t-1}, first action dim, (B,)
            data_inside, data_first = step_changes(data.chunks[full][..., 0], previous)
            policy = model.policy
            with th.no_grad():
                obs_h, act_h = data.observation_history[full], data.action_history[full]
                for n in args.flow_steps:
                    chunks = policy.sample_chunks(obs_h, act_h, 32, n).clamp(-1.0, 1.0)[..., 0]  # (B, 32, k)
                    inside, first = step_changes(chunks, previous)
                    rows.append((arch, n, loss, seconds, inside, first, data_inside, data_first))
        print(f"{'net_arch':>14} {'N':>3} {'flow loss':>9} {'train s':>8} {'in-chunk':>9} {'data':>7} {'ratio':>6}"
              f" {'into chunk':>10} {'data':>7} {'ratio':>6}")
        for arch, n, loss, seconds, inside, first, d_in, d_first in rows:
            print(f"{arch:>14} {n:>3} {loss:9.4f} {seconds:8.1f} {inside:9.4f} {d_in:7.4f} {inside / d_in:6.2f}"
                  f" {first:10.4f} {d_first:7.4f} {first / d_first:6.2f}")
    finally:
        env.close()
