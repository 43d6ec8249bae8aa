"""Statistics of the head-to-head with rliable (Agarwal et al., "Deep Reinforcement Learning at the
Edge of the Statistical Precipice", NeurIPS 2021): interquartile mean (IQM) with stratified bootstrap
confidence intervals, and the probability of improvement of one arm over another.

Layout. An arm's scores form a matrix ``(n_seeds, n_episodes)``: row ``s`` holds the evaluation
episodes of the run with seed ``s`` (:func:`score_matrix`). In rliable's terms the rows are runs
and the columns (evaluation episode ``i`` of every seed) are tasks: the IQM is taken over all
seeds × episodes, and the stratified bootstrap resamples the seeds independently within each
episode column, so the intervals carry the spread between training seeds as well as between
scenarios. The probability of improvement ``P(X > Y)`` is the Mann-Whitney statistic over the
seeds of each column, averaged over the columns (0.5 = no difference).

Metrics where lower is better (collision, jerk) are negated first (``higher_is_better=False``), so a
probability above 0.5 always means that X does better.

The point estimates are rliable's own functions (``rliable.metrics``). The bootstrap is rliable's
stratified resampling written out here (:func:`stratified_resamples`, a few lines of NumPy):
``rliable.library`` 1.2.0 needs ``arch < 8``, whose 7.x releases fail to import with pandas 3, and
its resampling draws from NumPy's global generator whatever ``random_state`` it is given; here a
seeded ``numpy.random.Generator`` makes every interval reproducible.

Student-t intervals and relative changes of paired runs (Figure 2) are at the end of this module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.stats

from sb3_ua2c.checks import check_int

#: Metrics of an evaluation episode where a lower value is better.
LOWER_IS_BETTER = frozenset({"cumulative_jerk", "jerk_per_step", "collision"})


def _metrics() -> Any:
    try:
        from rliable import metrics
    except ImportError as exc:
        raise ImportError('the peers statistics need rliable: pip install "sb3-ua2c[peers]"') from exc
    return metrics


def score_matrix(records: Sequence[Mapping[str, Any]], metric: str) -> np.ndarray:
    """The per-episode values of ``metric`` in the unit records of one arm, one row per seed.

    :param records: the records of one arm (:func:`experiments.peers.common.unit_record`), any order
    :param metric: a key of the evaluation episodes (``reward``, ``collision``, ``jerk_per_step``, ...)
    :return: ``(n_seeds, n_episodes)``, rows in increasing seed order (booleans as 0.0 / 1.0)
    """
    if not records:
        raise ValueError("records must not be empty")
    rows = []
    for record in sorted(records, key=lambda r: r["seed"]):
        episodes = record["evaluation"]["episodes"]
        if episodes and metric not in episodes[0]:
            raise ValueError(f"metric {metric!r} is not in the evaluation episodes; keys: {sorted(episodes[0])}")
        rows.append([float(e[metric]) for e in episodes])
    if len({len(row) for row in rows}) != 1:
        raise ValueError(f"every seed needs the same number of evaluation episodes, got {[len(r) for r in rows]}")
    return np.asarray(rows, dtype=np.float64)


def _check_matrix(name: str, scores: Any) -> np.ndarray:
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or scores.size == 0:
        raise ValueError(f"{name} must be a non-empty (n_seeds, n_episodes) matrix, got shape {scores.shape}")
    if not np.all(np.isfinite(scores)):
        raise ValueError(f"{name} holds NaN or inf")
    return scores


def stratified_resamples(scores: np.ndarray, reps: int, rng: np.random.Generator) -> np.ndarray:
    """``reps`` bootstrap copies of ``scores``, each column's rows (seeds) drawn with replacement
    independently of the other columns (rliable's ``StratifiedBootstrap``).

    :param scores: ``(n_seeds, n_episodes)``
    :return: ``(reps, n_seeds, n_episodes)``
    """
    n, m = scores.shape
    rows = rng.integers(0, n, size=(reps, n, m))  # (reps, n, m): the seed row taken, per column
    return scores[rows, np.arange(m)]


def iqm_of_resamples(boot: np.ndarray) -> np.ndarray:
    """rliable's ``aggregate_iqm`` of every bootstrap copy at once (scipy's 25 % trimmed mean per copy).

    :param boot: ``(reps, n_seeds, n_episodes)``
    :return: ``(reps,)``
    """
    from scipy.stats import trim_mean

    return trim_mean(boot.reshape(len(boot), -1), proportiontocut=0.25, axis=1)


def improvement_of_resamples(boot_x: np.ndarray, boot_y: np.ndarray) -> np.ndarray:
    """rliable's ``probability_of_improvement`` of every pair of bootstrap copies at once: per episode
    column the Mann-Whitney ``U / (n_x n_y)`` (the share of seed pairs with ``x > y``, ties counting
    one half; 0.5 for identical columns, as rliable sets), averaged over the columns.

    :param boot_x: ``(reps, n_x, m)``
    :param boot_y: ``(reps, n_y, m)``
    :return: ``(reps,)``
    """
    x, y = boot_x[:, :, None, :], boot_y[:, None, :, :]  # (reps, n_x, 1, m), (reps, 1, n_y, m)
    wins = (x > y) + 0.5 * (x == y)  # (reps, n_x, n_y, m)
    return wins.mean(axis=(1, 2)).mean(axis=1)


def _percentile_interval(values: np.ndarray, confidence: float) -> tuple[float, float]:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(values, [tail, 100.0 - tail])
    return float(low), float(high)


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50 % of all entries (25 % trimmed from each end)."""
    return float(_metrics().aggregate_iqm(_check_matrix("scores", scores)))


