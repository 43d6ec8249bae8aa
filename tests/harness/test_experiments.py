"""Figure-2 experiment runner: statistics, budget validation, aggregation and a quick end-to-end run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from experiments.common import names
from experiments.common.budget import library_default
from experiments.common.names import delta_name
from experiments.common.records import command_line, strict_json
from experiments.common.runner import list_schedule_seconds
from experiments.common.stats import (
    compare,
    relative_change_pct,
    student_t_quantile,
    t_confidence_interval,
)
from experiments.fig2 import budget as fig2_budget
from experiments.fig2 import cli as fig2_cli
from experiments.fig2 import units
from experiments.fig2.aggregation import aggregate, online_curve, online_phase_stats
from experiments.fig2.budget import FULL_BUDGET, QUICK_BUDGET, Fig2Budget, estimate_seconds
from experiments.fig2.report import format_markdown

DEFAULT_ELITE = library_default("policy_kwargs")["n_elite"]


# ---------------------------------------------------------------------------------------------
# statistics
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("df", "expected"),  # two-sided 95% critical values of Student's t (standard tables)
    [(1, 12.7062), (2, 4.3027), (4, 2.7764), (9, 2.2622), (30, 2.0423)],
)
def test_student_t_quantile_matches_tables(df: int, expected: float) -> None:
    assert student_t_quantile(0.95, df) == pytest.approx(expected, abs=1e-4)


def test_student_t_quantile_checks_its_arguments() -> None:
    with pytest.raises(ValueError, match="df"):
        student_t_quantile(0.95, 0)
    with pytest.raises(ValueError, match="confidence"):
        student_t_quantile(1.5, 3)


def test_t_confidence_interval_by_hand() -> None:
    # [1..5]: mean 3, sd sqrt(2.5), half = 2.776445 * sqrt(2.5) / sqrt(5) = 1.963243
    mean, half = t_confidence_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    assert mean == 3.0
    assert half == pytest.approx(1.963243, abs=1e-5)
    mean, half = t_confidence_interval([7.5])
    assert mean == 7.5 and math.isnan(half)
    with pytest.raises(ValueError, match="finite"):
        t_confidence_interval([1.0, math.nan])
    with pytest.raises(ValueError, match="non-empty"):
        t_confidence_interval([])


def test_relative_change_uses_the_magnitude_of_the_baseline() -> None:
    assert relative_change_pct(110.0, 100.0) == pytest.approx(10.0)
    assert relative_change_pct(-90.0, -100.0) == pytest.approx(10.0)  # less negative = better
    assert relative_change_pct(-110.0, -100.0) == pytest.approx(-10.0)
    assert math.isnan(relative_change_pct(1.0, 0.0))


def test_compare_headline_is_the_change_of_the_means() -> None:
    # means 15 vs 10 -> +50%; per seed +100% and +25% -> mean 62.5, half 12.7062 * 53.033 / sqrt(2)
    out = compare([20.0, 10.0], [10.0, 8.0])
    assert out["change_pct"] == pytest.approx(100.0 * (15.0 - 9.0) / 9.0)
    assert out["per_seed_pct"] == pytest.approx([100.0, 25.0])
    assert out["per_seed_mean_pct"] == pytest.approx(62.5)
    assert out["per_seed_ci95_pct"] == pytest.approx(
        12.7062 * np.std([100.0, 25.0], ddof=1) / math.sqrt(2), rel=1e-4
    )
    # the paired difference in the metric's units: 10 and 2 -> mean 6, sd 5.6569, half 12.7062 * 5.6569 / sqrt(2)
    paired = out["paired"]
    assert paired["difference"] == 6.0 and paired["runs"] == 2 and paired["x_better_runs"] == 2
    assert paired["ci_low"] == pytest.approx(6.0 - 12.7062 * 4.0, rel=1e-4)
    assert paired["ci_high"] == pytest.approx(6.0 + 12.7062 * 4.0, rel=1e-4)
    assert "paired" not in compare([2.0], [1.0])  # one seed: no interval
    with pytest.raises(ValueError, match="equal-length"):
        compare([1.0], [1.0, 2.0])


def test_strict_json_and_delta_names() -> None:
    assert strict_json({"a": [math.nan, math.inf, -math.inf, 1.5, np.int64(2)]}) == {
        "a": [None, "inf", "-inf", 1.5, 2]
    }
    assert [delta_name(d) for d in (0.0, 0.5, -1.0, math.inf)] == ["0", "0.5", "m1", "inf"]


# ---------------------------------------------------------------------------------------------
# budget
# ---------------------------------------------------------------------------------------------
def test_budget_validation_names_the_key() -> None:
    with pytest.raises(ValueError, match="pretrain_stepz"):
        Fig2Budget.from_dict({"pretrain_stepz": 10})
    with pytest.raises(ValueError, match="finetune_steps"):
        Fig2Budget(finetune_steps=0)
    with pytest.raises(ValueError, match="entropy_threshold"):
        Fig2Budget(entropy_threshold=math.inf)
    with pytest.raises(ValueError, match="style_episodes"):
        Fig2Budget(style_episodes=2)
    with pytest.raises(ValueError, match="chunk_size"):
        Fig2Budget(algo_kwargs={"chunk_size": 3})
    with pytest.raises(ValueError, match="delta_sweep"):
        Fig2Budget(delta_sweep=(math.nan,))
    with pytest.raises(ValueError, match="eval_episodes must be <= 1000"):
        Fig2Budget(eval_episodes=1001)  # would reuse the next seed's evaluation scenarios
    with pytest.raises(ValueError, match="elite_sweep"):
        Fig2Budget(elite_sweep=(0,))
    with pytest.raises(ValueError, match="elite_sweep holds 9, more than the 8 candidates"):
        Fig2Budget(elite_sweep=(9,), algo_kwargs={"n_candidates": 8})
    assert Fig2Budget().replace(elite_sweep=[16, 8, 8]).elite_sweep == (8, 16)
    for bad in (1, "yes", np.bool_(True)):  # written to JSON: Python bools only
        with pytest.raises(ValueError, match="Fig2Budget.sampled_eval must be a bool"):
            Fig2Budget(sampled_eval=bad)
    assert "sampled_eval" not in fig2_budget.UNIT_FIELDS  # it only adds evaluation units
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="Fig2Budget.flow_sweep"):
            Fig2Budget(flow_sweep=(bad,))
    budget = Fig2Budget().replace(flow_sweep=[3, 2, 2], elite_sweep=[8])
    assert budget.flow_sweep == (2, 3) and budget.to_dict()["flow_sweep"] == [2, 3]
    assert budget.acting_variants() == ((None, 1), (2, 8), (2, 1), (3, 8), (3, 1))  # UA2C's elite mean of 8
    assert budget.acting_variants(1) == ((None, 8), (2, 1), (2, 8), (3, 1), (3, 8))  # a report made under m = 1
    budget = Fig2Budget().replace(k_sweep=[10, 3, 3], delta_sweep=["inf", 0])
    assert budget.k_sweep == (3, 10) and budget.delta_sweep == (0.0, math.inf)
    assert budget.pretrain_ks == (1, 3, 5, 10)  # 1 and chunk_size always
    # checkpoints that act by another elite mean: the sweep names the library's and evaluates it like any other m
    elite4 = {"policy_kwargs": {"n_elite": 4}}
    budget = Fig2Budget().replace(algo_kwargs=elite4, elite_sweep=[4, 8], flow_sweep=[2])
    assert budget.default_elite == 4 and Fig2Budget().default_elite == DEFAULT_ELITE
    assert budget.acting_variants() == ((None, 1), (None, 8), (2, 4), (2, 1), (2, 8))
    assert [names.acting_name("chunk", n, m, 4) for n, m in budget.acting_variants()] == [
        "chunk_elite1", "chunk_elite8", "chunk_flow2", "chunk_flow2_elite1", "chunk_flow2_elite8"
    ]
    assert names.acting_name("onestep", None, 8, 1) == "onestep_elite8"  # default_elite = 1: the old names
    assert Fig2Budget(algo_kwargs=elite4).arm_kwargs(1)["policy_kwargs"] == elite4["policy_kwargs"]  # inherited
    with pytest.raises(ValueError, match="one-step baseline acts with n_elite=8 and the chunk policy with n_elite=4"):
        Fig2Budget(algo_kwargs=elite4, onestep_kwargs={"policy_kwargs": {"net_arch": [128, 128]}})
    assert Fig2Budget.from_dict(budget.to_dict()) == budget
    # the default run: the chunk policy at UA2C's defaults, the one-step baseline at 128 x 2, both acting alike
    assert FULL_BUDGET.default_elite == DEFAULT_ELITE and FULL_BUDGET.online_replicates == 2
    assert FULL_BUDGET.arm_kwargs(1)["policy_kwargs"] == {"net_arch": [128, 128]}
    assert "policy_kwargs" not in FULL_BUDGET.arm_kwargs(3)  # the k sweep too: UA2C's own defaults
    assert Fig2Budget.from_dict(FULL_BUDGET.to_dict()) == FULL_BUDGET


def test_finetune_kwargs_reach_every_fine_tuned_arm_on_top_of_the_cadence() -> None:
    budget = FULL_BUDGET.replace(finetune_kwargs={"smooth_weight": 100.0})
    assert fig2_budget.finetune_overrides(budget) == {"smooth_weight": 100.0, "train_freq": 5, "gradient_steps": 1}
    assert fig2_budget.finetune_overrides(FULL_BUDGET) == {"train_freq": 5, "gradient_steps": 1}
    assert Fig2Budget.from_dict(budget.to_dict()) == budget
    assert Fig2Budget.from_dict({k: v for k, v in Fig2Budget().to_dict().items() if k != "finetune_kwargs"}) == Fig2Budget()
    with pytest.raises(ValueError, match=r"finetune_kwargs must not set \['gradient_steps'\]"):
        Fig2Budget(finetune_kwargs={"gradient_steps": 4})
    with pytest.raises(ValueError, match="finetune_kwargs must be a mapping"):
        Fig2Budget(finetune_kwargs=[("smooth_weight", 1.0)])
    assert "finetune_kwargs" in fig2_budget.UNIT_FIELDS  # a resumed run refuses other Phase-2 overrides


def test_quick_budget_arms_act_with_the_n_elite_their_labels_say() -> None:
    """The quick budget leaves n_elite to UA2C: the arms' model kwargs and the acting sweep's labels agree on it."""
    from envs.collection import TRAFFIC_DEFAULTS, make_traffic_env
    from sb3_ua2c import UA2C

    assert "n_elite" not in QUICK_BUDGET.arm_kwargs(QUICK_BUDGET.chunk_size).get("policy_kwargs", {})
    env = make_traffic_env(env_kwargs=dict(QUICK_BUDGET.env_kwargs))
    try:
        for k in (1, QUICK_BUDGET.chunk_size):  # the kwargs the runner pre-trains each arm with (units.py)
            model = UA2C("MlpPolicy", env, device="cpu", **{**TRAFFIC_DEFAULTS, **QUICK_BUDGET.arm_kwargs(k)})
            assert model.policy.n_elite == QUICK_BUDGET.default_elite == DEFAULT_ELITE
    finally:
        env.close()
    # the sweep's labels: the arm's own m has no suffix, every other m is named
    labels = [names.acting_name("chunk", n, m, QUICK_BUDGET.default_elite) for n, m in QUICK_BUDGET.acting_variants()]
    assert "chunk" not in labels and f"chunk_elite{DEFAULT_ELITE}" not in labels and "chunk_elite1" in labels


def test_estimate_scales_the_recorded_stage_times_by_the_budget() -> None:
    budget = Fig2Budget(dataset_episodes=10, pretrain_steps=100, finetune_steps=50, eval_episodes=2, chunk_size=2,
                        style_episodes=5, delta_sweep=(0.0,), k_sweep=(1,), style_ablation=False, elite_sweep=(),
                        flow_sweep=(), sampled_eval=False)
    sizes = fig2_budget.stage_sizes(budget)
    # (N, m) in {10} x {m0, 1}: (10, 1) is the one variant; 4 main + 2 + 1 δ + 1 k + 2 acting = 10 evaluations
    assert sizes == {"datasets": 10, "pretrain": 200, "finetune": 100, "evaluate": 20, "style": 5, "style_ablation": 0}
    # a report measured at twice the sizes on 1 seed: every stage takes half its seconds per seed
    report = {"seeds": [0], "budget": budget.replace(dataset_episodes=20, pretrain_steps=200, finetune_steps=100,
                                                     eval_episodes=4, style_episodes=10).to_dict(),
              "seconds": {"measured": {"datasets": 8.0, "pretrain": 40.0, "finetune": 20.0, "evaluate": 10.0,
                                       "style": 2.0, "style_ablation": 0.0}}}
    est = estimate_seconds(budget, n_seeds=3, reports=[report])
    assert est["pretrain"] == pytest.approx(3 * 20.0) and est["datasets"] == pytest.approx(3 * 4.0)
    assert est["style_ablation"] == 0.0 and est["total"] == pytest.approx(3 * (4 + 20 + 10 + 5 + 1))
    # a stage no report measured takes the median rate of the others
    partial = {**report, "seconds": {"measured": {"pretrain": 40.0, "finetune": 20.0}}}
    assert estimate_seconds(budget, 1, [partial])["evaluate"] == pytest.approx(0.1 * 20)  # 40 / 400 and 20 / 200
    # the committed reports: the default budget is about two hours of wall time on 2 cores
    full = estimate_seconds(FULL_BUDGET, 5)
    wall = fig2_budget.estimate_wall_seconds(full, 5, 2)
    assert 30 * 60 <= wall <= 2.5 * 60 * 60
    # the two parts of a seed fill the workers: shorter than whole seeds (one worker runs 3 of 5)
    assert full["total"] / 2 <= wall < full["total"] / 5 * math.ceil(5 / 2)


def test_list_schedule_and_wall_estimate_by_hand() -> None:
    schedule = list_schedule_seconds
    # 2 workers take 4, 3 at t = 0; the third unit (2) goes to the worker free at 3, the fourth (2)
    # to the one free at 4: the workers end at 5 and 6
    assert schedule([4.0, 3.0, 2.0, 2.0], 2) == pytest.approx(6.0)
    assert schedule([4.0, 3.0, 2.0, 2.0], 1) == pytest.approx(11.0)
    assert schedule([4.0, 3.0], 8) == pytest.approx(4.0)  # more workers than units
    assert schedule([], 2) == 0.0
    with pytest.raises(ValueError, match="workers"):
        schedule([1.0], 0)
    # 3 seeds, main parts of 10 s and style parts of 4 s (style 1 + style_ablation 3 per seed) on 2
    # workers: mains end at 10, 10, 20 on the two workers; styles start at 10 (-> 14), 14 (-> 18), 18
    # (-> 22) on the worker free at 10, so the last one ends at 22
    stages = {"pretrain": 24.0, "evaluate": 6.0, "style": 3.0, "style_ablation": 9.0, "total": 42.0}
    assert fig2_budget.estimate_wall_seconds(stages, 3, 2) == pytest.approx(22.0)
    assert fig2_budget.estimate_wall_seconds(stages, 3, 1) == pytest.approx(42.0)
    assert fig2_budget.estimate_wall_seconds(stages, 3, 6) == pytest.approx(10.0)


# ---------------------------------------------------------------------------------------------
# aggregation from hand-made raw results
# ---------------------------------------------------------------------------------------------
def _summary(reward: float, jerk: float = 1.0, length: float = 1.0) -> dict[str, float]:
    return {
        "reward": reward,
        "cumulative_jerk": jerk,
        "collision": 0.0,
        "merge_success": 1.0,
        "mean_speed": 20.0,
        "mean_executed_length": length,
        "episodes": 1,
    }


def test_aggregate_by_hand() -> None:
    raw = {
        "onestep": {0: _summary(-10.0, jerk=100.0), 1: _summary(-20.0, jerk=300.0)},
        "chunk": {0: _summary(-9.0, jerk=80.0), 1: _summary(-18.0, jerk=240.0)},
        "fixed": {0: _summary(10.0), 1: _summary(30.0)},
        "adaptive": {0: _summary(12.0, length=2.0), 1: _summary(33.0, length=3.0)},
        "delta_inf": {0: _summary(1.0, length=5.0), 1: _summary(3.0, length=5.0)},
    }
    out = aggregate(raw, [0, 1], QUICK_BUDGET.replace(delta_sweep=[math.inf], k_sweep=[1]))
    assert out["offline_reward_gain_pct"] == pytest.approx(100 * (-13.5 + 15.0) / 15.0)  # +10%
    assert out["offline_jerk_change_pct"] == pytest.approx(100 * (160.0 - 200.0) / 200.0)  # -20%
    assert out["online_reward_gain_pct"] == pytest.approx(100 * (22.5 - 20.0) / 20.0)  # +12.5%
    assert out["comparisons"]["online_reward"]["per_seed_pct"] == pytest.approx([20.0, 10.0])
    assert out["methods"]["adaptive"]["mean_executed_length"]["mean"] == pytest.approx(2.5)
    assert out["delta_sweep"][0]["reward"]["mean"] == pytest.approx(2.0)
    assert math.isnan(out["style_macro_accuracy"])  # no style results given
    assert out["k_sweep"] == []  # k1 was not evaluated in this hand-made raw set
    with pytest.raises(ValueError, match="adaptive"):
        aggregate({k: v for k, v in raw.items() if k != "adaptive"}, [0, 1], QUICK_BUDGET)


def test_aggregate_sampled_rows_by_hand() -> None:
    raw = {
        "onestep": {0: _summary(10.0, jerk=100.0)},
        "chunk": {0: _summary(12.0, jerk=300.0)},
        "fixed": {0: _summary(20.0)},
        "adaptive": {0: _summary(18.0)},
        "onestep_sampled": {0: {**_summary(8.0, jerk=400.0), "jerk_per_step": 4.0}},
        "chunk_sampled": {0: {**_summary(10.0, jerk=300.0), "jerk_per_step": 2.0}},
        "fixed_sampled": {0: _summary(16.0)},
        "adaptive_sampled": {0: _summary(20.0)},
    }
    budget = QUICK_BUDGET.replace(delta_sweep=[math.inf], k_sweep=[1])
    out = aggregate(raw, [0], budget)
    assert out["offline_jerk_change_pct"] == pytest.approx(200.0)  # fixed noise: (300 - 100) / 100
    c = out["comparisons"]
    assert c["offline_reward_sampled"]["change_pct"] == pytest.approx(25.0)  # (10 - 8) / 8
    assert c["offline_jerk_sampled"]["change_pct"] == pytest.approx(-25.0)  # (300 - 400) / 400
    assert c["online_reward_sampled"]["change_pct"] == pytest.approx(25.0)  # (20 - 16) / 16
    assert c["offline_jerk_per_step_sampled"]["change_pct"] == pytest.approx(-50.0)  # (2 - 4) / 4
    assert "online_execution_rule_sampled" not in c  # fixed_adaptive_sampled was not evaluated
    assert set(names.CLAIM_COMPARISONS) == set(names.PAPER)
    assert out["sampled"] == pytest.approx(
        {"offline_reward_gain_pct": 25.0, "offline_jerk_change_pct": -25.0, "online_reward_gain_pct": 25.0}
    )
    md = format_markdown(out, "cmd", "today")
    assert "| (b) cumulative jerk, chunk vs one-step — sampled | -25.00% |" in md
    assert "| (c) online reward, adaptive vs fixed — sampled | +25.00% |" in md and "at or beyond" in md
    assert "| chunk policy (offline, full chunks), sampled | 10.00 |" in md
    # without every sampled arm of (a)-(c) there are no sampled rows
    del raw["fixed_sampled"]
    out = aggregate(raw, [0], budget)
    assert "sampled" not in out and "offline_jerk_sampled" not in out["comparisons"]


def test_aggregate_pools_online_phases_by_hand(tmp_path: Path) -> None:
    ep = lambda r: {"episodes": [{"reward": r, "length": 10, "collision": False}] * 4}  # noqa: E731
    raw = {
        "onestep": {0: _summary(10.0), 1: _summary(10.0)},
        "chunk": {0: _summary(12.0), 1: _summary(12.0)},
        "fixed": {0: _summary(100.0), 1: _summary(200.0)},
        "adaptive": {0: _summary(110.0), 1: _summary(180.0)},
        "fixed_r1": {0: _summary(50.0), 1: _summary(150.0)},
        "adaptive_r1": {0: _summary(100.0), 1: _summary(150.0)},
        "fixed_r2": {0: _summary(1.0)},  # phase 2 is missing seed 1: not pooled
        "adaptive_r2": {0: _summary(2.0)},
        "online/fixed": {0: ep(10.0), 1: ep(10.0)},
        "online/adaptive": {0: ep(20.0), 1: ep(20.0)},
        "online/fixed_r1": {0: ep(10.0), 1: ep(30.0)},
        "online/adaptive_r1": {0: ep(10.0), 1: ep(30.0)},
    }
    budget = QUICK_BUDGET.replace(delta_sweep=[math.inf], k_sweep=[1], online_replicates=3, sampled_eval=False)
    out = aggregate(raw, [0, 1], budget)
    # pooled runs (phase-major): adaptive 110, 180, 100, 150 (mean 135); fixed 100, 200, 50, 150 (mean 125)
    assert out["online_reward_gain_pct"] == pytest.approx(100 * (135 - 125) / 125)  # +8%
    c = out["comparisons"]
    assert c["online_reward"]["per_seed_pct"] == pytest.approx([10.0, -10.0, 100.0, 0.0])
    op = out["online_phases"]
    assert op["phases"] == [0, 1] and op["runs"] == 4
    assert op["adaptive"]["per_seed"] == [110.0, 180.0, 100.0, 150.0] and op["fixed"]["mean"] == 125.0
    assert [row["change"]["change_pct"] for row in op["per_phase"]] == pytest.approx(
        [100 * (145 - 150) / 150, 100 * (125 - 100) / 100]  # -3.33%, +25%
    )
    # (c'): training-episode returns, pooled the same way: adaptive 20, 20, 10, 30; fixed 10, 10, 10, 30
    assert c["online_phase_reward"]["change_pct"] == pytest.approx(100 * (20 - 15) / 15)
    assert out["methods"]["adaptive"]["reward"]["mean"] == 145.0  # the methods table: first phase
    md = format_markdown(out, "cmd", "today")
    assert "| (c) online reward, adaptive vs fixed (2 seeds × 2 online phases, pooled) | +8.00% |" in md
    assert "| 1 | 100.00 ± 635.31 | 125.00 ± 317.66 | +25.00% |  |" in md
    # t intervals over the 4 runs: 3.182 · sd / 2, sd = 64.55 (fixed) and 36.97 (adaptive)
    assert "| pooled (4 runs) | 125.00 ± 102.71 | 135.00 ± 58.83 | +8.00% |  |" in md
    assert "30 online steps per fine-tuned arm in each of 3 online phases;" in md
    # one phase (the default): the report is that of the first phase alone, as before
    single = aggregate(raw, [0, 1], budget.replace(online_replicates=1))
    assert single["online_reward_gain_pct"] == pytest.approx(100 * (145 - 150) / 150)
    assert "online phases" not in format_markdown(single, "cmd", "today")
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="Fig2Budget.online_replicates"):
            QUICK_BUDGET.replace(online_replicates=bad)
    assert "online_replicates" not in fig2_budget.UNIT_FIELDS  # more phases only add units
    assert names.replicate_name("fixed", 0) == "fixed" and names.replicate_name("fixed", 2) == "fixed_r2"


def test_online_phase_stats_and_curve_by_hand() -> None:
    episodes = [
        {"reward": 10.0, "length": 100, "collision": True},
        {"reward": 20.0, "length": 200, "collision": False},
        {"reward": 30.0, "length": 200, "collision": False},
        {"reward": 60.0, "length": 500, "collision": False},
    ]
    st = online_phase_stats(episodes)
    # all: (10 + 20 + 30 + 60) / 4 = 30; last quarter: round(0.25 * 4) = 1 episode -> 60; collisions 1/4
    assert st == {"reward": 30.0, "reward_last": 60.0, "collision": 0.25, "episodes": 4}
    assert online_phase_stats(episodes, last_fraction=0.5)["reward_last"] == 45.0
    assert math.isnan(online_phase_stats([])["reward"])
    # episodes end at steps 100, 300, 500, 1000 of 1000 -> bins [0, 500) | [500, 1000]: 100 and 300 in bin 0,
    # 500 is an edge (its episode belongs to the bin it closes), 1000 in bin 1
    curve = online_curve([episodes], 1000, n_bins=2)
    assert curve["steps"] == [500.0, 1000.0]
    assert curve["reward"] == pytest.approx([20.0, 60.0])
    # a second seed whose only episode ends in bin 1: bin 0 averages over the seed that has one
    other = [{"reward": 0.0, "length": 800, "collision": False}]
    assert online_curve([episodes, other], 1000, n_bins=2)["reward"] == pytest.approx([20.0, 30.0])


def test_aggregate_online_phase_and_jerk_per_step_by_hand() -> None:
    raw = {
        "onestep": {0: {**_summary(-10.0, jerk=100.0), "jerk_per_step": 1.0}},
        "chunk": {0: {**_summary(-9.0, jerk=80.0), "jerk_per_step": 0.5}},
        "fixed": {0: _summary(10.0)},
        "adaptive": {0: _summary(12.0)},
        "online/fixed": {0: {"episodes": [{"reward": 4.0, "length": 10, "collision": False}] * 4}},
        "online/adaptive": {0: {"episodes": [{"reward": 5.0, "length": 10, "collision": True}] * 4}},
    }
    out = aggregate(raw, [0], QUICK_BUDGET.replace(delta_sweep=[math.inf], k_sweep=[1]))
    assert out["comparisons"]["offline_jerk_per_step"]["change_pct"] == pytest.approx(-50.0)
    assert out["comparisons"]["online_phase_reward"]["change_pct"] == pytest.approx(25.0)  # (5 - 4) / 4
    assert out["online_phase"]["adaptive"]["collision"]["mean"] == 1.0
    assert "online/fixed" not in out["methods"]
    # raw data of an earlier version has no jerk_per_step: NaN, and no (b'') comparison
    old = {m: v for m, v in raw.items() if not m.startswith("online/")}
    old["chunk"] = {0: _summary(-9.0, jerk=80.0)}
    out = aggregate(old, [0], QUICK_BUDGET.replace(delta_sweep=[math.inf], k_sweep=[1]))
    assert math.isnan(out["methods"]["chunk"]["jerk_per_step"]["mean"])
    assert "offline_jerk_per_step" not in out["comparisons"] and "online_phase" not in out


# ---------------------------------------------------------------------------------------------
# end to end: --quick with 2 seeds, then a resumed call that must not train anything
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fig2")
    assert fig2_cli.main(["--quick", "--seed-list", "0", "1", "--workers", "1", "--out", str(out)]) == 0
    return out


def test_quick_run_writes_every_output(quick_run: Path) -> None:
    for name in (
        "fig2.md",
        "fig2.json",
        "fig2_a_offline_reward.png",
        "fig2_b_offline_jerk.png",
        "fig2_c_online_reward.png",
        "fig2_d_style_confusion.png",
        "fig2_sweeps.png",
        "fig2_c_online_curves.png",
    ):
        assert (quick_run / name).is_file(), name
    for arm in ("fixed", "adaptive", "adaptive_style"):  # Phase-2 training episodes, from the Monitor logs
        online = json.loads((quick_run / "fig2_raw" / "seed1" / "online" / f"{arm}.json").read_text())
        assert sum(e["length"] for e in online["episodes"]) <= QUICK_BUDGET.finetune_steps
        assert set(online["episodes"][0]) == {"reward", "length", "collision"}
    assert (quick_run / "fig2_a_offline_reward.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((quick_run / "fig2.json").read_text())  # strict JSON: no NaN / Infinity
    for key in (
        "offline_reward_gain_pct",
        "offline_jerk_change_pct",
        "online_reward_gain_pct",
        "style_macro_accuracy",
    ):
        assert isinstance(summary[key], float), key
    for method in (
        "onestep",
        "chunk",
        "chunk_adaptive",
        "fixed",
        "adaptive",
        "fixed_adaptive",
        "adaptive_style",
        "chunk_elite1",
        "chunk_elite2",
        "onestep_elite2",
        "chunk_flow2",
        "onestep_flow2_elite2",
        "k2",
        "delta_0",
        "delta_inf",
    ):
        for metric in (
            "reward",
            "collision",
            "mean_speed",
            "merge_success",
            "mean_executed_length",
            "cumulative_jerk",
            "jerk_per_step",
        ):
            assert len(summary["methods"][method][metric]["per_seed"]) == 2, (method, metric)
    assert len(summary["online_phase"]["adaptive"]["reward"]["per_seed"]) == 2
    measured = summary["seconds"]["measured"]  # wall-clock seconds of every unit, by stage
    assert set(measured) == {"datasets", "pretrain", "finetune", "evaluate", "style", "style_ablation", "total"}
    assert measured["total"] == pytest.approx(sum(v for k, v in measured.items() if k != "total"))
    work = quick_run / "fig2_work" / "seed0"
    units = json.loads((work / "unit_seconds.json").read_text())  # the seed's main part
    style = json.loads((work / "unit_seconds_style.json").read_text())  # its style part
    # main: dataset 1, pretrain k=1,2,3 3, offline evals 6 + 2 x 5 acting rules, finetune 2, online
    # evals 3, δ sweep 2, sampled evals 6, second online phase 2 + 2 evals + 2 sampled
    assert len(units) == 39 and "seed0/pretrain/pretrain_k2" in units
    # style: collect, train, evaluate; the ablation's dataset, pre-training, fine-tuning, evaluation
    assert sorted(style) == [
        "seed0/dataset_style", "seed0/evaluate/adaptive_style", "seed0/finetune/adaptive_style",
        "seed0/pretrain/pretrain_style", "seed0/style/collect", "seed0/style/evaluate", "seed0/style/train",
    ]
    units = {**units, **style}
    assert "seed0/finetune/adaptive_r1" in units and "seed0/evaluate/fixed_r1_sampled" in units
    # (c) pools both online phases: 2 seeds x 2 phases
    assert summary["online_phases"]["phases"] == [0, 1] and summary["online_phases"]["runs"] == 4
    assert len(summary["comparisons"]["online_reward"]["per_seed_pct"]) == 4
    for method in names.SAMPLED_METHODS:  # fresh candidate noise, recorded as such
        raw = json.loads((quick_run / "fig2_raw" / "seed0" / f"{method}_sampled.json").read_text())
        assert raw["deterministic"] is False and f"seed0/evaluate/{method}_sampled" in units
    assert json.loads((quick_run / "fig2_raw" / "seed0" / "chunk.json").read_text())["deterministic"] is True
    assert set(summary["sampled"]) == set(names.PAPER)
    assert (quick_run / "fig2_b_offline_jerk_sampled.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "seed0/evaluate/chunk_elite2" in units and "seed0/evaluate/onestep_flow2_elite2" in units
    # (N, m): the arms act with UA2C's m (the quick budget leaves n_elite out); the checkpoints' N (the
    # library's) with m = 1 and 2, then N = 2 with UA2C's m, 1 and 2
    m0, n0 = DEFAULT_ELITE, library_default("flow_steps")
    assert summary["acting_default"] == {"flow_steps": n0, "n_elite": m0}
    assert [(r["flow_steps"], r["n_elite"]) for r in summary["acting_sweep"]] == [(n0, 1), (n0, 2), (2, m0), (2, 1), (2, 2)]
    assert "Acting rule" in (quick_run / "fig2.md").read_text()
    md = (quick_run / "fig2.md").read_text()
    assert "+6.70%" in md and "-18.37%" in md and "+13.17%" in md
    assert "δ sweep" in md and "k sweep" in md and "Style context" in md


def test_a_rebuild_states_the_acting_rule_the_report_recorded() -> None:
    """A report rebuilt without its run's manifest keeps the N and m its checkpoints acted with, not today's defaults."""
    from experiments.fig2.aggregation import _acting_sweep

    recorded = _acting_sweep({}, FULL_BUDGET, {"flow_steps": 10, "n_elite": 1})  # a run of an earlier release
    assert recorded["acting_default"] == {"flow_steps": 10, "n_elite": 1}
    today = _acting_sweep({}, FULL_BUDGET, {})
    assert today["acting_default"] == {"flow_steps": library_default("flow_steps"), "n_elite": FULL_BUDGET.default_elite}
    assert library_default("flow_steps") != 10  # else the first check could not fail


def test_paper_verdict_by_hand() -> None:
    from experiments.fig2.report import paper_verdict

    assert paper_verdict("offline_reward_gain_pct", 6.70) == "at or beyond"  # paper: +6.70 %
    assert paper_verdict("offline_reward_gain_pct", 6.69) == "short"
    assert paper_verdict("offline_jerk_change_pct", -20.0) == "at or beyond"  # paper: -18.37 %, lower is better
    assert paper_verdict("offline_jerk_change_pct", 5.0) == "short"
    assert paper_verdict("online_reward_gain_pct", float("nan")) == "short"


def test_quick_run_gives_adaptive_and_fixed_the_same_online_updates(quick_run: Path) -> None:
    from sb3_ua2c import UA2C

    start = UA2C.load(quick_run / "fig2_work" / "seed0" / "pretrain_k3.zip", device="cpu")._n_updates
    online = {}
    for arm in ("adaptive", "fixed"):
        model = UA2C.load(quick_run / "fig2_work" / "seed0" / f"{arm}.zip", device="cpu")
        assert (model.train_freq.frequency, model.gradient_steps) == (3, 1)  # one update per k = 3 steps
        online[arm] = model._n_updates - start
    assert online["adaptive"] == online["fixed"] == 30 // 3  # 30 env steps in quick mode


def test_quick_run_numbers_follow_from_the_raw_data(quick_run: Path) -> None:
    summary = json.loads((quick_run / "fig2.json").read_text())

    def seed_means(method: str, key: str) -> list[float]:
        out = []
        for seed in (0, 1):
            raw = json.loads((quick_run / "fig2_raw" / f"seed{seed}" / f"{method}.json").read_text())
            out.append(float(np.mean([ep[key] for ep in raw["episodes"]])))
        return out

    def gain(method: str, base: str, key: str) -> float:
        new, ref = np.mean(seed_means(method, key)), np.mean(seed_means(base, key))
        return 100.0 * (new - ref) / abs(ref)

    assert summary["offline_reward_gain_pct"] == pytest.approx(gain("chunk", "onestep", "reward"))
    assert summary["offline_jerk_change_pct"] == pytest.approx(gain("chunk", "onestep", "cumulative_jerk"))
    # (c) pools the two online phases: the mean over 2 seeds x 2 phases of each arm
    pooled = {arm: np.mean(seed_means(arm, "reward") + seed_means(f"{arm}_r1", "reward")) for arm in ("adaptive", "fixed")}
    assert summary["online_reward_gain_pct"] == pytest.approx(100.0 * (pooled["adaptive"] - pooled["fixed"]) / abs(pooled["fixed"]))
    assert summary["online_phases"]["per_phase"][0]["change"]["change_pct"] == pytest.approx(gain("adaptive", "fixed", "reward"))
    assert summary["online_phases"]["per_phase"][1]["change"]["change_pct"] == pytest.approx(gain("adaptive_r1", "fixed_r1", "reward"))
    mean, half = t_confidence_interval(seed_means("adaptive", "reward"))
    assert summary["methods"]["adaptive"]["reward"]["mean"] == pytest.approx(mean)
    assert summary["methods"]["adaptive"]["reward"]["ci95"] == pytest.approx(half)
    # fixed execution runs whole chunks (k = 3 in quick mode); the one-step baseline one action per plan
    assert summary["methods"]["fixed"]["mean_executed_length"]["per_seed"] == pytest.approx([3.0, 3.0])
    assert summary["methods"]["onestep"]["mean_executed_length"]["per_seed"] == pytest.approx([1.0, 1.0])
    styles = [json.loads((quick_run / "fig2_raw" / f"seed{s}" / "style.json").read_text()) for s in (0, 1)]
    assert summary["style_macro_accuracy"] == pytest.approx(np.mean([s["macro_accuracy"] for s in styles]))
    assert (
        summary["style"]["confusion_matrix"]
        == (np.asarray(styles[0]["confusion_matrix"]) + np.asarray(styles[1]["confusion_matrix"])).tolist()
    )


def test_resumed_run_does_no_work(quick_run: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    from envs import collection, evaluation, style
    from sb3_ua2c import pipeline

    def forbidden(*args, **kwargs):
        raise AssertionError("a finished unit was run again")

    for module, name in (
        (collection, "collect_dataset"),
        (pipeline, "pretrain"),
        (pipeline, "finetune"),
        (evaluation, "evaluate"),
        (style, "collect_style_dataset"),
        (style, "train_style_classifier"),
        (style, "evaluate_style_classifier"),
    ):
        monkeypatch.setattr(module, name, forbidden)
    before = json.loads((quick_run / "fig2.json").read_text())
    assert (
        fig2_cli.main(["--quick", "--seed-list", "0", "1", "--workers", "1", "--out", str(quick_run)]) == 0
    )
    assert "0 unit(s) run" in capsys.readouterr().out
    after = json.loads((quick_run / "fig2.json").read_text())
    assert after["online_reward_gain_pct"] == before["online_reward_gain_pct"]
    # another budget must not reuse these units; the report alone uses the recorded budget
    args = ["--quick", "--seed-list", "0", "1", "--workers", "1", "--out", str(quick_run)]
    assert fig2_cli.main([*args, "--budget", '{"pretrain_steps": 9}']) == 2
    assert "pretrain_steps: recorded 8, now 9" in capsys.readouterr().err
    run_record = json.loads((quick_run / "fig2.json").read_text())
    assert fig2_cli.main(["--report-only", "--seed-list", "0", "1", "--out", str(quick_run)]) == 0
    rebuilt = json.loads((quick_run / "fig2.json").read_text())
    assert rebuilt["budget"]["pretrain_steps"] == 8
    # the rebuilt report keeps the command and date of the run that produced the results
    assert (rebuilt["command"], rebuilt["date"]) == (run_record["command"], run_record["date"])
    assert rebuilt["command"].startswith("python -m experiments fig2 --quick")
    # without the work directory (a fresh clone holds only results/), the run's budget and unit
    # timings come from fig2.json, so the compute table survives
    empty = quick_run / "no_work"
    args = ["--report-only", "--seed-list", "0", "1", "--out", str(quick_run), "--work", str(empty)]
    assert fig2_cli.main(args) == 0
    again = json.loads((quick_run / "fig2.json").read_text())
    assert again["seconds"]["measured"] == run_record["seconds"]["measured"] != {}
    assert again["budget"] == run_record["budget"]
    assert "| pretrain |" in (quick_run / "fig2.md").read_text()


def test_a_seed_in_use_is_refused(quick_run: Path, tmp_path: Path, capsys) -> None:
    import os

    work = tmp_path / "seed3"
    work.mkdir()
    with units.seed_lock(work):
        assert (work / ".lock").read_text() == str(os.getpid())
        with pytest.raises(units.SeedBusyError, match=f"{work} is in use .*pid {os.getpid()}"):
            with units.seed_lock(work):
                pass
        # a second fig2 process on the same work directory stops at the locked seed, with exit code 2
        held = quick_run / "fig2_work" / "seed1"
        with units.seed_lock(held):
            args = ["--quick", "--seed-list", "1", "--workers", "1", "--out", str(quick_run)]
            assert fig2_cli.main(args) == 2
            assert f"{held} is in use by another fig2 process" in capsys.readouterr().err
    with units.seed_lock(work):  # released on exit
        pass
    # each part of a seed has its own lock: a seed's style part runs next to its main part
    with units.seed_lock(work):
        with units.seed_lock(work, ".lock-style"):
            assert (work / ".lock-style").read_text() == str(os.getpid())
    with pytest.raises(ValueError, match="part must be one of \\['main', 'style', 'all'\\], got 'both'"):
        units.run_fig2_seed(3, QUICK_BUDGET, fig2_budget.RunPaths.under(tmp_path), part="both")


def test_online_seed_offset_reseeds_phase_2_only(quick_run: Path, tmp_path: Path, monkeypatch) -> None:
    import shutil

    from sb3_ua2c import pipeline

    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="Fig2Budget.online_seed_offset"):
            QUICK_BUDGET.replace(online_seed_offset=bad)
    assert "online_seed_offset" in fig2_budget.UNIT_FIELDS  # a resumed run refuses another offset
    # the pre-trained units of seed 1 are reused; the fine-tuned arms are trained again
    paths = fig2_budget.RunPaths.under(tmp_path)
    shutil.copytree(quick_run / "fig2_work" / "seed1", paths.seed_work(1))
    shutil.copytree(quick_run / "fig2_raw" / "seed1", paths.seed_raw(1))  # the offline evaluations
    for arm in ("adaptive", "fixed", "adaptive_style"):
        (paths.seed_work(1) / f"{arm}.zip").unlink()
    calls = []

    def fake_finetune(start, out, steps, **kwargs):
        calls.append((Path(start).name, kwargs["seed"]))
        raise KeyboardInterrupt  # stop at the first fine-tuned arm

    monkeypatch.setattr(pipeline, "finetune", fake_finetune)
    with pytest.raises(KeyboardInterrupt):
        units.run_fig2_seed(1, QUICK_BUDGET.replace(online_seed_offset=2), paths)
    assert calls == [("pretrain_k3.zip", 1 + 2 * names.MAX_SEED)]


def test_online_replicates_train_both_arms_again_from_the_same_checkpoint(
    quick_run: Path, tmp_path: Path, monkeypatch
) -> None:
    import shutil

    from sb3_ua2c import pipeline

    paths = fig2_budget.RunPaths.under(tmp_path)
    shutil.copytree(quick_run / "fig2_work" / "seed1", paths.seed_work(1))
    shutil.copytree(quick_run / "fig2_raw" / "seed1", paths.seed_raw(1))
    for path in [*paths.seed_work(1).glob("*_r1.zip"), *paths.seed_raw(1).glob("*_r1*.json")]:
        path.unlink()  # the quick run's second phase (offset 0 + 1): trained again below with 1 + 1
    calls = []

    def fake_finetune(start, out, steps, **kwargs):  # the pre-trained weights, as if fine-tuned
        calls.append((Path(start).name, Path(out).name, kwargs["entropy_threshold"], kwargs["seed"]))
        shutil.copy(start, out)
        return Path(out)

    monkeypatch.setattr(pipeline, "finetune", fake_finetune)
    budget = QUICK_BUDGET.replace(online_replicates=3, online_seed_offset=1)
    ran = units.run_fig2_seed(1, budget, paths)
    m = names.MAX_SEED
    assert calls == [  # the first phase is reused; phases 1 and 2 run with offsets 1 + 1 and 1 + 2
        ("pretrain_k3.zip", "adaptive_r1.zip", 0.0, 1 + 2 * m),
        ("pretrain_k3.zip", "fixed_r1.zip", math.inf, 1 + 2 * m),
        ("pretrain_k3.zip", "adaptive_r2.zip", 0.0, 1 + 3 * m),
        ("pretrain_k3.zip", "fixed_r2.zip", math.inf, 1 + 3 * m),
    ]
    for name in ("adaptive_r1", "fixed_r1", "adaptive_r2_sampled", "fixed_r2_sampled"):
        assert (paths.seed_raw(1) / f"{name}.json").is_file(), name
    assert len(ran) == 4 + 8  # four fine-tunings, eight evaluations
    assert units.run_fig2_seed(1, budget, paths) == []  # resumed: nothing left


def test_onestep_kwargs_reach_the_one_step_arm_only(quick_run: Path, tmp_path: Path, monkeypatch) -> None:
    import shutil

    from sb3_ua2c import pipeline

    small, large = {"net_arch": [128, 128]}, {"net_arch": [256, 256, 256]}
    budget = QUICK_BUDGET.replace(
        algo_kwargs={"batch_size": 32, "policy_kwargs": large}, onestep_kwargs={"policy_kwargs": small}
    )
    # key by key over algo_kwargs, for k = 1 only
    assert budget.arm_kwargs(1) == {"batch_size": 32, "policy_kwargs": small, "chunk_size": 1, "entropy_threshold": 0.0}
    assert budget.arm_kwargs(3) == {"batch_size": 32, "policy_kwargs": large, "chunk_size": 3, "entropy_threshold": 0.0}
    assert QUICK_BUDGET.arm_kwargs(1) == {"batch_size": 32, "chunk_size": 1, "entropy_threshold": 0.0}
    assert Fig2Budget.from_dict(budget.to_dict()) == budget
    assert Fig2Budget.from_dict({k: v for k, v in Fig2Budget().to_dict().items() if k != "onestep_kwargs"}) == Fig2Budget()
    assert "onestep_kwargs" in fig2_budget.UNIT_FIELDS  # a resumed run refuses another one-step size
    with pytest.raises(ValueError, match=r"onestep_kwargs must not set \['chunk_size'\]"):
        Fig2Budget(onestep_kwargs={"chunk_size": 1})
    with pytest.raises(ValueError, match="onestep_kwargs must be a mapping"):
        Fig2Budget(onestep_kwargs=[("policy_kwargs", small)])
    with pytest.raises(ValueError, match="elite_sweep holds 16, more than the 8 candidates"):
        Fig2Budget(onestep_kwargs={"n_candidates": 8})  # the default elite sweep reaches 16
    # the runner passes them to the k = 1 unit alone
    paths = fig2_budget.RunPaths.under(tmp_path)
    paths.seed_work(1).mkdir(parents=True)
    shutil.copytree(quick_run / "fig2_work" / "seed1" / "dataset", paths.seed_work(1) / "dataset")
    calls = {}

    def fake_pretrain(dataset, out, steps, seed, algo_kwargs, make_env):
        assert algo_kwargs.pop("discrete_action_dims") == {1: [-1.0, 0.0, 1.0]}  # MixedTraffic's lane change
        calls[Path(out).name] = algo_kwargs
        if len(calls) == len(budget.pretrain_ks):
            raise KeyboardInterrupt  # stop before the evaluations
        return Path(out)

    monkeypatch.setattr(pipeline, "pretrain", fake_pretrain)
    with pytest.raises(KeyboardInterrupt):
        units.run_fig2_seed(1, budget, paths)
    assert calls == {f"pretrain_k{k}.zip": budget.arm_kwargs(k) for k in (1, 2, 3)}
    assert calls["pretrain_k1.zip"]["policy_kwargs"] == small and calls["pretrain_k3.zip"]["policy_kwargs"] == large


def test_explicit_default_net_arch_builds_the_same_networks() -> None:
    """``policy_kwargs={"net_arch": DEFAULT_NET_ARCH}`` builds the default velocity field: a budget that
    spells the default out trains what one that leaves it unset trains."""
    import gymnasium as gym

    from sb3_ua2c import UA2C
    from sb3_ua2c.policies import DEFAULT_NET_ARCH

    models = [
        UA2C("MlpPolicy", gym.make("Pendulum-v1"), seed=3, device="cpu", **kwargs)
        for kwargs in ({}, {"policy_kwargs": {"net_arch": list(DEFAULT_NET_ARCH)}})
    ]
    (a, b) = (m.policy.state_dict() for m in models)
    assert a.keys() == b.keys()
    assert all(np.array_equal(a[key].numpy(), b[key].numpy()) for key in a)


def test_command_line_is_quoted_for_the_shell() -> None:
    assert command_line("python -m experiments fig2", []) == "python -m experiments fig2"
    line = command_line("python -m experiments fig2", ["--budget", '{"a": 1}', "--out", "r"])
    assert line == """python -m experiments fig2 --budget '{"a": 1}' --out r"""


def test_the_cli_subcommand_names_itself(capsys) -> None:
    with pytest.raises(SystemExit):
        fig2_cli.main(["--help"])
    assert capsys.readouterr().out.startswith("usage: python -m experiments fig2 ")


def test_one_entry_point_dispatches_every_command(capsys) -> None:
    import importlib

    from experiments.__main__ import COMMANDS, main

    assert main([]) == 2 and "peers-tuning" in capsys.readouterr().out  # the usage lists the commands
    assert main(["fig3"]) == 2 and "unknown command 'fig3'" in capsys.readouterr().err
    for name, (module, _) in COMMANDS.items():  # every command's module has main(argv, prog)
        assert "prog" in importlib.import_module(module).main.__code__.co_varnames, name
    with pytest.raises(SystemExit):
        main(["peers-tuning", "--help"])
    assert capsys.readouterr().out.startswith("usage: python -m experiments peers-tuning ")


def test_each_name_is_imported_from_its_defining_module() -> None:
    """``experiments.fig2`` re-exports nothing: a name has one home (its defining module)."""
    import types

    import experiments.fig2 as package

    public = {n: v for n, v in vars(package).items() if not n.startswith("_")}
    assert {"budget", "cli", "units"} <= set(public)  # imported above: attributes of the package
    assert all(isinstance(v, types.ModuleType) for v in public.values()), public  # and nothing but modules
    assert not hasattr(package, "__all__")


def test_cli_argument_types() -> None:
    import argparse

    from sb3_ua2c.cli_args import float_arg, json_object_arg

    assert json_object_arg('{"a": [1, 2]}') == {"a": [1, 2]}
    with pytest.raises(argparse.ArgumentTypeError, match="expected a JSON object, got '\\[1\\]'"):
        json_object_arg("[1]")
    with pytest.raises(argparse.ArgumentTypeError, match="not valid JSON"):
        json_object_arg("{a: 1}")
    assert float_arg("inf") == math.inf and float_arg("-0.5") == -0.5
    with pytest.raises(argparse.ArgumentTypeError, match="NaN is not a valid value"):
        float_arg("nan")
    with pytest.raises(ValueError):
        float_arg("x")



def test_bad_arguments_and_missing_results(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        fig2_cli.main(["--quick", "--budget", '{"pretrain_stepz": 1}', "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "pretrain_stepz" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        fig2_cli.main(["--seeds", "-1", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        fig2_cli.main(["--seed-list", "100", "--out", str(tmp_path)])
    assert "--seeds must be integers in [0, 100)" in capsys.readouterr().err
    assert fig2_cli.main(["--report-only", "--seeds", "1", "--out", str(tmp_path)]) == 2
    assert "no raw results for seed 1" in capsys.readouterr().err


def test_budget_of_reruns_a_report_with_its_own_budget(quick_run: Path, tmp_path: Path, capsys) -> None:
    recorded = fig2_cli.recorded_budget(quick_run)  # the directory, or the file itself
    assert recorded == QUICK_BUDGET == fig2_cli.recorded_budget(quick_run / "fig2.json")
    # a report made before a field existed: the field takes its class default
    old = json.loads((quick_run / "fig2.json").read_text())
    del old["budget"]["online_replicates"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert fig2_cli.recorded_budget(tmp_path / "old.json") == QUICK_BUDGET.replace(online_replicates=1)
    # rerun with the recorded budget: every unit of seed 0 exists
    rerun = ["--budget-of", str(quick_run), "--seeds", "0", "--workers", "1", "--out", str(tmp_path / "rerun"),
             "--work", str(quick_run / "fig2_work"), "--raw", str(quick_run / "fig2_raw")]
    assert fig2_cli.main(rerun) == 0
    out = capsys.readouterr().out  # the quick run's own budget: every unit of both parts exists
    assert "seed 0 (main): 0 unit(s) run" in out and "seed 0 (style): 0 unit(s) run" in out
    assert fig2_cli.recorded_budget(tmp_path / "rerun") == QUICK_BUDGET
    assert fig2_cli.main([*rerun, "--budget", '{"online_replicates": 1}']) == 0  # --budget applies on top
    assert fig2_cli.recorded_budget(tmp_path / "rerun") == QUICK_BUDGET.replace(online_replicates=1)
    (tmp_path / "nobudget.json").write_text("{}")
    for bad, message in (
        (tmp_path / "missing", "does not exist"),
        (tmp_path / "nobudget.json", "is not a fig2.json with a 'budget' key"),
    ):
        with pytest.raises(SystemExit) as exc:
            fig2_cli.main(["--budget-of", str(bad), "--out", str(tmp_path)])
        assert exc.value.code == 2 and message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        fig2_cli.main(["--budget-of", str(quick_run), "--quick", "--out", str(tmp_path)])
    assert "--budget-of and --quick" in capsys.readouterr().err


def test_run_all_submits_every_main_part_before_the_style_parts(tmp_path: Path, monkeypatch) -> None:

    calls = []

    def fake_seed_unit(seed, budget, paths, part="all"):
        calls.append((seed, part))
        return [f"seed{seed}/{part}/unit"]

    monkeypatch.setattr(units, "run_fig2_seed_unit", fake_seed_unit)
    lines: list[str] = []
    executed = units.run_all([3, 1], QUICK_BUDGET, fig2_budget.RunPaths.under(tmp_path), workers=1, printer=lines.append)
    assert calls == [(3, "main"), (1, "main"), (3, "style"), (1, "style")]
    assert executed == ["seed3/main/unit", "seed1/main/unit", "seed3/style/unit", "seed1/style/unit"]
    assert lines[0].startswith("seed 3 (main): 1 unit(s) run in ")


def test_methods_keep_the_mean_length_histogram_when_every_seed_recorded_one() -> None:
    from experiments.fig2.aggregation import _stats

    metrics = {"reward": 1.0, "cumulative_jerk": 1.0, "jerk_per_step": 1.0, "collision": 0.0, "merge_success": 1.0,
               "mean_speed": 1.0, "mean_executed_length": 2.0}
    per_seed = {0: {**metrics, "length_shares": [0.5, 0.5, 0.0]}, 1: {**metrics, "length_shares": [0.0, 0.5, 0.5]}}
    assert _stats(per_seed, [0, 1])["length_shares"] == [0.25, 0.5, 0.25]
    del per_seed[1]["length_shares"]  # a record made before 2026-12-04
    assert "length_shares" not in _stats(per_seed, [0, 1])
