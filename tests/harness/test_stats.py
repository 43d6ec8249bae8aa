"""Run-level statistics of the reports (experiments.common.stats) on hand-checkable inputs."""

from __future__ import annotations

import numpy as np
import pytest
from extras import require

require("rliable")

from experiments.common.stats import (  # noqa: E402
    iqm,
    iqm_with_ci,
    learning_curve_area,
    mean_with_ci,
    paired_difference,
    probability_of_improvement,
    run_scores,
    score_matrix,
    verdict,
)


def record(seed: int, rewards: list[float], **extra) -> dict:
    return {"seed": seed, "evaluation": {"episodes": [{"reward": r, "collision": r < 0} for r in rewards]}, **extra}


def test_a_run_scores_the_mean_of_its_episodes_in_seed_order():
    records = [record(2, [4.0, -2.0]), record(0, [1.0, 2.0, 3.0])]
    assert run_scores(records, "reward").tolist() == [2.0, 1.0]
    assert run_scores(records, "collision").tolist() == [0.0, 0.5]  # booleans: the run's rate
    assert score_matrix(records, "reward").tolist() == [[2.0], [1.0]]  # rliable: (n_runs, n_tasks = 1)
    offline = [{"seed": 0, "offline_evaluation": {"episodes": [{"reward": 7.0}]}}]
    assert run_scores(offline, "reward", evaluation="offline_evaluation").tolist() == [7.0]
    with pytest.raises(ValueError, match="'speed' is not in"):
        run_scores(records, "speed")
    with pytest.raises(ValueError, match="no evaluation episodes"):
        run_scores([record(0, [])], "reward")
    with pytest.raises(ValueError, match="records must not be empty"):
        run_scores([], "reward")


def test_the_bootstrap_resamples_runs_not_episodes():
    """Two runs, every episode of run 0 scores 0 and of run 1 scores 10. Resampling the 2 runs gives
    the means 0, 5 and 10 with probabilities 1/4, 1/2, 1/4, so the 95 % interval is [0, 10]. The old
    protocol (episodes as rliable tasks, runs resampled per episode column) averages 4 independent
    columns: its mean falls to 1.25 or below with probability 1/256 + 4 · (1/2) · (1/4)³ ≈ 3.5 %,
    so its interval is [1.25, 8.75], as if the 8 episodes were replications."""
    runs = [record(0, [0.0] * 4), record(1, [10.0] * 4)]
    out = mean_with_ci({"x": score_matrix(runs, "reward")}, reps=4000)["x"]
    assert out == {"mean": 5.0, "ci_low": 0.0, "ci_high": 10.0}
    episodes_as_tasks = np.array([[0.0] * 4, [10.0] * 4])  # (n_runs, n_episodes): the old layout
    old = mean_with_ci({"x": episodes_as_tasks}, reps=4000)["x"]
    assert (old["mean"], old["ci_low"], old["ci_high"]) == (5.0, 1.25, 8.75)  # narrower than 2 runs allow


def test_iqm_is_the_mean_of_the_middle_half_of_the_runs():
    assert iqm(np.arange(1.0, 9.0)[:, None]) == pytest.approx(4.5)  # mean(3, 4, 5, 6)
    assert iqm(np.array([[0.0], [1.0], [1.0], [100.0]])) == pytest.approx(1.0)  # outlier runs trimmed
    scores = {"a": np.random.default_rng(0).normal(10, 1, (10, 1)), "flat": np.full((5, 1), 3.0)}
    out = iqm_with_ci(scores, reps=500)
    assert out["flat"] == {"iqm": 3.0, "ci_low": 3.0, "ci_high": 3.0}
    assert out["a"]["iqm"] == pytest.approx(iqm(scores["a"]))
    assert out["a"]["ci_low"] < out["a"]["iqm"] < out["a"]["ci_high"]
    assert iqm_with_ci(scores, reps=500)["a"] == out["a"]  # seeded bootstrap
    state = np.random.get_state()  # noqa: NPY002  (rliable draws from the legacy global generator)
    iqm_with_ci(scores, reps=50)
    assert np.array_equal(np.random.get_state()[1], state[1])  # noqa: NPY002  # the caller's global generator is restored


