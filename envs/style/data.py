"""Labelled slot sequences for the style classifier: the dataset, its split by episode, and their
collection from ``MixedTraffic-v0`` (paper §4.4).

Importing this module never needs SUMO; only :func:`collect_style_dataset` builds the environment.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from envs.style.sequences import SLOT_FEATURES, SLOT_NAMES, STYLES, SlotSequences, read_slots
from sb3_ua2c.checks import check_int


@dataclass
class StyleDataset:
    """Labelled slot sequences.

    :param tokens: (n, seq_len, n_features) float32, right-aligned
    :param valid: (n, seq_len) bool
    :param labels: (n,) int64 ground-truth style index
    :param episodes: (n,) int64 episode index (the split unit)
    :param slots: (n,) int64 slot index in ``SLOT_NAMES``
    :param meta: JSON-serialisable description (features, styles, collection settings)
    """

    tokens: np.ndarray
    valid: np.ndarray
    labels: np.ndarray
    episodes: np.ndarray
    slots: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.tokens = np.asarray(self.tokens, dtype=np.float32)
        self.valid = np.asarray(self.valid, dtype=bool)
        self.labels = np.asarray(self.labels, dtype=np.int64)
        self.episodes = np.asarray(self.episodes, dtype=np.int64)
        self.slots = np.asarray(self.slots, dtype=np.int64)
        n = self.tokens.shape[0]
        if self.tokens.ndim != 3:
            raise ValueError(
                f"StyleDataset: tokens must be (n, seq_len, n_features), got {self.tokens.shape}"
            )
        if self.valid.shape != self.tokens.shape[:2]:
            raise ValueError(f"StyleDataset: valid must be {self.tokens.shape[:2]}, got {self.valid.shape}")
        for name in ("labels", "episodes", "slots"):
            if getattr(self, name).shape != (n,):
                raise ValueError(
                    f"StyleDataset: {name} must have shape ({n},), got {getattr(self, name).shape}"
                )
        if n and (self.labels.min() < 0):
            raise ValueError("StyleDataset: labels must be >= 0 (empty slots are not samples)")
        if n and not self.valid.any(1).all():
            raise ValueError("StyleDataset: every sample needs at least one valid token")

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    @property
    def lengths(self) -> np.ndarray:
        """(n,) number of valid tokens per sample."""
        return self.valid.sum(1)

    def subset(self, index: np.ndarray) -> StyleDataset:
        """:param index: integer or boolean index of the samples to keep"""
        return StyleDataset(
            self.tokens[index],
            self.valid[index],
            self.labels[index],
            self.episodes[index],
            self.slots[index],
            dict(self.meta),
        )

    def truncate(self, seq_len: int) -> StyleDataset:
        """The same samples with only their last ``seq_len`` tokens (a shorter history ``ℓ``).

        :param seq_len: new sequence length, at most the current one
        """
        check_int("StyleDataset.truncate: seq_len", seq_len)
        if seq_len > self.tokens.shape[1]:
            raise ValueError(
                f"StyleDataset.truncate: seq_len={seq_len} exceeds the stored {self.tokens.shape[1]}"
            )
        # sequences are right-aligned: the newest token is last and always valid
        return StyleDataset(
            self.tokens[:, -seq_len:],
            self.valid[:, -seq_len:],
            self.labels,
            self.episodes,
            self.slots,
            {**self.meta, "seq_len": seq_len},
        )

    def save(self, path: str | os.PathLike) -> None:
        """Save to a compressed ``.npz`` (meta as JSON).

        :param path: destination file
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            path,
            tokens=self.tokens,
            valid=self.valid,
            labels=self.labels,
            episodes=self.episodes,
            slots=self.slots,
            meta=np.array(json.dumps(self.meta)),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> StyleDataset:
        """:param path: file written by :meth:`save`"""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"dataset file not found: {str(path)!r}")
        with np.load(path, allow_pickle=False) as data:
            missing = {"tokens", "valid", "labels", "episodes", "slots"} - set(data.files)
            if missing:
                raise ValueError(f"{str(path)!r} is not a style dataset: missing arrays {sorted(missing)}")
            meta = json.loads(str(data["meta"])) if "meta" in data.files else {}
            return cls(data["tokens"], data["valid"], data["labels"], data["episodes"], data["slots"], meta)


