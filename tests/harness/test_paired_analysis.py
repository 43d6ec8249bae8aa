"""``python -m experiments paired``: the paired difference of two arms across runs, on hand-made
records with hand-computed intervals, and what bad input gets."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.analysis import paired

# Student-t quantile t_{0.975, 2} (tables): the 95 % interval of a mean of 3 paired differences.
T_975_2 = 4.302653


def _write_arm(raw: Path, arm: str, rewards: dict[int, list[float]], data_seed: int = 7, base: int = 4000,
               offline: bool = True) -> None:
    """One record per seed, ``rewards[seed]`` its evaluation episodes' rewards."""
    for seed, episode_rewards in rewards.items():
        episodes = [{"reward": r, "cumulative_jerk": 10.0 * r} for r in episode_rewards]
        record = {"arm": arm, "seed": seed, "dataset": {"seed": data_seed + seed}, "eval_seeds": [base + seed],
                  "evaluation": {"episodes": episodes},
                  "offline_evaluation": {"episodes": [{"reward": 0.0}]} if offline else None}
        (raw / f"seed{seed}").mkdir(parents=True, exist_ok=True)
        (raw / f"seed{seed}" / f"{arm}.json").write_text(json.dumps(record))


@pytest.fixture
def runs(tmp_path):
    """Two runs: ``a`` with arm ``x`` on seeds 1-3, ``b`` with arm ``y`` on seeds 1-4 (seed 4 unpaired).
    Run scores (episode means): x = 3, 5, 8; y = 2, 3, 5, 100; differences 1, 2, 3."""
    a, b = tmp_path / "a" / "peers_raw", tmp_path / "b" / "peers_raw"
    _write_arm(a, "x", {1: [2.0, 4.0], 2: [5.0, 5.0], 3: [8.0, 8.0]})
    _write_arm(b, "y", {1: [2.0, 2.0], 2: [1.0, 5.0], 3: [5.0, 5.0], 4: [100.0, 100.0]})
    return a, b


def test_pairs_across_runs_with_the_hand_computed_interval(runs):
    a, b = runs
    result = paired.pair(paired.load_scores(f"{a}:x", "reward", "evaluation"),
                         paired.load_scores(f"{b}:y", "reward", "evaluation"))
    # differences 1, 2, 3: mean 2, sample sd 1, standard error 1/sqrt(3)
    half = T_975_2 / 3 ** 0.5
    assert result["seeds"] == [1, 2, 3]
    assert result["x_mean"] == pytest.approx(16 / 3) and result["y_mean"] == pytest.approx(10 / 3)
    assert result["difference"] == pytest.approx(2.0)
    assert result["ci_low"] == pytest.approx(2.0 - half, abs=1e-5)
    assert result["ci_high"] == pytest.approx(2.0 + half, abs=1e-5)
    assert result["x_better_runs"] == 3 and result["runs"] == 3


def test_a_cost_reports_y_minus_x(runs):
    a, b = runs
    x = paired.load_scores(f"{a}:x", "cumulative_jerk", "evaluation")
    y = paired.load_scores(f"{b}:y", "cumulative_jerk", "evaluation")
    result = paired.pair(x, y, higher_is_better=False)
    assert result["difference"] == pytest.approx(-20.0)  # x's jerk is 10, 20, 30 above y's: x is worse
    assert result["x_better_runs"] == 0


def test_a_report_list_pairs_with_its_nearest_seeds(tmp_path, runs):
    a, _ = runs
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"seeds": [9, 9], "arms": {"z": {"seeds": [3, 2, 1], "online": [7.0, 4.0, 4.0]}}}))
    z = paired.load_scores(f"{report}:arms.z.online", "reward", "evaluation")
    assert z.scores == {3: 7.0, 2: 4.0, 1: 4.0}  # the arm's own seeds, not the top level's
    result = paired.pair(paired.load_scores(f"{a}:x", "reward", "evaluation"), z)
    assert result["difference"] == pytest.approx((-1 + 1 + 1) / 3)


def test_main_prints_the_difference(runs, capsys):
    a, b = runs
    assert paired.main([f"{a}:x", f"{b}:y"]) == 0
    out = capsys.readouterr().out
    assert "+2.00 [-0.48, +4.48]" in out and "X ahead in 3 of 3 runs" in out


