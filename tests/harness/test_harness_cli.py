"""The harness framework shared by every experiment (``experiments.common.cli``): the common options, the
seeds they select, and the check of the optional packages made before any unit runs."""

from __future__ import annotations

import pytest

from experiments.common import cli as common_cli
from experiments.common.cli import MissingExtraError, check_extras, harness_parent, select_seeds


def test_the_parent_parser_holds_the_common_options() -> None:
    parser = harness_parent(seeds="0 1", work="<out>/x_work", workers=3)
    args = parser.parse_args(["--seeds", "4", "2", "4", "--out", "r", "--ray-address", "auto", "--quick",
                              "--report-only"])
    assert (args.seeds, args.out, args.work, args.workers) == ([4, 2, 4], "r", None, 3)
    assert (args.ray_address, args.quick, args.report_only) == ("auto", True, True)
    defaults = parser.parse_args([])
    assert (defaults.seeds, defaults.out, defaults.ray_address, defaults.quick) == (None, "results", None, False)


def test_select_seeds_keeps_the_order_without_repeats() -> None:
    assert select_seeds([4, 2, 4], [0]) == [4, 2]
    assert select_seeds(None, range(3)) == [0, 1, 2]
    for bad in ([-1], [100], [], [True]):
        with pytest.raises(ValueError, match=r"--seeds must be integers in \[0, 100\)"):
            select_seeds(bad, [0])
    assert select_seeds([999], [0], high=1000) == [999]


def _without(monkeypatch, *modules: str) -> None:
    """Make ``modules`` look uninstalled to the extras check."""
    real = common_cli.find_spec
    monkeypatch.setattr(common_cli, "find_spec", lambda name: None if name in modules else real(name))


def test_check_extras_names_the_pip_install(monkeypatch) -> None:
    check_extras([])  # nothing needed: no error
    _without(monkeypatch, "rliable", "ogbench", "d3rlpy")
    with pytest.raises(MissingExtraError, match=r'needs rliable, ogbench.*pip install "sb3-ua2c\[ogbench,peers\]"'):
        check_extras(["rliable", "ogbench", "rliable"])
    with pytest.raises(ValueError, match=r'pip install "sb3-ua2c\[peers\]" && pip install --no-deps d3rlpy==2.8.1'):
        check_extras(["d3rlpy"])


def _no_unit_may_run(*args, **kwargs):
    raise AssertionError("a unit ran before the extras were checked")


def test_peers_checks_its_extras_before_any_unit(monkeypatch, tmp_path, capsys) -> None:
    from experiments.peers import cli

    monkeypatch.setattr(cli, "run_peers", _no_unit_may_run)
    _without(monkeypatch, "rliable")
    with pytest.raises(SystemExit) as exc:
        cli.main(["--quick", "--seeds", "0", "--arms", "sac", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert 'pip install "sb3-ua2c[peers]"' in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing written either


def test_peers_tuning_checks_its_extras_before_any_unit(monkeypatch, tmp_path, capsys) -> None:
    from experiments.peers import tuning

    monkeypatch.setattr(tuning, "run_peers", _no_unit_may_run)
    _without(monkeypatch, "d3rlpy")
    with pytest.raises(SystemExit) as exc:
        tuning.main(["--quick", "--arms", "iql", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "pip install --no-deps d3rlpy==2.8.1" in capsys.readouterr().err


def test_ogbench_checks_its_extras_before_any_unit(monkeypatch, tmp_path, capsys) -> None:
    from experiments.ogbench import cli, runner

    monkeypatch.setattr(runner, "run_benchmark", _no_unit_may_run)
    _without(monkeypatch, "ogbench")
    assert cli.main(["--quick", "--out", str(tmp_path)]) == 2
    assert 'pip install "sb3-ua2c[ogbench]"' in capsys.readouterr().err


def test_execution_checks_its_extras_before_any_unit(monkeypatch, tmp_path, capsys) -> None:
    from experiments.common import runner
    from experiments.execution import cli

    monkeypatch.setattr(runner, "run_units", _no_unit_may_run)
    _without(monkeypatch, "ogbench")
    with pytest.raises(SystemExit) as exc:
        cli.main(["--quick", "--env", "ogbench", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert 'pip install "sb3-ua2c[ogbench]"' in capsys.readouterr().err


def test_fig2_on_ray_checks_for_ray_before_any_unit(monkeypatch, tmp_path, capsys) -> None:
    from experiments.fig2 import cli

    monkeypatch.setattr(cli, "run_all", _no_unit_may_run)
    _without(monkeypatch, "ray")
    with pytest.raises(SystemExit) as exc:
        cli.main(["--quick", "--ray-address", "auto", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert 'pip install "sb3-ua2c[peers]"' in capsys.readouterr().err