def _aggregate_with_ci(
    scores: Mapping[str, np.ndarray], key: str, point: Any, of_resamples: Any, confidence: float, reps: int, seed: int
) -> dict[str, dict[str, float]]:
    check_int("reps", reps)
    out = {}
    for name, matrix in scores.items():
        matrix = _check_matrix(f"scores[{name!r}]", matrix)
        boot = stratified_resamples(matrix, reps, np.random.default_rng(seed))  # (reps, n, m)
        low, high = _percentile_interval(of_resamples(boot), confidence)
        out[name] = {key: float(point(matrix)), "ci_low": low, "ci_high": high}
    return out


def iqm_with_ci(
    scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """IQM of each arm with its stratified bootstrap confidence interval (percentile method).

    :param scores: arm name -> ``(n_seeds, n_episodes)`` matrix
    :param confidence: interval size
    :param reps: bootstrap replications
    :param seed: seed of the bootstrap's generator (the same call gives the same interval)
    :return: arm -> ``{"iqm", "ci_low", "ci_high"}``
    """
    return _aggregate_with_ci(scores, "iqm", _metrics().aggregate_iqm, iqm_of_resamples, confidence, reps, seed)


def mean_with_ci(
    scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """Mean of each arm over seeds × episodes (rliable's ``aggregate_mean``; for a 0/1 metric, the rate)
    with its stratified bootstrap confidence interval. Where a 0/1 metric such as collision is rarer
    than 1 in 4 episodes its IQM is 0, as the trimmed quarters hold every 1: report the rate.

    :return: arm -> ``{"mean", "ci_low", "ci_high"}`` (arguments as :func:`iqm_with_ci`)
    """
    of_resamples = lambda boot: boot.reshape(len(boot), -1).mean(axis=1)  # noqa: E731  (reps,)
    return _aggregate_with_ci(scores, "mean", _metrics().aggregate_mean, of_resamples, confidence, reps, seed)


def probability_of_improvement(
    x: np.ndarray,
    y: np.ndarray,
    higher_is_better: bool = True,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> dict[str, float]:
    """``P(X > Y)``: how likely a run of X does better than a run of Y on an evaluation episode
    column, averaged over the columns, with its stratified bootstrap confidence interval (X and Y
    resampled independently, as rliable's ``StratifiedIndependentBootstrap``).

    :param x: ``(n_seeds_x, n_episodes)`` scores of X
    :param y: ``(n_seeds_y, n_episodes)`` scores of Y (the same episode columns)
    :param higher_is_better: ``False`` for costs (collision, jerk): X is better when lower
    :return: ``{"probability", "ci_low", "ci_high"}``
    """
    check_int("reps", reps)
    metrics = _metrics()
    x, y = _check_matrix("x", x), _check_matrix("y", y)
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x and y need the same episode columns, got {x.shape[1]} and {y.shape[1]}")
    sign = 1.0 if higher_is_better else -1.0
    x, y = sign * x, sign * y
    rng = np.random.default_rng(seed)
    boot_x, boot_y = stratified_resamples(x, reps, rng), stratified_resamples(y, reps, rng)
    low, high = _percentile_interval(improvement_of_resamples(boot_x, boot_y), confidence)
    return {"probability": float(metrics.probability_of_improvement(x, y)), "ci_low": low, "ci_high": high}



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


__all__ = [
    "LOWER_IS_BETTER", "improvement_of_resamples", "iqm", "iqm_of_resamples", "iqm_with_ci", "mean_with_ci", "probability_of_improvement", "score_matrix", "stratified_resamples",
    "compare", "relative_change_pct", "student_t_quantile", "student_t_two_sided_cdf", "t_confidence_interval",
]