def test_probability_of_improvement_over_runs_by_hand():
    # run pairs (1 > 2, 1 > 4, 3 > 2, 3 > 4): 1 of 4
    assert probability_of_improvement(np.array([[1.0], [3.0]]), np.array([[2.0], [4.0]]), reps=200)["probability"] == 0.25
    # ties count one half: (5 > 5 tie, 5 > 1, 6 > 5, 6 > 1) -> (0.5 + 1 + 1 + 1) / 4
    assert probability_of_improvement(np.array([[5.0], [6.0]]), np.array([[5.0], [1.0]]),
                                      reps=200)["probability"] == 0.875
    # costs: fewer collisions is better
    out = probability_of_improvement(np.zeros((3, 1)), np.ones((3, 1)), higher_is_better=False, reps=200)
    assert out == {"probability": 1.0, "ci_low": 1.0, "ci_high": 1.0}


def test_paired_difference_is_scipys_t_interval():
    # differences 2, 3, 2, 1: mean 2, sd sqrt(2/3), half width t(0.975, 3) * sd / 2 = 3.18245 * 0.40825
    out = paired_difference([3.0, 5.0, 4.0, 6.0], [1.0, 2.0, 2.0, 5.0])
    assert out["difference"] == 2.0 and out["runs"] == 4 and out["x_better_runs"] == 4
    assert out["ci_low"] == pytest.approx(2.0 - 1.299228, abs=1e-6)
    assert out["ci_high"] == pytest.approx(2.0 + 1.299228, abs=1e-6)
    cost = paired_difference([0.1, 0.2], [0.3, 0.3], higher_is_better=False)  # X collides less
    assert cost["difference"] == pytest.approx(0.15) and cost["x_better_runs"] == 2
    assert paired_difference([1.0, 2.0], [0.0, 1.0]) == {
        "difference": 1.0, "ci_low": 1.0, "ci_high": 1.0, "runs": 2, "x_better_runs": 2}  # no spread
    with pytest.raises(ValueError, match="at least 2 runs"):
        paired_difference([1.0], [0.0])
    with pytest.raises(ValueError, match="paired 1-D"):
        paired_difference([1.0, 2.0], [0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        paired_difference([1.0, np.nan], [0.0, 1.0])


def test_verdict_follows_the_interval_not_the_sign():
    ahead = paired_difference([3.0, 5.0, 4.0, 6.0], [1.0, 2.0, 2.0, 5.0])
    assert verdict("UA2C", "SAC", ahead) == "UA2C vs SAC: +2.00 [+0.70, +3.30] over 4 paired runs (UA2C ahead in 4): UA2C better"
    unsure = paired_difference([3.0, 0.0, 4.0], [1.0, 2.0, 2.0])  # mean +0.67, interval spans 0
    assert verdict("UA2C", "SAC", unsure).endswith("(UA2C ahead in 2): no difference shown")
    behind = paired_difference([1.0, 2.0, 2.0, 5.0], [3.0, 5.0, 4.0, 6.0])
    assert verdict("UA2C", "SAC", behind).endswith("SAC better")
    assert "%" not in verdict("UA2C", "SAC", behind)


def test_learning_curve_area_weights_each_return_by_its_episode_length():
    # episode 1 runs steps 1-10 with return 1, episode 2 steps 11-30 with return 2: (10 + 40) / 30
    assert learning_curve_area([10, 30], [1.0, 2.0]) == pytest.approx(50.0 / 30.0)
    early, late = learning_curve_area([10, 20, 30], [0.0, 5.0, 5.0]), learning_curve_area([10, 20, 30], [0.0, 0.0, 5.0])
    assert early > late  # the same final return, learnt earlier
    with pytest.raises(ValueError, match="increasing"):
        learning_curve_area([10, 10], [1.0, 2.0])
    with pytest.raises(ValueError, match="non-empty"):
        learning_curve_area([], [])


def test_bad_matrices_are_refused():
    with pytest.raises(ValueError, match="matrix"):
        iqm(np.ones(4))
    with pytest.raises(ValueError, match="NaN"):
        iqm_with_ci({"a": np.array([[1.0], [np.nan]])})
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement(np.ones((2, 3)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="reps"):
        mean_with_ci({"x": np.ones((2, 1))}, reps=0)
    with pytest.raises(ValueError, match="confidence"):
        mean_with_ci({"x": np.ones((2, 1))}, confidence=1.5)
