"""Classification metrics of the style classifier and the confusion-matrix figure (paper Fig. 2d:
rows = inferred style, columns = ground truth)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from envs.style.sequences import STYLES


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


def class_names_for(n_classes: int) -> tuple[str, ...]:
    """Names of ``n_classes`` styles: :data:`STYLES` when the count matches, else ``style_<i>``."""
    return STYLES if n_classes == len(STYLES) else tuple(f"style_{i}" for i in range(n_classes))
