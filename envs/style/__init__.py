"""Driving-style inference (paper §3.1 "Driving-Style Inference Module", Eq. 5, and §4.4).

For every observed slot ``m`` in ``(l_1, l_2, l_3, f_1, f_2, f_3)`` the module keeps the token
sequence ``Z_m = [z_{t-ℓ+1}, ..., z_t]`` of the vehicle currently in that slot and a small
Transformer encoder maps it to a categorical distribution over the ``C`` driving styles,
``c_t^(m) = softmax(f_ψ(Z_m))``. The classifier is trained with the cross-entropy of Eq. 5.

================ ==============================================================================
module           role
================ ==============================================================================
``sequences``    slot contract with ``MixedTraffic-v0`` (styles, slots, token features) and the
                 right-aligned per-slot token sequences ``Z_m``
``model``        configs, the Transformer classifier ``f_ψ``, the loss of Eq. 5, the file format
``data``         labelled dataset, split by episode, collection from the environment
``metrics``      confusion matrix (rows = inferred, columns = ground truth, paper Fig. 2d),
                 accuracy, per-class precision/recall, the confusion figure
``baseline``     logistic regression on summary features, the reference to beat
``train``        training with early stopping, evaluation on held-out episodes
``cli``          ``python -m envs style collect|train|evaluate``
================ ==============================================================================

Every public name is importable from ``envs.style`` itself. The command line::

    python -m envs style collect  --out style_data.npz          # 1500 episodes, ~5 min
    python -m envs style train    --data style_data.npz --out style_classifier.pt
    python -m envs style evaluate --data style_data.npz --model style_classifier.pt
    # -> results/style_eval.json, results/style_confusion.png

(``python -m envs.style ...`` is the same command line.) The classifier shipped in
``envs/data/style_classifier.pt`` was made by these three commands with their defaults.

Importing this package never needs SUMO; only :func:`collect_style_dataset` builds the
environment.
"""

from envs.style.baseline import LogisticRegressionBaseline, summary_features
from envs.style.cli import build_parser, main
from envs.style.data import RandomDriver, StyleDataset, collect_style_dataset, split_by_episode
from envs.style.metrics import (
    class_names_for,
    classification_metrics,
    confusion_matrix,
    format_confusion,
    plot_confusion,
)
from envs.style.model import (
    DEFAULT_CLASSIFIER_PATH,
    EMPTY_OUTPUTS,
    DrivingStyleClassifier,
    StyleClassifierConfig,
    StyleTrainConfig,
    _EncoderLayer,  # noqa: F401  (whole-module pickles made before the split name envs.style._EncoderLayer)
    load_classifier,
    masked_mean,
    style_loss,
)
from envs.style.sequences import (
    SLOT_FEATURES,
    SLOT_NAMES,
    STYLES,
    SlotSequences,
    read_slots,
    valid_mask,
)
from envs.style.train import evaluate_style_classifier, train_style_classifier

__all__ = [
    "DEFAULT_CLASSIFIER_PATH",
    "EMPTY_OUTPUTS",
    "SLOT_FEATURES",
    "SLOT_NAMES",
    "STYLES",
    "DrivingStyleClassifier",
    "LogisticRegressionBaseline",
    "RandomDriver",
    "SlotSequences",
    "StyleClassifierConfig",
    "StyleDataset",
    "StyleTrainConfig",
    "build_parser",
    "class_names_for",
    "classification_metrics",
    "collect_style_dataset",
    "confusion_matrix",
    "evaluate_style_classifier",
    "format_confusion",
    "load_classifier",
    "main",
    "masked_mean",
    "plot_confusion",
    "read_slots",
    "split_by_episode",
    "style_loss",
    "summary_features",
    "train_style_classifier",
    "valid_mask",
]
