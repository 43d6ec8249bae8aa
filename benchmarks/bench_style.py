"""Cost of driving-style inference next to its peers, measured in the same run.

1. Classifier forward over the 6 slots (batch of 6 sequences): our compact encoder vs the same
   architecture built from ``torch.nn.TransformerEncoder`` (PyTorch's fused inference path).
2. ``DrivingStyleContext`` per-step overhead vs the environment's own step time, for several
   ``update_every`` values: every real step is timed, then its transition is replayed through
   each wrapper (and through a plain ``gym.Wrapper`` peer whose cost is subtracted), so the
   overhead and the env step are measured on the same steps. Goal: overhead < 20% of the step.

Usage::

    python benchmarks/bench_style.py                       # MixedTraffic-v0 + packaged classifier
    python benchmarks/bench_style.py --classifier my.pt --steps 3000
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from envs.style import (
    SLOT_FEATURES,
    DrivingStyleClassifier,
    RandomDriver,
    StyleClassifierConfig,
    load_classifier,
    valid_mask,
)
from envs.wrappers import DrivingStyleContext


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


def _interleaved_times(fns: list, n: int, repeats: int = 7) -> list[float]:
    """Median seconds per call of each function, the functions alternating in every repeat so
    that machine noise hits them alike."""
    for fn in fns:
        for _ in range(max(10, n // 10)):
            fn()
    samples: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            samples[k].append((time.perf_counter() - t0) / n)
    return [float(np.median(s)) for s in samples]


def bench_forward(model: DrivingStyleClassifier, n: int) -> None:
    c = model.config
    rng = np.random.default_rng(0)
    tokens = torch.from_numpy(rng.normal(size=(6, c.seq_len, len(SLOT_FEATURES))).astype(np.float32))
    lengths = np.array([c.seq_len, c.seq_len, 3, c.seq_len, 1, c.seq_len])
    valid = torch.from_numpy(valid_mask(lengths, c.seq_len))
    peer = _TorchEncoderPeer(c).eval()
    with torch.inference_mode():
        ours, theirs = _interleaved_times([lambda: model(tokens, valid), lambda: peer(tokens, valid)], n)
    n_params = sum(p.numel() for p in model.parameters())
    # multiply-adds of one forward over 6 slots: embed, qkv, scores, attn·v, out, ffn, head
    t, d, f = c.seq_len, c.d_model, c.dim_feedforward
    macs = 6 * (
        t * c.n_features * d
        + c.n_layers * (3 * t * d * d + 2 * t * t * d + t * d * d + 2 * t * d * f)
        + d * 3
    )
    print(
        f"classifier: {n_params} parameters, {2 * macs / 1e6:.2f} MFLOP per 6-slot forward "
        f"(seq_len={c.seq_len}, d_model={d}, layers={c.n_layers})"
    )
    print(
        f"  forward over 6 slots: ours {ours * 1e6:8.1f} us | nn.TransformerEncoder peer {theirs * 1e6:8.1f} us "
        f"| ratio ours/peer {ours / theirs:.2f} | {2 * macs / ours / 1e9:.2f} GFLOP/s"
    )


class _Replay(gym.Env):
    """Returns the transition it was loaded with: lets a wrapper process the real env's output
    without stepping the simulator a second time."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space):
        self.observation_space, self.action_space = observation_space, action_space
        self._next: tuple = ()

    def load(self, transition: tuple) -> None:
        self._next = transition

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple:
        return self._next

    def step(self, action: np.ndarray) -> tuple:
        return self._next


def bench_wrapper(
    env_id: str, classifier: DrivingStyleClassifier, steps: int, periods: list[int], sumo_driver: bool
) -> None:
    """Per step: time the real env step, then feed the same transition to each wrapper (and to a
    plain ``gym.Wrapper``, whose cost is subtracted) and time it."""
    import envs  # noqa: F401  (registers MixedTraffic-v0)

    env = gym.make(env_id)
    try:
        driver = RandomDriver(env.action_space, seed=0)
        variants: dict[str, tuple[_Replay, gym.Env]] = {}
        for key in ["peer", *periods]:
            replay = _Replay(env.observation_space, env.action_space)
            if key == "peer":
                variants[key] = (replay, gym.Wrapper(replay))
            else:
                variants[key] = (replay, DrivingStyleContext(replay, classifier=classifier, update_every=key))
        times = dict.fromkeys(variants, 0.0)
        env_time, episode, n = 0.0, 0, 0
        # SUMO's driver merges and follows traffic, so the slots are as busy as under a trained policy
        options = {"ego_controller": "sumo"} if sumo_driver else None
        obs, info = env.reset(seed=0, options=options)
        for replay, w in variants.values():
            replay.load((obs, info))
            w.reset()
        while n < steps:
            action = driver(obs)
            t0 = time.perf_counter()
            out = env.step(action)
            env_time += time.perf_counter() - t0
            n += 1
            for key, (replay, w) in variants.items():
                replay.load(out)
                t0 = time.perf_counter()
                w.step(action)
                times[key] += time.perf_counter() - t0
            obs = out[0]
            if out[2] or out[3]:
                episode += 1
                obs, info = env.reset(seed=episode, options=options)
                for replay, w in variants.values():
                    replay.load((obs, info))
                    w.reset()
        raw = env_time / n
        print(
            f"{env_id}: env step {raw * 1e6:.1f} us ({1 / raw:,.0f} steps/s) over {n} steps, {episode} resets"
        )
        for key in periods:
            over = (times[key] - times["peer"]) / n
            w = variants[key][1]
            print(
                f"  DrivingStyleContext(update_every={key:>2}): overhead {over * 1e6:6.1f} us/step "
                f"= {100 * over / raw:5.1f}% of the env step; one forward per {n / max(w.n_forwards, 1):.1f} steps"
            )
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--classifier", default=None, help="weights file (default: packaged classifier)")
    parser.add_argument("--env", default="MixedTraffic-v0")
    parser.add_argument("--steps", type=int, default=3000, help="steps per variant")
    parser.add_argument("--periods", type=int, nargs="+", default=[1, 5, 10], help="update_every values")
    parser.add_argument("--forward-calls", type=int, default=2000)
    parser.add_argument(
        "--random-driver",
        action="store_true",
        help="drive the AV randomly instead of by SUMO (emptier slots)",
    )
    parser.add_argument("--skip-env", action="store_true", help="only the classifier microbenchmark")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), f"torch {torch.__version__}, 1 thread")
    model = load_classifier(args.classifier)
    bench_forward(model, args.forward_calls)
    if not args.skip_env:
        bench_wrapper(args.env, model, args.steps, args.periods, sumo_driver=not args.random_driver)


if __name__ == "__main__":
    main()
