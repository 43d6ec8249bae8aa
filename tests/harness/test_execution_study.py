"""The execution-rule study (``python -m experiments execution``): the controls, the run-level report on
hand-made records, and bad input."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch as th
from extras import require

from envs.evaluation import EpisodeMetrics, plan_length_shares
from experiments.execution import cli
from experiments.execution.controls import FixedCut, RandomCut
from experiments.execution.report import markdown, run_score, secondary_lines, summarize


def test_plan_length_shares_by_hand():
    def episode(lengths):
        return EpisodeMetrics(0, 0.0, 1, 0.0, False, False, 0.0, 1.0, plan_lengths=tuple(lengths))

    assert plan_length_shares([episode([1, 1]), episode([3, 5])], 5) == [0.5, 0.0, 0.25, 0.0, 0.25]
    assert plan_length_shares([episode([])], 3) == [0.0, 0.0, 0.0]


def test_random_cut_draws_the_given_histogram_whatever_the_entropies():
    cut = RandomCut([0.5, 0.0, 0.25, 0.0, 0.25], seed=0)
    lengths = th.cat([cut(th.zeros(1000, 5)), cut(th.full((1000, 5), 9.0))])
    counts = np.bincount(lengths.numpy(), minlength=6)[1:] / lengths.numel()
    np.testing.assert_allclose(counts, [0.5, 0.0, 0.25, 0.0, 0.25], atol=0.03)
    again = RandomCut([0.5, 0.0, 0.25, 0.0, 0.25], seed=0)
    assert th.equal(again(th.zeros(1000, 5)), lengths[:1000])  # seeded
    assert FixedCut(2, 5)(th.zeros(4, 5)).tolist() == [2, 2, 2, 2]


@pytest.mark.parametrize("shares", [[0.5, 0.6], [-0.1, 1.1], []])
def test_random_cut_refuses_shares_that_are_not_probabilities(shares):
    with pytest.raises(ValueError, match="shares must be probabilities"):
        RandomCut(shares, seed=0)


def test_fixed_cut_refuses_a_length_outside_the_chunk():
    with pytest.raises(ValueError, match="length must be in \\[1, 5\\]"):
        FixedCut(6, 5)


def _entry(rewards, shares=(0.0, 1.0)):
    return {"episodes": [{"reward": r, "collision": r < 0} for r in rewards], "length_shares": list(shares)}


def _record(seed, fixed, rule, random_cut, fixed_k):
    modes = {"fixed": fixed, "growth0.5": rule, "growth0.5:random": random_cut, "growth0.5:fixed_k": fixed_k}
    return {"seed": seed, "checkpoints": {"offline": {arm: {"deterministic": _entry(r), "sampled": _entry(r)}
                                                      for arm, r in modes.items()}}}


def test_summary_pairs_each_rule_with_fixed_and_its_controls_per_seed():
    records = [_record(1, [10, 20], [30, 30], [10, 10], [20, 40]),
               _record(0, [0, 0], [10, 30], [20, 20], [-10, 10])]
    table = summarize(records)["offline"]["deterministic"]
    assert table["fixed"]["per_seed"] == [0.0, 15.0]  # seed order, one score per run
    assert table["growth0.5"]["per_seed"] == [20.0, 30.0]
    paired = table["growth0.5"]["paired"]
    # differences per seed: − fixed (20, 15) -> 17.5; − random cut (0, 20) -> 10; − fixed k' (20, 0) -> 10
    assert paired["fixed"]["difference"] == pytest.approx(17.5)
    assert paired["growth0.5:random"]["difference"] == pytest.approx(10.0)
    # t interval with 1 degree of freedom: 10 ± 12.706 × SD(0, 20)/√2 = 10 ± 127.06
    assert paired["growth0.5:fixed_k"]["ci_low"] == pytest.approx(10.0 - 127.062, abs=1e-2)
    assert table["fixed"]["collision"] == 0.0 and table["growth0.5:fixed_k"]["collision"] == 0.25
    assert "| growth0.5 | 25.0 | 0.00 | 0 100 | +17.5 [" in markdown(summarize(records), ["header"])
    assert run_score(_entry([1, 2, 6]), "reward") == 3.0


def test_second_score_section_gives_the_overview_of_its_own_metric():
    records = [_record(1, [10, 20], [30, 30], [10, 10], [20, 40]),
               _record(0, [0, 0], [10, 30], [20, 20], [-10, 10])]
    lines = secondary_lines("reward", "the same runs", summarize(records), {})
    assert lines[0] == "## Second score: reward (the same runs)"
    # both modes alike: − fixed 17.5, − random cut 10, − fixed k' 10 (see above); L_t = 2 in every plan; 2 cells
    assert "| growth0.5 | +17.5 | +10.0 | +10.0 | 2.00 | 2 |" in lines
    report = markdown(summarize(records), ["header"], secondary=lines)
    assert report.index("## Second score") < report.index("## offline, deterministic")


def test_cli_refuses_unknown_rules_and_a_screen_without_fixed(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--rules", "delta0", "entropy9"])
    assert "unknown rules ['entropy9']" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["--rules", "delta0", "growth0.5"])
    assert "--rules must include 'fixed'" in capsys.readouterr().err


def test_report_only_without_stored_runs_names_them(tmp_path, capsys):
    assert cli.main(["--report-only", "--seeds", "3", "--out", str(tmp_path)]) == 2
    assert "no stored runs for ['seed3']" in capsys.readouterr().err


def test_estimate_counts_training_and_every_evaluation():
    # 1 seed, 2 online rules, 3 rules evaluated, 10 episodes, 1 worker:
    # 70 + 2 × 55 = 180 s training; 3 checkpoints × (3·3 − 2) arms × 2 modes × 10 × 0.6 s = 252 s
    assert cli.estimate_minutes(1, 2, 3, 10, 1) == pytest.approx((180 + 252) / 60)


@pytest.mark.slow
def test_quick_run_end_to_end_writes_the_report_and_resumes(tmp_path, capsys):
    import json

    args = ["--quick", "--seeds", "0", "--workers", "1", "--online", "delta0", "--rules", "fixed", "delta0",
            "growth0.5", "--out", str(tmp_path)]
    assert cli.main(args) == 0
    summary = json.loads((tmp_path / "execution_development.json").read_text())["summary"]
    assert set(summary) == {"offline", "online_delta0"}
    table = summary["online_delta0"]["sampled"]
    assert set(table) == {"fixed", "delta0", "delta0:random", "delta0:fixed_k", "growth0.5", "growth0.5:random",
                          "growth0.5:fixed_k"}
    assert table["fixed"]["length_shares"][-1] == 1.0  # fixed chunks execute all k actions
    assert sum(table["growth0.5"]["length_shares"]) == pytest.approx(1.0)
    record = json.loads((tmp_path / "execution_work" / "development" / "seed0.json").read_text())
    assert record["scenario_seed"] == 3000 and record["checkpoints"]["offline"]["fixed"]["deterministic"]["episodes"]
    capsys.readouterr()
    assert cli.main(args) == 0  # the stored run is reused
    assert "unit seed0" not in capsys.readouterr().out


def test_ogbench_quick_run_scores_success_on_its_own_scenarios(tmp_path, capsys):
    require("ogbench")
    from experiments.ogbench.unit import EVAL_SEED_BASE, VALIDATION_SEED_BASE

    argv = ["--env", "ogbench", "--quick", "--seeds", "0", "1", "--rules", "fixed", "growth0.5", "--online", "fixed",
            "--out", str(tmp_path), "--workers", "1"]
    assert cli.main(argv) == 0
    records = [json.loads((tmp_path / "execution_work" / "ogbench_development" / f"seed{s}.json").read_text())
               for s in (0, 1)]
    assert [r["scenario_seed"] for r in records] == [VALIDATION_SEED_BASE, VALIDATION_SEED_BASE + 1000]
    assert VALIDATION_SEED_BASE != EVAL_SEED_BASE  # the screen never sees the reported scenarios
    offline = records[1]["checkpoints"]["offline"]
    assert sorted(offline) == ["fixed", "growth0.5", "growth0.5:fixed_k", "growth0.5:random"]
    episode = offline["growth0.5"]["sampled"]["episodes"][0]
    assert set(episode) == {"success", "return", "length"} and episode["success"] in (0.0, 1.0)
    assert offline["fixed"]["deterministic"]["length_shares"] == [0.0, 0.0, 0.0, 0.0, 1.0]  # k = 5, whole chunks
    assert sorted(records[0]["checkpoints"]) == ["offline", "online_fixed"]
    report = (tmp_path / "execution_ogbench_development.md").read_text()
    assert report.startswith("# Execution rules on pointmaze-medium-navigate-singletask-task1-v0")
    assert "| arm | success (mean of runs) | collision |" in report
    assert re.search(r"^\| fixed \| [01]\.\d\d \| — \| 0 0 0 0 100 \|", report, re.M)  # a rate, no collisions
    summary = json.loads((tmp_path / "execution_ogbench_development.json").read_text())["summary"]
    fixed = summary["offline"]["deterministic"]["fixed"]
    assert fixed["collision"] is None
    assert fixed["per_seed"] == [run_score(r["checkpoints"]["offline"]["fixed"]["deterministic"], "success")
                                 for r in records]
    second = json.loads((tmp_path / "execution_ogbench_development.json").read_text())["second_score"]
    assert second["metric"] == "return" and "## Second score: return (" in report
    assert second["summary"]["offline"]["deterministic"]["fixed"]["per_seed"] == [
        run_score(r["checkpoints"]["offline"]["fixed"]["deterministic"], "return") for r in records]


def test_task_is_only_for_ogbench(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--task", "pointmaze-medium-navigate-singletask-task1-v0"])
    assert "--task is for --env ogbench" in capsys.readouterr().err
