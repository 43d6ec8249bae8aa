"""Gymnasium wrappers of sb3-ua2c.

:class:`DrivingStyleContext` appends the driving-style context vector of Eq. 6,
``c_t = [c_t^(l_1), ..., c_t^(l_H), c_t^(f_1), ..., c_t^(f_H)]``, to the observation, so both
the actor and the critics see it (paper §3.1).
"""

from __future__ import annotations

import os
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from envs.style import (
    EMPTY_OUTPUTS,
    SLOT_NAMES,
    DrivingStyleClassifier,
    SlotSequences,
    load_classifier,
    read_slots,
    valid_mask,
)
from sb3_ua2c.checks import check_int


class DrivingStyleContext(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Append the inferred driving styles of the observed slots to a flat ``Box`` observation.

    Every step (and at ``reset``) the wrapper reads ``info["slots"]`` (the slot contract of
    ``MixedTraffic-v0``: ids, features, presence), appends one token to the sequence ``Z_m`` of
    each slot's occupant (a new occupant starts a new sequence), runs the classifier of Eq. 5 on
    the occupied slots in ONE batched forward, and appends the flattened distributions
    ``c_t`` (Eq. 6, slot order ``l_1..l_H, f_1..f_H``, ``2H·C`` numbers) to the observation:
    ``MixedTraffic-v0``'s 20 numbers become 20 + 18 = 38.

    Empty slot: the "no vehicle" output is all zeros (``empty="zeros"``, default; a point off the
    probability simplex, so "no vehicle" differs from "vehicle of unknown style") or the uniform
    distribution (``empty="uniform"``).

    Refresh period: one batched forward costs ~0.2 ms on one CPU thread, about as much as a
    ``MixedTraffic-v0`` step, while a vehicle's style is constant. So the classifier runs every
    ``update_every`` steps (counted from ``reset``, which always runs it) over all occupied
    slots; in between, a slot keeps the distribution of its (same) occupant, and a slot whose
    occupant changed shows the uniform distribution ("vehicle present, style not inferred yet")
    until the next refresh. ``update_every=1`` is Eq. 6 at every step. The default of 10 steps
    (2 s of ``MixedTraffic-v0``) keeps the overhead under ~20% of an env step
    (``benchmarks/bench_style.py``); a new occupant's first ~10 tokens classify least reliably
    anyway.

    Usable from an rl-zoo YAML file::

        env_wrapper:
          - envs.wrappers.DrivingStyleContext:
              classifier: path/to/style_classifier.pt
              update_every: 10

    The wrapper holds no simulator state of its own and pickles with its classifier, so it works
    in ``SubprocVecEnv`` workers. It records its arguments in ``env.spec``, so ``env.spec.make()``
    (Gymnasium's ``check_env`` does) rebuilds the wrapped env.

    :param env: environment with a 1-D ``Box`` observation whose ``info`` carries ``"slots"``
    :param classifier: a :class:`~envs.style.DrivingStyleClassifier`, a path to a file written
        by its ``save``, or ``None`` for the classifier shipped with the package
    :param update_every: refresh period in steps (>= 1) of an unchanged occupant's distribution
    :param empty: "no vehicle" output, ``"zeros"`` or ``"uniform"``
    """

    def __init__(
        self,
        env: gym.Env,
        classifier: DrivingStyleClassifier | str | os.PathLike | None = None,
        update_every: int = 10,
        empty: str = "zeros",
    ):
        gym.utils.RecordConstructorArgs.__init__(self, classifier=classifier, update_every=update_every, empty=empty)
        super().__init__(env)
        check_int("DrivingStyleContext: update_every", update_every)
        if empty not in EMPTY_OUTPUTS:
            raise ValueError(f"DrivingStyleContext: empty must be one of {EMPTY_OUTPUTS}, got {empty!r}")
        obs_space = env.observation_space
        if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
            raise ValueError(f"DrivingStyleContext needs a 1-D Box observation space, got {obs_space!r}")
        self.classifier = load_classifier(classifier)
        self.update_every = int(update_every)
        self.empty = empty
        cfg = self.classifier.config
        self.n_slots, self.n_classes = len(SLOT_NAMES), cfg.n_classes
        self._fill = 0.0 if empty == "zeros" else 1.0 / cfg.n_classes
        self._sequences = SlotSequences(self.n_slots, cfg.seq_len, cfg.n_features)
        #: (n_slots, n_classes) current c^(m), row order = SLOT_NAMES
        self.context = np.full((self.n_slots, self.n_classes), self._fill, dtype=np.float32)
        self._t = 0
        #: number of classifier forward passes so far (each covers all refreshed slots at once)
        self.n_forwards = 0
        n_ctx = self.n_slots * self.n_classes
        dtype = obs_space.dtype
        self.observation_space = spaces.Box(
            low=np.concatenate([obs_space.low.astype(dtype), np.zeros(n_ctx, dtype=dtype)]),
            high=np.concatenate([obs_space.high.astype(dtype), np.ones(n_ctx, dtype=dtype)]),
            dtype=dtype,
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._sequences.reset()
        self.context[:] = self._fill
        self._t = 0
        return self._observation(obs, info), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._observation(obs, info), reward, terminated, truncated, info

    def _observation(self, obs: np.ndarray, info: dict) -> np.ndarray:
        seqs = self._sequences
        slots = read_slots(info, seqs.n_slots, seqs.n_features)
        seqs.update(slots["ids"], slots["features"], slots["present"])
        tick = self._t % self.update_every == 0
        self._t += 1
        if seqs.any_vacated:
            self.context[seqs.vacated] = self._fill
        if tick:
            lengths = seqs.lengths
            rows = np.flatnonzero(lengths)  # occupied slots
            if rows.size:
                self.n_forwards += 1
                valid = valid_mask(lengths[rows], seqs.seq_len)  # (n_present, seq_len)
                with torch.inference_mode():
                    logits = self.classifier(torch.from_numpy(seqs.tokens[rows]), torch.from_numpy(valid))
                    self.context[rows] = logits.softmax(-1).numpy()  # (n_present, C)
        elif seqs.any_changed:
            self.context[seqs.changed] = 1.0 / self.n_classes  # new occupant: style not inferred yet
        # (n_slots, C) -> (n_slots * C,), order l_1..l_H, f_1..f_H as in Eq. 6
        return np.concatenate([np.asarray(obs, dtype=self.observation_space.dtype), self.context.reshape(-1)])
