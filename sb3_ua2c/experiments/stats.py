"""Statistics over seeds (pure): Student-t confidence intervals and relative changes of paired runs."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.stats


def _check_df(df: int) -> None:
    if isinstance(df, bool) or not isinstance(df, int | np.integer) or df < 1:
        raise ValueError(f"df must be an integer >= 1, got {df!r}")


def student_t_two_sided_cdf(t: float, df: int) -> float:
    """``P(|T| <= t) = 1 − 2 · P(T > t)`` for Student's t with integer ``df`` degrees of freedom
    (:data:`scipy.stats.t`).

    :param t: the bound, >= 0
    :param df: degrees of freedom, >= 1
    """
    _check_df(df)
    if not t >= 0:
        raise ValueError(f"t must be >= 0, got {t!r}")
    return float(1.0 - 2.0 * scipy.stats.t.sf(t, df))


def student_t_quantile(confidence: float, df: int) -> float:
    """Two-sided critical value ``t`` with ``P(|T| <= t) = confidence``: the ``(1 + confidence) / 2``
    quantile of Student's t (:data:`scipy.stats.t`).

    :param confidence: in (0, 1), e.g. 0.95 (``t = 2.776`` for ``df = 4``)
    :param df: degrees of freedom, >= 1
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    _check_df(df)
    return float(scipy.stats.t.ppf((1.0 + confidence) / 2.0, df))


def t_confidence_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float]:
    """Mean and half-width of the Student-t confidence interval over seeds.

    ``half = t_{(1+c)/2, n-1} · s / √n`` with the sample standard deviation ``s`` (ddof = 1);
    with one value the half-width is NaN (no spread can be estimated).

    :param values: (n,) one number per seed, finite
    :param confidence: coverage, e.g. 0.95
    :return: ``(mean, half_width)``
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"values must be a non-empty 1-D sequence, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"values must be finite, got {x.tolist()}")
    mean = float(x.mean())
    if x.size == 1:
        return mean, math.nan
    return mean, student_t_quantile(confidence, x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)


def relative_change_pct(new: float, base: float) -> float:
    """``100 · (new − base) / |base|``: positive when ``new`` is larger, whatever the sign of
    ``base`` (rewards may be negative). NaN when ``base`` is 0.

    :param new: the method's value
    :param base: the baseline's value
    """
    if base == 0 or not (math.isfinite(new) and math.isfinite(base)):
        return math.nan
    return 100.0 * (new - base) / abs(base)


def compare(new: Sequence[float], base: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """Relative change of paired per-seed values.

    :param new: (n,) the method's per-seed means
    :param base: (n,) the baseline's per-seed means, same seed order
    :return: ``change_pct`` (of the means over seeds, the headline figure), ``per_seed_pct``,
        and the t interval of the per-seed changes (``per_seed_mean_pct``, ``per_seed_ci95_pct``)
    """
    new_a, base_a = np.asarray(new, dtype=np.float64), np.asarray(base, dtype=np.float64)
    if new_a.shape != base_a.shape or new_a.ndim != 1 or new_a.size == 0:
        raise ValueError(
            f"new and base must be equal-length 1-D sequences, got {new_a.shape} and {base_a.shape}"
        )
    per_seed = [relative_change_pct(float(n), float(b)) for n, b in zip(new_a, base_a, strict=True)]
    finite = [p for p in per_seed if math.isfinite(p)]
    mean, half = t_confidence_interval(finite, confidence) if finite else (math.nan, math.nan)
    return {
        "change_pct": relative_change_pct(float(new_a.mean()), float(base_a.mean())),
        "per_seed_pct": per_seed,
        "per_seed_mean_pct": mean,
        "per_seed_ci95_pct": half,
    }
