"""Driving-style inference (paper §3.1 "Driving-Style Inference Module", Eq. 5, and §4.4).

For every observed slot ``m`` in ``(l_1, l_2, l_3, f_1, f_2, f_3)`` the module keeps the token
sequence ``Z_m = [z_{t-ℓ+1}, ..., z_t]`` of the vehicle currently in that slot and a small
Transformer encoder maps it to a categorical distribution over the ``C`` driving styles,
``c_t^(m) = softmax(f_ψ(Z_m))``. The classifier is trained with the cross-entropy of Eq. 5.

Tokens (one per simulation step, ``len(SLOT_FEATURES)`` numbers each) are the slot features the
environment reports in ``info["slots"]["features"]``:

=============== ================================================================== ========
feature         meaning                                                            unit
=============== ================================================================== ========
dp              occupant position minus AV position along the road (> 0: ahead)   m
dv              occupant speed minus AV speed                                      m/s
accel           occupant acceleration over the last step                           m/s²
speed           occupant speed                                                     m/s
lane_offset     occupant lane relative to the AV lane (+1 left, -1 right)          lanes
gap_to_leader   occupant's own gap to its leader (capped by the environment)      m
lane_density    vehicles per km on the occupant's lane in the observation window   veh/km
=============== ================================================================== ========

Sequence conventions (:class:`SlotSequences`):

* sequences are right-aligned: index ``ℓ-1`` is the newest token, padding sits on the left and
  is marked ``valid = False``;
* a new occupant (another vehicle id) starts a new sequence of length 1;
* an empty slot has length 0 (all tokens invalid, zeros). The classifier never sees such a row:
  :meth:`DrivingStyleClassifier.predict_proba` returns a documented "no vehicle" output for it
  (all zeros by default, or the uniform distribution).

The module also holds dataset collection from the environment, a split by episode, training with
early stopping, evaluation (accuracy, per-class precision/recall, confusion matrix with rows =
inferred and columns = ground truth, as in the paper's Fig. 2d), a logistic-regression baseline
on summary features, and a command-line interface::

    python -m sb3_ua2c.style collect  --out style_data.npz          # 1500 episodes, ~5 min
    python -m sb3_ua2c.style train    --data style_data.npz --out style_classifier.pt
    python -m sb3_ua2c.style evaluate --data style_data.npz --model style_classifier.pt
    # -> results/style_eval.json, results/style_confusion.png

The classifier shipped in ``sb3_ua2c/data/style_classifier.pt`` was made by these three
commands with their defaults.

Importing this module never needs SUMO; only :func:`collect_style_dataset` builds the
environment.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from sb3_ua2c.checks import check_int

# --------------------------------------------------------------------------------------------
# Contract with the environment (mirrors ``envs.mixed_traffic``; a test checks they agree).
# --------------------------------------------------------------------------------------------
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

#: file of the trained classifier shipped with the package (may be absent in a source checkout)
DEFAULT_CLASSIFIER_PATH = Path(__file__).resolve().parent / "data" / "style_classifier.pt"

EMPTY_OUTPUTS = ("zeros", "uniform")
_CHECKPOINT_FORMAT = 1


# --------------------------------------------------------------------------------------------
# Configs
# --------------------------------------------------------------------------------------------
def _config_from_dict(cls: type, values: dict[str, Any]) -> Any:
    """Build the frozen dataclass ``cls`` from ``values``; an unknown key raises ``ValueError``."""
    if not isinstance(values, dict):
        raise ValueError(f"{cls.__name__}: expected a dict, got {type(values).__name__}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown key(s) {unknown}; valid keys are {sorted(known)}")
    return cls(**values)


@dataclass(frozen=True)
class StyleClassifierConfig:
    """Architecture of :class:`DrivingStyleClassifier`.

    :param n_features: numbers per token (``len(SLOT_FEATURES)`` for ``MixedTraffic-v0``)
    :param n_classes: number of driving styles ``C``
    :param seq_len: number of tokens ``ℓ`` per slot sequence
    :param d_model: width of the Transformer
    :param n_heads: attention heads (must divide ``d_model``)
    :param n_layers: encoder layers
    :param dim_feedforward: hidden width of each layer's feed-forward block
    :param dropout: dropout inside the encoder during training
    """

    n_features: int = len(SLOT_FEATURES)
    n_classes: int = len(STYLES)
    seq_len: int = 20
    d_model: int = 32
    n_heads: int = 2
    n_layers: int = 1
    dim_feedforward: int = 64
    dropout: float = 0.0

    def __post_init__(self) -> None:
        for name in ("n_features", "seq_len", "d_model", "n_heads", "n_layers", "dim_feedforward"):
            check_int(f"StyleClassifierConfig: {name}", getattr(self, name))
        check_int("StyleClassifierConfig: n_classes", self.n_classes, low=2)
        if self.d_model % self.n_heads != 0:
            raise ValueError(
                f"StyleClassifierConfig: n_heads={self.n_heads} must divide d_model={self.d_model}"
            )
        if not (0.0 <= float(self.dropout) < 1.0):
            raise ValueError(f"StyleClassifierConfig: dropout must be in [0, 1), got {self.dropout!r}")

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> StyleClassifierConfig:
        """:param values: keys of this dataclass; an unknown key raises ``ValueError``."""
        return _config_from_dict(cls, values)


@dataclass(frozen=True)
class StyleTrainConfig:
    """Training of the style classifier (Eq. 5) with early stopping on the validation loss.

    :param learning_rate: Adam learning rate
    :param batch_size: minibatch size
    :param max_epochs: upper bound on epochs
    :param patience: epochs without validation-loss improvement before stopping
    :param weight_decay: AdamW weight decay
    :param val_fraction: fraction of EPISODES used for validation
    :param test_fraction: fraction of EPISODES held out for the test set
    :param class_weighted: weight the cross-entropy by inverse class frequency (useful when the
        styles are unbalanced; plain Eq. 5 when ``False``)
    :param seed: seed of the split, initialisation and minibatch order
    """

    learning_rate: float = 2e-3
    batch_size: int = 256
    max_epochs: int = 60
    patience: int = 8
    weight_decay: float = 1e-4
    val_fraction: float = 0.15
    test_fraction: float = 0.15
    class_weighted: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("batch_size", "max_epochs", "patience"):
            check_int(f"StyleTrainConfig: {name}", getattr(self, name))
        if not (self.learning_rate > 0 and math.isfinite(self.learning_rate)):
            raise ValueError(f"StyleTrainConfig: learning_rate must be > 0, got {self.learning_rate!r}")
        if self.weight_decay < 0:
            raise ValueError(f"StyleTrainConfig: weight_decay must be >= 0, got {self.weight_decay!r}")
        for name in ("val_fraction", "test_fraction"):
            value = getattr(self, name)
            if not (0.0 < value < 1.0):
                raise ValueError(f"StyleTrainConfig: {name} must be in (0, 1), got {value!r}")
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ValueError(
                "StyleTrainConfig: val_fraction + test_fraction must be < 1, got "
                f"{self.val_fraction} + {self.test_fraction}"
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> StyleTrainConfig:
        """:param values: keys of this dataclass; an unknown key raises ``ValueError``."""
        return _config_from_dict(cls, values)


# --------------------------------------------------------------------------------------------
# Slot sequences (tokens and masks)
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# The classifier (Eq. 5)
# --------------------------------------------------------------------------------------------
def masked_mean(h: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean of ``h`` over the valid positions.

    :param h: (batch, seq_len, d)
    :param valid: (batch, seq_len) bool
    :return: (batch, d); rows without a valid position give zeros
    """
    w = valid.unsqueeze(-1).to(h.dtype)  # (batch, seq_len, 1)
    return (h * w).sum(1) / w.sum(1).clamp_min(1.0)


