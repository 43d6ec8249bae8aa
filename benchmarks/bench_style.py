"""Cost of driving-style inference next to its peers, measured in the same run.

1. Classifier forward over the 6 slots (batch of 6 sequences): our compact encoder vs the same
   architecture built from ``torch.nn.TransformerEncoder`` (PyTorch's fused inference path).
2. ``DrivingStyleContext`` per-step overhead vs the environment's own step time, for several
   ``update_every`` values (raw and wrapped steps alternate in blocks on the SAME environment,
   so machine noise hits both alike). Goal: overhead < 20% of the env step.

Usage::

    python benchmarks/bench_style.py                       # MixedTraffic-v0 + packaged classifier
    python benchmarks/bench_style.py --classifier my.pt --steps 3000
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torch import nn

from sb3_ua2c.style import (
    SLOT_FEATURES,
    DrivingStyleClassifier,
    RandomDriver,
    StyleClassifierConfig,
    load_classifier,
    valid_mask,
)
from sb3_ua2c.wrappers import DrivingStyleContext


class _TorchEncoderPeer(nn.Module):
    """Same sizes as DrivingStyleClassifier, built from nn.TransformerEncoder."""

    def __init__(self, c: StyleClassifierConfig):
        super().__init__()
        self.embed = nn.Linear(c.n_features, c.d_model)
        self.position = nn.Parameter(torch.zeros(c.seq_len, c.d_model))
        layer = nn.TransformerEncoderLayer(
            c.d_model, c.n_heads, c.dim_feedforward, dropout=0.0, batch_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, c.n_layers, enable_nested_tensor=False)
        self.head = nn.Linear(c.d_model, c.n_classes)

    def forward(self, tokens: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        h = self.encoder(self.embed(tokens) + self.position, src_key_padding_mask=~valid)
        w = valid.unsqueeze(-1).float()
        return self.head((h * w).sum(1) / w.sum(1).clamp_min(1.0))


def _time_per_call(fn, n: int, repeats: int = 5) -> float:
    """Median over ``repeats`` of the mean seconds per call of ``fn``."""
    for _ in range(max(10, n // 10)):
        fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        out.append((time.perf_counter() - t0) / n)
    return float(np.median(out))


def bench_forward(model: DrivingStyleClassifier, n: int) -> None:
    c = model.config
    rng = np.random.default_rng(0)
    tokens = torch.from_numpy(rng.normal(size=(6, c.seq_len, len(SLOT_FEATURES))).astype(np.float32))
    valid = torch.from_numpy(
        valid_mask(np.array([c.seq_len, c.seq_len, 3, c.seq_len, 1, c.seq_len]), c.seq_len)
    )
    peer = _TorchEncoderPeer(c).eval()
    with torch.inference_mode():
        ours = _time_per_call(lambda: model(tokens, valid), n)
        theirs = _time_per_call(lambda: peer(tokens, valid), n)
    n_params = sum(p.numel() for p in model.parameters())
    # multiply-adds of one forward over 6 slots: embed, qkv, scores, attn·v, out, ffn, head
    t, d, f = c.seq_len, c.d_model, c.dim_feedforward
    macs = 6 * (
        t * c.n_features * d
        + c.n_layers * (t * d * 3 * d + 2 * t * t * d + t * d * d + 2 * t * d * f)
        + d * 3
    )
    print(
        f"classifier: {n_params} parameters, {2 * macs / 1e6:.2f} MFLOP per 6-slot forward "
        f"(seq_len={c.seq_len}, d_model={d}, layers={c.n_layers})"
    )
    print(
        f"  forward over 6 slots: ours {ours * 1e6:8.1f} us | nn.TransformerEncoder peer {theirs * 1e6:8.1f} us "
        f"| ratio ours/peer {ours / theirs:.2f}"
    )


def bench_wrapper(
    env_id: str, classifier: DrivingStyleClassifier, steps: int, block: int, periods: list[int]
) -> None:
    import gymnasium as gym

    import envs  # noqa: F401  (registers MixedTraffic-v0)

    env = gym.make(env_id)
    try:
        driver = RandomDriver(env.action_space, seed=0)
        wrappers = {k: DrivingStyleContext(env, classifier=classifier, update_every=k) for k in periods}
        raw_time, raw_steps = 0.0, 0
        wrap_time = dict.fromkeys(periods, 0.0)
        wrap_steps = dict.fromkeys(periods, 0)
        refreshes = dict.fromkeys(periods, 0)
        obs, _ = env.reset(seed=0)
        for w in wrappers.values():  # same env: each wrapper only needs its own sequences reset
            w._sequences.reset()
        rounds = max(1, steps // block)
        episode = 0

        def run(step_fn, n: int) -> tuple[float, int, bool]:
            nonlocal obs
            t0 = time.perf_counter()
            done, k = False, 0
            while k < n and not done:
                obs, _, term, trunc, _ = step_fn(driver(obs[:20]))
                done, k = term or trunc, k + 1
            return time.perf_counter() - t0, k, done

        for _ in range(rounds):
            for key in [None, *periods]:
                if key is None:
                    dt, k, done = run(env.step, block)
                    raw_time, raw_steps = raw_time + dt, raw_steps + k
                else:
                    w = wrappers[key]
                    before = _count_forwards(w)
                    dt, k, done = run(w.step, block)
                    wrap_time[key] += dt
                    wrap_steps[key] += k
                    refreshes[key] += _count_forwards(w) - before
                if done:
                    episode += 1
                    obs, _ = env.reset(seed=episode)
                    for w in wrappers.values():
                        w._sequences.reset()
        raw = raw_time / raw_steps
        print(f"{env_id}: env step {raw * 1e6:.1f} us ({1 / raw:,.0f} steps/s), {raw_steps} raw steps")
        for key in periods:
            per = wrap_time[key] / wrap_steps[key]
            over = per - raw
            print(
                f"  DrivingStyleContext(update_every={key:>2}): {per * 1e6:7.1f} us/step, overhead "
                f"{over * 1e6:6.1f} us = {100 * over / raw:5.1f}% of the env step; "
                f"forwards on {100 * refreshes[key] / wrap_steps[key]:.0f}% of steps"
            )
    finally:
        env.close()


def _count_forwards(wrapper: DrivingStyleContext) -> int:
    return wrapper.n_forwards


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--classifier", default=None, help="weights file (default: packaged classifier)")
    parser.add_argument("--env", default="MixedTraffic-v0")
    parser.add_argument("--steps", type=int, default=3000, help="steps per variant")
    parser.add_argument("--block", type=int, default=100, help="steps per alternating block")
    parser.add_argument("--periods", type=int, nargs="+", default=[1, 5, 10], help="update_every values")
    parser.add_argument("--forward-calls", type=int, default=2000)
    parser.add_argument("--skip-env", action="store_true", help="only the classifier microbenchmark")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), f"torch {torch.__version__}, 1 thread")
    model = load_classifier(args.classifier)
    bench_forward(model, args.forward_calls)
    if not args.skip_env:
        bench_wrapper(args.env, model, args.steps, args.block, args.periods)


if __name__ == "__main__":
    main()
