"""Run-level statistics of the experiment reports, after rliable (Agarwal et al., "Deep
Reinforcement Learning at the Edge of the Statistical Precipice", NeurIPS 2021).

The unit of replication is a run: one seed's data, training and evaluation. Every run is first
reduced to one score per metric, the mean over its evaluation episodes (:func:`run_scores`); an
arm's scores form rliable's ``(n_runs, n_tasks)`` matrix with one task per environment
(:func:`score_matrix`). The evaluation episodes of different seeds are different scenarios, so
they are never a task axis: resampling seeds within episode columns would hide the spread between
runs, and an IQM over episodes would trim rare crashes away.

* aggregates: rliable's IQM and mean over runs with stratified bootstrap intervals (runs resampled
  within each task; :func:`iqm_with_ci`, :func:`mean_with_ci`);
* ``P(X > Y)``: rliable's probability of improvement, the Mann-Whitney statistic over the runs of
  each task averaged over tasks, with a bootstrap interval (:func:`probability_of_improvement`);
* arms that share seeds (the same data and evaluation scenarios): the mean paired per-seed
  difference with its Student-t interval (:func:`paired_difference`, ``scipy.stats.ttest_rel``),
  and a verdict that names the interval (:func:`verdict`);
* learning: the area under a run's online learning curve (:func:`learning_curve_area`).

Metrics where lower is better (collision, jerk) are negated first (``higher_is_better=False``), so a
probability above 0.5 and a positive difference always mean that X does better.

Point estimates and intervals are rliable's own (``rliable.metrics``, and
``rliable.library.get_interval_estimates`` with the percentile method). ``rliable.library`` 1.2.0
imports ``arch < 8``, whose 7.x releases need pandas < 3 (the ``peers`` extra pins it). Its
resampling draws from NumPy's global generator, so every interval here is computed with that
generator seeded (and restored afterwards): the same call gives the same interval.

Student-t intervals and relative changes of Figure 2's claims are at the end of this module.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.stats

from sb3_ua2c.checks import check_int

#: Metrics of an evaluation episode where a lower value is better.
LOWER_IS_BETTER = frozenset({"cumulative_jerk", "jerk_per_step", "collision"})


def _rliable() -> tuple[Any, Any]:
    try:
        from rliable import library, metrics
    except ImportError as exc:
        raise ImportError('the report statistics need rliable: pip install -e ".[peers]"') from exc
    return library, metrics


def _interval_estimates(scores: Mapping[str, Any], func: Any, confidence: float, reps: int, seed: int) -> tuple:
    """rliable's ``get_interval_estimates`` (percentile method) with NumPy's global generator seeded."""
    check_int("reps", reps)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    library, _ = _rliable()
    state = np.random.get_state()  # noqa: NPY002  (rliable draws from the legacy global generator)
    np.random.seed(seed)  # noqa: NPY002
    try:
        with warnings.catch_warnings():  # arch deprecates the RandomState that rliable hands it
            warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
            return library.get_interval_estimates(dict(scores), func, reps=reps, confidence_interval_size=confidence,
                                                  random_state=np.random.RandomState(seed))  # noqa: NPY002
    finally:
        np.random.set_state(state)  # noqa: NPY002


def run_scores(records: Sequence[Mapping[str, Any]], metric: str, evaluation: str = "evaluation") -> np.ndarray:
    """One score per run: the mean of ``metric`` over the run's evaluation episodes.

    :param records: the records of one arm, one per seed, any order; ``record[evaluation]["episodes"]``
        holds the evaluation episodes (:func:`experiments.peers.common.unit_record`)
    :param metric: a key of the evaluation episodes (``reward``, ``collision``, ``jerk_per_step``, ...)
    :param evaluation: the record key of the evaluation (``"offline_evaluation"`` for the offline score)
    :return: ``(n_runs,)`` in increasing seed order (booleans as 0.0 / 1.0, so a rate for a 0/1 metric)
    """
    if not records:
        raise ValueError("records must not be empty")
    scores = []
    for record in sorted(records, key=lambda r: r["seed"]):
        episodes = record[evaluation]["episodes"]
        if not episodes:
            raise ValueError(f"seed {record['seed']} has no evaluation episodes")
        if metric not in episodes[0]:
            raise ValueError(f"metric {metric!r} is not in the evaluation episodes; keys: {sorted(episodes[0])}")
        scores.append(float(np.mean([float(e[metric]) for e in episodes])))
    return np.asarray(scores, dtype=np.float64)


def score_matrix(records: Sequence[Mapping[str, Any]], metric: str, evaluation: str = "evaluation") -> np.ndarray:
    """rliable's score matrix of one arm on one task: :func:`run_scores` as a column.

    :return: ``(n_runs, 1)``, rows in increasing seed order
    """
    return run_scores(records, metric, evaluation)[:, None]  # (n_runs,) -> (n_runs, 1)


def _check_matrix(name: str, scores: Any) -> np.ndarray:
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or scores.size == 0:
        raise ValueError(f"{name} must be a non-empty (n_runs, n_tasks) matrix, got shape {scores.shape}")
    if not np.all(np.isfinite(scores)):
        raise ValueError(f"{name} holds NaN or inf")
    return scores


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean over runs × tasks: the mean of the middle 50 % (25 % trimmed from each end)."""
    return float(_rliable()[1].aggregate_iqm(_check_matrix("scores", scores)))