class _EncoderLayer(nn.Module):
    """Post-norm Transformer encoder layer (Vaswani et al., 2017) written with few tensor ops,
    because the per-step cost of the wrapper is dominated by per-op overhead on tiny inputs."""

    def __init__(self, d_model: int, n_heads: int, dim_feedforward: int, dropout: float):
        super().__init__()
        self.n_heads = n_heads
        self.head_dim = d_model // n_heads
        self.qkv = nn.Linear(d_model, 3 * d_model)
        self.out = nn.Linear(d_model, d_model)
        self.ff1 = nn.Linear(d_model, dim_feedforward)
        self.ff2 = nn.Linear(dim_feedforward, d_model)
        self.norm1 = nn.LayerNorm(d_model)
        self.norm2 = nn.LayerNorm(d_model)
        self.dropout = nn.Dropout(dropout)

    def forward(self, h: torch.Tensor, key_valid: torch.Tensor) -> torch.Tensor:
        """:param h: (batch, seq_len, d_model)
        :param key_valid: (batch, 1, 1, seq_len) bool, True for the keys that may be attended
        :return: (batch, seq_len, d_model)
        """
        batch, seq_len, d_model = h.shape
        # (batch, T, 3d) -> (3, batch, heads, T, head_dim)
        q, k, v = (
            self.qkv(h).view(batch, seq_len, 3, self.n_heads, self.head_dim).permute(2, 0, 3, 1, 4).unbind(0)
        )
        attn = F.scaled_dot_product_attention(q, k, v, attn_mask=key_valid)  # (batch, heads, T, head_dim)
        attn = attn.transpose(1, 2).reshape(batch, seq_len, d_model)  # (batch, heads, T, hd) -> (batch, T, d)
        h = self.norm1(h + self.dropout(self.out(attn)))
        return self.norm2(h + self.dropout(self.ff2(self.dropout(F.relu(self.ff1(h))))))