def split_by_episode(
    episodes: np.ndarray, val_fraction: float = 0.15, test_fraction: float = 0.15, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split sample indices into train/validation/test so that no episode spans two parts.

    Episodes are shuffled with ``seed``; the test and validation parts get
    ``max(1, round(fraction * n_episodes))`` episodes each, the training part the rest.

    :param episodes: (n,) episode index of each sample
    :param val_fraction: fraction of episodes for validation
    :param test_fraction: fraction of episodes for the test set
    :param seed: shuffle seed
    :return: three sorted int64 index arrays (train, validation, test)
    """
    episodes = np.asarray(episodes)
    unique = np.unique(episodes)
    if unique.size < 3:
        raise ValueError(f"split_by_episode: need at least 3 distinct episodes, got {unique.size}")
    for name, value in (("val_fraction", val_fraction), ("test_fraction", test_fraction)):
        if not (0.0 < value < 1.0):
            raise ValueError(f"split_by_episode: {name} must be in (0, 1), got {value!r}")
    order = np.random.default_rng(seed).permutation(unique)
    n_test = max(1, round(test_fraction * unique.size))
    n_val = max(1, round(val_fraction * unique.size))
    if n_test + n_val >= unique.size:
        raise ValueError(
            f"split_by_episode: {unique.size} episodes leave none for training "
            f"(val_fraction={val_fraction}, test_fraction={test_fraction})"
        )
    test_eps, val_eps = order[:n_test], order[n_test : n_test + n_val]
    test = np.flatnonzero(np.isin(episodes, test_eps))
    val = np.flatnonzero(np.isin(episodes, val_eps))
    train = np.flatnonzero(~np.isin(episodes, np.concatenate([test_eps, val_eps])))
    return train, val, test


class RandomDriver:
    """Behaviour policy of the AV during data collection: keeps a random acceleration for a few
    steps and changes lane now and then, so the slots see varied interactions.

    Actions follow the env's ``Box(2)``: ``[acceleration, lane change]`` in the action space's
    bounds; a lane change is a value beyond ±1/3 of the second component's half-range.

    :param action_space: the env's ``Box`` action space
    :param hold_steps: steps each random acceleration is held
    :param lane_change_prob: probability per step of requesting a lane change
    :param seed: random seed
    """

    def __init__(
        self, action_space: Any, hold_steps: int = 10, lane_change_prob: float = 0.01, seed: int = 0
    ):
        low = np.asarray(action_space.low, dtype=np.float32)
        high = np.asarray(action_space.high, dtype=np.float32)
        if low.shape != (2,):
            raise ValueError(f"RandomDriver expects a Box(2) action space, got shape {low.shape}")
        check_int("RandomDriver: hold_steps", hold_steps)
        self.low, self.high = low, high
        self.hold_steps, self.lane_change_prob = hold_steps, float(lane_change_prob)
        self.rng = np.random.default_rng(seed)
        self._accel, self._left = 0.0, 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self._left <= 0:
            self._accel = float(self.rng.uniform(self.low[0], self.high[0]))
            self._left = self.hold_steps
        self._left -= 1
        mid = 0.5 * (self.low[1] + self.high[1])
        lane = mid
        if self.rng.random() < self.lane_change_prob:
            lane = self.low[1] if self.rng.random() < 0.5 else self.high[1]
        return np.array([self._accel, lane], dtype=np.float32)


def _episode_options(episode: int, sumo_driver_fraction: float) -> dict[str, str] | None:
    """Reset options of episode ``episode``: who drives the AV (``None`` when the fraction is 0).

    Deterministic interleaving: episode ``e`` is SUMO-driven when the running share lags behind
    ``sumo_driver_fraction``.
    """
    if sumo_driver_fraction <= 0:
        return None
    sumo = math.floor((episode + 1) * sumo_driver_fraction) > math.floor(episode * sumo_driver_fraction)
    return {"ego_controller": "sumo" if sumo else "agent"}


def _record_episode(
    env: Any,
    driver: Callable[[np.ndarray], np.ndarray],
    seqs: SlotSequences,
    out: dict[str, list],
    episode: int,
    reset_kwargs: dict[str, Any],
    stride: int,
    min_length: int,
    max_steps: int | None,
) -> int:
    """Run one episode and append its samples to ``out`` (one list entry per sampling step).

    :return: the number of environment steps taken
    """
    obs, info = env.reset(**reset_kwargs)
    seqs.reset()
    t, done = 0, False
    while True:
        slots = read_slots(info, seqs.n_slots, seqs.n_features)
        seqs.update(slots["ids"], slots["features"], slots["present"])
        if t % stride == 0:
            styles = np.asarray(slots["styles"])
            take = np.flatnonzero((seqs.lengths >= min_length) & (styles >= 0))
            if take.size:
                valid = seqs.valid
                out["tokens"].append(seqs.tokens[take].copy())  # (n_take, seq_len, n_features)
                out["valid"].append(valid[take])
                out["labels"].append(styles[take].astype(np.int64))
                out["episodes"].append(np.full(take.size, episode, dtype=np.int64))
                out["slots"].append(take.astype(np.int64))
        if done or (max_steps is not None and t >= max_steps):
            return t
        obs, _, terminated, truncated, info = env.step(driver(obs))
        done = terminated or truncated
        t += 1


def collect_style_dataset(
    n_episodes: int,
    env_id: str = "MixedTraffic-v0",
    seq_len: int = 20,
    stride: int = 5,
    min_length: int = 1,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    policy: Callable[[np.ndarray], np.ndarray] | None = None,
    max_steps_per_episode: int | None = None,
    sumo_driver_fraction: float = 0.5,
    progress_bar: bool = True,
) -> StyleDataset:
    """Roll out the environment and record labelled slot sequences.

    Every ``stride`` steps, each occupied slot whose occupant has a ground-truth style gives one
    sample: its current sequence ``Z_m`` (``seq_len`` tokens, right-aligned, shorter sequences
    padded) and the style label from ``info["slots"]["styles"]``. Episode ``e`` is reset with
    seed ``seed + e``.

    :param n_episodes: number of episodes
    :param env_id: gymnasium id (``import envs`` registers ``MixedTraffic-v0``)
    :param seq_len: tokens per sequence ``ℓ``
    :param stride: sampling period in steps (consecutive samples of a slot overlap less)
    :param min_length: skip sequences with fewer valid tokens
    :param seed: base seed of the episodes and the behaviour policy
    :param env_kwargs: keyword arguments of ``gym.make``
    :param policy: AV behaviour ``obs -> action``; default :class:`RandomDriver`
    :param max_steps_per_episode: cut episodes longer than this
    :param sumo_driver_fraction: fraction of episodes in which SUMO's own driver model drives
        the AV (reset option ``{"ego_controller": "sumo"}`` of ``MixedTraffic-v0``; it merges
        and follows traffic like an HDV); the other episodes use ``policy``. Use 0 for an
        environment without that option.
    :param progress_bar: show a tqdm progress bar over episodes
    """
    import gymnasium as gym

    check_int("collect_style_dataset: n_episodes", n_episodes)
    check_int("collect_style_dataset: seq_len", seq_len)
    check_int("collect_style_dataset: stride", stride)
    if not (0.0 <= sumo_driver_fraction <= 1.0):
        raise ValueError(
            f"collect_style_dataset: sumo_driver_fraction must be in [0, 1], got {sumo_driver_fraction!r}"
        )
    if not (1 <= min_length <= seq_len):
        raise ValueError(f"collect_style_dataset: min_length must be in [1, seq_len], got {min_length}")
    if env_id == "MixedTraffic-v0":
        import envs  # noqa: F401  (registers the id)

    env = gym.make(env_id, **(env_kwargs or {}))
    driver = policy if policy is not None else RandomDriver(env.action_space, seed=seed)
    seqs = SlotSequences(len(SLOT_NAMES), seq_len, len(SLOT_FEATURES))
    out: dict[str, list] = {"tokens": [], "valid": [], "labels": [], "episodes": [], "slots": []}
    steps = 0
    iterator: Any = range(n_episodes)
    if progress_bar:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc="collect", unit="ep")
    try:
        for episode in iterator:
            reset_kwargs = {
                "seed": seed + episode,
                "options": _episode_options(episode, sumo_driver_fraction),
            }
            steps += _record_episode(
                env, driver, seqs, out, episode, reset_kwargs, stride, min_length, max_steps_per_episode
            )
            if progress_bar:
                iterator.set_postfix(samples=sum(len(x) for x in out["labels"]), steps=steps)
    finally:
        env.close()
    if not out["labels"]:
        raise ValueError(
            "collect_style_dataset: the episodes produced no labelled slot (no HDV around the AV)"
        )
    meta = {
        "env_id": env_id,
        "n_episodes": n_episodes,
        "seq_len": seq_len,
        "stride": stride,
        "seed": seed,
        "env_kwargs": env_kwargs or {},
        "sumo_driver_fraction": sumo_driver_fraction,
        "features": list(SLOT_FEATURES),
        "styles": list(STYLES),
        "slot_names": list(SLOT_NAMES),
        "env_steps": steps,
    }
    return StyleDataset(
        *(np.concatenate(out[k]) for k in ("tokens", "valid", "labels", "episodes", "slots")), meta
    )