def _aggregate_with_ci(scores: Mapping[str, np.ndarray], key: str, aggregate: Any, confidence: float, reps: int,
                       seed: int) -> dict[str, dict[str, float]]:
    checked = {name: _check_matrix(f"scores[{name!r}]", matrix) for name, matrix in scores.items()}
    points, intervals = _interval_estimates(checked, lambda m: np.array([aggregate(m)]), confidence, reps, seed)
    return {name: {key: float(points[name][0]), "ci_low": float(intervals[name][0, 0]),
                   "ci_high": float(intervals[name][1, 0])} for name in checked}


def iqm_with_ci(
    scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """IQM of each arm over its runs with rliable's stratified bootstrap interval over runs.

    :param scores: arm name -> ``(n_runs, n_tasks)`` matrix (:func:`score_matrix`)
    :param confidence: interval size
    :param reps: bootstrap replications
    :param seed: seed of the bootstrap (the same call gives the same interval)
    :return: arm -> ``{"iqm", "ci_low", "ci_high"}``
    """
    return _aggregate_with_ci(scores, "iqm", _rliable()[1].aggregate_iqm, confidence, reps, seed)


def mean_with_ci(
    scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000, seed: int = 0
) -> dict[str, dict[str, float]]:
    """Mean of each arm over its runs (rliable's ``aggregate_mean``; for a 0/1 metric, the mean rate)
    with rliable's stratified bootstrap interval over runs.

    :return: arm -> ``{"mean", "ci_low", "ci_high"}`` (arguments as :func:`iqm_with_ci`)
    """
    return _aggregate_with_ci(scores, "mean", _rliable()[1].aggregate_mean, confidence, reps, seed)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, higher_is_better: bool = True, confidence: float = 0.95,
                               reps: int = 2000, seed: int = 0) -> dict[str, float]:
    """``P(X > Y)``: how likely a run of X scores higher than a run of Y on a task (ties count one
    half), averaged over the tasks, with rliable's bootstrap interval (X and Y resampled
    independently, rliable's ``StratifiedIndependentBootstrap``).

    :param x: ``(n_runs_x, n_tasks)`` scores of X
    :param y: ``(n_runs_y, n_tasks)`` scores of Y (the same tasks)
    :param higher_is_better: ``False`` for costs (collision, jerk): X is better when lower
    :return: ``{"probability", "ci_low", "ci_high"}``
    """
    x, y = _check_matrix("x", x), _check_matrix("y", y)
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x and y need the same tasks, got {x.shape[1]} and {y.shape[1]}")
    sign = 1.0 if higher_is_better else -1.0
    metrics = _rliable()[1]
    points, intervals = _interval_estimates({"pair": [sign * x, sign * y]},
                                            lambda a, b: np.array([metrics.probability_of_improvement(a, b)]),
                                            confidence, reps, seed)
    return {"probability": float(points["pair"][0]), "ci_low": float(intervals["pair"][0, 0]),
            "ci_high": float(intervals["pair"][1, 0])}


