"""The head-to-head command (``python -m experiments peers``): end to end at the quick budget, resuming and
rerunning one unit, the report builders on hand-made records, the estimate, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from extras import require

from experiments.common.names import DATASET_SEED_BASE
from experiments.common.runner import list_schedule_seconds
from experiments.peers import cli
from experiments.peers.budget import (
    ARMS,
    FULL_PEERS_BUDGET,
    PEER_ARMS,
    REFERENCE_ARMS,
    UA2C_ARMS,
    PeersBudget,
    estimate_units,
    format_estimate,
)
from experiments.peers.report import (
    aggregate,
    arm_summary,
    binned_curve,
    means_table,
    readme_table,
    results_table,
    training_table,
    verdicts,
)
from sb3_ua2c.presets import preset

OFFLINE_ARMS = {"ua2c", "ua2c_paper", "ua2c_adaptive", "ua2c_fixed", "ua2c_onestep", "ua2c_adaptive_per_step", "iql", "calql", "rebrac", "bc", "behaviour"}  # rlpd: none


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    require("d3rlpy")
    out = tmp_path_factory.mktemp("peers")
    assert cli.main(["--quick", "--seeds", "0", "1", "--workers", "1", "--out", str(out)]) == 0
    return out


def _records(out: Path, arm: str) -> list[dict]:
    return [json.loads((out / "peers_raw" / f"seed{s}" / f"{arm}.json").read_text()) for s in (0, 1)]


def test_quick_run_writes_the_report_with_every_arm(quick_run):
    for name in ("peers.md", "peers.json", "peers_curves.png", "peers_iqm.png"):
        assert (quick_run / name).is_file(), name
    summary = json.loads((quick_run / "peers.json").read_text())
    assert sorted(summary["arms"]) == sorted([*ARMS, "iql_best_of_n"]) and summary["seeds"] == [0, 1]
    assert len(summary["pairs"]) == len(UA2C_ARMS) * (len(PEER_ARMS) + len(REFERENCE_ARMS) + 1)
    for iql in _records(quick_run, "iql"):  # the best-of-N row: the same policy, its own evaluation
        assert iql["evaluation_best_of_n"]["n"] == 32
        assert [e["seed"] for e in iql["evaluation_best_of_n"]["episodes"]] == [e["seed"] for e in iql["evaluation"]["episodes"]]
    for ref in (*_records(quick_run, "bc"), *_records(quick_run, "behaviour")):  # no online phase, one evaluation
        assert ref["online_steps"] == 0 and ref["online_episodes"] == [] and ref["evaluation"] == ref["offline_evaluation"]
    assert summary["arms"]["bc"]["curve"] is None and summary["arms"]["rebrac"]["curve"] is not None
    # the best-of-N row evaluates IQL's policy: IQL's training, so no curve or curve area of its own
    best, iql_arm = summary["arms"]["iql_best_of_n"], summary["arms"]["iql"]
    assert best["curve"] is None and "mean" not in best["curve_area"]
    assert iql_arm["curve"] is not None and "mean" in iql_arm["curve_area"]
    rlpd = _records(quick_run, "rlpd")[0]
    assert rlpd["offline_steps"] == 0 and rlpd["hyperparams"]["updates_per_step"] == 4
    assert rlpd["hyperparams"]["config"]["critic_encoder_factory"]["params"]["use_layer_norm"] is True
    assert "unlike RLPD" in rlpd["notes"]
    assert _records(quick_run, "calql")[0]["hyperparams"]["config"]["alpha_threshold"] == 0.8
    rebrac = _records(quick_run, "rebrac")[0]["hyperparams"]["config"]
    assert rebrac["actor_beta"] == 0.01 and rebrac["critic_encoder_factory"]["params"]["use_layer_norm"] is True
    assert summary["budget"]["ua2c"]["finetune_steps"] == 30 and "WITHOUT" in summary["observation"]
    for arm, stats in summary["arms"].items():
        assert set(stats["metrics"]) == {"reward", "collision", "merge_success", "cumulative_jerk", "jerk_per_step"}
        assert (stats["offline_metrics"] is not None) == (arm in OFFLINE_ARMS), arm
        evaluation = "evaluation_best_of_n" if arm == "iql_best_of_n" else "evaluation"
        rewards = [r[evaluation]["episodes"][0]["reward"] for r in _records(quick_run, arm.removesuffix("_best_of_n"))]
        # 2 seeds x 1 episode: the 25 % trimmed mean trims nothing, the IQM is the mean
        assert stats["metrics"]["reward"]["iqm"] == pytest.approx(np.mean(rewards), abs=1e-9)
        assert stats["metrics"]["reward"]["ci_low"] == pytest.approx(min(rewards))
        assert stats["cpu_seconds"]["total"] > 0
    pair = summary["pairs"]["ua2c_adaptive_vs_sac"]
    assert set(pair) >= {"ua2c", "peer", "reward", "collision"} and 0.0 <= pair["reward"]["probability"] <= 1.0
    md = (quick_run / "peers.md").read_text()
    assert "zoo_configs/sac.yml" in md and "zoo_configs/crossq.yml" in md and "UNLIKE RLPD".lower() in md.lower() and "P(UA2C > peer)" in md


def test_every_arm_of_a_seed_reads_the_same_data_and_scenarios(quick_run):
    for s in (0, 1):
        records = [json.loads((quick_run / "peers_raw" / f"seed{s}" / f"{a}.json").read_text()) for a in ARMS]
        assert {r["dataset"]["path"] for r in records} == {str(quick_run / "peers_work" / f"seed{s}" / "dataset")}
        assert {r["dataset"]["seed"] for r in records} == {DATASET_SEED_BASE + 10_000 * s}
        assert {r["online_steps"] for r in records if r["arm"] not in REFERENCE_ARMS} == {30}
        # the test scenarios (the default): 1000 * (4000 + s) + i
        assert {tuple(e["seed"] for e in r["evaluation"]["episodes"]) for r in records} == {(4_000_000 + 1000 * s,)}
    adaptive, fixed = _records(quick_run, "ua2c_adaptive")[0], _records(quick_run, "ua2c_fixed")[0]
    assert adaptive["hyperparams"]["delta"] == 0.0 and fixed["hyperparams"]["delta"] == "inf"
    assert adaptive["hyperparams"]["finetune_overrides"] == {"train_freq": 3, "gradient_steps": 1}
    per_step = _records(quick_run, "ua2c_adaptive_per_step")[0]["hyperparams"]
    assert per_step["finetune_overrides"] == {"train_freq": 1, "gradient_steps": 1} and per_step["delta"] == 0.0
    assert _records(quick_run, "iql")[0]["offline_steps"] == 8  # the UA2C arms' pretrain_steps
    default, paper = _records(quick_run, "ua2c")[0]["hyperparams"], _records(quick_run, "ua2c_paper")[0]["hyperparams"]
    assert default["finetune_overrides"] == {} and paper["finetune_overrides"] == {}  # their own schedules
    assert default["algo_kwargs"] == {"batch_size": 32, "chunk_size": 3, "entropy_threshold": 0.0}
    assert paper["algo_kwargs"] == {**preset("paper"), "batch_size": 32, "chunk_size": 3} and paper["delta"] is None
    # each UA2C record says in words which configuration and cadence it ran with
    assert _records(quick_run, "ua2c")[0]["notes"].endswith("its configuration's own train_freq and gradient_steps")
    assert "preset('paper')" in _records(quick_run, "ua2c_paper")[0]["notes"]
    assert "(Figure 2's cadence)" in _records(quick_run, "ua2c_adaptive")[0]["notes"]
    # Figure 2's arms at the defaults keep the defaults' schedule: the same gradient steps as ua2c
    assert [_records(quick_run, a)[0]["hyperparams"]["finetune_overrides"] for a in ("ua2c_fixed", "ua2c_onestep")] == [{}, {}]
    assert "(the peers' cadence)" in _records(quick_run, "ua2c_adaptive_per_step")[0]["notes"]


def test_a_report_over_records_of_another_run_names_that_run(quick_run, tmp_path):
    out = tmp_path / "merged"
    for s in (0, 1):
        (out / "peers_raw" / f"seed{s}").mkdir(parents=True)
        for arm in ("ua2c", "sac"):
            name = f"seed{s}/{arm}.json"
            (out / "peers_raw" / name).write_text((quick_run / "peers_raw" / name).read_text())
    args = ["--quick", "--seeds", "0", "1", "--arms", "ua2c", "sac", "--out", str(out), "--report-only"]
    assert cli.main(args) == 0
    summary = json.loads((out / "peers.json").read_text())
    assert summary["reused"] == {(quick_run / "peers_work").as_posix(): ["sac", "ua2c"]}
    assert summary["estimate"]["per_unit"] == {} and summary["estimate"]["cpu"] == 0  # none ran here
    md = (out / "peers.md").read_text()
    assert f"Records reused from the run in `{(quick_run / 'peers_work').as_posix()}`" in md and ": sac, ua2c." in md
    # the run's own records are not "reused"
    assert json.loads((quick_run / "peers.json").read_text())["reused"] == {}


def test_a_second_run_skips_every_unit_and_one_deleted_unit_runs_alone(quick_run, capsys):
    args = ["--quick", "--seeds", "0", "1", "--workers", "1", "--out", str(quick_run)]
    sac = quick_run / "peers_raw" / "seed1" / "sac.json"
    before = json.loads(sac.read_text())
    capsys.readouterr()
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    n = 2 * len(ARMS)  # 2 seeds
    assert f"{n} of {n} unit(s) already stored, 0 to run" in out and f"0 arm unit(s) run, {n} stored" in out
    sac.unlink()
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert f"{n - 1} of {n} unit(s) already stored, 1 to run" in out and "[1/1] unit seed1/sac:" in out
    again = json.loads(sac.read_text())
    assert again["evaluation"] == before["evaluation"] and again["online_episodes"] == before["online_episodes"]
    # --rerun: the selected unit runs again without deleting anything by hand
    assert cli.main(["--quick", "--seeds", "1", "--arms", "sac", "--rerun", "--workers", "1", "--out", str(quick_run)]) == 0
    out = capsys.readouterr().out
    assert "[1/1] unit seed1/sac:" in out and "0 arm unit(s) run, 1 stored" not in out
    assert json.loads((quick_run / "peers.json").read_text())["seeds"] == [0, 1]  # the report keeps every record


def test_scenarios_are_recorded_and_a_validation_run_needs_its_own_directory(quick_run, capsys):
    summary = json.loads((quick_run / "peers.json").read_text())
    assert summary["budget"]["scenarios"] == "test" and summary["scenarios"].startswith("test ")
    assert "on the test scenarios" in (quick_run / "peers.md").read_text()
    args = ["--quick", "--scenarios", "validation", "--seeds", "0", "--arms", "sac", "--workers", "1", "--out", str(quick_run)]
    assert cli.main(args) == 2
    assert "another budget" in capsys.readouterr().err
    # a budget recorded before the split evaluated on Figure 2's scenarios
    old = FULL_PEERS_BUDGET.to_dict()
    del old["scenarios"]
    assert PeersBudget.from_dict(old).scenarios == "figure2"
    with pytest.raises(ValueError, match="PeersBudget.scenarios"):
        PeersBudget(scenarios="train")


def test_a_run_under_another_budget_is_refused(quick_run, capsys):
    args = ["--quick", "--online-steps", "40", "--seeds", "0", "--arms", "sac", "--workers", "1", "--out", str(quick_run)]
    assert cli.main(args) == 2
    assert "another budget" in capsys.readouterr().err


@pytest.mark.parametrize(("args", "message"), [
    (["--arms", "sac", "ppo"], "--arms: unknown arm(s) ['ppo']"),
    (["--seeds", "-1"], "--seeds must be integers in [0, 100)"),
    (["--seeds", "100"], "--seeds must be integers in [0, 100)"),
    (["--workers", "0"], "--workers must be an integer >= 1"),
    (["--online-steps", "0"], "--online-steps must be an integer >= 1"),
])
def test_bad_input_names_the_parameter(args, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([*args, "--out", str(tmp_path)])
    assert exc.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "peers_work").exists()


def _record(arm, seed, rewards, curve, offline=None):
    episodes = [{"seed": i, "reward": r, "collision": i == 0, "merge_success": True, "cumulative_jerk": 10.0 * r,
                 "jerk_per_step": r / 10} for i, r in enumerate(rewards)]
    evaluation = {"episodes": episodes}
    return {"arm": arm, "seed": seed, "online_steps": 100, "offline_steps": 0 if offline is None else 50,
            "evaluation": evaluation, "offline_evaluation": None if offline is None else {"episodes": [
                {**e, "reward": o} for e, o in zip(episodes, offline, strict=True)]},
            "online_episodes": [{"end_step": s, "reward": r, "collision": i == 0} for i, (s, r) in enumerate(curve)],
            "wall_seconds": {"total": 60.0 * (seed + 1)}, "cpu_seconds": {"total": 30.0}, "hyperparams": {}, "notes": ""}


def test_report_builders_on_hand_made_records():
    require("rliable")
    records = {
        "ua2c_adaptive": [_record("ua2c_adaptive", 0, [1.0, 2.0], [(50, 1.0), (100, 3.0)], offline=[0.0, 1.0]),
                          _record("ua2c_adaptive", 1, [3.0, 4.0], [(40, 2.0), (90, 5.0)], offline=[1.0, 2.0])],
        "sac": [_record("sac", 0, [5.0, 6.0], [(60, 0.0)]), _record("sac", 1, [7.0, 8.0], [(100, 4.0)])],
    }
    adaptive = arm_summary(records["ua2c_adaptive"], reps=200)
    # one score per run: seed 0 scores 1.5, seed 1 3.5; 25 % of 2 runs trims none, so the IQM is 2.5
    assert adaptive["per_seed"]["reward"] == [1.5, 3.5]
    assert adaptive["metrics"]["reward"]["iqm"] == pytest.approx(2.5)
    assert adaptive["metrics"]["collision"]["iqm"] == pytest.approx(0.5)
    assert adaptive["offline_metrics"]["reward"]["iqm"] == pytest.approx(1.0)  # runs 0.5 and 1.5
    assert adaptive["wall_seconds"] == {"mean_per_seed": 90.0, "total": 180.0}
    summary = aggregate(records, reps=200)
    assert summary["arms"]["sac"]["offline_metrics"] is None
    # both adaptive runs (1.5, 3.5) score below both SAC runs (5.5, 7.5): P(UA2C > SAC) = 0
    assert summary["pairs"]["ua2c_adaptive_vs_sac"]["reward"] == {"probability": 0.0, "ci_low": 0.0, "ci_high": 0.0}
    # jerk is a cost: lower adaptive jerk is an improvement
    assert summary["pairs"]["ua2c_adaptive_vs_sac"]["jerk_per_step"]["probability"] == 1.0
    (line,) = verdicts(summary)
    # paired per seed: 1.5 - 5.5 and 3.5 - 7.5, no spread; the verdict names the interval, no percentage
    assert line.startswith("UA2C adaptive, one update per k env steps vs SB3 SAC (online): -4.00 [-4.00, -4.00] over 2 paired runs "
                           "(UA2C adaptive, one update per k env steps ahead in 0): SB3 SAC (online) better; P(")
    assert "%" not in line
    # learning-curve area of seed 0: return 1 over steps 1-50, 3 over 51-100 -> 2.0; seed 1: (80 + 250) / 90
    assert adaptive["curve_area"]["per_seed"] == pytest.approx([2.0, 330 / 90])
    assert "| UA2C adaptive, one update per k env steps | 2.50 [" in results_table(summary)[2]
    row = readme_table(summary)[3]
    assert row.startswith("| SB3 SAC (online) | 6.50 [") and row.endswith("] | 6.50 | 0.50 | 1.00 |")
    # means over runs: reward (1.5 + 3.5) / 2, one collision per seed in two episodes
    assert adaptive["means"]["reward"]["mean"] == pytest.approx(2.5)
    assert adaptive["means"]["collision"]["mean"] == pytest.approx(0.5)
    assert adaptive["means"]["cumulative_jerk"]["mean"] == pytest.approx(25.0)
    assert means_table(summary)[2].startswith("| UA2C adaptive, one update per k env steps | 2.50 [")
    # training episodes: adaptive runs collide in 1 of 2 episodes each, earn (1 + 3) / 2 and (2 + 5) / 2;
    # SAC runs have one episode each, both collisions
    training = adaptive["training_episodes"]
    assert training["episodes_per_run"] == 2.0
    assert training["collision"]["mean"] == pytest.approx(0.5)
    assert training["reward"]["mean"] == pytest.approx((2.0 + 3.5) / 2)
    rows = training_table(summary)
    assert rows[2].startswith("| UA2C adaptive, one update per k env steps | 2 | 0.50 [0.50, 0.50] | 2.8 [")
    assert rows[3].startswith("| SB3 SAC (online) | 1 | 1.00 [1.00, 1.00] | 2.0 [")


def test_binned_curve_carries_the_last_return_forward():
    episodes = [{"end_step": 30, "reward": 1.0}, {"end_step": 40, "reward": 3.0}, {"end_step": 90, "reward": 5.0}]
    np.testing.assert_allclose(binned_curve(episodes, 100, bins=4), [np.nan, 2.0, 2.0, 5.0])


def test_estimate_scales_the_recorded_unit_seconds_by_the_steps():
    # two records of SAC (offline 0) at 5,000 and 15,000 online steps: 40 CPU s per 1,000 steps
    records = [{"arm": "sac", "cpu_seconds": {"total": 200.0}, "offline_steps": 0, "online_steps": 5000},
               {"arm": "sac", "cpu_seconds": {"total": 600.0}, "online_steps": 15000},
               {"arm": "iql", "cpu_seconds": {"total": 110.0}, "offline_steps": 6000, "online_steps": 5000}]
    at_10k = FULL_PEERS_BUDGET.with_online_steps(10_000)
    est = estimate_units(at_10k, ["sac", "iql", "tqc"], 2, workers=2, records=records)
    assert est["per_unit"]["sac"] == pytest.approx(400.0)
    assert est["per_unit"]["iql"] == pytest.approx(110.0 / 11_000 * 16_000)
    assert est["per_unit"]["tqc"] == pytest.approx((0.04 + 0.01) / 2 * 10_000)  # no record: the median rate
    assert est["cpu"] == pytest.approx(2 * sum(est["per_unit"].values()))
    # longest first on 2 workers: 5 | 4, 3 -> 7 | 3 -> 8 | 3 -> 10
    assert list_schedule_seconds(sorted([3, 5, 3, 4, 3], reverse=True), 2) == 10
    assert list_schedule_seconds([5, 3], 4) == 5
    assert est["wall"] == pytest.approx(sum(est["per_unit"].values()))  # each arm's two seeds on the two workers
    assert "tqc" in format_estimate(est) and "CPU-min" in format_estimate(est)
    # the committed records: every arm of the default run on 5 seeds fits within four hours on 2 cores
    full = estimate_units(FULL_PEERS_BUDGET, ARMS, 5, workers=2)
    assert full["wall"] < 4 * 3600 and full["cpu"] > full["wall"]


def test_ua2c_arms_take_their_configuration_checkpoint_and_cadence_from_the_budget():
    WIDE = {"net_arch": [512, 512, 512], "n_elite": 8}
    b = PeersBudget().with_overrides({"ua2c": {"algo_kwargs": {"batch_size": 128, "q_weight": 0.3, "policy_kwargs": WIDE},
                                               "finetune_kwargs": {"n_elite": 4}}})
    assert [b.pretrain_name(a) for a in UA2C_ARMS] == [
        "pretrain_k5", "pretrain_k5_paper", "pretrain_k5", "pretrain_k5", "pretrain_k1", "pretrain_k5"]
    # the preset keeps the budget's optimisation settings and nothing else of it
    assert b.pretrain_kwargs("ua2c_paper") == {**preset("paper"), "batch_size": 128, "chunk_size": 5}
    assert b.pretrain_kwargs("ua2c") == {"batch_size": 128, "q_weight": 0.3, "policy_kwargs": WIDE,
                                         "chunk_size": 5, "entropy_threshold": 0.0}
    assert b.finetune_overrides("ua2c") == {"n_elite": 4} and b.finetune_overrides("ua2c_paper") == {}
    assert b.finetune_overrides("ua2c_adaptive") == {"n_elite": 4, "train_freq": 5, "gradient_steps": 1}
    assert b.finetune_overrides("ua2c_adaptive_per_step") == {"n_elite": 4, "train_freq": 1, "gradient_steps": 1}
    assert (b.delta("ua2c"), b.delta("ua2c_paper"), b.delta("ua2c_fixed")) == (0.0, None, float("inf"))


def test_headline_names_the_best_of_each_side():
    require("rliable")
    from experiments.peers.report import headline

    records = {
        "ua2c_adaptive": [_record("ua2c_adaptive", s, [1.0, 2.0], [(50, 1.0)]) for s in (0, 1)],
        "ua2c_fixed": [_record("ua2c_fixed", s, [4.0, 4.0], [(50, 1.0)]) for s in (0, 1)],
        "sac": [_record("sac", s, [3.0, 3.0], [(50, 1.0)]) for s in (0, 1)],
    }
    line = headline(aggregate(records, reps=50))
    fixed = "UA2C (defaults) fixed chunks (δ=inf)"
    assert line == (f"Best UA2C arm by IQM reward over runs, {fixed} (4.00); best peer, SB3 SAC (online) (3.00). "
                    f"Paired per seed: {fixed} vs SB3 SAC (online): +1.00 [+1.00, +1.00] over 2 paired runs "
                    f"({fixed} ahead in 2): {fixed} better; P(UA2C > peer) = 1.00. By the mean reward: 4.00 vs "
                    "3.00 (+1.00); collision rate 0.50 vs 0.50.")


def test_figure2_claims_pair_the_ua2c_arms_per_seed():
    from experiments.peers.report import figure2_claims, figure2_lines

    records = {  # offline episodes carry the online episodes' jerk (10 x the online reward) in _record
        "ua2c_fixed": [_record("ua2c_fixed", 0, [1.0, 1.0], [(50, 1.0)], offline=[2.0, 4.0]),
                       _record("ua2c_fixed", 1, [2.0, 2.0], [(50, 1.0)], offline=[4.0, 6.0])],
        "ua2c_onestep": [_record("ua2c_onestep", 0, [3.0, 3.0], [(50, 1.0)], offline=[1.0, 1.0]),
                         _record("ua2c_onestep", 1, [5.0, 5.0], [(50, 1.0)], offline=[2.0, 2.0]),
                         _record("ua2c_onestep", 2, [9.0, 9.0], [(50, 1.0)], offline=[9.0, 9.0])],
        "ua2c": [_record("ua2c", s, [r, r], [(50, 1.0)], offline=[0.0, 0.0]) for s, r in ((0, 4.0), (1, 6.0))],
    }
    claims = figure2_claims(records)
    (a, b, c) = claims.values()
    # (a) offline reward over the shared seeds 0, 1 (seed 2 has no fixed run): fixed 3, 5; one-step 1, 2
    assert (a["x_mean"], a["y_mean"], a["difference"], a["x_better_runs"], a["runs"]) == (4.0, 1.5, 2.5, 2, 2)
    # differences 2 and 3: standard error 0.5, t(0.975, 1) = 12.706
    assert (a["ci_low"], a["ci_high"]) == pytest.approx((2.5 - 6.353, 2.5 + 6.353), abs=1e-3)
    # (b) jerk is a cost: one-step minus chunks, 30 - 10 and 50 - 20
    assert (b["x_mean"], b["y_mean"], b["difference"]) == (15.0, 40.0, 25.0)
    # (c) online reward, adaptive minus fixed: 4 - 1, 6 - 2
    assert c["difference"] == 3.5 and c["evaluation"] == "evaluation"
    assert figure2_lines({"figure2": claims})[2] == (
        "| (a) offline reward, chunks (k = 5) vs one-step | 4.00 | 1.50 | +2.50 [-3.85, +8.85] | 2 of 2 |")
    del records["ua2c_onestep"]
    assert list(figure2_claims(records)) == ["(c) online reward, adaptive vs fixed chunks"]
    assert figure2_lines({"figure2": {}})[0].startswith("The run lacks")


def test_length_shares_pool_the_plans_of_every_run_and_say_when_none_were_kept():
    from experiments.peers.report import arm_length_shares, lengths_table

    def record(lengths_per_episode, chunk_size=5):
        return {"hyperparams": {"chunk_size": chunk_size},
                "evaluation": {"episodes": [{"plan_lengths": list(x)} for x in lengths_per_episode]}}

    shares = arm_length_shares([record([[1, 5], [5]]), record([[2, 5]])])
    assert shares == [0.2, 0.2, 0.0, 0.0, 0.6]  # 5 plans: one 1, one 2, three 5
    assert arm_length_shares([{"hyperparams": {}, "evaluation": {"episodes": [{"plan_lengths": [1, 1]}]}}]) == [1.0]
    old = {"hyperparams": {}, "evaluation": {"episodes": [{"reward": 1.0}]}}
    assert arm_length_shares([old]) is None and arm_length_shares([old], "offline_evaluation") is None
    summary = {"arms": {"a": {"label": "UA2C", "length_shares": {"offline": None, "online": shares}},
                        "b": {"label": "SAC", "length_shares": {"offline": None, "online": [1.0]}}}}
    assert lengths_table(summary)[2:] == ["| UA2C | – | 20 20 0 0 60 |", "| SAC | – | 100 |"]
    assert "Not recorded" in lengths_table({"arms": {"b": {"label": "SAC", "length_shares": None}}})[0]


def test_budget_overrides_reach_the_budget_and_bad_keys_are_named(tmp_path, capsys):
    args = cli.build_parser().parse_args(
        ["--budget", '{"rlpd_updates_per_step": 8, "ua2c": {"pretrain_steps": 100}}', "--scenarios", "validation"]
    )
    budget = cli._budget(args)
    assert budget.rlpd_updates_per_step == 8 and budget.ua2c.pretrain_steps == 100
    assert budget.ua2c.finetune_steps == FULL_PEERS_BUDGET.online_steps and budget.scenarios == "validation"
    out = ["--out", str(tmp_path), "--seeds", "0", "--arms", "sac"]
    for bad, name in (('{"rlpd_utd": 8}', "rlpd_utd"), ('{"ua2c": {"pretrain_step": 5}}', "pretrain_step"),
                      ('{"ua2c": 3}', "ua2c")):
        with pytest.raises(SystemExit) as exit_info:
            cli.main(["--budget", bad, *out])
        assert exit_info.value.code == 2 and name in capsys.readouterr().err


