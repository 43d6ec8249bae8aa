"""The layout the docs promise (docs/layout.md): three one-way layers, modules small enough to read,
and a wheel that holds the algorithm and the traffic application, never a research harness.

* ``sb3_ua2c``: the algorithm. Imports neither ``envs`` nor ``experiments``; its command line
  (``sb3_ua2c/__main__.py``, the user's traffic job) may import ``envs``.
* ``envs``: the traffic application. May import ``sb3_ua2c``, never ``experiments``.
* ``experiments``: the research harnesses of a checkout, outside the wheel. May import both.
"""

import ast
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 800
PACKAGES = ("sb3_ua2c", "envs", "experiments")
MODULES = sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))
#: Top-level modules a layer must never import (anywhere in a module, lazily or not).
FORBIDDEN = {
    "sb3_ua2c": {"envs", "experiments", "libsumo", "traci", "sumolib", "ray", "d3rlpy", "rliable", "ogbench"},
    "envs": {"experiments", "ray", "d3rlpy", "rliable", "ogbench"},
    "experiments": set(),
}
#: What the user's command line (``python -m sb3_ua2c``) may import beyond the library.
ENTRY_SCRIPT_MAY_IMPORT = {"envs"}
#: Modules that ``import sb3_ua2c`` / ``import envs`` must not load.
HEAVY = ("envs", "experiments", "libsumo", "traci", "sumolib", "ray", "d3rlpy", "rliable", "ogbench", "minari",
         "optuna", "rl_zoo3")


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def imported_modules(source: str, package: str | None = None) -> set[str]:
    """Every module an ``import`` or ``from ... import`` statement names, anywhere in ``source``
    (relative imports resolved against ``package``)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = (package or "").split(".")
                base = base[: len(base) - node.level + 1]
                names.add(".".join([*base, node.module] if node.module else base))
            elif node.module:
                names.add(node.module)
    return names


def _package_of(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts if path.name == "__init__.py" else parts[:-1])


def test_the_tree_has_modules() -> None:
    assert {p.relative_to(ROOT).parts[0] for p in MODULES} == set(PACKAGES)
    assert len(MODULES) > 60


def test_imported_modules_sees_lazy_and_relative_imports() -> None:
    source = "import os\ndef f():\n    from envs.wrappers import X\n    from . import sibling\n    from ..b import c\n"
    assert imported_modules(source, "sb3_ua2c.sub") == {"os", "envs.wrappers", "sb3_ua2c.sub", "sb3_ua2c.b"}


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_module_length(path: Path) -> None:
    n_lines = len(path.read_text(encoding="utf-8").splitlines())
    assert n_lines <= MAX_MODULE_LINES, f"{_rel(path)} has {n_lines} lines (> {MAX_MODULE_LINES})"


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_layers_import_one_way(path: Path) -> None:
    layer = path.relative_to(ROOT).parts[0]
    tops = {name.split(".")[0] for name in imported_modules(path.read_text(encoding="utf-8"), _package_of(path))}
    forbidden = FORBIDDEN[layer] - (ENTRY_SCRIPT_MAY_IMPORT if _rel(path) == "sb3_ua2c/__main__.py" else set())
    assert not tops & forbidden, f"{_rel(path)} imports {sorted(tops & forbidden)} (layer {layer})"


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_no_module_imports_the_entry_script(path: Path) -> None:
    if path.name != "__main__.py":
        assert "sb3_ua2c.__main__" not in imported_modules(path.read_text(encoding="utf-8"), _package_of(path))


@pytest.mark.parametrize("package", ["sb3_ua2c", "envs"])
def test_importing_a_package_loads_no_heavy_module(package: str) -> None:
    code = (f"import sys, {package}; "
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}) - {{{package!r}}}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", f"import {package} loads {out.stdout.strip()}"


def test_the_wheel_holds_the_algorithm_and_the_application_only(tmp_path: Path) -> None:
    """Build the wheel from a copy of the tree (no stale ``build/``) and list its top-level entries."""
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "results", "runs", ".*_cache"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "wheel"), str(src)], check=True, capture_output=True, env=env)
    (wheel,) = (tmp_path / "wheel").glob("*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"sb3_ua2c", "envs"}
    assert "envs/data/style_classifier.pt" in names and "sb3_ua2c/ua2c.py" in names
    assert not [n for n in names if "experiments" in n.split("/") or n.startswith(("tests/", "benchmarks/"))]