def test_a_best_of_n_row_reads_the_peers_records(tmp_path, runs):
    a, b = runs
    for f in sorted(b.glob("seed*/y.json")):  # y acting by the best of N: its rewards + 10
        record = json.loads(f.read_text())
        best = [{**e, "reward": e["reward"] + 10.0} for e in record["evaluation"]["episodes"]]
        f.write_text(json.dumps({**record, "evaluation_best_of_n": {"episodes": best}}))
    best = paired.load_scores(f"{b}:y_best_of_n", "reward", "evaluation")
    assert best.scores == {1: 12.0, 2: 13.0, 3: 15.0, 4: 110.0}
    result = paired.pair(paired.load_scores(f"{a}:x", "reward", "evaluation"), best)
    assert result["difference"] == pytest.approx(-8.0)
    with pytest.raises(ValueError, match="has no 'evaluation_best_of_n'$"):  # x has no best-of-N evaluation
        paired.load_scores(f"{a}:x_best_of_n", "reward", "evaluation")


@pytest.mark.parametrize("spec, message", [
    ("nocolon", "expected RAW_DIR:ARM"),
    ("{a}:missing", "no records of arm 'missing'"),
    ("{tmp}/nodir:x", "no directory"),
    ("{tmp}/none.json:arms", "no file"),
])
def test_bad_specs_name_the_problem(tmp_path, runs, spec, message, capsys):
    a, b = runs
    with pytest.raises(SystemExit) as exc:
        paired.main([spec.format(a=a, tmp=tmp_path), f"{b}:y"])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_different_scenarios_are_not_paired(tmp_path, runs):
    a, _ = runs
    c = tmp_path / "c"
    _write_arm(c, "y", {1: [1.0], 2: [1.0]}, base=2000)  # other evaluation scenarios
    with pytest.raises(ValueError, match="not paired: on seed"):
        paired.pair(paired.load_scores(f"{a}:x", "reward", "evaluation"),
                    paired.load_scores(f"{c}:y", "reward", "evaluation"))


def test_too_few_shared_seeds_and_missing_offline_evaluation(tmp_path, runs):
    a, _ = runs
    d = tmp_path / "d"
    _write_arm(d, "y", {3: [1.0], 5: [1.0]}, offline=False)
    with pytest.raises(ValueError, match="share 1 seed"):
        paired.pair(paired.load_scores(f"{a}:x", "reward", "evaluation"),
                    paired.load_scores(f"{d}:y", "reward", "evaluation"))
    with pytest.raises(ValueError, match="has no 'offline_evaluation'"):
        paired.load_scores(f"{d}:y", "reward", "offline_evaluation")


def test_a_report_key_that_is_not_a_score_list(tmp_path):
    report = tmp_path / "r.json"
    report.write_text(json.dumps({"seeds": [1, 2], "a": {"b": [1.0, 2.0, 3.0]}, "c": "text"}))
    with pytest.raises(ValueError, match="no key 'x' at a"):
        paired.load_scores(f"{report}:a.x", "reward", "evaluation")
    with pytest.raises(ValueError, match="has 3 scores but the nearest 'seeds'"):
        paired.load_scores(f"{report}:a.b", "reward", "evaluation")
    with pytest.raises(ValueError, match="not a list of numbers"):
        paired.load_scores(f"{report}:c", "reward", "evaluation")


def test_the_printed_line_says_which_way_is_better_for_a_cost(runs, capsys):
    a, b = runs
    assert paired.main([f"{a}:x", f"{b}:y", "--metric", "cumulative_jerk"]) == 0
    out = capsys.readouterr().out  # x's jerk is 10, 20, 30 above y's on the 3 seeds
    assert "X − Y (a cost: X better when < 0" in out and "+20.00" in out and "X higher in 3 of 3 runs" in out
    assert paired.main([f"{a}:x", f"{b}:y", "--metric", "cumulative_jerk", "--lower-is-better"]) == 0
    out = capsys.readouterr().out
    assert "Y − X (lower is better), X better when > 0" in out and "-20.00" in out and "X ahead in 0 of 3 runs" in out
