"""Run-level statistics of the reports after rliable (Agarwal et al., 2021; ``docs/peers.md``), seeded bootstraps."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
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


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")


@contextmanager
def numpy_global_seed(seed: int) -> Iterator[None]:
    """Seed NumPy's legacy global generator inside the block (rliable and OGBench's oracles draw from it), then
    restore it."""
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def _interval_estimates(scores: Mapping[str, Any], func: Any, confidence: float, reps: int, seed: int) -> tuple:
    """rliable's ``get_interval_estimates`` (percentile method) with NumPy's global generator seeded."""
    check_int("reps", reps)
    _check_confidence(confidence)
    library, _ = _rliable()
    with numpy_global_seed(seed), warnings.catch_warnings():  # arch deprecates the RandomState rliable hands it
        warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
        return library.get_interval_estimates(dict(scores), func, reps=reps, confidence_interval_size=confidence,
                                              random_state=np.random.RandomState(seed))  # noqa: NPY002


def run_scores(records: Sequence[Mapping[str, Any]], metric: str, evaluation: str = "evaluation") -> np.ndarray:
    """``(n_runs,)`` in seed order: the mean of ``metric`` over each record's evaluation episodes."""
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
    """rliable's ``(n_runs, 1)`` score matrix of one arm on one task: :func:`run_scores` as a column."""
    return run_scores(records, metric, evaluation)[:, None]  # (n_runs,) -> (n_runs, 1)


def _check_matrix(name: str, scores: Any) -> np.ndarray:
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or scores.size == 0:
        raise ValueError(f"{name} must be a non-empty (n_runs, n_tasks) matrix, got shape {scores.shape}")
    if not np.all(np.isfinite(scores)):
        raise ValueError(f"{name} holds NaN or inf")
    return scores


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean over runs × tasks (25 % trimmed from each end)."""
    return float(_rliable()[1].aggregate_iqm(_check_matrix("scores", scores)))


def _aggregate_with_ci(scores: Mapping[str, np.ndarray], key: str, aggregate: Any, confidence: float, reps: int,
                       seed: int) -> dict[str, dict[str, float]]:
    checked = {name: _check_matrix(f"scores[{name!r}]", matrix) for name, matrix in scores.items()}
    points, intervals = _interval_estimates(checked, lambda m: np.array([aggregate(m)]), confidence, reps, seed)
    return {name: {key: float(points[name][0]), "ci_low": float(intervals[name][0, 0]),
                   "ci_high": float(intervals[name][1, 0])} for name in checked}


def iqm_with_ci(scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000,
                seed: int = 0) -> dict[str, dict[str, float]]:
    """Per arm, the IQM of its ``(n_runs, n_tasks)`` scores with rliable's stratified bootstrap interval."""
    return _aggregate_with_ci(scores, "iqm", _rliable()[1].aggregate_iqm, confidence, reps, seed)


def mean_with_ci(scores: Mapping[str, np.ndarray], confidence: float = 0.95, reps: int = 2000,
                 seed: int = 0) -> dict[str, dict[str, float]]:
    """:func:`iqm_with_ci` of the mean over runs: ``{"mean", "ci_low", "ci_high"}`` per arm."""
    return _aggregate_with_ci(scores, "mean", _rliable()[1].aggregate_mean, confidence, reps, seed)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, higher_is_better: bool = True, confidence: float = 0.95,
                               reps: int = 2000, seed: int = 0) -> dict[str, float]:
    """rliable's ``P(X > Y)`` over the runs of ``x`` and ``y`` with its bootstrap interval (costs negated)."""
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


