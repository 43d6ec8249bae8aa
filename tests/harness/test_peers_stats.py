"""rliable statistics of the head-to-head (experiments.common.stats) on hand-checkable inputs."""

from __future__ import annotations

import numpy as np
import pytest
from extras import require

require("rliable")

from experiments.common.stats import (  # noqa: E402
    iqm,
    iqm_with_ci,
    mean_with_ci,
    probability_of_improvement,
    score_matrix,
    stratified_resamples,
)


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.arange(1, 9).reshape(2, 4)) == pytest.approx(4.5)  # mean(3, 4, 5, 6)
    assert iqm(np.array([[0, 0, 1, 1], [1, 1, 100, 100]])) == pytest.approx(1.0)  # outliers trimmed


def test_iqm_interval_contains_the_point_and_is_reproducible():
    rng = np.random.default_rng(0)
    scores = {"a": rng.normal(10, 1, (5, 20)), "flat": np.full((5, 20), 3.0)}
    out = iqm_with_ci(scores, reps=500)
    assert out["flat"] == {"iqm": 3.0, "ci_low": 3.0, "ci_high": 3.0}
    a = out["a"]
    assert a["iqm"] == pytest.approx(iqm(scores["a"]))
    assert a["ci_low"] < a["iqm"] < a["ci_high"] and a["ci_high"] - a["ci_low"] < 1.0
    assert iqm_with_ci(scores, reps=500)["a"] == a  # seeded bootstrap


def test_mean_of_a_rare_event_is_its_rate_where_the_iqm_reads_zero():
    # 2 collisions in 10 episodes (5 seeds x 2): rate 0.2, but both 1s sit in the trimmed top quarter
    collisions = np.array([[0, 0], [0, 1], [0, 0], [1, 0], [0, 0]], dtype=float)
    assert iqm(collisions) == 0.0
    out = mean_with_ci({"x": collisions}, reps=500)["x"]
    assert out["mean"] == pytest.approx(0.2)
    assert 0.0 <= out["ci_low"] < 0.2 < out["ci_high"] <= 1.0
    assert mean_with_ci({"x": collisions}, reps=500)["x"] == out  # seeded bootstrap
    with pytest.raises(ValueError, match="reps"):
        mean_with_ci({"x": collisions}, reps=0)


def test_probability_of_improvement_by_hand():
    # one episode column: pairs (1 > 2, 1 > 4, 3 > 2, 3 > 4) -> 1 of 4
    assert probability_of_improvement(np.array([[1.0], [3.0]]), np.array([[2.0], [4.0]]), reps=200)["probability"] == 0.25
    # two columns: 1.0 in the first, ties (0.5 each) in the second -> mean 0.75
    x, y = np.array([[5.0, 1.0], [6.0, 1.0]]), np.array([[1.0, 1.0], [2.0, 1.0]])
    assert probability_of_improvement(x, y, reps=200)["probability"] == 0.75
    # costs: fewer collisions is better
    out = probability_of_improvement(np.zeros((3, 2)), np.ones((3, 2)), higher_is_better=False, reps=200)
    assert out == {"probability": 1.0, "ci_low": 1.0, "ci_high": 1.0}


def test_score_matrix_orders_seeds_and_reads_booleans():
    def record(seed, collisions):
        return {"seed": seed, "evaluation": {"episodes": [{"collision": c, "reward": 1.0} for c in collisions]}}

    m = score_matrix([record(2, [True, False]), record(0, [False, False])], "collision")
    assert m.tolist() == [[0.0, 0.0], [1.0, 0.0]]
    with pytest.raises(ValueError, match="same number of evaluation episodes"):
        score_matrix([record(0, [True]), record(1, [True, False])], "collision")
    with pytest.raises(ValueError, match="'speed' is not in"):
        score_matrix([record(0, [True])], "speed")


def test_bad_matrices_are_refused():
    with pytest.raises(ValueError, match="matrix"):
        iqm(np.ones(4))
    with pytest.raises(ValueError, match="NaN"):
        iqm_with_ci({"a": np.array([[1.0, np.nan]])})
    with pytest.raises(ValueError, match="same episode columns"):
        probability_of_improvement(np.ones((2, 3)), np.ones((2, 2)))


def test_stratified_resamples_draw_seeds_within_each_column():
    scores = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]])
    boot = stratified_resamples(scores, 50, np.random.default_rng(1))
    assert boot.shape == (50, 3, 2)
    assert set(np.unique(boot[:, :, 0])) <= {1.0, 2.0, 3.0} and set(np.unique(boot[:, :, 1])) <= {10.0, 20.0, 30.0}
    # the columns are drawn independently: some copy pairs row i of column 0 with another row of column 1
    assert np.any(boot[:, :, 1] != 10.0 * boot[:, :, 0])


def test_bad_bootstrap_settings_are_refused():
    with pytest.raises(ValueError, match="confidence"):
        iqm_with_ci({"a": np.ones((2, 2))}, confidence=95)
    with pytest.raises(ValueError, match="reps"):
        probability_of_improvement(np.ones((2, 2)), np.ones((2, 2)), reps=0)
