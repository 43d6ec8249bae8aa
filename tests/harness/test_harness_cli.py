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


def _only_missing(monkeypatch, module: str) -> None:
    """Make ``module`` look uninstalled and every other extra installed, whatever this machine has."""
    real = common_cli.find_spec
    extras = {"rliable", "ogbench", "d3rlpy", "ray"}
    monkeypatch.setattr(common_cli, "find_spec",
                        lambda name: None if name == module else object() if name in extras else real(name))


def test_check_extras_names_the_pip_install(monkeypatch) -> None:
    check_extras([])  # nothing needed: no error
    _without(monkeypatch, "rliable", "ogbench", "d3rlpy")
    with pytest.raises(MissingExtraError, match=r'needs rliable, ogbench.*pip install "sb3-ua2c\[ogbench,peers\]"'):
        check_extras(["rliable", "ogbench", "rliable"])
    with pytest.raises(ValueError, match=r'pip install "sb3-ua2c\[peers\]" && pip install --no-deps d3rlpy==2.8.1'):
        check_extras(["d3rlpy"])


def _no_unit_may_run(*args, **kwargs):
    raise AssertionError("a unit ran before the extras were checked")


@pytest.mark.parametrize(("command", "units", "missing", "argv", "install"), [
    ("experiments.peers.cli", "experiments.peers.cli:run_peers", "rliable", ["--seeds", "0", "--arms", "sac"],
     'pip install "sb3-ua2c[peers]"'),
    ("experiments.peers.tuning", "experiments.peers.tuning:run_peers", "d3rlpy", ["--arms", "iql"],
     'pip install "sb3-ua2c[peers]" && pip install --no-deps d3rlpy==2.8.1'),
    ("experiments.ogbench.cli", "experiments.ogbench.runner:run_benchmark", "ogbench", [],
     'pip install "sb3-ua2c[ogbench]"'),
    ("experiments.execution.cli", "experiments.execution.cli:run_units", "ogbench", ["--env", "ogbench"],
     'pip install "sb3-ua2c[ogbench]"'),
    ("experiments.fig2.cli", "experiments.fig2.cli:run_all", "ray", ["--ray-address", "auto"],
     'pip install "sb3-ua2c[peers]"'),
])
def test_each_harness_checks_its_extras_before_any_unit(command, units, missing, argv, install, monkeypatch,
                                                        tmp_path, capsys) -> None:
    import importlib

    module, name = units.split(":")
    monkeypatch.setattr(importlib.import_module(module), name, _no_unit_may_run)
    _only_missing(monkeypatch, missing)
    try:
        code = importlib.import_module(command).main(["--quick", *argv, "--out", str(tmp_path / "out")])
    except SystemExit as exc:  # argparse's error: usage and message on stderr
        code = exc.code
    assert code == 2
    assert install in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing written either
