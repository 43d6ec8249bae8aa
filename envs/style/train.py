"""Training of the style classifier with the cross-entropy of Eq. 5 (early stopping on the validation
loss, split by episode) and its evaluation on held-out episodes against the logistic-regression
baseline (paper §4.4, Fig. 2d)."""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from envs.style.baseline import LogisticRegressionBaseline
from envs.style.data import StyleDataset, split_by_episode
from envs.style.metrics import class_names_for, classification_metrics, confusion_matrix
from envs.style.model import DrivingStyleClassifier, StyleClassifierConfig, StyleTrainConfig, style_loss
from envs.style.sequences import SLOT_FEATURES, STYLES


def _batched_logits(
    model: DrivingStyleClassifier, tokens: np.ndarray, valid: np.ndarray, batch: int = 4096
) -> torch.Tensor:
    out = []
    with torch.inference_mode():
        for i in range(0, tokens.shape[0], batch):
            out.append(model(torch.from_numpy(tokens[i : i + batch]), torch.from_numpy(valid[i : i + batch])))
    return torch.cat(out) if out else torch.zeros(0, model.config.n_classes)


def _resolve_configs(
    dataset: StyleDataset,
    config: StyleClassifierConfig | dict[str, Any] | None,
    train_config: StyleTrainConfig | dict[str, Any] | None,
) -> tuple[StyleClassifierConfig, StyleTrainConfig]:
    """Both configs as dataclasses; ``seq_len``/``n_features`` default to the dataset's and must match it."""
    tc = (
        train_config
        if isinstance(train_config, StyleTrainConfig)
        else StyleTrainConfig.from_dict(train_config or {})
    )
    _, seq_len, n_features = dataset.tokens.shape
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
    return config, tc


def _inverse_frequency_weights(labels: np.ndarray, n_classes: int) -> torch.Tensor:
    """(C,) class weights ``n / (C * n_c)`` (0 for an absent class), so each class weighs the same in Eq. 5."""
    counts = np.bincount(labels, minlength=n_classes).astype(np.float64)
    w = np.where(counts > 0, counts.sum() / np.maximum(counts, 1) / n_classes, 0.0)
    return torch.as_tensor(w, dtype=torch.float32)


def _train_epoch(
    model: DrivingStyleClassifier,
    opt: torch.optim.Optimizer,
    batches: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    perm: torch.Tensor,
    batch_size: int,
    class_weights: torch.Tensor | None,
) -> float:
    """One pass over the training set in the order ``perm``; returns the summed (not averaged) loss.

    :param batches: tokens (n, seq_len, n_features), valid (n, seq_len), labels (n,)
    """
    x, m, y = batches
    model.train()
    total = 0.0
    for i in range(0, len(perm), batch_size):
        idx = perm[i : i + batch_size]
        loss = style_loss(model(x[idx], m[idx]), y[idx], class_weights)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        total += loss.item() * idx.numel()
    return total


def _validate(
    model: DrivingStyleClassifier, va: StyleDataset, class_weights: torch.Tensor | None
) -> tuple[float, float]:
    """Validation loss (Eq. 5, same class weights as training) and macro accuracy, in eval mode."""
    n_classes = model.config.n_classes
    model.eval()
    logits = _batched_logits(model, va.tokens, va.valid)
    val_loss = float(style_loss(logits, torch.from_numpy(va.labels), class_weights))
    val_acc = classification_metrics(
        confusion_matrix(logits.argmax(-1).numpy(), va.labels, n_classes), class_names_for(n_classes)
    )["macro_accuracy"]
    return val_loss, val_acc


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
    config, tc = _resolve_configs(dataset, config, train_config)
    train_idx, val_idx, test_idx = split_by_episode(
        dataset.episodes, tc.val_fraction, tc.test_fraction, tc.seed
    )
    torch.manual_seed(tc.seed)
    rng = np.random.default_rng(tc.seed)
    model = DrivingStyleClassifier(config)
    tr, va = dataset.subset(train_idx), dataset.subset(val_idx)
    model.fit_normalizer(tr.tokens, tr.valid)
    class_weights = _inverse_frequency_weights(tr.labels, config.n_classes) if tc.class_weighted else None
    opt = torch.optim.AdamW(model.parameters(), lr=tc.learning_rate, weight_decay=tc.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=tc.max_epochs)
    batches = (torch.from_numpy(tr.tokens), torch.from_numpy(tr.valid), torch.from_numpy(tr.labels))
    history: dict[str, list] = {"train_loss": [], "val_loss": [], "val_accuracy": []}
    best = (math.inf, -1, copy.deepcopy(model.state_dict()))
    epochs: Any = range(tc.max_epochs)
    if progress_bar:
        from tqdm.auto import tqdm

        epochs = tqdm(epochs, desc="train", unit="epoch")
    start = time.perf_counter()
    for epoch in epochs:
        perm = torch.from_numpy(rng.permutation(len(tr)))
        total = _train_epoch(model, opt, batches, perm, tc.batch_size, class_weights)
        sched.step()
        val_loss, val_acc = _validate(model, va, class_weights)
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


def _accuracy_by_history_length(
    pred: np.ndarray, labels: np.ndarray, lengths: np.ndarray, seq_len: int, names: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """Accuracy on short (``1..ℓ/4``), medium and full (``ℓ``) histories, keyed ``"lo-hi"``."""
    by_len = {}
    quarter = max(1, seq_len // 4)
    for lo, hi in ((1, quarter), (quarter + 1, seq_len - 1), (seq_len, seq_len)):
        sel = (lengths >= lo) & (lengths <= hi)
        if sel.any() and lo <= hi:
            m = classification_metrics(confusion_matrix(pred[sel], labels[sel], len(names)), names)
            by_len[f"{lo}-{hi}"] = {
                "macro_accuracy": m["macro_accuracy"],
                "accuracy": m["accuracy"],
                "n": m["n"],
            }
    return by_len


def _baseline_result(
    dataset: StyleDataset, split: dict[str, Any], test_mask: np.ndarray, names: Sequence[str]
) -> dict[str, Any]:
    """Fit :class:`LogisticRegressionBaseline` on the training episodes of ``split`` (or on every
    episode outside the test and validation parts) and evaluate it on the test samples."""
    n_classes = len(names)
    train_eps = split.get("train")
    if train_eps is None:
        train_mask = ~test_mask & ~np.isin(dataset.episodes, np.asarray(split.get("val", [])))
    else:
        train_mask = np.isin(dataset.episodes, np.asarray(train_eps))
    tr, te = dataset.subset(train_mask), dataset.subset(test_mask)
    lr = LogisticRegressionBaseline().fit(tr.tokens, tr.valid, tr.labels, n_classes)
    bmatrix = confusion_matrix(lr.predict_proba(te.tokens, te.valid).argmax(-1), te.labels, n_classes)
    bm = classification_metrics(bmatrix, names)
    return {
        "model": "logistic_regression_on_summary_features",
        "macro_accuracy": bm["macro_accuracy"],
        "accuracy": bm["accuracy"],
        "per_class": bm["per_class"],
        "confusion_matrix": bmatrix.tolist(),
    }


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
    names = class_names_for(model.config.n_classes)
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
    result["by_history_length"] = _accuracy_by_history_length(
        pred, te.labels, te.lengths, model.config.seq_len, names
    )
    if baseline:
        result["baseline"] = _baseline_result(dataset, split, test_mask, names)
    return result
