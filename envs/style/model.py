"""The driving-style classifier of paper §3.1 (Eq. 5): its configs, the Transformer encoder
``f_ψ`` over one slot sequence ``Z_m``, the cross-entropy of Eq. 5 and the classifier file format.

``c_t^(m) = softmax(f_ψ(Z_m))`` for every slot ``m``; an empty slot (no valid token) never reaches
the network: :meth:`DrivingStyleClassifier.predict_proba` returns a documented "no vehicle" output
for it (all zeros by default, or the uniform distribution).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from envs.style.sequences import SLOT_FEATURES, STYLES
from sb3_ua2c.checks import check_int

#: file of the trained classifier shipped with the package (may be absent in a source checkout)
DEFAULT_CLASSIFIER_PATH = Path(__file__).resolve().parents[1] / "data" / "style_classifier.pt"

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
        or ``None`` for the classifier shipped in ``envs/data``
    """
    if isinstance(classifier, DrivingStyleClassifier):
        return classifier.eval()
    if classifier is None:
        if not DEFAULT_CLASSIFIER_PATH.is_file():
            raise ValueError(
                "classifier=None needs the packaged default classifier, which is missing from this "
                "installation; train one with `python -m envs.style train` and pass its path"
            )
        return DrivingStyleClassifier.load(DEFAULT_CLASSIFIER_PATH)
    if isinstance(classifier, (str, os.PathLike)):
        return DrivingStyleClassifier.load(classifier)
    raise ValueError(
        f"classifier must be a DrivingStyleClassifier, a path or None, got {type(classifier).__name__}"
    )