def paired_difference(x: Sequence[float], y: Sequence[float], higher_is_better: bool = True,
                      confidence: float = 0.95) -> dict[str, float]:
    """Mean per-seed difference ``x_s − y_s`` (``y_s − x_s`` for a cost) with its Student-t interval."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"x and y must be paired 1-D score vectors, got shapes {x.shape} and {y.shape}")
    if len(x) < 2:
        raise ValueError(f"a paired interval needs at least 2 runs, got {len(x)}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    _check_confidence(confidence)
    better, worse = (x, y) if higher_is_better else (y, x)
    diff = better - worse  # (n_runs,)
    if np.all(diff == diff[0]):  # no spread: the interval is the point (ttest_rel would give NaN)
        low = high = float(diff[0])
    else:
        low, high = scipy.stats.ttest_rel(better, worse).confidence_interval(confidence)
    return {"difference": float(diff.mean()), "ci_low": float(low), "ci_high": float(high), "runs": len(diff),
            "x_better_runs": int(np.sum(diff > 0))}


def verdict(x: str, y: str, paired: Mapping[str, float], unit: str = "") -> str:
    """A sentence naming a :func:`paired_difference` with its interval and what it shows."""
    low, high = paired["ci_low"], paired["ci_high"]
    word = f"{x} better" if low > 0 else f"{y} better" if high < 0 else "no difference shown"
    return (f"{x} vs {y}: {paired['difference']:+.2f}{unit} [{low:+.2f}, {high:+.2f}] over {paired['runs']} paired "
            f"runs ({x} ahead in {paired['x_better_runs']}): {word}")


def interval(stat: Mapping[str, float], key: str = "difference", digits: int = 2, sign: str = "+") -> str:
    """A statistic with its interval, ``+3.10 [+0.70, +5.50]`` (``sign="+"``) or ``0.62 [0.40, 0.81]`` (``""``)."""
    spec = f"{sign}.{digits}f"
    return f"{stat[key]:{spec}} [{stat['ci_low']:{spec}}, {stat['ci_high']:{spec}}]"


def learning_curve_area(end_steps: Sequence[float], returns: Sequence[float]) -> float:
    """Area under one run's online learning curve per env step, ``Σ_i R_i ℓ_i / Σ_i ℓ_i``."""
    ends, rets = np.asarray(end_steps, dtype=np.float64), np.asarray(returns, dtype=np.float64)
    if ends.ndim != 1 or ends.shape != rets.shape or len(ends) == 0:
        raise ValueError(f"end_steps and returns must be non-empty and of one length, got {ends.shape}, {rets.shape}")
    lengths = np.diff(ends, prepend=0.0)  # (n_episodes,)
    if np.any(lengths <= 0):
        raise ValueError("end_steps must be positive and increasing")
    return float(np.sum(rets * lengths) / ends[-1])


def student_t_quantile(confidence: float, df: int) -> float:
    """Two-sided critical value of Student's t with ``df`` degrees of freedom (2.776 for 0.95 and ``df = 4``)."""
    _check_confidence(confidence)
    if isinstance(df, bool) or not isinstance(df, int | np.integer) or df < 1:
        raise ValueError(f"df must be an integer >= 1, got {df!r}")
    return float(scipy.stats.t.ppf((1.0 + confidence) / 2.0, df))


def t_confidence_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float]:
    """Mean and half-width ``t · s / √n`` of the Student-t interval over seeds (NaN half-width for one value)."""
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
    """``100 · (new − base) / |base|`` (rewards may be negative); NaN when ``base`` is 0 or a value is not finite."""
    if base == 0 or not (math.isfinite(new) and math.isfinite(base)):
        return math.nan
    return 100.0 * (new - base) / abs(base)


def compare(new: Sequence[float], base: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """Relative change of paired per-seed values (of the means, and per seed) and their paired difference."""
    new_a, base_a = np.asarray(new, dtype=np.float64), np.asarray(base, dtype=np.float64)
    if new_a.shape != base_a.shape or new_a.ndim != 1 or new_a.size == 0:
        raise ValueError(f"new and base must be equal-length 1-D sequences, got {new_a.shape} and {base_a.shape}")
    per_seed = [relative_change_pct(float(n), float(b)) for n, b in zip(new_a, base_a, strict=True)]
    summary = t_summary(per_seed, confidence)
    out = {"change_pct": relative_change_pct(float(new_a.mean()), float(base_a.mean())), "per_seed_pct": per_seed,
           "per_seed_mean_pct": summary["mean"], "per_seed_ci95_pct": summary["ci95"]}
    if new_a.size >= 2 and np.all(np.isfinite(new_a)) and np.all(np.isfinite(base_a)):
        out["paired"] = paired_difference(new_a, base_a, confidence=confidence)  # new − base, in the metric's units
    return out


def t_summary(values: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """``{"mean", "ci95", "per_seed"}``: :func:`t_confidence_interval` of the finite ``values`` (NaN without any)."""
    finite = [v for v in values if math.isfinite(v)]
    mean, half = t_confidence_interval(finite, confidence) if finite else (math.nan, math.nan)
    return {"mean": mean, "ci95": half, "per_seed": list(values)}