def paired_difference(
    x: Sequence[float], y: Sequence[float], higher_is_better: bool = True, confidence: float = 0.95
) -> dict[str, float]:
    """Mean of the per-seed differences ``x_s − y_s`` of two arms that share their seeds (the same
    data and evaluation scenarios), with its Student-t interval (``scipy.stats.ttest_rel``).

    :param x: one score per run of X (:func:`run_scores`), in seed order
    :param y: the same seeds' scores of Y
    :param higher_is_better: ``False`` for costs: the differences are ``y_s − x_s``, so that a
        positive difference always means that X does better
    :param confidence: interval size
    :return: ``{"difference", "ci_low", "ci_high", "runs", "x_better_runs"}``
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"x and y must be paired 1-D score vectors, got shapes {x.shape} and {y.shape}")
    if len(x) < 2:
        raise ValueError(f"a paired interval needs at least 2 runs, got {len(x)}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    better, worse = (x, y) if higher_is_better else (y, x)
    diff = better - worse  # (n_runs,)
    if np.all(diff == diff[0]):  # no spread: the interval is the point (ttest_rel would give NaN)
        low = high = float(diff[0])
    else:
        low, high = scipy.stats.ttest_rel(better, worse).confidence_interval(confidence)
    return {"difference": float(diff.mean()), "ci_low": float(low), "ci_high": float(high), "runs": len(diff),
            "x_better_runs": int(np.sum(diff > 0))}


def verdict(x: str, y: str, paired: Mapping[str, float], unit: str = "") -> str:
    """A sentence that names the interval of a :func:`paired_difference`, not only its sign.

    ``"X vs Y: +3.10 [0.70, 5.50] over 5 paired runs (X ahead in 4): X better"``; the last words are
    ``X better`` / ``Y better`` when the interval excludes 0, ``no difference shown`` otherwise.
    """
    low, high = paired["ci_low"], paired["ci_high"]
    word = f"{x} better" if low > 0 else f"{y} better" if high < 0 else "no difference shown"
    return (f"{x} vs {y}: {paired['difference']:+.2f}{unit} [{low:+.2f}, {high:+.2f}] over {paired['runs']} paired "
            f"runs ({x} ahead in {paired['x_better_runs']}): {word}")


def interval(stat: Mapping[str, float], key: str = "difference", digits: int = 2, sign: str = "+") -> str:
    """A statistic with its interval, ``+3.10 [+0.70, +5.50]`` (``sign="+"``) or ``0.62 [0.40, 0.81]`` (``""``)."""
    spec = f"{sign}.{digits}f"
    return f"{stat[key]:{spec}} [{stat['ci_low']:{spec}}, {stat['ci_high']:{spec}}]"


def learning_curve_area(end_steps: Sequence[float], returns: Sequence[float]) -> float:
    """Area under one run's online learning curve per env step: the return of the episode running at
    each step, averaged over the steps up to the last episode's end, i.e. ``Σ_i R_i ℓ_i / Σ_i ℓ_i``
    with ``ℓ_i`` the length of episode ``i`` in env steps (a run that learns early scores higher than
    one with the same final return that learns late).

    :param end_steps: the env step at which each online episode ended, increasing
    :param returns: the episodes' returns
    """
    ends, rets = np.asarray(end_steps, dtype=np.float64), np.asarray(returns, dtype=np.float64)
    if ends.ndim != 1 or ends.shape != rets.shape or len(ends) == 0:
        raise ValueError(f"end_steps and returns must be non-empty and of one length, got {ends.shape}, {rets.shape}")
    lengths = np.diff(ends, prepend=0.0)  # (n_episodes,)
    if np.any(lengths <= 0):
        raise ValueError("end_steps must be positive and increasing")
    return float(np.sum(rets * lengths) / ends[-1])


def student_t_quantile(confidence: float, df: int) -> float:
    """Two-sided critical value ``t`` with ``P(|T| <= t) = confidence``: the ``(1 + confidence) / 2``
    quantile of Student's t (:data:`scipy.stats.t`).

    :param confidence: in (0, 1), e.g. 0.95 (``t = 2.776`` for ``df = 4``)
    :param df: degrees of freedom, >= 1
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if isinstance(df, bool) or not isinstance(df, int | np.integer) or df < 1:
        raise ValueError(f"df must be an integer >= 1, got {df!r}")
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
        the t interval of the per-seed changes (``per_seed_mean_pct``, ``per_seed_ci95_pct``) and, with
        2 or more seeds, ``paired``: the mean per-seed difference ``new − base`` in the metric's units
        with its t interval (:func:`paired_difference`), which a base near or below 0 cannot distort
    """
    new_a, base_a = np.asarray(new, dtype=np.float64), np.asarray(base, dtype=np.float64)
    if new_a.shape != base_a.shape or new_a.ndim != 1 or new_a.size == 0:
        raise ValueError(f"new and base must be equal-length 1-D sequences, got {new_a.shape} and {base_a.shape}")
    per_seed = [relative_change_pct(float(n), float(b)) for n, b in zip(new_a, base_a, strict=True)]
    finite = [p for p in per_seed if math.isfinite(p)]
    mean, half = t_confidence_interval(finite, confidence) if finite else (math.nan, math.nan)
    out = {
        "change_pct": relative_change_pct(float(new_a.mean()), float(base_a.mean())),
        "per_seed_pct": per_seed,
        "per_seed_mean_pct": mean,
        "per_seed_ci95_pct": half,
    }
    if new_a.size >= 2 and np.all(np.isfinite(new_a)) and np.all(np.isfinite(base_a)):
        out["paired"] = paired_difference(new_a, base_a, confidence=confidence)  # new − base, in the metric's units
    return out


__all__ = [
    "LOWER_IS_BETTER", "interval", "iqm", "iqm_with_ci", "learning_curve_area", "mean_with_ci", "paired_difference",
    "probability_of_improvement", "run_scores", "score_matrix", "verdict",
    "compare", "relative_change_pct", "student_t_quantile", "t_confidence_interval"]
