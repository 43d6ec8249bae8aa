"""One home per default: the harnesses take UA2C's defaults from ``sb3_ua2c.defaults.defaults()`` and never write
one again; a line that states a default on purpose says so with ``# same as default: <reason>``."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from sb3_ua2c.defaults import defaults

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"
LITERAL = r"(\[[^\]]*\]|\([^)]*\)|-?[\d.e_+-]+|\"[^\"]*\"|'[^']*'|True|False)"
#: ``name=LIT``, ``name: type = LIT`` and ``"name": LIT``
ASSIGNMENT = re.compile(r"(?:\b(\w+)(?:\s*:\s*[\w\[\], |.]+)?\s*=\s*|[\"'](\w+)[\"']\s*:\s*)" + LITERAL)


def _flat_defaults() -> dict[str, object]:
    values = defaults()
    flat = {**values, **values.pop("policy_kwargs")}
    return {k: list(v) if isinstance(v, tuple) else v for k, v in flat.items()
            if v is not None and isinstance(v, int | float | str | bool | list | tuple)}


def _same(value: object, default: object) -> bool:
    value = list(value) if isinstance(value, tuple) else value
    if isinstance(value, bool) or isinstance(default, bool):
        return type(value) is type(default) and value == default
    return value == default


def default_literals(root: Path = EXPERIMENTS) -> list[str]:
    """``path:line: name=value`` of every UA2C default written as a literal without the comment."""
    flat, found = _flat_defaults(), []
    for path in sorted(root.rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if "# same as default:" in line:
                continue
            for match in ASSIGNMENT.finditer(line):
                name = match.group(1) or match.group(2)
                if name not in flat:
                    continue
                try:
                    value = ast.literal_eval(match.group(3))
                except (ValueError, SyntaxError):
                    continue
                if _same(value, flat[name]):
                    found.append(f"{path.relative_to(root.parent)}:{number}: {name}={match.group(3)}")
    return found


def test_no_ua2c_default_is_written_again_in_the_harnesses():
    assert default_literals() == []


def test_the_scan_finds_a_default_and_accepts_the_comment(tmp_path):
    n_elite = defaults()["policy_kwargs"]["n_elite"]
    (tmp_path / "budget.py").write_text(f'KW = {{"n_elite": {n_elite}}}\nX = dict(n_elite={n_elite})\n'
                                        f'Y = {{"n_elite": {n_elite}}}  # same as default: named on purpose\n'
                                        f'Z = {{"n_elite": {n_elite + 1}}}\n')
    assert default_literals(tmp_path) == [f"{tmp_path.name}/budget.py:1: n_elite={n_elite}",
                                          f"{tmp_path.name}/budget.py:2: n_elite={n_elite}"]
