"""The acting-rule screen (``python -m experiments acting``): cells, checkpoints by stage, the paired report by hand,
and a quick run end to end on a head-to-head run's snapshots."""

import json

import pytest

from experiments.acting import cli, report
from experiments.acting.cells import CELLS, DEFAULT_CELL, parse_cell, stage_checkpoint
from tests.extras import require


def test_cells_parse_and_name_a_bad_one():
    settings, rule = parse_cell("best@ensemble")
    assert settings == {"selection": "elite", "n_elite": 1} and rule.rule == "ensemble"
    assert CELLS[0] == DEFAULT_CELL and len(set(CELLS)) == len(CELLS) == 15
    for bad in ("median@eq7", "elite@forever", "elite"):
        with pytest.raises(ValueError, match="--cells"):
            parse_cell(bad)


def test_stage_checkpoints_are_found_or_named(tmp_path):
    (tmp_path / "pretrain_k5.zip").write_bytes(b"")
    snapshots = tmp_path / "ua2c" / "snapshots"
    snapshots.mkdir(parents=True)
    (snapshots / "model_5000_steps.zip").write_bytes(b"")
    assert stage_checkpoint(tmp_path, "pretrained").name == "pretrain_k5.zip"
    assert stage_checkpoint(tmp_path, "online_5000").name == "model_5000_steps.zip"
    with pytest.raises(FileNotFoundError, match="--snapshot-every"):
        stage_checkpoint(tmp_path, "online_20000")
    with pytest.raises(ValueError, match="--stages"):
        stage_checkpoint(tmp_path, "online")


def _summary(reward, collision=0.0):
    return {"reward": reward, "collision": collision, "jerk_per_step": 1.0, "mean_executed_length": 2.0,
            "ms_per_plan": 1.0}


def test_report_pairs_every_cell_with_the_default_the_best_and_the_behaviour_by_hand():
    require("rliable")
    records = {
        "online_20000": {DEFAULT_CELL: {0: _summary(10.0), 1: _summary(20.0), 2: _summary(30.0)},
                         "mean@eq7": {0: _summary(12.0), 1: _summary(21.0), 2: _summary(33.0)}},
        "pretrained": {DEFAULT_CELL: {0: _summary(1.0), 1: _summary(2.0), 2: _summary(3.0)}},
        "behaviour": {"behaviour": {0: _summary(5.0), 1: _summary(5.0), 2: _summary(5.0, 1.0)}},
    }
    summary = report.aggregate(records, reps=200)
    assert list(summary["stages"]) == ["pretrained", "online_20000"]
    stage = summary["stages"]["online_20000"]
    assert stage["best"] == "mean@eq7"
    mean = stage["cells"]["mean@eq7"]
    vs = mean["vs_default"]["reward"]  # differences 2, 1, 3: mean 2, SD 1, t(0.975, 2) = 4.303
    assert vs["difference"] == pytest.approx(2.0) and vs["x_better_runs"] == 3
    assert (vs["ci_low"], vs["ci_high"]) == pytest.approx((2 - 4.303 / 3**0.5, 2 + 4.303 / 3**0.5), abs=1e-3)
    assert mean["reward"]["mean"] == pytest.approx(22.0) and mean["reward_sd_over_runs"] == pytest.approx(10.536, abs=1e-3)
    assert mean["vs_behaviour"]["reward"]["difference"] == pytest.approx(17.0)
    assert summary["behaviour"]["collision"] == pytest.approx(1 / 3)
    text = report.markdown({**summary, "command": "c", "date": "d", "episodes": 100, "scenarios": "validation",
                            "checkpoints": "w"}, CELLS)
    assert "`mean@eq7` **(best)**" in text and "+2.0 [" in text


def test_cli_names_a_bad_cell_and_a_missing_run(tmp_path, capsys):
    require("rliable")
    with pytest.raises(SystemExit):
        cli.main(["--checkpoints", str(tmp_path), "--cells", "median@eq7"])
    assert "--cells" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["--checkpoints", str(tmp_path / "none")])
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_quick_run_on_a_head_to_head_run_writes_the_report_and_resumes(tmp_path, capsys):
    require("rliable")
    from experiments.peers import cli as peers_cli

    run = tmp_path / "run"
    assert peers_cli.main(["--quick", "--seeds", "0", "1", "--arms", "ua2c", "--snapshot-every", "10",
                           "--out", str(run), "--workers", "1", "--scenarios", "validation"]) == 0
    argv = ["--checkpoints", str(run), "--quick", "--seeds", "0", "1", "--stages", "pretrained", "online_20",
            "--cells", DEFAULT_CELL, "uncertainty@ensemble", "--workers", "1", "--scenarios", "validation",
            "--out", str(tmp_path / "screen")]
    assert cli.main(argv) == 0
    summary = json.loads((tmp_path / "screen" / "acting.json").read_text())
    assert set(summary["stages"]) == {"pretrained", "online_20"}
    text = (tmp_path / "screen" / "acting.md").read_text()
    assert text.index("## pretrained") < text.index("## online_20")
    cell = summary["stages"]["online_20"]["cells"]["uncertainty@ensemble"]
    assert cell["seeds"] == [0, 1] and cell["mean_executed_length"] == 1.0
    assert cell["vs_default"]["reward"]["runs"] == 2
    record = json.loads((tmp_path / "screen" / "acting_raw" / "seed1" / "online_20" / "uncertainty@ensemble.json")
                        .read_text())
    assert record["scenario_seed"] == 3001 and len(record["episodes"]["reward"]) == 2
    capsys.readouterr()
    assert cli.main(argv) == 0  # every unit stored: nothing runs again
    assert "(10 stored)" in capsys.readouterr().out
