"""The slot contract with ``MixedTraffic-v0`` and the per-slot token sequences ``Z_m`` (paper §3.1).

For every observed slot ``m`` in ``(l_1, l_2, l_3, f_1, f_2, f_3)`` the environment reports, at every
step, the occupant's id, its ground-truth style (for training only) and one token of
``len(SLOT_FEATURES)`` numbers in ``info["slots"]``:

=============== ================================================================== ========
feature         meaning                                                            unit
=============== ================================================================== ========
dp              occupant position minus AV position along the road (> 0: ahead)    m
dv              occupant speed minus AV speed                                      m/s
accel           occupant acceleration over the last step                           m/s²
speed           occupant speed                                                     m/s
lane_offset     occupant lane relative to the AV lane (+1 left, -1 right)          lanes
gap_to_leader   occupant's own gap to its leader (capped by the environment)       m
lane_density    vehicles per km on the occupant's lane in the observation window   veh/km
=============== ================================================================== ========

Sequence conventions (:class:`SlotSequences`):

* sequences are right-aligned: index ``ℓ-1`` is the newest token, padding sits on the left and
  is marked ``valid = False``;
* a new occupant (another vehicle id) starts a new sequence of length 1;
* an empty slot has length 0 (all tokens invalid, zeros).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_ua2c.checks import check_int

# Contract with the environment (mirrors ``envs.mixed_traffic``; a test checks they agree).
STYLES: tuple[str, ...] = ("conservative", "neutral", "aggressive")
SLOT_NAMES: tuple[str, ...] = ("l_1", "l_2", "l_3", "f_1", "f_2", "f_3")
SLOT_FEATURES: tuple[str, ...] = (
    "dp",
    "dv",
    "accel",
    "speed",
    "lane_offset",
    "gap_to_leader",
    "lane_density",
)


def valid_mask(lengths: np.ndarray, seq_len: int) -> np.ndarray:
    """Right-aligned validity mask of sequences of the given lengths.

    :param lengths: (n,) number of valid tokens per sequence, in ``[0, seq_len]``
    :param seq_len: sequence length ``ℓ``
    :return: (n, seq_len) bool, ``True`` on the last ``lengths[i]`` positions of row ``i``
    """
    lengths = np.asarray(lengths)
    return np.arange(seq_len)[None, :] >= (seq_len - lengths)[:, None]


class SlotSequences:
    """Per-slot token sequences ``Z_m`` of the current occupants (paper §3.1).

    Call :meth:`update` once per environment step (including the step returned by ``reset``)
    with ``info["slots"]``. Tokens are right-aligned (newest token last) and kept in place; the
    per-slot bookkeeping is plain Python over the ``2H`` slots, so an update costs two array
    copies and a few microseconds.

    :param n_slots: number of slots ``2H``
    :param seq_len: tokens per sequence ``ℓ``
    :param n_features: numbers per token
    """

    def __init__(
        self, n_slots: int = len(SLOT_NAMES), seq_len: int = 20, n_features: int = len(SLOT_FEATURES)
    ):
        for name, value in (("n_slots", n_slots), ("seq_len", seq_len), ("n_features", n_features)):
            check_int(f"SlotSequences: {name}", value)
        self.n_slots, self.seq_len, self.n_features = int(n_slots), int(seq_len), int(n_features)
        #: (n_slots, seq_len, n_features) float32 tokens, zeros where invalid
        self.tokens = np.zeros((self.n_slots, self.seq_len, self.n_features), dtype=np.float32)
        self.ids: list[str] = [""] * self.n_slots
        self._lengths = [0] * self.n_slots
        self._changed = [False] * self.n_slots
        self._vacated = [False] * self.n_slots
        #: True when some slot got a new occupant / became empty at the last update
        self.any_changed = False
        self.any_vacated = False

    def reset(self) -> None:
        """Forget every sequence (call at episode start, before the first :meth:`update`)."""
        self.tokens[:] = 0.0
        self.ids = [""] * self.n_slots
        self._lengths = [0] * self.n_slots
        self._changed = [False] * self.n_slots
        self._vacated = [False] * self.n_slots
        self.any_changed = self.any_vacated = False

    @property
    def lengths(self) -> np.ndarray:
        """(n_slots,) int64 number of valid tokens per slot."""
        return np.array(self._lengths, dtype=np.int64)

    @property
    def valid(self) -> np.ndarray:
        """(n_slots, seq_len) bool mask of valid tokens (right-aligned)."""
        return valid_mask(self.lengths, self.seq_len)

    @property
    def present(self) -> np.ndarray:
        """(n_slots,) bool, True where the slot has an occupant."""
        return self.lengths > 0

    @property
    def changed(self) -> np.ndarray:
        """(n_slots,) bool, True where a new occupant arrived (new sequence) at the last update."""
        return np.array(self._changed, dtype=bool)

    @property
    def vacated(self) -> np.ndarray:
        """(n_slots,) bool, True where the slot became empty at the last update."""
        return np.array(self._vacated, dtype=bool)

    def update(self, ids: Sequence[str], features: np.ndarray, present: Sequence[bool] | np.ndarray) -> None:
        """Append one token per occupied slot.

        :param ids: (n_slots,) vehicle ids, ``""`` for an empty slot
        :param features: (n_slots, n_features) this step's slot features
        :param present: (n_slots,) bool, True where the slot is occupied
        """
        features = np.asarray(features, dtype=np.float32)
        flags = present.tolist() if isinstance(present, np.ndarray) else list(present)
        if features.shape != (self.n_slots, self.n_features):
            raise ValueError(
                f"SlotSequences.update: features must have shape ({self.n_slots}, {self.n_features}), "
                f"got {features.shape}"
            )
        if len(flags) != self.n_slots or len(ids) != self.n_slots:
            raise ValueError(
                f"SlotSequences.update: ids and present must have length {self.n_slots}, "
                f"got {len(ids)} and {len(flags)}"
            )
        tokens, lengths, old_ids, seq_len = self.tokens, self._lengths, self.ids, self.seq_len
        tokens[:, :-1] = tokens[:, 1:]  # shift left: the newest token goes to index seq_len - 1
        tokens[:, -1] = features
        changed, vacated = self._changed, self._vacated
        for m in range(self.n_slots):
            if flags[m]:
                vacated[m] = False
                if lengths[m] and ids[m] == old_ids[m]:  # same occupant: the sequence grows
                    changed[m] = False
                    if lengths[m] < seq_len:
                        lengths[m] += 1
                    continue
                changed[m] = True  # new occupant: a new sequence
                if lengths[m]:
                    tokens[m, :-1] = 0.0
                lengths[m] = 1
            else:
                changed[m] = False
                vacated[m] = lengths[m] > 0
                if vacated[m]:
                    tokens[m, :-1] = 0.0
                tokens[m, -1] = 0.0  # an empty slot holds no token
                lengths[m] = 0
        self.any_changed, self.any_vacated = any(changed), any(vacated)
        self.ids = [i if p else "" for i, p in zip(ids, flags, strict=True)]


def read_slots(
    info: dict, n_slots: int = len(SLOT_NAMES), n_features: int = len(SLOT_FEATURES)
) -> dict[str, Any]:
    """Return ``info["slots"]`` after checking it follows the slot contract of ``MixedTraffic-v0``.

    :param info: the ``info`` dict of ``reset`` or ``step``
    :param n_slots: expected number of slots
    :param n_features: expected features per slot
    :return: the dict with ``ids``, ``styles``, ``features`` (n_slots, n_features), ``present``
    """
    if "slots" not in info:
        raise ValueError(
            "the environment's info has no 'slots' entry (see the MixedTraffic-v0 slot contract)"
        )
    slots = info["slots"]
    for key in ("ids", "styles", "features", "present"):
        if key not in slots:
            raise ValueError(f"info['slots'] lacks the key {key!r}")
    if np.shape(slots["features"]) != (n_slots, n_features):
        raise ValueError(
            f"info['slots']['features'] has shape {np.shape(slots['features'])}, expected ({n_slots}, {n_features})"
        )
    return slots
