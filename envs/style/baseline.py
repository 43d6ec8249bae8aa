"""The reference the style classifier must beat: multinomial logistic regression on per-sequence
summary features (mean, std, min, max, last value of every feature, and the history length)."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


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