class DrivingStyleClassifier(nn.Module):
    """Transformer encoder over a slot sequence ``Z_m`` → logits over ``C`` driving styles.

    ``c_t^(m) = softmax(f_ψ(Z_m))`` (paper §3.1); trained with the cross-entropy of Eq. 5
    (:func:`style_loss`). Tokens are standardised with statistics stored in the model (set by
    :meth:`fit_normalizer`), embedded linearly, given a learned position embedding (position
    ``ℓ-1`` is the newest token), encoded, averaged over the valid tokens and classified.

    Paper: UA2C, §3.1 "Driving-Style Inference Module", Eq. 5.

    :param config: architecture (``StyleClassifierConfig``) or a dict of its fields
    :param metadata: free JSON-like information saved with the weights (feature names, split, ...)
    """

    def __init__(
        self, config: StyleClassifierConfig | dict[str, Any] | None = None, metadata: dict | None = None
    ):
        super().__init__()
        if config is None:
            config = StyleClassifierConfig()
        elif isinstance(config, dict):
            config = StyleClassifierConfig.from_dict(config)
        elif not isinstance(config, StyleClassifierConfig):
            raise ValueError(f"config must be a StyleClassifierConfig or a dict, got {type(config).__name__}")
        self.config = config
        self.metadata: dict[str, Any] = dict(metadata or {})
        c = config
        self.register_buffer("feature_mean", torch.zeros(c.n_features))
        self.register_buffer("feature_std", torch.ones(c.n_features))
        self.embed = nn.Linear(c.n_features, c.d_model)
        self.position = nn.Parameter(torch.randn(c.seq_len, c.d_model) * 0.02)
        self.layers = nn.ModuleList(
            _EncoderLayer(c.d_model, c.n_heads, c.dim_feedforward, c.dropout) for _ in range(c.n_layers)
        )
        self.head = nn.Linear(c.d_model, c.n_classes)

    # ---- normalisation ------------------------------------------------------------------------
    def fit_normalizer(self, tokens: np.ndarray, valid: np.ndarray) -> None:
        """Set the per-feature standardisation from the valid tokens of a training set.

        :param tokens: (n, seq_len, n_features)
        :param valid: (n, seq_len) bool
        """
        flat = np.asarray(tokens, dtype=np.float64)[np.asarray(valid, dtype=bool)]  # (n_valid, n_features)
        if flat.shape[0] == 0:
            raise ValueError("fit_normalizer: tokens contain no valid token")
        std = flat.std(0)
        self.feature_mean.copy_(torch.as_tensor(flat.mean(0), dtype=torch.float32))
        self.feature_std.copy_(torch.as_tensor(np.where(std > 1e-6, std, 1.0), dtype=torch.float32))

    # ---- forward ------------------------------------------------------------------------------
    def forward(self, tokens: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """Logits ``f_ψ(Z_m)``.

        :param tokens: (batch, seq_len, n_features) right-aligned slot sequences
        :param valid: (batch, seq_len) bool; every row needs at least one valid token
        :return: (batch, n_classes) logits
        """
        x = (tokens - self.feature_mean) / self.feature_std
        h = self.embed(x) + self.position  # (batch, seq_len, d_model)
        # padded positions are never attended to and never pooled, whatever they hold
        key_valid = valid[:, None, None, :]  # (batch, 1, 1, seq_len)
        for layer in self.layers:
            h = layer(h, key_valid)
        return self.head(masked_mean(h, valid))

    def _check_inputs(self, tokens: np.ndarray, valid: np.ndarray) -> None:
        c = self.config
        if tokens.ndim != 3 or tokens.shape[1:] != (c.seq_len, c.n_features):
            raise ValueError(
                f"tokens must have shape (batch, {c.seq_len}, {c.n_features}), got {tuple(tokens.shape)}"
            )
        if valid.shape != tokens.shape[:2]:
            raise ValueError(f"valid must have shape {tuple(tokens.shape[:2])}, got {tuple(valid.shape)}")

    def predict_proba(self, tokens: np.ndarray, valid: np.ndarray, empty: str = "zeros") -> np.ndarray:
        """Style distributions ``c^(m)`` for a batch of slot sequences, in inference mode.

        A row without any valid token (empty slot) is not passed to the network and gets the
        "no vehicle" output: zeros (``empty="zeros"``, distinguishable from any distribution) or
        the uniform distribution (``empty="uniform"``).

        :param tokens: (batch, seq_len, n_features) float
        :param valid: (batch, seq_len) bool
        :param empty: ``"zeros"`` or ``"uniform"``
        :return: (batch, n_classes) float32
        """
        if empty not in EMPTY_OUTPUTS:
            raise ValueError(f"empty must be one of {EMPTY_OUTPUTS}, got {empty!r}")
        tokens = np.asarray(tokens, dtype=np.float32)
        valid = np.asarray(valid, dtype=bool)
        self._check_inputs(tokens, valid)
        fill = 0.0 if empty == "zeros" else 1.0 / self.config.n_classes
        out = np.full((tokens.shape[0], self.config.n_classes), fill, dtype=np.float32)
        rows = valid.any(1)
        if rows.any():
            all_rows = bool(rows.all())
            x = torch.from_numpy(tokens if all_rows else tokens[rows])
            m = torch.from_numpy(valid if all_rows else valid[rows])
            was_training = self.training
            self.eval()
            with torch.inference_mode():
                out[rows] = self(x, m).softmax(-1).numpy()
            self.train(was_training)
        return out

    # ---- persistence --------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Save weights, config and metadata to one file (loadable with ``weights_only=True``).

        :param path: destination file (conventionally ``.pt``); parent folders are created
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(
            {
                "format": _CHECKPOINT_FORMAT,
                "config": dataclasses.asdict(self.config),
                "state_dict": {k: v.detach().cpu() for k, v in self.state_dict().items()},
                "metadata": self.metadata,
            },
            path,
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> DrivingStyleClassifier:
        """Load a classifier saved by :meth:`save` (in eval mode).

        :param path: file written by :meth:`save`
        """
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"classifier file not found: {str(path)!r}")
        payload = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(payload, dict) or payload.get("format") != _CHECKPOINT_FORMAT:
            raise ValueError(
                f"{str(path)!r} is not a DrivingStyleClassifier file (format {_CHECKPOINT_FORMAT})"
            )
        model = cls(StyleClassifierConfig.from_dict(payload["config"]), metadata=payload.get("metadata"))
        model.load_state_dict(payload["state_dict"])
        return model.eval()


def style_loss(
    logits: torch.Tensor, labels: torch.Tensor, class_weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Cross-entropy of Eq. 5, averaged over slots: ``-mean_m Σ_b y_{m,b} log c_{t,b}^(m)``.

    :param logits: (batch, C) ``f_ψ(Z_m)``
    :param labels: (batch,) int64 style indices
    :param class_weights: optional (C,) per-class weights (normalised weighted mean)
    :return: scalar loss
    """
    return F.cross_entropy(logits, labels, weight=class_weights)


def load_classifier(classifier: DrivingStyleClassifier | str | os.PathLike | None) -> DrivingStyleClassifier:
    """Return ``classifier`` itself, load it from a path, or load the packaged default (``None``).

    :param classifier: a model, a path to a file written by :meth:`DrivingStyleClassifier.save`,
        or ``None`` for the classifier shipped in ``sb3_ua2c/data``
    """
    if isinstance(classifier, DrivingStyleClassifier):
        return classifier.eval()
    if classifier is None:
        if not DEFAULT_CLASSIFIER_PATH.is_file():
            raise ValueError(
                "classifier=None needs the packaged default classifier, which is missing from this "
                "installation; train one with `python -m sb3_ua2c.style train` and pass its path"
            )
        return DrivingStyleClassifier.load(DEFAULT_CLASSIFIER_PATH)
    if isinstance(classifier, (str, os.PathLike)):
        return DrivingStyleClassifier.load(classifier)
    raise ValueError(
        f"classifier must be a DrivingStyleClassifier, a path or None, got {type(classifier).__name__}"
    )


# --------------------------------------------------------------------------------------------
# Dataset
# --------------------------------------------------------------------------------------------
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
    n_slots, n_features = len(SLOT_NAMES), len(SLOT_FEATURES)
    driver = policy if policy is not None else RandomDriver(env.action_space, seed=seed)
    seqs = SlotSequences(n_slots, seq_len, n_features)
    out: dict[str, list] = {"tokens": [], "valid": [], "labels": [], "episodes": [], "slots": []}
    steps = 0
    iterator: Any = range(n_episodes)
    if progress_bar:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc="collect", unit="ep")
    try:
        for episode in iterator:
            options = None
            if sumo_driver_fraction > 0:
                # deterministic interleaving: episode e is SUMO-driven when the running share lags
                sumo = math.floor((episode + 1) * sumo_driver_fraction) > math.floor(
                    episode * sumo_driver_fraction
                )
                options = {"ego_controller": "sumo" if sumo else "agent"}
            obs, info = env.reset(seed=seed + episode, options=options)
            seqs.reset()
            t, done = 0, False
            while True:
                slots = read_slots(info, n_slots, n_features)
                seqs.update(slots["ids"], slots["features"], slots["present"])
                if t % stride == 0:
                    styles = np.asarray(slots["styles"])
                    take = np.flatnonzero((seqs.lengths >= min_length) & (styles >= 0))
                    if take.size:
                        valid = seqs.valid
                        out["tokens"].append(seqs.tokens[take].copy())
                        out["valid"].append(valid[take])
                        out["labels"].append(styles[take].astype(np.int64))
                        out["episodes"].append(np.full(take.size, episode, dtype=np.int64))
                        out["slots"].append(take.astype(np.int64))
                if done or (max_steps_per_episode is not None and t >= max_steps_per_episode):
                    break
                obs, _, terminated, truncated, info = env.step(driver(obs))
                done = terminated or truncated
                t += 1
            steps += t
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


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------
def confusion_matrix(predicted: np.ndarray, truth: np.ndarray, n_classes: int) -> np.ndarray:
    """Confusion matrix with ROWS = inferred style and COLUMNS = ground truth (paper Fig. 2d).

    :param predicted: (n,) predicted class indices
    :param truth: (n,) true class indices
    :param n_classes: number of classes ``C``
    :return: (C, C) int64 counts, ``M[i, j]`` = samples of true class ``j`` inferred as ``i``
    """
    predicted, truth = np.asarray(predicted, dtype=np.int64), np.asarray(truth, dtype=np.int64)
    if predicted.shape != truth.shape:
        raise ValueError(f"predicted {predicted.shape} and truth {truth.shape} must have the same shape")
    for name, arr in (("predicted", predicted), ("truth", truth)):
        if arr.size and (arr.min() < 0 or arr.max() >= n_classes):
            raise ValueError(f"{name} holds a class index outside [0, {n_classes})")
    m = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(m, (predicted, truth), 1)
    return m


def classification_metrics(matrix: np.ndarray, class_names: Sequence[str] = STYLES) -> dict[str, Any]:
    """Accuracy, macro accuracy (mean per-class recall) and per-class precision/recall.

    :param matrix: (C, C) confusion matrix, rows = inferred, columns = ground truth
    :param class_names: (C,) names used as keys of the per-class entries
    :return: ``{"accuracy", "macro_accuracy", "per_class": {name: {"precision", "recall",
        "support"}}, "n"}``; a precision/recall with an empty denominator is reported as 0
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] != len(class_names):
        raise ValueError(f"matrix must be ({len(class_names)}, {len(class_names)}), got {m.shape}")
    diag, inferred, support = np.diag(m), m.sum(1), m.sum(0)
    precision = np.divide(diag, inferred, out=np.zeros_like(diag), where=inferred > 0)
    recall = np.divide(diag, support, out=np.zeros_like(diag), where=support > 0)
    n = m.sum()
    present = support > 0
    return {
        "accuracy": float(diag.sum() / n) if n else 0.0,
        "macro_accuracy": float(recall[present].mean()) if present.any() else 0.0,
        "per_class": {
            name: {"precision": float(precision[i]), "recall": float(recall[i]), "support": int(support[i])}
            for i, name in enumerate(class_names)
        },
        "n": int(n),
    }


def format_confusion(matrix: np.ndarray, class_names: Sequence[str] = STYLES) -> str:
    """Text table of a confusion matrix (rows = inferred, columns = ground truth)."""
    width = max(12, *(len(n) + 2 for n in class_names))
    lines = ["inferred \\ truth".ljust(width) + "".join(n.rjust(width) for n in class_names)]
    for i, name in enumerate(class_names):
        lines.append(name.ljust(width) + "".join(str(int(v)).rjust(width) for v in matrix[i]))
    return "\n".join(lines)


def plot_confusion(
    matrix: np.ndarray, path: str | os.PathLike, class_names: Sequence[str] = STYLES, title: str = ""
) -> None:
    """Save the confusion matrix as a PNG (rows = inferred, columns = ground truth; cells show the
    column-normalised rate and the count).

    :param matrix: (C, C) counts
    :param path: destination ``.png``
    :param class_names: axis labels
    :param title: figure title
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    m = np.asarray(matrix, dtype=np.float64)
    rate = m / np.maximum(m.sum(0, keepdims=True), 1.0)  # per ground-truth column
    fig = Figure(
        figsize=(5.0, 4.2), dpi=120, layout="constrained"
    )  # no pyplot: the user's backend stays untouched
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    im = ax.imshow(rate, cmap="Blues", vmin=0.0, vmax=1.0)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            ax.text(
                j,
                i,
                f"{rate[i, j]:.2f}\n({int(m[i, j])})",
                ha="center",
                va="center",
                color="white" if rate[i, j] > 0.5 else "black",
                fontsize=8,
            )
    ax.set_xticks(range(len(class_names)), class_names)
    ax.set_yticks(range(len(class_names)), class_names)
    ax.set_xlabel("ground truth (cells: share of the column, count)")
    ax.set_ylabel("inferred")
    if title:
        ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.85)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight", pad_inches=0.1)


# --------------------------------------------------------------------------------------------
# Logistic-regression baseline on summary features
# --------------------------------------------------------------------------------------------
def summary_features(tokens: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per-sequence summary: mean, std, min, max and last value of every feature over the valid
    tokens, plus the number of valid tokens.

    :param tokens: (n, seq_len, n_features)
    :param valid: (n, seq_len) bool (right-aligned; every row has a valid token)
    :return: (n, 5 * n_features + 1) float32
    """
    x = np.asarray(tokens, dtype=np.float64)
    w = np.asarray(valid, dtype=bool)[..., None]  # (n, seq_len, 1)
    count = np.maximum(w.sum(1), 1)  # (n, 1)
    mean = np.where(w, x, 0.0).sum(1) / count
    std = np.sqrt(np.where(w, (x - mean[:, None]) ** 2, 0.0).sum(1) / count)
    lo = np.where(w, x, np.inf).min(1)
    hi = np.where(w, x, -np.inf).max(1)
    last = x[:, -1]
    return np.concatenate([mean, std, lo, hi, last, count], axis=1).astype(np.float32)


class LogisticRegressionBaseline:
    """Multinomial logistic regression on :func:`summary_features` (standardised), L2-regularised,
    fitted by full-batch L-BFGS. The reference the Transformer must beat.

    :param l2: L2 penalty on the weights
    :param max_iter: L-BFGS iterations
    """

    def __init__(self, l2: float = 1e-3, max_iter: int = 200):
        self.l2, self.max_iter = float(l2), int(max_iter)
        self.mean: np.ndarray | None = None
        self.std: np.ndarray | None = None
        self.weight: torch.Tensor | None = None
        self.bias: torch.Tensor | None = None

    def fit(
        self, tokens: np.ndarray, valid: np.ndarray, labels: np.ndarray, n_classes: int
    ) -> LogisticRegressionBaseline:
        """:param tokens: (n, seq_len, n_features)
        :param valid: (n, seq_len) bool
        :param labels: (n,) int64
        :param n_classes: number of classes
        """
        feats = summary_features(tokens, valid)
        self.mean, std = feats.mean(0), feats.std(0)
        self.std = np.where(std > 1e-6, std, 1.0).astype(np.float32)
        x = torch.from_numpy((feats - self.mean) / self.std)
        y = torch.as_tensor(labels, dtype=torch.int64)
        weight = torch.zeros(x.shape[1], n_classes, requires_grad=True)
        bias = torch.zeros(n_classes, requires_grad=True)
        opt = torch.optim.LBFGS([weight, bias], max_iter=self.max_iter, line_search_fn="strong_wolfe")

        def closure() -> torch.Tensor:
            opt.zero_grad()
            loss = F.cross_entropy(x @ weight + bias, y) + self.l2 * (weight**2).sum()
            loss.backward()
            return loss

        opt.step(closure)
        self.weight, self.bias = weight.detach(), bias.detach()
        return self

    def predict_proba(self, tokens: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """:return: (n, n_classes) class probabilities"""
        if self.weight is None:
            raise ValueError("LogisticRegressionBaseline: call fit() first")
        x = torch.from_numpy((summary_features(tokens, valid) - self.mean) / self.std)
        return (x @ self.weight + self.bias).softmax(-1).numpy()


# --------------------------------------------------------------------------------------------
# Training and evaluation
# --------------------------------------------------------------------------------------------
def _batched_logits(
    model: DrivingStyleClassifier, tokens: np.ndarray, valid: np.ndarray, batch: int = 4096
) -> torch.Tensor:
    out = []
    with torch.inference_mode():
        for i in range(0, tokens.shape[0], batch):
            out.append(model(torch.from_numpy(tokens[i : i + batch]), torch.from_numpy(valid[i : i + batch])))
    return torch.cat(out) if out else torch.zeros(0, model.config.n_classes)


def train_style_classifier(
    dataset: StyleDataset,
    config: StyleClassifierConfig | dict[str, Any] | None = None,
    train_config: StyleTrainConfig | dict[str, Any] | None = None,
    progress_bar: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[DrivingStyleClassifier, dict[str, Any]]:
    """Train a :class:`DrivingStyleClassifier` with the cross-entropy of Eq. 5.

    The dataset is split by episode (:func:`split_by_episode`); training stops when the
    validation loss has not improved for ``patience`` epochs and the best weights are restored.
    The split's episode ids are stored in ``model.metadata`` so :func:`evaluate_style_classifier`
    can evaluate on the same held-out episodes.

    :param dataset: labelled slot sequences
    :param config: architecture; ``seq_len``/``n_features`` default to the dataset's
    :param train_config: optimisation settings
    :param progress_bar: tqdm bar over epochs
    :param log: optional callback receiving one line per epoch
    :return: the trained model (eval mode) and a history dict
    """
    tc = (
        train_config
        if isinstance(train_config, StyleTrainConfig)
        else StyleTrainConfig.from_dict(train_config or {})
    )
    n, seq_len, n_features = dataset.tokens.shape
    if config is None:
        config = StyleClassifierConfig(seq_len=seq_len, n_features=n_features)
    elif isinstance(config, dict):
        config = StyleClassifierConfig.from_dict({"seq_len": seq_len, "n_features": n_features, **config})
    if (config.seq_len, config.n_features) != (seq_len, n_features):
        raise ValueError(
            f"config (seq_len={config.seq_len}, n_features={config.n_features}) does not match the dataset "
            f"(seq_len={seq_len}, n_features={n_features})"
        )
    if dataset.labels.size and dataset.labels.max() >= config.n_classes:
        raise ValueError(f"dataset has label {dataset.labels.max()} but n_classes={config.n_classes}")
    train_idx, val_idx, test_idx = split_by_episode(
        dataset.episodes, tc.val_fraction, tc.test_fraction, tc.seed
    )
    torch.manual_seed(tc.seed)
    rng = np.random.default_rng(tc.seed)
    model = DrivingStyleClassifier(config)
    tr, va = dataset.subset(train_idx), dataset.subset(val_idx)
    model.fit_normalizer(tr.tokens, tr.valid)
    class_weights = None
    if tc.class_weighted:
        counts = np.bincount(tr.labels, minlength=config.n_classes).astype(np.float64)
        w = np.where(counts > 0, counts.sum() / np.maximum(counts, 1) / config.n_classes, 0.0)
        class_weights = torch.as_tensor(w, dtype=torch.float32)
    opt = torch.optim.AdamW(model.parameters(), lr=tc.learning_rate, weight_decay=tc.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=tc.max_epochs)
    x_tr, m_tr, y_tr = torch.from_numpy(tr.tokens), torch.from_numpy(tr.valid), torch.from_numpy(tr.labels)
    y_va = torch.from_numpy(va.labels)
    history: dict[str, list] = {"train_loss": [], "val_loss": [], "val_accuracy": []}
    best = (math.inf, -1, copy.deepcopy(model.state_dict()))
    epochs: Any = range(tc.max_epochs)
    if progress_bar:
        from tqdm.auto import tqdm

        epochs = tqdm(epochs, desc="train", unit="epoch")
    start = time.perf_counter()
    for epoch in epochs:
        model.train()
        perm = torch.from_numpy(rng.permutation(len(tr)))
        total = 0.0
        for i in range(0, len(tr), tc.batch_size):
            idx = perm[i : i + tc.batch_size]
            loss = style_loss(model(x_tr[idx], m_tr[idx]), y_tr[idx], class_weights)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.item() * idx.numel()
        sched.step()
        model.eval()
        logits = _batched_logits(model, va.tokens, va.valid)
        val_loss = float(style_loss(logits, y_va, class_weights))
        val_acc = classification_metrics(
            confusion_matrix(logits.argmax(-1).numpy(), va.labels, config.n_classes),
            _class_names(config.n_classes),
        )["macro_accuracy"]
        history["train_loss"].append(total / len(tr))
        history["val_loss"].append(val_loss)
        history["val_accuracy"].append(val_acc)
        if val_loss < best[0] - 1e-5:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()))
        line = f"epoch {epoch}: train_loss={total / len(tr):.4f} val_loss={val_loss:.4f} val_macro_acc={val_acc:.3f}"
        if progress_bar:
            epochs.set_postfix(
                loss=f"{total / len(tr):.3f}", val_loss=f"{val_loss:.3f}", val_acc=f"{val_acc:.3f}"
            )
        if log is not None:
            log(line)
        if epoch - best[1] >= tc.patience:
            break
    model.load_state_dict(best[2])
    model.eval()
    history.update(best_epoch=best[1], best_val_loss=best[0], seconds=time.perf_counter() - start)
    model.metadata.update(
        features=list(dataset.meta.get("features", SLOT_FEATURES)),
        styles=list(dataset.meta.get("styles", STYLES)),
        train_config=dataclasses.asdict(tc),
        split_episodes={
            "train": np.unique(dataset.episodes[train_idx]).tolist(),
            "val": np.unique(dataset.episodes[val_idx]).tolist(),
            "test": np.unique(dataset.episodes[test_idx]).tolist(),
        },
        best_epoch=int(best[1]),
        dataset=dict(dataset.meta),
    )
    return model, history


def _class_names(n_classes: int) -> tuple[str, ...]:
    return STYLES if n_classes == len(STYLES) else tuple(f"style_{i}" for i in range(n_classes))


def evaluate_style_classifier(
    model: DrivingStyleClassifier,
    dataset: StyleDataset,
    test_episodes: Sequence[int] | None = None,
    baseline: bool = True,
) -> dict[str, Any]:
    """Evaluate on held-out episodes and compare with the logistic-regression baseline.

    :param model: trained classifier
    :param dataset: the full dataset (the split is taken from ``model.metadata`` unless
        ``test_episodes`` is given)
    :param test_episodes: episode ids to evaluate on
    :param baseline: also fit :class:`LogisticRegressionBaseline` on the training episodes and
        evaluate it on the same test episodes
    :return: JSON-serialisable dict with ``macro_accuracy``, ``accuracy``, ``per_class``,
        ``confusion_matrix`` (rows inferred, columns truth), accuracy by history length and the
        baseline's figures
    """
    split = model.metadata.get("split_episodes", {})
    if test_episodes is None:
        if "test" not in split:
            raise ValueError("the model carries no split; pass test_episodes")
        test_episodes = split["test"]
    test_mask = np.isin(dataset.episodes, np.asarray(test_episodes))
    if not test_mask.any():
        raise ValueError("no sample of the dataset belongs to the test episodes")
    names = _class_names(model.config.n_classes)
    te = dataset.subset(test_mask)
    proba = np.concatenate(
        [
            model.predict_proba(te.tokens[i : i + 4096], te.valid[i : i + 4096])
            for i in range(0, len(te), 4096)
        ]
    )
    pred = proba.argmax(-1)
    matrix = confusion_matrix(pred, te.labels, model.config.n_classes)
    result: dict[str, Any] = {
        "model": "transformer",
        **classification_metrics(matrix, names),
        "confusion_matrix": matrix.tolist(),
        "confusion_matrix_layout": "rows = inferred style, columns = ground truth",
        "classes": list(names),
        "test_episodes": [int(e) for e in test_episodes],
        "dataset": dict(dataset.meta),
        "classifier_config": dataclasses.asdict(model.config),
    }
    lengths = te.lengths
    by_len = {}
    seq_len = model.config.seq_len
    for lo, hi in ((1, max(1, seq_len // 4)), (max(1, seq_len // 4) + 1, seq_len - 1), (seq_len, seq_len)):
        sel = (lengths >= lo) & (lengths <= hi)
        if sel.any() and lo <= hi:
            m = classification_metrics(
                confusion_matrix(pred[sel], te.labels[sel], model.config.n_classes), names
            )
            by_len[f"{lo}-{hi}"] = {
                "macro_accuracy": m["macro_accuracy"],
                "accuracy": m["accuracy"],
                "n": m["n"],
            }
    result["by_history_length"] = by_len
    if baseline:
        train_eps = split.get("train")
        if train_eps is None:
            train_mask = ~test_mask & ~np.isin(dataset.episodes, np.asarray(split.get("val", [])))
        else:
            train_mask = np.isin(dataset.episodes, np.asarray(train_eps))
        tr = dataset.subset(train_mask)
        lr = LogisticRegressionBaseline().fit(tr.tokens, tr.valid, tr.labels, model.config.n_classes)
        bmatrix = confusion_matrix(
            lr.predict_proba(te.tokens, te.valid).argmax(-1), te.labels, model.config.n_classes
        )
        bm = classification_metrics(bmatrix, names)
        result["baseline"] = {
            "model": "logistic_regression_on_summary_features",
            "macro_accuracy": bm["macro_accuracy"],
            "accuracy": bm["accuracy"],
            "per_class": bm["per_class"],
            "confusion_matrix": bmatrix.tolist(),
        }
    return result


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------
def _parse_kv(pairs: Sequence[str] | None) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}`` (values parsed as JSON when possible)."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise ValueError(f"expected key=value, got {pair!r}")
        key, value = pair.split("=", 1)
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``python -m sb3_ua2c.style`` (subcommands collect, train, evaluate)."""
    parser = argparse.ArgumentParser(
        prog="python -m sb3_ua2c.style",
        description="Driving-style inference (UA2C Eq. 5): collect a labelled dataset from "
        "MixedTraffic-v0, train the Transformer classifier, evaluate it against a baseline.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    fmt = argparse.ArgumentDefaultsHelpFormatter
    c = sub.add_parser(
        "collect",
        formatter_class=fmt,
        help="roll out the environment and save labelled slot sequences (.npz)",
    )
    c.add_argument("--episodes", type=int, default=1500, help="number of episodes")
    c.add_argument("--out", default="style_data.npz", help="output .npz file")
    c.add_argument("--env", default="MixedTraffic-v0", help="gymnasium id")
    c.add_argument("--seq-len", type=int, default=20, help="tokens per slot sequence ℓ")
    c.add_argument("--stride", type=int, default=5, help="sample every N steps")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--max-steps", type=int, default=None, help="cut episodes after this many steps")
    c.add_argument(
        "--sumo-driver-fraction",
        type=float,
        default=0.5,
        help="share of episodes where SUMO drives the AV (the rest: random driver)",
    )
    c.add_argument("--env-kwargs", nargs="*", metavar="KEY=VALUE", help="gym.make keyword arguments")
    c.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    t = sub.add_parser(
        "train", formatter_class=fmt, help="train the classifier with early stopping (split by episode)"
    )
    t.add_argument("--data", required=True, help=".npz written by collect")
    t.add_argument("--out", default="style_classifier.pt", help="output weights file")
    t.add_argument("--model", nargs="*", metavar="KEY=VALUE", help="StyleClassifierConfig fields")
    t.add_argument("--train", nargs="*", metavar="KEY=VALUE", help="StyleTrainConfig fields")
    t.add_argument("--no-progress", action="store_true")
    e = sub.add_parser(
        "evaluate", formatter_class=fmt, help="evaluate on the held-out episodes, with the baseline"
    )
    e.add_argument("--data", required=True, help=".npz written by collect")
    e.add_argument("--model", required=True, help="weights file written by train")
    e.add_argument("--json", default="results/style_eval.json", help="metrics output")
    e.add_argument("--png", default="results/style_confusion.png", help="confusion matrix figure")
    e.add_argument("--no-baseline", action="store_true", help="skip the logistic-regression baseline")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m sb3_ua2c.style``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        if args.command == "collect":
            ds = collect_style_dataset(
                args.episodes,
                env_id=args.env,
                seq_len=args.seq_len,
                stride=args.stride,
                seed=args.seed,
                env_kwargs=_parse_kv(args.env_kwargs),
                max_steps_per_episode=args.max_steps,
                sumo_driver_fraction=args.sumo_driver_fraction,
                progress_bar=not args.no_progress,
            )
            ds.save(args.out)
            counts = np.bincount(ds.labels, minlength=len(STYLES))
            print(
                f"saved {len(ds)} samples from {args.episodes} episodes to {args.out}; "
                f"per style: {dict(zip(STYLES, counts.tolist(), strict=False))}"
            )
        elif args.command == "train":
            ds = StyleDataset.load(args.data)
            model, hist = train_style_classifier(
                ds, _parse_kv(args.model), _parse_kv(args.train), progress_bar=not args.no_progress
            )
            model.save(args.out)
            print(
                f"best epoch {hist['best_epoch']} (val loss {hist['best_val_loss']:.4f}, "
                f"val macro acc {hist['val_accuracy'][hist['best_epoch']]:.3f}) in {hist['seconds']:.1f}s; "
                f"saved to {args.out}"
            )
        else:
            ds = StyleDataset.load(args.data)
            model = DrivingStyleClassifier.load(args.model)
            res = evaluate_style_classifier(model, ds, baseline=not args.no_baseline)
            print(format_confusion(np.asarray(res["confusion_matrix"]), res["classes"]))
            print(
                f"transformer: macro accuracy {res['macro_accuracy']:.3f}, accuracy {res['accuracy']:.3f} "
                f"(n={res['n']})"
            )
            for name, pc in res["per_class"].items():
                print(
                    f"  {name:>12}: precision {pc['precision']:.3f} recall {pc['recall']:.3f} (n={pc['support']})"
                )
            if "baseline" in res:
                print(
                    f"baseline (logistic regression): macro accuracy {res['baseline']['macro_accuracy']:.3f}, "
                    f"accuracy {res['baseline']['accuracy']:.3f}"
                )
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
            plot_confusion(
                np.asarray(res["confusion_matrix"]),
                args.png,
                res["classes"],
                title=f"driving style, macro acc {res['macro_accuracy']:.3f}",
            )
            print(f"wrote {args.json} and {args.png}")
    except ValueError as err:
        parser.error(str(err))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
