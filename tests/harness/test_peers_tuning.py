"""The head-to-head's tuning (``python -m experiments peers-tuning``): each method's configurations as budgets,
per-arm hyperparameters reaching the units, the choice on hand-made records, the ``--budget @FILE`` of the test
run, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from extras import require

from experiments.peers import cli, tuning
from experiments.peers.budget import FULL_PEERS_BUDGET, QUICK_PEERS_BUDGET, PeersBudget
from experiments.peers.runner import PeersPaths, arm_unit


def test_configuration_zero_is_every_method_at_its_published_settings():
    base = FULL_PEERS_BUDGET
    # UA2C's published λ is 1 (the paper's, and its default when the tuning ran), written out now that the default
    # is 0.3, with that day's N = 10 and 3 × 512 field (the defaults since 2026-12-07 are N = 5 and 256 × 2)
    day = {"flow_steps": 10, "policy_kwargs": {"net_arch": [512, 512, 512], "n_elite": 8}}
    assert tuning.overrides({a: 0 for a in tuning.TUNED_ARMS}, base) == {"ua2c": {"algo_kwargs": {**day, "q_weight": 1.0}}}
    assert tuning.overrides({a: 0 for a in tuning.TUNED_ARMS if a != "ua2c_adaptive"}, base) == {}
    assert tuning.config_budget(0, tuning.TUNED_ARMS, base) == PeersBudget(scenarios="validation").with_overrides(
        {"ua2c": {"algo_kwargs": {**day, "q_weight": 1.0}}})
    assert all(len(settings) == tuning.N_CONFIGS for settings in tuning.GRID.values())  # the same budget for all


def test_a_configuration_sets_each_method_where_its_unit_reads_it():
    base = FULL_PEERS_BUDGET
    assert tuning.overrides({"ua2c_adaptive": 1, "sac": 1, "rlpd": 2, "iql": 1}, base) == {
        "ua2c": {"algo_kwargs": {**tuning.TUNING_DAY_FIELD, "q_weight": 0.3}},
        "peer_kwargs": {"sac": {"learning_rate": 1e-3}, "iql": {"expectile": 0.9, "weight_temp": 10.0}},
        "rlpd_updates_per_step": 8,
    }
    budget = tuning.config_budget(2, tuning.TUNED_ARMS, base)
    assert budget.scenarios == "validation" and budget.rlpd_updates_per_step == 8
    assert budget.ua2c.algo_kwargs == {**tuning.TUNING_DAY_FIELD, "q_weight": 3.0}  # the rest at UA2C's defaults
    assert budget.peer_kwargs["calql"] == {"conservative_weight": 0.2}
    paths = PeersPaths.under("/tmp/run")
    assert arm_unit("crossq", 0, budget, paths, {}).kwargs["hyperparams"] == {"learning_starts": 100}
    assert arm_unit("rebrac", 0, budget, paths, {}).kwargs["config_kwargs"] == {"actor_beta": 0.001, "critic_beta": 0.001}
    assert arm_unit("iql", 0, budget, paths, {}).kwargs["config_kwargs"] == {"weight_temp": 0.5}


def test_peer_kwargs_are_checked_and_merged_after_the_shared_sb3_settings():
    budget = QUICK_PEERS_BUDGET.with_overrides({"peer_kwargs": {"tqc": {"batch_size": 16}}})
    assert budget.sb3_kwargs("tqc") == {"learning_starts": 10, "batch_size": 16, "policy_kwargs": {"net_arch": [16]}}
    assert budget.sb3_kwargs("sac") == QUICK_PEERS_BUDGET.sb3_hyperparams
    with pytest.raises(ValueError, match=r"peer_kwargs: 'ua2c_fixed' is not a peer arm"):
        PeersBudget(peer_kwargs={"ua2c_fixed": {"q_weight": 1.0}})
    with pytest.raises(ValueError, match=r"peer_kwargs\['iql'\] must be a mapping"):
        PeersBudget(peer_kwargs={"iql": 0.9})
    with pytest.raises(ValueError, match="'peer_kwargs' must be an object"):
        FULL_PEERS_BUDGET.with_overrides({"peer_kwargs": [1]})
    with pytest.raises(ValueError, match="configuration of 'sac' must be an integer in"):
        tuning.overrides({"sac": 3}, FULL_PEERS_BUDGET)
    with pytest.raises(ValueError, match="'behaviour' is not tuned"):
        tuning.overrides({"behaviour": 0}, FULL_PEERS_BUDGET)


def test_a_run_recorded_before_peer_kwargs_existed_resumes(tmp_path):
    paths = PeersPaths.under(tmp_path)
    values = FULL_PEERS_BUDGET.to_dict()
    del values["peer_kwargs"]
    paths.work.mkdir(parents=True)
    paths.manifest.write_text(json.dumps(values, default=str).replace("Infinity", '"inf"'))
    paths.check_budget(FULL_PEERS_BUDGET)  # the same budget: no error
    with pytest.raises(ValueError, match=r"differs in \['peer_kwargs'\]"):
        paths.check_budget(FULL_PEERS_BUDGET.with_overrides({"peer_kwargs": {"sac": {"learning_rate": 1e-3}}}))


def _write(out: Path, config: int, arm: str, seed: int, rewards: list[float], collisions: list[bool]) -> None:
    path = tuning.config_paths(out, config).record(seed, arm)
    path.parent.mkdir(parents=True, exist_ok=True)
    episodes = [{"reward": r, "collision": c} for r, c in zip(rewards, collisions, strict=True)]
    path.write_text(json.dumps({"arm": arm, "seed": seed, "evaluation": {"episodes": episodes}}))


def test_the_choice_is_the_best_mean_over_runs_and_waits_for_every_run(tmp_path):
    # run scores (mean over episodes): c0 (10, 30) -> 20; c1 (25, 25) -> 25; c2 (40, 0) -> 20
    for config, per_seed in enumerate([([0, 20], [30, 30]), ([20, 30], [25, 25]), ([40, 40], [0, 0])]):
        for seed, rewards in enumerate(per_seed):
            _write(tmp_path, config, "sac", seed, rewards, [False, config == 2])
    for config in range(2):  # TQC: configuration 2 has not run yet
        for seed in range(2):
            _write(tmp_path, config, "tqc", seed, [float(config)], [False])
    methods = tuning.collect(tmp_path, ["sac", "tqc"], [0, 1])
    assert methods["sac"]["mean_reward"] == [20.0, 25.0, 20.0] and methods["sac"]["chosen"] == 1
    assert methods["sac"]["configs"][2]["collision"] == [0.5, 0.5]
    assert methods["tqc"]["chosen"] is None and methods["tqc"]["configs"][2]["reward"] == []
    assert tuning.selected_overrides(methods, FULL_PEERS_BUDGET) == {"peer_kwargs": {"sac": {"learning_rate": 1e-3}}}
    for seed in range(2):  # a tie keeps the earlier configuration
        _write(tmp_path, 2, "tqc", seed, [1.0], [False])
    assert tuning.collect(tmp_path, ["tqc"], [0, 1])["tqc"]["chosen"] == 1
    table = tuning.format_markdown({"command": "c", "date": "d", "seeds": [0, 1], "online_steps": 5000,
                                    "eval_episodes": 2, "methods": methods, "selected": {}})
    assert "| SB3 SAC (online) | 1: learning_rate 0.001 | 25.0, 25.0 | 25.0 | 0.00, 0.00 | **yes** |" in table
    assert "| sb3-contrib TQC (online) | 2: learning_starts 100 | — | — | — | pending |" in table


def test_the_test_run_reads_the_selection_from_a_file(tmp_path):
    selected = tmp_path / "selected.json"
    selected.write_text(json.dumps({"peer_kwargs": {"iql": {"weight_temp": 0.5}}, "rlpd_updates_per_step": 2}))
    args = cli.build_parser().parse_args(["--budget", f"@{selected}"])
    budget = cli._budget(args)
    assert budget.peer_kwargs == {"iql": {"weight_temp": 0.5}} and budget.rlpd_updates_per_step == 2
    assert budget.scenarios == "test"
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["--budget", f"@{tmp_path / 'missing.json'}"])


def test_tuning_command_end_to_end_at_the_quick_budget(tmp_path, capsys):
    require("rliable")  # the report's statistics: the peers extra
    argv = ["--quick", "--arms", "ua2c_adaptive", "sac", "--seeds", "0", "--workers", "1", "--out", str(tmp_path)]
    assert tuning.main(argv) == 0
    summary = json.loads((tmp_path / "tuning.json").read_text())
    assert [len(m["configs"]) for m in summary["methods"].values()] == [3, 3]
    assert all(m["chosen"] is not None for m in summary["methods"].values())
    record = json.loads(tuning.config_paths(tmp_path, 1).record(0, "sac").read_text())
    assert record["hyperparams"]["learning_rate"] == 1e-3 and record["eval_seeds"] == [3000]  # validation scenarios
    assert json.loads((tmp_path / "selected.json").read_text()) == summary["selected"]
    assert "(30 online env steps, 1 evaluation episode(s) per run)" in (tmp_path / "tuning.md").read_text()
    capsys.readouterr()
    assert tuning.main([*argv, "--report-only"]) == 0  # from the stored records: nothing runs
    assert "unit" not in capsys.readouterr().out
    assert tuning.main(argv) == 0  # resumes: every unit is stored
    assert " unit " not in capsys.readouterr().out
    assert tuning.main([*argv, "--report-only", "--seeds", "0", "1"]) == 0  # seed 1 never ran: no choice
    assert not (tmp_path / "selected.json").exists()
    assert "Pending: `selected.json`" in (tmp_path / "tuning.md").read_text()
    for bad in (["--arms", "behaviour"], ["--configs", "3"], ["--seeds", "-1"], ["--workers", "0"]):
        with pytest.raises(SystemExit):
            tuning.main([*bad, "--out", str(tmp_path / "bad")])
    assert not (tmp_path / "bad").exists()
