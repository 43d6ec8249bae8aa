"""The traffic job's command line: ``python -m envs <command>`` and the ``ua2c`` console script."""

from __future__ import annotations

import configparser
import importlib
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from envs.cli import build_parser, main
from sb3_ua2c import UA2C

ROOT = Path(__file__).resolve().parents[2]


def test_console_scripts_point_at_their_packages() -> None:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    lines = cfg["options.entry_points"]["console_scripts"].strip().splitlines()
    scripts = dict(line.replace(" ", "").split("=") for line in lines)
    assert scripts == {"ua2c": "envs.cli:main", "ua2c-zoo": "sb3_ua2c.zoo:main"}
    module, name = scripts["ua2c"].split(":")
    assert getattr(importlib.import_module(module), name) is main


def test_python_m_envs_runs_the_command_line() -> None:
    out = subprocess.run([sys.executable, "-m", "envs", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage: python -m envs [-h] {collect,pretrain,finetune,evaluate,main,style} ...")
    out = subprocess.run([sys.executable, "-m", "envs"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and "the following arguments are required: command" in out.stderr


def test_the_console_script_names_itself(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith("usage: ua2c [-h]")


def test_style_is_handed_to_the_style_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["style", "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith("usage: python -m envs.style [-h] {collect,train,evaluate}")


def test_entropy_threshold_argument_takes_auto() -> None:
    parser = build_parser()
    for command in (["finetune", "--checkpoint", "c.zip"], ["evaluate", "--checkpoint", "c.zip"]):
        assert parser.parse_args([*command, "--entropy-threshold", "auto"]).entropy_threshold == "auto"
        assert parser.parse_args([*command, "--entropy-threshold", "inf"]).entropy_threshold == math.inf
        assert parser.parse_args([*command, "--entropy-threshold", "0.25"]).entropy_threshold == 0.25
        with pytest.raises(SystemExit):
            parser.parse_args([*command, "--entropy-threshold", "Auto"])


def test_collect_takes_the_behaviour_defaults_from_one_place() -> None:
    args = build_parser().parse_args(["collect"])
    assert (args.sumo_fraction, args.perturb_prob, args.accel_noise, args.perturb_steps, args.lane_change_prob,
            args.driver_style) == (1.0, 0.03, 2.5, 15, 0.02, "mixed")
    with pytest.raises(SystemExit):
        build_parser().parse_args(["collect", "--driver-style", "calm"])


def test_cli_bad_input_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["pretrain", "--dataset", str(tmp_path / "none"), "--out", str(tmp_path / "m.zip")]) == 2
    assert "no dataset at" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["finetune", "--checkpoint", "x.zip", "--env-kwargs", "[1, 2]"])
    assert "expected a JSON object" in capsys.readouterr().err
    assert main(["pretrain", "--dataset", "x", "--threads", "-1"]) == 2
    assert "--threads must be an integer >= 0, got -1" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_main_quick_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    loaded = []
    load = UA2C.load.__func__

    def counting_load(cls, path, *args, **kwargs):
        loaded.append(Path(path).name)
        return load(cls, path, *args, **kwargs)

    monkeypatch.setattr(UA2C, "load", classmethod(counting_load))
    assert main(["main", "--quick", "--run-dir", str(tmp_path / "run"), "--no-progress"]) == 0
    # finetune loads the pre-trained checkpoint, the evaluation the fine-tuned one (the pre-trained one is
    # evaluated in a second process, whose loads this process does not see)
    assert loaded == ["pretrained.zip", "finetuned.zip"]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert set(summary["summary"]) == {"pretrained", "finetuned", "dataset"}
    # the L_t histogram of each checkpoint's evaluation plans, printed under the table
    out = capsys.readouterr().out
    assert out.count("    95 % CI | ") == 2  # a row of intervals under each checkpoint's row
    for name in ("pretrained", "finetuned"):
        lengths = [n for e in summary["episodes"][name] for n in e["plan_lengths"]]
        shares = [100 * lengths.count(u) / len(lengths) for u in range(1, 6)]
        assert f"{name:>11} | L_t = 1..5, % of plans: " + " ".join(f"{p:.0f}" for p in shares) in out
    for name in ("pretrained.zip", "finetuned.zip", "finetuned.monitor.csv", "dataset/data"):
        assert (tmp_path / "run" / name).exists()
